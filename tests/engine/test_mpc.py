"""The condensed MPC program against the non-condensed online MPC (an independent oracle)."""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest
from scipy.optimize import linprog

from codev_engine.errors import SpecError
from codev_engine.mpc import MpcProgram, OnlineMpc, build_program, check_feasible
from codev_engine.plant import LinearModel
from codev_engine.spec.problem import ModelSpec, MpcSpec, PlantSpec, Problem

RTOL = 1e-6
INF = np.inf


def close(a: float, b: float, rtol: float = RTOL) -> bool:
    return abs(a - b) <= rtol * max(1.0, abs(a), abs(b))


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------


def make_model(A, B, c=None, x_op=None, u_op=None) -> LinearModel:
    A = np.atleast_2d(np.asarray(A, float))
    B = np.asarray(B, float).reshape(A.shape[0], -1)
    n, m = B.shape
    return LinearModel(
        A=A, B=B, c=np.zeros(n) if c is None else np.asarray(c, float),
        dt=1.0, x_op=np.zeros(n) if x_op is None else np.asarray(x_op, float),
        u_op=np.zeros(m) if u_op is None else np.asarray(u_op, float),
    )


def make_spec(N, norm, Q, R, P=None, x_min=None, x_max=None, u_min=None, u_max=None,
              domain_bound=100.0) -> MpcSpec:
    Q, R = np.atleast_2d(np.asarray(Q, float)), np.atleast_2d(np.asarray(R, float))
    n, m = Q.shape[1], R.shape[1]

    def vec(v, k, default):
        return np.full(k, default) if v is None else np.asarray(v, float)

    return MpcSpec(
        horizon=N, norm=norm, Q=Q, R=R, P=None if P is None else np.atleast_2d(P),
        x_min=vec(x_min, n, -INF), x_max=vec(x_max, n, INF),
        u_min=vec(u_min, m, -INF), u_max=vec(u_max, m, INF), domain_bound=domain_bound,
    )


def make_problem(spec: MpcSpec, model: LinearModel) -> Problem:
    n, m = model.n, model.m
    return Problem(
        name="t",
        plant=PlantSpec(states=tuple(f"x{i}" for i in range(n)),
                        inputs=tuple(f"u{i}" for i in range(m))),
        model=ModelSpec(sample_time=model.dt, x_op=model.x_op, u_op=model.u_op,
                        A=model.A, B=model.B),
        mpc=spec, verify=None,
    )


class CondensedSolver:
    """Solves the condensed MpProgram at one theta (HiGHS for LP, Clarabel for QP)."""

    def __init__(self, mp: MpcProgram):
        self.mp = mp
        prog = mp.program
        self.prog = prog
        if not prog.is_lp:
            self.z = cp.Variable(prog.nz)
            self.th = cp.Parameter(prog.d)
            obj = 0.5 * cp.quad_form(self.z, cp.psd_wrap(prog.H)) + prog.c @ self.z \
                + (prog.C @ self.th) @ self.z
            cons = []
            if prog.A.shape[0]:
                cons.append(prog.A @ self.z <= prog.b + prog.F @ self.th)
            self.qp = cp.Problem(cp.Minimize(obj), cons)

    def solve(self, theta) -> tuple[float, np.ndarray | None]:
        """(optimal value incl. theta_constant, z) or (inf, None)."""
        prog = self.prog
        if np.any(prog.A_theta @ theta > prog.b_theta + 1e-9):
            return INF, None
        const = float(self.mp.theta_constant(theta[None, :])[0])
        if prog.is_lp:
            res = linprog(prog.c + prog.C @ theta, A_ub=prog.A, b_ub=prog.b + prog.F @ theta,
                          bounds=(None, None), method="highs",
                          options={"primal_feasibility_tolerance": 1e-10,
                                   "dual_feasibility_tolerance": 1e-10})
            if res.status == 2:
                return INF, None
            assert res.status == 0, res.message
            return res.fun + const, res.x
        self.th.value = theta
        self.qp.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10,
                      tol_feas=1e-10)
        if self.qp.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            return INF, None
        assert self.qp.status == cp.OPTIMAL, self.qp.status
        return float(self.qp.value) + const, np.array(self.z.value)


