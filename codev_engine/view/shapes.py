"""What a polytope looks like drawn: its outline in a plane, its triangle mesh in space,
its pixels in a raster of the plane.

All are built from the polytope's vertices (:mod:`codev_engine.geometry.vertices`) with
numpy; only the outline of a projection of a polytope of more than two dimensions calls
Qhull (SciPy's 2-D convex hull). Used by the recordings (``codev_engine.view.records``):
the partition is a region-index image (:func:`raster_polygons`), the filled sets and the
tube's footprint are masks (:func:`raster_polygons`, :func:`raster_boxes`).

A raster of the window ``[lo, hi]`` with ``(H, W)`` pixels has pixel ``(r, c)`` covering
``[lo_0 + c dx, lo_0 + (c + 1) dx] x [lo_1 + r dy, lo_1 + (r + 1) dy]`` (row 0 at the
bottom, ``lo_1``); a pixel belongs to a polygon when its centre does.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "check_axes",
    "meshes",
    "outline",
    "raster_boxes",
    "raster_polygons",
    "section_polygons",
]


def outline(V: np.ndarray, axes: tuple[int, int]) -> np.ndarray | None:
    """The closed outline of the projection of ``conv(V)`` on two coordinates.

    In 2-D the vertices are sorted by angle around their mean (every vertex of a convex
    polygon is on its outline); in more dimensions the outline is Qhull's 2-D hull of the
    projected vertices.

    Parameters
    ----------
    V : (v, d) ndarray
        The vertices of a polytope.
    axes : (int, int)
        The two coordinates.

    Returns
    -------
    (p + 1, 2) ndarray or None
        The outline, its first point repeated at the end; None when it is flat (fewer than
        three points, or no extent in one of the two coordinates).
    """
    P = V[:, list(axes)]
    if P.shape[0] < 3:
        return None
    if V.shape[1] == 2:
        # every vertex of a convex polygon is on its boundary: sort by angle
        c = P.mean(axis=0)
        order = np.argsort(np.arctan2(P[:, 1] - c[1], P[:, 0] - c[0]))
        P = P[order]
    else:
        from scipy.spatial import ConvexHull, QhullError

        try:
            P = P[ConvexHull(P).vertices]
        except (QhullError, ValueError):
            return None
    span = np.ptp(P, axis=0)
    if np.min(span) <= 1e-12 * (1.0 + np.max(np.abs(P))):
        return None
    return np.vstack([P, P[:1]])


def meshes(
    Vs: Sequence[np.ndarray | None],
    As: Sequence[np.ndarray],
    bs: Sequence[np.ndarray],
    tol: float = 1e-7,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """Triangle meshes of many 3-D polytopes from their vertices and rows, vectorised.

    Each row ``j`` of a polytope whose plane holds three or more of its vertices is a facet;
    the facet's vertices are sorted by angle around their centroid in the facet plane and
    fan-triangulated, counter-clockwise seen from outside (outward normals ``A_j``).

    Parameters
    ----------
    Vs : sequence of (v_i, 3) ndarray or None
        The vertices of each polytope (:mod:`codev_engine.geometry.vertices`).
    As, bs : sequence of (r_i, 3) and (r_i,) ndarray
        The rows the vertices came from (unit norm).
    tol : float
        A vertex is on a row's plane within ``tol * (1 + |b_j|)``.

    Returns
    -------
    positions : (N, 3) ndarray
    triangles : (T, 3) uint32 ndarray
        Indices into ``positions``.
    owner : (N,) ndarray of int
        Polytope index of each position.
    meshed : list of int
        The polytopes that got at least one triangle.
    """
    idx = [i for i, v in enumerate(Vs) if v is not None and v.shape[0] >= 4]
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint32), np.zeros(0, dtype=int), [])
    if not idx:
        return empty
    counts = np.array([Vs[i].shape[0] for i in idx])
    V = np.vstack([Vs[i] for i in idx])
    g = np.repeat(np.arange(len(idx)), counts)
    rmax = max(As[i].shape[0] for i in idx)
    Ap = np.zeros((len(idx), rmax, 3))
    bp = np.full((len(idx), rmax), np.nan)
    for k, i in enumerate(idx):
        r = As[i].shape[0]
        Ap[k, :r] = As[i]
        bp[k, :r] = bs[i]
    with np.errstate(invalid="ignore"):
        slack = np.abs(np.einsum("nrd,nd->nr", Ap[g], V) - bp[g])
        active = slack <= tol * (1.0 + np.abs(bp[g]))
    vi, j = np.nonzero(active)
    f = g[vi] * rmax + j  # facet id
    nf = len(idx) * rmax
    cnt = np.bincount(f, minlength=nf)
    keep = cnt[f] >= 3
    vi, f = vi[keep], f[keep]
    if vi.size == 0:
        return empty
    normal = Ap.reshape(-1, 3)[f]
    centre = np.stack([np.bincount(f, V[vi, c], minlength=nf) for c in range(3)], axis=1)
    centre = centre / np.maximum(cnt, 1)[:, None]
    # an in-plane basis (e1, e2) with e1 x e2 = normal
    axis = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    e1 = _cross(normal, axis)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = _cross(normal, e1)
    rel = V[vi] - centre[f]
    angle = np.arctan2(np.einsum("md,md->m", rel, e2), np.einsum("md,md->m", rel, e1))
    order = np.lexsort((angle, f))
    vi, f = vi[order], f[order]
    run_start = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
    first = np.repeat(run_start, np.diff(np.r_[run_start, f.size]))
    pos = np.arange(f.size) - first
    sel = np.flatnonzero(pos >= 2)
    tri = np.column_stack([vi[first[sel]], vi[sel - 1], vi[sel]]).astype(np.uint32)
    meshed = sorted({idx[k] for k in np.unique(g[tri[:, 0]])})
    owner = np.array(idx)[g]
    return V, tri, owner, meshed


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (``np.cross`` is slow on small batches)."""
    return np.column_stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ]
    )


