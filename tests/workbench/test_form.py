"""The workbench form (workbench/form.py): spec text <-> one entry per field.

The form must lose nothing (every example composes back to a problem with the same stage
keys as the file), accept Matlab-style entries, pin every error on the entry that caused it,
and never execute what is typed.
"""

from __future__ import annotations

import math
import tomllib
import uuid
from pathlib import Path

import pytest

import codev_engine as ce
from codev_engine.session import RunOptions, stage_keys
from workbench.tui.form import (
    FIELD_BY_NAME,
    FIELDS,
    check_form,
    compose,
    entry_to_toml,
    field_for_error,
    form_from_text,
    toml_value,
)

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "examples").glob("*.toml"))
DI = ROOT / "examples" / "double_integrator.toml"


def _di_form() -> tuple[dict[str, str], bool]:
    return form_from_text(DI.read_text(encoding="utf-8"))


def _check(**changes: str):
    values, has_verify = _di_form()
    for k, v in changes.items():
        assert k in values, k
        values[k] = v
    return check_form(values, with_verify=has_verify)


def _one_error(chk) -> tuple[str, str]:
    assert not chk.ok
    assert chk.general is None, chk.general
    assert len(chk.errors) == 1, chk.errors
    return next(iter(chk.errors.items()))


# --------------------------------------------------------------------------------------------
# Round trip: the form loses nothing
# --------------------------------------------------------------------------------------------


def test_every_example_is_found():
    assert len(EXAMPLES) >= 5, EXAMPLES


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_round_trip_keeps_the_stage_keys(path):
    text = path.read_text(encoding="utf-8")
    values, has_verify = form_from_text(text)
    assert set(values) == {fd.name for fd in FIELDS}
    loaded = ce.load_spec(path, check_mpc=False)
    assert has_verify == (loaded.verify is not None)
    chk = check_form(values, with_verify=has_verify)
    assert chk.ok, (chk.errors, chk.general, chk.text)
    for options in (RunOptions(), RunOptions(hold="continuous", max_depth=2)):
        assert stage_keys(chk.problem, options) == stage_keys(loaded, options)
    # and a second pass through the form is a fixed point
    values2, has_verify2 = form_from_text(chk.text)
    assert (values2, has_verify2) == (values, has_verify)


def test_without_verify_the_section_is_left_out():
    values, _ = _di_form()
    chk = check_form(values, with_verify=False)
    assert chk.ok, chk.errors
    assert chk.problem.verify is None
    assert "[verify]" not in chk.text
    # required verify entries do not matter when the section is off
    values["verify.time_horizon"] = ""
    assert check_form(values, with_verify=False).ok


def test_empty_optional_entries_take_the_engine_defaults():
    values, has_verify = _di_form()
    for name in ("model.method", "verify.max_depth", "verify.step", "mpc.domain_bound"):
        values[name] = ""
    chk = check_form(values, with_verify=has_verify)
    assert chk.ok, chk.errors
    p = chk.problem
    assert p.model.method == "zoh"
    assert p.verify.max_depth == 6 and p.verify.step == 0.01
    assert p.mpc.domain_bound == 100.0


def test_a_blank_form_with_only_the_required_entries_is_a_valid_spec():
    """A newcomer's form (issue 41): the plant, the sample time and the verification's
    required entries typed, every MPC entry left at its default. The loader requires the
    [mpc] section, so the form writes it even empty (before, the status said "fix mpc"
    with no entry to fix)."""
    values = {fd.name: "" for fd in FIELDS}
    values.update({
        "name": "msd", "plant.states": "p, v", "plant.inputs": "u",
        "plant.dynamics": "v\n-2*p - 0.5*v + u", "model.sample_time": "0.2",
        "verify.time_horizon": "3", "verify.initial_set.lower": "-0.5, -0.5",
        "verify.initial_set.upper": "0.5, 0.5",
    })
    chk = check_form(values, with_verify=True)
    assert chk.ok, (chk.errors, chk.general)
    assert "[mpc]" in chk.text
    assert chk.problem.mpc.horizon == 5 and chk.problem.mpc.norm == "2"


