"""The mp-QP search and the nonlinear verification on a real Dask cluster (2 processes).

Both must give the serial result exactly: the same regions (active sets, rows, laws, in the
same order), the same verdict, tube and counterexample, however many workers and whatever
finishes first; and a worker killed with SIGKILL mid-run changes nothing (the scheduler
reruns its tasks). The sweeps' own cluster tests are in test_sweep.py.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.mp import mpqp
from tests.engine.cli_process import run_codev
from tests.engine.test_mpqp_graph import _program
from tests.engine.test_mpsolve import PROGRAMS

ROOT = Path(__file__).resolve().parents[2]
CSTR = ROOT / "examples" / "cstr.toml"


def _same_regions(a: ce.MpSolution, b: ce.MpSolution) -> None:
    assert a.num_regions == b.num_regions > 1
    for r, s in zip(a.regions, b.regions, strict=True):
        assert r.active == s.active
        np.testing.assert_array_equal(r.A, s.A)
        np.testing.assert_array_equal(r.b, s.b)
        np.testing.assert_array_equal(r.K, s.K)
        np.testing.assert_array_equal(r.k, s.k)


def _kill_a_busy_worker(client, pids: dict, killed: list) -> None:
    """SIGKILL one worker process that holds unfinished tasks (once)."""
    if killed:
        return
    for address, keys in client.processing().items():
        if keys and address in pids:
            os.kill(pids[address], signal.SIGKILL)
            killed.append(pids[address])
            return


def _wait_for_workers(client, gone: int) -> None:
    """Until the nanny has started a new worker in place of the process ``gone`` (a loaded
    machine takes a while to start one)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        now = client.run(os.getpid)
        if len(now) == 2 and gone not in now.values():
            return
        time.sleep(0.2)
    raise AssertionError("the killed worker was not replaced")


# -- the mp-QP search ------------------------------------------------------------------------


def test_compiled_walk_on_a_cluster_gives_the_serial_regions(cluster, monkeypatch):
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", 1)
    serial = ce.mpsolve(_program(), options=ce.SolveOptions(workers=1))
    remote = ce.mpsolve(_program(), executor=cluster)
    assert serial.stats["jit"] is True and remote.stats["workers"] == 2
    assert remote.stats["tasks"] >= 1 and remote.stats["task_seconds"] > 0
    _same_regions(serial, remote)
    assert remote.stats["explored"] == serial.stats["explored"]
    assert remote.stats["candidates"] == serial.stats["candidates"]


@pytest.mark.parametrize("name", ["random_qp0", "random_qp4"])
def test_numpy_kernel_on_a_cluster_gives_the_serial_regions(name, cluster, monkeypatch):
    """Where the compiled kernel does not apply (forced here), chunks of candidates go to
    the workers with the numpy kernel (sent in memory); the regions are the serial ones."""
    serial = ce.mpsolve(PROGRAMS[name](), options=ce.SolveOptions(workers=1))
    assert serial.num_regions > 20
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", 1)
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(mpqp, "_CHUNK", 4)  # (small problems: tasks of 4 candidates)
    monkeypatch.setattr(mpqp._Kernel, "start_jit", lambda self: False)
    remote = ce.mpsolve(PROGRAMS[name](), executor=cluster)
    assert remote.stats.get("workers") == 2 and remote.stats["tasks"] > 1
    _same_regions(serial, remote)


def _degenerate_program() -> ce.MpProgram:
    """``_program()`` with two rows that are combinations of others (``A0 + A1``,
    ``A2 - A3 / 2``): 165 LICQ candidates and 9 handed back in a search of 752 regions."""
    p = _program()
    A, b, F = p.A, p.b, p.F
    return ce.MpProgram(
        H=p.H, c=p.c, C=p.C, A_theta=p.A_theta, b_theta=p.b_theta,
        A=np.vstack([A, A[0] + A[1], A[2] - 0.5 * A[3]]),
        b=np.concatenate([b, [b[0] + b[1], b[2] - 0.5 * b[3]]]),
        F=np.vstack([F, F[0] + F[1], F[2] - 0.5 * F[3]]),
    )


