"""The workbench driven through its UI (Textual's Pilot): a complete design session.

Each test starts the real app on a real session folder, presses the keys a user would, and
checks both the screen and the session folder (spec, journal, artifacts, replay).
"""

from __future__ import annotations

import asyncio
import shutil
import tomllib

import numpy as np
import pytest
from pilot_tools import EXAMPLES, ROOT, SIZE, entry, run, settle, text_of, type_into
from textual.widgets import DataTable, Input, Static

from codev_engine import load_spec
from codev_engine.session import Session
from workbench.tui.app import CodevApp
from workbench.tui.panes.plant import PlantPane
from workbench.tui.state import DRAFT, open_target


@pytest.fixture
def di_session(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="sessions/di")


def test_complete_design_session(di_session, tmp_path):
    """Load the double integrator, synthesise, change Q (stale), re-synthesise, verify, save."""
    app = CodevApp(di_session)
    folder = tmp_path / "sessions" / "di"

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            assert "synthesis missing" in text_of(app, "#pipeline")
            # plant screen: the derived model is shown
            assert "controllability rank 2 of 2" in app.query_one(PlantPane).report_text

            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            assert app.law is not None and app.law.num_regions == 10
            assert "10 critical regions" in text_of(app, "#synth-status")
            assert "current" in text_of(app, "#synth-status")

            # change Q on the MPC screen: synthesis (and what follows) becomes stale
            await pilot.press("f2")
            await type_into(pilot, app, "mpc.Q", "1 1; 0 2")
            await settle(pilot, app)
            assert app.check is not None and app.check.ok
            assert "synthesis stale" in text_of(app, "#pipeline")
            assert "model cached" in text_of(app, "#pipeline")
            await pilot.press("f3")
            await settle(pilot, app)
            assert "stale" in text_of(app, "#synth-status")

            await pilot.press("ctrl+g")
            await settle(pilot, app)
            assert "current" in text_of(app, "#synth-status")
            # locate a state through the side panel
            app.query_one("#locate-x", Input).focus()
            await pilot.press(*"9", "comma", "minus", "5", "enter")
            await pilot.pause(0.1)
            out = text_of(app, "#locate-out")
            k = app.law.locate(np.array([[9.0, -5.0]]))[0]
            assert f"region {k}" in out and "u = " in out

            await pilot.press("f4", "ctrl+g")
            await settle(pilot, app)
            assert app.result is not None, [n.message for n in app._notifications]
            banner = text_of(app, "#verdict")
            assert "ROBUSTLY SAFE" in banner
            assert app.query_one("#verdict").has_class("-safe")

            await pilot.press("ctrl+s")
            await settle(pilot, app)
            # the Session screen's journal shows every record of this session's runs
            await pilot.press("f5")
            await settle(pilot, app)
            rows = app.query_one("#journal", DataTable).row_count
            assert rows == len(Session.open(folder).journal()) >= 7
            await pilot.press("ctrl+q")

    run(scenario())
    # the session folder holds the edited spec, the journal of every stage, and replays
    spec = load_spec(folder / "spec.toml")
    assert spec.mpc.Q.tolist() == [[1.0, 1.0], [0.0, 2.0]]
    session = Session.open(folder)
    journal = session.journal()
    synth = [r for r in journal if r["stage"] == "synthesis" and r["status"] == "computed"]
    assert len({r["key"] for r in synth}) == 2
    assert any(
        r["stage"] == "verification" and r["outcome"]["verdict"] == "robustly_safe" for r in journal
    )
    assert (folder / "specs").is_dir() and len(list((folder / "specs").glob("*.toml"))) >= 2
    replay = session.replay()
    assert replay.ok and replay.checked == len(journal)


