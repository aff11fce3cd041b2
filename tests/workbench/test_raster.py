"""The half-block raster (workbench/raster.py) against brute-force definitions."""

from __future__ import annotations

import warnings
from collections import deque

import numpy as np
import pytest
from textcells import decode_cells, decode_pixels, plot_body

from workbench.tui.raster import Raster, nice_limits, plot_text

# --------------------------------------------------------------------------------------------
# Boxes
# --------------------------------------------------------------------------------------------


def _brute_boxes(r: Raster, xlo, xhi, ylo, yhi) -> np.ndarray:
    """Pixel (q, c) is covered by a non-empty box iff the closed box meets the half-open
    pixel ``[c, c+1) x [q, q+1)`` in pixel coordinates (columns right, rows down)."""
    rows, cols = r.shape
    (x0, x1), (y0, y1) = r.xlim, r.ylim
    cover = np.zeros((rows, cols), bool)
    with np.errstate(invalid="ignore"):
        for a, b, lo, hi in zip(xlo, xhi, ylo, yhi, strict=True):
            if not (a <= b and lo <= hi):  # empty, or NaN
                continue
            ca = (a - x0) / (x1 - x0) * cols
            cb = (b - x0) / (x1 - x0) * cols
            ra = (y1 - hi) / (y1 - y0) * rows  # top edge
            rb = (y1 - lo) / (y1 - y0) * rows
            for q in range(rows):
                if not (ra < q + 1 and rb >= q):
                    continue
                for c in range(cols):
                    if ca < c + 1 and cb >= c:
                        cover[q, c] = True
    return cover


def _random_boxes(rng: np.random.Generator, k: int, xlim, ylim):
    def side(lim):
        lo, hi = lim
        w = hi - lo
        a = rng.uniform(lo - 0.6 * w, hi + 0.6 * w, k)
        b = a + rng.exponential(0.2 * w, k)
        kind = rng.integers(0, 12, k)
        b[kind == 0] = a[kind == 0]  # zero width
        a[kind == 1] = -np.inf
        b[kind == 2] = np.inf
        a[kind == 3] = np.nan
        b[kind == 4] = np.nan
        a[kind == 5], b[kind == 5] = b[kind == 5], a[kind == 5]  # lower > upper: empty
        a[kind == 6], b[kind == 6] = -np.inf, np.inf
        a[kind == 7] = lo - 1e12 * w  # far outside
        b[kind == 8] = hi + 1e12 * w
        far = kind == 9
        a[far], b[far] = hi + 2 * w, hi + 3 * w  # entirely outside
        return a, b

    xlo, xhi = side(xlim)
    ylo, yhi = side(ylim)
    return xlo, xhi, ylo, yhi


@pytest.mark.parametrize("seed", range(12))
def test_boxes_union_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    width, height = int(rng.integers(2, 40)), int(rng.integers(1, 16))
    x0 = rng.uniform(-10, 10)
    y0 = rng.uniform(-10, 10)
    xlim = (x0, x0 + rng.uniform(0.1, 20))
    ylim = (y0, y0 + rng.uniform(0.1, 20))
    k = int(rng.integers(1, 25))
    boxes = _random_boxes(rng, k, xlim, ylim)
    r = Raster(width, height, xlim, ylim)
    r.boxes(*boxes, colour="#123456")
    want = _brute_boxes(r, *boxes)
    np.testing.assert_array_equal(r.pixels >= 0, want)
    if want.any():
        assert r.colours == ["#123456"]
        assert (r.pixels[want] == 0).all()


def test_boxes_each_box_separately_then_union():
    rng = np.random.default_rng(99)
    xlim, ylim = (0.0, 1.0), (-1.0, 1.0)
    boxes = _random_boxes(rng, 200, xlim, ylim)
    whole = Raster(37, 11, xlim, ylim)
    whole.boxes(*boxes, colour="a")
    union = np.zeros(whole.shape, bool)
    for b in zip(*boxes, strict=True):
        one = Raster(37, 11, xlim, ylim)
        one.boxes(*([v] for v in b), colour="a")
        union |= one.pixels >= 0
    np.testing.assert_array_equal(whole.pixels >= 0, union)


