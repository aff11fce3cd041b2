"""Disturbances that cannot change the plant are verified as the nominal plant (issue 38).

A disturbance box of zero width on every axis, or a disturbance that does not enter the
field (a zero column of ``E``, an expression whose derivative in it is zero), leaves
``f(x, u, w) = f(x, u, w_nominal)``: the tube is the nominal one (not the merged, disturbed
path's, wider and slower) and the claim says so. Checked against the nominal plant's tube
and by dense simulation of the law's own loop.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from test_verify import _initial_states, _outside

import codev_engine as ce
from codev_engine.plant import disturbances_matter, field_uncertain
from codev_engine.reach.claim import build_claim
from codev_engine.reach.simulate import simulate_many
from tests.conftest import EXAMPLES_DIR

DI = (EXAMPLES_DIR / "double_integrator.toml").read_text(encoding="utf-8")
DYN = 'dynamics = ["x2", "u"]'
MATRIX = DI.replace(DYN, "A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]")


def _with(text: str, plant: str) -> ce.Problem:
    assert text.count(DYN) == 1 or "A = [[" in text
    return ce.loads_spec(text.replace(DYN, plant) if DYN in text else text + plant)


def _matrix(extra: str) -> ce.Problem:
    return ce.loads_spec(MATRIX.replace("B = [[0.0], [1.0]]", "B = [[0.0], [1.0]]\n" + extra))


@pytest.fixture(scope="module")
def di_nominal():
    problem = ce.loads_spec(DI)
    law = ce.synthesize(problem)
    return law, ce.verify(problem, law)


def test_which_disturbances_can_act():
    acts = _with(DI, 'dynamics = ["x2", "u + w"]\ndisturbances = { w = [-0.1, 0.1] }')
    assert disturbances_matter(acts) and field_uncertain(acts)
    for inert in (
        _with(DI, 'dynamics = ["x2", "u + w"]\ndisturbances = { w = [0.0, 0.0] }'),
        _with(DI, 'dynamics = ["x2", "u + 0*w"]\ndisturbances = { w = [-1.0, 1.0] }'),
        # (one axis without width, the other without effect)
        _with(DI, 'dynamics = ["x2 + v", "u + w - w"]\n'
                  'disturbances = { v = [0.2, 0.2], w = [-1.0, 1.0] }'),
        _matrix("E = [[0.0], [0.0]]\ndisturbances = { w = [-1.0, 1.0] }"),
        _matrix("E = [[0.0], [1.0]]\ndisturbances = { w = [0.3, 0.3] }"),
    ):
        assert not disturbances_matter(inert) and not field_uncertain(inert)
        assert inert.plant.uncertain  # (declared all the same)
    assert disturbances_matter(_matrix("E = [[0.0], [1.0]]\ndisturbances = { w = [0, 1e-9] }"))


@pytest.mark.parametrize("plant", [
    'dynamics = ["x2", "u + w"]\ndisturbances = { w = [0.0, 0.0] }',
    'dynamics = ["x2", "u + 0*w"]\ndisturbances = { w = [-1.0, 1.0] }',
    "E = [[0.0], [0.0]]\ndisturbances = { w = [-1.0, 1.0] }",
])
def test_an_inert_disturbance_gives_the_nominal_tube_and_says_so(di_nominal, plant):
    law, nominal = di_nominal
    problem = (_matrix(plant) if plant.startswith("E") else _with(DI, plant))
    result = ce.verify(problem, law)
    assert result.verdict == "robustly_safe"
    assert np.array_equal(result.tube.lower, nominal.tube.lower)
    assert np.array_equal(result.tube.upper, nominal.tube.upper)
    (line,) = build_claim(problem, result).uncertainty
    assert line.endswith("verified as the nominal plant"), line


def test_a_constant_disturbance_s_drift_is_in_the_tube():
    # a zero-width box away from 0: w = 0.05 always (the nominal value too); the tube is the
    # nominal one with the drift E w, and holds the simulated states of the law's loop
    problem = _matrix("E = [[0.0], [1.0]]\ndisturbances = { w = [0.05, 0.05] }")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    assert result.verdict == "robustly_safe" and not disturbances_matter(problem)
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, 30, 20)
    P = X0.shape[0]
    signal = (1.0, np.full((P, 10, 1), 0.05), np.zeros((P, 0)))  # w(t) = 0.05, replayed
    t, X, _, alive = simulate_many(problem, law, X0, hold=result.hold, dt_out=0.05,
                                   disturbance=signal)
    assert np.all(alive)
    res = _outside(result.tube, t, X)
    assert res["count"] == 0 and res["gap_count"] == 0, res
    # the drift shows: without it (w = 0) the loop ends elsewhere than the tube says
    free = simulate_many(problem, law, X0, hold=result.hold, dt_out=0.05,
                         disturbance=(1.0, np.zeros((P, 10, 1)), np.zeros((P, 0))))
    assert _outside(result.tube, free.t, free.X)["count"] > 0


def test_a_nonlinear_plant_with_a_zero_disturbance_gets_its_ellipsoid_for_all_time():
    # the pendulum for all time with d in [0, 0]: unknown / no_invariant before ("ellipsoid
    # certificates cover nominal plants"); now the nominal run and certificate
    text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"',
                  (EXAMPLES_DIR / "pendulum.toml").read_text(encoding="utf-8"))
    text = text.replace('"9.81*sin(th) - 0.5*w + T"]', '"9.81*sin(th) - 0.5*w + T + d"]\n'
                        "disturbances = { d = [0.0, 0.0] }")
    problem = ce.loads_spec(text)
    assert not field_uncertain(problem)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", "invariant"), result.summary()
    assert result.stats["certificate"]["kind"] == "ellipsoid"
    # every state in the tube, or, once its set stopped in the ellipsoid, in the ellipsoid
    # at the samples (in its period's box between them: not stored)
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, 30, 10)
    Ts = problem.model.sample_time
    t, X, _, alive = simulate_many(problem, law, X0, t_end=float(result.tube.t_end.max()),
                                   dt_out=Ts)
    assert np.all(alive)
    P, c = result.certificate["P"], result.certificate["centre"]
    for k, tk in enumerate(t):
        lo, hi = result.tube.at(tk)
        x = X[:, k, :]
        in_box = np.any(np.all((x[:, None] >= lo[None] - 1e-9) & (x[:, None] <= hi[None] + 1e-9),
                               axis=2), axis=1) if lo.size else np.zeros(len(x), bool)
        y = x - c
        in_ell = np.einsum("pi,ij,pj->p", y, P, y) <= 1.0
        assert np.all(in_box | in_ell), f"a state in neither at t = {tk}"
