"""The notebook panel (issue 42): the bundled notebook ``examples/python_control_panel.ipynb``
designs from python-control, drives the panel from Python in a real kernel (nbclient: set a
field, click, wait for the stage) and exports C; its session replays with ``codev replay``.
The panel's cancel and cached stages are driven here without a kernel (the same widgets).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ipywidgets", reason="the notebook extra (a dev dependency)")
nbformat = pytest.importorskip("nbformat", reason="nbformat is a dev dependency")
nbclient = pytest.importorskip("nbclient", reason="nbclient is a dev dependency")

from test_notebook import kernel_name  # noqa: E402,F401  (the fixture: a kernel of this Python)

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "python_control_panel.ipynb"


def test_the_panel_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)


def test_the_panel_notebook_runs_in_a_kernel_and_its_session_replays(kernel_name, tmp_path):  # noqa: F811
    nb = nbformat.read(NOTEBOOK, as_version=4)
    # from an empty folder, as a user who has only the notebook: it needs no spec file
    client = nbclient.NotebookClient(
        nb, kernel_name=kernel_name, timeout=300, resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    assert not [o for o in outs if o.output_type == "error"]
    printed = "".join(o.get("text", "") for o in outs if o.output_type == "stream")
    assert "refused: horizon: must be >= 1, got 0" in printed
    # the edit marks the law and the verdict stale; synthesis makes the law current again
    assert "after the edit: {'model': 'cached', 'synthesis': 'stale'" in printed, printed
    assert "regions: 10 |" in printed
    assert "robustly_safe |" in printed and "'verification': 'cached'" in printed
    assert "cart_law.h cart_law.c" in printed
    views = [o for o in outs if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    assert views, "the panel did not display as a widget"
    pictures = [o for o in outs if "image/png" in o.get("data", {})]
    assert len(pictures) >= 2  # the partition and the verdict, as the engine draws them
    session = tmp_path / "sessions" / "cart"
    runs = {json.loads(line)["run"] for line in (session / "journal.jsonl").open()}
    assert len(runs) == 3
    replay = subprocess.run(
        [sys.executable, "-m", "workbench.cli", "replay", str(session)],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert replay.returncode == 0, replay.stdout + replay.stderr


def _panel(tmp_path: Path, **changes):
    import codev_engine as ce
    from workbench.notebook import Workbench

    problem = ce.load_spec(ROOT / "examples" / "double_integrator.toml").replace(
        hold="zoh", **changes
    )
    return Workbench(problem, session=tmp_path / "di")


def test_a_cached_stage_loads_and_an_edit_marks_what_it_feeds_stale(tmp_path):
    wb = _panel(tmp_path)
    wb.buttons["synthesis"].click()
    report = wb.wait(300)
    assert report is not None and wb.law is not None and not wb.stale("synthesis")
    shown = wb.law_out.outputs
    wb.buttons["synthesis"].click()
    again = wb.wait(300)
    assert [s.status for s in again.stages] == ["cached", "cached"]
    assert wb.law_out.outputs == shown  # the picture on screen is the law's: not redrawn
    wb.fields["horizon"].value = 3
    assert wb.stale("synthesis") and wb.statuses()["synthesis"] == "stale"
    assert "dashed" in str(wb.law_out.layout.border)
    wb.fields["Q"].value = "[[1, 1], [0"
    assert wb.problem is None and "Q: not a TOML value" in wb.message.value
    wb.buttons["synthesis"].click()  # refused, with the reason, nothing run
    assert wb.busy is None and "fix the design first" in wb.message.value


def test_cancel_stops_the_stage_and_frees_the_panel(tmp_path):
    wb = _panel(tmp_path, horizon=6)
    wb.buttons["synthesis"].click()
    wb.buttons["cancel"].click()
    assert wb.wait(300) is None
    assert wb.error == "cancelled" and wb.busy is None and wb.buttons["cancel"].disabled
    assert "cancelled" in wb.message.value
