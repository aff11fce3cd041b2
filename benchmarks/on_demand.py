"""Benchmark: verification on the regions reached, computed on demand, against the full law
(issue 39).

Usage::

    python benchmarks/on_demand.py [--full-chain] [--chain N] [--horizon T]

Cases: the bundled 2-norm linear examples (``double_integrator_lqr``, ``mass_spring_soft``,
``two_carts_mixed``, ``dc_motor_servo``) and a chain of integrators (8 states by default:
``x_i' = x_{i+1}``, ``x_7' = u``, sample time 0.5, norm 2, N = 4, Q = I, R = 1, ``|x_i| <=
2``, ``|u| <= 1``) verified from a box of 1 % of the state range around the origin over
``--horizon`` seconds (2.5 by default: the loop leaves the MPC's feasible set at 3 s, an
``unsafe``/``undefined`` verdict that is the design's, not the tool's). Per case: regions
computed, wall seconds (the law, then ``ce.verify``; ``time.perf_counter``), verdict, for the
full law (``ce.synthesize``), on demand (``OnDemandLaw``) and, for the chain, on demand again
from the region cache the first run saved (``OnDemandLaw.save``/``load``: what a session's
later run or another verification of the same MPC does), and whether the tubes are
identical. The chain's full synthesis takes minutes (11,794 regions): it runs only with
``--full-chain``.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.law_on_demand import OnDemandLaw

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ["double_integrator_lqr", "mass_spring_soft", "two_carts_mixed", "dc_motor_servo"]


def chain(n: int, horizon: float) -> ce.Problem:
    """The chain of ``n`` integrators of issue 23 with a [verify] table (a 1 % box)."""
    states = ", ".join(f'"x{i}"' for i in range(n))
    dyn = ", ".join([f'"x{i + 1}"' for i in range(n - 1)] + ['"u"'])
    eye = ", ".join("[" + ", ".join("1.0" if i == j else "0.0" for j in range(n)) + "]"
                    for i in range(n))

    def vec(v: float) -> str:
        return "[" + ", ".join([repr(v)] * n) + "]"

    text = f"""
name = "chain{n}"
[plant]
states = [{states}]
inputs = ["u"]
dynamics = [{dyn}]
[model]
sample_time = 0.5
[mpc]
horizon = 4
norm = "2"
Q = [{eye}]
R = [[1.0]]
x_min = {vec(-2.0)}
x_max = {vec(2.0)}
u_min = [-1.0]
u_max = [1.0]
[verify]
time_horizon = {horizon}
initial_set = {{ lower = {vec(-0.02)}, upper = {vec(0.02)} }}
input_bounds = true
[[verify.safe]]
lower = {vec(-2.0)}
upper = {vec(2.0)}
"""
    return ce.loads_spec(text, path=f"<chain of {n} integrators>", check_mpc=False)


def run(problem: ce.Problem, how: str, cache: Path | None = None) -> dict:
    """The law (``how``: "all", "reached", or "cached": the law on demand loaded from the
    region cache ``cache`` a "reached" run wrote) and its verification, timed."""
    t0 = time.perf_counter()
    if how == "all":
        law = ce.synthesize(problem)
    elif how == "cached":
        law = OnDemandLaw.load(cache, problem)
    else:
        law = OnDemandLaw(problem)
    t1 = time.perf_counter()
    result = ce.verify(problem, law)
    t2 = time.perf_counter()
    if how == "reached" and cache is not None:
        law.save(cache)
    return {"regions": law.num_regions, "law_s": t1 - t0, "verify_s": t2 - t1,
            "wall_s": t2 - t0, "verdict": f"{result.verdict}"
            + (f" ({result.reason})" if result.reason else ""), "tube": result.tube}


def _row(name: str, how: str, r: dict, same: str = "") -> None:
    print(f"{name:<24} {how:<8} {r['regions']:>8,} {r['law_s']:>9.2f} {r['verify_s']:>9.2f} "
          f"{r['wall_s']:>9.2f}  {r['verdict']:<28} {same}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full-chain", action="store_true",
                    help="also synthesise the chain's whole law (minutes)")
    ap.add_argument("--chain", type=int, default=8, help="states of the chain (default 8)")
    ap.add_argument("--horizon", type=float, default=2.5,
                    help="the chain's verification horizon in seconds (default 2.5)")
    args = ap.parse_args()
    print(f"{'case':<24} {'regions':<8} {'computed':>8} {'law s':>9} {'verify s':>9} "
          f"{'wall s':>9}  {'verdict':<28} tube")
    for name in EXAMPLES:
        problem = ce.load_spec(ROOT / "examples" / f"{name}.toml")
        full, mine = run(problem, "all"), run(problem, "reached")
        same = (np.array_equal(full["tube"].lower, mine["tube"].lower)
                and np.array_equal(full["tube"].upper, mine["tube"].upper))
        _row(name, "all", full)
        _row(name, "reached", mine, "identical" if same else "differs")
    problem = chain(args.chain, args.horizon)
    name = f"chain{args.chain} T={args.horizon:g}"
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "regions.npz"
        mine = run(problem, "reached", cache)
        again = run(problem, "cached", cache)
    _row(name, "cached", again)
    if args.full_chain:
        full = run(problem, "all")
        same = (np.array_equal(full["tube"].lower, mine["tube"].lower)
                and np.array_equal(full["tube"].upper, mine["tube"].upper))
        _row(name, "all", full)
        _row(name, "reached", mine, "identical" if same else "differs")
    else:
        _row(name, "reached", mine, "(full law: --full-chain)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
