"""Tests of the plant functions (codev_engine.plant)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import sympy

from codev_engine.errors import SpecError
from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.plant import (
    LinearModel,
    SymbolicPlant,
    discretize,
    linearize,
    numeric_dynamics,
    symbolic_model,
)
from codev_engine.spec.choices import METHODS
from codev_engine.spec.expr import make_symbol
from codev_engine.spec.problem import PlantSpec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

PENDULUM = """\
name = "pendulum"

[plant]
states = ["th", "w"]
inputs = ["T"]
dynamics = ["w", "-9.81*sin(th) - 0.1*w + T"]

[model]
sample_time = 0.1
{op}

[mpc]
horizon = 3
norm = "2"
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[0.1]]
u_min = [-20.0]
u_max = [20.0]
"""


def pendulum(op: str = ""):
    return loads_spec(PENDULUM.format(op=op))


def zoh_reference(Ac, Bc, dt):
    """Exact ZOH by the block matrix exponential."""
    n, k = Bc.shape
    M = np.zeros((n + k, n + k))
    M[:n, :n], M[:n, n:] = Ac, Bc
    E = scipy.linalg.expm(M * dt)
    return E[:n, :n], E[:n, n:]


def test_double_integrator_zoh():
    p = load_spec(EXAMPLES / "double_integrator.toml")
    model = discretize(p)
    assert isinstance(model, LinearModel)
    np.testing.assert_allclose(model.A, [[1.0, 1.0], [0.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(model.B, [[0.5], [1.0]], atol=1e-12)
    np.testing.assert_array_equal(model.c, [0.0, 0.0])
    np.testing.assert_array_equal(model.Ac, [[0.0, 1.0], [0.0, 0.0]])
    np.testing.assert_array_equal(model.Bc, [[0.0], [1.0]])
    assert model.dt == 1.0 and (model.n, model.m) == (2, 1)
    np.testing.assert_array_equal(model.x_op, [0.0, 0.0])
    np.testing.assert_array_equal(model.u_op, [0.0])


@pytest.mark.parametrize(
    "fname", ["magnetic_pointer_a.toml", "navigation.toml", "cruise_control.toml"]
)
def test_matrix_plants_zoh(fname):
    p = load_spec(EXAMPLES / fname)
    model = discretize(p)
    np.testing.assert_array_equal(model.Ac, p.plant.A)
    np.testing.assert_array_equal(model.Bc, p.plant.B)
    Ad, Bd = zoh_reference(p.plant.A, p.plant.B, p.model.sample_time)
    np.testing.assert_allclose(model.A, Ad, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(model.B, Bd, rtol=1e-10, atol=1e-12)
    assert not model.c.any()


def test_magnetic_pointer_continuous_matrices_exact():
    p = load_spec(EXAMPLES / "magnetic_pointer_c.toml")
    Ac, Bc, f0 = linearize(p.plant, np.zeros(3), np.zeros(1))
    assert Ac.tolist() == [[2.6629, -1.1644, 0.66598], [2.0, 0.0, 0.0], [0.0, 0.5, 0.0]]
    assert Bc.tolist() == [[0.25], [0.0], [0.0]]
    assert f0.tolist() == [0.0, 0.0, 0.0]


def test_explicit_discrete_model_used_as_given():
    text = """\
