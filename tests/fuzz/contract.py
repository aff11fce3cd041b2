"""The house contract for any input, checked on one run of ``codev`` (in-process or real).

Every input ends in a verdict (or a synthesised law), or ONE line on stderr with exit status 2
naming the file (bad input), or a one-line limit message with exit status 1 -- never a Python
traceback, ``internal error``, a warning reaching the terminal, a hang, or the execution of
text from the input (a canary file that hostile text would create).

Shared by the fuzz properties (tests/fuzz/test_fuzz_*.py) and the held-out fuzzer
(tests/fuzz/heldout.py), which tabulates the same classes.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass, field
from pathlib import Path

#: every outcome class, in the order the held-out fuzzer tabulates them
GOOD = ("verdict", "exit2_one_line", "exit1_one_line")
BAD = (
    "internal_error",
    "traceback",
    "warning_spill",
    "hang",
    "injection",
    "bad_error_line",  # exit 2 / 1 with several lines, or not naming the file
    "other_status",
)
CLASSES = GOOD + BAD

#: a substring of the stdout of every successful ``run`` / ``verify`` / ``synth`` / ``export``
_SUCCESS_MARKS = ("verdict:", "critical regions", "written to", "regions, theta of length",
                  "journal:", "replay of ", "-- matches", "-- MISMATCH")


@dataclass
class Outcome:
    """One run: exit status (None: hang), output, warnings that reached the terminal."""

    argv: list[str]
    status: int | None
    stdout: str
    stderr: str
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    exception: str | None = None  # an exception that escaped main() (in-process)
    input: str = ""  # what was fed (the spec's text), for the report

    def short(self) -> str:
        return (f"input={self.input[:4000]!r}\n" if self.input else "") + (
            f"argv={self.argv}\nstatus={self.status} seconds={self.seconds:.1f}\n"
            f"stdout={self.stdout[-1500:]!r}\nstderr={self.stderr[-3000:]!r}\n"
            f"warnings={self.warnings[:5]}\nexception={self.exception}"
        )


class _Hang(BaseException):
    """Raised by the alarm in a run past its deadline (a BaseException: the CLI's
    ``except Exception`` does not swallow it)."""


@contextlib.contextmanager
def _deadline(seconds: float):
    if threading.current_thread() is not threading.main_thread():
        yield  # (no alarm outside the main thread: the subprocess runs are the backstop)
        return

    def on_alarm(_sig, _frame):
        raise _Hang

    previous = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _terminal_filters() -> None:
    """The warning filters of a plain ``python`` process (what would reach the terminal),
    with "always" so that each one is recorded."""
    warnings.resetwarnings()
    warnings.simplefilter("always")
    for cat in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
        warnings.simplefilter("ignore", cat)


def run_inprocess(argv: list[str], *, timeout: float = 20.0) -> Outcome:
    """``workbench.cli.main(argv)`` with stdout / stderr captured, warnings recorded, and an
    alarm after ``timeout`` seconds (status None: a hang). ``-q`` is the caller's business."""
    from workbench.cli import main

    out, err = io.StringIO(), io.StringIO()
    status: int | None = None
    exc_text = None
    t0 = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        _terminal_filters()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                with _deadline(timeout):
                    status = main(list(argv))
            except _Hang:
                status = None
            except SystemExit as exc:
                status = exc.code if isinstance(exc.code, int) else 2
            except BaseException as exc:  # noqa: BLE001 -- escaped main(): a traceback
                if isinstance(exc, KeyboardInterrupt):
                    raise
                exc_text = "".join(traceback.format_exception(exc))
                status = 1
    return Outcome(
        argv=list(argv),
        status=status,
        stdout=out.getvalue(),
        stderr=err.getvalue(),
        warnings=[f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})"
                  for w in caught],
        seconds=time.monotonic() - t0,
        exception=exc_text,
    )


