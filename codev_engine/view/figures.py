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

if TYPE_CHECKING:  # pragma: no cover - typing only
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from codev_engine.law import ExplicitLaw
    from codev_engine.reach.verification import Counterexample, VerificationResult
    from codev_engine.spec.problem import Problem, SetSpec

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
_TUBE_FACE = "#6baed6"
#: the counterexample: a colour of its own (the unsafe sets are red), drawn on top
_TRACE = "#000000"
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


def section_polygons(
    A: list[np.ndarray],
    b: list[np.ndarray],
    *,
    axes: tuple[int, int] = (0, 1),
    at: np.ndarray | None = None,
    tol: float = 1e-9,
) -> tuple[list[np.ndarray], np.ndarray]:
    """The 2-D sections of polytopes ``{x : A_i x <= b_i}`` as ordered polygons.

    The section of region ``i`` is ``{(x[axes[0]], x[axes[1]]) : A_i x <= b_i}`` with every
    other coordinate fixed at ``at``. Its rows are normalised in the plane and its vertices
    found for all regions at once by :func:`~codev_engine.geometry.vertices.packed_vertices`
    (every pair of rows intersected, the points that satisfy all the region's rows kept),
    then sorted by angle around their mean.

    Parameters
    ----------
    A : list of (r_i, n) ndarray
        Region rows.
    b : list of (r_i,) ndarray
    axes : (2,) tuple of int
        The two coordinates spanning the plane (distinct, ``< n``).
    at : (n,) array_like, optional
        Values of the other coordinates (ignored for ``n == 2``); zeros by default.
    tol : float
        Feasibility tolerance of a candidate vertex, ``tol * (1 + |b_j|)`` for row ``j``
        (absolute and relative parts of :func:`~codev_engine.geometry.vertices.packed_vertices`).

    Returns
    -------
    polygons : list of (v_k, 2) ndarray
        Counter-clockwise vertices of each non-degenerate section (positive area).
    index : (p,) ndarray of int
        The region of each polygon, increasing.
    """
    R = len(A)
    if R == 0:
        return [], np.zeros(0, dtype=int)
    n = A[0].shape[1]
    i, j = _check_axes(axes, n)
    counts = np.array([a.shape[0] for a in A])
    rows = np.vstack(A).astype(float)
    rhs = np.concatenate(b).astype(float)
    region = np.repeat(np.arange(R), counts)
    others = [k for k in range(n) if k not in (i, j)]
    if others:
        at = np.zeros(n) if at is None else np.asarray(at, dtype=float).reshape(n)
        rhs = rhs - rows[:, others] @ at[others]
    plane = rows[:, [i, j]]
    scale = np.maximum(np.linalg.norm(rows, axis=1), 1e-300)
    norm = np.hypot(plane[:, 0], plane[:, 1])
    flat = norm <= 1e-12 * scale
    # a row without a component in the plane is a constant test: all or nothing
    empty = np.bincount(region[flat & (rhs < -tol * (1.0 + np.abs(rhs)))], minlength=R) > 0
    keep = ~flat & ~empty[region]
    plane = plane[keep] / norm[keep, None]
    rhs = rhs[keep] / norm[keep]
    region = region[keep]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(region, minlength=R))])
    # all regions in one enumeration (the section rows have unit norm in the plane)
    # imported here: geometry's LPs load scipy.optimize (~0.3 s), which the workbench's first
    # screen must not wait for
    from codev_engine.geometry.vertices import packed_vertices

    P, own, _ = packed_vertices(plane, rhs, offsets, tol, rtol=tol, max_combos=None)
    if own.size == 0:
        return [], np.zeros(0, dtype=int)
    # order the vertices of each region by angle around their mean
    num = np.bincount(own, minlength=R)
    centre = (
        np.stack([np.bincount(own, P[:, 0], R), np.bincount(own, P[:, 1], R)], axis=1)
        / np.maximum(num, 1)[:, None]
    )
    d = P - centre[own]
    order = np.lexsort((np.arctan2(d[:, 1], d[:, 0]), own))
    P, own = P[order], own[order]
    regs, first = np.unique(own, return_index=True)
    # shoelace area per region (cyclic successor inside each region's run)
    nxt = np.arange(1, own.size + 1)
    nxt[np.append(first[1:], own.size) - 1] = first
    cross = P[:, 0] * P[nxt, 1] - P[nxt, 0] * P[:, 1]
    area = 0.5 * np.add.reduceat(cross, first)
    span = float(np.ptp(P, axis=0).max()) if P.size else 0.0
    good = (np.diff(np.append(first, own.size)) >= 3) & (area > 1e-12 * max(span, 1.0) ** 2)
    polys = np.split(P, first[1:])
    return [polys[k] for k in np.flatnonzero(good)], regs[good]


