"""The problem a spec describes: frozen plain data (plant, model, MPC, verification).

Parsed and validated by :mod:`codev_engine.spec.parse`; the TOML contract is documented in
``docs/spec.md``. All bounds and sets are in *plant* coordinates (absolute values), never
deviations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PlantSpec", "ModelSpec", "MpcSpec", "SetSpec", "VerifySpec", "Problem"]


@dataclass(frozen=True)
class PlantSpec:
    """Continuous-time plant ``dx/dt = f(x, u)``.

    Exactly one of ``dynamics`` (expression strings, one per state) and the pair ``A``
    (n, n), ``B`` (n, m) is set -- unless the model section gives an explicit discrete model,
    in which case both may be absent.
    """

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    dynamics: tuple[str, ...] | None = None
    A: np.ndarray | None = None
    B: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.states)

    @property
    def m(self) -> int:
        return len(self.inputs)


@dataclass(frozen=True)
class ModelSpec:
    """Discrete-time prediction model settings.

    ``x_op`` (n,) and ``u_op`` (m,) are the operating point (linearisation point and MPC
    reference), zero by default. ``A``/``B`` set an explicit discrete model (then the plant
    is not discretised).
    """

    sample_time: float
    method: str = "zoh"
    x_op: np.ndarray = field(default_factory=lambda: np.zeros(0))
    u_op: np.ndarray = field(default_factory=lambda: np.zeros(0))
    A: np.ndarray | None = None
    B: np.ndarray | None = None


@dataclass(frozen=True)
class MpcSpec:
    """MPC design: horizon, norm, weights and bounds (bounds may be +-inf)."""

    horizon: int
    norm: str  # "1", "inf" or "2"
    Q: np.ndarray
    R: np.ndarray
    P: np.ndarray | None
    x_min: np.ndarray
    x_max: np.ndarray
    u_min: np.ndarray
    u_max: np.ndarray
    simplify: bool = False
    # Half-width of the exploration box around x_op on state axes whose x_min/x_max is
    # infinite: the explicit law is computed on that box there (the parameter set must be
    # bounded). Spec field ``mpc.domain_bound``, default 100.
    domain_bound: float = 100.0


@dataclass(frozen=True)
class SetSpec:
    """A set in state space: a box (``lower``/``upper``, +-inf allowed) or ``A x <= b``."""

    kind: str  # "box" or "polytope"
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    A: np.ndarray | None = None
    b: np.ndarray | None = None

    def halfspaces(self) -> tuple[np.ndarray, np.ndarray]:
        """H-representation ``(A, b)`` with ``A x <= b``; infinite box sides are dropped."""
        if self.kind == "polytope":
            assert self.A is not None and self.b is not None
            return self.A, self.b
        assert self.lower is not None and self.upper is not None
        n = self.lower.shape[0]
        eye = np.eye(n)
        rows, rhs = [], []
        for i in range(n):
            if np.isfinite(self.upper[i]):
                rows.append(eye[i])
                rhs.append(self.upper[i])
            if np.isfinite(self.lower[i]):
                rows.append(-eye[i])
                rhs.append(-self.lower[i])
        return np.array(rows, dtype=float).reshape(-1, n), np.array(rhs, dtype=float)


@dataclass(frozen=True)
class VerifySpec:
    """Closed-loop verification settings."""

    time_horizon: float
    initial_lower: np.ndarray
    initial_upper: np.ndarray
    hold: str = "zoh"  # "zoh" or "continuous"
    max_depth: int = 6
    step: float = 0.01
    input_bounds: bool = False
    unsafe: tuple[SetSpec, ...] = ()
    safe: tuple[SetSpec, ...] = ()


@dataclass(frozen=True)
class Problem:
    """A whole validated spec file."""

    name: str
    plant: PlantSpec
    model: ModelSpec
    mpc: MpcSpec
    verify: VerifySpec | None
    path: str | None = None
    source: str = ""  # the TOML text, for hashing and sessions