# --------------------------------------------------------------------------------------------
# Matlab-style entries
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kind", "matlab", "toml"),
    [
        ("matrix", "1 1; 0 1", "[[1, 1], [0, 1]]"),
        ("matrix", "[1 1; 0 1]", "[[1.0, 1.0], [0.0, 1.0]]"),
        ("matrix", "1, 1\n0, 1", "[[1, 1], [0, 1]]"),
        ("matrix", "0.8", "[[0.8]]"),
        ("matrix", "1e-3 -2.5E2", "[[0.001, -250.0]]"),
        ("vector", "-inf inf", "[-inf, inf]"),
        ("vector", "1, 2", "[1.0, 2.0]"),
        ("vector", "1 2", "[1, 2]"),
        ("vector", "-10,   -10", "[-10, -10]"),
        ("number", ".5", "0.5"),
        ("number", "1e-2", "0.01"),
    ],
)
def test_matlab_entry_equals_toml_entry(kind, matlab, toml):
    a = tomllib.loads("v = " + entry_to_toml(kind, matlab))["v"]
    b = tomllib.loads("v = " + entry_to_toml(kind, toml))["v"]
    assert a == b
    assert _floats(a) == _floats(b)


def _floats(v):
    return [_floats(x) for x in v] if isinstance(v, list) else float(v)


def test_matlab_entries_give_the_same_problem_as_toml_entries():
    values, has_verify = _di_form()
    values.update(
        {
            "mpc.Q": "1 1; 0 1",
            "mpc.R": "0.8",
            "mpc.x_min": "-10 -10",
            "mpc.x_max": "10, 10",
            "mpc.u_min": "-1",
            "mpc.u_max": "1",
            "verify.initial_set.lower": "8.99 -5.01",
            "verify.initial_set.upper": "9.01, -4.99",
        }
    )
    chk = check_form(values, with_verify=has_verify)
    assert chk.ok, chk.errors
    ref = ce.load_spec(DI, check_mpc=False)
    assert stage_keys(chk.problem, RunOptions()) == stage_keys(ref, RunOptions())


def test_infinite_bounds_typed_matlab_style():
    chk = _check(**{"mpc.x_min": "-inf -inf", "mpc.x_max": "inf inf"})
    assert chk.ok, chk.errors
    assert list(chk.problem.mpc.x_min) == [-math.inf, -math.inf]
    assert list(chk.problem.mpc.x_max) == [math.inf, math.inf]


def test_names_and_expressions_entries():
    values, has_verify = _di_form()
    assert values["plant.states"] == "x1, x2"
    assert values["plant.dynamics"] == "x2\nu"
    values["plant.states"] = "p  v"  # spaces work as separators too
    values["plant.dynamics"] = "\n  v  \n\nu\n"  # blank lines are ignored
    values["verify.unsafe"] = ""
    chk = check_form(values, with_verify=has_verify)
    assert chk.ok, chk.errors
    assert chk.problem.plant.states == ("p", "v")
    assert chk.problem.plant.dynamics == ("v", "u")


def test_choice_and_bool_entries():
    chk = _check(**{"mpc.norm": "INF", "mpc.simplify": "yes", "verify.hold": "zoh"})
    assert chk.ok, chk.errors
    assert chk.problem.mpc.norm == "inf"
    assert chk.problem.mpc.simplify is True
    assert chk.problem.verify.hold == "zoh"
    key, msg = _one_error(_check(**{"mpc.simplify": "maybe"}))
    assert key == "mpc.simplify" and "true or false" in msg


# --------------------------------------------------------------------------------------------
# Errors pinned on entries
# --------------------------------------------------------------------------------------------


def test_bad_q_entry_is_pinned_on_q():
    key, msg = _one_error(_check(**{"mpc.Q": "1 1; 0 x"}))
    assert key == "mpc.Q"
    assert "numbers" in msg


