"""The compiled walk of the mp-QP active-set graph (codev_engine/mp/active_sets.py).

Its bookkeeping against a plain Python model of the same rules, and whole searches against
the Python walk: serial, in threads, and with candidates handed back to the numpy kernel.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.geometry import polytope
from codev_engine.mp import active_sets, mpqp, mpqp_kernel


def _reference_visit(explored: set, stack: list, act, status, moves, swaps, nz, opposite):
    """explore_active_sets' visit rules, on Python tuples (the specification)."""

    def push(new):
        if new not in explored:
            explored.add(new)
            stack.append(new)

    if status in (mpqp_kernel.EMPTY, mpqp_kernel.FALLBACK):
        return
    if status == mpqp_kernel.LICQ:
        for i in act:
            push(tuple(x for x in act if x != i))
        return
    for v in moves:
        if v > 0:
            push(tuple(x for x in act if x != v - 1))
    if len(act) >= nz + 1:
        return
    blocked = set(act)
    for i in act:
        blocked |= set(np.flatnonzero(opposite[i]).tolist())
    for v in moves:
        if v < 0 and -v - 1 not in blocked:
            push(tuple(sorted(act + (-v - 1,))))
    for i, j in swaps:
        if i not in blocked:
            push(tuple(sorted(set(act) - {j} | {i})))


@pytest.mark.parametrize("m", [10, 64, 130])
def test_bitmask_walk_matches_the_python_rules(m):
    """Random candidates, statuses and moves (m up to three words): the same explored sets,
    the same stack contents, the keys decode to the active sets."""
    rng = np.random.default_rng(m)
    nz = 4
    opposite = np.zeros((m, m), dtype=bool)
    for i in range(0, m - 1, 2):
        opposite[i, i + 1] = opposite[i + 1, i] = True
    start = np.array([1.0, -2.0, 3.0])
    graph = active_sets.ActiveSetGraph(m, nz, opposite, start)
    seed = [tuple(sorted(rng.choice(m, size=int(rng.integers(0, nz + 1)), replace=False)))
            for _ in range(5)]
    explored, stack = set(seed), list(dict.fromkeys(seed))
    graph.seed(explored, stack)
    origin = dict.fromkeys(stack, tuple(start))  # the point each set is pushed with
    for _ in range(30):
        keys, points = graph.pop(7)
        acts, sizes = mpqp_kernel.decode(keys, nz + 2)
        batch = [tuple(a[:s].tolist()) for a, s in zip(acts, sizes, strict=True)]
        assert [stack.pop() for _ in batch][::-1] == batch
        assert [tuple(p) for p in points] == [origin[act] for act in batch]
        found = rng.normal(size=(len(batch), 3))
        status = rng.integers(0, 5, size=len(batch))
        moves, off, swaps, soff = [], [0], [], [0]
        for act in batch:
            mv = [i + 1 for i in act if rng.random() < 0.5]
            mv += [-(i + 1) for i in rng.choice(m, size=3, replace=False) if i not in act]
            moves += mv
            off.append(len(moves))
            out = [int(i) for i in rng.choice(m, size=2, replace=False) if i not in act]
            swaps += [(i, j) for i in out for j in act if rng.random() < 0.5]
            soff.append(len(swaps))
        for c, (act, st) in enumerate(zip(batch, status, strict=True)):
            before = len(stack)
            _reference_visit(explored, stack, act, st, moves[off[c]:off[c + 1]],
                             swaps[soff[c]:soff[c + 1]], nz, opposite)
            origin.update(dict.fromkeys(stack[before:], tuple(found[c])))
        graph.visit(keys, status.astype(np.int64), np.array(moves, dtype=np.int64),
                    np.array(off, dtype=np.int64),
                    np.array(swaps, dtype=np.int64).reshape(-1, 2),
                    np.array(soff, dtype=np.int64), found)
        assert graph.explored == len(explored)
        assert len(graph) == len(stack)
        if not stack:
            break
    rest, _ = graph.pop(len(graph))
    acts, sizes = mpqp_kernel.decode(rest, nz + 2)
    assert sorted(tuple(a[:s].tolist()) for a, s in zip(acts, sizes, strict=True)) == sorted(stack)


