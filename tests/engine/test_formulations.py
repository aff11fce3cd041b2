"""The MPC formulations of docs/spec.md against the online MPC, and their properties.

Every field of ``[mpc]`` beyond the regulator (move blocking, input rates, outputs, soft and
mixed constraints, a fixed or free reference, the LQR terminal cost and set, a polytopic
terminal set), alone and in combinations, is synthesised and compared point by point with
``OnlineMpc`` (non-condensed, cvxpy + Clarabel) in the law's parameter space ``theta = (x,
u_prev, r)``:

* **no holes**: online feasible => ``law.locate(theta) >= 0``;
* **no false regions**: online infeasible => ``law.locate(theta) == -1``;
* **optimality**: ``first_move_cost(theta, law(theta))`` equals the online optimum within
  1e-6 relative (absolute floor 1e-6);
* **no overlaps**: at most one region holds the point with a strict margin.

A feasibility disagreement is excused only within ``1e-6 * max(1, |theta|)`` of the law's
domain boundary (a hole or a false region deep inside the domain is not). The samples are
uniform in the parameter box (a third in the law's bounding box) plus points just inside
and outside region facets, where wrong laws hide.

The properties: the spelled-out defaults give the regulator's program bit for bit; the
law equals the LQR law around the target with ``P = "lqr"``; ``terminal_set = "lqr"`` is
recursively feasible; a fixed reference is tracked without offset; soft constraints are
exact (the soft law is the hard law wherever the hard problem is feasible) and extend the
domain. Bad input for every new field is one ``SpecError`` naming the field.
"""

from __future__ import annotations

import functools
import os

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.formulation import formulation
from codev_engine.mpc import build_program
from codev_engine.pipeline import loads_spec
from codev_engine.plant import discretize

RTOL = 1e-6
STRICT = 1e-9
PROBE = 1e-5
N_FAST = 120
N_SLOW = 600

BASE = """
name = "t"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 1.0], [0.0, 0.0]]
B = [[0.0], [1.0]]
[model]
sample_time = 0.2
[mpc]
horizon = {N}
norm = "{norm}"
Q = [[1.0, 0.0], [0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -2.0]
x_max = [5.0, 2.0]
u_min = [-1.0]
u_max = [1.0]
"""

# a two-input, three-state plant (two carts and a spring between them, the second pushed)
BASE2 = """
name = "t2"
[plant]
states = ["p1", "p2", "v"]
inputs = ["u1", "u2"]
A = [[0.0, 0.0, 1.0], [0.0, -0.5, 0.5], [0.0, 0.0, -0.2]]
B = [[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]]
[model]
sample_time = 0.25
[mpc]
horizon = {N}
norm = "{norm}"
Q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.5]]
R = [[0.5, 0.0], [0.0, 0.5]]
x_min = [-3.0, -3.0, -2.0]
x_max = [3.0, 3.0, 2.0]
u_min = [-1.0, -1.0]
u_max = [1.0, 1.0]
"""

REF_BOX = '[mpc.reference]\nsignal = "y"\nlower = [-1.0]\nupper = [1.0]\n'
LQR = 'P = "lqr"\nterminal_set = "lqr"\n'

