"""The engine's compiled kernels, compiled ahead of their first use.

The hot loops of the mp-QP search (``mp/mpqp_kernel.py``, ``mp/active_sets.py``), the
mp-LP basis graph (``mp/mplp_kernel.py``), the LPs and boxes of regions
(``geometry/lp_kernel.py``), the point locator (``geometry/locate_kernel.py``) and the
search tree of the C export (``deploy/prune_kernel.py``) are numba functions cached in their
package's ``__pycache__``. A fresh install compiles each on first use: about a minute of CPU
in all on a 2-core machine, paid by the first synthesis or verification that needs it. ::

    python -m codev_engine.kernels            # every kernel, in two processes
    python -m codev_engine.kernels mp         # one group

compiles them ahead, by running each group's real code path once on a small design (the
bundled double integrator's MPC) with the compiled path forced, so that exactly the
signatures the engine uses are compiled. A kernel already in the cache is only loaded.
The test suite does this before its worker processes start (``tests/conftest.py``), so
they do not each compile the same kernels.

**Announced, once.** A wheel cannot run code when it is installed, and numba's machine code
is tied to the CPU, numba, llvmlite and Python it was compiled with (and to the sources'
hashes), so compiled code shipped in the package would be refused by most machines. What
the user meets instead: ``make`` set-up compiles the kernels (``make demo``), and the
commands that compute (``codev run``, ``synth``, ``verify``, ``sweep``, ``replay``,
``export``, ``tui``) call :func:`prepare` first, which, when this installation's kernels
were never compiled into numba's cache, says so and compiles them with its progress
("preparing the solver kernels, once: 1/2 ...") before any stage starts, so that no stage's
time (a sweep's row included) is charged with it. A stamp beside numba's cache records the
compile (:func:`ready`); it names the kernels' sources, numba and Python, so an upgrade or an
edit prepares again.
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

__all__ = ["GROUPS", "compile_group", "compile_all", "ready", "prepare"]

#: the bundled double integrator (``examples/double_integrator.toml``) without its
#: verification (and a symmetric Q for norm 2): solved in a second
_DESIGN = """
name = "kernels"
[plant]
states = ["x1", "x2"]
inputs = ["u"]
dynamics = ["x2", "u"]
[model]
sample_time = 1.0
[mpc]
horizon = {horizon}
norm = "{norm}"
Q = {Q}
R = [[0.8]]
x_min = [-10.0, -10.0]
x_max = [10.0, 10.0]
u_min = [-1.0]
u_max = [1.0]
"""


def _design(norm: str, horizon: int):
    from codev_engine.pipeline import loads_spec

    Q = "[[1.0, 0.0], [0.0, 1.0]]" if norm == "2" else "[[1.0, 1.0], [0.0, 1.0]]"
    return loads_spec(_DESIGN.format(norm=norm, horizon=horizon, Q=Q))


def _mp() -> None:
    """The mp-QP search's kernel from the first region on (and the LP kernel it calls)."""
    from codev_engine.mp import mpqp
    from codev_engine.synthesis import synthesize

    saved = mpqp.JIT_AFTER
    mpqp.JIT_AFTER = 0
    try:
        synthesize(_design("2", 2))
    finally:
        mpqp.JIT_AFTER = saved


def _rest() -> None:
    """The mp-LP basis graph's kernel, the region boxes, the point locator and the export
    tree's kernel."""
    from codev_engine.deploy.export import export_c
    from codev_engine.mp import mplp_graph
    from codev_engine.synthesis import synthesize

    saved = mplp_graph.JIT_AFTER
    mplp_graph.JIT_AFTER = 0
    try:
        law = synthesize(_design("inf", 8))  # 122 regions
    finally:
        mplp_graph.JIT_AFTER = saved
    lo, hi = law.boxes  # one compiled call (from geometry.locate.COMPILED_BOXES regions)
    rng = np.random.default_rng(0)
    law.evaluate(rng.uniform(lo.min(axis=0), hi.max(axis=0), size=(4096, law.n)))
    import tempfile

    with tempfile.TemporaryDirectory() as out:
        export_c(law, out, method="bst")
    # and the large-partition policy's candidate filter (a law of over LARGE_FROM regions
    # has no table of extents): forced here on the small law
    from codev_engine.deploy import bst, plan

    saved_t, saved_l = bst.TABLE_ENTRIES, plan.LARGE_FROM
    bst.TABLE_ENTRIES, plan.LARGE_FROM = 0, 0
    try:
        plan.plan(law, "bst")
    finally:
        bst.TABLE_ENTRIES, plan.LARGE_FROM = saved_t, saved_l


