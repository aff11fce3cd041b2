"""Benchmark: nonlinear tubes under disturbances and uncertain parameters (issue 38).

Usage::

    python benchmarks/uncertain_tube.py [CASE ...] [--samples 400] [--no-carry]

Cases: ``pendulum_near_saturation`` (examples/pendulum.toml with ``-c*w + T + d``, ``c`` in
[0.4, 0.6], ``|d| <= 0.2``, 3 s: the design of issue 38), ``quadruple_tank``
(tests/engine/quadruple_tank.toml, Johansson 2000, ``g1`` in [0.67, 0.73], ``|d| <= 0.2``) and
``cruise_loaded`` (examples/, an affine plant: the linear engine). Per case: the verdict, CPU
seconds of ``ce.verify`` (``time.process_time``), branches and boxes, then per state the width
of the tube's boxes active at 1/4, 1/2, 3/4 and all of the tube's span over the width of the
hull of ``--samples`` dense simulations over the same time span (the initial set's corners
and random states, each under one of the verifier's own concrete signals: the boxes' centre,
their corners held constant, bang-bang and random pieces, and the parameter box's centre,
corners and random values), and how many simulated states lie outside the tube (must be 0).
``--no-carry`` measures the engine without the carried zonotope (``NonlinearReach.carry =
False``: the disturbances' first-order part in the remainder ball, as before issue 38's
change). Target: a ratio of at most 2.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.pipeline import loads_spec
from codev_engine.reach.nonlinear import NonlinearReach
from codev_engine.reach.simulate import simulate_many
from codev_engine.reach.verification import _signals

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # (the ratio is nonlinear_tube.py's)
from benchmarks.nonlinear_tube import hull_ratios  # noqa: E402

CASES = ["pendulum_near_saturation", "quadruple_tank", "cruise_loaded"]


def problem_of(case: str) -> ce.Problem:
    """The case's problem (see the module docstring)."""
    if case == "pendulum_near_saturation":
        text = (ROOT / "examples" / "pendulum.toml").read_text()
        text = text.replace('"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - c*w + T + d"')
        text = text.replace("[model]", "disturbances = { d = [-0.2, 0.2] }\n"
                            "parameters = { c = [0.4, 0.6] }\n\n[model]", 1)
        return loads_spec(text)
    if case == "quadruple_tank":
        return loads_spec((ROOT / "tests" / "engine" / "quadruple_tank.toml").read_text())
    return loads_spec((ROOT / "examples" / f"{case}.toml").read_text())


def ratios(problem: ce.Problem, law, tube, samples: int):
    """Tube width over simulated hull width per state at 1/4 ... 1 of the tube's span, and
    the number of simulated states outside the tube.

    Returns
    -------
    (list of (float, (n,) ndarray), int)
    """
    vs = problem.verify
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    rnd = np.random.default_rng(0).uniform(lo, hi, (max(samples - len(corners), 0), lo.size))
    X0 = np.vstack([corners, rnd])
    piece, W, Q = _signals(problem, X0.shape[0], seed=1)
    t, X, _, _ = simulate_many(problem, law, X0, hold=vs.hold, disturbance=(piece, W, Q))
    T = float(tube.t_end.max())
    out = hull_ratios(tube, t, X, (0.25, 0.5, 0.75, 1.0))
    outside = 0
    for k, tk in enumerate(t):
        if tk > T + 1e-9:
            break
        act = (tube.t_start <= tk + 1e-12) & (tube.t_end >= tk - 1e-12)
        x = X[:, k][np.all(np.isfinite(X[:, k]), axis=1)]
        inside = np.zeros(x.shape[0], dtype=bool)
        for bl, bh in zip(tube.lower[act], tube.upper[act], strict=True):
            inside |= np.all((x >= bl - 1e-9) & (x <= bh + 1e-9), axis=1)
        outside += int((~inside).sum())
    return out, outside


def main() -> int:
    """Run the benchmark (see the module docstring).

    Returns
    -------
    int
        The exit status (0).
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cases", nargs="*", default=CASES)
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--no-carry", action="store_true")
    args = ap.parse_args()
    if args.no_carry:  # (a dataclass field: set on each engine after its __init__)
        post = NonlinearReach.__post_init__

        def no_carry(self: NonlinearReach) -> None:
            post(self)
            self.carry = False

        NonlinearReach.__post_init__ = no_carry
    for case in args.cases:
        problem = problem_of(case)
        law = ce.synthesize(problem)
        t0 = time.process_time()
        res = ce.verify(problem, law, hold=problem.verify.hold)
        cpu = time.process_time() - t0
        st = res.stats
        print(f"{case}: {res.verdict} ({res.reason or '-'}), {cpu:.2f} s CPU, "
              f"{st.get('branches', 0)} branches, {res.tube.num_boxes} boxes", flush=True)
        if res.tube.num_boxes == 0:
            continue
        rs, outside = ratios(problem, law, res.tube, args.samples)
        for tk, r in rs:
            print(f"  t = {tk:7.3f}: tube / hull = " + " ".join(f"{v:.2f}" for v in r))
        print(f"  simulated states outside the tube: {outside}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