def default_slice_point(
    law: ExplicitLaw, problem: Problem | None = None, *, centre: np.ndarray | None = None
) -> np.ndarray:
    """The point whose other coordinates fix a 2-D section of a law of ``n > 2`` parameters.

    The states: with a ``problem`` that has a ``[verify]`` section, the centre of its initial
    set (where the tube starts: the one section rule of recordings, reports, notebook
    figures); else (and every parameter without a verified spec) the centre of the bounding
    box of the law's domain (the MPC's feasible set; two LPs per coordinate) -- for the usual
    designs around an operating point with symmetric bounds, that operating point. Without
    a stored domain: the centre of the regions' bounding boxes.

    For a law over ``theta = (x, u_prev, r)`` and a ``problem`` with a ``[verify]`` section,
    ``u_prev`` and ``r`` are the middle of the boxes the closed loop starts from
    (``[verify] initial_input``, else the operating input; ``[verify] reference``, else the
    ``[mpc.reference]`` box; :func:`codev_engine.reach.simulate.theta_initial_box`): the
    values recordings, reports, notebook figures and the workbench's slice all use.

    Parameters
    ----------
    law : ExplicitLaw
        The law, with ``n > 2`` parameters.
    problem : Problem, optional
        The spec the law was synthesised from; ignored when it does not fit the law.
    centre : (n,) array_like, optional
        ``default_slice_point(law)`` computed before (the domain's centre, LPs): a caller
        that moves only ``problem`` (the workbench, at every form check) passes it.

    Returns
    -------
    (n,) ndarray
    """
    from codev_engine.geometry.polytope import bounding_box

    point = None if centre is None else np.array(centre, dtype=float).reshape(law.n)
    if point is None and law.domain_A is not None and law.domain_A.shape[0]:
        lo, hi = bounding_box(law.domain_A, law.domain_b)
        if np.all(np.isfinite(lo) & np.isfinite(hi)):
            point = 0.5 * (lo + hi)
    if point is None:
        if law.num_regions == 0:
            point = np.zeros(law.n)
        else:
            lo, hi = law.boxes
            point = 0.5 * (lo.min(axis=0) + hi.max(axis=0))
    point = np.array(point, dtype=float)
    vs = problem.verify if problem is not None else None
    if vs is not None and len(law.states) == problem.plant.n <= law.n:
        point[: problem.plant.n] = 0.5 * (vs.initial_lower + vs.initial_upper)
    extra = verified_parameters(law, problem)
    if extra is not None:
        point[law.n - extra.size :] = extra
    return point


def verified_parameters(law: ExplicitLaw, problem: Problem | None) -> np.ndarray | None:
    """The middle of the initial ``(u_prev, r)`` box of ``problem``'s verification, for a
    law over ``theta = (x, u_prev, r)`` that fits it.

    Parameters
    ----------
    law : ExplicitLaw
    problem : Problem or None

    Returns
    -------
    (n - len(states),) ndarray or None
        None without ``problem``, without ``[verify]``, or for a law over the states.
    """
    if problem is None or problem.verify is None or not law.parameters:
        return None
    nx = problem.plant.n
    if len(law.states) != nx or law.n <= nx:
        return None
    from codev_engine.reach.simulate import theta_initial_box

    lo, hi = theta_initial_box(problem)
    if lo.shape[0] != law.n:
        return None
    return 0.5 * (lo[nx:] + hi[nx:])


