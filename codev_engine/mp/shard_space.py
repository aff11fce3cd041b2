"""The end of the sharded mp-QP search: the regions re-partitioned by space, on the workers.

During the search a shard holds the regions whose active set hashes to it (``sharded.owners``):
spread over the whole parameter set, so every law shard's box was the whole domain and a
question about one point read every shard. At the end the regions are cut by space instead,
without coming to the client:

1. each worker computes a centre for each of its hash shard's regions (a Chebyshev centre:
   a point of the region) and sends the client a small sample of them (at most
   ``SAMPLE`` in all, each shard's weighted by its regions);
2. the client cuts the parameter space into ``S`` cells, a k-d split at the sample's
   weighted medians (:func:`kd_cells`: half-open boxes that partition ``R^d``), and sends
   the cells to every worker;
3. each worker writes, for each cell ``c``, the part of its regions whose centre is in ``c``
   (``<shard>/cell-<c>.npz``, checked and atomic as the part files);
4. the worker of cell ``c`` reads the pieces of ``c`` from every shard, sorts them by active
   set, merges equal laws (across the former hash shards too) and writes the law's shard
   ``c`` (``finish``): its regions' box is about the cell's.

Every step is a pure function of the files written before it (and of the given seeds), so a
worker lost in any step is replaced by running its tasks again elsewhere: the same files.
Which cell a region goes to decides only where it is stored, never the law: the union of
the cells' regions is every region, each once.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from codev_engine.mp.solution import RegionArrays

__all__ = ["SAMPLE", "cell_of", "kd_cells", "region_centres"]

#: the region centres the client gets in all, to place the cuts
SAMPLE = 4096

# worker side: (directory, shard) -> (the shard's regions, their centres), from step 1 to 3
_HELD: dict[tuple[str, int], tuple[RegionArrays, np.ndarray]] = {}


def region_centres(regions: RegionArrays, x0: np.ndarray, bound: float) -> np.ndarray:
    """A point of each region: its Chebyshev centre (one LP; the compiled ``lp_kernel``).

    A region whose LP fails gets ``x0`` (an empty one, which a law never has, the LP's
    point of least violation): the centre only decides which cell stores the region,
    never the law.

    Parameters
    ----------
    regions : RegionArrays
        R regions in ``d`` parameters.
    x0 : (d,) ndarray
        The LPs' start (the parameter box's centre).
    bound : float
        A bound of ``max |x|_inf`` over the parameter set.

    Returns
    -------
    (R, d) ndarray
        Finite.
    """
    from codev_engine.geometry.lp_kernel import OPTIMAL, chebyshev

    R, d = len(regions), x0.size
    out = np.empty((R, d))
    x0 = np.ascontiguousarray(x0, dtype=float)
    for i in range(R):
        A, b = regions.rows(i)
        norm = np.linalg.norm(A, axis=1)
        keep = norm > 0
        st, centre, _, _ = chebyshev(np.ascontiguousarray(A[keep] / norm[keep, None]),
                                     np.ascontiguousarray(b[keep] / norm[keep]), x0,
                                     float(bound), 200 + 20 * d)
        out[i] = centre if st == OPTIMAL and np.all(np.isfinite(centre)) else x0
    return out


def kd_cells(points: np.ndarray, weights: np.ndarray, cells: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """A k-d split of space into ``cells`` half-open boxes ``lo <= x < hi`` that partition
    ``R^d``, each holding about the same weight of ``points``.

    Each split cuts the axis on which its points spread most at the weighted quantile that
    gives each side weight in proportion to its number of cells.

    Parameters
    ----------
    points : (P, d) ndarray
        Finite.
    weights : (P,) ndarray
        Positive.
    cells : int
        At least 1.

    Returns
    -------
    lo, hi : (cells, d) ndarrays
        With -inf / inf on the outer sides; a cell may be empty of points.
    """
    d = points.shape[1]
    lo_all, hi_all = [], []

    def split(idx: np.ndarray, k: int, lo: np.ndarray, hi: np.ndarray) -> None:
        if k == 1:
            lo_all.append(lo)
            hi_all.append(hi)
            return
        left = k // 2
        pts = points[idx]
        axis = int(np.argmax(np.ptp(pts, axis=0))) if idx.size else 0
        if idx.size:
            order = np.argsort(pts[:, axis], kind="stable")
            x = pts[order, axis]
            cw = np.cumsum(weights[idx][order])
            i = int(np.searchsorted(cw, cw[-1] * left / k))
            # between the two points on either side of the quantile (+inf: all go left)
            v = 0.5 * (x[i] + x[i + 1]) if i + 1 < x.size else np.inf
        else:
            v = 0.0
        # (inside the part: a cut past its side, +inf above a part of one point or 0 in
        # an empty one, would make a half larger than the part, overlapping its
        # neighbours; at its side, the other half is empty)
        v = min(max(v, lo[axis]), hi[axis])
        go_left = points[idx, axis] < v
        lhi, rlo = hi.copy(), lo.copy()
        lhi[axis], rlo[axis] = v, v
        split(idx[go_left], left, lo, lhi)
        split(idx[~go_left], k - left, rlo, hi)

    split(np.arange(points.shape[0]), max(1, int(cells)),
          np.full(d, -np.inf), np.full(d, np.inf))
    return np.array(lo_all), np.array(hi_all)


def cell_of(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The cell of :func:`kd_cells` holding each point.

    Parameters
    ----------
    points : (P, d) ndarray
        Finite.
    lo, hi : (S, d) ndarrays

    Returns
    -------
    (P,) ndarray of int64
        In ``range(S)``: the cells partition ``R^d``, so exactly one holds each point.
    """
    inside = np.all((points[:, None, :] >= lo[None]) & (points[:, None, :] < hi[None]),
                    axis=2)
    if not np.all(inside.sum(axis=1) == 1):  # (the cells are a partition: never)
        raise AssertionError("k-d cells that do not partition space")
    return np.argmax(inside, axis=1).astype(np.int64)


