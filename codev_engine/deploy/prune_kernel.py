"""The tree's LPs, compiled (numba): certified emptiness of a region's part of a cell.

A region is apart from a set of half-spaces when the largest ball in (the region,
enlarged) and (the half-spaces) has a negative radius bound by weak duality
(``lp_kernel.chebyshev``). :func:`apart` asks it for the members of every leaf;
:func:`split_node` for the regions of a node against the two sides of its hyperplane
(the sort by cell of ``bst.py``), :func:`local_counts` scores candidate hyperplanes by the
vertices inside a cell. ~10^5 such LPs for a 1008-region law: from Python, the
call and the stacking of rows cost more than the LP.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from codev_engine.geometry.lp_kernel import OPTIMAL, cache_follows, chebyshev, lp_max


@njit(cache=True)
def apart(An, be, off, PA, Pb, poff, members, moff, owner, box_A, box_b, x0, bound, maxit):
    """Which members of each leaf are proved apart from the leaf's cell.

    Parameters
    ----------
    An : (N, d) float64 ndarray
        Every region's rows, unit, region after region.
    be : (N,) float64 ndarray
        Their offsets, enlarged.
    off : (R + 1,) int64 ndarray
        Region ``i``'s rows are ``off[i]:off[i + 1]``.
    PA, Pb : (Q, d), (Q,) float64 ndarrays
        Every leaf's cell rows (widened), leaf after leaf.
    poff : (L + 1,) int64 ndarray
        Leaf ``l``'s cell rows are ``poff[l]:poff[l + 1]``.
    members : (M,) int64 ndarray
        Every leaf's members, leaf after leaf.
    moff : (L + 1,) int64 ndarray
        Leaf ``l``'s members are ``members[moff[l]:moff[l + 1]]``.
    owner : (L,) int64 ndarray
        Each leaf's owner (never dropped), -1 for none.
    box_A, box_b : (2d, d), (2d,) float64 ndarrays
        The box of all regions, as rows.
    x0 : (d,) float64 ndarray
        The LPs' start point.
    bound : float
        A bound of ``|x|_inf`` over the box.
    maxit : int
        The LP's pivot limit.

    Returns
    -------
    (M,) bool ndarray
        True where the member is proved apart (to be dropped).
    """
    d = An.shape[1]
    out = np.zeros(members.size, dtype=np.bool_)
    for leaf in range(moff.size - 1):
        if moff[leaf + 1] - moff[leaf] <= 1:
            continue
        npath = poff[leaf + 1] - poff[leaf]
        for q in range(moff[leaf], moff[leaf + 1]):
            r = members[q]
            if r == owner[leaf]:
                continue
            k = off[r + 1] - off[r]
            Ar = np.empty((k + npath + 2 * d, d))
            br = np.empty(k + npath + 2 * d)
            Ar[:k] = An[off[r] : off[r + 1]]
            br[:k] = be[off[r] : off[r + 1]]
            Ar[k : k + npath] = PA[poff[leaf] : poff[leaf + 1]]
            br[k : k + npath] = Pb[poff[leaf] : poff[leaf + 1]]
            Ar[k + npath :] = box_A
            br[k + npath :] = box_b
            status, _, _, upper = chebyshev(Ar, br, x0, bound, maxit)
            if status == OPTIMAL and upper < 0.0:
                out[q] = True
    return out


@njit(cache=True)
def _in_cell(V, i, CA, Cb, tol):
    for k in range(CA.shape[0]):
        s = -Cb[k]
        for t in range(V.shape[1]):
            s += CA[k, t] * V[i, t]
        if s > tol:
            return False
    return True


@njit(cache=True)
def _box_range(box_c, box_r, r, HA, Hb, h):
    """The least and largest ``s = HA[h] x - Hb[h]`` over region ``r``'s box (centre
    ``box_c[r]``, radius ``box_r[r]``): its support, exact."""
    mid = -Hb[h]
    half = 0.0
    for t in range(HA.shape[1]):
        mid += HA[h, t] * box_c[r, t]
        half += abs(HA[h, t]) * box_r[r, t]
    return mid - half, mid + half


@njit(cache=True)
def cutting(V, vstart, vcount, P, CA, Cb, tol, W, Wn, HA, Hb, cand, eps):
    """Which candidate hyperplanes cut the points known in the regions' parts of a cell:
    the (enlarged) vertices of regions ``P`` inside the cell and the witnesses inside it
    (centres of earlier LPs' balls, see :func:`split_node`). Only an estimate of where
    the cell holds regions (a region crossing the cell with no vertex in it may reach
    past them): the tree uses it to pick the candidates worth scoring, never to sort a
    region.

    Parameters
    ----------
    V : (K, d) float64 ndarray
        The regions' (enlarged) vertices, region after region.
    vstart, vcount : (R,) int64 ndarrays
        Region ``i``'s vertices are ``V[vstart[i]:vstart[i] + vcount[i]]``.
    P : (p,) int64 ndarray
        The regions whose vertices count.
    CA, Cb : (c, d), (c,) float64 ndarrays
        The cell.
    tol : float
        A point is in the cell when ``CA v - Cb <= tol``.
    W : (Q, K, d) float64 ndarray
        Witnesses (rings of ``K`` per region, as in :func:`split_node`).
    Wn : (Q,) int64 ndarray
        Witnesses stored per region.
    HA, Hb : (H, d), (H,) float64 ndarrays
        Every hyperplane.
    cand : (k,) int64 ndarray
        The candidates.
    eps : (k,) float64 ndarray
        Each candidate's margin: it cuts when some point has ``s < -eps`` and some
        ``s > eps``.

    Returns
    -------
    (k,) bool ndarray
        The candidates that cut (all of them where no point is in the cell).
    n : int
        The points in the cell.
    """
    pts = cell_points(V, vstart, vcount, P, CA, Cb, tol, W, Wn)
    return cuts(pts, HA, Hb, cand, eps), pts.shape[0]


@njit(cache=True)
def cell_points(V, vstart, vcount, P, CA, Cb, tol, W, Wn):
    """The points :func:`cutting` tests the candidates on: the (enlarged) vertices of
    regions ``P`` inside the cell and the witnesses inside it.

    Parameters
    ----------
    V : (K, d) float64 ndarray
        The regions' (enlarged) vertices, region after region.
    vstart, vcount : (R,) int64 ndarrays
        Region ``i``'s vertices are ``V[vstart[i]:vstart[i] + vcount[i]]``.
    P : (p,) int64 ndarray
        The regions whose vertices count.
    CA, Cb : (c, d), (c,) float64 ndarrays
        The cell.
    tol : float
        A point is in the cell when ``CA v - Cb <= tol``.
    W : (Q, K, d) float64 ndarray
        Witnesses (rings of ``K`` per region, as in :func:`split_node`).
    Wn : (Q,) int64 ndarray
        Witnesses stored per region.

    Returns
    -------
    (n, d) float64 ndarray
    """
    d = V.shape[1]
    n = 0
    for q in range(P.size):
        r = P[q]
        for i in range(vstart[r], vstart[r] + vcount[r]):
            if _in_cell(V, i, CA, Cb, tol):
                n += 1
    for q in range(Wn.size):
        for w in range(min(Wn[q], W.shape[1])):
            if _in_cell(W[q], w, CA, Cb, tol):
                n += 1
    pts = np.empty((n, d))
    m = 0
    for q in range(P.size):
        r = P[q]
        for i in range(vstart[r], vstart[r] + vcount[r]):
            if _in_cell(V, i, CA, Cb, tol):
                pts[m] = V[i]
                m += 1
    for q in range(Wn.size):
        for w in range(min(Wn[q], W.shape[1])):
            if _in_cell(W[q], w, CA, Cb, tol):
                pts[m] = W[q, w]
                m += 1
    return pts


@njit(cache=True)
def cuts(pts, HA, Hb, cand, eps):
    """Which candidates have points of ``pts`` on both sides beyond their margin (all of
    them where there is no point): :func:`cutting` on points found once.

    Parameters
    ----------
    pts : (n, d) float64 ndarray
    HA, Hb : (H, d), (H,) float64 ndarrays
        Every hyperplane.
    cand : (k,) int64 ndarray
        The candidates.
    eps : (k,) float64 ndarray
        Each candidate's margin.

    Returns
    -------
    (k,) bool ndarray
    """
    n, d = pts.shape
    out = np.ones(cand.size, dtype=np.bool_)
    if n == 0:
        return out
    for c in range(cand.size):
        h = cand[c]
        below = False
        above = False
        for k in range(n):
            s = -Hb[h]
            for t in range(d):
                s += HA[h, t] * pts[k, t]
            if s < -eps[c]:
                below = True
            elif s > eps[c]:
                above = True
            if below and above:
                break
        out[c] = below and above
    return out


@njit(cache=True)
def local_counts(V, vstart, vcount, box_c, box_r, P, CA, Cb, tol, HA, Hb, cand, eps):
    """Proper regions each side of each candidate hyperplane, by the regions' vertices
    inside the cell (all of a region's vertices where none is): an estimate of the split.

    Parameters
    ----------
    V : (K, d) float64 ndarray
        The regions' (enlarged) vertices, region after region.
    vstart, vcount : (R,) int64 ndarrays
        Region ``i``'s vertices are ``V[vstart[i]:vstart[i] + vcount[i]]``.
    box_c, box_r : (R, d) float64 ndarrays
        A region with ``box_r[r, 0] >= 0`` is *boxed*: its points are inside it, not its
        vertices (``inner_points``); its box (centre, radius) holds it, and the box's
        support along a row stands for all its vertices' (where no point is in the cell:
        for those in the cell too).
    P : (p,) int64 ndarray
        The regions counted.
    CA, Cb : (c, d), (c,) float64 ndarrays
        The cell.
    tol : float
        A vertex is in the cell when ``CA v - Cb <= tol``.
    HA, Hb : (H, d), (H,) float64 ndarrays
        Every hyperplane.
    cand : (k,) int64 ndarray
        The candidates.
    eps : (k,) float64 ndarray
        Each candidate's slack: proper beyond it.

    Returns
    -------
    nl, nr : (k,) int64 ndarrays
    """
    n = 0
    for q in range(P.size):
        n += vcount[P[q]]
    idx = np.empty(n, dtype=np.int64)
    seg = np.zeros(P.size + 1, dtype=np.int64)
    m = 0
    for q in range(P.size):
        r = P[q]
        m0 = m
        for i in range(vstart[r], vstart[r] + vcount[r]):
            if _in_cell(V, i, CA, Cb, tol):
                idx[m] = i
                m += 1
        if m == m0 and box_r[r, 0] < 0.0:
            for i in range(vstart[r], vstart[r] + vcount[r]):
                idx[m] = i
                m += 1
        seg[q + 1] = m
    d = V.shape[1]
    nl = np.zeros(cand.size, dtype=np.int64)
    nr = np.zeros(cand.size, dtype=np.int64)
    for c in range(cand.size):
        h = cand[c]
        for q in range(P.size):
            lo = np.inf
            hi = -np.inf
            for k in range(seg[q], seg[q + 1]):
                i = idx[k]
                s = -Hb[h]
                for t in range(d):
                    s += HA[h, t] * V[i, t]
                lo = min(lo, s)
                hi = max(hi, s)
            if seg[q + 1] == seg[q] and box_r[P[q], 0] >= 0.0:
                lo, hi = _box_range(box_c, box_r, P[q], HA, Hb, h)
            if lo < -eps[c]:
                nl[c] += 1
            if hi > eps[c]:
                nr[c] += 1
    return nl, nr


@njit(cache=True)
def both_counts(V, vstart, vcount, box_c, box_r, P, CA, Cb, tol, HA, Hb, cand, eps):
    """:func:`local_counts` in the cell and over all vertices (no cell) in one pass.

    Parameters
    ----------
    V : (K, d) float64 ndarray
        The regions' (enlarged) vertices, region after region.
    vstart, vcount : (R,) int64 ndarrays
        Region ``i``'s vertices are ``V[vstart[i]:vstart[i] + vcount[i]]``.
    box_c, box_r : (R, d) float64 ndarrays
        A region with ``box_r[r, 0] >= 0`` is *boxed*: its points are inside it, not its
        vertices (``inner_points``); its box (centre, radius) holds it, and the box's
        support along a row stands for all its vertices' (where no point is in the cell:
        for those in the cell too).
    P : (p,) int64 ndarray
        The regions counted.
    CA, Cb : (c, d), (c,) float64 ndarrays
        The cell.
    tol : float
        A vertex is in the cell when ``CA v - Cb <= tol``.
    HA, Hb : (H, d), (H,) float64 ndarrays
        Every hyperplane.
    cand : (k,) int64 ndarray
        The candidates.
    eps : (k,) float64 ndarray
        Each candidate's slack: proper beyond it.

    Returns
    -------
    nl, nr : (k,) int64 ndarrays
        By all vertices of each region.
    nl_cell, nr_cell : (k,) int64 ndarrays
        By the vertices in the cell (all where none is), as :func:`local_counts`.
    """
    n = 0
    for q in range(P.size):
        n += vcount[P[q]]
    incell = np.zeros(n, dtype=np.bool_)
    anyin = np.zeros(P.size, dtype=np.bool_)
    m = 0
    for q in range(P.size):
        r = P[q]
        for i in range(vstart[r], vstart[r] + vcount[r]):
            if _in_cell(V, i, CA, Cb, tol):
                incell[m] = True
                anyin[q] = True
            m += 1
    d = V.shape[1]
    nl = np.zeros(cand.size, dtype=np.int64)
    nr = np.zeros(cand.size, dtype=np.int64)
    nlc = np.zeros(cand.size, dtype=np.int64)
    nrc = np.zeros(cand.size, dtype=np.int64)
    for c in range(cand.size):
        h = cand[c]
        m = 0
        for q in range(P.size):
            r = P[q]
            lo = np.inf
            hi = -np.inf
            loc = np.inf
            hic = -np.inf
            for i in range(vstart[r], vstart[r] + vcount[r]):
                s = -Hb[h]
                for t in range(d):
                    s += HA[h, t] * V[i, t]
                lo = min(lo, s)
                hi = max(hi, s)
                if incell[m]:
                    loc = min(loc, s)
                    hic = max(hic, s)
                m += 1
            if box_r[r, 0] >= 0.0:
                lo, hi = _box_range(box_c, box_r, r, HA, Hb, h)
            if not anyin[q]:
                loc = lo
                hic = hi
            if lo < -eps[c]:
                nl[c] += 1
            if hi > eps[c]:
                nr[c] += 1
            if loc < -eps[c]:
                nlc[c] += 1
            if hic > eps[c]:
                nrc[c] += 1
    return nl, nr, nlc, nrc


@njit(cache=True)
def split_node(V, vstart, vcount, box_c, box_r, regs, isP, CA, Cb, Cbp, tol, ha, hb, e, p,
               An, be, off, box_A, box_b, bound, maxit, W, Wn, possible):
    """The regions of a node sorted into its children by their part inside the node's
    cell: the vertices decide where they can, a certified LP where they cannot.

    For the left child (``ha x <= hb``) a region is a *member* unless its part of the cell
    (widened) is proved to lie beyond ``ha x > hb + e``, and *proper* (``isP`` only)
    unless its part of the cell shrunk by ``p`` (where the fast path runs) is proved to
    lie within ``ha x > hb - p``; mirrored on the right. Proofs: every
    (enlarged) vertex beyond (their hull holds the region; a boxed region's box), or a
    negative radius bound of the largest ball in (region, cell, box, the side's
    half-space) (weak duality).
    A vertex inside the cell on the side decides the other way; an LP whose ball has
    radius >= 0 too. On any doubt the region stays (member, proper).

    Parameters
    ----------
    V : (K, d) float64 ndarray
        The regions' (enlarged) vertices, region after region.
    vstart, vcount : (R,) int64 ndarrays
    box_c, box_r : (R, d) float64 ndarrays
        A region with ``box_r[r, 0] >= 0`` is *boxed*: its points are inside it, not its
        vertices (``inner_points``); its box (centre, radius) holds it, and the box's
        support along a row stands for all its vertices' (where no point is in the cell:
        for those in the cell too).
    regs : (Q,) int64 ndarray
        The node's regions (proper and members).
    isP : (Q,) bool ndarray
        Which of them are proper at the node.
    CA, Cb : (c, d), (c,) float64 ndarrays
        The node's cell (unit rows, widened).
    Cbp : (c,) float64 ndarray
        The node's cell shrunk (``CA x <= Cbp``).
    tol : float
        A vertex is in the cell when ``CA v - Cb <= tol``.
    ha : (d,) float64 ndarray
        The hyperplane (unit).
    hb : float
    e : float
        The slack of member.
    p : float
        The margin of proper (``p >= e``).
    An : (N, d) float64 ndarray
        Every region's rows, unit.
    be : (N,) float64 ndarray
        Their offsets, enlarged.
    off : (R + 1,) int64 ndarray
    box_A, box_b : (2d, d), (2d,) float64 ndarrays
        The box of all regions, as rows.
    bound : float
        A bound of ``|x|_inf`` over the box.
    maxit : int
    W : (Q, K, d) float64 ndarray
        Witnesses: points found in each region's part of the cell (centres of earlier
        LPs' balls, here or at an ancestor node), a ring of ``K`` per region; the centres
        of this call's LPs are added. A witness that meets an undecided test (in the
        cell, on the side) decides it as the LP would (a feasible point: radius >= 0),
        without the LP. It can only keep a region (never drop one), whatever its
        accuracy.
    Wn : (Q,) int64 ndarray
        Witnesses stored per region so far (the ring holds the last ``K``).
    possible : (Q, 4) bool ndarray
        False where an ancestor node proved the region apart from that side of this
        hyperplane (columns as returned): apart from a larger cell, it is apart from
        this one too. All True: nothing known.

    Returns
    -------
    (Q, 4) bool ndarray
        Left member, left proper, right member, right proper.
    """
    d = An.shape[1]
    c = CA.shape[0]
    out = np.zeros((regs.size, 4), dtype=np.bool_)
    x0 = np.empty(d)
    for q in range(regs.size):
        r = regs[q]
        lo_all = np.inf
        hi_all = -np.inf
        lo_in = np.inf
        hi_in = -np.inf
        for t in range(d):
            x0[t] = 0.0
        for i in range(vstart[r], vstart[r] + vcount[r]):
            s = -hb
            for t in range(d):
                s += ha[t] * V[i, t]
                x0[t] += V[i, t]
            lo_all = min(lo_all, s)
            hi_all = max(hi_all, s)
            if _in_cell(V, i, CA, Cb, tol):
                lo_in = min(lo_in, s)
                hi_in = max(hi_in, s)
        if vcount[r] > 0:
            for t in range(d):
                x0[t] /= vcount[r]
        if box_r[r, 0] >= 0.0:
            # boxed: where it is not, by its box's support (its points lie inside it:
            # lo_in, hi_in hold)
            mid = -hb
            half = 0.0
            for t in range(d):
                mid += ha[t] * box_c[r, t]
                half += abs(ha[t]) * box_r[r, t]
                if vcount[r] == 0:
                    x0[t] = box_c[r, t]
            lo_all = mid - half
            hi_all = mid + half
        # 1 there, 0 not there, -1 undecided: left proper, left member, right ...
        dec = np.empty(4, dtype=np.int64)
        dec[0] = 0 if (lo_all >= -p or not isP[q]) else (1 if lo_in < -p else -1)
        dec[1] = 0 if lo_all > e else (1 if lo_in <= e else -1)
        dec[2] = 0 if (hi_all <= p or not isP[q]) else (1 if hi_in > p else -1)
        dec[3] = 0 if hi_all < -e else (1 if hi_in >= -e else -1)
        # proved apart at an ancestor (the output's columns: left member, left proper, ...)
        if dec[0] < 0 and not possible[q, 1]:
            dec[0] = 0
        if dec[1] < 0 and not possible[q, 0]:
            dec[1] = 0
        if dec[2] < 0 and not possible[q, 3]:
            dec[2] = 0
        if dec[3] < 0 and not possible[q, 2]:
            dec[3] = 0
        if dec[0] < 0 or dec[1] < 0 or dec[2] < 0 or dec[3] < 0:
            _witnessed(W, Wn, q, CA, Cb, Cbp, ha, hb, e, p, dec)
        if dec[0] < 0 or dec[1] < 0 or dec[2] < 0 or dec[3] < 0:
            k = off[r + 1] - off[r]
            n = k + c + 1 + 2 * d
            Ar = np.empty((n, d))
            br = np.empty(n)
            Ar[:k] = An[off[r] : off[r + 1]]
            br[:k] = be[off[r] : off[r + 1]]
            Ar[k : k + c] = CA
            br[k : k + c] = Cb
            Ar[k + c + 1 :] = box_A
            br[k + c + 1 :] = box_b
            for side in range(2):
                sg = 1.0 if side == 0 else -1.0
                for t in range(d):
                    Ar[k + c, t] = sg * ha[t]
                for j in range(2):
                    col = 2 * side + j
                    if dec[col] >= 0:
                        continue
                    # proper: sg (ha x - hb) <= -p in the shrunk cell; member: <= e in
                    # the widened one
                    br[k + c] = sg * hb + (-p if j == 0 else e)
                    br[k : k + c] = Cbp if j == 0 else Cb
                    status, centre, radius, upper = chebyshev(Ar, br, x0, bound, maxit)
                    if status == OPTIMAL and upper < 0.0:
                        dec[col] = 0
                    else:
                        if status == OPTIMAL and radius >= 0.0:
                            W[q, Wn[q] % W.shape[1]] = centre
                            Wn[q] += 1
                        dec[col] = 1
                        if j == 0:
                            dec[col + 1] = 1  # proper there: a member there too
        out[q, 0] = dec[1] > 0 or dec[0] > 0
        out[q, 1] = dec[0] > 0
        out[q, 2] = dec[3] > 0 or dec[2] > 0
        out[q, 3] = dec[2] > 0
    return out


@njit(cache=True)
def _witnessed(W, Wn, q, CA, Cb, Cbp, ha, hb, e, p, dec):
    """Decide (1) the undecided tests of ``dec`` (as in :func:`split_node`) that one of
    region ``q``'s witnesses meets: a point in the cell (shrunk for proper, widened for
    member) on the side (``s <= -p`` / ``s <= e`` left, mirrored right)."""
    d = ha.size
    for w in range(min(Wn[q], W.shape[1])):
        s = -hb
        for t in range(d):
            s += ha[t] * W[q, w, t]
        # worth a look only if it meets an undecided test
        if not ((dec[0] < 0 and s <= -p) or (dec[1] < 0 and s <= e)
                or (dec[2] < 0 and s >= p) or (dec[3] < 0 and s >= -e)):
            continue
        in_wide = True
        in_shrunk = True
        for k in range(CA.shape[0]):
            a = 0.0
            for t in range(d):
                a += CA[k, t] * W[q, w, t]
            if a > Cb[k]:
                in_wide = False
                in_shrunk = False
                break
            if a > Cbp[k]:
                in_shrunk = False
        if in_shrunk and s <= -p and dec[0] < 0:
            dec[0] = 1
        if in_wide and s <= e and dec[1] < 0:
            dec[1] = 1
        if in_shrunk and s >= p and dec[2] < 0:
            dec[2] = 1
        if in_wide and s >= -e and dec[3] < 0:
            dec[3] = 1
        if dec[0] >= 0 and dec[1] >= 0 and dec[2] >= 0 and dec[3] >= 0:
            return


@njit(cache=True)
def inner_points(An, be, off, which, blo, bhi, bound, maxit):
    """Points inside regions whose vertices are not enumerated (boxed ones): the centre
    of the largest ball and the ``2 d`` ends of the region along the axes (LPs started
    from the centre). They tell where a region is (a point in a cell on a side: it is
    there), never where it is not: the box does.

    Parameters
    ----------
    An : (N, d) float64 ndarray
        Every region's rows, unit.
    be : (N,) float64 ndarray
        Their offsets, enlarged.
    off : (R + 1,) int64 ndarray
    which : (w,) int64 ndarray
        The regions.
    blo, bhi : (w, d) float64 ndarrays
        Their boxes (rows added to each LP: bounded whatever the region's rows).
    bound : float
        A bound of ``|x|_inf`` over the boxes.
    maxit : int

    Returns
    -------
    X : (w, 2 d + 1, d) float64 ndarray
    ok : (w, 2 d + 1) bool ndarray
        Where an LP found the point (optimal, inside the region to 1e-9).
    """
    d = An.shape[1]
    X = np.zeros((which.size, 2 * d + 1, d))
    ok = np.zeros((which.size, 2 * d + 1), dtype=np.bool_)
    for q in range(which.size):
        r = which[q]
        k = off[r + 1] - off[r]
        Ar = np.empty((k + 2 * d, d))
        br = np.empty(k + 2 * d)
        Ar[:k] = An[off[r] : off[r + 1]]
        br[:k] = be[off[r] : off[r + 1]]
        for t in range(d):
            for j in range(d):
                Ar[k + t, j] = 0.0
                Ar[k + d + t, j] = 0.0
            Ar[k + t, t] = 1.0
            br[k + t] = bhi[q, t]
            Ar[k + d + t, t] = -1.0
            br[k + d + t] = -blo[q, t]
        x0 = 0.5 * (blo[q] + bhi[q])
        status, centre, radius, _ = chebyshev(Ar, br, x0, bound, maxit)
        if status != OPTIMAL or radius < 0.0:
            continue
        X[q, 0] = centre
        ok[q, 0] = True
        use = np.ones(k + 2 * d, dtype=np.bool_)
        c = np.zeros(d)
        for t in range(d):
            for sg in range(2):
                c[t] = 1.0 if sg == 0 else -1.0
                st, x, _, _, _ = lp_max(c, Ar, br, use, centre, np.empty(0, dtype=np.int64),
                                        0, np.inf, maxit)
                c[t] = 0.0
                if st != OPTIMAL:
                    continue
                worst = -np.inf
                for i in range(k + 2 * d):
                    v = -br[i]
                    for j in range(d):
                        v += Ar[i, j] * x[j]
                    worst = max(worst, v)
                if worst <= 1e-9:
                    X[q, 1 + 2 * t + sg] = x
                    ok[q, 1 + 2 * t + sg] = True
    return X, ok


cache_follows(globals())
