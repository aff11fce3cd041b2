"""The law that grows on demand (issue 39): its regions are the full law's, they cover any
set asked about, and a verification on it gives the full law's verdict and tube.

- bundled 2-norm examples and random small MPCs: ``verify`` on an ``OnDemandLaw`` against
  ``verify`` on the synthesised law (same verdict, same tube, every region computed one of
  the full law's with identical rows and law);
- random boxes and polytopes in the parameter space: every region of the full solution that
  meets the set is returned (by active set), and random points of the set are located in
  the returned regions with the online optimum's input;
- norms 1 and inf are walked too (their tests: ``test_on_demand_lp.py``);
- the spec field ``[synthesis] regions`` and the CLI's ``--regions``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.geometry.polytope import box_halfspaces, chebyshev_ball
from codev_engine.law_on_demand import OnDemandLaw
from codev_engine.mp.on_demand import OnDemandRegions
from codev_engine.mp.reduce import parameter_box, reduce_program
from codev_engine.mp.solve import mpsolve
from codev_engine.mpc import build_program
from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.plant import discretize
from tests.conftest import EXAMPLES_DIR as EXAMPLES

FAST = ["double_integrator_lqr.toml", "mass_spring_soft.toml"]
SLOW = ["two_carts_mixed.toml", "dc_motor_servo.toml"]


def _same_verification(problem, hold: str | None = None) -> None:
    law = ce.synthesize(problem)
    full = ce.verify(problem, law, hold=hold)
    od = OnDemandLaw(problem)
    mine = ce.verify(problem, od, hold=hold)
    assert mine.verdict == full.verdict and mine.reason == full.reason
    merged = law.meta["stats"].get("merged", 0)
    if not merged:
        # (regions of one law the full search merges where LICQ fails stay apart on
        # demand: more, smaller children, so another tube of the same verdict)
        assert np.array_equal(mine.tube.t_start, full.tube.t_start)
        assert np.array_equal(mine.tube.lower, full.tube.lower)
        assert np.array_equal(mine.tube.upper, full.tube.upper)
        if full.counterexample is not None:
            assert np.array_equal(mine.counterexample.x0, full.counterexample.x0)
    # (none when no reach set was computed: a law over theta under the continuous hold is
    # unknown, reason law_parameters, with the full law too)
    assert od.num_regions <= law.num_regions + merged
    assert od.num_regions > 0 or full.tube.num_boxes == 0
    rows = {(a.tobytes(), b.tobytes()): i for i, (a, b) in enumerate(zip(law.A, law.b,
                                                                             strict=True))}
    same = 0
    for i in range(od.num_regions):
        j = rows.get((od.A[i].tobytes(), od.b[i].tobytes()))
        if j is not None:
            assert np.array_equal(od.F[i], law.F[j]) and np.array_equal(od.G[i], law.G[j])
            same += 1
    # (regions of one law the full search merges where LICQ fails stay apart on demand)
    assert same >= od.num_regions - 2 * merged


@pytest.mark.parametrize("name", FAST)
def test_bundled_examples_verify_the_same_on_demand(name):
    _same_verification(load_spec(EXAMPLES / name))


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW)
def test_bundled_examples_verify_the_same_on_demand_slow(name):
    _same_verification(load_spec(EXAMPLES / name))


@pytest.mark.parametrize("name", ["mass_spring_soft.toml"])
def test_bundled_examples_verify_the_same_on_demand_continuous_hold(name):
    # (the simulations' per-region flows and the adjoint's steps grow with the law)
    _same_verification(load_spec(EXAMPLES / name), hold="continuous")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["double_integrator_lqr.toml", *SLOW])
def test_bundled_examples_verify_the_same_on_demand_continuous_hold_slow(name):
    _same_verification(load_spec(EXAMPLES / name), hold="continuous")


def _random_spec(seed: int, unsafe: bool = False) -> str:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 4))
    A = np.round(rng.normal(scale=0.6, size=(n, n)), 3)
    B = np.round(rng.normal(size=(n, 1)), 3)
    lo = np.round(rng.uniform(-0.6, 0.3, size=n), 3)
    hi = lo + 0.1

    def mat(M):
        return "[" + ", ".join("[" + ", ".join(repr(float(v)) for v in r) + "]" for r in M) + "]"

    def vec(v):
        return "[" + ", ".join(repr(float(x)) for x in v) + "]"

    bound = 1.0 if unsafe else 5.0
    return f"""
