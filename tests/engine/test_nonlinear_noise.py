"""Measurement noise on a nonlinear plant (the pendulum), followed by the nonlinear engine
(docs/verification.md, "Nonlinear plants with measurement noise"): a set branches into every
region its Minkowski sum with the noise box meets, and the noise's part of the input,
``F_i delta`` with ``|delta| <= vr`` held over the period, widens the input boxes and forces
the discrepancy (zoh and continuous hold).

The oracle: dense simulation under random, bang-bang and adversarial noise sequences (the
adversaries pick, at each sample, the corner of the box whose region and law push furthest
along a direction): every simulated state lies in a box of the tube active at its time, and no
simulated violation contradicts ``robustly_safe``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from codev_engine.pipeline import loads_spec
from codev_engine.reach.nonlinear import NonlinearReach
from codev_engine.reach.nonlinear_flow import _Set
from codev_engine.reach.simulate import first_violation, simulate
from codev_engine.reach.verification import verify
from codev_engine.synthesis import synthesize
from tests.engine.test_noise import _assert_sound

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
INITIAL = "initial_set = { lower = [0.55, -0.1], upper = [0.6, 0.0] }"
#: a nearly point-like initial set: the tube's width is then the noise's doing, so a bound
#: that leaves the noise out shows (the noisy runs leave it)
POINT = "initial_set = { lower = [0.575, -0.05], upper = [0.5751, -0.0499] }"


def _pendulum(lo, hi, T=0.6, hold="zoh", initial=INITIAL, depth=6):
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = text.replace("time_horizon = 3.0", f"time_horizon = {T}")
    text = text.replace('hold = "zoh"', f'hold = "{hold}"').replace(INITIAL, initial)
    text = text.replace("max_depth = 6", f"max_depth = {depth}")
    text = text.replace("[verify]", f"[verify]\nmeasurement_noise = {{ lower = {lo}, "
                        f"upper = {hi} }}", 1)
    return loads_spec(text)


@pytest.mark.parametrize("hold", ["zoh", "continuous"])
def test_pendulum_tube_holds_noisy_runs(hold):
    # noise of 0.5 % of the state range (th in [-1, 1], w in [-5, 5])
    problem = _pendulum([-0.005, -0.025], [0.005, 0.025], hold=hold)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result, P=150, seed=3)


@pytest.mark.parametrize("lo, hi, T, hold", [
    ([-0.002, -0.01], [0.002, 0.01], 3.0, "zoh"),
    ([-0.005, -0.025], [0.005, 0.025], 0.6, "zoh"),
    ([-0.002, -0.01], [0.002, 0.01], 2.0, "continuous"),
    ([-0.005, -0.025], [0.005, 0.025], 0.6, "continuous"),
])
def test_point_like_initial_set_tube_holds_noisy_runs(lo, hi, T, hold):
    # (without the noise's input widening or without its forcing, hundreds of these noisy
    # states leave the tube: the tube of a point-like set is that of one noise sequence)
    problem = _pendulum(lo, hi, T=T, initial=POINT, hold=hold)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result, P=100, seed=4)


def test_split_keeps_every_region_a_noisy_measurement_may_select():
    # a small set next to region boundaries: for states x of the set and noise values v of
    # the box, the region of x + v is a child and x lies in that child's set
    problem = _pendulum([-0.01, -0.05], [0.01, 0.05])
    law = synthesize(problem)
    eng = NonlinearReach(problem, law, "zoh", 0)
    rng = np.random.default_rng(5)
    vc, vr = eng.vc, eng.vr
    corners = np.array([[a, b] for a in (-1, 1) for b in (-1, 1)], float)
    tried = 0
    for x in rng.uniform([-0.6, -3.0], [0.6, 3.0], (4000, 2)):
        own = law.locate(x)[0]
        seen = law.locate(x + vc + corners * vr)
        if own < 0 or np.any(seen < 0) or np.all(seen == own):
            continue  # (only states whose measurement may select another region)
        r = np.full(2, 1e-4)
        V = np.array([[a, b] for a in (-r[0], r[0]) for b in (-r[1], r[1])])
        s = _Set(x, np.eye(2), np.zeros((2, 2)), 0, (), np.vstack([np.eye(2), -np.eye(2)]),
                 np.concatenate([r, r]), V)
        kids = {i: c for i, c in eng._split(s)}
        X = x + rng.uniform(-r, r, (30, 2))
        Vn = np.vstack([vc + corners * vr, vc + rng.uniform(-vr, vr, (30, 2))])
        for xs in X:
            for i in law.locate(xs + Vn):
                assert i in kids, f"region {i} of a measurement missed at {xs}"
                c = kids[i]
                d = np.linalg.solve(c.D, xs - c.y)
                assert np.all(c.H @ d <= c.h + 1e-9), f"{xs} not in the child of region {i}"
        tried += 1
        if tried >= 12:
            break
    assert tried >= 5


def test_verdict_is_no_longer_unknown_noise_and_for_all_time_still_is():
    problem = _pendulum([-0.002, -0.01], [0.002, 0.01], T=3.0)
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", None), result.summary()
    # (time_horizon = "inf": the ellipsoids of reach.terminal are the nominal loop's)
    ever = verify(_pendulum([-0.002, -0.01], [0.002, 0.01], T='"inf"\nmax_samples = 20'), law)
    assert (ever.verdict, ever.reason) == ("unknown", "noise")


def test_noise_large_enough_gives_a_replayed_counterexample():
    # noise of 5 % of the state range: the law, fooled at the samples where it leaves
    # saturation, lets the pendulum swing past upright (unsafe[1])
    problem = _pendulum([-0.1, -0.5], [0.1, 0.5], T=1.0, depth=1)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "unsafe", result.summary()
    cex = result.counterexample
    noise = cex.disturbance.noise
    assert noise is not None
    assert np.all(noise >= [-0.1, -0.5]) and np.all(noise <= [0.1, 0.5])
    trace = simulate(problem, law, cex.x0, disturbance=cex.disturbance)
    v = first_violation(problem, law, trace)
    assert v is not None and v.kind == cex.kind
