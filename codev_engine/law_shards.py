"""An explicit MPC law held as shards: one checked law file per shard, read when asked.

A law of millions of regions made by the sharded search (``mp/sharded.py``) need not be
whole in one process: :func:`write_law_shards` writes it as a folder of law files (each in
``ExplicitLaw``'s own format, ``law.LAW_FORMAT``, written atomically, with its regions'
bounding boxes) and a manifest, ``shards.json``, written last, that records each file's
SHA-256, its size, its number of regions, the bounding box of its regions and its
*groups*: at most ``GROUPS`` boxes, each the bounding box of a group of its regions (a k-d
split of their boxes, :func:`box_groups`), a summary of fixed size whatever the regions.
:class:`ShardedLaw` reads the manifest alone; a shard is read, and checked against its
SHA-256 and the manifest, the first time a question needs it:

- :meth:`ShardedLaw.regions_meeting` reads only the shards one of whose group boxes meets
  the box asked (a manifest written before the groups: whose box meets it);
- :meth:`ShardedLaw.locate` / :meth:`ShardedLaw.evaluate` only the shards one of whose
  group boxes holds one of the points (first the shard whose *cell* holds it, when the
  manifest records the cells of space the sharded search cut the regions by: most points
  are answered there);
- ``law.A[i]``, ``law.F[i]`` (and ``law.F[idx]`` for an index array) the shards of those
  regions.

Region ``i`` is the ``i - offset[j]``-th region of shard ``j`` (the shards in the
manifest's order). :meth:`ShardedLaw.merged` builds the whole ``ExplicitLaw`` (on demand:
what an exporter of one C table needs). The interface is the one ``ExplicitLaw`` and
``law_on_demand.OnDemandLaw`` give the reach engines. At most ``cache`` shards are held at
once (the least recently used one is dropped).

A law of the sharded search keeps its **domain** (the feasible parameter set ``D``) in the
shards too: each shard's facets of ``D`` (the rows of its regions that hold on all of ``D``)
in a checked side file ``facets-<j>.npz``, the parameter set's rows in the manifest.
:meth:`ShardedLaw.domain_rows` then answers a box with the parameter set's rows and the
facets of the shards whose group boxes meet it (:attr:`ShardedLaw.local_domain`: no file
but those shards' facets is read; docs/scale.md says why that describes ``D`` in the box).

A law cut by space (the sharded search's; :func:`write_law_shards` with ``cells``, from
:func:`split_by_cells`) may hold a **halo** (``law_halo``): each shard's cell's copies of the
other shards' regions whose boxes reach into it, and the facets of the domain that may meet
it, in a checked side file ``halo-<j>.npz``. With it, :meth:`ShardedLaw.regions_meeting` and
:meth:`ShardedLaw.domain_rows` read the shards and halos of the cells the box meets alone
(:attr:`ShardedLaw.has_halo`; the cells are checked to be a k-d partition of space when the
manifest is read, else the halo is not used): the same answers, from ~1.1 shards of 4 for
a box of 1 % on ``pop_mpqp_051`` where the group boxes read 3.99. A region found in a halo
is read from it (``law.A[i]``), its own shard unread.

A group box is the union of its regions' boxes, compared with the box asked at the same
tolerance (``_BOX_TOL``) as ``ExplicitLaw.regions_meeting`` compares theirs: a shard one of
whose regions' boxes meets the box always has a group box that meets it, so no shard that
holds an answer is skipped.

A damaged or edited shard is refused when read (``errors.DamagedFileError``, a ``SpecError``
naming the file): its size or its SHA-256 is not the manifest's (a manifest written before
the size was recorded: its SHA-256 alone). A manifest torn by a crash is not there at all
(it is renamed into place after every shard), so a folder either is a whole law or is
refused.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from codev_engine.errors import DamagedFileError, SpecError
from codev_engine.io.atomic import write_npz, write_text
from codev_engine.law import ExplicitLaw
from codev_engine.mp.solution import RegionArrays

__all__ = ["FACETS_FORMAT", "GROUPS", "SHARDS_FORMAT", "ShardWriter", "ShardedLaw",
           "box_groups", "manifest_files", "spatial_order", "split_by_cells", "split_law",
           "update_meta",
           "write_law_shards"]

#: format tag of a sharded law's manifest
SHARDS_FORMAT = "codev-law-shards/1"
#: the manifest's name in the folder
MANIFEST = "shards.json"
#: shards held in memory at once by default
CACHE = 4
#: format tag of a shard's facets file (``facets-<j>.npz``)
FACETS_FORMAT = "codev-law-facets/1"
#: the bounding-box tolerance of ``ExplicitLaw.regions_meeting``
_BOX_TOL = 1e-9
#: group boxes per shard in the manifest at most (``box_groups``): what a question checks
#: before it reads a shard; the manifest grows by ``2 * GROUPS * n`` numbers per shard
GROUPS = 64


def _save_facets(facets: np.ndarray, path: Path) -> dict:
    """Save a shard's facets ``(q, n + 1)`` rows ``[a, beta]`` (``a x <= beta``) atomically
    and return the fields of its manifest entry (the file, its SHA-256, the count)."""
    write_npz(path, {"format": np.array(FACETS_FORMAT), "facets": np.asarray(facets, float)},
              compress=False)
    return {"facets_file": path.name, "facets_sha256": _file_sha(path),
            "facets_bytes": path.stat().st_size, "facets": int(facets.shape[0])}


def manifest_files(entries: list[dict]) -> list[tuple[str, int | None]]:
    """Every file a manifest's shard entries name, with the size it records (None: a
    manifest written before sizes were recorded): each shard's law file and, for the
    sharded search's law, its facets file; with a halo, its halo file. What a session
    checks when it opens the law.

    Parameters
    ----------
    entries : list of dict
        The manifest's ``shards``.

    Returns
    -------
    list of (str, int or None)

    Raises
    ------
    KeyError, TypeError, AttributeError
        An entry that is not a dict naming its ``file``.
    """
    listed = [(str(e["file"]), e.get("bytes")) for e in entries]
    listed += [(str(e["facets_file"]), e.get("facets_bytes")) for e in entries
               if "facets_file" in e]
    listed += [(str(e["halo_file"]), e.get("halo_bytes")) for e in entries
               if "halo_file" in e]
    return listed


def _file_sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


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
        "file": path.name, "sha256": _file_sha(path), "bytes": path.stat().st_size,
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


def _cell(entry: dict, n: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A manifest entry's cell ``(lo, hi)``, null for an open side (None without one, or
    a malformed one: the cell only orders ``locate``'s look-ups, its boxes decide)."""
    try:
        lo = np.array([-np.inf if v is None else float(v) for v in entry["cell_lo"]])
        hi = np.array([np.inf if v is None else float(v) for v in entry["cell_hi"]])
    except (KeyError, TypeError, ValueError):
        return None
    return (lo, hi) if lo.shape == hi.shape == (n,) else None


