"""Long horizons scale with the horizon, not with the branches (issue 26).

The linear engine merges the sets of one sample that lie in one region (a sound template
hull) and stops at an invariance certificate: a set anchored at a sample (the hull of the
sample's sets and a small box around the operating point) into which every set of a later
sample falls; the tube then repeats with that period. Checked here by dense simulation
(every simulated state in an active box of the tube, the repeated part included) and by the
certificate recorded in the result. Speed targets live in benchmarks/long_horizon.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_verify import _initial_states, _outside

import codev_engine as ce
from codev_engine.reach.linear import LinearReach, affine_plant
from codev_engine.reach.simulate import simulate_many, violations_many
from codev_engine.reach.verification import VerificationResult, verify
from tests.di_variants import DI_PATH


def _di(horizon: float, norm: str = "inf", N: int = 2, extra=()) -> ce.Problem:
    text = DI_PATH.read_text()
    pairs = [("time_horizon = 9.0", f"time_horizon = {horizon}"), *extra]
    if norm != "inf":
        pairs.append(('norm = "inf"', f'norm = "{norm}"'))
    if N != 2:
        pairs.append(("horizon = 2\n", f"horizon = {N}\n"))
    for old, new in pairs:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return ce.loads_spec(text, path="<long horizon>")


def _assert_tube_holds(problem, law, result, n_states=60, dt=0.005):
    vs = problem.verify
    X0 = _initial_states(vs.initial_lower, vs.initial_upper, n_states, n_states // 2)
    t, X, U, alive = simulate_many(problem, law, X0, hold=result.hold, dt=dt, dt_out=0.37)
    bad, _ = violations_many(problem, t, X, U, alive)
    assert not bad.any(), "a simulated trajectory contradicts robustly_safe"
    res = _outside(result.tube, t, X)
    assert res["count"] == 0, f"states outside the tube: {res}"
    assert res["gap_count"] == 0, f"times without a tube box: {res['gap_times'][:5]}"
    assert result.tube.t_end.max() >= vs.time_horizon - 1e-9


@pytest.fixture(scope="module")
def di_long():
    problem = _di(200.0)
    law = ce.synthesize(problem)
    return problem, law, verify(problem, law)


def test_a_long_horizon_closes_with_an_invariance_certificate(di_long, tmp_path):
    problem, law, result = di_long
    assert (result.verdict, result.reason) == ("robustly_safe", None), result.summary()
    cert = result.stats["certificate"]
    assert cert["kind"] == "invariant"
    assert 0 <= cert["anchor_sample"] < cert["closed_sample"]
    assert cert["period"] == pytest.approx(
        (cert["closed_sample"] - cert["anchor_sample"]) * problem.model.sample_time
    )
    # far fewer branches than samples x regions: the horizon no longer multiplies them
    assert result.stats["branches"] < 200
    # the certificate survives a save and a load (it is part of the stats)
    result.save(tmp_path / "r.npz")
    assert VerificationResult.load(tmp_path / "r.npz").stats["certificate"] == cert


def test_the_repeated_tube_holds_every_trajectory(di_long):
    # 200 s: about ten times the certificate's time, the repeated tube included
    problem, law, result = di_long
    _assert_tube_holds(problem, law, result)


def test_merged_branches_hold_every_trajectory():
    # norm 1, N = 10: 224 regions; the sets of one sample that meet one region are merged
    problem = _di(9.0, norm="1", N=10)
    law = ce.synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.stats.get("merges", 0) > 0
    _assert_tube_holds(problem, law, result, n_states=120, dt=0.002)


def test_a_possible_violation_on_a_merged_set_is_decided_exactly():
    """The merged run stops at a possible violation on a merged set; the exact run (every
    branch kept) decides, so merging never turns a verdict into unknown."""
    # a safe set (x2 <= 0.6) the trajectories leave: the merged run meets it first
    tight = _di(12.0, extra=[("upper = [10.0, 10.0]", "upper = [10.0, 0.6]")])
    law = ce.synthesize(tight)
    merged = verify(tight, law)
    assert "merged_attempt" in merged.stats  # the merged run gave way to the exact one
    exact = LinearReach(tight, law, affine_plant(tight), "continuous", 6, merge=False)
    exact.run()
    assert any(f.alpha is not None for f in exact.findings)
    assert (merged.verdict, merged.reason) == ("unsafe", "safe"), merged.summary()
    assert merged.counterexample is not None


# ---------------------------------------------------------------------------------------
# safety for all time: time_horizon = "inf"
# ---------------------------------------------------------------------------------------


def _di_inf(extra: str = "") -> ce.Problem:
    text = DI_PATH.read_text().replace("time_horizon = 9.0", 'time_horizon = "inf"' + extra)
    return ce.loads_spec(text, path="<double integrator for all time>")


@pytest.fixture(scope="module")
def di_inf():
    problem = _di_inf()
    law = ce.synthesize(problem)
    return problem, law, verify(problem, law)


def test_the_spec_takes_an_infinite_horizon_and_max_samples():
    p = _di_inf()
    assert p.verify.time_horizon == np.inf and p.verify.max_samples == 1000
    assert _di_inf("\nmax_samples = 15").verify.max_samples == 15
    with pytest.raises(ce.SpecError, match="max_samples"):
        _di_inf("\nmax_samples = 0")
    with pytest.raises(ce.SpecError, match="time_horizon"):
        ce.loads_spec(DI_PATH.read_text().replace("time_horizon = 9.0", 'time_horizon = "-inf"'))


def test_safety_for_all_time_by_an_invariance_certificate(di_inf, tmp_path):
    problem, law, result = di_inf
    assert (result.verdict, result.reason) == ("robustly_safe", "invariant"), result.summary()
    cert = result.stats["certificate"]
    assert "sample" in result.detail and str(cert["closed_sample"]) in result.detail
    C = result.certificate
    assert C is not None and C["H"].shape[1] == problem.plant.n
    # the tube stops at the certificate (it repeats from there)
    assert result.tube.t_end.max() == pytest.approx(cert["closed_time"])
    # stored with the result and re-checked by LP on load
    path = tmp_path / "forever.npz"
    result.save(path)
    back = VerificationResult.load(path)
    assert (back.verdict, back.reason) == ("robustly_safe", "invariant")
    assert np.array_equal(back.certificate["H"], C["H"])
    # a tampered certificate is refused
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["cert_h"] = arrays["cert_h"] - 1.0
    bad = tmp_path / "tampered.npz"
    np.savez(bad, **arrays)
    with pytest.raises(ce.SpecError, match="certificate"):
        VerificationResult.load(bad)


@pytest.mark.slow  # 50x the certificate's time simulated (~10 s); checked by default too
def test_the_certificate_holds_for_fifty_times_its_time(di_inf):
    """Simulate 50x the certificate's closing time from random initial states: no property
    is violated, and at every closing time t_k + m L every state is in the invariant set."""
    problem, law, result = di_inf
    cert = result.stats["certificate"]
    t_close, L = cert["closed_time"], cert["period"]
    T = 50 * t_close
    text = DI_PATH.read_text().replace("time_horizon = 9.0", f"time_horizon = {T}")
    long = ce.loads_spec(text, path="<50x>")
    vs = long.verify
    rng = np.random.default_rng(26)
    X0 = np.vstack(
        [_initial_states(vs.initial_lower, vs.initial_upper, 0, 0), rng.uniform(
            vs.initial_lower, vs.initial_upper, (40, problem.plant.n))]
    )
    t, X, U, alive = simulate_many(long, law, X0, hold=result.hold, dt=0.01, dt_out=0.5)
    bad, t_first = violations_many(long, t, X, U, alive)
    assert not bad.any(), f"violation at t = {t_first[np.argmax(bad)]}"
    H, h = result.certificate["H"], result.certificate["h"]
    checked = 0
    for m in range(int((T - t_close) / L) + 1):
        k = np.flatnonzero(np.isclose(t, t_close + m * L, atol=1e-9))
        if k.size == 0:
            continue
        x = X[:, k[0], :]
        assert np.all(x @ H.T <= h + 1e-9), f"a state outside the invariant set at t = {t[k[0]]}"
        checked += 1
    assert checked >= 10


def test_no_certificate_within_max_samples_is_unknown():
    problem = _di_inf("\nmax_samples = 15")
    result = verify(problem, ce.synthesize(problem))
    assert (result.verdict, result.reason) == ("unknown", "no_invariant"), result.summary()
    assert "max_samples = 15" in result.detail
    assert result.certificate is None


def test_the_recording_draws_the_certificate_set(di_inf, tmp_path):
    # the invariant set that closes the induction, read back from a real .rrd: its outline
    # on the plane is the certificate's polytope (every vertex on its rows), and it holds the
    # points the certificate rests on
    from matplotlib.path import Path as MPath

    from codev_engine.view.records import write_recording
    from tests.engine.test_records import read

    problem, law, result = di_inf
    summary = write_recording(tmp_path / "forever.rrd", problem, law, result)
    entities = read(summary.path)
    strip = np.array(entities["/plane/certificate"].per_row("LineStrips2D:strips")[0][0],
                     dtype=float)
    H, h = result.certificate["H"], result.certificate["h"]
    assert np.all(strip @ H.T <= h + 1e-6)
    on = np.abs(strip @ H.T - h) <= 1e-6 * (1 + np.abs(h))
    assert np.all(on.any(axis=1))  # each vertex on a row: the set itself, not a box
    inside = MPath(strip).contains_points(result.certificate["points"], radius=1e-6)
    assert inside.all()
    text = entities["/verdict"].per_row("TextDocument:text")[0][0]
    assert "certificate's set purple" in str(text)
