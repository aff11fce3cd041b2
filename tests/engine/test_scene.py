"""One scene (codev_engine.view.scene): the recording and the report's figures show the same
numbers -- checked on the outputs: the .rrd read back with rerun's ``RrdReader`` (entities
and the blueprint store) against the matplotlib axes of the report's figures.

Bundled examples: cruise_grade (one state, all-time certificate) in the default suite; the
double integrator (2 states), the dc-motor servo (a theta law: a section) and navigation
(unsafe, 4 states) behind the slow marker (synthesis and verification take 5-40 s each).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

import codev_engine as ce
from codev_engine.view.glyphs import text_strips
from codev_engine.view.records import RecordingOptions, write_recording
from codev_engine.view.report import report_figures
from codev_engine.view.scene import MAX_STEPS, decade_range

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _entities(path: Path) -> dict[str, dict[str, list]]:
    """Entity path -> component column -> rows (python lists), of the recording store."""
    out: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for chunk in RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        for name in rb.schema.names:
            if ":" in name:
                out[chunk.entity_path][name] += rb.column(name).to_pylist()
    return out


def _times(path: Path, entity: str) -> np.ndarray:
    """The ``time`` timeline of one entity's rows, in seconds."""
    parts = [chunk.to_record_batch().column("time").cast("int64").to_numpy()
             for chunk in RrdReader(path).stream().to_chunks()
             if chunk.entity_path == entity and "time" in chunk.timeline_names]
    return np.concatenate(parts) / 1e9


def _views(path: Path) -> dict[str, dict[str, object]]:
    """View display name -> its blueprint components (``ScalarAxis:range``, ...)."""
    reader = RrdReader(path)
    parts: dict[str, dict[str, object]] = defaultdict(dict)
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            for name in rb.schema.names:
                if ":" in name and chunk.entity_path.startswith("/view/"):
                    view = "/".join(chunk.entity_path.split("/")[:3])
                    parts[view][name] = rb.column(name).to_pylist()[-1]
    return {str(p["ViewBlueprint:display_name"][0]): p for p in parts.values()
            if "ViewBlueprint:display_name" in p}


def _window(entities) -> tuple[np.ndarray, np.ndarray]:
    """The plane's window from its normalising transform (scale 1/span, shift -c/span)."""
    t = np.ravel(np.array(entities["/plane"]["Transform3D:translation"][0], dtype=float))[:2]
    s = np.ravel(np.array(entities["/plane"]["Transform3D:scale"][0], dtype=float))[:2]
    span = np.abs(1.0 / s)
    c = -t / s
    return c - 0.5 * span, c + 0.5 * span


def _horizontal_values(ax) -> set[float]:
    """The y of every horizontal line and of every edge of a patch spanning the axes."""
    ys: set[float] = set()
    for line in ax.get_lines():
        y = np.asarray(line.get_ydata(), dtype=float)
        if y.size == 2 and y[0] == y[1]:
            ys.add(round(float(y[0]), 9))
    for patch in ax.patches:
        verts = patch.get_path().vertices @ patch.get_patch_transform().get_matrix()[:2, :2].T
        verts = verts + patch.get_patch_transform().get_matrix()[:2, 2]
        ys.update(round(float(v), 9) for v in np.unique(verts[:, 1]))
    return ys


