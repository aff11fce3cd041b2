"""Shared fixtures of the test suite."""

from __future__ import annotations

from pathlib import Path

import pytest

import codev_engine as ce

EXAMPLES_DIR = Path(__file__).resolve().parents[1] / "examples"


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
