"""Matplotlib pictures of explicit laws and verification results (notebooks, reports).

Pure functions on the engine's objects. matplotlib is imported inside the functions that
draw, so ``import codev_engine`` never loads it. Everything uses the object-oriented API --
a ``matplotlib.figure.Figure`` rendered by the Agg canvas -- never ``pyplot``: no GUI
backend, no global figure registry, nothing left behind between calls.

The notebook display of :class:`~codev_engine.law.ExplicitLaw` and
:class:`~codev_engine.reach.verification.VerificationResult` (their ``_repr_png_``,
``_repr_html_`` and ``_repr_mimebundle_``, from :class:`codev_engine.display.Displayable`)
is drawn by :mod:`codev_engine.view.notebook` with :func:`figure_law`, :func:`figure_result`,
:func:`law_html`, :func:`result_html` and :func:`png_bytes` here.

Drawing is vectorised: a partition's polygons come from one batched vertex enumeration
(:func:`section_polygons`, on :mod:`codev_engine.geometry.vertices`; ~1000 regions in tens
of milliseconds) and a tube's boxes go into one ``PolyCollection`` per axes, not one patch
per box.
"""

from __future__ import annotations

import base64
import html
import io
from typing import TYPE_CHECKING, Any

import numpy as np

from codev_engine.view.scene import (
    Scene,
    StatePlot,
    build_scene,
    default_slice_point,
    law_section,
    padded,
    regions_words,
    verified_parameters,
)
from codev_engine.view.shapes import check_axes as _check_axes
from codev_engine.view.shapes import section_polygons

if TYPE_CHECKING:  # pragma: no cover - typing only
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from codev_engine.law import ExplicitLaw
    from codev_engine.reach.verification import Counterexample, VerificationResult
    from codev_engine.spec.problem import Problem

__all__ = [
    "VERDICT_COLOURS",
    "default_slice_point",
    "figure_law",
    "figure_result",
    "law_html",
    "law_section",
    "merge_bands",
    "plot_partition",
    "plot_output",
    "plot_plane",
    "plot_sweep",
    "plot_tube",
    "png_bytes",
    "result_html",
    "section_polygons",
    "verified_parameters",
]

#: banner / title colour of each verdict (green, red, amber)
VERDICT_COLOURS: dict[str, str] = {
    "robustly_safe": "#2e7d32",
    "unsafe": "#c62828",
    "unknown": "#e69500",
}
#: the tube: orange, as in the recordings (blue is the initial set)
_TUBE_FACE = "#f5a028"
#: the counterexample: a colour of its own (the unsafe sets are red), drawn on top
_TRACE = "#dc00aa"  # magenta, as in the recordings
CEX_COLOUR = _TRACE
_UNSAFE = "#e53935"
_SAFE = "#2e7d32"
_INITIAL = "#1e63d6"  # blue, as in the recordings
_REFERENCE = "#8e24aa"
#: the certificate band after an all-time certificate closed (hatched: a bound, not a tube)
_CERTIFICATE = "#6a1b9a"
#: resolution of the notebook pictures (dots per inch)
_DPI = 80


# --------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Rectangles ``[lo, hi]`` (K, 2) as closed polygons (K, 4, 2)."""
    return np.stack(
        [
            np.stack([lo[:, 0], lo[:, 1]], axis=1),
            np.stack([hi[:, 0], lo[:, 1]], axis=1),
            np.stack([hi[:, 0], hi[:, 1]], axis=1),
            np.stack([lo[:, 0], hi[:, 1]], axis=1),
        ],
        axis=1,
    )


def merge_bands(
    t_start: np.ndarray, t_end: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """The union of a tube's bands on one state, as fewer bands.

    Bands with the same time interval whose value intervals overlap are merged into their
    union (exactly: the union of the drawn rectangles does not change). Tubes of many
    branches on a common time grid shrink by about the number of branches.

    Parameters
    ----------
    t_start, t_end, lower, upper : (K,) ndarray

    Returns
    -------
    (k, 4) ndarray
        Rows ``(t_start, t_end, lower, upper)``, ``k <= K``.
    """
    if t_start.shape[0] == 0:
        return np.zeros((0, 4))
    order = np.lexsort((lower, t_end, t_start))
    ts, te, lo, hi = t_start[order], t_end[order], lower[order], upper[order]
    new_time = np.ones(ts.shape[0], dtype=bool)
    new_time[1:] = (ts[1:] != ts[:-1]) | (te[1:] != te[:-1])
    group = np.cumsum(new_time) - 1
    # running max of ``upper`` inside each time group: lift group g by g * span, so one
    # cumulative maximum never carries a value across groups
    span = 2.0 * (float(hi.max() - lo.min()) + 1.0)
    reach = np.maximum.accumulate(hi - lo.min() + group * span) - group * span + lo.min()
    gap = np.ones(ts.shape[0], dtype=bool)
    gap[1:] = new_time[1:] | (lo[1:] > reach[:-1])
    first = np.flatnonzero(gap)
    return np.stack([ts[first], te[first], lo[first], np.maximum.reduceat(hi, first)], axis=1)


def _add_boxes(ax: Axes, lo: np.ndarray, hi: np.ndarray, **style: Any) -> None:
    """Rectangles ``[lo[k], hi[k]]`` (K, 2) as one compound path: one artist, one draw call
    (10^5 boxes in a fraction of a second). Axis limits are the caller's to set."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path

    K = lo.shape[0]
    verts = np.concatenate([_box_corners(lo, hi), lo[:, None, :]], axis=1).reshape(-1, 2)
    step = [Path.MOVETO, Path.LINETO, Path.LINETO, Path.LINETO, Path.CLOSEPOLY]
    codes = np.tile(np.array(step, dtype=Path.code_type), K)
    # add_artist, not add_patch: add_patch walks the path in Python to update data limits
    ax.add_artist(PathPatch(Path(verts, codes), **style))


def _min_size(lo: np.ndarray, hi: np.ndarray, least: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``[lo, hi]`` (K, 2) widened about their centres to at least ``least`` (2,)."""
    mid, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), 0.5 * np.asarray(least))
    return mid - half, mid + half


