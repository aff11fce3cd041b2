"""Benchmark: the linear paper benchmarks under a bounded disturbance (issue 26, Targets 1).

Usage::

    python benchmarks/disturbance.py [--repeats 3] [--sims 200] [--fraction 0.01]

Cases: the six linear paper examples (``examples/{double_integrator, cruise_control,
magnetic_pointer_a, magnetic_pointer_b, magnetic_pointer_c, navigation}.toml``), each with
its own hold, given a disturbance on every state derivative, ``dx/dt = A x + B u + w``
(``E = I``), ``|w_i| <= 0.01 * range_i``, ``range_i`` the width of the state's MPC bounds
(``x_max - x_min``; ``2 * domain_bound`` on an unbounded axis): a box of 1 % of the state
range. Per case: verdict, wall seconds of ``verify`` (best of ``--repeats``), branches, and
the tube's width at the horizon against the hull of ``--sims`` simulations from the corners
and random states of the initial set under extreme signals (each corner of the box held,
bang-bang pieces of the reach step, random pieces; ``verification._signals``): the ratio
per state, its maximum reported ("at T"). The tube's boxes hold time intervals (a reach
step each), so "fair" compares the boxes over the last segment with the simulated states over
the same interval, and adds runs from the corners under the adjoint's bang-bang signals that
push each state up and down at that time (``reach.adversary.adjoint_signals``: the extremes
of the reach set for the region sequence they meet), a much closer lower bound of the reach
set. The verdicts of the nominal examples are not the point:
a disturbance of this size can make a property fail or unknown (the input bounds of a
saturating law, see docs/verification.md).
Targets: under 1 s each, the tube within 1.5x of the simulated hull.

With ``--noise``: measurement noise instead, ``|v_i| <= fraction * range_i`` on every state
the law sees (``[verify] measurement_noise``); the simulations then run under noise
sequences (centre, corners held, bang-bang, random: ``verification.noise_sequences``) and
under the feedback adversary (``verification.noise_adversary``, random directions), the hull
taken over both.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.reach.adversary import adjoint_signals
from codev_engine.reach.linear import affine_plant
from codev_engine.reach.simulate import simulate_many
from codev_engine.reach.verification import (
    _signals,
    noise_adversary,
    noise_sequences,
    verify,
)
from codev_engine.spec.problem import PlantSpec, Uncertain

ROOT = Path(__file__).resolve().parent.parent
STEMS = ["double_integrator", "cruise_control", "magnetic_pointer_a", "magnetic_pointer_b",
         "magnetic_pointer_c", "navigation"]


def disturbed(problem: ce.Problem, fraction: float = 0.01) -> ce.Problem:
    """The problem with ``|w_i| <= fraction * range_i`` on every state derivative."""
    ap = affine_plant(problem)
    mpc = problem.mpc
    span = np.where(np.isfinite(mpc.x_max - mpc.x_min), mpc.x_max - mpc.x_min,
                    2 * mpc.domain_bound)
    n = problem.plant.n
    r = fraction * span
    box = Uncertain(tuple(f"w{i}" for i in range(n)), -r, r, np.zeros(n))
    plant = PlantSpec(problem.plant.states, problem.plant.inputs, A=ap.Ac, B=ap.Bc,
                      disturbances=box, E=np.eye(n))
    return replace(problem, plant=plant)


def noisy(problem: ce.Problem, fraction: float = 0.01) -> ce.Problem:
    """The problem whose law sees ``x + v``, ``|v_i| <= fraction * range_i``."""
    mpc = problem.mpc
    span = np.where(np.isfinite(mpc.x_max - mpc.x_min), mpc.x_max - mpc.x_min,
                    2 * mpc.domain_bound)
    r = fraction * span
    return replace(problem, verify=replace(problem.verify, noise_lower=-r, noise_upper=r))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sims", type=int, default=200)
    ap.add_argument("--fraction", type=float, default=0.01,
                    help="disturbance half-width as a fraction of the state range")
    ap.add_argument("--noise", action="store_true",
                    help="measurement noise of that size instead of a disturbance")
    args = ap.parse_args()
    print(f"{'example':22s} {'hold':10s} {'verdict':14s} {'seconds':>8s} {'cpu s':>7s} "
          f"{'branches':>8s} {'tube/sim at T':>14s} {'fair':>6s}")
    for stem in STEMS:
        base = ce.load_spec(ROOT / "examples" / f"{stem}.toml")
        law = ce.synthesize(base)
        problem = (noisy if args.noise else disturbed)(base, args.fraction)
        best, cpu, result = np.inf, np.inf, None
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            result = verify(problem, law)
            best = min(best, time.perf_counter() - t0)
            cpu = min(cpu, time.process_time() - c0)
        vs = problem.verify
        n = problem.plant.n
        lo, hi = vs.initial_lower, vs.initial_upper
        rng = np.random.default_rng(0)
        corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)], indexing="ij"))
        X0 = np.vstack([corners.reshape(n, -1).T, rng.uniform(lo, hi, (args.sims, n))])
        if args.noise:
            dirs = rng.normal(size=(X0.shape[0], n))
            runs = [simulate_many(problem, law, X0, hold=result.hold, noise=noise)
                    for noise in (noise_sequences(problem, X0.shape[0], seed=1),
                                  noise_adversary(problem, law, dirs))]
            t = runs[0].t
            X = np.concatenate([r.X for r in runs], axis=0)
        else:
            piece, W, Q = _signals(problem, X0.shape[0], seed=1)
            t, X, _, _ = simulate_many(problem, law, X0, hold=result.hold,
                                       disturbance=(piece, W, Q))
        T = float(result.tube.t_end.max()) if result.tube.num_boxes else 0.0
        k = int(np.argmin(abs(t - 0.999 * T)))
        tlo, thi = result.tube.hull_at(t[k])
        sim = np.nanmax(X[:, k], 0) - np.nanmin(X[:, k], 0)
        ratio = float(np.max((thi - tlo) / np.maximum(sim, 1e-12)))
        fair = np.nan
        if not args.noise and result.tube.num_boxes and result.verdict != "unsafe":
            # (an unsafe run's tube stops at the counterexample: no ratio)
            fair = _fair(problem, law, result, corners.reshape(n, -1).T, [(t, X)])
        verdict = result.verdict + ("/" + result.reason if result.reason else "")
        print(f"{stem:22s} {result.hold:10s} {verdict:14s} "
              f"{best:8.3f} {cpu:7.3f} {result.stats.get('branches', 0):8d} {ratio:14.2f} "
              f"{fair:6.2f}  (t = {t[k]:.2f})", flush=True)


def _fair(problem: ce.Problem, law, result, corners: np.ndarray, runs: list) -> float:
    """The tube's boxes over its last segment against the simulated states over the same
    interval, the adjoint's extreme signals (each state up and down) added: the largest
    ratio of widths."""
    tube = result.tube
    n = problem.plant.n
    T = float(tube.t_end.max())
    tq = T - problem.verify.step / 2
    sel = (tube.t_start <= tq) & (tube.t_end >= tq)
    a, b = tube.t_start[sel].min(), tube.t_end[sel].max()
    width = tube.upper[sel].max(0) - tube.lower[sel].min(0)
    dirs = np.vstack([np.eye(n), -np.eye(n)])
    X0 = np.repeat(corners, len(dirs), axis=0)
    L = np.tile(dirs, (corners.shape[0], 1))
    dt = problem.verify.step / 2
    piece, W, Q, X0r = adjoint_signals(problem, law, X0, L, hold=result.hold, t_target=tq,
                                       iterations=3, dt=dt)
    r = simulate_many(problem, law, X0r, hold=result.hold, disturbance=(piece, W, Q), dt=dt,
                      dt_out=dt)
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    for t, X in [*runs, (r.t, r.X)]:
        k = (t >= a - 1e-9) & (t <= b + 1e-9)
        Y = X[:, k].reshape(-1, n)
        Y = Y[np.all(np.isfinite(Y), axis=1)]
        if Y.shape[0]:
            lo, hi = np.minimum(lo, Y.min(0)), np.maximum(hi, Y.max(0))
    return float(np.max(width / np.maximum(hi - lo, 1e-12)))


if __name__ == "__main__":
    main()
