"""Rerun recordings (``.rrd``) of a design, for offline review in the Rerun viewer.

One file holds the law's partition, the specification's sets, the reachtube, simulated
closed-loop traces, the counterexample (if any), input and unsafe-margin time series, the
verdict, and a blueprint (the viewer layout). The entity layout is documented in
``docs/recordings.md``.

The file is written atomically (a ``.tmp-*`` file in the same folder, then a rename), with a
private ``rerun.RecordingStream``: the global/thread-local rerun recordings and the global
strict mode are left as they were.
"""

from __future__ import annotations

import colorsys
import os
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import combinations
from math import comb
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.errors import CodevError, SolverError, SpecError
from codev_engine.geometry.polytope import normalize_rows
from codev_engine.io.atomic import atomic_path
from codev_engine.law import ExplicitLaw
from codev_engine.spec.problem import Problem, SetSpec

if TYPE_CHECKING:
    from codev_engine.reach.tube import Tube
    from codev_engine.reach.verification import Counterexample, VerificationResult

__all__ = ["RecordingOptions", "RecordingSummary", "write_recording", "check_recording"]

#: application id of every recording (the viewer groups recordings and blueprints by it)
APPLICATION_ID = "codev"
#: the timeline of everything temporal (a duration, in seconds)
TIMELINE = "time"

# colours (RGB / RGBA, 0-255)
_RED = (220, 40, 40)
_GREEN = (40, 170, 60)
_BLUE = (40, 110, 230)
_TUBE = (255, 150, 0, 200)
_TRACE = (90, 90, 90)

#: vertex enumeration of one polytope gives up beyond this many d-subsets of its rows
_MAX_COMBOS = 50_000
#: batch size (polytopes x row subsets) of the vectorised vertex enumeration
_BATCH = 200_000


@dataclass(frozen=True)
class RecordingOptions:
    """What to record.

    Attributes
    ----------
    axes : (int, int)
        State indices of the plane view (a projection when n > 2); must be distinct and
        ``< n`` (``SpecError`` with ``field="axes"``). Ignored when n == 1 (no plane view).
    traces : int
        Closed-loop traces simulated from the initial set (centre, corners, then seeded
        random points); 0 for none.
    seed : int
        Seed of the random initial states.
    """

    axes: tuple[int, int] = (0, 1)
    traces: int = 16
    seed: int = 0


@dataclass(frozen=True)
class RecordingSummary:
    """What ``write_recording`` wrote.

    Attributes
    ----------
    path : Path
        The ``.rrd`` file.
    entities : dict of str to int
        Entity path -> number of instances logged (strips, boxes, meshed polytopes, scalar
        samples, documents; see ``docs/recordings.md``).
    boxes : int
        Tube boxes logged (``result.tube.num_boxes``, 0 without a result).
    traces : int
        Simulated traces logged (the counterexample not included).
    seconds : float
        Wall time of the whole call.
    """

    path: Path
    entities: dict[str, int] = field(default_factory=dict)
    boxes: int = 0
    traces: int = 0
    seconds: float = 0.0


# ---------------------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------------------


def write_recording(
    path: str | os.PathLike,
    problem: Problem,
    law: ExplicitLaw,
    result: VerificationResult | None = None,
    *,
    options: RecordingOptions = RecordingOptions(),  # noqa: B008 - frozen, immutable
) -> RecordingSummary:
    """Write a Rerun recording of a design (and of its verification) to ``path``.

    Parameters
    ----------
    path : str or PathLike
        The ``.rrd`` file to write; parent folders are created; an existing file is
        replaced atomically.
    problem : Problem
        The spec. Without a ``[verify]`` section there are no sets and no traces.
    law : ExplicitLaw
        The explicit law (its n, m must be the problem's).
    result : VerificationResult, optional
        The outcome of ``verify``; None records the partition and the sets only (no tube).
    options : RecordingOptions

    Returns
    -------
    RecordingSummary

    Raises
    ------
    SpecError
        Bad ``options``, a ``path`` that does not end in ``.rrd``, or a law that does not
        fit the problem.
    CodevError
        Rerun is disabled in this environment (``RERUN=off``) or the file came out
        incomplete.
    """
    t0 = time.perf_counter()
    path = Path(path)
    if path.suffix != ".rrd":
        raise SpecError(
            f"a recording must be a .rrd file (got suffix {path.suffix!r})", file=str(path)
        )
    n = problem.plant.n
    if law.n != n or law.m != problem.plant.m:
        raise SpecError(
            f"the law has n={law.n}, m={law.m} but the spec has n={n}, m={problem.plant.m}",
            file=problem.path,
        )
    axes = _check_options(options, n)
    content = _Content.build(problem, law, result, options, axes)

    import rerun as rr
    from rerun.error_utils import catch_and_log_exceptions

    with atomic_path(path) as tmp:  # temp file + fsync + rename, removed on failure
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4().hex)
        if not rec.is_enabled():
            raise CodevError(
                "rerun logging is disabled in this environment (RERUN=off); unset RERUN to "
                "write recordings"
            )
        try:
            rec.save(tmp)
            rec.send_recording_name(problem.name)
            # strict (raise, do not warn and drop) for this thread while logging; restored
            with catch_and_log_exceptions(context="codev recording", strict=True):
                writer = _Writer(rec)
                content.log(writer)
                _send_blueprint(writer, content)
            rec.flush()
        finally:
            rec.disconnect()
        if not _has_footer(tmp):
            raise CodevError(f"rerun wrote an incomplete recording for {path}")
    return RecordingSummary(
        path=path,
        entities=dict(writer.entities),
        boxes=content.tube_boxes,
        traces=content.num_traces,
        seconds=time.perf_counter() - t0,
    )


