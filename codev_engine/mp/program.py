"""The general multi-parametric program (mp-LP / mp-QP) in the neutral convention.

::

    minimize_z   0.5 z'Hz + (c + C theta)'z
    subject to   A z   <= b   + F theta
                 Aeq z  = beq + Feq theta
                 A_theta theta <= b_theta

The MPC front door (``mpc.py``) builds one of these; ``mpsolve`` solves it. The same
convention is the ``.npz`` file format read by :meth:`MpProgram.load` (the mp_testset
convention: arrays ``H, c, C, A, b, F, A_theta, b_theta`` and optionally
``Aeq, beq, Feq``; other arrays such as ``kind`` or ``name`` are ignored).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.io.npz import NpzFormat, load_npz, real, save_npz

__all__ = ["MpProgram"]

#: the neutral convention of mp test sets: no format tag (``kind`` and ``name`` arrays)
_PROGRAM_FILE = NpzFormat("program file (.npz)")
_ARRAYS = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta")
_EQ = ("Aeq", "beq", "Feq")


@dataclass(frozen=True)
class MpProgram:
    """A multi-parametric LP (``H`` all zero) or QP (``H`` symmetric positive semi-definite).

    Construction validates every array: real, finite, consistent shapes, ``H`` symmetric and
    PSD. Anything wrong raises ``SpecError`` naming the array.

    Attributes
    ----------
    H : (nz, nz) ndarray
        Symmetric PSD Hessian, zero for an mp-LP.
    c : (nz,) ndarray
    C : (nz, d) ndarray
    A : (m, nz) ndarray
    b : (m,) ndarray
    F : (m, d) ndarray
    A_theta : (p, d) ndarray
    b_theta : (p,) ndarray
        The parameter set ``A_theta theta <= b_theta`` (bounded, non-empty).
    Aeq, beq, Feq : ndarray, optional
        Equalities ``(me, nz)``, ``(me,)``, ``(me, d)``; ``None`` when there are none.
    name : str
        A label for reports (the file stem when loaded).
    """

    H: np.ndarray
    c: np.ndarray
    C: np.ndarray
    A: np.ndarray
    b: np.ndarray
    F: np.ndarray
    A_theta: np.ndarray
    b_theta: np.ndarray
    Aeq: np.ndarray | None = None
    beq: np.ndarray | None = None
    Feq: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        data = {k: getattr(self, k) for k in _ARRAYS + _EQ if getattr(self, k) is not None}
        for key, val in _validated(data).items():
            object.__setattr__(self, key, val)

    @property
    def nz(self) -> int:
        """The number of decision variables."""
        return self.H.shape[0]

    @property
    def d(self) -> int:
        """The number of parameters."""
        return self.A_theta.shape[1]

    @property
    def is_lp(self) -> bool:
        """Whether ``H`` is all zero (an mp-LP)."""
        return not np.any(self.H)

    @property
    def kind(self) -> str:
        """``"mplp"`` or ``"mpqp"``."""
        return "mplp" if self.is_lp else "mpqp"

    # ---- persistence -----------------------------------------------------------------

    @classmethod
    def load(cls, path: str | os.PathLike) -> MpProgram:
        """Read a program from an ``.npz`` in the neutral convention (never unpickles).

        Parameters
        ----------
        path : path-like
            The file; its stem becomes the program's ``name``.

        Returns
        -------
        MpProgram

        Raises
        ------
        SpecError
            Naming the file, the array and the reason.
        """
        name = Path(path).stem

        def build(data: dict) -> MpProgram:
            missing = [k for k in _ARRAYS if k not in data]
            if missing:
                raise SpecError("missing array", field=missing[0])
            return cls(**{k: data[k] for k in _ARRAYS + _EQ if k in data}, name=name)

        return load_npz(path, _PROGRAM_FILE, build)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the program as an ``.npz`` in the same convention, atomically.

        The arrays ``kind`` and ``name`` are written too (and ignored on reading).

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.
        """
        arrays = {k: getattr(self, k) for k in _ARRAYS + _EQ if getattr(self, k) is not None}
        arrays["kind"] = np.array(self.kind)
        arrays["name"] = np.array(self.name)
        return save_npz(path, _PROGRAM_FILE, arrays)


def _validated(data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Check shapes, finiteness and H; returns float copies. Raises ``SpecError``."""
    out: dict[str, np.ndarray] = {}
    for k, v in data.items():
        arr = np.asarray(v)
        if arr.dtype.kind == "b":
            arr = arr.astype(float)
        out[k] = real({k: arr}, k)
    H = out["H"]
    if H.ndim != 2 or H.shape[0] != H.shape[1]:
        raise SpecError(f"must be a square matrix, got shape {H.shape}", field="H")
    nz = H.shape[0]
    if nz == 0:
        raise SpecError("the program has no decision variables", field="H")
    At = out["A_theta"]
    if At.ndim != 2 or At.shape[1] == 0:
        raise SpecError(
            f"must be a (p, d) matrix with d >= 1, got shape {At.shape}", field="A_theta"
        )
    d = At.shape[1]
    want = {
        "c": (nz,),
        "C": (nz, d),
        "b_theta": (At.shape[0],),
    }
    A = out["A"]
    if A.ndim != 2 or A.shape[1] != nz:
        raise SpecError(f"must have shape (m, {nz}) (nz = columns of H), got {A.shape}", field="A")
    want["b"] = (A.shape[0],)
    want["F"] = (A.shape[0], d)
    present = [k for k in _EQ if k in out]
    if present and len(present) != 3:
        raise SpecError(
            "equalities need all of Aeq, beq, Feq", field=next(k for k in _EQ if k not in out)
        )
    if present:
        Aeq = out["Aeq"]
        if Aeq.ndim != 2 or Aeq.shape[1] != nz:
            raise SpecError(f"must have shape (me, {nz}), got {Aeq.shape}", field="Aeq")
        want["beq"] = (Aeq.shape[0],)
        want["Feq"] = (Aeq.shape[0], d)
    for k, shape in want.items():
        if out[k].shape != shape:
            # a 1-column matrix given as a vector is a common slip: accept it
            if len(shape) == 2 and shape[1] == 1 and out[k].shape == (shape[0],):
                out[k] = out[k].reshape(shape)
                continue
            raise SpecError(f"must have shape {shape}, got {out[k].shape}", field=k)
    scale = max(1.0, float(np.max(np.abs(H))))
    if np.max(np.abs(H - H.T)) > 1e-9 * scale:
        raise SpecError("must be symmetric", field="H")
    H = 0.5 * (H + H.T)
    out["H"] = H
    if np.any(H):
        lam_min = float(np.min(np.linalg.eigvalsh(H)))
        if lam_min < -1e-9 * scale:
            raise SpecError(
                f"must be positive semi-definite (smallest eigenvalue {lam_min:.3g}): "
                "the program is not convex",
                field="H",
            )
    return out