def _region_colours(index: np.ndarray) -> np.ndarray:
    """Distinct pastel colours (k, 3): hues spaced by the golden ratio, by region index."""
    from matplotlib.colors import hsv_to_rgb

    hue = (np.asarray(index, dtype=float) * 0.618033988749895) % 1.0
    hsv = np.stack([hue, np.full_like(hue, 0.45), np.full_like(hue, 0.95)], axis=1)
    return hsv_to_rgb(hsv)


def _state_names(n: int, names: tuple[str, ...] | None) -> tuple[str, ...]:
    if names and len(names) == n:
        return tuple(names)
    return tuple(f"x[{k}]" for k in range(n))


def _new_axes(ax: Axes | None, figsize: tuple[float, float] = (6.0, 4.5)) -> Axes:
    if ax is not None:
        return ax
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained").add_subplot()


# --------------------------------------------------------------------------------------------
# laws
# --------------------------------------------------------------------------------------------


def plot_partition(
    law: ExplicitLaw,
    ax: Axes | None = None,
    *,
    axes: tuple[int, int] = (0, 1),
    at: np.ndarray | None = None,
    linewidth: float = 0.4,
    scene: Scene | None = None,
) -> Axes:
    """Draw the law's critical regions, one colour each.

    Parameters
    ----------
    law : ExplicitLaw
    ax : matplotlib Axes, optional
        Where to draw; a new figure's axes by default.
    axes : (2,) tuple of int
        The states on the horizontal and vertical axes (``n >= 2``).
    at : (n,) array_like, optional
        For ``n > 2``: the values of the other states; the picture is the section of the
        partition through ``at`` (default :func:`default_slice_point`, the centre of the
        domain's bounding box). Ignored for ``n <= 2``.
    linewidth : float
        Width of the region edges.
    scene : Scene, optional
        The design's scene (:func:`~codev_engine.view.scene.build_scene`): its regions,
        window, section and title are drawn (``axes`` and ``at`` are then ignored);
        built from the law alone by default.

    Returns
    -------
    matplotlib Axes

    Notes
    -----
    With one state the regions are intervals: each is drawn as a band, with the first
    input ``u = F_i x + G_i`` over it as a line.
    """
    ax = _new_axes(ax)
    # the law's axes are theta's (the states, prev_<input>, ref_<...>), not the states alone
    names = _state_names(law.n, law.parameter_names)
    # free text of the law file's metadata: its '$' drawn as such, never as mathtext
    label = str(law.meta.get("problem", "explicit law")).replace("$", r"\$")
    if scene is None:
        if law.n == 1:
            return _plot_intervals(law, ax, names[0], label, linewidth)
        scene = build_scene(None, law, axes=_check_axes(axes, law.n), at=at)
    if scene.axes is None:
        return _plot_intervals(law, ax, names[0], label, linewidth)
    i, j = scene.axes
    polys, index = list(scene.region_polygons), scene.region_index
    _add_polygons(ax, polys, _region_colours(index), linewidth)
    ax.set_xlim(scene.plane_lo[0], scene.plane_hi[0])
    ax.set_ylim(scene.plane_lo[1], scene.plane_hi[1])
    ax.set_xlabel(names[i])
    ax.set_ylabel(names[j])
    # the scene's title: "section at ..." when it is one, "the regions reached" on demand
    title = f"{label}: {scene.partition_title}".replace(": section at", "\nsection at")
    ax.set_title(title, fontsize="medium")
    return ax


def _add_polygons(ax: Axes, polys: list[np.ndarray], colours: np.ndarray, lw: float) -> None:
    from matplotlib.collections import PolyCollection

    if not polys:
        ax.text(0.5, 0.5, "no region meets this section", ha="center", transform=ax.transAxes)
        return
    coll = PolyCollection(
        polys, facecolors=colours, edgecolors="#333333", linewidths=lw, closed=True
    )
    ax.add_collection(coll, autolim=True)
    ax.autoscale_view()


