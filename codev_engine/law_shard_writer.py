"""Writing an explicit MPC law as shards: the folder ``law_shards.ShardedLaw`` reads.

:func:`write_law_shards` writes a law as ``shard-<j>.npz`` files (each an ``ExplicitLaw``
file, written atomically, with its regions' bounding boxes) and then the manifest,
``shards.json`` (``law_shards.SHARDS_FORMAT``), that records each file's SHA-256, size,
regions, box and *groups*: at most ``GROUPS`` boxes, each the bounding box of a group of
its regions (:func:`box_groups`, a k-d split of their boxes), what a question checks
before it reads a shard. The manifest is written last (renamed into place), so a folder
either is a whole law or is refused.

A law is cut into shards by :func:`split_law` (consecutive regions, in the law's order or
:func:`spatial_order`'s) or by :func:`split_by_cells` (by space, as the sharded search
does: then the shards' cells go in the manifest and each cell's halo, ``law_halo``, is
built after the shards). The sharded search's workers write their own shards
(:class:`ShardWriter`, ``mpsolve(..., shard_writer=...)``), each with its facets of the
law's domain (``facets-<j>.npz``, ``law_shards.FACETS_FORMAT``); the client then builds the
halos, writes the manifest (:func:`write_manifest`) and opens the law.
:func:`update_meta` adds to a written law's metadata.

This module opens the laws it writes (``law_shards.ShardedLaw``); the reader never imports
the writer.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from codev_engine.io.atomic import write_npz, write_text
from codev_engine.io.digest import file_sha256
from codev_engine.law import ExplicitLaw
from codev_engine.law_shards import (
    FACETS_FORMAT,
    MANIFEST,
    SHARDS_FORMAT,
    ShardedLaw,
)
from codev_engine.mp.solution import RegionArrays

__all__ = ["GROUPS", "ShardWriter", "box_groups", "spatial_order", "split_by_cells",
           "split_law", "update_meta", "write_law_shards"]

#: group boxes per shard in the manifest at most (``box_groups``): what a question checks
#: before it reads a shard; the manifest grows by ``2 * GROUPS * n`` numbers per shard
GROUPS = 64


def _save_facets(facets: np.ndarray, path: Path) -> dict:
    """Save a shard's facets ``(q, n + 1)`` rows ``[a, beta]`` (``a x <= beta``) atomically
    and return the fields of its manifest entry (the file, its SHA-256, the count)."""
    write_npz(path, {"format": np.array(FACETS_FORMAT), "facets": np.asarray(facets, float)},
              compress=False)
    return {"facets_file": path.name, "facets_sha256": file_sha256(path),
            "facets_bytes": path.stat().st_size, "facets": int(facets.shape[0])}


def spatial_order(law: ExplicitLaw) -> np.ndarray:
    """The regions ordered by the centre of their bounding box along the axis the centres
    spread most on: consecutive regions then lie in slabs, and a shard of them has a small
    box (a question about a small set reads few shards).

    Parameters
    ----------
    law : ExplicitLaw

    Returns
    -------
    (k,) ndarray of int
        A permutation of the regions.
    """
    lo, hi = law.boxes
    if not lo.shape[0]:
        return np.zeros(0, dtype=np.int64)
    centre = 0.5 * (lo + hi)
    axis = int(np.argmax(np.ptp(centre, axis=0)))
    return np.argsort(centre[:, axis], kind="stable")


def box_groups(lo: np.ndarray, hi: np.ndarray, most: int = GROUPS
               ) -> tuple[np.ndarray, np.ndarray]:
    """At most ``most`` boxes that together hold every given box: the bounding boxes of
    groups of them, made by a k-d split of the boxes' centres (each split on the axis the
    centres spread most, at the median), the summary of a shard's regions that a question
    checks before it reads the shard.

    Each box is in exactly one group and each group's box is the ``min`` / ``max`` of its
    boxes' sides (exact in floating point): a box that meets a set (at any tolerance)
    lies in a group box that meets it too.

    Parameters
    ----------
    lo, hi : (k, n) ndarrays
        The boxes (a shard's regions' bounding boxes, ``ExplicitLaw.boxes``).
    most : int
        At least 1.

    Returns
    -------
    lo, hi : (g, n) ndarrays
        ``g = min(most, k)`` boxes (none for no box).
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    k = lo.shape[0]
    centre = 0.5 * (lo + hi)
    out: list[np.ndarray] = []

    def split(idx: np.ndarray, groups: int) -> None:
        if groups <= 1 or idx.size <= 1:
            out.append(idx)
            return
        # (a box of an infinite side has a NaN or infinite centre: sorted like any other,
        # the group's box is then infinite on that side, as it must be)
        spread = np.ptp(np.nan_to_num(centre[idx]), axis=0)
        axis = int(np.argmax(spread))
        order = idx[np.argsort(centre[idx, axis], kind="stable")]
        left = groups // 2
        cut = min(max(1, round(order.size * left / groups)), order.size - 1)
        split(order[:cut], left)
        split(order[cut:], groups - left)

    if k:
        split(np.arange(k), min(max(1, int(most)), k))
    return (np.array([lo[g].min(axis=0) for g in out]).reshape(-1, lo.shape[1]),
            np.array([hi[g].max(axis=0) for g in out]).reshape(-1, lo.shape[1]))