name = "random{seed}"
[plant]
states = {json.dumps([f"x{i}" for i in range(n)])}
inputs = ["u"]
A = {mat(A)}
B = {mat(B)}
[model]
sample_time = 0.2
[mpc]
horizon = {int(rng.integers(2, 5))}
norm = "2"
Q = {mat(np.eye(n))}
R = [[{float(rng.uniform(0.1, 2.0))!r}]]
x_min = {vec(-5 * np.ones(n))}
x_max = {vec(5 * np.ones(n))}
u_min = [-1.0]
u_max = [1.0]
[verify]
time_horizon = 2.0
initial_set = {{ lower = {vec(lo)}, upper = {vec(hi)} }}
input_bounds = true
[[verify.safe]]
lower = {vec(-bound * np.ones(n))}
upper = {vec(bound * np.ones(n))}
"""


@pytest.mark.parametrize("name", ["tora.toml"])
def test_nonlinear_examples_verify_the_same_on_demand(name):
    # (the nonlinear engine asks the law for the regions meeting each set's box and for the
    # domain's rows there)
    _same_verification(load_spec(EXAMPLES / name))


@pytest.mark.slow
@pytest.mark.parametrize("hold", ["zoh", "continuous"])
@pytest.mark.parametrize("name", ["pendulum.toml", "cstr.toml", "tora.toml"])
def test_nonlinear_examples_verify_the_same_on_demand_slow(name, hold):
    _same_verification(load_spec(EXAMPLES / name), hold=hold)


def _forever(name: str):
    import re

    text = (EXAMPLES / name).read_text()
    text = re.sub(r"^time_horizon = .*$", 'time_horizon = "inf"', text, count=1, flags=re.M)
    return loads_spec(text, check_mpc=False)


def test_all_time_certificate_the_same_on_demand():
    # (the invariance certificate rests on the reach sets, which ask the law for the
    # regions they meet)
    _same_verification(_forever("double_integrator_lqr.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mass_spring_soft.toml", "two_carts_mixed.toml",
                                  "pendulum.toml"])
def test_all_time_certificate_the_same_on_demand_slow(name):
    # (pendulum: the invariant ellipsoid in the region at the operating point)
    _same_verification(_forever(name))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_mpcs_verify_the_same_on_demand(seed):
    _same_verification(loads_spec(_random_spec(seed), check_mpc=False))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3, 23))
def test_random_mpcs_verify_the_same_on_demand_slow(seed):
    _same_verification(loads_spec(_random_spec(seed, unsafe=seed % 2 == 0), check_mpc=False))


@pytest.mark.parametrize("seed", [0, 1])
def test_random_mpcs_verify_the_same_on_demand_continuous_hold(seed):
    _same_verification(loads_spec(_random_spec(seed, unsafe=seed % 2 == 0), check_mpc=False),
                       hold="continuous")


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2, 22))
def test_random_mpcs_verify_the_same_on_demand_continuous_hold_slow(seed):
    _same_verification(loads_spec(_random_spec(seed, unsafe=seed % 2 == 0), check_mpc=False),
                       hold="continuous")


def _disturbed_spec(seed: int) -> str:
    """:func:`_random_spec` with a disturbance on every state (the adjoint's signals)."""
    text = _random_spec(seed, unsafe=seed % 2 == 0)
    n = len(json.loads(text.split("states = ", 1)[1].split("\n", 1)[0]))
    E = "[" + ", ".join("[0.2]" for _ in range(n)) + "]"
    return text.replace('inputs = ["u"]', f'inputs = ["u"]\nE = {E}\n'
                        'disturbances = { w = [-0.5, 0.5] }', 1)


def test_disturbed_mpcs_verify_the_same_on_demand():
    # (seed 2: unsafe, the counterexample by the adjoint's extreme signals)
    _same_verification(loads_spec(_disturbed_spec(2), check_mpc=False), hold="continuous")


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2, 13))
@pytest.mark.parametrize("hold", ["zoh", "continuous"])
def test_disturbed_mpcs_verify_the_same_on_demand_slow(seed, hold):
    _same_verification(loads_spec(_disturbed_spec(seed), check_mpc=False), hold=hold)


