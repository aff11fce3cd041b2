"""Norms 1 and inf on demand (issue 39): the mp-LP's basis graph walked through the regions a
set meets (``mp.on_demand_lp``).

- bundled mp-LP examples (laws over theta = (x, u_prev, r) among them) and random mp-LP
  MPCs: ``verify`` on an ``OnDemandLaw`` against ``verify`` on the synthesised law (same
  verdict, tube and counterexample; every region computed one of the full law's, rows and
  law byte for byte);
- random boxes and polytopes in theta: every region of the full solution that meets the set
  is returned (by basis), and random points of the set lie in a returned region with the
  online optimum's input;
- the region cache of an mp-LP: read back the same, and refused when damaged.
"""

from __future__ import annotations

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.law_on_demand import OnDemandLaw
from codev_engine.mp.on_demand_lp import OnDemandBases
from codev_engine.mp.solve import mpsolve
from codev_engine.mpc import build_program
from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.plant import discretize
from tests.conftest import EXAMPLES_DIR as EXAMPLES
from tests.engine.test_on_demand import _meets, _random_spec

#: norm inf or 1; cruise_* and magnetic_pointer_a are laws over theta = (x, u_prev, r),
#: cruise_grade has a disturbance and an all-time certificate
FAST = ["double_integrator.toml", "cruise_control.toml", "cruise_grade.toml",
        "magnetic_pointer_a.toml"]
SLOW = ["cruise_loaded.toml", "magnetic_pointer_b.toml", "magnetic_pointer_c.toml",
        "navigation.toml", "vanderpol.toml"]  # (vanderpol: a nonlinear plant)


def _same_verification(problem, hold: str | None = None) -> None:
    law = ce.synthesize(problem, simplify=False)  # (merged regions are no basis's region)
    full = ce.verify(problem, law, hold=hold)
    od = OnDemandLaw(problem)
    mine = ce.verify(problem, od, hold=hold)
    assert law.meta["stats"]["mplp"] == "bases"
    assert mine.verdict == full.verdict and mine.reason == full.reason
    assert np.array_equal(mine.tube.t_start, full.tube.t_start)
    assert np.array_equal(mine.tube.lower, full.tube.lower)
    assert np.array_equal(mine.tube.upper, full.tube.upper)
    if full.counterexample is not None:
        assert np.array_equal(mine.counterexample.x0, full.counterexample.x0)
    assert 0 < od.num_regions <= law.num_regions
    rows = {(a.tobytes(), b.tobytes()): i for i, (a, b) in enumerate(zip(law.A, law.b,
                                                                             strict=True))}
    laws: dict[bytes, list[int]] = {}
    for j in range(law.num_regions):
        laws.setdefault(law.F[j].tobytes() + law.G[j].tobytes(), []).append(j)
    for i in range(od.num_regions):
        j = rows.get((od.A[i].tobytes(), od.b[i].tobytes()))
        if j is None:
            # (a weakly redundant row kept by one and not the other: the same set, the law
            # bit for bit, see mp/on_demand_lp.py)
            js = laws.get(od.F[i].tobytes() + od.G[i].tobytes(), [])
            assert any(_same_set(od.A[i], od.b[i], law.A[j], law.b[j]) for j in js), \
                f"region {i} is none of the full law's"
            continue
        assert np.array_equal(od.F[i], law.F[j]) and np.array_equal(od.G[i], law.G[j])


def _same_set(A1, b1, A2, b2, tol: float = 1e-10) -> bool:
    """Do ``A1 x <= b1`` and ``A2 x <= b2`` describe one polytope (each row's largest
    value over the other polytope within ``tol`` of its offset)?"""
    from codev_engine.geometry.polytope import solve_lp

    for (P, p), (Q, q) in (((A1, b1), (A2, b2)), ((A2, b2), (A1, b1))):
        for a, beta in zip(P, p, strict=True):
            x, st, _ = solve_lp(-a, Q, q)
            if st != "optimal" or a @ x > beta + tol * (1.0 + abs(beta)):
                return False
    return True


def _lp(seed: int, norm: str, unsafe: bool = False) -> str:
    text = _random_spec(seed, unsafe)
    return text.replace('norm = "2"', f'norm = "{norm}"').replace(f'name = "random{seed}"',
                                                                  f'name = "lp{seed}"')


@pytest.mark.parametrize("name", FAST)
def test_bundled_mplp_examples_verify_the_same_on_demand(name):
    _same_verification(load_spec(EXAMPLES / name))


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW)
def test_bundled_mplp_examples_verify_the_same_on_demand_slow(name):
    _same_verification(load_spec(EXAMPLES / name))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["double_integrator.toml", "vanderpol.toml"])
