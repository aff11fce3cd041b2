"""A law written as shards (``law_shard_writer.py``) and read lazily (``law_shards.py``) is
the whole law.

The shards of a synthesised law answer ``locate``, ``evaluate``, ``regions_meeting`` and
``law.F[i]`` as the law does, reading only the shards a question meets; a verification on
them gives the law's result; a shard file damaged, edited or swapped is refused with one
line naming it (the CLI: exit 2); ``codev export`` takes the folder. The sharded search on
a real Dask ``LocalCluster`` writes a law whose shards equal the serial law (slow: a
cluster).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.law_shard_writer import (
    box_groups,
    spatial_order,
    split_law,
    write_law_shards,
)
from codev_engine.law_shards import MANIFEST, ShardedLaw
from workbench.cli import main

SPEC = """
name = "t"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
[model]
sample_time = 0.2
[mpc]
horizon = 6
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -2.0]
x_max = [5.0, 2.0]
u_min = [-1.0]
u_max = [1.0]
[verify]
time_horizon = 3.0
initial_set = { lower = [-0.5, -0.2], upper = [0.5, 0.2] }
"""


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("shards") / "t.toml"
    path.write_text(SPEC)
    return path


@pytest.fixture(scope="module")
def law(spec):
    out = ce.synthesize(ce.load_spec(spec))
    assert out.num_regions > 20
    return out


def _equal_laws(a, b) -> None:
    assert a.num_regions == b.num_regions
    for i in range(a.num_regions):
        np.testing.assert_array_equal(a.A[i], b.A[i])
        np.testing.assert_array_equal(a.b[i], b.b[i])
    np.testing.assert_array_equal(np.asarray(a.F), np.asarray(b.F))
    np.testing.assert_array_equal(np.asarray(a.G), np.asarray(b.G))


def test_shards_read_lazily_answer_as_the_law(law, tmp_path):
    # in slabs (spatial_order): a small box meets a few shards, only those are read
    order = spatial_order(law)
    write_law_shards(tmp_path / "slabs", split_law(law, 4, order))
    slabs = ShardedLaw.load(tmp_path / "slabs")
    lo, hi = np.array([4.6, -0.4]), np.array([4.7, -0.3])
    assert len(law.regions_meeting(lo, hi))
    np.testing.assert_array_equal(np.sort(order[slabs.regions_meeting(lo, hi)]),
                                  law.regions_meeting(lo, hi))
    assert 0 < slabs.loads < 4
    X = np.random.default_rng(1).uniform([-6, -3], [6, 3], size=(3000, 2))
    np.testing.assert_array_equal(slabs.evaluate(X), law.evaluate(X))
    # the shards a point may be read from (the manifest's boxes): few in slabs
    inside = X[law.locate(X) >= 0]
    near = slabs.shards_at(inside)
    assert near.min() >= 1 and near.mean() < 2.5  # (every point of the law is in a box)
    # in the law's order: the same numbering
    write_law_shards(tmp_path, split_law(law, 4))
    shards = ShardedLaw.load(tmp_path, cache=2)
    assert shards.shards_at(inside).mean() > near.mean()
    assert shards.shards == 4 and shards.num_regions == law.num_regions and shards.loads == 0
    np.testing.assert_array_equal(shards.regions_meeting(lo, hi), law.regions_meeting(lo, hi))
    np.testing.assert_array_equal(shards.locate(X), law.locate(X))
    np.testing.assert_array_equal(shards.evaluate(X), law.evaluate(X))
    idx = np.array([0, law.num_regions - 1, 7, 7])
    np.testing.assert_array_equal(shards.F[idx], law.F[idx])
    np.testing.assert_array_equal(shards.A[5], law.A[5])
    assert len(shards._cache) <= 2  # (the rest were dropped, read again when asked)
    merged = shards.merged()
    _equal_laws(merged, law)
    np.testing.assert_array_equal(merged.boxes[0], law.boxes[0])


def _boxes_meeting(folder, lo, hi) -> int:
    """The shards whose box (the manifest's ``lo``, ``hi``) meets ``[lo, hi]``: the ones a
    question read before the manifest held group boxes."""
    entries = json.loads((folder / MANIFEST).read_text())["shards"]
    return sum(bool(np.all(np.asarray(e["lo"]) <= hi + 1e-9)
                    and np.all(np.asarray(e["hi"]) >= lo - 1e-9)) for e in entries)


def test_a_box_question_reads_only_the_shards_whose_group_boxes_meet_it(law, tmp_path):
    # in the law's order the shards' boxes overlap (each about the whole domain): the
    # group boxes in the manifest skip the shards none of whose regions' boxes meets the
    # box, and the answer stays the law's
    write_law_shards(tmp_path, split_law(law, 4))
    data = json.loads((tmp_path / MANIFEST).read_text())
    assert all(len(e["groups_lo"]) == min(e["regions"], 64) for e in data["shards"])
    rng = np.random.default_rng(2)
    inside = rng.uniform([-6, -3], [6, 3], size=(4000, 2))
    inside = inside[law.locate(inside) >= 0]
    before = after = 0
    for width in (0.01, 0.05):  # (of the parameter box's width, 12)
        for c in inside[:40]:
            lo, hi = c - 6 * width, c + 6 * width
            fresh = ShardedLaw(tmp_path)
            got = fresh.regions_meeting(lo, hi)
            np.testing.assert_array_equal(got, law.regions_meeting(lo, hi))
            assert fresh.loads == fresh.met  # (only the shards met are read)
            # no shard holding a region whose box meets the box is skipped
            theirs = {int(np.searchsorted(fresh.offsets, i, side="right")) - 1 for i in got}
            assert theirs <= set(fresh._cache)
            before += _boxes_meeting(tmp_path, lo, hi)
            after += fresh.loads
    assert after < 0.8 * before, (after, before)  # (207 against 296 when written)
    # a manifest written before the groups opens and answers as then: its shards' boxes
    for e in data["shards"]:
        del e["groups_lo"], e["groups_hi"]
    (tmp_path / MANIFEST).write_text(json.dumps(data))
    lo, hi = inside[0] - 0.3, inside[0] + 0.3
    old = ShardedLaw(tmp_path)
    np.testing.assert_array_equal(old.regions_meeting(lo, hi), law.regions_meeting(lo, hi))
    assert old.loads == _boxes_meeting(tmp_path, lo, hi)
    np.testing.assert_array_equal(old.locate(inside), law.locate(inside))
    # group boxes the reader cannot trust are refused, naming the field
    data["shards"][1]["groups_lo"] = [[0.0, 0.0]]
    data["shards"][1]["groups_hi"] = [[1.0]]
    (tmp_path / MANIFEST).write_text(json.dumps(data))
    with pytest.raises(SpecError, match=r"shards\.json: shards\[1\]\.groups_lo"):
        ShardedLaw(tmp_path)


def test_box_groups_hold_every_box():
    rng = np.random.default_rng(5)
    lo = rng.uniform(-5, 5, size=(1000, 3))
    hi = lo + rng.exponential(0.3, size=(1000, 3))
    lo[0, 1], hi[1, 2] = -np.inf, np.inf  # (an open side stays open in its group)
    glo, ghi = box_groups(lo, hi, 16)
    assert glo.shape == ghi.shape == (16, 3)
    held = (np.all(glo[None] <= lo[:, None], axis=2) & np.all(ghi[None] >= hi[:, None], axis=2))
    assert held.any(axis=1).all()
    assert box_groups(lo[:3], hi[:3], 16)[0].shape == (3, 3)
    assert box_groups(lo[:0], hi[:0])[0].shape == (0, 3)


def test_a_verification_on_the_shards_is_the_laws(spec, law, tmp_path):
    problem = ce.load_spec(spec)
    write_law_shards(tmp_path, split_law(law, 3))
    whole, sharded = ce.verify(problem, law), ce.verify(problem, ShardedLaw(tmp_path))
    assert sharded.verdict == whole.verdict == "robustly_safe"
    assert sharded.stats["partitions"] == whole.stats["partitions"]


def test_a_verification_reads_only_the_shards_its_tube_meets(spec, law, tmp_path):
    # in slabs of space, a tube near the origin never asks the outer slabs: the engine
    # must not read the whole law up front (it read every shard's boxes at its start)
    problem = ce.load_spec(spec)
    write_law_shards(tmp_path, split_law(law, 8, spatial_order(law)))
    slabs = ShardedLaw(tmp_path)
    result = ce.verify(problem, slabs)
    assert result.verdict == ce.verify(problem, law).verdict == "robustly_safe"
    assert 0 < slabs.loads < slabs.shards


def test_a_damaged_or_swapped_shard_is_refused(law, tmp_path):
    write_law_shards(tmp_path, split_law(law, 3))
    one = tmp_path / "shard-1.npz"
    good = one.read_bytes()
    damaged = bytearray(good)
    damaged[len(good) // 2] ^= 1
    one.write_bytes(bytes(damaged))
    shards = ShardedLaw(tmp_path)
    with pytest.raises(SpecError, match=r"shard-1\.npz: its SHA-256 is not the one"):
        shards.regions_meeting(np.array([-6.0, -3.0]), np.array([6.0, 3.0]))
    # a whole law file, but not the one the manifest records (shard 2 in its place)
    one.write_bytes((tmp_path / "shard-2.npz").read_bytes())
    with pytest.raises(SpecError, match="shard-1.npz"):
        ShardedLaw(tmp_path).merged()
    one.unlink()
    with pytest.raises(SpecError, match="shard-1.npz: missing"):
        ShardedLaw(tmp_path).merged()
    manifest = tmp_path / MANIFEST
    data = json.loads(manifest.read_text())
    data["shards"][0]["file"] = "../elsewhere.npz"
    manifest.write_text(json.dumps(data))
    with pytest.raises(SpecError, match=r"shards\.json: shards\[0\]"):
        ShardedLaw(tmp_path)
    manifest.write_text("{")
    with pytest.raises(SpecError, match="shards.json: unreadable"):
        ShardedLaw(tmp_path)


def test_the_cli_refuses_a_damaged_shard_in_one_line(spec, law, tmp_path, capsys):
    write_law_shards(tmp_path, split_law(law, 2))
    # the exporter takes the folder (the law merged on demand: one table)
    assert main(["export", str(tmp_path), "--python", str(tmp_path / "law.py")]) == 0
    assert f"{law.num_regions} regions" in capsys.readouterr().out
    path = tmp_path / "shard-0.npz"
    data = bytearray(path.read_bytes())
    data[-40] ^= 1
    path.write_bytes(bytes(data))
    assert main(["verify", str(spec), "--law", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("codev: error: ") and "shard-0.npz" in err[-1]
    assert main(["synth", str(spec), "--sharded"]) == 2
    assert "--sharded: needs --workers" in capsys.readouterr().err


def _same_function(serial, shards, lo, hi, points: int = 3000, seed: int = 0) -> None:
    """``shards`` locates and evaluates as ``serial`` at random points of the box
    ``[lo, hi]`` (which reaches past the domain): the same points inside, the same law."""
    X = np.random.default_rng(seed).uniform(lo, hi, size=(points, len(lo)))
    inside, got = serial.locate(X) >= 0, shards.locate(X) >= 0
    assert 0 < inside.sum() < points  # (points inside and outside the domain)
    np.testing.assert_array_equal(inside, got)
    np.testing.assert_allclose(shards.evaluate(X), serial.evaluate(X), rtol=1e-9, atol=1e-9)


@pytest.mark.slow  # (a LocalCluster: ~10 s on a loaded machine)
def test_the_sharded_search_s_workers_write_the_law(spec, tmp_path, monkeypatch, capsys):
    """``codev synth --sharded --out-shards``: each worker writes its shard's law (equal
    laws merged within the shard), the client the manifest: the serial law's function."""
    from codev_engine.mp import mpqp, sharded

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)  # (sharded from the first region)
    monkeypatch.setattr(sharded, "BUDGET", 16)  # (rounds, keys crossing shards)
    serial = ce.synthesize(ce.load_spec(spec), options=ce.SolveOptions(workers=1))
    out = tmp_path / "law"
    code = main(["synth", str(spec), "--workers", "2", "--shard-dir", str(tmp_path / "work"),
                 "--out-shards", str(out), "--json"])
    assert code == 0 and json.loads(capsys.readouterr().out)["out"] == str(out)
    shards = ShardedLaw(out)
    assert shards.shards == 2 and shards.meta["stats"]["shards"] == 2
    assert shards.meta["regions_before_merge"] == serial.meta["regions_before_merge"]
    assert not any((tmp_path / "work").iterdir())  # (the search's own files removed)
    # (the domain: the parameter set's rows, in the manifest, and each shard's facets; the
    # serial domain's rows among them)
    ours = np.hstack([shards.domain_A, shards.domain_b[:, None]])
    for row in np.hstack([serial.domain_A, serial.domain_b[:, None]]):
        assert np.min(np.abs(ours - row).max(axis=1)) < 1e-9
    _same_function(serial, shards, [-6.0, -2.5], [6.0, 2.5])
