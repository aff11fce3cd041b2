"""Sound reachtubes for nonlinear plants: simulation + on-the-fly discrepancy, made rigorous.

The reach set at a time is ``{y + D d + r : |d_i| <= r0_i, |r|_W <= rho}``: a computed
centre ``y``, a *sensitivity* matrix ``D`` applied to the initial deviation ``d`` (the initial
box, exactly: a zonotope), and a remainder ball of radius ``rho`` in the norm
``|v|_W = |W v|_2`` that absorbs every error. Along a substep ``[t_j, t_j + h]`` (see
docs/verification.md for the proofs):

1. **A-priori enclosure** ``B_j``: a box with ``S_j + [0, h] f(B_j, U(B_j)) subset B_j``
   (Picard-Lindeloef in interval arithmetic, ``S_j`` the box of the set at ``t_j``): every
   trajectory of the set, and the exact centre trajectory, stays in ``B_j`` over the substep.
   ``B_j`` is the tube's box for that substep.
2. **Centre**: one interval Taylor step ``y + h f(y) + h^2/2 (J f)(B_c)`` encloses the exact
   centre trajectory's value (Lagrange remainder over the centre's own enclosure ``B_c``);
   its midpoint is the next ``y``, its radius ``eps`` goes into ``rho``.
3. **Deviation**: by the mean-value theorem ``d/dt (x - y) = Jbar (x - y)`` with
   ``Jbar`` in the interval Jacobian ``J(B_j) = Jc + E``, ``|E| <= R_j``. The linear part
   ``Jc`` (the Jacobian at the centre) is propagated *exactly* by matrix exponentials into
   ``D`` (so rotations and contraction are kept); the perturbation ``E`` feeds ``rho``
   through a Groenwall bound with the log-norm ``mu_W(Jc)``:
   ``rho' <= e^{(mu + a) h} rho + (e^{(mu + a) h} - 1)/(mu + a) (a S + b)`` where
   ``a = ||W R W^-1||``, ``S`` bounds ``|D d|_W`` over the substep and ``b`` the effect of
   the held input's deviation (zoh).
With hold ``zoh`` the input ``u = F x_k + G`` is constant over a period; the sensitivity is
taken with respect to ``(x, u)`` and closed with ``F`` at the sample, which keeps the
closed loop's contraction across periods.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm, solve_continuous_lyapunov

from .law import ExplicitLaw
from .plant import linearize
from .polytope import chebyshev_ball, minimal_rows, normalize_rows, solve_lp
from .reach_linear import Finding
from .spec import Problem
from .tube import Tube

__all__ = ["NonlinearReach"]

_REL = 1e-12


@dataclass
class _Set:
    y: np.ndarray  # (n,) centre
    D: np.ndarray  # (n, n) sensitivity to the initial deviation
    rho: float  # remainder radius (W-norm)
    k: int  # sample index
    path: tuple[int, ...] = ()
    H: np.ndarray | None = None  # initial deviations d satisfy H d <= h ...
    h: np.ndarray | None = None
    V: np.ndarray | None = None  # ... a polytope with these vertices (nv, n)

    def range(self, M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """min and max of M D d over the deviation polytope (attained at vertices)."""
        vals = self.V @ (M @ self.D).T
        return vals.min(axis=0), vals.max(axis=0)

    def with_(self, D: np.ndarray, rho: float, y: np.ndarray | None = None) -> _Set:
        return _Set(self.y if y is None else y, D, rho, self.k, self.path, self.H, self.h, self.V)


class _EnclosureError(Exception):
    """The a-priori enclosure could not be established (set too large / step too long)."""


@dataclass
class NonlinearReach:
    """Reachability engine for a nonlinear plant (see module docstring)."""

    problem: Problem
    law: ExplicitLaw
    hold: str
    max_depth: int
    progress: Callable[[dict], None] | None = None
    stats: dict = field(default_factory=lambda: {"branches": 0, "refinements": 0, "partitions": 0})

    def __post_init__(self) -> None:
        from .interval import plant_enclosures

        p = self.problem
        vs = p.verify
        self.enc = plant_enclosures(p)
        self.n, self.m = p.plant.n, p.plant.m
        self.Ts = float(p.model.sample_time)
        self.T = float(vs.time_horizon)
        self.h = float(vs.step)
        self.unsafe = [normalize_rows(*s.halfspaces())[:2] for s in vs.unsafe]
        self.safe = [normalize_rows(*s.halfspaces())[:2] for s in vs.safe]
        self.check_u = bool(vs.input_bounds)
        # the law meets its own input bounds only up to round-off and the 1e-9 tolerance of
        # point location on region boundaries: input bounds are checked with 1e-7 slack
        self.u_min = np.asarray(p.mpc.u_min, float) - 1e-7 * (1 + np.abs(p.mpc.u_min))
        self.u_max = np.asarray(p.mpc.u_max, float) + 1e-7 * (1 + np.abs(p.mpc.u_max))
        self.boxes_lo, self.boxes_hi = self.law.boxes
        self.c0 = 0.5 * (vs.initial_lower + vs.initial_upper)
        self.V0 = np.diag(0.5 * (vs.initial_upper - vs.initial_lower))
        self.W, self.Winv = self._metric()
        self.absW, self.absWinv = np.abs(self.W), np.abs(self.Winv)
        self.wrow = np.linalg.norm(self.Winv, axis=1)  # |x_i - y_i| <= wrow_i |x - y|_W
        self.tubes: list[Tube] = []
        self.findings: list[Finding] = []

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
                A = Ac + (Bc @ self.law.F[i] if self.hold == "continuous" else 0)
                if self.hold == "zoh":
                    # discrete closed loop of the sample map; its Lyapunov metric
                    A = Ac + Bc @ self.law.F[i]
                if np.all(np.linalg.eigvals(A).real < 0):
                    P = solve_continuous_lyapunov(A.T, -np.eye(self.n))
                    P = 0.5 * (P + P.T)
                    P /= np.max(np.linalg.eigvalsh(P))
                    W = np.linalg.cholesky(P).T
                    if np.linalg.cond(W) < 1e6:
                        return W, np.linalg.inv(W)
        except Exception:  # the metric is only a tightness heuristic
            pass
        return np.eye(self.n), np.eye(self.n)

    def _wnorm_interval(self, R: np.ndarray) -> float:
        """Upper bound of ||W E W^-1||_2 over all |E| <= R (element-wise)."""
        M = self.absW @ R @ self.absWinv
        return float(np.linalg.norm(M, 2)) * (1 + 1e-12)

    def _lognorm(self, J: np.ndarray) -> float:
        """mu_W(J) = lambda_max(sym(W J W^-1)) for a point matrix J (with a margin)."""
        M = self.W @ J @ self.Winv
        S = 0.5 * (M + M.T)
        return float(np.max(np.linalg.eigvalsh(S))) + 1e-12 * (1 + np.abs(S).max())

    # ---- enclosures -----------------------------------------------------------------

    def _u_box(self, i: int, xlo: np.ndarray, xhi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        F, G = self.law.F[i], self.law.G[i]
        c, r = 0.5 * (xlo + xhi), 0.5 * (xhi - xlo)
        mid = F @ c + G
        rad = np.abs(F) @ r
        return _dn(mid - rad), _up(mid + rad)

    def _u_range(self, i: int, xlo: np.ndarray, xhi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Range of u = F_i x + G_i over the box *within region i* (the states that use
        law i at the sample are in the region): 2m small LPs, falling back to the box."""
        F, G = self.law.F[i], self.law.G[i]
        blo, bhi = self._u_box(i, xlo, xhi)
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

    def _picard(self, slo, shi, i, ulo, uhi, h) -> tuple[np.ndarray, np.ndarray]:
        """Box B with S + [0, h] f(B, U) inside B (U fixed, or U(B) = F B + G)."""
        lo, hi = slo.copy(), shi.copy()
        flo, fhi = self._f(lo, hi, i, ulo, uhi)
        grow = np.maximum(np.abs(flo), np.abs(fhi)) * h
        lo, hi = lo - 1.5 * grow - 1e-12, hi + 1.5 * grow + 1e-12
        for _ in range(20):
            flo, fhi = self._f(lo, hi, i, ulo, uhi)
            dlo, dhi = h * np.minimum(flo, 0.0), h * np.maximum(fhi, 0.0)
            nlo = slo + dlo - _add_pad(slo, dlo)
            nhi = shi + dhi + _add_pad(shi, dhi)
            if np.all(nlo >= lo) and np.all(nhi <= hi):
                return nlo, nhi  # contained: nlo/nhi is itself an enclosure
            # iterate the Picard operator with a little inflation (epsilon-inflation); a
            # blanket widening of every axis feeds back through f and can diverge
            span = nhi - nlo
            pad = 0.1 * span + 1e-12 * (1.0 + np.abs(nlo) + np.abs(nhi))
            lo = np.minimum(lo, nlo - pad)
            hi = np.maximum(hi, nhi + pad)
        raise _EnclosureError

    def _f(self, lo, hi, i, ulo, uhi):
        if ulo is None:  # continuous hold: u = F x + G over the box
            ulo, uhi = self._u_box(i, lo, hi)
        return self.enc.f(lo, hi, ulo, uhi)

    def _jac(self, lo, hi, i, ulo, uhi):
        """Interval Jacobians (Jx, Ju) over the box, for the mode's input."""
        if ulo is None:
            ulo, uhi = self._u_box(i, lo, hi)
        jx = self.enc.jac_x(lo, hi, ulo, uhi)
        ju = self.enc.jac_u(lo, hi, ulo, uhi)
        return jx, ju

    # ---- one period ------------------------------------------------------------------

    def _box(self, s: _Set) -> tuple[np.ndarray, np.ndarray]:
        """Box enclosing the set (exact for the star part, plus the remainder ball)."""
        lo, hi = s.range(np.eye(self.n))
        extra = self.wrow * s.rho
        pad = 1e-12 * (np.abs(s.y) + np.abs(lo) + np.abs(hi) + extra) + 1e-15
        return _dn(s.y + lo - extra - pad), _up(s.y + hi + extra + pad)

    def _dnorm(self, D: np.ndarray, V: np.ndarray) -> float:
        """max of |D d|_W over the deviation polytope (a convex function: at a vertex)."""
        return float(np.max(np.linalg.norm(V @ (self.W @ D).T, axis=1))) * (1 + 1e-12)

    def _period(self, s: _Set, i: int) -> tuple[_Set | None, Tube, list[Finding]]:
        n, m = self.n, self.m
        F, G = self.law.F[i], self.law.G[i]
        t_k = s.k * self.Ts
        tau_end = min(self.Ts, self.T - t_k)
        nsteps = max(1, int(np.ceil(tau_end / self.h - 1e-9)))
        taus = np.minimum(np.arange(nsteps + 1) * self.h, tau_end)
        taus[-1] = tau_end
        zoh = self.hold == "zoh"
        y, D, rho = s.y.copy(), s.D.copy(), s.rho
        xlo, xhi = self._box(s)
        if zoh:
            uc = F @ y + G  # the centre's held input
            ulo, uhi = self._u_box(i, xlo, xhi)
            # input deviation of a trajectory: du = F dx_k, |du|_2 <= du_norm
            du_norm = (
                float(np.max(np.linalg.norm(s.V @ (F @ D).T, axis=1)))
                + np.linalg.norm(F @ self.Winv, 2) * rho
            )
            Dx, Du = np.eye(n), np.zeros((n, m))
            r_loc = 0.0  # remainder born in this period
            base = D  # deviation at t_k = base d + r_k
            rho_k = rho
        else:
            uc = None
            ulo = uhi = None
        t0s, t1s, los, his = [], [], [], []
        zrec: list[tuple[_Set, np.ndarray, np.ndarray]] = []
        self._last_zrec = zrec
        findings: list[Finding] = []
        for j in range(nsteps):
            h = taus[j + 1] - taus[j]
            if zoh:
                cur_D = (Dx + Du @ F) @ base
                cur_rho = np.linalg.norm(self.W @ (Dx + Du @ F) @ self.Winv, 2) * rho_k + r_loc
                cur = s.with_(cur_D, cur_rho, y)
            else:
                cur = s.with_(D, rho, y)
            slo, shi = self._box(cur)
            try:
                Blo, Bhi = self._picard(slo, shi, i, ulo, uhi, h)
                ylo, yhi = self._picard(y, y, i, *((uc, uc) if zoh else (None, None)), h)
            except _EnclosureError:
                findings.append(Finding("max_depth", -1, t_k + taus[j], None))
                break
            t0s.append(t_k + taus[j])
            t1s.append(t_k + taus[j + 1])
            los.append(Blo)
            his.append(Bhi)
            # the set over the substep lies in (set at t_j) + [0, h] f(B): keep both parts
            # for property checks that are tighter than the box B
            flo, fhi = self._f(Blo, Bhi, i, ulo, uhi)
            zrec.append((cur, _dn(h * np.minimum(flo, 0.0)), _up(h * np.maximum(fhi, 0.0))))
            # centre: interval Taylor step with Lagrange remainder over its enclosure
            fl, fh = self._f(y, y, i, *((uc, uc) if zoh else (None, None)))
            (jxl, jxh), (jul, juh) = self._jac(ylo, yhi, i, *((uc, uc) if zoh else (None, None)))
            gl, gh = self._f(ylo, yhi, i, *((uc, uc) if zoh else (None, None)))
            if zoh:
                Jl, Jh = jxl, jxh
            else:
                Jl, Jh = _imat_add_point(jxl, jxh, jul, juh, F)
            ddl, ddh = _imatvec(Jl, Jh, gl, gh)
            t1l, t1h = h * fl, h * fh
            t2l, t2h = 0.5 * h * h * np.minimum(ddl, ddh), 0.5 * h * h * np.maximum(ddl, ddh)
            nlo = y + t1l + t2l - _add_pad(y, t1l, t2l)
            nhi = y + t1h + t2h + _add_pad(y, t1h, t2h)
            y_next = 0.5 * (nlo + nhi)
            eps = np.maximum(y_next - nlo, nhi - y_next)
            # deviation dynamics over B: Jacobian at the centre and its spread
            (Xl, Xh), (Ul, Uh) = self._jac(Blo, Bhi, i, ulo, uhi)
            (cxl, cxh), (cul, cuh) = self._jac(y, y, i, *((uc, uc) if zoh else (None, None)))
            Jxc = 0.5 * (cxl + cxh)
            Juc = 0.5 * (cul + cuh)
            Rx = np.maximum(np.abs(Xl - Jxc), np.abs(Xh - Jxc))
            Ru = np.maximum(np.abs(Ul - Juc), np.abs(Uh - Juc))
            if zoh:
                Jc = Jxc
                a = self._wnorm_interval(Rx)
                b = float(np.linalg.norm(self.absW @ Ru, 2)) * du_norm
                Me = np.zeros((n + m, n + m))
                Me[:n, :n] = Jxc
                Me[:n, n:] = Juc
                E = expm(h * Me)
                Dx, Du = E[:n, :n] @ Dx, E[:n, :n] @ Du + E[:n, n:]
                S = self._dnorm(cur_D, s.V) + cur_rho
                S *= np.exp(max(self._lognorm(Jc), 0.0) * h)
                mu = self._lognorm(Jc)
                r_loc = _gronwall(r_loc, mu, a, S, h, b)
                r_loc += float(np.linalg.norm(self.absW @ eps, 2)) + _REL * (1 + np.abs(y).max())
            else:
                Jc = Jxc + Juc @ F
                R = Rx + Ru @ np.abs(F)
                a = self._wnorm_interval(R)
                mu = self._lognorm(Jc)
                S = self._dnorm(D, s.V)
                S *= np.exp(max(mu, 0.0) * h)
                rho = _gronwall(rho, mu, a, S, h, 0.0)
                rho += float(np.linalg.norm(self.absW @ eps, 2)) + _REL * (1 + np.abs(y).max())
                D = expm(h * Jc) @ D
            y = y_next
        tube = Tube(
            np.array(t0s),
            np.array(t1s),
            np.array(los).reshape(-1, n),
            np.array(his).reshape(-1, n),
            np.full(len(t0s), self.stats["branches"]),
        )
        if findings:
            return None, tube, findings
        if zoh:
            D = (Dx + Du @ F) @ base
            rho = np.linalg.norm(self.W @ (Dx + Du @ F) @ self.Winv, 2) * rho_k + r_loc
        nxt = _Set(y, D, rho, s.k + 1, s.path, s.H, s.h, s.V)
        return nxt, tube, findings

    # ---- properties -------------------------------------------------------------------

    def _support(self, rec, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of A x over one substep's set (star + ball + sweep)."""
        cur, swlo, swhi = rec
        mid = A @ cur.y
        dlo, dhi = cur.range(A)
        ball = np.linalg.norm(A @ self.Winv, axis=1) * cur.rho
        lo_sw = np.minimum(A * swlo, A * swhi).sum(axis=1)
        hi_sw = np.maximum(A * swlo, A * swhi).sum(axis=1)
        slack = 1e-12 * (
            np.abs(A) @ (np.abs(cur.y) + np.abs(swlo) + np.abs(swhi))
            + np.abs(dlo)
            + np.abs(dhi)
            + ball
            + 1.0
        )
        return mid + dlo - ball + lo_sw - slack, mid + dhi + ball + hi_sw + slack

    def _violations(self, tube: Tube, i: int, s: _Set) -> bool:
        """Does the period's reach set possibly violate a property?

        Each substep's set is bounded both by its box B and by the zonotope at the substep's
        start plus the sweep [0, h] f(B); the tighter of the two bounds is used per row.
        """
        lo, hi = tube.lower, tube.upper
        recs = self._last_zrec
        for A, b in self.unsafe:
            for j in range(lo.shape[0]):
                zl, _ = self._support(recs[j], A)
                bl = np.where(A > 0, A, 0) @ lo[j] + np.where(A < 0, A, 0) @ hi[j]
                if np.any(np.maximum(zl, bl) > b):
                    continue  # one row of the unsafe set separates it
                # box B intersected with the half-spaces A x >= zl that hold on the set
                Aq = np.vstack([A, -A])
                bq = np.concatenate([b + 1e-12, -zl])
                x, st, _ = solve_lp(np.zeros(self.n), Aq, bq, lb=lo[j], ub=hi[j])
                if st == "optimal":
                    return True
        for A, b in self.safe:
            for j in range(lo.shape[0]):
                _, zu = self._support(recs[j], A)
                bu = np.where(A > 0, A, 0) @ hi[j] + np.where(A < 0, A, 0) @ lo[j]
                if np.any(np.minimum(zu, bu) > b):
                    return True
        if self.check_u and lo.shape[0]:
            if self.hold == "zoh":
                xlo, xhi = self._box(s)
                ulo, uhi = self._u_range(i, xlo, xhi)
                return bool(np.any(ulo < self.u_min) or np.any(uhi > self.u_max))
            F, G = self.law.F[i], self.law.G[i]
            for j in range(lo.shape[0]):
                zl, zu = self._support(recs[j], F)
                c, r = 0.5 * (lo[j] + hi[j]), 0.5 * (hi[j] - lo[j])
                bl, bu = F @ c - np.abs(F) @ r, F @ c + np.abs(F) @ r
                umin = np.maximum(zl, bl) + G
                umax = np.minimum(zu, bu) + G
                if np.any(umin < self.u_min) or np.any(umax > self.u_max):
                    return True
        return False

    # ---- driver -----------------------------------------------------------------------

    def _piece(
        self, lo: np.ndarray, hi: np.ndarray, complete: bool = False
    ) -> tuple[str, list[Tube], float | None]:
        """Reach the initial box [lo, hi]: 'ok', 'violation' or 'undefined' (possible).

        Stops at the first possible violation unless ``complete``: then it records the
        first one and goes on, so the tube still holds every trajectory of the piece for
        as long as its law is defined (used at the last refinement level).
        """
        n = self.n
        c = 0.5 * (lo + hi)
        r = 0.5 * (hi - lo)
        H0 = np.vstack([np.eye(n), -np.eye(n)])
        h0 = np.concatenate([r, r])
        V0 = np.array(np.meshgrid(*[[-ri, ri] for ri in r], indexing="ij")).reshape(n, -1).T
        stack = [_Set(c, np.eye(n), 0.0, 0, (), H0, h0, V0)]
        tubes: list[Tube] = []
        status, first_t = "ok", None

        def flag(kind: str, when: float) -> bool:
            nonlocal status, first_t
            if status == "ok":
                status, first_t = kind, when
            return not complete  # stop now?

        while stack:
            s = stack.pop()
            t = s.k * self.Ts
            A, b = self.law.domain_A, self.law.domain_b
            if A is not None and A.shape[0]:
                _, up = s.range(A)
                sup = A @ s.y + up + np.linalg.norm(A @ self.Winv, axis=1) * s.rho
                if np.any(sup > b) and flag("undefined", t):
                    return status, tubes, first_t
            for i, child in self._split(s):
                self.stats["branches"] += 1
                nxt, tube, findings = self._period(child, i)
                tubes.append(tube)
                if findings:
                    # the enclosure failed: this branch cannot go on, even when complete
                    flag("violation", findings[0].t)
                    return status, tubes, first_t
                if self._violations(tube, i, child):
                    when = float(tube.t_start[0]) if tube.num_boxes else t
                    if flag("violation", when):
                        return status, tubes, first_t
                if nxt is not None and nxt.k * self.Ts < self.T - 1e-12:
                    stack.append(nxt)
            if self.progress is not None:
                self.progress(dict(self.stats))
        return status, tubes, first_t

    def _split(self, s: _Set) -> list[tuple[int, _Set]]:
        """One child per region the set meets, its deviation polytope cut by the region.

        A state x = y + D d + r is in region i only if A_i D d <= b_i - A_i y + |A_i r|,
        and |a'r| <= |W^-T a| rho: adding these rows to the deviation polytope keeps every
        state of the region (plus 1e-9) -- exact for the star part, sound for the ball.
        """
        from .reach_linear import _checked_vertices

        xlo, xhi = self._box(s)
        cand = np.flatnonzero(
            np.all(self.boxes_lo <= xhi + 1e-9, axis=1)
            & np.all(self.boxes_hi >= xlo - 1e-9, axis=1)
        )
        out = []
        X = s.y[None, :] + s.V @ s.D.T  # images of the deviation polytope's vertices
        for i in cand:
            Ai, bi = self.law.A[i], self.law.b[i]
            slack = np.linalg.norm(Ai @ self.Winv, axis=1) * s.rho + 1e-9
            viol = X @ Ai.T - bi  # (nv, rows)
            if np.any(np.all(viol > slack, axis=0)):
                continue  # one row of the region excludes the whole set (convex hull)
            if np.all(viol <= -slack):
                out.append((int(i), _Set(s.y, s.D, s.rho, s.k, s.path + (int(i),), s.H, s.h, s.V)))
                continue  # the whole set is inside the region: no cut needed
            Hn = np.vstack([s.H, Ai @ s.D])
            hn = np.concatenate([s.h, bi - Ai @ s.y + slack])
            Hn, hn, ok = normalize_rows(Hn, hn)
            if not ok:
                continue
            _, radius = chebyshev_ball(Hn, hn)
            if not radius > 0:
                continue
            keep = minimal_rows(Hn, hn)
            Hn, hn = Hn[keep], hn[keep]
            V = _checked_vertices(Hn, hn)
            out.append((int(i), _Set(s.y, s.D, s.rho, s.k, s.path + (int(i),), Hn, hn, V)))
        return out

    def run(self) -> None:
        """Refine the initial set until every piece is proved or the depth runs out."""
        from .simulate import first_violation, simulate

        vs = self.problem.verify
        queue = [(vs.initial_lower.astype(float), vs.initial_upper.astype(float), 0)]
        while queue:
            lo, hi, depth = queue.pop()
            self.stats["partitions"] += 1
            status, tubes, t_bad = self._piece(lo, hi, complete=depth >= self.max_depth)
            if status == "ok":
                self.tubes.extend(tubes)
                continue
            # a concrete trajectory from the piece's centre may settle it
            x0 = 0.5 * (lo + hi)
            trace = simulate(self.problem, self.law, x0, hold=self.hold)
            v = first_violation(self.problem, self.law, trace)
            if v is not None:
                rad = np.diag(self.V0)
                alpha = np.where(rad > 0, (x0 - self.c0) / np.where(rad > 0, rad, 1.0), 0.0)
                self.findings.append(Finding(v.kind, int(v.index), float(v.t), alpha))
                self.tubes.extend(tubes)
                return
            if depth >= self.max_depth:
                kind = "undefined" if status == "undefined" else "max_depth"
                self.findings.append(Finding(kind, -1, float(t_bad or 0.0), None))
                self.tubes.extend(tubes)
                continue
            self.stats["refinements"] += 1
            # bisect the axis that is widest in the metric
            r = 0.5 * (hi - lo)
            ax = int(np.argmax(np.linalg.norm(self.W * r[None, :], axis=0)))
            mid = 0.5 * (lo[ax] + hi[ax])
            hi1 = hi.copy()
            hi1[ax] = mid
            lo2 = lo.copy()
            lo2[ax] = mid
            queue.append((lo2, hi, depth + 1))
            queue.append((lo, hi1, depth + 1))


def _gronwall(rho: float, mu: float, a: float, S: float, h: float, b: float) -> float:
    """Bound of |r(h)|_W for r' = Jc r + w, |w|_W <= a (S + |r|_W) + b, |r(0)|_W <= rho."""
    k = mu + a
    grow = np.exp(k * h)
    integ = h if abs(k * h) < 1e-12 else (grow - 1.0) / k
    return float(grow * rho + integ * (a * S + b)) * (1 + 1e-12)


_GAMMA = 4 * 2.0**-52  # per-term rounding allowance for short float sums and products


def _imat_add_point(Al, Ah, Bl, Bh, F):
    """[A] + [B] F for interval matrices [A] (n,n), [B] (n,m) and a point matrix F (m,n).

    Float sums are widened by the size of their *terms* (a cancelling sum's rounding error
    scales with the terms, not with the result).
    """
    Fp, Fn = np.maximum(F, 0), np.minimum(F, 0)
    lo = Al + Bl @ Fp + Bh @ Fn
    hi = Ah + Bh @ Fp + Bl @ Fn
    k = F.shape[0] + 2
    mag = np.maximum(np.abs(Al), np.abs(Ah)) + np.maximum(np.abs(Bl), np.abs(Bh)) @ np.abs(F)
    pad = k * _GAMMA * mag + 1e-300
    return lo - pad, hi + pad


def _imatvec(Al, Ah, xl, xh):
    """Interval matrix times interval vector, widened by the size of the summed terms."""
    cands = np.stack([Al * xl, Al * xh, Ah * xl, Ah * xh])
    lo = cands.min(axis=0).sum(axis=1)
    hi = cands.max(axis=0).sum(axis=1)
    pad = (xl.shape[0] + 2) * _GAMMA * np.abs(cands).max(axis=0).sum(axis=1) + 1e-300
    return lo - pad, hi + pad


def _add_pad(*terms):
    """Rounding allowance of a short float sum of these terms (element-wise)."""
    return (len(terms) + 1) * _GAMMA * sum(np.abs(t) for t in terms) + 1e-300


def _dn(x):
    return np.nextafter(np.nextafter(x, -np.inf), -np.inf)


def _up(x):
    return np.nextafter(np.nextafter(x, np.inf), np.inf)
