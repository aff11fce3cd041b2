"""The first hour of a newcomer (issue 23), driven through the real app (Textual's Pilot).

Each test types as a user would, right after start or after an F-key, with no Tab first,
and checks what lands where: focus, Open after another design, the plant report with only
the plant valid, ctrl+g before the first check, a change of size, defaults shown.
"""

from __future__ import annotations

import shutil

import pytest
from pilot_tools import EXAMPLES, SIZE, entry, run, settle, text_of, type_into
from textual import events
from textual.widgets import Input, OptionList, Select, Static

from workbench.tui.app import CodevApp
from workbench.tui.panes.plant import PlantPane
from workbench.tui.state import open_target
from workbench.tui.templates import TemplateScreen
from workbench.tui.widgets import FieldEntry

KEY = {" ": "space", ",": "comma", "-": "minus", ".": "full_stop", ";": "semicolon"}


def keys(text: str) -> list[str]:
    return [KEY.get(c, c) for c in text]


def test_keys_typed_at_start_and_after_every_f_key_land_in_the_first_field(tmp_path):
    """No Tab before the first field: at start the name, after F2 the horizon, after F3 the
    lookup, after F4 the time horizon, after F5 the path to open, after F1 the name again."""
    opened = open_target(None, sessions_root=tmp_path / "sessions")
    app = CodevApp(opened)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press(*keys("msd"))  # at once: before the first check, no Tab
            await settle(pilot, app)
            assert entry(app, "name").text == "msd"
            for key, widget, text in [
                ("f2", "#f-mpc-horizon #editor", "5"),
                ("f3", "#locate-x", "1, 2"),
                ("f4", "#f-verify-time-horizon #editor", "3"),
                ("f5", "#open-path", "x.toml"),
            ]:
                await pilot.press(key, *keys(text))
                await pilot.pause()
                assert app.focused is app.query_one(widget), (key, app.focused)
                assert app.query_one(widget, Input).value == text, key
            await pilot.press("f1", *keys("-2"))
            await pilot.pause()
            assert entry(app, "name").text == "msd-2"
            # the focused entry is marked (a bar at its left), not only by a shade
            assert entry(app, "name").has_pseudo_class("focus-within")
            assert entry(app, "name").styles.border_left[0] == "thick"
            # Tab goes to the next field: no tab bar, no invisible container in between
            await pilot.press("tab")
            assert app.focused is entry(app, "plant.states").editor
            await pilot.press("shift+tab")
            assert app.focused is entry(app, "name").editor

    run(scenario())


def test_session_tab_order_puts_each_path_before_its_button(tmp_path):
    opened = open_target(None, sessions_root=tmp_path / "sessions")
    app = CodevApp(opened)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f5")
            order = [app.focused.id]
            for _ in range(7):
                await pilot.press("tab")
                order.append(app.focused.id)
            assert order[:4] == ["open-path", "open", "save", "new"], order
            i = order.index("export-path")
            assert order[i + 1] == "export", order

    run(scenario())


