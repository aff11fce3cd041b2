"""Nonlinear plants with disturbances and uncertain parameters: the nonlinear engine's
enclosures over ``(x, u, w, p)`` and the discrepancy's forcing ``|J_w| |w - w_nom|``
(docs/verification.md, "Nonlinear plants with disturbances and parameters").

The oracle: dense simulation under bang-bang and random disturbance signals and random
parameter values (fixed per run; the centre and the corners too): every simulated state lies
in a box of the tube active at its time, and no simulated violation contradicts
``robustly_safe``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from codev_engine.pipeline import loads_spec
from codev_engine.reach.simulate import first_violation, simulate, simulate_many, violations_many
from codev_engine.reach.verification import _signals, verify
from codev_engine.synthesis import synthesize
from tests.engine.test_noise import _initial_states, _outside

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _pendulum(d=0.01, c=(0.45, 0.55), T=0.6, hold="zoh"):
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = text.replace('"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - c*w + T + d"')
    text = text.replace("[model]", f"disturbances = {{ d = [{-d}, {d}] }}\n"
                        f"parameters = {{ c = [{c[0]}, {c[1]}] }}\n\n[model]", 1)
    text = text.replace("time_horizon = 3.0", f"time_horizon = {T}")
    return loads_spec(text.replace('hold = "zoh"', f'hold = "{hold}"'))


def _assert_sound(problem, law, result, P=150, seed=1):
    X0 = _initial_states(problem, P, seed)
    piece, W, Q = _signals(problem, X0.shape[0], seed=seed)
    t, X, U, alive = simulate_many(problem, law, X0, hold=result.hold,
                                   disturbance=(piece, W, Q))
    count, worst = _outside(result.tube, t, X)
    assert count == 0, f"{count} simulated states outside the tube (worst {worst:g})"
    if result.verdict == "robustly_safe":
        bad, _ = violations_many(problem, t, X, U, alive)
        assert not bad.any(), "a simulated violation contradicts robustly_safe"


def test_pendulum_with_a_disturbance_and_a_parameter_keeps_every_run():
    problem = _pendulum()
    law = synthesize(problem)
    result = verify(problem, law, hold="zoh")
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result)


@pytest.mark.slow
@pytest.mark.parametrize("hold, T, d", [("continuous", 0.6, 0.01), ("zoh", 3.0, 0.005)])
def test_pendulum_uncertain_slow(hold, T, d):
    problem = _pendulum(d=d, T=T)
    law = synthesize(problem)
    result = verify(problem, law, hold=hold)
    assert result.verdict in ("robustly_safe", "unknown"), result.summary()
    _assert_sound(problem, law, result, P=400, seed=2)


@pytest.mark.slow
def test_nonlinear_unsafe_for_some_parameter_value_is_found_and_replayed():
    # (slow: about 10 s of CPU, the engine's bisections then the search)
    # a weaker actuator (gain k down to 0.6) cannot hold the pendulum beyond asin(3.6/9.81)
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = text.replace('"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - 0.5*w + k*T"')
    text = text.replace("[model]", "parameters = { k = [0.6, 1.0] }\nnominal = { k = 1.0 }\n\n"
                        "[model]", 1).replace("time_horizon = 3.0", "time_horizon = 1.0")
    # (a shallow refinement: the engine's part is to stop, the concrete search's to find)
    text = text.replace("max_depth = 6", "max_depth = 1")
    problem = loads_spec(text)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "unsafe", result.summary()
    ce = result.counterexample
    assert 0.6 <= ce.disturbance.parameters[0] < 1.0
    v = first_violation(problem, law, simulate(problem, law, ce.x0, disturbance=ce.disturbance))
    assert v is not None and v.kind == ce.kind
