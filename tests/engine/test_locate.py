"""Point location when a bounding-box LP fails (codev_engine.locate).

A thin sliver region -- two nearly opposite rows, width 1e-6, in a partition of a box of
side 200 -- is reported infeasible by DAQP for some of its bounding-box LPs. The box must
still be finite and contain the region (sound), and point location must still agree with
brute force on every region (the sliver and all the others). The fallbacks (HiGHS, the
enlarged region, the domain box, the overall box) and a locator given infinite / NaN boxes
are tested directly too.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import Delaunay

import codev_engine as ce
import codev_engine.geometry.locate as locate_mod
from codev_engine.geometry.locate import PointLocator, bounding_boxes
from codev_engine.geometry.polytope import solve_lp

LOC_TOL = 1e-9  # the locator's tolerance (unit-norm rows)
S = 100.0  # half side of the partitioned box
WIDTH = 1e-6  # the sliver's width


def voronoi_regions(k: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The Voronoi cells of k random sites in [-S, S]^2, unit-norm rows."""
    rng = np.random.default_rng(seed)
    sites = rng.uniform(-S, S, size=(k, 2))
    indptr, nbrs = Delaunay(sites).vertex_neighbor_vertices
    eye = np.eye(2)
    As, bs = [], []
    for i in range(k):
        J = nbrs[indptr[i] : indptr[i + 1]]
        A = np.vstack([sites[J] - sites[i], eye, -eye])
        b = np.concatenate(
            [(np.sum(sites[J] ** 2, axis=1) - sites[i] @ sites[i]) / 2, np.full(4, S)]
        )
        nrm = np.linalg.norm(A, axis=1)
        As.append(A / nrm[:, None])
        bs.append(b / nrm)
    return As, bs


def sliver(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``a x <= c``, ``-a' x <= -c + WIDTH`` (a' = a up to 1e-7), and the box rows."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=2)
    a /= np.linalg.norm(a)
    a2 = a + rng.normal(scale=1e-7, size=2)
    a2 /= np.linalg.norm(a2)
    c = rng.uniform(-0.3, 0.3) * S
    A = np.vstack([a, -a2, np.eye(2), -np.eye(2)])
    b = np.concatenate([[c, -c + WIDTH], np.full(4, S)])
    return A, b


def daqp_fails(A: np.ndarray, b: np.ndarray) -> bool:
    eye = np.eye(A.shape[1])
    return any(
        solve_lp(s * eye[j], A, b)[1] != "optimal" for j in range(A.shape[1]) for s in (1.0, -1.0)
    )


#: seeds of slivers on which DAQP fails (checked by test_the_sliver_defeats_daqp)
SLIVER_SEEDS = [0, 1, 2]


def brute_locate(As, bs, X: np.ndarray, near_tol: float = 1e-7):
    """Lowest region index holding each point (within LOC_TOL), and the points within
    ``near_tol`` of a boundary row of a region they (almost) belong to (rounding may
    decide those)."""
    idx = np.full(X.shape[0], -1)
    near = np.zeros(X.shape[0], dtype=bool)
    for i in reversed(range(len(As))):
        nrm = np.linalg.norm(As[i], axis=1)
        S_ = X @ (As[i] / nrm[:, None]).T - bs[i] / nrm
        smax = S_.max(axis=1)
        idx[smax <= LOC_TOL] = i
        near |= (smax <= near_tol) & np.any(np.abs(S_) <= near_tol, axis=1)
    return idx, near


def inside_points(A: np.ndarray, b: np.ndarray, rng, count: int = 200) -> np.ndarray:
    """Points of the region (strictly inside, found from its Chebyshev centre and the
    HiGHS extreme points in random directions)."""
    nrm = np.linalg.norm(A, axis=1)
    res = linprog(
        np.r_[np.zeros(A.shape[1]), -1.0],
        A_ub=np.hstack([A, nrm[:, None]]),
        b_ub=b,
        bounds=(None, None),
        method="highs",
    )
    assert res.status == 0 and res.x[-1] > 0
    centre = res.x[:-1]
    pts = []
    for _ in range(count):
        r = linprog(
            rng.normal(size=A.shape[1]), A_ub=A, b_ub=b, bounds=(None, None), method="highs"
        )
        pts.append(centre + rng.uniform(0.0, 0.9) * (r.x - centre))
    return np.array(pts)


