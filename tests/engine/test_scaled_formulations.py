"""Every formulation of docs/spec.md in states of units far apart (issue 38): the law of
the plant with its states rescaled (``x_s = S x``, ``S`` diagonal, random factors) is the
law of the plant in its own units.

The formulations are ``test_formulations.CASES`` (move blocking, input rates, outputs, soft
output bounds, mixed constraints, fixed and free references, the LQR terminal cost and set,
a polytopic terminal set, two inputs; norms 1, inf and 2) and soft **state** bounds. Each
is transformed consistently into the rescaled units (:func:`scaled_design`: the prediction
model ``S A S^-1``, ``S B``, ``S c``; the state weights ``Q S^-1`` (norms 1/inf) or
``S^-1 Q S^-1`` (norm 2), the state bounds, ``C S^-1``, ``Hx S^-1``, the terminal set's
rows, a state reference times ``S``), its law synthesised there, mapped back to the plant's
units and checked by ``test_formulations.oracle`` (no holes, no false regions, optimal
moves, no overlaps) against the online MPC **of the plant in its own units** (Clarabel on
the rescaled problem is not accurate enough to judge: ``test_scaled_units``).

A soft state bound's slack is in the units of its state, and ``soft_weight`` prices each
unit alike: rescaled, the penalty of a unit of ``x_i`` becomes ``soft_weight * s_i``. The
plant-units design that is the same program is the soft **output** bound ``y = S x <=
S x_max`` (one slack per row, in the row's units): that is the reference for these cases.
The domain of a soft axis is ``domain_bound`` in the rescaled units: the rescaled design's
is ``domain_bound * min(s)``, inside the reference's along every axis, and the samples are
drawn in the rescaled law's parameter box (mapped back).

The default run draws a few cases and rescalings (Hypothesis, derandomised); the sweep is
``slow``. Soft bounds on both states (norm 2) are also run over ``domain_bound`` 5 to 600
and a grid of factors (a dozen by default, 224 behind ``slow``): where the mp-QP search had
left a hole and the laws' moves went past their bounds (``mpqp.VANISH_ULPS``,
``mpqp._Kernel._refined``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import Phase, assume, example, given, settings
from hypothesis import strategies as st
from test_formulations import BASE, BASE2, CASES, oracle
from test_synthesis_oracle import _slow_gate

import codev_engine as ce
from codev_engine.errors import SolverError
from codev_engine.formulation import formulation
from codev_engine.mp.balance import rows_back
from codev_engine.mpc import build_program
from codev_engine.pipeline import loads_spec
from codev_engine.plant import LinearModel, discretize
from codev_engine.spec.problem import MixedConstraint, MpcSpec, Problem, SetSpec
from codev_engine.synthesis import WEIGHT_SPREAD_LIMIT, weight_spread

#: soft state bounds: name -> (extra [mpc] lines, norm, horizon, base)
SOFT_X_CASES: dict[str, tuple[str, str, int, str]] = {
    "soft_x_max_1": ('soft = ["x_max"]\ndomain_bound = 6.0\n', "1", 3, BASE),
    "soft_x_both_2": ('soft = ["x_min", "x_max"]\ndomain_bound = 6.0\n', "2", 3, BASE),
    # ties: the soft weight equals the state weight's scale (1/inf-norm degeneracy)
    "soft_x_inf_ties": ('soft = ["x_max"]\nsoft_weight = 1.0\ndomain_bound = 6.0\n', "inf", 3,
                        BASE),
    "soft_x_min_inf_2in": ('soft = ["x_min"]\ndomain_bound = 4.0\n', "inf", 2, BASE2),
    # a price that matters (not an exact penalty): the moves depend on the slack's units
    "soft_x_cheap_2": ('soft = ["x_max"]\nsoft_weight = 1.0\ndomain_bound = 6.0\n', "2", 3,
                       BASE),
}
ALL_CASES = {**CASES, **SOFT_X_CASES}


def _cols(M: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``M S^-1``: a row on ``x`` as a row on ``x_s``."""
    return np.asarray(M, float) / s