def test_an_empty_box_does_not_erase_another():
    r = Raster(20, 5, (0.0, 20.0), (0.0, 10.0))
    r.boxes([2.0, 12.0], [10.0, 4.0], [1.0, 1.0], [9.0, 9.0], "a")  # 2nd: lower > upper
    ref = Raster(20, 5, (0.0, 20.0), (0.0, 10.0))
    ref.boxes([2.0], [10.0], [1.0], [9.0], "a")
    np.testing.assert_array_equal(r.pixels, ref.pixels)
    assert (r.pixels[1:, 2:11] >= 0).all()


def test_boxes_degenerate_inputs():
    r = Raster(10, 4, (0.0, 1.0), (0.0, 1.0))
    r.boxes([], [], [], [], "a")
    assert (r.pixels < 0).all()
    # a point box is one pixel
    r.boxes([0.55], [0.55], [0.55], [0.55], "a")
    assert (r.pixels >= 0).sum() == 1
    assert r.pixels[3, 5] >= 0  # row (1 - 0.55) * 8 = 3.6, column 5.5
    # the whole plane
    r.boxes([-np.inf], [np.inf], [-np.inf], [np.inf], "b")
    assert (r.pixels == r.colours.index("b")).all()


def test_boxes_are_fast():
    import time

    rng = np.random.default_rng(0)
    lo = rng.uniform(0, 1, (100_000, 2))
    hi = lo + rng.uniform(0, 0.01, (100_000, 2))
    r = Raster(150, 40, (0.0, 1.0), (0.0, 1.0))
    # CPU seconds of this process (vectorised: ~0.04 s), not the wall clock, which a loaded
    # machine stretches
    t = time.process_time()
    r.boxes(lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], "a")
    assert time.process_time() - t < 2.0
    assert (r.pixels >= 0).mean() > 0.9


# --------------------------------------------------------------------------------------------
# Polylines
# --------------------------------------------------------------------------------------------


def _connected(mask: np.ndarray) -> bool:
    """Whether the True pixels form one 8-connected component."""
    pts = list(zip(*np.nonzero(mask), strict=True))
    if not pts:
        return True
    seen = {pts[0]}
    todo = deque([pts[0]])
    on = set(pts)
    while todo:
        q, c = todo.popleft()
        for dq in (-1, 0, 1):
            for dc in (-1, 0, 1):
                nb = (q + dq, c + dc)
                if nb in on and nb not in seen:
                    seen.add(nb)
                    todo.append(nb)
    return len(seen) == len(on)


def _px(r: Raster, x, y) -> tuple[float, float]:
    (x0, x1), (y0, y1) = r.xlim, r.ylim
    rows, cols = r.shape
    return (x - x0) / (x1 - x0) * cols, (y1 - y) / (y1 - y0) * rows


def _dist_to_segment(p, a, b) -> float:
    p, a, b = (np.asarray(v, float) for v in (p, a, b))
    d = b - a
    t = 0.0 if not d.any() else float(np.clip(np.dot(p - a, d) / np.dot(d, d), 0, 1))
    return float(np.linalg.norm(p - (a + t * d)))


@pytest.mark.parametrize("seed", range(10))
def test_polyline_segments_are_connected_and_on_the_line(seed):
    rng = np.random.default_rng(100 + seed)
    xlim, ylim = (-1.0, 3.0), (0.0, 2.0)
    width, height = int(rng.integers(2, 60)), int(rng.integers(1, 20))
    k = int(rng.integers(2, 12))
    # points in and around the view (some far out)
    x = rng.uniform(-3.0, 5.0, k)
    y = rng.uniform(-1.0, 3.0, k)
    x[rng.random(k) < 0.1] *= 1e6
    whole = Raster(width, height, xlim, ylim)
    whole.polyline(x, y, "line")
    union = np.zeros(whole.shape, bool)
    for s in range(k - 1):
        r = Raster(width, height, xlim, ylim)
        r.polyline(x[s : s + 2], y[s : s + 2], "line")
        mask = r.pixels >= 0
        union |= mask
        assert _connected(mask), (seed, s)
        a, b = _px(r, x[s], y[s]), _px(r, x[s + 1], y[s + 1])
        rows, cols = r.shape
        for end in (a, b):  # an end inside the view is drawn
            if 0 <= end[0] < cols and 0 <= end[1] < rows:
                assert mask[int(end[1]), int(end[0])]
        for q, c in zip(*np.nonzero(mask), strict=True):  # every pixel touches the segment
            assert _dist_to_segment((c + 0.5, q + 0.5), a, b) <= 0.75, (seed, s, q, c)
        # a segment through the middle of the view is drawn across it
        if min(a[0], b[0]) < 0 and max(a[0], b[0]) > cols and max(a[1], b[1]) < rows:
            if min(a[1], b[1]) >= 0:
                assert set(np.nonzero(mask)[1]) == set(range(cols))
    np.testing.assert_array_equal(whole.pixels >= 0, union)


