"""Sound reachtubes for nonlinear plants: the sets followed from the initial set to the horizon.

A reach set at a sample is ``{y + D d + M e + r : d in P, |e|_2 <= 1}``: a centre, a star
over the initial deviation ``d`` (a polytope ``P``) and a remainder ellipsoid.
``reach/nonlinear_flow.py`` (``NonlinearFlow``, the base class) carries one such set over one
period in one region of the law, with the tube's boxes over the period; its docstring and
docs/verification.md hold the proofs. ``NonlinearReach`` drives it:

- At each sample a set is cut by the law's regions (``_split``: one child per region it
  meets; a set the law's domain may not hold is ``undefined``), each child is carried over
  the period and its tube checked against the properties (``_violations``: the unsafe and
  safe sets, the input bounds).
- Sets that reach the same sample are merged into one star when that costs little (the
  difference of their affine maps is absorbed by the ellipsoid), which keeps the number of
  branches from multiplying at every crossing of a region boundary (``_merge``). Under
  disturbances or uncertain parameters a set whose remainder outweighs its star is
  re-rooted as a polytope (``_rerooted``), and a set inside an invariant ellipsoid of
  ``absorb`` is not followed further (``_absorbed``).
- A cell of the initial set whose ellipsoid outgrows its star is bisected (the
  second-order remainder shrinks with the square of the cell's size), up to
  ``bloat_depth``; a cell not proved is bisected up to ``max_depth``, its centre simulated
  for a concrete counterexample (``_cell``, ``_commit``). The cells are taken depth first
  (``run``), in this process or as an executor's tasks (``_cell_task``) in the serial
  order, within the exploration limits; after a budget's stop ``_complete_until`` keeps
  the tube of the cell in progress.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.executor import Executor, result_resubmitting, scattered
from codev_engine.geometry.polytope import solve_lp
from codev_engine.geometry.vertices import checked_piece
from codev_engine.limits import beat
from codev_engine.reach.linear import ExplorationLimitError, Finding
from codev_engine.reach.matrix_bounds import GAMMA, down2, up2
from codev_engine.reach.nonlinear_flow import _U, NonlinearFlow, _ell_rows, _Rec, _Set
from codev_engine.reach.tube import Tube

__all__ = ["NonlinearReach"]


@dataclass
class NonlinearReach(NonlinearFlow):
    """Reachability engine for a nonlinear plant (see the module docstrings of this module
    and of ``reach/nonlinear_flow.py``).

    After :meth:`run`, ``tubes`` holds the reachtube's pieces and ``findings`` the
    violations found (see ``linear.ClosedLoopSetup``).

    Attributes
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
    hold : {"zoh", "continuous"}
        How the input is applied between samples: held at the sample's value, or the law
        evaluated continuously.
    max_depth : int
        How many times the initial box may be bisected (a piece that is not proved at
        this depth gives a ``max_depth`` or ``undefined`` finding).
    progress : callable, optional
        Called with a copy of ``stats`` plus ``samples`` (the sample reached) and ``boxes``
        (the reachtube's boxes so far) after each branch period.
    stats : dict
        Counters updated by :meth:`run`: ``branches``, ``refinements``, ``partitions``,
        ``merges``.
    merge_cost : float
        Sets at a sample are merged when the merged remainder grows by at most this
        fraction of the set's size (in the W-norm; a heuristic: any merge is sound) ...
    max_sets : int
        ... and at most this many sets are kept per sample (cheapest merges first).
    bloat : float
        A cell whose remainder ellipsoid's W-size exceeds this multiple of its star's at a
        sample is bisected (a tightness heuristic; every split is sound) ...
    bloat_depth : int
        ... while its refinement depth is below this (and below ``max_depth``).
    absorb : callable, optional
        ``absorb(lo (n,), hi (n,)) -> (e,) bool``: which of ``e`` invariant sets (the
        ellipsoids of ``reach.terminal``) hold the box. A set whose box at a sample lies in
        one of them that holds every set absorbed before is recorded in ``absorbed``
        (``(sample, lo, hi)``) and not followed further; ``absorb_mask`` marks the sets that
        hold every absorbed box (None before the first), ``open_sets`` counts the sets that
        reached the horizon. In this process only: the cells an executor computes ignore
        it.
    reroot : float or None
        Under disturbances or uncertain parameters, a set whose remainder ellipsoid exceeds
        this fraction of its star at a sample is replaced by a polytope holding both, so
        the law's region cuts act on all of it (docs/verification.md, "Refuting first,
        and the remainder re-rooted"). None: never.
    carry : bool
        Under disturbances or uncertain parameters, their first-order part is carried
        through the linear flow as a zonotope (``reach/carried.py``) and folded into the
        star at each sample; False: it goes into the remainder ball, as before.
    continuous_substeps : int
        With ``carry``, under the continuous hold: how many substeps each ``step`` is cut
        into (docs/verification.md, "The continuous hold's substep").
    """

    max_depth: int
    progress: Callable[[dict], None] | None = None
    #: merge sets at a sample when the merged remainder grows by at most this fraction of
    #: the set's size (in the W-norm; a heuristic: any merge is sound) ...
    merge_cost: float = 0.1
    #: ... and always keep at most this many sets per sample (cheapest merges first)
    max_sets: int = 4
    #: ``absorb(lo, hi) -> (e,) bool``, which invariant sets hold a box: a set whose box at a
    #: sample lies in one of them (one that holds every set absorbed before) is not followed
    #: further; ``absorbed`` records it. None: every set is followed to the horizon (serial
    #: runs only: an executor's cells ignore it)
    absorb: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    #: a cell whose remainder ellipsoid outgrows this fraction of its star (W-sizes) at a
    #: sample is bisected (a tightness heuristic: the second-order remainder shrinks with
    #: the square of the cell's size; every split is sound) ...
    bloat: float = 1.0
    #: ... while its refinement depth is below this (and below ``max_depth``)
    bloat_depth: int = 2
    #: with disturbances or uncertain parameters: a set at a sample whose remainder
    #: ellipsoid's W-size exceeds this fraction of its star's is re-rooted (its star and
    #: ellipsoid replaced by a polytope over the deviation from its centre, which the region
    #: cuts then act on; ``_rerooted``). None: never (the remainder stays an ellipsoid)
    reroot: float | None = 0.25

    def __post_init__(self) -> None:
        super().__post_init__()  # (the plant's enclosures, the metric, the step)
        # the driver's own state: the enclosure failure met, the absorbed sets
        self._failed: Finding | None = None
        #: with ``absorb``: ``(sample, lo, hi)`` of each set left in the ellipsoids, the
        #: ellipsoids that hold all of them (a mask), the sets that reached the horizon
        self.absorbed: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.absorb_mask: np.ndarray | None = None
        self.open_sets = 0

    # ---- properties -------------------------------------------------------------------

    def _violations(self, tube: Tube, i: int, s: _Set, rec: _Rec) -> bool:
        """Does the period's reach set possibly violate a property?

        Each substep's set is bounded both by its box B and by the set at the substep's
        start plus the sweep [0, h] f(B); the tighter of the two bounds is used per row.
        """
        lo, hi = tube.lower, tube.upper
        if lo.shape[0] == 0:
            return False
        for A, b in self.unsafe:
            zl, _ = self._support(rec, A)
            bl = lo @ np.where(A > 0, A, 0).T + hi @ np.where(A < 0, A, 0).T
            sep = np.any(np.maximum(zl, bl) > b[None, :], axis=1)
            for j in np.flatnonzero(~sep):
                # box B intersected with the half-spaces A x >= zl that hold on the set
                Aq = np.vstack([A, -A])
                bq = np.concatenate([b + 1e-12, -zl[j]])
                x, st, _ = solve_lp(np.zeros(self.n), Aq, bq, lb=lo[j], ub=hi[j])
                if st == "optimal":
                    return True
        for A, b in self.safe:
            _, zu = self._support(rec, A)
            bu = hi @ np.where(A > 0, A, 0).T + lo @ np.where(A < 0, A, 0).T
            if np.any(np.minimum(zu, bu) > b[None, :]):
                return True
        if self.check_u:
            F, G = self.law.F[i], self.law.G[i]
            if self.hold == "zoh":
                # (with noise too: the input is the law at a point x + v of the region)
                if self._region_u_ok(i):
                    return False
                # range of the held input: over the star (cut by the region) and over the
                # box within the region (LPs); both are sound, take the tighter
                dlo, dhi = s.range(F)
                e = s.ell(F)
                nu = np.zeros(self.m)
                if self.vr is not None:  # F (x + vc) + G + F delta, |F delta| <= nu
                    G, nu = self.Gn[i], self._noise_input(i)
                c = F @ s.y + G
                pad = 1e-12 * (1 + np.abs(c) + np.abs(F) @ (np.abs(s.y) + s.mag()) + e)
                slo, shi = c + dlo - e - pad - nu, c + dhi + e + pad + nu
                xlo, xhi = self._box(s)
                if self.vr is not None:  # the measurement x + v: in this box and the region
                    xlo, xhi = down2(xlo + self.vc - self.vr), up2(xhi + self.vc + self.vr)
                ulo, uhi = self._u_range(i, xlo, xhi)
                ulo, uhi = np.maximum(ulo, slo), np.minimum(uhi, shi)
                umin, umax = self._u_bounds(i)
                return bool(np.any(ulo < umin) or np.any(uhi > umax))
            zl, zu = self._support(rec, F)
            c, r = 0.5 * (lo + hi), 0.5 * (hi - lo)
            bl, bu = c @ F.T - r @ np.abs(F).T, c @ F.T + r @ np.abs(F).T
            if self.vr is None:
                umin = np.maximum(zl, bl) + G
                umax = np.minimum(zu, bu) + G
            else:  # F (x + vc) + G + F delta: about Gn, widened by |F delta| <= nu
                nu = self._noise_input(i)
                umin = np.maximum(zl, bl) + self.Gn[i] - nu
                umax = np.minimum(zu, bu) + self.Gn[i] + nu
            # u(t) = u(t_k) + int F f: u(t_k) lies in the region's range of the law, and the
            # integral is bounded by the substeps' [F f](B) (a state at the region's edge
            # that moves inwards keeps its input inside the bounds)
            rlo, rhi = self._region_u(i)
            Fp, Fn = np.maximum(F, 0.0), np.minimum(F, 0.0)
            dlo = rec.flo @ Fp.T + rec.fhi @ Fn.T
            dhi = rec.fhi @ Fp.T + rec.flo @ Fn.T
            fmag = np.maximum(np.abs(rec.flo), np.abs(rec.fhi))
            mag = (self.n + 2) * GAMMA * (fmag @ np.abs(F).T)
            hc = rec.hs[:, None]
            dlo = hc * np.minimum(dlo - mag, 0.0)
            dhi = hc * np.maximum(dhi + mag, 0.0)
            cl = np.cumsum(dlo, axis=0)  # through the end of each substep
            ch = np.cumsum(dhi, axis=0)
            cpad = 8 * _U * np.cumsum(np.abs(dlo) + np.abs(dhi), axis=0) * lo.shape[0]
            umin = np.maximum(umin, rlo + cl - cpad)
            umax = np.minimum(umax, rhi + ch + cpad)
            pad = 1e-12 * (1 + np.abs(umin) + np.abs(umax))
            bmin, bmax = self._u_bounds(i)
            if np.any(umin - pad < bmin) or np.any(umax + pad > bmax):
                return True
        return False

    # ---- driver -----------------------------------------------------------------------

    def _piece(
        self, lo: np.ndarray, hi: np.ndarray, complete: bool = False, split: bool = False
    ) -> tuple[str, list[Tube], float | None]:
        """Reach the initial box [lo, hi]: 'ok', 'violation' or 'undefined' (possible), or
        'bloat' (with ``split``: a set's remainder outgrew ``bloat`` times its star, the
        box is better bisected).

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
        root = _Set(c, np.eye(n), np.zeros((n, n)), 0, (), H0, h0, V0)
        root.base = root.poly
        root_poly = root.poly  # holds every set's deviation polytope (for merges)
        frontier = [root]
        tubes: list[Tube] = []
        self._in_progress = (lo, hi, tubes)  # (what a budget stop keeps: _complete_until)
        status, first_t = "ok", None
        self._rho_hint = 0.0
        self._q_hint = None

        def flag(kind: str, when: float) -> bool:
            nonlocal status, first_t
            if status == "ok":
                status, first_t = kind, when
            return not complete  # stop now?

        while frontier:
            nexts: list[_Set] = []
            for s in frontier:
                t = s.k * self.Ts
                # the law's domain near the set (the whole domain of a full law; the rows
                # there of a law computed on demand, law_on_demand.py)
                A, b = self._domain_near(s)
                if A is not None and A.shape[0]:
                    _, up = s.range(A)
                    pad = 1e-12 * (1 + np.abs(A) @ (np.abs(s.y) + s.mag()))
                    sup = A @ s.y + up + s.ell(A) + pad
                    if self.vr is not None:  # a measurement x + v that may leave
                        sup = sup + (A @ self.vc + np.abs(A) @ self.vr) * (1.0 + 1e-12)
                    if np.any(sup > b) and flag("undefined", t):
                        return status, tubes, first_t
                children = self._split(s)
                if not children and flag("undefined", t):
                    return status, tubes, first_t
                for i, child in children:
                    self.stats["branches"] += 1
                    self._t_now, self._sample = t, s.k  # (where a deadline stops the run)
                    beat("enclosures")
                    nxt, tube, findings, rec = self._period(child, i)
                    tubes.append(tube)
                    self._tick(tube.num_boxes, child.k + 1, (child.k + 1) * self.Ts)
                    if findings:
                        # the enclosure failed: this branch cannot go on, even when complete
                        if findings[0].kind == "enclosure" and self._failed is None:
                            self._failed = findings[0]
                        flag("violation", findings[0].t)
                        return status, tubes, first_t
                    if self._violations(tube, i, child, rec):
                        when = float(tube.t_start[0]) if tube.num_boxes else t
                        if flag("violation", when):
                            return status, tubes, first_t
                    if nxt is not None and nxt.Z is not None:
                        # the disturbances' carried zonotope becomes part of the star
                        (nxt,), root_poly = self._rerooted([nxt], root_poly)
                    if nxt is not None and nxt.k * self.Ts < self.T - 1e-12:
                        if not self._absorbed(nxt):
                            nexts.append(nxt)
                    elif nxt is not None:
                        self.open_sets += 1
            frontier = self._merge(nexts, root_poly)
            if self.reroot is not None and self.xlo is not None and frontier:
                # disturbances, parameters: the remainder ellipsoid (their doing) becomes
                # part of the star, so the region cuts of the next sample act on it
                frontier, root_poly = self._rerooted(frontier, root_poly)
            if split and status == "ok" and any(self._bloated(s) for s in frontier):
                return "bloat", tubes, frontier[0].k * self.Ts
        return status, tubes, first_t

    def _template(self, s: _Set) -> np.ndarray:
        """Directions of a set's template hull (rows, in state coordinates).

        The axes and pairwise diagonals measured in the metric ``W`` (16 directions evenly
        spread in the plane of ``W`` when ``n = 2``), and the facets of the star
        ``{D d : H d <= h}`` (``H D^-1`` when ``D`` is well conditioned). Any directions
        give a sound hull; these keep it tight. When the disturbances' linear part is
        carried (``carry``: every set is re-rooted at every sample) the star's facets are
        left out, or the polytope would gain a template's worth of vertices per sample;
        64 directions in the plane instead of 16 keep the hull within 0.12 % of the set.
        """
        n = self.n
        carrying = self._carrying
        if n == 2:
            q = 64 if carrying else 16
            ang = np.arange(q) * (2 * np.pi / q)
            U = np.stack([np.cos(ang), np.sin(ang)], axis=1)
        else:
            rows = [np.eye(n), -np.eye(n)]
            for i in range(n):
                for j in range(i + 1, n):
                    for si in (1.0, -1.0):
                        for sj in (1.0, -1.0):
                            r = np.zeros(n)
                            r[i], r[j] = si, sj
                            rows.append(r[None, :] / np.sqrt(2.0))
            U = np.vstack(rows)
        A = U @ self.W  # a' z = u' (W z): the direction u in W-space
        if carrying and n > 2:
            # and the state axes and their diagonals themselves: the tube is read per state,
            # and a thin state's extent must not come from W's tilted rows
            A = np.vstack([A, U])
        if (not carrying or n > 2) and s.H is not None and np.linalg.cond(s.D) < 1e8:
            A = np.vstack([A, s.H @ np.linalg.inv(s.D)])
        A = A[np.linalg.norm(A, axis=1) > 0]
        return A / np.linalg.norm(A, axis=1, keepdims=True)

    def _rerooted(self, sets: list[_Set], root_poly: tuple) -> tuple[list[_Set], tuple]:
        """Each set whose remainder ellipsoid outweighs ``reroot`` times its star, as a
        star over the deviation from its centre with no ellipsoid, and the polytope that
        holds every set's deviation polytope (for the merges of later samples).

        The set ``{y + D d + M e : d in P, |e|_2 <= 1}`` lies in ``{y + z : a_r' z <=
        e_r}`` with ``e_r = max_{v in vert P} a_r' D v + |M' a_r|_2`` for any rows
        ``a_r`` (the support of a Minkowski sum is the sum of the supports; a star's is
        at a vertex, an ellipsoid's is ``|M' a|_2``), padded by the rounding of the
        products (``1e-12`` of the magnitudes). The new set is ``{y + I z + 0 e : z in
        P'}``, ``P'`` that polytope: it contains the old one, so every trajectory it held
        is still held. Its coordinates ``z`` are no initial deviations (the nonlinear
        engine never turns a set's coordinates into an initial state: its concrete
        findings come from simulated cell centres), and merges later need a polytope
        holding every set's coordinates: the box hull of the old one and the new ``P'``.

        Parameters
        ----------
        sets : list of _Set
            The sets at one sample.
        root_poly : tuple
            ``(H, h, V)`` holding every set's deviation polytope.

        Returns
        -------
        (list of _Set, tuple)
        """
        n = self.n
        out: list[_Set] = []
        pts = [root_poly[2]]
        for s in sets:
            star = float(np.max(np.linalg.norm(s.V @ (self.W @ s.D).T, axis=1)))
            ell = float(np.linalg.norm(self.W @ s.M, 2))
            if s.Z is None and not ell > self.reroot * star:
                out.append(s)
                continue
            A = self._template(s)
            _, up = s.range(A)
            mag = np.abs(A) @ s.mag()
            e = up + s.ell(A)
            if s.rem is not None:
                # the remainder lies in the W-ball and in its zonotope: the smaller support
                PM, rad, qc, Q = s.rem
                alt = up + _ell_rows(A @ PM) + A @ qc + np.abs(A @ Q).sum(axis=1)
                # (one of the two whole: a per-direction minimum is no support function,
                # and in the plane its polygons defeated the vertex enumeration)
                if alt.sum() < e.sum():
                    e = alt
                mag = mag + (np.abs(A) @ np.abs(Q)).sum(axis=1) + np.abs(A) @ (
                    np.abs(PM).sum(axis=1) + np.abs(qc))
            if s.Z is not None:  # the zonotope's support: sum_l |a' z_l|
                AZ = np.abs(A @ s.Z)
                e = e + AZ.sum(axis=1)
                mag = mag + (np.abs(A) @ np.abs(s.Z)).sum(axis=1)
            e = e * (1 + 1e-12) + 1e-12 * (1.0 + mag) + 1e-300
            try:
                piece = checked_piece(A, e)
            except ValueError:
                piece = None
            if piece is None:  # (not expected: the set holds its centre's neighbourhood)
                out.append(self._unzoned(s))
                continue
            H, h, V = piece
            poly = (H, h, V)
            out.append(_Set(s.y, np.eye(n), np.zeros((n, n)), s.k, s.path, H, h, V, poly))
            pts.append(V)
        if len(pts) == 1:
            return out, root_poly
        P = np.vstack(pts)
        lo, hi = P.min(axis=0), P.max(axis=0)
        pad = 1e-12 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
        lo, hi = lo - pad, hi + pad
        H0 = np.vstack([np.eye(n), -np.eye(n)])
        h0 = np.concatenate([hi, -lo])
        V0 = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)],
                                  indexing="ij")).reshape(n, -1).T
        return out, (H0, h0, V0)

    def _unzoned(self, s: _Set) -> _Set:
        """The set with its zonotope ``Z`` (if any) folded into the remainder ellipsoid
        (``|Z t|_W <= sum_l |W z_l|_2``: a ball of that radius holds it)."""
        if s.Z is None:
            return s
        r = float(np.linalg.norm(self.W @ s.Z, axis=0).sum()) * (1 + 1e-12)
        return _Set(s.y, s.D, self._ell_plus_ball(s.M, r), s.k, s.path, s.H, s.h, s.V, s.base)

    def _bloated(self, s: _Set) -> bool:
        """Is the set's remainder ellipsoid larger than ``bloat`` times its star (W-sizes)?

        Parameters
        ----------
        s : _Set
            A set at a sample.

        Returns
        -------
        bool
        """
        star = float(np.max(np.linalg.norm(s.V @ (self.W @ s.D).T, axis=1)))
        return float(np.linalg.norm(self.W @ s.M, 2)) > self.bloat * star

    def _absorbed(self, s: _Set) -> bool:
        """Does the set (at a sample) lie in an invariant ellipsoid of ``absorb`` that holds
        every set absorbed so far? Then it is recorded and not followed: every later state
        of its trajectories stays in the ellipsoid at the samples and in the ellipsoid's
        period box between them (``reach.terminal``; docs/verification.md)."""
        if self.absorb is None:
            return False
        lo, hi = self._box(s)
        inside = np.asarray(self.absorb(lo, hi), dtype=bool)
        mask = inside if self.absorb_mask is None else inside & self.absorb_mask
        if not np.any(mask):
            return False
        self.absorb_mask = mask
        self.absorbed.append((int(s.k), lo, hi))
        return True

    def _seen_box(self, s: _Set) -> tuple[np.ndarray, np.ndarray]:
        """The box of what the law may see of the set: its states, plus the noise."""
        xlo, xhi = self._box(s)
        if self.vr is not None:  # what the law may see: x + v
            xlo, xhi = down2(xlo + self.vc - self.vr), up2(xhi + self.vc + self.vr)
        return xlo, xhi

    def _domain_near(self, s: _Set) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Rows of the law's domain valid on it that describe it around the set (what the
        law may see of it): ``law.domain_rows`` (None, None when unknown)."""
        if not (getattr(self.law, "on_demand", False) or getattr(self.law, "local_domain", False)):
            return self.law.domain_A, self.law.domain_b
        rows = self.law.domain_rows(*self._seen_box(s))
        self._law_grown()
        return (None, None) if rows is None else rows

    def _split(self, s: _Set) -> list[tuple[int, _Set]]:
        """One child per region the set meets, its deviation polytope cut by the region.

        A state x = y + D d + M e is in region i only if A_i D d <= b_i - A_i y + |A_i M e|,
        and |a' M e| <= |M' a|_2: adding these rows to the deviation polytope keeps every
        state of the region (plus 1e-9) -- exact for the star part, sound for the ellipsoid.
        """
        xlo, xhi = self._seen_box(s)
        # the regions whose box meets the set's (within 1e-9); a law computed on demand
        # computes those that meet it now
        cand = self.law.regions_meeting(xlo, xhi)
        self._law_grown()
        out = []
        X = s.y[None, :] + s.V @ s.D.T  # images of the deviation polytope's vertices
        xpad = 1e-12 * (np.abs(s.y) + s.mag())
        poly = s.poly
        for i in cand:
            # (with noise: the states whose measurement x + v may be in the region)
            Ai, bi = self.law.A[i], self._reach_rows(self.law.A[i], self.law.b[i])
            slack = s.ell(Ai) + 1e-9 + np.abs(Ai) @ xpad
            viol = X @ Ai.T - bi  # (nv, rows)
            if np.any(np.all(viol > slack, axis=0)):
                continue  # one row of the region excludes the whole set (convex hull)
            if np.all(viol <= -slack):
                out.append(
                    (int(i), _Set(s.y, s.D, s.M, s.k, s.path + (int(i),), s.H, s.h, s.V, poly))
                )
                continue  # the whole set is inside the region: no cut needed
            try:
                piece = checked_piece(
                    np.vstack([s.H, Ai @ s.D]), np.concatenate([s.h, bi - Ai @ s.y + slack])
                )
            except ValueError:
                # no enclosing points for the cut (a degenerate sliver): the uncut
                # polytope, a superset
                piece = (s.H, s.h, s.V)
            if piece is None:
                continue
            Hn, hn, V = piece
            out.append((int(i), _Set(s.y, s.D, s.M, s.k, s.path + (int(i),), Hn, hn, V, poly)))
        return out

    # ---- merging ----------------------------------------------------------------------

    def _merged(self, sets: list[_Set], poly: tuple) -> tuple[_Set, float]:
        """One set containing every set of the list, and its cost.

        Each set is ``{y_j + D_j d + M_j e : d in P_j}`` with ``P_j`` inside the polytope
        ``poly``. The merged star ``y + D d`` (d in poly) is the least-squares fit of the
        sets' affine maps at their vertices; for d in P_j the mismatch
        ``(y_j - y) + (D_j - D) d`` is at most ``mu_j`` in the W-norm (convex in d: at
        P_j's vertices), so ``E(M_j) + ball_W(mu_j)`` holds the set's remainder; the merged
        ellipsoid contains all of those. Cost: growth of the remainder's W-size relative to
        the star's.
        """
        Vs = [s.V for s in sets]
        Ts = [s.y[None, :] + s.V @ s.D.T for s in sets]
        Amat = np.hstack([np.ones((sum(v.shape[0] for v in Vs), 1)), np.vstack(Vs)])
        coef, *_ = np.linalg.lstsq(Amat, np.vstack(Ts), rcond=None)
        y = coef[0].copy()
        D = coef[1:].T.copy()
        ells = []
        r_old = 0.0
        for s, V, T in zip(sets, Vs, Ts, strict=True):
            fit = y[None, :] + V @ D.T
            mis = np.linalg.norm((T - fit) @ self.W.T, axis=1).max()
            mag = (np.abs(T) + np.abs(y)[None, :] + np.abs(V) @ np.abs(D).T).sum(axis=1).max()
            mu = float(mis) * (1 + 1e-9) + 1e-12 * self.Wn * float(mag)
            ells.append(self._ell_plus_ball(s.M, mu))
            r_old = max(r_old, float(np.linalg.norm(self.W @ s.M, 2)))
        Mm = self._ell_hull(ells)
        r_new = float(np.linalg.norm(self.W @ Mm, 2))
        star = float(np.max(np.linalg.norm(poly[2] @ (self.W @ D).T, axis=1)))
        cost = (r_new - r_old) / max(star + r_old, 1e-300)
        k = sets[0].k
        merged = _Set(y, D, Mm, k, sets[0].path, poly[0], poly[1], poly[2], poly)
        return merged, cost

    @property
    def _carrying(self) -> bool:
        """Is the disturbances' linear part carried as a zonotope (``carry``)?"""
        return self.carry and self.xlo is not None

    def _rooted(self, s: _Set) -> bool:
        """Is the set a plain polytope over the deviation from its centre (``D = I``, no
        ellipsoid: re-rooted, or a cell's first set)?"""
        return s.Z is None and not s.M.any() and np.array_equal(s.D, np.eye(self.n))

    def _hulled(self, sets: list[_Set]) -> _Set | None:
        """One polytope holding plain polytopes ``{y_j + z : z in P_j}`` (``_rooted``):
        ``{y + z : a_r' z <= max_j max_{v in vert P_j} a_r' (v + y_j - y)}`` over the
        template's directions and every set's facets (the support of a polytope is at a
        vertex, of a union the largest), padded by ``1e-12`` of the products' magnitudes.
        None when no polytope could be formed (the caller merges as before)."""
        y = np.mean([s.y for s in sets], axis=0)
        A = self._template(sets[0])
        e = np.full(A.shape[0], -np.inf)
        mag = np.zeros(A.shape[0])
        for s in sets:
            P = s.V + (s.y - y)[None, :]
            e = np.maximum(e, (P @ A.T).max(axis=0))
            mag = np.maximum(mag, ((np.abs(s.V) + np.abs(s.y) + np.abs(y)) @ np.abs(A).T)
                             .max(axis=0))
        e = e + 1e-12 * (1.0 + mag) + 1e-300
        try:
            piece = checked_piece(A, e)
        except ValueError:
            piece = None
        if piece is None:
            return None
        H, h, V = piece
        return _Set(y, np.eye(self.n), np.zeros((self.n, self.n)), sets[0].k, sets[0].path,
                    H, h, V, (H, h, V))

    def _merge(self, sets: list[_Set], root_poly: tuple) -> list[_Set]:
        """Merge the sets of one sample greedily (closest pair first) while the cost is
        below ``merge_cost`` or there are more than ``max_sets`` sets."""
        if len(sets) <= 1:
            return sets
        sets = list(sets)
        if self._carrying and all(self._rooted(s) for s in sets):
            hull = self._hulled(sets)
            if hull is not None:
                self.stats["merges"] += len(sets) - 1
                return [hull]

        def poly_of(group):
            b = group[0].base
            return b if all(g.base is b for g in group) else root_poly

        # usually the whole sample merges cheaply: try that first
        whole, cost = self._merged(sets, poly_of(sets))
        if cost <= self.merge_cost:
            self.stats["merges"] += len(sets) - 1
            return [whole]
        # greedy: merge the pair whose bounding boxes' hull grows least (a cheap proxy of
        # the merge's cost), while the real cost is small or there are too many sets
        groups = [[s] for s in sets]
        bx = [self._box(s) for s in sets]
        glo = np.array([b[0] for b in bx])
        ghi = np.array([b[1] for b in bx])
        current = list(sets)
        while len(current) > 1:
            w = ghi - glo
            scale = np.maximum(w.max(axis=0), 1e-300)
            hull = np.maximum(ghi[:, None], ghi[None]) - np.minimum(glo[:, None], glo[None])
            grow = ((hull - np.maximum(w[:, None], w[None])) / scale).sum(axis=2)
            grow[np.diag_indices(len(current))] = np.inf
            p, q = np.unravel_index(int(np.argmin(grow)), grow.shape)
            p, q = min(p, q), max(p, q)
            members = groups[p] + groups[q]
            cand, cost = self._merged(members, poly_of(members))
            if cost > self.merge_cost and len(current) <= self.max_sets:
                break
            self.stats["merges"] += 1
            nlo, nhi = np.minimum(glo[p], glo[q]), np.maximum(ghi[p], ghi[q])
            for idx in (q, p):
                del current[idx]
                del groups[idx]
            keep = np.ones(len(glo), dtype=bool)
            keep[[p, q]] = False
            glo = np.vstack([glo[keep], nlo])
            ghi = np.vstack([ghi[keep], nhi])
            current.append(cand)
            groups.append(members)
        return current

    def _cell(self, lo: np.ndarray, hi: np.ndarray, depth: int) -> tuple:
        """Reach one cell ``[lo, hi]`` of the initial set (at refinement ``depth``); where it
        is not proved, simulate from its centre. A function of the cell alone (and of
        ``stats`` only through the tubes' branch numbers), so any worker may compute it.

        Returns
        -------
        tuple
            ``(status, tubes, t_bad, failed, violation)``: as ``_piece`` gives them, the
            enclosure failure it met (a Finding or None) and the centre's first violation
            (None when the cell is proved or the centre's trajectory is safe).
        """
        from codev_engine.reach.simulate import (
            first_violation,
            nominal_signal,
            simulate,
            simulate_many,
            violations_many,
        )

        self._failed = None
        kept = (len(self.absorbed), self.open_sets,
                None if self.absorb_mask is None else self.absorb_mask.copy())
        status, tubes, t_bad = self._piece(
            lo, hi, complete=depth >= self.max_depth,
            split=depth < min(self.bloat_depth, self.max_depth),
        )
        self._in_progress = None
        v = None
        if status == "bloat":
            # bisected for tightness: nothing was found, the halves are reached afresh
            del self.absorbed[kept[0]:]
            self.open_sets, self.absorb_mask = kept[1], kept[2]
        elif status != "ok":
            # (a piece not proved: what it absorbed is not part of the run's tube)
            del self.absorbed[kept[0]:]
            self.open_sets, self.absorb_mask = kept[1], kept[2]
            # a concrete trajectory from the piece's centre may settle it (screened with the
            # fast fixed-step simulation, confirmed with the reference integrator)
            x0 = 0.5 * (lo + hi)
            # (with noise: the noise's centre at every sample, one valid sequence)
            noise = sig = None
            if self.vr is not None:
                noise = self.vc[None, None, : self.n]
                sig = replace(nominal_signal(self.problem), noise=self.vc[None, : self.n])
            try:
                with np.errstate(all="ignore"):
                    sims = simulate_many(
                        self.problem, self.law, x0[None], hold=self.hold, dt=self.h,
                        noise=noise,
                    )
                if violations_many(self.problem, *sims)[0][0]:
                    trace = simulate(self.problem, self.law, x0, hold=self.hold,
                                     disturbance=sig)
                    v = first_violation(self.problem, self.law, trace)
            except SolverError:
                v = None  # the trajectory is not finite (a singularity): no counterexample
        return status, tubes, t_bad, self._failed, v

    def _commit(self, queue: list, lo, hi, depth: int, out: tuple) -> bool:
        """Take a cell's outcome, in the serial order: its tubes and findings, or its two
        halves pushed on ``queue``. True when the run stops (a concrete violation)."""
        status, tubes, t_bad, failed, v = out
        if status == "ok":
            self.tubes.extend(tubes)
            # the share of the initial set proved so far (a budget's verdict reports it)
            vs = self.problem.verify
            w0 = vs.initial_upper - vs.initial_lower
            share = np.prod(np.where(w0 > 0, (hi - lo) / np.where(w0 > 0, w0, 1.0), 1.0))
            self.stats["proved_share"] = self.stats.get("proved_share", 0.0) + float(share)
            return False
        if v is not None:
            x0 = 0.5 * (lo + hi)
            rad = np.diag(self.V0)
            alpha = np.where(rad > 0, (x0 - self.c0) / np.where(rad > 0, rad, 1.0), 0.0)
            self.findings.append(Finding(v.kind, int(v.index), float(v.t), alpha))
            self.tubes.extend(tubes)
            return True
        if depth >= self.max_depth:
            if failed is not None:
                # names the singular expression, or the enclosure that did not close: the
                # piece's tube ends there (a possible exit found before it is kept too)
                self.findings.append(failed)
                if status == "undefined":
                    self.findings.append(Finding("undefined", -1, float(t_bad or 0.0), None))
            else:
                kind = "undefined" if status == "undefined" else "max_depth"
                self.findings.append(Finding(kind, -1, float(t_bad or 0.0), None))
            self.tubes.extend(tubes)
            return False
        self.stats["refinements"] += 1
        # bisect the axis that is widest in the metric
        r = 0.5 * (hi - lo)
        ax = int(np.argmax(np.linalg.norm(self.W * r[None, :], axis=0)))
        mid = 0.5 * (lo[ax] + hi[ax])
        hi1 = hi.copy()
        hi1[ax] = mid
        lo2 = lo.copy()
        lo2[ax] = mid
        queue.append([lo2, hi, depth + 1, None])
        queue.append([lo, hi1, depth + 1, None])
        return False

    def _complete_until(self, t: float) -> float:
        """After a stop: the tube so far of the cell in progress joins the run's, and the
        time up to which the tube holds every trajectory.

        The cell's sets advance sample by sample, so its tube holds each of its trajectories
        up to the sample of the period in progress (``_t_now``). The proved cells' tubes
        hold theirs for the whole horizon (``stats["proved_share"]`` of the initial set).
        Together they cover the initial set only when no cell is left unexplored: then
        every trajectory is in the tube up to ``_t_now``; else 0 (the partial tube still
        gives the margins reached). ``stats["stopped_cell"]``: the cell's share of the
        initial set, the time its tube reached and its box (``lower``, ``upper``). Without
        a cell in progress (between cells, or the cells on a cluster's workers): 0, the
        proved cells' tubes alone.
        """
        self.stats.setdefault("proved_share", 0.0)
        cell = getattr(self, "_in_progress", None)
        self._in_progress = None
        if cell is None or not cell[2]:
            return 0.0
        lo, hi, tubes = cell
        self.tubes.extend(tubes)
        vs = self.problem.verify
        w0 = vs.initial_upper - vs.initial_lower
        share = float(np.prod(np.where(w0 > 0, (hi - lo) / np.where(w0 > 0, w0, 1.0), 1.0)))
        reached = float(min(t, getattr(self, "_t_now", 0.0)))
        self.stats["stopped_cell"] = {"share": share, "t": reached, "lower": lo.tolist(),
                                      "upper": hi.tolist()}
        # (sets absorbed by an invariant ellipsoid have no tube past it)
        whole = self.stats["proved_share"] + share >= 1.0 - 1e-9 and not self.absorbed
        return reached if whole else 0.0

    def run(self, executor: Executor | None = None, cells: int = 1) -> None:
        """Refine the initial set until every cell is proved or the depth runs out (or
        the exploration grows past ``codev_engine.limits``: a ``"limit"`` finding).

        The cells are taken depth first (a stack: a cell's first half, then its second).
        With an ``executor`` (a Dask cluster) the cells on the stack are computed ahead as
        its tasks, a bounded window of them in flight (``_WINDOW`` per worker), and taken
        in that same order as they come back: the tubes, findings, counters and
        counterexample are those of the serial run (the tubes' branch numbers are offset
        by the branches taken before the cell); cells computed past a counterexample are
        dropped. The limits count the whole run, as in serial: each task reports its
        cell's branches and boxes, and the cell that takes the run past a limit is
        computed again in this process from the run's counters, so the run stops where the
        serial run stops.

        Parameters
        ----------
        executor : Executor, optional
            Where the cells run (default: in this process, one after the other).
        cells : int
            Cut the initial set into ``cells`` equal parts along each axis first (a grid of
            ``cells ** n`` cells, taken in lexicographic order), each then refined up to
            ``max_depth`` times; 1 (default): the initial set is the one first cell.
        """
        self._limited(lambda: self._run(executor, cells))

    def _run(self, executor: Executor | None, cells: int) -> None:
        """:meth:`run`'s work (the limits' check is around it)."""
        vs = self.problem.verify
        lo0, hi0 = vs.initial_lower.astype(float), vs.initial_upper.astype(float)
        queue: list = []
        for idx in reversed(list(np.ndindex(*([int(cells)] * self.n)))):
            i = np.array(idx, dtype=float)
            lo = lo0 + (hi0 - lo0) * i / cells
            hi = np.where(i + 1 == cells, hi0, lo0 + (hi0 - lo0) * (i + 1) / cells)
            queue.append([lo, hi, 0, None])
        client = None if executor is None or executor.kind == "serial" else executor.client
        if client is None:
            while queue:
                lo, hi, depth, _ = queue.pop()
                self.stats["partitions"] += 1
                if self._commit(queue, lo, hi, depth, self._cell(lo, hi, depth)):
                    return
            return
        import uuid

        token = uuid.uuid4().hex
        data = (self.problem, self.law, self.hold, self.max_depth, self.merge_cost,
                self.max_sets, self.bloat, self.bloat_depth)
        shared = scattered(client, data)

        def submit(lo, hi, depth):
            nonlocal shared
            shared = scattered(client, data, shared)  # (again, if a lost worker took it)
            return client.submit(_cell_task, shared, token, lo, hi, depth, pure=False)

        window = _WINDOW * max(1, executor.workers)
        try:
            while queue:
                busy = 0
                for entry in reversed(queue):  # the next cells to take first
                    if entry[3] is None:
                        entry[3] = submit(*entry[:3])
                    busy += 1
                    if busy >= window:
                        break
                lo, hi, depth, future = queue[-1]
                (out, counts), queue[-1][3] = result_resubmitting(
                    future, lambda lo=lo, hi=hi, depth=depth: submit(lo, hi, depth)
                )  # (not counted in stats: the result is the serial one, counters too)
                queue.pop()
                self.stats["partitions"] += 1
                offset = self.stats["branches"]
                if (out is None or offset + counts["branches"] > self._max_branches
                        or self.boxes + counts["boxes"] > self._max_boxes):
                    # the limits count the whole run: the serial run stops inside this
                    # cell. It is computed again here, from the run's counters, so that it
                    # stops where the serial run stops (the ExplorationLimitError ends the
                    # run as a "limit" finding, what was explored kept)
                    cell = self._cell(lo, hi, depth)
                else:
                    tubes = [replace(t, branch=t.branch + offset) for t in out[1]]
                    for key in ("branches", "merges"):
                        self.stats[key] += counts[key]
                    self.boxes += counts["boxes"]
                    cell = (out[0], tubes, *out[2:])
                if self._commit(queue, lo, hi, depth, cell):
                    return
                if self.progress is not None:
                    self.progress(dict(self.stats))
                # (the cells' own checks run on the workers: the deadline is checked here)
                beat("cells on the cluster")
        finally:
            client.cancel([e[3] for e in queue if e[3] is not None] + [shared])


#: cells in flight per worker when the cells run on an executor
_WINDOW = 2
#: the engines a worker keeps (the latest runs'), by the run's token
_ENGINES: dict = {}


def _cell_task(shared: tuple, token: str, lo: np.ndarray, hi: np.ndarray, depth: int):
    """Worker side (an executor's task): one cell of a run, by an engine built once per run
    on this worker from the run's problem and law (sent in memory, scattered once).

    Parameters
    ----------
    shared : tuple
        ``(problem, law, hold, max_depth, merge_cost, max_sets, bloat, bloat_depth)`` of
        the run.
    token : str
        The run's id (the worker's engine for it is reused).
    lo, hi : (n,) ndarray
        The cell.
    depth : int
        Its refinement depth.
    """
    engine = _ENGINES.get(token)
    if engine is None:
        problem, law, hold, max_depth, merge_cost, max_sets, bloat, bloat_depth = shared
        engine = NonlinearReach(problem, law, hold, max_depth, merge_cost=merge_cost,
                                max_sets=max_sets, bloat=bloat, bloat_depth=bloat_depth)
        while len(_ENGINES) >= 2:
            _ENGINES.pop(next(iter(_ENGINES)))
        _ENGINES[token] = engine
    engine.stats = {"branches": 0, "refinements": 0, "partitions": 0, "merges": 0}
    engine.boxes = 0  # (the cell's own: the client adds them up in the serial order)
    try:
        out = engine._cell(lo, hi, depth)
    except ExplorationLimitError:
        # past this worker's limits within the one cell: the client computes it again
        # from the run's counters (where the serial run stops)
        return None, {**engine.stats, "boxes": engine.boxes}
    return out, {**engine.stats, "boxes": engine.boxes}
