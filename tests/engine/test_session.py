"""Sessions (codev_engine.session): keys, the cache, the journal, replay, damaged files.

Everything runs the real engine on real files in ``tmp_path``; the design is the double
integrator (synthesis + verification in ~0.1 s, a recording in ~0.5 s). Most tests stop at
the verification stage (``RunOptions(upto="verification")``); the recording stage is
exercised where it matters (its key, its cache, a failing recording, a run killed while
writing it).

The contract under test is the docstrings of ``codev_engine/session/`` (session, store, keys):

* a stage's key hashes everything it depends on, so a change reruns exactly the stages
  downstream of it and nothing else;
* an artifact is used only if the index has it, its bytes hash to the indexed SHA-256 and
  its loader accepts it -- a truncated, edited, foreign or half-written file is reported
  (``warn``) and recomputed, never used, never a crash; nothing is unpickled;
* the journal records every stage run (run number, stage, status, outcome); ``replay``
  re-executes it without modifying it and reports outcome mismatches;
* bad input is a ``SessionError`` (a ``SpecError``: exit status 2) and leaves every file of
  the session as it was.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import codev_engine.session.keys as keys_mod
import codev_engine.session.store as store_mod
from codev_engine import load_spec, loads_spec
from codev_engine.errors import CodevError, SpecError
from codev_engine.io.atomic import write_text
from codev_engine.session import STAGES, RunOptions, Session, SessionError, stage_keys
from codev_engine.session.stages import TABLE, Stage, StageRun, StageTable
from codev_engine.spec.parse import parse_spec

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
DI_PATH = EXAMPLES / "double_integrator.toml"
BASE = DI_PATH.read_text(encoding="utf-8")

ALL = {"model", "synthesis", "verification", "recording"}
SYN = {"synthesis", "verification", "recording"}
VER = {"verification", "recording"}
UPTO_V = RunOptions(upto="verification")

#: Outcomes of the double integrator (clean run) per stage.
CLEAN = {
    "model": {"n": 2, "m": 1, "dt": 1.0},
    "synthesis": {"regions": 10},
    "verification": {"verdict": "robustly_safe", "reason": None},
}


def edit(old: str, new: str, text: str = BASE) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


#: Q changed: 12 regions (the outcome differs from BASE's 10).
Q2 = edit("Q = [[1.0, 1.0], [0.0, 1.0]]", "Q = [[2.0, 0.0], [0.0, 1.0]]")
HORIZON8 = edit("time_horizon = 9.0", "time_horizon = 8.0")
PLANT2 = edit('dynamics = ["x2", "u"]', 'dynamics = ["x2", "0.5*u"]')


def problem(text: str = BASE, name: str = "spec.toml"):
    return loads_spec(text, path=name)


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (hidden ones too) -> its bytes."""
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def statuses(report) -> dict[str, str]:
    return {s.stage: s.status for s in report.stages}


def outcomes(report) -> dict[str, dict]:
    return {s.stage: s.outcome for s in report.stages}


def status_map(session: Session, prob=None, options=None) -> dict[str, str]:
    return {s.stage: s.status for s in session.status(prob, options)}


def art(session: Session, report, stage: str) -> Path:
    return session.path / report.stage(stage).artifact


def read_index(session: Session) -> dict:
    return json.loads((session.path / "artifacts" / "index.json").read_text())


def rewrite_journal(session: Session, change) -> bytes:
    """Apply ``change(records)`` to the journal's records; returns the new bytes."""
    file = session.path / "journal.jsonl"
    recs = [json.loads(line) for line in file.read_text().splitlines() if line.strip()]
    change(recs)
    data = ("\n".join(json.dumps(r, sort_keys=True) for r in recs) + "\n").encode()
    file.write_bytes(data)
    return data


@pytest.fixture
def sess(tmp_path) -> Session:
    return Session.create(tmp_path / "s")


@pytest.fixture
def warned():
    msgs: list[str] = []
    return msgs


# --------------------------------------------------------------------------------------------
# 1. keys
# --------------------------------------------------------------------------------------------


def _reformatted(text: str) -> str:
    """The same TOML, with other whitespace and other comments (no value changes)."""
    out = ["# a comment added at the top", ""]
    for line in text.splitlines():
        code = line.split("#", 1)[0].rstrip() if not line.lstrip().startswith("#") else ""
        if not code:
            out.append("   # " + line.strip().lstrip("#").strip())
            continue
        code = code.replace(" = ", "   =  ").replace(", ", ",   ")
        out.append("  " + code + "\t# changed comment")
        out.append("")
    return "\n".join(out) + "\n\n"


