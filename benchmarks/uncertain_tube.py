"""Benchmark: nonlinear tubes under disturbances and uncertain parameters (issue 38).

Usage::

    python benchmarks/uncertain_tube.py [CASE ...] [--samples 400] [--no-carry]
        [--no-adversarial] [--hold zoh|continuous]

Cases: ``pendulum_near_saturation`` (examples/pendulum.toml with ``-c*w + T + d``, ``c`` in
[0.4, 0.6], ``|d| <= 0.2``, 3 s: the design of issue 38), ``pendulum_disturbed_3`` (the
same with ``|d| <= 3``: unsafe, its verdict and CPU alone), ``quadruple_tank``
(tests/engine/quadruple_tank.toml, Johansson 2000, ``g1`` in [0.67, 0.73], ``|d| <= 0.2``) and
``cruise_loaded`` (examples/, an affine plant: the linear engine). Per case: the verdict, CPU
seconds of ``ce.verify`` (``time.process_time``), branches and boxes, then per state the width
of the tube's boxes active at 1/4, 1/2, 3/4 and all of the tube's span over the width of the
hull of ``--samples`` dense simulations over the same time span (the initial set's corners
and random states, each under one of the verifier's own concrete signals: the boxes' centre,
their corners held constant, bang-bang and random pieces, and the parameter box's centre,
corners and random values), then the same over the hull with the worst-case runs added
(``adversarial_runs``: first-order worst-case signals per state direction and measured time,
from the initial corners and centre and the parameter corners; ``--no-adversarial`` skips
them), and how many simulated states of both lie outside the tube (must be 0). ``--hold``
replaces the spec's hold. ``--no-carry`` measures the engine without the carried zonotope
(``NonlinearReach.carry = False``: the disturbances' first-order part in the remainder
ball, as before issue 38's change). Target: a ratio of at most 2.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.pipeline import loads_spec
from codev_engine.reach.adversary import sensitivity_signals
from codev_engine.reach.nonlinear import NonlinearReach
from codev_engine.reach.simulate import simulate_many
from codev_engine.reach.verification import _signals

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # (the ratio is nonlinear_tube.py's)
from benchmarks.nonlinear_tube import hull_ratios  # noqa: E402

CASES = ["pendulum_near_saturation", "pendulum_disturbed_3", "quadruple_tank", "cruise_loaded"]


def problem_of(case: str) -> ce.Problem:
    """The case's problem (see the module docstring)."""
    if case in ("pendulum_near_saturation", "pendulum_disturbed_3"):
        d = 0.2 if case == "pendulum_near_saturation" else 3.0
        text = (ROOT / "examples" / "pendulum.toml").read_text()
        text = text.replace('"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - c*w + T + d"')
        text = text.replace("[model]", f"disturbances = {{ d = [-{d}, {d}] }}\n"
                            "parameters = { c = [0.4, 0.6] }\n\n[model]", 1)
        return loads_spec(text)
    if case == "quadruple_tank":
        return loads_spec((ROOT / "tests" / "engine" / "quadruple_tank.toml").read_text())
    return loads_spec((ROOT / "examples" / f"{case}.toml").read_text())