def _groups(entry: dict, n: int, where: str, j: int) -> tuple[np.ndarray, np.ndarray]:
    """A manifest entry's group boxes ``(g, n)`` each (null sides read as -inf / inf); a
    manifest written before the groups: the entry's box as one group, or none (no region).
    ``SpecError`` naming the field when they are malformed: a group box the reader cannot
    trust would skip a shard that holds an answer."""
    if "groups_lo" not in entry and "groups_hi" not in entry:
        if entry.get("lo") is None or entry.get("hi") is None:
            return np.zeros((0, n)), np.zeros((0, n))
        return (np.asarray(entry["lo"], float).reshape(1, n),
                np.asarray(entry["hi"], float).reshape(1, n))
    try:
        lo = np.array([[-np.inf if v is None else float(v) for v in row]
                       for row in entry["groups_lo"]], dtype=float).reshape(-1, n)
        hi = np.array([[np.inf if v is None else float(v) for v in row]
                       for row in entry["groups_hi"]], dtype=float).reshape(-1, n)
        ok = (lo.shape == hi.shape and not np.isnan(lo).any() and not np.isnan(hi).any()
              and (lo.shape[0] > 0) == (entry["regions"] > 0))
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise SpecError(f"must be as many boxes of {n} sides in groups_lo as in groups_hi "
                        "(none without regions)", file=where, field=f"shards[{j}].groups_lo")
    return lo, hi


def _matrix(data: dict, a: str, b: str, n: int, where: str
            ) -> tuple[np.ndarray, np.ndarray]:
    """The manifest's rows ``data[a] x <= data[b]``, checked (``SpecError`` naming ``a``)."""
    try:
        A = np.asarray(data[a], dtype=float).reshape(-1, n)
        rhs = np.asarray(data[b], dtype=float).reshape(A.shape[0])
    except (TypeError, ValueError, KeyError):
        raise SpecError(f"must be a ({n}-column) matrix and its offsets", file=where,
                        field=a) from None
    return A, rhs


