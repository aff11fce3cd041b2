"""The MPC front door: condensed multi-parametric program and the online (reference) MPC.

Conventions (those of MPT3, see ``benchmarks/README.md``):

* prediction model in deviation coordinates ``dx+ = A dx + B du + c`` (``LinearModel``);
* stage costs ``k = 0..N-1`` on states and inputs, terminal cost on ``x_N`` when ``P`` is
  given;
* state bounds on ``x_0..x_N`` (the ``x_0`` bound is the parameter set), input bounds on
  ``u_0..u_{N-1}``;
* norm ``"2"``: ``sum_k x_k'Q x_k + u_k'R u_k + x_N'P x_N``;
  norms ``"1"``/``"inf"``: ``sum_k ||Q x_k||_p + ||R u_k||_p + ||P x_N||_p``.

``build_program`` condenses the MPC into an ``MpProgram`` whose parameter is the initial
state deviation ``theta = x_0 - x_op``. ``OnlineMpc`` solves the *non-condensed* MPC with
cvxpy + Clarabel at one state at a time; it is the reference the explicit law is tested
against.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import cvxpy as cp

from codev_engine.errors import SolverError, SpecError
from codev_engine.formulation import Formulation, formulation
from codev_engine.mp.coverage import feasibility_rows
from codev_engine.mp.program import MpProgram
from codev_engine.mp.reduce import reduce_program
from codev_engine.plant import LinearModel
from codev_engine.spec.choices import NORMS
from codev_engine.spec.problem import MpcSpec, Problem

__all__ = [
    "MpcProgram",
    "build_program",
    "check_feasible",
    "OnlineSolution",
    "OnlineMpc",
    "ONLINE_SOFT_RATIO",
]


#: the largest ``soft_weight`` the online MPC takes, as a multiple of the cost's smallest
#: weight (a row's largest entry of ``Q``, ``R``, ``P``, ``Rd``, as
#: ``synthesis.weight_spread``). The penalty is the cost's largest term there, and an
#: interior point's tolerances are relative to it. The double integrator with a soft output
#: bound (``Q = I``, ``R = 0.5``, horizons 4 and 8) is solved to the explicit law's moves up
#: to a ratio of 4e6 in norms 1/inf; at 1e7 (inf) and 2e7 (1) Clarabel stalls on the moves,
#: which rest on the weights below the penalty, at every setting of ``RETRY_OPTIONS``
#: ("Clarabel failed"; norm 2 at 2e10); HiGHS's simplex, tried instead, trades its
#: feasibility tolerance (1e-7 times the penalty) for cost. The explicit law (an exact
#: active-set search, checked by HiGHS / DAQP on the condensed program) has no such limit.
ONLINE_SOFT_RATIO = 2e6

# Clarabel settings of the reference solver: much tighter than the defaults (1e-8) so the
# online optimum is an oracle at 1e-6 relative.
CLARABEL_OPTIONS: dict[str, float | int] = {
    "tol_gap_abs": 1e-10,
    "tol_gap_rel": 1e-10,
    "tol_feas": 1e-10,
    "tol_infeas_abs": 1e-10,
    "tol_infeas_rel": 1e-10,
    "tol_ktratio": 1e-8,
    "max_iter": 500,
}

#: Clarabel settings tried, in order, when the tight settings fail at a state where the MPC
#: is feasible (HiGHS says so): the defaults, then more regularisation and iterations,
#: then looser tolerances with no equilibration.
RETRY_OPTIONS: tuple[dict, ...] = (
    {},
    {
        "static_regularization_constant": 1e-6,
        "max_iter": 1000,
        "tol_gap_abs": 1e-9,
        "tol_gap_rel": 1e-9,
        "tol_feas": 1e-9,
    },
    {
        "static_regularization_constant": 1e-5,
        "equilibrate_enable": False,
        "max_iter": 2000,
        "tol_gap_abs": 1e-7,
        "tol_gap_rel": 1e-7,
        "tol_feas": 1e-7,
    },
)


#: How soft constraints are priced (docs/spec.md). Norms "1"/"inf": ``soft_weight * sum(eps)``,
#: the l1 penalty. Norm "2": ``soft_weight * sum(eps + eps**2)``: the l1 part keeps a soft
#: constraint exact (no slack wherever the hard problem is feasible, for a weight above the
#: constraint's multipliers), the quadratic part keeps the QP strictly convex, so that the
#: optimal moves are unique and the mp-QP is definite (a semi-definite one with a slack per
#: soft row and step enumerates far too many active sets).
SOFT_COST = {"1": "l1", "inf": "l1", "2": "l1 + l2"}


# ---------------------------------------------------------------------------------------
# the condensed program
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MpcProgram:
    """The condensed MPC as a multi-parametric program, with what is needed to read it.

    The parameter is ``dtheta = theta - theta_op`` (d,), with ``theta = (x, u_prev, r)``
    (``x`` alone for a regulator without input rates: ``dtheta = x_0 - x_op``). The decision
    vector is ``z = [v_0, ..., v_{Nc-1}, eps, s]``: the free deviation moves (Nc*m) first,
    then the slacks of the soft constraints, then the slacks of the LP norms (none for norm
    ``"2"``). The full MPC cost at ``(dtheta, z)`` is
    ``0.5 z'Hz + (c + C dtheta)'z + theta_constant(dtheta)``.

    Attributes
    ----------
    program : MpProgram
        The condensed program in ``(theta, z)``.
    model : LinearModel
        The prediction model it was condensed from.
    spec : MpcSpec
        The MPC design (weights, bounds, norm).
    n, m, N : int
        State and input dimensions, horizon.
    u0_slice : slice
        Where the first deviation input ``u_0 - u_op`` sits inside ``z``.
    x_op : (n,) ndarray
        Operating point state: ``theta = x_0 - x_op``.
    u_op : (m,) ndarray
        Operating point input: the inputs in ``z`` are ``u_k - u_op``.
    formulation : Formulation or None
        The design's derived data (parameter layout, targets, terminal ingredients).
    """

    program: MpProgram
    model: LinearModel
    spec: MpcSpec
    n: int
    m: int
    N: int
    u0_slice: slice
    x_op: np.ndarray
    u_op: np.ndarray
    # theta_constant(theta) = theta' _Kq theta + _kl' theta + _k0   (norm "2")
    #                       = ||Q theta||_p                         (norms "1", "inf")
    _Kq: np.ndarray
    _kl: np.ndarray
    _k0: float
    formulation: Formulation | None = None
    # soft rows on theta alone: cost soft_weight * sum(max(0, A0 theta - b0))
    _soft0: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def d(self) -> int:
        """Length of the parameter ``theta`` (``n`` unless the law takes u_prev or r)."""
        return self.program.d

    @property
    def theta_op(self) -> np.ndarray:
        """(d,) ``theta - theta_op`` is the program's parameter (``x_op``, ``u_op``, 0)."""
        return self.x_op if self.formulation is None else self.formulation.theta_op

    @property
    def n_slack(self) -> int:
        """Number of slack variables (after the N*m inputs in ``z``)."""
        return self.program.nz - self.N * self.m

    def theta_constant(self, theta: np.ndarray) -> np.ndarray:
        """The part of the MPC cost that depends on theta only (dropped from the program).

        Parameters
        ----------
        theta : (P, d) ndarray
            Parameter deviations ``theta - theta_op``.

        Returns
        -------
        (P,) ndarray
        """
        T = np.atleast_2d(np.asarray(theta, dtype=float))
        if self.spec.norm == "2":
            out = np.einsum("pi,ij,pj->p", T, self._Kq, T) + T @ self._kl + self._k0
        else:
            Q = np.asarray(self.spec.Q, dtype=float)
            ordp = 1 if self.spec.norm == "1" else np.inf
            fm = self.formulation
            X0 = T[:, :self.n]
            if fm is not None and fm.tracking:
                X0 = X0 - T @ fm.Sx.T - fm.sx
            out = np.linalg.norm(X0 @ Q.T, ord=ordp, axis=1)
        if self._soft0 is not None and self._soft0[1].size:
            A0, b0 = self._soft0
            hinge = np.maximum(T @ A0.T - b0, 0.0).sum(axis=1)
            out = out + float(self.spec.soft_weight) * hinge
        return out

    def to_theta(self, X: np.ndarray) -> np.ndarray:
        """Map plant-coordinate parameters to the program's, ``dtheta = X - theta_op``.

        Parameters
        ----------
        X : (P, d) or (d,) array_like
            Plant states (then the previous input and the reference, when the law takes
            them).

        Returns
        -------
        (P, d) or (d,) ndarray
            The parameters, in the shape of ``X``.
        """
        return np.asarray(X, dtype=float) - self.theta_op

    def from_theta(self, theta: np.ndarray) -> np.ndarray:
        """Map the program's parameters to plant coordinates, ``X = dtheta + theta_op``.

        Parameters
        ----------
        theta : (P, d) or (d,) array_like
            Parameter deviations.

        Returns
        -------
        (P, d) or (d,) ndarray
            In plant coordinates, in the shape of ``theta``.
        """
        return np.asarray(theta, dtype=float) + self.theta_op

    def u0_from_z(self, Z: np.ndarray) -> np.ndarray:
        """The first move in plant coordinates, ``Z[..., u0_slice] + u_op``.

        Parameters
        ----------
        Z : (nz,) or (P, nz) ndarray
            Decision vectors of ``program``.

        Returns
        -------
        (m,) or (P, m) ndarray
        """
        return np.asarray(Z, dtype=float)[..., self.u0_slice] + self.u_op


