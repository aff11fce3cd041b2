"""A worker's result that arrives while the app closes is dropped, never applied to widgets
already pruned (CI saw ``WorkerFailed: NoMatches('#regions')`` when a test quit while the
region table was being filled)."""

from __future__ import annotations

import asyncio
import threading
import time

from pilot_tools import EXAMPLES, SIZE, run, settle

from workbench.tui.app import CodevApp
from workbench.tui.panes import synthesis
from workbench.tui.state import open_target


def test_a_region_table_ready_while_the_app_closes_is_dropped(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))
    real_rows = synthesis.region_rows
    handed = threading.Event()
    pane = None

    def rows_once_the_table_is_gone(law):
        # the real rows, handed over once closing has pruned the table (the pane is next)
        rows = real_rows(law)
        end = time.monotonic() + 30
        while pane.query("#regions") and time.monotonic() < end:
            time.sleep(0.001)
        handed.set()
        return rows

    async def slow_unmount(self) -> None:
        # the window CI hit by chance, held open: the loop still runs the app (and the
        # worker's hand-over) while the pane, its children gone, unmounts
        await asyncio.sleep(0.5)

    async def scenario():
        nonlocal pane
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app, timeout=120)
            assert app.law is not None
            monkeypatch.setattr(synthesis, "region_rows", rows_once_the_table_is_gone)
            monkeypatch.setattr(synthesis.SynthesisPane, "on_unmount", slow_unmount,
                                raising=False)
            pane = app.query_one("SynthesisPane")
            pane.refresh_law(force=True)
            await pilot.pause(0.05)

    run(scenario())  # raised WorkerFailed(NoMatches('#regions')) before the hand-over's guard
    assert handed.is_set()
