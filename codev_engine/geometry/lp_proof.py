"""Proofs of a small LP's answer, checked in numpy: DAQP's answers are taken only with one.

DAQP (a dual active-set solver; LPs through its proximal-point mode) answers most of the
engine's LPs (``polytope.solve_lp``). Its answers are floating-point decisions: it has
called a non-empty, thin polytope infeasible (the Chebyshev LP of a 3e-7 thick piece of a
reach set, and a parameter set with rows scaled 1e-6 .. 1e3, issue 38) and stopped 4e-5
short of a minimum. A caller that drops a piece of a tube on "infeasible", or decides
that a set lies below a bound by a maximum, would then lose states. So an answer is
accepted only with a certificate that numpy checks, else HiGHS is asked:

- "optimal": DAQP's multipliers ``lam`` (``f + M' lam = 0``) give a lower bound on the
  minimum by weak duality; the optimum is taken when ``f x`` is within
  ``GAP (1 + |f|_1 (1 + |x|_inf))`` of it, the dual residual charged at ``1 + |x|_inf``
  included, and the residual is below ``GAP (1 + |f|_1)`` (the rule of
  ``vertices._box_side``). On the cruise control DAQP stopped at 7.8504 for a maximum of
  7.8520 (issue 37) with a residual of 2e-6: refused here. Multipliers whose residual is
  rounding on their support are re-solved there (least squares) and checked again.
- "infeasible": a Farkas certificate, ``y >= 0`` on the inequality rows ``G x <= h``
  (free on the equalities ``E x = e``) with ``G' y + E' y_e = r`` and
  ``h' y + e' y_e < -|r|_1 R``: every ``x`` with ``|x|_inf <= R`` then violates a row.
  ``R`` is the box of the variables' bounds when they are all finite, else
  ``REACH (1 + |h, e|_inf)``: no point of the engine's sets lies a million times farther
  out than their offsets. The certificate is the multipliers of the elastic LP
  ``min t  s.t.  G x - max(|g|, 1) t <= h, E x = e, t >= 0`` (always feasible without
  equalities), solved by DAQP too: its optimum ``t > 0`` is the distance by which the
  rows miss each other, and its multipliers are the certificate. DAQP's own infeasible
  exit carries no multipliers (its Python interface leaves ``info["lam"]`` unset). The
  multipliers' residual is removed by least squares on their support, and the inequality
  is checked in exact rational arithmetic on those few rows.

DAQP called a strip of four nearly parallel rows infeasible with a point 2e-8 inside all of
them, and HiGHS (with presolve) one of ten (``tests/engine/test_lp_proof.py``); in
``benchmarks/verdicts.py`` DAQP called five of the point locator's box LPs infeasible
where HiGHS found points within 4e-13 of every row. So HiGHS's "infeasible" needs the same
certificate (:func:`highs_infeasibility`), and without one ``solve_lp`` answers over the
rows widened to where they meet.
"""

from __future__ import annotations

from fractions import Fraction

import daqp
import numpy as np

__all__ = [
    "GAP",
    "REACH",
    "certificate_holds",
    "farkas_proof",
    "highs_infeasibility",
    "one_sided",
    "optimum_proved",
]

#: duality gap (relative to the optimum) and dual residual (relative to the cost) within
#: which DAQP's optimum is taken (its tolerances are 1e-11 primal, 1e-12 dual)
GAP = 1e-9
#: without finite bounds, infeasibility is proved for ``|x|_inf <= REACH (1 + |offsets|)``
REACH = 1e6
_INF = 1e30


def optimum_proved(
    f: np.ndarray,
    M: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    x: np.ndarray,
    lam: np.ndarray,
) -> bool:
    """Do DAQP's multipliers prove ``x`` optimal for ``min f'x, lower <= M x <= upper``?

    Weak duality: for every feasible ``z``, ``f z = r z - lam' M z`` with ``r = f + M' lam``,
    and ``-lam_i M_i z >= -lam_i upper_i`` where ``lam_i > 0`` (``-lam_i lower_i`` where
    ``lam_i < 0``), so ``f z >= sum_i (that bound) - |r|_1 |z|_inf``.

    Parameters
    ----------
    f : (nx,) ndarray
    M : (n, nx) ndarray
    upper, lower : (n,) ndarray
        Row bounds, +-1e30 where absent (equalities: ``lower == upper``).
    x : (nx,) ndarray
        DAQP's optimum.
    lam : (n,) ndarray
        Its multipliers (DAQP's signs: > 0 at an upper bound, < 0 at a lower one).

    Returns
    -------
    bool
    """
    # (small arrays, once per LP of the engine's thousands: few numpy calls, Python sums)
    value = float(f @ x)
    size = 1.0 + max(map(abs, x.tolist()), default=0.0)
    cost = sum(map(abs, f.tolist()))
    if _bound_holds(f, M, upper, lower, lam, value, size, cost):
        return True
    # the multipliers' residual may be rounding on their support: solve stationarity again
    # there by least squares, signs kept, and check once more (else HiGHS, ~100x slower;
    # this proves the pendulum's one refused optimum). It cannot fix a proximal step's
    # residual (eps_prox (x - x_prev), outside the active rows' span: 5e-8 on the
    # headbox's thin pieces' Chebyshev LPs, 1.2e-6 wide, where DAQP stopped early)
    S = np.flatnonzero(lam)
    if S.size == 0:
        return False
    fix = np.linalg.lstsq(M[S].T, -(f + lam @ M), rcond=None)[0]
    lam2 = lam.copy()
    lam2[S] += fix
    if np.any(lam2[S] * lam[S] < 0.0):
        return False  # (a multiplier changed sign: the support was not the active set)
    return _bound_holds(f, M, upper, lower, lam2, value, size, cost)


