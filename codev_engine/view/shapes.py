"""What a polytope looks like drawn: its outline in a plane, its triangle mesh in space.

Both are built from the polytope's vertices (:mod:`codev_engine.geometry.vertices`) with
numpy; only the outline of a projection of a polytope of more than two dimensions calls
Qhull (SciPy's 2-D convex hull). Used by the recordings (``codev_engine.view.records``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["meshes", "outline"]


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
