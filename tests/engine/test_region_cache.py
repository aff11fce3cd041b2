"""The region cache of a law on demand (issue 39, test (d)): saved and loaded, it gives the
same regions bit for bit and the same verification without evaluating a candidate again; a
cache that is damaged, edited or made for another MPC is refused (one line naming the file
and the array), and a session recomputes it, never trusts it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.law_on_demand import OnDemandLaw
from codev_engine.pipeline import load_spec
from codev_engine.session import Session
from tests.conftest import EXAMPLES_DIR as EXAMPLES

LQR = EXAMPLES / "double_integrator_lqr.toml"


@pytest.fixture(scope="module")
def grown(tmp_path_factory):
    """A law on demand grown by a verification of double_integrator_lqr, saved."""
    problem = load_spec(LQR)
    law = OnDemandLaw(problem)
    result = ce.verify(problem, law)
    path = tmp_path_factory.mktemp("cache") / "regions.npz"
    assert law.grown
    law.save(path)
    assert not law.grown
    return problem, law, result, path


def test_a_saved_cache_gives_the_same_regions_and_verification(grown):
    problem, law, result, path = grown
    again = OnDemandLaw.load(path, problem)
    assert again.num_regions == law.num_regions > 0
    for i in range(law.num_regions):
        assert np.array_equal(again.A[i], law.A[i]) and np.array_equal(again.b[i], law.b[i])
        assert np.array_equal(again.F[i], law.F[i]) and np.array_equal(again.G[i], law.G[i])
    mine = ce.verify(problem, again)
    assert mine.verdict == result.verdict
    assert np.array_equal(mine.tube.lower, result.tube.lower)
    assert np.array_equal(mine.tube.upper, result.tube.upper)
    # every region the verification needed came from the cache
    assert again.stats["candidates"] == 0 and not again.grown


def _rewrite(src, dst, **changes) -> None:
    data = dict(np.load(src, allow_pickle=False))
    data.update(changes)
    np.savez(dst, **data)


def test_a_damaged_or_foreign_cache_is_refused(grown, tmp_path):
    problem, _, _, path = grown
    data = np.load(path, allow_pickle=False)
    # one bit of a region's row: the checksum no longer holds
    b = data["reg_b"].copy()
    b[0] = np.nextafter(b[0], np.inf)
    _rewrite(path, tmp_path / "bit.npz", reg_b=b)
    with pytest.raises(SpecError, match="bit.npz: checksum: .*damaged or edited"):
        OnDemandLaw.load(tmp_path / "bit.npz", problem)
    # a region's kind forged to "empty" (a hole in the walk) with the checksum rewritten
    # to match is caught by the consistency of the arrays
    kind = data["kind"].copy()
    kind[int(np.flatnonzero(kind == 0)[0])] = 2
    forged = {k: data[k] for k in data.files if k not in ("format", "checksum")}
    forged["kind"] = kind
    from codev_engine.law_on_demand import _checksum

    _rewrite(path, tmp_path / "forged.npz", kind=kind, checksum=np.array(_checksum(forged)))
    with pytest.raises(SpecError, match="forged.npz: region: "):
        OnDemandLaw.load(tmp_path / "forged.npz", problem)
    # truncated, and not an npz at all
    raw = path.read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(SpecError, match="cut.npz"):
        OnDemandLaw.load(tmp_path / "cut.npz", problem)
    # another MPC (the horizon changed): its fingerprint is not this one's
    other = load_spec(EXAMPLES / "mass_spring_soft.toml")
    with pytest.raises(SpecError, match="fingerprint: made for another MPC"):
        OnDemandLaw.load(path, other)
    # a full law's file is not a region cache
    law_file = tmp_path / "law.npz"
    ce.synthesize(problem).save(law_file)
    with pytest.raises(SpecError, match="unsupported region cache format"):
        OnDemandLaw.load(law_file, problem)


def test_a_session_reuses_the_cache_and_recomputes_a_damaged_one(tmp_path):
    spec = tmp_path / "lqr.toml"
    spec.write_text(LQR.read_text() + '\n[synthesis]\nregions = "reached"\n')
    problem = load_spec(spec)
    from codev_engine.session import RunOptions

    options = RunOptions(upto="verification")
    session = Session.create(tmp_path / "s")
    first = session.run(problem, options)
    cache = session.artifact_path("synthesis", first.stages[1].key)
    saved = OnDemandLaw.load(cache, problem)
    assert saved.num_regions == first.law.num_regions > 0  # written back after the run
    # another verification of the same MPC (deeper): the regions are the cache's
    deeper = session.run(problem, RunOptions(upto="verification", max_depth=3))
    assert [s.status for s in deeper.stages] == ["cached", "cached", "computed"]
    assert deeper.law.stats["candidates"] == 0
    assert deeper.result.verdict == first.result.verdict
    # one byte of the cache changed: the index's SHA-256 no longer matches, recomputed
    raw = bytearray(cache.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    cache.write_bytes(bytes(raw))
    said: list[str] = []
    again = session.run(problem, options, warn=said.append)
    assert again.stages[1].status == "computed" and "SHA-256" in said[0]
    assert again.result.verdict == first.result.verdict
    journal = [json.loads(x) for x in (tmp_path / "s" / "journal.jsonl").read_text().split("\n")
               if x]
    assert {r["outcome"]["regions"] for r in journal if r["stage"] == "synthesis"} == {"reached"}


def test_cli_session_with_regions_reached(tmp_path, capsys):
    from workbench.cli import main

    plain = tmp_path / "plain.toml"
    plain.write_text(LQR.read_text())
    code = main(["run", str(plain), "--session", str(tmp_path / "s"), "--regions", "reached"])
    err = capsys.readouterr().err
    assert code == 2 and 'write [synthesis] regions = "reached"' in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_a_session_of_an_mplp_reuses_its_cache(tmp_path):
    from codev_engine.session import RunOptions

    text = (EXAMPLES / "double_integrator.toml").read_text()  # (norm inf: an mp-LP)
    spec = tmp_path / "di.toml"
    spec.write_text(text + '\n[synthesis]\nregions = "reached"\n')
    problem = load_spec(spec)
    session = Session.create(tmp_path / "s")
    first = session.run(problem, RunOptions(upto="verification"))
    again = session.run(problem, RunOptions(upto="verification", max_depth=3))
    assert [s.status for s in again.stages] == ["cached", "cached", "computed"]
    assert again.law.stats["candidates"] == 0
    assert again.law.num_regions >= first.law.num_regions > 0


def test_a_law_past_its_region_limit_suggests_regions_reached():
    from codev_engine.errors import SolverError
    from codev_engine.mp.solve import SolveOptions

    with pytest.raises(SolverError, match=r"stopped past 5 critical.*--regions reached"):
        ce.synthesize(load_spec(LQR), options=SolveOptions(max_regions=5))
    # (norm inf: an mp-LP, computed on demand too)
    with pytest.raises(SolverError, match=r"stopped past 5 critical.*--regions reached"):
        ce.synthesize(load_spec(EXAMPLES / "double_integrator.toml"),
                      options=SolveOptions(max_regions=5))


def test_a_long_full_synthesis_suggests_regions_reached_once(monkeypatch, capsys):
    from workbench import cli

    monkeypatch.setattr(cli, "HINT_SECONDS", 0.0)
    monkeypatch.setattr(cli, "HINT_REGIONS", 2)
    assert cli.main(["verify", str(LQR)]) == 0
    err = capsys.readouterr().err
    assert err.count("--regions reached") == 1 and "critical regions after" in err
    # (norm inf: suggested too)
    cli.main(["verify", str(EXAMPLES / "double_integrator.toml")])
    assert capsys.readouterr().err.count("--regions reached") == 1


def test_pictures_say_the_regions_are_those_reached(grown):
    import matplotlib

    matplotlib.use("Agg")
    from codev_engine.view.figures import plot_partition
    from codev_engine.view.record_content import RecordingContent, RecordingOptions

    problem, law, result, _ = grown
    assert "regions reached (computed on demand" in plot_partition(law).get_title()
    content = RecordingContent.build(problem, law, result, RecordingOptions(traces=2), (0, 1))
    assert "reached (computed on demand; not the whole law)" in content.verdict_text()


def test_cli_records_the_regions_reached(tmp_path, capsys):
    from workbench.cli import main

    rrd = tmp_path / "od.rrd"
    assert main(["verify", str(LQR), "--regions", "reached", "--record", str(rrd),
                 "--traces", "2"]) == 0
    assert rrd.stat().st_size > 0 and "computed on demand" in capsys.readouterr().out
    code = main(["verify", str(LQR), "--regions", "reached", "--law", str(rrd)])
    assert code == 2 and "--law needs the whole law" in capsys.readouterr().err
