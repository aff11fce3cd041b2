"""Sessions: a design's spec, a journal of the stages run, and their cached artifacts.

A session is a folder (``sessions/<name>`` by convention, any path works)::

    session.json        format tag, the engine that created it, creation time
    spec.toml           the spec of the latest run
    specs/<hash>.toml   every spec a run used, by the SHA-256 of its text (for replay)
    journal.jsonl       one JSON object per stage executed (what, inputs, when, outcome)
    artifacts/          <stage>-<key>.<ext>: model.npz, synthesis.npz (the explicit law),
                        verification.npz (verdict, tube, counterexample), recording.rrd
    artifacts/index.json  name -> SHA-256 and size of every artifact written completely

Stages, each keyed by a hash of everything it depends on (its inputs from the spec, the
keys of the stages upstream, and the engine version)::

    model         plant + model sections                     -> LinearModel
    synthesis     model key + mpc section + names            -> ExplicitLaw
    verification  synthesis key + plant + verify section     -> VerificationResult
                  + hold/max_depth overrides
    recording     verification (or synthesis) key + options  -> .rrd

A stage whose key has a valid artifact is loaded ("cached"), otherwise computed. Artifacts
are written atomically (temp file + rename), then entered in the index; an artifact is used
only if the index has it and its bytes hash to the indexed SHA-256 and its loader accepts
it, so a run killed mid-write, a truncated or edited file, or a file from elsewhere is
reported and recomputed, never used. Nothing is unpickled; loading a session never runs
code from it.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields, is_dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from codev_engine.errors import CodevError, SpecError
from codev_engine.io.atomic import atomic_path, write_text
from codev_engine.spec.choices import HOLDS

if TYPE_CHECKING:
    # imported where used: the session's bookkeeping (keys, status of a cached folder, the
    # journal) needs none of them, and the workbench draws its first screen before sympy
    # and scipy are loaded
    from codev_engine.law import ExplicitLaw
    from codev_engine.plant import LinearModel
    from codev_engine.reach.verification import VerificationResult
    from codev_engine.spec.problem import Problem
from codev_engine.version import __version__

__all__ = [
    "SESSION_FORMAT",
    "STAGES",
    "RunOptions",
    "RunReport",
    "ReplayReport",
    "Session",
    "SessionError",
    "StageReport",
    "StageStatus",
    "stage_keys",
]

SESSION_FORMAT = "codev-session/1"
STAGES: tuple[str, ...] = ("model", "synthesis", "verification", "recording")
_EXT = {"model": "npz", "synthesis": "npz", "verification": "npz", "recording": "rrd"}

#: ``on_event(stage, event, data)``: ``event`` is "start", "progress" (``data["count"]``:
#: regions found / branches explored) or "done" (``data``: the StageReport as a dict).
EventCallback = Callable[[str, str, dict], None]


class SessionError(SpecError):
    """A session folder that cannot be used as asked (bad input: exit status 2)."""


# --------------------------------------------------------------------------------------------
# Plain data
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunOptions:
    """What a run does besides the spec: the last stage, verification overrides, recording.

    Attributes
    ----------
    upto : str
        Last stage to run (one of ``STAGES``); stages that need a ``[verify]`` section are
        skipped when the spec has none.
    hold : str or None
        Overrides ``verify.hold``.
    max_depth : int or None
        Overrides ``verify.max_depth``.
    axes : (2,) tuple of int
        State indices of the recording's plane view.
    traces : int
        Simulated traces in the recording.
    """

    upto: str = "recording"
    hold: str | None = None
    max_depth: int | None = None
    axes: tuple[int, int] = (0, 1)
    traces: int = 16

    def to_json(self) -> dict[str, Any]:
        return {
            "upto": self.upto,
            "hold": self.hold,
            "max_depth": self.max_depth,
            "axes": list(self.axes),
            "traces": self.traces,
        }

    @classmethod
    def from_json(cls, d: Any, *, where: str = "options") -> RunOptions:
        """Validate the options of a journal record (no field may carry code or junk)."""
        if not isinstance(d, dict):
            raise SessionError("must be a JSON object", field=where)
        try:
            opts = cls(
                upto=str(d.get("upto", "recording")),
                hold=d.get("hold"),
                max_depth=d.get("max_depth"),
                axes=tuple(d.get("axes", (0, 1))),  # type: ignore[arg-type]
                traces=d.get("traces", 16),
            )
        except TypeError:
            raise SessionError("malformed run options", field=where) from None
        opts.check(field_prefix=where)
        return opts

    def check(self, *, field_prefix: str = "options") -> None:
        """``SessionError`` naming the option that is out of range."""
        if self.upto not in STAGES:
            raise SessionError(f"must be one of {', '.join(STAGES)}", field=f"{field_prefix}.upto")
        if self.hold is not None and self.hold not in HOLDS:
            raise SessionError("must be zoh or continuous", field=f"{field_prefix}.hold")
        if self.max_depth is not None and (
            not isinstance(self.max_depth, int)
            or isinstance(self.max_depth, bool)
            or self.max_depth < 0
        ):
            raise SessionError("must be a non-negative integer", field=f"{field_prefix}.max_depth")
        if (
            len(self.axes) != 2
            or not all(isinstance(a, int) and not isinstance(a, bool) for a in self.axes)
            or self.axes[0] == self.axes[1]
            or min(self.axes) < 0
        ):
            raise SessionError("must be two distinct state indices", field=f"{field_prefix}.axes")
        if not isinstance(self.traces, int) or isinstance(self.traces, bool) or self.traces < 0:
            raise SessionError("must be a non-negative integer", field=f"{field_prefix}.traces")


@dataclass(frozen=True)
class StageReport:
    """What one stage did in a run.

    ``status`` is "computed", "cached", "skipped" or "failed"; ``outcome`` holds the fields a
    replay compares (regions, verdict, ...), ``details`` the rest (timings, sizes).
    """

    stage: str
    status: str
    key: str
    seconds: float
    outcome: dict[str, Any]
    details: dict[str, Any] = field(default_factory=dict)
    artifact: str | None = None
    note: str | None = None


@dataclass
class RunReport:
    """The result of :meth:`Session.run`: what each stage did and the values it produced."""

    run: int
    stages: list[StageReport]
    problem: Problem
    model: LinearModel | None = None
    law: ExplicitLaw | None = None
    result: VerificationResult | None = None
    recording: Path | None = None
    seconds: float = 0.0

    def stage(self, name: str) -> StageReport | None:
        return next((s for s in self.stages if s.stage == name), None)


@dataclass(frozen=True)
class StageStatus:
    """Cache status of one stage for a spec and options: "cached" (a valid artifact for the
    current inputs), "stale" (computed before, but its inputs changed since), "missing"
    (never computed, or the artifact is gone) or "corrupt" (the artifact fails its check).
    """

    stage: str
    key: str
    status: str
    artifact: str | None
    reason: str | None = None


@dataclass(frozen=True)
class ReplayReport:
    """The result of :meth:`Session.replay`.

    ``mismatches`` lists ``(run, stage, recorded outcome, replayed outcome)``.
    """

    runs: int
    checked: int
    cached: int
    mismatches: list[tuple[int, str, dict, dict]]
    seconds: float

    @property
    def ok(self) -> bool:
        return not self.mismatches


# --------------------------------------------------------------------------------------------
# Keys
# --------------------------------------------------------------------------------------------


def _canon(obj: Any) -> Any:
    """A JSON-able, exact and machine-independent rendering of spec data for hashing.

    Floats as ``float.hex`` (exact), arrays by dtype, shape and the SHA-256 of their
    little-endian bytes, dataclasses as dicts of their fields.
    """
    if is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _canon(getattr(obj, f.name)) for f in fields(obj)}
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.kind == "f":
            a = a.astype("<f8")
        elif a.dtype.kind in "iub":
            a = a.astype("<i8")
        elif a.dtype.kind == "U":
            return {"text": a.tolist()}
        return {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": _sha(a.tobytes())}
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj).hex()
    if isinstance(obj, (list, tuple)):
        return [_canon(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _canon(v) for k, v in obj.items()}
    raise TypeError(f"cannot hash {type(obj).__name__}")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _key(stage: str, inputs: dict[str, Any]) -> str:
    doc = {"engine": __version__, "stage": stage, "inputs": _canon(inputs)}
    return _sha(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode())


def stage_keys(problem: Problem, options: RunOptions = RunOptions()) -> dict[str, str]:
    """The key of every stage for a problem and run options (no computation).

    Returns
    -------
    dict
        Stage name -> 64-hex key; "verification" is absent when the spec has no
        ``[verify]`` section.
    """
    keys = {"model": _key("model", {"plant": problem.plant, "model": problem.model})}
    keys["synthesis"] = _key(
        "synthesis",
        {
            "model": keys["model"],
            "mpc": problem.mpc,
            "states": problem.plant.states,
            "inputs": problem.plant.inputs,
            "name": problem.name,
        },
    )
    upstream = {"synthesis": keys["synthesis"]}
    if problem.verify is not None:
        vs = _effective_verify(problem, options)
        keys["verification"] = _key(
            "verification",
            {"synthesis": keys["synthesis"], "plant": problem.plant, "verify": vs},
        )
        upstream = {"verification": keys["verification"]}
    keys["recording"] = _key(
        "recording",
        {**upstream, "axes": list(options.axes), "traces": options.traces, "name": problem.name},
    )
    return keys


def _effective_verify(problem: Problem, options: RunOptions):
    vs = problem.verify
    assert vs is not None
    return replace(
        vs,
        hold=options.hold or vs.hold,
        max_depth=vs.max_depth if options.max_depth is None else options.max_depth,
    )


def _stages_for(problem: Problem, options: RunOptions) -> list[str]:
    last = STAGES.index(options.upto)
    stages = list(STAGES[: last + 1])
    if problem.verify is None and "verification" in stages:
        stages.remove("verification")
    return stages


# --------------------------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------------------------


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _file_sha(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """Serialise read-modify-write of the journal and index between processes (POSIX)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: atomic renames still protect files
        yield
        return
    with (folder / ".lock").open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


