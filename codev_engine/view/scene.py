"""What a picture of a design shows, computed once: the scene.

Every picture of a design -- the Rerun recording (:mod:`codev_engine.view.record_content`),
the matplotlib figures of notebooks, HTML reports and the workbench
(:mod:`codev_engine.view.figures`) -- renders one :class:`Scene`, so they show the same
numbers: the section of the partition (:func:`default_slice_point`, the one section rule),
the plane's window and ticks, the time axis, each state's time plot (its y range and ticks,
the unsafe/safe limits the verify sets put on it, the initial interval at ``t = 0``, the
tube's boxes before an all-time certificate closes and the certificate band after it), and
the titles. Plain data: frozen dataclasses and numpy arrays, no matplotlib, no rerun.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover - typing only
    from codev_engine.law import ExplicitLaw
    from codev_engine.reach.claim import CertificateBand
    from codev_engine.reach.verification import VerificationResult
    from codev_engine.spec.problem import Problem, SetSpec

__all__ = [
    "Limit",
    "OutputPlot",
    "Scene",
    "Section",
    "SetShape",
    "StatePlot",
    "bounds_on",
    "build_scene",
    "decade_range",
    "default_slice_point",
    "law_section",
    "nice_ticks",
    "padded",
    "regions_words",
    "set_rows",
    "verified_parameters",
]


# --------------------------------------------------------------------------------------------
# the section rule
# --------------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------------
# small numeric helpers shared by the renderers
# --------------------------------------------------------------------------------------------


def padded(lo: float, hi: float, frac: float = 0.15) -> tuple[float, float]:
    """An interval around ``[lo, hi]`` with a margin (a unit margin when it is a point).

    Parameters
    ----------
    lo, hi : float
    frac : float
        The margin on each side, as a fraction of ``hi - lo``.

    Returns
    -------
    (float, float)
        ``(-1, 1)`` when a side is not finite.
    """
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return -1.0, 1.0
    pad = frac * (hi - lo) if hi > lo else max(1.0, abs(lo)) * 0.1
    return lo - pad, hi + pad


def nice_ticks(lo: float, hi: float, k: int = 5) -> np.ndarray:
    """About ``k`` round values in ``[lo, hi]`` (steps 1, 2, 2.5, 5 times a power of ten).

    Parameters
    ----------
    lo, hi : float
    k : int

    Returns
    -------
    (t,) ndarray
        At least three values for a finite ``lo < hi`` and ``k >= 4``.
    """
    span = hi - lo
    if not (np.isfinite(span) and span > 0):
        return np.array([lo])
    raw = span / k
    mag = 10.0 ** np.floor(np.log10(raw))
    step = mag * min((s for s in (1.0, 2.0, 2.5, 5.0, 10.0) if s * mag >= raw), default=10.0)
    first = np.ceil(lo / step) * step
    ticks = np.arange(first, hi + 1e-9 * step, step)
    return np.where(np.abs(ticks) < 1e-9 * step, 0.0, ticks)


#: at most this many steps of the labelled power of ten in a :func:`decade_range`
MAX_STEPS = 8


def decade_range(lo: float, hi: float) -> tuple[float, float]:
    """A plot's range around ``[lo, hi]`` that holds at least three and at most
    ``MAX_STEPS + 1`` multiples of a power of ten, plus a 4 % margin.

    A viewer that labels its grid at powers of ten, a step only when it is at least 20 px
    high (the Rerun viewer's time plots, 190 px high when three are stacked), then shows
    at least three y tick labels, none at the very edge.

    Parameters
    ----------
    lo, hi : float

    Returns
    -------
    (float, float)
        ``(-1, 1)`` when a side is not finite.
    """
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return -1.0, 1.0
    if hi <= lo:
        lo, hi = padded(lo, hi)
    step = 10.0 ** np.floor(np.log10(hi - lo))
    a, b = np.floor(lo / step) * step, np.ceil(hi / step) * step
    if round((b - a) / step) > MAX_STEPS:
        # the viewer labels a step only when it is >= 20 px high: ten steps in a 190 px
        # plot (three time views stacked) would show the single label "0"; the next power
        # of ten labels the plot
        step *= 10.0
        a, b = np.floor(lo / step) * step, np.ceil(hi / step) * step
    if round((b - a) / step) < 2:  # two steps: three labelled values
        a, b = (a - step, b) if lo - a < b - hi else (a, b + step)
    margin = 0.04 * (b - a)
    return float(a - margin), float(b + margin)


def bounds_on(s: SetSpec, state: int, *, alone: bool) -> tuple[float, float] | None:
    """Bounds ``(lo, hi)`` (+-inf allowed) that a verify set puts on one state.

    Parameters
    ----------
    s : SetSpec
    state : int
    alone : bool
        Only when the set constrains no other state (then ``x`` is in the set exactly when
        ``x[state]`` is within the bounds; None otherwise). Without: the bounds implied by
        the set's rows on this state only -- necessary conditions of membership.

    Returns
    -------
    (float, float) or None
    """
    A, b = s.halfspaces()
    on = np.all(np.delete(A, state, axis=1) == 0, axis=1)
    if alone and not np.all(on):
        return None
    a, c = A[on, state], b[on]
    lo = np.max(c[a < 0] / a[a < 0], initial=-np.inf)
    hi = np.min(c[a > 0] / a[a > 0], initial=np.inf)
    return float(lo), float(hi)


# --------------------------------------------------------------------------------------------
# the scene
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Section:
    """The 2-D section a partition view shows.

    Attributes
    ----------
    point : (n,) ndarray
        The law's parameters at which the other coordinates are fixed (n the drawn law's).
    fixed : tuple of (str, float)
        Every value the picture fixes: the states off the plane, a theta law's ``u_prev``
        and ``r`` (in that order).
    """

    point: np.ndarray
    fixed: tuple[tuple[str, float], ...]

    @property
    def words(self) -> str:
        """``x3 = 0.025, prev_V = 0`` (three significant digits, as every title)."""
        return ", ".join(f"{k} = {v:.3g}" for k, v in self.fixed)


@dataclass(frozen=True)
class Limit:
    """A value a verify set puts on one state: a line in the state's time plot.

    Attributes
    ----------
    kind : str
        ``"unsafe"`` (a set on this state alone: ``x`` beyond it is unsafe) or ``"safe"``.
    index : int
        The set's index in ``[[verify.unsafe]]`` / ``[[verify.safe]]``.
    side : str
        ``"lower"`` or ``"upper"``.
    value : float
    """

    kind: str
    index: int
    side: str
    value: float


@dataclass(frozen=True)
class StatePlot:
    """One state against time.

    Attributes
    ----------
    name : str
    label : str
        The name with its unit (``v (m/s)``).
    y_range : (float, float)
        :func:`decade_range` of the values shown: the tube shown, the certificate band,
        the traces, the counterexample up to its violation, every limit, the initial
        interval.
    y_ticks : (k,) ndarray
        At least three round values inside ``y_range``.
    limits : tuple of Limit
        Finite edges only.
    unsafe_bands : tuple of (int, float, float)
        ``(index, lo, hi)`` of each unsafe set on this state alone (sides may be infinite).
    initial : (float, float) or None
        The initial set's interval, drawn at ``t = 0`` only.
    """

    name: str
    label: str
    y_range: tuple[float, float]
    y_ticks: np.ndarray
    limits: tuple[Limit, ...]
    unsafe_bands: tuple[tuple[int, float, float], ...]
    initial: tuple[float, float] | None


@dataclass(frozen=True)
class SetShape:
    """A set of ``[verify]`` (or the certificate's invariant set) as drawn.

    Attributes
    ----------
    name : str
        ``initial``, ``unsafe/<k>``, ``safe/<k>`` or ``certificate``.
    spec : SetSpec
        The set.
    vertices : (v, n) ndarray or None
        Its vertices clipped to the view box (None: empty there, or not enumerable).
    polygon : (p, 2) ndarray or None
        Its projection on the plane, counter-clockwise (n == 1: the interval as a band over
        the time window; the initial set a thin bar at t = 0); None: flat or empty.
    A, b : (r, n) and (r,) ndarray
        Its unit rows with the view box's, which the vertices came from.
    """

    name: str
    spec: SetSpec
    vertices: np.ndarray | None
    polygon: np.ndarray | None
    A: np.ndarray
    b: np.ndarray


@dataclass(frozen=True)
class OutputPlot:
    """One output ``y = C x`` against time.

    Attributes
    ----------
    name : str
        ``y<i>``.
    y_range : (float, float)
        :func:`decade_range` of the tube's outputs shown (``C`` applied interval-wise),
        the certificate band's, the traces', the counterexample's up to its violation, the
        reference followed, and the MPC's bounds on it that are near those.
    y_ticks : (k,) ndarray
    """

    name: str
    y_range: tuple[float, float]
    y_ticks: np.ndarray


@dataclass(frozen=True)
class Scene:
    """What every picture of one design shows (see the module's docstring).

    Attributes
    ----------
    name : str
        The design's name.
    states : tuple of str
    axes : (int, int) or None
        The plane's state indices (None when n == 1: the plane is (time, state)).
    section : Section or None
        None when the partition drawn is not a section (n <= 2 over the states).
    partition_title : str
        :func:`regions_words`.
    view_lo, view_hi : (n,) ndarray
        The view box in the states (infinite sets are clipped to it).
    plane_lo, plane_hi : (2,) ndarray
        The plane's window (horizontal, vertical).
    plane_x_ticks, plane_y_ticks : ndarray
        Round values inside the window.
    t_end : float
        The time axis' end (``[0, t_end]``): the horizon, the shown horizon for ``"inf"``.
    plots : tuple of StatePlot
        One per state.
    outputs : tuple of OutputPlot
        One per row of ``mpc.C`` (none without outputs).
    sets : tuple of SetShape
        The initial set, the unsafe sets, the safe sets, the certificate's invariant set,
        clipped to the view box (none without ``[verify]``).
    certificate : CertificateBand or None
        The band after an all-time certificate closed (drawn from ``t_closed`` to
        ``band_end``); the tube's boxes from ``t_closed`` on are not drawn.
    band_end : float
    tube_shown : (K,) bool ndarray
        The tube's boxes drawn against time (all but those after the certificate closed).
    region_polygons : tuple of (v, 2) ndarray
        The regions in the plane clipped to the window (n > 2: their sections; n == 1:
        each interval as a band over the time window).
    region_index : (p,) int ndarray
        The region of each polygon.
    """

    name: str
    states: tuple[str, ...]
    axes: tuple[int, int] | None
    section: Section | None
    partition_title: str
    view_lo: np.ndarray
    view_hi: np.ndarray
    plane_lo: np.ndarray
    plane_hi: np.ndarray
    plane_x_ticks: np.ndarray
    plane_y_ticks: np.ndarray
    t_end: float
    plots: tuple[StatePlot, ...]
    outputs: tuple[OutputPlot, ...]
    sets: tuple[SetShape, ...]
    certificate: CertificateBand | None
    band_end: float
    tube_shown: np.ndarray
    region_polygons: tuple[np.ndarray, ...]
    region_index: np.ndarray

    @property
    def plane_names(self) -> tuple[str, str]:
        """The plane's horizontal and vertical quantities (``time`` and the state for n == 1)."""
        if self.axes is None:
            return "time", self.states[0]
        return self.states[self.axes[0]], self.states[self.axes[1]]


def _section(law: ExplicitLaw, problem: Problem | None, axes: tuple[int, int] | None,
             at: np.ndarray | None = None) -> Section | None:
    """The section a partition of ``law`` (in the states: a theta law's section already)
    shows in the plane ``axes``, through ``at`` (default :func:`default_slice_point`)."""
    fixed: list[tuple[str, float]] = []
    point = np.zeros(law.n)
    if law.n > 2 and axes is not None:
        point = (default_slice_point(law, problem) if at is None
                 else np.asarray(at, dtype=float).reshape(law.n))
        names = law.parameter_names if law.parameter_names else law.states
        names = names if len(names) == law.n else tuple(f"x[{k}]" for k in range(law.n))
        fixed += [(names[k], float(point[k])) for k in range(law.n) if k not in axes]
    fixed += [(k, float(v)) for k, v in dict(law.meta.get("section", {})).items()]
    return Section(point, tuple(fixed)) if fixed else None


def regions_words(law: ExplicitLaw, section: Section | None, meet: int) -> str:
    """A partition view's title: ``"101 regions"``, ``"section at v1 = 0.025: 101 regions
    (37 meet it)"``; for a law computed on demand ``"the regions reached (computed on
    demand): 12"``, not the whole law (issue 39).

    Parameters
    ----------
    law : ExplicitLaw
    section : Section or None
    meet : int
        The regions drawn (meeting the section).

    Returns
    -------
    str
    """
    k = law.num_regions
    if getattr(law, "on_demand", False):
        text = f"the regions reached (computed on demand): {k}"  # (short: a title)
    else:
        text = f"{k} regions"
    if section is not None:
        text = f"section at {section.words}: {text} ({meet} meet it)"
    return text


def build_scene(
    problem: Problem | None,
    law: ExplicitLaw | None,
    result: VerificationResult | None = None,
    *,
    axes: tuple[int, int] | None = (0, 1),
    traces: np.ndarray | None = None,
    at: np.ndarray | None = None,
) -> Scene:
    """The scene of a design: computed once, rendered by the recording and the figures.

    Parameters
    ----------
    problem : Problem or None
        Without it (a bare law in a notebook): no sets, no time plots' limits.
    law : ExplicitLaw or None
        The law drawn, in the states (a theta law's section: :func:`law_section`); None for
        a result drawn without its law (no partition, no section).
    result : VerificationResult, optional
    axes : (int, int) or None
        The plane's state indices, checked by the caller (None when n == 1).
    traces : (P, K, n) ndarray, optional
        Simulated closed-loop states (NaN where a trace stopped): part of the windows.
    at : (n,) ndarray, optional
        The section's point for a law of ``n > 2`` (default :func:`default_slice_point`).

    Returns
    -------
    Scene
    """
    from codev_engine.reach.claim import certificate_band

    if problem is not None:
        n, states = problem.plant.n, problem.plant.states
    else:
        n = law.n if law is not None else result.tube.lower.shape[1]
        named = law.states if law is not None else ()
        states = named if len(named) == n else tuple(f"x[{k}]" for k in range(n))
    vs = problem.verify if problem is not None else None
    tube = result.tube if result is not None else None

    # the time axis and what of the tube is drawn against it
    if vs is not None:
        from codev_engine.reach.simulate import shown_horizon

        t_end = shown_horizon(problem)  # finite, also for time_horizon = "inf"
    elif problem is not None:
        t_end = 10.0 * float(problem.model.sample_time)
    else:
        t_end = 1.0
    cert = certificate_band(result) if result is not None else None
    K = 0 if tube is None else int(tube.num_boxes)
    shown = np.ones(K, dtype=bool)
    band_end = t_end
    if cert is not None:  # after the certificate the band, not the tube repeated
        shown = np.asarray(tube.t_start, float) < cert.t_closed - 1e-9 * max(1.0, cert.t_closed)
        band_end = t_end if t_end > cert.t_closed else cert.t_closed + 4 * (
            cert.t_closed - cert.t_anchor)
        t_end = max(t_end, band_end)

    # the counterexample up to its violation
    cex_x = None
    ce = None if result is None else result.counterexample
    if ce is not None:
        ct = np.asarray(ce.trace.t, dtype=float)
        cx = np.asarray(ce.trace.x, dtype=float)
        v = np.array([np.interp(ce.t, ct, cx[:, k]) for k in range(cx.shape[1])])
        cex_x = np.vstack([cx[ct < ce.t], v])

    # the view box in the states: the law's domain box, widened to what else is shown
    if law is not None and law.num_regions:
        blo, bhi = law.boxes
        lo, hi = blo.min(axis=0).astype(float), bhi.max(axis=0).astype(float)
    elif problem is not None:
        mpc = problem.mpc
        x_op = np.asarray(problem.model.x_op, dtype=float)
        x_op = x_op if x_op.shape == (n,) else np.zeros(n)
        D = float(mpc.domain_bound)
        lo = np.where(np.isfinite(mpc.x_min), mpc.x_min, x_op - D).astype(float)
        hi = np.where(np.isfinite(mpc.x_max), mpc.x_max, x_op + D).astype(float)
    else:
        lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    extra: list[np.ndarray] = []
    if vs is not None:
        extra += [vs.initial_lower, vs.initial_upper]
    if tube is not None and K:
        extra += [tube.lower.min(axis=0), tube.upper.max(axis=0)]
    finite_traces = None
    if traces is not None and traces.size:
        with np.errstate(all="ignore"):
            finite_traces = np.where(np.isfinite(traces), traces, np.nan).reshape(-1, n)
        if np.any(np.isfinite(finite_traces)):
            extra += [np.nanmin(finite_traces, axis=0), np.nanmax(finite_traces, axis=0)]
    if cex_x is not None and np.all(np.isfinite(cex_x)):
        extra += [cex_x.min(axis=0), cex_x.max(axis=0)]
    for e in extra:
        e = np.asarray(e, dtype=float)
        ok = np.isfinite(e)
        lo[ok] = np.minimum(lo[ok], e[ok])
        hi[ok] = np.maximum(hi[ok], e[ok])
    lo, hi = np.where(lo <= hi, lo, -1.0), np.where(lo <= hi, hi, 1.0)  # nothing: [-1, 1]
    pad = 0.05 * np.maximum(hi - lo, 1e-9) + 1e-9
    view_lo, view_hi = lo - pad, hi + pad
    if axes is None:
        plane_lo = np.array([0.0, view_lo[0]])
        plane_hi = np.array([t_end, view_hi[0]])
    else:
        plane_lo, plane_hi = view_lo[list(axes)].copy(), view_hi[list(axes)].copy()

    plots = tuple(_state_plot(problem, k, states[k], result, shown, cert, finite_traces, cex_x)
                  for k in range(n))
    outputs = _output_plots(problem, result, shown, cert, finite_traces, cex_x)
    section = None if law is None else _section(law, problem, axes, at)
    polys, index = _regions(law, axes, section, plane_lo, plane_hi)
    name = problem.name if problem is not None else (
        str(law.meta.get("problem", "")) if law is not None else "")
    return Scene(
        name=name,
        states=tuple(states),
        axes=axes,
        section=section,
        partition_title="" if law is None else regions_words(law, section, len(polys)),
        view_lo=view_lo,
        view_hi=view_hi,
        plane_lo=plane_lo,
        plane_hi=plane_hi,
        plane_x_ticks=nice_ticks(plane_lo[0], plane_hi[0]),
        plane_y_ticks=nice_ticks(plane_lo[1], plane_hi[1]),
        t_end=float(t_end),
        plots=plots,
        outputs=outputs,
        sets=_set_shapes(problem, result, view_lo, view_hi, axes, plane_lo, plane_hi),
        certificate=cert,
        band_end=float(band_end),
        tube_shown=shown,
        region_polygons=tuple(polys),
        region_index=index,
    )


def _regions(law: ExplicitLaw | None, axes: tuple[int, int] | None, section: Section | None,
             lo: np.ndarray, hi: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """The regions in the plane window ``[lo, hi]`` -> (polygons, region index)."""
    if law is None or law.num_regions == 0:
        return [], np.zeros(0, dtype=int)
    if axes is None:  # one state: each interval as a band over the time window
        k = law.num_regions
        rows = np.concatenate([a[:, 0] for a in law.A])
        rhs = np.concatenate(law.b)
        region = np.repeat(np.arange(k), [a.shape[0] for a in law.A])
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = rhs / rows
        a = np.full(k, -np.inf)
        b = np.full(k, np.inf)
        np.maximum.at(a, region[rows < 0], bound[rows < 0])
        np.minimum.at(b, region[rows > 0], bound[rows > 0])
        a, b = np.maximum(a, lo[1]), np.minimum(b, hi[1])
        keep = np.flatnonzero(a < b)
        polys = [np.array([[lo[0], a[r]], [hi[0], a[r]], [hi[0], b[r]], [lo[0], b[r]]])
                 for r in keep]
        return polys, keep
    from codev_engine.view.shapes import section_polygons

    i, j = axes
    box = np.zeros((4, law.n))
    box[[0, 2], i] = 1.0, -1.0
    box[[1, 3], j] = 1.0, -1.0
    rhs = np.array([hi[0], hi[1], -lo[0], -lo[1]])
    A = [np.vstack([a, box]) for a in law.A]
    b = [np.concatenate([bb, rhs]) for bb in law.b]
    at = section.point if section is not None and law.n > 2 else None
    return section_polygons(A, b, axes=(i, j), at=at)


def _state_plot(
    problem: Problem | None,
    i: int,
    name: str,
    result: VerificationResult | None,
    shown: np.ndarray,
    cert: CertificateBand | None,
    traces: np.ndarray | None,
    cex_x: np.ndarray | None,
) -> StatePlot:
    """State ``i``'s time plot: its limits, initial interval, y range and ticks."""
    vs = problem.verify if problem is not None else None
    values: list[float] = []
    limits: list[Limit] = []
    bands: list[tuple[int, float, float]] = []
    initial = None
    if vs is not None:
        for kind, sets, alone in (("unsafe", vs.unsafe, True), ("safe", vs.safe, False)):
            for k, s in enumerate(sets):
                ext = bounds_on(s, i, alone=alone)
                if ext is None:
                    continue
                if kind == "unsafe":
                    bands.append((k, ext[0], ext[1]))
                for side, v in zip(("lower", "upper"), ext, strict=True):
                    if np.isfinite(v):
                        limits.append(Limit(kind, k, side, float(v)))
        initial = (float(vs.initial_lower[i]), float(vs.initial_upper[i]))
        values += list(initial)
    values += [lim.value for lim in limits]
    if result is not None and result.tube.num_boxes and np.any(shown):
        values += [float(result.tube.lower[shown, i].min()),
                   float(result.tube.upper[shown, i].max())]
    if cert is not None:
        values += [float(cert.lower[i]), float(cert.upper[i])]
    if traces is not None:
        col = traces[:, i]
        if np.any(np.isfinite(col)):
            values += [float(np.nanmin(col)), float(np.nanmax(col))]
    if cex_x is not None:
        values += [float(cex_x[:, i].min()), float(cex_x[:, i].max())]
    if problem is not None:
        from codev_engine.view.signals import reference_band

        ref = reference_band(problem)
        if ref is not None and ref.signal == "x":
            values += [float(ref.lower[i]), float(ref.upper[i])]
    vals = np.array([v for v in values if np.isfinite(v)], dtype=float)
    ylo, yhi = (float(vals.min()), float(vals.max())) if vals.size else (np.nan, np.nan)
    y_range = decade_range(ylo, yhi)
    ticks = nice_ticks(*y_range, k=5)
    label = problem.plant.state_label(i) if problem is not None else name
    return StatePlot(name, label, y_range, ticks, tuple(limits), tuple(bands), initial)


def _output_plots(
    problem: Problem | None,
    result: VerificationResult | None,
    shown: np.ndarray,
    cert: CertificateBand | None,
    traces: np.ndarray | None,
    cex_x: np.ndarray | None,
) -> tuple[OutputPlot, ...]:
    """The outputs' time plots: their y ranges and ticks (none without ``mpc.C``)."""
    if problem is None or problem.mpc.C is None:
        return ()
    from codev_engine.view.signals import (
        output_bounds,
        output_boxes,
        output_names,
        reference_band,
    )

    C = np.asarray(problem.mpc.C, dtype=float)
    if C.shape[1] != problem.plant.n:
        return ()
    ref = reference_band(problem)
    out = []
    for k, name in enumerate(output_names(problem)):
        row = C[k : k + 1]
        values: list[float] = []
        if result is not None and result.tube.num_boxes and np.any(shown):
            ylo, yhi = output_boxes(row, result.tube.lower[shown], result.tube.upper[shown])
            values += [float(ylo.min()), float(yhi.max())]
        if cert is not None:
            ylo, yhi = output_boxes(row, cert.lower[None], cert.upper[None])
            values += [float(ylo[0, 0]), float(yhi[0, 0])]
        if traces is not None:
            y = traces @ row[0]
            if np.any(np.isfinite(y)):
                values += [float(np.nanmin(y)), float(np.nanmax(y))]
        if cex_x is not None:
            y = cex_x @ row[0]
            values += [float(y.min()), float(y.max())]
        if ref is not None and ref.signal == "y":
            values += [float(ref.lower[k]), float(ref.upper[k])]
        vals = np.array([v for v in values if np.isfinite(v)], dtype=float)
        lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (np.nan, np.nan)
        span = hi - lo if np.isfinite(hi - lo) else 0.0
        for _, v in output_bounds(problem, k):  # a bound near what is drawn is in view
            if not np.isfinite(lo) or abs(v - np.clip(v, lo, hi)) <= max(span, 1e-9):
                lo, hi = min(lo, v), max(hi, v)
        y_range = decade_range(lo, hi)
        out.append(OutputPlot(name, y_range, nice_ticks(*y_range)))
    return tuple(out)


#: feasibility tolerance of the drawn sets' vertices, ``_TOL * (1 + |b|)``
_TOL = 1e-9
#: a set with more d-subsets of rows than this is not enumerated (no LP fallback here)
_MAX_COMBOS = 50_000


def set_rows(s: SetSpec) -> tuple[np.ndarray, np.ndarray]:
    """Unit-norm H-representation of a set (infinite box sides dropped).

    Parameters
    ----------
    s : SetSpec

    Returns
    -------
    A : (r, n) ndarray
    b : (r,) ndarray
        An empty set keeps an impossible pair of rows.
    """
    from codev_engine.geometry.polytope import normalize_rows

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


def _set_shapes(
    problem: Problem | None,
    result: VerificationResult | None,
    lo: np.ndarray,
    hi: np.ndarray,
    axes: tuple[int, int] | None,
    plo: np.ndarray,
    phi: np.ndarray,
) -> tuple[SetShape, ...]:
    """The verify sets (and a certificate's invariant set) clipped to the view box
    ``[lo, hi]`` and projected on the plane (window ``[plo, phi]``)."""
    vs = problem.verify if problem is not None else None
    if vs is None:
        return ()
    from codev_engine.geometry.vertices import vertices_many
    from codev_engine.spec.problem import SetSpec
    from codev_engine.view.shapes import outline

    n = problem.plant.n
    sets = [("initial", SetSpec("box", lower=vs.initial_lower, upper=vs.initial_upper))]
    sets += [(f"unsafe/{k}", s) for k, s in enumerate(vs.unsafe)]
    sets += [(f"safe/{k}", s) for k, s in enumerate(vs.safe)]
    cert = None if result is None else result.certificate
    if cert is not None and "H" in cert and np.shape(cert["H"])[1] == n:
        # the invariant set that closes the induction (time_horizon = "inf")
        sets.append(("certificate", SetSpec("polytope", A=np.asarray(cert["H"], float),
                                            b=np.asarray(cert["h"], float))))
    rows = [set_rows(s) for _, s in sets]
    eye = np.vstack([np.eye(n), -np.eye(n)])
    As = [np.vstack([A, eye]) for A, _ in rows]
    bs = [np.concatenate([b, hi, -lo]) for _, b in rows]
    V = vertices_many(As, bs, _TOL, rtol=_TOL, max_combos=_MAX_COMBOS)
    out = []
    for (name, spec), v, A, b in zip(sets, V, As, bs, strict=True):
        poly = None
        if v is None or v.shape[0] == 0:
            v = None
        elif axes is None:
            a, c = float(v.min()), float(v.max())
            # the initial set holds at t = 0 only: a thin bar there, not a band in time
            t0 = min(plo[0], 0.0)
            t1 = 0.01 * (phi[0] - plo[0]) if name == "initial" else phi[0]
            poly = np.array([[t0, a], [t1, a], [t1, c], [t0, c]]) if c > a else None
        else:
            ring = outline(v, axes)
            poly = None if ring is None else ring[:-1]
        out.append(SetShape(name, spec, v, poly, A, b))
    return tuple(out)