def _bound_holds(f, M, upper, lower, lam, value, size, cost) -> bool:
    """:func:`optimum_proved`'s inequalities for the multipliers ``lam``."""
    # (a multiplier on an absent bound, +-1e30, makes the bound useless, not wrong)
    side = upper if lam.min(initial=0.0) >= 0.0 else np.where(lam > 0, upper, lower)
    dual = -float(lam @ side)
    res = sum(map(abs, (f + lam @ M).tolist()))  # the dual residual |f + M' lam|_1
    # (the residual charged at the optimum's size: the set's points that matter are there;
    # the gap measured against f's terms at x, whose rounding it cannot beat: on the CSTR
    # 1.7e-9 at |x| = 350 for a value of 0.19)
    gap = value - dual + res * size
    return gap <= GAP * (1.0 + cost * size) and res <= GAP * (1.0 + cost)


def one_sided(
    M: np.ndarray, upper: np.ndarray, lower: np.ndarray, equality: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """DAQP's rows ``lower <= M x <= upper`` as ``G x <= h`` and ``E x = e``.

    Parameters
    ----------
    M : (n, nx) ndarray
    upper, lower : (n,) ndarray
        Row bounds, +-1e30 where absent.
    equality : (n,) ndarray of bool
        Rows with ``lower == upper``.

    Returns
    -------
    G : (k, nx) ndarray
    h : (k,) ndarray
    E : (ke, nx) ndarray
    e : (ke,) ndarray
    """
    up = ~equality & (upper < _INF)
    lo = ~equality & (lower > -_INF)
    G = np.vstack([M[up], -M[lo]])
    h = np.concatenate([upper[up], -lower[lo]])
    return G, h, M[equality], upper[equality]


def certificate_holds(
    G: np.ndarray,
    h: np.ndarray,
    E: np.ndarray,
    e: np.ndarray,
    y: np.ndarray,
    ye: np.ndarray,
    box: float | None,
) -> bool:
    """Does ``(y, ye)`` prove ``{G x <= h, E x = e, |x|_inf <= R}`` empty?

    For such an ``x``, ``0 <= y' (h - G x) + ye' (e - E x) = h' y + e' ye - r' x`` with
    ``r = G' y + E' ye``, so ``h' y + e' ye >= -|r|_1 R``; a value below that, by more than
    the sums' rounding, is a contradiction. Negative entries of ``y`` are clipped to 0.

    Parameters
    ----------
    G : (k, nx) ndarray
    h : (k,) ndarray
    E : (ke, nx) ndarray
    e : (ke,) ndarray
    y : (k,) ndarray
    ye : (ke,) ndarray
    box : float or None
        ``R``; None: ``REACH (1 + |h, e|_inf)``.

    Returns
    -------
    bool
    """
    y = np.maximum(y, 0.0)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(ye))):
        return False
    if box is None:
        box = REACH * (1.0 + float(np.abs(np.concatenate([h, e])).max(initial=0.0)))
    if _holds(G, h, E, e, y, ye, box):
        return True
    # a solver's multipliers leave a residual at its tolerance (1e-9 on a pair of opposite
    # rows, charged at R: no proof); remove it on their support by least squares, once
    S = y > 1e-9 * y.max(initial=0.0)
    if not S.any():
        return False
    K = np.vstack([G[S], E])  # (s + ke, nx)
    r = G.T @ y + E.T @ ye
    delta = np.linalg.lstsq(K.T, -r, rcond=None)[0]
    y2 = y.copy()
    y2[S] = np.maximum(y[S] + delta[: S.sum()], 0.0)
    return _holds(G, h, E, e, y2, ye + delta[S.sum():], box)


def _holds(G, h, E, e, y, ye, box) -> bool:
    """:func:`certificate_holds`'s inequality (``y >= 0``), in exact rational arithmetic on
    the rows the certificate uses (a float residual's rounding charged at ``R`` would hide
    gaps below ~1e-9 at ``R = 1e6``; these are a handful of rows, on a rare path)."""
    S = np.flatnonzero(y)
    Se = np.flatnonzero(ye)
    if S.size + Se.size == 0:
        return False
    terms = [(G[i], h[i], Fraction(float(y[i]))) for i in S]
    terms += [(E[i], e[i], Fraction(float(ye[i]))) for i in Se]
    value = sum((Fraction(float(c)) * m for _, c, m in terms), Fraction(0))
    r = [sum((Fraction(float(g[j])) * m for g, _, m in terms), Fraction(0))
         for j in range(G.shape[1])]
    return value + sum(abs(v) for v in r) * Fraction(float(box)) < 0


