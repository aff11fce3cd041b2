"""Numbers drawn as line segments (a seven-segment stroke font), placed in data coordinates.

The Rerun viewer draws a point's label below the point, a dozen pixels down, whatever the
zoom: a tick label of the plane's vertical axis logged as a labelled point sits under its
tick (a tube read as crossing a line it does not cross). Strokes in data coordinates sit
where they are put at every size: the recording's tick labels are drawn with
:func:`text_strips`, centred on their ticks exactly.
"""

from __future__ import annotations

import numpy as np

__all__ = ["WIDTH", "text_strips"]

#: a character's advance, as a fraction of its height (the glyph is 0.55 wide)
WIDTH = 0.75
_W = 0.55

# the seven segments of a cell [0, _W] x [0, 1]: a top, b/c right, d bottom, e/f left, g middle
_SEG = {
    "a": ((0.0, 1.0), (_W, 1.0)),
    "b": ((_W, 1.0), (_W, 0.5)),
    "c": ((_W, 0.5), (_W, 0.0)),
    "d": ((0.0, 0.0), (_W, 0.0)),
    "e": ((0.0, 0.0), (0.0, 0.5)),
    "f": ((0.0, 0.5), (0.0, 1.0)),
    "g": ((0.0, 0.5), (_W, 0.5)),
}
_DIGITS = {
    "0": "abcdef", "2": "abged", "3": "abgcd", "4": "fgbc", "5": "afgcd",
    "6": "afgedc", "7": "abc", "8": "abcdefg", "9": "abcdfg", "-": "g", "e": "afged",
}
#: characters drawn otherwise: the decimal point (a short tick on the base line), plus
_OTHER = {
    ".": (((0.2, 0.0), (0.32, 0.0)), ((0.26, 0.0), (0.26, 0.1))),
    # a one in the middle of its cell (on the right edge it reads as a gap before it)
    "1": (((0.18, 0.85), (0.33, 1.0)), ((0.33, 1.0), (0.33, 0.0))),
    "+": (((0.05, 0.5), (0.5, 0.5)), ((0.275, 0.28), (0.275, 0.72))),
}


def text_strips(
    text: str,
    anchor: tuple[float, float],
    height: tuple[float, float],
    *,
    align: str = "right",
) -> list[np.ndarray]:
    """The strokes of ``text`` (digits, ``-``, ``.``, ``e``, ``+``; others leave a gap).

    Parameters
    ----------
    text : str
    anchor : (float, float)
        Where the text is put, in data coordinates: the middle of its right edge
        (``align="right"``) or of its top edge (``align="top"``).
    height : (float, float)
        The character height in data units along the horizontal and the vertical axis (a
        plane scaled to a square has different units on each: one height in the picture).
    align : {"right", "top"}

    Returns
    -------
    list of (2, 2) ndarray
        One segment per stroke; the strokes' vertical extent is centred on ``anchor[1]``
        for ``align="right"``.
    """
    hx, hy = float(height[0]), float(height[1])
    segs: list[tuple[tuple[float, float], tuple[float, float]]] = []
    for k, ch in enumerate(text):
        if ch in _DIGITS and ch not in _OTHER:
            strokes = [_SEG[s] for s in _DIGITS[ch]]
        else:
            strokes = list(_OTHER.get(ch, ()))
        segs += [((k * WIDTH + p[0], p[1]), (k * WIDTH + q[0], q[1])) for p, q in strokes]
    if not segs:
        return []
    P = np.array(segs, dtype=float)  # (s, 2 ends, 2): cell units, x right, y up in [0, 1]
    length = (len(text) - 1) * WIDTH + _W
    if align == "right":
        P[..., 0] = anchor[0] + (P[..., 0] - length) * hx
        P[..., 1] = anchor[1] + (P[..., 1] - 0.5) * hy
    elif align == "top":
        P[..., 0] = anchor[0] + (P[..., 0] - 0.5 * length) * hx
        P[..., 1] = anchor[1] + (P[..., 1] - 1.0) * hy
    else:
        raise ValueError(f"align must be 'right' or 'top', got {align!r}")
    return list(P)
