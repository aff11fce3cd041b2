"""Nonlinear plants with disturbances and uncertain parameters: the nonlinear engine's
enclosures over ``(x, u, w, p)`` and the discrepancy's forcing ``|J_w| |w - w_nom|``
(docs/verification.md, "Nonlinear plants with disturbances and parameters").

The oracle: dense simulation under bang-bang and random disturbance signals and random
parameter values (fixed per run; the centre and the corners too): every simulated state lies
in a box of the tube active at its time, and no simulated violation contradicts
``robustly_safe``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from codev_engine.pipeline import loads_spec
from codev_engine.reach.adversary import sensitivity_signals
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


# ---- issue 38, "decisive under uncertainty": the pendulum near the point of no return ----
# |T| <= 6 holds the pendulum up to asin(6/9.81) = 0.658 rad; it starts at 0.55-0.6 rad with
# the damping uncertain in [0.4, 0.6] and a torque disturbance (m = l = 1, g = 9.81, the
# bundled example's MPC on the linearisation, unsafe beyond 0.7 rad or past upright).


def _near_saturation(d: float, T: float = 3.0, point: bool = False):
    problem = _pendulum(d=d, c=(0.4, 0.6), T=T)
    if point:  # one initial state: the tube's width is the uncertainty's doing alone
        vs = problem.verify
        lo = np.array([0.575, -0.05])
        problem = replace(problem, verify=replace(vs, initial_lower=lo,
                                                  initial_upper=lo + 1e-6))
    return problem


def test_near_saturation_with_a_large_disturbance_is_refuted_before_the_proof():
    # +-3 N m against a 0.46 N m torque margin at 0.6 rad: the search under extreme signals
    # and parameter corners finds it in about a second, before any reach set is computed
    problem = _near_saturation(3.0)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "unsafe", result.summary()
    assert result.stats.get("refuted_first") and result.stats["branches"] == 0
    ce = result.counterexample
    assert 0.4 <= ce.disturbance.parameters[0] <= 0.6
    assert np.all(np.abs(ce.disturbance.values) <= 3.0)
    # replayed with the law's own loop (the reference integrator, the same signal)
    v = first_violation(problem, law, simulate(problem, law, ce.x0, disturbance=ce.disturbance))
    assert v is not None and v.kind == ce.kind and abs(v.t - ce.t) < 1e-6


def test_near_saturation_disturbance_tube_is_rerooted_and_holds_every_run():
    # from one initial state the whole width is the disturbance's and the damping's: kept
    # as a remainder ellipsoid that no region cut could touch, it grew to 10 rad by 0.9 s
    # (every saturated child carried the states of the unsaturated region and vice versa);
    # re-rooted into the star at each sample it is cut by the regions and stays bounded
    problem = _near_saturation(0.2, T=1.5, point=True)
    law = synthesize(problem)
    result = verify(problem, law, max_depth=0)
    assert result.verdict in ("robustly_safe", "unknown"), result.summary()
    tube = result.tube
    assert float(tube.t_end.max()) >= 1.5 - 1e-9  # complete
    sel = (tube.t_start <= 0.9) & (tube.t_end >= 0.9)
    assert (tube.upper[sel] - tube.lower[sel]).max() < 1.0
    _assert_sound(problem, law, result, P=100, seed=3)


@pytest.mark.slow
def test_near_saturation_with_the_reported_disturbance_is_robustly_safe_and_sound():
    # (slow: about 9 s of CPU for the proof) the reported design (+-0.2, damping in [0.4,
    # 0.6], 3 s): robustly_safe since the disturbances' first-order part is carried as a
    # zonotope (it was unknown / max_depth after ~100 s), and every run under bang-bang and
    # random signals and parameter corners inside the tube
    problem = _near_saturation(0.2)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    _assert_sound(problem, law, result, P=300, seed=4)
    _assert_sound(problem, law, result, P=300, seed=5)
    # and the worst-case signals from the initial set's corners and centre
    vs = problem.verify
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    X0 = np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]],
                   0.5 * (lo + hi)])
    _worst_case_runs(problem, law, result, X0, (0.75, 1.5, 2.25, 3.0))


def test_near_saturation_from_one_state_is_proved_by_the_carried_zonotope():
    # from one initial state the width is the disturbance's and the damping's alone; their
    # first-order part carried through the linear flow (a zonotope folded into the star at
    # each sample) keeps the tube within 1.4x of the hull in th and proves the whole 3 s
    # without refinement; in the remainder ball (isotropic in W, 44x the true extent in th
    # per substep) the same cell met the unsafe set at 0.7 s
    problem = _near_saturation(0.2, point=True)
    law = synthesize(problem)
    result = verify(problem, law, max_depth=0)
    assert result.verdict == "robustly_safe", result.summary()
    assert float(result.tube.t_end.max()) >= 3.0 - 1e-9
    _assert_sound(problem, law, result, P=150, seed=6)


def _worst_case_runs(problem, law, result, X0, times):
    """Runs under the first-order worst-case signals (``sensitivity_signals``: each piece
    at the bound that pushes ``±x_i(t)`` up) from each state of ``X0``, each parameter
    corner and each of ``times``, asserted inside the tube; returns ``(t, X)``."""
    q = problem.plant.parameters
    corners = [np.array([lo, hi]) for lo, hi in zip(q.lower, q.upper, strict=True)]
    Qc = np.array(np.meshgrid(*corners, indexing="ij")).reshape(len(corners), -1).T
    dirs = np.vstack([np.eye(problem.plant.n), -np.eye(problem.plant.n)])
    rows = [(x0, tf, ell, qc) for x0 in X0 for tf in times for ell in dirs for qc in Qc]
    Xr = np.array([r[0] for r in rows])
    piece, W, Q = sensitivity_signals(problem, law, Xr, np.array([r[2] for r in rows]),
                                      np.array([r[1] for r in rows]),
                                      Q=np.array([r[3] for r in rows]), hold=result.hold)
    t, X, _, _ = simulate_many(problem, law, Xr, hold=result.hold, disturbance=(piece, W, Q))
    count, worst = _outside(result.tube, t, X)
    assert count == 0, f"{count} worst-case states outside the tube (worst {worst:g})"
    return t, X


def test_near_saturation_from_one_state_holds_the_worst_case_signals():
    # the runs under random and bang-bang signals stay well inside the tube (3-4.6x in w
    # on the full design); the first-order worst-case signals reach near its edges (1.5x
    # on the full design), so they test the tube where it is thinnest relative to the
    # reach set -- and each is a real run
    problem = _near_saturation(0.2, T=1.5, point=True)
    law = synthesize(problem)
    result = verify(problem, law, max_depth=0)
    assert result.verdict == "robustly_safe", result.summary()
    x0 = np.asarray(problem.verify.initial_lower, float)
    t, X = _worst_case_runs(problem, law, result, x0[None], (0.5, 1.0, 1.5))
    # they push w farther than 100 random and bang-bang runs do (at 1.5 s; measured 3.4x)
    P0, W0, Q0 = _signals(problem, 100, seed=7)
    t0, Xr, _, _ = simulate_many(problem, law, np.repeat(x0[None], 100, axis=0),
                                 hold=result.hold, disturbance=(P0, W0, Q0))
    span = np.ptp(X[:, int(np.argmin(np.abs(t - 1.5))), 1])
    assert span > 1.5 * np.ptp(Xr[:, int(np.argmin(np.abs(t0 - 1.5))), 1])


QUADRUPLE_TANK = Path(__file__).resolve().parent / "quadruple_tank.toml"


@pytest.mark.slow  # (the 60 s proof over pieces, in the default suite, covers it)
def test_quadruple_tank_tube_holds_every_run():
    # Johansson's quadruple tank (sqrt outflows) with an uncertain valve split and an
    # inflow disturbance: 4-D sets re-rooted at every sample; whatever the verdict, every
    # run under the verifier's signals and parameter corners lies in the tube (its ratio to
    # the hull: benchmarks/uncertain_tube.py)
    problem = loads_spec(QUADRUPLE_TANK.read_text())
    vs = problem.verify
    problem = replace(problem, verify=replace(vs, time_horizon=20.0))
    law = synthesize(problem)
    result = verify(problem, law, max_depth=0)
    assert result.verdict in ("robustly_safe", "unknown"), result.summary()
    _assert_sound(problem, law, result, P=100, seed=7)


def test_quadruple_tank_is_proved_on_its_whole_valve_box_and_its_tube_holds_every_run():
    # the remainder bounded per axis as well (a zonotope of the linear flow next to the
    # W-ball, docs/verification.md "The remainder per axis") keeps the thin h2, h3 thin:
    # the whole box of g1 proves the 60 s in one run (with the ball alone it failed its
    # enclosure at 34 s and needed eight pieces), and every simulated run lies in the tube
    problem = loads_spec(QUADRUPLE_TANK.read_text())
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.stats["parameter_pieces"] == 1
    assert float(result.tube.t_end.max()) == pytest.approx(60.0)
    _assert_sound(problem, law, result, P=100, seed=10)


def test_quadruple_tank_under_continuous_hold_halves_its_substeps_and_holds_every_run():
    # under the continuous hold (g1 in [0.67, 0.73], |d| <= 0.2) each 0.5 s step is cut in
    # two: the curvature term of the remainder squares the substep's a-priori deviation
    # (h2 at 60 s 2.08x -> 1.83x the worst-case runs' hull); one run, every run in the tube
    problem = loads_spec(QUADRUPLE_TANK.read_text())
    problem = replace(problem, verify=replace(problem.verify, hold="continuous"))
    law = synthesize(problem)
    result = verify(problem, law, hold="continuous")
    assert result.verdict == "robustly_safe", result.summary()
    assert result.stats["parameter_runs"] == 1
    tb = result.tube
    assert float(np.max(tb.t_end - tb.t_start)) == pytest.approx(0.25)
    assert float(tb.t_end.max()) == pytest.approx(60.0)
    _assert_sound(problem, law, result, P=100, seed=12)


def test_quadruple_tank_is_proved_over_pieces_of_the_valve_split():
    # a wider valve split, g1 in [0.62, 0.78]: the whole box fails its enclosure (the
    # bilinear g1 x v1 term of the remainder); on eighths of it, each about its own
    # midpoint, the proof holds over the 60 s horizon, and the pieces' tubes together hold
    # every run (g1 fixed per run: exact)
    text = QUADRUPLE_TANK.read_text().replace("g1 = [0.67, 0.73]", "g1 = [0.62, 0.78]")
    problem = loads_spec(text)
    law = synthesize(problem)
    seen = []
    result = verify(problem, law, progress=seen.append)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.stats["parameter_pieces"] > 1
    # progress over the pieces: counters that never go back, the run named
    branches = [d["branches"] for d in seen if "branches" in d]
    assert branches == sorted(branches)
    assert max(d.get("parameter_run", 1) for d in seen) == result.stats["parameter_runs"]
    assert float(result.tube.t_end.max()) == pytest.approx(60.0)
    _assert_sound(problem, law, result, P=100, seed=8)


def test_a_piece_of_the_parameter_box_is_a_problem_with_its_midpoint_as_nominal():
    from codev_engine.reach.parameter_split import split_axis, sub_problem

    problem = _pendulum(c=(0.4, 0.6))
    sub = sub_problem(problem, np.array([0.4]), np.array([0.45]))
    assert sub.plant.parameters.nominal == pytest.approx([0.425])
    assert sub.plant.parameters.upper == pytest.approx([0.45])
    assert problem.plant.parameters.upper == pytest.approx([0.6])  # (a new problem)
    assert split_axis(problem, np.array([0.4]), np.array([0.6])) == 0


def test_the_pieces_of_a_parameter_box_share_one_compiled_field():
    # the enclosures and second derivatives of f(x, u, w, p) are derived and compiled once
    # per field, not once per piece (each piece is a problem with its own box and nominal)
    from codev_engine.reach.enclosure import uncertain_enclosures
    from codev_engine.reach.parameter_split import sub_problem

    problem = _pendulum(c=(0.4, 0.6))
    a = uncertain_enclosures(sub_problem(problem, np.array([0.4]), np.array([0.5])))
    b = uncertain_enclosures(sub_problem(problem, np.array([0.5]), np.array([0.6])))
    assert a[0] is b[0] and a[1] is b[1]
    assert a[3][-1] == pytest.approx(0.5) and b[3][-1] == pytest.approx(0.6)  # (own boxes)
    assert b[4][-1] == pytest.approx(0.55)
    # another field compiles its own
    other = loads_spec((EXAMPLES / "pendulum.toml").read_text().replace(
        '"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - c*w + 2*T"').replace(
        "[model]", "parameters = { c = [0.4, 0.6] }\n\n[model]", 1))
    assert uncertain_enclosures(other)[0] is not a[0]


def test_the_split_parameter_is_the_one_whose_forcing_dominates():
    # -c*w with |w| <= 0.1 on the initial set against k*T with |T| <= 6: the gain's box,
    # though narrower, forces far more, so it is cut
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = text.replace('"9.81*sin(th) - 0.5*w + T"', '"9.81*sin(th) - c*w + k*T"')
    text = text.replace("[model]", "parameters = { c = [0.4, 0.6], k = [0.95, 1.05] }\n\n"
                        "[model]", 1)
    problem = loads_spec(text)
    from codev_engine.reach.parameter_split import split_axis

    pp = problem.plant.parameters
    assert pp.names == ("c", "k")
    assert split_axis(problem, pp.lower, pp.upper) == 1
    # on a piece where c's box is wide and k's a sliver, c is cut
    assert split_axis(problem, np.array([0.0, 1.0]), np.array([10.0, 1.0001])) == 0


@pytest.mark.slow
def test_quadruple_tank_under_continuous_hold_fails_its_enclosure_cleanly_then_splits():
    # the whole box's Picard candidate became NaN under the continuous hold (a ValueError
    # from the interval function, a traceback): now that substep fails like any enclosure,
    # the box is split, and the pieces prove the 60 s (the wider valve split: the reported
    # box now proves whole, with the remainder per axis)
    text = QUADRUPLE_TANK.read_text().replace("g1 = [0.67, 0.73]", "g1 = [0.62, 0.78]")
    problem = loads_spec(text)
    problem = replace(problem, verify=replace(problem.verify, hold="continuous"))
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.stats["parameter_runs"] > 1
    _assert_sound(problem, law, result, P=60, seed=9)
