"""Benchmark: ``mpsolve`` on the whole mp_testset, against PPOPT 1.6.12, in the same run.

Usage::

    python benchmarks/mp.py [FOLDER] [--timeout 60] [--jobs 2] [--no-peer]
                            [--problems a,b,pop_mpqp_0*] [--json OUT]

FOLDER defaults to ``../shared/benchmarks/mp_testset`` beside the repository (the test set is
never copied into the repository). For every problem and solver, one subprocess (its own
process group, killed at ``--timeout`` + 5 s wall: start-up and imports are not charged to
the limit, as in the test set's README); at most ``--jobs`` (<= 2) subprocesses at a time.

* **Ours**: ``ce.MpProgram(...)`` from the file's arrays, then ``ce.mpsolve``; time = build +
  solve (``time.perf_counter``), imports and file reading excluded.
* **PPOPT**: ``MPQP_Program`` (``MPLP_Program`` for an mp-LP) with default constraint
  processing, equalities stacked on top of ``A`` and passed as ``equality_indices``, then
  ``solve_mpqp(prog, mpqp_algorithm.combinatorial)`` (as the test set's README measured it,
  for mp-LPs too); time = build + solve.

A run that ends after the limit counts as a timeout. Region counts are reported as found,
next to the test set's ``ref_regions`` (not checked: ``tests/engine/test_mp_testset.py`` is
the conformance suite). Prints a table, totals, the number solved by each and the geometric
mean of the speed ratio PPOPT s / ours s over the problems both solve. It is a benchmark,
not a test: it asserts nothing and exits 0 unless it crashes.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_FOLDER = ROOT.parent / "shared" / "benchmarks" / "mp_testset"
GRACE = 5.0  # seconds of wall time for start-up and imports, on top of --timeout
SOLVERS = ("ours", "ppopt")


# ---------------------------------------------------------------------------------------
# the workers (run inside the subprocess)
# ---------------------------------------------------------------------------------------


def _arrays(path: str) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def worker_ours(path: str) -> dict:
    import codev_engine as ce
    import codev_engine.mp.mpqp_kernel

    # imports are not charged: codev_engine loads its modules lazily, on first use (this
    # includes numba, which the compiled mp-QP kernel needs; loading the compiled code
    # itself, at the first candidate it evaluates, is charged)
    import codev_engine.mp.program
    import codev_engine.mp.solve  # noqa: F401

    data = _arrays(path)
    keys = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq")
    import resource

    def cpu() -> float:  # this process and its reaped children (the search's workers)
        me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(
            resource.RUSAGE_CHILDREN
        )
        return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime

    t0, c0 = time.perf_counter(), cpu()
    prog = ce.MpProgram(**{k: data[k] for k in keys if k in data}, name=Path(path).stem)
    sol = ce.mpsolve(prog)
    seconds = time.perf_counter() - t0
    return {
        "regions": sol.num_regions,
        "seconds": seconds,
        "cpu_seconds": cpu() - c0,
        "workers": sol.stats.get("workers", 1),
        "solve_seconds": sol.seconds,
    }


def worker_ppopt(path: str) -> dict:
    import warnings

    warnings.simplefilter("ignore")
    from ppopt.mp_solvers.solve_mpqp import mpqp_algorithm, solve_mpqp
    from ppopt.mplp_program import MPLP_Program
    from ppopt.mpqp_program import MPQP_Program

    d = _arrays(path)
    A, b, F = d["A"], d["b"], d["F"]
    eq: list[int] = []
    if "Aeq" in d and d["Aeq"].shape[0]:
        me = d["Aeq"].shape[0]
        A = np.vstack([d["Aeq"], A])
        b = np.concatenate([d["beq"], b])
        F = np.vstack([d["Feq"], F])
        eq = list(range(me))
    t0 = time.perf_counter()
    common = dict(
        A=A,
        b=b.reshape(-1, 1),
        c=d["c"].reshape(-1, 1),
        H=d["C"],
        A_t=d["A_theta"],
        b_t=d["b_theta"].reshape(-1, 1),
        F=F,
        equality_indices=eq or None,
    )
    if np.any(d["H"]):
        prob = MPQP_Program(Q=d["H"], **common)
    else:
        prob = MPLP_Program(**common)
    t1 = time.perf_counter()
    sol = solve_mpqp(prob, mpqp_algorithm.combinatorial)
    t2 = time.perf_counter()
    return {
        "regions": len(sol.critical_regions),
        "seconds": t2 - t0,
        "build_seconds": t1 - t0,
        "solve_seconds": t2 - t1,
    }


def run_worker(solver: str, path: str, out: str) -> None:
    try:
        res = {"status": "ok", **(worker_ours(path) if solver == "ours" else worker_ppopt(path))}
    except Exception as exc:  # noqa: BLE001 - a benchmark reports whatever failed
        tb = traceback.extract_tb(exc.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno}" if tb else ""
        res = {"status": "error", "error": f"{type(exc).__name__}: {exc}"[:300], "where": where}
    Path(out).write_text(json.dumps(res))


# ---------------------------------------------------------------------------------------
# the driver
# ---------------------------------------------------------------------------------------


class Job:
    def __init__(self, solver: str, path: Path, workdir: Path):
        self.solver, self.path = solver, path
        self.out = workdir / f"{path.stem}.{solver}.json"
        self.log = workdir / f"{path.stem}.{solver}.log"
        self.proc: subprocess.Popen | None = None
        self.t0 = 0.0
        self.load = float("nan")

    def start(self) -> None:
        cmd = [
            sys.executable,
            str(Path(__file__).resolve()),
            "--_worker",
            self.solver,
            str(self.path),
            str(self.out),
        ]
        env = dict(os.environ)
        # one BLAS thread per process: two processes share two cores
        for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env[var] = "1"
        self.load = os.getloadavg()[0]
        self.t0 = time.perf_counter()
        with open(self.log, "wb") as log:
            self.proc = subprocess.Popen(
                cmd, stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True, cwd=ROOT
            )

    def _kill(self) -> None:
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)  # the group: any worker pool too
        except (ProcessLookupError, PermissionError):
            pass

    def poll(self, timeout: float) -> dict | None:
        """The result when the job is over (None while it runs)."""
        wall = time.perf_counter() - self.t0
        if self.proc.poll() is None:
            if wall <= timeout + GRACE:
                return None
            self._kill()
            self.proc.wait()
            return {"status": "timeout", "wall": wall, "load_before": self.load}
        self._kill()  # a pool left behind
        if not self.out.exists():
            tail = self.log.read_text(errors="replace")[-300:]
            return {
                "status": "crash",
                "error": f"exit {self.proc.returncode}: {tail}",
                "wall": wall,
                "load_before": self.load,
            }
        res = json.loads(self.out.read_text())
        res.update(wall=wall, load_before=self.load)
        if res["status"] == "ok" and res["seconds"] > timeout:
            res["status"] = "timeout"
        return res


def problem_info(path: Path) -> dict:
    d = _arrays(str(path))
    return {
        "name": path.stem,
        "kind": str(d["kind"]) if "kind" in d else ("mplp" if not np.any(d["H"]) else "mpqp"),
        "nz": int(d["H"].shape[0]),
        "d": int(d["A_theta"].shape[1]),
        "ref": int(d["ref_regions"]) if "ref_regions" in d else None,
    }


def fmt_s(x) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.3f}" if x < 10 else f"{x:.1f}"


def cell(res: dict | None, timeout: float) -> tuple[str, str]:
    if res is None:
        return "", ""
    st = res["status"]
    if st == "ok":
        return str(res["regions"]), fmt_s(res["seconds"])
    if st == "timeout":
        return ("timeout (README)" if res.get("readme") else "timeout"), f">{timeout:g}"
    return st.upper(), "-"


def row_ratio(row: dict) -> float | None:
    o, p = row.get("ours"), row.get("ppopt")
    if o and p and o["status"] == "ok" and p["status"] == "ok" and o["seconds"] > 0:
        return p["seconds"] / o["seconds"]
    return None


def ratio_at_least(row: dict, timeout: float) -> float | None:
    """PPOPT timed out where ours solved: its time is above ``timeout``, so the ratio is at
    least ``timeout / ours`` (None otherwise)."""
    o, p = row.get("ours"), row.get("ppopt")
    if o and p and o["status"] == "ok" and p["status"] == "timeout" and o["seconds"] > 0:
        return timeout / o["seconds"]
    return None


def ratio_text(row: dict, timeout: float) -> str:
    """The ratio cell: ``12.3x``, ``>=45.6x`` (PPOPT timed out) or empty."""
    ratio = row_ratio(row)
    if ratio is not None:
        return f"{ratio:.1f}x"
    bound = ratio_at_least(row, timeout)
    return f">={bound:.1f}x" if bound is not None else ""


def table(rows: list[dict], with_peer: bool, timeout: float) -> str:
    head = ["name", "kind", "nz", "d", "ref", "our regions", "our s"]
    if with_peer:
        head += ["PPOPT regions", "PPOPT s", "ratio"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            r["name"],
            r["kind"],
            str(r["nz"]),
            str(r["d"]),
            str(r["ref"]) if r["ref"] is not None else "",
        ]
        cells += list(cell(r.get("ours"), timeout))
        if with_peer:
            cells += list(cell(r.get("ppopt"), timeout))
            cells.append(ratio_text(r, timeout))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def totals(rows: list[dict], with_peer: bool) -> tuple[str, dict]:
    def ok(r, s):
        return r.get(s) is not None and r[s]["status"] == "ok"

    out: dict = {"problems": len(rows)}
    lines = []
    for s in SOLVERS if with_peer else ("ours",):
        solved = [r for r in rows if ok(r, s)]
        counts: dict[str, int] = {}
        for r in rows:
            if r.get(s) is not None:
                counts[r[s]["status"]] = counts.get(r[s]["status"], 0) + 1
        by_kind = {k: sum(1 for r in solved if r["kind"] == k) for k in ("mpqp", "mplp")}
        secs = sum(r[s]["seconds"] for r in solved)
        out[s] = {
            "solved": len(solved),
            "status_counts": counts,
            "solved_by_kind": by_kind,
            "seconds_solved": secs,
        }
        label = "ours " if s == "ours" else "PPOPT"
        lines.append(
            f"{label}: solved {len(solved)} of {len(rows)} ({by_kind['mpqp']} mp-QP, "
            f"{by_kind['mplp']} mp-LP); outcomes {counts}; {secs:.1f} s on those"
        )
    if with_peer:
        both = [r for r in rows if ok(r, "ours") and ok(r, "ppopt")]
        ratios = [row_ratio(r) for r in both]
        only_ours = [r["name"] for r in rows if ok(r, "ours") and not ok(r, "ppopt")]
        only_peer = [r["name"] for r in rows if ok(r, "ppopt") and not ok(r, "ours")]
        so = sum(r["ours"]["seconds"] for r in both)
        sp = sum(r["ppopt"]["seconds"] for r in both)
        gm = math.exp(sum(math.log(x) for x in ratios) / len(ratios)) if ratios else None
        # ours may use both cores on large mp-QPs (PPOPT's combinatorial uses one): the
        # ratio of PPOPT's wall time to our CPU time charges ours for every core it used
        cpu = [
            r["ppopt"]["seconds"] / r["ours"]["cpu_seconds"]
            for r in both
            if r["ours"].get("cpu_seconds")
        ]
        gm_cpu = math.exp(sum(math.log(x) for x in cpu) / len(cpu)) if cpu else None
        same = sum(1 for r in both if r["ours"]["regions"] == r["ppopt"]["regions"])
        out["both"] = {
            "solved": len(both),
            "ours_seconds": so,
            "ppopt_seconds": sp,
            "geomean_ratio": gm,
            "geomean_ratio_vs_our_cpu": gm_cpu,
            "same_region_count": same,
            "only_ours": only_ours,
            "only_ppopt": only_peer,
        }
        lines.append(
            f"both solve {len(both)}: ours {so:.1f} s, PPOPT {sp:.1f} s; geometric "
            f"mean of PPOPT s / ours s = "
            f"{'-' if gm is None else f'{gm:.2f}x'} (against our CPU time: "
            f"{'-' if gm_cpu is None else f'{gm_cpu:.2f}x'}); same region count on {same}"
        )
        lines.append(
            f"only ours: {len(only_ours)}; only PPOPT: {len(only_peer)}"
            + (f" ({', '.join(only_peer)})" if only_peer else "")
        )
    return "\n".join(lines), out


def engine_info() -> dict:
    """Where ``codev_engine`` is imported from, and (read-only) the repository's commit."""
    import codev_engine as ce

    info: dict = {"module": str(Path(ce.__file__).resolve().parent)}
    try:
        info["repo_head"] = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        info["repo_engine_modified"] = bool(
            subprocess.run(
                ["git", "-C", str(ROOT), "status", "--porcelain", "--", "codev_engine"],
                capture_output=True,
                text=True,
                check=True,
            ).stdout.strip()
        )
    except (OSError, subprocess.CalledProcessError):
        pass
    return info


