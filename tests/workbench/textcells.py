"""Decode the half-block pictures of workbench/raster.py back into pixel colours (tests)."""

from __future__ import annotations

from rich.style import Style
from rich.text import Text


def _hex(colour) -> str | None:
    return None if colour is None else colour.triplet.hex if colour.triplet else colour.name


def cell_styles(line: Text) -> list[Style]:
    """The style of every character of one line of text (spans applied in order)."""
    styles = [Style() for _ in line.plain]
    for span in line.spans:
        st = span.style if isinstance(span.style, Style) else Style.parse(span.style)
        for k in range(span.start, min(span.end, len(styles))):
            styles[k] = styles[k] + st
    return styles


def decode_cells(line: Text) -> list[tuple[str | None, str | None]]:
    """(top, bottom) pixel colour (``#rrggbb``, None for the background) of every cell."""
    out = []
    for ch, st in zip(line.plain, cell_styles(line), strict=True):
        fg, bg = _hex(st.color), _hex(st.bgcolor)
        if ch == "▀":
            out.append((fg, bg))
        elif ch == "▄":
            out.append((bg, fg))
        elif ch == " ":
            out.append((bg, bg))
        else:
            raise AssertionError(f"unexpected character {ch!r} in a raster line")
    return out


def decode_pixels(lines: list[Text]) -> list[list[str | None]]:
    """The (2H, W) pixel colours of H raster lines."""
    rows: list[list[str | None]] = []
    for line in lines:
        cells = decode_cells(line)
        rows.append([t for t, _ in cells])
        rows.append([b for _, b in cells])
    return rows


def plot_body(text: Text, height: int) -> list[Text]:
    """The H raster lines of a ``plot_text`` picture, without the y-axis margin (and
    without a title line above it, as the partition's)."""
    lines = text.split("\n")
    while lines and "│" not in lines[0].plain:
        lines = lines[1:]  # the title
    assert len(lines) >= height, (len(lines), height)
    body = []
    for line in lines[:height]:
        bar = line.plain.index("│")
        body.append(line[bar + 1 :])
    return body


def colours_in(text: Text) -> set[str]:
    """Every foreground and background colour used in a text."""
    found = set()
    for line in text.split("\n"):
        for st in cell_styles(line):
            for c in (st.color, st.bgcolor):
                if c is not None:
                    found.add(_hex(c))
    return found
