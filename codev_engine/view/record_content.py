"""What a recording holds: the partition, the sets, the tube, the traces, the verdict.

:class:`RecordingContent` computes everything first, with numpy only: the traces
(:func:`simulate_traces`, on ``codev_engine.reach.simulate``), the view box, the regions'
vertices (:mod:`codev_engine.geometry.vertices`, clipped to their bounding boxes); then
:meth:`RecordingContent.log` logs it to a stream through an :class:`EntityWriter`, which
counts the instances of each entity. The entity layout is documented in
``docs/recordings.md``; the file itself (atomic write, checks) is ``records``', the viewer
layout ``blueprint``'s.
"""

from __future__ import annotations

import colorsys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.geometry.polytope import normalize_rows
from codev_engine.geometry.vertices import vertices_in_boxes, vertices_many
from codev_engine.law import ExplicitLaw
from codev_engine.reach.simulate import simulate_many
from codev_engine.spec.problem import Problem, SetSpec
from codev_engine.view.shapes import meshes, outline

if TYPE_CHECKING:
    from codev_engine.reach.tube import Tube
    from codev_engine.reach.verification import Counterexample, VerificationResult

__all__ = [
    "TIMELINE",
    "EntityWriter",
    "RecordingContent",
    "RecordingOptions",
    "Traces",
    "simulate_traces",
    "unsafe_margin",
]

#: the timeline of everything temporal (a duration, in seconds)
TIMELINE = "time"

# colours (RGB / RGBA, 0-255)
_RED = (220, 40, 40)
_GREEN = (40, 170, 60)
_BLUE = (40, 110, 230)
_TUBE = (255, 150, 0, 200)
_TRACE = (90, 90, 90)

#: feasibility tolerance of the drawn polytopes' vertices, ``_TOL * (1 + |b|)`` (the
#: drawings' choice in ``geometry.vertices``)
_TOL = 1e-9
#: a polytope with more d-subsets of rows than this is not drawn (no LP fallback here)
_MAX_COMBOS = 50_000


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


class EntityWriter:
    """A recording stream plus the instance count of each entity logged.

    Parameters
    ----------
    rec : rerun.RecordingStream
        The stream, already saving to its file.

    Attributes
    ----------
    rec : rerun.RecordingStream
    entities : dict of str to int
        Entity path -> instances logged (``RecordingSummary.entities``).
    """

    def __init__(self, rec) -> None:
        self.rec = rec
        self.entities: dict[str, int] = {}

    def static(self, entity: str, archetype, count: int) -> None:
        """Log a static ``archetype`` (strict: bad data raises) of ``count`` instances.

        Parameters
        ----------
        entity : str
            The entity path.
        archetype : rerun archetype
        count : int
            Instances it holds (added to ``entities[entity]``).
        """
        self.rec.log(entity, archetype, static=True, strict=True)
        self.entities[entity] = self.entities.get(entity, 0) + int(count)

    def columns(self, entity: str, times: np.ndarray, columns: list, count: int) -> None:
        """Send ``columns`` on the ``time`` timeline, one row per time (strict).

        Parameters
        ----------
        entity : str
            The entity path.
        times : (T,) ndarray
            The rows' times in seconds.
        columns : list
            Rerun component columns with T rows.
        count : int
            Instances they hold (added to ``entities[entity]``).
        """
        import rerun as rr

        self.rec.send_columns(
            entity,
            indexes=[rr.TimeColumn(TIMELINE, duration=_ns(times))],
            columns=columns,
            strict=True,
        )
        self.entities[entity] = self.entities.get(entity, 0) + int(count)


@dataclass
class Traces:
    """Simulated closed-loop traces (``simulate_many`` output).

    Attributes
    ----------
    t : (K,) ndarray
    X : (P, K, n) ndarray
    U : (P, K, m) ndarray
    alive : (P, K) bool ndarray
    """

    t: np.ndarray
    X: np.ndarray
    U: np.ndarray
    alive: np.ndarray


def simulate_traces(
    problem: Problem, law: ExplicitLaw, options: RecordingOptions, hold: str, notes: list[str]
) -> Traces | None:
    """Closed-loop traces (``reach.simulate.simulate_many``) from the centre, the corners
    and seeded random points of the initial box.

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
    options : RecordingOptions
        ``traces`` of them, the random points from ``seed``.
    hold : str
        The hold of the simulation.
    notes : list of str
        Gets a note when the simulation breaks down (``SolverError``).

    Returns
    -------
    Traces or None
        None when the simulation broke down.
    """
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
    return Traces(np.asarray(t), np.asarray(X), np.asarray(U), np.asarray(alive, dtype=bool))


