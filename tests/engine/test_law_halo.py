"""A sharded law's halo (``law_halo``, issue 43): each cell's shard also holds copies of the
other shards' regions whose boxes reach into its cell, so a box question reads only the
shards (and halos) of the cells the box meets, and answers what the merged law answers.

On laws cut by space (2-d and 3-d, written here; 2-d, written by the sharded search's
workers on a real ``LocalCluster``): random boxes give the merged ``ExplicitLaw``'s
``regions_meeting`` (the same ascending global indices, each once) from at most the cells
the box meets; ``domain_rows`` holds every facet of the domain meeting the box (an LP
each); a damaged halo is refused, naming it; the session's store checks it.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy.optimize import linprog

import codev_engine as ce
from codev_engine.errors import DamagedFileError
from codev_engine.law_halo import cells_partition
from codev_engine.law_shard_writer import split_by_cells, write_law_shards
from codev_engine.law_shards import MANIFEST, ShardedLaw
from codev_engine.mp import mpqp, sharded
from tests.engine.test_law_shards import SPEC

#: a triple integrator: a 3-d law of a few hundred regions
SPEC3 = """
name = "t3"
[plant]
states = ["p", "v", "a"]
inputs = ["u"]
A = [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
B = [[0.0], [0.0], [1.0]]
[model]
sample_time = 0.2
[mpc]
horizon = 4
Q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -2.0, -1.0]
x_max = [5.0, 2.0, 1.0]
u_min = [-1.0]
u_max = [1.0]
[verify]
time_horizon = 1.0
initial_set = { lower = [-0.5, -0.2, -0.1], upper = [0.5, 0.2, 0.1] }
"""


def _law(tmp_path_factory, text: str):
    path = tmp_path_factory.mktemp("halo") / "t.toml"
    path.write_text(text)
    return ce.synthesize(ce.load_spec(path))


@pytest.fixture(scope="module", params=["2d", "3d"])
def written(request, tmp_path_factory):
    """A law cut into 4 cells by space, written with its halo: (the law, its folder)."""
    law = _law(tmp_path_factory, SPEC if request.param == "2d" else SPEC3)
    parts, cells = split_by_cells(law, 4)
    folder = tmp_path_factory.mktemp("law") / "law"
    write_law_shards(folder, parts, cells)
    return law, folder


def _cells_met(law: ShardedLaw, lo: np.ndarray, hi: np.ndarray) -> set[int]:
    clo, chi = law._halo
    return set(np.flatnonzero(np.all(clo <= hi + 1e-8, axis=1)
                              & np.all(chi >= lo - 1e-8, axis=1)).tolist())


def test_a_box_question_reads_the_cells_it_meets_alone(written):
    """Random boxes (small and large, in and about the domain): the merged law's answer,
    from the shards and halos of the cells the box meets alone; the rows of a region found
    in a halo are the region's."""
    law, folder = written
    sl = ShardedLaw(folder)
    assert sl.has_halo and sl.shards == 4
    assert sum(e["halo"] for e in sl._entries) > 0
    merged = sl.merged()
    n = sl.n
    lo0, hi0 = merged.boxes[0].min(axis=0), merged.boxes[1].max(axis=0)
    rng = np.random.default_rng(1)
    fewer = 0
    for q in range(120):
        c = rng.uniform(lo0, hi0)
        r = (hi0 - lo0) * rng.choice([0.01, 0.05, 0.2]) * rng.uniform(0.5, 1.0, n)
        lo, hi = c - r, c + r
        fresh = ShardedLaw(folder, cache=8)
        got = fresh.regions_meeting(lo, hi)
        np.testing.assert_array_equal(got, merged.regions_meeting(lo, hi))
        met = _cells_met(fresh, lo, hi)
        assert set(fresh._cache) <= met and set(fresh._halos) <= met, (q, met)
        fewer += len(met) < 4
        for i in got[:4]:  # (a copy's rows and law are its owner's)
            np.testing.assert_array_equal(fresh.A[int(i)], merged.A[int(i)])
            np.testing.assert_array_equal(fresh.b[int(i)], merged.b[int(i)])
            np.testing.assert_array_equal(fresh.F[int(i)], merged.F[int(i)])
            np.testing.assert_array_equal(fresh.G[int(i)], merged.G[int(i)])
        assert set(fresh._cache) <= met  # (the copies' rows read from the halos)
    assert fewer > 60  # (most boxes meet fewer cells than there are)
    # locate and evaluate are unchanged: the law's
    X = rng.uniform(lo0, hi0, size=(400, n))
    np.testing.assert_array_equal(sl.evaluate(X), merged.evaluate(X))