def _as2d(M: np.ndarray | None, cols: int) -> np.ndarray | None:
    if M is None:
        return None
    return np.asarray(M, dtype=float).reshape(-1, cols)


def _check_soft_weight(spec: MpcSpec, fm: Formulation) -> None:
    """Refuse, naming ``mpc.soft_weight``, a penalty past ``ONLINE_SOFT_RATIO`` times the
    cost's smallest weight: the online MPC would fail on it (a vague solver error) or
    return moves off the optimum."""
    if not spec.soft:
        return
    small = None
    for name, M in (("Q", spec.Q), ("R", spec.R), ("P", fm.P), ("Rd", spec.Rd)):
        if M is None:
            continue
        rows = np.max(np.abs(np.atleast_2d(np.asarray(M, dtype=float))), axis=1, initial=0.0)
        rows = rows[rows > 0.0]
        if rows.size and (small is None or rows.min() < small[0]):
            small = (float(rows.min()), f"mpc.{name}")
    w = float(spec.soft_weight)
    if small is None or w <= ONLINE_SOFT_RATIO * small[0]:
        return
    raise SpecError(
        f"{w:.3g} is {w / small[0]:.3g} times the cost's smallest weight ({small[1]} "
        f"{small[0]:.3g}): the online MPC (cvxpy + Clarabel) cannot resolve the moves next "
        f"to such a penalty; it takes soft_weight up to {ONLINE_SOFT_RATIO * small[0]:.3g} "
        f"here ({ONLINE_SOFT_RATIO:.0e} times it). The explicit law (codev run) has no such "
        "limit", field="mpc.soft_weight")


def _check_dims(spec: MpcSpec, n: int, m: int) -> None:
    if spec.norm not in NORMS:
        raise SpecError(f"norm must be one of {NORMS}, got {spec.norm!r}", field="mpc.norm")
    if spec.horizon < 1:
        raise SpecError("the horizon must be at least 1", field="mpc.horizon")
    for name, M, cols in (("Q", spec.Q, n), ("R", spec.R, m), ("P", spec.P, n)):
        if M is None:
            continue
        M = np.asarray(M)
        if M.ndim != 2 or M.shape[1] != cols:
            raise SpecError(f"{name} must have {cols} columns, got shape {M.shape}",
                            field=f"mpc.{name}")
        if spec.norm == "2":
            if M.shape[0] != cols:
                raise SpecError(f"{name} must be square ({cols}x{cols}) for norm '2'",
                                field=f"mpc.{name}")
            Ms = 0.5 * (M + M.T).astype(float)
            if np.linalg.eigvalsh(Ms).min() < -1e-10 * max(1.0, np.abs(Ms).max()):
                raise SpecError(f"{name} must be positive semidefinite for norm '2'",
                                field=f"mpc.{name}")