#: group name -> what compiles it (each runs in its own process in ``compile_all``)
GROUPS: dict[str, Callable[[], None]] = {"mp": _mp, "rest": _rest}


def compile_group(name: str) -> float:
    """Compile (or load from the cache) one group's kernels in this process.

    Parameters
    ----------
    name : str
        A key of :data:`GROUPS`.

    Returns
    -------
    float
        The CPU seconds it took (about 0.5 s when every kernel was in the cache).
    """
    t0 = time.process_time()
    GROUPS[name]()
    return time.process_time() - t0


def compile_all(
    *, python: str = sys.executable, on_done: Callable[[str, float], None] | None = None
) -> dict[str, float]:
    """Compile every group's kernels, each group in its own process at the same time.

    Parameters
    ----------
    python : str
        The interpreter to run (this one by default).
    on_done : callable, optional
        Called as ``on_done(name, seconds)`` as each group's process ends (``seconds``
        negative for a group that failed), and every second as ``on_done("", seconds)``
        while any still runs: progress.

    Returns
    -------
    dict of str to float
        The wall seconds of each group's process; a group that failed is left out (its
        kernels then compile on first use, as without this call).
    """
    t0 = time.perf_counter()
    procs = {
        name: subprocess.Popen([python, "-m", "codev_engine.kernels", name],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for name in GROUPS
    }
    done: dict[str, float] = {}
    tick = t0
    try:
        while procs:
            for name, p in list(procs.items()):
                if p.poll() is not None:
                    del procs[name]
                    seconds = time.perf_counter() - t0
                    if p.returncode == 0:
                        done[name] = seconds
                    if on_done is not None:
                        on_done(name, seconds if p.returncode == 0 else -seconds)
            time.sleep(0.05)
            if on_done is not None and procs and time.perf_counter() - tick >= 1.0:
                tick = time.perf_counter()
                on_done("", tick - t0)
    finally:  # interrupted (Ctrl-C): no compiler process outlives the command
        for p in procs.values():
            p.kill()
            p.wait()
    return done


# -- ready, or prepared once with its progress ----------------------------------------------

#: the modules holding numba functions (their sources are part of the stamp)
_SOURCES = (
    "geometry/lp_kernel.py", "geometry/locate_kernel.py", "geometry/vertices_kernel.py",
    "mp/mpqp_kernel.py", "mp/mplp_kernel.py", "mp/active_sets.py", "deploy/prune_kernel.py",
)  # fmt: skip
_STAMP = "codev-kernels-ready"
_ROOT = Path(__file__).parent


def _key() -> str:
    """What the stamp holds for this installation: codev, numba, Python, the machine, the
    numba cache folder asked for and the kernels' sources (numba's own cache keys on the
    same: a change to any of them compiles again)."""
    from importlib.metadata import version

    from codev_engine.version import __version__

    digest = hashlib.sha256()
    for rel in _SOURCES:
        digest.update((_ROOT / rel).read_bytes())
    return " ".join((__version__, version("numba"), platform.python_version(),
                     platform.machine(), os.environ.get("NUMBA_CACHE_DIR", ""),
                     digest.hexdigest()[:16]))


def _stamp_path() -> Path | None:
    """The stamp's file: in numba's cache folder of the LP kernel (the package's
    ``__pycache__``, ``$NUMBA_CACHE_DIR``'s or numba's user-wide one, as numba chose);
    None when numba keeps no disk cache there. Imports numba (about a second)."""
    from codev_engine.geometry import lp_kernel

    try:
        return Path(lp_kernel.chebyshev._cache._cache_path) / _STAMP
    except AttributeError:  # a numba without that attribute: no stamp, prepare every time
        return None


def ready() -> bool:
    """True when this installation's kernels were compiled into numba's cache (a stamp
    written by :func:`prepare` says so).

    A few milliseconds where numba caches beside the sources (the usual case: a
    writable installation, no ``$NUMBA_CACHE_DIR``); elsewhere numba is imported to ask
    where its cache is (about a second).

    Returns
    -------
    bool
    """
    key = _key()
    # the usual folder first, read without importing numba
    usual = _ROOT / "geometry" / "__pycache__" / _STAMP
    candidates = [usual] if not os.environ.get("NUMBA_CACHE_DIR") else []
    for path in candidates:
        try:
            if path.read_text(encoding="utf-8") == key:
                return True
        except OSError:
            pass
    path = _stamp_path()
    try:
        return path is not None and path.read_text(encoding="utf-8") == key
    except OSError:
        return False


def prepare(announce: Callable[[str, bool], None] | None = None) -> float | None:
    """Compile the kernels now, announced, unless :func:`ready`.

    Parameters
    ----------
    announce : callable, optional
        ``announce(line, lasting)`` receives the progress: ``"preparing the solver
        kernels, once ...: 0/2 ..."``, a line per group done and a last one with the time
        (``lasting`` True), and every second the elapsed time (``lasting`` False: a
        terminal rewrites it in place). Default: stderr.

    Returns
    -------
    float or None
        The wall seconds it took; None when the kernels were ready (nothing said or done).
    """
    if ready():
        return None
    if announce is None:
        announce = _Announcer()
    n = len(GROUPS)
    count = [0]
    head = "preparing the solver kernels, once (about a minute, then cached)"
    announce(f"{head}: 0/{n} ...", True)

    def on_done(name: str, seconds: float) -> None:
        if name:
            count[0] += 1
            what = "done" if seconds >= 0 else "failed: compiled on first use instead"
            announce(f"{head}: {count[0]}/{n} ({name} {what}, {abs(seconds):.0f} s)", True)
        else:
            announce(f"{head}: {count[0]}/{n} ... {seconds:.0f} s", False)

    t0 = time.perf_counter()
    done = compile_all(on_done=on_done)
    seconds = time.perf_counter() - t0
    if len(done) == n:
        path = _stamp_path()
        if path is not None:
            try:
                path.write_text(_key(), encoding="utf-8")
            except OSError:  # a read-only cache folder: numba then compiles in memory anyway
                pass
    announce(f"solver kernels ready ({seconds:.0f} s; not again on this machine)", True)
    return seconds


class _Announcer:
    """Progress lines on stderr; on a terminal the passing ones (the elapsed time) rewrite
    one line, elsewhere (a log) they are left out."""

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()

    def __call__(self, line: str, lasting: bool) -> None:
        if self.tty:
            sys.stderr.write("\r\033[K" + line + ("\n" if lasting else ""))
        elif lasting:
            sys.stderr.write(line + "\n")
        sys.stderr.flush()


def _main(argv: list[str]) -> int:
    if argv == ["--prepare"]:  # make's set-up: announced, and nothing when ready
        prepare()
        return 0
    names = argv or list(GROUPS)
    unknown = [n for n in names if n not in GROUPS]
    if unknown:
        print(f"codev_engine.kernels: no group {unknown[0]!r} (groups: {', '.join(GROUPS)})",
              file=sys.stderr)
        return 2
    if len(names) == 1:
        print(f"{names[0]}: {compile_group(names[0]):.1f} s CPU")
        return 0
    done = compile_all()
    for name in names:
        print(f"{name}: " + (f"{done[name]:.1f} s" if name in done else "failed"))
    return 0 if len(done) == len(names) else 1


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1:]))