def scaled_mpc(mpc: MpcSpec, s: np.ndarray) -> MpcSpec:
    """The ``[mpc]`` table in the states ``x_s = diag(s) x`` (the inputs and outputs keep
    their units; a soft state bound's slack is then in the rescaled state's units).

    Parameters
    ----------
    mpc : MpcSpec
    s : (n,) ndarray
        The factors, > 0.

    Returns
    -------
    MpcSpec
    """
    quad = mpc.norm == "2"

    def weight(M):
        if M is None:
            return None
        return _cols(M, s) / s[:, None] if quad else _cols(M, s)

    ts = mpc.terminal_set
    if isinstance(ts, SetSpec):
        if ts.kind == "polytope":
            ts = replace(ts, A=_cols(ts.A, s))
        else:
            ts = replace(ts, lower=ts.lower * s, upper=ts.upper * s)
    ref = mpc.reference
    if ref is not None and ref.signal == "x":
        ref = replace(ref, **{k: None if getattr(ref, k) is None else getattr(ref, k) * s
                              for k in ("value", "lower", "upper")})
    return replace(
        mpc, Q=weight(mpc.Q), P=weight(mpc.P), x_min=mpc.x_min * s, x_max=mpc.x_max * s,
        C=None if mpc.C is None else _cols(mpc.C, s), terminal_set=ts, reference=ref,
        constraints=tuple(MixedConstraint(Hx=_cols(c.Hx, s), Hu=c.Hu, h=c.h)
                          for c in mpc.constraints),
    )


def scaled_model(model: LinearModel, s: np.ndarray) -> LinearModel:
    """The prediction model in ``x_s = diag(s) x``: ``S A S^-1``, ``S B``, ``S c``,
    ``S x_op`` (the continuous matrices dropped: the law needs the discrete ones)."""
    return replace(model, A=s[:, None] * model.A / s, B=s[:, None] * model.B, c=s * model.c,
                   x_op=s * model.x_op, Ac=None, Bc=None)


def soft_x_as_outputs(mpc: MpcSpec, s: np.ndarray) -> MpcSpec:
    """A design with soft state bounds, rescaled by ``s``, as the same program in the
    plant's units: soft output bounds ``y = S x <= S x_max`` (one slack per row, in the
    row's units, as the rescaled state bound's), the state bounds that were soft dropped
    (the domain along them: ``domain_bound``)."""
    n = mpc.x_min.shape[0]
    lo_soft, hi_soft = "x_min" in mpc.soft, "x_max" in mpc.soft
    return replace(
        mpc, C=np.diag(s),
        y_min=s * mpc.x_min if lo_soft else np.full(n, -np.inf),
        y_max=s * mpc.x_max if hi_soft else np.full(n, np.inf),
        soft=tuple("y_" + g[2:] if g in ("x_min", "x_max") else g for g in mpc.soft),
        x_min=np.full(n, -np.inf) if lo_soft else mpc.x_min,
        x_max=np.full(n, np.inf) if hi_soft else mpc.x_max,
    )


def scaled_design(name: str, exps, domain: float | None = None
                  ) -> tuple[Problem, LinearModel, Problem, LinearModel, np.ndarray]:
    """Case ``name`` rescaled by ``10**exps`` and its reference in the plant's units
    (``domain``: the case's ``domain_bound`` in the plant's units, if given).

    Returns
    -------
    (problem_s, model_s, problem, model, s)
        The rescaled design and its model; the reference design (a soft state bound
        written as the same program's soft output bound) and its model; the factors.
    """
    extra, norm, N, base = ALL_CASES[name]
    problem = loads_spec(base.format(N=N, norm=norm) + extra)
    if domain is not None:
        problem = replace(problem, mpc=replace(problem.mpc, domain_bound=float(domain)))
    model = discretize(problem)
    n = model.n
    s = 10.0 ** np.asarray(exps[:n], float)
    problem_s = replace(problem, mpc=scaled_mpc(problem.mpc, s))
    model_s = scaled_model(model, s)
    if {"x_min", "x_max"} & set(problem.mpc.soft):
        # a soft axis' domain is domain_bound in the rescaled units: D min(s) keeps it
        # inside the plant's D along every axis (the online MPC at states of 1e3 and more
        # is not accurate enough to judge)
        D = float(problem.mpc.domain_bound)
        problem_s = replace(problem_s, mpc=replace(problem_s.mpc, domain_bound=D * np.min(s)))
        problem = replace(problem, mpc=soft_x_as_outputs(problem.mpc, s))
    return problem_s, model_s, problem, model, s


