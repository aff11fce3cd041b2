"""The stage table: every stage a session runs, declared once.

A :class:`Stage` says everything the session needs to know about one stage: the inputs its
key hashes, its artifact's extension, how to check, compute, load and describe it, and which
:class:`~codev_engine.session.reports.RunReport` field holds its value. The session, the
keys, the status and the replay only walk :data:`TABLE` (in order: a stage reads the values
of the stages before it) and look stages up in it by name.

Adding a stage is one entry in :data:`TABLE`: its key, artifact, cache check, journal
record, status line and replay comparison all follow from it.

::

    model         plant + model sections                     -> LinearModel       .npz
    synthesis     model key + mpc section + names            -> ExplicitLaw       .npz
                  (+ regions = "reached": an OnDemandLaw, its region cache .npz)
                  (+ sharded: a ShardedLaw, a folder of shards  .shards/)
    verification  synthesis key + plant + verify section     -> VerificationResult .npz
                  + hold/max_depth overrides (only with [verify])
    recording     verification (or synthesis) key + options  -> Rerun recording   .rrd
                  + the drawing code's hash (view_code_sha)

The engine modules each stage runs are imported when it runs: the session's bookkeeping (keys,
the status of a cached folder, the journal) needs none of them, and the workbench draws its
first screen before sympy and scipy are loaded.
"""

from __future__ import annotations

import functools
import hashlib
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from codev_engine.session.store import SessionError

if TYPE_CHECKING:
    from codev_engine.executor import Executor
    from codev_engine.spec.problem import Problem, VerifySpec

__all__ = ["STAGES", "TABLE", "Stage", "StageRun", "StageTable", "view_code_sha"]


class StageOptions(Protocol):
    """What the stages read of a run's options (:class:`codev_engine.session.RunOptions`).

    A protocol, so that the table does not import the options, which take their stage
    names (``upto``) from the table.

    Attributes
    ----------
    hold : str or None
        Overrides ``verify.hold``.
    max_depth : int or None
        Overrides ``verify.max_depth``.
    axes : (2,) tuple of int
        State indices of the recording's plane view.
    traces : int
        Simulated traces in the recording.
    sharded : bool
        The law is computed by the sharded search and stored as shards.
    """

    hold: str | None
    max_depth: int | None
    axes: tuple[int, int]
    traces: int
    sharded: bool


@dataclass(frozen=True)
class StageRun:
    """What a stage's ``compute`` is given.

    Attributes
    ----------
    problem : Problem
    options : StageOptions
    upstream : mapping
        Stage name -> value of every stage run before this one in the same run.
    path : Path
        Where the artifact goes (the stage writes it, atomically).
    progress : callable
        ``progress(count, **extra)``: regions found, branches explored, ...; ``extra``
        (e.g. ``samples``, ``boxes``) goes into the progress event's data.
    executor : Executor or None
        Where the stage's parallel work runs (the mp-QP search's candidates, the nonlinear
        verification's cells); None: in this process. Never part of a key: the artifacts
        are the same whatever runs them.
    """

    problem: Problem
    options: StageOptions
    upstream: Mapping[str, Any]
    path: Path
    progress: Callable[..., None]
    executor: Executor | None = None