@dataclass
class RecordingContent:
    """Everything a recording shows, computed before the file is opened (numpy, no rerun),
    and how it is logged (:meth:`log`; the entity layout of ``docs/recordings.md``).

    Attributes
    ----------
    problem : Problem
    law : ExplicitLaw
    result : VerificationResult or None
    axes : (int, int) or None
        The plane view's state indices (None when n == 1).
    view_lo, view_hi : (n,) ndarray
        The view box (infinite sets are clipped to it).
    region_vertices : list of (v_i, n) ndarray or None
        The vertices of each region clipped to its bounding box (None: too many rows).
    region_rows : (list of ndarray, list of ndarray)
        The rows those vertices were enumerated from.
    colors : (k, 3) uint8 ndarray
        One colour per region.
    traces : Traces or None
    notes : list of str
        What could not be drawn (shown in the verdict document).
    tube_boxes : int
        Tube boxes logged.
    """

    problem: Problem
    law: ExplicitLaw
    result: VerificationResult | None
    axes: tuple[int, int] | None
    view_lo: np.ndarray
    view_hi: np.ndarray
    region_vertices: list[np.ndarray | None]
    region_rows: tuple[list[np.ndarray], list[np.ndarray]]
    colors: np.ndarray
    traces: Traces | None
    notes: list[str]
    tube_boxes: int = 0

    @property
    def n(self) -> int:
        """The number of states."""
        return self.problem.plant.n

    @property
    def num_traces(self) -> int:
        """Simulated traces (the counterexample not included)."""
        return 0 if self.traces is None else int(self.traces.X.shape[0])

    @property
    def states(self) -> tuple[str, ...]:
        """The state names."""
        return self.problem.plant.states

    @property
    def inputs(self) -> tuple[str, ...]:
        """The input names."""
        return self.problem.plant.inputs

    @property
    def tube(self) -> Tube | None:
        """The result's reachtube (None without a result)."""
        return None if self.result is None else self.result.tube

    @property
    def counterexample(self) -> Counterexample | None:
        """The result's counterexample, if any."""
        return None if self.result is None else self.result.counterexample

    @property
    def horizon(self) -> float:
        """The time axis' extent: ``verify.time_horizon``, else ten sample times."""
        vs = self.problem.verify
        if vs is not None:
            from codev_engine.reach.simulate import shown_horizon

            return shown_horizon(self.problem)  # finite, also for time_horizon = "inf"
        return 10.0 * float(self.problem.model.sample_time)

    @classmethod
    def build(
        cls,
        problem: Problem,
        law: ExplicitLaw,
        result: VerificationResult | None,
        options: RecordingOptions,
        axes: tuple[int, int] | None,
    ) -> RecordingContent:
        """Simulate the traces, choose the view box, enumerate the regions' vertices.

        Parameters
        ----------
        problem : Problem
        law : ExplicitLaw
        result : VerificationResult or None
        options : RecordingOptions
        axes : (int, int) or None
            The checked plane axes (None when n == 1).

        Returns
        -------
        RecordingContent
        """
        notes: list[str] = []
        n = problem.plant.n
        vs = problem.verify
        # the traces first: their extent is part of the view box
        traces = None
        if vs is not None and options.traces > 0:
            hold = result.hold if result is not None else vs.hold
            traces = simulate_traces(problem, law, options, hold, notes)
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
            regions, rA, rb = vertices_in_boxes(
                law.A, law.b, blo, bhi, _TOL, rtol=_TOL, max_combos=_MAX_COMBOS
            )
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

    def log(self, w: EntityWriter) -> None:
        """Log everything but the blueprint.

        Parameters
        ----------
        w : EntityWriter
        """
        self._log_partition(w)
        self._log_sets(w)
        self._log_tube(w)
        self._log_traces(w)
        self._log_counterexample(w)
        self._log_verdict(w)

    def _log_partition(self, w: EntityWriter) -> None:
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
            poly = outline(self.region_vertices[i], self.axes)
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
            V, tri, owner, meshed = meshes(self.region_vertices, *self.region_rows)
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

    def _log_sets(self, w: EntityWriter) -> None:
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
        V = vertices_many(As, bs, _TOL, rtol=_TOL, max_combos=_MAX_COMBOS)
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
            poly = outline(v, self.axes)
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
                    P3, tri, _, meshed = meshes([v], [As[k]], [bs[k]])
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

    def _log_tube(self, w: EntityWriter) -> None:
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

    def _log_traces(self, w: EntityWriter) -> None:
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
        w: EntityWriter,
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

    def _log_counterexample(self, w: EntityWriter) -> None:
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
        """The verdict document.

        Returns
        -------
        str
            Markdown: problem, verdict, sizes, the counterexample and the notes.
        """
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

    def _log_verdict(self, w: EntityWriter) -> None:
        import rerun as rr

        w.static("/verdict", rr.TextDocument(self.verdict_text(), media_type="text/markdown"), 1)


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


def _ns(t: np.ndarray) -> np.ndarray:
    """Seconds -> ``timedelta64[ns]`` rounded to the nanosecond (rerun truncates floats)."""
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def _palette(k: int) -> np.ndarray:
    """``k`` well-separated colours (golden-ratio hues) -> (k, 3) uint8."""
    hues = (np.arange(k) * 0.618033988749895) % 1.0
    rgb = [colorsys.hsv_to_rgb(h, 0.55, 0.92) for h in hues]
    return (np.array(rgb, dtype=float).reshape(k, 3) * 255).round().astype(np.uint8)
