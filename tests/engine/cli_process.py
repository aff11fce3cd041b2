"""Running ``codev`` as a real process from the tests (exit status, stderr, no mocks)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def run_codev(
    *args, cwd: str | Path, timeout: float = 300, env: dict | None = None
) -> subprocess.CompletedProcess:
    """``python -m workbench.cli ARGS`` in ``cwd``, output captured; ``CODEV_DEBUG`` is
    cleared so that bad input gives its one-line error, not a traceback; ``env`` adds
    variables."""
    env = {**{k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "workbench.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )


class Interrupted:
    """``codev ARGS`` started in its own process group, interrupted by Ctrl-C as a terminal
    sends it: SIGINT to the whole group (the command, its pool workers, a Dask cluster's
    processes), ``delay`` seconds after a line of stderr starts with ``after``.

    Attributes
    ----------
    returncode : int
    stdout, stderr : str
        Everything written (stderr: the lines before the interrupt too).
    seen : float
        Seconds from the start to the line ``after``.
    """

    def __init__(
        self, *args, cwd: str | Path, after: str, timeout: float = 120, delay: float = 0.0
    ):
        import queue
        import signal
        import threading
        import time

        env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
        t0 = time.monotonic()
        proc = subprocess.Popen(
            [sys.executable, "-m", "workbench.cli", *map(str, args)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=cwd,
            env=env,
            start_new_session=True,  # its own group: the signal reaches every process of it
        )
        self.pid = proc.pid
        lines: queue.Queue = queue.Queue()
        err: list[str] = []

        def read() -> None:
            for line in proc.stderr:
                err.append(line)
                lines.put(line)
            lines.put(None)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            while True:
                line = lines.get(timeout=max(0.1, timeout - (time.monotonic() - t0)))
                if line is None:
                    raise AssertionError(f"codev ended before {after!r}: {''.join(err)}")
                if line.startswith(after):
                    break
            self.seen = time.monotonic() - t0
            time.sleep(delay)
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=timeout)
            self.stdout = proc.stdout.read()
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        reader.join(timeout=10)
        self.returncode = proc.returncode
        self.stderr = "".join(err)

    def left(self, wait: float = 20.0) -> list[str]:
        """The processes of the group still running after ``wait`` seconds at most
        (``ps -s``; zombies about to be reaped are not counted)."""
        import time

        deadline = time.monotonic() + wait
        while True:
            out = subprocess.run(
                ["ps", "-s", str(self.pid), "-o", "pid=,stat=,args="],
                capture_output=True,
                text=True,
            ).stdout
            alive = [p for p in out.splitlines() if p.split()[1:2] and "Z" not in p.split()[1]]
            if not alive or time.monotonic() > deadline:
                return alive
            time.sleep(0.2)
