"""What the pictures draw besides the states: the outputs ``y = C x`` and the reference.

Shared by the recordings (:mod:`codev_engine.view.record_content`) and the notebook and
report figures (:mod:`codev_engine.view.figures`), numpy only.

- :func:`output_names` -- ``y0, y1, ...`` for the rows of ``mpc.C`` (the names the law's
  reference parameters use, ``ref_y<i>``);
- :func:`output_boxes` -- a tube's boxes mapped through ``C`` interval-wise, rounded
  outward: every trajectory the tube contains has its output inside them;
- :func:`reference_band` -- what the design follows: a fixed value, or the box an unknown
  constant reference is verified in (``[verify] reference``, else ``[mpc.reference]``'s box).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover - typing only
    from codev_engine.spec.problem import Problem

__all__ = ["ReferenceBand", "output_bounds", "output_boxes", "output_names", "reference_band"]


def output_names(problem: Problem) -> tuple[str, ...]:
    """The outputs' names, ``y<i>`` for the rows of ``mpc.C`` (none without ``C``).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    tuple of str
        p names.
    """
    C = problem.mpc.C
    return () if C is None else tuple(f"y{i}" for i in range(np.asarray(C).shape[0]))


def output_boxes(
    C: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The image of boxes under ``y = C x``, interval-wise and rounded outward.

    ``y_lo = C⁺ lower + C⁻ upper`` and ``y_hi = C⁺ upper + C⁻ lower`` (``C⁺ = max(C, 0)``,
    ``C⁻ = min(C, 0)``): the exact interval hull of ``C x`` over each box, i.e. centre
    ``C c`` and radius ``|C| r``. Each side is then widened by ``(n + 2) ε |C| max(|lower|,
    |upper|)``, which bounds the rounding of the floating-point sums (ε the unit
    roundoff), so the boxes returned contain ``C x`` for every ``x`` in the boxes given.

    Parameters
    ----------
    C : (p, n) ndarray
    lower, upper : (K, n) ndarray
        The boxes (e.g. a tube's).

    Returns
    -------
    ylo, yhi : (K, p) ndarray
    """
    C = np.asarray(C, dtype=float)
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    Cp, Cm = np.maximum(C, 0.0), np.minimum(C, 0.0)
    ylo = lo @ Cp.T + hi @ Cm.T
    yhi = hi @ Cp.T + lo @ Cm.T
    with np.errstate(invalid="ignore"):
        err = (C.shape[1] + 2) * np.finfo(float).eps * (np.maximum(np.abs(lo), np.abs(hi))
                                                        @ np.abs(C).T)
    return ylo - err, yhi + err


def output_bounds(problem: Problem, k: int) -> list[tuple[str, float]]:
    """The finite bounds the MPC puts on output ``k``: ``("y_min" or "y_max" (with
    " (soft)" when that group is soft), value)``.

    Parameters
    ----------
    problem : Problem
    k : int
        The output's index.

    Returns
    -------
    list of (str, float)
    """
    mpc = problem.mpc
    out = []
    for side, v in (("y_min", mpc.y_min), ("y_max", mpc.y_max)):
        if v is not None and np.isfinite(v[k]):
            label = side + (" (soft)" if side in mpc.soft else "")
            out.append((label, float(v[k])))
    return out


@dataclass(frozen=True)
class ReferenceBand:
    """What the design follows, as drawn.

    Attributes
    ----------
    signal : str
        ``"x"`` (the states) or ``"y"`` (the outputs ``C x``).
    names : tuple of str
        The followed signals' names (the states, or ``y<i>``).
    lower, upper : (p,) ndarray
        The reference: equal for a fixed one; for a free reference the box of the unknown
        constant verified (``[verify] reference``, else the ``[mpc.reference]`` box).
    fixed : bool
        A fixed reference (one value).
    """

    signal: str
    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    fixed: bool


def reference_band(problem: Problem) -> ReferenceBand | None:
    """The reference a design follows (None: it regulates to the operating point).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    ReferenceBand or None
    """
    ref = problem.mpc.reference
    if ref is None:
        return None
    names = problem.plant.states if ref.signal == "x" else output_names(problem)
    if ref.value is not None:
        v = np.asarray(ref.value, dtype=float)
        return ReferenceBand(ref.signal, tuple(names), v.copy(), v.copy(), True)
    vs = problem.verify
    if vs is not None and vs.reference_lower is not None:
        lo, hi = vs.reference_lower, vs.reference_upper
    else:
        lo, hi = ref.lower, ref.upper
    return ReferenceBand(ref.signal, tuple(names), np.asarray(lo, dtype=float),
                         np.asarray(hi, dtype=float), False)
