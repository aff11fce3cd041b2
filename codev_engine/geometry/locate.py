"""Point location in a polyhedral partition.

Two ways, one answer (see :meth:`PointLocator.locate` for the region a point gets):

- **brute force**: every region's rows against every point, as one matrix product over all
  rows (in chunks), then the largest violation per region. No set-up; the cost per point is
  the number of rows. Used for few points in a large partition (a conformance check
  locating a hundred points in 860,000 regions).
- **grid**: a uniform grid over the partition's bounding box lists, per cell, the regions
  whose bounding box meets the cell. A query finds its cell and tests that cell's
  candidates (a compiled loop, ``locate_kernel.walk``), so the work is proportional to the
  (small) number of candidates per cell. Its set-up (a bounding box per region, the cell
  lists) pays once many points are located. A region whose box spans too many cells (thin
  and oblique, in 5-8 dimensions) goes to a coarser grid instead (half as many cells per
  axis, as often as needed): every point is offered the candidates of its cell in each grid.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from codev_engine.geometry.polytope import solve_lp

__all__ = ["PointLocator", "bounding_boxes", "row_values"]


class _Grid(NamedTuple):
    """One grid of :class:`PointLocator`: ``g`` cells per axis of size ``cell`` (d,); the
    regions of the cell of index vector ``c`` (number ``sum(c[t] g^t)``) are
    ``cands[start[n]:start[n + 1]]``, ascending."""

    g: int
    cell: np.ndarray
    start: np.ndarray
    cands: np.ndarray


def bounding_boxes(
    As: list[np.ndarray],
    bs: list[np.ndarray],
    domain: tuple[np.ndarray, np.ndarray] | None = None,
    rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding boxes of bounded polytopes ``{x : As[i] x <= bs[i]}``.

    Each bound is an LP. From ``COMPILED_BOXES`` regions on, all of them are one compiled
    call (``lp_kernel.region_boxes``; its multipliers must reproduce the cost; loading the
    compiled code costs ~0.3 s once per process, too much for a few regions). A region it
    gives no bound for, and each region of fewer, is bounded by DAQP when DAQP's multipliers
    prove its optimum (dual feasible, no gap), else by HiGHS with tight tolerances. (On
    needles of radius 1e-7, with multipliers of 1e6, DAQP and HiGHS at their default
    tolerances stopped short of the true bound by up to 0.01: a box that did not contain
    its region.) The bounds are the LPs' vertices: the grid of ``PointLocator`` widens them
    by ``1e-9 (1 + |v|)`` against their rounding. A thin sliver may defeat every LP
    (reported infeasible or unbounded); its bound then comes, in this order, from

    1. the same LP on the region enlarged by ``1e-7 * (1 + |b|)`` on every row (which
       contains the region, so the bound stays sound),
    2. the bounding box of ``domain = (A, b)`` (the union of all regions), if given,
    3. the overall box of all finite bounds of all regions.

    The result is always finite (when there is at least one finite bound per axis): a
    point locator built on it must never see an infinite or NaN box.

    Parameters
    ----------
    As, bs : lists of (k_i, d) and (k_i,) ndarray
        The R regions.
    domain : (A, b), optional
        The union of all regions, ``A`` (k, d) and ``b`` (k,): its box fills a bound that
        no LP gives.
    rows : (A, b, offsets), optional
        All rows region after region, (N, d), (N,) and (R + 1,) int64, when the caller has
        them already (a second copy of 860k regions' rows is 2 GB).

    Returns
    -------
    lower, upper : (R, d) ndarray
    """
    R = len(As)
    d = As[0].shape[1] if R else 0
    if R >= COMPILED_BOXES:
        lo, hi, ok = _compiled_boxes(As, bs, d, rows)
    else:
        lo, hi, ok = np.full((R, d), np.nan), np.full((R, d), np.nan), np.zeros(R, dtype=bool)
    for i in np.flatnonzero(~ok):
        lo[i], hi[i] = _box(As[i], bs[i], d)
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