def test_inline_errors_and_draft(di_session, tmp_path):
    """A bad entry is marked next to the field, kept as a draft, and never crashes the app."""
    app = CodevApp(di_session)
    folder = tmp_path / "sessions" / "di"

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f2")
            await type_into(pilot, app, "mpc.Q", "1 1; 0")
            await settle(pilot, app)
            q = entry(app, "mpc.Q")
            assert q.has_class("-error")
            assert "different lengths" in str(q.query_one(".help", Static).render())
            assert "spec not valid" in text_of(app, "#pipeline")
            assert (folder / DRAFT).is_file()
            # a stage cannot run on an invalid spec: a message, not a crash
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            assert app.law is None
            # a name the dynamics do not know, in the plant screen's text area
            await pilot.press("f1")
            await settle(pilot, app)
            await pilot.press("f2")
            await type_into(pilot, app, "mpc.Q", "1 1; 0 1")
            await settle(pilot, app)
            assert not entry(app, "mpc.Q").has_class("-error")
            assert not (folder / DRAFT).exists()
            await type_into(pilot, app, "model.sample_time", "-1")
            await settle(pilot, app)
            assert entry(app, "model.sample_time").has_class("-error")
            assert "once the fields marked in red are fixed" in app.query_one(PlantPane).report_text
            # back to the spec whose report was shown before: the report comes back
            await type_into(pilot, app, "model.sample_time", "1.0")
            await settle(pilot, app)
            assert app.check.ok
            assert "controllability rank 2 of 2" in app.query_one(PlantPane).report_text

    run(scenario())


def test_draft_restored_after_a_crash(di_session, tmp_path):
    """Entries typed but not valid yet survive the app's death (the draft is on disk)."""
    app = CodevApp(di_session)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f2")
            await type_into(pilot, app, "mpc.R", "0.8 x")
            await settle(pilot, app)

    run(scenario())  # the app is gone without a save
    reopened = open_target(str(tmp_path / "sessions" / "di"))
    assert reopened.values["mpc.R"] == "0.8 x"
    assert "restored" in (reopened.note or "")


def test_cancel_a_synthesis(tmp_path, monkeypatch):
    """Esc stops a running synthesis: nothing is cached or journaled as computed for it."""
    monkeypatch.chdir(tmp_path)
    # the magnetic pointer with horizon 6: ~3800 regions, seconds of work even on a fast
    # machine, so the cancel lands mid-search however loaded the machine is
    text = (EXAMPLES / "magnetic_pointer_a.toml").read_text()
    text = text.replace("horizon = 4", "horizon = 6")
    assert "horizon = 6" in text
    spec = tmp_path / "pointer_n6.toml"
    spec.write_text(text)
    opened = open_target(str(spec), session_dir="s")
    app = CodevApp(opened)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f3")
            # Pilot.press waits for the process to go idle, which it does not while the
            # engine works: start the run as ctrl+g does, then watch without the pilot
            app.action_go()
            loop = asyncio.get_running_loop()
            end = loop.time() + 30
            while loop.time() < end and not (app.progress and app.progress[1] > 0):
                await asyncio.sleep(0.005)
            assert app.busy == "synthesis", [n.message for n in app._notifications]
            await pilot.press("escape")
            await settle(pilot, app)
            assert app.law is None
            assert "cancelled" in text_of(app, "#synth-status")

    run(scenario())
    session = Session.open(tmp_path / "s")
    assert not any(r["stage"] == "synthesis" for r in session.journal())
    assert not list((tmp_path / "s" / "artifacts").glob("synthesis-*"))


