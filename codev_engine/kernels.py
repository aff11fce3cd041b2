"""The engine's compiled kernels, compiled ahead of their first use.

The hot loops of the mp-QP search (``mp/mpqp_kernel.py``, ``mp/active_sets.py``), the
mp-LP basis graph (``mp/mplp_kernel.py``), the LPs and boxes of regions
(``geometry/lp_kernel.py``), the point locator (``geometry/locate_kernel.py``) and the
search tree of the C export (``deploy/prune_kernel.py``) are numba functions cached in their
package's ``__pycache__``. A fresh install compiles each on first use: about a minute of CPU
in all on a 2-core machine, paid by the first synthesis or verification that needs it. ::

    python -m codev_engine.kernels            # every group, a process each
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
edit prepares again. The C export's kernels (the group ``export``, 17 s of CPU) are not
among them: they are prepared, announced the same way, when a search tree is first built
(``deploy.bst``; ``codev export``), so the step before a first synthesis is shorter
(``python -m codev_engine.kernels --prepare-all`` takes both steps). The engine's own entry
points (``ce.sweep``, ``ce.synthesize``, ``ce.verify``, ``Session.run``) prepare the same
way, so a notebook or a script meets the same announcement
(:mod:`codev_engine.kernel_cache`, where ``ready`` and ``prepare`` live).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable

import numpy as np

# the stamp, the processes and the announcement live below the pipeline, so that its entry
# points can prepare too (re-exported here: the CLI's, the workbench's and the tests' name)
from codev_engine.kernel_cache import GROUP_NAMES, LATER, compile_all, prepare, ready

__all__ = ["GROUPS", "LATER", "compile_group", "compile_all", "ready", "prepare"]

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
    """The mp-LP basis graph's kernel, the region boxes and the point locator."""
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


def _export() -> None:
    """The C export's search tree kernels (``deploy/prune_kernel.py``): prepared when an
    export first needs them, not with the others (12 s of CPU few newcomers use)."""
    import tempfile

    from codev_engine.deploy.export import export_c
    from codev_engine.mp import mplp_graph
    from codev_engine.synthesis import synthesize

    saved = mplp_graph.JIT_AFTER
    mplp_graph.JIT_AFTER = 10**9  # the numpy path: this group compiles no mp-LP kernel
    try:
        law = synthesize(_design("inf", 8))  # 122 regions
    finally:
        mplp_graph.JIT_AFTER = saved

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
    # and the points inside a region whose vertices are not enumerated (high dimension:
    # the quadrotor's region of operation), on a region of the small law
    from codev_engine.deploy.prune_kernel import inner_points

    lo, hi = law.boxes
    A0, b0 = np.asarray(law.A[0], float), np.asarray(law.b[0], float)
    nrm = np.linalg.norm(A0, axis=1)
    inner_points(A0 / nrm[:, None], b0 / nrm, np.array([0, A0.shape[0]]), np.array([0]),
                 lo[:1].copy(), hi[:1].copy(), float(np.abs(lo).max() + np.abs(hi).max()), 500)


#: group name -> what compiles it (each runs in its own process in ``compile_all``)
GROUPS: dict[str, Callable[[], None]] = {"mp": _mp, "rest": _rest, "export": _export}
assert tuple(GROUPS) == GROUP_NAMES + LATER  # kernel_cache starts a process per name


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


def _main(argv: list[str]) -> int:
    if argv == ["--prepare"]:  # make's set-up: announced, and nothing when ready
        prepare()
        return 0
    if argv == ["--prepare-all"]:  # the export's kernels too (a Docker build, say)
        prepare()
        prepare(groups=LATER)
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
    done = compile_all(groups=tuple(names))
    for name in names:
        print(f"{name}: " + (f"{done[name]:.1f} s" if name in done else "failed"))
    return 0 if len(done) == len(names) else 1


if __name__ == "__main__":
    raise SystemExit(_main(sys.argv[1:]))
