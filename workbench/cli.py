"""The ``codev`` command line: a thin shell over the engine.

Exit status: 0 success (for ``verify``/``run``: robustly safe), 1 an outcome that is not
a success but not the input's fault either: a verification that is not a proof (unsafe or
unknown), a solver breakdown (``SolverError``, a synthesis past its region limit) or a
``--timeout`` reached; 2 bad input (one line on stderr: file, field, reason); 130 Ctrl-C
(one line; nothing half-written). Progress of long work goes to stderr
(:mod:`workbench.progress`; ``--quiet`` turns it off).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
import unicodedata
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

from codev_engine.errors import CodevError, SolverError, SpecError

__all__ = ["main"]


def _terminal_text(msg: str) -> str:
    """``msg`` with every control, format and separator character escaped (``\\x1b``,
    ``\\u202e``, ``\\n``): an error quoting a hostile spec can neither move the cursor, recolour
    or rewrite the terminal, nor span two lines."""
    out = []
    for ch in str(msg):
        if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Zl", "Zp", "Co", "Cn"):
            out.append(ch.encode("unicode_escape", "backslashreplace").decode("ascii"))
        else:
            out.append(ch)
    return "".join(out)


def _err(msg: str) -> None:
    print(f"codev: error: {_terminal_text(msg)}", file=sys.stderr)


@contextmanager
def _progress(label: str, enabled: bool, unit: str = "regions") -> Iterator[Callable[[int], None]]:
    """A live counter (``unit`` found so far) for one long step: a one-stage
    :func:`_stage_progress`."""
    with _stage_progress(enabled, {label: unit}) as on_event:
        on_event(label, "start", {})
        yield lambda count, **extra: on_event(label, "progress", {"count": count, **extra})
        on_event(label, "done", {"status": "done"})


def _prepare_kernels(*, export: bool = False) -> None:
    """Compile the solver kernels now, announced on stderr, if this installation never did
    (once per machine: ``codev_engine.kernels.prepare``); called by the commands that
    compute, once their input is read (a bad file is reported first). ``export``: the C
    export's kernels too (prepared only when first needed)."""
    from codev_engine.kernels import LATER, prepare

    prepare()
    if export:
        prepare(groups=LATER)


def _clean_beside(*paths: str | os.PathLike | None) -> None:
    """Remove the temporaries a killed write of these output files left beside them (the
    engine's own writers of exports, reports and recordings do the same)."""
    from codev_engine.io.atomic import remove_stale_beside

    remove_stale_beside(*(p for p in paths if p))


def _cmd_synth(args: argparse.Namespace) -> int:
    from codev_engine.pipeline import load_spec
    from codev_engine.synthesis import synthesize

    problem = load_spec(args.spec)
    if (args.sharded or args.shard_dir) and args.workers is None and args.scheduler is None:
        raise SpecError("needs --workers N or --scheduler ADDR (a Dask cluster to shard the "
                        "search across)", field="--sharded" if args.sharded else "--shard-dir")
    _prepare_kernels()
    with _executor(args) as executor, _progress(f"synthesising {problem.name}", True) as update:
        sharded = args.sharded or bool(args.shard_dir)
        # (sharded: each worker writes its shard of the law; none comes back here)
        law = synthesize(problem, progress=update, executor=executor, sharded=sharded,
                         shard_dir=args.shard_dir, out_shards=args.out_shards if sharded else None)
        shards = executor.workers  # (1 when serial)
    out = None
    if args.out_shards:  # (files in the folder: the shards, their facets, the manifest)
        _clean_beside(Path(args.out_shards) / "shards.json", Path(args.out_shards) / "s.npz")
    if args.out:
        _clean_beside(args.out)
        # (a single law file from the shards: merged here, on demand)
        out = str((law.merged() if hasattr(law, "merged") else law).save(args.out))
    if args.out_shards and hasattr(law, "merged"):
        out = out or args.out_shards
    elif args.out_shards:
        from codev_engine.law_shard_writer import split_by_cells, write_law_shards

        # (one checked law file per worker, in cells of space, each with its halo, and the
        # manifest: codev_engine/law_shard_writer.py, law_halo.py)
        write_law_shards(args.out_shards, *split_by_cells(law, shards))
        out = out or args.out_shards
    if args.json:
        print(
            json.dumps(
                {
                    "problem": problem.name,
                    "regions": law.num_regions,
                    "regions_before_merge": law.meta.get("regions_before_merge"),
                    "seconds": law.meta["seconds"],
                    "n": law.n,
                    "m": law.m,
                    "norm": problem.mpc.norm,
                    "horizon": problem.mpc.horizon,
                    "out": out,
                }
            )
        )
        return 0
    mpc = problem.mpc
    print(
        f"{problem.name}: explicit MPC with {law.num_regions} critical regions "
        f"(n={law.n}, m={law.m}, N={mpc.horizon}, norm {mpc.norm}) "
        f"in {law.meta['seconds']:.3f} s"
    )
    if law.meta.get("regions_before_merge") != law.num_regions:
        print(f"  merged from {law.meta['regions_before_merge']} regions (simplify)")
    shown = min(law.num_regions, 5)
    # the law is over theta (the states, prev_<input>, ref_<...>), not the states alone
    theta = law.parameter_names
    if len(theta) != law.n:
        theta = tuple(f"theta{k}" for k in range(law.n))
    if len(theta) != len(law.states):
        print(f"  law over theta = ({', '.join(theta)})")
    inputs = law.inputs if len(law.inputs) == law.m else tuple(f"u{k}" for k in range(law.m))
    for i in range(shown):
        terms = []
        for r in range(law.m):
            # (law.F[i][r]: a sharded law's F takes one index at a time)
            coef = " ".join(f"{v:+.4g}*{s}" for v, s in zip(law.F[i][r], theta, strict=True))
            terms.append(f"{inputs[r]} = {coef} {law.G[i][r]:+.4g}")
        print(f"  region {i}: {law.A[i].shape[0]} facets; " + "; ".join(terms))
    if law.num_regions > shown:
        print(f"  ... {law.num_regions - shown} more regions")
    if out:
        print(f"law written to {out}")
    return 0


def _result_payload(problem, law, result, synth_seconds, tube_path) -> dict:
    """The JSON summary of a verification (``codev verify --json``, ``codev run --json``)."""
    import numpy as np

    from codev_engine.reach.claim import build_claim, width_at_end

    t_end, width, which = width_at_end(problem, result)
    cex = result.counterexample
    return {
        "problem": problem.name,
        "verdict": result.verdict,
        "reason": result.reason,
        "detail": result.detail,
        "hold": result.hold,
        "regions": law.num_regions,
        "synthesis_seconds": synth_seconds,
        "verification_seconds": round(result.seconds, 6),
        "branches": result.stats.get("branches"),
        "partitions": result.stats.get("partitions"),
        "boxes": result.tube.num_boxes,
        "tube_width_at_horizon": [None if not np.isfinite(w) else float(w) for w in width],
        # a verdict stopped by its budget: the best margin to each property, where
        "margins": result.stats.get("margins"),
        "width_at": {"t": t_end, "of": which},  # the set whose width that is
        "counterexample": None
        if cex is None
        else {"x0": cex.x0.tolist(), "t": cex.t, "kind": cex.kind, "index": cex.index,
              **({} if cex.disturbance is None else {"disturbance": {
                  "piece": cex.disturbance.piece,
                  "values": cex.disturbance.values.tolist(),
                  "parameters": cex.disturbance.parameters.tolist(),
                  **({} if cex.disturbance.noise is None
                     else {"noise": cex.disturbance.noise.tolist()})}})},
        "tube": tube_path,
        "claim": build_claim(problem, result).as_dict(),
    }


