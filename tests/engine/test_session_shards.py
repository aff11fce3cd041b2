"""A session stores a sharded synthesis as a folder of shards (issue 43, Deliver 2).

``RunOptions(sharded=True)`` (``codev run --session DIR --workers N --sharded``): the workers
write the law's shards into a temporary folder beside the artifact, renamed into place once
its manifest is written; the store opens the folder from its manifest's SHA-256 and a stat
of each shard (its size); loading opens a ``ShardedLaw`` that reads no shard until asked,
and checks each shard's SHA-256 when it reads it. A shard of the wrong size is reported at
open, one damaged in place when read (one line), naming it, and recomputed by the next run
(the store's rule for every artifact); a torn folder is never taken. Sharding is in the
synthesis key, the serial keys are as they were. The recording's key follows the code that
draws it. The cluster runs are slow (a LocalCluster); the rest runs the same stage without
one (one shard).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from codev_engine.errors import DamagedFileError
from codev_engine.law_shards import ShardedLaw
from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.session import RunOptions, Session, SessionError, stage_keys
from codev_engine.session.stages import view_code_sha
from codev_engine.session.store import check_artifact, mark_damaged, register_artifact
from tests.engine.test_law_shards import SPEC
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
SHARDED = RunOptions(sharded=True, traces=1)


@pytest.fixture
def spec(tmp_path) -> Path:
    path = tmp_path / "t.toml"
    path.write_text(SPEC)
    return path


def _leftovers(session: Path) -> list[str]:
    """Temporary files or folders left in the session's artifacts."""
    return [p.name for p in (session / "artifacts").iterdir() if p.name.startswith(".tmp-")]


def test_a_sharded_run_stores_a_folder_of_shards_opened_lazily(spec, tmp_path):
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    rep = session.run(problem, SHARDED)
    syn = rep.stage("synthesis")
    folder = session.path / syn.artifact
    assert folder.is_dir() and folder.suffix == ".shards"
    assert sorted(p.name for p in folder.iterdir()) == ["facets-0.npz", "shard-0.npz",
                                                         "shards.json"]
    assert isinstance(rep.law, ShardedLaw) and rep.law.shards == syn.details["shards"] == 1
    assert not _leftovers(session.path)
    assert rep.stage("recording").details["view"] == view_code_sha()  # (which code drew it)
    from codev_engine.view.figures import law_html

    assert f"{rep.law.num_regions} in 1 shard<" in law_html(rep.law)  # (the notebook's)
    # the serial law beside it, under another key: the same function, the same verdict
    serial = session.run(problem, RunOptions(traces=1))
    assert serial.stage("synthesis").key != syn.key
    assert serial.stage("synthesis").outcome == syn.outcome
    assert serial.stage("verification").outcome == rep.stage("verification").outcome
    X = np.random.default_rng(0).uniform([-6, -2.5], [6, 2.5], size=(500, 2))
    np.testing.assert_array_equal(rep.law.locate(X) >= 0, serial.law.locate(X) >= 0)
    np.testing.assert_allclose(rep.law.evaluate(X), serial.law.evaluate(X), atol=1e-9)
    # again: every stage cached, the law opened without reading a shard (nothing asks it)
    again = session.run(problem, SHARDED)
    assert [s.status for s in again.stages] == ["cached"] * 4
    assert isinstance(again.law, ShardedLaw) and again.law.loads == 0
    # the journal keeps the choice; the status of the last run's options finds the folder
    assert session.journal()[-1]["options"]["sharded"] is True
    assert {s.stage: s.status for s in session.status(problem)}["synthesis"] == "cached"
    # the shard's facets of the domain are checked as its shards: one damaged in place is
    # refused when read, naming it; one truncated is named at open
    facets = folder / "facets-0.npz"
    kept = facets.read_bytes()
    _flip(facets)
    with pytest.raises(DamagedFileError, match="facets-0.npz"):
        ShardedLaw(folder).domain_rows(np.full(2, -1.0), np.full(2, 1.0))
    facets.write_bytes(kept[:-1])
    status = {s.stage: s for s in session.status(problem)}["synthesis"]
    assert status.status == "corrupt" and "facets-0.npz: its size" in status.reason


