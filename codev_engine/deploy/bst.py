"""A binary search tree over a law's regions (Tøndel, Johansen & Bemporad 2003), exact.

The tree answers the question ``ExplicitLaw.locate`` answers, with the same answer at
every point, boundaries included. ``locate``'s rule (``geometry.locate``): region ``i``'s
*violation* at ``theta`` is ``v_i = max_j (A_i theta - b_i)_j`` (its stored rows; -1 for a
region without rows). The region is the lowest index with ``v_i <= 0`` (holds); when none
holds, the one with the smallest ``v_i <= tol`` (near; the lowest index on ties); else -1.

How the tree keeps that rule
----------------------------
Each internal node tests a hyperplane ``s = a theta - b`` (unit ``a``; one of the regions'
facets, duplicates merged) and goes left when ``s <= 0``. The regions are sorted into the
children by their part inside the node's *cell* (the half-spaces its path took; the
default, ``sort="cell"``): a region (*enlarged by* ``tol``) is a *member* of the left child
unless its part of the cell, widened, is proved to lie beyond ``s > eps``, and *proper*
there unless its part of the cell shrunk by ``PROPER (1 + |b|)`` per test (where the fast
path runs) is proved to lie within ``s > -PROPER (1 + |b|)`` (right: mirrored). Proofs
come from the enlarged vertices (their hull holds every point that can hold or be near
the region) or from a certified LP (``prune_kernel.split_node``). No LP is solved where
an ancestor node proved the region apart from that side of the same hyperplane (apart
from a larger cell), or where a *witness* (a point of the region's part of the cell, the
centre of an earlier LP's ball) already meets the test: the LP would keep the region too.
With ``sort="vertices"``
(the first version) all of a region's vertices decide: member when some vertex has
``s <= eps``, proper when some has ``s < -eps``. A member that is not proper only touches
the hyperplane (a neighbour across a shared facet) or lies beyond it within the cell.
Splitting stops when at most one proper region is left (the leaf's *owner*), at a bucket
(at most ``leaf_size`` proper regions, or all of one law: the fast path runs the rule
over them; with ``stop_ratio``, also a node of at most ``bucket_max`` that no split makes
much smaller), or where no hyperplane takes a proper region off.

At run time every test also notes whether ``|s| <= delta`` (``delta = 1e-7 (1 + |b|)``,
float32: ``1e-4 (1 + |b|)``): the point is *near* a tested hyperplane.

* Not near (the fast path): the point is more than ``delta`` inside every tested
  half-space, so it is outside every region that was dropped or is not proper (each was
  proved apart from that part of a cell): only the owner (a bucket's regions) can hold it
  or be near it. The owner's rows are evaluated (those equal to a tested hyperplane, on the
  side taken, are negative there and skipped) and the rule decides between the owner and
  -1.
* Near: the rule is evaluated over the leaf's members (owner and touching regions, in
  index order, every stored row): they include every region the point can hold or be near.

Either way the answer is ``locate``'s, evaluated in the same arithmetic as its compiled
walk (``-b_j + sum_t A_jt theta_t`` in order of ``t``, no fused multiply-add). A box around
all (enlarged) regions is checked first: outside it no region holds or is near.

The cost of a call is bounded by the tree: :meth:`Tree.cost` walks every leaf.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.geometry.polytope import unique_rows
from codev_engine.geometry.vertices import packed_vertices

__all__ = ["LOCATE_TOL", "Tree", "TreeTooLargeError", "build_tree", "sequential_tree"]


class TreeTooLargeError(SolverError):
    """The tree would exceed its node budget (regions the vertex sort cannot tell apart:
    high dimension, boxes instead of vertices); the sequential search remains."""

#: the locator's tolerance (``PointLocator``'s default): near a region means ``v <= tol``
LOCATE_TOL = 1e-9
#: classification slack (relative to ``1 + |b|``) of the vertices against a hyperplane
EPS = 1e-8
#: the cell sort's margin of a proper region: half the smallest run-time delta (a point
#: on the fast path is more than delta inside every tested half-space, rounding included)
PROPER = 5e-7
#: the run-time "near a tested hyperplane" margin (relative to ``1 + |b|``), per precision
DELTA = {"double": 1e-6, "float": 1e-4}
#: below this many hyperplanes x regions, their extents are tabulated once
TABLE_ENTRIES = 4_000_000
#: the most internal nodes per region (a tree past it is given up: TreeTooLargeError)
NODES_PER_REGION = 100
#: CPU seconds of construction after which the tree is given up (TreeTooLargeError; CPU,
#: not wall time: the verdict does not depend on the load of the machine)
TIME_LIMIT = 300.0
#: vertex evaluations spent scoring a cell-sorted node's candidate hyperplanes (at least
#: one chunk)
BUDGET = 2e7
#: candidates of a cell-sorted node confirmed by LPs, at most, before the best by all
#: vertices
TRIES = 6
#: the cell sort's charge per region copied into both children of a split (0: balance
#: first, as in Tøndel et al.)
DUPLICATE_WEIGHT = 0.25
#: witnesses kept per region and node (points of its part of the cell, from the LPs:
#: an undecided test they meet needs no LP; ``prune_kernel.split_node``)
WITNESSES = 6
#: a region of at most this many d-subsets of rows has its vertices from the subsets,
#: a larger one from Qhull (``_enlarged_vertices``)
SUBSET_MAX = 2_000
#: the most vertices (upper bound theorem) of a region given to Qhull; past it the region
#: takes its box (Qhull's time follows the vertices)
HULL_MAX_VERTICES = 200_000
#: the deepest tree built; a node deeper becomes a leaf that checks all its members
MAX_DEPTH = 64


@dataclass
class Tree:
    """A point-location tree over regions (from :func:`build_tree`).

    Attributes
    ----------
    d : int
        The parameter's dimension.
    node_a : (N, d) ndarray
        The tested hyperplanes (unit rows), one per internal node.
    node_b : (N,) ndarray
    node_next : (N, 2) ndarray of int
        The child taken when ``s <= 0`` (column 0) and ``s > 0`` (column 1): a node index
        (>= 0) or ``-1 - leaf``.
    leaf_owner : (L,) ndarray of int
        The leaf's single proper region, -1 for none.
    leaf_general : (L,) ndarray of bool
        A leaf with several proper regions (no hyperplane separates them, or too deep):
        it always checks all its members.
    leaf_fast : list of (q_l,) ndarray of int
        The owner's rows (global row numbers) the fast path evaluates.
    leaf_members : list of (p_l,) ndarray of int
        The regions evaluated near a tested hyperplane, ascending.
    leaf_depth : (L,) ndarray of int
        The number of tests on the path to the leaf.
    box_lo, box_hi : (d,) ndarray or None
        Outside this box no region holds or is near a point (None: no box, only
        non-finite parameters are turned away before the search).
    row_off : (R + 1,) ndarray of int
        Region ``i``'s stored rows are ``row_off[i]:row_off[i + 1]``.
    seconds : float
        Construction time.
    stats : dict
        Counters of the construction (``hyperplanes``: distinct ones, ``vertices``).
    leaf_group : list of (g_l,) ndarray of int
        A leaf whose proper regions all have one affine law (``build_tree(labels=...)``)
        or are at most ``leaf_size`` lists them, ascending: its fast path runs the rule
        over them alone (no further split); empty for other leaves (or an empty list:
        none).
    """

    d: int
    node_a: np.ndarray
    node_b: np.ndarray
    node_next: np.ndarray
    leaf_owner: np.ndarray
    leaf_general: np.ndarray
    leaf_fast: list[np.ndarray]
    leaf_members: list[np.ndarray]
    leaf_depth: np.ndarray
    box_lo: np.ndarray | None
    box_hi: np.ndarray | None
    row_off: np.ndarray
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    leaf_group: list[np.ndarray] = field(default_factory=list)

    def group(self, leaf: int) -> np.ndarray:
        """The proper regions a group leaf checks on its fast path (empty otherwise).

        Parameters
        ----------
        leaf : int

        Returns
        -------
        (g,) ndarray of int
        """
        if not self.leaf_group:
            return np.zeros(0, dtype=np.int64)
        return self.leaf_group[leaf]

    @property
    def num_nodes(self) -> int:
        """Internal nodes (hyperplane tests)."""
        return self.node_b.shape[0]

    @property
    def num_leaves(self) -> int:
        """Leaves."""
        return self.leaf_owner.shape[0]

    def cost(self) -> dict:
        """The worst case of one call, by exhaustive traversal of every leaf.

        Returns
        -------
        dict
            ``depth``: the most hyperplane tests on a path; ``fast``: the most tests plus
            owner rows on the fast path; ``tests``: the most tests plus rows on any path
            (fast or near a hyperplane): the certified worst case of hyperplane
            evaluations, each ``d`` multiply-adds.
        """
        nrows = np.diff(self.row_off)
        depth = fast = tests = 0
        for leaf in range(self.num_leaves):
            dep = int(self.leaf_depth[leaf])
            members = int(nrows[self.leaf_members[leaf]].sum())
            own = members if self.leaf_general[leaf] else int(self.leaf_fast[leaf].size)
            if self.group(leaf).size:
                own = int(nrows[self.group(leaf)].sum())
            depth = max(depth, dep)
            fast = max(fast, dep + own)
            tests = max(tests, dep + max(own, members))
        return {"depth": depth, "fast": fast, "tests": tests}

    def traverse_depths(self) -> np.ndarray:
        """Depth of each leaf found by walking the node table from the root (a check of
        ``leaf_depth``).

        Returns
        -------
        (L,) ndarray of int
        """
        out = np.full(self.num_leaves, -1, dtype=np.int64)
        if self.num_nodes == 0:
            out[:] = 0
            return out
        stack = [(0, 0)]
        while stack:
            k, dep = stack.pop()
            for child in self.node_next[k]:
                if child >= 0:
                    stack.append((int(child), dep + 1))
                else:
                    out[-1 - int(child)] = dep + 1
        return out


def _score(nl, nr, p: int, cellwise: bool):
    """The score of a split into ``nl`` and ``nr`` proper regions of ``p`` (lower is
    better): the larger side, then the sum (Tøndel et al.); the cell sort also charges
    each region copied into both children ``DUPLICATE_WEIGHT`` (a thin region crossed by
    many hyperplanes multiplies the leaves)."""
    worst = np.maximum(nl, nr)
    if cellwise:
        worst = worst + DUPLICATE_WEIGHT * np.maximum(nl + nr - p, 0)
    return worst * (2 * p + 1) + (nl + nr)


def _normalised(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    nrm = np.linalg.norm(A, axis=1)
    nrm[nrm == 0] = 1.0
    return A / nrm[:, None], b / nrm


def _canonical(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each unit row signed so that its largest entry in magnitude is positive (first on
    ties); returns the signed rows and the signs (+1 / -1)."""
    j = np.argmax(np.abs(A) + 1e-12 * np.arange(A.shape[1], 0, -1), axis=1)
    sign = np.where(A[np.arange(A.shape[0]), j] < 0, -1.0, 1.0)
    return A * sign[:, None], b * sign, sign