def check_agrees(As, bs, locator: PointLocator, X: np.ndarray) -> np.ndarray:
    got = locator.locate(X)
    want, near = brute_locate(As, bs, X)
    differ = np.flatnonzero((got != want) & ~near)
    assert differ.size == 0, (
        f"{differ.size} of {X.shape[0]} points located differently from brute force, e.g. "
        f"x={X[differ[0]].tolist()}: locate={got[differ[0]]}, brute={want[differ[0]]}"
    )
    return got


def sample(rng, n_uniform: int = 20_000) -> np.ndarray:
    return rng.uniform(-1.05 * S, 1.05 * S, size=(n_uniform, 2))


# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SLIVER_SEEDS)
def test_the_sliver_defeats_daqp(seed):
    """Harness check: the slivers really exercise the fallback (DAQP fails on them)."""
    A, b = sliver(seed)
    if not daqp_fails(A, b):
        pytest.skip("DAQP solves this sliver now (the fallback is tested below anyway)")


@pytest.mark.parametrize("position", ["first", "middle", "last"])
@pytest.mark.parametrize("seed", SLIVER_SEEDS)
def test_sliver_region_keeps_point_location_exact(seed, position):
    As, bs = voronoi_regions(300, seed=10 + seed)
    A, b = sliver(seed)
    at = {"first": 0, "middle": 150, "last": len(As)}[position]
    As.insert(at, A)
    bs.insert(at, b)
    law = ce.ExplicitLaw(A=As, b=bs, F=np.zeros((len(As), 1, 2)), G=np.zeros((len(As), 1)))
    lo, hi = law.boxes
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
    # sound: the sliver's box contains the sliver (its HiGHS extreme points)
    rng = np.random.default_rng(seed)
    pts = inside_points(A, b, rng)
    assert np.all(pts >= lo[at] - 1e-9) and np.all(pts <= hi[at] + 1e-9)
    X = sample(rng)
    got = check_agrees(As, bs, law.locator, X)
    assert np.count_nonzero(got >= 0) > 0.9 * X.shape[0]  # the partition covers the box
    # points of the sliver: it wins where it is first, otherwise brute force decides
    got = check_agrees(As, bs, law.locator, pts)
    if position == "first":
        assert np.all(got == 0)
    assert np.all(got >= 0)


@pytest.mark.parametrize("domain", [False, True])
def test_every_lp_failing_falls_back_to_a_sound_finite_box(monkeypatch, domain):
    """The compiled LPs, DAQP and HiGHS all fail (also on the enlarged sliver): the domain
    box or the overall box of the other regions replaces the sliver's box, never
    infinity."""
    As, bs = voronoi_regions(200, seed=21)
    A, b = sliver(0)
    As.insert(7, A)
    bs.insert(7, b)
    real_solve_lp, real_linprog = locate_mod.solve_lp, locate_mod.linprog

    def is_sliver(M):
        return M.shape == A.shape and np.allclose(M, A)

    def failing_solve_lp(f, M, rhs, *args, **kw):
        if is_sliver(M):
            return None, "infeasible", None
        return real_solve_lp(f, M, rhs, *args, **kw)

    def failing_linprog(c, A_ub=None, b_ub=None, **kw):
        res = real_linprog(c, A_ub=A_ub, b_ub=b_ub, **kw)
        if A_ub is not None and is_sliver(A_ub):
            res.status, res.x = 2, None
        return res

    def failing_compiled(As_, bs_, d, rows=None):
        lo, hi, ok = real_compiled(As_, bs_, d, rows)
        for i, M in enumerate(As_):
            if is_sliver(M):
                lo[i], hi[i], ok[i] = np.nan, np.nan, False
        return lo, hi, ok

    real_compiled = locate_mod._compiled_boxes
    monkeypatch.setattr(locate_mod, "_compiled_boxes", failing_compiled)
    monkeypatch.setattr(locate_mod, "solve_lp", failing_solve_lp)
    monkeypatch.setattr(locate_mod, "linprog", failing_linprog)
    box = (np.vstack([np.eye(2), -np.eye(2)]), np.full(4, S)) if domain else None
    lo, hi = bounding_boxes(As, bs, domain=box)
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
    np.testing.assert_allclose(lo[7], -S, atol=1e-9)  # the whole partition's box
    np.testing.assert_allclose(hi[7], S, atol=1e-9)
    monkeypatch.undo()
    ref_lo, ref_hi = bounding_boxes(
        [A for i, A in enumerate(As) if i != 7], [b for i, b in enumerate(bs) if i != 7]
    )
    np.testing.assert_array_equal(np.delete(lo, 7, axis=0), ref_lo)
    np.testing.assert_array_equal(np.delete(hi, 7, axis=0), ref_hi)
    rng = np.random.default_rng(5)
    locator = PointLocator(As, bs, boxes=(lo, hi))
    check_agrees(As, bs, locator, sample(rng))
    assert np.all(check_agrees(As, bs, locator, inside_points(A, b, rng)) >= 0)


