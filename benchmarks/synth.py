"""Benchmark: explicit MPC synthesis of the five paper mp-LPs, ours against PPOPT 1.6.12.

Usage::

    python benchmarks/synth.py [--timeout 120] [--no-peer] [--json OUT]
                               [--repeats 3] [--samples 500] [--variant same|mpt3|both]
                               [--algorithms geometric,combinatorial,geometric_parallel_exp]

What it does (see ``benchmarks/README.md``):

1. **Ours**, first, before any PPOPT process is started: ``ce.synthesize(load_spec(...))``
   timed with ``time.perf_counter`` (wall, spec -> law, including discretisation, condensing, the
   mp-LP solve and the region merge), best of ``--repeats`` runs (the median is kept too).
2. **PPOPT**, afterwards, one subprocess per (problem, algorithm) with a wall-clock limit
   (the whole process group is killed on timeout). The subprocess builds the
   ``MPLP_Program`` from the *same* condensed program as ours (``ce.build_program``) and
   solves it; its time is build + solve (PPOPT import excluded).
3. **Correctness**, for both: ``--samples`` random feasible parameters (uniform in the
   parameter box, rejection on HiGHS feasibility, fixed seed) are located in each solution
   and the value there is compared with ``scipy.optimize.linprog`` (HiGHS) on the same
   program. A result is *correct* when every test point is located, the located law is
   feasible (1e-6) and its value matches the LP optimum within 1e-6 relative.

``--variant mpt3`` (or ``both``) also runs the MPT3-style program: the same LP plus the
theta-only stage cost ``||Q x_0||`` as an extra slack (that is how MPT3 and the PPOPT
numbers in ``shared/benchmarks/README.md`` build it). For that variant "ours" is
``ce.mpsolve`` on the very same MPT3-style program, labelled as such.

This is a benchmark, not a test: it asserts nothing and exits 0 unless it crashes.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"

# The distinct MPC problems of the paper (magnetic_pointer_b is the same MPC as _a).
PROBLEMS = [
    "double_integrator",
    "navigation",
    "cruise_control",
    "magnetic_pointer_a",
    "magnetic_pointer_c",
]
DEFAULT_ALGORITHMS = ["geometric", "combinatorial", "geometric_parallel_exp"]

VALUE_RTOL = 1e-6
FEAS_TOL = 1e-6
SEED = 20240601


# ---------------------------------------------------------------------------------------
# the programs
# ---------------------------------------------------------------------------------------


@dataclass
class Prog:
    """An mp-LP ``min (c + C theta)'z  s.t.  A z <= b + F theta,  A_t theta <= b_t``."""

    c: np.ndarray
    C: np.ndarray
    A: np.ndarray
    b: np.ndarray
    F: np.ndarray
    A_t: np.ndarray
    b_t: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ("c", "C", "A", "b", "F", "A_t", "b_t")}


def same_program(mp) -> Prog:
    """Our condensed program, as it is."""
    p = mp.program
    if np.any(p.H):
        raise SystemExit("the benchmark covers mp-LPs only")
    if p.Aeq is not None and p.Aeq.size:
        raise SystemExit("the benchmark expects no equalities")
    return Prog(p.c.copy(), p.C.copy(), p.A.copy(), p.b.copy(), p.F.copy(),
                p.A_theta.copy(), p.b_theta.copy())


def mpt3_program(mp) -> Prog:
    """Ours plus the theta-only stage cost ``||Q x_0||`` as slack(s), as MPT3 builds it.

    norm "inf": one slack ``t0`` with ``+-Q theta - t0 <= 0``; norm "1": one slack per row
    of Q. The optimizer (the inputs) is unchanged; the value gains ``||Q theta||``.
    """
    base = same_program(mp)
    Q = np.asarray(mp.spec.Q, dtype=float).reshape(-1, mp.n)
    q = Q.shape[0]
    ns = 1 if mp.spec.norm == "inf" else q
    nz = base.A.shape[1]
    S = np.zeros((q, ns))
    if ns == 1:
        S[:, 0] = -1.0
    else:
        S[:] = -np.eye(q)
    # Q theta - t <= 0  <=>  -t <= -Q theta ;  -Q theta - t <= 0  <=>  -t <= Q theta
    A_new = np.vstack([np.hstack([np.zeros((2 * q, nz)), np.vstack([S, S])])])
    A = np.vstack([np.hstack([base.A, np.zeros((base.A.shape[0], ns))]), A_new])
    b = np.concatenate([base.b, np.zeros(2 * q)])
    F = np.vstack([base.F, -Q, Q])
    c = np.concatenate([base.c, np.ones(ns)])
    C = np.vstack([base.C, np.zeros((ns, mp.n))])
    return Prog(c, C, A, b, F, base.A_t, base.b_t)


