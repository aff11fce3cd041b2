"""The Sweep tab (F6), driven through the real app: a grid typed, the designs × outcomes
table filled as they finish, the sweep saved as one session in ``<session>/sweep`` and shown
again when the design is opened later; a bad value is one line naming the field."""

from __future__ import annotations

import json

import pytest
from pilot_tools import EXAMPLES, SIZE, run, settle, text_of
from textual.widgets import Input

from codev_engine.sweeps.folder import read_sweep, replay_sweep
from workbench.tui.app import CodevApp
from workbench.tui.panes.sweep import SweepPane
from workbench.tui.state import open_target

KEYS = {"=": "equals_sign", "[": "left_square_bracket", "]": "right_square_bracket",
        ";": "semicolon", ",": "comma", ".": "full_stop", " ": "space"}


async def type_grid(pilot, app: CodevApp, text: str) -> None:
    editor = app.query_one("#sweep-grid", Input)
    assert app.focused is editor  # F6 puts the focus on the grid
    await pilot.press("end", *["backspace"] * (len(editor.value) + 2))
    await pilot.press(*[KEYS.get(c, c) for c in text])


@pytest.fixture
def di_session(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="sessions/di")


@pytest.mark.slow
def test_sweep_tab_runs_a_grid_and_shows_designs_by_outcomes(di_session, tmp_path):
    app = CodevApp(di_session)
    folder = tmp_path / "sessions" / "di" / "sweep"

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f6")
            await type_grid(pilot, app, "mpc.horizon=2,3; mpc.R=[[1.0]]")
            await pilot.press("ctrl+g")
            await settle(pilot, app, timeout=120)
            pane = app.query_one(SweepPane)
            rows = pane.rows()
            assert [r[:4] for r in rows] == [
                ["2", "[[1]]", "10", "robustly_safe"],
                ["3", "[[1]]", "22", "robustly_safe"],
            ]
            assert "2 designs in" in text_of(app, "#sweep-status")
            assert "2 robustly_safe" in text_of(app, "#sweep-status")
            assert "saved in sessions/di/sweep" in text_of(app, "#sweep-status")  # issue 41
            assert "replay sessions/di/sweep" in text_of(app, "#sweep-out")

            # a bad value: one line naming the field, nothing runs, the table stays
            await type_grid(pilot, app, "mpc.horizon=2,0")
            await pilot.press("ctrl+g")
            await settle(pilot, app)
            shown = [n.message for n in app._notifications]
            assert any("mpc.horizon: must be >= 1, got 0" in m for m in shown), shown
            assert len(pane.rows()) == 2

    run(scenario())
    # the sweep is one session: its manifest and files check, and it replays
    recorded = read_sweep(folder)
    assert [r["regions"] for r in recorded.rows] == [10, 22]
    assert recorded.recording is not None and len(recorded.journal) == 1
    assert replay_sweep(folder).ok
    assert json.loads((folder / "sweep.json").read_text())["grid"] == {
        "mpc.horizon": [2, 3], "mpc.R": [[[1.0]]]}

    # opened again later: the recorded sweep is on the tab, its grid in the entry
    again = CodevApp(open_target(str(tmp_path / "sessions" / "di")))

    async def reopened():
        async with again.run_test(size=SIZE) as pilot:
            await settle(pilot, again)
            await pilot.press("f6")
            pane = again.query_one(SweepPane)
            assert [r[2] for r in pane.rows()] == ["10", "22"]
            assert "recorded sweep: 2 designs (1 run(s))" in text_of(again, "#sweep-status")
            assert pane.grid_text() == "mpc.horizon=2, 3; mpc.R=[[1.0]]"

    run(reopened())


def test_a_bad_workers_value_is_one_line_and_nothing_runs(di_session):
    app = CodevApp(di_session)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f6")
            await type_grid(pilot, app, "mpc.horizon=2,3")
            app.query_one("#sweep-workers", Input).value = "0"
            await pilot.press("ctrl+g")
            await settle(pilot, app)
            shown = [n.message for n in app._notifications]
            assert any("workers: must be a positive whole number" in m and "'0'" in m
                       for m in shown), shown
            assert app.busy is None and app.query_one(SweepPane).rows() == []

    run(scenario())


@pytest.mark.slow
def test_sweep_tab_on_two_local_workers_gives_the_serial_rows(di_session, tmp_path):
    """The workers field runs the designs on a real local Dask cluster: the same rows."""
    app = CodevApp(di_session)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f6")
            await type_grid(pilot, app, "mpc.horizon=2,3; mpc.R=[[1.0]]")
            app.query_one("#sweep-workers", Input).value = "2"
            await pilot.press("ctrl+g")
            await settle(pilot, app, timeout=180)
            rows = app.query_one(SweepPane).rows()
            assert [r[:4] for r in rows] == [
                ["2", "[[1]]", "10", "robustly_safe"],
                ["3", "[[1]]", "22", "robustly_safe"],
            ]
            assert "2 designs in" in text_of(app, "#sweep-status")

    run(scenario())
    recorded = read_sweep(tmp_path / "sessions" / "di" / "sweep")
    assert recorded.journal[-1].get("workers") == 2, recorded.journal[-1]