def _stack(
    As: list[np.ndarray], bs: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every row, region after region: A (N, d), b (N,) and the offsets (R + 1,) (at
    least one region)."""
    off = np.zeros(len(As) + 1, dtype=np.int64)
    np.cumsum([a.shape[0] for a in As], out=off[1:])
    A = np.ascontiguousarray(np.vstack(As), dtype=float)
    b = np.ascontiguousarray(np.concatenate(bs), dtype=float)
    return A, b, off


def _compiled_boxes(
    As: list[np.ndarray],
    bs: list[np.ndarray],
    d: int,
    rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``lp_kernel.region_boxes`` on the regions (``rows``: their ``_stack``, if at hand):
    lower, upper (R, d) and ok (R,)."""
    from codev_engine.geometry import lp_kernel

    if len(As) == 0:
        return np.zeros((0, d)), np.zeros((0, d)), np.zeros(0, dtype=bool)
    A, b, off = rows if rows is not None else _stack(As, bs)
    return lp_kernel.region_boxes(A, b, off, 50 * (int(np.diff(off).max()) + d + 1))


#: From this many regions on, bounding boxes come from one compiled call
COMPILED_BOXES = 64
#: Regions per call of ``bounding_boxes`` when their rows must be put together first
_BOX_CHUNK = 1 << 16
#: HiGHS tolerances for a bound (its defaults, 1e-7, stop short on needle regions)
_TIGHT = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


def _box(A: np.ndarray, b: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of ``{x : A x <= b}``; NaN where no LP gave a finite optimum."""
    lo = np.full(d, np.nan)
    hi = np.full(d, np.nan)
    eye = np.eye(d)
    relaxed = b + 1e-7 * (1.0 + np.abs(b))
    for j in range(d):
        for sign, out in ((1.0, lo), (-1.0, hi)):
            f = sign * eye[j]
            x, st, lam = solve_lp(f, A, b)
            if st != "optimal" or not _proved(f, A, b, x, lam):
                x = _highs(f, A, b, _TIGHT)
            if x is None:
                x = _highs(f, A, relaxed)
            if x is not None:
                out[j] = x[j]
    return lo, hi


def _proved(
    f: np.ndarray, A: np.ndarray, b: np.ndarray, x: np.ndarray | None, lam: np.ndarray | None
) -> bool:
    """Whether DAQP's ``x`` minimises ``f'x`` over ``A x <= b``, by its multipliers: ``lam
    >= 0`` with ``f + A' lam = 0`` and no gap between ``f'x`` and the dual bound ``-b' lam``
    (to 1e-9)."""
    if x is None or lam is None or not np.all(np.isfinite(x)):
        return False
    y = np.asarray(lam, dtype=float)[: A.shape[0]]
    if not np.all(np.isfinite(y)) or np.any(y < -1e-9):
        return False
    y = np.maximum(y, 0.0)
    value = float(f @ x)
    return bool(
        np.sum(np.abs(f + A.T @ y)) <= 1e-9 and abs(value + b @ y) <= 1e-9 * (1.0 + abs(value))
    )


def linprog(*args, **kwargs):
    """``scipy.optimize.linprog``, imported on the first call (~0.4 s of imports, which a
    run that only loads cached laws never pays).

    Parameters
    ----------
    *args, **kwargs
        As for ``scipy.optimize.linprog``.

    Returns
    -------
    scipy.optimize.OptimizeResult
    """
    from scipy.optimize import linprog as scipy_linprog

    return scipy_linprog(*args, **kwargs)


def _highs(
    f: np.ndarray, A: np.ndarray, b: np.ndarray, options: dict | None = None
) -> np.ndarray | None:
    """``argmin f'x s.t. A x <= b`` by HiGHS; None unless optimal (and finite)."""
    try:
        res = linprog(
            f, A_ub=A, b_ub=b, bounds=(None, None), method="highs", options=options or {}
        )
    except ValueError:  # non-finite input
        return None
    if res.status != 0 or res.x is None or not np.all(np.isfinite(res.x)):
        return None
    return np.asarray(res.x, dtype=float)


#: A region whose bounding box covers more grid cells than this goes to a coarser grid
#: instead of being entered in every cell (see PointLocator)
WIDE_CELLS = 4096
#: The grid is built (when no boxes are given) once this many points have been located:
#: its set-up costs about as much as brute force on ~3000 points, whatever the number of
#: regions (on pop_mpqp_024's 430k regions in 6-D: boxes 41 s and cell lists 17 s, against
#: 18 ms per point; then 0.1 ms per point)
GRID_POINTS = 2000
#: With fewer regions than this, no grid unless asked for: brute force costs a few rows per
#: point, and loading the grid's compiled code ~0.25 s once per process
GRID_REGIONS = 64
#: Entries (rows x points) of one brute-force chunk: 2 MB of doubles, which stay in cache
#: for the maximum per region (4x faster than 256 MB chunks: 21 vs 80 ms per point on 430k
#: regions of 24 rows in 6-D)
_CHUNK = 1 << 18


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
        Precomputed bounding boxes (R, d) each (computed when the grid needs them).
    grid : bool, optional
        True: build the grid now; False: never (brute force only). By default, from
        ``GRID_REGIONS`` regions on, it is built at once when ``boxes`` are given, else once
        ``GRID_POINTS`` points have been located (brute force until then); with fewer
        regions, never. The answers are the same either way, but for
        a point on a facet two regions share, which rounding may give to either.
    """

    def __init__(
        self,
        As: list[np.ndarray],
        bs: list[np.ndarray],
        tol: float = 1e-9,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
        grid: bool | None = None,
    ):
        rows = _stack(As, bs) if len(As) else (np.zeros((0, 0)), np.zeros(0), np.zeros(1, int))
        self._setup(*rows, None, None, tol, boxes, grid)

    @classmethod
    def packed(
        cls,
        A: np.ndarray,
        b: np.ndarray,
        offsets: np.ndarray,
        shared: tuple[np.ndarray, np.ndarray] | None = None,
        implied: np.ndarray | None = None,
        tol: float = 1e-9,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
        grid: bool | None = None,
    ) -> PointLocator:
        """A locator on regions packed as in ``mp.solution.RegionArrays``: region ``i`` is
        ``A[offsets[i]:offsets[i + 1]]`` and, where ``implied[i]``, the ``shared`` rows.

        Parameters
        ----------
        A : (N, d) ndarray
            Every region's own rows, region after region.
        b : (N,) ndarray
        offsets : (R + 1,) ndarray of int
            Region ``i``'s rows are ``offsets[i]:offsets[i + 1]``.
        shared : (SA, Sb), optional
            Rows (s, d) and (s,) held once and implied in every region marked in
            ``implied``.
        implied : (R,) ndarray of bool, optional
            Which regions include the ``shared`` rows.
        tol : float
            As for the constructor.
        boxes : (lower, upper), optional
            As for the constructor.
        grid : bool, optional
            As for the constructor.

        Returns
        -------
        PointLocator
        """
        self = cls.__new__(cls)
        if implied is None or shared is None or not np.any(implied):
            shared = implied = None
        self._setup(
            np.ascontiguousarray(A, dtype=float), np.ascontiguousarray(b, dtype=float),
            np.asarray(offsets, dtype=np.int64), shared, implied, tol, boxes, grid,
        )
        return self

    def _setup(self, A, b, off, shared, implied, tol, boxes, grid) -> None:
        self.num_regions = off.size - 1
        self.tol = tol
        self._grid = False
        self._located = 0
        self._boxes = boxes
        # below GRID_REGIONS regions brute force is as fast, and the grid's compiled code
        # would cost more to load than it saves
        self._auto = grid is None and off.size - 1 >= GRID_REGIONS
        # shared rows: held once; a point's largest violation of them is computed once
        self._shared = shared
        self._implied = implied
        if self.num_regions == 0:
            return
        self.d = A.shape[1]
        # every row, region after region (brute force, the wide regions, the boxes)
        self.rows_A, self.rows_b, self.off = A, b, off
        if grid or (self._auto and boxes is not None):
            self._build_grid()

    def _region(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Region ``i``'s rows, the shared ones included."""
        r0, r1 = self.off[i], self.off[i + 1]
        if self._implied is None or not self._implied[i]:
            return self.rows_A[r0:r1], self.rows_b[r0:r1]
        SA, Sb = self._shared
        return np.vstack([self.rows_A[r0:r1], SA]), np.concatenate([self.rows_b[r0:r1], Sb])

    def _shared_violation(self, X: np.ndarray) -> np.ndarray | None:
        """Per point of ``X`` (P, d), the largest violation of the shared rows (None
        without shared rows)."""
        if self._implied is None:
            return None
        SA, Sb = self._shared
        if Sb.size == 0:
            return np.full(X.shape[0], -np.inf)
        return row_values(SA, Sb, X).max(axis=0)

    @property
    def box_lo(self) -> np.ndarray:
        """Lower corners of the regions' bounding boxes (R, d), as the grid uses them."""
        self._clip_boxes()
        return self._box_lo

    @property
    def box_hi(self) -> np.ndarray:
        """Upper corners of the regions' bounding boxes (R, d), as the grid uses them."""
        self._clip_boxes()
        return self._box_hi

    def _clip_boxes(self) -> None:
        """The boxes (given, or computed now), made finite."""
        if hasattr(self, "_box_lo"):
            return
        R, d = self.num_regions, self.d
        boxes = self._boxes
        if boxes is None and self._implied is None:
            rows = (self.rows_A, self.rows_b, self.off)
            As = [self.rows_A[self.off[i] : self.off[i + 1]] for i in range(R)]
            bs = [self.rows_b[self.off[i] : self.off[i + 1]] for i in range(R)]
            boxes = bounding_boxes(As, bs, rows=rows)
        elif boxes is None:
            # with the shared rows, a chunk of regions at a time (not a second copy of all)
            los, his = [], []
            for c0 in range(0, R, _BOX_CHUNK):
                regs = [self._region(i) for i in range(c0, min(R, c0 + _BOX_CHUNK))]
                lo_c, hi_c = bounding_boxes([r[0] for r in regs], [r[1] for r in regs])
                los.append(lo_c)
                his.append(hi_c)
            boxes = np.concatenate(los), np.concatenate(his)
        lo, hi = boxes
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
        self._box_lo, self._box_hi = lo, hi
        self.lo, self.hi = flo, fhi

    def _build_grid(self) -> None:
        if self._grid or self.num_regions == 0:
            return
        self._grid = True
        self._clip_boxes()
        R, d = self.num_regions, self.d
        lo, hi = self._box_lo, self._box_hi
        span = np.maximum(self.hi - self.lo, 1e-12)
        # about 16 cells per region overall, at most 256 per axis
        g = int(np.clip(np.ceil((16 * R) ** (1.0 / d)), 1, 256))
        self.g = g
        # (the boxes widened against the rounding of the LPs' vertices)
        wlo = lo - 1e-9 * (1.0 + np.abs(lo))
        whi = hi + 1e-9 * (1.0 + np.abs(hi))
        # a region whose box spans very many cells (thin and oblique, in 7-8 dimensions)
        # would cost millions of cell entries (pop_mpqp_0xx solutions spent over 15 minutes
        # and 3.7 GB building a single grid): it goes to a coarser grid, halved until the
        # region spans at most WIDE_CELLS cells (the coarsest grid, one cell, takes any).
        # Testing such regions against every point instead took 97% of locating 50,000
        # points in pop_mpqp_088's 62,304 regions (4,627 of them wide; 15.6 s).
        level = np.full(R, -1, dtype=np.int64)
        self.levels = []
        gl = g
        while np.any(level < 0):
            cell = span / gl
            clo = np.clip(np.floor((wlo - self.lo) / cell - 1e-9), 0, gl - 1).astype(np.int64)
            chi = np.clip(np.floor((whi - self.lo) / cell + 1e-9), 0, gl - 1).astype(np.int64)
            ncells = np.prod((chi - clo + 1).astype(float), axis=1)
            mine = (level < 0) & ((ncells <= WIDE_CELLS) | (gl == 1))
            level[mine] = len(self.levels)
            self.levels.append(self._cell_lists(np.flatnonzero(mine), gl, cell, clo, chi))
            gl = (gl + 1) // 2 if gl > 1 else 1
        self.wide = np.flatnonzero(level > 0)
        self.cell = self.levels[0].cell
        # what every walk passes to the compiled loop, made once
        self._origin = np.ascontiguousarray(self.lo, dtype=float)
        self._implied_mask = (
            self._implied if self._implied is not None else np.zeros(R, dtype=bool)
        )
        # the rows of the loose regions, for brute force
        self._loose_rows = self._subset_rows(self.loose)

    def _cell_lists(
        self, regs: np.ndarray, g: int, cell: np.ndarray, clo: np.ndarray, chi: np.ndarray
    ) -> _Grid:
        """The grid of ``g`` cells per axis listing the regions ``regs`` (ascending) in the
        cells ``clo[i] .. chi[i]`` (R, d) of their boxes that none of their rows separates
        from them."""
        from codev_engine.geometry.locate_kernel import cell_lists

        start, cands = cell_lists(
            self.rows_A, self.rows_b, self.off, regs.astype(np.int64), clo, chi,
            np.ascontiguousarray(self.lo, dtype=float), np.ascontiguousarray(cell, dtype=float),
            float(self.tol), g,
        )
        return _Grid(g, cell, start, cands)

    def _subset_rows(self, regions: np.ndarray) -> tuple[np.ndarray, ...]:
        """Rows, row offsets and indices of ``regions`` (ascending), for :meth:`_brute`."""
        idx = [np.arange(self.off[i], self.off[i + 1]) for i in regions]
        rows = np.concatenate(idx) if idx else np.zeros(0, dtype=np.int64)
        off = np.zeros(regions.size + 1, dtype=np.int64)
        np.cumsum(np.diff(self.off)[regions], out=off[1:])
        return self.rows_A[rows], self.rows_b[rows], off, regions

    def locate(self, X: np.ndarray) -> np.ndarray:
        """The region of each point: the index of a region per row of ``X``.

        A point inside regions (every row holds as computed) gets the lowest of them; a
        point inside none but within ``tol`` of some gets the one whose rows it violates
        least (the lowest index on ties). A region that a point is only near is never
        preferred to one that holds it: a sliver's law extrapolated 4e-10 past its facet was
        6e-6 (relative) off the optimum on ``pop_mpqp_002``, whose gains reach 1e7.

        Parameters
        ----------
        X : (P, d) or (d,) ndarray
            The points, one a row; a point with a non-finite coordinate is in no region.

        Returns
        -------
        (P,) ndarray of int
            The region index, -1 outside every region.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        P = X.shape[0]
        out = np.full(P, -1, dtype=int)
        if self.num_regions == 0:
            return out
        # the largest violation of the located region's rows: <= 0 inside, <= tol near
        best = np.full(P, np.inf)
        finite = np.all(np.isfinite(X), axis=1)
        sv = self._shared_violation(X)
        self._located += P
        if self._auto and not self._grid and self._located > GRID_POINTS:
            self._build_grid()
        if not self._grid:
            every = (self.rows_A, self.rows_b, self.off, np.arange(self.num_regions))
            self._brute(every, np.flatnonzero(finite), X, out, best, sv)
            return out
        inbox = finite & np.all((X >= self.lo - self.tol) & (X <= self.hi + self.tol), axis=1)
        if self.loose.size:
            # outside the grid only the regions without a proper box can hold a point
            self._brute(self._loose_rows, np.flatnonzero(finite & ~inbox), X, out, best, sv)
        pts = np.flatnonzero(inbox)
        Xc = np.ascontiguousarray(X)
        shared = sv if sv is not None else np.zeros(P)
        for grid in self.levels:
            self._walk(grid, pts, Xc, out, best, shared)
        return out

    def _walk(
        self,
        grid: _Grid,
        pts: np.ndarray,
        X: np.ndarray,
        out: np.ndarray,
        best: np.ndarray,
        sv: np.ndarray,
    ) -> None:
        """Offer the points ``pts`` of ``X`` (C-contiguous) the regions listed in their
        cells of ``grid``, merged into ``out`` / ``best`` as in :meth:`_brute` (``sv``: the
        points' violations of the shared rows, zeros without them). A compiled loop over the
        points: ~300 candidates a point in the coarser grid of ``pop_mpqp_024``'s thin
        regions."""
        from codev_engine.geometry.locate_kernel import walk

        walk(
            X, pts, self._origin, grid.cell, grid.g, grid.start, grid.cands, self.rows_A,
            self.rows_b, self.off, self._implied_mask, sv, float(self.tol), out, best,
        )

    def _brute(
        self,
        rows: tuple[np.ndarray, ...],
        sel: np.ndarray,
        X: np.ndarray,
        out: np.ndarray,
        best: np.ndarray,
        sv: np.ndarray | None = None,
    ) -> None:
        """Offer the regions of ``rows`` (from :meth:`_subset_rows`) to the points ``sel``:
        merged into ``out`` / ``best`` by the rule of :meth:`locate` (``sv``: the points'
        violations of the shared rows, from :meth:`_shared_violation`).

        The rows times the points is one matrix product per chunk of regions; the largest
        violation per region is a ``maximum.reduceat`` over its rows.
        """
        A, b, off, regions = rows
        if sel.size == 0 or regions.size == 0:
            return
        Xs = X[sel]
        step = max(1, _CHUNK // sel.size)
        i = 0
        while i < regions.size:
            # whole regions, about ``step`` rows
            j = int(np.searchsorted(off, off[i] + step, side="right")) - 1
            j = min(max(j, i + 1), regions.size)
            V = row_values(A[off[i] : off[j]], b[off[i] : off[j]], Xs)
            lens = np.diff(off[i : j + 1])
            M = np.full((j - i, sel.size), -1.0)  # (regions, points); no rows: all space
            has = lens > 0
            if np.any(has):
                M[has] = np.maximum.reduceat(V, (off[i:j] - off[i])[has], axis=0)
            if sv is not None:
                imp = self._implied[regions[i:j]]
                M[imp] = np.maximum(M[imp], sv[None, sel])
            held = M <= 0.0
            h = np.argmax(held, axis=0)  # the lowest region holding the point, if any
            n = np.argmin(M, axis=0)  # the nearest (the lowest on ties)
            cols = np.arange(sel.size)
            idx = np.where(held[h, cols], h, n)
            _merge(out, best, sel, regions[i + idx], M[idx, cols], self.tol)
            i = j


def row_values(A: np.ndarray, b: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``A x - b`` for every row and point, summed as ``-b_j + A_j0 x_0 + A_j1 x_1 + ...``.

    The order of the compiled walk (``locate_kernel.walk``) and of the exported code
    (``codev_engine.deploy``), each product rounded on its own (no fused multiply-add): a
    point on a shared facet gets the same region from brute force, the grid and the
    exported C (a matrix product sums in another order and put such points on the other
    side of a tie).

    Parameters
    ----------
    A : (r, d) ndarray
    b : (r,) ndarray
    X : (P, d) ndarray

    Returns
    -------
    (r, P) ndarray
    """
    V = -b[:, None] + A[:, :1] * X[None, :, 0]
    for t in range(1, A.shape[1]):
        V += A[:, t : t + 1] * X[None, :, t]
    return V


def _merge(
    out: np.ndarray,
    best: np.ndarray,
    sel: np.ndarray,
    reg: np.ndarray,
    viol: np.ndarray,
    tol: float,
) -> None:
    """Take region ``reg`` (violation ``viol``) for the points ``sel`` where it beats the
    region found so far: held beats near, then the lower index among held, the smaller
    violation among near (the lower index on ties); near means within ``tol``."""
    cur, now = best[sel], out[sel]
    held = viol <= 0.0
    take = (held & ((cur > 0.0) | (reg < now))) | (
        ~held
        & (viol <= tol)
        & (cur > 0.0)
        & ((viol < cur) | ((viol == cur) & (reg < now)))
    )
    out[sel[take]] = reg[take]
    best[sel[take]] = viol[take]
