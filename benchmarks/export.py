"""Benchmark: the exported C of the paper's laws, binary search tree against sequential search.

Usage::

    python benchmarks/export.py [--states 100000] [--problems a,b] [--solution FILE.npz]
                                [--reps 8] [--rounds 3] [--seq-reps K] [--seq-rounds R]
                                [--no-peer] [--json OUT]

For every problem (``examples/<name>.toml``, synthesised with ``ce.synthesize``) and both
methods: the construction time of the search (``plan``, tree and member LPs; the compiled
code warmed up first), the certified worst case from the header (tests on the path, row
evaluations, multiply-adds), the ROM of the tables, and the time of one call of the
compiled C (``gcc -O2``) on ``--states`` states drawn uniformly from the law's domain
(rejection from its box): per state the best of 3 rounds of 8 calls (``--rounds``,
``--reps``; the sequential search's may be fewer: ``--seq-rounds``, ``--seq-reps``),
``clock_gettime``;
the median and the worst over the states. Every state's region is checked against
``law.locate`` on the way (a mismatch is printed). ``--solution`` adds an mp problem of the
mp_testset (its ``.npz``, solved by ``ce.mpsolve``) exported as ``MpSolution``.
``--problems quadrotor-operation``: the region of operation of issue 39's quadrotor (12
states, N = 10, verified on demand; ``deploy.operation``), on states of its tube.

The peer: PPOPT 1.6.12's C++ export (``ppopt.upop.linear_code_gen.generate_code_cpp``)
cannot be imported (the template module ``ppopt.upop.lib_upop`` is missing from the
wheel) and its tree export (``ucontroller.generate_code``) is a stub returning
``["None"]``; its usable evaluator is ``ppopt.upop.point_location.PointLocation``, a numba
sequential search called from Python, timed here on the same regions and states (per call,
``perf_counter_ns``, the Python call included, as a user would call it).

The target "worst case <= 2 ceil(log2 R) + n hyperplane tests" is measured on the
hyperplane tests on the path (the tree's depth, from the exhaustive traversal); the
worst fast path adds the owner's (a bucket's) rows, and the certified worst case adds,
instead, every member's rows: the fallback a point within delta of a tested hyperplane
takes (rounding could put it on either side), which the target does not count.

It is a benchmark, not a test: it prints a table and exits 0.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

PROBLEMS = ("double_integrator", "cruise_control", "navigation", "magnetic_pointer_c",
            "magnetic_pointer_a")

DRIVER = r"""
#define _POSIX_C_SOURCE 199309L
#include <time.h>
#include "{name}.h"

static double now_ns(void)
{{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e9 + (double)t.tv_nsec;
}}

/* per state: the best of `rounds` rounds of `reps` calls, ns per call; idx: its region */
void bench(int P, const double *X, double *ns, int *idx, int reps, int rounds)
{{
    double u[{up}_NU];
    volatile int sink = 0;
    int p, r, k;
    for (p = 0; p < P; ++p) {{
        double best = 1e300;
        for (r = 0; r < rounds; ++r) {{
            double t0 = now_ns(), t1;
            for (k = 0; k < reps; ++k) {{
                sink += {name}_evaluate(X + p * {up}_NTHETA, u);
            }}
            t1 = now_ns();
            if ((t1 - t0) / reps < best) {{
                best = (t1 - t0) / reps;
            }}
        }}
        ns[p] = best;
        idx[p] = {name}_evaluate(X + p * {up}_NTHETA, u);
    }}
    (void)sink;
}}
"""


def states_inside(law, dep, count: int, seed: int) -> np.ndarray:
    lo, hi = dep.boxes
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    rng = np.random.default_rng(seed)
    out, have = [], 0
    while have < count:
        X = rng.uniform(lo, hi, size=(4 * count, lo.size))
        X = X[law.locate(X) >= 0]
        out.append(X)
        have += X.shape[0]
    return np.vstack(out)[:count]


#: the region of operation of issue 39's quadrotor (``--problems quadrotor-operation``)
OPERATION = "quadrotor-operation"


def operation_quadrotor(count: int, states: dict) -> object:
    """The quadrotor at hover, N = 10 (``benchmarks/on_demand.py``), verified over 5 s on
    demand; its region of operation (``deploy.operation.operation_law``). Its states
    (``states[OPERATION]``): uniform in the tube's sample sets (the domain's box holds
    almost none of the regions' volume in 12 dimensions)."""
    import codev_engine as ce
    from benchmarks.on_demand import quadrotor
    from codev_engine.deploy.operation import operation_law
    from codev_engine.law_on_demand import OnDemandLaw

    problem = quadrotor(10)
    od = OnDemandLaw(problem)
    t0 = time.perf_counter()
    result = ce.verify(problem, od)
    law, _ = operation_law(problem, od, result)
    print(f"{OPERATION}: {result.verdict} on {law.num_regions} regions in "
          f"{time.perf_counter() - t0:.1f} s", flush=True)
    tube, Ts = result.tube, float(problem.model.sample_time)
    k = np.ceil(tube.t_start / Ts - 1e-9)
    hit = k * Ts <= tube.t_end + 1e-12
    lo, hi = tube.lower[hit], tube.upper[hit]
    rng = np.random.default_rng(0)
    pick = rng.integers(0, lo.shape[0], count)
    states[OPERATION] = lo[pick] + rng.uniform(size=(count, law.n)) * (hi[pick] - lo[pick])
    return law


