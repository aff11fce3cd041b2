"""First-run benchmark: ``codev run`` from a fresh wheel install, first run against second.

What a newcomer meets (issue 41): the wheel built from this checkout, installed into a
venv, run from a folder outside the checkout with a fresh numba cache (``NUMBA_CACHE_DIR``
pointed at an empty folder). For each spec, ``codev run ex/SPEC --traces 1`` twice. The
first command of all finds the solver kernels never compiled: it says so on stderr
("preparing the solver kernels, once ...") and compiles them before its stages
(``codev_engine.kernels.prepare``); every later command loads them from the cache. The
figures: the announced step's wall time, and per spec the first run (the step taken out)
against the second. Issue 41's targets: the step under 60 s, each first run within 2 s of
the second (quiet machine).

Wall and CPU times (user + system of the children) are reported; the load average is
printed beside them. A benchmark, not a test: exits 0 whatever the figures are (the slow
test ``tests/contract/test_wheel.py::test_first_run_from_a_fresh_wheel`` runs it and checks
what is said, not how fast).

Usage::

    .venv/bin/python benchmarks/first_run.py [--venv DIR] [--json out.json]
        [SPEC ...]   # default: double_integrator.toml pendulum.toml vanderpol.toml

``--venv DIR``: reuse (or create) that venv: an existing one gets the new wheel without its
dependencies (minutes saved on a slow index); without it a temporary venv is built.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SPECS = ("double_integrator.toml", "pendulum.toml", "vanderpol.toml")
ANNOUNCED = "preparing the solver kernels, once"


def build_wheel(out: Path) -> Path:
    """The wheel of this checkout, built from a copy (an in-tree build leaves build/)."""
    src = out / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for folder in ("codev_engine", "workbench", "examples"):
        shutil.copytree(ROOT / folder, src / folder, ignore=ignore)
    for f in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / f, src / f)
    dist = out / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", str(src), "-w",
                    str(dist)], check=True, cwd=out, capture_output=True)
    (wheel,) = dist.glob("codev-*.whl")
    return wheel


def install(wheel: Path, venv: Path) -> Path:
    """``venv``'s python with ``wheel`` installed (a new venv gets the dependencies too)."""
    py = venv / "bin" / "python"
    if py.exists():
        cmd = [str(py), "-m", "pip", "install", "-q", "--no-deps", "--force-reinstall",
               str(wheel)]
    else:
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        cmd = [str(py), "-m", "pip", "install", "-q", str(wheel)]
    subprocess.run(cmd, check=True, capture_output=True)
    return py


def timed(args: list[str], cwd: Path, env: dict) -> dict:
    """One process: wall and CPU seconds, exit status, stderr."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=1800)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "status": out.returncode, "stdout": out.stdout,
            "stderr": out.stderr}


def measure(py: Path, specs: tuple[str, ...], work: Path) -> dict:
    """Each spec run twice by the venv's ``codev``, with a fresh numba cache.

    Returns
    -------
    dict
        ``step`` (the announced step's seconds as it printed them, or None), ``load``
        (the 1-minute load average before and after) and ``runs``: per spec ``first`` and
        ``second`` (each ``wall``, ``cpu``, ``status``, ``announced``) and ``first_wall``
        (the first run's wall time less the announced step's).
    """
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "CODEV_DEBUG")}
    env["NUMBA_CACHE_DIR"] = str(work / "numba-cache")  # fresh: nothing compiled yet
    codev = str(py.parent / "codev")
    subprocess.run([codev, "examples", "ex"], cwd=work, env=env, check=True,
                   capture_output=True)
    result: dict = {"step": None, "load": [os.getloadavg()[0]], "runs": {}}
    for spec in specs:
        runs = {}
        for which in ("first", "second"):
            r = timed([codev, "run", f"ex/{spec}", "--traces", "1"], work, env)
            r["announced"] = ANNOUNCED in r["stderr"]
            step = re.search(r"solver kernels ready \((\d+) s", r["stderr"])
            if step:
                result["step"] = float(step.group(1))
            runs[which] = r
        step = (result["step"] or 0.0) if runs["first"]["announced"] else 0.0
        first = runs["first"]["wall"] - step
        result["runs"][spec] = {**runs, "first_wall": first}
    result["load"].append(os.getloadavg()[0])
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("specs", nargs="*", default=list(SPECS))
    ap.add_argument("--venv", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        py = install(build_wheel(tmp), args.venv or tmp / "venv")
        print(f"wheel built and installed in {time.perf_counter() - t0:.0f} s")
        work = tmp / "work"
        work.mkdir()
        res = measure(py, tuple(args.specs), work)
    print(f"load average (1 min) {res['load'][0]:.1f} before, {res['load'][1]:.1f} after")
    print("announced step (first command only): "
          + ("not seen" if res["step"] is None else f"{res['step']:.0f} s"))
    print(f"{'spec':<24} {'1st wall':>9} {'2nd wall':>9} {'1st-2nd':>8} "
          f"{'1st cpu':>8} {'2nd cpu':>8}  status  announced")
    for spec, r in res["runs"].items():
        f, s = r["first"], r["second"]
        print(f"{spec:<24} {r['first_wall']:9.1f} {s['wall']:9.1f} "
              f"{r['first_wall'] - s['wall']:8.1f} {f['cpu']:8.1f} {s['cpu']:8.1f}  "
              f"{f['status']}/{s['status']}     {int(f['announced'])}/{int(s['announced'])}")
    if args.json:
        for r in res["runs"].values():
            for which in ("first", "second"):
                r[which].pop("stdout")
        args.json.write_text(json.dumps(res, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
