"""The critical regions of an mp-QP that meet a given set, computed when asked for.

A verification needs only the regions its reach sets meet, not the whole partition (issue
39). :class:`OnDemandRegions` walks the same graph of active sets as the full search
(``mpqp.explore_active_sets``), with the same candidate evaluation (``mpqp._Kernel``), but
only through the active sets whose polyhedron meets the set asked about:

- it starts from the optimal active set at a point of the set (the program solved there);
- a candidate is evaluated exactly as in the full search; a full-dimensional region or a
  lower-dimensional optimal set that misses the set (by more than a tolerance) is neither
  returned nor walked through; one that meets it is, with the same moves (facets, tight
  constraints, LICQ subsets, the opposite-bound rule) as the full search.

Why nothing is missed: two regions meeting the set (a box or polytope, convex) are joined by
a segment inside it; the active sets optimal along the segment are optimal at points of the
set, so the path of one-constraint changes the full search relies on between them stays
among the candidates walked here. The connectivity is the full search's own assumption
(checked by its conformance suite), restricted to a convex set.

Every evaluation is cached by active set, so later sets reuse what earlier ones found; a
region is the kernel's result for its active set, the same rows and law as in the full
partition (the full search's regions are its kernel's results too, sorted by active set).
Differences with the full partition: regions of one law that the full search merges where
LICQ fails on a full-dimensional set (``mpqp._merge_equal_laws``) stay apart here (they
overlap, with the same law); and only strictly convex mp-QPs (norm 2) are walked.
"""

from __future__ import annotations

import numpy as np

from codev_engine.errors import SolverError, SpecError
from codev_engine.geometry.polytope import (
    chebyshev_ball,
    normalize_rows,
    radius_upper_bound,
    solve_lp,
)
from codev_engine.mp.mpqp import JIT_AFTER, _active_set_at, _Kernel, dependent_rows
from codev_engine.mp.program import MpProgram
from codev_engine.mp.reduce import Reduced, lifted, parameter_box, reduce_program, start_point
from codev_engine.mp.solution import CriticalRegion, TooManyRegionsError, too_many_regions
from codev_engine.mp.solve import SolveOptions

__all__ = ["OnDemandRegions", "lifted_centre"]

#: the kinds of a candidate in the walk's cache, as :meth:`OnDemandRegions.state` numbers them
_KINDS = ("full", "lower", "empty", "licq")

#: a candidate meets a set when its rows, relaxed by this times the parameter set's size,
#: meet the set relaxed as much. Generous on purpose: a region found too many costs a
#: little walking, one missed is a hole. Slivers the kernel proves full (radius 2e-8) were
#: called empty by DAQP and by HiGHS (whose feasibility tolerance is 1e-7) on a chain of 5
#: integrators when relaxed by 1e-8 only
MEET_TOL = 1e-6
#: candidates of the full search's numpy phase replayed at most (:meth:`_replay`)
REPLAY_CANDIDATES = 2500
#: the same for a lower-dimensional optimal set (its rows as the kernel writes them)
LOWER_TOL = 1e-6


def lifted_centre(red: Reduced, lifted_rows: tuple[np.ndarray, np.ndarray], A: np.ndarray,
                  b: np.ndarray, scale: float) -> tuple[np.ndarray, float] | None:
    """The Chebyshev centre of the set ``{theta : A theta <= b}`` inside the feasible set,
    found in the lifted space ``(w, theta)`` of the reduced program (its radius at most
    ``scale``): where a walk on demand starts (the mp-QP's and the mp-LP's alike).

    Parameters
    ----------
    red : Reduced
        The reduced program (``G``, ``S``, ``At``).
    lifted_rows : tuple of ndarray
        ``reduce.lifted(red)``: the feasible set's rows over ``(w, theta)``.
    A : (p, d) ndarray
    b : (p,) ndarray
    scale : float

    Returns
    -------
    tuple of ((d,) ndarray, float) or None
        The centre in ``theta`` and its radius (>= 0); None when the set misses the
        feasible set.
    """
    nw, d = red.G.shape[1], A.shape[1]
    LA, Lb = lifted_rows
    rows = np.vstack([LA, np.hstack([np.zeros((A.shape[0], nw)), A])])
    rhs = np.concatenate([Lb, b])
    norms = np.concatenate([np.linalg.norm(red.S, axis=1), np.linalg.norm(red.At, axis=1),
                            np.ones(A.shape[0])])
    f = np.zeros(nw + d + 1)
    f[-1] = -1.0
    ub = np.full(nw + d + 1, np.inf)
    ub[-1] = scale
    x, st, _ = solve_lp(f, np.hstack([rows, norms[:, None]]), rhs, ub=ub)
    if st != "optimal" or x is None or x[-1] < -1e-9 * scale:
        return None
    return x[nw : nw + d], max(float(x[-1]), 0.0)