KEY_CASES = [
    # (id, spec text, options, stages whose key must change)
    ("plant-dynamics", PLANT2, None, ALL),
    ("model-sample_time", edit("sample_time = 1.0", "sample_time = 0.5"), None, ALL),
    ("mpc-Q", Q2, None, SYN),
    ("mpc-R", edit("R = [[0.8]]", "R = [[0.5]]"), None, SYN),
    ("mpc-horizon", edit("horizon = 2", "horizon = 3"), None, SYN),
    ("verify-time_horizon", HORIZON8, None, VER),
    ("verify-initial_set", edit("lower = [8.99, -5.01]", "lower = [8.98, -5.01]"), None, VER),
    ("verify-safe", edit("upper = [10.0, 10.0]", "upper = [10.0, 11.0]"), None, VER),
    ("verify-hold", edit('hold = "continuous"', 'hold = "zoh"'), None, VER),
    ("verify-max_depth", edit("max_depth = 6", "max_depth = 4"), None, VER),
    ("options-hold", BASE, RunOptions(hold="zoh"), VER),
    ("options-max_depth", BASE, RunOptions(max_depth=3), VER),
    ("options-axes", BASE, RunOptions(axes=(1, 0)), {"recording"}),
    ("options-traces", BASE, RunOptions(traces=3), {"recording"}),
    # the effective verification inputs: an override equal to the spec changes nothing
    ("options-hold-same", BASE, RunOptions(hold="continuous"), set()),
    ("options-max_depth-same", BASE, RunOptions(max_depth=6), set()),
    ("options-upto", BASE, RunOptions(upto="verification"), set()),
    ("whitespace-comments", _reformatted(BASE), None, set()),
    (
        "number-spelling",
        edit(
            "time_horizon = 9.0", "time_horizon = 9", edit("sample_time = 1.0", "sample_time = 1e0")
        ),
        None,
        set(),
    ),
]


def test_keys_are_deterministic_hex_and_distinct():
    p = problem()
    k1, k2 = stage_keys(p), stage_keys(problem())
    assert k1 == k2
    assert set(k1) == ALL
    for k in k1.values():
        assert len(k) == 64 and all(c in "0123456789abcdef" for c in k)
    assert len(set(k1.values())) == 4
    # the spec's file name is not an input
    assert stage_keys(problem(name="elsewhere/other.toml")) == k1
    assert stage_keys(load_spec(DI_PATH)) == k1


@pytest.mark.parametrize(
    ("text", "options", "changed"),
    [c[1:] for c in KEY_CASES],
    ids=[c[0] for c in KEY_CASES],
)
def test_keys_change_exactly_downstream(text, options, changed):
    base = stage_keys(problem(), RunOptions())
    other = stage_keys(problem(text), options or RunOptions())
    got = {s for s in ALL if base[s] != other[s]}
    assert got == changed


def test_keys_depend_on_the_engine_version(monkeypatch):
    base = stage_keys(problem())
    monkeypatch.setattr(keys_mod, "__version__", "0.0.0-other")
    other = stage_keys(problem())
    assert all(base[s] != other[s] for s in ALL)


def test_keys_without_verify_section():
    text = BASE.split("[verify]")[0]
    keys = stage_keys(problem(text))
    assert set(keys) == {"model", "synthesis", "recording"}
    base = stage_keys(problem())
    assert keys["model"] == base["model"] and keys["synthesis"] == base["synthesis"]
    assert keys["recording"] != base["recording"]


# --------------------------------------------------------------------------------------------
# 2. running and caching
# --------------------------------------------------------------------------------------------


def test_first_run_computes_then_everything_is_cached(sess):
    r1 = sess.run(problem(), UPTO_V)
    assert r1.run == 1
    assert statuses(r1) == {s: "computed" for s in ("model", "synthesis", "verification")}
    assert outcomes(r1) == CLEAN
    assert r1.law.num_regions == 10 and r1.result.verdict == "robustly_safe"
    r2 = sess.run(problem(), UPTO_V)
    assert r2.run == 2
    assert statuses(r2) == {s: "cached" for s in ("model", "synthesis", "verification")}
    assert outcomes(r2) == CLEAN
    assert r2.law.num_regions == 10 and r2.result.verdict == "robustly_safe"
    assert np.array_equal(r2.model.A, r1.model.A)
    assert r2.result.tube.num_boxes == r1.result.tube.num_boxes
    # spec.toml and the snapshot
    sha = store_mod.sha(BASE.encode())
    assert (sess.path / "spec.toml").read_text() == BASE
    assert (sess.path / "specs" / f"{sha[:16]}.toml").read_text() == BASE
    assert sorted(p.name for p in (sess.path / "specs").iterdir()) == [f"{sha[:16]}.toml"]
    # the journal: one record per stage per run, in order
    j = sess.journal()
    assert [(r["run"], r["stage"], r["status"]) for r in j] == [
        (1, "model", "computed"),
        (1, "synthesis", "computed"),
        (1, "verification", "computed"),
        (2, "model", "cached"),
        (2, "synthesis", "cached"),
        (2, "verification", "cached"),
    ]
    keys = stage_keys(problem(), UPTO_V)
    for rec in j:
        assert rec["key"] == keys[rec["stage"]]
        assert rec["spec"] == sha
        assert rec["outcome"] == CLEAN[rec["stage"]]
        assert rec["engine"] == keys_mod.__version__
        assert rec["options"]["upto"] == "verification"
        assert (sess.path / rec["artifact"]).is_file()
    # no temporary file is left behind
    assert not [p for p in sess.path.rglob(".tmp-*")]


