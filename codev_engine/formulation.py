"""What an ``[mpc]`` table means on a prediction model, derived once for both MPCs.

The condensed program (:func:`codev_engine.mpc.build_program`) and the online MPC
(:class:`codev_engine.mpc.OnlineMpc`) condense and solve independently -- one is the
other's oracle -- but they share what is not a matter of condensing:

* the **parameter** ``theta = (x, u_prev, r)``: ``u_prev`` (the input applied at the previous
  sample) when the design has input rates, ``r`` when the reference is free (a box);
* the **targets** ``(x_s, u_s)``: the operating point when regulating; when tracking, the
  minimum-norm solution of ``[[A - I, B], [C_r, 0]] [dx_s; du_s] = [-c; r - C_r x_op]``
  (deviation coordinates of the prediction model), affine in ``r``;
* the **terminal weight** (``P`` as given, or the DARE solution for ``P = "lqr"``) and the
  **terminal set** (a given polytope, or the maximal positively invariant set of the LQR loop
  around the target for ``terminal_set = "lqr"``, see :mod:`codev_engine.terminal`);
* the **parameter box** on which the explicit law is computed.

All in deviation coordinates of the model: ``dx = x - x_op``, ``du = u - u_op``; ``r`` is in
plant coordinates of the tracked signal.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.plant import LinearModel
from codev_engine.spec.problem import MpcSpec, parameter_names
from codev_engine.terminal import lqr_terms, maximal_invariant_set

__all__ = ["Formulation", "formulation", "parameter_names", "U_PREV_MARGIN"]

#: The law's domain in ``u_prev`` is ``[u_min, u_max]`` widened by this much (relative, floor
#: 1): the law is exact there too (the MPC is solved as stated, ``u_prev`` only enters the
#: rate rows), and a held input on its bound keeps its rounding error inside the domain.
U_PREV_MARGIN = 1e-6


@dataclass(frozen=True)
class Formulation:
    """The shared derived data of an MPC design on a model (see the module docstring).

    Attributes
    ----------
    n, m, N, Nc : int
        States, inputs, horizon, control horizon.
    nr : int
        Length of the free reference (0 when fixed or regulating).
    d : int
        Length of ``theta``: ``n`` + (``m`` with rates) + ``nr``.
    rates : bool
        The law takes ``u_prev``.
    theta_op : (d,) ndarray
        ``theta - theta_op`` is the program's parameter: ``(x - x_op, u_prev - u_op, r)``.
    Sx : (n, d) ndarray
    sx : (n,) ndarray
        State target ``dx_s = Sx @ dtheta + sx``.
    Su : (m, d) ndarray
    su : (m,) ndarray
        Input target ``du_s = Su @ dtheta + su``.
    tracking : bool
        False when the targets are the operating point (all four zero).
    P : (p, n) ndarray or None
        The terminal weight (the DARE solution for ``P = "lqr"``).
    K : (m, n) ndarray or None
        The LQR gain (``u - u_s = -K (x - x_s)``) when ``P`` or the terminal set is "lqr".
    term_Ax : (t, n) ndarray
    term_At : (t, d) ndarray
    term_b : (t,) ndarray
        The terminal constraint ``term_Ax @ dx_N + term_At @ dtheta <= term_b`` (t = 0: none).
    terminal_steps : int
        Gilbert--Tan steps of the LQR terminal set (0 otherwise).
    theta_lo, theta_hi : (d,) ndarray
        The parameter box, deviation coordinates.
    """

    n: int
    m: int
    N: int
    Nc: int
    nr: int
    d: int
    rates: bool
    theta_op: np.ndarray
    Sx: np.ndarray
    sx: np.ndarray
    Su: np.ndarray
    su: np.ndarray
    tracking: bool
    P: np.ndarray | None
    K: np.ndarray | None
    term_Ax: np.ndarray
    term_At: np.ndarray
    term_b: np.ndarray
    terminal_steps: int
    theta_lo: np.ndarray
    theta_hi: np.ndarray

    @property
    def x_cols(self) -> slice:
        """Where ``x`` sits in ``theta``."""
        return slice(0, self.n)

    @property
    def up_cols(self) -> slice:
        """Where ``u_prev`` sits in ``theta`` (empty without rates)."""
        return slice(self.n, self.n + (self.m if self.rates else 0))

    @property
    def r_cols(self) -> slice:
        """Where ``r`` sits in ``theta`` (empty without a free reference)."""
        return slice(self.d - self.nr, self.d)

    def blocking(self) -> np.ndarray:
        """The move-blocking map ``U = Bk @ v`` from the ``Nc*m`` free moves to ``N*m``.

        Returns
        -------
        (N*m, Nc*m) ndarray
            ``u_k = v_{min(k, Nc-1)}``.
        """
        m = self.m
        Bk = np.zeros((self.N * m, self.Nc * m))
        for k in range(self.N):
            j = min(k, self.Nc - 1)
            Bk[k * m:(k + 1) * m, j * m:(j + 1) * m] = np.eye(m)
        return Bk


_CACHE: dict[str, Formulation] = {}


def formulation(spec: MpcSpec, model: LinearModel) -> Formulation:
    """The derived data of ``spec`` on ``model`` (computed once per design and model).

    Parameters
    ----------
    spec : MpcSpec
    model : LinearModel
        The prediction model, deviation coordinates.

    Returns
    -------
    Formulation

    Raises
    ------
    SpecError
        A reference with no exact steady state (fixed) or one the box does not exclude
        (free); an LQR term with no stabilising solution; a terminal set that is empty,
        unbounded or not finitely determined.
    """
    key = _fingerprint(spec, model)
    hit = _CACHE.get(key)
    if hit is None:
        hit = _derive(spec, model)
        if len(_CACHE) > 32:
            _CACHE.clear()
        _CACHE[key] = hit
    return hit


def _fingerprint(spec: MpcSpec, model: LinearModel) -> str:
    h = hashlib.sha256()

    def put(v) -> None:
        if v is None:
            h.update(b"N")
        elif isinstance(v, np.ndarray):
            h.update(str(v.shape).encode())
            h.update(np.ascontiguousarray(v, dtype="<f8").tobytes())
        elif isinstance(v, (tuple, list)):
            h.update(b"(")
            for x in v:
                put(x)
            h.update(b")")
        elif hasattr(v, "__dataclass_fields__"):
            h.update(type(v).__name__.encode())
            for name in v.__dataclass_fields__:
                put(getattr(v, name))
        else:
            h.update(repr(v).encode())

    put(spec)
    for a in (model.A, model.B, model.c, model.x_op, model.u_op):
        put(np.asarray(a, dtype=float))
    return h.hexdigest()


def _derive(spec: MpcSpec, model: LinearModel) -> Formulation:
    A = np.asarray(model.A, dtype=float)
    B = np.asarray(model.B, dtype=float)
    c = np.asarray(model.c, dtype=float).reshape(-1)
    n, m = B.shape
    x_op = np.asarray(model.x_op, dtype=float).reshape(n)
    u_op = np.asarray(model.u_op, dtype=float).reshape(m)
    N, Nc = int(spec.horizon), int(spec.Nc)
    rates = spec.has_rates
    ref = spec.reference
    nr = int(ref.lower.shape[0]) if spec.free_reference else 0  # type: ignore[union-attr]
    d = n + (m if rates else 0) + nr
    theta_op = np.concatenate([x_op, u_op if rates else np.zeros(0), np.zeros(nr)])
    D = float(spec.domain_bound)

    # --- targets ---------------------------------------------------------------------
    Sx, sx = np.zeros((n, d)), np.zeros(n)
    Su, su = np.zeros((m, d)), np.zeros(m)
    tracking = ref is not None
    if ref is not None:
        if ref.signal == "y":
            assert spec.C is not None
            Cr = np.asarray(spec.C, dtype=float)
        else:
            Cr = np.eye(n)
        p = Cr.shape[0]
        M = np.block([[A - np.eye(n), B], [Cr, np.zeros((p, m))]])
        Mp = np.linalg.pinv(M)
        T = Mp[:, n:]  # (n+m, p): the part of the target that follows r
        t0 = Mp[:, :n] @ (-c) - T @ (Cr @ x_op)
        scale = 1.0 + np.abs(M).max()

        def residual(r: np.ndarray) -> float:
            sol = t0 + T @ r
            rhs = np.concatenate([-c, r - Cr @ x_op])
            return float(np.abs(M @ sol - rhs).max()) / (scale * (1.0 + np.abs(rhs).max()))

        if ref.free:
            assert ref.lower is not None and ref.upper is not None
            corners = _corners(ref.lower, ref.upper)
            worst = max(residual(r) for r in corners)
            if worst > 1e-8:
                raise SpecError(
                    "no steady state of the prediction model tracks every reference in the box "
                    "(more tracked signals than inputs, or a signal the inputs cannot hold); "
                    "narrow the box or track fewer signals",
                    field="mpc.reference",
                )
            Sx[:, n + (m if rates else 0):] = T[:n]
            Su[:, n + (m if rates else 0):] = T[n:]
            sx, su = t0[:n], t0[n:]
        else:
            assert ref.value is not None
            if residual(ref.value) > 1e-8:
                raise SpecError(
                    "no steady state of the prediction model has this reference value "
                    "(more tracked signals than inputs, or a value the inputs cannot hold)",
                    field="mpc.reference.value",
                )
            sol = t0 + T @ ref.value
            sx, su = sol[:n], sol[n:]

    # --- terminal weight -------------------------------------------------------------
    Q = np.asarray(spec.Q, dtype=float)
    R = np.asarray(spec.R, dtype=float)
    P = None if spec.P is None else np.asarray(spec.P, dtype=float)
    K = None
    if spec.terminal_cost == "lqr":
        P, K = lqr_terms(A, B, Q, R)
    if spec.terminal_set == "lqr" and K is None:
        Ql, Rl = (Q, R) if spec.norm == "2" else (Q.T @ Q, R.T @ R)
        if np.linalg.eigvalsh(0.5 * (Rl + Rl.T)).min() <= 1e-12 * max(1.0, np.abs(Rl).max()):
            raise SpecError(
                "the LQR terminal set needs R'R positive definite (R of full column rank)",
                field="mpc.terminal_set",
            )
        _, K = lqr_terms(A, B, Ql, Rl)

    # --- parameter box -----------------------------------------------------------------
    soft = set(spec.soft)
    xmin = np.asarray(spec.x_min, dtype=float) - x_op
    xmax = np.asarray(spec.x_max, dtype=float) - x_op
    lo_x = np.where(np.isfinite(xmin) & ("x_min" not in soft), xmin, -D)
    hi_x = np.where(np.isfinite(xmax) & ("x_max" not in soft), xmax, D)
    lo, hi = [lo_x], [hi_x]
    if rates:
        # u_prev in the input box, widened by U_PREV_MARGIN: a held input on its bound
        # (the law saturates there) stays inside the law's domain with its rounding error,
        # so the verifier's reach set of (x, u_prev) does not leave the domain at a bound
        umin = np.asarray(spec.u_min, dtype=float) - u_op
        umax = np.asarray(spec.u_max, dtype=float) - u_op
        pad_lo = U_PREV_MARGIN * np.maximum(1.0, np.abs(np.asarray(spec.u_min, dtype=float)))
        pad_hi = U_PREV_MARGIN * np.maximum(1.0, np.abs(np.asarray(spec.u_max, dtype=float)))
        lo.append(np.where(np.isfinite(umin), umin - pad_lo, -D))
        hi.append(np.where(np.isfinite(umax), umax + pad_hi, D))
    if nr:
        assert ref is not None and ref.lower is not None and ref.upper is not None
        lo.append(np.asarray(ref.lower, dtype=float))
        hi.append(np.asarray(ref.upper, dtype=float))
    theta_lo, theta_hi = np.concatenate(lo), np.concatenate(hi)

    # --- terminal set ----------------------------------------------------------------
    term_Ax, term_At, term_b = np.zeros((0, n)), np.zeros((0, d)), np.zeros(0)
    steps = 0
    ts = spec.terminal_set
    if ts is not None and ts != "lqr":
        TA, Tb = ts.halfspaces()  # type: ignore[union-attr]
        TA = np.asarray(TA, dtype=float)
        _check_bounded(TA, np.asarray(Tb, dtype=float))
        term_Ax, term_At, term_b = TA, np.zeros((TA.shape[0], d)), Tb - TA @ x_op
    elif ts == "lqr":
        assert K is not None
        term_Ax, term_At, term_b, steps = _lqr_set(spec, A, B, K, x_op, u_op, Sx, sx, Su, su,
                                                   n, m, d, nr, D)

    return Formulation(
        n=n, m=m, N=N, Nc=Nc, nr=nr, d=d, rates=rates, theta_op=theta_op,
        Sx=Sx, sx=sx, Su=Su, su=su, tracking=tracking, P=P, K=K,
        term_Ax=term_Ax, term_At=term_At, term_b=term_b, terminal_steps=steps,
        theta_lo=theta_lo, theta_hi=theta_hi,
    )


def _corners(lo: np.ndarray, hi: np.ndarray) -> list[np.ndarray]:
    p = lo.shape[0]
    if p > 12:
        return [lo, hi, 0.5 * (lo + hi)]
    grid = np.array(np.meshgrid(*[[a, b] for a, b in zip(lo, hi, strict=True)], indexing="ij"))
    return list(grid.reshape(p, -1).T)


def _check_bounded(A: np.ndarray, b: np.ndarray) -> None:
    from codev_engine.geometry.polytope import chebyshev_ball, solve_lp

    n = A.shape[1]
    for i in range(n):
        for sgn in (1.0, -1.0):
            f = np.zeros(n)
            f[i] = -sgn
            _, status, _ = solve_lp(f, A, b)
            if status == "unbounded":
                raise SpecError("the terminal set is unbounded: give a bounded polytope",
                                field="mpc.terminal_set")
            if status == "infeasible":
                raise SpecError("the terminal set is empty", field="mpc.terminal_set")
    _, radius = chebyshev_ball(A, b)
    if not radius > 1e-9:
        raise SpecError("the terminal set has no interior", field="mpc.terminal_set")


def _lqr_set(spec, A, B, K, x_op, u_op, Sx, sx, Su, su, n, m, d, nr, D):
    """The MPI set of the LQR loop in v = (xi, r), as rows on (dx_N, dtheta)."""
    # x = x_op + Sx_r r + sx + xi ; u = u_op + Su_r r + su - K xi  (r: the free reference)
    rc = slice(d - nr, d)
    Xr, Ur = Sx[:, rc], Su[:, rc]  # (n, nr), (m, nr)
    rows: list[np.ndarray] = []
    rhs: list[np.ndarray] = []

    def add(Hx: np.ndarray, Hu: np.ndarray, h: np.ndarray) -> None:
        # Hx x + Hu u <= h  in v = (xi, r)
        Gxi = Hx - Hu @ K
        Gr = Hx @ Xr + Hu @ Ur
        g = h - Hx @ (x_op + sx) - Hu @ (u_op + su)
        keep = np.isfinite(g)
        rows.append(np.hstack([Gxi, Gr])[keep])
        rhs.append(g[keep])

    I_n, I_m = np.eye(n), np.eye(m)
    xmin = np.where(np.isfinite(spec.x_min), spec.x_min, x_op - D)
    xmax = np.where(np.isfinite(spec.x_max), spec.x_max, x_op + D)
    add(I_n, np.zeros((n, m)), xmax)
    add(-I_n, np.zeros((n, m)), -xmin)
    add(np.zeros((m, n)), I_m, np.asarray(spec.u_max, float))
    add(np.zeros((m, n)), -I_m, -np.asarray(spec.u_min, float))
    if spec.C is not None and spec.y_max is not None:
        C = np.asarray(spec.C, float)
        add(C, np.zeros((C.shape[0], m)), np.asarray(spec.y_max, float))
        add(-C, np.zeros((C.shape[0], m)), -np.asarray(spec.y_min, float))
    for mc in spec.constraints:
        add(np.asarray(mc.Hx, float), np.asarray(mc.Hu, float), np.asarray(mc.h, float))
    G = np.vstack(rows)
    g = np.concatenate(rhs)
    Phi = A - B @ K
    if nr:
        ref = spec.reference
        Ir = np.eye(nr)
        G = np.vstack([G, np.hstack([np.zeros((nr, n)), Ir]), np.hstack([np.zeros((nr, n)), -Ir])])
        g = np.concatenate([g, ref.upper, -ref.lower])
        Phi = np.block([[Phi, np.zeros((n, nr))], [np.zeros((nr, n)), Ir]])
    mpi = maximal_invariant_set(Phi, G, g)
    Axi, Ar = mpi.A[:, :n], mpi.A[:, n:]
    # xi = dx_N - Sx dtheta - sx ; r = dtheta[r cols]
    At = -Axi @ Sx
    if nr:
        At[:, rc] += Ar
    return Axi, At, mpi.b + Axi @ sx, mpi.steps
