"""Polytopes in H-representation and the small LPs the engine needs on them.

A polytope is ``{x : A x <= b}`` with ``A`` (k, d) and ``b`` (k,). The LPs here are tiny
(d <= ~10 variables, tens of rows) and are solved thousands of times during synthesis, so
they go to DAQP (a dual active-set solver in C; LPs via its proximal-point mode), which is
one to two orders of magnitude faster than a general LP front end on this size; SciPy's
HiGHS is the fallback whenever DAQP does not report a clean optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import daqp
import numpy as np

from codev_engine.errors import SolverError
from codev_engine.geometry.lp_proof import (
    farkas_proof,
    highs_infeasibility,
    one_sided,
    optimum_proved,
)
from codev_engine.limits import beat

__all__ = [
    "Polytope",
    "solve_lp",
    "chebyshev_ball",
    "minimal_rows",
    "normalize_rows",
    "box_halfspaces",
    "contains",
]

_INF = 1e30
#: cap on the Chebyshev radius LP so that unbounded sets still give a finite answer
_RADIUS_CAP = 1e6


@dataclass(frozen=True)
class Polytope:
    """``{x : A x <= b}``.

    Attributes
    ----------
    A : (k, d) ndarray
    b : (k,) ndarray
    """

    A: np.ndarray
    b: np.ndarray

    @property
    def dim(self) -> int:
        """The dimension ``d`` of the space."""
        return self.A.shape[1]

    def contains(self, X: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Membership of the rows of ``X``: ``A x <= b + tol``.

        Parameters
        ----------
        X : (P, d) or (d,) ndarray
            The points, one a row.
        tol : float
            Absolute slack allowed on every row.

        Returns
        -------
        (P,) ndarray of bool
        """
        return contains(self.A, self.b, X, tol)

    def chebyshev(self) -> tuple[np.ndarray, float]:
        """Centre (d,) and radius of the largest inscribed ball (radius < 0: empty)."""
        return chebyshev_ball(self.A, self.b)