def _flip(path: Path) -> None:
    """One byte of ``path`` changed, its size kept (what a stat cannot see)."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))


def test_a_truncated_shard_is_named_at_open_and_recomputed(spec, tmp_path, capsys):
    """A shard of another size than its manifest's (truncated, or another law's swapped
    in), found when the session opens the law (a stat): ``codev session`` names it, a run
    (here ``codev replay``, which recomputes without a cluster: one shard) says so on one
    warning line and recomputes it; the verification downstream, whose key holds the
    law's, stays cached."""
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    rep = session.run(problem, SHARDED)
    folder = session.path / rep.stage("synthesis").artifact
    shard = folder / "shard-0.npz"
    shard.write_bytes(shard.read_bytes()[:-1])
    status = {s.stage: s for s in session.status(problem)}["synthesis"]
    assert status.status == "corrupt" and "shard-0.npz: its size" in status.reason
    assert main(["session", str(session.path)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "synthesis" in ln)
    assert "corrupt" in line and "shard-0.npz" in line
    assert main(["replay", str(session.path), "--json"]) == 0
    out, err = capsys.readouterr()
    got = json.loads(out)
    assert got["match"] and got["cached"] == 3  # (all but the law)
    warned = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warned) == 1 and "shard-0.npz" in warned[0] and "recomputed" in warned[0]
    assert check_artifact(session.path, folder, rep.stage("synthesis").key) is None
    assert not _leftovers(session.path)  # (the damaged folder removed once replaced)


def test_opening_a_cached_sharded_law_reads_no_shard(spec, tmp_path):
    """The session opens a law of shards from its manifest and a stat of each shard: every
    file the process opens during a cached run is recorded (the interpreter's audit
    hook, nothing patched), and no shard is among them, though every shard's content is
    damaged (its size kept: found only when read). The first question reads one and
    refuses it, naming it. A manifest written before the sizes were recorded is opened
    too (a shard's SHA-256 is checked when read)."""
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    upto = replace_upto(SHARDED, "synthesis")
    folder = session.path / session.run(problem, upto).stage("synthesis").artifact
    for shard in folder.glob("shard-*.npz"):
        _flip(shard)
    opened: list[str] = []
    recording = [False]

    def hook(event: str, args: tuple) -> None:
        if recording[0] and event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
            opened.append(os.fsdecode(args[0]))

    sys.addaudithook(hook)  # (for the rest of the process: off outside the block)
    recording[0] = True
    try:
        again = session.run(problem, upto)
        status = {s.stage: s.status for s in session.status(problem)}
    finally:
        recording[0] = False
    assert again.stage("synthesis").status == "cached" and status["synthesis"] == "cached"
    assert again.law.loads == 0
    assert any(Path(f).name == "shards.json" for f in opened)  # (the hook saw the opens)
    assert not [f for f in opened if Path(f).name.startswith("shard-")], opened
    with pytest.raises(DamagedFileError, match=r"shard-0\.npz: its SHA-256 is not the one"):
        again.law.locate(np.zeros((1, 2)))
    # a manifest without sizes (written before they were recorded): opened, checked when read
    manifest = folder / "shards.json"
    data = json.loads(manifest.read_text())
    for entry in data["shards"]:
        del entry["bytes"]
    manifest.write_text(json.dumps(data))
    register_artifact(session.path, folder, "synthesis", again.stage("synthesis").key)
    old = session.run(problem, upto)
    assert old.stage("synthesis").status == "cached" and old.law.loads == 0
    with pytest.raises(DamagedFileError, match=r"shard-0\.npz"):
        old.law.locate(np.zeros((1, 2)))


