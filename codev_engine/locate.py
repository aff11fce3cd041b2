"""Vectorised point location in a polyhedral partition.

A uniform grid over the partition's bounding box lists, per cell, the regions whose
bounding box meets the cell. A query finds its cell and tests the candidates of that cell
in rounds: round r tests every still-unlocated point against its r-th candidate at once,
so the work is numpy-vectorised over points and proportional to the (small) number of
candidates per cell rather than to the number of regions.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from .polytope import solve_lp

__all__ = ["PointLocator", "bounding_boxes"]


def bounding_boxes(
    As: list[np.ndarray],
    bs: list[np.ndarray],
    domain: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding boxes of bounded polytopes -> lower (R, d), upper (R, d).

    Each bound is an LP (DAQP, then HiGHS when DAQP gives no optimum). A thin sliver region
    may defeat both (reported infeasible or unbounded); its bound then comes, in this
    order, from

    1. the same LP on the region enlarged by ``1e-7 * (1 + |b|)`` on every row (which
       contains the region, so the bound stays sound),
    2. the bounding box of ``domain = (A, b)`` (the union of all regions), if given,
    3. the overall box of all finite bounds of all regions.

    The result is always finite (when there is at least one finite bound per axis): a
    point locator built on it must never see an infinite or NaN box.
    """
    R = len(As)
    d = As[0].shape[1] if R else 0
    lo = np.full((R, d), np.nan)
    hi = np.full((R, d), np.nan)
    for i, (A, b) in enumerate(zip(As, bs, strict=True)):
        lo[i], hi[i] = _box(A, b, d)
    failed = ~(np.isfinite(lo) & np.isfinite(hi))
    if not np.any(failed):
        return lo, hi
    dlo = dhi = None
    if domain is not None and domain[0] is not None and domain[0].shape[1] == d:
        dlo, dhi = _box(np.asarray(domain[0], float), np.asarray(domain[1], float), d)
    flo, fhi = _finite_hull(lo, hi)
    for box, overall, pick in ((lo, flo, np.minimum), (hi, fhi, np.maximum)):
        for j in range(d):
            bad = ~np.isfinite(box[:, j])
            if not np.any(bad):
                continue
            fill = overall[j]
            if domain is not None and dlo is not None:
                dom = (dlo if box is lo else dhi)[j]
                if np.isfinite(dom):
                    # the domain contains every region; keep the overall box too, in case
                    # the domain is only approximately their union
                    fill = pick(dom, fill) if np.isfinite(fill) else dom
            box[bad, j] = fill
    return lo, hi


