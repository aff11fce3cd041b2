"""A design as one self-contained HTML file, for reviewers who do not run the Rerun viewer.

:func:`report_html` writes the verdict panel (the recording's verdict document,
:meth:`~codev_engine.view.record_content.RecordingContent.verdict_text`, turned into HTML),
then the notebook figures (:mod:`codev_engine.view.figures`: one drawing code path) as inline
SVG: the tube of each state against time and in the plane, the partition, the inputs of the
simulated traces against their bounds; then the spec's TOML. Nothing is fetched: no script,
no style sheet, no font, no image from elsewhere; any browser shows it offline.
"""

from __future__ import annotations

import html
import io
import os
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.io.atomic import remove_stale_beside, write_text
from codev_engine.law import ExplicitLaw
from codev_engine.spec.problem import Problem
from codev_engine.view import figures

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from codev_engine.reach.verification import VerificationResult
    from codev_engine.view.record_content import RecordingContent, Traces

__all__ = ["figure_inputs", "markdown_html", "report_figures", "report_html", "write_report"]

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Helvetica, Arial, sans-serif;
       margin: 1.5em auto; max-width: 1100px; color: #222; padding: 0 1em; }
.banner { color: white; padding: 0.5em 1em; border-radius: 4px; font-size: 1.4em;
          font-weight: bold; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { text-align: left; padding: 2px 12px 2px 0; border-bottom: 1px solid #ddd; }
code, pre { font-family: ui-monospace, Menlo, Consolas, monospace; background: #f4f4f4; }
pre { padding: 0.8em; overflow-x: auto; }
figure { margin: 1.5em 0; }
figure svg { max-width: 100%; height: auto; }
figcaption { color: #555; font-size: 0.9em; }
"""


def report_html(
    problem: Problem,
    law: ExplicitLaw,
    result: VerificationResult | None = None,
    *,
    traces: int = 16,
    axes: tuple[int, int] = (0, 1),
) -> str:
    """The HTML report of a design (and of its verification).

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
    result : VerificationResult, optional
        Without it: the partition and the spec only.
    traces : int
        Closed-loop traces simulated for the inputs' figure (0: none).
    axes : (int, int)
        The plane's state indices (as in recordings).

    Returns
    -------
    str
        One HTML document: figures as inline SVG, no external reference.
    """
    content, figs = report_figures(problem, law, result, traces=traces, axes=axes)
    parts = [(_svg(fig), caption) for fig, caption in figs]
    section = content.section_words()
    law_figure = 2 if result is not None else 1  # the partition's (report_figures' order)
    colour = figures.VERDICT_COLOURS.get(result.verdict if result else "", "#555555")
    word = result.verdict.replace("_", " ") if result else "not verified"
    body = [
        f"<div class='banner' style='background:{colour}'>{html.escape(problem.name)}: "
        f"{html.escape(word)}</div>",
        markdown_html(content.verdict_text(views=False)),
    ]
    if section is not None:
        # on the first screen, as the recording's plane title says it (the partition's
        # figure is below the fold)
        body.insert(1, f"<p class='section'>The partition (Figure {law_figure}) is the "
                    f"section at {html.escape(section)}.</p>")
    for k, (svg, caption) in enumerate(parts):
        body.append(
            f"<figure id='figure-{k}'>{svg}<figcaption>Figure {k + 1}. "
            f"{html.escape(caption)}</figcaption></figure>"
        )
    if problem.source:
        body.append("<h3>the spec</h3><pre>" + html.escape(problem.source) + "</pre>")
    title = html.escape(f"codev report: {problem.name}")
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        f"<meta name='viewport' content='width=device-width, initial-scale=1'><title>{title}"
        f"</title><style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n"
    )


def report_figures(
    problem: Problem,
    law: ExplicitLaw,
    result: VerificationResult | None = None,
    *,
    traces: int = 16,
    axes: tuple[int, int] = (0, 1),
) -> tuple[RecordingContent, list[tuple[Figure, str]]]:
    """The report's figures with their captions, drawn from the recording's scene.

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
    result : VerificationResult, optional
    traces : int
        Closed-loop traces simulated (0: none).
    axes : (int, int)
        The plane's state indices.

    Returns
    -------
    content : RecordingContent
        What a recording of the design holds (its ``scene`` is the figures').
    figures : list of (matplotlib Figure, str)
        The tubes against time and in the plane (with a result), the partition, the
        inputs of the traces.
    """
    from codev_engine.view.record_content import RecordingContent, RecordingOptions
    from codev_engine.view.records import _check_options, drawable

    full_law = law
    law, options = drawable(problem, law, RecordingOptions(axes=axes, traces=traces))
    plane = _check_options(options, problem.plant.n)
    content = RecordingContent.build(problem, law, result, options, plane, trace_law=full_law)
    scene = content.scene  # one scene: the report's figures show the recording's numbers
    parts: list[tuple[Figure, str]] = []
    if result is not None:
        fig = figures.figure_result(result, problem, law=law, max_states=min(problem.plant.n, 8),
                                    scene=scene)
        caption = "The reachtube of each state against time, and projected on the plane"
        if plane is not None:
            caption += f" of {problem.plant.states[plane[0]]} and {problem.plant.states[plane[1]]}"
        parts.append((fig, caption + ", with the sets and the counterexample (if any)."))
    fig = figures.figure_law(law, scene=scene)
    if getattr(law, "on_demand", False):  # (issue 39: the regions computed, not the law)
        parts.append((fig, "The regions reached by the verification (not the whole law): "
                      f"{scene.partition_title}."))
    elif getattr(law, "shards", None) is not None:  # (a law stored as shards, issue 43)
        many = "s" if law.shards != 1 else ""
        parts.append((fig, f"The partition of the explicit law: {scene.partition_title}; "
                      f"the law is stored as {law.shards} shard{many}."))
    else:
        parts.append((fig, f"The partition of the explicit law: {scene.partition_title}."))
    if content.traces is not None and problem.plant.m:
        fig = figure_inputs(problem, content.traces, result, t_end=scene.t_end)
        parts.append((fig, "The inputs of the simulated traces, with their bounds."))
    return content, parts


def write_report(
    path: str | os.PathLike,
    problem: Problem,
    law: ExplicitLaw,
    result: VerificationResult | None = None,
    **options: object,
) -> Path:
    """Write :func:`report_html` to ``path`` atomically.

    Parameters
    ----------
    path : str or PathLike
        The ``.html`` file; parent folders are created.
    problem : Problem
    law : ExplicitLaw
    result : VerificationResult, optional
    **options : object
        ``traces``, ``axes`` (:func:`report_html`).

    Returns
    -------
    Path
    """
    html = report_html(problem, law, result, **options)  # type: ignore[arg-type]
    remove_stale_beside(path)  # (what a report killed while writing left)
    return write_text(path, html)


def figure_inputs(
    problem: Problem,
    traces: Traces,
    result: VerificationResult | None = None,
    *,
    t_end: float | None = None,
) -> Figure:
    """Each input of the simulated traces against time, with its bounds (and the
    counterexample's input, if any).

    Parameters
    ----------
    problem : Problem
    traces : Traces
        ``record_content.simulate_traces`` output: ``t`` (K,), ``U`` (P, K, m), ``alive``.
    result : VerificationResult, optional
    t_end : float, optional
        The time axis' end (the scene's); the traces' end by default.

    Returns
    -------
    matplotlib Figure
        One axes per input.
    """
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    m = problem.plant.m
    fig = Figure(figsize=(9.0, 1.0 + 2.2 * m), layout="constrained")
    axs = fig.subplots(m, 1, squeeze=False)[:, 0]
    cex = result.counterexample if result is not None else None
    for j, ax in enumerate(axs):
        lines = []
        for p in range(traces.U.shape[0]):
            keep = traces.alive[p] & np.isfinite(traces.U[p, :, j])
            lines.append(np.column_stack([traces.t[keep], traces.U[p, keep, j]]))
        ax.add_collection(LineCollection(lines, colors="#777777", linewidths=0.8, label="traces"))
        if cex is not None:
            u = np.asarray(cex.trace.u, dtype=float)[:, j]
            ok = (np.asarray(cex.trace.region) >= 0) & np.isfinite(u)
            # the counterexample in its own colour (magenta, as in every view), on top
            ax.plot(np.asarray(cex.trace.t)[ok], u[ok], color=figures.CEX_COLOUR, lw=1.5,
                    label="counterexample", zorder=5)
        for v in (problem.mpc.u_min[j], problem.mpc.u_max[j]):
            if np.isfinite(v):
                ax.axhline(float(v), color="k", lw=1.0, ls="--")
        ax.autoscale_view()
        ax.set_ylabel(problem.plant.input_label(j))
        ax.set_xlabel("t (s)")
        # the traces' own end: for time_horizon = "inf" that is the shown horizon, not inf
        end = t_end if t_end is not None else (float(traces.t[-1]) if traces.t.size else None)
        ax.set_xlim(0.0, end if end and np.isfinite(end) and end > 0 else None)
    axs[0].set_title("inputs of the simulated traces (bounds dashed)", fontsize="medium")
    return fig


def _svg(fig: Figure) -> str:
    """The figure as an inline ``<svg>`` element (no XML prologue, no doctype, no date)."""
    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    text = buf.getvalue()
    return text[text.index("<svg") :]


# ---- a small markdown subset (what verdict_text writes) ------------------------------------


def markdown_html(text: str) -> str:
    """The markdown of the verdict document as HTML: ``#`` headings, paragraphs, ``-`` lists,
    ``| a | b |`` tables, ``**bold**`` and `` `code` `` (everything escaped).

    Parameters
    ----------
    text : str

    Returns
    -------
    str
    """
    out: list[str] = []
    para: list[str] = []
    items: list[str] = []
    rows: list[list[str]] = []

    def flush() -> None:
        if para:
            out.append("<p>" + _inline(" ".join(para)) + "</p>")
            para.clear()
        if items:
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
            items.clear()
        if rows:
            body = [r for r in rows if not all(set(c) <= {"-", ""} for c in r)]
            body = [r for r in body if any(c for c in r)]
            out.append(
                "<table>"
                + "".join(
                    "<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>" for r in body
                )
                + "</table>"
            )
            rows.clear()

    for line in text.splitlines():
        s = line.strip()
        heading = re.match(r"^(#{1,6})\s+(.*)$", s)
        if not s:
            flush()
        elif heading:
            flush()
            level = len(heading.group(1)) + 1  # the banner is the page's title
            out.append(f"<h{min(level, 6)}>{_inline(heading.group(2))}</h{min(level, 6)}>")
        elif s.startswith("- "):
            if para or rows:
                flush()
            items.append(s[2:])
        elif s.startswith("|"):
            if para or items:
                flush()
            rows.append([c.strip() for c in s.strip("|").split("|")])
        else:
            para.append(s)
    flush()
    return "\n".join(out)


def _inline(s: str) -> str:
    s = html.escape(s)
    s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", s)