def test_polyline_inside_the_view_is_connected():
    rng = np.random.default_rng(5)
    r = Raster(80, 20, (0.0, 1.0), (0.0, 1.0))
    x, y = rng.uniform(0, 1, 50), rng.uniform(0, 1, 50)
    r.polyline(x, y, "a")
    assert _connected(r.pixels >= 0)


def test_long_polyline_is_connected():
    # many short segments (the vectorised resampling path)
    t = np.linspace(0, 10, 20_001)
    r = Raster(120, 30, (0.0, 10.0), (-1.1, 1.1))
    r.polyline(t, np.sin(3 * t), "a")
    mask = r.pixels >= 0
    assert _connected(mask)
    assert set(np.nonzero(mask)[1]) == set(range(120))  # every column


def test_polyline_to_a_far_point_draws_the_visible_part():
    r = Raster(20, 5, (0.0, 20.0), (0.0, 10.0))
    r.polyline([1.0, 1e9], [5.0, 5.0], "a")
    row = (10.0 - 5.0) / 10.0 * 10  # pixel row 5
    assert (r.pixels[int(row), 1:] >= 0).all()
    assert (r.pixels >= 0).sum() == 19


@pytest.mark.parametrize("seed", range(6))
def test_polyline_from_inside_to_far_away(seed):
    """The visible part of a segment to a far point is drawn up to the border."""
    rng = np.random.default_rng(200 + seed)
    r = Raster(int(rng.integers(5, 50)), int(rng.integers(3, 20)), (0.0, 1.0), (0.0, 1.0))
    rows, cols = r.shape
    for _ in range(20):
        start = rng.uniform(0.05, 0.95, 2)
        ang = rng.uniform(0, 2 * np.pi)
        end = start + 1e7 * np.array([np.cos(ang), np.sin(ang)])
        one = Raster(r.width, r.height, r.xlim, r.ylim)
        one.polyline([start[0], end[0]], [start[1], end[1]], "a")
        mask = one.pixels >= 0
        assert _connected(mask)
        a, b = np.array(_px(one, *start)), np.array(_px(one, *end))
        assert mask[int(a[1]), int(a[0])]
        # where the segment leaves the view (pixel coordinates)
        d = b - a
        with np.errstate(divide="ignore"):
            t = min(
                ((cols if d[0] > 0 else 0) - a[0]) / d[0] if d[0] else np.inf,
                ((rows if d[1] > 0 else 0) - a[1]) / d[1] if d[1] else np.inf,
            )
        exit_ = a + t * d
        assert mask.sum() >= np.floor(np.max(np.abs(exit_ - a))) - 1
        for q, c in zip(*np.nonzero(mask), strict=True):
            assert _dist_to_segment((c + 0.5, q + 0.5), a, exit_) <= 0.75


def test_polyline_diagonal_between_far_points():
    r = Raster(20, 10, (0.0, 20.0), (0.0, 20.0))  # square pixels
    r.polyline([-1e6, 1e6], [-1e6 + 0.5, 1e6 + 0.5], "a")
    mask = r.pixels >= 0
    assert _connected(mask)
    assert set(np.nonzero(mask)[1]) == set(range(20))
    assert set(np.nonzero(mask)[0]) == set(range(20))
    # through the pixel corners exactly: rounding must not break the line
    corner = Raster(20, 10, (0.0, 20.0), (0.0, 20.0))
    corner.polyline([-1e6, 1e6], [-1e6, 1e6], "a")
    assert _connected(corner.pixels >= 0)
    for k in range(1, 40):
        t = Raster(40, 20, (0.0, 40.0), (0.0, 40.0))
        t.polyline([0.0, 40.0], [0.0, 40.0 * k / 40], "a")
        assert _connected(t.pixels >= 0), k


