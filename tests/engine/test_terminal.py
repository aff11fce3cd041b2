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
    # the pendulum's tube enters its ellipsoid at samples 35-40: within 30 samples it has not
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
    # the ellipsoid drawn on the plane (read back from the .rrd): its outline is the
    # ellipsoid's boundary ((y - c)' P (y - c) = 1 for n = 2) and holds the certificate's boxes
    from matplotlib.path import Path as MPath

    strip = np.array(entities["/plane/certificate"].per_row("LineStrips2D:strips")[0][0],
                     dtype=float)
    cert = result.certificate
    P, c = np.asarray(cert["P"]), np.asarray(cert["centre"])
    d = strip - c
    np.testing.assert_allclose(np.einsum("pi,ij,pj->p", d, P, d), 1.0, rtol=1e-4)  # (float32)
    assert strip.shape[0] > 40 and np.allclose(strip[0], strip[-1])
    corners = np.vstack([cert["lower"], cert["upper"],
                         np.column_stack([cert["lower"][:, 0], cert["upper"][:, 1]]),
                         np.column_stack([cert["upper"][:, 0], cert["lower"][:, 1]])])
    # (the polygon is inscribed in the ellipse: 1 % towards the centre clears its chords)
    assert MPath(strip).contains_points(c + 0.99 * (corners - c)).all()
    assert "invariant ellipsoid of the certificate purple" in text


def test_the_outline_of_an_ellipsoid_is_its_shadow_on_the_plane():
    # n = 3: the projection of {x : (x - c)' P (x - c) <= 1} on axes (0, 2) has, in every
    # direction l of the plane, the ellipsoid's support sqrt(l' P^-1 l) (lifted to 3-d)
    from codev_engine.reach.terminal import ellipsoid_outline

    rng = np.random.default_rng(3)
    R = rng.normal(size=(3, 3))
    P = R @ R.T + 0.5 * np.eye(3)
    c = np.array([0.3, -1.0, 2.0])
    ring = ellipsoid_outline(P, c, (0, 2), points=2001)
    assert ring.shape == (2001, 2) and np.allclose(ring[0], ring[-1])
    E = np.linalg.inv(P)
    for ang in np.linspace(0.0, np.pi, 7):
        lp = np.array([np.cos(ang), np.sin(ang)])
        l3 = np.array([lp[0], 0.0, lp[1]])
        support = float(l3 @ c + np.sqrt(l3 @ E @ l3))
        assert abs(float(np.max(ring @ lp)) - support) <= 1e-5 * (1 + abs(support))
    # one axis: the interval; not positive definite: None
    ends = ellipsoid_outline(P, c, (1,))
    np.testing.assert_allclose(ends[:, 0], c[1] + np.array([-1, 1]) * np.sqrt(E[1, 1]))
    assert ellipsoid_outline(-P, c, (0, 1)) is None


def test_each_set_of_the_tube_stops_where_it_enters_an_invariant_ellipsoid():
    # the nonlinear engine with absorb: a set whose box at a sample lies in an ellipsoid
    # is not followed further (the ellipsoid is invariant); every set of the pendulum's tube
    # enters one within 60 samples (none reaches the horizon), with fewer branches than the
    # tube followed to the horizon, and every simulated trajectory is, from the last
    # absorption's sample on, in the ellipsoid that holds every absorbed box
    from dataclasses import replace

    from codev_engine.reach.nonlinear import NonlinearReach
    from codev_engine.reach.terminal import ellipsoid_holds
    from codev_engine.reach.verification import _in_ellipsoids

    problem = _pendulum()
    law = synthesize(problem)
    ells, why = terminal_ellipsoids(problem, law)
    assert ells, why
    vs = problem.verify
    Ts = float(problem.model.sample_time)
    bounded = replace(problem, verify=replace(vs, time_horizon=60 * Ts))
    eng = NonlinearReach(bounded, law, "zoh", vs.max_depth, absorb=_in_ellipsoids(ells))
    eng.run()
    assert not eng.findings and eng.open_sets == 0 and eng.absorbed
    assert eng.absorb_mask is not None and eng.absorb_mask.any()
    e = ells[int(np.flatnonzero(eng.absorb_mask)[0])]
    for k, lo, hi in eng.absorbed:
        assert 0 < k < 60 and ellipsoid_holds(e.P, e.centre, lo[None], hi[None])
    plain = NonlinearReach(bounded, law, "zoh", vs.max_depth)
    plain.run()
    assert eng.stats["branches"] < plain.stats["branches"]
    last = max(a[0] for a in eng.absorbed)
    rng = np.random.default_rng(5)
    X0 = rng.uniform(vs.initial_lower, vs.initial_upper, (60, 2))
    t, X, _, _ = simulate_many(problem, law, X0, hold="zoh", t_end=80 * Ts, dt_out=Ts)
    for k in range(last, 81):
        d = X[:, np.flatnonzero(np.abs(t - k * Ts) < 1e-9)[-1]] - e.centre
        assert np.all(np.einsum("pi,ij,pj->p", d, e.P, d) <= 1.0)


def test_the_all_time_tube_holds_every_state_after_its_sets_enter_the_ellipsoid():
    # each set of the pendulum's all-time tube stops at the sample it enters the ellipsoid;
    # the ellipsoid's period box, active from the first entry on, keeps the tube's contract:
    # every simulated state, every 10 ms up to the tube's end, lies in an active box (without
    # that box 166 of ~9,000 did not)
    problem = _pendulum()
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", "invariant"), result.summary()
    assert result.stats["certificate"]["per_set"]
    tube = result.tube
    end = float(tube.t_end.max())
    vs = problem.verify
    rng = np.random.default_rng(11)
    X0 = rng.uniform(vs.initial_lower, vs.initial_upper, (45, 2))
    t, X, _, _ = simulate_many(problem, law, X0, hold="zoh", t_end=end, dt_out=0.01)
    outside = 0
    for k, tk in enumerate(t):
        sel = (tube.t_start <= tk + 1e-12) & (tk - 1e-12 <= tube.t_end)
        x = X[:, k, :]
        inside = np.any(np.all((x[:, None, :] >= tube.lower[sel][None] - 1e-9)
                               & (x[:, None, :] <= tube.upper[sel][None] + 1e-9), axis=2),
                        axis=1)
        outside += int((~inside).sum())
    assert outside == 0