def contains(A: np.ndarray, b: np.ndarray, X: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Which rows ``x`` of ``X`` satisfy ``A x <= b + tol``.

    Parameters
    ----------
    A : (k, d) ndarray
    b : (k,) ndarray
    X : (P, d) or (d,) ndarray
        The points, one a row.
    tol : float
        Absolute slack allowed on every row.

    Returns
    -------
    (P,) ndarray of bool
    """
    X = np.atleast_2d(X)
    return np.all(X @ A.T <= b + tol, axis=1)


def box_halfspaces(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H-representation of the box ``lower <= x <= upper`` (finite sides only).

    Parameters
    ----------
    lower, upper : (d,) ndarray
        The box's sides; an infinite side gives no row.

    Returns
    -------
    A : (k, d) ndarray
        Rows ``e_i`` (upper sides) then ``-e_i`` (lower sides), ``k <= 2 d``.
    b : (k,) ndarray
    """
    d = lower.shape[0]
    eye = np.eye(d)
    A = np.vstack([eye, -eye])
    b = np.concatenate([upper, -lower])
    keep = np.isfinite(b)
    return A[keep], b[keep]


def normalize_rows(
    A: np.ndarray, b: np.ndarray, tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Scale rows to unit norm and drop rows ``0 <= b``.

    Parameters
    ----------
    A : (k, d) ndarray
    b : (k,) ndarray
    tol : float
        A row of norm at most ``tol`` counts as zero (and ``b >= -tol`` as ``0 <= b``).

    Returns
    -------
    A, b : ndarray
        Normalised rows.
    feasible : bool
        False when a zero row reads ``0 <= b`` with ``b < 0`` (the set is empty).
    """
    norms = np.linalg.norm(A, axis=1)
    zero = norms <= tol
    feasible = bool(np.all(b[zero] >= -tol))
    keep = ~zero
    return A[keep] / norms[keep, None], b[keep] / norms[keep], feasible


def solve_lp(
    f: np.ndarray,
    A: np.ndarray,
    b: np.ndarray,
    Aeq: np.ndarray | None = None,
    beq: np.ndarray | None = None,
    lb: np.ndarray | None = None,
    ub: np.ndarray | None = None,
    iter_limit: int = 10000,
    *,
    certify_optimum: bool = True,
) -> tuple[np.ndarray | None, str, np.ndarray | None]:
    """``min f'x  s.t.  A x <= b, Aeq x = beq, lb <= x <= ub``.

    Every answer is proved (``lp_proof``): callers drop a piece of a reach set, skip a
    violation or call a row redundant on "infeasible" or on an optimum's value, so DAQP's
    answer stands only with a certificate checked here (weak duality for an optimum, a
    Farkas certificate for "infeasible"), else HiGHS answers, and its "infeasible" needs the
    certificate too; without one the LP is solved over its rows widened to where they meet
    (a superset). Which callers are unsound on a wrong answer and which only conservative:
    docs/verification.md, "The LPs' answers".

    Parameters
    ----------
    f : (nx,) ndarray
        The cost.
    A : (k, nx) ndarray
    b : (k,) ndarray
    Aeq : (ke, nx) ndarray, optional
    beq : (ke,) ndarray, optional
    lb, ub : (nx,) ndarray, optional
        Bounds of the variables; infinite entries are no bound.
    iter_limit : int
        DAQP's iteration limit (its default); past it HiGHS answers.
    certify_optimum : bool
        False: DAQP's optimum is taken without its proof (an "infeasible" still needs
        one), for a caller whose decision by value is checked later: the mp-LP explorer's
        facet pieces (synthesis' coverage check), where HiGHS's radii (1e-7 off by its
        tolerances, on facets of radius 0) made the explorer run out of pieces.

    Returns
    -------
    x : (nx,) ndarray or None
    status : str
        ``"optimal"``, ``"infeasible"`` or ``"unbounded"``.
    lam : ndarray or None
        Multipliers of the rows of ``A`` (>= 0), then of ``Aeq`` (DAQP's sign convention,
        ``f + A' lam = 0`` at the optimum); None when they come from the fallback.

    Raises
    ------
    SolverError
        Neither DAQP nor HiGHS answers (even on the widened rows).
    """
    beat("LPs")  # (a verification's heartbeat: loops of many LPs report progress)
    nx = f.shape[0]
    k = b.shape[0]
    ke = Aeq.shape[0] if Aeq is not None else 0
    bounded = lb is not None or ub is not None
    n = k + ke + (nx if bounded else 0)
    # DAQP's rows: those of A, of Aeq (sense 5: equalities), then the bounds, written in
    # place (these LPs are small and many: their set-up costs as much as the solve)
    M = np.empty((n, nx))
    M[:k] = A
    upper = np.empty(n)
    upper[:k] = b
    lower = np.full(n, -_INF)
    sense = np.zeros(n, dtype=np.int32)
    if ke:
        M[k : k + ke] = Aeq
        upper[k : k + ke] = beq
        lower[k : k + ke] = beq
        sense[k : k + ke] = 5
    if bounded:
        M[k + ke :] = np.eye(nx)
        upper[k + ke :] = _INF if ub is None else np.where(np.isfinite(ub), ub, _INF)
        if lb is not None:
            lower[k + ke :] = np.where(np.isfinite(lb), lb, -_INF)
    f = np.ascontiguousarray(f, dtype=float)
    x, flag, lam = _daqp(f, M, upper, lower, sense, iter_limit)
    # DAQP's answer stands only with a proof checked here (``lp_proof``): a wrong
    # "infeasible" or a maximum stopped short would drop states (see the docstring)
    if flag == 1:
        if not certify_optimum or optimum_proved(f, M, upper, lower, x, lam):
            return x, "optimal", lam
        # DAQP's proximal iterations can stop one step early, their multipliers off by
        # eps_prox (x - x_prev) (5e-8 on the headbox's thin pieces' Chebyshev LPs): once
        # more from x, which proves those in one iteration, before HiGHS (~100x slower)
        x, flag, lam = _daqp(f, M, upper, lower, sense, iter_limit, start=x)
        if flag == 1 and optimum_proved(f, M, upper, lower, x, lam):
            return x, "optimal", lam
    elif flag == -1 and farkas_proof(M, upper, lower, sense == 5, _box(lb, ub)):
        return None, "infeasible", None
    # anything else (no proof, cycling, iteration limit, unbounded claims): ask HiGHS
    bounds = [(None, None)] * nx
    if lb is not None or ub is not None:
        lo = np.full(nx, -np.inf) if lb is None else lb
        hi = np.full(nx, np.inf) if ub is None else ub
        bounds = [
            (None if not np.isfinite(lo_i) else lo_i, None if not np.isfinite(hi_i) else hi_i)
            for lo_i, hi_i in zip(lo, hi, strict=True)
        ]
    from scipy.optimize import linprog  # (~0.4 s of imports: only when daqp cannot decide)

    res = linprog(
        f,
        A_ub=A if A.shape[0] else None,
        b_ub=b if A.shape[0] else None,
        A_eq=Aeq if Aeq is not None and Aeq.shape[0] else None,
        b_eq=beq if Aeq is not None and Aeq.shape[0] else None,
        bounds=bounds,
        method="highs",
    )
    if res.status not in (0, 3):
        # HiGHS's "infeasible" (or its failure) needs a proof too; without one the LP is
        # answered on its rows widened by the distance at which they meet (a superset of
        # the set: every caller's use of an optimum, a maximum or a point in it, is then
        # conservative), without presolve, whose reductions made the wrong calls found
        # so far (tests/engine/test_lp_proof.py)
        G, h, E, e = one_sided(M, upper, lower, sense == 5)
        widen = highs_infeasibility(G, h, E, e, _box(lb, ub))
        if widen is None:
            return None, "infeasible", None
        if np.isfinite(widen):
            # (and 1e-9 of each offset past it: HiGHS's distance has its tolerance)
            h = h + widen * np.maximum(np.linalg.norm(G, axis=1), 1.0) + 1e-9 * (1 + abs(h))
            res = linprog(f, A_ub=G, b_ub=h, A_eq=E if E.shape[0] else None,
                          b_eq=e if E.shape[0] else None, bounds=[(None, None)] * nx,
                          method="highs", options={"presolve": False})
    if res.status == 0:
        return np.asarray(res.x), "optimal", None
    if res.status == 3:
        return None, "unbounded", None
    # (an iteration limit or numerical trouble: no answer is sound for every caller, and
    # "infeasible" would drop whatever the LP was asked about)
    raise SolverError(f"an LP failed in both DAQP (flag {flag}) and HiGHS: {res.message}")


def _daqp(
    f: np.ndarray,
    M: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    sense: np.ndarray,
    iter_limit: int,
    start: np.ndarray | None = None,
) -> tuple[np.ndarray, int, np.ndarray]:
    """DAQP's LP (proximal mode): ``(x (nx,), flag, lam (n,))``, optionally from ``start``."""
    x, _, flag, info = daqp.solve(
        np.zeros((f.shape[0], f.shape[0])),
        f,
        M,
        upper,
        lower,
        sense,
        eps_prox=1e-2,
        # DAQP's default primal tolerance (1e-6) is far too loose for geometry: a facet
        # centre 3e-7 off its hyperplane made the exploration cycle
        primal_tol=1e-11,
        dual_tol=1e-12,
        iter_limit=iter_limit,
        primal_start=start,
    )
    return np.asarray(x, dtype=float), flag, np.asarray(info["lam"], dtype=float)


def _box(lb: np.ndarray | None, ub: np.ndarray | None) -> float | None:
    """A bound on ``|x|_inf`` from the variables' bounds (None unless all are finite)."""
    if lb is None or ub is None or not (np.all(np.isfinite(lb)) and np.all(np.isfinite(ub))):
        return None
    return float(max(np.abs(lb).max(initial=0.0), np.abs(ub).max(initial=0.0)))


def chebyshev_ball(
    A: np.ndarray,
    b: np.ndarray,
    Aeq: np.ndarray | None = None,
    beq: np.ndarray | None = None,
    *,
    solver: str = "daqp",
    multipliers: bool = False,
    tol: float | None = None,
    certify_optimum: bool = True,
) -> tuple[np.ndarray, float] | tuple[np.ndarray, float, np.ndarray | None]:
    """Largest ball inside ``{A x <= b}`` (within the affine set ``Aeq x = beq``).

    With equalities the radius is measured inside the affine set: each row's norm is the
    norm of its component orthogonal to the equality rows.

    Parameters
    ----------
    A : (k, d) ndarray
    b : (k,) ndarray
    Aeq : (ke, d) ndarray, optional
    beq : (ke,) ndarray, optional
    solver : {"daqp", "highs"}
        DAQP (fast; its proximal LP can be off by ~1e-5 on badly scaled rows) or HiGHS.
    multipliers : bool
        Also return the LP's multipliers.
    tol : float, optional
        With HiGHS: its primal and dual feasibility tolerances (default HiGHS's own, 1e-7,
        which leaves a ball of radius 1e-8 unproved: ``mpqp._Kernel._chebyshev``).
    certify_optimum : bool
        With DAQP: as in :func:`solve_lp`.

    Returns
    -------
    centre : (d,) ndarray
    radius : float
        Negative when the set is empty; capped at 1e6 for unbounded sets.
    y : (k + 1,) ndarray or None
        With ``multipliers``: the multipliers (>= 0) of the rows and of the radius cap
        (last), or None when the solver gives none (see :func:`radius_upper_bound`).
    """
    d = A.shape[1]
    if Aeq is not None and Aeq.shape[0]:
        Qe, _ = np.linalg.qr(Aeq.T)
        proj = A - (A @ Qe) @ Qe.T
        norms = np.linalg.norm(proj, axis=1)
    else:
        norms = np.linalg.norm(A, axis=1)
    # variables (x, r): A x + |a| r <= b, and the cap r <= _RADIUS_CAP as one more row (not
    # as variable bounds, which would add d + 1 rows to every one of these hot-path LPs)
    k = A.shape[0]
    Ab = np.zeros((k + 1, d + 1))
    Ab[:k, :d] = A
    Ab[:k, d] = norms
    Ab[k, d] = 1.0
    bb = np.empty(k + 1)
    bb[:k] = b
    bb[k] = _RADIUS_CAP
    f = np.zeros(d + 1)
    f[-1] = -1.0
    Aeq_b = None if Aeq is None else np.hstack([Aeq, np.zeros((Aeq.shape[0], 1))])
    if solver == "highs":
        x, y = _highs_lp(f, Ab, bb, Aeq_b, beq, tol=tol)
        status = "failed" if x is None else "optimal"
    else:
        x, status, y = solve_lp(f, Ab, bb, Aeq_b, beq, certify_optimum=certify_optimum)
    y = None if y is None else y[: k + 1]  # (the rows and the cap, not the equalities)
    if status != "optimal" or x is None:
        out = np.full(d, np.nan), -np.inf
    else:
        out = x[:d], float(x[d])
    return (*out, y) if multipliers else out


def _highs_lp(
    f: np.ndarray, A: np.ndarray, b: np.ndarray, Aeq: np.ndarray | None = None,
    beq: np.ndarray | None = None, *, tol: float | None = None,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``min f'x  s.t.  A x <= b, Aeq x = beq`` by HiGHS through highspy (scipy's
    ``linprog`` costs ~2 ms of checks around a 0.2 ms solve here): (x, y) with the
    multipliers y >= 0 of the rows (``A' y = -f`` on the inequality part), or (None, None).
    ``tol``: HiGHS's primal and dual feasibility tolerances (default its own)."""
    import highspy

    inf = highspy.kHighsInf
    rows = A if Aeq is None or not Aeq.shape[0] else np.vstack([A, Aeq])
    lo = np.concatenate([np.full(A.shape[0], -inf), [] if Aeq is None else beq])
    hi = np.concatenate([b, [] if Aeq is None else beq])
    nr, nx = rows.shape
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    if tol is not None:
        h.setOptionValue("primal_feasibility_tolerance", float(tol))
        h.setOptionValue("dual_feasibility_tolerance", float(tol))
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = nx, nr
    lp.col_cost_ = np.asarray(f, dtype=float)
    lp.col_lower_ = np.full(nx, -inf)
    lp.col_upper_ = np.full(nx, inf)
    lp.row_lower_ = lo.astype(float)
    lp.row_upper_ = hi.astype(float)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.arange(0, nr * nx + 1, nx)
    lp.a_matrix_.index_ = np.tile(np.arange(nx), nr)
    lp.a_matrix_.value_ = np.ascontiguousarray(rows, dtype=float).ravel()
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return None, None
    sol = h.getSolution()
    return np.array(sol.col_value), -np.array(sol.row_dual)[: A.shape[0]]


def _highs_box_lps(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The bounding box ``(lo, hi)`` of ``{A x <= b}`` by the 2d LPs ``min / max x_j``, in
    one HiGHS model whose cost alone changes between them (each LP starts from the last
    one's basis: the same optima as :func:`_highs_lp` one by one, without building a model
    per LP); None when one has no optimum."""
    import highspy

    inf = highspy.kHighsInf
    nr, nx = A.shape
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = nx, nr
    lp.col_cost_ = np.zeros(nx)
    lp.col_lower_ = np.full(nx, -inf)
    lp.col_upper_ = np.full(nx, inf)
    lp.row_lower_ = np.full(nr, -inf)
    lp.row_upper_ = np.asarray(b, dtype=float)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
    lp.a_matrix_.start_ = np.arange(0, nr * nx + 1, nx)
    lp.a_matrix_.index_ = np.tile(np.arange(nx), nr)
    lp.a_matrix_.value_ = np.ascontiguousarray(A, dtype=float).ravel()
    h.passModel(lp)
    lo, hi = np.empty(nx), np.empty(nx)
    cols = np.arange(nx, dtype=np.int32)
    for j in range(nx):
        for sign, side in ((1.0, lo), (-1.0, hi)):
            cost = np.zeros(nx)
            cost[j] = sign
            h.changeColsCost(nx, cols, cost)
            h.run()
            if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
                return None
            side[j] = h.getSolution().col_value[j]
    return lo, hi


def radius_upper_bound(A: np.ndarray, b: np.ndarray, y: np.ndarray, bound: float) -> float:
    """An upper bound of the radius of every ball inside ``{A x <= b}`` (unit rows, among
    them rows that keep the set within ``|x|_inf <= bound``), from any multipliers ``y``
    (k + 1,) of :func:`chebyshev_ball`'s LP, however inaccurate: weak duality.

    For (x, r) feasible and ``y >= 0`` (negative entries clipped), ``(A' y) x + s r <= b' y
    + cap y_cap`` with ``s = sum(y)``, so ``r <= b' y + cap y_cap + |A' y|_1 |x|_inf +
    |1 - s| |r|``. A ball of radius r >= -1 has its centre within bound + 1 of the origin
    (the bounding rows are among A), charged as 2 bound + 1; |r| is charged at the cap.
    """
    y = np.maximum(np.asarray(y, dtype=float), 0.0)
    yr, yc = y[:-1], y[-1]
    val = float(b @ yr) + _RADIUS_CAP * yc
    resid = float(np.abs(A.T @ yr).sum())
    return val + resid * (2.0 * bound + 1.0) + abs(1.0 - float(yr.sum()) - yc) * _RADIUS_CAP


def bounding_box(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box ``(lo, hi)`` of ``{x : A x <= b}`` by 2d LPs; a side whose LP has no
    optimum (unbounded or failed) is -inf / +inf."""
    d = A.shape[1]
    lo, hi = np.full(d, -np.inf), np.full(d, np.inf)
    for i in range(d):
        e = np.zeros(d)
        e[i] = 1.0
        x, st, _ = solve_lp(e, A, b)
        if st == "optimal" and x is not None:
            lo[i] = x[i]
        x, st, _ = solve_lp(-e, A, b)
        if st == "optimal" and x is not None:
            hi[i] = x[i]
    return lo, hi


def row_keys(M: np.ndarray, decimals: int) -> np.ndarray:
    """One hashable, comparable key per row of ``M`` rounded to ``decimals`` -> (r,) void.

    ``np.unique(M, axis=0)`` sorts structured records and was a tenth of the mp-QP
    explorer's time; a byte view of each rounded row (with -0.0 made +0.0) compares the
    same and sorts as one 1-D array.
    """
    R = np.ascontiguousarray(np.round(M, decimals) + 0.0)
    return R.view(np.dtype((np.void, R.dtype.itemsize * R.shape[1]))).ravel()


def _rounded(M: np.ndarray, decimals: int) -> np.ndarray:
    return np.ascontiguousarray(np.round(M, decimals) + 0.0)  # (-0.0 made +0.0)


def row_hashes(R: np.ndarray) -> np.ndarray:
    """A 64-bit hash of each row's bytes (R float64, C-contiguous) -> (r,) uint64."""
    V = R.view(np.uint64)
    h = np.full(R.shape[0], 0x9E3779B97F4A7C15, dtype=np.uint64)
    for j in range(R.shape[1]):  # a splitmix step per column (uint64 arithmetic wraps)
        h ^= V[:, j]
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(31)
    return h


def unique_rows(M: np.ndarray, decimals: int) -> np.ndarray:
    """Indices of the first occurrence of each distinct rounded row, ascending.

    Rows are grouped by a hash (sorting 64-bit integers, not the rows' bytes: ~10x faster
    on the million rows of a large partition), then rows of one hash are compared; should
    two different rows share a hash, the exact byte sort decides instead.
    """
    R = _rounded(M, decimals)
    h = row_hashes(R)
    order = np.argsort(h, kind="stable")
    hs = h[order]
    same_h = hs[1:] == hs[:-1]
    i = np.flatnonzero(same_h)  # rows equal to the one before them, if the hash tells true
    if np.any(R[order[i]] != R[order[i + 1]]):  # a collision (or NaN)
        _, first = np.unique(row_keys(M, decimals), return_index=True)
        return np.sort(first)
    return np.sort(order[np.concatenate([[True], ~same_h])])


def rows_in(Q: np.ndarray, M: np.ndarray, decimals: int) -> np.ndarray:
    """Whether each row of ``Q``, rounded to ``decimals``, is a row of ``M`` rounded -> (q,)
    bool. Hashes first, every hit confirmed row by row (a collision falls back to the
    exact byte comparison)."""
    if M.shape[0] == 0:
        return np.zeros(Q.shape[0], dtype=bool)
    RQ, RM = _rounded(Q, decimals), _rounded(M, decimals)
    hq, hm = row_hashes(RQ), row_hashes(RM)
    order = np.argsort(hm, kind="stable")
    hm = hm[order]
    pos = np.minimum(np.searchsorted(hm, hq), hm.size - 1)
    hit = hm[pos] == hq
    same = np.all(RM[order[pos[hit]]] == RQ[hit], axis=1)
    if not np.all(same):  # a collision: the hash's first row is another row
        return np.isin(row_keys(Q, decimals), row_keys(M, decimals))
    return hit


def minimal_rows(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Indices of the non-redundant rows of a full-dimensional polytope ``A x <= b``.

    Rows are expected normalised (``normalize_rows``). Exact duplicates are removed first
    (keeping the first), then DAQP's minimal-representation routine removes the rest.

    Parameters
    ----------
    A : (k, d) ndarray
        Unit rows.
    b : (k,) ndarray

    Returns
    -------
    (r,) ndarray of int
    """
    if A.shape[0] == 0:
        return np.zeros(0, dtype=int)
    first = unique_rows(np.hstack([A, b[:, None]]), 10)
    # a row parallel to another with a larger offset is redundant too; minrep handles it
    Au = np.ascontiguousarray(A[first])
    bu = np.ascontiguousarray(b[first])
    redundant = np.asarray(daqp.minrep(Au, bu), dtype=bool)
    return first[~redundant]


def checked_minimal_rows(
    A: np.ndarray, b: np.ndarray, centre: np.ndarray, radius: float
) -> np.ndarray:
    """:func:`minimal_rows`, checked against the set's largest inscribed ball.

    DAQP's minrep decides redundancy at its own tolerance and was seen dropping rows 1e-5
    (normalised) from redundant: a sliver region of pop_mpqp_084 (inscribed radius 4e-6)
    then stretched over its neighbours with a law of gain ~1e8. The kept rows' inscribed
    ball must be the full set's (``centre``, ``radius``) and poke through no dropped row;
    otherwise redundancy is decided row by row with tight LPs (:func:`exact_minimal_rows`).
    Rows must be normalised.
    """
    keep = minimal_rows(A, b)
    dropped = np.setdiff1d(np.arange(A.shape[0]), keep)
    if dropped.size == 0:
        return keep
    c2, r2 = chebyshev_ball(A[keep], b[keep])
    tol = 1e-9 * (1.0 + np.abs(b[dropped]))
    same_ball = r2 <= radius + 1e-6 * abs(radius) + 1e-12
    if same_ball and np.all(A[dropped] @ c2 + r2 <= b[dropped] + tol):
        return keep
    return exact_minimal_rows(A, b, centre)


def certified_minimal_rows(
    A: np.ndarray,
    b: np.ndarray,
    bound: float,
    fixed: np.ndarray | None = None,
) -> np.ndarray:
    """Non-redundant rows of a bounded polytope ``A x <= b``, where a row is dropped only
    with a certificate.

    DAQP's minrep proposes the rows to drop. A proposed row ``a_i x <= b_i`` is dropped
    only when multipliers ``y >= 0`` over rows ``K`` that are kept prove it:
    ``b_K' y + |a_i - A_K' y|_1 bound <= b_i`` (``bound`` >= max |x| over the set), so every
    x in the set satisfies it whatever the accuracy of the ``y``. Otherwise it is kept
    (harmless: a redundant row only costs a needless neighbour candidate). minrep's and
    even a tight LP's redundancy decisions were seen wrong by 5e-6 on ill-conditioned
    sets (pop_mpqp_001, _084), where a wrongly dropped row made a region overlap its
    neighbours with a wrong law.

    The ``y`` are the multipliers of one LP ``max a_i x`` over ``K`` per proposed row
    (a non-negative least-squares fit, used before, failed for a third of the rows that
    were redundant: the LP's multipliers are the best ``y``).

    Parameters
    ----------
    A : (k, d) ndarray
        Normalised rows; with ``fixed`` they describe a bounded set.
    b : (k,) ndarray
    bound : float
        An upper bound of ``max |x|_inf`` over the set.
    fixed : (f,) ndarray of int, optional
        Rows kept whatever their redundancy (they prove others but need no proof).

    Returns
    -------
    (r,) ndarray of int
        Ascending.
    """
    kept = np.zeros(A.shape[0], dtype=bool)
    kept[minimal_rows(A, b)] = True
    if fixed is not None:
        kept[fixed] = True
    pending = np.flatnonzero(~kept)
    if pending.size:
        # a row with the same normal as a kept row and no smaller offset is implied by it:
        # it goes without a proof (a copy's would fail, by the margin; merged regions share
        # rows, and copies through one vertex made the compiled LP's working set singular)
        K = np.flatnonzero(kept)
        same = np.all(A[pending, None, :] == A[None, K, :], axis=2)
        pending = pending[~np.any(same & (b[pending, None] >= b[None, K]), axis=1)]
    beta = b - 1e-12 * (1.0 + np.abs(b))  # a margin for the rounding of the check
    proved = np.zeros(A.shape[0], dtype=bool)
    for n, i in enumerate(pending):
        if proved[i]:
            continue
        K = np.flatnonzero(kept)
        y = _lp_multipliers(A[K], b[K], A[i])
        if y is None or not _certifies(A[K], b[K], y, A[i], beta[i], bound):
            kept[i] = True
            continue
        # the optimal basis often proves rows still to come (their normals in its cone):
        # least-squares multipliers on its rows, checked as any (no LP for them)
        rest = pending[n + 1 :]
        rest = rest[~proved[rest]]
        B = K[y > 0.0]
        if rest.size and B.size:
            proved[rest[_cone_proofs(A[B], b[B], A[rest], beta[rest], bound)]] = True
    return np.flatnonzero(kept)


def _cone_proofs(
    AB: np.ndarray, bB: np.ndarray, Ar: np.ndarray, beta: np.ndarray, bound: float
) -> np.ndarray:
    """Which rows ``Ar x <= beta`` (r,) the rows ``AB x <= bB`` prove on ``|x|_inf <=
    bound``, with least-squares multipliers (negative ones clipped): the weak-duality check
    of :func:`_certifies`, for all rows at once."""
    Y = np.maximum(np.linalg.lstsq(AB.T, Ar.T, rcond=None)[0], 0.0)  # (|B|, r)
    resid = np.abs(Ar.T - AB.T @ Y).sum(axis=0)
    return bB @ Y + resid * bound <= beta


def _lp_multipliers(AK: np.ndarray, bK: np.ndarray, a: np.ndarray) -> np.ndarray | None:
    """Multipliers (k,) of ``max a x`` over ``AK x <= bK`` (None when DAQP fails)."""
    k, d = AK.shape
    _, _, flag, info = daqp.solve(
        np.zeros((d, d)),
        -a,
        np.ascontiguousarray(AK),
        np.ascontiguousarray(bK),
        np.full(k, -_INF),
        np.zeros(k, dtype=np.int32),
        # DAQP's defaults: 3x faster than solve_lp's proximal settings here, and as many
        # certificates succeed (_certifies does not trust the solver's accuracy)
    )
    if flag != 1:
        return None
    return np.asarray(info["lam"], dtype=float)


def _certifies(
    AK: np.ndarray, bK: np.ndarray, y: np.ndarray, a: np.ndarray, beta: float, bound: float
) -> bool:
    """Whether the multipliers ``y`` (k,) prove ``a x <= beta`` on ``{x : AK x <= bK,
    |x|_inf <= bound}``: weak duality, with negative multipliers clipped and the residual
    of the dual equation charged at ``bound``.

    For x in the set, ``a x = (AK' y) x + (a - AK' y) x <= bK' y + |a - AK' y|_1 bound``.
    """
    y = np.maximum(y, 0.0)
    resid = float(np.abs(a - AK.T @ y).sum())
    return float(bK @ y) + resid * bound <= beta


def exact_minimal_rows(A: np.ndarray, b: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Non-redundant rows of ``A x <= b`` by one tight LP per row (``max a_i x`` over the
    rows kept so far), rows farthest from ``centre`` (an interior point) first."""
    k = A.shape[0]
    keep = np.ones(k, dtype=bool)
    for i in np.argsort(-(b - A @ centre)):
        keep[i] = False
        x, status, _ = solve_lp(-A[i], A[keep], b[keep])
        redundant = status == "optimal" and x is not None
        if not (redundant and A[i] @ x <= b[i] + 1e-9 * (1 + abs(b[i]))):
            keep[i] = True
    return np.flatnonzero(keep)
