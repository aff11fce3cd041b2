"""The plant's model (codev_engine.plant.plant_model): derived once per plant and shared."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import sympy

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.plant import (
    clear_plant_models,
    linearize,
    model_derivations,
    numeric_dynamics,
    plant_model,
    symbolic_model,
)
from codev_engine.reach.enclosure import plant_enclosures, plant_hessian
from codev_engine.reach.simulate import simulate, simulate_many
from codev_engine.spec.problem import PlantSpec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def lambdify_calls(monkeypatch):
    """Counts the numeric compilations (``sympy.lambdify``) made while the test runs."""
    calls = []
    real = sympy.lambdify

    def counting(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(sympy, "lambdify", counting)
    return calls


def _walk(name: str, law=None):
    """load_spec -> synthesize (unless ``law`` is given) -> verify -> simulate."""
    problem = ce.load_spec(EXAMPLES / f"{name}.toml")
    law = ce.synthesize(problem) if law is None else law
    result = ce.verify(problem, law)
    x0 = 0.5 * (problem.verify.initial_lower + problem.verify.initial_upper)
    simulate(problem, law, x0)
    simulate_many(problem, law, x0[None])
    return problem, law, result


@pytest.mark.parametrize(
    ("name", "verdict"),
    [
        ("pendulum", "robustly_safe"),  # nonlinear: the nonlinear reach engine
        ("double_integrator", "robustly_safe"),  # linear dynamics expressions
        ("navigation", "unsafe"),  # matrix plant; counterexample search simulates
    ],
)
def test_a_walk_derives_the_model_once(name, verdict, lambdify_calls):
    clear_plant_models()
    before = model_derivations()
    problem, law, result = _walk(name)
    assert result.verdict == verdict
    assert model_derivations() == before + 1
    compiled = len(lambdify_calls)
    # f, jac_x, jac_u, the simulator's f and the centre trajectory's f at most, once each
    assert compiled <= 5
    # a second walk (a new Problem of the same spec) derives and compiles nothing
    problem2, _, result2 = _walk(name, law)
    assert problem2 is not problem
    assert model_derivations() == before + 1
    assert len(lambdify_calls) == compiled
    assert result2.verdict == verdict
    np.testing.assert_array_equal(result2.tube.lower, result.tube.lower)
    np.testing.assert_array_equal(result2.tube.upper, result.tube.upper)


def test_every_user_takes_the_same_model():
    problem = ce.load_spec(EXAMPLES / "pendulum.toml")
    model = plant_model(problem)
    assert plant_model(problem.plant) is model
    assert symbolic_model(problem) is model.sym
    assert numeric_dynamics(problem) is model.numeric
    assert plant_enclosures(problem) is plant_enclosures(problem.plant)
    assert plant_enclosures(problem).sym is model.sym
    assert plant_hessian(problem) is plant_hessian(problem.plant)


def test_plants_are_keyed_by_value():
    a = PlantSpec(("p", "q"), ("u",), A=np.array([[0.0, 1.0], [0.0, 0.0]]),
                  B=np.array([[0.0], [1.0]]))
    same = dataclasses.replace(a, A=a.A.copy(), B=a.B.copy())
    other = dataclasses.replace(a, A=np.array([[0.0, 1.0], [-1.0, 0.0]]))
    renamed = dataclasses.replace(a, states=("p", "r"))
    assert plant_model(same) is plant_model(a)
    assert plant_model(other) is not plant_model(a)
    assert plant_model(renamed) is not plant_model(a)
    Ac, _, _ = linearize(other, np.zeros(2), np.zeros(1))
    np.testing.assert_array_equal(Ac, other.A)
    nd = numeric_dynamics(other)
    np.testing.assert_array_equal(nd.jac_x(np.zeros(2), np.zeros(1)), other.A)
    d1 = PlantSpec(("x",), ("u",), dynamics=("-x + u",))
    d2 = PlantSpec(("x",), ("u",), dynamics=("-2*x + u",))
    assert plant_model(d1) is plant_model(dataclasses.replace(d1, dynamics=("-x + u",)))
    assert plant_model(d2) is not plant_model(d1)
    assert numeric_dynamics(d2).f(np.ones(1), np.zeros(1)).tolist() == [-2.0]


def test_the_cache_is_bounded_and_can_be_cleared():
    clear_plant_models()
    before = model_derivations()
    plants = [PlantSpec(("x",), ("u",), dynamics=(f"-{k}*x + u",)) for k in range(1, 20)]
    first = plant_model(plants[0])
    for p in plants[1:]:
        plant_model(p)
    assert model_derivations() == before + len(plants)
    again = plant_model(plants[0])  # evicted (least recently used): derived again
    assert again is not first and model_derivations() == before + len(plants) + 1
    assert plant_model(plants[-1]) is plant_model(plants[-1])
    assert model_derivations() == before + len(plants) + 1
    clear_plant_models()
    plant_model(plants[-1])
    assert model_derivations() == before + len(plants) + 2


def test_a_bad_plant_is_not_cached():
    bad = PlantSpec(("x",), ("u",))  # no continuous-time dynamics
    before = model_derivations()
    for _ in range(2):
        with pytest.raises(SpecError, match="no continuous-time plant"):
            plant_model(bad)
    assert model_derivations() == before + 2  # tried again: errors are not remembered
