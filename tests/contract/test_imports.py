"""The import contracts of ``[tool.importlinter]`` in pyproject.toml, run by import-linter.

- every contract is kept by the code as it is (``lint-imports --contract ID`` exits 0);
- each contract breaks when a forbidden import is added: the packages are copied to a
  temporary folder, one import statement is appended to one module of the copy, and the
  linter, run on the copy, fails that contract and names the new import;
- importing the engine loads none of the front end's or the pictures' libraries (textual,
  rich, rerun, matplotlib), checked in a fresh interpreter's ``sys.modules``;
- the engine imports a module by name (``importlib.import_module``, which no contract
  sees) only where that is known: its lazy public names and the notebook backend.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: the linter's command line, from the interpreter running the tests (no PATH lookup)
LINT = [
    sys.executable,
    "-c",
    "import sys; from importlinter.cli import lint_imports_command; lint_imports_command()",
]


def lint(cwd: Path, *contracts: str) -> subprocess.CompletedProcess:
    """``lint-imports`` in ``cwd`` (its pyproject.toml, the packages found from ``cwd``)."""
    args = [arg for c in contracts for arg in ("--contract", c)]
    # wide lines: the report names an import on one line, not wrapped at 80 columns
    env = {**os.environ, "COLUMNS": "500", "PYTHONPATH": str(cwd)}
    return subprocess.run(
        [*LINT, "--no-cache", "--no-logo", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def contract_ids() -> list[str]:
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    return [c["id"] for c in config["tool"]["importlinter"]["contracts"]]


@pytest.mark.parametrize("contract", contract_ids())
def test_contract_is_kept(contract):
    out = lint(ROOT, contract)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Contracts: 1 kept, 0 broken." in out.stdout, out.stdout


#: contract id -> (module file of the copy, the line appended to it, the import reported)
BREAKS = {
    "engine-no-front-end": (
        "codev_engine/spec/expr.py",
        "import textual",
        "codev_engine.spec.expr -> textual",
    ),
    "view-only-draws": (
        "codev_engine/reach/tube.py",
        "import rerun",
        "codev_engine.reach.tube -> rerun",
    ),
    "reach-below-session-view": (
        "codev_engine/reach/tube.py",
        "from codev_engine.session import Session",
        "codev_engine.reach.tube -> codev_engine.session",
    ),
    "mp-geometry-below-problems": (
        "codev_engine/geometry/polytope.py",
        "from codev_engine.spec.problem import Problem",
        "codev_engine.geometry.polytope -> codev_engine.spec.problem",
    ),
    "engine-layers": (
        "codev_engine/mpc.py",
        "from codev_engine.synthesis import synthesize",
        "codev_engine.mpc -> codev_engine.synthesis",
    ),
}


def test_every_contract_has_a_break():
    assert sorted(BREAKS) == sorted(contract_ids())


@pytest.mark.parametrize("contract", sorted(BREAKS))
def test_contract_fails_when_broken(contract, tmp_path):
    ignore = shutil.ignore_patterns("__pycache__")
    for package in ("codev_engine", "workbench"):
        shutil.copytree(ROOT / package, tmp_path / package, ignore=ignore)
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    module, line, reported = BREAKS[contract]
    target = tmp_path / module
    target.write_text(target.read_text(encoding="utf-8") + f"\n{line}\n", encoding="utf-8")

    out = lint(tmp_path, contract)
    assert out.returncode == 1, out.stdout + out.stderr
    assert "0 kept, 1 broken." in out.stdout, out.stdout
    assert reported in out.stdout, out.stdout  # the copy was linted, and the new import named


#: what the engine must not load when imported: the front end's and the pictures' libraries
FRONT_END = ("textual", "rich", "rerun", "matplotlib")


def loaded_after(*modules: str) -> set[str]:
    """Top-level names in ``sys.modules`` of a fresh interpreter after importing ``modules``."""
    code = (
        "import json, sys\n"
        + "".join(f"import {m}\n" for m in modules)
        + "print(json.dumps(sorted({n.split('.')[0] for n in sys.modules})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert out.returncode == 0, out.stderr
    return set(json.loads(out.stdout))


def test_importing_the_engine_loads_no_front_end():
    loaded = loaded_after("codev_engine")
    assert "codev_engine" in loaded
    assert loaded.isdisjoint(FRONT_END), loaded & set(FRONT_END)
    # and no numerical stack either (codev_engine/__init__.py: public names are lazy)
    assert loaded.isdisjoint({"numpy", "scipy", "sympy"}), loaded
    # nor the executor's cluster (codev_engine/executor.py: dask on first use)
    assert loaded.isdisjoint({"dask", "distributed"}), loaded


def test_the_engine_modules_and_the_cli_load_no_front_end_on_import():
    # the pictures and the progress bars are imported when drawn, the workbench for `tui`
    loaded = loaded_after(
        "codev_engine.session",
        "codev_engine.synthesis",
        "codev_engine.reach.verification",
        "codev_engine.view.figures",
        "codev_engine.view.records",
        "codev_engine.sweeps",
        "workbench.cli",
    )
    assert "codev_engine" in loaded and "workbench" in loaded
    assert loaded.isdisjoint(FRONT_END), loaded & set(FRONT_END)
    assert loaded.isdisjoint({"dask", "distributed"}), loaded  # a cluster is started on use


def test_the_workbench_starts_without_the_solvers():
    # the first screen draws before the numerical stack is loaded (benchmarks/tui.py): the
    # solvers and the symbolic model load in the first check's worker. A top-level import of
    # geometry in view.figures once cost the first screen ~0.3 s (scipy.optimize).
    code = (
        "import sys\nimport workbench.tui.app\n"
        "heavy = ('scipy.optimize', 'sympy', 'control', 'cvxpy', 'numba', 'matplotlib', 'rerun',"
        " 'distributed')\n"
        "print(','.join(m for m in heavy if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", out.stdout


#: the engine's imports by name, which the linter cannot see: the lazy public names of
#: ``import codev_engine`` (its own submodules), the notebook backend (codev_engine.view)
#: and ``Problem.replace``, whose checks are the design API's, layers above the data class
IMPORTS_BY_NAME = {
    "codev_engine/__init__.py", "codev_engine/display.py", "codev_engine/spec/problem.py",
}  # fmt: skip


def test_the_engine_imports_by_name_only_where_known():
    # an import_module elsewhere would pass every contract unseen
    def calls_by_name(path: Path) -> bool:
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call):
                f = node.func
                name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", None)
                if name in ("import_module", "__import__"):
                    return True
        return False

    by_name = {
        str(p.relative_to(ROOT))
        for p in sorted((ROOT / "codev_engine").rglob("*.py"))
        if calls_by_name(p)
    }
    assert by_name == IMPORTS_BY_NAME
