"""The derived views of a design (workbench/design.py): plant report, MPC preview, regions."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from workbench.tui.design import (
    locate_state,
    mpc_preview,
    plant_report,
    preview_extras,
    region_rows,
    shared_laws,
)

ROOT = Path(__file__).resolve().parents[2]
PENDULUM = ROOT / "examples" / "pendulum.toml"
DI = ROOT / "examples" / "double_integrator.toml"


@pytest.fixture(scope="module")
def di(example_law):
    return example_law("double_integrator.toml")


# --------------------------------------------------------------------------------------------
# plant_report
# --------------------------------------------------------------------------------------------


def test_plant_report_pendulum():
    problem = ce.load_spec(PENDULUM)
    text, model = plant_report(problem)
    assert "9.81*cos(th)" in text
    assert "-0.5]" in text  # sympy floats shown short, not -0.500000000000000
    assert "0.500000000" not in text
    assert "controllability rank 2 of 2  (controllable)" in text
    assert "Linearisation at x = (th=0, w=0), u = (T=0)" in text
    assert "dt = 0.05 s" in text and "(zoh" in text
    assert "not asymptotically stable" in text  # upright pendulum
    assert "open loop not stable" in text
    assert "c =" not in text.splitlines()  # the upright position is an equilibrium
    assert "not an equilibrium" not in text
    # the model returned is the engine's discretisation
    ref = ce.discretize(problem)
    np.testing.assert_allclose(model.A, ref.A)
    np.testing.assert_allclose(model.B, ref.B)
    # and the matrices printed are those of the model
    a = _matrix_after(text, "A =")
    np.testing.assert_allclose(a, model.A, rtol=1e-5)
    ac = _matrix_after(text, "Ac =")
    np.testing.assert_allclose(ac, [[0.0, 1.0], [9.81, -0.5]])


def _matrix_after(text: str, label: str) -> np.ndarray:
    lines = text.splitlines()
    k = lines.index(label)
    rows = []
    for line in lines[k + 1 :]:
        m = re.fullmatch(r"\s*\[(.*)\]\s*", line)
        if not m:
            break
        rows.append([float(v) for v in m.group(1).split()])
    return np.array(rows)


def test_plant_report_off_equilibrium_operating_point_shows_c():
    text = PENDULUM.read_text(encoding="utf-8").replace(
        'method = "zoh"', 'method = "zoh"\noperating_point = { x = [0.1, 0.0], u = [0.5] }'
    )
    problem = ce.loads_spec(text, check_mpc=False)
    report, model = plant_report(problem)
    assert "Linearisation at x = (th=0.1, w=0), u = (T=0.5)" in report
    assert "c =" in report
    assert "(the operating point is not an equilibrium)" in report
    c = _matrix_after(report, "c =")
    np.testing.assert_allclose(c.ravel(), model.c, rtol=1e-5)
    assert np.all(model.c != 0)
    # Ac at th = 0.1: d/dth (9.81 sin th) = 9.81 cos(0.1)
    ac = _matrix_after(report, "Ac =")
    assert ac[1, 0] == pytest.approx(9.81 * np.cos(0.1), rel=1e-5)


def test_plant_report_uncontrollable_and_stable():
    head = DI.read_text(encoding="utf-8")
    head = head[: head.index("[verify]")]
    text = head.replace('dynamics = ["x2", "u"]', 'dynamics = ["-x1", "-2*x2 + u"]')
    problem = ce.loads_spec(text, check_mpc=False)
    report, _ = plant_report(problem)
    assert "controllability rank 1 of 2  (NOT controllable)" in report
    assert "eig(Ac) = -2, -1   (stable)" in report
    assert "  (stable)" in report.split("eig(A)")[1]


def test_plant_report_linear_plant():
    head = DI.read_text(encoding="utf-8")
    head = head[: head.index("[verify]")]
    text = head.replace(
        'dynamics = ["x2", "u"]', "A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]"
    )
    report, model = plant_report(ce.loads_spec(text))
    np.testing.assert_allclose(_matrix_after(report, "A ="), [[1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(_matrix_after(report, "B ="), [[0.5], [1.0]])
    assert "controllability rank 2 of 2" in report


# --------------------------------------------------------------------------------------------
# mpc_preview
# --------------------------------------------------------------------------------------------


def test_mpc_preview_double_integrator_converges():
    problem = ce.load_spec(DI)
    model = ce.discretize(problem)
    x0 = np.array([9.0, -5.0])
    prev = mpc_preview(problem, model, x0, 25)
    assert prev.infeasible_at is None
    assert prev.X.shape == (26, 2) and prev.U.shape == (25, 1) and prev.t.shape == (26,)
    np.testing.assert_allclose(prev.t, np.arange(26) * 1.0)
    np.testing.assert_array_equal(prev.X[0], x0)
    # within the bounds, and converging to the origin
    assert np.all(prev.U >= -1.0 - 1e-7) and np.all(prev.U <= 1.0 + 1e-7)
    assert np.all(np.abs(prev.X) <= 10.0 + 1e-6)
    norms = np.abs(prev.X).max(axis=1)
    assert norms[-1] < 1e-2 * norms[0]
    assert norms[-1] < 0.05
    # the loop is the prediction model x+ = A x + B u
    for k in range(25):
        want = model.A @ prev.X[k] + model.B @ prev.U[k]
        np.testing.assert_allclose(prev.X[k + 1], want, atol=1e-12)
    assert prev.seconds > 0


def test_mpc_preview_agrees_with_the_explicit_law(di):
    problem, law = di
    model = ce.discretize(problem)
    prev = mpc_preview(problem, model, np.array([9.0, -5.0]), 8)
    # the explicit law gives an optimal input too; same cost-to-go trend: both saturate at +1
    # from (9, -5) and bring the state into the law's domain
    assert prev.U[0, 0] == pytest.approx(float(law.evaluate(prev.X[:1])[0, 0]), abs=1e-6)
    assert (law.locate(prev.X) >= 0).all()


def test_mpc_preview_follows_the_reference_of_a_servo():
    """A law over θ = (x, u_prev, r): the preview holds the input it applied (the slew limit
    binds: |Δu| ≤ 0.5 per sample), follows the middle of [verify] reference by default or
    the r given, and starts from the middle of [verify] initial_input."""
    problem = ce.load_spec(ROOT / "examples" / "dc_motor_servo.toml")
    model = ce.discretize(problem)
    u_prev, r = preview_extras(problem)
    assert u_prev.tolist() == [0.0] and r.tolist() == [0.5]
    prev = mpc_preview(problem, model, np.zeros(2), 40)
    assert prev.infeasible_at is None and prev.reference.tolist() == [0.5]
    du = np.diff(np.r_[prev.u_prev0, prev.U[:, 0]])
    assert np.all(np.abs(du) <= 0.5 + 1e-6) and np.max(np.abs(du)) > 0.49
    assert prev.X[-1, 0] == pytest.approx(0.5, abs=1e-3)
    back = mpc_preview(problem, model, np.zeros(2), 60, reference=[-0.8])
    assert back.reference.tolist() == [-0.8] and back.X[-1, 0] == pytest.approx(-0.8, abs=1e-3)
    # regulation: nothing extra
    assert preview_extras(ce.load_spec(DI)) == (None, None)


def test_mpc_preview_infeasible_start():
    problem = ce.load_spec(DI)
    model = ce.discretize(problem)
    prev = mpc_preview(problem, model, np.array([30.0, -5.0]), 10)
    assert prev.infeasible_at == 0
    assert prev.X.shape == (1, 2) and prev.U.shape == (0, 1)
    np.testing.assert_array_equal(prev.X[0], [30.0, -5.0])


def test_mpc_preview_stops_when_asked():
    problem = ce.load_spec(DI)
    model = ce.discretize(problem)
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 3

    prev = mpc_preview(problem, model, np.array([9.0, -5.0]), 50, should_stop=stop)
    assert prev.infeasible_at is None
    assert prev.U.shape == (3, 1) and prev.X.shape == (4, 2)


def test_mpc_preview_off_equilibrium_model_uses_c():
    text = PENDULUM.read_text(encoding="utf-8").replace(
        'method = "zoh"', 'method = "zoh"\noperating_point = { x = [0.1, 0.0], u = [0.981] }'
    )
    problem = ce.loads_spec(text, check_mpc=False)
    model = ce.discretize(problem)
    prev = mpc_preview(problem, model, np.array([0.2, 0.0]), 5)
    for k in range(prev.U.shape[0]):
        want = (
            model.x_op
            + model.A @ (prev.X[k] - model.x_op)
            + model.B @ (prev.U[k] - model.u_op)
            + model.c
        )
        np.testing.assert_allclose(prev.X[k + 1], want, atol=1e-12)


# --------------------------------------------------------------------------------------------
# region_rows, locate_state
# --------------------------------------------------------------------------------------------

_TERM = re.compile(r"([+-][0-9.e+-]+)·(\w+)")


def test_region_rows_double_integrator(di):
    _, law = di
    rows = region_rows(law)
    assert len(rows) == law.num_regions == 10
    lo, hi = law.boxes
    for k, (idx, facets, text, box) in enumerate(rows):
        assert idx == str(k)
        assert facets == str(len(law.b[k])) and int(facets) >= 3
        # "u = F x + G" written with 4 significant digits
        coef = dict.fromkeys(law.states, 0.0)
        for value, name in _TERM.findall(text):
            coef[name] = float(value)
        const = float(text.split()[-1])
        np.testing.assert_allclose(
            [coef[s] for s in law.states], law.F[k][0], rtol=1e-3, atol=1e-12
        )
        assert const == pytest.approx(law.G[k][0], rel=1e-3, abs=1e-12)
        parts = re.findall(r"\[([^,\]]+), ([^\]]+)\]", box)
        assert len(parts) == 2
        for j, (a, b) in enumerate(parts):
            assert float(a) == pytest.approx(lo[k, j], rel=1e-2, abs=1e-9)
            assert float(b) == pytest.approx(hi[k, j], rel=1e-2, abs=1e-9)
    assert len(region_rows(law, limit=3)) == 3


def test_region_rows_drop_round_off_coefficients(di):
    """A saturated region's law reads +1, not -1.665e-16·x1 +6.661e-16·x2 +1 (issue 23), and
    regions whose laws are equal are counted for the merge hint."""
    _, law = di
    k = next(k for k in range(law.num_regions) if np.allclose(law.F[k], 0))
    F = np.array(law.F, dtype=float)
    F[k] = [[-1.665e-16, 6.661e-16]]
    noisy = replace(law, F=F)
    text = region_rows(noisy)[k][2]
    assert "e-16" not in text and "·" not in text, text
    assert text == f"{law.G[k][0]:+.4g}"
    # a small but real gain stays
    F[k] = [[-1e-3, 0.0]]
    assert "-0.001·x1" in region_rows(replace(law, F=F))[k][2]
    # the double integrator's saturated regions share u = +1 or u = -1
    assert shared_laws(law) >= 1


def test_region_rows_show_rounding_bounds_as_zero():
    """A box corner the LP puts at 5.55e-17 (a vertex at 0, rounded) reads 0; a small
    bound that is not rounding next to the partition's size keeps its value."""
    A = np.vstack([np.eye(2), -np.eye(2)])
    law = ce.ExplicitLaw(
        A=[A, A], b=[np.array([5.55e-17, 4.0, 10.0, 1.78e-15]), np.array([1e-6, 2, 1, 1])],
        F=np.zeros((2, 1, 2)), G=np.zeros((2, 1)),
    )
    lo = np.array([[-10.0, -1.78e-15], [-1.0, -1.0]])
    law._boxes = (lo, np.array([[5.55e-17, 4.0], [1e-6, 2]]))
    rows = region_rows(law)
    assert rows[0][3] == "[-10, 0] × [0, 4]"
    assert rows[1][3] == "[-1, 1e-06] × [-1, 2]"


def test_region_rows_zero_gain_region(di):
    # a saturated region (u = +-1) shows just the constant
    _, law = di
    k = next(i for i in range(law.num_regions) if not law.F[i].any())
    assert region_rows(law)[k][2] == f"{law.G[k][0]:+.4g}"


def test_locate_state(di):
    _, law = di
    k, u = locate_state(law, np.array([9.0, -5.0]))
    assert k >= 0 and k == int(law.locate(np.array([[9.0, -5.0]]))[0])
    np.testing.assert_allclose(u, law.evaluate(np.array([[9.0, -5.0]]))[0])
    assert u.shape == (1,)
    assert locate_state(law, [50.0, 50.0]) == (-1, None)
    with pytest.raises(ValueError):
        locate_state(law, [1.0, 2.0, 3.0])
