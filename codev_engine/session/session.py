"""Sessions: a design's spec, a journal of the stages run, and their cached artifacts.

A session is a folder (``sessions/<name>`` by convention, any path works); its files are
described in :mod:`codev_engine.session.store`, the stages in
:mod:`codev_engine.session.stages` and their keys in :mod:`codev_engine.session.keys`.

Each stage is keyed by a hash of everything it depends on (its inputs from the spec, the keys
of the stages upstream, and the engine version). A stage whose key has a valid artifact is
loaded ("cached"), otherwise computed. Artifacts are written atomically (temp file +
rename), then entered in the index; an artifact is used only if the index has it and its
bytes hash to the indexed SHA-256 and its loader accepts it, so a run killed mid-write, a
truncated or edited file, or a file from elsewhere is reported and recomputed, never used;
the temporaries a killed run left are removed by the next run (those no live writer holds).
A law stored as shards is opened from its manifest's SHA-256 and each shard's size; each
shard's SHA-256 is checked when it is read, and a shard found damaged then (by a stage, or
by a front end after the run: the session binds every law it opens, :meth:`Session.load`)
is said in one line, marked, and recomputed by the next run (docs/sessions.md, "What is
checked when").
Nothing is unpickled; loading a session never runs code from it.

:class:`Session` runs, reports the status of, replays and exports from a session; it knows
the stages only through its stage table.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from codev_engine.errors import CodevError, DamagedFileError
from codev_engine.io.atomic import atomic_path, remove_stale_beside
from codev_engine.kernel_cache import prepare
from codev_engine.session import store
from codev_engine.session.keys import stage_keys
from codev_engine.session.options import DEFAULT_OPTIONS, RunOptions
from codev_engine.session.reports import ReplayReport, RunReport, StageReport, StageStatus
from codev_engine.session.stages import TABLE, Stage, StageRun, StageTable
from codev_engine.session.store import SessionError
from codev_engine.version import __version__

if TYPE_CHECKING:
    from codev_engine.executor import Executor
    from codev_engine.spec.problem import Problem

__all__ = ["EventCallback", "Session"]

#: ``on_event(stage, event, data)``: ``event`` is "start", "progress" (``data["count"]``:
#: regions found / branches explored; for verification also ``samples``, the sample
#: reached, ``boxes``, the reachtube's boxes so far, when known, and ``regions``, the
#: critical regions computed so far by a law on demand, else None) or "done" (``data``:
#: the StageReport as a dict).
EventCallback = Callable[[str, str, dict], None]


class Session:
    """A session folder; see the module docstring.

    Use :meth:`open` for an existing session, :meth:`create` for a new one, or
    :meth:`open_or_create`.

    Parameters
    ----------
    path : Path
        The folder.
    meta : dict
        Its ``session.json``.

    Attributes
    ----------
    table : StageTable
        The stages it runs (a class attribute: codev's :data:`~stages.TABLE`).
    """

    table: StageTable = TABLE

    def __init__(self, path: Path, meta: dict[str, Any]):
        self.path = path
        self.meta = meta

    # ---- opening ---------------------------------------------------------------------

    @classmethod
    def open(cls, path: str | os.PathLike) -> Session:
        """Open an existing session.

        Parameters
        ----------
        path : str or os.PathLike
            The session folder.

        Returns
        -------
        Session

        Raises
        ------
        SessionError
            The folder is not a session.
        """
        path = Path(path)
        return cls(path, store.read_meta(path))

    @classmethod
    def create(cls, path: str | os.PathLike) -> Session:
        """Make a new session.

        Parameters
        ----------
        path : str or os.PathLike
            The folder: created, or an empty one.

        Returns
        -------
        Session

        Raises
        ------
        SessionError
            ``path`` is a file or a folder with something in it.
        """
        path = Path(path)
        return cls(path, store.create_folder(path))

    @classmethod
    def open_or_create(cls, path: str | os.PathLike) -> Session:
        """:meth:`open` the session in ``path`` if it has a ``session.json``, else :meth:`create`.

        Parameters
        ----------
        path : str or os.PathLike

        Returns
        -------
        Session
        """
        path = Path(path)
        if (path / "session.json").exists():
            return cls.open(path)
        return cls.create(path)

    # ---- the spec and the journal ----------------------------------------------------

    def spec_path(self) -> Path:
        """The session's current spec file, ``spec.toml`` (it may not exist yet)."""
        return store.spec_path(self.path)

    def problem(self) -> Problem:
        """The session's current spec, parsed and validated."""
        from codev_engine.pipeline import load_spec

        if not self.spec_path().is_file():
            raise SessionError("the session has no spec.toml yet", file=str(self.path))
        return load_spec(self.spec_path())

    def journal(self) -> list[dict[str, Any]]:
        """Every journal record, oldest first; ``SessionError`` on a malformed line."""
        return store.read_journal(self.path, self.table.names)

    def save_spec(self, problem: Problem) -> str:
        """Make ``problem``'s TOML the session's ``spec.toml``.

        Every spec that was ever ``spec.toml`` keeps a snapshot in ``specs/<sha>.toml``
        (the one replaced included), so an edit saved by the workbench loses nothing.

        Parameters
        ----------
        problem : Problem
            Its ``source`` is stored.

        Returns
        -------
        str
            The SHA-256 of the source.
        """
        if not problem.source.strip():
            raise SessionError("the problem has no TOML source to store in the session")
        return store.save_spec_text(self.path, problem.source)

    def _spec_of(self, spec_sha: str, where: str) -> Problem:
        """The spec snapshot a journal run used, parsed (its stages check it when run)."""
        from codev_engine.pipeline import loads_spec

        text = store.read_spec_snapshot(self.path, spec_sha)
        path = store.snapshot_path(self.path, spec_sha)
        return loads_spec(text, path=str(path), check_mpc=False)

    def last_options(self, journal: list[dict[str, Any]] | None = None) -> RunOptions:
        """The options of the session's latest run (``RunOptions()`` before the first).

        The front ends that run stages themselves (the workbench, the notebook) keep its
        ``sharded``: a session whose law is stored as shards is opened with them, not given
        a serial law beside them.

        Parameters
        ----------
        journal : list of dict, optional
            The journal, when already read.

        Returns
        -------
        RunOptions
        """
        journal = self.journal() if journal is None else journal
        if not journal:
            return RunOptions()
        return RunOptions.from_json(journal[-1]["options"], stages=self.table.names)

    # ---- artifacts -------------------------------------------------------------------

    def artifact_path(
        self, stage: str, key: str, options: RunOptions = DEFAULT_OPTIONS
    ) -> Path:
        """Where stage ``stage``'s artifact for ``key`` is (extension from the table).

        Parameters
        ----------
        stage : str
        key : str
        options : RunOptions
            The run's (a sharded synthesis is a folder, ``.shards``).

        Returns
        -------
        Path
        """
        return store.artifact_path(self.path, stage, key, self.table[stage].extension(options))

    def load(self, stage: str, path: Path, problem: Problem) -> Any:
        """A stage's cached artifact, loaded by the stage, bound to this session.

        What every front end that opens a cached artifact uses (``codev report``, the
        workbench, the notebook; :meth:`run` and :meth:`status` too): a law held as shards
        reads a shard only when a question needs it, after the run that opened it maybe,
        and a shard found damaged then marks the artifact damaged in the index wherever the
        question came from, so that the next run recomputes it (its error says so).

        Parameters
        ----------
        stage : str
            The stage's name.
        path : Path
            The artifact (checked already: ``status`` or the run's check).
        problem : Problem
            The spec it was computed for.

        Returns
        -------
        object
            The stage's value.

        Raises
        ------
        CodevError
            The stage's loader refuses it.
        """
        return self.bind(self.table[stage].load(path, problem))

    def bind(self, value: Any) -> Any:
        """``value``, a law held as shards, told to mark this session's artifact when it
        finds one of its files damaged (``ShardedLaw.on_damaged``); anything else as it is.

        Parameters
        ----------
        value : object
            A stage's value (a law opened from this session's artifacts).

        Returns
        -------
        object
            ``value``.
        """
        if hasattr(value, "on_damaged"):
            value.on_damaged = self._damaged
        return value

    @classmethod
    def holding(cls, path: str | os.PathLike) -> Session | None:
        """The session whose ``artifacts/`` holds ``path``, or None.

        For a law's folder given by its path (``codev export DIR``, ``codev verify --law
        DIR``): bound to its session (:meth:`bind`), a damaged shard it reads is marked
        there as when the session opens it.

        Parameters
        ----------
        path : str or os.PathLike
            An artifact (a file or a folder).

        Returns
        -------
        Session or None
            None when ``path`` is in no session's ``artifacts/`` (or the session is not
            readable: then there is nothing to mark).
        """
        path = Path(path).resolve()
        folder = path.parent.parent
        if path.parent.name != "artifacts" or not (folder / "session.json").is_file():
            return None
        try:
            return cls.open(folder)
        except SessionError:
            return None

    def _check_artifact(
        self, stage: Stage, key: str, options: RunOptions
    ) -> tuple[Path, str | None]:
        """The artifact path and why it cannot be used (None: it can)."""
        path = store.artifact_path(self.path, stage.name, key, stage.extension(options))
        return path, store.check_artifact(self.path, path, key)

    # ---- status ----------------------------------------------------------------------

    def status(
        self, problem: Problem | None = None, options: RunOptions | None = None
    ) -> list[StageStatus]:
        """Cache status per stage, without computing anything.

        Parameters
        ----------
        problem : Problem, optional
            Default: the session's ``spec.toml``.
        options : RunOptions, optional
            Default: those of the latest run.

        Returns
        -------
        list of StageStatus
            In table order, for the stages that apply to the spec.
        """
        problem = problem if problem is not None else self.problem()
        journal = self.journal()
        if options is None:
            options = self.last_options(journal)
        keys = stage_keys(problem, options, self.table)
        out = []
        for stage in self.table:
            if stage.name not in keys:
                continue
            name, key = stage.name, keys[stage.name]
            path, why = self._check_artifact(stage, key, options)
            rel = str(path.relative_to(self.path))
            if why is None:
                try:
                    self.load(name, path, problem)
                except CodevError as exc:
                    out.append(StageStatus(name, key, "corrupt", rel, str(exc)))
                    continue
                out.append(StageStatus(name, key, "cached", rel))
            elif why != "missing":
                out.append(StageStatus(name, key, "corrupt", rel, why))
            elif any(r["stage"] == name for r in journal):
                last = next(r for r in reversed(journal) if r["stage"] == name)
                if last["key"] != key:
                    out.append(
                        StageStatus(name, key, "stale", None, "inputs changed since the last run")
                    )
                else:
                    out.append(StageStatus(name, key, "missing", None, "artifact deleted"))
            else:
                out.append(StageStatus(name, key, "missing", None))
        return out

    # ---- running ---------------------------------------------------------------------

    def run(
        self,
        problem: Problem,
        options: RunOptions = DEFAULT_OPTIONS,
        *,
        fresh: bool = False,
        on_event: EventCallback | None = None,
        warn: Callable[[str], None] | None = None,
        journal: bool = True,
        raise_errors: bool = True,
        executor: Executor | None = None,
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
            with that stage's "failed" StageReport (its outcome holds the error). A file of
            a cached artifact found damaged when read (``DamagedFileError``: a shard of the
            law) is re-raised either way, the artifact marked for the next run to recompute.
        executor : Executor, optional
            Where the stages' parallel work runs (see ``StageRun``); the artifacts, keys
            and journal are the same whatever runs them.

        Returns
        -------
        RunReport

        Raises
        ------
        SpecError
            Before anything is written: options out of range, or a stage's check failing
            (the spec's plant not linearisable, its MPC infeasible) for a stage not cached.
        """
        options.check(stages=self.table.names)
        prepare()  # a fresh installation's kernels, announced, before any stage's clock
        t_run = time.perf_counter()
        emit = on_event or (lambda _s, _e, _d: None)
        say = warn or (lambda _m: None)
        keys = stage_keys(problem, options, self.table)
        stages = self.table.upto(options.upto, keys)
        for stage in stages:
            if stage.check_options is not None:
                stage.check_options(problem, options)
        self.journal()  # a malformed journal fails here, before anything is written
        self._check_stages(problem, options, keys, fresh)
        # (what killed runs left, once the run is known to write: the temporaries no live
        # writer holds, a concurrent run's kept; nothing reads them, they only take space)
        store.remove_temporaries(self.path)
        spec_sha = self.save_spec(problem) if journal else store.sha(problem.source.encode())
        # run 0 until the records are appended: numbered then, under the lock
        report = RunReport(run=0, stages=[], problem=problem)
        values: dict[str, Any] = {}  # stage name -> value, for the stages downstream
        records: list[dict[str, Any]] = []
        try:
            for stage in stages:
                name, key = stage.name, keys[stage.name]
                emit(name, "start", {"key": key})
                started = store.now()
                t0 = time.perf_counter()
                value, status, note = None, "computed", None
                path, why = self._check_artifact(stage, key, options)
                if not fresh and why is None:
                    try:
                        value = self.load(name, path, problem)
                        status = "cached"
                    except CodevError as exc:
                        why = f"unreadable ({exc})"
                if status != "cached":
                    if why not in (None, "missing") and not fresh:
                        note = f"{path.name}: {why}; recomputed"
                        say(f"{self.path}: artifact {note}")
                    try:
                        value = self.bind(stage.compute(
                            StageRun(problem, options, values, path, _progress(emit, name),
                                     executor)
                        ))
                    except CodevError as exc:
                        if isinstance(exc, DamagedFileError):  # (a shard of a cached law)
                            exc = self._damaged(exc)
                        error = {"error": type(exc).__name__, "message": str(exc)}
                        sr = StageReport(name, "failed", key, time.perf_counter() - t0, error)
                        records.append(_record(sr, spec_sha, options, started))
                        if raise_errors or isinstance(exc, DamagedFileError):
                            # (a damaged file of the session is no outcome of the stage: a
                            # replay would report it as a mismatch; the run ends in its line)
                            raise exc from None
                        report.stages.append(sr)
                        emit(name, "done", sr.to_json())
                        break
                    store.register_artifact(self.path, path, name, key)
                outcome, details = stage.describe(value, values)
                values[name] = value
                if stage.report_field is not None:
                    setattr(report, stage.report_field, value)
                seconds = time.perf_counter() - t0
                rel = str(path.relative_to(self.path))
                sr = StageReport(name, status, key, seconds, outcome, details, rel, note)
                report.stages.append(sr)
                records.append(_record(sr, spec_sha, options, started))
                emit(name, "done", sr.to_json())
            self._save_regions(values.get("synthesis"), keys)
        finally:
            if journal and records:
                report.run = store.append_journal(self.path, records, self.table.names)
        report.seconds = time.perf_counter() - t_run
        return report

    def _damaged(self, exc: DamagedFileError) -> DamagedFileError:
        """A file of a cached artifact found damaged when read (a shard of the law: the
        store checks its size when the session opens the law, its SHA-256 is checked when
        it is read: by a stage, or by a front end after the run). The store's rule for a
        damaged artifact: it is not used again, the next run recomputes it (the artifact
        is marked in the index); the error says so. Called by the law itself
        (:meth:`bind`), and by :meth:`run` for an error that comes back from a worker
        (which held a copy of the law, unbound); once per error."""
        if exc.artifact is not None:  # (marked already: by the law, before it reached run)
            return exc
        name = None if exc.file is None else store.mark_damaged(self.path, exc.file,
                                                                exc.reason)
        if name is None:  # (a file of no artifact of this session)
            return exc
        out = DamagedFileError(f"{exc.reason}; the session's next run recomputes {name}",
                               file=exc.file, field=exc.field)
        out.artifact = name
        return out

    def _save_regions(self, law: Any, keys: dict[str, str]) -> None:
        """Write the region cache of a law on demand again when the run grew it, so that
        later runs and other verifications of the same MPC start from its regions."""
        if not getattr(law, "on_demand", False) or not law.grown:
            return
        path = self.artifact_path("synthesis", keys["synthesis"])
        law.save(path)
        store.register_artifact(self.path, path, "synthesis", keys["synthesis"])

    def _check_stages(
        self, problem: Problem, options: RunOptions, keys: dict[str, str], fresh: bool
    ) -> None:
        """Run the check of every stage of the spec whose artifact is not usable.

        Every stage with a key, not only those up to ``upto``: the spec becomes the session's
        ``spec.toml``, so it must be one every stage can run. A cached artifact proves its
        stage's check (and spares its cost, e.g. the MPC's LP and python-control's imports).
        """
        for stage in self.table:
            if stage.check is None or stage.name not in keys:
                continue
            if fresh or self._check_artifact(stage, keys[stage.name], options)[1] is not None:
                stage.check(problem)

    # ---- replay ----------------------------------------------------------------------

    def replay(
        self,
        *,
        on_event: EventCallback | None = None,
        warn: Callable[[str], None] | None = None,
        on_run: Callable[[int, RunReport, list], None] | None = None,
    ) -> ReplayReport:
        """Re-execute every run of the journal (reusing valid cache) and compare outcomes.

        The journal is not modified.

        Parameters
        ----------
        on_event : callable, optional
            Progress, as for :meth:`run`.
        warn : callable, optional
            As for :meth:`run`.
        on_run : callable, optional
            ``on_run(run, report, mismatches)`` after each run is replayed.

        Returns
        -------
        ReplayReport

        Raises
        ------
        SessionError
            The journal is empty, was written by another engine version (its outcomes
            cannot be compared), or a run's spec snapshot is missing or edited.
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
        names = self.table.names
        runs: dict[int, list[dict]] = {}
        for rec in journal:
            runs.setdefault(rec["run"], []).append(rec)
        mismatches: list[tuple[int, str, dict, dict]] = []
        checked = cached = 0
        for run_no, recs in sorted(runs.items()):
            where = f"journal run {run_no}"
            problem = self._spec_of(recs[0]["spec"], where)
            options = RunOptions.from_json(
                recs[0]["options"], where=f"{where}.options", stages=names
            )
            last = max(names.index(r["stage"]) for r in recs)
            options = replace(options, upto=names[last])
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
        """Copy an artifact out of the session atomically (e.g. ``--record FILE.rrd``).

        Parameters
        ----------
        artifact : Path
            The artifact (``RunReport.recording``, ...).
        dest : str or os.PathLike
            Where the copy goes.

        Returns
        -------
        Path
            ``dest``.
        """
        remove_stale_beside(dest)  # (what a copy killed while writing left)
        with atomic_path(dest) as tmp:
            shutil.copyfile(artifact, tmp)
        return Path(dest)


def _progress(emit: EventCallback, stage: str) -> Callable[..., None]:
    def count(c: int, **extra: Any) -> None:
        emit(stage, "progress", {"count": int(c), **extra})

    return count


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