def raster_polygons(
    polys: Sequence[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    shape: tuple[int, int],
    values: np.ndarray | None = None,
) -> np.ndarray:
    """Rasterise convex polygons: each pixel whose centre is in polygon ``k`` gets ``values[k]``.

    Each polygon is tested only on the pixels of its bounding box (the work is the sum of
    the boxes' pixel counts times the edges: a partition of 10^3 regions at 600 x 600 in
    tens of milliseconds). Later polygons overwrite earlier ones where they overlap.

    Parameters
    ----------
    polys : sequence of (v_k, 2) ndarray
        Convex polygons, vertices in order (either orientation).
    lo, hi : (2,) ndarray
        The window.
    shape : (int, int)
        ``(H, W)`` pixels.
    values : (p,) ndarray of int, optional
        The value of each polygon's pixels (default ``k + 1``); the rest is 0.

    Returns
    -------
    (H, W) ndarray
        ``uint32``; row 0 is the bottom of the window (``lo[1]``).
    """
    H, W = int(shape[0]), int(shape[1])
    out = np.zeros((H, W), dtype=np.uint32)
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    dx, dy = (hi[0] - lo[0]) / W, (hi[1] - lo[1]) / H
    if not (dx > 0 and dy > 0):
        return out
    vals = np.arange(1, len(polys) + 1) if values is None else np.asarray(values)
    for k, P in enumerate(polys):
        P = np.asarray(P, dtype=float)
        if P.shape[0] < 3:
            continue
        c0 = max(int(np.floor((P[:, 0].min() - lo[0]) / dx - 0.5)), 0)
        c1 = min(int(np.ceil((P[:, 0].max() - lo[0]) / dx - 0.5)), W - 1)
        r0 = max(int(np.floor((P[:, 1].min() - lo[1]) / dy - 0.5)), 0)
        r1 = min(int(np.ceil((P[:, 1].max() - lo[1]) / dy - 0.5)), H - 1)
        if c1 < c0 or r1 < r0:
            continue
        xs = lo[0] + (np.arange(c0, c1 + 1) + 0.5) * dx
        ys = lo[1] + (np.arange(r0, r1 + 1) + 0.5) * dy
        E = np.roll(P, -1, axis=0) - P  # edges
        # signed area: orient the edge test so "inside" is >= 0
        area2 = np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
        sign = 1.0 if area2 >= 0 else -1.0
        inside = np.ones((ys.size, xs.size), dtype=bool)
        for e in range(P.shape[0]):
            cross = E[e, 0] * (ys[:, None] - P[e, 1]) - E[e, 1] * (xs[None, :] - P[e, 0])
            inside &= sign * cross >= -1e-12 * (1.0 + np.abs(E[e]).max())
        block = out[r0 : r1 + 1, c0 : c1 + 1]
        block[inside] = vals[k]
    return out


def raster_boxes(
    lower: np.ndarray,
    upper: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    shape: tuple[int, int],
    *,
    min_pixels: int = 2,
) -> np.ndarray:
    """The union of boxes as a mask, each box at least ``min_pixels`` wide and high.

    One pass for all boxes (a 2-D difference array: +1/-1 at the corners, then cumulative
    sums): 10^4 boxes in a few milliseconds. A box narrower than ``min_pixels`` is widened
    about its centre, so a thin tube stays visible (the picture, not the data: the boxes
    themselves are logged unchanged).

    Parameters
    ----------
    lower, upper : (K, 2) ndarray
        The boxes.
    lo, hi : (2,) ndarray
        The window.
    shape : (int, int)
        ``(H, W)`` pixels.
    min_pixels : int
        The least width and height of a box in pixels.

    Returns
    -------
    (H, W) bool ndarray
        Row 0 is the bottom of the window.
    """
    H, W = int(shape[0]), int(shape[1])
    lower = np.asarray(lower, dtype=float).reshape(-1, 2)
    upper = np.asarray(upper, dtype=float).reshape(-1, 2)
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    size = np.array([W, H], dtype=float)
    if lower.shape[0] == 0 or not np.all(hi > lo):
        return np.zeros((H, W), dtype=bool)
    a = (lower - lo) / (hi - lo) * size  # pixel coordinates
    b = (upper - lo) / (hi - lo) * size
    mid, half = 0.5 * (a + b), np.maximum(0.5 * (b - a), 0.5 * min_pixels)
    ok = np.all(np.isfinite(mid) & np.isfinite(half), axis=1)
    i0 = np.clip(np.floor(mid - half), 0, size).astype(int)[ok]
    i1 = np.clip(np.ceil(mid + half), 0, size).astype(int)[ok]
    keep = np.all(i1 > i0, axis=1)
    i0, i1 = i0[keep], i1[keep]
    diff = np.zeros((H + 1, W + 1), dtype=np.int32)
    np.add.at(diff, (i0[:, 1], i0[:, 0]), 1)
    np.add.at(diff, (i0[:, 1], i1[:, 0]), -1)
    np.add.at(diff, (i1[:, 1], i0[:, 0]), -1)
    np.add.at(diff, (i1[:, 1], i1[:, 0]), 1)
    return np.cumsum(np.cumsum(diff, axis=0), axis=1)[:H, :W] > 0


def section_polygons(
    A: list[np.ndarray],
    b: list[np.ndarray],
    *,
    axes: tuple[int, int] = (0, 1),
    at: np.ndarray | None = None,
    tol: float = 1e-9,
) -> tuple[list[np.ndarray], np.ndarray]:
    """The 2-D sections of polytopes ``{x : A_i x <= b_i}`` as ordered polygons.

    The section of region ``i`` is ``{(x[axes[0]], x[axes[1]]) : A_i x <= b_i}`` with every
    other coordinate fixed at ``at``. Its rows are normalised in the plane and its vertices
    found for all regions at once by :func:`~codev_engine.geometry.vertices.packed_vertices`
    (every pair of rows intersected, the points that satisfy all the region's rows kept),
    then sorted by angle around their mean.

    Parameters
    ----------
    A : list of (r_i, n) ndarray
        Region rows.
    b : list of (r_i,) ndarray
    axes : (2,) tuple of int
        The two coordinates spanning the plane (distinct, ``< n``).
    at : (n,) array_like, optional
        Values of the other coordinates (ignored for ``n == 2``); zeros by default.
    tol : float
        Feasibility tolerance of a candidate vertex, ``tol * (1 + |b_j|)`` for row ``j``
        (absolute and relative parts of :func:`~codev_engine.geometry.vertices.packed_vertices`).

    Returns
    -------
    polygons : list of (v_k, 2) ndarray
        Counter-clockwise vertices of each non-degenerate section (positive area).
    index : (p,) ndarray of int
        The region of each polygon, increasing.
    """
    R = len(A)
    if R == 0:
        return [], np.zeros(0, dtype=int)
    n = A[0].shape[1]
    i, j = check_axes(axes, n)
    counts = np.array([a.shape[0] for a in A])
    rows = np.vstack(A).astype(float)
    rhs = np.concatenate(b).astype(float)
    region = np.repeat(np.arange(R), counts)
    others = [k for k in range(n) if k not in (i, j)]
    if others:
        at = np.zeros(n) if at is None else np.asarray(at, dtype=float).reshape(n)
        rhs = rhs - rows[:, others] @ at[others]
    plane = rows[:, [i, j]]
    scale = np.maximum(np.linalg.norm(rows, axis=1), 1e-300)
    norm = np.hypot(plane[:, 0], plane[:, 1])
    flat = norm <= 1e-12 * scale
    # a row without a component in the plane is a constant test: all or nothing
    empty = np.bincount(region[flat & (rhs < -tol * (1.0 + np.abs(rhs)))], minlength=R) > 0
    keep = ~flat & ~empty[region]
    plane = plane[keep] / norm[keep, None]
    rhs = rhs[keep] / norm[keep]
    region = region[keep]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(region, minlength=R))])
    # all regions in one enumeration (the section rows have unit norm in the plane)
    # imported here: geometry's LPs load scipy.optimize (~0.3 s), which the workbench's first
    # screen must not wait for
    from codev_engine.geometry.vertices import packed_vertices

    P, own, _ = packed_vertices(plane, rhs, offsets, tol, rtol=tol, max_combos=None)
    if own.size == 0:
        return [], np.zeros(0, dtype=int)
    # order the vertices of each region by angle around their mean
    num = np.bincount(own, minlength=R)
    centre = (
        np.stack([np.bincount(own, P[:, 0], R), np.bincount(own, P[:, 1], R)], axis=1)
        / np.maximum(num, 1)[:, None]
    )
    d = P - centre[own]
    order = np.lexsort((np.arctan2(d[:, 1], d[:, 0]), own))
    P, own = P[order], own[order]
    regs, first = np.unique(own, return_index=True)
    # shoelace area per region (cyclic successor inside each region's run)
    nxt = np.arange(1, own.size + 1)
    nxt[np.append(first[1:], own.size) - 1] = first
    cross = P[:, 0] * P[nxt, 1] - P[nxt, 0] * P[:, 1]
    area = 0.5 * np.add.reduceat(cross, first)
    span = float(np.ptp(P, axis=0).max()) if P.size else 0.0
    good = (np.diff(np.append(first, own.size)) >= 3) & (area > 1e-12 * max(span, 1.0) ** 2)
    polys = np.split(P, first[1:])
    return [polys[k] for k in np.flatnonzero(good)], regs[good]


def check_axes(axes: tuple[int, int], n: int) -> tuple[int, int]:
    """Two distinct coordinate indices below ``n``.

    Parameters
    ----------
    axes : (2,) tuple of int
        The plane's coordinates.
    n : int
        The dimension.

    Returns
    -------
    (int, int)

    Raises
    ------
    ValueError
        The indices are equal or out of range.
    """
    i, j = (int(a) for a in axes)
    if i == j or not (0 <= i < n and 0 <= j < n):
        raise ValueError(f"axes must be two distinct state indices below {n}, got {axes}")
    return i, j
