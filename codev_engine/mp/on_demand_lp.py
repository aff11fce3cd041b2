"""The critical regions of an mp-LP (norm 1 or inf) that meet a given set, computed when
asked for.

:class:`OnDemandBases` is :class:`~codev_engine.mp.on_demand.OnDemandRegions` for the
mp-LPs of the basis graph (``mplp_graph.explore_bases``): the same search object
(``mplp_graph._Search``: the lexicographic selection, the dual simplex across a facet, the
numpy and the compiled region), walked only through the regions that meet the set asked
about:

- it starts from the lexicographically optimal basis at a point of the set (the program
  solved there and settled, as the full search's start);
- from a region that meets the set (relaxed by ``MEET_TOL``) it crosses the facets whose
  hyperplane meets the set's bounding box, exactly as the full search crosses them (the
  same facet centre, the same settling, the same region of the neighbour's basis).

Why nothing is missed: the doubly perturbed LP makes the regions a facet-to-facet
partition of the feasible set with one basis per region; two regions meeting the (convex)
set are joined by a segment inside it, and the regions along the segment meet the set and
are crossed from one to the next through facets at points of the set.

Same regions as the full law: a region is a function of its basis (rows, law and the rows
kept by the certified redundancy test), computed by the numpy code for the regions the full
search computes with it (its first ``mplp_graph.JIT_AFTER`` regions, found here by replaying
its start) and by the compiled kernel for every other one, as the full search does. The
compiled region's Chebyshev LP starts from the facet centre it was reached by; the rows kept
are those the certified test proves non-redundant, whichever centre it starts from.

Where the full search cannot be made exact it falls back to the geometric explorer, whose
regions differ; here the walk stops with a ``SolverError`` (use ``regions = "all"``).
"""

from __future__ import annotations

import numpy as np

from codev_engine.errors import SolverError, SpecError
from codev_engine.geometry.polytope import chebyshev_ball
from codev_engine.mp.mplp_graph import JIT_AFTER, _NotExactError, _Search
from codev_engine.mp.on_demand import (
    MEET_TOL,
    OnDemandRegions,
    _rows,
    _split,
    lifted_centre,
)
from codev_engine.mp.program import MpProgram
from codev_engine.mp.reduce import lifted, parameter_box, reduce_program
from codev_engine.mp.solution import CriticalRegion, TooManyRegionsError, too_many_regions
from codev_engine.mp.solve import SolveOptions

__all__ = ["OnDemandBases"]


