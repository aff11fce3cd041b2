"""Invariant ellipsoids of a nonlinear sampled-data loop near its operating point.

For ``time_horizon = "inf"`` on a plant that is not affine (docs/verification.md, "Safety
for all time on nonlinear plants"): an ellipsoid ``S = {x : (x - x_op)' P (x - x_op) <= c}``
inside one region of the law (the law is ``u = F_0 x + G_0`` on it), invariant for the
sampled closed loop under zoh, with the nonlinear plant's linearisation error covered by an
interval Jacobian over an a priori enclosure of every trajectory of a period, and every
state between two samples in a box that is checked against the properties. Every bound is
widened for the rounding of its computation. This module claims nothing about the states
before the reach sets enter ``S``: :func:`codev_engine.reach.verification.verify` checks that
part with the nonlinear engine's tube.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm, solve_discrete_lyapunov

from codev_engine.law import ExplicitLaw
from codev_engine.spec.problem import Problem

__all__ = ["TerminalEllipsoid", "ellipsoid_holds", "ellipsoid_outline", "terminal_ellipsoids"]

#: relative widening of every bound computed in floating point (far above its rounding)
_REL = 1e-9


@dataclass(frozen=True)
class TerminalEllipsoid:
    """An invariant ellipsoid ``{x : (x - centre)' P (x - centre) <= 1}`` (``c`` folded into
    ``P``) and the box every trajectory from it stays in over a period.

    Attributes
    ----------
    P : (n, n) ndarray
        Symmetric positive definite.
    centre : (n,) ndarray
    region : int
        The law's region that holds the ellipsoid.
    box_lo, box_hi : (n,) ndarray
        Every state between two samples of a trajectory from the ellipsoid.
    rho : float
        The sampled linear loop's contraction in the ``P`` norm.
    margin : float
        ``1 - (contraction + error terms) / radius``, > 0.
    """

    P: np.ndarray
    centre: np.ndarray
    region: int
    box_lo: np.ndarray
    box_hi: np.ndarray
    rho: float
    margin: float

    def contains_boxes(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Do the boxes (p, n) lie inside the ellipsoid (every corner, widened)?

        Parameters
        ----------
        lo, hi : (p, n) ndarray

        Returns
        -------
        bool
        """
        return ellipsoid_holds(self.P, self.centre, lo, hi)