#: name -> (extra [mpc] lines, norm, horizon, base)
CASES: dict[str, tuple[str, str, int, str]] = {
    "nc1_2": ("control_horizon = 1\n", "2", 4, BASE),
    "nc2_inf": ("control_horizon = 2\n", "inf", 4, BASE),
    "rates_2": ("du_min = [-0.3]\ndu_max = [0.3]\nRd = [[1.0]]\n", "2", 4, BASE),
    "rates_Rd0_2": ("du_min = [-0.3]\ndu_max = [0.3]\nRd = [[0.0]]\n", "2", 3, BASE),
    "rates_1": ("Rd = [[1.0]]\n", "1", 3, BASE),
    "rates_inf": ("du_min = [-0.3]\ndu_max = [0.3]\nRd = [[0.5]]\n", "inf", 3, BASE),
    "outputs_inf": ("C = [[1.0, 1.0]]\ny_min = [-3.0]\ny_max = [2.0]\n", "inf", 4, BASE),
    "soft_y_2": ('C = [[1.0, 0.0]]\ny_max = [1.0]\nsoft = ["y_max"]\n', "2", 4, BASE),
    "soft_y_1": ('C = [[1.0, 0.0]]\ny_max = [1.0]\nsoft = ["y_max"]\n', "1", 4, BASE),
    # ties: the soft weight equals the state weight's scale (1/inf-norm degeneracy)
    "soft_x_inf_ties": ('soft = ["x_max"]\nsoft_weight = 1.0\ndomain_bound = 6.0\n', "inf", 3,
                        BASE),
    "mixed_2": ("[[mpc.constraints]]\nHx = [[1.0, 1.0]]\nHu = [[1.0]]\nh = [2.5]\n", "2", 4,
                BASE),
    "ref_fixed_2": ('C = [[1.0, 0.0]]\n[mpc.reference]\nsignal = "y"\nvalue = [1.0]\n', "2", 4,
                    BASE),
    "ref_box_2": ("C = [[1.0, 0.0]]\n" + REF_BOX, "2", 4, BASE),
    "ref_box_inf": ("C = [[1.0, 0.0]]\n" + REF_BOX, "inf", 3, BASE),
    "servo_2": ("C = [[1.0, 0.0]]\ndu_min = [-0.3]\ndu_max = [0.3]\n" + REF_BOX, "2", 4, BASE),
    "lqr_2": (LQR, "2", 3, BASE),
    "lqr_ref_box_2": (LQR + "C = [[1.0, 0.0]]\n" + REF_BOX, "2", 3, BASE),
    "terminal_poly_inf": (
        "terminal_set = { A = [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]], "
        "b = [1.0, 1.0, 1.0, 1.0] }\n", "inf", 4, BASE),
    "lqr_set_1": ('terminal_set = "lqr"\n', "1", 3, BASE),
    "combo_1": ('control_horizon = 2\nC = [[1.0, 0.0]]\ny_max = [1.5]\nsoft = ["y_max"]\n'
                "du_min = [-0.5]\ndu_max = [0.5]\n" + REF_BOX, "1", 3, BASE),
    "two_input_mixed_blocked_2": (
        "control_horizon = 2\n[[mpc.constraints]]\nHx = [[0.0, 0.0, 0.0]]\nHu = [[1.0, 1.0]]\n"
        "h = [1.2]\n[[mpc.constraints]]\nHx = [[1.0, -1.0, 0.0]]\nh = [2.0]\n", "2", 4, BASE2),
}


@functools.cache
def design(name: str):
    extra, norm, N, base = CASES[name]
    problem = loads_spec(base.format(N=N, norm=norm) + extra)
    model = discretize(problem)
    law = ce.synthesize(problem)
    return problem, model, law


def _spec(extra: str, norm: str = "2", N: int = 4, base: str = BASE):
    return loads_spec(base.format(N=N, norm=norm) + extra)


def _probes(law, X, idx, lo, hi, rng, count=40) -> np.ndarray:
    located = np.flatnonzero(idx >= 0)
    out = []
    for p in rng.choice(located, size=min(count, located.size), replace=False):
        A, b = law.A[idx[p]], law.b[idx[p]]
        nrm = np.linalg.norm(A, axis=1)
        A, b = A / nrm[:, None], b / nrm
        d = rng.normal(size=X.shape[1])
        d /= np.linalg.norm(d)
        Ad = A @ d
        pos = Ad > 1e-12
        if not np.any(pos):
            continue
        t = (b[pos] - A[pos] @ X[p]) / Ad[pos]
        j = int(np.argmin(t))
        e = X[p] + max(float(t[j]), 0.0) * d
        off = PROBE * (1.0 + np.max(np.abs(e)))
        for q in (e - off * A[pos][j], e + off * A[pos][j]):
            if np.all(q > lo) and np.all(q < hi):
                out.append(q)
    return np.array(out).reshape(-1, X.shape[1])


