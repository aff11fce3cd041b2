"""Terminal ingredients of an MPC: the LQR cost and the maximal positively invariant set.

``P = "lqr"`` is the solution of the discrete algebraic Riccati equation for the prediction
model and the weights ``(Q, R)`` (python-control's ``dare``); with it the MPC's cost-to-go
beyond the horizon is the unconstrained LQR's, so inside the target's region the explicit
law *is* the LQR law.

``terminal_set = "lqr"`` is the maximal positively invariant (MPI) set of the LQR loop
``xi+ = (A - B K) xi`` (``xi = x - x_s``) inside every constraint of the design, computed by
the Gilbert--Tan iteration: ``O_t = {xi : G (A - B K)^k xi <= g, k = 0..t}``, stopped at the
first ``t`` whose next rows are all implied by ``O_t`` (each checked by an LP); the result is
finitely determined or an error. With a free reference the target moves with ``r``, and the
set lives in ``(xi, r)`` with ``r+ = r`` (the reference is constant along a prediction).

Reference: E. G. Gilbert and K. T. Tan, "Linear systems with state and control constraints:
the theory and application of maximal output admissible sets", IEEE TAC 36(9), 1991.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.geometry.polytope import (
    bounding_box,
    chebyshev_ball,
    minimal_rows,
    normalize_rows,
    solve_lp,
)
from codev_engine.mp.balance import parameter_scaling, rows_back

__all__ = ["lqr_terms", "InvariantSet", "maximal_invariant_set"]

#: Gilbert--Tan steps tried before the set is declared not finitely determined.
MAX_STEPS = 200


def lqr_terms(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """The infinite-horizon LQR of ``x+ = A x + B u`` with cost ``x'Qx + u'Ru``.

    Parameters
    ----------
    A : (n, n) ndarray
    B : (n, m) ndarray
    Q : (n, n) ndarray
        Symmetric positive semidefinite.
    R : (m, m) ndarray
        Symmetric positive definite.

    Returns
    -------
    P : (n, n) ndarray
        The stabilising solution of the DARE (symmetric).
    K : (m, n) ndarray
        The gain: ``u = -K x``.

    Raises
    ------
    SpecError
        ``field="mpc.P"`` when the DARE has no stabilising solution (``(A, B)`` not
        stabilisable or ``(Q, A)`` with unobservable modes on the unit circle).
    """
    import control  # python-control: the Riccati solver (slycot-free path)

    Qs = 0.5 * (Q + Q.T)
    Rs = 0.5 * (R + R.T)
    try:
        P, _, K = control.dare(A, B, Qs, Rs)
    except Exception as exc:  # noqa: BLE001 -- python-control raises several kinds
        raise SpecError(
            f"the Riccati equation has no stabilising solution for this model and (Q, R): "
            f"{exc}",
            field="mpc.P",
        ) from None
    P = np.asarray(P, dtype=float)
    return 0.5 * (P + P.T), np.asarray(K, dtype=float).reshape(B.shape[1], A.shape[0])


@dataclass(frozen=True)
class InvariantSet:
    """A polytope ``A v <= b`` that the loop ``v+ = Phi v`` never leaves.

    Attributes
    ----------
    A : (k, d) ndarray
        Unit rows, no redundant row.
    b : (k,) ndarray
    steps : int
        The Gilbert--Tan steps it took (``t`` of the module docstring).
    """

    A: np.ndarray
    b: np.ndarray
    steps: int


def _box(G: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The extent of ``G v <= g`` along each axis through the origin (the target, inside
    the set: every ``g > 0``), else its LP bounding box.

    It sets the iteration's units only (to a power of two), and needs no LP: the LPs'
    tolerances in the plant's own coordinates are what the units are there to avoid (the
    LP box of the double integrator with x1 x1e3 and x2 x1e-3 came out infinite along x1).

    Parameters
    ----------
    G : (c, d) ndarray
    g : (c,) ndarray

    Returns
    -------
    lo, hi : (d,) ndarrays
        +-inf where nothing bounds an axis.
    """
    if np.all(g > 0.0):
        with np.errstate(divide="ignore", invalid="ignore"):
            t = g[:, None] / G  # where the ray along +-e_j meets row i
        hi = np.min(np.where(G > 0.0, t, np.inf), axis=0)
        lo = np.max(np.where(G < 0.0, t, -np.inf), axis=0)
        if np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)):
            return lo, hi
    return bounding_box(G, g)


def maximal_invariant_set(Phi: np.ndarray, G: np.ndarray, g: np.ndarray, *,
                          field: str = "mpc.terminal_set",
                          max_steps: int = MAX_STEPS) -> InvariantSet:
    """The maximal positively invariant set of ``v+ = Phi v`` inside ``G v <= g``.

    Parameters
    ----------
    Phi : (d, d) ndarray
        The closed loop.
    G : (c, d) ndarray
    g : (c,) ndarray
        The constraints; they must bound a set with an interior point.
    field : str
        The spec field blamed by errors.
    max_steps : int
        Steps tried before giving up.

    Returns
    -------
    InvariantSet

    Raises
    ------
    SpecError
        When the constraints have no interior point (the target violates a constraint) or
        the set is not finitely determined within ``max_steps`` (the loop is not
        asymptotically stable in some direction the constraints see).
    """
    G, g, feasible = normalize_rows(np.asarray(G, float), np.asarray(g, float))
    if not feasible:
        raise SpecError("the LQR terminal set is empty", field=field)
    # axes far apart in size (states in units 1e3 and 1e-3): the iteration runs on
    # v = W v_s (W powers of two, mp/balance.py) and the set is mapped back. In the
    # plant's own coordinates the LPs' tolerances are of the wide axis' size: the double
    # integrator with x1 x1e3 and x2 x1e-3 got 3 rows after 56 steps, a set unbounded
    # along x2, for the 12 rows after 5 steps it has in its own units (issue 38)
    W = parameter_scaling(*_box(G, g))
    if W is not None:
        inner = maximal_invariant_set(W[:, None] ** -1 * Phi * W, G * W, g, field=field,
                                      max_steps=max_steps)
        A, b = rows_back(inner.A, inner.b, W)
        return InvariantSet(A=A, b=b, steps=inner.steps)
    A, b = G.copy(), g.copy()
    _, radius = chebyshev_ball(A, b)
    if not radius > 1e-9:
        raise SpecError(
            "the LQR terminal set is empty or flat: the target lies on or outside a "
            "constraint of the design",
            field=field,
        )
    Gk = G
    for t in range(1, max_steps + 1):
        Gk = Gk @ Phi
        new = []
        for i in range(Gk.shape[0]):
            a = Gk[i]
            if not np.any(a):
                if g[i] < 0:
                    raise SpecError("the LQR terminal set is empty", field=field)
                continue
            x, status, _ = solve_lp(-a, A, b)
            if status == "optimal" and float(a @ x) <= g[i] + 1e-9 * max(1.0, abs(g[i])):
                continue
            new.append(i)
        if not new:
            keep = minimal_rows(A, b)
            return InvariantSet(A=A[keep], b=b[keep], steps=t - 1)
        An, bn, _ = normalize_rows(Gk[new], g[new])
        A = np.vstack([A, An])
        b = np.concatenate([b, bn])
        if A.shape[0] > 400:
            keep = minimal_rows(A, b)
            A, b = A[keep], b[keep]
    raise SpecError(
        f"the LQR terminal set is not finitely determined within {max_steps} steps "
        "(the constraints see a mode the LQR loop does not drive to the target)",
        field=field,
    )
