"""Exact mp-LP on the graph of optimal bases (the parameter in the right-hand side only).

``mpsolve`` (``solve.py``) hands a reduced mp-LP whose cost does not depend on the
parameter (``C = 0``: every MPC with norm 1 or inf) to :func:`explore_bases`. The law is the
one the geometric explorer (``mplp.py``) selects: at every parameter the optimal vertex
that is lexicographically optimal for ``(c, r)``, ``r`` the explorer's fixed generic
direction (same seed, same draw), so at every parameter the law is the explorer's.

**Bases.** A basis ``B`` (``nw`` linearly independent rows of ``G``) gives the affine law
``w_B(theta) = G_B^-1 (w0_B + S_B theta)`` and the slack of every other row, an affine
function of theta. Its critical region is where all slacks are >= 0. Under primal
degeneracy (the tail of a long horizon that sits at the origin: both rows ``+-M v <= t``
tight at ``v = 0, t = 0``, hundreds of tight rows for each vertex) a vertex has
exponentially many bases and most of them have lower-dimensional regions: picking one at
a point and hoping it is full-dimensional is what made the explorer give up ("could not
identify a full-dimensional critical region").

**Unique basis.** The right-hand side is perturbed lexicographically as well
(Jones, Kerrigan & Maciejowski 2007): row ``i`` gets ``+ eps_i`` with
``eps_1 >> eps_2 >> ...`` (relaxing every row, so feasibility is unchanged). With the
cost perturbed lexicographically by ``r`` the perturbed LP is non-degenerate both ways:
at every parameter exactly one basis is optimal, its vertex is the ``(c, r)``-optimal one
(the explorer's law), its region is full-dimensional, and the regions form a
facet-to-facet partition of the feasible set. Regions of equal laws have equal rows, so
the regions are the explorer's (one per law).

**Neighbours by pivoting.** Across facet ``F`` of a region, at its Chebyshev centre
``theta0`` and direction ``a`` (its outer normal), the neighbour's basis is the optimal
basis of the perturbed LP at ``theta0 + t a`` for an infinitesimal ``t > 0``: a
lexicographic dual simplex from ``B`` whose right-hand side is ordered
``(w0 + S theta0, S a, eps)``. Only rows tight at ``theta0`` ever enter (the vertex at
``theta0`` does not move), the ratio test is lexicographic in ``(c, r)`` with the
explorer's classification of tied duals, and a row with no positive ratio means the LP is
infeasible past ``F`` (it is on the feasible set's boundary). No step, no LP solve at a
point and no coverage of facets by pieces: one region per basis, found once.

**Compiled.** From ``JIT_AFTER`` regions on, a basis's region (with its facets' centres),
the dual simplex and the lexicographic test are compiled calls (``mplp_kernel``), the same
decisions as the numpy code here; where the kernel cannot conclude, the numpy code does
that step.

**Slivers.** A neighbour thinner than ``region_tol`` is computed again with the floor
``SLIVER_FLOOR`` and kept when a ball checked on all its rows is above that floor and
``SLIVER_MARGIN`` times its boundary's uncertainty (the magnetic pointer with N = 8 has ten,
radius ~5e-9, among 8,706 regions).

When a step of the search cannot be made exact (a basis matrix numerically singular, a
neighbour thinner than ``region_tol`` that is no certified sliver, a neighbour that does
not touch the facet) :func:`explore_bases` returns None and the caller uses the geometric
explorer.
A region whose boundary is beyond double precision (``mplp.boundary_uncertainty`` above
``mplp.PRECISION_LIMIT``) raises the explorer's ``too_imprecise`` error at once: the
explorer would meet the same law and fail after far longer.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

# LAPACK straight (what scipy's lu_factor / lu_solve call, bit for bit): their wrappers
# cost several times the factorisation of a small basis
from scipy.linalg.lapack import dgetrf, dgetrs

from codev_engine.geometry.polytope import certified_minimal_rows, chebyshev_ball
from codev_engine.mp.mplp import (
    _TIE,
    PRECISION_LIMIT,
    _Explorer,
    boundary_uncertainty,
    too_imprecise,
)
from codev_engine.mp.reduce import ParameterBox, Reduced, start_point
from codev_engine.mp.solution import CriticalRegion, TooManyRegionsError, too_many_regions

__all__ = ["JIT_AFTER", "explore_bases"]

#: regions found before each basis's work goes to the compiled kernel (``mplp_kernel``:
#: importing numba and loading the kernel costs ~0.7 s of CPU, more than a small mp-LP
#: takes altogether); a fixed count, so the partition depends on the problem alone
JIT_AFTER = 32
#: factorisations of basis matrices kept, the least recently used dropped (see
#: ``_Search._factor``): a region's basis for its facets, and the few a crossing makes
LU_CACHE = 8
#: pivots of the compiled dual simplex between fresh factorisations (rank-1 updates of the
#: basis inverse in between; the basis it ends on is checked from a fresh factorisation)
REFRESH = 8
#: a neighbour thinner than ``region_tol`` (a sliver: the lexicographic pivots make it
#: full-dimensional in exact arithmetic) is kept when its inscribed radius is above this
#: (relative to the parameter set's size) and ``SLIVER_MARGIN`` times the uncertainty of
#: its boundary in double precision
SLIVER_FLOOR = 1e-12
SLIVER_MARGIN = 1e3


class _NotExactError(Exception):
    """A step of the basis search could not be made exact here (the caller falls back)."""


#: why the compiled dual simplex stopped (``mplp_kernel.settle_once``'s other statuses), in
#: the numpy code's words
_SETTLE_FAILURES = {
    3: "a basis matrix is numerically singular",
    4: "a basis is not primal feasible where it should be",
    5: "the lexicographic dual simplex cycled",
    6: "an infinitesimal infeasibility (rounding)",
    7: "the lexicographic dual simplex did not settle",
}


def explore_bases(
    red: Reduced,
    size: ParameterBox,
    *,
    region_tol: float,
    lp_perturbation: float,
    seed: int,
    max_regions: int,
    progress: Callable[[int], None] | None = None,
    stats: dict | None = None,
) -> list[CriticalRegion] | None:
    """The critical regions of the mp-LP ``red`` (``H = 0``, ``C = 0``) by a search on
    the graph of its lexicographically optimal bases; None when the search could not be
    made exact (then the geometric explorer, ``mplp.explore_facets``, is used).

    Parameters
    ----------
    red : Reduced
        With ``H = 0`` and ``C = 0``.
    size : ParameterBox
        Of ``red``'s parameter set.
    region_tol : float
        A region whose inscribed ball is smaller is lower-dimensional (absolute).
    lp_perturbation : float
        Relative size of the generic cost perturbation of the LP solves at the start
        point (the selection itself is exact, lexicographic).
    seed : int
        Of the generic direction and the start point (as the explorer's).
    max_regions : int
        More regions raise a ``SolverError``.
    progress : callable, optional
        Called with the number of regions found so far each time one is added.
    stats : dict, optional
        Counters are added to it (``bases``, ``pivots``, ``facets``).

    Returns
    -------
    list of CriticalRegion or None
        In the order found; empty when the program is infeasible for every parameter.
    """
    if np.any(red.H) or np.any(red.C):
        raise ValueError("explore_bases solves mp-LPs with a parameter-free cost (H = 0, C = 0)")
    stats = {} if stats is None else stats
    try:
        return _Search(
            red,
            size,
            region_tol=region_tol,
            lp_perturbation=lp_perturbation,
            seed=seed,
            max_regions=max_regions,
            progress=progress,
            stats=stats,
        ).run()
    except _NotExactError as e:
        stats["graph_fallback"] = str(e)
        return None


class _Search:
    """The search of :func:`explore_bases` (see the module docstring)."""

    def __init__(
        self,
        red: Reduced,
        size: ParameterBox,
        *,
        region_tol: float,
        lp_perturbation: float,
        seed: int,
        max_regions: int,
        progress: Callable | None,
        stats: dict,
    ):
        self.r = red
        self.size = size
        self.scale = size.scale
        self.region_tol = region_tol
        self.max_regions = max_regions
        self.progress = progress
        self.stats = stats
        for key in ("bases", "pivots", "facets"):
            stats.setdefault(key, 0)
        # the explorer draws the generic direction first, then the start point: the same
        # draws here give the same selection (and the same start point)
        self.ex = _Explorer(
            red,
            size,
            region_tol=region_tol,
            step=1e-6 * size.scale,
            lp_perturbation=lp_perturbation,
            seed=seed,
            max_regions=max_regions,
            progress=None,
            stats=stats,
        )
        self.pert = self.ex.pert
        self.cmag = self.ex.cmag
        self.m, self.nw = red.G.shape
        self.d = red.At.shape[1]
        # a slack is zero at a point below this (absolute, in the reduced rows, which are
        # unit rows of G: a length in w)
        self.zero = 1e-9 * max(self.scale, 1.0)
        #: pivots between fresh factorisations in the dual simplex
        self.refresh = REFRESH
        self.known: dict[bytes, int] = {}
        self._rows: tuple[np.ndarray, np.ndarray] | None = None  # see _region
        self.jit = None  # the module mplp_kernel once _start_jit succeeded
        self.jit_tried = False
        self.maxit = int(50 * (self.m + red.At.shape[0] + self.d))
        # the numpy code's factorisations, by basis (rows in their order): a basis is
        # factorised for its settling, its lexicographic test and its region, and a region's
        # for each of its facets; the same LAPACK call on the same matrix, done once
        self._lus: dict[bytes, list] = {}
        self._eye = np.eye(self.nw)
        # the cost at theta = 0 as the explorer's ``_lex_state`` forms it (C = 0)
        cq0 = red.c + red.C @ np.zeros(self.d)
        self._neg_cq0, self._abs_cq0 = -cq0, np.abs(cq0)
        self._neg_pert = -self.pert
        self._abs_c = np.abs(red.c)
        self._abs_G = np.abs(red.G)
        # (|G|, |S|, |w|) for ``boundary_uncertainty``, once
        self._absolute = (self._abs_G, np.abs(red.S), np.abs(red.w))
        self._pert_tol = 1e-9 * np.max(np.abs(self.pert))

    def _start_jit(self) -> None:
        """Do each basis's work with the compiled kernel (``mplp_kernel``) from now on;
        without numba the numpy code goes on."""
        self.jit_tried = True
        try:
            from codev_engine.mp import mplp_kernel
        except ImportError:  # pragma: no cover - numba is a dependency
            self.stats["jit"] = False
            return
        f = np.ascontiguousarray
        r = self.r
        self.G, self.c, self.w, self.S = f(r.G), f(r.c, dtype=float), f(r.w), f(r.S)
        self.At, self.bt = f(r.At), f(r.bt)
        self.pertc = f(self.pert, dtype=float)
        self.jit = mplp_kernel
        self.stats["jit"] = True

    # ---- one basis --------------------------------------------------------------------

    def _factor(self, B: np.ndarray) -> list:
        """The LU factorisation of ``G[B]`` (B's rows in their order) -> ``[lu, piv,
        inverse or None, diag]``, computed once (``LU_CACHE`` kept; the inverse when first
        asked for, by :meth:`_inverse`; ``diag``: ``|diag(lu)|``, or None when ``lu`` is
        not finite). Not checked: see :meth:`_lu`."""
        key = np.asarray(B, dtype=np.intp).tobytes()
        lus = self._lus
        hit = lus.pop(key, None)
        if hit is None:
            lu, piv, _ = dgetrf(self.r.G[B])
            if len(lus) >= LU_CACHE:
                del lus[next(iter(lus))]  # the least recently used
            diag = np.abs(np.diag(lu)) if np.isfinite(lu).all() else None
            hit = [lu, piv, None, diag]
        lus[key] = hit  # (the most recently used last)
        return hit

    def _inverse(self, fac: list) -> np.ndarray:
        """``G_B^-1`` (nw, nw) of a factorisation of :meth:`_factor` (shared: not to be
        written to)."""
        if fac[2] is None:
            fac[2] = dgetrs(fac[0], fac[1], self._eye)[0]
        return fac[2]

    def _lu(self, B: np.ndarray) -> list:
        fac = self._factor(B)
        diag = fac[3]
        if diag is None or diag.min() <= 1e-12 * max(1.0, diag.max()):
            raise _NotExactError("a basis matrix is numerically singular")
        return fac

    def _settle(
        self, B: np.ndarray, theta: np.ndarray, a: np.ndarray | None, verified: bool = False
    ):
        """The optimal basis of the doubly perturbed LP at ``theta + t a`` (t -> 0+), by a
        lexicographic dual simplex from the (c, r)-optimal basis ``B``, primal feasible at
        ``theta``; None when the LP is infeasible there (past a boundary facet).

        The final basis is checked with the explorer's own test
        (``mplp._Explorer._lex_state``) from a fresh factorisation; the pivots in between
        update the tableau of the rows tight at ``theta`` (the only rows that can enter:
        the vertex at ``theta`` does not move). ``verified``: B passed that test already
        (it is not repeated when no pivot is made), nor for a basis found before.
        """
        B = np.array(B, dtype=np.intp)
        start = np.sort(B).tobytes()
        for _ in range(4):
            B, done = self._settle_once(B, theta, a)
            if B is None:
                return None
            if done:
                key = np.sort(B).tobytes()
                if key == start and verified or key in self.known or self._lex_ok(B):
                    return B
        raise _NotExactError("the lexicographic dual simplex did not settle")

    def _lex_ok(self, B: np.ndarray) -> bool:
        if self.jit is not None:
            return bool(
                self.jit.lex_ok(self.G, self.c, self.pertc, np.asarray(B, dtype=np.int64),
                                float(self.cmag))
            )
        # the explorer's test (``_Explorer._lex_state`` at theta = 0, then
        # ``_lex_negative``), on the shared factorisation
        fac = self._factor(B)
        lu, piv = fac[0], fac[1]
        if fac[3] is None or fac[3].min() == 0.0:
            return False
        d0 = dgetrs(lu, piv, self._neg_cq0, trans=1)[0]
        d1 = dgetrs(lu, piv, self._neg_pert, trans=1)[0]
        Binv = self._inverse(fac)
        err0 = np.abs(Binv.T) @ (self._abs_cq0 + self._abs_G[B].T @ np.abs(d0))
        tie = np.abs(d0) <= np.minimum(_TIE * (err0 + self.cmag), 1e-9 * self.cmag)
        return not ((~tie & (d0 < 0)) | (tie & (d1 < -self._pert_tol))).any()

    def _settle_once(self, B: np.ndarray, theta: np.ndarray, a: np.ndarray | None):
        if self.jit is not None:
            return self._settle_once_jit(B, theta, a)
        return self._settle_once_numpy(B, theta, a)

    def _settle_once_jit(self, B: np.ndarray, theta: np.ndarray, a: np.ndarray | None):
        """:meth:`_settle_once_numpy` by the compiled kernel, with rank-1 updates of the
        basis inverse between fresh factorisations every ``REFRESH`` pivots."""
        jit = self.jit
        status, Bn, piv = jit.settle_once(
            self.G, self.c, self.pertc, self.w, self.S, np.asarray(B, dtype=np.int64),
            np.asarray(theta, dtype=float), np.zeros(self.d) if a is None else a,
            self.zero, float(self.cmag), REFRESH, 20 * self.nw + 200,
        )
        self.stats["pivots"] += int(piv)
        if status == jit.SETTLED:
            return Bn, True
        if status == jit.DRIFTED:
            return Bn, False
        if status == jit.INFEASIBLE:
            return None, True
        raise _NotExactError(_SETTLE_FAILURES[int(status)])

    def _settle_once_numpy(self, B: np.ndarray, theta: np.ndarray, a: np.ndarray | None):
        r = self.r
        h = r.w + r.S @ theta
        fac = self._lu(B)
        x = dgetrs(fac[0], fac[1], h[B])[0]
        s = h - r.G @ x
        nb = np.ones(self.m, dtype=bool)
        nb[B] = False
        if (s[nb] < -1e3 * self.zero).any():
            raise _NotExactError("a basis is not primal feasible where it should be")
        tight = np.flatnonzero(nb & (s <= self.zero))
        if tight.size == 0:
            return B, True
        ha = r.S @ a if a is not None else np.zeros(self.m)
        # the local tableau: rows T (the basis, then the tight rows), in basis coordinates
        T = np.concatenate([B, tight])
        Binv = self._inverse(fac).copy()  # (updated below)
        M = r.G[T] @ Binv  # (|T|, nw); row g = M_g' G_B
        M[: self.nw] = self._eye
        pos_of = np.full(T.size, -1, dtype=np.intp)  # position in the basis, or -1
        pos_of[: self.nw] = np.arange(self.nw)
        Bloc = np.arange(self.nw)  # local index of the basis's rows
        d0 = -(r.c @ Binv)
        d1 = -(self.pert @ Binv)
        cap = 1e-9 * self.cmag
        absc = self._abs_c
        haT = ha[T]
        seen: set[bytes] = set()
        since = 0
        for _ in range(20 * self.nw + 200):
            if since >= self.refresh:
                # rounding accumulates in the updates: a fresh factorisation now and then
                since = 0
                Binv = self._inverse(self._lu(T[Bloc])).copy()
                M = r.G[T] @ Binv
                M[Bloc] = self._eye
                d0 = -(r.c @ Binv)
                d1 = -(self.pert @ Binv)
            since += 1
            rowsB = T[Bloc]  # (a new array: returned as it is)
            key = np.sort(rowsB).tobytes()
            if key in seen:
                raise _NotExactError("the lexicographic dual simplex cycled")
            seen.add(key)
            nbl = np.flatnonzero(pos_of < 0)
            Mn = M[nbl]
            haN, haB = haT[nbl], haT[Bloc]
            absM = np.abs(Mn)
            der = haN - Mn @ haB
            dtol = 1e-9 * (np.abs(haN) + absM @ np.abs(haB) + 1e-3)
            negd = der < -dtol
            if negd.any():
                kk = int(np.where(negd, der, np.inf).argmin())
            else:
                # the eps part of slack g: +eps_g - sum_j M_gj eps_{B_j}; its sign is that
                # of the lowest-numbered row with a nonzero coefficient
                zerod = np.abs(der) <= dtol
                big = absM > 1e-9 * np.maximum(absM.max(axis=1, keepdims=True), 1.0)
                cand = np.where(big, rowsB[None, :], self.m)
                first = cand.argmin(axis=1)
                lowB = cand[np.arange(nbl.size), first]
                TN = T[nbl]
                epsneg = zerod & (lowB < TN) & (Mn[np.arange(nbl.size), first] > 0)
                if not epsneg.any():
                    return rowsB, True
                kk = int(np.flatnonzero(epsneg)[TN[epsneg].argmin()])
            k = int(nbl[kk])
            al = M[k].copy()
            aal = np.abs(al)
            al[aal <= 1e-9 * max(1.0, float(aal.max()))] = 0.0  # rounding
            pos = np.flatnonzero(al > 0)
            if pos.size == 0:
                if negd[kk]:
                    return None, True  # dual unbounded: the LP is infeasible past theta
                raise _NotExactError("an infinitesimal infeasibility (rounding)")
            # ties: the explorer's rule (_Explorer._lex_state), from the updated inverse
            err0 = np.abs(Binv.T) @ (absc + self._abs_G[rowsB].T @ np.abs(d0))
            thr = np.minimum(_TIE * (err0 + self.cmag), cap)
            d0 = np.where(np.abs(d0) <= thr, 0.0, d0)
            if (d0 < 0).any():
                return rowsB, False  # drifted: refactorise
            # the lexicographic ratio test, with ties as the zeroing above makes them: a
            # dual that the step brings within the cap of zero is a tie, and the ties are
            # decided by r (so that every tie the step makes has d1 >= 0)
            d0p, alp = d0[pos], al[pos]
            rmin = float((d0p / alp).min())
            cand_i = pos[d0p - rmin * alp <= thr[pos]]
            i = int(cand_i[(d1[cand_i] / al[cand_i]).argmin()])
            if rmin == 0.0 and d1[i] < 0:
                return rowsB, False  # drifted: refactorise
            self.stats["pivots"] += 1
            t0, t1 = rmin, d1[i] / al[i]
            d0 = d0 - t0 * al
            d0[i] = t0
            d1 = d1 - t1 * al
            d1[i] = t1
            # (np.outer's products, without its wrapper)
            col = M[:, i] / al[i]
            M -= col[:, None] * al[None, :]
            M[:, i] = col
            col = Binv[:, i] / al[i]
            Binv -= col[:, None] * al[None, :]
            Binv[:, i] = col
            pos_of[Bloc[i]] = -1
            pos_of[k] = i
            Bloc[i] = k
        raise _NotExactError("the lexicographic dual simplex did not settle")

    def _region(self, B: np.ndarray, x0: np.ndarray | None = None):
        """The critical region of basis B -> (CriticalRegion, from_theta, facets) where
        ``from_theta`` marks the rows of the parameter set and ``facets`` is None or the
        centres (r, d) and radii (r,) of its facets in their hyperplanes (NaN radius: not
        known); None when thinner than ``region_tol``. ``x0``: a point near the region.

        Raises the explorer's ``too_imprecise`` error when the region's boundary cannot be
        located in double precision (``mplp.boundary_uncertainty``): the explorer would
        meet the same law and fail after far longer."""
        self._rows = None
        out = self._region_raw(B, x0)
        if out is not None:
            reg = out[0]
            # (the numpy code leaves the region's rows before the clean-up in ``_rows``)
            move = boundary_uncertainty(self.r, reg.K, reg.k, self.size.bound, self.scale,
                                        rows=self._rows, absolute=self._absolute)
            if move > PRECISION_LIMIT:
                c, _ = chebyshev_ball(reg.A, reg.b)
                raise too_imprecise(c if c is not None else x0, move)
        return out

    def _sliver(self, B: np.ndarray, x0: np.ndarray):
        """:meth:`_region` for a neighbour that came out thinner than ``region_tol``: its
        region again with the tolerance ``SLIVER_FLOOR`` (relative), accepted when its
        inscribed radius is also ``SLIVER_MARGIN`` times its boundary's uncertainty in
        double precision (``mplp.boundary_uncertainty``), else None.

        Parameters
        ----------
        B : numpy.ndarray
            The neighbour's basis, reached by the lexicographic dual simplex (so its
            region is full-dimensional in exact arithmetic).
        x0 : numpy.ndarray
            The centre of the facet crossed.

        Returns
        -------
        tuple or None
            As :meth:`_region`, with the tolerance used for its facets last.
        """
        from codev_engine.geometry.lp_kernel import OPTIMAL, chebyshev
        from codev_engine.mp import mplp_kernel

        r, f = self.r, np.ascontiguousarray
        tol = SLIVER_FLOOR * self.scale
        B = np.sort(np.asarray(B, dtype=np.int64))
        # the compiled region in either mode: its Chebyshev LP is a simplex to rounding
        # level (DAQP's can be off by far more than a sliver's width)
        status, K, k0, A, b, mark, fc, frho = mplp_kernel.region(
            f(r.G), f(r.w), f(r.S), f(r.At), f(r.bt), B, self.zero, float(tol),
            float(self.size.bound), np.asarray(x0, dtype=float), self.maxit,
        )
        if status != mplp_kernel.FULL:
            return None
        move = boundary_uncertainty(r, K, k0, self.size.bound, self.scale)
        if move > PRECISION_LIMIT:
            raise too_imprecise(x0, move)
        st, centre, _, _ = chebyshev(A, b, np.asarray(x0, dtype=float), float(self.size.bound),
                                     self.maxit)
        if st != OPTIMAL:
            return None
        # the ball certified on every row of the region (the slacks of all other rows and
        # the parameter set), not only on the rows kept
        nb = np.ones(self.m, dtype=bool)
        nb[B] = False
        Ar = np.vstack([(r.G @ K - r.S)[nb], r.At])
        br = np.concatenate([(r.w - r.G @ k0)[nb], r.bt])
        nrm = np.linalg.norm(Ar, axis=1)
        live = nrm > 1e-12
        if np.any(br[~live] < 0.0):
            return None
        radius = float(np.min((br[live] - Ar[live] @ centre) / nrm[live]))
        if not radius > max(tol, SLIVER_MARGIN * move * self.scale):
            return None
        self.stats["slivers"] = self.stats.get("slivers", 0) + 1
        reg = CriticalRegion(A=A, b=b, K=K, k=k0, active=tuple(int(i) for i in B))
        return reg, mark, (fc, frho), tol

    def _region_raw(self, B: np.ndarray, x0: np.ndarray | None = None,
                    tol: float | None = None):
        tol = self.region_tol if tol is None else tol
        if self.jit is not None:
            jit = self.jit
            status, K, k0, A, b, mark, fc, frho = jit.region(
                self.G, self.w, self.S, self.At, self.bt, np.sort(B).astype(np.int64),
                self.zero, float(tol), float(self.size.bound),
                np.zeros(self.d) if x0 is None else np.asarray(x0, dtype=float), self.maxit,
            )
            if status == jit.THIN:
                return None
            if status == jit.FALLBACK:
                self.stats["region_retries"] = self.stats.get("region_retries", 0) + 1
            else:
                active = tuple(int(i) for i in np.sort(B))
                return CriticalRegion(A=A, b=b, K=K, k=k0, active=active), mark, (fc, frho)
        return self._region_numpy(B, tol)

    def _region_numpy(self, B: np.ndarray, tol: float):
        r = self.r
        fac = self._lu(B)
        Z = dgetrs(fac[0], fac[1], np.hstack([r.w[B, None], r.S[B]]))[0]
        k0, K = Z[:, 0], Z[:, 1:]
        Ar = r.G @ K - r.S
        br = r.w - r.G @ k0
        self._rows = (Ar, br)
        nb = np.ones(self.m, dtype=bool)
        nb[B] = False
        Ar, br = Ar[nb], br[nb]
        # slacks identically zero (degenerate rows the perturbation has settled) go
        flat = (np.max(np.abs(Ar), axis=1) <= 1e-10) & (np.abs(br) <= 1e3 * self.zero)
        Ar, br = Ar[~flat], br[~flat]
        p = r.At.shape[0]
        Ar = np.vstack([Ar, r.At])
        br = np.concatenate([br, r.bt])
        mark = np.zeros(Ar.shape[0], dtype=bool)
        mark[-p:] = True
        nrm = np.linalg.norm(Ar, axis=1)
        if np.any(nrm <= 1e-12):
            zero_rows = nrm <= 1e-12
            if np.any(br[zero_rows] < -1e3 * self.zero):
                return None
            Ar, br, mark, nrm = Ar[~zero_rows], br[~zero_rows], mark[~zero_rows], nrm[~zero_rows]
        Ar, br = Ar / nrm[:, None], br / nrm
        centre, radius = chebyshev_ball(Ar, br)
        if not radius > tol:
            return None
        keep = certified_minimal_rows(Ar, br, self.size.bound)
        active = tuple(np.sort(B).tolist())  # (Python ints)
        reg = CriticalRegion(A=Ar[keep], b=br[keep], K=K, k=k0, active=active)
        return reg, mark[keep], None

    # ---- the search -------------------------------------------------------------------

    def _start(self):
        """The optimal basis at a start point and its region, or None (infeasible)."""
        ex = self.ex
        q = start_point(self.r, self.scale, self.region_tol, ex.rng)
        if q is None:
            return None
        for _ in range(8):
            sol = ex._solve_at(q)
            if sol is None:
                return None
            if not isinstance(sol, str):
                act = ex._lp_basis(q, sol[1])
                if act is not None:
                    B = self._settle(act, q, None)
                    if B is not None:
                        out = self._region(B)
                        if out is not None:
                            return B, out
            # q on a degenerate spot: move off it
            q = ex._jitter(q, 1e-3 * self.scale)
        raise _NotExactError("no full-dimensional region at the start point")

    def run(self) -> list[CriticalRegion]:
        if JIT_AFTER <= 0:
            self._start_jit()
        first = self._start()
        if first is None:
            return []
        regions: list[CriticalRegion] = []
        marks: list[np.ndarray] = []
        facets: list = []
        tols: list[float] = []  # each region's tolerance (``region_tol``, or a sliver's)
        known: dict[bytes, int] = {}
        self.known = known

        def add(B, out) -> int:
            reg, mark, fac = out[:3]
            known[np.sort(B).tobytes()] = len(regions)
            regions.append(reg)
            marks.append(mark)
            facets.append(fac)
            tols.append(out[3] if len(out) > 3 else self.region_tol)
            self.stats["bases"] += 1
            if self.progress is not None:
                self.progress(len(regions))
            if len(regions) > self.max_regions:
                raise TooManyRegionsError(too_many_regions(self.max_regions))
            if not self.jit_tried and len(regions) >= JIT_AFTER:
                self._start_jit()
            return len(regions) - 1

        At, bt = self.r.At, self.r.bt
        stats = self.stats
        stats.setdefault("touching_rows", 0)
        queue = deque([add(*first)])
        while queue:
            i = queue.popleft()
            reg = regions[i]
            B = np.array(reg.active, dtype=np.intp)
            todo = np.flatnonzero(~marks[i])
            stats["facets"] += todo.size
            fac = facets[i]
            tol = tols[i]
            if fac is not None:
                # the compiled kernel's facet centres: the rows that only touch the region
                # and the slacks' rows on the parameter set's boundary go at once
                fc, frho = fac
                rho = frho[todo]
                touching = rho <= tol
                stats["touching_rows"] += int(np.count_nonzero(touching))
                todo = todo[~touching]
                if todo.size and At.shape[0]:
                    onb = np.any(
                        (At @ reg.A[todo].T >= 1.0 - 1e-9)
                        & (np.abs(At @ fc[todo].T - bt[:, None]) <= 1e-9 * self.scale),
                        axis=0,
                    )
                    todo = todo[~onb | np.isnan(frho[todo])]
            for j in todo:
                a, beta = reg.A[j], reg.b[j]
                if fac is not None and not np.isnan(fac[1][j]):
                    centre = fac[0][j]
                else:
                    if fac is not None:
                        stats["ball_retries"] = stats.get("ball_retries", 0) + 1
                    others = np.arange(reg.A.shape[0])
                    others = others[others != j]  # (np.delete's indices)
                    centre, rho = chebyshev_ball(
                        reg.A[others], reg.b[others], a[None, :], np.array([beta])
                    )
                    if not rho > tol:
                        # a row kept without a proof of redundancy that only touches the
                        # region (at a vertex, say): not a facet, nothing to cross
                        stats["touching_rows"] += 1
                        continue
                    if np.any(
                        (At @ a >= 1.0 - 1e-9)
                        & (np.abs(At @ centre - bt) <= 1e-9 * self.scale)
                    ):
                        continue  # a slack's row on the parameter set's boundary
                nbr = self._settle(B, centre, a, verified=True)
                if nbr is None:
                    continue  # the LP is infeasible past the facet: the feasible set's boundary
                key = np.sort(nbr).tobytes()
                if key in known:
                    kn = known[key]
                    o = regions[kn]
                    marks[kn] |= (np.max(np.abs(o.A + a), axis=1) <= 1e-9) & (
                        np.abs(o.b + beta) <= 1e-9 * self.scale
                    )
                    continue
                out = self._region(nbr, centre)
                if out is None:
                    out = self._sliver(nbr, centre)
                if out is None:
                    raise _NotExactError("a neighbour's region is lower-dimensional")
                nreg = out[0]
                if np.any(nreg.A @ centre - nreg.b > 1e-7 * self.scale):
                    raise _NotExactError("a neighbour does not touch the facet crossed")
                k = add(nbr, out)
                # facet to facet: the neighbour's facet back across this one is done
                back = (np.max(np.abs(nreg.A + a), axis=1) <= 1e-9) & (
                    np.abs(nreg.b + beta) <= 1e-9 * self.scale
                )
                marks[k] = marks[k] | back
                queue.append(k)
        return regions
