"""The mp-QP candidate evaluation compiled with numba: KKT, Chebyshev ball and a certified
minimal representation, on the compiled LP of ``geometry/lp_kernel``.

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
"""

from __future__ import annotations

import numpy as np
from numba import njit

from codev_engine.geometry.lp_kernel import (
    OPTIMAL,
    cache_follows,
    certified_keep,
    chebyshev,
    orthonormal_rows,
    project_row,
    solve_rt,
)

#: statuses returned by ``evaluate``
LICQ, EMPTY, LOWER, FULL, FALLBACK = 0, 1, 2, 3, 4
#: an inactive row this close to the span of the active rows (unit rows) has its slack from
#: that dependency (``mpqp.DEPENDENT_SLACK``, the same)
DEPENDENT_SLACK = 1e-9
#: a row vanishes for every theta below this many ulps of its terms (``mpqp.VANISH_ULPS``)
VANISH_ULPS = 64.0
#: their names in ``mpqp._Kernel.evaluate_numpy`` (FALLBACK: it has none, it concludes)
STATUS_NAMES = {LICQ: "licq", EMPTY: "empty", LOWER: "lower", FULL: "full"}


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



@njit(cache=True, nogil=True)
def evaluate(
    act, start, G, M, Dfull, negZ0, Hinv_Gt, H, rhs_z, wS, At, bt, box_c, box_h, scale,
    region_tol, nonempty_tol, ill_conditioned, maxit, close,
):
    """One candidate active set ``act`` (sorted int64): see ``mpqp._Kernel.evaluate``.
    ``start`` (d,) is where the Chebyshev LP starts: any point will do, one near the
    region saves pivots (the walk passes the centre of the region that led here: about
    14 pivots instead of 25 from the centre of the parameter box).

    The problem is ``min 0.5 z'Hz + (c + C theta)'z s.t. G z <= w + S theta, At theta <=
    bt`` (``mpqp.explore_active_sets``); its precomputed products are those of
    ``mpqp._Kernel``, every array float64 and C-contiguous but ``act``.

    Parameters
    ----------
    act : (na,) int64 ndarray
        The candidate active set, ascending.
    start : (d,) float64 ndarray
        Where the Chebyshev LP starts.
    G : (m, nz) ndarray
        Constraint rows, unit norm.
    M : (m, m) ndarray
        ``G H^-1 G'``.
    Dfull : (m, d + 1) ndarray
        ``d(theta) = w + S theta + G H^-1 (c + C theta)`` as columns (constant, theta).
    negZ0 : (nz, d + 1) ndarray
        ``-H^-1 (c + C theta)`` as columns (constant, theta).
    Hinv_Gt : (nz, m) ndarray
        ``H^-1 G'``.
    H : (nz, nz) ndarray
        The Hessian (for the augmented KKT system of ill-conditioned active sets).
    rhs_z : (nz, d + 1) ndarray
        ``-(c + C theta)`` as columns (constant, theta).
    wS : (m, d + 1) ndarray
        ``w + S theta`` as columns (constant, theta).
    At : (p, d) ndarray
    bt : (p,) ndarray
        The parameter set ``At theta <= bt``.
    box_c, box_h : (d,) ndarrays
        Centre and half-widths of a box containing the parameter set (``mpqp._padded_box``).
    scale : float
        Size of the parameter set (tolerances are relative to it).
    region_tol : float
        A region is FULL only with a verified inscribed ball of radius above this.
    nonempty_tol : float
        A region is EMPTY only with a proved radius bound below ``-nonempty_tol``.
    ill_conditioned : float
        Estimated condition number of ``M_AA`` above which the augmented KKT system
        gives the multipliers and the law.
    maxit : int
        The LPs' pivot limit.
    close : float
        ``mpqp.CLOSE_CALL``: FULL needs a ball above ``close * region_tol``, LOWER a radius
        bound below ``region_tol / close``; the close calls between are FALLBACK (the numpy
        kernel decides them from the active set alone: here the LP's result depends on
        ``start``).

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
    if na and orthonormal_rows(G, act, na, Qb, Rb) < 1e-9:
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
    # the magnitudes of each row's terms (constant, theta): its rounding (VANISH_ULPS);
    # the multipliers share the largest one's (one solve)
    big = np.zeros(d + 1)
    for i in range(na):
        for u in range(d + 1):
            big[u] = max(big[u], abs(Lam[i, u]))
    magc = np.zeros(nr)
    magt = np.zeros(nr)
    bigt = 0.0
    for t in range(d):
        bigt += big[t + 1] * big[t + 1]
    for i in range(na):
        for t in range(d):
            Ar[i, t] = -Lam[i, t + 1]
        br[i] = Lam[i, 0]
        src[i] = act[i] + 1
        magc[i] = big[0]
        magt[i] = np.sqrt(bigt)
    row = np.empty(d + 1)
    mrow = np.empty(d + 1)
    # the optimizer's columns, for the slacks of rows in the span of the active ones
    Zdep = Zaug if augmented else _law(negZ0, Hinv_Gt, act, Lam) if na else Zaug
    qv = np.empty(na)
    cv = np.empty(na)
    rv = np.empty(nz)
    for q in range(ni):
        iq = inact[q]
        if na and _dependent(G, iq, Qb, na, qv, rv):
            # g_i = G_A' c + r: the slack from the dependency, not from the multipliers
            # (mpqp._Kernel._dependent_slacks: they lose ~1e-7 where they are huge)
            solve_rt(Rb, qv, na, cv)
            for s in range(d + 1):
                row[s] = wS[iq, s]
                mrow[s] = abs(wS[iq, s])
            for i in range(na):
                for s in range(d + 1):
                    row[s] -= cv[i] * wS[act[i], s]
                    mrow[s] += abs(cv[i] * wS[act[i], s])
            for t in range(nz):
                for s in range(d + 1):
                    row[s] -= rv[t] * Zdep[t, s]
                    mrow[s] += abs(rv[t] * Zdep[t, s])
        elif augmented:
            # slack = w + S theta - G z
            for s in range(d + 1):
                row[s] = wS[iq, s]
                mrow[s] = abs(wS[iq, s])
            for t in range(nz):
                g = G[iq, t]
                for s in range(d + 1):
                    row[s] -= g * Zaug[t, s]
                    mrow[s] += abs(g * Zaug[t, s])
        else:
            for s in range(d + 1):
                row[s] = Dfull[iq, s]
                mrow[s] = abs(Dfull[iq, s])
            for i in range(na):
                coef = abs(M[act[i], iq])
                for s in range(d + 1):
                    row[s] += M[act[i], iq] * Lam[i, s]
                    mrow[s] += coef * (abs(Lam[i, s]) + big[s])
        for t in range(d):
            Ar[na + q, t] = -row[t + 1]
        br[na + q] = row[0]
        src[na + q] = -(iq + 1)
        magc[na + q] = mrow[0]
        mt = 0.0
        for t in range(d):
            mt += mrow[t + 1] * mrow[t + 1]
        magt[na + q] = np.sqrt(mt)
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
    ulp = VANISH_ULPS * np.finfo(np.float64).eps
    for i in range(nr):
        s = 0.0
        for t in range(d):
            s += Ar[i, t] * Ar[i, t]
        s = np.sqrt(s)
        if s <= max(1e-12, ulp * magt[i]):
            if br[i] < -max(1e-12, ulp * magc[i]):
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
    status, centre, rho, upper = chebyshev(Am, bm, start, bound, maxit)
    if status != OPTIMAL:
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
    # a close call (a thin region: its radius near the region tolerance) is not decided
    # here: from one start the LP proves it full, from another it proves nothing, and its
    # class (kept or not) and its neighbours would follow the walk's order
    if upper > region_tol / close and true_rho <= close * region_tol:
        return FALLBACK, e2, e1, ez, ek, em, True, es, start
    if upper <= region_tol / close:
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
    if true_rho <= close * region_tol or rho < -nonempty_tol:
        return FALLBACK, e2, e1, ez, ek, em, True, es, start
    sm = src[maybe]
    fixed = sm == 0
    kept = certified_keep(Am, bm, fixed, centre, bound, maxit)
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
    Z = Zaug if augmented else Zdep if na else _law(negZ0, Hinv_Gt, act, Lam)  # (above)
    if na:
        Z = _refined(Z, Lam, act, G, H, rhs_z, wS)
    return FULL, Ak, bk, Z[:, 1:].copy(), Z[:, 0].copy(), moves, True, swaps, centre


@njit(cache=True)
def _refined(Z, Lam, act, G, H, rhs_z, wS):
    """The law ``Z`` (nz, d + 1) after one step of iterative refinement on the KKT system
    of the active set ``act`` (``mpqp._Kernel._refined``: its active constraints then
    hold to the rounding of their own terms, whatever the multipliers' size)."""
    nz, k = Z.shape
    na = act.size
    Kkt = np.zeros((nz + na, nz + na))
    Kkt[:nz, :nz] = H
    r = np.empty((nz + na, k))
    for t in range(nz):
        for s in range(k):
            v = rhs_z[t, s]
            for u in range(nz):
                v -= H[t, u] * Z[u, s]
            for i in range(na):
                v -= G[act[i], t] * Lam[i, s]
            r[t, s] = v
    for i in range(na):
        for t in range(nz):
            Kkt[t, nz + i] = G[act[i], t]
            Kkt[nz + i, t] = G[act[i], t]
        for s in range(k):
            v = wS[act[i], s]
            for t in range(nz):
                v -= G[act[i], t] * Z[t, s]
            r[nz + i, s] = v
    X = np.linalg.solve(Kkt, r)
    return Z + X[:nz]


@njit(cache=True)
def _law(negZ0, Hinv_Gt, act, Lam):
    """The optimizer's columns (constant, theta): ``z = -H^-1 (c + C theta) - H^-1 G_A'
    lambda_A(theta)``, (nz, d + 1)."""
    Z = negZ0.copy()
    for i in range(act.size):
        for t in range(Z.shape[0]):
            h = Hinv_Gt[t, act[i]]
            for s in range(Z.shape[1]):
                Z[t, s] -= h * Lam[i, s]
    return Z


@njit(cache=True)
def _dependent(G, i, Q, na, q, r):
    """Whether the unit row ``G[i]`` lies within ``DEPENDENT_SLACK`` of the span of the
    orthonormal rows ``Q[:na]``; its coordinates ``q`` (na,) and the residual ``r`` (nz,)
    written in place."""
    project_row(Q, na, G, i, q)
    res = 0.0
    for t in range(G.shape[1]):
        v = G[i, t]
        for l in range(na):
            v -= q[l] * Q[l, t]
        r[t] = v
        res += v * v
    return res < DEPENDENT_SLACK * DEPENDENT_SLACK


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
        project_row(Q, na, G, i, q)
        res = 0.0
        for t in range(nz):
            v = G[i, t]
            for l in range(na):
                v -= q[l] * Q[l, t]
            res += v * v
        if np.sqrt(res) >= 1e-9:
            continue  # A + i keeps LICQ: the plain move
        solve_rt(R, q, na, c)
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


# Batches of candidates, as ``active_sets`` walks them. They live here, with ``evaluate``:
# numba's on-disk cache of a function is renewed when its own file changes, not when a
# function it calls from another file does (see ``cache_follows`` at the end).

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
    """Active sets of bitmasks: bit ``i`` of the words of a key set for constraint i.

    Parameters
    ----------
    keys : (B, W) uint64 ndarray
        The bitmasks.
    width : int
        Entries per row of the result (a set's constraints past ``width`` are counted in
        its size but not listed).

    Returns
    -------
    acts : (B, width) int64 ndarray
        Each set's constraint ids, ascending, padded with -1.
    sizes : (B,) int64 ndarray
        Each set's size.
    """
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
    ``start`` from ``starts`` (B, d), in one call. A candidate that falls back is
    evaluated once more from the centre of the parameter box.

    Parameters
    ----------
    keys : (B, W) uint64 ndarray
        The candidates' bitmasks (``active_sets.ActiveSetGraph``).
    starts : (B, d) float64 ndarray
        Where each candidate's Chebyshev LP starts.
    args : tuple
        ``evaluate``'s parameters after ``act`` and ``start``, in its order.

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


# the LP of geometry/lp_kernel is compiled into the functions above: their disk cache is
# renewed when that file changes too
cache_follows(globals())
