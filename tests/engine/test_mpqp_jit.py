"""The compiled kernels (codev_engine/geometry/lp_kernel.py, mp/mpqp_kernel.py) against
independent solvers.

The LP solver against HiGHS, its certified minimal representation against one exact LP per
row, and whole candidate evaluations against the numpy kernel on a real problem.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

import codev_engine as ce
from codev_engine.geometry import lp_kernel, polytope
from codev_engine.mp import active_sets, mpqp, mpqp_kernel

TESTSET = Path(__file__).resolve().parents[3] / "shared" / "benchmarks" / "mp_testset"


def _random_polytope(rng, k: int, d: int):
    """A bounded polytope ``A x <= b`` (unit rows) around the origin, with a box of 2d rows
    (returned first) so that it is bounded whatever the random rows."""
    A = rng.normal(size=(k, d))
    A /= np.linalg.norm(A, axis=1)[:, None]
    b = rng.uniform(0.2, 2.0, size=k)
    box = np.vstack([np.eye(d), -np.eye(d)])
    return np.vstack([box, A]), np.concatenate([np.full(2 * d, 3.0), b])


@pytest.mark.parametrize("seed", range(40))
def test_lp_max_matches_highs(seed):
    rng = np.random.default_rng(seed)
    d = int(rng.integers(1, 9))
    A, b = _random_polytope(rng, int(rng.integers(d, 40)), d)
    # degenerate on purpose in some cases: repeated rows and rows through one vertex
    if seed % 3 == 0:
        A = np.vstack([A, A[-3:]])
        b = np.concatenate([b, b[-3:]])
    c = rng.normal(size=d)
    use = np.ones(A.shape[0], dtype=bool)
    status, x, y, _, _ = lp_kernel.lp_max(
        c, A, b, use, np.zeros(d), np.empty(0, dtype=np.int64), 0, np.inf, 10_000
    )
    ref = linprog(-c, A_ub=A, b_ub=b, bounds=[(None, None)] * d, method="highs")
    assert status == lp_kernel.OPTIMAL
    assert np.all(A @ x <= b + 1e-9)
    assert c @ x == pytest.approx(-ref.fun, rel=1e-9, abs=1e-9)
    # the multipliers are a dual certificate: y >= 0, A'y = c, b'y = the optimum
    assert np.all(y >= -1e-12)
    np.testing.assert_allclose(A.T @ y, c, atol=1e-9)
    assert b @ y == pytest.approx(-ref.fun, rel=1e-9, abs=1e-9)


def test_lp_max_stops_once_past_the_stop_value():
    A = np.vstack([np.eye(2), -np.eye(2)])
    b = np.ones(4)
    status, x, *_ = lp_kernel.lp_max(
        np.array([1.0, 0.0]), A, b, np.ones(4, dtype=bool), np.zeros(2),
        np.empty(0, dtype=np.int64), 0, 0.5, 100,
    )
    assert status == lp_kernel.EXCEEDS and x[0] > 0.5


@pytest.mark.parametrize("how", ["compiled", "numpy"])
@pytest.mark.parametrize("seed", range(30))
def test_certified_reduction_drops_only_redundant_rows(seed, how):
    """Every dropped row is redundant (an exact LP over the kept rows does not pass it) and
    every row that is a facet is kept: ``lp_kernel.certified_keep`` and
    ``polytope.certified_minimal_rows`` (minrep's proposals, each proved by an LP's
    multipliers or by the cone of an earlier LP's optimal basis)."""
    rng = np.random.default_rng(100 + seed)
    d = int(rng.integers(2, 8))
    A, b = _random_polytope(rng, int(rng.integers(5, 50)), d)
    if seed % 4 == 0:  # exact and near duplicates
        A = np.vstack([A, A[-2:], A[-1:] * (1 + 1e-15)])
        b = np.concatenate([b, b[-2:], b[-1:]])
    k = A.shape[0]
    fixed = np.zeros(k, dtype=bool)
    fixed[: 2 * d] = True
    res = linprog(
        np.r_[np.zeros(d), -1.0], A_ub=np.c_[A, np.ones(k)], b_ub=b,
        bounds=[(None, None)] * d + [(0, None)], method="highs",
    )
    centre = res.x[:d]
    if how == "compiled":
        kept = lp_kernel.certified_keep(A, b, fixed, centre, 3.0, 10_000)
    else:
        kept = np.zeros(k, dtype=bool)
        kept[polytope.certified_minimal_rows(A, b, 3.0, np.flatnonzero(fixed))] = True
    assert np.all(kept[fixed])
    for i in range(k):
        others = kept.copy()
        others[i] = False
        top = linprog(-A[i], A_ub=A[others], b_ub=b[others], bounds=[(None, None)] * d,
                      method="highs")
        needed = top.status == 0 and -top.fun > b[i] + 1e-7
        if not kept[i]:
            assert not needed, f"row {i} dropped but needed (max {-top.fun} > {b[i]})"
        all_but_i = np.ones(k, dtype=bool)
        all_but_i[i] = False
        facet = linprog(-A[i], A_ub=A[all_but_i], b_ub=b[all_but_i],
                        bounds=[(None, None)] * d, method="highs")
        if facet.status == 0 and -facet.fun > b[i] + 1e-7:
            assert kept[i], f"facet {i} dropped"


def _kernel_of(name: str, max_regions: int | None = None):
    """The numpy kernel of a test-set problem, as explore_active_sets builds it, and the
    solution (None when ``max_regions`` stops the solve early)."""
    path = TESTSET / f"{name}.npz"
    if not path.exists():
        pytest.skip(f"{path} not present")
    kernels = []
    start = mpqp._Kernel.start_jit

    def grab(self):
        kernels.append(self)
        return start(self)

    mp = pytest.MonkeyPatch()
    mp.setattr(mpqp._Kernel, "start_jit", grab)
    mp.setattr(mpqp, "JIT_AFTER", 0)
    sol = None
    try:
        if max_regions is None:
            sol = ce.mpsolve(ce.MpProgram.load(path), options=ce.SolveOptions(workers=1))
        else:
            options = ce.SolveOptions(workers=1, max_regions=max_regions)
            with pytest.raises(ce.SolverError):
                ce.mpsolve(ce.MpProgram.load(path), options=options)
    finally:
        mp.undo()
    return kernels[0], sol


def test_compiled_and_numpy_kernels_agree_on_a_real_problem():
    """pop_mpqp_099: every region's active set evaluated by both kernels gives the same class
    and the same law; the compiled rows describe the same region (their Chebyshev centre
    lies in the numpy rows and the other way round)."""
    kernel, sol = _kernel_of("pop_mpqp_099")
    assert sol.stats.get("jit") is True
    for reg in sol.regions:
        act = np.array(reg.active, dtype=np.int64)
        got = mpqp_kernel.evaluate(act, kernel.box[0], *kernel._jit_args)
        ref = kernel.evaluate_numpy(reg.active)
        assert ref[0] == "full" and got[0] == mpqp_kernel.FULL
        np.testing.assert_allclose(got[3], ref[2][0], atol=1e-8)
        np.testing.assert_allclose(got[4], ref[2][1], atol=1e-8)
        for (A1, b1), (A2, b2) in (((got[1], got[2]), ref[1]), (ref[1], (got[1], got[2]))):
            centre, radius = polytope.chebyshev_ball(A1, b1)
            assert radius > 0 and np.all(A2 @ centre <= b2 + 1e-9)


def test_numpy_path_and_compiled_path_give_the_same_partition():
    """The compiled kernel takes over after JIT_AFTER regions; the partition must not depend
    on where (slivers that DAQP's LP misjudged aside: none in this problem)."""
    path = TESTSET / "pop_mpqp_099.npz"
    if not path.exists():
        pytest.skip(f"{path} not present")
    prog = ce.MpProgram.load(path)
    mp = pytest.MonkeyPatch()
    try:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        a = ce.mpsolve(prog, options=ce.SolveOptions(workers=1))
        mp.setattr(mpqp, "JIT_AFTER", 10**9)
        b = ce.mpsolve(prog, options=ce.SolveOptions(workers=1))
    finally:
        mp.undo()
    assert a.stats.get("jit") is True and "jit" not in b.stats
    assert sorted(r.active for r in a.regions) == sorted(r.active for r in b.regions)


def test_numpy_kernel_keeps_regions_daqps_ball_misjudges():
    """pop_mpqp_084's active set (0, 1, 3, 4, 8) has a region of radius 1.1e-5 (the compiled
    kernel's centre has that slack in every row) that DAQP's Chebyshev LP puts at -2.8e-6:
    the numpy kernel, which the walk uses before the compiled one starts and for what that
    one hands back, dropped it and left a hole. It needs proofs now, as the compiled one (and
    ``solve_lp`` takes DAQP's optimum only with its proof: the ball is right now)."""
    kernel, sol = _kernel_of("pop_mpqp_084")
    act = (0, 1, 3, 4, 8)
    status, rows, *_ = kernel.evaluate_numpy(act)
    assert status == "full"
    A, b = rows
    assert polytope.chebyshev_ball(A, b)[1] > 1e-5  # (DAQP alone: -2.8e-6, unproved)
    got = mpqp_kernel.evaluate(np.array(act), kernel.box[0], *kernel._jit_args)
    assert got[0] == mpqp_kernel.FULL
    assert np.min(got[2] - got[1] @ got[8]) > 1e-5
    assert act in {r.active for r in sol.regions}


@pytest.mark.parametrize("seed", range(20))
def test_radius_upper_bound_holds_for_any_multipliers(seed):
    """The bound is >= the largest radius (HiGHS) whatever the multipliers, and tight with
    the LP's own; an empty polytope gets a negative bound."""
    rng = np.random.default_rng(300 + seed)
    d = int(rng.integers(2, 7))
    A, b = _random_polytope(rng, int(rng.integers(5, 30)), d)
    if seed % 2:  # empty: a row that cuts everything off
        A = np.vstack([A, A[-1:], -A[-1:]])
        b = np.concatenate([b, [-0.5], [-0.5]])
    _, radius, y = polytope.chebyshev_ball(A, b, solver="highs", multipliers=True)
    bound = 3.0
    assert polytope.radius_upper_bound(A, b, y, bound) == pytest.approx(radius, abs=1e-7)
    for _ in range(5):
        noisy = y + rng.normal(scale=1e-3, size=y.size)
        assert polytope.radius_upper_bound(A, b, noisy, bound) >= radius - 1e-12
    if seed % 2:
        assert radius < 0 and polytope.radius_upper_bound(A, b, y, bound) < 0


def _swap_problem():
    """``min 0.5 |z|^2 - (2, 3, 0)'z`` over theta in [0, 1], s.t. (0) z1 <= theta, (1) z2 <=
    theta, (2) (z1 + z2)/sqrt(2) <= 0.5 + (sqrt(2) - 1) theta, (3) z3 <= 1e7, (4) z3 <= -1.

    The region of (0, 1, 4) is theta <= 0.5: there constraint 2 enters, with g_2 = (g_0 +
    g_1)/sqrt(2), so 0 or 1 must leave (lambda_0 = 2 - theta is the smaller: 0 leaves).
    Constraint 3's slack is 1e7 + 1 and lambda_4 is 1 for every theta: rows that vanish
    with a positive constant.
    """
    r = np.sqrt(2.0)
    G = np.array([[1, 0, 0], [0, 1, 0], [1 / r, 1 / r, 0], [0, 0, 1], [0, 0, 1]], dtype=float)
    w = np.array([0.0, 0.0, 0.5, 1e7, -1.0])
    S = np.array([[1.0], [1.0], [r - 1.0], [0.0], [0.0]])
    return np.eye(3), np.array([-2.0, -3.0, 0.0]), np.zeros((3, 1)), G, w, S


def test_swaps_are_taken_past_rows_that_vanish_with_a_positive_constant():
    """pop_mpqp_033: bounds z_i <= 1e7 whose slack is constant on a region had switched the
    swaps off, and every dependent entering constraint went through all subsets of the
    dependent set: 4 LICQ and 1.4 empty candidates per region. A swap that leaves out a
    constraint outside the dependency (c_l = 0) stays dependent and is not made."""
    H, c, C, G, w, S = _swap_problem()
    At, bt = np.array([[1.0], [-1.0]]), np.array([1.0, 0.0])
    kernel = mpqp._Kernel(H, c, C, G, w, S, At, bt, 1.0, 1e-9, (np.zeros(1), np.ones(1)))
    assert kernel.start_jit()
    act = np.array([0, 1, 4], dtype=np.int64)
    status, Ak, bk, K, k, moves, _, swaps, _ = mpqp_kernel.evaluate(
        act, np.array([0.5]), *kernel._jit_args
    )
    assert status == mpqp_kernel.FULL
    np.testing.assert_allclose(K @ [0.25] + k, [0.25, 0.25, -1.0])
    # entering 2 is a swap (0 or 1 leaves), never a plain move into the dependent set
    assert sorted(map(tuple, swaps.tolist())) == [(2, 0), (2, 1)]
    assert -3 not in moves.tolist()
    # the whole problem: the explicit law is the optimum on a grid of theta
    prog = ce.MpProgram(
        H=H, c=c, C=C, A=G, b=w, F=S, A_theta=At, b_theta=bt, name="swaps"
    )
    sol = ce.mpsolve(prog, options=ce.SolveOptions(workers=1))
    theta = np.linspace(0.0, 1.0, 101)[:, None]
    got = sol.value(theta)
    for t, v in zip(theta[:, 0], got, strict=True):
        z = np.array([min(t, 2.0), min(t, 3.0), -1.0])
        # past theta = 0.5: (1, 2, 4) active (z2 = theta, z1 from constraint 2)
        if z[:2].sum() / np.sqrt(2) > 0.5 + (np.sqrt(2) - 1) * t:
            z[1] = t
            z[0] = np.sqrt(2) * (0.5 + (np.sqrt(2) - 1) * t) - t
        assert v == pytest.approx(0.5 * z @ z + c @ z, abs=1e-9), t


def test_a_candidate_handed_back_is_tried_again_from_the_box_centre():
    """A candidate the compiled kernel hands back from the start point the walk gives it
    is evaluated once more from the parameter box's centre before the numpy kernel:
    pop_mpqp_036's (3, 26, 30, 31, 34, 38, 40, 47), a sliver whose Chebyshev LP from some
    start points ends where no class is proved, is lower-dimensional from the box centre.
    (The start point is one of 300 random ones; the centre of the region that pushed it in
    the walk was one such point until the slacks of rows in the span of the active ones
    were taken from the dependency, ``mpqp._Kernel._dependent_slacks``: this active set
    has 8 rows in 8 variables, so every slack is one.) (pop_mpqp_047's sliver (5, 7, 29,
    33, 34, 35, 42), radius 1.1e-7, was left a hole when the numpy kernel judged it; since
    the LP stops taking a dropped row back at once, it is full from both points. Its radius
    is 5.5 region tolerances (2e-8), past ``CLOSE_CALL``: the compiled kernel proves it full
    from both points, and the numpy kernel, which decides the close calls from the active
    set alone, agrees.)"""
    kernel, _ = _kernel_of("pop_mpqp_036", max_regions=300)
    act = np.array([3, 26, 30, 31, 34, 38, 40, 47], dtype=np.int64)
    pushed_from = np.array([
        -4.049519252846971, 6.502665906605449, 1.5988114721594062, -3.3841377357590616,
        0.7116659170764486, -0.7752183338182963, 0.8827557528998433, -5.249171873419717,
    ])
    alone = mpqp_kernel.evaluate(act, pushed_from, *kernel._jit_args)
    assert alone[0] == mpqp_kernel.FALLBACK
    graph = active_sets.ActiveSetGraph(kernel.m, kernel.nz, np.zeros((kernel.m,) * 2, dtype=bool))
    keys = graph.key(act)[None]
    status = mpqp_kernel.evaluate_batch(keys, pushed_from[None], kernel._jit_args)[0]
    assert status[0] == mpqp_kernel.LOWER

    kernel, _ = _kernel_of("pop_mpqp_047", max_regions=300)
    act = np.array([5, 7, 29, 33, 34, 35, 42], dtype=np.int64)
    pushed_from = np.array([
        -7.427232366017716, -4.966641423987682, -8.799176218843456, 3.1102465240714032,
        -9.94378840950449, 9.943788409504489, -9.943788409504391, 9.943788409504485,
    ])
    for start in (pushed_from, kernel._jit_args[10]):
        got = mpqp_kernel.evaluate(act, start, *kernel._jit_args)
        assert got[0] == mpqp_kernel.FULL
    assert 1.1e-7 > mpqp.CLOSE_CALL * kernel.region_tol
    status, rows, *_ = kernel.evaluate_numpy(tuple(act.tolist()))
    assert status == "full"
    assert polytope.chebyshev_ball(*rows, solver="highs", tol=1e-10)[1] > 5e-8


def test_a_row_dropped_and_blocking_at_once_does_not_stall_the_lp():
    """pop_mpqp_036's candidate (18, 24, 26, 37, 38, 42, 45, 47): at a degenerate vertex
    of its Chebyshev LP the projected cost has norm 4e-10 once a row is dropped, and the
    row blocked again at once (a slope of rounding size): drop and add alternated until
    the stall limit, and the numpy kernel had to decide. Now the point is taken as
    stationary for the rows left, and the compiled kernel proves the class the numpy
    kernel finds."""
    kernel, _ = _kernel_of("pop_mpqp_036", max_regions=300)
    act = (18, 24, 26, 37, 38, 42, 45, 47)
    got = mpqp_kernel.evaluate(np.array(act, dtype=np.int64), np.zeros(8), *kernel._jit_args)
    assert got[0] == mpqp_kernel.LOWER
    assert kernel.evaluate_numpy(act)[0] == "lower"


def test_lp_with_a_blocking_row_dependent_on_its_working_set_gives_up_without_raising():
    """A merged sliver region of a random norm-inf MPC (the oracle sweep's rand145): rows
    through the origin in near-copies. In the Chebyshev LP a blocking row was, to the last
    bit, a copy of the working rows: Gram-Schmidt left it norm 0 and the multipliers
    divided by it (numba raises ZeroDivisionError: the synthesis crashed). The LP gives
    up instead; the box falls back to HiGHS and still holds the region."""
    rows = np.array([
        [-0.4563219618068808, -0.7063034100240011, 0.54120768671665, 0.0],
        [-0.45632196180688067, -0.7063034100240009, 0.54120768671665, 0.0],
        [0.4471286407631589, 0.7087621696383684, -0.5456483899901134, 0.0],
        [0.4471286407631589, 0.7087621696383682, -0.5456483899901133, 0.0],
        [-0.44772217946183507, -0.7086061794566614, 0.5453642199977721, 0.0],
        [0.4467730153566052, 0.7088554519327811, -0.5458184872412617, 0.0],
        [-0.4475789842102189, -0.708643847742125, 0.5454328097489043, 0.0],
        [-0.4474519464112698, -0.708677247303576, 0.5454936432324325, 0.0],
        [-0.4474393007908286, -0.708680571021447, 0.5454996978592473, 0.0],
        [-0.4474502159617575, -0.7086777021372563, 0.545494471767803, 0.0],
        [0.4553317097793248, 0.661557013845265, -0.5958316469453202, 0.0],
        [-0.46225573752327187, -0.7046676017877633, 0.5382965763568428, 0.0],
        [1.0, 0.0, 0.0, 5.0],
        [0.0, 0.0, 1.0, 5.0],
    ])
    A, b = rows[:, :3].copy(), rows[:, 3].copy()
    lo, hi, ok = lp_kernel.region_boxes(A, b, np.array([0, len(b)]), 1000)
    if ok[0]:
        assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
    from codev_engine.geometry.locate import bounding_boxes

    lo, hi = bounding_boxes([A] * 70, [b] * 70)  # 70 regions: the compiled path first
    for j in range(3):
        for sign in (1.0, -1.0):
            res = linprog(-sign * np.eye(3)[j], A_ub=A, b_ub=b, bounds=[(None, None)] * 3,
                          method="highs")
            top = sign * -res.fun
            assert lo[0, j] - 1e-9 <= top <= hi[0, j] + 1e-9


def test_cone_proofs_prove_only_what_the_rows_imply():
    """x <= 1 and y <= 1 prove x + y <= 2 (multipliers (1, 1)), not x + y <= 1.9 and not
    2x <= 1 (multipliers (2, 0) give 2). x - y <= 3.5 needs a negative multiplier: clipped
    to (1, 0), the residual (0, -1) is charged at the bound, 1 + bound: no proof on |x|_inf
    <= 3, a proof on |x|_inf <= 1."""
    from codev_engine.geometry.polytope import _cone_proofs

    AB, bB = np.eye(2), np.ones(2)
    Ar = np.array([[1.0, 1.0], [1.0, 1.0], [2.0, 0.0], [1.0, -1.0]])
    beta = np.array([2.0, 1.9, 1.0, 3.5])
    np.testing.assert_array_equal(_cone_proofs(AB, bB, Ar, beta, 3.0),
                                  [True, False, False, False])
    np.testing.assert_array_equal(_cone_proofs(AB, bB, Ar, beta, 1.0),
                                  [True, False, False, True])


_CALLEE = """from numba import njit


@njit(cache=True)
def f():
    return {value}
"""

_CALLER = """import sys

import callee
from numba import njit

from codev_engine.geometry.lp_kernel import cache_follows


@njit(cache=True)
def g():
    return callee.f() + 10


cache_follows(globals(), callee.__file__)
value = g()
print(value, sum(g.stats.cache_hits.values()), sum(g.stats.cache_misses.values()))
"""


def test_cache_follows_renews_a_callers_cache_when_the_callees_file_changes(tmp_path):
    """numba renews a function's disk cache when its own file changes, not when that of a
    compiled function it calls does: the mp-QP kernel, with the LP of ``lp_kernel``
    compiled into it, would go on running an old LP after an edit there. With
    ``cache_follows`` an edit of the callee's file renews the caller's cache, and an
    unchanged file still loads it (a cache hit, no compilation)."""
    import os
    import subprocess
    import sys

    (tmp_path / "caller.py").write_text(_CALLER)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}

    def run(value: int) -> tuple[int, int, int]:
        """g() with callee.f returning ``value``: (g(), cache hits, cache misses)."""
        (tmp_path / "callee.py").write_text(_CALLEE.format(value=value))
        out = subprocess.run(
            [sys.executable, "caller.py"], cwd=tmp_path, env=env, capture_output=True,
            text=True, timeout=300, check=True,
        )
        got, hits, misses = (int(s) for s in out.stdout.split())
        return got, hits, misses

    assert run(1) == (11, 0, 1)  # compiled: nothing cached yet
    assert run(1) == (11, 1, 0)  # loaded from the cache
    assert run(2) == (12, 0, 1)  # the callee's edit renewed the caller's cache
    assert run(2) == (12, 1, 0)


def test_the_mp_qp_kernels_cache_follows_the_lp_kernel():
    """Every compiled function of ``mpqp_kernel`` with a disk cache has it stamped with
    ``lp_kernel.py``'s hash too (``cache_follows`` at the end of the module)."""
    import hashlib

    digest = hashlib.sha256(Path(lp_kernel.__file__).read_bytes()).digest()
    here = mpqp_kernel.__name__
    cached = [
        fn for fn in vars(mpqp_kernel).values()
        if getattr(fn, "py_func", None) is not None and fn.py_func.__module__ == here
    ]
    assert {fn.__name__ for fn in cached} >= {"evaluate", "evaluate_batch", "decode", "_swaps"}
    for fn in cached:
        stamp = fn._cache._cache_file._source_stamp
        assert isinstance(stamp, tuple) and stamp[1] == digest, fn.__name__