def _regions(directory: str, j: int, seeds: RegionArrays) -> RegionArrays:
    """Hash shard ``j``'s regions: its part files, round by round, then its seeds (the same
    order in every step)."""
    from codev_engine.mp.shard_files import _read_parts

    parts = _read_parts(Path(directory) / f"{j}")
    if len(seeds):
        parts.append(seeds)
    return RegionArrays.concat(parts) if parts else seeds


def _centres_task(directory: str, j: int, seeds: RegionArrays, x0: np.ndarray,
                  bound: float, sample: int) -> tuple:
    """Worker side, step 1: shard ``j``'s region centres (written to ``centres.npz``,
    checked) and a sample of at most ``sample`` of them; (sample, regions, CPU seconds)."""
    from codev_engine.mp.shard_files import _write

    t0 = time.process_time()
    regions = _regions(directory, j, seeds)
    centres = region_centres(regions, x0, bound)
    folder = Path(directory) / f"{j}"
    folder.mkdir(parents=True, exist_ok=True)  # (a shard that found no region has none)
    _write(folder / "centres.npz", {"centres": centres})
    _HELD[(directory, j)] = (regions, centres)
    R = centres.shape[0]
    # (evenly spread over the shard's regions: deterministic)
    pick = np.unique(np.linspace(0, R - 1, min(R, sample)).astype(np.int64)) if R else []
    return centres[pick], R, time.process_time() - t0


def _cut_task(directory: str, j: int, seeds: RegionArrays, lo: np.ndarray,
              hi: np.ndarray) -> tuple:
    """Worker side, step 3: shard ``j``'s regions to ``cell-<c>.npz`` by the cell of their
    centre (from step 1's memory, else its files); (regions per cell, whether it read
    them from the files, CPU seconds)."""
    from codev_engine.errors import SolverError
    from codev_engine.mp.shard_files import _read, _write, region_arrays

    t0 = time.process_time()
    held = _HELD.pop((directory, j), None)
    folder = Path(directory) / f"{j}"
    if held is None:  # (step 1 ran on a worker since lost, or elsewhere)
        regions = _regions(directory, j, seeds)
        centres = _read(folder / "centres.npz")["centres"]
        if centres.shape[0] != len(regions):
            raise SolverError(f"{folder / 'centres.npz'}: not the shard's regions")
    else:
        regions, centres = held
    cell = cell_of(centres, lo, hi) if len(regions) else np.zeros(0, np.int64)
    counts = []
    for c in range(lo.shape[0]):
        part = regions.take(np.flatnonzero(cell == c))
        counts.append(len(part))
        folder.mkdir(parents=True, exist_ok=True)
        _write(folder / f"cell-{c}.npz", region_arrays(part))
    return counts, held is None, time.process_time() - t0


