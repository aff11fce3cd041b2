"""The one vertex enumeration (codev_engine.geometry.vertices).

Three contracts, one per kind of caller:

- the mp-LP explorer and reachability call ``vertices(A, b, tol=...)`` (absolute tolerance):
  the result is the one of the enumeration they used before the merge (``_reference``
  below, kept verbatim from ``geometry/polytope.py``), bit for bit, on random and
  degenerate polytopes in 2-D to 4-D;
- drawings call it with a relative tolerance: the vertices are Qhull's (the halfspace
  intersection), each once;
- reachability needs a sound enclosure (``checked_vertices``): the hull of what it returns
  holds every point of the polytope, whether the enumeration was accepted or the bounding
  box taken.
"""

from __future__ import annotations

from itertools import combinations
from math import comb

import numpy as np
import pytest
from scipy.spatial import ConvexHull, HalfspaceIntersection

from codev_engine.geometry import vertices as vx
from codev_engine.geometry.polytope import bounding_box, chebyshev_ball, normalize_rows
from codev_engine.geometry.vertices import (
    box_corners,
    checked_vertices,
    packed_vertices,
    vertices,
    vertices_in_boxes,
    vertices_many,
)


def _reference(A: np.ndarray, b: np.ndarray, tol: float = 1e-9, max_combos: int = 20_000):
    """``geometry.polytope.vertices`` before the merge (commit 3a1c4cc), verbatim."""
    k, d = A.shape
    if k < d or comb(k, d) > max_combos:
        return None
    idx = np.array(list(combinations(range(k), d)), dtype=int)
    M = A[idx]
    rhs = b[idx]
    det = np.linalg.det(M)
    ok = np.abs(det) > 1e-12
    if not np.any(ok):
        return np.zeros((0, d))
    X = np.linalg.solve(M[ok], rhs[ok][..., None])[..., 0]
    feas = np.all(X @ A.T <= b + tol, axis=1)
    V = X[feas]
    if V.shape[0] == 0:
        return V
    _, first = np.unique(np.round(V / tol), axis=0, return_index=True)
    return V[np.sort(first)]


def _random_polytope(rng: np.random.Generator, d: int) -> tuple[np.ndarray, np.ndarray]:
    """A bounded polytope around the origin: random unit rows plus a box, random offsets."""
    k = int(rng.integers(1, 9))
    A = np.vstack([rng.normal(size=(k, d)), np.eye(d), -np.eye(d)])
    b = np.concatenate([rng.uniform(0.2, 2.0, k), rng.uniform(1.0, 3.0, 2 * d)])
    A, b, ok = normalize_rows(A, b)
    assert ok
    return A, b


