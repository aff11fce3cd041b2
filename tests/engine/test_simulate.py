"""Closed-loop simulation (codev_engine.simulate) against closed forms and against itself.

* zoh on the (linear) double integrator: the states at the sample times follow the
  discretised model ``x_{k+1} = A x_k + B u_k`` exactly;
* continuous hold: inside a period the loop is the linear ODE ``dx = (Ac + Bc F_i) x + Bc G_i``,
  whose solution is a matrix exponential;
* the vectorised RK4 (``simulate_many``) agrees with the DOP853 reference (``simulate``) on
  the nonlinear examples;
* every kind of violation is found where it is known to happen, and nothing is found where
  nothing happens.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from scipy.optimize import brentq

import codev_engine as ce
from codev_engine.reach.simulate import (
    ManyTraces,
    Trace,
    Violation,
    first_violation,
    simulate,
    simulate_many,
    violations_many,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DI_PATH = EXAMPLES / "double_integrator.toml"


@pytest.fixture(scope="module")
def di():
    p = ce.load_spec(DI_PATH)
    return p, ce.synthesize(p)


def _di_text(**repl: str) -> str:
    text = DI_PATH.read_text()
    for old, new in repl.items():
        assert old in text
        text = text.replace(old, new)
    return text


def _expm_step(Ac, Bc, F, G, x, t):
    """Solution at time t of dx/dt = Ac x + Bc (F x + G) from x (the continuous hold)."""
    n = Ac.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = Ac + Bc @ F
    M[:n, n] = Bc @ G
    return (scipy.linalg.expm(M * t) @ np.append(x, 1.0))[:n]


def _box_points(problem, k: int, seed: int = 0) -> np.ndarray:
    v = problem.verify
    lo, hi = v.initial_lower, v.initial_upper
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))))
    rng = np.random.default_rng(seed)
    return np.vstack([corners, (lo + hi) / 2, lo + rng.random((k, lo.size)) * (hi - lo)])


# ---------------------------------------------------------------------------------------
# closed forms on the double integrator
# ---------------------------------------------------------------------------------------


def test_zoh_follows_the_discrete_model(di):
    p, law = di
    model = ce.discretize(p)
    for x0 in ([9.0, -5.0], [-3.0, 2.5]):
        tr = simulate(p, law, x0, hold="zoh")
        assert isinstance(tr, Trace) and tr.hold == "zoh" and tr.undefined_at is None
        assert np.all(np.diff(tr.t) > 0) and tr.t[0] == 0.0 and tr.t[-1] == pytest.approx(9.0)
        np.testing.assert_array_equal(tr.x0, x0)
        ks = [int(np.flatnonzero(np.isclose(tr.t, k))[0]) for k in range(10)]
        for a, b in itertools.pairwise(ks):
            xk, uk = tr.x[a], tr.u[a]
            np.testing.assert_allclose(uk, law.evaluate(xk)[0], atol=1e-12)
            assert tr.region[a] == law.locate(xk)[0]
            np.testing.assert_allclose(tr.x[b], model.A @ xk + model.B @ uk, atol=1e-9)
            # zoh: the input is constant over the period
            np.testing.assert_array_equal(tr.u[a:b], np.broadcast_to(uk, tr.u[a:b].shape))


def test_continuous_hold_follows_the_matrix_exponential(di):
    p, law = di
    Ac, Bc = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])
    tr = simulate(p, law, [9.0, -5.0], hold="continuous")
    assert tr.hold == "continuous"
    for k in range(9):
        a = int(np.flatnonzero(np.isclose(tr.t, k))[0])
        i = tr.region[a]
        assert i == law.locate(tr.x[a])[0]
        F, G = law.F[i], law.G[i]
        for j in np.flatnonzero((tr.t > k) & (tr.t <= k + 1))[::37]:
            expect = _expm_step(Ac, Bc, F, G, tr.x[a], tr.t[j] - k)
            np.testing.assert_allclose(tr.x[j], expect, atol=1e-9)
            if tr.t[j] < k + 1 - 1e-9:  # inside the period: u = F x(t) + G, same region
                assert tr.region[j] == i
                np.testing.assert_allclose(tr.u[j], F @ tr.x[j] + G, atol=1e-12)
    # the two holds differ once the law leaves saturation (t > 6 from this state)
    z = simulate(p, law, [9.0, -5.0], hold="zoh")
    assert np.abs(z.x[-1] - tr.x[-1]).max() > 1e-2


def test_default_settings_come_from_the_spec(di):
    p, law = di
    tr = simulate(p, law, [9.0, -5.0], t_end=1.0)
    assert tr.hold == p.verify.hold == "continuous"
    assert np.diff(tr.t).max() == pytest.approx(p.verify.step / 4)
    with pytest.raises(ValueError, match="hold"):
        simulate(p, law, [9.0, -5.0], hold="foh")
    with pytest.raises(ValueError, match="x0"):
        simulate(p, law, [9.0, -5.0, 1.0])


# ---------------------------------------------------------------------------------------
# simulate_many against simulate
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "holds", "t_end"),
    [("vanderpol", ("zoh", "continuous"), 2.0), ("pendulum", ("zoh", "continuous"), 1.5)],
)
def test_simulate_many_agrees_with_simulate(name, holds, t_end):
    p = ce.load_spec(EXAMPLES / f"{name}.toml")
    law = ce.synthesize(p)
    X0 = _box_points(p, 0)[[0, -1]]  # two corners of the initial box
    for hold in holds:
        many = simulate_many(p, law, X0, hold=hold, t_end=t_end)
        assert isinstance(many, ManyTraces)
        t, X, U, alive = many
        assert alive.all()
        Ts = p.model.sample_time
        assert Ts / many.h == pytest.approx(round(Ts / many.h))  # the step divides Ts
        # each interior sample time appears twice (end of one period, start of the next)
        n_samples = int(round(t_end / Ts))
        ts, counts = np.unique(np.round(t, 9), return_counts=True)
        assert set(ts[counts == 2]) == {round(k * Ts, 9) for k in range(1, n_samples + 1)}
        for p_i, x0 in enumerate(X0):
            tr = simulate(p, law, x0, hold=hold, t_end=t_end)
            # compare on the common times (the last entry of a duplicated sample time: the
            # new period's input, as in Trace)
            common = 0
            for j, tj in enumerate(tr.t):
                hit = np.flatnonzero(np.abs(t - tj) < 1e-9)
                if hit.size == 0:
                    continue
                common += 1
                np.testing.assert_allclose(X[p_i, hit[-1]], tr.x[j], atol=1e-6)
                np.testing.assert_allclose(U[p_i, hit[-1]], tr.u[j], atol=1e-6)
            assert common >= t_end / 0.01


# ---------------------------------------------------------------------------------------
# violations
# ---------------------------------------------------------------------------------------


def test_unsafe_set_across_the_nominal_trajectory(di):
    _, law = di
    # the nominal trajectory from (9, -5) passes (1, -3) at t = 2
    text = _di_text(
        **{
            "[[verify.safe]]": "[[verify.unsafe]]\nlower = [-9.0, 5.0]\nupper = [-8.0, 6.0]\n\n"
            "[[verify.unsafe]]\nlower = [0.5, -3.5]\nupper = [1.5, -2.5]\n\n[[verify.safe]]"
        }
    )
    p = ce.loads_spec(text)
    assert len(p.verify.unsafe) == 2
    tr = simulate(p, law, [9.0, -5.0])
    v = first_violation(p, law, tr)
    assert isinstance(v, Violation)
    assert (v.kind, v.index) == ("unsafe", 1)
    box_lo, box_hi = np.array([0.5, -3.5]), np.array([1.5, -2.5])
    assert np.all(v.x >= box_lo) and np.all(v.x <= box_hi)
    j = int(np.flatnonzero(tr.t == v.t)[0])
    assert not np.all((tr.x[j - 1] >= box_lo) & (tr.x[j - 1] <= box_hi))  # the first one
    assert 1.5 < v.t < 2.0
    # the same with the vectorised path
    bad, t_first = violations_many(p, *simulate_many(p, law, [[9.0, -5.0], [-3.0, 2.5]]))
    assert bad.tolist() == [True, False]
    assert t_first[0] == pytest.approx(v.t, abs=0.01) and t_first[1] == np.inf
    # touching counts: the quadrant x <= x_touch (componentwise), where x_touch is a state of
    # the trajectory; x1 decreases and x2 increases there, so only that state is in it
    x_touch = tr.x[j + 5]
    touch = _di_text(
        **{
            "[[verify.safe]]": "[[verify.unsafe]]\nlower = [-inf, -inf]\n"
            f"upper = [{float(x_touch[0])!r}, {float(x_touch[1])!r}]\n\n[[verify.safe]]"
        }
    )
    pt = ce.loads_spec(touch)
    v2 = first_violation(pt, law, tr)
    assert v2 is not None and (v2.kind, v2.index) == ("unsafe", 0) and v2.t == tr.t[j + 5]
    np.testing.assert_array_equal(v2.x, x_touch)


def test_paper_double_integrator_continuous_is_clean(di):
    p, law = di
    assert p.verify.hold == "continuous" and p.verify.input_bounds
    tr = simulate(p, law, [9.0, -5.0])
    assert tr.undefined_at is None
    assert first_violation(p, law, tr) is None
    X0 = _box_points(p, 60)
    bad, t_first = violations_many(p, *simulate_many(p, law, X0))
    assert not bad.any() and np.all(np.isinf(t_first))


def test_undefined_at_the_initial_state(di):
    p, law = di
    x0 = np.array([9.9, 9.9])  # inside the state bounds, outside the MPC's feasible set
    assert law.locate(x0)[0] == -1
    tr = simulate(p, law, x0)
    assert tr.undefined_at == 0.0 and tr.t.tolist() == [0.0] and tr.region.tolist() == [-1]
    assert np.isnan(tr.u).all()
    v = first_violation(p, law, tr)
    assert v is not None and (v.kind, v.index, v.t) == ("undefined", -1, 0.0)
    np.testing.assert_array_equal(v.x, x0)
    t, X, U, alive = simulate_many(p, law, [x0, [9.0, -5.0]])
    assert not alive[0].any() and alive[1].all()
    assert np.isnan(X[0, 1:]).all() and np.isnan(U[0]).all()
    bad, t_first = violations_many(p, t, X, U, alive)
    assert bad.tolist() == [True, False] and t_first[0] == 0.0


def test_undefined_in_the_middle_of_a_trajectory():
    # The MPC's model is the double integrator, the plant has an extra destabilising term:
    # the closed loop leaves the MPC's feasible set at t = 3.
    text = _di_text(
        **{
            'dynamics = ["x2", "u"]': 'dynamics = ["x2", "u + 0.6*x2"]',
            'method = "zoh"': "A = [[1.0, 1.0], [0.0, 1.0]]\nB = [[0.5], [1.0]]",
        }
    )
    p = ce.loads_spec(text)
    law = ce.synthesize(p)
    tr = simulate(p, law, [5.0, -2.0], hold="zoh")
    assert tr.undefined_at == 3.0 and tr.t[-1] == 3.0 and tr.region[-1] == -1
    assert np.all(tr.region[:-1] >= 0)
    assert law.locate(tr.x[-1])[0] == -1
    v = first_violation(p, law, tr)
    assert v is not None and v.kind == "undefined" and v.t == 3.0
    t, X, U, alive = simulate_many(p, law, [[5.0, -2.0]], hold="zoh")
    stop = int(np.argmin(alive[0]))
    assert t[stop] == 3.0 and not alive[0, stop:].any() and alive[0, :stop].all()
    np.testing.assert_allclose(X[0, stop], tr.x[-1], atol=1e-6)
    bad, t_first = violations_many(p, t, X, U, alive)
    assert bad[0] and t_first[0] == 3.0


def test_input_bounds_between_samples_with_the_continuous_hold(di):
    _, law = di
    p = ce.loads_spec(_di_text())  # hold "continuous", input_bounds = true
    x0 = np.array([9.5, -3.9])
    i = law.locate(x0)[0]
    F, G = law.F[i], law.G[i]
    assert abs(F @ x0 + G)[0] < 0.9  # well inside the bounds at the sample
    Ac, Bc = np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])

    def excess(s):
        return abs(F @ _expm_step(Ac, Bc, F, G, x0, s) + G)[0] - 1.0

    t_cross = brentq(excess, 0.0, 0.6)  # |u(t)| reaches 1 inside the first period
    assert excess(1.0) > 0

    tr = simulate(p, law, x0, t_end=1.0)
    v = first_violation(p, law, tr)
    assert v is not None and (v.kind, v.index) == ("input_bounds", 0)
    assert t_cross < v.t <= t_cross + 0.0025 + 1e-9
    # on a grid of sample times only, the left limit of the period's input catches it
    coarse = simulate(p, law, x0, t_end=1.0, dt=1.0)
    assert coarse.t.tolist() == [0.0, 1.0]
    assert abs(coarse.u[-1, 0]) <= 1.0 + 1e-9  # the new period's input is fine ...
    v = first_violation(p, law, coarse)
    assert v is not None and v.kind == "input_bounds" and v.t == 1.0  # ... the old one not
    # the digital controller holds F x0 + G: no input violation
    z = simulate(p, law, x0, t_end=1.0, hold="zoh")
    assert first_violation(p, law, z) is None
    # vectorised: the same verdicts
    bad_c, t_c = violations_many(p, *simulate_many(p, law, [x0], t_end=1.0))
    bad_z, _ = violations_many(p, *simulate_many(p, law, [x0], t_end=1.0, hold="zoh"))
    assert bad_c[0] and t_cross < t_c[0] <= t_cross + 0.0025 + 1e-9 and not bad_z[0]
    # on the output grid of simulate_many (sample times only), the left-limit entry
    t, X, U, alive = simulate_many(p, law, [x0], t_end=1.0, dt_out=1.0)
    assert t.tolist() == [0.0, 1.0, 1.0]
    assert abs(U[0, 1, 0]) > 1.0 and abs(U[0, 2, 0]) <= 1.0 + 1e-9
    assert violations_many(p, t, X, U, alive)[0][0]


# ---------------------------------------------------------------------------------------
# the nonlinear examples
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["pendulum", "tora", "vanderpol"])
def test_nonlinear_example_is_safe_in_simulation(name):
    p = ce.load_spec(EXAMPLES / f"{name}.toml")
    assert p.plant.dynamics is not None and p.verify is not None
    law = ce.synthesize(p)
    X0 = _box_points(p, 10)
    assert np.all(law.locate(X0) >= 0)
    t, X, U, alive = simulate_many(p, law, X0)
    assert alive.all()  # every sampled state stays in the law's domain
    bad, _ = violations_many(p, t, X, U, alive)
    assert not bad.any()
    tr = simulate(p, law, X0[len(X0) - 11])  # the centre of the initial set
    assert first_violation(p, law, tr) is None


def test_tora_continuous_hold_breaks_the_input_bound():
    """As its header says: with u = F_i x(t) + G_i between samples, |u| exceeds 0.7."""
    p = ce.load_spec(EXAMPLES / "tora.toml")
    law = ce.synthesize(p)
    x0 = 0.5 * (p.verify.initial_lower + p.verify.initial_upper)
    tr = simulate(p, law, x0, hold="continuous", t_end=2.0)
    v = first_violation(p, law, tr)
    assert v is not None and (v.kind, v.index) == ("input_bounds", 0) and 0.0 < v.t < 1.0
    assert first_violation(p, law, simulate(p, law, x0, hold="zoh", t_end=2.0)) is None