def split_law(law: ExplicitLaw, shards: int, order: np.ndarray | None = None
              ) -> list[ExplicitLaw]:
    """Cut a law into ``shards`` laws of consecutive regions (for :func:`write_law_shards`).

    Parameters
    ----------
    law : ExplicitLaw
    shards : int
        At least 1; fewer laws when the law has fewer regions.
    order : (k,) ndarray of int, optional
        The regions in this order first (:func:`spatial_order`): the sharded law's region
        ``i`` is then the law's ``order[i]``.

    Returns
    -------
    list of ExplicitLaw
        Each with the law's names, fingerprint, meta and domain.
    """
    k = law.num_regions
    order = np.arange(k) if order is None else np.asarray(order, dtype=np.int64)
    cuts = np.linspace(0, k, max(1, min(int(shards), max(k, 1))) + 1).astype(int)
    return [_part(law, order[lo:hi]) for lo, hi in zip(cuts[:-1], cuts[1:], strict=True)]


def _part(law: ExplicitLaw, take: np.ndarray) -> ExplicitLaw:
    """The regions ``take`` of ``law`` as a law of their own (its names, meta, domain)."""
    part = ExplicitLaw(
        A=[law.A[i] for i in take], b=[law.b[i] for i in take], F=law.F[take],
        G=law.G[take],
        states=law.states, inputs=law.inputs, fingerprint=law.fingerprint,
        meta=law.meta, domain_A=law.domain_A, domain_b=law.domain_b,
        parameters=law.parameters,
    )
    if law._boxes is not None:
        part._boxes = (law._boxes[0][take], law._boxes[1][take])
    return part


def split_by_cells(law: ExplicitLaw, shards: int
                   ) -> tuple[list[ExplicitLaw], tuple[np.ndarray, np.ndarray]]:
    """Cut a law by space, as the sharded search does: the cells of a k-d split of its
    regions' box centres (``mp.shard_space.kd_cells``: half-open boxes that partition
    ``R^n``), shard ``c`` the regions whose box centre is in cell ``c`` (for
    :func:`write_law_shards` with ``cells``: a halo).

    Parameters
    ----------
    law : ExplicitLaw
    shards : int
        At least 1.

    Returns
    -------
    parts : list of ExplicitLaw
        One per cell (a cell may hold no region).
    cells : (lo, hi)
        ``(shards, n)`` each, -inf / inf on the outer sides.
    """
    from codev_engine.mp.shard_space import cell_of, kd_cells

    lo, hi = law.boxes
    centre = np.nan_to_num(0.5 * (lo + hi))
    clo, chi = kd_cells(centre, np.ones(centre.shape[0]), max(1, int(shards)))
    cell = cell_of(centre, clo, chi) if centre.shape[0] else np.zeros(0, np.int64)
    return [_part(law, np.flatnonzero(cell == c)) for c in range(clo.shape[0])], (clo, chi)


