"""Exact-flow reachability of an affine plant in closed loop with an explicit law.

Reach sets are *star sets* ``{c + V alpha : alpha in P}`` over the initial box's
coordinates ``alpha`` (``P`` starts as ``[-1, 1]^n``). Between samples the closed loop of
one region is an affine ODE, so the star at any time ``tau`` after the sample is the exact
affine image ``Phi(tau) (c + V alpha) + g(tau)`` (matrix exponentials). At a sample the
star is split exactly by the regions it meets: the child for region ``i`` adds the rows
``A_i (c + V alpha) <= b_i`` to ``P``. So the only over-approximation is between grid
points, where it is bounded as follows (the soundness argument, see docs/verification.md):

* Every trajectory is C^2 on a segment ``[tau_j, tau_j + h]`` and its second derivative
  obeys ``d/dt xdd = M xdd`` (``M = A`` for zoh, ``A + B F_i`` for continuous hold), so
  ``|xdd(tau_j + s)| <= expm(|M| h) |xdd(tau_j)|`` element-wise, and ``|xdd(tau_j)|`` is
  maximised at a vertex of the star (it is affine in ``alpha``).
* Linear interpolation error of a C^2 function on a segment of length ``h`` is at most
  ``h^2 / 8 max |xdd|`` per component; the interpolant lies in the hull of the boxes of the
  two end stars. Hence segment box = hull(end boxes) +- E_j.
* Floating point: stars carry an error bound ``err`` (n,) propagated as
  ``|Phi| err + 1e-12 (|Phi||c| + |Phi V| 1 + |g|)``: the matrix exponentials and the short
  products here are accurate to ~1e-15 relative, so 1e-12 is a wide margin.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from scipy.linalg import expm

from codev_engine.errors import RegionLimitError
from codev_engine.geometry.polytope import (
    normalize_rows,
    solve_lp,
)
from codev_engine.geometry.vertices import FACET_TOL, box_corners, checked_piece, vertices
from codev_engine.law import ExplicitLaw
from codev_engine.limits import DeadlineReached, beat, limits, stoppable, time_over_kind
from codev_engine.plant import disturbances_matter, symbolic_model
from codev_engine.reach.simulate import theta_initial_box
from codev_engine.reach.tube import Tube
from codev_engine.spec.problem import Problem

__all__ = ["AffinePlant", "affine_plant", "LinearReach", "Finding", "affine_range"]

_REL = 1e-12  # relative floating-point margin per propagated quantity

class ExplorationLimitError(Exception):
    """The exploration grew past ``codev_engine.limits`` (``branches``, ``tube_bytes``; the
    message says which, and what to change); ``t`` is the time reached; ``kind`` is
    ``"limit"``, or ``"budget"`` when the verification's time budget ran out."""

    def __init__(self, message: str, t: float, kind: str = "limit"):
        super().__init__(message)
        self.t = t
        self.kind = kind

    def __reduce__(self):  # (whole through pickle: a worker's exception reaches the client)
        return type(self), (str(self), self.t, self.kind)


@dataclass(frozen=True)
class AffinePlant:
    """``dx/dt = Ac x + Bc u + f0`` in plant coordinates.

    Attributes
    ----------
    Ac : (n, n) ndarray
    Bc : (n, m) ndarray
    f0 : (n,) ndarray
        The drift at ``x = 0, u = 0`` (with a disturbance: at its box's centre).
    E : (n, d) ndarray or None
        The disturbance input: ``dx/dt = Ac x + Bc u + f0 + E delta(t)``, ``delta(t)`` any
        measurable signal with ``|delta| <= w_radius`` (the box about its centre, which
        ``f0`` already holds); None without disturbances.
    w_radius : (d,) ndarray or None
        The half-widths of the disturbance box.
    dA, dB : (n, n), (n, m) ndarray or None
        With uncertain parameters ``p`` (the field affine in ``(x, u, w)`` for each ``p``,
        ``Ac``, ``Bc``, ``E``, ``f0`` at the nominal ``p``): element-wise bounds on
        ``|A(p) - Ac|``, ``|B(p) - Bc|`` over the parameter box (interval enclosures).
    dE : (n, d) ndarray or None
        Likewise ``|E(p) - E|`` (zeros without disturbances: shape (n, 0)).
    dc : (n,) ndarray or None
        Likewise ``|c(p) - c(p_nom)|``, ``c(p) = f(0, 0, 0, p)``.
    w_abs : (d,) ndarray or None
        ``max |w|`` over the disturbance box (zeros (0,) without disturbances).
    p_offset : callable or None
        With uncertain parameters: ``p_offset(x, u, w) -> (n,)``, a bound on
        ``|f(x, u, w, p) - f_nom(x, u, w)|`` over the parameter box at one point ``(x, u,
        w)`` (the whole field's interval enclosure there, so the parameters' effect keeps
        its correlation across the terms; :func:`_parameter_offset`).
    """

    Ac: np.ndarray
    Bc: np.ndarray
    f0: np.ndarray
    E: np.ndarray | None = None
    w_radius: np.ndarray | None = None
    dA: np.ndarray | None = None
    dB: np.ndarray | None = None
    dE: np.ndarray | None = None
    dc: np.ndarray | None = None
    w_abs: np.ndarray | None = None
    p_offset: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None


def affine_plant(problem: Problem) -> AffinePlant | None:
    """The plant as an affine ODE, or None when it is nonlinear.

    A plant given by ``A``, ``B`` matrices is affine; one given by expressions is when its
    Jacobians are constant (then ``f0 = f(0, 0)``).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    AffinePlant or None
        None also for a plant whose disturbances enter non-affinely, or whose field is not
        affine in ``(x, u, w)`` for each value of its uncertain parameters.
    """
    pl = problem.plant
    if pl.parameters is not None:
        return _parametric_plant(problem)
    # disturbances that cannot change the field (a zero-width box, a zero input): the
    # nominal plant, its drift E w_nominal included
    w = pl.disturbances if disturbances_matter(pl) else None
    if pl.A is not None and pl.B is not None:
        if w is None:
            drift = (np.zeros(pl.n) if pl.E is None or pl.disturbances is None else
                     np.asarray(pl.E, float) @ np.asarray(pl.disturbances.nominal, float))
            return AffinePlant(np.asarray(pl.A, float), np.asarray(pl.B, float), drift)
        E = np.asarray(pl.E, float)
        return AffinePlant(np.asarray(pl.A, float), np.asarray(pl.B, float),
                           E @ np.asarray(w.centre, float), E, np.asarray(w.radius, float))
    if pl.dynamics is None:
        return None
    sym = symbolic_model(problem)
    if sym.Jx.free_symbols or sym.Ju.free_symbols:
        return None
    zero = {s: 0 for s in (*sym.x, *sym.u)}
    if w is None:
        f0 = np.array([float(e.subs(zero)) for e in sym.f], dtype=float)
        return AffinePlant(
            np.array(sym.Jx.tolist(), dtype=float), np.array(sym.Ju.tolist(), dtype=float), f0
        )
    # the field before the nominal values: affine in (x, u, w) with constant Jacobians
    import sympy

    from codev_engine.plant import full_field

    f, xs, us, ws, _ = full_field(pl)
    J = f.jacobian(sympy.Matrix([*xs, *us, *ws]))
    if J.free_symbols:
        return None
    n, m = pl.n, pl.m
    Jn = np.array(J.tolist(), dtype=float)
    at = {**{s: 0 for s in (*xs, *us)}, **dict(zip(ws, w.centre.tolist(), strict=True))}
    f0 = np.array([float(e.subs(at)) for e in f], dtype=float)
    return AffinePlant(Jn[:, :n], Jn[:, n : n + m], f0, Jn[:, n + m :],
                       np.asarray(w.radius, float))


def _parametric_plant(problem: Problem) -> AffinePlant | None:
    """An expression plant with uncertain parameters ``p``: ``f = A(p) x + B(p) u + E(p) w +
    c(p)`` (the Jacobian in ``(x, u, w)`` free of ``x, u, w``), as the nominal affine plant
    and interval bounds on the deviations over the parameter box (docs/verification.md,
    "Uncertain parameters"); None when it is not of that form."""
    import sympy

    from codev_engine.plant import full_field
    from codev_engine.reach.interval_function import compile_interval

    pl = problem.plant
    if pl.dynamics is None:
        return None
    f, xs, us, ws, ps = full_field(pl)
    J = f.jacobian(sympy.Matrix([*xs, *us, *ws]))
    if J.free_symbols - set(ps):
        return None
    n, m, d = pl.n, pl.m, len(ws)
    zero = {s: 0 for s in (*xs, *us, *ws)}
    c = sympy.Matrix(f).subs(zero)  # (n, 1): c(p)
    box = pl.parameters
    nom = dict(zip(ps, box.nominal.tolist(), strict=True))
    try:
        Jn = np.array(J.subs(nom).tolist(), dtype=float)
        cn = np.array(c.subs(nom).tolist(), dtype=float).reshape(n)
        Jf = compile_interval(J, ps)
        cf = compile_interval(c, ps)
        lo, hi = np.asarray(box.lower, float), np.asarray(box.upper, float)
        Jlo, Jhi = (np.asarray(a, float) for a in Jf(lo, hi))
        clo, chi = (np.asarray(a, float).reshape(n) for a in cf(lo, hi))
    except (TypeError, ValueError, ArithmeticError, NotImplementedError):
        return None  # (an enclosure that cannot be computed: not followed by this engine)
    dJ = np.maximum(np.abs(Jhi - Jn), np.abs(Jn - Jlo)) * (1.0 + 1e-12) + 1e-12 * np.abs(Jn)
    dc = np.maximum(np.abs(chi - cn), np.abs(cn - clo)) * (1.0 + 1e-12) + 1e-12 * np.abs(cn)
    if not (np.all(np.isfinite(dJ)) and np.all(np.isfinite(dc))):
        return None
    Ac, Bc, En = Jn[:, :n], Jn[:, n : n + m], Jn[:, n + m :]
    if d:
        wl, wh = np.asarray(pl.disturbances.lower, float), np.asarray(pl.disturbances.upper,
                                                                        float)
        wc, wr = 0.5 * (wl + wh), 0.5 * (wh - wl)
        f0 = cn + En @ wc
        dc = dc + 1e-12 * (np.abs(En) @ np.abs(wc))  # (the rounding of f0's product)
        w_abs = np.maximum(np.abs(wl), np.abs(wh))
        E, w_radius = En, wr
    else:
        f0, w_abs, E, w_radius = cn, np.zeros(0), None, None
    try:
        ff = compile_interval(f, (*xs, *us, *ws, *ps))
    except (TypeError, ValueError, ArithmeticError, NotImplementedError):
        ff = None  # (then the bound about the origin alone, as before)
    offset = None if ff is None else partial(_parameter_offset, ff, Jn, cn, lo, hi)
    return AffinePlant(Ac, Bc, f0, E, w_radius, dJ[:, :n], dJ[:, n : n + m], dJ[:, n + m :],
                       dc, w_abs, offset)


