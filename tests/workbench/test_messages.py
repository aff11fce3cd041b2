"""The panes ask, the app does: the typed messages of ``workbench.tui.messages`` seen on the
way (``run_test(message_hook=...)`` sees every message any widget receives: a pane's once at
each widget it bubbles through, up to the app)."""

from __future__ import annotations

import shutil

import pytest
from pilot_tools import EXAMPLES, ROOT, SIZE, run, settle, text_of
from textual.widgets import Input, Switch

from codev_engine.session import Session
from workbench.tui.app import CodevApp
from workbench.tui.messages import ExportRequested, RunRequested, SaveRequested, VerifyToggled
from workbench.tui.state import open_target


def posted(seen: list[object], kind: type) -> list[object]:
    """The messages of ``kind``, each once (a bubbling message is seen at every step)."""
    return list({id(m): m for m in seen if isinstance(m, kind)}.values())


@pytest.fixture
def di_app(tmp_path, monkeypatch) -> CodevApp:
    monkeypatch.chdir(tmp_path)
    return CodevApp(
        open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="sessions/di")
    )


def test_ctrl_g_on_the_synthesis_tab_posts_run_requested_and_the_app_runs_it(di_app, tmp_path):
    seen: list[object] = []

    async def scenario():
        async with di_app.run_test(size=SIZE, message_hook=seen.append) as pilot:
            await settle(pilot, di_app)
            assert not posted(seen, RunRequested)
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, di_app)
            runs = posted(seen, RunRequested)
            assert runs == [RunRequested("synthesis")]
            assert di_app.law is not None and di_app.law.num_regions == 10
            assert "10 critical regions" in text_of(di_app, "#synth-status")

    run(scenario())
    journal = Session.open(tmp_path / "sessions" / "di").journal()
    assert [r["stage"] for r in journal] == ["model", "synthesis"]
    assert journal[-1]["status"] == "computed"


def test_the_panes_buttons_and_switch_post_messages(di_app, tmp_path):
    """Verify's switch: VerifyToggled(False), and the saved spec loses its [verify]; the
    Session tab's Save: SaveRequested; Synthesize: the same RunRequested as ctrl+g."""
    seen: list[object] = []
    spec = tmp_path / "sessions" / "di" / "spec.toml"

    async def scenario():
        async with di_app.run_test(size=SIZE, message_hook=seen.append) as pilot:
            await settle(pilot, di_app)
            assert "[verify]" in spec.read_text()
            await pilot.press("f4")
            await pilot.click("#verify-enabled")
            await settle(pilot, di_app)
            assert posted(seen, VerifyToggled) == [VerifyToggled(False)]
            assert not di_app.has_verify
            assert "[verify]" not in spec.read_text()
            assert not di_app.query_one("#verify-enabled", Switch).value

            await pilot.press("f5")
            await pilot.click("#save")
            await settle(pilot, di_app)
            assert posted(seen, SaveRequested) == [SaveRequested()]
            saved = f"saved {di_app.session.spec_path()}"
            assert any(n.message == saved for n in di_app._notifications)

            await pilot.press("f3")
            await pilot.click("#synth-run")
            await settle(pilot, di_app)
            assert posted(seen, RunRequested) == [RunRequested("synthesis")]
            assert di_app.law is not None

    run(scenario())


def test_a_copy_that_fails_is_shown_not_raised(tmp_path, monkeypatch):
    """ctrl+g on the Session tab: RunRequested("recording"), then the pane asks for the
    copy (ExportRequested) and shows why it failed (its folder is a file)."""
    monkeypatch.chdir(tmp_path)
    src = ROOT / "sessions" / "double-integrator"
    shutil.copytree(src, "s", ignore=shutil.ignore_patterns("artifacts", "tui-draft.json"))
    (tmp_path / "a-file").write_text("")
    dest = str(tmp_path / "a-file" / "out.rrd")
    app = CodevApp(open_target("s"))
    seen: list[object] = []

    async def scenario():
        async with app.run_test(size=SIZE, message_hook=seen.append) as pilot:
            await settle(pilot, app)
            await pilot.press("f5")
            app.query_one("#export-path", Input).value = dest
            await pilot.press("ctrl+g")
            await settle(pilot, app, timeout=120)
            assert posted(seen, RunRequested) == [RunRequested("recording")]
            (export,) = posted(seen, ExportRequested)
            assert export.dest == dest and export.recording.is_file()
            out = text_of(app, "#export-out")
            assert f"cannot copy to {dest}" in out
            assert f"codev view {export.recording}" in out

    run(scenario())
