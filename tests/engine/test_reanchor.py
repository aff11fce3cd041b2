"""After an invariance certificate, the tube is not the early anchor's transient (issue 38).

A certificate closed early repeats the anchor set's own transient up to the horizon (a
saw-tooth as wide as the transient) although the true sets shrink; the linear engine
therefore anchors again from the closing sets (``LinearReach._reanchor``), nominal runs and
``time_horizon = "inf"`` included. Checked here by dense simulation of the law's own loop
to the end of the shown horizon: every state in a box of the tube active at its time, and
(``"inf"``) every state after the anchor in the certificate's band.
"""

from __future__ import annotations

import numpy as np
from test_verify import _initial_states, _outside

import codev_engine as ce
from codev_engine.reach.claim import WIDTH_OF_BAND, certificate_band, width_at_end
from codev_engine.reach.simulate import simulate_many
from tests.di_variants import DI_PATH


def test_a_nominal_certificate_repeats_a_tight_period_that_holds_every_state(example_law):
    # mass-spring (zoh, 8 s): anchored at 0.2 s and closed at 2 s, the repeated period was
    # 0.5 x 1.1 wide at 8 s where the simulated states are within 1e-6
    problem, law = example_law("mass_spring_soft.toml")
    result = ce.verify(problem, law)
    cert = result.stats["certificate"]
    assert result.verdict == "robustly_safe" and cert["anchor_time"] > 1.0, cert
    T, width, _ = width_at_end(problem, result)
    assert np.all(width < 0.01), width
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, 40, 20)
    t, X, _, alive = simulate_many(problem, law, X0, t_end=T, dt_out=0.05)
    assert np.all(alive) and t[-1] == T
    res = _outside(result.tube, t, X)
    assert res["count"] == 0 and res["gap_count"] == 0, res
    # the repeated period is within a few times the simulated spread plus its rounding
    lo, hi = result.tube.hull_at(T)
    assert np.all(hi - lo <= 100 * np.ptp(X[:, -1, :], axis=0) + 1e-3)


def test_an_all_time_band_is_the_last_anchor_s_and_holds_every_state():
    # the double integrator for all time (continuous hold): the band was 0.96 x 0.45 (anchor
    # at 9 s, closed at 19 s); the states converge to the origin
    text = DI_PATH.read_text().replace("time_horizon = 9.0", 'time_horizon = "inf"')
    problem = ce.loads_spec(text, path="<double integrator for all time>")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", "invariant"), result.summary()
    band = certificate_band(result)
    T, width, which = width_at_end(problem, result)
    assert which == WIDTH_OF_BAND and np.all(width < 0.1), width
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, 24, 12)
    t_end = 2 * band.t_closed
    t, X, _, alive = simulate_many(problem, law, X0, hold=result.hold, t_end=t_end,
                                   dt=0.01, dt_out=0.1)
    assert np.all(alive)
    res = _outside(result.tube, t, X)  # (up to the tube's end, the closing sample)
    assert res["count"] == 0 and res["gap_count"] == 0, res
    after = X[:, t >= band.t_anchor - 1e-9, :]
    assert np.all(after >= band.lower - 1e-9) and np.all(after <= band.upper + 1e-9)


def test_a_limit_while_re_anchored_keeps_the_certificate_that_closed(monkeypatch):
    # the branch limit reached in the re-anchored set's period: the certificate that closed
    # before it still holds; the verdict stays robustly_safe (was unknown / limit), with
    # the first certificate's (wider, sound) repeated tube
    text = DI_PATH.read_text().replace("time_horizon = 9.0", "time_horizon = 60.0")
    problem = ce.loads_spec(text, path="<double integrator, 60 s>")
    law = ce.synthesize(problem)
    full = ce.verify(problem, law)
    assert full.verdict == "robustly_safe", full.summary()
    monkeypatch.setenv("CODEV_LIMITS", f"branches={full.stats['branches'] - 2}")
    result = ce.verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", None), result.summary()
    first, last = result.stats["certificate"], full.stats["certificate"]
    assert first["closed_sample"] <= last["anchor_sample"] < last["closed_sample"]
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, 24, 12)
    t, X, _, alive = simulate_many(problem, law, X0, hold=result.hold, dt=0.01, dt_out=0.25)
    assert np.all(alive) and result.tube.t_end.max() == 60.0
    res = _outside(result.tube, t, X)
    assert res["count"] == 0 and res["gap_count"] == 0, res