@dataclass(frozen=True)
class Stage:
    """One stage of a session run.

    Attributes
    ----------
    name : str
        Stage name: in keys, artifact names, the journal and ``RunOptions.upto``.
    ext : str
        Extension of the artifact ``<name>-<key[:16]>.<ext>``.
    report_field : str or None
        The :class:`RunReport` attribute that receives the stage's value (None: none).
    inputs : callable
        ``inputs(problem, options, keys) -> dict or None``: what the key hashes, given the
        keys of the stages before it; None when the stage does not apply to the spec.
    compute : callable
        ``compute(StageRun) -> value``; writes the artifact to ``StageRun.path``.
    load : callable
        ``load(path, problem) -> value`` of a cached artifact (its SHA-256 already
        matched); ``CodevError`` if the file is not one.
    describe : callable
        ``describe(value, upstream) -> (outcome, details)``: what a replay compares, and the
        rest (timings, sizes), both JSON-able.
    check : callable or None
        ``check(problem)``: the stage's precondition on the spec (raises ``SpecError``), run
        before anything is written unless the stage's artifact is cached (a cached artifact
        proves it) -- whatever ``upto`` is, so a spec no stage can run is never stored.
    check_options : callable or None
        ``check_options(problem, options)``: the run options fit the spec; run when the stage
        is part of the run, before anything is written.
    ext_for : callable or None
        ``ext_for(options) -> str``: the extension for these options when it depends on
        them (the synthesis's folder of shards, ``shards``); None: always ``ext``.
    """

    name: str
    ext: str
    report_field: str | None
    inputs: Callable[[Problem, StageOptions, Mapping[str, str]], dict[str, Any] | None]
    compute: Callable[[StageRun], Any]
    load: Callable[[Path, Problem], Any]
    describe: Callable[[Any, Mapping[str, Any]], tuple[dict[str, Any], dict[str, Any]]]
    check: Callable[[Problem], None] | None = None
    check_options: Callable[[Problem, StageOptions], None] | None = None
    ext_for: Callable[[StageOptions], str] | None = None

    def extension(self, options: StageOptions) -> str:
        """The artifact's extension for a run's options (``ext`` unless ``ext_for``).

        Parameters
        ----------
        options : StageOptions
            The run's options (a sharded synthesis is a folder, ``.shards``).

        Returns
        -------
        str
        """
        return self.ext if self.ext_for is None else self.ext_for(options)


@dataclass(frozen=True)
class StageTable:
    """The stages of a run, in order, with unique names.

    Attributes
    ----------
    stages : tuple of Stage
        In the order a run executes them: a stage may read the values of those before it.

    Raises
    ------
    ValueError
        Two stages with one name.
    """

    stages: tuple[Stage, ...]

    def __post_init__(self) -> None:
        names = [s.name for s in self.stages]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"stage names must be unique: {', '.join(dup)} repeated")

    @property
    def names(self) -> tuple[str, ...]:
        """The stage names, in order."""
        return tuple(s.name for s in self.stages)

    def __iter__(self) -> Iterator[Stage]:
        return iter(self.stages)

    def __getitem__(self, name: str) -> Stage:
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(name)

    def upto(self, last: str, keys: Mapping[str, str]) -> list[Stage]:
        """The stages of a run that stops after ``last``.

        Parameters
        ----------
        last : str
            The last stage's name (``RunOptions.upto``).
        keys : mapping
            The stage keys of the spec (:func:`~codev_engine.session.keys.stage_keys`): a
            stage without one does not apply and is left out.

        Returns
        -------
        list of Stage
        """
        stop = self.names.index(last)
        return [s for s in self.stages[: stop + 1] if s.name in keys]


# --------------------------------------------------------------------------------------------
# model: the linearised, discretised plant
# --------------------------------------------------------------------------------------------


def _model_inputs(problem: Problem, options: StageOptions, keys: Mapping[str, str]) -> dict:
    return {"plant": problem.plant, "model": problem.model}


def _model_check(problem: Problem) -> None:
    from codev_engine.pipeline import check_model

    check_model(problem)


def _model_compute(run: StageRun) -> Any:
    from codev_engine.plant import discretize

    model = discretize(run.problem)
    model.save(run.path)
    return model


def _model_load(path: Path, problem: Problem) -> Any:
    from codev_engine.plant import LinearModel

    return LinearModel.load(path)


def _model_describe(model: Any, upstream: Mapping[str, Any]) -> tuple[dict, dict]:
    eig = np.linalg.eigvals(model.A)
    return (
        {"n": model.n, "m": model.m, "dt": model.dt},
        {"spectral_radius": round(float(np.max(np.abs(eig))), 9)},
    )


# --------------------------------------------------------------------------------------------
# synthesis: the explicit MPC law
# --------------------------------------------------------------------------------------------