def test_the_cells_must_partition_space(written, tmp_path):
    """A halo answers exactly because every point is in a cell: a manifest whose cells
    leave a gap is answered without it (by the group boxes); one without the halo opens
    as before."""
    _, folder = written
    data = json.loads((folder / MANIFEST).read_text())
    lo = np.array([[-np.inf if v is None else v for v in e["cell_lo"]] for e in data["shards"]])
    hi = np.array([[np.inf if v is None else v for v in e["cell_hi"]] for e in data["shards"]])
    assert cells_partition(lo, hi)
    assert np.isinf(lo).any() and np.isinf(hi).any()  # (the outer cells are unbounded)
    shrunk = hi.copy()
    shrunk[0][np.isfinite(shrunk[0])] -= 1e-3  # (a gap beside cell 0)
    shrunk[0][np.isinf(shrunk[0])] = 1e6
    assert not cells_partition(lo, shrunk)
    copy = tmp_path / "law"
    shutil.copytree(folder, copy)
    data["shards"][0]["cell_hi"] = [float(v) for v in shrunk[0]]
    (copy / MANIFEST).write_text(json.dumps(data))
    gap = ShardedLaw(copy)
    assert not gap.has_halo
    box = (np.full(gap.n, -0.3), np.full(gap.n, 0.3))
    np.testing.assert_array_equal(gap.regions_meeting(*box),
                                  ShardedLaw(folder).regions_meeting(*box))
    # (a manifest written before the halo: its group boxes, the same answers)
    for e in data["shards"]:
        for key in ("halo_file", "halo_sha256", "halo_bytes", "halo", "halo_facets"):
            e.pop(key)
    (copy / MANIFEST).write_text(json.dumps(data))
    old = ShardedLaw(copy)
    assert not old.has_halo
    np.testing.assert_array_equal(old.regions_meeting(*box),
                                  ShardedLaw(folder).regions_meeting(*box))


def test_a_damaged_halo_is_refused_naming_it(written, tmp_path):
    _, folder = written
    copy = tmp_path / "law"
    shutil.copytree(folder, copy)
    data = json.loads((copy / MANIFEST).read_text())
    name = next(e["halo_file"] for e in data["shards"] if e["halo"])
    path = copy / name
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 1
    path.write_bytes(bytes(raw))
    law = ShardedLaw(copy)
    with pytest.raises(DamagedFileError, match=name):
        law.regions_meeting(np.full(law.n, -100.0), np.full(law.n, 100.0))
    path.unlink()
    with pytest.raises(DamagedFileError, match=f"{name}: missing"):
        ShardedLaw(copy).regions_meeting(np.full(law.n, -100.0), np.full(law.n, 100.0))


# -- the sharded search's workers build the halo ---------------------------------------------


@pytest.fixture(scope="module")
def searched(cluster, tmp_path_factory):
    """The 2-d law of the sharded search (2 workers: 2 cells), written with its halo by the
    workers, and the serial law."""
    path = tmp_path_factory.mktemp("spec") / "t.toml"
    path.write_text(SPEC)
    problem = ce.load_spec(path)
    out = tmp_path_factory.mktemp("law") / "law"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        mp.setattr(sharded, "BUDGET", 16)
        law = ce.synthesize(problem, executor=cluster, sharded=True, out_shards=out)
    assert isinstance(law, ShardedLaw) and law.shards == 2 and law.has_halo
    return law, ce.synthesize(problem)


