"""A sharded law's *halo*: each cell's shard also holds copies of the regions reaching into it.

A sharded law cut by space (``law_shards``: shard ``c`` holds the regions whose centre is
in cell ``c`` of a k-d split that partitions ``R^n``) answers a point from about one shard,
but a box question (``regions_meeting``, ``domain_rows``) from every shard one of whose
regions' boxes meets the box: on ``pop_mpqp_051``'s 7-d slivers, nearly every shard for a
box of 1 % (each region's box overhangs its cell by its own size). The halo cures that: the
side file ``halo-<c>.npz`` of shard ``c`` holds a copy of every region of the *other* shards
whose bounding box meets cell ``c`` (its rows, law and box, with its owner's global index)
and the facets of the domain those shards hold that may meet the cell. A box question then
reads only the shards, and halos, whose *cells* meet the box:

- ``regions_meeting(lo, hi)``: take a region ``R`` whose box meets the box ``B`` (both
  grown by the tolerance ``_BOX_TOL``) at a point ``z``. The cells partition ``R^n`` (checked
  when the manifest is read: :func:`cells_partition`), so ``z`` is in some cell ``c``; ``R``'s
  box meets ``c`` at ``z``, so ``R`` is in shard ``c`` or in its halo, and ``B`` meets ``c`` at
  ``z``, so ``c`` is read. The answer is the union over the cells read, each region once
  (the owner's global index): the merged law's.
- ``domain_rows(lo, hi)``: the argument of docs/scale.md ("The domain's facets in the
  shards") needs, for a facet ``f`` of the domain meeting ``B`` at ``z``, ``f``'s row among
  the rows answered. ``z`` is in a cell ``c`` that ``B`` meets, and in a region ``R`` with a
  facet on ``f`` (stored in shard ``c'``, whose facets file holds ``f``'s row). With
  ``c' = c`` the shard's facets hold it; else the halo of ``c`` holds every facet of shard
  ``c'`` whose *facet box* meets ``c``: the union of the boxes of ``c'``'s regions that have
  a row within ``_ROW_TOL`` of it (:func:`facet_boxes`), ``R``'s among them, so ``z`` is in
  it. A facet no region's row matches gets the whole space as its box (every halo holds
  it): the matching only ever drops a facet from a halo it cannot meet.

The halo is built from the shard files once they are written (:func:`halo_pieces` for
each shard: what it sends to each other cell; :func:`write_halo` for each cell: its
pieces into one checked file), on the workers for the sharded search
(:func:`build_halo_on_workers`, the client handling the manifest entries only) and in
this process for ``law_shard_writer.write_law_shards`` (:func:`build_halo`). Storage: each region
is stored once per cell its box meets (x2 at 4 cells and x3 at 8 on ``pop_mpqp_051``).
"""

from __future__ import annotations

import time
import zipfile
from pathlib import Path

import numpy as np

from codev_engine.errors import DamagedFileError
from codev_engine.io.atomic import write_npz
from codev_engine.io.digest import file_sha256
from codev_engine.law import ExplicitLaw

__all__ = ["HALO_FORMAT", "Halo", "build_halo", "build_halo_on_workers", "cells_partition",
           "facet_boxes", "halo_pieces", "read_halo", "write_halo"]

#: format tag of a shard's halo file (``halo-<c>.npz``)
HALO_FORMAT = "codev-law-halo/1"
#: the bounding-box tolerance of ``ExplicitLaw.regions_meeting`` (``law_shards._BOX_TOL``)
_BOX_TOL = 1e-9
#: two unit rows ``[a, beta]`` are one facet's when ``a`` differs by at most this (max
#: norm) and ``beta`` by this relative to ``1 + |beta|``: far above the rounding of rows
#: computed for one plane, far below the gap between two facets of a region
_ROW_TOL = 1e-6


