"""Driving the workbench in tests: wait for it to settle, type into an entry, read a widget."""

from __future__ import annotations

import asyncio
from pathlib import Path

from textual.widgets import Input, Static

from workbench.tui.app import CodevApp
from workbench.tui.widgets import FieldEntry

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
SIZE = (160, 50)


async def settle(pilot, app: CodevApp, timeout: float = 120.0) -> None:
    """Wait until no stage runs, the form check is done and every worker has finished.

    A condition, so the bound is generous: a fresh process's first check, plant report and
    synthesis load their modules and kernels, and at load 8-9 (2 cores) one step of
    test_first_hour's synthesis-while-verify-is-unfinished took 40 s of the 60 s it had.
    """
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while loop.time() < end:
        await pilot.pause(0.05)
        busy = app.busy is not None or app._check_timer is not None
        running = [w for w in app.workers if w.is_running]
        if not busy and not running and app.check is not None:
            await pilot.pause(0.05)
            return
    raise AssertionError(f"the app did not settle in {timeout} s (busy={app.busy})")


async def type_into(pilot, app: CodevApp, field: str, text: str) -> None:
    """Replace an entry's text by typing, as a user would."""
    entry = next(e for e in app.query(FieldEntry) if e.field_name == field)
    editor = entry.query_one(Input)
    editor.focus()
    await pilot.pause()
    await pilot.press("end", *["backspace"] * (len(editor.value) + 2))
    await pilot.press(
        *[
            {" ": "space", ";": "semicolon", ",": "comma", "-": "minus", ".": "full_stop"}.get(c, c)
            for c in text
        ]
    )


def entry(app: CodevApp, field: str) -> FieldEntry:
    return next(e for e in app.query(FieldEntry) if e.field_name == field)


def text_of(app: CodevApp, selector: str) -> str:
    return str(app.query_one(selector, Static).render())


def run(coro) -> None:
    """Run a pilot scenario (tests stay synchronous: no pytest-asyncio needed)."""
    asyncio.run(coro)
