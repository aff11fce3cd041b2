"""The sharded search's law keeps its domain in the shards (issue 43), and runs in balanced
units (issue 38) on a real Dask ``LocalCluster`` of 2 workers.

Each shard's facets of the feasible set ``D`` are in a checked side file; the manifest has
the parameter set's rows only. ``ShardedLaw.domain_rows(lo, hi)`` (the parameter set's rows
and the facets of the shards whose box meets the box) must hold on all of ``D`` and, when
the box meets ``D``, describe ``D`` in it: checked against the serial law's domain on
random boxes inside, across and outside it. A verification reads the domain near its sets
alone and gives the merged law's verdict and tube. A plant whose state axes are in units
far apart is solved sharded in balanced units and written in its own: the serial law.
"""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest
from scipy.optimize import linprog

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.law_shards import MANIFEST, ShardedLaw
from codev_engine.mp import mpqp, sharded
from tests.engine.test_law_shards import SPEC, _boxes_meeting

#: the spec with an initial set that leaves the MPC's feasible set (fast towards a wall)
WIDE = SPEC.replace("initial_set = { lower = [-0.5, -0.2], upper = [0.5, 0.2] }",
                    "initial_set = { lower = [3.5, 1.2], upper = [4.0, 1.6] }")


@pytest.fixture(scope="module")
def cluster():
    with ce.Executor(workers=2) as ex:
        yield ex


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    path = tmp_path_factory.mktemp("domain") / "t.toml"
    path.write_text(SPEC)
    return ce.load_spec(path)


@pytest.fixture(scope="module")
def serial(problem):
    return ce.synthesize(problem)


@pytest.fixture(scope="module")
def written(problem, cluster, tmp_path_factory):
    """The law of the sharded search (sharded from the first region), written by the
    workers."""
    out = tmp_path_factory.mktemp("law") / "law"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        mp.setattr(sharded, "BUDGET", 16)
        law = ce.synthesize(problem, executor=cluster, sharded=True, out_shards=out)
    assert isinstance(law, ShardedLaw) and law.shards == 2 and law.local_domain
    return law


def _support(A: np.ndarray, b: np.ndarray, a: np.ndarray) -> float:
    """max a'x over {A x <= b}."""
    res = linprog(-a, A_ub=A, b_ub=b, bounds=[(None, None)] * a.size, method="highs")
    assert res.status == 0
    return -res.fun


def test_domain_rows_describe_the_domain_in_a_box(written, serial):
    law = written
    dA, db = serial.domain_A, serial.domain_b
    norm = np.linalg.norm(dA, axis=1)
    # every row the law may answer holds on the whole domain (an LP each)
    A, b = law.domain_A, law.domain_b
    assert A.shape[0] > dA.shape[0] / 2
    for a, beta in zip(A, b, strict=True):
        assert _support(dA, db, a) <= beta + 1e-7
    # and the domain's facets are among them: the same set
    for a, beta in zip(dA, db, strict=True):
        assert _support(A, b, a) <= beta + 1e-7
    rng = np.random.default_rng(0)
    kinds: Counter = Counter()
    fewer = 0
    for _ in range(80):
        c = rng.uniform([-7.0, -3.0], [7.0, 3.0])
        r = rng.uniform(0.05, 1.5, 2)
        lo, hi = c - r, c + r
        A, b = law.domain_rows(lo, hi)
        fewer += A.shape[0] < law.domain_A.shape[0]
        X = rng.uniform(lo, hi, size=(300, 2))
        inside = np.all(X @ dA.T <= db + 1e-9, axis=1)
        ours = np.all(X @ A.T <= b + 1e-9, axis=1)
        assert np.all(ours[inside])  # (rows of the domain: no point of it is cut)
        if inside.any():  # the box meets D: its rows say which points are in D
            clear = np.min(np.abs(X @ dA.T - db) / norm, axis=1) > 1e-6
            np.testing.assert_array_equal(ours[clear], inside[clear])
            kinds["inside" if inside.all() else "across"] += 1
        else:  # (no point of it in D: the engine finds no region there, never "inside")
            assert np.all(law.locate(X) < 0)
            kinds["outside"] += 1
    assert min(kinds["inside"], kinds["across"], kinds["outside"]) >= 5, kinds
    assert fewer > 0  # (some boxes meet one shard: its facets alone are read)


