"""Terminal pictures of the engine's objects: partitions, reachtubes, time series.

Each function takes engine data and a size in cells and returns a ``rich.text.Text`` (see
:mod:`workbench.tui.raster`). Pure functions of their inputs: the widgets call them from a worker
thread and only swap the finished text in.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from rich.text import Text

if TYPE_CHECKING:
    from collections.abc import Sequence

    from codev_engine import ExplicitLaw, Problem, VerificationResult

from codev_engine.view.figures import default_slice_point

from .raster import COLOURS, Raster, nice_limits, plot_text

#: the colour of a reference line (the preview's)
REFERENCE = "#d37bff"

__all__ = ["law_limits", "partition_text", "plane_text", "series_text", "tube_time_text"]


def law_limits(law: ExplicitLaw, axes: tuple[int, int]) -> tuple[tuple[float, float], ...]:
    """View limits of the law's domain on two state axes (its regions' bounding box).

    Parameters
    ----------
    law : ExplicitLaw
    axes : tuple of (int, int)
        The state axes shown, horizontal then vertical.

    Returns
    -------
    tuple of ((float, float), (float, float))
        The x and y limits, padded by 3 %.
    """
    lo, hi = law.boxes
    i, j = axes
    return (
        nice_limits(lo[:, i].min(), hi[:, i].max(), 0.03),
        nice_limits(lo[:, j].min(), hi[:, j].max(), 0.03),
    )


def partition_text(
    law: ExplicitLaw,
    width: int,
    height: int,
    *,
    axes: tuple[int, int] = (0, 1),
    at: np.ndarray | None = None,
    marker: np.ndarray | None = None,
    limits: tuple[tuple[float, float], tuple[float, float]] | None = None,
) -> Text:
    """The critical regions coloured on a pixel grid (a 2-D section for n > 2), under a title
    that names the section.

    Parameters
    ----------
    law : ExplicitLaw
    width, height : int
        Plot size in cells (the pixel grid is width × 2·height).
    axes : (2,) tuple of int
        The state axes shown.
    at : (n,) array_like, optional
        The other parameters' values on the section (default: ``figures.default_slice_point``
        without a spec, the centre of the domain's bounding box; the workbench passes the
        spec's, the one section rule of recordings and reports).
    marker : (n,) array_like, optional
        A state to mark (the located state).
    limits : tuple of ((float, float), (float, float)), optional
        The x and y limits of the view (default: :func:`law_limits`).

    Returns
    -------
    rich.text.Text
        The title (the number of regions, the section), the picture and its axes.
    """
    n = law.n
    i, j = axes
    xlim, ylim = limits or law_limits(law, axes)
    r = Raster(width, height, xlim, ylim)
    xs, ys = r.centres()
    if at is None:
        at = default_slice_point(law)  # the notebook pictures use the same slice
    base = np.asarray(at, dtype=float).reshape(n)
    gx, gy = np.meshgrid(xs, ys)
    X = np.tile(base, (gx.size, 1))
    X[:, i] = gx.ravel()
    X[:, j] = gy.ravel()
    idx = law.locate(X).reshape(gx.shape)
    r.paint(idx)
    if marker is not None:
        mk = np.asarray(marker, dtype=float).reshape(n)
        r.points([mk[i]], [mk[j]], COLOURS["marker"])
    names = law.parameter_names or tuple(f"x{k}" for k in range(n))
    found = len(np.unique(idx[idx >= 0]))
    # the title names the section as recordings and reports do (record_content.section_words)
    title = f"the partition, {law.num_regions} regions ({found} in view)"
    if n > 2:
        fixed = ", ".join(f"{names[k]} = {base[k]:.3g}" for k in range(n) if k not in axes)
        title += f", section at {fixed}"
    out = Text(title + "\n", style=COLOURS["axis"], no_wrap=True, overflow="crop")
    return out + plot_text(r, xlabel=names[i], ylabel=names[j])


def tube_time_text(
    result: VerificationResult,
    width: int,
    height: int,
    *,
    state: int = 0,
    problem: Problem | None = None,
    names: tuple[str, ...] = (),
) -> Text:
    """One state's reachtube against time, with unsafe bounds and the counterexample.

    Parameters
    ----------
    result : VerificationResult
        Its tube's boxes are drawn over their time intervals, its counterexample's trace
        (if any) as a line.
    width, height : int
        Plot size in cells.
    state : int
        The state shown.
    problem : Problem, optional
        The spec verified: its unsafe boxes are drawn (their bounds on ``state`` near the
        tube widen the view) and its state names label the axis.
    names : tuple of str
        The state names (default: the problem's, else ``x0``, ``x1``, ...).

    Returns
    -------
    rich.text.Text
    """
    tube = result.tube
    names = names or (problem.plant.states if problem is not None else ())
    name = names[state] if names else f"x{state}"
    if tube.num_boxes == 0:
        return Text("(empty reachtube)")
    t1 = float(tube.t_end.max())
    ts, te = np.asarray(tube.t_start, float), np.asarray(tube.t_end, float)
    lo, hi = tube.lower[:, state], tube.upper[:, state]
    # after an all-time certificate: the tube to its closing sample, then the band that
    # holds every later state, to the view's end (as the figures and the recording)
    from codev_engine.reach.claim import certificate_band

    cert = certificate_band(result)
    if cert is not None:
        mine = ts < cert.t_closed - 1e-9 * max(1.0, cert.t_closed)
        ts, te, lo, hi = ts[mine], te[mine], lo[mine], hi[mine]
        if problem is not None and problem.verify is not None:
            from codev_engine.reach.simulate import shown_horizon

            t1 = max(t1, shown_horizon(problem))
    ymin, ymax = float(np.min(lo)), float(np.max(hi))
    if cert is not None:
        ymin, ymax = min(ymin, float(cert.lower[state])), max(ymax, float(cert.upper[state]))
    cex = result.counterexample
    trace = getattr(cex, "trace", None) if cex is not None else None
    if trace is not None:
        ymin = min(ymin, float(np.nanmin(trace.x[:, state])))
        ymax = max(ymax, float(np.nanmax(trace.x[:, state])))
    if problem is not None and problem.verify is not None:
        # show an unsafe bound that is near the tube (within half its range): the margin is
        # what the user looks for
        near = 0.5 * max(ymax - ymin, 1e-9)
        for s in problem.verify.unsafe:
            if s.kind != "box":
                continue
            for v in (float(s.lower[state]), float(s.upper[state])):
                if np.isfinite(v) and ymin - near <= v <= ymax + near:
                    ymin, ymax = min(ymin, v), max(ymax, v)
    r = Raster(width, height, nice_limits(0.0, t1, 0.0), nice_limits(ymin, ymax))
    legend = [("reachtube", COLOURS["tube"])]
    if problem is not None and problem.verify is not None:
        for s in problem.verify.unsafe:
            if s.kind == "box":
                r.boxes([0.0], [t1], [s.lower[state]], [s.upper[state]], COLOURS["unsafe"])
        if problem.verify.unsafe:
            legend.append(("unsafe (boxes)", COLOURS["unsafe"]))
    r.boxes(ts, te, lo, hi, COLOURS["tube"])
    if cert is not None and t1 > cert.t_closed:
        r.boxes([cert.t_closed], [t1], [cert.lower[state]], [cert.upper[state]],
                COLOURS["certificate"])
        legend.append(("certificate band", COLOURS["certificate"]))
    if trace is not None:
        r.polyline(trace.t, trace.x[:, state], COLOURS["cex"])
        legend.append(("counterexample", COLOURS["cex"]))
    return plot_text(r, xlabel="t (s)", ylabel=name, legend=legend)


def _with_edges_near(values: np.ndarray, edges: list[float]) -> np.ndarray:
    """``values`` plus the finite ``edges`` within one extent of ``values`` of their range."""
    lo, hi = float(values.min()), float(values.max())
    near = max(hi - lo, 1e-9 * max(1.0, abs(lo), abs(hi)))
    extra = [float(e) for e in edges if np.isfinite(e) and lo - near <= e <= hi + near]
    return np.concatenate([values, np.asarray(extra, dtype=float)]) if extra else values


def _certificate_outline(result: VerificationResult, axes: tuple[int, int]
                         ) -> np.ndarray | None:
    """The invariance certificate's set (``H x <= h``, or the invariant ellipsoid of a
    nonlinear plant; time_horizon = "inf") projected on ``axes``, as a closed outline
    (k + 1, 2); None without a certificate (or a flat one)."""
    cert = result.certificate
    if cert is not None and "P" in cert:  # an invariant ellipsoid: its shadow on the plane
        from codev_engine.reach.terminal import ellipsoid_outline

        if np.ndim(cert["P"]) != 2 or max(axes) >= np.shape(cert["P"])[0]:
            return None
        return ellipsoid_outline(cert["P"], cert["centre"], tuple(axes))
    if cert is None or "H" not in cert:
        return None
    from scipy.spatial import ConvexHull, QhullError

    from codev_engine.geometry.polytope import normalize_rows
    from codev_engine.geometry.vertices import vertices

    H, h, ok = normalize_rows(np.asarray(cert["H"], float), np.asarray(cert["h"], float))
    V = vertices(H, h, 1e-9) if ok else None
    if V is None or V.shape[0] < 3:
        return None
    P = V[:, list(axes)]
    try:
        order = ConvexHull(P).vertices
    except QhullError:
        return None
    return np.vstack([P[order], P[order[:1]]])


def plane_text(
    result: VerificationResult,
    width: int,
    height: int,
    *,
    axes: tuple[int, int] = (0, 1),
    problem: Problem | None = None,
    names: tuple[str, ...] = (),
) -> Text:
    """The reachtube's boxes projected on two state axes, with the sets and counterexample.

    Parameters
    ----------
    result : VerificationResult
        Its tube's boxes are drawn, its counterexample's trace (if any) as a line.
    width, height : int
        Plot size in cells.
    axes : tuple of (int, int)
        The state axes shown, horizontal then vertical.
    problem : Problem, optional
        The spec verified: its unsafe boxes are filled and its initial set outlined.
    names : tuple of str
        The state names (default: the problem's, else ``x0``, ``x1``, ...).

    Returns
    -------
    rich.text.Text
    """
    tube = result.tube
    i, j = axes
    pts_x = [tube.lower[:, i], tube.upper[:, i]]
    pts_y = [tube.lower[:, j], tube.upper[:, j]]
    vs = problem.verify if problem is not None else None
    if vs is not None:
        pts_x += [vs.initial_lower[i : i + 1], vs.initial_upper[i : i + 1]]
        pts_y += [vs.initial_lower[j : j + 1], vs.initial_upper[j : j + 1]]
    cex = result.counterexample
    trace = getattr(cex, "trace", None) if cex is not None else None
    if trace is not None:
        pts_x.append(trace.x[:, i])
        pts_y.append(trace.x[:, j])
    allx, ally = np.concatenate(pts_x), np.concatenate(pts_y)
    allx, ally = allx[np.isfinite(allx)], ally[np.isfinite(ally)]
    if allx.size == 0:
        return Text("(nothing to draw)")
    if vs is not None:
        # the unsafe boxes' edges near the tube (within its extent again) are in the window:
        # the margin to them is what the picture is for; farther ones would squash the tube
        boxes = [s for s in vs.unsafe if s.kind == "box"]
        allx = _with_edges_near(allx, [v for s in boxes for v in (s.lower[i], s.upper[i])])
        ally = _with_edges_near(ally, [v for s in boxes for v in (s.lower[j], s.upper[j])])
    r = Raster(
        width, height, nice_limits(allx.min(), allx.max()), nice_limits(ally.min(), ally.max())
    )
    legend = [("reachtube", COLOURS["tube"])]
    if vs is not None:
        for s in vs.unsafe:
            if s.kind == "box":
                r.boxes([s.lower[i]], [s.upper[i]], [s.lower[j]], [s.upper[j]], COLOURS["unsafe"])
        if vs.unsafe:
            legend.append(("unsafe", COLOURS["unsafe"]))
    r.boxes(tube.lower[:, i], tube.upper[:, i], tube.lower[:, j], tube.upper[:, j], COLOURS["tube"])
    if vs is not None:
        r.outline(
            vs.initial_lower[i],
            vs.initial_upper[i],
            vs.initial_lower[j],
            vs.initial_upper[j],
            COLOURS["initial"],
        )
        legend.append(("initial set", COLOURS["initial"]))
    outline = _certificate_outline(result, axes)
    if outline is not None:
        r.polyline(outline[:, 0], outline[:, 1], COLOURS["certificate"])
        legend.append(("invariant set", COLOURS["certificate"]))
    if trace is not None:
        r.polyline(trace.x[:, i], trace.x[:, j], COLOURS["cex"])
        legend.append(("counterexample", COLOURS["cex"]))
    nm = (
        names
        or (problem.plant.states if problem is not None else ())
        or tuple(f"x{k}" for k in range(tube.lower.shape[1]))
    )
    return plot_text(r, xlabel=nm[i], ylabel=nm[j], legend=legend)


def series_text(
    t: np.ndarray,
    Y: np.ndarray,
    labels: tuple[str, ...],
    width: int,
    height: int,
    *,
    steps: bool = False,
    lines: Sequence[tuple[str, float]] = (),
) -> Text:
    """Time series as coloured lines, one per column of ``Y``, and horizontal lines.

    Parameters
    ----------
    t : (K,) array_like of float
        Sample times.
    Y : (K, k) array_like of float
        The signals' values at the samples.
    labels : tuple of str
        The signals' names in the legend (missing ones: ``y0``, ``y1``, ...).
    width, height : int
        Plot size in cells.
    steps : bool
        Draw each signal held from one sample to the next (an input under zero-order hold).
    lines : sequence of (str, float)
        Horizontal lines over the whole time axis, dashed in :data:`REFERENCE` (the
        reference a preview follows), named in the legend; always in view.

    Returns
    -------
    rich.text.Text
    """
    t = np.asarray(t, dtype=float).ravel()
    Y = np.asarray(Y, dtype=float)
    if t.size == 0 or Y.size == 0:
        return Text("(no data)")
    Y = Y.reshape(t.size, -1)
    finite = Y[np.isfinite(Y)]
    if finite.size == 0:
        return Text("(no data)")
    levels = np.array([v for _, v in lines if np.isfinite(v)], dtype=float)
    lo, hi = finite.min(), finite.max()
    if levels.size:
        lo, hi = min(lo, levels.min()), max(hi, levels.max())
    r = Raster(width, height, nice_limits(t.min(), t.max(), 0.0), nice_limits(lo, hi))
    r.polyline(t, np.zeros_like(t), COLOURS["axis"])
    palette = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948")
    legend = []
    for k in range(Y.shape[1]):
        colour = palette[k % len(palette)]
        if steps:
            tt = np.repeat(t, 2)[1:]
            yy = np.repeat(Y[:, k], 2)[:-1]
        else:
            tt, yy = t, Y[:, k]
        r.polyline(tt, yy, colour)
        legend.append((labels[k] if k < len(labels) else f"y{k}", colour))
    if lines:
        # dashed: 3 pixels on, 2 off, across the time axis
        cols = r.shape[1]
        x0, x1 = r.xlim
        edges = x0 + np.arange(cols + 1) * (x1 - x0) / cols
        for label, v in lines:
            if not np.isfinite(v):
                continue
            for c in range(0, cols, 5):
                a, b = edges[c] + 1e-9 * (x1 - x0), edges[min(c + 3, cols)] - 1e-9 * (x1 - x0)
                r.polyline(np.array([a, b]), np.array([v, v]), REFERENCE)
            legend.append((f"{label} = {v:.4g}", REFERENCE))
    return plot_text(r, xlabel="t (s)", legend=legend)