def cells_partition(lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether the half-open boxes ``lo <= x < hi`` are a k-d partition of ``R^n``: some
    cut ``x_i = v`` parts them into the cells below and above it, recursively, down to one
    cell, whose box is the whole part (the outer sides infinite). What makes a halo's
    answers exact (see the module): every point is in a cell. Empty cells (``lo >= hi``
    on an axis: ``kd_cells`` cuts at ``inf`` when all its points go left) hold no point
    and are left out.

    Parameters
    ----------
    lo, hi : (S, n) ndarrays
        -inf / inf on open sides.

    Returns
    -------
    bool
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    if lo.ndim != 2 or lo.shape != hi.shape or not lo.shape[0] or np.isnan(lo).any() \
            or np.isnan(hi).any():
        return False

    def check(idx: np.ndarray, blo: np.ndarray, bhi: np.ndarray) -> bool:
        if idx.size == 1:
            return bool(np.array_equal(lo[idx[0]], blo) and np.array_equal(hi[idx[0]], bhi))
        for axis in range(lo.shape[1]):
            for v in np.unique(lo[idx, axis]):
                if not blo[axis] < v < bhi[axis]:
                    continue
                below = hi[idx, axis] <= v
                above = lo[idx, axis] >= v
                if np.all(below | above) and below.any() and above.any():
                    lhi, rlo = bhi.copy(), blo.copy()
                    lhi[axis], rlo[axis] = v, v
                    return check(idx[below], blo, lhi) and check(idx[above], rlo, bhi)
        return False

    n = lo.shape[1]
    keep = np.flatnonzero(np.all(lo < hi, axis=1))
    return bool(keep.size) and check(keep, np.full(n, -np.inf), np.full(n, np.inf))


def _meets(blo: np.ndarray, bhi: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(k,) bool: which boxes ``[blo, bhi]`` meet ``[lo, hi]`` (both grown by ``_BOX_TOL``)."""
    return (np.all(blo <= hi + 2 * _BOX_TOL, axis=1)
            & np.all(bhi >= lo - 2 * _BOX_TOL, axis=1))


def _unit(rows: np.ndarray) -> np.ndarray:
    """Rows ``[a, beta]`` scaled to a unit ``a`` (a zero ``a`` kept)."""
    norm = np.linalg.norm(rows[:, :-1], axis=1)
    norm[norm == 0.0] = 1.0
    return rows / norm[:, None]


def facet_boxes(shard: ExplicitLaw, facets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box holding each facet of the domain a shard's facets file lists, on the shard's
    regions: the union of the boxes of its regions with a row within ``_ROW_TOL`` of the
    facet's (a region with a facet on it has such a row); the whole space for a facet no
    row matches.

    Parameters
    ----------
    shard : ExplicitLaw
        With its boxes (saved with it).
    facets : (q, n + 1) ndarray
        Rows ``[a, beta]``.

    Returns
    -------
    lo, hi : (q, n) ndarrays
    """
    from scipy.spatial import cKDTree

    n = shard.n
    q = facets.shape[0]
    lo, hi = np.full((q, n), np.inf), np.full((q, n), -np.inf)
    if not q:
        return lo, hi
    blo, bhi = shard.boxes
    k = shard.num_regions
    counts = np.array([a.shape[0] for a in shard.A], dtype=np.int64)
    rows = _unit(np.hstack([np.vstack(shard.A), np.concatenate(shard.b)[:, None]])
                 if k else np.zeros((0, n + 1)))
    owner = np.repeat(np.arange(k), counts)
    F = _unit(np.asarray(facets, float))
    if rows.shape[0]:
        tree = cKDTree(rows[:, :-1])
        near = tree.query_ball_point(F[:, :-1], r=_ROW_TOL, p=np.inf)
    else:
        near = [[] for _ in range(q)]
    for f, cand in enumerate(near):
        cand = np.asarray(cand, dtype=np.int64)
        if cand.size:
            beta = F[f, -1]
            cand = cand[np.abs(rows[cand, -1] - beta) <= _ROW_TOL * (1.0 + abs(beta))]
        if cand.size:
            regs = np.unique(owner[cand])
            lo[f], hi[f] = blo[regs].min(axis=0), bhi[regs].max(axis=0)
        else:  # (no region's row: in every halo)
            lo[f], hi[f] = -np.inf, np.inf
    return lo, hi


def halo_pieces(shard: ExplicitLaw, j: int, offset: int, facets: np.ndarray | None,
                cells_lo: np.ndarray, cells_hi: np.ndarray) -> dict[int, dict]:
    """What shard ``j`` sends each other cell's halo: its regions whose box meets the cell
    (their rows, laws, boxes and global indices) and its facets whose :func:`facet_boxes`
    meet it.

    Parameters
    ----------
    shard : ExplicitLaw
        Shard ``j``, with its boxes.
    j : int
    offset : int
        Its first region's global index.
    facets : (q, n + 1) ndarray or None
        Its facets of the domain (None: the law holds none).
    cells_lo, cells_hi : (S, n) ndarrays
        The cells (closed here: a region's box touching a cell's open side is sent too).

    Returns
    -------
    dict of int to dict
        For each cell ``c != j``: arrays ``owner`` (h,), ``A`` (rows, n), ``b``,
        ``counts`` (h,), ``F`` (h, m, n), ``G`` (h, m), ``box_lo``, ``box_hi`` (h, n),
        ``facets`` (f, n + 1).
    """
    blo, bhi = shard.boxes
    n = shard.n
    if facets is not None and facets.shape[0]:
        flo, fhi = facet_boxes(shard, facets)
    else:
        facets, flo, fhi = np.zeros((0, n + 1)), np.zeros((0, n)), np.zeros((0, n))
    out = {}
    for c in range(cells_lo.shape[0]):
        if c == j:
            continue
        take = np.flatnonzero(_meets(blo, bhi, cells_lo[c], cells_hi[c]))
        ftake = np.flatnonzero(_meets(flo, fhi, cells_lo[c], cells_hi[c]))
        out[c] = {
            "owner": (take + offset).astype(np.int64),
            "A": (np.vstack([shard.A[i] for i in take]) if take.size else np.zeros((0, n))),
            "b": (np.concatenate([shard.b[i] for i in take]) if take.size else np.zeros(0)),
            "counts": np.array([shard.A[i].shape[0] for i in take], dtype=np.int64),
            "F": shard.F[take], "G": shard.G[take],
            "box_lo": blo[take], "box_hi": bhi[take],
            "facets": np.asarray(facets, float)[ftake],
        }
    return out


def write_halo(path: Path, pieces: list[dict], n: int, m: int) -> dict:
    """Write one cell's halo (atomic): the pieces the other shards sent it, the regions in
    ascending global index, the facets each once; return its manifest fields.

    Parameters
    ----------
    path : Path
        ``halo-<c>.npz`` in the law's folder.
    pieces : list of dict
        :func:`halo_pieces`' answers for this cell.
    n, m : int

    Returns
    -------
    dict
        ``halo_file``, ``halo_sha256``, ``halo_bytes``, ``halo`` (regions), ``halo_facets``.
    """
    from codev_engine.geometry.polytope import unique_rows

    pieces = [p for p in pieces if p is not None]
    owner = np.concatenate([p["owner"] for p in pieces] + [np.zeros(0, np.int64)])
    counts = np.concatenate([p["counts"] for p in pieces] + [np.zeros(0, np.int64)])
    A = np.vstack([p["A"] for p in pieces] + [np.zeros((0, n))])
    b = np.concatenate([p["b"] for p in pieces] + [np.zeros(0)])
    F = np.concatenate([p["F"].reshape(-1, m, n) for p in pieces] + [np.zeros((0, m, n))])
    G = np.concatenate([p["G"].reshape(-1, m) for p in pieces] + [np.zeros((0, m))])
    blo = np.vstack([p["box_lo"] for p in pieces] + [np.zeros((0, n))])
    bhi = np.vstack([p["box_hi"] for p in pieces] + [np.zeros((0, n))])
    facets = np.vstack([p["facets"] for p in pieces] + [np.zeros((0, n + 1))])
    if facets.shape[0]:
        facets = facets[np.sort(unique_rows(facets, 12))]
    # (the regions by their owner's index: one order whatever the pieces' order)
    order = np.argsort(owner, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)])
    rows = (np.concatenate([np.arange(starts[i], starts[i + 1]) for i in order])
            if order.size else np.zeros(0, np.int64))
    write_npz(path, {"format": np.array(HALO_FORMAT), "owner": owner[order],
                     "counts": counts[order], "A": A[rows], "b": b[rows], "F": F[order],
                     "G": G[order], "box_lo": blo[order], "box_hi": bhi[order],
                     "facets": facets})
    return {"halo_file": path.name, "halo_sha256": file_sha256(path),
            "halo_bytes": path.stat().st_size, "halo": int(owner.size),
            "halo_facets": int(facets.shape[0])}


