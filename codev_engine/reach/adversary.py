"""Extreme disturbance signals for an affine plant in closed loop, chosen by the adjoint.

For a fixed sequence of regions the closed loop is an affine system driven by the
disturbance, ``l' x(T)`` is affine in the signal, and the signal that maximises it is
bang-bang: ``w(s) = centre + radius * sign(E' lambda(s))`` with ``lambda`` the adjoint
(costate) of the loop's flow, ``lambda(T) = l`` (Pontryagin's principle for a linear system;
the reachable set's support function in direction ``l``). The regions depend on the signal,
so the choice is iterated: simulate, locate the regions at the samples, solve the adjoint
backwards, take the signs, simulate again. Every iterate is a signal in the box, so the
simulated states are reachable states: the hull of such simulations is a lower bound of the
reach set, much closer to it than random or held-corner signals (the benchmarks and tests
compare the reachtube with it).

A nonlinear plant (or one with uncertain parameters) has no such adjoint at hand:
:func:`sensitivity_signals` takes the same signs from finite differences of the simulated
final state, one run per piece of the signal pushed to the box's bound (the first-order
worst case along the centre signal's run).

This module is for tests, benchmarks and searches: it claims nothing about safety.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from codev_engine.law import ExplicitLaw
from codev_engine.spec.problem import Problem

__all__ = ["adjoint_signals", "sensitivity_signals"]


def adjoint_signals(
    problem: Problem,
    law: ExplicitLaw,
    X0: np.ndarray,
    directions: np.ndarray,
    *,
    hold: str | None = None,
    t_target: float | np.ndarray | None = None,
    iterations: int = 3,
    dt: float | None = None,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Bang-bang disturbance signals pushing ``directions' x(t_target)`` to its maximum.

    Parameters
    ----------
    problem : Problem
        An affine plant (``reach.linear.affine_plant`` not None) with disturbances, a
        ``[verify]`` section, a law over the state alone.
    law : ExplicitLaw
    X0 : (P, n) ndarray
        Initial states.
    directions : (P, n) ndarray
        One direction ``l`` per trajectory.
    hold : {"zoh", "continuous"}, optional
        Default ``problem.verify.hold``.
    t_target : float or (P,) ndarray, optional
        The time at which ``l' x`` is pushed up; default the horizon.
    iterations : int
        Rounds of simulate / adjoint / signs (each round's signal is returned).
    dt : float, optional
        The RK4 step requested of ``simulate_many`` (default ``verify.step / 10``, its
        default): simulate the returned signals with the same ``dt``.

    Returns
    -------
    piece : float
        The pieces' length (s): the RK4 step ``simulate_many`` takes for ``dt``, so each
        piece is one step of the simulation.
    W : (iterations * P, K, d) ndarray
        The signals (round by round, ``P`` per round), for ``simulate_many``'s
        ``disturbance`` with ``Q``.
    Q : (iterations * P, q) ndarray
        The uncertain parameters, at their nominal values.
    X0r : (iterations * P, n) ndarray
        ``X0`` repeated for each round.
    """
    from codev_engine.reach.linear import affine_plant
    from codev_engine.reach.simulate import simulate_many

    ap = affine_plant(problem)
    pl = problem.plant
    if ap is None or ap.E is None or pl.disturbances is None:
        raise ValueError("adjoint signals need an affine plant with disturbances")
    if law.n != pl.n:
        raise ValueError("adjoint signals need a law over the state alone")
    vs = problem.verify
    hold = hold or vs.hold
    X0 = np.atleast_2d(np.asarray(X0, float))
    L = np.atleast_2d(np.asarray(directions, float))
    P, n = X0.shape
    m = pl.m
    Ts = float(problem.model.sample_time)
    T = float(vs.time_horizon)
    dt = vs.step / 10.0 if dt is None else float(dt)
    S = max(1, int(np.ceil(Ts / dt - 1e-9)))  # simulate_many's RK4 steps per period
    h = Ts / S
    J = int(np.floor(T / h + 1e-9))  # whole steps up to the horizon
    K = J + 1
    tt = np.broadcast_to(np.asarray(T if t_target is None else t_target, float), (P,))
    jt = np.minimum(np.round(tt / h).astype(int), J)  # the step index of each target
    box = pl.disturbances
    wc, wr = np.asarray(box.centre, float), np.asarray(box.radius, float)
    # ap.E multiplies the deviation from the box's centre (ap.f0 holds the centre)
    E = ap.E
    q = np.asarray(pl.parameters.nominal, float) if pl.parameters is not None else np.zeros(0)
    Q = np.repeat(q[None, :], P, axis=0)
    # the adjoint's step over h within a period: per region (continuous hold), computed for
    # the regions the runs visit (a law on demand grows while they run); one for zoh, whose
    # jump at a sample is applied below
    if hold == "continuous":
        steps: dict[int, np.ndarray] = {}

        def step_T(regs: np.ndarray) -> np.ndarray:
            for r in np.unique(regs):
                if int(r) not in steps:
                    steps[int(r)] = expm((ap.Ac + ap.Bc @ law.F[r]) * h).T
            return np.stack([steps[int(r)] for r in regs]).reshape(len(regs), n, n)
        width = n
    else:
        Ma = np.zeros((n + m, n + m))
        Ma[:n, :n], Ma[:n, n:] = ap.Ac, ap.Bc
        one = expm(Ma * h).T

        def step_T(regs: np.ndarray) -> np.ndarray:
            return np.broadcast_to(one, (len(regs), n + m, n + m))
        width = n + m
    W = np.repeat(np.repeat(wc[None, None, :], K, axis=1), P, axis=0)
    out_W = []
    for it in range(iterations):
        # (the exact flow of the affine plant per step: no RK4 error at this coarse step)
        exact = ap if pl.parameters is None else None
        if it == 0:
            # every trajectory under the box's centre: one run per distinct initial state
            X0u, inv = np.unique(X0, axis=0, return_inverse=True)
            inv = np.asarray(inv).reshape(-1)
            runs = simulate_many(problem, law, X0u, hold=hold,
                                 disturbance=(h, W[: X0u.shape[0]], Q[: X0u.shape[0]]), dt=h,
                                 affine=exact)
            t, X = runs.t, runs.X[inv]
        else:
            runs = simulate_many(problem, law, X0, hold=hold, disturbance=(h, W, Q), dt=h,
                                 affine=exact)
            t, X = runs.t, runs.X
        # the regions at the samples (the state after the jump: the last record at t_k)
        ks = int(np.floor(T / Ts + 1e-9)) + 1
        reg = np.zeros((P, ks), dtype=int)
        for k in range(ks):
            idx = np.flatnonzero(np.abs(t - k * Ts) < 1e-9 * Ts)
            if idx.size == 0:
                continue
            xk = X[:, idx[-1]]
            ok = np.all(np.isfinite(xk), axis=1)
            r = np.full(P, -1, dtype=int)
            r[ok] = law.locate(xk[ok])
            # outside the law's domain: the last sample's region (a law on demand numbers
            # its regions as it finds them, so a fixed index would be another region there
            # than the full law's); region 0 only for a start outside the domain
            reg[:, k] = np.where(r >= 0, r, reg[:, k - 1] if k else 0)
        # the adjoint backwards over the steps; lam (P, n [+ m]) at the step's end
        lam = np.zeros((P, width))
        grad = np.zeros((P, K, E.shape[1]))
        for j in range(J - 1, -1, -1):
            hit = jt == j + 1
            lam[hit, :n] = L[hit]
            k = min(j // S, reg.shape[1] - 1)
            # the step's sensitivity: x at the step's end moves with E w over the step
            grad[:, j] = lam[:, :n] @ E
            lam = np.einsum("pab,pb->pa", step_T(reg[:, k]), lam)
            if j % S == 0 and hold == "zoh":  # u_k = F x(t_k) + G: the jump's adjoint
                F = law.F[reg[:, k]]  # (P, m, n)
                lam[:, :n] = lam[:, :n] + np.einsum("pmn,pm->pn", F, lam[:, n:])
                lam[:, n:] = 0.0
        W = np.where(grad >= 0, wc + wr, wc - wr)
        W[np.arange(K)[None, :] >= jt[:, None]] = wc  # after the target: the centre
        out_W.append(W.copy())
    return (h, np.concatenate(out_W, axis=0), np.tile(Q, (iterations, 1)),
            np.tile(X0, (iterations, 1)))


def sensitivity_signals(
    problem: Problem,
    law: ExplicitLaw,
    X0: np.ndarray,
    directions: np.ndarray,
    t_target: float | np.ndarray,
    *,
    Q: np.ndarray | None = None,
    hold: str | None = None,
) -> tuple[float, np.ndarray, np.ndarray]:
    """Bang-bang disturbance signals pushing ``directions' x(t_target)`` up, any plant.

    For each distinct ``(x0, q)`` one run under the box's centre and one per piece and
    disturbance component with that piece at the box's upper bound (the rest at the centre)
    give the sensitivities ``g_j`` of ``x(t)`` to piece ``j``; the signal for a direction
    ``l`` is ``d_j = upper`` where ``l' g_j > 0``, ``lower`` where ``< 0`` (the centre past
    the target). Exact for a linear closed loop; for a nonlinear one, or one whose regions
    change with the signal, the first-order worst case along the centre's run. Every signal
    lies in the box, so every run under it is a reachable trajectory.

    Parameters
    ----------
    problem : Problem
        A plant with disturbances and a ``[verify]`` section.
    law : ExplicitLaw
    X0 : (P, n) ndarray
        Initial states.
    directions : (P, n) ndarray
        One direction ``l`` per trajectory.
    t_target : float or (P,) ndarray
        The time at which ``l' x`` is pushed up.
    Q : (P, q) ndarray, optional
        The uncertain parameters' values (default their nominal values).
    hold : {"zoh", "continuous"}, optional
        Default ``problem.verify.hold``.

    Returns
    -------
    piece : float
        The pieces' length (s; ``simulate_many``'s ``disturbance``).
    W : (P, K, d) ndarray
        The signals.
    Q : (P, q) ndarray
        The parameters (as given).
    """
    from codev_engine.reach.simulate import simulate_many

    pl, vs = problem.plant, problem.verify
    if pl.disturbances is None:
        raise ValueError("sensitivity signals need a plant with disturbances")
    hold = hold or vs.hold
    X0 = np.atleast_2d(np.asarray(X0, float))
    L = np.atleast_2d(np.asarray(directions, float))
    P, n = X0.shape
    tt = np.broadcast_to(np.asarray(t_target, float), (P,))
    if Q is None:
        q0 = np.asarray(pl.parameters.nominal, float) if pl.parameters is not None else (
            np.zeros(0))
        Q = np.repeat(q0[None, :], P, axis=0)
    Q = np.atleast_2d(np.asarray(Q, float)).reshape(P, -1)
    # pieces as the verifier's own search takes them (verification._signals)
    Ts = float(problem.model.sample_time)
    S = max(1, int(np.ceil(Ts / (vs.step / 10.0) - 1e-9)))
    h = Ts / S
    piece = h * max(1, round(vs.step / h))
    K = int(np.ceil(vs.time_horizon / piece)) + 1
    lo = np.asarray(pl.disturbances.lower, float)
    hi = np.asarray(pl.disturbances.upper, float)
    mid = 0.5 * (lo + hi)
    d = lo.size
    t_end = float(tt.max())
    J = min(K, int(np.ceil(t_end / piece - 1e-9)))  # the pieces before the last target
    W = np.repeat(np.repeat(mid[None, None, :], K, axis=1), P, axis=0)
    sens: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
    for p in range(P):
        key = np.concatenate([X0[p], Q[p]]).tobytes()
        if key not in sens:
            # the centre run, then one run per (piece, component) pushed to the upper bound
            Wp = np.repeat(np.repeat(mid[None, None, :], K, axis=1), 1 + J * d, axis=0)
            for j in range(J):
                for i in range(d):
                    Wp[1 + j * d + i, j, i] = hi[i]
            R = Wp.shape[0]
            runs = simulate_many(problem, law, np.repeat(X0[p][None], R, axis=0), hold=hold,
                                 t_end=t_end, disturbance=(piece, Wp, np.repeat(Q[p][None],
                                                                                R, axis=0)))
            sens[key] = (runs.t, runs.X)
        t, X = sens[key]
        k = int(np.argmin(np.abs(t - tt[p])))
        g = ((X[1:, k] - X[0, k]) @ L[p]).reshape(J, d)  # l' dx(t) per piece's push
        g[~np.isfinite(g)] = 0.0
        jt = min(J, int(np.ceil(tt[p] / piece - 1e-9)))
        W[p, :jt] = np.where(g[:jt] > 0, hi, np.where(g[:jt] < 0, lo, mid))
    return piece, W, Q
