"""The completeness check of a polytope's vertices, compiled (numba).

:func:`closed_under_edges` is ``vertices._closed_under_edges`` as a loop: the search tree
checks every region's vertices (13,266 regions of ``pop_mpqp_083``), where Python's
per-region overhead cost ~2 ms a region.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _null_direction(M, m, e, det_tol):
    """A unit vector orthogonal to the ``m`` rows of ``M`` (modified Gram-Schmidt, into
    ``e``); False when a row's distance to the span of the ones before is at most
    ``det_tol`` (never for rows whose smallest singular value exceeds it)."""
    d = M.shape[1]
    Q = np.empty((m, d))
    for r in range(m):
        for t in range(d):
            Q[r, t] = M[r, t]
        for p in range(r):
            g = 0.0
            for t in range(d):
                g += Q[p, t] * Q[r, t]
            for t in range(d):
                Q[r, t] -= g * Q[p, t]
        nrm = 0.0
        for t in range(d):
            nrm += Q[r, t] * Q[r, t]
        nrm = np.sqrt(nrm)
        if nrm <= det_tol:
            return False
        for t in range(d):
            Q[r, t] /= nrm
    # the coordinate vector with the largest part outside the rows' span
    best = -1.0
    keep = 0
    for c in range(d):
        for t in range(d):
            e[t] = 1.0 if t == c else 0.0
        for p in range(m):
            g = Q[p, c]
            for t in range(d):
                e[t] -= g * Q[p, t]
        nrm = 0.0
        for t in range(d):
            nrm += e[t] * e[t]
        if nrm > best:
            best = nrm
            keep = c
    for t in range(d):
        e[t] = 1.0 if t == keep else 0.0
    for _ in range(2):  # twice: re-orthogonalised
        for p in range(m):
            g = 0.0
            for t in range(d):
                g += Q[p, t] * e[t]
            for t in range(d):
                e[t] -= g * Q[p, t]
    nrm = 0.0
    for t in range(d):
        nrm += e[t] * e[t]
    nrm = np.sqrt(nrm)
    for t in range(d):
        e[t] /= nrm
    return True


@njit(cache=True)
def closed_under_edges(V, A, b, tol, det_tol, leave_tol, end_tol):
    """Whether every edge of ``{A x <= b}`` that leaves a vertex of ``V`` ends at a vertex
    of ``V`` (and none is unbounded): ``vertices._closed_under_edges``, compiled.

    The edges at a vertex are the extreme rays of its tangent cone (``T`` its rows tight
    within ``tol``): the direction orthogonal to d - 1 independent rows of ``T`` (either
    sign) that gains at most ``leave_tol`` on every row of ``T``, followed to the first row
    it gains more than ``leave_tol`` on; its end must be within ``end_tol (1 + |end|)``
    of a vertex of ``V``.

    Parameters
    ----------
    V : (v, d) float64 ndarray
        The vertices found.
    A : (k, d) float64 ndarray
        Unit rows.
    b : (k,) float64 ndarray
    tol : float
        A row is tight at a vertex within this slack.
    det_tol : float
        Rows closer than this to the span of others are dependent (no edge from them).
    leave_tol : float
        A direction leaves a row when it gains more than this on it.
    end_tol : float
        An edge's end is a vertex of ``V`` within this fraction of ``1 + |end|``.

    Returns
    -------
    bool
    """
    nv, d = V.shape
    k = A.shape[0]
    slack = np.empty((nv, k))
    for i in range(nv):
        for j in range(k):
            s = b[j]
            for t in range(d):
                s -= A[j, t] * V[i, t]
            slack[i, j] = s
    tight = np.empty(k, dtype=np.int64)
    m = d - 1
    sub = np.empty(max(m, 1), dtype=np.int64)
    M = np.empty((max(m, 1), d))
    e = np.empty(d)
    g = np.empty(k)
    for i in range(nv):
        nt = 0
        for j in range(k):
            if abs(slack[i, j]) <= tol:
                tight[nt] = j
                nt += 1
        if nt < d:
            return False
        for r in range(m):
            sub[r] = r
        while True:
            ok = True
            if m == 0:
                e[0] = 1.0
            else:
                for r in range(m):
                    for t in range(d):
                        M[r, t] = A[tight[sub[r]], t]
                ok = _null_direction(M, m, e, det_tol)
            if ok:
                for sgn in (1.0, -1.0):
                    for j in range(k):
                        s = 0.0
                        for t in range(d):
                            s += A[j, t] * e[t]
                        g[j] = sgn * s
                    ray = True
                    for q in range(nt):
                        if g[tight[q]] > leave_tol:
                            ray = False
                            break
                    if not ray:
                        continue
                    step = np.inf
                    for j in range(k):
                        if g[j] > leave_tol:
                            step = min(step, slack[i, j] / g[j])
                    if step == np.inf:
                        return False  # an unbounded edge
                    wmax = 0.0
                    for t in range(d):
                        wmax = max(wmax, abs(V[i, t] + step * sgn * e[t]))
                    best = np.inf
                    for p in range(nv):
                        gap = 0.0
                        for t in range(d):
                            gap = max(gap, abs(V[i, t] + step * sgn * e[t] - V[p, t]))
                        best = min(best, gap)
                    if best > end_tol * (1.0 + wmax):
                        return False
            if m == 0:
                break
            r = m - 1
            while r >= 0 and sub[r] == nt - m + r:
                r -= 1
            if r < 0:
                break
            sub[r] += 1
            for t in range(r + 1, m):
                sub[t] = sub[t - 1] + 1
    return True