def adversarial_runs(problem: ce.Problem, law, targets: list[float], X0: np.ndarray,
                     hold: str | None):
    """Runs under first-order worst-case disturbance signals (``sensitivity_signals``:
    each piece at the bound that pushes ``±x_i(t_f)`` up), from each state of ``X0`` and
    each corner of the parameter box, for each target time ``t_f`` and state direction.
    Random and bang-bang signals seldom push a state to its extreme; every one of these is
    a real run, so their hull is still a lower bound of the reach set's.

    Returns
    -------
    (t (K,), X (R, K, n))
    """
    pl = problem.plant
    n = pl.n
    if pl.parameters is not None:
        plo, phi = np.asarray(pl.parameters.lower, float), np.asarray(pl.parameters.upper, float)
        pc = np.array(list(itertools.product(*zip(plo, phi, strict=True))))
    else:
        pc = np.zeros((1, 0))
    dirs = np.vstack([np.eye(n), -np.eye(n)])
    rows = list(itertools.product(range(len(X0)), range(len(pc)), targets, range(len(dirs))))
    Xr = np.array([X0[a] for a, _, _, _ in rows])
    Qr = np.array([pc[b] for _, b, _, _ in rows])
    tr = np.array([t for _, _, t, _ in rows])
    Lr = np.array([dirs[c] for _, _, _, c in rows])
    piece, W, Q = sensitivity_signals(problem, law, Xr, Lr, tr, Q=Qr, hold=hold)
    t, X, _, _ = simulate_many(problem, law, Xr, hold=hold, disturbance=(piece, W, Q))
    return t, X


def ratios(problem: ce.Problem, law, tube, samples: int, adversarial: bool = True):
    """Tube width over simulated hull width per state at 1/4 ... 1 of the tube's span, the
    same over the hull with the adversarial runs added (None without disturbances or with
    ``adversarial`` off), and the number of simulated states (of both) outside the tube.

    Returns
    -------
    (list of (float, (n,) ndarray), list or None, int)
    """
    vs = problem.verify
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    rnd = np.random.default_rng(0).uniform(lo, hi, (max(samples - len(corners), 0), lo.size))
    X0 = np.vstack([corners, rnd])
    piece, W, Q = _signals(problem, X0.shape[0], seed=1)
    t, X, _, _ = simulate_many(problem, law, X0, hold=vs.hold, disturbance=(piece, W, Q))
    T = float(tube.t_end.max())
    fr = (0.25, 0.5, 0.75, 1.0)
    out = hull_ratios(tube, t, X, fr)
    adv = None
    if adversarial and problem.plant.disturbances is not None:
        targets = [float(t[int(np.argmin(np.abs(t - T * f)))]) for f in fr]
        ta, Xa = adversarial_runs(problem, law, targets,
                                  np.vstack([corners, 0.5 * (lo + hi)]), vs.hold)
        if ta.shape == t.shape and np.allclose(ta, t):
            X = np.concatenate([X, Xa], axis=0)
            adv = hull_ratios(tube, t, X, fr)
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
    return out, adv, outside


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
    ap.add_argument("--no-adversarial", action="store_true")
    ap.add_argument("--hold", choices=["zoh", "continuous"], default=None)
    args = ap.parse_args()
    if args.no_carry:  # (a dataclass field: set on each engine after its __init__)
        post = NonlinearReach.__post_init__

        def no_carry(self: NonlinearReach) -> None:
            post(self)
            self.carry = False

        NonlinearReach.__post_init__ = no_carry
    for case in args.cases:
        problem = problem_of(case)
        if args.hold is not None:  # (the spec's hold otherwise)
            problem = replace(problem, verify=replace(problem.verify, hold=args.hold))
        law = ce.synthesize(problem)
        t0 = time.process_time()
        res = ce.verify(problem, law, hold=problem.verify.hold)
        cpu = time.process_time() - t0
        st = res.stats
        print(f"{case}: {res.verdict} ({res.reason or '-'}), {cpu:.2f} s CPU, "
              f"{st.get('branches', 0)} branches, {res.tube.num_boxes} boxes", flush=True)
        if res.tube.num_boxes == 0 or res.verdict == "unsafe":
            continue  # (an unsafe verdict's tube is cut at the counterexample)
        rs, adv, outside = ratios(problem, law, res.tube, args.samples,
                                  not args.no_adversarial)
        for j, (tk, r) in enumerate(rs):
            line = f"  t = {tk:7.3f}: tube / hull = " + " ".join(f"{v:.2f}" for v in r)
            if adv is not None:
                line += "; with the adversarial runs " + " ".join(f"{v:.2f}" for v in adv[j][1])
            print(line)
        print(f"  simulated states outside the tube: {outside}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