def ellipsoid_holds(P: np.ndarray, centre: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Every corner of every box ``[lo, hi]`` within ``(x - centre)' P (x - centre) <= 1``,
    with a relative margin for the rounding (the ellipsoid is convex: its corners suffice).

    Parameters
    ----------
    P : (n, n) ndarray
    centre : (n,) ndarray
    lo, hi : (p, n) ndarray

    Returns
    -------
    bool
    """
    lo, hi = np.atleast_2d(lo), np.atleast_2d(hi)
    n = P.shape[0]
    if lo.shape[0] == 0 or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        return False
    if n > 12:
        return False
    bits = ((np.arange(2 ** n)[:, None] >> np.arange(n)[None, :]) & 1).astype(bool)
    C = np.where(bits[None], hi[:, None, :], lo[:, None, :]).reshape(-1, n) - centre
    q = np.einsum("pi,ij,pj->p", C, P, C)
    bound = np.einsum("pi,ij,pj->p", np.abs(C), np.abs(P), np.abs(C))
    return bool(np.all(q + 1e-12 * bound <= 1.0 - 1e-9))


def ellipsoid_reach(P: np.ndarray) -> np.ndarray:
    """Half-widths of the bounding box of ``{x : (x - c)' P (x - c) <= 1}`` about ``c``:
    ``sqrt(diag(P^-1))`` (the support of ``+-e_i``), widened for the inverse's rounding
    (relative 1e-6 and ``cond(P)`` times the epsilon, plus 1e-12).

    Parameters
    ----------
    P : (n, n) ndarray
        Symmetric positive definite.

    Returns
    -------
    (n,) ndarray
    """
    P = np.asarray(P, dtype=float)
    reach = np.sqrt(np.abs(np.diag(np.linalg.inv(P))))
    return reach * (1.0 + 1e-6 + np.linalg.cond(P) * np.finfo(float).eps) + 1e-12


def ellipsoid_outline(P: np.ndarray, centre: np.ndarray, axes: tuple[int, ...],
                      points: int = 97) -> np.ndarray | None:
    """The shadow of ``{x : (x - centre)' P (x - centre) <= 1}`` on the plane of ``axes``, as
    a closed outline (for the pictures).

    The projection of the ellipsoid is the ellipse ``{y : (y - c_a)' (E_a)^{-1} (y - c_a)
    <= 1}`` with ``E = P^{-1}`` and ``E_a`` its block on ``axes`` (the support function
    ``sqrt(l' E l)`` of a direction in the plane is the ellipsoid's); its points are ``c_a +
    L (cos s, sin s)`` with ``E_a = L L'``. One axis: the interval ``c +- sqrt(E_aa)`` as its
    two end points.

    Parameters
    ----------
    P : (n, n) ndarray
        Symmetric positive definite.
    centre : (n,) ndarray
    axes : tuple of int
        One or two state indices.
    points : int
        Points of the outline (the last equal to the first).

    Returns
    -------
    (points, 2) or (2, 1) ndarray, or None
        None when ``P`` is not positive definite (or not finite).
    """
    P = 0.5 * (np.asarray(P, float) + np.asarray(P, float).T)
    c = np.asarray(centre, float)
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(c))):
        return None
    try:
        np.linalg.cholesky(P)
        E = np.linalg.inv(P)
    except np.linalg.LinAlgError:
        return None
    ax = list(axes)
    Ea = 0.5 * (E[np.ix_(ax, ax)] + E[np.ix_(ax, ax)].T)
    if len(ax) == 1:
        r = float(np.sqrt(max(Ea[0, 0], 0.0)))
        return np.array([[c[ax[0]] - r], [c[ax[0]] + r]])
    try:
        L = np.linalg.cholesky(Ea)
    except np.linalg.LinAlgError:
        return None
    s = np.linspace(0.0, 2.0 * np.pi, points)
    s[-1] = 0.0  # (closed exactly)
    return c[ax][None, :] + np.column_stack([np.cos(s), np.sin(s)]) @ L.T


def _plant_parts(problem: Problem):
    from codev_engine.reach.enclosure import plant_enclosures

    enc = plant_enclosures(problem)
    n, m = problem.plant.n, problem.plant.m
    mo = problem.model
    x_op = np.asarray(mo.x_op, float) if np.size(mo.x_op) else np.zeros(n)
    u_op = np.asarray(mo.u_op, float) if np.size(mo.u_op) else np.zeros(m)
    return enc, x_op, u_op


def terminal_ellipsoids(problem: Problem, law: ExplicitLaw
                        ) -> tuple[list[TerminalEllipsoid], str]:
    """Invariant ellipsoids, one per shape tried (the Lyapunov matrices of the sampled
    linear loop for the identity and the MPC's ``Q``, and the MPC's terminal weight ``P``),
    each the largest of a geometric sequence of sizes; or none and why not.

    Parameters
    ----------
    problem : Problem
        A plant without disturbances (that can act) or parameters, zoh, no measurement
        noise, a law over the state alone.
    law : ExplicitLaw

    Returns
    -------
    ellipsoids : list of TerminalEllipsoid
    reason : str
        Empty when some were found; otherwise why none was established.
    """
    from codev_engine.plant import field_uncertain

    pl, vs = problem.plant, problem.verify
    if field_uncertain(pl) or vs.noisy or law.n != pl.n:  # (inert disturbances: nominal)
        return [], "ellipsoid certificates cover nominal plants and laws over the state"
    if vs.hold != "zoh":
        return [], "ellipsoid certificates cover the zoh hold only"
    enc, x_op, u_op = _plant_parts(problem)
    n, m = pl.n, pl.m
    Ts = float(problem.model.sample_time)
    reg = int(law.locate(x_op[None, :])[0])
    if reg < 0:
        return [], "the operating point is outside the law's domain"
    F0, G0 = np.asarray(law.F[reg], float), np.asarray(law.G[reg], float)
    Ar, br = np.asarray(law.A[reg], float), np.asarray(law.b[reg], float)
    # the expansion point: the operating state and the law's input there (the input of
    # every state of S lies around it; any point of the box B x U works for the mean value)
    u_op = F0 @ x_op + G0
    # the linear model at that point: J0 the midpoint of the degenerate box's interval
    # Jacobian (any fixed matrix works: the remainder is taken about the same J0)
    try:
        with np.errstate(all="ignore"):
            jx = enc.jac_x(x_op, x_op, u_op, u_op)
            ju = enc.jac_u(x_op, x_op, u_op, u_op)
            flo, fhi = enc.f(x_op, x_op, u_op, u_op)
    except (ArithmeticError, ValueError) as exc:
        return [], f"the plant's enclosures fail at the operating point ({exc})"
    Ax, Bu = 0.5 * (jx[0] + jx[1]), 0.5 * (ju[0] + ju[1])
    if not all(np.all(np.isfinite(a)) for a in (Ax, Bu, flo, fhi)):
        return [], "the plant's enclosures are not finite at the operating point"
    c0 = 0.5 * (flo + fhi)
    c0_err = 0.5 * (fhi - flo) * (1 + _REL) + 1e-300
    # the period's exact linear map: y+ = M y + d, y = x - x_op, the held input's deviation
    # v = F0 y + g0
    g0 = F0 @ x_op + G0 - u_op
    Z = np.zeros((2 * n + m, 2 * n + m))
    Z[:n, :n], Z[:n, n:n + m], Z[:n, n + m:] = Ax, Bu, np.eye(n)
    E = expm(Z * Ts)
    Phi, Gam_B, Gam = E[:n, :n], E[:n, n:n + m], E[:n, n + m:]
    M = Phi + Gam_B @ F0
    d = Gam_B @ g0 + Gam @ c0
    # |int_0^Ts e^{Ax s} ds| <= int_0^Ts e^{|Ax| s} ds (the series' terms), computed by the
    # same block exponential of |Ax|, widened
    Za = np.zeros((2 * n, 2 * n))
    Za[:n, :n], Za[:n, n:] = np.abs(Ax), np.eye(n)
    Gabs = expm(Za * Ts)[:n, n:] * (1 + 1e-6) + 1e-15
    shapes = [np.eye(n)]
    Q = getattr(problem.mpc, "Q", None)
    if Q is not None and np.shape(Q) == (n, n):
        shapes.append(np.asarray(Q, float))
    Pt = getattr(problem.mpc, "P", None)
    cands = []
    for Qs in shapes:
        try:
            cands.append(solve_discrete_lyapunov(M.T, 0.5 * (Qs + Qs.T)))
        except (np.linalg.LinAlgError, ValueError):
            pass
    if Pt is not None and np.shape(Pt) == (n, n):
        cands.append(np.asarray(Pt, float))  # the MPC's terminal weight, if it contracts
    found: list[TerminalEllipsoid] = []
    whys: list[str] = [] if cands else ["the sampled linear loop at the operating point is "
                                        "not stable"]
    for P0 in cands:
        e = _size(problem, enc, x_op, u_op, reg, F0, G0, Ar, br, Ax, Bu, c0, c0_err, Ts, M,
                  d, Gabs, P0)
        if isinstance(e, str):
            if e not in whys:
                whys.append(e)
        else:
            found.append(e)
    return found, ("" if found else "; ".join(whys))


def _size(problem, enc, x_op, u_op, reg, F0, G0, Ar, br, Ax, Bu, c0, c0_err, Ts, M, d, Gabs,
          P0):
    """The largest of a geometric sequence of the ellipsoids of shape ``P0`` that passes
    :func:`_check`, or why none does."""
    eps_M = 1e-10 * (np.abs(M).max() + 1.0)  # expm's rounding, elementwise, generous
    eps_d = 1e-10 * (np.abs(d).max() + 1.0)
    P0 = 0.5 * (P0 + P0.T)
    try:
        R = np.linalg.cholesky(P0).T  # P0 = R' R, ||y||_P0 = ||R y||
    except (np.linalg.LinAlgError, ValueError):
        return "the sampled linear loop at the operating point is not stable"
    if not np.all(np.isfinite(R)):
        return "the sampled linear loop at the operating point is not stable"
    Ri = np.linalg.inv(R)
    rho = float(np.linalg.norm(R @ M @ Ri, 2)) * (1 + _REL) + 1e-15
    if not rho < 1.0:
        return f"the sampled linear loop does not contract (rho = {rho:.6g})"
    nR, nRi = float(np.linalg.norm(R, 2)) * (1 + _REL), float(np.linalg.norm(Ri, 2)) * (1 + _REL)
    Pinv = Ri @ Ri.T
    dP = np.sqrt(np.maximum(np.diag(Pinv), 0.0)) * (1 + 1e-6)  # box half-widths per sqrt(c)
    # the largest c that keeps S inside the region (its support on each row, with a margin)
    rows = np.sqrt(np.maximum(np.einsum("ri,ij,rj->r", Ar, Pinv, Ar), 0.0)) * (1 + 1e-6)
    slack = br - Ar @ x_op
    if np.any(slack <= 0):
        return "the operating point lies on the boundary of its region"
    sc_max = float(np.min(slack / np.maximum(rows, 1e-300))) * (1 - 1e-6)
    why = "no ellipsoid of 40 sizes is invariant with its linearisation error"
    for k in range(40):
        sc = sc_max * 0.7 ** k  # sqrt(c)
        try:
            with np.errstate(all="ignore"):
                e = _check(problem, enc, x_op, u_op, F0, G0, Ax, Bu, c0, c0_err, Ts, dP * sc,
                           rho, nR, nRi, eps_M, eps_d, d, Gabs, sc)
        except (ArithmeticError, ValueError) as exc:  # an enclosure meets a singularity
            e = f"an enclosure over the ellipsoid's period fails ({exc})"
        if isinstance(e, str):
            why = e
            continue
        margin, blo, bhi = e
        return TerminalEllipsoid(P0 / sc ** 2, x_op.copy(), reg, blo, bhi, rho, margin)
    return why


def _check(problem, enc, x_op, u_op, F0, G0, Ax, Bu, c0, c0_err, Ts, half, rho, nR, nRi,
           eps_M, eps_d, d, Gabs, sc):
    """The invariance and safety checks of ``S_c`` (``sqrt(c) = sc``, box half-widths
    ``half``): (margin, box_lo, box_hi), or a string saying which check failed."""
    from codev_engine.reach.matrix_bounds import add_pad

    vs = problem.verify
    n = x_op.shape[0]
    slo, shi = x_op - half, x_op + half
    # the held input over S: F0 x + G0, x in the box of S
    uc = F0 @ x_op + G0
    ur = np.abs(F0) @ half * (1 + _REL) + 1e-12 * (np.abs(uc) + 1.0)
    ulo, uhi = uc - ur, uc + ur
    mpc = problem.mpc
    if vs.input_bounds and (np.any(ulo < mpc.u_min) or np.any(uhi > mpc.u_max)):
        return "the input over the ellipsoid leaves its bounds"
    # a priori enclosure of a period: B with box(S) + [0, Ts] f(B, U) inside B
    blo, bhi = slo - half - 1e-9, shi + half + 1e-9
    ok = False
    for _ in range(30):
        flo, fhi = enc.f(blo, bhi, ulo, uhi)
        if not (np.all(np.isfinite(flo)) and np.all(np.isfinite(fhi))):
            return "the field is not finite over the period's enclosure"
        dlo, dhi = Ts * np.minimum(flo, 0.0), Ts * np.maximum(fhi, 0.0)
        nlo = slo + dlo - add_pad(slo, dlo)
        nhi = shi + dhi + add_pad(shi, dhi)
        if np.all(nlo >= blo) and np.all(nhi <= bhi):
            ok = True
            break
        pad = 0.1 * (nhi - nlo) + 1e-12
        blo, bhi = np.minimum(blo, nlo - pad), np.maximum(bhi, nhi + pad)
    if not ok:
        return "no a priori enclosure of a period from the ellipsoid"
    # the states between samples: B against every property
    for st in vs.unsafe:
        A, b = st.halfspaces()
        mn = np.minimum(A * blo, A * bhi).sum(axis=1)
        if not np.any(mn > b + 1e-9 * (1 + np.abs(b))):
            return "the period's enclosure meets an unsafe set"
    for st in vs.safe:
        A, b = st.halfspaces()
        mx = np.maximum(A * blo, A * bhi).sum(axis=1)
        if np.any(mx > b - 1e-9 * (1 + np.abs(b))):
            return "the period's enclosure leaves a safe set"
    # the linearisation error over B x U: f(z) - f(z0) - J0 (z - z0) = (J(xi) - J0)(z - z0)
    # (mean value per component, xi on the segment, inside the convex box that holds z0)
    if np.any(x_op < blo) or np.any(x_op > bhi) or np.any(u_op < ulo) or np.any(u_op > uhi):
        return "the operating point is outside the period's enclosure"
    jxl, jxh = enc.jac_x(blo, bhi, ulo, uhi)
    jul, juh = enc.jac_u(blo, bhi, ulo, uhi)
    dJx = np.maximum(np.abs(jxl - Ax), np.abs(jxh - Ax))
    dJu = np.maximum(np.abs(jul - Bu), np.abs(juh - Bu))
    dx = np.maximum(np.abs(blo - x_op), np.abs(bhi - x_op))
    du = np.maximum(np.abs(ulo - u_op), np.abs(uhi - u_op))
    ebar = (dJx @ dx + dJu @ du) * (1 + 1e-6) + c0_err
    if not np.all(np.isfinite(ebar)):
        return "the linearisation error is not finite"
    rbar = Gabs @ ebar * (1 + 1e-6)
    # || M y + d + r ||_P0 <= rho sc + ||R|| (eps_M sqrt(n) ||Ri|| sc + ||d|| + eps_d + ||r||)
    err = nR * (eps_M * n * nRi * sc + np.linalg.norm(d) + eps_d * np.sqrt(n)
                + np.linalg.norm(rbar)) * (1 + _REL)
    total = rho * sc + err
    if not total <= sc * (1 - 1e-9):
        return "the linearisation error exceeds the contraction on every ellipsoid tried"
    return 1.0 - total / sc, blo, bhi
