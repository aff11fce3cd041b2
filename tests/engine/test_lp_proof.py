"""``solve_lp``'s answers are proved: a wrong "infeasible" would drop a piece of a reach set.

The strips below were found by a randomised search (seeded) over thin polytopes of nearly
parallel rows: each has a point inside every row by 2e-8 (the first) or 1.2e-8 (the
second), yet DAQP 0.11 with ``solve_lp``'s settings calls the first infeasible, and HiGHS
(through SciPy, with presolve) the second.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from codev_engine.geometry.lp_proof import (
    certificate_holds,
    farkas_proof,
    highs_infeasibility,
    one_sided,
    optimum_proved,
)
from codev_engine.geometry.polytope import chebyshev_ball, solve_lp

# DAQP: infeasible (for the costs 0 and x1); x0 inside every row by >= 2.2e-8
DAQP_A = np.array([
    [-0.7471202142392163, 0.06411739639963712],
    [-0.7471198729624909, 0.0641171870617063],
    [-0.7471202197306401, 0.06411717270131906],
    [0.7471202142392163, -0.06411739639963712],
])
DAQP_B = np.array([0.26345639901612294, 0.26345620943852877, 0.2634563176690092,
                   -0.26345634232279924])
DAQP_X0 = np.array([-0.32348956313346866, 0.3395455504180084])

# HiGHS with presolve: infeasible; x0 inside every row by >= 1.2e-8 (DAQP: infeasible too)
HIGHS_A = np.array([
    [-0.41044115840432993, 0.1169349190900188],
    [-0.41044115373013174, 0.11693486298609844],
    [-0.4104411571170997, 0.11693490452023306],
    [-0.41044113324856923, 0.11693491619829102],
    [-0.41044110079631585, 0.11693490293856683],
    [-0.4104411467172796, 0.11693491954308198],
    [-0.41044112855501225, 0.11693492750692676],
    [0.41044115840432993, -0.1169349190900188],
    [0.41044115373013174, -0.11693486298609844],
    [0.4104411571170997, -0.11693490452023306],
])
HIGHS_B = np.array([2.531484261172735, 2.531483974910479, 2.5314842114558718,
                    2.5314841110777997, 2.531483873003241, 2.5314841923291427,
                    2.531484146346839, -2.5314841981484357, -2.5314838856874777,
                    -2.53148411658821])
HIGHS_X0 = np.array([-4.840974464337509, 4.656855689691184])

STRIPS = [(DAQP_A, DAQP_B, DAQP_X0), (HIGHS_A, HIGHS_B, HIGHS_X0)]


def _rows(A: np.ndarray, b: np.ndarray) -> tuple:
    n = A.shape[0]
    return A, b, np.full(n, -1e30), np.zeros(n, dtype=bool)


@pytest.mark.parametrize("A, b, x0", STRIPS)
def test_a_strip_with_a_point_inside_is_not_called_infeasible(A, b, x0):
    assert np.all(A @ x0 < b - 1e-8)  # the fixture: a point inside every row
    x, status, _ = solve_lp(np.zeros(2), A, b)
    assert status == "optimal"
    # a point of the set, or of its rows widened by no more than HiGHS's tolerance
    assert np.all(A @ x <= b + 1e-7)


def test_the_strips_fixtures_fool_the_solvers():
    """Guards the fixtures' purpose (a solver upgrade that fixes them shows here)."""
    import daqp

    x, _, flag, _ = daqp.solve(np.zeros((2, 2)), np.zeros(2), DAQP_A, DAQP_B.copy(),
                               np.full(4, -1e30), np.zeros(4, dtype=np.int32), eps_prox=1e-2,
                               primal_tol=1e-11, dual_tol=1e-12)
    assert flag == -1
    res = linprog(np.zeros(2), A_ub=HIGHS_A, b_ub=HIGHS_B, bounds=[(None, None)] * 2,
                  method="highs")
    assert res.status == 2


@pytest.mark.parametrize("A, b, x0", STRIPS)
def test_no_certificate_for_a_set_with_a_point(A, b, x0):
    # whatever the solvers' multipliers, the check refuses them: the set is not empty
    assert not farkas_proof(*_rows(A, b), None)
    G, h, E, e = one_sided(*_rows(A, b))
    assert highs_infeasibility(G, h, E, e, None) is not None


def test_a_cost_over_the_strip_matches_highs_without_presolve():
    f = np.array([1.0, 0.0])
    x, status, _ = solve_lp(f, DAQP_A, DAQP_B)  # DAQP: infeasible
    ref = linprog(f, A_ub=DAQP_A, b_ub=DAQP_B, bounds=[(None, None)] * 2, method="highs",
                  options={"presolve": False})
    assert status == {0: "optimal", 3: "unbounded"}[ref.status]
    if status == "optimal":
        assert f @ x == pytest.approx(ref.fun, abs=1e-6)
        assert np.all(DAQP_A @ x <= DAQP_B + 1e-7)


