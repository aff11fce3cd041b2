"""The explicit solution of an ``MpProgram``: critical regions with affine optimizers.

Saved as a plain ``.npz`` (format tag ``codev-mp-solution/2``, no pickle): the program's
own arrays under a ``program.`` prefix, the regions' own rows concatenated with an offset
array, the rows they share (the parameter set's) once with a flag per region, the affine
laws stacked. Format 1 files (every row in its region, no shared rows) are still read.
"""

from __future__ import annotations

import json
import operator
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import numpy as np

from codev_engine.errors import SolverError, SpecError
from codev_engine.geometry.locate import PointLocator
from codev_engine.io.npz import NpzFormat, array, load_npz, offsets, real, save_npz, text
from codev_engine.mp.program import MpProgram

__all__ = [
    "CriticalRegion", "MpSolution", "RegionArrays", "SOLUTION_FORMAT", "TooManyRegionsError",
    "too_many_regions",
]

#: format tag of solution files; bumped on incompatible changes
SOLUTION_FORMAT = "codev-mp-solution/2"
#: format 1: every region with all its rows (no shared rows); still read
_FORMAT_1 = "codev-mp-solution/1"
_SOLUTION_FILE = NpzFormat("solution file", SOLUTION_FORMAT, "solution", reads=(_FORMAT_1,))
#: solutions of more bytes are saved uncompressed
_COMPRESS_BELOW = 1 << 26


@dataclass(frozen=True)
class CriticalRegion:
    """A region ``{theta : A theta <= b}`` where ``z*(theta) = K theta + k``.

    Attributes
    ----------
    A : (r, d) ndarray
        Non-redundant, unit-norm rows.
    b : (r,) ndarray
    K : (nz, d) ndarray
    k : (nz,) ndarray
    active : tuple of int
        The optimal active set (QP) or basis (LP), as row indices of the reduced program.
    """

    A: np.ndarray
    b: np.ndarray
    K: np.ndarray
    k: np.ndarray
    active: tuple[int, ...] = ()


