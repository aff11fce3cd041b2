"""``RegionArrays``: critical regions packed in flat arrays, the parameter set's rows held
once for the regions that share them; what they give back must be the regions they pack."""

from __future__ import annotations

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.geometry.locate import PointLocator
from codev_engine.mp import mpqp
from codev_engine.mp.solution import CriticalRegion, RegionArrays
from tests.engine.test_mpqp_graph import _program


def _random_regions(rng, n: int = 40, d: int = 3, nz: int = 2) -> list[CriticalRegion]:
    out = []
    for _ in range(n):
        r = int(rng.integers(0, 6))
        act = tuple(sorted(rng.choice(9, size=int(rng.integers(0, 4)), replace=False).tolist()))
        out.append(
            CriticalRegion(
                A=rng.normal(size=(r, d)), b=rng.normal(size=r), K=rng.normal(size=(nz, d)),
                k=rng.normal(size=nz), active=act,
            )
        )
    return out


def _same_region(r: CriticalRegion, s: CriticalRegion) -> None:
    assert r.active == s.active
    for x, y in ((r.A, s.A), (r.b, s.b), (r.K, s.K), (r.k, s.k)):
        np.testing.assert_array_equal(x, y)


def test_packed_regions_are_the_regions_they_pack():
    rng = np.random.default_rng(0)
    regs = _random_regions(rng)
    ra = RegionArrays.from_regions(regs)
    assert len(ra) == len(regs)
    for r, s in zip(regs, ra, strict=True):
        _same_region(r, s)
    _same_region(ra[-1], regs[-1])
    assert [r.active for r in ra[3:7]] == [r.active for r in regs[3:7]]
    with pytest.raises(IndexError):
        ra[len(regs)]
    # a permutation, and the regions again after them
    perm = rng.permutation(len(regs))
    both = RegionArrays.concat([ra.take(perm), ra])
    for r, i in zip(both, np.r_[perm, np.arange(len(regs))], strict=True):
        _same_region(r, regs[i])
    # the order by active set is the order of the tuples
    order = ra.active_order()
    assert [regs[i].active for i in order] == sorted(r.active for r in regs)
    np.testing.assert_array_equal(ra.num_rows(), [r.A.shape[0] for r in regs])


def test_implied_regions_give_back_their_shared_rows():
    rng = np.random.default_rng(1)
    regs = _random_regions(rng, n=5)
    SA, Sb = rng.normal(size=(2, 3)), rng.normal(size=2)
    ra = RegionArrays.from_regions(regs)
    implied = np.array([True, False, True, True, False])
    ra = RegionArrays(ra.A, ra.b, ra.offsets, ra.K, ra.k, ra.active, ra.active_offsets,
                      implied, SA, Sb)
    for i, r in enumerate(ra):
        A = np.vstack([regs[i].A, SA]) if implied[i] else regs[i].A
        b = np.concatenate([regs[i].b, Sb]) if implied[i] else regs[i].b
        np.testing.assert_array_equal(r.A, A)
        np.testing.assert_array_equal(r.b, b)
    np.testing.assert_array_equal(ra.num_rows(), [r.A.shape[0] for r in ra])
    other = RegionArrays(ra.A, ra.b, ra.offsets, ra.K, ra.k, ra.active, ra.active_offsets,
                         implied, SA + 1.0, Sb)
    with pytest.raises(ValueError, match="shared rows"):
        RegionArrays.concat([ra, other])


@pytest.fixture(scope="module")
def compiled_solution() -> ce.MpSolution:
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(mpqp, "JIT_AFTER", 0)
        return ce.mpsolve(_program(), options=ce.SolveOptions(workers=1))


def test_compiled_walk_holds_the_parameter_set_once(compiled_solution):
    """The compiled kernel puts the parameter set's rows last in every region: the walk
    keeps them once, and each region gives them back, bit for bit, at the end."""
    sol = compiled_solution
    ra = sol.regions
    assert sol.stats["jit"] is True and ra.implied.all()
    p = sol.program.A_theta.shape[0]
    assert ra.shared_A.shape == (p, sol.program.d)
    assert ra.A.shape[0] == ra.offsets[-1] == int(np.sum(ra.num_rows())) - p * len(ra)
    for r in ra:
        np.testing.assert_array_equal(r.A[-p:], ra.shared_A)
        np.testing.assert_array_equal(r.b[-p:], ra.shared_b)


