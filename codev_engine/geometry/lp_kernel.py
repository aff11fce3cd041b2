"""A small dense LP solver compiled with numba, and the polytope computations built on it:
the Chebyshev ball, a certified minimal representation and the bounding boxes of many
polytopes.

The problems here are small and many: the mp-QP kernel (``mp/mpqp_kernel``) solves ~15
of them per candidate active set, the point locator (``locate.bounding_boxes``) 2 d per
region. Python's per-call overhead would dominate the arithmetic, so they are loops
compiled once (``cache=True``: numba's on-disk cache, in ``__pycache__``). Every decision
that matters for exactness is proved, not trusted to the LP's accuracy: a row is dropped
from a description only with multipliers ``y >= 0`` that prove it redundant by weak
duality (the residual of the dual equation charged at the parameter set's size), exactly
as ``polytope.certified_minimal_rows``; a radius is bounded from above the same way; a
bounding box counts only when its LPs' multipliers reproduce their costs.

The LP solver is a primal active-set method (the simplex method started from a feasible
point that need not be a vertex): move along the cost projected on the working set's null
space to the first blocking row; at a vertex, drop the row with the most negative
multiplier (Bland's rule after degenerate steps, against cycling; a row dropped at a point
that blocks again at once is taken as rounding, the point as stationary for the rows
left, since drop and add alternated there for hundreds of pivots). Problems here have
d + 1 <= 10 variables and tens of rows, so the working set's basis is re-orthonormalised
from scratch (modified Gram-Schmidt) at every step.

A module whose compiled functions call these calls :func:`cache_follows` (numba does not
renew a function's cache when a function it calls from another file changes).
"""

from __future__ import annotations

import hashlib

import numpy as np
from numba import njit

#: LP outcomes
OPTIMAL, UNBOUNDED, FAILED, EXCEEDS = 0, 1, 2, 3

_RADIUS_CAP = 1e6
#: vertices kept for warm starts in ``certified_keep``
_WARM_STARTS = 16
#: pivots without gain after which an LP gives up (cycling by rounding)
_STALL = 200
#: a row whose distance to the span of the working rows is below this (relative to its
#: norm) counts as dependent on them: it never enters the working set (its slope along a
#: direction in their null space is rounding, and R would be (nearly) singular)
_DEPENDENT = 1e-10


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
def solve_rt(R, rhs, nw, out):
    """``R[:nw, :nw]' out = rhs`` (R lower triangular, as from ``_append_row``), by back
    substitution into ``out`` (which may be ``rhs`` itself).

    Parameters
    ----------
    R : (m, m) float64 ndarray
        Lower triangular in its leading ``nw`` rows and columns, ``m >= nw``.
    rhs : (>= nw,) float64 ndarray
    nw : int
        The size of the system.
    out : (>= nw,) float64 ndarray
        Receives the solution in ``out[:nw]``.
    """
    for i in range(nw - 1, -1, -1):
        s = rhs[i]
        for j in range(i + 1, nw):
            s -= R[j, i] * out[j]
        out[i] = s / R[i, i]


@njit(cache=True)
def orthonormal_rows(A, W, nw, Q, R):
    """``A[W[:nw]] = R Q`` with ``Q`` (nw, n) orthonormal rows and ``R`` (nw, nw) lower
    triangular, written in place (modified Gram-Schmidt, twice).

    Parameters
    ----------
    A : (k, n) float64 ndarray
    W : (>= nw,) int64 ndarray
        The rows of ``A`` to factor.
    nw : int
    Q : (>= nw, n) float64 ndarray
        Receives the orthonormal rows.
    R : (>= nw, >= nw) float64 ndarray
        Receives the lower triangular factor.

    Returns
    -------
    float
        The smallest ``|R_ii|``: (near) zero when the rows are (nearly) dependent.
    """
    smallest = np.inf
    for j in range(nw):
        smallest = min(smallest, _append_row(A, W[j], Q, R, j))
    return smallest


@njit(cache=True)
def _row_norm(A, j):
    s = 0.0
    for t in range(A.shape[1]):
        s += A[j, t] * A[j, t]
    return np.sqrt(s)


@njit(cache=True)
def _independent(A, W, nw, Q, R):
    """:func:`orthonormal_rows` of ``A[W[:nw]]``; whether no row is within ``_DEPENDENT``
    (relative) of the span of the rows before it."""
    for j in range(nw):
        if not _append_row(A, W[j], Q, R, j) > _DEPENDENT * _row_norm(A, W[j]):
            return False
    return True