def engine_info() -> dict:
    """Where ``codev_engine`` was imported from and, read-only, the repository's commit."""
    import codev_engine as ce

    module = Path(ce.__file__).resolve().parent
    info: dict = {"module": str(module)}
    if not module.is_relative_to(ROOT):
        # e.g. an exported commit put first on PYTHONPATH: the repository says nothing
        return info
    try:
        info["repo_head"] = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True, text=True, check=True).stdout.strip()
        info["repo_engine_modified"] = bool(subprocess.run(
            ["git", "-C", str(ROOT), "status", "--porcelain", "--", "codev_engine"],
            capture_output=True, text=True, check=True).stdout.strip())
    except (OSError, subprocess.CalledProcessError):
        pass
    return info


def to_mpprogram(prog: Prog):
    import codev_engine as ce

    nz = prog.A.shape[1]
    return ce.MpProgram(H=np.zeros((nz, nz)), c=prog.c, C=prog.C, A=prog.A, b=prog.b,
                        F=prog.F, A_theta=prog.A_t, b_theta=prog.b_t)


# ---------------------------------------------------------------------------------------
# the oracle: HiGHS at random feasible parameters
# ---------------------------------------------------------------------------------------


def lp_at(prog: Prog, theta: np.ndarray) -> float | None:
    """Optimal value at ``theta`` (HiGHS), None when infeasible."""
    from scipy.optimize import linprog

    res = linprog(prog.c + prog.C @ theta, A_ub=prog.A, b_ub=prog.b + prog.F @ theta,
                  bounds=(None, None), method="highs")
    if res.status == 0:
        return float(res.fun)
    if res.status == 2:
        return None
    raise RuntimeError(f"HiGHS: status {res.status}: {res.message}")


def parameter_box(prog: Prog) -> tuple[np.ndarray, np.ndarray]:
    from scipy.optimize import linprog

    d = prog.A_t.shape[1]
    lo, hi = np.empty(d), np.empty(d)
    for i in range(d):
        e = np.zeros(d)
        e[i] = 1.0
        lo[i] = linprog(e, A_ub=prog.A_t, b_ub=prog.b_t, bounds=(None, None)).fun
        hi[i] = -linprog(-e, A_ub=prog.A_t, b_ub=prog.b_t, bounds=(None, None)).fun
    return lo, hi


def sample_feasible(prog: Prog, count: int, seed: int) -> tuple[np.ndarray, int]:
    """``count`` parameters, uniform in the box, feasible for the LP.

    Returns the points (P, d) and the number of candidates drawn.
    """
    rng = np.random.default_rng(seed)
    lo, hi = parameter_box(prog)
    pts: list[np.ndarray] = []
    drawn = 0
    while len(pts) < count and drawn < 200 * count:
        th = lo + (hi - lo) * rng.random(lo.size)
        drawn += 1
        if np.any(prog.A_t @ th > prog.b_t):
            continue
        if lp_at(prog, th) is not None:
            pts.append(th)
    return np.array(pts).reshape(-1, lo.size), drawn


def oracle_values(prog: Prog, thetas: np.ndarray) -> np.ndarray:
    return np.array([lp_at(prog, th) for th in thetas], dtype=float)


