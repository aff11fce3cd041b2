"""Benchmark: verification on the regions reached, computed on demand, against the full law
(issue 39).

Usage::

    python benchmarks/on_demand.py [CASE ...] [--full] [--horizon T]

Cases: ``examples`` (the bundled 2-norm linear examples ``double_integrator_lqr``,
``mass_spring_soft``, ``two_carts_mixed``, ``dc_motor_servo``, full law and on demand),
``examples-lp`` (the bundled norm-1 and norm-inf examples, the same; their full laws
unmerged, whatever ``mpc.simplify`` says, so that the tubes compare),
``chain6``, ``chain8``, ``chain10`` (chains of integrators: ``tests/engine/test_mpqp_chain.py``'s
spec, N = 4, from a box of 1 % of the state range over ``--horizon`` seconds, 2.5 by
default: over 5 s the loop leaves the MPC's feasible set at 3 s, the design's verdict),
``afti16-5``, ``afti16-10`` and ``quadrotor-5``, ``quadrotor-10`` (:func:`afti16`,
:func:`quadrotor`); default ``examples chain8``. Per case: regions computed, wall seconds
(the law, then ``ce.verify``; ``time.perf_counter``), CPU seconds and peak resident memory
of the process, verdict, on demand (``OnDemandLaw``), again from the region cache the first
run saved (``OnDemandLaw.save``/``load``: what a session's later run or another
verification of the same MPC does) and, with ``--full``, for the full law
(``ce.synthesize``: minutes to hours) with whether the tubes are identical. Run one case per
process for its own peak memory.

A benchmark, not a test: it asserts nothing and exits 0.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import codev_engine as ce
from codev_engine.law_on_demand import OnDemandLaw

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # (the chain's spec is the test suite's)
EXAMPLES = ["double_integrator_lqr", "mass_spring_soft", "two_carts_mixed", "dc_motor_servo"]
#: the bundled norm-1 / norm-inf examples (mp-LPs: the basis walk, ``mp/on_demand_lp.py``)
EXAMPLES_LP = ["double_integrator", "cruise_control", "cruise_grade", "cruise_loaded",
               "magnetic_pointer_a", "magnetic_pointer_b", "magnetic_pointer_c", "navigation"]


def _vec(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def _mat(M) -> str:
    return "[" + ", ".join(_vec(r) for r in np.atleast_2d(M)) + "]"


def chain(n: int, horizon: float) -> ce.Problem:
    """The chain of ``n`` integrators of issue 23 (``tests/engine/test_mpqp_chain.py``'s
    spec) with a [verify] table: from a box of 1 % of the state range, safe in the bounds."""
    from tests.engine.test_mpqp_chain import chain_spec

    text = chain_spec(n) + f"""
[verify]
time_horizon = {horizon}
initial_set = {{ lower = {_vec([-0.02] * n)}, upper = {_vec([0.02] * n)} }}
input_bounds = true
[[verify.safe]]
lower = {_vec([-2.0] * n)}
upper = {_vec([2.0] * n)}
"""
    return ce.loads_spec(text, path=f"<chain of {n} integrators>", check_mpc=False)


def afti16(horizon: int, seconds: float = 2.0) -> ce.Problem:
    """The AFTI-16 aircraft (the MPC and Hybrid Toolboxes' ``afti16`` demo: Kapasouris,
    Athans and Stein's linearised longitudinal dynamics, 4 states, 2 elevator/flaperon
    inputs in degrees, |u| <= 25, sample time 0.05 s) tracking a 10 degree pitch reference
    (y = (attack angle, pitch), r = (0, 10)) with a soft attack-angle bound |y1| <= 0.5,
    weights 10 on both outputs and 0.01 on the inputs; verified from a small box around
    level flight: the pitch stays within [-5, 15] and the attack angle within [-5, 5]. The
    speed (unweighted and unbounded, ft/s) falls by about 400 a second while the pitch rises:
    it leaves the law's domain (``domain_bound``, 100 around level flight) at 0.3 s, so the
    verdict is ``unsafe`` (``undefined``), the design's. (With ``domain_bound = 1000`` it is
    ``robustly_safe`` at N = 3: tests/engine/test_thin_pieces.py holds the thin pieces that
    once ended it in a ValueError.)"""
    A = [[-0.0151, -60.5651, 0.0, -32.174], [-0.0001, -1.3411, 0.9929, 0.0],
         [0.00018, 43.2541, -0.86939, 0.0], [0.0, 0.0, 1.0, 0.0]]
    B = [[-2.516, -13.136], [-0.1689, -0.2514], [-17.251, -1.5766], [0.0, 0.0]]
    C = [[0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    Q = np.diag([0.0, 10.0, 0.0, 10.0])
    text = f"""
