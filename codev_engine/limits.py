"""The engine's limits on work that grows while it runs (docs/spec.md, "Limits").

The loader refuses a spec whose size is too large before any work starts
(``pipeline.check_size``). Some work cannot be sized from the fields: how many critical
regions a synthesis finds, how many branches and reachtube boxes a verification explores.
These limits stop it while it runs, with a one-line message that names what to change:

* ``region_bytes``: the memory the critical regions of one synthesis may take (the
  synthesis ends in a ``SolverError``, exit 1);
* ``branches``: branch periods one verification explores (one set through one sample
  period), and ``tube_bytes``: the memory its reachtube's boxes may take; past either, the
  verdict is ``unknown`` with reason ``"limit"`` (a limitation of the verifier, not of the
  design).

* ``time``: seconds a synthesis or a verification may run (0, the default: no limit;
  ``codev --time-limit`` sets one for a whole command). It is a deadline the engine checks
  cooperatively where it reports progress (each branch period of a verification, each
  region of a synthesis, between the stages): a verification past it is ``unknown`` with
  reason ``"limit"``, a synthesis ends in a :class:`TimeLimitError` (a ``SolverError``,
  exit 1), both saying the time and what to change.

A verification's own time budget (``[verify] time_budget``, ``codev verify --budget``) is a
deadline too (:func:`budget`), but it ends in a verdict that says how far the proof got:
``unknown`` with reason ``"budget"`` (:func:`time_over_kind` tells the two apart).

Long steps report progress through a heartbeat (:func:`heartbeat`, :func:`beat`): the loops
that can hold for long (LPs, vertex enumerations, enclosures, simulations) call
:func:`beat`, which repeats the last progress report, with what is being done, once a
second has passed without one -- so no progress line stops for more than a few seconds.

The environment variable ``CODEV_LIMITS`` overrides them, e.g.
``CODEV_LIMITS="branches=2e6,tube_bytes=8e9"`` (read when a synthesis or a verification
starts; an unknown name or a value that is not a positive number is an error naming it).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from codev_engine.errors import SolverError, SpecError

__all__ = [
    "DEFAULTS",
    "LIMITS_ENV",
    "DeadlineReached",
    "TimeLimitError",
    "beat",
    "budget",
    "check_time",
    "deadline",
    "heartbeat",
    "limits",
    "stage_deadline",
    "stoppable",
    "time_over",
    "time_over_kind",
]

#: the environment variable that overrides :data:`DEFAULTS`
LIMITS_ENV = "CODEV_LIMITS"

#: the limits when ``CODEV_LIMITS`` does not set them
DEFAULTS: dict[str, int] = {
    "region_bytes": 2**32,  # 4 GiB of critical regions in one synthesis
    "branches": 500_000,  # branch periods of one verification
    "tube_bytes": 2**31,  # 2 GiB of reachtube boxes ((2 n + 3) × 8 bytes each)
    "time": 0,  # seconds of one synthesis or verification; 0: no limit
}


def limits() -> dict[str, int]:
    """The limits in force: :data:`DEFAULTS`, updated from ``CODEV_LIMITS``.

    Returns
    -------
    dict of str to int

    Raises
    ------
    SpecError
        ``CODEV_LIMITS`` names an unknown limit or gives a value that is not a positive
        number (``field="CODEV_LIMITS"``).
    """
    out = dict(DEFAULTS)
    text = os.environ.get(LIMITS_ENV, "").strip()
    for item in filter(None, (p.strip() for p in text.split(","))):
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in DEFAULTS:
            raise SpecError(
                f"unknown limit {name!r} (known: {', '.join(DEFAULTS)})", field=LIMITS_ENV
            )
        try:
            number = float(value)
        except ValueError:
            number = float("nan")
        if not number >= 1 or number == float("inf"):
            raise SpecError(f"{name}: expected a positive number, got {value!r}", field=LIMITS_ENV)
        out[name] = int(number)
    return out


class TimeLimitError(SolverError):
    """The time limit (``--time-limit``, ``CODEV_LIMITS=time=...``) was reached.

    Parameters
    ----------
    message : str
        One line: what stopped, after how long, and what to change.
    """


#: the deadline in force (``time.monotonic()`` seconds), the limit it came from (s) and its
#: kind (``"limit"``: ``--time-limit``; ``"budget"``: a verification's ``time_budget``)
_DEADLINE: list[tuple[float, float, str] | None] = [None]


@contextmanager
def deadline(seconds: float | None, kind: str = "limit") -> Iterator[None]:
    """Run the body under a deadline ``seconds`` from now (None or 0: no new deadline).

    Deadlines nest: the earlier one is in force. The engine checks it with
    :func:`check_time` / :func:`time_over` where it reports progress.

    Parameters
    ----------
    seconds : float or None
        The time limit.
    kind : {"limit", "budget"}
        What the deadline is (:func:`time_over_kind`).

    Yields
    ------
    None
    """
    previous = _DEADLINE[0]
    if seconds:
        end = time.monotonic() + float(seconds)
        if previous is None or end < previous[0]:
            _DEADLINE[0] = (end, float(seconds), kind)
    try:
        yield
    finally:
        _DEADLINE[0] = previous


@contextmanager
def stage_deadline() -> Iterator[None]:
    """:func:`deadline` of ``limits()["time"]`` (``CODEV_LIMITS=time=...``) for one stage.

    Yields
    ------
    None
    """
    with deadline(limits()["time"] or None):
        yield


@contextmanager
def budget(seconds: float | None) -> Iterator[None]:
    """A verification's time budget: :func:`deadline` of kind ``"budget"``.

    Parameters
    ----------
    seconds : float or None
        The budget (None: none).

    Yields
    ------
    None
    """
    with deadline(seconds, "budget"):
        yield


def time_over_kind() -> tuple[str, float] | None:
    """The kind (``"limit"`` or ``"budget"``) and seconds of the passed deadline, else None.

    Returns
    -------
    tuple of (str, float) or None
    """
    current = _DEADLINE[0]
    if current is not None and time.monotonic() >= current[0]:
        return current[2], current[1]
    return None


def time_over() -> float | None:
    """The limit in seconds when the deadline has passed, else None.

    Returns
    -------
    float or None
    """
    current = _DEADLINE[0]
    if current is not None and time.monotonic() >= current[0]:
        return current[1]
    return None


def check_time(what: str, fix: str) -> None:
    """Raise :class:`TimeLimitError` when the deadline has passed.

    Parameters
    ----------
    what : str
        What stops (``"synthesis"``).
    fix : str
        What to change besides the limit (``"shorten mpc.horizon"``).

    Raises
    ------
    TimeLimitError
        One line: the limit, what stopped, and what to change.
    """
    over = time_over()
    if over is not None:
        raise TimeLimitError(
            f"time limit reached: the {what} stopped after {over:g} s; {fix}, or raise "
            "--time-limit / CODEV_LIMITS=time=SECONDS"
        )


#: seconds without a progress report after which :func:`beat` repeats the last one
BEAT_EVERY = 1.0
#: the heartbeat of the work running in this thread (a progress callback, its last report)
_BEAT = threading.local()


@contextmanager
def heartbeat(
    progress: Callable[[dict], None] | None, every: float | None = None
) -> Iterator[Callable[[dict], None] | None]:
    """Wrap a progress callback so that :func:`beat` can repeat its last report.

    Parameters
    ----------
    progress : callable or None
        Called with a dict of counters (None: no reports).
    every : float, optional
        Seconds without a report after which :func:`beat` reports again (default
        :data:`BEAT_EVERY`, read now).

    Yields
    ------
    callable or None
        The callback to give the engine: it reports and remembers the report (None without
        ``progress``; :func:`stoppable` then still stops at the deadline).
    """
    every = BEAT_EVERY if every is None else every
    state = {"fn": progress, "stats": {}, "last": time.monotonic(), "every": float(every)}

    def report(stats: dict) -> None:
        state["stats"], state["last"] = dict(stats), time.monotonic()
        progress(stats)

    previous = getattr(_BEAT, "state", None)
    _BEAT.state = state
    try:
        yield None if progress is None else report
    finally:
        _BEAT.state = previous


class DeadlineReached(Exception):  # noqa: N818 (not an error: a stop, made a verdict)
    """A deadline passed inside a long step under :func:`stoppable` (from :func:`beat`).

    Parameters
    ----------
    kind : {"limit", "budget"}
    seconds : float
        The deadline's limit.
    """

    def __init__(self, kind: str, seconds: float):
        super().__init__(f"{kind} of {seconds:g} s reached")
        self.kind, self.seconds = kind, seconds


@contextmanager
def stoppable() -> Iterator[None]:
    """Within the body, :func:`beat` raises :class:`DeadlineReached` past the deadline.

    For work whose caller turns the exception into a verdict (a reach engine's run, which
    keeps what it explored): a step as long as a minute then stops within a beat of its
    deadline instead of at the next branch period. Without a heartbeat in force, nothing.

    Yields
    ------
    None
    """
    state = getattr(_BEAT, "state", None)
    previous = None if state is None else state.get("stop", False)
    if state is not None:
        state["stop"] = True
    try:
        yield
    finally:
        if state is not None:
            state["stop"] = previous


def beat(doing: str) -> None:
    """Repeat the last progress report, with ``doing``, when none came for a while.

    Cheap (a clock read) when no heartbeat is in force or one reported recently: the loops
    that can hold for seconds call it once per step. Under :func:`stoppable`, past the
    deadline it raises :class:`DeadlineReached`.

    Parameters
    ----------
    doing : str
        What is being done (``"vertex enumeration"``), shown on the progress line.

    Raises
    ------
    DeadlineReached
        Under :func:`stoppable`, once the deadline has passed.
    """
    state = getattr(_BEAT, "state", None)
    if state is None:
        return
    if state.get("stop"):
        over = time_over_kind()
        if over is not None:
            raise DeadlineReached(*over)
    now = time.monotonic()
    if state["fn"] is None or now - state["last"] < state["every"]:
        return
    state["last"] = now
    state["fn"]({**state["stats"], "doing": doing})