def _parameter_offset(ff, Jn: np.ndarray, cn: np.ndarray, plo: np.ndarray, phi: np.ndarray,
                      x: np.ndarray, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A bound on ``|f(z, p) - (Jn z + cn)|`` over the parameter box at the point ``z =
    (x, u, w)``: the field's interval enclosure with ``z`` a point and ``p`` the box,
    minus the nominal model's value (its float rounding bounded by ``1e-12`` of the terms).

    Parameters
    ----------
    ff : IntervalFunction
        The field ``f`` (n,) over ``(x, u, w, p)``.
    Jn : (n, n + m + d) ndarray
        The nominal Jacobian in ``(x, u, w)``.
    cn : (n,) ndarray
        The nominal ``f(0, 0, 0, p_nom)``.
    plo, phi : (q,) ndarray
        The parameter box.
    x, u, w : (n,), (m,), (d,) ndarray
        The point.

    Returns
    -------
    (n,) ndarray
        ``inf`` where the enclosure fails (the caller then keeps its other bound).
    """
    z = np.concatenate([x, u, w])
    lo = np.concatenate([z, plo])
    hi = np.concatenate([z, phi])
    try:
        flo, fhi = (np.asarray(a, float).reshape(-1) for a in ff(lo, hi))
    except (TypeError, ValueError, ArithmeticError):
        return np.full(cn.shape, np.inf)
    fn = Jn @ z + cn
    mag = np.abs(Jn) @ np.abs(z) + np.abs(cn)
    out = np.maximum(fhi - fn, fn - flo) * (1.0 + 1e-12) + 1e-12 * mag
    return np.where(np.isfinite(out), np.maximum(out, 0.0), np.inf)


@dataclass
class _Star:
    c: np.ndarray  # (n,)
    V: np.ndarray  # (n, na)
    H: np.ndarray  # (r, na)  alpha-polytope rows
    h: np.ndarray  # (r,)
    verts: np.ndarray  # (nv, na)
    err: np.ndarray  # (n,)
    k: int  # sample index
    path: tuple[int, ...] = ()
    #: False for a merged set (a sound hull in state coordinates: ``c = 0``, ``V = I``): its
    #: points are no longer tied to initial states, so a violation on it is only possible
    exact: bool = True
    #: with a disturbance: generators (d, g) of the disturbance accumulated over earlier
    #: periods, and the rest of the error (rounding, boxed generators) ``eround`` (d,);
    #: ``err >= eround + |Gw| 1`` is their box (what every reader of ``err`` uses)
    Gw: np.ndarray | None = None
    eround: np.ndarray | None = None


class _NeedExactError(Exception):
    """The merged exploration met a possible violation: redo it without merging."""


@dataclass(frozen=True)
class Finding:
    """A property violation found on the over-approximation.

    ``alpha`` is set when the violation is *exact* (a concrete initial state reaches it:
    ``x0 = c0 + V0 alpha``); otherwise it is only a possible violation.

    Attributes
    ----------
    kind : str
        ``"unsafe"``, ``"safe"``, ``"input_bounds"`` (a property violated), ``"undefined"``
        (the set leaves the law's domain), ``"max_depth"`` (the refinement budget ran out),
        ``"over_approximation"`` (a merged or disturbed set still meets a property after
        the time refinements such a set gets), ``"enclosure"`` (the uncertain parameters'
        effect over a period could not be bounded) or ``"limit"`` (the exploration grew
        past ``codev_engine.limits``; ``detail`` says which limit and what to change).
    index : int
        The unsafe or safe set, or the input, violated; -1 for the other kinds.
    t : float
        The time (s) of the violation, or of the segment that could not be decided.
    alpha : (n,) ndarray or None
        The initial state's coordinates in the initial box (``[-1, 1]^n``).
    detail : str or None
        For ``"enclosure"`` (an interval enclosure met a singularity, e.g. a division by an
        interval containing 0): the operation, the expression and the time, in words.
    """

    kind: str  # "unsafe", "safe", "input_bounds", "undefined", "max_depth", "enclosure", ...
    index: int
    t: float
    alpha: np.ndarray | None
    detail: str | None = None



def affine_range(F: np.ndarray, G: np.ndarray, A: np.ndarray, b: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Range of ``u = F x + G`` over the polytope ``A x <= b``, by two LPs per input.

    Each bound is widened by ``1e-9 (1 + |F_r| |x| + |G_r|)`` (the LP's and the
    evaluation's rounding), so it holds the law's value at every point of the polytope.

    Parameters
    ----------
    F : (m, n) ndarray
    G : (m,) ndarray
    A : (k, n) ndarray
    b : (k,) ndarray

    Returns
    -------
    lo, hi : (m,) ndarray
        Infinite where an LP fails.
    """
    m = F.shape[0]
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    for r in range(m):
        for sgn in (1.0, -1.0):
            x, st, _ = solve_lp(sgn * F[r], A, b)
            if st != "optimal":
                continue
            v = F[r] @ x + G[r]
            pad = 1e-9 * (1 + np.abs(F[r]) @ np.abs(x) + abs(G[r]))
            if sgn > 0:
                lo[r] = v - pad
            else:
                hi[r] = v + pad
    return lo, hi


class ClosedLoopSetup:
    """What both reach engines (linear and nonlinear) read from the problem and the law.

    Sets ``n, m, Ts, T``, the normalised ``unsafe``/``safe`` sets, the input-bound check
    (``check_u``, ``u_min``, ``u_max`` with a 1e-7 slack), the law's region boxes, the
    initial box as centre ``c0`` and generator ``V0``, and empty ``tubes``/``findings``.
    """

    problem: Problem
    law: ExplicitLaw

    def _init_properties(self) -> None:
        p = self.problem
        vs = p.verify
        self.n, self.m = p.plant.n, p.plant.m
        self.Ts = float(p.model.sample_time)
        self.T = float(vs.time_horizon)
        self.unsafe = [normalize_rows(*s.halfspaces())[:2] for s in vs.unsafe]
        self.safe = [normalize_rows(*s.halfspaces())[:2] for s in vs.safe]
        self.check_u = bool(vs.input_bounds)
        # the law meets its own input bounds only up to round-off and the 1e-9 tolerance of
        # point location on region boundaries: input bounds are checked with 1e-7 slack
        self.u_min = np.asarray(p.mpc.u_min, float) - 1e-7 * (1 + np.abs(p.mpc.u_min))
        self.u_max = np.asarray(p.mpc.u_max, float) + 1e-7 * (1 + np.abs(p.mpc.u_max))
        # the closed loop's state is the law's parameter theta = (x, u_prev, r): u_prev is
        # the input held over the last period, r a constant (d = n for a law in x alone)
        self.d = (int(self.law.n) if self.law.num_regions or getattr(self.law, "on_demand", False)
                  else self.n)
        self._known = self.law.num_regions  # (a law on demand grows: _law_grown)
        lo, hi = theta_initial_box(p) if self.d > self.n else (vs.initial_lower,
                                                                 vs.initial_upper)
        self.c0 = 0.5 * (lo + hi)
        self.V0 = np.diag(0.5 * (hi - lo))
        self.tubes: list[Tube] = []
        self.findings: list[Finding] = []
        self.boxes = 0  # the reachtube's boxes so far (for progress and the limits)
        lim = limits()
        self._max_branches = lim["branches"]
        self._max_boxes = max(1, lim["tube_bytes"] // ((2 * self.n + 3) * 8))
        self._tube_gib = lim["tube_bytes"] / 2**30

    def _region_u(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The range of the law's input over region ``i`` and the bounds it is checked
        against (cached; 4m small LPs per region).

        Every state the law gives region ``i`` lies in ``{A_i x <= b_i + 1e-9}`` (point
        location: inside the region, or within 1e-9 of it outside the domain), so any input
        region ``i`` applies at a sample -- with measurement noise too: it is the law at a
        measured point of the region -- lies in the LP range of ``F_i x + G_i`` over it,
        padded by ``1e-9`` of the terms for the LPs' accuracy (``lo``, ``hi``). The input
        bounds are meant up to the law's rounding: the mp solvers meet ``u_min``, ``u_max``
        to their tolerance (``1e-7 (1 + |bound|)``, the slack of ``u_min`` / ``u_max``), on
        the region itself; what the 1e-9 of point location adds beyond the region (its
        spill, ``range over the relaxed rows - range over the rows``, up to ``|F| 1e-9`` near
        a sharp corner) is the locator's rounding, not the law's, and widens the bounds
        the region is checked against (``umin``, ``umax``). Infinite where an LP fails.

        Parameters
        ----------
        i : int
            The region.

        Returns
        -------
        lo, hi, umin, umax : (m,) ndarray
        """
        cache = self.__dict__.setdefault("_u_cache", {})
        if i not in cache:
            F, G = self.law.F[i], self.law.G[i]
            A, b = self.law.A[i], self.law.b[i]
            lo0, hi0 = affine_range(F, G, A, b)
            lo, hi = affine_range(F, G, A, b + 1e-9)
            spill_hi = np.where(np.isfinite(hi) & np.isfinite(hi0), np.maximum(hi - hi0, 0), 0)
            spill_lo = np.where(np.isfinite(lo) & np.isfinite(lo0), np.maximum(lo0 - lo, 0), 0)
            cache[i] = (lo, hi, self.u_min - spill_lo, self.u_max + spill_hi)
        return cache[i]

    def _init_noise(self) -> None:
        """The measurement noise's centre ``vc`` and radius ``vr`` (None without noise), the
        law's offsets with the noise's centre ``Gn`` and a bound ``Gn_err`` on their
        rounding (docs/verification.md, "Measurement noise"). After :meth:`_init_properties`.
        """
        vs = self.problem.verify
        # measurement noise (docs/verification.md, "Measurement noise"): the law sees
        # theta + v, v in the box (centre vc, radius vr; zero on u_prev and r). Region i
        # applies F_i (theta + vc) + G_i + F_i delta, |delta| <= vr: the centre goes into
        # the law's offset Gn, the rest is a bounded input held over the period (the linear
        # engine: a disturbance (Bc F_i, vr); the nonlinear one: a widened input box)
        F = self.law.F
        self.vc = self.vr = None
        self.Gn = self.law.G
        if vs.noisy:
            pad = np.zeros(self.d - self.n)
            lo, hi = np.asarray(vs.noise_lower, float), np.asarray(vs.noise_upper, float)
            self.vc = np.concatenate([0.5 * (lo + hi), pad])
            self.vr = np.concatenate([0.5 * (hi - lo), pad]) * (1.0 + 1e-12)
            if self.law.num_regions:
                self.Gn = self.law.G + np.einsum("rmd,d->rm", F, self.vc)
        #: a bound on the rounding of Gn (per region, (R, m)): an input disturbance too
        self.Gn_err = (
            4e-16 * (self.d + 2) * (np.abs(self.law.G) + np.einsum("rmd,d->rm", np.abs(F),
                                                                   np.abs(self.vc)))
            if self.vc is not None and self.law.num_regions else None
        )

    def _law_grown(self) -> None:
        """After a law computed on demand has grown: the regions' offsets again (``Gn``;
        the linear engine asks the law for the regions meeting a set, not their boxes)."""
        if self.law.num_regions != self._known:
            self._known = self.law.num_regions
            self._init_noise()

    def _reach_rows(self, A: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The right-hand side of ``{theta : A (theta + v) <= b for some v in the noise
        box}`` (a superset: row by row, ``b - A vc + |A| vr`` and its rounding); ``b``
        without noise."""
        if self.vr is None:
            return b
        absA = np.abs(A)
        return (b - A @ self.vc + absA @ self.vr
                + 1e-12 * (np.abs(b) + absA @ (np.abs(self.vc) + self.vr)))

    def _noise_input(self, i: int) -> np.ndarray:
        """(m,) bound on the input's part from the noise about its centre (and the rounding
        of the noisy offset): ``|F_i| vr + Gn_err_i``; zeros without noise."""
        if self.vr is None:
            return np.zeros(self.m)
        return (np.abs(self.law.F[i]) @ self.vr + self.Gn_err[i]) * (1.0 + 1e-12)

    def _tick(self, boxes: int, sample: int, t: float) -> None:
        """Count one branch period's ``boxes``; report progress (``samples``: the sample
        reached); raise :class:`ExplorationLimitError` past ``codev_engine.limits``."""
        self.boxes += boxes
        if self.stats["branches"] > self._max_branches:
            raise ExplorationLimitError(
                f"more than {self._max_branches:,} branches explored by t = {t:.4g}: "
                "shrink verify.initial_set, shorten verify.time_horizon or lower "
                "verify.max_depth",
                t,
            )
        if self.boxes > self._max_boxes:
            raise ExplorationLimitError(
                f"the reachtube passed {self._max_boxes:,} boxes ({self._tube_gib:.3g} GiB) "
                f"by t = {t:.4g}: raise verify.step or shorten verify.time_horizon",
                t,
            )
        over = time_over_kind()
        if over is not None:
            raise self._deadline_error(*over, t, max(sample - 1, 0))
        progress = getattr(self, "progress", None)
        if progress is not None:
            progress({**self.stats, "samples": sample, "boxes": self.boxes})

    def _deadline_error(self, kind: str, seconds: float, t: float,
                        period: int) -> ExplorationLimitError:
        """The stop at a deadline (``kind`` ``"limit"`` or ``"budget"``) at time ``t`` of
        sample period ``period``, in words: where (and in which region), what to change."""
        where = f"t = {t:.4g} (sample period {period}"
        region = getattr(self, "_region", None)
        where += ")" if region is None else f", region {region})"
        if kind == "budget":
            return ExplorationLimitError(
                f"the time budget of {seconds:g} s ran out at {where}: raise "
                "verify.time_budget / --budget, shrink verify.initial_set or shorten "
                "verify.time_horizon", t, "budget")
        return ExplorationLimitError(
            f"the time limit of {seconds:g} s was reached at {where}: raise "
            "--time-limit / CODEV_LIMITS=time=SECONDS, shrink verify.initial_set, "
            "shorten verify.time_horizon or lower verify.max_depth", t)

    def _limited(self, run: Callable[[], None]) -> None:
        """``run()``; past a limit, a ``"limit"`` finding (what was explored is kept)."""
        try:
            with stoppable():  # a long step stops within a heartbeat of the deadline
                run()
        except DeadlineReached as stop:
            # in the middle of a period: its star (``_t_now``, 0 for a nonlinear cell) is
            # not finished, what was explored before it is kept
            exc = self._deadline_error(stop.kind, stop.seconds, getattr(self, "_t_now", 0.0),
                                       getattr(self, "_sample", 0))
            self.findings.append(Finding(exc.kind, -1, exc.t, None, str(exc)))
            self.stats["complete_until"] = self._complete_until(exc.t)
        except ExplorationLimitError as exc:
            self.findings.append(Finding(exc.kind, -1, exc.t, None, str(exc)))
            self.stats["complete_until"] = self._complete_until(exc.t)
        except RegionLimitError as exc:
            # a law computed on demand needs more regions than the full synthesis may hold
            t = getattr(self, "_t_now", 0.0)
            self.findings.append(Finding("limit", -1, t, None, f"at t = {t:.4g} {exc}"))
            self.stats["complete_until"] = self._complete_until(t)

    def _complete_until(self, t: float) -> float:
        """After a stop at time ``t``: every trajectory is in the tube up to the earliest
        branch left unexplored (the stack of stars at their samples, the stopped one)."""
        return float(min([t, *(st.k * self.Ts for st in getattr(self, "_pending", ()))]))


@dataclass
class LinearReach(ClosedLoopSetup):
    """Reachability engine for one problem, law and hold (see module docstring).

    After :meth:`run`, ``tubes`` holds the reachtube's pieces and ``findings`` the
    violations found (see :class:`ClosedLoopSetup`).

    Attributes
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
    plant : AffinePlant
        The plant, from :func:`affine_plant`.
    hold : {"zoh", "continuous"}
        How the input is applied between samples: held at the sample's value, or the law
        evaluated continuously.
    max_depth : int
        How many times a suspicious segment may be refined in time (each refinement cuts
        it in four).
    stats : dict
        Counters: ``branches`` and ``refinements``, updated by :meth:`run` (``boxes`` is
        counted by ``verify``, on the tube); ``merges`` and, when an invariance certificate
        closed the run, ``certificate`` (anchor and closing samples, period).
    merge : bool
        Merge the sets of a sample that lie in one region and look for an invariance
        certificate, falling back to the exact exploration at a possible violation on a
        merged set (docs/verification.md); False: every branch separately.
    unbounded : bool
        Safety for all time: the run ends at an invariance certificate (the tube is not
        repeated) or at the horizon ``max_samples`` sample times (no certificate).
    progress : callable, optional
        Called with a copy of ``stats`` plus ``samples`` (the sample reached) and ``boxes``
        (the reachtube's boxes so far) after each branch period.
    """

    problem: Problem
    law: ExplicitLaw
    plant: AffinePlant
    hold: str
    max_depth: int
    stats: dict = field(default_factory=lambda: {"branches": 0, "refinements": 0, "boxes": 0})
    #: merge the sets of one sample that lie in one region and look for an invariance
    #: certificate (:meth:`_run_merged`); False: every branch separately
    merge: bool = True
    #: safety for all time: stop at the certificate without repeating the tube, and never
    #: fall back to the exact exploration (it would not end)
    unbounded: bool = False
    #: called with a copy of ``stats`` plus ``samples`` (the sample reached) and ``boxes``
    #: after each branch period
    progress: Callable[[dict], None] | None = None

    def __post_init__(self) -> None:
        p = self.problem
        vs = p.verify
        self._init_properties()
        #: this period's held input is decided (zoh: once per period, :meth:`_period`)
        self._held_ok = False
        #: the input bounds this period's region is checked against (:meth:`_region_u`)
        self._ubounds = (self.u_min, self.u_max)
        self.step = float(vs.step)
        self._flows: dict = {}
        #: the arrays of an invariance certificate (H, h, points, pads), when one closed
        self.certificate: dict | None = None
        self._init_noise()
        #: uncertain parameters: their deviation from the nominal model is an additive
        #: disturbance whose radius ``_prad`` (n,) is bounded per period (:meth:`_param_bound`)
        self.param = self.plant.dA is not None
        self._prad = np.zeros(self.n)
        #: the times of the current period found free of exact violations (:meth:`_resolve`)
        self._no_violation: set[float] = set()
        #: disturbances, noise or parameters: the star carries generators, nothing is exact
        self.uncertain = self.plant.E is not None or self.vr is not None or self.param

    # ---- flows --------------------------------------------------------------------------

    def _mode(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(M, v) of the affine ODE in region i for continuous hold; (Ac, f0) for zoh."""
        pl = self.plant
        if self.hold == "zoh":
            return pl.Ac, pl.f0
        F, G = self.law.F[i], self.Gn[i]
        return pl.Ac + pl.Bc @ F, pl.Bc @ G + pl.f0

    def _flow(self, i: int, taus: np.ndarray):
        """Flow of region i's closed loop: x(tau) = Phi x_k + g.

        Returns Phi (J, n, n), g (J, n) and the *magnitudes* Pm (J, n, n), gm (J, n) that
        bound the rounding error of Phi and g relative to the terms they are computed from
        (``|E11| + |E12||F|`` for zoh: the sum can cancel, e.g. for a deadbeat law, and
        its error scales with the terms, not with the result).
        """
        key = (i if self.hold == "continuous" else -1, taus.tobytes())
        hit = self._flows.get(key)
        if hit is None:
            n, m = self.n, self.m
            pl = self.plant
            if self.hold == "zoh":
                # state (x, u, 1): xdot = Ac x + Bc u + f0, udot = 0
                Ma = np.zeros((n + m + 1, n + m + 1))
                Ma[:n, :n] = pl.Ac
                Ma[:n, n : n + m] = pl.Bc
                Ma[:n, -1] = pl.f0
            else:
                M, v = self._mode(i)
                Ma = np.zeros((n + 1, n + 1))
                Ma[:n, :n] = M
                Ma[:n, -1] = v
            E = expm(taus[:, None, None] * Ma[None])
            # scaling-and-squaring error grows with expm(|Ma| tau), not with |expm(Ma tau)|
            Emag = expm(taus[:, None, None] * np.abs(Ma)[None])
            hit = (E, Emag)
            self._flows[key] = hit
        E, Emag = hit
        n = self.n
        if self.hold == "zoh":
            F, G = self.law.F[i], self.Gn[i]
            E11, E12, E13 = E[:, :n, :n], E[:, :n, n : n + self.m], E[:, :n, -1]
            M11, M12, M13 = Emag[:, :n, :n], Emag[:, :n, n : n + self.m], Emag[:, :n, -1]
            if self.d > n:  # x(tau) from theta_k = (x_k, u_prev, r): pad with zeros
                pad = np.zeros((E11.shape[0], n, self.d - n))
                E11, M11 = np.concatenate([E11, pad], 2), np.concatenate([M11, pad], 2)
            Phi = E11 + E12 @ F
            g = np.einsum("jnm,m->jn", E12, G) + E13
            Pm = M11 + M12 @ np.abs(F)
            gm = np.einsum("jnm,m->jn", M12, np.abs(G)) + M13
            return Phi, g, Pm, gm
        return E[:, :n, :n], E[:, :n, -1], Emag[:, :n, :n], Emag[:, :n, -1]

    def _inputs(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The bounded inputs of region i's period: ``(E (n, k), |E| (n, k), radius (k,))``
        with ``dx/dt = ... + E delta(t)``, ``|delta| <= radius``; None when there are none.

        The plant's disturbance ``(E, w_radius)``; with measurement noise also
        ``(Bc F_i, vr)`` (the law's reaction to the noise about its centre, held over the
        period -- a constant is one of the signals bounded) and ``(Bc, Gn_err_i)`` (the
        rounding of the noisy law's offset). ``|E|`` bounds the rounding of E's entries
        (``|Bc| |F_i|`` for a product that may cancel).
        """
        pl = self.plant
        cols: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        if pl.E is not None:
            cols.append((pl.E, np.abs(pl.E), pl.w_radius))
        if self.vr is not None:
            F = self.law.F[i][:, : self.n]
            cols.append((pl.Bc @ F, np.abs(pl.Bc) @ np.abs(F) * (1.0 + 1e-12),
                         self.vr[: self.n]))
            cols.append((pl.Bc, np.abs(pl.Bc), self.Gn_err[i]))
        if self.param:  # the parameters' deviation, bounded for this period (_param_bound)
            eye = np.eye(self.n)
            cols.append((eye, eye, self._prad))
        if not cols:
            return None
        return (np.hstack([c[0] for c in cols]), np.hstack([c[1] for c in cols]),
                np.concatenate([c[2] for c in cols]))

    def _disturbance(self, i: int, taus: np.ndarray) -> np.ndarray | None:
        """(J, n) bounds ``D(tau)`` on ``|int_0^tau e^{M (tau - s)} E delta(s) ds|`` for
        every measurable ``|delta| <= w_radius``; None without disturbances.

        On a grid ``s_j = j h`` of the period, ``|e^{M s} E| <= e^{|M| h} |e^{M s_j} E|``
        for ``s in [s_j, s_j + h]`` (element-wise, ``|e^{M r}| <= e^{|M| r}``), so
        ``D(s_J) = sum_{j<J} h e^{|M| h} (|e^{M s_j} E| + rounding) w_radius`` bounds the
        integral up to ``s_J``; ``D`` is non-decreasing, and ``tau`` takes the value of the
        grid point at or after it (docs/verification.md, "Disturbances").
        """
        w = self._inputs(i)
        if w is None:
            return None
        Ew, absE, radius = w
        key = ("w", i if self.hold == "continuous" or self.vr is not None else -1)
        hit = self._flows.get(key)
        if hit is None:
            M, _ = self._mode(i)
            M = M[:, : self.n]
            h = min(self.step, self.Ts) / 4.0
            K = int(np.ceil(self.Ts / h)) + 2
            sj = np.arange(K) * h
            Ex = expm(sj[:, None, None] * M[None])
            Em = expm(sj[:, None, None] * np.abs(M)[None])
            G = np.abs(Ex @ Ew) + _REL * (Em @ absE) + 1e-300  # (K, n, d)
            growth = expm(h * np.abs(M)) * (1.0 + 1e-9)
            # per unit radius of each column: the radius (the parameters' part is set per
            # period) is applied at the call, D being linear in it
            incr = h * np.einsum("ab,jbd->jad", growth, G)
            Du = np.concatenate([np.zeros((1, self.n, Ew.shape[1])), np.cumsum(incr, axis=0)],
                                axis=0) * (1.0 + 1e-9)
            hit = (h, Du)
            self._flows[key] = hit
        h, Du = hit
        idx = np.ceil(taus / h).astype(int)
        if np.any(idx >= Du.shape[0]):  # cannot happen: taus lie in one period
            raise _NeedExactError
        return (Du[idx] @ radius) * (1.0 + 1e-12)

    # ---- one period of one branch ----------------------------------------------------

    def _images(self, s: _Star, i: int, taus: np.ndarray):
        Phi, g, Pm, gm = self._flow(i, taus)
        X = Phi @ s.c + g  # (J, n)
        W = Phi @ s.V  # (J, n, na)
        Y = X[:, None, :] + np.einsum("jna,va->jvn", W, s.verts)  # (J, nv, n)
        # the true Phi is within _REL * Pm of the computed one (element-wise), likewise g
        bound = np.abs(Phi) + _REL * Pm
        if s.Gw is None:
            err = (
                bound @ s.err + _REL * (Pm @ np.abs(s.c) + (Pm @ np.abs(s.V)).sum(axis=2) + gm)
                + 1e-300
            )
        else:  # the accumulated disturbance as generators: mapped exactly, no wrapping
            err = (
                bound @ s.eround
                + _REL * (Pm @ np.abs(s.c) + (Pm @ np.abs(s.V)).sum(axis=2) + gm
                          + (Pm @ np.abs(s.Gw)).sum(axis=2))
                + np.abs(Phi @ s.Gw).sum(axis=2) * (1.0 + 1e-12)
                + 1e-300
            )
        D = self._disturbance(i, taus)
        if D is not None:  # the disturbance's part of the state, bounded on its own
            err = err + D
        return X, W, Y, err

    def _segments(self, s: _Star, i: int, taus: np.ndarray):
        """Boxes of the segments between consecutive taus, and the input boxes."""
        X, W, Y, err = self._images(s, i, taus)
        lo = Y.min(axis=1) - err
        hi = Y.max(axis=1) + err
        pl = self.plant
        F, G = self.law.F[i], self.Gn[i]
        M, _ = self._mode(i)
        if self.hold == "zoh":
            xk = s.c[None, :] + s.verts @ s.V.T  # (nv, n) states at the sample
            uv = xk @ F.T + G  # (nv, m)
            acc = Y @ (pl.Ac @ pl.Ac).T + ((uv @ pl.Bc.T + pl.f0) @ pl.Ac.T)[None]
            ue = np.abs(F) @ s.err
            if s.Gw is not None:
                ue = np.minimum(ue, (np.abs(F) @ s.eround + np.abs(F @ s.Gw).sum(axis=1)
                                     + _REL * (np.abs(F) @ np.abs(s.Gw)).sum(axis=1))
                                * (1.0 + 1e-12))
            ue = ue + self._noise_input(i)
            u_lo, u_hi = uv.min(axis=0) - ue, uv.max(axis=0) + ue
            if self.check_u:
                # the held input is the law at a state of region i: within its range there
                # (sound whatever the star's vertices are -- its bounding box's corners too)
                rlo, rhi, _, _ = self._region_u(i)
                u_lo, u_hi = np.maximum(u_lo, rlo), np.minimum(u_hi, rhi)
            u_lo = np.repeat(u_lo[None], len(taus) - 1, 0)
            u_hi = np.repeat(u_hi[None], len(taus) - 1, 0)
        else:
            _, v = self._mode(i)
            acc = Y @ (M @ M).T + (M @ v)[None, None]
        amax = np.abs(acc).max(axis=1)  # (J, n)
        amax = amax * (1 + 1e-9) + err @ (np.abs(M) @ np.abs(M)).T
        D = self._disturbance(i, taus)
        if self.hold == "zoh":
            # the state's error at the sample also moves the held input: its part p of the
            # state has p'' = Ac (Ac p + Bc F e), |e| <= s.err (rounding alone: ~1e-15; with
            # a disturbance, the disturbance's part too)
            amax = amax + (np.abs(pl.Ac) @ np.abs(pl.Bc) @ np.abs(F) @ s.err)[None, :]
        hseg = np.diff(taus)
        # the same for every period of region i on this grid (zoh: of every region)
        gkey = ("growth", i if self.hold == "continuous" else -1, hseg.tobytes())
        growth = self._flows.get(gkey)
        if growth is None:
            growth = self._flows[gkey] = expm(hseg[:, None, None] * np.abs(M)[None])
        E = (hseg**2 / 8.0)[:, None] * np.einsum("jab,jb->ja", growth, amax[:-1])
        if D is not None:
            # err holds D(tau_j) at the ends; between them the disturbance's part may grow
            # to D(tau_{j+1}): the hull is widened by the difference (docs/verification.md)
            E = E + (D[1:] - D[:-1])
        slo = np.minimum(lo[:-1], lo[1:]) - E
        shi = np.maximum(hi[:-1], hi[1:]) + E
        if self.hold == "continuous":
            U = Y @ F.T + G  # (J, nv, m)
            ue = np.abs(F) @ err.T + self._noise_input(i)[:, None]  # (m, J)
            ulo = U.min(axis=1) - ue.T
            uhi = U.max(axis=1) + ue.T
            uE = E @ np.abs(F).T
            u_lo = np.minimum(ulo[:-1], ulo[1:]) - uE
            u_hi = np.maximum(uhi[:-1], uhi[1:]) + uE
        return X, W, err, slo, shi, u_lo, u_hi

    def _bad_segments(self, slo, shi, u_lo, u_hi) -> np.ndarray:
        """(J-1,) mask of segments whose box may violate a property."""
        bad = np.zeros(slo.shape[0], dtype=bool)
        for A, b in self.unsafe:
            # box meets {A x <= b} unless one row separates them
            low = np.where(A > 0, A, 0) @ slo.T + np.where(A < 0, A, 0) @ shi.T  # (r, J)
            maybe = ~np.any(low > b[:, None], axis=0)
            for j in np.flatnonzero(maybe & ~bad):
                if _box_meets(A, b, slo[j], shi[j]):
                    bad[j] = True
        for A, b in self.safe:
            high = np.where(A > 0, A, 0) @ shi.T + np.where(A < 0, A, 0) @ slo.T
            bad |= np.any(high > b[:, None], axis=0)
        if self.check_u and not self._held_ok:
            umin, umax = self._ubounds
            bad |= np.any(u_lo < umin, axis=1) | np.any(u_hi > umax, axis=1)
        return bad

    def _meets(self, lo: np.ndarray, hi: np.ndarray) -> str:
        """Which property the box ``[lo, hi]`` may violate, in words (for a ``detail``)."""
        for idx, (A, b) in enumerate(self.unsafe):
            if _box_meets(A, b, lo, hi):
                return f"meets unsafe set {idx}"
        for idx, (A, b) in enumerate(self.safe):
            if np.any(np.where(A > 0, A, 0) @ hi + np.where(A < 0, A, 0) @ lo > b):
                return f"leaves safe set {idx}"
        return "may take an input past its bounds"

    def _exact_violation(self, s: _Star, i: int, tau: float, t: float) -> Finding | None:
        """Is there alpha in P whose exact trajectory violates a property at tau?"""
        X, W, _, err = self._images(s, i, np.array([tau]))
        X, W, err = X[0], W[0], err[0]
        margin = float(np.max(err)) * 10 + 1e-12
        # the polytope P of alpha lies in the hull of s.verts (what the tube's boxes rest
        # on too), so a linear function's maximum over P is at most its maximum over them:
        # an LP whose bound the vertices already keep below the threshold finds nothing
        # and is skipped (a suspicious segment's endpoints are mostly of this kind)
        Y = X[None, :] + s.verts @ W.T  # (nv, n)
        for idx, (A, b) in enumerate(self.unsafe):
            if np.any((Y @ A.T).min(axis=0) > b - margin):
                continue  # a row of the unsafe set no point of P reaches by the margin
            # maximise r s.t. A (X + W a) + r <= b, a in P
            na = W.shape[1]
            Aa = np.vstack(
                [
                    np.hstack([A @ W, np.ones((A.shape[0], 1))]),
                    np.hstack([s.H, np.zeros((s.H.shape[0], 1))]),
                ]
            )
            ba = np.concatenate([b - A @ X, s.h])
            f = np.zeros(na + 1)
            f[-1] = -1.0
            ub = np.full(na + 1, np.inf)
            ub[-1] = 1.0
            x, st, _ = solve_lp(f, Aa, ba, ub=ub)
            if st == "optimal" and x[-1] >= margin:
                return Finding("unsafe", idx, t, x[:na])
        for idx, (A, b) in enumerate(self.safe):
            high = (Y @ A.T).max(axis=0)
            for r in range(A.shape[0]):
                if high[r] <= b[r] + margin:
                    continue
                x, st, _ = solve_lp(-(A[r] @ W), s.H, s.h)
                if st == "optimal" and A[r] @ (X + W @ x) > b[r] + margin:
                    return Finding("safe", idx, t, x)
        if self.check_u and not self._held_ok:
            F, G = self.law.F[i], self.Gn[i]
            if self.hold == "zoh":
                Xu, Wu = s.c, s.V
            else:
                Xu, Wu = X, W
            umin, umax = self._ubounds
            Yu = Xu[None, :] + s.verts @ Wu.T  # (nv, d)
            for r in range(self.m):
                for sign, bound in ((1.0, umax[r]), (-1.0, -umin[r])):
                    if not np.isfinite(bound):
                        continue
                    row = sign * F[r]
                    if (Yu @ row).max() + sign * G[r] <= bound + margin:
                        continue  # (as above: no point of P exceeds the bound)
                    x, st, _ = solve_lp(-(row @ Wu), s.H, s.h)
                    if st == "optimal" and row @ (Xu + Wu @ x) + sign * G[r] > bound + margin:
                        return Finding("input_bounds", r, t, x)
        return None

    def _held_violation(self, s: _Star, i: int, t: float, err: np.ndarray,
                        u_lo: np.ndarray, u_hi: np.ndarray) -> Finding:
        """Decide a held input (zoh) that may leave its bounds, once for the period.

        An LP over the star's polytope finds the largest (smallest) held input
        ``F_i (c + V a) + G_i``; beyond the region's bound by more than ten times the
        star's error it is a concrete violation (``alpha`` set, the initial state). Else
        it is a possible violation that no time refinement can decide (the input is held):
        an ``"over_approximation"`` finding whose ``detail`` says which input, the range and the
        tolerance.
        """
        F, G = self.law.F[i], self.Gn[i]
        umin, umax = self._ubounds
        margin = float(np.max(err)) * 10 + 1e-12
        for r in range(self.m):
            for sign, bound in ((1.0, umax[r]), (-1.0, -umin[r])):
                if not np.isfinite(bound):
                    continue
                row = sign * F[r]
                a, st, _ = solve_lp(-(row @ s.V), s.H, s.h)
                if st == "optimal" and row @ (s.c + s.V @ a) + sign * G[r] > bound + margin:
                    if s.exact or not self.uncertain:
                        return Finding("input_bounds", r, t, a)
        r = int(np.argmax(np.maximum(u_hi - umax, umin - u_lo)))
        tol_hi = umax[r] - float(self.problem.mpc.u_max[r])
        tol_lo = float(self.problem.mpc.u_min[r]) - umin[r]
        # (an over-approximation's range, not a refinement budget: no time refinement is
        # tried, and raising max_depth would change nothing)
        return Finding(
            "over_approximation", -1, t, None,
            f"at t = {t:.6g} the input {r} held by region {i} lies in [{u_lo[r]:.10g}, "
            f"{u_hi[r]:.10g}] (bounds [{self.problem.mpc.u_min[r]:g}, "
            f"{self.problem.mpc.u_max[r]:g}], tolerance {max(tol_lo, tol_hi):.3g}); "
            "held over the period, it is not decided by time refinement",
        )

    def _param_bound(self, s: _Star, i: int, taus: np.ndarray) -> bool:
        """Set ``_prad``, the radius of the parameters' deviation over this period.

        ``f(x, u, w, p) - f_nom = dA(p) x + dB(p) u + dE(p) w + dc(p)``: with ``x`` in a box
        ``B``, ``u`` in its range, ``|.| <= |dA| |x|_B + |dB| |u| + |dE| |w| + |dc|``; and,
        centred at the point ``z_c = (x_c, u_c, w_c)`` of the ranges' midpoints (the field
        being affine in ``z`` for each ``p``), ``|.| <= |dA| x_r + |dB| u_r + |dE| w_r +
        |f(z_c, p) - f_nom(z_c)|``, the last term the whole field's interval enclosure at
        ``z_c`` (``AffinePlant.p_offset``): the smaller of the two per state is taken. ``B``
        is found by bootstrapping: if the period's tube computed with the bound of ``B``
        lies in ``B``'s interior, every trajectory stays in ``B`` over the period (at the
        first time one would leave ``B`` it is still in the tube, inside the interior: a
        contradiction), so the bound holds (docs/verification.md, "Uncertain parameters").
        False when no such ``B`` is found in a few rounds.
        """
        pl = self.plant
        self._prad = np.zeros(self.n)
        _, _, _, slo, shi, u_lo, u_hi = self._segments(s, i, taus)
        lo, hi = slo.min(axis=0), shi.max(axis=0)
        wterm = pl.dE @ pl.w_abs if pl.w_abs is not None and pl.w_abs.size else 0.0
        wbox = self.problem.plant.disturbances
        if wbox is not None:  # the disturbance box about its centre
            wc, wr = _mid_rad(np.asarray(wbox.lower, float), np.asarray(wbox.upper, float))
        else:
            wc, wr = np.zeros(0), np.zeros(0)
        for _ in range(8):
            pad = 0.25 * (hi - lo) + 1e-9 * (1.0 + np.abs(lo) + np.abs(hi))
            blo, bhi = lo - pad, hi + pad
            xa = np.maximum(np.abs(blo), np.abs(bhi))
            xc, xr = _mid_rad(blo, bhi)
            if self.hold == "zoh":  # the held input: from the sample, this period's B aside
                ua = np.maximum(np.abs(u_lo), np.abs(u_hi)).max(axis=0)
                uc, ur = _mid_rad(u_lo.min(axis=0), u_hi.max(axis=0))
            else:  # u = F (x + v) + G over B
                F = self.law.F[i][:, : self.n]
                uc = F @ xc + self.Gn[i]
                if self.d > self.n:  # (not reached: theta laws are verified under zoh)
                    raise _NeedExactError
                ur = ((np.abs(F) @ xr + self._noise_input(i)) * (1.0 + 1e-12)
                      + 1e-12 * (np.abs(F) @ np.abs(xc) + np.abs(self.Gn[i])))
                ua = (np.abs(uc) + ur) * (1.0 + 1e-12)
            about0 = pl.dA @ xa + pl.dB @ ua + wterm + pl.dc
            if pl.p_offset is not None:  # centred: the parameters' effect at z_c is exact-ish
                centred = pl.dA @ xr + pl.dB @ ur + pl.dE @ wr + pl.p_offset(xc, uc, wc)
                about0 = np.minimum(about0, centred)
            self._prad = about0 * (1.0 + 1e-12) + 1e-300
            _, _, _, slo, shi, _, _ = self._segments(s, i, taus)
            nlo, nhi = slo.min(axis=0), shi.max(axis=0)
            if np.all(nlo > blo) and np.all(nhi < bhi):
                return True
            lo, hi = np.minimum(lo, nlo), np.maximum(hi, nhi)
        return False

    def _period(self, s: _Star, i: int) -> _Star | None:
        """Propagate star s (at sample k, in region i) through one period; check it."""
        # (where a limit stops the run, in its message)
        self._region, self._t_now, self._sample = i, s.k * self.Ts, s.k
        t_k = s.k * self.Ts
        tau_end = min(self.Ts, self.T - t_k)
        taus = _grid(tau_end, self.step)
        if self.param and not self._param_bound(s, i, taus):
            # the parameters' effect could not be bounded over this period: an a-priori
            # enclosure that did not close (the tube stops holding this branch)
            self.findings.append(Finding(
                "enclosure", -1, t_k, None,
                f"at t = {t_k:.6g} the uncertain parameters' effect over the sample period "
                "could not be bounded (no box around the period's tube closed in 8 rounds); "
                "the tube of that branch ends there: narrow plant.parameters or "
                "verify.initial_set"))
            return None
        self._held_ok, self._ubounds = False, (self.u_min, self.u_max)
        if self.check_u and self.hold == "zoh":
            self._ubounds = self._region_u(i)[2:]
        X, W, err, slo, shi, u_lo, u_hi = self._segments(s, i, taus)
        if self.check_u and self.hold == "zoh":
            # the held input does not change over the period: no time refinement can
            # change its check, so it is decided here, once (docs/verification.md)
            umin, umax = self._ubounds
            self._held_ok = bool(np.all(u_lo[0] >= umin) and np.all(u_hi[0] <= umax))
            if not self._held_ok:
                f = self._held_violation(s, i, t_k, err[0], u_lo[0], u_hi[0])
                self._held_ok = True  # decided: the segments check the states alone
                if f.alpha is not None:
                    self.findings.append(f)
                    branch = self.stats["branches"]
                    t0 = np.full(len(taus) - 1, t_k) + taus[:-1]
                    self.tubes.append(Tube(t0, t0 + np.diff(taus), slo, shi,
                                           np.full(len(taus) - 1, branch)))
                    return None
                self.findings.append(f)
        bad = self._bad_segments(slo, shi, u_lo, u_hi)
        t0 = np.full(len(taus) - 1, t_k) + taus[:-1]
        t1 = np.full(len(taus) - 1, t_k) + taus[1:]
        keep = ~bad
        branch = self.stats["branches"]
        self.tubes.append(
            Tube(t0[keep], t1[keep], slo[keep], shi[keep], np.full(int(keep.sum()), branch))
        )
        self._tick(int(keep.sum()), s.k + 1, t_k + tau_end)
        # the times of this period found free of exact violations: adjacent suspicious
        # segments share an end, and a refinement's first end is its parent's
        self._no_violation = set()
        for j in np.flatnonzero(bad):
            if not self._resolve(s, i, taus[j], taus[j + 1], 0, slo[j], shi[j], branch):
                return None
        if t_k + tau_end >= self.T - 1e-12:
            return None
        if self.uncertain:
            return self._next_disturbed(s, i, taus[-1:], X[-1], W[-1])
        if self.d > self.n:
            return self._next_theta(s, i, X[-1], W[-1], err[-1])
        return _Star(X[-1], W[-1], s.H, s.h, s.verts, err[-1], s.k + 1, s.path, s.exact)

    def _next_disturbed(self, s: _Star, i: int, tau: np.ndarray, X: np.ndarray,
                        W: np.ndarray) -> _Star:
        """The star at the next sample with the disturbance's part as generators.

        ``x = Phi (star + e + Gw beta) + g + d``: the rounding ``e`` is propagated as in
        :meth:`_images`, the generators exactly (``Phi Gw``, its rounding into ``eround``),
        and this period's ``d``, ``|d| <= D(T)``, becomes ``n`` new generators
        ``diag(D(T))``; beyond ``4 d`` generators the smallest are boxed into ``eround``.
        """
        Phi, g, Pm, gm = self._flow(i, tau)
        Phi, Pm, gm = Phi[0], Pm[0], gm[0]
        base = s.err if s.Gw is None else s.eround
        er = ((np.abs(Phi) + _REL * Pm) @ base
              + _REL * (Pm @ np.abs(s.c) + (Pm @ np.abs(s.V)).sum(axis=1) + gm) + 1e-300)
        D = self._disturbance(i, tau)[0]
        cols = [np.diag(D)]
        if s.Gw is not None:
            er = er + _REL * (Pm @ np.abs(s.Gw)).sum(axis=1)
            cols.insert(0, Phi @ s.Gw)
        Gx = np.hstack(cols)  # (n, g)
        if self.d > self.n:  # theta = (x, u_prev, r): the held input and r take their parts
            n, m = self.n, self.m
            F, G = self.law.F[i], self.Gn[i]
            nd = self.n  # the new columns (this period's d) touch x only
            Gs = s.Gw if s.Gw is not None else np.zeros((self.d, 0))
            rows_G, rows_e = [Gx], [er]
            if self.problem.mpc.has_rates:
                uG = np.hstack([F @ Gs, np.zeros((m, nd))])
                ue = (np.abs(F) @ base + _REL * (np.abs(F) @ np.abs(s.c)
                      + (np.abs(F) @ np.abs(s.V)).sum(axis=1) + np.abs(G)
                      + (np.abs(F) @ np.abs(Gs)).sum(axis=1)) + 1e-300
                      + self._noise_input(i))  # the held input saw the noise too
                rows_G.append(uG)
                rows_e.append(ue)
            r0 = n + (m if self.problem.mpc.has_rates else 0)
            rows_G.append(np.hstack([Gs[r0:], np.zeros((self.d - r0, nd))]))
            rows_e.append(base[r0:])
            Gx, er = np.vstack(rows_G), np.concatenate(rows_e)
            uc = F @ s.c + G
            parts_c = [X] + ([uc] if self.problem.mpc.has_rates else []) + [s.c[r0:]]
            parts_V = [W] + ([F @ s.V] if self.problem.mpc.has_rates else []) + [s.V[r0:]]
            X, W = np.concatenate(parts_c), np.vstack(parts_V)
        limit = 4 * Gx.shape[0]
        if Gx.shape[1] > limit:  # box the smallest generators (Girard's order)
            score = np.abs(Gx).sum(axis=0) - np.abs(Gx).max(axis=0)
            order = np.argsort(score)
            drop = order[: Gx.shape[1] - limit]
            er = er + np.abs(Gx[:, drop]).sum(axis=1) * (1.0 + 1e-12)
            Gx = Gx[:, np.sort(order[Gx.shape[1] - limit :])]
        err = (er + np.abs(Gx).sum(axis=1)) * (1.0 + 1e-12)
        return _Star(X, W, s.H, s.h, s.verts, err, s.k + 1, s.path, s.exact, Gx, er)

    def _next_theta(self, s: _Star, i: int, X: np.ndarray, W: np.ndarray, err: np.ndarray
                    ) -> _Star:
        """theta at the next sample: (x(T), the input just held, r) -- exact affine maps.

        The held input ``u = F_i theta + G_i`` is affine in alpha; its rounding error is
        bounded like the flow's (``|F| err`` propagated, ``_REL`` of the terms added).
        """
        n, m = self.n, self.m
        F, G = self.law.F[i], self.Gn[i]
        parts_c, parts_V, parts_e = [X], [W], [err]
        if self.problem.mpc.has_rates:
            uc = F @ s.c + G
            uV = F @ s.V
            ue = (np.abs(F) @ s.err + _REL * (np.abs(F) @ np.abs(s.c)
                  + (np.abs(F) @ np.abs(s.V)).sum(axis=1) + np.abs(G)) + 1e-300)
            parts_c.append(uc)
            parts_V.append(uV)
            parts_e.append(ue)
        r0 = n + (m if self.problem.mpc.has_rates else 0)
        parts_c.append(s.c[r0:])
        parts_V.append(s.V[r0:])
        parts_e.append(s.err[r0:])
        return _Star(np.concatenate(parts_c), np.vstack(parts_V), s.H, s.h, s.verts,
                     np.concatenate(parts_e), s.k + 1, s.path, s.exact)

    def _resolve(self, s, i, ta, tb, depth, blo, bhi, branch) -> bool:
        """Decide a suspicious segment: exact violation, or refine it in time.

        Returns False when a concrete violation was found (the branch stops).
        """
        t_k = s.k * self.Ts
        for tau in (ta, tb):
            if float(tau) in self._no_violation:
                continue  # (the same star, region and time: the same answer)
            f = self._exact_violation(s, i, tau, t_k + tau)
            if f is None:
                self._no_violation.add(float(tau))
            if f is not None and not s.exact and self.uncertain:
                # a point of a hull (a merge, a region's cut of a disturbed star: state
                # coordinates, no initial state): a possible violation only, which the
                # concrete searches decide
                f = Finding(f.kind, f.index, f.t, None)
            if f is not None:
                self.findings.append(f)
                self.tubes.append(
                    Tube(
                        np.array([t_k + ta]),
                        np.array([t_k + tb]),
                        blo[None],
                        bhi[None],
                        np.array([branch]),
                    )
                )
                return False
        # a merged set is an over-approximation: refining it in time cannot remove what it
        # adds, so it gets few levels (the exact run decides what it cannot)
        # (so does a disturbance's box: time refinement shrinks the interpolation error,
        # not the disturbance's part of the set)
        exact = s.exact and not self.uncertain
        limit = self.max_depth if exact else min(self.max_depth, _MERGED_DEPTH)
        if depth >= limit:
            if exact:
                self.findings.append(Finding("max_depth", -1, t_k + ta, None))
            else:
                # (refining a merged or disturbed set in time cannot remove what the merge
                # or the disturbance adds: max_depth is not what stopped it)
                self.findings.append(Finding(
                    "over_approximation", -1, t_k + ta, None,
                    f"at t = {t_k + ta:.6g} the over-approximation (a merged or disturbed "
                    f"reach set) {self._meets(blo, bhi)} on [{t_k + ta:.6g}, {t_k + tb:.6g}] after "
                    f"{limit} time refinements (at most {_MERGED_DEPTH} for such a set: "
                    "they cannot remove the merge's or the disturbance's part)"))
            self.tubes.append(
                Tube(
                    np.array([t_k + ta]),
                    np.array([t_k + tb]),
                    blo[None],
                    bhi[None],
                    np.array([branch]),
                )
            )
            return True
        self.stats["refinements"] += 1
        taus = np.linspace(ta, tb, 5)
        _, _, _, slo, shi, u_lo, u_hi = self._segments(s, i, taus)
        bad = self._bad_segments(slo, shi, u_lo, u_hi)
        keep = ~bad
        self.tubes.append(
            Tube(
                t_k + taus[:-1][keep],
                t_k + taus[1:][keep],
                slo[keep],
                shi[keep],
                np.full(int(keep.sum()), branch),
            )
        )
        for j in np.flatnonzero(bad):
            if not self._resolve(s, i, taus[j], taus[j + 1], depth + 1, slo[j], shi[j], branch):
                return False
        return True

    # ---- samples: domain check and split --------------------------------------------

    def _split(self, s: _Star) -> list[tuple[int, _Star]] | Finding:
        """Children of s, one per region it meets, or a Finding if it leaves the domain.

        With measurement noise, one child per region that the star's Minkowski sum with
        the noise box meets: the child holds the states whose measurement may select it.
        """
        self._region, self._t_now, self._sample = None, s.k * self.Ts, s.k
        Y = s.c[None, :] + s.verts @ s.V.T
        lo = Y.min(axis=0) - s.err
        hi = Y.max(axis=0) + s.err
        if self.vr is not None:  # what the law may see: theta + v
            lo, hi = lo + self.vc - self.vr, hi + self.vc + self.vr
        law = self.law
        t = s.k * self.Ts
        # (the law's domain near the set, and its regions meeting it: a law computed on
        # demand computes them now, law_on_demand.py)
        domain = law.domain_rows(lo, hi)
        cand = law.regions_meeting(lo, hi)
        self._law_grown()
        if domain is not None and domain[0].shape[0]:
            A, b = domain
            # (with noise: the largest A v over the box, so any measurement that may leave)
            viol = Y @ A.T + (np.abs(A) @ s.err)[None, :] - b[None, :]
            if self.vr is not None:
                viol = viol + (A @ self.vc + np.abs(A) @ self.vr)[None, :] * (1.0 + 1e-12)
            if np.max(viol) > 0:
                # (a measured state that may leave the domain is no concrete violation: the
                # concrete search decides, under noise sequences.) The star's points may be
                # its bounding box's corners (the vertex enumeration's fallback), which are
                # no states: an exit is exact only when an LP over the polytope attains it
                alpha, worst = None, float(np.max(viol))
                if self.vr is None:
                    alpha, worst = self._exit(s, A, b, viol)
                if alpha is not None:
                    return Finding("undefined", -1, t, alpha)
            if np.max(viol) > 0 and worst is not None:
                # only the over-approximation leaves the domain: say so, and go on with the
                # part inside the regions so the tube still holds every trajectory for as
                # long as its law is defined
                self.findings.append(Finding(
                    "undefined", -1, t, None,
                    f"at t = {t:.6g} the reach set's over-approximation may leave the law's "
                    f"domain by {worst:.3g} (no state of it is shown to); the tube goes on "
                    "with its part inside the regions"))
        children = []
        # a disturbed star's generators are not tied to alpha: cutting alpha alone would keep
        # the whole disturbance box in every child (and the law's value over it). Where a
        # region cuts such a star, the child is the star's state polytope (its template hull,
        # exact support of the generators) cut by the region's rows (docs/verification.md)
        cut_state = s.Gw is not None and self.d == self.n
        for r in cand:
            A, b = law.A[r], law.b[r]
            if cut_state:
                # (only which way to cut: both are sound)
                top = (Y @ A.T).max(axis=0) + np.abs(A @ s.Gw).sum(axis=1) + np.abs(A) @ s.eround
                if np.any(top > self._reach_rows(A, b)):  # the region cuts the star
                    self.stats["state_cuts"] = self.stats.get("state_cuts", 0) + 1
                    child = self._cut_hull(s, int(r))
                    if child is not None:
                        children.append((int(r), child))
                    continue
            Hn = A @ s.V
            hn = self._reach_rows(A, b) - A @ s.c + np.abs(A) @ s.err + 1e-9
            # P lies in the hull of s.verts: a row of the region that every one of them
            # violates (beyond the products' rounding) leaves no point of P in the region,
            # the piece is empty (no LP needed; as the nonlinear engine's split)
            VH = s.verts @ Hn.T  # (nv, rows)
            over = VH.min(axis=0) - hn
            if np.any(over > 1e-12 * (1.0 + (np.abs(s.verts) @ np.abs(Hn).T).max(axis=0)
                                      + np.abs(hn))):
                continue
            exact = s.exact
            try:
                piece = checked_piece(np.vstack([s.H, Hn]), np.concatenate([s.h, hn]))
            except ValueError:
                # the vertex enumeration could not close the cut polytope (degenerate
                # rows): keep the uncut one, a superset, and no longer call it exact
                piece, exact = (s.H, s.h, s.verts), False
            if piece is None:
                continue
            H, h, verts = piece
            children.append(
                (int(r), _Star(s.c, s.V, H, h, verts, s.err, s.k, s.path + (int(r),), exact,
                               s.Gw, s.eround))
            )
        if not children:
            self.findings.append(Finding(
                "undefined", -1, t, None,
                f"at t = {t:.6g} the reach set's over-approximation meets no region of the "
                "law (no piece of it is left after the regions' cuts); the tube of that "
                "branch ends there"))
        return children

    def _exit(self, s: _Star, A: np.ndarray, b: np.ndarray, viol: np.ndarray
              ) -> tuple[np.ndarray | None, float]:
        """Does a state of the star leave the domain ``{A x <= b}``? LPs over its polytope.

        For each row some point of the star's over-approximation violates (largest first):
        the largest ``A_r (c + V a) - b_r`` over ``H a <= h``. An exit is exact when it
        exceeds ten times the star's error plus the locator's tolerance (``1e-9 |A_r|``)
        at a point ``a`` of the polytope (checked):
        returns that ``a`` and the LP's largest violation; ``(None, None)`` when every such
        row's maximum, widened by the star's error and the LP's accuracy (1e-9 of the
        terms), is within its bound: no state leaves (the points were loose, e.g. the
        corners of a bounding box); else ``(None, largest)``, a possible exit.
        """
        top = viol.max(axis=0)
        rows = np.argsort(-top)
        rows = rows[top[rows] > 0]
        margin = 10 * float(np.max(s.err)) + 1e-12
        worst = -np.inf
        inside = True  # every flagged row's LP maximum, widened, is within its bound
        for r in rows:
            a, st, _ = solve_lp(-(A[r] @ s.V), s.H, s.h)
            if st != "optimal" or not np.all(s.H @ a <= s.h + 1e-9 * (1 + np.abs(s.h))):
                inside = False
                continue
            AV = A[r] @ s.V
            gap = float(A[r] @ (s.c + s.V @ a) - b[r])
            worst = max(worst, gap)
            # (within the locator's 1e-9 of the row a state still gets a region, so the
            # simulation would not reproduce that exit: a possible one at most)
            if gap > margin + 1e-9 * float(np.linalg.norm(A[r])):
                return a, gap
            # the LP's accuracy (1e-9 of the terms) and the star's error
            pad = (float(np.abs(A[r]) @ s.err)
                   + 1e-9 * (1 + abs(b[r]) + np.abs(A[r]) @ np.abs(s.c) + np.abs(AV) @ np.abs(a)))
            inside = inside and gap + pad <= 0
        if inside:
            return None, None
        return None, float(worst if np.isfinite(worst) else viol.max())

    def run(self) -> None:
        """Explore every branch; results in ``self.tubes`` and ``self.findings``.

        First with merging and invariance certificates (:meth:`_run_merged`); when that
        meets a possible violation on a merged set, again exactly (every branch kept).
        """
        #: a re-anchored candidate's anchor while it runs, a certificate closed behind it
        self._reanchored: dict | None = None
        self._limited(self._run)
        behind = self._reanchored
        if behind is not None and self.findings and all(
                f.kind in ("limit", "budget") for f in self.findings):
            # a limit or the budget stopped the run from a re-anchored set: the certificate
            # that closed before it holds (re-anchoring never costs a verdict)
            self.findings = []
            self.stats.pop("complete_until", None)
            self._close_previous(behind)

    def _run(self) -> None:
        if (self.merge or self.unbounded) and self.d == self.n:
            try:
                self._run_merged()
                return
            except _NeedExactError:
                if self.unbounded or self.uncertain:
                    # (with a disturbance the exact exploration is no more exact than the
                    # merged one -- its sets carry the disturbance's box -- and its branches
                    # multiply: a possible violation stays possible, the verdict unknown)
                    t = getattr(self, "_t_now", 0.0)
                    if not self.findings:
                        self.findings.append(Finding(
                            "max_depth", -1, t, None,
                            f"at t = {t:.6g} a merged set could not be formed; the tube "
                            "ends there"))
                    # the merged run stopped at this sample: every trajectory is in the
                    # tube up to it, not after (the verdict's detail says so)
                    self.stats["complete_until"] = self._complete_until(t)
                    return
                self.stats["merged_attempt"] = {
                    k: self.stats[k] for k in ("branches", "refinements")
                }
                self.tubes, self.findings, self.boxes = [], [], 0
                self.stats.update(branches=0, refinements=0)
                self.stats.pop("certificate", None)
        self._run_exact()

    def _run_exact(self) -> None:
        """Every branch explored separately (depth first), nothing merged."""
        n = self.d  # alpha: the coordinates of the initial theta box
        H0 = np.vstack([np.eye(n), -np.eye(n)])
        h0 = np.ones(2 * n)
        verts0 = box_corners(-np.ones(n), np.ones(n))  # P's vertices, exact
        stack = [_Star(self.c0.copy(), self.V0.copy(), H0, h0, verts0, np.zeros(n), 0)]
        self._pending = stack  # (what a limit leaves unexplored: stats["complete_until"])
        while stack:
            s = stack.pop()
            out = self._split(s)
            if isinstance(out, Finding):
                self.findings.append(out)
                if out.alpha is not None:
                    return
                continue
            for i, child in out:
                self.stats["branches"] += 1
                nxt = self._period(child, i)
                if any(f.alpha is not None for f in self.findings):
                    return
                if nxt is not None:
                    stack.append(nxt)


    # ---- merging and invariance certificates --------------------------------------------

    def _directions(self, members: list[_Star], i: int | None) -> np.ndarray:
        """Unit directions (k, n) of a merged set's template: the axes, the pairwise
        diagonals, region i's rows (if any) and the members' own facets (in state
        coordinates)."""
        n = self.n
        eye = np.eye(n)
        rows = [eye, -eye]
        for a, b in itertools.combinations(range(n), 2):
            for sg in (1.0, -1.0):
                d = (eye[a] + sg * eye[b]) / np.sqrt(2.0)
                rows += [d[None], -d[None]]
        if i is not None:
            rows.append(self.law.A[i])
        for s in members:
            if not s.exact:
                rows.append(s.H)
            elif np.linalg.cond(s.V) < 1e8:
                rows.append(s.H @ np.linalg.inv(s.V))  # any direction is sound
            if s.Gw is not None:  # a disturbed star: its facets and its zonotope's
                if not s.exact and np.linalg.cond(s.V) < 1e8:
                    rows.append(s.H @ np.linalg.inv(s.V))
                rows.append(_zonotope_normals(s.Gw))
        D = np.vstack(rows)
        D = D / np.maximum(np.linalg.norm(D, axis=1, keepdims=True), 1e-300)
        _, keep = np.unique(np.round(D, 6), axis=0, return_index=True)
        return D[np.sort(keep)]

    def _hull(
        self, members: list[_Star], i: int | None, extra: np.ndarray | None = None
    ) -> _Star:
        """One set in region i containing every member (and the points ``extra``); with
        ``i`` None, not cut by a region (a set at a sample, before its split).

        The template polytope ``{x : d' x <= e_d}``: ``e_d`` is the largest value of
        ``d' x`` over the members' vertices widened by their error boxes and by the rounding
        of the vertex images and of the products (1e-12 relative, far above it), so every
        point of every member satisfies every row; cut by region i's rows (+1e-9, as a
        split): the members' states that use law i are in the region. The result is in
        state coordinates (``c = 0``, ``V = I``, no error) and not ``exact``.
        """
        D = self._directions(members, i)
        absD = np.abs(D)
        e = np.full(D.shape[0], -np.inf)
        mag = np.zeros(D.shape[0])
        for s in members:
            X = s.c[None, :] + s.verts @ s.V.T  # (nv, n)
            pad = _REL * (np.abs(s.c)[None, :] + np.abs(s.verts) @ np.abs(s.V).T)
            if s.Gw is None:
                pad = pad + s.err
                e = np.maximum(e, (X @ D.T + pad @ absD.T).max(axis=0))
            else:  # the disturbance's part: its exact support, |d' Gw| 1 + |d|' eround
                zs = np.abs(D @ s.Gw).sum(axis=1) * (1.0 + 1e-12) + absD @ s.eround
                e = np.maximum(e, (X @ D.T + pad @ absD.T).max(axis=0) + zs)
                pad = pad + s.err
            mag = np.maximum(mag, ((np.abs(X) + pad) @ absD.T).max(axis=0))
        if extra is not None:
            e = np.maximum(e, (extra @ D.T).max(axis=0))
            mag = np.maximum(mag, (np.abs(extra) @ absD.T).max(axis=0))
        e = e + _REL * (1.0 + mag) + 1e-300
        if i is not None:
            A, b = self.law.A[i], self.law.b[i]
            D, e = np.vstack([D, A]), np.concatenate([e, self._reach_rows(A, b) + 1e-9])
        piece = checked_piece(D, e)
        if piece is None:  # cannot happen for non-empty members; never drop a set
            raise _NeedExactError
        H, h, verts = piece
        n = self.n
        k = members[0].k
        path = () if i is None else (i,)
        return _Star(np.zeros(n), np.eye(n), H, h, verts, np.zeros(n), k, path, exact=False)

    def _cut_hull(self, s: _Star, i: int) -> _Star | None:
        """The part of disturbed star s in region i as a star in state coordinates: its
        template hull (:meth:`_hull`, the generators' exact support) cut by region i's rows
        (+1e-9); None when that is empty (the star misses the region)."""
        beat("a disturbed set cut by a region")
        D = self._directions([s], i)
        absD = np.abs(D)
        X = s.c[None, :] + s.verts @ s.V.T
        pad = _REL * (np.abs(s.c)[None, :] + np.abs(s.verts) @ np.abs(s.V).T)
        zs = np.abs(D @ s.Gw).sum(axis=1) * (1.0 + 1e-12) + absD @ s.eround
        e = (X @ D.T + pad @ absD.T).max(axis=0) + zs
        mag = ((np.abs(X) + pad + s.err) @ absD.T).max(axis=0)
        e = e + _REL * (1.0 + mag) + 1e-300
        A, b = self.law.A[i], self.law.b[i]
        piece = _tight_piece(np.vstack([D, A]),
                             np.concatenate([e, self._reach_rows(A, b) + 1e-9]))
        if piece is None:
            return None
        H, h, verts = piece
        n = self.n
        return _Star(np.zeros(n), np.eye(n), H, h, verts, np.zeros(n), s.k, s.path + (i,),
                     exact=False)

    def _inside(self, s: _Star, S: _Star) -> bool:
        """Is every point of star s (its error box included) in the merged set S?

        S is in state coordinates (``H x <= h``); s lies in the hull of its vertex images
        widened by its error box and their rounding, and a polytope contains a convex hull
        when it contains the points.
        """
        X = s.c[None, :] + s.verts @ s.V.T
        pad = _REL * (np.abs(s.c)[None, :] + np.abs(s.verts) @ np.abs(s.V).T) + s.err
        absH = np.abs(S.H)
        vals = X @ S.H.T + pad @ absH.T + _REL * (1.0 + np.abs(X) @ absH.T)
        return bool(np.all(vals <= S.h[None, :]))

    def _anchor(self, frontier: list[_Star]) -> _Star:
        """A set containing every set of the sample and a small box around the MPC's
        operating point (where the loop is steered): the candidate invariant set."""
        lo = np.min([(s.c[None, :] + s.verts @ s.V.T).min(axis=0) - s.err for s in frontier], 0)
        hi = np.max([(s.c[None, :] + s.verts @ s.V.T).max(axis=0) + s.err for s in frontier], 0)
        xs = np.asarray(self.problem.model.x_op, float)
        delta = 0.05 * (np.maximum(hi, xs) - np.minimum(lo, xs)) + 1e-9 * (1.0 + np.abs(xs))
        return self._hull(frontier, None, extra=box_corners(xs - delta, xs + delta))

    def _reanchor(self, anchor: dict, frontier: list[_Star], k: int,
                  done: int) -> _Star | None:
        """A tighter candidate set than the anchor's, from the sets at sample ``k`` (which
        lie in it), or None to close the certificate now.

        The tube repeated by a certificate is the anchor set's own transient, so an anchor
        taken while the sets still converge (a wide ``S``) repeats that width up to the
        horizon (``"inf"``: the band of :func:`~codev_engine.reach.claim.certificate_band`
        is that width). The loop goes on from the sets at ``k`` anchored again, while that
        set's box is at most ``_REANCHOR_SHRINK`` (nominal: ``_REANCHOR_SHRINK_NOMINAL``)
        of the anchor's along some axis, at most
        ``_REANCHORS`` times and while ``_ANCHOR_MIN_SAMPLES`` remain (docs/verification.md,
        "Merging and invariance certificates"); nominal runs too (their sets shrink toward
        the operating point, the early anchor's saw-tooth does not).
        """
        remaining = (self.T - k * self.Ts) / self.Ts
        if done >= _REANCHORS or remaining < _ANCHOR_MIN_SAMPLES:
            return None
        S2 = self._anchor(frontier)
        old, new = (np.ptp(S.c[None, :] + S.verts @ S.V.T, axis=0) + 2.0 * S.err
                    for S in (anchor["S"], S2))
        shrink = _REANCHOR_SHRINK if self.uncertain else _REANCHOR_SHRINK_NOMINAL
        if not np.any(new <= shrink * old):
            return None
        return S2

    def _close(self, anchor: dict, k: int) -> None:
        """Every set at sample k lies in the anchor's set S (sample ka < k): the tube of
        [t_ka, t_k] repeats with period (k - ka) Ts up to the horizon (docs/verification.md,
        "Invariance certificates")."""
        self._reanchored = None  # (closed: nothing to fall back to)
        ka = anchor["k"]
        L = (k - ka) * self.Ts
        t_k = k * self.Ts
        self.stats["certificate"] = {
            "kind": "invariant",
            "anchor_sample": int(ka),
            "closed_sample": int(k),
            "anchor_time": float(ka * self.Ts),
            "closed_time": float(t_k),
            "period": float(L),
        }
        # what the containment rests on, for an independent re-check (verification.py):
        # the anchor's rows and the sets' points widened by what _inside widens them by
        S = anchor["S"]
        pts, pads = [], []
        for s in anchor["closing"]:
            X = s.c[None, :] + s.verts @ s.V.T
            pad = _REL * (np.abs(s.c)[None, :] + np.abs(s.verts) @ np.abs(s.V).T) + s.err
            pts.append(X)
            pads.append(pad + _REL * (1.0 + np.abs(X)))
        self.certificate = {
            "H": S.H.copy(),
            "h": S.h.copy(),
            "points": np.vstack(pts),
            "pads": np.vstack(pads),
        }
        if self.unbounded or t_k >= self.T:
            return
        seg = Tube.concatenate(self.tubes[anchor["ntubes"] :], self.n)
        copies = int(np.ceil((self.T - t_k) / L - 1e-12))
        shift = np.repeat(np.arange(1, copies + 1) * L, seg.num_boxes)
        t0 = np.tile(seg.t_start, copies) + shift
        t1 = np.tile(seg.t_end, copies) + shift
        keep = t0 < self.T
        self.tubes.append(
            Tube(
                t0[keep],
                np.minimum(t1[keep], self.T),
                np.tile(seg.lower, (copies, 1))[keep],
                np.tile(seg.upper, (copies, 1))[keep],
                np.tile(seg.branch, copies)[keep],
            )
        )

    def _close_previous(self, anchor: dict) -> None:
        """Undo a re-anchored candidate (``anchor``: its tube dropped) and close the
        certificate that closed at its sample instead (``_reanchor``)."""
        del self.tubes[anchor["ntubes"]:]
        self._close(anchor["closed"], anchor["k"])

    def _run_merged(self) -> None:
        """Breadth first over samples; the sets of a sample that lie in one region become
        one (``_hull``), and a set anchored at an attracting fixed point is checked for an
        invariance certificate at every later sample.

        Raises ``_NeedExactError`` at a possible violation on a merged set (the exact run
        decides); a possible violation after an anchor first undoes the anchor.
        """
        n = self.n
        H0 = np.vstack([np.eye(n), -np.eye(n)])
        frontier = [
            _Star(self.c0.copy(), self.V0.copy(), H0, np.ones(2 * n),
                  box_corners(-np.ones(n), np.ones(n)), np.zeros(n), 0)
        ]
        anchor: dict | None = None
        next_try, attempts, reanchors = 1, 0, 0
        while frontier:
            k = frontier[0].k
            # (sample by sample: a stop leaves the tube complete up to this sample)
            self._pending = frontier
            if anchor is not None and k > anchor["k"]:
                if all(self._inside(s, anchor["S"]) for s in frontier):
                    anchor["closing"] = frontier  # (closed: the sets its certificate holds)
                    S2 = self._reanchor(anchor, frontier, k, reanchors)
                    if S2 is None:
                        self._close(anchor, k)
                        return
                    # the tube of [t_ka, t_k] from S stays (it holds every trajectory);
                    # the loop goes on from the tighter S2, a new candidate; the closed
                    # certificate is kept should S2's fail
                    reanchors += 1
                    anchor = {"k": k, "S": S2, "ntubes": len(self.tubes),
                              "frontier": frontier, "closed": anchor}
                    self._reanchored = anchor
                    frontier = [S2]
                elif k - anchor["k"] > _ANCHOR_BUDGET:
                    if "closed" in anchor:
                        self._close_previous(anchor)
                        return
                    anchor, next_try = None, k + 10  # keep the (sound, wider) sets
            remaining = (self.T - k * self.Ts) / self.Ts
            if (
                anchor is None
                and k >= next_try
                and attempts < _ANCHOR_ATTEMPTS
                and remaining >= _ANCHOR_MIN_SAMPLES
            ):
                attempts += 1
                S = self._anchor(frontier)
                anchor = {"k": k, "S": S, "ntubes": len(self.tubes), "frontier": frontier}
                frontier = [S]
            groups: dict[int, list[_Star]] = {}
            failed = False
            for s in frontier:
                out = self._split(s)
                if isinstance(out, Finding):
                    self.findings.append(out)
                if self.findings:
                    failed = True
                    break
                for i, child in out:
                    groups.setdefault(i, []).append(child)
            children = []
            if not failed:
                few = sum(len(g) for g in groups.values()) <= _MERGE_ABOVE
                for i, members in groups.items():
                    if few:  # few sets: kept exact (tighter, exact counterexamples)
                        children.extend((i, m) for m in members)
                    elif len(members) == 1:
                        children.append((i, members[0]))
                    else:
                        children.append((i, self._hull(members, i)))
                        self.stats["merges"] = self.stats.get("merges", 0) + len(members) - 1
            nexts = []
            if not failed:
                for i, child in children:
                    self.stats["branches"] += 1
                    nxt = self._period(child, i)
                    if self.findings:
                        failed = True
                        concrete = child.exact and all(
                            f.alpha is not None for f in self.findings
                        )
                        if concrete and anchor is None:
                            return  # a real counterexample (an exact star's initial state)
                        break
                    if nxt is not None:
                        nexts.append(nxt)
            if failed:
                if anchor is None:
                    raise _NeedExactError
                if "closed" in anchor:
                    # a re-anchored set met a possible violation: the certificate that
                    # closed before it holds (its tube is kept); close it
                    self.findings = []
                    self._close_previous(anchor)
                    return
                # undo the anchor: back to its sample; inflate again only later
                self.findings = []
                del self.tubes[anchor["ntubes"] :]
                next_try = k + 2 * (k - anchor["k"]) + 5
                frontier, anchor = anchor["frontier"], None
                continue
            frontier = nexts


#: samples an anchored set may take to return into itself before it is given up
_ANCHOR_BUDGET = 200
#: anchor only when at least this many samples remain (a short horizon needs no certificate)
_ANCHOR_MIN_SAMPLES = 20
#: the sets of a sample are merged by region only when there are more than this many
#: (fewer stay exact: tighter tubes and exact counterexamples)
_MERGE_ABOVE = 8
#: time refinements of a suspicious segment of a merged set
_MERGED_DEPTH = 2
#: anchors tried per run (each undone one costs the samples it ran)
_ANCHOR_ATTEMPTS = 5
#: with disturbances, noise or parameters, a closed anchor is taken again from the closing
#: sets (a tighter repeated tube) while their box is at most this share of the anchor's along
#: some axis, at most _REANCHORS times (_reanchor)
_REANCHOR_SHRINK = 0.9
#: the same for a nominal run, whose sets keep shrinking: a new anchor (its period run
#: again) only while it halves the width along some axis
_REANCHOR_SHRINK_NOMINAL = 0.5
_REANCHORS = 4


def _tight_piece(A: np.ndarray, b: np.ndarray) -> tuple | None:
    """``checked_piece`` of ``{x : A x <= b}`` without the rows that touch it in fewer than
    ``d`` vertices.

    A template has rows that only touch the polytope at a vertex (weakly redundant); they
    make ``checked_vertices`` doubt its enumeration and fall back to the bounding box.
    Dropping a row can only enlarge the set, so the result still holds it (sound), and a
    row on fewer than ``d`` vertices is no facet, so the set is the same.
    """
    piece = checked_piece(A, b)
    if piece is None:
        return None
    H, h, _ = piece
    d = H.shape[1]
    V = vertices(H, h, 1e-10)
    if V is None or V.shape[0] <= d:
        return piece
    keep = (np.abs(V @ H.T - h[None, :]) <= FACET_TOL).sum(axis=0) >= d
    if keep.all() or keep.sum() <= d:
        return piece
    return checked_piece(H[keep], h[keep]) or piece


def _zonotope_normals(G: np.ndarray, most: int = 8) -> np.ndarray:
    """Unit normals (k, n) of the facets spanned by the largest generators of ``G`` (n, g):
    for each ``n - 1`` of the ``most`` longest columns (``n + 1`` of them from n = 4 on: the
    template's vertex enumeration grows with its rows), the direction orthogonal to them
    (both signs). In the plane these are every facet of the zonotope (its edges are its
    generators), so a template over them and a polygon's facets holds their Minkowski sum
    exactly; any direction is sound."""
    n = G.shape[0]
    if n < 2 or G.shape[1] == 0:
        return np.zeros((0, n))
    if n >= 4:
        most = min(most, n + 1)
    order = np.argsort(-np.linalg.norm(G, axis=0))[:most]
    out = []
    for sub in itertools.combinations(order, n - 1):
        _, sv, vt = np.linalg.svd(G[:, list(sub)].T, full_matrices=True)
        if sv.size and sv[-1] <= 1e-12 * max(sv[0], 1e-300):
            continue  # dependent generators: no facet
        out += [vt[-1], -vt[-1]]
    return np.array(out).reshape(-1, n)


def _mid_rad(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The midpoint ``c`` of the box ``[lo, hi]`` (k,) as computed, and a radius ``r`` with
    ``|x - c| <= r`` for every ``x`` in the box despite the rounding of ``c`` and ``r``."""
    c = 0.5 * (lo + hi)
    return c, np.maximum(hi - c, c - lo) * (1.0 + 1e-12)


def _grid(tau_end: float, step: float) -> np.ndarray:
    k = max(1, int(np.ceil(tau_end / step - 1e-9)))
    taus = np.minimum(np.arange(k + 1) * step, tau_end)
    taus[-1] = tau_end
    return taus



def _box_meets(A: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Does the box [lo, hi] meet {A x <= b} (closed sets)?"""
    n = lo.shape[0]
    x, st, _ = solve_lp(np.zeros(n), A, b + 1e-12, lb=lo, ub=hi)
    return st == "optimal"