def test_wrong_shape_is_pinned_on_its_entry():
    key, msg = _one_error(_check(**{"mpc.Q": "1 1 1; 0 1 0"}))
    assert key == "mpc.Q"
    assert "2" in msg and "3" in msg


def test_unknown_name_in_second_dynamics_line():
    key, msg = _one_error(_check(**{"plant.dynamics": "x2\ny"}))
    assert key == "plant.dynamics"
    assert "plant.dynamics[1]" in msg
    assert "'y'" in msg


@pytest.mark.parametrize("name", [fd.name for fd in FIELDS if fd.required])
def test_missing_required_entry(name):
    key, msg = _one_error(_check(**{name: "   "}))
    assert (key, msg) == (name, "required")


def test_all_entry_syntax_errors_are_reported_together():
    chk = _check(**{"mpc.Q": "a", "name": "", "verify.unsafe": "[{"})
    assert set(chk.errors) == {"mpc.Q", "name", "verify.unsafe"}


def test_an_empty_norm_is_the_default_2():
    # issue 41: the README promises defaults; the form shows "default: 2"
    assert FIELD_BY_NAME["mpc.norm"].default == "2" and not FIELD_BY_NAME["mpc.norm"].required
    chk = _check(**{"mpc.norm": "", "mpc.Q": "1 0; 0 1"})
    assert chk.ok and chk.problem.mpc.norm == "2", chk.errors


def test_nan_is_pinned_with_its_index():
    key, msg = _one_error(_check(**{"mpc.Q": "1 nan; 0 1"}))
    assert key == "mpc.Q"
    assert msg.startswith("mpc.Q[0][1]")
    assert "NaN" in msg
    key, msg = _one_error(_check(**{"model.sample_time": "nan"}))
    assert key == "model.sample_time" and "NaN" in msg


def test_non_number_token():
    for name, text in (
        ("mpc.x_min", "-10 ten"),
        ("verify.initial_set.lower", "8.99, 0x"),
        ("mpc.R", "0.8 1,,x"),
    ):
        key, msg = _one_error(_check(**{name: text}))
        assert key == name
        assert "expected numbers" in msg


def test_unbalanced_toml_bracket():
    key, msg = _one_error(_check(**{"mpc.Q": "[[1, 1], [0, 1]"}))
    assert key == "mpc.Q"
    assert msg.startswith("not a valid value")
    key, _ = _one_error(_check(**{"verify.unsafe": "[{ lower = [1, 2], upper = [3, 4] }"}))
    assert key == "verify.unsafe"


def test_verify_set_of_the_wrong_length():
    key, msg = _one_error(_check(**{"verify.unsafe": "[{ lower = [1, 2, 3], upper = [4, 5, 6] }]"}))
    assert key == "verify.unsafe"
    assert msg.startswith("verify.unsafe[0].lower")
    key, msg = _one_error(
        _check(
            **{
                "verify.unsafe": "[{ lower = [0, 0], upper = [1, 1] },\n"
                " { A = [[1, 0, 0]], b = [1] }]"
            }
        )
    )
    assert key == "verify.unsafe"
    assert msg.startswith("verify.unsafe[1].A")


def test_operating_point_of_the_wrong_length():
    key, msg = _one_error(_check(**{"model.operating_point.x": "1, 2, 3"}))
    assert key == "model.operating_point.x"
    assert "3" in msg
    key, _ = _one_error(_check(**{"model.operating_point.u": "1, 2"}))
    assert key == "model.operating_point.u"


def test_non_differentiable_operating_point_goes_to_the_point():
    # the engine names the table (model.operating_point): the form shows it on x
    key, msg = _one_error(_check(**{"plant.dynamics": "x2\nsqrt(x1) + u"}))
    assert key == "model.operating_point.x"
    assert msg.startswith("model.operating_point:")