name = "afti16_N{horizon}"
[plant]
states = ["speed", "attack", "pitch_rate", "pitch"]
inputs = ["elevator", "flaperon"]
A = {_mat(A)}
B = {_mat(B)}
[model]
sample_time = 0.05
[mpc]
horizon = {horizon}
norm = "2"
Q = {_mat(Q)}
R = {_mat(0.01 * np.eye(2))}
u_min = [-25.0, -25.0]
u_max = [25.0, 25.0]
C = {_mat(C)}
y_min = [-0.5, -100.0]
y_max = [0.5, 100.0]
soft = ["y_min", "y_max"]
[mpc.reference]
signal = "y"
value = [0.0, 10.0]
[verify]
time_horizon = {seconds}
initial_set = {{ lower = [-0.1, -0.01, -0.01, -0.1], upper = [0.1, 0.01, 0.01, 0.1] }}
input_bounds = true
[[verify.safe]]
lower = [-inf, -5.0, -inf, -5.0]
upper = [inf, 5.0, inf, 15.0]
"""
    return ce.loads_spec(text, path=f"<AFTI-16, N = {horizon}>", check_mpc=False)


def quadrotor(horizon: int, seconds: float = 5.0) -> ce.Problem:
    """A quadrotor linearised at hover (12 states: position, roll/pitch/yaw, velocity, body
    rates; 4 inputs: thrust and the three torques about hover; m = 1.4 kg, Jx = Jy = 0.054,
    Jz = 0.104 kg m^2, g = 9.81: the ARCH quadrotor's numbers), sample time 0.1 s, Q = I,
    R = 0.1 I, P = "lqr", bounds on tilt, velocity and inputs; verified from a box of 1 %
    of the ARCH initial set's radius (0.4) around hover: the altitude stays within 0.5."""
    m, jx, jy, jz, g = 1.4, 0.054, 0.054, 0.104, 9.81
    A = np.zeros((12, 12))
    A[0:3, 6:9] = np.eye(3)  # position' = velocity
    A[3:6, 9:12] = np.eye(3)  # attitude' = body rates (at hover)
    A[6, 4], A[7, 3] = g, -g  # vx' = g pitch, vy' = -g roll
    B = np.zeros((12, 4))
    B[8, 0], B[9, 1], B[10, 2], B[11, 3] = 1 / m, 1 / jx, 1 / jy, 1 / jz
    big = [10.0, 10.0, 10.0, 0.5, 0.5, 3.0, 2.0, 2.0, 2.0, 3.0, 3.0, 3.0]
    names = ["px", "py", "pz", "roll", "pitch", "yaw", "vx", "vy", "vz", "p", "q", "r"]
    r0 = 0.004
    text = f"""
name = "quadrotor_N{horizon}"
[plant]
states = {json.dumps(names)}
inputs = ["thrust", "tau_roll", "tau_pitch", "tau_yaw"]
A = {_mat(A)}
B = {_mat(B)}
[model]
sample_time = 0.1
[mpc]
horizon = {horizon}
norm = "2"
Q = {_mat(np.eye(12))}
R = {_mat(0.1 * np.eye(4))}
P = "lqr"
x_min = {_vec([-b for b in big])}
x_max = {_vec(big)}
u_min = [-5.0, -0.5, -0.5, -0.2]
u_max = [5.0, 0.5, 0.5, 0.2]
[verify]
time_horizon = {seconds}
initial_set = {{ lower = {_vec([-r0] * 6 + [0.0] * 6)}, upper = {_vec([r0] * 6 + [0.0] * 6)} }}
input_bounds = true
[[verify.safe]]
lower = {_vec([-np.inf] * 2 + [-0.5] + [-np.inf] * 9)}
upper = {_vec([np.inf] * 2 + [0.5] + [np.inf] * 9)}
"""
    return ce.loads_spec(text, path=f"<quadrotor, N = {horizon}>", check_mpc=False)


CASES = {
    "chain6": lambda a: chain(6, a.horizon), "chain8": lambda a: chain(8, a.horizon),
    "chain10": lambda a: chain(10, a.horizon), "afti16-5": lambda a: afti16(5),
    "afti16-10": lambda a: afti16(10), "quadrotor-5": lambda a: quadrotor(5),
    "quadrotor-10": lambda a: quadrotor(10),
}


def run(problem: ce.Problem, how: str, cache: Path | None = None) -> dict:
    """The law (``how``: "all", "reached", or "cached": the law on demand loaded from the
    region cache ``cache`` a "reached" run wrote) and its verification, timed (wall and
    CPU seconds of this process; ``peak_mb`` the process's peak resident memory so far)."""
    t0, c0 = time.perf_counter(), time.process_time()
    if how == "all":
        # (an mp-LP's merged regions are no basis's: unmerged, the tubes compare)
        law = ce.synthesize(problem, simplify=None if problem.mpc.norm == "2" else False)
    elif how == "cached":
        law = OnDemandLaw.load(cache, problem)
    else:
        law = OnDemandLaw(problem)
    t1 = time.perf_counter()
    result = ce.verify(problem, law)
    t2, c2 = time.perf_counter(), time.process_time()
    if how == "reached" and cache is not None:
        law.save(cache)
    return {"regions": law.num_regions, "law_s": t1 - t0, "verify_s": t2 - t1,
            "wall_s": t2 - t0, "cpu_s": c2 - c0,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "verdict": f"{result.verdict}" + (f" ({result.reason})" if result.reason else ""),
            "tube": result.tube}


def _row(name: str, how: str, r: dict, same: str = "") -> None:
    print(f"{name:<24} {how:<8} {r['regions']:>8,} {r['law_s']:>9.2f} {r['verify_s']:>9.2f} "
          f"{r['wall_s']:>9.2f} {r['cpu_s']:>9.2f} {r['peak_mb']:>8.0f}  {r['verdict']:<28} "
          f"{same}", flush=True)


def _same(a: dict, b: dict) -> str:
    same = (a["tube"].lower.shape == b["tube"].lower.shape
            and np.array_equal(a["tube"].lower, b["tube"].lower)
            and np.array_equal(a["tube"].upper, b["tube"].upper))
    return "identical" if same else "differs"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", default=["examples", "chain8"],
                    help=f"examples, examples-lp, or any of {', '.join(CASES)} "
                    "(default: examples chain8)")
    ap.add_argument("--full", action="store_true",
                    help="also synthesise the cases' whole laws (minutes to hours)")
    ap.add_argument("--horizon", type=float, default=2.5,
                    help="the chains' verification horizon in seconds (default 2.5)")
    args = ap.parse_args()
    for c in args.cases:
        if c not in ("examples", "examples-lp") and c not in CASES:
            ap.error(f"unknown case {c!r}")
    print(f"{'case':<24} {'regions':<8} {'computed':>8} {'law s':>9} {'verify s':>9} "
          f"{'wall s':>9} {'cpu s':>9} {'peak MB':>8}  {'verdict':<28} tube")
    for c in args.cases:
        if c in ("examples", "examples-lp"):
            for name in EXAMPLES if c == "examples" else EXAMPLES_LP:
                problem = ce.load_spec(ROOT / "examples" / f"{name}.toml")
                full, mine = run(problem, "all"), run(problem, "reached")
                _row(name, "all", full)
                _row(name, "reached", mine, _same(full, mine))
            continue
        problem = CASES[c](args)
        with tempfile.TemporaryDirectory() as tmp:
            cache = Path(tmp) / "regions.npz"
            mine = run(problem, "reached", cache)
            _row(c, "reached", mine, "" if args.full else "(full law: --full)")
            _row(c, "cached", run(problem, "cached", cache))
        if args.full:
            full = run(problem, "all")
            _row(c, "all", full, _same(full, mine))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