def _predictions(
    model: LinearModel, N: int
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Condensed predictions ``x_k = Phi_k theta + Gam_k u + d_k``, k = 0..N.

    Returns
    -------
    Phi : list of (n, n) ndarray
    Gam : list of (n, N*m) ndarray
    d : list of (n,) ndarray
    """
    A = np.asarray(model.A, dtype=float)
    B = np.asarray(model.B, dtype=float)
    c = np.asarray(model.c, dtype=float).reshape(-1)
    n, m = B.shape
    Phi = [np.eye(n)]
    Gam = [np.zeros((n, N * m))]
    d = [np.zeros(n)]
    for k in range(N):
        G = A @ Gam[k]
        G[:, k * m:(k + 1) * m] += B
        Phi.append(A @ Phi[k])
        Gam.append(G)
        d.append(A @ d[k] + c)
    return Phi, Gam, d


def _theta_box(spec: MpcSpec, x_op: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bounded parameter box ``lo <= theta <= hi``.

    The finite state bounds (minus ``x_op``); an infinite side is replaced by
    ``-+spec.domain_bound``.
    """
    xmin = np.asarray(spec.x_min, dtype=float) - x_op
    xmax = np.asarray(spec.x_max, dtype=float) - x_op
    D = float(spec.domain_bound)
    lo = np.where(np.isfinite(xmin), xmin, -D)
    hi = np.where(np.isfinite(xmax), xmax, D)
    return lo, hi


def build_program(spec: MpcSpec, model: LinearModel) -> MpcProgram:
    """Condense the MPC into a multi-parametric LP (norms "1", "inf") or QP (norm "2").

    Parameters
    ----------
    spec : MpcSpec
        Weights ``Q`` (q, n), ``R`` (r, m), optional ``P`` (p, n) (square for norm "2"),
        bounds in plant coordinates, and the optional terms of ``docs/spec.md`` (rates,
        outputs, soft and mixed constraints, move blocking, reference, terminal set).
    model : LinearModel
        The discrete-time model in deviation coordinates: A (n, n), B (n, m), c (n,).

    Returns
    -------
    MpcProgram
        ``program`` has parameter ``dtheta = theta - theta_op`` (d,), ``theta = (x, u_prev,
        r)`` (see :mod:`codev_engine.formulation`), and decision ``z = [v_0..v_{Nc-1}
        (deviation moves), soft slacks, LP-norm slacks]``; every constraint that involves a
        move is a row ``A z <= b + F dtheta``; the parameter box (``domain_bound`` on
        infinite or soft sides) and the constraints on ``dtheta`` alone form
        ``A_theta dtheta <= b_theta``.

    Raises
    ------
    SpecError
        When ``spec`` does not fit the model: an unknown norm, a horizon below 1, weights
        of the wrong shape, (norm "2") a weight that is not square or not positive
        semidefinite, a reference with no steady state, a bad terminal set.
    """
    # One overflow (an unstable model over a long horizon, a weight near 1e308) would
    # spill RuntimeWarnings and end in an error about the program's internal matrices:
    # computed quietly, then checked, the error names the spec field it comes from.
    with np.errstate(all="ignore"):
        try:
            mp = _build_program(spec, model)
        except SpecError as exc:  # MpProgram's own check: names its matrix, not the spec's
            if exc.field not in _PROGRAM_ARRAYS:
                raise
            _overflow(spec, model, [exc.field])
        arrays = {"Kq": mp._Kq, "kl": mp._kl, "k0": np.asarray(mp._k0)}
        bad = [k for k, v in arrays.items() if not np.all(np.isfinite(v))]
        if bad:
            _overflow(spec, model, bad)
    return mp


_PROGRAM_ARRAYS = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq")


def _overflow(spec: MpcSpec, model: LinearModel, bad: list[str | None]) -> None:
    """Raise the ``SpecError`` naming the spec field an overflow of the program comes
    from: the horizon (the predictions) or the largest weight (the cost)."""
    N = int(spec.horizon)
    Phi, Gam, d = _predictions(model, N)
    if not all(np.all(np.isfinite(M)) for M in (*Phi[-1:], *Gam[-1:], *d[-1:])):
        A = np.asarray(model.A, dtype=float)
        if np.all(np.isfinite(A)):
            radius = f"spectral radius {float(np.max(np.abs(np.linalg.eigvals(A)))):.3g}"
        else:  # (entries past 1e308 already)
            radius = "entries past 1e308"
        raise SpecError(
            f"the predictions overflow over the horizon of {N:,} steps (the prediction "
            f"model's A has {radius}; its powers pass 1e308): shorten "
            "mpc.horizon, or change the plant (plant.dynamics / plant.A, model.sample_time)",
            field="mpc.horizon",
        )
    P = spec.P if isinstance(spec.P, np.ndarray) else None
    weights = {"mpc.Q": spec.Q, "mpc.R": spec.R, "mpc.P": P, "mpc.Rd": spec.Rd}
    sizes = {k: float(np.max(np.abs(v))) for k, v in weights.items()
             if v is not None and np.size(v)}
    field = max(sizes, key=lambda k: sizes[k]) if sizes else "mpc"
    raise SpecError(
        f"the condensed MPC overflows (non-finite {', '.join(map(str, bad))}; the largest "
        f"weight is {field} = {sizes.get(field, 0.0):.3g}): scale the weights and bounds "
        "down, or shorten mpc.horizon",
        field=field,
    )


def _build_program(spec: MpcSpec, model: LinearModel) -> MpcProgram:
    n, m = np.asarray(model.B).shape
    N = int(spec.horizon)
    _check_dims(spec, n, m)
    fm = formulation(spec, model)
    dth, Nc = fm.d, fm.Nc
    x_op = np.asarray(model.x_op, dtype=float).reshape(n)
    u_op = np.asarray(model.u_op, dtype=float).reshape(m)
    nu = Nc * m  # the free moves
    Phi, Gam, d = _predictions(model, N)
    Bk = None
    if Nc < N:
        Bk = fm.blocking()
        Gam = [G @ Bk for G in Gam]
    if dth > n:
        Phi = [np.hstack([P_, np.zeros((n, dth - n))]) for P_ in Phi]

    def move(k: int) -> np.ndarray:
        """(m, nu) selection of the move applied at step k."""
        S = np.zeros((m, nu))
        j = min(k, Nc - 1)
        S[:, j * m:(j + 1) * m] = np.eye(m)
        return S

    Q = _as2d(spec.Q, n)
    R = _as2d(spec.R, m)
    P = None if fm.P is None else _as2d(fm.P, n)
    soft = set(spec.soft)

    # --- bounds: rows  Au u <= b + F theta  (u = the free deviation moves) ---------------
    Au_rows: list[np.ndarray] = []
    b_rows: list[np.ndarray] = []
    F_rows: list[np.ndarray] = []
    # soft rows: Au u - eps <= b + F theta (one slack each); soft rows on x_0 / y_0 alone
    # do not involve a move: their cost is in theta_constant
    Su_rows: list[np.ndarray] = []
    sb_rows: list[float] = []
    SF_rows: list[np.ndarray] = []
    s0_A: list[np.ndarray] = []
    s0_b: list[float] = []

    umin = np.asarray(spec.u_min, dtype=float) - u_op
    umax = np.asarray(spec.u_max, dtype=float) - u_op
    Iu = np.eye(nu)
    for k in range(Nc):
        for i in range(m):
            j = k * m + i
            if np.isfinite(umax[i]):
                Au_rows.append(Iu[j])
                b_rows.append(np.array([umax[i]]))
                F_rows.append(np.zeros((1, dth)))
            if np.isfinite(umin[i]):
                Au_rows.append(-Iu[j])
                b_rows.append(np.array([-umin[i]]))
                F_rows.append(np.zeros((1, dth)))
    if spec.du_min is not None:
        # du_k = v_k - v_{k-1} (k < Nc; zero beyond), du_0 = v_0 - u_prev (deviations)
        dumin = np.asarray(spec.du_min, dtype=float)
        dumax = np.asarray(spec.du_max, dtype=float)
        up = fm.up_cols
        for k in range(Nc):
            for i in range(m):
                row = Iu[k * m + i].copy()
                Frow = np.zeros((1, dth))
                if k == 0:
                    Frow[0, up.start + i] = 1.0
                else:
                    row[(k - 1) * m + i] -= 1.0
                if np.isfinite(dumax[i]):
                    Au_rows.append(row)
                    b_rows.append(np.array([dumax[i]]))
                    F_rows.append(Frow)
                if np.isfinite(dumin[i]):
                    Au_rows.append(-row)
                    b_rows.append(np.array([-dumin[i]]))
                    F_rows.append(-Frow)
    xmin = np.asarray(spec.x_min, dtype=float) - x_op
    xmax = np.asarray(spec.x_max, dtype=float) - x_op
    up, lo = np.flatnonzero(np.isfinite(xmax)), np.flatnonzero(np.isfinite(xmin))
    if "x_max" in soft:
        up_soft, up = up, up[:0]
    else:
        up_soft = up[:0]
    if "x_min" in soft:
        lo_soft, lo = lo, lo[:0]
    else:
        lo_soft = lo[:0]
    for k in range(1, N + 1):
        # x_k = Phi theta + Gam u + d <= xmax   <=>   Gam u <= xmax - d - Phi theta
        for i in up:
            Au_rows.append(Gam[k][i])
            b_rows.append(np.array([xmax[i] - d[k][i]]))
            F_rows.append(-Phi[k][i][None, :])
        for i in lo:
            Au_rows.append(-Gam[k][i])
            b_rows.append(np.array([d[k][i] - xmin[i]]))
            F_rows.append(Phi[k][i][None, :])
    for k in range(N + 1):
        for i in up_soft:
            _soft_row(k, Gam[k][i], xmax[i] - d[k][i], -Phi[k][i], Su_rows, sb_rows, SF_rows,
                      s0_A, s0_b)
        for i in lo_soft:
            _soft_row(k, -Gam[k][i], d[k][i] - xmin[i], Phi[k][i], Su_rows, sb_rows, SF_rows,
                      s0_A, s0_b)
    if spec.C is not None and spec.y_min is not None:
        C = np.asarray(spec.C, dtype=float)
        ymax = np.asarray(spec.y_max, dtype=float) - C @ x_op
        ymin = np.asarray(spec.y_min, dtype=float) - C @ x_op
        for k in range(N + 1):
            CG, CP, Cd = C @ Gam[k], C @ Phi[k], C @ d[k]
            for i in range(C.shape[0]):
                for sgn, bound, group in ((1.0, ymax[i], "y_max"), (-1.0, -ymin[i], "y_min")):
                    if not np.isfinite(bound):
                        continue
                    # sgn (C Gam u + C Phi theta + C d) <= bound
                    a, bb, f = sgn * CG[i], bound - sgn * Cd[i], -sgn * CP[i]
                    if group in soft:
                        _soft_row(k, a, bb, f, Su_rows, sb_rows, SF_rows, s0_A, s0_b)
                    else:
                        Au_rows.append(a)
                        b_rows.append(np.array([bb]))
                        F_rows.append(f[None, :])
    for mc in spec.constraints:
        Hx, Hu = np.asarray(mc.Hx, dtype=float), np.asarray(mc.Hu, dtype=float)
        h = np.asarray(mc.h, dtype=float) - Hx @ x_op - Hu @ u_op
        for k in range(N):
            # Hx (Phi theta + Gam u + d) + Hu v_k <= h
            Au_rows.extend(Hx @ Gam[k] + Hu @ move(k))
            b_rows.append(h - Hx @ d[k])
            F_rows.append(-Hx @ Phi[k])
    if fm.term_b.size:
        # term_Ax (Phi_N theta + Gam_N u + d_N) + term_At theta <= term_b
        Au_rows.extend(fm.term_Ax @ Gam[N])
        b_rows.append(fm.term_b - fm.term_Ax @ d[N])
        F_rows.append(-(fm.term_Ax @ Phi[N] + fm.term_At))

    Au = np.array(Au_rows, dtype=float).reshape(-1, nu)
    bu = np.concatenate(b_rows) if b_rows else np.zeros(0)
    Fu = np.vstack(F_rows) if F_rows else np.zeros((0, dth))

    # --- the parameter set: box, plus the pure-theta rows --------------------------------
    th_lo, th_hi = fm.theta_lo, fm.theta_hi
    A_theta_rows = [np.eye(dth), -np.eye(dth)]
    b_theta_rows = [th_hi, -th_lo]
    pure = ~np.any(Au != 0.0, axis=1)
    if np.any(pure):
        # 0 <= b + F theta   <=>   -F theta <= b; drop the ones the box already implies
        At, bt = -Fu[pure], bu[pure]
        box_max = np.maximum(At * th_lo, At * th_hi).sum(axis=1)
        scale = 1.0 + np.abs(bt) + np.abs(At) @ np.maximum(np.abs(th_lo), np.abs(th_hi))
        keep = box_max > bt + 1e-12 * scale
        A_theta_rows.append(At[keep])
        b_theta_rows.append(bt[keep])
        Au, bu, Fu = Au[~pure], bu[~pure], Fu[~pure]
    A_theta = np.vstack(A_theta_rows)
    b_theta = np.concatenate(b_theta_rows)

    # --- soft slacks: columns after the moves ---------------------------------------------
    ns = len(Su_rows)
    if ns:
        Au = np.vstack([
            np.hstack([Au, np.zeros((Au.shape[0], ns))]),
            np.hstack([np.array(Su_rows).reshape(ns, nu), -np.eye(ns)]),
            np.hstack([np.zeros((ns, nu)), -np.eye(ns)]),
        ])
        bu = np.concatenate([bu, np.array(sb_rows), np.zeros(ns)])
        Fu = np.vstack([Fu, np.array(SF_rows).reshape(ns, dth), np.zeros((ns, dth))])
    nd = nu + ns  # moves and soft slacks
    soft0 = (np.array(s0_A).reshape(-1, dth), np.array(s0_b))

    # extra cost terms (v = Gv z + Phv theta + dv, weight M), beyond the state and input
    # terms of the regulator: input rates, and the input target of a tracking design
    extra: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    if spec.Rd is not None:
        Rd = _as2d(spec.Rd, m)
        for k in range(min(N, Nc)):
            G = move(k) - (move(k - 1) if k else 0.0)
            Ph = np.zeros((m, dth))
            if k == 0:
                Ph[:, fm.up_cols] = -np.eye(m)
            extra.append((Rd, np.hstack([G, np.zeros((m, ns))]), np.zeros(m), Ph))
    # state targets: the k-th state term is dx_k - dx_s = Gam u + (Phi - Sx) theta + d - sx
    if fm.tracking:
        Phi_t = [P_ - fm.Sx for P_ in Phi]
        d_t = [dk - fm.sx for dk in d]
    else:
        Phi_t, d_t = Phi, d
    Gam_z = Gam if not ns else [np.hstack([G, np.zeros((n, ns))]) for G in Gam]

    # --- the cost ------------------------------------------------------------------------
    if spec.norm == "2":
        assert Q is not None and R is not None
        Qs = 0.5 * (Q + Q.T)
        Rs = 0.5 * (R + R.T)
        W = [Qs] * N + ([0.5 * (P + P.T)] if P is not None else [np.zeros((n, n))])
        if Bk is None:
            H = 2.0 * np.kron(np.eye(N), Rs)
        else:
            H = 2.0 * Bk.T @ np.kron(np.eye(N), Rs) @ Bk
        if ns:
            H = np.block([[H, np.zeros((nu, ns))], [np.zeros((ns, nu)), np.zeros((ns, ns))]])
        cz = np.zeros(nd)
        Cz = np.zeros((nd, dth))
        Kq = np.zeros((dth, dth))
        kl = np.zeros(dth)
        k0 = 0.0
        for k in range(N + 1):
            Gk, Wk = Gam_z[k], W[k]
            H += 2.0 * Gk.T @ Wk @ Gk
            cz += 2.0 * Gk.T @ Wk @ d_t[k]
            Cz += 2.0 * Gk.T @ Wk @ Phi_t[k]
            Kq += Phi_t[k].T @ Wk @ Phi_t[k]
            kl += 2.0 * Phi_t[k].T @ Wk @ d_t[k]
            k0 += float(d_t[k] @ Wk @ d_t[k])
        if fm.tracking:
            # (v_k - du_s)'R(v_k - du_s): the cross and constant terms of the input target
            for k in range(N):
                Gv = np.hstack([move(k), np.zeros((m, ns))])
                extra.append((R, np.zeros((m, nd)), -fm.su, -fm.Su))
                cz += -2.0 * Gv.T @ Rs @ fm.su
                Cz += -2.0 * Gv.T @ Rs @ fm.Su
        for M, Gv, dv, Ph in extra:
            Ms = 0.5 * (M + M.T)
            H += 2.0 * Gv.T @ Ms @ Gv
            cz += 2.0 * Gv.T @ Ms @ dv
            Cz += 2.0 * Gv.T @ Ms @ Ph
            Kq += Ph.T @ Ms @ Ph
            kl += 2.0 * Ph.T @ Ms @ dv
            k0 += float(dv @ Ms @ dv)
        if ns:
            # soft_weight * (eps + eps^2): see SOFT_COST
            cz[nu:] += float(spec.soft_weight)
            H[nu:, nu:] += 2.0 * float(spec.soft_weight) * np.eye(ns)
        H = 0.5 * (H + H.T)
        Kq = 0.5 * (Kq + Kq.T)
        program = MpProgram(
            H=H, c=cz, C=Cz, A=Au, b=bu, F=Fu, A_theta=A_theta, b_theta=b_theta,
        )
        return MpcProgram(
            program=program, model=model, spec=spec, n=n, m=m, N=N,
            u0_slice=slice(0, m), x_op=x_op, u_op=u_op, _Kq=Kq, _kl=kl, _k0=k0,
            formulation=fm, _soft0=soft0,
        )

    # LP norms: terms (M, Gv, dv, Phiv) with v = Gv u + Phiv theta + dv
    assert Q is not None and R is not None
    terms: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for k in range(1, N):  # the k = 0 state term depends on theta only
        terms.append((Q, Gam_z[k], d_t[k], Phi_t[k]))
    for k in range(N):
        if Bk is None and not ns:
            G = np.zeros((m, nu))
            G[:, k * m:(k + 1) * m] = np.eye(m)
        else:
            G = np.hstack([move(k), np.zeros((m, ns))])
        if fm.tracking:
            terms.append((R, G, -fm.su, -fm.Su))
        else:
            terms.append((R, G, np.zeros(m), np.zeros((m, dth))))
    if P is not None:
        terms.append((P, Gam_z[N], d_t[N], Phi_t[N]))
    terms += extra
    terms = [t for t in terms if t[0].shape[0] > 0]

    n_slack = sum(M.shape[0] for M, *_ in terms) if spec.norm == "1" else len(terms)
    nz = nd + n_slack
    A_rows = [np.hstack([Au, np.zeros((Au.shape[0], n_slack))])]
    b_list = [bu]
    F_list = [Fu]
    s = nd  # index of the next slack
    # each slack is measured in its weight's units, t = sigma t' (sigma: the largest entry
    # of the weight's row (norm "1") or matrix (norm "inf"); 1 for a zero weight), at the
    # cost sigma: the rows are then the same for the weights times any factor, and the
    # cost only scales (the solver normalises it), where rows M G u - t <= ... with t of
    # size 1e7 had left the slack's coefficient at 1e-7 after row normalisation (issue 37).
    # (Scaling only the weights far from 1 was tried: the designs near the edge of that
    # band, R = 1e3 next to Q = 1e10, failed in the basis graph)
    c_slack = np.ones(n_slack)
    for M, G, dv, Ph in terms:
        q = M.shape[0]
        sig = np.max(np.abs(M), axis=1 if spec.norm == "1" else None, keepdims=True)
        sig = np.where(sig > 0.0, sig, 1.0).reshape(-1, 1) * np.ones((q, 1))
        Ms = M / sig
        MG, Md, MP = Ms @ G, Ms @ dv, Ms @ Ph
        S = np.zeros((q, n_slack))
        if spec.norm == "1":
            S[:, s - nd:s - nd + q] = -np.eye(q)
            c_slack[s - nd:s - nd + q] = sig[:, 0]
            s += q
        else:
            S[:, s - nd] = -1.0
            c_slack[s - nd] = sig[0, 0]
            s += 1
        #  M(G u + Ph theta + dv) / sigma - t' <= 0   and   -M(...) / sigma - t' <= 0
        A_rows += [np.hstack([MG, S]), np.hstack([-MG, S])]
        b_list += [-Md, Md]
        F_list += [-MP, MP]
    A_all = np.vstack(A_rows)
    b_all = np.concatenate(b_list)
    F_all = np.vstack(F_list)
    cz = np.concatenate([np.zeros(nu), np.full(ns, float(spec.soft_weight)), c_slack])
    program = MpProgram(
        H=np.zeros((nz, nz)), c=cz, C=np.zeros((nz, dth)), A=A_all, b=b_all, F=F_all,
        A_theta=A_theta, b_theta=b_theta,
    )
    return MpcProgram(
        program=program, model=model, spec=spec, n=n, m=m, N=N,
        u0_slice=slice(0, m), x_op=x_op, u_op=u_op,
        _Kq=np.zeros((dth, dth)), _kl=np.zeros(dth), _k0=0.0,
        formulation=fm, _soft0=soft0,
    )


def _soft_row(k: int, a: np.ndarray, b: float, f: np.ndarray,
              Su_rows: list, sb_rows: list, SF_rows: list, s0_A: list, s0_b: list) -> None:
    """File the soft row ``a u <= b + f theta`` of step k.

    A row on theta alone (``x_0``, ``y_0``, or a step no move reaches) cannot change the
    optimal moves: its slack would only split regions, so its cost goes to
    ``theta_constant`` instead.
    """
    if k == 0 or not np.any(a):
        s0_A.append(-f)
        s0_b.append(float(b))
    else:
        Su_rows.append(a)
        sb_rows.append(float(b))
        SF_rows.append(f)


def _onto_bounds(v: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 tol: float = 1e-9) -> np.ndarray | None:
    """``v`` clipped to ``[lo, hi]`` if it is within ``tol * max(1, |bound|)`` of it (and
    finite); None otherwise."""
    v = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(v)):
        return None
    if np.any(v < lo - tol * np.maximum(1.0, np.abs(lo))) or np.any(
        v > hi + tol * np.maximum(1.0, np.abs(hi))
    ):
        return None
    return np.clip(v, lo, hi)