def test_licq_subsets_given_as_moves_walk_the_same():
    """The LICQ candidates' subsets computed where a batch was evaluated
    (``active_sets.licq_moves``, on a worker) and given to ``visit`` as moves push what
    ``visit`` pushes when it computes them (an SVD of the candidate's rows) itself."""
    rng = np.random.default_rng(5)
    m, nz = 12, 3
    G = rng.normal(size=(m, nz))
    G[6] = 2.0 * G[1]  # rows 1 and 6 dependent: LICQ breaks on smaller sets too
    G[7] = G[2] - G[3]
    graphs = [active_sets.ActiveSetGraph(m, nz, np.zeros((m, m), dtype=bool), np.zeros(2), G,
                                         mpqp.DEPENDENT_SIGMA, mpqp.SUPPORT_TOL)
              for _ in range(2)]
    acts = [(0, 1, 2, 3), (1, 6, 9), (2, 3, 7), (0, 4, 5, 8), (1, 4), (2, 3, 7, 10)]
    keys = np.stack([graphs[0].key(a) for a in acts])
    status = np.array([mpqp_kernel.LICQ, mpqp_kernel.LICQ, mpqp_kernel.LICQ,
                       mpqp_kernel.LICQ, mpqp_kernel.FULL, mpqp_kernel.LICQ], dtype=np.int64)
    moves = np.array([-1, 2, -4], dtype=np.int64)  # (1, 4)'s
    off = np.array([0, 0, 0, 0, 0, 3, 3], dtype=np.int64)
    swaps, soff = np.zeros((0, 2), dtype=np.int64), np.zeros(7, dtype=np.int64)
    found = rng.normal(size=(len(acts), 2))
    graphs[0].visit(keys, status, moves, off, swaps, soff, found)
    given, given_off = active_sets.licq_moves(keys, status, moves, off, G,
                                              mpqp.DEPENDENT_SIGMA, mpqp.SUPPORT_TOL)
    assert given.size > moves.size
    graphs[1].visit(keys, status, given, given_off, swaps, soff, found, licq_moves=True)
    assert graphs[0].explored == graphs[1].explored > 10
    for got, want in zip(graphs[1].pop(100), graphs[0].pop(100), strict=True):
        np.testing.assert_array_equal(got, want)
    # (1, 6, 9): only 1 and 6 may leave (9 is outside the null vector's support)
    sub = active_sets.licq_moves(keys[1:2], status[1:2], moves[:0], off[:2], G,
                                 mpqp.DEPENDENT_SIGMA, mpqp.SUPPORT_TOL)[0]
    assert sub.tolist() == [2, 7]


def test_table_keeps_every_key_when_it_grows():
    graph = active_sets.ActiveSetGraph(100, 3, np.zeros((100, 100), dtype=bool))
    acts = {tuple(sorted(c)) for c in np.random.default_rng(0).integers(0, 100, size=(20000, 3))}
    acts = sorted(acts)
    graph.seed(acts, [])
    assert graph.explored == len(acts) and graph.table.shape[0] >= 2 * len(acts)
    # every key is found again (a second insert is refused) and nothing else is
    for act in acts[::97]:
        assert not active_sets._insert(graph.table, graph.used, graph.key(act))
    assert active_sets._insert(graph.table, graph.used, graph.key((1, 2, 99, 98)))


def _program(seed: int = 2) -> ce.MpProgram:
    """A random strictly convex mp-QP with some hundreds of regions (nz = 5, d = 4)."""
    rng = np.random.default_rng(seed)
    nz, d, m = 5, 4, 16
    A = np.vstack([rng.normal(size=(m, nz)), np.eye(nz), -np.eye(nz)])
    b = np.concatenate([rng.uniform(0.5, 1.5, m), np.full(2 * nz, 2.0)])
    F = np.vstack([rng.normal(size=(m, d)), np.zeros((2 * nz, d))])
    L = rng.normal(size=(nz, nz))
    return ce.MpProgram(
        H=L @ L.T + 0.1 * np.eye(nz), c=rng.normal(size=nz), C=rng.normal(size=(nz, d)),
        A=A, b=b, F=F, A_theta=np.vstack([np.eye(d), -np.eye(d)]), b_theta=np.ones(2 * d),
    )


def _solve(monkeypatch, jit_after: int, workers: int = 1, parallel_after: int = 400):
    monkeypatch.setattr(mpqp, "JIT_AFTER", jit_after)
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", parallel_after)
    return ce.mpsolve(_program(), options=ce.SolveOptions(workers=workers))


def _same(a: ce.MpSolution, b: ce.MpSolution) -> None:
    assert a.num_regions == b.num_regions
    for r, s in zip(a.regions, b.regions, strict=True):
        assert r.active == s.active
        np.testing.assert_array_equal(r.A, s.A)
        np.testing.assert_array_equal(r.b, s.b)
        np.testing.assert_array_equal(r.K, s.K)