name = "explicit"
[plant]
states = ["x1", "x2", "x3"]
inputs = ["u"]
[model]
sample_time = 1.0
operating_point = { x = [1.0, 2.0, 2.0], u = [0.5] }
A = [[2.6629, -1.1644, 0.66598], [2.0, 0.0, 0.0], [0.0, 0.5, 0.0]]
B = [[0.25], [0.0], [0.0]]
[mpc]
horizon = 2
norm = "inf"
Q = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
R = [[1]]
x_min = [-5, -5, -5]
x_max = [5, 5, 5]
u_min = [-40]
u_max = [40]
"""
    p = loads_spec(text)
    model = discretize(p)
    assert model.A.tolist() == [[2.6629, -1.1644, 0.66598], [2.0, 0.0, 0.0], [0.0, 0.5, 0.0]]
    assert model.B.tolist() == [[0.25], [0.0], [0.0]]
    assert model.c.tolist() == [0.0, 0.0, 0.0]
    assert model.Ac is None and model.Bc is None
    assert model.x_op.tolist() == [1.0, 2.0, 2.0] and model.u_op.tolist() == [0.5]
    with pytest.raises(SpecError):
        symbolic_model(p)


def test_pendulum_linearisation_at_zero():
    p = pendulum()
    Ac, Bc, f0 = linearize(p.plant, [0.0, 0.0], [0.0])
    np.testing.assert_allclose(Ac, [[0.0, 1.0], [-9.81, -0.1]], atol=1e-14)
    np.testing.assert_allclose(Bc, [[0.0], [1.0]], atol=1e-14)
    np.testing.assert_array_equal(f0, [0.0, 0.0])
    model = discretize(p)
    Ad, Bd = zoh_reference(Ac, Bc, 0.1)
    np.testing.assert_allclose(model.A, Ad, atol=1e-12)
    np.testing.assert_allclose(model.B, Bd, atol=1e-12)
    np.testing.assert_array_equal(model.c, [0.0, 0.0])


def test_pendulum_non_equilibrium_operating_point():
    p = pendulum("operating_point = { x = [0.5, 0.2], u = [1.0] }")
    model = discretize(p)
    th, w, T = 0.5, 0.2, 1.0
    Ac = np.array([[0.0, 1.0], [-9.81 * np.cos(th), -0.1]])
    Bc = np.array([[0.0], [1.0]])
    f0 = np.array([w, -9.81 * np.sin(th) - 0.1 * w + T])
    np.testing.assert_allclose(model.Ac, Ac, atol=1e-14)
    np.testing.assert_allclose(model.Bc, Bc, atol=1e-14)
    Ad, Bd = zoh_reference(Ac, np.hstack([Bc, f0[:, None]]), 0.1)
    np.testing.assert_allclose(model.A, Ad, atol=1e-12)
    np.testing.assert_allclose(model.B, Bd[:, :1], atol=1e-12)
    np.testing.assert_allclose(model.c, Bd[:, 1], atol=1e-12)
    assert np.linalg.norm(model.c) > 0.1
    np.testing.assert_array_equal(model.x_op, [0.5, 0.2])
    np.testing.assert_array_equal(model.u_op, [1.0])


def test_affine_term_matches_nonlinear_step():
    """For a short step the affine model predicts the nonlinear flow to second order."""
    p = pendulum("operating_point = { x = [0.5, 0.0], u = [0.0] }")
    model = discretize(p)
    f, _ = numeric_dynamics(p)
    x, dt, steps = np.array([0.5, 0.0]), 0.1, 1000
    for _ in range(steps):  # explicit midpoint integration of the nonlinear plant, u = u_op
        x = x + dt / steps * f(x + 0.5 * dt / steps * f(x, [0.0]), [0.0])
    np.testing.assert_allclose(x - model.x_op, model.c, atol=5e-3)


@pytest.mark.parametrize("method", METHODS)
def test_all_methods_run(method):
    p = loads_spec(
        PENDULUM.format(op="operating_point = { x = [0.5, 0.0], u = [0.0] }").replace(
            "sample_time = 0.1", f'sample_time = 0.1\nmethod = "{method}"'
        )
    )
    model = discretize(p)
    assert model.A.shape == (2, 2) and model.B.shape == (2, 1) and model.c.shape == (2,)
    assert np.all(np.isfinite(model.A)) and np.all(np.isfinite(model.c))
    assert model.c.any()


def test_tustin_double_integrator():
    p = load_spec(EXAMPLES / "double_integrator.toml")
    p2 = dataclasses.replace(p, model=dataclasses.replace(p.model, method="tustin"))
    model = discretize(p2)
    np.testing.assert_allclose(model.A, [[1.0, 1.0], [0.0, 1.0]], atol=1e-12)


def test_symbolic_model_dynamics():
    sym = symbolic_model(pendulum())
    assert isinstance(sym, SymbolicPlant)
    th, w, T = make_symbol("th"), make_symbol("w"), make_symbol("T")
    assert sym.x == (th, w) and sym.u == (T,)
    assert sym.f.shape == (2, 1) and sym.Jx.shape == (2, 2) and sym.Ju.shape == (2, 1)
    expected_Jx = sympy.Matrix([[0, 1], [-9.81 * sympy.cos(th), -0.1]])
    assert sympy.simplify(sym.Jx - expected_Jx) == sympy.zeros(2, 2)
    assert sym.Ju == sympy.Matrix([[0], [1]])


def test_symbolic_model_matrix_plant():
    p = load_spec(EXAMPLES / "navigation.toml")
    sym = symbolic_model(p.plant)  # a PlantSpec works too
    J = np.array(sym.Jx.tolist(), dtype=float)
    np.testing.assert_array_equal(J, p.plant.A)
    np.testing.assert_array_equal(np.array(sym.Ju.tolist(), dtype=float), p.plant.B)
    vals = {s: v for s, v in zip(sym.x + sym.u, [1, 2, 3, 4, 5, 6], strict=True)}
    got = np.array(sym.f.subs(vals).tolist(), dtype=float).ravel()
    np.testing.assert_allclose(got, p.plant.A @ [1, 2, 3, 4] + p.plant.B @ [5, 6])


def test_numeric_dynamics_pendulum():
    nd = numeric_dynamics(pendulum())
    f, jac_x = nd  # unpacks as a pair
    jac_u = nd.jac_u
    x, u = np.array([0.3, -0.4]), np.array([0.7])
    np.testing.assert_allclose(f(x, u), [-0.4, -9.81 * np.sin(0.3) + 0.04 + 0.7])
    np.testing.assert_allclose(jac_x(x, u), [[0.0, 1.0], [-9.81 * np.cos(0.3), -0.1]])
    np.testing.assert_allclose(jac_u(x, u), [[0.0], [1.0]])
    assert f(x, u).shape == (2,) and jac_x(x, u).shape == (2, 2) and jac_u(x, u).shape == (2, 1)
    # finite differences
    h = 1e-6
    fd = np.column_stack([(f(x + h * e, u) - f(x - h * e, u)) / (2 * h) for e in np.eye(2)])
    np.testing.assert_allclose(jac_x(x, u), fd, atol=1e-6)
    # vectorised
    rng = np.random.default_rng(0)
    X, U = rng.normal(size=(7, 2)), rng.normal(size=(7, 1))
    FX, JX, JU = f(X, U), jac_x(X, U), jac_u(X, U)
    assert FX.shape == (7, 2) and JX.shape == (7, 2, 2) and JU.shape == (7, 2, 1)
    for i in range(7):
        np.testing.assert_allclose(FX[i], f(X[i], U[i]))
        np.testing.assert_allclose(JX[i], jac_x(X[i], U[i]))
    np.testing.assert_allclose(f(X, u), f(X, np.repeat(u[None], 7, axis=0)))
    with pytest.raises(ValueError):
        f(np.zeros(3), u)


def test_numeric_dynamics_matrix_plant():
    p = load_spec(EXAMPLES / "navigation.toml")
    f, jac_x = numeric_dynamics(p)
    jac_u = numeric_dynamics(p).jac_u
    x, u = np.arange(4.0), np.array([1.0, -1.0])
    np.testing.assert_allclose(f(x, u), p.plant.A @ x + p.plant.B @ u)
    np.testing.assert_array_equal(jac_x(x, u), p.plant.A)
    np.testing.assert_array_equal(jac_u(x, u), p.plant.B)
    X, U = np.ones((5, 4)), np.ones((5, 2))
    assert f(X, U).shape == (5, 4) and jac_x(X, U).shape == (5, 4, 4)
    assert jac_u(X, U).shape == (5, 4, 2)


def test_numeric_dynamics_nonsmooth_functions():
    plant = PlantSpec(
        states=("a", "b"),
        inputs=("u",),
        dynamics=("abs(a) + sign(b) + max(a, u, 0)", "min(a, b) + atan2(b, 1) + sqrt(4 + a**2)"),
    )
    f, jac_x = numeric_dynamics(plant)
    x, u = np.array([-1.0, 2.0]), np.array([0.5])
    np.testing.assert_allclose(f(x, u), [1 + 1 + 0.5, -1 + np.arctan2(2, 1) + np.sqrt(5)])
    J = jac_x(x, u)
    np.testing.assert_allclose(J, [[-1.0, 0.0], [1.0 - 1 / np.sqrt(5), 1 / 5]], atol=1e-12)


def test_constant_dynamics_vectorise():
    plant = PlantSpec(states=("a",), inputs=("u",), dynamics=("1.5",))
    f, jac_x = numeric_dynamics(plant)
    assert f(np.zeros((4, 1)), np.zeros((4, 1))).tolist() == [[1.5]] * 4
    assert jac_x(np.zeros((4, 1)), np.zeros((4, 1))).shape == (4, 1, 1)
