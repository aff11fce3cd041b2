"""Vertices of polytopes ``{x : A x <= b}``: the one vertex enumeration of the engine.

Every d-subset of a polytope's rows is solved as a ``d x d`` linear system; the solutions
that satisfy all the rows are its vertices (a bounded polytope is the convex hull of them;
an unbounded one has only the vertices it has, possibly none). This is meant for the small
H-representations of the engine -- critical regions, reach-set stars, sets drawn -- in low
dimension: ``C(k, d)`` systems for ``k`` rows. Many polytopes are enumerated at once
(:func:`vertices_many`, vectorised over all polytopes with the same number of rows).

Rows are expected of unit norm (every caller normalises them), so ``a_j x - b_j`` is the
signed distance to row ``j``'s hyperplane and ``|det|`` of d rows is the volume their
normals span. The tolerances, and what each guards against:

``DET_TOL = 1e-12`` (singular subsets)
    A subset whose ``|det|`` is below it has (nearly) dependent rows: the system has no
    unique solution, or one too inaccurate to trust, and gives no vertex. A vertex where
    facets meet at such a small angle is lost; the callers that need every vertex check
    for that (:func:`checked_vertices`, the mp-LP explorer's facet check).
``tol`` and ``rtol`` (feasibility)
    A solution is a vertex when ``A x <= b + tol + rtol |b|`` for every row. The rounding
    of the solve leaves the rows that are tight at a vertex slightly violated -- notably
    at a degenerate vertex, where more than d facets meet and the rows outside the subset
    are tight too; the tolerance keeps such vertices. Too wide a tolerance would admit
    points just outside the polytope (where a nearly redundant row cuts a corner off).
    The callers choose (``tol`` is in units of ``x``):

    * the mp-LP explorer: its touch tolerance ``1e-11 * scale``, ``rtol = 0``;
    * reachability (:func:`checked_vertices`): ``1e-10``, ``rtol = 0``;
    * drawings (figures, recordings): ``1e-9`` with ``rtol = 1e-9``, for sets whose
      offsets ``b`` have any magnitude.
``tol`` again (merging)
    The solutions of the subsets that meet at a degenerate vertex differ by rounding only,
    far below ``tol``: solutions that round to the same multiple of ``tol`` are one vertex
    (the first found, in subset order, is kept).
``FACET_TOL = 1e-8`` and the edge tolerances (the completeness checks of
:func:`checked_vertices`)
    A vertex is on a facet when its distance to the facet's hyperplane is at most
    ``FACET_TOL``. For the edges: a row is tight at a vertex within the enumeration's
    ``tol``; a unit direction leaves a row's hyperplane when it gains more than ``1e-9``
    on it; an edge's end is a found vertex when within ``1e-9 (1 + |x|)`` of one (a missed
    vertex that close to a found one is within the enumeration's own accuracy).
``_SPAN_TOL = 1e-6`` (:func:`vertices_in_boxes`)
    Vertices span their box when they reach each side to ``1e-6 (1 + |box|)``; the boxes
    come from LPs accurate to ~1e-9, so a larger gap means the polytope does not fill it.
``max_combos`` (a budget, not a tolerance)
    A polytope with more d-subsets than this is not enumerated (None): the callers fall
    back to LPs (``MAX_COMBOS = 20_000``), or take a larger budget where they have no
    fallback (recordings: 50,000; 2-D sections: none).

:func:`checked_vertices` is the *sound* variant for reachability: points whose convex hull
contains the polytope -- its vertices when their enumeration passes a completeness check,
else the corners of its bounding box.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from math import comb

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.geometry.polytope import (
    _highs_box_lps,
    _highs_lp,
    chebyshev_ball,
    minimal_rows,
    normalize_rows,
    solve_lp,
)
from codev_engine.limits import beat

__all__ = [
    "DET_TOL",
    "FACET_TOL",
    "MAX_COMBOS",
    "box_corners",
    "checked_piece",
    "hull_vertices",
    "checked_vertices",
    "packed_vertices",
    "vertices",
    "vertices_in_boxes",
    "vertices_many",
]

#: |det| of d unit rows below this: the rows are (nearly) dependent, no vertex from them
DET_TOL = 1e-12
#: a vertex is on a facet (the check of ``checked_vertices``) within this distance
FACET_TOL = 1e-8
#: ``checked_vertices``' edges: a unit direction leaves a row when it gains more than this
_LEAVE_TOL = 1e-9
#: ``checked_vertices``' edges: an edge's end is a found vertex within this of ``1 + |x|``
_END_TOL = 1e-9
#: default budget of d-subsets per polytope (None beyond it)
MAX_COMBOS = 20_000
#: cap on ``polytopes x row subsets x rows`` per vectorised batch
_BATCH = 2_000_000
#: ``vertices_in_boxes``: vertices span their box when they reach each side to this
#: fraction of ``1 + |box|`` (the boxes come from LPs accurate to ~1e-9)
_SPAN_TOL = 1e-6


def vertices(
    A: np.ndarray,
    b: np.ndarray,
    tol: float = 1e-9,
    *,
    rtol: float = 0.0,
    max_combos: int | None = MAX_COMBOS,
) -> np.ndarray | None:
    """Vertices of one polytope ``{x : A x <= b}`` (see the module docstring).

    Parameters
    ----------
    A : (k, d) ndarray
        Rows of unit norm.
    b : (k,) ndarray
    tol : float
        Absolute feasibility tolerance, also the grid on which vertices are merged.
    rtol : float
        Feasibility tolerance relative to ``|b_j|``.
    max_combos : int or None
        Give up (None) beyond this many d-subsets of the rows; None for no limit.

    Returns
    -------
    (v, d) ndarray or None
        The distinct vertices, in the order of the first subset that gives each; none when
        the polytope is empty, has fewer than d rows or has no vertex; None when the
        enumeration would exceed ``max_combos``.
    """
    return vertices_many([A], [b], tol, rtol=rtol, max_combos=max_combos)[0]


def vertices_many(
    As: Sequence[np.ndarray],
    bs: Sequence[np.ndarray],
    tol: float = 1e-9,
    *,
    rtol: float = 0.0,
    max_combos: int | None = MAX_COMBOS,
) -> list[np.ndarray | None]:
    """Vertices of many polytopes ``{x : A_i x <= b_i}`` of one dimension, vectorised.

    Same result for each polytope as :func:`vertices` (see :func:`packed_vertices`).

    Parameters
    ----------
    As : sequence of (k_i, d) ndarray
        Rows of unit norm.
    bs : sequence of (k_i,) ndarray
    tol : float
        Absolute feasibility tolerance, also the grid on which vertices are merged.
    rtol : float
        Feasibility tolerance relative to ``|b_j|``.
    max_combos : int or None
        Give up on a polytope (None) beyond this many d-subsets; None for no limit.

    Returns
    -------
    list of (v_i, d) ndarray or None
        As :func:`vertices`, one entry per polytope.
    """
    R = len(As)
    if R == 0:
        return []
    offsets = np.concatenate([[0], np.cumsum([np.shape(A)[0] for A in As])])
    V, owner, done = packed_vertices(
        np.vstack(As), np.concatenate(bs), offsets, tol, rtol=rtol, max_combos=max_combos
    )
    parts = np.split(V, np.cumsum(np.bincount(owner, minlength=R))[:-1])
    return [parts[i] if done[i] else None for i in range(R)]


def packed_vertices(
    A: np.ndarray,
    b: np.ndarray,
    offsets: np.ndarray,
    tol: float = 1e-9,
    *,
    rtol: float = 0.0,
    max_combos: int | None = MAX_COMBOS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices of polytopes packed in flat arrays (region after region), vectorised.

    The polytopes with the same number of rows are solved together, in batches of at most
    ``2e6`` subset rows; each polytope's result is that of :func:`vertices`.

    Parameters
    ----------
    A : (q, d) ndarray
        The polytopes' rows (unit norm), polytope after polytope.
    b : (q,) ndarray
    offsets : (R + 1,) ndarray of int
        Polytope ``i``'s rows are ``A[offsets[i]:offsets[i + 1]]``.
    tol : float
        Absolute feasibility tolerance, also the grid on which vertices are merged.
    rtol : float
        Feasibility tolerance relative to ``|b_j|``.
    max_combos : int or None
        Give up on a polytope beyond this many d-subsets; None for no limit.

    Returns
    -------
    V : (N, d) ndarray
        The vertices, polytope after polytope (each in the order of :func:`vertices`).
    owner : (N,) ndarray of int
        The polytope of each vertex (non-decreasing).
    enumerated : (R,) bool ndarray
        False for the polytopes given up on (they have no vertices in ``V``).
    """
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    offsets = np.asarray(offsets, dtype=np.intp)
    d = A.shape[1]
    counts = np.diff(offsets)
    enumerated = np.ones(counts.shape[0], dtype=bool)
    found_V, found_owner = [np.zeros((0, d))], [np.zeros(0, dtype=np.intp)]
    for k in np.unique(counts):
        k = int(k)
        members = np.flatnonzero(counts == k)
        if k < d:  # no vertex
            continue
        C = comb(k, d)
        if max_combos is not None and C > max_combos:
            enumerated[members] = False
            continue
        idx = np.array(list(combinations(range(k), d)), dtype=np.intp).reshape(C, d)
        per = max(1, _BATCH // (C * k))
        for s in range(0, members.size, per):
            sel = members[s : s + per]
            rows = offsets[sel][:, None] + np.arange(k)  # (G, k)
            g, X = _enumerate(A[rows], b[rows], idx, tol, rtol)
            found_V.append(X)
            found_owner.append(sel[g])
    V, owner = np.concatenate(found_V), np.concatenate(found_owner)
    order = np.argsort(owner, kind="stable")
    return V[order], owner[order], enumerated


def _enumerate(
    A: np.ndarray, b: np.ndarray, idx: np.ndarray, tol: float, rtol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of G polytopes of k rows each, ``A`` (G, k, d), ``b`` (G, k), from the row
    subsets ``idx`` (C, d) -> the polytope of each (N,), non-decreasing, and the vertices
    (N, d)."""
    beat("vertex enumeration")
    G, k, d = A.shape
    C = idx.shape[0]
    bound = b + (tol + rtol * np.abs(b))  # (G, k) what A x may reach
    # subsets per step: all of them, unless one polytope has too many (then G == 1, and
    # the steps' results come in subset order)
    chunk = max(1, _BATCH // (G * k))
    found_g, found_X = [], []
    for s in range(0, C, chunk):
        sub = idx[s : s + chunk]
        M = A[:, sub]  # (G, c, d, d)
        with np.errstate(all="ignore"):
            det = np.linalg.det(M)
        g, c = np.nonzero(np.abs(det) > DET_TOL)
        if g.size == 0:
            continue
        X = np.linalg.solve(M[g, c], b[:, sub][g, c][..., None])[..., 0]  # (N, d)
        if G == 1:  # one polytope: one matrix product
            feas = np.all(X @ A[0].T <= bound[0], axis=1)
        else:
            feas = np.all(np.einsum("nkd,nd->nk", A[g], X) <= bound[g], axis=1)
        found_g.append(g[feas])
        found_X.append(X[feas])
    if not found_g:
        return np.zeros(0, dtype=np.intp), np.zeros((0, d))
    g, X = np.concatenate(found_g), np.concatenate(found_X)
    if g.size == 0:
        return g, X
    # merge: the first solution of each vertex on the grid ``tol`` (see the module docstring)
    _, first = np.unique(np.column_stack([g, np.round(X / tol)]), axis=0, return_index=True)
    first.sort()
    return g[first], X[first]


def hull_vertices(
    A: np.ndarray, b: np.ndarray, offsets: np.ndarray, which: np.ndarray, tol: float = 1e-9
) -> tuple[list[np.ndarray | None], np.ndarray]:
    """Vertices of the polytopes ``which`` by Qhull's halfspace intersection (pivoting on
    the dual hull), for polytopes with too many d-subsets of rows for :func:`vertices`.

    Each polytope gets a strict interior point, the centre of its largest ball (a
    compiled LP, ``lp_kernel.chebyshev``), and ``scipy.spatial.HalfspaceIntersection``
    intersects its rows from there: one point per facet of the dual hull, i.e. per
    vertex (a degenerate vertex, where more than d facets meet, may come several times;
    such points are merged on the grid ``tol`` as in :func:`vertices`). The cost grows
    with the vertices, not with ``C(k, d)``: a region of 30 rows in 5 dimensions has
    ~1.4e5 row subsets but some tens of vertices.

    Qhull's points come from its dual facets (off by up to ~1e-8 on badly scaled
    polytopes); each is solved again on the rows that meet there (:func:`_polished`).
    No vertex is dropped for a feasibility test, and nothing here proves the list
    complete: a caller that needs every vertex keeps its own check (the search tree's:
    the vertices span the polytope's box and are closed under its edges). A polytope
    that is unbounded, has no interior ball (radius <= 1e-12) or that Qhull rejects
    gives None: the caller falls back as for a polytope over the subset budget.

    Parameters
    ----------
    A : (q, d) ndarray
        The polytopes' rows (unit norm), polytope after polytope.
    b : (q,) ndarray
    offsets : (R + 1,) ndarray of int
        Polytope ``i``'s rows are ``A[offsets[i]:offsets[i + 1]]``.
    which : (w,) ndarray of int
        The polytopes to enumerate.
    tol : float
        The grid on which repeated points are merged.

    Returns
    -------
    vertices : list of (v, d) ndarray or None
        One entry per polytope of ``which``, None where given up.
    seconds : (w,) ndarray
        CPU seconds spent per polytope (the LP and Qhull).
    """
    import time

    from scipy.spatial import HalfspaceIntersection, QhullError

    from codev_engine.geometry.lp_kernel import OPTIMAL, chebyshev

    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    d = A.shape[1]
    out: list[np.ndarray | None] = []
    secs = np.zeros(len(which))
    for n, i in enumerate(which):
        t0 = time.process_time()
        Ai = np.ascontiguousarray(A[offsets[i] : offsets[i + 1]])
        bi = np.ascontiguousarray(b[offsets[i] : offsets[i + 1]])
        # (the bound only enters the LP's duality bound, unused here)
        status, centre, radius, _ = chebyshev(Ai, bi, np.zeros(d), 1.0, 500)
        V = None
        if status == OPTIMAL and radius > 1e-12 and Ai.shape[0] > d:
            try:
                hs = HalfspaceIntersection(np.column_stack([Ai, -bi]), centre)
                V = _polished(hs.intersections, hs.dual_facets, Ai, bi, tol)
            except (QhullError, ValueError):
                V = None
        out.append(V)
        secs[n] = time.process_time() - t0
    return out, secs


def _polished(
    X: np.ndarray, facets: list, A: np.ndarray, b: np.ndarray, tol: float
) -> np.ndarray | None:
    """Qhull's intersections ``X`` solved again on the rows that meet at each (``facets``,
    least squares: Qhull's own points come from its dual facets, off by ~1e-9 on a
    badly scaled region), the better of the two kept; merged on the grid ``tol``. None
    when a point is not finite or violates a row by more than ``1e-6 (1 + |x|)`` (an
    unbounded polytope: the dual hull does not surround the origin)."""
    if X.shape[0] == 0 or not np.all(np.isfinite(X)):
        return None
    d = A.shape[1]
    sol = X.copy()
    simple = np.array([len(f) == d for f in facets], dtype=bool)
    if np.any(simple):  # d rows meet: one batched solve
        idx = np.array([f for f, s in zip(facets, simple, strict=True) if s], dtype=np.intp)
        M = A[idx]
        good = np.abs(np.linalg.det(M)) > DET_TOL
        if np.any(good):
            part = sol[simple]
            part[good] = np.linalg.solve(M[good], b[idx[good]][..., None])[..., 0]
            sol[simple] = part
    for j in np.flatnonzero(~simple):  # a degenerate vertex: least squares
        rows = np.asarray(facets[j], dtype=np.intp)
        sol[j] = np.linalg.lstsq(A[rows], b[rows], rcond=None)[0]
    # the better of Qhull's point and the solve (largest violation of a row)
    finite = np.all(np.isfinite(sol), axis=1)
    sol[~finite] = X[~finite]
    better = (sol @ A.T - b).max(axis=1) <= (X @ A.T - b).max(axis=1)
    out = np.where(better[:, None], sol, X)
    viol = (out @ A.T - b[None, :]).max(axis=1)
    if np.any(viol > 1e-6 * (1.0 + np.abs(out).max(axis=1))):
        return None
    _, first = np.unique(np.round(out / tol), axis=0, return_index=True)
    return out[np.sort(first)]


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The ``2^d`` corners of the box ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : (d,) ndarray

    Returns
    -------
    (2^d, d) ndarray
        In binary order, the last coordinate fastest (``lo`` first, ``hi`` last).
    """
    d = lo.shape[0]
    grids = np.stack(np.meshgrid(*[[lo[j], hi[j]] for j in range(d)], indexing="ij"), -1)
    return grids.reshape(-1, d)


