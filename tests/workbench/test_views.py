"""Terminal pictures of laws and verification results (workbench/views.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from textcells import decode_pixels, plot_body

import codev_engine as ce
from tests.di_variants import UNSAFE_ON_PATH
from workbench.tui.raster import COLOURS, PALETTE
from workbench.tui.views import law_limits, partition_text, plane_text, series_text, tube_time_text

ROOT = Path(__file__).resolve().parents[2]
DI = ROOT / "examples" / "double_integrator.toml"

TRIPLE = """
name = "triple"
[plant]
states = ["p", "v", "a"]
inputs = ["j"]
dynamics = ["v", "a", "j"]
[model]
sample_time = 0.5
[mpc]
horizon = 1
norm = "inf"
Q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -5.0, -5.0]
x_max = [5.0, 5.0, 5.0]
u_min = [-1.0]
u_max = [1.0]
"""


@pytest.fixture(scope="module")
def di(example_law):
    return example_law("double_integrator.toml")


@pytest.fixture(scope="module")
def triple():
    problem = ce.loads_spec(TRIPLE)
    return problem, ce.synthesize(problem)


@pytest.fixture(scope="module")
def unsafe_result(di):
    text = DI.read_text(encoding="utf-8")
    problem = ce.loads_spec(text[: text.index("[verify]")] + UNSAFE_ON_PATH, path="<unsafe>")
    result = ce.verify(problem, di[1])
    assert result.verdict == "unsafe", result.summary()
    assert result.counterexample is not None
    return problem, result


@pytest.fixture(scope="module")
def safe_result(di):
    problem, law = di
    result = ce.verify(problem, law, hold="zoh")
    assert result.verdict == "robustly_safe", result.summary()
    return problem, result


def _pixels(text, height):
    body = plot_body(text, height)
    return np.array(decode_pixels(body), dtype=object)


def _centres(xlim, ylim, width, height):
    xs = xlim[0] + (np.arange(width) + 0.5) * (xlim[1] - xlim[0]) / width
    ys = ylim[1] - (np.arange(2 * height) + 0.5) * (ylim[1] - ylim[0]) / (2 * height)
    return xs, ys


def _check_partition(law, text, width, height, axes, at):
    """Each pixel shows the region ``law.locate`` finds at its centre (background: none)."""
    pix = _pixels(text, height)
    assert pix.shape == (2 * height, width)
    xlim, ylim = law_limits(law, axes)
    xs, ys = _centres(xlim, ylim, width, height)
    gx, gy = np.meshgrid(xs, ys)
    X = np.tile(np.asarray(at, float), (gx.size, 1))
    X[:, axes[0]] = gx.ravel()
    X[:, axes[1]] = gy.ravel()
    want = law.locate(X).reshape(gx.shape)
    for (q, c), k in np.ndenumerate(want):
        assert pix[q, c] == (None if k < 0 else PALETTE[k % len(PALETTE)]), (q, c, k)
    return want


# --------------------------------------------------------------------------------------------
# Partitions
# --------------------------------------------------------------------------------------------


def test_partition_of_the_double_integrator(di):
    problem, law = di
    assert law.num_regions == 10
    width, height = 90, 28
    text = partition_text(law, width, height)
    lines = text.plain.split("\n")
    assert len(lines) == height + 3  # the title, the raster, the x-axis, the caption
    assert lines[0] == "the partition, 10 regions (10 in view)"  # two states: no section
    assert "x: x1" in lines[-1] and "y: x2" in lines[-1]
    assert len(PALETTE) >= law.num_regions  # colours identify regions here
    lo, hi = law.boxes
    want = _check_partition(law, text, width, height, (0, 1), 0.5 * (lo.min(0) + hi.max(0)))
    assert set(np.unique(want)) >= set(range(10))  # every region is on screen


def test_partition_marker_and_limits(di):
    _, law = di
    width, height = 40, 12
    limits = ((-2.0, 2.0), (-1.0, 1.0))
    text = partition_text(law, width, height, marker=np.array([0.05, 0.05]), limits=limits)
    pix = _pixels(text, height)
    # the marker sits at column (0.05 + 2) / 4 * 40 = 20.5, row (1 - 0.05) / 2 * 24 = 11.4
    assert pix[11, 20] == COLOURS["marker"]
    assert sum(v == COLOURS["marker"] for v in pix.ravel()) == 1
    lines = text.plain.split("\n")[1:]  # below the title
    assert lines[0].split("│")[0].strip() == "1"
    assert lines[height].split()[0] == "-2"
    # the title counts the regions actually on screen
    shown = {v for v in pix.ravel() if v is not None and v != COLOURS["marker"]}
    assert f"10 regions ({len(shown)} in view)" in text.plain.split("\n")[0]


def test_partition_slice_of_a_three_state_law(triple):
    problem, law = triple
    assert law.n == 3
    width, height = 50, 16
    at = np.array([0.0, 0.3, -0.4])
    text = partition_text(law, width, height, axes=(0, 2), at=at)
    first, last = text.plain.split("\n")[0], text.plain.split("\n")[-1]
    assert f"{law.num_regions} regions" in first
    assert first.endswith("section at v = 0.3")  # the title names the section
    assert "x: p" in last and "y: a" in last
    _check_partition(law, text, width, height, (0, 2), at)
    # the default slice is the centre of the domain box
    text = partition_text(law, width, height, axes=(1, 2))
    lo, hi = law.boxes
    centre = 0.5 * (lo.min(0) + hi.max(0))
    assert f"section at p = {centre[0]:.3g}" in text.plain
    _check_partition(law, text, width, height, (1, 2), centre)


@pytest.mark.parametrize(("w", "h"), [(2, 1), (13, 5), (160, 45)])
def test_partition_sizes(di, w, h):
    _, law = di
    text = partition_text(law, w, h)
    body = plot_body(text, h)
    assert len(body) == h
    assert all(len(line.plain) == w for line in body)


# --------------------------------------------------------------------------------------------
# Verification pictures
# --------------------------------------------------------------------------------------------


def _count(pix, colour):
    return int(sum(v == colour for v in pix.ravel()))


def test_tube_time_text_with_a_counterexample(unsafe_result):
    problem, result = unsafe_result
    width, height = 100, 20
    text = tube_time_text(result, width, height, state=0, problem=problem)
    pix = _pixels(text, height)
    assert _count(pix, COLOURS["cex"]) > 20
    assert _count(pix, COLOURS["tube"]) > 20
    assert _count(pix, COLOURS["unsafe"]) > 0
    last = text.plain.split("\n")[-1]
    assert "counterexample" in last and "unsafe (boxes)" in last and "reachtube" in last
    assert "y: x1" in last
    # the counterexample starts at x0 and the plot's y range covers the tube and the trace
    trace = result.counterexample.trace
    top = float(text.plain.split("\n")[0].split("│")[0])
    assert top >= max(result.tube.upper[:, 0].max(), trace.x[:, 0].max())
    # time axis from 0 to the end of the tube
    xticks = text.plain.split("\n")[height].split()
    assert float(xticks[0]) == 0.0
    assert float(xticks[-1]) == pytest.approx(result.tube.t_end.max(), rel=1e-2)


def test_tube_time_text_second_state(unsafe_result):
    problem, result = unsafe_result
    text = tube_time_text(result, 60, 10, state=1, problem=problem)
    assert "y: x2" in text.plain
    assert _count(_pixels(text, 10), COLOURS["cex"]) > 0


def test_plane_text_with_a_counterexample(unsafe_result):
    problem, result = unsafe_result
    width, height = 80, 24
    text = plane_text(result, width, height, problem=problem)
    pix = _pixels(text, height)
    assert _count(pix, COLOURS["cex"]) > 20
    assert _count(pix, COLOURS["unsafe"]) > 0
    assert _count(pix, COLOURS["tube"]) > 0
    last = text.plain.split("\n")[-1]
    for word in ("reachtube", "unsafe", "initial set", "counterexample", "x: x1", "y: x2"):
        assert word in last
    # the counterexample reaches the unsafe box: some cex pixel is next to an unsafe pixel
    # or on it (drawn over it)
    cex = np.argwhere(pix == COLOURS["cex"])
    uns = np.argwhere(pix == COLOURS["unsafe"])
    d = np.abs(cex[:, None, :] - uns[None, :, :]).max(axis=2)
    assert d.min() <= 1


def test_plane_text_without_a_problem_names_axes_x0_x1(unsafe_result):
    _, result = unsafe_result
    text = plane_text(result, 40, 10)
    assert "x: x0" in text.plain and "y: x1" in text.plain
    assert "unsafe" not in text.plain.split("\n")[-1]


def test_safe_result_has_no_counterexample_colour(safe_result):
    problem, result = safe_result
    for text, h in (
        (tube_time_text(result, 70, 12, state=1, problem=problem), 12),
        (plane_text(result, 70, 12, problem=problem), 12),
    ):
        pix = _pixels(text, h)
        assert _count(pix, COLOURS["cex"]) == 0
        assert _count(pix, COLOURS["tube"]) > 0
        assert "counterexample" not in text.plain


def test_plane_text_tube_pixels_are_inside_the_hull(safe_result):
    problem, result = safe_result
    width, height = 60, 20
    text = plane_text(result, width, height, problem=problem)
    pix = _pixels(text, height)
    tube = result.tube
    xl = (tube.lower[:, 0].min(), tube.upper[:, 0].max())
    yl = (tube.lower[:, 1].min(), tube.upper[:, 1].max())
    # the axis ticks give the limits: recompute the view as plane_text does
    from workbench.tui.raster import nice_limits

    vs = problem.verify
    xlim = nice_limits(min(xl[0], vs.initial_lower[0]), max(xl[1], vs.initial_upper[0]))
    ylim = nice_limits(min(yl[0], vs.initial_lower[1]), max(yl[1], vs.initial_upper[1]))
    xs, ys = _centres(xlim, ylim, width, height)
    cw = (xlim[1] - xlim[0]) / width
    rh = (ylim[1] - ylim[0]) / (2 * height)
    for q, c in np.argwhere(pix == COLOURS["tube"]):
        assert xl[0] - cw <= xs[c] <= xl[1] + cw
        assert yl[0] - rh <= ys[q] <= yl[1] + rh


def test_empty_tube():
    result = ce.VerificationResult("unsafe", "undefined", ce.Tube.empty(2), "zoh")
    assert tube_time_text(result, 30, 5).plain == "(empty reachtube)"
    assert plane_text(result, 30, 5).plain == "(nothing to draw)"


# --------------------------------------------------------------------------------------------
# Time series
# --------------------------------------------------------------------------------------------


def test_series_text_lines_and_legend():
    t = np.linspace(0.0, 4.0, 41)
    Y = np.column_stack([np.sin(t), 2 * np.cos(t)])
    width, height = 60, 15
    text = series_text(t, Y, ("s", "c"), width, height)
    lines = text.plain.split("\n")
    assert len(lines) == height + 2
    assert "■ s" in lines[-1] and "■ c" in lines[-1] and "x: t (s)" in lines[-1]
    pix = _pixels(text, height)
    blue, orange = "#4e79a7", "#f28e2b"
    assert _count(pix, blue) > width // 2 and _count(pix, orange) > width // 2
    # the second series (drawn last) is at its samples
    ylim = (float(lines[height - 1].split("│")[0]), float(lines[0].split("│")[0]))
    assert ylim[0] < -1.9 and ylim[1] > 1.9


def test_series_text_one_series_hits_its_samples():
    t = np.arange(11) * 0.5
    y = np.array([0.0, 1, 3, 2, 5, 4, 4, 1, -2, -1, 0])
    width, height = 47, 12  # no sample on a pixel boundary
    text = series_text(t, y[:, None], ("y",), width, height)
    pix = _pixels(text, height)
    from workbench.tui.raster import nice_limits

    xlim = nice_limits(t.min(), t.max(), 0.0)
    ylim = nice_limits(y.min(), y.max())
    for tk, yk in zip(t[:-1], y[:-1], strict=True):  # t = 5 is the view's right edge
        c = int((tk - xlim[0]) / (xlim[1] - xlim[0]) * width)
        q = int((ylim[1] - yk) / (ylim[1] - ylim[0]) * 2 * height)
        assert pix[q, c] == "#4e79a7", (tk, yk)


def test_series_text_steps_nan_and_empty():
    t = np.arange(6.0)
    u = np.array([[1.0], [np.nan], [-1.0], [-1.0], [0.5], [0.5]])
    text = series_text(t, u, ("u",), 30, 8, steps=True)
    assert "■ u" in text.plain
    assert _count(_pixels(text, 8), "#4e79a7") > 10
    assert series_text(np.zeros(0), np.zeros((0, 1)), ("u",), 30, 8).plain == "(no data)"
    assert series_text(t, np.full((6, 1), np.nan), ("u",), 30, 8).plain == "(no data)"
    # a label missing: y<k>
    assert "■ y1" in series_text(t, np.ones((6, 2)), ("a",), 30, 8).plain


def test_plane_text_frames_an_unsafe_box_near_the_tube(safe_result):
    """Issue 23: an unsafe set just past the tube (p >= 1.5 while the tube ends at 1.16) is
    in the picture; one far away does not squash the tube."""
    from dataclasses import replace

    from codev_engine.spec.problem import SetSpec

    problem, result = safe_result
    hi = float(result.tube.upper[:, 0].max())
    lo = float(result.tube.lower[:, 0].min())
    near = hi + 0.3 * (hi - lo)
    box = SetSpec(
        kind="box", lower=np.array([near, -np.inf]), upper=np.array([np.inf, np.inf])
    )
    shown = replace(problem, verify=replace(problem.verify, unsafe=(box,)))
    width, height = 80, 24
    pix = _pixels(plane_text(result, width, height, problem=shown), height)
    assert _count(pix, COLOURS["unsafe"]) > 0
    far = replace(box, lower=np.array([hi + 1e6, -np.inf]))
    shown = replace(problem, verify=replace(problem.verify, unsafe=(far,)))
    pix = _pixels(plane_text(result, width, height, problem=shown), height)
    assert _count(pix, COLOURS["unsafe"]) == 0
    assert _count(pix, COLOURS["tube"]) > 0.02 * width * 2 * height


def test_plane_text_draws_the_invariance_certificate(di):
    # time_horizon = "inf": the set that closes the induction is outlined on the plane
    from dataclasses import replace

    problem, law = di
    text = DI.read_text(encoding="utf-8").replace("time_horizon = 9.0",
                                                  'time_horizon = "inf"')
    p = ce.loads_spec(text)
    result = ce.verify(p, law)
    assert result.reason == "invariant", result.summary()
    drawn = plane_text(result, 80, 24, problem=p)
    assert _count(_pixels(drawn, 24), COLOURS["certificate"]) > 0
    assert "invariant set" in drawn.plain.split("\n")[-1]
    bare = plane_text(replace(result, certificate=None), 80, 24, problem=p)
    assert _count(_pixels(bare, 24), COLOURS["certificate"]) == 0
    assert "invariant set" not in bare.plain


def test_plane_text_draws_the_invariant_ellipsoid_of_a_nonlinear_certificate():
    # the pendulum for all time: its certificate is an ellipsoid (not a polytope), outlined
    # on the plane like the polytope's set (not drawn before)
    import re
    from dataclasses import replace

    text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"',
                  (ROOT / "examples" / "pendulum.toml").read_text(encoding="utf-8"))
    p = ce.loads_spec(text)
    result = ce.verify(p, ce.synthesize(p))
    assert result.reason == "invariant" and "P" in result.certificate, result.summary()
    drawn = plane_text(result, 80, 24, problem=p)
    assert _count(_pixels(drawn, 24), COLOURS["certificate"]) > 0
    assert "invariant set" in drawn.plain.split("\n")[-1]
    bare = plane_text(replace(result, certificate=None), 80, 24, problem=p)
    assert _count(_pixels(bare, 24), COLOURS["certificate"]) == 0


def test_tube_time_text_after_a_certificate_shows_the_band_to_the_view_s_end():
    # cruise_grade ("inf"): the tube stops at 1 s; the band runs to the shown 25 s
    from codev_engine.reach.claim import certificate_band

    problem = ce.load_spec(ROOT / "examples" / "cruise_grade.toml")
    result = ce.verify(problem, ce.synthesize(problem))
    assert certificate_band(result) is not None
    plain = tube_time_text(result, 70, 12, problem=problem).plain
    assert "certificate band" in plain and plain.splitlines()[-2].rstrip().endswith("25")
