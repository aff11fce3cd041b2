"""The viewer layout (blueprint) a recording carries, so it opens on the story.

Left: the plane (``/plane``: partition, sets, tube, traces, counterexample; shown from the
view origin ``/`` so the plane's normalising transform applies), the state space
(``/space``, n == 3) and the verdict; right: one time-series view per state
(``/time/<state>``) and per output ``y = C x`` (``/output/<y>``), then ``u(t)`` per input
and the margin to the unsafe sets. The selection and blueprint panels start closed, the
time panel collapsed on the ``time`` timeline, following (the cursor at the end).
See ``docs/recordings.md``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from codev_engine.view.record_content import TIMELINE

if TYPE_CHECKING:
    from codev_engine.view.record_content import RecordingContent

__all__ = ["blueprint"]


def blueprint(entities: dict[str, int], content: RecordingContent):
    """The viewer layout of a recording; views without data are left out.

    Parameters
    ----------
    entities : dict of str to int
        The entities logged (``EntityWriter.entities``).
    content : RecordingContent

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun as rr
    import rerun.blueprint as rrb

    e = entities
    states = content.states
    up_to_cursor = rr.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.infinite(),
        end=rrb.TimeRangeBoundary.cursor_relative(seconds=0.0),
    )
    no_legend = rrb.PlotLegend(visible=False)
    # every time plot shows [0, T] with a margin each side: the first and the last time
    # label are not clipped at the view's edges
    T = content.scene.t_end
    time_axis = rrb.TimeAxis(view_range=rrb.TimeRange(
        start=rrb.TimeRangeBoundary.absolute(seconds=-0.04 * T),
        end=rrb.TimeRangeBoundary.absolute(seconds=1.06 * T)))
    left: list = []
    if any(k.startswith("/plane/") for k in e):
        xname, yname = content.plane_names
        # the scene's title: "section at ..." when it is one, "the regions reached" on demand
        title = content.scene.partition_title
        at = f", {title}" if content.law.num_regions else ""
        left.append(
            rrb.Spatial2DView(
                origin="/",
                contents=["/plane/**"],
                name=f"plane: {xname} → , {yname} ↑{at}  (orange tube, red unsafe, blue initial, "
                "grey traces" + (", purple certificate" if "/plane/certificate" in e else "")
                + (", magenta counterexample" if content.counterexample is not None else "")
                + ")",
                time_ranges=up_to_cursor,
                background=(255, 255, 255),
                # the window (a unit square, y down in the view) with its labels: the plane
                # fills its view instead of floating in the bounds of everything logged
                visual_bounds=rrb.VisualBounds2D(x_range=(-0.66, 0.56), y_range=(-0.58, 0.7)),
            )
        )
    if any(k.startswith("/space/") for k in e):
        left.append(
            rrb.Spatial3DView(origin="/space", name="state space", time_ranges=up_to_cursor)
        )
    left.append(rrb.TextDocumentView(origin="/verdict", name="verdict"))
    cex = ", counterexample magenta" if content.counterexample is not None else ""

    def reference(root: str) -> str:
        return ", reference purple" if any(k.startswith(f"{root}/reference/") for k in e) else ""

    def unit(label: str, name: str) -> str:
        return label[len(name):] if label != name else ""  # " (m/s)" or ""

    time_views = [
        rrb.TimeSeriesView(
            origin=f"/time/{s}",
            name=f"{s}(t){unit(content.problem.plant.state_label(k), s)}: tube orange, "
            "traces grey" + cex + reference(f"/time/{s}")
            + (", certificate band purple" if f"/time/{s}/certificate/lower" in e else "")
            + (", unsafe limits red" if any(k.startswith(f"/time/{s}/unsafe/") for k in e)
               else "")
            + (", safe limits green" if any(k.startswith(f"/time/{s}/safe/") for k in e)
               else ""),
            plot_legend=no_legend,
            # the scene's y range: the limits, the initial set, the tube, the certificate
            # band and the traces in view (the report's figure shows the same)
            axis_y=rrb.ScalarAxis(range=content.scene.plots[k].y_range),
            axis_x=time_axis,
        )
        for k, s in enumerate(states)
        if any(key.startswith(f"/time/{s}/") for key in e)
    ]
    # the outputs y = C x, after the states: their bounds black, the reference if followed
    time_views += [
        rrb.TimeSeriesView(
            origin=f"/output/{y}",
            name=f"{y}(t) = C x: tube orange, traces grey"
            + (", certificate band purple" if f"/output/{y}/certificate/lower" in e else "")
            + (", bounds black" if any(k.startswith(f"/output/{y}/bounds/") for k in e) else "")
            + cex + reference(f"/output/{y}"),
            plot_legend=no_legend,
            axis_y=(rrb.ScalarAxis(range=content.scene.outputs[k].y_range)
                    if k < len(content.scene.outputs) else None),
            axis_x=time_axis,
        )
        for k, y in enumerate(content.outputs)
        if any(k.startswith(f"/output/{y}/") for k in e)
    ]
    p_dist = content.problem.plant.disturbances
    series = [
        rrb.TimeSeriesView(
            origin=f"/scalars/u/{u}",
            name=f"{u}(t){unit(content.problem.plant.input_label(j), u)}, bounds black",
            plot_legend=no_legend,
            axis_x=time_axis,
        )
        for j, u in enumerate(content.inputs)
        if any(k.startswith(f"/scalars/u/{u}/") for k in e)
    ]
    for kind, names, what in (
        ("disturbance", () if p_dist is None else p_dist.names, "disturbance"),
        ("noise", content.states, "measurement noise"),
    ):
        for nm in names:
            if any(k.startswith(f"/scalars/{kind}/{nm}/") for k in e):
                series.append(rrb.TimeSeriesView(
                    origin=f"/scalars/{kind}/{nm}",
                    name=f"{what} {nm}: its interval black, the counterexample magenta",
                    plot_legend=no_legend,
                    axis_x=time_axis,
                ))
    if any(k.startswith("/scalars/unsafe_distance/") for k in e):
        series.append(
            rrb.TimeSeriesView(
                origin="/scalars/unsafe_distance",
                name="margin to the unsafe sets (< 0: inside)",
                plot_legend=no_legend,
                axis_x=time_axis,
            )
        )
    right: list = []
    if time_views:
        right.append(rrb.Vertical(*time_views) if len(time_views) <= 3 else rrb.Grid(*time_views))
    if series:
        right.append(rrb.Horizontal(*series))
    if len(left) == 3:
        # the verdict (the claim: initial set, sets checked) keeps a third of the column,
        # not two ninths: with the 3-D view it showed only the name and the verdict
        shares = [4, 2, 3]
    else:
        shares = [5, 3]
    layout_left = rrb.Vertical(*left, row_shares=shares)
    if right:
        # the time views three quarters: three stacked keep 190 px plots, room for the
        # viewer's y labels at eight steps of a power of ten (the scene's decade_range)
        right_col = rrb.Vertical(*right, row_shares=[3, 1] if len(right) == 2 else None)
        layout = rrb.Horizontal(layout_left, right_col, column_shares=[1, 1])
    else:
        layout = layout_left
    return rrb.Blueprint(
        layout,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed", play_state="following"),
        auto_views=False,
        auto_layout=False,
    )