def _plot_intervals(law: ExplicitLaw, ax: Axes, name: str, label: str, lw: float) -> Axes:
    """One-state law: a band per region and the first input over it."""
    from matplotlib.collections import LineCollection, PolyCollection

    k = law.num_regions
    if k == 0:
        ax.set_title(f"{label}: {regions_words(law, None, 0)}", fontsize="medium")
        return ax
    rows = np.concatenate([a[:, 0] for a in law.A])
    rhs = np.concatenate(law.b)
    region = np.repeat(np.arange(k), [a.shape[0] for a in law.A])
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rhs / rows
    lo = np.full(k, -np.inf)
    hi = np.full(k, np.inf)
    np.maximum.at(lo, region[rows < 0], bound[rows < 0])
    np.minimum.at(hi, region[rows > 0], bound[rows > 0])
    ok = np.isfinite(lo) & np.isfinite(hi) & (lo < hi)
    lo, hi, idx = lo[ok], hi[ok], np.flatnonzero(ok)
    x = np.stack([lo, hi], axis=1)  # (k, 2)
    u = law.F[idx, 0, 0][:, None] * x + law.G[idx, 0][:, None]
    umin, umax = padded(float(np.min(u)), float(np.max(u)), 0.1) if u.size else (-1, 1)
    colours = _region_colours(idx)
    bands = _box_corners(
        np.stack([lo, np.full_like(lo, umin)], axis=1),
        np.stack([hi, np.full_like(hi, umax)], axis=1),
    )
    ax.add_collection(
        PolyCollection(bands, facecolors=colours, edgecolors="#333333", linewidths=lw)
    )
    ax.add_collection(LineCollection(np.stack([x, u], axis=2), colors="k", linewidths=1.5))
    ax.set_xlim(float(lo.min()) if lo.size else -1, float(hi.max()) if hi.size else 1)
    ax.set_ylim(umin, umax)
    ax.set_xlabel(name)
    ax.set_ylabel(law.inputs[0] if law.inputs else "u[0]")
    ax.set_title(f"{label}: {regions_words(law, None, k)}", fontsize="medium")
    return ax