def oracle(problem, model, law, npts: int, seed: int = 0, box=None, judge=None) -> list[str]:
    """The failures of the four checks of the module docstring (empty: the law is exact);
    the samples in ``box`` ``(lo, hi)`` when given, else in the parameter box. ``judge(theta,
    u)``, when given, has the last word on a move whose cost is not Clarabel's optimum
    (an exact LP where Clarabel is not accurate enough)."""
    fm = formulation(problem.mpc, model)
    lo, hi = fm.theta_lo + fm.theta_op, fm.theta_hi + fm.theta_op
    if box is not None:
        lo, hi = (np.asarray(v, float) for v in box)
    rng = np.random.default_rng(seed)
    X = lo + (hi - lo) * rng.uniform(size=(npts, fm.d))
    if law.num_regions:
        blo = np.maximum(law.boxes[0].min(axis=0), lo)
        bhi = np.minimum(law.boxes[1].max(axis=0), hi)
        k = npts // 3
        X[:k] = blo + (bhi - blo) * rng.uniform(size=(k, fm.d))
    idx = law.locate(X)
    X = np.vstack([X, _probes(law, X, idx, lo, hi, rng)])
    idx = law.locate(X)
    U = law.evaluate(X)
    online = ce.OnlineMpc(problem.mpc, model)
    dA, db = law.domain_A, law.domain_b
    nrm = np.linalg.norm(dA, axis=1)
    fails = []
    for p, x in enumerate(X):
        sol = online.solve(x)
        tol = 1e-6 * max(1.0, float(np.max(np.abs(x))))
        near = (np.min(np.abs(db - dA @ x) / nrm) <= tol) if dA.size else True
        if sol.feasible and idx[p] < 0:
            if not near:
                fails.append(f"hole at theta={x.tolist()} (online cost {sol.cost:.9g})")
        elif not sol.feasible and idx[p] >= 0:
            if not near:
                fails.append(f"false region {idx[p]} at theta={x.tolist()}")
        elif sol.feasible:
            if not np.all(np.isfinite(U[p])):
                fails.append(f"non-finite u at theta={x.tolist()}")
                continue
            c = online.first_move_cost(x, U[p])
            if not abs(c - sol.cost) <= RTOL * max(1.0, abs(sol.cost)) and not (
                    judge is not None and judge(x, U[p])):
                fails.append(f"theta={x.tolist()} region {idx[p]}: u={U[p].tolist()} "
                             f"cost {c:.12g} vs optimum {sol.cost:.12g}")
    counts = np.zeros(X.shape[0], dtype=int)
    for A, b in zip(law.A, law.b, strict=True):
        counts += np.all(X @ A.T < b - STRICT, axis=1)
    fails += [f"overlap at theta={X[p].tolist()}" for p in np.flatnonzero(counts > 1)]
    return fails


@pytest.mark.parametrize("name", sorted(CASES))
def test_law_matches_online_mpc(name):
    problem, model, law = design(name)
    assert law.num_regions > 0
    assert law.n == formulation(problem.mpc, model).d
    fails = oracle(problem, model, law, N_FAST)
    assert not fails, f"{name}: {len(fails)} failures\n" + "\n".join(fails[:8])


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(CASES))
def test_law_matches_online_mpc_dense(name, request):
    if not (os.environ.get("CODEV_SLOW") or request.config.getoption("-m") == "slow"):
        pytest.skip("dense oracle: run with -m slow")
    problem, model, law = design(name)
    fails = oracle(problem, model, law, N_SLOW, seed=1)
    assert not fails, f"{name}: {len(fails)} failures\n" + "\n".join(fails[:8])


def test_oracle_catches_a_wrong_law():
    problem, model, law = design("rates_2")
    bad = ce.ExplicitLaw(A=law.A, b=law.b, F=law.F.copy(), G=law.G + 1e-3,
                         states=law.states, inputs=law.inputs, parameters=law.parameters,
                         domain_A=law.domain_A, domain_b=law.domain_b)
    assert oracle(problem, model, bad, 40)


# --- the parameter -----------------------------------------------------------------------


def test_parameter_names_and_order():
    assert design("rates_2")[2].parameter_names == ("p", "v", "prev_u")
    assert design("ref_box_2")[2].parameter_names == ("p", "v", "ref_y0")
    assert design("servo_2")[2].parameter_names == ("p", "v", "prev_u", "ref_y0")
    assert design("lqr_2")[2].parameter_names == ("p", "v")
    assert design("lqr_2")[2].parameters == ()