def check_recording(path: str | os.PathLike, *, deep: bool = True) -> None:
    """Check that ``path`` is a complete, readable Rerun recording.

    Parameters
    ----------
    path : str or PathLike
    deep : bool
        Also open it with Rerun's reader (about 0.4 s to import Rerun). Sessions pass False
        for a cached artifact whose bytes already match the SHA-256 recorded when it was
        written and checked: the header and footer checks then suffice.

    Raises
    ------
    SpecError
        (with ``file=str(path)``) the file is missing, not a regular file, not an ``.rrd``,
        truncated or incomplete (no footer, unreadable, or without a recording store).
    """
    file = str(path)
    p = Path(path)
    if not p.exists():
        raise SpecError("recording not found", file=file)
    if not p.is_file():
        raise SpecError("not a file", file=file)
    if p.suffix != ".rrd":
        raise SpecError(
            f"not a Rerun recording (expected a .rrd file, got {p.suffix!r})", file=file
        )
    try:
        with p.open("rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise SpecError(f"cannot read the file: {exc.strerror or exc}", file=file) from None
    if magic[:3] != b"RRF":
        raise SpecError("not a Rerun recording (no RRF header)", file=file)
    if not _has_footer(p):
        raise SpecError("incomplete recording (truncated: no RRD footer)", file=file)
    if not deep:
        return
    try:
        from rerun.chunk import RrdReader

        recordings = RrdReader(p).recordings()
    except Exception as exc:  # any reader failure means a bad file
        raise SpecError(f"unreadable recording ({type(exc).__name__}: {exc})", file=file) from None
    if not recordings:
        raise SpecError("the file holds no recording store", file=file)


# ---------------------------------------------------------------------------------------
# options, small helpers
# ---------------------------------------------------------------------------------------


def _check_options(options: RecordingOptions, n: int) -> tuple[int, int] | None:
    """Validate ``options`` for an n-state problem -> the plane axes (None when n == 1)."""
    traces = options.traces
    if isinstance(traces, bool) or not isinstance(traces, int | np.integer) or traces < 0:
        raise SpecError(f"must be an integer >= 0, got {traces!r}", field="traces")
    if n < 2:
        return None
    axes = tuple(options.axes)
    ok = len(axes) == 2 and all(
        isinstance(a, int | np.integer) and not isinstance(a, bool) for a in axes
    )
    if not ok:
        raise SpecError(f"expected two state indices, got {options.axes!r}", field="axes")
    i, j = int(axes[0]), int(axes[1])
    if i == j or not (0 <= i < n and 0 <= j < n):
        raise SpecError(
            f"expected two distinct state indices in 0..{n - 1}, got {options.axes!r}",
            field="axes",
        )
    return i, j


def _has_footer(path: Path) -> bool:
    from rerun_bindings import check_for_rrd_footer

    try:
        return bool(check_for_rrd_footer(str(path)))
    except Exception:  # unreadable is "no footer"
        return False


def _ns(t: np.ndarray) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]`` rounded to the nanosecond (rerun truncates floats)."""
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def _palette(k: int) -> np.ndarray:
    """``k`` well-separated colours (golden-ratio hues) -> (k, 3) uint8."""
    hues = (np.arange(k) * 0.618033988749895) % 1.0
    rgb = [colorsys.hsv_to_rgb(h, 0.55, 0.92) for h in hues]
    return (np.array(rgb, dtype=float).reshape(k, 3) * 255).round().astype(np.uint8)


# ---------------------------------------------------------------------------------------
# geometry: vertices, polygons, meshes
# ---------------------------------------------------------------------------------------


def enumerate_vertices(
    As: Sequence[np.ndarray], bs: Sequence[np.ndarray], tol: float = 1e-9
) -> list[np.ndarray | None]:
    """Vertices of many bounded polytopes ``{x : A_i x <= b_i}``, vectorised.

    Every d-subset of a polytope's rows is solved as a linear system (all polytopes with the
    same number of rows at once); the feasible solutions are the vertices.

    Parameters
    ----------
    As : sequence of (r_i, d) ndarray
        Rows, expected of unit norm (the feasibility tolerance is absolute in ``b``).
    bs : sequence of (r_i,) ndarray
    tol : float
        Feasibility tolerance, relative to ``1 + |b|``.

    Returns
    -------
    list of (v_i, d) ndarray or None
        The distinct vertices of each polytope (possibly none: empty or unbounded without
        vertices); None when the enumeration would exceed 50,000 row subsets.
    """
    out: list[np.ndarray | None] = [None] * len(As)
    if not As:
        return out
    d = As[0].shape[1]
    groups: dict[int, list[int]] = {}
    for i, A in enumerate(As):
        groups.setdefault(A.shape[0], []).append(i)
    for k, members in groups.items():
        if k < d:
            for i in members:
                out[i] = np.zeros((0, d))
            continue
        C = comb(k, d)
        if C > _MAX_COMBOS:
            continue
        idx = np.array(list(combinations(range(k), d)), dtype=np.intp).reshape(C, d)
        per = max(1, _BATCH // C)
        for s in range(0, len(members), per):
            sel = members[s : s + per]
            A = np.stack([np.asarray(As[i], dtype=float) for i in sel])  # (G, k, d)
            b = np.stack([np.asarray(bs[i], dtype=float) for i in sel])  # (G, k)
            M = A[:, idx]  # (G, C, d, d)
            rhs = b[:, idx]  # (G, C, d)
            with np.errstate(all="ignore"):
                det = np.linalg.det(M)
            g, c = np.nonzero(np.abs(det) > 1e-10)
            parts: list[np.ndarray] = [np.zeros((0, d))] * len(sel)
            if g.size:
                X = np.linalg.solve(M[g, c], rhs[g, c][..., None])[..., 0]  # (N, d)
                slack = np.einsum("nkd,nd->nk", A[g], X) - b[g]
                feas = np.all(slack <= tol * (1.0 + np.abs(b[g])), axis=1)
                g, X = g[feas], X[feas]
                if g.size:
                    key = np.column_stack([g, np.round(X / 1e-7)])
                    _, first = np.unique(key, axis=0, return_index=True)
                    first.sort()
                    g, X = g[first], X[first]
                    order = np.argsort(g, kind="stable")
                    counts = np.bincount(g, minlength=len(sel))
                    parts = np.split(X[order], np.cumsum(counts)[:-1])
            for j, i in enumerate(sel):
                out[i] = parts[j]
    return out


def _bounded_vertices(
    As: Sequence[np.ndarray],
    bs: Sequence[np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[list[np.ndarray | None], list[np.ndarray], list[np.ndarray]]:
    """Vertices of polytopes clipped to their boxes ``lo[i] <= x <= hi[i]`` (R, d).

    Fast path: the polytopes' own rows; a polytope whose vertices do not span its box
    (unbounded, or an unreliable box) is enumerated again with the box's rows added, which
    bounds it (and is redundant for a bounded polytope inside its box).

    Returns
    -------
    vertices : list of (v_i, d) ndarray or None
    A, b : list of ndarray
        The rows the vertices were enumerated from (the box rows appended where used).
    """
    V = enumerate_vertices(As, bs)
    As, bs = list(As), list(bs)
    d = lo.shape[1]
    eye = np.vstack([np.eye(d), -np.eye(d)])
    redo = []
    for i, v in enumerate(V):
        if v is None or v.shape[0] == 0:
            redo.append(i)
            continue
        tol = 1e-6 * (1.0 + max(np.abs(lo[i]).max(), np.abs(hi[i]).max()))
        if np.abs(v.min(axis=0) - lo[i]).max() > tol or np.abs(v.max(axis=0) - hi[i]).max() > tol:
            redo.append(i)
    if redo:
        for i in redo:
            As[i] = np.vstack([As[i], eye])
            bs[i] = np.concatenate([bs[i], hi[i], -lo[i]])
        for i, v in zip(
            redo, enumerate_vertices([As[i] for i in redo], [bs[i] for i in redo]), strict=True
        ):
            V[i] = v
    return V, As, bs


def _polygon(V: np.ndarray, axes: tuple[int, int]) -> np.ndarray | None:
    """Closed outline (p + 1, 2) of the projection of ``conv(V)`` on ``axes`` (None: flat)."""
    P = V[:, list(axes)]
    if P.shape[0] < 3:
        return None
    if V.shape[1] == 2:
        # every vertex of a convex polygon is on its boundary: sort by angle
        c = P.mean(axis=0)
        order = np.argsort(np.arctan2(P[:, 1] - c[1], P[:, 0] - c[0]))
        P = P[order]
    else:
        from scipy.spatial import ConvexHull, QhullError

        try:
            P = P[ConvexHull(P).vertices]
        except (QhullError, ValueError):
            return None
    span = np.ptp(P, axis=0)
    if np.min(span) <= 1e-12 * (1.0 + np.max(np.abs(P))):
        return None
    return np.vstack([P, P[:1]])


def _meshes(
    Vs: Sequence[np.ndarray | None],
    As: Sequence[np.ndarray],
    bs: Sequence[np.ndarray],
    tol: float = 1e-7,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """Triangle meshes of many 3-D polytopes from their vertices and rows, vectorised.

    Each row ``j`` of a polytope whose plane holds three or more of its vertices is a facet;
    the facet's vertices are sorted by angle around their centroid in the facet plane and
    fan-triangulated, counter-clockwise seen from outside (outward normals ``A_j``).

    Parameters
    ----------
    Vs : sequence of (v_i, 3) ndarray or None
        The vertices of each polytope (``enumerate_vertices``).
    As, bs : sequence of (r_i, 3) and (r_i,) ndarray
        The rows the vertices came from (unit norm).
    tol : float
        A vertex is on a row's plane within ``tol * (1 + |b_j|)``.

    Returns
    -------
    positions : (N, 3) ndarray
    triangles : (T, 3) uint32 ndarray
        Indices into ``positions``.
    owner : (N,) ndarray of int
        Polytope index of each position.
    meshed : list of int
        The polytopes that got at least one triangle.
    """
    idx = [i for i, v in enumerate(Vs) if v is not None and v.shape[0] >= 4]
    empty = (np.zeros((0, 3)), np.zeros((0, 3), dtype=np.uint32), np.zeros(0, dtype=int), [])
    if not idx:
        return empty
    counts = np.array([Vs[i].shape[0] for i in idx])
    V = np.vstack([Vs[i] for i in idx])
    g = np.repeat(np.arange(len(idx)), counts)
    rmax = max(As[i].shape[0] for i in idx)
    Ap = np.zeros((len(idx), rmax, 3))
    bp = np.full((len(idx), rmax), np.nan)
    for k, i in enumerate(idx):
        r = As[i].shape[0]
        Ap[k, :r] = As[i]
        bp[k, :r] = bs[i]
    with np.errstate(invalid="ignore"):
        slack = np.abs(np.einsum("nrd,nd->nr", Ap[g], V) - bp[g])
        active = slack <= tol * (1.0 + np.abs(bp[g]))
    vi, j = np.nonzero(active)
    f = g[vi] * rmax + j  # facet id
    nf = len(idx) * rmax
    cnt = np.bincount(f, minlength=nf)
    keep = cnt[f] >= 3
    vi, f = vi[keep], f[keep]
    if vi.size == 0:
        return empty
    normal = Ap.reshape(-1, 3)[f]
    centre = np.stack([np.bincount(f, V[vi, c], minlength=nf) for c in range(3)], axis=1)
    centre = centre / np.maximum(cnt, 1)[:, None]
    # an in-plane basis (e1, e2) with e1 x e2 = normal
    axis = np.eye(3)[np.argmin(np.abs(normal), axis=1)]
    e1 = _cross(normal, axis)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = _cross(normal, e1)
    rel = V[vi] - centre[f]
    angle = np.arctan2(np.einsum("md,md->m", rel, e2), np.einsum("md,md->m", rel, e1))
    order = np.lexsort((angle, f))
    vi, f = vi[order], f[order]
    run_start = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
    first = np.repeat(run_start, np.diff(np.r_[run_start, f.size]))
    pos = np.arange(f.size) - first
    sel = np.flatnonzero(pos >= 2)
    tri = np.column_stack([vi[first[sel]], vi[sel - 1], vi[sel]]).astype(np.uint32)
    meshed = sorted({idx[k] for k in np.unique(g[tri[:, 0]])})
    owner = np.array(idx)[g]
    return V, tri, owner, meshed


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N, 3) arrays (``np.cross`` is slow on small batches)."""
    return np.column_stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ]
    )


