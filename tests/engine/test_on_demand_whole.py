"""A law on demand that knows its whole partition answers as the full law does, and a walk
on demand stops at the full synthesis' region limit (issue 39).

- a small law (the replay of the full search's start reaches its end) is ``complete`` once
  asked about a first set: its regions meeting a box, its located points and its domain
  are the full law's, in the full law's order, without LPs (``law_on_demand._whole_law``);
  a region cache loaded again is complete too (the mp-LP's facets crossed again);
- ``SolveOptions.max_regions`` and ``CODEV_LIMITS=region_bytes`` bound the regions computed
  on demand: the verification ends in ``unknown`` (``limit``) naming the count and the
  field, and the region cache written after it loads back.
"""

from __future__ import annotations

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.law_on_demand import OnDemandLaw
from codev_engine.mp.solve import SolveOptions
from codev_engine.pipeline import load_spec
from tests.conftest import EXAMPLES_DIR as EXAMPLES


def _full_index(law, od) -> np.ndarray:
    """For each region of ``od``, the index of the full law's region with its rows."""
    rows = {(a.tobytes(), b.tobytes()): i for i, (a, b) in enumerate(zip(law.A, law.b,
                                                                             strict=True))}
    return np.array([rows[(od.A[i].tobytes(), od.b[i].tobytes())]
                     for i in range(od.num_regions)])


# norm inf (an mp-LP, 10 regions) and norm 2 (an mp-QP, 27 regions)
@pytest.mark.parametrize("name", ["double_integrator.toml", "double_integrator_lqr.toml"])
def test_a_small_law_known_whole_answers_as_the_full_law(name, tmp_path):
    problem = load_spec(EXAMPLES / name)
    law = ce.synthesize(problem, simplify=False)
    od = OnDemandLaw(problem)
    assert not od.complete or od.num_regions == law.num_regions
    lo, hi = law.boxes[0].min(axis=0), law.boxes[1].max(axis=0)
    od.regions_meeting(lo, lo + 0.01 * (hi - lo))
    assert od.complete and od.num_regions == law.num_regions
    lps = od.stats["lps"]
    to_full = _full_index(law, od)
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = np.sort(rng.uniform(lo - 1, hi + 1, size=(2, law.n)), axis=0)
        # the same regions, in the same order
        assert np.array_equal(to_full[od.regions_meeting(a, b)], law.regions_meeting(a, b))
    X = rng.uniform(lo - 1, hi + 1, size=(500, law.n))  # (past the domain too)
    got, want = od.locate(X), law.locate(X)
    assert np.array_equal(got >= 0, want >= 0)
    assert np.array_equal(to_full[got[got >= 0]], want[want >= 0])
    assert np.array_equal(od.evaluate(X), law.evaluate(X), equal_nan=True)
    A, b = od.domain_rows(lo, hi)
    inside = np.all(X @ A.T <= b + 1e-9, axis=1)
    assert np.array_equal(inside, want >= 0)
    assert od.stats["lps"] == lps  # (no meeting test once the partition is known)
    # a region cache loaded again is known whole at once
    od.save(tmp_path / "regions.npz")
    again = OnDemandLaw.load(tmp_path / "regions.npz", problem)
    assert again.complete and again.num_regions == law.num_regions
    assert np.array_equal(again.locate(X), got)


def test_a_walk_on_demand_stops_at_max_regions(tmp_path):
    # magnetic_pointer_a: 40 regions computed on demand (1,008 in the full law), 32 of
    # them the replay's; at 36 the walk stops in the middle of the horizon
    problem = load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    od = OnDemandLaw(problem, options=SolveOptions(max_regions=36))
    result = ce.verify(problem, od)
    assert (result.verdict, result.reason) == ("unknown", "limit")
    assert "36 critical regions computed" in result.detail
    assert "max_regions" in result.detail
    assert od.num_regions == 36 and result.tube.num_boxes > 0
    assert result.tube.t_end.max() < problem.verify.time_horizon
    # (the cache the walk leaves is consistent: it loads back)
    od.save(tmp_path / "regions.npz")
    assert OnDemandLaw.load(tmp_path / "regions.npz", problem).num_regions == 36


def test_a_walk_on_demand_stops_at_the_region_bytes_limit(monkeypatch):
    # mass_spring_soft: 76 regions, all found by the replay; about 38 fit in 100 kB
    monkeypatch.setenv("CODEV_LIMITS", "region_bytes=1e5")
    problem = load_spec(EXAMPLES / "mass_spring_soft.toml")
    od = OnDemandLaw(problem)
    assert od.max_regions < 76
    result = ce.verify(problem, od)
    assert (result.verdict, result.reason) == ("unknown", "limit")
    assert f"{od.max_regions} critical regions computed" in result.detail
    assert "CODEV_LIMITS=region_bytes" in result.detail
    assert od.num_regions == od.max_regions


def test_pictures_of_a_law_over_theta_on_demand_draw_the_regions_reached(tmp_path):
    # dc_motor_servo: theta = (x, u_prev, r); the pictures draw a section of the regions
    # computed (a recording of it had ended in an AttributeError: no OnDemandLaw.section)
    import matplotlib

    matplotlib.use("Agg")
    from codev_engine.reach.simulate import theta_initial_box
    from codev_engine.view.figures import plot_partition
    from codev_engine.view.record_content import RecordingOptions
    from codev_engine.view.records import drawable
    from codev_engine.view.report import report_html

    problem = load_spec(EXAMPLES / "dc_motor_servo.toml")
    od = OnDemandLaw(problem)
    od.regions_meeting(*theta_initial_box(problem))  # (the first set a verification asks)
    law, _ = drawable(problem, od, RecordingOptions())
    assert law.n == problem.plant.n and law.num_regions == od.num_regions
    assert "regions reached (computed on demand)" in plot_partition(law).get_title()
    html = report_html(problem, od, None, traces=0)
    assert "The regions reached by the verification" in html
    assert "The partition of the explicit law" not in html