def figure_law(
    law: ExplicitLaw,
    *,
    axes: tuple[int, int] = (0, 1),
    at: np.ndarray | None = None,
    scene: Scene | None = None,
) -> Figure:
    """A figure of the law's partition (see :func:`plot_partition`).

    Parameters
    ----------
    law : ExplicitLaw
        The law whose critical regions are drawn.
    axes : (2,) tuple of int
        State indices of the drawn plane.
    at : (n,) ndarray, optional
        For ``n > 2``: the point whose other coordinates fix the section (default
        :func:`default_slice_point`).
    scene : Scene, optional
        The design's scene (:func:`plot_partition`).

    Returns
    -------
    matplotlib Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.5), layout="constrained")
    plot_partition(law, fig.add_subplot(), axes=axes, at=at, scene=scene)
    return fig


# --------------------------------------------------------------------------------------------
# verification results
# --------------------------------------------------------------------------------------------


def plot_tube(
    result: VerificationResult,
    ax: Axes | None = None,
    *,
    state: int = 0,
    problem: Problem | None = None,
    scene: Scene | None = None,
) -> Axes:
    """Draw one state's reachtube against time.

    Each box ``k`` of the tube is the band ``[t_start[k], t_end[k]] x [lower[k, state],
    upper[k, state]]``; the bands are merged where they overlap (:func:`merge_bands`) and
    drawn as one compound path; after an all-time certificate closed, the certificate band
    (hatched) instead. The counterexample trace, if any, is drawn over them, solid up to
    its violation (marked) and faint after it.

    Parameters
    ----------
    result : VerificationResult
    ax : matplotlib Axes, optional
    state : int
        Index of the state.
    problem : Problem, optional
        Adds the states' names, the time horizon and the verify sets on that state: unsafe
        sets that constrain this state alone as red bands (a set that also constrains other
        states is not a band in this picture; see :func:`plot_plane`), the bounds that
        safe sets put on this state alone as green dashed lines, the initial interval at
        ``t = 0``; and, for a design that tracks the states (``[mpc.reference] signal =
        "x"``), the reference (purple: a line, or the box of an unknown constant reference).
    scene : Scene, optional
        The design's scene (default: built from ``result`` and ``problem``): the y range,
        the ticks, the limits and the time axis drawn.

    Returns
    -------
    matplotlib Axes
    """
    tube = result.tube
    n = tube.lower.shape[1]
    if not 0 <= state < n:
        raise ValueError(f"state must be in [0, {n}), got {state}")
    if scene is None:
        scene = build_scene(problem, None, result, axes=None)
    plot = scene.plots[state]
    return _plot_signal(result, ax, np.eye(n)[state], tube.lower[:, state],
                        tube.upper[:, state], plot.label, problem, scene, plot=plot)


def plot_output(
    result: VerificationResult,
    problem: Problem,
    ax: Axes | None = None,
    *,
    output: int = 0,
    scene: Scene | None = None,
) -> Axes:
    """Draw one output ``y = C x`` of the reachtube against time, with its MPC bounds.

    The tube's boxes are mapped through ``C`` interval-wise, rounded outward
    (:func:`codev_engine.view.signals.output_boxes`): every trajectory the tube contains
    has its output inside the bands drawn. ``y_min`` / ``y_max`` are black dashed lines
    (dotted when soft), the reference of a design tracking the outputs is purple, and the
    counterexample's output is drawn as in :func:`plot_tube`.

    Parameters
    ----------
    result : VerificationResult
    problem : Problem
        With ``mpc.C``.
    ax : matplotlib Axes, optional
    output : int
        Index of the output (row of ``C``).
    scene : Scene, optional
        The design's scene: its time axis.

    Returns
    -------
    matplotlib Axes
    """
    from codev_engine.view.signals import output_boxes, output_names

    C = problem.mpc.C
    if C is None:
        raise ValueError("the design has no outputs (mpc.C)")
    C = np.asarray(C, dtype=float)
    if not 0 <= output < C.shape[0]:
        raise ValueError(f"output must be in [0, {C.shape[0]}), got {output}")
    tube = result.tube
    ylo, yhi = output_boxes(C[output : output + 1], tube.lower, tube.upper)
    name = output_names(problem)[output]
    if scene is None:
        scene = build_scene(problem, None, result, axes=None)
    return _plot_signal(result, ax, C[output], ylo[:, 0], yhi[:, 0], f"{name} = C x",
                        problem, scene, output=output)


def _plot_signal(
    result: VerificationResult,
    ax: Axes | None,
    row: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    ylabel: str,
    problem: Problem | None,
    scene: Scene,
    *,
    plot: StatePlot | None = None,
    output: int | None = None,
) -> Axes:
    """One signal ``row @ x`` against time: the tube's bands (``lower``, ``upper``, (K,)),
    the certificate band, the counterexample, and a state's ``plot`` (its y range, ticks,
    limits and initial interval) or an output's bounds and reference."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from codev_engine.view.signals import output_bounds, reference_band

    ax = _new_axes(ax, (6.0, 3.0))
    tube = result.tube
    cert = scene.certificate
    t_start, t_end = np.asarray(tube.t_start, float), np.asarray(tube.t_end, float)
    drawn_boxes = scene.tube_shown
    bands = merge_bands(t_start[drawn_boxes], t_end[drawn_boxes], lower[drawn_boxes],
                        upper[drawn_boxes])
    handles: list[Any] = []
    ylo, yhi = np.inf, -np.inf
    if bands.shape[0]:
        ylo, yhi = float(bands[:, 2].min()), float(bands[:, 3].max())
        handles.append(Patch(facecolor=_TUBE_FACE, label=f"tube ({tube.num_boxes} boxes)"))
    cert_span = None
    if cert is not None:
        # the signal row @ x over the band's box (an interval per term)
        terms = np.stack([row * cert.lower, row * cert.upper])
        cert_span = (float(terms.min(axis=0).sum()), float(terms.max(axis=0).sum()))
        ylo, yhi = min(ylo, cert_span[0]), max(yhi, cert_span[1])
        handles.append(Patch(facecolor="none", edgecolor=_CERTIFICATE, hatch="///",
                             label=f"certificate band (every state, t >= {cert.t_closed:.3g})"))
    ce = result.counterexample
    if ce is not None:
        n = tube.lower.shape[1]
        (th, xh), (tt, xt), v = _split_trace(ce, list(range(n)))
        yh, yt, yv = xh @ row, xt @ row, float(v @ row)
        # on top of everything else (zorder), in the counterexample's own colour
        ax.plot(th, yh, color=_TRACE, lw=1.2, zorder=6)
        ax.plot(tt, yt, color=_TRACE, lw=1.0, alpha=0.35, zorder=6)
        ax.plot([ce.t], [yv], marker="X", color=_TRACE, ms=8, ls="none", zorder=7)
        handles.append(
            Line2D([], [], color=_TRACE, marker="X", label=f"counterexample ({ce.kind})")
        )
        ylo, yhi = min(ylo, float(yh.min())), max(yhi, float(yh.max()))
    # an output: what the design asks of it, in view when near the tube
    lines: list[tuple[str, float]] = []
    band = None
    if problem is not None and output is not None:
        lines = output_bounds(problem, output)
        ref = reference_band(problem)
        if ref is not None and ref.signal == "y":
            band = (float(ref.lower[output]), float(ref.upper[output]), ref.fixed)
    elif problem is not None and plot is not None:
        ref = reference_band(problem)
        k = scene.states.index(plot.name)
        if ref is not None and ref.signal == "x":
            band = (float(ref.lower[k]), float(ref.upper[k]), ref.fixed)
    if plot is not None:
        ylim = plot.y_range  # the scene's: the recording's state view shows the same
    elif output is not None and output < len(scene.outputs):
        ylim = scene.outputs[output].y_range
    else:
        near = [v for _, v in lines] + ([band[0], band[1]] if band is not None else [])
        span = yhi - ylo if np.isfinite(yhi - ylo) else 0.0
        for v in near:
            if not np.isfinite(ylo) or abs(v - np.clip(v, ylo, yhi)) <= max(span, 1e-9):
                ylo, yhi = min(ylo, v), max(yhi, v)
        ylim = padded(ylo, yhi)
    if bands.shape[0]:
        # at least 1 % of the axis high, so a thin tube does not read as a line (the
        # picture only; edges in the face colour keep boxes narrower than a pixel visible)
        lo_b, hi_b = _min_size(
            bands[:, [0, 2]], bands[:, [1, 3]], np.array([0.0, 0.01 * (ylim[1] - ylim[0])])
        )
        _add_boxes(ax, lo_b, hi_b, fc=_TUBE_FACE, ec=_TUBE_FACE, lw=0.8)
    if cert_span is not None:
        ax.add_patch(_rectangle(cert.t_closed, cert_span[0], scene.band_end - cert.t_closed,
                                cert_span[1] - cert_span[0]))
    ax.set_ylim(*ylim)
    ax.set_xlim(0.0, scene.t_end)
    if plot is not None:
        ax.set_yticks(plot.y_ticks)  # at least three labels
        handles += _state_bounds(ax, plot, ylim)
    elif output is not None and output < len(scene.outputs):
        ax.set_yticks(scene.outputs[output].y_ticks)
    drawn = [(label, v) for label, v in lines if ylim[0] <= v <= ylim[1]]
    for label, v in drawn:
        ax.axhline(v, color="k", lw=1.0, ls=":" if "soft" in label else "--")
    for dotted in (False, True):  # one legend entry for the hard bounds, one for the soft
        which = [label for label, _ in drawn if ("soft" in label) == dotted]
        if which:
            handles.append(Line2D([], [], color="k", ls=":" if dotted else "--",
                                  label=", ".join(which)))
    if band is not None:
        lo_r, hi_r, fixed = band
        if fixed or hi_r <= lo_r:
            ax.axhline(lo_r, color=_REFERENCE, lw=1.5)
            handles.append(Line2D([], [], color=_REFERENCE, label=f"reference {lo_r:.4g}"))
        else:
            ax.axhspan(lo_r, hi_r, color=_REFERENCE, alpha=0.15, lw=0)
            for v in (lo_r, hi_r):
                ax.axhline(v, color=_REFERENCE, lw=1.0)
            handles.append(Patch(facecolor=_REFERENCE, alpha=0.3,
                                 label=f"reference in [{lo_r:.4g}, {hi_r:.4g}]"))
    ax.set_xlabel("t (s)")
    ax.set_ylabel(ylabel)
    if handles:
        ax.legend(handles=handles, fontsize="small", loc="upper right")
    return ax