def _set_rows(s: SetSpec) -> tuple[np.ndarray, np.ndarray]:
    """Unit-norm H-representation of a set (infinite box sides dropped)."""
    A, b = s.halfspaces()
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    if A.shape[0] == 0:
        return A, b
    A, b, feasible = normalize_rows(A, b)
    if not feasible:  # 0 <= b < 0: an empty set; an impossible row keeps it empty
        A = np.vstack([A, np.eye(A.shape[1])[:1], -np.eye(A.shape[1])[:1]])
        b = np.concatenate([b, [-1.0, -1.0]])
    return A, b


def unsafe_margin(sets: Sequence[SetSpec], X: np.ndarray) -> np.ndarray:
    """Signed margin of states to the nearest unsafe set.

    For a set ``{x : A x <= b}`` with unit rows the margin is ``max_i (A_i x - b_i)``:
    <= 0 inside (minus the depth), > 0 outside (a lower bound on the Euclidean distance,
    exact when the nearest point is inside a facet). The margin to several sets is the
    minimum.

    Parameters
    ----------
    sets : sequence of SetSpec
    X : (..., n) ndarray

    Returns
    -------
    (...) ndarray
        ``+inf`` without sets; ``-inf`` for a set without finite rows (the whole space).
    """
    X = np.asarray(X, dtype=float)
    out = np.full(X.shape[:-1], np.inf)
    for s in sets:
        A, b = _set_rows(s)
        if A.shape[0] == 0:
            out = np.full_like(out, -np.inf)
            continue
        m = np.max(X @ A.T - b, axis=-1)
        out = np.minimum(out, m)
    return out