def _unit(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(A, axis=1, keepdims=True)
    return np.hstack([A, b[:, None]]) / norm


def test_the_workers_halo_answers_as_the_merged_law(searched):
    """The workers' halo: each cell's copies are the other shard's regions whose boxes
    meet it; box questions read the cells they meet alone and answer the merged law's;
    the stats say what it cost."""
    law, _ = searched
    stats = law.meta["stats"]
    assert stats["halo_regions"] == sum(e["halo"] for e in law._entries) > 0
    assert stats["halo_worker_cpu_seconds"] > 0 and stats["halo_bytes"] > 0
    merged = law.merged()
    blo, bhi = merged.boxes
    clo, chi = law._halo
    for c in range(2):
        want = np.flatnonzero(np.all(blo <= chi[c] + 2e-9, axis=1)
                              & np.all(bhi >= clo[c] - 2e-9, axis=1))
        own = np.arange(law.offsets[c], law.offsets[c + 1])
        np.testing.assert_array_equal(law.halo(c).owner, np.setdiff1d(want, own))
    rng = np.random.default_rng(5)
    for _ in range(60):
        c = rng.uniform([-6.0, -2.5], [6.0, 2.5])
        r = rng.choice([0.06, 0.3, 1.0]) * np.array([1.0, 0.5])
        fresh = ShardedLaw(law.dir)
        np.testing.assert_array_equal(fresh.regions_meeting(c - r, c + r),
                                      merged.regions_meeting(c - r, c + r))
        met = _cells_met(fresh, c - r, c + r)
        assert set(fresh._cache) <= met and set(fresh._halos) <= met


def test_domain_rows_with_a_halo_hold_every_facet_that_meets_the_box(searched):
    """docs/scale.md's guarantee with the halo: every facet of the domain meeting the box
    (an LP each) is among the rows, the facets of the cells it meets (own and halo) alone
    read."""
    law, serial = searched
    dA, db = serial.domain_A, serial.domain_b
    theirs = _unit(dA, db)
    rng = np.random.default_rng(3)
    hits = 0
    for q in range(60):
        c = rng.uniform([-6.0, -2.5], [6.0, 2.5])
        if q % 2:  # (about the middle of a facet)
            f = rng.integers(dA.shape[0])
            ends = [linprog(s * np.array([1.0, 1.0]), A_ub=dA, b_ub=db, A_eq=dA[f:f + 1],
                            b_eq=db[f:f + 1], bounds=[(None, None)] * 2, method="highs").x
                    for s in (1.0, -1.0)]
            c = 0.5 * (ends[0] + ends[1]) + rng.normal(0.0, 0.05, 2)
        r = rng.choice([0.06, 0.3]) * np.array([1.0, 0.5])
        lo, hi = c - r, c + r
        fresh = ShardedLaw(law.dir)
        A, b = fresh.domain_rows(lo, hi)
        assert set(fresh._facets) <= _cells_met(fresh, lo, hi)
        ours = _unit(A, b)
        for f in range(dA.shape[0]):
            res = linprog(np.zeros(2), A_ub=dA, b_ub=db + 1e-12, A_eq=dA[f:f + 1],
                          b_eq=db[f:f + 1], bounds=list(zip(lo, hi, strict=True)),
                          method="highs")
            if res.status == 0:
                hits += 1
                assert np.min(np.abs(ours - theirs[f]).max(axis=1)) < 1e-7, (f, lo, hi)
    assert hits >= 20


def test_the_k_d_cells_of_the_sharded_search_are_a_partition():
    """``kd_cells``' cells, however many and however few points (empty cells, a cut at
    infinity), pass ``cells_partition``; a missing cell or an overlap does not."""
    from codev_engine.mp.shard_space import kd_cells

    rng = np.random.default_rng(2)
    for cells in (1, 2, 3, 4, 7, 8):
        for points in (rng.normal(size=(500, 3)), rng.normal(size=(2, 3)),
                       np.zeros((1, 3))):
            lo, hi = kd_cells(points, np.ones(points.shape[0]), cells)
            assert cells_partition(lo, hi), (cells, points.shape)
    lo, hi = kd_cells(rng.normal(size=(500, 3)), np.ones(500), 4)
    assert not cells_partition(lo[1:], hi[1:])  # (a hole)
    over = hi.copy()
    over[0][np.isfinite(over[0])] += 0.1  # (an overlap)
    assert not cells_partition(lo, over)
