"""Design sweeps: the Cartesian product of spec values, each design synthesised and verified.

::

    import codev_engine as ce
    problem = ce.load_spec("examples/double_integrator.toml")
    rows = ce.sweep(problem, {"mpc.horizon": [2, 4, 6], "mpc.R": [[[0.1]], [[1.0]]]})

Each design is the spec's TOML document with the swept fields set (a dotted name, any field
of the spec), written back to TOML text and parsed by the normal loader
(:func:`codev_engine.pipeline.loads_spec`): a bad value is the loader's one-line
``SpecError`` naming the field, raised before any design runs. Nothing is evaluated.

The designs run on an :class:`~codev_engine.executor.Executor` (serial by default); a task
is the design's TOML text, parsed again on the worker, so what travels is text and the
rows that come back are plain JSON-able dicts. Rows are in the product's order (the first
field varies slowest), whatever the executor.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import time
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from codev_engine.errors import SolverError, SpecError
from codev_engine.executor import Executor

__all__ = ["sweep", "parse_sets", "grid_values", "design_texts", "design_id", "design_row",
           "report_row",
           "set_field", "dumps_toml", "TIMING_FIELDS"]

#: the row fields that are wall times (they differ run to run; everything else is exact)
TIMING_FIELDS = ("synthesis_seconds", "verification_seconds")


def sweep(
    problem,
    grid: Mapping[str, Sequence[Any]],
    *,
    executor: Executor | None = None,
    progress: Callable[[int, dict], None] | None = None,
    session: str | os.PathLike | None = None,
    recording: bool = True,
) -> list[dict]:
    """Synthesise and verify every design of a grid of spec values.

    Parameters
    ----------
    problem : Problem
        The base design (from ``load_spec``; its ``source`` TOML text is what is edited).
    grid : mapping of str to sequence
        Dotted spec field -> the values it takes (TOML values: numbers, strings, lists);
        the designs are the Cartesian product, the first field varying slowest.
    executor : Executor, optional
        What runs the designs; default ``Executor()``: serial in this process, or the
        cluster of ``$CODEV_SCHEDULER`` when set (connected to for this sweep only).
    progress : callable, optional
        Called as ``progress(i, row)`` in this process as design ``i`` finishes.
    session : path-like, optional
        A folder for the sweep: each design runs as a session (``codev_engine.session``) in
        ``session/<id>``, ``id`` the first 16 hex digits of the SHA-256 of its TOML text, so
        a rerun loads the stages of unchanged designs from their caches and ``codev replay
        session/<id>`` reproduces one. The folder is the sweep's own session
        (:mod:`codev_engine.sweeps.folder`): ``sweep.json`` lists the grid, the designs and
        their rows, ``journal.jsonl`` each sweep run, ``sweep.rrd`` is its Rerun recording;
        ``codev replay session`` replays the whole sweep. The folders must be on a disk
        every worker sees.
    recording : bool
        With ``session``: also write the sweep's Rerun recording ``session/sweep.rrd``.

    Returns
    -------
    list of dict
        One row per design, in the product's order: ``values`` (field -> value set),
        ``regions``, ``synthesis_seconds``, ``verdict``, ``reason``,
        ``verification_seconds``, ``tube_width_at_horizon`` ((n,) list, None where
        undefined), ``closed_loop_cost`` (see :func:`design_row`) and ``error`` (None, or
        the solver's message when synthesis or verification broke down: the fields not
        computed are then None).

    Raises
    ------
    SpecError
        A value the loader rejects (naming the design's values and the field), an empty
        grid field, or a name that is not a spec field; ``session`` a folder that is not a
        sweep's (a design's session, or a folder holding something else).
    """
    if executor is None:  # serial, or $CODEV_SCHEDULER's cluster: closed when done
        with Executor() as own:
            return sweep(problem, grid, executor=own, progress=progress, session=session,
                         recording=recording)
    texts = design_texts(problem, grid)  # every design read by the loader before any runs
    if session is not None:
        from codev_engine.sweeps.folder import check_target

        check_target(session)
    values = _value_rows(grid)
    # equal designs (a value listed twice) run once: one task, one session folder
    unique = list(dict.fromkeys(texts))
    where: dict[str, list[int]] = {}
    for i, text in enumerate(texts):
        where.setdefault(text, []).append(i)
    folders = None
    if session is not None:
        root = Path(session)
        folders = {text: str(root / design_id(text)) for text in unique}

    def on_result(j: int, row: dict) -> None:
        if progress is not None:
            for i in where[unique[j]]:  # each design of the grid reported, equal ones too
                progress(i, {"values": values[i], **row})

    path = problem.path or "<string>"
    calls = [(text, path, None if folders is None else folders[text]) for text in unique]
    started, t0 = _now(), time.perf_counter()
    done = dict(zip(unique, executor.map(design_row, calls, on_result=on_result), strict=True))
    rows = [{"values": v, **done[text]} for v, text in zip(values, texts, strict=True)]
    if session is not None:
        from codev_engine.sweeps.folder import record_sweep

        record_sweep(
            session, spec=path, base_text=problem.source, grid=grid, values=values,
            texts=texts, rows=rows, started=started, seconds=time.perf_counter() - t0,
            executor=executor.kind, workers=executor.workers, recording=recording,
            title=problem.name,
        )
    return rows


def parse_sets(items: Sequence[str], *, origin: str = "--set") -> dict[str, list]:
    """``FIELD=V1,V2,...`` texts -> the grid ``{field: [values]}``, each value a TOML value.

    Parameters
    ----------
    items : sequence of str
        One swept field each: ``mpc.horizon=2,4,6``, ``mpc.R=[[0.1]],[[1.0]]``,
        ``mpc.norm="inf","1"``.
    origin : str
        Where the texts came from, named in errors (``--set``, a form field).

    Returns
    -------
    dict of str to list
        In the order given (the first field varies slowest in the sweep).

    Raises
    ------
    SpecError
        A text without ``=`` or a name, a field given twice, values that are not a list of
        TOML values, or no values; one line naming the field.
    """
    grid: dict[str, list] = {}
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise SpecError(f"expected FIELD=V1,V2,... got {item!r}", field=origin)
        if name in grid:
            raise SpecError("set twice", field=f"{origin} {name}")
        try:
            values = tomllib.loads(f"v = [{text}]")["v"]
        except tomllib.TOMLDecodeError:
            raise SpecError(
                f"not a list of TOML values: {text!r} (strings need quotes: '\"a\",\"b\"')",
                field=f"{origin} {name}",
            ) from None
        if not values:
            raise SpecError("no values", field=f"{origin} {name}")
        grid[name] = values
    return grid


def design_id(text: str) -> str:
    """The name of a design's session folder: 16 hex digits of the SHA-256 of its text.

    Parameters
    ----------
    text : str
        The design's TOML document.

    Returns
    -------
    str
    """
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _now() -> str:
    from codev_engine.session.store import now

    return now()


def grid_values(grid: Mapping[str, Sequence[Any]]) -> list[dict]:
    """Each design's swept values, in the sweep's order (the first field varies slowest).

    Parameters
    ----------
    grid : mapping of str to sequence

    Returns
    -------
    list of dict
    """
    return _value_rows(grid)


def _value_rows(grid: Mapping[str, Sequence[Any]]) -> list[dict]:
    names = list(grid)
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*grid.values())]


def design_texts(problem, grid: Mapping[str, Sequence[Any]]) -> list[str]:
    """The TOML text of every design of ``grid``, each checked by the loader.

    Parameters
    ----------
    problem : Problem
        The base design; its ``source`` is the TOML text edited.
    grid : mapping of str to sequence
        As :func:`sweep`.

    Returns
    -------
    list of str
        One TOML document per design, in the product's order.

    Raises
    ------
    SpecError
        As :func:`sweep`.
    """
    from codev_engine.pipeline import loads_spec

    base = tomllib.loads(problem.source)
    file = problem.path or "<string>"
    for name, vals in grid.items():
        if isinstance(vals, (str, bytes)) or not isinstance(vals, Sequence) or not len(vals):
            raise SpecError("a swept field needs a non-empty list of values", file=file,
                            field=name)
        for v in vals:
            try:
                _inline(v)
            except SpecError as exc:
                raise SpecError(exc.reason, file=file, field=name) from None
    texts = []
    for values in _value_rows(grid):
        data = json.loads(json.dumps(base))  # a deep copy of plain TOML data
        for name, value in values.items():
            set_field(data, name, value)
        text = dumps_toml(data)
        label = ", ".join(f"{k} = {_inline(v)}" for k, v in values.items())
        loads_spec(text, path=f"{file} [{label}]")  # the loader's checks, one line each
        texts.append(text)
    return texts


def set_field(data: dict, name: str, value: Any) -> None:
    """Set the dotted field ``name`` of a parsed TOML document to ``value`` (in place).

    Parameters
    ----------
    data : dict
        From ``tomllib.loads``.
    name : str
        ``table.key`` or deeper (``verify.initial_set.lower``); missing tables are made.
    value : object
        A TOML value.

    Raises
    ------
    SpecError
        An empty part of the name, or a part that is a value, not a table.
    """
    parts = name.split(".")
    if not all(p.strip() for p in parts):
        raise SpecError("not a dotted field name", field=name)
    node = data
    for i, part in enumerate(parts[:-1]):
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise SpecError("is a value, not a table", field=".".join(parts[: i + 1]))
        node = nxt
    node[parts[-1]] = value


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Write parsed TOML data back as a TOML document (``tomllib.loads`` reads it equal).

    Parameters
    ----------
    data : mapping
        Strings, booleans, integers, floats (inf and nan included), lists and tables, as
        ``tomllib.loads`` gives them (dates are not used by specs and are refused).

    Returns
    -------
    str
        Top-level values first, then one ``[table]`` per top-level table, the values in
        it inline.

    Raises
    ------
    SpecError
        A value TOML cannot hold.
    """
    lines = [f"{_key(k)} = {_inline(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"\n[{_key(k)}]")
            lines.extend(f"{_key(k2)} = {_inline(v2)}" for k2, v2 in v.items())
    return "\n".join(lines) + "\n"


def _key(k: str) -> str:
    return k if _BARE_KEY.match(k) else json.dumps(k)


def _inline(v: Any) -> str:
    if hasattr(v, "tolist") and not isinstance(v, (list, dict)):
        v = v.tolist()  # numpy scalars and arrays as Python values
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # JSON's escapes are TOML's basic-string escapes
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_inline(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_inline(x)}" for k, x in v.items()) + "}"
    raise SpecError(f"not a TOML value: {type(v).__name__}")


