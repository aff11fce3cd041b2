"""How far a stopped proof got: the margins of a partial reachtube to each property.

A verification stopped by its time budget (``[verify] time_budget``, ``codev verify
--budget``) is ``unknown``; what it proved is still worth saying. :func:`property_margins`
measures, over the tube explored so far, the smallest signed distance between its boxes and
each checked set (positive: every box keeps clear of the unsafe set / inside the safe set by
at least that much; negative: for an unsafe set, no row of the set separates some box from
it -- the box may meet it, a possible violation not yet decided -- and for a safe set some
box sticks out of it by that much), and the time where it is smallest. :func:`budget_detail` puts it
in words with how much of the horizon and of the initial set was proved.

The distances are along the sets' normalised rows (``normalize_rows``), so a positive margin
is a lower bound on the Euclidean distance from the boxes to an unsafe polytope (and on the
depth of the boxes inside a safe one).
"""

from __future__ import annotations

import numpy as np

from codev_engine.geometry.polytope import normalize_rows
from codev_engine.reach.tube import Tube
from codev_engine.spec.problem import Problem

__all__ = ["budget_detail", "property_margins"]


def _row_ranges(A: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, r) smallest and largest ``A_r x`` over each box ``[lo, hi]`` (N, n)."""
    Ap, An = np.maximum(A, 0.0), np.minimum(A, 0.0)
    return lo @ Ap.T + hi @ An.T, hi @ Ap.T + lo @ An.T


def property_margins(problem: Problem, tube: Tube) -> list[dict]:
    """The smallest signed distance of the tube's boxes to each checked set.

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.
    tube : Tube
        The (possibly partial) reachtube, N boxes.

    Returns
    -------
    list of dict
        One per ``[[verify.unsafe]]`` then ``[[verify.safe]]`` set: ``property``
        (``"unsafe set 0"``), ``margin`` (float; ``None`` for an empty tube or a box
        without finite bounds) and ``t`` (the start of the box where it is smallest).
    """
    vs = problem.verify
    out: list[dict] = []
    lo, hi = tube.lower, tube.upper
    for kind, sets in (("unsafe", vs.unsafe), ("safe", vs.safe)):
        for j, s in enumerate(sets):
            A, b = normalize_rows(*s.halfspaces())[:2]
            entry: dict = {"property": f"{kind} set {j}", "margin": None, "t": None}
            if tube.num_boxes and A.shape[0]:
                low, high = _row_ranges(A, lo, hi)
                with np.errstate(invalid="ignore"):
                    if kind == "unsafe":  # the box is clear of {A x <= b} past some row
                        gap = np.max(low - b[None, :], axis=1)
                    else:  # the box is inside {A x <= b}: the least slack of its rows
                        gap = np.min(b[None, :] - high, axis=1)
                if np.all(np.isfinite(gap)):
                    k = int(np.argmin(gap))
                    entry.update(margin=float(gap[k]), t=float(tube.t_start[k]))
            out.append(entry)
    return out


def budget_detail(problem: Problem, tube: Tube, stats: dict, stopped: str) -> str:
    """The ``detail`` of a verdict stopped by its time budget: where, and how far it got.

    Parameters
    ----------
    problem : Problem
    tube : Tube
        The tube explored so far.
    stats : dict
        The engine's counters: ``complete_until`` (every trajectory is in the tube up to
        this time), ``proved_share`` (the nonlinear engine: the share of the initial set
        proved for the whole horizon), ``stopped_cell`` (the nonlinear engine: the share
        of the initial set of the cell it stopped in, and the time its tube reached),
        ``margins`` (:func:`property_margins`).
    stopped : str
        The engine's words for where it stopped (time, sample period, region).

    Returns
    -------
    str
        One line.
    """
    T = float(problem.verify.time_horizon)
    words = [stopped]
    done = stats.get("complete_until")
    if done is not None and np.isfinite(T) and T > 0:
        words.append(f"the tube holds every trajectory up to t = {done:.6g} "
                     f"({100 * min(done / T, 1.0):.0f} % of the horizon)" if done > 0 else
                     "no stretch of the horizon is proved for every trajectory")
    share = stats.get("proved_share")
    if share is not None:
        words.append(f"{100 * min(share, 1.0):.1f} % of the initial set proved")
    cell = stats.get("stopped_cell")
    if cell is not None:
        words.append(f"the cell in progress ({100 * min(cell['share'], 1.0):.1f} % of the "
                     f"initial set) reached t = {cell['t']:.6g}, its tube kept")
    shown = [f"{m['property']} {m['margin']:+.3g} at t = {m['t']:.4g}"
             for m in stats.get("margins", []) if m["margin"] is not None]
    if shown:
        words.append("best margins so far (+: kept): " + ", ".join(shown))
    return "; ".join(words)
