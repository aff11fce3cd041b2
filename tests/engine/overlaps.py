"""A test helper: the pairs of regions of a partition whose interiors overlap.

A partition of the feasible parameter set has no overlaps when no two regions share a ball
larger than the region tolerance (the search keeps a region only with a proved ball above
it: thinner pieces are lower-dimensional). Sampling finds an overlap only where a sample
falls into it, and chain5's were of radius 7e-8 in a box of 4: this check looks at every
pair whose bounding boxes meet, with one LP each, the Chebyshev ball of the intersection
of both regions' rows (the compiled LP of ``geometry/lp_kernel``, whose weak-duality bound
proves most pairs apart; HiGHS at tight tolerances where it proves nothing).
"""

from __future__ import annotations

import numpy as np

from codev_engine.geometry import lp_kernel
from codev_engine.geometry.locate import bounding_boxes
from codev_engine.geometry.polytope import chebyshev_ball


def region_rows(regions) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Each region's rows, unit norm (a ``RegionArrays``, or ``ExplicitLaw.A``/``b``
    given as a pair of lists)."""
    if isinstance(regions, tuple):
        As, bs = regions
    else:
        As, bs = zip(*(regions.rows(i) for i in range(len(regions))), strict=True)
    out_A, out_b = [], []
    for A, b in zip(As, bs, strict=True):
        n = np.linalg.norm(A, axis=1)
        keep = n > 0
        out_A.append(A[keep] / n[keep, None])
        out_b.append(b[keep] / n[keep])
    return out_A, out_b


def overlapping_pairs(regions, tol: float) -> list[tuple[int, int, float]]:
    """The pairs of regions whose intersection holds a ball of radius above ``tol``.

    Parameters
    ----------
    regions : RegionArrays or (list of (r_i, d) ndarray, list of (r_i,) ndarray)
        The partition's regions ``A_i theta <= b_i``.
    tol : float
        The region tolerance (absolute): an intersection thinner than this is a shared
        facet, not an overlap.

    Returns
    -------
    list of (i, j, radius)
        ``i < j``, with the radius of the intersection's Chebyshev ball (HiGHS at tight
        tolerances, the ball checked against both regions' rows).
    """
    As, bs = region_rows(regions)
    R = len(As)
    if R < 2:
        return []
    lo, hi = bounding_boxes(As, bs)
    pad = 1e-9 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
    lo, hi = lo - pad, hi + pad
    bound = float(np.max(np.abs(np.vstack([lo, hi]))))
    # pairs whose boxes meet: sweep along the widest axis, then every axis
    ax = int(np.argmax(np.ptp(hi, axis=0) if R else 0))
    order = np.argsort(lo[:, ax], kind="stable")
    out = []
    for p, i in enumerate(order):
        later = order[p + 1:]
        later = later[lo[later, ax] <= hi[i, ax]]
        if not later.size:
            continue
        meet = np.all((lo[later] <= hi[i]) & (lo[i] <= hi[later]), axis=1)
        for j in later[meet]:
            A = np.vstack([As[i], As[j]])
            b = np.concatenate([bs[i], bs[j]])
            ball = _ball(A, b, 0.5 * (lo[i] + hi[i]), bound, tol)
            if ball > tol:
                a, c = sorted((int(i), int(j)))
                out.append((a, c, ball))
    return sorted(out)


def _ball(A: np.ndarray, b: np.ndarray, start: np.ndarray, bound: float, tol: float) -> float:
    """The radius of a checked ball inside ``{A x <= b}`` (unit rows, the set within
    ``|x|_inf <= bound``), or 0 when none above ``tol`` exists (proved by the compiled LP's
    bound, else not found by HiGHS at tight tolerances)."""
    status, centre, _, upper = lp_kernel.chebyshev(A, b, start, bound, 50 * (A.shape[0] + 10))
    if status == lp_kernel.OPTIMAL:
        if upper <= tol:
            return 0.0
        ball = float(np.min(b - A @ centre))
        if ball > tol:
            return ball
    centre, rho = chebyshev_ball(A, b, solver="highs", tol=1e-10)
    if not rho > tol:
        return 0.0
    return max(float(np.min(b - A @ centre)), 0.0)
