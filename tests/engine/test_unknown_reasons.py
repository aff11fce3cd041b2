"""Every ``unknown`` names its real cause, and its tube's contract (issue 38, Deliver 3).

Small real plants that end in each reason the engines give: the reason, the ``detail``
(the time, what happened, what to change) and, where the tube is partial, that it ends
where the detail says and holds every trajectory of the law's own loop (dense simulation
under the disturbance's extreme and switching signals) up to that time
(docs/verification.md, "Verdicts" and "The tube file").
"""

from __future__ import annotations

import re
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.pipeline import loads_spec
from codev_engine.reach.linear import Finding
from codev_engine.reach.simulate import simulate_many, violations_many
from codev_engine.reach.verification import (
    UNKNOWN_WORDS,
    VerificationResult,
    _signals,
    _unknown_reason,
    verify,
)
from codev_engine.synthesis import synthesize
from codev_engine.view.record_content import _verdict_sentence
from tests.conftest import EXAMPLES_DIR
from tests.di_variants import HULL_CORNER, di_spec
from tests.engine.test_examples_tube import _complete_until, _outside
from tests.engine.test_formulations import BASE
from tests.engine.test_noise import _di


def _corners_and_random(lo: np.ndarray, hi: np.ndarray, P: int, seed: int = 3) -> np.ndarray:
    d = lo.shape[0]
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(d)], indexing="ij"))
    rng = np.random.default_rng(seed)
    return np.vstack([corners.reshape(d, -1).T, rng.uniform(lo, hi, (P, d))])


def _dense_inside(problem, law, result, t_max: float, P: int = 40) -> tuple[int, bool]:
    """(states outside the tube up to ``t_max``, any violation) of the law's own loop from
    the initial set's corners and random states, under the disturbance's signals (or the
    noise's sequences) when the plant has them."""
    vs = problem.verify
    sim = replace(problem, verify=replace(vs, time_horizon=float(vs.time_horizon)))
    X0 = _corners_and_random(vs.initial_lower, vs.initial_upper, P)
    kw: dict = {"hold": result.hold}
    if problem.plant.uncertain:
        kw["disturbance"] = _signals(sim, X0.shape[0], seed=5)
    if vs.noisy:
        from codev_engine.reach.verification import noise_sequences

        kw["noise"] = noise_sequences(sim, X0.shape[0], seed=5)
    t, X, U, alive = simulate_many(sim, law, X0, **kw)
    count, _ = _outside(result.tube, np.asarray(t), X, t_max)
    return count, bool(violations_many(sim, t, X, U, alive)[0].any())


def _partial_after(detail: str) -> float:
    return float(re.search(r"partial after t = ([0-9.eE+-]+)", detail).group(1))


# the cruise control on a hilly road (examples/cruise_grade.toml) over 5 s, with the speed
# limit just below its disturbed tube's top (10.0558) and above what the searches reach
CRUISE_TIGHT = (
    (EXAMPLES_DIR / "cruise_grade.toml").read_text()
    .replace('time_horizon = "inf"', "time_horizon = 5.0")
    .replace("lower = [11.0]", "lower = [10.05]")
)


@pytest.fixture(scope="module")
def cruise():
    problem = loads_spec(CRUISE_TIGHT)
    law = synthesize(problem)
    return problem, law, verify(problem, law)


def test_a_disturbed_hull_that_meets_an_unsafe_set_is_over_approximation_not_max_depth(cruise):
    problem, law, result = cruise
    assert (result.verdict, result.reason) == ("unknown", "over_approximation"), \
        result.summary()
    d = result.detail
    # what happened, where, and that raising max_depth is not the way out
    assert "over-approximation" in d and "meets unsafe set 0" in d and "at t = " in d
    assert "no concrete search found" in d and "raise verify.max_depth" not in d
    # the merged run stopped there: the tube is partial after the sample it stopped at
    t_stop = _partial_after(d)
    Ts = float(problem.model.sample_time)
    assert 0 < t_stop < problem.verify.time_horizon
    assert t_stop == _complete_until(problem, result) == result.stats["complete_until"]
    assert t_stop - 1e-9 <= result.tube.t_end.max() <= t_stop + Ts + 1e-9
    outside, violated = _dense_inside(problem, law, result, t_stop)
    assert outside == 0
    assert not violated  # (no concrete trajectory does: why it is not unsafe)


def test_the_recording_and_the_json_say_the_reason_and_its_detail(cruise, tmp_path):
    problem, law, result = cruise
    sentence = _verdict_sentence(SimpleNamespace(result=result, horizon=5.0))
    assert "(over_approximation)" in sentence and result.detail in sentence
    # a saved result keeps reason and detail (the --json and the session's file)
    result.save(tmp_path / "r.npz")
    again = VerificationResult.load(tmp_path / "r.npz")
    assert (again.reason, again.detail) == (result.reason, result.detail)