def _rectangle(x: float, y: float, w: float, h: float) -> Any:
    """The certificate band's patch: hatched, outlined, not filled (a bound, not a tube)."""
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, facecolor="none", edgecolor=_CERTIFICATE, hatch="///",
                     lw=1.0, zorder=1.5)


def _state_bounds(ax: Axes, plot: StatePlot, ylim: tuple[float, float]) -> list:
    """Draw a state plot's limits (unsafe bands red, safe bounds green dashed) and its
    initial interval (a bar at ``t = 0``); returns legend handles."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = []
    drawn_unsafe = False
    for _, a, b in plot.unsafe_bands:
        lo, hi = max(a, ylim[0]), min(b, ylim[1])
        if lo < hi:
            ax.axhspan(lo, hi, color=_UNSAFE, alpha=0.2, lw=0)
            drawn_unsafe = True
    safe = [lim.value for lim in plot.limits if lim.kind == "safe"]
    for y in safe:
        ax.axhline(y, color=_SAFE, ls="--", lw=1)
    if drawn_unsafe:
        handles.append(Patch(facecolor=_UNSAFE, alpha=0.2, label="unsafe"))
    if safe:
        handles.append(Line2D([], [], color=_SAFE, ls="--", label="safe bound"))
    if plot.initial is not None:
        # the initial set holds at t = 0 only: a bar there, not a band in time
        a, b = plot.initial
        ax.plot([0.0, 0.0], [a, b], color=_INITIAL, lw=4, solid_capstyle="butt", zorder=5,
                clip_on=False)
        handles.append(Line2D([], [], color=_INITIAL, lw=4, label="initial set (t = 0)"))
    return handles


def plot_plane(
    result: VerificationResult,
    ax: Axes | None = None,
    *,
    axes: tuple[int, int] = (0, 1),
    problem: Problem | None = None,
    law: ExplicitLaw | None = None,
    scene: Scene | None = None,
) -> Axes:
    """Draw the tube's boxes projected on a plane of two states.

    Parameters
    ----------
    result : VerificationResult
    ax : matplotlib Axes, optional
    axes : (2,) tuple of int
        The states on the horizontal and vertical axes.
    problem : Problem, optional
        Adds the initial set (blue outline), the unsafe sets (red) and the safe sets (green
        outline): the scene's (:class:`~codev_engine.view.scene.SetShape`), each clipped to
        the view box and projected on the plane, as in the recording.
    law : ExplicitLaw, optional
        Adds the outline of the law's domain (for ``n > 2``, its section through the centre
        of the initial set, or :func:`default_slice_point` without a problem).
    scene : Scene, optional
        The design's scene (default: built from the arguments): its window.

    Returns
    -------
    matplotlib Axes
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch, Polygon, Rectangle

    ax = _new_axes(ax)
    tube = result.tube
    n = tube.lower.shape[1]
    i, j = _check_axes(axes, n)
    names = _state_names(n, problem.plant.states if problem is not None else None)
    handles: list[Any] = []
    if scene is None or scene.axes != (i, j):
        scene = build_scene(problem, law, result, axes=(i, j))
    lo2 = np.unique(np.hstack([tube.lower[:, [i, j]], tube.upper[:, [i, j]]]), axis=0)
    if lo2.shape[0]:
        handles.append(Patch(facecolor=_TUBE_FACE, label=f"tube ({tube.num_boxes} boxes)"))
    ce = result.counterexample
    if ce is not None:
        (_, head), (_, tail), v = _split_trace(ce, [i, j])
        # on top of the tube and the sets (zorder), in the counterexample's own colour
        ax.plot(head[:, 0], head[:, 1], color=_TRACE, lw=1.2, zorder=6)
        ax.plot(tail[:, 0], tail[:, 1], color=_TRACE, lw=1.0, alpha=0.35, zorder=6)
        ax.plot(v[:1], v[1:], marker="X", color=_TRACE, ms=8, ls="none", zorder=7)
        handles.append(
            Line2D([], [], color=_TRACE, marker="X", label=f"counterexample ({ce.kind})")
        )
    vs = problem.verify if problem is not None else None
    if vs is not None:
        ilo, ihi = vs.initial_lower[[i, j]], vs.initial_upper[[i, j]]
        ax.add_patch(Rectangle(ilo, *(ihi - ilo), fill=False, ec=_INITIAL, lw=1.2, zorder=3))
        initial_box = np.array([ilo, [ihi[0], ilo[1]], ihi, [ilo[0], ihi[1]]])
        handles.append(Patch(fill=False, ec=_INITIAL, label="initial set"))
    # the scene's window: the recording's plane shows the same
    xlim = (float(scene.plane_lo[0]), float(scene.plane_hi[0]))
    ylim = (float(scene.plane_lo[1]), float(scene.plane_hi[1]))
    if lo2.shape[0]:
        # at least 0.6 % of the view wide and high, so a thin tube does not read as a line
        # (the picture only: the boxes are widened about their centres)
        span = np.array([xlim[1] - xlim[0], ylim[1] - ylim[0]])
        blo, bhi = _min_size(lo2[:, :2], lo2[:, 2:], 0.006 * span)
        _add_boxes(ax, blo, bhi, fc=_TUBE_FACE, ec=_TUBE_FACE, lw=0.5, zorder=2)
    # sets are clipped to a box a little larger than the view: no clipped edge shows
    margin = 0.1 * np.array([xlim[1] - xlim[0], ylim[1] - ylim[0]])
    view = (np.array([xlim[0], ylim[0]]) - margin, np.array([xlim[1], ylim[1]]) + margin)
    # the scene's sets: each clipped to the view box and projected on the plane (the
    # recording draws the same polygons)
    window = (scene.plane_lo, scene.plane_hi)
    drawn = set()
    for shape in scene.sets:
        kind, poly = shape.name.split("/")[0], shape.polygon
        if kind not in ("unsafe", "safe") or poly is None or poly.shape[0] < 3:
            continue
        if kind == "safe" and _fills_view(poly, window):
            continue  # the safe set contains the whole view: nothing to see
        if kind == "unsafe":
            ax.add_patch(Polygon(poly, fc=_UNSAFE, alpha=0.35, lw=0, zorder=0.5))
            _mark_if_small(ax, poly, xlim, ylim, _UNSAFE)
        else:
            ax.add_patch(Polygon(poly, fill=False, ec=_SAFE, ls="--", lw=1))
        drawn.add(kind)
    if "unsafe" in drawn:
        handles.append(Patch(facecolor=_UNSAFE, alpha=0.35, label="unsafe"))
    if "safe" in drawn:
        handles.append(Line2D([], [], color=_SAFE, ls="--", label="safe"))
    if law is not None:
        at = scene.section.point if scene.section is not None and law.n > 2 else None
        dom = _domain_polygon(law, (i, j), at, view)
        if dom is not None:
            ax.add_patch(Polygon(dom, fill=False, ec="#555555", ls=":", lw=1.2))
            word = "law domain" if law.n == 2 else "law domain (section)"
            handles.append(Line2D([], [], color="#555555", ls=":", label=word))
    if vs is not None:
        _mark_if_small(ax, initial_box, xlim, ylim, _INITIAL)
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    if problem is not None:
        ax.set_xlabel(problem.plant.state_label(i))
        ax.set_ylabel(problem.plant.state_label(j))
    else:
        ax.set_xlabel(names[i])
        ax.set_ylabel(names[j])
    if handles:  # where it covers least (the tube is one patch: one box to avoid)
        ax.legend(handles=handles, fontsize="small", loc="best", framealpha=0.85)
    return ax