# ---------------------------------------------------------------------------------------
# what goes into the file
# ---------------------------------------------------------------------------------------


class _Writer:
    """A recording stream plus the instance count of each entity logged."""

    def __init__(self, rec) -> None:
        self.rec = rec
        self.entities: dict[str, int] = {}

    def static(self, entity: str, archetype, count: int) -> None:
        self.rec.log(entity, archetype, static=True, strict=True)
        self.entities[entity] = self.entities.get(entity, 0) + int(count)

    def columns(self, entity: str, times: np.ndarray, columns: list, count: int) -> None:
        import rerun as rr

        self.rec.send_columns(
            entity,
            indexes=[rr.TimeColumn(TIMELINE, duration=_ns(times))],
            columns=columns,
            strict=True,
        )
        self.entities[entity] = self.entities.get(entity, 0) + int(count)


@dataclass
class _Traces:
    """Simulated traces: t (K,), X (P, K, n), U (P, K, m), alive (P, K)."""

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    alive: np.ndarray


@dataclass
class _Content:
    """Everything computed before the file is opened (numpy only, no rerun)."""

    problem: Problem
    law: ExplicitLaw
    result: VerificationResult | None
    axes: tuple[int, int] | None
    view_lo: np.ndarray
    view_hi: np.ndarray
    region_vertices: list[np.ndarray | None]
    region_rows: tuple[list[np.ndarray], list[np.ndarray]]
    colors: np.ndarray
    traces: _Traces | None
    notes: list[str]
    tube_boxes: int = 0

    @property
    def n(self) -> int:
        return self.problem.plant.n

    @property
    def num_traces(self) -> int:
        return 0 if self.traces is None else int(self.traces.X.shape[0])

    @property
    def states(self) -> tuple[str, ...]:
        return self.problem.plant.states

    @property
    def inputs(self) -> tuple[str, ...]:
        return self.problem.plant.inputs

    @property
    def tube(self) -> Tube | None:
        return None if self.result is None else self.result.tube

    @property
    def counterexample(self) -> Counterexample | None:
        return None if self.result is None else self.result.counterexample

    @property
    def horizon(self) -> float:
        vs = self.problem.verify
        if vs is not None:
            return float(vs.time_horizon)
        return 10.0 * float(self.problem.model.sample_time)

    @classmethod
    def build(
        cls,
        problem: Problem,
        law: ExplicitLaw,
        result: VerificationResult | None,
        options: RecordingOptions,
        axes: tuple[int, int] | None,
    ) -> _Content:
        notes: list[str] = []
        n = problem.plant.n
        vs = problem.verify
        # the traces first: their extent is part of the view box
        traces = None
        if vs is not None and options.traces > 0:
            hold = result.hold if result is not None else vs.hold
            traces = _simulate(problem, law, options, hold, notes)
        # the law's domain box, widened to what else is shown
        if law.num_regions:
            blo, bhi = law.boxes
            dlo, dhi = blo.min(axis=0), bhi.max(axis=0)
        else:
            mpc = problem.mpc
            x_op = np.asarray(problem.model.x_op, dtype=float)
            x_op = x_op if x_op.shape == (n,) else np.zeros(n)
            D = float(mpc.domain_bound)
            dlo = np.where(np.isfinite(mpc.x_min), mpc.x_min, x_op - D)
            dhi = np.where(np.isfinite(mpc.x_max), mpc.x_max, x_op + D)
        lo, hi = np.array(dlo, dtype=float), np.array(dhi, dtype=float)
        extra = []
        if vs is not None:
            extra += [vs.initial_lower, vs.initial_upper]
        if result is not None and result.tube.num_boxes:
            extra += [result.tube.lower.min(axis=0), result.tube.upper.max(axis=0)]
        if traces is not None:
            with np.errstate(all="ignore"):
                finite = np.where(np.isfinite(traces.X), traces.X, np.nan).reshape(-1, n)
            if np.any(np.isfinite(finite)):
                extra += [np.nanmin(finite, axis=0), np.nanmax(finite, axis=0)]
        for e in extra:
            e = np.asarray(e, dtype=float)
            ok = np.isfinite(e)
            lo[ok] = np.minimum(lo[ok], e[ok])
            hi[ok] = np.maximum(hi[ok], e[ok])
        pad = 0.05 * np.maximum(hi - lo, 1e-9) + 1e-9
        view_lo, view_hi = lo - pad, hi + pad

        regions: list[np.ndarray | None] = []
        rows: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
        if law.num_regions:
            blo, bhi = law.boxes
            regions, rA, rb = _bounded_vertices(law.A, law.b, blo, bhi)
            rows = (rA, rb)
        content = cls(
            problem=problem,
            law=law,
            result=result,
            axes=axes,
            view_lo=view_lo,
            view_hi=view_hi,
            region_vertices=regions,
            region_rows=rows,
            colors=_palette(law.num_regions),
            traces=traces,
            notes=notes,
        )
        content.tube_boxes = 0 if result is None else int(result.tube.num_boxes)
        return content

    # ---- logging ---------------------------------------------------------------------

    def log(self, w: _Writer) -> None:
        self._log_partition(w)
        self._log_sets(w)
        self._log_tube(w)
        self._log_traces(w)
        self._log_counterexample(w)
        self._log_verdict(w)

    def _log_partition(self, w: _Writer) -> None:
        import rerun as rr

        n = self.n
        ok = [i for i, v in enumerate(self.region_vertices) if v is not None and v.shape[0]]
        if not ok:
            return
        labels = [f"R{i}" for i in range(self.law.num_regions)]
        if n == 1:
            # intervals: bands over the time horizon in the one state-vs-time view
            iv = np.array([[v.min(), v.max()] for v in (self.region_vertices[i] for i in ok)])
            iv = iv.reshape(-1, 2)
            T = self.horizon
            w.static(
                f"/time/{self.states[0]}/regions",
                rr.Boxes2D(
                    mins=np.column_stack([np.zeros(len(ok)), iv[:, 0]]),
                    sizes=np.column_stack([np.full(len(ok), T), iv[:, 1] - iv[:, 0]]),
                    colors=self.colors[ok],
                    labels=[labels[i] for i in ok],
                    draw_order=-10.0,
                ),
                len(ok),
            )
            return
        assert self.axes is not None
        strips, keep = [], []
        for i in ok:
            poly = _polygon(self.region_vertices[i], self.axes)
            if poly is not None:
                strips.append(poly)
                keep.append(i)
        if len(keep) < self.law.num_regions:
            self.notes.append(
                f"{self.law.num_regions - len(keep)} degenerate or too complex region(s) not "
                "drawn in the plane"
            )
        if strips:
            w.static(
                "/plane/regions",
                rr.LineStrips2D(
                    strips,
                    colors=self.colors[keep],
                    labels=[labels[i] for i in keep],
                    radii=rr.components.Radius.ui_points(0.75),
                    draw_order=-10.0,
                ),
                len(strips),
            )
        if n == 3:
            V, tri, owner, meshed = _meshes(self.region_vertices, *self.region_rows)
            if meshed:
                w.static(
                    "/space/regions",
                    rr.Mesh3D(
                        vertex_positions=V, triangle_indices=tri, vertex_colors=self.colors[owner]
                    ),
                    len(meshed),
                )

    def _sets(self) -> list[tuple[str, SetSpec, tuple[int, ...]]]:
        vs = self.problem.verify
        if vs is None:
            return []
        out = [("initial", SetSpec("box", lower=vs.initial_lower, upper=vs.initial_upper), _BLUE)]
        out += [(f"unsafe/{k}", s, _RED) for k, s in enumerate(vs.unsafe)]
        out += [(f"safe/{k}", s, _GREEN) for k, s in enumerate(vs.safe)]
        return out

    def _log_sets(self, w: _Writer) -> None:
        import rerun as rr

        sets = self._sets()
        if not sets:
            return
        n = self.n
        lo, hi = self.view_lo, self.view_hi
        rows = [_set_rows(s) for _, s, _ in sets]
        eye = np.vstack([np.eye(n), -np.eye(n)])
        As = [np.vstack([A, eye]) for A, _ in rows]
        bs = [np.concatenate([b, hi, -lo]) for _, b in rows]
        V = enumerate_vertices(As, bs)
        for k, ((name, s, color), v) in enumerate(zip(sets, V, strict=True)):
            if v is None or v.shape[0] == 0:
                self.notes.append(f"set {name} is empty inside the view box: not drawn")
                continue
            width = 2.5 if name.startswith("unsafe") else 1.5
            radius = rr.components.Radius.ui_points(width)
            if n == 1:
                T = self.horizon
                a, b = float(v.min()), float(v.max())
                w.static(
                    f"/time/{self.states[0]}/{name}",
                    rr.Boxes2D(
                        mins=[[0.0, a]],
                        sizes=[[T, b - a]],
                        colors=[color],
                        radii=radius,
                        labels=[name],
                        draw_order=-5.0,
                    ),
                    1,
                )
                continue
            assert self.axes is not None
            poly = _polygon(v, self.axes)
            if poly is not None:
                w.static(
                    f"/plane/{name}",
                    rr.LineStrips2D(
                        [poly], colors=[color], radii=radius, labels=[name], draw_order=-5.0
                    ),
                    1,
                )
            if n == 3:
                if s.kind == "box":
                    bl, bh = v.min(axis=0), v.max(axis=0)
                    w.static(
                        f"/space/{name}",
                        rr.Boxes3D(
                            mins=[bl],
                            sizes=[bh - bl],
                            colors=[color],
                            labels=[name],
                            fill_mode=rr.components.FillMode.TransparentFillMajorWireframe,
                        ),
                        1,
                    )
                else:
                    P3, tri, _, meshed = _meshes([v], [As[k]], [bs[k]])
                    if meshed:
                        w.static(
                            f"/space/{name}",
                            rr.Mesh3D(
                                vertex_positions=P3,
                                triangle_indices=tri,
                                vertex_colors=np.tile(np.array(color, np.uint8), (len(P3), 1)),
                            ),
                            1,
                        )

    def _log_tube(self, w: _Writer) -> None:
        import rerun as rr

        tube = self.tube
        if tube is None or tube.num_boxes == 0:
            return
        ts = np.asarray(tube.t_start, dtype=float)
        te = np.asarray(tube.t_end, dtype=float)
        lo = np.asarray(tube.lower, dtype=float)
        hi = np.asarray(tube.upper, dtype=float)
        K = ts.shape[0]
        order = np.argsort(ts, kind="stable")
        times, counts = np.unique(ts[order], return_counts=True)
        rows = times.shape[0]
        color = np.tile(np.array(_TUBE, dtype=np.uint8), (rows, 1))
        if self.axes is not None:
            ax = list(self.axes)
            c = 0.5 * (lo[order][:, ax] + hi[order][:, ax])
            h = 0.5 * (hi[order][:, ax] - lo[order][:, ax])
            cols = [
                *rr.Boxes2D.columns(centers=c, half_sizes=h).partition(counts),
                *rr.Boxes2D.columns(colors=color),
            ]
            w.columns("/plane/tube", times, cols, K)
        if self.n == 3:
            c = 0.5 * (lo[order] + hi[order])
            h = 0.5 * (hi[order] - lo[order])
            cols = [
                *rr.Boxes3D.columns(centers=c, half_sizes=h).partition(counts),
                *rr.Boxes3D.columns(colors=color),
            ]
            w.columns("/space/tube", times, cols, K)
        for i, s in enumerate(self.states):
            w.static(
                f"/time/{s}/tube",
                rr.Boxes2D(
                    mins=np.column_stack([ts, lo[:, i]]),
                    sizes=np.column_stack([te - ts, hi[:, i] - lo[:, i]]),
                    colors=[_TUBE],
                    radii=rr.components.Radius.ui_points(0.5),
                ),
                K,
            )

    def _log_traces(self, w: _Writer) -> None:
        import rerun as rr

        tr = self.traces
        if tr is None:
            return
        P = tr.X.shape[0]
        ok = np.all(np.isfinite(tr.X), axis=2)  # (P, K) state meaningful
        names = [f"trace_{p}" for p in range(P)]
        radius = rr.components.Radius.ui_points(1.0)
        if self.axes is not None:
            ax = list(self.axes)
            strips = [tr.X[p][ok[p]][:, ax] for p in range(P)]
            w.static(
                "/plane/traces",
                rr.LineStrips2D(strips, colors=[_TRACE], radii=radius, labels=names),
                P,
            )
        if self.n == 3:
            strips3 = [tr.X[p][ok[p]] for p in range(P)]
            w.static(
                "/space/traces",
                rr.LineStrips3D(strips3, colors=[_TRACE], radii=radius, labels=names),
                P,
            )
        for i, s in enumerate(self.states):
            strips = [np.column_stack([tr.t[ok[p]], tr.X[p, ok[p], i]]) for p in range(P)]
            w.static(
                f"/time/{s}/traces",
                rr.LineStrips2D(strips, colors=[_TRACE], radii=radius, labels=names),
                P,
            )
        colors = _palette(P)
        for p in range(P):
            color = tuple(int(c) for c in colors[p])
            self._log_scalars(w, tr.t, tr.U[p], tr.X[p], tr.alive[p], names[p], color, 1.0)

    def _log_scalars(
        self,
        w: _Writer,
        t: np.ndarray,
        U: np.ndarray,
        X: np.ndarray,
        alive: np.ndarray,
        name: str,
        color: tuple[int, ...],
        width: float,
    ) -> None:
        """Log ``u(t)`` per input and the unsafe margin of one trajectory.

        ``t`` (K,), ``U`` (K, m), ``X`` (K, n), ``alive`` (K,) bool.
        """
        import rerun as rr

        for j, u_name in enumerate(self.inputs):
            keep = alive & np.isfinite(U[:, j])
            if not np.any(keep):
                continue
            entity = f"/scalars/u/{u_name}/{name}"
            w.static(entity, rr.SeriesLines(colors=[color], widths=[width], names=[name]), 0)
            w.columns(entity, t[keep], [*rr.Scalars.columns(scalars=U[keep, j])], int(keep.sum()))
        vs = self.problem.verify
        if vs is None or not vs.unsafe:
            return
        margin = unsafe_margin(vs.unsafe, X)
        keep = np.isfinite(margin)
        if not np.any(keep):
            return
        entity = f"/scalars/unsafe_distance/{name}"
        w.static(entity, rr.SeriesLines(colors=[color], widths=[width], names=[name]), 0)
        w.columns(entity, t[keep], [*rr.Scalars.columns(scalars=margin[keep])], int(keep.sum()))

    def _log_counterexample(self, w: _Writer) -> None:
        import rerun as rr

        cex = self.counterexample
        if cex is None:
            return
        trace = cex.trace
        t = np.asarray(trace.t, dtype=float)
        X = np.asarray(trace.x, dtype=float)
        U = np.asarray(trace.u, dtype=float)
        ok = np.all(np.isfinite(X), axis=1)
        label = f"counterexample ({cex.kind} at t = {cex.t:.4g} s)"
        radius = rr.components.Radius.ui_points(3.0)
        if self.axes is not None:
            w.static(
                "/plane/counterexample",
                rr.LineStrips2D(
                    [X[ok][:, list(self.axes)]],
                    colors=[_RED],
                    radii=radius,
                    labels=[label],
                    draw_order=10.0,
                ),
                1,
            )
        if self.n == 3:
            w.static(
                "/space/counterexample",
                rr.LineStrips3D([X[ok]], colors=[_RED], radii=radius, labels=[label]),
                1,
            )
        for i, s in enumerate(self.states):
            w.static(
                f"/time/{s}/counterexample",
                rr.LineStrips2D(
                    [np.column_stack([t[ok], X[ok, i]])],
                    colors=[_RED],
                    radii=radius,
                    labels=[label],
                    draw_order=10.0,
                ),
                1,
            )
        alive = np.asarray(trace.region) >= 0
        self._log_scalars(w, t, U, X, alive, "counterexample", _RED, 3.0)

    def verdict_text(self) -> str:
        """The verdict as markdown."""
        p, law, r = self.problem, self.law, self.result
        lines = [f"# {p.name}", ""]
        if r is None:
            lines += ["**verdict:** not verified (partition and sets only)", ""]
        else:
            lines += [f"**verdict:** `{r.verdict}`" + (f" ({r.reason})" if r.reason else ""), ""]
        lines += [
            "| | |",
            "|---|---|",
            f"| states | {', '.join(p.plant.states)} |",
            f"| inputs | {', '.join(p.plant.inputs)} |",
            f"| regions | {law.num_regions} |",
        ]
        if r is not None:
            lines += [
                f"| hold | {r.hold} |",
                f"| reason | {r.reason or '-'} |",
                f"| tube boxes | {r.tube.num_boxes} |",
                f"| verification time | {r.seconds:.3f} s |",
            ]
        if self.axes is not None:
            a, b = self.axes
            lines.append(f"| plane axes | {p.plant.states[a]} (x), {p.plant.states[b]} (y) |")
        lines.append(f"| simulated traces | {self.num_traces} |")
        cex = self.counterexample
        if cex is not None:
            x0 = np.array2string(np.asarray(cex.x0), precision=6, separator=", ")
            lines += [
                "",
                "## counterexample",
                "",
                f"- kind: `{cex.kind}` (index {cex.index})",
                f"- time: {cex.t:.6g} s",
                f"- x0: `{x0}`",
            ]
        if self.notes:
            lines += ["", "## notes", ""] + [f"- {s}" for s in self.notes]
        return "\n".join(lines) + "\n"

    def _log_verdict(self, w: _Writer) -> None:
        import rerun as rr

        w.static("/verdict", rr.TextDocument(self.verdict_text(), media_type="text/markdown"), 1)


