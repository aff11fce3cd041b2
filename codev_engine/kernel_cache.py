"""Whether the engine's compiled kernels are in numba's cache, and compiling them, announced.

The compile itself runs the pipeline's stages once (:mod:`codev_engine.kernels`, above every
layer); this module only starts it, in processes of its own (``python -m
codev_engine.kernels GROUP``), and keeps the stamp that says it was done, so the entry points
below the pipeline's top (:func:`codev_engine.sweeps.sweep`, ``synthesize``, ``verify``,
``Session.run``) can prepare the kernels, announced, before their first stage instead of
compiling in silence inside it (and charging the compile to a design's time). See
:mod:`codev_engine.kernels` for why compiled code is not shipped.

:func:`ready` is a few milliseconds (once per process: the answer is kept), so every entry
point may ask.
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

__all__ = ["GROUP_NAMES", "LATER", "compile_all", "ready", "prepare"]

#: the groups of :data:`codev_engine.kernels.GROUPS` prepared before the first command
#: that computes, each compiled in its own process
GROUP_NAMES: tuple[str, ...] = ("mp", "rest")
#: the groups prepared when first needed (announced the same way): the C export's search
#: tree (``deploy.bst``), 12 s of CPU that a first synthesis and verification never use
LATER: tuple[str, ...] = ("export",)
#: set in the compiling processes: their own stages must not prepare again (they are the
#: preparation)
_COMPILING = "CODEV_KERNELS_COMPILING"


def compile_all(
    *, python: str = sys.executable, on_done: Callable[[str, float], None] | None = None,
    groups: tuple[str, ...] = GROUP_NAMES,
) -> dict[str, float]:
    """Compile the groups' kernels, each group in its own process at the same time.

    Parameters
    ----------
    groups : tuple of str
        Keys of :data:`codev_engine.kernels.GROUPS`; default :data:`GROUP_NAMES`.
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
    env = dict(os.environ, **{_COMPILING: "1"})
    procs = {
        name: subprocess.Popen([python, "-m", "codev_engine.kernels", name], env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for name in groups
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
#: the groups this process found ready, or prepared (either way not asked again)
_known_ready: set[tuple[str, ...]] = set()


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


def _stamp_name(groups: tuple[str, ...]) -> str:
    """The stamp of the first groups keeps its name (the checkouts and installations
    prepared before the export's kernels were a group of their own)."""
    return _STAMP if groups == GROUP_NAMES else "-".join((_STAMP, *groups))


def _stamp_path() -> Path | None:
    """The stamp's file: in numba's cache folder of the LP kernel (the package's
    ``__pycache__``, ``$NUMBA_CACHE_DIR``'s or numba's user-wide one, as numba chose);
    None when numba keeps no disk cache there. Imports numba (about a second)."""
    from codev_engine.geometry import lp_kernel

    try:
        return Path(lp_kernel.chebyshev._cache._cache_path) / _STAMP
    except AttributeError:  # a numba without that attribute: no stamp, prepare every time
        return None


def ready(groups: tuple[str, ...] = GROUP_NAMES) -> bool:
    """True when this installation's kernels were compiled into numba's cache (a stamp
    written by :func:`prepare` says so).

    A few milliseconds where numba caches beside the sources (the usual case: a
    writable installation, no ``$NUMBA_CACHE_DIR``); elsewhere numba is imported to ask
    where its cache is (about a second).

    Parameters
    ----------
    groups : tuple of str
        Which groups: default those prepared before the first command that computes;
        :data:`LATER` for the export's.

    Returns
    -------
    bool
    """
    if groups in _known_ready:
        return True
    if _read_stamp(_stamp_name(groups)):
        _known_ready.add(groups)
        return True
    return False


def _read_stamp(name: str) -> bool:
    """The stamp ``name`` beside numba's cache holds this installation's key."""
    key = _key()
    # the usual folder first, read without importing numba
    usual = _ROOT / "geometry" / "__pycache__" / name
    candidates = [usual] if not os.environ.get("NUMBA_CACHE_DIR") else []
    for path in candidates:
        try:
            if path.read_text(encoding="utf-8") == key:
                return True
        except OSError:
            pass
    path = _stamp_path()
    try:
        return path is not None and (path.parent / name).read_text(encoding="utf-8") == key
    except OSError:
        return False


def prepare(
    announce: Callable[[str, bool], None] | None = None, *,
    groups: tuple[str, ...] = GROUP_NAMES,
) -> float | None:
    """Compile the kernels now, announced, unless :func:`ready`.

    Parameters
    ----------
    groups : tuple of str
        Default the groups every synthesis and verification needs; :data:`LATER` for the
        export's (``deploy.bst`` asks for them when it first builds a tree).
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
    if os.environ.get(_COMPILING) or ready(groups):  # (a compiling process is the preparation)
        return None
    if announce is None:
        announce = _Announcer()
    n = len(groups)
    count = [0]
    head = ("preparing the solver kernels, once (about a minute, then cached)"
            if groups == GROUP_NAMES else
            f"preparing the {'/'.join(groups)} kernels, once (about 15 s, then cached)")
    announce(f"{head}: 0/{n} ...", True)

    def on_done(name: str, seconds: float) -> None:
        if name:
            count[0] += 1
            what = "done" if seconds >= 0 else "failed: compiled on first use instead"
            announce(f"{head}: {count[0]}/{n} ({name} {what}, {abs(seconds):.0f} s)", True)
        else:
            announce(f"{head}: {count[0]}/{n} ... {seconds:.0f} s", False)

    t0 = time.perf_counter()
    done = compile_all(on_done=on_done, groups=groups)
    seconds = time.perf_counter() - t0
    if len(done) == n:
        path = _stamp_path()
        if path is not None:
            try:
                (path.parent / _stamp_name(groups)).write_text(_key(), encoding="utf-8")
            except OSError:  # a read-only cache folder: numba then compiles in memory anyway
                pass
    # not again in this process, stamped or not (a read-only cache folder: every later entry
    # point would start the compile again)
    _known_ready.add(groups)
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
