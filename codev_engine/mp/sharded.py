"""The mp-QP active-set search sharded across a Dask cluster: the regions stay on the workers.

Today's distributed search (``mpqp._CompiledWalk.run`` with an executor) sends every
region back to the client, which walks the graph: its CPU per region caps the speed-up
(issue 43). Here the walk's state is split into ``n`` *shards* (one per worker at the
start): an active set belongs to the shard its key hashes to (:func:`owners`, the high bits
of the walk's own splitmix hash). A shard holds the explored active sets it owns, its
frontier (a stack with each set's start point) and its regions. The search goes in
**rounds**: in round ``r`` every shard takes the keys the others sent it in round ``r - 1``
(new ones join its frontier), evaluates up to ``budget`` candidates of its frontier with
the compiled kernel, pushes the neighbours it owns on its own stack and puts the others'
in its outbox (keys and start points only). The client submits one task per shard and
round and gets back a few counters; it never sees a region or a key. It stops when no
shard has a frontier and none sent a key.

Each round a shard writes one *checked* file of what it changed (its new regions, its new
explored keys, the top of its stack above the lowest point the round reached) and one of
its outboxes: atomic (``os.replace`` of a
fsynced temporary file) with a SHA-256 of the arrays in the file, so a torn or corrupted
shard is refused on reading (``SolverError``), never merged. A worker caches its shards in
memory; a shard's round that runs elsewhere (its worker was killed, the scheduler moved the
task) rebuilds the shard from its files: nothing is lost, and a round run twice writes the
same files (a shard's own state does not depend on what it cached of the others' keys).
The files need a directory every worker can write (a local cluster: any; a remote one: a
shared file system).

**Order.** The serial walk is depth first; its order decides the regions' numbering and the
point each candidate's LPs start from (the point of the candidate that pushed it first).
Neither decides a region. Where it once did: a thin region (inscribed radius near the
region tolerance) was proved full by the compiled kernel from some start points and not
from others, and the numpy kernel (HiGHS at its default tolerance 1e-7) found it no
checked centre: chain5's partition had 1,392 to 1,402 regions by how the search ran
(numpy kernel, compiled, Dask, sharded on 1 or 2 workers). Now the compiled kernel decides
only with a proof ``mpqp.CLOSE_CALL`` clear of the tolerance, and hands every close call to
the numpy kernel, whose decision is a function of the active set alone (no start point,
HiGHS at fixed tolerances: ``mpqp._Kernel._chebyshev``). So each candidate's class is the
same however the walk is split, and so is the set of regions reached (1,407 on chain5,
every way: ``tests/engine/test_mpqp_same.py``). What the order still moves: the
*candidates* and *explored* counters (a lower-dimensional candidate's neighbours are the
constraints tight at the point its LP found), a region's rows where one is redundant by
less than the proof's margin, and the last bits of rows and laws where one kernel computed
them and not the other. The numbering is made canonical at the end: the regions are sorted
by active set (``RegionArrays.active_order``) before the laws are merged
(``mpqp._merge_equal_laws``).

**The end** (with ``finish``: the workers write the law): the regions are re-partitioned by
space on the workers (``shard_space``): the law's shard ``c`` holds the regions whose
centre lies in the ``c``-th cell of a k-d split, so a question about a point reads the one
or two shards near it. The client gets a sample of centres and sends the cuts, never a region.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import CancelledError
from pathlib import Path

import numpy as np
from numba import njit

from codev_engine.errors import SolverError
from codev_engine.mp.active_sets import _hash, _insert, _push_if_new
from codev_engine.mp.shard_files import _read, _read_parts, _write
from codev_engine.mp.solution import RegionArrays, TooManyRegionsError, too_many_regions

__all__ = ["owners", "read_shards", "sharded_walk"]

#: candidates a shard evaluates in one round at most (~0.3 s of work: a round costs the
#: client one task per shard, a few ms)
BUDGET = 4096
#: times a round is submitted before the search gives up (its tasks cancelled each time)
_ATTEMPTS = 3
#: a benchmark's prefix (``benchmarks/scale.py --stop-at``): the rounds end once this many
#: regions are found and the end (the merge, or the workers' law shards) runs on them; not
#: a law of the program (part of the parameter set is not covered). None: the whole search
STOP_AT: int | None = None
#: candidates per call of the compiled kernel (as ``mpqp._CHUNK``)
_CHUNK = 64

# the worker side's shards, by (directory, shard): (round, _Shard)
_CACHE: dict[tuple[str, int], tuple[int, object]] = {}


@njit(cache=True)
def _owners(keys, n):
    out = np.empty(keys.shape[0], dtype=np.int64)
    for c in range(keys.shape[0]):
        # the high bits: the tables index with the low ones (a shard's keys all sharing
        # their low bits would crowd its table)
        out[c] = np.int64((_hash(keys[c]) >> np.uint64(32)) % np.uint64(n))
    return out


def owners(keys: np.ndarray, n: int) -> np.ndarray:
    """The shard each active set belongs to.

    Parameters
    ----------
    keys : (B, W) ndarray of uint64
        Active sets as bitmasks (``active_sets.ActiveSetGraph.key``).
    n : int
        Number of shards.

    Returns
    -------
    (B,) ndarray of int64
        In ``range(n)``.
    """
    return _owners(np.ascontiguousarray(keys, dtype=np.uint64), np.int64(n))


@njit(cache=True)
def _receive(table, used, stack, points, meta, keys, pts):
    """Push the keys not yet in the table (``_push_if_new`` for each); how many were new."""
    before = meta[0]
    for c in range(keys.shape[0]):
        _push_if_new(table, used, stack, points, meta, keys[c], pts[c])
    return meta[0] - before


@njit(cache=True)
def _insert_all(table, used, keys):
    for c in range(keys.shape[0]):
        _insert(table, used, keys[c])


# -- a shard ----------------------------------------------------------------------------------


class _Shard:
    """A shard's walk: an ``mpqp._CompiledWalk`` whose graph holds the shard's explored
    active sets (and, as a cache, the others' keys it has sent) and its frontier."""

    def __init__(self, shared: tuple, j: int, n: int, directory: str):
        # (the walk's class comes with the shared data: mpqp imports this module)
        self.args, opposite, kernel, walk_class = shared
        self.j, self.n, self.dir = j, n, Path(directory)
        self.stats: dict = {}
        self.walk = walk_class(kernel, opposite, set(), [], [], self.stats)
        self.graph = self.walk.graph
        self.found = 0  # regions written so far
        self.seeded: list[np.ndarray] = []  # keys given at the start, written in round 0

    def seed(self, keys: np.ndarray, points: np.ndarray, done: np.ndarray) -> None:
        """Start from the active sets ``keys`` to evaluate (from ``points``) and ``done``,
        evaluated already (the search's serial start); round 0 writes both as explored."""
        g = self.graph
        g.reserve(keys.shape[0] + done.shape[0])
        _insert_all(g.table, g.used, done)
        g.meta[0] += done.shape[0]
        _receive(g.table, g.used, g.stack, g.points, g.meta, keys, points)
        self.seeded = [done, keys]

    def restore(self, r: int) -> None:
        """The shard as it was after round ``r`` (from its files: the explored keys, and
        the stack replayed from each round's change to it)."""
        g = self.graph
        top = 0
        for q in range(r + 1):
            part = _read(self.dir / f"{self.j}" / f"part-{q}.npz")
            g.reserve(part["explored"].shape[0] + part["stack"].shape[0])
            _insert_all(g.table, g.used, part["explored"])
            g.meta[0] += part["explored"].shape[0]
            self.found += int(part["K"].shape[0])
            if part["shared_A"].shape[0] and self.walk.shared is None:
                self.walk.shared = (part["shared_A"], part["shared_b"])
            # the round kept its stack up to ``stack_low`` and put these on it
            low, keys = int(part["stack_low"]), part["stack"]
            if low > top:
                raise SolverError(f"{self.dir / str(self.j)}: shard files out of order")
            g.stack[low : low + keys.shape[0]] = keys
            g.points[low : low + keys.shape[0]] = part["points"]
            top = low + keys.shape[0]
            g.meta[1] = top

    def round(self, r: int, inbox: list[tuple[np.ndarray, np.ndarray]], budget: int) -> dict:
        """Take the keys sent to this shard, evaluate up to ``budget`` candidates, write
        the round's files; the round's counters."""
        from codev_engine.mp import mpqp_kernel

        g, walk = self.graph, self.walk
        new_keys, self.seeded = self.seeded, []
        explored0 = g.explored
        low0 = len(g) if r else 0  # (round 0: its seeds are on the stack)
        for keys, points in inbox:
            if keys.shape[0]:
                g.reserve(keys.shape[0])
                top = len(g)
                _receive(g.table, g.used, g.stack, g.points, g.meta, keys, points)
                new_keys.append(g.stack[top : len(g)].copy())
        received = g.explored - explored0
        outbox = [[] for _ in range(self.n)]
        evaluated = 0
        # the stack below ``low`` is not touched this round: only the rest is written (a
        # frontier of a million sets is not rewritten for each 4096 candidates)
        low = low0
        while len(g) and evaluated < budget:
            keys, starts = g.pop(_CHUNK)
            low = min(low, len(g))
            evaluated += keys.shape[0]
            result = mpqp_kernel.evaluate_batch(keys, starts, self.args)
            top = len(g)
            walk._take(keys, result)
            # the neighbours pushed: this shard's stay on its stack, the others' go out
            pk, pp = g.pop(len(g) - top)
            own = owners(pk, self.n)
            for i in np.unique(own):
                sel = own == i
                if i == self.j:
                    k = int(np.count_nonzero(sel))
                    g.stack[len(g) : len(g) + k] = pk[sel]
                    g.points[len(g) : len(g) + k] = pp[sel]
                    g.meta[1] += k
                    new_keys.append(pk[sel])
                else:
                    outbox[i].append((pk[sel], pp[sel]))
        W, d = g.W, g.start.size
        parts = walk.chunks + walk.parts
        walk.chunks, walk.parts = [], []
        nz = walk.kernel.nz
        regions = RegionArrays.concat(parts) if parts else RegionArrays(
            np.zeros((0, d)), np.zeros(0), np.zeros(1, np.int64), np.zeros((0, nz, d)),
            np.zeros((0, nz)), np.zeros(0, np.int64), np.zeros(1, np.int64))
        shared = walk.shared or (np.zeros((0, d)), np.zeros(0))
        explored = np.concatenate(new_keys) if new_keys else np.zeros((0, W), np.uint64)
        folder = self.dir / f"{self.j}"
        folder.mkdir(parents=True, exist_ok=True)
        _write(folder / f"part-{r}.npz", {
            "A": regions.A, "b": regions.b, "offsets": regions.offsets, "K": regions.K,
            "k": regions.k, "active": regions.active, "active_offsets": regions.active_offsets,
            "implied": regions.implied, "shared_A": shared[0], "shared_b": shared[1],
            "explored": explored, "stack_low": np.array(low), "stack": g.stack[low : len(g)],
            "points": g.points[low : len(g)],
        })
        flow = {}
        sent = 0
        for i in range(self.n):
            ks = [k for k, _ in outbox[i]]
            ps = [p for _, p in outbox[i]]
            flow[f"keys_{i}"] = np.concatenate(ks) if ks else np.zeros((0, W), np.uint64)
            flow[f"points_{i}"] = np.concatenate(ps) if ps else np.zeros((0, d))
            sent += flow[f"keys_{i}"].shape[0]
        _write(folder / f"flow-{r}.npz", flow)
        old = folder / f"flow-{r - 2}.npz"  # (every shard has read it: round r-1 is done)
        if old.exists():
            old.unlink()
        self.found += len(regions)
        return {"found": len(regions), "frontier": len(g), "sent": sent,
                "received": received, "evaluated": evaluated, "explored": explored.shape[0]}


def _round(shared, directory: str, j: int, n: int, r: int, budget: int, seed) -> tuple:
    """Worker side: shard ``j``'s round ``r`` (its cached walk, else rebuilt from files);
    (counters, stats, the worker's address, CPU seconds)."""
    t0 = time.process_time()
    cached = _CACHE.pop((directory, j), None)
    restored = 0
    if cached is not None and cached[0] == r - 1:
        shard = cached[1]
    else:
        restored = int(r > 0)
        shard = _Shard(shared, j, n, directory)
        if r == 0:
            shard.seed(*seed)
        else:
            shard.restore(r - 1)
    inbox = []
    if r > 0:
        for i in range(n):
            flow = _read(Path(directory) / f"{i}" / f"flow-{r - 1}.npz")
            inbox.append((flow[f"keys_{j}"], flow[f"points_{j}"]))
    shard.stats.clear()
    counts = shard.round(r, inbox, budget)
    counts["restored"] = restored
    _CACHE[(directory, j)] = (r, shard)
    try:
        from distributed import get_worker

        where = get_worker().address
    except (ImportError, ValueError):  # pragma: no cover - not on a worker
        where = None
    return counts, dict(shard.stats), where, time.process_time() - t0


def cached_shards() -> int:
    """Worker side: how many shards this process holds in memory (any search)."""
    return len(_CACHE)


def _forget(directory: str) -> int:
    """Worker side: drop the cached shards of a search."""
    from codev_engine.mp.shard_space import forget

    gone = [key for key in _CACHE if key[0] == directory]
    for key in gone:
        del _CACHE[key]
    return len(gone) + forget(directory)


def read_shards(directory: str | os.PathLike) -> RegionArrays:
    """Every region of a sharded search's files, in canonical order (by active set).

    Parameters
    ----------
    directory : path
        The search's directory (a folder per shard of checked ``part-<round>.npz`` files).

    Returns
    -------
    RegionArrays
        Sorted by active set (the same whatever the number of shards).

    Raises
    ------
    SolverError
        A shard file that is unreadable or fails its checksum.
    """
    parts = []
    for folder in sorted(Path(directory).iterdir(), key=lambda p: p.name):
        if folder.is_dir():
            parts += _read_parts(folder)
    if not parts:
        return None
    out = RegionArrays.concat(parts)
    return out.take(out.active_order())


def _finish_on_workers(client, directory: str, n: int, regions: list, g, kernel,
                       where: dict, merge, finish, totals: dict) -> list[tuple]:
    """The law's shards written by the workers, the regions re-partitioned by space on the
    way (``shard_space.end_by_space``); the given regions (the few hundred found before the
    walk was sharded) each to the hash shard that owns it."""
    from codev_engine.mp.shard_space import end_by_space

    seeds = RegionArrays.from_regions(regions, kernel.nz, kernel.d)
    keys = (np.stack([g.key(a) for a in (r.active for r in regions)]) if regions
            else np.zeros((0, g.W), np.uint64))
    own = owners(keys, n)
    return end_by_space(client, directory, n,
                        [seeds.take(np.flatnonzero(own == j)) for j in range(n)], where,
                        np.asarray(kernel.box[0], float), float(kernel.bound), merge, finish,
                        totals, _gather_retrying)


def _gather_retrying(client, submit: Callable[[int], list], what: str, totals: dict,
                     on_retry: Callable[[], None] | None = None) -> list:
    """The results of the tasks ``submit(attempt)`` gives, submitted again (at most
    ``_ATTEMPTS`` times in all) when the scheduler cancels them: a worker killed between
    rounds can leave the scheduler without a round's tasks ("already forgotten"; seen on a
    loaded machine). A task run again gives the same files (a shard whose round ran
    already is rebuilt from its files up to the round before)."""
    for attempt in range(_ATTEMPTS):
        futures = submit(attempt)
        try:
            return client.gather(futures)
        except CancelledError:
            if attempt == _ATTEMPTS - 1:
                raise SolverError(f"the sharded search's {what} was cancelled "
                                  f"{_ATTEMPTS} times (workers lost?)") from None
            totals["rounds_retried"] = totals.get("rounds_retried", 0) + 1
            if on_retry is not None:
                on_retry()
        finally:
            # (released: a worker lost later must not make the scheduler run an old round
            # again, which would leave a stale shard in a worker's memory)
            del futures
    raise AssertionError("unreachable")


def sharded_walk(kernel, opposite: dict, explored: set, stack: list, regions: list,
                 stats: dict, executor, max_regions: int, progress=None,
                 directory: str | None = None, budget: int | None = None, *,
                 walk_class: type, warm, finish=None, merge=None
                 ) -> RegionArrays | list[tuple]:
    """The rest of an mp-QP search (``mpqp.explore_active_sets`` once the compiled kernel
    runs), sharded across the executor's workers.

    Parameters
    ----------
    kernel : mpqp._Kernel
        Its compiled kernel started (``start_jit``).
    opposite : dict of int to set of int
        Rows that cannot be active together.
    explored : set of tuple of int
        The active sets explored so far (``stack`` among them).
    stack : list of tuple of int
        The active sets still to evaluate (from the parameter box's centre).
    regions : list of CriticalRegion
        The regions found so far (kept here: a few hundred).
    stats : dict
        Updated with the search's counters (summed over the shards) and ``shards``,
        ``rounds``, ``client_cpu_seconds``, ``setup_client_cpu_seconds`` (this process
        before the first round), ``rounds_client_cpu_seconds`` (during the rounds),
        ``worker_cpu_seconds``, ``shards_restored``
        (rounds whose shard was rebuilt from its files: its worker was lost),
        ``rounds_retried`` (rounds whose tasks the scheduler cancelled, submitted again).
    executor : Executor
        A Dask one (local or remote).
    max_regions : int
        ``TooManyRegionsError`` once more are found (checked after each round).
    progress : callable, optional
        Called with the regions found so far after each round.
    directory : str, optional
        The folder in which the shards' files go (in a fresh folder, removed at the end):
        every worker must reach it (a remote cluster: a shared file system); default the
        system's temporary folder.
    budget : int, optional
        Candidates a shard evaluates per round at most (default ``BUDGET``).
    walk_class : type
        ``mpqp._CompiledWalk``, the walk each shard runs (given, not imported: mpqp
        imports this module, and the import graph has no circles).
    warm : callable
        ``mpqp._warm_worker``, run once on every worker before the first round.
    finish : callable, optional
        ``finish(regions, c) -> answer``, run on the workers at the end, once per *cell*
        of space (as many as shards: the regions re-partitioned by their centres,
        ``shard_space``), with the cell's regions (sorted by active set, equal laws merged
        by ``merge``): it writes the law's shard ``c`` where the regions are. Then no
        region comes back to this process.
    merge : callable, optional
        ``merge(regions, stats) -> regions`` (with ``finish``): ``mpqp._merge_equal_laws``
        on one cell (regions of equal laws in different cells stay apart: the law is the
        same function).

    Returns
    -------
    RegionArrays or list of tuple
        Every region (the ones given and the shards'), sorted by active set; with
        ``finish``, its answer for each cell with the cell's merge stats, its number
        of regions before the merge and the cell: ``(answer, stats, regions, (lo, hi))``.
    """
    import copy

    from codev_engine.mp.active_sets import ActiveSetGraph

    cpu0 = time.process_time()
    budget = BUDGET if budget is None else int(budget)
    client = executor.client
    workers = sorted(client.scheduler_info()["workers"])
    if not workers:
        raise SolverError("the sharded search found no Dask worker on its cluster")
    n = len(workers)
    if directory is not None:
        Path(directory).mkdir(parents=True, exist_ok=True)
    # (a fresh folder: files of an earlier search in the same place are never read)
    directory = tempfile.mkdtemp(prefix="codev-shards-", dir=directory)
    numpy_kernel = copy.copy(kernel)
    numpy_kernel._jit = None
    shared = client.scatter([(kernel._jit_args, opposite, numpy_kernel, walk_class)],
                            broadcast=True, hash=False)[0]
    client.run(warm, kernel._jit_args)
    # the seeds, each to its shard
    g = ActiveSetGraph(kernel.m, kernel.nz, np.zeros((kernel.m, kernel.m), bool), kernel.box[0])
    def keyed(sets: list) -> np.ndarray:
        return np.stack([g.key(a) for a in sets]) if sets else np.zeros((0, g.W), np.uint64)

    keys = keyed(stack)
    points = np.broadcast_to(kernel.box[0], (len(stack), kernel.box[0].size)).copy()
    on_stack = set(stack)
    done = keyed([a for a in explored if a not in on_stack])  # evaluated already
    own, own_done = owners(keys, n), owners(done, n)
    where = {j: workers[j % len(workers)] for j in range(n)}
    found = len(regions)
    totals: dict = {}
    r = 0
    walk0, walked, rounds0 = time.thread_time(), None, time.process_time()
    # (the set-up: the kernel's arrays scattered, the workers warmed, the seeds keyed)
    stats["setup_client_cpu_seconds"] = rounds0 - cpu0

    def submit_round(attempt: int) -> list:
        return [
            client.submit(_round, shared, directory, j, n, r, budget,
                          (keys[own == j], points[own == j], done[own_done == j])
                          if r == 0 else None,
                          workers=[where[j]], allow_other_workers=True, pure=False,
                          key=f"codev-shard-{os.path.basename(directory)}-{j}-{r}-{attempt}")
            for j in range(n)
        ]

    def rescatter() -> None:
        # (the kernel's arrays may have gone with the cancelled round's worker)
        nonlocal shared
        client.cancel([shared])
        shared = client.scatter([(kernel._jit_args, opposite, numpy_kernel, walk_class)],
                                broadcast=True, hash=False)[0]

    try:
        while True:
            # a shard whose worker is gone, or shares it while a worker idles, moves to an
            # idle one (where it is rebuilt from its files)
            live = set(client.scheduler_info()["workers"])
            idle = sorted(live - set(where.values()))
            held: set = set()
            for j in range(n):
                if (where[j] not in live or where[j] in held) and idle:
                    where[j] = idle.pop()
                held.add(where[j])
            results = _gather_retrying(client, submit_round, f"round {r}", totals,
                                       rescatter)
            busy = False
            for j, (counts, st, addr, cpu) in enumerate(results):
                if addr is not None:
                    where[j] = addr
                found += counts["found"]
                busy |= counts["frontier"] > 0 or counts["sent"] > 0
                for key, v in st.items():
                    totals[key] = totals.get(key, 0) + v
                totals["explored"] = totals.get("explored", 0) + counts["explored"]
                totals["shards_restored"] = totals.get("shards_restored", 0) + counts["restored"]
                totals["worker_cpu_seconds"] = totals.get("worker_cpu_seconds", 0.0) + cpu
            r += 1
            if progress is not None:
                progress(found)
            if found > max_regions:
                stats["rounds_client_cpu_seconds"] = time.process_time() - rounds0
                raise TooManyRegionsError(too_many_regions(max_regions))
            if not busy or (STOP_AT is not None and found >= STOP_AT):
                break
        # the walk is done: what follows is the merge on demand, its cost apart
        walked = time.thread_time() - walk0
        stats["rounds_client_cpu_seconds"] = time.process_time() - rounds0
        cpu1 = time.process_time()
        if finish is not None:
            out = _finish_on_workers(client, directory, n, regions, g, kernel, where,
                                     merge, finish, totals)
            stats["merge_cpu_seconds"] = time.process_time() - cpu1
            return out
        theirs = read_shards(directory)
        parts = [RegionArrays.from_regions(regions, kernel.nz, kernel.d)]
        if theirs is not None:
            parts.append(theirs)
        out = RegionArrays.concat(parts)
        out = out.take(out.active_order())
        stats["merge_cpu_seconds"] = time.process_time() - cpu1
    finally:
        # (a worker lost just now must not turn a finished search into an error)
        client.run(_forget, directory, on_error="ignore")
        client.cancel([shared])
        shutil.rmtree(directory, ignore_errors=True)
        for key, v in totals.items():
            stats[key] = stats.get(key, 0) + v
        # (the coordinator's own thread; a LocalCluster's scheduler runs in this process
        # too, in other threads: client_cpu_seconds counts them, with the merge)
        # (when the walk ended, for mpsolve's end_client_cpu_seconds)
        stats["_walk_end_cpu"] = time.process_time()
        stats.update(shards=n, rounds=r, workers=n, client_cpu_seconds=time.process_time() - cpu0,
                     coordinator_cpu_seconds=walked if walked is not None
                     else time.thread_time() - walk0)
    return out