def _elastic(
    G: np.ndarray, h: np.ndarray, E: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The elastic LP's rows in ``(x, t)``: ``G x - max(|g|, 1) t <= h``, ``E x = e``,
    ``-t <= 0``, and its cost ``t``. (Rows of norm below 1 are relaxed at unit rate: a
    row of rounding, 1e-15 x <= -0.7 in a region's description, asked for t = 6e14 and
    HiGHS called the elastic LP infeasible.)"""
    k, nx = G.shape
    w = np.maximum(np.linalg.norm(G, axis=1), 1.0)
    Ge = np.zeros((k + 1, nx + 1))
    Ge[:k, :nx] = G
    Ge[:k, nx] = -w
    Ge[-1, nx] = -1.0
    cost = np.zeros(nx + 1)
    cost[-1] = 1.0
    return Ge, np.hstack([E, np.zeros((E.shape[0], 1))]), cost


def farkas_proof(
    M: np.ndarray,
    upper: np.ndarray,
    lower: np.ndarray,
    equality: np.ndarray,
    box: float | None,
) -> bool:
    """Is ``{x : lower <= M x <= upper}`` proved empty (within ``|x|_inf <= R``)? DAQP
    solves the elastic LP; its multipliers are checked by :func:`certificate_holds`.

    Parameters
    ----------
    M : (n, nx) ndarray
    upper, lower : (n,) ndarray
        Row bounds, +-1e30 where absent.
    equality : (n,) ndarray of bool
        Rows with ``lower == upper`` (their multiplier is free).
    box : float or None
        A bound on ``|x|_inf`` that the rows themselves impose (the variables' bounds), or
        None: then ``R = REACH (1 + |offsets|_inf)``.

    Returns
    -------
    bool
        True only with a checked certificate; False says nothing (ask another solver).
    """
    G, h, E, e = one_sided(M, upper, lower, equality)
    k, ke = G.shape[0], E.shape[0]
    if k == 0:
        return False  # equalities alone: not this certificate's business
    Ge, Ee, cost = _elastic(G, h, E)
    n = k + 1 + ke
    L = np.vstack([Ge[:k], Ee, Ge[k:]])
    bu = np.concatenate([h, e, [0.0]])
    bl = np.concatenate([np.full(k, -_INF), e, [-_INF]])
    sense = np.zeros(n, dtype=np.int32)
    sense[k : k + ke] = 5
    _, _, flag, info = daqp.solve(
        np.zeros((L.shape[1], L.shape[1])), cost, L, bu, bl, sense,
        eps_prox=1e-2, primal_tol=1e-11, dual_tol=1e-12,
    )
    if flag != 1:
        return False
    lam = np.asarray(info["lam"], dtype=float)
    return certificate_holds(G, h, E, e, lam[:k], lam[k : k + ke], box)


def highs_infeasibility(
    G: np.ndarray, h: np.ndarray, E: np.ndarray, e: np.ndarray, box: float | None
) -> float | None:
    """After HiGHS called ``{G x <= h, E x = e}`` infeasible: prove it, or say how far.

    HiGHS solves the elastic LP; its duals are checked by :func:`certificate_holds`. HiGHS's
    own "infeasible" is no proof: with presolve it called a strip of ten nearly parallel
    rows infeasible although a point satisfied every row by 1.2e-8
    (``tests/engine/test_lp_proof.py``).

    Parameters
    ----------
    G : (k, n) ndarray
    h : (k,) ndarray
        The inequality rows ``G x <= h``.
    E : (ke, n) ndarray
    e : (ke,) ndarray
        The equality rows ``E x = e`` (``ke`` may be 0).
    box : float or None
        A bound on ``|x|_inf`` the certificate's residual is charged at (None: one derived
        from the rows, as in :func:`certificate_holds`).

    Returns
    -------
    float or None
        None: proved empty. Else the elastic LP's distance ``t >= 0``: the rows widened
        by ``t max(|g|, 1)`` meet (to HiGHS's tolerance: widen a little more).
    """
    from scipy.optimize import linprog

    Ge, Ee, cost = _elastic(G, h, E)
    k = G.shape[0]
    res = linprog(
        cost, A_ub=Ge, b_ub=np.concatenate([h, [0.0]]),
        A_eq=Ee if E.shape[0] else None, b_eq=e if E.shape[0] else None,
        bounds=[(None, None)] * Ge.shape[1], method="highs",
        options={"presolve": False},  # (its reductions made the wrong calls found so far)
    )
    if res.status != 0:
        return np.inf  # (equalities that cannot hold, or a failure: no widening helps)
    y = -np.asarray(res.ineqlin.marginals)[:k]
    ye = -np.asarray(res.eqlin.marginals) if E.shape[0] else np.zeros(0)
    if certificate_holds(G, h, E, e, y, ye, box):
        return None
    return max(float(res.x[-1]), 0.0)