class Halo:
    """One cell's halo as read: the copies' law (:attr:`law`, an ``ExplicitLaw`` with their
    boxes), their global indices (:attr:`owner`, ascending) and the facets (:attr:`facets`).

    Parameters
    ----------
    law : ExplicitLaw
    owner : (h,) ndarray of int
    facets : (f, n + 1) ndarray
    """

    def __init__(self, law: ExplicitLaw, owner: np.ndarray, facets: np.ndarray):
        self.law, self.owner, self.facets = law, owner, facets

    def index(self, i: int) -> int:
        """The copy of global region ``i`` here.

        Parameters
        ----------
        i : int
            A region's global index.

        Returns
        -------
        int
            The copy's index in this halo, -1 when it holds none.
        """
        q = int(np.searchsorted(self.owner, i))
        return q if q < self.owner.size and self.owner[q] == i else -1


def read_halo(path: Path, entry: dict, n: int, m: int, names: dict | None = None) -> Halo:
    """A halo file, checked against its manifest entry (size and SHA-256 checked by the
    caller) and read.

    Parameters
    ----------
    path : Path
    entry : dict
        Its shard's manifest entry (``halo``, ``halo_facets``).
    n, m : int
    names : dict, optional
        The copies' ``states``, ``inputs``, ``parameters`` and ``fingerprint`` (the law's).

    Returns
    -------
    Halo

    Raises
    ------
    DamagedFileError
        Unreadable, or not the halo the manifest records.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            got = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        raise DamagedFileError("unreadable halo file", file=str(path)) from None
    try:
        owner = np.asarray(got["owner"], np.int64)
        counts = np.asarray(got["counts"], np.int64)
        h = owner.size
        A, b = np.asarray(got["A"], float), np.asarray(got["b"], float)
        F = np.asarray(got["F"], float).reshape(h, m, n)
        G = np.asarray(got["G"], float).reshape(h, m)
        blo = np.asarray(got["box_lo"], float).reshape(h, n)
        bhi = np.asarray(got["box_hi"], float).reshape(h, n)
        facets = np.asarray(got["facets"], float).reshape(-1, n + 1)
        ok = (str(got["format"]) == HALO_FORMAT and h == entry["halo"]
              and facets.shape[0] == entry["halo_facets"] and counts.shape == (h,)
              and np.all(counts >= 0) and A.shape == (int(counts.sum()), n)
              and b.shape == (A.shape[0],) and np.all(np.diff(owner) > 0))
    except (KeyError, ValueError, TypeError):
        ok = False
    if not ok:
        raise DamagedFileError("not the halo shards.json records (format, counts or "
                               "shapes)", file=str(path))
    cuts = np.cumsum(counts)[:-1]
    law = ExplicitLaw(A=np.split(A, cuts) if h else [], b=np.split(b, cuts) if h else [],
                      F=F, G=G, **(names or {}))
    law._boxes = (blo, bhi)
    return Halo(law, owner, facets)


def _load_shard(folder: Path, entry: dict) -> tuple[ExplicitLaw, np.ndarray | None]:
    """A shard's law and facets from its files (just written: read as they are)."""
    law = ExplicitLaw.load(folder / entry["file"])
    facets = None
    if "facets_file" in entry:
        with np.load(folder / entry["facets_file"], allow_pickle=False) as z:
            facets = np.asarray(z["facets"], float)
    return law, facets


