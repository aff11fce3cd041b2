"""The solver kernels' one-time compile is known to be done, or not (issue 41).

``tests/conftest.py`` prepared this checkout's kernels (``codev_engine.kernels.prepare``)
before any test: here they are ready, and ``prepare`` says and does nothing; a fresh numba
cache (``NUMBA_CACHE_DIR`` on an empty folder, as a fresh installation has) is not ready.
The compile itself, announced, is the slow wheel test's
(``tests/contract/test_wheel.py::test_first_run_from_a_fresh_wheel``).
"""

from __future__ import annotations

import os
import subprocess
import sys

from codev_engine.kernels import prepare, ready


def test_this_checkout_is_ready_and_prepare_says_nothing():
    said: list[str] = []
    assert ready()
    assert prepare(announce=lambda line, lasting: said.append(line)) is None
    assert said == []


def test_a_fresh_numba_cache_is_not_ready(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    out = subprocess.run(
        [sys.executable, "-c", "from codev_engine.kernels import ready; print(ready())"],
        env=env, capture_output=True, text=True, timeout=120, check=True,
    )
    assert out.stdout.strip() == "False", out.stderr