def test_the_chebyshev_lp_of_a_strip_is_never_infeasible():
    # (always feasible: a negative radius satisfies every row)
    centre, radius = chebyshev_ball(HIGHS_A, HIGHS_B)
    assert np.isfinite(radius) and radius > -1e-7


@pytest.mark.parametrize("gap", [1e-3, 1e-7])
def test_an_empty_set_is_still_infeasible(gap):
    # the strip cut by a slab on the other side of x0: empty by `gap`
    a = np.array([0.6, 0.8])
    A = np.vstack([DAQP_A, a, -a])
    b = np.concatenate([DAQP_B, [a @ DAQP_X0 - 1.0 - gap, -(a @ DAQP_X0 - 1.0)]])
    assert solve_lp(np.zeros(2), A, b)[1] == "infeasible"
    assert solve_lp(np.array([1.0, -2.0]), A, b)[1] == "infeasible"
    # within bounds, and with an equality
    lb, ub = np.full(2, -10.0), np.full(2, 10.0)
    assert solve_lp(np.zeros(2), A, b, lb=lb, ub=ub)[1] == "infeasible"
    assert solve_lp(np.zeros(2), np.vstack([a, -a]), b[-2:], Aeq=np.array([[1.0, 1.0]]),
                    beq=np.array([3.0]))[1] == "infeasible"


def test_a_certificate_that_does_not_prove_is_refused():
    # 0 <= x <= 1e-12: not empty; y = (1, 1) gives 0 x <= 1e-12, no contradiction
    G = np.array([[1.0], [-1.0]])
    h = np.array([1e-12, 0.0])
    E, e = np.zeros((0, 1)), np.zeros(0)
    assert not certificate_holds(G, h, E, e, np.array([1.0, 1.0]), np.zeros(0), None)
    # -1e-9 >= x >= 0: empty, proved by the same y
    h = np.array([-1e-9, 0.0])
    assert certificate_holds(G, h, E, e, np.array([1.0, 1.0]), np.zeros(0), None)
    # -2 <= x <= -1 is not empty; y = (1, 0.4) gives h' y = -0.2 < 0 only with its residual
    # r = 0.6 ignored (charged at R = 1: 0.4 > 0), and cleaning it does not help
    G2 = np.array([[1.0], [-1.0]])
    h2 = np.array([-1.0, 2.0])
    assert not certificate_holds(G2, h2, E, e, np.array([1.0, 0.4]), np.zeros(0), 1.0)
    # x <= -1e-9, 1.001 x >= 0 is empty: y = (1, 1) leaves r = -0.001, which the cleaning
    # on the support removes
    G3 = np.array([[1.0], [-1.001]])
    assert certificate_holds(G3, h, E, e, np.array([1.0, 1.0]), np.zeros(0), 1.0)


def test_an_optimum_stopped_short_is_refused():
    # min -x over x <= 1, x >= -5 (rows x <= 1, -x <= 5): optimum x = 1, multiplier 1
    M = np.array([[1.0], [-1.0]])
    upper, lower = np.array([1.0, 5.0]), np.full(2, -1e30)
    f = np.array([-1.0])
    lam = np.array([1.0, 0.0])
    assert optimum_proved(f, M, upper, lower, np.array([1.0]), lam)
    assert not optimum_proved(f, M, upper, lower, np.array([1.0 - 1e-6]), lam)
    # a multiplier with a residual that re-solving on its support removes (x is optimal)
    assert optimum_proved(f, M, upper, lower, np.array([1.0]), np.array([0.999, 0.0]))
    # a residual outside the active rows' span: min -x1 - 1e-6 x2 over x1 <= 1, |x2| <= 5
    # stopped at (1, 0), 5e-6 short of (1, 5), with the multiplier of x1 <= 1 alone
    M2 = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    f2 = np.array([-1.0, -1e-6])
    up2, lo2 = np.array([1.0, 5.0, 5.0]), np.full(3, -1e30)
    assert not optimum_proved(f2, M2, up2, lo2, np.array([1.0, 0.0]), np.array([1.0, 0, 0]))
    assert optimum_proved(f2, M2, up2, lo2, np.array([1.0, 5.0]), np.array([1.0, 1e-6, 0]))
    # a multiplier on an absent bound
    assert not optimum_proved(f, M, upper, lower, np.array([1.0]), np.array([1.0, -1.0]))