def check_answers(prog: Prog, thetas: np.ndarray, vstar: np.ndarray, Z: np.ndarray,
                  located: np.ndarray, multi: np.ndarray | None = None) -> dict:
    """Compare located laws ``Z`` (P, nz) (NaN rows where not located) with the oracle."""
    P = thetas.shape[0]
    ok_loc = located
    vals = np.full(P, np.nan)
    feas = np.zeros(P, dtype=bool)
    for i in np.flatnonzero(ok_loc):
        z, th = Z[i], thetas[i]
        vals[i] = float((prog.c + prog.C @ th) @ z)
        rhs = prog.b + prog.F @ th
        feas[i] = bool(np.all(prog.A @ z - rhs <= FEAS_TOL * (1.0 + np.abs(rhs))))
    good_val = np.abs(vals - vstar) <= VALUE_RTOL * np.maximum(1.0, np.abs(vstar))
    good = ok_loc & feas & good_val
    out = {
        "points": int(P),
        "not_located": int(P - ok_loc.sum()),
        "infeasible_law": int((ok_loc & ~feas).sum()),
        "wrong_value": int((ok_loc & feas & ~good_val).sum()),
        "max_rel_err": float(np.nanmax(np.abs(vals - vstar) / np.maximum(1.0, np.abs(vstar))))
        if ok_loc.any() else None,
        "correct": bool(good.all()) and P > 0,
    }
    if multi is not None:
        out["in_several_regions"] = int((multi > 1).sum())
    return out


# ---------------------------------------------------------------------------------------
# ours
# ---------------------------------------------------------------------------------------


@dataclass
class Row:
    problem: str
    variant: str
    n: int
    N: int
    ours_regions: int = 0
    ours_regions_before_merge: int = 0
    ours_seconds: float = float("nan")
    ours_seconds_median: float = float("nan")
    ours_cpu_seconds: float = float("nan")
    ours_check: dict = field(default_factory=dict)
    peer: dict = field(default_factory=dict)  # algorithm -> result
    samples_drawn: int = 0
    ours_load_before: float = float("nan")
    ours_error: str | None = None

    def best_peer(self) -> tuple[str, dict] | None:
        ok = [(a, r) for a, r in self.peer.items() if r.get("check", {}).get("correct")]
        if not ok:
            return None
        return min(ok, key=lambda ar: ar[1]["seconds"])


def tree_cpu_seconds() -> float:
    """CPU seconds (user + system) of this process, its reaped children and, on Linux, its
    live descendants (PPOPT's parallel algorithms leave their worker pool running)."""
    t = os.times()
    total = t.user + t.system + t.children_user + t.children_system
    proc = Path("/proc")
    if not proc.is_dir():
        return total
    tick = os.sysconf("SC_CLK_TCK")
    parent: dict[int, int] = {}
    ticks: dict[int, int] = {}
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        parent[int(d.name)] = int(fields[1])
        ticks[int(d.name)] = int(fields[11]) + int(fields[12])  # utime + stime
    me = os.getpid()
    todo, seen = [me], set()
    while todo:
        p = todo.pop()
        for c, pp in parent.items():
            if pp == p and c not in seen:
                seen.add(c)
                todo.append(c)
    return total + sum(ticks[c] for c in seen) / tick


def time_ours(problem_path: Path, repeats: int) -> tuple[float, float, float, object]:
    """Best wall, median wall, best CPU seconds of ``synthesize``, and the law."""
    import codev_engine as ce

    p = ce.load_spec(problem_path)
    times, cpus = [], []
    law = None
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        law = ce.synthesize(p)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(times), statistics.median(times), min(cpus), law


def time_ours_mpsolve(prog: Prog, repeats: int) -> tuple[float, float, float, object]:
    """Best wall, median wall, best CPU seconds of ``mpsolve``, and the solution."""
    import codev_engine as ce

    mpp = to_mpprogram(prog)
    times, cpus = [], []
    sol = None
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        sol = ce.mpsolve(mpp)
        times.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(times), statistics.median(times), min(cpus), sol


def check_ours(sol, prog: Prog, thetas: np.ndarray, vstar: np.ndarray) -> dict:
    idx = sol.locate(thetas)
    Z = sol.primal(thetas)
    return check_answers(prog, thetas, vstar, Z, idx >= 0)


# ---------------------------------------------------------------------------------------
# PPOPT, in a subprocess
# ---------------------------------------------------------------------------------------


