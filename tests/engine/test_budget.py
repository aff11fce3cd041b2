"""A budget that answers (issue 38): ``[verify] time_budget`` / ``--budget``, the heartbeat.

A verification past its budget is ``unknown`` with reason ``budget``, where the proof
stopped and the best margins reached, and its partial tube still holds every simulated
trajectory up to the time it says. Progress reports never stop for long: the engine's
long steps (region cuts of a disturbed set, vertex enumerations, LPs) beat. Also the
nonlinear engine's input check with the linear engine's tolerance, and a paper-machine
headbox with an inf-norm law and a disturbance checked against dense simulation.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from codev_engine import limits
from codev_engine.errors import SpecError
from codev_engine.pipeline import loads_spec
from codev_engine.reach.linear import ClosedLoopSetup
from codev_engine.reach.nonlinear import NonlinearReach
from codev_engine.reach.simulate import simulate_many, violations_many
from codev_engine.reach.verification import VerificationResult, _signals, verify
from codev_engine.synthesis import synthesize
from tests.engine.cli_process import run_codev

# Paper-machine headbox (the MPC Toolbox's "papermach" example, after Ying, Rao & Sun):
# stock and white-water flows Gp, Gw drive the feed tank level H1, the headbox level H2 and
# the consistencies N1, N2; the feed's stock consistency Np is an unmeasured disturbance.
# Time in minutes. An inf-norm law; the disturbed sets cut by its regions make each sample's
# split a long step (seconds): the heartbeat's design.
HEADBOX = """
name = "headbox"
[plant]
states = ["H1", "H2", "N1", "N2"]
inputs = ["Gp", "Gw"]
A = [[-1.93, 0.0, 0.0, 0.0], [0.394, -0.426, 0.0, 0.0], [0.0, 0.0, -0.63, 0.0],
     [0.82, -0.784, 0.413, -0.426]]
