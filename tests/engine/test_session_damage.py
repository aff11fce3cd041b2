"""A session's artifacts survive damage found late, kills and Ctrl-C (issue 43, "the session
stores the shards").

- A shard of a stored law found damaged by whatever reads it, after the run included (``codev
  report``, the workbench, the notebook: they open cached artifacts through
  ``Session.load``), marks the artifact damaged: one line naming the file, exit 2, and the
  next run recomputes it.
- A law folder that lost a shard file, or whose manifest is truncated: ``codev session``
  lists it corrupt naming the file, ``codev report`` refuses it in one line (exit 2),
  ``codev replay`` and the next run recompute it.
- A writer killed mid-write (SIGKILL, SIGTERM; SIGINT removes its own) leaves ``.tmp-*`` entries,
  never used; the next run removes those no live writer holds (``io.atomic.remove_stale``:
  the writer's ``flock``), never one a concurrent live run is writing.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from codev_engine.errors import DamagedFileError
from codev_engine.io.atomic import STALE_AFTER, remove_stale
from codev_engine.law_shards import ShardedLaw
from codev_engine.pipeline import load_spec
from codev_engine.session import RunOptions, Session
from codev_engine.session.store import (
    check_artifact,
    file_sha,
    register_artifact,
    remove_temporaries,
)
from tests.engine.test_law_shards import SPEC
from tests.engine.test_session_shards import SHARDED, _flip, _leftovers, replace_upto
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def spec(tmp_path) -> Path:
    path = tmp_path / "t.toml"
    path.write_text(SPEC)
    return path


def _age(paths, seconds: float = 2 * STALE_AFTER) -> None:
    """Make ``paths`` look ``seconds`` old (what the wait for a stale temporary would do)."""
    past = time.time() - seconds
    for p in paths:
        os.utime(p, (past, past))


# --------------------------------------------------------------------------------------------
# 1. a damaged shard found after the run
# --------------------------------------------------------------------------------------------


def test_a_shard_damaged_found_by_codev_report_marks_it_and_the_next_run_recomputes(
        spec, tmp_path, capsys):
    """The run is over and cached; a shard is damaged in place (its size kept: the open
    cannot see it). ``codev report DIR`` draws the law, reads the shard, and ends in one
    line naming it and saying the next run recomputes it (exit 2); the index marks it, so
    ``codev session`` lists it corrupt and the next run recomputes it (one warning) instead
    of failing again."""
    problem = load_spec(spec)
    s = tmp_path / "s"
    session = Session.create(s)
    upto = replace_upto(SHARDED, "verification")
    syn = session.run(problem, upto).stage("synthesis")
    folder = s / syn.artifact
    _flip(folder / "shard-0.npz")
    assert check_artifact(s, folder, syn.key) is None  # (a stat cannot see it)
    code = main(["report", str(s), "--out", str(tmp_path / "r.html")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "shard-0.npz: its SHA-256" in err[0] and "next run recomputes" in err[0]
    assert not (tmp_path / "r.html").exists()
    assert "shard-0.npz" in check_artifact(s, folder, syn.key)
    assert main(["session", str(s)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "synthesis" in ln)
    assert "corrupt" in line and "shard-0.npz" in line and "found when read" in line
    warned: list[str] = []
    again = session.run(problem, upto, warn=warned.append)
    assert again.stage("synthesis").status == "computed"
    assert len(warned) == 1 and "shard-0.npz" in warned[0] and "recomputed" in warned[0]
    assert check_artifact(s, folder, syn.key) is None


def test_every_law_the_session_opens_marks_its_artifact_when_a_shard_is_damaged(
        spec, tmp_path):
    """The workbench and the notebook open cached artifacts with ``Session.load`` (as
    ``codev report``): a question asked of the law after the run, here the law's facets of
    the domain and a point located, marks the artifact whichever file is found damaged.
    A law a run computed is bound too. A law opened from the folder alone (no session)
    raises the error as it is and marks nothing."""
    problem = load_spec(spec)
    s = tmp_path / "s"
    session = Session.create(s)
    upto = replace_upto(SHARDED, "synthesis")
    rep = session.run(problem, upto)
    syn = rep.stage("synthesis")
    folder = s / syn.artifact
    kept = (folder / "facets-0.npz").read_bytes()
    _flip(folder / "facets-0.npz")
    alone = ShardedLaw(folder)  # (no session: nothing to mark, the error as it is)
    with pytest.raises(DamagedFileError) as exc:
        alone.domain_rows(np.full(2, -1.0), np.full(2, 1.0))
    assert "next run" not in str(exc.value) and check_artifact(s, folder, syn.key) is None
    with pytest.raises(DamagedFileError, match=r"facets-0\.npz.*next run recomputes") as exc:
        rep.law.domain_rows(np.full(2, -1.0), np.full(2, 1.0))  # (the computed one)
    assert exc.value.artifact == folder.name
    assert "facets-0.npz" in check_artifact(s, folder, syn.key)
    # recomputed (the same bytes: the same key, the same law), then opened as a front end does
    (folder / "facets-0.npz").write_bytes(kept)
    assert session.run(problem, upto).stage("synthesis").status == "computed"
    law = session.load("synthesis", folder, problem)
    _flip(folder / "shard-0.npz")
    with pytest.raises(DamagedFileError, match=r"shard-0\.npz.*next run recomputes"):
        law.locate(np.zeros((1, 2)))
    assert "shard-0.npz" in check_artifact(s, folder, syn.key)
    # (a copy sent to a worker carries no callback: the session marks the error it returns)
    import pickle

    assert pickle.loads(pickle.dumps(law)).on_damaged is None


def test_a_session_law_folder_given_by_its_path_is_marked_too(spec, tmp_path, capsys):
    """``codev export DIR`` and ``codev verify SPEC --law DIR`` of a session's folder of
    shards (``codev export SESSION`` names it): a damaged shard is one line naming it (exit
    2) and marks the artifact in its session (``Session.holding``); a copy of the folder
    out of the session marks nothing."""
    problem = load_spec(spec)
    s = tmp_path / "s"
    syn = Session.create(s).run(problem, replace_upto(SHARDED, "synthesis")).stage("synthesis")
    folder = s / syn.artifact
    import shutil

    shutil.copytree(folder, tmp_path / "copy.shards")
    _flip(folder / "shard-0.npz")
    _flip(tmp_path / "copy.shards" / "shard-0.npz")
    code = main(["export", str(tmp_path / "copy.shards"), "--python", str(tmp_path / "l.py")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "copy.shards/shard-0.npz" in err[0], err
    assert "next run" not in err[0] and check_artifact(s, folder, syn.key) is None
    for args in (["export", str(folder), "--python", str(tmp_path / "l.py")],
                 ["verify", str(spec), "--law", str(folder)]):
        code = main(args)
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1, (args, err)
        assert "shard-0.npz: its SHA-256" in err[0] and "next run recomputes" in err[0]
        assert "shard-0.npz" in check_artifact(s, folder, syn.key)
        register_artifact(s, folder, "synthesis", syn.key)  # (unmarked, for the next)


# --------------------------------------------------------------------------------------------
# 2. a lost shard file, a truncated manifest
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("damage", ["lost shard", "truncated manifest"])
def test_a_lost_shard_or_a_truncated_manifest_is_named_and_recomputed(spec, tmp_path, capsys,
                                                                     damage):
    """``codev session`` lists the law corrupt naming the file; ``codev report`` refuses it
    in one line naming the artifact and what is wrong (exit 2, no traceback); ``codev
    replay`` recomputes it (one warning naming it) and matches; everything is cached after."""
    problem = load_spec(spec)
    s = tmp_path / "s"
    syn = Session.create(s).run(problem, SHARDED).stage("synthesis")
    folder = s / syn.artifact
    if damage == "lost shard":
        (folder / "shard-0.npz").unlink()
        named = "shard-0.npz is missing"
    else:
        manifest = folder / "shards.json"
        manifest.write_bytes(manifest.read_bytes()[:40])
        named = "shards.json does not match"
    assert main(["session", str(s)]) == 0  # (a listing: the state of each stage)
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "synthesis" in ln)
    assert "corrupt" in line and named in line
    code = main(["report", str(s), "--out", str(tmp_path / "r.html")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert str(folder) in err[0] and named in err[0] and "recomputes" in err[0]
    assert main(["replay", str(s), "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["match"]
    warned = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warned) == 1 and folder.name in warned[0] and named in warned[0]
    assert check_artifact(s, folder, syn.key) is None
    assert main(["session", str(s), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert {st["status"] for st in got["stages"]} == {"cached"}


# --------------------------------------------------------------------------------------------
# 3. temporaries: a live writer's kept, a dead writer's removed
# --------------------------------------------------------------------------------------------

#: a writer that holds a temporary file and a temporary folder open until killed
_WRITER = """
import signal, sys, time
from pathlib import Path
from codev_engine.io.atomic import atomic_folder, atomic_path
# Ctrl-C as a terminal gives it, whatever the test process's disposition: an ignored
# SIGINT is inherited and Python keeps it (CI: SIGINT ignored, the writer slept on for 30 s)
signal.signal(signal.SIGINT, signal.default_int_handler)
folder = Path(sys.argv[1])
with atomic_path(folder / "a.npz") as f, atomic_folder(folder / "b.shards") as d:
    f.write_bytes(b"half")
    (d / "shard-0.npz").write_bytes(b"half")
    print("writing", flush=True)
    time.sleep(60)