def _print_result(problem, law, result, tube_path) -> None:
    import numpy as np

    from codev_engine.reach.claim import build_claim, width_at_end

    how = " computed on demand" if getattr(law, "on_demand", False) else ""
    print(f"{problem.name}: {law.num_regions} regions{how}; " + result.summary())
    t_end, width, which = width_at_end(problem, result)
    if np.any(np.isfinite(width)):
        print(f"  width at t = {t_end:.4g} s ({which}): " + np.array2string(width, precision=4))
    else:  # a violation or a limit stopped the tube before t
        print(f"  width at t = {t_end:.4g} s: none (no box of the tube reaches it)")
    print("the claim:")  # what the verdict says, and what it does not
    for line in build_claim(problem, result).lines():
        print("  " + line)
    if tube_path:
        print(f"tube written to {tube_path}")


def _verification(
    args: argparse.Namespace, problem, law, synth_seconds: float | None, executor=None
) -> int:
    from codev_engine.reach.verification import verify

    if problem.verify is None:
        raise CodevError(f"{problem.path}: verify: the spec has no [verify] section")
    with _progress(f"verifying {problem.name}", True, "branches") as update:
        result = verify(
            problem,
            law,
            hold=args.hold,
            max_depth=args.max_depth,
            progress=lambda st: update(
                st.get("branches", 0), samples=st.get("samples"), boxes=st.get("boxes"),
                doing=st.get("doing"),
            ),
            executor=executor,
            budget=args.budget,
        )
    _clean_beside(args.export_tube)
    tube_path = str(result.tube.save(args.export_tube)) if args.export_tube else None
    if getattr(args, "record", None):
        from codev_engine.view.records import RecordingOptions, write_recording

        write_recording(
            args.record,
            problem,
            law,
            result,
            options=RecordingOptions(axes=args.axes, traces=args.traces),
        )
    if args.json:
        payload = _result_payload(problem, law, result, synth_seconds, tube_path)
        payload["recording"] = getattr(args, "record", None)
        print(json.dumps(payload))
    else:
        _print_result(problem, law, result, tube_path)
        if getattr(args, "record", None):
            _say_recording(args.record)
    return 0 if result.verdict == "robustly_safe" else 1


def _say_recording(path) -> None:
    print(f"recording written to {path}\n  view it: {_codev()} view {path}")


def _executor(args: argparse.Namespace):
    """The executor of ``--workers N`` / ``--scheduler ADDR`` (serial without either, or
    ``$CODEV_SCHEDULER``)."""
    from codev_engine.executor import Executor

    if args.workers is not None and args.workers < 1:
        raise SpecError("must be a positive number of workers", field="--workers")
    return Executor(workers=args.workers, scheduler=args.scheduler)


def _add_executor_options(p: argparse.ArgumentParser, what: str) -> None:
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N",
                       help=f"run {what} on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", metavar="ADDR",
                       help=f"run {what} on a running Dask cluster (tcp://HOST:PORT; default "
                       "$CODEV_SCHEDULER, else in this process)")


def _cmd_verify(args: argparse.Namespace) -> int:
    with _executor(args) as executor:
        return _verify_on(args, executor)


def _verify_on(args: argparse.Namespace, executor) -> int:
    from codev_engine.law import ExplicitLaw
    from codev_engine.pipeline import load_spec
    from codev_engine.reach.verification import check_law_matches
    from codev_engine.synthesis import synthesize

    problem = load_spec(args.spec)
    if problem.verify is None:
        raise CodevError(f"{args.spec}: verify: the spec has no [verify] section")
    _prepare_kernels()
    if (getattr(args, "regions", None) or problem.regions) == "reached":
        return _verify_reached(args, problem, executor)
    if args.law:
        if Path(args.law).is_dir():  # (a law written as shards: read lazily)
            law = _sharded_law(args.law)
        else:
            law = ExplicitLaw.load(args.law)
        check_law_matches(problem, law, file=args.law)
        synth_seconds = law.meta.get("seconds")
    else:
        with _progress(f"synthesising {problem.name}", True) as update:
            law = synthesize(problem, progress=_hint_reached(problem, update),
                             executor=executor)
        synth_seconds = law.meta["seconds"]
    return _verification(args, problem, law, synth_seconds, executor)


#: a full synthesis still running after this many seconds, with at least ``HINT_REGIONS``
#: regions, suggests ``--regions reached`` (once) when the design can be verified so
HINT_SECONDS = 15.0
HINT_REGIONS = 1000


def _hint_reached(problem, update: Callable[..., None]) -> Callable[..., None]:
    """``update`` that also says, once, when the full law looks too large to wait for, that
    the verification can run on the regions reached (issue 39): past ``HINT_SECONDS`` and
    ``HINT_REGIONS``, for a design the law on demand serves."""
    import time

    if problem.verify is None:
        return update
    t0, said = time.perf_counter(), [False]

    def progress(count: int, **extra) -> None:
        update(count, **extra)
        t = time.perf_counter() - t0
        if not said[0] and t >= HINT_SECONDS and count >= HINT_REGIONS:
            said[0] = True
            _warn(f"{problem.name}: {count:,} critical regions after {t:.0f} s of synthesis "
                  f"({count / t:,.0f} a second) and counting; if the whole law is out of "
                  "reach, verify on the regions the reach sets meet alone: --regions "
                  "reached (or [synthesis] regions = \"reached\")")

    return progress


def _verify_reached(args: argparse.Namespace, problem, executor) -> int:
    """Verify on the regions the reach sets meet, computed on demand (``--regions reached``
    or ``[synthesis] regions = "reached"``): no law file (the regions are cached in a
    session: ``codev run --session``); a recording draws the regions computed."""
    from codev_engine.law_on_demand import OnDemandLaw

    if getattr(args, "law", None):
        raise SpecError('--law needs the whole law: not with regions = "reached" (a '
                        "session caches the regions computed: codev run --session)",
                        field="--law")
    law = OnDemandLaw(problem)
    return _verification(args, problem, law, None, executor)


