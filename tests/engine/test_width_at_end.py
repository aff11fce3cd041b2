"""The width at the end of the view is of a set that holds every simulated state there, and
says which set it is (reach.claim.width_at_end; CLI, --json, sweep rows; issue 40)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.reach.claim import (
    WIDTH_OF_LAST_BOX,
    WIDTH_OF_NONE,
    WIDTH_OF_REPEAT,
    certificate_band,
    width_at_end,
)
from codev_engine.reach.simulate import simulate_many
from codev_engine.sweeps.rows import _verified_row
from tests.di_variants import UNSAFE_ON_PATH
from workbench.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _states_at_end(problem, law, T: float, count: int = 48) -> np.ndarray:
    """Simulated states at ``T`` from the initial set's corners and random points (P, n)."""
    vs = problem.verify
    lo, hi = vs.initial_lower, vs.initial_upper
    corners = np.array(np.meshgrid(*zip(lo, hi, strict=True))).reshape(lo.size, -1).T
    rng = np.random.default_rng(40)
    X0 = np.vstack([corners, rng.uniform(lo, hi, (count, lo.size))])
    tr = simulate_many(problem, law, X0, t_end=T)
    assert np.all(tr.alive)
    k = int(np.argmin(np.abs(tr.t - T)))
    assert tr.t[k] == pytest.approx(T)
    return tr.X[:, k, :]


def _inside_boxes_at(result, T: float, x: np.ndarray) -> bool:
    lo, hi = result.tube.hull_at(T)
    return bool(np.all(x >= lo - 1e-9) and np.all(x <= hi + 1e-9))


def test_after_a_certificate_the_width_is_of_the_repeated_period(example_law):
    # mass-spring, T = 8 s: a certificate closes at 2 s and the tube repeats its period up
    # to T; the width is sound but not of the reach set at T, and says so
    problem, law = example_law("mass_spring_soft.toml")
    result = ce.verify(problem, law)
    band = certificate_band(result)
    assert result.verdict == "robustly_safe" and band is not None and band.t_closed < 8.0
    T, width, which = width_at_end(problem, result)
    assert T == 8.0 and which == WIDTH_OF_REPEAT
    assert np.allclose(width, result.width_at(T)) and np.all(np.isfinite(width))
    x = _states_at_end(problem, law, T)
    assert _inside_boxes_at(result, T, x)
    # the simulated states at T spread far less than the repeated box: why it is named
    assert np.all(np.ptp(x, axis=0) < 0.5 * width)
    # the sweep's row names the set as the CLI does
    row = _verified_row(problem, law, result, {})
    assert row["width_at_horizon_of"] == WIDTH_OF_REPEAT
    assert np.allclose(row["tube_width_at_horizon"], width)


def test_without_a_certificate_the_width_is_of_the_tubes_last_box(example_law, capsys):
    problem, law = example_law("double_integrator.toml")
    result = ce.verify(problem, law)
    assert result.verdict == "robustly_safe" and certificate_band(result) is None
    T, width, which = width_at_end(problem, result)
    assert T == 9.0 and which == WIDTH_OF_LAST_BOX
    # the boxes at T are each branch's last (they end at T): their hull holds every state
    assert np.all(result.tube.t_end[(result.tube.t_start <= T) & (T <= result.tube.t_end)]
                  == pytest.approx(T))
    x = _states_at_end(problem, law, T)
    assert _inside_boxes_at(result, T, x)
    assert np.all(np.ptp(x, axis=0) <= width + 1e-9)


def test_a_tube_stopped_by_a_violation_has_no_width_and_says_none(example_law, tmp_path,
                                                                   capsys):
    text = (EXAMPLES / "double_integrator.toml").read_text()
    spec = tmp_path / "unsafe.toml"
    spec.write_text(text[: text.index("[verify]")] + UNSAFE_ON_PATH)
    assert main(["verify", str(spec), "-q"]) == 1
    out = capsys.readouterr().out
    assert "width at t = 9 s: none (no box of the tube reaches it)" in out, out
    assert main(["verify", str(spec), "--json"]) == 1
    got = json.loads(capsys.readouterr().out)
    assert got["verdict"] == "unsafe" and got["width_at"] == {"t": 9.0, "of": WIDTH_OF_NONE}
    assert got["tube_width_at_horizon"] == [None, None]
