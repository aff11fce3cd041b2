"""Exact mp-LP by geometric exploration: critical regions found across every facet.

``mpsolve`` (``solve.py``) hands a reduced mp-LP (``reduce.py``, H = 0) to
:func:`explore_facets` (see ``docs/algorithm.md`` for the argument):

1. **Unique selection.** The optimizer is made a single-valued function of theta: the
   cost is perturbed by a tiny generic vector (fixed seed) so that every LP has exactly one
   optimal vertex; the optimal basis of the perturbed LP is checked to be optimal for the
   *original* cost (its reduced costs are >= 0 under it), so every law is exactly optimal.
   When it is not (costs of very different sizes, where no perturbation size suits every
   dual), a primal simplex with the lexicographic rule finishes from that basis.
2. **Critical region at a point.** Solve at theta (DAQP, exact active sets), take the
   optimal active set / basis, and write the affine optimizer ``z = K theta + k`` and the
   polyhedron where it stays optimal (primal feasibility of every row): the whole set
   where that law is primal feasible, which makes regions of different laws
   interior-disjoint.
3. **Exploration with a non-facet-to-facet-safe step.** Every facet of every region is
   covered: a facet is split into *pieces*; for each piece, step a tiny distance across its
   Chebyshev centre, find (or compute) the region there, check it touches the piece, and
   subtract it from the piece (set difference by reversing its rows one at a time). A piece
   is done when it is empty, or its hyperplane supports the feasible set (an LP, asked when
   the step lands outside the set; when the set goes on past the hyperplane but is thinner
   than the step there, the step goes towards a feasible point past it instead). So the
   union of the regions is the whole feasible set: no holes even when neighbouring regions
   do not meet facet to facet.
4. **Skipped pieces probed.** A piece past which no full-dimensional region can be
   identified is skipped as numerically flat; when the queue empties, points a little
   further past every skipped piece are probed, and a feasible one in no region is a hole:
   its region is explored like any other, or the solve stops with the clear "too
   degenerate" error (:meth:`_Explorer._fill_holes`).
5. **Beyond double precision, stop at once.** A region whose boundary rounding can move
   by more than :data:`PRECISION_LIMIT` of the parameter set's scale
   (:func:`boundary_uncertainty`), or a lexicographic refinement that does not settle
   within its work limit (:data:`REFINE_WORK`), ends the solve with the one-line
   :func:`too_imprecise` error naming ``mpc.horizon`` (issue 29: a long horizon's tail
   with norm 1 or inf), instead of retrying for minutes and failing anyway.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import daqp
import numpy as np

# LAPACK straight: what lu_factor / lu_solve call, without their wrappers' cost
from scipy.linalg.lapack import dgetrf, dgetrs

from codev_engine.errors import SolverError, SpecError
from codev_engine.geometry.polytope import (
    certified_minimal_rows,
    chebyshev_ball,
    normalize_rows,
    solve_lp,
)
from codev_engine.geometry.vertices import vertices
from codev_engine.mp.coverage import feasibility_rows
from codev_engine.mp.reduce import ParameterBox, Reduced, lifted, start_point
from codev_engine.mp.solution import CriticalRegion, TooManyRegionsError, too_many_regions

__all__ = ["COUNTERS", "PRECISION_LIMIT", "boundary_uncertainty", "explore_facets"]

#: the exploration's counters, which always appear in its stats (rarer steps add their own)
COUNTERS = ("solves", "pieces", "jitters", "step_refinements")

#: a dual is a tie (zero) below this times its componentwise rounding-error bound (the bound
#: without its factor n; 1e-14 is about 50 units of roundoff)
_TIE = 1e-14


def explore_facets(
    red: Reduced,
    size: ParameterBox,
    *,
    region_tol: float,
    step: float,
    lp_perturbation: float,
    seed: int,
    max_regions: int,
    progress: Callable[[int], None] | None = None,
    stats: dict | None = None,
) -> list[CriticalRegion]:
    """The critical regions of the mp-LP ``red`` (in its reduced variables), in the order
    found; none when the program is infeasible for every parameter.

    Parameters
    ----------
    red : Reduced
        With ``H = 0``.
    size : ParameterBox
        Of ``red``'s parameter set.
    region_tol : float
        A region or facet piece whose inscribed ball is smaller is lower-dimensional
        (absolute, like ``step``).
    step : float
        Distance stepped across a facet to find the neighbour.
    lp_perturbation : float
        Relative size of the generic cost perturbation (times ``max |c|``).
    seed : int
        Of the perturbation, the start point and the jitter.
    max_regions : int
        More regions raise a ``SolverError``.
    progress : callable, optional
        Called with the number of regions found so far each time one is added.
    stats : dict, optional
        Counters of the exploration are added to it (``solves``, ``pieces``, ...).
    """
    if np.any(red.H):
        raise ValueError("explore_facets solves mp-LPs (H = 0); mp-QPs: mpqp.py")
    ex = _Explorer(
        red,
        size,
        region_tol=region_tol,
        step=step,
        lp_perturbation=lp_perturbation,
        seed=seed,
        max_regions=max_regions,
        progress=progress,
        stats={} if stats is None else stats,
    )
    return ex.run()


class _NoRegionError(SolverError):
    """No full-dimensional region could be identified around a point (degenerate spot)."""


#: the largest uncertainty of a region's boundary, in double precision and relative to the
#: parameter set's scale, that the mp-LP engines accept (:func:`boundary_uncertainty`).
#: Above it the tightness and lexicographic decisions fall to rounding and both engines
#: end after many seconds (minutes at N = 100) of pivots with "too degenerate"; they now
#: stop at once. Measured (issue 29) over every region computed: the double integrator
#: with norm inf solves at N = 30 with at most 3e-8, norm 1 at N = 20 with 5.6e-7; norm 1
#: N = 30 to 60 exceed it at once; the paper mp-LPs and the test set's stay below 1e-12.
PRECISION_LIMIT = 1e-6

#: the work (in units of one multiply-add) that the lexicographic pivots of one
#: refinement (:meth:`_Explorer._lex_pivots`) may take, ~nw^3 a pivot, before the program
#: is taken to be beyond double precision: 4e9 lets the double integrator with norm inf and
#: N = 30 finish its longest refinement (790 pivots, nw = 89: 5.6e8) and stops the walks
#: that never settle (N = 100: 4,000 pivots of nw = 299, 16 s) after ~150 pivots, 0.6 s.
#: The paper mp-LPs and the test set's need at most 29 pivots (nw = 63: 7e6).
REFINE_WORK = 4e9
_EPS = float(np.finfo(float).eps)


def boundary_uncertainty(red: Reduced, K: np.ndarray, k0: np.ndarray, bound: float,
                         scale: float, *, rows: tuple[np.ndarray, np.ndarray] | None = None,
                         absolute: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
                         ) -> float:
    """How far, relative to ``scale``, the computed boundary of a basis's critical region
    may be from the true one, from the rounding of its rows in double precision.

    Row i of the region is ``a_i theta <= b_i`` with ``a_i = G_i K - S_i`` and
    ``b_i = w_i - G_i k0``; rounding makes ``a_i`` uncertain by about
    ``e_i = eps (|G_i| |K| + |S_i|)`` and ``b_i`` by ``f_i = eps (|G_i| |k0| + |w_i|)``, so
    within ``|theta|_inf <= bound`` its hyperplane moves by up to
    ``(|e_i| bound + f_i) / |a_i|``. On a long horizon with norm 1 or inf the optimal
    plan decays geometrically (the double integrator: by 0.6 a step), ``a_i`` of the tail's
    rows shrinks with it while ``e_i`` does not (the condensed rows sum terms of the size of
    the head to get the tail), and the hyperplanes get lost in rounding.

    Parameters
    ----------
    red : Reduced
        The reduced mp-LP.
    K, k0 : numpy.ndarray
        The basis's law ``w = K theta + k0``.
    bound : float
        Of ``|theta|_inf`` on the parameter set.
    scale : float
        The parameter set's size.
    rows : tuple of numpy.ndarray, optional
        ``(G K - S, w - G k0)`` ((m, d), (m,)) when the caller has them (the same
        products, not computed again).
    absolute : tuple of numpy.ndarray, optional
        ``(|G|, |S|, |w|)`` of ``red`` when the caller keeps them.

    Returns
    -------
    float
        The largest such move over the rows that are not constant (gradient above 1e-10
        and ten times its rounding) and whose hyperplane can meet the parameter set,
        divided by ``scale``.
    """
    eps = _EPS
    a, b = (red.G @ K - red.S, red.w - red.G @ k0) if rows is None else rows
    aG, aS, aw = (np.abs(red.G), np.abs(red.S), np.abs(red.w)) if absolute is None else absolute
    e = eps * (aG @ np.abs(K) + aS)
    f = eps * (aG @ np.abs(k0) + aw)
    na = np.linalg.norm(a, axis=1)
    ne = np.linalg.norm(e, axis=1)
    d = K.shape[1]
    # a gradient not clearly above its own rounding is a constant row (the engines drop
    # slacks that are identically zero; cruise control has one at 1e-10 with rounding 6e-10)
    live = (na > 1e-10) & (na > 10.0 * ne) & (np.abs(b) <= 2.0 * bound * np.sqrt(d) * na)
    if not np.any(live):
        return 0.0
    move = (ne[live] * bound + f[live]) / na[live]
    return float(np.max(move)) / max(scale, 1e-300)


def cannot_step(p: np.ndarray) -> SolverError:
    """The explorer's error where it cannot find the region past a facet: every step
    across, down to rounding level, lands in the region it starts from or in none that
    touches the facet (one line, naming what to change).

    Parameters
    ----------
    p : numpy.ndarray
        The point of the facet stepped from.

    Returns
    -------
    SolverError
        To raise.
    """
    where = np.array2string(np.asarray(p, dtype=float), precision=4)
    return SolverError(
        f"the mp-LP explorer could not step across a facet near theta={where}: the regions "
        "there are thinner than its steps resolve in double precision (with norm 1 or inf, "
        "typically a long horizon); shorten mpc.horizon, or use norm = \"2\""
    )


def too_imprecise(q: np.ndarray | None, move: float | None) -> SolverError:
    """The error the mp-LP engines raise where double precision cannot decide a region
    (one line, naming what to change).

    Parameters
    ----------
    q : numpy.ndarray or None
        The parameter where it was found.
    move : float or None
        The uncertainty of the boundary (:func:`boundary_uncertainty`) when it is above
        :data:`PRECISION_LIMIT`; None when the lexicographic pivots did not settle.

    Returns
    -------
    SolverError
        To raise.
    """
    where = "" if q is None else (
        f" near theta={np.array2string(np.asarray(q, dtype=float), precision=4)}")
    why = (
        f"its critical regions' boundaries are known only to {move:.0e} of the parameter "
        "range in double precision"
        if move is not None
        else "its lexicographic pivots do not settle in double precision"
    )
    return SolverError(
        f"the mp-LP is too ill-conditioned to solve exactly{where}: {why} (with norm 1 "
        "or inf, typically a long horizon whose optimal tail decays to rounding level); "
        "shorten mpc.horizon, or use norm = \"2\""
    )


class _Explorer:
    """The exploration of one mp-LP (see the module docstring): :func:`explore_facets`."""

    def __init__(
        self,
        red: Reduced,
        size: ParameterBox,
        *,
        region_tol: float,
        step: float,
        lp_perturbation: float,
        seed: int,
        max_regions: int,
        progress: Callable | None,
        stats: dict,
    ):
        self.r = red
        self.progress = progress
        self.d = red.At.shape[1]
        self.nw = red.H.shape[0]
        self.rng = np.random.default_rng(seed)
        self.stats = stats
        for key in COUNTERS:
            stats.setdefault(key, 0)
        self.scale = size.scale
        self.bound = size.bound  # of |theta|_inf
        self.region_tol = region_tol
        self.step = step
        self.touch_tol = 1e-11 * self.scale
        self.lp_perturbation = lp_perturbation
        self.max_regions = max_regions
        self._hs = None
        self._hs_cost: np.ndarray | None = None
        self.cmag = max(np.max(np.abs(red.c), initial=0.0), 1.0)
        # the generic direction of the perturbation (drawn before the start point's jitter)
        self.pert = self.rng.uniform(0.5, 1.0, self.nw) * self.rng.choice([-1.0, 1.0], self.nw)
        self.c_pert = red.c + lp_perturbation * self.cmag * self.pert
        self.regions: list[CriticalRegion] = []
        self._verts: list[np.ndarray | None] = []
        self._done: list[np.ndarray] = []  # per region: facets already known to be covered
        # all regions' rows, contiguous per region, in growing buffers (for _find)
        self._bufA = np.zeros((1024, self.d))
        self._bufb = np.zeros(1024)
        self._nrows = 0
        self._starts = np.zeros(0, dtype=np.intp)
        self._far: dict[bytes, np.ndarray | None] = {}  # see _past
        self._feas_rows: tuple[np.ndarray, np.ndarray, int] | None = None  # see _highs_max
        self._lifted = lifted(red)
        # facet pieces skipped as numerically flat: (a point of the piece, its normal)
        self._skipped: list[tuple[np.ndarray, np.ndarray]] = []

    # ---- small geometry helpers -------------------------------------------------------

    def _in_theta(self, q: np.ndarray) -> bool:
        return bool(np.all(self.r.At @ q <= self.r.bt + 1e-12 * self.scale))

    def _find(self, q: np.ndarray, tol: float) -> int:
        """Index of a found region containing q (-1 if none)."""
        if not self.regions:
            return -1
        rows = self._nrows
        viol = (self._bufA[:rows] @ q - self._bufb[:rows] > tol).astype(np.int32)
        counts = np.add.reduceat(viol, self._starts)
        hits = np.flatnonzero(counts == 0)
        return int(hits[0]) if hits.size else -1

    # ---- optimisation at a point ------------------------------------------------------

    def _solve_at(self, q: np.ndarray):
        """Solve the (perturbed) program at theta = q -> (w, lam) or None if infeasible."""
        r = self.r
        self.stats["solves"] += 1
        rhs = r.w + r.S @ q
        m = rhs.shape[0]
        sense = np.zeros(m, dtype=np.int32)
        lower = np.full(m, -1e30)
        flag = -3
        for cost in (self.c_pert, *self._smaller_perturbations()):
            x, _, flag, info = daqp.solve(
                np.zeros((self.nw, self.nw)),
                cost + r.C @ q,
                r.G,
                rhs,
                lower,
                sense,
                eps_prox=1e-2,
                iter_limit=10_000,
                primal_tol=1e-11,
                dual_tol=1e-12,
            )
            if flag != -3:
                break
        if flag == -1:
            return None if self._infeasible(q) else self._solve_at_fallback(q)
        if flag == -3:
            raise SpecError(
                f"the program is unbounded at theta={np.array2string(q, precision=4)} (the "
                "cost decreases without end along a feasible direction: bound the variables "
                "or make the cost definite)",
                field="c",
            )
        if flag != 1:
            return self._solve_at_fallback(q)
        return np.asarray(x), np.asarray(info["lam"])

    def _smaller_perturbations(self) -> tuple[np.ndarray, ...]:
        """Costs to try when the perturbed LP is unbounded: the perturbation can outweigh
        a cost coefficient far below ``max|c|`` (weights Q = 1e7 next to R = 1 give slack
        costs 1 and 1e-7 after the reduction's normalisation) and make its slack's cost
        negative. The perturbation relative to the smallest cost, then none (the
        selection is lexicographic anyway: only DAQP's start basis depends on it)."""
        c = np.abs(self.r.c)
        small = float(np.min(c[c > 0.0], initial=self.cmag))
        if small >= self.cmag:
            return (self.r.c,)
        return (self.r.c + self.lp_perturbation * small * self.pert, self.r.c)

    def _solve_at_fallback(self, q: np.ndarray):
        """HiGHS when DAQP reports trouble (cycling near the feasibility boundary)."""
        import highspy

        h = self._highs(q)
        status = h.getModelStatus()
        if status == highspy.HighsModelStatus.kInfeasible:
            return None
        if status != highspy.HighsModelStatus.kOptimal:
            return "fail"
        sol = h.getSolution()
        return np.asarray(sol.col_value), -np.asarray(sol.row_dual)

    def _region_at(self, q: np.ndarray, jitter: float):
        """Critical region whose closure holds q (or a jittered q); None if infeasible."""
        for _ in range(8):
            sol = self._solve_at(q)
            if sol is None:
                return None
            if not isinstance(sol, str):
                reg = self._region_from_solution(q, *sol)
                if reg is not None:
                    return reg
            # q sits on a degenerate spot (lower-dimensional set): move off it
            q = self._jitter(q, jitter)
            self.stats["jitters"] += 1
        raise _NoRegionError(
            "the mp-LP is too degenerate to solve exactly near theta="
            f"{np.array2string(q, precision=4)} (many constraints tight at once: with norm 1 "
            "or inf, typically a long horizon whose tail rests at the target); shorten "
            "mpc.horizon, or use norm = \"2\""
        )

    def _jitter(self, q: np.ndarray, size: float) -> np.ndarray:
        qn = q + self.rng.normal(size=q.shape) * size
        return qn if self._in_theta(qn) else q

    def _check_precision(self, q: np.ndarray, K: np.ndarray, k0: np.ndarray) -> None:
        """Raise :func:`too_imprecise` when the rows of the law ``K theta + k0`` cannot
        locate its region's boundary in double precision (:func:`boundary_uncertainty`)."""
        move = boundary_uncertainty(self.r, K, k0, self.bound, self.scale)
        if move > PRECISION_LIMIT:
            raise too_imprecise(q, move)

    def _lex_state(self, act, q: np.ndarray):
        """Duals of the basis ``act`` at q -> (vertex, d0, d1, tie, inverse), or None when the
        basis matrix is singular.

        The selection rule is lexicographic in (c, r), r the fixed generic direction of the
        perturbation: a basis is lexicographically optimal when its duals for the original
        cost, d0, are >= 0 and, on the ties (d0 ~ 0), its duals for r, d1, are >= 0. Among
        all c-optimal vertices this picks the r-optimal one, which is unique for a generic r
        -- the same vertex whatever the perturbation size used to find it, so regions of
        different laws cannot overlap.

        A tie is a dual within a small multiple (``_TIE``) of its own rounding error, bounded
        componentwise by ``|B^-T| (|c| + |B^T| |d0|) + max|c|`` (B the basis matrix), and
        never more than ``1e-9 max|c|``. A fixed ``1e-9 max|c|`` is far above the rounding
        error when costs have very different sizes (soft-constraint penalties): in
        mpt3_mpqp_04_dat (costs 1e9 next to 10, max|c| 7e8 after the reduction) genuine
        duals of the small costs are 0.03 to 0.2 and rounding errors 1e-7, and
        ``1e-9 max|c|`` = 0.7 called those duals ties (wrong laws).
        """
        r = self.r
        GB = r.G[act]
        lu, piv, _ = dgetrf(GB)  # singular: checked below
        if not np.all(np.isfinite(lu)) or np.min(np.abs(np.diag(lu))) == 0.0:
            return None
        cq = r.c + r.C @ q
        # LU solves (backward stable), not products with the inverse: a dual that is zero
        # by the structure of the basis comes out zero, not as rounding noise of the inverse
        d0 = dgetrs(lu, piv, -cq, trans=1)[0]
        d1 = dgetrs(lu, piv, -self.pert, trans=1)[0]
        x = dgetrs(lu, piv, r.w[act] + r.S[act] @ q)[0]
        Binv = dgetrs(lu, piv, np.eye(self.nw))[0]
        err0 = np.abs(Binv.T) @ (np.abs(cq) + np.abs(GB.T) @ np.abs(d0))
        tie = np.abs(d0) <= np.minimum(_TIE * (err0 + self.cmag), 1e-9 * self.cmag)
        return x, d0, d1, tie, Binv

    def _lex_negative(self, d0, d1, tie) -> np.ndarray:
        """Rows of a basis whose dual is lexicographically negative."""
        return (~tie & (d0 < 0)) | (tie & (d1 < -1e-9 * np.max(np.abs(self.pert))))

    def _lex_optimal(self, act: np.ndarray, q: np.ndarray) -> bool:
        """Is the basis ``act`` lexicographically optimal (and primal feasible) at q?"""
        st = self._lex_state(act, q)
        if st is None:
            return False
        x, d0, d1, tie, _ = st
        if np.any(self._lex_negative(d0, d1, tie)):
            return False
        r = self.r
        return bool(np.all(r.G @ x <= r.w + r.S @ q + 1e-9 * self.scale))

    def _lex_refine(self, act: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """:meth:`_lex_pivots`; when it fails after more pivots than the basis has rows,
        :func:`too_imprecise` is raised instead.

        Such a walk (a basis repeated, a basis that drifts out of primal feasibility, the
        pivot limit) means that the lexicographic decisions are at rounding level (a long
        horizon's tail with norm 1 or inf, issue 29): the retries from other points and
        perturbations did the same, for tens of seconds (minutes at N = 100), and the
        search ended with "too degenerate" anyway. The programs that solve need at most
        a few pivots where a refinement fails (measured: the paper mp-LPs, the test set's,
        the double integrator up to the horizons it solves).

        Parameters
        ----------
        act : numpy.ndarray
            A primal-feasible basis at ``q``.
        q : numpy.ndarray
            The parameter.

        Returns
        -------
        numpy.ndarray or None
            The lexicographically optimal basis (sorted), or None.
        """
        before = self.stats.get("lex_pivots", 0)
        out = self._lex_pivots(act, q)
        if out is None and self.stats.get("lex_pivots", 0) - before > self.nw:
            raise too_imprecise(q, None)
        return out

    def _lex_pivots(self, act: np.ndarray, q: np.ndarray) -> np.ndarray | None:
        """Primal simplex from the primal-feasible basis ``act`` to the lexicographically
        optimal one; None if ``act`` is not a primal-feasible basis or the pivots do not
        settle.

        The LP solvers find the optimal vertex of a perturbed cost ``c + delta r``; when
        delta is not small against every genuine dual of c (costs of very different sizes)
        their basis is not c-optimal, and no one perturbation size suits every program.
        This finishes the job with the exact rule, in two phases, each by Bland's rule (the
        lowest-numbered negative row leaves, the lowest-numbered first blocking row enters:
        no cycling on degenerate vertices):

        A. rows with a clearly negative d0 leave until the basis is c-optimal;
        B. the rows with a clearly positive d0 are then held (every optimal point has them
           active: this is the optimal face) and tied rows with a negative d1 leave: the
           simplex for r on the optimal face, whose decisions do not depend on the
           classification of ties.

        A basis seen twice (ties classified differently at different bases) ends it. The
        pivots are limited (:data:`REFINE_WORK`); the limit raises :func:`too_imprecise`.
        """
        r = self.r
        h = r.w + r.S @ q
        B = np.array(act, dtype=np.intp)
        inB = np.zeros(r.G.shape[0], dtype=bool)
        inB[B] = True
        held: np.ndarray | None = None  # phase B: rows of the optimal face
        seen: set[bytes] = set()
        feas_tol = 1e-9 * self.scale
        # the pivots allowed: 20 nw + 100, and work of at most REFINE_WORK (a fresh
        # factorisation and inverse, ~nw^3, per pivot); reaching the limit raises
        limit = min(20 * self.nw + 100, max(self.nw + 100, int(REFINE_WORK / self.nw**3)))
        for _ in range(limit):
            key = np.sort(B).tobytes()
            if key in seen:
                break
            seen.add(key)
            st = self._lex_state(B, q)
            if st is None:
                return None
            x, d0, d1, tie, Binv = st
            slack = h - r.G @ x
            if np.any(slack < -feas_tol):
                return None
            neg = self._lex_negative(d0, d1, tie)
            if not np.any(neg):
                return np.sort(B)
            if held is None:
                cand = np.flatnonzero(~tie & (d0 < 0))
                if cand.size == 0:
                    held = np.zeros_like(inB)
                    held[B[~tie & (d0 > 0)]] = True
            if held is not None:
                cand = np.flatnonzero(neg & ~held[B])
                if cand.size == 0:
                    break  # the face's r-optimum fails the test: not settled
            self.stats["lex_pivots"] = self.stats.get("lex_pivots", 0) + 1
            i = cand[np.argmin(B[cand])]
            u = -Binv[:, i]  # G_B u = -e_i: off row i into its feasible side
            Gu = r.G @ u
            block = ~inB & (Gu > 1e-9 * np.linalg.norm(u))
            if not np.any(block):
                return None  # unbounded along the face (no lexicographic optimum)
            rows = np.flatnonzero(block)
            t = np.maximum(slack[rows], 0.0) / Gu[rows]
            tmin = np.min(t)
            j = int(np.min(rows[t <= tmin + 1e-12 * max(1.0, tmin)]))
            inB[B[i]] = False
            inB[j] = True
            B[i] = j
        else:
            raise too_imprecise(q, None)
        self.stats["lex_refine_failed"] = self.stats.get("lex_refine_failed", 0) + 1
        return None

    def _lp_basis(self, q: np.ndarray, lam: np.ndarray) -> np.ndarray | None:
        """The lexicographically optimal basis (row indices) of the LP at q.

        DAQP's working set is tried first. Otherwise (DAQP's proximal LP mode can stop on an
        edge when the cost slope along it is as small as the perturbation) HiGHS's dual
        simplex solves the perturbed LP, with smaller perturbations if needed. A basis that
        fails the lexicographic test is finished by ``_lex_refine``.
        """
        act = np.flatnonzero(lam > 0)
        if act.size == self.nw and self._primal_ok(act, q):
            if self._lex_optimal(act, q):
                return act
            act = self._lex_refine(act, q)
            if act is not None:
                return act
        for delta in self._highs_perturbations():
            act = self._highs_basis(q, delta)
            if isinstance(act, str):  # (the perturbed LP is unbounded: a smaller one)
                continue
            if act is None:
                return None
            if self._lex_optimal(act, q):
                return act
            act = self._lex_refine(act, q)
            if act is not None:
                return act
            self.stats["rejected_bases"] = self.stats.get("rejected_bases", 0) + 1
        return None

    def _highs_perturbations(self) -> tuple[float, ...]:
        """The sizes (relative to ``max|c|``) of the perturbation HiGHS is asked with, in
        turn: ``lp_perturbation`` and a thousandth of it, then, when the smallest cost
        coefficient is below the perturbation, the same relative to that coefficient.

        The cost's coefficients can be further apart than ``lp_perturbation``: a soft
        weight of 1e4 next to a state weight of 10^-1.5 (the state in units 10^1.5 times
        smaller, issue 38) leaves that state's slack at a cost of 3e-6 of the largest, and
        the perturbation (up to 1e-5) made it negative: the perturbed LP was unbounded,
        and the first unbounded answer ended the basis search before the smaller size was
        tried (every start point, then "too degenerate"). An unbounded size now moves on
        to the next (``_solve_at`` has the same cure for DAQP,
        :meth:`_smaller_perturbations`).

        Returns
        -------
        tuple of float
        """
        base = (self.lp_perturbation, 1e-3 * self.lp_perturbation)
        c = np.abs(self.r.c)
        small = float(np.min(c[c > 0.0], initial=self.cmag)) / self.cmag
        if small > base[-1]:  # (|pert| <= 1: every cost stays > 0 at the last size)
            return base
        return (*base, self.lp_perturbation * small, 1e-3 * self.lp_perturbation * small)

    def _primal_ok(self, act: np.ndarray, q: np.ndarray) -> bool:
        """Is the vertex of the basis ``act`` feasible at q (to 1e-9, relative)? DAQP's
        working set can be the right duals' but not a vertex at q: on the cruise control
        with its slacks scaled, its LP stopped short (7.8504 for 7.8520 on another LP), and
        the basis it handed on gave an empty region at q, so two sliver regions were
        never found."""
        r = self.r
        rhs = r.w + r.S @ q
        try:
            z = np.linalg.solve(r.G[act], rhs[act])
        except np.linalg.LinAlgError:
            return False
        return bool(np.all(r.G @ z - rhs <= 1e-9 * (1.0 + np.abs(rhs) + np.abs(r.G) @ np.abs(z))))

    def _highs(self, q: np.ndarray, delta: float | None = None):
        """Solve the perturbed LP at q with HiGHS (warm-started dual simplex)."""
        import highspy

        r = self.r
        m, nw = r.G.shape
        inf = highspy.kHighsInf
        if self._hs is None:
            h = highspy.Highs()
            h.setOptionValue("output_flag", False)
            # the perturbation must dominate the solver's tolerances
            h.setOptionValue("primal_feasibility_tolerance", 1e-10)
            h.setOptionValue("dual_feasibility_tolerance", 1e-10)
            lp = highspy.HighsLp()
            lp.num_col_, lp.num_row_ = nw, m
            # the objective divided by max|c| (the same optimizer): HiGHS refuses costs
            # like 1e9 ("excessive dual values")
            lp.col_cost_ = self.c_pert / self.cmag
            lp.col_lower_ = np.full(nw, -inf)
            lp.col_upper_ = np.full(nw, inf)
            lp.row_lower_ = np.full(m, -inf)
            lp.row_upper_ = r.w.copy()
            lp.a_matrix_.format_ = highspy.MatrixFormat.kRowwise
            lp.a_matrix_.start_ = np.arange(0, m * nw + 1, nw)
            lp.a_matrix_.index_ = np.tile(np.arange(nw), m)
            lp.a_matrix_.value_ = r.G.ravel()
            h.passModel(lp)
            self._hs = h
        h = self._hs
        self.stats["highs"] = self.stats.get("highs", 0) + 1
        h.changeRowsBounds(m, np.arange(m, dtype=np.int32), np.full(m, -inf), r.w + r.S @ q)
        delta = self.lp_perturbation if delta is None else delta
        cost = (r.c + r.C @ q) / self.cmag + delta * self.pert
        if self._hs_cost is None or np.any(cost != self._hs_cost):
            h.changeColsCost(nw, np.arange(nw, dtype=np.int32), cost)
            self._hs_cost = cost
        h.run()
        if h.getModelStatus() == highspy.HighsModelStatus.kUnknown:
            # a warm start gone wrong, or tolerances too tight for this point: cold start,
            # then once more with HiGHS's default tolerances
            h.clearSolver()
            h.run()
            if h.getModelStatus() == highspy.HighsModelStatus.kUnknown:
                h.setOptionValue("primal_feasibility_tolerance", 1e-7)
                h.setOptionValue("dual_feasibility_tolerance", 1e-7)
                h.clearSolver()
                h.run()
                h.setOptionValue("primal_feasibility_tolerance", 1e-10)
                h.setOptionValue("dual_feasibility_tolerance", 1e-10)
        return h

    def _highs_basis(self, q: np.ndarray, delta: float) -> np.ndarray | str | None:
        """HiGHS's basis of the LP perturbed by ``delta`` at q, completed to ``nw`` rows;
        ``"unbounded"`` when the perturbed LP is unbounded, None when HiGHS fails."""
        import highspy

        h = self._highs(q, delta)
        status = h.getModelStatus()
        if status == highspy.HighsModelStatus.kUnbounded:
            return "unbounded"
        if status != highspy.HighsModelStatus.kOptimal:
            return None
        rows = np.array(
            [st == highspy.HighsBasisStatus.kUpper for st in h.getBasis().row_status], dtype=bool
        )
        act = np.flatnonzero(rows)
        if act.size < self.nw:
            r = self.r
            x = np.asarray(h.getSolution().col_value)
            slack = r.w + r.S @ q - r.G @ x
            tight = np.setdiff1d(np.flatnonzero(slack <= 1e-9 * self.scale), act)
            act = _complete_basis(r.G, act, tight, self.nw)
        return act

    def _infeasible(self, q: np.ndarray) -> bool:
        """Confirm with HiGHS that the program is infeasible at q (a false 'infeasible'
        would end the exploration of a facet and leave a hole)."""
        import highspy

        h = self._highs(q)
        return h.getModelStatus() == highspy.HighsModelStatus.kInfeasible

    def _region_from_solution(self, q, x, lam):
        r = self.r
        act = self._lp_basis(q, lam)
        if act is None:
            return None
        GB = r.G[act]
        try:
            # _lp_basis checked the basis is optimal for the ORIGINAL cost
            Z = np.linalg.solve(GB, np.hstack([r.w[act, None], r.S[act]]))
        except np.linalg.LinAlgError:
            return None
        k0, K = Z[:, 0], Z[:, 1:]
        self._check_precision(q, K, k0)
        Ar = r.G @ K - r.S
        br = r.w - r.G @ k0
        # a row whose theta part cancels to rounding level (relative to the terms that
        # cancel, not to 1: a row of norm 1.2e-10 and offset -3.6e-10 on the cruise
        # control with its slacks scaled read "theta >= 3" once normalised, and emptied
        # the region) is a constant row: it holds (to rounding) or the region is empty
        size = np.abs(r.G) @ np.abs(K) + np.abs(r.S)
        flat = np.linalg.norm(Ar, axis=1) <= 1e-10 * np.maximum(np.linalg.norm(size, axis=1),
                                                                1e-300)
        if np.any(flat):
            off = 1e-9 * (np.abs(r.w) + np.abs(r.G) @ np.abs(k0) + 1e-300)
            if np.any(br[flat] < -off[flat] - np.linalg.norm(Ar[flat], axis=1) * self.bound):
                return None
            Ar, br = Ar[~flat], br[~flat]
        if np.any(r.C):
            # with a parameter-dependent cost the basis needs duals >= 0 as well
            Dl = np.linalg.solve(GB.T, -np.hstack([r.c[:, None], r.C]))
            Ar = np.vstack([Ar, -Dl[:, 1:]])
            br = np.concatenate([br, Dl[:, 0]])
        Ar = np.vstack([Ar, r.At])
        br = np.concatenate([br, r.bt])
        Ar, br, ok = normalize_rows(Ar, br, tol=1e-10)
        if not ok:
            return None
        centre, radius = chebyshev_ball(Ar, br)
        if not radius > self.region_tol:
            return None
        if np.any(Ar @ q - br > 1e-7 * self.scale):
            return None
        # redundant rows dropped only with a proof: DAQP's minrep alone dropped a
        # parameter-set row that a sliver region (radius 3e-5) crossed by 0.7 (an MPC of
        # the oracle tests). (Not the compiled lp_kernel.certified_keep: loading numba's
        # cached code costs ~0.2 s, far more than the whole solve of a small program.)
        keep = certified_minimal_rows(Ar, br, self.bound)
        return CriticalRegion(A=Ar[keep], b=br[keep], K=K, k=k0, active=tuple(int(i) for i in act))

    # ---- exploration --------------------------------------------------------------------

    def _add(self, reg: CriticalRegion, verts: np.ndarray | None = None) -> int:
        """Append ``reg`` (with its vertices, if already enumerated); its index."""
        self.regions.append(reg)
        self._verts.append(vertices(reg.A, reg.b, tol=self.touch_tol) if verts is None else verts)
        self._done.append(np.zeros(reg.A.shape[0], dtype=bool))
        k = reg.A.shape[0]
        if self._nrows + k > self._bufA.shape[0]:
            cap = 2 * (self._nrows + k)
            self._bufA = np.resize(self._bufA, (cap, self.d))
            self._bufb = np.resize(self._bufb, cap)
        self._bufA[self._nrows : self._nrows + k] = reg.A
        self._bufb[self._nrows : self._nrows + k] = reg.b
        self._starts = np.append(self._starts, self._nrows)
        self._nrows += k
        if self.progress is not None:
            self.progress(len(self.regions))
        if len(self.regions) > self.max_regions:
            raise TooManyRegionsError(too_many_regions(self.max_regions))
        return len(self.regions) - 1

    def run(self) -> list[CriticalRegion]:
        q0 = start_point(self.r, self.scale, self.region_tol, self.rng)
        if q0 is None:
            return []
        first = self._region_at(q0, 1e-3 * self.scale)
        if first is None:
            return []
        queue = deque([self._add(first)])
        while queue:
            while queue:
                i = queue.popleft()
                reg = self.regions[i]
                for j in range(reg.A.shape[0]):
                    if self._done[i][j]:
                        continue
                    for new in self._cover_facet(i, j):
                        queue.append(new)
            queue.extend(self._fill_holes())
        return self.regions

    #: distances (times the parameter set's scale) past a skipped facet piece at which
    #: :meth:`_fill_holes` looks for a feasible parameter that no region holds
    PROBES = (1e-5, 1e-4, 1e-3, 1e-2)

    def _fill_holes(self) -> list[int]:
        """Regions found past the facet pieces skipped as numerically flat, where a
        feasible parameter a little further out has no region; their indices.

        A piece is skipped when no full-dimensional region could be identified just past
        it, on the premise that only regions thinner than ``region_tol`` live there. Under
        massive primal degeneracy (the 1-norm double integrator with N = 20: slacks of the
        tail decaying to 1e-8 and below) the premise fails: the pieces bounded holes of
        the partition (39 of the synthesis oracle's points, 1 to 10 units wide). So past
        every skipped piece, at the distances ``PROBES``, a feasible parameter outside
        every region is a hole: its region is identified and explored like any other, or
        the search ends with the clear error of :meth:`_region_at` -- never a law with a
        hole. (Probes find the holes next to skipped pieces, not every possible hole.)
        """
        skipped, self._skipped = self._skipped, []
        new: list[int] = []
        for p, a in skipped:
            for t in self.PROBES:
                q = p + t * self.scale * a
                if not self._in_theta(q) or self._find(q, 1e-12 * self.scale) >= 0:
                    continue
                sol = self._solve_at(q)
                if sol is None:
                    continue  # infeasible there: no hole
                try:
                    nreg = self._region_at(q, 0.1 * t * self.scale)
                except _NoRegionError:
                    # a thin region close to the piece, or a hole whose region cannot be
                    # identified: further out, or (at the last probe) the clear error
                    if t == self.PROBES[-1]:
                        raise
                    continue
                if nreg is None:
                    continue
                V = vertices(nreg.A, nreg.b, tol=self.touch_tol)
                k = self._known(V)
                if k >= 0:
                    self.stats["copies"] = self.stats.get("copies", 0) + 1
                    continue
                self.stats["holes_filled"] = self.stats.get("holes_filled", 0) + 1
                new.append(self._add(nreg, V))
                break
        return new

    def _past(self, a: np.ndarray, beta: float) -> np.ndarray | None:
        """A feasible parameter farthest along ``a``, when it is past ``a theta = beta`` by
        more than ``region_tol`` (else None: the hyperplane supports the feasible set, and
        a facet on it is on the set's boundary). One LP over the lifted set per direction
        (many facets share a boundary hyperplane)."""
        key = a.tobytes()
        if key not in self._far:
            nw = self.nw
            x, st, _ = solve_lp(np.concatenate([np.zeros(nw), -a]), *self._lifted)
            self._far[key] = x[nw:] if st == "optimal" and x is not None else None
        z = self._far[key]
        if z is None or a @ z <= beta + self.region_tol:
            # DAQP's LP mode can stop short of the maximum: 7.8504 for 7.8520 on the cruise
            # control once its slacks were scaled (issue 37), which made two regions' facets
            # boundary facets and dropped the regions past them. HiGHS, on the rows that can
            # restrict theta, decides before a facet is called a boundary
            hkey = b"highs" + key
            if hkey not in self._far:
                self._far[hkey] = self._highs_max(a)
            z = self._far[hkey]
            if z is None or a @ z <= beta + self.region_tol:
                return None
        return z

    def _highs_max(self, a: np.ndarray) -> np.ndarray | None:
        """A parameter of the feasible set farthest along ``a`` (HiGHS), or None."""
        from scipy.optimize import linprog

        if self._feas_rows is None:
            r = self.r
            self._feas_rows = feasibility_rows(r.G, r.S, r.w, r.At, r.bt)
        A, b, nw = self._feas_rows
        res = linprog(np.concatenate([np.zeros(nw), -a]), A_ub=A, b_ub=b, bounds=(None, None),
                      method="highs", options={"primal_feasibility_tolerance": 1e-10,
                                               "dual_feasibility_tolerance": 1e-10})
        self.stats["boundary_lps"] = self.stats.get("boundary_lps", 0) + 1
        return np.asarray(res.x[nw:]) if res.status == 0 else None

    def _known(self, V: np.ndarray | None) -> int:
        """Index of a found region that a new region (vertices ``V``) is a copy of (a
        degenerate vertex reached by another basis gives the same region), else -1: one of
        its inner points (the mean of its vertices) strictly inside a found region means
        an overlap."""
        if V is None or V.shape[0] == 0:
            return -1
        return self._find(V.mean(axis=0), -1e-9 * self.scale)

    def _facet_vertices(self, i: int, j: int) -> np.ndarray | None:
        V = self._verts[i]
        if V is None:
            return None
        reg = self.regions[i]
        Vf = V[np.abs(V @ reg.A[j] - reg.b[j]) <= self.touch_tol]
        # a facet of a d-dimensional polytope has >= d vertices spanning d-1 dimensions;
        # anything less means the enumeration lost a vertex: do not trust it
        if Vf.shape[0] < self.d:
            return None
        if self.d > 1 and np.linalg.matrix_rank(Vf[1:] - Vf[0], tol=self.touch_tol) < self.d - 1:
            return None
        return Vf

    def _covers_whole_facet(self, i: int, j: int, k: int) -> bool:
        """Does region k contain all of facet j of region i (vertex test)?

        When it does and k has the opposite facet, that facet of k is covered by region i
        as soon as its vertices lie in region i: mark it so it is not explored twice.
        """
        Vf = self._facet_vertices(i, j)
        if Vf is None or Vf.shape[0] == 0:
            return False
        Rk = self.regions[k]
        if not np.all(Vf @ Rk.A.T - Rk.b <= self.touch_tol):
            return False
        reg = self.regions[i]
        match = np.flatnonzero(
            (np.abs(Rk.A @ reg.A[j] + 1.0) <= 1e-9) & (np.abs(Rk.b + reg.b[j]) <= self.touch_tol)
        )
        for r in match:
            Vk = self._facet_vertices(k, r)
            if Vk is not None and Vk.shape[0] and np.all(Vk @ reg.A.T - reg.b <= self.touch_tol):
                self._done[k][r] = True
        return True

    def _cover_facet(self, i: int, j: int) -> list[int]:
        """Make sure every point of facet j of region i has a region on its other side."""
        reg = self.regions[i]
        a, beta = reg.A[j], reg.b[j]
        others = np.delete(np.arange(reg.A.shape[0]), j)
        baseA, baseb = reg.A[others], reg.b[others]
        new_regions: list[int] = []
        # a piece: extra rows (EA, Eb), a step scale, and its Chebyshev ball if known
        pieces: list = [(np.zeros((0, self.d)), np.zeros(0), 1.0, None)]
        budget = 2000
        whole = True  # the first piece is the whole facet
        while pieces and budget:
            budget -= 1
            EA, Eb, scale, ball = pieces.pop()
            self.stats["pieces"] += 1
            if ball is None:
                PA = np.vstack([baseA, EA])
                Pb = np.concatenate([baseb, Eb])
                # (DAQP's radius unproved: a facet piece missed is the coverage check's)
                ball = chebyshev_ball(PA, Pb, a[None, :], np.array([beta]),
                                      certify_optimum=False)
            p, rho = ball
            if not rho > self.region_tol:
                continue
            if scale < 1e-6:
                self.stats["skipped_pieces"] = self.stats.get("skipped_pieces", 0) + 1
                self._skipped.append((p, a))
                continue
            eps = min(self.step, 0.5 * rho) * scale
            target = -1
            # across the facet (eps: the distance past its hyperplane): along its normal,
            # unless the feasible set is thinner than that there
            direction = a
            tries = 0
            while tries < 6:
                tries += 1
                q = p + eps * direction
                # past the hyperplane, outside the parameter set or where the program is
                # infeasible: the facet is on the feasible set's boundary only if that is
                # so along all of the hyperplane
                beyond = not self._in_theta(q)
                if not beyond:
                    k = self._find(q, 1e-12 * self.scale)
                    if k < 0:
                        try:
                            nreg = self._region_at(q, 0.1 * eps)
                        except _NoRegionError:
                            # only regions thinner than region_tol live here: a numerically
                            # flat piece; counted and reported, never silently
                            self.stats["skipped_pieces"] = self.stats.get("skipped_pieces", 0) + 1
                            self._skipped.append((p, a))
                            target = -3
                            break
                        beyond = nreg is None
                        if not beyond:
                            V = vertices(nreg.A, nreg.b, tol=self.touch_tol)
                            k = self._known(V)
                            if k >= 0:
                                self.stats["copies"] = self.stats.get("copies", 0) + 1
                            else:
                                k = self._add(nreg, V)
                                new_regions.append(k)
                if beyond:
                    if direction is not a:
                        # on the segment from p to a feasible point: rounding at a
                        # boundary point of the set; step closer
                        eps *= 0.1
                        self.stats["step_refinements"] += 1
                        continue
                    z = self._past(a, beta)
                    if z is None:
                        target = -2  # the set ends at this hyperplane: boundary
                        break
                    # the set goes on past the hyperplane, but by less than eps at p (a
                    # thin wedge): step towards a feasible point z past it instead, eps
                    # past the hyperplane as before (the segment from p, a point of the
                    # set, to z lies in the set)
                    past = float(a @ (z - p))
                    direction = (z - p) / past
                    eps = min(eps, 0.5 * past)
                    self.stats["wedges"] = self.stats.get("wedges", 0) + 1
                    tries -= 1
                    continue
                if k == i:
                    # rounding put q in the region stepped from: taking it as the neighbour
                    # would mark the piece covered and leave a hole; refuse loudly
                    break
                R2 = self.regions[k]
                if np.all(R2.A @ p - R2.b <= self.touch_tol):
                    target = k
                    break
                eps *= 0.1  # a thinner region lies in between: step closer
                self.stats["step_refinements"] += 1
            if target == -3:
                continue
            if target == -2:
                return new_regions  # the facet is on the feasible set's boundary
            if target < 0:
                raise cannot_step(p)
            if whole and self._covers_whole_facet(i, j, target):
                return new_regions  # neighbour meets this facet facet-to-facet (or more)
            whole = False
            # subtract R2 from the piece, inside the facet's hyperplane
            R2 = self.regions[target]
            tang = R2.A - np.outer(R2.A @ a, a)
            cut = np.linalg.norm(tang, axis=1) > 1e-9
            prevA = np.zeros((0, self.d))
            prevb = np.zeros(0)
            # progress needs R2 to cover a relative-interior ball of the piece; when R2 only
            # touches the piece (at p, in a lower-dimensional set), step again, closer
            _, common = chebyshev_ball(
                np.vstack([baseA, EA, R2.A]),
                np.concatenate([baseb, Eb, R2.b]),
                a[None, :],
                np.array([beta]),
                certify_optimum=False,
            )
            if not common > self.region_tol:
                self.stats["step_refinements"] += 1
                pieces.append((EA, Eb, scale * 0.1, ball))
                continue
            for row, rhs in zip(R2.A[cut], R2.b[cut], strict=True):
                nEA = np.vstack([EA, prevA, -row[None, :]])
                nEb = np.concatenate([Eb, prevb, [-rhs]])
                pieces.append((nEA, nEb, 1.0, None))
                prevA = np.vstack([prevA, row[None, :]])
                prevb = np.concatenate([prevb, [rhs]])
        if budget == 0:
            raise SolverError("facet coverage did not converge (too many pieces)")
        return new_regions



def _complete_basis(G, act, tight, n):
    """Extend the rows ``act`` with rows of ``tight`` to n linearly independent rows."""
    rows = list(act)
    for t in tight:
        trial = G[rows + [t]]
        if np.linalg.matrix_rank(trial, tol=1e-9) == len(rows) + 1:
            rows.append(int(t))
            if len(rows) == n:
                break
    return np.array(rows) if len(rows) == n else None

