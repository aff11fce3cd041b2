"""The nonlinear engine over pieces of the uncertain parameters' box (issue 38).

A parameter is constant during a run, so the closed loop under a parameter box is the union
of the closed loops under the pieces of any partition of the box: a tube per piece, taken
together, holds every trajectory, and a verdict proved on every piece holds for the box.
Splitting is exact (unlike splitting a disturbance's box, whose signal may switch between
pieces). The nonlinear engine's tube carries the parameters' first-order part about their
nominal values and bounds the rest -- the parameters' deviation times the set's and the
inputs' spread, a bilinear term -- in its remainder ball; on a piece both shrink with the
piece's width, about the piece's own midpoint (docs/verification.md, "Splitting the
parameter box").

Policy: the whole box first (no cost where it proves); a piece whose proof fails for want of
precision (a possible violation, an enclosure, ``max_depth``) is cut into ``FACTOR`` equal
pieces along the parameter whose first-order forcing over the initial set and input box
dominates, while the pieces stay within ``MAX_PIECES``; a concrete violation, a limit or
the time budget ends the splitting.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from codev_engine.limits import time_over
from codev_engine.reach.tube import Tube
from codev_engine.spec.problem import Problem

__all__ = ["FACTOR", "MAX_PIECES", "split_axis", "split_run"]

#: pieces a failed piece is cut into along one parameter
FACTOR = 8
#: at most this many pieces of the parameter box (each a full run of the engine)
MAX_PIECES = 16
# findings that a narrower parameter box may clear (a possible violation, no concrete state)
_IMPRECISE = {"unsafe", "safe", "input_bounds", "undefined", "max_depth", "enclosure"}


def sub_problem(problem: Problem, lower: np.ndarray, upper: np.ndarray) -> Problem:
    """``problem`` with the parameter box ``[lower, upper]`` (a piece of its own).

    The nominal values (about which the engine linearises the parameters' forcing) become
    the piece's midpoints; the law is the caller's, designed for the whole box.

    Parameters
    ----------
    problem : Problem
        With ``plant.parameters``.
    lower, upper : (d,) ndarray
        The piece, inside the problem's parameter box.

    Returns
    -------
    Problem
    """
    pp = problem.plant.parameters
    lo, hi = np.asarray(lower, float).copy(), np.asarray(upper, float).copy()
    par = replace(pp, lower=lo, upper=hi, nominal=0.5 * (lo + hi))
    return replace(problem, plant=replace(problem.plant, parameters=par))


def split_axis(problem: Problem, lower: np.ndarray, upper: np.ndarray) -> int:
    """The parameter whose first-order forcing dominates on the piece ``[lower, upper]``.

    The score of parameter ``j`` is ``max |df/dp_j| r_j`` per state, over the corners of the
    initial set and of the input bounds (disturbances and other parameters at their
    nominal values), each state scaled by the initial set's width in it, summed over the
    states. A heuristic: it chooses the cut, soundness does not depend on it.

    Parameters
    ----------
    problem : Problem
    lower, upper : (d,) ndarray
        The piece of the parameter box.

    Returns
    -------
    int
        The parameter's index.
    """
    import sympy

    from codev_engine.plant import full_field

    d = int(np.size(lower))
    r = 0.5 * (np.asarray(upper, float) - np.asarray(lower, float))
    if d == 1:
        return 0
    pl, vs = problem.plant, problem.verify
    f, xs, us, ws, ps = full_field(pl)
    jac = sympy.lambdify((*xs, *us, *ws, *ps), f.jacobian(sympy.Matrix(ps)), modules="numpy")
    xlo, xhi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    u0 = np.asarray(problem.model.u_op, float)
    ucorners = [u0]
    if problem.mpc is not None:
        ulo, uhi = np.asarray(problem.mpc.u_min, float), np.asarray(problem.mpc.u_max, float)
        if np.all(np.isfinite(ulo)) and np.all(np.isfinite(uhi)):
            ucorners = list(itertools.islice(itertools.product(*zip(ulo, uhi, strict=True)), 16))
    xcorners = list(itertools.islice(itertools.product(*zip(xlo, xhi, strict=True)), 64))
    w = np.asarray(pl.disturbances.nominal, float) if pl.disturbances is not None else []
    p = 0.5 * (np.asarray(lower, float) + np.asarray(upper, float))
    scale = np.maximum(xhi - xlo, 1e-9)
    best = np.zeros((pl.n, d))
    for x, u in itertools.product(xcorners, ucorners):
        try:
            J = np.abs(np.asarray(jac(*x, *u, *w, *p), float).reshape(pl.n, d))
        except (ValueError, ZeroDivisionError, OverflowError, TypeError):
            continue
        best = np.maximum(best, np.where(np.isfinite(J), J, 0.0))
    score = (best * r[None, :] / scale[:, None]).sum(axis=0)
    return int(np.argmax(score))


def split_run(
    problem: Problem,
    law,
    hold: str,
    depth: int,
    progress: Callable[[dict], None] | None,
    executor,
    cells: int,
) -> tuple[list, list[Tube], dict, np.ndarray, np.ndarray]:
    """The nonlinear engine over the parameter box, failed pieces split (module docstring).

    Parameters
    ----------
    problem : Problem
        A nonlinear plant; with ``plant.parameters`` for any splitting to happen.
    law : ExplicitLaw
    hold : {"zoh", "continuous"}
    depth : int
        The engine's refinement budget (per piece).
    progress : callable or None
        The engine's progress callback; from the second run on, the earlier runs'
        counters (``branches``, ``boxes``, ...: explored, failed pieces included) are
        added, so they never go back, and ``parameter_run`` says which run (from 1).
    executor : Executor or None
    cells : int
        As for :func:`codev_engine.reach.verification.verify`.

    Returns
    -------
    findings : list of Finding
        Of the kept pieces.
    tubes : list of Tube
        Of the kept pieces, branch numbers offset so that they stay distinct.
    stats : dict
        The engine's counters summed over every piece run (``proved_share`` weighted by
        the pieces' share of the box), with ``parameter_pieces`` (pieces kept) and
        ``parameter_runs`` (engine runs).
    c0, V0 : (n,) ndarray, (n, n) ndarray
        The initial box's centre and half-widths (the findings' ``alpha`` coordinates).
    """
    from codev_engine.reach.nonlinear import NonlinearReach

    pp = problem.plant.parameters
    queue: list[tuple[np.ndarray, np.ndarray]] = [(None, None)]  # the whole box first
    kept: list[tuple[list, Tube | list[Tube], float]] = []
    stats: dict = {}
    runs = boxes = 0
    c0 = V0 = None
    total = float(np.prod(np.maximum(pp.upper - pp.lower, 1e-300))) if pp is not None else 1.0
    while queue:
        lo, hi = queue.pop(0)
        sub = problem if lo is None else sub_problem(problem, lo, hi)
        report = progress
        if progress is not None and runs:
            report = _cumulative(progress, {**stats, "boxes": boxes}, runs + 1)
        eng = NonlinearReach(sub, law, hold, depth, progress=report)
        with np.errstate(all="ignore"):  # an overflow is checked on the tube by the caller
            eng.run(executor, cells=cells)
        runs += 1
        boxes += int(getattr(eng, "boxes", 0))
        c0, V0 = eng.c0, eng.V0
        for key, val in eng.stats.items():
            if key == "proved_share":
                continue
            if isinstance(val, (int, float)) and not isinstance(val, bool):
                stats[key] = stats.get(key, 0) + val
            else:
                stats.setdefault(key, val)
        share = 1.0
        if pp is not None:
            plo = pp.lower if lo is None else lo
            phi = pp.upper if hi is None else hi
            share = float(np.prod(np.maximum(phi - plo, 1e-300))) / total
        if "proved_share" in eng.stats:
            stats["proved_share"] = stats.get("proved_share", 0.0) + share * float(
                eng.stats["proved_share"]
            )
        findings = list(eng.findings)
        imprecise = bool(findings) and all(
            f.alpha is None and f.kind in _IMPRECISE for f in findings
        )
        room = len(kept) + len(queue) + FACTOR <= MAX_PIECES
        if pp is not None and imprecise and room and time_over() is None:
            j = split_axis(problem, plo, phi)
            edges = np.linspace(plo[j], phi[j], FACTOR + 1)
            for a, b in itertools.pairwise(edges):
                nlo, nhi = np.array(plo, float), np.array(phi, float)
                nlo[j], nhi[j] = a, b
                queue.append((nlo, nhi))
            continue
        kept.append((findings, list(eng.tubes), share))
        if findings and not imprecise:
            # a concrete violation, a limit or the budget: the verdict is the caller's now
            # (the pieces not yet run have no tube; the tube's contract says so: an
            # unknown verdict names where it stopped)
            if lo is not None:  # (a piece of the box: its tube holds its parameters only)
                stats["complete_until"] = 0.0
            break
    out_findings: list = []
    out_tubes: list[Tube] = []
    offset = 0
    for findings, tubes, _ in kept:
        out_findings += findings
        top = 0
        for tb in tubes:
            if tb.num_boxes:
                out_tubes.append(replace(tb, branch=tb.branch + offset))
                top = max(top, int(tb.branch.max()) + 1)
        offset += top
    if pp is not None:
        stats["parameter_pieces"] = len(kept)
        stats["parameter_runs"] = runs
    return out_findings, out_tubes, stats, c0, V0


def _cumulative(progress: Callable[[dict], None], done: dict, run: int) -> Callable[[dict], None]:
    """``progress`` with the earlier pieces' counters added (so they never go back) and
    ``parameter_run``, the engine run counting from 1."""

    def report(counters: dict) -> None:
        out = dict(counters)
        for key, val in done.items():
            cur = out.get(key)
            if (isinstance(val, (int, float)) and not isinstance(val, bool)
                    and isinstance(cur, (int, float)) and not isinstance(cur, bool)
                    and key not in ("samples", "proved_share")):
                out[key] = cur + val
        out["parameter_run"] = run
        progress(out)

    return report
