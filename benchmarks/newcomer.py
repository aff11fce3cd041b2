"""Benchmark: a newcomer in a real terminal, ``codev tui`` on a blank form to a verdict.

Usage::

    python benchmarks/newcomer.py [--pace 0.15] [--json OUT]

Starts the workbench with no spec (``codev tui --session DIR``, DIR a fresh temporary folder)
in a detached tmux pane on a private server (``-L``) and types, one key every ``--pace``
seconds, what a newcomer types for a mass-spring-damper (issue 41): Name, States, Inputs,
the two dynamics, the sample time on the Plant tab; F4 and the time horizon and the initial
set on the Verification tab; every MPC entry left at its default; then ctrl+g. Reports the
keys sent, the seconds from launch to the first screen, to the last key and to the verdict
banner, and which typed values the saved spec (ctrl+s) lacks (``lost``: a key lost). The
typing is a script's, so the seconds are the app's and the pace's, not a person's reading
time. It asserts nothing; skipped (exit 0) without tmux.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

#: what the saved spec must hold when no key was lost
TYPED = ('"msd"', '"p"', '"v"', '"u"', "-2*p - 0.5*v + u", "0.2", "-0.5", "0.5")
VERDICT = re.compile(r"ROBUSTLY SAFE|UNSAFE|UNKNOWN")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pace", type=float, default=0.15, help="seconds between keys")
    ap.add_argument("--json", metavar="OUT", help="write the figures as JSON")
    args = ap.parse_args(argv)
    if shutil.which("tmux") is None:
        print("newcomer: tmux is not installed; skipped")
        return 0
    sock, name = f"codev-newcomer-{uuid.uuid4().hex[:8]}", "nc"
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    keys = 0

    def tm(*a: str) -> str:
        return subprocess.run(["tmux", "-L", sock, "-f", "/dev/null", *a], capture_output=True,
                              text=True, env=env, timeout=20).stdout

    def wait(ok, timeout: float, what: str) -> str:
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < timeout:
            screen = tm("capture-pane", "-p", "-t", name)
            if ok(screen):
                return screen
            time.sleep(0.1)
        raise SystemExit(f"newcomer: timed out waiting for {what}")

    def typed(text: str) -> None:
        nonlocal keys
        for c in text:
            tm("send-keys", "-t", name, "-l", "--", c)
            keys += 1
            time.sleep(args.pace)

    def press(*ks: str) -> None:
        nonlocal keys
        for k in ks:
            tm("send-keys", "-t", name, k)
            keys += 1
            time.sleep(args.pace)

    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "s"
        app = shlex.join(["env", "-u", "COLUMNS", "-u", "LINES", sys.executable, "-m",
                          "workbench.cli", "tui", "--session", str(session)])
        try:
            tm("new-session", "-d", "-s", name, "-x", "160", "-y", "50")
            t0 = time.perf_counter()
            tm("send-keys", "-t", name, f"{app}; echo CODEV-EXIT=$?", "Enter")
            wait(lambda s: "Plant [F1]" in s, 120, "the first screen")
            t_first = time.perf_counter() - t0
            typed("msd"), press("Tab"), typed("p, v"), press("Tab"), typed("u"), press("Tab")
            typed("v"), press("Enter"), typed("-2*p - 0.5*v + u"), press("Tab", "Tab", "Tab")
            typed("0.2")
            press("F4"), typed("3"), press("Tab", "Tab"), typed("-0.5, -0.5"), press("Tab")
            typed("0.5, 0.5")
            t_typed = time.perf_counter() - t0
            press("C-g")
            screen = wait(lambda s: VERDICT.search(s) is not None, 600, "the verdict")
            t_verdict = time.perf_counter() - t0
            press("C-s")
            spec = session / "spec.toml"
            while not spec.is_file() and time.perf_counter() - t0 < t_verdict + 10:
                time.sleep(0.1)
            text = spec.read_text(encoding="utf-8") if spec.is_file() else ""
            press("C-q")
            wait(lambda s: "CODEV-EXIT=" in s, 30, "the app to exit")
        finally:
            tm("kill-server")  # our private server only
    out = {"pace_s": args.pace, "keys": keys, "first_screen_s": round(t_first, 1),
           "last_key_s": round(t_typed, 1), "verdict_s": round(t_verdict, 1),
           "verdict": VERDICT.search(screen).group(0),
           "lost": [v for v in TYPED if v not in text], "load": os.getloadavg()[0]}
    print(json.dumps(out, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
