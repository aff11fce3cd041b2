"""Pictures of laws and verification results (codev_engine.figures) and the notebook hooks.

The geometry is checked against the engine itself: the polygons of a partition tile the
law's domain (their areas add up to the domain's) and each polygon's centroid is located by
``law.locate`` in the polygon's own region, for a 2-D law and for sections of a 3-D law with
1008 regions. The drawings are checked through the artists they create (one polygon per
region, the tube's boxes, the counterexample trace, the verify sets), the notebook hooks
through IPython's own display formatter, and the import hygiene in a fresh interpreter.
"""

from __future__ import annotations

import base64
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.reach.tube import Tube
from codev_engine.reach.verification import VerificationResult
from codev_engine.view import figures
from tests.di_variants import HULL_CORNER, UNSAFE_ON_PATH, di_spec

matplotlib = pytest.importorskip("matplotlib")
from matplotlib.collections import LineCollection, PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import PathPatch, Polygon  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
DI_TEXT = (ROOT / "examples" / "double_integrator.toml").read_text()
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

# plus a half-plane in the (x1, x2) plane, far from the tube (drawn, never entered)
UNSAFE_AND_HALF_PLANE = (
    UNSAFE_ON_PATH
    + """
[[verify.unsafe]]
A = [[1.0, 1.0]]
b = [-7.0]
"""
)


