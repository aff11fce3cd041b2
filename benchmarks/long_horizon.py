"""Benchmark: long horizons of the bundled double integrator (issue 26, Targets bullet 3).

Usage::

    python benchmarks/long_horizon.py [--exact] [--timeout 120] [--repeats 3]

Cases: ``examples/double_integrator.toml`` (continuous hold, norm inf, N = 2) over 9, 45, 100
and 1000 s, and its norm-1, N = 10 variant (224 regions) over 9 s. Per case: regions, verdict,
wall and CPU seconds (best of ``--repeats``, ``time.perf_counter`` / ``time.process_time`` around
``ce.verify``), branches and
the invariance certificate if one closed the run. ``--exact`` runs the linear engine without
merging and certificates (``LinearReach(..., merge=False)``, the engine before issue 26) with
a wall-clock limit per case (SIGALRM): "timeout" when it does not finish.
Targets: 1000 s in under 1 s; the norm-1, N = 10 variant over 9 s in under 2 s.

Then ``time_horizon = "inf"`` (safety for all time) on ``examples/double_integrator.toml``
(a polytope certificate, linear engine) and ``examples/pendulum.toml`` (an invariant
ellipsoid, nonlinear engine): verdict, reason, wall and CPU seconds (best of
``--repeats``), the certificate. Target: under 2 s each.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import re
import signal
import time
from pathlib import Path

import codev_engine as ce
from codev_engine.reach.linear import LinearReach, affine_plant
from codev_engine.reach.verification import verify

ROOT = Path(__file__).resolve().parent.parent
DI = ROOT / "examples" / "double_integrator.toml"
CASES = [(9.0, "inf", 2), (45.0, "inf", 2), (100.0, "inf", 2), (1000.0, "inf", 2), (9.0, "1", 10)]


def _spec(horizon: float, norm: str, N: int) -> ce.Problem:
    text = DI.read_text().replace("time_horizon = 9.0", f"time_horizon = {horizon}")
    text = text.replace('norm = "inf"', f'norm = "{norm}"').replace(
        "horizon = 2\n", f"horizon = {N}\n"
    )
    return ce.loads_spec(text, path=f"<double integrator T={horizon} norm={norm} N={N}>")


class _TimeoutError(Exception):
    pass


def _alarm(signum, frame):
    raise _TimeoutError


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--exact", action="store_true", help="the engine without merging")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    signal.signal(signal.SIGALRM, _alarm)
    print("| T (s) | norm | N | regions | verdict | seconds | CPU s | branches | certificate |")
    print("|---|---|---|---|---|---|---|---|---|")
    for T, norm, N in CASES:
        problem = _spec(T, norm, N)
        law = ce.synthesize(problem)
        best, verdict, branches, cert = float("inf"), "?", "?", "-"
        cpu = float("inf")
        for _ in range(args.repeats):
            signal.setitimer(signal.ITIMER_REAL, args.timeout)
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                if args.exact:
                    eng = LinearReach(
                        problem, law, affine_plant(problem), problem.verify.hold,
                        problem.verify.max_depth, merge=False,
                    )
                    eng.run()
                    verdict = "robustly_safe" if not eng.findings else "not proved"
                    stats = eng.stats
                else:
                    r = verify(problem, law)
                    verdict, stats = r.verdict, r.stats
            except _TimeoutError:
                verdict, branches = f"timeout {args.timeout:g} s", "-"
                break
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            best = min(best, time.perf_counter() - t0)
            cpu = min(cpu, time.process_time() - c0)
            branches = stats.get("branches")
            c = stats.get("certificate")
            if c:
                cert = f"samples {c['anchor_sample']} -> {c['closed_sample']}"
        secs = "-" if best == float("inf") else f"{best:.3f}"
        cpus = "-" if cpu == float("inf") else f"{cpu:.3f}"
        print(f"| {T:g} | {norm} | {N} | {law.num_regions} | {verdict} | {secs} | {cpus} | "
              f"{branches} | {cert} |", flush=True)
    print()
    print("| example | time_horizon | verdict | wall s | CPU s | certificate |")
    print("|---|---|---|---|---|---|")
    for stem in ("double_integrator", "pendulum"):
        text = re.sub(r"time_horizon = [0-9.]+", 'time_horizon = "inf"',
                      (ROOT / "examples" / f"{stem}.toml").read_text())
        problem = ce.loads_spec(text, path=f"<{stem} inf>")
        law = ce.synthesize(problem)
        best, cpu = float("inf"), float("inf")
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            r = verify(problem, law)
            best = min(best, time.perf_counter() - t0)
            cpu = min(cpu, time.process_time() - c0)
        c = r.stats.get("certificate") or {}
        cert = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}"
                         for k, v in c.items()) or (r.detail or "-")
        print(f"| {stem} | inf | {r.verdict}/{r.reason} | {best:.3f} | {cpu:.3f} | {cert} |",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
