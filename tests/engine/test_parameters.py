"""Uncertain parameters in the linear engine: a field affine in ``(x, u, w)`` for each value of
its parameters is followed as the nominal model plus an additive disturbance bounded per
period (docs/verification.md, "Uncertain parameters").

The oracle: dense simulation with random parameter values (fixed per run, the box's centre
and corners included) under random and bang-bang disturbance signals: every simulated state
lies in a box of the tube active at its time, and no simulated violation contradicts
``robustly_safe``.
"""

from __future__ import annotations

import numpy as np
import pytest

from codev_engine.pipeline import loads_spec
from codev_engine.reach.linear import affine_plant
from codev_engine.reach.simulate import first_violation, simulate, simulate_many, violations_many
from codev_engine.reach.verification import _signals, verify
from codev_engine.synthesis import synthesize
from tests.engine.test_noise import DI_V, _initial_states, _outside

GAIN = 'dynamics = ["v", "k*a"]\nparameters = { k = [0.8, 1.2] }'
DAMPING = 'dynamics = ["v", "a - c*v"]\nparameters = { c = [0.0, 0.4] }'
BOTH = ('dynamics = ["v", "k*a - c*v + w"]\nparameters = { k = [0.9, 1.1], c = [0.0, 0.2] }\n'
        "disturbances = { w = [-0.05, 0.05] }")
MATRIX = "A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]"


def _di(plant, hold="zoh", T=2.0, edge=-1.0, noise=""):
    return loads_spec(DI_V.format(plant=plant, hold=hold, T=T, edge=edge, noise=noise))


def _assert_sound(problem, law, result, P=100, seed=1):
    X0 = _initial_states(problem, P, seed)
    piece, W, Q = _signals(problem, X0.shape[0], seed=seed)
    # a random parameter value per run as well as the centre and the corners (_signals)
    t, X, U, alive = simulate_many(problem, law, X0, hold=result.hold,
                                   disturbance=(piece, W, Q))
    count, worst = _outside(result.tube, t, X)
    assert count == 0, f"{count} simulated states outside the tube (worst {worst:g})"
    if result.verdict == "robustly_safe":
        bad, _ = violations_many(problem, t, X, U, alive)
        assert not bad.any(), "a simulated violation contradicts robustly_safe"


def test_affine_plant_bounds_the_deviation_over_the_box():
    ap = affine_plant(_di(BOTH))
    np.testing.assert_allclose(ap.Ac, [[0.0, 1.0], [0.0, -0.1]])  # nominal c = 0.1
    np.testing.assert_allclose(ap.Bc, [[0.0], [1.0]])
    np.testing.assert_allclose(ap.dA, [[0.0, 0.0], [0.0, 0.1]], rtol=1e-9, atol=2e-12)
    np.testing.assert_allclose(ap.dB, [[0.0], [0.1]], rtol=1e-9, atol=2e-12)
    np.testing.assert_allclose(ap.w_abs, [0.05])
    # not affine in x for fixed parameters: not this engine's
    assert affine_plant(_di('dynamics = ["v", "k*a - c*sin(p)"]\n'
                            "parameters = { k = [0.9, 1.1], c = [0.0, 0.2] }")) is None


@pytest.mark.parametrize("plant, hold", [(GAIN, "zoh"), (DAMPING, "continuous"),
                                         (BOTH, "zoh")])
def test_tube_contains_runs_with_random_parameters(plant, hold):
    problem = _di(plant, hold)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result)
    # the parameters widen the tube
    nominal = verify(_di(MATRIX, hold), law)
    assert np.all(result.width_at(1.9) > nominal.width_at(1.9))


@pytest.mark.slow
@pytest.mark.parametrize("plant, hold", [(GAIN, "continuous"), (DAMPING, "zoh"),
                                         (BOTH, "continuous")])
def test_tube_contains_runs_with_random_parameters_slow(plant, hold):
    problem = _di(plant, hold, T=3.0)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result, P=300, seed=2)


def test_parameters_with_measurement_noise_keep_every_run():
    from codev_engine.reach.verification import noise_sequences
    from tests.engine.test_noise import NOISE

    problem = _di(BOTH, noise=NOISE.format(a=-0.02, b=0.02))
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    X0 = _initial_states(problem, 60, 3)
    piece, W, Q = _signals(problem, X0.shape[0], seed=3)
    t, X, _, _ = simulate_many(problem, law, X0, disturbance=(piece, W, Q),
                               noise=noise_sequences(problem, X0.shape[0], seed=3))
    count, worst = _outside(result.tube, t, X)
    assert count == 0, f"{count} states outside the tube (worst {worst:g})"


def test_safe_nominally_unsafe_for_some_parameter_value():
    # anti-damping up to c = -2 (nominal 0): the saturated law cannot stop the mass in time
    plant = 'dynamics = ["v", "a - c*v"]\nparameters = { c = [-2.0, 0.0] }\nnominal = { c = 0.0 }'
    problem = _di(plant, T=2.5, edge=-0.3)
    law = synthesize(problem)
    assert verify(_di(MATRIX, T=2.5, edge=-0.3), law).verdict == "robustly_safe"
    result = verify(problem, law)
    assert result.verdict == "unsafe", result.summary()
    ce = result.counterexample
    assert ce.disturbance is not None and -2.0 <= ce.disturbance.parameters[0] <= 0.0
    v = first_violation(problem, law, simulate(problem, law, ce.x0, disturbance=ce.disturbance))
    assert v is not None and v.kind == "unsafe"