def theta_factors(problem: Problem, model: LinearModel, s: np.ndarray) -> np.ndarray:
    """The factors of ``theta_s = diag(f) theta``: ``s`` on ``x`` (and on a free state
    reference), 1 on ``u_prev`` and an output reference."""
    fm = formulation(problem.mpc, model)
    f = np.ones(fm.d)
    f[:s.size] = s
    ref = problem.mpc.reference
    if ref is not None and ref.signal == "x" and ref.free:
        f[fm.d - s.size:] = s
    return f


def law_in_plant_units(law: ce.ExplicitLaw, f: np.ndarray) -> ce.ExplicitLaw:
    """The law over ``theta_s = diag(f) theta`` as a law over ``theta`` (rows made
    unit-norm again), its domain too."""
    As, bs = [], []
    for A, b in zip(law.A, law.b, strict=True):
        A, b = rows_back(A, b, 1.0 / f)
        As.append(A)
        bs.append(b)
    dA, db = rows_back(law.domain_A, law.domain_b, 1.0 / f)
    return ce.ExplicitLaw(A=As, b=bs, F=law.F * f, G=law.G, domain_A=dA, domain_b=db)


def exact_judge(problem: Problem, model: LinearModel):
    """``judge(theta, u)``: is ``u`` an optimal first move of the MPC at ``theta`` (plant
    units)? By an exact solve of the condensed program (HiGHS for norms 1/inf, DAQP's
    active-set QP for norm 2), the first move fixed or free, to 1e-9 relative of the MPC's
    cost; a move past an input bound by rounding (1e-9) is taken on the bound. Clarabel's
    optima of the soft designs with ``C = diag(1e3, 1e-3)`` were off by 1e-5 relative where
    the law's moves are the exact solver's to rounding, and a move 4.6e-13 above ``u_max``
    had no cost at all."""
    import daqp
    from scipy.optimize import linprog

    mp = build_program(problem.mpc, model)
    P = mp.program
    nz = P.c.size
    fix = np.eye(nz)[mp.u0_slice]
    umin, umax = np.asarray(problem.mpc.u_min, float), np.asarray(problem.mpc.u_max, float)

    def best(dth: np.ndarray, v: np.ndarray | None) -> float:
        c, rhs = P.c + P.C @ dth, P.b + P.F @ dth
        if problem.mpc.norm != "2":
            res = linprog(c, A_ub=P.A, b_ub=rhs, A_eq=None if v is None else fix,
                          b_eq=v, bounds=[(None, None)] * nz, method="highs")
            return float(res.fun) if res.status == 0 else np.inf
        A, up = (P.A, rhs) if v is None else (np.vstack([P.A, fix]), np.concatenate([rhs, v]))
        lo = np.full(up.size, -1e30)
        sense = np.zeros(up.size, dtype=np.int32)
        if v is not None:
            lo[-v.size:] = v
            sense[-v.size:] = 5  # (equalities)
        z, _, flag, _ = daqp.solve(np.ascontiguousarray(P.H), c, np.ascontiguousarray(A), up,
                                   lo, sense, primal_tol=1e-12, dual_tol=1e-12)
        return float(0.5 * z @ P.H @ z + c @ z) if flag == 1 else np.inf

    def judge(theta: np.ndarray, u: np.ndarray) -> bool:
        tol = 1e-9 * (1.0 + np.abs(u))
        if np.any(u > umax + tol) or np.any(u < umin - tol):
            return False
        u = np.clip(u, umin, umax)
        dth = mp.to_theta(theta)
        opt, c = best(dth, None), best(dth, u - mp.u_op)
        total = abs(opt + float(mp.theta_constant(dth[None])[0]))
        return bool(abs(c - opt) <= 1e-9 * max(1.0, total))

    return judge


