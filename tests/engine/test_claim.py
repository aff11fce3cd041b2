"""The claim of a verdict (codev_engine.reach.claim) and ``[verify] constraints = true``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.reach.claim import build_claim
from workbench.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
GRADE = (EXAMPLES / "cruise_grade.toml").read_text()


def _grade(*, x_max: str = "20.0", constraints: str | None = None, horizon: str = "5.0"):
    text = GRADE.replace("x_max = [20.0]", f"x_max = [{x_max}]")
    text = text.replace('time_horizon = "inf"', f"time_horizon = {horizon}")
    if constraints is not None:
        text = text.replace("[verify]\n", f"[verify]\nconstraints = {constraints}\n")
    return ce.loads_spec(text, path="grade.toml")


def test_claim_names_the_sets_the_time_the_hold_and_what_was_not_checked():
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    c = build_claim(problem)
    assert c.verdict is None and c.initial == ("v in [8, 9]",)
    assert c.uncertainty == ("disturbance signal w in [-98.1, 98.1] at every t",)
    assert c.checked[:2] == ("never enters unsafe set 0: v >= 11",
                             "never enters unsafe set 1: v <= 7")
    assert c.checked[2] == "the input stays within its bounds: F in [0, 1500]"
    assert "at every sample" in c.checked[3]  # zoh: the law is evaluated at samples only
    assert c.time.startswith("for all t >= 0") and c.hold.startswith("zoh")
    # the MPC's own bound on v is not a property of this verdict, and the claim says so
    (nc,) = c.not_checked
    assert "0 <= v <= 20" in nc and "constraints = true" in nc
    lines = c.lines()
    assert lines[0].startswith("- system: cruise-grade") and lines[-1].startswith("- NOT checked")


def test_claim_after_a_certificate_names_it():
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    result = ce.verify(problem, ce.synthesize(problem))
    assert result.reason == "invariant"
    assert "invariance certificate: every reach set at sample" in build_claim(problem, result).time


def test_constraints_true_checks_the_design_bounds_for_all_t():
    off, on = _grade(x_max="8.5"), _grade(x_max="8.5", constraints="true")
    assert not off.verify.constraints and off.verify.safe == ()
    assert on.verify.constraints and on.verify.input_bounds
    (box,) = on.verify.safe
    assert box.lower.tolist() == [0.0] and box.upper.tolist() == [8.5]
    claim = build_claim(on)
    assert "the design's hard bounds (safe set 0): 0 <= v <= 8.5" in " ".join(claim.checked)
    assert claim.not_checked == ()
    # the initial set [8, 9] crosses v = 8.5: off, only the law's domain at samples says so;
    # on, the bound itself is the violated property
    r_off = ce.verify(off, ce.synthesize(off))
    r_on = ce.verify(on, ce.synthesize(on))
    assert r_off.counterexample.kind == "undefined"
    assert (r_on.counterexample.kind, r_on.counterexample.index) == ("safe", 0)


def test_constraints_keep_a_safe_verdict_and_default_off_changes_nothing():
    on = _grade(constraints="true")
    assert ce.verify(on, ce.synthesize(on)).verdict == "robustly_safe"
    off, default = _grade(constraints="false"), _grade()
    assert not off.verify.constraints and off.verify.safe == default.verify.safe == ()
    assert off.verify.input_bounds == default.verify.input_bounds


def test_cli_prints_the_claim_and_its_json(tmp_path, capsys):
    spec = tmp_path / "grade.toml"
    spec.write_text(GRADE)
    assert main(["verify", str(spec), "-q"]) == 0
    out = capsys.readouterr().out
    assert "the claim:" in out and "  - checked: never enters unsafe set 0: v >= 11" in out
    assert "  - NOT checked: the design's bounds 0 <= v <= 20" in out
    assert main(["verify", str(spec), "--json"]) == 0
    claim = json.loads(capsys.readouterr().out)["claim"]
    assert claim["verdict"] == "robustly_safe" and claim["initial"] == ["v in [8, 9]"]
    assert len(claim["checked"]) == 4 and len(claim["not_checked"]) == 1


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.toml")))
def test_every_bundled_claim_states_time_initial_set_and_properties(name):
    problem = ce.load_spec(EXAMPLES / name)
    c = build_claim(problem)
    assert c.initial and c.checked and c.time.startswith("for all t")
    assert c.checked[-1].startswith("the law is defined")


def test_certificate_band_holds_simulated_states_long_after_the_tube_stops():
    # cruise_grade, "inf": the tube stops at the closing sample (3 s, the certificate
    # anchored again twice after 1 s: a band of 0.11 m/s, not the early anchor's 1.6); the
    # band must hold every state after it, for any grade profile -- simulated up to 40 s,
    # piecewise constant extreme and random grades
    from codev_engine.reach.claim import certificate_band, width_at_end
    from codev_engine.reach.simulate import simulate_many

    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    band = certificate_band(result)
    assert band is not None and band.t_closed <= 5.0
    assert np.all(band.upper - band.lower < 0.2)
    T, width, which = width_at_end(problem, result)
    assert which == "certificate band" and np.allclose(width, band.upper - band.lower)
    rng = np.random.default_rng(3)
    P, piece, t_end = 24, 0.5, 40.0
    X0 = rng.uniform(8.0, 9.0, (P, 1))
    W = np.where(rng.random((P, int(t_end / piece) + 1, 1)) < 0.5, -98.1, 98.1)
    W[:4] = rng.uniform(-98.1, 98.1, W[:4].shape)
    tr = simulate_many(problem, law, X0, t_end=t_end, dt_out=0.05,
                       disturbance=(piece, W, np.zeros((P, 0))))
    after = tr.t >= band.t_anchor
    x = tr.X[:, after, 0]
    assert np.all(tr.alive) and np.all(np.isfinite(x))
    assert x.min() >= band.lower[0] - 1e-9 and x.max() <= band.upper[0] + 1e-9


def test_units_label_the_axes_and_bad_units_are_one_line():
    from codev_engine.errors import SpecError
    from codev_engine.view import figures

    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    assert problem.plant.state_label(0) == "v (m/s)" and problem.plant.input_label(0) == "F (N)"
    result = ce.verify(problem, ce.synthesize(problem))
    ax = figures.figure_result(result, problem).axes[0]
    assert ax.get_ylabel() == "v (m/s)" and ax.get_xlabel() == "t (s)"
    with pytest.raises(SpecError, match="plant.state_units: expected 1 units"):
        ce.loads_spec(GRADE.replace('state_units = ["m/s"]', 'state_units = ["m/s", "m"]'))


def test_constraints_off_keeps_the_session_keys_and_on_changes_them():
    from codev_engine.session import RunOptions, stage_keys

    default, off, on = _grade(), _grade(constraints="false"), _grade(constraints="true")
    k = stage_keys(default, RunOptions())["verification"]
    assert stage_keys(off, RunOptions())["verification"] == k
    assert stage_keys(on, RunOptions())["verification"] != k


def test_to_toml_writes_the_flag_and_the_units_not_the_appended_sets():
    on = _grade(constraints="true")
    again = ce.loads_spec(on.to_toml())
    assert again.verify.constraints and len(again.verify.safe) == len(on.verify.safe) == 1
    assert again.plant.state_units == ("m/s",) and again == on