def _synthesis_inputs(problem: Problem, options: StageOptions, keys: Mapping[str, str]) -> dict:
    inputs = {
        "model": keys["model"],
        "mpc": problem.mpc,
        "states": problem.plant.states,
        "inputs": problem.plant.inputs,
        "name": problem.name,
    }
    if problem.regions == "reached":  # (left out for "all": the keys stay as they were)
        inputs["regions"] = "reached"
    if getattr(options, "sharded", False):
        # Sharding is in the key (left out when not sharded: the serial keys stay as they
        # were), though the sharded law is the same function as the serial one: the
        # artifact is another object, a folder read lazily that a serial run must not be
        # handed to merge, nor a sharded run a single file its user asked to keep off one
        # process; and its partition is numbered otherwise (by active set, shard by shard)
        # and, with mpc.simplify, merged within each shard only. A verification follows the
        # partition (its reachtube's boxes, and in edge cases its verdict: an
        # over-approximation), so the verification cached downstream, keyed by this key,
        # must name the partition it was computed on. The number of workers is left out:
        # the search's regions do not depend on it (mp/sharded.py; with simplify the
        # merges within shards may differ: a cached law is any shard count's, the same
        # function).
        inputs["sharded"] = True
    return inputs


def _synthesis_check(problem: Problem) -> None:
    # an LP that loads python-control: only run when the law is not cached
    from codev_engine.pipeline import check_mpc_feasible

    check_mpc_feasible(problem)
    if problem.regions == "reached":
        # what a law on demand is not computed for (norms 1 and inf: an mp-LP), refused
        # before the spec is stored
        from codev_engine.law_on_demand import OnDemandLaw

        OnDemandLaw(problem)


def _synthesis_check_options(problem: Problem, options: StageOptions) -> None:
    if getattr(options, "sharded", False) and problem.regions == "reached":
        raise SessionError('the whole law is sharded, not its regions computed on demand '
                           '(regions = "reached")', field="sharded")


def _synthesis_ext(options: StageOptions) -> str:
    return "shards" if getattr(options, "sharded", False) else "npz"


def _synthesis_compute(run: StageRun) -> Any:
    from codev_engine.synthesis import synthesize

    if run.problem.regions == "reached":
        # the law on demand, with no region yet: its artifact is the region cache, which
        # the session writes again once the later stages have grown it (Session.run)
        from codev_engine.law_on_demand import OnDemandLaw

        law = OnDemandLaw(run.problem, model=run.upstream["model"])
        law.save(run.path)
        return law
    if getattr(run.options, "sharded", False):
        return _sharded_compute(run)

    law = synthesize(run.problem, model=run.upstream["model"], progress=run.progress,
                     executor=run.executor)
    law.save(run.path)
    return law


def _sharded_compute(run: StageRun) -> Any:
    """The law written as shards by the workers that found its regions, in a temporary
    folder beside the artifact (the session's ``artifacts/``: a remote cluster's workers
    need it on a shared file system) renamed into place once its manifest is written, so a
    folder of that name is never a torn law (``io.atomic.atomic_folder``)."""
    from codev_engine.io.atomic import atomic_folder
    from codev_engine.law_shard_writer import split_law, write_law_shards
    from codev_engine.law_shards import ShardedLaw
    from codev_engine.synthesis import synthesize

    with atomic_folder(run.path) as tmp:
        # (the search's own files in the same folder: removed by the search at its end)
        law = synthesize(run.problem, model=run.upstream["model"], progress=run.progress,
                         executor=run.executor, sharded=True, shard_dir=tmp, out_shards=tmp)
        if not isinstance(law, ShardedLaw):  # (a search that wrote no shards: one here)
            write_law_shards(tmp, split_law(law, 1))
    return ShardedLaw(run.path)


def _synthesis_load(path: Path, problem: Problem) -> Any:
    from codev_engine.law import ExplicitLaw

    if path.is_dir():
        # (a law as shards: opened from its manifest, read lazily, never merged here; the
        # store checked each shard's size, ShardedLaw checks its SHA-256 when it reads it)
        from codev_engine.law_shards import ShardedLaw

        return ShardedLaw(path)

    if problem.regions == "reached":
        from codev_engine.law_on_demand import OnDemandLaw

        # (the cache's fingerprint and checksum are checked: a damaged one is recomputed)
        return OnDemandLaw.load(path, problem)

    return ExplicitLaw.load(path)


