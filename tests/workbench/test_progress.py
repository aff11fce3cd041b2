"""The command line's progress on stderr when it is not a terminal (issue 23): plain lines,
the first once a stage has run a second, then one per four seconds, and a closing line;
nothing for work shorter than a second or when turned off. The clock is the module's own
``time.monotonic``, set by the test."""

from __future__ import annotations

import io

import pytest

from workbench import progress


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    return now


def test_plain_lines_are_rate_limited_and_closed(clock):
    out = io.StringIO()
    with progress.stage_progress(True, stream=out, tty=False) as on_event:
        on_event("verification", "start", {})
        for t in (0.2, 0.9, 1.1, 2.0, 5.9, 6.2, 7.0):
            clock[0] = 100.0 + t
            on_event("verification", "progress", {"count": int(10 * t), "samples": 3})
        on_event("verification", "done", {"status": "computed"})
    assert out.getvalue().splitlines() == [
        "codev: verification: 11 branches, sample 3, 1 s",
        "codev: verification: 59 branches, sample 3, 6 s",
        "codev: verification: computed in 7.0 s",
    ]


def test_short_work_prints_nothing(clock):
    out = io.StringIO()
    with progress.stage_progress(True, stream=out, tty=False) as on_event:
        on_event("synthesis", "start", {})
        clock[0] += 0.5
        on_event("synthesis", "progress", {"count": 12})
        on_event("synthesis", "done", {"status": "computed"})
    assert out.getvalue() == ""


def test_turned_off_prints_nothing(clock):
    out = io.StringIO()
    with progress.stage_progress(False, stream=out, tty=False) as on_event:
        on_event("synthesis", "start", {})
        clock[0] += 10
        on_event("synthesis", "progress", {"count": 12})
    assert out.getvalue() == ""


def test_describe_names_counts_samples_and_boxes():
    assert progress.describe({"count": 1234}, "regions") == "1,234 regions"
    text = progress.describe({"count": 8, "samples": 12, "boxes": 4000}, "branches")
    assert text == "8 branches, sample 12, 4,000 boxes"
    text = progress.describe({"count": 8, "samples": 2, "regions": 1500}, "branches")
    assert text == "8 branches, sample 2, 1,500 regions computed"


def test_verification_on_demand_reports_the_regions_computed_so_far(tmp_path):
    # (issue 39: the TUI's and the command line's progress show them live)
    from codev_engine.pipeline import loads_spec
    from codev_engine.session import RunOptions, Session
    from tests.engine.test_on_demand import _random_spec

    problem = loads_spec(_random_spec(0) + '\n[synthesis]\nregions = "reached"\n',
                         check_mpc=False)
    seen: list[dict] = []
    Session.create(tmp_path / "s").run(
        problem, RunOptions(upto="verification"),
        on_event=lambda stage, event, data: seen.append(data)
        if (stage, event) == ("verification", "progress") else None)
    regions = [d["regions"] for d in seen]
    assert regions and regions == sorted(regions) and regions[-1] > 0