def _cmd_run(args: argparse.Namespace) -> int:
    if args.session is None:
        if args.fresh:
            raise SpecError(
                "--fresh needs --session (there is no cache without one)", field="--fresh"
            )
        if args.sharded:
            raise SpecError("--sharded needs --session (the session stores the law's shards; "
                            "without one: codev synth --sharded --out-shards DIR, then codev "
                            "verify --law DIR)", field="--sharded")
        return _cmd_verify(args)
    if args.sharded and args.workers is None and args.scheduler is None:
        raise SpecError("needs --workers N or --scheduler ADDR (a Dask cluster to shard the "
                        "search across)", field="--sharded")
    if args.budget is not None:  # (a session records the spec, where the budget belongs)
        raise SpecError("--budget is not recorded by a session: write [verify] time_budget "
                        "in the spec instead", field="--budget")
    from codev_engine.pipeline import load_spec
    from codev_engine.session import RunOptions, Session

    # bad input fails here or in Session.run's own checks, before the session is touched;
    # the MPC's feasibility LP (python-control, ~1 s of imports) only when not cached
    problem = load_spec(args.spec, check_mpc=False)
    if args.regions and args.regions != problem.regions:
        # (a session runs and replays its spec: the choice must be written in it)
        raise SpecError(f"with --session, write [synthesis] regions = \"{args.regions}\" in "
                        "the spec instead (a session replays its spec)", field="--regions")
    session = Session.open_or_create(args.session)
    _prepare_kernels()
    options = RunOptions(
        hold=args.hold, max_depth=args.max_depth, axes=args.axes, traces=args.traces,
        sharded=args.sharded,
    )
    with _executor(args) as executor, _stage_progress(True) as on_event:
        hint = _hint_reached(problem, lambda count, **extra: None)

        def event(stage: str, what: str, data: dict) -> None:
            on_event(stage, what, data)
            if stage == "synthesis" and what == "progress" and problem.regions == "all":
                hint(int(data.get("count", 0)))

        report = session.run(problem, options, fresh=args.fresh, on_event=event, warn=_warn,
                             executor=executor)
    tube_path = None
    if args.export_tube and report.result is not None:
        _clean_beside(args.export_tube)
        tube_path = str(report.result.tube.save(args.export_tube))
    record = None
    if report.recording is not None:
        record = (
            str(session.export(report.recording, args.record))
            if args.record
            else str(report.recording)
        )
    stages = {
        s.stage: {
            "status": s.status,
            "seconds": round(s.seconds, 6),
            "key": s.key,
            "artifact": s.artifact,
            "outcome": s.outcome,
        }
        for s in report.stages
    }
    law, result = report.law, report.result
    if args.json:
        payload: dict = {"problem": problem.name, "regions": law.num_regions if law else None}
        if result is not None:
            synth = law.meta.get("seconds") if law else None
            payload = _result_payload(problem, law, result, synth, tube_path)
        payload["recording"] = record
        payload["session"] = {
            "dir": str(session.path),
            "run": report.run,
            "seconds": round(report.seconds, 6),
            "stages": stages,
        }
        print(json.dumps(payload))
    else:
        print(f"session {session.path} (run {report.run})")
        for s in report.stages:
            print(f"  {s.stage:<13} {s.status:<9} {s.seconds:8.3f} s  "
                  f"{_stage_text(s.outcome, s.details)}")
        if result is not None:
            _print_result(problem, law, result, tube_path)
        if record:
            _say_recording(record)
    if result is None:
        return 0
    return 0 if result.verdict == "robustly_safe" else 1


def _outcome_text(outcome: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in outcome.items() if v is not None)


def _stage_text(outcome: dict, details: dict) -> str:
    """A stage's outcome, and a law's shards: "regions=N in S shards"."""
    text = _outcome_text(outcome)
    shards = details.get("shards") if isinstance(details, dict) else None
    if shards is None:
        return text
    return f"{text} in {shards} shard{'s' if shards != 1 else ''}"


def _warn(msg: str) -> None:
    print(f"codev: warning: {_terminal_text(msg)}", file=sys.stderr)


@contextmanager
def _stage_progress(
    enabled: bool, units: dict[str, str] | None = None
) -> Iterator[Callable[[str, str, dict], None]]:
    """Progress of each stage on stderr (:mod:`workbench.progress`): a live line per stage on
    a terminal, rate-limited plain lines otherwise; nothing when not ``enabled``."""
    from workbench.progress import stage_progress

    with stage_progress(enabled and not _QUIET[0], units) as on_event:
        yield on_event


#: ``--quiet``: no progress on stderr (set by :func:`main`)
_QUIET = [False]
#: set by the SIGINT handler: an exception that follows Ctrl-C is its consequence (compiled
#: code turns the KeyboardInterrupt raised inside it into a SystemError, a library may wrap
#: it in its own error), so it ends the command as an interrupt, exit 130
_INTERRUPTED = [False]


def _codev() -> str:
    """``codev`` as the user can type it from here (``.venv/bin/codev`` when the checkout's
    venv is not activated; issue 23)."""
    from .commands import runnable

    return runnable("codev")


def _cmd_replay(args: argparse.Namespace) -> int:
    from codev_engine.sweeps.folder import is_sweep

    _prepare_kernels()
    if is_sweep(args.dir):
        return _replay_sweep(args)
    return _replay_session(args)


def _replay_sweep(args: argparse.Namespace) -> int:
    """``codev replay DIR`` of a sweep (``codev sweep --session DIR``): its manifest and
    files checked, every design's session replayed, and each design's row rebuilt from the
    replayed run and compared with the sweep's table."""
    from codev_engine.sweeps.folder import replay_sweep

    def on_design(d: dict) -> None:
        if args.json:
            return
        shown = ", ".join(f"{k} = {_sweep_cell(v)}" for k, v in d["values"].items())
        state = "matches" if d["match"] else (
            f"{d['mismatches']} MISMATCH(ES)" if d["mismatches"] else "ROW MISMATCH")
        print(f"design {d['folder']} [{shown}]: {d['runs']} run(s) -- {state}")

    with _stage_progress(True) as on_event:
        rep = replay_sweep(args.dir, on_design=on_design, on_event=on_event, warn=_warn)
    if args.json:
        print(json.dumps({"dir": str(args.dir), "designs": rep.designs, "match": rep.ok}))
    else:
        print(f"replay of the sweep {args.dir}: {len(rep.designs)} design(s), "
              + ("every outcome matches" if rep.ok else "mismatches"))
    return 0 if rep.ok else 1


def _show_sweep(args: argparse.Namespace) -> int:
    """``codev session DIR`` of a sweep: its runs and its table, every file checked."""
    from codev_engine.sweeps.folder import read_sweep

    sw = read_sweep(args.dir)
    if args.json:
        print(json.dumps({"dir": str(sw.path), "kind": "sweep", "spec": sw.spec,
                          "grid": sw.grid, "runs": sw.journal, "rows": sw.rows,
                          "recording": None if sw.recording is None else str(sw.recording)}))
        return 0
    print(f"sweep {sw.path}: {len(sw.designs)} designs of {sw.spec}, "
          f"{len(sw.journal)} run(s)")
    for run in sw.journal:
        counts: dict[str, int] = {}
        for d in run["designs"]:
            counts[d.get("status", "?")] = counts.get(d.get("status", "?"), 0) + 1
        print(f"  run {run['run']} at {run.get('started')}: {run['seconds']:.2f} s on "
              f"{run.get('executor')} ({run.get('workers')} worker(s)); "
              + ", ".join(f"{v} {k}" for k, v in counts.items()))
    for i, (d, row) in enumerate(zip(sw.designs, sw.rows, strict=True)):
        shown = ", ".join(f"{k} = {_sweep_cell(v)}" for k, v in d["values"].items())
        outcome = row["error"] or f"{row['regions']} regions, {row['verdict']}"
        print(f"  {i}: {d['folder']} [{shown}]: {outcome}")
    if sw.recording is not None:
        print(f"  recording: {sw.recording}\n  view it: {_codev()} view {sw.recording}")
    return 0


def _replay_session(args: argparse.Namespace) -> int:
    from codev_engine.session import Session

    session = Session.open(args.dir)
    quiet = args.json

    def on_run(run_no, rep, mismatches) -> None:
        if quiet:
            return
        parts = ", ".join(f"{s.stage} {s.status}" for s in rep.stages)
        verdict = f"; {rep.result.verdict}" if rep.result is not None else ""
        state = "matches" if not mismatches else f"{len(mismatches)} MISMATCH(ES)"
        print(f"run {run_no}: {parts}{verdict} -- {state}")
        for _r, stage, want, got in mismatches:
            print(f"  {stage}: recorded {_outcome_text(want)}; replayed {_outcome_text(got)}")
        if rep.recording is not None:
            print(f"  recording: {rep.recording}\n  view it: {_codev()} view {rep.recording}")

    with _stage_progress(True) as on_event:
        rep = session.replay(on_event=on_event, warn=_warn, on_run=on_run)
    if args.json:
        print(
            json.dumps(
                {
                    "dir": str(session.path),
                    "runs": rep.runs,
                    "checked": rep.checked,
                    "cached": rep.cached,
                    "match": rep.ok,
                    "mismatches": [
                        {"run": r, "stage": st, "recorded": a, "replayed": b}
                        for r, st, a, b in rep.mismatches
                    ],
                    "seconds": round(rep.seconds, 6),
                }
            )
        )
    else:
        verdict = "every outcome matches" if rep.ok else f"{len(rep.mismatches)} mismatch(es)"
        print(
            f"replay of {session.path}: {rep.runs} run(s), {rep.checked} stage(s) checked "
            f"({rep.cached} cached): {verdict} in {rep.seconds:.2f} s"
        )
    return 0 if rep.ok else 1


