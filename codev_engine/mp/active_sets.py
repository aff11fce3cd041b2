"""The bookkeeping of the mp-QP active-set graph search, compiled with numba.

``mpqp.explore_active_sets`` walks a graph whose nodes are active sets. Once the compiled
kernel (``mpqp_kernel``) evaluates candidates, the Python side of the walk (a set of tuples
for the explored sets, a list as the stack, a loop over each candidate's moves) costs as
much as the evaluation of most candidates. Here an active set is a bitmask of ``W = ceil(m
/ 64)`` words; the explored sets live in an open-addressing hash table and the stack in an
array, and one call visits a whole batch of evaluated candidates.

The graph and the rules for its edges are those of ``mpqp.explore_active_sets`` (its
``visit``): the result does not depend on which of the two walks the search.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from codev_engine.mp.mpqp_kernel import EMPTY, FALLBACK, LICQ

__all__ = ["ActiveSetGraph", "licq_moves", "unpaired_rows"]

_ONE = np.uint64(1)


@njit(cache=True)
def _hash(key):
    """A 64-bit mix of the words of ``key`` (splitmix64 steps)."""
    h = np.uint64(0x9E3779B97F4A7C15)
    for t in range(key.size):
        h ^= key[t]
        h *= np.uint64(0xBF58476D1CE4E5B9)
        h ^= h >> np.uint64(31)
        h *= np.uint64(0x94D049BB133111EB)
        h ^= h >> np.uint64(29)
    return h


@njit(cache=True)
def _insert(table, used, key):
    """Add ``key`` to the table; False when it was there already. The table (a power of
    two in size) must have a free slot."""
    mask = table.shape[0] - 1
    i = np.int64(_hash(key) & np.uint64(mask))
    W = key.size
    while used[i]:
        same = True
        for t in range(W):
            if table[i, t] != key[t]:
                same = False
                break
        if same:
            return False
        i = (i + 1) & mask
    used[i] = True
    for t in range(W):
        table[i, t] = key[t]
    return True


@njit(cache=True)
def _rehash(table, used, size):
    """The keys of ``table`` in a new table of ``size`` slots."""
    new = np.zeros((size, table.shape[1]), dtype=np.uint64)
    new_used = np.zeros(size, dtype=np.bool_)
    for i in range(table.shape[0]):
        if used[i]:
            _insert(new, new_used, table[i])
    return new, new_used


@njit(cache=True)
def _push_if_new(table, used, stack, points, meta, key, point):
    if _insert(table, used, key):
        meta[0] += 1  # explored
        top = meta[1]
        for t in range(key.size):
            stack[top, t] = key[t]
        for t in range(point.size):
            points[top, t] = point[t]
        meta[1] = top + 1


@njit(cache=True)
def _visit(
    table, used, stack, points, meta, keys, status, moves, moves_off, swaps, swaps_off, nz,
    opposite, found, G, sigma, support, licq_moves,
):
    """Push the unexplored neighbours of a batch of evaluated candidates, each with the
    point its candidate found (where the neighbour's LPs start).

    Parameters
    ----------
    table, used : (cap, W) uint64, (cap,) bool
        The explored active sets.
    stack, points : (scap, W) uint64, (scap, d)
        The active sets still to evaluate, ``meta[1]`` of them, and their start points.
    meta : (2,) int64
        (explored count, stack top), updated.
    keys : (B, W) uint64
        The candidates.
    status : (B,) int64
        Their ``mpqp_kernel`` status (EMPTY and FALLBACK ones are skipped).
    moves, moves_off : (q,) int64, (B + 1,) int64
        Signed constraint ids of each candidate's neighbours (``+i+1``: i may leave,
        ``-(i+1)``: i may enter), candidate c's in ``moves[moves_off[c]:moves_off[c+1]]``.
    swaps, swaps_off : (s, 2) int64, (B + 1,) int64
        Pairs (i, j): i may enter as j leaves (``mpqp_kernel._swaps``), laid out as moves.
    nz : int
        Number of variables (an active set of more rows breaks LICQ).
    opposite : (m, W) uint64
        Bitmasks of the rows that cannot be active together with each row.
    found : (B, d)
        The candidates' points (``mpqp_kernel.evaluate``'s last result).
    G : (m, nz) ndarray
        The constraint rows (for the subsets of LICQ candidates, see ``_dependent_rows``).
    sigma, support : float
        ``mpqp.DEPENDENT_SIGMA`` and ``mpqp.SUPPORT_TOL``.
    licq_moves : bool
        The LICQ candidates' subsets are given as their moves (``+i+1``, ascending, from
        :func:`licq_moves`, computed where the batch was evaluated), not computed here.
    """
    W = keys.shape[1]
    new = np.empty(W, dtype=np.uint64)
    blocked = np.empty(W, dtype=np.uint64)
    for c in range(keys.shape[0]):
        st = status[c]
        if st == EMPTY or st == FALLBACK:
            continue
        key = keys[c]
        size = 0
        for t in range(W):
            w = key[t]
            while w:
                w &= w - _ONE
                size += 1
        if st == LICQ:
            # its subsets are the way on: those without a constraint of the support of a
            # null vector of its rows (mpqp.dependent_rows)
            if licq_moves:
                rows = moves[moves_off[c] : moves_off[c + 1]] - 1
            else:
                rows = _dependent_rows(G, key, size, sigma, support)
            for r in rows:
                new[:] = key
                new[r >> 6] &= ~(_ONE << np.uint64(r & 63))
                _push_if_new(table, used, stack, points, meta, new, found[c])
            continue
        for q in range(moves_off[c], moves_off[c + 1]):
            v = moves[q]
            if v > 0:
                i = v - 1
                new[:] = key
                new[i >> 6] &= ~(_ONE << np.uint64(i & 63))
                _push_if_new(table, used, stack, points, meta, new, found[c])
        if size >= nz + 1:
            continue
        blocked[:] = key
        for j in range(opposite.shape[0]):
            if (key[j >> 6] >> np.uint64(j & 63)) & _ONE:
                for s in range(W):
                    blocked[s] |= opposite[j, s]
        for q in range(moves_off[c], moves_off[c + 1]):
            v = moves[q]
            if v < 0:
                i = -v - 1
                bit = _ONE << np.uint64(i & 63)
                if blocked[i >> 6] & bit:
                    continue
                new[:] = key
                new[i >> 6] |= bit
                _push_if_new(table, used, stack, points, meta, new, found[c])
        for q in range(swaps_off[c], swaps_off[c + 1]):
            i, j = swaps[q, 0], swaps[q, 1]
            bit = _ONE << np.uint64(i & 63)
            if blocked[i >> 6] & bit:
                continue  # (as the plain move: A + i is never explored then)
            new[:] = key
            new[i >> 6] |= bit
            new[j >> 6] &= ~(_ONE << np.uint64(j & 63))
            _push_if_new(table, used, stack, points, meta, new, found[c])


@njit(cache=True)
def _dependent_rows(G, key, size, sigma, support):
    """``mpqp.dependent_rows`` of the active set ``key`` (of ``size`` constraints): the
    constraints whose removal the walk tries, ascending."""
    T = np.empty(size, dtype=np.int64)
    n = 0
    for t in range(key.size):
        w = key[t]
        while w:
            low = w & (~w + _ONE)
            w ^= low
            i = t * 64
            while low > _ONE:
                low >>= _ONE
                i += 1
            T[n] = i
            n += 1
    nz = G.shape[1]
    if n < 2:
        return T
    GT = np.empty((nz, n))
    for j in range(n):
        for t in range(nz):
            GT[t, j] = G[T[j], t]
    _, sv, Vt = np.linalg.svd(GT)
    if n <= nz and not sv[sv.size - 1] < sigma:
        return T
    vmax = 0.0
    for j in range(n):
        vmax = max(vmax, abs(Vt[n - 1, j]))
    out = np.empty(n, dtype=np.int64)
    q = 0
    for j in range(n):
        if abs(Vt[n - 1, j]) > support * vmax:
            out[q] = T[j]
            q += 1
    return out[:q]


class ActiveSetGraph:
    """Explored active sets and the stack of those still to evaluate, as bitmasks.

    Parameters
    ----------
    m : int
        Number of constraints.
    nz : int
        Number of variables.
    opposite : (m, m) bool ndarray
        ``opposite[i, j]``: rows i and j cannot be active together.
    start : (d,) ndarray, optional
        The start point of the sets seeded (each set pushed later carries the point of
        the candidate that pushed it).
    G : (m, nz) ndarray, optional
        The constraint rows: the subsets of an LICQ candidate visited are those of
        ``mpqp.dependent_rows`` with ``sigma`` and ``support`` (without it, every subset).
    sigma, support : float, optional
        ``mpqp.DEPENDENT_SIGMA`` and ``mpqp.SUPPORT_TOL`` (the defaults, -1, keep every
        subset).
    """

    def __init__(
        self, m: int, nz: int, opposite: np.ndarray, start: np.ndarray | None = None,
        G: np.ndarray | None = None, sigma: float = -1.0, support: float = -1.0,
    ):
        self.m, self.nz = m, nz
        self.G = np.eye(m, max(nz, 1)) if G is None else np.ascontiguousarray(G, dtype=float)
        self.sigma = float(sigma) if G is not None else -1.0
        self.support = float(support) if G is not None else -1.0
        self.W = (m + 63) // 64
        self.start = np.zeros(1) if start is None else np.asarray(start, dtype=float)
        self.table = np.zeros((1 << 12, self.W), dtype=np.uint64)
        self.used = np.zeros(1 << 12, dtype=np.bool_)
        self.stack = np.zeros((1 << 10, self.W), dtype=np.uint64)
        self.points = np.zeros((1 << 10, self.start.size))
        self.meta = np.zeros(2, dtype=np.int64)  # explored, stack top
        self.opposite = np.stack([self.key(np.flatnonzero(row)) for row in opposite])

    def key(self, act) -> np.ndarray:
        """The bitmask of an active set: bit ``i`` of the words set for each constraint i.

        Parameters
        ----------
        act : iterable of int
            The active set's constraint ids (in ``range(m)``).

        Returns
        -------
        (W,) ndarray of uint64
        """
        key = np.zeros(self.W, dtype=np.uint64)
        for i in act:
            key[int(i) >> 6] |= np.uint64(1) << np.uint64(int(i) & 63)
        return key

    @property
    def explored(self) -> int:
        """How many distinct active sets have been pushed (or seeded) so far."""
        return int(self.meta[0])

    def __len__(self) -> int:
        """Active sets on the stack."""
        return int(self.meta[1])

    def reserve(self, n: int) -> None:
        """Room for ``n`` more explored sets (table at most half full) and stack entries.

        Parameters
        ----------
        n : int
            The number of sets about to be added.
        """
        need = self.meta[0] + n
        if 2 * need > self.table.shape[0]:
            size = self.table.shape[0]
            while 2 * need > size:
                size *= 2
            self.table, self.used = _rehash(self.table, self.used, size)
        need = self.meta[1] + n
        if need > self.stack.shape[0]:
            size = self.stack.shape[0]
            while need > size:
                size *= 2
            grown = np.zeros((size, self.W), dtype=np.uint64)
            grown[: self.meta[1]] = self.stack[: self.meta[1]]
            self.stack = grown
            points = np.zeros((size, self.start.size))
            points[: self.meta[1]] = self.points[: self.meta[1]]
            self.points = points

    def seed(self, explored, stack) -> None:
        """Take over a search begun elsewhere: the active sets ``explored`` (an iterable
        of tuples, ``stack`` among them) are known, those of ``stack`` are still to
        evaluate.

        Parameters
        ----------
        explored : iterable of tuple of int
            The active sets explored so far (``stack`` among them).
        stack : sequence of tuple of int
            The active sets still to evaluate; each gets the graph's ``start`` point.
        """
        explored = list(explored)
        self.reserve(len(explored) + len(stack))
        for act in explored:
            _insert(self.table, self.used, self.key(act))
        self.meta[0] = len(explored)
        for i, act in enumerate(stack):
            self.stack[i] = self.key(act)
            self.points[i] = self.start
        self.meta[1] = len(stack)

    def pop(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Take the newest ``n`` (or fewer) active sets off the stack.

        Parameters
        ----------
        n : int
            At most this many.

        Returns
        -------
        keys : (b, W) ndarray of uint64
            Their bitmasks, ``b = min(n, len(self))``.
        points : (b, d) ndarray
            Their start points.
        """
        top = int(self.meta[1])
        b = min(n, top)
        keys = self.stack[top - b : top].copy()
        points = self.points[top - b : top].copy()
        self.meta[1] = top - b
        return keys, points

    def visit(
        self, keys, status, moves, moves_off, swaps, swaps_off, found=None, licq_moves=False
    ) -> None:
        """Push the unexplored neighbours of evaluated candidates (see ``_visit``).

        Parameters
        ----------
        keys : (B, W) ndarray of uint64
            The candidates' bitmasks.
        status : (B,) ndarray of int64
            Their ``mpqp_kernel`` status (EMPTY and FALLBACK ones have no neighbours).
        moves, moves_off : (q,) and (B + 1,) ndarray of int64
            Signed constraint ids of each candidate's neighbours (``+i+1``: i may leave,
            ``-(i+1)``: i may enter), candidate c's in ``moves[moves_off[c]:moves_off[c+1]]``.
        swaps, swaps_off : (s, 2) and (B + 1,) ndarray of int64
            Pairs (i, j): i may enter as j leaves, laid out as ``moves``.
        found : (B, d) ndarray, optional
            The candidates' points, where their neighbours' LPs start; without it, the
            graph's ``start`` point.
        licq_moves : bool
            The LICQ candidates' moves are their subsets to visit (:func:`licq_moves`), not
            to be computed here.
        """
        if found is None:
            found = np.broadcast_to(self.start, (keys.shape[0], self.start.size)).copy()
        # a move per constraint at most, and nz swaps for each
        self.reserve(keys.shape[0] * (self.m + 1) * (self.nz + 1))
        _visit(
            self.table,
            self.used,
            self.stack,
            self.points,
            self.meta,
            keys,
            status,
            moves,
            moves_off,
            swaps,
            swaps_off,
            self.nz,
            self.opposite,
            np.ascontiguousarray(found, dtype=float),
            self.G,
            self.sigma,
            self.support,
            bool(licq_moves),
        )