def law_section(law: ExplicitLaw, problem: Problem | None = None) -> ExplicitLaw:
    """The law in the states alone: for a law over ``theta = (x, u_prev, r)``, its section
    (:meth:`ExplicitLaw.section`) at :func:`default_slice_point`'s ``u_prev`` and ``r``; any
    other law as it is.

    Parameters
    ----------
    law : ExplicitLaw
    problem : Problem, optional

    Returns
    -------
    ExplicitLaw
    """
    nx = len(law.states)
    if not law.parameters or law.n == nx:
        return law
    return law.section(default_slice_point(law, problem)[nx:])


def _check_axes(axes: tuple[int, int], n: int) -> tuple[int, int]:
    i, j = (int(a) for a in axes)
    if i == j or not (0 <= i < n and 0 <= j < n):
        raise ValueError(f"axes must be two distinct state indices below {n}, got {axes}")
    return i, j


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


def _padded(lo: float, hi: float, frac: float = 0.15) -> tuple[float, float]:
    """An interval around ``[lo, hi]`` with a margin (a unit margin when it is a point)."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return -1.0, 1.0
    pad = frac * (hi - lo) if hi > lo else max(1.0, abs(lo)) * 0.1
    return lo - pad, hi + pad


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
    if law.n == 1:
        return _plot_intervals(law, ax, names[0], label, linewidth)
    i, j = _check_axes(axes, law.n)
    at_full = None
    if law.n > 2:
        at_full = default_slice_point(law) if at is None else np.asarray(at, dtype=float)
    polys, index = section_polygons(law.A, law.b, axes=(i, j), at=at_full)
    _add_polygons(ax, polys, _region_colours(index), linewidth)
    ax.set_xlabel(names[i])
    ax.set_ylabel(names[j])
    title = f"{label}: {_regions_text(law, law.num_regions)}"
    # every value the picture fixes: the states off the plane, a theta law's u_prev and r
    fixed_at = [f"{names[k]} = {at_full[k]:.3g}" for k in range(law.n) if k not in (i, j)
                ] if at_full is not None else []
    fixed_at += [f"{k} = {v:.3g}" for k, v in dict(law.meta.get("section", {})).items()]
    if fixed_at:
        title += f"\nsection at {', '.join(fixed_at)} ({len(polys)} regions meet it)"
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
        ax.set_title(f"{label}: 0 regions", fontsize="medium")
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
    umin, umax = _padded(float(np.min(u)), float(np.max(u)), 0.1) if u.size else (-1, 1)
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
    ax.set_title(f"{label}: {_regions_text(law, k)}", fontsize="medium")
    return ax


def _regions_text(law, k: int) -> str:
    """``"k regions"``, or for a law computed on demand ``"k regions reached"``: the regions
    its verification reached, not the whole law (issue 39)."""
    if getattr(law, "on_demand", False):
        return f"{k} regions reached (computed on demand, not the whole law)"
    return f"{k} regions"


def figure_law(
    law: ExplicitLaw, *, axes: tuple[int, int] = (0, 1), at: np.ndarray | None = None
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

    Returns
    -------
    matplotlib Figure
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.5), layout="constrained")
    plot_partition(law, fig.add_subplot(), axes=axes, at=at)
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
) -> Axes:
    """Draw one state's reachtube against time.

    Each box ``k`` of the tube is the band ``[t_start[k], t_end[k]] x [lower[k, state],
    upper[k, state]]``; the bands are merged where they overlap (:func:`merge_bands`) and
    drawn as one compound path. The counterexample trace, if any, is drawn over them, solid
    up to its violation (marked) and faint after it.

    Parameters
    ----------
    result : VerificationResult
    ax : matplotlib Axes, optional
    state : int
        Index of the state.
    problem : Problem, optional
        Adds the states' names, the time horizon and the verify sets on that state: unsafe
        sets that constrain this state alone as red bands (a set that also constrains other
        states is not a band in this picture; see :func:`plot_plane`), and the bounds that
        safe sets put on this state alone as green dashed lines; and, for a design that
        tracks the states (``[mpc.reference] signal = "x"``), the reference (purple: a
        line, or the box of an unknown constant reference).

    Returns
    -------
    matplotlib Axes
    """
    tube = result.tube
    n = tube.lower.shape[1]
    if not 0 <= state < n:
        raise ValueError(f"state must be in [0, {n}), got {state}")
    names = _state_names(n, problem.plant.states if problem is not None else None)
    row = np.eye(n)[state]
    label = problem.plant.state_label(state) if problem is not None else names[state]
    return _plot_signal(result, ax, row, tube.lower[:, state], tube.upper[:, state],
                        label, problem, state=state)


def plot_output(
    result: VerificationResult,
    problem: Problem,
    ax: Axes | None = None,
    *,
    output: int = 0,
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
    return _plot_signal(result, ax, C[output], ylo[:, 0], yhi[:, 0], f"{name} = C x",
                        problem, output=output)


def _plot_signal(
    result: VerificationResult,
    ax: Axes | None,
    row: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    ylabel: str,
    problem: Problem | None,
    *,
    state: int | None = None,
    output: int | None = None,
) -> Axes:
    """One signal ``row @ x`` against time: the tube's bands (``lower``, ``upper``, (K,)),
    the counterexample, and (with ``problem``) the sets on a state, the bounds on an output
    and the reference of the signal followed."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from codev_engine.reach.claim import certificate_band
    from codev_engine.view.signals import output_bounds, reference_band

    ax = _new_axes(ax, (6.0, 3.0))
    tube = result.tube
    cert = certificate_band(result)
    t_start, t_end = np.asarray(tube.t_start, float), np.asarray(tube.t_end, float)
    drawn_boxes = np.ones(t_start.shape[0], dtype=bool)
    if cert is not None:  # after the certificate the band, not the tube repeated
        drawn_boxes = t_start < cert.t_closed - 1e-9 * max(1.0, cert.t_closed)
    bands = merge_bands(t_start[drawn_boxes], t_end[drawn_boxes], lower[drawn_boxes],
                        upper[drawn_boxes])
    handles: list[Any] = []
    ylo, yhi, tmax = np.inf, -np.inf, 0.0
    if bands.shape[0]:
        ylo, yhi = float(bands[:, 2].min()), float(bands[:, 3].max())
        tmax = float(bands[:, 1].max())
        handles.append(Patch(facecolor=_TUBE_FACE, label=f"tube ({tube.num_boxes} boxes)"))
    cert_span = None
    if cert is not None:
        # the signal row @ x over the band's box (an interval per term)
        terms = np.stack([row * cert.lower, row * cert.upper])
        cert_span = (float(terms.min(axis=0).sum()), float(terms.max(axis=0).sum()))
        ylo, yhi = min(ylo, cert_span[0]), max(yhi, cert_span[1])
        tmax = max(tmax, float(t_end.max(initial=0.0)))
        handles.append(Patch(facecolor="none", edgecolor=_CERTIFICATE, hatch="///",
                             label=f"certificate band (every state, t >= {cert.t_closed:.3g})"))
    ce = result.counterexample
    if ce is not None:
        n = tube.lower.shape[1]
        (th, xh), (tt, xt), v = _split_trace(ce, list(range(n)))
        yh, yt, yv = xh @ row, xt @ row, float(v @ row)
        ax.plot(th, yh, color=_TRACE, lw=1.2)
        ax.plot(tt, yt, color=_TRACE, lw=1.0, alpha=0.35)
        ax.plot([ce.t], [yv], marker="X", color=_TRACE, ms=8, ls="none")
        handles.append(
            Line2D([], [], color=_TRACE, marker="X", label=f"counterexample ({ce.kind})")
        )
        ylo, yhi = min(ylo, float(yh.min())), max(yhi, float(yh.max()))
        tmax = max(tmax, float(tt[-1]))
    # what the design asks of this signal: drawn, and in view when near the tube
    lines: list[tuple[str, float]] = []
    band = None
    if problem is not None:
        if output is not None:
            lines = output_bounds(problem, output)
        ref = reference_band(problem)
        k = state if ref is not None and ref.signal == "x" else output
        if ref is not None and k is not None and (ref.signal == "x") == (state is not None):
            band = (float(ref.lower[k]), float(ref.upper[k]), ref.fixed)
        if problem.verify is not None:
            from codev_engine.reach.simulate import shown_horizon

            tmax = max(tmax, shown_horizon(problem))
    near = [v for _, v in lines] + ([band[0], band[1]] if band is not None else [])
    span = yhi - ylo if np.isfinite(yhi - ylo) else 0.0
    for v in near:
        if not np.isfinite(ylo) or abs(v - np.clip(v, ylo, yhi)) <= max(span, 1e-9):
            ylo, yhi = min(ylo, v), max(yhi, v)
    if state is not None and problem is not None and problem.verify is not None:
        # the properties on this state are always in view: a reader sees the margin
        for v in _property_edges(problem, state):
            ylo, yhi = min(ylo, v), max(yhi, v)
    ylim = _padded(ylo, yhi)
    if bands.shape[0]:
        # at least 1 % of the axis high, so a thin tube does not read as a line (the
        # picture only; edges in the face colour keep boxes narrower than a pixel visible)
        lo_b, hi_b = _min_size(
            bands[:, [0, 2]], bands[:, [1, 3]], np.array([0.0, 0.01 * (ylim[1] - ylim[0])])
        )
        _add_boxes(ax, lo_b, hi_b, fc=_TUBE_FACE, ec=_TUBE_FACE, lw=0.8)
    if cert_span is not None:
        t_band_end = tmax if tmax > cert.t_closed else cert.t_closed + 4 * (
            cert.t_closed - cert.t_anchor)
        ax.add_patch(_rectangle(cert.t_closed, cert_span[0], t_band_end - cert.t_closed,
                                cert_span[1] - cert_span[0]))
        tmax = max(tmax, t_band_end)
    ax.set_ylim(*ylim)
    ax.set_xlim(0.0, tmax if tmax > 0 else 1.0)
    if problem is not None and problem.verify is not None and state is not None:
        handles += _state_bounds(ax, problem, state, ylim)
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


