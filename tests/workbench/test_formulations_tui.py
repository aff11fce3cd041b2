"""The MPC designs of issue 25 (and the uncertain plants of issue 26) in the workbench.

Each bundled example with those fields opens in the form, synthesises (F3, ctrl+g) and
verifies (F4, ctrl+g) through the real app (behind ``-m slow``). The DC-motor servo's
synthesis and preview run by default: its law is over θ = (angle, speed, prev_V, ref_y0),
so the region table, the lookup and the slice take four numbers.
"""

from __future__ import annotations

import numpy as np
import pytest
from pilot_tools import EXAMPLES, SIZE, entry, run, settle, text_of
from textcells import decode_pixels, plot_body
from textual.widgets import Collapsible, Input

from workbench.tui.app import CodevApp
from workbench.tui.design import shared_laws
from workbench.tui.state import open_target
from workbench.tui.views import REFERENCE


@pytest.fixture(autouse=True)
def _stages_at_full_priority(monkeypatch):
    """The app runs its stages at a lower CPU priority than the keyboard. On a machine
    shared with other work (the test machines are) such a verification waits behind every
    other process: these tests check what the workbench shows, not the scheduler."""
    monkeypatch.setattr("workbench.tui.app._lower_priority", lambda *a, **k: None)


KEY = {" ": "space", ",": "comma", "-": "minus", ".": "full_stop"}


def keys(text: str) -> list[str]:
    return [KEY.get(c, c) for c in text]


def rows_of(rows: list[list[str | None]], colour: str) -> list[int]:
    """For each pixel column (left to right), the first row of ``colour`` (columns
    without it left out)."""
    out = []
    for c in range(len(rows[0])):
        hit = [k for k in range(len(rows)) if rows[k][c] == colour]
        if hit:
            out.append(hit[0])
    return out


async def _synthesise_and_verify(pilot, app: CodevApp, timeout: float) -> None:
    await settle(pilot, app, timeout=timeout)  # the first check imports the engine
    assert app.check.ok, (app.check.errors, app.check.general)
    await pilot.press("f3", "ctrl+g")
    await settle(pilot, app, timeout=timeout)
    assert app.law is not None and app.law_current(), [n.message for n in app._notifications]
    await pilot.press("f4", "ctrl+g")
    await settle(pilot, app, timeout=timeout)
    assert app.result is not None and app.result_current(), [
        n.message for n in app._notifications
    ]


def test_the_servo_opens_and_synthesises_in_the_workbench(tmp_path, monkeypatch):
    """By default: the form, the synthesis over θ of length 4, the lookup and the slice; its
    preview and verification are in the slow set below (test_design checks the preview's
    loop at no app cost)."""
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / "dc_motor_servo.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            # the groups the design uses are open, the others closed
            groups = {c.title: c.collapsed for c in app.query(Collapsible)}
            assert groups["Tracking: a reference"] is False
            assert groups["Input rates and move blocking"] is False
            assert groups["Soft constraints"] is True
            assert entry(app, "mpc.du_max").text == "[0.5]"
            assert entry(app, "verify.reference").text == "{ lower = [0.45], upper = [0.55] }"
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app, timeout=240)
            law = app.law
            assert law is not None and app.law_current(), [n.message for n in app._notifications]
            assert law.n == 4 and law.parameter_names == ("angle", "speed", "prev_V", "ref_y0")
            # "96 share a law" is right: the first move is at a limit almost everywhere
            # (u = ±1 in 13 regions each, u = u_prev ± 0.5 in 37 each), 5 distinct laws
            FG = np.hstack([law.F.reshape(law.num_regions, -1), law.G])
            distinct = {tuple(np.round(row, 9)) for row in FG}
            assert shared_laws(law) == law.num_regions - len(distinct) == 96
            # the region table names θ; the lookup takes its four numbers
            row = app.query_one("#regions").get_row_at(0)
            assert "prev_V" in row[2] or "ref_y0" in row[2] or row[2].startswith("+"), row
            await pilot.press("f3")
            assert "prev_V, ref_y0" in app.query_one("#locate-x", Input).placeholder
            await pilot.press(*keys("0.1, 0, 0, 0.5"), "enter")
            await pilot.pause(0.1)
            k, u = law.locate([[0.1, 0.0, 0.0, 0.5]])[0], law.evaluate([[0.1, 0.0, 0.0, 0.5]])
            assert f"region {k}" in text_of(app, "#locate-out").replace("[b]", "")
            assert f"V = {float(u[0, 0]):.6g}" in text_of(app, "#locate-out")
            # by default the slice is at the middle of [verify] initial_input and reference,
            # as in recordings and reports; typed, it takes the extra parameters alone
            pane = app.query_one("SynthesisPane")
            assert pane._at(law).tolist()[2:] == pytest.approx([0.0, 0.5])
            assert "middle of [verify]" in app.query_one("#synth-at", Input).placeholder
            app.query_one("#synth-at", Input).value = "0.2, -0.5"
            assert pane._at(law).tolist()[2:] == [0.2, -0.5]
            # the preview draws the reference it follows (y = angle: on the angle's plot)
            await pilot.press("f2", "ctrl+g")
            await settle(pilot, app, timeout=240)
            mpc = app.query_one("MpcPane")
            assert mpc.last is not None and "following r = 0.5" in text_of(app, "#preview-status")
            assert mpc.reference_lines == [("r angle", 0.5)]
            picture = app.query_one("#preview-states")._draw(60, 12)
            assert "r angle = 0.5" in picture.plain
            rows = decode_pixels(plot_body(picture, 12))
            on = [k for k, row in enumerate(rows) if row.count(REFERENCE) >= 20]
            assert len(on) == 1, on  # one dashed horizontal line across the plot
            # at the reference's height: the angle's last samples (it settles at 0.5) are
            # drawn on that pixel row or next to it
            angle = rows_of(rows, "#4e79a7")
            assert min(abs(k - on[0]) for k in angle[-3:]) <= 1, (on, angle[-3:])

    run(scenario())


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        "dc_motor_servo",
        "mass_spring_soft",
        "two_carts_mixed",
        "double_integrator_lqr",
        "cruise_grade",
        "cstr",
    ],
)
def test_the_examples_of_issues_25_and_26_synthesise_and_verify_in_the_workbench(
    tmp_path, monkeypatch, name
):
    monkeypatch.chdir(tmp_path)
    app = CodevApp(open_target(str(EXAMPLES / f"{name}.toml"), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await _synthesise_and_verify(pilot, app, timeout=600)
            assert app.result.verdict in ("robustly_safe", "unknown", "unsafe")
            if name == "dc_motor_servo":  # θ of length 4, verified over the reference box
                assert app.law.n == 4 and app.result.verdict == "robustly_safe"
                assert "ROBUSTLY SAFE" in text_of(app, "#verdict")
                # the preview follows a reference: the middle of [verify] reference, or typed
                assert app.query_one("#preview-r", Input).placeholder == "default: 0.5"
                await pilot.press("f2", "ctrl+g")
                await settle(pilot, app, timeout=600)
                status = text_of(app, "#preview-status")
                assert "following r = 0.5" in status and "infeasible" not in status, status
                app.query_one("#preview-r", Input).value = "-0.8"
                app.query_one("#preview-steps", Input).value = "60"
                await pilot.press("ctrl+g")
                await settle(pilot, app, timeout=600)
                assert app.query_one("MpcPane").last.X[-1, 0] == pytest.approx(-0.8, abs=1e-3)

    run(scenario())