def licq_moves(keys, status, moves, moves_off, G, sigma, support):
    """A batch's moves with each LICQ candidate's subsets to visit as its moves (``+i+1``
    for each row ``i`` that :func:`_dependent_rows` lets leave, ascending): what
    ``ActiveSetGraph.visit(..., licq_moves=True)`` takes, so that the SVDs run where the
    batch was evaluated, not where the graph is.

    Parameters
    ----------
    keys : (B, W) ndarray of uint64
        The candidates' bitmasks.
    status : (B,) ndarray of int64
        Their ``mpqp_kernel`` status.
    moves, moves_off : (q,) and (B + 1,) ndarray of int64
        The batch's moves (an LICQ candidate has none).
    G : (m, nz) ndarray
        The constraint rows.
    sigma, support : float
        ``mpqp.DEPENDENT_SIGMA`` and ``mpqp.SUPPORT_TOL``.

    Returns
    -------
    moves, moves_off : (q',) and (B + 1,) ndarray of int64
    """
    licq = np.flatnonzero(status == LICQ)
    if not licq.size:
        return moves, moves_off
    G = np.ascontiguousarray(G, dtype=float)
    segments, off = [], np.zeros(status.size + 1, dtype=np.int64)
    for c in range(status.size):
        if status[c] == LICQ:  # (its moves, if any, are not the walk's: replaced)
            key = keys[c]
            size = sum(bin(int(w)).count("1") for w in key)
            seg = _dependent_rows(G, key, size, float(sigma), float(support)) + 1
        else:
            seg = moves[moves_off[c] : moves_off[c + 1]]
        segments.append(seg)
        off[c + 1] = off[c] + seg.size
    return np.concatenate(segments).astype(np.int64, copy=False), off


