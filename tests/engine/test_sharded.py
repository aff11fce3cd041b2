"""The sharded mp-QP search (``mp/sharded.py``) on a real Dask ``LocalCluster``.

Its regions and laws must be the serial search's, whatever the number of workers (1, 2 and
3 shards here), and a worker killed with SIGKILL mid-search must lose nothing: the shard is
rebuilt from its checked files on another worker. A torn shard file is refused.
"""

from __future__ import annotations

import json
import os
import signal

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SolverError
from codev_engine.mp import mpqp, shard_files, sharded
from tests.engine.test_mpqp_graph import _program
from tests.engine.test_scale import _wait_for_workers


def _same_regions(a: ce.MpSolution, b: ce.MpSolution) -> None:
    """The same regions (active sets, rows, laws) in the same (canonical) order."""
    assert a.num_regions == b.num_regions > 1
    for r, s in zip(a.regions, b.regions, strict=True):
        assert r.active == s.active
        np.testing.assert_array_equal(r.A, s.A)
        np.testing.assert_array_equal(r.b, s.b)
        np.testing.assert_array_equal(r.K, s.K)
        np.testing.assert_array_equal(r.k, s.k)


@pytest.fixture(scope="module")
def serial():
    """The serial search, the compiled kernel from the first region (as the sharded runs
    below: the numpy kernel's rows differ from it in the last bits)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        return ce.mpsolve(_program(), options=ce.SolveOptions(workers=1))


@pytest.mark.parametrize(
    "workers", [1, 2, pytest.param(3, marks=pytest.mark.slow)]  # (a cluster each: ~5 s)
)
def test_sharded_search_gives_the_serial_regions(workers, serial, monkeypatch):
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)  # (sharded from the first region)
    monkeypatch.setattr(sharded, "BUDGET", 128)  # (many rounds, keys crossing shards)
    with ce.Executor(workers=workers) as ex:
        got = ce.mpsolve(_program(), executor=ex, sharded=True)
    assert got.stats["shards"] == workers and got.stats["rounds"] > 3
    # (the candidates and active sets explored are not: a lower-dimensional candidate's
    # neighbours are the constraints tight at the point its LP found, which depends on
    # where the LP started; the regions do not)
    assert got.stats["explored"] > got.num_regions
    _same_regions(serial, got)


@pytest.mark.slow  # (~40 s: the nanny starts a new worker on a loaded machine)
def test_a_worker_killed_mid_sharded_search_loses_nothing(serial, monkeypatch, tmp_path):
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(sharded, "BUDGET", 64)
    with ce.Executor(workers=2) as ex:
        client = ex.client
        pids = client.run(os.getpid)
        killed: list[int] = []

        def progress(found: int) -> None:
            if found >= 100 and not killed:  # (between rounds: the shard's files are whole)
                holding = client.run(sharded.cached_shards)
                address = max(sorted(holding), key=lambda a: holding[a])  # (holds a shard)
                os.kill(pids[address], signal.SIGKILL)
                killed.append(pids[address])

        got = ce.mpsolve(_program(), executor=ex, sharded=True, progress=progress)
        assert killed and got.stats["shards_restored"] >= 1
        _same_regions(serial, got)
        _wait_for_workers(client, killed[0])


def test_a_torn_shard_file_is_refused(tmp_path):
    path = tmp_path / "part-0.npz"
    shard_files._write(path, {"K": np.zeros((2, 1, 1)), "explored": np.ones((2, 1), np.uint64)})
    assert shard_files._read(path)["K"].shape == (2, 1, 1)
    whole = path.read_bytes()
    at = whole.index(np.ones(2, np.uint64).tobytes())  # (the keys, stored as they are)
    altered = bytearray(whole)
    altered[at] = 2
    path.write_bytes(bytes(altered))
    with pytest.raises(SolverError, match="part-0.npz: "):  # (zip's CRC, or the SHA-256)
        shard_files._read(path)
    path.write_bytes(whole[: len(whole) // 2])  # (torn)
    with pytest.raises(SolverError, match="part-0.npz: unreadable"):
        shard_files._read(path)


def test_owners_spread_the_keys():
    keys = np.arange(1, 4001, dtype=np.uint64)[:, None]
    counts = np.bincount(sharded.owners(keys, 4), minlength=4)
    assert counts.min() > 800


@pytest.mark.slow  # (a cluster: ~10 s on a loaded machine)
def test_a_round_whose_tasks_are_cancelled_is_run_again(serial, monkeypatch):
    """The scheduler may drop a round's tasks when a worker dies ("already forgotten"):
    here a round's tasks are cancelled from another thread while the client waits for
    them; the round is submitted again and the regions are the serial ones."""
    import threading
    import time

    from distributed import Future

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(sharded, "BUDGET", 64)
    with ce.Executor(workers=2) as ex:
        client = ex.client
        cancelled: list[str] = []

        def cancel_next_round() -> None:
            for _ in range(2000):  # (the next round's first attempt, once submitted)
                keys = [k for ks in client.processing().values() for k in ks
                        if str(k).startswith("codev-shard-") and str(k).endswith("-0")]
                if keys:
                    client.cancel([Future(k, client) for k in keys])
                    cancelled.extend(keys)
                    return
                time.sleep(0.005)

        def progress(found: int) -> None:
            if found >= 100 and not cancelled and not getattr(progress, "started", False):
                progress.started = True
                threading.Thread(target=cancel_next_round, daemon=True).start()

        got = ce.mpsolve(_program(), executor=ex, sharded=True, progress=progress)
    assert cancelled and got.stats["rounds_retried"] >= 1
    _same_regions(serial, got)


def _same_function(serial: ce.MpSolution, law, points: int = 2000) -> None:
    """The sharded law (``u = z``) locates and evaluates as the serial solution at random
    points of a box past the parameter set ``[-1, 1]^4`` (outside the domain too)."""
    X = np.random.default_rng(3).uniform(-1.3, 1.3, size=(points, 4))
    inside = serial.locate(X) >= 0
    assert 0 < inside.sum() < points
    np.testing.assert_array_equal(law.locate(X) >= 0, inside)
    U = law.evaluate(X)
    assert np.all(np.isnan(U[~inside]))
    np.testing.assert_allclose(U[inside], serial.primal(X[inside]), rtol=1e-9, atol=1e-9)


def test_the_workers_write_the_law_s_shards(serial, monkeypatch, tmp_path):
    """``mpsolve(shard_writer=...)``: each worker writes its shard of the law, the client
    collects the manifest's entries and the domain's facets alone; a damaged shard is
    refused."""
    from codev_engine.errors import SpecError
    from codev_engine.law_shard_writer import ShardWriter
    from codev_engine.law_shards import ShardedLaw

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(sharded, "BUDGET", 128)
    p = _program()
    writer = ShardWriter(str(tmp_path / "law"), np.zeros(p.d), rows=(0, p.nz))
    with ce.Executor(workers=2) as ex:
        got = ce.mpsolve(p, executor=ex, sharded=True, shard_writer=writer)
    assert isinstance(got, ce.ShardedSolution) and got.stats["shards"] == 2
    law = ShardedLaw(tmp_path / "law")
    assert law.shards == 2 and law.num_regions == got.num_regions
    # (equal laws merged within a shard: at most the serial count before its merge)
    assert serial.num_regions <= law.num_regions <= serial.num_regions + serial.stats.get(
        "merged", 0)
    # the domain from the shards' facets (each shard's in its own file) and the parameter
    # set's rows: the serial one's rows, and parameter-set rows the facets imply
    rows = np.hstack([got.domain_A, got.domain_b[:, None]])
    theirs = np.hstack([serial.domain_A, serial.domain_b[:, None]])
    assert np.all(np.min(np.abs(theirs[:, None, :] - rows[None]).max(axis=2), axis=1) < 1e-9)
    box = np.hstack([p.A_theta, p.b_theta[:, None]])
    extra = np.min(np.abs(rows[:, None, :] - theirs[None]).max(axis=2), axis=1) > 1e-9
    assert np.all(np.min(np.abs(rows[extra][:, None, :] - box[None]).max(axis=2), axis=1)
                  < 1e-9)
    manifest = json.loads((tmp_path / "law" / "shards.json").read_text())
    assert "domain_A" not in manifest and sum(e["facets"] for e in manifest["shards"]) == (
        got.stats["domain_facets"])
    _same_function(serial, law)
    # the workers built each cell's halo: a box question (4-d) reads the cells it meets
    # alone and answers the merged law's
    assert law.has_halo and got.stats["halo_regions"] > 0
    merged = law.merged()
    rng = np.random.default_rng(7)
    for _ in range(40):
        c, r = rng.uniform(-1, 1, 4), rng.choice([0.02, 0.1, 0.4])
        fresh = ShardedLaw(tmp_path / "law")
        np.testing.assert_array_equal(fresh.regions_meeting(c - r, c + r),
                                      merged.regions_meeting(c - r, c + r))
        clo, chi = fresh._halo
        met = set(np.flatnonzero(np.all(clo <= c + r + 1e-8, axis=1)
                                 & np.all(chi >= c - r - 1e-8, axis=1)).tolist())
        assert set(fresh._cache) <= met and set(fresh._halos) <= met
    # the shards are cells of space: locate asks the point's cell's shard first
    X = np.random.default_rng(4).uniform(-1, 1, size=(500, 4))
    fresh = ShardedLaw(tmp_path / "law")
    np.testing.assert_array_equal(fresh.locate(X) >= 0, serial.locate(X) >= 0)
    assert fresh.asked < law.shards_at(X).sum()
    assert all(cell is not None for cell in fresh._cells)  # (the manifest's, read back)

    def strict(name: str):
        raise AssertionError(f"the manifest is not strict JSON: {name}")

    json.loads((tmp_path / "law" / "shards.json").read_text(), parse_constant=strict)
    # a shard damaged after the fact is refused, naming it
    path = tmp_path / "law" / "shard-1.npz"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))
    with pytest.raises(SpecError, match="shard-1.npz"):
        ShardedLaw(tmp_path / "law").merged()


@pytest.mark.slow  # (~40 s: the nanny starts a new worker on a loaded machine)
def test_a_worker_killed_while_the_workers_write_the_law_loses_nothing(
        serial, monkeypatch, tmp_path):
    from codev_engine.law_shard_writer import ShardWriter

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(sharded, "BUDGET", 64)
    p = _program()
    writer = ShardWriter(str(tmp_path / "law"), np.zeros(p.d), rows=(0, p.nz))
    with ce.Executor(workers=2) as ex:
        client = ex.client
        pids = client.run(os.getpid)
        killed: list[int] = []

        def progress(found: int) -> None:
            if found >= 100 and not killed:
                holding = client.run(sharded.cached_shards)
                address = max(sorted(holding), key=lambda a: holding[a])
                os.kill(pids[address], signal.SIGKILL)
                killed.append(pids[address])

        got = ce.mpsolve(p, executor=ex, sharded=True, progress=progress,
                         shard_writer=writer)
        assert killed and got.stats["shards_restored"] >= 1
        _same_function(serial, got.law)
        _wait_for_workers(client, killed[0])


def test_kd_cells_partition_space_and_balance_the_weight():
    """The end's cells (``shard_space.kd_cells``) are half-open boxes: every point is in
    exactly one (the cuts' own coordinates and the sample's outliers too), and each holds
    about its share of the weighted sample."""
    from codev_engine.mp.shard_space import cell_of, kd_cells

    rng = np.random.default_rng(5)
    pts = rng.normal(size=(3000, 3)) * [1.0, 4.0, 0.5]
    w = np.where(pts[:, 0] > 0, 3.0, 1.0)  # (a shard of 3x the regions per sample)
    for cells in (1, 2, 3, 5, 8):
        lo, hi = kd_cells(pts, w, cells)
        assert lo.shape == hi.shape == (cells, 3)
        c = cell_of(pts, lo, hi)
        share = np.bincount(c, weights=w, minlength=cells) / w.sum()
        assert np.all(np.abs(share - 1 / cells) < 0.02), share
        # the cuts themselves and far points are in exactly one cell
        edges = np.vstack([np.where(np.isfinite(lo), lo, 0.0), np.full((1, 3), 1e300),
                           np.full((1, 3), -1e300)])
        assert np.all(cell_of(edges, lo, hi) < cells)
    lo, hi = kd_cells(np.zeros((0, 2)), np.zeros(0), 4)  # (no region: 4 cells, all of space)
    assert cell_of(np.array([[0.0, 0.0], [1.0, -1.0]]), lo, hi).shape == (2,)
    lo, hi = kd_cells(np.ones((10, 2)), np.ones(10), 3)  # (all at one point: one cell)
    assert len(set(cell_of(np.ones((10, 2)), lo, hi))) == 1


@pytest.mark.slow  # (two searches and a worker restarted: ~40 s on a loaded machine)
def test_a_worker_killed_in_the_search_s_last_step_writes_the_same_law(
        monkeypatch, tmp_path):
    """SIGKILL to a worker while it runs a task of the end (``shard_space``: the regions
    cut by space): its tasks run again on the other worker from the files, and the law
    written is the one written without the kill, shard by shard."""
    import threading
    import time

    from codev_engine.law_shard_writer import ShardWriter
    from codev_engine.law_shards import ShardedLaw

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(sharded, "BUDGET", 128)
    p = _program()
    with ce.Executor(workers=2) as ex:
        client = ex.client
        ce.mpsolve(p, executor=ex, sharded=True,
                   shard_writer=ShardWriter(str(tmp_path / "calm"), np.zeros(p.d),
                                            rows=(0, p.nz)))
        pids = client.run(os.getpid)
        killed: list[int] = []

        def kill_in_the_last_step() -> None:
            for _ in range(20000):  # (a task cutting a shard by space, on its worker)
                for address, keys in client.processing().items():
                    if any("-cut-" in str(k) for k in keys) and address in pids:
                        os.kill(pids[address], signal.SIGKILL)
                        killed.append(pids[address])
                        return
                time.sleep(0.002)

        def progress(found: int) -> None:
            if not getattr(progress, "started", False):
                progress.started = True
                threading.Thread(target=kill_in_the_last_step, daemon=True).start()

        got = ce.mpsolve(p, executor=ex, sharded=True, progress=progress,
                         shard_writer=ShardWriter(str(tmp_path / "killed"), np.zeros(p.d),
                                                  rows=(0, p.nz)))
        assert killed, "no task of the last step was seen on a worker"
        # (the killed worker's shard was cut again elsewhere, from its files)
        assert got.stats["end_restored"] >= 1
        _wait_for_workers(client, killed[0])
    calm, law = ShardedLaw(tmp_path / "calm"), ShardedLaw(tmp_path / "killed")
    assert law.shards == calm.shards == 2 and got.num_regions == calm.num_regions
    np.testing.assert_array_equal(law.offsets, calm.offsets)
    for j in range(law.shards):
        a, b = law.shard(j), calm.shard(j)
        for name in ("F", "G"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        for x, y in zip(a.A + a.b, b.A + b.b, strict=True):
            np.testing.assert_array_equal(x, y)


def test_region_centres_are_points_of_their_regions():
    """The end stores a region by its centre (``shard_space.region_centres``): a point of
    the region (a Chebyshev centre); of an empty one (none in a law), a finite point."""
    from codev_engine.mp.shard_space import region_centres
    from codev_engine.mp.solution import RegionArrays

    eye = np.eye(2)
    box = lambda lo, hi: (np.vstack([eye, -eye]), np.r_[hi, -np.asarray(lo)])  # noqa: E731
    regions = [box([0.0, 0.0], [4.0, 1.0]), box([-3.0, -3.0], [-2.0, 5.0]),
               (np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-1.0, 0.0]))]  # (empty)
    A = np.vstack([a for a, _ in regions])
    b = np.concatenate([b for _, b in regions])
    ra = RegionArrays(A, b, np.array([0, 4, 8, 10]), np.zeros((3, 1, 2)), np.zeros((3, 1)),
                      np.zeros(0, np.int64), np.zeros(4, np.int64))
    x0 = np.array([7.0, 7.0])
    c = region_centres(ra, x0, 10.0)
    assert c.shape == (3, 2) and np.all(np.isfinite(c))
    for i in range(2):
        assert np.all(regions[i][0] @ c[i] <= regions[i][1] - 0.4)  # (inside, with a ball)
    assert abs(c[2, 0] + 0.5) < 1e-9  # (the LP's ball of radius -0.5: the least violation)
