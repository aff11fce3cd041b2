"""Hostile inputs end in one line, never a traceback, a warning or a silent hang (issue 37).

Each case was reproduced on main: a 400-digit TOML integer (``OverflowError``), a 5001-digit
one (tomllib's ``ValueError``), a 310-digit integer in a dynamics expression, a parameter
box that makes the dynamics undefined (``KeyError: 'ComplexInfinity'``), a disturbance box
of +-1e308 (RuntimeWarnings, then ``OverflowError``), ``horizon = 10**30`` with
``control_horizon = 1`` (``Maximum allowed dimension exceeded``; 1e5..1e9 allocated for
20 s first), an overflowing prediction (RuntimeWarnings, then an error naming the program's
``H``), ``tanh`` nested 10 deep (36 s in the loader), and runs without end or word
(``--traces 300000``, a journal's ``traces = 1e9``, a long synthesis under ``--json``).

The contract is about the terminal, so most cases run the real ``codev`` process: exit
status 2 for bad input (one line naming the file and the field), 1 for a limit reached
while running, and stderr without "Traceback" or "Warning".
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from cli_process import run_codev

from codev_engine import SpecError, load_spec, loads_spec, synthesize
from codev_engine.limits import TimeLimitError, deadline
from codev_engine.pipeline import program_bytes
from codev_engine.plant import linearize
from codev_engine.reach.verification import verify
from codev_engine.spec.expr import make_symbol, parse_expression

ROOT = Path(__file__).resolve().parents[2]
DI_PATH = ROOT / "examples" / "double_integrator.toml"
DI = DI_PATH.read_text(encoding="utf-8")
DYN = 'dynamics = ["x2", "u"]'


def _nested(depth: int, fn: str = "tanh") -> str:
    text = "x1"
    for _ in range(depth):
        text = f"{fn}({text})"
    return text


def _one_line(out, status: int, *needles: str) -> str:
    """The process ended with ``status`` and one clean error line holding ``needles``."""
    assert out.returncode == status, (out.returncode, out.stderr)
    assert "Traceback" not in out.stderr and "Warning" not in out.stderr, out.stderr
    errors = [ln for ln in out.stderr.splitlines() if ln.startswith("codev: error:")]
    assert len(errors) == 1, out.stderr
    for needle in needles:
        assert needle in errors[0], errors[0]
    return errors[0]


# --- bad input: one line naming the field, exit 2 (checked on the loader, fast) -------------

FIELD_CASES = [
    # a TOML integer of 400 digits in a number field
    ("400 digits", DI.replace("R = [[0.8]]", f"R = [[1{'0' * 399}]]"), "mpc.R[0][0]"),
    ("400 digits, count", DI.replace("horizon = 2\n", f"horizon = 1{'0' * 399}\n"),
     "mpc.horizon"),
    ("310 digits in an expression",
     DI.replace(DYN, f'dynamics = ["x2", "u + {1}{"0" * 309}*x1"]'), "plant.dynamics[1]"),
    ("undefined nominal parameter",
     DI.replace(DYN, 'dynamics = ["x2", "(u - x1)/k"]\nparameters = { k = [0, 0] }'),
     "plant.parameters"),
    ("disturbance box of +-1e308",
     DI.replace(DYN, 'dynamics = ["x2", "u + w"]\ndisturbances = { w = [-1e308, 1e308] }'),
     "plant.disturbances.w"),
    ("horizon 1e30, control_horizon 1",
     DI.replace("horizon = 2\n", f"horizon = 1{'0' * 30}\ncontrol_horizon = 1\n"),
     "mpc.horizon"),
    ("horizon 1e5, control_horizon 1",
     DI.replace("horizon = 2\n", "horizon = 100000\ncontrol_horizon = 1\n"), "mpc.horizon"),
]


@pytest.mark.parametrize(("text", "field"), [c[1:] for c in FIELD_CASES],
                         ids=[c[0] for c in FIELD_CASES])
def test_hostile_field_is_a_spec_error(text, field):
    # CPU seconds of this process, not the wall clock: a loaded machine stretches the
    # latter, not the work (the guard is against work, e.g. an allocation of 1e30 rows)
    t0 = time.process_time()
    with pytest.raises(SpecError) as err:
        loads_spec(text, path="bad.toml", check_mpc=False)
    assert err.value.field == field, str(err.value)
    assert str(err.value).startswith("bad.toml: "), str(err.value)
    assert "\n" not in str(err.value) and len(str(err.value)) < 400
    assert time.process_time() - t0 < 10  # refused before any allocation


def test_5001_digits_is_a_toml_error_with_its_line():
    text = DI.replace("R = [[0.8]]", f"R = [[1{'0' * 5000}]]")
    with pytest.raises(SpecError) as err:
        loads_spec(text, path="bad.toml", check_mpc=False)
    line = 1 + text[: text.index("R = [[1")].count("\n")
    assert f"at line {line}," in str(err.value) and "4,300 digits" in str(err.value)
    assert len(str(err.value)) < 300


def test_sweep_value_of_5001_digits_is_one_line():
    from codev_engine.sweeps.grid import parse_sets

    with pytest.raises(SpecError):
        parse_sets([f"mpc.horizon=1{'0' * 5000}"])


def test_expression_constants_must_fit_a_float():
    x = make_symbol("x")
    for text in ("10**400*x", "1e308*10*x", f"{10**309}*x"):
        with pytest.raises(SpecError, match="too large"):
            parse_expression(text, {"x": x})
    assert parse_expression("2**1000*x", {"x": x}) is not None  # 1e301 fits


def test_horizon_allocation_is_estimated_on_the_full_horizon():
    base = loads_spec(DI, check_mpc=False)
    long = DI.replace("horizon = 2\n", "horizon = 1500\ncontrol_horizon = 1\n")
    # the program's predictions grow with N^2 whatever the control horizon
    assert program_bytes(loads_spec(long, check_mpc=False)) > 1000 * program_bytes(base)


def test_overflowing_predictions_name_the_horizon_quietly(recwarn):
    text = (
        'name = "unstable"\n[plant]\nstates = ["x"]\ninputs = ["u"]\nA = [[10.0]]\n'
        "B = [[1.0]]\n[model]\nsample_time = 1.0\n[mpc]\nhorizon = 1000\n"
        'control_horizon = 1\nnorm = "2"\nx_min = [-1.0]\nx_max = [1.0]\n'
        "u_min = [-1.0]\nu_max = [1.0]\n"
    )
    with pytest.raises(SpecError) as err:
        loads_spec(text, path="u.toml")
    assert err.value.field == "mpc.horizon", str(err.value)
    big_q = text.replace("A = [[10.0]]", "A = [[0.5]]").replace(
        'norm = "2"', 'norm = "2"\nQ = [[1e308]]'
    )
    with pytest.raises(SpecError) as err:
        loads_spec(big_q, path="q.toml")
    assert err.value.field == "mpc.Q", str(err.value)
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


# --- the loader is polynomial in the expressions' size --------------------------------------


@pytest.mark.parametrize("fn", ["tanh", "sin", "cos", "sqrt", "abs", "atan"])
def test_nested_expressions_load_in_seconds(fn):
    """Depth 150 (the documented nesting limit is 200 syntax levels); 36 s at depth 10 of
    tanh on main (lambdify's dummies re-derived each node's assumptions)."""
    inner = _nested(150, fn).replace("x1", "0.1*x1 + 1")
    text = DI.replace(DYN, f'dynamics = ["x2", "{inner} + u"]')
    t0 = time.process_time()  # CPU seconds: the work, whatever the machine's load
    problem = loads_spec(text, check_mpc=False)
    Ac, Bc, f0 = linearize(problem.plant, [0.3, 0.0], [0.0])
    assert time.process_time() - t0 < 20
    assert np.all(np.isfinite(Ac)) and np.all(np.isfinite(f0))
    # the derivative by the chain rule, numerically
    h = 1e-6
    fp = linearize(problem.plant, [0.3 + h, 0.0], [0.0])[2]
    fm = linearize(problem.plant, [0.3 - h, 0.0], [0.0])[2]
    assert abs((fp[1] - fm[1]) / (2 * h) - Ac[1, 0]) < 1e-5 * max(1.0, abs(Ac[1, 0]))
    assert Bc[1, 0] == 1.0


def test_numeric_jacobian_matches_sympy_on_every_function():
    import sympy

    from codev_engine.plant import _compile

    names = {s: make_symbol(s) for s in ("x0", "numpy", "u")}  # names the code could clash
    texts = [
        "sin(x0)*cos(numpy) + u", "atan2(x0, numpy)*exp(u)", "sqrt(x0**2 + 1)*log(numpy**2 + 2)",
        "abs(x0)*sign(numpy) + max(x0, numpy, u) - min(x0, u)",
        "tanh(sinh(x0))/cosh(numpy) + asin(0.3*x0) + acos(0.2*u) + atan(numpy)",
        "x0**3*numpy**-2 + pi*e*u + tan(x0)", "(x0 + u)**2.5*sqrt(2)", "3",
    ]
    exprs = [parse_expression(t, names) for t in texts]
    args = tuple(names.values())
    f, J = _compile(exprs, args), _compile(exprs, args, wrt=args)
    ref_f = sympy.lambdify(args, exprs)
    jac = sympy.Matrix(exprs).jacobian(args)
    ref_J = sympy.lambdify(args, [e.replace(sympy.DiracDelta, lambda *a: 0) for e in jac])
    for z in ([0.4, -0.7, 0.2], [0.9, 0.3, 0.6]):
        np.testing.assert_allclose(np.array(f(*z), float), ref_f(*z), rtol=1e-13)
        np.testing.assert_allclose(np.array(J(*z), float), ref_J(*z), rtol=1e-12, atol=1e-14)


# --- the real process -----------------------------------------------------------------------

PROCESS_CASES = [
    ("400 digits", DI.replace("time_horizon = 9.0", f"time_horizon = 1{'0' * 399}"),
     "verify.time_horizon"),
    ("5001 digits", DI.replace("R = [[0.8]]", f"R = [[1{'0' * 5000}]]"), "invalid TOML"),
    ("undefined nominal parameter",
     DI.replace(DYN, 'dynamics = ["x2", "(u - x1)/k"]\nparameters = { k = [0, 0] }'),
     "plant.parameters"),
    ("horizon 1e30",
     DI.replace("horizon = 2\n", f"horizon = 1{'0' * 30}\ncontrol_horizon = 1\n"),
     "mpc.horizon"),
]


@pytest.mark.parametrize(("text", "needle"), [c[1:] for c in PROCESS_CASES],
                         ids=[c[0] for c in PROCESS_CASES])
def test_codev_refuses_hostile_specs_in_one_line(tmp_path, text, needle):
    spec = tmp_path / "bad.toml"
    spec.write_text(text, encoding="utf-8")
    out = run_codev("run", spec, "--json", cwd=tmp_path, timeout=120)
    _one_line(out, 2, "bad.toml", needle)
    assert out.stdout == ""


def test_option_values_are_bounded_where_read(tmp_path):
    out = run_codev("run", DI_PATH, "--traces", "300000", cwd=tmp_path, timeout=120)
    _one_line(out, 2, "--traces")
    out = run_codev("verify", DI_PATH, "--time-limit", "-1", cwd=tmp_path, timeout=120)
    _one_line(out, 2, "--time-limit")
    session = tmp_path / "s"
    shutil.copytree(ROOT / "sessions" / "double-integrator", session)
    journal = session / "journal.jsonl"
    journal.write_text(journal.read_text().replace('"traces": 16', '"traces": 1000000000'))
    out = run_codev("replay", session, "--json", cwd=tmp_path, timeout=120)
    _one_line(out, 2, "traces")


def test_a_synthesis_past_its_time_limit_is_one_line(tmp_path):
    """horizon = 500 on the double integrator ran past 60 s without a word under --json."""
    spec = tmp_path / "long.toml"
    spec.write_text(DI.replace("horizon = 2\n", "horizon = 500\n"), encoding="utf-8")
    t0 = time.perf_counter()
    out = run_codev("synth", spec, "--json", "--time-limit", "3", cwd=tmp_path, timeout=120)
    _one_line(out, 1, "time limit reached")
    assert out.stdout == ""
    assert time.perf_counter() - t0 < 60


def test_the_engine_stops_at_its_deadline():
    """Cooperatively: a verification past it is unknown (limit) with the time in its
    detail, a synthesis raises the one-line TimeLimitError."""
    text = DI.replace("time_horizon = 9.0", "time_horizon = 3000.0")
    problem = loads_spec(text, check_mpc=False)
    law = synthesize(problem)
    with deadline(0.3):
        result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "limit")
    assert "time limit of 0.3 s" in result.detail
    with deadline(1e-6), pytest.raises(TimeLimitError, match="time limit reached"):
        time.sleep(1e-3)
        synthesize(load_spec(DI_PATH))


def test_codev_limits_time_is_read(monkeypatch):
    from codev_engine.limits import limits

    monkeypatch.setenv("CODEV_LIMITS", "time=30")
    assert limits()["time"] == 30
    monkeypatch.setenv("CODEV_LIMITS", "time=-1")
    with pytest.raises(SpecError, match="CODEV_LIMITS"):
        limits()


def test_progress_under_json_goes_to_stderr_and_stdout_stays_json(tmp_path):
    """A silent stage still says it is alive (the heartbeat), on stderr."""
    import io

    from workbench.progress import stage_progress

    buf = io.StringIO()
    with (
        pytest.MonkeyPatch.context() as mp,
        stage_progress(True, {"synthesis": "regions"}, stream=buf, tty=False) as on_event,
    ):
        mp.setattr("workbench.progress.PLAIN_AFTER", 0.2)
        on_event("synthesis", "start", {})
        # no progress event at all: the heartbeat thread (it polls every 0.5 s) speaks;
        # waited for, not slept (a fixed 1.2 s left a loaded machine 0.7 s to run it)
        t0 = time.monotonic()
        while "codev: synthesis: 0 regions" not in buf.getvalue() and time.monotonic() - t0 < 60:
            time.sleep(0.05)
        on_event("synthesis", "done", {"status": "done"})
    assert "codev: synthesis: 0 regions" in buf.getvalue()
    out = run_codev("verify", DI_PATH, "--json", cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stderr
    json.loads(out.stdout)


def test_an_error_quoting_control_characters_cannot_drive_the_terminal(tmp_path):
    # an unknown field whose name holds an escape sequence, a bidi override and a line
    # separator: the error quotes it, escaped, on one line
    spec = tmp_path / "ctl.toml"
    spec.write_text(DI.replace("[model]\n", '[model]\n"x\\u001b[2J\\u202e\\u2028y" = 1\n'),
                    encoding="utf-8")
    out = run_codev("run", spec, cwd=tmp_path, timeout=120)
    line = _one_line(out, 2, "ctl.toml", "model.")
    assert "\x1b" not in out.stderr and "\u202e" not in out.stderr
    assert "\u2028" not in out.stderr, out.stderr
    assert "\\x1b" in line, line


def test_theta_names_are_distinct():
    # a state named prev_u beside an input u with rates would give theta two 'prev_u'
    text = DI.replace('states = ["x1", "x2"]', 'states = ["x1", "prev_u"]')
    text = text.replace(DYN, 'dynamics = ["prev_u", "u"]')
    text = text.replace("R = [[0.8]]", "R = [[0.8]]\nRd = [[0.1]]")
    with pytest.raises(SpecError, match="prev_u") as exc:
        loads_spec(text)
    assert exc.value.field == "plant.states"


def test_a_plant_whose_discretisation_overflows_is_one_line():
    # (held-out fuzzer: a 6.7e150 entry of plant.A made the discretised A infinite, and the
    # overflow message's eigenvalues raised LinAlgError)
    text = DI.replace(DYN, "A = [[0.0, 1.0], [0.0, 6.7e150]]\nB = [[0.0], [1.0]]")
    with pytest.raises(SpecError, match="overflow"):
        synthesize(loads_spec(text))


def test_a_sampled_model_that_overflows_names_the_sample_time(recwarn):
    # (the slow fuzzer: plant.A = [[2**63 - 1]] overflowed scipy's expm with five
    # RuntimeWarnings before the horizon's overflow message)
    text = DI.replace(DYN, "A = [[0.0, 1.0], [0.0, 9223372036854775807]]\nB = [[0.0], [1.0]]")
    with pytest.raises(SpecError, match="overflows") as exc:
        synthesize(loads_spec(text))
    assert exc.value.field == "model.sample_time"
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_a_finite_bound_past_1e100_is_refused_naming_it():
    # (the slow fuzzer: x_min = -1e308 overflowed the reduction's row normalisation, then
    # linprog refused its own input: an internal error)
    text = DI.replace("x_min = [-10.0, -10.0]", "x_min = [-1e308, -10.0]")
    with pytest.raises(SpecError, match="inf") as exc:
        loads_spec(text)
    assert exc.value.field == "mpc.x_min[0]"