def _bounds_on(s: SetSpec, state: int, *, alone: bool) -> tuple[float, float] | None:
    """Bounds ``(lo, hi)`` (+-inf allowed) that a verify set puts on one state.

    With ``alone`` only when the set constrains no other state (then ``x`` is in the set
    exactly when ``x[state]`` is within the bounds; None otherwise). Without: the bounds
    implied by the set's rows on this state only -- necessary conditions of membership.
    """
    A, b = s.halfspaces()
    on = np.all(np.delete(A, state, axis=1) == 0, axis=1)
    if alone and not np.all(on):
        return None
    a, c = A[on, state], b[on]
    lo = np.max(c[a < 0] / a[a < 0], initial=-np.inf)
    hi = np.min(c[a > 0] / a[a > 0], initial=np.inf)
    return float(lo), float(hi)


def _property_edges(problem: Problem, state: int) -> list[float]:
    """The finite edges the verify sets put on one state (unsafe sets on it alone, every
    safe set's bounds on it), which its time plot must show."""
    vs = problem.verify
    edges: list[float] = []
    for sets, alone in ((vs.unsafe, True), (vs.safe, False)):
        for s in sets:
            ext = _bounds_on(s, state, alone=alone)
            if ext is not None:
                edges += [float(v) for v in ext if np.isfinite(v)]
    return edges