@njit(cache=True)
def lp_workspace(k, n):
    """Scratch arrays for :func:`_lp` on ``k`` rows and ``n`` variables (a critical region
    needs ~15 LPs of one size: allocating once saves ~10 allocations each).

    Parameters
    ----------
    k : int
        Rows of the LP.
    n : int
        Variables of the LP.

    Returns
    -------
    tuple of ndarray
        ``x`` (n,), ``y`` (k,), ``W`` (n,) int64, ``inW`` (k,) bool, ``Q`` and ``R``
        (n, n), ``p``, ``qc`` (n,), ``steps``, ``slopes``, ``slack`` (k,).
    """
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
        Stop early (status ``EXCEEDS``) as soon as ``c'x > stop_value``.
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
    if nw and not _independent(A, W, nw, Q, R):
        # (nearly) dependent start rows: start from x0 alone
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
    # rows that blocked while (nearly) in the span of the working rows: their slope along
    # p is rounding (0 in exact arithmetic), they are left out of the ratio tests until
    # the working set changes
    skip = np.zeros(k, dtype=np.bool_)
    stationary = False
    for _ in range(maxit):
        if value > stop_value:
            return EXCEEDS, x, y, W, nw
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
            solve_rt(R, qc, nw, steps)
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
                    return FAILED, x, y, W, nw  # not stationary after all: no answer
                for i in range(nw):
                    y[W[i]] = steps[i]
                return OPTIMAL, x, y, W, nw
            stationary = False
            dropped[W[drop]] = True
            ndropped += 1
            inW[W[drop]] = False
            for i in range(drop, nw - 1):
                W[i] = W[i + 1]
            nw -= 1
            # the rows before the one dropped keep their orthonormal rows (Gram-Schmidt
            # takes the rows in order): only the later ones are redone; one that comes out
            # (nearly) dependent on the rows before it by rounding leaves the working set
            # too (it stays tight; a zero pivot of R is a division by zero in solve_rt)
            i = drop
            while i < nw:
                if _append_row(A, W[i], Q, R, i) > _DEPENDENT * _row_norm(A, W[i]):
                    i += 1
                    continue
                inW[W[i]] = False
                for j in range(i, nw - 1):
                    W[j] = W[j + 1]
                nw -= 1
            for i in range(k):
                skip[i] = False
            continue
        # ratio test: the first row the step along p hits; among rows hit (nearly) at once
        # (a degenerate vertex) the one most across p, which keeps the working set well
        # conditioned
        alpha = np.inf
        for i in range(k):
            steps[i] = np.inf
            if inW[i] or not use[i] or skip[i]:
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
            return UNBOUNDED, x, y, W, nw
        block = -1
        reach = alpha + 1e-12 * (1.0 + abs(alpha))
        bland = degenerate > 2 * n
        for i in range(k):
            if steps[i] <= reach and (
                block < 0 or (slopes[i] > slopes[block] and not bland)
            ):
                block = i  # (Bland: the lowest index among the rows hit at once)
        if not _append_row(A, block, Q, R, nw) > _DEPENDENT * _row_norm(A, block):
            # the blocking row is (to rounding) in the span of the working rows (seen
            # with exact duplicates through one vertex, and with rows 1e-15 from the span
            # on the 8-integrator chain, which later made R singular: a division by zero).
            # Its slope along p is rounding: it does not block
            skip[block] = True
            degenerate += 1
            if degenerate > _STALL:
                return FAILED, x, y, W, nw
            continue
        if dropped[block] and alpha <= 1e-12 * (1.0 + abs(value)):
            # a row dropped at this point blocks at once: in exact arithmetic it cannot
            # (its multiplier was negative), so p is rounding (|p| ~ 4e-10 at pop_mpqp_036's
            # ill-conditioned degenerate vertices, where drop and add alternated for 400
            # pivots): take the point as stationary for the rows left
            stationary = True
            degenerate += 1
            if degenerate > _STALL:
                return FAILED, x, y, W, nw
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
                return FAILED, x, y, W, nw  # cycling all the same: no answer
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
        W[nw] = block  # (Q[nw], R[nw] hold it already: appended above)
        nw += 1
        inW[block] = True
        for i in range(k):
            skip[i] = False
    return FAILED, x, y, W, nw