def run(name: str, exps, npts: int = 40, seed: int = 0,
        domain: float | None = None) -> ce.ExplicitLaw:
    """Synthesise case ``name`` in units ``10**exps`` (``domain_bound`` ``domain`` in the
    plant's units, if given) and check it against the online MPC in the plant's units
    (``test_formulations.oracle``); the law in the rescaled units."""
    problem_s, model_s, problem, model, s = scaled_design(name, exps, domain)
    law = ce.synthesize(problem_s, model=model_s)
    assert law.num_regions > 0
    f = theta_factors(problem_s, model_s, s)
    fm = formulation(problem_s.mpc, model_s)
    box = ((fm.theta_lo + fm.theta_op) / f, (fm.theta_hi + fm.theta_op) / f)
    fails = oracle(problem, model, law_in_plant_units(law, f), npts, seed=seed, box=box,
                   judge=exact_judge(problem, model))
    assert not fails, (f"{name} x {s.tolist()}: {len(fails)} failures\n"
                       + "\n".join(fails[:6]))
    return law


#: the weights' spread the property covers. Past it, up to ``WEIGHT_SPREAD_LIMIT``, the
#: online MPC cannot always judge: soft bounds on both states, norm 2, factors 10^2.5 and
#: 10^3 (spread 1e10): Clarabel fails at some states (where it solves, the law is its
#: optimum). A move there was 2.6e-7 above ``u_max``: the law is now refined on its KKT
#: system (``mpqp._Kernel._refined``) and a saturated move set to its bound
#: (``synthesis.snap_saturated``, ``test_saturation``)
SPREAD_TESTED = 1e9


def _spread_ok(name: str, exps) -> bool:
    """Weights within ``SPREAD_TESTED`` (past ``WEIGHT_SPREAD_LIMIT`` ``synthesize``
    refuses in one line, by design: ``x'Qx`` with factors 1e-3 and 1e3 spans 1e12 times
    Q's own spread)."""
    problem_s = scaled_design(name, exps)[0]
    return weight_spread(problem_s.mpc)[0] <= min(SPREAD_TESTED, WEIGHT_SPREAD_LIMIT)


# decades of each state's factor, in halves: 10^-3 ... 10^3
_exps = st.lists(st.integers(-6, 6).map(lambda k: k / 2.0), min_size=3, max_size=3)


@settings(max_examples=3, deadline=None, derandomize=True, database=None,
          phases=(Phase.explicit, Phase.generate))  # (no shrinking: minutes of solves)
@given(name=st.sampled_from(sorted(ALL_CASES)), exps=_exps)
@example(name="soft_x_max_1", exps=[1.5, -2.0, 0.0])
@example(name="soft_y_1", exps=[2.0, -2.0, 0.0])  # (refused before: mplp perturbation)
@example(name="lqr_set_1", exps=[3.0, -3.0, 0.0])  # (false regions: terminal set)
@example(name="outputs_inf", exps=[3.0, -3.0, 0.0])  # (refused: parameter box)
def test_every_formulation_in_rescaled_units_is_the_mpc(name, exps):
    assume(_spread_ok(name, exps))
    run(name, exps, npts=30)


def test_a_soft_state_bound_is_priced_in_its_own_units():
    """The rescaled soft state bound is not the plant's soft state bound (its slack is
    priced per rescaled unit) but the plant's soft output bound ``y = S x``: the laws tell
    the two apart (else the soft-state cases above would prove nothing about the slack's
    units). With ``soft_weight = 1`` (a price that matters: 1e4 is an exact penalty either
    way) and p in units 10 times larger."""
    problem_s, model_s, problem, model, s = scaled_design("soft_x_cheap_2", [-1.0, 0.0])
    law = law_in_plant_units(ce.synthesize(problem_s, model=model_s),
                             theta_factors(problem_s, model_s, s))
    same = ce.synthesize(problem, model=model)
    plain = ce.synthesize(loads_spec(BASE.format(N=3, norm="2")
                                     + 'soft = ["x_max"]\nsoft_weight = 1.0\n'
                                     "domain_bound = 6.0\n"))
    X = np.random.default_rng(4).uniform([-5.0, -2.0], [6.0, 0.6], size=(400, 2))
    X = X[(law.locate(X) >= 0) & (same.locate(X) >= 0) & (plain.locate(X) >= 0)]
    assert X.shape[0] > 200
    np.testing.assert_allclose(law.evaluate(X), same.evaluate(X), rtol=1e-7, atol=1e-7)
    assert np.max(np.abs(law.evaluate(X) - plain.evaluate(X))) > 1e-2


