"""The mp-LP basis graph's per-basis work compiled with numba (``mplp_graph._Search``).

``mplp_graph`` does the same work in numpy, SciPy and DAQP calls: on the paper MPCs
(tens of rows, 3-7 parameters) one basis costs ~4 ms, nearly all of it Python overhead
around microseconds of arithmetic. Here one call does each step:

- :func:`region`: the affine law of a basis, its critical region (slacks of the other
  rows and the parameter set's rows, normalised), its Chebyshev ball, a certified minimal
  representation (``lp_kernel.certified_keep``: a row is dropped only with multipliers
  that prove it redundant) and the Chebyshev centre of every facet inside its hyperplane;
- :func:`settle_once`: one run of the lexicographic dual simplex of
  ``mplp_graph._Search._settle_once``, decision for decision (the same tolerances, the same
  ties, the same order), on the tableau of the rows tight at the point, with rank-1 updates
  of the basis inverse and a fresh factorisation every ``refresh`` pivots;
- :func:`lex_ok`: the explorer's lexicographic optimality test of a basis
  (``mplp._Explorer._lex_state``) from a fresh factorisation.

Whenever a step cannot conclude (a singular basis matrix, an LP without an answer) the
status says so and the caller does that step with the numpy code instead.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from codev_engine.geometry.lp_kernel import OPTIMAL, cache_follows, certified_keep, chebyshev

#: statuses of :func:`region`
FULL, THIN, FALLBACK = 0, 1, 2
#: outcomes of :func:`settle_once`
SETTLED, DRIFTED, INFEASIBLE, SINGULAR, NOT_FEASIBLE, CYCLED, ROUNDING, NO_SETTLE = range(8)
#: a dual is a tie below this times its rounding-error bound (``mplp._TIE``)
_TIE = 1e-14
_CAP = 1e6


@njit(cache=True)
def lu_factor(M):
    """LU factorisation with partial pivoting ``M[perm] = L U`` (L unit lower, in the
    strict lower part of the result, U in its upper part).

    Parameters
    ----------
    M : (n, n) ndarray
        The matrix (not changed).

    Returns
    -------
    LU : (n, n) ndarray
    perm : (n,) int ndarray
    mindiag, maxdiag : float
        Smallest and largest ``|U_ii|`` (NaN entries give ``mindiag`` NaN).
    """
    n = M.shape[0]
    LU = M.copy()
    perm = np.arange(n)
    for j in range(n):
        p = j
        big = abs(LU[j, j])
        for i in range(j + 1, n):
            if abs(LU[i, j]) > big:
                big = abs(LU[i, j])
                p = i
        if p != j:
            for t in range(n):
                tmp = LU[j, t]
                LU[j, t] = LU[p, t]
                LU[p, t] = tmp
            tp = perm[j]
            perm[j] = perm[p]
            perm[p] = tp
        piv = LU[j, j]
        if piv != 0.0:
            for i in range(j + 1, n):
                f = LU[i, j] / piv
                LU[i, j] = f
                if f != 0.0:
                    for t in range(j + 1, n):
                        LU[i, t] -= f * LU[j, t]
    mindiag = np.inf
    maxdiag = 0.0
    for j in range(n):
        v = abs(LU[j, j])
        if not v >= mindiag:
            mindiag = v
        if v > maxdiag:
            maxdiag = v
    return LU, perm, mindiag, maxdiag


@njit(cache=True)
def lu_solve(LU, perm, B):
    """``M X = B`` from :func:`lu_factor`.

    Parameters
    ----------
    LU : (n, n) ndarray
    perm : (n,) int ndarray
        :func:`lu_factor`'s factors of ``M``.
    B : (n, r) ndarray
        The right-hand sides.

    Returns
    -------
    X : (n, r) ndarray
    """
    n, r = B.shape
    X = np.empty((n, r))
    for c in range(r):
        for i in range(n):
            s = B[perm[i], c]
            for t in range(i):
                s -= LU[i, t] * X[t, c]
            X[i, c] = s
        for i in range(n - 1, -1, -1):
            s = X[i, c]
            for t in range(i + 1, n):
                s -= LU[i, t] * X[t, c]
            X[i, c] = s / LU[i, i]
    return X


@njit(cache=True)
def lu_solve_t(LU, perm, b):
    """``M' y = b`` from :func:`lu_factor`.

    Parameters
    ----------
    LU : (n, n) ndarray
    perm : (n,) int ndarray
        :func:`lu_factor`'s factors of ``M``.
    b : (n,) ndarray
        The right-hand side.

    Returns
    -------
    y : (n,) ndarray
    """
    n = b.size
    z = np.empty(n)
    for i in range(n):  # U' z = b
        s = b[i]
        for t in range(i):
            s -= LU[t, i] * z[t]
        z[i] = s / LU[i, i]
    v = np.empty(n)
    for i in range(n - 1, -1, -1):  # L' v = z
        s = z[i]
        for t in range(i + 1, n):
            s -= LU[t, i] * v[t]
        v[i] = s
    y = np.empty(n)
    for i in range(n):
        y[perm[i]] = v[i]
    return y


@njit(cache=True)
def _factor(G, B):
    """The basis matrix ``G[B]`` factorised, and whether it is well enough conditioned
    (``mplp_graph._Search._lu``)."""
    nw = B.size
    GB = np.empty((nw, G.shape[1]))
    for q in range(nw):
        GB[q] = G[B[q]]
    LU, perm, mn, mx = lu_factor(GB)
    ok = np.all(np.isfinite(LU)) and mn > 1e-12 * max(1.0, mx)
    return LU, perm, ok


@njit(cache=True)
def lex_ok(G, c, pert, B, cmag):
    """Whether the basis ``B`` is lexicographically optimal for ``(c, pert)``: the
    explorer's ``_lex_state`` and ``_lex_negative`` at a parameter-free cost, from a fresh
    factorisation.

    Parameters
    ----------
    G : (m, nw) ndarray
        The LP's constraint rows.
    c : (nw,) ndarray
        The cost.
    pert : (nw,) ndarray
        The lexicographic perturbation of the cost.
    B : (nw,) int ndarray
        The basis: rows of ``G``.
    cmag : float
        The cost's magnitude (the scale of the tie tolerance).

    Returns
    -------
    bool
    """
    nw = B.size
    GB = np.empty((nw, G.shape[1]))
    for q in range(nw):
        GB[q] = G[B[q]]
    LU, perm, mn, _ = lu_factor(GB)
    if not np.all(np.isfinite(LU)) or mn == 0.0:
        return False
    d0 = lu_solve_t(LU, perm, -c)
    d1 = lu_solve_t(LU, perm, -pert)
    Binv = lu_solve(LU, perm, np.eye(nw))
    u = np.abs(c) + np.abs(GB.T) @ np.abs(d0)
    err0 = np.abs(Binv.T) @ u
    ptol = 1e-9 * np.max(np.abs(pert))
    for q in range(nw):
        tie = abs(d0[q]) <= min(_TIE * (err0[q] + cmag), 1e-9 * cmag)
        if (not tie and d0[q] < 0) or (tie and d1[q] < -ptol):
            return False
    return True


@njit(cache=True)
def settle_once(G, c, pert, w, S, B, theta, a, zero, cmag, refresh, maxit):
    """One run of the lexicographic dual simplex of ``mplp_graph._Search._settle_once``
    from the basis ``B`` at ``theta`` along ``a`` (zeros: none).

    Parameters
    ----------
    G : (m, nw) ndarray
        The LP's constraint rows ``G z <= w + S theta``.
    c, pert : (nw,) ndarray
        The cost and its lexicographic perturbation.
    w : (m,) ndarray
    S : (m, d) ndarray
        The right-hand side's offset and parameter matrix.
    B : (nw,) int ndarray
        The starting basis.
    theta : (d,) ndarray
        The parameter.
    a : (d,) ndarray
        A direction in parameter space: ties are broken as at ``theta + eps a`` (the
        right-hand side perturbed by ``S a``; zeros: no direction).
    zero : float
        A slack below this is zero.
    cmag : float
        The cost's magnitude (the scale of the tie tolerance).
    refresh : int
        Rank-1 updates of the basis inverse between fresh factorisations.
    maxit : int
        Pivots before giving up (cycling).

    Returns
    -------
    status : int
        ``SETTLED`` (no row left to enter), ``DRIFTED`` (rounding made a dual negative:
        start again from the basis returned, freshly factorised), ``INFEASIBLE`` (the LP
        is infeasible past ``theta``) or a reason the step is not exact.
    B : (nw,) int ndarray
        The basis reached (unsorted).
    pivots : int
    """
    m, nw = G.shape
    h = w + S @ theta
    ha = S @ a
    LU, perm, ok = _factor(G, B)
    if not ok:
        return SINGULAR, B, 0
    hB = np.empty((nw, 1))
    for q in range(nw):
        hB[q, 0] = h[B[q]]
    x = lu_solve(LU, perm, hB)[:, 0].copy()
    s = h - G @ x
    inB = np.zeros(m, dtype=np.bool_)
    for q in range(nw):
        inB[B[q]] = True
    ntight = 0
    for g in range(m):
        if inB[g]:
            continue
        if s[g] < -1e3 * zero:
            return NOT_FEASIBLE, B, 0
        if s[g] <= zero:
            ntight += 1
    if ntight == 0:
        return SETTLED, B, 0
    nT = nw + ntight
    T = np.empty(nT, dtype=np.int64)
    for q in range(nw):
        T[q] = B[q]
    j = nw
    for g in range(m):
        if not inB[g] and s[g] <= zero:
            T[j] = g
            j += 1
    GT = np.empty((nT, G.shape[1]))
    for q in range(nT):
        GT[q] = G[T[q]]
    Binv = lu_solve(LU, perm, np.eye(nw))
    M = GT @ Binv
    for q in range(nw):
        for t in range(nw):
            M[q, t] = 1.0 if q == t else 0.0
    pos_of = np.full(nT, -1, dtype=np.int64)
    Bloc = np.arange(nw)
    for q in range(nw):
        pos_of[q] = q
    d0 = -(c @ Binv)
    d1 = -(pert @ Binv)
    cap = 1e-9 * cmag
    absc = np.abs(c)
    haT = np.empty(nT)
    for q in range(nT):
        haT[q] = ha[T[q]]
    seen = np.empty((maxit, nw), dtype=np.int64)
    nseen = 0
    since = 0
    pivots = 0
    rowsB = np.empty(nw, dtype=np.int64)
    al = np.empty(nw)
    thr = np.empty(nw)
    for _ in range(maxit):
        for q in range(nw):
            rowsB[q] = T[Bloc[q]]
        if since >= refresh:
            since = 0
            LU, perm, ok = _factor(G, rowsB)
            if not ok:
                return SINGULAR, rowsB.copy(), pivots
            Binv = lu_solve(LU, perm, np.eye(nw))
            M = GT @ Binv
            for q in range(nw):
                for t in range(nw):
                    M[Bloc[q], t] = 1.0 if q == t else 0.0
            d0 = -(c @ Binv)
            d1 = -(pert @ Binv)
        since += 1
        key = np.sort(rowsB)
        for v in range(nseen):
            same = True
            for q in range(nw):
                if seen[v, q] != key[q]:
                    same = False
                    break
            if same:
                return CYCLED, rowsB.copy(), pivots
        seen[nseen] = key
        nseen += 1
        # the row to enter: the most negative derivative, else the lowest-numbered
        # eps-negative row (the first basis row with a nonzero coefficient decides)
        hB0 = np.empty(nw)
        for q in range(nw):
            hB0[q] = haT[Bloc[q]]
        best = np.inf
        kk = -1
        negd_k = False
        for g in range(nT):
            if pos_of[g] >= 0:
                continue
            der = haT[g]
            acc = 0.0
            for q in range(nw):
                der -= M[g, q] * hB0[q]
                acc += abs(M[g, q]) * abs(hB0[q])
            dtol = 1e-9 * (abs(haT[g]) + acc + 1e-3)
            if der < -dtol and der < best:
                best = der
                kk = g
        if kk >= 0:
            negd_k = True
        else:
            lowT = m + 1
            for g in range(nT):
                if pos_of[g] >= 0:
                    continue
                der = haT[g]
                acc = 0.0
                mx = 0.0
                for q in range(nw):
                    der -= M[g, q] * hB0[q]
                    acc += abs(M[g, q]) * abs(hB0[q])
                    if abs(M[g, q]) > mx:
                        mx = abs(M[g, q])
                dtol = 1e-9 * (abs(haT[g]) + acc + 1e-3)
                if not abs(der) <= dtol:
                    continue
                lim = 1e-9 * max(mx, 1.0)
                lowB = m
                first = -1
                for q in range(nw):
                    if abs(M[g, q]) > lim and rowsB[q] < lowB:
                        lowB = rowsB[q]
                        first = q
                if first < 0 or not lowB < T[g] or not M[g, first] > 0:
                    continue
                if T[g] < lowT:
                    lowT = T[g]
                    kk = g
            if kk < 0:
                return SETTLED, rowsB.copy(), pivots
        k = kk
        amax = 0.0
        for q in range(nw):
            al[q] = M[k, q]
            if abs(al[q]) > amax:
                amax = abs(al[q])
        lim = 1e-9 * max(1.0, amax)
        npos = 0
        for q in range(nw):
            if abs(al[q]) <= lim:
                al[q] = 0.0
            if al[q] > 0:
                npos += 1
        if npos == 0:
            if negd_k:
                return INFEASIBLE, rowsB.copy(), pivots
            return ROUNDING, rowsB.copy(), pivots
        # ties: the explorer's rule, from the updated inverse
        u = absc.copy()
        for t in range(nw):
            acc = 0.0
            for q in range(nw):
                acc += abs(G[rowsB[q], t]) * abs(d0[q])
            u[t] += acc
        for q in range(nw):
            e = 0.0
            for t in range(nw):
                e += abs(Binv[t, q]) * u[t]
            thr[q] = min(_TIE * (e + cmag), cap)
            if abs(d0[q]) <= thr[q]:
                d0[q] = 0.0
        for q in range(nw):
            if d0[q] < 0:
                return DRIFTED, rowsB.copy(), pivots
        rmin = np.inf
        for q in range(nw):
            if al[q] > 0:
                r0 = d0[q] / al[q]
                if r0 < rmin:
                    rmin = r0
        i = -1
        bestr = np.inf
        for q in range(nw):
            if al[q] > 0 and d0[q] - rmin * al[q] <= thr[q]:
                r1 = d1[q] / al[q]
                if r1 < bestr:
                    bestr = r1
                    i = q
        if rmin == 0.0 and d1[i] < 0:
            return DRIFTED, rowsB.copy(), pivots
        pivots += 1
        t0 = rmin
        t1 = d1[i] / al[i]
        for q in range(nw):
            d0[q] -= t0 * al[q]
            d1[q] -= t1 * al[q]
        d0[i] = t0
        d1[i] = t1
        ai = al[i]
        for g in range(nT):
            cg = M[g, i] / ai
            for q in range(nw):
                M[g, q] -= cg * al[q]
            M[g, i] = cg
        for t in range(nw):
            cg = Binv[t, i] / ai
            for q in range(nw):
                Binv[t, q] -= cg * al[q]
            Binv[t, i] = cg
        pos_of[Bloc[i]] = -1
        pos_of[k] = i
        Bloc[i] = k
    for q in range(nw):
        rowsB[q] = T[Bloc[q]]
    return NO_SETTLE, rowsB.copy(), pivots


@njit(cache=True)
def _ball_holds(A, b, x, rho, upper, region_tol):
    """Whether the LP's ball (centre ``x``, radius ``rho``) is what it says (every unit
    row's slack at ``x`` is ``rho`` or more, to rounding) and its verdict against
    ``region_tol`` is proved (a radius at or below it only with an upper bound at or below
    it too): else the caller asks another solver."""
    low = _CAP
    for i in range(A.shape[0]):
        s = b[i]
        for t in range(A.shape[1]):
            s -= A[i, t] * x[t]
        if s < low:
            low = s
    if not abs(low - rho) <= 1e-9 * (1.0 + abs(rho)):
        return False
    return rho > region_tol or upper <= region_tol


@njit(cache=True)
def _facet_ball(A, b, kept, j, centre, bound, region_tol, maxit):
    """Chebyshev ball of facet ``j`` of ``{A x <= b}`` (the kept rows, unit) inside its
    hyperplane, each row's norm that of its part in the hyperplane (as
    ``polytope.chebyshev_ball`` with an equality); radius -inf when empty, NaN when the
    LP gave no answer."""
    k, d = A.shape
    a = A[j]
    beta = b[j]
    out = np.empty(d)
    if d == 1:
        for i in range(k):
            if i != j and kept[i]:
                if b[i] - beta * A[i, 0] * a[0] < -1e-9 * (1.0 + abs(b[i])):
                    return out, -np.inf
        out[0] = beta * a[0]
        return out, _CAP
    # an orthonormal basis N (d, d - 1) of the hyperplane's directions (Householder)
    p = 0
    for t in range(d):
        if abs(a[t]) > abs(a[p]):
            p = t
    u = a.copy()
    u[p] += 1.0 if a[p] >= 0 else -1.0
    uu = 0.0
    for t in range(d):
        uu += u[t] * u[t]
    N = np.empty((d, d - 1))
    col = 0
    for e in range(d):
        if e == p:
            continue
        for t in range(d):
            N[t, col] = (1.0 if t == e else 0.0) - 2.0 * u[t] * u[e] / uu
        col += 1
    rows = np.empty((k, d - 1))
    rhs = np.empty(k)
    n = 0
    for i in range(k):
        if i == j or not kept[i]:
            continue
        aa = 0.0
        for t in range(d):
            aa += A[i, t] * a[t]
        ci = b[i] - beta * aa
        nrm = 0.0
        for q in range(d - 1):
            v = 0.0
            for t in range(d):
                v += A[i, t] * N[t, q]
            rows[n, q] = v
            nrm += v * v
        nrm = np.sqrt(nrm)
        if nrm <= 1e-12:
            if ci < -1e-9 * (1.0 + abs(b[i])):
                return out, -np.inf
            continue
        for q in range(d - 1):
            rows[n, q] /= nrm
        rhs[n] = ci / nrm
        n += 1
    if n == 0:
        for t in range(d):
            out[t] = beta * a[t]
        return out, _CAP
    y0 = np.zeros(d - 1)
    for q in range(d - 1):
        for t in range(d):
            y0[q] += N[t, q] * (centre[t] - beta * a[t])
    status, y, rho, upper = chebyshev(
        rows[:n].copy(), rhs[:n].copy(), y0, 2.0 * np.sqrt(d) * bound, maxit
    )
    if status != OPTIMAL or not _ball_holds(rows[:n], rhs[:n], y, rho, upper, region_tol):
        return out, np.nan
    for t in range(d):
        s = beta * a[t]
        for q in range(d - 1):
            s += N[t, q] * y[q]
        out[t] = s
    return out, rho


@njit(cache=True)
def region(G, w, S, At, bt, B, zero, region_tol, bound, x0, maxit):
    """The critical region of basis ``B`` (``mplp_graph._Search._region``) and the
    Chebyshev centres of its facets.

    Parameters
    ----------
    G : (m, nw) ndarray
    w : (m,) ndarray
    S : (m, d) ndarray
    At : (p, d) ndarray
    bt : (p,) ndarray
        The parameter set.
    B : (nw,) int ndarray
        Sorted.
    zero : float
        A slack below this is zero.
    region_tol : float
    bound : float
        Of ``|theta|_inf`` over the parameter set.
    x0 : (d,) ndarray
        A start point of the Chebyshev LP.
    maxit : int

    Returns
    -------
    status : int
        ``FULL``, ``THIN`` (thinner than ``region_tol``) or ``FALLBACK``.
    K : (nw, d) ndarray
    k0 : (nw,) ndarray
    A : (r, d) ndarray
    b : (r,) ndarray
    mark : (r,) bool ndarray
        The parameter set's rows.
    fc : (r, d) ndarray
    frho : (r,) ndarray
        Centre and radius of each facet (radius -inf: not a facet; NaN: no answer; only
        for the rows not marked).
    """
    m, nw = G.shape
    d = S.shape[1]
    p = At.shape[0]
    e0 = np.empty((0, d))
    e1 = np.empty(0)
    eb = np.empty(0, dtype=np.bool_)
    LU, perm, ok = _factor(G, B)
    if not ok:
        return FALLBACK, np.empty((nw, d)), np.empty(nw), e0, e1, eb, e0, e1
    rhs = np.empty((nw, d + 1))
    for q in range(nw):
        rhs[q, 0] = w[B[q]]
        for t in range(d):
            rhs[q, t + 1] = S[B[q], t]
    Z = lu_solve(LU, perm, rhs)
    k0 = Z[:, 0].copy()
    K = Z[:, 1:].copy()
    inB = np.zeros(m, dtype=np.bool_)
    for q in range(nw):
        inB[B[q]] = True
    Ar = np.empty((m + p, d))
    br = np.empty(m + p)
    mark = np.zeros(m + p, dtype=np.bool_)
    n = 0
    for g in range(m):
        if inB[g]:
            continue
        mx = 0.0
        for t in range(d):
            v = -S[g, t]
            for q in range(nw):
                v += G[g, q] * K[q, t]
            Ar[n, t] = v
            if abs(v) > mx:
                mx = abs(v)
        v = w[g]
        for q in range(nw):
            v -= G[g, q] * k0[q]
        br[n] = v
        if mx <= 1e-10 and abs(v) <= 1e3 * zero:
            continue  # identically zero slack
        n += 1
    for i in range(p):
        for t in range(d):
            Ar[n, t] = At[i, t]
        br[n] = bt[i]
        mark[n] = True
        n += 1
    r = 0
    for i in range(n):
        nrm = 0.0
        for t in range(d):
            nrm += Ar[i, t] * Ar[i, t]
        nrm = np.sqrt(nrm)
        if nrm <= 1e-12:
            if br[i] < -1e3 * zero:
                return THIN, K, k0, e0, e1, eb, e0, e1
            continue
        for t in range(d):
            Ar[r, t] = Ar[i, t] / nrm
        br[r] = br[i] / nrm
        mark[r] = mark[i]
        r += 1
    A = Ar[:r].copy()
    b = br[:r].copy()
    mk = mark[:r].copy()
    status, centre, radius, upper = chebyshev(A, b, x0, bound, maxit)
    if status != OPTIMAL or not _ball_holds(A, b, centre, radius, upper, region_tol):
        return FALLBACK, K, k0, e0, e1, eb, e0, e1
    if not radius > region_tol:
        return THIN, K, k0, e0, e1, eb, e0, e1
    kept = certified_keep(A, b, np.zeros(r, dtype=np.bool_), centre, bound, maxit)
    nk = 0
    for i in range(r):
        if kept[i]:
            nk += 1
    fc = np.zeros((nk, d))
    frho = np.full(nk, -np.inf)
    Ak = np.empty((nk, d))
    bk = np.empty(nk)
    mkk = np.empty(nk, dtype=np.bool_)
    j = 0
    for i in range(r):
        if kept[i]:
            Ak[j] = A[i]
            bk[j] = b[i]
            mkk[j] = mk[i]
            j += 1
    allk = np.ones(nk, dtype=np.bool_)
    for j in range(nk):
        if mkk[j]:
            continue
        ctr, rho = _facet_ball(Ak, bk, allk, j, centre, bound, region_tol, maxit)
        fc[j] = ctr
        frho[j] = rho
    return FULL, K, k0, Ak, bk, mkk, fc, frho


# the LP of geometry/lp_kernel is compiled into the functions above: their disk cache is
# renewed when that file changes too
cache_follows(globals())