def test_a_shard_damaged_in_place_is_refused_when_read_and_recomputed(spec, tmp_path,
                                                                      capsys):
    """A flipped byte, the size kept: the session opens the law (cached), and the
    verification's first read of the shard refuses it: ``codev run --session`` ends in one
    line naming the file, exit 2, no traceback, and the artifact is marked damaged in the
    index. The run after recomputes the law (one warning naming the shard), verifies, and
    the one after that finds everything cached."""
    problem = load_spec(spec)
    s = tmp_path / "s"
    session = Session.create(s)
    syn = session.run(problem, replace_upto(SHARDED, "synthesis")).stage("synthesis")
    _flip(s / syn.artifact / "shard-0.npz")
    # (--workers: the CLI's sharded run needs a cluster; the law is cached and the linear
    # verification asks none, so none is started)
    code = main(["run", str(spec), "--session", str(s), "--workers", "2", "--sharded",
                 "--traces", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("codev: error: ") and "shard-0.npz: its SHA-256" in err[0]
    assert "next run recomputes" in err[0]
    failed = session.journal()[-1]
    assert failed["stage"] == "verification" and failed["status"] == "failed"
    assert "shard-0.npz" in check_artifact(s, s / syn.artifact, syn.key)
    status = {st.stage: st for st in session.status(problem, SHARDED)}["synthesis"]
    assert status.status == "corrupt" and "found when read" in status.reason
    # (a file of no artifact of this session, a law from elsewhere: nothing to mark)
    assert mark_damaged(s, tmp_path / "law.shards" / "shard-0.npz", "damaged") is None
    warned: list[str] = []
    after = session.run(problem, SHARDED, warn=warned.append)
    assert [st.status for st in after.stages] == ["cached", "computed", "computed", "computed"]
    assert len(warned) == 1 and "shard-0.npz" in warned[0] and "recomputed" in warned[0]
    assert after.stage("synthesis").outcome == syn.outcome
    assert after.result.verdict == "robustly_safe"
    assert check_artifact(s, s / syn.artifact, syn.key) is None
    code = main(["run", str(spec), "--session", str(s), "--workers", "2", "--sharded",
                 "--traces", "1", "--json"])
    got = json.loads(capsys.readouterr().out)
    assert code == 0 and all(st["status"] == "cached" for st in got["session"]["stages"].values())


def test_a_replay_that_finds_a_damaged_shard_ends_and_the_next_recomputes(spec, tmp_path):
    """A replay compares the stages' outcomes, a failed stage's included; a damaged shard
    is no outcome of the stage that read it: the replay ends in its error, and the replay
    after recomputes the law (one warning naming the shard) and matches."""
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    rep = session.run(problem, SHARDED)
    (session.path / rep.stage("verification").artifact).unlink()  # (the replay reads the law)
    _flip(session.path / rep.stage("synthesis").artifact / "shard-0.npz")
    with pytest.raises(DamagedFileError, match=r"shard-0\.npz: its SHA-256.*next run recomp"):
        session.replay()
    warned: list[str] = []
    again = session.replay(warn=warned.append)
    assert again.ok and again.cached == 2  # (the model, the recording: its key is the same)
    assert len(warned) == 1 and "shard-0.npz" in warned[0] and "recomputed" in warned[0]


@pytest.mark.parametrize("tear", ["manifest", "index"])
def test_a_torn_folder_is_never_taken(spec, tmp_path, tear):
    """A folder without its manifest, or one the index does not list (a write killed
    before the rename, a folder copied in): refused, recomputed."""
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    rep = session.run(problem, replace_upto(SHARDED, "synthesis"))
    folder = session.path / rep.stage("synthesis").artifact
    if tear == "manifest":
        (folder / "shards.json").unlink()
    else:
        (session.path / "artifacts" / "index.json").unlink()
    status = {s.stage: s for s in session.status(problem)}["synthesis"]
    assert status.status == "corrupt"
    assert ("shards.json" if tear == "manifest" else "index") in status.reason
    again = session.run(problem, replace_upto(SHARDED, "synthesis"))
    assert again.stage("synthesis").status == "computed"
    assert isinstance(again.law, ShardedLaw)


def replace_upto(options: RunOptions, upto: str) -> RunOptions:
    from dataclasses import replace

    return replace(options, upto=upto)


def test_sharding_keys_the_law_and_leaves_the_serial_keys_as_they_were():
    """The bundled session's first run, recorded before sharding existed: its synthesis
    and verification keys are the ones computed today."""
    bundled = Session.open(ROOT / "sessions" / "double-integrator")
    journal = bundled.journal()
    first = [r for r in journal if r["run"] == 1]
    problem = bundled._spec_of(first[0]["spec"], "run 1")
    options = RunOptions.from_json(first[0]["options"])
    keys = stage_keys(problem, options)
    recorded = {r["stage"]: r["key"] for r in first}
    assert keys["model"] == recorded["model"]
    assert keys["synthesis"] == recorded["synthesis"]
    assert keys["verification"] == recorded["verification"]
    sharded = stage_keys(problem, RunOptions.from_json({**first[0]["options"], "sharded": True}))
    assert sharded["model"] == keys["model"]
    assert all(sharded[s] != keys[s] for s in ("synthesis", "verification", "recording"))


def test_a_law_on_demand_is_not_sharded(tmp_path):
    text = SPEC.replace('name = "t"', 'name = "t"\n[synthesis]\nregions = "reached"')
    problem = loads_spec(text, path=str(tmp_path / "t.toml"))
    session = Session.create(tmp_path / "s")
    with pytest.raises(SessionError, match="sharded"):
        session.run(problem, SHARDED)
    assert not session.journal()
    # a journal's options are checked field by field: no junk in ``sharded``
    with pytest.raises(SessionError, match="options.sharded: must be true or false"):
        RunOptions.from_json({"sharded": "yes"})


def test_the_cli_refuses_sharded_without_a_session_or_a_cluster(spec, tmp_path, capsys):
    for args, field in (
        (["run", spec, "--sharded", "--workers", "2"], "--sharded needs --session"),
        (["run", spec, "--session", tmp_path / "s", "--sharded"], "--workers N"),
    ):
        code = main([str(a) for a in args])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and field in err[0], err
    assert not (tmp_path / "s").exists()


def test_the_recording_key_follows_the_drawing_code(tmp_path):
    """A copy of the engine with one line of its drawing code changed (as a picture fix
    would): the recording's key changes, no other stage's does, so the cached recording of
    the old drawing is not served (before, a fix needed ``--fresh``)."""
    import codev_engine

    copy = tmp_path / "pkg" / "codev_engine"
    shutil.copytree(Path(codev_engine.__file__).parent, copy,
                    ignore=shutil.ignore_patterns("__pycache__"))
    records = copy / "view" / "records.py"
    records.write_text(records.read_text(encoding="utf-8") + "\n# a picture fixed\n",
                       encoding="utf-8")
    spec = ROOT / "examples" / "double_integrator.toml"
    code = ("import json, sys, codev_engine\n"
            "from codev_engine.pipeline import load_spec\n"
            "from codev_engine.session import stage_keys\n"
            "assert codev_engine.__file__.startswith(sys.argv[2]), codev_engine.__file__\n"
            "print(json.dumps(stage_keys(load_spec(sys.argv[1]))))\n")
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "pkg")}
    out = subprocess.run([sys.executable, "-c", code, str(spec), str(tmp_path / "pkg")],
                         capture_output=True, text=True, env=env, timeout=120, check=True,
                         cwd=tmp_path)  # (not the checkout's folder, first on sys.path)
    theirs = json.loads(out.stdout)
    ours = stage_keys(load_spec(spec))
    assert theirs["recording"] != ours["recording"]
    assert {k: v for k, v in theirs.items() if k != "recording"} == {
        k: v for k, v in ours.items() if k != "recording"}


