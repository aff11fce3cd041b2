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
import signal
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

    problem = ce.load_spec(DI)
    grid = {"mpc.horizon": [2, 3, 2]}  # a value twice: one design, one folder
    out = tmp_path / "sweep"
    first = ce.sweep(problem, grid, session=out)
    summary = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    folders = [d["folder"] for d in summary["designs"]]
    assert folders[0] == folders[2] != folders[1] and summary["rows"] == first
    again = ce.sweep(problem, grid, session=out)
    assert again == first  # the recorded wall times included: nothing was recomputed
    for folder in set(folders):
        journal = Session.open(out / folder).journal()
        assert [r["status"] for r in journal if r["run"] == 2] == ["cached"] * 3
    # codev replay DIR replays the whole sweep: each design's session once
    done = run_codev("replay", out, "--json", cwd=ROOT)
    assert done.returncode == 0, done.stderr
    replayed = json.loads(done.stdout)
    assert replayed["match"] and sorted(d["folder"] for d in replayed["designs"]) == sorted(
        set(folders)
    )
    assert all(d["runs"] == 2 and d["match"] for d in replayed["designs"])


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
    # both workers took part (the merge order is not the order of arrival)
    ran_on = cluster.client.run(os.getpid)
    assert len(set(ran_on.values())) == 2


def test_a_worker_killed_mid_sweep_changes_nothing(cluster, serial_rows):
    client = cluster.client
    before = client.run(os.getpid)  # worker address -> its process id
    killed: list[tuple[str, int, int]] = []

    def kill_a_busy_worker(i, row):
        if killed:
            return
        for address, keys in client.processing().items():
            if keys:  # this worker holds tasks not finished yet
                os.kill(before[address], signal.SIGKILL)
                killed.append((address, before[address], len(keys)))
                return

    rows = ce.sweep(ce.load_spec(DI), GRID, executor=cluster, progress=kill_a_busy_worker)
    assert killed, "no worker had tasks left after the first design"
    assert exact(rows) == exact(serial_rows)  # each design once, in its place
    # the process was really gone: the nanny started a new one in its place
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        after = client.run(os.getpid)
        if len(after) == 2 and killed[0][1] not in after.values():
            break
        time.sleep(0.2)
    assert killed[0][1] not in client.run(os.getpid).values()


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