def test_unsafe_verdict_shows_the_counterexample(tmp_path, monkeypatch):
    """An unsafe spec: red banner, counterexample text, and the trace in the plots."""
    monkeypatch.chdir(tmp_path)
    text = (EXAMPLES / "double_integrator.toml").read_text()
    text += "\n[[verify.unsafe]]\nlower = [4.0, -10.0]\nupper = [6.0, 0.0]\n"
    spec = tmp_path / "di_unsafe.toml"
    spec.write_text(text)
    app = CodevApp(open_target(str(spec), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f4", "ctrl+g")
            await settle(pilot, app)
            assert app.result is not None and app.result.verdict == "unsafe"
            assert "UNSAFE" in text_of(app, "#verdict")
            assert app.query_one("#verdict").has_class("-unsafe")
            assert "counterexample" in text_of(app, "#cex")

    run(scenario())


def test_open_and_export_recording(tmp_path, monkeypatch):
    """The Session screen opens a copy of the bundled session and exports its recording."""
    monkeypatch.chdir(tmp_path)
    src = ROOT / "sessions" / "double-integrator"
    dst = tmp_path / "bundled"
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("artifacts", "tui-draft.json"))
    first = open_target(str(EXAMPLES / "pendulum.toml"), session_dir="other")
    app = CodevApp(first)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f5")
            app.query_one("#open-path", Input).focus()
            await pilot.press(*str(dst).replace("/", "/"))
            await pilot.press("enter")
            await settle(pilot, app)
            assert app.session.path == dst
            assert entry(app, "name").text == "double-integrator"
            app.query_one("#export-path", Input).value = str(tmp_path / "out.rrd")
            await pilot.press("ctrl+g")
            await settle(pilot, app, timeout=120)
            out = text_of(app, "#export-out")
            assert "codev view" in out and "out.rrd" in out

    run(scenario())
    assert (tmp_path / "out.rrd").stat().st_size > 0
    from codev_engine.view.records import check_recording

    check_recording(tmp_path / "out.rrd")
    # the journal of the opened session grew by this run, and still replays
    session = Session.open(dst)
    assert session.replay().ok
    assert tomllib.loads((dst / "spec.toml").read_text())["name"] == "double-integrator"


def test_tui_without_a_terminal_is_a_clear_error(tmp_path):
    """`codev tui` in a pipe: one line, exit status 2, and no session folder created."""
    import subprocess
    import sys

    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "workbench.cli",
            "tui",
            str(EXAMPLES / "double_integrator.toml"),
            "--session",
            str(tmp_path / "s"),
        ],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 2
    assert "needs a terminal" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_a_late_picture_does_not_replace_the_latest():
    """Plots draw in threads that cannot be stopped: a picture asked for earlier (an older
    size, an older drawing) that finishes last must not stay up."""
    import threading

    from rich.text import Text
    from textual.app import App

    from workbench.tui.app import STYLESHEET
    from workbench.tui.widgets import Plot

    class Seen(Plot):
        """The plot, noting each picture handed back to the app (shown or not)."""

        handed: list[str] = []

        def _show(self, request: int, text: Text) -> None:
            super()._show(request, text)
            self.handed.append(str(text))

    class One(App):
        CSS_PATH = STYLESHEET  # the plot's size

        def compose(self):
            yield Seen(id="plot")

    release, started = threading.Event(), threading.Event()

    def old(w, h):
        started.set()
        release.wait(60)
        return Text("old picture")

    async def scenario():
        app = One()
        async with app.run_test(size=(60, 20)) as pilot:

            async def until(ok, what: str) -> None:  # conditions, not pauses: under load
                end = asyncio.get_running_loop().time() + 60  # a thread may wait seconds
                while not ok():
                    assert asyncio.get_running_loop().time() < end, f"no {what} in 60 s"
                    await pilot.pause(0.02)

            plot = app.query_one(Seen)
            await until(lambda: plot.content_size.width >= 12, "layout")  # (drawn from 12)
            plot.set_draw(old)
            await until(started.is_set, "start of the old drawing")
            plot.set_draw(lambda w, h: Text("new picture"))
            await until(lambda: str(plot.render()) == "new picture", "new picture")
            release.set()  # the old one finishes now, after the new one
            await until(lambda: "old picture" in plot.handed, "old picture handed back")
            await pilot.pause()
            assert str(plot.render()) == "new picture"

    run(scenario())


