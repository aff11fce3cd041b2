"""Closed-loop simulation of the sampled explicit-MPC loop, and property checks.

The semantics (the contract of the verifier, ``docs/spec.md`` ``[verify]``):

* sample times ``t_k = k * Ts`` (``Ts = problem.model.sample_time``, ``k = 0, 1, ...``);
* at ``t_k`` the region ``i = law.locate(x(t_k))`` is found; if it is ``-1`` the law is
  undefined there: the trajectory stops at ``t_k`` (a violation of kind ``"undefined"``);
* over ``[t_k, t_k + Ts)`` the plant runs ``dx/dt = f(x, u)`` with
  ``u = F_i x(t_k) + G_i`` (hold ``"zoh"``) or ``u = F_i x(t) + G_i`` (hold
  ``"continuous"``: the region stays fixed over the period, only ``x(t)`` varies);
* the properties hold over ``t in [0, T]``, between samples included: ``x(t)`` outside every
  unsafe set (closed: touching is a violation), inside every safe set, and with
  ``input_bounds`` ``u_min <= u(t) <= u_max``.

A sample time that equals the end of the simulated interval (``t_end``, by default the
verify ``time_horizon``) is a sample like the others: the law is evaluated there, so a state
outside the law's domain at ``t = T`` is an ``"undefined"`` violation, and the input of the
new period, ``u(T)``, is checked against the input bounds.

Two simulators:

* :func:`simulate` -- one trajectory, adaptive DOP853 (``scipy.integrate.solve_ivp``) per
  sample period at tight tolerances (default ``rtol=1e-10``, ``atol=1e-12``), output on a
  grid. The reference.
* :func:`simulate_many` -- many trajectories at once, vectorised fixed-step classical RK4
  whose step divides the sample time (so sample times are grid points and the integrand
  is smooth inside each step for smooth dynamics). Global error ``O(h^4)`` per unit time
  (with the default ``h = step / 10 = 1e-3`` s: ~1e-12 times the size of the fourth
  derivatives of the closed-loop trajectories; measured: agreement with :func:`simulate`
  to ~1e-12 on every example, both holds, with the defaults). Dynamics with ``abs``,
  ``sign``, ``min`` or ``max`` are only piecewise smooth: there the order drops (still
  convergent).

Property checks (:func:`first_violation`, :func:`violations_many`) are evaluated on the
output grid points (plus, at each sample time, the *left limit* of the input of the period
that ends there, where a ``"continuous"`` hold input is furthest from its region). They are
checks of simulated trajectories -- a falsification tool and a test oracle, not a proof:
a violation strictly between two grid points can be missed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.law import ExplicitLaw
from codev_engine.plant import plant_model
from codev_engine.spec.choices import HOLDS
from codev_engine.spec.problem import Problem, VerifySpec

__all__ = [
    "DisturbanceSignal",
    "Trace",
    "Violation",
    "ManyTraces",
    "simulate",
    "simulate_many",
    "first_violation",
    "violations_many",
    "INPUT_TOL",
]

#: Relative tolerance of the input-bound check: ``u > u_max + INPUT_TOL * (1 + |u_max|)``
#: is a violation. The law's ``F``, ``G`` come from a numerical mp solver, so a saturated
#: input is ``u_max`` only up to round-off; set membership of states is checked exactly.
INPUT_TOL = 1e-9

_TIME_EPS = 1e-9  # relative (to the sample time) tolerance when matching times


# ---------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Trace:
    """One simulated closed-loop trajectory on an output grid.

    Attributes
    ----------
    t : (K,) ndarray
        Increasing times, from 0; every sample time ``k * Ts <= t_end`` is one of them,
        and so is the last time (``t_end``, or ``undefined_at``).
    x : (K, n) ndarray
        The state at each time.
    u : (K, m) ndarray
        The input in force at each time; at a sample time, the input of the period that
        starts there. NaN at the final entry of an undefined trajectory.
    region : (K,) ndarray of int
        The law's region in force at each time (at a sample time: the new period's);
        -1 at the final entry of an undefined trajectory.
    x0 : (n,) ndarray
        The initial state.
    hold : str
        ``"zoh"`` or ``"continuous"``.
    undefined_at : float or None
        The sample time at which ``law.locate`` returned -1 (the trace ends there), or
        None if the law was defined at every sample time.
    noise : (K, n) ndarray or None
        With measurement noise: the noise the law saw in the period of each entry (at a
        sample time, the new period's); None without noise.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    region: np.ndarray
    x0: np.ndarray
    hold: str
    undefined_at: float | None = None
    noise: np.ndarray | None = None


@dataclass(frozen=True)
class Violation:
    """The first violated property of a trajectory.

    Attributes
    ----------
    kind : str
        ``"unsafe"`` (entered ``verify.unsafe[index]``), ``"safe"`` (left
        ``verify.safe[index]``), ``"input_bounds"`` (input ``index`` outside
        ``[u_min, u_max]``) or ``"undefined"`` (the state is outside the law's domain at a
        sample time; ``index`` is -1).
    index : int
    t : float
        The (grid) time of the violation.
    x : (n,) ndarray
        The state at that time.
    """

    kind: str
    index: int
    t: float
    x: np.ndarray


@dataclass(frozen=True)
class DisturbanceSignal:
    """A concrete disturbance signal and parameter values: what a counterexample replays.

    ``w(t) = values[min(floor(t / piece), K - 1)]``: piecewise constant on pieces of
    length ``piece`` from ``t = 0`` (the last value held after the end).

    Attributes
    ----------
    piece : float
        Length of each piece (s), > 0.
    values : (K, d) ndarray
        The disturbance on each piece (``d`` = the plant's disturbances; may be 0).
    parameters : (q,) ndarray
        The uncertain parameters' values, fixed over the run (``q`` may be 0).
    noise : (S, n) ndarray or None
        Measurement noise: the law sees ``x(t_k) + noise[min(k, S - 1)]`` at sample ``k``;
        None: no noise.
    """

    piece: float
    values: np.ndarray
    parameters: np.ndarray
    noise: np.ndarray | None = None

    def noise_at(self, k: int) -> np.ndarray | None:
        """The measurement noise (n,) at sample ``k``, or None without noise.

        Parameters
        ----------
        k : int

        Returns
        -------
        (n,) ndarray or None
        """
        if self.noise is None:
            return None
        return self.noise[min(max(k, 0), self.noise.shape[0] - 1)]

    def index(self, t: float) -> int:
        """The piece in force at time ``t`` (s).

        Parameters
        ----------
        t : float

        Returns
        -------
        int
        """
        return int(min(max(math.floor(t / self.piece + 1e-12), 0), self.values.shape[0] - 1))

    def at(self, t: float) -> np.ndarray:
        """The disturbance (d,) in force at time ``t`` (s).

        Parameters
        ----------
        t : float

        Returns
        -------
        (d,) ndarray
        """
        return self.values[self.index(t)]


def nominal_signal(problem: Problem) -> DisturbanceSignal:
    """The nominal values as a (constant) signal.

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    DisturbanceSignal
    """
    pl = problem.plant
    w = np.asarray(pl.disturbances.nominal, float) if pl.disturbances else np.zeros(0)
    q = np.asarray(pl.parameters.nominal, float) if pl.parameters else np.zeros(0)
    return DisturbanceSignal(float(problem.model.sample_time), w[None, :], q)


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------


#: sample times simulated and shown for a spec verified for all time (time_horizon = "inf")
SHOWN_SAMPLES = 50


def shown_horizon(problem: Problem) -> float:
    """The time simulations and figures cover by default: ``verify.time_horizon``, or for
    a spec verified for all time (``"inf"``) ``min(max_samples, 50)`` sample times.

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.

    Returns
    -------
    float
        A finite time (s).
    """
    vs = problem.verify
    if math.isfinite(vs.time_horizon):
        return float(vs.time_horizon)
    return min(vs.max_samples, SHOWN_SAMPLES) * float(problem.model.sample_time)


def _settings(problem: Problem, hold, t_end, dt, dt_factor: float) -> tuple[str, float, float]:
    v = problem.verify
    hold = hold if hold is not None else (v.hold if v is not None else "zoh")
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    if t_end is None:
        if v is None:
            raise ValueError("the problem has no [verify] section: give t_end")
        t_end = shown_horizon(problem)
    t_end = float(t_end)
    if not (math.isfinite(t_end) and t_end >= 0.0):
        raise ValueError(f"t_end must be finite and >= 0, got {t_end}")
    if dt is None:
        dt = (v.step if v is not None else 0.01) / dt_factor
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be finite and > 0, got {dt}")
    return hold, t_end, dt


def _check_law(problem: Problem, law: ExplicitLaw) -> None:
    n, m = problem.plant.n, problem.plant.m
    d = n + extra_length(problem)
    if law.num_regions and (law.n != d or law.m != m):
        raise ValueError(f"the law is for n={law.n}, m={law.m}, the problem has n={d}, m={m}")


def extra_length(problem: Problem) -> int:
    """The length of the law's parameters after the state (``u_prev``, then ``r``).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    int
    """
    mpc = problem.mpc
    k = problem.plant.m if mpc.has_rates else 0
    if mpc.free_reference:
        assert mpc.reference is not None and mpc.reference.lower is not None
        k += int(mpc.reference.lower.shape[0])
    return k


def theta_initial_box(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The box of the closed loop's initial ``theta = (x_0, u_prev_0, r)``.

    ``x_0`` in ``verify.initial_set``; ``u_prev_0`` (with input rates) in
    ``verify.initial_input`` (default: the operating input); ``r`` (a free reference) in
    ``verify.reference`` (default: the whole box of ``mpc.reference``).

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.

    Returns
    -------
    lo, hi : (d,) ndarray
    """
    vs = problem.verify
    assert vs is not None
    mpc = problem.mpc
    lo, hi = [vs.initial_lower], [vs.initial_upper]
    if mpc.has_rates:
        if vs.initial_input_lower is not None:
            lo.append(vs.initial_input_lower)
            hi.append(vs.initial_input_upper)
        else:
            u_op = np.asarray(problem.model.u_op, dtype=float)
            u_op = u_op if u_op.size else np.zeros(problem.plant.m)
            lo.append(u_op)
            hi.append(u_op)
    if mpc.free_reference:
        ref = mpc.reference
        assert ref is not None
        if vs.reference_lower is not None:
            lo.append(vs.reference_lower)
            hi.append(vs.reference_upper)
        else:
            lo.append(ref.lower)
            hi.append(ref.upper)
    return (np.concatenate(lo).astype(float), np.concatenate(hi).astype(float))


def _affine(law: ExplicitLaw, region: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``F_r x + G_r`` row-wise: region (P,), X (P, n) -> (P, m)."""
    return np.einsum("pij,pj->pi", law.F[region], X) + law.G[region]


def _dynamics(problem: Problem):
    """``(f_point, f_batch)``: the plant's vector field for one point and for a batch.

    ``f_point(x (n,), u (m,)) -> (n,)``, ``f_batch(X (P, n), U (P, m)) -> (P, n)``, compiled
    once per plant (``PlantModel.vector_field``): the same vector field as
    ``numeric_dynamics(problem).f``, without its general broadcasting wrapper.
    """
    return plant_model(problem).vector_field


def _halfspaces(verify: VerifySpec | None):
    if verify is None:
        return [], []
    unsafe = [tuple(np.asarray(a, float) for a in s.halfspaces()) for s in verify.unsafe]
    safe = [tuple(np.asarray(a, float) for a in s.halfspaces()) for s in verify.safe]
    return unsafe, safe


def _state_flags(verify: VerifySpec | None, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per point: in unsafe set j (..., n_unsafe), outside safe set j (..., n_safe).

    Closed sets, exact comparisons: ``A x <= b`` on every row is inside an unsafe set
    (a set with no finite side is the whole space); ``A x > b`` on some row is outside a
    safe set. NaN states flag nothing.
    """
    unsafe, safe = _halfspaces(verify)
    lead = X.shape[:-1]
    inside_unsafe = np.zeros((*lead, len(unsafe)), dtype=bool)
    outside_safe = np.zeros((*lead, len(safe)), dtype=bool)
    finite = np.all(np.isfinite(X), axis=-1)
    X2 = X.reshape(-1, X.shape[-1])  # (one 2-d product: a batched one is much slower)
    for j, (A, b) in enumerate(unsafe):
        inside_unsafe[..., j] = finite & np.all(X2 @ A.T <= b, axis=-1).reshape(lead)
    for j, (A, b) in enumerate(safe):
        outside_safe[..., j] = np.any(X2 @ A.T > b, axis=-1).reshape(lead)
    return inside_unsafe, outside_safe


def _input_flags(problem: Problem, U: np.ndarray) -> np.ndarray:
    """Per point and input: outside ``[u_min, u_max]`` (..., m); False if no input bounds."""
    v = problem.verify
    if v is None or not v.input_bounds:
        return np.zeros(U.shape, dtype=bool)
    lo = np.asarray(problem.mpc.u_min, dtype=float)
    hi = np.asarray(problem.mpc.u_max, dtype=float)
    with np.errstate(invalid="ignore"):
        return (U > hi + INPUT_TOL * (1.0 + np.abs(hi))) | (U < lo - INPUT_TOL * (1.0 + np.abs(lo)))


# ---------------------------------------------------------------------------------------
# one trajectory: adaptive DOP853
# ---------------------------------------------------------------------------------------


def _period_rhs(f, hold: str, F: np.ndarray, G: np.ndarray, u: np.ndarray):
    """The right-hand side ``(t, x) -> dx/dt`` of one sample period."""
    if hold == "zoh":
        return lambda _t, y: f(y, u)
    return lambda _t, y: f(y, F @ y + G)


def simulate(
    problem: Problem,
    law: ExplicitLaw,
    x0,
    *,
    hold: str | None = None,
    t_end: float | None = None,
    dt: float | None = None,
    method: str = "auto",
    rtol: float = 1e-10,
    atol: float = 1e-12,
    extra0=None,
    disturbance: DisturbanceSignal | None = None,
) -> Trace:
    """Simulate the sampled closed loop from ``x0`` (see the module docstring).

    Each sample period is integrated separately with ``scipy.integrate.solve_ivp``
    (``max_step = dt``), evaluated on the output grid ``j * dt`` plus both period ends.

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
        The explicit law of ``problem`` (plant coordinates).
    x0 : (n,) array_like
    hold : {"zoh", "continuous"}, optional
        Default ``problem.verify.hold`` (``"zoh"`` without a verify section).
    t_end : float, optional
        Default ``problem.verify.time_horizon``.
    dt : float, optional
        Output grid step; default ``problem.verify.step / 4``.
    method : str
        ``solve_ivp`` method; ``"auto"`` is ``"DOP853"``.
    rtol, atol : float
        ``solve_ivp`` tolerances.
    extra0 : (d - n,) array_like, optional
        For a law over ``theta = (x, u_prev, r)``: the initial ``(u_prev, r)``; default
        the centre of :func:`theta_initial_box` after the state. ``u_prev`` then follows
        the applied input, ``r`` stays constant.
    disturbance : DisturbanceSignal, optional
        The plant's disturbance signal and parameter values; default: the nominal values
        (the design model). Each period is integrated piece by piece, so the signal's
        jumps are integration end points. Its ``noise``, if any, is added to the state the
        law sees at each sample (region and input: ``u = F_i (x + v_k) + G_i``).

    Returns
    -------
    Trace

    Raises
    ------
    SolverError
        If the integrator fails inside a period (e.g. finite escape time).
    """
    from scipy.integrate import solve_ivp  # (~1 s of imports: when a trace is computed)

    hold, t_end, dt = _settings(problem, hold, t_end, dt, 4.0)
    _check_law(problem, law)
    n, m = problem.plant.n, problem.plant.m
    x = np.asarray(x0, dtype=float).reshape(-1)
    if x.shape != (n,):
        raise ValueError(f"x0 must have {n} entries, got {x.size}")
    x0 = x.copy()
    x0.setflags(write=False)
    extra = _extra0(problem, extra0, 1)[0]
    rates = problem.mpc.has_rates
    f = _dynamics(problem)[0]
    Ts = float(problem.model.sample_time)
    eps = _TIME_EPS * Ts
    solver = "DOP853" if method == "auto" else method

    ts: list[float] = []
    xs: list[np.ndarray] = []
    us: list[np.ndarray] = []
    rs: list[int] = []
    vs: list[np.ndarray] = []  # the noise in force at each entry
    undefined_at = None
    k = 0
    noisy = disturbance is not None and disturbance.noise is not None
    if disturbance is not None and not problem.plant.uncertain:
        disturbance = replace(disturbance, values=np.zeros((1, 0)))
    while True:
        a = k * Ts
        vk = disturbance.noise_at(k) if noisy else np.zeros(n)
        theta = np.concatenate([x + vk, extra])
        i = int(law.locate(theta[None, :])[0])
        if i < 0:
            ts.append(a)
            xs.append(x.copy())
            us.append(np.full(m, np.nan))
            rs.append(-1)
            vs.append(vk)
            undefined_at = a
            break
        # the law in the state during this period: (u_prev, r) are fixed at the sample
        Fi = law.F[i][:, :n]
        Gi = law.G[i] + law.F[i][:, n:] @ extra + Fi @ vk  # the measured state x + v_k
        ua = Fi @ x + Gi
        if rates:
            extra[:m] = ua  # the next sample's previous input
        ts.append(a)
        xs.append(x.copy())
        us.append(ua)
        rs.append(i)
        vs.append(vk)
        if a >= t_end - eps:
            break
        b_sample = (k + 1) * Ts
        last = b_sample > t_end + eps  # the horizon ends inside this period
        b = t_end if last else b_sample
        j0 = math.floor(a / dt + 1e-9) + 1
        j1 = math.ceil(b / dt - 1e-9) - 1
        grid = np.arange(j0, j1 + 1) * dt
        grid = grid[(grid > a + eps) & (grid < b - eps)]
        t_eval = np.concatenate([[a], grid, [b]])

        if disturbance is None or disturbance.values.shape[1] == 0 and (
            disturbance.parameters.size == 0
        ):
            sol = solve_ivp(
                _period_rhs(f, hold, Fi, Gi, ua),
                (a, b),
                x,
                method=solver,
                t_eval=t_eval,
                rtol=rtol,
                atol=atol,
                max_step=dt,
            )
            if sol.status < 0 or sol.y.shape[1] != t_eval.size:
                raise SolverError(
                    f"closed-loop integration failed on [{a:g}, {b:g}] s: {sol.message}"
                )
            Y = sol.y.T  # (len(t_eval), n)
        else:
            Y = _pieces(problem, disturbance, hold, Fi, Gi, ua, x, t_eval,
                        dict(method=solver, rtol=rtol, atol=atol, max_step=dt))
        for tj, yj in zip(t_eval[1:-1], Y[1:-1], strict=True):
            ts.append(float(tj))
            xs.append(yj.copy())
            us.append(ua if hold == "zoh" else Fi @ yj + Gi)
            rs.append(i)
            vs.append(vk)
        x = Y[-1].copy()
        if not np.all(np.isfinite(x)):
            raise SolverError(f"closed-loop state not finite at t = {b:g} s")
        if last:
            ts.append(b)
            xs.append(x.copy())
            us.append(ua if hold == "zoh" else Fi @ x + Gi)
            rs.append(i)
            vs.append(vk)
            break
        k += 1

    def frozen(arr, shape, dtype=float):
        out = np.array(arr, dtype=dtype).reshape(shape)
        out.setflags(write=False)
        return out

    K = len(ts)
    return Trace(
        t=frozen(ts, (K,)),
        x=frozen(xs, (K, n)),
        u=frozen(us, (K, m)),
        region=frozen(rs, (K,), int),
        x0=x0,
        hold=hold,
        undefined_at=undefined_at,
        noise=frozen(vs, (K, n)) if noisy else None,
    )


def _pieces(problem, sig, hold, Fi, Gi, ua, x, t_eval, opts) -> np.ndarray:
    """One period under a disturbance signal, integrated piece by piece: (len(t_eval), n)."""
    from scipy.integrate import solve_ivp

    fu = plant_model(problem).uncertain_point
    q = np.asarray(sig.parameters, float)
    a, b = float(t_eval[0]), float(t_eval[-1])
    cuts = [a]
    k = sig.index(a) + 1
    while k * sig.piece < b - _TIME_EPS * sig.piece and k < sig.values.shape[0]:
        # a cut where the value changes (equal neighbouring pieces are one piece of the
        # same signal: fewer, longer integrations)
        if k * sig.piece > a + _TIME_EPS * sig.piece and np.any(
            sig.values[k] != sig.values[k - 1]
        ):
            cuts.append(k * sig.piece)
        k += 1
    cuts.append(b)
    Y = np.empty((t_eval.size, x.size))
    Y[0] = x
    y = x
    for c0, c1 in zip(cuts[:-1], cuts[1:], strict=True):
        w = np.asarray(sig.at(0.5 * (c0 + c1)), float)
        if hold == "zoh":
            def rhs(_t, z, w=w):
                return fu(z, ua, w, q)
        else:
            def rhs(_t, z, w=w):
                return fu(z, Fi @ z + Gi, w, q)
        inside = (t_eval > c0) & (t_eval <= c1)
        te = np.concatenate([[c0], t_eval[inside & (t_eval < c1)], [c1]])
        sol = solve_ivp(rhs, (c0, c1), y, t_eval=te, **opts)
        if sol.status < 0 or sol.y.shape[1] != te.size:
            raise SolverError(f"closed-loop integration failed on [{c0:g}, {c1:g}] s: "
                              f"{sol.message}")
        Yp = sol.y.T
        Y[np.flatnonzero(inside & (t_eval < c1))] = Yp[1:-1]
        y = Yp[-1]
        Y[np.flatnonzero(t_eval == c1)] = y
    return Y


# ---------------------------------------------------------------------------------------
# many trajectories: vectorised RK4
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ManyTraces:
    """Result of :func:`simulate_many`; unpacks as ``t, X, U, alive = simulate_many(...)``.

    Attributes
    ----------
    t : (K,) ndarray
        Non-decreasing output times. Each sample time ``t_k > 0`` (up to ``t_end``)
        appears **twice**: first as the end of the period ``[t_{k-1}, t_k]`` (``U`` is that
        period's input at ``x(t_k)``, its left limit), then as the start of the new period
        (``U`` is the new input). So every input the trajectory takes is checked.
    X : (P, K, n) ndarray
        States; NaN after the trajectory stopped (the state at the stopping time itself is
        kept).
    U : (P, K, m) ndarray
        Inputs in force; NaN where not alive.
    alive : (P, K) bool ndarray
        The law is defined (at the last sample time at or before ``t``). Once False, False
        until the end; False at the start-of-period entry of the sample time where
        ``law.locate`` returned -1.
    h : float
        The RK4 step actually used (``Ts / ceil(Ts / dt)``).
    noise : (P, S, n) ndarray or None
        The measurement noise the law saw at each of the ``S`` sample times (0 where not
        alive); None when simulated without noise.
    """

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    alive: np.ndarray
    h: float
    noise: np.ndarray | None = None

    def __iter__(self):
        return iter((self.t, self.X, self.U, self.alive))


def simulate_many(
    problem: Problem,
    law: ExplicitLaw,
    X0,
    *,
    hold: str | None = None,
    t_end: float | None = None,
    dt: float | None = None,
    dt_out: float | None = None,
    extra0=None,
    disturbance: tuple[float, np.ndarray, np.ndarray] | None = None,
    noise=None,
    affine=None,
) -> ManyTraces:
    """Simulate many closed-loop trajectories at once with vectorised fixed-step RK4.

    Same semantics as :func:`simulate`. The RK4 step is ``h = Ts / ceil(Ts / dt)`` (it
    divides the sample time, so every sample time is a grid point; a last partial step
    reaches ``t_end`` if it is not on the grid). RK4's global error is ``O(h^4)``; with the
    default ``h`` about ``1e-3`` s it agrees with :func:`simulate` to ~1e-12 on the
    examples.

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
    X0 : (P, n) array_like
        Initial states.
    hold, t_end : optional
        As in :func:`simulate`.
    dt : float, optional
        Requested RK4 step (an upper bound); default ``problem.verify.step / 10``.
    dt_out : float, optional
        Output spacing, rounded to a multiple of ``h`` (memory is ``P * K * (n + m)``
        floats); default ``problem.verify.step / 4``. Pass ``dt_out=dt`` to keep every
        step. Sample times and ``t_end`` are always output.
    extra0 : (P, d - n) array_like, optional
        As in :func:`simulate`, one row per trajectory.
    disturbance : (piece, W, Q), optional
        Disturbance signals and parameter values, one per trajectory: ``W`` (P, K, d) the
        values on pieces of length ``piece`` (as :class:`DisturbanceSignal`), ``Q`` (P, q)
        the parameters; each RK4 step takes the piece in force at its start. Default: the
        nominal values.
    noise : (P, S, n) ndarray or callable, optional
        Measurement noise: at sample ``k`` the law of trajectory ``p`` sees
        ``x + noise[p, min(k, S - 1)]``. A callable ``noise(k, X (q, n), idx (q,)) -> (q, n)``
        chooses it from the states of the trajectories ``idx`` still alive (a feedback
        adversary); the values used are returned in ``ManyTraces.noise``. Default: none.
    affine : AffinePlant, optional
        The plant as an affine ODE (``reach.linear.affine_plant(problem)``, without uncertain
        parameters): each step is then the exact flow of the step's linear ODE (a matrix
        exponential per region and step length, cached) instead of RK4, so a coarse ``dt``
        loses no accuracy (the concrete searches use it; every violation they find is
        replayed by :func:`simulate`). The rest (records, regions, noise) is unchanged.

    Returns
    -------
    ManyTraces
        Unpacks as ``(t (K,), X (P, K, n), U (P, K, m), alive (P, K))``.
    """
    hold, t_end, dt = _settings(problem, hold, t_end, dt, 10.0)
    _check_law(problem, law)
    v = problem.verify
    if dt_out is None:
        dt_out = (v.step if v is not None else 0.01) / 4.0
    n, m = problem.plant.n, problem.plant.m
    X0 = np.atleast_2d(np.asarray(X0, dtype=float))
    if X0.ndim != 2 or X0.shape[1] != n:
        raise ValueError(f"X0 must have shape (P, {n}), got {X0.shape}")
    P = X0.shape[0]
    extra = _extra0(problem, extra0, P)
    rates = problem.mpc.has_rates
    f = _dynamics(problem)[1]
    Ts = float(problem.model.sample_time)
    S = max(1, math.ceil(Ts / dt - 1e-9))  # RK4 steps per period
    h = Ts / S
    stride = max(1, round(float(dt_out) / h))
    eps = _TIME_EPS * Ts
    # the steps: J full steps of h, plus maybe a partial one up to t_end
    J = math.floor(t_end / h + 1e-9)
    partial = t_end - J * h > eps

    def time(j: int) -> float:
        return (j // S) * Ts + (j % S) * h

    ts: list[float] = []
    Xs: list[np.ndarray] = []
    Us: list[np.ndarray] = []
    As: list[np.ndarray] = []

    def record(tj, x, u, alive):
        ts.append(tj)
        Xs.append(x.copy())
        Us.append(np.where(alive[:, None], u, np.nan))
        As.append(alive.copy())

    x = X0.copy()
    alive = np.ones(P, dtype=bool)
    region = np.zeros(P, dtype=int)
    Fi = np.zeros((P, m, n))
    Gi = np.zeros((P, m))
    u = np.full((P, m), np.nan)
    dead_state = np.zeros(P, dtype=bool)  # stopped before the current time: state NaN

    def u_of(xx, idx):
        if hold == "zoh":
            return u[idx]
        return np.einsum("pij,pj->pi", Fi[idx], xx) + Gi[idx]

    used: list[np.ndarray] = []  # the noise of each sample

    def at_sample(tj: float):
        nonlocal x, u
        if tj > 0:
            # the left limit: the ending period's input at x(t_k)
            uleft = u.copy()
            if hold == "continuous":
                idx = np.flatnonzero(alive)
                uleft[idx] = u_of(x[idx], idx)
            record(tj, x, uleft, alive)
        idx = np.flatnonzero(alive)
        v = np.zeros((P, n))
        if noise is not None:
            ks = len(used)
            if callable(noise):
                v[idx] = noise(ks, x[idx].copy(), idx)
            else:
                v[idx] = noise[idx, min(ks, noise.shape[1] - 1)]
            used.append(v)
        theta = np.hstack([x[idx] + v[idx], extra[idx]])
        reg = law.locate(theta) if idx.size else np.zeros(0, dtype=int)
        dead = idx[reg < 0]
        alive[dead] = False
        ok = idx[reg >= 0]
        region[ok] = reg[reg >= 0]
        Fr = law.F[region[ok]]
        Fi[ok] = Fr[:, :, :n]
        Gi[ok] = (law.G[region[ok]] + np.einsum("pij,pj->pi", Fr[:, :, n:], extra[ok])
                  + np.einsum("pij,pj->pi", Fi[ok], v[ok]))  # the law sees x + v
        u[ok] = np.einsum("pij,pj->pi", Fi[ok], x[ok]) + Gi[ok]
        if rates:
            extra[ok, :m] = u[ok]
        u[dead] = np.nan
        record(tj, x, u, alive)

    fu = (plant_model(problem).uncertain
          if disturbance is not None and affine is None else None)
    t_now = 0.0
    if affine is not None and problem.plant.parameters is not None:
        affine = None  # (uncertain parameters: the RK4 steps take their values)
    flows = _ExactFlows(affine, law, hold, n, m) if affine is not None else None
    if flows is not None and problem.plant.disturbances is not None:
        flows.set_centre(problem.plant.disturbances.centre)
        # without signals: the nominal values (the design model), as the RK4 steps take them
        flows.nominal = (np.asarray(problem.plant.disturbances.nominal, float)
                         - flows.wc)

    def step(hh: float):
        nonlocal x
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            return
        y = x[idx]

        if flows is not None:
            # z = (x, g, delta, 1): g the held input (zoh) or the affine law's offset
            # (continuous), delta the disturbance's deviation from its box's centre
            g = u[idx] if hold == "zoh" else Gi[idx]
            if disturbance is not None and flows.d:
                piece, Wd, _ = disturbance
                kw = min(max(math.floor(t_now / piece + 1e-9), 0), Wd.shape[1] - 1)
                delta = Wd[idx, kw] - flows.wc
            else:
                delta = np.broadcast_to(flows.nominal, (idx.size, flows.d))
            z = np.hstack([y, g, delta, np.ones((idx.size, 1))])
            x[idx] = flows.step(hh, region[idx], z)
            return

        if disturbance is None:
            def rhs(z):
                return f(z, u_of(z, idx))
        else:
            piece, Wd, Qd = disturbance
            kw = min(max(math.floor(t_now / piece + 1e-9), 0), Wd.shape[1] - 1)
            wz, qz = Wd[idx, kw], Qd[idx]

            def rhs(z):
                return fu(z, u_of(z, idx), wz, qz)

        k1 = rhs(y)
        k2 = rhs(y + 0.5 * hh * k1)
        k3 = rhs(y + 0.5 * hh * k2)
        k4 = rhs(y + hh * k3)
        x[idx] = y + (hh / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    for j in range(J + 1):
        tj = time(j)
        # states of trajectories that stopped at an earlier sample are NaN from now on
        x[dead_state] = np.nan
        if j % S == 0:
            at_sample(tj)
        elif j % stride == 0 or (j == J and not partial):
            if hold == "continuous":
                idx = np.flatnonzero(alive)
                uj = u.copy()
                uj[idx] = u_of(x[idx], idx)
            else:
                uj = u
            record(tj, x, uj, alive)
        dead_state |= ~alive
        if j == J:
            break
        t_now = tj
        step(h)
        if not np.all(np.isfinite(x[alive])):
            raise SolverError(f"closed-loop state not finite near t = {time(j + 1):g} s")
    if partial:
        x[dead_state] = np.nan
        t_now = J * h
        step(t_end - J * h)
        uj = u.copy()
        if hold == "continuous":
            idx = np.flatnonzero(alive)
            uj[idx] = u_of(x[idx], idx)
        record(t_end, x, uj, alive)

    t = np.array(ts)
    X = np.stack(Xs, axis=1)
    U = np.stack(Us, axis=1)
    A = np.stack(As, axis=1)
    N = np.stack(used, axis=1) if used else None
    return ManyTraces(t=t, X=X, U=U, alive=A, h=h, noise=N)


class _ExactFlows:
    """The exact flow of an affine plant over one step, per region (continuous hold) or
    one for all (zoh): ``x(t + h) = T_r (x, g, delta, 1)`` with ``T_r`` the top rows of
    ``expm(M_r h)``, ``M_r = [[Ac + Bc F_r, Bc, E, f0], 0]`` (continuous; ``g = G_r`` and
    the law's other parts) or ``[[Ac, Bc, E, f0], 0]`` (zoh; ``g`` the held input)."""

    def __init__(self, ap, law: ExplicitLaw, hold: str, n: int, m: int) -> None:
        self.ap, self.law, self.hold, self.n, self.m = ap, law, hold, n, m
        self.E = (np.zeros((n, 0)) if ap.E is None else np.asarray(ap.E, float))
        self.d = self.E.shape[1]
        self.wc = np.zeros(self.d)
        self.nominal = np.zeros(self.d)  # the nominal disturbance's deviation from wc
        self.cache: dict[float, np.ndarray] = {}
        self.have: dict[float, np.ndarray] = {}

    def set_centre(self, wc: np.ndarray) -> None:
        """The disturbance box's centre (``delta = w - wc``).

        Parameters
        ----------
        wc : (d,) ndarray
        """
        self.wc = np.asarray(wc, float)

    def _matrix(self, h: float, r: int) -> np.ndarray:
        from scipy.linalg import expm

        n, m, d = self.n, self.m, self.d
        ap = self.ap
        M = np.zeros((n + m + d + 1, n + m + d + 1))
        A = np.asarray(ap.Ac, float)
        if self.hold == "continuous" and self.law.num_regions:
            A = A + np.asarray(ap.Bc, float) @ self.law.F[r][:, :n]
        M[:n, :n] = A
        M[:n, n : n + m] = ap.Bc
        M[:n, n + m : n + m + d] = self.E
        M[:n, -1] = ap.f0
        return expm(M * h)[:n]

    def step(self, h: float, regions: np.ndarray, z: np.ndarray) -> np.ndarray:
        """The states after a step of length ``h``.

        Parameters
        ----------
        h : float
        regions : (p,) int ndarray
            Each trajectory's region (continuous hold).
        z : (p, n + m + d + 1) ndarray

        Returns
        -------
        (p, n) ndarray
        """
        per_region = self.hold == "continuous" and self.law.num_regions
        R = max(self.law.num_regions, 1) if per_region else 1
        key = float(h)
        if key not in self.cache:
            self.cache[key] = np.zeros((R, self.n, z.shape[1]))
            self.have[key] = np.zeros(R, dtype=bool)
        T, have = self.cache[key], self.have[key]
        if not per_region:
            if not have[0]:
                T[0], have[0] = self._matrix(h, 0), True
            return z @ T[0].T
        if regions.size and int(regions.max()) >= T.shape[0]:
            # (a law on demand computed regions since the cache was sized)
            grow = int(regions.max()) + 1 - T.shape[0]
            T = self.cache[key] = np.concatenate([T, np.zeros((grow,) + T.shape[1:])])
            have = self.have[key] = np.concatenate([have, np.zeros(grow, dtype=bool)])
        need = np.unique(regions[~have[regions]])
        for r in need:
            T[r], have[r] = self._matrix(h, int(r)), True
        return np.einsum("pij,pj->pi", T[regions], z)


# ---------------------------------------------------------------------------------------
# property checks
# ---------------------------------------------------------------------------------------


def first_violation(problem: Problem, law: ExplicitLaw, trace: Trace) -> Violation | None:
    """The first violated property along a simulated trajectory, or None.

    Checked at every point of ``trace`` (the whole trace, whatever its length): the state
    against ``verify.unsafe`` and ``verify.safe`` (closed sets, exact comparisons), the
    input against ``[u_min, u_max]`` if ``verify.input_bounds`` (relative tolerance
    ``INPUT_TOL``) -- including, at each sample time, the left limit of the ending period's
    input (``F_i x(t_k) + G_i`` with the old region, for the ``"continuous"`` hold) -- and
    the law being defined (``trace.undefined_at``). At equal times the order is unsafe,
    safe, input_bounds, undefined.

    Parameters
    ----------
    problem : Problem
        Its ``[verify]`` section gives the properties.
    law : ExplicitLaw
        The law the trace was simulated with (for the left limits of the input).
    trace : Trace
        From :func:`simulate`.

    Returns
    -------
    Violation or None
    """
    t, X, U, R = trace.t, trace.x, trace.u, trace.region
    K = t.size
    inside_unsafe, outside_safe = _state_flags(problem.verify, X)
    bad_u = _input_flags(problem, U)
    # left limits at each entry j >= 1 (redundant except at sample times)
    U_left = np.full_like(U, np.nan)
    if K > 1:
        prev = R[:-1]
        ok = np.flatnonzero(prev >= 0) + 1
        if trace.hold == "zoh":
            U_left[ok] = U[ok - 1]
        else:
            # (the law saw x + v: the ending period's noise, with measurement noise)
            seen = X[ok] if trace.noise is None else X[ok] + trace.noise[ok - 1]
            U_left[ok] = _affine(law, R[ok - 1], seen)
    bad_left = _input_flags(problem, U_left)
    undefined = R < 0

    candidates = []  # (entry, priority, kind, index)
    for kind, prio, flags in (
        ("unsafe", 0, inside_unsafe),
        ("safe", 1, outside_safe),
        ("input_bounds", 2, bad_left),
        ("input_bounds", 3, bad_u),
    ):
        hits = np.argwhere(flags)
        if hits.size:
            j, idx = hits[0]
            candidates.append((int(j), prio, kind, int(idx)))
    if np.any(undefined):
        candidates.append((int(np.argmax(undefined)), 4, "undefined", -1))
    if not candidates:
        return None
    j, _, kind, idx = min(candidates)
    return Violation(kind=kind, index=idx, t=float(t[j]), x=np.array(X[j]))


def violations_many(problem: Problem, t, X, U, alive) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised property check of :func:`simulate_many` output.

    Parameters
    ----------
    problem : Problem
    t : (K,) ndarray
    X : (P, K, n) ndarray
    U : (P, K, m) ndarray
    alive : (P, K) bool ndarray

    Returns
    -------
    violated : (P,) bool ndarray
        Some property fails at some output point: a state in an unsafe set or outside a
        safe set (checked while alive and at the point where the trajectory stopped), an
        input out of bounds (if ``verify.input_bounds``; while alive), or the trajectory
        stopped (law undefined) at or before ``t[-1]``.
    t_first : (P,) ndarray
        The first such time; ``inf`` where nothing is violated.
    """
    t = np.asarray(t, dtype=float)
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float)
    alive = np.asarray(alive, dtype=bool)
    P, K = alive.shape
    # the state is meaningful while alive and at the first not-alive entry
    state_ok = alive.copy()
    state_ok[:, 0] = True
    state_ok[:, 1:] |= alive[:, :-1]
    inside_unsafe, outside_safe = _state_flags(problem.verify, X)
    bad = (inside_unsafe.any(-1) | outside_safe.any(-1)) & state_ok
    bad |= _input_flags(problem, U).any(-1) & alive
    bad |= ~alive  # undefined (the first not-alive entry is the stopping time)
    violated = bad.any(axis=1)
    t_first = np.where(violated, t[np.argmax(bad, axis=1)], np.inf)
    return violated, t_first


def _extra0(problem: Problem, extra0, P: int) -> np.ndarray:
    """(P, d - n) initial (u_prev, r): as given, or the centre of their initial box."""
    k = extra_length(problem)
    if extra0 is None:
        if k == 0 or problem.verify is None:
            return np.zeros((P, k))
        lo, hi = theta_initial_box(problem)
        n = problem.plant.n
        return np.tile(0.5 * (lo[n:] + hi[n:]), (P, 1))
    E = np.array(extra0, dtype=float).reshape(P, k)
    return E
