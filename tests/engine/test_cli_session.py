"""The session commands of the CLI: ``codev run --session``, ``replay``, ``session``, ``view``.

Through ``workbench.cli.main(argv)`` (stdout/stderr captured), plus real subprocesses for
the exit status. Exit codes: 0 success / robustly safe; 1 a verdict that is not a proof or a
replay mismatch; 2 bad input, with exactly one line ``codev: error: ...`` on stderr and
every file of the session left byte for byte as it was.

One session is made once per module (``codev run examples/double_integrator.toml --session
DIR --traces 1 --json``) and copied into each test's ``tmp_path``.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from cli_process import run_codev

from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
DI_PATH = ROOT / "examples" / "double_integrator.toml"
BASE = DI_PATH.read_text(encoding="utf-8")
STAGES = ["model", "synthesis", "verification", "recording"]


def edit(old: str, new: str, text: str = BASE) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def cli(capsys, *args) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("codev: error: "), err
    return lines[0]


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (hidden ones too) -> its bytes."""
    if not root.exists():
        return {}
    if root.is_file():
        return {root.name: root.read_bytes()}
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def run_argv(spec, d, *extra) -> list[str]:
    return ["run", str(spec), "--session", str(d), "--traces", "1", *extra]


def write_spec(tmp_path: Path, text: str, name: str = "spec.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, dict]:
    """A session after one ``codev run --json`` of the double integrator, and its JSON."""
    d = tmp_path_factory.mktemp("base") / "s"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(run_argv(DI_PATH, d, "--json"))
    assert code == 0
    return d, json.loads(buf.getvalue())


@pytest.fixture
def sdir(base, tmp_path) -> Path:
    d = tmp_path / "s"
    shutil.copytree(base[0], d)
    return d


def journal(d: Path) -> list[dict]:
    return [json.loads(x) for x in (d / "journal.jsonl").read_text().splitlines() if x.strip()]


def rewrite_journal(d: Path, change) -> None:
    recs = journal(d)
    change(recs)
    (d / "journal.jsonl").write_text("\n".join(json.dumps(r, sort_keys=True) for r in recs) + "\n")


# --------------------------------------------------------------------------------------------
# codev run --session
# --------------------------------------------------------------------------------------------


def test_run_json_is_verify_json_plus_session_and_recording(base, capsys):
    d, payload = base
    code, out, _ = cli(capsys, "verify", DI_PATH, "--json")
    assert code == 0
    verify_payload = json.loads(out)
    assert set(payload) == set(verify_payload) | {"session", "recording"}
    for k in ("problem", "verdict", "reason", "hold", "regions", "boxes", "counterexample"):
        assert payload[k] == verify_payload[k], k
    assert payload["verdict"] == "robustly_safe" and payload["regions"] == 10
    sess = payload["session"]
    assert sess["dir"] == str(d) and sess["run"] == 1
    assert list(sess["stages"]) == STAGES
    for st in sess["stages"].values():
        assert st["status"] == "computed"
        assert len(st["key"]) == 64
        assert (d / st["artifact"]).is_file()
        assert set(st) >= {"status", "seconds", "key", "artifact", "outcome"}
    assert sess["stages"]["synthesis"]["outcome"] == {"regions": 10}
    assert Path(payload["recording"]).is_file() and payload["recording"].endswith(".rrd")
    assert Path(payload["recording"]) == d / sess["stages"]["recording"]["artifact"]
    assert (d / "session.json").is_file() and (d / "spec.toml").read_text() == BASE


def test_second_run_is_cached(sdir, capsys):
    code, out, err = cli(capsys, *run_argv(DI_PATH, sdir))
    assert code == 0, err
    assert f"session {sdir} (run 2)" in out
    for stage in STAGES:
        line = next(x for x in out.splitlines() if x.strip().startswith(stage))
        assert "cached" in line, line
    assert "robustly_safe" in out and "recording written to" in out
    code, out, _ = cli(capsys, *run_argv(DI_PATH, sdir, "--json"))
    payload = json.loads(out)
    assert payload["session"]["run"] == 3
    assert {s["status"] for s in payload["session"]["stages"].values()} == {"cached"}
    assert [r["run"] for r in journal(sdir)] == [1] * 4 + [2] * 4 + [3] * 4


@pytest.mark.parametrize(
    ("text", "extra", "want"),
    [
        (edit("time_horizon = 9.0", "time_horizon = 8.0"), [], ["cached", "cached", "computed"]),
        (BASE, ["--hold", "zoh"], ["cached", "cached", "computed"]),
        (BASE, ["--max-depth", "2"], ["cached", "cached", "computed"]),
        (
            edit("Q = [[1.0, 1.0], [0.0, 1.0]]", "Q = [[1.0, 1.0], [0.0, 2.0]]"),
            [],
            ["cached", "computed", "computed"],
        ),
        (
            edit('dynamics = ["x2", "u"]', 'dynamics = ["x2", "0.5*u"]'),
            [],
            ["computed", "computed", "computed"],
        ),
        (BASE, ["--axes", "1,0"], ["cached", "cached", "cached"]),
    ],
    ids=["time_horizon", "hold", "max_depth", "Q", "plant", "axes"],
)
def test_run_reruns_only_what_changed(sdir, tmp_path, capsys, text, extra, want):
    spec = write_spec(tmp_path, text)
    code, out, err = cli(capsys, *run_argv(spec, sdir, "--json", *extra))
    assert code in (0, 1), err
    stages = json.loads(out)["session"]["stages"]
    assert [stages[s]["status"] for s in STAGES[:3]] == want
    assert stages["recording"]["status"] == "computed"
    assert (sdir / "spec.toml").read_text() == text


def test_run_fresh_and_record(sdir, tmp_path, capsys):
    rrd = tmp_path / "out" / "di.rrd"
    code, out, err = cli(capsys, *run_argv(DI_PATH, sdir, "--json", "--fresh", "--record", rrd))
    assert code == 0, err
    payload = json.loads(out)
    assert {s["status"] for s in payload["session"]["stages"].values()} == {"computed"}
    assert payload["recording"] == str(rrd) and rrd.is_file()
    artifact = sdir / payload["session"]["stages"]["recording"]["artifact"]
    assert rrd.read_bytes() == artifact.read_bytes()
    # cached recording, exported again
    rrd2 = tmp_path / "again.rrd"
    code, out, _ = cli(capsys, *run_argv(DI_PATH, sdir, "--record", rrd2))
    assert code == 0 and rrd2.read_bytes() == artifact.read_bytes()
    assert f"recording written to {rrd2}" in out and f"codev view {rrd2}" in out


def test_run_export_tube(sdir, tmp_path, capsys):
    tube = tmp_path / "tube.npz"
    code, out, _ = cli(capsys, *run_argv(DI_PATH, sdir, "--json", "--export-tube", tube))
    assert code == 0 and json.loads(out)["tube"] == str(tube) and tube.is_file()


def test_run_unsafe_exits_1(tmp_path, capsys):
    text = BASE + "\n[[verify.unsafe]]\nlower = [-1.0, -1.0]\nupper = [1.0, 1.0]\n"
    spec = write_spec(tmp_path, text)
    d = tmp_path / "s"
    code, out, err = cli(capsys, *run_argv(spec, d, "--json"))
    assert code == 1, err
    payload = json.loads(out)
    assert payload["verdict"] == "unsafe" and payload["counterexample"] is not None
    assert payload["session"]["stages"]["verification"]["outcome"]["verdict"] == "unsafe"
    # cached: the same verdict, the same exit status
    code, out, _ = cli(capsys, *run_argv(spec, d, "--json"))
    assert code == 1 and json.loads(out)["verdict"] == "unsafe"
    assert json.loads(out)["session"]["stages"]["verification"]["status"] == "cached"


def test_run_without_verify_section(tmp_path, capsys):
    spec = write_spec(tmp_path, BASE.split("[verify]")[0])
    d = tmp_path / "s"
    code, out, err = cli(capsys, *run_argv(spec, d, "--json"))
    assert code == 0, err
    payload = json.loads(out)
    assert set(payload) >= {"problem", "regions", "recording", "session"}
    assert payload["regions"] == 10
    assert list(payload["session"]["stages"]) == ["model", "synthesis", "recording"]
    assert Path(payload["recording"]).is_file()


def test_fresh_without_session_is_bad_input(capsys):
    code, out, err = cli(capsys, "run", DI_PATH, "--fresh")
    assert code == 2 and out == ""
    assert "--fresh" in one_error_line(err)


# --------------------------------------------------------------------------------------------
# codev session
# --------------------------------------------------------------------------------------------


def test_session_command(sdir, capsys):
    code, out, err = cli(capsys, "session", sdir, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["dir"] == str(sdir) and info["format"] == "codev-session/1"
    assert info["problem"] == "double-integrator"
    assert info["runs"] == 1 and info["records"] == 4 and info["last"]
    assert [s["stage"] for s in info["stages"]] == STAGES
    assert {s["status"] for s in info["stages"]} == {"cached"}
    code, out, _ = cli(capsys, "session", sdir)
    assert code == 0
    assert "journal: 1 run(s), 4 stage record(s)" in out
    for stage in STAGES:
        assert any(x.split()[:2] == [stage, "cached"] for x in out.splitlines()), out


def test_session_command_shows_stale_and_corrupt(sdir, capsys):
    # spec.toml edited by hand (valid): verification and recording inputs changed
    spec = sdir / "spec.toml"
    spec.write_text(edit("time_horizon = 9.0", "time_horizon = 8.0"))
    synth = next((sdir / "artifacts").glob("synthesis-*.npz"))
    synth.write_bytes(synth.read_bytes()[:100])
    before = {p: p.read_bytes() for p in sdir.rglob("*") if p.is_file()}
    code, out, err = cli(capsys, "session", sdir, "--json")
    assert code == 0, err
    st = {s["stage"]: s for s in json.loads(out)["stages"]}
    assert st["model"]["status"] == "cached"
    assert st["synthesis"]["status"] == "corrupt" and st["synthesis"]["reason"]
    assert st["verification"]["status"] == "stale"
    assert st["recording"]["status"] == "stale"
    assert {p: p.read_bytes() for p in sdir.rglob("*") if p.is_file()} == before


# --------------------------------------------------------------------------------------------
# codev replay
# --------------------------------------------------------------------------------------------


def test_replay_command_matches(sdir, tmp_path, capsys):
    spec = write_spec(
        tmp_path, edit("Q = [[1.0, 1.0], [0.0, 1.0]]", "Q = [[2.0, 0.0], [0.0, 1.0]]")
    )
    cli(capsys, *run_argv(spec, sdir))
    before = snapshot(sdir)
    code, out, err = cli(capsys, "replay", sdir, "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert set(rep) == {"dir", "runs", "checked", "cached", "match", "mismatches", "seconds"}
    assert rep["match"] is True and rep["mismatches"] == []
    assert rep["runs"] == 2 and rep["checked"] == 8 and rep["cached"] == 8
    code, out, _ = cli(capsys, "replay", sdir)
    assert code == 0 and "every outcome matches" in out
    assert "run 1:" in out and "run 2:" in out
    assert snapshot(sdir) == before


def test_replay_command_mismatch_exits_1(sdir, capsys):
    def change(recs):
        next(r for r in recs if r["stage"] == "synthesis")["outcome"] = {"regions": 999}

    rewrite_journal(sdir, change)
    before = snapshot(sdir)
    code, out, _ = cli(capsys, "replay", sdir, "--json")
    assert code == 1
    rep = json.loads(out)
    assert rep["match"] is False
    assert rep["mismatches"] == [
        {"run": 1, "stage": "synthesis", "recorded": {"regions": 999}, "replayed": {"regions": 10}}
    ]
    code, out, _ = cli(capsys, "replay", sdir)
    assert code == 1 and "MISMATCH" in out and "1 mismatch" in out
    assert snapshot(sdir) == before


def test_replay_command_recomputes_deleted_artifacts(sdir, capsys):
    shutil.rmtree(sdir / "artifacts")
    j = (sdir / "journal.jsonl").read_bytes()
    code, out, err = cli(capsys, "replay", sdir, "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert rep["match"] is True and rep["cached"] == 0 and rep["checked"] == 4
    assert (sdir / "journal.jsonl").read_bytes() == j


def test_run_warns_on_a_damaged_artifact(sdir, capsys):
    synth = next((sdir / "artifacts").glob("synthesis-*.npz"))
    synth.write_bytes(synth.read_bytes()[:-10])
    code, out, err = cli(capsys, *run_argv(DI_PATH, sdir, "--json"))
    assert code == 0
    warnings = [x for x in err.splitlines() if x.startswith("codev: warning:")]
    assert len(warnings) == 1 and synth.name in warnings[0]
    stages = json.loads(out)["session"]["stages"]
    assert stages["synthesis"]["status"] == "computed"
    assert stages["synthesis"]["outcome"] == {"regions": 10}
    assert stages["verification"]["status"] == "cached"


# --------------------------------------------------------------------------------------------
# codev view
# --------------------------------------------------------------------------------------------


def test_view_print_only_and_no_display(base, capsys, monkeypatch):
    rrd = Path(base[1]["recording"])
    code, out, err = cli(capsys, "view", rrd, "--print-only")
    assert code == 0, err
    assert str(rrd) in out and "rerun" in out
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, out2, _ = cli(capsys, "view", rrd)
    assert code == 0 and "no display" in out2.lower() and str(rrd) in out2


def test_report_from_a_session(base, tmp_path, capsys):
    d = base[0]
    before = sorted(p.name for p in (d / "artifacts").iterdir())
    out_file = tmp_path / "r" / "di.html"
    code, out, err = cli(capsys, "report", d, "--out", out_file, "--traces", "2")
    assert code == 0, err
    assert f"report written to {out_file}" in out
    text = out_file.read_text()
    assert text.startswith("<!DOCTYPE html>") and text.count("<figure") == 3
    assert "ROBUSTLY SAFE" in text
    assert sorted(p.name for p in (d / "artifacts").iterdir()) == before  # nothing computed
    code, _, err = cli(capsys, "report", d, "--out", tmp_path / "r.pdf")
    assert code == 2 and "--out" in one_error_line(err)


def test_report_from_a_session_without_a_law(tmp_path, capsys):
    from codev_engine.session import Session

    d = tmp_path / "s"

    session = Session.create(d)
    session.save_spec(ce_load(DI_PATH))
    code, _, err = cli(capsys, "report", d)
    assert code == 2 and "codev run" in one_error_line(err)


def ce_load(path: Path):
    import codev_engine as ce

    return ce.load_spec(path)


def _gone(pid: int, seconds: float = 5.0) -> bool:
    """Has process ``pid`` exited (absent, or a zombie waiting for its reaper)?"""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError):
            return True
        if state == "Z":
            return True
        time.sleep(0.05)
    return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_run_viewer_stops_what_it_started(tmp_path):
    """A viewer that leaves a child behind (as the rerun script leaves its server) has the
    child stopped when codev's wait ends."""
    from workbench.cli import run_viewer

    pidfile = tmp_path / "pid"
    code = run_viewer(["sh", "-c", f"sleep 300 & echo $! > {pidfile}; exit 3"], grace=2.0)
    assert code == 3
    assert _gone(int(pidfile.read_text()))


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc")
def test_view_web_ctrl_c_leaves_no_server(base, tmp_path):
    """``codev view --web``, then Ctrl-C: the rerun script and its server are gone."""
    import signal
    import socket
    import subprocess
    import sys

    rrd = Path(base[1]["recording"])
    port = _free_port_pair()
    proc = subprocess.Popen(
        [sys.executable, "-m", "workbench.cli", "view", "--web", "--port", str(port), str(rrd)],
        start_new_session=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 60
        up = False
        while time.monotonic() < deadline and not up:
            with socket.socket() as s:
                up = s.connect_ex(("127.0.0.1", port)) == 0
            time.sleep(0.2)
        assert up, "the web viewer did not start"
        group = [
            int(p.name)
            for p in Path("/proc").iterdir()
            if p.name.isdigit()
            and _pgid(int(p.name)) not in (None, proc.pid, os.getpgid(0))
            and _ancestor(int(p.name), proc.pid)
        ]
        assert group, "the viewer runs in a process group of its own"
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 130
        assert all(_gone(pid) for pid in group)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _free_port_pair() -> int:
    """A port P with P + 1 free too (``codev view --web --port P`` serves the data on P + 1):
    the system's free port alone left P + 1 to chance, taken by any connection's port."""
    import socket

    for _ in range(100):
        with socket.socket() as a, socket.socket() as b:
            a.bind(("127.0.0.1", 0))
            port = a.getsockname()[1]
            if port >= 65535:
                continue
            try:
                b.bind(("127.0.0.1", port + 1))
            except OSError:
                continue
            return port
    raise AssertionError("no two free ports in a row on 127.0.0.1")


def _pgid(pid: int) -> int | None:
    try:
        return os.getpgid(pid)
    except ProcessLookupError:
        return None


def _ancestor(pid: int, root: int) -> bool:
    """Is ``root`` an ancestor of ``pid``?"""
    for _ in range(20):
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (FileNotFoundError, ValueError, IndexError):
            return False
        if pid == root:
            return True
        if pid <= 1:
            return False
    return False


# --------------------------------------------------------------------------------------------
# bad input: exit 2, one line, nothing in the session changed
# --------------------------------------------------------------------------------------------


def _bad_spec(d: Path, tmp: Path) -> list:
    return run_argv(write_spec(tmp, edit("horizon = 2", "horizon = -2"), "bad.toml"), d)


def _foreign(d: Path, tmp: Path) -> None:
    shutil.rmtree(d)
    d.mkdir()
    (d / "notes.txt").write_text("my own notes")


def _format(d: Path, tmp: Path) -> None:
    meta = json.loads((d / "session.json").read_text())
    meta["format"] = "codev-session/99"
    (d / "session.json").write_text(json.dumps(meta))


def _engine(d: Path, tmp: Path) -> None:
    def change(recs):
        for r in recs:
            r["engine"] = "0.0.1"

    rewrite_journal(d, change)


def _bad_line(d: Path, tmp: Path) -> None:
    with (d / "journal.jsonl").open("a") as fh:
        fh.write('{"run": 2, "stage": "model", oops\n')


def _spec_invalid(d: Path, tmp: Path) -> None:
    (d / "spec.toml").write_text(edit("R = [[0.8]]", "R = [[0.8, 1.0]]"))


def _snapshot_edited(d: Path, tmp: Path) -> None:
    snap = next((d / "specs").glob("*.toml"))
    snap.write_text(snap.read_text() + "\n# edited\n")


def _snapshot_deleted(d: Path, tmp: Path) -> None:
    next((d / "specs").glob("*.toml")).unlink()


def _no_journal(d: Path, tmp: Path) -> None:
    (d / "journal.jsonl").unlink()


def _garbage_meta(d: Path, tmp: Path) -> None:
    (d / "session.json").write_text("{{{")


def _nothing(d: Path, tmp: Path) -> None:
    pass


Q2 = edit("Q = [[1.0, 1.0], [0.0, 1.0]]", "Q = [[2.0, 0.0], [0.0, 1.0]]")

BAD = [
    # (id, setup(d, tmp), argv(d, tmp))
    ("replay-missing-dir", _nothing, lambda d, t: ["replay", t / "nope"]),
    ("session-missing-dir", _nothing, lambda d, t: ["session", t / "nope"]),
    ("replay-a-file", _nothing, lambda d, t: ["replay", d / "spec.toml"]),
    ("run-into-foreign-folder", _foreign, lambda d, t: run_argv(DI_PATH, d)),
    ("replay-foreign-folder", _foreign, lambda d, t: ["replay", d]),
    ("session-foreign-folder", _foreign, lambda d, t: ["session", d]),
    ("run-session-is-a-file", _nothing, lambda d, t: run_argv(DI_PATH, d / "spec.toml")),
    ("run-unknown-format", _format, lambda d, t: run_argv(DI_PATH, d)),
    ("replay-unknown-format", _format, lambda d, t: ["replay", d]),
    ("session-unknown-format", _format, lambda d, t: ["session", d]),
    ("session-garbage-session-json", _garbage_meta, lambda d, t: ["session", d]),
    ("replay-other-engine", _engine, lambda d, t: ["replay", d]),
    ("replay-malformed-journal", _bad_line, lambda d, t: ["replay", d, "--json"]),
    ("session-malformed-journal", _bad_line, lambda d, t: ["session", d]),
    (
        "run-malformed-journal",
        _bad_line,
        lambda d, t: run_argv(write_spec(t, Q2, "q2.toml"), d),
    ),
    ("run-bad-spec", _nothing, _bad_spec),
    ("run-bad-spec-json", _nothing, lambda d, t: [*_bad_spec(d, t), "--json"]),
    ("run-axes-out-of-range", _nothing, lambda d, t: run_argv(DI_PATH, d, "--axes", "0,5")),
    ("run-negative-traces", _nothing, lambda d, t: [*run_argv(DI_PATH, d), "--traces", "-1"]),
    ("run-negative-max-depth", _nothing, lambda d, t: run_argv(DI_PATH, d, "--max-depth", "-1")),
    ("session-spec-edited-invalid", _spec_invalid, lambda d, t: ["session", d]),
    ("session-spec-edited-invalid-json", _spec_invalid, lambda d, t: ["session", d, "--json"]),
    ("replay-snapshot-edited", _snapshot_edited, lambda d, t: ["replay", d]),
    ("replay-snapshot-deleted", _snapshot_deleted, lambda d, t: ["replay", d]),
    ("replay-empty-journal", _no_journal, lambda d, t: ["replay", d]),
]


@pytest.mark.parametrize(("setup", "argv"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_exits_2_and_changes_nothing(sdir, tmp_path, capsys, setup, argv):
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    setup(sdir, inputs)
    args = argv(sdir, inputs)
    before = snapshot(sdir)
    code, out, err = cli(capsys, *args)
    assert code == 2, (out, err)
    line = one_error_line(err)
    assert "internal error" not in line
    assert snapshot(sdir) == before
    assert not (tmp_path / "nope").exists()


def test_bad_spec_message_names_the_field(sdir, tmp_path, capsys):
    code, _, err = cli(capsys, *_bad_spec(sdir, tmp_path))
    assert code == 2 and "mpc.horizon" in one_error_line(err)
    _spec_invalid(sdir, tmp_path)
    code, _, err = cli(capsys, "session", sdir)
    assert code == 2
    line = one_error_line(err)
    assert "spec.toml" in line and "mpc.R" in line


def test_foreign_engine_advice_makes_the_session_replayable(sdir, tmp_path, capsys):
    """The error names the engine and advises a new session from the old one's spec;
    following the advice gives a replayable session."""
    _engine(sdir, tmp_path)
    code, _, err = cli(capsys, "replay", sdir)
    line = one_error_line(err)
    assert code == 2 and "0.0.1" in line and "new session" in line and "NEW_DIR" in line
    spec = line.split("codev run ", 1)[1].split(" --session", 1)[0]
    new = tmp_path / "new"
    code, _, err = cli(capsys, *run_argv(spec, str(new)))
    assert code == 0, err
    code, _, err = cli(capsys, "replay", str(new))
    assert code == 0, err


@pytest.mark.parametrize("damage", ["truncated", "header-only", "not-rrd", "missing", "npz"])
def test_view_bad_recording_exits_2(base, tmp_path, capsys, damage):
    good = Path(base[1]["recording"]).read_bytes()
    f = tmp_path / "x.rrd"
    if damage == "truncated":
        f.write_bytes(good[: len(good) // 2])
    elif damage == "header-only":
        f.write_bytes(good[:64])
    elif damage == "not-rrd":
        f.write_text("hello, I am not a recording\n")
    elif damage == "npz":
        f = tmp_path / "x.npz"
        f.write_bytes(good)
    code, out, err = cli(capsys, "view", f, "--print-only")
    assert code == 2 and out == ""
    assert str(f) in one_error_line(err)


# --------------------------------------------------------------------------------------------
# real processes: the exit status
# --------------------------------------------------------------------------------------------


def _codev(*args) -> subprocess.CompletedProcess:
    return run_codev(*args, cwd=ROOT, timeout=120)


def test_exit_status_of_real_processes(sdir, tmp_path):
    bad = write_spec(tmp_path, edit("horizon = 2", "horizon = -2"), "bad.toml")
    before = snapshot(sdir)
    p = _codev("run", bad, "--session", sdir)
    assert p.returncode == 2 and p.stdout == ""
    one_error_line(p.stderr)
    assert snapshot(sdir) == before

    def change(recs):
        next(r for r in recs if r["stage"] == "verification")["outcome"]["verdict"] = "unknown"

    rewrite_journal(sdir, change)
    before = snapshot(sdir)
    p = _codev("replay", sdir, "--json")
    assert p.returncode == 1, p.stderr
    rep = json.loads(p.stdout)
    assert rep["match"] is False and [m["stage"] for m in rep["mismatches"]] == ["verification"]
    assert snapshot(sdir) == before


def test_bench_runs_a_benchmark_script(capsys):
    """``codev bench NAME ARGS`` runs benchmarks/NAME.py with ARGS (here: its --help)."""
    from workbench.cli import main

    assert main(["bench", "session", "--help"]) == 0


def test_reader_gone_away_is_silent_141(sdir):
    """``codev run ... | head``: stdout's reader has left; the command ends as a program
    killed by SIGPIPE would (status 141) with nothing on stderr, not ``error: Broken pipe``."""
    import sys

    r, w = os.pipe()
    os.close(r)  # the reader is gone before the first write
    try:
        p = subprocess.run(
            [sys.executable, "-m", "workbench.cli", "session", str(sdir)],
            stdout=w,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
    finally:
        os.close(w)
    assert p.returncode == 141, p.stderr
    assert p.stderr == ""