def _size(entry: dict) -> int | None:
    """A manifest entry's ``bytes`` (None: not recorded, a manifest written before it was;
    -1: not a count)."""
    got = entry.get("bytes")
    if got is None:
        return None
    return got if isinstance(got, int) and not isinstance(got, bool) and got >= 0 else -1


def _checked(path: Path, sha256: str, size: int | None, what: str) -> Path:
    """``path``, once it is there with the size (when recorded) and the SHA-256 the
    manifest records; else ``DamagedFileError`` naming it (``what`` says what it holds)."""
    if not path.is_file():
        raise DamagedFileError(f"missing ({what})", file=str(path))
    if size is not None and path.stat().st_size != size:
        raise DamagedFileError(f"its size is not the one {MANIFEST} records (damaged or "
                               "edited): refused", file=str(path))
    if _file_sha(path) != sha256:
        raise DamagedFileError(f"its SHA-256 is not the one {MANIFEST} records (damaged or "
                               "edited): refused", file=str(path))
    return path


def _json(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(type(obj).__name__)


class _Rows:
    """``law.A`` (``law.b``, ``law.F``, ``law.G``) of a sharded law: item ``i`` read from
    its shard; ``F`` and ``G`` also take an index array (``law.F[idx]``)."""

    def __init__(self, law: ShardedLaw, name: str):
        self.law, self.name = law, name

    def __len__(self) -> int:
        return self.law.num_regions

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[q] for q in range(*i.indices(len(self)))]
        idx = np.asarray(i)
        if idx.ndim == 0:
            law, q = self.law._source(int(idx))
            return getattr(law, self.name)[q]
        if idx.dtype == bool:
            idx = np.flatnonzero(idx)
        parts = [getattr(law, self.name)[q] for law, q in map(self.law._source, idx)]
        if self.name in ("F", "G"):
            F = self.law.shard(0).F if self.name == "F" else self.law.shard(0).G
            return np.array(parts).reshape((len(parts),) + F.shape[1:])
        return parts

    def __iter__(self):
        for j in range(len(self.law.offsets) - 1):
            yield from getattr(self.law.shard(j), self.name)

    def __array__(self, dtype=None, copy=None):
        # (the whole table: what ``np.asarray(law.F)`` asks for)
        parts = [getattr(self.law.shard(j), self.name) for j in range(len(self.law.offsets) - 1)]
        return np.concatenate(parts).astype(dtype) if dtype else np.concatenate(parts)