"""


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGINT])
def test_a_live_writers_temporaries_are_kept_a_killed_ones_removed(tmp_path, sig):
    """What a session run removes first (``store.remove_temporaries``: its folder,
    ``specs/``, ``artifacts/``) never includes what a live writer holds (its ``flock``),
    however old it looks; killed (SIGKILL, or SIGTERM: no unwinding) the writer leaves its
    temporaries, removed then (once past ``STALE_AFTER``: the lock is taken just after the
    entry is made); interrupted (SIGINT) it removes its own. A young unlocked entry is
    kept."""
    arts = tmp_path / "artifacts"
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(arts)], cwd=ROOT,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline() == "writing\n"
        tmps = sorted(p for p in arts.iterdir() if p.name.startswith(".tmp-"))
        assert sorted(p.suffix for p in tmps) == [".npz", ".shards"]
        _age(tmps)
        assert remove_temporaries(tmp_path) == [] and remove_stale(arts, older_than=0) == []
        assert all(p.exists() for p in tmps)
        proc.send_signal(sig)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    left = sorted(p.name for p in arts.iterdir())
    if sig == signal.SIGINT:
        assert left == []  # (removed by the writer's own unwinding)
        return
    assert left == sorted(p.name for p in tmps)
    _age(tmps, 0)
    assert remove_temporaries(tmp_path) == []  # (young: it may be a writer not yet locked)
    _age(tmps)
    assert sorted(remove_temporaries(tmp_path)) == sorted(f"artifacts/{p.name}" for p in tmps)
    assert list(arts.iterdir()) == []


def _kill_when(args: list[str], d: Path, sig: int, condition, deadline: float = 60.0
               ) -> tuple[int, list[str]]:
    """Start ``args`` (python's) in its own process group and send the group ``sig`` (as
    a terminal's Ctrl-C reaches a command and its cluster's processes) once
    ``condition(names)`` holds for the names in ``d/artifacts``. Returns (its exit status,
    the names at the signal)."""
    env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
    proc = subprocess.Popen([sys.executable, *args], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    names: list[str] = []
    t0 = time.monotonic()
    try:
        while proc.poll() is None and time.monotonic() - t0 < deadline:
            try:
                names = os.listdir(d / "artifacts")
            except FileNotFoundError:
                names = []
            if condition(names):
                os.killpg(proc.pid, sig)
                break
            time.sleep(0.0005)
        proc.wait(timeout=60)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # (what is left of the group: a cluster's)
        except ProcessLookupError:
            pass
        proc.wait()
    return proc.returncode, names


#: a sharded run of the session (no cluster: the stage writes one shard, in its folder)
_SHARDED_RUN = """
import sys
from codev_engine.pipeline import load_spec
from codev_engine.session import RunOptions, Session
Session.open_or_create(sys.argv[2]).run(load_spec(sys.argv[1]),
                                        RunOptions(sharded=True, traces=1))