def test_a_noisy_loop_s_merged_set_meeting_an_unsafe_set_is_over_approximation():
    # the double integrator measured with noise, an unsafe half-plane p <= 0.01 that its
    # merged sets touch near t = 1.9 s
    problem = _di(edge=0.01, T=2.0)
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "over_approximation"), \
        result.summary()
    t_stop = _partial_after(result.detail)
    assert result.tube.t_end.max() <= t_stop + float(problem.model.sample_time) + 1e-9
    outside, _ = _dense_inside(problem, law, result, t_stop)
    assert outside == 0


def test_max_depth_names_the_field_to_raise_and_keeps_the_tube_whole(example_law):
    _, law = example_law("double_integrator.toml")
    problem = di_spec(HULL_CORNER)
    result = verify(problem, law, max_depth=0)
    assert (result.verdict, result.reason) == ("unknown", "max_depth"), result.summary()
    assert "verify.max_depth = 0" in result.detail and "at t = " in result.detail
    assert "partial" not in result.detail  # refinement ran out: the branch goes on
    T = float(problem.verify.time_horizon)
    assert result.tube.t_end.max() >= T - 1e-9
    assert _dense_inside(problem, law, result, T)[0] == 0


def test_a_set_past_the_domain_by_less_than_the_locator_s_tolerance_is_a_possible_exit():
    # the double integrator's initial set 1e-10 past its domain's face p <= 5: the law is
    # defined there (the locator's 1e-9), so no exit is exact and the tube goes on whole
    problem = _di(noise=False, T=1.0, edge=-3.0)
    vs = replace(problem.verify, initial_lower=np.array([4.5, -0.1]),
                 initial_upper=np.array([5.0 + 1e-10, 0.0]))
    problem = replace(problem, verify=vs)
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "infeasible_region"), \
        result.summary()
    d = result.detail
    assert "at t = 0" in d and "may leave the law's domain" in d and "tube goes on" in d
    assert "partial" not in d
    assert result.tube.t_end.max() >= 1.0 - 1e-9
    outside, violated = _dense_inside(problem, law, result, 1.0)
    assert outside == 0 and not violated


def test_a_nonlinear_max_depth_names_the_field_and_keeps_the_tube_whole(example_law):
    # the pendulum over 0.7 s without bisections of its initial set: undecided at 0.6 s,
    # the last refinement level goes on, so the tube holds every trajectory to the end
    problem, law = example_law("pendulum.toml")
    problem = replace(problem, verify=replace(problem.verify, time_horizon=0.7))
    result = verify(problem, law, max_depth=0)
    assert (result.verdict, result.reason) == ("unknown", "max_depth"), result.summary()
    assert "at t = 0.6" in result.detail and "verify.max_depth = 0" in result.detail
    assert result.tube.t_end.max() >= 0.7 - 1e-9
    assert _dense_inside(problem, law, result, 0.7, P=30)[0] == 0


def test_law_parameters_says_why_and_that_there_is_no_tube():
    text = BASE.format(N=3, norm="2").replace(
        'A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]', 'dynamics = ["v", "u - 0.1*sin(p)"]'
    ) + "du_min = [-0.5]\ndu_max = [0.5]\n" + (
        '[verify]\ntime_horizon = 1.0\nhold = "zoh"\n'
        "initial_set = { lower = [0.0, 0.0], upper = [0.1, 0.1] }\n"
    )
    problem = loads_spec(text)
    result = ce.verify(problem, ce.synthesize(problem))
    assert (result.verdict, result.reason) == ("unknown", "law_parameters")
    assert "the plant is not affine" in result.detail and "tube is empty" in result.detail
    assert result.tube.num_boxes == 0


def test_a_hull_s_violation_without_refinement_findings_is_over_approximation():
    # the engine's finding for a violation on a merged or disturbed set (state coordinates,
    # no initial state to replay): what _unknown_reason makes of it
    f = Finding("safe", 1, 0.75, None)
    reason, detail = _unknown_reason([f], [], 6)
    assert reason == "over_approximation"
    assert "at t = 0.75" in detail and "leaves safe set 1" in detail
    assert "ends there" in detail
    # beside a refinement that ran out, max_depth (raising it may help) is named
    reason, detail = _unknown_reason([f, Finding("max_depth", -1, 0.5, None)], [], 6)
    assert reason == "max_depth" and "verify.max_depth = 6" in detail


def test_every_reason_has_words():
    for reason in ("max_depth", "over_approximation", "infeasible_region", "enclosure",
                   "limit", "budget", "no_invariant", "law_parameters", "noise"):
        assert UNKNOWN_WORDS[reason]