def _finite_hull(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the smallest interval holding every finite number of ``lo`` and ``hi``.

    ``(inf, -inf)`` on an axis without a finite number.
    """
    both = np.vstack([lo, hi])
    fin = np.isfinite(both)
    return (
        np.where(fin, both, np.inf).min(axis=0, initial=np.inf),
        np.where(fin, both, -np.inf).max(axis=0, initial=-np.inf),
    )


def _box(A: np.ndarray, b: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of ``{x : A x <= b}``; NaN where no LP gave a finite optimum."""
    lo = np.full(d, np.nan)
    hi = np.full(d, np.nan)
    eye = np.eye(d)
    relaxed = b + 1e-7 * (1.0 + np.abs(b))
    for j in range(d):
        for sign, out in ((1.0, lo), (-1.0, hi)):
            f = sign * eye[j]
            x, st, _ = solve_lp(f, A, b)
            if st != "optimal" or x is None or not np.isfinite(x[j]):
                x = _highs(f, A, b)
            if x is None:
                x = _highs(f, A, relaxed)
            if x is not None:
                out[j] = x[j]
    return lo, hi


def _highs(f: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """``argmin f'x s.t. A x <= b`` by HiGHS; None unless optimal (and finite)."""
    try:
        res = linprog(f, A_ub=A, b_ub=b, bounds=(None, None), method="highs")
    except ValueError:  # non-finite input
        return None
    if res.status != 0 or res.x is None or not np.all(np.isfinite(res.x)):
        return None
    return np.asarray(res.x, dtype=float)


#: A region whose bounding box covers more grid cells than this is tested point by point
#: instead of being entered in every cell (see PointLocator)
WIDE_CELLS = 4096


class PointLocator:
    """Locate points in the regions ``{x : A_i x <= b_i}``.

    Parameters
    ----------
    As, bs : lists of (k_i, d) and (k_i,) arrays
        The regions (bounded).
    tol : float
        A point within ``tol`` of a region (row-wise, unit-norm rows) counts as near it:
        see :meth:`locate` for the region a point gets.
    boxes : (lower, upper), optional
        Precomputed bounding boxes (R, d) each.
    """

    def __init__(
        self,
        As: list[np.ndarray],
        bs: list[np.ndarray],
        tol: float = 1e-9,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.num_regions = len(As)
        self.tol = tol
        self.loose = np.zeros(0, dtype=int)
        if self.num_regions == 0:
            return
        self.d = As[0].shape[1]
        kmax = max(a.shape[0] for a in As)
        R, d = self.num_regions, self.d
        self.Apad = np.zeros((R, kmax, d))
        self.bpad = np.ones((R, kmax))
        for i, (A, b) in enumerate(zip(As, bs, strict=True)):
            self.Apad[i, : A.shape[0]] = A
            self.bpad[i, : A.shape[0]] = b
        lo, hi = boxes if boxes is not None else bounding_boxes(As, bs)
        lo = np.array(lo, dtype=float).reshape(R, d)
        hi = np.array(hi, dtype=float).reshape(R, d)
        # A box that is not finite (an LP failed when it was computed, or it came so from
        # a file) or is reversed does not bound its region: clip it to the finite hull of
        # all boxes, so that the grid stays finite, and test the region by brute force
        # at points outside that hull.
        flo, fhi = _finite_hull(lo, hi)
        none = ~(flo <= fhi)
        flo[none], fhi[none] = -1.0, 1.0
        loose = ~np.all(np.isfinite(lo) & np.isfinite(hi) & (lo <= hi), axis=1)
        lo = np.where(np.isfinite(lo) & ~loose[:, None], lo, flo)
        hi = np.where(np.isfinite(hi) & ~loose[:, None], hi, fhi)
        self.loose = np.flatnonzero(loose)
        self.box_lo, self.box_hi = lo, hi
        self.lo, self.hi = flo, fhi
        span = np.maximum(self.hi - self.lo, 1e-12)
        # about 16 cells per region overall, at most 256 per axis
        g = int(np.clip(np.ceil((16 * R) ** (1.0 / d)), 1, 256))
        self.g = g
        self.cell = span / g
        half = 0.5 * self.cell
        clo = np.clip(np.floor((lo - self.lo) / self.cell - 1e-9), 0, g - 1).astype(int)
        chi = np.clip(np.floor((hi - self.lo) / self.cell + 1e-9), 0, g - 1).astype(int)
        lists: list[list[int]] = [[] for _ in range(g**d)]
        strides = g ** np.arange(d)
        # a region whose box spans very many cells (thin and oblique, in 7-8 dimensions)
        # would cost millions of cell entries: such "wide" regions are tested directly
        # (pop_mpqp_0xx solutions spent over 15 minutes and 3.7 GB building the grid)
        ncells = np.prod((chi - clo + 1).astype(float), axis=1)
        self.wide = np.flatnonzero(ncells > WIDE_CELLS)
        skip = np.zeros(R, dtype=bool)
        skip[self.wide] = True
        for i in range(R):
            if skip[i]:
                continue
            ranges = [np.arange(clo[i, j], chi[i, j] + 1) for j in range(d)]
            mesh = np.stack(np.meshgrid(*ranges, indexing="ij"), axis=-1).reshape(-1, d)
            # drop cells that one of the region's rows separates from it entirely
            centres = self.lo + (mesh + 0.5) * self.cell
            A, b = As[i], bs[i]
            lowest = centres @ A.T - np.abs(A) @ half
            meets = np.all(lowest <= b + tol, axis=1)
            for c in mesh[meets] @ strides:
                lists[int(c)].append(i)
        counts = np.array([len(x) for x in lists])
        self.start = np.concatenate([[0], np.cumsum(counts)])
        self.cands = np.array([r for x in lists for r in x], dtype=int)
        self.strides = strides

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index per row of ``X`` (P, d) -> (P,) int, -1 outside every region.

        A point inside regions (every row holds as computed) gets the lowest of them; a
        point inside none but within ``tol`` of some gets the one whose rows it violates
        least (the lowest index on ties). A region that a point is only near is never
        preferred to one that holds it: a sliver's law extrapolated 4e-10 past its facet was
        6e-6 (relative) off the optimum on ``pop_mpqp_002``, whose gains reach 1e7.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        P = X.shape[0]
        out = np.full(P, -1, dtype=int)
        if self.num_regions == 0:
            return out
        # the largest violation of the located region's rows: <= 0 inside, <= tol near
        best = np.full(P, np.inf)
        finite = np.all(np.isfinite(X), axis=1)
        inbox = finite & np.all((X >= self.lo - self.tol) & (X <= self.hi + self.tol), axis=1)
        if self.loose.size:
            # outside the grid only the regions without a proper box can hold a point
            rest = np.flatnonzero(finite & ~inbox)
            for i in self.loose:
                if rest.size == 0:
                    break
                self._offer(i, rest, X, out, best)
                rest = rest[best[rest] > 0.0]
        pts = np.flatnonzero(inbox)
        cidx = np.clip(np.floor((X[pts] - self.lo) / self.cell), 0, self.g - 1).astype(int)
        cell = cidx @ self.strides
        first = self.start[cell]
        count = self.start[cell + 1] - first
        r = 0
        alive = count > 0
        while np.any(alive):
            sel = np.flatnonzero(alive)
            reg = self.cands[first[sel] + r]
            p = pts[sel]
            viol = (np.einsum("pkd,pd->pk", self.Apad[reg], X[p]) - self.bpad[reg]).max(axis=1)
            # a cell lists its regions in increasing order: the first that holds a point
            # is the lowest, and a later one only near it never beats an earlier one
            take = (viol <= self.tol) & (viol < best[p])
            out[p[take]] = reg[take]
            best[p[take]] = viol[take]
            alive[sel[viol <= 0.0]] = False
            r += 1
            alive &= count > r
        for i in self.wide:
            # only points not held by a lower region
            self._offer(i, pts[(best[pts] > 0.0) | (out[pts] > i)], X, out, best)
        return out

    def _offer(self, i: int, sel: np.ndarray, X: np.ndarray, out: np.ndarray, best: np.ndarray):
        """Region ``i`` for the points ``sel`` (none held by a lower region than ``i``):
        taken where it holds a point that no lower region holds, or is nearer than the
        region found so far."""
        if sel.size == 0:
            return
        viol = (X[sel] @ self.Apad[i].T - self.bpad[i]).max(axis=1)
        cur = best[sel]
        take = (viol <= 0.0) | (
            (viol <= self.tol) & ((viol < cur) | ((viol == cur) & (out[sel] > i)))
        )
        out[sel[take]] = i
        best[sel[take]] = viol[take]
