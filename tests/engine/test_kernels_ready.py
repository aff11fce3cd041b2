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
from pathlib import Path

import pytest

from codev_engine.kernels import prepare, ready

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


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


def test_a_compiling_process_does_not_prepare_again(tmp_path):
    """The compile's own processes run the pipeline's stages (``ce.synthesize``), which
    prepare the kernels: there it must be nothing, not a compile starting another."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"),
               CODEV_KERNELS_COMPILING="1")
    code = ("from codev_engine.kernel_cache import prepare, ready\n"
            "print(ready(), prepare(announce=lambda line, lasting: print(line)))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120, check=True)
    assert out.stdout.strip() == "False None", out.stderr


@pytest.mark.slow
def test_a_python_sweep_on_a_fresh_cache_announces_the_compile_first(tmp_path):
    """``ce.sweep`` from Python (a notebook, a script) on a fresh installation's cache says
    it prepares the kernels, and does it before the first design (whose row then holds
    no compile); the ``ce.synthesize`` after it says nothing (issue 41)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))
    code = (
        "import sys\n"
        "import codev_engine as ce\n"
        f"p = ce.load_spec({str(EXAMPLES / 'double_integrator.toml')!r})\n"
        "rows = ce.sweep(p, {'mpc.horizon': [2, 3]},\n"
        "    progress=lambda i, row: print('row', i, file=sys.stderr, flush=True))\n"
        "print('after', file=sys.stderr, flush=True)\n"
        "ce.synthesize(p)\n"
        "print('rows', [r['error'] for r in rows])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=900, check=True)
    said = out.stderr.splitlines()
    assert said[0].startswith("preparing the solver kernels, once"), out.stderr
    ready_at = next(i for i, line in enumerate(said) if line.startswith("solver kernels ready"))
    assert ready_at < said.index("row 0") < said.index("after"), out.stderr
    assert said[-1] == "after", out.stderr  # synthesize: nothing more to say
    assert out.stdout.strip() == "rows [None, None]"
