"""Benchmark: the nonlinear tube against the hull of dense simulations (issue 26, Deliver 5).

Usage::

    python benchmarks/nonlinear_tube.py [STEM ...] [--repeats 3] [--samples 2000]

Per bundled nonlinear example (default: pendulum, vanderpol, cstr, tora; the spec's own hold):
the verdict, CPU and wall seconds of ``ce.verify`` (best of ``--repeats``,
``time.process_time`` / ``time.perf_counter``), the tube's boxes, and at a quarter, half and
all of the horizon, per state, the width of the tube's boxes active at that time over the width
of the hull of dense simulations (the initial set's corners and ``--samples`` random states,
RK4 at a tenth of ``verify.step``) over the same time span. Target: at most 2 at the horizon on
every state.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import itertools
import os
import time
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.reach.simulate import simulate_many

ROOT = Path(__file__).resolve().parent.parent
STEMS = ["pendulum", "vanderpol", "cstr", "tora"]


def ratios(problem: ce.Problem, law, tube, samples: int) -> list[tuple[float, np.ndarray]]:
    """Tube width over simulated hull width, per state, at 1/4, 1/2 and all of the horizon.

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
        The verified law.
    tube : Tube
        The verification's reachtube.
    samples : int
        Random initial states (besides the corners).

    Returns
    -------
    list of (float, ndarray)
        ``(t, ratio (n,))`` per time.
    """
    vs = problem.verify
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    X0 = np.vstack([corners, np.random.default_rng(0).uniform(lo, hi, (samples, lo.size))])
    t, X, _, _ = simulate_many(problem, law, X0, hold=vs.hold, dt=vs.step / 10, dt_out=vs.step)
    return hull_ratios(tube, t, X, (0.25, 0.5, 1.0))


def hull_ratios(tube, t: np.ndarray, X: np.ndarray,
                fractions: tuple[float, ...]) -> list[tuple[float, np.ndarray]]:
    """Tube width over simulated hull width, per state, at fractions of the tube's span.

    Parameters
    ----------
    tube : Tube
    t : (K,) ndarray
        The simulation's output times.
    X : (P, K, n) ndarray
        The simulated states (NaN where a run ended).
    fractions : tuple of float
        Of the tube's end time; each is taken at the nearest output time.

    Returns
    -------
    list of (float, ndarray)
        ``(t, ratio (n,))`` per time a box of the tube is active at: the hull of the boxes
        active then over the hull of the simulated states over those boxes' span.
    """
    T = float(tube.t_end.max())
    out = []
    for frac in fractions:
        tk = float(t[int(np.argmin(np.abs(t - T * frac)))])
        act = (tube.t_start <= tk + 1e-12) & (tube.t_end >= tk - 1e-12)
        if not act.any():
            continue
        a, b = tube.t_start[act].min(), tube.t_end[act].max()
        xs = X[:, (t >= a - 1e-12) & (t <= b + 1e-12)].reshape(-1, X.shape[-1])
        xs = xs[np.all(np.isfinite(xs), axis=1)]
        width = tube.upper[act].max(axis=0) - tube.lower[act].min(axis=0)
        out.append((tk, width / np.maximum(xs.max(axis=0) - xs.min(axis=0), 1e-300)))
    return out


def main() -> int:
    """Run the benchmark (see the module docstring).

    Returns
    -------
    int
        The exit status (0).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("stems", nargs="*", default=STEMS)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--samples", type=int, default=2000)
    args = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}")
    print("| example | verdict | CPU s | wall s | boxes | tube / simulated hull per state |")
    print("|---|---|---|---|---|---|")
    for stem in args.stems:
        problem = ce.load_spec(ROOT / "examples" / f"{stem}.toml")
        law = ce.synthesize(problem)
        cpu = wall = np.inf
        for _ in range(max(1, args.repeats)):
            c0, w0 = time.process_time(), time.perf_counter()
            res = ce.verify(problem, law)
            cpu = min(cpu, time.process_time() - c0)
            wall = min(wall, time.perf_counter() - w0)
        r = "; ".join(
            f"t={tk:.3g}: {' '.join(f'{v:.2f}' for v in ratio)}"
            for tk, ratio in ratios(problem, law, res.tube, args.samples)
        )
        print(f"| {stem} | {res.verdict} | {cpu:.2f} | {wall:.2f} | {res.tube.num_boxes} | {r} |",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
