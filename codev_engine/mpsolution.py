"""The explicit solution of an ``MpProgram``: critical regions with affine optimizers.

Saved as a plain ``.npz`` (format tag ``codev-mp-solution/1``, no pickle): the program's
own arrays under a ``program.`` prefix, the regions' rows concatenated with an offset
array, the affine laws stacked.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import write_npz
from .errors import SpecError
from .locate import PointLocator
from .mpprogram import MpProgram
from .npzfile import array, load_checked, offsets, real, text

__all__ = ["CriticalRegion", "MpSolution", "SOLUTION_FORMAT"]

#: format tag of solution files; bumped on incompatible changes
SOLUTION_FORMAT = "codev-mp-solution/1"


@dataclass(frozen=True)
class CriticalRegion:
    """A region ``{theta : A theta <= b}`` where ``z*(theta) = K theta + k``.

    Attributes
    ----------
    A : (r, d) ndarray
        Non-redundant, unit-norm rows.
    b : (r,) ndarray
    K : (nz, d) ndarray
    k : (nz,) ndarray
    active : tuple of int
        The optimal active set (QP) or basis (LP), as row indices of the reduced program.
    """

    A: np.ndarray
    b: np.ndarray
    K: np.ndarray
    k: np.ndarray
    active: tuple[int, ...] = ()


@dataclass
class MpSolution:
    """Explicit solution of an ``MpProgram``: a partition of its feasible parameter set.

    Attributes
    ----------
    program : MpProgram
    regions : list of CriticalRegion
        In the original variables ``z`` (equalities eliminated internally are mapped back).
    domain_A, domain_b : ndarray
        The feasible parameter set (the union of the regions) as ``domain_A theta <=
        domain_b``: its facets, non-redundant up to 5,000 rows (above that a row may
        also only touch the set; see docs/algorithm.md).
    seconds : float
        Wall time of the solve.
    stats : dict
        Counters (LPs solved, pieces, ...).
    """

    program: MpProgram
    regions: list[CriticalRegion]
    domain_A: np.ndarray | None = None
    domain_b: np.ndarray | None = None
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    _locator: PointLocator | None = field(default=None, repr=False)
    _laws: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def num_regions(self) -> int:
        return len(self.regions)

    @property
    def locator(self) -> PointLocator:
        if self._locator is None:
            self._locator = PointLocator([r.A for r in self.regions], [r.b for r in self.regions])
        return self._locator

    def _theta(self, Theta: np.ndarray) -> np.ndarray:
        Theta = np.atleast_2d(np.asarray(Theta, dtype=float))
        if Theta.shape[1] != self.program.d:
            raise ValueError(
                f"expected parameters of dimension {self.program.d}, got {Theta.shape[1]}"
            )
        return Theta

    def locate(self, Theta: np.ndarray) -> np.ndarray:
        """Region index per row of ``Theta`` (P, d) -> (P,) int, -1 outside."""
        return self.locator.locate(self._theta(Theta))

    def primal(self, Theta: np.ndarray) -> np.ndarray:
        """Optimizer ``z*(theta)`` per row -> (P, nz), NaN outside the feasible set."""
        Theta = self._theta(Theta)
        idx = self.locate(Theta)
        Z = np.full((Theta.shape[0], self.program.nz), np.nan)
        if self.regions:
            if self._laws is None:  # (stacked once: 860k regions of 8 x 8 are 440 MB)
                self._laws = (
                    np.stack([r.K for r in self.regions]),
                    np.stack([r.k for r in self.regions]),
                )
            K, k = self._laws
            inside = idx >= 0
            Z[inside] = np.einsum("pij,pj->pi", K[idx[inside]], Theta[inside]) + k[idx[inside]]
        return Z

    def value(self, Theta: np.ndarray) -> np.ndarray:
        """Optimal value per row -> (P,), NaN outside the feasible set."""
        Theta = self._theta(Theta)
        Z = self.primal(Theta)
        p = self.program
        lin = p.c[None, :] + Theta @ p.C.T
        return 0.5 * np.einsum("pi,ij,pj->p", Z, p.H, Z) + np.einsum("pi,pi->p", lin, Z)

    def summary(self) -> str:
        p = self.program
        return (
            f"{p.kind} {p.name or ''}: {self.num_regions} critical regions "
            f"(nz={p.nz}, d={p.d}) in {self.seconds:.3f} s"
        ).replace("  ", " ")

    def __repr__(self) -> str:
        return (
            f"MpSolution(num_regions={self.num_regions}, nz={self.program.nz}, d={self.program.d})"
        )

    # ---- persistence -----------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write the solution (and its program) to ``path`` (``.npz``) atomically."""
        p = self.program
        d, nz = p.d, p.nz
        regs = self.regions
        arrays: dict[str, np.ndarray] = {
            "format": np.array(SOLUTION_FORMAT),
            "A": np.vstack([r.A for r in regs]) if regs else np.zeros((0, d)),
            "b": np.concatenate([r.b for r in regs]) if regs else np.zeros(0),
            "offsets": np.cumsum([0] + [r.A.shape[0] for r in regs]).astype(np.int64),
            "K": np.stack([r.K for r in regs]) if regs else np.zeros((0, nz, d)),
            "k": np.stack([r.k for r in regs]) if regs else np.zeros((0, nz)),
            "active": np.array([i for r in regs for i in r.active], dtype=np.int64),
            "active_offsets": np.cumsum([0] + [len(r.active) for r in regs]).astype(np.int64),
            "domain_A": self.domain_A if self.domain_A is not None else np.zeros((0, d)),
            "domain_b": self.domain_b if self.domain_b is not None else np.zeros(0),
            "meta": np.array(json.dumps({"seconds": self.seconds, "name": p.name})),
        }
        for key in ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq"):
            val = getattr(p, key)
            if val is not None:
                arrays[f"program.{key}"] = val
        return write_npz(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> MpSolution:
        """Read a solution written by ``save``; a malformed file raises ``SpecError``."""
        return load_checked(path, "solution file", cls._from_arrays)

    @classmethod
    def _from_arrays(cls, data: dict[str, np.ndarray]) -> MpSolution:
        fmt = text(data, "format")
        if fmt != SOLUTION_FORMAT:
            raise SpecError(f"unsupported solution format {fmt!r}", field="format")
        prog = {k[len("program.") :]: v for k, v in data.items() if k.startswith("program.")}
        try:
            meta = json.loads(text(data, "meta"))
        except ValueError:
            raise SpecError("not valid JSON", field="meta") from None
        if not isinstance(meta, dict):
            raise SpecError("must be a JSON object", field="meta")
        for key in ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta"):
            if key not in prog:
                raise SpecError("missing array", field=f"program.{key}")
        try:
            program = MpProgram(**prog, name=str(meta.get("name", "")))
        except TypeError:
            raise SpecError("unknown program arrays", field="program") from None
        except SpecError as exc:
            raise SpecError(exc.reason, field=f"program.{exc.field}") from None
        d, nz = program.d, program.nz
        K = real(data, "K", ndim=3)
        R = K.shape[0]
        if K.shape[1:] != (nz, d):
            raise SpecError(f"must have shape ({R}, {nz}, {d}), got {K.shape}", field="K")
        k = real(data, "k", shape=(R, nz))
        A = real(data, "A", ndim=2)
        if A.shape[1] != d:
            raise SpecError(f"must have {d} columns, got {A.shape}", field="A")
        b = real(data, "b", shape=(A.shape[0],))
        off = offsets(data, "offsets", R, A.shape[0])
        act = array(data, "active")
        if act.dtype.kind not in "iu" or act.ndim != 1:
            raise SpecError("must be a 1-D integer array", field="active")
        aoff = offsets(data, "active_offsets", R, act.shape[0])
        dA = real(data, "domain_A", ndim=2)
        if dA.shape[1] != d:
            raise SpecError(f"must have {d} columns, got {dA.shape}", field="domain_A")
        db = real(data, "domain_b", shape=(dA.shape[0],))
        regions = [
            CriticalRegion(
                A=A[off[i] : off[i + 1]],
                b=b[off[i] : off[i + 1]],
                K=K[i],
                k=k[i],
                active=tuple(int(j) for j in act[aoff[i] : aoff[i + 1]]),
            )
            for i in range(R)
        ]
        return cls(
            program=program,
            regions=regions,
            domain_A=dA,
            domain_b=db,
            seconds=float(meta.get("seconds", 0.0)),
        )