def test_initial_set_order_error():
    key, msg = _one_error(
        _check(**{"verify.initial_set.lower": "9.5 -5", "verify.initial_set.upper": "9 -4"})
    )
    assert key == "verify.initial_set.lower"


def test_infeasible_mpc_is_a_general_error():
    # u bounds that exclude the equilibrium u = 0 of a state bounded box: infeasible for
    # every state (checked only with check_mpc=True)
    values, has_verify = _di_form()
    values.update({"mpc.u_min": "5", "mpc.u_max": "6", "mpc.x_min": "-1 -1", "mpc.x_max": "1 1"})
    assert check_form(values, with_verify=has_verify).ok
    chk = check_form(values, with_verify=has_verify, check_mpc=True)
    assert not chk.ok
    assert chk.errors == {}
    assert chk.general is not None and chk.general.startswith("mpc:")


@pytest.mark.parametrize(
    ("field", "entry"),
    [
        ("mpc.Q", "mpc.Q"),
        ("mpc.Q[0][1]", "mpc.Q"),
        ("plant.dynamics[1]", "plant.dynamics"),
        ("verify.unsafe[3].lower", "verify.unsafe"),
        ("verify.unsafe[0].A", "verify.unsafe"),
        ("verify.safe[0].upper[1]", "verify.safe"),
        ("verify.initial_set.upper[0]", "verify.initial_set.upper"),
        ("verify.initial_set", "verify.initial_set.lower"),
        ("model.operating_point", "model.operating_point.x"),
        ("model.operating_point.u[0]", "model.operating_point.u"),
        ("name", "name"),
        ("mpc", None),
        ("verify", None),
        ("plant", None),
        ("", None),
        (None, None),
        ("model.A", None),
        ("nonsense.field", None),
    ],
)
def test_field_for_error(field, entry):
    assert field_for_error(field) == entry


def test_every_field_maps_to_itself():
    for fd in FIELDS:
        assert field_for_error(fd.name) == fd.name
        assert FIELD_BY_NAME[fd.name] is fd


# --------------------------------------------------------------------------------------------
# toml_value
# --------------------------------------------------------------------------------------------


def _round(value):
    return tomllib.loads("v = " + toml_value(value))["v"]


@pytest.mark.parametrize(
    "x",
    [
        0.0,
        -0.0,
        0.1,
        1 / 3,
        2.0**-1074,
        1.7976931348623157e308,
        -1e-300,
        123456789.123456789,
        5e-324,
    ],
)
def test_toml_value_floats_are_exact(x):
    y = _round(x)
    assert isinstance(y, float)
    assert y == x and math.copysign(1, y) == math.copysign(1, x)
    assert toml_value(x) == repr(x)


def test_toml_value_random_floats_are_exact():
    import random

    rng = random.Random(7)
    for _ in range(2000):
        x = rng.uniform(-1, 1) * 10 ** rng.randint(-300, 300)
        assert _round(x) == x


def test_toml_value_infinities_nan_ints_bools():
    assert _round(math.inf) == math.inf
    assert _round(-math.inf) == -math.inf
    assert math.isnan(_round(math.nan))
    assert _round(3) == 3 and isinstance(_round(3), int)
    assert _round(-(2**62)) == -(2**62)
    assert _round(True) is True and _round(False) is False


@pytest.mark.parametrize(
    "s",
    [
        "",
        'say "hi"',
        "back\\slash \\n not a newline",
        "tab\tnew\nline\rcr",
        "ünïcödé θ ω ∂ 😀",
        "\x00\x01\x1f\x7f",
        "'single' quotes",
        '""" triple',
        "# not a comment",
        "\u2028\u2029",
    ],
)
def test_toml_value_strings(s):
    assert _round(s) == s


def test_toml_value_nested_lists_and_tables():
    v = [[1.0, -math.inf], [0.5, 2], []]
    assert _round(v) == v
    sets = [
        {"lower": [-0.6, -2.7], "upper": [-0.2, math.inf]},
        {"A": [[1.0, 1.0]], "b": [-20.0]},
        {"odd key": "x", "ü": [True]},
    ]
    text = toml_value(sets)
    assert text.count("\n") == 4  # one table per line
    assert _round(sets) == sets
    assert _round({"x": [1.0, 2.0], "u": []}) == {"x": [1.0, 2.0], "u": []}


