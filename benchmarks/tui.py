"""Workbench responsiveness: start-up in a real terminal, and key presses during a synthesis.

- **start**: ``codev tui examples/double_integrator.toml`` in a tmux pane (a real terminal,
  interpreter start and imports included), timed from launch until the status line shows
  the stages' cache status (the app has checked the spec and answers keys). Best and median
  of ``--repeats`` launches. Skipped when tmux is not installed.
- **keys**: in process (Textual's headless driver), while a long synthesis runs in the
  app's worker (the magnetic pointer with horizon 8, ~8500 regions), a function key is sent
  every 100 ms and the time until the tab switch is visible in the app's state is measured.
  Target: every key answered within 100 ms.

A benchmark, not a test: prints a table (``--json OUT`` writes it) and exits 0.

Usage::

    .venv/bin/python benchmarks/tui.py [--repeats 3] [--keys 40] [--json out.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def start_times(repeats: int) -> tuple[list[float], list[float]] | None:
    """Seconds from launching ``codev tui`` in tmux to the first screen (the tabs drawn:
    keys are taken from here on) and to the first status line (the spec checked)."""
    if shutil.which("tmux") is None:
        return None
    out: list[float] = []
    paint: list[float] = []
    for k in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            name = f"codev-bench-{os.getpid()}-{k}"
            cmd = (
                f"{sys.executable} -m workbench.cli tui examples/double_integrator.toml "
                f"--session {tmp}/s"
            )
            t0 = time.perf_counter()
            subprocess.run(
                [
                    "tmux",
                    "new-session",
                    "-d",
                    "-s",
                    name,
                    "-x",
                    "150",
                    "-y",
                    "45",
                    "-c",
                    str(ROOT),
                    cmd,
                ],
                check=True,
            )
            try:
                seen = None
                while time.perf_counter() - t0 < 30:
                    pane = subprocess.run(
                        ["tmux", "capture-pane", "-p", "-t", name], capture_output=True, text=True
                    ).stdout
                    if len(paint) == k and "Plant [F1]" in pane:
                        paint.append(time.perf_counter() - t0)
                    if "model missing" in pane or "model cached" in pane:
                        seen = time.perf_counter() - t0
                        break
                    time.sleep(0.01)
                if seen is not None:
                    out.append(seen)
            finally:
                subprocess.run(["tmux", "kill-session", "-t", name], capture_output=True)
    return paint, out


async def _press(app, tabs, i: int) -> float:
    """Send F1 or F3 and wait until the tab has switched; then 100 ms of quiet."""
    from textual import events

    want = "plant" if i % 2 == 0 else "synthesis"
    key = "f1" if want == "plant" else "f3"
    t0 = time.perf_counter()
    app.post_message(events.Key(key, None))
    while tabs.active != want and time.perf_counter() - t0 < 5:
        await asyncio.sleep(0.001)
    dt = time.perf_counter() - t0
    await asyncio.sleep(0.1)
    return dt


async def key_latencies(keys: int, horizon: int) -> dict:
    """Latency of F1/F3 presses while a synthesis runs in the app's worker."""
    from textual.widgets import TabbedContent

    from workbench.tui.app import CodevApp
    from workbench.tui.state import open_target

    text = (ROOT / "examples" / "magnetic_pointer_a.toml").read_text()
    text = text.replace("horizon = 4", f"horizon = {horizon}")
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "pointer.toml"
        spec.write_text(text)
        app = CodevApp(open_target(str(spec), session_dir=f"{tmp}/s"))
        lat: list[float] = []
        async with app.run_test(size=(150, 45)):
            while app.check is None:
                await asyncio.sleep(0.01)
            tabs = app.query_one("#tabs", TabbedContent)
            app.action_show("synthesis")
            await asyncio.sleep(0.5)
            idle = [await _press(app, tabs, i) for i in range(10)]
            app.run_stage("synthesis")
            while not (app.progress and app.progress[1] > 0):
                await asyncio.sleep(0.005)
            for i in range(keys):
                if app.busy is None:
                    break
                lat.append(await _press(app, tabs, i))
            during = app.busy is not None
            regions = app.progress[1] if app.progress else None
            app.action_cancel()
            while app.busy is not None:
                await asyncio.sleep(0.05)
    lat.sort()
    return {
        "idle_median_ms": 1000 * statistics.median(idle),
        "keys": len(lat),
        "all_during_synthesis": during,
        "regions_when_done": regions,
        "median_ms": 1000 * statistics.median(lat) if lat else None,
        "p95_ms": 1000 * lat[int(0.95 * (len(lat) - 1))] if lat else None,
        "max_ms": 1000 * lat[-1] if lat else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--keys", type=int, default=40)
    ap.add_argument("--horizon", type=int, default=8)
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args()
    starts = start_times(args.repeats)
    keys = asyncio.run(key_latencies(args.keys, args.horizon))
    load = os.getloadavg()[0]
    res = {"load_average": load, "start_s": starts, "keys": keys}
    print(f"load average {load:.2f}")
    if starts:
        paint, status = starts
        res["first_screen_s"], res["start_s"] = paint, status
        print(
            f"start to first screen (tmux, real terminal): best {min(paint):.2f} s, "
            f"median {statistics.median(paint):.2f} s over {len(paint)} (target < 1 s)"
        )
        print(
            f"start to first status line (spec checked): best {min(status):.2f} s, "
            f"median {statistics.median(status):.2f} s"
        )
    else:
        print("start: tmux not installed, skipped")
    print(f"key presses when idle: median {keys['idle_median_ms']:.1f} ms")
    print(
        f"key presses during synthesis: {keys['keys']} keys, median {keys['median_ms']:.1f} ms,"
        f" p95 {keys['p95_ms']:.1f} ms, max {keys['max_ms']:.1f} ms (target < 100 ms); "
        f"synthesis still running at the end: {keys['all_during_synthesis']}"
    )
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