def manual_cost(spec: MpcSpec, model: LinearModel, x0, U) -> float:
    """MPC cost of the plan U (N, m) from x0 by simulation, all in plant coordinates."""
    N = spec.horizon
    ordp = {"1": 1, "inf": INF}.get(spec.norm)

    def term(M, v):
        if spec.norm == "2":
            return float(v @ M @ v)
        return float(np.linalg.norm(M @ v, ordp))

    dx = np.asarray(x0, float) - model.x_op
    J = 0.0
    for k in range(N):
        du = U[k] - model.u_op
        J += term(spec.Q, dx) + term(spec.R, du)
        dx = model.A @ dx + model.B @ du + model.c
    if spec.P is not None:
        J += term(spec.P, dx)
    return J


def sample_states(mp: MpcProgram, rng, count: int) -> np.ndarray:
    """States in the parameter box, enlarged by 10% on sides with a finite state bound."""
    spec = mp.spec
    lo = np.where(np.isfinite(spec.x_min), spec.x_min - mp.x_op, -spec.domain_bound)
    hi = np.where(np.isfinite(spec.x_max), spec.x_max - mp.x_op, spec.domain_bound)
    w = hi - lo
    lo = np.where(np.isfinite(spec.x_min), lo - 0.1 * w, lo)
    hi = np.where(np.isfinite(spec.x_max), hi + 0.1 * w, hi)
    return mp.from_theta(lo + (hi - lo) * rng.random((count, mp.n)))


def compare(spec: MpcSpec, model: LinearModel, rng, count: int = 50) -> dict:
    """Condensed optimum + theta_constant == online cost, same feasibility, u0 oracle."""
    mp = build_program(spec, model)
    online = OnlineMpc(spec, model)
    cond = CondensedSolver(mp)
    stats = {"feasible": 0, "infeasible": 0}
    for x in sample_states(mp, rng, count):
        J_cond, z = cond.solve(mp.to_theta(x))
        sol = online.solve(x)
        assert np.isfinite(J_cond) == sol.feasible, (x, J_cond, sol.status)
        if not sol.feasible:
            stats["infeasible"] += 1
            assert sol.cost == INF and np.all(np.isnan(sol.u0))
            continue
        stats["feasible"] += 1
        assert close(J_cond, sol.cost), (x, J_cond, sol.cost)
        # the online plan's cost, recomputed by simulation
        assert close(manual_cost(spec, model, x, sol.U), sol.cost), x
        # the online first move is optimal ...
        assert close(online.first_move_cost(x, sol.u0), sol.cost), x
        # ... and so is the condensed one (u0_slice and u_op read correctly)
        assert close(online.first_move_cost(x, mp.u0_from_z(z)), sol.cost), x
    return stats