class ShardedLaw:
    """A piecewise-affine MPC law whose regions live in shard files, read when asked.

    Parameters
    ----------
    directory : path-like
        A folder of :func:`write_law_shards`.
    cache : int
        Shards held in memory at once (at least 1).
    on_damaged : callable, optional
        See the attribute.

    Raises
    ------
    SpecError
        The manifest is missing or malformed (naming it and the field).

    Attributes
    ----------
    A, b, F, G
        Sequences of the regions' rows and laws (``law.A[i]``), each read from its shard.
    states, inputs, parameters : tuple of str
    fingerprint : str
    meta : dict
    offsets : (S + 1,) ndarray of int
        Shard ``j`` holds the regions ``offsets[j]:offsets[j + 1]``.
    local_domain : bool
        The domain is held as each shard's facets (the sharded search's law):
        :meth:`domain_rows` reads only the facets of the shards a box meets, and a
        consumer that needs the domain near a set asks it rather than :attr:`domain_A`.
    has_halo : bool
        Each shard holds a halo (``law_halo``): box questions read the cells they meet.
    loads, asked, met : int
        Counters so far: the shard (and halo) files read; the (point, shard) look-ups of
        :meth:`locate`; the (box, shard) pairs :meth:`regions_meeting` and
        :meth:`domain_rows` looked in (one of the shard's group boxes met the box; with a
        halo, its cell).
    on_damaged : callable or None
        Called with the ``DamagedFileError`` of a file found damaged when read, before it
        is raised; what it returns is raised instead. Who opened the law from a store sets
        it (a session marks its artifact damaged so that its next run recomputes it,
        whichever front end asked the question). Not pickled: a copy sent to a worker
        raises the error as it is, and the session marks it when it comes back.
    """

    def __init__(self, directory: str | os.PathLike, *, cache: int = CACHE,
                 on_damaged: Callable[[DamagedFileError], DamagedFileError] | None = None):
        self.dir = Path(directory)
        self.on_damaged = on_damaged
        where = str(self.dir / MANIFEST)
        try:
            data = json.loads((self.dir / MANIFEST).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise SpecError("no sharded law here (missing)", file=where) from None
        except (OSError, ValueError, RecursionError, UnicodeDecodeError) as exc:
            raise SpecError(f"unreadable ({type(exc).__name__})", file=where) from None
        if not isinstance(data, dict) or data.get("format") != SHARDS_FORMAT:
            raise SpecError(f"not a sharded law (format must be {SHARDS_FORMAT!r})",
                            file=where, field="format")
        shards = data.get("shards")
        if not isinstance(shards, list) or not shards:
            raise SpecError("must list at least one shard", file=where, field="shards")
        counts = []
        for j, e in enumerate(shards):
            ok = (isinstance(e, dict) and isinstance(e.get("file"), str)
                  and Path(e["file"]).name == e["file"] and isinstance(e.get("sha256"), str)
                  and isinstance(e.get("regions"), int) and e["regions"] >= 0
                  and _size(e) != -1)
            if not ok:
                raise SpecError("must name a file in the folder, its sha256 and its regions "
                                "(and its bytes, a count, when recorded)",
                                file=where, field=f"shards[{j}]")
            if "facets_file" in e and not (
                    isinstance(e["facets_file"], str)
                    and Path(e["facets_file"]).name == e["facets_file"]
                    and isinstance(e.get("facets_sha256"), str)
                    and isinstance(e.get("facets"), int) and e["facets"] >= 0
                    and _size({"bytes": e.get("facets_bytes")}) != -1):
                raise SpecError("must name its facets file in the folder, its sha256 and "
                                "its count", file=where, field=f"shards[{j}].facets_file")
            if "halo_file" in e and not (
                    isinstance(e["halo_file"], str)
                    and Path(e["halo_file"]).name == e["halo_file"]
                    and isinstance(e.get("halo_sha256"), str)
                    and isinstance(e.get("halo"), int) and e["halo"] >= 0
                    and isinstance(e.get("halo_facets"), int) and e["halo_facets"] >= 0
                    and _size({"bytes": e.get("halo_bytes")}) != -1):
                raise SpecError("must name its halo file in the folder, its sha256 and its "
                                "counts", file=where, field=f"shards[{j}].halo_file")
            counts.append(e["regions"])
        self._entries = shards
        self.offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.fingerprint = str(data.get("fingerprint", ""))
        self.states = tuple(data.get("states", ()))
        self.inputs = tuple(data.get("inputs", ()))
        self.parameters = tuple(data.get("parameters", ()))
        self.meta = data.get("meta") if isinstance(data.get("meta"), dict) else {}
        self._n, self._m = int(data.get("n", 0)), int(data.get("m", 0))
        # each shard's group boxes ((g, n) each; none: no region), to skip the shards a
        # question does not meet: the manifest's groups, or (written before them) its box
        self._lo, self._hi = [], []
        for j, e in enumerate(shards):
            glo, ghi = _groups(e, self._n, where, j)
            self._lo.append(glo)
            self._hi.append(ghi)
        # each shard's cell of space, when the sharded search cut its regions by space
        # (``lo <= x < hi``, from the regions' centres): ``locate`` asks it first
        self._cells = [_cell(e, self._n) for e in shards]
        # a halo (``law_halo``): every shard names its halo file and the cells partition
        # space, so a box question reads the shards (and halos) of the cells it meets
        self._halo = None
        if any("halo_file" in e for e in shards):
            from codev_engine.law_halo import cells_partition

            if not all("halo_file" in e for e in shards) or any(c is None for c in self._cells):
                raise SpecError("a law with a halo must name every shard's halo file and "
                                "cell", file=where, field="shards")
            lo = np.array([c[0] for c in self._cells])
            hi = np.array([c[1] for c in self._cells])
            # (cells that are no partition of space: the halo is not used, the group boxes
            # answer, as exactly)
            if cells_partition(lo, hi):
                self._halo = (lo, hi)
        self._halos: OrderedDict[int, object] = OrderedDict()
        # the domain, when the manifest holds it (the sharded search's workers write their
        # shards before it is known); else the shards' own
        self._domain = None
        if data.get("domain_A") is not None:
            self._domain = _matrix(data, "domain_A", "domain_b", self._n, where)
        # the sharded search's: the parameter set's rows here, each shard's facets of the
        # domain in its own file (read when a box meets the shard)
        self._set = None
        if data.get("parameter_set_A") is not None:
            self._set = _matrix(data, "parameter_set_A", "parameter_set_b", self._n, where)
            if not all("facets_file" in e for e in shards):
                raise SpecError("a law with the parameter set's rows must name every "
                                "shard's facets file", file=where, field="shards")
        self._facets: dict[int, np.ndarray] = {}  # (the boundary: small, all kept)
        self._whole_domain: tuple[np.ndarray, np.ndarray] | None = None
        self._cache: OrderedDict[int, ExplicitLaw] = OrderedDict()
        self._most = max(1, int(cache))
        self.loads = 0  # shard (and halo) files read (and checked) so far
        self.asked = 0  # (point, shard) pairs ``locate`` has looked up in a shard so far
        # (box, shard) pairs ``regions_meeting`` and ``domain_rows`` have looked up so far
        # (the shard, or its facets, read for them)
        self.met = 0
        self.A, self.b = _Rows(self, "A"), _Rows(self, "b")
        self.F, self.G = _Rows(self, "F"), _Rows(self, "G")

    @classmethod
    def load(cls, directory: str | os.PathLike, **kwargs) -> ShardedLaw:
        """The sharded law in ``directory`` (see the class).

        Parameters
        ----------
        directory : str or PathLike
            The folder holding ``shards.json`` and the shard files.
        **kwargs
            Passed on to the class (the number of shards kept in memory).

        Returns
        -------
        ShardedLaw
        """
        return cls(directory, **kwargs)

    # ---- shape -----------------------------------------------------------------------

    @property
    def num_regions(self) -> int:
        """The number of critical regions (over all shards)."""
        return int(self.offsets[-1])

    @property
    def shards(self) -> int:
        """The number of shard files."""
        return len(self.offsets) - 1

    @property
    def n(self) -> int:
        """The length of ``theta``."""
        return self._n

    @property
    def m(self) -> int:
        """The input dimension."""
        return self._m

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the law's parameter ``theta`` (as ``ExplicitLaw.parameter_names``)."""
        return self.parameters or self.states

    @property
    def local_domain(self) -> bool:
        """The domain is held as each shard's facets (see the class)."""
        return self._set is not None

    @property
    def domain_A(self) -> np.ndarray | None:
        """The law's domain rows (the manifest's; with :attr:`local_domain` the parameter
        set's rows and every shard's facets, read now: for a consumer of the whole law,
        an exporter or a picture; else every shard holds them: read from the first)."""
        if self._set is not None:
            return self._whole()[0]
        return self._domain[0] if self._domain is not None else self.shard(0).domain_A

    @property
    def domain_b(self) -> np.ndarray | None:
        """The right-hand side of :attr:`domain_A`."""
        if self._set is not None:
            return self._whole()[1]
        return self._domain[1] if self._domain is not None else self.shard(0).domain_b

    def _whole(self) -> tuple[np.ndarray, np.ndarray]:
        """The parameter set's rows and every shard's facets, each once (a facet of the
        domain split between shards is in each)."""
        if self._whole_domain is None:
            from codev_engine.geometry.polytope import unique_rows

            rows = np.vstack([np.hstack([self._set[0], self._set[1][:, None]])]
                             + [self.facets(j) for j in range(self.shards)])
            rows = rows[unique_rows(rows, 9)] if rows.shape[0] else rows
            self._whole_domain = (rows[:, :-1], rows[:, -1])
        return self._whole_domain

    def facets(self, j: int) -> np.ndarray:
        """Shard ``j``'s facets of the law's domain, read and checked on first use.

        Parameters
        ----------
        j : int

        Returns
        -------
        (q, n + 1) ndarray
            Rows ``[a, beta]``: ``a theta <= beta`` holds on the whole domain (none for a
            law without facets files).

        Raises
        ------
        SpecError
            The file is missing, is not the one the manifest records, or is malformed.
        """
        got = self._facets.get(j)
        if got is not None:
            return got
        entry = self._entries[j]
        if "facets_file" not in entry:
            return np.zeros((0, self.n + 1))
        try:
            F = self._read_facets(entry)
        except DamagedFileError as exc:
            raise self._damaged(exc) from None
        self._facets[j] = F
        return F

    def _read_facets(self, entry: dict) -> np.ndarray:
        """A shard's facets file, checked (``DamagedFileError``: see :meth:`facets`)."""
        path = _checked(self.dir / entry["facets_file"], entry["facets_sha256"],
                        _size({"bytes": entry.get("facets_bytes")}),
                        "a shard's facets of the law's domain")
        try:
            with np.load(path, allow_pickle=False) as z:
                tag, F = str(z["format"]), np.asarray(z["facets"], dtype=float)
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            raise DamagedFileError("unreadable facets file", file=str(path)) from None
        if (tag != FACETS_FORMAT or F.shape != (entry["facets"], self.n + 1)
                or not np.all(np.isfinite(F))):
            raise DamagedFileError(f"not the facets {MANIFEST} records (format, count or "
                                   "values)", file=str(path))
        return F

    def _damaged(self, exc: DamagedFileError) -> DamagedFileError:
        """The error to raise for a file found damaged: :attr:`on_damaged`'s, if set."""
        return exc if self.on_damaged is None else self.on_damaged(exc)

    def __getstate__(self) -> dict:
        # (the callback is its opener's, in this process: see on_damaged)
        return {**self.__dict__, "on_damaged": None}

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes of every region, (k, n) each (reads every shard)."""
        parts = [self.shard(j).boxes for j in range(self.shards)]
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    # ---- the shards ------------------------------------------------------------------

    def shard(self, j: int) -> ExplicitLaw:
        """Shard ``j`` as an ``ExplicitLaw`` (its regions ``offsets[j]:offsets[j + 1]``),
        read and checked on first use.

        Parameters
        ----------
        j : int
            The shard's index, ``0 <= j < shards``.

        Returns
        -------
        ExplicitLaw

        Raises
        ------
        DamagedFileError
            The file is missing, is not the one the manifest records (its size, its
            SHA-256), or is not a law of this problem.
        """
        got = self._cache.get(j)
        if got is not None:
            self._cache.move_to_end(j)
            return got
        entry = self._entries[j]
        try:
            path = _checked(self.dir / entry["file"], entry["sha256"], _size(entry),
                            "a shard of the law")
            law = ExplicitLaw.load(path)
            if law.num_regions != entry["regions"] or law.fingerprint != self.fingerprint:
                raise DamagedFileError(f"not the shard {MANIFEST} records (regions or "
                                       "fingerprint)", file=str(path))
        except DamagedFileError as exc:
            raise self._damaged(exc) from None
        self.loads += 1
        self._cache[j] = law
        while len(self._cache) > self._most:
            self._cache.popitem(last=False)
        return law

    @property
    def has_halo(self) -> bool:
        """Each shard also holds copies of the regions reaching into its cell
        (``law_halo``): a box question reads the shards of the cells it meets alone."""
        return self._halo is not None

    def halo(self, c: int):
        """Cell ``c``'s halo (``law_halo.Halo``), read and checked on first use (at most
        ``cache`` held, as the shards).

        Parameters
        ----------
        c : int

        Returns
        -------
        law_halo.Halo

        Raises
        ------
        DamagedFileError
            The file is missing, is not the one the manifest records (its size, its
            SHA-256) or is malformed.
        """
        from codev_engine.law_halo import read_halo

        got = self._halos.get(c)
        if got is not None:
            self._halos.move_to_end(c)
            return got
        entry = self._entries[c]
        try:
            path = _checked(self.dir / entry["halo_file"], entry["halo_sha256"],
                            _size({"bytes": entry.get("halo_bytes")}),
                            "a shard's halo: copies of the regions reaching into its cell")
            got = read_halo(path, entry, self.n, self.m, {
                "states": self.states, "inputs": self.inputs,
                "parameters": self.parameters, "fingerprint": self.fingerprint})
            if got.owner.size and (got.owner[0] < 0 or got.owner[-1] >= self.num_regions):
                raise DamagedFileError("not the halo shards.json records (a region's "
                                       "index)", file=str(path))
        except DamagedFileError as exc:
            raise self._damaged(exc) from None
        self.loads += 1
        self._halos[c] = got
        while len(self._halos) > self._most:
            self._halos.popitem(last=False)
        return got

    def _source(self, i: int) -> tuple[ExplicitLaw, int]:
        """A law holding region ``i`` and its index there: its shard when held, else a
        held halo's copy of it, else its shard read (the rows of a region a box question
        found in a halo are read from the halo)."""
        j, q = self._where(i)
        if j not in self._cache:
            for h in reversed(self._halos.values()):
                k = h.index(i)
                if k >= 0:
                    return h.law, k
        return self.shard(j), q

    def _cells_meeting(self, lo: np.ndarray, hi: np.ndarray) -> list[int]:
        """The cells whose (closed) box meets ``[lo, hi]`` (at the boxes' tolerance, on
        both): with a halo, the shards a box question reads (:attr:`met` counts them)."""
        clo, chi = self._halo
        met = np.flatnonzero(np.all(clo <= hi + 2 * _BOX_TOL, axis=1)
                             & np.all(chi >= lo - 2 * _BOX_TOL, axis=1))
        self.met += int(met.size)
        return [int(c) for c in met]

    def _where(self, i: int) -> tuple[int, int]:
        """(shard, index in it) of region ``i``."""
        if not 0 <= i < self.num_regions:
            raise IndexError(f"region {i} of a law of {self.num_regions}")
        j = int(np.searchsorted(self.offsets, i, side="right")) - 1
        return j, i - int(self.offsets[j])

    def _meets(self, j: int, lo: np.ndarray, hi: np.ndarray) -> bool:
        """One of shard ``j``'s group boxes meets ``[lo, hi]`` (``ExplicitLaw``'s test of
        a region's box, at its tolerance: every region box that meets it is in one)."""
        met = bool(np.any(np.all(self._lo[j] <= hi + _BOX_TOL, axis=1)
                          & np.all(self._hi[j] >= lo - _BOX_TOL, axis=1)))
        self.met += met
        return met

    def _holding(self, j: int, X: np.ndarray) -> np.ndarray:
        """(P,) bool: which points one of shard ``j``'s group boxes holds."""
        out = np.zeros(X.shape[0], dtype=bool)
        for glo, ghi in zip(self._lo[j], self._hi[j], strict=True):
            out |= (np.all(X >= glo - _BOX_TOL, axis=1) & np.all(X <= ghi + _BOX_TOL, axis=1))
        return out

    # ---- the interface of the reach engines ------------------------------------------

    def regions_meeting(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The regions whose bounding box meets ``[lo, hi]`` (``ExplicitLaw``'s answer),
        from the shards one of whose group boxes meets it alone; with a halo, the shards
        and halos of the cells it meets alone (:attr:`met` counts them).

        Parameters
        ----------
        lo, hi : (n,) ndarray

        Returns
        -------
        (q,) ndarray of int
            Ascending.
        """
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        if self._halo is not None:
            # (every region whose box meets the box meets it in a cell the box meets: that
            # cell's shard holds it, or its halo a copy; each region once, by its index)
            found = []
            for c in self._cells_meeting(lo, hi):
                found.append(self.shard(c).regions_meeting(lo, hi) + self.offsets[c])
                h = self.halo(c)
                found.append(h.owner[h.law.regions_meeting(lo, hi)])
            return (np.unique(np.concatenate(found)) if found
                    else np.zeros(0, dtype=np.int64))
        found = [self.shard(j).regions_meeting(lo, hi) + self.offsets[j]
                 for j in range(self.shards) if self._meets(j, lo, hi)]
        return np.concatenate(found) if found else np.zeros(0, dtype=np.int64)

    def domain_rows(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Rows of the law's domain ``D`` valid on all of it that describe it inside the
        box ``[lo, hi]``.

        With :attr:`local_domain`: the parameter set's rows and the facets of the shards
        one of whose group boxes meets the box (every facet of ``D`` that meets the box is
        among them: a region's box that holds a point of it is in a group box); with a
        halo, the facets of the shards and halos of the cells the box meets (the facet
        meets the box in such a cell: ``law_halo`` says why they hold it), so
        when the box meets ``D`` a point of the box is in ``D`` exactly when it satisfies
        them all (docs/scale.md, "The domain's facets in the shards"). When the box misses
        ``D`` they may all hold on part of it: as ``law_on_demand.OnDemandLaw.domain_rows``,
        the engine then finds no region for the set there. Otherwise the whole domain
        (``ExplicitLaw.domain_rows``: the same whatever the box).

        Parameters
        ----------
        lo, hi : (n,) ndarray

        Returns
        -------
        (A, b) or None
            ``(q, n)``, ``(q,)``; None when the law holds no domain.
        """
        if self._set is None:
            return None if self.domain_A is None else (self.domain_A, self.domain_b)
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        if self._halo is not None:
            # (a facet meeting the box meets it in a cell the box meets: among that cell's
            # facets or its halo's; ``law_halo`` says why)
            met = self._cells_meeting(lo, hi)
            parts = [p for c in met for p in (self.facets(c), self.halo(c).facets)]
        else:
            parts = [self.facets(j) for j in range(self.shards) if self._meets(j, lo, hi)]
        rows = np.vstack([np.hstack([self._set[0], self._set[1][:, None]])] + parts)
        return rows[:, :-1], rows[:, -1]

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index of each point (-1 outside the domain), from a shard whose regions
        hold it: first the shard whose cell holds the point (a manifest of the sharded
        search: ``cell_lo``, ``cell_hi``), then the others one of whose group boxes holds
        it, in the manifest's order (:attr:`asked` counts the look-ups).

        Parameters
        ----------
        X : (P, n) or (n,) array_like

        Returns
        -------
        (P,) ndarray of int
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != self.n:
            raise ValueError(f"expected theta of dimension {self.n}, got {X.shape[1]}")
        out = np.full(X.shape[0], -1, dtype=np.int64)
        # a point clearly outside the domain is in no region: no shard is read for it
        # (the margin is far above the locator's tolerance, 1e-9 on unit rows)
        outside = np.zeros(X.shape[0], dtype=bool)
        # (with the facets in the shards, the parameter set's rows: the manifest's)
        known = self._domain if self._set is None else self._set
        if known is not None and known[0].shape[0]:
            dA, db = known
            norm = np.maximum(np.linalg.norm(dA, axis=1), 1e-300)
            outside = np.any((X @ dA.T - db) / norm > 1e-6 * (1.0 + np.abs(db) / norm),
                             axis=1)
        # first the shard whose cell holds the point (most regions about a point have
        # their centre in its cell), then any other one of whose group boxes holds it
        first = np.full(X.shape[0], -1, dtype=np.int64)
        for j, cell in enumerate(self._cells):
            if cell is not None:
                first[np.all((X >= cell[0]) & (X < cell[1]), axis=1)] = j
        for j in range(self.shards):
            self._ask(j, X, np.flatnonzero((first == j) & ~outside), out)
        for j in range(self.shards):
            self._ask(j, X, np.flatnonzero((out < 0) & ~outside & (first != j)), out)
        return out

    def _ask(self, j: int, X: np.ndarray, todo: np.ndarray, out: np.ndarray) -> None:
        """Locate the points ``X[todo]`` that shard ``j``'s group boxes hold in its
        regions."""
        if not todo.size:
            return
        near = todo[self._holding(j, X[todo])]
        if near.size:
            self.asked += int(near.size)
            idx = self.shard(j).locate(X[near])
            hit = idx >= 0
            out[near[hit]] = idx[hit] + self.offsets[j]

    def shards_at(self, X: np.ndarray) -> np.ndarray:
        """How many shards' group boxes (their boxes, in a manifest written before the
        groups) hold each point: the shards :meth:`locate` may read for it (from the
        manifest alone; a measure of how the shards cut space).

        Parameters
        ----------
        X : (P, n) array_like

        Returns
        -------
        (P,) ndarray of int
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        out = np.zeros(X.shape[0], dtype=np.int64)
        for j in range(self.shards):
            out += self._holding(j, X)
        return out

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """The control ``u = F_i x + G_i`` (NaN rows outside the domain).

        Parameters
        ----------
        X : (P, n) or (n,) array_like

        Returns
        -------
        (P, m) ndarray
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        idx = self.locate(X)
        U = np.full((X.shape[0], self.m), np.nan)
        for j in range(self.shards):
            sel = np.flatnonzero((idx >= self.offsets[j]) & (idx < self.offsets[j + 1]))
            if sel.size:
                law = self.shard(j)
                q = idx[sel] - self.offsets[j]
                U[sel] = np.einsum("pij,pj->pi", law.F[q], X[sel]) + law.G[q]
        return U

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.evaluate(X)

    # ---- the whole law, on demand ----------------------------------------------------

    def merged(self) -> ExplicitLaw:
        """Every shard in one ``ExplicitLaw`` (the regions in the shards' order).

        Returns
        -------
        ExplicitLaw
            With the shards' boxes; what a consumer of the whole table (an exporter of
            one C array) reads.
        """
        parts = [self.shard(j) for j in range(self.shards)]
        law = ExplicitLaw(
            A=[a for p in parts for a in p.A], b=[b for p in parts for b in p.b],
            F=np.concatenate([p.F for p in parts]), G=np.concatenate([p.G for p in parts]),
            states=self.states, inputs=self.inputs, fingerprint=self.fingerprint,
            meta=dict(self.meta, shards=self.shards), domain_A=self.domain_A,
            domain_b=self.domain_b, parameters=self.parameters,
        )
        law._boxes = (np.concatenate([p.boxes[0] for p in parts]),
                      np.concatenate([p.boxes[1] for p in parts]))
        return law

    def summary(self) -> str:
        """A few lines of text: the regions, the shards and the problem's metadata."""
        rows = [f"explicit law: {self.num_regions} regions in {self.shards} shards, "
                f"n={self.n}, m={self.m}"]
        for key in ("problem", "norm", "horizon", "seconds"):
            if key in self.meta:
                rows.append(f"  {key}: {self.meta[key]}")
        return "\n".join(rows)

    def __repr__(self) -> str:
        return f"ShardedLaw(num_regions={self.num_regions}, shards={self.shards}, n={self.n})"