def test_toml_value_rejects_other_types():
    with pytest.raises(TypeError):
        toml_value(object())
    with pytest.raises(TypeError):
        toml_value(None)


# --------------------------------------------------------------------------------------------
# Nothing typed is executed, nothing is injected
# --------------------------------------------------------------------------------------------


def test_nothing_typed_is_executed(tmp_path):
    marker = tmp_path / f"pwned-{uuid.uuid4().hex}"
    payloads = [
        f"__import__('os').system('touch {marker}')",
        f'__import__("os").system("touch {marker}")',
        f"[__import__('os').system('touch {marker}')]",
        f"eval(\"__import__('os').system('touch {marker}')\")",
        f"1\n__import__('os').system('touch {marker}')",
    ]
    values0, has_verify = _di_form()
    for fd in FIELDS:
        for payload in payloads:
            values = dict(values0)
            values[fd.name] = payload
            chk = check_form(values, with_verify=has_verify, check_mpc=True)
            assert not chk.ok, (fd.name, payload)
            if chk.errors:
                assert set(chk.errors) == {fd.name}, (fd.name, payload, chk.errors)
            else:  # an error the engine does not pin on an entry
                assert chk.general, (fd.name, payload)
            assert not marker.exists(), (fd.name, payload)
    assert not marker.exists()


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("name", '"x"\nfoo = 1'),
        ("mpc.horizon", "2\nP = [[1, 0], [0, 1]]"),
        ("mpc.horizon", "2\n[extra]\nk = 1"),
        ("model.sample_time", "1.0\n\n[[verify.unsafe]]\nlower = [0, 0]\nupper = [1, 1]"),
        ("mpc.Q", "[[1, 1], [0, 1]]\nR = [[1]]"),
        ("mpc.norm", '"inf"\nsimplify = true'),
        ("plant.states", '["x1", "x2"]\ninputs2 = ["v"]'),
        ("plant.dynamics", '["x2", "u"]\nA = [[0]]'),
        ("verify.unsafe", "[]\nsafe = []"),
    ],
)
def test_an_entry_cannot_inject_other_fields(name, text):
    key, msg = _one_error(_check(**{name: text}))
    assert key == name
    assert "one value" in msg or "valid value" in msg


def test_composed_document_has_one_line_per_entry():
    values, has_verify = _di_form()
    text, errors = compose(values, with_verify=has_verify)
    assert errors == {}
    data = tomllib.loads(text)
    assert set(data) == {"name", "plant", "model", "mpc", "verify"}
    assert data["mpc"]["Q"] == [[1.0, 1.0], [0.0, 1.0]]


# --------------------------------------------------------------------------------------------
# form_from_text
# --------------------------------------------------------------------------------------------


def test_explicit_discrete_model_is_refused_by_name():
    text = """
name = "explicit"
[plant]
states = ["x1", "x2"]
inputs = ["u"]
[model]
sample_time = 1.0
A = [[1.0, 1.0], [0.0, 1.0]]
B = [[0.5], [1.0]]
[mpc]
horizon = 2
norm = "inf"
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[1.0]]
"""
    ce.loads_spec(text)  # a valid spec: only the form has no entry for it
    with pytest.raises(ce.SpecError) as info:
        form_from_text(text)
    assert info.value.field == "model.A"
    assert "model.A" in str(info.value)
    assert "edit the spec file as text" in info.value.reason


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ("[mpc]\nfoo = 1\n", "mpc.foo"),
        ("[extra]\nkey = 1\n", "extra.key"),
        ("[model.operating_point]\nz = [1]\n", "model.operating_point.z"),
    ],
)
def test_unknown_fields_are_refused(extra, field):
    text = DI.read_text(encoding="utf-8")
    if extra.startswith("[mpc]"):
        text = text.replace("[mpc]\n", extra)
    else:
        text = text.replace("[mpc]\n", extra + "\n[mpc]\n")
    with pytest.raises(ce.SpecError) as info:
        form_from_text(text)
    assert info.value.field == field