def _synthesis_describe(law: Any, upstream: Mapping[str, Any]) -> tuple[dict, dict]:
    if getattr(law, "on_demand", False):
        # (the regions computed grow from run to run: not an outcome a replay compares)
        return {"regions": "reached"}, {"regions_computed": law.num_regions}
    if hasattr(law, "shards"):
        # (the shards are details: their number is the workers', not part of the key, and
        # a replay without a cluster writes one)
        return (
            {"regions": law.num_regions},
            {"shards": law.shards, "regions_before_merge": law.meta.get("regions_before_merge"),
             "synthesis_seconds": law.meta.get("seconds")},
        )
    return (
        {"regions": law.num_regions},
        {
            "regions_before_merge": law.meta.get("regions_before_merge"),
            "synthesis_seconds": law.meta.get("seconds"),
        },
    )


# --------------------------------------------------------------------------------------------
# verification: verdict, reachtube, counterexample (only with a [verify] section)
# --------------------------------------------------------------------------------------------


def _effective_verify(problem: Problem, options: StageOptions) -> VerifySpec:
    """The ``[verify]`` section with the run's ``hold`` / ``max_depth`` overrides applied."""
    vs = problem.verify
    assert vs is not None
    return replace(
        vs,
        hold=options.hold or vs.hold,
        max_depth=vs.max_depth if options.max_depth is None else options.max_depth,
    )


def _at_default(value, f) -> bool:
    """A field still at its default (None, or a plain default such as ``constraints =
    False``)."""
    if f.default is None:
        return value is None
    return type(value) is type(f.default) and value == f.default


def _verification_inputs(
    problem: Problem, options: StageOptions, keys: Mapping[str, str]
) -> dict | None:
    if problem.verify is None:
        return None
    vs = _effective_verify(problem, options)
    # fields added since (initial_input, reference) are left out at their defaults, as in
    # keys.canon: the keys of sessions recorded before them stay the same
    verify_fields = {
        f.name: getattr(vs, f.name)
        for f in fields(vs)
        if not (f.metadata.get("key_omit_default") and _at_default(getattr(vs, f.name), f))
    }
    if math.isfinite(vs.time_horizon):
        # max_samples only matters for time_horizon = "inf": left out, the keys of every
        # bounded verification are the ones sessions recorded before it existed
        del verify_fields["max_samples"]
    inputs = {
        "synthesis": keys["synthesis"],
        "plant": problem.plant,
        "verify": verify_fields,
    }
    # a verdict "unknown" / "limit" depends on the exploration's limits: limits set by
    # CODEV_LIMITS key the result (the defaults are left out: keys stay as they were)
    from codev_engine.limits import DEFAULTS, limits

    reach = {k: v for k, v in limits().items() if k != "region_bytes" and v != DEFAULTS[k]}
    if reach:
        inputs["limits"] = reach
    return inputs


def _verification_compute(run: StageRun) -> Any:
    from codev_engine.reach.verification import verify

    law = run.upstream["synthesis"]
    # a law on demand grows during the verification: its regions computed so far go with
    # each progress event (the TUI shows them live), None for a full law
    on_demand = getattr(law, "on_demand", False)
    result = verify(
        run.problem,
        law,
        hold=run.options.hold,
        max_depth=run.options.max_depth,
        progress=lambda st: run.progress(
            st.get("branches", 0), samples=st.get("samples"), boxes=st.get("boxes"),
            doing=st.get("doing"), regions=law.num_regions if on_demand else None,
        ),
        executor=run.executor,
    )
    result.save(run.path)
    return result


def _verification_load(path: Path, problem: Problem) -> Any:
    from codev_engine.reach.verification import VerificationResult

    return VerificationResult.load(path)


def _verification_describe(result: Any, upstream: Mapping[str, Any]) -> tuple[dict, dict]:
    cex = result.counterexample
    return (
        {"verdict": result.verdict, "reason": result.reason},
        {
            "hold": result.hold,
            "boxes": result.tube.num_boxes,
            "branches": result.stats.get("branches"),
            "verification_seconds": round(result.seconds, 6),
            "counterexample": None
            if cex is None
            else {"x0": cex.x0.tolist(), "t": cex.t, "kind": cex.kind},
        },
    )


# --------------------------------------------------------------------------------------------
# recording: the Rerun recording of the law (and the tube, when verified)
# --------------------------------------------------------------------------------------------


