"""Start the installed workbench headless on a spec, synthesise from its keys, quit.

``python tui_smoke.py SPEC SESSION_DIR`` opens SPEC as ``codev tui SPEC --session
SESSION_DIR`` does, in Textual's headless driver (``App.run_test``), waits for the pipeline
line to show the synthesis stage's status (the spec checked), presses F3 (the synthesis
tab) and ctrl+g (run the synthesis), waits for the session's journal to record the
synthesis, then presses ctrl+q. Exit 0 and one line with the region count, or a
traceback. Run by .ci/run and tests/contract/test_wheel.py with the Python of a venv where
the wheel is installed, from outside the checkout: it imports only the installed packages.
"""

from __future__ import annotations

import asyncio
import json
import re
import sys
import time
from pathlib import Path

from workbench.tui.app import CodevApp
from workbench.tui.state import open_target


def synthesis_records(session: Path) -> list[dict]:
    journal = session / "journal.jsonl"
    if not journal.is_file():
        return []
    lines = journal.read_text(encoding="utf-8").splitlines()
    return [r for r in map(json.loads, filter(str.strip, lines)) if r["stage"] == "synthesis"]


#: the pipeline line once the spec is checked (ctrl+g before that is refused: not valid yet)
CHECKED = re.compile(r"synthesis (missing|cached|stale|corrupt)|spec not valid")


async def scenario(spec: str, session: Path, timeout: float = 180.0) -> dict:
    app = CodevApp(open_target(spec, session_dir=str(session)))
    async with app.run_test(size=(160, 50)) as pilot:
        end = time.monotonic() + timeout
        while not CHECKED.search(line := str(app.query_one("#pipeline").render())):
            assert time.monotonic() < end, f"the spec was not checked after {timeout} s: {line}"
            await pilot.pause(0.2)
        assert "spec not valid" not in line, line
        await pilot.press("f3")
        await pilot.pause(0.2)
        active = app.query_one("#tabs").active
        assert active == "synthesis", f"F3 showed the {active!r} tab"
        await pilot.press("ctrl+g")
        end = time.monotonic() + timeout
        while not synthesis_records(session):
            assert time.monotonic() < end, f"no synthesis in the journal after {timeout} s"
            await pilot.pause(0.2)
        await pilot.press("ctrl+q")
    assert app.return_code in (0, None), app.return_code
    return synthesis_records(session)[-1]


def main() -> int:
    spec, session = sys.argv[1], Path(sys.argv[2])
    record = asyncio.run(scenario(spec, session))
    assert record["status"] == "computed", record
    print(f"codev tui: synthesis {record['status']}, outcome {record['outcome']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
