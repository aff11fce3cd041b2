"""The nonlinear flow over one period: a set at a sample carried soundly to the next.

The reach set at a sample time is ``{y + D d + M e + r : d in P, |e|_2 <= 1}``: a centre
``y``, a *sensitivity* matrix ``D`` applied to the initial deviation ``d`` (a polytope ``P``
of the initial box's coordinates: exact star part), and a *remainder ellipsoid* ``M e``
that absorbs every error. Within a period (``N`` substeps of length ``h``) the deviation
from the centre is written ``x - y = Phi (D d + M e) + psi`` where ``Phi`` is the exact
flow of the centre's Jacobian ``Jc`` (matrix exponentials) and ``psi`` is a local
remainder bounded in the norm ``|v|_W = |W v|_2`` (see docs/verification.md for the
proofs):

1. **Centre**: a point trajectory ``y_j`` computed by RK4 (not rigorous) is validated
   substep by substep: the exact solution from ``y_j`` is enclosed at ``h`` by an interval
   Taylor step ``y_j + h f(y_j) + h^2/2 (J f)(B^c_j)`` (Lagrange remainder over its
   a-priori enclosure ``B^c_j``); its distance ``eps_j`` to ``y_{j+1}`` goes into ``psi``.
2. **A-priori enclosure** ``B_j``: a box with ``S_j + [0, h] f(B_j, U) subset B_j``
   (Picard-Lindeloef in interval arithmetic, ``S_j`` the box of the set at ``t_j``): every
   trajectory of the set stays in ``B_j`` over the substep. The tube's box is ``B_j``
   intersected with the linear part's bound: the centre's enclosure plus the star and the
   ellipsoid carried by ``Phi(t)`` over the substep (chord plus curvature) plus the ball.
3. **Deviation**: by the mean-value theorem ``d/dt (x - z) = Jbar (x - z)`` (+ the held
   input's deviation) with ``Jbar`` in the interval Jacobian over the hull of ``B_j`` and
   ``B^c_j``; the point part ``Jc`` drives ``Phi`` exactly, the spread ``E`` (|E| <= R)
   feeds ``|psi|_W`` through a Groenwall bound with the log-norm ``mu_W(Jc)``.
4. At the sample the ellipsoid is carried *exactly* through the linear part: the new
   remainder ellipsoid is an outer ellipsoid of ``Phi M e + psi`` (ellipsoid + ball).

All ``N`` substeps of a period are computed as batches (numpy arrays over substeps): the
local remainder profile ``rho_j`` is guessed, the enclosures are computed for the guessed
sets, and the guess is accepted only if the Groenwall bound it leads to stays below it at
every substep (induction over ``j``); otherwise the guess is raised and the period redone.

This module holds that step (``NonlinearFlow._period``) and what it is made of: the metric
``W``, the sets (``_Set``) and a period's record (``_Rec``), the interval evaluation of the
plant and of the law's input, the a-priori enclosures, the Jacobians, the validated centre
and the interval helpers. The driver that follows the sets from the initial set to the
horizon (region cuts, merges, re-rooting, the cells and their refinement) is
``reach/nonlinear.py`` (``NonlinearReach``).
"""

from __future__ import annotations

import warnings
from dataclasses import KW_ONLY, dataclass, field

import numpy as np
from scipy.linalg import expm, solve_continuous_lyapunov, solve_triangular

from codev_engine.geometry.polytope import solve_lp
from codev_engine.law import ExplicitLaw
from codev_engine.plant import field_uncertain, linearize, plant_model
from codev_engine.reach.carried import carried_zonotope, offset_zonotope
from codev_engine.reach.interval import IntervalDomainError
from codev_engine.reach.linear import ClosedLoopSetup, Finding, affine_range
from codev_engine.reach.matrix_bounds import (
    add_pad,
    down2,
    expabs_vec,
    gronwall,
    imat_add_point,
    imatvec,
    norm2,
    up2,
)
from codev_engine.reach.tube import Tube
from codev_engine.spec.problem import Problem

__all__ = ["NonlinearFlow"]

_REL = 1e-12
#: relative allowance for the rounding of matrix exponentials and small matrix products
#: (about 1e-15 relative at these sizes and step lengths)
_FPM = 1e-10
_U = 2.0**-53