class OnDemandRegions:
    """The critical regions of a strictly convex mp-QP, computed where they are asked for.

    Parameters
    ----------
    program : MpProgram
        An mp-QP whose Hessian is positive definite after the reduction (every 2-norm MPC
        without soft constraints).
    options : SolveOptions, optional
        The full search's tolerances (``region_tol``, ``seed``).

    Raises
    ------
    SolverError
        For an mp-LP or a semi-definite mp-QP: not walked on demand (yet).

    Attributes
    ----------
    regions : list of CriticalRegion
        Every region found so far, in the order found, in the program's variables ``z``
        (as ``MpSolution.regions``); ``regions[i].active`` its active set.
    stats : dict
        ``candidates`` (active sets evaluated), ``walks`` (sets asked about), ``lps``
        (meeting tests solved as LPs).
    max_regions : int
        The walk raises ``TooManyRegionsError`` rather than compute one region more
        (``options.max_regions`` at first; the caller may lower it).
    """

    def __init__(self, program: MpProgram, options: SolveOptions | None = None):
        opts = options or SolveOptions()
        red = reduce_program(program)
        if not np.any(red.H):
            raise SolverError(
                "regions are computed on demand for norm 2 (an mp-QP) only; an mp-LP "
                "(norm 1 or inf) needs the full law (regions = \"all\")"
            )
        if np.min(np.linalg.eigvalsh(red.H)) <= 1e-12 * max(1.0, np.max(np.abs(red.H))):
            raise SolverError(
                "regions are computed on demand for a strictly convex mp-QP only (this one's "
                "Hessian is singular, e.g. soft constraints' slacks): use regions = \"all\""
            )
        self.program = program
        self._red = red
        size = parameter_box(red)
        self.scale = size.scale
        self._region_tol = opts.region_tol * size.scale
        self._kernel = _Kernel(red.H, red.c, red.C, red.G, red.w, red.S, red.At, red.bt,
                               size.scale, self._region_tol, size.box)
        G = red.G
        self._nz = G.shape[1]
        self._opposite = [
            set(int(x) for x in np.flatnonzero(np.abs(G + G[i]).max(axis=1) <= 1e-12))
            for i in range(G.shape[0])
        ]
        self._lifted = lifted(red)
        # active set -> ("full", index) | ("lower", (A, b), moves) | ("empty",) | ("licq",)
        self._cache: dict[tuple[int, ...], tuple] = {}
        self.regions: list[CriticalRegion] = []
        self._boxes_lo: list[np.ndarray] = []
        self._boxes_hi: list[np.ndarray] = []
        self._boundary: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._row_valid: dict[bytes, bool] = {}
        self.stats = {"candidates": 0, "walks": 0, "lps": 0, "compiled": 0}
        self._seed = opts.seed
        #: the active sets the full search evaluates with the numpy kernel (known once
        #: :meth:`_replay` has run); every other one it evaluates compiled
        self._numpy_acts: set[tuple[int, ...]] = set()
        self._replayed = False
        self._bound = size.bound  # max |theta| over the set asked about (_rows_meet)
        self.max_regions = opts.max_regions
        #: active sets a non-empty candidate leads to (its neighbours) not evaluated yet:
        #: empty once the whole partition is known (:attr:`complete`)
        self._frontier: set[tuple[int, ...]] = set()

    # ---- the walk ----------------------------------------------------------------------

    def start(self) -> None:
        """Replay the full search's start (:meth:`_replay`) if not done yet: a small law is
        then known whole (:attr:`complete`) before the first set is asked about."""
        if not self._replayed:
            self._replay()

    @property
    def complete(self) -> bool:
        """Every region of the partition is known: every neighbour of every candidate
        evaluated has been evaluated too (the closure the full search enumerates from its
        start, which the replay evaluated), so no set can meet a region not found yet."""
        return self._replayed and bool(self.regions) and not self._frontier

    def meeting(self, A: np.ndarray, b: np.ndarray) -> list[int]:
        """The regions that meet the polytope ``{theta : A theta <= b}`` (up to a relative
        ``MEET_TOL``), computing those not found yet.

        Parameters
        ----------
        A : (p, d) ndarray
        b : (p,) ndarray
            A bounded polytope in the program's parameter (a box: its six rows, say).

        Returns
        -------
        list of int
            Indices into :attr:`regions`, ascending by active set (the full partition's
            order).
        """
        asked = self._set_asked(A, b)
        if asked is None:
            return []
        A, b, lo, hi = asked
        starts = self._starts(A, b)
        if not starts:
            return []
        found: list[int] = []
        seen: set[tuple[int, ...]] = set()
        stack: list[tuple[int, ...]] = []
        for act in starts:
            if act not in seen:
                seen.add(act)
                stack.append(act)
        while stack:
            act = stack.pop()
            entry = self._evaluate(act)
            kind = entry[0]
            if kind == "empty":
                continue
            if kind == "full":
                i = entry[1]
                if not self._region_meets(i, A, b, lo, hi):
                    continue
                found.append(i)
                moves = entry[2]
            elif kind == "lower":
                rows, moves = entry[1], entry[2]
                if not self._rows_meet(rows[0], rows[1] + LOWER_TOL * self.scale, A, b):
                    continue
            else:
                moves = None
            for nxt in self._neighbours(act, kind, moves):
                if nxt not in seen:
                    seen.add(nxt)
                    stack.append(nxt)
        found.sort(key=lambda i: self.regions[i].active)
        return found

    def _starts(self, A: np.ndarray, b: np.ndarray) -> list[tuple[int, ...]]:
        """Optimal active sets at points of the set inside the feasible set: its lifted
        Chebyshev centre moved off it (as ``reduce.start_point``), and the centre itself;
        none when the set misses the feasible set."""
        red = self._red
        d = A.shape[1]
        ball = lifted_centre(red, self._lifted, A, b, self.scale)
        if ball is None:
            return []
        centre, rho = ball
        points = [centre]
        if rho > 0:
            u = np.random.default_rng(0).normal(size=d)
            points.insert(0, centre + 0.37 * rho * u / np.linalg.norm(u))
        out = []
        for p in points:
            try:
                out.append(_active_set_at(red.H, red.c, red.C, red.G, red.w, red.S, p))
            except SolverError:
                continue
        return out

    def _replay(self) -> None:
        """The full search's first steps, as it takes them: from its start point, depth
        first, with the numpy kernel, until it has ``mpqp.JIT_AFTER`` regions (then it
        goes on with the compiled kernel). The two kernels prove the same regions but
        round differently (rows and laws differ in the last bits), so the candidates
        evaluated here are the ones this walk evaluates with the numpy kernel too, and
        every other one with the compiled kernel: each region is the full partition's bit
        for bit. A search that ends first is the whole partition (all numpy). The replay
        stops after ``REPLAY_CANDIDATES`` candidates (the rest of the full search's numpy
        phase is evaluated compiled here: the same regions, rounded differently; two_carts_mixed
        takes 1,193 candidates to its last region, dc_motor_servo 545): on a
        chain of 8 integrators its 200 regions take 5,000 candidates, ~50 s."""
        red = self._red
        self._replayed = True
        q0 = start_point(red, self.scale, self._region_tol, np.random.default_rng(self._seed))
        if q0 is None:
            return
        act0 = _active_set_at(red.H, red.c, red.C, red.G, red.w, red.S, q0)
        explored, stack, found = {act0}, [act0], 0
        while stack and found < JIT_AFTER and len(self._numpy_acts) < REPLAY_CANDIDATES:
            act = stack.pop()
            self._numpy_acts.add(act)
            entry = self._evaluate(act)
            if entry[0] == "empty":
                continue
            found += entry[0] == "full"
            moves = entry[2] if entry[0] in ("full", "lower") else None
            for nxt in self._neighbours(act, entry[0], moves):
                if nxt not in explored:
                    explored.add(nxt)
                    stack.append(nxt)
        if stack:
            self._kernel.start_jit()  # (False without numba: the numpy kernel throughout)

    def _evaluate(self, act: tuple[int, ...]) -> tuple:
        """The candidate ``act`` classified by the full search's kernel, cached."""
        hit = self._cache.get(act)
        if hit is not None:
            return hit
        kernel = self._kernel
        if kernel._jit is not None and act not in self._numpy_acts:
            status, rows, law, moves, _ = kernel.evaluate(act)
            self.stats["compiled"] += 1
        else:
            status, rows, law, moves, _ = kernel.evaluate_numpy(act)
        if status == "full" and len(self.regions) >= self.max_regions:
            # (before the region is kept: the cache stays consistent for a save)
            raise TooManyRegionsError(too_many_regions(self.max_regions))
        self.stats["candidates"] += 1
        if status == "full":
            red = self._red
            K = red.Z1 + red.Nz @ law[0]
            k = red.Z0 + red.Nz @ law[1]
            self.regions.append(CriticalRegion(A=rows[0], b=rows[1], K=K, k=k, active=act))
            entry: tuple = ("full", len(self.regions) - 1, moves)
        elif status == "lower":
            entry = ("lower", self._candidate_rows(act), moves)
        else:
            entry = (status,)
        self._cache[act] = entry
        self._discovered(act, entry)
        return entry

    def _discovered(self, act: tuple[int, ...], entry: tuple) -> None:
        """Keep :attr:`_frontier` up to date once ``act`` is evaluated (``entry``)."""
        self._frontier.discard(act)
        if entry[0] == "empty":
            return
        moves = entry[2] if entry[0] in ("full", "lower") else None
        for nxt in self._neighbours(act, entry[0], moves):
            if nxt not in self._cache:
                self._frontier.add(nxt)

    def _candidate_rows(self, act: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The (unit) rows of the polyhedron where ``act`` is optimal (multipliers and
        slacks non-negative, the parameter set), as the kernel writes them."""
        kernel = self._kernel
        Lam, Sl, *_ = kernel._kkt(np.array(act, dtype=np.intp))
        Ar = np.vstack([-Lam[:, 1:], -Sl[:, 1:], kernel.At])
        br = np.concatenate([Lam[:, 0], Sl[:, 0], kernel.bt])
        norms = np.linalg.norm(Ar, axis=1)
        keep = norms > 1e-12
        return Ar[keep] / norms[keep, None], br[keep] / norms[keep]

    def _neighbours(self, act: tuple[int, ...], kind: str, moves) -> list[tuple[int, ...]]:
        """The active sets the full search visits from ``act`` (``explore_active_sets``'s
        ``visit``): subsets of a set breaking LICQ, across the facets of a region or the
        constraints tight on a lower-dimensional set, never two opposite bounds."""
        if kind == "licq":
            leave, enter = dependent_rows(self._red.G, act), []
        else:
            mv = [] if moves is None else [int(v) for v in moves]
            leave = [v - 1 for v in mv if v > 0]
            enter = [-v - 1 for v in mv if v < 0]
        out = [tuple(x for x in act if x != i) for i in leave]
        if kind == "licq" or len(act) >= self._nz + 1:
            return out
        blocked = set(act)
        for i in act:
            blocked |= self._opposite[i]
        out += [tuple(sorted(act + (i,))) for i in enter if i not in blocked]
        return out

    # ---- meeting tests -----------------------------------------------------------------

    def _set_asked(self, A: np.ndarray, b: np.ndarray):
        """A set a walk is asked about, made ready (both walks, :meth:`meeting`): the full
        search's start replayed if not yet, the rows normalised and relaxed by
        ``MEET_TOL``, its bounding box (which also bounds the meeting tests' scale,
        ``_bound``); None when the set is empty."""
        if not self._replayed:
            self._replay()
        self.stats["walks"] += 1
        A, b, ok = normalize_rows(np.asarray(A, float), np.asarray(b, float))
        if not ok:
            return None
        b = b + MEET_TOL * self.scale
        lo, hi = self._box_of(A, b)
        if lo is None:
            return None
        self._bound = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
        return A, b, lo, hi

    def _box_of(self, A: np.ndarray, b: np.ndarray):
        """The bounding box of ``A theta <= b`` (None, None when it is empty)."""
        from codev_engine.geometry.polytope import bounding_box

        _, st, _ = solve_lp(np.zeros(A.shape[1]), A, b)
        if st == "infeasible":
            return None, None
        return bounding_box(A, b)

    def _region_meets(self, i: int, A, b, lo, hi) -> bool:
        """Does region ``i``, relaxed by ``MEET_TOL``, meet ``A theta <= b`` (box lo, hi)?"""
        tol = MEET_TOL * self.scale
        if i < len(self._boxes_lo):  # (its box known: a box apart is a quick no)
            if np.any(self._boxes_lo[i] > hi + tol) or np.any(self._boxes_hi[i] < lo - tol):
                return False
        reg = self.regions[i]
        return self._rows_meet(reg.A, reg.b + tol, A, b)

    def _rows_meet(self, Ar, br, A, b) -> bool:
        """Is ``{Ar theta <= br, A theta <= b}`` non-empty? DAQP's Chebyshev centre first
        (its plain LP with a zero cost said "infeasible" to most sets); a "no" stands when
        its multipliers prove it (``radius_upper_bound`` below 0), else HiGHS's Chebyshev
        ball decides (DAQP called slivers of radius 2e-8 that the kernel had
        proved full infeasible, on a chain of 4 integrators)."""
        self.stats["lps"] += 1
        M, v = np.vstack([Ar, A]), np.concatenate([br, b])
        centre, rho, y = chebyshev_ball(M, v, multipliers=True)
        if np.max(M @ centre - v) <= 0.1 * MEET_TOL * self.scale:
            return True
        if y is not None and radius_upper_bound(M, v, y, self._bound) < 0.0:
            return False  # (proved empty: weak duality, whatever DAQP's accuracy)
        self.stats["highs"] = self.stats.get("highs", 0) + 1
        centre, rho = chebyshev_ball(M, v, solver="highs")
        return bool(rho >= 0.0 or float(np.max(M @ centre - v)) <= 0.0)

    # ---- the domain ----------------------------------------------------------------------

    def boundary_rows(self, indices: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """The rows of the regions ``indices`` that hold on the whole feasible set (its
        facets there, as ``solve._domain_from_regions`` decides them), and the parameter
        set's rows.

        Where a set meets these regions and no others, the feasible set inside it is
        exactly these rows: every facet of the feasible set that cuts the set is a facet
        of a region meeting it.

        Parameters
        ----------
        indices : list of int

        Returns
        -------
        A : (q, d) ndarray
        b : (q,) ndarray
        """
        red = self._red
        As, bs = [red.At], [red.bt]
        for i in indices:
            if i not in self._boundary:
                self._boundary[i] = self._valid_rows(self.regions[i])
            As.append(self._boundary[i][0])
            bs.append(self._boundary[i][1])
        return np.vstack(As), np.concatenate(bs)

    def _valid_rows(self, reg: CriticalRegion) -> tuple[np.ndarray, np.ndarray]:
        red = self._red
        LA, Lb = self._lifted
        nw = red.G.shape[1]
        tol = 1e-9 * self.scale
        keep = np.zeros(reg.A.shape[0], dtype=bool)
        theta_rows = np.hstack([red.At, red.bt[:, None]])
        for j, (a, beta) in enumerate(zip(reg.A, reg.b, strict=True)):
            if np.any(np.all(np.abs(theta_rows - np.append(a, beta)) <= 1e-12, axis=1)):
                continue  # (the parameter set's rows are added anyway)
            key = np.round(np.append(a, beta), 9).tobytes()
            valid = self._row_valid.get(key)
            if valid is None:
                x, st, _ = solve_lp(np.concatenate([np.zeros(nw), -a]), LA, Lb)
                valid = st == "optimal" and float(a @ x[nw:]) <= beta + tol
                self._row_valid[key] = valid
            keep[j] = valid
        return reg.A[keep], reg.b[keep]

    def separating_row(self, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, float] | None:
        """A row valid on the whole feasible set that every point of the polytope ``A theta
        <= b`` violates (the polytope misses the feasible set), or None when none is found
        (the polytope meets it, or the LPs could not show it).

        The direction is the one of the shortest segment from the feasible set to the
        polytope (a QP), the offset the largest value over the feasible set (an LP): the
        row is valid whatever the accuracy of the QP; it is returned only when the LP over
        the polytope shows every point of it beyond the row.

        Parameters
        ----------
        A : (p, d) ndarray
        b : (p,) ndarray

        Returns
        -------
        (a, beta) or None
            Unit row ``a`` (d,) and offset ``beta``.
        """
        import daqp

        red = self._red
        nw, d = red.G.shape[1], A.shape[1]
        LA, Lb = self._lifted
        # variables (w, theta, p): (w, theta) feasible, p in the polytope, min |theta - p|^2
        nv = nw + 2 * d
        H = 1e-9 * np.eye(nv)
        H[nw:, nw:] += np.block([[np.eye(d), -np.eye(d)], [-np.eye(d), np.eye(d)]])
        rows = np.vstack([np.hstack([LA, np.zeros((LA.shape[0], d))]),
                          np.hstack([np.zeros((A.shape[0], nw + d)), A])])
        rhs = np.concatenate([Lb, b])
        m = rows.shape[0]
        x, _, flag, _ = daqp.solve(H, np.zeros(nv), rows, rhs, np.full(m, -1e30),
                                   np.zeros(m, dtype=np.int32))
        if flag != 1:
            return None
        a = x[nw + d :] - x[nw : nw + d]
        norm = float(np.linalg.norm(a))
        if not norm > 1e-9 * self.scale:
            return None
        a = a / norm
        xs, st, _ = solve_lp(np.concatenate([np.zeros(nw), -a]), LA, Lb)
        if st != "optimal":
            return None
        beta = float(a @ xs[nw:]) + 1e-9 * self.scale
        xp, st, _ = solve_lp(a, A, b)
        if st != "optimal" or not float(a @ xp) > beta:
            return None
        return a, beta

    # ---- persistence ---------------------------------------------------------------------

    def state(self) -> dict[str, np.ndarray]:
        """Every candidate evaluated so far and how (the walk's cache), as plain arrays.

        What :meth:`restore` needs to go on as if it had evaluated them itself: each active
        set's kind, moves and rows, the regions (rows and law, bit for bit), the active sets
        of the replayed numpy phase and whether the compiled kernel had started (so later
        candidates are evaluated by the same kernel as in the full search).

        Returns
        -------
        dict of str to ndarray
            ``acts``/``acts_len`` (flat active sets, their sizes (q,)); ``kind`` (q,) 0 full,
            1 lower, 2 empty, 3 LICQ; ``region`` (q,) the region index of a full one (-1);
            ``moves``/``moves_len`` (-1: none); ``lower_A`` (r, d), ``lower_b``,
            ``lower_len``; ``reg_A`` (R, d), ``reg_b``, ``reg_len`` (k,), ``reg_K``
            (k, nz, d), ``reg_k`` (k, nz); ``numpy_acts``/``numpy_len``; ``flags``
            (replayed, compiled kernel started); ``box_lo``, ``box_hi`` (k', d) the boxes
            of the first k' regions (those computed).
        """
        d = self._red.At.shape[1]
        acts, acts_len, kind, region, moves, moves_len = [], [], [], [], [], []
        lower_A, lower_b, lower_len = [np.zeros((0, d))], [np.zeros(0)], []
        for act, entry in self._cache.items():
            acts += act
            acts_len.append(len(act))
            kind.append(_KINDS.index(entry[0]))
            region.append(entry[1] if entry[0] == "full" else -1)
            mv = entry[2] if entry[0] in ("full", "lower") else None
            moves_len.append(-1 if mv is None else len(mv))
            moves += [] if mv is None else [int(v) for v in mv]
            rows = entry[1] if entry[0] == "lower" else None
            lower_len.append(0 if rows is None else rows[0].shape[0])
            if rows is not None:
                lower_A.append(rows[0])
                lower_b.append(rows[1])
        regs = self.regions
        nz = self._red.Z1.shape[0]
        numpy_acts = [a for a in self._numpy_acts]
        i64 = np.int64
        return {
            "acts": np.array(acts, i64), "acts_len": np.array(acts_len, i64),
            "kind": np.array(kind, i64), "region": np.array(region, i64),
            "moves": np.array(moves, i64), "moves_len": np.array(moves_len, i64),
            "lower_A": np.vstack(lower_A), "lower_b": np.concatenate(lower_b),
            "lower_len": np.array(lower_len, i64),
            "reg_A": np.vstack([np.zeros((0, d))] + [r.A for r in regs]),
            "reg_b": np.concatenate([np.zeros(0)] + [r.b for r in regs]),
            "reg_len": np.array([r.A.shape[0] for r in regs], i64),
            "reg_K": np.array([r.K for r in regs]).reshape(len(regs), nz, d),
            "reg_k": np.array([r.k for r in regs]).reshape(len(regs), nz),
            "numpy_acts": np.array([x for a in numpy_acts for x in a], i64),
            "numpy_len": np.array([len(a) for a in numpy_acts], i64),
            "flags": np.array([self._replayed, self._kernel._jit is not None], i64),
            # (the boxes known: a loaded cache need not solve their LPs again)
            "box_lo": np.array(self._boxes_lo).reshape(-1, d),
            "box_hi": np.array(self._boxes_hi).reshape(-1, d),
        }

    def restore(self, st: dict[str, np.ndarray]) -> None:
        """Take over a walk's cache written by :meth:`state` (by a walk of the same program
        and options: the caller checks the fingerprint), replacing this one's.

        Parameters
        ----------
        st : dict of str to ndarray
            As :meth:`state` returns; shapes, ranges and consistency are checked here.

        Raises
        ------
        SpecError
            Naming the array that does not fit this program (``field``).
        """
        d = self._red.At.shape[1]
        ncons = self._red.G.shape[0]
        nz = self._red.Z1.shape[0]
        q = st["kind"].shape[0]
        acts = _split(st, "acts", "acts_len", q)
        for a in acts:
            if any(x < 0 or x >= ncons for x in a) or list(a) != sorted(set(a)) \
                    or len(a) > self._nz + 1:
                raise SpecError("not active sets of this program", field="acts")
        if len(set(acts)) != q:
            raise SpecError("an active set twice", field="acts")
        kind, region = st["kind"], st["region"]
        if kind.shape != (q,) or np.any((kind < 0) | (kind >= len(_KINDS))):
            raise SpecError("must be q kinds in 0..3", field="kind")
        k = st["reg_len"].shape[0]
        full = kind == 0
        if region.shape != (q,) or sorted(region[full].tolist()) != list(range(k)) \
                or np.any(region[~full] != -1):
            raise SpecError("must number the full regions 0..k-1 once each", field="region")
        ml = st["moves_len"]
        if ml.shape != (q,) or np.any(ml < -1) or np.any((ml == -1) & (kind < 2)):
            raise SpecError("bad move counts", field="moves_len")
        mv = _split(st, "moves", None, q, sizes=np.maximum(ml, 0))
        if any(abs(v) > ncons for m in mv for v in m):  # (0: a row of the parameter set)
            raise SpecError("moves out of range", field="moves")
        ll = st["lower_len"]
        if ll.shape != (q,) or np.any(ll < 0) or np.any((ll > 0) & (kind != 1)):
            raise SpecError("bad row counts", field="lower_len")
        lA, lb = _rows(st, "lower_A", "lower_b", ll, d)
        rA, rb = _rows(st, "reg_A", "reg_b", st["reg_len"], d)
        K, kk = st["reg_K"], st["reg_k"]
        if K.shape != (k, nz, d) or kk.shape != (k, nz):
            raise SpecError(f"must have shapes ({k}, {nz}, {d}) and ({k}, {nz})",
                            field="reg_K")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(kk))):
            raise SpecError("non-finite numbers (NaN or inf)", field="reg_K")
        flags = st["flags"]
        if flags.shape != (2,):
            raise SpecError("must have shape (2,)", field="flags")
        numpy_acts = _split(st, "numpy_acts", "numpy_len", st["numpy_len"].shape[0])
        order = np.argsort(region[full], kind="stable")
        full_acts = [acts[i] for i in np.flatnonzero(full)[order]]
        regions = [CriticalRegion(A=rA[i], b=rb[i], K=K[i].copy(), k=kk[i].copy(),
                                  active=full_acts[i]) for i in range(k)]
        cache: dict[tuple[int, ...], tuple] = {}
        for i, act in enumerate(acts):
            name = _KINDS[int(kind[i])]
            moves = None if ml[i] < 0 else np.array(mv[i], dtype=np.int64)
            if name == "full":
                cache[act] = ("full", int(region[i]), moves)
            elif name == "lower":
                cache[act] = ("lower", (lA[i], lb[i]), moves)
            else:
                cache[act] = (name,)
        self._cache = cache
        self.regions = regions
        self._frontier = set()
        for act, entry in cache.items():
            self._discovered(act, entry)
        lo, hi = st["box_lo"], st["box_hi"]
        if lo.ndim != 2 or lo.shape[1] != d or lo.shape[0] > k or hi.shape != lo.shape \
                or np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise SpecError(f"must be at most {k} boxes of {d} columns", field="box_lo")
        self._boxes_lo, self._boxes_hi = list(lo), list(hi)
        self._boundary, self._row_valid = {}, {}
        self._numpy_acts = set(numpy_acts)
        self._replayed = bool(flags[0])
        if flags[1] and self._kernel._jit is None:
            self._kernel.start_jit()

    # ---- bounding boxes ------------------------------------------------------------------

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """The bounding boxes of the regions found, lower and upper (R, d) each."""
        d = self._red.At.shape[1]
        if not self.regions:
            return np.zeros((0, d)), np.zeros((0, d))
        k = len(self._boxes_lo)
        if k < len(self.regions):
            # the new regions' boxes in one call (compiled from 64 regions on: one LP each
            # by HiGHS took 35 ms a region on a chain of 8 integrators)
            from codev_engine.geometry.locate import bounding_boxes

            new = self.regions[k:]
            lo, hi = bounding_boxes([r.A for r in new], [r.b for r in new])
            self._boxes_lo += list(lo)
            self._boxes_hi += list(hi)
        return np.array(self._boxes_lo), np.array(self._boxes_hi)


def _split(st: dict[str, np.ndarray], key: str, lens: str | None, q: int,
           sizes: np.ndarray | None = None) -> list[tuple[int, ...]]:
    """The flat integer array ``st[key]`` cut into ``q`` tuples of sizes ``st[lens]``."""
    flat = st[key]
    sizes = st[lens] if sizes is None else sizes
    if flat.dtype.kind not in "iu" or flat.ndim != 1 or sizes.shape != (q,) \
            or np.any(sizes < 0) or int(sizes.sum()) != flat.shape[0]:
        raise SpecError("does not match its sizes", field=key)
    cuts = np.cumsum(sizes)[:-1] if q else []
    return [tuple(int(x) for x in part) for part in np.split(flat, cuts)] if q else []


def _rows(st: dict[str, np.ndarray], ka: str, kb: str, sizes: np.ndarray, d: int
          ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The stacked rows ``st[ka] theta <= st[kb]`` cut into blocks of ``sizes`` rows."""
    A, b = st[ka], st[kb]
    if A.ndim != 2 or A.shape[1] != d or b.shape != (A.shape[0],) or np.any(sizes < 0) \
            or int(sizes.sum()) != A.shape[0]:
        raise SpecError(f"must be rows of {d} columns matching their counts", field=ka)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        raise SpecError("non-finite numbers (NaN or inf)", field=ka)
    if not sizes.size:
        return [], []
    cuts = np.cumsum(sizes)[:-1]
    return np.split(A, cuts), np.split(b, cuts)
