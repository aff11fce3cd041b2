"""Benchmark: the mp-QP search and a nonlinear verification on 1 and 2 Dask workers.

Usage::

    python benchmarks/scale.py [--mp pop_mpqp_051] [--folder MP_TESTSET] [--verify SPEC]
                               [--workers 1,2] [--skip-mp] [--skip-verify] [--json OUT]

For each worker count W, a ``LocalCluster`` of W processes (``ce.Executor(workers=W)``),
started and warmed first (``start``: the cluster up and, for the verification, one run of
the spec on it: the workers' plant enclosures compiled), then timed:

- **mp**: ``ce.mpsolve`` of the mp test set's problem (default ``pop_mpqp_051``, 970k
  regions; ``--folder`` defaults to ``$CODEV_MP_TESTSET``, else
  ``../shared/benchmarks/mp_testset`` beside the checkout) with the executor:
  wall time, the workers' numba warm-up (``worker_warmup_seconds``), the tasks and the
  seconds they took on the workers, the client's CPU seconds (this process: the walk's
  merge of every batch in its own thread, Dask's threads and the local scheduler; and the
  walk's thread alone), and a digest of the regions (every run must give the same);
- **verify**: ``ce.verify`` of ``--verify`` (default ``examples/vanderpol.toml``) with its
  initial set cut into ``--cells`` parts per axis (default 8: 64 cells, each a task) with
  the executor; the result must equal the serial one (verdict, tube, counters), which is
  timed too (``serial``, in this process);
- speed-up and efficiency from 1 to W workers (``T_1 / (W T_W)``), and the workers' CPU
  share (their CPU time over W times the wall time: below 1 when the machine's other work
  held the cores);
- the scheduler's per-task overhead on the largest cluster: 2000 no-op tasks submitted at
  once (wall time per task), and one task's round trip (median of 50).

With ``--sharded --out-shards DIR`` the workers write the law (``mpsolve(shard_writer=...)``)
and the run also reports the end's CPU on the workers (``end_worker_cpu_seconds``: the
regions' centres, the cut by space, the merge and the law files) and, on the law written,
how many shard boxes hold a point and how many shards ``locate`` asks per point (the
Chebyshev centres of 4,000 regions drawn at random; read after the client's CPU is taken).

The load average is printed before and after. It is a benchmark, not a test: it prints a
table and exits 0 (the equality checks print ``DIFFER`` if they fail).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
DEFAULT_FOLDER = Path(
    os.environ.get("CODEV_MP_TESTSET") or ROOT.parent / "shared" / "benchmarks" / "mp_testset"
)



def _digest(sol) -> str:
    """A hash of every region's rows, law and active set, in order."""
    h = hashlib.sha256()
    ra = sol.regions
    for name in ("A", "b", "offsets", "K", "k", "active", "active_offsets"):
        h.update(np.ascontiguousarray(getattr(ra, name)).tobytes())
    return h.hexdigest()[:16]


def _verify_key(result) -> tuple:
    t = result.tube
    arrays = b"".join(np.ascontiguousarray(getattr(t, f)).tobytes()
                      for f in ("t_start", "t_end", "lower", "upper", "branch"))
    counts = tuple(result.stats.get(k) for k in ("branches", "refinements", "partitions"))
    return result.verdict, result.reason, counts, hashlib.sha256(arrays).hexdigest()[:16]


#: the mp-QP search's counters of the latest solve (kept even when it stops at the limit)
_LAST_STATS: dict = {}


def _capture_stats() -> None:
    """Keep a reference to the search's ``stats`` dict (``mpsolve`` drops it on an error)."""
    from codev_engine.mp import solve

    inner = solve.explore_active_sets

    def explore(*args, **kwargs):
        _LAST_STATS.clear()
        kwargs["stats"] = kwargs.get("stats") if kwargs.get("stats") is not None else {}
        try:
            return inner(*args, **kwargs)
        finally:
            _LAST_STATS.update(kwargs["stats"])

    solve.explore_active_sets = explore