def _enlarged_vertices(
    A: np.ndarray, b: np.ndarray, off: np.ndarray, boxes: tuple[np.ndarray, np.ndarray],
    tally: dict | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Points whose convex hull contains each region enlarged by ``LOCATE_TOL``: its
    vertices when they are proved complete, else its box (widened).

    The vertices come from the row subsets (``packed_vertices``) for a region of at most
    ``SUBSET_MAX`` d-subsets of rows, else from Qhull's halfspace intersection
    (``hull_vertices``: its cost follows the vertices, not ``C(k, d)``); a subset
    enumeration that fails the check below is done again by Qhull. They are accepted
    when more than d, spanning the region's box, and closed under the polytope's edges
    (every edge leaving one ends at one: by Balinski's theorem they are all the
    vertices; ``vertices_kernel.closed_under_edges``). The subsets alone lose a vertex where
    its facets meet at a tiny angle (``|det| < DET_TOL``): in pop_mpqp_023 two vertices
    1.2 away from the rest while the others still spanned the box.

    A region that passes neither (a degenerate one: where many facets meet, the
    enlargement splits a vertex into a cluster ~1e-9 wide whose edges the check cannot
    follow; 12 of magnetic pointer A's 1,008 regions; ``tally["unproved"]``) takes its
    box: sound whatever vertex was lost, at the price of more leaves and LPs.

    A region whose vertices could be many (over ``HULL_MAX_VERTICES`` by the upper bound
    theorem: :func:`max_vertices`) and that the subsets did not settle is not given to
    Qhull: it takes its box too.

    Returns the points (V, d): the vertices where they are proved, points inside a
    boxed region else (``prune_kernel.inner_points``: they tell where it is, its box
    where it is not); the region of each (V,), non-decreasing; and the number of regions
    that fell back on their box (``tally["box"]``: which).
    """
    from codev_engine.geometry.vertices import _END_TOL, _LEAVE_TOL, DET_TOL, hull_vertices
    from codev_engine.geometry.vertices_kernel import closed_under_edges

    R = off.size - 1
    d = A.shape[1]
    An, bn = _normalised(A, b)
    # the enlarged region {A x <= b + tol} in unit rows
    nrm = np.linalg.norm(A, axis=1)
    nrm[nrm == 0] = 1.0
    be = bn + LOCATE_TOL / nrm
    V, owner, done = packed_vertices(An, be, off, 1e-10, rtol=1e-12, max_combos=SUBSET_MAX)
    lo, hi = boxes
    gap = 1e-6 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
    counts = np.bincount(owner, minlength=R)
    parts = np.split(V, np.cumsum(counts)[:-1])

    def spans(i: int, P: np.ndarray | None) -> bool:
        if P is None or P.shape[0] <= d:
            return False
        short = np.any(P.min(axis=0) > lo[i] + gap[i]) or np.any(P.max(axis=0) < hi[i] - gap[i])
        return not short

    def closed(i: int, P: np.ndarray) -> bool:
        Ai = np.ascontiguousarray(An[off[i] : off[i + 1]])
        bi = np.ascontiguousarray(be[off[i] : off[i + 1]])
        P = np.ascontiguousarray(P, dtype=float)
        return any(
            closed_under_edges(P, Ai, bi, t, DET_TOL, _LEAVE_TOL, _END_TOL) for t in (1e-10, 1e-9)
        )

    ok = np.zeros(R, dtype=bool)
    for i in range(R):
        ok[i] = bool(done[i]) and spans(i, parts[i]) and closed(i, parts[i])
    # Qhull only where the vertices can be few: its time follows them, and a region of
    # the quadrotor's region of operation (50-98 rows in d = 12, up to ~10^7 vertices by
    # the upper bound theorem) had not ended after 100 s; the others keep their box
    rows = np.diff(off)
    few = np.array([max_vertices(int(k), d) <= HULL_MAX_VERTICES for k in rows], dtype=bool)
    redo = np.flatnonzero(~ok & few)
    unproved = 0
    if redo.size:
        again, _ = hull_vertices(An, be, off, redo, 1e-10)
        for i, Q in zip(redo, again, strict=True):
            if spans(int(i), Q) and closed(int(i), Q):
                parts[i] = Q
                ok[i] = True
                continue
            # not proved (a degenerate region: vertices where many facets meet split into
            # clusters ~1e-9 apart by the enlargement, whose edges the check cannot
            # follow): its box, which holds it whatever vertex was lost (a lost
            # vertex beyond a hyperplane would drop the region from a side it reaches)
            unproved += 1
    unproved += int(np.count_nonzero(~ok & ~few))
    boxed = np.flatnonzero(~ok)
    if boxed.size:
        # a boxed region's points lie inside it (``prune_kernel.inner_points``): where it
        # is, never where it is not (its box's support, exact, says that; ``build_tree``)
        from codev_engine.deploy.prune_kernel import inner_points

        lo, hi = (np.asarray(x, dtype=float) for x in boxes)
        bound = float(np.abs(np.concatenate([lo[boxed], hi[boxed]])).max(initial=0.0)) + 1.0
        X, got = inner_points(np.ascontiguousarray(An), np.ascontiguousarray(be),
                              off.astype(np.int64), boxed.astype(np.int64),
                              np.ascontiguousarray(lo[boxed]), np.ascontiguousarray(hi[boxed]),
                              bound, 500)
        for q, i in enumerate(boxed):
            parts[i] = np.unique(X[q][got[q]], axis=0)
    if tally is not None:
        tally["unproved"] = unproved
        tally["box"] = ~ok
    pts, own = [np.zeros((0, d))], [np.zeros(0, dtype=np.int64)]
    for i in range(R):
        P = parts[i] if parts[i] is not None else np.zeros((0, d))
        pts.append(P)
        own.append(np.full(P.shape[0], i, dtype=np.int64))
    return np.concatenate(pts), np.concatenate(own), int(boxed.size)


def max_vertices(k: int, d: int) -> int:
    """The most vertices a polytope of ``k`` facets in ``d`` dimensions can have (the
    upper bound theorem, McMullen 1970: the cyclic polytope's count).

    Parameters
    ----------
    k, d : int

    Returns
    -------
    int
    """
    if k <= d:
        return 1 if k == d else 0
    h = d // 2
    if d % 2 == 0:
        return k * math.comb(k - h - 1, h - 1) // h if h else 1
    return 2 * math.comb(k - h - 1, h)


def build_tree(
    A: np.ndarray,
    b: np.ndarray,
    off: np.ndarray,
    boxes: tuple[np.ndarray, np.ndarray],
    *,
    prune: bool = True,
    sort: str = "cell",
    labels: np.ndarray | None = None,
    leaf_size: int = 1,
    stop_ratio: float | None = None,
    bucket_max: int = 0,
    budget: float = BUDGET,
    tries: int = TRIES,
) -> Tree:
    """The binary search tree of regions ``{theta : A[off[i]:off[i+1]] theta <= b[...]}``.

    Parameters
    ----------
    A : (N, d) ndarray
        The regions' stored rows, region after region.
    b : (N,) ndarray
    off : (R + 1,) ndarray of int
    boxes : (lo, hi), each (R, d) ndarray
        Bounding boxes of the regions (``ExplicitLaw.boxes``): the fallback for a region
        whose vertices cannot be trusted.
    prune : bool
        With ``sort="vertices"``: take off a leaf's member list every region that an LP
        proves apart from the leaf's cell (see :func:`_prune_members`).
    sort : {"cell", "vertices"}
        How a node sorts its regions into its children: by their part inside the node's
        cell (vertices first, an LP where they cannot decide; the default), or by all
        their vertices (the first version: a region crossing many hyperplanes is copied
        into many leaves).
    labels : (R,) ndarray of int, optional
        A label per region (equal labels: equal affine laws). A node whose proper regions
        all carry one label is not split further: its leaf's fast path runs the rule
        over those regions (``Tree.leaf_group``), so it still returns ``locate``'s region.
    leaf_size : int
        A node with at most this many proper regions is not split further either: its
        leaf checks them (a *bucket*, as a group leaf). 1: split down to one region. A
        few regions a leaf bound the worst case by their rows while the tree of a large
        partition has far fewer nodes (the last splits copy the most regions).
    stop_ratio : float, optional
        With the cell sort, a node of at most ``bucket_max`` proper regions is not split
        either (it becomes a bucket leaf, as above) when its best split leaves more than
        ``stop_ratio`` of them in the larger child: by the cell's vertices (an optimistic
        estimate, before any LP) or by the split's LPs. Where a thin region crosses
        every hyperplane that could split a node, each split copies most regions into
        both children and the tree multiplies its leaves without making them smaller
        (``pop_mpqp_083``: 13,266 regions in d = 5). None: split down to ``leaf_size``.
    bucket_max : int
        The largest node the stopping rule may turn into a leaf (see ``stop_ratio``).
    budget : float
        Vertex evaluations spent scoring a node's candidate hyperplanes (at least one
        chunk; ``BUDGET`` by default).
    tries : int
        Candidates confirmed by the LPs of their split, at most, before the best by all
        vertices (``TRIES`` by default).

    Returns
    -------
    Tree

    Raises
    ------
    TreeTooLargeError
        Past ``NODES_PER_REGION`` internal nodes per region or ``TIME_LIMIT`` CPU seconds
        of this process, or
        when the vertices of over a quarter of the regions cannot be enumerated.
    """
    import time

    t0 = time.perf_counter()
    c0 = time.process_time()
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    off = np.asarray(off, dtype=np.int64)
    labels = None if labels is None else np.asarray(labels, dtype=np.int64)
    R = off.size - 1
    d = A.shape[1]
    if sort not in ("cell", "vertices"):
        raise ValueError(f"unknown sort {sort!r}")
    cellwise = sort == "cell"
    _prepare_kernels()  # (``_enlarged_vertices`` may call one: ``inner_points``)
    vcounts: dict = {}
    V, owner, boxed = _enlarged_vertices(A, b, off, boxes, vcounts)
    if boxed > max(8, R // 4) and not cellwise:
        # boxes overlap wherever the regions are thin and oblique: the sort by hyperplanes
        # would copy most regions into most leaves (pop_mpqp_007, d = 8, 12,232 regions
        # of 22-45 rows: every region boxed, no tree after 10 minutes)
        raise TreeTooLargeError(
            f"the vertices of {boxed} of {R} regions could not be enumerated (too many "
            f"rows in {d} dimensions): no search tree (use the sequential search)"
        )
    vcount = np.bincount(owner, minlength=R)
    # the boxed regions (no points): their boxes widened as in ``_enlarged_vertices``,
    # as centre and radius (the support of a box along a row is exact: c.a +- r.|a|)
    isbox = np.asarray(vcounts.pop("box"), dtype=bool)
    blo, bhi = (np.asarray(x, dtype=float) for x in boxes)
    bpad = 1e-7 * (1.0 + np.maximum(np.abs(blo), np.abs(bhi)))
    box_c = np.ascontiguousarray(0.5 * ((blo - bpad) + (bhi + bpad)))
    box_r = np.ascontiguousarray(0.5 * ((bhi + bpad) - (blo - bpad)))
    box_r[~isbox] = -1.0  # (a region with points: not boxed, radius < 0)
    ends = [V] + [blo[isbox] - bpad[isbox], bhi[isbox] + bpad[isbox]]
    P_all = np.vstack(ends)
    pad = 1e-6 * (1.0 + np.abs(P_all).max(initial=1.0))
    box_lo = (P_all.min(axis=0) if P_all.shape[0] else np.zeros(d)) - pad
    box_hi = (P_all.max(axis=0) if P_all.shape[0] else np.zeros(d)) + pad
    xmax = float(np.abs(np.concatenate([box_lo, box_hi])).max(initial=0.0))

    # the candidate hyperplanes: the regions' rows, unit, signed canonically, deduplicated
    An, bn = _normalised(A, b)
    nrm = np.linalg.norm(A, axis=1)
    nrm[nrm == 0] = 1.0
    Ac, bc, sign = _canonical(An, bn)
    first = unique_rows(np.column_stack([Ac, bc]), 9)
    key_rows = np.column_stack([Ac, bc])
    H_A, H_b = Ac[first], bc[first]
    H = first.size
    # each row's hyperplane (rows equal to 9 decimals share one)
    from codev_engine.geometry.polytope import row_keys

    keys = row_keys(key_rows, 9)
    ukeys = keys[first]
    order = np.argsort(ukeys)
    pos = np.searchsorted(ukeys[order], keys)
    row_h = order[pos]

    # a region's extent along hyperplanes: min / max of s over its (enlarged) vertices,
    # computed per node for the candidates and regions at hand (no hyperplanes x regions
    # table: 10^4 regions have ~10^5 distinct facets)
    vend = np.cumsum(vcount)

    def extents(hs: np.ndarray, regs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if table is not None:
            return table[0][np.ix_(hs, regs)], table[1][np.ix_(hs, regs)]
        return extents_now(hs, regs)

    def extents_now(hs: np.ndarray, regs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cnt = vcount[regs]
        seg = np.cumsum(cnt) - cnt
        idx = np.repeat(vend[regs] - cnt - seg, cnt) + np.arange(int(cnt.sum()))
        S = H_A[hs] @ V[idx].T - H_b[hs][:, None]
        lo = np.full((hs.size, regs.size), np.inf)
        hi = np.full((hs.size, regs.size), -np.inf)
        has = cnt > 0
        if np.any(has):
            lo[:, has] = np.minimum.reduceat(S, seg[has], axis=1)
            hi[:, has] = np.maximum.reduceat(S, seg[has], axis=1)
        bx = isbox[regs]
        if np.any(bx):  # a boxed region: its box's support
            mid = H_A[hs] @ box_c[regs[bx]].T - H_b[hs][:, None]
            half = np.abs(H_A[hs]) @ box_r[regs[bx]].T
            lo[:, bx], hi[:, bx] = mid - half, mid + half
        eps = EPS * (1.0 + np.abs(H_b[hs]))[:, None]
        return lo / eps, hi / eps  # in units of eps: proper beyond -1 / 1, member within

    # a small law: every hyperplane against every region once (at most 64 MB)
    table = None
    if H * R <= TABLE_ENTRIES:
        table = extents_now(np.arange(H), np.arange(R))

    # the hyperplanes of each region (its facets' ids)
    region_h = [np.unique(row_h[off[i] : off[i + 1]]) for i in range(R)]

    max_nodes = NODES_PER_REGION * R + 1000
    nodes_a: list[np.ndarray] = []
    nodes_b: list[float] = []
    nodes_next: list[list[int]] = []
    leaves: list[tuple] = []

    def leaf(
        P: np.ndarray, M: np.ndarray, path: list[tuple[int, int]], general: bool,
        group: bool = False,
    ) -> int:
        members = np.union1d(P, M).astype(np.int64)
        if group:
            leaves.append([-1, False, np.zeros(0, dtype=np.int64), members, len(path),
                           list(path), np.sort(P).astype(np.int64)])
            return -1 - (len(leaves) - 1)
        own = int(P[0]) if P.size == 1 and not general else -1
        fast = np.zeros(0, dtype=np.int64)
        if own >= 0:
            rows = np.arange(off[own], off[own + 1])
            # a row equal to a tested hyperplane, on the side taken, is negative there
            # (equal to within a quarter of delta at the largest |theta| of the box)
            taken = {(h, side) for h, side in path}
            skip = np.zeros(rows.size, dtype=bool)
            for q, j in enumerate(rows):
                h = int(row_h[j])
                if (h, 0 if sign[j] > 0 else 1) in taken:
                    gap = np.abs(Ac[j] - H_A[h]).sum() * xmax + abs(bc[j] - H_b[h])
                    skip[q] = gap <= 0.25 * DELTA["double"] * (1.0 + abs(H_b[h]))
            fast = rows[~skip]
        leaves.append([own, general or P.size > 1, fast, members, len(path), list(path),
                       np.zeros(0, dtype=np.int64)])
        return -1 - (len(leaves) - 1)

    # the cell sort: the LPs' data (regions enlarged by tol, plus a rounding margin of
    # the violation's sum; the box of all regions)
    be_lp = bn + LOCATE_TOL / nrm + 1e-13 * (1.0 + np.abs(bn) + xmax)
    box_A = np.vstack([np.eye(d), -np.eye(d)])
    box_b = np.concatenate([box_hi, -box_lo])
    stats = {"retries": 0}

    def cell_rows(path: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        """The cell of a path, widened (every point that takes the path lies in it,
        rounding of ``s`` included)."""
        if not path:
            return np.zeros((0, d)), np.zeros(0), np.zeros(0)
        hs = np.array([h for h, _ in path], dtype=np.int64)
        sg = np.array([1.0 if side == 0 else -1.0 for _, side in path])
        wid = EPS * (1.0 + np.abs(H_b[hs])) + 1e-14 * xmax
        shrink = PROPER * (1.0 + np.abs(H_b[hs]))
        return (np.ascontiguousarray(H_A[hs] * sg[:, None]),
                np.ascontiguousarray(H_b[hs] * sg + wid),
                np.ascontiguousarray(H_b[hs] * sg - shrink))

    _prepare_kernels()
    from codev_engine.deploy.prune_kernel import (
        both_counts,
        cell_points,
        cuts,
        local_counts,
        split_node,
    )

    vstart = (vend - vcount).astype(np.int64)
    Vc = np.ascontiguousarray(V)
    An_c = np.ascontiguousarray(An)
    in_tol = 1e-9 * (1.0 + xmax)

    def split(h: int, allm: np.ndarray, inP: np.ndarray, CA, Cb, Cbp, W, Wn, memo):
        """Members and proper regions of both children (``prune_kernel.split_node``;
        ``W``, ``Wn``: the witnesses of ``allm``, updated; ``memo``: the splits tried at
        this node and its ancestors, nearest last, ``{h: (regions, split)}``: a region
        apart from a side there is apart here, where the cell is smaller)."""
        possible = None
        for tried_at in reversed(memo):
            if h in tried_at:
                regs, was = tried_at[h]
                possible = was[np.searchsorted(regs, allm)]
                break
        if possible is None:
            possible = np.ones((allm.size, 4), dtype=bool)
        got = split_node(
            Vc, vstart, vcount, box_c, box_r, allm, inP, CA, Cb, Cbp, in_tol, H_A[h], float(H_b[h]),
            EPS * (1.0 + abs(H_b[h])), PROPER * (1.0 + abs(H_b[h])), An_c, be_lp, off,
            box_A, box_b, xmax + 1.0, 500, W, Wn, possible,
        )
        memo[-1][h] = (allm, got)
        return got[:, 0], got[:, 1], got[:, 2], got[:, 3]

    # depth-first: (proper, members, path)
    def grow(P: np.ndarray, M: np.ndarray, path: list[tuple[int, int]], wit, memo) -> int:
        """The subtree of proper regions ``P`` and members ``M`` at the end of ``path``;
        ``wit``: the parent's regions and their witnesses (``prune_kernel.split_node``),
        or None at the root; ``memo``: the splits tried at the ancestors (``split``)."""
        if P.size <= 1:
            return leaf(P, M, path, False)
        if P.size <= leaf_size or (labels is not None and np.all(labels[P] == labels[P[0]])):
            return leaf(P, M, path, False, group=True)
        if len(path) >= MAX_DEPTH:
            return leaf(P, M, path, True)
        stoppable = stop_ratio is not None and P.size <= bucket_max
        used = {h for h, _ in path}
        cand = np.unique(np.concatenate([region_h[i] for i in P]))
        if used:
            cand = cand[~np.isin(cand, np.fromiter(used, dtype=np.int64))]
        if cand.size == 0:
            return leaf(P, M, path, True)
        CA, Cb, Cbp = cell_rows(path) if cellwise else (None, None, None)
        nvert = int(vcount[P].sum())
        # the candidates in chunks of at most ~min(2e7, budget) vertex evaluations (the
        # first chunks up to ``budget`` evaluations in all, at least one)
        per = int(np.clip(min(2e7, budget) / max(1, nvert), 16, 4096))
        allm = np.union1d(P, M)
        memo = memo + [{}]
        if wit is None:
            W = np.zeros((allm.size, WITNESSES, d))
            Wn = np.zeros(allm.size, dtype=np.int64)
        else:
            at = np.searchsorted(wit[0], allm)
            W, Wn = wit[1][at], wit[2][at]
        inP = np.isin(allm, P)
        # a large law (no table) scores only the candidates cutting the points known in
        # the cell (its regions' vertices and witnesses there): in a deep cell most of
        # the regions' facets pass by it; all of them if none of those splits. (A small
        # law scores them all: magnetic pointer A's tree took 27 more nodes filtered.)
        filt = cellwise and bool(path) and table is None
        if cand.size > per:
            cand = np.random.default_rng(len(nodes_b)).permutation(cand)

        def choose_both(keep: int, local: bool = True, filt: bool = False):
            """The best candidates, ``(score, worst, h)``, best first: by all vertices
            (the best one: an upper bound of its split, which the cell sort can only
            improve on) and, with ``local``, by those in the cell (the ``keep`` best: an
            estimate, to be confirmed). Score ``worst * (2 |P| + 1) + (nl + nr)`` over
            the counts of proper regions each side (``_score``). Without a table both
            come from one pass over the vertices (``prune_kernel.both_counts``)."""
            best_g: list[tuple[int, int, int]] = []
            best_l: list[tuple[int, int, int]] = []
            spent = 0

            def merge(best, nl, nr, chunk, k):
                worst = np.maximum(nl, nr)
                score = _score(nl, nr, P.size, cellwise)
                top = np.argsort(score, kind="stable")[:k]
                return sorted(
                    best + [(int(score[j]), int(worst[j]), int(chunk[j])) for j in top]
                )[:k]

            # (the points in the cell, for the filter, are found once a node)
            pts = cell_points(Vc, vstart, vcount, P, CA, Cb, in_tol, W, Wn) if filt else None
            for s0 in range(0, cand.size, per):
                chunk = cand[s0 : s0 + per]
                stats["candidates"] = stats.get("candidates", 0) + chunk.size
                if filt:
                    cut = cuts(pts, H_A, H_b, chunk, PROPER * (1.0 + np.abs(H_b[chunk])))
                    spent += chunk.size * pts.shape[0]
                    chunk = chunk[cut]
                    if chunk.size == 0:
                        continue
                stats["scored"] = stats.get("scored", 0) + chunk.size
                eps_c = (PROPER if cellwise else EPS) * (1.0 + np.abs(H_b[chunk]))
                if cellwise and table is None:
                    # (with no cell rows: every vertex counts)
                    nl, nr, nlc, nrc = both_counts(
                        Vc, vstart, vcount, box_c, box_r, P, CA, Cb, in_tol, H_A, H_b, chunk, eps_c
                    )
                    best_g = merge(best_g, nl, nr, chunk, 1)
                    if local:
                        best_l = merge(best_l, nlc, nrc, chunk, keep)
                else:
                    lo, hi = extents(chunk, P)
                    best_g = merge(best_g, (lo < -1.0).sum(axis=1), (hi > 1.0).sum(axis=1),
                                   chunk, 1)
                    if local:
                        nl, nr = local_counts(
                            Vc, vstart, vcount, box_c, box_r, P, CA, Cb, in_tol, H_A, H_b,
                            chunk, eps_c,
                        )
                        best_l = merge(best_l, nl, nr, chunk, keep)
                spent += chunk.size * nvert
                found = bool(best_g) and best_g[0][1] < P.size and (
                    not local or (bool(best_l) and best_l[0][1] < P.size))
                if found and (not cellwise or spent >= budget):
                    break
            return best_g, best_l

        def tried(h: int):
            got = split(h, allm, inP, CA, Cb, Cbp, W, Wn, memo)
            nl, nr = int(np.count_nonzero(got[1])), int(np.count_nonzero(got[3]))
            return int(_score(nl, nr, P.size, True)), max(nl, nr), h, got

        def pick(glob, loc):
            """The cell's estimates, best first, confirmed by the LPs of the split; then
            the best by all vertices (whose split is at least as good as its score)."""
            bound_g = glob[0][0] if glob and glob[0][1] < P.size else None
            best_o = None
            for q, (est, _, h) in enumerate(loc):
                if bound_g is not None and est >= bound_g:
                    break
                if q >= tries and best_o is not None:
                    break
                o = tried(h)
                if o[1] < P.size and (best_o is None or o[0] < best_o[0]):
                    best_o = o
                else:
                    stats["retries"] += 1
                nxt = loc[q + 1][0] if q + 1 < len(loc) else None
                if best_o is not None and (nxt is None or best_o[0] <= nxt):
                    break
            if bound_g is not None and (best_o is None or best_o[0] > bound_g):
                o = tried(glob[0][2])
                if best_o is None or o[0] < best_o[0]:
                    best_o = o
            return best_o

        glob, loc = choose_both(4 * tries, cellwise, filt)
        best_o = None
        if stoppable and loc and loc[0][1] > stop_ratio * P.size:
            stats["stopped_est"] = stats.get("stopped_est", 0) + 1
            return leaf(P, M, path, False, group=True)
        if filt:
            best_o = pick(glob, loc)
            if best_o is None or best_o[1] >= P.size:
                stats["uncut"] = stats.get("uncut", 0) + 1
                glob, loc = choose_both(4 * tries, cellwise)
                best_o = None
        if not cellwise:
            if not glob or glob[0][1] >= P.size:
                return leaf(P, M, path, True)
            h = glob[0][2]
            lo, hi = extents(np.array([h]), allm)
            sides = ((lo[0] <= 1.0, lo[0] < -1.0), (hi[0] >= -1.0, hi[0] > 1.0))
        else:
            if best_o is None:
                best_o = pick(glob, loc)
            if best_o is None or best_o[1] >= P.size:
                return leaf(P, M, path, True)
            _, worst, h, got = best_o
            if stoppable and worst > stop_ratio * P.size:
                stats["stopped"] = stats.get("stopped", 0) + 1
                return leaf(P, M, path, False, group=True)
            sides = ((got[0], got[1]), (got[2], got[3]))
        node = len(nodes_b)
        if node >= max_nodes or (node % 256 == 0 and time.process_time() - c0 > TIME_LIMIT):
            exc = TreeTooLargeError(
                f"the search tree for {R} regions in {d} dimensions would exceed "
                f"{max_nodes} nodes or {TIME_LIMIT:g} s of CPU ({node} nodes after "
                f"{time.process_time() - c0:.0f} s; use the sequential search)"
            )
            exc.stats = dict(stats, leaves=len(leaves))
            raise exc
        nodes_a.append(H_A[h])
        nodes_b.append(float(H_b[h]))
        nodes_next.append([0, 0])
        for side, (mem, prop) in enumerate(sides):
            Pc = allm[prop & inP]
            Mc = allm[mem & ~(prop & inP)]
            nodes_next[node][side] = grow(Pc, Mc, path + [(h, side)], (allm, W, Wn), memo)
        return node

    import sys

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * MAX_DEPTH + 1000))
    try:
        grow(np.arange(R, dtype=np.int64), np.zeros(0, dtype=np.int64), [], None, [])
    finally:
        sys.setrecursionlimit(limit)
    if prune and not cellwise:
        _prune_members(leaves, An, bn + LOCATE_TOL / nrm, off, H_A, H_b, box_lo, box_hi, xmax)
    node_next = np.array(nodes_next, dtype=np.int64).reshape(-1, 2)
    return Tree(
        d=d,
        node_a=np.array(nodes_a, dtype=float).reshape(-1, d),
        node_b=np.array(nodes_b, dtype=float),
        node_next=node_next,
        leaf_owner=np.array([lf[0] for lf in leaves], dtype=np.int64),
        leaf_general=np.array([lf[1] for lf in leaves], dtype=bool),
        leaf_fast=[lf[2] for lf in leaves],
        leaf_members=[lf[3] for lf in leaves],
        leaf_depth=np.array([lf[4] for lf in leaves], dtype=np.int64),
        box_lo=box_lo,
        box_hi=box_hi,
        row_off=off,
        seconds=time.perf_counter() - t0,
        leaf_group=[lf[6] for lf in leaves] if any(lf[6].size for lf in leaves) else [],
        stats={"hyperplanes": int(H), "vertices": int(V.shape[0]), "sort": sort, "boxed": boxed,
               **vcounts, **stats},
    )


def _prune_members(leaves, An, be, off, H_A, H_b, box_lo, box_hi, xmax) -> None:
    """Drop from each leaf's members the regions that cannot reach its cell.

    The vertices sort a region by one hyperplane at a time; a region may pass each test of
    a path and still miss the cell they cut out. A member is dropped when the largest ball
    in (the region enlarged by the locator's tolerance) and (the cell widened by
    ``1e-9 (1 + |b|)`` per test) and the box has a radius whose upper bound by weak
    duality (``lp_kernel.chebyshev``) is negative: the two are apart, whatever the LP's
    accuracy. On any doubt (an LP not solved) the member stays.
    """
    _prepare_kernels()
    from codev_engine.deploy.prune_kernel import apart

    d = An.shape[1]
    PAs, Pbs, plen, mems, mlen, owners = [], [], [], [], [], []
    for lf in leaves:
        path = lf[5]
        hs = np.array([h for h, _ in path], dtype=np.int64)
        sg = np.array([1.0 if side == 0 else -1.0 for _, side in path])
        PAs.append(H_A[hs] * sg[:, None])
        Pbs.append(H_b[hs] * sg + 1e-9 * (1.0 + np.abs(H_b[hs])))
        plen.append(hs.size)
        mems.append(lf[3])
        mlen.append(lf[3].size)
        owners.append(lf[0])
    members = np.concatenate(mems).astype(np.int64)
    drop = apart(
        np.ascontiguousarray(An), np.ascontiguousarray(be), off.astype(np.int64),
        np.ascontiguousarray(np.vstack(PAs)).reshape(-1, d), np.concatenate(Pbs),
        np.concatenate([[0], np.cumsum(plen)]).astype(np.int64), members,
        np.concatenate([[0], np.cumsum(mlen)]).astype(np.int64),
        np.array(owners, dtype=np.int64), np.vstack([np.eye(d), -np.eye(d)]),
        np.concatenate([box_hi, -box_lo]), 0.5 * (box_lo + box_hi), xmax + 1.0, 500,
    )
    start = 0
    for lf, k in zip(leaves, mlen, strict=True):
        lf[3] = lf[3][~drop[start : start + k]]
        start += k


def sequential_tree(
    A: np.ndarray, b: np.ndarray, off: np.ndarray, box_lo=None, box_hi=None
) -> Tree:
    """The degenerate tree of the sequential search: no test, one leaf checking every
    region in index order (the rule of ``locate`` over all of them).

    Parameters
    ----------
    A : (N, d) ndarray
        The regions' stored rows, region after region.
    b : (N,) ndarray
    off : (R + 1,) ndarray of int
    box_lo, box_hi : (d,) ndarray, optional
        Outside this box no region holds or is near a point; without it only a
        non-finite ``theta`` is turned away before the search.

    Returns
    -------
    Tree
    """
    d = np.asarray(A).shape[1]
    R = np.asarray(off).size - 1
    return Tree(
        d=d,
        node_a=np.zeros((0, d)),
        node_b=np.zeros(0),
        node_next=np.zeros((0, 2), dtype=np.int64),
        leaf_owner=np.array([-1]),
        leaf_general=np.array([True]),
        leaf_fast=[np.zeros(0, dtype=np.int64)],
        leaf_members=[np.arange(R, dtype=np.int64)],
        leaf_depth=np.array([0]),
        box_lo=None if box_lo is None else np.asarray(box_lo, dtype=float),
        box_hi=None if box_hi is None else np.asarray(box_hi, dtype=float),
        row_off=np.asarray(off, dtype=np.int64),
    )


def _prepare_kernels() -> None:
    """The tree's compiled kernels, prepared (announced, once per installation) when a tree
    first needs them: they are not among those prepared before the first command."""
    from codev_engine.kernel_cache import LATER, prepare

    prepare(groups=LATER)
