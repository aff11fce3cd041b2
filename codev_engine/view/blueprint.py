"""The viewer layout (blueprint) a recording carries, so it opens on the codev views.

Left: the plane (``/plane``), the state space (``/space``, n == 3) and the verdict; right:
one ``<state>(t)`` view per state, then the input and unsafe-margin time series; the time
panel expanded on the ``time`` timeline. See ``docs/recordings.md``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from codev_engine.view.record_content import TIMELINE

if TYPE_CHECKING:
    from codev_engine.view.record_content import RecordingContent

__all__ = ["blueprint"]


def blueprint(entities: dict[str, int], content: RecordingContent):
    """The viewer layout of a recording: plane (+ 3-D) views, state-vs-time views, series,
    verdict; views without data are left out.

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
    return rrb.Blueprint(*parts, auto_views=False, auto_layout=False)