def _mark_if_small(
    ax: Axes, poly: np.ndarray, xlim: tuple[float, float], ylim: tuple[float, float], colour: str
) -> None:
    """Ring a polygon smaller than 2 % of the view, so a small set is seen at all."""
    span = np.ptp(poly, axis=0) / np.array([xlim[1] - xlim[0], ylim[1] - ylim[0]])
    if np.all(span < 0.02):
        c = poly.mean(axis=0)
        ax.plot([c[0]], [c[1]], marker="o", ms=14, mfc="none", mec=colour, mew=1.5, zorder=4)


def _split_trace(
    ce: Counterexample, cols: list[int]
) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray]:
    """A counterexample's trace on states ``cols``, split at the violation.

    Returns
    -------
    head : ((k,) ndarray, (k, c) ndarray)
        Times and states up to and including the violation (interpolated at ``ce.t``).
    tail : ((l,) ndarray, (l, c) ndarray)
        From the violation to the end of the simulation (drawn faint).
    v : (c,) ndarray
        The state at the violation.
    """
    t = np.asarray(ce.trace.t, dtype=float)
    X = np.asarray(ce.trace.x, dtype=float)[:, cols]
    v = np.array([np.interp(ce.t, t, X[:, k]) for k in range(X.shape[1])])
    before = t < ce.t
    head = (np.append(t[before], ce.t), np.vstack([X[before], v]))
    tail = (np.insert(t[~before], 0, ce.t), np.vstack([v, X[~before]]))
    return head, tail, v


