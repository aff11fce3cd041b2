"""The example notebook runs without errors (nbclient), from the repository root and from
``examples/``, and shows what it promises: the law's partition, the verdicts.

The kernel must run this interpreter (the one with ``codev_engine`` and the test
dependencies), whatever kernelspecs the user has installed: a kernelspec pointing at
``sys.executable`` is installed into a temporary directory placed first on
``JUPYTER_PATH``, under a name no other installation uses.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="nbformat is a dev dependency")
nbclient = pytest.importorskip("nbclient", reason="nbclient is a dev dependency")
kernelspec = pytest.importorskip("ipykernel.kernelspec", reason="ipykernel is a dev dependency")

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "double_integrator.ipynb"
KERNEL = "codev-test-python"


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A kernelspec that runs ``sys.executable`` (with the repository importable)."""
    prefix = tmp_path_factory.mktemp("jupyter")
    kernelspec.install(kernel_name=KERNEL, prefix=str(prefix))
    mp = pytest.MonkeyPatch()
    paths = [str(prefix / "share" / "jupyter"), os.environ.get("JUPYTER_PATH", "")]
    mp.setenv("JUPYTER_PATH", os.pathsep.join(p for p in paths if p))
    mp.setenv(
        "PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    )
    from jupyter_client.kernelspec import KernelSpecManager

    spec = KernelSpecManager().get_kernel_spec(KERNEL)
    assert Path(spec.argv[0]).resolve() == Path(sys.executable).resolve(), spec.argv
    yield KERNEL
    mp.undo()


def _execute(cwd: Path, kernel: str) -> nbformat.NotebookNode:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        kernel_name=kernel,
        timeout=120,
        resources={"metadata": {"path": str(cwd)}},
    )
    client.execute()  # raises CellExecutionError on the first failing cell
    return nb


def _outputs(nb: nbformat.NotebookNode) -> list[tuple[str, list[dict]]]:
    return [(c.source, c.outputs) for c in nb.cells if c.cell_type == "code"]


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)
    assert NOTEBOOK.stat().st_size < 20_000


# from the examples folder too, as a user of the wheel runs it (slow: one run of the notebook,
# ~6 s quiet, is enough for the default suite)
@pytest.mark.parametrize("cwd", [pytest.param("examples", marks=pytest.mark.slow), "root"])
def test_notebook_runs_end_to_end(kernel_name, cwd):
    nb = _execute(NOTEBOOK.parent if cwd == "examples" else ROOT, kernel_name)
    cells = _outputs(nb)
    errors = [o for _, outs in cells for o in outs if o.output_type == "error"]
    assert not errors, errors
    stderr = [o.text for _, outs in cells for o in outs if o.get("name") == "stderr"]
    assert not any("Traceback" in t for t in stderr), stderr

    def result_of(source_end: str) -> dict:
        (outs,) = [outs for src, outs in cells if src.rstrip().endswith(source_end)]
        (res,) = [o for o in outs if o.output_type == "execute_result"]
        return res.data

    law = result_of("\nlaw")
    assert {"image/png", "text/html"} <= set(law), law.keys()
    assert law["text/plain"].startswith("explicit law: 10 regions")
    assert '<img src="data:image/png;base64,' in law["text/html"]

    safe = result_of("\nresult")
    assert "image/png" in safe and "robustly safe" in safe["text/html"]
    unsafe = result_of("\nunsafe")
    assert "unsafe: enters unsafe set 0" in unsafe["text/html"]
    coarse = result_of("\ncoarse")
    assert "unknown (max_depth)" in coarse["text/html"]
    printed = "".join(o.text for _, outs in cells for o in outs if o.output_type == "stream")
    assert "run 2: model cached, synthesis cached, verification cached" in printed