# -- one design (runs on a worker) ---------------------------------------------------------


def design_row(text: str, path: str, session: str | None = None) -> dict:
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

    Returns
    -------
    dict
        ``regions``, ``synthesis_seconds``, ``verdict``, ``reason``,
        ``verification_seconds``, ``tube_width_at_horizon`` ((n,) list of float or None),
        ``closed_loop_cost`` and ``error`` (a solver's message, see :func:`sweep`). The
        closed-loop cost is that of the nominal
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
        return _session_row(problem, session, row)
    t0 = time.perf_counter()
    try:
        law = synthesize(problem)
    except SolverError as exc:
        row["error"] = str(exc)
        return row
    row["regions"] = int(law.num_regions)
    row["synthesis_seconds"] = round(time.perf_counter() - t0, 6)
    if problem.verify is None:
        return row
    from codev_engine.reach.verification import verify

    try:
        result = verify(problem, law)
    except SolverError as exc:
        row["error"] = str(exc)
        return row
    return _verified_row(problem, law, result, row)


def _session_row(problem, folder: str, row: dict) -> dict:
    from codev_engine.session import RunOptions, Session

    upto = "verification" if problem.verify is not None else "synthesis"
    report = Session.open_or_create(folder).run(
        problem, RunOptions(upto=upto), raise_errors=False
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
    from codev_engine.reach.simulate import shown_horizon

    row["verdict"] = result.verdict
    row["reason"] = result.reason
    row["verification_seconds"] = round(result.seconds, 6)
    T = shown_horizon(problem)
    if not math.isfinite(problem.verify.time_horizon) and result.tube.num_boxes:
        T = float(result.tube.t_end.max())
    row["tube_width_at_horizon"] = [
        float(w) if math.isfinite(w) else None for w in result.width_at(T)
    ]
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
