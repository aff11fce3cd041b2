"""Work too large is refused before it starts (issue 23): one line naming the field, exit 2.

The specs are the bundled double integrator with one field typed wrong; before the limits,
``step = 1e-12`` ended in ``internal error (MemoryError ...)`` and the others ran for
minutes without end. Checked as a real ``codev run`` process.

Work that grows while it runs (``codev_engine.limits``: the regions of a synthesis, the
branches and tube boxes of a verification) stops at its limit: a synthesis with one line and
exit 1, a verification with the verdict ``unknown`` (reason ``"limit"``), exit 1. The limits
are lowered through ``CODEV_LIMITS`` so that they are reached in a second.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_process import run_codev

from codev_engine import SpecError, load_spec, loads_spec, synthesize
from codev_engine.pipeline import LIMITS
from codev_engine.reach.verification import verify
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
DI = (ROOT / "examples" / "double_integrator.toml").read_text(encoding="utf-8")

CASES = [
    ("step = 0.01", "step = 1e-12", "verify.step"),
    ("time_horizon = 9.0", "time_horizon = 1e9", "verify.time_horizon"),
    ("sample_time = 1.0", "sample_time = 1e-9", "verify.time_horizon"),
    ("horizon = 2\n", "horizon = 100000\n", "mpc.horizon"),
]


@pytest.mark.parametrize(("old", "new", "field"), CASES)
def test_too_large_is_a_field_error(old, new, field):
    with pytest.raises(SpecError) as err:
        loads_spec(DI.replace(old, new), check_mpc=False)
    assert err.value.field == field
    assert "exceeds the limit" in str(err.value)


def test_too_many_states_is_a_field_error():
    n = LIMITS["states"] + 1
    names = ", ".join(f'"x{i}"' for i in range(n))
    text = (
        f'name = "big"\n[plant]\nstates = [{names}]\ninputs = ["u"]\n'
        f"A = [{', '.join('[' + ', '.join(['0'] * n) + ']' for _ in range(n))}]\n"
        f"B = [{', '.join(['[1]'] * n)}]\n[model]\nsample_time = 1.0\n[mpc]\nnorm = 2\n"
    )
    with pytest.raises(SpecError) as err:
        loads_spec(text, check_mpc=False)
    assert err.value.field == "plant.states"


def test_the_bundled_examples_are_within_the_limits():
    for spec in sorted((ROOT / "examples").glob("*.toml")):
        loads_spec(spec.read_text(encoding="utf-8"), check_mpc=False)


@pytest.mark.parametrize(("old", "new", "field"), CASES[:2])
def test_codev_run_refuses_in_one_line(tmp_path, old, new, field):
    spec = tmp_path / "big.toml"
    spec.write_text(DI.replace(old, new), encoding="utf-8")
    out = run_codev("run", spec, "--session", tmp_path / "s", cwd=tmp_path, timeout=60)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and field in lines[0] and "exceeds the limit" in lines[0], lines
    assert "internal error" not in out.stderr and "Traceback" not in out.stderr


def test_a_verification_past_its_branch_limit_is_unknown(tmp_path):
    out = run_codev("verify", ROOT / "examples" / "double_integrator.toml", "--json",
                    cwd=tmp_path, timeout=120, env={"CODEV_LIMITS": "branches=3"})
    assert out.returncode == 1, out.stderr
    # progress stays on under --json (stderr, issue 37); never an error or a traceback
    assert all(ln.startswith("codev: verif") for ln in out.stderr.splitlines()), out.stderr
    payload = json.loads(out.stdout)
    assert (payload["verdict"], payload["reason"]) == ("unknown", "limit"), payload
    assert "more than 3 branches" in payload["detail"] and "verify." in payload["detail"]


@pytest.mark.slow
def test_a_verification_past_its_tube_memory_is_unknown(monkeypatch):
    monkeypatch.setenv("CODEV_LIMITS", "tube_bytes=40000")
    problem = load_spec(ROOT / "examples" / "double_integrator.toml")
    result = verify(problem, synthesize(problem))
    assert (result.verdict, result.reason) == ("unknown", "limit")
    assert "the reachtube passed" in result.detail and "verify.step" in result.detail


def test_a_synthesis_past_its_region_memory_is_one_line(tmp_path):
    out = run_codev("run", ROOT / "examples" / "double_integrator.toml", "--session",
                    tmp_path / "s", cwd=tmp_path, timeout=120,
                    env={"CODEV_LIMITS": "region_bytes=1"})
    assert out.returncode == 1, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("codev: error: synthesis stopped past 1 "), lines
    assert "mpc.horizon" in lines[0] and "internal error" not in lines[0]


def test_a_bad_limit_override_is_bad_input(monkeypatch, capsys):
    monkeypatch.setenv("CODEV_LIMITS", "branches=-1")
    assert main(["synth", str(ROOT / "examples" / "double_integrator.toml")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "CODEV_LIMITS" in lines[0] and "branches" in lines[0], lines