def checked_vertices(A: np.ndarray, b: np.ndarray, tol: float = 1e-10) -> np.ndarray:
    """Points whose convex hull contains the bounded polytope ``{x : A x <= b}`` (sound).

    Reachability bounds sets by their vertices, so a lost vertex would shrink the reach
    set. The enumeration (:func:`vertices`, ``rtol = 0``) is accepted only if it is
    complete:

    * it has more than d vertices and every row carries at least d of them within
      ``FACET_TOL`` (true for every facet of a polytope);
    * every edge that leaves one of them ends at one of them. The vertices and edges of a
      polytope form a connected graph (Balinski's theorem), so a set of its vertices that
      no edge leaves is all of them. (The facet count alone misses, e.g., a cube without
      one corner.)

    Otherwise the corners of the polytope's bounding box (2d LPs) are returned, which
    over-approximate: they are no points of the polytope in general, so a caller must
    never take one for a state (an LP over the rows decides what is attained).

    A thin polytope (an interior ball of radius ~1e-10, a sliver between a region's row
    and its slack) can defeat the bounding box LPs, which then call it infeasible within
    their own tolerances although it is not empty. Such a polytope is never dropped: its
    box is taken from the rows relaxed by ``_BLOAT (1 + |b|)``, a superset, and widened by
    the same amount (far above the LPs' tolerances, ~1e-9), which still contains it.

    Parameters
    ----------
    A : (k, d) ndarray
        Non-redundant rows of unit norm (a redundant row carries no vertex and forces the
        bounding box).
    b : (k,) ndarray
    tol : float
        Feasibility tolerance of the enumeration (absolute).

    Returns
    -------
    (v, d) ndarray

    Raises
    ------
    ValueError
        The polytope is unbounded (a bounding box LP is unbounded), or even the relaxed
        rows' box LPs fail: no enclosing points (the caller keeps a superset it knows).
    """
    V = _complete_vertices(A, b, tol)
    if V is not None:
        return V
    try:
        lo, hi, certified = _bounding_box(A, b)
        if not certified:  # a side from HiGHS: its tolerances (~1e-7 relative) covered
            widen = _BLOAT * (1.0 + np.abs(b).max() + np.maximum(np.abs(lo), np.abs(hi)))
            lo, hi = lo - widen, hi + widen
    except SolverError:
        # a thin polytope the LPs call infeasible within their tolerances: the box of the
        # relaxed rows (a superset), widened by the relaxation (module docstring)
        pad = _BLOAT * (1.0 + np.abs(b))
        try:
            lo, hi, _ = _bounding_box(A, b + pad)
        except SolverError as exc:
            raise ValueError(f"no bounding box for a degenerate polytope: {exc}") from exc
        widen = _BLOAT * (1.0 + np.abs(b).max() + np.maximum(np.abs(lo), np.abs(hi)))
        lo, hi = lo - widen, hi + widen
    return box_corners(lo, hi)