def test_compiled_walk_finds_the_python_walks_regions(monkeypatch):
    python = _solve(monkeypatch, jit_after=10**9)
    compiled = _solve(monkeypatch, jit_after=0)
    assert "jit" not in python.stats and compiled.stats["jit"] is True
    assert python.num_regions > 200
    # (the kernels' moves may differ by a candidate or two; the regions may not; both
    # walks' regions are sorted by active set, up to mpqp.SORTED_UP_TO)
    assert [r.active for r in python.regions] == [r.active for r in compiled.regions]


def test_compiled_walk_in_threads_gives_the_serial_result(monkeypatch):
    serial = _solve(monkeypatch, jit_after=0)
    threads = _solve(monkeypatch, jit_after=0, workers=2, parallel_after=1)
    assert threads.stats.get("workers") == 2
    assert threads.stats["explored"] == serial.stats["explored"]
    _same(serial, threads)


def test_compiled_walk_batches_do_not_depend_on_timing_or_workers(monkeypatch):
    """Each candidate's Chebyshev LP starts from the point of the region that pushed it, so
    the walk's order must not depend on which thread finishes first: every batch, and every
    start point in it, is the same serially and in threads."""
    batch = mpqp_kernel.evaluate_batch

    def run(workers: int) -> list:
        seen = []

        def recording(keys, starts, args):
            seen.append((keys.tobytes(), starts.tobytes()))
            return batch(keys, starts, args)

        monkeypatch.setattr(mpqp_kernel, "evaluate_batch", recording)
        _solve(monkeypatch, jit_after=0, workers=workers, parallel_after=1)
        return sorted(seen)

    serial = run(1)
    assert len(serial) > 10
    assert run(2) == serial


def test_candidates_handed_back_to_numpy_change_nothing(monkeypatch):
    """The compiled kernel hands back what it cannot conclude on (FALLBACK); forced here on
    every third candidate, the numpy kernel takes them and the walk finds the same regions
    (in another order: the neighbours of a candidate handed back are pushed after the
    batch's)."""
    ref = _solve(monkeypatch, jit_after=0)
    batch = mpqp_kernel.evaluate_batch
    handed = []

    def some_back(keys, *args):
        out = batch(keys, *args)
        status = out[0].copy()
        status[::3] = mpqp_kernel.FALLBACK
        handed.append(int(np.count_nonzero(status == mpqp_kernel.FALLBACK)))
        return (status, *out[1:])

    monkeypatch.setattr(mpqp_kernel, "evaluate_batch", some_back)
    got = _solve(monkeypatch, jit_after=0)
    assert sum(handed) > 100
    assert got.stats["handed_back"] == sum(handed)
    assert _classes(got.stats) == got.stats["candidates"]
    ref_regions = sorted(ref.regions, key=lambda r: r.active)
    got_regions = sorted(got.regions, key=lambda r: r.active)
    assert [r.active for r in ref_regions] == [r.active for r in got_regions]
    for r, s in zip(ref_regions, got_regions, strict=True):
        np.testing.assert_allclose(r.K, s.K, atol=1e-9)
        np.testing.assert_allclose(r.k, s.k, atol=1e-9)


def _classes(stats: dict) -> int:
    return sum(v for k, v in stats.items() if k.startswith("candidates_"))


def test_candidates_are_counted_by_class(monkeypatch):
    """``stats`` splits the candidates by class, in both walks; a full candidate is a
    region (before the merge of equal laws)."""
    for jit_after in (10**9, 0):
        sol = _solve(monkeypatch, jit_after=jit_after)
        st = sol.stats
        assert st["candidates_full"] == sol.num_regions + st.get("merged", 0)
        assert st["candidates_empty"] > 0
        assert _classes(st) == st["candidates"]
    assert st.get("handed_back", 0) == 0


def _rows_with_twins(seed: int):
    """Random unit rows with exact duplicates, negated copies and -0.0 entries."""
    rng = np.random.default_rng(seed)
    M = rng.normal(size=(300, 4))
    M[rng.random(M.shape) < 0.2] = 0.0
    M = np.vstack([M, M[:60], -M[40:100], -M[:5] * 0.0])
    return M[rng.permutation(M.shape[0])]


def _keys(M):
    return [tuple(np.round(r, 7) + 0.0) for r in M]