def test_a_degenerate_search_on_a_cluster_gives_the_serial_regions(cluster, monkeypatch):
    """LICQ candidates (their subsets to visit computed on the workers) and candidates
    handed back (evaluated there with the numpy kernel): the serial regions still."""
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", 1)
    serial = ce.mpsolve(_degenerate_program(), options=ce.SolveOptions(workers=1))
    assert serial.stats["candidates_licq"] > 100 and serial.stats["handed_back"] > 0
    remote = ce.mpsolve(_degenerate_program(), executor=cluster)
    assert remote.stats["tasks"] >= 1
    _same_regions(serial, remote)
    for key in ("explored", "candidates", "candidates_licq", "handed_back"):
        assert remote.stats[key] == serial.stats[key], key


def _hand_back_every_third(on: bool) -> None:
    """Make the compiled kernel hand back every third candidate (FALLBACK) in this process
    (here, or on a worker through ``client.run``), or undo it."""
    from codev_engine.mp import mpqp_kernel

    if not hasattr(mpqp_kernel, "_unforced_evaluate_batch"):
        mpqp_kernel._unforced_evaluate_batch = mpqp_kernel.evaluate_batch
    batch = mpqp_kernel._unforced_evaluate_batch

    def some_back(keys, *args):
        out = batch(keys, *args)
        status = out[0].copy()
        status[::3] = mpqp_kernel.FALLBACK
        return (status, *out[1:])

    mpqp_kernel.evaluate_batch = some_back if on else batch


def test_candidates_handed_back_go_through_numpy_on_the_workers(cluster, monkeypatch):
    """The candidates the compiled kernel hands back are evaluated with the numpy kernel by
    the worker that had them (not by the client, whose CPU the walk's merge needs); the
    regions are the serial ones."""
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", 1)
    client = cluster.client
    try:
        _hand_back_every_third(True)
        client.run(_hand_back_every_third, True)
        serial = ce.mpsolve(_program(), options=ce.SolveOptions(workers=1))
        remote = ce.mpsolve(_program(), executor=cluster)
    finally:
        _hand_back_every_third(False)
        client.run(_hand_back_every_third, False)
    assert serial.stats["handed_back"] > 100
    assert remote.stats["handed_back"] == serial.stats["handed_back"]
    # (the batches before the workers started were evaluated here)
    assert remote.stats.get("handed_back_on_workers", 0) > serial.stats["handed_back"] // 2
    _same_regions(serial, remote)
    assert remote.stats["explored"] == serial.stats["explored"]


def test_a_worker_killed_mid_search_changes_nothing(cluster, monkeypatch):
    # small tasks (one batch each, 8 in flight), so the search is many tasks long
    monkeypatch.setattr(mpqp, "JIT_AFTER", 0)
    monkeypatch.setattr(mpqp, "PARALLEL_AFTER", 1)
    monkeypatch.setattr(mpqp, "_GROUP", 1)
    monkeypatch.setattr(mpqp, "_DEPTH", 8)
    serial = ce.mpsolve(_program(), options=ce.SolveOptions(workers=1))
    client = cluster.client
    pids = client.run(os.getpid)
    killed: list[int] = []

    def progress(found: int) -> None:
        if found >= 100:
            _kill_a_busy_worker(client, pids, killed)

    remote = ce.mpsolve(_program(), executor=cluster, progress=progress)
    assert killed, "no worker held a task once 100 regions were found"
    assert remote.stats["tasks"] > 10
    _same_regions(serial, remote)
    _wait_for_workers(client, killed[0])


# -- the nonlinear verification's cells ---------------------------------------------------------


def _same_result(a, b) -> None:
    assert (a.verdict, a.reason, a.detail) == (b.verdict, b.reason, b.detail)
    for f in ("t_start", "t_end", "lower", "upper", "branch"):
        np.testing.assert_array_equal(getattr(a.tube, f), getattr(b.tube, f))
    for k in ("branches", "refinements", "partitions", "merges", "boxes"):
        assert a.stats[k] == b.stats[k], k
    assert (a.counterexample is None) == (b.counterexample is None)
    if a.counterexample is not None:
        ca, cb = a.counterexample, b.counterexample
        assert (ca.kind, ca.index, ca.t) == (cb.kind, cb.index, cb.t)
        np.testing.assert_array_equal(ca.x0, cb.x0)