def test_highs_backs_daqp_on_the_sliver():
    """With DAQP failing, the sliver's box is its true box (HiGHS), not a fallback."""
    A, b = sliver(0)
    lo, hi = bounding_boxes([A], [b])
    for j in range(2):
        for s, bound in ((1.0, lo[0, j]), (-1.0, hi[0, j])):
            r = linprog(s * np.eye(2)[j], A_ub=A, b_ub=b, bounds=(None, None), method="highs")
            assert r.status == 0
            assert bound == pytest.approx(r.x[j], abs=1e-6)


@pytest.mark.parametrize("bad", [np.inf, np.nan])
def test_locator_survives_non_finite_boxes(bad):
    """Boxes with inf / NaN entries (an old law file, a failed LP): the grid is finite,
    and location still agrees with brute force (also outside the other boxes)."""
    As, bs = voronoi_regions(200, seed=22)
    lo, hi = bounding_boxes(As, bs)
    lo, hi = lo.copy(), hi.copy()
    lo[3, 0] = -bad
    hi[50, 1] = bad
    lo[120] = bad  # a reversed / unknown box
    # and a region that really is larger than every other box: the half-plane x0 >= 2S
    # (bounded in x1 by the box rows), found beyond the grid by brute force
    As.append(np.vstack([[-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [1.0, 0.0]]))
    bs.append(np.array([-2 * S, S, S, 3 * S]))
    lo = np.vstack([lo, [-np.inf, -S]])
    hi = np.vstack([hi, [np.inf, S]])
    locator = PointLocator(As, bs, boxes=(lo, hi))
    assert np.all(np.isfinite(locator.lo)) and np.all(np.isfinite(locator.hi))
    assert np.all(np.isfinite(locator.cell))
    rng = np.random.default_rng(6)
    X = np.vstack([sample(rng), rng.uniform([-S, -S], [3.2 * S, S], size=(5000, 2))])
    got = check_agrees(As, bs, locator, X)
    assert np.any(got == len(As) - 1) and np.any(got == 3) and np.any(got == 120)


def test_law_boxes_use_the_domain_box(monkeypatch):
    """``ExplicitLaw.boxes`` hands the law's domain to the fallback."""
    As, bs = voronoi_regions(50, seed=23)
    A, b = sliver(1)
    As.append(A)
    bs.append(b)
    seen = {}
    real = locate_mod.bounding_boxes

    def spy(As_, bs_, domain=None):
        seen["domain"] = domain
        return real(As_, bs_, domain=domain)

    monkeypatch.setattr("codev_engine.law.bounding_boxes", spy)
    dA, db = np.vstack([np.eye(2), -np.eye(2)]), np.full(4, S)
    law = ce.ExplicitLaw(
        A=As, b=bs, F=np.zeros((len(As), 1, 2)), G=np.zeros((len(As), 1)), domain_A=dA, domain_b=db
    )
    lo, hi = law.boxes
    assert seen["domain"][0] is dA and seen["domain"][1] is db
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))


