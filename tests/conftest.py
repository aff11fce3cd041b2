"""Shared fixtures of the test suite."""

from __future__ import annotations

from pathlib import Path

import pytest

import codev_engine as ce

EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"


def pytest_configure(config):
    """Compile the engine's numba kernels once, before any test (and before the test
    processes of ``-n 2`` start): ``codev_engine.kernels.prepare``, its two groups at once,
    then the export's group, nothing when this checkout's kernels are ready.

    Without it each process compiled the kernels its first tests needed, at the same time
    as the other, on a fresh clone: about a minute of CPU each (a kernel in the cache is
    only loaded, a few seconds in all); and each ``codev`` the tests start would announce
    the compile on its stderr. A failure here is left to the tests to show.
    """
    if hasattr(config, "workerinput"):
        return
    from codev_engine.kernels import LATER, prepare

    quiet = lambda line, lasting: None  # noqa: E731
    first = prepare(announce=quiet)
    later = prepare(announce=quiet, groups=LATER)  # the export's (the export tests')
    config._codev_kernels = None if first is later is None else (first or 0.0) + (later or 0.0)


def pytest_report_header(config):
    """Say how long compiling the kernels ahead took (see ``pytest_configure``)."""
    seconds = getattr(config, "_codev_kernels", None)
    if seconds is None:
        return None
    return f"kernels compiled ahead (codev_engine.kernels.prepare): {seconds:.1f} s"


@pytest.fixture(scope="session")
def example_law():
    """``example_law(fname) -> (Problem, ExplicitLaw)`` for ``examples/<fname>``.

    Each example is loaded and synthesised at most once per test session (the magnetic
    pointer laws take seconds); a synthesis error is cached and re-raised.
    """
    cache: dict[str, tuple[ce.Problem, ce.ExplicitLaw] | BaseException] = {}

    def get(fname: str) -> tuple[ce.Problem, ce.ExplicitLaw]:
        if fname not in cache:
            try:
                problem = ce.load_spec(EXAMPLES_DIR / fname)
                cache[fname] = (problem, ce.synthesize(problem))
            except Exception as exc:
                cache[fname] = exc
        got = cache[fname]
        if isinstance(got, BaseException):
            raise got
        return got

    return get


@pytest.fixture(scope="module")
def cluster():
    """A real Dask ``LocalCluster`` of 2 worker processes (``ce.Executor(workers=2)``),
    started once per test module that needs one (~5 s to start and stop); tests may kill
    its workers: the nanny starts new ones. Not once per session: its scheduler runs in
    this process, and kept alive it slowed the Textual app tests that follow ~3x."""
    with ce.Executor(workers=2) as executor:
        assert executor.workers == 2
        yield executor


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Print the per-problem lines tests recorded with ``record_property("mp_testset", ...)``.

    tests/engine/test_mp_testset.py records one line per problem (regions found, reference
    count, time, verdict); they are listed, sorted, in an "mp_testset" section at the end.
    """
    lines: dict[str, str] = {}
    for reports in terminalreporter.stats.values():
        for rep in reports:
            for key, value in getattr(rep, "user_properties", ()) or ():
                if key == "mp_testset":
                    lines[rep.nodeid] = str(value)
    if lines:
        terminalreporter.section("mp_testset: regions found (ref = reference count)")
        for _, line in sorted(lines.items()):
            terminalreporter.write_line(line)


def pytest_collection_modifyitems(config, items):
    """Skip tests marked ``slow`` unless asked for (``-m slow`` or ``CODEV_SLOW=1``).

    One gate for the whole suite, so that a new slow test cannot creep into the default run
    (the suite must stay under 10 minutes on 2 cores); the checks run before an issue is
    resolved with ``pytest -m slow``.
    """
    import os

    if "slow" in (config.getoption("markexpr") or "") or os.environ.get("CODEV_SLOW"):
        return
    skip = pytest.mark.skip(reason="slow: run with -m slow (or CODEV_SLOW=1)")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