def _axes() -> matplotlib.axes.Axes:
    return Figure().add_subplot()


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _inside(poly: np.ndarray, X: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Points (P, 2) inside a counter-clockwise convex polygon."""
    e = np.roll(poly, -1, axis=0) - poly
    rel = X[:, None, :] - poly[None]
    cross = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]
    return np.all(cross >= -tol, axis=1)


@pytest.fixture(scope="module")
def di(example_law):
    return example_law("double_integrator.toml")


@pytest.fixture(scope="module")
def mp3(example_law):
    """A 3-state law with 1008 regions (synthesis ~1 s)."""
    return example_law("magnetic_pointer_a.toml")


@pytest.fixture(scope="module")
def results(di):
    problem, law = di
    safe = ce.verify(problem, law)
    unsafe_problem = di_spec(UNSAFE_AND_HALF_PLANE)
    unsafe = ce.verify(unsafe_problem, law)
    unknown = ce.verify(di_spec(HULL_CORNER), law, max_depth=0)
    assert safe.verdict == "robustly_safe", safe.summary()
    assert unsafe.verdict == "unsafe", unsafe.summary()
    assert unknown.verdict == "unknown", unknown.summary()
    return {"safe": safe, "unsafe": unsafe, "unknown": unknown, "unsafe_problem": unsafe_problem}


# --------------------------------------------------------------------------------------------
# import hygiene
# --------------------------------------------------------------------------------------------


def test_import_and_drawing_keep_matplotlib_lazy_and_pyplot_out(tmp_path):
    """``import codev_engine`` (figures included) loads no matplotlib; drawing loads no pyplot
    and picks no GUI backend."""
    script = textwrap.dedent(
        """
        import sys
        import codev_engine as ce
        import codev_engine.view.figures, codev_engine.law, codev_engine.reach.verification
        assert "matplotlib" not in sys.modules, "matplotlib imported at import time"
        law = ce.ExplicitLaw.load(sys.argv[1])
        png = law._repr_png_()
        assert png.startswith(b"\\x89PNG")
        assert "matplotlib" in sys.modules
        assert "matplotlib.pyplot" not in sys.modules, "pyplot imported by the drawing"
        print("ok")
        """
    )
    problem = ce.load_spec(ROOT / "examples" / "cruise_control.toml")
    path = ce.synthesize(problem).save(tmp_path / "law.npz")
    out = subprocess.run(
        [sys.executable, "-c", script, str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_displayed_types_import_no_drawing_code(tmp_path):
    """The law and the result display through ``codev_engine.display``: no import statement
    of theirs (lazy ones included) names ``codev_engine.view``; the drawing backend is
    imported by module name on the first display."""
    import ast

    for rel in ("codev_engine/law.py", "codev_engine/reach/verification.py"):
        tree = ast.parse((ROOT / rel).read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
        assert not [m for m in names if m.startswith("codev_engine.view")], rel
    script = textwrap.dedent(
        """
        import sys
        import codev_engine.law, codev_engine.reach.verification
        views = lambda: sorted(m for m in sys.modules if m.startswith("codev_engine.view"))
        assert views() == [], views()
        law = codev_engine.law.ExplicitLaw.load(sys.argv[1])
        assert law._repr_mimebundle_()["image/png"]
        assert "codev_engine.view.notebook" in views(), views()
        assert "matplotlib.pyplot" not in sys.modules
        print("ok")
        """
    )
    problem = ce.load_spec(ROOT / "examples" / "cruise_control.toml")
    path = ce.synthesize(problem).save(tmp_path / "law.npz")
    out = subprocess.run(
        [sys.executable, "-c", script, str(path)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


# --------------------------------------------------------------------------------------------
# partitions
# --------------------------------------------------------------------------------------------


def test_section_polygons_tile_the_2d_domain(di):
    _, law = di
    polys, index = figures.section_polygons(law.A, law.b)
    assert list(index) == list(range(law.num_regions))
    areas = np.array([_area(p) for p in polys])
    assert np.all(areas > 0), "vertices must be counter-clockwise"
    (domain,), _ = figures.section_polygons([law.domain_A], [law.domain_b])
    assert areas.sum() == pytest.approx(_area(domain), rel=1e-9)
    for k, poly in zip(index, polys, strict=True):
        # every vertex satisfies its region's rows, and the centroid is located in it
        assert np.all(poly @ law.A[k].T <= law.b[k] + 1e-7)
        assert law.locate(poly.mean(axis=0))[0] == k
    # random states: located in region k <=> inside polygon k
    X = np.random.default_rng(1).uniform(-10, 10, (2000, 2))
    where = law.locate(X)
    for k, poly in zip(index, polys, strict=True):
        inside = _inside(poly, X)
        assert np.array_equal(inside[where == k], np.ones(np.sum(where == k), bool)), k


def test_plot_partition_2d_one_polygon_per_region(di):
    _, law = di
    ax = figures.plot_partition(law, _axes())
    (coll,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    assert len(coll.get_paths()) == law.num_regions == 10
    colours = np.unique(np.round(coll.get_facecolors(), 6), axis=0)
    assert colours.shape[0] == law.num_regions, "regions must have distinct colours"
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x1", "x2")
    assert "10 regions" in ax.get_title()
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 <= -10 and x1 >= 10 and y0 <= -10 and y1 >= 10
    swapped = figures.plot_partition(law, _axes(), axes=(1, 0))
    assert (swapped.get_xlabel(), swapped.get_ylabel()) == ("x2", "x1")


def test_plot_partition_rejects_bad_axes(di):
    _, law = di
    for bad in [(0, 0), (0, 2), (-1, 1)]:
        with pytest.raises(ValueError, match="axes"):
            figures.plot_partition(law, _axes(), axes=bad)


def test_3d_law_sections_match_point_location(mp3):
    _, law = mp3
    assert law.n == 3 and law.num_regions > 1000
    centre = figures.default_slice_point(law)
    # deviation coordinates with symmetric bounds: the domain's box is centred on 0
    np.testing.assert_allclose(centre, 0.0, atol=1e-6)
    for axes, at in [((0, 1), centre), ((1, 2), np.array([0.7, 0.0, 0.0]))]:
        polys, index = figures.section_polygons(law.A, law.b, axes=axes, at=at)
        assert 20 < len(polys) < law.num_regions
        (dom,), _ = figures.section_polygons([law.domain_A], [law.domain_b], axes=axes, at=at)
        assert sum(_area(p) for p in polys) == pytest.approx(_area(dom), rel=1e-6)
        other = ({0, 1, 2} - set(axes)).pop()
        X = np.zeros((len(polys), 3))
        X[:, list(axes)] = [p.mean(axis=0) for p in polys]
        X[:, other] = at[other]
        np.testing.assert_array_equal(law.locate(X), index)


def test_plot_partition_3d_is_one_collection_and_titled(mp3):
    """A section of 1008 regions is one PolyCollection (quick to draw: no patch per
    region); the count is checked, not a wall time (timed targets live in benchmarks/)."""
    _, law = mp3
    ax = figures.plot_partition(law, _axes(), axes=(0, 1), at=[0.0, 0.0, 1.0])
    png = figures.png_bytes(ax.figure)
    assert png.startswith(PNG_MAGIC)
    assert len(ax.patches) <= 10
    (coll,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    polys, _ = figures.section_polygons(law.A, law.b, at=np.array([0.0, 0.0, 1.0]))
    assert len(coll.get_paths()) == len(polys)
    assert "1008 regions" in ax.get_title() and "x3 = 1" in ax.get_title()


def test_plot_partition_one_state_draws_the_law(example_law):
    problem, law = example_law("cruise_control.toml")
    ax = figures.plot_partition(law, _axes())
    (bands,) = [c for c in ax.collections if isinstance(c, PolyCollection)]
    (lines,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(bands.get_paths()) == law.num_regions
    for seg in lines.get_segments():
        mid = seg.mean(axis=0)  # the line is u = F x + G over each region
        assert law.evaluate([[mid[0]]])[0, 0] == pytest.approx(mid[1], rel=1e-9, abs=1e-9)
    assert ax.get_xlabel() == problem.plant.states[0]


# --------------------------------------------------------------------------------------------
# tubes and results
# --------------------------------------------------------------------------------------------


def test_merge_bands_keeps_the_union():
    rng = np.random.default_rng(3)
    K = 4000
    ts = rng.integers(0, 20, K) * 0.1
    te = ts + 0.1
    lo = rng.uniform(-1, 1, K)
    hi = lo + rng.uniform(0, 0.3, K)
    merged = figures.merge_bands(ts, te, lo, hi)
    assert merged.shape[0] < K / 5
    t = rng.integers(0, 20, 20000) * 0.1 + 0.05
    y = rng.uniform(-1.2, 1.4, 20000)

    def covered(ts, te, lo, hi):
        out = np.zeros(t.shape, dtype=bool)
        for a, b, c, d in zip(ts, te, lo, hi, strict=True):
            out |= (a <= t) & (t <= b) & (c <= y) & (y <= d)
        return out

    np.testing.assert_array_equal(covered(ts, te, lo, hi), covered(*merged.T))


def _boxes_patch(ax) -> PathPatch:
    (patch,) = [p for p in ax.patches if isinstance(p, PathPatch)]
    return patch


def test_plot_tube_draws_the_boxes_and_the_safe_bound(di, results):
    problem, _ = di
    result = results["safe"]
    ax = figures.plot_tube(result, _axes(), state=0, problem=problem)
    tube = result.tube
    bands = figures.merge_bands(tube.t_start, tube.t_end, tube.lower[:, 0], tube.upper[:, 0])
    verts = _boxes_patch(ax).get_path().vertices.reshape(-1, 5, 2)
    assert verts.shape[0] == bands.shape[0] > 0
    # each band drawn as itself, or widened about its centre to 1 % of the axis (visible)
    least = 0.01 * np.ptp(ax.get_ylim())
    lo, hi = verts[:, 0], verts[:, 2]
    np.testing.assert_allclose(lo[:, 0], bands[:, 0])
    np.testing.assert_allclose(hi[:, 0], bands[:, 1])
    assert np.all(lo[:, 1] <= bands[:, 2] + 1e-12) and np.all(hi[:, 1] >= bands[:, 3] - 1e-12)
    assert np.all(hi[:, 1] - lo[:, 1] >= least * (1 - 1e-9))
    tall = bands[:, 3] - bands[:, 2] >= least
    np.testing.assert_allclose(lo[tall, 1], bands[tall, 2])
    np.testing.assert_allclose(0.5 * (lo[:, 1] + hi[:, 1]), bands[:, 2:].mean(axis=1))
    assert ax.get_ylim()[0] <= tube.lower[:, 0].min() and ax.get_ylim()[1] >= 10.0
    # the safe set's bound x1 <= 10 is in view: a horizontal line at 10
    assert any(np.allclose(line.get_ydata(), 10.0) for line in ax.lines)
    assert ax.get_ylabel() == "x1"
    with pytest.raises(ValueError, match="state"):
        figures.plot_tube(result, _axes(), state=2)


def test_unsafe_result_shows_the_counterexample(results):
    result, problem = results["unsafe"], results["unsafe_problem"]
    cex = result.counterexample
    fig = figures.figure_result(result, problem)
    tube_ax, _, plane_ax = fig.axes
    head = [ln for ln in tube_ax.lines if ln.get_alpha() is None and len(ln.get_xdata()) > 1]
    t, x = head[0].get_xdata(), head[0].get_ydata()
    assert t[-1] == pytest.approx(cex.t) and t[0] == 0.0
    assert x[0] == pytest.approx(cex.x0[0])
    marker = [ln for ln in tube_ax.lines if ln.get_marker() == "X"]
    assert marker and marker[0].get_xdata()[0] == pytest.approx(cex.t)
    title = fig._suptitle.get_text()
    assert title.startswith("double-integrator: unsafe: enters unsafe set 0 at t = ")
    assert fig._suptitle.get_color() == figures.VERDICT_COLOURS["unsafe"]
    # the plane: the unsafe box and the half-plane x1 + x2 <= -7 (clipped to the view)
    polys = [p for p in plane_ax.patches if isinstance(p, Polygon) and p.get_fill()]
    assert len(polys) == 2
    box = polys[0].get_xy()
    assert box[:, 0].min() == pytest.approx(-0.6) and box[:, 1].max() == pytest.approx(-2.3)
    assert np.all(polys[1].get_xy().sum(axis=1) <= -7.0 + 1e-9)


def test_plane_of_a_3d_result_with_its_law(example_law):
    problem, law = example_law("magnetic_pointer_c.toml")
    result = ce.verify(problem, law)
    assert result.verdict == "unsafe" and result.counterexample.kind == "undefined"
    fig = figures.figure_result(result, problem, law=law)
    assert len(fig.axes) == 4  # three states against time, one plane
    ax = figures.plot_plane(result, _axes(), axes=(0, 2), problem=problem, law=law)
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x1", "x3")
    verts = _boxes_patch(ax).get_path().vertices.reshape(-1, 5, 2)
    lo, hi = verts[:, 0], verts[:, 2]
    # every box is drawn, as itself or widened about its centre (0.6 % of the view at least)
    want_lo, want_hi = result.tube.lower[:, [0, 2]], result.tube.upper[:, [0, 2]]
    covered = np.all(
        (lo[None] <= want_lo[:, None] + 1e-12) & (hi[None] >= want_hi[:, None] - 1e-12), axis=2
    )
    assert covered.any(axis=1).all()
    span = np.array([np.ptp(ax.get_xlim()), np.ptp(ax.get_ylim())])
    assert np.all(hi - lo >= 0.006 * span * (1 - 1e-9))
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "initial set" in labels and any(s.startswith("counterexample") for s in labels)
    with pytest.raises(ValueError, match="axes"):
        figures.plot_plane(result, _axes(), axes=(1, 1))


# --------------------------------------------------------------------------------------------
# notebook hooks
# --------------------------------------------------------------------------------------------


def test_law_repr_png_and_html(di):
    _, law = di
    png = law._repr_png_()
    assert png.startswith(PNG_MAGIC) and len(png) > 5000
    html = law._repr_html_()
    assert '<img src="data:image/png;base64,' in html
    assert "<th style='text-align:left;padding-right:1em'>regions</th>" in html
    assert ">10<" in html and "inf" in html and "x1, x2" in html


@pytest.mark.parametrize(
    ("key", "words"),
    [
        ("safe", ["robustly safe", "initial set: x1 in", "NOT checked: "]),
        ("unsafe", ["unsafe: enters unsafe set 0", "checked: never enters unsafe set 0",
                    "counterexample x0", "[ 8.99"]),
        ("unknown", ["unknown (max_depth)"]),
    ],
)
def test_result_html_banner(results, key, words):
    result = results[key]
    html = result._repr_html_()
    colour = figures.VERDICT_COLOURS[result.verdict]
    assert f"background:{colour}" in html
    for word in words:
        assert word in html, word
    assert f">{result.tube.num_boxes}<" in html
    assert len(set(figures.VERDICT_COLOURS.values())) == 3


def test_ipython_displays_html_and_png_rendered_once(di, results, monkeypatch):
    formatters = pytest.importorskip("IPython.core.formatters")
    _, law = di
    calls = []
    real = figures.png_bytes
    monkeypatch.setattr(figures, "png_bytes", lambda fig, **kw: calls.append(1) or real(fig))
    for obj in (law, results["unsafe"]):
        calls.clear()
        data, _ = formatters.DisplayFormatter().format(obj)
        assert {"text/plain", "text/html", "image/png"} <= set(data)
        assert base64.b64decode(data["image/png"]).startswith(PNG_MAGIC)
        assert data["text/plain"] == obj.summary()
        assert len(calls) == 1, "the picture must be rendered once per display"


def test_result_repr_of_a_large_tube_draws_collections_not_patches(monkeypatch):
    """A tube of 10^5 boxes displays (HTML and PNG) with a bounded number of artists: the
    boxes go into one collection per axes, not one patch each (which took minutes). The
    count, not a wall time, is checked: timed targets live in benchmarks/."""
    rng = np.random.default_rng(0)
    K = 100_000
    ts = np.repeat(np.arange(K // 20) * 0.01, 20)
    centre = np.stack([np.sin(ts), np.cos(ts), ts], axis=1) + rng.normal(0, 0.05, (K, 3))
    tube = Tube(ts, ts + 0.01, centre - 0.01, centre + 0.01, np.zeros(K, dtype=int))
    result = VerificationResult("unknown", "max_depth", tube, "zoh", None, {"seconds": 1.0})
    drawn = []
    real = figures.figure_result
    monkeypatch.setattr(
        figures, "figure_result", lambda r, *a, **k: drawn.append(real(r, *a, **k)) or drawn[-1]
    )
    bundle = result._repr_mimebundle_()
    assert "unknown (max_depth)" in bundle["text/html"] and bundle.get("image/png")
    (fig,) = drawn
    artists = sum(len(ax.patches) + len(ax.collections) + len(ax.lines) for ax in fig.axes)
    assert artists <= 60, f"{K} boxes drawn as {artists} artists"
    # the tube is drawn, not left out: the first state's axes hold all of its boxes
    lo, hi = fig.axes[0].get_ylim()
    assert lo <= tube.lower[:, 0].min() and tube.upper[:, 0].max() <= hi


def test_bare_result_display_has_state_names_and_obstacles(results, tmp_path, monkeypatch):
    """A result of ``verify`` displays with its spec (names, sets): ``verify`` attaches it;
    a result loaded from a file has none and falls back to ``x[i]``."""
    from codev_engine.display import context

    result, problem = results["unsafe"], results["unsafe_problem"]
    assert context(result)["problem"] is problem and "law" in context(result)
    drawn = []
    real = figures.figure_result
    monkeypatch.setattr(
        figures, "figure_result", lambda r, *a, **k: drawn.append(real(r, *a, **k)) or drawn[-1]
    )
    result._repr_png_()
    (fig,) = drawn
    labels = [a.get_ylabel() for a in fig.axes]
    assert labels[:2] == ["x1", "x2"]
    plane = fig.axes[-1]
    assert plane.get_xlabel() == "x1"
    texts = [t.get_text() for t in plane.get_legend().get_texts()]
    assert "unsafe" in texts and any(t.startswith("counterexample") for t in texts)
    # the set the counterexample enters is in view
    box = problem.verify.unsafe[0]
    (x0, x1), (y0, y1) = plane.get_xlim(), plane.get_ylim()
    assert x0 <= box.lower[0] and box.upper[0] <= x1 and y0 <= box.lower[1] <= y1
    loaded = VerificationResult.load(result.save(tmp_path / "r.npz"))
    assert context(loaded) == {} and loaded.verdict == result.verdict
    drawn.clear()
    loaded._repr_png_()
    assert drawn[0].axes[0].get_ylabel() == "x[0]"


# --------------------------------------------------------------------------------------------
# outputs and references (issue 25)
# --------------------------------------------------------------------------------------------


def _short(problem: ce.Problem, horizon: float) -> ce.Problem:
    import re

    return ce.loads_spec(re.sub(r"time_horizon = [0-9.]+", f"time_horizon = {horizon}",
                                problem.source))


def test_servo_figure_shows_the_output_tube_and_the_reference_box(example_law):
    """The servo's law is over theta = (x, u_prev, r): the figure draws its section in the
    plane (it raised before) and a y0 = C x panel with the reference box of [verify]."""
    problem, law = example_law("dc_motor_servo.toml")
    problem = _short(problem, 0.2)
    result = ce.verify(problem, law)
    fig = figures.figure_result(result, problem, law=law)
    axes = [a for a in fig.axes if a.get_ylabel() == "y0 = C x"]
    assert len(axes) == 1 and len(fig.axes) == 4  # angle, speed, y0 and the plane
    ax = axes[0]
    ys = sorted(float(np.mean(line.get_ydata())) for line in ax.lines)
    assert ys == pytest.approx([0.45, 0.55])  # the reference box's sides
    assert any("reference in [0.45, 0.55]" in t.get_text() for t in ax.get_legend().get_texts())
    # the bands are C applied to the boxes: here y = angle, so the angle panel's bands
    angle = next(a for a in fig.axes if a.get_ylabel() == "angle")
    v_y = _boxes_patch(ax).get_path().vertices
    v_x = _boxes_patch(angle).get_path().vertices
    assert v_y.shape == v_x.shape and np.allclose(v_y[:, 0], v_x[:, 0])
    # no reference on the states (the design follows y)
    assert not any("reference" in t.get_text() for t in angle.get_legend().get_texts())


def test_soft_output_bound_is_drawn_dotted(example_law):
    problem, law = example_law("mass_spring_soft.toml")
    result = ce.verify(_short(problem, 2.0), law)
    ax = figures.plot_output(result, problem, _axes(), output=0)
    dotted = [line for line in ax.lines if line.get_linestyle() == ":"]
    assert len(dotted) == 1 and np.allclose(dotted[0].get_ydata(), 1.0)
    assert ax.get_ylim()[1] > 1.0  # the bound is in view, above the tube
    assert [t.get_text() for t in ax.get_legend().get_texts()][-1] == "y_max (soft)"
    with pytest.raises(ValueError, match="output"):
        figures.plot_output(result, problem, _axes(), output=1)


def test_default_slice_is_the_verified_middle_of_u_prev_and_r(example_law):
    """The slice for u_prev and r: the middle of [verify] initial_input and reference; the
    domain's centre without [verify]; recordings take the same section."""
    from codev_engine.view.records import _section_point

    problem, law = example_law("dc_motor_servo.toml")
    at = figures.default_slice_point(law, problem)
    assert at[2:] == pytest.approx([0.0, 0.5])  # initial_input 0, reference [0.45, 0.55]
    bare = figures.default_slice_point(law)
    assert bare[:2] == pytest.approx(at[:2]) and bare[3] == pytest.approx(0.0, abs=1e-9)
    assert _section_point(problem, law) == pytest.approx(at[2:])
    no_verify = ce.loads_spec(problem.source.split("[verify]")[0])
    assert figures.default_slice_point(law, no_verify) == pytest.approx(bare)
    assert _section_point(no_verify, law) == pytest.approx(bare[2:])


def test_output_panel_draws_the_counterexample_through_c(example_law):
    problem, law = example_law("mass_spring_soft.toml")
    unsafe = ce.loads_spec(_short(problem, 2.0).source.replace("lower = [1.3, -inf]",
                                                               "lower = [0.75, -inf]"))
    result = ce.verify(unsafe, law)
    cex = result.counterexample
    assert result.verdict == "unsafe" and cex is not None
    ax = figures.plot_output(result, unsafe, _axes(), output=0)
    (mark,) = [line for line in ax.lines if line.get_marker() == "X"]
    p_at = np.interp(cex.t, np.asarray(cex.trace.t), np.asarray(cex.trace.x)[:, 0])
    assert mark.get_xdata()[0] == pytest.approx(cex.t)
    assert mark.get_ydata()[0] == pytest.approx(p_at)


def test_all_time_tube_ends_in_the_certificate_band_and_shows_the_unsafe_limits():
    # cruise_grade ("inf"): the tube stops at the closing sample (3 s); the band covers the
    # rest of the 25 s view, hatched; the unsafe limits v = 7 and v = 11 are in view
    from matplotlib.patches import Rectangle

    from codev_engine.reach.claim import certificate_band

    problem = ce.load_spec(ROOT / "examples" / "cruise_grade.toml")
    result = ce.verify(problem, ce.synthesize(problem))
    ax = figures.figure_result(result, problem).axes[0]
    (band,) = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_hatch() == "///"]
    t_closed = certificate_band(result).t_closed
    assert band.get_x() == pytest.approx(t_closed) and band.get_x() + band.get_width() == 25.0
    lo, hi = ax.get_ylim()
    assert lo <= 7.0 and hi >= 11.0 and ax.get_xlim() == (0.0, 25.0)