def test_open_replaces_the_whole_previous_design(tmp_path, monkeypatch):
    """After the double integrator was previewed, located and exported, opening the
    pendulum leaves nothing of it: x0, the input plot, the lookup, messages, the copy path."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(EXAMPLES / "pendulum.toml", tmp_path / "pendulum.toml")
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s/di"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app)
            assert app.query_one("#preview-x0", Input).value == "9, -5"
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            await pilot.press("f3", *keys("1, 0"), "enter")
            await pilot.pause(0.1)
            assert "region" in text_of(app, "#locate-out")
            await pilot.press("f5")
            app.query_one("#export-path", Input).value = str(tmp_path / "di.rrd")
            await pilot.press(*keys("pendulum"), "full_stop", *keys("toml"), "enter")
            await settle(pilot, app)
            assert entry(app, "name").text == "pendulum"
            assert app.query_one("#export-path", Input).value == ""
            assert text_of(app, "#export-out") == ""
            assert text_of(app, "#locate-out") == ""
            assert app.query_one("#locate-x", Input).value == ""
            assert app.query_one("#preview-x0", Input).value == ""
            assert text_of(app, "#preview-status") == ""
            assert app.law is None and app.result is None
            assert app.query_one("#regions").row_count == 0
            # the preview of the new design starts from its own initial set, not (9, -5)
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app)
            x0 = app.query_one("#preview-x0", Input).value
            assert x0 != "9, -5" and "infeasible" not in text_of(app, "#preview-status")

    run(scenario())


def test_plant_report_appears_with_only_the_plant_valid(tmp_path):
    """Name and [verify] still empty (the norm too: it has a default): the derived model is
    shown all the same, and ctrl+g says which tabs hold what is missing."""
    app = CodevApp(open_target(None, sessions_root=tmp_path / "sessions"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("tab")  # name left empty: states
            await pilot.press(*keys("p, v"), "tab", "u", "tab")
            await pilot.press(*keys("v"), "enter", *keys("-p - 0.5*v + u"))
            await type_into(pilot, app, "model.sample_time", "0.1")
            await settle(pilot, app)
            assert not app.check.ok
            report = app.query_one(PlantPane).report_text
            assert "controllability rank 2 of 2" in report, report
            for name in ("plant.states", "plant.inputs", "plant.dynamics", "model.sample_time"):
                assert not entry(app, name).has_class("-error"), name
            await pilot.press("ctrl+g")
            await pilot.pause()
            note = app._notifications
            messages = [n.message for n in note]
            assert not any("mpc.norm" in m for m in messages), messages  # default "2"
            assert any("Verification (F4)" in m for m in messages), messages
            assert "Plant (F1): name" in text_of(app, "#pipeline")

    run(scenario())


def test_ctrl_g_before_the_first_check_waits_for_it(tmp_path, monkeypatch):
    """ctrl+g at once after start runs the stage of a valid spec (it used to say "the spec
    is not valid yet" because the first check had not answered)."""
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            messages = [n.message for n in app._notifications]
            assert not any("not valid" in m for m in messages), messages
            assert app.law is not None and app.law.num_regions == 10
            assert "synthesised in" in text_of(app, "#synth-status")

    run(scenario())


def test_synthesis_runs_while_verify_is_unfinished(tmp_path):
    """[verify] is on by default: with its fields still empty, F3 ctrl+g synthesises all
    the same (the synthesis needs none of them), and the law shown is current."""
    app = CodevApp(open_target(None, sessions_root=tmp_path / "sessions"))
    values = {
        "name": "msd",
        "plant.states": "p, v",
        "plant.inputs": "u",
        "plant.dynamics": "v\n-2*p - 0.5*v + u",
        "model.sample_time": "0.2",
        "mpc.norm": "inf",
        "mpc.u_min": "-1",
        "mpc.u_max": "1",
        "mpc.x_min": "-5 -5",
        "mpc.x_max": "5 5",
    }

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            for name, text in values.items():
                entry(app, name).set_text(text)
                app.values[name] = text
            app._schedule_check()
            await settle(pilot, app)
            assert not app.check.ok and set(app.check.errors) <= {
                "verify.time_horizon",
                "verify.initial_set.lower",
                "verify.initial_set.upper",
            }
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            assert app.law is not None, [n.message for n in app._notifications]
            assert app.law_current() and "current" in text_of(app, "#synth-status")
            # the MPC preview runs too
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app)
            assert app.query_one("#preview-x0", Input).value
            assert "steps" in text_of(app, "#preview-status")

    run(scenario())