#: the code that draws a recording: ``codev_engine/view``
VIEW_DIR = Path(__file__).resolve().parents[1] / "view"


@functools.cache
def view_code_sha(root: Path = VIEW_DIR) -> str:
    """SHA-256 of the sources of the code that draws the recordings, read once.

    The recording's key holds it, so that a change to the pictures is not served from the
    cache (a fix needed ``--fresh``). The sources' hash, rather than a format constant
    bumped by hand: a constant is forgotten exactly when a picture is fixed, while the hash
    follows every change, in a checkout (whose version does not change between commits)
    and an installation alike (a wheel installs the ``.py`` files: they are read by path,
    ~12 files, well under a millisecond, without importing Rerun). Where they are not (an
    application frozen to bytecode) it is ``"no sources"``: the engine version, in every key,
    is then the drawing code's version.

    Parameters
    ----------
    root : Path
        The folder of the drawing code (default ``codev_engine/view``).

    Returns
    -------
    str
        64 hex digits, or ``"no sources"``.
    """
    files = sorted(root.rglob("*.py"))
    if not files:
        return "no sources"
    h = hashlib.sha256()
    for f in files:  # (each file's name and content: a file renamed changes it too)
        h.update(f.relative_to(root).as_posix().encode() + b"\0")
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


def _recording_inputs(problem: Problem, options: StageOptions, keys: Mapping[str, str]) -> dict:
    upstream = (
        {"verification": keys["verification"]}
        if "verification" in keys
        else {"synthesis": keys["synthesis"]}
    )
    return {
        **upstream,
        "axes": list(options.axes),
        "traces": options.traces,
        "name": problem.name,
        "view": view_code_sha(),
    }


def _recording_check_options(problem: Problem, options: StageOptions) -> None:
    n = problem.plant.n
    if n >= 2 and max(options.axes) >= n:  # one state: no plane view, axes unused
        raise SessionError(
            f"state index {max(options.axes)} out of range: the plant has {n} states",
            field="axes",
        )


def _recording_compute(run: StageRun) -> Path:
    from codev_engine.view.records import RecordingOptions, write_recording

    write_recording(
        run.path,
        run.problem,
        run.upstream["synthesis"],
        run.upstream.get("verification"),
        options=RecordingOptions(axes=run.options.axes, traces=run.options.traces),
    )
    return run.path


def _recording_load(path: Path, problem: Problem) -> Path:
    from codev_engine.view.records import check_recording

    check_recording(path, deep=False)  # the SHA-256 already matched the written file
    return path


def _recording_describe(path: Path, upstream: Mapping[str, Any]) -> tuple[dict, dict]:
    result = upstream.get("verification")
    boxes = result.tube.num_boxes if result is not None else 0
    # (the drawing code's hash is in the key: the journal says which code drew it)
    return ({"boxes": boxes}, {"bytes": Path(path).stat().st_size, "view": view_code_sha()})


# --------------------------------------------------------------------------------------------
# The table
# --------------------------------------------------------------------------------------------

TABLE = StageTable(
    (
        Stage(
            name="model",
            ext="npz",
            report_field="model",
            inputs=_model_inputs,
            compute=_model_compute,
            load=_model_load,
            describe=_model_describe,
            check=_model_check,
        ),
        Stage(
            name="synthesis",
            ext="npz",
            report_field="law",
            inputs=_synthesis_inputs,
            compute=_synthesis_compute,
            load=_synthesis_load,
            describe=_synthesis_describe,
            check=_synthesis_check,
            check_options=_synthesis_check_options,
            ext_for=_synthesis_ext,
        ),
        Stage(
            name="verification",
            ext="npz",
            report_field="result",
            inputs=_verification_inputs,
            compute=_verification_compute,
            load=_verification_load,
            describe=_verification_describe,
        ),
        Stage(
            name="recording",
            ext="rrd",
            report_field="recording",
            inputs=_recording_inputs,
            compute=_recording_compute,
            load=_recording_load,
            describe=_recording_describe,
            check_options=_recording_check_options,
        ),
    )
)

#: The stage names, in the order a run executes them.
STAGES: tuple[str, ...] = TABLE.names