@njit(cache=True)
def chebyshev(Ar, br, x0, bound, maxit):
    """Largest ball in ``{Ar x <= br}`` (unit rows, the set within ``|x|_inf <= bound``).

    One LP in ``(x, r)``, started from ``x0``; the radius is capped at 1e6.

    Parameters
    ----------
    Ar : (k, d) float64 ndarray
        Unit rows.
    br : (k,) float64 ndarray
    x0 : (d,) float64 ndarray
        A start point (feasible or not: its radius is the smallest slack).
    bound : float
        An upper bound of ``max |x|_inf`` over the set (its rows among ``Ar``).
    maxit : int
        The LP's pivot limit.

    Returns
    -------
    status : int
        ``OPTIMAL`` or another LP outcome.
    centre : (d,) float64 ndarray
    radius : float
    upper : float
        An upper bound of the largest radius by weak duality, whatever the accuracy of
        the LP (inf unless ``OPTIMAL``).
    """
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
    if status == OPTIMAL:
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
def certified_keep(A, b, fixed, centre, bound, maxit):
    """Rows of the bounded polytope ``A x <= b`` (unit rows) to keep: every row not kept
    is proved redundant by multipliers over kept rows (weak duality, residual charged at
    ``bound``). ``fixed`` rows are always kept; ``centre`` is an interior point. An LP that
    gives no answer keeps its row.

    Parameters
    ----------
    A : (k, d) float64 ndarray
        Unit rows.
    b : (k,) float64 ndarray
    fixed : (k,) bool ndarray
        Rows kept whatever their redundancy.
    centre : (d,) float64 ndarray
        An interior point (the LPs' start and the origin of the facet rays).
    bound : float
        An upper bound of ``max |x|_inf`` over the set, at which the residual of the
        dual equation is charged.
    maxit : int
        Each LP's pivot limit.

    Returns
    -------
    (k,) bool ndarray
        The rows kept.
    """
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
        if status != OPTIMAL:
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
            orthonormal_rows(A, basis, nb, Qb, Rb)
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
def project_row(Q, nq, A, j, out):
    """:func:`_project` of the row ``A[j]`` (by index: no view in the hot loops).

    Parameters
    ----------
    Q : (>= nq, n) float64 ndarray
        Orthonormal rows.
    nq : int
        How many rows of ``Q``.
    A : (k, n) float64 ndarray
    j : int
        The row of ``A``.
    out : (>= nq,) float64 ndarray
        Receives ``Q[:nq] A[j]`` in ``out[:nq]``.
    """
    for i in range(nq):
        s = 0.0
        for t in range(A.shape[1]):
            s += Q[i, t] * A[j, t]
        out[i] = s


@njit(cache=True)
def _basis_proves(A, b, B, nb, Q, R, j, bound, beta, y):
    """Whether the rows ``A[B[:nb]] = R Q`` prove ``a_j x <= beta`` with y from
    ``R' y = Q a_j``; ``y`` (>= nb,) is work space."""
    project_row(Q, nb, A, j, y)
    solve_rt(R, y, nb, y)  # in place: each entry is read before it is written
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
        status, centre, rho, _ = chebyshev(Ar, br, np.zeros(d), 1.0, maxit)
        if status != OPTIMAL or not rho >= 0.0:
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
                if status != OPTIMAL:
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


# A caller's cache


def cache_follows(namespace: dict, source: str = __file__) -> None:
    """Make the on-disk cache of the compiled functions defined in ``namespace`` (a
    module's ``globals()``) depend on the file ``source`` (by default this one) as on their
    own.

    numba keeps a function's cached machine code while the function's own file is
    unchanged (its stamp is the file's hash); the compiled functions it calls from other
    files are compiled into it, and their changes go unnoticed (numba issue #1833): the
    mp-QP kernel would go on running an old LP after an edit here. The stamp each cache
    index is checked against becomes the pair (its own stamp, ``source``'s hash), so a
    change to either file renews it. Call at the end of the module, before any of its
    functions is compiled; functions without a disk cache are left alone.

    Parameters
    ----------
    namespace : dict
        The calling module's ``globals()``.
    source : str
        The path of the file whose changes must renew the caches.
    """
    with open(source, "rb") as f:
        digest = hashlib.sha256(f.read()).digest()
    module = namespace["__name__"]
    for fn in list(namespace.values()):
        index = getattr(getattr(fn, "_cache", None), "_cache_file", None)
        if index is None or getattr(fn.py_func, "__module__", None) != module:
            continue
        index._source_stamp = (index._source_stamp, digest)