def _same_numbers(name: str, tmp_path: Path) -> None:
    problem = ce.load_spec(EXAMPLES / f"{name}.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    options = RecordingOptions(traces=3)
    write_recording(tmp_path / "r.rrd", problem, law, result, options=options)
    entities, views = _entities(tmp_path / "r.rrd"), _views(tmp_path / "r.rrd")
    content, figs = report_figures(problem, law, result, traces=3)
    scene = content.scene
    tube_fig, law_fig = figs[0][0], figs[1][0]
    n = problem.plant.n

    # the partition's title (the section, when it is one): the recording's plane view and
    # the report's partition figure say the same words
    (plane,) = [v for v in views if v.startswith("plane")]
    title = plane.split("↑, ", 1)[1].split("  (", 1)[0]
    assert title == scene.partition_title
    law_title = law_fig.axes[0].get_title().replace("\nsection at", ": section at")
    assert law_title.endswith(f": {title}"), (law_title, title)
    if problem.plant.n > 2 or law.n > problem.plant.n:
        assert "section at" in title

    # the plane's window
    lo, hi = _window(entities)
    if n >= 2:
        plane_ax = tube_fig.axes[-1]
        assert np.allclose([plane_ax.get_xlim(), plane_ax.get_ylim()], np.c_[lo, hi], atol=1e-9)
        assert np.allclose([law_fig.axes[0].get_xlim(), law_fig.axes[0].get_ylim()],
                           np.c_[lo, hi], atol=1e-9)
        if scene.section is not None:
            assert plane_ax.get_title() == f"section at {scene.section.words}"
        # the sets in the plane: each unsafe set's outline in the recording is a patch of
        # the figure's plane, vertex for vertex
        from matplotlib.patches import Polygon

        patches = [p.get_xy() for p in plane_ax.patches if isinstance(p, Polygon)]
        for e in [e for e in entities if e.startswith("/plane/unsafe/")]:
            ring = np.array(entities[e]["LineStrips2D:strips"][0][0], dtype=float)[:-1]
            assert any(xy.shape[0] - 1 == ring.shape[0] and np.allclose(xy[:-1], ring,
                                                                         atol=1e-5)
                       for xy in patches), e
    else:  # (time, state): the time axis is the figures'
        assert lo[0] == pytest.approx(0.0) and hi[0] == pytest.approx(scene.t_end)

    # each state's time plot: y range, time axis, label, limits
    for k, s in enumerate(problem.plant.states):
        (view,) = [p for v, p in views.items() if v.startswith(f"{s}(t)")]
        ax = tube_fig.axes[k]
        assert np.allclose(view["ScalarAxis:range"], ax.get_ylim(), atol=1e-9)
        t_range = view["TimeAxis:view_range"][0]
        T = (t_range["end"] - t_range["start"]) / 1.10 / 1e9
        assert ax.get_xlim() == pytest.approx((0.0, T), rel=1e-6)
        assert ax.get_ylabel() == problem.plant.state_label(k)
        assert len([y for y in ax.get_yticks() if ax.get_ylim()[0] <= y <= ax.get_ylim()[1]]) >= 3
        drawn = _horizontal_values(ax)
        limits = [e for e in entities if e.startswith(f"/time/{s}/unsafe/")
                  or e.startswith(f"/time/{s}/safe/")]
        for e in limits:
            (v,) = set(np.round(np.concatenate(entities[e]["Scalars:scalars"]), 5))
            lo_y, hi_y = ax.get_ylim()
            assert lo_y < v < hi_y  # in view in both
            assert any(abs(v - y) < 1e-5 for y in drawn), (s, e, v, sorted(drawn))
        initial = np.concatenate(entities[f"/time/{s}/initial"]["Scalars:scalars"])
        assert np.allclose(sorted(initial), [problem.verify.initial_lower[k],
                                             problem.verify.initial_upper[k]], atol=1e-6)

    # each output y = C x: its y range
    for k, out in enumerate(scene.outputs):
        (view,) = [p for v, p in views.items() if v.startswith(f"{out.name}(t) = C x")]
        ax = tube_fig.axes[n + k]
        assert ax.get_ylabel() == f"{out.name} = C x"
        assert np.allclose(view["ScalarAxis:range"], ax.get_ylim(), atol=1e-9)


def test_cruise_grade_recording_and_report_show_the_same_numbers(tmp_path):
    _same_numbers("cruise_grade", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["double_integrator", "dc_motor_servo", "navigation"])
def test_recording_and_report_show_the_same_numbers(name, tmp_path):
    _same_numbers(name, tmp_path)


def test_plane_y_tick_labels_are_centred_on_their_ticks(tmp_path):
    # the labels are strokes in data coordinates: each y label's strokes span a band
    # centred on its tick's y exactly, to the left of the frame (a labelled point's text
    # sat ~13 px under its tick in the viewer)
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    write_recording(tmp_path / "t.rrd", problem, law, None, options=RecordingOptions(traces=0))
    e = _entities(tmp_path / "t.rrd")
    lo, hi = _window(e)
    frame = [np.array(s) for s in e["/plane/axes/frame"]["LineStrips2D:strips"][0]]
    ticks = sorted({float(s[0, 1]) for s in frame[1:] if s[0, 0] == lo[0] and s[1, 0] < lo[0]})
    assert len(ticks) >= 3
    segs = np.array(e["/plane/axes/y_labels"]["LineStrips2D:strips"][0], dtype=float)
    assert np.all(segs[:, :, 0] < lo[0])
    gap = np.min(np.diff(ticks))
    for y in ticks:
        mine = segs[np.abs(segs[:, :, 1].mean(axis=1) - y) < 0.5 * gap]
        assert mine.size, y
        top, bottom = mine[:, :, 1].max(), mine[:, :, 1].min()
        assert 0.5 * (top + bottom) == pytest.approx(y, abs=1e-9 * (hi[1] - lo[1]))
        assert top - bottom > 0.02 * (hi[1] - lo[1])  # a label, not a dot


def test_text_strips_centre_every_digit():
    for text in ("0", "1", "-2.5", "10", "7e-05", "+3"):
        P = np.array(text_strips(text, (0.0, 3.0), (0.1, 0.2)))
        if any(c.isdigit() for c in text):
            assert P[..., 1].min() == pytest.approx(2.9) and P[..., 1].max() == pytest.approx(3.1)
        assert P[..., 0].max() <= 1e-12  # right-aligned at the anchor


@pytest.mark.parametrize("lo, hi", [(-14.6, -1.9), (7.0, 11.0), (0.55, 0.7), (-0.1, 0.0),
                                    (8.0, 10.1), (3.0, 3.0), (-1e-3, 2e-4), (-4.0, 4.0),
                                    (-4.6, 4.5), (0.0, 9.5)])
def test_decade_range_holds_three_multiples_of_its_decade(lo, hi):
    a, b = decade_range(lo, hi)
    assert a < lo and b > hi
    # the viewer labels the smallest power of ten at least 20 px high: in a 190 px plot
    # (three stacked) some power of ten has between three and MAX_STEPS + 1 multiples in
    # view ([-4.6, 4.5] had ten steps of 1, the label "0" only)
    counts = [int(np.floor(b / s) - np.ceil(a / s)) + 1
              for s in 10.0 ** np.arange(-6, 4, dtype=float)]
    assert any(3 <= c <= MAX_STEPS + 1 for c in counts), (lo, hi, counts)
    for step in (10.0 ** np.floor(np.log10(b - a)), 10.0 ** np.floor(np.log10(b - a) - 1)):
        first = np.ceil(a / step)
        count = int(np.floor(b / step) - first) + 1
        if step <= (b - a) / 2:
            assert count >= 3, (lo, hi, step)


def test_outputs_after_the_certificate_show_its_band_not_the_tube_repeated(tmp_path):
    """mass_spring_soft's y0(t) repeated the certificate's period (the tube jumping back
    every 1.8 s) where its state plots show the certificate band: the outputs are drawn
    like the states."""
    text = (EXAMPLES / "mass_spring_soft.toml").read_text().replace(
        "time_horizon = 8.0", "time_horizon = 5.0")
    problem = ce.loads_spec(text)
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    write_recording(tmp_path / "r.rrd", problem, law, result,
                    options=RecordingOptions(traces=2))
    entities = _entities(tmp_path / "r.rrd")
    from codev_engine.reach.claim import certificate_band

    cert = certificate_band(result)
    assert cert is not None and cert.t_closed < 5.0
    C = np.asarray(problem.mpc.C, dtype=float)
    lo = (np.minimum(C * cert.lower, C * cert.upper)).sum(axis=1)
    hi = (np.maximum(C * cert.lower, C * cert.upper)).sum(axis=1)
    for k in range(C.shape[0]):
        for side, want in (("lower", lo[k]), ("upper", hi[k])):
            band = np.concatenate(entities[f"/output/y{k}/certificate/{side}"]
                                  ["Scalars:scalars"])
            assert np.allclose(band, want, atol=1e-5)
        # the tube's hull stops at the closing sample: its last value is no repeat
        for side in ("lower", "upper"):
            times = _times(tmp_path / "r.rrd", f"/output/y{k}/tube/{side}")
            assert times.max() <= cert.t_closed + 1e-6
            assert _times(tmp_path / "r.rrd", f"/output/y{k}/certificate/{side}").max() \
                == pytest.approx(5.0)


def test_the_figure_title_fits_a_one_state_figure():
    """cruise_control's report lost the title's first letter (":ruise-control"): on one
    line it was wider than the one-state figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from codev_engine.view import figures

    problem = ce.load_spec(EXAMPLES / "cruise_control.toml")
    law = ce.synthesize(problem)
    fig = figures.figure_result(ce.verify(problem, law), problem, law=law)
    FigureCanvasAgg(fig).draw()
    box = fig._suptitle.get_window_extent()
    assert 0 <= box.x0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1
    assert fig._suptitle.get_text().startswith("cruise-control: ")


def test_the_verdict_document_puts_the_claim_on_the_first_screen():
    """cruise_grade's recording showed its sets below the fold (name, verdict and sentence
    as three blocks, the uncertainty and the hold before the sets): the system and the
    verdict share the first line, then the initial set, the horizon and every property
    checked, within the first 12 lines the viewer shows at 1600x1000."""
    problem = ce.load_spec(EXAMPLES / "cruise_grade.toml")
    law = ce.synthesize(problem)
    result = ce.verify(problem, law)
    content, _ = report_figures(problem, law, result, traces=0)
    lines = [ln for ln in content.verdict_text().splitlines() if ln.strip()]
    assert lines[0] == "## cruise-grade · verdict: ROBUSTLY SAFE"
    labels = [ln.split("**")[1] for ln in lines[:12] if ln.startswith("- **")]
    assert labels[:3] == ["system", "initial set", "time"]
    assert labels.count("checked") >= 3  # unsafe sets 0 and 1, the law's domain, ...
    assert labels.index("for every") > max(i for i, x in enumerate(labels) if x == "checked")
    first = "\n".join(lines[:12])
    assert "v >= 11" in first and "v <= 7" in first and "for all t >= 0" in first
