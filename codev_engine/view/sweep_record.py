"""The Rerun recording of a design sweep (``sweep.rrd`` in a sweep's folder).

Entities (the ``design`` timeline is the design's index in the table, 0-based)::

    /sweep/table                 static markdown: the whole table, one row per design
    /sweep/design                markdown per design (its values and outcomes), at its index
    /sweep/regions/<verdict>     the law's regions per design, one point series per verdict
                                 ("robustly_safe" green, "unsafe" red, "unknown" amber,
                                 "error" grey), so the plot shows regions and the verdict
                                 against the swept values
    /sweep/seconds/synthesis     wall times per design
    /sweep/seconds/verification

The blueprint puts the table on the left and the two plots on the right. Written
atomically with a private ``rerun.RecordingStream``, as :mod:`codev_engine.view.records`.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from codev_engine.errors import CodevError
from codev_engine.io.atomic import atomic_path, remove_stale_beside

__all__ = ["SWEEP_TIMELINE", "sweep_markdown", "write_sweep_recording"]

#: the timeline whose steps are the sweep's designs
SWEEP_TIMELINE = "design"
_ERROR_COLOUR = "#9e9e9e"


def _cell(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_cell(x) for x in v) + "]"
    return str(v)


def _rgb(hex_colour: str) -> tuple[int, int, int]:
    h = hex_colour.lstrip("#")
    return int(h[0:2], 16), int(h[2:4], 16), int(h[4:6], 16)


def _verdict(row: dict) -> str:
    if row.get("error"):
        return "error"
    return str(row.get("verdict") or "synthesised")


def sweep_markdown(rows: Sequence[dict], fields: Sequence[str], *, title: str = "sweep") -> str:
    """The sweep's table as a markdown document.

    Parameters
    ----------
    rows : sequence of dict
        ``ce.sweep``'s rows.
    fields : sequence of str
        The swept fields (the table's first columns).
    title : str
        The heading.

    Returns
    -------
    str
    """
    counts: dict[str, int] = {}
    for r in rows:
        counts[_verdict(r)] = counts.get(_verdict(r), 0) + 1
    head = ["#", *fields, "regions", "verdict", "reason", "synth s", "verify s",
            "width at T", "width of", "cost"]
    lines = [
        f"# {title}: {len(rows)} designs",
        "",
        ", ".join(f"**{k}**: {v}" for k, v in counts.items()),
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for i, r in enumerate(rows):
        cells = [str(i), *(_cell(r["values"].get(f)) for f in fields), _cell(r.get("regions")),
                 _verdict(r), (r.get("error") or r.get("reason") or "").replace("|", "/"),
                 _cell(r.get("synthesis_seconds")), _cell(r.get("verification_seconds")),
                 _cell(r.get("tube_width_at_horizon")), _cell(r.get("width_at_horizon_of")),
                 _cell(r.get("closed_loop_cost"))]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "The plots' horizontal axis is the design's row (#) on the *design* "
              "timeline; points are coloured by verdict (green robustly safe, red unsafe, "
              "amber unknown, grey error)."]
    return "\n".join(lines) + "\n"


def write_sweep_recording(
    path: str | os.PathLike, rows: Sequence[dict], fields: Sequence[str], *, title: str = "sweep"
) -> Path:
    """Write the sweep's Rerun recording.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.rrd`` file (replaced atomically).
    rows : sequence of dict
        ``ce.sweep``'s rows, in the table's order.
    fields : sequence of str
        The swept fields.
    title : str
        The recording's name and the table's heading.

    Returns
    -------
    Path

    Raises
    ------
    CodevError
        Rerun is disabled here (``RERUN=off``) or the file came out incomplete.
    """
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun.error_utils import catch_and_log_exceptions

    from codev_engine.view.figures import VERDICT_COLOURS
    from codev_engine.view.records import APPLICATION_ID, _has_footer

    path = Path(path)
    top = 1.1 * max((float(r["regions"]) for r in rows if r.get("regions")), default=1.0)
    colours = {**VERDICT_COLOURS, "error": _ERROR_COLOUR, "synthesised": "#1565c0"}
    remove_stale_beside(path)  # (what a recording killed while writing left)
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4().hex)
        if not rec.is_enabled():
            raise CodevError("rerun logging is disabled in this environment (RERUN=off); "
                             "unset RERUN to write recordings")
        try:
            rec.save(tmp)
            rec.send_recording_name(f"{title} (sweep)")
            with catch_and_log_exceptions(context="codev sweep recording", strict=True):
                rec.log("/sweep/table", rr.TextDocument(
                    sweep_markdown(rows, fields, title=title),
                    media_type=rr.MediaType.MARKDOWN), static=True)
                for v in dict.fromkeys(_verdict(r) for r in rows):
                    rec.log(f"/sweep/regions/{v}", rr.SeriesPoints(
                        colors=[_rgb(colours.get(v, _ERROR_COLOUR))], names=v, markers="circle",
                        marker_sizes=6.0), static=True)
                for name, colour in (("synthesis", "#1565c0"), ("verification", "#6a1b9a")):
                    rec.log(f"/sweep/seconds/{name}", rr.SeriesLines(
                        colors=[_rgb(colour)], names=f"{name} s"), static=True)
                for i, r in enumerate(rows):
                    rec.set_time(SWEEP_TIMELINE, sequence=i)
                    shown = ", ".join(f"{k} = {_cell(x)}" for k, x in r["values"].items())
                    rec.log("/sweep/design", rr.TextDocument(
                        f"## design {i}: {shown}\n\n" + "\n".join(
                            f"- **{k}**: {_cell(r.get(k))}" for k in (
                                "regions", "verdict", "reason", "error", "synthesis_seconds",
                                "verification_seconds", "tube_width_at_horizon",
                                "width_at_horizon_of", "closed_loop_cost")),
                        media_type=rr.MediaType.MARKDOWN))
                    if r.get("regions") is not None:
                        rec.log(f"/sweep/regions/{_verdict(r)}", rr.Scalars(float(r["regions"])))
                    for name in ("synthesis", "verification"):
                        s = r.get(f"{name}_seconds")
                        if s is not None:
                            rec.log(f"/sweep/seconds/{name}", rr.Scalars(float(s)))
                rec.send_blueprint(rrb.Blueprint(
                    rrb.Horizontal(
                        rrb.Vertical(
                            rrb.TextDocumentView(origin="/sweep/table", name="sweep table"),
                            rrb.TextDocumentView(origin="/sweep/design", name="design at cursor"),
                            row_shares=[3, 1]),
                        rrb.Vertical(
                            rrb.TimeSeriesView(origin="/sweep/regions",
                                               name="regions per design, by verdict",
                                               axis_y=rrb.ScalarAxis(range=(0.0, top))),
                            rrb.TimeSeriesView(origin="/sweep/seconds",
                                               name="synthesis and verification s"),
                        ),
                        column_shares=[3, 2],
                    ),
                    rrb.BlueprintPanel(state="collapsed"),
                    rrb.SelectionPanel(state="collapsed"),
                    rrb.TimePanel(timeline=SWEEP_TIMELINE, state="collapsed"),
                    auto_views=False, auto_layout=False,
                ))
            rec.flush()
        finally:
            rec.disconnect()
        if not _has_footer(tmp):
            raise CodevError(f"rerun wrote an incomplete recording for {path}")
    return path