def _domain_polygon(
    law: ExplicitLaw,
    axes: tuple[int, int],
    at: np.ndarray | None,
    view: tuple[np.ndarray, np.ndarray],
) -> np.ndarray | None:
    """The section of the law's domain clipped to ``view`` -> (v, 2); None when the domain's
    boundary does not cross the view (or the law stores no domain)."""
    if law.domain_A is None or not law.domain_A.shape[0]:
        return None
    lo, hi = view
    E = np.zeros((4, law.n))
    E[[0, 2], axes[0]] = 1.0, -1.0
    E[[1, 3], axes[1]] = 1.0, -1.0
    e = np.array([hi[0], hi[1], -lo[0], -lo[1]])
    A = np.vstack([law.domain_A, E])
    b = np.concatenate([law.domain_b, e])
    polys, _ = section_polygons([A], [b], axes=axes, at=at)
    if not polys:
        return None
    return None if _fills_view(polys[0], view) else polys[0]


def _fills_view(poly: np.ndarray, view: tuple[np.ndarray, np.ndarray]) -> bool:
    """Is a polygon clipped to ``view`` the whole view box (its boundary out of sight)?"""
    lo, hi = view
    corners = _box_corners(lo[None], hi[None])[0]
    gap = np.abs(poly[:, None, :] - corners[None]).max(axis=2).min(axis=1)
    return bool(np.all(gap <= 1e-9 * (1.0 + np.abs(corners).max())))


def _verdict_text(result: VerificationResult) -> str:
    """``robustly safe``, ``unsafe: enters unsafe set 0 at t = 2.47``, ``unknown (max_depth)``."""
    text = result.verdict.replace("_", " ")
    ce = result.counterexample
    if result.verdict == "unsafe" and ce is not None:
        return f"{text}: {ce.describe()} at t = {ce.t:.4g}"
    return f"{text} ({result.reason})" if result.reason else text


def figure_result(
    result: VerificationResult,
    problem: Problem | None = None,
    *,
    law: ExplicitLaw | None = None,
    max_states: int = 4,
    scene: Scene | None = None,
) -> Figure:
    """A figure of a verification result: verdict title, tubes against time, plane view.

    Parameters
    ----------
    result : VerificationResult
    problem : Problem, optional
        Adds state names, the problem's name and the verify section's sets.
    law : ExplicitLaw, optional
        Adds the law's domain to the plane view.
    max_states : int
        Tubes against time are drawn for the first ``max_states`` states (and outputs).
    scene : Scene, optional
        The design's scene (:func:`~codev_engine.view.scene.build_scene`; the HTML report
        passes the recording's): windows, ranges, limits, the plane's axes and section.
        Built from the arguments by default.

    Returns
    -------
    matplotlib Figure
        Left: one tube-vs-time panel per state, then one per output ``y = C x`` of the
        problem (:func:`plot_output`); right (``n >= 2``): the plane of the first
        two states (:func:`plot_plane`).
    """
    from matplotlib.figure import Figure

    n = result.tube.lower.shape[1]
    p = 0
    if problem is not None and problem.mpc.C is not None and problem.plant.n == n:
        p = min(np.asarray(problem.mpc.C).shape[0], max_states)
    shown = max(1, min(n, max_states))
    rows = shown + p
    plane = n >= 2
    drawn = None if law is None else law_section(law, problem)  # a theta law: its section
    if scene is None:
        scene = build_scene(problem, drawn, result, axes=(0, 1) if plane else None)
    fig = Figure(figsize=(11.0 if plane else 6.5, 1.2 + 2.0 * rows), layout="constrained")
    grid = fig.add_gridspec(rows, 2 if plane else 1, width_ratios=[1.2, 1] if plane else None)
    for k in range(rows):
        ax = fig.add_subplot(grid[k, 0])
        if k < shown:
            plot_tube(result, ax, state=k, problem=problem, scene=scene)
        else:
            assert problem is not None
            plot_output(result, problem, ax, output=k - shown, scene=scene)
        if k < rows - 1:
            ax.set_xlabel("")
    if plane:
        ax = fig.add_subplot(grid[:, 1])
        plot_plane(result, ax, axes=scene.axes or (0, 1), problem=problem, law=drawn,
                   scene=scene)
        if scene.section is not None:
            ax.set_title(f"section at {scene.section.words}", fontsize="medium")
    name = f"{problem.name}: " if problem is not None else ""
    stats = f"{result.tube.num_boxes} boxes, {result.seconds:.3g} s, hold {result.hold}"
    # the numbers on a line of their own: on one line the title of a one-state figure
    # (6.5 in wide) was wider than the figure, and lost its first and last letters
    # (":ruise-control", cruise_control's report)
    fig.suptitle(
        f"{name}{_verdict_text(result)}\n[{stats}]",
        color=VERDICT_COLOURS.get(result.verdict, "k"),
        fontweight="bold",
    )
    return fig


# --------------------------------------------------------------------------------------------
# notebook rendering
# --------------------------------------------------------------------------------------------


def png_bytes(fig: Figure, *, dpi: float = _DPI) -> bytes:
    """The figure as PNG bytes (rendered by Agg; no backend or pyplot involved).

    Parameters
    ----------
    fig : matplotlib Figure
        The figure to render.
    dpi : float
        Resolution of the PNG.

    Returns
    -------
    bytes
        The PNG file's content.
    """
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _img(png: bytes) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%"/>'


def _table(rows: list[tuple[str, str]]) -> str:
    body = "".join(
        f"<tr><th style='text-align:left;padding-right:1em'>{html.escape(k)}</th>"
        f"<td style='text-align:left'>{html.escape(v)}</td></tr>"
        for k, v in rows
    )
    return f"<table>{body}</table>"


