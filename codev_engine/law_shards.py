"""An explicit MPC law held as shards: one checked law file per shard, read when asked.

A law of millions of regions made by the sharded search (``mp/sharded.py``) need not be
whole in one process: ``law_shard_writer`` writes it as a folder of law files (each in
``ExplicitLaw``'s own format, ``law.LAW_FORMAT``, written atomically, with its regions'
bounding boxes) and a manifest, ``shards.json``, written last, that records each file's
SHA-256, its size, its number of regions, the bounding box of its regions and its
*groups*: at most ``law_shard_writer.GROUPS`` boxes, each the bounding box of a group of
its regions (a k-d split of their boxes, ``law_shard_writer.box_groups``), a summary of
fixed size whatever the regions. This module reads such a folder and checks it.
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

A law cut by space (the sharded search's; ``law_shard_writer.write_law_shards`` with
``cells``, from ``law_shard_writer.split_by_cells``) may hold a **halo** (``law_halo``):
each shard's cell's copies of the other shards' regions whose boxes reach into it, and the
facets of the domain that may meet it, in a checked side file ``halo-<j>.npz``. With it,
:meth:`ShardedLaw.regions_meeting` and :meth:`ShardedLaw.domain_rows` read the shards and
halos of the cells the box meets alone (:attr:`ShardedLaw.has_halo`; the cells are checked
to be a k-d partition of space when the manifest is read, else the halo is not used): the
same answers, from ~1.1 shards of 4 for a box of 1 % on ``pop_mpqp_051`` where the group
boxes read 3.99. A region found in a halo is read from it (``law.A[i]``), its own shard
unread.

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

import json
import os
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import numpy as np

from codev_engine.errors import DamagedFileError, SpecError
from codev_engine.io.digest import file_sha256
from codev_engine.law import ExplicitLaw

__all__ = ["FACETS_FORMAT", "SHARDS_FORMAT", "ShardedLaw", "manifest_files"]

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
    if file_sha256(path) != sha256:
        raise DamagedFileError(f"its SHA-256 is not the one {MANIFEST} records (damaged or "
                               "edited): refused", file=str(path))
    return path


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
        A folder of ``law_shard_writer.write_law_shards``.
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
