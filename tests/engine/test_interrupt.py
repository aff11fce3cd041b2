"""Ctrl-C ends any ``codev`` command with exit 130 and one line, nothing half-written (issue 23).

Each test starts a real ``codev`` process in its own process group, waits for a progress
line on stderr (the work has started), and sends SIGINT to the whole group, as a terminal's
Ctrl-C does: the command, the search's pool workers, a Dask cluster's processes all get it.
Then: exit 130, the last line of stderr is ``codev: error: interrupted (Ctrl-C)``, no
traceback, no temporary file left in the session, no process of the group left running, and
the session still loads, replays and runs.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest
from cli_process import Interrupted

from codev_engine.session import Session
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
PENDULUM = (ROOT / "examples" / "pendulum.toml").read_text(encoding="utf-8")
INTERRUPTED = "codev: error: interrupted (Ctrl-C)"


def pendulum(time_horizon: float) -> str:
    """The bundled pendulum verified over ``time_horizon`` s (60 s: a minute of work)."""
    assert PENDULUM.count("time_horizon = 3.0") == 1
    return PENDULUM.replace("time_horizon = 3.0", f"time_horizon = {time_horizon}")


def assert_interrupted(run: Interrupted) -> None:
    """Exit 130; stderr: progress lines, then the one line of the interrupt; no traceback."""
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 130, run.stderr
    assert lines[-1] == INTERRUPTED, run.stderr
    assert "Traceback" not in run.stderr and "Error" not in run.stderr, run.stderr
    assert sum("error" in line for line in lines) == 1, run.stderr
    assert run.left() == [], "processes of the interrupted command still run"


def no_temporary_files(folder: Path) -> None:
    assert not [p for p in folder.rglob(".tmp-*")], sorted(folder.rglob("*"))


def cli(*args) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue()


def test_ctrl_c_in_verification_keeps_the_session_usable(tmp_path):
    spec = tmp_path / "pendulum.toml"
    spec.write_text(pendulum(60.0), encoding="utf-8")
    folder = tmp_path / "s"
    run = Interrupted("run", spec, "--session", folder, cwd=tmp_path, after="codev: verification:")
    assert_interrupted(run)
    assert run.stdout == ""
    no_temporary_files(folder)
    # the finished stages are cached and journaled; the interrupted one left nothing
    status = {s.stage: s.status for s in Session.open(folder).status()}
    assert status == {
        "model": "cached", "synthesis": "cached", "verification": "missing", "recording": "missing"
    }, status
    journal = Session.open(folder).journal()
    assert [r["stage"] for r in journal] == ["model", "synthesis"]
    code, out = cli("replay", folder, "--json")
    assert code == 0 and json.loads(out)["match"], out
    # a rerun (a shorter horizon: the same law) loads the law and verifies
    spec.write_text(pendulum(0.3), encoding="utf-8")
    code, out = cli("run", spec, "--session", folder, "--json", "--traces", "1")
    assert code == 0, out
    stages = json.loads(out)["session"]["stages"]
    assert stages["synthesis"]["status"] == "cached"
    assert stages["verification"]["status"] == "computed"


def chain(n: int) -> str:
    """A chain of ``n`` integrators under a quadratic MPC (issue 23's mp-QP, 6 states: a few
    thousand regions, found by the search's worker pool)."""
    names = ", ".join(f'"x{i}"' for i in range(n))
    dyn = ", ".join([f'"x{i + 1}"' for i in range(n - 1)] + ['"u"'])
    eye = "[" + ", ".join(
        "[" + ", ".join("1.0" if i == j else "0.0" for j in range(n)) + "]" for i in range(n)
    ) + "]"

    def vec(v):
        return "[" + ", ".join([str(v)] * n) + "]"

    return (
        f'name = "chain{n}"\n[plant]\nstates = [{names}]\ninputs = ["u"]\ndynamics = [{dyn}]\n'
        f"[model]\nsample_time = 0.5\n[mpc]\nhorizon = 4\nnorm = 2\nQ = {eye}\nR = [[1.0]]\n"
        f"u_min = [-1.0]\nu_max = [1.0]\nx_min = {vec(-2.0)}\nx_max = {vec(2.0)}\n"
        f"[verify]\ntime_horizon = 2.0\n"
        f"initial_set = {{ lower = {vec(-0.1)}, upper = {vec(0.1)} }}\n"
    )


@pytest.mark.slow
def test_ctrl_c_in_synthesis_stops_the_search_and_its_workers(tmp_path):
    spec = tmp_path / "chain6.toml"
    spec.write_text(chain(6), encoding="utf-8")
    folder = tmp_path / "s"
    run = Interrupted("run", spec, "--session", folder, cwd=tmp_path, after="codev: synthesis:")
    assert_interrupted(run)
    no_temporary_files(folder)
    status = {s.stage: s.status for s in Session.open(folder).status()}
    assert status["model"] == "cached" and status["synthesis"] == "missing", status
    code, out = cli("replay", folder, "--json")
    assert code == 0 and json.loads(out)["match"], out
    # the command without a session too
    run = Interrupted("synth", spec, cwd=tmp_path, after="codev: synthesising")
    assert_interrupted(run)


@pytest.mark.slow
def test_ctrl_c_in_a_dask_sweep_leaves_no_worker(tmp_path):
    spec = tmp_path / "pendulum.toml"
    spec.write_text(pendulum(60.0), encoding="utf-8")
    run = Interrupted(
        "sweep", spec, "--set", "mpc.horizon=6,8,10", "--workers", "2",
        "--session", tmp_path / "sweep", cwd=tmp_path, after="codev: sweep:", timeout=300,
        delay=3.0,  # the designs are running on the workers
    )
    assert_interrupted(run)
    # each design's session: whole files only; one whose worker was stopped before its
    # first stage has no spec.toml yet (as right after Session.create), which a rerun fills
    for folder in (tmp_path / "sweep").glob("*/"):
        no_temporary_files(folder)
        session = Session.open(folder)
        session.journal()
        if session.spec_path().is_file():
            session.status()