def test_soft_state_bounds_in_units_31_and_3_norm_2():
    """Soft bounds on both states, norm 2, p in units 10^1.5 and v 10^0.5 smaller (found
    by the property above). The exact penalty (1e4) makes multipliers of 1.5e5, and a
    slack that is zero for every theta came out as -1.1e-11 + 3.7e-13 theta_2: against
    an absolute 1e-12 the active sets across the facet where x_2 reaches its bound were
    "empty", the search stopped at 5 regions and its coverage check refused ("the mp-QP
    search left a hole") for domain_bound 19 to 100 in the rescaled units. A row now
    vanishes by the rounding of its own terms (``mpqp.VANISH_ULPS``)."""
    run("soft_x_both_2", [1.5, 0.5, 0.0], npts=30)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ALL_CASES))
def test_every_formulation_in_rescaled_units_sweep(name, request):
    _slow_gate(request)
    rng = np.random.default_rng(sum(map(ord, name)))
    for _ in range(4):
        exps = rng.integers(-6, 7, 3) / 2.0
        if _spread_ok(name, exps):
            run(name, exps, npts=80, seed=1)


def _soft_both(exps, domain: float, npts: int, seed: int) -> None:
    """``soft_x_both_2`` with p and v in units ``10**exps`` and ``domain_bound`` ``domain``
    in the rescaled units (the plant's ``domain / min(s)``)."""
    s = 10.0 ** np.asarray(exps, float)
    run("soft_x_both_2", [*exps, 0.0], npts=npts, seed=seed, domain=domain / np.min(s))


@pytest.mark.parametrize(("exps", "domain"), [
    *(([1.5, 0.5], D) for D in (5.0, 10.0, 30.0, 60.0, 190.0)),
    ([0.5, -0.5], 19.0), ([0.5, -0.5], 100.0), ([1.0, 0.0], 30.0), ([1.0, 0.0], 100.0),
    ([-1.0, 0.5], 60.0), ([1.5, -0.5], 100.0),
])
def test_soft_state_bounds_over_domains_and_units(exps, domain):
    """The neighbours of the case above: ``domain_bound`` 5 to 190 in the rescaled units
    at its factors, and other factors (each axis' rows in the parameter set, the exact
    penalty's multipliers in its units). Factors 10^1.5 and 10^0.5 at 190 (and 10 and 1 at
    100) had a move 3e-9 (2e-9) past ``u_min`` before the law was refined
    (``mpqp._Kernel._refined``)."""
    _soft_both(exps, domain, npts=20, seed=0)


#: the online MPC (Clarabel) fails there: the reference cannot judge (states of 40 to 100)
_NO_REFERENCE = {(-1.0, 1.0, 30), (-0.5, 1.0, 19)}


def _sweep_cases():
    for a in (-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0):
        for b in (-0.5, 0.0, 0.5, 1.0):
            for D in (5, 10, 19, 30, 60, 100, 190, 600):
                marks = []
                if (a, b, D) in _NO_REFERENCE:
                    marks = [pytest.mark.xfail(strict=True, raises=SolverError,
                                               reason="the online MPC fails")]
                yield pytest.param([a, b], float(D), marks=marks, id=f"{a}_{b}_{D}")


@pytest.mark.slow
@pytest.mark.parametrize(("exps", "domain"), list(_sweep_cases()))
def test_soft_state_bounds_over_domains_and_units_sweep(exps, domain, request):
    """Every factor 10^-1 to 10^2 of p and 10^-0.5 to 10 of v (halves of decades), and
    ``domain_bound`` 5 to 600 in the rescaled units: no hole (the search's coverage check),
    and the law is the online MPC's. Before ``mpqp._Kernel._refined`` 25 of these 224 had
    a move past its bound by 2e-9 to 1.8e-6 (multipliers of 1e6: the law of an active set
    with ``u`` at its bound violated that bound by their rounding)."""
    _slow_gate(request)
    _soft_both(exps, domain, npts=20, seed=1)
