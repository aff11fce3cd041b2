"""Strictly convex mp-QP by combinatorial adjacency: a graph search over active sets.

For ``H > 0`` the optimizer is unique and, for an active set ``A`` with linearly
independent rows, the KKT conditions give affine multipliers and slacks (the least-distance
form, ``M = G H^-1 G'`` and ``d(theta) = w + S theta + G H^-1 (c + C theta)``)::

    lambda_A(theta) = -M_AA^-1 d_A(theta)          (must be >= 0)
    slack_I(theta)  = d_I(theta) + M_IA lambda_A    (must be >= 0, I the other rows)

``A`` is *optimal* when that polyhedron (intersected with the parameter set) is non-empty;
it is a critical region of the partition when it is full-dimensional. The optimal active
sets, lower-dimensional ones included, are connected by adding or removing one constraint;
where LICQ breaks (dependent rows, or more rows than variables) the subsets of the set are
explored instead. Exploring that graph from one optimal active set reaches every critical
region, degenerate facets included (several constraints changing on one hyperplane, which
defeats exploration "across the facet"). This is the combinatorial-adjacency idea of
Arnstroem & Axehill (CDC 2024, ParametricDAQP), written here for numpy: one small solve and
one Chebyshev-ball LP per candidate active set.
"""

from __future__ import annotations

import copy
import functools
import os
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace

import daqp
import numpy as np
from scipy.linalg import cho_solve, solve_triangular
from scipy.linalg.lapack import dgeqrf

from codev_engine.errors import SolverError
from codev_engine.executor import Executor, result_resubmitting, scattered
from codev_engine.geometry.polytope import (
    bounding_box,
    certified_minimal_rows,
    chebyshev_ball,
    checked_minimal_rows,
    radius_upper_bound,
    row_hashes,
)
from codev_engine.mp.solution import (
    CriticalRegion,
    RegionArrays,
    TooManyRegionsError,
    segment_indices,
    too_many_regions,
)

__all__ = ["explore_active_sets"]


#: regions found before the search goes parallel (small problems stay serial: a thread
#: pool costs little, but an executor's tasks cost milliseconds each)
PARALLEL_AFTER = 400
#: regions found before candidates go to the compiled kernel (mpqp_kernel; importing numba
#: and loading the kernel costs ~1 s, more than small problems take altogether)
JIT_AFTER = 200
#: results of the compiled walk up to this many regions are sorted by active set, as the
#: numpy walk's are (the partition's order then depends on neither walk; larger ones stay
#: in the walk's order, which spares a second copy of every row)
SORTED_UP_TO = 200_000
#: batches' regions put together into one chunk of arrays during the compiled walk
_PARTS_PER_CHUNK = 256
#: candidates in one batch of the compiled walk (and per numpy-kernel task)
_CHUNK = 64
#: batches in flight in the compiled walk, whatever runs them: batches are popped and their
#: results taken at fixed points of the walk, never "when ready", so its order, and with it
#: the point each candidate's LP starts from, depends on neither timing, nor the executor,
#: nor the worker count (the partition is the same, bit for bit)
_DEPTH = 64
#: consecutive batches sent to an executor as one task (1024 candidates, ~0.1 s of work:
#: a Dask task costs milliseconds); _DEPTH / _GROUP tasks are in flight
_GROUP = 16

#: HiGHS's primal and dual feasibility tolerances where it decides a candidate's class
#: (``_Kernel._chebyshev``): a ball of radius 5e-9 then checks (scale 4)
CANONICAL_TOL = 1e-10
#: the compiled kernel concludes on a candidate only with a proof this factor clear of the
#: region tolerance (a ball above ``CLOSE_CALL * region_tol``, a radius bound below
#: ``region_tol / CLOSE_CALL``); the close calls between are handed to the numpy kernel,
#: whose decision is a function of the active set alone (``_Kernel._chebyshev``)
CLOSE_CALL = 2.0

#: an inactive constraint's row this close (unit rows) to the span of the active rows has its
#: slack computed from that dependency, not from the multipliers
#: (``_Kernel._dependent_slacks``; the same bound as ``mpqp_kernel._swaps``' dependency)
DEPENDENT_SLACK = 1e-9

#: a multiplier's or slack's row (columns constant, theta) vanishes for every theta when its
#: theta part is below this many ulps of the terms it was computed from (at least 1e-12),
#: and its constant then decides alone (``_vanishing``): the terms, not 1, set
#: the rounding. An exact penalty of 1e4 on soft state bounds in units 10^1.5 apart gave
#: multipliers of 1.5e5 and a slack that is zero for every theta computed as -1.1e-11 +
#: 3.7e-13 theta_2: judged against an absolute 1e-12, the region across that facet was
#: "empty", the search stopped at 5 regions and left a hole (test_scaled_formulations)
VANISH_ULPS = 64.0

#: Estimated condition number of M_AA (from its Cholesky factor's diagonal) above which an
#: active set's multipliers and law come from the augmented KKT system (_kkt_augmented)
ILL_CONDITIONED = 1e6