@pytest.mark.parametrize("seed", range(3))
def test_row_hashing_agrees_with_exact_comparison(seed):
    """unique_rows, rows_in (numpy, hashed) and unpaired_rows (compiled) against sets of
    rounded tuples."""
    M = _rows_with_twins(seed)
    keys = _keys(M)
    first = polytope.unique_rows(M, 7)
    seen = {}
    for i, k in enumerate(keys):
        seen.setdefault(k, i)
    assert first.tolist() == sorted(seen.values())
    Q = np.vstack([M[:50], M[:50] + 1e-3])
    assert polytope.rows_in(Q, -M, 7).tolist() == [
        k in set(_keys(-M)) for k in _keys(Q)
    ]
    got = active_sets.unpaired_rows(np.ascontiguousarray(M[:, :-1]), M[:, -1].copy(), 7)
    negs = set(_keys(-M))
    want = [i in seen.values() and seen[k] == i and k not in negs for i, k in enumerate(keys)]
    assert got.tolist() == want


def test_row_hash_collisions_fall_back_to_exact_comparison(monkeypatch):
    """Every row hashed alike: unique_rows and rows_in must notice and still be exact."""
    M = _rows_with_twins(0)
    want_first = polytope.unique_rows(M, 7)
    Q = np.vstack([M[:50], M[:50] + 1e-3])
    want_in = polytope.rows_in(Q, -M, 7)
    monkeypatch.setattr(polytope, "row_hashes", lambda R: np.zeros(R.shape[0], np.uint64))
    np.testing.assert_array_equal(polytope.unique_rows(M, 7), want_first)
    np.testing.assert_array_equal(polytope.rows_in(Q, -M, 7), want_in)


def test_a_merged_region_keeps_one_copy_of_a_shared_row():
    """[0,1]x[0,1] and [1,2]x[0,1] merge into [0,2]x[0,1], whose envelope holds y <= 1 and
    y >= 0 from both boxes. The copy's redundancy has no certificate with a margin (it is
    the same half-space), so it used to stay: 6 rows instead of 4 (and copies through one
    vertex later made the compiled LP's working set singular)."""
    from codev_engine.mp.merge import merge_regions

    A = np.vstack([np.eye(2), -np.eye(2)])
    As, bs, src = merge_regions([A, A], [np.array([1.0, 1, 0, 0]), np.array([2.0, 1, -1, 0])],
                                [b"k", b"k"])
    assert len(As) == 1 and As[0].shape == (4, 2)
    lo, hi = polytope.bounding_box(As[0], bs[0])
    np.testing.assert_allclose(lo, [0, 0], atol=1e-12)
    np.testing.assert_allclose(hi, [2, 1], atol=1e-12)


def test_equal_laws_are_merged_after_rounding():
    """mpqp._merge_equal_laws rounds laws to 1e-7 of the scale (np.rint, -0.0 as +0.0):
    two adjacent boxes whose laws differ by 1e-12 and a signed zero become one region; a
    third with another law stays apart, and all-distinct laws leave the list as it is."""
    from codev_engine.mp.solution import CriticalRegion, RegionArrays

    def box(lo, hi, K, k, act):
        A = np.vstack([np.eye(2), -np.eye(2)])
        b = np.r_[hi, -np.asarray(lo)].astype(float)
        return CriticalRegion(A=A, b=b, K=K, k=k, active=act)

    K = np.array([[1.0, 0.0], [2.0, -3.0]])
    k = np.array([0.5, 0.0])
    regions = [
        box([0, 0], [1, 1], K, k, (0,)),
        box([1, 0], [2, 1], K + 1e-12, np.array([0.5, -0.0]), (1,)),
        box([2, 0], [3, 1], 2 * K, k, (2,)),
    ]
    stats: dict = {}
    merged = mpqp._merge_equal_laws(RegionArrays.from_regions(regions), 1.0, stats)
    assert len(merged) == 2 and stats["merged"] == 1
    wide = [r for r in merged if np.array_equal(r.K, K)][0]
    lo, hi = polytope.bounding_box(wide.A, wide.b)
    np.testing.assert_allclose(lo, [0, 0], atol=1e-9)
    np.testing.assert_allclose(hi, [2, 1], atol=1e-9)
    apart = RegionArrays.from_regions(
        [box([0, 0], [1, 1], K, k, (0,)), box([1, 0], [2, 1], K + 1e-3, k, (1,))]
    )
    assert mpqp._merge_equal_laws(apart, 1.0, {}) is apart


# ---------------------------------------------------------------------------------------
# the subsets of an active set that breaks LICQ (mpqp.dependent_rows)
# ---------------------------------------------------------------------------------------


