"""The general multi-parametric program (mp-LP / mp-QP) in the neutral convention.

::

    minimize_z   0.5 z'Hz + (c + C theta)'z
    subject to   A z   <= b   + F theta
                 Aeq z  = beq + Feq theta
                 A_theta theta <= b_theta

The MPC front door (``mpc.py``) builds one of these; ``mpsolve`` solves it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MpProgram"]


@dataclass(frozen=True)
class MpProgram:
    """A multi-parametric LP (``H`` all zero) or QP.

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
        The parameter set ``A_theta theta <= b_theta`` (bounded).
    Aeq, beq, Feq : ndarray, optional
        Equalities ``(me, nz)``, ``(me,)``, ``(me, d)``; ``None`` when there are none.
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

    @property
    def nz(self) -> int:
        return self.H.shape[0]

    @property
    def d(self) -> int:
        return self.A_theta.shape[1]

    @property
    def is_lp(self) -> bool:
        return not np.any(self.H)