def _cmd_session(args: argparse.Namespace) -> int:
    from codev_engine.session import Session
    from codev_engine.sweeps.folder import is_sweep

    if is_sweep(args.dir):
        return _show_sweep(args)
    session = Session.open(args.dir)
    journal = session.journal()
    status = session.status()
    problem = session.problem()
    runs = sorted({r["run"] for r in journal})
    if args.json:
        print(
            json.dumps(
                {
                    "dir": str(session.path),
                    "format": session.meta.get("format"),
                    "engine": session.meta.get("engine"),
                    "created": session.meta.get("created"),
                    "problem": problem.name,
                    "runs": len(runs),
                    "records": len(journal),
                    "last": journal[-1]["started"] if journal else None,
                    "stages": [
                        {
                            "stage": s.stage,
                            "status": s.status,
                            "key": s.key,
                            "artifact": s.artifact,
                            "reason": s.reason,
                        }
                        for s in status
                    ],
                }
            )
        )
        return 0
    meta = session.meta
    print(
        f"session {session.path}: {problem.name}; created {meta.get('created', '?')} by "
        f"codev {meta.get('engine', '?')}"
    )
    last = f", last at {journal[-1]['started']}" if journal else ""
    print(f"journal: {len(runs)} run(s), {len(journal)} stage record(s){last}")
    for s in status:
        where = s.artifact or ""
        why = f" ({s.reason})" if s.reason else ""
        print(f"  {s.stage:<13} {s.status:<8} {where}{why}")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    import shutil

    from codev_engine.view.records import check_recording

    check_recording(args.file)
    has_display = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        sys.platform in ("darwin", "win32")
    )
    viewer = shutil.which("rerun")
    cmd = [viewer] if viewer else [sys.executable, "-m", "rerun"]
    if args.web and not args.print_only:
        port = int(args.port)
        url = f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port + 1}%2Fproxy"
        print(
            f"serving {args.file} at http://127.0.0.1:{port} (no GPU: add &renderer=webgl to "
            f"the address, i.e. {url}&renderer=webgl); Ctrl-C stops the viewer"
        )
        web = [
            *cmd,
            "--web-viewer",
            "--bind",
            "127.0.0.1",
            "--web-viewer-port",
            str(port),
            "--port",
            str(port + 1),
            str(args.file),
        ]
        return run_viewer(web)
    if has_display and not args.print_only:
        print(f"opening {args.file} in the Rerun viewer (closing it or Ctrl-C ends codev view)")
        return run_viewer([*cmd, str(args.file)])
    from .commands import runnable

    codev = runnable("codev")  # works from here, venv activated or not
    print(
        f"{args.file} is a valid recording. There is no display here; to look at it:\n"
        f"  on a machine with a display:  {codev} view {args.file}   "
        f"(or rerun {args.file}; pip install 'rerun-sdk>=0.41,<0.42')\n"
        f"  in a browser, served from here:  {codev} view --web {args.file}   "
        f"(then open the address it prints; without a GPU add &renderer=webgl)\n"
        f"  without the viewer:  {codev} report SESSION_DIR --out report.html"
    )
    return 0


def run_viewer(cmd: list[str], *, grace: float = 3.0) -> int:
    """Run a viewer in its own process group until it exits or Ctrl-C, then stop the group.

    The ``rerun`` console script starts the viewer (and, with ``--web-viewer``, a server)
    as child processes: stopping only the script leaves them running. The whole group is
    sent SIGTERM, then SIGKILL after ``grace`` seconds.

    Parameters
    ----------
    cmd : list of str
        The command.
    grace : float
        Seconds between SIGTERM and SIGKILL.

    Returns
    -------
    int
        The viewer's exit status (130 after Ctrl-C).
    """
    import signal
    import subprocess
    import time

    proc = subprocess.Popen(cmd, start_new_session=True)
    status = 0
    try:
        status = proc.wait()
    except KeyboardInterrupt:
        status = 130
    finally:
        if hasattr(os, "killpg"):
            for sig in (signal.SIGTERM, signal.SIGKILL):
                try:
                    os.killpg(proc.pid, sig)
                except (ProcessLookupError, PermissionError):
                    break  # the group is gone
                deadline = time.monotonic() + grace
                while time.monotonic() < deadline and _group_alive(proc.pid):
                    proc.poll()
                    time.sleep(0.05)
                if not _group_alive(proc.pid):
                    break
        elif proc.poll() is None:
            proc.kill()
        proc.poll()
    return status


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    return True


def _cmd_report(args: argparse.Namespace) -> int:
    from codev_engine.view.report import write_report

    target = Path(args.target)
    if target.is_dir():
        problem, law, result = _from_session(target)
    else:
        from codev_engine.pipeline import load_spec
        from codev_engine.synthesis import synthesize

        problem = load_spec(target)
        if problem.regions == "reached":
            # the regions the verification reaches, computed on demand: the report's
            # partition draws those (and says so), never the whole law
            from codev_engine.law_on_demand import OnDemandLaw

            law = OnDemandLaw(problem)
        else:
            with _progress(f"synthesising {problem.name}", True) as update:
                law = synthesize(problem, progress=update)
        result = None
        if problem.verify is not None:
            from codev_engine.reach.verification import verify

            with _progress(f"verifying {problem.name}", True, "branches") as update:
                result = verify(
                    problem,
                    law,
                    progress=lambda st: update(
                        st.get("branches", 0), samples=st.get("samples"), boxes=st.get("boxes")
                    ),
                )
    out = Path(args.out) if args.out else Path(f"{problem.name}-report.html")
    if out.suffix.lower() not in (".html", ".htm"):
        raise SpecError(f"a report is an .html file (got suffix {out.suffix!r})", field="--out")
    path = write_report(out, problem, law, result, traces=args.traces, axes=args.axes)
    print(f"report written to {path} ({path.stat().st_size / 1e6:.2f} MB; open it in a browser)")
    return 0


def _sharded_law(path: str | Path):
    """The law as shards in folder ``path``; a session's artifact is bound to its session
    (``Session.holding``): a shard found damaged marks it, the next run recomputes it."""
    from codev_engine.law_shards import ShardedLaw
    from codev_engine.session import Session

    law = ShardedLaw.load(path)
    session = Session.holding(path)
    return law if session is None else session.bind(law)


def _from_session(d: Path):
    """The spec, the law and the result (or None) cached in a session folder."""
    from codev_engine.reach.verification import VerificationResult
    from codev_engine.session import Session

    session = Session.open(d)
    problem = session.problem()
    status = {s.stage: s for s in session.status(problem)}
    syn = status.get("synthesis")
    if syn is not None and syn.status == "corrupt":  # (named, with what is wrong with it)
        raise SpecError(
            f"the session's law is unusable ({syn.reason}); its next run recomputes it: "
            f"codev run {session.spec_path()} --session {d}",
            file=str(d / syn.artifact),
        )
    if syn is None or syn.status != "cached":
        raise SpecError(
            f"the session has no cached law for its spec; run: codev run {session.spec_path()} "
            f"--session {d}",
            file=str(d),
        )
    # (the stage's loader, through the session: a full law, the region cache of regions =
    # "reached", or a law as shards, which marks the artifact if a shard it reads is damaged)
    law = session.load("synthesis", d / syn.artifact, problem)
    ver = status.get("verification")
    result = None
    if ver is not None and ver.status == "cached":
        result = VerificationResult.load(d / ver.artifact)
    return problem, law, result