def _cells(entries: list[dict], n: int) -> tuple[np.ndarray, np.ndarray]:
    def side(v, fill):
        return [fill if x is None else float(x) for x in v]

    return (np.array([side(e["cell_lo"], -np.inf) for e in entries]).reshape(-1, n),
            np.array([side(e["cell_hi"], np.inf) for e in entries]).reshape(-1, n))


def _out_task(directory: str, entries: list[dict], j: int, n: int) -> tuple:
    """Worker side: shard ``j``'s pieces for the other cells; (pieces, CPU seconds)."""
    t0 = time.process_time()
    offsets = np.concatenate([[0], np.cumsum([e["regions"] for e in entries])])
    law, facets = _load_shard(Path(directory), entries[j])
    lo, hi = _cells(entries, n)
    pieces = halo_pieces(law, j, int(offsets[j]), facets, lo, hi)
    return pieces, time.process_time() - t0


def _in_task(directory: str, c: int, n: int, m: int, *pieces) -> tuple:
    """Worker side: cell ``c``'s halo file from every other shard's piece for it; (its
    manifest fields, CPU seconds)."""
    t0 = time.process_time()
    fields = write_halo(Path(directory) / f"halo-{c}.npz", list(pieces), n, m)
    return fields, time.process_time() - t0


def _piece(out: tuple, c: int) -> dict | None:
    """Worker side: the piece for cell ``c`` of a shard's :func:`_out_task` answer (run
    where it is: only that piece travels to the cell's worker)."""
    return out[0].get(c)