@dataclass
class _Set:
    y: np.ndarray  # (n,) centre
    D: np.ndarray  # (n, n) sensitivity to the initial deviation
    M: np.ndarray  # (n, n) remainder ellipsoid {M e : |e|_2 <= 1}
    k: int  # sample index
    path: tuple[int, ...] = ()
    H: np.ndarray | None = None  # initial deviations d satisfy H d <= h ...
    h: np.ndarray | None = None
    V: np.ndarray | None = None  # ... a polytope with these vertices (nv, n)
    base: tuple | None = None  # polytope (H, h, V) this one was cut from (contains it)
    #: (n, k) generators of the disturbances' linear part ``{Z t : |t|_inf <= 1}`` added
    #: to the set at a sample (``_period``); folded into the star by ``_rerooted`` before
    #: the set is used (None: none)
    Z: np.ndarray | None = None
    #: with ``Z``: the remainder's two bounds at the sample, for ``_rerooted``'s support
    #: (``M`` holds ``PM e`` plus the ball): the carried ellipsoid ``PM`` (n, n), the
    #: ball's W-radius and the remainder's zonotope, offset (n,) and generators (n, k)
    #: (``_period``;
    #: docs/verification.md, "The remainder per axis"). None: ``M`` alone.
    rem: tuple[np.ndarray, float, np.ndarray, np.ndarray] | None = None

    @property
    def poly(self) -> tuple:
        return (self.H, self.h, self.V)

    def range(self, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """min and max of A D d over the deviation polytope (attained at vertices)."""
        vals = self.V @ (A @ self.D).T
        return vals.min(axis=0), vals.max(axis=0)

    def ell(self, A: np.ndarray) -> np.ndarray:
        """max of |a' M e| over the unit ball for each row a of A: |M' a|_2 (rounded up)."""
        return _ell_rows(A @ self.M)

    def mag(self) -> np.ndarray:
        """(n,) magnitudes bounding |D| |d| + |M| |e| (scale of the products' rounding)."""
        return np.max(np.abs(self.V) @ np.abs(self.D).T, axis=0) + np.abs(self.M).sum(axis=1)


def _ell_rows(AM: np.ndarray) -> np.ndarray:
    """Row norms (..., k, n) -> (..., k), with a margin for rounding."""
    return np.sqrt(np.einsum("...ij,...ij->...i", AM, AM)) * (1 + 1e-12) + 1e-300


@dataclass
class _Rec:
    """One period's sets at the substep starts, for property checks."""

    Y: np.ndarray  # (N, n) centres
    PD: np.ndarray  # (N, n, n) star matrices
    PM: np.ndarray  # (N, n, n) ellipsoid generators
    rho: np.ndarray  # (N,) local remainder radii (W-norm)
    swlo: np.ndarray  # (N, n) sweep [0, h] f(B) over the substep
    swhi: np.ndarray
    V: np.ndarray  # (nv, n) deviation polytope's vertices
    flo: np.ndarray  # (N, n) f over the substep's enclosure
    fhi: np.ndarray
    hs: np.ndarray  # (N,) substep lengths
    vmag: np.ndarray  # (N, n) magnitudes of the star's and ellipsoid's terms
    zsub: np.ndarray | None = None  # (N, n) box of the disturbances' linear part


@dataclass
class NonlinearFlow(ClosedLoopSetup):
    """One period of a nonlinear plant's closed loop: a set at a sample, in one region of the
    law, carried to the next sample with the tube's boxes over the period (see module
    docstring). The base of ``reach.nonlinear.NonlinearReach``, which drives it.

    ``_period(s, i)`` gives the next set, the period's tube, the findings (an enclosure
    that could not be established) and the record the property checks read
    (``_support``). ``__post_init__`` compiles the plant's enclosures once and sets the
    metric ``W`` (``_metric``), the step ``h`` and the substep ``h_sub``.

    Attributes
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
    hold : {"zoh", "continuous"}
        How the input is applied between samples: held at the sample's value, or the law
        evaluated continuously.
    stats : dict
        The driver's counters; ``stats["branches"]`` numbers the branch of a period's tube
        boxes.
    carry : bool
        Under disturbances or uncertain parameters, their first-order part is carried
        through the linear flow as a zonotope (``reach/carried.py``) and folded into the
        star at each sample; False: it goes into the remainder ball, as before.
    continuous_substeps : int
        With ``carry``, under the continuous hold: how many substeps each ``step`` is cut
        into (docs/verification.md, "The continuous hold's substep").
    """

    problem: Problem
    law: ExplicitLaw
    hold: str
    # (keyword-only: the driver's own fields, ``max_depth`` first, follow these positionally)
    _: KW_ONLY
    stats: dict = field(
        default_factory=lambda: {"branches": 0, "refinements": 0, "partitions": 0, "merges": 0}
    )
    #: with disturbances or uncertain parameters: their first-order part ``J_{w,p} (w -
    #: w_n, p - p_n)`` is carried through the linear flow as a zonotope
    #: (``reach/carried.py``) and folded into the star at each sample (docs/verification.md,
    #: "The disturbances' linear part"); with it the remainder is also bounded per axis
    #: (its second-order forcing carried as a zonotope about an offset, "The remainder per
    #: axis"); False: both go into the remainder ball, isotropic in ``W``, as before
    carry: bool = True
    #: with ``carry``, under the continuous hold: each ``step`` is cut into this many
    #: substeps (the remainder's curvature term squares the substep's a-priori deviation,
    #: which holds the set's and the centre's sweeps over it)
    continuous_substeps: int = 2

    def __post_init__(self) -> None:
        from codev_engine.reach.enclosure import (
            plant_enclosures,
            plant_hessian,
            uncertain_enclosures,
        )

        p = self.problem
        vs = p.verify
        # all compiled once per plant (the shared plant model) and reused by every run; with
        # disturbances or parameters, the field over (x, u, w, p) below instead
        uncertain = field_uncertain(p)  # (disturbances that cannot act: nominal)
        if not uncertain:
            self.enc = plant_enclosures(p)
            self.hess = plant_hessian(p)
        self._init_properties()
        # measurement noise (docs/verification.md, "Nonlinear plants with measurement
        # noise"): vc, vr, the offsets Gn = G + F vc (None: no noise, nothing changes)
        self._init_noise()
        # disturbances and uncertain parameters (docs/verification.md, "Nonlinear plants
        # with disturbances"): enclosures over (x, u, w, p), (w, p) appended to the input box
        self.xlo = self.xhi = self.xnom = self.xdev = None
        if uncertain:
            self.enc, self.hess, self.xlo, self.xhi, self.xnom = uncertain_enclosures(p)
            self.xdev = np.maximum(self.xhi - self.xnom, self.xnom - self.xlo) * (1 + 1e-12)
        self._fnum = plant_model(p).scalar_field  # the (non-rigorous) centre trajectory
        self.h = float(vs.step)
        # the substep of the enclosures: under the continuous hold with disturbances or
        # parameters, a fraction of ``step`` (``continuous_substeps``; docs/verification.md,
        # "The remainder per axis")
        self.h_sub = self.h
        if self.hold == "continuous" and self.xlo is not None and self.carry:
            self.h_sub = self.h / max(1, int(self.continuous_substeps))
        self.W, self.Winv = self._metric()
        cond = float(np.linalg.norm(self.W, 2) * np.linalg.norm(self.Winv, 2))
        # Winv is the inverse of W up to rounding: directions through Winv are inflated by
        # far more than cond(W)^2 * n * u
        self.winv_pad = 1.0 + 64 * self.n * cond * cond * _U + 1e-12
        self.Wn = float(np.linalg.norm(self.W, 2)) * (1 + 1e-12)
        self.absW, self.absWinv = np.abs(self.W), np.abs(self.Winv)
        # |x_i - y_i| <= wrow_i |x - y|_W
        self.wrow = np.linalg.norm(self.Winv, axis=1) * self.winv_pad
        self._u_ok: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._rho_hint = 0.0
        self._q_hint: np.ndarray | None = None  # (n,) the remainder per axis, last period
        #: the last interval operation outside its domain (names the expression), if any
        self.domain_note: str | None = None

    # ---- metric ---------------------------------------------------------------------

    def _metric(self) -> tuple[np.ndarray, np.ndarray]:
        """W with |v|_W = |W v|_2 from a Lyapunov function of the nominal closed loop.

        Any invertible W is sound; a Lyapunov metric of the linearised closed loop at the
        operating point makes the log-norm negative where the loop contracts, which keeps
        tubes tight. Falls back to the identity.
        """
        p = self.problem
        try:
            Ac, Bc, _ = linearize(p.plant, p.model.x_op, p.model.u_op)
            i = int(self.law.locate(p.model.x_op[None])[0])
            if i >= 0:
                A = Ac + Bc @ self.law.F[i]
                if np.all(np.linalg.eigvals(A).real < 0):
                    # in the states scaled by the initial set's half-widths: a state that
                    # varies by 0.01 next to one that varies by 1 K (a reactor's
                    # concentration and temperature) must not share one ball's radius
                    vs = p.verify
                    half = 0.5 * (vs.initial_upper - vs.initial_lower)
                    sc = np.where(half > 0, half, max(float(half.max()), 1.0))
                    sc = sc / sc.max()
                    As = A * sc[None, :] / sc[:, None]  # S^-1 A S
                    with warnings.catch_warnings():
                        # (scipy perturbs a near-singular Sylvester problem and warns: such
                        # a metric is no good; the identity below, quietly)
                        warnings.simplefilter("error", RuntimeWarning)
                        P = solve_continuous_lyapunov(As.T, -np.eye(self.n))
                    P = 0.5 * (P + P.T)
                    P /= np.max(np.linalg.eigvalsh(P))
                    W = np.linalg.cholesky(P).T / sc[None, :]  # |v|_W = |Ws S^-1 v|
                    W /= np.linalg.norm(W, 2)
                    if np.linalg.cond(W) < 1e6:
                        return W, np.linalg.inv(W)
        except Exception:  # the metric is only a tightness heuristic
            pass
        return np.eye(self.n), np.eye(self.n)

    def _ball_rows(self, A: np.ndarray) -> np.ndarray:
        """max of |a' v| over |v|_W <= 1, for each row a of A."""
        return np.linalg.norm(A @ self.Winv, axis=-1) * self.winv_pad

    # ---- ellipsoids -----------------------------------------------------------------

    def _ell_plus_ball(self, A: np.ndarray, rho: float) -> np.ndarray:
        """Generator of an ellipsoid containing {A e} + {v : |v|_W <= rho}.

        E(A) + E(B) lies in E((1 + 1/p) A A' + (1 + p) B B') for every p > 0 (B = rho W^-1);
        the Cholesky factor of that matrix plus delta I, delta = 1e-12 of its trace (far
        above the rounding of the products and of the factorisation), is the generator.
        """
        n = self.n
        if rho <= 0.0:
            return A
        B = (rho * self.winv_pad * (1 + 1e-12)) * self.Winv
        t1 = float(np.einsum("ij,ij->", A, A))
        if t1 == 0.0:
            return B
        Q1 = A @ A.T
        Q2 = B @ B.T
        t2 = float(np.trace(Q2))
        p = np.sqrt(t1 / t2)
        Q = (1 + 1 / p) * Q1 + (1 + p) * Q2
        Q = 0.5 * (Q + Q.T)
        Q[np.diag_indices(n)] += 1e-12 * float(np.trace(Q)) + 1e-300
        try:
            return np.linalg.cholesky(Q)
        except np.linalg.LinAlgError:
            r = float(np.linalg.norm(self.W @ A, 2)) * (1 + 1e-9) + rho
            return (r * self.winv_pad * (1 + 1e-12)) * self.Winv

    def _ell_hull(self, Ms: list[np.ndarray]) -> np.ndarray:
        """Generator of an ellipsoid containing every E(M_j) (a scaled one of them).

        E(M_j) is inside E(lam L) when |L^-1 M_j|_2 <= lam; the triangular solves are
        accurate to cond(L) * n * u relative, covered by the 1e-6 inflation for
        cond(L) <= 1e6. Otherwise: the W-ball through all of them.
        """
        if len(Ms) == 1:
            return Ms[0]
        # base: the largest of them (trace), as a lower-triangular factor
        b = int(np.argmax([float(np.einsum("ij,ij->", M, M)) for M in Ms]))
        L = Ms[b]
        if not np.array_equal(L, np.tril(L)):
            try:
                L = np.linalg.cholesky(L @ L.T)
            except np.linalg.LinAlgError:
                L = None
        if L is not None:
            d = np.abs(np.diag(L))
            if d.min() > 0 and np.linalg.cond(L) <= 1e6:
                lam = 1.0
                for Mj in Ms:
                    X = solve_triangular(L, Mj, lower=True)
                    lam = max(lam, float(np.linalg.norm(X, 2)))
                return (lam * (1 + 1e-6)) * L
        r = max(float(np.linalg.norm(self.W @ Mj, 2)) for Mj in Ms) * (1 + 1e-9)
        return (r * self.winv_pad * (1 + 1e-12)) * self.Winv

    # ---- enclosures -----------------------------------------------------------------

    def _u_range(self, i: int, xlo: np.ndarray, xhi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Range of u = F_i x + G_i over the box *within region i* (the states that use
        law i at the sample are in the region): 2m small LPs, falling back to the box."""
        F, G = self.law.F[i], self.law.G[i]
        c, r = 0.5 * (xlo + xhi), 0.5 * (xhi - xlo)
        mid = F @ c + G
        rad = np.abs(F) @ r
        blo, bhi = down2(mid - rad), up2(mid + rad)
        A, b = self.law.A[i], self.law.b[i] + 1e-9
        lo, hi = blo.copy(), bhi.copy()
        for r in range(F.shape[0]):
            x, st, _ = solve_lp(F[r], A, b, lb=xlo, ub=xhi)
            if st == "optimal":
                lo[r] = max(blo[r], F[r] @ x + G[r] - 1e-12 * (1 + np.abs(F[r]) @ np.abs(x)))
            x, st, _ = solve_lp(-F[r], A, b, lb=xlo, ub=xhi)
            if st == "optimal":
                hi[r] = min(bhi[r], F[r] @ x + G[r] + 1e-12 * (1 + np.abs(F[r]) @ np.abs(x)))
        return lo, hi

    def _region_u(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Range of u = F_i x + G_i over region i (LPs, cached; infinite where an LP fails)."""
        if i not in self._u_ok:
            law = self.law
            self._u_ok[i] = affine_range(law.F[i], law.G[i], law.A[i], law.b[i] + 1e-9)
        return self._u_ok[i]

    def _u_bounds(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The input bounds region ``i``'s input is checked against: ``u_min``, ``u_max``
        with their 1e-7 slack (the law's rounding), widened by the region's spill -- what
        the 1e-9 of point location adds to the law's range beyond the region, the
        locator's rounding, not the law's -- as in the linear engine
        (``linear.ClosedLoopSetup._region_u``, docs/verification.md). Cached."""
        cache = self.__dict__.setdefault("_u_bounds_cache", {})
        if i not in cache:
            law = self.law
            lo, hi = self._region_u(i)
            lo0, hi0 = affine_range(law.F[i], law.G[i], law.A[i], law.b[i])
            spill_hi = np.where(np.isfinite(hi) & np.isfinite(hi0), np.maximum(hi - hi0, 0), 0)
            spill_lo = np.where(np.isfinite(lo) & np.isfinite(lo0), np.maximum(lo0 - lo, 0), 0)
            cache[i] = (self.u_min - spill_lo, self.u_max + spill_hi)
        return cache[i]

    def _region_u_ok(self, i: int) -> bool:
        """Does u = F_i x + G_i meet the input bounds on the whole region i?"""
        lo, hi = self._region_u(i)
        umin, umax = self._u_bounds(i)
        return bool(np.all(lo >= umin) and np.all(hi <= umax))

    def _eval(self, fn, zlo, zhi):
        """``fn`` over joint boxes, a box meeting a singularity giving ``[-inf, inf]``.

        An interval operation outside its domain (division by an interval containing 0, log
        of an interval reaching 0, ...) means that box has no finite enclosure: its outputs
        become infinite (sound: every enclosure that uses them fails or is unbounded) and the
        reason, naming the expression, is kept in ``self.domain_note`` for the verdict.
        """
        try:
            return fn(zlo, zhi)
        except IntervalDomainError as exc:
            self.domain_note = str(exc)
            bad = exc.boxes
        zlo, zhi = np.asarray(zlo, float), np.asarray(zhi, float)
        shape = fn.shape if zlo.ndim == 1 else (zlo.shape[0], *fn.shape)
        lo, hi = np.full(shape, -np.inf), np.full(shape, np.inf)
        if zlo.ndim == 1 or bad is None:
            return lo, hi
        good = np.ones(zlo.shape[0], dtype=bool)
        good[bad] = False
        idx = np.flatnonzero(good)
        if idx.size:
            glo, ghi = self._eval(fn, zlo[idx], zhi[idx])
            lo[idx], hi[idx] = glo, ghi
        return lo, hi

    def _fb(self, lo, hi, i, ulo, uhi, nom=False):
        """f over boxes (N, n); ulo None: continuous hold, u = F x + G over the box.

        With disturbances or parameters the input box gets their box appended (their
        nominal values for the centre, ``nom``), unless it already has them.
        """
        if ulo is None:
            ulo, uhi = self._u_boxes(i, lo, hi, nom)
        ulo, uhi = self._with_extra(ulo, uhi, nom)
        return self._eval(self.enc.f_fn, *self.enc.box(lo, hi, ulo, uhi))

    def _with_extra(self, ulo, uhi, nom=False):
        """``(u, w, p)`` boxes from ``u`` boxes (unchanged for a certain plant)."""
        if self.xlo is None or np.shape(ulo)[-1] != self.m:
            return ulo, uhi
        elo, ehi = (self.xnom, self.xnom) if nom else (self.xlo, self.xhi)
        ulo, uhi = np.asarray(ulo, float), np.asarray(uhi, float)
        if ulo.ndim == 2:
            P = ulo.shape[0]
            return (np.hstack([ulo, np.broadcast_to(elo, (P, elo.size))]),
                    np.hstack([uhi, np.broadcast_to(ehi, (P, ehi.size))]))
        return np.concatenate([ulo, elo]), np.concatenate([uhi, ehi])

    def _u_boxes(self, i, lo, hi, nom=False):
        """Boxes of the continuous hold's input ``F_i x + G_i`` over state boxes; with
        measurement noise ``F_i (x + v_k) + G_i``: about the noise's centre (``Gn``), widened
        by ``_noise_input`` unless ``nom`` (the centre's own input, the noise's centre)."""
        F, G = self.law.F[i], self.law.G[i]
        if self.vr is not None:
            G = self.Gn[i]
        c, r = 0.5 * (lo + hi), 0.5 * (hi - lo)
        mid = c @ F.T + G
        rad = r @ np.abs(F).T
        pad = 4 * _U * (np.abs(c) @ np.abs(F).T + np.abs(G) + rad) + 1e-300
        if self.vr is not None and not nom:
            rad = rad + self._noise_input(i)
        return down2(mid - rad - pad), up2(mid + rad + pad)

    def _picard(self, slo, shi, i, ulo, uhi, h, nom=False):
        """Boxes B (N, n) with S + [0, h] f(B, U) inside B, batched over rows.

        Returns (Blo, Bhi, flo, fhi, ok): f over the box of the last containment check (the
        sweep ``[0, h] f`` of the substep lies in ``[h min(flo, 0), h max(fhi, 0)]``) and a
        mask of the rows whose enclosure was established (the others are infinite).
        """
        N = slo.shape[0]
        hc = h[:, None]
        flo, fhi = self._fb(slo, shi, i, ulo, uhi, nom)
        grow = np.maximum(np.abs(flo), np.abs(fhi)) * hc
        lo = slo - 1.5 * grow - 1e-12 * (1.0 + np.abs(slo))
        hi = shi + 1.5 * grow + 1e-12 * (1.0 + np.abs(shi))
        Blo = np.full((N, self.n), -np.inf)
        Bhi = np.full((N, self.n), np.inf)
        Flo = np.full((N, self.n), -np.inf)
        Fhi = np.full((N, self.n), np.inf)
        ok = np.zeros(N, dtype=bool)
        # a first candidate that is not finite (f unbounded or NaN on the set: a
        # singularity) cannot become an enclosure: that row fails, as in the loop below
        todo = np.flatnonzero(np.all(np.isfinite(lo), axis=1) & np.all(np.isfinite(hi), axis=1))
        for _ in range(20):
            if todo.size == 0:
                break
            ul = uh = None
            if ulo is not None:
                ul = ulo if ulo.ndim == 1 else ulo[todo]
                uh = uhi if uhi.ndim == 1 else uhi[todo]
            flo, fhi = self._fb(lo[todo], hi[todo], i, ul, uh, nom)
            hh = hc[todo]
            dlo, dhi = hh * np.minimum(flo, 0.0), hh * np.maximum(fhi, 0.0)
            s0, s1 = slo[todo], shi[todo]
            nlo = s0 + dlo - add_pad(s0, dlo)
            nhi = s1 + dhi + add_pad(s1, dhi)
            good = np.all(nlo >= lo[todo], axis=1) & np.all(nhi <= hi[todo], axis=1)
            g = todo[good]
            Blo[g], Bhi[g], Flo[g], Fhi[g] = nlo[good], nhi[good], flo[good], fhi[good]
            ok[g] = True
            todo, nlo, nhi = todo[~good], nlo[~good], nhi[~good]
            if todo.size == 0:
                break
            # iterate the Picard operator with a little inflation (epsilon-inflation); a
            # blanket widening of every axis feeds back through f and can diverge
            pad = 0.1 * (nhi - nlo) + 1e-12 * (1.0 + np.abs(nlo) + np.abs(nhi))
            lo[todo] = np.minimum(lo[todo], nlo - pad)
            hi[todo] = np.maximum(hi[todo], nhi + pad)
            # a candidate that is no longer finite (f unbounded on it: a singularity, an
            # overflow) cannot become an enclosure: that row fails
            fin = np.all(np.isfinite(lo[todo]), axis=1) & np.all(np.isfinite(hi[todo]), axis=1)
            todo = todo[fin]
            if todo.size == 0:
                break
        return Blo, Bhi, Flo, Fhi, ok

    def _jac(self, lo, hi, i, ulo, uhi, nom=False):
        """Interval Jacobians (Jx, Ju) over boxes, for the mode's input (Ju also in the
        disturbances and parameters, after the inputs' m columns, when there are any)."""
        if ulo is None:
            ulo, uhi = self._u_boxes(i, lo, hi, nom)
        ulo, uhi = self._with_extra(ulo, uhi, nom)
        z = self.enc.box(lo, hi, ulo, uhi)
        return self._eval(self.enc.jac_x_fn, *z), self._eval(self.enc.jac_u_fn, *z)

    # ---- one period ------------------------------------------------------------------

    def _box(self, s: _Set) -> tuple[np.ndarray, np.ndarray]:
        """Box enclosing the set (exact for the star part, plus the ellipsoid)."""
        lo, hi = s.range(np.eye(self.n))
        extra = s.ell(np.eye(self.n))
        pad = 1e-12 * (np.abs(s.y) + s.mag() + extra) + 1e-15
        return down2(s.y + lo - extra - pad), up2(s.y + hi + extra + pad)

    def _centre(self, y0, uc, F, G, hs) -> np.ndarray:
        """Point trajectory of the centre (RK4 per substep; validated afterwards)."""
        f = self._fnum
        zoh = self.hold == "zoh"
        Y = np.empty((hs.size + 1, self.n))
        Y[0] = y0
        x = [float(v) for v in y0]
        u = [float(v) for v in uc]
        Fl, Gl = F.tolist(), G.tolist()
        n = self.n

        def rhs(z):
            if not zoh:
                uu = [
                    sum(a * b for a, b in zip(row, z, strict=True)) + g
                    for row, g in zip(Fl, Gl, strict=True)
                ]
                return f(*z, *uu)
            return f(*z, *u)

        for j, h in enumerate(hs.tolist()):
            k1 = rhs(x)
            k2 = rhs([x[q] + 0.5 * h * k1[q] for q in range(n)])
            k3 = rhs([x[q] + 0.5 * h * k2[q] for q in range(n)])
            k4 = rhs([x[q] + h * k3[q] for q in range(n)])
            x = [x[q] + h / 6.0 * (k1[q] + 2 * k2[q] + 2 * k3[q] + k4[q]) for q in range(n)]
            Y[j + 1] = x
        return Y

    def _failure(self, t: float) -> Finding:
        """The finding of an enclosure that could not be established at time t."""
        if self.domain_note:
            return Finding("enclosure", -1, t, None, f"{self.domain_note} at t = {t:.6g}")
        # (no singularity: the Picard iteration or the remainder's bound did not close)
        return Finding("enclosure", -1, t, None,
                       f"no a-priori enclosure of the set's trajectories at t = {t:.6g} (the "
                       "Picard iteration or the remainder's bound did not close); the tube "
                       "of that piece of the initial set ends there")

    def _period(self, s: _Set, i: int):
        """Reach over one period in region i: (next set, tube, findings, record)."""
        self.domain_note = None
        n, m = self.n, self.m
        F, G = self.law.F[i], self.law.G[i]
        # with noise: the input is F (x_k + vc) + G + F delta (continuous: F (x(t) + vc) +
        # G + F delta), |delta| <= vr: the centre's offset Gn, the rest a bounded input
        # ``nu`` held over the period
        nu = None
        if self.vr is not None:
            G, nu = self.Gn[i], self._noise_input(i)
        t_k = s.k * self.Ts
        tau_end = min(self.Ts, self.T - t_k)
        N = max(1, int(np.ceil(tau_end / self.h_sub - 1e-9)))
        taus = np.minimum(np.arange(N + 1) * self.h_sub, tau_end)
        taus[-1] = tau_end
        hs = np.diff(taus)
        zoh = self.hold == "zoh"
        y0 = s.y
        uc = F @ y0 + G  # the centre's input at the sample
        FDlo, FDhi = s.range(F)
        FMn = s.ell(F)
        if zoh:
            # held input of the set's trajectories: u = uc + F (D d + M e)
            pad = 1e-12 * (np.abs(F) @ (np.abs(y0) + s.mag()) + np.abs(G) + FMn)
            ulo = down2(uc + FDlo - FMn - pad)
            uhi = up2(uc + FDhi + FMn + pad)
            # the centre's input may lie outside (y need not be in a cut set): hull
            ulo, uhi = np.minimum(ulo, down2(uc)), np.maximum(uhi, up2(uc))
            if nu is not None:  # every held input of every noise value
                ulo, uhi = down2(ulo - nu), up2(uhi + nu)
            FDv = s.V @ (F @ s.D).T
            du_norm = (
                float(np.max(np.linalg.norm(FDv, axis=1))) + float(np.linalg.norm(F @ s.M, 2))
            ) * (1 + 1e-9) + 1e-300
        # bound of | |D| |d| + |M| |e| |_2 for the rounding allowances
        dabs = float(np.linalg.norm(s.mag()))

        # 1. centre: point trajectory, validated substep by substep
        try:
            Y = self._centre(y0, uc, F, G, hs)
        except (ValueError, OverflowError, ZeroDivisionError, TypeError):
            Y = np.full((N + 1, n), np.nan)
        Y0 = Y[:-1]
        if not np.all(np.isfinite(Y)):
            return None, _empty_tube(n), [self._failure(t_k)], None
        uC = (None, None) if not zoh else (uc, uc)
        Bclo, Bchi, _, _, okc = self._picard(Y0, Y0, i, uC[0], uC[1], hs, nom=True)
        fyl, fyh = self._fb(Y0, Y0, i, *uC, nom=True)
        if not okc.all():
            j = int(np.argmin(okc))
            return None, _empty_tube(n), [self._failure(t_k + taus[j])], None
        (jxl, jxh), (jul, juh) = self._jac(Bclo, Bchi, i, *uC, nom=True)
        # |df/d(w, p)| along the centre's substeps (nominal values): the first-order part of
        # the disturbances' and parameters' forcing
        Jwc = np.maximum(np.abs(jul[..., m:]), np.abs(juh[..., m:]))
        jwl, jwh = jul[..., m:], juh[..., m:]
        jul, juh = jul[..., :m], juh[..., :m]  # (the inputs' columns)
        gl, gh = self._fb(Bclo, Bchi, i, *uC, nom=True)
        if zoh:
            Jl, Jh = jxl, jxh
        else:
            Jl, Jh = imat_add_point(jxl, jxh, jul, juh, F)
        ddl, ddh = imatvec(Jl, Jh, gl, gh)
        cjl, cjh = (jxl, jul), (jxh, juh)  # Jacobians along the centre's substep trajectory
        hc = hs[:, None]
        t1l, t1h = hc * fyl, hc * fyh
        h2 = 0.5 * hc * hc
        t2l, t2h = h2 * np.minimum(ddl, ddh), h2 * np.maximum(ddl, ddh)
        Tlo = Y0 + t1l + t2l - add_pad(Y0, t1l, t2l)
        Thi = Y0 + t1h + t2h + add_pad(Y0, t1h, t2h)
        Y1 = Y[1:]
        eps = np.maximum(Thi - Y1, Y1 - Tlo)
        eps = np.maximum(eps, 0.0) * (1 + 8 * _U) + 4 * _U * np.abs(Y1) + 1e-300
        eps_w = np.linalg.norm(eps @ self.absW.T, axis=1) * (1 + 1e-12)

        # 2. Jacobian at the centre and the linear flow Phi (exact up to rounding)
        (cxl, cxh), (cul, cuh) = self._jac(Y0, Y0, i, *uC, nom=True)
        # the disturbances' and parameters' Jacobian at the centre's points (nominal
        # values): their first-order part Jw0 (w - w_n, p - p_n) is carried by the linear
        # flow (``zsub``, ``Z`` below); only the spread about Jw0 enters the remainder
        Jw0 = None
        if self.xlo is not None and self.carry:
            Jw0 = 0.5 * (cul[..., m:] + cuh[..., m:])
            if not np.all(np.isfinite(Jw0)):
                Jw0 = None
        cul, cuh = cul[..., :m], cuh[..., :m]
        if not (np.all(np.isfinite(cxl + cxh)) and np.all(np.isfinite(cul + cuh))):
            j = int(np.argmin(np.all(np.isfinite(cxl + cxh), axis=(1, 2))))
            return None, _empty_tube(n), [self._failure(t_k + taus[j])], None
        Jxc = 0.5 * (cxl + cxh)
        Juc = 0.5 * (cul + cuh)
        if zoh:
            Me = np.zeros((N, n + m, n + m))
            Me[:, :n, :n] = Jxc
            Me[:, :n, n:] = Juc
            E = expm(Me * hs[:, None, None])
            Dx, Du = np.eye(n), np.zeros((n, m))
            Phi = np.empty((N + 1, n, n))
            Phi[0] = np.eye(n)
            phin = np.empty(N + 1)  # magnitude of the terms of Phi (rounding allowance)
            phin[0] = np.sqrt(n)
            Fn_ = float(np.linalg.norm(F)) + 1.0
            for j in range(N):
                Dx, Du = E[j, :n, :n] @ Dx, E[j, :n, :n] @ Du + E[j, :n, n:]
                Phi[j + 1] = Dx + Du @ F
                phin[j + 1] = (
                    np.linalg.norm(Dx) + (np.linalg.norm(Du) + np.linalg.norm(E[j, :n, n:])) * Fn_
                )
            Jc = Jxc
        else:
            Jc = Jxc + Juc @ F
            E = expm(Jc * hs[:, None, None])
            Phi = np.empty((N + 1, n, n))
            Phi[0] = np.eye(n)
            for j in range(N):
                Phi[j + 1] = E[j] @ Phi[j]
            phin = np.linalg.norm(Phi, axis=(1, 2))
        zsub = zgen = None
        if Jw0 is not None:
            # the spread of J_{w,p} along the centre's enclosures about Jw0 (the rest of
            # the second-order bound's first-order term)
            Jwc = np.maximum(np.abs(jwl - Jw0), np.abs(jwh - Jw0))
            frc = np.einsum("jie,e->ji", np.abs(Jw0), self.xdev) * (1 + 1e-12)
            zsub, zgen, zbox = carried_zonotope(Jxc if zoh else Jc, frc, hs)
        # spread of the Jacobian along the exact centre trajectory, about Jc (joint in
        # (x, u) for zoh; of the closed loop f(x, F x + G) for continuous hold)
        if zoh:
            Rc = np.concatenate(
                [
                    np.maximum(np.abs(cjl[0] - Jxc), np.abs(cjh[0] - Jxc)),
                    np.maximum(np.abs(cjl[1] - Juc), np.abs(cjh[1] - Juc)),
                ],
                axis=2,
            )
        else:
            Rc = np.maximum(np.abs(Jl - Jc[:, :, :]), np.abs(Jh - Jc))
        Mw = self.W @ Jc @ self.Winv
        Sy = 0.5 * (Mw + np.swapaxes(Mw, 1, 2))
        mu = np.linalg.eigvalsh(Sy)[:, -1] + 1e-12 * (1 + np.abs(Sy).max(axis=(1, 2)))
        grow = np.exp(np.maximum(mu, 0.0) * hs)
        PD = Phi @ s.D
        PM = Phi @ s.M
        vals = np.einsum("vk,jik->jvi", s.V, PD)  # (N+1, nv, n) images of the vertices
        slo_star, shi_star = vals.min(axis=1), vals.max(axis=1)
        Sstar = np.linalg.norm(vals @ self.W.T, axis=2).max(axis=1) * (1 + 1e-12)
        SM = np.linalg.norm(self.W @ PM, 2, axis=(1, 2)) * (1 + 1e-12)
        Mrows = _ell_rows(PM)  # (N+1, n)
        Sfull = grow * (Sstar[:-1] + SM[:-1])
        if zoh:
            WJu = np.linalg.norm(self.W @ Juc, 2, axis=(1, 2)) * (1 + 1e-12)
            Sfull = Sfull + grow * hs * WJu * du_norm
        if zsub is not None:  # x - z holds the carried part too
            Sfull = Sfull + np.linalg.norm(zsub @ self.absW.T, axis=1) * (1 + 1e-12)
        # rounding of the exponentials and products (Phi, Phi D, Phi M and the vertex
        # images), relative to the magnitude of their terms
        fpm = _FPM * self.Wn * (1.0 + phin[:-1] + phin[1:]) * (1.0 + dabs) + _REL * (
            1.0 + np.abs(Y1).max(axis=1)
        )
        absPhi = np.abs(Phi)
        vmag = np.max(np.abs(s.V) @ np.swapaxes(absPhi @ np.abs(s.D), 1, 2), axis=1) + (
            absPhi @ np.abs(s.M)
        ).sum(axis=2)  # (N+1, n)

        # 3. the local remainder: guess, enclose, check (induction over substeps)
        gpad = 1e-12 * (1.0 + np.abs(y0).max())
        frac = taus[:-1] / max(self.Ts, 1e-300)
        guess = 1.5 * self._rho_hint * frac + gpad
        # with the disturbances' carried part: a guess of the remainder per axis at the
        # substep starts too (``qg``, induction like ``guess``: the start boxes assume
        # both, the pass checks both; inf: none), the remainder's zonotope ``qres``
        qg = qres = None
        if zsub is not None:
            qg = np.full((N, n), np.inf)
            if self._q_hint is not None:
                qg = 1.5 * self._q_hint[None, :] * frac[:, None] + gpad
        qtries = 0
        rho = None
        for _attempt in range(14):
            base_lo = Y0 + slo_star[:-1] - Mrows[:-1]
            base_hi = Y0 + shi_star[:-1] + Mrows[:-1]
            ext = self.wrow[None, :] * guess[:, None]
            if qg is not None:
                ext = np.minimum(ext, qg)
            if zsub is not None:
                ext = ext + zbox
            bpad = 1e-12 * (np.abs(Y0) + vmag[:-1] + Mrows[:-1] + ext) + 1e-15
            Slo = down2(base_lo - ext - bpad)
            Shi = up2(base_hi + ext + bpad)
            if zoh:
                Blo, Bhi, flo, fhi, okb = self._picard(Slo, Shi, i, ulo, uhi, hs)
            else:
                Blo, Bhi, flo, fhi, okb = self._picard(Slo, Shi, i, None, None, hs)
            # deviation dynamics over the hull of the set's and the centre's enclosures
            Hlo, Hhi = np.minimum(Blo, Bclo), np.maximum(Bhi, Bchi)
            jfin = np.flatnonzero(okb)
            a = np.full(N, np.inf)
            b = np.zeros(N)
            c2 = np.full(N, np.inf)
            if jfin.size:
                # second-order bound of the nonlinear forcing (no feedback through psi):
                # |w_i| <= 1/2 Dz' |H_i| Dz + (Rc Dz)_i, Dz the a-priori bound of |x - z|
                # (and |u - uc|) over the substep, from the enclosures
                Dx = np.maximum(np.maximum(Bhi - Bclo, Bchi - Blo), 0.0)[jfin]
                if zoh:
                    Du_ = np.broadcast_to(np.maximum(uhi - uc, uc - ulo), (jfin.size, m))
                    zl = np.hstack([Hlo[jfin], np.broadcast_to(ulo, (jfin.size, m))])
                    zh = np.hstack([Hhi[jfin], np.broadcast_to(uhi, (jfin.size, m))])
                else:
                    Du_ = Dx @ np.abs(F).T
                    if nu is not None:  # u - u_z = F (x - z) + eta, |eta| <= nu
                        Du_ = Du_ + nu
                    ul_, uh_ = self._u_boxes(i, Hlo[jfin], Hhi[jfin])
                    zl = np.hstack([Hlo[jfin], ul_])
                    zh = np.hstack([Hhi[jfin], uh_])
                if self.xlo is not None:  # (w, p) vary in their boxes about the nominal
                    e = self.xlo.size
                    zl = np.hstack([zl, np.broadcast_to(self.xlo, (jfin.size, e))])
                    zh = np.hstack([zh, np.broadcast_to(self.xhi, (jfin.size, e))])
                    Du_ = np.hstack([Du_, np.broadcast_to(self.xdev, (jfin.size, e))])
                Dz = np.hstack([Dx, Du_]) * (1 + 1e-12)
                hl, hh = self._eval(self.hess, zl, zh)
                k = zl.shape[1]
                Hm = np.maximum(np.abs(hl), np.abs(hh)).reshape(-1, n, k, k)
                Hm = np.where(np.isnan(Hm), np.inf, Hm)
                q = 0.5 * np.einsum("pikl,pk,pl->pi", Hm, Dz, Dz)
                # (signed: the diagonal terms H_kk dz_k^2 lie in [min(hl_kk, 0), max(hh_kk,
                # 0)] Dz_k^2, the rest symmetric: q = qsym + qdiag)
                Dz2 = Dz * Dz
                hdl = np.diagonal(hl.reshape(-1, n, k, k), axis1=2, axis2=3)
                hdh = np.diagonal(hh.reshape(-1, n, k, k), axis1=2, axis2=3)
                hdl = np.where(np.isnan(hdl), -np.inf, np.minimum(hdl, 0.0))
                hdh = np.where(np.isnan(hdh), np.inf, np.maximum(hdh, 0.0))
                with np.errstate(invalid="ignore"):
                    qd_lo = 0.5 * np.einsum("pik,pk->pi", hdl, Dz2)
                    qd_hi = 0.5 * np.einsum("pik,pk->pi", hdh, Dz2)
                    qd = 0.5 * np.einsum("pik,pk->pi",
                                         np.diagonal(Hm, axis1=2, axis2=3), Dz2)
                if zoh:
                    q = q + np.einsum("pik,pk->pi", Rc[jfin], Dz[:, : n + m])
                else:
                    q = q + np.einsum("pik,pk->pi", Rc[jfin], Dz[:, :n])
                if self.xlo is not None:
                    q = q + Jwc[jfin] @ self.xdev
                if nu is not None:  # the linear part leaves out the noise's input eta:
                    # Juc eta under zoh (J(z, uc) - Jc is in Rc Dz, Dz holding |eta|); the
                    # Jacobian along the centre J_u(z) eta under continuous hold (Rc is the
                    # closed loop's, over x - z only)
                    Jn = np.abs(Juc) if zoh else np.maximum(np.abs(cjl[1]), np.abs(cjh[1]))
                    q = q + Jn[jfin] @ nu
                with np.errstate(invalid="ignore"):
                    c2[jfin] = np.linalg.norm(q @ self.absW.T, axis=1) * (1 + 1e-10) + 1e-300
                    # the symmetric part: the off-diagonal terms and the linear ones added
                    # to q0 (differences of sums: 1e-12 of the magnitudes covers their
                    # rounding)
                    qsym = np.maximum(q - qd, 0.0)
                    slack = 1e-12 * (q + np.abs(qd_lo) + qd_hi) + 1e-300
                    qlo = qd_lo - qsym - slack
                    qhi = qd_hi + qsym + slack
                c2 = np.where(np.isnan(c2), np.inf, c2)
            if jfin.size:
                if zoh:
                    (Xl, Xh), (Ul, Uh) = self._jac(Hlo[jfin], Hhi[jfin], i, ulo, uhi)
                else:
                    (Xl, Xh), (Ul, Uh) = self._jac(Hlo[jfin], Hhi[jfin], i, None, None)
                if self.xlo is not None:
                    # the disturbances' and parameters' deviation from the centre's nominal
                    # values: a forcing |Jw| |w - w_nom| (mean value over the boxes)
                    Jw = np.maximum(np.abs(Ul[..., m:]), np.abs(Uh[..., m:]))
                    if Jw0 is not None:  # (its spread about the carried Jw0)
                        Jw = np.maximum(np.abs(Ul[..., m:] - Jw0[jfin]),
                                        np.abs(Uh[..., m:] - Jw0[jfin]))
                    with np.errstate(invalid="ignore"):
                        bw = np.linalg.norm((Jw @ self.xdev) @ self.absW.T, axis=1)
                    bw = np.where(np.isnan(bw), np.inf, bw) * (1 + 1e-10) + 1e-300
                    Ul, Uh = Ul[..., :m], Uh[..., :m]
                else:
                    bw = 0.0
                if nu is not None:
                    # the noise's part of the held input: a forcing |Ju| |F delta| (mean
                    # value over the enclosures, the input box holds every noise value)
                    Jn = np.maximum(np.abs(Ul), np.abs(Uh))
                    with np.errstate(invalid="ignore"):
                        bn = np.linalg.norm((Jn @ nu) @ self.absW.T, axis=1)
                    bw = bw + np.where(np.isnan(bn), np.inf, bn) * (1 + 1e-10) + 1e-300
                Rx = np.maximum(np.abs(Xl - Jxc[jfin]), np.abs(Xh - Jxc[jfin]))
                Ru = np.maximum(np.abs(Ul - Juc[jfin]), np.abs(Uh - Juc[jfin]))
                R = Rx if zoh else Rx + Ru @ np.abs(F)
                with np.errstate(invalid="ignore"):
                    a[jfin] = norm2(self.absW @ R @ self.absWinv) * (1 + 1e-12) * self.winv_pad
                    if zoh:
                        b[jfin] = norm2(self.absW @ Ru) * (1 + 1e-12) * du_norm
                b[jfin] = (b[jfin] + bw) * (1 + 1e-12)
            qall = None
            if jfin.size == N and np.all(np.isfinite(c2)):
                # (the second-order forcing of every substep, element-wise, signed)
                qall = (qlo, qhi) if np.all(np.isfinite(qlo + qhi)) else None
            rho = np.zeros(N + 1)
            bad, r, last = -1, 0.0, N
            for j in range(N):
                if bad < 0 and not (r <= guess[j]):
                    bad = j
                if not okb[j]:
                    if bad < 0:
                        bad = j
                    last = j
                    break
                with np.errstate(all="ignore"):
                    r1 = gronwall(r, mu[j], a[j], Sfull[j], hs[j], b[j])
                    r2 = gronwall(r, mu[j], 0.0, 0.0, hs[j], c2[j]) if np.isfinite(c2[j]) else r1
                    r = (np.fmin(r1, r2) + eps_w[j] + fpm[j]) * (1 + 1e-12)
                if not np.isfinite(r):
                    # no finite bound (an enclosure met a singularity): the substep fails
                    okb = okb.copy()
                    okb[j] = False
                    if bad < 0:
                        bad = j
                    last = j
                    break
                rho[j + 1] = r
            qres = None
            if qg is not None and qall is not None:
                jump = eps * (1 + 1e-12) + self.wrow[None, :] * fpm[:, None]
                qres = offset_zonotope(Jxc if zoh else Jc, qall[0], qall[1], hs, jump)
            if qg is not None and np.any(np.isfinite(qg)):
                # the start boxes assumed the per-axis guess: proved up to its first miss
                over = 0
                if qres is not None:
                    with np.errstate(invalid="ignore"):
                        okq = np.all(qres[4] <= qg, axis=1)
                    over = N if okq.all() else int(np.argmin(okq))
                if over < N and (bad < 0 or over <= bad):
                    bad = over
                    qtries += 1
                    if qres is None or qtries > 4:
                        qg = np.full((N, n), np.inf)  # give the per-axis guess up
                    else:
                        qg = np.maximum(qg, 1.25 * qres[4]) + gpad
                    qres = None
                    continue
            elif qres is not None and bad < 0 and qtries == 0:
                # no guess yet: one more pass with this one (tighter start boxes)
                qtries += 1
                qg = 1.25 * qres[4] + gpad
                continue
            if bad < 0:
                break
            if not okb[bad] and rho[bad] <= guess[bad]:
                break  # the set is where the guess says, but its enclosure fails
            # the guess was too small: raise it to the estimates of this pass and redo
            est = rho[:N].copy()
            est[last:] = rho[last]
            guess = np.maximum(guess, 1.25 * est) + gpad
        if bad >= 0:
            # tube up to the failing substep (those boxes are proved), then stop
            tube = _tube(
                t_k + taus[:bad],
                t_k + taus[1 : bad + 1],
                Blo[:bad],
                Bhi[:bad],
                self.stats["branches"],
            )
            return None, tube, [self._failure(t_k + taus[bad])], None
        self._rho_hint = 0.5 * self._rho_hint + 0.5 * float(rho[N])
        # the remainder per axis (with the disturbances' carried part only): psi' = J_j psi
        # + w, |w| <= q_j, plus the centre's error and the rounding at each substep's end,
        # the very recursion the W-ball bounds, carried as a zonotope of the linear flow:
        # it keeps the thin directions the ball (isotropic in W) fills
        qsub = qgen = None
        if zgen is not None and qres is not None:
            qlo_s, qhi_s, qoff, qgen, _ = qres
            qsub = (qlo_s, qhi_s)
            self._q_hint = np.abs(qoff) + np.abs(qgen).sum(axis=1)
        # within a substep the set is also the centre's enclosure plus the star and the
        # ellipsoid carried by Phi(t) plus the remainder ball: far tighter than the sweep
        # S_j + [0, h] f(B_j) once the set is wide across a fast direction of f
        if zoh:
            Ma = np.abs(Me)
            zeta = np.hstack([
                np.maximum(np.abs(slo_star[:-1]), np.abs(shi_star[:-1])) + Mrows[:-1],
                np.broadcast_to(np.maximum(np.abs(FDlo), np.abs(FDhi)) + FMn, (N, m)),
            ])
        else:
            Ma = np.abs(Jc)
            zeta = np.maximum(np.abs(slo_star[:-1]), np.abs(shi_star[:-1])) + Mrows[:-1]
        Blo, Bhi = self._linear_boxes(
            Blo, Bhi, Bclo, Bchi, slo_star, shi_star, Mrows, rho, fpm, Ma, zeta, hs, vmag, zsub,
            qsub,
        )
        tube = _tube(t_k + taus[:-1], t_k + taus[1:], Blo, Bhi, self.stats["branches"])
        swlo = down2(hc * np.minimum(flo, 0.0))
        swhi = up2(hc * np.maximum(fhi, 0.0))
        rec = _Rec(Y0, PD[:-1], PM[:-1], rho[:-1], swlo, swhi, s.V, flo, fhi, hs, vmag[:-1],
                   zsub)
        Mn = self._ell_plus_ball(PM[N], float(rho[N]))
        nxt = _Set(Y[N].copy(), PD[N], Mn, s.k + 1, s.path, s.H, s.h, s.V, s.base, zgen)
        if qgen is not None and n > 2:
            # (not in the plane: there the zonotopes' nearly parallel generators make a
            # sliver polygon whose vertex enumeration falls back to its bounding box)
            nxt.rem = (PM[N], float(rho[N]), qoff, qgen)
        return nxt, tube, [], rec

    def _linear_boxes(
        self, Blo, Bhi, Bclo, Bchi, slo, shi, Mrows, rho, fpm, Ma, zeta, hs, vmag, zsub=None,
        qsub=None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The substeps' tube boxes ``B_j`` intersected with the linear-part bound.

        Over substep ``j`` (``tau in [0, h]``) every trajectory is ``x = z_j + g(tau) +
        psi``: ``z_j`` the exact centre (in ``B^c_j``), ``g(tau) = Phi(t_j + tau) (D d + M
        e)`` and ``|psi|_W <= max(rho_j, rho_{j+1})`` (each Groenwall bound is monotone in
        ``tau``, from ``rho_j`` towards its fixed point), plus ``fpm_j`` for the rounding of
        the computed ``Phi_{j+1}`` (the chord's far end). ``g`` is the x part of ``exp(Me
        tau) zeta``, ``zeta = (Phi_j v, F v)`` (zoh; ``Me = [[Jx, Ju], [0, 0]]``) or
        ``exp(Jc tau) Phi_j v`` (continuous hold): it lies within ``h^2/8 max |g''|`` of the
        chord between ``g(0)`` and ``g(h)``, and ``|g''| <= |Me|^2 exp(|Me| h) |zeta|``
        element-wise. The chord's range over the star and the ellipsoid lies in the hull of
        their ranges at the two ends.

        Parameters
        ----------
        Blo, Bhi : (N, n) ndarray
            The substeps' a-priori boxes.
        Bclo, Bchi : (N, n) ndarray
            The centre's enclosures over the substeps.
        slo, shi : (N + 1, n) ndarray
            The star's ranges at the substep points.
        Mrows : (N + 1, n) ndarray
            The ellipsoid's half-widths at the substep points.
        rho : (N + 1,) ndarray
            The remainder radii (W-norm) at the substep points.
        fpm : (N,) ndarray
            The substeps' rounding allowances of the exponentials and products (W-norm).
        Ma : (N, q, q) ndarray
            ``|Me|`` (zoh, ``q = n + m``) or ``|Jc|`` (continuous hold, ``q = n``).
        zeta : (N, q) ndarray
            Bounds of ``|zeta|`` over the set.
        hs : (N,) ndarray
            The substep lengths.
        vmag : (N + 1, n) ndarray
            Magnitudes of the star's and the ellipsoid's terms (rounding allowance).
        zsub : (N, n) ndarray, optional
            Half-widths of the disturbances' carried linear part over the substeps.
        qsub : tuple of two (N, n) ndarray, optional
            A box holding the remainder over the substeps, its ends included (from the
            remainder's zonotope about its offset): intersected with the W-ball per axis.

        Returns
        -------
        lo, hi : (N, n) ndarray
            The tightened boxes (each inside the a-priori one).
        """
        n = self.n
        v = expabs_vec(Ma * hs[:, None, None], zeta)
        if v is None:
            return Blo, Bhi
        g2 = np.einsum("jab,jbc,jc->ja", Ma, Ma, v)[:, :n] * (1 + 1e-10)
        err = (0.125 * hs * hs)[:, None] * g2 * (1 + 1e-10)
        ell = np.maximum(Mrows[:-1], Mrows[1:])
        ball = self.wrow[None, :] * (np.maximum(rho[:-1], rho[1:]) + fpm)[:, None]
        blo = bhi = ball  # the remainder lies in [-blo, bhi]
        if qsub is not None:  # two bounds of the same remainder: their intersection
            fp = self.wrow[None, :] * fpm[:, None]
            blo = np.minimum(ball, fp - qsub[0])
            bhi = np.minimum(ball, qsub[1] + fp)
        if zsub is not None:
            blo, bhi = blo + zsub, bhi + zsub
        dlo = np.minimum(slo[:-1], slo[1:]) - ell - blo - err
        dhi = np.maximum(shi[:-1], shi[1:]) + ell + bhi + err
        pad = 1e-12 * (
            np.abs(Bclo) + np.abs(Bchi) + np.maximum(vmag[:-1], vmag[1:]) + ell
            + np.maximum(np.abs(blo), np.abs(bhi)) + err
        ) + 1e-15
        lo = down2(Bclo + dlo - pad)
        hi = up2(Bchi + dhi + pad)
        ok = np.all(np.isfinite(lo), axis=1) & np.all(np.isfinite(hi), axis=1)
        lo = np.where(ok[:, None], np.maximum(Blo, lo), Blo)
        hi = np.where(ok[:, None], np.minimum(Bhi, hi), Bhi)
        return lo, hi

    # ---- the period's support (for the property checks) --------------------------------

    def _support(self, rec: _Rec, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds (N, K) of A x over each substep's set (star + ellipsoid +
        ball + sweep)."""
        mid = rec.Y @ A.T  # (N, K)
        AD = A @ rec.PD  # (N, K, n)
        vals = AD @ rec.V.T  # (N, K, nv)
        dlo, dhi = vals.min(axis=2), vals.max(axis=2)
        ell = _ell_rows(A @ rec.PM)
        ball = self._ball_rows(A)[None, :] * rec.rho[:, None]
        if rec.zsub is not None:  # the disturbances' carried part
            ball = ball + rec.zsub @ np.abs(A).T * (1 + 1e-12)
        pl, ph = A[None] * rec.swlo[:, None, :], A[None] * rec.swhi[:, None, :]
        lo_sw = np.minimum(pl, ph).sum(axis=2)
        hi_sw = np.maximum(pl, ph).sum(axis=2)
        slack = 1e-12 * (
            (np.abs(rec.Y) + np.abs(rec.swlo) + np.abs(rec.swhi) + rec.vmag) @ np.abs(A).T
            + np.abs(dlo)
            + np.abs(dhi)
            + ell
            + ball
            + 1.0
        )
        lo = mid + dlo - ell - ball + lo_sw - slack
        hi = mid + dhi + ell + ball + hi_sw + slack
        return lo, hi


def _tube(t0, t1, lo, hi, branch) -> Tube:
    n = lo.shape[-1] if lo.ndim == 2 else 0
    return Tube(
        np.asarray(t0, float),
        np.asarray(t1, float),
        np.asarray(lo, float).reshape(-1, n),
        np.asarray(hi, float).reshape(-1, n),
        np.full(len(t0), branch),
    )


def _empty_tube(n: int) -> Tube:
    return Tube.empty(n)
