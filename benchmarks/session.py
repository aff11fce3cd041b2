"""Session cache benchmark: the first run of a session against a second, unchanged run.

For each spec, in a fresh temporary session folder:

- **in-process**: ``Session.run`` (model, synthesis, verification, recording) twice in one
  interpreter; the second run loads every artifact (checked by SHA-256 and by its loader).
- **CLI**: ``codev run SPEC --session DIR --json`` twice as subprocesses (wall time,
  interpreter start and imports included, which caching cannot remove).

With ``--sharded DIR``: the law as shards (issue 43). A session in ``DIR`` (made when
missing: a chain of ``--chain`` integrators, ``RunOptions(sharded=True, upto="synthesis")``,
one shard without a cluster), then its cached run, ``--repeats`` times: the run's wall time,
the synthesis stage's, the bytes this process read in it (``rchar`` of ``/proc/self/io``:
every ``read``, page cache included) and the shards the law read (``ShardedLaw.loads``).

Prints a table and, with ``--json OUT``, writes the numbers. A benchmark, not a test:
exits 0 whatever the ratios are.

Usage::

    .venv/bin/python benchmarks/session.py [--specs a.toml b.toml] [--repeats 3] [--json out.json]
    .venv/bin/python benchmarks/session.py --sharded /tmp/s6 [--chain 6] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import codev_engine as ce  # noqa: E402
from codev_engine.session import RunOptions, Session  # noqa: E402

DEFAULT_SPECS = ["examples/magnetic_pointer_a.toml", "examples/double_integrator.toml"]


def in_process(spec: Path, repeats: int) -> dict:
    """Best-of-``repeats`` first and second ``Session.run`` times, with per-stage seconds."""
    firsts, seconds_, stages = [], [], {}
    for _ in range(repeats):
        problem = ce.load_spec(spec)
        with tempfile.TemporaryDirectory() as tmp:
            session = Session.create(Path(tmp) / "s")
            first = session.run(problem, RunOptions())
            second = session.run(problem, RunOptions())
        assert all(s.status == "cached" for s in second.stages), second.stages
        firsts.append(first.seconds)
        seconds_.append(second.seconds)
        stages = {
            s.stage: {"first": round(s.seconds, 4), "second": round(t.seconds, 4)}
            for s, t in zip(first.stages, second.stages, strict=True)
        }
    return {
        "first_s": min(firsts),
        "second_s": min(seconds_),
        "first_median_s": statistics.median(firsts),
        "second_median_s": statistics.median(seconds_),
        "ratio": min(firsts) / min(seconds_),
        "stages": stages,
        "regions": first.law.num_regions if first.law else None,
        "verdict": first.result.verdict if first.result else None,
    }


def cli(spec: Path) -> dict:
    """Wall time of two ``codev run --session`` processes (imports included)."""
    exe = Path(sys.executable).parent / "codev"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "workbench.cli"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("first", "second"):
            t0 = time.perf_counter()
            proc = subprocess.run(
                [*cmd, "run", str(spec), "--session", f"{tmp}/s", "--json"],
                capture_output=True,
                text=True,
                env=env,
                check=False,
            )
            out[f"{name}_s"] = time.perf_counter() - t0
            if proc.returncode not in (0, 1):
                raise SystemExit(f"codev run failed: {proc.stderr.strip()}")
            out[f"{name}_statuses"] = {
                k: v["status"] for k, v in json.loads(proc.stdout)["session"]["stages"].items()
            }
    out["ratio"] = out["first_s"] / out["second_s"]
    return out


def _rchar() -> int:
    """Bytes this process has read so far (every ``read``, the page cache's included)."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("rchar:"):
            return int(line.split()[1])
    return 0


def chain(n: int) -> str:
    """A chain of ``n`` integrators under a quadratic MPC, horizon 4 (as
    ``tests/engine/test_interrupt.chain``: 5 -> ~1,400 regions)."""
    eye = [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]
    return (
        f'name = "chain{n}"\n[plant]\nstates = {json.dumps([f"x{i}" for i in range(n)])}\n'
        f'inputs = ["u"]\ndynamics = {json.dumps([f"x{i + 1}" for i in range(n - 1)] + ["u"])}\n'
        f"[model]\nsample_time = 0.5\n[mpc]\nhorizon = 4\nnorm = 2\nQ = {eye}\nR = [[1.0]]\n"
        f"u_min = [-1.0]\nu_max = [1.0]\nx_min = {[-2.0] * n}\nx_max = {[2.0] * n}\n"
        f"[verify]\ntime_horizon = 2.0\n"
        f"initial_set = {{ lower = {[-0.1] * n}, upper = {[0.1] * n} }}\n"
    )


def sharded_open(folder: Path, chain_n: int, repeats: int) -> dict:
    """The cached run of a session whose law is stored as shards (made in ``folder`` when
    missing): wall time, the synthesis stage's, bytes read, shards read."""
    problem = ce.loads_spec(chain(chain_n), path=str(folder.parent / f"chain{chain_n}.toml"))
    options = RunOptions(sharded=True, upto="synthesis")
    out: dict = {"chain": chain_n}
    if not (folder / "session.json").exists():
        t0 = time.perf_counter()
        rep = Session.create(folder).run(problem, options)
        out["computed_s"] = time.perf_counter() - t0
        assert rep.stage("synthesis").status == "computed"
    session = Session.open(folder)
    shards = next((folder / "artifacts").glob("synthesis-*.shards"))
    out["artifact_bytes"] = sum(p.stat().st_size for p in shards.iterdir())
    runs = []
    for _ in range(repeats):
        before = _rchar()
        c0, t0 = time.process_time(), time.perf_counter()
        rep = session.run(problem, options, journal=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        read = _rchar() - before
        syn = rep.stage("synthesis")
        assert syn.status == "cached", syn
        runs.append({"wall_s": wall, "cpu_s": cpu, "synthesis_s": syn.seconds, "read_bytes": read,
                     "shards_read": rep.law.loads})
    out["regions"] = rep.law.num_regions
    out["shards"] = rep.law.shards
    out["runs"] = runs
    best = min(runs, key=lambda r: r["wall_s"])
    print(f"load average {os.getloadavg()[0]:.1f}; chain{chain_n}: {out['regions']} regions "
          f"in {out['shards']} shard(s), {out['artifact_bytes'] / 1e6:.2f} MB"
          + (f", computed in {out['computed_s']:.1f} s" if "computed_s" in out else ""))
    print(f"cached run (best of {repeats}): {best['wall_s'] * 1e3:.1f} ms, synthesis stage "
          f"{best['synthesis_s'] * 1e3:.1f} ms, {best['read_bytes'] / 1e6:.2f} MB read, "
          f"{best['shards_read']} shards read; median wall "
          f"{statistics.median(r['wall_s'] for r in runs) * 1e3:.1f} ms, median CPU "
          f"{statistics.median(r['cpu_s'] for r in runs) * 1e3:.1f} ms")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--specs", nargs="+", default=DEFAULT_SPECS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="OUT")
    ap.add_argument("--sharded", metavar="DIR", type=Path,
                    help="the cached run of a session whose law is stored as shards")
    ap.add_argument("--chain", type=int, default=6,
                    help="with --sharded: the chain of integrators whose law it stores")
    args = ap.parse_args()
    if args.sharded:
        got = sharded_open(args.sharded.resolve(), args.chain, args.repeats)
        if args.json:
            Path(args.json).write_text(json.dumps(got, indent=2))
        return 0
    rows = []
    print(f"load average {os.getloadavg()[0]:.1f}; best of {args.repeats} in-process runs")
    header = (
        f"{'spec':<28} {'regions':>7} {'first s':>8} {'second s':>9} {'ratio':>7}"
        f" | {'CLI first s':>11} {'CLI second s':>12} {'CLI ratio':>9}"
    )
    print(header)
    print("-" * len(header))
    for spec in args.specs:
        path = (ROOT / spec) if not Path(spec).is_absolute() else Path(spec)
        ip = in_process(path, args.repeats)
        c = cli(path)
        rows.append({"spec": spec, "in_process": ip, "cli": c})
        print(
            f"{Path(spec).stem:<28} {ip['regions']:>7} {ip['first_s']:>8.3f} "
            f"{ip['second_s']:>9.4f} {ip['ratio']:>6.0f}x | {c['first_s']:>11.2f} "
            f"{c['second_s']:>12.2f} {c['ratio']:>8.1f}x"
        )
        for stage, t in ip["stages"].items():
            print(f"    {stage:<14} first {t['first']:>8.4f} s   second {t['second']:>8.4f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