def _reset_peak() -> None:
    """Reset this process's peak resident memory (``VmHWM``; Linux: clear_refs 5)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass


def _peak_mb() -> float:
    """This process's peak resident memory since :func:`_reset_peak`, in MB (VmHWM)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def _shards_per_point(law, points: int = 4000) -> dict:
    """How many shard boxes (the shards ``locate`` may read) hold a point of the law, and
    how many shards ``locate`` looks in for it: the Chebyshev centres of ``points``
    regions drawn at random (this reads the shards; a uniform draw in the domain's box
    misses the regions of a --stop-at prefix, and a draw in a region's box its sliver)."""
    from codev_engine.geometry.polytope import chebyshev_ball

    if not law.num_regions:
        return {}
    rng = np.random.default_rng(0)
    pick = rng.integers(0, law.num_regions, size=points)
    X = np.array([chebyshev_ball(law.A[int(i)], law.b[int(i)])[0] for i in pick])
    X = X[type(law)(law.dir, cache=law.shards).locate(X) >= 0]
    k = law.shards_at(X)
    # the look-ups ``locate`` makes (its cell's shard first, when the manifest has cells)
    fresh = type(law)(law.dir, cache=law.shards)
    fresh.locate(X)
    return {"shards": law.shards, "points": int(X.shape[0]),
            "mean": float(k.mean()) if k.size else float("nan"),
            "max": int(k.max(initial=0)), "one": float(np.mean(k == 1)) if k.size else 0.0,
            "asked": fresh.asked / max(1, X.shape[0])}


def _cpu(client) -> float:
    return sum(client.run(time.process_time).values())


def _wait_for(client, n: int, timeout: float = 120.0) -> None:
    """Wait until ``n`` workers have joined the scheduler."""
    t0 = time.perf_counter()
    while len(client.scheduler_info()["workers"]) < n:
        if time.perf_counter() - t0 > timeout:
            raise RuntimeError(f"{n} workers did not join in {timeout:.0f} s")
        time.sleep(0.2)