def build_halo(directory: str | Path, entries: list[dict], n: int, m: int) -> list[dict]:
    """The halo of a law's shards written in ``directory`` (their entries with cells),
    built here, one shard at a time: the entries with the halo files' fields.

    Parameters
    ----------
    directory : path-like
    entries : list of dict
        The shards' manifest entries, each with ``cell_lo``, ``cell_hi``.
    n, m : int

    Returns
    -------
    list of dict
    """
    outs = [_out_task(str(directory), entries, j, n) for j in range(len(entries))]
    return [dict(e, **_in_task(str(directory), c, n, m, *(_piece(o, c) for o in outs))[0])
            for c, e in enumerate(entries)]


def build_halo_on_workers(client, directory: str, entries: list[dict], n: int, m: int
                          ) -> tuple[list[dict], float]:
    """:func:`build_halo` on a Dask cluster: a task per shard sends its pieces (held by
    the workers, passed from worker to worker), a task per cell writes its halo file; the
    client gets the manifest fields back, nothing that grows with the regions.

    Parameters
    ----------
    client : distributed.Client
    directory : str
        The law's folder (every worker reaches it).
    entries : list of dict
        With ``cell_lo``, ``cell_hi``.
    n, m : int

    Returns
    -------
    entries : list of dict
        With the halo's fields.
    cpu : float
        The workers' CPU seconds for it.
    """
    S = len(entries)
    outs = [client.submit(_out_task, directory, entries, j, n, pure=False) for j in range(S)]
    # (each cell's worker gets only the pieces for it: a small task per pair picks them
    # where they are)
    ins = [client.submit(_in_task, directory, c, n, m,
                         *[client.submit(_piece, outs[j], c, pure=False)
                           for j in range(S) if j != c], pure=False)
           for c in range(S)]
    got = client.gather(ins)
    # (the pieces' CPU: each task's second number, the pieces themselves stay put)
    cpu_out = sum(client.gather([client.submit(_second, o, pure=False) for o in outs]))
    del outs
    return ([dict(e, **fields) for e, (fields, _) in zip(entries, got, strict=True)],
            cpu_out + sum(t for _, t in got))


def _second(pair: tuple) -> float:
    return pair[1]
