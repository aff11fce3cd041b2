"""A sweep's table: one design synthesised and verified (on a worker, or in its session
folder) and the row of outcomes it gives, from a run or from a session's report."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

from codev_engine.errors import SolverError

#: the row fields that are wall times (they differ run to run; everything else is exact)
TIMING_FIELDS = ("synthesis_seconds", "verification_seconds")


# -- one design (runs on a worker) ---------------------------------------------------------


def design_row(text: str, path: str, session: str | None = None,
               interrupt: Callable[[], None] | None = None) -> dict:
    """Synthesise and verify one design given as TOML text: its row of the sweep table.

    Parameters
    ----------
    text : str
        The design's TOML document (from :func:`design_texts`, so already checked).
    path : str
        The base spec's path, for messages.
    session : str, optional
        A session folder to run the design in (created if new): its cached stages are
        loaded, the others computed and cached; the wall times are then those recorded
        when each stage was computed.
    interrupt : callable, optional
        Called at each step of the synthesis and the verification (a region found, a
        sample or cell of the tube): an exception it raises stops the design there and
        propagates (how a sweep is cancelled mid-design; the stages already cached stay).

    Returns
    -------
    dict
        ``regions``, ``synthesis_seconds``, ``verdict``, ``reason``,
        ``verification_seconds``, ``tube_width_at_horizon`` ((n,) list of float or None),
        ``width_at_horizon_of`` (the set measured, ``reach.claim.width_at_end``'s ``which``;
        absent without a verification), ``closed_loop_cost`` and ``error`` (a solver's
        message, see :func:`sweep`). The closed-loop cost is that of the nominal
        trajectory from the centre of ``verify.initial_set``, simulated with the spec's
        hold over the verified horizon: the sum over the sample times ``k Ts < T`` of the
        MPC's stage cost in deviation from the operating point (``x'Qx + u'Ru`` for norm
        "2", ``||Qx|| + ||Ru||`` for norms "1" and "inf"); None when the law is undefined
        along the way. Without a ``[verify]`` section the verification fields are None.
    """
    from codev_engine.pipeline import loads_spec
    from codev_engine.synthesis import synthesize

    problem = loads_spec(text, path=path, check_mpc=False)
    row: dict[str, Any] = dict.fromkeys(
        ("regions", "synthesis_seconds", "verdict", "reason", "verification_seconds",
         "tube_width_at_horizon", "closed_loop_cost", "error")
    )  # fmt: skip
    if session is not None:
        return _session_row(problem, session, row, interrupt)
    t0 = time.perf_counter()
    try:
        law = synthesize(problem, progress=_step(interrupt))
    except SolverError as exc:
        row["error"] = str(exc)
        return row
    row["regions"] = int(law.num_regions)
    row["synthesis_seconds"] = round(time.perf_counter() - t0, 6)
    if problem.verify is None:
        return row
    from codev_engine.reach.verification import verify

    try:
        result = verify(problem, law, progress=_step(interrupt))
    except SolverError as exc:
        row["error"] = str(exc)
        return row
    return _verified_row(problem, law, result, row)


def _step(interrupt: Callable[[], None] | None) -> Callable[..., None] | None:
    """A progress callback (any arguments) that calls ``interrupt``; None without one."""
    if interrupt is None:
        return None
    return lambda *_args, **_kwargs: interrupt()


def _session_row(problem, folder: str, row: dict,
                 interrupt: Callable[[], None] | None = None) -> dict:
    from codev_engine.session import RunOptions, Session

    upto = "verification" if problem.verify is not None else "synthesis"
    report = Session.open_or_create(folder).run(
        problem, RunOptions(upto=upto), on_event=_step(interrupt), raise_errors=False
    )
    return report_row(problem, report, row)


def report_row(problem, report, row: dict | None = None) -> dict:
    """A design's row from a session run's report (a run, or a replayed run).

    Parameters
    ----------
    problem : Problem
        The design.
    report : RunReport
        The session's run of it (up to verification when it has ``[verify]``).
    row : dict, optional
        The row to fill (default: every field None).

    Returns
    -------
    dict
        As :func:`design_row`; the wall times are those recorded when each stage was
        computed.
    """
    if row is None:
        row = dict.fromkeys(
            ("regions", "synthesis_seconds", "verdict", "reason", "verification_seconds",
             "tube_width_at_horizon", "closed_loop_cost", "error")
        )  # fmt: skip
    failed = next((s for s in report.stages if s.status == "failed"), None)
    law, result = report.law, report.result
    if law is not None:
        row["regions"] = int(law.num_regions)
        row["synthesis_seconds"] = round(float(law.meta.get("seconds", 0.0)), 6)
    if failed is not None:
        row["error"] = str(failed.outcome.get("message", failed.outcome))
        return row
    if result is None:
        return row
    return _verified_row(problem, law, result, row)


def _verified_row(problem, law, result, row: dict) -> dict:
    from codev_engine.reach.claim import width_at_end

    row["verdict"] = result.verdict
    row["reason"] = result.reason
    row["verification_seconds"] = round(result.seconds, 6)
    # the set that holds the state at the view's end: the tube's boxes, or for "inf" the
    # certificate band (the same rule as codev verify), named: widths compare between
    # designs only when they are of the same kind of set
    _, width, which = width_at_end(problem, result)
    row["tube_width_at_horizon"] = [float(w) if math.isfinite(w) else None for w in width]
    row["width_at_horizon_of"] = which
    row["closed_loop_cost"] = closed_loop_cost(problem, law)
    return row


def closed_loop_cost(problem, law) -> float | None:
    """The MPC stage cost summed along the nominal closed loop from the initial set's centre.

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.
    law : ExplicitLaw
        Its explicit law.

    Returns
    -------
    float or None
        ``sum_k l(x_k - x_op, u_k - u_op)`` over the sample times ``k Ts`` before the
        verified horizon (:func:`~codev_engine.reach.simulate.shown_horizon` for ``inf``),
        ``l`` the stage cost of ``mpc.norm``; None when the law is undefined on the way.
    """
    import numpy as np

    from codev_engine.reach.simulate import shown_horizon, simulate, theta_initial_box

    lo, hi = theta_initial_box(problem)
    n = problem.plant.n
    centre = 0.5 * (lo + hi)
    T = shown_horizon(problem)
    Ts = float(problem.model.sample_time)
    # the output grid is the sample times (the cost's), the integration as tight as ever
    extra0 = centre[n:] if lo.size > n else None
    trace = simulate(problem, law, centre[:n], t_end=T, dt=Ts, extra0=extra0)
    if trace.undefined_at is not None:
        return None
    K = int(np.floor(T / Ts + 1e-9))
    idx = [int(np.argmin(np.abs(trace.t - k * Ts))) for k in range(K)]
    x_op = np.asarray(problem.model.x_op, dtype=float)
    u_op = np.asarray(problem.model.u_op, dtype=float)
    X = trace.x[idx] - (x_op if x_op.size else 0.0)
    U = trace.u[idx] - (u_op if u_op.size else 0.0)
    mpc = problem.mpc
    Q, R = np.asarray(mpc.Q, dtype=float), np.asarray(mpc.R, dtype=float)
    if mpc.norm == "2":
        cost = np.einsum("ki,ij,kj->", X, Q, X) + np.einsum("ki,ij,kj->", U, R, U)
    else:
        order = 1 if mpc.norm == "1" else np.inf
        cost = np.linalg.norm(X @ Q.T, ord=order, axis=1).sum()
        cost += np.linalg.norm(U @ R.T, ord=order, axis=1).sum()
    return float(cost)