def peer_worker(prog_file: str, algorithm: str, out_file: str) -> None:
    """Run inside the subprocess: build the MPLP_Program, solve, pickle the regions."""
    import warnings

    warnings.simplefilter("ignore")
    result: dict = {"algorithm": algorithm}
    try:
        from ppopt.mp_solvers.solve_mpqp import mpqp_algorithm, solve_mpqp
        from ppopt.mplp_program import MPLP_Program

        data = np.load(prog_file)
        algo = mpqp_algorithm[algorithm]
        c0, t0 = tree_cpu_seconds(), time.perf_counter()
        prob = MPLP_Program(
            A=data["A"], b=data["b"].reshape(-1, 1), c=data["c"].reshape(-1, 1),
            H=data["C"], A_t=data["A_t"], b_t=data["b_t"].reshape(-1, 1), F=data["F"],
        )
        t1 = time.perf_counter()
        sol = solve_mpqp(prob, algo)
        t2 = time.perf_counter()
        cpu = tree_cpu_seconds() - c0
        result.update(
            status="ok",
            cpu_seconds=cpu,
            build_seconds=t1 - t0,
            solve_seconds=t2 - t1,
            seconds=t2 - t0,
            regions=len(sol.critical_regions),
            is_overlapping=bool(sol.is_overlapping),
            tol=float(sol.point_location_tolerance),
            E=[np.asarray(r.E, dtype=float) for r in sol.critical_regions],
            f=[np.asarray(r.f, dtype=float).reshape(-1) for r in sol.critical_regions],
            K=[np.asarray(r.A, dtype=float) for r in sol.critical_regions],
            k=[np.asarray(r.b, dtype=float).reshape(-1) for r in sol.critical_regions],
        )
    except Exception as exc:  # noqa: BLE001 - report whatever PPOPT raised
        tb = traceback.extract_tb(exc.__traceback__)
        where = f"{Path(tb[-1].filename).name}:{tb[-1].lineno} {tb[-1].name}" if tb else ""
        result.update(status="error", error=f"{type(exc).__name__}: {exc}"[:300],
                      where=where, traceback=traceback.format_exc()[-2000:])
    with open(out_file, "wb") as fh:
        pickle.dump(result, fh)


def run_peer(prog: Prog, algorithm: str, timeout: float, workdir: Path, tag: str) -> dict:
    prog_file = workdir / f"{tag}.npz"
    out_file = workdir / f"{tag}-{algorithm}.pkl"
    log_file = workdir / f"{tag}-{algorithm}.log"
    np.savez(prog_file, **prog.arrays())
    cmd = [sys.executable, str(Path(__file__).resolve()), "--_peer-worker",
           str(prog_file), algorithm, str(out_file)]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with open(log_file, "wb") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            # the process group holds PPOPT's worker pool too
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
            return {"status": "timeout", "seconds": float(timeout),
                    "wall": time.perf_counter() - t0, "load_before": load}
    wall = time.perf_counter() - t0
    # a pool left behind by a crashed worker: end this group only
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    if not out_file.exists():
        tail = log_file.read_text(errors="replace")[-300:]
        return {"status": "crash", "error": f"exit {proc.returncode}: {tail}", "wall": wall,
                "load_before": load}
    with open(out_file, "rb") as fh:
        res = pickle.load(fh)
    res["wall"] = wall
    res["load_before"] = load
    return res


def check_peer(res: dict, prog: Prog, thetas: np.ndarray, vstar: np.ndarray) -> dict:
    """Locate as PPOPT does (E theta - f < tol; among several, the lowest objective)."""
    P = thetas.shape[0]
    nz = prog.A.shape[1]
    Z = np.full((P, nz), np.nan)
    located = np.zeros(P, dtype=bool)
    multi = np.zeros(P, dtype=int)
    tol = res.get("tol", 1e-5)
    for i, th in enumerate(thetas):
        best, best_obj = None, np.inf
        for E, f, K, k in zip(res["E"], res["f"], res["K"], res["k"], strict=True):
            if np.all(E @ th - f < tol):
                multi[i] += 1
                z = K @ th + k
                obj = float((prog.c + prog.C @ th) @ z)
                if best is None or obj <= best_obj:
                    best, best_obj = z, obj
                if not res.get("is_overlapping", True):
                    break
        if best is not None:
            Z[i] = best
            located[i] = True
    return check_answers(prog, thetas, vstar, Z, located, multi)


