"""Design sweeps (``ce.sweep``, ``codev sweep``) and the executor they run on.

- every bundled spec survives the sweep's TOML round trip (dict -> text -> the same dict);
- a design is the loader's: a bad swept value is its one-line SpecError naming the field,
  and ``codev sweep`` exits 2 with one line;
- on a real Dask LocalCluster (2 worker processes, shared by the tests of this module, as
  they take seconds to start) the rows are those of the serial run, in the same order;
- a worker process killed while it holds tasks: the scheduler reruns them elsewhere and the
  rows are still the serial ones, each design once.
"""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
import tomllib
from pathlib import Path

import pytest

import codev_engine as ce
from codev_engine.sweeps import TIMING_FIELDS, dumps_toml, set_field
from tests.engine.cli_process import run_codev

ROOT = Path(__file__).resolve().parents[2]
DI = ROOT / "examples" / "double_integrator.toml"

#: 8 designs of the double integrator, ~0.05 s each
GRID = {"mpc.horizon": [2, 3], "mpc.R": [[[0.5]], [[0.8]], [[1.0]], [[2.0]]]}


def exact(rows: list[dict]) -> list[dict]:
    """The rows without their wall times (everything else must agree bit for bit)."""
    return [{k: v for k, v in row.items() if k not in TIMING_FIELDS} for row in rows]


@pytest.mark.parametrize("spec", sorted((ROOT / "examples").glob("*.toml")), ids=lambda p: p.stem)
def test_toml_round_trip_of_every_example(spec):
    data = tomllib.loads(spec.read_text(encoding="utf-8"))
    assert tomllib.loads(dumps_toml(data)) == data


def test_special_floats_and_quoted_keys_round_trip():
    data = {"a": float("inf"), "b": {"x y": [-float("inf"), 1e-300, 'q"\\\n'], "t": True}}
    back = tomllib.loads(dumps_toml(data))
    assert back["a"] == float("inf") and back["b"]["x y"][0] == -float("inf")
    assert back["b"]["x y"][1:] == [1e-300, 'q"\\\n'] and back["b"]["t"] is True


def test_set_field_makes_tables_and_refuses_values():
    data = {"mpc": {"horizon": 2}}
    set_field(data, "verify.initial_set.lower", [0.0])
    assert data["verify"] == {"initial_set": {"lower": [0.0]}}
    with pytest.raises(ce.SpecError, match="mpc.horizon: is a value"):
        set_field(data, "mpc.horizon.x", 1)


def test_serial_rows_are_in_product_order_and_a_bad_value_names_its_field():
    problem = ce.load_spec(DI)
    rows = ce.sweep(problem, {"mpc.horizon": [3, 2]})
    assert [r["values"] for r in rows] == [{"mpc.horizon": 3}, {"mpc.horizon": 2}]
    assert [r["regions"] for r in rows] == [26, 10]  # as `codev synth` finds them
    assert all(r["verdict"] == "robustly_safe" and r["error"] is None for r in rows)
    assert all(r["closed_loop_cost"] > 0 and len(r["tube_width_at_horizon"]) == 2 for r in rows)
    with pytest.raises(ce.SpecError) as info:
        ce.sweep(problem, {"mpc.horizon": [2, 0]})
    assert str(info.value).endswith("[mpc.horizon = 0]: mpc.horizon: must be >= 1, got 0")


@pytest.mark.parametrize(
    "value, words",
    [
        ("mpc.horizon=2,0", "mpc.horizon: must be >= 1, got 0"),
        ("mpc.horizon=2,[", "--set mpc.horizon: not a list of TOML values"),
        ("mpc.R=[[0.1, 0.2]]", "mpc.R: "),
        ("mpc.horizn=2", "unknown field 'horizn'"),
        ("mpc.horizon", "--set: expected FIELD=V1,V2,..."),
    ],
)
def test_cli_bad_value_is_one_line_exit_2(value, words):
    out = run_codev("sweep", DI, "--set", value, cwd=ROOT)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("codev: error: "), out.stderr
    assert words in lines[0]