# --------------------------------------------------------------------------------------------
# The session
# --------------------------------------------------------------------------------------------


class Session:
    """A session folder; see the module docstring for its layout.

    Use :meth:`open` for an existing session, :meth:`create` for a new one, or
    :meth:`open_or_create`.
    """

    def __init__(self, path: Path, meta: dict[str, Any]):
        self.path = path
        self.meta = meta

    # ---- opening ---------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | os.PathLike) -> Session:
        """Open an existing session; ``SessionError`` if the folder is not one."""
        path = Path(path)
        if not path.exists():
            raise SessionError("no such session folder", file=str(path))
        if not path.is_dir():
            raise SessionError("not a folder (a session is a folder)", file=str(path))
        meta_file = path / "session.json"
        if not meta_file.is_file():
            raise SessionError(
                "not a codev session (no session.json); create one with "
                "`codev run SPEC --session DIR`",
                file=str(path),
            )
        try:
            meta = json.loads(meta_file.read_text(encoding="utf-8"))
        except (OSError, ValueError, RecursionError) as exc:
            raise SessionError(
                f"unreadable session.json ({exc.__class__.__name__})", file=str(meta_file)
            ) from None
        if not isinstance(meta, dict) or not isinstance(meta.get("format"), str):
            raise SessionError("not a codev session file (no format)", file=str(meta_file))
        if meta["format"] != SESSION_FORMAT:
            raise SessionError(
                f"session format {meta['format']!r} is not {SESSION_FORMAT!r} (written by "
                f"codev {meta.get('engine', '?')}; this is codev {__version__})",
                file=str(meta_file),
                field="format",
            )
        return cls(path, meta)

    @classmethod
    def create(cls, path: str | os.PathLike) -> Session:
        """Make a new session in ``path`` (created, or an empty folder)."""
        path = Path(path)
        if path.exists() and not path.is_dir():
            raise SessionError("exists and is not a folder", file=str(path))
        if path.is_dir() and not _empty(path):
            raise SessionError(
                "not a codev session (no session.json) and not empty: refusing to write into it",
                file=str(path),
            )
        path.mkdir(parents=True, exist_ok=True)
        meta = {"format": SESSION_FORMAT, "engine": __version__, "created": _now()}
        write_text(path / "session.json", json.dumps(meta, indent=2) + "\n")
        (path / "artifacts").mkdir(exist_ok=True)
        return cls(path, meta)

    @classmethod
    def open_or_create(cls, path: str | os.PathLike) -> Session:
        path = Path(path)
        if (path / "session.json").exists():
            return cls.open(path)
        return cls.create(path)

    # ---- the spec and the journal ----------------------------------------------------

    def spec_path(self) -> Path:
        return self.path / "spec.toml"

    def problem(self) -> Problem:
        """The session's current spec, parsed and validated."""
        from codev_engine.pipeline import load_spec

        if not self.spec_path().is_file():
            raise SessionError("the session has no spec.toml yet", file=str(self.path))
        return load_spec(self.spec_path())

    def journal(self) -> list[dict[str, Any]]:
        """Every journal record, oldest first; ``SessionError`` on a malformed line."""
        file = self.path / "journal.jsonl"
        if not file.exists():
            return []
        try:
            lines = file.read_text(encoding="utf-8").splitlines()
        except (OSError, UnicodeDecodeError) as exc:
            raise SessionError(f"unreadable journal ({exc})", file=str(file)) from None
        records = []
        for i, line in enumerate(lines, 1):
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
            except (ValueError, RecursionError):
                raise SessionError(f"line {i} is not valid JSON", file=str(file)) from None
            _check_record(rec, f"{file}:{i}")
            records.append(rec)
        return records

    def _append(self, records: list[dict[str, Any]]) -> int:
        """Add one run's records to the journal under the next run number; returns it.

        The whole file is rewritten atomically under the lock, so concurrent runs get
        distinct numbers and no record is lost.
        """
        with _locked(self.path):
            old = self.journal()
            run = max((r["run"] for r in old), default=0) + 1
            for r in records:
                r["run"] = run
            lines = [json.dumps(r, sort_keys=True) for r in old + records]
            write_text(self.path / "journal.jsonl", "\n".join(lines) + "\n")
        return run

    def save_spec(self, problem: Problem) -> str:
        """Make ``problem``'s TOML the session's ``spec.toml``; returns its SHA-256.

        Every spec that was ever ``spec.toml`` keeps a snapshot in ``specs/<sha>.toml``
        (the one replaced included), so an edit saved by the workbench loses nothing.
        """
        if not problem.source.strip():
            raise SessionError("the problem has no TOML source to store in the session")
        sha = _sha(problem.source.encode())
        self._snapshot(problem.source)
        current = self.spec_path()
        try:
            old: str | None = current.read_text("utf-8")
        except (OSError, UnicodeDecodeError):
            old = None  # absent or unreadable: nothing worth keeping
        if old == problem.source:
            return sha
        if old is not None and old.strip():
            self._snapshot(old)
        write_text(current, problem.source)
        return sha

    def _snapshot(self, text: str) -> None:
        snap = self.path / "specs" / f"{_sha(text.encode())[:16]}.toml"
        if not snap.exists():
            write_text(snap, text)

    def _spec_of(self, sha: str, where: str) -> Problem:
        snap = self.path / "specs" / f"{sha[:16]}.toml"
        try:
            text = snap.read_bytes().decode("utf-8")
        except FileNotFoundError:
            raise SessionError("the spec this run used is missing", file=str(snap)) from None
        except (OSError, UnicodeDecodeError) as exc:
            raise SessionError(f"unreadable spec ({exc})", file=str(snap)) from None
        if _sha(text.encode()) != sha:
            raise SessionError("the stored spec was edited (hash mismatch)", file=str(snap))
        from codev_engine.pipeline import loads_spec

        return loads_spec(text, path=str(snap))

    # ---- artifacts -------------------------------------------------------------------

    def artifact_path(self, stage: str, key: str) -> Path:
        return self.path / "artifacts" / f"{stage}-{key[:16]}.{_EXT[stage]}"

    def _index(self) -> dict[str, dict[str, Any]]:
        file = self.path / "artifacts" / "index.json"
        try:
            data = json.loads(file.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {}
        except (OSError, ValueError, RecursionError, UnicodeDecodeError):
            return {}  # a damaged index only costs recomputation
        return data if isinstance(data, dict) else {}

    def _register(self, path: Path, stage: str, key: str) -> str:
        sha = _file_sha(path)
        with _locked(self.path):
            index = self._index()
            index[path.name] = {
                "stage": stage,
                "key": key,
                "sha256": sha,
                "bytes": path.stat().st_size,
                "engine": __version__,
            }
            write_text(
                self.path / "artifacts" / "index.json", json.dumps(index, indent=1, sort_keys=True)
            )
        return sha

    def _check_artifact(self, stage: str, key: str) -> tuple[Path, str | None]:
        """The artifact path and why it cannot be used (None: it can)."""
        path = self.artifact_path(stage, key)
        if not path.exists():
            return path, "missing"
        if not path.is_file():
            return path, "not a regular file"
        entry = self._index().get(path.name)
        if not isinstance(entry, dict) or entry.get("key") != key:
            return path, "not in the artifact index (an interrupted write?)"
        if entry.get("sha256") != _file_sha(path):
            return path, "its content does not match the recorded SHA-256 (damaged or edited)"
        return path, None

    def _load(self, stage: str, path: Path) -> Any:
        if stage == "model":
            from codev_engine.plant import LinearModel

            return LinearModel.load(path)
        if stage == "synthesis":
            from codev_engine.law import ExplicitLaw

            return ExplicitLaw.load(path)
        if stage == "verification":
            from codev_engine.reach.verification import VerificationResult

            return VerificationResult.load(path)
        from codev_engine.view.records import check_recording

        check_recording(path, deep=False)  # the SHA-256 already matched the written file
        return path

    # ---- status ----------------------------------------------------------------------

    def status(
        self, problem: Problem | None = None, options: RunOptions | None = None
    ) -> list[StageStatus]:
        """Cache status per stage for ``problem`` (default: the session's spec) and
        ``options`` (default: those of the latest run)."""
        problem = problem if problem is not None else self.problem()
        journal = self.journal()
        if options is None:
            options = RunOptions.from_json(journal[-1]["options"]) if journal else RunOptions()
        keys = stage_keys(problem, options)
        out = []
        for stage in STAGES:
            if stage not in keys:
                continue
            key = keys[stage]
            path, why = self._check_artifact(stage, key)
            rel = str(path.relative_to(self.path))
            if why is None:
                try:
                    self._load(stage, path)
                except CodevError as exc:
                    out.append(StageStatus(stage, key, "corrupt", rel, str(exc)))
                    continue
                out.append(StageStatus(stage, key, "cached", rel))
            elif why != "missing":
                out.append(StageStatus(stage, key, "corrupt", rel, why))
            elif any(r["stage"] == stage for r in journal):
                last = next(r for r in reversed(journal) if r["stage"] == stage)
                if last["key"] != key:
                    out.append(
                        StageStatus(stage, key, "stale", None, "inputs changed since the last run")
                    )
                else:
                    out.append(StageStatus(stage, key, "missing", None, "artifact deleted"))
            else:
                out.append(StageStatus(stage, key, "missing", None))
        return out

    # ---- running ---------------------------------------------------------------------

    def run(
        self,
        problem: Problem,
        options: RunOptions = RunOptions(),
        *,
        fresh: bool = False,
        on_event: EventCallback | None = None,
        warn: Callable[[str], None] | None = None,
        journal: bool = True,
        raise_errors: bool = True,
    ) -> RunReport:
        """Run the stages up to ``options.upto``, loading valid cached artifacts.

        Parameters
        ----------
        problem : Problem
            The spec (its TOML ``source`` is stored in the session).
        options : RunOptions
        fresh : bool
            Recompute every stage, ignoring the cache.
        on_event : callable, optional
            Progress: ``on_event(stage, event, data)``.
        warn : callable, optional
            Called with a message when an artifact is found unusable and is recomputed.
        journal : bool
            Append the run to the journal (``replay`` passes False).
        raise_errors : bool
            A stage failing with a ``CodevError`` (bad input, solver breakdown) is journaled
            as "failed" and re-raised; with False the run stops there and the report ends
            with that stage's "failed" StageReport (its outcome holds the error).

        Returns
        -------
        RunReport
        """
        options.check()
        if "recording" in _stages_for(problem, options):
            _check_axes(problem, options)
        t_run = time.perf_counter()
        emit = on_event or (lambda _s, _e, _d: None)
        say = warn or (lambda _m: None)
        self.journal()  # a malformed journal fails here, before anything is written
        keys = stage_keys(problem, options)
        if fresh or self._check_artifact("synthesis", keys["synthesis"])[1] is not None:
            # a cached law proves the MPC feasible; otherwise say so before writing anything
            from codev_engine.pipeline import check_mpc_feasible

            check_mpc_feasible(problem)
        spec_sha = self.save_spec(problem) if journal else _sha(problem.source.encode())
        # run 0 until the records are appended: numbered then, under the lock
        report = RunReport(run=0, stages=[], problem=problem)
        records: list[dict[str, Any]] = []
        try:
            for stage in _stages_for(problem, options):
                key = keys[stage]
                emit(stage, "start", {"key": key})
                started = _now()
                t0 = time.perf_counter()
                value, status, note = None, "computed", None
                path, why = self._check_artifact(stage, key)
                if not fresh and why is None:
                    try:
                        value = self._load(stage, path)
                        status = "cached"
                    except CodevError as exc:
                        why = f"unreadable ({exc})"
                if value is None:
                    if why not in (None, "missing") and not fresh:
                        note = f"{path.name}: {why}; recomputed"
                        say(f"{self.path}: artifact {note}")
                    try:
                        value = self._compute(stage, problem, options, report, path, emit)
                    except CodevError as exc:
                        error = {"error": type(exc).__name__, "message": str(exc)}
                        sr = StageReport(stage, "failed", key, time.perf_counter() - t0, error)
                        records.append(_record(sr, spec_sha, options, started))
                        if raise_errors:
                            raise
                        report.stages.append(sr)
                        emit(stage, "done", _report_json(sr))
                        break
                    self._register(path, stage, key)
                outcome, details = self._describe(stage, value, report)
                _attach(report, stage, value)
                seconds = time.perf_counter() - t0
                rel = str(path.relative_to(self.path))
                sr = StageReport(stage, status, key, seconds, outcome, details, rel, note)
                report.stages.append(sr)
                records.append(_record(sr, spec_sha, options, started))
                emit(stage, "done", _report_json(sr))
        finally:
            if journal and records:
                report.run = self._append(records)
        report.seconds = time.perf_counter() - t_run
        return report

    def _compute(
        self,
        stage: str,
        problem: Problem,
        options: RunOptions,
        report: RunReport,
        path: Path,
        emit: EventCallback,
    ) -> Any:
        def count(c: int) -> None:
            emit(stage, "progress", {"count": int(c)})

        if stage == "model":
            from codev_engine.plant import discretize

            model = discretize(problem)
            model.save(path)
            return model
        if stage == "synthesis":
            from codev_engine.synthesis import synthesize

            law = synthesize(problem, model=report.model, progress=count)
            law.save(path)
            return law
        if stage == "verification":
            from codev_engine.reach.verification import verify

            assert report.law is not None
            result = verify(
                problem,
                report.law,
                hold=options.hold,
                max_depth=options.max_depth,
                progress=lambda st: count(st.get("branches", 0)),
            )
            result.save(path)
            return result
        from codev_engine.view.records import RecordingOptions, write_recording

        assert report.law is not None
        write_recording(
            path,
            problem,
            report.law,
            report.result,
            options=RecordingOptions(axes=options.axes, traces=options.traces),
        )
        return path

    def _describe(self, stage: str, value: Any, report: RunReport) -> tuple[dict, dict]:
        """(outcome compared by replay, details that are not)."""
        if stage == "model":
            eig = np.linalg.eigvals(value.A)
            return (
                {"n": value.n, "m": value.m, "dt": value.dt},
                {"spectral_radius": round(float(np.max(np.abs(eig))), 9)},
            )
        if stage == "synthesis":
            return (
                {"regions": value.num_regions},
                {
                    "regions_before_merge": value.meta.get("regions_before_merge"),
                    "synthesis_seconds": value.meta.get("seconds"),
                },
            )
        if stage == "verification":
            cex = value.counterexample
            return (
                {"verdict": value.verdict, "reason": value.reason},
                {
                    "hold": value.hold,
                    "boxes": value.tube.num_boxes,
                    "branches": value.stats.get("branches"),
                    "verification_seconds": round(value.seconds, 6),
                    "counterexample": None
                    if cex is None
                    else {"x0": cex.x0.tolist(), "t": cex.t, "kind": cex.kind},
                },
            )
        boxes = report.result.tube.num_boxes if report.result is not None else 0
        return ({"boxes": boxes}, {"bytes": Path(value).stat().st_size})

    # ---- replay ----------------------------------------------------------------------

    def replay(
        self,
        *,
        on_event: EventCallback | None = None,
        warn: Callable[[str], None] | None = None,
        on_run: Callable[[int, RunReport, list], None] | None = None,
    ) -> ReplayReport:
        """Re-execute every run of the journal (reusing valid cache) and compare outcomes.

        The journal is not modified. ``SessionError`` if the journal is empty or was written
        by another engine version (its outcomes cannot be compared).
        """
        t0 = time.perf_counter()
        journal = self.journal()
        if not journal:
            raise SessionError("the journal is empty: nothing to replay", file=str(self.path))
        foreign = sorted({r["engine"] for r in journal} - {__version__})
        if foreign:
            raise SessionError(
                f"the journal was recorded by codev {', '.join(foreign)}; this is codev "
                f"{__version__}, whose outcomes may differ: record a new session with `codev run "
                f"{self.path / 'spec.toml'} --session NEW_DIR`",
                file=str(self.path / "journal.jsonl"),
            )
        runs: dict[int, list[dict]] = {}
        for rec in journal:
            runs.setdefault(rec["run"], []).append(rec)
        mismatches: list[tuple[int, str, dict, dict]] = []
        checked = cached = 0
        for run_no, recs in sorted(runs.items()):
            where = f"journal run {run_no}"
            problem = self._spec_of(recs[0]["spec"], where)
            options = RunOptions.from_json(recs[0]["options"], where=f"{where}.options")
            last = max(STAGES.index(r["stage"]) for r in recs)
            options = replace(options, upto=STAGES[last])
            rep = self.run(
                problem, options, on_event=on_event, warn=warn, journal=False, raise_errors=False
            )
            run_mismatches = []
            for rec in recs:
                sr = rep.stage(rec["stage"])
                got = sr.outcome if sr is not None else {"error": "not reached"}
                checked += 1
                cached += sr is not None and sr.status == "cached"
                if got != rec["outcome"]:
                    run_mismatches.append((run_no, rec["stage"], rec["outcome"], got))
            mismatches.extend(run_mismatches)
            if on_run is not None:
                on_run(run_no, rep, run_mismatches)
        return ReplayReport(
            runs=len(runs),
            checked=checked,
            cached=cached,
            mismatches=mismatches,
            seconds=time.perf_counter() - t0,
        )

    # ---- housekeeping ----------------------------------------------------------------

    def export(self, artifact: Path, dest: str | os.PathLike) -> Path:
        """Copy an artifact out of the session atomically (e.g. ``--record FILE.rrd``)."""
        with atomic_path(dest) as tmp:
            shutil.copyfile(artifact, tmp)
        return Path(dest)


def _empty(folder: Path) -> bool:
    """Nothing in ``folder`` but what an interrupted :meth:`Session.create` leaves behind
    (temporary files, an empty ``artifacts/``)."""
    for p in folder.iterdir():
        if p.name.startswith(".tmp-") and p.is_file():
            continue
        if p.name == "artifacts" and p.is_dir() and not any(p.iterdir()):
            continue
        return False
    return True


def _check_axes(problem: Problem, options: RunOptions) -> None:
    n = problem.plant.n
    if n >= 2 and max(options.axes) >= n:  # one state: no plane view, axes unused
        raise SessionError(
            f"state index {max(options.axes)} out of range: the plant has {n} states",
            field="axes",
        )


def _attach(report: RunReport, stage: str, value: Any) -> None:
    if stage == "model":
        report.model = value
    elif stage == "synthesis":
        report.law = value
    elif stage == "verification":
        report.result = value
    else:
        report.recording = Path(value)


def _record(sr: StageReport, spec_sha: str, options: RunOptions, started: str) -> dict:
    """The journal record of a stage (its ``run`` is set when appended)."""
    rec = {
        "run": 0,
        "stage": sr.stage,
        "key": sr.key,
        "spec": spec_sha,
        "options": options.to_json(),
        "started": started,
        "seconds": round(sr.seconds, 6),
        "status": sr.status,
        "outcome": sr.outcome,
        "details": sr.details,
        "artifact": sr.artifact,
        "engine": __version__,
    }
    if sr.note:
        rec["note"] = sr.note
    return rec


def _report_json(sr: StageReport) -> dict[str, Any]:
    return {
        "stage": sr.stage,
        "status": sr.status,
        "key": sr.key,
        "seconds": round(sr.seconds, 6),
        "outcome": sr.outcome,
        "details": sr.details,
        "artifact": sr.artifact,
        "note": sr.note,
    }


_RECORD_FIELDS = {
    "run": int,
    "stage": str,
    "key": str,
    "spec": str,
    "options": dict,
    "started": str,
    "seconds": (int, float),
    "status": str,
    "outcome": dict,
    "details": dict,
    "engine": str,
}


def _check_record(rec: Any, where: str) -> None:
    """A journal record must have the expected fields with the expected types."""
    if not isinstance(rec, dict):
        raise SessionError("a journal record must be a JSON object", file=where)
    for name, typ in _RECORD_FIELDS.items():
        if name not in rec:
            raise SessionError("missing field", file=where, field=name)
        if not isinstance(rec[name], typ) or isinstance(rec[name], bool):
            raise SessionError("wrong type", file=where, field=name)
    if rec["stage"] not in STAGES:
        raise SessionError(f"unknown stage {rec['stage']!r}", file=where, field="stage")
    if rec["status"] not in ("computed", "cached", "failed"):
        raise SessionError(f"unknown status {rec['status']!r}", file=where, field="status")
    if len(rec["spec"]) != 64 or any(c not in "0123456789abcdef" for c in rec["spec"]):
        raise SessionError("not a SHA-256 hex digest", file=where, field="spec")