def test_a_change_of_size_flags_every_entry_that_no_longer_fits(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await type_into(pilot, app, "plant.states", "x1, x2, x3")
            await settle(pilot, app)
            flagged = {e.field_name for e in app.query(FieldEntry) if e.has_class("-error")}
            want = {
                "plant.dynamics",
                "mpc.Q",
                "mpc.x_min",
                "mpc.x_max",
                "verify.initial_set.lower",
                "verify.initial_set.upper",
                "verify.safe",
            }
            assert want <= flagged, flagged
            assert "plant.states" not in flagged and "mpc.R" not in flagged

    run(scenario())


def test_empty_optional_entries_show_their_default(tmp_path):
    app = CodevApp(open_target(None, sessions_root=tmp_path / "sessions"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            want = {
                "mpc.horizon": "default: 5",
                "mpc.Q": "default: identity",
                "mpc.R": "default: identity",
                "mpc.P": "default: none",
                "mpc.domain_bound": "default: 100",
                "verify.max_depth": "default: 6",
                "verify.step": "default: 0.01",
                "model.operating_point.x": "default: zeros",
            }
            for name, text in want.items():
                assert entry(app, name).query_one(Input).placeholder == text, name
            for name, text in {"model.method": "zoh", "verify.hold": "zoh"}.items():
                sel = entry(app, name).query_one(Select)
                assert sel.is_blank() and sel.prompt == f"default: {text}", name
            # Norm starts empty and shows its default (issue 41), not preset to a choice
            norm = entry(app, "mpc.norm").query_one(Select)
            assert norm.is_blank() and norm.prompt == "default: 2"
            assert "required" not in str(entry(app, "mpc.norm").query_one("#help", Static).render())
            # a character typed on the closed choice picks it: i -> inf, 2 -> 2
            await pilot.press("f2", "tab", "i")
            await settle(pilot, app)
            assert norm.value == "inf" and app.values["mpc.norm"] == "inf"
            await pilot.press("2")
            assert norm.value == "2"
            await settle(pilot, app)  # (the check the key set off: not left to the quit)

    run(scenario())


@pytest.mark.parametrize(
    ("field", "text"),
    [
        ("mpc.horizon", "1000000000"),
        ("model.sample_time", "1e-300"),
        ("model.sample_time", "nan"),
        ("mpc.Q", "1e308 1e308; 1e308 1e308"),
        ("plant.states", "ψ, ω"),
        ("name", "x" * 5000),
        ("mpc.x_min", " ".join(["1"] * 20000)),
        ("verify.time_horizon", "1e9"),
        ("verify.step", "1e-12"),
    ],
)
def test_adversarial_entries_never_crash_or_hang(tmp_path, monkeypatch, field, text):
    """Huge, tiny, NaN, unicode, very long: the form answers (an error or a valid spec),
    the app keeps running, and the check ends in time."""
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            e = entry(app, field)
            e.query_one(Input).value = text
            # a bound for a hang (forever), not a time target: the plant report's worker is
            # waited for too, and its first derivation in a process took 5.5 s at load 8
            await settle(pilot, app, timeout=60)
            assert app.check is not None
            assert app.is_running

    run(scenario())


def test_new_from_a_template_leaves_nothing_of_the_design_before(tmp_path, monkeypatch):
    """ctrl+n offers the templates; a copy of an example replaces the design on screen
    as Open does (preview, lookup, law, copy path, messages), lives in a fresh session
    folder named after it, and synthesises at once. The blank template empties the form,
    and its folder follows the name typed."""
    monkeypatch.chdir(tmp_path)
    app = CodevApp(
        open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s/di"),
        sessions_root=tmp_path / "sessions",
    )

    async def pick(pilot, key: str) -> None:
        await pilot.press("ctrl+n")
        await pilot.pause()
        assert isinstance(app.screen, TemplateScreen)
        options = app.screen.query_one(OptionList)
        ids = [options.get_option_at_index(i).id for i in range(options.option_count)]
        await pilot.press(*["down"] * ids.index(key), "enter")
        await settle(pilot, app)

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app)
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            await pilot.press(*keys("1, 0"), "enter")
            await pilot.pause(0.1)
            assert "region" in text_of(app, "#locate-out")
            await pilot.press("f5")
            app.query_one("#export-path", Input).value = str(tmp_path / "di.rrd")
            # Esc keeps the design on screen
            await pilot.press("ctrl+n", "escape")
            await pilot.pause()
            assert not isinstance(app.screen, TemplateScreen) and app.law is not None
            await pick(pilot, "double_integrator_lqr")
            assert app.session.path == tmp_path / "sessions" / "double-integrator-lqr"
            assert entry(app, "name").text == "double-integrator-lqr"
            assert entry(app, "mpc.terminal_set").text == "lqr"
            assert app.focused is entry(app, "name").editor
            assert app.query_one("#export-path", Input).value == ""
            assert text_of(app, "#export-out") == ""
            assert text_of(app, "#locate-out") == ""
            assert app.query_one("#locate-x", Input).value == ""
            assert app.query_one("#preview-x0", Input).value == ""
            assert text_of(app, "#preview-status") == ""
            assert app.law is None and app.result is None
            assert app.query_one("#regions").row_count == 0
            assert not [n for n in app._notifications if "double_integrator.toml" in n.message]
            # the template runs at once
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app)
            assert app.law is not None and app.law_current(), [
                n.message for n in app._notifications
            ]
            assert (app.session.path / "spec.toml").is_file()
            # the blank form: nothing of the example, a new folder that follows the name
            await pick(pilot, "empty")
            assert set(app.values.values()) == {""} and app.law is None
            assert app.session.path == tmp_path / "sessions" / "untitled"
            await pilot.press(*keys("msd"))
            await settle(pilot, app)
            assert app.session.path == tmp_path / "sessions" / "msd"

    run(scenario())


def burst(app: CodevApp, *names: str) -> None:
    """Deliver keys as a terminal does under load: all at once, none waiting for the one
    before it to be handled (Pilot's ``press`` waits for the app to be idle after each)."""
    for name in names:
        event = events.Key(name, name if len(name) == 1 else None)
        event.set_sender(app)
        app._driver.send_message(event)


def test_ctrl_g_right_after_f3_and_typing_runs_the_synthesis_of_the_spec_typed(
    tmp_path, monkeypatch
):
    """Issue 23: in a real terminal, ctrl+g pressed right after F3 ran the Plant tab's stage.
    ctrl+g is a priority key (handled as it arrives), an F-key was not (first sent to the
    focused entry, then back up to the app), so the ctrl+g overtook the F3. Likewise the
    keys typed just before ctrl+g reached their entry after it, and the run took the spec
    without them."""
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            burst(app, "f3", "ctrl+g")
            await settle(pilot, app)
            assert app.law is not None and app.law_current(), [
                n.message for n in app._notifications
            ]
            # a new bound typed, then at once F3 and ctrl+g: the law is the new spec's
            await pilot.press("f2")
            entry(app, "mpc.u_max").editor.focus()
            await pilot.pause()
            assert entry(app, "mpc.u_max").text == "[1.0]"
            burst(app, "backspace", "backspace", "5", "]", "f3", "ctrl+g")
            await settle(pilot, app)
            assert app.check.ok, (app.values["mpc.u_max"], app.check.errors)
            assert app.check.problem.mpc.u_max.tolist() == [1.5]
            assert app.law_current(), [n.message for n in app._notifications]
            assert "current" in text_of(app, "#synth-status")

    run(scenario())


def test_the_preview_is_marked_stale_when_r_changes(tmp_path):
    """Issue 41: the preview drawn is of the spec as it was; R changed, the status line
    says it is stale, and R put back takes it back."""
    app = CodevApp(open_target(str(EXAMPLES / "double_integrator.toml"),
                               session_dir=str(tmp_path / "s")))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app)
            shown = text_of(app, "#preview-status")
            assert "steps" in shown and "stale" not in shown, shown
            before = entry(app, "mpc.R").text
            await type_into(pilot, app, "mpc.R", "0.5")
            await settle(pilot, app)
            assert "stale" in text_of(app, "#preview-status")
            await type_into(pilot, app, "mpc.R", before)
            await settle(pilot, app)
            assert text_of(app, "#preview-status") == shown

    run(scenario())
