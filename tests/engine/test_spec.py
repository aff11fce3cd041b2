"""Tests of the spec loader (codev_engine.spec)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from codev_engine.errors import SpecError
from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.spec.choices import METHODS
from codev_engine.spec.problem import MpcSpec, Problem, SetSpec, VerifySpec

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

BASE = """\
name = "base"

[plant]
states = ["x1", "x2"]
inputs = ["u"]
dynamics = ["x2", "u"]

[model]
sample_time = 1.0
method = "zoh"

[mpc]
horizon = 2
norm = "inf"
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[0.8]]
x_min = [-10.0, -10.0]
x_max = [10.0, 10.0]
u_min = [-1.0]
u_max = [1.0]

[verify]
time_horizon = 3.0
step = 0.01
initial_set = { lower = [0.9, -0.1], upper = [1.1, 0.1] }

[[verify.unsafe]]
lower = [-inf, 5.0]
upper = [inf, inf]

[[verify.unsafe]]
A = [[1.0, 1.0]]
b = [-20.0]

[[verify.safe]]
lower = [-10.0, -10.0]
upper = [10.0, 10.0]
"""


def edit(*pairs: tuple[str, str], text: str = BASE) -> str:
    """Apply exact replacements; each ``old`` must occur exactly once."""
    for old, new in pairs:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


def write(tmp_path: Path, text: str, name: str = "bad_spec.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def load_error(tmp_path: Path, text: str) -> SpecError:
    path = write(tmp_path, text)
    with pytest.raises(SpecError) as info:
        load_spec(path)
    err = info.value
    assert err.file == str(path)
    assert "bad_spec.toml" in str(err)
    return err


# --- good specs -----------------------------------------------------------------------------

EXPECTED = {
    # file: (name, n, m, horizon, Q rows, n unsafe, n safe, hold)
    "double_integrator.toml": ("double-integrator", 2, 1, 2, 2, 0, 1, "continuous"),
    "navigation.toml": ("navigation", 4, 2, 2, 4, 3, 0, "continuous"),
    "cruise_control.toml": ("cruise-control", 1, 1, 10, 1, 2, 0, "continuous"),
    "magnetic_pointer_a.toml": ("magnetic-pointer-a", 3, 1, 4, 3, 0, 1, "continuous"),
    "magnetic_pointer_b.toml": ("magnetic-pointer-b", 3, 1, 4, 3, 0, 1, "continuous"),
    "magnetic_pointer_c.toml": ("magnetic-pointer-c", 3, 1, 2, 3, 0, 1, "continuous"),
}


#: examples added since the paper: nonlinear plants (``dynamics`` only, linearised at the
#: origin unless an operating point is given), digital controllers (hold "zoh"), input
#: bounds checked, terminal weights P
NONLINEAR = {
    "pendulum.toml": dict(
        name="pendulum", states=("th", "w"), inputs=("T",),
        dynamics=("w", "9.81*sin(th) - 0.5*w + T"), sample_time=0.05, horizon=8, norm="2",
        Q=[[10.0, 0.0], [0.0, 1.0]], R=[[0.1]], P=[[228.6, 47.8], [47.8, 14.8]],
        x_min=[-1.0, -5.0], x_max=[1.0, 5.0], u_min=[-6.0], u_max=[6.0], domain_bound=100.0,
        time_horizon=3.0, initial=([0.55, -0.1], [0.6, 0.0]),
        unsafe=[("box", [0.7, -np.inf], [np.inf, np.inf]), ("polytope", [[1.0, 0.5]], [-0.15])],
        safe=[],
    ),
    "tora.toml": dict(
        name="tora", states=("x1", "x2", "x3", "x4"), inputs=("u",),
        dynamics=("x2", "-x1 + 0.1*sin(x3)", "x4", "u"), sample_time=0.5, horizon=3, norm="2",
        Q=np.diag([1.0, 1.0, 0.1, 0.1]).tolist(), R=[[1.0]],
        P=[[34.969, -0.5, -3.93, -2.52], [-0.5, 33.139, 1.061, -1.424],
           [-3.93, 1.061, 1.116, 0.92], [-2.52, -1.424, 0.92, 2.084]],
        x_min=[-np.inf, -np.inf, -2.0, -2.0], x_max=[np.inf, np.inf, 2.0, 2.0],
        u_min=[-0.65], u_max=[0.65], domain_bound=2.5,
        time_horizon=10.0, initial=([0.6, -0.7, -0.4, 0.5], [0.63, -0.67, -0.37, 0.53]),
        unsafe=[], safe=[("box", [-2.0] * 4, [2.0] * 4)],
    ),
    "cstr.toml": dict(
        name="cstr", states=("CA", "T"), inputs=("Tc",),
        dynamics=("(1.0 - CA) - 7.2e10*exp(-8750/T)*CA",
                  "(350.0 - T) + 209.2050209*7.2e10*exp(-8750/T)*CA + 2.092050209*(Tc - T)"),
        sample_time=0.05, horizon=5, norm="2",
        Q=[[100.0, 0.0], [0.0, 1.0]], R=[[0.1]], P=[[5550.0, 99.37], [99.37, 5.704]],
        x_min=[0.0, 320.0], x_max=[1.0, 380.0], u_min=[280.0], u_max=[320.0],
        domain_bound=100.0, x_op=[0.5, 350.0], u_op=[300.0],
        time_horizon=3.0, initial=([0.52, 351.0], [0.56, 354.0]),
        unsafe=[("box", [-np.inf, 365.0], [np.inf, np.inf])],
        safe=[("box", [0.0, 320.0], [1.0, 380.0])],
    ),
    "vanderpol.toml": dict(
        name="vanderpol", states=("x1", "x2"), inputs=("u",),
        dynamics=("x2", "(1 - x1**2)*x2 - x1 + u"), sample_time=0.1, horizon=5, norm="inf",
        Q=[[1.0, 0.0], [0.0, 1.0]], R=[[0.5]], P=[[10.0, 0.0], [0.0, 10.0]],
        x_min=[-3.0, -4.0], x_max=[3.0, 4.0], u_min=[-2.0], u_max=[2.0], domain_bound=100.0,
        time_horizon=6.0, initial=([-1.55, 1.2], [-1.5, 1.25]),
        unsafe=[("box", [-np.inf, 1.6], [np.inf, np.inf]),
                ("box", [0.3, -np.inf], [np.inf, np.inf])],
        safe=[("box", [-3.0, -4.0], [3.0, 4.0])],
    ),
}


#: examples of the formulations of docs/spec.md (terminal ingredients, soft outputs, mixed
#: constraints and move blocking): file -> (name, fields that must be set as given)
FORMULATIONS = {
    "double_integrator_lqr.toml": ("double-integrator-lqr",
                                   dict(terminal_cost="lqr", terminal_set="lqr", P=None)),
    "mass_spring_soft.toml": ("mass-spring-soft", dict(soft=("y_max",), soft_weight=1000.0)),
    "two_carts_mixed.toml": ("two-carts-mixed", dict(control_horizon=2)),
    "dc_motor_servo.toml": ("dc-motor-servo", dict(has_rates=True, free_reference=True)),
}


#: examples with bounded disturbances / uncertain parameters: file -> (name, disturbance
#: names, their intervals)
UNCERTAIN = {
    "cruise_grade.toml": ("cruise-grade", ("w",), [[-98.1, 98.1]]),
    "cruise_loaded.toml": ("cruise-loaded", ("w",), [[-107.9, 107.9]]),
}


@pytest.mark.parametrize("fname", sorted(UNCERTAIN))
def test_uncertain_examples_load(fname):
    name, names, boxes = UNCERTAIN[fname]
    p = load_spec(EXAMPLES / fname)
    assert p.name == name
    w = p.plant.disturbances
    assert w is not None and w.names == names
    np.testing.assert_array_equal(np.stack([w.lower, w.upper], 1), boxes)
    np.testing.assert_array_equal(w.nominal, np.zeros(len(names)))


def test_all_examples_are_listed():
    assert not set(EXPECTED) & set(NONLINEAR)
    listed = {**EXPECTED, **NONLINEAR, **FORMULATIONS, **UNCERTAIN}
    assert sorted(p.name for p in EXAMPLES.glob("*.toml")) == sorted(listed)
    assert len(EXPECTED) == 6  # the paper's examples, all still there


@pytest.mark.parametrize("fname", sorted(FORMULATIONS))
def test_formulation_examples_load(fname):
    name, fields = FORMULATIONS[fname]
    p = load_spec(EXAMPLES / fname)
    assert p.name == name
    for key, value in fields.items():
        assert getattr(p.mpc, key) == value, key
    assert p.verify is not None and p.verify.hold == "zoh"


@pytest.mark.parametrize("fname", sorted(EXPECTED))
def test_examples_load(fname):
    name, n, m, N, q, n_unsafe, n_safe, hold = EXPECTED[fname]
    path = EXAMPLES / fname
    p = load_spec(path)
    assert isinstance(p, Problem)
    assert p.name == name
    assert p.path == str(path)
    assert p.source == path.read_text()
    assert (p.plant.n, p.plant.m) == (n, m)
    assert p.mpc.horizon == N
    assert p.mpc.norm == "inf"
    assert p.mpc.Q.shape == (q, n)
    assert p.mpc.R.shape == (m, m)
    assert p.mpc.P is None
    for v, k in ((p.mpc.x_min, n), (p.mpc.x_max, n), (p.mpc.u_min, m), (p.mpc.u_max, m)):
        assert v.shape == (k,) and v.dtype == float
    assert p.model.x_op.shape == (n,) and not p.model.x_op.any()
    assert p.model.u_op.shape == (m,) and not p.model.u_op.any()
    assert p.model.A is None
    v = p.verify
    assert isinstance(v, VerifySpec)
    assert v.initial_lower.shape == v.initial_upper.shape == (n,)
    assert np.all(v.initial_lower <= v.initial_upper)
    assert (len(v.unsafe), len(v.safe), v.hold) == (n_unsafe, n_safe, hold)
    for s in (*v.unsafe, *v.safe):
        assert s.kind == "box" and s.lower.shape == s.upper.shape == (n,)
    if fname == "double_integrator.toml":
        assert p.plant.dynamics == ("x2", "u")
        assert p.plant.A is None
        assert v.input_bounds is True
    else:
        assert p.plant.A.shape == (n, n) and p.plant.B.shape == (n, m)
        assert v.input_bounds is False


@pytest.mark.parametrize("fname", sorted(NONLINEAR))
def test_nonlinear_examples_load(fname):
    want = NONLINEAR[fname]
    path = EXAMPLES / fname
    p = load_spec(path)
    assert isinstance(p, Problem)
    assert p.name == want["name"]
    assert p.path == str(path)
    assert p.source == path.read_text()
    n, m = len(want["states"]), len(want["inputs"])
    # plant: nonlinear dynamics only, no matrices
    assert (p.plant.states, p.plant.inputs) == (want["states"], want["inputs"])
    assert (p.plant.n, p.plant.m) == (n, m)
    assert p.plant.dynamics == want["dynamics"]
    assert p.plant.A is None and p.plant.B is None
    # model: linearised at the origin (or the given operating point), sampled with zoh
    assert (p.model.method, p.model.sample_time) == ("zoh", want["sample_time"])
    assert p.model.x_op.tolist() == want.get("x_op", [0.0] * n)
    assert p.model.u_op.tolist() == want.get("u_op", [0.0] * m)
    assert p.model.A is None and p.model.B is None
    # mpc
    mpc = p.mpc
    assert (mpc.horizon, mpc.norm) == (want["horizon"], want["norm"])
    for key in ("Q", "R", "P", "x_min", "x_max", "u_min", "u_max"):
        got = getattr(mpc, key)
        assert got.dtype == float and got.tolist() == want[key], key
    assert mpc.domain_bound == want["domain_bound"]
    assert mpc.simplify is False
    if mpc.norm == "2":  # the terminal weight is a (rounded) Riccati solution: PD
        assert np.array_equal(mpc.P, mpc.P.T) and np.linalg.eigvalsh(mpc.P).min() > 0
    # verify: digital controller, input bounds checked
    v = p.verify
    assert isinstance(v, VerifySpec)
    assert (v.hold, v.input_bounds, v.max_depth, v.step) == ("zoh", True, 6, 0.01)
    assert v.time_horizon == want["time_horizon"]
    assert (v.initial_lower.tolist(), v.initial_upper.tolist()) == want["initial"]
    assert np.all(v.initial_lower < v.initial_upper)
    # the initial set lies inside the MPC's state bounds
    assert np.all(v.initial_lower >= mpc.x_min) and np.all(v.initial_upper <= mpc.x_max)
    for sets, wanted in ((v.unsafe, want["unsafe"]), (v.safe, want["safe"])):
        assert len(sets) == len(wanted)
        for s, (kind, a, b) in zip(sets, wanted, strict=True):
            assert s.kind == kind
            if kind == "box":
                assert (s.lower.tolist(), s.upper.tolist()) == (a, b)
            else:
                assert (s.A.tolist(), s.b.tolist()) == (a, b)


def test_magnetic_pointer_matrices_exact():
    p = load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    A = [[2.6629, -1.1644, 0.66598], [2.0, 0.0, 0.0], [0.0, 0.5, 0.0]]
    assert p.plant.A.tolist() == A
    assert p.plant.B.tolist() == [[0.25], [0.0], [0.0]]
    assert p.mpc.Q.tolist() == np.eye(3).tolist()
    assert p.mpc.u_max.tolist() == [40.0]
    assert p.verify.time_horizon == 1.1
    assert p.verify.initial_lower.tolist() == [-1.1, -2.1, -2.1]


def test_navigation_infinite_box_sides():
    p = load_spec(EXAMPLES / "navigation.toml")
    s = p.verify.unsafe[0]
    assert s.lower.tolist() == [-4.5, -7.0, -np.inf, -np.inf]
    A, b = s.halfspaces()
    assert A.shape == (4, 4) and b.tolist() == [-4.2, 4.5, -5.4, 7.0]


def test_base_spec_and_defaults(tmp_path):
    p = load_spec(write(tmp_path, BASE, "good.toml"))
    assert p.model.method == "zoh"
    assert p.mpc.simplify is False
    assert p.mpc.domain_bound == 100.0
    v = p.verify
    assert (v.hold, v.max_depth, v.step, v.input_bounds) == ("zoh", 6, 0.01, False)
    assert v.unsafe[1] == dataclasses.replace(v.unsafe[1])  # frozen dataclass copy works
    poly = v.unsafe[1]
    assert poly.kind == "polytope" and poly.A.tolist() == [[1.0, 1.0]]
    assert poly.b.tolist() == [-20.0]
    assert isinstance(poly, SetSpec)
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.mpc.horizon = 3  # type: ignore[misc]
    with pytest.raises(ValueError):
        p.mpc.Q[0, 0] = 5.0  # arrays are read-only


def test_loads_spec_matches_load_spec(tmp_path):
    path = write(tmp_path, BASE, "good.toml")
    a, b = load_spec(path), loads_spec(BASE, path=str(path))
    assert a.name == b.name and a.source == b.source and a.path == b.path
    assert np.array_equal(a.mpc.Q, b.mpc.Q)
    assert loads_spec(BASE).path == "<string>"


def test_optional_sections_and_fields():
    text = edit(
        (
            "x_min = [-10.0, -10.0]\nx_max = [10.0, 10.0]\nu_min = [-1.0]\nu_max = [1.0]\n",
            "simplify = true\ndomain_bound = 50\n",
        ),
    )
    text = text[: text.index("[verify]")]
    p = loads_spec(text)
    assert p.verify is None
    assert p.mpc.simplify is True and p.mpc.domain_bound == 50.0
    assert p.mpc.x_min.tolist() == [-np.inf, -np.inf]
    assert p.mpc.u_max.tolist() == [np.inf]


@pytest.mark.parametrize(
    ("value", "norm"),
    [
        ('"1"', "1"),
        ('"2"', "2"),
        ('"inf"', "inf"),
        ('"Inf"', "inf"),
        ("1", "1"),
        ("2", "2"),
        ("inf", "inf"),
    ],
)
def test_norm_spellings(value, norm):
    p = loads_spec(edit(('norm = "inf"', f"norm = {value}")))
    assert p.mpc.norm == norm
    assert isinstance(p.mpc, MpcSpec)


@pytest.mark.parametrize("value", ['"3"', "3", "0", "true", '"two"', "1.0", "-inf"])
def test_bad_norms(value):
    with pytest.raises(SpecError) as info:
        loads_spec(edit(('norm = "inf"', f"norm = {value}")))
    assert info.value.field == "mpc.norm"


def test_norm_1_allows_rectangular_weights():
    p = loads_spec(
        edit(
            ('norm = "inf"', 'norm = "1"'),
            ("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 1.0]]\nP = [[1, 0], [0, 1], [1, 1]]"),
            ("R = [[0.8]]", "R = [[0.8], [0.2]]"),
        )
    )
    assert p.mpc.Q.shape == (1, 2) and p.mpc.R.shape == (2, 1) and p.mpc.P.shape == (3, 2)


def test_norm_2_weights():
    p = loads_spec(
        edit(
            ('norm = "inf"', 'norm = "2"'),
            ("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1, 0], [0, 0]]\nP = [[2, 1], [1, 2]]"),
        )
    )
    assert p.mpc.norm == "2" and p.mpc.P.tolist() == [[2.0, 1.0], [1.0, 2.0]]


def test_operating_point_and_methods():
    for method in METHODS:
        p = loads_spec(
            edit(
                (
                    'method = "zoh"',
                    f'method = "{method}"\noperating_point = {{ x = [1.0, 0.0], u = [0.0] }}',
                ),
            )
        )
        assert p.model.method == method
        assert p.model.x_op.tolist() == [1.0, 0.0] and p.model.u_op.tolist() == [0.0]


def test_explicit_discrete_model_without_plant_dynamics():
    text = edit(
        ('dynamics = ["x2", "u"]\n', ""),
        ('method = "zoh"', "A = [[1, 1], [0, 1]]\nB = [[0.5], [1]]"),
    )
    p = loads_spec(text[: text.index("[verify]")])
    assert p.plant.dynamics is None and p.plant.A is None
    assert p.model.A.tolist() == [[1.0, 1.0], [0.0, 1.0]]
    # ... but verification needs the continuous plant.
    with pytest.raises(SpecError) as info:
        loads_spec(text)
    assert info.value.field == "verify"


def test_mpc_defaults_horizon_q_r():
    """horizon, Q and R may be left out: 5 and identities (docs/spec.md)."""
    gone = [("horizon = 2\n", ""), ("Q = [[1.0, 0.0], [0.0, 1.0]]\n", ""), ("R = [[0.8]]\n", "")]
    p = loads_spec(edit(*gone))
    assert p.mpc.horizon == 5
    assert p.mpc.Q.tolist() == [[1.0, 0.0], [0.0, 1.0]] and p.mpc.R.tolist() == [[1.0]]


def test_mpc_norm_defaults_to_2():
    """norm may be left out: "2", the quadratic cost (docs/spec.md; issue 41: the README
    promises defaults)."""
    p = loads_spec(edit(('norm = "inf"\n', "")))
    assert p.mpc.norm == "2"


def test_matrix_plant_ints_accepted():
    p = loads_spec(edit(('dynamics = ["x2", "u"]', "A = [[0, 1], [0, 0]]\nB = [[0], [1]]")))
    assert p.plant.A.dtype == float and p.plant.B.tolist() == [[0.0], [1.0]]


# --- bad specs: the required list -----------------------------------------------------------

BAD = [
    # id, replacements, field, reason fragment
    ("missing-field", [("sample_time = 1.0\n", "")], "model.sample_time",
     "missing required field"),
    (
        "missing-section",
        [("[verify]\ntime_horizon = 3.0\n", "[verify]\n")],
        "verify.time_horizon",
        "missing",
    ),
    (
        "unknown-field",
        [("horizon = 2", "horizon = 2\nhorizn = 3")],
        "mpc.horizn",
        "unknown field 'horizn'",
    ),
    (
        "unknown-top-level",
        [('name = "base"', 'name = "base"\ncolour = "red"')],
        "colour",
        "unknown field",
    ),
    (
        "unknown-set-field",
        [("lower = [-inf, 5.0]", "lower = [-inf, 5.0]\nlowr = [0, 0]")],
        "verify.unsafe[0].lowr",
        "unknown field",
    ),
    (
        "unknown-op-field",
        [('method = "zoh"', "operating_point = { x = [0, 0], y = [0] }")],
        "model.operating_point.y",
        "unknown field",
    ),
    (
        "matrix-shape",
        [("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]")],
        "mpc.Q",
        "expected a matrix with 2 columns, got 2×3",
    ),
    (
        "matrix-shape-norm2",
        [('norm = "inf"', 'norm = "2"'), ("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 0.0]]")],
        "mpc.Q",
        "expected a 2×2 matrix, got 1×2",
    ),
    (
        "plant-A-shape",
        [('dynamics = ["x2", "u"]', "A = [[0, 1, 0], [0, 0, 0]]\nB = [[0], [1]]")],
        "plant.A",
        "expected a 2×2 matrix, got 2×3",
    ),
    (
        "plant-B-shape",
        [('dynamics = ["x2", "u"]', "A = [[0, 1], [0, 0]]\nB = [[0, 1]]")],
        "plant.B",
        "expected a 2×1 matrix, got 1×2",
    ),
    (
        "ragged-matrix",
        [("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 0.0], [1.0]]")],
        "mpc.Q",
        "different lengths",
    ),
    ("flat-matrix", [("R = [[0.8]]", "R = [0.8]")], "mpc.R", "list of rows"),
    ("nan", [("R = [[0.8]]", "R = [[nan]]")], "mpc.R[0][0]", "NaN"),
    ("nan-bound", [("u_max = [1.0]", "u_max = [nan]")], "mpc.u_max[0]", "NaN"),
    ("inf-weight", [("R = [[0.8]]", "R = [[inf]]")], "mpc.R[0][0]", "infinite"),
    (
        "inf-initial",
        [("upper = [1.1, 0.1]", "upper = [1.1, inf]")],
        "verify.initial_set.upper[1]",
        "infinite",
    ),
    ("bool-in-matrix", [("R = [[0.8]]", "R = [[true]]")], "mpc.R[0][0]", "expected a number"),
    (
        "string-number",
        [("sample_time = 1.0", 'sample_time = "1.0"')],
        "model.sample_time",
        "expected a number",
    ),
    (
        "q-not-psd",
        [
            ('norm = "inf"', 'norm = "2"'),
            ("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 0.0], [0.0, -1.0]]"),
        ],
        "mpc.Q",
        "positive semidefinite",
    ),
    (
        "q-not-symmetric",
        [
            ('norm = "inf"', 'norm = "2"'),
            ("Q = [[1.0, 0.0], [0.0, 1.0]]", "Q = [[1.0, 1.0], [0.0, 1.0]]"),
        ],
        "mpc.Q",
        "symmetric",
    ),
    (
        "r-not-pd",
        [('norm = "inf"', 'norm = "2"'), ("R = [[0.8]]", "R = [[0.0]]")],
        "mpc.R",
        "positive definite",
    ),
    (
        "p-not-psd",
        [('norm = "inf"', 'norm = "2"'), ("R = [[0.8]]", "R = [[0.8]]\nP = [[-1, 0], [0, 1]]")],
        "mpc.P",
        "positive semidefinite",
    ),
    (
        "x-min-gt-max",
        [("x_min = [-10.0, -10.0]", "x_min = [-10.0, 11.0]")],
        "mpc.x_min",
        "x_min[1] = 11 is greater than x_max[1] = 10",
    ),
    ("u-min-gt-max", [("u_min = [-1.0]", "u_min = [2.0]")], "mpc.u_min", "greater than"),
    (
        "x-min-plus-inf",
        [("x_min = [-10.0, -10.0]", "x_min = [inf, -10.0]")],
        "mpc.x_min[0]",
        "cannot be +inf",
    ),
    (
        "unknown-name",
        [('dynamics = ["x2", "u"]', 'dynamics = ["x2", "y"]')],
        "plant.dynamics[1]",
        "unknown name 'y' (known: x1, x2, u, pi, e)",
    ),
    (
        "unknown-function",
        [('dynamics = ["x2", "u"]', 'dynamics = ["x2", "foo(u)"]')],
        "plant.dynamics[1]",
        "unknown function 'foo'",
    ),
    (
        "caret",
        [('dynamics = ["x2", "u"]', 'dynamics = ["x2^2", "u"]')],
        "plant.dynamics[0]",
        "use ** for powers",
    ),
    (
        "dynamics-count",
        [('dynamics = ["x2", "u"]', 'dynamics = ["x2"]')],
        "plant.dynamics",
        "expected 2 expressions",
    ),
    (
        "dynamics-and-A",
        [('dynamics = ["x2", "u"]', 'dynamics = ["x2", "u"]\nA = [[0, 1], [0, 0]]')],
        "plant.A",
        "not both",
    ),
    ("no-dynamics", [('dynamics = ["x2", "u"]\n', "")], "plant.dynamics", "missing"),
    ("A-without-B", [('dynamics = ["x2", "u"]', "A = [[0, 1], [0, 0]]")], "plant.B", "missing"),
    ("horizon-zero", [("horizon = 2", "horizon = 0")], "mpc.horizon", "must be >= 1"),
    ("horizon-float", [("horizon = 2", "horizon = 2.0")], "mpc.horizon", "expected an integer"),
    (
        "sample-time-zero",
        [("sample_time = 1.0", "sample_time = 0.0")],
        "model.sample_time",
        "must be > 0",
    ),
    (
        "sample-time-negative",
        [("sample_time = 1.0", "sample_time = -1")],
        "model.sample_time",
        "must be > 0",
    ),
    (
        "sample-time-inf",
        [("sample_time = 1.0", "sample_time = inf")],
        "model.sample_time",
        "infinite",
    ),
    ("method", [('method = "zoh"', 'method = "magic"')], "model.method", "expected one of"),
    (
        "initial-lower-gt-upper",
        [("lower = [0.9, -0.1]", "lower = [1.2, -0.1]")],
        "verify.initial_set.lower",
        "lower[0] = 1.2 is greater than upper[0] = 1.1",
    ),
    (
        "initial-wrong-dim",
        [("lower = [0.9, -0.1]", "lower = [0.9]")],
        "verify.initial_set.lower",
        "expected a list of 2 numbers, got 1",
    ),
    (
        "initial-missing-upper",
        [(", upper = [1.1, 0.1]", "")],
        "verify.initial_set.upper",
        "missing",
    ),
    (
        "unsafe-wrong-dim",
        [("lower = [-inf, 5.0]", "lower = [-inf, 5.0, 0.0]")],
        "verify.unsafe[0].lower",
        "expected a list of 2 numbers, got 3",
    ),
    (
        "unsafe-polytope-wrong-dim",
        [("A = [[1.0, 1.0]]", "A = [[1.0, 1.0, 1.0]]")],
        "verify.unsafe[1].A",
        "expected a matrix with 2 columns, got 1×3",
    ),
    (
        "unsafe-polytope-b-dim",
        [("b = [-20.0]", "b = [-20.0, 1.0]")],
        "verify.unsafe[1].b",
        "expected a list of 1 number, got 2",
    ),
    (
        "unsafe-box-and-polytope",
        [("b = [-20.0]", "b = [-20.0]\nlower = [0, 0]")],
        "verify.unsafe[1]",
        "not both",
    ),
    (
        "safe-wrong-dim",
        [("upper = [10.0, 10.0]", "upper = [10.0]")],
        "verify.safe[0].upper",
        "expected a list of 2 numbers, got 1",
    ),
    (
        "safe-lower-gt-upper",
        [
            (
                "lower = [-10.0, -10.0]\nupper = [10.0, 10.0]",
                "lower = [-10.0, 11.0]\nupper = [10.0, 10.0]",
            )
        ],
        "verify.safe[0].lower",
        "greater than",
    ),
    (
        "time-horizon-lt-step",
        [("time_horizon = 3.0", "time_horizon = 0.001")],
        "verify.time_horizon",
        "horizon shorter than one step",
    ),
    (
        "time-horizon-zero",
        [("time_horizon = 3.0", "time_horizon = 0")],
        "verify.time_horizon",
        "must be > 0",
    ),
    ("hold", [("step = 0.01", 'step = 0.01\nhold = "foh"')], "verify.hold", "expected one of"),
    (
        "max-depth",
        [("step = 0.01", "step = 0.01\nmax_depth = -1")],
        "verify.max_depth",
        "must be >= 0",
    ),
    (
        "input-bounds",
        [("step = 0.01", 'step = 0.01\ninput_bounds = "yes"')],
        "verify.input_bounds",
        "expected true or false",
    ),
    (
        "constraints",
        [("step = 0.01", 'step = 0.01\nconstraints = 1')],
        "verify.constraints",
        "expected true or false",
    ),
    (
        "simplify",
        [("horizon = 2", "horizon = 2\nsimplify = 1")],
        "mpc.simplify",
        "expected true or false",
    ),
    (
        "domain-bound",
        [("horizon = 2", "horizon = 2\ndomain_bound = 0")],
        "mpc.domain_bound",
        "must be > 0",
    ),
    ("unsafe-not-array", [("[[verify.safe]]", "[verify.safe]")], "verify.safe", "array of tables"),
    (
        "duplicate-state",
        [('states = ["x1", "x2"]', 'states = ["x1", "x1"]')],
        "plant.states[1]",
        "duplicate",
    ),
    ("state-is-input", [('inputs = ["u"]', 'inputs = ["x1"]')], "plant.inputs", "both"),
    (
        "reserved-name",
        [('states = ["x1", "x2"]', 'states = ["x1", "sin"]')],
        "plant.states[1]",
        "cannot be a name",
    ),
    (
        "keyword-name",
        [('inputs = ["u"]', 'inputs = ["lambda"]')],
        "plant.inputs[0]",
        "reserved word",
    ),
    ("bad-identifier", [('inputs = ["u"]', 'inputs = ["u-1"]')], "plant.inputs[0]", "invalid name"),
    ("no-states", [('states = ["x1", "x2"]', "states = []")], "plant.states", "empty"),
    ("bad-spec-name", [('name = "base"', 'name = "../etc"')], "name", "invalid name"),
    (
        "op-wrong-dim",
        [('method = "zoh"', "operating_point = { x = [0.0], u = [0.0] }")],
        "model.operating_point.x",
        "expected a list of 2 numbers, got 1",
    ),
    (
        "op-not-differentiable",
        [('dynamics = ["x2", "u"]', 'dynamics = ["sqrt(x1)", "u"]')],
        "model.operating_point",
        "cannot be linearised",
    ),
    (
        "injection",
        [
            (
                'dynamics = ["x2", "u"]',
                "dynamics = [\"__import__('os').system('touch /tmp/pwned')\", \"u\"]",
            )
        ],
        "plant.dynamics[0]",
        "unknown function '__import__'",
    ),
]


@pytest.mark.parametrize(
    ("replacements", "field", "fragment"), [b[1:] for b in BAD], ids=[b[0] for b in BAD]
)
def test_bad_specs(tmp_path, replacements, field, fragment):
    err = load_error(tmp_path, edit(*replacements))
    assert err.field == field
    assert field in str(err)
    assert fragment in err.reason


def test_toml_syntax_error_has_line(tmp_path):
    text = edit(("horizon = 2", "horizon = = 2"))
    line = text.splitlines().index("horizon = = 2") + 1
    err = load_error(tmp_path, text)
    assert "invalid TOML" in err.reason
    assert f"line {line}" in str(err)


def test_toml_error_at_end_of_file_has_line(tmp_path):
    err = load_error(tmp_path, BASE + "extra = [1, 2\n")
    assert "line" in err.reason


def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(SpecError) as info:
        load_spec(path)
    assert "nope.toml" in str(info.value) and "not found" in info.value.reason


def test_not_utf8(tmp_path):
    path = tmp_path / "bad_spec.toml"
    path.write_bytes(b'name = "\xff"\n')
    with pytest.raises(SpecError, match="UTF-8"):
        load_spec(path)


def test_injection_not_executed(tmp_path):
    target = tmp_path / "pwned"
    existed = Path("/tmp/pwned").exists()
    text = edit(
        (
            'dynamics = ["x2", "u"]',
            f"dynamics = [\"__import__('os').system('touch {target}')\", \"u\"]",
        )
    )
    load_error(tmp_path, text)
    assert not target.exists()
    if not existed:
        assert not Path("/tmp/pwned").exists()


def test_loads_spec_errors_name_the_path():
    with pytest.raises(SpecError) as info:
        loads_spec(edit(("horizon = 2", "horizon = 0")), path="inline.toml")
    assert str(info.value).startswith("inline.toml: mpc.horizon: ")


def test_feasibility_check_is_called(tmp_path, monkeypatch):
    mpc = pytest.importorskip("codev_engine.mpc")

    def infeasible(problem):
        raise SpecError("the MPC is infeasible", field="mpc")

    monkeypatch.setattr(mpc, "check_feasible", infeasible)
    err = load_error(tmp_path, BASE)
    assert err.field == "mpc" and "infeasible" in err.reason