class OnDemandBases(OnDemandRegions):
    """The critical regions of an mp-LP with a parameter-free cost, computed where they are
    asked for (the full law's regions: ``mpsolve`` with the basis graph).

    Parameters
    ----------
    program : MpProgram
        An mp-LP whose reduced cost does not depend on the parameter (every MPC with norm 1
        or inf).
    options : SolveOptions, optional
        The full search's tolerances (``region_tol``, ``lp_perturbation``, ``seed``).

    Raises
    ------
    SolverError
        For an mp-QP, or an mp-LP whose cost depends on the parameter.

    Attributes
    ----------
    regions : list of CriticalRegion
        Every region found so far, in the order found, in the program's variables ``z``;
        ``regions[i].active`` its (sorted) basis.
    stats : dict
        ``candidates`` (regions computed), ``walks`` (sets asked about), ``lps`` (meeting
        tests), ``crossings`` (facets crossed).
    max_regions : int
        As for ``OnDemandRegions``.
    """

    def __init__(self, program: MpProgram, options: SolveOptions | None = None):
        opts = options or SolveOptions()
        red = reduce_program(program)
        if np.any(red.H) or np.any(red.C):
            raise SolverError("the mp-LP walk on demand needs an mp-LP whose cost does not "
                              "depend on the parameter (norm 1 or inf)")
        self.program = program
        self._red = red
        size = parameter_box(red)
        self.scale = size.scale
        self._region_tol = opts.region_tol * size.scale
        self._sstats: dict = {}
        self._search = _Search(red, size, region_tol=self._region_tol,
                               lp_perturbation=opts.lp_perturbation, seed=opts.seed,
                               max_regions=opts.max_regions, progress=None,
                               stats=self._sstats)
        self._lifted = lifted(red)
        self.regions: list[CriticalRegion] = []
        # per region (reduced space): parameter-set rows, facet centres or None, tolerance
        self._marks: list[np.ndarray] = []
        self._facets: list = []
        self._tols: list[float] = []
        self._known: dict[bytes, int] = {}
        self._search.known = self._known
        self._cross: dict[tuple[int, int], int] = {}  # (region, row) -> region or -1
        self._boxes_lo: list[np.ndarray] = []
        self._boxes_hi: list[np.ndarray] = []
        self._boundary: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._row_valid: dict[bytes, bool] = {}
        self.stats = {"candidates": 0, "walks": 0, "lps": 0, "crossings": 0}
        self._numpy_bases: set[tuple[int, ...]] = set()
        self._replayed = False
        self._bound = size.bound
        self.max_regions = opts.max_regions
        #: (region, row) of the facets not crossed yet: empty once the whole partition is
        #: known (:attr:`complete`)
        self._pending: set[tuple[int, int]] = set()

    @property
    def complete(self) -> bool:
        """Every region of the partition is known: every facet of every region found has
        been crossed (the closure the full search enumerates from its start).

        A region cache does not keep the facets crossed: when the replay had found the
        whole partition (it ended before ``JIT_AFTER`` regions), they are crossed again
        here (a dual simplex each, no new region)."""
        if not self._replayed or not self.regions:
            return False
        if self._pending and not self._search.jit_tried:
            try:
                for i, j in sorted(self._pending):
                    self._neighbour(i, j)
            except (_NotExactError, TooManyRegionsError):  # (a replay the limit cut short)
                return False
        return not self._pending

    # ---- regions by basis ----------------------------------------------------------------

    def _add(self, B: np.ndarray, out: tuple) -> int:
        if len(self.regions) >= self.max_regions:
            raise TooManyRegionsError(too_many_regions(self.max_regions))
        reg, mark, fac = out[:3]
        red = self._red
        key = np.sort(B).tobytes()
        K = red.Z1 + red.Nz @ reg.K
        k = red.Z0 + red.Nz @ reg.k
        self.regions.append(CriticalRegion(A=reg.A, b=reg.b, K=K, k=k, active=reg.active))
        self._marks.append(np.asarray(mark, dtype=bool))
        self._facets.append(fac)
        self._tols.append(out[3] if len(out) > 3 else self._region_tol)
        self._known[key] = len(self.regions) - 1
        self._pending.update((len(self.regions) - 1, int(j)) for j in np.flatnonzero(~mark))
        self.stats["candidates"] += 1
        if self._search.jit is None:
            self._numpy_bases.add(tuple(int(i) for i in np.sort(B)))
        if not self._search.jit_tried and len(self.regions) >= JIT_AFTER:
            self._search._start_jit()
        return len(self.regions) - 1

    def _replay(self) -> None:
        """The full search's start and its first ``JIT_AFTER`` regions, breadth first as it
        finds them (with the numpy code), so that every region is computed by the same code
        as in the full search."""
        self._replayed = True
        try:
            first = self._search._start()
            if first is None:
                return
            queue = [self._add(*first)]
            while queue and not self._search.jit_tried:
                i = queue.pop(0)
                for j in np.flatnonzero(~self._marks[i]):
                    if self._search.jit_tried:
                        break
                    before = len(self.regions)
                    if self._neighbour(i, int(j)) >= before:
                        queue.append(before)  # (a new region: the full search queues it)
        except _NotExactError as e:
            raise _not_exact(e) from None
        if not self._search.jit_tried and self._search.jit is None and JIT_AFTER <= 0:
            self._search._start_jit()

    def _neighbour(self, i: int, j: int) -> int:
        """The region across row ``j`` of region ``i`` (-1: none, the row is no facet or the
        feasible set ends there), as the full search's facet loop decides it."""
        hit = self._cross.get((i, j))
        if hit is not None:
            return hit
        self._cross[(i, j)] = out = self._cross_facet(i, j)
        self._pending.discard((i, j))
        return out

    def _cross_facet(self, i: int, j: int) -> int:
        s = self._search
        reg, fac, tol = self.regions[i], self._facets[i], self._tols[i]
        At, bt = self._red.At, self._red.bt
        a, beta = reg.A[j], reg.b[j]
        if self._marks[i][j]:
            return -1
        if fac is not None and not np.isnan(fac[1][j]):
            centre, rho = fac[0][j], fac[1][j]
            if rho <= tol:
                return -1  # only touches the region
        else:
            others = np.arange(reg.A.shape[0])
            others = others[others != j]
            centre, rho = chebyshev_ball(reg.A[others], reg.b[others], a[None, :],
                                         np.array([beta]))
            if not rho > tol:
                return -1
        if At.shape[0] and np.any((At @ a >= 1.0 - 1e-9)
                                  & (np.abs(At @ centre - bt) <= 1e-9 * self.scale)):
            return -1  # a slack's row on the parameter set's boundary
        self.stats["crossings"] += 1
        nbr = s._settle(np.array(reg.active, dtype=np.intp), centre, a, verified=True)
        if nbr is None:
            return -1
        key = np.sort(nbr).tobytes()
        if key in self._known:
            return self._known[key]
        out = s._region(nbr, centre)
        if out is None:
            out = s._sliver(nbr, centre)
        if out is None:
            raise _NotExactError("a neighbour's region is lower-dimensional")
        if np.any(out[0].A @ centre - out[0].b > 1e-7 * self.scale):
            raise _NotExactError("a neighbour does not touch the facet crossed")
        return self._add(nbr, out)

    # ---- the walk ------------------------------------------------------------------------

    def meeting(self, A: np.ndarray, b: np.ndarray) -> list[int]:
        """The regions that meet the polytope ``{theta : A theta <= b}`` (up to a relative
        ``MEET_TOL``), computing those not found yet.

        Parameters
        ----------
        A : (p, d) ndarray
        b : (p,) ndarray
            A bounded polytope in the program's parameter.

        Returns
        -------
        list of int
            Indices into :attr:`regions`, ascending by basis.

        Raises
        ------
        SolverError
            When a step of the walk cannot be made exact (the full search would fall back
            to the geometric explorer, whose regions differ).
        """
        asked = self._set_asked(A, b)
        if asked is None:
            return []
        A, b, lo, hi = asked
        mid, rad = 0.5 * (lo + hi), 0.5 * (hi - lo)
        try:
            start = self._start_in(A, b)
            if start is None:
                return []
            found: list[int] = []
            seen, queue = {start}, [start]
            while queue:
                i = queue.pop()
                if not self._region_meets(i, A, b, lo, hi):
                    continue
                found.append(i)
                reg = self.regions[i]
                # a facet whose hyperplane misses the set's box is not crossed: the segments
                # inside the set cross regions at points of the set
                reach = reg.A @ mid + np.abs(reg.A) @ rad
                near = reach >= reg.b - MEET_TOL * self.scale
                for j in np.flatnonzero(near & ~self._marks[i]):
                    n = self._neighbour(i, int(j))
                    if n >= 0 and n not in seen:
                        seen.add(n)
                        queue.append(n)
        except _NotExactError as e:
            raise _not_exact(e) from None
        found.sort(key=lambda k: self.regions[k].active)
        return found

    def _start_in(self, A: np.ndarray, b: np.ndarray) -> int | None:
        """The region of the lexicographically optimal basis at a point of the set inside
        the feasible set (its lifted Chebyshev centre), or None when the set misses it."""
        s = self._search
        d = A.shape[1]
        ball = lifted_centre(self._red, self._lifted, A, b, self.scale)
        if ball is None:
            return None
        q, rho = ball
        for_point = [q]
        rng = np.random.default_rng(0)
        for _ in range(7):
            u = rng.normal(size=d)
            for_point.append(q + 0.37 * rho * u / np.linalg.norm(u))
        for p in for_point:
            known = self._containing(p)
            if known is not None:
                return known
            sol = s.ex._solve_at(p)
            if sol is None or isinstance(sol, str):
                continue
            act = s.ex._lp_basis(p, sol[1])
            if act is None:
                continue
            B = s._settle(act, p, None)
            if B is None:
                continue
            key = np.sort(B).tobytes()
            if key in self._known:
                return self._known[key]
            out = s._region(B, p)
            if out is not None:
                return self._add(B, out)
        raise _NotExactError("no full-dimensional region at a point of the set")

    def _containing(self, p: np.ndarray) -> int | None:
        """A region found so far that holds ``p`` well inside (skips a solve)."""
        for i, reg in enumerate(self.regions):
            if np.all(reg.A @ p <= reg.b - 1e-7 * self.scale):
                return i
        return None

    # ---- persistence -------------------------------------------------------------------

    def state(self) -> dict[str, np.ndarray]:
        """The regions computed so far, as plain arrays (the keys of
        ``OnDemandRegions.state``: every active set a region's basis, ``kind`` 0; the
        regions the numpy code computed in ``numpy_acts``; ``lower_*`` and ``moves`` empty).
        The facets crossed are not kept (crossing one again costs a dual simplex, no region).

        Returns
        -------
        dict of str to ndarray
        """
        d = self._red.At.shape[1]
        nz = self._red.Z1.shape[0]
        regs = self.regions
        k = len(regs)
        i64 = np.int64
        nb = list(self._numpy_bases)
        return {
            "acts": np.array([x for r in regs for x in r.active], i64),
            "acts_len": np.array([len(r.active) for r in regs], i64),
            "kind": np.zeros(k, i64), "region": np.arange(k, dtype=i64),
            "moves": np.zeros(0, i64), "moves_len": np.zeros(k, i64),
            "lower_A": np.zeros((0, d)), "lower_b": np.zeros(0),
            "lower_len": np.zeros(k, i64),
            "reg_A": np.vstack([np.zeros((0, d))] + [r.A for r in regs]),
            "reg_b": np.concatenate([np.zeros(0)] + [r.b for r in regs]),
            "reg_len": np.array([r.A.shape[0] for r in regs], i64),
            "reg_K": np.array([r.K for r in regs]).reshape(k, nz, d),
            "reg_k": np.array([r.k for r in regs]).reshape(k, nz),
            "numpy_acts": np.array([x for a in nb for x in a], i64),
            "numpy_len": np.array([len(a) for a in nb], i64),
            "flags": np.array([self._replayed, self._search.jit is not None], i64),
            "box_lo": np.array(self._boxes_lo).reshape(-1, d),
            "box_hi": np.array(self._boxes_hi).reshape(-1, d),
        }

    def restore(self, st: dict[str, np.ndarray]) -> None:
        """Take over the regions written by :meth:`state` (checked; ``SpecError`` names the
        array that does not fit). The facet data of each region (its parameter-set rows,
        facet centres) are recomputed from its basis, and its rows must come out the same:
        a cache is never half trusted.

        Parameters
        ----------
        st : dict of str to numpy.ndarray
            The arrays :meth:`state` wrote (read back from the region cache).
        """
        red = self._red
        d, nz, ncons, nw = red.At.shape[1], red.Z1.shape[0], red.G.shape[0], red.G.shape[1]
        k = st["reg_len"].shape[0]
        acts = _split(st, "acts", "acts_len", k)
        if any(len(a) != nw or list(a) != sorted(set(a)) or min(a, default=0) < 0
               or max(a, default=0) >= ncons for a in acts) or len(set(acts)) != k:
            raise SpecError("not the bases of this program", field="acts")
        if not (np.array_equal(st["kind"], np.zeros(k)) and
                np.array_equal(st["region"], np.arange(k))):
            raise SpecError("must number the regions 0..k-1", field="region")
        rA, rb = _rows(st, "reg_A", "reg_b", st["reg_len"], d)
        K, kk = st["reg_K"], st["reg_k"]
        if K.shape != (k, nz, d) or kk.shape != (k, nz) or not np.all(np.isfinite(K)) \
                or not np.all(np.isfinite(kk)):
            raise SpecError(f"must be finite, of shapes ({k}, {nz}, {d}), ({k}, {nz})",
                            field="reg_K")
        flags = st["flags"]
        if flags.shape != (2,):
            raise SpecError("must have shape (2,)", field="flags")
        numpy_bases = set(_split(st, "numpy_acts", "numpy_len", st["numpy_len"].shape[0]))
        if not numpy_bases <= set(acts):
            raise SpecError("not bases of the regions", field="numpy_acts")
        lo, hi = st["box_lo"], st["box_hi"]
        if lo.ndim != 2 or lo.shape[1] != d or lo.shape[0] > k or hi.shape != lo.shape \
                or np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise SpecError(f"must be at most {k} boxes of {d} columns", field="box_lo")
        # recompute each region from its basis, by the code that computed it
        s = self._search
        self.regions, self._marks, self._facets, self._tols = [], [], [], []
        self._known.clear()
        self._cross = {}
        self._pending = set()
        most, self.max_regions = self.max_regions, max(self.max_regions, k)
        try:
            for i, act in enumerate(acts):
                B = np.array(act, dtype=np.intp)
                if act in numpy_bases:
                    jit, s.jit = s.jit, None
                    out = s._region(B)
                    s.jit = jit
                else:
                    if s.jit is None:
                        s._start_jit()
                    out = s._region(B)
                    if out is None:
                        out = s._sliver(B, np.zeros(d))
                if out is None or not (np.array_equal(out[0].A, rA[i])
                                       and np.array_equal(out[0].b, rb[i])):
                    raise SpecError("a region's rows are not its basis's", field="reg_A")
                self._add(B, out)
                if not (np.array_equal(self.regions[i].K, K[i])
                        and np.array_equal(self.regions[i].k, kk[i])):
                    raise SpecError("a region's law is not its basis's", field="reg_K")
        except _NotExactError:
            raise SpecError("a basis without a region", field="acts") from None
        finally:
            self.max_regions = most
        self.stats["candidates"] = 0  # (checks of the cache, not the walk's)
        self._numpy_bases = numpy_bases
        self._replayed = bool(flags[0])
        if flags[1] and s.jit is None:
            s._start_jit()
        s.jit_tried = s.jit_tried or bool(flags[1]) or k >= JIT_AFTER
        self._boxes_lo, self._boxes_hi = list(lo), list(hi)
        self._boundary, self._row_valid = {}, {}


def _not_exact(e: Exception) -> SolverError:
    return SolverError(
        f"the mp-LP's regions cannot be walked exactly on demand here ({e}): the full "
        "synthesis falls back to its geometric explorer; use regions = \"all\""
    )