def random_case(seed: int):
    rng = np.random.default_rng(seed)
    n, m, N = int(rng.integers(1, 4)), int(rng.integers(1, 3)), int(rng.integers(1, 5))
    norm = ("1", "inf", "2")[seed % 3]
    bounds = ("none", "some", "all")[(seed // 3) % 3]
    A = rng.normal(size=(n, n))
    A *= rng.uniform(0.5, 1.3) / max(1e-9, np.max(np.abs(np.linalg.eigvals(A))))
    B = rng.normal(size=(n, m))
    if n > 1 and seed % 4 == 0:
        B[-1] = 0.0  # an uncontrolled state: pure-theta rows
    op = seed % 2 == 1
    c = rng.normal(scale=0.3, size=n) if op else np.zeros(n)
    x_op = rng.normal(size=n) if op else np.zeros(n)
    u_op = rng.normal(size=m) if op else np.zeros(m)
    model = make_model(A, B, c, x_op, u_op)
    if norm == "2":
        L = rng.normal(size=(n, n))
        Q = L @ L.T + 0.1 * np.eye(n)
        Lr = rng.normal(size=(m, m))
        R = Lr @ Lr.T + 0.1 * np.eye(m)
        P = None if seed % 5 == 0 else Q * rng.uniform(1, 3)
    else:
        Q = rng.normal(size=(int(rng.integers(1, n + 2)), n))
        R = rng.normal(size=(int(rng.integers(1, m + 2)), m))
        P = None if seed % 5 == 0 else rng.normal(size=(int(rng.integers(1, n + 2)), n))

    def side(k, sign, center, lo, hi):
        v = center + sign * rng.uniform(lo, hi, size=k)
        if bounds == "none":
            return np.full(k, sign * INF)
        if bounds == "some":
            v[rng.random(k) < 0.5] = sign * INF
        return v

    spec = make_spec(
        N, norm, Q, R, P,
        x_min=side(n, -1, x_op, 1, 5), x_max=side(n, 1, x_op, 1, 5),
        u_min=side(m, -1, u_op, 0.3, 2), u_max=side(m, 1, u_op, 0.3, 2),
        domain_bound=5.0,
    )
    return spec, model, rng


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(27))
def test_random_condensed_matches_online(seed):
    spec, model, rng = random_case(seed)
    stats = compare(spec, model, rng, count=30)
    assert stats["feasible"] > 0


def double_integrator():
    model = make_model([[1, 1], [0, 1]], [[0.5], [1]])
    spec = make_spec(2, "inf", [[1, 1], [0, 1]], [[0.8]], None,
                     x_min=[-10, -10], x_max=[10, 10], u_min=[-1], u_max=[1])
    return spec, model


def test_double_integrator():
    spec, model = double_integrator()
    mp = build_program(spec, model)
    prog = mp.program
    # MPT3-style LP: u (2) + slacks for ||Q x_1||, ||R u_0||, ||R u_1|| (3)
    assert prog.is_lp and prog.nz == 5 and mp.n_slack == 3
    # 4 input rows, 8 state rows (k = 1, 2), 2*2 + 2*2 slack rows
    assert prog.A.shape == (20, 5) and prog.F.shape == (20, 2)
    assert prog.A_theta.shape == (4, 2)
    assert np.allclose(prog.b_theta, 10.0)
    stats = compare(spec, model, np.random.default_rng(1), count=50)
    assert stats["feasible"] > 10 and stats["infeasible"] > 0

    online = OnlineMpc(spec, model)
    sol = online.solve(np.zeros(2))
    assert sol.feasible and abs(sol.cost) < 1e-8 and np.allclose(sol.u0, 0, atol=1e-7)
    # a known value: x = (1, 0): J = |Q x0| + ... ; check against the oracle's own plan
    x = np.array([1.0, 0.0])
    sol = online.solve(x)
    assert close(manual_cost(spec, model, x, sol.U), sol.cost)
    assert sol.cost >= 1.0  # ||Q x_0||_inf = 1 is part of the cost
    # the theta-only term matters: the program optimum alone is smaller
    assert close(float(mp.theta_constant(x[None])[0]), 1.0)
    # outside the state bounds: infeasible
    assert online.solve(np.array([10.5, 0.0])).status == "infeasible"
    U0, cost, feas = online.solve_many(np.array([[0.0, 0.0], [10.5, 0.0], [1.0, 0.0]]))
    assert feas.tolist() == [True, False, True]
    assert np.isinf(cost[1]) and np.all(np.isnan(U0[1]))
    assert close(cost[2], sol.cost) and U0.shape == (3, 1)


def test_first_move_cost_detects_suboptimal_moves():
    # norm 2 with R > 0: the optimal first move is unique, so perturbing it costs more
    rng = np.random.default_rng(7)
    spec = make_spec(3, "2", np.eye(2), [[0.5]], 2 * np.eye(2),
                     x_min=[-5, -5], x_max=[5, 5], u_min=[-2], u_max=[2])
    model = make_model([[1, 0.5], [0, 1]], [[0.1], [0.5]], c=[0.05, -0.02],
                       x_op=[1.0, 0.5], u_op=[0.3])
    online = OnlineMpc(spec, model)
    worse = 0
    for x in rng.uniform([-3, -3], [4, 4], size=(20, 2)):
        sol = online.solve(x)
        if not sol.feasible:
            continue
        J = online.first_move_cost(x, sol.u0 + 0.05)
        assert J >= sol.cost - 1e-9
        worse += J > sol.cost * (1 + 1e-5) + 1e-7
    assert worse >= 10


def test_condensed_cost_is_the_mpc_cost_at_any_plan():
    # the QP objective + theta_constant equals the simulated cost for arbitrary inputs
    rng = np.random.default_rng(3)
    for _ in range(5):
        n, m, N = 3, 2, 4
        model = make_model(rng.normal(size=(n, n)) * 0.5, rng.normal(size=(n, m)),
                           rng.normal(size=n), rng.normal(size=n), rng.normal(size=m))
        L, S = rng.normal(size=(n, n)), rng.normal(size=(n, n))
        # a non-symmetric Q (PSD symmetric part): the quadratic form uses (Q + Q')/2
        spec = make_spec(N, "2", L @ L.T + (S - S.T), np.eye(m), np.eye(n) * 2)
        mp = build_program(spec, model)
        prog = mp.program
        assert np.allclose(prog.H, prog.H.T)
        x = rng.normal(size=n)
        U = rng.normal(size=(N, m))
        th = mp.to_theta(x)
        z = (U - model.u_op).reshape(-1)
        J = 0.5 * z @ prog.H @ z + (prog.c + prog.C @ th) @ z + mp.theta_constant(th[None])[0]
        assert close(J, manual_cost(spec, model, x, U), 1e-9)


@pytest.mark.parametrize("norm", ["1", "inf", "2"])
def test_operating_point(norm):
    # scalar plant, not an equilibrium at the operating point (c != 0)
    model = make_model([[0.9]], [[0.5]], c=[0.2], x_op=[3.0], u_op=[1.0])
    spec = make_spec(3, norm, [[2.0]], [[0.5]], [[3.0]],
                     x_min=[0.0], x_max=[6.0], u_min=[-1.0], u_max=[2.0])
    mp = build_program(spec, model)
    assert np.allclose(mp.to_theta(np.array([[3.0]])), 0.0)
    assert np.allclose(mp.from_theta(np.array([[0.0]])), 3.0)
    # the parameter set is the state box, in deviations
    box = mp.program.A_theta @ np.array([-3.0]) <= mp.program.b_theta + 1e-12
    assert box.all()
    stats = compare(spec, model, np.random.default_rng(11), count=40)
    assert stats["feasible"] > 20 and stats["infeasible"] > 0
    # at x = x_op the drift c makes the cost positive
    assert OnlineMpc(spec, model).solve(np.array([3.0])).cost > 1e-3


def test_pure_theta_rows_go_to_the_parameter_set():
    # x2 is not controlled and drifts by +0.5 per step: x2_k = x2_0 + 0.5 k <= 1
    model = make_model(np.eye(2), [[1.0], [0.0]], c=[0.0, 0.5])
    spec = make_spec(2, "inf", np.eye(2), [[1.0]], None,
                     x_min=[-1, -1], x_max=[1, 1], u_min=[-1], u_max=[1])
    mp = build_program(spec, model)
    prog = mp.program
    assert np.all(np.any(prog.A != 0, axis=1))  # no pure-theta rows left in A
    # theta2 <= 0 (from k = 2) is in the parameter set; the box rows come first
    assert prog.A_theta.shape[0] > 4
    inside = prog.A_theta @ np.array([0.0, -0.5]) <= prog.b_theta
    outside = prog.A_theta @ np.array([0.0, 0.3]) <= prog.b_theta
    assert inside.all() and not outside.all()
    online = OnlineMpc(spec, model)
    assert online.solve(np.array([0.0, 0.3])).status == "infeasible"
    assert online.solve(np.array([0.0, -0.5])).status == "optimal"
    compare(spec, model, np.random.default_rng(5), count=30)


def test_unbounded_axes_use_domain_bound():
    model = make_model([[1.0, 0.1], [0.0, 1.0]], [[0.0], [0.1]])
    spec = make_spec(2, "1", np.eye(2), [[1.0]], None, x_min=[-2, -INF], x_max=[INF, 3],
                     domain_bound=7.0)
    prog = build_program(spec, model).program
    # the box comes first (then a pure-theta row: x1_1 = x1_0 + 0.1 x2_0 >= -2)
    assert np.allclose(prog.A_theta[:4], np.vstack([np.eye(2), -np.eye(2)]))
    assert np.allclose(prog.b_theta[:4], [7.0, 3.0, 2.0, 7.0])


def test_check_feasible():
    model = make_model([[1.0]], [[0.0]], c=[3.0])  # x1 = x0 + 3 cannot stay in [-1, 1]
    spec = make_spec(1, "inf", [[1.0]], [[1.0]], x_min=[-1], x_max=[1])
    with pytest.raises(SpecError) as err:
        check_feasible(make_problem(spec, model), model)
    assert err.value.field == "mpc"
    assert "infeasible for every initial state" in str(err.value)

    # with an input that can push back it is feasible (for some states)
    model = make_model([[1.0]], [[1.0]], c=[3.0])
    spec = make_spec(2, "2", [[1.0]], [[1.0]], x_min=[-1], x_max=[1], u_min=[-3.5],
                     u_max=[0])
    check_feasible(make_problem(spec, model), model)
    # ... but not if the input is too weak
    spec = make_spec(2, "2", [[1.0]], [[1.0]], x_min=[-1], x_max=[1], u_min=[-0.5],
                     u_max=[0])
    with pytest.raises(SpecError):
        check_feasible(make_problem(spec, model), model)
    # the double integrator is feasible
    spec, model = double_integrator()
    check_feasible(make_problem(spec, model), model)


def test_bad_norm_is_a_spec_error():
    model = make_model([[1.0]], [[1.0]])
    spec = make_spec(1, "3", [[1.0]], [[1.0]])
    with pytest.raises(SpecError):
        build_program(spec, model)


def test_indefinite_weight_is_a_spec_error():
    model = make_model(np.eye(2), np.eye(2))
    spec = make_spec(1, "2", [[1.0, 0.0], [0.0, -1.0]], np.eye(2))
    with pytest.raises(SpecError) as err:
        build_program(spec, model)
    assert err.value.field == "mpc.Q"
    # LP norms take any (even non-square) weights
    build_program(make_spec(1, "inf", [[1.0, 0.0], [0.0, -1.0], [1, 1]], np.eye(2)), model)


# ---------------------------------------------------------------------------------------
# OnlineMpc where Clarabel struggles: near the edge of the feasible set
# ---------------------------------------------------------------------------------------


def lp_feasible(spec: MpcSpec, model: LinearModel, x0: np.ndarray) -> bool:
    """The non-condensed MPC constraints at ``x0``, written out here, solved by HiGHS."""
    A, B = np.asarray(model.A, float), np.asarray(model.B, float)
    n, m = B.shape
    N = spec.horizon
    nv = (N + 1) * n + N * m
    Aeq = np.zeros((N * n, nv))
    beq = np.zeros(N * n)
    for k in range(N):
        r = slice(k * n, (k + 1) * n)
        Aeq[r, (k + 1) * n:(k + 2) * n] = np.eye(n)
        Aeq[r, k * n:(k + 1) * n] = -A
        Aeq[r, (N + 1) * n + k * m:(N + 1) * n + (k + 1) * m] = -B
        beq[r] = model.c + model.x_op - A @ model.x_op - B @ model.u_op
    if np.any(x0 < spec.x_min) or np.any(x0 > spec.x_max):
        return False

    def fin(v):
        return float(v) if np.isfinite(v) else None

    bounds = [(float(v), float(v)) for v in x0]
    bounds += [(fin(spec.x_min[i]), fin(spec.x_max[i])) for _ in range(N) for i in range(n)]
    bounds += [(fin(spec.u_min[j]), fin(spec.u_max[j])) for _ in range(N) for j in range(m)]
    res = linprog(np.zeros(nv), A_eq=Aeq, b_eq=beq, bounds=bounds, method="highs")
    assert res.status in (0, 2), res.message
    return res.status == 0


def tora(u_max: float):
    import dataclasses
    from pathlib import Path

    from codev_engine.pipeline import load_spec
    from codev_engine.plant import discretize

    p = load_spec(Path(__file__).resolve().parents[2] / "examples" / "tora.toml")
    mpc = dataclasses.replace(p.mpc, u_min=np.array([-u_max]), u_max=np.array([u_max]))
    p = dataclasses.replace(p, mpc=mpc)
    return p.mpc, discretize(p)


def edge_points(spec, model, rng, rays: int, offsets) -> list[tuple[float, np.ndarray]]:
    """Points ``offset`` (along a random ray from a feasible state) beyond the boundary of
    the feasible set (negative: inside), the boundary found by bisection with HiGHS."""
    n = model.n
    out = []
    while len(out) < rays * len(offsets):
        a = rng.uniform(-1.0, 1.0, n) * np.where(np.isfinite(spec.x_max), spec.x_max, 2.5)
        if not lp_feasible(spec, model, a):
            continue
        d = rng.normal(size=n)
        d /= np.linalg.norm(d)
        s0, s1 = 0.0, 1.0
        while lp_feasible(spec, model, a + s1 * d):
            s0, s1 = s1, 2 * s1
        for _ in range(50):
            mid = 0.5 * (s0 + s1)
            s0, s1 = (mid, s1) if lp_feasible(spec, model, a + mid * d) else (s0, mid)
        out += [(off, a + (s0 + off) * d) for off in offsets]
    return out


@pytest.mark.parametrize("u_max", [0.5, 0.65])
def test_online_mpc_at_the_edge_of_the_feasible_set(u_max):
    """TORA (examples/tora.toml, and with |u| <= 0.5): Clarabel at tight tolerances fails
    (NumericalError, iteration limit, inaccurate) at states slightly outside -- and some
    slightly inside -- the feasible set. ``solve`` must still answer: infeasible outside,
    optimal inside, with first moves whose cost is the optimum."""
    spec, model = tora(u_max)
    online = OnlineMpc(spec, model)
    rng = np.random.default_rng(2024)
    offsets = (-1e-5, -1e-6, -1e-8, 0.0, 1e-8, 1e-6, 1e-5, 5e-5, 1e-4)
    points = edge_points(spec, model, rng, rays=12, offsets=offsets)
    X = np.array([x for _, x in points])
    U0, cost, feas = online.solve_many(X)  # no SolverError
    for (off, x), u0, J, f in zip(points, U0, cost, feas, strict=True):
        if off >= 5e-5:
            assert not f and np.isinf(J) and np.all(np.isnan(u0)), (off, x.tolist())
        if off <= -1e-6:
            assert f, (off, x.tolist())
        if f:
            assert np.all(np.isfinite(u0)) and np.isfinite(J)
            assert close(online.first_move_cost(x, u0), J), (off, x.tolist())
            worse = online.first_move_cost(x, u0 - 0.01 * np.sign(u0 + 1e-300))
            assert worse >= J * (1 - RTOL) - RTOL, (off, x.tolist())
        elif off >= 5e-5:  # (closer, Clarabel's tolerances may accept a fixed move)
            assert online.first_move_cost(x, np.zeros(1)) == np.inf
        sol = online.solve(x)
        assert sol.feasible == f and (not f or close(sol.cost, J))


class _Scripted:
    """Replaces ``OnlineMpc._clarabel``: the first ``fail`` calls report ``status``
    (without solving); the rest solve for real."""

    def __init__(self, fail: int, status: str = "failed"):
        self.fail, self.status, self.calls = fail, status, 0

    def __call__(self, prob, options):
        self.calls += 1
        if self.calls <= self.fail:
            return self.status, "scripted failure"
        prob.solve(solver=cp.CLARABEL, **options)
        return prob.status, ""


@pytest.mark.parametrize("status", ["failed", "user_limit", "infeasible_inaccurate",
                                    "optimal_inaccurate"])
def test_online_mpc_falls_back_on_highs_and_retries(monkeypatch, status):
    spec, model = double_integrator()
    online = OnlineMpc(spec, model)
    x_in, x_out = np.array([1.0, -0.5]), np.array([9.9, 9.9])  # feasible / not (HiGHS)
    assert lp_feasible(spec, model, x_in) and not lp_feasible(spec, model, x_out)
    ref = online.solve(x_in)
    ref_fixed = online.first_move_cost(x_in, ref.u0)
    assert ref.feasible

    # infeasible per HiGHS: answered without any retry
    script = _Scripted(fail=1, status=status)
    monkeypatch.setattr(OnlineMpc, "_clarabel", staticmethod(script))
    sol = online.solve(x_out)
    assert sol.status == "infeasible" and sol.cost == np.inf and np.all(np.isnan(sol.u0))
    assert script.calls == 1
    # first_move_cost: infeasible because of u0 (out of bounds) or of the state
    script.calls = 0
    assert online.first_move_cost(x_in, np.array([1.5])) == np.inf
    script.calls = 0
    assert online.first_move_cost(x_out, np.array([0.0])) == np.inf

    # feasible per HiGHS: Clarabel again (defaults), the same optimum
    for fail in (1, 2, 3):
        script = _Scripted(fail=fail, status=status)
        monkeypatch.setattr(OnlineMpc, "_clarabel", staticmethod(script))
        sol = online.solve(x_in)
        assert sol.feasible and close(sol.cost, ref.cost), fail
        assert np.allclose(sol.u0, ref.u0, atol=1e-6)
        assert script.calls == fail + 1
        script.calls = 0
        assert close(online.first_move_cost(x_in, ref.u0), ref_fixed)
    U0, cost, feas = online.solve_many(np.array([x_in, x_out]))
    assert feas.tolist() == [True, False] and close(cost[0], ref.cost)


def test_online_mpc_raises_only_when_every_retry_fails(monkeypatch):
    from codev_engine.errors import SolverError
    from codev_engine.mpc import RETRY_OPTIONS

    spec, model = double_integrator()
    online = OnlineMpc(spec, model)
    script = _Scripted(fail=10**9)
    monkeypatch.setattr(OnlineMpc, "_clarabel", staticmethod(script))
    with pytest.raises(SolverError, match="HiGHS: feasible"):
        online.solve(np.array([1.0, -0.5]))
    assert script.calls == 1 + len(RETRY_OPTIONS)
    with pytest.raises(SolverError):
        online.first_move_cost(np.array([1.0, -0.5]), np.array([0.0]))
    # an infeasible state never needs Clarabel to succeed
    assert online.solve(np.array([9.9, 9.9])).status == "infeasible"
    assert online.solve(np.array([10.5, 0.0])).status == "infeasible"  # outside x bounds


@pytest.mark.parametrize("status", ["failed", "optimal_inaccurate"])
def test_first_move_a_rounding_error_beyond_its_bound(monkeypatch, status):
    """A law's first move on an input bound is often 1 ulp beyond it: when Clarabel needs
    the HiGHS fallback there, the move still counts as feasible (and 1e-6 beyond does not)."""
    spec, model = double_integrator()
    online = OnlineMpc(spec, model)
    x = np.array([6.0, -1.0])  # saturated: u0 = -1 (the lower bound)
    sol = online.solve(x)
    assert sol.feasible and np.isclose(sol.u0[0], -1.0, atol=1e-7)
    u_ulp = np.array([np.nextafter(-1.0, -2.0)])
    monkeypatch.setattr(OnlineMpc, "_clarabel", staticmethod(_Scripted(fail=1, status=status)))
    J = online.first_move_cost(x, u_ulp)
    assert np.isfinite(J) and J >= sol.cost * (1 - RTOL) - RTOL
    monkeypatch.setattr(OnlineMpc, "_clarabel", staticmethod(_Scripted(fail=1, status=status)))
    assert online.first_move_cost(x, np.array([-1.0 - 1e-6])) == np.inf
