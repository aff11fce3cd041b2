"""The leaves' member check of the tree, compiled (numba): one certified LP per member.

A member of a leaf is kept unless the largest ball in (its region, enlarged) and (the
leaf's cell, widened) has a negative radius bound by weak duality (``lp_kernel.chebyshev``).
~10^5 such LPs for a 1008-region law: from Python, the call and the stacking of rows cost
more than the LP.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from codev_engine.geometry.lp_kernel import OPTIMAL, cache_follows, chebyshev


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


cache_follows(globals())