def test_invalid_toml_is_a_spec_error():
    with pytest.raises(ce.SpecError, match="invalid TOML"):
        form_from_text("name = [\n")


def test_spec_without_verify():
    text = DI.read_text(encoding="utf-8")
    text = text[: text.index("[verify]")]
    values, has_verify = form_from_text(text)
    assert has_verify is False
    assert all(values[fd.name] == "" for fd in FIELDS if fd.section == "verify")


# --------------------------------------------------------------------------------------------
# The fields of issues 25 and 26: entries, defaults, errors, exact round trip
# --------------------------------------------------------------------------------------------

SERVO = ROOT / "examples" / "dc_motor_servo.toml"

#: every field of the formulations (25) and of the uncertain plant (26), in one document
#: (the loader is not asked: the form alone must keep each value exactly)
EVERY_NEW_FIELD = """
name = "every-field"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 1.0], [0.0, -0.5]]
B = [[0.0], [1.0]]
E = [[0.0], [1.0]]
disturbances = { w = [-0.1, 0.1] }
parameters = { k = [1.0, 2.0] }
nominal = { w = 0.05, k = 1.5 }
[model]
sample_time = 0.1
[mpc]
horizon = 6
control_horizon = 3
norm = "2"
P = "lqr"
terminal_set = { lower = [-1.0, -1.0], upper = [1.0, 1.0] }
du_min = [-0.5]
du_max = [0.25]
Rd = [[0.1]]
C = [[1.0, 0.0]]
y_min = [-2.0]
y_max = [2.0]
soft = ["y_max", "x_max"]
soft_weight = 1000.0
x_max = [5.0, 5.0]
[[mpc.constraints]]
Hx = [[1.0, 1.0]]
Hu = [[0.5]]
h = [2.0]
[[mpc.constraints]]
Hu = [[1.0]]
h = [0.9]
[mpc.reference]
signal = "y"
lower = [-1.0]
upper = [1.0]
[verify]
time_horizon = "inf"
max_samples = 200
initial_set = { lower = [0.0, 0.0], upper = [0.1, 0.1] }
initial_input = { lower = [-0.1], upper = [0.1] }
reference = [0.5]
measurement_noise = { lower = [-0.01, -0.02], upper = [0.01, 0.02] }
"""


def test_every_new_field_has_an_entry_and_round_trips_exactly():
    values, has_verify = form_from_text(EVERY_NEW_FIELD)
    text, errors = compose(values, with_verify=has_verify)
    assert errors == {}
    assert tomllib.loads(text) == tomllib.loads(EVERY_NEW_FIELD)
    # and the entries read as typed: words bare, tables inline
    assert values["mpc.P"] == "lqr" and values["verify.time_horizon"] == "inf"
    assert values["mpc.soft"] == "y_max, x_max"
    assert values["plant.disturbances"] == "{ w = [-0.1, 0.1] }"
    assert values["verify.initial_input"] == "{ lower = [-0.1], upper = [0.1] }"
    assert values["verify.measurement_noise"] == (
        "{ lower = [-0.01, -0.02], upper = [0.01, 0.02] }"
    )
    assert form_from_text(text) == (values, has_verify)


def test_every_optional_entry_shows_its_default():
    for fd in FIELDS:
        if not fd.required and fd.kind != "bool":
            assert fd.default, fd.name
    # the words and the short forms typed are what the spec means
    values, has_verify = form_from_text(EVERY_NEW_FIELD)
    values["plant.disturbances"] = "w = [-0.1, 0.1]"  # braces left out
    values["mpc.P"] = "'lqr'"
    values["verify.reference"] = "0.5"
    values["mpc.du_min"] = "-0.5"
    text, errors = compose(values, with_verify=has_verify)
    assert errors == {} and tomllib.loads(text) == tomllib.loads(EVERY_NEW_FIELD)