def law_html(law: ExplicitLaw, png: bytes | None = None) -> str:
    """HTML summary of a law (regions, n, m, norm, ...) with the partition picture.

    Parameters
    ----------
    law : ExplicitLaw
    png : bytes, optional
        The picture (:func:`figure_law` rendered by :func:`png_bytes`); drawn if None.
    """
    if png is None:
        png = png_bytes(figure_law(law))
    rows = [
        # (a law stored as shards: "N in S shards", its files read, never merged)
        ("regions", str(law.num_regions) if getattr(law, "shards", None) is None
         else f"{law.num_regions} in {law.shards} shard{'s' if law.shards != 1 else ''}"),
        ("states", f"{len(law.states)} ({', '.join(law.states)})" if law.states else str(law.n)),
        ("inputs", f"{law.m} ({', '.join(law.inputs)})" if law.inputs else str(law.m)),
    ]
    if law.parameters and len(law.parameters) != len(law.states):
        rows.append(("theta", f"{law.n} ({', '.join(law.parameters)})"))
    for key in ("norm", "horizon", "seconds"):
        if key in law.meta:
            rows.append((key, str(law.meta[key])))
    title = html.escape(str(law.meta.get("problem", "")))
    head = f"<b>ExplicitLaw</b> {title}".rstrip()
    return f"<div>{head}{_table(rows)}{_img(png)}</div>"


def result_html(
    result: VerificationResult, png: bytes | None = None, *, problem: Problem | None = None
) -> str:
    """HTML summary of a verification result: a coloured verdict banner, the claim (with
    the spec), the counterexample, timings and sizes, and the tube picture.

    Parameters
    ----------
    result : VerificationResult
    png : bytes, optional
        The picture (:func:`figure_result` rendered by :func:`png_bytes`); drawn if None.
    problem : Problem, optional
        The spec verified: the claim (:func:`codev_engine.reach.claim.build_claim`) is
        listed under the banner.
    """
    if png is None:
        png = png_bytes(figure_result(result))
    colour = VERDICT_COLOURS.get(result.verdict, "#555555")
    banner = (
        f"<div style='background:{colour};color:white;padding:4px 10px;"
        f"font-weight:bold;border-radius:3px'>{html.escape(_verdict_text(result))}</div>"
    )
    rows = [
        ("hold", result.hold),
        ("boxes", str(result.tube.num_boxes)),
        ("branches", str(result.stats.get("branches", 0))),
        ("seconds", f"{result.seconds:.3f}"),
    ]
    ce = result.counterexample
    if ce is not None:
        rows += [
            ("counterexample x0", np.array2string(np.asarray(ce.x0), precision=6)),
            ("violation", f"{ce.kind} (index {ce.index}) at t = {ce.t:.4f}"),
        ]
    claim = ""
    if problem is not None and problem.verify is not None:
        from codev_engine.reach.claim import build_claim

        items = build_claim(problem, result).lines()
        claim = "<ul>" + "".join(f"<li>{html.escape(i[2:])}</li>" for i in items) + "</ul>"
    return f"<div>{banner}{claim}{_table(rows)}{_img(png)}</div>"


# --------------------------------------------------------------------------------------------
# sweeps
# --------------------------------------------------------------------------------------------

#: the bar colour of a design whose synthesis or verification broke down
_SWEEP_ERROR = "#9e9e9e"


def _sweep_value(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_sweep_value(x) for x in v) + "]"
    return str(v)


def plot_sweep(rows: list[dict], *, ax: Axes | None = None) -> Axes:
    """A sweep's designs against their swept values: bars of the law's regions, coloured
    by the verdict (``VERDICT_COLOURS``; grey where the design broke down).

    Parameters
    ----------
    rows : list of dict
        ``ce.sweep``'s rows (``values``, ``regions``, ``verdict``, ``error``), in order.
    ax : matplotlib Axes, optional
        Draw into it (default: a new figure's).

    Returns
    -------
    Axes
        One bar per design, labelled with its swept values; the bar's text is the
        verdict's reason where there is one.
    """
    ax = _new_axes(ax, (max(4.0, 0.8 * len(rows) + 2.0), 4.0))
    x = np.arange(len(rows))
    heights = [float(r.get("regions") or 0) for r in rows]
    colours = [
        _SWEEP_ERROR if r.get("error") else VERDICT_COLOURS.get(r.get("verdict"), _SWEEP_ERROR)
        for r in rows
    ]
    bars = ax.bar(x, heights, color=colours, edgecolor="black", linewidth=0.5)
    for bar, r in zip(bars, rows, strict=True):
        note = "error" if r.get("error") else (r.get("reason") or "")
        if note:
            ax.annotate(note, (bar.get_x() + bar.get_width() / 2, bar.get_height()),
                        ha="center", va="bottom", fontsize=7, rotation=90)
    labels = ["\n".join(f"{k} = {_sweep_value(v)}" for k, v in r["values"].items())
              for r in rows]
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("critical regions")
    ax.set_title("sweep: regions and verdict per design")
    from matplotlib.patches import Patch

    seen = dict.fromkeys(("error" if r.get("error") else r.get("verdict")) for r in rows)
    ax.legend(handles=[Patch(color=VERDICT_COLOURS.get(v, _SWEEP_ERROR), label=str(v))
                       for v in seen], fontsize=7, loc="best")
    return ax
