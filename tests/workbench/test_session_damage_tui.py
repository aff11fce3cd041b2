"""The workbench on a session whose cached law has a shard damaged in place (issue 43):
the picture of the partition reads it after the run, says so in place of the picture in
one line, and the session marks the artifact, so that its next run recomputes the law
instead of failing on it again."""

from __future__ import annotations

import asyncio

from pilot_tools import EXAMPLES, SIZE, settle, text_of

from codev_engine import load_spec
from codev_engine.session import RunOptions, Session
from codev_engine.session.store import check_artifact
from workbench.tui.app import CodevApp
from workbench.tui.state import open_target
from workbench.tui.widgets import Plot


def _flip(path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))


def test_the_workbench_marks_a_shard_it_finds_damaged_drawing_the_law(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    folder = tmp_path / "sessions" / "di"
    problem = load_spec(EXAMPLES / "double_integrator.toml")
    upto = RunOptions(upto="synthesis", sharded=True)
    syn = Session.create(folder).run(problem, upto).stage("synthesis")
    _flip(folder / syn.artifact / "shard-0.npz")
    app = CodevApp(open_target(str(folder)))
    shown: list[str] = []

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f3")  # (the synthesis tab: its picture is drawn)
            # (a condition, not a count of pauses: 400 of them were 20 s, and the whole test
            # took 14 s at load 10 on two test processes)
            end = asyncio.get_running_loop().time() + 60
            while asyncio.get_running_loop().time() < end:
                await pilot.pause(0.05)
                shown[:] = [str(app.query_one("#partition", Plot).render()),
                            text_of(app, "#synth-status")]
                if all("shard-0.npz" in t for t in shown):
                    break

    asyncio.run(scenario())  # (the region table's worker read it too: the app lives on)
    for text in shown:  # the picture, and the status line (the region table's)
        assert "shard-0.npz: its SHA-256" in text and "next run recomputes" in text, shown
    # (marked: the next run recomputes it, as tests/engine/test_session_damage.py runs)
    assert "shard-0.npz" in check_artifact(folder, folder / syn.artifact, syn.key)