def test_a_session_sweep_reruns_from_the_cache_and_replays_whole(tmp_path):
    from codev_engine.session import Session
    from codev_engine.sweeps.folder import read_sweep

    problem = ce.load_spec(DI)
    grid = {"mpc.horizon": [2, 3, 2]}  # a value twice: one design, one folder
    out = tmp_path / "sweep"
    first = ce.sweep(problem, grid, session=out)
    summary = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    folders = [d["folder"] for d in summary["designs"]]
    assert folders[0] == folders[2] != folders[1] and summary["rows"] == first
    assert summary["format"] == "codev-sweep/1" and (out / "base.toml").read_text() == (
        problem.source
    )
    again = ce.sweep(problem, grid, session=out)
    assert again == first  # the recorded wall times included: nothing was recomputed
    for folder in set(folders):
        journal = Session.open(out / folder).journal()
        assert [r["status"] for r in journal if r["run"] == 2] == ["cached"] * 3
    # the sweep's own journal: one record per sweep run, each design's status in it
    runs = read_sweep(out).journal
    assert [r["run"] for r in runs] == [1, 2]
    assert [d["status"] for d in runs[0]["designs"]] == ["computed"] * 3
    assert [d["status"] for d in runs[1]["designs"]] == ["cached"] * 3
    # codev replay DIR replays the whole sweep: each design's session once, its row rebuilt
    done = run_codev("replay", out, "--json", cwd=ROOT)
    assert done.returncode == 0, done.stderr
    replayed = json.loads(done.stdout)
    assert replayed["match"] and sorted(d["folder"] for d in replayed["designs"]) == sorted(
        set(folders)
    )
    assert all(d["runs"] == 2 and d["match"] and d["row_match"] for d in replayed["designs"])
    shown = run_codev("session", out, cwd=ROOT)
    assert shown.returncode == 0 and "2 run(s)" in shown.stdout, shown.stderr
    assert "run 2 at" in shown.stdout and "3 cached" in shown.stdout


@pytest.fixture()
def sweep_dir(tmp_path):
    out = tmp_path / "sweep"
    ce.sweep(ce.load_spec(DI), {"mpc.horizon": [2, 3]}, session=out)
    return out


def test_a_sweep_is_not_written_into_a_folder_of_something_else(tmp_path):
    problem = ce.load_spec(DI)
    run_codev("run", DI, "--session", tmp_path / "design", "--quiet", cwd=ROOT)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    for folder, words in ((tmp_path / "design", "is a design's session"),
                          (other, "not a sweep (no sweep.json) and not empty")):
        with pytest.raises(ce.SpecError, match=re.escape(words)):
            ce.sweep(problem, {"mpc.horizon": [2]}, session=folder)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]


def test_replay_finds_a_row_that_is_not_the_designs(sweep_dir):
    manifest = sweep_dir / "sweep.json"
    data = json.loads(manifest.read_text())
    data["rows"][1]["regions"] += 1  # the table says what the design's session does not
    manifest.write_text(json.dumps(data))
    done = run_codev("replay", sweep_dir, "--json", cwd=ROOT)
    assert done.returncode == 1, done.stderr
    designs = json.loads(done.stdout)["designs"]
    assert [d["row_match"] for d in designs] == [True, False]
    assert [d["mismatches"] for d in designs] == [0, 0]  # the stages themselves agree


@pytest.mark.parametrize(
    "damage, words",
    [
        (lambda d: (d / "base.toml").write_text("x = 1\n"), "base.toml: the base spec was edited"),
        (lambda d: (d / "sweep.rrd").write_bytes(b"RRF2"),
         "sweep.rrd: the recording does not match its SHA-256"),
        (lambda d: (d / "sweep.json").write_text("{"), "sweep.json: unreadable sweep.json"),
        (lambda d: next(d.glob("*/specs/*.toml")).write_text("[mpc]\nhorizon = 9\n"),
         "the stored spec was edited (hash mismatch)"),
    ],
    ids=["base", "recording", "manifest", "design-spec"],
)
def test_a_damaged_sweep_is_refused_in_one_line(sweep_dir, damage, words):
    damage(sweep_dir)
    for command in ("replay", "session"):
        done = run_codev(command, sweep_dir, cwd=ROOT)
        assert done.returncode == 2, done.stderr
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and words in lines[0], done.stderr