def _simulate(
    problem: Problem, law: ExplicitLaw, options: RecordingOptions, hold: str, notes: list[str]
) -> _Traces | None:
    """Closed-loop traces from the centre, corners and seeded random points of the initial box."""
    from codev_engine.reach.simulate import simulate_many

    vs = problem.verify
    assert vs is not None
    lo = np.asarray(vs.initial_lower, dtype=float)
    hi = np.asarray(vs.initial_upper, dtype=float)
    n = lo.shape[0]
    P = int(options.traces)
    k = min(P - 1, 2**n if n < 30 else P)
    bits = (np.arange(k)[:, None] >> np.arange(n)[None, :]) & 1
    corners = np.where(bits == 1, hi, lo)
    rng = np.random.default_rng(options.seed)
    X0 = np.vstack([0.5 * (lo + hi), corners, rng.uniform(lo, hi, (max(0, P - 1 - k), n))])[:P]
    try:
        # for display: RK4 steps of step/2, not the default step/10 (5x faster; measured
        # difference <= 6e-10 of the states' scale on the examples); output every step
        t, X, U, alive = simulate_many(problem, law, X0, hold=hold, dt=vs.step / 2, dt_out=vs.step)
    except SolverError as exc:
        notes.append(f"traces not simulated: {exc}")
        return None
    return _Traces(np.asarray(t), np.asarray(X), np.asarray(U), np.asarray(alive, dtype=bool))