def test_bundled_mplp_examples_verify_the_same_on_demand_continuous_hold(name):
    _same_verification(load_spec(EXAMPLES / name), hold="continuous")


@pytest.mark.parametrize("seed,norm,unsafe", [(0, "inf", False), (1, "1", True)])
def test_random_mplp_mpcs_verify_the_same_on_demand(seed, norm, unsafe):
    _same_verification(loads_spec(_lp(seed, norm, unsafe), check_mpc=False))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2, 12))
def test_random_mplp_mpcs_verify_the_same_on_demand_slow(seed):
    norm = "inf" if seed % 2 else "1"
    _same_verification(loads_spec(_lp(seed, norm, unsafe=seed % 3 == 0), check_mpc=False))


def _cover(problem, seed: int, sets: int) -> None:
    from codev_engine.geometry.polytope import box_halfspaces
    from codev_engine.mp.reduce import parameter_box, reduce_program

    mp = build_program(problem.mpc, discretize(problem))
    sol = mpsolve(mp.program)
    assert sol.stats["mplp"] == "bases"
    od = OnDemandBases(mp.program)
    size = parameter_box(reduce_program(mp.program))
    rng = np.random.default_rng(seed)
    d = mp.d
    odd: set[tuple[int, ...]] = set()
    for k in range(sets):
        centre = rng.uniform(size.lo, size.hi)
        half = rng.uniform(0.02, 0.3) * (size.hi - size.lo)
        A, b = box_halfspaces(centre - half, centre + half)
        if k % 2:
            cut = rng.normal(size=(2, d))
            cut /= np.linalg.norm(cut, axis=1, keepdims=True)
            A, b = np.vstack([A, cut]), np.concatenate([b, cut @ centre + 0.1 * half.max()])
        returned = od.meeting(A, b)
        got = {od.regions[i].active for i in returned}
        want = {r.active for r in sol.regions if _meets(A, b, r.A, r.b)}
        assert want <= got, f"missing {want - got}"
        full = {r.active: r for r in sol.regions}
        for i in returned:  # the full solution's region of that basis, law bit for bit
            reg, ref = od.regions[i], full[od.regions[i].active]
            assert np.array_equal(reg.K, ref.K) and np.array_equal(reg.k, ref.k)
            if not (np.array_equal(reg.A, ref.A) and np.array_equal(reg.b, ref.b)):
                assert _same_set(reg.A, reg.b, ref.A, ref.b)
                odd.add(reg.active)
        pts = centre + rng.uniform(-1, 1, size=(200, d)) * half
        pts = pts[np.all(pts @ A.T <= b, axis=1)]
        pts = pts[sol.locate(pts) >= 0]
        for x in pts:
            hold = [i for i in returned
                    if np.max(od.regions[i].A @ x - od.regions[i].b) <= 1e-9]
            assert hold, f"a point of the set in no returned region: {x}"
            reg = od.regions[hold[0]]
            # (the law, not the whole optimizer: the first input is what the law applies)
            sl = mp.u0_slice
            assert np.allclose((reg.K @ x + reg.k)[sl], sol.primal(x[None])[0][sl], atol=1e-6)
    # (a weakly redundant row kept or not: 2 of magnetic_pointer_a's 905 regions walked)
    assert len(odd) <= 0.01 * len(od.regions)


@pytest.mark.parametrize("name", ["double_integrator.toml",
                                  pytest.param("magnetic_pointer_a.toml", marks=pytest.mark.slow)])
def test_regions_returned_cover_random_sets(name):
    _cover(load_spec(EXAMPLES / name), seed=1, sets=6)


@pytest.mark.parametrize("seed,norm", [(0, "inf"), (1, "1")])
def test_regions_returned_cover_random_sets_of_random_mplps(seed, norm):
    _cover(loads_spec(_lp(seed, norm), check_mpc=False), seed=seed, sets=6)


def test_mplp_region_cache_reads_back_and_refuses_damage(tmp_path):
    problem = load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    od = OnDemandLaw(problem)
    ce.verify(problem, od)
    path = od.save(tmp_path / "regions.npz")
    back = OnDemandLaw.load(path, problem)
    assert back.num_regions == od.num_regions
    for i in range(od.num_regions):
        assert np.array_equal(back.A[i], od.A[i]) and np.array_equal(back.F[i], od.F[i])
    assert ce.verify(problem, back).verdict == ce.verify(problem, od).verdict
    data = dict(np.load(path))
    data["reg_b"] = data["reg_b"] + 1e-3
    bad = tmp_path / "bad.npz"
    np.savez(bad, **data)
    with pytest.raises(SpecError, match="checksum"):
        OnDemandLaw.load(bad, problem)