def _cmd_tui(args: argparse.Namespace) -> int:
    if not (sys.stdin.isatty() and sys.stdout.isatty()):
        raise SpecError("codev tui needs a terminal (for scripts use codev run / codev replay)")
    # the workbench is a separate package on top of the engine: imported only here
    from workbench import run_workbench

    return run_workbench(args.target, session_dir=args.session)


#: the benchmark scripts ``codev bench NAME`` runs (``benchmarks/NAME.py`` in the checkout)
#: the scripts of a checkout's benchmarks/ that ``codev bench`` runs: every one
#: (``hylaa_peer.py`` is ``paper.py``'s Hylaa model, not a benchmark of its own)
BENCHMARKS = (
    "mp", "mplp", "synth", "formulations", "export", "paper", "long_horizon", "on_demand",
    "nonlinear_tube", "uncertain_tube", "disturbance", "verdicts", "session", "recording",
    "startup", "first_run", "newcomer", "tui", "panel", "sweep", "scale", "shard_queries",
)



def _sweep_grid(sets: list[str]) -> dict:
    """``--set FIELD=V1,V2,...`` options -> {field: [values]} (each value a TOML value)."""
    from codev_engine.sweeps import parse_sets

    return parse_sets(sets, origin="--set")


def _sweep_cell(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list) and all(isinstance(x, float) or x is None for x in v):
        return "[" + ", ".join(_sweep_cell(x) for x in v) + "]"
    return json.dumps(v) if not isinstance(v, str) else v


def _cmd_sweep(args: argparse.Namespace) -> int:
    from codev_engine.executor import Executor
    from codev_engine.pipeline import load_spec
    from codev_engine.sweeps import sweep

    if not args.set:
        raise SpecError("give at least one --set FIELD=V1,V2,...", field="--set")
    if args.workers is not None and args.workers < 1:
        raise SpecError("must be a positive number of workers", field="--workers")
    grid = _sweep_grid(args.set)
    problem = load_spec(args.spec)
    _prepare_kernels()  # before the first design: no row's time holds the compile
    count = math.prod(len(v) for v in grid.values())
    executor = Executor(workers=args.workers, scheduler=args.scheduler)
    t0 = time.perf_counter()
    done = [0]

    def progress(i: int, row: dict) -> None:
        done[0] += 1
        if args.quiet:
            return
        values = ", ".join(f"{k} = {_sweep_cell(v)}" for k, v in row["values"].items())
        outcome = row["error"] or f"{row['regions']} regions, {row['verdict']}"
        print(f"design {done[0]}/{count} [{values}]: {outcome}", file=sys.stderr, flush=True)

    with executor:  # (every design is read by the loader before the cluster starts)
        if executor.kind != "serial" and not args.quiet:
            executor.client  # noqa: B018 (started, or connected to, here: said when up)
            print(f"codev: sweep: {count} designs on {executor.workers} workers "
                  f"({executor.kind})", file=sys.stderr, flush=True)
        rows = sweep(problem, grid, executor=executor, progress=progress, session=args.session)
    seconds = time.perf_counter() - t0
    if args.json:
        print(json.dumps({"problem": problem.name, "executor": executor.kind,
                          "seconds": round(seconds, 6), "rows": rows}))
    else:
        from rich.console import Console
        from rich.table import Table

        table = Table(title=f"{problem.name}: {count} designs in {seconds:.2f} s "
                      f"({executor.kind})")
        cols = ("regions", "synthesis_seconds", "verdict", "reason", "verification_seconds",
                "tube_width_at_horizon", "width_at_horizon_of", "closed_loop_cost")
        heads = ("regions", "synth s", "verdict", "reason", "verify s", "width at T",
                 "width of", "cost")
        for name in grid:
            table.add_column(name)
        for head in heads:
            table.add_column(head)
        for row in rows:
            cells = [_sweep_cell(row["values"][k]) for k in grid]
            shown = dict(row, verdict="error", reason=row["error"]) if row["error"] else row
            cells += [_sweep_cell(shown[c]) for c in cols]
            table.add_row(*cells)
        Console(width=max(100, _terminal_width())).print(table)
        if args.session:
            from pathlib import Path

            rrd = Path(args.session) / "sweep.rrd"
            print(f"sweep session: {args.session} (replay it: {_codev()} replay "
                  f"{args.session})\n  view it: {_codev()} view {rrd}")
    return 1 if any(row["error"] for row in rows) else 0


def _terminal_width() -> int:
    import shutil

    return shutil.get_terminal_size((120, 24)).columns


def _cmd_bench(args: argparse.Namespace) -> int:
    from workbench.bundled import benchmarks_dir

    folder = benchmarks_dir()
    if folder is None:
        raise CodevError(
            "codev bench needs a checkout of the repository: the benchmarks are not "
            "installed with the package (clone it and run codev bench there)"
        )
    script = folder / f"{args.name}.py"
    if not script.is_file():
        raise CodevError(f"{script}: no such benchmark script in this checkout")
    # in its own process group, stopped with it: Ctrl-C ends the script (SIGTERM, no
    # traceback of its own) and every process it started
    status = run_viewer([sys.executable, str(script), *args.args])
    if status == 130:
        _err("interrupted (Ctrl-C)")
    return status


def _cmd_examples(args: argparse.Namespace) -> int:
    from workbench.bundled import next_steps, write_examples

    written = write_examples(args.dir, force=args.force)
    print(f"wrote {len(written)} example files to {args.dir}:")
    for path in written:
        print(f"  {path}")
    print("next, try:")
    for command in next_steps(args.dir):
        print(f"  {command}")
    return 0