@pytest.mark.parametrize(
    ("text", "options", "want"),
    [
        (HORIZON8, UPTO_V, ("cached", "cached", "computed")),
        (
            edit("upper = [9.01, -4.99]", "upper = [9.02, -4.99]"),
            UPTO_V,
            ("cached", "cached", "computed"),
        ),
        (BASE, RunOptions(upto="verification", hold="zoh"), ("cached", "cached", "computed")),
        (BASE, RunOptions(upto="verification", max_depth=2), ("cached", "cached", "computed")),
        (Q2, UPTO_V, ("cached", "computed", "computed")),
        (PLANT2, UPTO_V, ("computed", "computed", "computed")),
        (_reformatted(BASE), UPTO_V, ("cached", "cached", "cached")),
    ],
    ids=["time_horizon", "initial_set", "hold", "max_depth", "Q", "plant", "whitespace"],
)
def test_a_change_reruns_only_the_stages_downstream(sess, text, options, want):
    sess.run(problem(), UPTO_V)
    rep = sess.run(problem(text), options)
    assert tuple(s.status for s in rep.stages) == want
    assert [s.stage for s in rep.stages] == ["model", "synthesis", "verification"]
    # the new spec is the session's spec and has its own snapshot; the old one is kept
    assert (sess.path / "spec.toml").read_text() == text
    for t in {BASE, text}:
        assert (sess.path / "specs" / f"{store_mod.sha(t.encode())[:16]}.toml").read_text() == t
    # and now it is cached too, the old one as well
    assert {s.status for s in sess.run(problem(text), options).stages} == {"cached"}
    assert {s.status for s in sess.run(problem(), UPTO_V).stages} == {"cached"}


def test_fresh_recomputes_every_stage(sess, warned):
    sess.run(problem(), UPTO_V)
    rep = sess.run(problem(), UPTO_V, fresh=True, warn=warned.append)
    assert {s.status for s in rep.stages} == {"computed"}
    assert outcomes(rep) == CLEAN
    assert warned == []
    assert [r["status"] for r in sess.journal() if r["run"] == 2] == ["computed"] * 3


def test_recording_stage_cached_and_keyed_by_options(sess):
    rep = sess.run(problem(), RunOptions(traces=2))
    assert statuses(rep) == {s: "computed" for s in ALL}
    assert rep.recording is not None and rep.recording.is_file()
    assert rep.recording.suffix == ".rrd"
    assert rep.stage("recording").outcome == {"boxes": rep.result.tube.num_boxes}
    rep2 = sess.run(problem(), RunOptions(traces=2))
    assert statuses(rep2) == {s: "cached" for s in ALL}
    assert rep2.recording == rep.recording
    # options that only the recording depends on rerun the recording only
    rep3 = sess.run(problem(), RunOptions(traces=1))
    assert statuses(rep3) == {**{s: "cached" for s in ALL}, "recording": "computed"}
    assert rep3.recording != rep.recording
    assert status_map(sess, problem(), RunOptions(traces=2)) == {s: "cached" for s in ALL}


def test_events_are_emitted_per_stage(sess):
    events: list[tuple[str, str]] = []
    sess.run(problem(), UPTO_V, on_event=lambda st, ev, data: events.append((st, ev)))
    for stage in ("model", "synthesis", "verification"):
        assert (stage, "start") in events and (stage, "done") in events
        assert events.index((stage, "start")) < events.index((stage, "done"))


def test_run_options_are_validated_before_anything_is_written(sess):
    sess.run(problem(), UPTO_V)
    before = snapshot(sess.path)
    for bad in (
        RunOptions(upto="everything"),
        RunOptions(hold="sometimes"),
        RunOptions(max_depth=-1),
        RunOptions(axes=(0, 0)),
        RunOptions(axes=(0, 5)),
        RunOptions(traces=-1),
    ):
        with pytest.raises(SessionError):
            sess.run(problem(Q2), bad)
    assert snapshot(sess.path) == before


#: u >= 5 takes x2 out of [-1, 1] in one step: the MPC is infeasible for every state.
INFEASIBLE = edit(
    "u_max = [1.0]",
    "u_max = [6.0]",
    edit(
        "u_min = [-1.0]",
        "u_min = [5.0]",
        edit(
            "x_max = [10.0, 10.0]",
            "x_max = [1.0, 1.0]",
            edit("x_min = [-10.0, -10.0]", "x_min = [-1.0, -1.0]"),
        ),
    ),
)
#: f is not finite at the operating point x = 0: the plant cannot be linearised there.
SINGULAR = edit('dynamics = ["x2", "u"]', 'dynamics = ["x2", "u + 1/x1"]')


@pytest.mark.parametrize("options", [UPTO_V, RunOptions(upto="model")], ids=["verify", "model"])
def test_stage_checks_fail_before_anything_is_written(sess, options):
    sess.run(problem(), UPTO_V)
    before = snapshot(sess.path)
    # parsed only (the pipeline's checks not run): the session runs the stages' checks
    with pytest.raises(SpecError, match="cannot be linearised") as exc:
        sess.run(parse_spec(SINGULAR, path="singular.toml"), options)
    assert (exc.value.file, exc.value.field) == ("singular.toml", "model.operating_point")
    # the model is cached (same plant) but the law is not: its check runs, even for a run
    # that stops at the model, since the spec would become the session's spec.toml
    with pytest.raises(SpecError, match="infeasible for every initial state") as exc:
        sess.run(parse_spec(INFEASIBLE, path="infeasible.toml"), options)
    assert (exc.value.file, exc.value.field) == ("infeasible.toml", "mpc")
    assert snapshot(sess.path) == before


def test_a_stage_check_runs_only_when_its_artifact_is_not_cached(tmp_path):
    calls: list[str] = []

    def counted(stage: Stage) -> Stage:
        def check(prob):
            calls.append(stage.name)
            stage.check(prob)  # the pipeline's own check

        return replace(stage, check=check)

    class Counting(Session):
        table = StageTable(tuple(counted(st) if st.check else st for st in TABLE))

    sess = Counting.create(tmp_path / "s")
    rep = sess.run(problem(), UPTO_V)
    assert calls == ["model", "synthesis"]
    calls.clear()
    sess.run(problem(), UPTO_V)
    assert calls == []  # a cached artifact proves its stage's check
    sess.run(problem(), UPTO_V, fresh=True)
    assert calls == ["model", "synthesis"]
    calls.clear()
    art(sess, rep, "synthesis").unlink()
    sess.run(problem(), RunOptions(upto="model"))
    assert calls == ["synthesis"]


