"""The tube's contract on every bundled example (issue 38): verified, then simulated densely.

For each ``examples/*.toml``: the verdict, and -- unless it is ``unsafe`` -- no simulated
state of the law's own loop (its rate limit's ``u_prev`` and reference, disturbance signals
and parameter corners, measurement-noise sequences) outside the exported tube up to the time
the tube is complete (the horizon, the explored part of one for all time, or the time a
partial tube's ``detail`` gives, docs/verification.md "The tube file").
"""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from codev_engine.pipeline import load_spec
from codev_engine.reach.simulate import simulate_many, theta_initial_box
from codev_engine.reach.verification import _signals, noise_sequences, verify
from codev_engine.synthesis import synthesize

EXAMPLES = sorted((Path(__file__).resolve().parents[2] / "examples").glob("*.toml"))


def _outside(tube, t: np.ndarray, X: np.ndarray, t_max: float, tol: float = 1e-9) -> tuple:
    """(count, worst excess) of the simulated states (P, K, n) at times ``t <= t_max`` in no
    box of the tube active at their time."""
    count, worst = 0, 0.0
    for k, tk in enumerate(t):
        if tk > t_max + 1e-12:
            break
        sel = (tube.t_start <= tk + 1e-12) & (tk - 1e-12 <= tube.t_end)
        x = X[:, k, :]
        x = x[np.all(np.isfinite(x), axis=1)]
        if x.shape[0] == 0:
            continue
        if not sel.any():
            count += x.shape[0]
            continue
        lo, hi = tube.lower[sel], tube.upper[sel]
        exc = np.maximum(lo[None] - x[:, None], x[:, None] - hi[None]).max(-1).min(-1)
        count += int((exc > tol).sum())
        worst = max(worst, float(exc.max()))
    return count, worst


def _complete_until(problem, result) -> float:
    """The time up to which the tube holds every trajectory, by the verdict's contract."""
    T = float(problem.verify.time_horizon)
    if not np.isfinite(T):
        T = float(result.tube.t_end.max(initial=0.0))
    if result.verdict == "unknown" and result.detail:
        # a partial tube says where it ends ("the tube ends at t = ...", "partial after
        # t = ...", "the tube of that piece ... ends there" after "at t = ...")
        ends = re.findall(r"(?:ends at|partial after) t = ([0-9.eE+-]+)", result.detail)
        if "ends there" in result.detail:
            ends += re.findall(r"at t = ([0-9.eE+-]+)", result.detail)[:1]
        if ends:
            T = min(T, *map(float, ends))
        if "complete_until" in result.stats:
            T = min(T, float(result.stats["complete_until"]))
    return T


@pytest.mark.slow
@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_example_tube_holds_the_simulated_loop(path):
    problem = load_spec(path)
    if problem.verify is None:
        pytest.skip("no [verify] section")
    law = synthesize(problem)
    result = verify(problem, law)
    if result.verdict == "unsafe":
        return
    T = _complete_until(problem, result)
    if T <= 0 or result.tube.num_boxes == 0:
        return
    sim = replace(problem, verify=replace(problem.verify, time_horizon=T))
    lo, hi = theta_initial_box(sim)
    d, n = lo.shape[0], problem.plant.n
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(d)], indexing="ij"))
    rng = np.random.default_rng(11)
    T0 = np.vstack([corners.reshape(d, -1).T, rng.uniform(lo, hi, (80, d))])
    P = T0.shape[0]
    kw: dict = {"hold": result.hold, "t_end": T}
    if d > n:
        kw["extra0"] = T0[:, n:]
    pl = problem.plant
    if pl.disturbances is not None or pl.parameters is not None:
        kw["disturbance"] = _signals(sim, P, seed=5)
    if problem.verify.noisy:
        kw["noise"] = noise_sequences(sim, P, seed=5)
    t, X, _, _ = simulate_many(sim, law, T0[:, :n], **kw)
    count, worst = _outside(result.tube, np.asarray(t), X, T)
    assert count == 0, (f"{count} simulated states outside the tube before t = {T:g} "
                        f"(worst {worst:g}); {result.summary()}")