def check_feasible(problem: Problem, model: LinearModel | None = None) -> None:
    """Raise ``SpecError`` if no initial state in the state bounds has a feasible MPC.

    Feasibility does not depend on the cost: the LP (HiGHS, zero cost) is over the lifted
    set ``{(theta, z): A z <= b + F theta, A_theta theta <= b_theta}`` without the rows
    that the cost's and the soft constraints' slacks satisfy for any moves
    (``mp.coverage.feasibility_rows``), rows normalised. With those rows, whose size
    follows the weights, HiGHS had called a feasible MPC with ``Q = 1e16`` infeasible
    (issue 37).

    Parameters
    ----------
    problem : Problem
        The problem whose ``mpc`` is checked.
    model : LinearModel, optional
        The prediction model; ``plant.discretize(problem)`` when omitted.

    Raises
    ------
    SpecError
        ``field="mpc"`` when the lifted set is empty.
    SolverError
        When HiGHS fails.
    """
    if model is None:
        from codev_engine.plant import discretize

        model = discretize(problem)
    prog = build_program(problem.mpc, model).program
    infeasible = SpecError("the MPC is infeasible for every initial state in the state bounds",
                           field="mpc")
    try:
        red = reduce_program(prog)
    except SpecError:
        raise infeasible from None  # an empty parameter set, inconsistent equalities
    A, b, _ = feasibility_rows(red.G, red.S, red.w, red.At, red.bt)
    from scipy.optimize import linprog

    res = linprog(np.zeros(A.shape[1]), A_ub=A, b_ub=b, bounds=(None, None), method="highs")
    if res.status == 2:
        raise infeasible
    if res.status != 0:
        raise SolverError(f"MPC feasibility LP failed: {res.message}")