# --------------------------------------------------------------------------------------------
# 3. damaged artifacts: reported, recomputed, never used
# --------------------------------------------------------------------------------------------


def _truncate(s, p):
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])


def _flip(s, p):
    b = bytearray(p.read_bytes())
    b[len(b) // 2] ^= 0xFF
    p.write_bytes(bytes(b))


def _empty(s, p):
    p.write_bytes(b"")


def _other_stage(s, p):
    shutil.copyfile(next((s.path / "artifacts").glob("model-*.npz")), p)


def _unindexed(s, p):
    idx = read_index(s)
    del idx[p.name]
    (s.path / "artifacts" / "index.json").write_text(json.dumps(idx))


CORRUPT_ONE = {
    "truncated": _truncate,
    "flipped-byte": _flip,
    "emptied": _empty,
    "other-stage-file": _other_stage,
    "not-in-index": _unindexed,
}


@pytest.mark.parametrize("damage", list(CORRUPT_ONE), ids=list(CORRUPT_ONE))
def test_damaged_artifact_is_reported_and_recomputed(sess, warned, damage):
    r1 = sess.run(problem(), UPTO_V)
    target = art(sess, r1, "synthesis")
    CORRUPT_ONE[damage](sess, target)
    st = {s.stage: s for s in sess.status()}
    assert st["synthesis"].status == "corrupt" and st["synthesis"].reason
    assert st["model"].status == "cached" and st["verification"].status == "cached"
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert statuses(rep) == {"model": "cached", "synthesis": "computed", "verification": "cached"}
    assert len(warned) == 1 and target.name in warned[0]
    assert rep.stage("synthesis").note and target.name in rep.stage("synthesis").note
    assert outcomes(rep) == CLEAN
    assert rep.law.num_regions == 10
    # repaired: indexed again, and the next run uses it
    assert read_index(sess)[target.name]["sha256"] == store_mod.file_sha(target)
    assert status_map(sess)["synthesis"] == "cached"
    warned.clear()
    assert {s.status for s in sess.run(problem(), UPTO_V, warn=warned.append).stages} == {"cached"}
    assert warned == []
    note = [r for r in sess.journal() if r["run"] == 2 and r["stage"] == "synthesis"][0]
    assert note["status"] == "computed" and "note" in note


@pytest.mark.parametrize(
    "damage",
    ["deleted", "garbage", "json-list", "truncated-json", "binary"],
)
def test_damaged_index_costs_recomputation_only(sess, warned, damage):
    sess.run(problem(), UPTO_V)
    index = sess.path / "artifacts" / "index.json"
    if damage == "deleted":
        index.unlink()
    elif damage == "garbage":
        index.write_text("this is not json {")
    elif damage == "json-list":
        index.write_text("[1, 2, 3]")
    elif damage == "truncated-json":
        index.write_text(index.read_text()[:40])
    else:
        index.write_bytes(b"\xff\xfe\x00\x80" * 16)
    assert {s.status for s in sess.status()[:3]} == {"corrupt"}
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert {s.status for s in rep.stages} == {"computed"}
    assert len(warned) == 3
    assert outcomes(rep) == CLEAN
    assert set(read_index(sess)) >= {s.artifact.split("/")[-1] for s in rep.stages}
    assert {s.status for s in sess.run(problem(), UPTO_V).stages} == {"cached"}


def test_indexed_file_of_the_wrong_kind_is_refused_by_its_loader(sess, warned):
    """Even with a matching SHA-256 in the index, the loader must accept the file."""
    r1 = sess.run(problem(), UPTO_V)
    target = art(sess, r1, "verification")
    shutil.copyfile(art(sess, r1, "synthesis"), target)
    idx = read_index(sess)
    idx[target.name]["sha256"] = store_mod.file_sha(target)
    idx[target.name]["bytes"] = target.stat().st_size
    (sess.path / "artifacts" / "index.json").write_text(json.dumps(idx))
    assert status_map(sess)["verification"] == "corrupt"
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert statuses(rep)["verification"] == "computed"
    assert len(warned) == 1 and target.name in warned[0]
    assert outcomes(rep) == CLEAN


class _Trap:
    """Unpickling this object would create the file ``marker``."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


def test_pickled_artifact_is_never_unpickled(sess, warned, tmp_path):
    r1 = sess.run(problem(), UPTO_V)
    marker = tmp_path / "UNPICKLED"
    target = art(sess, r1, "model")
    with target.open("wb") as fh:
        np.savez(fh, format=np.array([_Trap(str(marker))], dtype=object), A=np.eye(2))
    idx = read_index(sess)
    idx[target.name]["sha256"] = store_mod.file_sha(target)
    (sess.path / "artifacts" / "index.json").write_text(json.dumps(idx))
    assert status_map(sess)["model"] == "corrupt"
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert not marker.exists()
    assert statuses(rep)["model"] == "computed"
    assert outcomes(rep) == CLEAN
    assert len(warned) == 1


def test_valid_looking_file_not_in_the_index_is_not_used(sess, warned):
    """A complete, loadable artifact that the index does not list (a write interrupted
    between the rename and the index update, or a file copied in) is recomputed."""
    other = Session.create(sess.path.parent / "other")
    r_other = other.run(problem(edit("sample_time = 1.0", "sample_time = 0.5")), UPTO_V)
    keys = stage_keys(problem(), UPTO_V)
    target = sess.artifact_path("model", keys["model"])
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(art(other, r_other, "model"), target)  # dt = 0.5, not 1.0
    assert status_map(sess, problem(), UPTO_V)["model"] == "corrupt"
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert statuses(rep)["model"] == "computed"
    assert rep.model.dt == 1.0 and outcomes(rep) == CLEAN
    assert len(warned) == 1 and "index" in warned[0]


def test_leftover_temporary_files_are_ignored(sess, warned):
    r1 = sess.run(problem(), UPTO_V)
    arts = sess.path / "artifacts"
    shutil.copyfile(art(sess, r1, "synthesis"), arts / ".tmp-0123456789ab.npz")
    (arts / ".tmp-deadbeef0000.json").write_text("{")
    rep = sess.run(problem(), UPTO_V, warn=warned.append)
    assert {s.status for s in rep.stages} == {"cached"} and warned == []


def test_damaged_recording_is_recomputed(sess, warned):
    opts = RunOptions(traces=1)
    r1 = sess.run(problem(), opts)
    rrd = r1.recording
    rrd.write_bytes(rrd.read_bytes()[: rrd.stat().st_size - 100])
    assert status_map(sess, problem(), opts)["recording"] == "corrupt"
    rep = sess.run(problem(), opts, warn=warned.append)
    assert statuses(rep) == {**{s: "cached" for s in ALL}, "recording": "computed"}
    assert len(warned) == 1 and rrd.name in warned[0]
    from codev_engine.view.records import check_recording

    check_recording(rep.recording)


# --------------------------------------------------------------------------------------------
# status
# --------------------------------------------------------------------------------------------


def test_status_missing_cached_stale(sess):
    with pytest.raises(SessionError):
        sess.status()  # no spec.toml yet
    assert status_map(sess, problem(), UPTO_V) == {s: "missing" for s in ALL}
    sess.run(problem(), UPTO_V)
    assert status_map(sess) == {
        "model": "cached",
        "synthesis": "cached",
        "verification": "cached",
        "recording": "missing",
    }
    st = {s.stage: s for s in sess.status(problem(HORIZON8))}
    assert st["model"].status == "cached" and st["synthesis"].status == "cached"
    assert st["verification"].status == "stale" and st["verification"].reason
    assert st["recording"].status == "missing"
    st = {s.stage: s.status for s in sess.status(problem(Q2))}
    assert st["synthesis"] == "stale" and st["verification"] == "stale"
    assert st["model"] == "cached"


def test_status_deleted_artifact_is_missing(sess):
    """StageStatus docstring: "missing" = never computed, *or the artifact is gone*;
    "stale" = computed before but its inputs changed since. Deleting the artifact of an
    unchanged stage is therefore "missing", not "stale"."""
    r1 = sess.run(problem(), UPTO_V)
    art(sess, r1, "synthesis").unlink()
    st = {s.stage: s for s in sess.status()}
    assert st["synthesis"].status == "missing", st["synthesis"]
    rep = sess.run(problem(), UPTO_V)
    assert statuses(rep)["synthesis"] == "computed" and outcomes(rep) == CLEAN


# --------------------------------------------------------------------------------------------
# 4. replay
# --------------------------------------------------------------------------------------------


def test_replay_matches_and_changes_nothing(sess):
    sess.run(problem(), UPTO_V)
    sess.run(problem(Q2), UPTO_V)
    sess.run(problem(), RunOptions(upto="synthesis"))
    before = snapshot(sess.path)
    rep = sess.replay()
    assert rep.ok and rep.mismatches == []
    assert rep.runs == 3 and rep.checked == 8 and rep.cached == 8
    assert snapshot(sess.path) == before


def test_replay_reports_an_edited_outcome_and_keeps_the_journal(sess):
    sess.run(problem(), UPTO_V)
    sess.run(problem(Q2), UPTO_V)

    def change(recs):
        for r in recs:
            if r["run"] == 2 and r["stage"] == "synthesis":
                r["outcome"]["regions"] = 999

    edited = rewrite_journal(sess, change)
    runs_seen: list[tuple[int, int]] = []
    rep = sess.replay(on_run=lambda n, r, mm: runs_seen.append((n, len(mm))))
    assert not rep.ok
    assert rep.mismatches == [(2, "synthesis", {"regions": 999}, {"regions": 12})]
    assert runs_seen == [(1, 0), (2, 1)]
    assert (sess.path / "journal.jsonl").read_bytes() == edited


def test_replay_recomputes_deleted_artifacts(sess, warned):
    sess.run(problem(), UPTO_V)
    sess.run(problem(Q2), UPTO_V)
    journal = (sess.path / "journal.jsonl").read_bytes()
    shutil.rmtree(sess.path / "artifacts")
    rep = sess.replay(warn=warned.append)
    # run 2 (Q changed) shares run 1's model, recomputed by the replay of run 1
    assert rep.ok and rep.cached == 1 and rep.checked == 6
    assert warned == []
    assert (sess.path / "journal.jsonl").read_bytes() == journal
    assert {s.status for s in sess.status(problem(), UPTO_V)[:3]} == {"cached"}
    # corrupt artifacts: warned and recomputed during replay, still matching
    for p in (sess.path / "artifacts").glob("synthesis-*.npz"):
        _flip(sess, p)
    rep = sess.replay(warn=warned.append)
    assert rep.ok and len(warned) == 2
    assert (sess.path / "journal.jsonl").read_bytes() == journal


def test_replay_refuses_a_journal_from_another_engine(sess):
    sess.run(problem(), UPTO_V)

    def change(recs):
        recs[1]["engine"] = "0.0.1"

    rewrite_journal(sess, change)
    before = snapshot(sess.path)
    with pytest.raises(SessionError, match="0.0.1"):
        sess.replay()
    assert snapshot(sess.path) == before


def test_replay_refuses_an_edited_or_missing_spec_snapshot(sess):
    sess.run(problem(), UPTO_V)
    snap = next((sess.path / "specs").iterdir())
    snap.write_text(snap.read_text().replace("time_horizon = 9.0", "time_horizon = 3.0"))
    before = snapshot(sess.path)
    with pytest.raises(SessionError, match="edited"):
        sess.replay()
    assert snapshot(sess.path) == before
    snap.unlink()
    with pytest.raises(SessionError, match="missing"):
        sess.replay()


def test_replay_of_an_empty_journal_is_an_error(sess):
    with pytest.raises(SessionError, match="empty"):
        sess.replay()


BAD_LINES = {
    "not-json": "{not json",
    "json-list": "[1, 2]",
    "missing-field": json.dumps({"run": 1, "stage": "model"}),
    "wrong-type": None,  # filled from a real record below
    "unknown-stage": None,
    "unknown-status": None,
    "spec-not-a-hash": None,
    "bad-options": None,
}


@pytest.mark.parametrize("case", list(BAD_LINES))
def test_malformed_journal_line_is_a_session_error(sess, case):
    sess.run(problem(), UPTO_V)
    file = sess.path / "journal.jsonl"
    good = json.loads(file.read_text().splitlines()[0])
    line = BAD_LINES[case]
    if line is None:
        rec = dict(good)
        if case == "wrong-type":
            rec["run"] = "1"
        elif case == "unknown-stage":
            rec["stage"] = "deploy"
        elif case == "unknown-status":
            rec["status"] = "maybe"
        elif case == "spec-not-a-hash":
            rec["spec"] = "../../etc/passwd"
        else:
            rec["run"] = 2  # a run of its own: its options are the run's options
            rec["options"] = {"axes": "xy", "traces": -3}
        line = json.dumps(rec)
    with file.open("a") as fh:
        fh.write(line + "\n")
    before = snapshot(sess.path)
    if case == "bad-options":  # a well-formed record: the options are checked on use
        with pytest.raises(SessionError):
            sess.replay()
    else:
        with pytest.raises(SessionError):
            sess.journal()
        with pytest.raises(SessionError):
            sess.replay()
    assert snapshot(sess.path) == before


def test_run_with_a_malformed_journal_changes_nothing(sess):
    """A run that fails because the journal is malformed (bad input, exit 2) must leave
    the session as it was -- spec.toml and specs/ included."""
    sess.run(problem(), UPTO_V)
    with (sess.path / "journal.jsonl").open("a") as fh:
        fh.write("{not json\n")
    before = snapshot(sess.path)
    with pytest.raises(SessionError):
        sess.run(problem(Q2), UPTO_V)
    assert snapshot(sess.path) == before


# --------------------------------------------------------------------------------------------
# opening and creating
# --------------------------------------------------------------------------------------------


def test_open_and_create_bad_folders(tmp_path):
    with pytest.raises(SessionError, match="no such"):
        Session.open(tmp_path / "nope")
    (tmp_path / "file").write_text("x")
    with pytest.raises(SessionError):
        Session.open(tmp_path / "file")
    with pytest.raises(SessionError):
        Session.open_or_create(tmp_path / "file")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(SessionError, match="not a codev session"):
        Session.open(foreign)
    with pytest.raises(SessionError, match="not empty"):
        Session.open_or_create(foreign)
    assert snapshot(foreign) == {"notes.txt": b"mine"}
    for meta in ('{"format": "codev-session/99"}', "[]", "{}", "not json", '{"format": 3}'):
        s = tmp_path / f"s{abs(hash(meta))}"
        s.mkdir()
        (s / "session.json").write_text(meta)
        with pytest.raises(SessionError):
            Session.open(s)
        with pytest.raises(SessionError):
            Session.open_or_create(s)
        assert snapshot(s) == {"session.json": meta.encode()}
    assert issubclass(SessionError, SpecError)


def test_create_in_empty_folder_and_reopen(tmp_path):
    (tmp_path / "empty").mkdir()
    s = Session.create(tmp_path / "empty")
    assert json.loads((s.path / "session.json").read_text())["format"] == "codev-session/1"
    again = Session.open_or_create(tmp_path / "empty")
    assert again.meta == s.meta


def test_a_create_interrupted_before_session_json_does_not_lock_the_folder(tmp_path):
    """``Session.create`` makes ``artifacts/`` and then writes ``session.json``; a run
    killed in between leaves a folder holding only an empty ``artifacts/``. That folder
    holds nothing of the user's and must still be usable as a new session."""
    d = tmp_path / "s"
    (d / "artifacts").mkdir(parents=True)
    s = Session.open_or_create(d)
    assert s.run(problem(), UPTO_V).stage("verification").outcome == CLEAN["verification"]


# --------------------------------------------------------------------------------------------
# 5. a failing stage
# --------------------------------------------------------------------------------------------


def test_failing_stage_is_journaled_as_failed(sess, monkeypatch):
    monkeypatch.setenv("RERUN", "off")  # the recording stage fails (CodevError)
    with pytest.raises(CodevError, match="RERUN"):
        sess.run(problem(), RunOptions(traces=0))
    j = sess.journal()
    assert [(r["run"], r["stage"], r["status"]) for r in j] == [
        (1, "model", "computed"),
        (1, "synthesis", "computed"),
        (1, "verification", "computed"),
        (1, "recording", "failed"),
    ]
    assert j[-1]["outcome"]["error"] == "CodevError" and "RERUN" in j[-1]["outcome"]["message"]
    assert not list(sess.path.rglob(".tmp-*"))
    assert status_map(sess)["recording"] != "cached"
    # replay in the same environment fails the same way: a match
    rep = sess.replay()
    assert rep.ok and rep.checked == 4  # three stages cached, recording fails again
    # once rerun is enabled, the run goes through; the replay of run 1 now differs
    monkeypatch.delenv("RERUN")
    rep2 = sess.run(problem(), RunOptions(traces=0))
    assert rep2.run == 2
    assert statuses(rep2) == {**{s: "cached" for s in ALL}, "recording": "computed"}
    replay = sess.replay()
    assert [(m[0], m[1]) for m in replay.mismatches] == [(1, "recording")]


def test_replay_of_a_stage_that_now_fails_is_a_mismatch(sess, monkeypatch):
    sess.run(problem(), RunOptions(traces=0))
    shutil.rmtree(sess.path / "artifacts")
    monkeypatch.setenv("RERUN", "off")  # the recording stage cannot be recomputed now
    rep = sess.replay()
    assert [(m[0], m[1]) for m in rep.mismatches] == [(1, "recording")]
    assert rep.mismatches[0][3]["error"] == "CodevError"


# --------------------------------------------------------------------------------------------
# 6. a run killed while writing
# --------------------------------------------------------------------------------------------


def _kill_when(d: Path, condition, deadline: float = 30.0) -> tuple[bool, list[str]]:
    """Start ``codev run DI --session d`` and SIGKILL it when ``condition(names)`` holds for
    the names in ``d/artifacts``. Returns (killed before it finished, names at the kill)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "workbench.cli", "run", str(DI_PATH), "--session", str(d)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    t0 = time.monotonic()
    names: list[str] = []
    try:
        while proc.poll() is None and time.monotonic() - t0 < deadline:
            try:
                names = os.listdir(d / "artifacts")
            except FileNotFoundError:
                names = []
            if condition(names):
                os.kill(proc.pid, signal.SIGKILL)
                break
            time.sleep(0.0005)
    finally:
        if proc.poll() is None:
            proc.kill()
        rc = proc.wait()
    return rc == -signal.SIGKILL, names


KILL_POINTS = {
    # while the recording (the longest write) is being written
    "recording-tmp": lambda names: any(n.startswith(".tmp-") and n.endswith(".rrd") for n in names),
    # as soon as the verification artifact is renamed into place (maybe not yet indexed)
    "verification-renamed": lambda names: any(n.startswith("verification-") for n in names),
    # the very first temporary file (the model being written)
    "first-tmp": lambda names: any(n.startswith(".tmp-") for n in names),
}


def _check_after_kill(d: Path, label: str) -> None:
    """After a killed run: the index lists complete files only, and the next run uses
    nothing else, reports every unusable file it finds, and gives the clean outcome."""
    arts = d / "artifacts"
    try:
        index = json.loads((arts / "index.json").read_text())
    except FileNotFoundError:
        index = {}
    valid = set()
    for name, entry in index.items():
        assert not name.startswith(".tmp-"), label
        f = arts / name
        assert f.is_file(), (label, name)
        assert entry["sha256"] == store_mod.file_sha(f), (label, name)
        assert entry["bytes"] == f.stat().st_size
        valid.add(name)
    present = {p.name for p in arts.iterdir() if not p.name.startswith(".tmp-")}
    warned: list[str] = []
    rep = Session.open(d).run(load_spec(DI_PATH), RunOptions(), warn=warned.append)
    for st in rep.stages:
        name = Path(st.artifact).name
        assert st.status in ("cached", "computed"), (label, st)
        if st.status == "cached":
            assert name in valid, (label, st.stage)
        elif name in present:  # on disk but unusable: reported
            assert any(name in w for w in warned), (label, name, warned)
    assert {k: v for k, v in outcomes(rep).items() if k != "recording"} == CLEAN, label
    assert rep.stage("recording").outcome == {"boxes": rep.result.tube.num_boxes}
    assert {s.status for s in Session.open(d).status()} == {"cached"}, label
    assert Session.open(d).replay().ok, label


def test_run_killed_mid_write_leaves_nothing_that_is_used(tmp_path):
    mid_write = 0
    points = [*KILL_POINTS, "recording-tmp", "recording-tmp"]  # retries if the window is missed
    for i, label in enumerate(points):
        if i >= len(KILL_POINTS) and mid_write:
            break
        d = tmp_path / f"{i}-{label}"
        killed, _ = _kill_when(d, KILL_POINTS[label])
        if not (d / "session.json").exists():
            continue  # killed before the session existed: nothing to check
        mid_write += bool(killed and list((d / "artifacts").glob(".tmp-*")))
        _check_after_kill(d, label)
    assert mid_write >= 1, "no kill happened while a file was being written"


# --------------------------------------------------------------------------------------------
# 7. journal appends
# --------------------------------------------------------------------------------------------


def test_sequential_sessions_keep_every_record(sess):
    a, b = sess, Session.open(sess.path)
    a.run(problem(), UPTO_V)
    b.run(problem(Q2), UPTO_V)
    a.run(problem(HORIZON8), UPTO_V)
    j = Session.open(sess.path).journal()
    assert [r["run"] for r in j] == [1] * 3 + [2] * 3 + [3] * 3
    assert Session.open(sess.path).replay().ok


def test_interleaved_runs_get_distinct_run_numbers(sess):
    """Two runs in flight on one session (two processes, or the workbench and the CLI):
    each must get its own run number, else replay merges them and compares one run's
    outcomes with the other's spec. Simulated deterministically: a second run starts and
    finishes while the first is at its first stage."""
    started = []

    def on_event(stage, event, data):
        if event == "start" and not started:
            started.append(stage)
            Session.open(sess.path).run(problem(Q2), UPTO_V)

    sess.run(problem(), UPTO_V, on_event=on_event)
    j = sess.journal()
    assert len(j) == 6
    runs = {(r["run"], r["spec"]) for r in j}
    assert len(runs) == 2 and len({r for r, _ in runs}) == 2, runs
    assert sess.replay().ok


# --------------------------------------------------------------------------------------------
# 8. the stage table
# --------------------------------------------------------------------------------------------


def test_every_stage_has_exactly_one_table_entry():
    names = [st.name for st in TABLE]
    assert names == list(STAGES) == ["model", "synthesis", "verification", "recording"]
    assert all(names.count(n) == 1 and TABLE[n].name == n for n in STAGES)
    assert [st.ext for st in TABLE] == ["npz", "npz", "npz", "rrd"]
    with pytest.raises(ValueError, match="unique: model repeated"):
        StageTable((*TABLE.stages, TABLE["model"]))
    with pytest.raises(KeyError):
        TABLE["digest"]


def _digest_compute(run: StageRun) -> dict:
    write_text(run.path, json.dumps({"regions": run.upstream["synthesis"].num_regions}))
    return _digest_load(run.path, run.problem)


def _digest_load(path: Path, problem) -> dict:
    data = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(data, dict) or not isinstance(data.get("regions"), int):
        raise SpecError("not a digest", file=str(path))
    return data


#: A stage that is not codev's: one entry, between synthesis and verification.
DIGEST = Stage(
    name="digest",
    ext="json",
    report_field=None,
    inputs=lambda prob, options, keys: {"synthesis": keys["synthesis"]},
    compute=_digest_compute,
    load=_digest_load,
    describe=lambda value, upstream: ({"regions": value["regions"]}, {"n": upstream["model"].n}),
)
WITH_DIGEST = StageTable(
    (TABLE["model"], TABLE["synthesis"], DIGEST, TABLE["verification"], TABLE["recording"])
)


class DigestSession(Session):
    table = WITH_DIGEST


def test_a_new_stage_is_one_table_entry(tmp_path):
    """The table drives the run, the keys, the artifacts, the journal, status and replay."""
    sess = DigestSession.create(tmp_path / "s")
    rep = sess.run(problem(), UPTO_V)
    assert [(st.stage, st.status) for st in rep.stages] == [
        ("model", "computed"),
        ("synthesis", "computed"),
        ("digest", "computed"),
        ("verification", "computed"),
    ]
    keys = stage_keys(problem(), UPTO_V, WITH_DIGEST)
    # a stage downstream changes no key upstream or beside it
    assert {k: v for k, v in keys.items() if k != "digest"} == stage_keys(problem(), UPTO_V)
    digest = rep.stage("digest")
    # its description (outcome, details: the model from upstream) and extension are its entry's
    assert (digest.outcome, digest.details) == ({"regions": 10}, {"n": 2})
    assert digest.artifact == f"artifacts/digest-{keys['digest'][:16]}.json"
    assert read_index(sess)[Path(digest.artifact).name]["key"] == keys["digest"]
    assert [(st.stage, st.status, st.artifact) for st in sess.status(problem(), UPTO_V)][2] == (
        "digest",
        "cached",
        digest.artifact,
    )
    again = sess.run(problem(), UPTO_V)
    assert set(statuses(again).values()) == {"cached"} and len(again.stages) == 4
    # Q changes the law, so the digest downstream of it
    assert statuses(sess.run(problem(Q2), UPTO_V))["digest"] == "computed"
    digests = [r["outcome"] for r in sess.journal() if r["stage"] == "digest"]
    assert digests == [{"regions": 10}, {"regions": 10}, {"regions": 12}]
    replayed = sess.replay()
    assert replayed.ok and replayed.checked == 12 and replayed.cached == 12
    # replay compares what the entry describes: another description is a mismatch
    recount = replace(DIGEST, describe=lambda v, up: ({"regions": v["regions"] + 1}, {}))

    class Recounting(Session):
        table = StageTable(tuple(recount if st is DIGEST else st for st in WITH_DIGEST))

    assert Recounting.open(sess.path).replay().mismatches == [
        (1, "digest", {"regions": 10}, {"regions": 11}),
        (2, "digest", {"regions": 10}, {"regions": 11}),
        (3, "digest", {"regions": 12}, {"regions": 13}),
    ]
    # codev's own table has no such stage: its journal is refused, not misread
    with pytest.raises(SessionError, match="unknown stage 'digest'"):
        Session.open(sess.path).journal()
