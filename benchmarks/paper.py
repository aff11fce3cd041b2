"""Benchmark: the six CODEV paper specs end to end (synthesis + verification, both holds),
next to the paper's figures, the tube's tightness against dense simulations, and the Hylaa
peer on the same closed loop.

Usage::

    python benchmarks/paper.py [--only NAME,...] [--holds continuous,zoh] [--repeats 3]
                               [--samples 500] [--seed 20240601] [--json OUT]
                               [--hylaa all | none | NAME,...] [--hylaa-regions all,tube]
                               [--hylaa-max-all 100] [--hylaa-timeout 900]

Per benchmark (``examples/<name>.toml``) and hold (``continuous`` and ``zoh``):

* **ours**: ``ce.synthesize`` (regions, ``law.meta["seconds"]``; best of ``--repeats``) and
  ``ce.verify(problem, law, hold=...)`` (verdict, reason, ``r.seconds``,
  best of ``--repeats``), the tube's width at the horizon ``r.width_at(T)`` per state and
  its max. ``width_at(T)`` is the hull of the tube boxes active at ``T``, i.e. the box of the
  last grid segment ``[T - step, T]``: it contains the motion over one step as well;
* **the paper** (CODEV tool paper, Table 1; MPT3 + the original tool): regions ``k``, MPC
  solve, ``T_v``, verification seconds, result;
* **tightness** (linear plants): ``codev_engine.simulate.simulate_many`` from the corners and
  the centre of the initial box and ``--samples`` uniform random initial states; the hull of
  ``x(T)`` over the trajectories defined up to ``T``; ratio = tube width / hull width per
  state (target <= 1.5); ``n/a`` when the tube stops early (``unsafe``) or no trajectory
  reaches ``T``. A ratio below 1 (marked ``(!)``) means the tube misses simulated states;
* **Hylaa** (``benchmarks/hylaa_peer.py``, when ``hylaa`` is importable), for the listed
  benchmarks (default all; the issue requires the double integrator and magnetic pointer
  C): the same closed loop as a Hylaa hybrid automaton, run in a subprocess with a
  wall-clock limit; its verdict, reach-set width at ``T`` (exact at grid times), wall time
  split into setup and reachability, and the speed ratio Hylaa s / ours s. ``--hylaa-regions``
  ``all`` makes every region a mode; ``tube`` only the regions whose box meets codev's tube
  at a sample time (a superset of the regions visited only when codev's tube is complete:
  verdict ``robustly_safe``; an ``unsafe`` tube stops at the counterexample, and an
  ``unknown`` one was measured to stop the branches that met a property, see PAPER.md);
  the all-regions model has k^2 sample transitions and is only built up to
  ``--hylaa-max-all`` regions.

This is a benchmark, not a test: it asserts nothing and exits 0 unless it crashes.
Timings are wall clock (``time.perf_counter``) on whatever machine runs it.
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import json
import os
import pickle
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
HERE = Path(__file__).resolve().parent

import codev_engine as ce  # noqa: E402
from codev_engine.reach.linear import affine_plant  # noqa: E402
from codev_engine.reach.simulate import simulate_many  # noqa: E402
from codev_engine.reach.verification import verify  # noqa: E402

BENCHMARKS = [
    "double_integrator",
    "navigation",
    "cruise_control",
    "magnetic_pointer_a",
    "magnetic_pointer_b",
    "magnetic_pointer_c",
]
HOLDS = ["continuous", "zoh"]
HYLAA_DEFAULT = ["double_integrator", "magnetic_pointer_c"]

# CODEV tool paper, Table 1 (as reproduced in shared/benchmarks/README.md). The original tool's
# hold is "continuous" (u = F_i x(t) + G_i between samples).
PAPER = {
    "double_integrator": dict(k=20, mpc_s=1.25, T_v=9.0, verify_s=165.10, result="RobustSafe"),
    "navigation": dict(k=580, mpc_s=50.08, T_v=2.0, verify_s=102.28, result="RobustSafe"),
    "cruise_control": dict(k=3, mpc_s=5.31, T_v=10.0, verify_s=19.13, result="RobustSafe"),
    "magnetic_pointer_a": dict(k=1646, mpc_s=154.68, T_v=1.1, verify_s=33.39, result="RobustSafe"),
    "magnetic_pointer_b": dict(k=1646, mpc_s=154.68, T_v=2.0, verify_s=70.96, result="MaxPart"),
    "magnetic_pointer_c": dict(k=212, mpc_s=12.45, T_v=1.1, verify_s=28.65, result="Infeasible"),
}

SEED = 20240601


# ---------------------------------------------------------------------------------------
# ours
# ---------------------------------------------------------------------------------------


def synthesize(problem, repeats: int):
    times, law = [], None
    for _ in range(max(1, repeats)):
        law = ce.synthesize(problem)
        times.append(float(law.meta.get("seconds", float("nan"))))
    return law, min(times), statistics.median(times)


def run_verify(problem, law, hold: str, repeats: int):
    times, r = [], None
    for _ in range(max(1, repeats)):
        r = verify(problem, law, hold=hold)
        times.append(r.seconds)
    return r, min(times), statistics.median(times)


def initial_states(problem, samples: int, seed: int) -> np.ndarray:
    v = problem.verify
    lo, hi = np.asarray(v.initial_lower, float), np.asarray(v.initial_upper, float)
    corners = np.array(list(itertools.product(*zip(lo, hi, strict=True))), dtype=float)
    rng = np.random.default_rng(seed)
    rand = lo + (hi - lo) * rng.random((samples, lo.size))
    return np.vstack([corners, 0.5 * (lo + hi), rand])


def sim_hull_at_horizon(problem, law, hold: str, X0: np.ndarray):
    """Hull width (n,) of ``x(T)`` over the simulated trajectories defined up to ``T``.

    When ``T`` is a sample time, ``simulate_many`` outputs ``T`` twice: first the end of the
    last period (its ``alive`` flags are those of the period), then the sample itself (where
    the law is evaluated and may be undefined). The first one is used: ``x(T)`` exists even
    if the law is undefined there, and it is what the tube and Hylaa's reach set contain.
    """
    t, X, _U, alive = simulate_many(problem, law, X0, hold=hold)
    T = float(problem.verify.time_horizon)
    at_T = np.flatnonzero(np.abs(t - T) <= 1e-9 * max(1.0, T))
    assert at_T.size, (t[-1], T)
    j = int(at_T[0])
    ok = alive[:, j] & np.all(np.isfinite(X[:, j]), axis=1)
    if not np.any(ok):
        return None, 0, X0.shape[0]
    XT = X[ok, j]
    return XT.max(axis=0) - XT.min(axis=0), int(ok.sum()), X0.shape[0]


def ratio(width, ref):
    """Per-state ratio width / ref where ref is not degenerate; (per_state, max) or None."""
    if width is None or ref is None:
        return None, None
    width, ref = np.asarray(width, float), np.asarray(ref, float)
    if not np.all(np.isfinite(width)):
        return None, None
    scale = max(1.0, float(np.max(np.abs(ref))))
    ok = ref > 1e-9 * scale
    if not np.any(ok):
        return None, None
    per = np.where(ok, width / np.where(ok, ref, 1.0), np.nan)
    return per, float(np.nanmax(per))


# ---------------------------------------------------------------------------------------
# Hylaa (subprocess)
# ---------------------------------------------------------------------------------------


def hylaa_available() -> bool:
    return importlib.util.find_spec("hylaa") is not None


def run_hylaa(spec: Path, law, hold: str, regions, timeout: float, workdir: Path) -> dict:
    law_path = workdir / f"{spec.stem}.law.pickle"
    if not law_path.exists():
        with open(law_path, "wb") as fh:
            pickle.dump(law, fh)
    out = workdir / f"{spec.stem}.{hold}.{'all' if regions is None else 'sub'}.json"
    if out.exists():
        out.unlink()
    reg = "all" if regions is None else ",".join(str(r) for r in regions)
    cmd = [
        sys.executable,
        str(HERE / "hylaa_peer.py"),
        str(spec),
        str(law_path),
        hold,
        reg,
        str(out),
    ]
    env = dict(os.environ, PYTHONPATH=str(HERE) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        _o, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return {"status": "timeout", "wall": time.perf_counter() - t0, "timeout": timeout}
    wall = time.perf_counter() - t0
    if proc.returncode != 0 or not out.exists():
        return {"status": "crash", "wall": wall, "stderr": err[-3000:]}
    with open(out) as fh:
        row = json.load(fh)
    row["status"] = "ok"
    row["wall"] = wall
    return row


# ---------------------------------------------------------------------------------------
# formatting
# ---------------------------------------------------------------------------------------


def fnum(x, digits=3):
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "n/a"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    ax = abs(x)
    if ax == 0:
        return "0"
    if ax >= 100:
        return f"{x:.0f}" if ax >= 1000 else f"{x:.1f}"
    if ax >= 0.01:
        return f"{x:.{digits}g}" if ax < 1 else f"{x:.{digits}g}"
    return f"{x:.2e}"


def fratio(x):
    if x is None:
        return "n/a"
    return fnum(x) + (" (!)" if x < 1.0 - 1e-9 else "")


def fvec(v, digits=3):
    if v is None:
        return "n/a"
    return "[" + ", ".join(fnum(float(a), digits) for a in v) + "]"


def verdict_str(verdict, reason):
    return verdict + (f" ({reason})" if reason else "")


# ---------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default=",".join(BENCHMARKS))
    ap.add_argument("--holds", default=",".join(HOLDS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--samples", type=int, default=500)
    ap.add_argument("--seed", type=int, default=SEED)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--hylaa",
        default="all",
        help="benchmarks, 'all' or 'none' (the issue requires " + " and ".join(HYLAA_DEFAULT) + ")",
    )
    ap.add_argument("--hylaa-regions", default="all,tube", help="'all', 'tube' or both")
    ap.add_argument(
        "--hylaa-max-all",
        type=int,
        default=100,
        help="the all-regions model (k^2 sample transitions) only up to this many regions",
    )
    ap.add_argument("--hylaa-timeout", type=float, default=900.0)
    args = ap.parse_args(argv)

    names = [n for n in args.only.split(",") if n]
    holds = [h for h in args.holds.split(",") if h]
    if args.hylaa == "none":
        hylaa_names = []
    elif args.hylaa == "all":
        hylaa_names = list(names)
    else:
        hylaa_names = [n for n in args.hylaa.split(",") if n in names]
    hylaa_modes = [m for m in args.hylaa_regions.split(",") if m in ("all", "tube")]
    have_hylaa = hylaa_available()
    if hylaa_names and have_hylaa:
        import hylaa_peer  # noqa: F401  (only when hylaa is importable)

        hylaa_version = hylaa_peer.HYLAA_VERSION
    else:
        hylaa_peer = None
        hylaa_version = None

    print(
        f"# paper benchmarks: {platform.node()}, {os.cpu_count()} cpus, "
        f"load {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}, "
        f"python {platform.python_version()}, numpy {np.__version__}"
    )
    if hylaa_names:
        print(f"# Hylaa peer: {hylaa_version if have_hylaa else 'NOT importable (skipped)'}")
    print()

    rows = []
    laws = {}
    problems = {}
    vresults = {}
    # ---- ours (all of it first, before any Hylaa process) --------------------------------
    for name in names:
        spec = EXAMPLES / f"{name}.toml"
        problem = ce.load_spec(spec)
        problems[name] = problem
        t0 = time.perf_counter()
        law, syn_best, syn_med = synthesize(problem, args.repeats)
        laws[name] = law
        print(
            f"{name}: {law.num_regions} regions, synthesis {syn_best:.3f} s "
            f"(median {syn_med:.3f} s)",
            flush=True,
        )
        linear = affine_plant(problem) is not None
        X0 = initial_states(problem, args.samples, args.seed) if linear else None
        T = float(problem.verify.time_horizon)
        for hold in holds:
            try:
                r, v_best, v_med = run_verify(problem, law, hold, args.repeats)
            except Exception as exc:  # a benchmark: report and go on
                traceback.print_exc()
                rows.append(dict(benchmark=name, hold=hold, error=repr(exc)))
                continue
            vresults[(name, hold)] = r
            width = r.width_at(T)
            width = None if not np.all(np.isfinite(width)) else width
            sim_w, sim_n, sim_total = (None, 0, 0)
            if linear:
                sim_w, sim_n, sim_total = sim_hull_at_horizon(problem, law, hold, X0)
            per, rmax = ratio(width, sim_w)
            row = dict(
                benchmark=name,
                hold=hold,
                n=problem.plant.n,
                m=problem.plant.m,
                N=problem.mpc.horizon,
                T=T,
                regions=law.num_regions,
                regions_before_merge=law.meta.get("regions_before_merge"),
                synthesis_s=syn_best,
                synthesis_s_median=syn_med,
                verify_s=v_best,
                verify_s_median=v_med,
                verdict=r.verdict,
                reason=r.reason,
                branches=r.stats.get("branches"),
                refinements=r.stats.get("refinements"),
                boxes=r.stats.get("boxes"),
                counterexample=None
                if r.counterexample is None
                else dict(
                    x0=[float(a) for a in r.counterexample.x0],
                    t=float(r.counterexample.t),
                    kind=r.counterexample.kind,
                ),
                width_T=None if width is None else [float(a) for a in width],
                width_T_max=None if width is None else float(np.max(width)),
                sim_hull_T=None if sim_w is None else [float(a) for a in sim_w],
                sim_hull_T_max=None if sim_w is None else float(np.max(sim_w)),
                sim_defined_at_T=sim_n,
                sim_trajectories=sim_total,
                ratio_T=None
                if per is None
                else [None if not np.isfinite(a) else float(a) for a in per],
                ratio_T_max=rmax,
                paper=PAPER.get(name),
                wall_s=time.perf_counter() - t0,
                hylaa=[],
            )
            rows.append(row)
            print(
                f"  {hold:10s} {verdict_str(r.verdict, r.reason):32s} verify {v_best:.3f} s "
                f"width(T) {fvec(width)} sim hull {fvec(sim_w)} ratio {fnum(rmax)}",
                flush=True,
            )

    # ---- Hylaa ----------------------------------------------------------------------------
    if hylaa_names and have_hylaa:
        print()
        with tempfile.TemporaryDirectory(prefix="paper_hylaa_") as tmp:
            work = Path(tmp)
            for row in rows:
                name, hold = row["benchmark"], row["hold"]
                if name not in hylaa_names or "error" in row:
                    continue
                r = vresults[(name, hold)]
                for mode in hylaa_modes:
                    if mode == "all" and laws[name].num_regions > args.hylaa_max_all:
                        row["hylaa"].append(
                            dict(
                                status="skipped",
                                regions_mode="all",
                                wall=0.0,
                                regions_note=f"{laws[name].num_regions} regions > --hylaa-max-all "
                                f"{args.hylaa_max_all} ({laws[name].num_regions ** 2} "
                                "sample transitions)",
                            )
                        )
                        continue
                    if mode == "tube":
                        regs = hylaa_peer.regions_from_tube(problems[name], laws[name], r)
                        if r.verdict != "robustly_safe":
                            note = (
                                f"tube-pruned model; codev's tube may be incomplete "
                                f"(verdict {r.verdict}): the model may miss regions"
                            )
                        else:
                            note = "tube-pruned model"
                    else:
                        regs, note = None, "all regions"
                    print(
                        f"hylaa {name} {hold} ({mode}: "
                        f"{laws[name].num_regions if regs is None else len(regs)} modes) ...",
                        end=" ",
                        flush=True,
                    )
                    h = run_hylaa(
                        EXAMPLES / f"{name}.toml", laws[name], hold, regs, args.hylaa_timeout, work
                    )
                    h["regions_mode"] = mode
                    h["regions_note"] = note
                    if h["status"] == "ok":
                        hw = h.get("width")
                        per, rmax = ratio(hw, row["sim_hull_T"])
                        h["ratio_T_vs_sim"] = (
                            None
                            if per is None
                            else [None if not np.isfinite(a) else float(a) for a in per]
                        )
                        h["ratio_T_vs_sim_max"] = rmax
                        h["speed_ratio"] = (
                            h["run_seconds"] / row["verify_s"] if row["verify_s"] else None
                        )
                        vs = verdict_str(h["verdict"], h["reason"])
                        print(
                            f"{vs}, run {h['run_seconds']:.2f} s "
                            f"(setup {h['setup_seconds']:.2f} s, "
                            f"reach {h['reach_seconds']:.2f} s), width(T) {fvec(hw)}",
                            flush=True,
                        )
                    else:
                        print(h["status"], flush=True)
                        if h.get("stderr"):
                            print(h["stderr"], file=sys.stderr)
                    row["hylaa"].append(h)

    # ---- tables ---------------------------------------------------------------------------
    print()
    print("## Ours vs the paper")
    print()
    print(
        "| benchmark | hold | regions (paper k) | synthesis s (paper) "
        "| verification s (paper, T_v) | verdict (paper) | width at T, max "
        "| sim hull at T, max | ratio |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        if "error" in row:
            print(f"| {row['benchmark']} | {row['hold']} | error: {row['error']} |||||||")
            continue
        pp = row["paper"] or {}
        print(
            f"| {row['benchmark']} | {row['hold']} | {row['regions']} ({pp.get('k', '?')}) "
            f"| {fnum(row['synthesis_s'])} ({pp.get('mpc_s', '?')}) "
            f"| {fnum(row['verify_s'])} ({pp.get('verify_s', '?')}, {pp.get('T_v', '?')} s) "
            f"| {verdict_str(row['verdict'], row['reason'])} ({pp.get('result', '?')}) "
            f"| {fnum(row['width_T_max'])} | {fnum(row['sim_hull_T_max'])} "
            f"| {fratio(row['ratio_T_max'])} |"
        )
    print()
    print("(!) ratio < 1: the tube at T does not contain all simulated states at T.")
    print()
    print("## Per-state widths at the horizon")
    print()
    print(
        "| benchmark | hold | tube width at T | simulated hull at T (defined/total) "
        "| ratio per state |"
    )
    print("|---|---|---|---|---|")
    for row in rows:
        if "error" in row:
            continue
        print(
            f"| {row['benchmark']} | {row['hold']} | {fvec(row['width_T'])} "
            f"| {fvec(row['sim_hull_T'])} ({row['sim_defined_at_T']}/{row['sim_trajectories']}) "
            f"| {fvec(row['ratio_T'])} |"
        )
    hrows = [(row, h) for row in rows if "error" not in row for h in row["hylaa"]]
    if hrows:
        print()
        print(f"## Hylaa peer ({hylaa_version})")
        print()
        print(
            "| benchmark | hold | model | Hylaa verdict | ours | Hylaa s (setup + reach) "
            "| ours s | Hylaa / ours | Hylaa width at T | sim hull at T | ours width at T |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for row, h in hrows:
            model = ("all" if h["regions_mode"] == "all" else "tube") + (
                f", {h['modes']} modes, {h['transitions']} transitions"
                if h["status"] == "ok"
                else ""
            )
            if h["status"] != "ok":
                what = (
                    h["status"]
                    if h["status"] == "skipped"
                    else f"{h['status']} after {h['wall']:.0f} s"
                )
                print(
                    f"| {row['benchmark']} | {row['hold']} | {h['regions_mode']}: "
                    f"{h.get('regions_note', '')} | {what} "
                    f"| {verdict_str(row['verdict'], row['reason'])} "
                    f"| | {fnum(row['verify_s'])} | | | | |"
                )
                continue
            hv = verdict_str(h["verdict"], h["reason"])
            if h.get("error_time") is not None:
                hv += f" at t={h['error_time']:.2f}"
            ws = ""
            if h.get("width_seconds") is not None:
                ws = f"; width run {h['width_seconds']:.1f} s"
            print(
                f"| {row['benchmark']} | {row['hold']} | {model} | {hv} "
                f"| {verdict_str(row['verdict'], row['reason'])} "
                f"| {h['run_seconds']:.2f} "
                f"({h['setup_seconds']:.2f} + {h['reach_seconds']:.2f}){ws} "
                f"| {fnum(row['verify_s'])} | {fnum(h['speed_ratio'])} "
                f"| {fvec(h.get('width'))} | {fvec(row['sim_hull_T'])} | {fvec(row['width_T'])} |"
            )
        print()
        print(
            "Hylaa s = Core.run wall time of the verdict run (stops at the first concrete error); "
            "'width run' = an extra reach-only run (no error modes) for the width at T when the "
            "verdict run stopped early. Hylaa / ours = Hylaa s / ours s (verification only)."
        )

    if args.json:
        meta = dict(
            host=platform.node(),
            cpus=os.cpu_count(),
            load=list(os.getloadavg()),
            python=platform.python_version(),
            numpy=np.__version__,
            hylaa=hylaa_version,
            samples=args.samples,
            seed=args.seed,
            repeats=args.repeats,
        )
        with open(args.json, "w") as fh:
            json.dump({"meta": meta, "rows": rows}, fh, indent=1, default=_json_default)
        print(f"\nwrote {args.json}")
    return 0


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    return str(obj)


if __name__ == "__main__":
    raise SystemExit(main())