def _axes(text: str) -> tuple[int, int]:
    try:
        parts = tuple(int(p) for p in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("must be two state indices, e.g. 0,1") from None
    if len(parts) != 2 or parts[0] == parts[1] or min(parts) < 0:
        raise argparse.ArgumentTypeError("must be two distinct state indices, e.g. 0,1")
    return parts  # type: ignore[return-value]


class _TimeLimitError(Exception):
    """Raised (by SIGALRM) when ``--timeout`` seconds have passed."""


@contextmanager
def _time_limit(seconds: float | None) -> Iterator[None]:
    """Interrupt the body after ``seconds`` of wall time (main thread, POSIX; else no limit)."""
    if not seconds or not hasattr(signal, "setitimer"):
        yield
        return

    def _expired(_signum, _frame):
        raise _TimeLimitError

    previous = signal.signal(signal.SIGALRM, _expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _cmd_mpsolve(args: argparse.Namespace) -> int:
    from codev_engine.mp.program import MpProgram
    from codev_engine.mp.solve import SolveOptions, mpsolve

    if args.timeout is not None and not args.timeout > 0:
        raise SpecError("must be a positive number of seconds", field="--timeout")
    if args.max_regions is not None and not args.max_regions > 0:
        raise SpecError("must be a positive number of regions", field="--max-regions")
    options = SolveOptions()
    if args.max_regions is not None:
        options = replace(options, max_regions=args.max_regions)
    executor = _executor(args)
    program = MpProgram.load(args.file)
    try:
        with (
            executor,
            _time_limit(args.timeout),
            _progress(f"solving {program.name}", not args.json) as update,
        ):
            sol = mpsolve(program, options=options, progress=update, executor=executor)
    except _TimeLimitError:
        _err(f"{args.file}: no solution within the time limit ({args.timeout:g} s)")
        return 1
    except SolverError as exc:
        _err(f"{args.file}: solver failed: {exc}")
        return 1
    except SpecError as exc:  # found by the solver (empty parameter set, unbounded, ...)
        raise (exc if exc.file else exc.with_file(str(args.file))) from None
    _clean_beside(args.out)
    out = str(sol.save(args.out)) if args.out else None
    if args.json:
        print(
            json.dumps(
                {
                    "name": program.name,
                    "kind": program.kind,
                    "nz": program.nz,
                    "d": program.d,
                    "regions": sol.num_regions,
                    "seconds": round(sol.seconds, 6),
                    "stats": {k: _jsonable(v) for k, v in sol.stats.items()},
                    "out": out,
                }
            )
        )
        return 0
    print(
        f"{program.name}: {sol.num_regions} critical regions in {sol.seconds:.3f} s "
        f"({program.kind}, nz={program.nz}, d={program.d})"
    )
    if out:
        print(f"solution written to {out}")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from codev_engine.deploy.export import export_c, export_python
    from codev_engine.deploy.plan import METHODS, ceil_log2, plan
    from codev_engine.io.npz import read_npz, text

    if not args.c and not args.python:
        raise SpecError("give --c DIR and/or --python FILE.py", field="codev export")
    if args.method not in METHODS:  # (argparse checks too; kept for direct calls)
        raise SpecError(f"must be one of {', '.join(METHODS)}", field="--method")
    if args.c:  # before the plan, which can take minutes on a large law
        from codev_engine.deploy.escape import c_prefix

        try:
            c_prefix(args.name)
        except SpecError as exc:
            raise SpecError(exc.reason, field="--name") from None
    note = None
    if (Path(args.file) / "shards.json").is_file():  # a law as shards (codev synth --out-shards)
        _prepare_kernels(export=True)
        obj, tag = _sharded_law(args.file).merged(), None  # (one table: merged on demand)
    elif Path(args.file).is_dir():
        _prepare_kernels(export=True)  # (the region cache may grow: the mp-QP kernel)
        obj, note = _operation_of(Path(args.file))
        tag = None
    else:
        data = read_npz(args.file, "law or solution file")
        try:
            tag = text(data, "format") if "format" in data else ""
        except SpecError as exc:
            raise exc.with_file(str(args.file)) from None
        _prepare_kernels(export=True)
    if tag is None:
        pass
    elif tag.startswith("codev-mp-solution/"):
        from codev_engine.mp.solution import MpSolution

        obj = MpSolution.load(args.file)
    else:
        from codev_engine.law import ExplicitLaw

        obj = ExplicitLaw.load(args.file)
    try:
        ex = plan(obj, args.method, merge_equal_laws=args.merge_equal_laws)
    except SpecError as exc:
        raise (exc if exc.file else exc.with_file(str(args.file))) from None
    R, d = ex.dep.num_regions, ex.dep.F.shape[2]
    print(
        f"{args.file}: {R} regions, theta of length {d}; {ex.method}: worst case "
        f"{ex.depth} tests on the path (2 ceil(log2 R) + n = {2 * ceil_log2(R) + d}), "
        f"{ex.tests} row evaluations, {ex.macs} multiply-adds per call"
    )
    if args.c:
        h, c = export_c(ex, args.c, name=args.name, float32=args.float32, note=note)
        print(f"C written to {h} and {c}")
    if args.python:
        path = export_python(ex, args.python, note=note)
        print(f"Python written to {path}")
    return 0


def _operation_of(folder: Path):
    """The law of the region of operation of a session verified on demand (``regions =
    "reached"``) and the header note stating it (``deploy.operation``)."""
    from codev_engine.deploy.operation import operation_law, operation_note

    problem, law, result = _from_session(folder)
    if not getattr(law, "on_demand", False):
        # (a law the session stores as shards: its folder, merged there on demand)
        where = f": codev export {law.dir}" if hasattr(law, "shards") else ""
        raise SpecError('a session exports its region of operation with regions = "reached" '
                        f"(export a full law from its law file{where})", file=str(folder))
    if result is None:
        raise SpecError("the session has no verification cached for its spec; run: codev run "
                        f"{folder / 'spec.toml'} --session {folder}", file=str(folder))
    obj, cert = operation_law(problem, law, result)
    return obj, operation_note(problem, cert)


def _jsonable(v):
    """Counters of ``stats`` as plain JSON numbers (numpy scalars included)."""
    if hasattr(v, "item"):
        v = v.item()
    return v if isinstance(v, (int, float, str, bool, type(None))) else str(v)


def _build_parser() -> argparse.ArgumentParser:
    from workbench.bundled import DEFAULT_EXAMPLES_DIR

    parser = argparse.ArgumentParser(
        prog="codev",
        description="Explicit MPC synthesis and closed-loop verification.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command")

    p = sub.add_parser("synth", help="synthesise the explicit MPC law of a spec")
    p.add_argument("spec", help="problem spec (TOML)")
    p.add_argument("--out", help="write the law to this .npz file")
    p.add_argument("--out-shards", metavar="DIR",
                   help="write the law as shards: a checked law file per worker and a "
                   "manifest in DIR (read lazily: codev_engine.law_shards.ShardedLaw)")
    p.add_argument("--json", action="store_true", help="print a JSON summary only")
    _add_executor_options(p, "the mp-QP search")
    p.add_argument("--sharded", action="store_true",
                   help="with --workers/--scheduler: the mp-QP search's state sharded across "
                   "the workers (docs/scale.md)")
    p.add_argument("--shard-dir", metavar="DIR",
                   help="where the sharded search's files go (implies --sharded; default the "
                   "temporary folder): a remote cluster needs one its workers all reach")
    p.set_defaults(func=_cmd_synth)

    for name, helptext in (
        ("verify", "verify the closed loop (synthesises first unless --law is given)"),
        ("run", "synthesise, then verify"),
    ):
        p = sub.add_parser(name, help=helptext)
        p.add_argument("spec", help="problem spec (TOML) with a [verify] section")
        if name == "verify":
            p.add_argument("--law", help="use this law file (from codev synth --out), or folder "
                           "of shards (--out-shards)")
        p.add_argument("--hold", choices=["zoh", "continuous"], help="override verify.hold")
        p.add_argument("--max-depth", type=int, help="override verify.max_depth")
        p.add_argument("--regions", choices=["all", "reached"],
                       help="override synthesis.regions: the whole law, or only the regions "
                       "the reach sets meet, computed on demand (linear MPCs of norm 1, 2 "
                       "or inf)")
        p.add_argument("--export-tube", metavar="FILE", help="write the reachtube (.npz)")
        p.add_argument(
            "--budget", type=float, metavar="SECONDS",
            help="the verification's time budget (overrides verify.time_budget): past it "
            "the verdict is unknown (reason budget) with where the proof stopped and the "
            "best margins reached. Unlike --time-limit (the whole command, synthesis "
            "included, which may end without a verdict) it always ends in a verdict")
        p.add_argument("--json", action="store_true", help="print a JSON summary only")
        _add_executor_options(p, "the mp-QP search and the nonlinear verification's cells")
        p.add_argument("--record", metavar="FILE.rrd", help="write a Rerun recording")
        p.add_argument(
            "--axes",
            type=_axes,
            default=(0, 1),
            metavar="I,J",
            help="state indices of the recording's plane view (default 0,1)",
        )
        p.add_argument(
            "--traces",
            type=int,
            default=16,
            metavar="K",
            help="simulated traces in the recording (default 16)",
        )
        if name == "run":
            p.add_argument(
                "--session",
                metavar="DIR",
                help="keep the spec, a journal and cached artifacts in DIR (created if new)",
            )
            p.add_argument(
                "--fresh", action="store_true", help="recompute every stage (with --session)"
            )
            p.add_argument(
                "--sharded", action="store_true",
                help="with --session and --workers/--scheduler: the mp-QP search sharded "
                "across the workers, each writing its shard of the law into the session "
                "(a folder of shards, read lazily; docs/sessions.md)")
            p.set_defaults(func=_cmd_run, law=None)
        else:
            p.set_defaults(func=_cmd_verify, law=None, session=None)

    p = sub.add_parser(
        "sweep",
        help="synthesise and verify every design of a grid of spec values (a table)",
        description="The Cartesian product of the --set values, each design synthesised and "
        "verified: a table (JSON rows with --json), progress per design on stderr. Values are "
        "TOML values: --set mpc.horizon=2,4,6 --set 'mpc.R=[[0.1]],[[1.0]]' "
        "--set 'mpc.norm=\"inf\",\"1\"'. Exit 2 on a bad value, 1 when a design's "
        "synthesis broke down.",
    )
    p.add_argument("spec", help="the base design (TOML)")
    p.add_argument("--set", action="append", metavar="FIELD=V1,V2,...",
                   help="a dotted spec field and its values (repeat for more fields)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N",
                       help="run the designs on a local Dask cluster of N worker processes")
    where.add_argument("--scheduler", metavar="ADDR",
                       help="run them on a running Dask cluster (tcp://HOST:PORT; default "
                       "$CODEV_SCHEDULER, else serial)")
    p.add_argument(
        "--session",
        metavar="DIR",
        help="make DIR the sweep's session: each design runs as a session in DIR/<id> (a "
        "rerun loads unchanged designs from their caches), DIR/sweep.json lists the designs "
        "and the table, DIR/journal.jsonl each sweep run, DIR/sweep.rrd is its Rerun "
        "recording; codev replay DIR reproduces the whole sweep",
    )
    p.add_argument("--json", action="store_true", help="print the rows as JSON only")
    p.set_defaults(func=_cmd_sweep)

    p = sub.add_parser("replay", help="re-execute a session's journal and compare outcomes")
    p.add_argument("dir", metavar="DIR",
                   help="the session folder, or a sweep's (codev sweep --session DIR)")
    p.add_argument("--json", action="store_true", help="print a JSON summary only")
    p.set_defaults(func=_cmd_replay)

    p = sub.add_parser("session", help="show a session: journal and what is cached or stale")
    p.add_argument("dir", metavar="DIR", help="the session folder")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=_cmd_session)

    p = sub.add_parser(
        "examples",
        help="write the bundled example specs and notebook to a folder",
        description="Write the bundled example specs (*.toml) and notebook (*.ipynb) to DIR.",
    )
    p.add_argument(
        "dir",
        nargs="?",
        default=DEFAULT_EXAMPLES_DIR,
        metavar="DIR",
        help=f"the folder to write to, created if missing (default ./{DEFAULT_EXAMPLES_DIR})",
    )
    p.add_argument("--force", action="store_true", help="overwrite files that exist already")
    p.set_defaults(func=_cmd_examples)

    p = sub.add_parser(
        "bench",
        help="run a benchmark against the peers (benchmarks/NAME.py of a checkout; "
        "see benchmarks/README.md)",
    )
    p.add_argument("name", choices=BENCHMARKS)
    p.add_argument("args", nargs=argparse.REMAINDER, help="passed to the script (--help)")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser(
        "tui", help="the design workbench: plant, MPC, synthesis, verification, session"
    )
    p.add_argument(
        "target",
        nargs="?",
        metavar="SPEC.toml|SESSION_DIR",
        help="a spec (its session is sessions/<name>, or --session) or a session folder",
    )
    p.add_argument("--session", metavar="DIR", help="the session folder for a spec")
    p.set_defaults(func=_cmd_tui)

    p = sub.add_parser("view", help="open a Rerun recording (.rrd) in the viewer")
    p.add_argument("file", metavar="FILE.rrd")
    p.add_argument(
        "--print-only", action="store_true", help="only print how to open it, even with a display"
    )
    p.add_argument(
        "--web",
        action="store_true",
        help="serve it to a browser from here (127.0.0.1) until Ctrl-C, then stop the server",
    )
    p.add_argument(
        "--port", type=int, default=9090, help="web viewer port (the data on PORT+1; default 9090)"
    )
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser(
        "report",
        help="write a self-contained HTML report of a design (for any browser)",
        description="Write one HTML file (figures inline, nothing fetched): the verdict, the "
        "tube per state and in the plane, the partition, the inputs, the spec. From a session "
        "folder its cached law and result are used; from a spec they are computed.",
    )
    p.add_argument("target", metavar="SESSION_DIR|SPEC.toml")
    p.add_argument("--out", metavar="FILE.html", help="default ./<name>-report.html")
    p.add_argument("--traces", type=int, default=16, metavar="K", help="simulated traces")
    p.add_argument(
        "--axes", type=_axes, default=(0, 1), metavar="I,J", help="the plane's state indices"
    )
    p.set_defaults(func=_cmd_report)

    p = sub.add_parser(
        "mpsolve", help="solve a multi-parametric LP/QP (.npz, the mp_testset convention)"
    )
    p.add_argument("file", metavar="FILE.npz", help="the program (arrays H, c, C, A, b, F, ...)")
    p.add_argument("--out", metavar="SOLUTION.npz", help="write the explicit solution")
    p.add_argument("--json", action="store_true", help="print a JSON summary only")
    p.add_argument(
        "--timeout",
        type=float,
        metavar="S",
        help="give up after S seconds of wall time (exit 1)",
    )
    p.add_argument(
        "--max-regions",
        type=int,
        metavar="N",
        help="give up past N critical regions (exit 1; default 1,000,000, ~2.5 GB)",
    )
    _add_executor_options(p, "the mp-QP search's candidates")
    p.set_defaults(func=_cmd_mpsolve)

    p = sub.add_parser(
        "export", help="write a law (or an mp solution) as C99 or Python code"
    )
    p.add_argument("file", metavar="LAW.npz|SOLUTION.npz|SESSION",
                   help="a law or mp solution file, or a session verified with regions = "
                   "\"reached\": the law of its region of operation (certified)")
    p.add_argument("--c", metavar="DIR", help="write DIR/PREFIX.h and DIR/PREFIX.c")
    p.add_argument("--python", metavar="FILE.py", help="write a numpy-only Python module")
    p.add_argument("--name", default="codev_law", metavar="PREFIX",
                   help="file and symbol prefix of the C code (default codev_law)")
    p.add_argument("--float32", action="store_true", help="float instead of double in C")
    p.add_argument("--method", default="auto", choices=("bst", "sequential", "auto"),
                   help="binary search tree, sequential search, or the cheaper (default)")
    p.add_argument("--merge-equal-laws", action="store_true",
                   help="regions with equal laws share tree leaves (same region returned)")
    p.set_defaults(func=_cmd_export)
    for name in ("synth", "verify", "run", "sweep", "replay"):
        sub.choices[name].add_argument(
            "--time-limit",
            type=float,
            metavar="SECONDS",
            help="end the command after SECONDS: a verification is unknown (reason limit), "
            "a synthesis one line, exit 1 (also CODEV_LIMITS=time=SECONDS; for the "
            "verification alone, with margins: --budget)",
        )
    for name in ("synth", "verify", "run", "sweep", "replay", "mpsolve", "report"):
        sub.choices[name].add_argument(
            "-q",
            "--quiet",
            action="store_true",
            help="no progress on stderr (by default: a live line on a terminal, else a plain "
            "line once work has run 1 s, then every 4 s)",
        )
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``codev`` console script.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: 0 success (or robustly safe), 1 unsafe / unknown / solver failure,
        2 bad input (one line on stderr naming the file, the field and the reason), 130
        interrupted by Ctrl-C (one line), 141 stdout's reader went away (``| head``; silent).
    """
    parser = _build_parser()
    args = parser.parse_args(argv)
    _QUIET[0] = bool(getattr(args, "quiet", False))
    try:
        with _interrupt_once():
            return _dispatch(parser, args)
    except KeyboardInterrupt:  # (between two handlers)
        _err("interrupted (Ctrl-C)")
        return 130


@contextmanager
def _interrupt_once() -> Iterator[None]:
    """Ctrl-C (SIGINT) raises KeyboardInterrupt once; a second is ignored while the command
    unwinds (pools stopped, temporary files removed, the journal written), so it cannot cut
    that cleanup short; a third exits at once (status 130; at worst a ``.tmp-*`` file is
    left, which no reader looks at). The previous handler is put back after. In the main
    thread only (elsewhere Python's default stays)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    count = [0]

    def _handler(_signum, _frame):
        count[0] += 1
        _INTERRUPTED[0] = True
        if count[0] == 1:
            raise KeyboardInterrupt
        if count[0] >= 3:
            _err("interrupted (Ctrl-C three times: stopped at once)")
            os._exit(130)

    _INTERRUPTED[0] = False
    previous = signal.signal(signal.SIGINT, _handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _dispatch(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Run the subcommand; every failure is one line on stderr and an exit status."""
    if args.version:
        from codev_engine.version import __version__

        print(__version__)
        return 0
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _check_counts(args)
        with _command_deadline(args):
            status = int(args.func(args))
        sys.stdout.flush()  # here, where a reader gone away (BrokenPipeError) is handled
        return status
    except KeyboardInterrupt:
        _err("interrupted (Ctrl-C)")
        return 130
    except Exception as exc:
        if _INTERRUPTED[0]:  # a consequence of Ctrl-C (see _INTERRUPTED)
            _err("interrupted (Ctrl-C)")
            return 130
        if isinstance(exc, BrokenPipeError):  # `codev run ... | head`: the reader left
            # as a program killed by SIGPIPE would: no message, status 128 + 13; stdout
            # pointed at /dev/null so that the interpreter's final flush cannot fail again
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 141
        if isinstance(exc, SolverError):  # the engine's failure, not the input's
            _err(str(exc))
            return 1
        if isinstance(exc, CodevError):
            _err(str(exc))
            return 2
        if isinstance(exc, MemoryError):  # past what the limits foresaw: still one line
            _err(
                "out of memory: the work outgrew this machine (docs/spec.md, \"Limits\"; "
                "CODEV_LIMITS=region_bytes=...,tube_bytes=... lowers the limits)"
            )
            return 1
        if isinstance(exc, OSError):
            name = getattr(exc, "filename", None)
            _err(f"{name}: {exc.strerror}" if name else str(exc))
            return 2
        # a bug in codev: one line, the traceback on request
        if os.environ.get("CODEV_DEBUG"):
            raise
        _err(f"internal error ({exc.__class__.__name__}: {exc}); set CODEV_DEBUG=1 for details")
        return 1


def _check_counts(args: argparse.Namespace) -> None:
    """Bound the options that size work, where they are read: one line naming the option."""
    from codev_engine.session.options import MAX_DEPTH, MAX_TRACES

    traces = getattr(args, "traces", None)
    if traces is not None and not 0 <= traces <= MAX_TRACES:
        raise SpecError(f"must be 0..{MAX_TRACES:,} simulated traces, got {traces:,}",
                        field="--traces")
    depth = getattr(args, "max_depth", None)
    if depth is not None and not 0 <= depth <= MAX_DEPTH:
        raise SpecError(f"must be 0..{MAX_DEPTH}, got {depth:,}", field="--max-depth")
    for flag in ("time_limit", "budget"):
        limit = getattr(args, flag, None)
        if limit is not None and not (math.isfinite(limit) and limit > 0):
            raise SpecError(f"must be a positive number of seconds, got {limit:g}",
                            field="--" + flag.replace("_", "-"))


#: seconds past the deadline before the backstop interrupts work that does not check it
_BACKSTOP_GRACE = 2.0


@contextmanager
def _command_deadline(args: argparse.Namespace) -> Iterator[None]:
    """The command's time limit: ``--time-limit`` or ``CODEV_LIMITS=time=...``.

    The engine checks the deadline cooperatively (``codev_engine.limits``): a verification
    ends ``unknown`` (reason ``limit``), a synthesis in one line. A stretch of work that
    reports no progress (one long LP, a compiled kernel) is interrupted by SIGALRM
    ``_BACKSTOP_GRACE`` seconds later with the same one line, exit 1.
    """
    from codev_engine.limits import TimeLimitError, deadline, limits

    seconds = getattr(args, "time_limit", None)
    if "time_limit" not in vars(args):  # a command without a time limit
        yield
        return
    env = limits()["time"]
    if env and (seconds is None or env < seconds):
        seconds = float(env)
    if not seconds:
        yield
        return

    def _expired(_signum, _frame):
        raise TimeLimitError(
            f"time limit reached: stopped after {seconds:g} s; raise --time-limit / "
            "CODEV_LIMITS=time=SECONDS, or make the work smaller (mpc.horizon, "
            "verify.initial_set, verify.time_horizon)"
        )

    backstop = hasattr(signal, "setitimer") and _in_main_thread()
    if backstop:
        previous = signal.signal(signal.SIGALRM, _expired)
        signal.setitimer(signal.ITIMER_REAL, seconds + _BACKSTOP_GRACE)
    # the last resort: a compiled solver that holds the main thread for minutes (one dense
    # LP of a long horizon) lets no Python handler run; past a longer grace the command
    # ends from this thread, with the same line (artifacts are written atomically: what
    # was being written is not there, what was written is whole)
    ended = threading.Event()
    last_resort = threading.Thread(
        target=_hard_stop, args=(ended, seconds), name="codev-time-limit", daemon=True
    )
    last_resort.start()
    try:
        with deadline(seconds):
            yield
    finally:
        ended.set()
        if backstop:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)


#: seconds past the deadline before a command that did not stop is ended from a thread
_HARD_GRACE = 10.0


def _hard_stop(ended: threading.Event, seconds: float) -> None:
    """Wait for the command to end; past its deadline by :data:`_HARD_GRACE` seconds, say
    the one line, stop the child processes and exit with status 1."""
    if ended.wait(seconds + _HARD_GRACE):
        return
    import multiprocessing

    _err(
        f"time limit reached: stopped after {seconds:g} s (inside a compiled solver that "
        "does not check the time); raise --time-limit / CODEV_LIMITS=time=SECONDS, or make "
        "the work smaller (mpc.horizon, verify.initial_set, verify.time_horizon)"
    )
    for child in multiprocessing.active_children():
        child.terminate()
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(1)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _path(s: str) -> Path:
    return Path(s)


if __name__ == "__main__":
    sys.exit(main())