def _meets(A, b, Ar, br) -> bool:
    _, rho = chebyshev_ball(np.vstack([A, Ar]), np.concatenate([b, br]), solver="highs")
    return rho > 1e-7


def _cover(problem, seed: int, sets: int) -> None:
    mp = build_program(problem.mpc, discretize(problem))
    sol = mpsolve(mp.program)
    od = OnDemandRegions(mp.program)
    size = parameter_box(reduce_program(mp.program))
    rng = np.random.default_rng(seed)
    d = mp.d
    for k in range(sets):
        # a box, or a random polytope (a box cut by two random rows), somewhere in theta
        centre = rng.uniform(size.lo, size.hi)
        half = rng.uniform(0.02, 0.3) * (size.hi - size.lo)
        A, b = box_halfspaces(centre - half, centre + half)
        if k % 2:
            cut = rng.normal(size=(2, d))
            cut /= np.linalg.norm(cut, axis=1, keepdims=True)
            A, b = np.vstack([A, cut]), np.concatenate([b, cut @ centre + 0.1 * half.max()])
        got = {od.regions[i].active for i in od.meeting(A, b)}
        want = {r.active for r in sol.regions if _meets(A, b, r.A, r.b)}
        assert want <= got, f"missing {want - got}"
        # random points of the set: in a returned region, with the optimum's input
        pts = centre + rng.uniform(-1, 1, size=(200, d)) * half
        pts = pts[np.all(pts @ A.T <= b, axis=1)]
        idx = sol.locate(pts)
        pts = pts[idx >= 0]
        for x in pts:
            hold = [i for i in od.meeting(A, b)
                    if np.max(od.regions[i].A @ x - od.regions[i].b) <= 1e-9]
            assert hold, f"a point of the set in no returned region: {x}"
            reg = od.regions[hold[0]]
            assert np.allclose(reg.K @ x + reg.k, sol.primal(x[None])[0], atol=1e-6)


@pytest.mark.parametrize("name", FAST)
def test_regions_returned_cover_random_sets(name):
    _cover(load_spec(EXAMPLES / name), seed=1, sets=6)


@pytest.mark.parametrize("seed", [0, 1])
def test_regions_returned_cover_random_sets_of_random_mpcs(seed):
    _cover(loads_spec(_random_spec(seed), check_mpc=False), seed=seed, sets=6)


def test_locate_and_evaluate_agree_with_the_full_law():
    problem = load_spec(EXAMPLES / "double_integrator_lqr.toml")
    law = ce.synthesize(problem)
    od = OnDemandLaw(problem)
    rng = np.random.default_rng(3)
    X = rng.uniform(-12, 12, size=(300, 2))  # (past the domain too)
    assert np.array_equal(od.locate(X) >= 0, law.locate(X) >= 0)
    U, V = od.evaluate(X), law.evaluate(X)
    assert np.allclose(U, V, equal_nan=True, atol=1e-9)


def test_norms_1_and_inf_are_walked_too():
    # (norm inf: an mp-LP, walked on its basis graph; tests/engine/test_on_demand_lp.py)
    od = OnDemandLaw(load_spec(EXAMPLES / "double_integrator.toml"))
    assert od.meta["norm"] == "inf" and od.num_regions == 0


