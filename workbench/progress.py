"""Progress of long work on stderr, for the ``codev`` command line.

The engine reports progress through plain callbacks (``progress(count)`` of synthesis and
verification, ``on_event(stage, event, data)`` of a session run); this module shows it:

* on a terminal, one live line per stage (rich: spinner, count, elapsed seconds), erased
  when the stage ends;
* elsewhere (a pipe, a log file, CI), plain lines ``codev: STAGE: COUNT UNIT, T s``: the
  first once a stage has run :data:`PLAIN_AFTER` seconds, then at most one per
  :data:`PLAIN_EVERY` seconds, and a closing ``codev: STAGE: done in T s`` for a stage that
  printed one. Work shorter than a second prints nothing.

A stage that reports nothing for a while (one long step of a search) still gets its
plain line every :data:`PLAIN_EVERY` seconds, with the last count and the time (a
heartbeat), so no long run is silent. ``--quiet`` turns progress off; under ``--json`` it
stays on, on stderr: stdout is never written to.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

__all__ = ["PLAIN_AFTER", "PLAIN_EVERY", "describe", "stage_progress"]

#: seconds a stage runs before its first plain progress line
PLAIN_AFTER = 1.0
#: seconds between two plain progress lines of one stage
PLAIN_EVERY = 4.0  # (the heartbeat thread polls every 0.5 s: lines at most 4.5 s apart)
#: the unit of each stage's count
UNITS = {"synthesis": "regions", "verification": "branches"}


def describe(data: dict, unit: str) -> str:
    """The words of one progress event: ``"120 regions"``, ``"8 branches, sample 12"``.

    Parameters
    ----------
    data : dict
        The event's data: ``count`` and, for verification, ``samples`` (the sample reached),
        ``boxes`` (reachtube boxes so far), ``regions`` (the regions a law on demand has
        computed so far) and ``doing`` (what a long step is doing).
    unit : str
        What ``count`` counts.

    Returns
    -------
    str
    """
    words = [f"{data.get('count', 0):,} {unit}".strip()]
    if data.get("samples") is not None:
        words.append(f"sample {data['samples']:,}")
    if data.get("boxes") is not None:
        words.append(f"{data['boxes']:,} boxes")
    if data.get("regions") is not None:  # (a law on demand: regions computed so far)
        words.append(f"{data['regions']:,} regions computed")
    if data.get("doing"):  # the engine's heartbeat in a long step (limits.beat)
        words.append(str(data["doing"]))
    return ", ".join(words)


@contextmanager
def stage_progress(
    enabled: bool,
    units: dict[str, str] | None = None,
    *,
    stream: TextIO | None = None,
    tty: bool | None = None,
) -> Iterator[Callable[[str, str, dict], None]]:
    """An ``on_event(stage, event, data)`` callback that shows progress on stderr.

    Parameters
    ----------
    enabled : bool
        False: the callback does nothing.
    units : dict of str to str, optional
        What each stage's count counts (default :data:`UNITS`).
    stream : file, optional
        Where to write (default ``sys.stderr``).
    tty : bool, optional
        Live lines (True) or plain lines (False); default: whether ``stream`` is a terminal.

    Yields
    ------
    callable
        ``on_event(stage, event, data)`` with ``event`` one of "start", "progress" (``data``:
        ``count`` and optional ``samples``, ``boxes``) and "done" (``data["status"]``).
    """
    out = sys.stderr if stream is None else stream
    unit = UNITS if units is None else units
    if not enabled:
        yield lambda _stage, _event, _data: None
        return
    live = out.isatty() if tty is None else tty
    if not live:
        with _plain(out, unit) as on_event:
            yield on_event
        return
    from rich.console import Console
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(
        SpinnerColumn(),
        TextColumn("[bold]{task.description:<13}"),
        TextColumn("{task.fields[info]}"),
        TimeElapsedColumn(),
        transient=True,
        console=Console(file=out),
    ) as prog:
        tasks: dict[str, int] = {}
        last = [0.0]

        def on_event(stage: str, event: str, data: dict) -> None:
            if event == "start":
                tasks[stage] = prog.add_task(stage, info="")
            elif event == "progress" and stage in tasks:
                now = time.monotonic()
                if now - last[0] > 0.1:  # ~10 Hz
                    last[0] = now
                    prog.update(tasks[stage], info=describe(data, unit.get(stage, "")))
            elif event == "done" and stage in tasks:
                prog.update(tasks[stage], info=data["status"], completed=1, total=1)

        yield on_event


@contextmanager
def _plain(out: TextIO, unit: dict[str, str]) -> Iterator[Callable[[str, str, dict], None]]:
    """Plain, rate-limited progress lines (see the module docstring), and the heartbeat
    of stages that report nothing: a daemon thread that says the last count when a stage
    has been silent for :data:`PLAIN_EVERY` seconds (:data:`PLAIN_AFTER` at first)."""
    started: dict[str, float] = {}
    said: dict[str, float] = {}  # stage -> when its last line was written
    last: dict[str, dict] = {}  # stage -> the data of its last progress event
    lock = threading.Lock()
    stop = threading.Event()

    def line(text: str) -> None:
        try:
            print(f"codev: {text}", file=out, flush=True)
        except (OSError, ValueError):  # stderr closed: progress is not worth an error
            pass

    def say(stage: str, now: float, force: bool = False) -> None:
        t0 = started.setdefault(stage, now)
        before = said.get(stage)
        due = now - t0 >= PLAIN_AFTER if before is None else now - before >= PLAIN_EVERY
        if due or force:
            said[stage] = now
            line(f"{stage}: {describe(last.get(stage, {}), unit.get(stage, ''))}, "
                 f"{now - t0:.0f} s")

    def on_event(stage: str, event: str, data: dict) -> None:
        now = time.monotonic()
        with lock:
            if event == "start":
                started[stage] = now
                said.pop(stage, None)
                last.pop(stage, None)
                return
            started.setdefault(stage, now)
            if event == "progress":
                last[stage] = data
                say(stage, now)
            elif event == "done":
                if stage in said:
                    line(f"{stage}: {data.get('status', 'done')} in "
                         f"{now - started[stage]:.1f} s")
                started.pop(stage, None)
                said.pop(stage, None)

    def heartbeat() -> None:
        while not stop.wait(0.5):
            now = time.monotonic()
            with lock:
                for stage in list(started):
                    say(stage, now)

    beat = threading.Thread(target=heartbeat, name="codev-progress", daemon=True)
    beat.start()
    try:
        yield on_event
    finally:
        stop.set()
        beat.join(timeout=2)