@pytest.mark.slow  # (a LocalCluster of 2 workers: ~15 s at load 8)
def test_codev_run_sharded_on_a_cluster_stores_the_workers_shards(spec, tmp_path, capsys,
                                                                   monkeypatch):
    """``codev run --session --workers 2 --sharded``: each worker writes its shard into
    the session ("regions=N in 2 shards"); the rerun, the replay and the status load it
    without a cluster; ``codev export`` of the session names the folder, which exports."""
    from codev_engine.mp import mpqp, sharded

    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)  # (sharded from the first region)
    monkeypatch.setattr(sharded, "BUDGET", 16)  # (rounds, keys crossing shards)
    s = tmp_path / "s"
    code = main(["run", str(spec), "--session", str(s), "--workers", "2", "--sharded",
                 "--traces", "1"])
    out = capsys.readouterr().out
    assert code == 0, out
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("synthesis"))
    assert "computed" in line and "in 2 shards" in line
    serial = Session.create(tmp_path / "serial").run(load_spec(spec), RunOptions(traces=1))
    assert f"regions={serial.law.num_regions} in 2 shards" in line
    folder = next((s / "artifacts").glob("synthesis-*.shards"))
    # (each shard's law, its facets of the domain and its halo, then the manifest)
    assert sorted(p.name for p in folder.iterdir()) == [
        "facets-0.npz", "facets-1.npz", "halo-0.npz", "halo-1.npz", "shard-0.npz",
        "shard-1.npz", "shards.json"]
    assert not _leftovers(s)
    # the rerun from the cache starts no cluster (nothing asks it) and says the same
    code = main(["run", str(spec), "--session", str(s), "--workers", "2", "--sharded",
                 "--traces", "1", "--json"])
    got = json.loads(capsys.readouterr().out)
    assert code == 0 and all(st["status"] == "cached" for st in got["session"]["stages"].values())
    assert got["verdict"] == serial.result.verdict
    # the replay (no cluster) loads the folder and matches
    assert main(["replay", str(s), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["match"]
    # export: the session names its folder of shards, which exports (merged on demand)
    assert main(["export", str(s), "--python", str(tmp_path / "law.py")]) == 2
    assert str(folder) in capsys.readouterr().err
    assert main(["export", str(folder), "--python", str(tmp_path / "law.py")]) == 0


def test_atomic_folder_is_renamed_whole_or_not_at_all(tmp_path):
    """``io.atomic.atomic_folder``: the folder takes its name only when the body returns
    (replacing the one there, moved aside first); a body that raises, Ctrl-C included,
    leaves the old folder as it was and no temporary folder."""
    from codev_engine.io.atomic import atomic_folder

    target = tmp_path / "law.shards"
    with atomic_folder(target) as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(".tmp-") and not target.exists()
        (tmp / "a").write_text("1")
    assert (target / "a").read_text() == "1"
    for exc in (RuntimeError, KeyboardInterrupt):
        with pytest.raises(exc), atomic_folder(target) as tmp:
            (tmp / "b").write_text("2")
            raise exc
        assert sorted(p.name for p in tmp_path.iterdir()) == ["law.shards"]
        assert sorted(p.name for p in target.iterdir()) == ["a"]
    with atomic_folder(target) as tmp:
        (tmp / "c").write_text("3")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["law.shards"]
    assert sorted(p.name for p in target.iterdir()) == ["c"]


def test_a_stored_law_with_a_halo_has_its_halo_files_checked(spec, tmp_path):
    """A law of shards cut by space, with its halo (``law_halo``: copies of the regions
    reaching into each shard's cell), stored in a session: the store checks each halo
    file's size as it does a shard's, and the law read back answers box questions from
    its halos; a truncated halo is named at open, as a shard is."""
    from codev_engine.law_shard_writer import split_by_cells, write_law_shards

    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    upto = replace_upto(SHARDED, "synthesis")
    rep = session.run(problem, upto)
    folder = session.path / rep.stage("synthesis").artifact
    law = rep.law.merged()
    for f in folder.iterdir():
        f.unlink()
    write_law_shards(folder, *split_by_cells(law, 3))
    register_artifact(session.path, folder, "synthesis", rep.stage("synthesis").key)
    again = session.run(problem, upto)
    assert again.stage("synthesis").status == "cached" and again.law.has_halo
    box = (np.array([-1.0, -0.5]), np.array([1.0, 0.5]))
    got = again.law.regions_meeting(*box)
    np.testing.assert_array_equal(got, again.law.merged().regions_meeting(*box))
    assert got.size and again.law.halo(0).owner.size
    halo = next(f for f in sorted(folder.glob("halo-*.npz"))
                if json.loads((folder / "shards.json").read_text())["shards"][
                    int(f.stem.split("-")[1])]["halo"])
    raw = halo.read_bytes()
    # damaged in place, its size kept: refused when a question first reads it, naming it,
    # and the artifact marked damaged (the next run recomputes it)
    fresh = session.run(problem, upto).law
    _flip(halo)
    with pytest.raises(DamagedFileError, match=halo.name):
        fresh.regions_meeting(np.full(2, -100.0), np.full(2, 100.0))
    status = {s.stage: s for s in session.status(problem)}["synthesis"]
    assert status.status == "corrupt" and halo.name in status.reason
    # truncated: named when the session opens the law (a stat)
    halo.write_bytes(raw[:-1])
    register_artifact(session.path, folder, "synthesis", rep.stage("synthesis").key)
    status = {s.stage: s for s in session.status(problem)}["synthesis"]
    assert status.status == "corrupt" and f"{halo.name}: its size" in status.reason
