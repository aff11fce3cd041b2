"""Benchmark: the mp-LP engines on the paper MPCs, in one process (issue 29).

Usage::

    python benchmarks/mplp.py [--repeats 2] [--horizons 20] [--pointer-horizons 8]
                              [--testset DIR] [--json OUT]
                              [--ppopt combinatorial,geometric] [--ppopt-timeout 120]

For each of the five paper mp-LPs (the condensed MPC of ``examples/<name>.toml``) it
times ``mpsolve`` with ``SolveOptions(mplp="facets")`` (the geometric explorer, the engine
before issue 29) and ``mplp="bases"`` (the basis graph of ``mp/mplp_graph.py``), best of
``--repeats``, warm (a first solve of each is not timed), and checks that both have the
same number of regions. Times are CPU seconds of this process (``time.process_time``: wall
times on a shared machine follow its load), wall seconds in the JSON. ``bases`` runs its
compiled kernel from ``mplp_graph.JIT_AFTER`` regions on, as by default. Next to them:
the same MPC with ``norm = "2"`` (the mp-QP active-set search), its time per region.

Then the double integrator with norms inf and 1 at each of ``--horizons``
(``mplp="auto"``: the graph, or the explorer where the graph falls back), with its
outcome (and the explorer's facet pieces skipped as flat, and the holes found past them and
explored: ``mplp._Explorer._fill_holes``), and the magnetic pointer with norm inf at
each of ``--pointer-horizons`` (``auto``, one warm run). With ``--testset``: the mp-LPs of
that folder (the shared mp test set), facets against auto. With ``--ppopt``: PPOPT 1.6.12 on the
same five programs, each algorithm in its own subprocess killed at ``--ppopt-timeout``
(``synth.run_peer``; CPU of the subprocess tree). Prints a table; asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import codev_engine as ce
from codev_engine.mp import mplp_graph
from codev_engine.mpc import build_program
from codev_engine.pipeline import load_spec
from codev_engine.plant import discretize

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PROBLEMS = [
    "double_integrator",
    "navigation",
    "cruise_control",
    "magnetic_pointer_a",
    "magnetic_pointer_c",
]


def program(name: str, **mpc) -> ce.MpProgram:
    """The condensed MPC of an example, with fields of its ``[mpc]`` table replaced."""
    prob = load_spec(EXAMPLES / f"{name}.toml")
    prob = dataclasses.replace(prob, mpc=dataclasses.replace(prob.mpc, **mpc))
    return build_program(prob.mpc, discretize(prob)).program


def timed(prog: ce.MpProgram, mode: str, repeats: int) -> tuple[float, ce.MpSolution]:
    """Best CPU time of ``repeats`` solves (after one untimed) and the last solution (its
    best wall time in ``sol.stats["wall_s"]``)."""
    sol = ce.mpsolve(prog, options=ce.SolveOptions(mplp=mode, workers=1))
    best = wall = float("inf")
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        sol = ce.mpsolve(prog, options=ce.SolveOptions(mplp=mode, workers=1))
        best = min(best, time.process_time() - c)
        wall = min(wall, time.perf_counter() - t)
    sol.stats["wall_s"] = wall
    return best, sol


def ppopt(prog: ce.MpProgram, algorithm: str, timeout: float, workdir: Path, tag: str) -> str:
    """PPOPT on ``prog`` in a subprocess (``synth.run_peer``): regions and CPU seconds, or
    what went wrong."""
    from synth import Prog, run_peer

    p = Prog(prog.c, prog.C, prog.A, prog.b, prog.F, prog.A_theta, prog.b_theta)
    res = run_peer(p, algorithm, timeout, workdir, tag)
    if res.get("status") != "ok":
        return f"{res.get('status')} {res.get('error', '')[:60]}"
    return f"{res['regions']} regions {res['cpu_seconds']:.2f} s"


def main() -> None:
    """Run the benchmark and print its table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--horizons", default="20", help="comma-separated horizons")
    ap.add_argument("--pointer-horizons", default="8",
                    help="comma-separated horizons of the magnetic pointer (norm inf), or ''")
    ap.add_argument("--testset", default=None, help="folder of .npz programs")
    ap.add_argument("--json", default=None)
    ap.add_argument("--ppopt", default="", help="comma-separated PPOPT algorithms")
    ap.add_argument("--ppopt-timeout", type=float, default=120.0)
    args = ap.parse_args()
    print(f"load: {os.getloadavg()}")
    rows = []
    tot = {"facets": 0.0, "bases": 0.0}
    print(f"CPU seconds; the basis graph's kernel from {mplp_graph.JIT_AFTER} regions on")
    print(f"{'problem':22s} {'regions':>7s} {'facets s':>9s} {'bases s':>9s} {'ratio':>6s} "
          f"{'bases ms/reg':>12s} {'mp-QP ms/reg':>12s}")
    for name in PROBLEMS:
        prog = program(name)
        tf, sf = timed(prog, "facets", args.repeats)
        tb, sb = timed(prog, "bases", args.repeats)
        tot["facets"] += tf
        tot["bases"] += tb
        try:
            tq, sq = timed(program(name, norm="2"), "auto", args.repeats)
            qp = 1e3 * tq / max(1, len(sq.regions))
        except ce.CodevError:
            qp = float("nan")
        assert len(sf.regions) == len(sb.regions)
        row = dict(problem=name, regions=len(sb.regions), facets_s=tf, bases_s=tb,
                   facets_wall_s=sf.stats["wall_s"], bases_wall_s=sb.stats["wall_s"],
                   bases_ms_per_region=1e3 * tb / max(1, len(sb.regions)), qp_ms_per_region=qp,
                   qp_regions=len(sq.regions) if qp == qp else None)
        rows.append(row)
        print(f"{name:22s} {row['regions']:7d} {tf:9.3f} {tb:9.3f} {tf / tb:6.2f} "
              f"{row['bases_ms_per_region']:12.2f} {qp:12.2f}")
    print(f"{'together':22s} {'':7s} {tot['facets']:9.3f} {tot['bases']:9.3f} "
          f"{tot['facets'] / tot['bases']:6.2f}")
    for norm in ("inf", "1"):
        for n in (int(h) for h in args.horizons.split(",") if h):
            prog = program("double_integrator", norm=norm, horizon=n)
            t = time.process_time()
            try:
                sol = ce.mpsolve(prog, options=ce.SolveOptions(workers=1))
                out = f"{len(sol.regions)} regions, {sol.stats.get('mplp')}"
                if "graph_fallback" in sol.stats:
                    out += f" ({sol.stats['graph_fallback']})"
                for key in ("skipped_pieces", "holes_filled"):
                    if sol.stats.get(key):
                        out += f", {key} {sol.stats[key]}"
            except ce.CodevError as e:
                out = f"error: {e}"
            dt = time.process_time() - t
            rows.append(dict(problem=f"double_integrator norm={norm} N={n}", seconds=dt,
                             outcome=out))
            print(f"double integrator norm={norm:3s} N={n:3d}: {dt:7.2f} s CPU  {out}")
    for n in (int(h) for h in args.pointer_horizons.split(",") if h):
        # issue 29's target: N = 8 (~8,500 regions) under 5 s (auto, warm)
        prog = program("magnetic_pointer_a", horizon=n)
        try:
            t, sol = timed(prog, "auto", 1)
            out = f"{len(sol.regions)} regions, {sol.stats.get('mplp')}, " \
                  f"{1e3 * t / max(1, len(sol.regions)):.2f} ms/region, " \
                  f"slivers {sol.stats.get('slivers', 0)}"
        except ce.CodevError as e:
            t, out = float("nan"), f"error: {e}"
        rows.append(dict(problem=f"magnetic_pointer_a N={n}", seconds=t, outcome=out))
        print(f"magnetic pointer N={n:3d}: {t:7.2f} s CPU  {out}")
    if args.testset:
        tot = {"facets": 0.0, "auto": 0.0}
        for path in sorted(Path(args.testset).glob("*.npz")):
            prog = ce.MpProgram.load(path)
            if not prog.is_lp:
                continue
            tf, sf = timed(prog, "facets", 1)
            ta, sa = timed(prog, "auto", 1)
            tot["facets"] += tf
            tot["auto"] += ta
            rows.append(dict(problem=path.stem, regions_facets=len(sf.regions),
                             regions_auto=len(sa.regions), facets_s=tf, auto_s=ta,
                             engine=sa.stats.get("mplp")))
            print(f"{path.stem:28s} {len(sf.regions):6d} {len(sa.regions):6d} {tf:8.3f} "
                  f"{ta:8.3f} {tf / ta:6.2f} {sa.stats.get('mplp')}")
        print(f"{'test-set mp-LPs together':28s} {'':13s} {tot['facets']:8.3f} "
              f"{tot['auto']:8.3f} {tot['facets'] / tot['auto']:6.2f}")
    algorithms = [a for a in args.ppopt.split(",") if a]
    if algorithms:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            for name in PROBLEMS:
                for alg in algorithms:
                    out = ppopt(program(name), alg, args.ppopt_timeout, Path(tmp), name)
                    rows.append(dict(problem=name, ppopt=alg, outcome=out))
                    print(f"PPOPT {alg:14s} {name:22s} {out}", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
