"""The notebook panel's stage latency (issue 42): a cached stage, and an edit then synthesis.

Drives ``workbench.notebook.Workbench`` from Python as a notebook would (set a field, click,
wait), without a kernel: the time from the click to the end of the stage, drawing included.

    .venv/bin/python benchmarks/panel.py [--repeats 5]

Needs the notebook extra (``pip install -e '.[notebook]'``).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    import codev_engine as ce
    from workbench.notebook import Workbench

    problem = ce.load_spec(ROOT / "examples" / "double_integrator.toml").replace(hold="zoh")
    with tempfile.TemporaryDirectory() as folder:
        wb = Workbench(problem, session=Path(folder) / "di")

        def click(stage: str) -> float:
            t0 = time.perf_counter()
            wb.buttons[stage].click()
            wb.wait()
            assert wb.error is None, wb.error
            return time.perf_counter() - t0

        first = click("verification")
        cached = [click("verification") for _ in range(args.repeats)]
        edits = []
        for i in range(args.repeats):
            wb.fields["horizon"].value = 3 + i % 2  # 3, 4, 3, ...: computed, then cached
            edits.append(click("synthesis"))
    print(f"first run (model, synthesis, verification computed, drawn): {first:.2f} s")
    print(f"cached verification run, median of {args.repeats}: {statistics.median(cached):.3f} s"
          f" (max {max(cached):.3f} s)")  # fmt: skip
    print("horizon edited, then synthesise (computed twice, then cached; law redrawn): "
          + ", ".join(f"{t:.2f}" for t in edits) + " s")


if __name__ == "__main__":
    main()