def test_locating_with_shared_rows_is_locating_with_all_rows(compiled_solution, tmp_path):
    """The locator tests the shared rows once per point; brute force and the grid give what
    a locator on every region's whole rows gives, and so does a saved and loaded solution,
    in this format and in format 1 (every row in its region)."""
    sol = compiled_solution
    rng = np.random.default_rng(3)
    d = sol.program.d
    X = np.vstack([rng.uniform(-1.1, 1.1, (3000, d)), rng.uniform(-1.0, 1.0, (1000, d))])
    regs = list(sol.regions)
    ref = PointLocator([r.A for r in regs], [r.b for r in regs], grid=False).locate(X)
    assert np.any(ref >= 0) and np.any(ref < 0)
    ra = sol.regions
    for grid in (False, True):
        loc = PointLocator.packed(
            ra.A, ra.b, ra.offsets, shared=(ra.shared_A, ra.shared_b), implied=ra.implied,
            grid=grid,
        )
        np.testing.assert_array_equal(loc.locate(X), ref)
    np.testing.assert_array_equal(sol.locate(X), ref)
    loaded = ce.MpSolution.load(sol.save(tmp_path / "s.npz"))
    assert loaded.regions.implied.all()
    np.testing.assert_array_equal(loaded.locate(X), ref)
    np.testing.assert_array_equal(loaded.primal(X), sol.primal(X))
    # format 1: every row in its region
    with np.load(tmp_path / "s.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k not in ("implied", "shared_A", "shared_b")}
    full = RegionArrays.from_regions(regs)
    arrays.update(format=np.array("codev-mp-solution/1"), A=full.A, b=full.b,
                  offsets=full.offsets)
    np.savez(tmp_path / "v1.npz", **arrays)
    old = ce.MpSolution.load(tmp_path / "v1.npz")
    assert not old.regions.implied.any()
    for r, s in zip(old.regions, regs, strict=True):
        _same_region(r, s)
    np.testing.assert_array_equal(old.locate(X), ref)


def test_large_solutions_are_saved_uncompressed(compiled_solution, tmp_path, monkeypatch):
    """Above ``_COMPRESS_BELOW`` bytes a solution is written without deflate (zlib took
    minutes on gigabytes of rows); it reads back the same."""
    import zipfile

    from codev_engine.mp import solution as mpsolution

    small = compiled_solution.save(tmp_path / "small.npz")
    monkeypatch.setattr(mpsolution, "_COMPRESS_BELOW", 0)
    large = compiled_solution.save(tmp_path / "large.npz")
    with zipfile.ZipFile(small) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_DEFLATED}
    with zipfile.ZipFile(large) as z:
        assert {i.compress_type for i in z.infolist()} == {zipfile.ZIP_STORED}
    back = ce.MpSolution.load(large)
    for r, s in zip(back.regions, compiled_solution.regions, strict=True):
        _same_region(r, s)


def test_reading_a_float_array_makes_no_second_copy(monkeypatch):
    """Loading a solution checks its arrays in place: ``astype`` copied every one, which
    doubled a 13 GB solution (pop_mpqp_036) in memory; NaN is still found, chunk by chunk."""
    from codev_engine.io import npz as npzfile

    monkeypatch.setattr(npzfile, "_FINITE_CHUNK", 7)
    A = np.arange(60.0).reshape(20, 3)
    assert npzfile.real({"A": A}, "A", ndim=2) is A
    ints = np.arange(5)
    np.testing.assert_array_equal(npzfile.real({"i": ints}, "i"), ints.astype(float))
    A[17, 2] = np.nan
    with pytest.raises(ce.SpecError, match="non-finite"):
        npzfile.real({"A": A}, "A")