def run_forked(argv: list[str], *, timeout: float = 20.0) -> Outcome:
    """:func:`run_inprocess` in a forked child (its own process group, killed whole past
    ``timeout``: status None). An alarm cannot stop a call stuck in compiled code (an LP
    solver, a huge numpy operation); a fork can be killed, and still runs ``main(argv)``
    with the modules already imported."""
    import pickle

    r, w = os.pipe()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:  # the child: run, send the outcome, leave without cleanup handlers
        code = 0
        try:
            os.close(r)
            os.setsid()
            o = run_inprocess(argv, timeout=timeout * 10)
            with os.fdopen(w, "wb") as f:
                pickle.dump(o, f)
        except BaseException:  # noqa: BLE001
            code = 3
        finally:
            os._exit(code)
    os.close(w)
    import select

    chunks: list[bytes] = []
    eof = False
    with os.fdopen(r, "rb") as f:
        fd = f.fileno()
        while not eof:
            left = timeout - (time.monotonic() - t0)
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                break
            chunk = os.read(fd, 1 << 16)
            eof = not chunk
            chunks.append(chunk)
    if not eof:  # past the deadline: a hang
        with contextlib.suppress(ProcessLookupError):
            os.killpg(pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        return Outcome(list(argv), None, "", "", [], time.monotonic() - t0)
    os.waitpid(pid, 0)
    with contextlib.suppress(ProcessLookupError):  # (a pool the command left behind)
        os.killpg(pid, signal.SIGKILL)
    try:
        return pickle.loads(b"".join(chunks))
    except Exception as exc:  # noqa: BLE001 -- the child died without an outcome
        return Outcome(list(argv), 1, "", "", [], time.monotonic() - t0,
                       exception=f"child died without an outcome ({exc!r})")


def run_subprocess(argv: list[str], *, cwd: str | Path, timeout: float = 60.0) -> Outcome:
    """``python -m workbench.cli ARGV`` as a real process in its own group (killed whole on
    timeout: status None), ``CODEV_DEBUG`` cleared."""
    env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [sys.executable, "-m", "workbench.cli", *map(str, argv)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        cwd=cwd,
        env=env,
        start_new_session=True,
    )
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
        status: int | None = proc.returncode
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        stdout, stderr = proc.communicate()
        status = None
    return Outcome(list(map(str, argv)), status, stdout, stderr, [], time.monotonic() - t0)


def classify(
    o: Outcome, *, names: tuple[str, ...] = (), canaries: tuple[Path, ...] = (),
    allow_warning_lines: bool = False,
) -> str:
    """The outcome's class (see ``CLASSES``). ``names``: one of them (a file name) must appear
    in an exit-2 line; ``canaries``: files that executed input text would have created;
    ``allow_warning_lines``: ``codev: warning: ...`` lines (a session's artifact recomputed)
    may precede the outcome."""
    if any(Path(c).exists() for c in canaries):
        return "injection"
    if o.status is None:
        return "hang"
    text = o.stdout + o.stderr
    if o.exception or "Traceback (most recent call last)" in text:
        return "traceback"
    if "internal error" in o.stderr:
        return "internal_error"
    lines = [ln for ln in o.stderr.splitlines() if ln.strip()]
    if allow_warning_lines:
        lines = [ln for ln in lines if not ln.startswith("codev: warning: ")]
    if o.warnings or any("Warning:" in ln or "warnings.warn" in ln for ln in lines):
        return "warning_spill"
    if o.status == 2:
        if len(lines) == 1 and lines[0].startswith("codev: error: ") and (
            not names or any(n in lines[0] for n in names)
        ):
            return "exit2_one_line"
        return "bad_error_line"
    if o.status in (0, 1) and any(mark in o.stdout for mark in _SUCCESS_MARKS) and not lines:
        return "verdict"
    if o.status == 1:
        if len(lines) == 1 and lines[0].startswith("codev: error: "):
            return "exit1_one_line"
        return "bad_error_line"
    return "other_status"


def check(o: Outcome, **kw) -> str:
    """Assert the contract (``classify`` in ``GOOD``); returns the class."""
    cls = classify(o, **kw)
    assert cls in GOOD, f"contract broken: {cls}\n{o.short()}"
    return cls


# --------------------------------------------------------------------------------------------
# A small TOML writer (the fuzz specs): tables as [sections], everything below inline
# --------------------------------------------------------------------------------------------


class Raw(str):
    """Literal TOML text written as is (a 5001-digit integer never goes through ``int``:
    ``str(int)`` of it is refused by Python, and the harness must not lift that limit in the
    process under test)."""


def _key(k: str) -> str:
    if k and all(c.isascii() and (c.isalnum() or c in "-_") for c in k):
        return k
    return _string(k)


def _string(s: str) -> str:
    out = ['"']
    for c in s:
        if c == '"':
            out.append('\\"')
        elif c == "\\":
            out.append("\\\\")
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def toml_value(v) -> str:
    if isinstance(v, Raw):
        return str(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return repr(v)
    if isinstance(v, float):
        if v != v:
            return "nan"
        if v in (float("inf"), float("-inf")):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_dumps(doc: dict) -> str:
    head, tables = [], []
    for k, v in doc.items():
        if isinstance(v, dict) and not isinstance(v, Raw):
            tables.append(f"\n[{_key(k)}]")
            tables.extend(f"{_key(kk)} = {toml_value(vv)}" for kk, vv in v.items())
        else:
            head.append(f"{_key(k)} = {toml_value(v)}")
    return "\n".join(head + tables) + "\n"
