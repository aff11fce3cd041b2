"""Quitting while a thread worker has not reached the widgets yet: a worker never looks the
DOM up from its thread. A thread worker may start late (the event loop's executor has few
threads, the other workers hold them), after a quit began pruning the panes; a DOM query
made there raised ``NoMatches`` inside the worker and ended the app with ``WorkerFailed``,
as the region table did in CI (tests/workbench/test_handoff.py)."""

from __future__ import annotations

import asyncio
import threading
import time

from pilot_tools import EXAMPLES, SIZE, run, settle
from textual.widgets import TabPane

from codev_engine.session import Session
from workbench.tui import app as app_module
from workbench.tui.app import CodevApp
from workbench.tui.panes.sweep import SweepPane
from workbench.tui.state import open_target


def test_a_sweep_thread_that_starts_after_the_quit_began_leaves_the_app_cleanly(
    tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))
    started = threading.Event()

    def start_once_the_pane_is_gone(*args, **kwargs) -> None:
        # the sweep's thread, held at its first line until quitting has removed the Sweep
        # pane (the order CI's load can give by chance)
        end = time.monotonic() + 30
        while app.query(SweepPane) and time.monotonic() < end:
            time.sleep(0.001)
        started.set()

    async def slow_unmount(self) -> None:
        # the window held open: the app's loop still runs its workers while the tabs unmount
        await asyncio.sleep(0.5)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            monkeypatch.setattr(app_module, "_lower_priority", start_once_the_pane_is_gone)
            monkeypatch.setattr(TabPane, "on_unmount", slow_unmount, raising=False)
            app.run_sweep("mpc.horizon=2")
            assert app.busy == "sweep"

    run(scenario())  # raised WorkerFailed(NoMatches(SweepPane)) with the pane found in the thread
    assert started.is_set()


def test_quitting_while_a_synthesis_runs_cancels_it(tmp_path, monkeypatch):
    """A thread cannot be stopped and the event loop waits for it before the app exits: a
    quit mid-synthesis waited for the whole search (and cached its law). The run is
    cancelled instead, at its next progress event: nothing is journaled or cached for it."""
    monkeypatch.chdir(tmp_path)
    # the magnetic pointer with horizon 6: ~3800 regions, seconds of work (test_app's cancel)
    text = (EXAMPLES / "magnetic_pointer_a.toml").read_text().replace("horizon = 4",
                                                                       "horizon = 6")
    assert "horizon = 6" in text
    spec = tmp_path / "pointer_n6.toml"
    spec.write_text(text)
    app = CodevApp(open_target(str(spec), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            app.run_stage("synthesis")
            loop = asyncio.get_running_loop()
            end = loop.time() + 60
            while loop.time() < end and not (app.progress and app.progress[1] > 0):
                await asyncio.sleep(0.005)
            assert app.busy == "synthesis", [n.message for n in app._notifications]
        # (quit here, mid-search)

    run(scenario())
    session = Session.open(tmp_path / "s")
    assert not any(r["stage"] == "synthesis" for r in session.journal())
    assert not list((tmp_path / "s" / "artifacts").glob("synthesis-*"))


def test_the_progress_tick_while_the_app_quits_touches_no_widget(tmp_path, monkeypatch):
    """The 10 Hz tick shows a running stage's progress on the panes' status lines; it fires
    on while a quit prunes the panes (the app's timers stop last). It looked for the
    ``#pipeline`` line to tell: still up (a slow unmount holds it, as a loaded machine can),
    the status lines already gone raised ``NoMatches``."""
    import time as clock

    from textual.widgets import Static

    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))

    async def slow_pipeline_unmount(self) -> None:
        if self.id == "pipeline":
            await asyncio.sleep(0.5)  # 5 ticks while the panes go

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            monkeypatch.setattr(Static, "on_unmount", slow_pipeline_unmount, raising=False)
            # a stage running as the quit comes (its counters only: no thread needed)
            app.busy, app.progress = "synthesis", ("synthesis", 7, clock.perf_counter())
            await pilot.pause(0.15)
            assert "7 regions" in str(app.query_one("#synth-status", Static).render())

    run(scenario())  # raised NoMatches from _tick with the guard on #pipeline


def test_a_pane_s_request_the_app_takes_while_it_quits_is_dropped(tmp_path, monkeypatch):
    """The app's own queue closes last, after the panes: a request a pane posted just before
    the quit (a button, ctrl+g) is taken while they are pruned, and its handler found no
    pane (``NoMatches``); it is dropped, as a worker's late result is."""
    from workbench.tui.messages import LawExportRequested

    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))
    posted = threading.Event()

    async def request_as_the_tab_goes(self) -> None:
        # the Synthesis tab's pane is gone, the tab not yet: its export request comes now
        if self.id == "synthesis":
            posted.set()
            self.app.post_message(LawExportRequested("law_c"))
            await asyncio.sleep(0.5)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            monkeypatch.setattr(TabPane, "on_unmount", request_as_the_tab_goes, raising=False)

    run(scenario())  # raised NoMatches(SynthesisPane) from on_law_export_requested before
    assert posted.is_set()