def _complete_vertices(A: np.ndarray, b: np.ndarray, tol: float) -> np.ndarray | None:
    """The vertices of ``{A x <= b}`` (v, d) when their enumeration passes the completeness
    checks of :func:`checked_vertices`, else None."""
    d = A.shape[1]
    V = vertices(A, b, tol)
    if V is not None and V.shape[0] > d:
        on = np.abs(V @ A.T - b[None, :]) <= FACET_TOL
        if np.all(on.sum(axis=0) >= d) and _closed_under_edges(V, A, b, tol):
            return V
    return None


#: relative relaxation of a thin polytope's rows (its bounding box LPs failed, or its
#: interior ball is below ``_THIN``): a superset with an interior
_BLOAT = 1e-7
#: an interior radius below which a piece is decided again (HiGHS) and relaxed if kept
_THIN = 1e-9
#: a piece whose Chebyshev radius is below ``-_EMPTY`` (DAQP's: ``-_EMPTY (1 + max |b|)``)
#: is empty (dropped)
_EMPTY = 1e-6


def _bounding_box(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """The bounding box ``(lo, hi)`` of ``{A x <= b}`` by 2d LPs, and whether every side is
    DAQP's with a certificate (else some come from HiGHS: :func:`_box_side`). SolverError
    when one has no solution, ValueError when unbounded."""
    d = A.shape[1]
    lo, hi = np.empty(d), np.empty(d)
    certified = True
    for j in range(d):
        e = np.zeros(d)
        e[j] = 1.0
        lo[j], ok_lo = _box_side(e, A, b)
        v, ok_hi = _box_side(-e, A, b)
        hi[j] = -v
        certified = certified and ok_lo and ok_hi
    return lo, hi, certified


def _closed_under_edges(V: np.ndarray, A: np.ndarray, b: np.ndarray, tol: float) -> bool:
    """Whether every edge of ``{A x <= b}`` that leaves a vertex of ``V`` (v, d) ends at a
    vertex of ``V`` (and none is unbounded).

    The edges at a vertex are the extreme rays of its tangent cone ``{e : A_T e <= 0}``
    (``T`` its tight rows): the null direction of d - 1 independent tight rows that
    leaves no tight row. Each is followed to the first row it meets.
    """
    beat("vertex enumeration")
    nv, d = V.shape
    slack = b[None, :] - V @ A.T  # (v, k)
    tight = np.abs(slack) <= tol
    if np.any(tight.sum(axis=1) < d):
        return False
    at, subsets = [], []
    for i in range(nv):
        for S in combinations(np.flatnonzero(tight[i]), d - 1):
            at.append(i)
            subsets.append(S)
    at = np.array(at, dtype=np.intp)
    if d == 1:
        E = np.ones((at.size, 1))
    else:
        _, sv, Vt = np.linalg.svd(A[np.array(subsets, dtype=np.intp)])  # (N, d-1, d)
        independent = sv[:, -1] > DET_TOL
        at, E = at[independent], Vt[independent, -1]
    at, E = np.concatenate([at, at]), np.concatenate([E, -E])
    AE = E @ A.T  # (N, k) what each direction gains on each row
    ray = ~np.any(tight[at] & (AE > _LEAVE_TOL), axis=1)  # in the tangent cone
    at, E, AE = at[ray], E[ray], AE[ray]
    meets = AE > _LEAVE_TOL
    if not np.all(meets.any(axis=1)):
        return False  # an unbounded edge
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(meets, slack[at] / AE, np.inf).min(axis=1)
    W = V[at] + t[:, None] * E  # the edges' ends
    gap = np.abs(W[:, None, :] - V[None]).max(axis=2).min(axis=1)
    return bool(np.all(gap <= _END_TOL * (1.0 + np.abs(W).max(axis=1))))


def _box_side(f: np.ndarray, A: np.ndarray, b: np.ndarray) -> tuple[float, bool]:
    """The minimum of ``f x`` over ``A x <= b`` (a bounding box LP), and whether it is
    DAQP's with a certificate.

    DAQP's answer is taken when its multipliers ``lam`` (``f + A' lam = 0``) prove it:
    ``f x`` within ``_GAP (1 + |f x|)`` of the dual bound ``-b' lam`` and a dual residual
    below ``_GAP``. On a long, thin piece (AFTI-16 with ``domain_bound = 1000``: 3e-7 thick,
    500 long) DAQP called the set infeasible, or stopped 4e-5 short of the minimum (gap
    1.2e-4, residual 5e-7): a box side inside the set, which would lose states. Then HiGHS
    answers (its optimum satisfied the rows to 1e-15 there; the caller widens its box).
    """
    x, status, lam = solve_lp(f, A, b)
    if status == "unbounded":
        raise ValueError("an unbounded polytope has no enclosing vertices")
    value = _proved(f, A, b, x, lam)
    if value is not None:
        return value, True
    x, _ = _highs_lp(f, A, b)
    if x is None:  # DAQP's failure confirmed (infeasible, or no optimum)
        raise SolverError(f"the bounding box LP of a polytope is {status} (empty, or failed)")
    return float(f @ x), False


def _proved(f: np.ndarray, A: np.ndarray, b: np.ndarray, x: np.ndarray | None,
            lam: np.ndarray | None) -> float | None:
    """DAQP's minimum ``f x`` (solution ``x`` (d,), multipliers ``lam``) of ``min f x``
    over ``A x <= b`` when its multipliers prove it (:func:`_box_side`'s rule), else None."""
    if x is None or lam is None:
        return None
    lam = lam[: b.shape[0]]
    value = float(f @ x)
    gap = abs(value + float(b @ lam))
    if gap <= _GAP * (1.0 + abs(value)) and np.abs(f + A.T @ lam).sum() <= _GAP:
        return value
    return None


#: a bounding box LP's duality gap (relative) and dual residual within which DAQP's
#: optimum is taken (its tolerances are 1e-11 and 1e-12: a larger gap is a failure)
_GAP = 1e-9


def vertices_in_boxes(
    As: Sequence[np.ndarray],
    bs: Sequence[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    tol: float = 1e-9,
    *,
    rtol: float = 0.0,
    max_combos: int | None = MAX_COMBOS,
) -> tuple[list[np.ndarray | None], list[np.ndarray], list[np.ndarray]]:
    """Vertices of polytopes clipped to their boxes, ``{x : A_i x <= b_i, lo_i <= x <= hi_i}``.

    Fast path: the polytopes' own rows. A polytope whose vertices do not reach every side
    of its box (unbounded, or a box wider than the polytope) is enumerated again with the
    box's rows added, which bounds it (and changes nothing for a bounded polytope inside
    its box).

    Parameters
    ----------
    As : sequence of (k_i, d) ndarray
        Rows of unit norm.
    bs : sequence of (k_i,) ndarray
    lo, hi : (R, d) ndarray
        The boxes (finite), e.g. the polytopes' bounding boxes.
    tol, rtol, max_combos
        As in :func:`vertices_many`.

    Returns
    -------
    vertices : list of (v_i, d) ndarray or None
    A, b : list of ndarray
        The rows the vertices were enumerated from (the box rows appended where used).
    """
    V = vertices_many(As, bs, tol, rtol=rtol, max_combos=max_combos)
    As, bs = list(As), list(bs)
    d = lo.shape[1]
    eye = np.vstack([np.eye(d), -np.eye(d)])
    redo = []
    for i, v in enumerate(V):
        if v is None or v.shape[0] == 0:
            redo.append(i)
            continue
        gap = _SPAN_TOL * (1.0 + max(np.abs(lo[i]).max(), np.abs(hi[i]).max()))
        if np.abs(v.min(axis=0) - lo[i]).max() > gap or np.abs(v.max(axis=0) - hi[i]).max() > gap:
            redo.append(i)
    if redo:
        for i in redo:
            As[i] = np.vstack([As[i], eye])
            bs[i] = np.concatenate([bs[i], hi[i], -lo[i]])
        again = vertices_many(
            [As[i] for i in redo], [bs[i] for i in redo], tol, rtol=rtol, max_combos=max_combos
        )
        for i, v in zip(redo, again, strict=True):
            V[i] = v
    return V, As, bs


def checked_piece(
    A: np.ndarray, b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A polytope ``{x : A x <= b}`` made ready for reachability, or None when it is empty.

    The rows are normalised, the set is dropped when it is empty, the redundant rows are
    removed and the set is bounded by :func:`checked_vertices` -- the sequence both reach
    engines run on a set cut by a critical region.

    Dropping is sound only for a set that is truly empty. The reach engines cut sets by a
    region's rows relaxed by 1e-9 (and the rounding bound), so a set that holds a state of
    the region yields a piece with an interior ball of radius ~1e-10 or more, which an LP
    can misjudge within its tolerances. So a piece is dropped only when DAQP's Chebyshev
    radius is below ``-_EMPTY (1 + max |b|)`` (every point violates some row by more than
    1e-6 of the offsets: empty far beyond DAQP's accuracy, which is relative on badly
    scaled rows); a radius in ``[-_EMPTY (1 + max |b|), _THIN]`` (thin, flat, or empty
    within tolerance) is decided again by HiGHS, and unless HiGHS finds it empty by more
    than ``_EMPTY`` the piece is kept with its rows relaxed by ``_BLOAT (1 + |b|)``
    (plus twice a negative radius):
    a superset with an interior, which over-approximates (never an exception, never a
    state lost).

    Parameters
    ----------
    A : (k, d) ndarray
        Rows of the polytope, any scale.
    b : (k,) ndarray
        Right-hand sides.

    Returns
    -------
    tuple of ((k', d) ndarray, (k',) ndarray, (v, d) ndarray) or None
        The non-redundant unit rows, their right-hand sides and points whose convex hull
        contains the polytope; None when the polytope is empty.
    """
    A, b, ok = normalize_rows(A, b)
    if not ok:
        return None
    centre, radius, y = chebyshev_ball(A, b, multipliers=True)
    # DAQP's radius is off by up to ~1e-9 of the offsets on badly scaled rows (AFTI-16,
    # offsets 1000: -1.2e-6 for a piece HiGHS gives +1.5e-7): its "empty" is relative
    if radius < -_EMPTY * (1.0 + float(np.abs(b).max())):
        return None
    # (no multipliers: solve_lp found DAQP's answer unproved and HiGHS gave the radius,
    # a piece DAQP misjudges, whose rows DAQP's minrep would cut wrongly too)
    if not radius > _THIN or y is None:
        # thin, flat or empty within the LP's tolerance: HiGHS decides, else a superset.
        # A centre strictly inside every row proves the piece is not empty: HiGHS could
        # only confirm that it is kept (relaxed when thin; its "thicker than _THIN" is
        # within its own 1e-7 tolerances), so it is not asked again (a sliver along a
        # region's face, the common case: ~0.5 ms of HiGHS each)
        if not (radius > 0.0 and _strictly_inside(A, b, centre)):
            _, radius = chebyshev_ball(A, b, solver="highs")
            if radius < -_EMPTY and np.isfinite(radius):
                return None
        if not radius > _THIN:  # (or HiGHS failed: kept, relaxed)
            radius = radius if np.isfinite(radius) else 0.0
            b = b + _BLOAT * (1.0 + np.abs(b)) + 2.0 * max(-float(radius), 0.0)
        return _highs_piece(A, b)  # (DAQP misjudged it: proved LPs decide the rest)
    keep = minimal_rows(A, b)
    A, b = A[keep], b[keep]
    return A, b, checked_vertices(A, b)


def _highs_piece(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`checked_piece` of a piece whose Chebyshev radius DAQP misjudged (thin by
    DAQP's LP, HiGHS decided or a centre proved it not empty; a thin one's rows already
    relaxed), decided by proved LPs alone.

    DAQP misjudges sets that are long as well as thin (AFTI-16 with ``domain_bound =
    1000``: a piece 3e-7 thick and 50 long, its states ~500): its box LPs call the set
    infeasible, or return a side 4e-5 short of HiGHS's (whose optimum satisfies every row
    to 1e-15), its ``minrep`` drops rows that are not redundant (the kept rows stretched
    the piece to the law's domain, 10x longer), and its Chebyshev radius was -3e-5 for a
    piece of radius 2e-5. So the box is
    over all the rows, by DAQP's LPs where their multipliers prove every side, else by
    HiGHS's (:func:`_highs_box`), widened by ``_BLOAT (1 + |b| + |box|)`` (far above
    either's tolerances, 1e-7 relative for HiGHS); minrep's rows are kept only when their
    own box is that box (else all the rows: sound, only slower); the vertices are the
    enumeration's when it passes its completeness checks, else the widened box's corners.

    Parameters
    ----------
    A : (k, d) ndarray
        Unit rows.
    b : (k,) ndarray
        Offsets (relaxed, for a thin piece).

    Returns
    -------
    tuple of ((k', d) ndarray, (k',) ndarray, (v, d) ndarray)
        As :func:`checked_piece`.

    Raises
    ------
    ValueError
        HiGHS finds no box (the relaxed rows unbounded, or its LPs fail).
    """
    beat("a piece decided by HiGHS")
    lo, hi = _highs_box(A, b)
    widen = _BLOAT * (1.0 + np.abs(b).max() + np.maximum(np.abs(lo), np.abs(hi)))
    keep = minimal_rows(A, b)
    if keep.size < A.shape[0]:
        try:
            lo_k, hi_k = _highs_box(A[keep], b[keep])
        except ValueError:
            lo_k, hi_k = lo - 2 * widen, hi + 2 * widen
        if np.any(lo_k < lo - widen) or np.any(hi_k > hi + widen):
            keep = np.arange(A.shape[0])  # minrep dropped a row that cuts the piece
    A, b = A[keep], b[keep]
    V = _complete_vertices(A, b, 1e-10)
    if V is None:
        V = box_corners(lo - widen, hi + widen)
    return A, b, V


def _strictly_inside(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> bool:
    """Whether ``A x < b`` (unit rows (k, d), offsets (k,), point (d,)) holds beyond the
    rounding of ``A x`` (a point of the polytope: it is not empty)."""
    if not np.all(np.isfinite(x)):
        return False
    slack = b - A @ x
    return bool(np.all(slack > 1e-14 * (1.0 + np.abs(A) @ np.abs(x) + np.abs(b))))


def _highs_box(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box (lo, hi) of ``{A x <= b}``: DAQP's when every side is proved
    (:func:`_proved_box`), else by 2d HiGHS LPs in one model (``polytope._highs_box_lps``;
    ValueError when one has no optimum). The callers widen it by ``_BLOAT``, far above
    either's accuracy."""
    box = _proved_box(A, b)
    if box is None:
        box = _highs_box_lps(A, b)
    if box is None:
        raise ValueError("no bounding box for a degenerate polytope (HiGHS finds no "
                         "optimum)")
    return box


def _proved_box(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The bounding box (lo, hi) of ``{A x <= b}`` by DAQP's 2d LPs, each side proved by
    its multipliers (:func:`_proved`: within ``_GAP`` of a lower bound of the minimum by
    weak duality, whatever the set's shape -- a long, thin piece's unproved answers are
    what misled it); None at the first side without a proof (~20x cheaper than HiGHS's
    model when it succeeds, the common case)."""
    d = A.shape[1]
    lo, hi = np.empty(d), np.empty(d)
    for j in range(d):
        for sign, side in ((1.0, lo), (-1.0, hi)):
            f = np.zeros(d)
            f[j] = sign
            x, status, lam = solve_lp(f, A, b)
            if status != "optimal" or lam is None or np.any(lam[: b.shape[0]] < 0.0):
                return None  # (weak duality needs the multipliers >= 0)
            value = _proved(f, A, b, x, lam)
            if value is None:
                return None
            side[j] = sign * value
    return lo, hi