def _rate_rows() -> np.ndarray:
    """Unit rows of a 3-input horizon: bounds +-u_k, and rate rows +-(u_k - u_{k-1})."""
    eye = np.eye(3)
    rows = [eye[0], eye[1], eye[2], -eye[0], -eye[1], -eye[2]]
    for k in (1, 2):
        r = (eye[k] - eye[k - 1]) / np.sqrt(2.0)
        rows += [r, -r]
    return np.array(rows)


def test_dependent_rows_are_the_support_of_the_dependency():
    G = _rate_rows()
    # u_1 <= ., u_0 >= ., and the rate u_1 - u_0 <= .: g_6 = (g_1 + g_3) / sqrt 2; the
    # bound of u_2 is independent of them: it is never the one to leave
    assert mpqp.dependent_rows(G, (1, 2, 3, 6)) == [1, 3, 6]
    # independent rows: every one (the rule for sets LICQ judged broken by a tolerance)
    assert mpqp.dependent_rows(G, (0, 1, 2)) == [0, 1, 2]
    # more rows than variables: the support of a null vector
    got = mpqp.dependent_rows(G, (0, 1, 2, 6))
    assert set(got) == {0, 1, 6}
    # nearly dependent rows (not to rounding): every one
    Gn = np.vstack([G, (G[1] + G[3] + 1e-7 * G[2]) / np.linalg.norm(G[1] + G[3] + 1e-7 * G[2])])
    assert mpqp.dependent_rows(Gn, (1, 3, 10)) == [1, 3, 10]
    # exactly dependent with a small coefficient: still in the support
    assert mpqp.dependent_rows(Gn, (1, 2, 3, 10)) == [1, 2, 3, 10]


@pytest.mark.parametrize("seed", range(6))
def test_dependent_rows_compiled_and_numpy_agree(seed):
    rng = np.random.default_rng(seed)
    G = _rate_rows()
    G = np.vstack([G, rng.normal(size=(4, 3))])
    G /= np.linalg.norm(G, axis=1)[:, None]
    graph = active_sets.ActiveSetGraph(G.shape[0], 3, np.zeros((G.shape[0],) * 2, bool),
                                       G=G, sigma=mpqp.DEPENDENT_SIGMA,
                                       support=mpqp.SUPPORT_TOL)
    for _ in range(30):
        act = tuple(sorted(rng.choice(G.shape[0], size=int(rng.integers(2, 5)),
                                      replace=False).tolist()))
        key = graph.key(act)
        got = active_sets._dependent_rows(graph.G, key, len(act), graph.sigma, graph.support)
        assert got.tolist() == mpqp.dependent_rows(G, act), act


def test_pruned_licq_subsets_find_every_region(monkeypatch):
    """Visiting only the subsets without a constraint of the dependency (the default) finds
    the same regions as visiting every subset of an LICQ set (a sigma and a support of -1),
    with fewer candidates (459 against 1,119 in the numpy walk): the servo of
    benchmarks/formulations.py at N = 5 (theta of length 4; its rate rows make dependent
    active sets), both walks."""
    from codev_engine.mpc import build_program
    from codev_engine.pipeline import loads_spec
    from codev_engine.plant import discretize

    sys_path = str(Path(__file__).resolve().parents[2] / "benchmarks")
    monkeypatch.syspath_prepend(sys_path)
    import formulations

    problem = loads_spec(formulations.SERVO.format(N=5), check_mpc=False)
    program = build_program(problem.mpc, discretize(problem)).program
    for jit_after in (0, 10**9):
        monkeypatch.setattr(mpqp, "JIT_AFTER", jit_after)
        pruned = ce.mpsolve(program, options=ce.SolveOptions(workers=1))
        monkeypatch.setattr(mpqp, "DEPENDENT_SIGMA", -1.0)
        monkeypatch.setattr(mpqp, "SUPPORT_TOL", -1.0)
        every = ce.mpsolve(program, options=ce.SolveOptions(workers=1))
        monkeypatch.undo()
        assert pruned.num_regions == every.num_regions > 50
        assert [r.active for r in pruned.regions] == [r.active for r in every.regions]
        for r, s in zip(pruned.regions, every.regions, strict=True):
            np.testing.assert_allclose(r.K, s.K, rtol=1e-9, atol=1e-9)
        # (the compiled walk from the start swaps across most such facets already)
        limit = 1.0 if jit_after == 0 else 0.6
        assert pruned.stats["candidates"] <= limit * every.stats["candidates"]