def main(argv: list[str] | None = None) -> int:
    import codev_engine as ce

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mp", default="pop_mpqp_051", help="the mp test set's problem")
    ap.add_argument("--folder", default=str(DEFAULT_FOLDER), help="the mp test set")
    ap.add_argument("--verify", metavar="SPEC", default=str(ROOT / "examples" / "vanderpol.toml"),
                    help="the verification (default examples/vanderpol.toml)")
    ap.add_argument("--cells", type=int, default=8, help="cells per axis (default 8)")
    ap.add_argument("--workers", default="1,2", help="worker counts (default 1,2)")
    ap.add_argument("--max-regions", type=int, metavar="N",
                    help="time the search up to N regions only (it stops there: the walk is "
                    "the same for every worker count, so is that prefix)")
    ap.add_argument("--sharded", action="store_true",
                    help="the sharded search (mpsolve(sharded=True): regions stay on workers)")
    ap.add_argument("--stop-at", type=int, metavar="N",
                    help="with --sharded: end the rounds at N regions and run the search's "
                    "end on them (the merge, or the workers' law shards): a prefix, not a "
                    "law of the program (no coverage check)")
    ap.add_argument("--out-shards", metavar="DIR",
                    help="with --sharded: the workers write the law's shards into DIR/<W> "
                    "(mpsolve(shard_writer=...)); no region comes back to this process")
    ap.add_argument("--scheduler-process", action="store_true",
                    help="the scheduler and the workers in processes of their own (a "
                         "SubprocessCluster): this process is only the client, as with a "
                         "remote cluster")
    ap.add_argument("--skip-mp", action="store_true")
    ap.add_argument("--skip-verify", action="store_true")
    ap.add_argument("--json", metavar="OUT", help="write the numbers as JSON")
    args = ap.parse_args(argv)
    counts = [int(w) for w in args.workers.split(",")]
    _capture_stats()
    out: dict = {"cpus": os.cpu_count(), "load_before": os.getloadavg(), "mp": {},
                 "verify": {}}
    print(f"load average before: {out['load_before']}")

    problem = law = None
    if not args.skip_verify:
        problem = ce.load_spec(args.verify)
        law = ce.synthesize(problem)
        t0 = time.perf_counter()
        serial = ce.verify(problem, law, cells=args.cells)
        out["verify"]["serial"] = {"seconds": time.perf_counter() - t0,
                                   "result": _verify_key(serial)}
        print(f"verify {problem.name}: serial {out['verify']['serial']['seconds']:.2f} s, "
              f"{serial.verdict}, {serial.stats['partitions']} cells")
    program = None
    if not args.skip_mp:
        with np.load(Path(args.folder) / f"{args.mp}.npz", allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        keys = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta", "Aeq", "beq", "Feq")
        program = ce.MpProgram(**{k: data[k] for k in keys if k in data}, name=args.mp)
    overhead = None
    for w in counts:
        t0 = time.perf_counter()
        cluster = None
        if args.scheduler_process:
            # (the scheduler out of this process: its CPU is not the client's)
            from distributed.deploy.subprocess import SubprocessCluster

            cluster = SubprocessCluster(n_workers=w, threads_per_worker=1,
                                        dashboard_address=None, silence_logs=40)
            executor = ce.Executor(scheduler=cluster.scheduler_address)
            _wait_for(executor.client, w)
        else:
            executor = ce.Executor(workers=w)
        try:
            client = executor.client
            if problem is not None:
                from codev_engine.reach.enclosure import plant_enclosures, plant_hessian

                # every worker's plant enclosures compiled (cached per plant, per process)
                client.run(plant_enclosures, problem)
                client.run(plant_hessian, problem)
            start = time.perf_counter() - t0
            if problem is not None:
                cpu0, t1 = _cpu(client), time.perf_counter()
                res = ce.verify(problem, law, executor=executor, cells=args.cells)
                wall = time.perf_counter() - t1
                out["verify"][w] = {
                    "start_seconds": start, "seconds": wall,
                    "cpu_share": (_cpu(client) - cpu0) / (w * wall),
                    "equal_serial": _verify_key(res) == out["verify"]["serial"]["result"],
                }
                print(f"verify, {w} workers: {wall:.2f} s "
                      f"(cpu share {out['verify'][w]['cpu_share']:.2f}), "
                      f"{'equal' if out['verify'][w]['equal_serial'] else 'DIFFER'}")
            if program is not None:
                cpu0, me0, t1 = _cpu(client), time.process_time(), time.perf_counter()
                main0 = time.thread_time()
                st: dict = {}
                found = [0]
                opts = ce.SolveOptions(max_regions=args.max_regions or 10**8)
                writer = None
                if args.stop_at:
                    from codev_engine.mp import sharded

                    sharded.STOP_AT = args.stop_at
                    opts = ce.SolveOptions(max_regions=opts.max_regions, coverage_samples=0)
                if args.out_shards:
                    from codev_engine.law_shard_writer import ShardWriter

                    writer = ShardWriter(str(Path(args.out_shards) / str(w)),
                                         np.zeros(program.d), rows=(0, program.nz))
                _reset_peak()
                try:
                    sol = ce.mpsolve(program, executor=executor, options=opts,
                                     progress=lambda r, f=found: f.__setitem__(0, r),
                                     sharded=args.sharded, shard_writer=writer)
                    st, regions = sol.stats, sol.num_regions
                    digest = (_digest(sol) if writer is None
                              else f"{sol.law.shards} shards written by the workers")
                except ce.SolverError as exc:  # (--max-regions: the prefix)
                    regions, digest = found[0], f"prefix of {found[0]}"
                    st, sol = _LAST_STATS, None
                    print(f"  stopped: {exc}", flush=True)
                wall = time.perf_counter() - t1
                out["mp"][w] = {
                    "seconds": wall, "regions": regions, "digest": digest,
                    "cpu_share": (_cpu(client) - cpu0) / (w * wall),
                    "client_cpu_seconds": time.process_time() - me0,
                    # (of which the walk's own thread: the rest is Dask's, the scheduler's
                    # of a LocalCluster included, which runs in this process)
                    "client_main_cpu_seconds": time.thread_time() - main0,
                    "tasks": st.get("tasks"), "task_seconds": st.get("task_seconds") or 0.0,
                    "worker_warmup_seconds": st.get("worker_warmup_seconds") or 0.0,
                    "candidates": st.get("candidates"),
                    "load": os.getloadavg()[0],
                    # (this process's peak resident memory during the solve, VmHWM)
                    "client_peak_rss_mb": _peak_mb(),
                    "regions_before_merge": st.get("regions_before_merge") or regions,
                    "finish_client_cpu_seconds": st.get("finish_client_cpu_seconds"),
                    # (from the walk's last round to the solution: merge, domain, coverage)
                    "end_client_cpu_seconds": st.get("end_client_cpu_seconds"),
                    # (sharded: the coordinator's thread, the rounds, the merge at the end)
                    "coordinator_cpu_seconds": st.get("coordinator_cpu_seconds"),
                    "rounds": st.get("rounds"), "merge_cpu_seconds": st.get("merge_cpu_seconds"),
                    "worker_cpu_seconds": st.get("worker_cpu_seconds"),
                    # (the end on the workers: centres, the cut by space, merge and write)
                    "end_worker_cpu_seconds": st.get("end_worker_cpu_seconds"),
                    "rounds_client_cpu_seconds": st.get("rounds_client_cpu_seconds"),
                    "setup_client_cpu_seconds": st.get("setup_client_cpu_seconds"),
                    # (this process before the sharded walk: the program reduced, the
                    # first regions found serially, the compiled kernel loaded)
                    "before_walk_client_cpu_seconds": time.process_time() - me0
                    - (st.get("client_cpu_seconds") or 0.0),
                }
                d = out["mp"][w]
                # (after the client's CPU is read: this reads the law's shards here)
                d["shards_per_point"] = (_shards_per_point(sol.law) if writer is not None
                                         and hasattr(sol, "law") else None)
                print(f"mp {args.mp}, {w} workers: {wall:.1f} s, {d['regions']} regions "
                      f"[{d['digest']}], {d['tasks']} tasks ({d['task_seconds']:.1f} s on "
                      f"workers), client CPU {d['client_cpu_seconds']:.1f} s (the walk's thread "
                      f"{d['client_main_cpu_seconds']:.1f} s), warm-up "
                      f"{d['worker_warmup_seconds']:.2f} s, cpu share {d['cpu_share']:.2f}",
                      flush=True)
                if args.sharded:
                    per = 1e6 / max(d["regions"], 1)
                    print(f"  sharded: {d['rounds']} rounds, coordinator thread "
                          f"{d['coordinator_cpu_seconds']:.2f} s "
                          f"({per * d['coordinator_cpu_seconds']:.1f} us/region), client "
                          f"process {per * d['client_cpu_seconds']:.1f} us/region (during "
                          f"the rounds {per * (d['rounds_client_cpu_seconds'] or 0):.1f}), merge "
                          f"{d['merge_cpu_seconds'] or 0:.2f} s, workers' CPU "
                          f"{d['worker_cpu_seconds'] or 0:.1f} s", flush=True)
                    after = (d["client_cpu_seconds"] - d["before_walk_client_cpu_seconds"]
                             - (d["setup_client_cpu_seconds"] or 0)
                             - (d["rounds_client_cpu_seconds"] or 0))
                    print(f"  client process CPU: {d['before_walk_client_cpu_seconds']:.2f} s "
                          f"before the walk (the serial start), "
                          f"{d['setup_client_cpu_seconds'] or 0:.2f} s its set-up, "
                          f"{d['rounds_client_cpu_seconds'] or 0:.2f} s the rounds, "
                          f"{after:.2f} s after (merge, clean-up)", flush=True)
                    print(f"  client peak memory (VmHWM) {d['client_peak_rss_mb']:.0f} MB, "
                          f"its CPU from the last round on {d['end_client_cpu_seconds'] or 0:.2f} s"
                          + (f"; the end on the client: {d['finish_client_cpu_seconds']:.4f} s"
                             " (the manifest, coverage; the facets stay in the shards)"
                             if d["finish_client_cpu_seconds"] is not None else ""),
                          flush=True)
                    if d["shards_per_point"]:
                        q = d["shards_per_point"]
                        print(f"  the law's shards: {q['shards']}; a point of the domain is "
                              f"in {q['mean']:.2f} shard boxes on average (max {q['max']}, "
                              f"one box: {100 * q['one']:.0f} %; {q['points']} points); "
                              f"locate looks in {q['asked']:.2f} shards per point; "
                              f"the end on the workers {d['end_worker_cpu_seconds'] or 0:.1f} s "
                              "CPU", flush=True)
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
            if cluster is not None:
                cluster.close()
    for kind in ("verify", "mp"):
        base = out[kind].get(1, {}).get("seconds")
        for w in counts:
            d = out[kind].get(w)
            if d and base:
                d["speedup"] = base / d["seconds"]
                d["efficiency"] = d["speedup"] / w
                print(f"{kind}: {w} workers {d['seconds']:.2f} s, speed-up {d['speedup']:.2f}, "
                      f"efficiency {d['efficiency']:.2f}, cpu share {d['cpu_share']:.2f}")
    if program is not None:
        digests = {d["digest"] for w, d in out["mp"].items()}
        print(f"mp regions {'equal' if len(digests) == 1 else 'DIFFER'} across worker counts")
    if overhead:
        out["overhead"] = overhead
        print(f"scheduler: {1e3 * overhead['per_task_seconds']:.2f} ms per task (2000 no-ops "
              f"at once), {1e3 * overhead['round_trip_seconds']:.2f} ms one task's round trip")
    out["load_after"] = os.getloadavg()
    print(f"load average after: {out['load_after']} on {out['cpus']} CPUs")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=str), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