B = [[1.274, 1.274], [0.0, 0.0], [1.34, -0.65], [0.0, 0.0]]
E = [[0.0], [0.0], [0.203], [0.0]]
disturbances = { Np = [-0.5, 0.5] }
[model]
sample_time = 2.0
[mpc]
horizon = 2
norm = "inf"
Q = [[0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
R = [[0.1, 0.0], [0.0, 0.1]]
x_min = [-10.0, -10.0, -10.0, -10.0]
x_max = [10.0, 10.0, 10.0, 10.0]
u_min = [-1.0, -1.0]
u_max = [1.0, 1.0]
[verify]
time_horizon = 20.0
hold = "zoh"
step = 0.1
initial_set = { lower = [-0.5, 0.5, -0.5, 0.5], upper = [0.5, 1.5, 0.5, 1.5] }
[[verify.safe]]
lower = [-10.0, -10.0, -10.0, -10.0]
upper = [10.0, 10.0, 10.0, 10.0]
"""

# the headbox over 200 sample periods: its verification takes far longer than the budgets
# below on any machine (about 2 s per 10 periods here), so they always run out
HEADBOX_LONG = HEADBOX.replace("time_horizon = 20.0", "time_horizon = 400.0")

# the bundled pendulum (examples/pendulum.toml) over its saturated first 0.5 s, coarser
PENDULUM_SAT = """
name = "pendulum-sat"
[plant]
states = ["th", "w"]
inputs = ["T"]
dynamics = ["w", "9.81*sin(th) - 0.5*w + T"]
[model]
sample_time = 0.05
[mpc]
horizon = 8
norm = "2"
Q = [[10.0, 0.0], [0.0, 1.0]]
R = [[0.1]]
P = [[228.6, 47.8], [47.8, 14.8]]
x_min = [-1.0, -5.0]
x_max = [1.0, 5.0]
u_min = [-6.0]
u_max = [6.0]
[verify]
time_horizon = 0.5
hold = "zoh"
max_depth = 3
step = 0.01
initial_set = { lower = [0.55, -0.1], upper = [0.6, 0.0] }
input_bounds = true
[[verify.unsafe]]
lower = [0.7, -inf]
upper = [inf, inf]
"""


def _outside(tube, t: np.ndarray, X: np.ndarray, t_max: float, tol: float = 1e-9) -> int:
    """The simulated states (P, K, n) at times t <= t_max in no active box of the tube."""
    count = 0
    for k, tk in enumerate(t):
        if tk > t_max + 1e-12:
            break
        sel = (tube.t_start <= tk + 1e-12) & (tk - 1e-12 <= tube.t_end)
        x = X[:, k, :]
        x = x[np.all(np.isfinite(x), axis=1)]
        lo, hi = tube.lower[sel], tube.upper[sel]
        inside = np.any(np.all((x[:, None, :] >= lo[None] - tol)
                               & (x[:, None, :] <= hi[None] + tol), axis=2), axis=1)
        count += int((~inside).sum())
    return count


def _disturbed_runs(problem, law, P: int = 60, seed: int = 3, t_end: float | None = None):
    """Dense simulations (up to ``t_end``, default the horizon) from the initial box's
    corners and random points, each under its own disturbance signal (held corners,
    bang-bang and random pieces)."""
    vs = problem.verify
    n = problem.plant.n
    lo, hi = vs.initial_lower, vs.initial_upper
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)], indexing="ij"))
    rng = np.random.default_rng(seed)
    X0 = np.vstack([corners.reshape(n, -1).T, rng.uniform(lo, hi, (P, n))])
    piece, W, Q = _signals(problem, X0.shape[0], seed=seed)
    return simulate_many(problem, law, X0, disturbance=(piece, W, Q), t_end=t_end)


# --- the spec field ---------------------------------------------------------------------------


def test_time_budget_is_read_and_bad_values_name_the_field():
    assert loads_spec(HEADBOX, check_mpc=False).verify.time_budget is None
    spec = HEADBOX.replace('hold = "zoh"', 'hold = "zoh"\ntime_budget = 2.5')
    assert loads_spec(spec, check_mpc=False).verify.time_budget == 2.5
    for bad in ("-1", "0", '"soon"', "inf", "true"):
        with pytest.raises(SpecError) as err:
            loads_spec(HEADBOX.replace('hold = "zoh"', f'hold = "zoh"\ntime_budget = {bad}'))
        assert err.value.field == "verify.time_budget"


def test_budget_flag_errors_are_one_line(tmp_path):
    spec = tmp_path / "headbox.toml"
    spec.write_text(HEADBOX)
    bad = run_codev("verify", spec, "--budget", "-2", cwd=tmp_path)
    assert bad.returncode == 2 and "--budget" in bad.stderr
    assert "Traceback" not in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    session = run_codev("run", spec, "--session", tmp_path / "s", "--budget", "5", cwd=tmp_path)
    assert session.returncode == 2 and "time_budget" in session.stderr
    assert not (tmp_path / "s").exists()


# --- the budget's verdict and the heartbeat ------------------------------------------------


def test_budget_ends_in_unknown_with_margins_and_a_partial_tube_that_holds(tmp_path,
                                                                           monkeypatch):
    """The headbox under a budget: unknown / budget, the detail says where the proof stopped
    and how far it got, the margins are in stats, --json and the saved result; the tube holds
    every disturbed trajectory up to the time the detail gives. Progress never paused for
    more than a few heartbeats (each long step beats once a second)."""
    problem = loads_spec(HEADBOX_LONG)
    law = synthesize(problem)
    reports: list[tuple[float, dict]] = []
    # every beat reports (1 s without a report by default): the beats' places are what is
    # tested, and which of them came 0.1 s after a report depended on the machine's speed
    # (on a quiet CI machine the region cuts never did)
    monkeypatch.setattr(limits, "BEAT_EVERY", 0.0)

    def progress(stats: dict) -> None:
        reports.append((time.monotonic(), stats))

    start = time.monotonic()
    result = verify(problem, law, budget=3.0, progress=progress)
    end = time.monotonic()
    assert (result.verdict, result.reason) == ("unknown", "budget"), result.summary()
    assert "time budget of 3 s ran out at t = " in result.detail
    assert "sample period" in result.detail and "% of the horizon" in result.detail
    assert "best margins so far" in result.detail and "safe set 0" in result.detail
    (margin,) = result.stats["margins"]
    assert margin["property"] == "safe set 0" and margin["margin"] > 0
    assert "time budget ran out" in result.summary()
    # the heartbeat: the long steps reported what they were doing, no long silence
    times = [start] + [t for t, _ in reports] + [end]
    assert max(np.diff(times)) < 3.0, max(np.diff(times))
    doing = {s.get("doing") for _, s in reports}
    assert "a disturbed set cut by a region" in doing, doing
    # the partial tube's contract, against the law's own loop under disturbances
    done = result.stats["complete_until"]
    assert f"up to t = {done:.6g}" in result.detail
    assert done > 0 and result.tube.t_end.max() >= done
    t, X, _, _ = _disturbed_runs(problem, law, t_end=done)
    assert _outside(result.tube, t, X, done) == 0
    # the verdict artifact keeps them
    again = VerificationResult.load(result.save(tmp_path / "r.npz"))
    assert again.reason == "budget" and again.stats["margins"] == result.stats["margins"]


def test_cli_budget_answers_with_margins_in_json(tmp_path):
    import json

    spec = tmp_path / "headbox.toml"
    spec.write_text(HEADBOX_LONG.replace('hold = "zoh"', 'hold = "zoh"\ntime_budget = 600'))
    out = run_codev("verify", spec, "--budget", "2", "--json", cwd=tmp_path)
    assert out.returncode == 1, out.stderr
    payload = json.loads(out.stdout)  # the flag overrides the spec's budget
    assert (payload["verdict"], payload["reason"]) == ("unknown", "budget")
    assert "time budget of 2 s" in payload["detail"]
    assert payload["margins"][0]["property"] == "safe set 0"


# --- the nonlinear engine's input check -------------------------------------------------------


def test_nonlinear_input_check_has_the_linear_engine_s_tolerance():
    """A saturating law whose saturated offsets exceed u_max by rounding (1e-11, 1e-10) is
    decided as the exact law is, with the same refinements; past the tolerance (1e-6) it is
    a concrete violation. The bounds each region is checked against are the linear
    engine's (the 1e-7 slack widened by the region's point-location spill)."""
    problem = loads_spec(PENDULUM_SAT)
    law = synthesize(problem)
    sat = np.all(np.abs(law.F) < 1e-12, axis=(1, 2))
    assert sat.any() and np.allclose(np.abs(law.G[sat]), 6.0)
    exact = verify(problem, law)
    assert exact.verdict == "robustly_safe", exact.summary()
    eng = NonlinearReach(problem, law, "zoh", 3)
    for i in range(law.num_regions):
        ours = eng._u_bounds(i)
        linear = ClosedLoopSetup._region_u(eng, i)[2:]
        assert np.array_equal(ours[0], linear[0]) and np.array_equal(ours[1], linear[1])
    for bump, verdict in ((1.3e-11, "robustly_safe"), (1e-10, "robustly_safe"),
                          (1e-6, "unsafe")):
        G = law.G.copy()
        G[sat] += np.sign(G[sat]) * bump
        result = verify(problem, replace(law, G=G))
        assert result.verdict == verdict, (bump, result.summary())
        if verdict == "robustly_safe":
            assert result.stats["refinements"] == exact.stats["refinements"]
            assert result.tube.num_boxes == exact.tube.num_boxes


# --- the headbox, whole ---------------------------------------------------------------------


@pytest.mark.slow
def test_headbox_inf_norm_with_a_disturbance_is_decided_and_its_tube_holds():
    problem = loads_spec(HEADBOX)
    law = synthesize(problem)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.tube.t_end.max() >= problem.verify.time_horizon - 1e-9
    t, X, U, alive = _disturbed_runs(problem, law)
    assert _outside(result.tube, t, X, problem.verify.time_horizon) == 0
    assert not violations_many(problem, t, X, U, alive)[0].any()



def test_nonlinear_budget_says_how_much_of_the_initial_set_it_proved():
    """The nonlinear engine's cells join the tube when proved whole: a budget that stops
    one says the share of the initial set proved (also under time_horizon = "inf", where
    the run looks for an invariant ellipsoid), and the tube is complete up to t = 0 unless
    the cell it stopped in is all that is left (then up to the time that cell reached)."""
    for text in (PENDULUM_SAT, PENDULUM_SAT.replace("time_horizon = 0.5",
                                                    'time_horizon = "inf"')):
        problem = loads_spec(text)
        law = synthesize(problem)
        result = verify(problem, law, budget=0.02)
        assert (result.verdict, result.reason) == ("unknown", "budget"), result.summary()
        assert "% of the initial set proved" in result.detail
        done = result.stats["complete_until"]
        cell = result.stats.get("stopped_cell")
        assert done == 0.0 or (cell is not None and done == cell["t"]
                               and cell["share"] + result.stats["proved_share"] >= 1 - 1e-9)


def _cell_runs(problem, law, cell: dict, t_end: float):
    """Dense simulations from the corners of a stopped cell and 40 random points in it."""
    lo, hi = np.array(cell["lower"]), np.array(cell["upper"])
    n = lo.size
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)], indexing="ij"))
    X0 = np.vstack([corners.reshape(n, -1).T,
                    np.random.default_rng(4).uniform(lo, hi, (40, n))])
    return simulate_many(problem, law, X0, t_end=t_end)


def test_nonlinear_stop_keeps_the_stopped_cell_s_tube(monkeypatch):
    """A nonlinear run stopped inside a cell (here by the branch limit: deterministic)
    keeps that cell's tube so far: it holds every simulated trajectory from the cell up to
    the sample its sets reached (``stats["stopped_cell"]``), and when the cell is the whole
    initial set the tube is complete up to that time."""
    problem = loads_spec(PENDULUM_SAT.replace("time_horizon = 0.5", "time_horizon = 3.0"))
    law = synthesize(problem)
    monkeypatch.setenv("CODEV_LIMITS", "branches=30")
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "limit"), result.summary()
    cell = result.stats["stopped_cell"]
    assert cell["t"] > 0.1 and result.tube.num_boxes > 0
    assert result.tube.t_end.max() >= cell["t"]
    t, X, _, _ = _cell_runs(problem, law, cell, cell["t"])
    assert _outside(result.tube, t, X, cell["t"]) == 0
    if cell["share"] == 1.0:
        assert result.stats["complete_until"] == cell["t"]


def test_nonlinear_budget_reports_the_margins_of_the_tube_so_far():
    """examples/pendulum.toml's loop over 3 s under a budget of 0.5 s: unknown / budget with
    the best margins reached over the stopped cell's tube (none before, the tube was empty),
    and the cell's tube holds its simulated trajectories."""
    problem = loads_spec(PENDULUM_SAT.replace("time_horizon = 0.5", "time_horizon = 3.0"))
    law = synthesize(problem)
    result = verify(problem, law, budget=0.5)
    assert (result.verdict, result.reason) == ("unknown", "budget"), result.summary()
    cell = result.stats.get("stopped_cell")
    if cell is None or result.tube.num_boxes == 0:  # (a loaded machine: no period ended)
        assert "no stretch of the horizon is proved" in result.detail
        return
    assert "the cell in progress" in result.detail
    assert "best margins so far" in result.detail and "unsafe set 0" in result.detail
    (margin,) = result.stats["margins"]
    assert margin["property"] == "unsafe set 0" and margin["margin"] > 0
    t, X, _, _ = _cell_runs(problem, law, cell, max(cell["t"], 0.05))
    assert _outside(result.tube, t, X, cell["t"]) == 0


def test_budget_partial_tube_of_merged_exploration_holds_up_to_its_time():
    """The pitch loop (the linear engine's sample-by-sample merged exploration) stopped by a
    budget: the tube holds every simulated state up to the time the detail gives (the
    sample the frontier had reached, not the end of the period that ran past the budget)."""
    from tests.engine.test_verdicts import PITCH, _initial

    # 20 s of horizon, not the 2 s of test_verdicts (0.36 s of CPU there): the budget runs
    # out on a machine many times faster than this one too
    problem = loads_spec(PITCH.replace("time_horizon = 2.0", "time_horizon = 20.0"))
    law = synthesize(problem)
    result = verify(problem, law, budget=0.1)
    assert (result.verdict, result.reason) == ("unknown", "budget"), result.summary()
    done = result.stats["complete_until"]
    if done == 0:  # (a loaded machine: the budget ran out before the first period)
        assert "no stretch of the horizon is proved" in result.detail
        return
    assert f"up to t = {done:.6g}" in result.detail
    vs = problem.verify
    t, X, _, _ = simulate_many(problem, law, _initial(vs.initial_lower, vs.initial_upper, 60))
    assert _outside(result.tube, t, X, done) == 0



def test_property_margins_are_signed_distances_along_the_sets_rows():
    from codev_engine.reach.margin import property_margins
    from codev_engine.reach.tube import Tube

    spec = HEADBOX.replace(
        "[[verify.safe]]",
        "[[verify.unsafe]]\nlower = [2.0, -inf, -inf, -inf]\nupper = [inf, inf, inf, inf]\n"
        "[[verify.safe]]")
    problem = loads_spec(spec, check_mpc=False)
    lo = np.array([[0.0, 0.0, 0.0, 0.0], [1.0, -9.5, 0.0, 0.0]])
    hi = np.array([[0.5, 1.0, 1.0, 1.0], [2.5, 0.0, 0.0, 0.0]])
    tube = Tube(np.array([0.0, 1.0]), np.array([1.0, 2.0]), lo, hi, np.zeros(2, dtype=int))
    unsafe, safe = property_margins(problem, tube)
    # box 0 keeps 1.5 from x1 >= 2, box 1 reaches 0.5 into it; box 1 is 0.5 from x2 = -10
    assert unsafe == {"property": "unsafe set 0", "margin": -0.5, "t": 1.0}
    assert safe == {"property": "safe set 0", "margin": 0.5, "t": 1.0}
