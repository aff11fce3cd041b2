"""Session cache benchmark: the first run of a session against a second, unchanged run.

For each spec, in a fresh temporary session folder:

- **in-process**: ``Session.run`` (model, synthesis, verification, recording) twice in one
  interpreter; the second run loads every artifact (checked by SHA-256 and by its loader).
- **CLI**: ``codev run SPEC --session DIR --json`` twice as subprocesses (wall time,
  interpreter start and imports included, which caching cannot remove).

Prints a table and, with ``--json OUT``, writes the numbers. A benchmark, not a test:
exits 0 whatever the ratios are.

Usage::

    .venv/bin/python benchmarks/session.py [--specs a.toml b.toml] [--repeats 3] [--json out.json]
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--specs", nargs="+", default=DEFAULT_SPECS)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args()
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