def test_spec_field_and_cli_flag(tmp_path, capsys):
    from workbench.cli import main

    text = (EXAMPLES / "double_integrator_lqr.toml").read_text()
    assert loads_spec(text, check_mpc=False).regions == "all"
    spec = tmp_path / "lqr.toml"
    spec.write_text(text + '\n[synthesis]\nregions = "reached"\n')
    assert load_spec(spec).regions == "reached"
    bad = tmp_path / "bad.toml"
    bad.write_text(text + '\n[synthesis]\nregions = "some"\n')
    with pytest.raises(SpecError, match="synthesis.regions"):
        load_spec(bad)
    assert main(["verify", str(spec), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict"] == "robustly_safe" and out["synthesis_seconds"] is None
    plain = tmp_path / "plain.toml"
    plain.write_text(text)
    assert main(["run", str(plain), "--regions", "reached"]) == 0
    assert "computed on demand" in capsys.readouterr().out


def _online_loop_in_tube(problem, runs: int, seed: int, tol: float) -> None:
    """Test (c) of issue 39: the closed loop with the online MPC (cvxpy + Clarabel, an
    independent controller) in the loop, the plant's exact zoh flow, from random states and
    corners of the initial set: every state at the samples and at 4 points per period lies
    in the tube verified on demand (within the online solver's accuracy ``tol``)."""
    from scipy.linalg import expm

    from codev_engine.mpc import OnlineMpc
    from codev_engine.plant import linearize

    od = OnDemandLaw(problem)
    result = ce.verify(problem, od)
    assert result.verdict == "robustly_safe", result.summary()
    tube = result.tube
    model = discretize(problem)
    online = OnlineMpc(problem.mpc, model)
    Ac, Bc, _ = linearize(problem.plant, problem.model.x_op, problem.model.u_op)
    n, m = Bc.shape
    Ts = float(problem.model.sample_time)
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = Ac, Bc
    taus = np.linspace(0.0, Ts, 5)[1:]
    flows = [expm(M * tau)[:n] for tau in taus]
    vs = problem.verify
    lo, hi = np.asarray(vs.initial_lower), np.asarray(vs.initial_upper)
    rng = np.random.default_rng(seed)
    X0 = [lo, hi, *(lo + rng.uniform(size=(runs - 2, n)) * (hi - lo))]
    worst = 0.0
    for x in X0:
        t = 0.0
        while t < vs.time_horizon - 1e-9:
            sol = online.solve(x)
            assert sol.feasible
            z = np.concatenate([x, sol.u0])
            for tau, Phi in zip(taus, flows, strict=True):
                y = Phi @ z
                sel = (tube.t_start <= t + tau + 1e-12) & (tube.t_end >= t + tau - 1e-12)
                exc = np.maximum(tube.lower[sel] - y, y - tube.upper[sel]).max(-1).min()
                worst = max(worst, float(exc))
            x, t = flows[-1] @ z, t + Ts
    assert worst <= tol, f"an online-MPC trajectory leaves the tube by {worst:g}"


@pytest.mark.slow
def test_online_mpc_loops_stay_in_the_tube_on_demand_chain():
    from tests.engine.test_mpqp_chain import chain_spec

    n = 6
    text = chain_spec(n) + f"""
[verify]
time_horizon = 2.5
initial_set = {{ lower = {[-0.02] * n}, upper = {[0.02] * n} }}
input_bounds = true
"""
    _online_loop_in_tube(loads_spec(text, check_mpc=False), runs=12, seed=0, tol=1e-6)


@pytest.mark.slow
@pytest.mark.parametrize("hold", ["zoh", "continuous"])
def test_nonlinear_plant_with_measurement_noise_verifies_the_same_on_demand(hold):
    from tests.engine.test_nonlinear_noise import _pendulum

    _same_verification(_pendulum([-0.005, -0.025], [0.005, 0.025], hold=hold))