def test_polyline_skips_non_finite_points_without_warnings():
    r = Raster(20, 5, (0.0, 20.0), (0.0, 10.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r.polyline([1.0, np.nan, 5.0, np.inf], [1.0, 2.0, 1.0, 3.0], "a")
        r.points([np.inf, -np.inf, np.nan, 3.0], [1.0, 1.0, 1.0, np.nan], "b")
        r.polyline([], [], "a")
        r.polyline([3.0], [3.0], "c")
    # the NaN point is dropped: (1, 1) -> (5, 1) is one horizontal line on pixel row 9
    assert (r.pixels[9, 1:6] == r.colours.index("a")).all()
    assert r.pixels[7, 3] == r.colours.index("c")
    assert "b" not in r.colours or not (r.pixels == r.colours.index("b")).any()


# --------------------------------------------------------------------------------------------
# paint, to_text, plot_text
# --------------------------------------------------------------------------------------------


def test_paint_colours_each_label():
    r = Raster(6, 2, (0.0, 1.0), (0.0, 1.0))
    labels = np.arange(24).reshape(4, 6) - 3  # -3..20
    palette = ("#000001", "#000002", "#000003", "#000004", "#000005")
    r.paint(labels, palette)
    for (q, c), lab in np.ndenumerate(labels):
        if lab < 0:
            assert r.pixels[q, c] == -1
        else:
            assert r.colours[r.pixels[q, c]] == palette[lab % len(palette)]
    rows = decode_pixels(r.to_text().split("\n"))
    for (q, c), lab in np.ndenumerate(labels):
        assert rows[q][c] == (None if lab < 0 else palette[lab % len(palette)])


@pytest.mark.parametrize(("w", "h"), [(2, 1), (7, 3), (40, 12), (1, 0)])
def test_to_text_has_h_lines_of_w_cells(w, h):
    rng = np.random.default_rng(w * 100 + h)
    r = Raster(w, h, (0.0, 1.0), (0.0, 1.0))
    W, H = r.width, r.height
    assert (W, H) == (max(w, 2), max(h, 1))
    r.paint(rng.integers(-2, 5, r.shape))
    text = r.to_text()
    lines = text.plain.split("\n")
    assert len(lines) == H
    assert all(len(line) == W for line in lines)
    # each cell shows its two pixels
    want = [[r.colours[p] if p >= 0 else None for p in row] for row in r.pixels]
    assert decode_pixels(text.split("\n")) == want


def test_to_text_characters_and_background():
    r = Raster(3, 1, (0.0, 1.0), (0.0, 1.0))
    r.pixels[0, 0] = r.colour("#ff0000")  # top only
    r.pixels[1, 1] = r.colour("#00ff00")  # bottom only
    text = r.to_text(background="#101010")
    assert text.plain == "▀▄ "
    cells = decode_cells(text)
    assert cells == [("#ff0000", "#101010"), ("#101010", "#00ff00"), ("#101010", "#101010")]


def test_plot_text_axes_and_legend():
    r = Raster(30, 6, (-2.0, 4.0), (10.0, 20.0))
    r.boxes([0.0], [1.0], [12.0], [15.0], "#abcdef")
    text = plot_text(r, xlabel="p", ylabel="v", legend=[("thing", "#abcdef")])
    lines = text.plain.split("\n")
    assert len(lines) == 6 + 2
    assert lines[0].split("│")[0].strip() == "20"
    assert lines[5].split("│")[0].strip() == "10"
    assert lines[6].split() == ["-2", "1", "4"]
    assert "x: p" in lines[7] and "y: v" in lines[7] and "■ thing" in lines[7]
    body = plot_body(text, 6)
    assert all(len(line.plain) == 30 for line in body)
    assert any("#abcdef" in row for row in decode_pixels(body))


@pytest.mark.parametrize(
    ("lo", "hi"),
    [(0.0, 1.0), (5.0, 5.0), (-np.inf, 1.0), (np.nan, 0.0), (3.0, -3.0), (0.0, 0.0), (1e9, 1e9)],
)
def test_nice_limits_are_finite_and_not_empty(lo, hi):
    a, b = nice_limits(lo, hi)
    assert np.isfinite(a) and np.isfinite(b) and a < b
    if np.isfinite(lo) and np.isfinite(hi) and lo <= hi:
        assert a <= lo and b >= hi


def test_a_tick_at_zero_within_rounding_reads_0():
    # issue 41: the preview's u axis read 4.99e-12 where it meant 0
    r = Raster(20, 5, (0.0, 1.0 + 1e-11), (-1.0, 1.0 + 1e-11))
    text = plot_text(r).plain
    assert "e-12" not in text and "e-11" not in text, text
    assert [ln.split("│")[0].strip() for ln in text.splitlines()[:5]] == ["1", "", "0", "", "-1"]
