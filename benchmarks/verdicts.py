"""Benchmark: verdicts on the textbook plants of issue 38, and the budget's heartbeat.

Usage::

    python benchmarks/verdicts.py [--budget 10]

Cases (the test suite's fixtures, written from published parameters): ``pitch`` (a
saturating aircraft pitch loop, ``input_bounds = true``), ``cart-pendulum-rate`` (a
rate-limited 4-state law over theta = (x, u_prev)), ``cart-pendulum-tracking`` (the same
tracking a cart position, theta = (x, u_prev, r)), ``ball-beam-stiff`` (a nonlinear plant
whose a-priori enclosure fails: ``unknown`` / ``enclosure``), ``headbox`` (a paper machine,
inf-norm law, a disturbance) and ``pendulum-sat`` (the nonlinear engine's input check on a
saturating law). Per case: the verdict, the synthesis and the verification's wall seconds,
and the longest pause between two progress reports (the engine's reports and its heartbeat,
``codev_engine.limits.beat``). Then the headbox with horizon 4 (310 regions: each sample
period's region cuts of its disturbed sets take tens of seconds, the issue's stall) under
``--budget`` seconds: the verdict
(``unknown`` / ``budget``), its wall time against the budget and the longest pause.
Target: each case ends in a verdict within 60 s; no pause past 5 s.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from codev_engine.pipeline import loads_spec  # noqa: E402
from codev_engine.reach.verification import verify  # noqa: E402
from codev_engine.synthesis import synthesize  # noqa: E402
from tests.engine.test_budget import HEADBOX, PENDULUM_SAT  # noqa: E402
from tests.engine.test_verdicts import (  # noqa: E402
    CART_PENDULUM,
    CART_TRACKING,
    PITCH,
    STIFF_BEAM,
)

CASES = {"pitch": PITCH, "cart-pendulum-rate": CART_PENDULUM,
         "cart-pendulum-tracking": CART_TRACKING, "ball-beam-stiff": STIFF_BEAM,
         "headbox": HEADBOX, "pendulum-sat": PENDULUM_SAT}


def _timed(problem, law, budget: float | None = None):
    """(result, seconds, longest pause between progress reports)."""
    stamps = [time.monotonic()]
    result = verify(problem, law, budget=budget, progress=lambda _st: stamps.append(
        time.monotonic()))
    stamps.append(time.monotonic())
    gaps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    return result, stamps[-1] - stamps[0], max(gaps)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=10.0)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'case':<24} {'verdict':<36} {'synth s':>8} {'verify s':>9} {'max pause s':>12}")
    for name, text in CASES.items():
        problem = loads_spec(text)
        t0 = time.perf_counter()
        law = synthesize(problem)
        synth = time.perf_counter() - t0
        result, seconds, pause = _timed(problem, law)
        verdict = f"{result.verdict}/{result.reason or '-'}"
        print(f"{name:<24} {verdict:<36} {synth:>8.2f} {seconds:>9.2f} {pause:>12.2f}")
    # the stall of the issue: horizon 4 (310 regions), its disturbed sets' region cuts
    # take tens of seconds per sample period
    problem = loads_spec(HEADBOX.replace("\nhorizon = 2\n", "\nhorizon = 4\n"))
    law = synthesize(problem)
    result, seconds, pause = _timed(problem, law, args.budget)
    print(f"headbox N = 4, budget {args.budget:g} s: {result.verdict}/{result.reason} in "
          f"{seconds:.2f} s, max pause {pause:.2f} s\n  {result.detail}")


if __name__ == "__main__":
    main()
