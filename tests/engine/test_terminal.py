"""Safety for all time of a nonlinear plant: an invariant ellipsoid around the operating point
(``reach.terminal``) entered by the nonlinear engine's tube.

The oracle: dense simulation from random initial states over 50 times the certificate's
closing time: no violation, and at every sample after the closing one every state lies in
the ellipsoid; a tampered certificate is refused when the result is loaded.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from codev_engine.errors import SpecError
from codev_engine.pipeline import loads_spec
from codev_engine.reach.simulate import simulate_many, violations_many
from codev_engine.reach.terminal import terminal_ellipsoids
from codev_engine.reach.verification import VerificationResult, check_certificate, verify
from codev_engine.synthesis import synthesize

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _pendulum(horizon: str = '"inf"'):
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = re.sub(r"time_horizon = [0-9.]+", f"time_horizon = {horizon}", text)
    return loads_spec(text, path="<pendulum inf>")


def test_pendulum_ellipsoid_is_invariant_under_dense_simulation():
    # the ellipsoids alone (no reach run): from random states inside each, every sampled
    # state of the nonlinear loop stays inside, and no state between samples leaves its box
    problem = _pendulum()
    law = synthesize(problem)
    ells, why = terminal_ellipsoids(problem, law)
    assert ells, why
    rng = np.random.default_rng(0)
    Ts = float(problem.model.sample_time)
    for e in ells:
        L = np.linalg.cholesky(np.linalg.inv(e.P))
        z = rng.normal(size=(200, 2))
        z /= np.linalg.norm(z, axis=1, keepdims=True)
        X0 = e.centre + (z * rng.uniform(0.9, 1.0, (200, 1)) ** 0.5) @ L.T
        t, X, U, alive = simulate_many(problem, law, X0, hold="zoh", t_end=40 * Ts)
        for k in range(1, 41):
            idx = np.flatnonzero(np.abs(t - k * Ts) < 1e-9)[-1]
            d = X[:, idx] - e.centre
            assert np.all(np.einsum("pi,ij,pj->p", d, e.P, d) <= 1.0 + 1e-9)
        assert np.all(X >= e.box_lo - 1e-12) and np.all(X <= e.box_hi + 1e-12)
        bad, _ = violations_many(problem, t, X, U, alive)
        assert not bad.any()


@pytest.mark.slow
def test_pendulum_is_safe_for_all_time_and_50x_the_certificate_holds(tmp_path):
    # unknown / no_invariant before (certificates were for affine plants only)
    problem = _pendulum()
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", "invariant"), result.summary()
    c = result.stats["certificate"]
    assert c["kind"] == "ellipsoid"
    cert = result.certificate
    assert check_certificate(cert)
    Ts = float(problem.model.sample_time)
    tk = float(c["closed_time"])
    vs = problem.verify
    rng = np.random.default_rng(1)
    lo, hi = vs.initial_lower, vs.initial_upper
    corners = np.array([[a, b] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])])
    X0 = np.vstack([corners, rng.uniform(lo, hi, (36, 2))])
    T = 50 * tk
    t, X, U, alive = simulate_many(problem, law, X0, hold="zoh", t_end=T, dt=0.005,
                                   dt_out=Ts)
    bad, _ = violations_many(problem, t, X, U, alive)
    assert not bad.any()
    P, centre = np.asarray(cert["P"]), np.asarray(cert["centre"])
    for k in range(int(c["closed_sample"]), int(np.floor(T / Ts + 1e-9)) + 1):
        idx = np.flatnonzero(np.abs(t - k * Ts) < 1e-9)
        d = X[:, idx[-1]] - centre
        assert np.all(np.einsum("pi,ij,pj->p", d, P, d) <= 1.0)
    # saved and loaded: re-checked; a tampered certificate is refused
    result.save(tmp_path / "r.npz")
    back = VerificationResult.load(tmp_path / "r.npz")
    assert back.verdict == "robustly_safe" and check_certificate(back.certificate)
    moved = dict(cert, centre=centre + np.array([1.0, 0.0]))
    assert not check_certificate(moved)
    import numpy.lib.npyio  # noqa: F401  (the result file is an npz archive)

    data = dict(np.load(tmp_path / "r.npz", allow_pickle=False))
    data["cert_centre"] = data["cert_centre"] + np.array([1.0, 0.0])
    np.savez(tmp_path / "bad.npz", **data)
    with pytest.raises(SpecError):
        VerificationResult.load(tmp_path / "bad.npz")


def test_a_continuous_hold_gets_no_ellipsoid_and_says_why():
    problem = _pendulum()
    from dataclasses import replace

    problem = replace(problem, verify=replace(problem.verify, hold="continuous"))
    law = synthesize(problem)
    ells, why = terminal_ellipsoids(problem, law)
    assert ells == [] and "zoh" in why


def test_a_tube_that_has_not_entered_the_ellipsoid_is_unknown_no_invariant():
    # the pendulum's tube enters its ellipsoid at sample 41: within 30 samples it has not
    text = (EXAMPLES / "pendulum.toml").read_text()
    text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"\nmax_samples = 30', text)
    problem = loads_spec(text, path="<pendulum inf 30>")
    result = verify(problem, synthesize(problem))
    assert (result.verdict, result.reason) == ("unknown", "no_invariant"), result.summary()
    assert "did not enter an invariant ellipsoid" in result.detail
    assert result.certificate is None


def test_the_cstr_gets_no_ellipsoid_and_the_verdict_says_why():
    # an Arrhenius plant far from the origin: the a priori enclosures of the larger
    # ellipsoids meet T = 0 (-8750/T: an enclosure failure, not an error) and the smaller
    # ones have a linearisation error beyond the contraction: unknown / no_invariant, the
    # reason in the detail (before the expansion point and the catch: an exception)
    text = (EXAMPLES / "cstr.toml").read_text()
    text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"\nmax_samples = 20', text)
    problem = loads_spec(text, path="<cstr inf>")
    law = synthesize(problem)
    ells, why = terminal_ellipsoids(problem, law)
    assert ells == [] and why
    result = verify(problem, law)
    assert result.verdict in ("unknown", "unsafe")
    if result.verdict == "unknown":
        assert result.reason == "no_invariant"
        assert "no invariance certificate" in result.detail and why in result.detail


@pytest.mark.slow
def test_the_recording_of_the_pendulum_for_all_time_describes_its_ellipsoid(tmp_path):
    from codev_engine.view.records import write_recording
    from tests.engine.test_records import read

    problem = _pendulum()
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.reason == "invariant"
    entities = read(write_recording(tmp_path / "p.rrd", problem, law, result).path)
    text = str(entities["/verdict"].per_row("TextDocument:text")[0][0])
    assert "ellipsoid around the operating point" in text and "for all time" in text
    assert "/plane/certificate" not in entities  # (a polytope's outline only)