def _state_bounds(ax: Axes, problem: Problem, state: int, ylim: tuple[float, float]) -> list:
    """Draw the verify sets' bounds on one state; returns legend handles."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    vs = problem.verify
    handles: list[Any] = []
    drawn_unsafe = drawn_safe = False
    for s in vs.unsafe:  # only sets on this state alone: others are not bands in time
        ext = _bounds_on(s, state, alone=True)
        if ext is None:
            continue
        lo, hi = max(ext[0], ylim[0]), min(ext[1], ylim[1])
        if lo < hi:
            ax.axhspan(lo, hi, color=_UNSAFE, alpha=0.2, lw=0)
            drawn_unsafe = True
    for s in vs.safe:  # every bound of a safe set must hold on its own
        ext = _bounds_on(s, state, alone=False)
        if ext is None:
            continue
        for y in ext:
            if ylim[0] <= y <= ylim[1]:
                ax.axhline(y, color=_SAFE, ls="--", lw=1)
                drawn_safe = True
    if drawn_unsafe:
        handles.append(Patch(facecolor=_UNSAFE, alpha=0.2, label="unsafe"))
    if drawn_safe:
        handles.append(Line2D([], [], color=_SAFE, ls="--", label="safe bound"))
    return handles


def plot_plane(
    result: VerificationResult,
    ax: Axes | None = None,
    *,
    axes: tuple[int, int] = (0, 1),
    problem: Problem | None = None,
    law: ExplicitLaw | None = None,
) -> Axes:
    """Draw the tube's boxes projected on a plane of two states.

    Parameters
    ----------
    result : VerificationResult
    ax : matplotlib Axes, optional
    axes : (2,) tuple of int
        The states on the horizontal and vertical axes.
    problem : Problem, optional
        Adds the initial set (black outline), the unsafe sets (red) and the safe sets (green
        outline), clipped to the view. Boxes are drawn as their projections; polytope sets
        whose rows only involve the two plotted states are drawn exactly, other polytope sets
        are listed as not drawn.
    law : ExplicitLaw, optional
        Adds the outline of the law's domain (for ``n > 2``, its section through the centre
        of the initial set, or :func:`default_slice_point` without a problem).

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
    lo2 = np.unique(np.hstack([tube.lower[:, [i, j]], tube.upper[:, [i, j]]]), axis=0)
    pts = [lo2[:, :2], lo2[:, 2:]]
    if lo2.shape[0]:
        handles.append(Patch(facecolor=_TUBE_FACE, label=f"tube ({tube.num_boxes} boxes)"))
    ce = result.counterexample
    if ce is not None:
        (_, head), (_, tail), v = _split_trace(ce, [i, j])
        ax.plot(head[:, 0], head[:, 1], color=_TRACE, lw=1.2)
        ax.plot(tail[:, 0], tail[:, 1], color=_TRACE, lw=1.0, alpha=0.35)
        ax.plot(v[:1], v[1:], marker="X", color=_TRACE, ms=8, ls="none")
        handles.append(
            Line2D([], [], color=_TRACE, marker="X", label=f"counterexample ({ce.kind})")
        )
        pts.append(head)
    vs = problem.verify if problem is not None else None
    if vs is not None:
        ilo, ihi = vs.initial_lower[[i, j]], vs.initial_upper[[i, j]]
        ax.add_patch(Rectangle(ilo, *(ihi - ilo), fill=False, ec=_INITIAL, lw=1.2, zorder=3))
        initial_box = np.array([ilo, [ihi[0], ilo[1]], ihi, [ilo[0], ihi[1]]])
        handles.append(Patch(fill=False, ec=_INITIAL, label="initial set"))
        pts += [ilo[None], ihi[None]]
    if vs is not None and vs.unsafe:
        # the obstacles near what is drawn are in the picture too, the one the
        # counterexample enters always (bounded ones: their bounds on the two states)
        base = np.vstack(pts)
        blo, bhi = np.nanmin(base, axis=0), np.nanmax(base, axis=0)
        reach = 0.5 * np.maximum(bhi - blo, 1e-9)
        for k, s in enumerate(vs.unsafe):
            bx, by = _bounds_on(s, i, alone=False), _bounds_on(s, j, alone=False)
            box = np.array([[bx[0], by[0]], [bx[1], by[1]]])
            # an unbounded side: a sliver past the finite one (the edge comes into view),
            # or what is drawn already when both sides are unbounded
            lo_inf, hi_inf = ~np.isfinite(box[0]), ~np.isfinite(box[1])
            both = lo_inf & hi_inf
            box[0] = np.where(both, blo, np.where(lo_inf, box[1] - 0.1 * reach, box[0]))
            box[1] = np.where(both, bhi, np.where(hi_inf, box[0] + 0.1 * reach, box[1]))
            hit = ce is not None and ce.kind == "unsafe" and ce.index == k
            near = np.all(box[0] <= bhi + reach) and np.all(box[1] >= blo - reach)
            if hit or near:
                pts.append(box)
    allpts = np.vstack(pts) if pts else np.zeros((0, 2))
    xlim = _padded(*_range(allpts[:, 0]))
    ylim = _padded(*_range(allpts[:, 1]))
    if lo2.shape[0]:
        # at least 0.6 % of the view wide and high, so a thin tube does not read as a line
        # (the picture only: the boxes are widened about their centres)
        span = np.array([xlim[1] - xlim[0], ylim[1] - ylim[0]])
        blo, bhi = _min_size(lo2[:, :2], lo2[:, 2:], 0.006 * span)
        _add_boxes(ax, blo, bhi, fc=_TUBE_FACE, ec=_TUBE_FACE, lw=0.5, zorder=2)
    # sets are clipped to a box a little larger than the view: no clipped edge shows
    margin = 0.1 * np.array([xlim[1] - xlim[0], ylim[1] - ylim[0]])
    view = (np.array([xlim[0], ylim[0]]) - margin, np.array([xlim[1], ylim[1]]) + margin)
    if vs is not None:
        skipped = 0
        for sets, style in ((vs.unsafe, "unsafe"), (vs.safe, "safe")):
            drawn = False
            for s in sets:
                poly = _set_in_view(s, i, j, view)
                if poly is None:
                    skipped += 1
                elif poly.shape[0] >= 3:
                    if style == "safe" and _fills_view(poly, view):
                        continue  # the safe set contains the whole view: nothing to see
                    if style == "unsafe":
                        ax.add_patch(Polygon(poly, fc=_UNSAFE, alpha=0.35, lw=0, zorder=0.5))
                        _mark_if_small(ax, poly, xlim, ylim, _UNSAFE)
                    else:
                        ax.add_patch(Polygon(poly, fill=False, ec=_SAFE, ls="--", lw=1))
                    drawn = True
            if drawn and style == "unsafe":
                handles.append(Patch(facecolor=_UNSAFE, alpha=0.35, label="unsafe"))
            elif drawn:
                handles.append(Line2D([], [], color=_SAFE, ls="--", label="safe"))
        if skipped:
            handles.append(Patch(fill=False, lw=0, label=f"({skipped} polytope set(s) not drawn)"))
    if law is not None:
        at = None
        if law.n > 2:
            at = default_slice_point(law, problem)  # the one section rule
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


