"""Pictures in the terminal: a pixel raster drawn with half blocks.

A terminal cell shows two pixels stacked (``▀`` with a foreground and a background colour), so a
W×H-cell plot has W×2H pixels. Everything is filled into an integer colour-index image with
numpy (region membership on a pixel grid, box unions by 2-D prefix sums, polylines by
resampling), then turned into one ``rich.text.Text``. No Textual import: the widgets wrap it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rich.style import Style
from rich.text import Text

__all__ = ["PALETTE", "Raster", "nice_limits", "plot_text"]

#: Region colours (distinct on dark and light themes); index -1 is the background.
PALETTE: tuple[str, ...] = (
    "#4e79a7",
    "#f28e2b",
    "#59a14f",
    "#b07aa1",
    "#edc948",
    "#76b7b2",
    "#ff9da7",
    "#9c755f",
    "#8cd17d",
    "#86bcb6",
    "#d37295",
    "#a0cbe8",
)
#: Named colours for overlays.
COLOURS = {
    "tube": "#4e79a7",
    "tube2": "#a0cbe8",
    "unsafe": "#e15759",
    "safe": "#59a14f",
    "initial": "#edc948",
    "trace": "#ffffff",
    "cex": "#ff2d2d",
    "certificate": "#b07aa1",
    "marker": "#ffffff",
    "axis": "#777777",
}


def nice_limits(lo: float, hi: float, pad: float = 0.05) -> tuple[float, float]:
    """Padded, finite, non-empty axis limits for data in ``[lo, hi]``.

    Parameters
    ----------
    lo, hi : float
        The data's range. Not finite: ``(-1, 1)`` is used; empty or a single value: a
        small span around ``lo``.
    pad : float
        The margin on each side, as a fraction of ``hi - lo``.

    Returns
    -------
    tuple of (float, float)
        The lower and upper limits (lower < upper).
    """
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        lo, hi = -1.0, 1.0
    if hi <= lo:
        c = lo
        w = max(abs(c) * 0.1, 1e-6)
        return c - w, c + w
    w = hi - lo
    return lo - pad * w, hi + pad * w


@dataclass
class Raster:
    """A W×2H pixel image over the data box ``xlim × ylim``.

    Attributes
    ----------
    width : int
        W, the width in cells and pixels (at least 2).
    height : int
        H, the height in cells (at least 1): two pixel rows per cell.
    xlim, ylim : tuple of (float, float)
        The data box shown: the left and right, bottom and top limits.
    pixels : (2H, W) ndarray of int
        Colour per pixel: an index into ``colours``; -1 is the background. Row 0 is the top
        (``ylim[1]``).
    colours : list of str
        The colours used so far, in the order of first use.
    """

    width: int
    height: int
    xlim: tuple[float, float]
    ylim: tuple[float, float]

    def __post_init__(self) -> None:
        self.width = max(int(self.width), 2)
        self.height = max(int(self.height), 1)
        self.pixels = np.full((2 * self.height, self.width), -1, dtype=np.int16)
        self.colours: list[str] = []

    # ---- coordinates -----------------------------------------------------------------

    @property
    def shape(self) -> tuple[int, int]:
        """The pixel grid's shape, ``(2H, W)``."""
        return self.pixels.shape  # type: ignore[return-value]

    def centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Data coordinates of the pixel centres: x (W,), y (2H,) (top row first)."""
        rows, cols = self.shape
        x0, x1 = self.xlim
        y0, y1 = self.ylim
        xs = x0 + (np.arange(cols) + 0.5) * (x1 - x0) / cols
        ys = y1 - (np.arange(rows) + 0.5) * (y1 - y0) / rows
        return xs, ys

    def _col(self, x: np.ndarray) -> np.ndarray:
        x0, x1 = self.xlim
        return (np.asarray(x, dtype=float) - x0) / (x1 - x0) * self.shape[1]

    def _row(self, y: np.ndarray) -> np.ndarray:
        y0, y1 = self.ylim
        return (y1 - np.asarray(y, dtype=float)) / (y1 - y0) * self.shape[0]

    def colour(self, name: str) -> int:
        """Index of a colour in ``colours`` (added on first use).

        Parameters
        ----------
        name : str
            A colour as rich reads it (``"#4e79a7"``).

        Returns
        -------
        int
        """
        if name not in self.colours:
            self.colours.append(name)
        return self.colours.index(name)

    # ---- drawing ---------------------------------------------------------------------

    def paint(self, index: np.ndarray, palette: tuple[str, ...] = PALETTE) -> None:
        """Colour each pixel by an integer label (a critical region's index, say).

        Parameters
        ----------
        index : (2H, W) ndarray of int
            The label of each pixel; negative labels stay unpainted.
        palette : tuple of str
            The colours, cycled: label ``k`` gets ``palette[k % len(palette)]``.
        """
        index = np.asarray(index)
        ids = [self.colour(c) for c in palette]
        lut = np.asarray(ids, dtype=np.int16)
        ok = index >= 0
        self.pixels[ok] = lut[index[ok] % len(palette)]

    def boxes(
        self, xlo: np.ndarray, xhi: np.ndarray, ylo: np.ndarray, yhi: np.ndarray, colour: str
    ) -> None:
        """Fill the union of K axis-aligned boxes (each at least one pixel), vectorised.

        Coverage is counted with a 2-D difference array and prefix sums, so 1e5 boxes cost a
        few milliseconds. A box that is empty (a lower bound above its upper one, or NaN)
        or outside the view draws nothing.

        Parameters
        ----------
        xlo, xhi : (K,) array_like of float
            The boxes' left and right bounds (data coordinates).
        ylo, yhi : (K,) array_like of float
            The boxes' lower and upper bounds.
        colour : str
            The fill colour.
        """
        rows, cols = self.shape
        xlo, xhi = np.asarray(xlo, float), np.asarray(xhi, float)
        ylo, yhi = np.asarray(ylo, float), np.asarray(yhi, float)
        if xlo.size == 0:
            return
        with np.errstate(invalid="ignore"):
            c0 = np.floor(self._col(np.clip(xlo, *_wide(self.xlim))))
            c1 = np.floor(self._col(np.clip(xhi, *_wide(self.xlim))))
            r0 = np.floor(self._row(np.clip(yhi, *_wide(self.ylim))))
            r1 = np.floor(self._row(np.clip(ylo, *_wide(self.ylim))))
        keep = (c1 >= 0) & (c0 < cols) & (r1 >= 0) & (r0 < rows)
        # an empty box (lower > upper, or NaN) draws nothing; with the difference array it
        # would otherwise *subtract* coverage from the boxes it overlaps
        keep &= (xlo <= xhi) & (ylo <= yhi)
        keep &= np.isfinite(c0) & np.isfinite(c1) & np.isfinite(r0) & np.isfinite(r1)
        if not keep.any():
            return
        c0 = np.clip(c0[keep], 0, cols - 1).astype(int)
        c1 = np.clip(c1[keep], 0, cols - 1).astype(int)
        r0 = np.clip(r0[keep], 0, rows - 1).astype(int)
        r1 = np.clip(r1[keep], 0, rows - 1).astype(int)
        diff = np.zeros((rows + 1, cols + 1), dtype=np.int64)
        np.add.at(diff, (r0, c0), 1)
        np.add.at(diff, (r0, c1 + 1), -1)
        np.add.at(diff, (r1 + 1, c0), -1)
        np.add.at(diff, (r1 + 1, c1 + 1), 1)
        cover = diff.cumsum(axis=0).cumsum(axis=1)[:rows, :cols] > 0
        self.pixels[cover] = self.colour(colour)

    def outline(self, xlo: float, xhi: float, ylo: float, yhi: float, colour: str) -> None:
        """The border of one box (clipped to the view).

        Parameters
        ----------
        xlo, xhi : float
            The box's left and right bounds (data coordinates).
        ylo, yhi : float
            Its lower and upper bounds.
        colour : str
            The line colour.
        """
        xlo, xhi = _clip_span(xlo, xhi, self.xlim)
        ylo, yhi = _clip_span(ylo, yhi, self.ylim)
        if xlo > xhi or ylo > yhi:
            return
        self.polyline([xlo, xhi, xhi, xlo, xlo], [ylo, ylo, yhi, yhi, ylo], colour)

    def polyline(self, x: np.ndarray, y: np.ndarray, colour: str) -> None:
        """A line through the points (resampled so consecutive pixels touch).

        Each segment is first clipped to the view (with a one-pixel margin), so a segment
        to a far-away point still draws its visible part as a connected line; points that
        are not finite are dropped (the line joins their neighbours).

        Parameters
        ----------
        x, y : (K,) array_like of float
            The points, in data coordinates and in order.
        colour : str
            The line colour.
        """
        c = self._col(np.asarray(x, float).ravel())
        r = self._row(np.asarray(y, float).ravel())
        good = np.isfinite(c) & np.isfinite(r)
        c, r = c[good], r[good]
        if c.size <= 1:
            self.points_px(c, r, colour)
            return
        rows, cols = self.shape
        ca, cb, ra, rb = _clip_segments(c[:-1], c[1:], r[:-1], r[1:], cols, rows)
        if ca.size == 0:
            return
        # samples at most half a pixel apart on each axis (both ends included): consecutive
        # samples fall in the same or 8-adjacent pixels even when rounding moves a sample
        # that sits on a pixel corner
        steps = np.ceil(2 * np.maximum(np.abs(cb - ca), np.abs(rb - ra))).astype(int) + 1
        seg = np.repeat(np.arange(ca.size), steps)
        k = np.arange(seg.size) - np.repeat(np.cumsum(steps) - steps, steps)
        frac = k / np.maximum(np.repeat(steps, steps) - 1, 1)
        cc = ca[seg] + frac * (cb[seg] - ca[seg])
        rr = ra[seg] + frac * (rb[seg] - ra[seg])
        self.points_px(cc, rr, colour)

    def points(self, x: np.ndarray, y: np.ndarray, colour: str) -> None:
        """Single pixels at data points (points outside the view are skipped).

        Parameters
        ----------
        x, y : (K,) array_like of float
            The points, in data coordinates.
        colour : str
            The pixels' colour.
        """
        self.points_px(self._col(np.asarray(x, float)), self._row(np.asarray(y, float)), colour)

    def points_px(self, c: np.ndarray, r: np.ndarray, colour: str) -> None:
        """Single pixels at pixel coordinates (not finite or outside the grid: skipped).

        Parameters
        ----------
        c, r : (K,) array_like of float
            Column and row of each pixel (fractional: the pixel containing it; row 0 is the
            top).
        colour : str
            The pixels' colour.
        """
        rows, cols = self.shape
        c, r = np.asarray(c, float).ravel(), np.asarray(r, float).ravel()
        ok = np.isfinite(c) & np.isfinite(r)
        ok[ok] = (c[ok] >= 0) & (c[ok] < cols) & (r[ok] >= 0) & (r[ok] < rows)
        ci, ri = np.floor(c[ok]).astype(int), np.floor(r[ok]).astype(int)
        self.pixels[ri, ci] = self.colour(colour)

    # ---- output ----------------------------------------------------------------------

    def to_text(self, background: str | None = None) -> Text:
        """The image as half-block text (H lines of W cells).

        Parameters
        ----------
        background : str, optional
            The colour of unpainted pixels (None: the terminal's background).

        Returns
        -------
        rich.text.Text
        """
        text = Text(no_wrap=True, overflow="crop")
        styles: dict[tuple[int, int], Style] = {}
        bg = background
        for row in range(self.height):
            top = self.pixels[2 * row]
            bot = self.pixels[2 * row + 1]
            start = 0
            for col in range(1, self.width + 1):
                if col < self.width and top[col] == top[start] and bot[col] == bot[start]:
                    continue
                t, b = int(top[start]), int(bot[start])
                key = (t, b)
                if key not in styles:
                    styles[key] = self._style(t, b, bg)
                char = " " if t < 0 and b < 0 else ("▀" if t >= 0 else "▄")
                text.append(char * (col - start), styles[key])
                start = col
            if row < self.height - 1:
                text.append("\n")
        return text

    def _style(self, t: int, b: int, bg: str | None) -> Style:
        ct = self.colours[t] if t >= 0 else bg
        cb = self.colours[b] if b >= 0 else bg
        if t < 0 and b < 0:
            return Style(bgcolor=bg) if bg else Style()
        if t >= 0:
            return Style(color=ct, bgcolor=cb)
        return Style(color=cb, bgcolor=ct)


def _wide(lim: tuple[float, float]) -> tuple[float, float]:
    w = lim[1] - lim[0]
    return lim[0] - w, lim[1] + w


def _clip_segments(
    c0: np.ndarray, c1: np.ndarray, r0: np.ndarray, r1: np.ndarray, cols: int, rows: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Segments (pixel coordinates) clipped to the view plus a one-pixel margin
    (Liang-Barsky); segments that miss it are dropped."""
    t0 = np.zeros(c0.shape)
    t1 = np.ones(c0.shape)
    for p0, p1, lo, hi in ((c0, c1, -1.0, cols + 1.0), (r0, r1, -1.0, rows + 1.0)):
        d = p1 - p0
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (lo - p0) / d
            tb = (hi - p0) / d
        flat = d == 0
        enter = np.where(flat, np.where((p0 >= lo) & (p0 <= hi), 0.0, np.inf), np.minimum(ta, tb))
        leave = np.where(flat, np.where((p0 >= lo) & (p0 <= hi), 1.0, -np.inf), np.maximum(ta, tb))
        t0 = np.maximum(t0, enter)
        t1 = np.minimum(t1, leave)
    ok = t0 <= t1
    t0, t1 = t0[ok], t1[ok]
    c0, c1, r0, r1 = c0[ok], c1[ok], r0[ok], r1[ok]
    dc, dr = c1 - c0, r1 - r0
    return c0 + t0 * dc, c0 + t1 * dc, r0 + t0 * dr, r0 + t1 * dr


def _clip_span(lo: float, hi: float, lim: tuple[float, float]) -> tuple[float, float]:
    return max(lo, lim[0]), min(hi, lim[1])


def _tick(v: float, span: float = 0.0) -> str:
    """A tick's label; a value within rounding of 0 against the axis's ``span`` is "0" (the
    middle of [-1, 1 + 1e-11] read 4.99e-12 where the axis means 0)."""
    if abs(v) <= 1e-9 * abs(span):
        return "0"
    return f"{v:.3g}"


def plot_text(
    raster: Raster,
    *,
    xlabel: str = "",
    ylabel: str = "",
    legend: list[tuple[str, str]] | None = None,
    background: str | None = None,
) -> Text:
    """The raster with a y-axis (top, middle, bottom ticks), an x-axis and a legend line.

    Parameters
    ----------
    raster : Raster
        The picture (its limits label the axes).
    xlabel, ylabel : str
        The axes' names, in the caption (empty: left out).
    legend : list of (str, str), optional
        ``(name, colour)`` pairs shown after the caption.
    background : str, optional
        The colour of unpainted pixels (see :meth:`Raster.to_text`).

    Returns
    -------
    rich.text.Text
    """
    y0, y1 = raster.ylim
    ys = y1 - y0
    ticks = {0: _tick(y1, ys), raster.height // 2: _tick((y0 + y1) / 2, ys),
             raster.height - 1: _tick(y0, ys)}
    margin = max(len(s) for s in ticks.values()) + 1
    body = raster.to_text(background).split("\n")
    out = Text(no_wrap=True, overflow="crop")
    axis = Style(color=COLOURS["axis"])
    for i, line in enumerate(body):
        out.append(ticks.get(i, "").rjust(margin - 1) + "│", axis)
        out.append_text(line)
        out.append("\n")
    x0, x1 = raster.xlim
    xs = x1 - x0
    left, mid, right = _tick(x0, xs), _tick((x0 + x1) / 2, xs), _tick(x1, xs)
    w = raster.width
    row = [" "] * (w + 1)
    for pos, s in ((0, left), (w // 2 - len(mid) // 2, mid), (w - len(right), right)):
        for k, ch in enumerate(s):
            if 0 <= pos + k < len(row):
                row[pos + k] = ch
    out.append(" " * margin + "".join(row).rstrip(), axis)
    caption = "  ".join(
        p for p in (f"x: {xlabel}" if xlabel else "", f"y: {ylabel}" if ylabel else "") if p
    )
    if caption or legend:
        out.append("\n" + " " * margin)
        if caption:
            out.append(caption + "   ", axis)
        for name, colour in legend or []:
            out.append("■ ", Style(color=colour))
            out.append(name + "  ")
    return out