def write_law_shards(directory: str | os.PathLike, shards: Iterable[ExplicitLaw],
                     cells: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write a law as shards: ``shard-<j>.npz`` for each, then the manifest.

    The shards are taken one at a time (an iterator may make each when it is asked for:
    only one is in memory here). They must share the names, the fingerprint and ``n``,
    ``m``; the first one's ``meta`` and domain are the law's.

    Parameters
    ----------
    directory : path-like
        Made when missing; its manifest, and shard files of the same names, are replaced.
    shards : iterable of ExplicitLaw
    cells : (lo, hi), optional
        ``(S, n)`` each: the cells of space the shards were cut by (:func:`split_by_cells`:
        a k-d partition of ``R^n``, shard ``j`` in cell ``j``). Then each shard's cell is in
        the manifest and its halo (``law_halo``: copies of the other shards' regions whose
        boxes meet its cell) in ``halo-<j>.npz``, built here after the shards.

    Returns
    -------
    Path
        The manifest.

    Raises
    ------
    ValueError
        Shards of different problems (fingerprint, names or dimensions), or none, or not
        one per cell.
    """
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    entries: list[dict] = []
    head: dict | None = None
    for j, part in enumerate(shards):
        mine = {"fingerprint": part.fingerprint, "states": list(part.states),
                "inputs": list(part.inputs), "parameters": list(part.parameters),
                "n": part.n, "m": part.m}
        if head is None:
            head = dict(mine, meta=part.meta, domain=part.domain_A is not None)
        elif any(head[key] != mine[key] for key in mine):
            raise ValueError(f"shard {j} is not of the first shard's law (fingerprint, "
                             "names or dimensions differ)")
        entries.append(_save_shard(part, folder / f"shard-{j}.npz"))
    if head is None:
        raise ValueError("a sharded law needs at least one shard")
    if cells is not None:
        from codev_engine.law_halo import build_halo

        clo, chi = (np.asarray(v, float) for v in cells)
        if clo.shape != chi.shape or clo.shape[0] != len(entries):
            raise ValueError(f"{len(entries)} shards need as many cells, not {clo.shape[0]}")
        entries = [dict(e, cell_lo=_sides(a), cell_hi=_sides(b))
                   for e, a, b in zip(entries, clo, chi, strict=True)]
        entries = build_halo(folder, entries, head["n"], head["m"])
    return write_manifest(folder, head, entries)


def _save_shard(part: ExplicitLaw, path: Path) -> dict:
    """Save one shard (atomically, with its boxes) and return its manifest entry."""
    lo, hi = part.boxes  # (saved with the shard: its regions' LPs are not solved again)
    path = part.save(path)
    # the groups' boxes: what a question checks before it reads the shard (the same boxes
    # as the file's, so a region's box is in its group's)
    glo, ghi = box_groups(lo, hi)
    return {  # (bytes: what a session checks when it opens the law, the SHA-256 when read)
        "file": path.name, "sha256": file_sha256(path), "bytes": path.stat().st_size,
        "regions": part.num_regions,
        "lo": lo.min(axis=0).tolist() if lo.shape[0] else None,
        "hi": hi.max(axis=0).tolist() if hi.shape[0] else None,
        "groups_lo": [_sides(v) for v in glo], "groups_hi": [_sides(v) for v in ghi],
    }


def _sides(v: np.ndarray) -> list:
    """A box's side as strict JSON: an infinite end as null (read back as -inf / inf)."""
    return [float(x) if np.isfinite(x) else None for x in v]


def write_manifest(directory: str | os.PathLike, head: dict, entries: list[dict]) -> Path:
    """Write (atomically, last) the manifest of shards already written.

    Parameters
    ----------
    directory : path-like
        The folder of the shard files.
    head : dict
        ``fingerprint``, ``states``, ``inputs``, ``parameters``, ``n``, ``m``, ``meta``,
        ``domain`` (bool) and, optionally, ``parameter_set_A`` / ``parameter_set_b`` (the
        parameter set's rows, when the entries name each shard's facets of the domain:
        the sharded search's) or ``domain_A`` / ``domain_b`` (the law's whole domain).
    entries : list of dict
        One per shard file, in order (``file``, ``sha256``, ``bytes``, ``regions``, ``lo``,
        ``hi``, ``groups_lo``, ``groups_hi``; ``facets_file``, ``facets_sha256``,
        ``facets_bytes``, ``facets`` with the facets in side files).

    Returns
    -------
    Path
        The manifest.
    """
    manifest = {"format": SHARDS_FORMAT, **head, "shards": entries}
    return write_text(Path(directory) / MANIFEST,
                      json.dumps(manifest, indent=1, default=_json))


def update_meta(directory: str | os.PathLike, extra: dict) -> ShardedLaw:
    """Add ``extra`` to a sharded law's metadata (its manifest rewritten atomically; the
    shards untouched) and open it.

    Parameters
    ----------
    directory : path-like
    extra : dict

    Returns
    -------
    ShardedLaw
    """
    law = ShardedLaw(directory)  # (checks the manifest)
    data = json.loads((Path(directory) / MANIFEST).read_text(encoding="utf-8"))
    data["meta"] = dict(law.meta, **extra)
    write_text(Path(directory) / MANIFEST, json.dumps(data, indent=1, default=_json))
    return ShardedLaw(directory)


@dataclass(frozen=True)
class ShardWriter:
    """Turns the regions of one shard of the sharded search into a law file, on the worker
    that holds them (``mpsolve(..., shard_writer=...)``): the law ``u = F theta + G`` of
    the optimiser's rows ``sl`` about the operating point ``op`` (as
    ``synthesis.law_from_solution``), regions of equal laws merged where their union is
    convex (``simplify``, within the shard: the law is the same function).

    Attributes
    ----------
    directory : str
        The law's folder (every worker must reach it).
    op : (d,) ndarray
        ``theta_op``: the law's ``theta`` is the program's plus ``op``.
    rows : (int, int)
        The optimiser's rows that are the input (``(0, nz)``: the law of an ``MpProgram``
        as it is, ``u = z``).
    u_op : (m,) ndarray or None
        Added to the input (None: zero).
    simplify : bool
    fingerprint : str
    states, inputs, parameters : tuple of str
    meta : dict
        The law's metadata (the manifest's).
    """

    directory: str
    op: np.ndarray
    rows: tuple[int, int] = (0, 0)
    u_op: np.ndarray | None = None
    simplify: bool = False
    fingerprint: str = ""
    states: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    parameters: tuple[str, ...] = ()
    meta: dict = field(default_factory=dict)

    def law(self, regions: RegionArrays) -> ExplicitLaw:
        """The shard's law (no domain: the manifest holds it).

        Parameters
        ----------
        regions : RegionArrays
            In the program's variables (``theta - op``), merged (``mpqp._merge_equal_laws``).

        Returns
        -------
        ExplicitLaw
        """
        from codev_engine.mp.merge import merge_equal_laws

        k, d = len(regions), self.op.size
        sl = slice(*self.rows)
        K, kk = regions.K[:, sl], regions.k[:, sl]
        m = K.shape[1]
        As, bs = [], []
        for i in range(k):
            A, b = regions.rows(i)
            As.append(A)
            bs.append(b + A @ self.op)
        F = K.reshape(k, m, d)
        G = kk - np.einsum("rij,j->ri", K, self.op) + (0.0 if self.u_op is None else self.u_op)
        G = G.reshape(k, m)
        if self.simplify and k:  # the same rule as synthesis.law_from_solution
            As, bs, F, G = merge_equal_laws(As, bs, F, G)
        return ExplicitLaw(A=As, b=bs, F=F, G=G, states=self.states, inputs=self.inputs,
                           fingerprint=self.fingerprint, meta={"shard": True},
                           parameters=self.parameters)

    def write(self, regions: RegionArrays, j: int, facets: np.ndarray | None = None,
              scale: np.ndarray | None = None) -> dict:
        """Worker side: write shard ``j`` (``shard-<j>.npz``, atomic) and, given, its facets
        of the law's domain (``facets-<j>.npz``, atomic, in the law's variables) and return
        its manifest entry (the files' SHA-256, the regions, the box, the facets' count).

        Parameters
        ----------
        regions : RegionArrays
        j : int
        facets : (q, d + 1) ndarray, optional
            Rows ``[a, beta]``, ``a theta <= beta`` in the program's variables
            (``theta - op``): the feasible set's facets among the shard's rows.
        scale : (d,) ndarray, optional
            The search ran on ``theta = scale * theta_s`` (``mp.balance``): the regions'
            boxes are computed in ``theta_s``, where the axes are of like size, and scaled
            (in ``theta`` the LPs of a box stopped short of a region 2**-11 wide on one
            axis and 2**13 on another, by 2e-6: a box that missed part of its region).

        Returns
        -------
        dict
        """
        folder = Path(self.directory)
        folder.mkdir(parents=True, exist_ok=True)
        law = self.law(regions)
        if scale is not None and law.num_regions:
            law._boxes = _scaled_boxes(law, np.asarray(scale, float), self.op)
        entry = _save_shard(law, folder / f"shard-{j}.npz")
        if facets is not None:
            F = np.asarray(facets, float).reshape(-1, self.op.size + 1).copy()
            F[:, -1] += F[:, :-1] @ self.op  # (to the law's variables)
            entry.update(_save_facets(F, folder / f"facets-{j}.npz"))
        return entry

    def point(self, X: np.ndarray) -> np.ndarray:
        """Points of the search's ``theta`` in the law's variables (``theta + op``).

        Parameters
        ----------
        X : (P, d) or (d,) ndarray

        Returns
        -------
        ndarray
            ``X``'s shape.
        """
        return np.asarray(X, float) + self.op

    def locate(self, j: int, X: np.ndarray) -> np.ndarray:
        """Worker side: region index of each point in shard ``j`` alone (-1 outside its
        regions): the coverage check asks the workers, so no shard is read by the client.

        Parameters
        ----------
        j : int
        X : (P, n) ndarray
            In the law's variables.

        Returns
        -------
        (P,) ndarray of int
        """
        return ExplicitLaw.load(Path(self.directory) / f"shard-{j}.npz").locate(X)

    def halo(self, client, entries: list[dict]) -> tuple[list[dict], float]:
        """Client side: each cell's halo (``law_halo``) built by the workers from the
        shard files written (``law_halo.build_halo_on_workers``); the entries with the
        halo files' fields and the workers' CPU seconds for it.

        Parameters
        ----------
        client : distributed.Client
        entries : list of dict
            :meth:`write`'s answers with their cells (``cell_lo``, ``cell_hi``, in the
            law's variables), in shard order.

        Returns
        -------
        entries : list of dict
        cpu : float
        """
        from codev_engine.law_halo import build_halo_on_workers

        return build_halo_on_workers(client, self.directory, entries, int(self.op.size),
                                     int(self.rows[1] - self.rows[0]))

    def open(self, entries: list[dict], set_A: np.ndarray, set_b: np.ndarray,
             meta: dict | None = None) -> ShardedLaw:
        """Client side: write the manifest of the shards written (with the parameter
        set's rows, in the program's variables, shifted to the law's: with the shards'
        facets, the law's domain) and open the law.

        Parameters
        ----------
        entries : list of dict
            :meth:`write`'s answers (with their facets), in shard order.
        set_A, set_b : (p, d), (p,) ndarrays
            The parameter set's rows (every one: the domain is the set cut by the facets).
        meta : dict, optional
            Added to :attr:`meta`.

        Returns
        -------
        ShardedLaw
        """
        m = self.rows[1] - self.rows[0]
        pA = np.asarray(set_A, float).reshape(-1, self.op.size)
        head = {"fingerprint": self.fingerprint, "states": list(self.states),
                "inputs": list(self.inputs), "parameters": list(self.parameters),
                "n": int(self.op.size), "m": int(m), "meta": dict(self.meta, **(meta or {})),
                "domain": True, "parameter_set_A": pA,
                "parameter_set_b": np.asarray(set_b, float) + pA @ self.op}
        write_manifest(self.directory, head, entries)
        return ShardedLaw(self.directory)


def _scaled_boxes(law: ExplicitLaw, D: np.ndarray, op: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The bounding boxes of ``law``'s regions (in ``theta``), computed in ``theta_s``
    with ``theta = D theta_s + op`` (``D`` powers of two: the scaling back is exact)."""
    from codev_engine.geometry.locate import bounding_boxes

    As, bs = [], []
    for A, b in zip(law.A, law.b, strict=True):
        As_ = A * D
        nrm = np.linalg.norm(As_, axis=1)
        nrm[nrm == 0.0] = 1.0
        As.append(As_ / nrm[:, None])
        bs.append((b - A @ op) / nrm)
    lo, hi = bounding_boxes(As, bs)
    return lo * D + op, hi * D + op


def _json(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(type(obj).__name__)
