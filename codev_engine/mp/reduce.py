"""The reduced program that both mp algorithms solve, and what they measure it by.

``mpsolve`` (``solve.py``) reduces the program once and hands it to the mp-QP search
(``mpqp.py``) or the mp-LP explorer (``mplp.py``); the front door also needs it for the
domain and to map the laws back. Here and not in ``solve.py``, because the explorer uses it
too and ``solve.py`` imports the explorer:

- **the reduction**: equalities eliminated, pure-parameter rows moved to the parameter set,
  rows normalised and de-duplicated (:func:`reduce_program`);
- **the lifted feasible set** ``{(w, theta)}`` (:func:`lifted`);
- **the parameter set's size**, which every length of the solver is relative to
  (:func:`parameter_box`), and a start point well inside the feasible set
  (:func:`start_point`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.geometry.polytope import bounding_box, normalize_rows, solve_lp
from codev_engine.mp.coverage import feasibility_rows, feasible_ball
from codev_engine.mp.program import MpProgram

__all__ = [
    "BALANCE_RATIO", "ParameterBox", "Reduced", "lifted", "parameter_box", "parameter_scaling",
    "reduce_program", "start_point",
]


@dataclass(frozen=True)
class Reduced:
    """The program after equality elimination and row clean-up::

        min_w  0.5 w'H w + (c + C theta)'w   s.t.  G w <= w0 + S theta,  At theta <= bt

    (the offset ``w0`` is the field ``w``). ``z = Z0 + Z1 theta + Nz w`` maps the reduced
    variables ``w`` back.

    Attributes
    ----------
    H : (nw, nw) ndarray
        Symmetric; zero for an mp-LP.
    c, C : (nw,), (nw, d) ndarrays
    G, w, S : (m, nw), (m,), (m, d) ndarrays
        Unit rows ``G``, none of them zero, none repeated.
    At, bt : (p, d), (p,) ndarrays
        The parameter set, normalised.
    Z0, Z1, Nz : (nz,), (nz, d), (nz, nw) ndarrays
    """

    H: np.ndarray
    c: np.ndarray
    C: np.ndarray
    G: np.ndarray
    w: np.ndarray
    S: np.ndarray
    At: np.ndarray
    bt: np.ndarray
    Z0: np.ndarray
    Z1: np.ndarray
    Nz: np.ndarray


def reduce_program(p: MpProgram) -> Reduced:
    """Eliminate the equalities (``z = Z0 + Z1 theta + Nz w``, ``Nz`` a basis of the null
    space of ``Aeq``), move the rows without variables to the parameter set, normalise the
    rows and drop repeated ones (they would break LICQ everywhere).

    Parameters
    ----------
    p : MpProgram

    Returns
    -------
    Reduced

    Raises
    ------
    SpecError
        When the equalities are inconsistent for some parameters or the parameter set is
        empty.
    """
    nz, d = p.nz, p.d
    H, c, C, G, w, S = p.H, p.c, p.C, p.A, p.b, p.F
    Z0 = np.zeros(nz)
    Z1 = np.zeros((nz, d))
    Nz = np.eye(nz)
    if p.Aeq is not None and p.Aeq.shape[0]:
        Aeq, beq, Feq = p.Aeq, p.beq, p.Feq
        U, s, Vt = np.linalg.svd(Aeq)
        rank = int(np.sum(s > 1e-10 * max(1.0, s[0] if s.size else 1.0)))
        pinv = np.linalg.pinv(Aeq, rcond=1e-10)
        # equalities must be consistent for every theta: the rows outside the range of Aeq
        resid = np.hstack([beq[:, None], Feq]) - Aeq @ pinv @ np.hstack([beq[:, None], Feq])
        if np.max(np.abs(resid), initial=0.0) > 1e-8 * max(1.0, np.max(np.abs(Feq), initial=1)):
            raise SpecError(
                "equality constraints are inconsistent for some parameters", field="Aeq"
            )
        Z0 = pinv @ beq
        Z1 = pinv @ Feq
        Nz = Vt[rank:].T
        H, c, C = Nz.T @ H @ Nz, Nz.T @ (H @ Z0 + c), Nz.T @ (H @ Z1 + C)
        w = w - G @ Z0
        S = S - G @ Z1
        G = G @ Nz
    # the optimizer does not change when the cost is multiplied by a positive number: make
    # its largest coefficient 1, so that the engines' tolerances on costs, duals and
    # multipliers see the same numbers for weights Q, R, P and the same weights times 1e8
    # (an absolute floor of 1 on the cost's size had let the LP's perturbation swamp a cost
    # of 1e-8, issue 37)
    # (an mp-QP only when its cost is far from that size: the classifications of sliver
    # candidates that tests pin moved when every H was divided)
    cost_scale = max(np.max(np.abs(H), initial=0.0), np.max(np.abs(c), initial=0.0),
                     np.max(np.abs(C), initial=0.0))
    qp_far = not 1e-6 <= cost_scale <= 1e6
    if (qp_far or not np.any(H)) and np.isfinite(cost_scale) and cost_scale > 0.0:
        H, c, C = H / cost_scale, c / cost_scale, C / cost_scale
    # pure parameter rows belong to the parameter set
    gnorm = np.linalg.norm(G, axis=1)
    pure = gnorm <= 1e-12 * max(1.0, np.max(gnorm, initial=1.0))
    At = np.vstack([p.A_theta, -S[pure]])
    bt = np.concatenate([p.b_theta, w[pure]])
    G, w, S = G[~pure], w[~pure], S[~pure]
    scale = np.linalg.norm(G, axis=1)
    G, w, S = G / scale[:, None], w / scale, S / scale[:, None]
    # identical rows are one constraint (they would break LICQ everywhere)
    if G.shape[0]:
        key = np.round(np.hstack([G, w[:, None], S]), 11)
        _, first = np.unique(key, axis=0, return_index=True)
        first = np.sort(first)
        G, w, S = G[first], w[first], S[first]
    At, bt, ok = normalize_rows(At, bt)
    if not ok:
        raise SpecError("the parameter set is empty", field="A_theta")
    return Reduced(H=0.5 * (H + H.T), c=c, C=C, G=G, w=w, S=S, At=At, bt=bt, Z0=Z0, Z1=Z1, Nz=Nz)


def lifted(red: Reduced) -> tuple[np.ndarray, np.ndarray]:
    """The feasible set lifted to (w, theta): rows ``G w - S theta <= w`` and ``At theta
    <= bt``.

    Parameters
    ----------
    red : Reduced

    Returns
    -------
    A : (m + p, nw + d) ndarray
    b : (m + p,) ndarray
    """
    zero = np.zeros((red.At.shape[0], red.G.shape[1]))
    return np.block([[red.G, -red.S], [zero, red.At]]), np.concatenate([red.w, red.bt])


@dataclass(frozen=True)
class ParameterBox:
    """The parameter set's bounding box and size.

    Attributes
    ----------
    lo, hi : (d,) ndarrays
        The box.
    scale : float
        Its largest width (at least 1e-12): the solver's lengths are relative to it.
    bound : float
        The largest ``|theta|_inf`` in the box: where certificates charge residuals.
    """

    lo: np.ndarray
    hi: np.ndarray
    scale: float
    bound: float

    @property
    def box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo, hi)``."""
        return self.lo, self.hi