def _send_blueprint(w: _Writer, content: _Content) -> None:
    """The viewer layout: plane (+ 3-D) views, state-vs-time views, series, verdict."""
    import rerun as rr
    import rerun.blueprint as rrb

    e = w.entities
    states = content.states
    up_to_cursor = rr.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0),
    )
    left: list = []
    if any(k.startswith("/plane/") for k in e):
        a, b = content.axes or (0, 1)
        left.append(
            rrb.Spatial2DView(
                origin="/plane",
                name=f"plane: {states[a]} → right, {states[b]} ↓ down",
                time_ranges=up_to_cursor,
            )
        )
    if any(k.startswith("/space/") for k in e):
        left.append(
            rrb.Spatial3DView(origin="/space", name="state space", time_ranges=up_to_cursor)
        )
    left.append(rrb.TextDocumentView(origin="/verdict", name="verdict"))
    time_views = [
        rrb.Spatial2DView(origin=f"/time/{s}", name=f"{s}(t) (↓ increasing)")
        for s in states
        if any(k.startswith(f"/time/{s}/") for k in e)
    ]
    series = []
    if len(content.inputs) == 1:
        if any(k.startswith("/scalars/u/") for k in e):
            series.append(rrb.TimeSeriesView(origin="/scalars/u", name="u(t)"))
    else:  # one plot per input: their scales may differ
        series += [
            rrb.TimeSeriesView(origin=f"/scalars/u/{u}", name=f"{u}(t)")
            for u in content.inputs
            if any(k.startswith(f"/scalars/u/{u}/") for k in e)
        ]
    if any(k.startswith("/scalars/unsafe_distance/") for k in e):
        series.append(
            rrb.TimeSeriesView(origin="/scalars/unsafe_distance", name="margin to unsafe sets")
        )
    right: list = []
    if time_views:
        right.append(rrb.Grid(*time_views) if len(time_views) > 1 else time_views[0])
    if series:
        right.append(rrb.Horizontal(*series))
    shares = [3, 3, 1] if len(left) == 3 else [4, 1]
    layout_left = rrb.Vertical(*left, row_shares=shares)
    layout = rrb.Horizontal(layout_left, rrb.Vertical(*right)) if right else layout_left
    parts: list = [layout]
    if (
        any(k in e for k in ("/plane/tube", "/space/tube"))
        or content.num_traces
        or (content.counterexample is not None)
    ):
        parts.append(rrb.TimePanel(timeline=TIMELINE, state="expanded"))
    w.rec.send_blueprint(rrb.Blueprint(*parts, auto_views=False, auto_layout=False))