def _degenerate_polytopes(d: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Repeated rows, many facets through one vertex, a cube with a redundant row."""
    out = []
    cube = np.vstack([np.eye(d), -np.eye(d)]), np.ones(2 * d)
    out.append((np.vstack([cube[0], cube[0][:2]]), np.concatenate([cube[1], cube[1][:2]])))
    # a pyramid: seven facets through its apex (0, .., 0, 1), cut by x_d >= 0 (in 2-D the
    # sides repeat: cos is even; in 4-D the apex is an edge, cut by |x_2| <= 3)
    m = 7
    ang = 2 * np.pi * np.arange(m) / m
    sides = np.zeros((m, d))
    sides[:, 0] = np.cos(ang)
    if d > 2:
        sides[:, 1] = np.sin(ang)
    sides[:, -1] = 1.0
    middle = np.eye(d)[2:-1]
    A = np.vstack([sides, -np.eye(d)[-1:], middle, -middle])
    b = np.concatenate([np.ones(m), [0.0], np.full(2 * middle.shape[0], 3.0)])
    A, b, _ = normalize_rows(A, b)
    out.append((A, b))
    # the cube with a redundant row (x_0 <= 2) and a row touching a corner (sum x <= d)
    extra = np.vstack([np.eye(d)[:1], np.ones((1, d))])
    A, b, _ = normalize_rows(np.vstack([cube[0], extra]), np.concatenate([cube[1], [2.0, d]]))
    out.append((A, b))
    return out


def _sharp_polytopes(d: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Where the tolerances decide: a vertex between facets at 1e-11 rad (|det| ~ 2e-11), and
    a box of half-width 10 with a corner cut off at 1e-8, 3e-10 and 2e-11 from the corner
    (new vertices that close to each other; the corner just outside the cut)."""
    out = []
    eps = 1e-11
    roof = np.zeros((2, d))
    roof[:, 0] = [np.sin(eps), -np.sin(eps)]
    roof[:, -1] = np.cos(eps)
    eye = np.eye(d)
    A = np.vstack([roof, eye[:-1], -eye])
    out.append((A, np.ones(A.shape[0])))
    for delta in (1e-8, 3e-10, 2e-11):
        cut = np.ones((1, d)) / np.sqrt(d)
        A = np.vstack([eye, -eye, cut])
        out.append((A, np.r_[np.full(2 * d, 10.0), 10.0 * np.sqrt(d) - delta]))
    return out


def _hull_points(rng: np.random.Generator, A: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Points of ``{A x <= b}`` by rejection in its bounding box (n of them at most)."""
    lo, hi = bounding_box(A, b)
    X = rng.uniform(lo, hi, (20 * n, A.shape[1]))
    return X[np.all(X @ A.T <= b, axis=1)][:n]


def _same_points(P: np.ndarray, Q: np.ndarray, atol: float = 1e-7) -> bool:
    """The same points up to ``atol``, each once (no duplicates on either side)."""
    if P.shape != Q.shape:
        return False
    if P.shape[0] == 0:
        return True
    D = np.abs(P[:, None] - Q[None]).max(axis=2)
    return bool(np.all(np.sum(D <= atol, axis=1) == 1) and np.all(np.sum(D <= atol, axis=0) == 1))


# --------------------------------------------------------------------------------------------
# the absolute-tolerance callers: the enumeration they used, bit for bit
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", [2, 3, 4])
@pytest.mark.parametrize("tol", [1e-9, 1e-10, 1e-11])
def test_matches_the_old_enumeration_bit_for_bit(d, tol):
    rng = np.random.default_rng(100 * d + int(-np.log10(tol)))
    cases = [_random_polytope(rng, d) for _ in range(60)]
    cases += _degenerate_polytopes(d) + _sharp_polytopes(d)
    for A, b in cases:
        old, new = _reference(A, b, tol), vertices(A, b, tol)
        assert old is not None and new is not None
        assert old.shape == new.shape and np.array_equal(old, new)
        # the batched path gives the same, for each polytope of a batch
        for V in vertices_many([A, A[::-1], A], [b, b[::-1], b], tol)[::2]:
            assert np.array_equal(V, new)


def test_the_old_cases_at_the_edges():
    A, b = np.vstack([np.eye(3), -np.eye(3)]), np.ones(6)
    # fewer rows than dimensions: no vertex (the old code said None; callers treat both alike)
    assert _reference(A[:2], b[:2]) is None and vertices(A[:2], b[:2]).shape == (0, 3)
    # over the budget: None, as before
    big = np.tile(A, (4, 1))  # 24 rows in 3-D: C(24, 3) = 2024 subsets
    assert vertices(big, np.tile(b, 4), max_combos=2000) is None
    assert _reference(big, np.tile(b, 4), max_combos=2000) is None
    # repeated rows: each vertex once
    assert vertices(big, np.tile(b, 4)).shape == (8, 3)
    # empty: no vertex
    assert vertices(A, np.array([1.0, 1, 1, -2, 1, 1])).shape == (0, 3)
    # unbounded: the vertices it has (the orthant's apex), none for a slab
    assert np.array_equal(vertices(-np.eye(3), np.zeros(3)), np.zeros((1, 3)))
    assert vertices(np.array([[1.0, 0.0], [-1.0, 0.0]]), np.ones(2)).shape == (0, 2)


def test_subset_batches_keep_the_subset_order(monkeypatch):
    """A polytope whose subsets are solved in several steps gives what one step gives."""
    rng = np.random.default_rng(7)
    cases = [_random_polytope(rng, 3) for _ in range(20)] + _degenerate_polytopes(3)
    whole = [vertices(A, b) for A, b in cases]
    monkeypatch.setattr(vx, "_BATCH", 50)  # a few subsets per step
    for (A, b), V in zip(cases, whole, strict=True):
        assert np.array_equal(vertices(A, b), V)
    many = vertices_many([A for A, _ in cases], [b for _, b in cases])
    assert all(np.array_equal(u, v) for u, v in zip(many, whole, strict=True))


# --------------------------------------------------------------------------------------------
# the drawings' tolerance: Qhull's vertices, each once
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", [2, 3, 4])
def test_vertices_are_qhulls(d):
    rng = np.random.default_rng(d)
    cases = [_random_polytope(rng, d) for _ in range(40)] + _degenerate_polytopes(d)
    got = vertices_many([A for A, _ in cases], [b for _, b in cases], 1e-9, rtol=1e-9)
    for (A, b), V in zip(cases, got, strict=True):
        centre, radius = chebyshev_ball(A, b)
        assert radius > 0
        hs = HalfspaceIntersection(np.column_stack([A, -b]), centre)
        H = hs.intersections[ConvexHull(hs.intersections).vertices]
        assert _same_points(H, V)
        assert _same_points(V, V)  # each vertex once


def test_packed_vertices_owner_and_budget():
    A2 = np.vstack([np.eye(2), -np.eye(2)])
    rows = [A2, A2[:1], np.tile(A2, (60, 1)), A2]
    rhs = [np.ones(4), np.ones(1), np.ones(240), 2 * np.ones(4)]
    offsets = np.cumsum([0] + [r.shape[0] for r in rows])
    V, owner, done = packed_vertices(np.vstack(rows), np.concatenate(rhs), offsets, max_combos=1000)
    assert done.tolist() == [True, True, False, True]  # C(240, 2) > 1000
    assert owner.tolist() == [0] * 4 + [3] * 4
    assert np.allclose(np.abs(V), np.repeat([1.0, 2.0], 4)[:, None])
    many = vertices_many(rows, rhs, max_combos=1000)
    assert many[1].shape == (0, 2) and many[2] is None
    assert np.array_equal(np.vstack([many[0], many[3]]), V)


def test_vertices_in_boxes_clip_unbounded_regions():
    # the orthant x >= 0 and a slab: unbounded, clipped to their boxes
    As = [-np.eye(2), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.vstack([np.eye(2), -np.eye(2)])]
    bs = [np.zeros(2), np.ones(2), np.ones(4)]
    lo = np.array([[0.0, 0.0], [-1.0, -3.0], [-1.0, -1.0]])
    hi = np.array([[2.0, 5.0], [1.0, 3.0], [1.0, 1.0]])
    V, A, b = vertices_in_boxes(As, bs, lo, hi)
    for i in range(3):
        assert _same_points(np.unique(V[i], axis=0), box_corners(lo[i], hi[i]))
    assert A[0].shape == (6, 2) and A[1].shape == (6, 2)  # box rows added
    assert A[2] is As[2]  # a bounded polytope spanning its box: its own rows


# --------------------------------------------------------------------------------------------
# reachability: a sound enclosure
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("d", [2, 3, 4])
def test_checked_vertices_enclose_the_polytope(d):
    rng = np.random.default_rng(40 + d)
    cases = [_random_polytope(rng, d) for _ in range(15)] + _degenerate_polytopes(d)
    for A, b in cases:
        V = checked_vertices(A, b)
        X = _hull_points(rng, A, b, 200)
        hull = ConvexHull(V)
        # every point of P inside conv(V) (hull equations: normal x + offset <= 0)
        assert np.all(X @ hull.equations[:, :-1].T + hull.equations[:, -1] <= 1e-9)


def test_checked_vertices_fall_back_on_the_bounding_box():
    d = 3
    cube = np.vstack([np.eye(d), -np.eye(d)])
    # a complete enumeration is accepted as it is
    V = checked_vertices(cube, np.ones(2 * d))
    assert np.array_equal(V, vertices(cube, np.ones(2 * d), 1e-10))
    # a redundant row carries no vertex: the facet check fails, the box is taken
    A, b, _ = normalize_rows(np.vstack([cube, [[1.0, 1.0, 0.0]]]), np.r_[np.ones(2 * d), 5.0])
    lo, hi = bounding_box(A, b)
    assert np.array_equal(checked_vertices(A, b), box_corners(lo, hi))
    # over the enumeration budget: the box
    A = np.vstack([cube] * 10)  # 60 rows: C(60, 3) = 34,220 subsets
    A = A + 1e-3 * np.random.default_rng(0).normal(size=A.shape)
    A, b, _ = normalize_rows(A, np.ones(A.shape[0]))
    assert vertices(A, b) is None
    assert checked_vertices(A, b).shape == (8, 3)


def test_checked_vertices_refuse_unbounded_sets():
    with pytest.raises(ValueError, match="unbounded"):
        checked_vertices(-np.eye(2), np.zeros(2))


def test_box_corners_order():
    C = box_corners(np.array([0.0, 10.0]), np.array([1.0, 20.0]))
    assert C.tolist() == [[0, 10], [0, 20], [1, 10], [1, 20]]


def test_the_edge_check_finds_a_lost_vertex():
    """A vertex set that misses one vertex of the polytope is not closed under edges, even
    where every facet still carries d of them (the facet count alone would accept it)."""
    rng = np.random.default_rng(5)
    for d in (2, 3, 4):
        cube = np.vstack([np.eye(d), -np.eye(d)]), np.ones(2 * d)
        cases = [cube] + [_random_polytope(rng, d) for _ in range(10)]
        cases += _degenerate_polytopes(d)
        for A, b in cases:
            V = vertices(A, b, 1e-10)
            assert vx._closed_under_edges(V, A, b, 1e-10)
            for i in range(V.shape[0]):
                assert not vx._closed_under_edges(np.delete(V, i, axis=0), A, b, 1e-10)
        # the cube without a corner passes the facet count
        A, b = cube
        V = vertices(A, b, 1e-10)[1:]
        assert d < 3 or np.all((np.abs(V @ A.T - b) <= vx.FACET_TOL).sum(axis=0) >= d)


def _roof(alpha: float = 1e-5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cube ``[-1, 1]^4`` under a low roof of four planes whose normals differ by
    ``alpha``: their apex is a vertex where every 4-subset of the tight rows has
    ``|det| < DET_TOL`` (lost by the row subsets), inside the box spanned by the other
    vertices. Returns the unit rows, offsets and the apex."""
    d = 4
    u = np.full(d, 0.5)
    W = np.linalg.qr(np.column_stack([u, np.eye(d)[:, :3]]))[0][:, 1:]  # u's complement
    dirs = np.vstack([W.T, -W.T.sum(axis=0)])  # 4 directions summing to 0
    N = u[None, :] + alpha * dirs
    N /= np.linalg.norm(N, axis=1)[:, None]
    apex = np.full(d, 0.2)
    A = np.vstack([np.eye(d), -np.eye(d), N])
    b = np.concatenate([np.ones(2 * d), N @ apex])
    return A, b, apex


def test_qhull_finds_a_vertex_the_row_subsets_lose():
    A, b, apex = _roof()
    assert abs(np.linalg.det(A[8:])) < vx.DET_TOL  # the apex's only subset: lost
    by_subsets = vertices(A, b, 1e-10, max_combos=None)
    assert np.abs(by_subsets - apex).max(axis=1).min() > 1e-3
    # ... while the others still span the box: a span check alone would accept them
    assert np.allclose(by_subsets.min(axis=0), -1) and np.allclose(by_subsets.max(axis=0), 1)
    assert not vx._closed_under_edges(by_subsets, A, b, 1e-10)  # the edge check refuses
    (by_hull,), _ = vx.hull_vertices(A, b, np.array([0, A.shape[0]]), np.array([0]), 1e-10)
    assert np.abs(by_hull - apex).max(axis=1).min() < 1e-9
    assert vx._closed_under_edges(by_hull, A, b, 1e-10)
    # the same vertices otherwise (the subsets' found ones are Qhull's too)
    gap = np.abs(by_subsets[:, None, :] - by_hull[None]).max(axis=2).min(axis=1)
    assert gap.max() < 1e-9


def test_hull_vertices_of_random_polytopes_match_the_subsets():
    rng = np.random.default_rng(3)
    for d in (2, 3, 4, 5):
        for _ in range(5):
            A = np.vstack([rng.normal(size=(3 * d, d)), np.eye(d), -np.eye(d)])
            A, b, _ = normalize_rows(A, np.concatenate([np.ones(3 * d), np.full(2 * d, 3.0)]))
            (got,), _ = vx.hull_vertices(A, b, np.array([0, A.shape[0]]), np.array([0]))
            ref = vertices(A, b, max_combos=None)
            assert got.shape == ref.shape
            assert np.abs(got[:, None, :] - ref[None]).max(axis=2).min(axis=1).max() < 1e-12


def test_tree_encloses_the_apex_the_subsets_lose():
    """The search tree's points of a region hold its every point (its decisions rest on
    them): with the roof's apex lost, a region would be proved apart from where it is."""
    from codev_engine.deploy.bst import _enlarged_vertices

    A, b, apex = _roof()
    lo, hi = np.full((1, 4), -1.0), np.full((1, 4), 1.0)
    P, owner, boxed = _enlarged_vertices(A, b, np.array([0, A.shape[0]]), (lo, hi))
    assert boxed == 0
    assert np.abs(P - apex).max(axis=1).min() < 1e-8


def test_compiled_edge_check_agrees_with_the_reference():
    """``vertices_kernel.closed_under_edges`` (the tree's) against
    ``vertices._closed_under_edges``: complete lists pass, a list without one vertex fails."""
    from codev_engine.geometry.vertices_kernel import closed_under_edges

    def nb(V, A, b, tol=1e-10):
        return closed_under_edges(np.ascontiguousarray(V), np.ascontiguousarray(A),
                                  np.ascontiguousarray(b), tol, vx.DET_TOL, vx._LEAVE_TOL,
                                  vx._END_TOL)

    rng = np.random.default_rng(5)
    for d in (1, 2, 3, 4, 5):
        for _ in range(4):
            A = np.vstack([rng.normal(size=(2 * d, d)), np.eye(d), -np.eye(d)])
            A, b, _ = normalize_rows(A, np.concatenate([np.ones(2 * d), np.full(2 * d, 3.0)]))
            V = vertices(A, b, max_combos=None)
            assert nb(V, A, b) and vx._closed_under_edges(V, A, b, 1e-10)
            for drop in range(min(3, V.shape[0])):
                W = np.delete(V, drop, axis=0)
                assert not nb(W, A, b)
                assert not vx._closed_under_edges(W, A, b, 1e-10)
    A, b, _ = _roof()
    assert not nb(vertices(A, b, 1e-10, max_combos=None), A, b)