#: an axis of the parameter box narrower than the widest by more than this factor is
#: rescaled (a power of two, to the widest's width)
BALANCE_RATIO = 64.0


def parameter_scaling(lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """The diagonal ``D`` (``theta = D theta_s``) that balances the box ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : (d,) ndarrays
        The parameter set's bounding box (finite).

    Returns
    -------
    (d,) ndarray or None
        Powers of two, at most 1 (the widest axis keeps its units); None when every axis
        is within ``BALANCE_RATIO`` of the widest (nothing to do).
    """
    width = np.asarray(hi, float) - np.asarray(lo, float)
    top = float(np.max(width, initial=0.0))
    if not np.isfinite(top) or top <= 0.0:
        return None
    # (a point-like axis, width 0, is left alone: there is no scale to match)
    narrow = (width > 0.0) & (width * BALANCE_RATIO < top)
    if not np.any(narrow):
        return None
    D = np.ones_like(width)
    D[narrow] = np.exp2(np.round(np.log2(width[narrow] / top)))
    return D


def _axis_units(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Powers of two ``W`` (``theta = W theta_w``) that bring the widths of ``A theta <=
    b`` along each axis, as its rows on that axis alone bound them, within
    ``BALANCE_RATIO`` of the widest (:func:`parameter_scaling` of those widths); ones when
    they are already, or when an axis has no such rows.

    Parameters
    ----------
    A : (p, d) ndarray
    b : (p,) ndarray

    Returns
    -------
    (d,) ndarray
    """
    d = A.shape[1]
    lo, hi = np.full(d, -np.inf), np.full(d, np.inf)
    for i in np.flatnonzero(np.count_nonzero(A, axis=1) == 1):
        j = int(np.flatnonzero(A[i])[0])
        if A[i, j] > 0.0:
            hi[j] = min(hi[j], b[i] / A[i, j])
        else:
            lo[j] = max(lo[j], b[i] / A[i, j])
    width = hi - lo
    if not np.all(np.isfinite(width)) or np.any(width <= 0.0):
        return np.ones(d)
    W = parameter_scaling(lo, hi)
    return np.ones(d) if W is None else W


def parameter_box(red: Reduced) -> ParameterBox:
    """The bounding box of the parameter set ``At theta <= bt``.

    Parameters
    ----------
    red : Reduced

    Returns
    -------
    ParameterBox

    Raises
    ------
    SpecError
        When the parameter set is empty or unbounded.
    """
    d = red.At.shape[1]
    # the LPs in units where the axes' widths (read off the rows on one axis) are within
    # BALANCE_RATIO: in the plant's own (x1 in 1e3, x2 in 1e-3 units, and an output bound
    # x1 1e-6 + x2 <= 2e-3) DAQP called the set infeasible when asked for max x1, and the
    # spec was refused, "the parameter set is unbounded" (issue 38)
    W = _axis_units(red.At, red.bt)
    At, bt = (red.At, red.bt) if np.all(W == 1.0) else normalize_rows(red.At * W, red.bt)[:2]
    _, st, _ = solve_lp(np.zeros(d), At, bt)
    if st == "infeasible":
        raise SpecError("the parameter set is empty", field="A_theta")
    lo, hi = bounding_box(At, bt)
    lo, hi = lo * W, hi * W
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise SpecError("the parameter set is unbounded", field="A_theta")
    if np.any(hi - lo < 0):
        raise SpecError("the parameter set is empty", field="A_theta")
    return ParameterBox(
        lo=lo,
        hi=hi,
        scale=float(max(np.max(hi - lo), 1e-12)),
        bound=float(max(np.max(np.abs(lo)), np.max(np.abs(hi)))),
    )


def start_point(
    red: Reduced, scale: float, region_tol: float, rng: np.random.Generator
) -> np.ndarray | None:
    """A parameter well inside the feasible set (lifted Chebyshev centre), or None when
    the set is empty or thinner than ``region_tol``.

    The radius is measured in theta only (a ball of theta's, any w) and capped at
    ``scale``; the point is moved off the centre by 0.37 of the radius in a direction
    drawn from ``rng`` (one ``normal(size=d)`` draw), since the centre is often a
    symmetric, degenerate point (the origin).

    Parameters
    ----------
    red : Reduced
    scale : float
        The parameter set's size (the radius's cap).
    region_tol : float
        The smallest radius accepted.
    rng : numpy.random.Generator
        Draws the direction of the offset.

    Returns
    -------
    (d,) ndarray or None
    """
    d, nw = red.At.shape[1], red.H.shape[0]
    A, b = lifted(red)
    # radius measured in theta only: ball of theta's, any w
    norms = np.concatenate([np.linalg.norm(red.S, axis=1), np.linalg.norm(red.At, axis=1)])
    f = np.zeros(nw + d + 1)
    f[-1] = -1.0
    ub = np.full(nw + d + 1, np.inf)
    ub[-1] = scale
    x, st, _ = solve_lp(f, np.hstack([A, norms[:, None]]), b, ub=ub)
    if st == "optimal" and x is not None and x[-1] > region_tol:
        centre, radius = x[nw : nw + d], float(x[-1])
    else:
        # empty or thin by DAQP: HiGHS on the rows that can restrict theta (DAQP answered
        # "optimal" with a radius of 1e-12 for a ball of radius 7, on rows where an LP
        # norm's slack had the coefficient 1e-7: issue 37)
        ball = feasible_ball(*feasibility_rows(red.G, red.S, red.w, red.At, red.bt), scale,
                             robust=True)
        if ball is None or ball[1] <= region_tol:
            return None
        centre, radius = ball
    # the centre is often a symmetric, degenerate point (the origin): start off it
    u = rng.normal(size=d)
    return centre + 0.37 * radius * u / np.linalg.norm(u)