# ---------------------------------------------------------------------------------------
# the report
# ---------------------------------------------------------------------------------------


def fmt_s(x: float) -> str:
    if x is None or not np.isfinite(x):
        return "-"
    return f"{x:.3f}" if x < 10 else f"{x:.1f}"


def peer_note(alg: str, r: dict) -> str:
    st = r.get("status")
    if st == "timeout":
        return f"{alg}: timeout {r['seconds']:.0f} s"
    if st in ("error", "crash"):
        return f"{alg}: {st} ({r.get('error', '')[:60].strip()})"
    ch = r.get("check", {})
    if ch.get("correct"):
        return f"{alg}: ok {r['regions']} reg {fmt_s(r['seconds'])} s"
    bits = []
    if ch.get("not_located"):
        bits.append(f"{ch['not_located']} holes")
    if ch.get("infeasible_law"):
        bits.append(f"{ch['infeasible_law']} infeasible laws")
    if ch.get("wrong_value"):
        bits.append(f"{ch['wrong_value']} wrong values")
    if not bits:
        bits.append("no test point")
    return f"{alg}: WRONG {r['regions']} reg {fmt_s(r['seconds'])} s, " + ", ".join(bits) + \
        f" /{ch.get('points', 0)}"


def ours_note(row: Row) -> str:
    if row.ours_error:
        return f"OURS FAILED: {row.ours_error[:120]}"
    ch = row.ours_check
    if not ch:
        return ""
    if ch.get("correct"):
        return f"ours ok {ch['points']}/{ch['points']}"
    return (f"OURS WRONG: {ch['not_located']} holes, {ch['infeasible_law']} infeasible, "
            f"{ch['wrong_value']} wrong values /{ch['points']}")