def test_wide_regions_are_located_exactly():
    """Thin oblique slabs in 7-D: every box spans the whole grid, so they go to the
    coarsest grid, and located indices equal brute force: the lowest region holding a
    point, else the nearest within the tolerance."""
    from codev_engine.geometry.locate import WIDE_CELLS, PointLocator

    rng = np.random.default_rng(7)
    d, R = 7, 400
    a = rng.normal(size=d)
    a /= np.linalg.norm(a)
    cuts = np.linspace(-np.abs(a).sum(), np.abs(a).sum(), R + 1)
    box_A = np.vstack([np.eye(d), -np.eye(d)])
    box_b = np.ones(2 * d)
    As = [np.vstack([box_A, a, -a]) for _ in range(R)]
    bs = [np.concatenate([box_b, [cuts[k + 1], -cuts[k]]]) for k in range(R)]
    loc = PointLocator(As, bs, boxes=(-np.ones((R, d)), np.ones((R, d))))
    assert loc.wide.size == R and loc.g**d > WIDE_CELLS
    assert loc.levels[0].cands.size == 0 and loc.levels[-1].g < loc.g
    X = np.vstack([rng.uniform(-1, 1, size=(3000, d)), 1.5 * rng.uniform(-1, 1, size=(200, d))])
    # points on cuts: the region whose rows hold the point as computed must win
    on = rng.uniform(-0.2, 0.2, size=(50, d))
    on += np.outer(cuts[R // 2] - on @ a, a)
    X = np.vstack([X, on])
    got = loc.locate(X)
    viol = np.stack([(X @ A.T - b).max(axis=1) for A, b in zip(As, bs, strict=True)], axis=1)
    inside = viol <= 0.0
    near = np.where(viol <= 1e-9, viol, np.inf)
    found = np.where(np.isfinite(near).any(axis=1), near.argmin(axis=1), -1)
    want = np.where(inside.any(axis=1), inside.argmax(axis=1), found)
    np.testing.assert_array_equal(got[:-50], want[:-50])
    # a point on a cut is on the boundary of both regions: which one holds it "as
    # computed" depends on the rounding of the product (einsum in the grid, a matrix
    # product here), so either may get it, but it must be on the region it gets
    assert np.all((got[-50:] == R // 2 - 1) | (got[-50:] == R // 2))
    assert np.all(viol[np.arange(len(X))[-50:], got[-50:]] <= 1e-12)


def test_regions_spread_over_coarser_grids_are_located_as_by_brute_force(monkeypatch):
    """With a small ``WIDE_CELLS`` the Voronoi cells go to grids of 70, 35 and 18 cells
    per axis by size: a point is offered the candidates of its cell in each of
    them, and gets the region brute force gives it."""
    monkeypatch.setattr(locate_mod, "WIDE_CELLS", 16)
    As, bs = voronoi_regions(300, seed=33)
    loc = PointLocator(As, bs, grid=True)
    used = [grid.g for grid in loc.levels if grid.cands.size]
    assert len(used) >= 3 and used[0] == loc.g
    assert 0 < loc.wide.size < len(As)
    check_agrees(As, bs, loc, sample(np.random.default_rng(12)))


@pytest.mark.parametrize("path", ["grid", "wide", "brute"])
def test_a_region_that_holds_a_point_beats_one_only_near_it(path, monkeypatch):
    """pop_mpqp_002: a sliver (lower index) whose facet passes 4e-10 short of a point of
    its neighbour must not take the point (its law extrapolated there was 6e-6 off); in a
    gap between regions the nearest one wins. The same in the grid, for regions tested
    put in the coarsest grid ("wide") and by brute force."""
    if path == "wide":  # every region in the coarsest grid (one cell) instead
        monkeypatch.setattr(locate_mod, "WIDE_CELLS", 0)
    # strips lo <= x0 <= hi of the square |x1| <= 1
    strips = [(-1e-3, -4e-10), (0.0, 0.5), (0.5 + 5e-10, 1.0), (0.5 + 2e-10, 1.0)]
    A = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    bs = [np.array([hi, -lo, 1.0, 1.0]) for lo, hi in strips]
    loc = PointLocator([A] * 4, bs, grid=path != "brute")
    if path != "brute":
        assert (loc.wide.size == 4) == (path == "wide")
    x0 = [
        1e-10,  # in 1; 0 is 5e-10 off
        -1e-4,  # in 0
        0.5 + 3e-10,  # in 3; 2 is 2e-10 off
        0.5 + 1.5e-10,  # in none: 3 is 0.5e-10 off, 1 1.5e-10, 2 3.5e-10
        0.5 + 0.8e-10,  # in none: 1 is 0.8e-10 off, 3 1.2e-10
        0.5 + 2e-9,  # in 2 and 3: the lower wins
        -2e-3,  # outside every region by more than the tolerance
    ]
    X = np.column_stack([x0, np.linspace(-0.9, 0.9, len(x0))])
    np.testing.assert_array_equal(loc.locate(X), [1, 0, 3, 3, 1, 2, -1])


def random_polytopes(count: int, d: int, seed: int) -> tuple[list, list]:
    """Random bounded polytopes around the origin (unit rows), every third one a thin
    slab of width 1e-6 between nearly parallel rows (radius ~5e-7, multipliers ~1e3)."""
    rng = np.random.default_rng(seed)
    As, bs = [], []
    for n in range(count):
        A = np.vstack([rng.normal(size=(4 * d, d)), np.eye(d), -np.eye(d)])
        b = np.concatenate([rng.uniform(0.5, 2.0, size=4 * d), np.full(2 * d, 3.0)])
        if n % 3 == 0:
            v = rng.normal(size=d)
            A = np.vstack([A, v, -v + 1e-3 * rng.normal(size=d)])
            b = np.concatenate([b, [5e-7, 5e-7]])
        nrm = np.linalg.norm(A, axis=1)
        As.append(A / nrm[:, None])
        bs.append(b / nrm)
    return As, bs


@pytest.mark.parametrize("d", [2, 5, 8])
def test_compiled_boxes_are_the_tight_bounds(d):
    """``bounding_boxes``' compiled LPs: every bound within 1e-9 of HiGHS at tolerance
    1e-10 (the grid widens them against rounding, not the boxes themselves)."""
    As, bs = random_polytopes(30, d, seed=40 + d)
    lo, hi, ok = locate_mod._compiled_boxes(As, bs, d)
    assert ok.sum() >= 25  # the compiled path answers nearly all of them
    blo, bhi = bounding_boxes(As, bs)  # (30 regions: DAQP, proved by its multipliers)
    np.testing.assert_allclose(blo[ok], lo[ok], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(bhi[ok], hi[ok], rtol=1e-9, atol=1e-9)
    for i in range(len(As)):
        for j in range(d):
            for s, bound in ((1.0, blo[i, j]), (-1.0, bhi[i, j])):
                f = s * np.eye(d)[j]
                r = linprog(f, A_ub=As[i], b_ub=bs[i], bounds=(None, None), method="highs",
                            options=locate_mod._TIGHT)
                assert r.status == 0
                assert abs(bound - r.x[j]) <= 1e-9 * (1 + abs(r.x[j]))


@pytest.mark.parametrize("d", [2, 6])
def test_brute_force_and_grid_agree(d, monkeypatch):
    """The same index for every point by brute force, by the grid (with wide regions) and
    by a locator that switches to the grid after ``GRID_POINTS`` points."""
    if d == 2:
        As, bs = voronoi_regions(300, seed=31)
        A, b = sliver(2)
        As.insert(100, A)
        bs.insert(100, b)
        rng = np.random.default_rng(8)
        X = sample(rng, 5000)
    else:  # thin oblique slabs in a box: all of them wide
        rng = np.random.default_rng(9)
        a = rng.normal(size=d)
        a /= np.linalg.norm(a)
        cuts = np.linspace(-np.abs(a).sum(), np.abs(a).sum(), 201)
        box_A = np.vstack([np.eye(d), -np.eye(d)])
        As = [np.vstack([box_A, a, -a]) for _ in range(200)]
        bs = [np.concatenate([np.ones(2 * d), [cuts[k + 1], -cuts[k]]]) for k in range(200)]
        X = rng.uniform(-1.05, 1.05, size=(3000, d))
        # points on the cuts, held by two regions
        X[:300] -= np.outer(X[:300] @ a - cuts[rng.integers(1, 200, 300)], a)
    def same(got, want):
        # a point on a facet shared by two regions may go either way by rounding (a matrix
        # product here, einsum there): then it is on both regions' boundaries
        for i in np.flatnonzero(got != want):
            for r in (got[i], want[i]):
                assert r >= 0 and np.max(As[r] @ X[i] - bs[r]) <= 1e-12, (i, got[i], want[i])
        assert np.mean(got == want) > 0.97

    brute = PointLocator(As, bs, grid=False)
    grid = PointLocator(As, bs, grid=True)
    want = brute.locate(X)
    assert not brute._grid and grid._grid
    same(grid.locate(X), want)
    monkeypatch.setattr(locate_mod, "GRID_POINTS", 150)
    auto = PointLocator(As, bs)
    np.testing.assert_array_equal(auto.locate(X[:1]), want[:1])
    assert not auto._grid  # one point: brute force
    np.testing.assert_array_equal(auto.locate(X[:100]), want[:100])
    same(auto.locate(X), want)
    assert auto._grid  # past GRID_POINTS points: the grid pays
    if d == 2:
        check_agrees(As, bs, brute, X)


def test_an_unproved_daqp_bound_goes_to_highs(monkeypatch):
    """DAQP's answer counts only with multipliers that prove it: a point short of the true
    bound (as DAQP gave on needle regions of pop_mpqp_024) is replaced by HiGHS's."""
    A = np.vstack([np.eye(2), -np.eye(2)])
    b = np.array([1.0, 2.0, 3.0, 4.0])  # the box [-3, 1] x [-4, 2]
    real = locate_mod.solve_lp

    def short(f, M, rhs, *args, **kw):
        x, st, lam = real(f, M, rhs, *args, **kw)
        return 0.5 * x, st, lam  # feasible, not optimal; the multipliers do not fit it

    monkeypatch.setattr(locate_mod, "solve_lp", short)
    lo, hi = bounding_boxes([A], [b])
    np.testing.assert_allclose(lo, [[-3.0, -4.0]], atol=1e-9)
    np.testing.assert_allclose(hi, [[1.0, 2.0]], atol=1e-9)
    monkeypatch.undo()
    x, st, lam = real(np.array([1.0, 0.0]), A, b)
    assert locate_mod._proved(np.array([1.0, 0.0]), A, b, x, lam)
    assert not locate_mod._proved(np.array([1.0, 0.0]), A, b, 0.5 * x, lam)


@pytest.mark.slow  # a test-set law (~18 s): the suite stays under 10 min
def test_compiled_boxes_stay_in_the_parameter_set_of_pop_mpqp_016():
    """On a region of pop_mpqp_016 the compiled LP took a step of 9e12 along a projected
    cost of norm 1e-12 (mostly rounding) and ended 3e-4 outside its working rows: the box
    reached 10.00012 past the parameter set's bound 10. A bound now counts only if its
    vertex holds every row; every box stays inside the parameter set's."""
    from test_mpqp_jit import TESTSET

    path = TESTSET / "pop_mpqp_016.npz"
    if not path.exists():
        pytest.skip(f"{path} not present")
    prog = ce.MpProgram.load(path)
    sol = ce.mpsolve(prog)
    As, bs = [r.A for r in sol.regions], [r.b for r in sol.regions]
    lo, hi = bounding_boxes(As, bs)
    plo, phi = bounding_boxes([prog.A_theta], [prog.b_theta])
    assert np.all(lo >= plo - 1e-9) and np.all(hi <= phi + 1e-9)


def test_few_regions_stay_with_brute_force_unless_a_grid_is_asked_for():
    """Below ``GRID_REGIONS`` regions no grid is built by default, even with boxes given
    or past ``GRID_POINTS`` points (brute force is as fast, the grid's compiled code slower
    to load); ``grid=True`` still builds one, and both give the same regions."""
    As, bs = voronoi_regions(locate_mod.GRID_REGIONS - 1, seed=41)
    X = sample(np.random.default_rng(13), locate_mod.GRID_POINTS + 500)
    plain = PointLocator(As, bs, boxes=bounding_boxes(As, bs))
    got = check_agrees(As, bs, plain, X)
    assert not plain._grid
    asked = PointLocator(As, bs, grid=True)
    assert asked._grid
    np.testing.assert_array_equal(asked.locate(X), got)
    many, more = voronoi_regions(locate_mod.GRID_REGIONS, seed=41)
    assert PointLocator(many, more, boxes=bounding_boxes(many, more))._grid