def _unit(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rows ``[a, beta]`` scaled to unit ``a``."""
    norm = np.linalg.norm(A, axis=1, keepdims=True)
    return np.hstack([A, b[:, None]]) / norm


def test_domain_rows_hold_every_facet_that_meets_the_box(written, serial):
    """The guarantee ``domain_rows`` documents, with the shards skipped by their group
    boxes: every facet of the domain that meets the box (an LP each) is among the rows."""
    law = written
    dA, db = serial.domain_A, serial.domain_b
    theirs = _unit(dA, db)
    rng = np.random.default_rng(3)
    met = boxes = hits = 0
    for q in range(60):
        c = rng.uniform([-6.0, -2.5], [6.0, 2.5])
        if q % 2:  # (half of them about a point of the boundary: a facet's middle)
            f = rng.integers(dA.shape[0])
            ends = [linprog(s * np.array([1.0, 1.0]), A_ub=dA, b_ub=db, A_eq=dA[f:f + 1],
                            b_eq=db[f:f + 1], bounds=[(None, None)] * 2, method="highs").x
                    for s in (1.0, -1.0)]
            c = 0.5 * (ends[0] + ends[1]) + rng.normal(0.0, 0.05, 2)
        r = rng.choice([0.06, 0.3]) * np.array([1.0, 0.5])  # (1 % and 5 % of its box)
        lo, hi = c - r, c + r
        before = law.met
        A, b = law.domain_rows(lo, hi)
        met += law.met - before
        boxes += _boxes_meeting(law.dir, lo, hi)
        ours = _unit(A, b)
        for f in range(dA.shape[0]):
            # the facet {x in D : dA[f] x = db[f]} meets [lo, hi]?
            res = linprog(np.zeros(2), A_ub=dA, b_ub=db + 1e-12, A_eq=dA[f:f + 1],
                          b_eq=db[f:f + 1], bounds=list(zip(lo, hi, strict=True)),
                          method="highs")
            if res.status == 0:
                hits += 1
                assert np.min(np.abs(ours - theirs[f]).max(axis=1)) < 1e-7, (f, lo, hi)
    assert hits >= 20  # (boxes across the boundary)
    assert met < boxes, (met, boxes)  # (fewer shards than their boxes meet)


def test_the_manifest_holds_no_facet(written, tmp_path):
    """The manifest keeps the parameter set's rows and each shard's facet count; the facets
    are in checked files of their own, refused when edited."""
    folder = written.dir
    data = json.loads((folder / MANIFEST).read_text())
    assert "domain_A" not in data and "domain_b" not in data
    facets = [e["facets"] for e in data["shards"]]
    assert sum(facets) == data["meta"]["stats"]["domain_facets"] > 0
    # (the rows of the parameter set: its box and the MPC's bound, whatever the facets)
    assert np.asarray(data["parameter_set_A"]).shape[0] <= 2 * 2 + 2 * 2 * 2
    # a facets file edited after the fact is refused, naming it
    import shutil

    copy = tmp_path / "law"
    shutil.copytree(folder, copy)
    path = copy / data["shards"][0]["facets_file"]
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 2] ^= 1
    path.write_bytes(bytes(raw))
    with pytest.raises(SpecError, match=data["shards"][0]["facets_file"]):
        ShardedLaw(copy).domain_rows(np.full(2, -10.0), np.full(2, 10.0))


def test_a_verification_on_the_sharded_law_is_the_merged_law_s(written, problem, tmp_path):
    """A verification reads the domain near its sets (``domain_rows``): the verdict and
    tube of the merged law (the whole domain), inside the domain and leaving it."""
    merged = written.merged()
    verdicts = []
    for text in (SPEC, WIDE):
        path = tmp_path / "p.toml"
        path.write_text(text)
        p = ce.load_spec(path)
        law = ShardedLaw(written.dir)
        got, whole = ce.verify(p, law), ce.verify(p, merged)
        assert law._whole_domain is None  # (the domain near its sets alone was read)
        assert got.verdict == whole.verdict
        assert got.reason == whole.reason
        assert got.stats["partitions"] == whole.stats["partitions"]
        np.testing.assert_array_equal(got.tube.lower, whole.tube.lower)
        np.testing.assert_array_equal(got.tube.upper, whole.tube.upper)
        verdicts.append(got.verdict)
    # (the second leaves the domain: a finding, not a proof)
    assert verdicts[0] == "robustly_safe" != verdicts[1]


def test_the_nonlinear_engine_reads_the_domain_near_its_sets(cluster, tmp_path):
    """A nonlinear plant (a cubic drag): its engine asks ``domain_rows`` of a law whose
    domain is in its shards (``local_domain``), and gets the merged law's verdict and tube,
    inside the domain and for a set that leaves it."""
    nonlinear = SPEC.replace('A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]\n',
                             'dynamics = ["v", "u - 0.05 * v * v * v"]\n')
    assert nonlinear != SPEC
    path = tmp_path / "nl.toml"
    path.write_text(nonlinear)
    problem = ce.load_spec(path)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        mp.setattr(sharded, "BUDGET", 16)
        written = ce.synthesize(problem, executor=cluster, sharded=True,
                                out_shards=tmp_path / "law")
    merged = written.merged()
    verdicts = []
    for text in (nonlinear, nonlinear.replace(
            "initial_set = { lower = [-0.5, -0.2], upper = [0.5, 0.2] }",
            "initial_set = { lower = [3.5, 1.2], upper = [4.0, 1.6] }")):
        path.write_text(text)
        p = ce.load_spec(path)
        law = ShardedLaw(written.dir)
        got, whole = ce.verify(p, law), ce.verify(p, merged)
        assert "refinements" in got.stats  # (the nonlinear engine)
        assert law._whole_domain is None  # (the domain near its sets alone was read)
        assert (got.verdict, got.reason) == (whole.verdict, whole.reason)
        np.testing.assert_array_equal(got.tube.lower, whole.tube.lower)
        np.testing.assert_array_equal(got.tube.upper, whole.tube.upper)
        verdicts.append(got.verdict)
    assert verdicts[0] == "robustly_safe" != verdicts[1]


def test_a_plant_in_mm_and_km_per_s_is_written_in_its_units(cluster, tmp_path):
    """Issue 38's double integrator (x1 x1e3, x2 x1e-3), norm 2, synthesised as shards:
    searched in balanced units, written in the plant's (the serial law's function and
    domain); the fast case of the test below."""
    from test_scaled_units import scaled_case
    from test_synthesis_oracle import make_problem

    spec_s, model_s, *_ = scaled_case("di", "2", [3.0, -3.0])
    problem = make_problem(spec_s, model_s)
    serial = ce.synthesize(problem, model=model_s)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        law = ce.synthesize(problem, model=model_s, executor=cluster, sharded=True,
                            out_shards=tmp_path / "law")
    assert law.meta["stats"]["parameter_axes_scaled"] == 1
    X = np.random.default_rng(1).uniform([-1.2e4, -1.2e-2], [1.2e4, 1.2e-2], size=(2000, 2))
    inside = serial.locate(X) >= 0
    assert 0 < inside.sum() < X.shape[0]
    np.testing.assert_array_equal(law.locate(X) >= 0, inside)
    np.testing.assert_allclose(law.evaluate(X)[inside], serial.evaluate(X)[inside],
                               rtol=1e-7, atol=1e-9)
    A, b = law.domain_rows(X.min(axis=0), X.max(axis=0))
    clear = np.min(np.abs(X @ serial.domain_A.T - serial.domain_b)
                   / np.linalg.norm(serial.domain_A, axis=1), axis=1) > 1e-6
    np.testing.assert_array_equal(np.all(X @ A.T <= b + 1e-9, axis=1)[clear], inside[clear])


@pytest.mark.slow  # (two sharded searches of 743 regions: ~20 s on a loaded machine)
def test_the_sharded_search_in_balanced_units_is_the_serial_law(cluster, tmp_path):
    """A 4-parameter mp-QP with two axes rescaled by 2**-12 and 2**12 (widths 2**-11 and
    2**13): searched in its own units its sharded search lost half the regions (379 of
    743, points of the feasible set in none). The search runs in balanced units; the
    workers write the law in the program's (as the serial law: the same function at random
    points, no holes); so does the search without a writer."""
    from codev_engine.law_shard_writer import ShardWriter
    from codev_engine.mp.balance import balanced
    from tests.engine.test_mpqp_graph import _program

    p = _program()
    E = np.array([1.0, 2.0**-12, 2.0**12, 1.0])
    ps = balanced(p, 1.0 / E)  # (theta_s = E theta: columns times 1 / E, exact)
    serial = ce.mpsolve(p, options=ce.SolveOptions(workers=1))
    writer = ShardWriter(str(tmp_path / "law"), np.zeros(4), rows=(0, p.nz))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        mp.setattr(sharded, "BUDGET", 512)
        got = ce.mpsolve(ps, executor=cluster, sharded=True, shard_writer=writer)
        whole = ce.mpsolve(ps, executor=cluster, sharded=True)
    law = got.law
    assert law.shards == 2 and whole.num_regions == serial.num_regions > 700
    X = np.random.default_rng(2).uniform(-1.3, 1.3, size=(3000, 4))
    inside = serial.locate(X) >= 0
    assert 0 < inside.sum() < X.shape[0]
    for other in (law, whole):
        np.testing.assert_array_equal(other.locate(X * E) >= 0, inside)
    np.testing.assert_allclose(law.evaluate(X * E)[inside], serial.primal(X[inside]),
                               rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(whole.primal(X[inside] * E), serial.primal(X[inside]),
                               rtol=1e-7, atol=1e-9)
    # the domain in the program's units: the serial one's points inside, the others not
    A, b = law.domain_rows(np.full(4, -1.3) * E, np.full(4, 1.3) * E)
    clear = np.min(np.abs(X @ serial.domain_A.T - serial.domain_b)
                   / np.linalg.norm(serial.domain_A, axis=1), axis=1) > 1e-6
    ours = np.all((X * E) @ A.T <= b + 1e-9, axis=1)
    np.testing.assert_array_equal(ours[clear], inside[clear])
    # (axes 0 and 3, width 2, are narrower than axis 2 by more than 64 too)
    assert got.stats["parameter_axes_scaled"] == whole.stats["parameter_axes_scaled"] == 3