def _cell_task(directory: str, c: int, n: int, merge, finish) -> tuple:
    """Worker side, step 4: cell ``c``'s regions from every shard's ``cell-<c>.npz``,
    sorted by active set, equal laws merged (``merge``), handed to ``finish`` (which writes
    the law's shard ``c``); (``finish``'s answer, stats, regions, CPU seconds)."""
    from codev_engine.mp.shard_files import _read, regions_of

    t0 = time.process_time()
    parts = [regions_of(_read(Path(directory) / f"{i}" / f"cell-{c}.npz")) for i in range(n)]
    regions = RegionArrays.concat(parts)
    regions = regions.take(regions.active_order())
    stats: dict = {}
    found = len(regions)
    regions = merge(regions, stats)
    answer = finish(regions, c)
    return answer, stats, found, time.process_time() - t0


def forget(directory: str) -> int:
    """Worker side: drop what step 1 holds of a search."""
    gone = [key for key in _HELD if key[0] == directory]
    for key in gone:
        del _HELD[key]
    return len(gone)


def end_by_space(client, directory: str, n: int, seeds: list[RegionArrays], where: dict,
                 x0: np.ndarray, bound: float, merge, finish, totals: dict,
                 gather) -> list[tuple]:
    """The end of a sharded search (the steps of the module's docstring): the law's shard
    ``c`` written by the worker of cell ``c``.

    Parameters
    ----------
    client : distributed.Client
    directory : str
        The search's folder (a folder per hash shard of part files).
    n : int
        Shards, and cells.
    seeds : list of RegionArrays
        The regions found before the walk was sharded, each hash shard's.
    where : dict of int to str
        The worker each shard's tasks go to first.
    x0, bound
        The parameter box's centre and a bound of ``|x|_inf`` on it (the centres' LPs).
    merge, finish : callable
        As ``sharded.sharded_walk``'s.
    totals : dict
        Updated with ``end_worker_cpu_seconds`` (also in ``worker_cpu_seconds``),
        ``end_sample`` (the centres the client got), ``end_restored`` (shards cut by a
        worker that had not computed their centres: the first one was lost) and the
        merge's counters.
    gather : callable
        ``sharded._gather_retrying``.

    Returns
    -------
    list of tuple
        ``(answer, stats, regions, (lo, hi))`` for each cell, in order: ``lo <= x < hi``
        is the cell (-inf / inf on its outer sides).
    """
    tag = os.path.basename(directory)

    def tasks(fn, what, args_of):
        return gather(client, lambda attempt: [
            client.submit(fn, *args_of(j), workers=[where[j]], allow_other_workers=True,
                          pure=False, key=f"codev-shard-{tag}-{j}-{what}-{attempt}")
            for j in range(n)
        ], f"last step ({what})", totals)

    per = max(1, SAMPLE // n)
    got = tasks(_centres_task, "centres",
                lambda j: (directory, j, seeds[j], x0, bound, per))
    cpu = sum(t for _, _, t in got)
    # each sampled centre stands for its shard's regions / its sample size
    pts = [s for s, _, _ in got if len(s)]
    wts = [np.full(len(s), R / len(s)) for s, R, _ in got if len(s)]
    d = x0.size
    points = np.vstack(pts) if pts else np.zeros((0, d))
    lo, hi = kd_cells(points, np.concatenate(wts) if wts else np.zeros(0), n)
    totals["end_sample"] = totals.get("end_sample", 0) + points.shape[0]
    cut = tasks(_cut_task, "cut", lambda j: (directory, j, seeds[j], lo, hi))
    cpu += sum(t for _, _, t in cut)
    # (a worker lost after step 1: its shard was read again from the files)
    totals["end_restored"] = totals.get("end_restored", 0) + sum(r for _, r, _ in cut)
    ends = tasks(_cell_task, "end", lambda c: (directory, c, n, merge, finish))
    out = []
    for c, (answer, st, found, t) in enumerate(ends):
        for key, v in st.items():
            totals[key] = totals.get(key, 0) + v
        cpu += t
        out.append((answer, st, found, (lo[c], hi[c])))
    totals["worker_cpu_seconds"] = totals.get("worker_cpu_seconds", 0.0) + cpu
    totals["end_worker_cpu_seconds"] = totals.get("end_worker_cpu_seconds", 0.0) + cpu
    return out