def readme_timeouts(folder: Path) -> set[str]:
    """Problems whose PPOPT column in the test set's README says it timed out."""
    out = set()
    readme = folder / "README.md"
    if readme.exists():
        for line in readme.read_text(encoding="utf-8").splitlines():
            cells = [c.strip() for c in line.split("|")]
            if len(cells) > 10 and cells[10].startswith("FAIL (timeout"):
                out.add(cells[1])
    return out


def select(files: list[Path], spec: str | None) -> list[Path]:
    if not spec:
        return files
    pats = [p.strip() for p in spec.split(",") if p.strip()]
    chosen = [f for f in files if any(fnmatch.fnmatch(f.stem, p) for p in pats)]
    unknown = [p for p in pats if not any(fnmatch.fnmatch(f.stem, p) for f in files)]
    if unknown:
        raise SystemExit(f"no problem matches {unknown}")
    return chosen


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_worker":
        run_worker(*argv[1:4])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "folder",
        nargs="?",
        default=str(DEFAULT_FOLDER),
        help="the mp_testset folder (default: %(default)s)",
    )
    ap.add_argument(
        "--timeout",
        type=float,
        default=60.0,
        help="limit per solve, seconds (default 60; +5 s for start-up)",
    )
    ap.add_argument(
        "--jobs", type=int, default=2, choices=[1, 2], help="subprocesses at a time (default 2)"
    )
    ap.add_argument("--no-peer", action="store_true", help="run ours only")
    ap.add_argument(
        "--peer-skip-readme-timeouts",
        action="store_true",
        help="do not rerun PPOPT where the test set's README measured a timeout on this "
        "machine (saves ~55 min); those count as PPOPT timeouts, marked 'readme'",
    )
    ap.add_argument("--problems", help="comma-separated names or patterns (pop_mpqp_00*)")
    ap.add_argument("--json", metavar="OUT", help="write the rows and totals as JSON")
    args = ap.parse_args(argv)

    folder = Path(args.folder)
    if not folder.is_dir():
        raise SystemExit(f"mp_testset folder not found: {folder}")
    files = select(sorted(folder.glob("*.npz")), args.problems)
    with_peer = not args.no_peer
    peer_version = None
    if with_peer:
        try:
            from importlib.metadata import version

            import ppopt  # noqa: F401

            peer_version = version("ppopt")
        except Exception as exc:  # noqa: BLE001
            print(f"PPOPT cannot be imported ({exc}); running ours only", file=sys.stderr)
            with_peer = False

    solvers = SOLVERS if with_peer else ("ours",)
    rows = {f.stem: problem_info(f) for f in files}
    load_start = os.getloadavg()
    t_start = time.perf_counter()
    print(
        f"engine: {engine_info()}; PPOPT {peer_version or 'not run'}; {len(files)} problems; "
        f"timeout {args.timeout:g} s; {args.jobs} at a time",
        flush=True,
    )

    skip = readme_timeouts(folder) if with_peer and args.peer_skip_readme_timeouts else set()
    for f in files:
        if f.stem in skip:
            rows[f.stem]["ppopt"] = {"status": "timeout", "readme": True, "load_before": 0.0}
    with tempfile.TemporaryDirectory(prefix="mp-bench-") as tmp:
        pending = [
            Job(s, f, Path(tmp))
            for f in files
            for s in solvers
            if not (s == "ppopt" and f.stem in skip)
        ]
        pending.reverse()
        running: list[Job] = []
        while pending or running:
            while pending and len(running) < args.jobs:
                job = pending.pop()
                job.start()
                running.append(job)
            time.sleep(0.05)
            for job in list(running):
                res = job.poll(args.timeout)
                if res is None:
                    continue
                running.remove(job)
                rows[job.path.stem][job.solver] = res
                regions, secs = cell(res, args.timeout)
                extra = (
                    f"  {res.get('error', '')[:100]}"
                    if res["status"] not in ("ok", "timeout")
                    else ""
                )
                print(
                    f"{job.solver:5s} {job.path.stem:30s} {regions:>8s} {secs:>7s} s "
                    f"(load {res['load_before']:.1f}){extra}",
                    flush=True,
                )

    ordered = [rows[f.stem] for f in files]
    print()
    print(table(ordered, with_peer, args.timeout))
    print()
    text, summary = totals(ordered, with_peer)
    print(text)
    load_end = os.getloadavg()
    wall = time.perf_counter() - t_start
    print(
        f"\nload average (1/5/15 min) at start {load_start}, at end {load_end}; "
        f"benchmark wall time {wall:.0f} s"
    )
    if args.json:
        meta = {
            "engine": engine_info(),
            "ppopt": peer_version,
            "timeout": args.timeout,
            "grace": GRACE,
            "jobs": args.jobs,
            "folder": str(folder),
            "load_start": load_start,
            "load_end": load_end,
            "cpus": os.cpu_count(),
            "wall_seconds": wall,
        }
        Path(args.json).write_text(
            json.dumps({"meta": meta, "totals": summary, "rows": ordered}, indent=2)
        )
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