"""


def _writing(suffix: str):
    return lambda names: any(n.startswith(".tmp-") and n.endswith(suffix) for n in names)


def _check_next_run(spec: Path, s: Path, options: RunOptions, label: str) -> None:
    """After a killed run: the index lists whole artifacts only; the next run (its
    temporaries aged past ``STALE_AFTER``) removes them, uses only what is whole, and
    gives the clean outcome; all is cached after."""
    arts = s / "artifacts"
    index = json.loads((arts / "index.json").read_text()) if (arts / "index.json").exists() \
        else {}
    for name, entry in index.items():
        assert not name.startswith(".tmp-"), label
        path = arts / name
        manifest = path / "shards.json" if entry.get("folder") else path
        assert entry["sha256"] == file_sha(manifest), (label, name)
    _age([p for p in arts.iterdir() if p.name.startswith(".tmp-")])
    problem = load_spec(spec)
    rep = Session.open(s).run(problem, options)
    assert not _leftovers(s), label
    assert rep.result.verdict == "robustly_safe", label  # (the clean run's, both specs)
    assert {st.status for st in Session.open(s).status(problem, options)} == {"cached"}


@pytest.mark.parametrize("sig", [signal.SIGKILL,
                                 pytest.param(signal.SIGINT, marks=pytest.mark.slow)])
def test_a_sharded_run_killed_writing_its_law_folder(spec, tmp_path, sig):
    """A real process storing the law as shards, killed while its ``.tmp-*.shards`` folder
    is being written: SIGKILL leaves it (never used, never indexed), the next run removes
    it and recomputes; SIGINT removes it itself."""
    s = tmp_path / "s"
    code, names = _kill_when(["-c", _SHARDED_RUN, str(spec), str(s)], s, sig,
                             _writing(".shards"))
    assert any(n.endswith(".shards") and n.startswith(".tmp-") for n in names), names
    assert code == -sig or (sig == signal.SIGINT and code == 1), code
    left = _leftovers(s)
    if sig == signal.SIGINT:
        assert left == [], left  # (KeyboardInterrupt: atomic_folder removed its folder)
    else:
        assert any(n.endswith(".shards") for n in left), left
    assert not list((s / "artifacts").glob("synthesis-*.shards"))
    _check_next_run(spec, s, SHARDED, f"sharded-{sig}")


@pytest.mark.slow  # (two runs of the double integrator, its recording drawn: ~4 s each)
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_codev_run_killed_writing_an_artifact(tmp_path, sig):
    """``codev run DI --session d`` killed while it writes its recording (its longest
    write): SIGKILL leaves the ``.tmp-*.rrd``, the next run removes it; Ctrl-C leaves
    nothing and exits 130."""
    spec = ROOT / "examples" / "double_integrator.toml"
    s = tmp_path / "s"
    code, names = _kill_when(["-m", "workbench.cli", "run", str(spec), "--session", str(s)],
                             s, sig, _writing(".rrd"))
    if not any(n.endswith(".rrd") and n.startswith(".tmp-") for n in names):
        pytest.skip(f"the recording's write was missed (exit {code})")  # pragma: no cover
    left = _leftovers(s)
    if sig == signal.SIGINT:
        assert code == 130 and left == [], (code, left)
    else:
        assert code == -sig and any(n.endswith(".rrd") for n in left), (code, left)
    _check_next_run(spec, s, RunOptions(), f"cli-{sig}")


@pytest.mark.slow  # (a LocalCluster of 2 workers started by each run: ~15 s at load 8)
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT])
def test_codev_run_sharded_on_a_cluster_killed_writing_the_law(spec, tmp_path, sig):
    """``codev run --session --workers 2 --sharded``, the search writing its files into the
    law's ``.tmp-*.shards`` folder (the first one seen there, a ``.tmp-*.npz`` being
    written), interrupted (Ctrl-C to the group: exit 130) or killed (SIGKILL to the group)
    meanwhile: no folder of shards is taken half-written,
    whatever a worker still wrote after the client left is removed by the next run, which
    recomputes the law (without a cluster: the same key)."""
    s = tmp_path / "s"
    inside: list[str] = []

    def workers_writing(names: list[str]) -> bool:
        # (the folder is made before the cluster starts: wait for the workers' files in it)
        for n in names:
            if n.startswith(".tmp-") and n.endswith(".shards"):
                try:
                    inside[:] = os.listdir(s / "artifacts" / n)
                except OSError:
                    continue
                if inside:
                    return True
        return False

    code, names = _kill_when(["-m", "workbench.cli", "run", str(spec), "--session", str(s),
                              "--workers", "2", "--sharded", "--traces", "1"], s, sig,
                             workers_writing, deadline=120)
    assert inside, names  # (killed while the workers' files were being written)
    assert code == (130 if sig == signal.SIGINT else -sig), code
    assert not list((s / "artifacts").glob("synthesis-*.shards"))
    _check_next_run(spec, s, SHARDED, f"cluster-{sig}")
