"""Benchmark: the MPC formulations (tracking, input rates, soft and mixed constraints, move
blocking, LQR terminal ingredients) as multi-parametric programs, ours against PPOPT.

Usage::

    python benchmarks/formulations.py [--out DIR] [--timeout 60] [--no-peer] [--json OUT]

Each design below is condensed by ``codev_engine.mpc.build_program`` and written to ``DIR``
(default: a temporary folder) in the mp_testset ``.npz`` convention (``H, c, C, A, b, F,
A_theta, b_theta``); then ``benchmarks/mp.py`` solves every file with ``mpsolve`` and with
PPOPT 1.6.12 in the same run (one subprocess per solve, see its docstring). The designs: the
bundled examples of the formulations, a 2-state position servo with a free reference box and a
slew-rate limit (theta of dimension 4) at N = 10 -- the issue's target, under 1 s and at least
10x PPOPT -- and seeded random tracking / rate designs.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import codev_engine as ce  # noqa: E402
from codev_engine.mpc import build_program  # noqa: E402
from codev_engine.pipeline import loads_spec  # noqa: E402
from codev_engine.plant import discretize  # noqa: E402

SERVO = """
name = "servo"
# a DC-motor position servo (second-order model: J = 0.01 kg m^2, b = 0.1 N m s, K = 0.01
# N m/A folded into the input gain), voltage limited to +-1 (normalised), slew +-0.2 per sample
[plant]
states = ["theta", "omega"]
inputs = ["V"]
A = [[0.0, 1.0], [0.0, -10.0]]
B = [[0.0], [10.0]]
[model]
sample_time = 0.05
[mpc]
horizon = {N}
norm = "2"
Q = [[10.0, 0.0], [0.0, 0.1]]
R = [[0.1]]
x_min = [-2.0, -5.0]
x_max = [2.0, 5.0]
u_min = [-1.0]
u_max = [1.0]
C = [[1.0, 0.0]]
du_min = [-0.2]
du_max = [0.2]
[mpc.reference]
signal = "y"
lower = [-1.0]
upper = [1.0]
"""


def random_design(seed: int) -> str:
    """A seeded random 2-state, 1-input tracking design with rate bounds."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1.0, 0.5)
    N = int(rng.integers(3, 7))
    du = float(rng.uniform(0.1, 0.5))
    rd = float(rng.uniform(0.0, 1.0))
    return f"""
name = "rand{seed}"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 1.0], [0.0, {a:.3f}]]
B = [[0.0], [1.0]]
[model]
sample_time = 0.2
[mpc]
horizon = {N}
norm = "2"
Q = [[1.0, 0.0], [0.0, 0.1]]
R = [[0.2]]
Rd = [[{rd:.3f}]]
x_min = [-4.0, -2.0]
x_max = [4.0, 2.0]
u_min = [-1.0]
u_max = [1.0]
C = [[1.0, 0.0]]
du_min = [-{du:.3f}]
du_max = [{du:.3f}]
[mpc.reference]
signal = "y"
lower = [-1.0]
upper = [1.0]
"""


def designs() -> dict[str, str]:
    out = {}
    for f in ("double_integrator_lqr", "mass_spring_soft", "two_carts_mixed"):
        out[f] = (ROOT / "examples" / f"{f}.toml").read_text(encoding="utf-8")
    out["servo_N10"] = SERVO.format(N=10)
    out["servo_N5"] = SERVO.format(N=5)
    for s in range(4):
        out[f"random_track_rate_{s}"] = random_design(s)
    return out


def export(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in designs().items():
        problem = loads_spec(text, check_mpc=False)
        p = build_program(problem.mpc, discretize(problem)).program
        np.savez(folder / f"{name}.npz", H=p.H, c=p.c, C=p.C, A=p.A, b=p.b, F=p.F,
                 A_theta=p.A_theta, b_theta=p.b_theta)
        law = ce.synthesize(problem)
        print(f"{name:24s} theta {p.d}  z {p.nz}  rows {p.A.shape[0]}  "
              f"law {law.num_regions} regions in {law.meta['seconds']:.3f} s (synthesize)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="folder for the .npz programs (default: temporary)")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument("--json", metavar="OUT")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(args.out) if args.out else Path(tmp)
        export(folder)
        sys.path.insert(0, str(ROOT / "benchmarks"))
        import mp  # benchmarks/mp.py: the peer run

        json_out = args.json or str(Path(tmp) / "formulations.json")
        rest = [str(folder), "--timeout", str(args.timeout), "--json", json_out]
        if args.no_peer:
            rest.append("--no-peer")
        code = mp.main(rest)
        print()
        print(target_lines(json.loads(Path(json_out).read_text()), args.timeout))
        return code


def target_lines(report: dict, timeout: float) -> str:
    """The issue's target on the servo at N = 10, from this run: our wall and CPU time
    (build + solve, imports excluded, numba's cached kernel loading included) with the
    load when the solve started, PPOPT's time, and the ratio (a lower bound when PPOPT
    timed out)."""
    import mp

    row = next((r for r in report["rows"] if r["name"] == "servo_N10"), None)
    if row is None or row.get("ours", {}).get("status") != "ok":
        return "servo_N10: not solved by ours in this run"
    o = row["ours"]
    text = (f"servo_N10 target (under 1 s, >= 10x PPOPT): ours {o['seconds']:.3f} s wall, "
            f"{o.get('cpu_seconds', float('nan')):.3f} s CPU, {o['regions']} regions, "
            f"load {o['load_before']:.1f} at start")
    p = row.get("ppopt")
    if p is not None:
        ratio = mp.ratio_text(row, timeout)
        peer = (f"{p['seconds']:.3f} s" if p["status"] == "ok"
                else f"{p['status']} (> {timeout:g} s)")
        text += f"; PPOPT {peer}; ratio {ratio or '-'}"
        ratio_cpu = None
        if o.get("cpu_seconds"):
            if p["status"] == "ok":
                ratio_cpu = p["seconds"] / o["cpu_seconds"]
            elif p["status"] == "timeout":
                ratio_cpu = timeout / o["cpu_seconds"]
        if ratio_cpu is not None:
            text += (f" ({'>=' if p['status'] != 'ok' else ''}{ratio_cpu:.1f}x against our "
                     "CPU time)")
    return text


if __name__ == "__main__":
    raise SystemExit(main())