class _Kernel:
    """Everything needed to evaluate one candidate active set (the problem's data,
    precomputed). Before the compiled kernel starts it is plain data: an executor's
    workers get a copy in memory (scattered once)."""

    def __init__(self, H, c, C, G, w, S, At, bt, scale: float, region_tol: float, box):
        self._setup(G, At, bt, scale, region_tol, box)
        self.Hinv_Gt = np.linalg.solve(H, G.T)  # (nz, m)
        self.M = G @ self.Hinv_Gt  # (m, m)
        Hinv_c = np.linalg.solve(H, c)
        Hinv_C = np.linalg.solve(H, C)
        # d(theta) = D0 + D1 theta, as one (m, d+1) array
        self.Dfull = np.hstack([(w + G @ Hinv_c)[:, None], S + G @ Hinv_C])
        self.negZ0 = -np.hstack([Hinv_c[:, None], Hinv_C])
        # for the KKT system of ill-conditioned active sets (see _kkt)
        self.H = H
        self.rhs_z = np.hstack([-c[:, None], -C])
        self.wS = np.hstack([w[:, None], S])

    def _inactive(self, A: np.ndarray) -> np.ndarray:
        """The constraints not in the active set ``A``, in order."""
        mask = np.ones(self.m, dtype=bool)
        mask[A] = False
        return self.idx[mask]

    def _solve_kkt(self, A: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``[[H, G_A'], [G_A, 0]] [Z; Lam] = rhs`` -> (Z (nz, k), Lam (na, k))."""
        nz, GA = self.nz, self.G[A]
        K = np.zeros((nz + A.size, nz + A.size))
        K[:nz, :nz] = self.H
        K[:nz, nz:] = GA.T
        K[nz:, :nz] = GA
        X = np.linalg.solve(K, rhs)
        return X[:nz], X[nz:]

    def _setup(self, G, At, bt, scale: float, region_tol: float, box) -> None:
        """What every kernel needs: sizes, the parameter set, tolerances, its box."""
        self.nz, self.d, self.m = G.shape[1], At.shape[1], G.shape[0]
        self.G = G
        self.At, self.bt = At, bt
        self.idx = np.arange(self.m)
        self.zeros_t = np.zeros(At.shape[0], dtype=np.intp)
        self.scale = scale
        self.region_tol = region_tol
        self.nonempty_tol = 1e-8 * scale
        self.box = _padded_box(*box)  # (centre, half-widths) or None
        # max |theta_i| over the box: where certificates charge their residuals
        self.bound = (
            None if self.box is None else float(np.max(np.abs(self.box[0]) + self.box[1]))
        )
        self._jit = None  # the module mpqp_kernel once start_jit succeeded

    def start_jit(self) -> bool:
        """Evaluate candidates with the compiled kernel (``mpqp_kernel``) from now on, where it
        applies (H > 0 and a bounded parameter set); False when numba is unavailable."""
        if self.box is None or type(self) is not _Kernel:
            return False
        try:
            from codev_engine.mp import mpqp_kernel
        except ImportError:  # pragma: no cover - numba is a dependency
            return False
        f = np.ascontiguousarray
        self._jit_args = (
            f(self.G), f(self.M), f(self.Dfull), f(self.negZ0), f(self.Hinv_Gt), f(self.H),
            f(self.rhs_z), f(self.wS), f(self.At),
            f(self.bt), f(self.box[0]), f(self.box[1]), float(self.scale),
            float(self.region_tol), float(self.nonempty_tol), float(ILL_CONDITIONED),
            int(50 * (self.m + self.At.shape[0] + self.d)), float(CLOSE_CALL),
        )
        self._jit = mpqp_kernel
        return True

    def evaluate(self, act: tuple[int, ...]):
        """:meth:`evaluate_numpy`, by the compiled kernel once :meth:`start_jit` succeeded
        (it hands back the candidates it cannot conclude on)."""
        jit = self._jit
        if jit is not None:
            status, Ak, bk, K, k, moves, lp, swaps, _ = jit.evaluate(
                np.array(act, dtype=np.int64), self.box[0], *self._jit_args
            )
            if status == jit.FULL:
                if swaps.size:  # this walk takes the plain moves (see mpqp_kernel._swaps)
                    moves = np.union1d(moves, -(swaps[:, 0] + 1))
                return "full", (Ak, bk), (K, k), moves, lp
            if status != jit.FALLBACK:
                neighbours = moves if status == jit.LOWER else None
                return jit.STATUS_NAMES[status], None, None, neighbours, lp
        return self.evaluate_numpy(act)

    def evaluate_numpy(self, act: tuple[int, ...]):
        """Classify the active set ``act``.

        Returns
        -------
        (status, rows, law, moves, lp) : tuple
            ``status`` is "licq" (rows dependent or too many), "empty", "lower" or "full";
            ``rows = (A, b)`` and ``law = (K, k)`` for a full region; ``moves`` the signed
            constraint ids of the neighbours (``+i+1``: i may leave, ``-(i+1)``: i may enter);
            ``lp`` whether a Chebyshev LP was solved.
        """
        A = np.array(act, dtype=np.intp)
        if A.size > self.nz:
            return "licq", None, None, None, False
        # rows of G_A (unit norm) dependent, or nearly: LICQ broken
        # (LAPACK's QR straight: numpy's wrapper costs more than the factorisation)
        if A.size and np.min(np.abs(np.diagonal(dgeqrf(self.G[A].T)[0])[: A.size])) < 1e-9:
            return "licq", None, None, None, False
        kkt = self._kkt(A)
        if isinstance(kkt, str):
            return kkt, None, None, None, False
        Lam, Sl, inact, tie, Z, mag = kkt
        # lambda >= 0  <=>  -Lam1 theta <= Lam0 ;  slack >= 0  <=>  -Sl1 theta <= Sl0
        Ar = np.vstack([-Lam[:, 1:], -Sl[:, 1:], self.At])
        br = np.concatenate([Lam[:, 0], Sl[:, 0], self.bt])
        src = np.concatenate([A + 1, -(inact + 1), self.zeros_t])
        norms = np.sqrt(np.einsum("ij,ij->i", Ar, Ar))
        zero_tol, const_tol = _vanishing(mag, self.At.shape[0])
        zero = norms <= zero_tol
        if np.any(zero):
            bz = br[zero]
            bad = bz < -const_tol[zero]
            if tie is not None:
                # a multiplier or slack that is zero for every theta: the tie is broken by
                # the perturbation direction (lexicographic selection, semi-definite H)
                tz = np.concatenate([tie, np.zeros(self.At.shape[0])])[zero]
                bad |= (bz <= 1e-10 * (1.0 + self.scale)) & (tz < -1e-12 * (1.0 + self.scale))
            if np.any(bad):
                return "empty", None, None, None, False
        keep_nz = ~zero
        Ar, br, src = Ar[keep_nz] / norms[keep_nz, None], br[keep_nz] / norms[keep_nz], src[keep_nz]
        centre, rho = self._chebyshev(Ar, br)
        if not rho >= -self.nonempty_tol:
            return "empty", None, None, None, True
        if not rho > self.region_tol:
            # lower-dimensional: its neighbours are the constraints tight at a point of it
            tight = Ar @ centre - br >= -max(rho, 0.0) - 1e-7 * self.scale
            return "lower", None, None, src[tight], True
        # rows that hold on the whole bounding box of the parameter set are implied by the
        # parameter-set rows (always kept): only the others go to the LP-based minrep
        # (the parameter-set rows go in too: minrep needs a bounded polytope, and dropped a
        # needed row of pop_mpqp_084 without them)
        maybe = np.ones(src.shape[0], dtype=bool)
        if self.box is not None:
            reach = Ar @ self.box[0] + np.abs(Ar) @ self.box[1]  # max of each row on the box
            maybe = (reach > br - 1e-9 * self.scale) | (src == 0)
        maybe = np.flatnonzero(maybe)
        fixed = np.flatnonzero(src[maybe] == 0)
        if self.box is not None:
            # minrep's redundancy decisions were seen wrong by 5e-6 (normalised), amplified by
            # the rows' gains (pop_mpqp_084: a law off by 16; pop_mpqp_011, _017, _019:
            # overlaps of 2e-5): a row is dropped only with a certificate. DAQP's minrep was
            # also seen dropping a parameter-set row that is not redundant (pop_mpqp_085: a
            # region reaching theta_2 = 106 in a box of +-10); those rows are few and cheap to
            # keep: every region stays inside the parameter set
            keep = maybe[certified_minimal_rows(Ar[maybe], br[maybe], self.bound, fixed)]
        else:
            keep = maybe[checked_minimal_rows(Ar[maybe], br[maybe], centre, rho)]
            keep = np.union1d(keep, maybe[fixed])
        # the neighbours: constraints of the facets, and of rows on a facet's hyperplane
        # (several constraints changing on one hyperplane: a degenerate facet)
        bf = br[keep]
        tol = 1e-9 * (1.0 + np.abs(bf))
        i, j = np.nonzero(np.abs(br[:, None] - bf[None, :]) <= tol)  # offsets first: cheap
        same = np.abs(Ar[i] - Ar[keep[j]]).max(axis=1) <= tol[j]
        moves = src[np.unique(i[same])]
        if Z is None:
            # z = -H^-1 (c + C theta) - H^-1 G_A' lambda_A(theta)
            Z = self.negZ0 - self.Hinv_Gt[:, A] @ Lam
        Z = self._refined(A, Z, Lam)
        return "full", (Ar[keep], br[keep]), (Z[:, 1:], Z[:, 0]), moves, True

    def _refined(self, A: np.ndarray, Z: np.ndarray, Lam: np.ndarray) -> np.ndarray:
        """The law ``Z`` (nz, d+1) after one step of iterative refinement on the KKT system
        of ``A``: its active constraints then hold to the rounding of their own terms.

        Through ``M_AA`` (or the augmented system) the multipliers carry the rounding of
        the largest of them into the law: with an exact penalty's multipliers of 1e6 a
        region with ``u`` at its bound had ``u`` 2e-9 to 1.8e-6 past it
        (test_scaled_formulations, soft state bounds in units far apart). The same step
        as ``mpqp_kernel._refined``."""
        if not A.size:
            return Z
        GA, k = self.G[A], Z.shape[1]
        r = np.vstack([self.rhs_z[:, :k] - self.H @ Z - GA.T @ Lam,
                       self._slack_columns()[A, :k] - GA @ Z])
        dZ, _ = self._solve_kkt(A, r)
        return Z + dZ

    def _chebyshev(self, Ar: np.ndarray, br: np.ndarray) -> tuple[np.ndarray, float]:
        """Chebyshev ball of a candidate's rows (unit rows, parameter-set rows among them).

        With a bounded parameter set the radius decides nothing unproved, as in the
        compiled kernel: a region is full only with a centre whose slack in every row
        exceeds the region tolerance, empty or lower-dimensional only with an upper bound
        of the radius from the LP's multipliers (:func:`radius_upper_bound`). DAQP's ball
        comes first; where it proves nothing, HiGHS's decides, with tolerances of
        ``CANONICAL_TOL`` (its default 1e-7 left thin regions of radius 2e-8 with a
        centre that does not check: taken as lower-dimensional, while the compiled kernel
        proved them full from some start points: chain5's partitions differed by such
        regions, and had holes there). What no ball nor bound proves is lower-dimensional.
        DAQP's proximal LP was seen 1e-5 off: it judged empty regions of ``pop_mpqp_001``
        and ``pop_mpqp_084`` of radius 1e-5, and the partitions had holes there.

        Every step is a function of the rows alone (no start point, fixed solver options):
        the compiled kernel hands its close calls to this one (``CLOSE_CALL``), so a thin
        region's class does not depend on the walk's order nor on the kernel.

        Returns
        -------
        centre : (d,) ndarray
        rho : float
            Above ``region_tol``: a proved ball (full); below ``-nonempty_tol``: proved empty;
            else lower-dimensional (``rho`` is then the centre's radius, clipped to that
            range).
        """
        centre, rho, y = chebyshev_ball(Ar, br, multipliers=True)
        if self.box is None or self._proved(Ar, br, centre, rho, y):
            return centre, rho
        centre, rho, y = chebyshev_ball(Ar, br, solver="highs", multipliers=True,
                                        tol=CANONICAL_TOL)
        if not np.all(np.isfinite(centre)):  # (HiGHS failed: empty, as it always was)
            return centre, rho
        ball = float(np.min(br - Ar @ centre))
        if ball > self.region_tol:
            return centre, ball
        upper = np.inf if y is None else radius_upper_bound(Ar, br, y, self.bound)
        if upper < -self.nonempty_tol:
            return centre, upper
        # lower-dimensional: proved (upper <= region_tol), or the unproved default
        return centre, min(max(ball, -self.nonempty_tol), self.region_tol)

    def _proved(
        self, Ar: np.ndarray, br: np.ndarray, centre: np.ndarray, rho: float,
        y: np.ndarray | None,
    ) -> bool:
        """Whether the ball (centre, rho) from multipliers ``y`` proves its class."""
        if rho > self.region_tol:
            return float(np.min(br - Ar @ centre)) > self.region_tol
        if y is None:
            return False
        need = self.region_tol if rho >= -self.nonempty_tol else -self.nonempty_tol
        return radius_upper_bound(Ar, br, y, self.bound) <= need

    def _kkt(self, A: np.ndarray):
        """Multipliers and slacks of the active set ``A`` (LICQ holds), affine in theta.

        Returns
        -------
        str or tuple
            "licq" when ``M_AA`` is not positive definite; else ``(Lam (na, d+1),
            Sl (m-na, d+1), inact, tie, Z)`` with columns (constant, theta), ``tie`` None
            (H > 0: the optimizer is unique) and ``Z`` None (computed for full regions).
        """
        if A.size:
            MA = self.M[A]
            try:
                Lc = np.linalg.cholesky(MA[:, A])
            except np.linalg.LinAlgError:
                return "licq"
            diag = np.diag(Lc)
            if (diag.max() / diag.min()) ** 2 > ILL_CONDITIONED:
                return self._kkt_augmented(A)
            Lam = cho_solve((Lc, True), -self.Dfull[A])  # (na, d+1)
        else:
            MA = np.zeros((0, self.m))
            Lam = np.zeros((0, self.d + 1))
        inact = self._inactive(A)
        Sl = self.Dfull[inact] + MA[:, inact].T @ Lam
        # the rounding of each row: the multipliers share the largest one's (one solve),
        # a slack adds its terms' magnitudes (see VANISH_ULPS)
        big = np.abs(Lam).max(axis=0, initial=0.0)
        mag = np.vstack([np.broadcast_to(big, Lam.shape),
                         np.abs(self.Dfull[inact]) + np.abs(MA[:, inact]).T @ (np.abs(Lam) + big)])
        Sl = self._dependent_slacks(A, inact, Sl, lambda: self.negZ0 - self.Hinv_Gt[:, A] @ Lam,
                                    mag)
        return Lam, Sl, inact, None, None, mag

    def _dependent_slacks(
        self, A: np.ndarray, inact: np.ndarray, Sl: np.ndarray, law: Callable[[], np.ndarray],
        mag: np.ndarray,
    ) -> np.ndarray:
        """``Sl`` with the slack of every inactive constraint whose row lies in the span of
        the active rows (``g_i = G_A' c + r``, ``|r| < DEPENDENT_SLACK``) taken from that
        dependency: ``w_i + S_i theta - c' (w_A + S_A theta) - r' z(theta)``.

        Where LICQ nearly fails the multipliers are huge (chain5's thin regions: 3e9 on
        rows of size 1), and ``d_i + M_iA lambda_A`` loses ~1e-7 to rounding, while the
        slack of a constraint in the span of the active ones does not depend on the
        multipliers at all (the active constraints hold with equality): a twin of an
        active constraint (chain5's ``u_0 <= 1`` and ``u_0 <= 4 - 2 x_4``) and a row that
        is a combination of active ones. Those rows are the degenerate facets, where the
        region across has the twin active instead (``mpqp_kernel._swaps``); computed from
        the multipliers, the facet of each side was off by up to 1.4e-7, and the regions
        on either side overlapped by that (radius 7e-8, the region tolerance 4e-9).

        Parameters
        ----------
        A : (na,) ndarray of int
            The active set (LICQ holds).
        inact : (ni,) ndarray of int
            The other constraints, ``Sl``'s rows.
        Sl : (ni, k) ndarray
            Their slacks as columns (constant, theta, ...), as ``wS`` (``self.wS``'s
            columns).
        law : callable
            Gives the optimizer's columns ``z`` (nz, k) (called only when a row is
            dependent).
        mag : (na + ni, k) ndarray
            The magnitudes of the terms of the multipliers' and slacks' rows (their
            rounding, ``VANISH_ULPS``); a dependent row's are set here, in place.

        Returns
        -------
        (ni, k) ndarray
        """
        if not A.size or not inact.size:
            return Sl
        Q, R = np.linalg.qr(self.G[A].T)  # G_A' = Q R
        P = self.G[inact] @ Q  # (ni, na)
        resid = self.G[inact] - P @ Q.T
        dep = np.flatnonzero(np.einsum("ij,ij->i", resid, resid) < DEPENDENT_SLACK**2)
        if not dep.size:
            return Sl
        wS = self._slack_columns()
        c = solve_triangular(R, P[dep].T)  # (na, nd): G_A' c = Q P' for each row
        Sl = Sl.copy()
        Z = law()
        Sl[dep] = wS[inact[dep]] - c.T @ wS[A] - resid[dep] @ Z
        mag[A.size + dep] = (np.abs(wS[inact[dep]]) + np.abs(c.T) @ np.abs(wS[A])
                             + np.abs(resid[dep]) @ np.abs(Z))
        return Sl

    def _slack_columns(self) -> np.ndarray:
        """``w + S theta`` as columns (constant, theta), as the slacks' columns."""
        return self.wS

    def _kkt_augmented(self, A: np.ndarray):
        """The KKT system ``[[H, G_A'], [G_A, 0]] [z; lambda] = [-(c + C theta); w_A + S_A
        theta]`` solved as it stands, for nearly dependent active rows.

        The dual Schur complement ``M_AA = G_A H^-1 G_A'`` squares their conditioning: on
        pop_mpqp_021 (active rows with singular values 856 and 0.088, cond(M_AA) = 6e10)
        the law it gave violated its own active constraints by 1e-5 and its value was off by
        5e-5 relative; the augmented system does not square it.
        """
        Z, Lam = self._solve_kkt(A, np.vstack([self.rhs_z, self.wS[A]]))  # columns (1, theta)
        inact = self._inactive(A)
        Sl = self.wS[inact] - self.G[inact] @ Z
        mag = _solved_magnitudes(Lam, self.wS[inact], self.G[inact], Z)
        return Lam, self._dependent_slacks(A, inact, Sl, lambda: Z, mag), inact, None, Z, mag


def _solved_magnitudes(Lam: np.ndarray, wS: np.ndarray, G: np.ndarray,
                       Z: np.ndarray) -> np.ndarray:
    """The terms' magnitudes (``VANISH_ULPS``) of multipliers ``Lam`` (na, k) and slacks
    ``wS - G Z`` (ni, k) from one solve of the KKT system (columns as ``Lam``'s):
    the multipliers share the largest one's, a slack adds its terms'."""
    big = np.abs(Lam).max(axis=0, initial=0.0)
    return np.vstack([np.broadcast_to(big, Lam.shape), np.abs(wS) + np.abs(G) @ np.abs(Z)])


def _vanishing(mag: np.ndarray, p: int) -> tuple[np.ndarray, np.ndarray]:
    """The tolerances under which a candidate's row vanishes for every theta.

    Parameters
    ----------
    mag : (r, d + 1) ndarray
        The magnitudes of the terms each multiplier's and slack's row was computed from,
        columns (constant, theta).
    p : int
        The parameter-set rows that follow them (exact data: the absolute floor).

    Returns
    -------
    zero_tol : (r + p,) ndarray
        A row whose theta part's norm is at most this is constant (rounding).
    const_tol : (r + p,) ndarray
        Such a row with a constant below minus this is violated everywhere (empty).
    """
    ulp = VANISH_ULPS * np.finfo(float).eps
    zero = np.maximum(1e-12, ulp * np.sqrt(np.einsum("ij,ij->i", mag[:, 1:], mag[:, 1:])))
    const = np.maximum(1e-12, ulp * mag[:, 0])
    floor = np.full(p, 1e-12)
    return np.concatenate([zero, floor]), np.concatenate([const, floor])


#: a set of rows whose smallest singular value is below this is taken as exactly dependent
#: (rounding): its null vector's support decides which subsets the walk visits
#: (``dependent_rows``); near-dependent sets keep the rule "every subset"
DEPENDENT_SIGMA = 1e-12
#: entries of that null vector below this (relative to its largest) are taken as zero
SUPPORT_TOL = 1e-12


def dependent_rows(G: np.ndarray, act: tuple[int, ...]) -> list[int]:
    """The constraints of an active set that breaks LICQ whose removal the graph search
    tries (one subset each).

    An active set ``T`` breaks LICQ (``G_T`` dependent, or more rows than variables). The
    active sets the search needs below it are those with independent rows (the others are
    LICQ again). Every subset ``S`` of ``T`` with independent rows misses a constraint of
    the support of any null vector ``v`` of ``G_T'`` (else ``G_S' v_S = G_T' v = 0``), so
    ``S`` lies inside ``T - k`` for some ``k`` in that support: removing those constraints
    alone reaches every basis of ``T`` (when ``T - k`` breaks LICQ too, its own rule goes
    on). The other subsets of ``T`` (removing constraints outside the support too: double
    moves) are reached, where they are optimal, by the moves of the sets they are subsets
    of, as every other active set is. On the servo of ``benchmarks/formulations.py`` (N =
    10) this takes the search from 31,044 candidates to about 1,100, for the same 341
    regions: the rate rows make many dependent sets, each of whose subsets (mostly empty)
    were all visited before.

    ``T`` whose rows are only nearly dependent (smallest singular value above
    ``DEPENDENT_SIGMA``: LICQ was judged broken by a tolerance or by the Cholesky factor
    of ``M_TT``) keep the old rule: every constraint is tried.

    Parameters
    ----------
    G : (m, nz) ndarray
        The constraint rows (unit norm).
    act : tuple of int
        The active set ``T``, ascending.

    Returns
    -------
    list of int
        The constraints of ``T`` to try removing, ascending.
    """
    T = list(act)
    n, nz = len(T), G.shape[1]
    if n < 2:
        return T
    _, sv, Vt = np.linalg.svd(G[T].T)  # (nz, n): Vt (n, n)
    if n <= nz and not sv[-1] < DEPENDENT_SIGMA:
        return T
    v = np.abs(Vt[-1])
    return [a for a, x in zip(T, v, strict=True) if x > SUPPORT_TOL * v.max()]


def _padded_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The parameter set's bounding box as (centre, half-widths), widened by a relative
    1e-9 so that it surely contains the set; None when a side is infinite (then no row is
    dropped on its account)."""
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        return None
    pad = 1e-9 * (1.0 + np.abs(lo) + np.abs(hi))
    return 0.5 * (lo + hi), 0.5 * (hi - lo) + pad


class _KernelSemidefinite(_Kernel):
    """The kernel for a positive semi-definite (singular, non-zero) H.

    The optimizer need not be unique: the one selected is the limit, as eps -> 0+, of the
    unique optimizer for the cost ``c + eps r`` with a fixed generic direction ``r`` (the
    lexicographic rule of the mp-LP path). For an active set whose KKT matrix
    ``[[H, G_A'], [G_A, 0]]`` is nonsingular (G_A independent, H definite on its null
    space) the multipliers, slacks and optimizer are affine in theta plus eps times a
    constant; a row that vanishes for every theta is decided by its eps part. Active sets
    with a singular KKT matrix are "singular": the search goes on through their supersets
    (across such a facet one constraint leaves and another enters, as in a simplex pivot).
    The caller makes sure no direction of recession exists (the eps problem is bounded).
    """

    def __init__(self, H, c, C, G, w, S, At, bt, scale: float, region_tol: float, box, r):
        self._setup(G, At, bt, scale, region_tol, box)
        self.H, self.w, self.S = H, w, S
        # right-hand sides (constant, theta, eps) of the stationarity rows
        self.rhs_z = np.hstack([-c[:, None], -C, -r[:, None]])
        self.h_tol = 1e-9 * max(1.0, float(np.max(np.abs(H))))

    def _kkt(self, A: np.ndarray):
        nz, na, d = self.nz, A.size, self.d
        GA = self.G[A]
        # H definite on null(G_A)?  (else the KKT matrix is singular)
        if na < nz:
            Q = np.linalg.qr(GA.T, mode="complete")[0] if na else np.eye(nz)
            N = Q[:, na:]
            if np.linalg.eigvalsh(N.T @ self.H @ N).min() <= self.h_tol:
                return "singular"
        rhs = np.vstack([self.rhs_z, np.hstack([self.w[A, None], self.S[A], np.zeros((na, 1))])])
        Zf, Lf = self._solve_kkt(A, rhs)  # columns constant, theta, eps
        inact = self._inactive(A)
        Sf = np.hstack([self.w[inact, None], self.S[inact], np.zeros((inact.size, 1))])
        mag = _solved_magnitudes(Lf, Sf, self.G[inact], Zf)
        Sf -= self.G[inact] @ Zf
        Sf = self._dependent_slacks(A, inact, Sf, lambda: Zf, mag)
        tie = np.concatenate([Lf[:, -1], Sf[:, -1]])
        return Lf[:, : d + 1], Sf[:, : d + 1], inact, tie, Zf[:, : d + 1], mag[:, : d + 1]

    def _slack_columns(self) -> np.ndarray:
        """``w + S theta + 0 eps`` as columns (constant, theta, eps)."""
        return np.hstack([self.w[:, None], self.S, np.zeros((self.m, 1))])


def _evaluate_chunk(kernel: _Kernel, acts: list[tuple[int, ...]]) -> list:
    """Worker side (an executor's task): evaluate candidates with the numpy kernel, which
    the client sent in memory (scattered once to every worker)."""
    return [kernel.evaluate_numpy(a) for a in acts]


def _evaluate_batches(shared: tuple, batches: list) -> tuple[list, float]:
    """Worker side (an executor's task): the compiled kernel on consecutive batches of the
    walk; the results in the batches' order (compacted: :func:`_compact`), and the seconds
    this took on the worker.

    Parameters
    ----------
    shared : tuple
        ``(args, tail, kernel)``: the compiled kernel's problem data (``_Kernel._jit_args``:
        arrays and numbers), the parameter set's rows as the client's regions hold them
        (``_CompiledWalk.shared``, or None) and the numpy kernel (a ``_Kernel`` without
        its compiled one), scattered once to every worker.
    batches : list of ((b, W) uint64 ndarray, (b, d) ndarray)
        The candidates' bitmasks and start points, as ``ActiveSetGraph.pop`` gave them.

    Returns
    -------
    tuple
        ``(out, seconds)``: each batch's compacted result (:func:`_compact`), its LICQ
        candidates' subsets to visit as their moves (``active_sets.licq_moves``) and the
        numpy kernel's results of the candidates the compiled one handed back; and the
        seconds this took on the worker.
    """
    from codev_engine.mp import active_sets, mpqp_kernel  # (numba: from its cache)

    args, tail, kernel = shared
    t0 = time.perf_counter()
    out = []
    for keys, starts in batches:
        result = mpqp_kernel.evaluate_batch(keys, starts, args)
        # the candidates the compiled kernel handed back, through the numpy kernel here (it
        # is a function of the candidate alone): the client only takes the results
        status, acts, sizes = result[0], result[2], result[3]
        handed = [kernel.evaluate_numpy(tuple(acts[c, : sizes[c]].tolist()))
                  for c in np.flatnonzero(status == mpqp_kernel.FALLBACK)]
        # and the LICQ candidates' subsets to visit (an SVD each) as their moves
        moves = active_sets.licq_moves(keys, status, result[9], result[10], args[0],
                                       DEPENDENT_SIGMA, SUPPORT_TOL)
        result = (*result[:9], *moves, *result[11:])
        out.append((*_compact(result, tail, mpqp_kernel.FULL), handed))
    return _pack_batches(out), time.perf_counter() - t0


def _pack_batches(results: list) -> tuple:
    """The batches' results of a task as one array per field (each field's arrays
    concatenated): a task's ~270 small arrays cost the client ~9 ms more CPU to receive
    than 16 arrays of the same bytes. :func:`_batch_of` takes batch ``i`` back out.

    Parameters
    ----------
    results : list of tuple
        Each batch's compacted result and handed-back results (``_evaluate_batches``).

    Returns
    -------
    tuple
        ``(arrays, offsets, handed)``: the fields (None where a field is None), the
        (len(results) + 1, fields) list of each batch's start in each field, and the
        handed-back results of each batch.
    """
    fields = len(results[0]) - 1
    counts = [[0 if r[j] is None else len(r[j]) for j in range(fields)] for r in results]
    arrays = tuple(
        None if results[0][j] is None else np.concatenate([r[j] for r in results])
        for j in range(fields)
    )
    offsets = np.zeros((len(results) + 1, fields), dtype=np.int64)
    np.cumsum(np.array(counts, dtype=np.int64).reshape(len(results), fields), axis=0,
              out=offsets[1:])
    return arrays, offsets.tolist(), [r[-1] for r in results]


def _batch_of(packed: tuple, i: int) -> tuple:
    """Batch ``i``'s result out of :func:`_pack_batches`' (views of its arrays).

    Parameters
    ----------
    packed : tuple
        ``_pack_batches``' result.
    i : int
        The batch.

    Returns
    -------
    tuple
        The batch's compacted result, then its handed-back results.
    """
    arrays, offsets, handed = packed
    lo, hi = offsets[i], offsets[i + 1]
    return (*(None if a is None else a[s:e] for a, s, e in zip(arrays, lo, hi, strict=True)),
            handed[i])


def _compact(result: tuple, tail: tuple | None, full_code: int) -> tuple:
    """A batch's result without what the client would throw away, so that less travels:
    the law of the regions only (``K``, ``k`` of the FULL candidates: (f, nz, d), (f, nz)),
    and, given the parameter set's rows ``tail``, each region's rows without that tail
    where the region ends with it (``implied``, the same test as
    :meth:`_CompiledWalk._pack`'s). The result's other fields are unchanged.

    Parameters
    ----------
    result : tuple
        ``mpqp_kernel.evaluate_batch``'s.
    tail : tuple of ((p, d) ndarray, (p,) ndarray) or None
        The parameter set's rows; None: the rows are kept whole.
    full_code : int
        ``mpqp_kernel.FULL``.

    Returns
    -------
    tuple
        ``result`` with ``rows_off``, ``A``, ``b``, ``K``, ``k`` compacted, and one more
        field: the (f,) ``implied`` flags (None when ``tail`` is None).
    """
    (status, lp, acts, sizes, rows_off, A, b, K, k, *rest) = result
    full = np.flatnonzero(status == full_code)
    K, k = K[full], k[full]
    if tail is None:
        return (status, lp, acts, sizes, rows_off, A, b, K, k, *rest, None)
    r0, r1 = rows_off[full], rows_off[full + 1]
    p = tail[0].shape[0]
    implied = np.zeros(full.size, dtype=bool)
    if p and full.size:
        at = r1[:, None] - p + np.arange(p)
        implied = (r1 - r0 >= p) & np.all(
            np.all(A[at] == tail[0], axis=2) & (b[at] == tail[1]), axis=1
        )
    kept = r1 - r0 - p * implied
    rows, _ = segment_indices(r0, kept)
    off = np.zeros(status.size + 1, dtype=np.int64)
    off[full + 1] = kept
    np.cumsum(off, out=off)
    return (status, lp, acts, sizes, off, A[rows], b[rows], K, k, *rest, implied)


def _warm_worker(args: tuple) -> float:
    """Worker side: import and load the compiled kernel (numba's cache) with a batch of no
    candidates, so the first real task does not pay for it; the seconds it took."""
    t0 = time.perf_counter()
    from codev_engine.mp import mpqp_kernel

    d = args[10].shape[0]
    W = (args[0].shape[0] + 63) // 64
    mpqp_kernel.evaluate_batch(np.zeros((0, W), np.uint64), np.zeros((0, d)), args)
    from codev_engine.mp import active_sets

    # (and the LICQ candidates' SVD: active_sets.licq_moves)
    active_sets.licq_moves(np.zeros((1, W), np.uint64), np.array([mpqp_kernel.LICQ]),
                           np.zeros(0, np.int64), np.zeros(2, np.int64), args[0],
                           DEPENDENT_SIGMA, SUPPORT_TOL)
    return time.perf_counter() - t0


def _workers(requested: int | None) -> int:
    if requested is not None:
        return max(1, int(requested))
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cpus = os.cpu_count() or 1
    return max(1, cpus)


def explore_active_sets(
    H: np.ndarray,
    c: np.ndarray,
    C: np.ndarray,
    G: np.ndarray,
    w: np.ndarray,
    S: np.ndarray,
    At: np.ndarray,
    bt: np.ndarray,
    theta0: np.ndarray,
    *,
    scale: float,
    region_tol: float,
    max_regions: int,
    theta_box: tuple[np.ndarray, np.ndarray] | None = None,
    workers: int | None = None,
    executor: Executor | None = None,
    semidefinite: bool = False,
    progress: Callable[[int], None] | None = None,
    stats: dict | None = None,
    sharded: bool = False,
    shard_dir: str | os.PathLike | None = None,
    finish: Callable | None = None,
) -> RegionArrays:
    """All full-dimensional critical regions of ``min 0.5 z'Hz + (c + C theta)'z s.t.
    G z <= w + S theta, At theta <= bt`` (H positive definite, rows of G unit norm).

    Parameters
    ----------
    H : (nz, nz) ndarray
        The Hessian (positive definite, or semi-definite with ``semidefinite``).
    c : (nz,) ndarray
    C : (nz, d) ndarray
        The linear cost ``(c + C theta)' z``.
    G : (m, nz) ndarray
        Constraint rows, unit norm.
    w : (m,) ndarray
    S : (m, d) ndarray
        The constraints ``G z <= w + S theta``.
    At : (p, d) ndarray
    bt : (p,) ndarray
        The parameter set ``At theta <= bt``.
    theta0 : (d,) ndarray
        A feasible parameter (the search starts from the optimal active set there).
    scale : float
        Size of the parameter set (tolerances are relative to it).
    region_tol : float
        A region counts as full-dimensional only with a proved inscribed ball larger than
        this (thinner ones are lower-dimensional: explored through, not kept).
    max_regions : int
        The search stops with ``SolverError`` once it finds more regions than this.
    theta_box : ((d,), (d,)) ndarrays, optional
        The parameter set's bounding box (lo, hi), if the caller has it already.
    workers : int, optional
        Threads of this process evaluating candidates with the compiled kernel once more
        than ``PARALLEL_AFTER`` regions are found (default: the CPUs this process may use;
        1 = serial), when no ``executor`` is given.
    executor : Executor, optional
        Evaluate candidates as tasks on this executor's workers instead (a Dask cluster;
        a serial one changes nothing): batches of the compiled walk, ``_GROUP`` batches a
        task, or chunks of the numpy kernel where the compiled one does not apply. The
        workers get the problem's arrays in memory, scattered once. The result is the same,
        bit for bit and in the same order, whatever runs the tasks and however many
        workers there are.
    semidefinite : bool
        H is only positive semi-definite (singular): the optimizer is selected
        lexicographically (see ``_KernelSemidefinite``); the caller has checked that the
        problem has no direction of recession.
    progress : callable, optional
        Called with the number of regions found so far, as they are found.
    stats : dict, optional
        Updated in place with the search's counters (``candidates``, ``lps``,
        ``explored``, ``candidates_<status>``, ``jit``, ``workers``, ``merged``, ...).
    sharded : bool
        With a Dask ``executor``, once the compiled kernel runs: the walk's state sharded
        across the workers, the regions kept there until the end (``sharded.py``); the
        regions are then sorted by active set whatever their number.
    shard_dir : path-like, optional
        With ``sharded``: the folder in which the search's shard files go (a fresh folder in
        it, removed at the end; every worker must reach it); default the system's
        temporary folder.
    finish : callable, optional
        With ``sharded``: ``finish(regions, j)``, run on the worker of each shard at the
        end with the shard's regions, merged (``sharded.sharded_walk``): then no region
        comes back here.

    Returns
    -------
    RegionArrays or list of tuple
        In the variables z; ``active`` holds the active set. Sorted by active set, but for
        more than ``SORTED_UP_TO`` regions found by the compiled walk, which stay in the
        order it found them (neither timing nor the worker count changes that order).
        With ``finish``, once the walk was sharded: each shard's ``(answer, merge stats,
        regions before the merge)``.

    Raises
    ------
    SolverError
        When more than ``max_regions`` regions are found.
    """
    stats = {} if stats is None else stats
    # (the cluster is started, or connected to, only when the search goes parallel)
    remote_ok = executor is not None and executor.kind != "serial"
    client = None
    box = theta_box if theta_box is not None else bounding_box(At, bt)
    if semidefinite:
        r = np.random.default_rng(0).normal(size=G.shape[1])
        kernel: _Kernel = _KernelSemidefinite(H, c, C, G, w, S, At, bt, scale, region_tol, box, r)
        act0 = _active_set_at(H + 1e-9 * np.eye(H.shape[0]), c + 1e-7 * r, C, G, w, S, theta0)
    else:
        kernel = _Kernel(H, c, C, G, w, S, At, bt, scale, region_tol, box)
        act0 = _active_set_at(H, c, C, G, w, S, theta0)
    nz, m = kernel.nz, kernel.m
    # rows that cannot be active together: exact opposites (a variable's two bounds)
    opposite = {}
    for i in range(m):
        j = np.flatnonzero(np.abs(G + G[i]).max(axis=1) <= 1e-12)
        opposite[i] = set(int(x) for x in j)

    regions: list[CriticalRegion] = []
    explored = {act0}
    stack = [act0]
    nworkers = _workers(workers)
    remote = None  # (the scattered kernel, the number of workers) once the tasks start
    jit_applies = kernel.box is not None and type(kernel) is _Kernel  # (see start_jit)
    jit_tried = False

    def visit(act, result) -> None:
        status, rows, law, moves, lp = result
        stats["candidates"] = stats.get("candidates", 0) + 1
        stats["lps"] = stats.get("lps", 0) + int(lp)
        _count_class(stats, status)
        if status == "empty":
            return
        if status == "full":
            regions.append(CriticalRegion(A=rows[0], b=rows[1], K=law[0], k=law[1], active=act))
            if progress is not None:
                progress(len(regions))
            if len(regions) > max_regions:
                raise TooManyRegionsError(too_many_regions(max_regions))
        if status == "licq":
            leave, enter = dependent_rows(kernel.G, act), []  # its subsets are the way on
        elif status == "singular":
            leave, enter = [], [i for i in range(m) if i not in act]  # its supersets
        else:
            # across the facets of a full-dimensional region, or the constraints tight
            # on a lower-dimensional one
            leave = [int(v) - 1 for v in moves if v > 0]
            enter = [int(-v) - 1 for v in moves if v < 0]
        for i in leave:
            new = tuple(x for x in act if x != i)
            if new not in explored:
                explored.add(new)
                stack.append(new)
        if status == "licq" or len(act) >= nz + 1:
            return
        blocked = set(act)
        for i in act:
            blocked |= opposite[i]
        for i in enter:
            if i in blocked:
                continue
            new = tuple(sorted(act + (i,)))
            if new not in explored:
                explored.add(new)
                stack.append(new)

    compiled = False
    walk = None
    inflight: deque = deque()  # (chunk, Future), oldest first
    try:
        while stack or inflight:
            if not jit_tried and len(regions) >= JIT_AFTER:
                jit_tried = True
                stats["jit"] = kernel.start_jit()
                if stats["jit"]:
                    compiled = True  # the compiled walk takes over (below)
                    break
            if (remote is None and remote_ok and len(regions) >= PARALLEL_AFTER
                    and (jit_tried or not jit_applies)):
                # the numpy kernel on the executor's workers: only once the compiled one is
                # known not to apply, so the switch to it never depends on timing
                client = executor.client
                shared = client.scatter(kernel, broadcast=True, hash=False)
                remote = (shared, max(1, executor.workers))
                stats["workers"] = remote[1]
            if remote is None:
                act = stack.pop()
                visit(act, kernel.evaluate(act))
                continue
            # the workers get chunks of the newest candidates (depth first, as in the
            # serial search); this process evaluates candidates too while they work, and
            # visits their results oldest first (the numpy kernel does not depend on the
            # order, and the regions are sorted below)
            while len(stack) > _CHUNK and len(inflight) < 2 * remote[1]:
                chunk = stack[-_CHUNK:]
                del stack[-_CHUNK:]
                future = client.submit(_evaluate_chunk, remote[0], chunk, pure=False)
                inflight.append((chunk, future))
            if inflight and (inflight[0][1].done() or not stack):
                chunk, future = inflight.popleft()
                stats["tasks"] = stats.get("tasks", 0) + 1
                for act, result in zip(chunk, future.result(), strict=True):
                    visit(act, result)
            elif stack:
                act = stack.pop()
                visit(act, kernel.evaluate(act))
        if compiled and sharded and remote_ok:
            from codev_engine.mp.sharded import sharded_walk

            compiled = False  # (its regions come back sorted: below, as the numpy walk's)
            regions = sharded_walk(kernel, opposite, explored, stack, regions, stats,
                                   executor, max_regions, progress, directory=shard_dir,
                                   walk_class=_CompiledWalk, warm=_warm_worker,
                                   finish=finish,
                                   merge=None if finish is None
                                   else functools.partial(_merge_shard, scale))
            if finish is not None:
                return regions  # (each shard's law written where it was made)
        elif compiled:
            walk = _CompiledWalk(kernel, opposite, explored, stack, regions, stats)
            walk.run(nworkers, max_regions, progress, executor if remote_ok else None)
    finally:
        if inflight:
            client.cancel([f for _, f in inflight])
        if remote is not None:
            client.cancel([remote[0]])
    if isinstance(regions, RegionArrays):  # (sharded: sorted, counted)
        packed = regions
    elif not compiled:
        stats["explored"] = len(explored)
    if compiled:
        # the compiled walk's order depends on neither timing nor the worker count; not
        # sorting it spares a second copy of every row (5M regions of pop_mpqp_095: 10 GB)
        packed = walk.result()
        walk = None  # (the walk's hash table and stack)
        if len(packed) <= SORTED_UP_TO:
            packed = packed.take(packed.active_order())
    elif not isinstance(regions, RegionArrays):
        regions.sort(key=lambda r: r.active)  # the same order however they were found
        packed = RegionArrays.from_regions(regions, nz, kernel.d)
    return _merge_equal_laws(packed, scale, stats)


class _CompiledWalk:
    """The rest of the search once the compiled kernel runs: the explored active sets and
    the stack as bitmasks (``active_sets``), candidates evaluated in batches by compiled
    code (in threads: it releases the GIL); only the regions found and the candidates the
    compiled kernel hands back come to Python."""

    def __init__(
        self,
        kernel: _Kernel,
        opposite: dict,
        explored: set,
        stack: list,
        regions: list[CriticalRegion],
        stats: dict,
    ):
        from codev_engine.mp import active_sets, mpqp_kernel

        self.kernel, self.regions, self.stats = kernel, regions, stats
        self.parts: list[RegionArrays] = []  # the latest batches' regions
        self.chunks: list[RegionArrays] = []  # the earlier ones, in larger arrays
        self.found = len(regions)  # regions in both
        self.shared: tuple[np.ndarray, np.ndarray] | None = None  # the kernel's At rows
        self.jit = mpqp_kernel
        self.evaluate_batch = mpqp_kernel.evaluate_batch
        self.codes = {name: code for code, name in mpqp_kernel.STATUS_NAMES.items()}
        m = kernel.m
        opp = np.zeros((m, m), dtype=bool)
        for i, js in opposite.items():
            opp[i, list(js)] = True
        self.graph = active_sets.ActiveSetGraph(
            m, kernel.nz, opp, kernel.box[0], kernel.G, DEPENDENT_SIGMA, SUPPORT_TOL
        )
        self.graph.seed(explored, stack)

    def run(self, nworkers: int, max_regions: int, progress, executor=None) -> None:
        """Walk until the stack is empty.

        The walk pops batches of ``_CHUNK`` candidates and takes their results (records
        the regions, pushes the neighbours) oldest first, ``_DEPTH`` batches in flight: the
        same sequence of pops and takes whatever evaluates the batches, so the same walk.
        They are evaluated in this thread when it takes them (serial), by a pool of
        ``nworkers`` threads (the compiled kernel releases the GIL), or, with a Dask
        ``executor`` (its client started once ``PARALLEL_AFTER`` regions are found), as
        tasks of ``_GROUP`` consecutive batches on its workers (a group is sent when full,
        or earlier when this thread is about to take its oldest batch).
        """
        graph, args = self.graph, self.kernel._jit_args
        pool = client = remote = None
        shared = None  # the kernel's arrays, scattered to the workers
        window: deque = deque()  # [keys, starts, job], oldest first
        group: list = []  # batches popped, not yet sent (with a client)
        tasks: set = set()  # futures not yet taken in full
        stats = self.stats

        def submit(batches: list):
            nonlocal shared
            shared = scattered(client, remote, shared)  # (again, if a lost worker took it)
            future = client.submit(_evaluate_batches, shared, batches, pure=False)
            tasks.add(future)
            return future

        def send() -> None:
            batches = [(e[0], e[1]) for e in group]
            box: dict = {"future": submit(batches), "left": len(group), "batches": batches}
            for i, entry in enumerate(group):
                entry[2] = (box, i)
            group.clear()

        def fetch(job) -> tuple:
            box, i = job
            if "out" not in box:
                tasks.discard(box["future"])
                (box["out"], seconds), box["future"] = result_resubmitting(
                    box["future"], lambda: submit(box["batches"]), stats
                )
                tasks.add(box["future"])
                stats["task_seconds"] = stats.get("task_seconds", 0.0) + seconds
                stats["tasks"] = stats.get("tasks", 0) + 1
            out = _batch_of(box["out"], i)
            box["left"] -= 1
            if not box["left"]:  # taken in full: the worker may drop it
                tasks.discard(box["future"])
                box.clear()
            return out

        try:
            while len(graph) or window:
                if self.found >= PARALLEL_AFTER and pool is None and shared is None:
                    if executor is not None:
                        t0 = time.perf_counter()
                        client = executor.client
                        # the parameter set's rows as the regions found so far hold them:
                        # the workers leave them out of the regions that end with them
                        # and the numpy kernel, for the candidates the compiled one hands
                        # back (without the compiled module, which does not pickle)
                        numpy_kernel = copy.copy(self.kernel)
                        numpy_kernel._jit = None
                        remote = (args, self.shared, numpy_kernel)
                        shared = scattered(client, remote)
                        # numba's cached kernel loaded on every worker before the first task
                        warm = client.run(_warm_worker, args)
                        stats["workers"] = len(warm)
                        stats["worker_warmup_seconds"] = max(warm.values(), default=0.0)
                        stats["start_seconds"] = time.perf_counter() - t0
                    elif nworkers > 1:
                        from multiprocessing.pool import ThreadPool

                        pool = ThreadPool(nworkers)
                        stats["workers"] = nworkers
                while len(graph) and len(window) < _DEPTH:
                    keys, starts = graph.pop(_CHUNK)
                    entry = [keys, starts, None]
                    window.append(entry)
                    if shared is not None:
                        group.append(entry)
                        if len(group) == _GROUP:
                            send()
                    elif pool is not None:
                        entry[2] = pool.apply_async(self.evaluate_batch, (keys, starts, args))
                entry = window.popleft()
                if any(e is entry for e in group):
                    send()  # (this batch is in the group not yet sent)
                keys, starts, job = entry
                if job is None:  # (popped before the workers started, or serial)
                    result = self.evaluate_batch(keys, starts, args)
                elif isinstance(job, tuple):
                    result = fetch(job)
                else:
                    result = job.get()
                self._take(keys, result)
                if progress is not None:
                    progress(self.found)
                if self.found > max_regions:
                    raise TooManyRegionsError(too_many_regions(max_regions))
        finally:
            stats["explored"] = graph.explored
            if pool is not None:
                pool.terminate()
                pool.join()
            if client is not None and (tasks or shared is not None):
                client.cancel([*tasks, *([shared] if shared is not None else [])])

    def _take(self, keys: np.ndarray, result: tuple) -> None:
        """Record a batch's regions and push its neighbours; the candidates the compiled
        kernel could not conclude on go to the numpy kernel, one by one."""
        (status, lp, acts, sizes, rows_off, A, b, K, k, moves, moves_off, swaps, swaps_off,
         points, *implied) = result  # (a worker's compacted result: _evaluate_batches)
        handed_back = implied[1] if len(implied) > 1 else None
        jit, stats = self.jit, self.stats
        stats["candidates"] = stats.get("candidates", 0) + status.size
        stats["lps"] = stats.get("lps", 0) + int(np.count_nonzero(lp))
        counts = np.bincount(status, minlength=jit.FALLBACK + 1)
        for code, name in jit.STATUS_NAMES.items():
            _count_class(stats, name, int(counts[code]))
        # the candidates handed back, through the numpy kernel (it does not depend on the
        # walk's state); their regions are kept in their place among the batch's
        back = np.flatnonzero(status == jit.FALLBACK)
        stats["handed_back"] = stats.get("handed_back", 0) + back.size
        results = [] if handed_back is None else handed_back
        if handed_back is not None and back.size:
            stats["handed_back_on_workers"] = stats.get("handed_back_on_workers", 0) + back.size
        for i, c in enumerate(back):
            if handed_back is None:  # (evaluated here)
                results.append(self.kernel.evaluate_numpy(tuple(acts[c, : sizes[c]].tolist())))
            stats["lps"] += int(results[i][4])
            _count_class(stats, results[i][0])
        full = np.flatnonzero(status == jit.FULL)
        if not implied:  # (evaluated here: the law of every candidate, the rows whole)
            K, k, implied = K[full], k[full], [None]
        mine = (self._pack(full, acts, sizes, rows_off, A, b, K, k, implied[0])
                if full.size else None)
        handed = [
            (int(c), CriticalRegion(A=rows[0], b=rows[1], K=law[0], k=law[1],
                                    active=tuple(acts[c, : sizes[c]].tolist())))
            for c, (st, rows, law, _, _) in zip(back, results, strict=True) if st == "full"
        ]
        if handed:
            theirs = RegionArrays.from_regions([reg for _, reg in handed])
            at = np.array([c for c, _ in handed])
            if mine is not None:
                theirs = RegionArrays.concat([mine, theirs])
                at = np.concatenate([full, at])
            mine = theirs.take(np.argsort(at, kind="stable"))
        if mine is not None:
            self._keep(mine)
        self.graph.visit(keys, status, moves, moves_off, swaps, swaps_off, points,
                         licq_moves=handed_back is not None)
        for c, (st, _, _, mv, _) in zip(back, results, strict=True):
            mv = np.zeros(0, dtype=np.int64) if mv is None else np.asarray(mv, dtype=np.int64)
            no_swaps = np.zeros((0, 2), dtype=np.int64)
            self.graph.visit(
                keys[c : c + 1], np.array([self.codes[st]]), mv, np.array([0, mv.size]),
                no_swaps, np.zeros(2, dtype=np.int64), points[c : c + 1],
            )

    def _pack(self, full, acts, sizes, rows_off, A, b, K, k, implied=None) -> RegionArrays:
        """The regions ``full`` of a batch as packed arrays (copies: a view would keep
        the whole batch alive), without the parameter set's rows, which the compiled kernel
        puts last in every region: they are held once (``RegionArrays.shared_A``).
        ``K``, ``k`` are the regions' (f, nz, d), (f, nz); ``implied`` given, a worker
        has left those rows out already (:func:`_compact`)."""
        r0, r1 = rows_off[full], rows_off[full + 1]
        p = self.kernel.At.shape[0]
        if implied is not None:
            rows, off = segment_indices(r0, r1 - r0)
            n = sizes[full]
            part = acts[full]
            active = part[np.arange(part.shape[1])[None, :] < n[:, None]]
            aoff = np.zeros(full.size + 1, dtype=np.int64)
            np.cumsum(n, out=aoff[1:])
            return RegionArrays(A[rows], b[rows], off, K, k, active, aoff, implied,
                                *self.shared)
        implied = np.zeros(full.size, dtype=bool)
        if p and self.shared is None:
            self.shared = (A[r1[0] - p : r1[0]].copy(), b[r1[0] - p : r1[0]].copy())
        if p:
            tail = r1[:, None] - p + np.arange(p)
            implied = (r1 - r0 >= p) & np.all(
                np.all(A[tail] == self.shared[0], axis=2) & (b[tail] == self.shared[1]), axis=1
            )
        rows, off = segment_indices(r0, r1 - r0 - p * implied)
        n = sizes[full]
        part = acts[full]
        active = part[np.arange(part.shape[1])[None, :] < n[:, None]]
        aoff = np.zeros(full.size + 1, dtype=np.int64)
        np.cumsum(n, out=aoff[1:])
        shared = self.shared or (None, None)
        return RegionArrays(A[rows], b[rows], off, K, k, active, aoff, implied, *shared)

    def _keep(self, part: RegionArrays) -> None:
        self.parts.append(part)
        self.found += len(part)
        if len(self.parts) >= _PARTS_PER_CHUNK:
            # (large arrays are given back to the system when freed; a million small ones
            # fragment the heap)
            self.chunks.append(RegionArrays.concat(self.parts))
            self.parts = []

    def result(self) -> RegionArrays:
        """Every region found, packed, in the order found (the walk's copies are freed as
        they are copied)."""
        parts = [RegionArrays.from_regions(self.regions, self.kernel.nz, self.kernel.d)]
        parts += self.chunks + self.parts
        self.regions, self.chunks, self.parts = [], [], []
        return RegionArrays.concat(parts, consume=True)


def _count_class(stats: dict, status: str, n: int = 1) -> None:
    """Count ``n`` candidates of class ``status`` ("full", "empty", "lower", "licq" or
    "singular") as ``stats["candidates_<status>"]`` (only once there is one)."""
    if n:
        key = f"candidates_{status}"
        stats[key] = stats.get(key, 0) + n


def _merge_shard(scale: float, regions: RegionArrays, stats: dict) -> RegionArrays:
    """``_merge_equal_laws`` on one shard (a worker of the sharded search)."""
    return _merge_equal_laws(regions, scale, stats)


def _merge_equal_laws(regions: RegionArrays, scale: float, stats: dict) -> RegionArrays:
    """One region per affine law where the union is provably convex.

    Where LICQ fails on a full-dimensional set (more constraints tight than independent),
    several active sets give the same law on overlapping regions (the multipliers are not
    unique). Regions with equal laws are merged pairwise while the union is convex
    (``merge.merge_regions``, an exact envelope test), which removes the overlaps. Regions
    whose law no other has stay as they are, in their place.
    """
    from codev_engine.mp.merge import merge_regions

    n = len(regions)
    if not n:
        return regions
    nz, d = regions.K.shape[1:]
    laws = np.concatenate([regions.K, regions.k[:, :, None]], axis=2).reshape(n, nz * (d + 1))
    laws *= 1.0 / (1e-7 * max(scale, 1.0))
    np.rint(laws, out=laws)  # (np.round took 30x as long on pop_mpqp_024)
    laws += 0.0  # (-0.0 made +0.0)
    h = row_hashes(laws)
    _, hinv, hcount = np.unique(h, return_inverse=True, return_counts=True)
    cand = np.flatnonzero(hcount[hinv.reshape(-1)] > 1)  # (a hash shared: maybe a law)
    if cand.size == 0:
        return regions
    _, cfirst, cinv, ccount = np.unique(
        laws[cand], axis=0, return_index=True, return_inverse=True, return_counts=True
    )
    cinv = cinv.reshape(-1)
    if np.all(ccount == 1):
        return regions
    # the groups with a shared law, in the order of their first region; each is merged on
    # its own (merge_regions keeps a group's order) and put where its first region was
    lone = np.ones(n, dtype=bool)
    pieces: dict[int, RegionArrays] = {}
    for g in np.flatnonzero(ccount > 1):
        idx = cand[cinv == g]  # ascending
        lone[idx] = False
        group = [regions[int(i)] for i in idx]
        As, bs, src = merge_regions([r.A for r in group], [r.b for r in group], [b""] * idx.size)
        pieces[int(idx[0])] = RegionArrays.from_regions(
            [replace(group[i], A=a, b=b) for a, b, i in zip(As, bs, src, strict=True)]
        )
    # the regions in order: runs of regions of their own law, and each group at its first
    parts: list[RegionArrays] = []
    start = 0
    for f in sorted(pieces):
        run = np.flatnonzero(lone[start:f]) + start
        parts += [regions.take(run), pieces[f]]
        start = f + 1
    parts.append(regions.take(np.flatnonzero(lone[start:]) + start))
    out = RegionArrays.concat(parts)
    stats["merged"] = n - len(out)
    return out


def _active_set_at(H, c, C, G, w, S, theta) -> tuple[int, ...]:
    m = G.shape[0]
    x, _, flag, info = daqp.solve(
        H,
        c + C @ theta,
        G,
        w + S @ theta,
        np.full(m, -1e30),
        np.zeros(m, dtype=np.int32),
        iter_limit=10_000,
        primal_tol=1e-11,
        dual_tol=1e-12,
    )
    if flag != 1:
        raise SolverError(f"could not solve the QP at the start parameter (DAQP flag {flag})")
    lam = np.asarray(info["lam"])
    return tuple(int(i) for i in np.flatnonzero(lam > 0))
