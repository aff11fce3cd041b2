"""Rerun recordings (``.rrd``) of a design, for offline review in the Rerun viewer.

One file holds the law's partition, the specification's sets, the reachtube, simulated
closed-loop traces, the counterexample (if any), input and unsafe-margin time series, the
verdict, and a blueprint (the viewer layout). The entity layout is documented in
``docs/recordings.md``. This module writes and checks the file; what goes into it is
:mod:`codev_engine.view.record_content`'s, the viewer layout
:mod:`codev_engine.view.blueprint`'s.

The file is written atomically (a ``.tmp-*`` file in the same folder, then a rename), with a
private ``rerun.RecordingStream``: the global/thread-local rerun recordings and the global
strict mode are left as they were.
"""

from __future__ import annotations

import os
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.errors import CodevError, SpecError
from codev_engine.io.atomic import atomic_path, remove_stale_beside
from codev_engine.law import ExplicitLaw
from codev_engine.spec.problem import Problem
from codev_engine.view.blueprint import blueprint
from codev_engine.view.record_content import EntityWriter, RecordingContent, RecordingOptions

if TYPE_CHECKING:
    from codev_engine.reach.verification import VerificationResult

__all__ = ["RecordingOptions", "RecordingSummary", "write_recording", "check_recording"]

#: application id of every recording (the viewer groups recordings and blueprints by it)
APPLICATION_ID = "codev"


@dataclass(frozen=True)
class RecordingSummary:
    """What ``write_recording`` wrote.

    Attributes
    ----------
    path : Path
        The ``.rrd`` file.
    entities : dict of str to int
        Entity path -> number of instances logged (strips, boxes, meshed polytopes, scalar
        samples, documents; see ``docs/recordings.md``).
    boxes : int
        Tube boxes logged (``result.tube.num_boxes``, 0 without a result).
    traces : int
        Simulated traces logged (the counterexample not included).
    seconds : float
        Wall time of the whole call.
    """

    path: Path
    entities: dict[str, int] = field(default_factory=dict)
    boxes: int = 0
    traces: int = 0
    seconds: float = 0.0


# ---------------------------------------------------------------------------------------
# public API
# ---------------------------------------------------------------------------------------


def write_recording(
    path: str | os.PathLike,
    problem: Problem,
    law: ExplicitLaw,
    result: VerificationResult | None = None,
    *,
    options: RecordingOptions = RecordingOptions(),  # noqa: B008 - frozen, immutable
) -> RecordingSummary:
    """Write a Rerun recording of a design (and of its verification) to ``path``.

    Parameters
    ----------
    path : str or PathLike
        The ``.rrd`` file to write; parent folders are created; an existing file is
        replaced atomically.
    problem : Problem
        The spec. Without a ``[verify]`` section there are no sets and no traces.
    law : ExplicitLaw
        The explicit law (its n, m must be the problem's).
    result : VerificationResult, optional
        The outcome of ``verify``; None records the partition and the sets only (no tube).
    options : RecordingOptions

    Returns
    -------
    RecordingSummary

    Raises
    ------
    SpecError
        Bad ``options``, a ``path`` that does not end in ``.rrd``, or a law that does not
        fit the problem.
    CodevError
        Rerun is disabled in this environment (``RERUN=off``) or the file came out
        incomplete.
    """
    t0 = time.perf_counter()
    path = Path(path)
    if path.suffix != ".rrd":
        raise SpecError(
            f"a recording must be a .rrd file (got suffix {path.suffix!r})", file=str(path)
        )
    n = problem.plant.n
    full_law = law
    law, options = drawable(problem, law, options)
    if law.n != n or law.m != problem.plant.m:
        raise SpecError(
            f"the law has n={law.n}, m={law.m} but the spec has n={n}, m={problem.plant.m}",
            file=problem.path,
        )
    axes = _check_options(options, n)
    content = RecordingContent.build(problem, law, result, options, axes, trace_law=full_law)

    import rerun as rr
    from rerun.error_utils import catch_and_log_exceptions

    remove_stale_beside(path)  # (what a recording killed while writing left)
    with atomic_path(path) as tmp:  # temp file + fsync + rename, removed on failure
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4().hex)
        if not rec.is_enabled():
            raise CodevError(
                "rerun logging is disabled in this environment (RERUN=off); unset RERUN to "
                "write recordings"
            )
        try:
            rec.save(tmp)
            rec.send_recording_name(problem.name)
            # strict (raise, do not warn and drop) for this thread while logging; restored
            with catch_and_log_exceptions(context="codev recording", strict=True):
                writer = EntityWriter(rec)
                content.log(writer)
                _send_blueprint(writer, content)
            rec.flush()
        finally:
            rec.disconnect()
        if not _has_footer(tmp):
            raise CodevError(f"rerun wrote an incomplete recording for {path}")
    return RecordingSummary(
        path=path,
        entities=dict(writer.entities),
        boxes=content.tube_boxes,
        traces=content.num_traces,
        seconds=time.perf_counter() - t0,
    )


