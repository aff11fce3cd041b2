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
import sys as _sys
import types as _types

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
from .version import __version__ as __version__

# The public names, imported from their modules on first use (PEP 562): `import
# codev_engine` stays cheap (no numpy, scipy or sympy), so a command or the workbench can
# draw its first output before the numerical stack is loaded.
_LAZY: dict[str, str] = {
    "ExplicitLaw": "law",
    "MpcProgram": "mpc",
    "OnlineMpc": "mpc",
    "build_program": "mpc",
    "MpProgram": "mpprogram",
    "CriticalRegion": "mpsolve",
    "MpSolution": "mpsolve",
    "SolveOptions": "mpsolve",
    "mpsolve": "mpsolve",
    "LinearModel": "plant",
    "discretize": "plant",
    "Problem": "spec",
    "load_spec": "spec",
    "loads_spec": "spec",
    "synthesize": "synthesis",
    "Tube": "tube",
    "Counterexample": "verify",
    "VerificationResult": "verify",
    "verify": "verify",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        # submodules (codev_engine.figures, .session, ...) as attributes, like a package
        # that imported them
        if name.isidentifier() and not name.startswith("_"):
            import importlib

            try:
                return importlib.import_module(f"{__name__}.{name}")
            except ModuleNotFoundError as exc:
                if exc.name != f"{__name__}.{name}":
                    raise
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


class _Package(_types.ModuleType):
    """``codev_engine.verify`` and ``codev_engine.mpsolve`` are functions that share their
    name with their modules. The import system sets a package attribute to the submodule
    once that submodule is imported; with lazy imports this can happen after the function
    was fetched, or before. Refusing that assignment keeps ``ce.verify`` / ``ce.mpsolve``
    the functions whatever the import order (as when this file imported them eagerly);
    the modules stay available as ``sys.modules["codev_engine.verify"]`` and through
    ``from codev_engine.verify import ...``."""

    def __setattr__(self, name: str, value: object) -> None:
        if name in ("verify", "mpsolve") and isinstance(value, _types.ModuleType):
            return
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package


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
