"""The point locator's grid, built by a compiled loop (numba).

Listing a region in the cells of its bounding box that none of its rows separates from it
is a loop over ragged boxes (a few to 4096 cells each) and ragged rows; in numpy it was a
meshgrid per region, ~90 us of overhead each (48 s on ``pop_mpqp_024``'s 430,000 regions).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def cell_lists(A, b, off, regs, clo, chi, origin, cell, tol, g):
    """The regions ``regs`` listed in the cells of a grid of ``g`` cells per axis.

    Region ``r`` is entered in each cell ``clo[r] <= c <= chi[r]`` (by axis) unless one of
    its rows ``A[off[r]:off[r + 1]] x <= b[...]`` (unit rows) exceeds ``tol`` at every point
    of the cell. The cell of index vector ``c`` is number ``sum(c[t] g^t)``.

    Parameters
    ----------
    A : (N, d) ndarray
    b : (N,) ndarray
    off : (R + 1,) int ndarray
    regs : (q,) int ndarray
        Ascending.
    clo, chi : (R, d) int ndarrays
        Each region's first and last cell on each axis.
    origin, cell : (d,) ndarrays
        The grid's lower corner and cell size.
    tol : float
    g : int

    Returns
    -------
    start : (g^d + 1,) int ndarray
    cands : (start[-1],) int ndarray
        Cell ``c`` lists ``cands[start[c]:start[c + 1]]``, ascending.
    """
    d = A.shape[1]
    half = 0.5 * cell
    ncell = g**d
    strides = np.empty(d, dtype=np.int64)
    s = 1
    for t in range(d):
        strides[t] = s
        s *= g
    # the cells entered, region after region (``first[q]``: region ``regs[q]``'s first),
    # in a buffer doubled when full
    cap = max(1024, 16 * regs.size)
    ent = np.empty(cap, dtype=np.int64)
    first = np.empty(regs.size + 1, dtype=np.int64)
    n = 0
    idx = np.empty(d, dtype=np.int64)
    centre = np.empty(d)
    for q in range(regs.size):
        r = regs[q]
        first[q] = n
        for t in range(d):
            idx[t] = clo[r, t]
        while True:
            for t in range(d):
                centre[t] = origin[t] + (idx[t] + 0.5) * cell[t]
            meets = True
            for j in range(off[r], off[r + 1]):
                low = 0.0
                for t in range(d):
                    low += A[j, t] * centre[t] - abs(A[j, t]) * half[t]
                if low > b[j] + tol:
                    meets = False
                    break
            if meets:
                if n == cap:
                    cap *= 2
                    grown = np.empty(cap, dtype=np.int64)
                    grown[:n] = ent[:n]
                    ent = grown
                c = 0
                for t in range(d):
                    c += idx[t] * strides[t]
                ent[n] = c
                n += 1
            # the next cell of the box (an odometer over its axes)
            t = 0
            while t < d:
                idx[t] += 1
                if idx[t] <= chi[r, t]:
                    break
                idx[t] = clo[r, t]
                t += 1
            if t == d:
                break
    first[regs.size] = n
    # a counting sort by cell keeps each cell's regions in region order
    start = np.zeros(ncell + 1, dtype=np.int64)
    for e in range(n):
        start[ent[e] + 1] += 1
    for c in range(ncell):
        start[c + 1] += start[c]
    pos = start[:ncell].copy()
    cands = np.empty(n, dtype=np.int64)
    for q in range(regs.size):
        for e in range(first[q], first[q + 1]):
            cands[pos[ent[e]]] = regs[q]
            pos[ent[e]] += 1
    return start, cands


@njit(cache=True)
def walk(X, pts, origin, cell, g, start, cands, A, b, off, implied, sv, tol, out, best):
    """Offer each point ``X[p]``, ``p`` in ``pts``, the regions its cell lists (see
    :func:`cell_lists`), and keep in ``out[p]`` / ``best[p]`` (its largest violation) the
    one that wins by the rule of ``locate.PointLocator.locate``: held (largest violation
    <= 0) beats near (<= ``tol``), then the lower index among held, the smaller violation
    among near (the lower index on ties).

    A region's violation is the largest of its rows ``A[off[r]:off[r + 1]] x - b`` (-1
    without rows), and of ``sv[p]`` (the point's violation of the shared rows) where
    ``implied[r]``. A cell's list ascends, so past the first region that holds the point
    none of them can win.

    Parameters
    ----------
    X : (P, d) float64 ndarray
        The points, C-contiguous.
    pts : (q,) int64 ndarray
        The rows of ``X`` to locate (inside the grid's box).
    origin, cell : (d,) float64 ndarrays
        The grid's lower corner and cell size.
    g : int
        Cells per axis.
    start, cands : int64 ndarrays
        The grid's cell lists, from :func:`cell_lists`.
    A : (N, d) float64 ndarray
        Every region's rows, region after region.
    b : (N,) float64 ndarray
    off : (R + 1,) int64 ndarray
        Region ``r``'s rows are ``off[r]:off[r + 1]``.
    implied : (R,) bool ndarray
        Which regions include the shared rows.
    sv : (P,) float64 ndarray
        Each point's largest violation of the shared rows (zeros without them).
    tol : float
        How far outside a region a point is still near it.
    out : (P,) int ndarray
        The region found so far per point (-1: none); updated in place.
    best : (P,) float64 ndarray
        The violation of ``out``'s region per point (inf: none); updated in place.
    """
    d = X.shape[1]
    for p in pts:
        c = 0
        s = 1
        for t in range(d):
            k = np.floor((X[p, t] - origin[t]) / cell[t])
            k = min(max(k, 0.0), g - 1.0)
            c += int(k) * s
            s *= g
        for e in range(start[c], start[c + 1]):
            r = cands[e]
            v = -1.0
            if off[r + 1] > off[r]:
                v = -np.inf
                for j in range(off[r], off[r + 1]):
                    a = -b[j]
                    for t in range(d):
                        a += A[j, t] * X[p, t]
                    v = max(v, a)
            if implied[r]:
                v = max(v, sv[p])
            cur = best[p]
            now = out[p]
            if v <= 0.0:
                if cur > 0.0 or r < now:
                    out[p] = r
                    best[p] = v
                break
            if v <= tol and cur > 0.0 and (v < cur or (v == cur and r < now)):
                out[p] = r
                best[p] = v
