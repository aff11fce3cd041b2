"""The mp-QP candidate evaluation compiled with numba: KKT, Chebyshev ball and a certified
minimal representation, with a small dense LP solver of its own.

``mpqp._Kernel.evaluate`` does the same work in numpy, SciPy and DAQP calls; on the
CDC-24 set (d = 5-8, tens of rows) each call costs 10-60 us of Python overhead for a few
microseconds of arithmetic, and a critical region needs about 30 of them. Here one call
per candidate does everything. Every decision that matters for exactness is proved, not
trusted to the LP's accuracy:

- a row is dropped from a region's description only with multipliers ``y >= 0`` that
  prove it redundant by weak duality (the residual of the dual equation charged at the
  parameter set's size), exactly as ``polytope.certified_minimal_rows``;
- a region is "full" only with a centre whose ball of radius ``rho`` is verified inside
  every row.

Whenever the solver cannot conclude (iteration limit, an ill-conditioned active set, a
degenerate spot), the status is ``FALLBACK`` and the caller evaluates the candidate with
the numpy kernel instead.

The LP solver is a primal active-set method (the simplex method started from a feasible
point that need not be a vertex): move along the cost projected on the working set's null
space to the first blocking row; at a vertex, drop the row with the most negative
multiplier (Bland's rule after degenerate steps, against cycling; a row dropped at a point
that blocks again at once is taken as rounding, the point as stationary for the rows
left, since drop and add alternated there for hundreds of pivots). Problems here have
d + 1 <= 10 variables and tens of rows, so the working set's basis is re-orthonormalised
from scratch (modified Gram-Schmidt) at every step.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: statuses returned by ``evaluate``
LICQ, EMPTY, LOWER, FULL, FALLBACK = 0, 1, 2, 3, 4
#: their names in ``mpqp._Kernel.evaluate_numpy`` (FALLBACK: it has none, it concludes)
STATUS_NAMES = {LICQ: "licq", EMPTY: "empty", LOWER: "lower", FULL: "full"}

#: LP outcomes
_OPTIMAL, _UNBOUNDED, _FAILED, _EXCEEDS = 0, 1, 2, 3

_RADIUS_CAP = 1e6
#: vertices kept for warm starts in ``_certified_keep``
_WARM_STARTS = 16
#: pivots without gain after which an LP gives up (cycling by rounding)
_STALL = 200


@njit(cache=True)
def _append_row(A, j, Q, R, nw):
    """Orthonormalise the row ``A[j]`` against ``Q[:nw]`` (modified Gram-Schmidt, twice:
    that is enough for orthogonality to rounding even for nearly dependent rows) and store
    it as ``Q[nw]``, with ``R[nw, :nw + 1]`` such that ``A[j] = R[nw] Q``. Returns the norm
    left. (Rows by index, built in place: a row view costs an atomic reference count
    increment and decrement, which were 22% of the mp-QP search's time.)"""
    n = A.shape[1]
    for t in range(n):
        Q[nw, t] = A[j, t]
    for i in range(nw):
        R[nw, i] = 0.0
    for _ in range(2):
        for i in range(nw):
            r = 0.0
            for t in range(n):
                r += Q[i, t] * Q[nw, t]
            R[nw, i] += r
            for t in range(n):
                Q[nw, t] -= r * Q[i, t]
    nv = 0.0
    for t in range(n):
        nv += Q[nw, t] * Q[nw, t]
    nv = np.sqrt(nv)
    R[nw, nw] = nv
    for t in range(n):
        Q[nw, t] = Q[nw, t] / nv if nv > 0.0 else 0.0
    return nv


@njit(cache=True)
def _solve_rt(R, rhs, nw, out):
    """``R[:nw, :nw]' out = rhs`` (R lower triangular, as from ``_append_row``), by back
    substitution into ``out`` (which may be ``rhs`` itself)."""
    for i in range(nw - 1, -1, -1):
        s = rhs[i]
        for j in range(i + 1, nw):
            s -= R[j, i] * out[j]
        out[i] = s / R[i, i]


@njit(cache=True)
def _orthonormal_rows(A, W, nw, Q, R):
    """``A[W[:nw]] = R Q`` with ``Q`` (nw, n) orthonormal rows and ``R`` (nw, nw) lower
    triangular. Returns the smallest |R_ii|."""
    smallest = np.inf
    for j in range(nw):
        smallest = min(smallest, _append_row(A, W[j], Q, R, j))
    return smallest


@njit(cache=True)
def lp_workspace(k, n):
    """Scratch arrays for :func:`_lp` on ``k`` rows and ``n`` variables (a critical region
    needs ~15 LPs of one size: allocating once saves ~10 allocations each)."""
    return (
        np.empty(n), np.zeros(k), np.empty(n, dtype=np.int64), np.zeros(k, dtype=np.bool_),
        np.zeros((n, n)), np.zeros((n, n)), np.empty(n), np.empty(n), np.empty(k),
        np.empty(k), np.empty(k),
    )


@njit(cache=True)
def lp_max(c, A, b, use, x0, W0, nw0, stop_value, maxit):
    """``max c'x  s.t.  A_i x <= b_i`` for the rows with ``use[i]``, from the feasible point
    ``x0`` with the rows ``W0[:nw0]`` (independent, tight at ``x0``) as working set.

    Parameters
    ----------
    c : (n,) ndarray
    A : (k, n) ndarray
    b : (k,) ndarray
    use : (k,) bool ndarray
    x0 : (n,) ndarray
        Feasible (``A x0 <= b`` up to rounding).
    W0 : (n,) int ndarray
    nw0 : int
    stop_value : float
        Stop early (status ``_EXCEEDS``) as soon as ``c'x > stop_value``.
    maxit : int

    Returns
    -------
    status : int
    x : (n,) ndarray
    y : (k,) ndarray
        Multipliers (``A' y = c`` on the working set) at an optimum.
    W, nw : (n,) int ndarray, int
        The final working set.
    """
    return _lp(c, A, b, use, x0, W0, nw0, stop_value, maxit, lp_workspace(*A.shape))


@njit(cache=True)
def _lp(c, A, b, use, x0, W0, nw0, stop_value, maxit, ws):
    """:func:`lp_max` in the scratch arrays ``ws`` (from :func:`lp_workspace`); the
    ``x``, ``y`` and ``W`` it returns are those arrays, valid until the next call."""
    k, n = A.shape
    x, y, W, inW, Q, R, p, qc, steps, slopes, slack = ws
    for t in range(n):
        x[t] = x0[t]
    for i in range(k):
        y[i] = 0.0
        inW[i] = False
    nw = 0
    for j in range(nw0):
        W[nw] = W0[j]
        inW[W0[j]] = True
        nw += 1
    if nw and not _orthonormal_rows(A, W, nw, Q, R) > 0.0:
        # dependent start rows: start from x0 alone
        for j in range(nw):
            inW[W[j]] = False
        nw = 0
    # slack = b - A x, kept up to date along the steps
    for i in range(k):
        if use[i]:
            s = b[i]
            for t in range(n):
                s -= A[i, t] * x[t]
            slack[i] = s
    value = 0.0
    cnorm = 0.0
    for t in range(n):
        cnorm += c[t] * c[t]
        value += c[t] * x[t]
    cnorm = np.sqrt(cnorm)
    degenerate = 0
    # rows dropped since the last step that gained: one of them blocking again at once
    # is rounding (see below)
    dropped = np.zeros(k, dtype=np.bool_)
    ndropped = 0
    stationary = False
    for _ in range(maxit):
        if value > stop_value:
            return _EXCEEDS, x, y, W, nw
        # p = c projected on the null space of the working rows (qc = Q c, kept for the
        # multipliers)
        _project(Q, nw, c, qc)
        for t in range(n):
            p[t] = c[t]
        for i in range(nw):
            for t in range(n):
                p[t] -= qc[i] * Q[i, t]
        pn = 0.0
        for t in range(n):
            pn += p[t] * p[t]
        pn = np.sqrt(pn)
        if nw == n or pn <= 1e-13 * (cnorm + 1.0) or stationary:
            # a stationary point of the working set: multipliers from R' lam = Q c
            # (the multipliers in steps, free until the next ratio test: no alias,
            # which would cost a reference count)
            _solve_rt(R, qc, nw, steps)
            drop = -1
            worst = -1e-12 * (cnorm + 1.0)
            for i in range(nw):
                if degenerate > 2 * n:
                    # Bland: the lowest row index among the negative multipliers
                    if steps[i] < worst and (drop < 0 or W[i] < W[drop]):
                        drop = i
                elif steps[i] < worst:
                    worst = steps[i]
                    drop = i
            if drop < 0:
                if stationary and pn > 1e-6 * (cnorm + 1.0):
                    return _FAILED, x, y, W, nw  # not stationary after all: no answer
                for i in range(nw):
                    y[W[i]] = steps[i]
                return _OPTIMAL, x, y, W, nw
            stationary = False
            dropped[W[drop]] = True
            ndropped += 1
            inW[W[drop]] = False
            for i in range(drop, nw - 1):
                W[i] = W[i + 1]
            nw -= 1
            # the rows before the one dropped keep their orthonormal rows (Gram-Schmidt
            # takes the rows in order): only the later ones are redone
            for i in range(drop, nw):
                _append_row(A, W[i], Q, R, i)
            continue
        # ratio test: the first row the step along p hits; among rows hit (nearly) at once
        # (a degenerate vertex) the one most across p, which keeps the working set well
        # conditioned
        alpha = np.inf
        for i in range(k):
            steps[i] = np.inf
            if inW[i] or not use[i]:
                continue
            ap = 0.0
            for t in range(n):
                ap += A[i, t] * p[t]
            slopes[i] = ap
            if ap > 1e-12 * pn:
                steps[i] = max(slack[i], 0.0) / ap
                if steps[i] < alpha:
                    alpha = steps[i]
        if alpha == np.inf:
            return _UNBOUNDED, x, y, W, nw
        block = -1
        reach = alpha + 1e-12 * (1.0 + abs(alpha))
        bland = degenerate > 2 * n
        for i in range(k):
            if steps[i] <= reach and (
                block < 0 or (slopes[i] > slopes[block] and not bland)
            ):
                block = i  # (Bland: the lowest index among the rows hit at once)
        if dropped[block] and alpha <= 1e-12 * (1.0 + abs(value)):
            # a row dropped at this point blocks at once: in exact arithmetic it cannot
            # (its multiplier was negative), so p is rounding (|p| ~ 4e-10 at pop_mpqp_036's
            # ill-conditioned degenerate vertices, where drop and add alternated for 400
            # pivots): take the point as stationary for the rows left
            stationary = True
            degenerate += 1
            if degenerate > _STALL:
                return _FAILED, x, y, W, nw
            continue
        before = value
        for t in range(n):
            x[t] += alpha * p[t]
            value += alpha * c[t] * p[t]
        # a step that gains nothing counts as degenerate (rounding leaves some slacks at
        # 1e-18 instead of 0: steps of that size cycled for thousands of pivots on slivers)
        if value - before <= 1e-14 * (1.0 + abs(value)):
            degenerate += 1
            if degenerate > _STALL:
                return _FAILED, x, y, W, nw  # cycling all the same: no answer
        else:
            degenerate = 0
            if ndropped:  # (not a pass over the rows at every step)
                for i in range(k):
                    dropped[i] = False
                ndropped = 0
        for i in range(k):
            if use[i] and not inW[i]:
                slack[i] -= alpha * slopes[i]
        slack[block] = 0.0
        W[nw] = block
        if not _append_row(A, block, Q, R, nw) > 0.0:
            # the blocking row is (to rounding) a copy of working rows: seen with exact
            # duplicates through one vertex; R would be singular (a division by zero)
            return _FAILED, x, y, W, nw
        nw += 1
        inW[block] = True
    return _FAILED, x, y, W, nw


@njit(cache=True)
def _chebyshev(Ar, br, x0, bound, maxit):
    """Largest ball in ``{Ar x <= br}`` (unit rows, the set within ``|x|_inf <= bound``):
    (status, centre, radius, an upper bound of the radius)."""
    k, d = Ar.shape
    A = np.zeros((k + 1, d + 1))
    b = np.empty(k + 1)
    A[:k, :d] = Ar
    A[:k, d] = 1.0
    b[:k] = br
    A[k, d] = 1.0
    b[k] = _RADIUS_CAP
    start = np.empty(d + 1)
    start[:d] = x0
    r0 = _RADIUS_CAP
    for i in range(k):
        s = br[i]
        for t in range(d):
            s -= Ar[i, t] * x0[t]
        if s < r0:
            r0 = s
    start[d] = r0
    c = np.zeros(d + 1)
    c[d] = 1.0
    status, z, y, _, _ = lp_max(
        c, A, b, np.ones(k + 1, dtype=np.bool_), start, np.empty(0, dtype=np.int64), 0, np.inf,
        maxit,
    )
    # an upper bound of the largest radius by weak duality (y clipped at 0; the residual of
    # A' y = c charged at max |x| <= bound, and at the radius cap for its own column)
    upper = np.inf
    if status == _OPTIMAL:
        res = c.copy()
        val = 0.0
        for i in range(k + 1):
            yi = max(y[i], 0.0)
            if yi > 0.0:
                val += b[i] * yi
                for t in range(d + 1):
                    res[t] -= A[i, t] * yi
        rs = 0.0
        for t in range(d):
            rs += abs(res[t])
        # (a point with radius r >= -1 lies within about bound + 1 of the origin: the
        # generous 2 bound + 1 covers it; the residuals are ~1e-16 anyway)
        upper = val + rs * (2.0 * bound + 1.0) + abs(res[d]) * _RADIUS_CAP
    return status, z[:d].copy(), z[d], upper


@njit(cache=True)
def _cholesky(M):
    """Lower Cholesky factor, or an empty array when M is not positive definite."""
    n = M.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        s = M[j, j]
        for t in range(j):
            s -= L[j, t] * L[j, t]
        if not s > 0.0:
            return np.zeros((0, 0))
        L[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = M[i, j]
            for t in range(j):
                s -= L[i, t] * L[j, t]
            L[i, j] = s / L[j, j]
    return L


@njit(cache=True)
def _cho_solve(L, B):
    """Solve ``L L' X = B`` (B (n, r))."""
    n, r = B.shape
    X = B.copy()
    for col in range(r):
        for i in range(n):
            s = X[i, col]
            for t in range(i):
                s -= L[i, t] * X[t, col]
            X[i, col] = s / L[i, i]
        for i in range(n - 1, -1, -1):
            s = X[i, col]
            for t in range(i + 1, n):
                s -= L[t, i] * X[t, col]
            X[i, col] = s / L[i, i]
    return X


@njit(cache=True)
def _certified_keep(A, b, fixed, centre, bound, maxit):
    """Rows of the bounded polytope ``A x <= b`` (unit rows) to keep: every row not kept
    is proved redundant by multipliers over kept rows (weak duality, residual charged at
    ``bound``). ``fixed`` rows are always kept; ``centre`` is an interior point. An LP that
    gives no answer keeps its row. Returns the keep mask."""
    k, d = A.shape
    kept = np.ones(k, dtype=np.bool_)
    margin = np.empty(k)
    for i in range(k):
        margin[i] = b[i] - 1e-12 * (1.0 + abs(b[i]))
    # exact duplicates (same row, offset not smaller): the later one goes
    for i in range(k):
        if fixed[i] or not kept[i]:
            continue
        for j in range(k):
            if j == i or not kept[j]:
                continue
            if b[j] > b[i] or (b[j] == b[i] and j > i):
                continue
            same = True
            for t in range(d):
                if A[i, t] != A[j, t]:
                    same = False
                    break
            if same:
                kept[i] = False
                break
    basis = np.empty(d, dtype=np.int64)
    Qb = np.zeros((d, d))
    Rb = np.zeros((d, d))
    work = np.empty(d)
    ws = lp_workspace(k, d)
    # vertices where earlier LPs ended (ring buffer): each LP starts from the one best for
    # its cost, with that vertex's rows as working set (they are all points of the
    # polytope: dropping redundant rows leaves it as it is); ~40% fewer pivots than
    # starting from the centre
    VX = np.empty((_WARM_STARTS, d))
    VW = np.empty((_WARM_STARTS, d), dtype=np.int64)
    nv = 0  # vertices in the buffer
    stored = 0  # vertices ever stored (the next goes to stored % _WARM_STARTS)
    W0 = np.empty(d, dtype=np.int64)
    X0 = np.empty(d)
    crow = np.empty(d)
    # facets seen from the centre: along a row's normal, the ray that reaches that row's
    # plane strictly before every other plane proves the row needed (the point it hits is
    # inside all the others), with no LP
    facet = np.zeros(k, dtype=np.bool_)
    dist = np.empty(k)
    for i in range(k):
        s = b[i]
        for t in range(d):
            s -= A[i, t] * centre[t]
        dist[i] = s
    for i in range(k):
        if fixed[i] or not kept[i]:
            continue
        first = dist[i]  # the ray c + s a_i meets row i at s = dist_i (unit rows)
        ok = first > 0.0
        for j in range(k):
            if j == i or not kept[j] or not ok:
                continue
            aj = 0.0
            for t in range(d):
                aj += A[j, t] * A[i, t]
            if aj > 0.0 and dist[j] <= aj * first * (1.0 + 1e-9) + 1e-12:
                ok = False
        facet[i] = ok
    # the rest: one LP each, max a_i x over the other kept rows (it stops once past row i:
    # then the row is needed); the rows farthest from the centre first, as they are the
    # likely redundant ones, whose optimal bases prove rows still to come
    order = np.argsort(-dist)
    done = np.zeros(k, dtype=np.bool_)
    for i in order:
        done[i] = True
        if fixed[i] or not kept[i] or facet[i]:
            continue
        kept[i] = False  # the LP is over the others
        stop = b[i] + 1e-9 * (1.0 + abs(b[i]))
        start = -1
        top = -np.inf
        for v in range(nv):
            s = 0.0
            for t in range(d):
                s += A[i, t] * VX[v, t]
            if s > top:
                top = s
                start = v
        nw0 = 0
        if start >= 0:
            for t in range(d):
                X0[t] = VX[start, t]
            for q in range(d):
                if kept[VW[start, q]]:
                    W0[nw0] = VW[start, q]
                    nw0 += 1
        else:
            for t in range(d):
                X0[t] = centre[t]
        for t in range(d):
            crow[t] = A[i, t]
        status, x, y, W, nw = _lp(crow, A, b, kept, X0, W0, nw0, stop, maxit, ws)
        kept[i] = True
        if status != _OPTIMAL:
            continue  # a point of the others outside row i (needed), or no answer: keep
        if nw == d:
            slot = stored % _WARM_STARTS
            for t in range(d):
                VX[slot, t] = x[t]
                VW[slot, t] = W[t]
            stored += 1
            nv = min(stored, _WARM_STARTS)
        nb = 0
        for j in range(nw):
            if y[W[j]] > 0.0:
                basis[nb] = W[j]
                work[nb] = y[W[j]]
                nb += 1
        if _proves(A, b, basis, nb, work, i, bound, margin[i]):
            kept[i] = False
            if nb == d:
                _mark_simple_vertex(A, b, kept, x, basis, facet)
            # the optimal basis often proves rows still to come: a_j in the cone of its
            # rows with a small enough offset (an O(d^2) solve each, no LP); a basis row
            # is not offered its own basis (it would be proved by itself)
            _orthonormal_rows(A, basis, nb, Qb, Rb)
            for j in range(k):
                if done[j] or fixed[j] or not kept[j] or facet[j] or _member(basis, nb, j):
                    continue
                # a_j in the cone of the basis rows (tight at x, slack at the centre)
                # needs a_j (x - centre) > 0: d flops that spare ~30% of the d^2 tests
                ax = 0.0
                for t in range(d):
                    ax += A[j, t] * (x[t] - centre[t])
                if ax <= 0.0:
                    continue
                if _basis_proves(A, b, basis, nb, Qb, Rb, j, bound, margin[j], work):
                    kept[j] = False
    return kept


@njit(cache=True)
def _member(B, nb, j):
    for q in range(nb):
        if B[q] == j:
            return True
    return False


@njit(cache=True)
def _mark_simple_vertex(A, b, kept, x, basis, facet):
    """Mark the rows ``basis`` (d of them) as facets when ``x`` is a simple vertex of the
    kept rows: no other kept row is tight there. (At a simple vertex each of its d planes
    holds a facet: moving from ``x`` into that plane, away from the other d - 1, stays
    inside every other row for a while.) A row marked needs no LP; the mark only ever
    keeps a row, so a rounding slip here costs a neighbour candidate, never a facet."""
    k, d = A.shape
    ntight = 0
    for j in range(k):
        if not kept[j]:
            continue
        sl = b[j]
        for t in range(d):
            sl -= A[j, t] * x[t]
        if sl <= 1e-9 * (1.0 + abs(b[j])):
            ntight += 1
    if ntight == d:
        for q in range(d):
            facet[basis[q]] = True


@njit(cache=True)
def _project(Q, nq, a, out):
    """``out[:nq] = Q[:nq] a``: the coordinates of ``a`` on orthonormal rows."""
    for i in range(nq):
        s = 0.0
        for t in range(a.size):
            s += Q[i, t] * a[t]
        out[i] = s


@njit(cache=True)
def _project_row(Q, nq, A, j, out):
    """:func:`_project` of the row ``A[j]`` (by index: no view in the hot loops)."""
    for i in range(nq):
        s = 0.0
        for t in range(A.shape[1]):
            s += Q[i, t] * A[j, t]
        out[i] = s


@njit(cache=True)
def _basis_proves(A, b, B, nb, Q, R, j, bound, beta, y):
    """Whether the rows ``A[B[:nb]] = R Q`` prove ``a_j x <= beta`` with y from
    ``R' y = Q a_j``; ``y`` (>= nb,) is work space."""
    _project_row(Q, nb, A, j, y)
    _solve_rt(R, y, nb, y)  # in place: each entry is read before it is written
    for q in range(nb):
        if y[q] < -1e-9:
            return False  # a_j is not in the cone (most rows): no proof to try
    return _proves(A, b, B, nb, y, j, bound, beta)


@njit(cache=True)
def _proves(A, b, B, nb, y, j, bound, beta):
    """Whether multipliers ``y[:nb]`` on the rows ``A[B[:nb]]`` (negative ones taken as 0)
    prove ``a_j x <= beta`` over the set within ``|x|_inf <= bound``: weak duality, with
    the residual of ``A_B' y = a_j`` charged at ``bound``."""
    d = A.shape[1]
    val = 0.0
    rs = 0.0
    for t in range(d):
        res = A[j, t]
        for i in range(nb):
            if y[i] > 0.0:
                res -= A[B[i], t] * y[i]
        rs += abs(res)
    for i in range(nb):
        if y[i] > 0.0:
            val += b[B[i]] * y[i]
    return val + rs * bound <= beta


@njit(cache=True, nogil=True)
def evaluate(
    act, start, G, M, Dfull, negZ0, Hinv_Gt, H, rhs_z, wS, At, bt, box_c, box_h, scale,
    region_tol, nonempty_tol, ill_conditioned, maxit,
):
    """One candidate active set ``act`` (sorted int64): see ``mpqp._Kernel.evaluate``.
    ``start`` (d,) is where the Chebyshev LP starts: any point will do, one near the
    region saves pivots (the walk passes the centre of the region that led here: about
    14 pivots instead of 25 from the centre of the parameter box).

    Returns
    -------
    status : int
        LICQ, EMPTY, LOWER, FULL or FALLBACK.
    rows_A, rows_b : (r, d), (r,) ndarrays
        The region's certified rows (FULL).
    K, k : (nz, d), (nz,) ndarrays
        The law (FULL).
    moves : (q,) ndarray of int
        Signed constraint ids of the neighbours (FULL, LOWER).
    lp : bool
        Whether an LP was solved.
    swaps : (s, 2) ndarray of int
        See :func:`_swaps` (FULL).
    point : (d,) ndarray
        The Chebyshev centre (FULL, LOWER), else ``start``: where the LPs of the
        neighbours should start.
    """
    m, nz = G.shape
    d = At.shape[1]
    na = act.size
    e2 = np.zeros((0, d))
    e1 = np.zeros(0)
    ez = np.zeros((nz, d))
    ek = np.zeros(nz)
    em = np.zeros(0, dtype=np.int64)
    es = np.zeros((0, 2), dtype=np.int64)
    if na > nz:
        return LICQ, e2, e1, ez, ek, em, False, es, start
    Qb = np.zeros((na, nz))
    Rb = np.zeros((na, na))
    if na and _orthonormal_rows(G, act, na, Qb, Rb) < 1e-9:
        return LICQ, e2, e1, ez, ek, em, False, es, start
    inact = np.empty(m - na, dtype=np.int64)
    isact = np.zeros(m, dtype=np.bool_)
    for i in range(na):
        isact[act[i]] = True
    r = 0
    for i in range(m):
        if not isact[i]:
            inact[r] = i
            r += 1
    # multipliers and slacks, affine in theta: columns (constant, theta)
    Lam = np.zeros((na, d + 1))
    Zaug = np.zeros((nz, d + 1))
    augmented = False
    if na:
        MAA = np.empty((na, na))
        for i in range(na):
            for j in range(na):
                MAA[i, j] = M[act[i], act[j]]
        L = _cholesky(MAA)
        if L.shape[0] == 0:
            return LICQ, e2, e1, ez, ek, em, False, es, start
        dmax = 0.0
        dmin = np.inf
        for i in range(na):
            dmax = max(dmax, L[i, i])
            dmin = min(dmin, L[i, i])
        if (dmax / dmin) ** 2 > ill_conditioned:
            # nearly dependent active rows: M_AA squares their conditioning, the augmented
            # KKT system does not (see mpqp._Kernel._kkt_augmented)
            Kkt = np.zeros((nz + na, nz + na))
            Kkt[:nz, :nz] = H
            rhs = np.empty((nz + na, d + 1))
            rhs[:nz] = rhs_z
            for i in range(na):
                Kkt[:nz, nz + i] = G[act[i]]
                Kkt[nz + i, :nz] = G[act[i]]
                rhs[nz + i] = wS[act[i]]
            X = np.linalg.solve(Kkt, rhs)
            augmented = True
            Zaug = X[:nz].copy()
            Lam = X[nz:].copy()
        else:
            B = np.empty((na, d + 1))
            for i in range(na):
                for u in range(d + 1):
                    B[i, u] = -Dfull[act[i], u]
            Lam = _cho_solve(L, B)
    ni = m - na
    p = At.shape[0]
    nr = na + ni + p
    Ar = np.empty((nr, d))
    br = np.empty(nr)
    src = np.zeros(nr, dtype=np.int64)
    for i in range(na):
        for t in range(d):
            Ar[i, t] = -Lam[i, t + 1]
        br[i] = Lam[i, 0]
        src[i] = act[i] + 1
    row = np.empty(d + 1)
    for q in range(ni):
        iq = inact[q]
        if augmented:
            # slack = w + S theta - G z
            for s in range(d + 1):
                row[s] = wS[iq, s]
            for t in range(nz):
                g = G[iq, t]
                for s in range(d + 1):
                    row[s] -= g * Zaug[t, s]
        else:
            for s in range(d + 1):
                row[s] = Dfull[iq, s]
            for i in range(na):
                coef = M[act[i], iq]
                for s in range(d + 1):
                    row[s] += coef * Lam[i, s]
        for t in range(d):
            Ar[na + q, t] = -row[t + 1]
        br[na + q] = row[0]
        src[na + q] = -(iq + 1)
    for q in range(p):
        for t in range(d):
            Ar[na + ni + q, t] = At[q, t]
        br[na + ni + q] = bt[q]
    # normalise; rows that vanish for every theta decide emptiness alone
    keep_row = np.ones(nr, dtype=np.bool_)
    # a multiplier or slack that may be zero for every theta (the swaps' argument needs
    # none); one constant and clearly positive is never zero (pop_mpqp_033's bounds
    # +-z_i <= 1e7 with g_i in the span of G_A: slack 1e7 for every theta)
    vanished = False
    for i in range(nr):
        s = 0.0
        for t in range(d):
            s += Ar[i, t] * Ar[i, t]
        s = np.sqrt(s)
        if s <= 1e-12:
            if br[i] < -1e-12:
                return EMPTY, e2, e1, ez, ek, em, False, es, start
            keep_row[i] = False
            if br[i] <= 1e-6 * (1.0 + scale):
                vanished = True
        else:
            for t in range(d):
                Ar[i, t] /= s
            br[i] /= s
    Ar = Ar[keep_row]
    br = br[keep_row]
    src = src[keep_row]
    nr = Ar.shape[0]
    bound = 0.0
    for t in range(d):
        bound = max(bound, abs(box_c[t]) + box_h[t])
    # rows that hold on the whole box of the parameter set are implied by its rows: every
    # ball inside the parameter set is inside them, and any upper bound of the radius
    # without them holds with them
    maybe = np.zeros(nr, dtype=np.bool_)
    for i in range(nr):
        reach = 0.0
        for t in range(d):
            reach += Ar[i, t] * box_c[t] + abs(Ar[i, t]) * box_h[t]
        maybe[i] = reach > br[i] - 1e-9 * scale or src[i] == 0
    Am = Ar[maybe]
    bm = br[maybe]
    status, centre, rho, upper = _chebyshev(Am, bm, start, bound, maxit)
    if status != _OPTIMAL:
        return FALLBACK, e2, e1, ez, ek, em, True, es, start
    # the radius the centre really has (the LP's steps drift off their rows by rounding):
    # a region is full only if this one is large enough
    true_rho = np.inf
    for i in range(nr):
        s = br[i]
        for t in range(d):
            s -= Ar[i, t] * centre[t]
        true_rho = min(true_rho, s)
    # each class needs its proof: empty and lower-dimensional an upper bound of the radius,
    # full a ball (true_rho, from the rows themselves)
    if upper < -nonempty_tol:
        return EMPTY, e2, e1, ez, ek, em, True, es, start
    if upper <= region_tol:
        # lower-dimensional: its neighbours are the constraints tight at a point of it
        tol = -max(rho, 0.0) - 1e-7 * scale
        tight = np.zeros(nr, dtype=np.bool_)
        for i in range(nr):
            s = -br[i]
            for t in range(d):
                s += Ar[i, t] * centre[t]
            if s >= tol:
                tight[i] = True
        return LOWER, e2, e1, ez, ek, src[tight], True, es, centre
    if true_rho <= region_tol or rho < -nonempty_tol:
        return FALLBACK, e2, e1, ez, ek, em, True, es, start
    sm = src[maybe]
    fixed = sm == 0
    kept = _certified_keep(Am, bm, fixed, centre, bound, maxit)
    Ak = Am[kept]
    bk = bm[kept]
    # the neighbours: constraints of the kept rows, and of rows on their hyperplanes
    # (several constraints changing on one hyperplane: a degenerate facet)
    on = np.zeros(nr, dtype=np.bool_)
    on_plane = np.zeros(Ak.shape[0], dtype=np.int64)  # rows on each kept row's hyperplane
    for j in range(Ak.shape[0]):
        tol = 1e-9 * (1.0 + abs(bk[j]))
        for i in range(nr):
            if abs(br[i] - bk[j]) > tol:
                continue
            same = True
            for t in range(d):
                if abs(Ar[i, t] - Ak[j, t]) > tol:
                    same = False
                    break
            if same:
                on[i] = True
                on_plane[j] += 1
    moves = np.unique(src[on])
    swaps = es
    if not vanished and na:
        moves, swaps = _swaps(moves, on_plane == 1, sm[kept], G, act, Qb, Rb)
    # z = -H^-1 (c + C theta) - H^-1 G_A' lambda_A(theta)
    if augmented:
        return FULL, Ak, bk, Zaug[:, 1:].copy(), Zaug[:, 0].copy(), moves, True, swaps, centre
    Z = negZ0.copy()
    for i in range(na):
        for t in range(nz):
            h = Hinv_Gt[t, act[i]]
            for s in range(d + 1):
                Z[t, s] -= h * Lam[i, s]
    return FULL, Ak, bk, Z[:, 1:].copy(), Z[:, 0].copy(), moves, True, swaps, centre


@njit(cache=True)
def _swaps(moves, alone, src_kept, G, act, Q, R):
    """Facets across which a constraint enters an active set that it makes dependent:
    the constraints that may leave as it enters.

    A facet of the region of ``A`` (a kept row, from ``src_kept``) where the slack of
    constraint i vanishes, alone on its hyperplane (``alone``), with ``g_i = sum_j c_j g_j`` over
    ``A`` (so ``A + i`` breaks LICQ, with the one dependency ``(-c, 1)``). At a point of
    the facet where every multiplier ``lambda_j`` of ``A`` is positive and no other
    constraint is tight (all of it but a lower-dimensional part, since no other row
    shares the hyperplane), the optimizer is that of ``A``, the tight constraints are
    ``A + i``, and an active set optimal there is a subset of ``A + i`` that keeps LICQ,
    so it leaves out some j with ``c_j != 0``. Its multipliers are then ``lambda - t c``
    on ``A`` and ``t`` on i, with ``t = lambda_j / c_j``: ``t >= 0`` needs ``c_j > 0``,
    and leaving out one more constraint l needs ``lambda_l = t c_l`` as well (a
    lower-dimensional part again). So the regions across the facet are among ``A + i -
    j`` with ``c_j > 0``, and the walk goes there directly instead of through ``A + i``
    and all its subsets (most of them empty).

    Returns
    -------
    moves : (q,) int64
        ``moves`` without the entering moves replaced by swaps.
    swaps : (s, 2) int64
        Pairs (entering constraint, leaving constraint).
    """
    na, nz = Q.shape  # (na >= 1)
    out = np.empty((src_kept.size * na, 2), dtype=np.int64)
    ns = 0
    replaced = np.zeros(moves.size, dtype=np.bool_)
    q = np.empty(na)
    c = np.empty(na)
    for r in range(src_kept.size):
        if src_kept[r] >= 0 or not alone[r]:
            continue
        i = -src_kept[r] - 1
        # g_i in the span of G_A?  (rows unit norm: the residual of the projection)
        _project_row(Q, na, G, i, q)
        res = 0.0
        for t in range(nz):
            v = G[i, t]
            for l in range(na):
                v -= q[l] * Q[l, t]
            res += v * v
        if np.sqrt(res) >= 1e-9:
            continue  # A + i keeps LICQ: the plain move
        _solve_rt(R, q, na, c)
        cmax = 0.0
        for l in range(na):
            cmax = max(cmax, abs(c[l]))
        for l in range(na):
            # (c_l about 0: A + i - l still dependent, never a region; LICQ breaks at the
            # same 1e-9 for unit rows, so such a candidate would only be LICQ, and its
            # subsets leave out one more constraint: lower-dimensional on the facet)
            if c[l] > 1e-9 * max(1.0, cmax):
                out[ns, 0] = i
                out[ns, 1] = act[l]
                ns += 1
        for u in range(moves.size):
            if moves[u] == src_kept[r]:
                replaced[u] = True
    return moves[~replaced], out[:ns].copy()


# Batches of candidates, as ``mpqp_graph`` walks them. They live here, with ``evaluate``:
# numba's on-disk cache of a function is renewed when its own file changes, not when a
# function it calls from another file does.

_ONE = np.uint64(1)


@njit(cache=True)
def _bit_index(low):
    """The index of the single set bit of ``low``."""
    i = 0
    while low > _ONE:
        low >>= _ONE
        i += 1
    return i


@njit(cache=True)
def decode(keys, width):
    """Active sets of the bitmasks ``keys`` (B, W): (B, width) int64 rows, ascending, padded
    with -1, and their sizes (B,)."""
    B, W = keys.shape
    acts = np.full((B, width), -1, dtype=np.int64)
    sizes = np.zeros(B, dtype=np.int64)
    for c in range(B):
        n = 0
        for t in range(W):
            w = keys[c, t]
            while w:
                low = w & (~w + _ONE)
                w ^= low
                if n < width:
                    acts[c, n] = t * 64 + _bit_index(low)
                n += 1
        sizes[c] = n
    return acts, sizes


@njit(cache=True, nogil=True)
def evaluate_batch(keys, starts, args):
    """``evaluate(act, start, *args)`` on each candidate ``act`` of ``keys`` (B, W) with its
    ``start`` from ``starts`` (B, d), in one call.

    Returns
    -------
    status, lp : (B,) int64, (B,) bool
    acts, sizes : (B, nz + 1) int64, (B,) int64
        The active sets (see ``decode``).
    rows_off, rows_A, rows_b : (B + 1,), (R, d), (R,)
        Candidate c's certified rows are ``rows_A[rows_off[c]:rows_off[c + 1]]`` (FULL).
    K, k : (B, nz, d), (B, nz)
        The laws (FULL).
    moves, moves_off : (q,), (B + 1,) int64
        The neighbours' signed constraint ids (FULL, LOWER), as in ``_visit``.
    swaps, swaps_off : (s, 2), (B + 1,) int64
        Swaps (FULL), as in ``_visit``.
    points : (B, d)
        ``evaluate``'s points: where the neighbours' LPs should start.
    """
    G, At, box_c = args[0], args[8], args[10]  # (evaluate's parameters after act, start)
    m, nz = G.shape
    d = At.shape[1]
    B = keys.shape[0]
    acts, sizes = decode(keys, nz + 1)
    status = np.empty(B, dtype=np.int64)
    lp = np.zeros(B, dtype=np.bool_)
    K = np.zeros((B, nz, d))
    k = np.zeros((B, nz))
    nr = m + At.shape[0]
    Ab = np.empty((B * nr, d))
    bb = np.empty(B * nr)
    mv = np.empty(B * nr, dtype=np.int64)
    sw = np.empty((B * m * max(nz, 1), 2), dtype=np.int64)
    rows_off = np.zeros(B + 1, dtype=np.int64)
    moves_off = np.zeros(B + 1, dtype=np.int64)
    swaps_off = np.zeros(B + 1, dtype=np.int64)
    points = starts.copy()
    for c in range(B):
        r0 = rows_off[c]
        q0 = moves_off[c]
        s0 = swaps_off[c]
        rows_off[c + 1] = r0
        moves_off[c + 1] = q0
        swaps_off[c + 1] = s0
        if sizes[c] > nz:
            status[c] = LICQ
            continue
        act = acts[c, : sizes[c]].copy()
        st, Ak, bk, Kc, kc, moves, used_lp, swaps, point = evaluate(act, starts[c], *args)
        if st == FALLBACK:
            # once more from the centre of the parameter box: on a sliver the LP from the
            # neighbour's centre can end where no centre checks, and the numpy kernel may
            # then judge it lower-dimensional (pop_mpqp_047's (5, 7, 29, 33, 34, 35, 42),
            # radius 1.1e-7, was left a hole that way); a class either start proves is sound
            st, Ak, bk, Kc, kc, moves, used_lp, swaps, point = evaluate(act, box_c, *args)
        status[c] = st
        points[c] = point
        lp[c] = used_lp
        if st == FULL:
            nk = Ak.shape[0]
            Ab[r0 : r0 + nk] = Ak
            bb[r0 : r0 + nk] = bk
            rows_off[c + 1] = r0 + nk
            K[c] = Kc
            k[c] = kc
        nm = moves.size
        mv[q0 : q0 + nm] = moves
        moves_off[c + 1] = q0 + nm
        ns = swaps.shape[0]
        sw[s0 : s0 + ns] = swaps
        swaps_off[c + 1] = s0 + ns
    R = rows_off[B]
    return (
        status,
        lp,
        acts,
        sizes,
        rows_off,
        Ab[:R].copy(),
        bb[:R].copy(),
        K,
        k,
        mv[: moves_off[B]].copy(),
        moves_off,
        sw[: swaps_off[B]].copy(),
        swaps_off,
        points,
    )


# Bounding boxes of many polytopes (the point locator's grid, the conformance checks): the
# same LP solver, one compiled call for all regions instead of 2 d Python LP calls each.


@njit(cache=True)
def region_boxes(A, b, off, maxit):
    """Axis-aligned bounding boxes of the polytopes ``A[off[i]:off[i+1]] x <=
    b[off[i]:off[i+1]]``.

    Per region: a Chebyshev centre (a feasible start), then ``2 d`` LPs, each started
    from the vertex where the last one ended; a bound counts only when the LP's
    multipliers reproduce its cost and its vertex holds every row (to 1e-9).

    Parameters
    ----------
    A : (N, d) ndarray
    b : (N,) ndarray
    off : (R + 1,) int ndarray
    maxit : int

    Returns
    -------
    lo, hi : (R, d) ndarrays
    ok : (R,) bool ndarray
        False where an LP gave no optimum (an empty, unbounded or too thin region): the
        caller bounds that region another way (its ``lo``, ``hi`` rows are NaN).
    """
    R = off.size - 1
    d = A.shape[1]
    lo = np.full((R, d), np.nan)
    hi = np.full((R, d), np.nan)
    ok = np.zeros(R, dtype=np.bool_)
    c = np.zeros(d)
    W0 = np.empty(d, dtype=np.int64)
    x0 = np.empty(d)
    for r in range(R):
        k = off[r + 1] - off[r]
        if k == 0:
            continue
        Ar = np.empty((k, d))
        br = np.empty(k)
        good = True
        for i in range(k):
            s = 0.0
            for t in range(d):
                s += A[off[r] + i, t] ** 2
            s = np.sqrt(s)
            if not s > 0.0 or not np.isfinite(s) or not np.isfinite(b[off[r] + i]):
                good = False
                break
            for t in range(d):
                Ar[i, t] = A[off[r] + i, t] / s
            br[i] = b[off[r] + i] / s
        if not good:
            continue
        status, centre, rho, _ = _chebyshev(Ar, br, np.zeros(d), 1.0, maxit)
        if status != _OPTIMAL or not rho >= 0.0:
            continue
        use = np.ones(k, dtype=np.bool_)
        ws = lp_workspace(k, d)
        for t in range(d):
            x0[t] = centre[t]
        nw0 = 0
        for j in range(d):
            for sign in (1.0, -1.0):
                c[j] = sign
                status, x, y, W, nw = _lp(c, Ar, br, use, x0, W0, nw0, np.inf, maxit, ws)
                c[j] = 0.0
                if status != _OPTIMAL:
                    good = False
                    break
                # the multipliers must reproduce the cost: on a needle (radius 1e-7,
                # multipliers 1e6) an ill-conditioned working set can stop the LP
                # half-way, with A_W' y far from e_j
                res = 0.0
                for t in range(d):
                    rt = sign if t == j else 0.0
                    for q in range(nw):
                        rt -= Ar[W[q], t] * max(y[W[q]], 0.0)
                    res += abs(rt)
                if res > 1e-9:
                    good = False
                    break
                # and the vertex must be a point of the region: where the projected cost is
                # ~1e-12 its rounding (~1e-16) is a large part of p, and a step of 1e13
                # along it left the working rows by 3e-4 (pop_mpqp_016)
                for i in range(k):
                    s = -br[i]
                    for t in range(d):
                        s += Ar[i, t] * x[t]
                    if s > 1e-9 * (1.0 + abs(br[i])):
                        good = False
                if not good:
                    break
                if sign > 0.0:
                    hi[r, j] = x[j]
                else:
                    lo[r, j] = x[j]
                for t in range(d):
                    x0[t] = x[t]
                for q in range(nw):
                    W0[q] = W[q]
                nw0 = nw
            if not good:
                break
        if good:
            ok[r] = True
        else:
            for t in range(d):
                lo[r, t] = np.nan
                hi[r, t] = np.nan
    return lo, hi, ok