def test_the_sweep_recording_holds_the_table_and_a_point_per_design(sweep_dir):
    from rerun.chunk import RrdReader

    rows = json.loads((sweep_dir / "sweep.json").read_text())["rows"]
    texts: dict[str, list[str]] = {}
    points: dict[str, list[float]] = {}
    for chunk in RrdReader(sweep_dir / "sweep.rrd").stream().to_chunks():
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if name.endswith("TextDocument:text"):
                texts.setdefault(chunk.entity_path, []).extend(
                    t for v in rb.column(name).to_pylist() for t in (v or []))
            if name.endswith("Scalars:scalars"):
                points.setdefault(chunk.entity_path, []).extend(
                    x for v in rb.column(name).to_pylist() for x in (v or []))
    table = texts["/sweep/table"][0]
    assert table.startswith("# double-integrator: 2 designs\n")
    for i, row in enumerate(rows):
        assert f"| {i} | {row['values']['mpc.horizon']} | {row['regions']} | " \
            f"{row['verdict']} |" in table
    assert len(texts["/sweep/design"]) == 2  # one per design, on the design timeline
    assert points["/sweep/regions/robustly_safe"] == [r["regions"] for r in rows]


# -- a real cluster ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def serial_rows():
    return ce.sweep(ce.load_spec(DI), GRID)


def test_cluster_rows_equal_serial_rows(cluster, serial_rows, tmp_path):
    rows = ce.sweep(ce.load_spec(DI), GRID, executor=cluster)
    assert exact(rows) == exact(serial_rows)
    # in session folders too (the workers write them; the client writes sweep.json)
    rows = ce.sweep(ce.load_spec(DI), GRID, executor=cluster, session=tmp_path / "s")
    assert exact(rows) == exact(serial_rows)
    assert len(json.loads((tmp_path / "s" / "sweep.json").read_text())["designs"]) == 8
    from codev_engine.sweeps.folder import read_sweep, replay_sweep

    run = read_sweep(tmp_path / "s").journal[-1]  # the sweep's journal names its executor
    assert (run["executor"], run["workers"]) == ("local", 2)
    assert replay_sweep(tmp_path / "s").ok  # (the workers wrote the designs' sessions)
    # both workers took part (the merge order is not the order of arrival)
    ran_on = cluster.client.run(os.getpid)
    assert len(set(ran_on.values())) == 2


def test_a_worker_killed_mid_sweep_changes_nothing(cluster, serial_rows):
    client = cluster.client
    before = client.run(os.getpid)  # worker address -> its process id
    killed: list[tuple[str, int, int]] = []
    stop = threading.Event()

    def kill_a_busy_worker() -> None:
        # from the sweep's start, not after its first row: under load the 8 short designs
        # (~0.05 s each) could all be done before the client saw the first row, leaving
        # no worker with a task to lose
        while not stop.is_set() and not killed:
            for address, keys in client.processing().items():
                if keys:  # this worker holds tasks not finished yet
                    os.kill(before[address], signal.SIGKILL)
                    killed.append((address, before[address], len(keys)))
                    return
            time.sleep(0.005)

    killer = threading.Thread(target=kill_a_busy_worker, daemon=True)
    killer.start()
    try:
        rows = ce.sweep(ce.load_spec(DI), GRID, executor=cluster)
    finally:
        stop.set()
        killer.join(30)
    assert killed, "no worker held a task while the sweep ran"
    assert exact(rows) == exact(serial_rows)  # each design once, in its place
    # the process was really gone: the nanny started a new one in its place
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        after = client.run(os.getpid)
        if len(after) == 2 and killed[0][1] not in after.values():
            break
        time.sleep(0.2)
    assert killed[0][1] not in client.run(os.getpid).values()


def _span(seconds: float) -> tuple[float, float, int]:
    """A task (on a worker): when it started and ended (the system's monotonic clock), and
    the worker process that ran it."""
    t0 = time.monotonic()
    time.sleep(seconds)
    return t0, time.monotonic(), os.getpid()


def test_the_costliest_calls_start_first_on_a_cluster(cluster):
    # 4 calls on 2 workers, given cheapest first: one of the two costliest starts first (in
    # the order given, the cheapest went first): each worker holds one of them and starts
    # with the costliest it holds. No more of the order: on a loaded machine a worker
    # process may wait ~1 s before its first call, and the other, idle, steals its queued
    # calls in any order, so a worker may run call 0 before a call 1 it stole afterwards
    # (seen on a CI machine), or the costliest may start last
    spans = cluster.map(_span, [(0.3,)] * 4, cost=[1.0, 2.0, 3.0, 4.0])
    started = [i for _, i in sorted((t0, i) for i, (t0, _, _) in enumerate(spans))]
    assert started[0] in (2, 3), spans
    with pytest.raises(ValueError, match="2 values for 4 calls"):
        cluster.map(_span, [(0.0,)] * 4, cost=[1.0, 2.0])