def run_c(obj, method: str, X: np.ndarray, ref: np.ndarray, tmp: Path,
          leaf_size: int | None = None, reps: int = 8, rounds: int = 3) -> dict:
    from codev_engine.deploy.expected import expected_rows
    from codev_engine.deploy.export import export_c
    from codev_engine.deploy.plan import plan

    t0 = time.perf_counter()
    c0 = time.process_time()
    ex = plan(obj, method, leaf_size=leaf_size)
    build_cpu = time.process_time() - c0
    build = time.perf_counter() - t0
    name = f"b_{method}"
    h, c = export_c(ex, tmp, name=name)
    (tmp / f"drv_{method}.c").write_text(DRIVER.format(name=name, up=name.upper()))
    so = tmp / f"{name}.so"
    subprocess.run(
        ["gcc", "-O2", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-shared",
         "-fPIC", "-o", str(so), str(c), str(tmp / f"drv_{method}.c")],
        check=True,
    )
    lib = ctypes.CDLL(str(so))
    P = X.shape[0]
    ns = np.empty(P)
    idx = np.empty(P, dtype=np.intc)
    ptr = np.ctypeslib.ndpointer
    lib.bench.argtypes = [ctypes.c_int, ptr(np.float64), ptr(np.float64), ptr(np.intc),
                          ctypes.c_int, ctypes.c_int]
    lib.bench(P, np.ascontiguousarray(X), ns, idx, reps, rounds)
    header = h.read_text()
    rom = int(header.split(f"#define {name.upper()}_ROM_BYTES ")[1].split()[0])
    return {
        "method": ex.method,
        "build_s": build,
        "build_cpu_s": build_cpu,
        "depth": ex.depth,
        "worst_tests": ex.tests,
        # tests on the path plus the owner's rows: the worst call away from every tested
        # hyperplane (the near-facet fallback, which checks every member, is worst_tests)
        "worst_fast_rows": ex.tree.cost()["fast"],
        "worst_macs": ex.macs,
        "rom_bytes": rom,
        "median_ns": float(np.median(ns)),
        "worst_ns": float(ns.max()),
        "p99_ns": float(np.percentile(ns, 99)),
        "mismatches": int(np.count_nonzero(idx != ref)),
        # the rows the code evaluates on the first 2,000 states, at the mean
        # (deploy.expected: what plan's auto compares on a region of operation)
        "mean_rows": float(expected_rows(ex.tree, ex.dep.A, ex.dep.b, ex.dep.off,
                                         X[:2000]).mean()),
        "leaves": int(ex.tree.num_leaves),
        "nodes": int(ex.tree.num_nodes),
        "leaf_size": max([1] + [int(g.size) for g in ex.tree.leaf_group]),
        "calls_per_state": f"best of {rounds} rounds of {reps}",
    }


