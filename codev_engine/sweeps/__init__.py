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

import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from codev_engine.executor import Executor
from codev_engine.io.toml import dumps_toml
from codev_engine.kernel_cache import prepare
from codev_engine.sweeps.grid import (
    _value_rows,
    design_cost,
    design_id,
    design_texts,
    designs,
    grid_values,
    parse_sets,
    set_field,
)
from codev_engine.sweeps.rows import TIMING_FIELDS, design_row, report_row

__all__ = ["sweep", "parse_sets", "grid_values", "design_texts", "design_id", "design_row",
           "design_cost", "report_row",
           "set_field", "dumps_toml", "TIMING_FIELDS"]


def sweep(
    problem,
    grid: Mapping[str, Sequence[Any]],
    *,
    executor: Executor | None = None,
    progress: Callable[[int, dict], None] | None = None,
    session: str | os.PathLike | None = None,
    recording: bool = True,
    interrupt: Callable[[], None] | None = None,
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
    interrupt : callable, optional
        Called often while the designs run (serially: at each step of the current design's
        synthesis and verification; on a cluster: every 0.2 s while waiting): an exception
        it raises stops the sweep, the current design included, and propagates (a UI's
        cancel). The designs done keep their session folders; the sweep's table is not
        written.

    Returns
    -------
    list of dict
        One row per design, in the product's order: ``values`` (field -> value set),
        ``regions``, ``synthesis_seconds``, ``verdict``, ``reason``,
        ``verification_seconds``, ``tube_width_at_horizon`` ((n,) list, None where
        undefined), ``width_at_horizon_of`` (the set it is of), ``closed_loop_cost`` (see
        :func:`design_row`) and ``error`` (None, or the solver's message when synthesis
        or verification broke down: the fields not computed are then None).

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
                         recording=recording, interrupt=interrupt)
    # every design read by the loader before any runs
    loaded = designs(problem, grid)
    texts = [text for text, _ in loaded]
    cost_of = {text: design_cost(design) for text, design in loaded}
    if session is not None:
        from codev_engine.io.atomic import remove_stale
        from codev_engine.sweeps.folder import check_target

        check_target(session)
        # (what a killed sweep left in its folder: the temporaries of its manifest, journal
        # or recording no live writer holds; each design's session cleans its own as it runs)
        remove_stale(session)
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
    if executor.kind == "serial" and interrupt is not None:
        # in this process: the current design itself polls (a callable cannot travel to a
        # worker; there the executor polls while it waits)
        calls = [(*call, interrupt) for call in calls]
    # a fresh installation's kernels, announced, before the first design: no row's time
    # holds the compile (nor do the workers each compile them)
    prepare()
    started, t0 = _now(), time.perf_counter()
    done = dict(zip(unique, executor.map(
        design_row, calls, on_result=on_result, cost=[cost_of[text] for text in unique],
        interrupt=interrupt,
    ), strict=True))
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


def _now() -> str:
    from codev_engine.session.store import now

    return now()
