"""Does a solution cover the feasible parameter set? A check after every solve.

The union of the critical regions must be the feasible parameter set: a law with a hole is
wrong where the hole is, and a solve that finds no region at all for a program that is
feasible somewhere (issue 37: an inf-norm MPC with ``Q = 1e7`` gave 0 regions, exit 0)
is wrong everywhere. Neither algorithm proves it (docs/algorithm.md), so ``mpsolve``
checks it on every solution, with as few LPs as possible:

- the **feasible set's inscribed ball** (Chebyshev ball in theta of the lifted set): an
  empty solution is accepted only when no ball larger than the region tolerance fits;
- **sample points** well inside the feasible set (on segments from the ball's centre
  towards LP vertices in random directions and towards random convex combinations of
  them, at most 95 % of the way: each keeps a ball of at least 5 % of the centre's radius
  inside the set, by convexity) must each lie in a region. A point no region holds is
  confirmed feasible by HiGHS before it is called a hole, so that a wrong vertex of the
  fast LP can never refuse a correct law.

The feasibility LPs leave out the rows that the cost's slacks always satisfy
(:func:`constraining_rows`): they are the rows whose size follows the weights (an LP
norm's ``M (G u + ...) - t <= 0``), the ones that made the lifted LP badly scaled.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.geometry.polytope import solve_lp

__all__ = ["check_coverage", "constraining_rows", "feasible_ball", "feasibility_rows"]

#: LP vertices per solution (each one LP of the lifted set, DAQP); the points checked
#: are on the segments to them and among their convex combinations (9 per vertex)
SAMPLES = 8

#: sample points lie at most this fraction of the way from the centre to a vertex
_REACH = 0.95

#: points per vertex that are convex combinations of the vertices (no LP each)
_COMBINATIONS = 8


def constraining_rows(G: np.ndarray) -> np.ndarray:
    """The rows of ``G w <= ...`` that can restrict the parameter.

    A variable whose column is ``<= 0`` in every row it enters (an LP norm's slack ``t``
    in ``+-M(...) - t <= 0``, a soft constraint's slack) can grow without bound and satisfy
    all of them, whatever the other variables and the parameter are; the same for a
    column ``>= 0`` and a variable that falls. Such rows and columns are dropped, and again
    on what is left, until none is.

    Parameters
    ----------
    G : (m, nw) ndarray
        The rows' variable part (no variable in an equality: ``reduce_program`` has
        eliminated them).

    Returns
    -------
    (m,) ndarray of bool
        True for the rows kept.
    """
    m, nw = G.shape
    rows = np.ones(m, dtype=bool)
    cols = np.ones(nw, dtype=bool)
    while True:
        sub = G[rows][:, cols]
        used = np.any(sub != 0.0, axis=0)
        one_signed = used & (np.all(sub <= 0.0, axis=0) | np.all(sub >= 0.0, axis=0))
        if not one_signed.any():
            return rows
        drop = np.flatnonzero(cols)[one_signed]
        rows &= ~np.any(G[:, drop] != 0.0, axis=1)
        cols[drop] = False


def feasibility_rows(
    G: np.ndarray, S: np.ndarray, w: np.ndarray, At: np.ndarray, bt: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """The lifted feasible set ``{(w, theta): G w - S theta <= w0, At theta <= bt}``
    without the rows the slacks satisfy (:func:`constraining_rows`), rows normalised.

    Parameters
    ----------
    G, S, w : (m, nw), (m, d), (m,) ndarrays
        The program's rows ``G w <= w0 + S theta``.
    At, bt : (p, d), (p,) ndarrays
        The parameter set.

    Returns
    -------
    A : (k, nw' + d) ndarray
        Over the variables left (``nw'``) and theta (last ``d`` columns).
    b : (k,) ndarray
    nw : int
        The number of variables left.
    """
    keep = constraining_rows(G)
    cols = np.any(G[keep] != 0.0, axis=0)
    Gk = G[keep][:, cols]
    A = np.block([[Gk, -S[keep]], [np.zeros((At.shape[0], Gk.shape[1])), At]])
    b = np.concatenate([w[keep], bt])
    norms = np.linalg.norm(A, axis=1)
    live = norms > 0.0
    if np.any(b[~live] < 0.0):
        # a row 0 <= b < 0: empty (an impossible row of the program itself)
        A = np.vstack([A[live], np.zeros((1, A.shape[1]))])
        b = np.concatenate([b[live] / norms[live], [-1.0]])
        return A, b, Gk.shape[1]
    return A[live] / norms[live, None], b[live] / norms[live], Gk.shape[1]


def feasible_ball(
    A: np.ndarray, b: np.ndarray, nw: int, cap: float, *, robust: bool = False
) -> tuple[np.ndarray, float] | None:
    """The largest ball of parameters (any variables) in the lifted set ``A (w, theta)
    <= b``, its radius capped at ``cap``.

    Parameters
    ----------
    A, b : ndarray
        From :func:`feasibility_rows`.
    nw : int
        The number of variables before theta's columns.
    cap : float
        The largest radius sought (the parameter set's size).
    robust : bool
        HiGHS instead of DAQP (DAQP's LP mode answered "optimal" with a radius of 1e-12
        on a badly scaled lifted set that held a ball of radius 7).

    Returns
    -------
    (centre, radius) or None
        None when the set is empty.
    """
    d = A.shape[1] - nw
    norms = np.linalg.norm(A[:, nw:], axis=1)
    f = np.zeros(nw + d + 1)
    f[-1] = -1.0
    Ab = np.hstack([A, norms[:, None]])
    if not robust:
        ub = np.full(nw + d + 1, np.inf)
        ub[-1] = cap
        x, st, _ = solve_lp(f, Ab, b, ub=ub)
        if st != "optimal" or x is None:
            return None
        return x[nw:nw + d], float(x[-1])
    from scipy.optimize import linprog

    bounds = [(None, None)] * (nw + d) + [(None, cap)]
    res = linprog(f, A_ub=Ab, b_ub=b, bounds=bounds, method="highs",
                  options={"primal_feasibility_tolerance": 1e-10,
                           "dual_feasibility_tolerance": 1e-10})
    if res.status != 0:
        return None
    return np.asarray(res.x[nw:nw + d]), float(res.x[-1])


def check_coverage(
    rows: tuple[np.ndarray, np.ndarray, int],
    locate: Callable[[np.ndarray], np.ndarray],
    num_regions: int,
    *,
    scale: float,
    region_tol: float,
    kind: str,
    seed: int = 0,
    samples: int = SAMPLES,
) -> dict:
    """Raise ``SolverError`` unless the regions cover the feasible parameter set (at the
    sample points of the module docstring).

    Parameters
    ----------
    rows : tuple
        ``(A, b, nw)`` of :func:`feasibility_rows`.
    locate : callable
        ``(P, d) -> (P,)`` region indices, -1 outside every region.
    num_regions : int
        How many regions the solution has.
    scale : float
        The parameter set's size (radii are capped at it).
    region_tol : float
        The radius below which a set is lower-dimensional (absolute).
    kind : str
        ``"mp-LP"`` or ``"mp-QP"``, for the message.
    seed : int
        Of the sample directions.
    samples : int
        How many points beside the centre.

    Returns
    -------
    dict
        ``coverage_points``: the points checked; ``feasible_radius``: the ball's radius.

    Raises
    ------
    SolverError
        One line: where the feasible parameter lies that no region holds.
    """
    A, b, nw = rows
    ball = feasible_ball(A, b, nw, scale)
    if ball is None or ball[1] <= 1e3 * region_tol:
        # thin or empty by DAQP's LP: HiGHS decides (DAQP can be wrong on bad scaling)
        ball = feasible_ball(A, b, nw, scale, robust=True)
    if ball is None or ball[1] <= 1e3 * region_tol:
        return {"coverage_points": 0, "feasible_radius": 0.0 if ball is None else ball[1]}
    centre, radius = ball
    if num_regions == 0:
        raise _hole(kind, centre, radius, none=True)
    d = A.shape[1] - nw
    rng = np.random.default_rng(seed)
    vertices = []
    for _ in range(samples):
        u = rng.normal(size=d)
        f = np.concatenate([np.zeros(nw), -u / np.linalg.norm(u)])
        x, st, _ = solve_lp(f, A, b)
        if st == "optimal" and x is not None:
            vertices.append(x[nw:])
    points = [centre[None, :]]
    if vertices:
        V = np.array(vertices)
        # convex combinations of the centre (weight >= 1 - _REACH) and the vertices: inside
        # the set with a ball of radius >= (1 - _REACH) * radius, and no LP each
        lam = rng.dirichlet(np.ones(V.shape[0]), size=_COMBINATIONS * V.shape[0])
        t = rng.uniform(0.05, _REACH, size=(lam.shape[0], 1))
        points.append(centre + t * (lam @ V - centre))
        t = rng.uniform(0.05, _REACH, size=(V.shape[0], 1))
        points.append(centre + t * (V - centre))
    P = np.vstack(points)
    where = locate(P)
    for p in P[where < 0]:
        margin = _margin(A, b, nw, p, scale)
        if margin > 1e3 * region_tol:
            raise _hole(kind, p, margin, none=False)
    return {"coverage_points": int(P.shape[0]), "feasible_radius": float(radius)}


def _margin(A: np.ndarray, b: np.ndarray, nw: int, theta: np.ndarray, cap: float) -> float:
    """How far inside the feasible set ``theta`` is (HiGHS): the largest ``s`` with a
    ``w`` such that every row holds with slack ``s`` times the row's theta-norm; -inf
    when no such ``w`` (outside)."""
    from scipy.optimize import linprog

    norms = np.linalg.norm(A[:, nw:], axis=1)
    f = np.zeros(nw + 1)
    f[-1] = -1.0
    Ab = np.hstack([A[:, :nw], norms[:, None]])
    res = linprog(f, A_ub=Ab, b_ub=b - A[:, nw:] @ theta,
                  bounds=[(None, None)] * nw + [(None, cap)], method="highs")
    return float(res.x[-1]) if res.status == 0 else -np.inf


def _hole(kind: str, theta: np.ndarray, radius: float, *, none: bool) -> SolverError:
    where = np.array2string(np.asarray(theta, dtype=float), precision=4)
    what = (
        "found no critical region, but the program is feasible"
        if none
        else "left a hole: no critical region holds the feasible parameter"
    )
    return SolverError(
        f"the {kind} search {what} near theta={where} (a ball of radius {radius:.2g} "
        "there is feasible): the program is too badly scaled for double precision; "
        "bring its weights and bounds closer in magnitude, or shorten mpc.horizon"
    )