def check_recording(path: str | os.PathLike, *, deep: bool = True) -> None:
    """Check that ``path`` is a complete, readable Rerun recording.

    Parameters
    ----------
    path : str or PathLike
    deep : bool
        Also open it with Rerun's reader (about 0.4 s to import Rerun). Sessions pass False
        for a cached artifact whose bytes already match the SHA-256 recorded when it was
        written and checked: the header and footer checks then suffice.

    Raises
    ------
    SpecError
        (with ``file=str(path)``) the file is missing, not a regular file, not an ``.rrd``,
        truncated or incomplete (no footer, unreadable, or without a recording store).
    """
    file = str(path)
    p = Path(path)
    if not p.exists():
        raise SpecError("recording not found", file=file)
    if not p.is_file():
        raise SpecError("not a file", file=file)
    if p.suffix != ".rrd":
        raise SpecError(
            f"not a Rerun recording (expected a .rrd file, got {p.suffix!r})", file=file
        )
    try:
        with p.open("rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise SpecError(f"cannot read the file: {exc.strerror or exc}", file=file) from None
    if magic[:3] != b"RRF":
        raise SpecError("not a Rerun recording (no RRF header)", file=file)
    if not _has_footer(p):
        raise SpecError("incomplete recording (truncated: no RRD footer)", file=file)
    if not deep:
        return
    try:
        from rerun.chunk import RrdReader

        recordings = RrdReader(p).recordings()
    except Exception as exc:  # any reader failure means a bad file
        raise SpecError(f"unreadable recording ({type(exc).__name__}: {exc})", file=file) from None
    if not recordings:
        raise SpecError("the file holds no recording store", file=file)


# ---------------------------------------------------------------------------------------
# options, small helpers
# ---------------------------------------------------------------------------------------


def _check_options(options: RecordingOptions, n: int) -> tuple[int, int] | None:
    """Validate ``options`` for an n-state problem -> the plane axes (None when n == 1)."""
    traces = options.traces
    if isinstance(traces, bool) or not isinstance(traces, int | np.integer) or traces < 0:
        raise SpecError(f"must be an integer >= 0, got {traces!r}", field="traces")
    if n < 2:
        return None
    axes = tuple(options.axes)
    ok = len(axes) == 2 and all(
        isinstance(a, int | np.integer) and not isinstance(a, bool) for a in axes
    )
    if not ok:
        raise SpecError(f"expected two state indices, got {options.axes!r}", field="axes")
    i, j = int(axes[0]), int(axes[1])
    if i == j or not (0 <= i < n and 0 <= j < n):
        raise SpecError(
            f"expected two distinct state indices in 0..{n - 1}, got {options.axes!r}",
            field="axes",
        )
    return i, j


def _has_footer(path: Path) -> bool:
    from rerun_bindings import check_for_rrd_footer

    try:
        return bool(check_for_rrd_footer(str(path)))
    except Exception:  # unreadable is "no footer"
        return False


def _send_blueprint(w: EntityWriter, content: RecordingContent) -> None:
    """Send the viewer layout (after the data: it shows the views that have data)."""
    w.rec.send_blueprint(blueprint(w.entities, content))


def drawable(problem: Problem, law: ExplicitLaw, options: RecordingOptions
             ) -> tuple[ExplicitLaw, RecordingOptions]:
    """The law and options a picture of ``problem`` draws.

    For a law over ``theta = (x, u_prev, r)``: its section (:meth:`ExplicitLaw.section`) at
    the middle of the initial ``u_prev`` and ``r`` boxes of ``[verify]``, the centre of the
    law's domain without one (``scene.default_slice_point``, the slice every picture
    uses); the traces are simulated with
    the whole law (``RecordingContent.build``'s ``trace_law``), over its own ``u_prev``.

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
    options : RecordingOptions

    Returns
    -------
    law : ExplicitLaw
        In the states.
    options : RecordingOptions
    """
    if law.n > problem.plant.n and law.parameters:
        law = law.section(_section_point(problem, law))
    return law, options


def _section_point(problem: Problem, law: ExplicitLaw) -> np.ndarray:
    """The default values of the parameters after the states
    (:func:`codev_engine.view.scene.default_slice_point`): the middle of the initial
    ``u_prev`` and ``r`` boxes of ``[verify]``, the centre of the law's domain without one."""
    from codev_engine.view.scene import default_slice_point

    return default_slice_point(law, problem)[problem.plant.n :]