def run_ppopt(dep, X: np.ndarray, ref: np.ndarray) -> dict | None:
    try:
        from ppopt.critical_region import CriticalRegion
        from ppopt.solution import Solution
        from ppopt.upop.point_location import PointLocation
    except ImportError:
        return None
    regions = []
    for i in range(dep.num_regions):
        r0, r1 = dep.off[i], dep.off[i + 1]
        regions.append(CriticalRegion(
            A=dep.F[i], b=dep.G[i][:, None], C=np.zeros((0, 0)), d=np.zeros((0, 1)),
            E=dep.A[r0:r1], f=dep.b[r0:r1][:, None], active_set=[],
        ))
    pl = PointLocation(Solution(program=None, critical_regions=regions, is_overlapping=False))
    P = min(X.shape[0], 20_000)
    ns = np.empty(P)
    idx = np.empty(P, dtype=int)
    pl.locate(X[0][:, None])  # compile
    for p in range(P):
        th = X[p][:, None]
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter_ns()
            k = pl.locate(th)
            best = min(best, time.perf_counter_ns() - t0)
        ns[p] = best
        idx[p] = k
    return {
        "method": "ppopt-PointLocation",
        "median_ns": float(np.median(ns)),
        "worst_ns": float(ns.max()),
        "states": P,
        # (its rule: the first region whose rows hold, no tolerance)
        "disagreements": int(np.count_nonzero(idx != ref[:P])),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--states", type=int, default=100_000)
    ap.add_argument("--problems", default=",".join(PROBLEMS))
    ap.add_argument("--solution", action="append", default=[],
                    help="an mp_testset problem (.npz) to solve and export, or a solution "
                    "saved by codev mpsolve --out")
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument("--leaf-size", type=int, default=None,
                    help="regions a tree leaf may check (default: plan's, 8 above 2,000)")
    ap.add_argument("--time-limit", type=float, default=None,
                    help="seconds before the tree is given up (default: bst.TIME_LIMIT)")
    ap.add_argument("--reps", type=int, default=8, help="calls per round (default 8)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds per state, the best "
                    "counts (default 3)")
    ap.add_argument("--seq-reps", type=int, default=None,
                    help="calls per round of the sequential search (default --reps: on a "
                    "10^4-region law, 10^5 states x 24 calls of ~0.2 ms take ~9 min)")
    ap.add_argument("--seq-rounds", type=int, default=None,
                    help="rounds per state of the sequential search (default --rounds)")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    seq_reps = args.reps if args.seq_reps is None else args.seq_reps
    seq_rounds = args.rounds if args.seq_rounds is None else args.seq_rounds
    if shutil.which("gcc") is None:
        print("no gcc on PATH: nothing to measure")
        return 0
    import codev_engine as ce
    from codev_engine.deploy import bst
    from codev_engine.deploy.plan import ceil_log2, deployable, plan

    if args.time_limit is not None:
        bst.TIME_LIMIT = args.time_limit

    # warm up the compiled code (numba caches) on a small law
    plan(ce.synthesize(ce.load_spec(ROOT / "examples" / "double_integrator.toml")), "bst")
    objs = []
    states: dict[str, np.ndarray] = {}
    for name in [p for p in args.problems.split(",") if p]:
        if name == OPERATION:
            objs.append((name, operation_quadrotor(args.states, states)))
            continue
        objs.append((name, ce.synthesize(ce.load_spec(ROOT / "examples" / f"{name}.toml"))))
    keys = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq")
    for path in args.solution:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in keys if k in z.files}
            solved = "format" in z.files and str(z["format"]).startswith("codev-mp-solution")
        if solved:  # a solution saved by `codev mpsolve --out`
            objs.append((Path(path).stem, ce.MpSolution.load(path)))
            continue
        t0 = time.perf_counter()
        sol = ce.mpsolve(ce.MpProgram(**data, name=Path(path).stem))
        print(f"{Path(path).stem}: {sol.num_regions} regions solved in "
              f"{time.perf_counter() - t0:.1f} s", flush=True)
        objs.append((Path(path).stem, sol))
    rows = []
    for name, obj in objs:
        dep = deployable(obj)
        X = states[name] if name in states else states_inside(obj, dep, args.states, seed=0)
        ref = obj.locate(X)
        R, d = dep.num_regions, dep.F.shape[2]
        from codev_engine.deploy.bst import TreeTooLargeError

        with tempfile.TemporaryDirectory() as tmp:
            s = run_c(obj, "sequential", X, ref, Path(tmp), reps=seq_reps, rounds=seq_rounds)
            try:
                b = run_c(obj, "bst", X, ref, Path(tmp), args.leaf_size, args.reps,
                          args.rounds)
            except TreeTooLargeError as exc:
                b = None
                print(f"{name}: no tree: {exc}", flush=True)
        if name == OPERATION:  # (the tree is built again: auto's choice on the tube)
            from codev_engine.deploy.plan import plan

            print(f"{name}: auto chooses {plan(obj, 'auto').method}", flush=True)
        peer = None if args.no_peer else run_ppopt(dep, X, ref)
        rows.append({"problem": name, "regions": R, "n": d, "target_tests":
                     2 * ceil_log2(R) + d, "c": [r for r in (b, s) if r], "ppopt": peer})
        if b is None:
            print(f"{name}: {R} regions, n={d} | sequential: worst {s['worst_tests']} rows, "
                  f"ROM {s['rom_bytes']} B, median {s['median_ns']:.0f} ns, worst "
                  f"{s['worst_ns']:.0f} ns, mismatches {s['mismatches']}", flush=True)
            continue
        print(
            f"{name}: {R} regions, n={d} | bst: build {b['build_s']:.2f} s "
            f"({b['build_cpu_s']:.2f} s CPU), "
            f"{b['nodes']} nodes, leaves of <= {b['leaf_size']} regions, hyperplane tests "
            f"on the path {b['depth']} (target 2*ceil(log2 R) + n = {2 * ceil_log2(R) + d}), "
            f"worst fast path {b['worst_fast_rows']} rows, certified worst "
            f"{b['worst_tests']} rows / "
            f"{b['worst_macs']} MACs, ROM {b['rom_bytes']} B, median {b['median_ns']:.0f} ns, "
            f"worst {b['worst_ns']:.0f} ns, mean rows {b['mean_rows']:.0f}, mismatches "
            f"{b['mismatches']} | sequential: worst "
            f"{s['worst_tests']} rows, ROM {s['rom_bytes']} B, median {s['median_ns']:.0f} ns, "
            f"mean rows {s['mean_rows']:.0f}, "
            f"worst {s['worst_ns']:.0f} ns, mismatches {s['mismatches']}"
            + ("" if peer is None else f" | PPOPT PointLocation: median "
               f"{peer['median_ns']:.0f} ns, worst {peer['worst_ns']:.0f} ns "
               f"({peer['disagreements']} disagreements)"),
            flush=True,
        )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
