"""The names ``import codev_engine as ce`` offers: every one that was public before the
layout change keeps working, plus ``ce.Session`` and ``ce.RunOptions``; each is the object
its module defines (no module shadows a function of the same name)."""

from __future__ import annotations

import inspect
import subprocess
import sys

import pytest

import codev_engine as ce

#: public before the layout change (issue 22); a name leaves only by a deliberate change here
PINNED = {
    "CodevError": "codev_engine.errors",
    "SpecError": "codev_engine.errors",
    "SolverError": "codev_engine.errors",
    "CriticalRegion": "codev_engine.mp.solution",
    "ExplicitLaw": "codev_engine.law",
    "LinearModel": "codev_engine.plant",
    "MpProgram": "codev_engine.mp.program",
    "MpSolution": "codev_engine.mp.solution",
    "ShardedSolution": "codev_engine.mp.solution",
    "MpcProgram": "codev_engine.mpc",
    "OnlineMpc": "codev_engine.mpc",
    "Problem": "codev_engine.spec.problem",
    "SolveOptions": "codev_engine.mp.solve",
    "build_program": "codev_engine.mpc",
    "discretize": "codev_engine.plant",
    "load_spec": "codev_engine.pipeline",
    "loads_spec": "codev_engine.pipeline",
    "mpsolve": "codev_engine.mp.solve",
    "synthesize": "codev_engine.synthesis",
    "Tube": "codev_engine.reach.tube",
    "Counterexample": "codev_engine.reach.verification",
    "VerificationResult": "codev_engine.reach.verification",
    "verify": "codev_engine.reach.verification",
    # new with the layout change
    "Session": "codev_engine.session.session",
    "RunOptions": "codev_engine.session.options",
    # the law as code (issue 27)
    "export_c": "codev_engine.deploy.export",
    "export_python": "codev_engine.deploy.export",
    # scale out (issue 28)
    "Executor": "codev_engine.executor",
    "sweep": "codev_engine.sweeps",
    # the Python design API (issue 42)
    "design": "codev_engine.design_api",
}


def test_all_lists_exactly_the_pinned_names():
    assert set(ce.__all__) == set(PINNED)


@pytest.mark.parametrize("name", sorted(PINNED))
def test_a_public_name_is_its_module_object(name):
    obj = getattr(ce, name)
    assert not inspect.ismodule(obj), f"ce.{name} is a module"
    assert obj.__module__ == PINNED[name]


def test_functions_stay_functions_whatever_the_import_order():
    # the old layout had modules named verify and mpsolve beside the functions: importing
    # the module after fetching the function replaced ce.verify by the module
    code = (
        "import codev_engine as ce\n"
        "import codev_engine.reach.verification, codev_engine.mp.solve, codev_engine.session\n"
        "assert callable(ce.verify) and callable(ce.mpsolve), (ce.verify, ce.mpsolve)\n"
        "assert ce.verify.__module__ == 'codev_engine.reach.verification'\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        ce.nonexistent  # noqa: B018