# ---------------------------------------------------------------------------------------
# the online (reference) MPC
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class OnlineSolution:
    """Result of one online MPC solve (plant coordinates).

    Attributes
    ----------
    status : str
        ``"optimal"`` or ``"infeasible"``.
    u0 : (m,) ndarray
        First move; NaN when infeasible.
    U : (N, m) ndarray
        All planned inputs; NaN when infeasible.
    X : (N+1, n) ndarray
        Predicted states ``x_0..x_N``; NaN when infeasible.
    cost : float
        Optimal MPC cost (including the ``x_0`` stage term); ``inf`` when infeasible.
    """

    status: str
    u0: np.ndarray
    U: np.ndarray
    X: np.ndarray
    cost: float

    @property
    def feasible(self) -> bool:
        """True when the MPC has a solution at this state (``status == "optimal"``)."""
        return self.status == "optimal"


class OnlineMpc:
    """The MPC solved online at one state, non-condensed, with cvxpy + Clarabel.

    Variables are the plant-coordinate states ``x_0..x_N`` (with the dynamics as
    equalities) and inputs ``u_0..u_{N-1}``; the cost includes the ``x_0`` stage term, so
    ``solve(x).cost`` is the full MPC cost. The problems are compiled once (DPP, ``x_0`` is a
    cvxpy Parameter), so repeated solves are cheap.

    Unlike the explicit law's parameter set, no ``domain_bound`` is imposed on state axes
    with infinite bounds.

    Where Clarabel fails at the tight settings (near the boundary of the feasible set),
    feasibility is decided by a HiGHS LP on the same constraints and Clarabel is retried
    with other settings (see ``_run``); ``SolverError`` only when all of that fails.

    Parameters
    ----------
    spec : MpcSpec
        The MPC design (horizon, norm, weights, bounds in plant coordinates).
    model : LinearModel
        The prediction model in deviation coordinates.
    solver_options : dict, optional
        Clarabel settings; defaults to ``CLARABEL_OPTIONS``.

    Raises
    ------
    SpecError
        When ``spec`` does not fit the model (as :func:`build_program`), or a soft
        constraint's ``soft_weight`` is over ``ONLINE_SOFT_RATIO`` times the cost's smallest
        weight (naming ``mpc.soft_weight`` and the largest value taken).
    """

    def __init__(self, spec: MpcSpec, model: LinearModel,
                 solver_options: dict | None = None) -> None:
        A = np.asarray(model.A, dtype=float)
        B = np.asarray(model.B, dtype=float)
        c = np.asarray(model.c, dtype=float).reshape(-1)
        n, m = B.shape
        N = int(spec.horizon)
        _check_dims(spec, n, m)
        self.spec = spec
        self.model = model
        self.n, self.m, self.N = n, m, N
        self.x_op = np.asarray(model.x_op, dtype=float).reshape(n)
        self.u_op = np.asarray(model.u_op, dtype=float).reshape(m)
        self.solver_options = dict(CLARABEL_OPTIONS if solver_options is None
                                   else solver_options)

        import cvxpy as cp  # imported here: loading a spec or a law does not need it

        fm = formulation(spec, model)
        _check_soft_weight(spec, fm)
        self.formulation = fm
        self.d = fm.d
        x = cp.Variable((N + 1, n), name="x")
        u = cp.Variable((N, m), name="u")
        self._x, self._u = x, u
        self._x0 = cp.Parameter(fm.d, name="theta")  # theta = (x_0, u_prev, r)
        self._u0 = cp.Parameter(m, name="u0")
        dtheta = self._x0 - fm.theta_op
        dx = [x[k] - self.x_op for k in range(N + 1)]
        du = [u[k] - self.u_op for k in range(N)]
        # the cost's targets (the operating point when regulating)
        ex = dx if not fm.tracking else [v - (fm.Sx @ dtheta + fm.sx) for v in dx]
        eu = du if not fm.tracking else [v - (fm.Su @ dtheta + fm.su) for v in du]

        cons = [x[0] == self._x0[:n]]
        for k in range(N):
            cons.append(dx[k + 1] == A @ dx[k] + B @ du[k] + c)
        xmin, xmax = np.asarray(spec.x_min, float), np.asarray(spec.x_max, float)
        umin, umax = np.asarray(spec.u_min, float), np.asarray(spec.u_max, float)
        # the same constraints for the feasibility LP (HiGHS): variables x_0..x_N, then
        # u_0..u_{N-1}; dynamics as equalities, bounds as variable bounds
        self._xmin, self._xmax, self._umin, self._umax = xmin, xmax, umin, umax
        nv = (N + 1) * n + N * m
        Aeq = np.zeros((N * n, nv))
        for k in range(N):
            r = slice(k * n, (k + 1) * n)
            Aeq[r, (k + 1) * n:(k + 2) * n] = np.eye(n)
            Aeq[r, k * n:(k + 1) * n] = -A
            Aeq[r, (N + 1) * n + k * m:(N + 1) * n + (k + 1) * m] = -B
        self._lp_Aeq = Aeq
        self._lp_beq = np.tile(c + self.x_op - A @ self.x_op - B @ self.u_op, N)
        soft = set(spec.soft)
        slacks = []

        def bound(expr, lo: np.ndarray, hi: np.ndarray, soft_lo: bool, soft_hi: bool) -> None:
            ilo, ihi = np.flatnonzero(np.isfinite(lo)), np.flatnonzero(np.isfinite(hi))
            for idx, side, is_soft in ((ilo, -1.0, soft_lo), (ihi, 1.0, soft_hi)):
                if not idx.size:
                    continue
                lim = hi[idx] if side > 0 else lo[idx]
                if is_soft:
                    e = cp.Variable(idx.size, nonneg=True)
                    slacks.append(e)
                    cons.append(side * (expr[idx] - lim) <= e)
                else:
                    cons.append(side * (expr[idx] - lim) <= 0)

        for k in range(N + 1):
            bound(x[k], xmin, xmax, "x_min" in soft, "x_max" in soft)
        for k in range(N):
            bound(u[k], umin, umax, False, False)
        if spec.C is not None and spec.y_min is not None:
            Cy = np.asarray(spec.C, float)
            for k in range(N + 1):
                bound(Cy @ x[k], np.asarray(spec.y_min, float), np.asarray(spec.y_max, float),
                      "y_min" in soft, "y_max" in soft)
        rate = []
        if fm.rates:
            u_prev = self._x0[fm.up_cols]
            rate = [u[0] - u_prev] + [u[k] - u[k - 1] for k in range(1, N)]
        if spec.du_min is not None:
            for v in rate:
                bound(v, np.asarray(spec.du_min, float), np.asarray(spec.du_max, float),
                      False, False)
        for k in range(fm.Nc, N):  # move blocking
            cons.append(u[k] == u[fm.Nc - 1])
        for mc in spec.constraints:
            for k in range(N):
                cons.append(mc.Hx @ x[k] + mc.Hu @ u[k] <= mc.h)
        if fm.term_b.size:
            cons.append(fm.term_Ax @ dx[N] + fm.term_At @ dtheta <= fm.term_b)
        self._extended = bool(
            fm.d > n or fm.tracking or spec.soft or spec.constraints or fm.term_b.size
            or fm.Nc < N or spec.y_min is not None
        )

        Q = _as2d(spec.Q, n)
        R = _as2d(spec.R, m)
        P = None if fm.P is None else _as2d(fm.P, n)
        Rd = None if spec.Rd is None else _as2d(spec.Rd, m)
        # the objective divided by the largest weight (the same optimum; costs are scaled
        # back): Clarabel's absolute tolerances had called the MPC infeasible at most
        # states with Q = 1e10 (issue 37). Not by soft_weight, a penalty usually far above
        # the weights: the regulator's terms would shrink below the absolute tolerances
        weights = [M for M in (Q, R, P, Rd) if M is not None]
        kappa = max((float(np.max(np.abs(M), initial=0.0)) for M in weights), default=0.0)
        kappa = kappa if np.isfinite(kappa) and kappa > 0.0 else 1.0
        self._cost_scale = kappa
        Q, R = Q / kappa, R / kappa
        P = None if P is None else P / kappa
        Rd = None if Rd is None else Rd / kappa
        terms = []
        if spec.norm == "2":
            def quad(v, M):
                if v.parameters():
                    # cvxpy's QP path does not keep quad_form(parameter-affine) DPP (it
                    # would recompile at every solve): name the argument by a variable
                    w = cp.Variable(v.shape)
                    cons.append(w == v)
                    v = w
                return cp.quad_form(v, cp.psd_wrap(0.5 * (M + M.T)))
        else:
            ordp = 1 if spec.norm == "1" else "inf"

            def quad(v, M):
                return cp.norm(M @ v, ordp)
        for k in range(N):
            if Q.shape[0]:
                terms.append(quad(ex[k], Q))
            if R.shape[0]:
                terms.append(quad(eu[k], R))
        if P is not None and P.shape[0]:
            terms.append(quad(ex[N], P))
        if Rd is not None:
            terms += [quad(v, Rd) for v in rate]
        if slacks:
            eps = cp.hstack(slacks)
            terms.append(float(spec.soft_weight) / kappa * cp.sum(eps))
            if spec.norm == "2":  # see SOFT_COST
                terms.append(float(spec.soft_weight) / kappa * cp.sum_squares(eps))
        objective = cp.Minimize(cp.sum(cp.hstack(terms)) if terms else cp.Constant(0.0))

        self._cons = cons
        self._prob = cp.Problem(objective, cons)
        self._prob_fixed = cp.Problem(objective, cons + [u[0] == self._u0])
        assert self._prob.is_dcp(dpp=True) and self._prob_fixed.is_dcp(dpp=True)

    def _run(self, prob: cp.Problem, u0: np.ndarray | None = None) -> bool:
        """Solve ``prob``; True if optimal, False if infeasible.

        Clarabel at the tight ``solver_options`` first. When it does not answer cleanly
        (inaccurate, iteration limit, numerical failure -- typically a few 1e-5 outside the
        feasible set, where the problem is nearly infeasible), feasibility is decided by an
        exact LP (HiGHS) on the same constraints: infeasible is the answer; feasible means
        Clarabel is retried with the settings of ``RETRY_OPTIONS`` (defaults first), and
        only if every one fails is ``SolverError`` raised.

        ``u0`` is the fixed first move of ``_prob_fixed`` (for the feasibility LP).
        """
        import cvxpy as cp

        status, error = self._clarabel(prob, self.solver_options)
        attempts = [status]
        if status == cp.OPTIMAL:
            return True
        if status == cp.INFEASIBLE:
            return False
        feasible = self._feasible_lp(np.asarray(self._x0.value, dtype=float), u0)
        if feasible is False:
            return False
        inaccurate = self.solver_options if status == cp.OPTIMAL_INACCURATE else None
        for options in RETRY_OPTIONS:
            status, err = self._clarabel(prob, options)
            attempts.append(status)
            error = err or error
            if status == cp.OPTIMAL:
                return True
            if status == cp.INFEASIBLE:
                # a certificate of infeasibility: HiGHS (tolerance 1e-9) accepted a state
                # within its tolerance of the feasible set, or could not decide
                return False
            if status == cp.OPTIMAL_INACCURATE and inaccurate is None:
                inaccurate = options
        if inaccurate is not None:
            # no setting reached its tolerances: the first inaccurate answer is still an
            # answer (and HiGHS agrees the problem is feasible); solve again to restore it
            status, err = self._clarabel(prob, inaccurate)
            if status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
                return True
        what = "feasible" if feasible else "undecided"
        raise SolverError(
            f"online MPC: Clarabel failed at x0={self._x0.value.tolist()} (HiGHS: {what}); "
            f"statuses {', '.join(attempts)}" + (f"; {error}" if error else "")
        )

    @staticmethod
    def _clarabel(prob: cp.Problem, options: dict) -> tuple[str, str]:
        """Solve with Clarabel -> (cvxpy status, error text); a solver failure is the
        status ``"failed"``."""
        import cvxpy as cp

        try:
            with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
                # "Solution may be inaccurate": the status says so, and it is handled (as
                # are overflows in the objective value of a diverged iterate)
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                prob.solve(solver=cp.CLARABEL, **options)
        except cp.SolverError as exc:
            return "failed", str(exc)
        return prob.status, ""

    def _feasible_lp(self, x0: np.ndarray, u0: np.ndarray | None) -> bool | None:
        """Are the MPC constraints feasible at ``x0`` (and first move ``u0``)? HiGHS LP.

        ``x0`` and ``u0`` may exceed their bounds by the LP's tolerance (1e-9, relative to
        the bound when larger than 1; a first move on an input bound is often a rounding
        error beyond it) and are then moved onto the bound.

        True / False, or None when HiGHS cannot decide either.
        """
        n, m, N = self.n, self.m, self.N
        if self._extended:
            return self._feasible_cvxpy(x0, u0)
        x0 = _onto_bounds(x0, self._xmin, self._xmax)
        if x0 is None:
            return False
        lo = np.concatenate([x0, np.tile(self._xmin, N), np.tile(self._umin, N)])
        hi = np.concatenate([x0, np.tile(self._xmax, N), np.tile(self._umax, N)])
        if u0 is not None:
            u0 = _onto_bounds(np.asarray(u0, dtype=float).reshape(m), self._umin, self._umax)
            if u0 is None:
                return False
            lo[(N + 1) * n:(N + 1) * n + m] = u0
            hi[(N + 1) * n:(N + 1) * n + m] = u0
        from scipy.optimize import linprog

        try:
            res = linprog(np.zeros(lo.shape[0]), A_eq=self._lp_Aeq, b_eq=self._lp_beq,
                          bounds=np.column_stack([lo, hi]), method="highs",
                          options={"primal_feasibility_tolerance": 1e-9})
        except ValueError:
            return None
        if res.status == 0:
            return True
        if res.status == 2:
            return False
        return None

    def _feasible_cvxpy(self, theta: np.ndarray, u0: np.ndarray | None) -> bool | None:
        """:meth:`_feasible_lp` for designs beyond the box-bounded regulator: the same
        constraints as the MPC (cvxpy, zero cost) by HiGHS, with ``x_0`` and ``u0`` moved onto
        their box bounds when within the LP's tolerance of them."""
        import cvxpy as cp

        n, m = self.n, self.m
        x0 = _onto_bounds(theta[:n], self._xmin, self._xmax)
        if x0 is None and not self.spec.soft:
            return False
        theta = np.array(theta, dtype=float)
        if x0 is not None:
            theta[:n] = x0
        cons = list(self._cons)
        if u0 is not None:
            u0 = _onto_bounds(np.asarray(u0, dtype=float).reshape(m), self._umin, self._umax)
            if u0 is None:
                return False
            cons.append(self._u[0] == u0)
        saved = self._x0.value
        self._x0.value = theta
        try:
            prob = cp.Problem(cp.Minimize(0), cons)
            with warnings.catch_warnings():
                # cvxpy's SciPy path does not cache parametrised problems ("not DPP"): this
                # LP runs only where Clarabel failed, so its compile time does not matter
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=cp.SCIPY, scipy_options={"method": "highs"})
        except (cp.SolverError, ValueError):
            return None
        finally:
            self._x0.value = saved
        if prob.status in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE):
            return True
        if prob.status in (cp.INFEASIBLE, cp.INFEASIBLE_INACCURATE):
            return False
        return None

    def solve(self, x: np.ndarray) -> OnlineSolution:
        """Solve the MPC at one plant state.

        Parameters
        ----------
        x : (d,) array_like
            The parameter ``theta``: the initial state ``x_0`` (then ``u_prev`` and ``r``
            when the design takes them), in plant coordinates.

        Returns
        -------
        OnlineSolution
            ``status="infeasible"`` (NaN plans, infinite cost) when no plan satisfies the
            constraints.

        Raises
        ------
        SolverError
            When Clarabel fails at every setting although the MPC may be feasible.
        """
        self._x0.value = np.asarray(x, dtype=float).reshape(self.d)
        if not self._run(self._prob):
            nan = np.nan
            return OnlineSolution(
                status="infeasible", u0=np.full(self.m, nan),
                U=np.full((self.N, self.m), nan), X=np.full((self.N + 1, self.n), nan),
                cost=float("inf"),
            )
        U = np.array(self._u.value, dtype=float)
        return OnlineSolution(
            status="optimal", u0=U[0].copy(), U=U, X=np.array(self._x.value, dtype=float),
            cost=float(self._prob.value) * self._cost_scale,
        )

    def first_move_cost(self, x: np.ndarray, u0: np.ndarray) -> float:
        """Optimal MPC cost at ``x`` with the first move fixed to ``u0``.

        ``u0`` is an optimal first move iff this equals ``solve(x).cost`` (within solver
        tolerance), which tests an explicit law's move even where the optimal move is not
        unique (and so need not be the one :meth:`solve` returns).

        Parameters
        ----------
        x : (d,) array_like
            The parameter ``theta`` (as :meth:`solve`), in plant coordinates.
        u0 : (m,) array_like
            The first move, in plant coordinates.

        Returns
        -------
        float
            ``inf`` when no feasible plan starts with ``u0``.

        Raises
        ------
        SolverError
            As :meth:`solve`.
        """
        self._x0.value = np.asarray(x, dtype=float).reshape(self.d)
        self._u0.value = np.asarray(u0, dtype=float).reshape(self.m)
        if not self._run(self._prob_fixed, u0=self._u0.value):
            return float("inf")
        return float(self._prob_fixed.value) * self._cost_scale

    def solve_many(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Solve the MPC at each of several plant states (see :meth:`solve`).

        Parameters
        ----------
        X : (P, d) or (d,) array_like
            The parameters ``theta`` (as :meth:`solve`), one per row.

        Returns
        -------
        U0 : (P, m) ndarray
            First moves (NaN where infeasible).
        cost : (P,) ndarray
            Optimal costs (inf where infeasible).
        feasible : (P,) bool ndarray
            Where the MPC has a solution.

        Raises
        ------
        SolverError
            As :meth:`solve`.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        U0 = np.full((X.shape[0], self.m), np.nan)
        cost = np.full(X.shape[0], np.inf)
        feasible = np.zeros(X.shape[0], dtype=bool)
        for p, xp in enumerate(X):
            sol = self.solve(xp)
            U0[p], cost[p], feasible[p] = sol.u0, sol.cost, sol.feasible
        return U0, cost, feasible
