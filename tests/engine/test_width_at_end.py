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


def test_an_invariant_ellipsoid_s_box_is_the_width_for_all_time():
    # the pendulum for all time: its tube stops where each set enters the invariant
    # ellipsoid (closed at 2 s of the 2.5 s shown); the width there was "none", now the
    # ellipsoid's box c +- sqrt(diag(P^-1)), which holds every simulated state at every
    # sample after the closing one (up to 10 s), named in --json and the recording's summary
    import re

    from codev_engine.reach.claim import WIDTH_OF_ELLIPSOID, ellipsoid_box
    from codev_engine.view.record_content import RecordingContent, RecordingOptions
    from workbench.cli import _result_payload

    text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"',
                  (EXAMPLES / "pendulum.toml").read_text(encoding="utf-8"))
    problem = ce.loads_spec(text)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    cert = result.stats["certificate"]
    assert (result.reason, cert["kind"]) == ("invariant", "ellipsoid"), result.summary()
    T, width, which = width_at_end(problem, result)
    lo, hi = ellipsoid_box(result)
    assert T >= cert["closed_time"] and which == WIDTH_OF_ELLIPSOID
    assert np.allclose(width, hi - lo) and np.all(width > 0) and np.all(np.isfinite(width))
    # the box is the ellipsoid's: its support along each axis (a boundary point attains it)
    P, c = result.certificate["P"], result.certificate["centre"]
    for i in range(P.shape[0]):
        y = np.linalg.solve(P, np.eye(P.shape[0])[i])
        x = c + y / np.sqrt(y @ P @ y)  # on the boundary, extreme along axis i
        assert x[i] <= hi[i] and x[i] >= hi[i] - 1e-5 * (hi[i] - lo[i])
    vs = problem.verify
    rng = np.random.default_rng(38)
    X0 = rng.uniform(vs.initial_lower, vs.initial_upper, (100, P.shape[0]))
    Ts = problem.model.sample_time
    tr = simulate_many(problem, law, X0, t_end=10.0, dt_out=Ts)
    after = tr.X[:, tr.t >= cert["closed_time"] - 1e-9, :]
    assert np.all(tr.alive) and after.shape[1] > 150
    assert np.all(after >= lo) and np.all(after <= hi)
    # named wherever the width is shown: --json and the recording's / report's summary
    got = json.loads(json.dumps(_result_payload(problem, law, result, None, None)))
    assert got["width_at"] == {"t": T, "of": WIDTH_OF_ELLIPSOID}
    assert np.allclose(got["tube_width_at_horizon"], width)
    content = RecordingContent.build(problem, law, result, RecordingOptions(traces=2), (0, 1))
    assert f"| width at t = {T:.4g} s ({WIDTH_OF_ELLIPSOID}) |" in content.verdict_text()