def test_law_domain_in_u_prev_and_r_is_their_box():
    problem, model, law = design("servo_2")
    from codev_engine.formulation import U_PREV_MARGIN

    lo, hi = law.boxes[0].min(axis=0), law.boxes[1].max(axis=0)
    # u_prev: the input box widened by U_PREV_MARGIN; r: the reference box
    np.testing.assert_allclose(lo[2:], [-1.0 - U_PREV_MARGIN, -1.0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(hi[2:], [1.0 + U_PREV_MARGIN, 1.0], rtol=0, atol=1e-9)


def test_law_with_parameters_saves_and_loads(tmp_path):
    law = design("servo_2")[2]
    back = ce.ExplicitLaw.load(law.save(tmp_path / "law.npz"))
    assert back.parameter_names == law.parameter_names and back.states == law.states
    X = np.array([[0.5, 0.1, 0.2, -0.3], [1.0, -0.5, 0.0, 0.9]])
    np.testing.assert_array_equal(back.evaluate(X), law.evaluate(X))


def test_section_is_the_law_at_fixed_parameters():
    law = design("servo_2")[2]
    sec = law.section([0.1, 0.4])
    assert sec.n == 2 and sec.meta["section"] == {"prev_u": 0.1, "ref_y0": 0.4}
    X = np.random.default_rng(3).uniform([-2, -1], [2, 1], size=(200, 2))
    full = np.hstack([X, np.tile([0.1, 0.4], (200, 1))])
    np.testing.assert_allclose(sec.evaluate(X), law.evaluate(full), rtol=1e-12, atol=1e-12)


# --- defaults and the regulator --------------------------------------------------------------


def _program_arrays(problem):
    p = build_program(problem.mpc, discretize(problem)).program
    return [p.H, p.c, p.C, p.A, p.b, p.F, p.A_theta, p.b_theta]


@pytest.mark.parametrize("norm", ["2", "1", "inf"])
def test_spelled_out_defaults_give_the_regulator_bit_for_bit(norm):
    plain = _spec("", norm)
    spelled = _spec("control_horizon = 4\nsoft = []\nsoft_weight = 10000.0\n", norm)
    for a, b in zip(_program_arrays(plain), _program_arrays(spelled), strict=True):
        assert a.shape == b.shape and np.array_equal(a, b)


def test_session_keys_of_old_specs_ignore_the_new_fields():
    from codev_engine.session.keys import canon

    doc = canon(_spec("").mpc)
    assert "control_horizon" not in doc and "reference" not in doc and "soft" not in doc
    assert "control_horizon" in canon(_spec("control_horizon = 2\n").mpc)


# --- terminal ingredients ------------------------------------------------------------------


def test_lqr_cost_is_the_riccati_solution_and_the_law_is_lqr_at_the_target():
    import control

    problem, model, law = design("lqr_2")
    P, _, K = control.dare(model.A, model.B, problem.mpc.Q, problem.mpc.R)
    fm = formulation(problem.mpc, model)
    np.testing.assert_allclose(fm.P, P, rtol=1e-9)
    i = int(law.locate(np.zeros((1, 2)))[0])
    np.testing.assert_allclose(law.F[i], -K, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(law.G[i], 0.0, atol=1e-9)


def test_lqr_terminal_set_is_recursively_feasible():
    problem, model, law = design("lqr_2")
    fm = formulation(problem.mpc, model)
    assert fm.term_b.size and fm.terminal_steps >= 0
    rng = np.random.default_rng(0)
    lo, hi = fm.theta_lo + fm.theta_op, fm.theta_hi + fm.theta_op
    X = lo + (hi - lo) * rng.uniform(size=(3000, 2))
    X = X[law.locate(X) >= 0]
    assert X.shape[0] > 200
    U = law.evaluate(X)
    Xn = (X - model.x_op) @ model.A.T + (U - model.u_op) @ model.B.T + model.c + model.x_op
    inside = law.locate(Xn) >= 0
    # a successor on the domain's boundary may round to outside: allow 1e-9 slack
    if not inside.all():
        dA, db = law.domain_A, law.domain_b
        slack = np.max(Xn[~inside] @ dA.T - db, axis=1)
        assert np.all(slack <= 1e-9), slack.max()


def test_lqr_terminal_set_is_invariant_for_the_lqr_loop():
    problem, model, _ = design("lqr_2")
    fm = formulation(problem.mpc, model)
    rng = np.random.default_rng(1)
    V = rng.uniform(-3, 3, size=(20000, 2))
    V = V[np.all(V @ fm.term_Ax.T <= fm.term_b, axis=1)]
    Vn = V @ (model.A - model.B @ fm.K).T
    assert np.all(Vn @ fm.term_Ax.T <= fm.term_b + 1e-9)
    U = -V @ fm.K.T
    assert np.all(np.abs(U) <= 1.0 + 1e-9)


# --- tracking ------------------------------------------------------------------------------


def test_a_fixed_reference_is_tracked_without_offset():
    problem, model, law = design("ref_fixed_2")
    x = np.array([-2.0, 0.0])
    for _ in range(300):
        u = law.evaluate(x)[0]
        assert np.all(np.isfinite(u))
        x = model.A @ (x - model.x_op) + model.B @ (u - model.u_op) + model.c + model.x_op
    assert abs(x[0] - 1.0) < 1e-6 and abs(x[1]) < 1e-6


def test_free_reference_law_tracks_each_reference():
    problem, model, law = design("servo_2")
    for r in (-0.8, 0.3, 0.9):
        x, u_prev = np.array([0.0, 0.0]), np.zeros(1)
        for _ in range(400):
            u = law.evaluate(np.concatenate([x, u_prev, [r]]))[0]
            assert np.all(np.isfinite(u))
            assert abs(u[0] - u_prev[0]) <= 0.3 + 1e-9
            x = model.A @ x + model.B @ u + model.c
            u_prev = u
        assert abs(x[0] - r) < 1e-5


def test_target_with_offset_operating_point_and_drift():
    # a plant with an operating point away from 0 and dynamics with a constant term
    text = BASE.format(N=3, norm="2").replace(
        "[model]\nsample_time = 0.2",
        "[model]\nsample_time = 0.2\noperating_point = { x = [0.5, 0.0], u = [0.0] }",
    ) + 'C = [[1.0, 0.0]]\n[mpc.reference]\nsignal = "y"\nvalue = [1.5]\n'
    problem = loads_spec(text)
    model = discretize(problem)
    fm = formulation(problem.mpc, model)
    xs, us = model.x_op + fm.sx, model.u_op + fm.su
    np.testing.assert_allclose(xs, [1.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(us, [0.0], atol=1e-12)


# --- soft constraints ----------------------------------------------------------------------


@pytest.mark.parametrize("norm", ["2", "1"])
def test_soft_law_is_the_hard_law_where_the_hard_problem_is_feasible(norm):
    soft = _spec('C = [[1.0, 0.0]]\ny_max = [1.0]\nsoft = ["y_max"]\n', norm)
    hard = _spec("C = [[1.0, 0.0]]\ny_max = [1.0]\n", norm)
    ls, lh = ce.synthesize(soft), ce.synthesize(hard)
    rng = np.random.default_rng(2)
    X = rng.uniform([-5, -2], [5, 2], size=(3000, 2))
    in_hard = lh.locate(X) >= 0
    assert in_hard.sum() > 300 and (~in_hard).sum() > 300
    np.testing.assert_allclose(ls.evaluate(X[in_hard]), lh.evaluate(X[in_hard]),
                               rtol=1e-6, atol=1e-6)
    # ... and the soft law is defined beyond it (the state and input bounds stay hard)
    in_soft = ls.locate(X) >= 0
    assert np.all(in_soft[in_hard]) and in_soft.sum() > in_hard.sum() + 100


def test_soft_state_bound_extends_the_domain_to_domain_bound():
    problem = _spec('soft = ["x_max"]\ndomain_bound = 7.0\n', "inf", N=2)
    fm = formulation(problem.mpc, discretize(problem))
    np.testing.assert_array_equal(fm.theta_hi, [7.0, 7.0])
    np.testing.assert_array_equal(fm.theta_lo, [-5.0, -2.0])


# --- bad input -----------------------------------------------------------------------------


BAD = [
    ('P = "lqr"\n', "inf", "mpc.P", "norm"),
    ('P = "riccati"\n', "2", "mpc.P", "lqr"),
    ("control_horizon = 5\n", "2", "mpc.control_horizon", "at most"),
    ("control_horizon = 0\n", "2", "mpc.control_horizon", ">= 1"),
    ("du_min = [0.1]\ndu_max = [0.3]\n", "2", "mpc.du_min[0]", "constant input"),
    ("du_min = [-0.1, 0.2]\n", "2", "mpc.du_min", "1 number"),
    ("Rd = [[1.0, 0.0]]\n", "2", "mpc.Rd", "1×1"),
    ("y_max = [1.0]\n", "2", "mpc.y_max", "mpc.C"),
    ("C = [[1.0]]\n", "2", "mpc.C", "2 columns"),
    ('soft = ["u_max"]\n', "2", "mpc.soft[0]", "x_min"),
    ('C = [[1.0, 0.0]]\nsoft = ["y_max"]\n', "2", "mpc.soft[0]", "names no constraint"),
    ('soft = ["x_max", "x_max"]\n', "2", "mpc.soft[1]", "twice"),
    ("soft_weight = 0.0\n", "2", "mpc.soft_weight", "> 0"),
    ("[[mpc.constraints]]\nHx = [[1.0, 0.0]]\n", "2", "mpc.constraints[0].h", "missing"),
    ("[[mpc.constraints]]\nh = [1.0]\n", "2", "mpc.constraints[0]", "Hx, Hu"),
    ("[[mpc.constraints]]\nHu = [[1.0], [2.0]]\nh = [1.0]\n", "2", "mpc.constraints[0].Hu",
     "1×1"),
    ('[mpc.reference]\nsignal = "y"\nvalue = [1.0]\n', "2", "mpc.reference.signal", "mpc.C"),
    ('[mpc.reference]\nsignal = "z"\nvalue = [1.0]\n', "2", "mpc.reference.signal", '"y"'),
    ('[mpc.reference]\nsignal = "x"\nvalue = [1.0, 0.0]\nlower = [0.0, 0.0]\n', "2",
     "mpc.reference", "not both"),
    ('[mpc.reference]\nsignal = "x"\n', "2", "mpc.reference", "give value"),
    ('[mpc.reference]\nsignal = "x"\nlower = [0.0, 0.0]\n', "2", "mpc.reference.upper",
     "missing"),
    ('terminal_set = "maximal"\n', "2", "mpc.terminal_set", "lqr"),
    ("terminal_set = { A = [[1.0]], b = [1.0] }\n", "2", "mpc.terminal_set.A", "2 columns"),
]


@pytest.mark.parametrize(("extra", "norm", "field", "words"), BAD)
def test_bad_field_is_one_error_naming_it(extra, norm, field, words):
    with pytest.raises(ce.SpecError) as err:
        _spec(extra, norm)
    assert err.value.field == field, str(err.value)
    assert words in str(err.value)


LATE = [
    # found by the MPC stage (they need the model): still one SpecError naming the field
    ('[mpc.reference]\nsignal = "x"\nvalue = [1.0, 0.5]\n', "mpc.reference.value",
     "steady state"),
    ('[mpc.reference]\nsignal = "x"\nlower = [0.0, 0.0]\nupper = [1.0, 1.0]\n',
     "mpc.reference", "steady state"),
    ("terminal_set = { A = [[1.0, 0.0], [-1.0, 0.0]], b = [1.0, 1.0] }\n", "mpc.terminal_set",
     "unbounded"),
    ("terminal_set = { A = [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]], "
     "b = [-1.0, -1.0, 1.0, 1.0] }\n", "mpc.terminal_set", "empty"),
]


@pytest.mark.parametrize(("extra", "field", "words"), LATE)
def test_bad_design_is_one_error_naming_the_field(extra, field, words):
    with pytest.raises(ce.SpecError) as err:
        _spec(extra)
    assert err.value.field == field, str(err.value)
    assert words in str(err.value)


def test_rates_with_a_continuous_hold_is_refused():
    text = BASE.format(N=3, norm="2") + "du_max = [0.5]\n" + (
        '[verify]\ntime_horizon = 1.0\nhold = "continuous"\n'
        "initial_set = { lower = [0.0, 0.0], upper = [0.1, 0.1] }\n"
    )
    with pytest.raises(ce.SpecError) as err:
        loads_spec(text)
    assert err.value.field == "verify.hold"


def test_verifying_a_law_with_parameters_on_a_nonlinear_plant_is_an_unknown_verdict():
    # the nonlinear engine does not follow u_prev yet: a verdict, not an error
    text = BASE.format(N=3, norm="2").replace(
        'A = [[0.0, 1.0], [0.0, 0.0]]\nB = [[0.0], [1.0]]', 'dynamics = ["v", "u - 0.1*sin(p)"]'
    ) + "du_min = [-0.5]\ndu_max = [0.5]\n" + (
        '[verify]\ntime_horizon = 1.0\nhold = "zoh"\n'
        "initial_set = { lower = [0.0, 0.0], upper = [0.1, 0.1] }\n"
    )
    problem = loads_spec(text)
    law = ce.synthesize(problem)
    res = ce.verify(problem, law)
    assert res.verdict == "unknown" and res.reason == "law_parameters"


# --- the bundled examples of the formulations ---------------------------------------------


@pytest.mark.parametrize(
    "fname", ["double_integrator_lqr.toml", "mass_spring_soft.toml", "two_carts_mixed.toml"]
)
def test_formulation_examples_verify_robustly_safe(fname):
    from pathlib import Path

    problem = ce.load_spec(Path(__file__).resolve().parents[2] / "examples" / fname)
    law = ce.synthesize(problem)
    res = ce.verify(problem, law)
    assert res.verdict == "robustly_safe", res.summary() if hasattr(res, "summary") else res


# --- verification over theta = (x, u_prev, r) ---------------------------------------------

VERIFY = """
[verify]
time_horizon = {T}
hold = "zoh"
step = 0.02
initial_set = {{ lower = [{x0lo}], upper = [{x0hi}] }}
{extra}
[[verify.safe]]
lower = [-5.0, -2.0]
upper = [5.0, 2.0]
{unsafe}
"""

THETA_CASES = {
    # name: (mpc extra, verify extra, initial box, unsafe block, expected verdict)
    "rates_initial_input_box": (
        "du_min = [-0.3]\ndu_max = [0.3]\nRd = [[0.5]]\n",
        "initial_input = { lower = [-0.4], upper = [0.4] }", ("1.0, -0.2", "1.3, 0.2"), "",
        "robustly_safe"),
    "servo_reference_box": (
        "C = [[1.0, 0.0]]\ndu_min = [-0.3]\ndu_max = [0.3]\n" + REF_BOX,
        "reference = { lower = [-0.5], upper = [0.5] }\ninitial_input = [0.0]",
        ("-0.2, -0.1", "0.2, 0.1"), "", "robustly_safe"),
    "tracking_free_reference": (
        "C = [[1.0, 0.0]]\n" + REF_BOX, "reference = [0.8]", ("-0.1, 0.0", "0.1, 0.1"), "",
        "robustly_safe"),
    # the slew limit makes the loop overshoot past p = 2.2 from a fast start
    "rates_overshoot_unsafe": (
        "du_min = [-0.05]\ndu_max = [0.05]\n", "initial_input = [0.0]",
        ("1.5, 1.5", "1.6, 1.6"), "[[verify.unsafe]]\nlower = [2.2, -inf]\nupper = [inf, inf]",
        "unsafe"),
}


def _theta_problem(name: str):
    mpc_extra, v_extra, (lo, hi), unsafe, _ = THETA_CASES[name]
    text = BASE.format(N=4, norm="2") + mpc_extra
    # [mpc.reference] ends the [mpc] table: the [verify] tables come after it
    text += VERIFY.format(T=4.0, x0lo=lo, x0hi=hi, extra=v_extra, unsafe=unsafe)
    return loads_spec(text)


@functools.cache
def _theta_verified(name: str):
    problem = _theta_problem(name)
    law = ce.synthesize(problem)
    return problem, law, ce.verify(problem, law)


@pytest.mark.parametrize("name", sorted(THETA_CASES))
def test_verification_over_theta_is_sound_by_dense_simulation(name):
    from codev_engine.reach.simulate import simulate_many, theta_initial_box, violations_many

    problem, law, res = _theta_verified(name)
    assert res.verdict == THETA_CASES[name][-1], (res.verdict, res.reason)
    n = problem.plant.n
    lo, hi = theta_initial_box(problem)
    rng = np.random.default_rng(5)
    T0 = np.vstack([lo, hi, 0.5 * (lo + hi), rng.uniform(lo, hi, size=(60, lo.size))])
    vs = problem.verify
    t, X, U, alive = simulate_many(problem, law, T0[:, :n], extra0=T0[:, n:],
                                   dt=vs.step / 10, dt_out=0.3 * vs.step)
    if res.verdict == "robustly_safe":
        bad, _ = violations_many(problem, t, X, U, alive)
        assert not bad.any(), f"UNSOUND: {int(bad.sum())} simulations violate"
        until = vs.time_horizon
    else:
        cex = res.counterexample
        assert cex is not None and cex.extra0.shape == (lo.size - n,)
        # the counterexample replays: same violation from the same theta0
        from codev_engine.reach.simulate import first_violation, simulate

        again = simulate(problem, law, cex.x0, extra0=cex.extra0)

        assert first_violation(problem, law, again) is not None
        until = cex.t - vs.step
    tube = res.tube
    ks = np.flatnonzero(t <= until)
    ok = alive[:, ks]
    P, K = np.nonzero(ok)
    inside = tube.contains(t[ks][K], X[P, ks[K]], 1e-7)
    assert inside.all(), f"UNSOUND tube: {int((~inside).sum())} states outside"


def test_counterexample_with_theta_survives_save_and_load(tmp_path):
    problem, law, res = _theta_verified("rates_overshoot_unsafe")
    back = type(res).load(res.save(tmp_path / "v.npz"))
    np.testing.assert_array_equal(back.counterexample.extra0, res.counterexample.extra0)


def test_initial_input_and_reference_bad_input():
    base = BASE.format(N=3, norm="2")
    verify = VERIFY.format(T=1.0, x0lo="0.0, 0.0", x0hi="0.1, 0.1", extra="{}", unsafe="")
    cases = [
        ("", "initial_input = [0.0]", "verify.initial_input", "no previous input"),
        ("du_max = [0.3]\n", "initial_input = [2.0]", "verify.initial_input", "outside"),
        ("du_max = [0.3]\n", "initial_input = [0.0, 1.0]", "verify.initial_input", "1 number"),
        ("", "reference = [0.0]", "verify.reference", "no reference"),
        ("C = [[1.0, 0.0]]\n" + REF_BOX, "reference = [2.0]", "verify.reference", "inside"),
    ]
    for mpc_extra, v_extra, field, words in cases:
        with pytest.raises(ce.SpecError) as err:
            loads_spec(base + mpc_extra + verify.replace("{}", v_extra))
        assert err.value.field == field and words in str(err.value), str(err.value)


def test_examples_over_theta_match_online_mpc(example_law):
    """The bundled examples whose law takes (x, u_prev, r), through this file's oracle."""
    from test_synthesis_oracle import THETA_EXAMPLES

    assert THETA_EXAMPLES == ["dc_motor_servo.toml"]
    for fname in THETA_EXAMPLES:
        problem, law = example_law(fname)
        fails = oracle(problem, discretize(problem), law, N_FAST)
        assert not fails, f"{fname}: {len(fails)} failures\n" + "\n".join(fails[:8])


@pytest.mark.slow
def test_dc_motor_servo_verifies_robustly_safe(request):
    if not (os.environ.get("CODEV_SLOW") or request.config.getoption("-m") == "slow"):
        pytest.skip("~5 s of verification (3000 branches over theta): run with -m slow")
    from pathlib import Path

    problem = ce.load_spec(Path(__file__).resolve().parents[2] / "examples" / "dc_motor_servo.toml")
    law = ce.synthesize(problem)
    assert law.parameter_names == ("angle", "speed", "prev_V", "ref_y0")
    res = ce.verify(problem, law)
    assert res.verdict == "robustly_safe"