def test_a_plot_is_up_to_date_once_the_picture_for_its_size_is_up():
    """What a screenshot waits for (tests/workbench/test_snapshots.py): a picture drawn for
    the plot's size as laid out now, not the one before a resize still on screen."""
    import threading

    from rich.text import Text
    from textual.app import App

    from workbench.tui.app import STYLESHEET
    from workbench.tui.widgets import Plot

    class One(App):
        CSS_PATH = STYLESHEET

        def compose(self):
            yield Plot(id="plot")

    release = threading.Event()
    asked: list[tuple[int, int]] = []

    def draw(w: int, h: int) -> Text:
        asked.append((w, h))
        release.wait(60)
        return Text(f"{w}x{h}")

    async def scenario():
        app = One()
        async with app.run_test(size=(60, 20)) as pilot:

            async def until(ok, what: str) -> None:
                end = asyncio.get_running_loop().time() + 60
                while not ok():
                    assert asyncio.get_running_loop().time() < end, f"no {what} in 60 s"
                    await pilot.pause(0.02)

            plot = app.query_one(Plot)
            await until(lambda: plot.content_size.width >= 12, "layout")
            assert plot.up_to_date  # nothing to draw yet
            plot.set_draw(draw)
            await until(lambda: bool(asked), "drawing")
            assert not plot.up_to_date  # drawn in its thread, not up yet
            release.set()
            await until(lambda: plot.up_to_date, "picture")
            assert str(plot.render()) == f"{asked[-1][0]}x{asked[-1][1]}"
            before = plot.content_size.height
            await pilot.resize_terminal(60, 14)
            await until(lambda: plot.content_size.height != before, "resize")
            await until(lambda: plot.up_to_date, "picture for the new size")
            assert asked[-1][1] == plot.content_size.height - 3  # (the axes' rows)
            assert str(plot.render()) == f"{asked[-1][0]}x{asked[-1][1]}"

    run(scenario())


def test_synthesis_tab_exports_the_law_as_c(di_session, tmp_path):
    """F3: a folder typed in *export the law as C99* gets the .h and .c of the law on screen,
    and they compile (the C itself is checked against locate in tests/engine/test_export.py)."""
    import shutil
    import subprocess

    app = CodevApp(di_session)
    dest = tmp_path / "law_c"

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f3")
            await settle(pilot, app)
            box = app.query_one("#law-export-dir", Input)
            box.focus()
            await pilot.press("enter")  # empty: says what to do
            await pilot.pause(0.1)
            assert "type a folder first" in text_of(app, "#law-export-out")
            await pilot.press(*"law", "enter")  # no law yet
            await pilot.pause(0.1)
            assert "synthesize first" in text_of(app, "#law-export-out")
            await pilot.press("ctrl+g")
            await settle(pilot, app)
            assert app.law is not None
            box.value = str(dest)
            box.focus()
            await pilot.press("enter")
            for _ in range(600):  # the tree and its kernel: seconds on a cold cache
                await pilot.pause(0.05)
                if "wrote" in text_of(app, "#law-export-out") or "failed" in text_of(
                    app, "#law-export-out"
                ):
                    break
            out = text_of(app, "#law-export-out")
            assert "wrote" in out and "worst case multiply-adds" in out, out

    asyncio.run(scenario())
    headers = sorted(dest.glob("*.h"))
    assert len(headers) == 1 and headers[0].with_suffix(".c").exists()
    assert app.law.fingerprint in headers[0].read_text()
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc:
        run = subprocess.run(
            [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-c",
             str(headers[0].with_suffix(".c")), "-o", str(tmp_path / "law.o")],
            capture_output=True, text=True,
        )
        assert run.returncode == 0, run.stderr


def test_regions_computed_so_far_are_shown_live(di_session):
    """Issue 39: while a verification runs on a law on demand (regions = "reached"), both
    the synthesis and the verification tabs show the regions computed so far (the
    verification's progress events carry them; the 10 Hz tick shows the last)."""
    import time

    from workbench.tui.panes.synthesis import SynthesisPane
    from workbench.tui.panes.verification import VerificationPane

    app = CodevApp(di_session)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            app.busy = "verification"
            app.query_one(SynthesisPane).show_busy("verification")
            app.query_one(VerificationPane).show_busy("verification")
            app.progress = ("verification", 7, time.perf_counter())
            app.regions_known = 1234
            app._tick()
            await pilot.pause()
            assert "1234 regions computed so far" in text_of(app, "#verify-status")
            assert "1234 regions computed so far" in text_of(app, "#synth-status")
            app.regions_known = None  # (a full law: no such words)
            app._tick()
            await pilot.pause()
            assert "regions computed" not in text_of(app, "#verify-status")
            app.busy = None

    run(scenario())