class RegionArrays(Sequence[CriticalRegion]):
    """Critical regions packed in flat arrays (what a solution of millions of regions holds).

    A sequence of ``CriticalRegion``: ``ra[i]`` builds region ``i`` (views of the arrays,
    plus a copy of its rows when it has shared ones). Bulk code (locating, saving, the
    domain) reads the arrays themselves.

    Parameters
    ----------
    A, b : (q, d), (q,) ndarrays
        The regions' own rows, region after region.
    offsets : (R + 1,) int64
        Region ``i``'s own rows are ``A[offsets[i]:offsets[i + 1]]``.
    K, k : (R, nz, d), (R, nz) ndarrays
        The laws.
    active, active_offsets : (s,), (R + 1,) int64
        The active sets, laid out as the rows.
    implied : (R,) bool, optional
        Regions whose rows go on with ``shared_A theta <= shared_b`` (the parameter set's
        rows, which every region of an mp-QP has: held once, not a million times).
    shared_A, shared_b : (p, d), (p,) ndarrays, optional
    """

    def __init__(
        self,
        A: np.ndarray,
        b: np.ndarray,
        offsets: np.ndarray,
        K: np.ndarray,
        k: np.ndarray,
        active: np.ndarray,
        active_offsets: np.ndarray,
        implied: np.ndarray | None = None,
        shared_A: np.ndarray | None = None,
        shared_b: np.ndarray | None = None,
    ):
        R, d = K.shape[0], A.shape[1]
        self.A, self.b, self.offsets = A, b, np.asarray(offsets, dtype=np.int64)
        self.K, self.k = K, k
        self.active = np.asarray(active, dtype=np.int64)
        self.active_offsets = np.asarray(active_offsets, dtype=np.int64)
        self.implied = np.zeros(R, dtype=bool) if implied is None else np.asarray(implied, bool)
        self.shared_A = np.zeros((0, d)) if shared_A is None else shared_A
        self.shared_b = np.zeros(0) if shared_b is None else shared_b

    @classmethod
    def from_regions(
        cls, regions: Sequence[CriticalRegion], nz: int = 0, d: int = 0
    ) -> RegionArrays:
        """Pack ``regions`` into flat arrays (no region has shared rows).

        Parameters
        ----------
        regions : sequence of CriticalRegion
            Returned as it is when it is a ``RegionArrays`` already.
        nz, d : int
            The shapes of the laws when there are no regions (else taken from them).

        Returns
        -------
        RegionArrays
        """
        if isinstance(regions, RegionArrays):
            return regions
        n = len(regions)
        if n:
            nz, d = regions[0].K.shape
        off = np.zeros(n + 1, dtype=np.int64)
        np.cumsum([r.A.shape[0] for r in regions], out=off[1:])
        aoff = np.zeros(n + 1, dtype=np.int64)
        np.cumsum([len(r.active) for r in regions], out=aoff[1:])
        return cls(
            np.vstack([r.A for r in regions]) if n else np.zeros((0, d)),
            np.concatenate([r.b for r in regions]) if n else np.zeros(0),
            off,
            np.stack([r.K for r in regions]) if n else np.zeros((0, nz, d)),
            np.stack([r.k for r in regions]) if n else np.zeros((0, nz)),
            np.fromiter((i for r in regions for i in r.active), np.int64, int(aoff[-1])),
            aoff,
        )

    def __len__(self) -> int:
        return self.K.shape[0]

    @overload
    def __getitem__(self, i: int) -> CriticalRegion: ...

    @overload
    def __getitem__(self, i: slice) -> list[CriticalRegion]: ...

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        n = len(self)
        i = operator.index(i)
        if not -n <= i < n:
            raise IndexError(f"region {i} of {n}")
        i %= n
        A, b = self.rows(i)
        a0, a1 = self.active_offsets[i], self.active_offsets[i + 1]
        return CriticalRegion(
            A=A, b=b, K=self.K[i], k=self.k[i], active=tuple(self.active[a0:a1].tolist())
        )

    def rows(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Region ``i``'s rows, the shared ones included.

        Parameters
        ----------
        i : int

        Returns
        -------
        A : (r, d) ndarray
        b : (r,) ndarray
            Views of the arrays, or a copy when the region has shared rows.
        """
        r0, r1 = self.offsets[i], self.offsets[i + 1]
        if not self.implied[i]:
            return self.A[r0:r1], self.b[r0:r1]
        return (
            np.vstack([self.A[r0:r1], self.shared_A]),
            np.concatenate([self.b[r0:r1], self.shared_b]),
        )

    def num_rows(self) -> np.ndarray:
        """Rows per region, the shared ones included: (R,) int."""
        return np.diff(self.offsets) + self.implied * self.shared_b.size

    def take(self, idx: np.ndarray) -> RegionArrays:
        """The regions ``idx``, in that order (copies of their rows).

        Parameters
        ----------
        idx : (n,) array_like of int

        Returns
        -------
        RegionArrays
            With the same shared rows.
        """
        idx = np.asarray(idx, dtype=np.int64)
        o, a = self.offsets, self.active_offsets
        rows, off = segment_indices(o[idx], o[idx + 1] - o[idx])
        acts, aoff = segment_indices(a[idx], a[idx + 1] - a[idx])
        return RegionArrays(
            self.A[rows], self.b[rows], off, self.K[idx], self.k[idx], self.active[acts], aoff,
            self.implied[idx], self.shared_A, self.shared_b,
        )

    @classmethod
    def concat(cls, parts: list[RegionArrays], consume: bool = False) -> RegionArrays:
        """The regions of ``parts`` one after the other (their shared rows must agree
        where they have implied regions). ``consume``: each part is dropped from the list
        once copied, so that the copy and the parts are not all held at once (the result
        is allocated empty, and its pages are touched only as they are filled).

        Parameters
        ----------
        parts : list of RegionArrays
        consume : bool
            Empty ``parts`` as they are copied (and give the freed memory back).

        Returns
        -------
        RegionArrays

        Raises
        ------
        ValueError
            When parts with implied regions have different shared rows.
        """
        live = [p for p in parts if len(p)] or list(parts[:1])
        src = next((p for p in live if p.implied.any()), live[0])
        for p in live:
            if p.implied.any() and not (
                np.array_equal(p.shared_A, src.shared_A)
                and np.array_equal(p.shared_b, src.shared_b)
            ):
                raise ValueError("regions with different shared rows")
        R = sum(len(p) for p in live)
        q = sum(p.A.shape[0] for p in live)
        s = sum(p.active.size for p in live)
        (nz, d), dt = src.K.shape[1:], src.A.dtype
        out = cls(
            np.empty((q, d), dt), np.empty(q), np.zeros(R + 1, np.int64),
            np.empty((R, nz, d)), np.empty((R, nz)), np.empty(s, np.int64),
            np.zeros(R + 1, np.int64), np.empty(R, bool), src.shared_A, src.shared_b,
        )
        r = i = a = 0
        if consume:
            parts[:] = live
            live = parts
        freed = 0
        for n in range(len(live)):
            p = live[n]
            nr, ni, na = len(p), p.A.shape[0], p.active.size
            out.A[i : i + ni] = p.A
            out.b[i : i + ni] = p.b
            out.offsets[r + 1 : r + nr + 1] = p.offsets[1:] + i
            out.K[r : r + nr] = p.K
            out.k[r : r + nr] = p.k
            out.active[a : a + na] = p.active
            out.active_offsets[r + 1 : r + nr + 1] = p.active_offsets[1:] + a
            out.implied[r : r + nr] = p.implied
            r, i, a = r + nr, i + ni, a + na
            if consume:
                live[n] = None  # type: ignore[call-overload]
                freed += p.A.nbytes + p.K.nbytes
                del p
                if freed > _TRIM_BYTES:
                    freed = 0
                    _trim_heap()
        if consume:
            parts.clear()
            _trim_heap()
        return out

    def active_order(self) -> np.ndarray:
        """The permutation that sorts the regions by active set (as tuples sort)."""
        n = len(self)
        sizes = np.diff(self.active_offsets)
        width = int(sizes.max(initial=0))
        pad = np.full((n, width), -1, dtype=np.int64)  # a prefix sorts first, as in tuples
        cols = np.arange(self.active.size) - np.repeat(self.active_offsets[:-1], sizes)
        pad[np.repeat(np.arange(n), sizes), cols] = self.active
        return np.lexsort(pad.T[::-1]) if width else np.arange(n)


def segment_indices(starts: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The indices ``starts[i] .. starts[i] + sizes[i] - 1`` of consecutive segments, one
    after the other (q,), and where each begins in them (n + 1,)."""
    off = np.zeros(sizes.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=off[1:])
    return np.arange(off[-1]) - np.repeat(off[:-1] - starts, sizes), off


class TooManyRegionsError(SolverError):
    """The search passed ``SolveOptions.max_regions`` (the message: :func:`too_many_regions`)."""


def too_many_regions(limit: int) -> str:
    """The message of the solver's safety stop on the number of regions.

    Parameters
    ----------
    limit : int
        The largest number of regions allowed.

    Returns
    -------
    str
    """
    return (
        f"more than {limit:,} regions: the safety stop (raise it with --max-regions or "
        "SolveOptions.max_regions; a region of the CDC-24 set holds ~2.5 KB)"
    )


#: bytes of parts freed between two heap trims in ``RegionArrays.concat(consume=True)``
_TRIM_BYTES = 1 << 28


def _trim_heap() -> None:
    """Give the heap's free pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere). Arrays under glibc's mmap threshold (up to 32 MB) live on the heap: the
    walk's parts, freed as they are copied, would otherwise stay resident beside the copy
    (3.7 instead of 2.1 GB at the end of pop_mpqp_033)."""
    global _LIBC
    if _LIBC is None:
        try:
            import ctypes

            _LIBC = ctypes.CDLL("libc.so.6")
            _LIBC.malloc_trim.argtypes = [ctypes.c_size_t]
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC.malloc_trim(0)


_LIBC = None


@dataclass
class MpSolution:
    """Explicit solution of an ``MpProgram``: a partition of its feasible parameter set.

    Attributes
    ----------
    program : MpProgram
    regions : RegionArrays
        A sequence of ``CriticalRegion``, packed (a list given here is packed), in the
        original variables ``z`` (equalities eliminated internally are mapped back).
    domain_A, domain_b : ndarray
        The feasible parameter set (the union of the regions) as ``domain_A theta <=
        domain_b``: its facets, non-redundant up to 5,000 rows (above that a row may
        also only touch the set; see docs/algorithm.md).
    seconds : float
        Wall time of the solve.
    stats : dict
        Counters of the solve, for reports (``codev mpsolve --json`` prints them). mp-QP:
        ``candidates`` (active sets evaluated), split by class into ``candidates_full``,
        ``candidates_empty``, ``candidates_lower`` (lower-dimensional), ``candidates_licq``
        (dependent constraints) and ``candidates_singular`` (semi-definite H only);
        ``lps`` (candidates that took an LP), ``explored`` (active sets pushed), ``jit``
        (whether the compiled kernel ran), ``handed_back`` (candidates it left to the numpy kernel),
        ``workers`` (threads or processes, when parallel), ``merged`` (regions merged
        into others by equal laws). mp-LP: ``solves``, ``pieces``, ``jitters``,
        ``step_refinements`` and counters of rarer steps (``highs``, ``wedges``, ...).
        Keys appear once they count something; none of them is part of the result.
    """

    program: MpProgram
    regions: RegionArrays
    domain_A: np.ndarray | None = None
    domain_b: np.ndarray | None = None
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)
    _locator: PointLocator | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        # (a list of regions is packed: the solution holds flat arrays)
        self.regions = RegionArrays.from_regions(self.regions, self.program.nz, self.program.d)

    @property
    def num_regions(self) -> int:
        """The number of critical regions."""
        return len(self.regions)

    @property
    def locator(self) -> PointLocator:
        """The point locator on the regions (the shared rows held once), built on first use."""
        if self._locator is None:
            ra = self.regions
            self._locator = PointLocator.packed(
                ra.A, ra.b, ra.offsets, shared=(ra.shared_A, ra.shared_b), implied=ra.implied
            )
        return self._locator

    def _theta(self, Theta: np.ndarray) -> np.ndarray:
        Theta = np.atleast_2d(np.asarray(Theta, dtype=float))
        if Theta.shape[1] != self.program.d:
            raise ValueError(
                f"expected parameters of dimension {self.program.d}, got {Theta.shape[1]}"
            )
        return Theta

    def locate(self, Theta: np.ndarray) -> np.ndarray:
        """The region of each parameter (see :meth:`PointLocator.locate`).

        Parameters
        ----------
        Theta : (P, d) or (d,) array_like

        Returns
        -------
        (P,) ndarray of int
            -1 outside the feasible set.

        Raises
        ------
        ValueError
            When the parameters are not of dimension ``d``.
        """
        return self.locator.locate(self._theta(Theta))

    def primal(self, Theta: np.ndarray) -> np.ndarray:
        """The optimizer ``z*(theta) = K_i theta + k_i`` of each parameter.

        Parameters
        ----------
        Theta : (P, d) or (d,) array_like

        Returns
        -------
        (P, nz) ndarray
            NaN rows outside the feasible set.
        """
        Theta = self._theta(Theta)
        idx = self.locate(Theta)
        Z = np.full((Theta.shape[0], self.program.nz), np.nan)
        K, k = self.regions.K, self.regions.k
        inside = idx >= 0
        Z[inside] = np.einsum("pij,pj->pi", K[idx[inside]], Theta[inside]) + k[idx[inside]]
        return Z

    def value(self, Theta: np.ndarray) -> np.ndarray:
        """The optimal value ``0.5 z'Hz + (c + C theta)'z`` of each parameter.

        Parameters
        ----------
        Theta : (P, d) or (d,) array_like

        Returns
        -------
        (P,) ndarray
            NaN outside the feasible set.
        """
        Theta = self._theta(Theta)
        Z = self.primal(Theta)
        p = self.program
        lin = p.c[None, :] + Theta @ p.C.T
        return 0.5 * np.einsum("pi,ij,pj->p", Z, p.H, Z) + np.einsum("pi,pi->p", lin, Z)

    def summary(self) -> str:
        """One line: the program's kind and name, its regions, sizes and solve time."""
        p = self.program
        return (
            f"{p.kind} {p.name or ''}: {self.num_regions} critical regions "
            f"(nz={p.nz}, d={p.d}) in {self.seconds:.3f} s"
        ).replace("  ", " ")

    def __repr__(self) -> str:
        return (
            f"MpSolution(num_regions={self.num_regions}, nz={self.program.nz}, d={self.program.d})"
        )

    # ---- persistence -----------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write the solution (and its program) to ``path`` (``.npz``, format
        ``SOLUTION_FORMAT``) atomically; a large one uncompressed.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.
        """
        p = self.program
        d = p.d
        ra = self.regions
        arrays: dict[str, np.ndarray] = {
            "A": ra.A,
            "b": ra.b,
            "offsets": ra.offsets,
            "K": ra.K,
            "k": ra.k,
            "active": ra.active,
            "active_offsets": ra.active_offsets,
            "implied": ra.implied,
            "shared_A": ra.shared_A,
            "shared_b": ra.shared_b,
            "domain_A": self.domain_A if self.domain_A is not None else np.zeros((0, d)),
            "domain_b": self.domain_b if self.domain_b is not None else np.zeros(0),
            "meta": np.array(json.dumps({"seconds": self.seconds, "name": p.name})),
        }
        for key in ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq"):
            val = getattr(p, key)
            if val is not None:
                arrays[f"program.{key}"] = val
        # (large solutions uncompressed: deflating 10 GB of rows took 5 minutes)
        size = sum(a.nbytes for a in arrays.values())
        return save_npz(path, _SOLUTION_FILE, arrays, compress=size < _COMPRESS_BELOW)

    @classmethod
    def load(cls, path: str | os.PathLike) -> MpSolution:
        """Read a solution written by :meth:`save` (format 2, or format 1).

        Parameters
        ----------
        path : path-like

        Returns
        -------
        MpSolution

        Raises
        ------
        SpecError
            The file is missing or malformed (naming the file and the array).
        """
        return load_npz(path, _SOLUTION_FILE, cls._from_arrays)

    @classmethod
    def _from_arrays(cls, data: dict[str, np.ndarray]) -> MpSolution:
        fmt = text(data, "format")  # (checked by load_npz: this one or format 1)
        prog = {k[len("program.") :]: v for k, v in data.items() if k.startswith("program.")}
        try:
            meta = json.loads(text(data, "meta"))
        except ValueError:
            raise SpecError("not valid JSON", field="meta") from None
        if not isinstance(meta, dict):
            raise SpecError("must be a JSON object", field="meta")
        for key in ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta"):
            if key not in prog:
                raise SpecError("missing array", field=f"program.{key}")
        try:
            program = MpProgram(**prog, name=str(meta.get("name", "")))
        except TypeError:
            raise SpecError("unknown program arrays", field="program") from None
        except SpecError as exc:
            raise SpecError(exc.reason, field=f"program.{exc.field}") from None
        d, nz = program.d, program.nz
        K = real(data, "K", ndim=3)
        R = K.shape[0]
        if K.shape[1:] != (nz, d):
            raise SpecError(f"must have shape ({R}, {nz}, {d}), got {K.shape}", field="K")
        k = real(data, "k", shape=(R, nz))
        A = real(data, "A", ndim=2)
        if A.shape[1] != d:
            raise SpecError(f"must have {d} columns, got {A.shape}", field="A")
        b = real(data, "b", shape=(A.shape[0],))
        off = offsets(data, "offsets", R, A.shape[0])
        act = array(data, "active")
        if act.dtype.kind not in "iu" or act.ndim != 1:
            raise SpecError("must be a 1-D integer array", field="active")
        aoff = offsets(data, "active_offsets", R, act.shape[0])
        dA = real(data, "domain_A", ndim=2)
        if dA.shape[1] != d:
            raise SpecError(f"must have {d} columns, got {dA.shape}", field="domain_A")
        db = real(data, "domain_b", shape=(dA.shape[0],))
        implied = shared_A = shared_b = None
        if fmt != _FORMAT_1:  # (format 1 has every row in its region)
            implied = array(data, "implied")
            if implied.dtype != np.bool_ or implied.shape != (R,):
                raise SpecError(f"must be a boolean array of shape ({R},)", field="implied")
            shared_A = real(data, "shared_A", ndim=2)
            if shared_A.shape[1] != d:
                raise SpecError(f"must have {d} columns, got {shared_A.shape}", field="shared_A")
            shared_b = real(data, "shared_b", shape=(shared_A.shape[0],))
        regions = RegionArrays(
            np.ascontiguousarray(A), b, off, K, k, act.astype(np.int64, copy=False), aoff, implied,
            shared_A, shared_b,
        )
        return cls(
            program=program,
            regions=regions,
            domain_A=dA,
            domain_b=db,
            seconds=float(meta.get("seconds", 0.0)),
        )


@dataclass
class ShardedSolution:
    """The explicit solution as a law held in shard files, each written by the worker that
    found its regions (``mpsolve(..., sharded=True, shard_writer=...)``): no region was in
    this process.

    Attributes
    ----------
    program : MpProgram
    law : object
        The sharded law (``law_shards.ShardedLaw``): ``locate``, ``evaluate``,
        ``regions_meeting``, ``merged()``, in the law's variables (``shard_writer.op``
        added to the program's ``theta``).
    op : (d,) ndarray
        ``shard_writer.op``: the law's ``theta`` is the program's plus ``op``.
    seconds : float
    stats : dict
        ``MpSolution``'s, and ``domain_facets`` (the feasible set's facets the shards
        found: each shard holds its own), ``finish_client_cpu_seconds`` (this process's
        end: the manifest, the coverage check).
    """

    program: MpProgram
    law: object
    op: np.ndarray
    seconds: float = 0.0
    stats: dict = field(default_factory=dict)

    @property
    def domain_A(self) -> np.ndarray:
        """The feasible parameter set's rows, in the program's ``theta`` (as
        ``MpSolution``'s, redundant rows of the parameter set kept): the law's domain,
        every shard's facets read now."""
        return self.law.domain_A

    @property
    def domain_b(self) -> np.ndarray:
        """The right-hand side of :attr:`domain_A` (the law's, shifted back by ``op``)."""
        return self.law.domain_b - self.law.domain_A @ self.op

    @property
    def num_regions(self) -> int:
        """The number of regions in the law's shards (equal laws merged within a shard)."""
        return int(self.law.num_regions)
