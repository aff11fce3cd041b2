"""Benchmark: an 8-design sweep of the double integrator, serial against Dask workers.

Usage::

    python benchmarks/sweep.py [--grid balanced|lopsided] [--workers 1,2] [--repeat 3]
                               [--json OUT]

The grid (``GRIDS``) is 8 designs of ``examples/double_integrator.toml``, each synthesised
and verified (``ce.sweep``): ``balanced`` is ``mpc.horizon = 5, 6, 7, 8`` x
``mpc.R = [[0.8]], [[1.0]]``, ``lopsided`` ``mpc.horizon = 2, 3, 4, 5`` x
``mpc.R = [[0.5]], [[1.0]]``. Timed, each the best of ``--repeat`` runs:

- ``serial``: ``ce.sweep`` in this process (after one design run to load the modules);
- for each worker count W: a ``LocalCluster`` of W processes (``ce.Executor(workers=W)``),
  ``start`` (the cluster up and every worker's modules loaded by one small design run on
  each, ``client.run``), ``sweep`` (the table on the warm cluster) and ``cold`` (start +
  one sweep: what ``codev sweep --workers W`` costs from nothing);
- speed-up and efficiency from 1 to W workers (``T_1 / (W T_W)``, warm), and the workers'
  CPU share (their CPU time over ``W`` times the wall time: below 1 when other work on the
  machine held the cores);
- the scheduler's per-task overhead on the largest cluster: 2000 no-op tasks (``abs``)
  submitted at once (wall time per task), and the round trip of one task (median of 50).

Every executor's rows are checked equal to the serial rows (wall times aside). It is a
benchmark, not a test: it prints a table and exits 0.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: the grids: ``balanced``, 8 designs of similar cost (each robustly safe in ~0.3 s), and
#: ``lopsided``, where one design (N = 4, R = 1: unknown after max_depth refinements) costs
#: most of the sweep, so that 2 workers cannot halve it whatever the executor
GRIDS = {
    "balanced": {"mpc.horizon": [5, 6, 7, 8], "mpc.R": [[[0.8]], [[1.0]]]},
    "lopsided": {"mpc.horizon": [2, 3, 4, 5], "mpc.R": [[[0.5]], [[1.0]]]},
}


def best(fn, repeat: int) -> tuple[float, object]:
    """The least wall time of ``repeat`` calls of ``fn`` and its last result."""
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv: list[str] | None = None) -> int:
    import codev_engine as ce
    from codev_engine.sweeps import TIMING_FIELDS, design_row, design_texts

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--grid", choices=sorted(GRIDS), default="balanced", help="the designs")
    ap.add_argument("--workers", default="1,2", help="worker counts (default 1,2)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing (best of)")
    ap.add_argument("--json", metavar="OUT", help="write the numbers as JSON")
    args = ap.parse_args(argv)
    counts = [int(w) for w in args.workers.split(",")]
    GRID = GRIDS[args.grid]

    def exact(rows):
        return [{k: v for k, v in r.items() if k not in TIMING_FIELDS} for r in rows]

    problem = ce.load_spec(ROOT / "examples" / "double_integrator.toml")
    warm_text = design_texts(problem, {"mpc.horizon": [2]})[0]
    design_row(warm_text, str(problem.path))  # this process's modules loaded
    serial, rows = best(lambda: ce.sweep(problem, GRID), args.repeat)
    reference = exact(rows)
    out: dict = {
        "designs": len(rows),
        "grid": args.grid,
        "serial_seconds": serial,
        "cpus": os.cpu_count(),
        "load_average": os.getloadavg()[0],
        "workers": {},
    }
    print(f"{len(rows)} designs; serial {serial:.3f} s (best of {args.repeat})")
    for r in rows:
        print(f"  {r['values']}: {r['regions']} regions, {r['verdict']}, "
              f"{r['synthesis_seconds'] + r['verification_seconds']:.3f} s")
    overhead = None
    for w in counts:
        t0 = time.perf_counter()
        executor = ce.Executor(workers=w)
        try:
            client = executor.client
            client.run(design_row, warm_text, str(problem.path))  # every worker's imports
            start = time.perf_counter() - t0
            t1 = time.perf_counter()
            first = ce.sweep(problem, GRID, executor=executor)
            cold = start + time.perf_counter() - t1
            cpu0 = sum(client.run(time.process_time).values())
            warm, rows = best(lambda ex=executor: ce.sweep(problem, GRID, executor=ex),
                              args.repeat)
            # the workers' CPU time over W cores' wall time: below 1 when the machine's other
            # work took the cores (a shared machine), whatever the executor does
            cpu = sum(client.run(time.process_time).values()) - cpu0
            same = exact(first) == reference and exact(rows) == reference
            out["workers"][w] = {"start_seconds": start, "sweep_seconds": warm,
                                 "cold_seconds": cold, "rows_equal_serial": same,
                                 "cpu_share": cpu / (args.repeat * warm * w)}
            if w == max(counts):
                n = 2000
                t1 = time.perf_counter()
                client.gather(client.map(abs, range(-n, 0), pure=False))
                per_task = (time.perf_counter() - t1) / n
                trips = []
                for i in range(50):
                    t1 = time.perf_counter()
                    client.submit(abs, -i, pure=False).result()
                    trips.append(time.perf_counter() - t1)
                overhead = {"per_task_seconds": per_task,
                            "round_trip_seconds": statistics.median(trips)}
        finally:
            executor.close()
    base = out["workers"].get(1, {}).get("sweep_seconds")
    print(f"\n{'workers':>7} {'start s':>8} {'sweep s':>8} {'cold s':>7} {'vs serial':>9} "
          f"{'speed-up':>8} {'efficiency':>10} {'cpu share':>9}  rows")
    for w, d in out["workers"].items():
        d["speedup_vs_serial"] = serial / d["sweep_seconds"]
        if base:
            d["speedup"] = base / d["sweep_seconds"]
            d["efficiency"] = d["speedup"] / w
        print(f"{w:>7} {d['start_seconds']:>8.2f} {d['sweep_seconds']:>8.3f} "
              f"{d['cold_seconds']:>7.2f} {d['speedup_vs_serial']:>9.2f} "
              f"{d.get('speedup', float('nan')):>8.2f} {d.get('efficiency', float('nan')):>10.2f}"
              f" {d['cpu_share']:>9.2f}  {'equal' if d['rows_equal_serial'] else 'DIFFER'}")
    if overhead:
        out["overhead"] = overhead
        print(f"\nscheduler: {1e3 * overhead['per_task_seconds']:.2f} ms per task (2000 no-ops "
              f"at once), {1e3 * overhead['round_trip_seconds']:.2f} ms one task's round trip")
    print(f"load average at start: {out['load_average']:.2f} on {out['cpus']} CPUs")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
