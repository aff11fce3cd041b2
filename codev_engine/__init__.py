"""codev engine: explicit MPC synthesis and closed-loop verification.

Public API::

    import codev_engine as ce
    problem = ce.load_spec("examples/double_integrator.toml")
    # or from python-control: ce.design(ct.ss(A, B, C, D), sample_time=1.0, norm="inf", ...)
    law = ce.synthesize(problem)
    law.evaluate([[1.0, 2.0]])

The engine never imports UI code.
"""

from __future__ import annotations

import os as _os

# The engine's linear algebra is on tiny matrices, thousands of times: a multi-threaded
# BLAS only adds thread contention (measured: a batch of 101 4x4 expm took 1.5 s with
# OpenBLAS threads on a loaded 2-core machine, 0.7 ms single-threaded). Environment
# variables work when numpy is not imported yet; threadpoolctl covers the other case.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
try:
    from threadpoolctl import threadpool_limits as _limits

    _limits(limits=1, user_api="blas")
except ImportError:  # pragma: no cover - threadpoolctl is a dependency
    pass

from codev_engine.errors import CodevError, SolverError, SpecError
from codev_engine.version import __version__ as __version__

# The public names, imported from their modules on first use (PEP 562): `import
# codev_engine` stays cheap (no numpy, scipy or sympy), so a command or the workbench can
# draw its first output before the numerical stack is loaded.
_LAZY: dict[str, str] = {
    "ExplicitLaw": "law",
    "MpcProgram": "mpc",
    "OnlineMpc": "mpc",
    "build_program": "mpc",
    "MpProgram": "mp.program",
    "CriticalRegion": "mp.solution",
    "MpSolution": "mp.solution",
    "ShardedSolution": "mp.solution",
    "SolveOptions": "mp.solve",
    "mpsolve": "mp.solve",
    "LinearModel": "plant",
    "discretize": "plant",
    "Problem": "spec.problem",
    "design": "design_api",
    "load_spec": "pipeline",
    "loads_spec": "pipeline",
    "synthesize": "synthesis",
    "export_c": "deploy.export",
    "export_python": "deploy.export",
    "Tube": "reach.tube",
    "Counterexample": "reach.verification",
    "VerificationResult": "reach.verification",
    "verify": "reach.verification",
    "RunOptions": "session",
    "Session": "session",
    "Executor": "executor",
    "sweep": "sweeps",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = [
    "CodevError",
    "CriticalRegion",
    "ExplicitLaw",
    "LinearModel",
    "MpProgram",
    "MpSolution",
    "MpcProgram",
    "OnlineMpc",
    "Problem",
    "ShardedSolution",
    "SolveOptions",
    "design",
    "SolverError",
    "SpecError",
    "build_program",
    "discretize",
    "load_spec",
    "loads_spec",
    "mpsolve",
    "synthesize",
    "export_c",
    "export_python",
    "Tube",
    "Counterexample",
    "VerificationResult",
    "verify",
    "RunOptions",
    "Session",
    "Executor",
    "sweep",
]