@njit(cache=True)
def unpaired_rows(A, b, decimals):
    """The rows ``(A_i, b_i)`` that are the first of their kind and whose negation is no
    row: the facets of a partition's regions that no neighbour shares. Rows are compared
    rounded to ``decimals``.

    The rounded rows are not stored but made again where hashes match: on
    ``pop_mpqp_024``'s 10M rows storing them cost more in fresh memory (~600 MB) than
    the rounding does.

    Parameters
    ----------
    A : (n, d) ndarray
    b : (n,) ndarray
    decimals : int

    Returns
    -------
    (n,) bool ndarray
    """
    n, d = A.shape
    f = 10.0**decimals
    key = np.empty(d + 1)
    h = np.empty(n, dtype=np.uint64)
    for i in range(n):
        h[i] = _rounded_hash(A, b, i, f, 1.0, key)
    # (at most 80% full, and far less as a rule: each shared facet is one entry for two
    # rows and the parameter set's rows one for all regions; int32 indices, as 2**31 rows
    # would take 100 GB: a smaller table is one that stays in cache)
    cap = 1
    while 4 * cap < 5 * n:
        cap *= 2
    slots = np.full(cap, -1, dtype=np.int32)
    first = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        _rounded_hash(A, b, i, f, 1.0, key)
        j = _probe(slots, A, b, f, h, h[i], key)
        if slots[j] < 0:
            slots[j] = i
            first[i] = True
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if first[i]:
            hq = _rounded_hash(A, b, i, f, -1.0, key)
            out[i] = slots[_probe(slots, A, b, f, h, hq, key)] < 0
    return out


@njit(cache=True)
def _rounded_hash(A, b, i, f, sign, key):
    """``key`` = ``sign`` times row i rounded (times ``f``, to integers, and back; -0.0
    made +0.0), and its hash."""
    d = A.shape[1]
    for t in range(d + 1):
        v = A[i, t] if t < d else b[i]
        key[t] = sign * (np.rint(v * f) / f) + 0.0
    return _hash(key.view(np.uint64))


@njit(cache=True)
def _probe(slots, A, b, f, h, hq, key):
    """The slot of the table ``slots`` (row indices, their hashes ``h``) holding the
    rounded row ``key`` (hash ``hq``), or the free slot where it would go."""
    mask = slots.size - 1
    j = np.int64(hq & np.uint64(mask))
    d = A.shape[1]
    while slots[j] >= 0:
        s = slots[j]
        if h[s] == hq:
            same = True
            for t in range(d + 1):
                v = A[s, t] if t < d else b[s]
                if np.rint(v * f) / f != key[t]:
                    same = False
                    break
            if same:
                return j
        j = (j + 1) & mask
    return j
