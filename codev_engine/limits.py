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

The environment variable ``CODEV_LIMITS`` overrides them, e.g.
``CODEV_LIMITS="branches=2e6,tube_bytes=8e9"`` (read when a synthesis or a verification
starts; an unknown name or a value that is not a positive number is an error naming it).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from contextlib import contextmanager

from codev_engine.errors import SolverError, SpecError

__all__ = [
    "DEFAULTS",
    "LIMITS_ENV",
    "TimeLimitError",
    "check_time",
    "deadline",
    "limits",
    "stage_deadline",
    "time_over",
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


#: the deadline in force (``time.monotonic()`` seconds) and the limit it came from (s)
_DEADLINE: list[tuple[float, float] | None] = [None]


@contextmanager
def deadline(seconds: float | None) -> Iterator[None]:
    """Run the body under a deadline ``seconds`` from now (None or 0: no new deadline).

    Deadlines nest: the earlier one is in force. The engine checks it with
    :func:`check_time` / :func:`time_over` where it reports progress.

    Parameters
    ----------
    seconds : float or None
        The time limit.

    Yields
    ------
    None
    """
    previous = _DEADLINE[0]
    if seconds:
        end = time.monotonic() + float(seconds)
        if previous is None or end < previous[0]:
            _DEADLINE[0] = (end, float(seconds))
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