def _range(v: np.ndarray) -> tuple[float, float]:
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max())) if v.size else (np.nan, np.nan)


def _set_in_view(
    s: SetSpec, i: int, j: int, view: tuple[np.ndarray, np.ndarray]
) -> np.ndarray | None:
    """A verify set's projection on states (i, j), clipped to the view box -> (v, 2).

    None when it cannot be drawn exactly (a polytope with rows on other states); an empty
    array when it misses the view.
    """
    from codev_engine.geometry.polytope import box_halfspaces

    if s.kind == "box":
        A, b = box_halfspaces(s.lower[[i, j]], s.upper[[i, j]])
    elif np.any(np.delete(s.A, [i, j], axis=1) != 0):
        return None
    else:
        A, b = s.A[:, [i, j]], s.b
    Av, bv = box_halfspaces(*view)
    polys, _ = section_polygons([np.vstack([A, Av])], [np.concatenate([b, bv])])
    return polys[0] if polys else np.zeros((0, 2))


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
    fig = Figure(figsize=(11.0 if plane else 6.5, 1.2 + 2.0 * rows), layout="constrained")
    grid = fig.add_gridspec(rows, 2 if plane else 1, width_ratios=[1.2, 1] if plane else None)
    for k in range(rows):
        ax = fig.add_subplot(grid[k, 0])
        if k < shown:
            plot_tube(result, ax, state=k, problem=problem)
        else:
            assert problem is not None
            plot_output(result, problem, ax, output=k - shown)
        if k < rows - 1:
            ax.set_xlabel("")
    if plane:
        drawn = None if law is None else law_section(law, problem)  # a theta law: its section
        plot_plane(result, fig.add_subplot(grid[:, 1]), problem=problem, law=drawn)
    name = f"{problem.name}: " if problem is not None else ""
    stats = f"{result.tube.num_boxes} boxes, {result.seconds:.3g} s, hold {result.hold}"
    fig.suptitle(
        f"{name}{_verdict_text(result)}   [{stats}]",
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
        ("regions", str(law.num_regions)),
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