def table(rows: list[Row], with_peer: bool) -> str:
    head = ["problem", "variant", "ours regions (before merge)", "ours s"]
    if with_peer:
        head += ["PPOPT best correct", "its regions", "its s", "ratio PPOPT/ours",
                 "CPU ratio"]
    head += ["notes"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        regs = ("error" if r.ours_error else
                f"{r.ours_regions} ({r.ours_regions_before_merge})")
        cells = [r.problem, r.variant, regs, fmt_s(r.ours_seconds)]
        notes = [ours_note(r)]
        if with_peer:
            best = r.best_peer()
            if best:
                alg, res = best
                cells += [alg, str(res["regions"]), fmt_s(res["seconds"])]
                if r.ours_error:
                    cells += ["-", "-"]
                else:
                    ratio = res["seconds"] / r.ours_seconds
                    cpu_ratio = res["cpu_seconds"] / r.ours_cpu_seconds
                    cells += [f"{ratio:.1f}x", f"{cpu_ratio:.1f}x"]
            else:
                cells += ["none", "-", "-", "-", "-"]
            notes += [peer_note(a, res) for a, res in r.peer.items()
                      if not (best and a == best[0])]
        cells.append("; ".join(n for n in notes if n))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def totals(rows: list[Row], with_peer: bool) -> str:
    out = []
    for variant in dict.fromkeys(r.variant for r in rows):
        vr = [r for r in rows if r.variant == variant]
        ok = [r for r in vr if not r.ours_error]
        ours_total = sum(r.ours_seconds for r in ok)
        out.append(f"[{variant}] ours, {len(ok)} of {len(vr)} problems solved: "
                   f"{ours_total:.3f} s (CPU {sum(r.ours_cpu_seconds for r in ok):.3f} s), "
                   f"{sum(r.ours_regions for r in ok)} regions")
        failed = [r.problem for r in vr if r.ours_error]
        if failed:
            out.append(f"[{variant}] OURS FAILED on: {', '.join(failed)}")
        if with_peer:
            both = [(r, r.best_peer()) for r in ok if r.best_peer()]
            if both:
                o = sum(r.ours_seconds for r, _ in both)
                p = sum(b[1]["seconds"] for _, b in both)
                oc = sum(r.ours_cpu_seconds for r, _ in both)
                pc = sum(b[1]["cpu_seconds"] for _, b in both)
                names = ", ".join(r.problem for r, _ in both)
                out.append(f"[{variant}] where PPOPT is correct ({names}): ours {o:.3f} s, "
                           f"PPOPT {p:.3f} s, ratio {p / o:.1f}x (CPU: ours {oc:.3f} s, "
                           f"PPOPT {pc:.3f} s, ratio {pc / oc:.1f}x)")
                for r, (alg, res) in both:
                    out.append(f"    {r.problem}: PPOPT {alg} {res['seconds']:.3f} s / ours "
                               f"{r.ours_seconds:.3f} s = {res['seconds'] / r.ours_seconds:.1f}x")
            else:
                out.append(f"[{variant}] PPOPT correct on no problem")
            missing = [r.problem for r in vr if not r.best_peer()]
            if missing:
                out.append(f"[{variant}] no correct PPOPT result: {', '.join(missing)}")
    return "\n".join(out)


def row_json(r: Row) -> dict:
    best = r.best_peer()
    peer = {}
    for a, res in r.peer.items():
        peer[a] = {k: v for k, v in res.items()
                   if k not in ("E", "f", "K", "k", "traceback")}
    return {
        "problem": r.problem, "variant": r.variant, "n": r.n, "N": r.N,
        "ours_regions": r.ours_regions,
        "ours_regions_before_merge": r.ours_regions_before_merge,
        "ours_seconds_best": r.ours_seconds, "ours_seconds_median": r.ours_seconds_median,
        "ours_cpu_seconds_best": r.ours_cpu_seconds,
        "ours_check": r.ours_check,
        "ours_load_before": r.ours_load_before,
        "ours_error": r.ours_error,
        "samples_drawn": r.samples_drawn,
        "peer": peer,
        "peer_best": None if not best or r.ours_error else {
            "algorithm": best[0], "regions": best[1]["regions"],
            "seconds": best[1]["seconds"], "ratio": best[1]["seconds"] / r.ours_seconds,
            "cpu_seconds": best[1]["cpu_seconds"],
            "cpu_ratio": best[1]["cpu_seconds"] / r.ours_cpu_seconds,
        },
    }


# ---------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "--_peer-worker":
        peer_worker(*argv[1:4])
        return 0

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timeout", type=float, default=120.0,
                    help="wall-clock limit per PPOPT run, seconds (default 120)")
    ap.add_argument("--no-peer", action="store_true", help="run ours only")
    ap.add_argument("--json", metavar="OUT", help="write the rows as JSON")
    ap.add_argument("--repeats", type=int, default=3, help="runs of ours; best is reported")
    ap.add_argument("--samples", type=int, default=500, help="random feasible test states")
    ap.add_argument("--variant", choices=["same", "mpt3", "both"], default="same",
                    help="same program as ours (default), the MPT3-style one, or both")
    ap.add_argument("--algorithms", default=",".join(DEFAULT_ALGORITHMS),
                    help="PPOPT algorithms (names of mpqp_algorithm), at most 3")
    ap.add_argument("--problems", default=",".join(PROBLEMS))
    args = ap.parse_args(argv)

    import codev_engine as ce

    algorithms = [a for a in args.algorithms.split(",") if a][:3]
    problems = [p for p in args.problems.split(",") if p]
    variants = ["same", "mpt3"] if args.variant == "both" else [args.variant]
    with_peer = not args.no_peer

    if with_peer:
        try:
            import ppopt  # noqa: F401
            from ppopt.mp_solvers.solve_mpqp import mpqp_algorithm
        except Exception as exc:  # noqa: BLE001
            print(f"PPOPT cannot be imported ({exc}); running ours only", file=sys.stderr)
            with_peer = False
        else:
            bad = [a for a in algorithms if a not in mpqp_algorithm.__members__]
            if bad:
                raise SystemExit(f"unknown PPOPT algorithms {bad}; "
                                 f"known: {list(mpqp_algorithm.__members__)}")

    load_start = os.getloadavg()
    t_start = time.perf_counter()

    print(f"engine: {engine_info()}", flush=True)

    # --- 1. ours, sequentially, before any PPOPT process ----------------------------------
    rows: list[Row] = []
    progs: dict[tuple[str, str], Prog] = {}
    for name in problems:
        path = EXAMPLES / f"{name}.toml"
        p = ce.load_spec(path)
        mp = ce.build_program(p.mpc, ce.discretize(p))
        for variant in variants:
            prog = same_program(mp) if variant == "same" else mpt3_program(mp)
            progs[(name, variant)] = prog
            row = Row(problem=name, variant=variant, n=mp.n, N=mp.N,
                      ours_load_before=os.getloadavg()[0])
            rows.append(row)
            try:
                if variant == "same":
                    best, med, cpu, law = time_ours(path, args.repeats)
                    row.ours_regions = int(law.num_regions)
                    row.ours_regions_before_merge = int(law.meta["regions_before_merge"])
                else:
                    best, med, cpu, sol = time_ours_mpsolve(prog, args.repeats)
                    row.ours_regions = row.ours_regions_before_merge = sol.num_regions
            except Exception as exc:  # noqa: BLE001 - a benchmark reports, it does not stop
                row.ours_error = f"{type(exc).__name__}: {exc}"
                print(f"ours   {name:20s} {variant:5s} FAILED: {row.ours_error}", flush=True)
                continue
            row.ours_seconds, row.ours_seconds_median, row.ours_cpu_seconds = best, med, cpu
            print(f"ours   {name:20s} {variant:5s} {row.ours_regions:5d} regions "
                  f"({row.ours_regions_before_merge} before merge)  best {best:.3f} s  "
                  f"median {med:.3f} s  cpu {cpu:.3f} s  (load {row.ours_load_before:.1f})",
                  flush=True)

    # --- 2. the test states and the oracle ----------------------------------------------
    tests: dict[str, tuple[np.ndarray, int]] = {}  # problem -> (thetas, drawn)
    vstars: dict[tuple[str, str], np.ndarray] = {}
    for row in rows:
        prog = progs[(row.problem, row.variant)]
        if row.problem not in tests:
            # the same states for both variants (they have the same feasible set)
            tests[row.problem] = sample_feasible(prog, args.samples, SEED)
        thetas, drawn = tests[row.problem]
        row.samples_drawn = drawn
        vstar = oracle_values(prog, thetas)
        vstars[(row.problem, row.variant)] = vstar
        if not row.ours_error:
            sol = ce.mpsolve(to_mpprogram(prog))
            row.ours_check = check_ours(sol, prog, thetas, vstar)
        print(f"check  {row.problem:20s} {row.variant:5s} {len(thetas)} feasible states "
              f"(of {drawn} drawn): {ours_note(row)}", flush=True)

    # --- 3. PPOPT, one subprocess at a time ---------------------------------------------
    if with_peer:
        with tempfile.TemporaryDirectory(prefix="synth-bench-") as tmp:
            for row in rows:
                key = (row.problem, row.variant)
                prog, thetas = progs[key], tests[row.problem][0]
                for alg in algorithms:
                    res = run_peer(prog, alg, args.timeout, Path(tmp),
                                   f"{row.problem}-{row.variant}")
                    if res.get("status") == "ok":
                        res["check"] = check_peer(res, prog, thetas, vstars[key])
                    row.peer[alg] = res
                    print(f"PPOPT  {row.problem:20s} {row.variant:5s} "
                          f"{peer_note(alg, res)}  (load {res['load_before']:.1f})", flush=True)

    print()
    print(table(rows, with_peer))
    print()
    print(totals(rows, with_peer))
    load_end = os.getloadavg()
    print(f"\nload average (1/5/15 min) at start {load_start}, at end {load_end}; "
          f"benchmark wall time {time.perf_counter() - t_start:.0f} s")
    if args.json:
        meta = {"engine": engine_info(), "timeout": args.timeout, "repeats": args.repeats,
                "samples": args.samples,
                "algorithms": algorithms, "ours_time": "best of repeats (wall, perf_counter)",
                "load_start": load_start, "load_end": load_end, "cpus": os.cpu_count(),
                "wall_seconds": time.perf_counter() - t_start}
        try:
            from importlib.metadata import version

            meta["ppopt"] = version("ppopt")
        except Exception:  # noqa: BLE001
            meta["ppopt"] = None
        Path(args.json).write_text(json.dumps(
            {"meta": meta, "rows": [row_json(r) for r in rows]}, indent=2, default=float))
        print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