def test_the_designs_cost_grows_with_the_horizon():
    from codev_engine.sweeps import design_cost
    from codev_engine.sweeps.grid import designs

    costs = [design_cost(p) for _, p in designs(ce.load_spec(DI), {"mpc.horizon": [2, 5, 8]})]
    assert costs == sorted(costs) and len(set(costs)) == 3


def test_a_spec_error_travels_whole():
    # a worker's SpecError comes back through pickle with its file and field
    import pickle

    from codev_engine.session.store import SessionError

    for cls in (ce.SpecError, SessionError):
        err = pickle.loads(pickle.dumps(cls("must be >= 1", file="a.toml", field="mpc.horizon")))
        assert type(err) is cls and (err.file, err.field) == ("a.toml", "mpc.horizon")
        assert str(err) == "a.toml: mpc.horizon: must be >= 1"


def test_the_executor_keeps_the_input_order_and_refuses_two_targets():
    assert ce.Executor().map(divmod, [(7, 2), (9, 4)]) == [(3, 1), (2, 1)]
    with pytest.raises(ValueError, match="not both"):
        ce.Executor(workers=2, scheduler="tcp://127.0.0.1:1")


def test_numpy_values_are_toml_values_and_a_bad_one_names_its_field():
    import numpy as np

    problem = ce.load_spec(DI)
    rows = ce.sweep(problem, {"mpc.horizon": [np.int64(2)], "mpc.R": [np.array([[0.8]])]})
    assert rows[0]["regions"] == 10
    with pytest.raises(ce.SpecError, match="mpc.R: not a TOML value: object"):
        ce.sweep(problem, {"mpc.R": [object()]})


def test_the_sweep_figure_has_a_bar_per_design_coloured_by_verdict(serial_rows):
    from matplotlib.colors import to_hex

    from codev_engine.view.figures import VERDICT_COLOURS, plot_sweep

    ax = plot_sweep(serial_rows)
    bars = ax.patches
    assert len(bars) == len(serial_rows) == 8
    for bar, row in zip(bars, serial_rows, strict=True):
        assert bar.get_height() == row["regions"]
        assert to_hex(bar.get_facecolor()) == VERDICT_COLOURS[row["verdict"]]
    labels = [t.get_text() for t in ax.get_xticklabels()]
    assert all("mpc.horizon = " in t and "mpc.R = " in t for t in labels)


def test_design_texts_are_compact_and_ascii_only():
    """The sweep's design text stays compact and ASCII-only (its hash names the design's
    folder, so its layout must not change), reads back equal, and a raw DEL is escaped
    (TOML forbids it in a string; JSON, whose escapes the writer uses, does not)."""
    data = {"name": "Pendel \u00fc\x7f",
            "verify": {"initial_set": {"lower": [0.5], "upper": [1.0]}},
            "mpc": {"constraints": [{"h": [1.0]}, {"h": [2.0]}]}}
    text = dumps_toml(data)
    assert 'name = "Pendel \\u00fc\\u007f"' in text
    assert "initial_set = {lower = [0.5], upper = [1.0]}" in text
    assert "constraints = [{h = [1.0]}, {h = [2.0]}]" in text
    assert tomllib.loads(text) == data


class _StopError(Exception):
    pass


@pytest.mark.parametrize("session", [False, True])
def test_interrupt_stops_the_design_that_runs(tmp_path, session):
    """Issue 41: the sweep's interrupt is called inside the running design (its synthesis
    and verification progress), not only between designs: raising there stops the design
    at once, and the exception reaches the caller."""
    problem = ce.load_spec(DI)
    calls = []

    def interrupt() -> None:
        calls.append(1)
        if len(calls) == 3:  # the first design's third progress event: mid-design
            raise _StopError

    rows = []
    with pytest.raises(_StopError):
        ce.sweep(problem, {"mpc.horizon": [4, 5]}, interrupt=interrupt,
                 progress=lambda i, row: rows.append(i),
                 session=tmp_path / "sweep" if session else None)
    assert rows == []  # stopped inside the first design, before it finished
    if session:  # the sweep's table is not written (its designs' caches may be)
        assert not (tmp_path / "sweep" / "sweep.json").exists()
