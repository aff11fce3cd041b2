"""The mp-LP basis graph (``mp/mplp_graph.py``) against the geometric explorer (``mplp.py``).

Both select the same optimizer at every parameter (the lexicographic rule: cost first,
then the explorer's fixed generic direction), so the two solutions must have the same
regions with the same laws: every region of one, at its Chebyshev centre, lies in a region
of the other with the same law ``z = K theta + k``, and the region counts agree. The
degenerate reproducers of ``test_mpsolve.py`` (dual- and primal-degenerate, inf-norm
ties, the soft penalty), random degenerate mp-LPs and paper MPCs with norms 1 and inf.
The dense comparison (more random programs, bigger MPCs) is ``slow``.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.geometry.polytope import chebyshev_ball
from codev_engine.mp import mplp_graph
from codev_engine.mpc import build_program
from codev_engine.pipeline import load_spec
from codev_engine.plant import discretize
from tests.engine.test_mpsolve import PROGRAMS, program

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(params=["numpy", "compiled"])
def kernel(request, monkeypatch):
    """The basis graph's numpy code throughout (small programs never reach ``JIT_AFTER``
    regions), or its compiled kernel (``mplp_kernel``) from the first basis on."""
    if request.param == "compiled":
        monkeypatch.setattr(mplp_graph, "JIT_AFTER", 0)
    else:
        monkeypatch.setattr(mplp_graph, "JIT_AFTER", 10**9)
    return request.param


def _solve(prog: ce.MpProgram, mode: str) -> ce.MpSolution:
    return ce.mpsolve(prog, options=ce.SolveOptions(mplp=mode))


def _same_laws(new: ce.MpSolution, old: ce.MpSolution) -> None:
    """Every region of each solution, at its centre, in a region of the other with the
    same law; and as many regions."""
    assert len(new.regions) == len(old.regions), (len(new.regions), len(old.regions))
    for a, b in ((new, old), (old, new)):
        for reg in a.regions:
            centre, radius = chebyshev_ball(reg.A, reg.b)
            assert radius > 0
            hits = [r for r in b.regions if np.all(r.A @ centre <= r.b + 1e-9)]
            assert hits, f"no region of the other solution at {centre}"
            z = reg.K @ centre + reg.k
            scale = 1.0 + float(np.max(np.abs(z)))
            assert any(np.allclose(r.K @ centre + r.k, z, atol=1e-7 * scale) for r in hits)
            tol = 1e-7 * (1 + np.abs(reg.K).max())
            law = [r for r in hits if np.allclose(r.K, reg.K, atol=tol)]
            assert law, f"no region with the same gain at {centre}"


@pytest.mark.parametrize(
    "name",
    ["lp_dual_degenerate", "lp_primal_degenerate", "lp_inf_norm", "lp_soft_penalty",
     "lp_equality", "random_lp0", "random_lp1", "random_lp3", "random_lp4"],
)
def test_basis_graph_gives_the_explorers_laws(name, kernel):
    prog = PROGRAMS[name]()
    new = _solve(prog, "auto")
    assert new.stats["mplp"] == "bases", new.stats.get("graph_fallback")
    assert new.stats.get("jit", False) == (kernel == "compiled")
    _same_laws(new, _solve(prog, "facets"))


def test_parameter_dependent_cost_goes_to_the_explorer():
    prog = PROGRAMS["lp_param_cost"]()
    assert _solve(prog, "auto").stats["mplp"] == "facets"
    with pytest.raises(ce.SolverError, match="C = 0"):
        _solve(prog, "bases")


def random_degenerate(seed: int) -> ce.MpProgram:
    """A random bounded mp-LP with a parameter-free cost and both degeneracies built in:
    repeated and scaled rows, rows through a common vertex (primal), and cost vectors
    parallel to rows (dual: whole edges optimal)."""
    rng = np.random.default_rng(seed)
    nz, d = int(rng.integers(2, 5)), int(rng.integers(1, 4))
    m = int(rng.integers(nz, 2 * nz + 2))
    A = rng.integers(-2, 3, size=(m, nz)).astype(float)
    A[np.all(A == 0, axis=1), 0] = 1.0
    F = rng.integers(-1, 2, size=(m, d)).astype(float)
    b = rng.integers(0, 3, size=m).astype(float)  # many rows through the origin
    A = np.vstack([A, 2.0 * A[:2], np.eye(nz), -np.eye(nz)])
    F = np.vstack([F, 2.0 * F[:2], np.zeros((2 * nz, d))])
    b = np.concatenate([b, 2.0 * b[:2], np.full(2 * nz, 2.0)])
    c = -A[int(rng.integers(0, m))].copy() if seed % 2 else rng.integers(-1, 2, nz).astype(float)
    return program(c=c, A=A, b=b, F=F, theta_lo=np.full(d, -1.0), theta_hi=np.full(d, 1.0))


@pytest.mark.parametrize("seed", range(8))
def test_random_degenerate_mp_lps(seed, kernel):
    prog = random_degenerate(seed)
    _same_laws(_solve(prog, "bases"), _solve(prog, "facets"))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(8, 58))
def test_random_degenerate_mp_lps_dense(seed, kernel):
    prog = random_degenerate(seed)
    _same_laws(_solve(prog, "bases"), _solve(prog, "facets"))


def _mpc(example: str, **mpc) -> ce.MpProgram:
    prob = load_spec(EXAMPLES / f"{example}.toml")
    prob = dataclasses.replace(prob, mpc=dataclasses.replace(prob.mpc, **mpc))
    return build_program(prob.mpc, discretize(prob)).program


@pytest.mark.parametrize(
    "example, mpc",
    [("double_integrator", {}), ("double_integrator", {"norm": "1", "horizon": 3}),
     ("cruise_control", {})],
)
def test_paper_mpcs_same_laws(example, mpc, kernel):
    prog = _mpc(example, **mpc)
    new = _solve(prog, "bases")
    _same_laws(new, _solve(prog, "facets"))


@pytest.mark.slow
@pytest.mark.parametrize(
    "example, mpc",
    [("magnetic_pointer_c", {}), ("navigation", {}), ("magnetic_pointer_a", {}),
     ("double_integrator", {"horizon": 8}), ("double_integrator", {"norm": "1", "horizon": 8})],
)
def test_paper_mpcs_same_laws_dense(example, mpc, kernel):
    prog = _mpc(example, **mpc)
    _same_laws(_solve(prog, "bases"), _solve(prog, "facets"))


def _di_problem(norm: str, horizon: int):
    prob = load_spec(EXAMPLES / "double_integrator.toml")
    return dataclasses.replace(prob, mpc=dataclasses.replace(prob.mpc, norm=norm, horizon=horizon))


@pytest.mark.slow
@pytest.mark.parametrize("norm, horizon", [("inf", 20), ("1", 8), ("inf", 8)])
def test_double_integrator_long_horizon_passes_the_oracle(norm, horizon):
    """The synthesis oracle (online MPC at random points and across facets) on the law the
    basis graph gives the double integrator."""
    from tests.engine.test_synthesis_oracle import _check, compare

    prob = _di_problem(norm, horizon)
    model = discretize(prob)
    sol = ce.mpsolve(build_program(prob.mpc, model).program)
    assert sol.stats["mplp"] == "bases"
    law = ce.synthesize(prob, model=model)
    _check(compare(f"di_{norm}_{horizon}", prob.mpc, model, law))


@pytest.mark.slow
@pytest.mark.parametrize("norm, horizon", [("1", 20), ("inf", 30)])
def test_explorer_fills_the_holes_of_skipped_pieces(norm, horizon):
    """Where the basis graph falls back, the geometric explorer skips facet pieces it takes
    for numerically flat; with norm 1 and N = 20 they bounded real holes (134 regions, 39
    of the oracle's points without a region). The law now covers them (or the search
    ends with the clear error): the synthesis oracle finds no hole. (Norm inf, N = 30,
    where the explorer also takes over, passed before: a guard of that path.)"""
    from tests.engine.test_synthesis_oracle import _check, compare

    prob = _di_problem(norm, horizon)
    model = discretize(prob)
    law = ce.synthesize(prob, model=model)
    _check(compare(f"di_{norm}_{horizon}", prob.mpc, model, law))


@pytest.mark.slow
def test_too_degenerate_mp_lp_names_what_to_change():
    """The double integrator with norm inf and N = 50: neither engine is exact there (the
    tail's slacks decay to rounding level); the error says what to change, never "could
    not identify a full-dimensional critical region"."""
    with pytest.raises(ce.SolverError, match="mpc.horizon"):
        ce.synthesize(_di_problem("inf", 50))


def _explore_counted(prog: ce.MpProgram, engine: str, stats: dict):
    """The explorer (``facets``) or the basis graph (``bases``) on ``prog`` as ``mpsolve``
    calls it, with its counters in ``stats``."""
    from codev_engine.mp.mplp import explore_facets
    from codev_engine.mp.reduce import parameter_box, reduce_program

    red = reduce_program(prog)
    size = parameter_box(red)
    opts = ce.SolveOptions()
    common = dict(region_tol=opts.region_tol * size.scale, lp_perturbation=opts.lp_perturbation,
                  seed=opts.seed, max_regions=opts.max_regions, stats=stats)
    if engine == "facets":
        return explore_facets(red, size, step=opts.step * size.scale, **common)
    return mplp_graph.explore_bases(red, size, **common)


@pytest.mark.parametrize(
    "norm, horizon, engine",
    [("inf", 50, "facets"), ("inf", 50, "bases"), ("1", 30, "facets"), ("inf", 60, "facets"),
     ("inf", 60, "bases")],
)
def test_beyond_double_precision_stops_at_once(norm, horizon, engine):
    """Issue 29: on the double integrator with a long horizon the optimal tail decays by
    0.6 a step, and the regions' boundaries (inf N = 50, norm 1 N = 30) or the
    lexicographic pivots (inf N = 60) are beyond double precision. Both engines used to
    go on for seconds to minutes (tens of thousands of Bland pivots, hundreds of LP
    solves) and end with "too degenerate" (the graph: fall back to the explorer); now
    each stops at the first such region or walk with the one-line error naming
    ``mpc.horizon``. The work is counted, not timed. (The graph falls back on norm 1,
    N = 30: its dual simplex cycles before it meets such a region.)"""
    prog = _mpc("double_integrator", norm=norm, horizon=horizon)
    stats: dict = {}
    with pytest.raises(ce.SolverError, match=r"too ill-conditioned.*mpc\.horizon.*norm"):
        _explore_counted(prog, engine, stats)
    from codev_engine.mp.mplp import REFINE_WORK

    nw = prog.A.shape[1]
    # one refinement at most, within its limit (before: 9,000-30,000 pivots)
    assert stats.get("lex_pivots", 0) <= max(nw + 100, REFINE_WORK / nw**3) + 1, stats
    assert stats.get("solves", 0) <= 200, stats


def test_boundary_uncertainty_separates_the_horizons():
    """The measure behind the early stop stays below ``PRECISION_LIMIT`` (by more than 10x)
    on every region of the double integrator with norm inf and N = 20, which solves."""
    from codev_engine.mp.mplp import PRECISION_LIMIT, boundary_uncertainty
    from codev_engine.mp.reduce import parameter_box, reduce_program

    red = reduce_program(_mpc("double_integrator", norm="inf", horizon=20))
    size = parameter_box(red)
    sol = _explore_counted(_mpc("double_integrator", norm="inf", horizon=20), "bases", {})
    assert len(sol) == 160
    worst = max(boundary_uncertainty(red, r.K, r.k, size.bound, size.scale) for r in sol)
    assert worst < 0.1 * PRECISION_LIMIT


def test_boundary_uncertainty_from_the_callers_products():
    """Given the region's rows and ``|G|, |S|, |w|`` (as the basis graph keeps them), the
    measure is the one it computes itself, bit for bit."""
    from codev_engine.mp.mplp import boundary_uncertainty
    from codev_engine.mp.reduce import parameter_box, reduce_program

    red = reduce_program(_mpc("magnetic_pointer_c"))
    size = parameter_box(red)
    absolute = (np.abs(red.G), np.abs(red.S), np.abs(red.w))
    sol = _explore_counted(_mpc("magnetic_pointer_c"), "bases", {})
    for r in sol:
        rows = (red.G @ r.K - red.S, red.w - red.G @ r.k)
        alone = boundary_uncertainty(red, r.K, r.k, size.bound, size.scale)
        given = boundary_uncertainty(red, r.K, r.k, size.bound, size.scale, rows=rows,
                                     absolute=absolute)
        assert given == alone


def sliver_program(delta: float) -> ce.MpProgram:
    """``min z`` with ``z >= 0, z >= t1, z >= 2 t1 - delta`` (and ``z <= 10``),
    ``t in [-1, 1]^2``: the law ``z = t1`` holds on the slab ``0 <= t1 <= delta`` only."""
    return program(c=[1.0], A=[[-1.0], [-1.0], [-1.0], [1.0]], b=[0.0, 0.0, delta, 10.0],
                   F=[[-1.0, 0.0], [0.0, 0.0], [-2.0, 0.0], [0.0, 0.0]],
                   theta_lo=[-1.0, -1.0], theta_hi=[1.0, 1.0])


@pytest.mark.parametrize("kernel_mode", ["numpy", "compiled"])
def test_sliver_thinner_than_region_tol_stays_on_the_graph(kernel_mode, monkeypatch):
    """A neighbour reached by the lexicographic pivots is full-dimensional in exact
    arithmetic; one thinner than ``region_tol`` (here 2e-9 for this parameter box) whose
    certified inscribed radius is far above its boundary's rounding is a real region (the
    magnetic pointer with N = 8 has ten, radius ~5e-9 near the box's face x2 = 10). The
    graph used to give up there ("a neighbour's region is lower-dimensional") and hand the
    program to the explorer, which drops such slivers (a hole) and on that MPC failed."""
    monkeypatch.setattr(mplp_graph, "JIT_AFTER", 0 if kernel_mode == "compiled" else 10**9)
    sol = _solve(sliver_program(3e-9), "auto")
    assert sol.stats["mplp"] == "bases", sol.stats.get("graph_fallback")
    assert sol.stats.get("slivers") == 1
    assert len(sol.regions) == 3
    # the slab's law at a point inside it (no other region holds that point)
    x = np.array([1.5e-9, 0.3])
    inside = [r for r in sol.regions if np.all(r.A @ x <= r.b)]
    assert len(inside) == 1
    reg = inside[0]
    assert np.allclose(reg.K @ x + reg.k, [x[0]], rtol=0, atol=1e-15)


@pytest.mark.slow
def test_magnetic_pointer_long_horizon_passes_the_oracle():
    """Issue 29's target: the magnetic pointer (norm inf) with N = 8, 8,706 regions on the
    basis graph (ten slivers thinner than ``region_tol``), where it used to fall back at
    1,390 regions and the explorer ended with "could not step across a facet" after
    5,248. The synthesis oracle on 400 random points and the facet probes, and HiGHS's
    optimum of the condensed LP at the centre of every region thinner than 1e-6 (98, the
    ten slivers among them)."""
    from scipy.optimize import linprog

    from codev_engine.synthesis import law_from_solution
    from tests.engine.test_synthesis_oracle import _check, compare

    prob = load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    prob = dataclasses.replace(prob, mpc=dataclasses.replace(prob.mpc, horizon=8))
    model = discretize(prob)
    mp = build_program(prob.mpc, model)
    sol = ce.mpsolve(mp.program)
    assert sol.stats["mplp"] == "bases", sol.stats.get("graph_fallback")
    assert len(sol.regions) == 8706
    assert sol.stats.get("slivers", 0) >= 1
    law = law_from_solution(mp, sol, simplify=prob.mpc.simplify)
    prog = mp.program
    thin = 0
    for reg in sol.regions:
        centre, radius = chebyshev_ball(reg.A, reg.b, solver="highs")
        if radius > 1e-6:
            continue
        thin += 1
        # the region's own law against HiGHS on the condensed LP at its centre (the online
        # MPC is no reference this close to the box's faces: its first move passes u_max
        # by its tolerance, 6e-7 at one of them, and the cost there is steep in u)
        z = reg.K @ centre + reg.k
        rhs = prog.b + prog.F @ centre
        assert np.max(prog.A @ z - rhs) <= 1e-8, centre
        lp = linprog(prog.c, A_ub=prog.A, b_ub=rhs, bounds=(None, None), method="highs")
        assert lp.status == 0
        assert prog.c @ z <= lp.fun + 1e-9 * max(1.0, abs(lp.fun)), centre
    assert thin >= 10, thin
    _check(compare("magnetic_pointer_a_N8", prob.mpc, model, law, n_uniform=400))


@pytest.mark.slow
def test_explorer_alone_on_the_slivers_gives_the_graphs_law_or_names_what_to_change():
    """The explorer alone on the magnetic pointer with N = 8 (``mplp="facets"``): it used
    to stop near the slivers, at about 5,200 regions, with "could not step across a facet
    (numerical trouble)". Today it ends in a law of 8,692 regions: the graph's 8,706 but
    for regions thinner than its steps. Either ending is allowed: the message naming what
    to change, or a law that is the graph's wherever both have a region (the first move at
    2,000 random parameters)."""
    prob = load_spec(EXAMPLES / "magnetic_pointer_a.toml")
    prob = dataclasses.replace(prob, mpc=dataclasses.replace(prob.mpc, horizon=8))
    mp = build_program(prob.mpc, discretize(prob))
    prog = mp.program
    try:
        alone = _solve(prog, "facets")
    except ce.SolverError as exc:
        assert re.search(r"could not step across a facet near theta=.*"
                         r"shorten mpc\.horizon, or use norm = \"2\"", str(exc)), str(exc)
        return
    graph = _solve(prog, "bases")
    assert 0.99 * graph.num_regions <= alone.num_regions <= graph.num_regions
    rng = np.random.default_rng(8)
    # parameters in the parameter box (the first 2 d rows of A_theta are the box's)
    upper, lower = prog.b_theta[:prog.d], -prog.b_theta[prog.d:2 * prog.d]
    Theta = rng.uniform(lower, upper, size=(2000, prog.d))
    ia, ig = alone.locate(Theta), graph.locate(Theta)
    both = (ia >= 0) & (ig >= 0)
    assert both.sum() >= 200, both.sum()
    # where one solution has a region the other has one too (no hole bigger than a sliver)
    assert np.array_equal(ia >= 0, ig >= 0)
    za, zg = alone.primal(Theta[both]), graph.primal(Theta[both])
    ua, ug = za[:, mp.u0_slice], zg[:, mp.u0_slice]
    assert np.allclose(ua, ug, atol=1e-7 * (1.0 + np.abs(ug).max()))
