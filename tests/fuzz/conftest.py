"""The fuzz tests' warm-up: imports and compiled kernels loaded once, before the first fork.

Every example runs ``main(argv)`` in a child forked from the test process
(``contract.run_forked``). A child inherits what the parent has loaded and nothing it loads
itself survives it, so with a cold parent each of them imported python-control / scipy.signal,
sympy's printers, the session and export modules (~2.5 s of CPU) and loaded its numba kernels
from the on-disk cache (~0.5-1 s more): 3-4 s of CPU per example, 245 s for the module at 10
examples per property. Warmed once here (~5 s of CPU; the kernels compiled first if the cache
is cold), a child costs what its own input costs (0.1-0.7 s for the bundled examples).

The warm-up runs real ``codev`` commands in-process -- every command the properties run, on
bundled inputs -- and then clears the engine's in-memory caches (plant models, enclosures,
formulations), so that a child starts as a fresh process would, less imports and compiled
code. What a cold child alone would have seen -- a warning raised on import, say -- is seen
by the warm-up's own runs, which ``test_warmup_keeps_the_contract`` checks like any example.
"""

from __future__ import annotations

import functools
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from tests.fuzz.contract import Outcome, run_inprocess
from tests.fuzz.mutations import EXAMPLES, ROOT

#: bundled examples whose runs load the remaining kernels and modules (nonlinear reach,
#: the mixed-norm design); each about a second when warm
_RUN = ("vanderpol.toml", "two_carts_mixed.toml")


def _commands(tmp: Path) -> list[list[str]]:
    spec = EXAMPLES / "double_integrator.toml"
    law = tmp / "di.npz"
    session = tmp / "session"
    shutil.copytree(ROOT / "sessions" / "double-integrator", session)
    return [
        ["synth", "-q", str(spec), "--out", str(law)],
        ["verify", "-q", str(spec), "--law", str(law)],
        ["export", str(law), "--python", str(tmp / "m.py"), "--c", str(tmp / "c")],
        *(["run", "-q", str(EXAMPLES / name)] for name in _RUN),
        ["replay", "-q", str(session)],
        ["session", str(session)],
        ["run", "-q", str(session / "spec.toml"), "--session", str(session)],
    ]


def _clear_engine_caches() -> None:
    """Empty the in-memory caches of ``codev_engine`` / ``workbench`` (``lru_cache`` functions
    and the formulations): a child then derives its plant models afresh, as a new process."""
    for name, module in list(sys.modules.items()):
        if module is None or not name.startswith(("codev_engine", "workbench")):
            continue
        for value in list(vars(module).values()):
            if isinstance(value, functools._lru_cache_wrapper):
                value.cache_clear()
    formulation = sys.modules.get("codev_engine.formulation")
    if formulation is not None:
        formulation._CACHE.clear()


@pytest.fixture(scope="session", autouse=True)
def fuzz_warmup() -> dict:
    """Run once per test process that runs a fuzz test; returns the outcomes and the cost."""
    from codev_engine.kernels import compile_group

    t0, c0 = time.perf_counter(), time.process_time()
    # (threads of tests that ran before in this process, e.g. Dask's idle offload thread
    # under xdist, are not the warm-up's: only what it starts is checked)
    before = set(threading.enumerate())
    for group in ("mp", "rest"):  # every kernel, loaded (or compiled into the cache)
        compile_group(group)
    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="codev-fuzz-warmup-") as tmp:
        for argv in _commands(Path(tmp)):
            outcomes.append(run_inprocess(argv, timeout=300))
    _clear_engine_caches()
    # a thread left running would be copied half-way into every fork (a held lock: a hang)
    extra = [t.name for t in threading.enumerate()
             if t is not threading.main_thread() and t not in before]
    return {"outcomes": outcomes, "threads": extra,
            "seconds": time.perf_counter() - t0, "cpu": time.process_time() - c0}