def test_the_servo_through_the_form_has_theta_of_length_4():
    values, has_verify = form_from_text(SERVO.read_text(encoding="utf-8"))
    chk = check_form(values, with_verify=has_verify)
    assert chk.ok, (chk.errors, chk.general)
    assert chk.problem.mpc.du_min.tolist() == [-0.5]
    assert chk.problem.mpc.reference.signal == "y"
    assert chk.problem.verify.reference_lower.tolist() == [0.45]


def _servo_check(**changes: str):
    values, has_verify = form_from_text(SERVO.read_text(encoding="utf-8"))
    for k, v in changes.items():
        assert k in values, k
        values[k] = v
    return check_form(values, with_verify=has_verify)


@pytest.mark.parametrize(
    ("field", "text", "words"),
    [
        ("mpc.du_min", "a b", "expected numbers"),
        ("mpc.du_max", "0.5 0.5", "expected 1 numbers"),
        ("mpc.du_min", "0.1", "du_min"),
        ("mpc.Rd", "1 0; 0 1", "expected 1×1"),
        ("mpc.C", "1 0 0", "expected 2 columns"),
        ("mpc.y_max", "1 2", "expected 1 numbers (one per output)"),
        ("mpc.control_horizon", "9", "control_horizon"),
        ("mpc.soft", "z_max", "soft"),
        ("mpc.soft_weight", "-1", "soft_weight"),
        ("mpc.terminal_set", "{ A = [[1, 0]] }", "terminal_set"),
        ("mpc.terminal_set", "lqq", "terminal_set"),
        ("mpc.P", "lqrr", "expected numbers"),
        ("mpc.constraints", "[{ Hx = [[1, 0, 0]], h = [1] }]", "constraints"),
        ("mpc.reference.lower", "3", "greater than upper"),
        ("mpc.reference.signal", "", "signal"),
        ("verify.initial_input", "0 0", "initial_input"),
        ("verify.reference", "{ lower = [0.9], upper = [1.5] }", "reference"),
        ("verify.max_samples", "0", "max_samples"),
        ("verify.time_horizon", "forever", "time_horizon"),
    ],
)
def test_bad_values_of_the_new_fields_are_pinned_on_their_entry(field, text, words):
    key, msg = _one_error(_servo_check(**{field: text}))
    assert key == field, (key, msg)
    assert words in msg or words in key, msg


@pytest.mark.parametrize(
    ("field", "text"),
    [
        ("plant.disturbances", "w = [1]"),
        ("plant.disturbances", "{ w = [1, 0] }"),
        ("plant.nominal", "w = 500"),
        ("plant.E", "1; 1; 1"),
    ],
)
def test_bad_uncertain_plant_entries_are_pinned_on_their_entry(field, text):
    values, has_verify = form_from_text(
        (ROOT / "examples" / "cruise_grade.toml").read_text(encoding="utf-8")
    )
    assert check_form(values, with_verify=has_verify).ok
    values[field] = text
    key, _ = _one_error(check_form(values, with_verify=has_verify))
    assert key == field


def test_toml_value_is_the_engines_writer_in_a_readable_layout():
    """The form writes through the engine's one TOML writer, in a person's layout:
    characters outside ASCII as they are, a list of tables one per line, DEL escaped."""
    from codev_engine.io.toml import toml_literal

    tables = [{"h": [1.0]}, {"h": [2.0]}]
    assert toml_value(tables) == "[\n  { h = [1.0] },\n  { h = [2.0] },\n]"
    assert toml_value("\u00fc") == '"\u00fc"' and toml_literal("\u00fc") == '"\\u00fc"'
    for value in (tables, "a\x7fb", {"k y": "\u00fc"}):
        assert tomllib.loads("v = " + toml_value(value))["v"] == value
