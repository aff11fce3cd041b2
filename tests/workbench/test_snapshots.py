"""Screen snapshots of the workbench, one per stage screen (pytest-textual-snapshot).

The SVGs live in ``__snapshots__/``; after an intended change of a screen, look at the
report and run ``pytest tests/workbench/test_snapshots.py --snapshot-update``. Screens are
taken on sessions under a relative path (``sessions/...``) and after the notifications
are cleared, so no temporary path or timing reaches a picture.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from pilot_tools import EXAMPLES, ROOT, settle
from textual.widgets import DataTable, Input, Static, TabbedContent

from workbench.tui.app import CodevApp
from workbench.tui.state import open_target
from workbench.tui.widgets import Plot

SIZE = (150, 44)


@pytest.fixture(autouse=True)
def _plain_environment(monkeypatch):
    """Screens must not depend on the terminal settings of the machine running the tests
    (NO_COLOR drops every colour from the SVG; COLUMNS/LINES are ignored for the explicit
    size but dropped too, for safety)."""
    for var in ("NO_COLOR", "COLUMNS", "LINES", "TEXTUAL_THEME"):
        monkeypatch.delenv(var, raising=False)


@pytest.fixture
def di_app(tmp_path, monkeypatch) -> CodevApp:
    monkeypatch.chdir(tmp_path)
    return CodevApp(
        open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="sessions/di")
    )


def _steps(*keys: str):
    async def run_before(pilot) -> None:
        app = pilot.app
        await settle(pilot, app)
        for key in keys:
            if key == "go":
                app.action_go()  # ctrl+g, without the pilot's idle wait on busy workers
            else:
                await pilot.press(key)
            await settle(pilot, app)
        app.clear_notifications()
        # what changes from run to run is fixed: the cursor's blink (the focus is in a
        # field on every tab), the seconds of the synthesis and the verification
        for w in app.query(Input):
            w.cursor_blink = False
        if app.law is not None:
            app.law.meta["seconds"] = 0.5
        if app.result is not None:
            app.result.stats["seconds"] = 0.5
        app._show_results()
        status = app.query_one("#verify-status", Static)
        if "computed in" in str(status.render()):
            status.update("computed in 0.50 s")
        await pilot.pause(0.1)
        # the region table is filled by a worker: wait for its rows (under load, and on
        # two test processes, the picture was taken between the rows and their widths)
        if app.law is not None:
            regions = app.query_one("#regions", DataTable)
            for _ in range(200):
                if regions.row_count >= app.law.num_regions:
                    break
                await pilot.pause(0.05)
        await _pictures_up(pilot, app)
        # a DataTable sizes its columns on a later refresh: under load the picture was
        # taken before (the region table's columns came out narrower, one run in three)
        # (and once again in a two-process CI run: so also wait until the table's scrollable
        # width is that of its columns, then for the app to be idle, so the repaint is done)
        def sized(t: DataTable) -> bool:
            if t._require_update_dimensions or t._new_rows or t._updated_cells:
                return False
            width = sum(c.get_render_width(t) for c in t.ordered_columns)
            if t._labelled_row_exists or t.show_row_labels and t._label_column.content_width:
                width += t._label_column.get_render_width(t)
            return t.virtual_size.width == width

        for _ in range(100):
            if all(sized(t) for t in app.query(DataTable)):
                break
            await pilot.pause(0.05)
        # and still, under load, a table's lines rendered before its widths were measured
        # stayed in its line cache (the widths right, the picture narrow, 3 runs in 6 at
        # load 3): drop the caches so the picture is drawn from the measured widths
        for t in app.query(DataTable):
            t._clear_caches()
            t.refresh()
        await pilot.pause()
        await pilot.pause(0.1)
        await _pictures_up(pilot, app)

    return run_before


async def _pictures_up(pilot, app: CodevApp) -> None:
    """Wait until each plot on screen shows the picture for its size as laid out now.

    The pictures are drawn in threads, again after each resize, and the resize comes after
    the layout that follows a run's end (a verification screen, under load on two test
    processes, was taken with the reachtube drawn for the taller plot before the verdict's
    lines were written: the settle had seen no worker running in between).
    """
    shown = app.query_one("#tabs", TabbedContent).active_pane
    for _ in range(1200):
        if shown is None or all(p.up_to_date for p in shown.query(Plot)):
            await pilot.pause()  # (and painted)
            return
        await pilot.pause(0.05)
    raise AssertionError("a plot's picture for its current size is not up in 60 s")


def test_plant_screen(di_app, snap_compare):
    assert snap_compare(di_app, terminal_size=SIZE, run_before=_steps())


def test_mpc_screen_with_preview(di_app, snap_compare):
    assert snap_compare(di_app, terminal_size=SIZE, run_before=_steps("f2", "go"))


def test_synthesis_screen(di_app, snap_compare):
    assert snap_compare(di_app, terminal_size=SIZE, run_before=_steps("f3", "go"))


def test_verification_screen(di_app, snap_compare):
    assert snap_compare(di_app, terminal_size=SIZE, run_before=_steps("f4", "go"))


def test_session_screen(tmp_path, monkeypatch, snap_compare):
    """The bundled session as committed: its journal (fixed timings), nothing cached yet."""
    monkeypatch.chdir(tmp_path)
    shutil.copytree(
        ROOT / "sessions" / "double-integrator",
        Path("sessions/double-integrator"),
        ignore=shutil.ignore_patterns("artifacts", "tui-draft.json"),
    )
    app = CodevApp(open_target("sessions/double-integrator"))
    assert snap_compare(app, terminal_size=SIZE, run_before=_steps("f5"))
