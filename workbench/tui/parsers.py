"""Parsers of the panes' small inputs (a state, a pair of axes), shared by every pane.

Each turns the user's text into plain numbers or indices, or raises ``ValueError`` with a
message meant to be shown next to the input.
"""

from __future__ import annotations

import numpy as np

__all__ = ["parse_axes", "parse_state", "parse_state_name"]


def parse_state(text: str, n: int) -> np.ndarray:
    """A state typed as ``"1, -2"`` or ``"1 -2"`` (commas, semicolons or spaces).

    Parameters
    ----------
    text : str
        The user's entry.
    n : int
        The number of states expected.

    Returns
    -------
    (n,) ndarray of float

    Raises
    ------
    ValueError
        An entry that is not a number, the wrong count, or a value that is not finite.
    """
    parts = [p for p in text.replace(",", " ").replace(";", " ").split() if p]
    try:
        x = np.array([float(p) for p in parts])
    except ValueError:
        raise ValueError("expected numbers, e.g. 1.5, -2") from None
    if x.size != n:
        raise ValueError(f"expected {n} numbers, got {x.size}")
    if not np.all(np.isfinite(x)):
        raise ValueError("the state must be finite")
    return x


def parse_axes(text: str, names: tuple[str, ...]) -> tuple[int, int]:
    """Two plot axes typed as state names (``"x1, x2"``) or indices (``"0 1"``).

    Parameters
    ----------
    text : str
        The user's entry.
    names : tuple of str
        The plant's state names, in state order.

    Returns
    -------
    tuple of (int, int)
        Two distinct state indices.

    Raises
    ------
    ValueError
        Not two entries, an unknown state, or the same state twice.
    """
    parts = [p for p in text.replace(",", " ").split() if p]
    if len(parts) != 2:
        raise ValueError("give two states, e.g. " + ", ".join(names[:2]))
    out = []
    for p in parts:
        if p in names:
            out.append(names.index(p))
        elif p.isdigit() and int(p) < len(names):
            out.append(int(p))
        else:
            raise ValueError(f"unknown state {p!r} (states: {', '.join(names)})")
    if out[0] == out[1]:
        raise ValueError("the two axes must differ")
    return out[0], out[1]


def parse_state_name(text: str, names: tuple[str, ...]) -> int:
    """One state typed as a name (``"x1"``) or an index (``"0"``); empty means state 0.

    Parameters
    ----------
    text : str
        The user's entry.
    names : tuple of str
        The plant's state names, in state order.

    Returns
    -------
    int
        The state index.

    Raises
    ------
    ValueError
        An unknown state.
    """
    text = text.strip()
    if not text:
        return 0
    if text in names:
        return names.index(text)
    if text.isdigit() and int(text) < max(len(names), 1):
        return int(text)
    raise ValueError(f"unknown state {text!r} (states: {', '.join(names)})")
