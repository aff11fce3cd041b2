"""Start-up benchmark: ``codev`` as whole processes, interpreter start and imports included.

Three commands, each run as a fresh process (issue 23's targets in brackets):

- ``codev --help``                                   [under 0.2 s]
- the first ``codev run SPEC --session DIR``          (a fresh DIR: every stage computed;
  the compiled kernels' disk cache warm, from one run before the measured ones)
- the cached rerun, the same command again            [at least 10x faster than the first]

Wall time and CPU time (user + system of the child) are both reported: on a shared machine
the wall time grows with the load, the CPU time much less. The best of ``--repeats`` runs is
the figure (the median is printed too). Then one more cached run in a process that reports
which heavy libraries it imported (scipy, sympy, cvxpy, control, numba, rerun, matplotlib,
dask): a fully cached run needs none but rerun's small native reader of the file footer.

``--before DIR``: the same commands also on another checkout (e.g. ``git archive COMMIT |
tar -x -C DIR``), run by this interpreter with ``PYTHONPATH=DIR``, in the same run, so the
two are measured under the same load. Prints a table; ``--json OUT`` writes the numbers.
A benchmark, not a test: exits 0 whatever the figures are.

Usage::

    .venv/bin/python benchmarks/startup.py [--spec examples/magnetic_pointer_a.toml]
        [--repeats 5] [--before DIR] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SPEC = "examples/magnetic_pointer_a.toml"

#: the libraries a cached run should not import (top-level module names)
HEAVY = ("scipy", "sympy", "cvxpy", "control", "numba", "rerun", "rerun_bindings", "matplotlib",
         "dask", "distributed", "textual", "rich")


def timed(cmd: list[str], env: dict, cwd: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one process; it must exit 0 (or 1: a verdict that is no proof)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0, 1):
        raise SystemExit(f"{' '.join(cmd)}: exit {proc.returncode}\n{proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def summary(samples: list[tuple[float, float]]) -> dict:
    walls, cpus = [s[0] for s in samples], [s[1] for s in samples]
    return {
        "wall_s": round(min(walls), 4),
        "wall_median_s": round(statistics.median(walls), 4),
        "cpu_s": round(min(cpus), 4),
        "cpu_median_s": round(statistics.median(cpus), 4),
    }


def loaded_on_cached_run(code_root: Path, spec: Path, session: Path, env: dict) -> list[str]:
    """The heavy libraries in ``sys.modules`` after a cached ``codev run`` in a process."""
    probe = (
        "import sys, io, contextlib\n"
        "from workbench.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        f"    code = main(['run', {str(spec)!r}, '--session', {str(session)!r}])\n"
        "assert code in (0, 1), code\n"
        f"print('loaded:' + ','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, cwd=code_root
    )
    if not out.stdout.startswith("loaded:"):
        raise SystemExit(f"the import probe failed:\n{out.stderr}")
    return [m for m in out.stdout.strip().removeprefix("loaded:").split(",") if m]


def measure(code_root: Path, spec: Path, repeats: int) -> dict:
    """The three commands against the checkout ``code_root``."""
    env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
    env["PYTHONPATH"] = str(code_root)
    codev = [sys.executable, "-m", "workbench.cli"]
    helps, firsts, cached = [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        # warm-up, not measured: the compiled kernels' disk cache (numba) of this checkout
        warm = [*codev, "run", str(spec), "--session", str(Path(tmp) / "warm")]
        timed(warm, env, code_root)
        for _ in range(repeats):
            helps.append(timed([*codev, "--help"], env, code_root))
        for i in range(repeats):
            session = Path(tmp) / f"s{i}"
            run = [*codev, "run", str(spec), "--session", str(session)]
            firsts.append(timed(run, env, code_root))
            cached.append(timed(run, env, code_root))
        heavy = loaded_on_cached_run(code_root, spec, Path(tmp) / "s0", env)
    first, again = summary(firsts), summary(cached)
    return {
        "help": summary(helps),
        "first_run": first,
        "cached_run": again,
        "ratio_wall": round(first["wall_s"] / again["wall_s"], 2),
        "ratio_cpu": round(first["cpu_s"] / again["cpu_s"], 2),
        "heavy_imports_on_cached_run": heavy,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", default=DEFAULT_SPEC, help="the spec (default %(default)s)")
    ap.add_argument("--repeats", type=int, default=5, help="runs of each command (best of)")
    ap.add_argument("--before", metavar="DIR", help="also measure this checkout, same run")
    ap.add_argument("--json", metavar="OUT", help="write the numbers as JSON")
    args = ap.parse_args()
    spec = (ROOT / args.spec).resolve()
    roots = {"this checkout": ROOT}
    if args.before:
        roots = {"before": Path(args.before).resolve(), "after": ROOT}
    load = os.getloadavg()
    results = {name: measure(root, spec, args.repeats) for name, root in roots.items()}
    load_end = os.getloadavg()
    print(f"{spec.name}; best of {args.repeats}; load average {load[0]:.2f} at the start, "
          f"{load_end[0]:.2f} at the end ({os.cpu_count()} cores)")
    print(f"{'':<14} {'--help s':>16} {'first run s':>16} {'cached run s':>16} "
          f"{'ratio':>12}  heavy imports on a cached run")
    print(f"{'':<14} {'wall / CPU':>16} {'wall / CPU':>16} {'wall / CPU':>16} "
          f"{'wall / CPU':>12}")
    for name, r in results.items():
        cells = [f"{r[k]['wall_s']:.3f} / {r[k]['cpu_s']:.3f}"
                 for k in ("help", "first_run", "cached_run")]
        ratio = f"{r['ratio_wall']:.1f} / {r['ratio_cpu']:.1f}"
        heavy = ", ".join(r["heavy_imports_on_cached_run"]) or "none"
        print(f"{name:<14} {cells[0]:>16} {cells[1]:>16} {cells[2]:>16} {ratio:>12}  {heavy}")
    if args.json:
        Path(args.json).write_text(
            json.dumps({"spec": str(args.spec), "repeats": args.repeats,
                        "load": [load[0], load_end[0]], "results": results}, indent=1),
            encoding="utf-8",
        )


if __name__ == "__main__":
    main()