@pytest.fixture(scope="module")
def cstr():
    problem = ce.load_spec(CSTR)
    law = ce.synthesize(problem)
    return problem, law, ce.verify(problem, law)


@pytest.mark.slow  # (~16 s on a quiet machine: the workers compile the plant's enclosures)
def test_verification_cells_on_a_cluster_give_the_serial_result(cluster, cstr):
    problem, law, serial = cstr
    assert serial.stats["partitions"] > 1  # refined: several cells
    _same_result(serial, ce.verify(problem, law, executor=cluster))


@pytest.mark.slow
def test_a_worker_killed_mid_verification_changes_nothing(cluster, tmp_path):
    """An unsafe variant of the CSTR (a wider initial set): ~30 cells before the
    counterexample, cells computed ahead of it dropped; a worker killed once 4 cells are
    taken."""
    text = CSTR.read_text().replace(
        "initial_set = { lower = [0.52, 351.0], upper = [0.56, 354.0] }",
        "initial_set = { lower = [0.48, 347.0], upper = [0.60, 358.0] }",
    )
    spec = tmp_path / "cstr_wide.toml"
    spec.write_text(text)
    problem = ce.load_spec(spec)
    law = ce.synthesize(problem)
    serial = ce.verify(problem, law)
    assert serial.verdict == "unsafe" and serial.stats["partitions"] > 8
    client = cluster.client
    pids = client.run(os.getpid)
    killed: list[int] = []

    def progress(stats: dict) -> None:
        if stats["partitions"] >= 4:
            _kill_a_busy_worker(client, pids, killed)

    remote = ce.verify(problem, law, executor=cluster, progress=progress)
    assert killed
    _same_result(serial, remote)
    _wait_for_workers(client, killed[0])


# -- the command line ------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["verify", "mpsolve"])
def test_cli_bad_worker_count_is_one_line_exit_2(command):
    target = CSTR if command != "mpsolve" else ROOT / "missing.npz"
    out = run_codev(command, target, "--workers", "0", cwd=ROOT)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "--workers" in lines[0], out.stderr


@pytest.mark.slow
def test_cli_run_on_two_workers_gives_the_serial_result(tmp_path):
    serial = run_codev("verify", CSTR, "--json", cwd=ROOT, timeout=1200)
    remote = run_codev("run", CSTR, "--json", "--workers", "2", "--session", tmp_path / "s",
                       cwd=ROOT, timeout=1200)
    assert serial.returncode == remote.returncode == 0, remote.stderr
    a, b = json.loads(serial.stdout), json.loads(remote.stdout)
    for key in ("verdict", "reason", "regions", "branches", "partitions", "boxes",
                "tube_width_at_horizon"):
        assert a[key] == b[key], key


def _set_limits(text: str | None) -> None:
    """Worker side: set (or unset) this process's CODEV_LIMITS."""
    if text is None:
        os.environ.pop("CODEV_LIMITS", None)
    else:
        os.environ["CODEV_LIMITS"] = text


@pytest.mark.slow  # (~20 s on a quiet machine)
def test_the_limits_count_the_whole_run_on_a_cluster(cluster, cstr, monkeypatch):
    """The run-time limits count the whole verification, as in serial, not each cell on
    each worker: the CSTR (271 branches) with a limit of 120 stops at the same branch with
    the same tube; and a worker whose own limits are lower stops nothing early."""
    problem, law, _ = cstr
    monkeypatch.setenv("CODEV_LIMITS", "branches=120")
    serial = ce.verify(problem, law)
    assert (serial.verdict, serial.reason) == ("unknown", "limit")
    _same_result(serial, ce.verify(problem, law, executor=cluster))
    client = cluster.client
    client.run(_set_limits, "branches=3")  # every cell passes the workers' own limit
    try:
        _same_result(serial, ce.verify(problem, law, executor=cluster))
    finally:
        client.run(_set_limits, None)
