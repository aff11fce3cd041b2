"""Recording benchmark: a 10^3-region, 10^4-box recording, its time and its size.

``magnetic_pointer_a``'s law (1008 regions in 3-D) with a synthetic tube of 10,000 boxes
(2,000 distinct start times), with 0 and 16 traces; also the HTML report of the same design.
The target (issue 24): written in under 1 s and under 20 MB. Prints a table and, with
``--json OUT``, writes the numbers. A benchmark, not a test: exits 0 whatever it measures.

Usage::

    .venv/bin/python benchmarks/recording.py [--repeats 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import codev_engine as ce  # noqa: E402
from codev_engine.reach.tube import Tube  # noqa: E402
from codev_engine.reach.verification import VerificationResult  # noqa: E402
from codev_engine.view.records import RecordingOptions, write_recording  # noqa: E402
from codev_engine.view.report import write_report  # noqa: E402


def synthetic_tube(n: int, boxes: int = 10_000, starts: int = 2_000) -> Tube:
    """``boxes`` boxes of side 0.1 at seeded random places, ``boxes // starts`` per start."""
    rng = np.random.default_rng(3)
    dt = 1.1 / starts
    ts = np.repeat(np.arange(starts) * dt, boxes // starts)
    lo = rng.uniform(-3.0, 3.0, (ts.size, n))
    return Tube(ts, ts + dt, lo, lo + 0.1, np.zeros(ts.size, dtype=int))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args()
    problem = ce.load_spec(ROOT / "examples" / "magnetic_pointer_a.toml")
    law = ce.synthesize(problem)
    tube = synthetic_tube(problem.plant.n)
    result = VerificationResult("robustly_safe", None, tube, "continuous", None, {})
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        warm = RecordingOptions(traces=0)
        write_recording(Path(tmp) / "warm.rrd", problem, law, result, options=warm)
        for traces in (0, 16):
            times, size = [], 0
            for k in range(args.repeats):
                path = Path(tmp) / f"r{traces}-{k}.rrd"
                opts = RecordingOptions(traces=traces)
                s = write_recording(path, problem, law, result, options=opts)
                times.append(s.seconds)
                size = path.stat().st_size
            rows.append(
                {"what": f"recording, {traces} traces", "seconds": min(times), "mb": size / 1e6}
            )
        t0 = time.perf_counter()
        path = write_report(Path(tmp) / "r.html", problem, law, result, traces=16)
        rows.append(
            {
                "what": "HTML report, 16 traces",
                "seconds": time.perf_counter() - t0,
                "mb": path.stat().st_size / 1e6,
            }
        )
    print(f"{law.num_regions} regions, {tube.num_boxes} boxes (target: < 1 s, < 20 MB)")
    for r in rows:
        print(f"  {r['what']:<26} {r['seconds']:6.3f} s  {r['mb']:6.2f} MB")
    if args.json:
        Path(args.json).write_text(json.dumps({"regions": law.num_regions, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
