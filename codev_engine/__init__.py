"""codev engine: explicit MPC synthesis and closed-loop verification.

Public API::

    import codev_engine as ce
    problem = ce.load_spec("examples/double_integrator.toml")
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

from .errors import CodevError, SolverError, SpecError
from .law import ExplicitLaw
from .mpc import MpcProgram, OnlineMpc, build_program
from .mpprogram import MpProgram
from .mpsolve import CriticalRegion, MpSolution, SolveOptions, mpsolve
from .plant import LinearModel, discretize
from .spec import Problem, load_spec, loads_spec
from .synthesis import synthesize
from .tube import Tube
from .verify import Counterexample, VerificationResult, verify
from .version import __version__ as __version__

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
    "SolveOptions",
    "SolverError",
    "SpecError",
    "build_program",
    "discretize",
    "load_spec",
    "loads_spec",
    "mpsolve",
    "synthesize",
    "Tube",
    "Counterexample",
    "VerificationResult",
    "verify",
]
