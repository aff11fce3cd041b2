"""Verdicts on textbook plants (issue 38): no numerical dead end, complete tubes.

Plants written from published parameters, each checked against dense simulation with the
law's own loop (the rate limit's ``u_prev``): the verdict, and tube completeness (no
simulated state outside a tube whose verdict is not ``unsafe``). Also the geometry's
degenerate pieces and the bounding box corners that are no states.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from codev_engine.errors import SolverError
from codev_engine.geometry import vertices as vx
from codev_engine.geometry.vertices import box_corners, checked_piece, checked_vertices
from codev_engine.pipeline import loads_spec
from codev_engine.reach.linear import LinearReach, _Star, affine_plant
from codev_engine.reach.simulate import simulate_many, theta_initial_box, violations_many
from codev_engine.reach.verification import verify
from codev_engine.synthesis import synthesize

# Aircraft pitch (Messner & Tilbury, CTMS): angle of attack, pitch rate, pitch angle;
# the elevator saturates at |delta| <= 0.1 for most of the first second
PITCH = """
name = "pitch"
[plant]
states = ["alpha", "q", "theta"]
inputs = ["delta"]
A = [[-0.313, 56.7, 0.0], [-0.0139, -0.426, 0.0], [0.0, 56.7, 0.0]]
B = [[0.232], [0.0203], [0.0]]
[model]
sample_time = 0.1
[mpc]
horizon = 3
norm = "2"
Q = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 10.0]]
R = [[1.0]]
x_min = [-1.0, -1.0, -1.0]
x_max = [1.0, 1.0, 1.0]
u_min = [-0.1]
u_max = [0.1]
[verify]
time_horizon = 2.0
hold = "zoh"
step = 0.01
initial_set = { lower = [-0.01, -0.01, 0.18], upper = [0.01, 0.01, 0.2] }
input_bounds = true
[[verify.safe]]
lower = [-1.0, -1.0, -1.0]
upper = [1.0, 1.0, 1.0]
"""

# Cart-pendulum (Messner & Tilbury, CTMS inverted pendulum), a force-rate limit: the law
# takes theta = (x, u_prev), 5 dimensions
CART_PENDULUM = """
name = "cart-pendulum-rate"
[plant]
states = ["x", "v", "phi", "w"]
inputs = ["F"]
A = [[0.0, 1.0, 0.0, 0.0], [0.0, -0.1818, 2.6727, 0.0], [0.0, 0.0, 0.0, 1.0],
     [0.0, -0.4545, 31.1818, 0.0]]
B = [[0.0], [1.8182], [0.0], [4.5455]]
[model]
sample_time = 0.05
[mpc]
horizon = 3
norm = "2"
Q = [[10.0, 0.0, 0.0, 0.0], [0.0, 0.1, 0.0, 0.0], [0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 0.1]]
R = [[0.1]]
x_min = [-1.0, -3.0, -0.5, -5.0]
x_max = [1.0, 3.0, 0.5, 5.0]
u_min = [-5.0]
u_max = [5.0]
du_min = [-2.0]
du_max = [2.0]
P = "lqr"
[verify]
time_horizon = 1.0
hold = "zoh"
step = 0.01
initial_set = { lower = [-0.02, -0.01, 0.04, -0.01], upper = [0.02, 0.01, 0.06, 0.01] }
initial_input = [0.0]
input_bounds = true
[[verify.safe]]
lower = [-1.0, -3.0, -0.5, -5.0]
upper = [1.0, 3.0, 0.5, 5.0]
"""

# The same cart-pendulum tracking a cart position: a free reference r (the law's parameter
# theta = (x, u_prev, r), 6 dimensions), a step to an unknown 0.4..0.42 m
CART_TRACKING = CART_PENDULUM.replace(
    'P = "lqr"\n',
    'P = "lqr"\nC = [[1.0, 0.0, 0.0, 0.0]]\n'
    '[mpc.reference]\nsignal = "y"\nlower = [-0.5]\nupper = [0.5]\n',
).replace(
    "initial_input = [0.0]\n",
    "initial_input = [0.0]\nreference = { lower = [0.4], upper = [0.42] }\n",
).replace(
    "lower = [-0.02, -0.01, 0.04, -0.01], upper = [0.02, 0.01, 0.06, 0.01]",
    "lower = [-0.01, -0.01, -0.01, -0.01], upper = [0.01, 0.01, 0.01, 0.01]",
).replace('name = "cart-pendulum-rate"', 'name = "cart-pendulum-tracking"')

# A ball on a beam with a stiff (cubic) drag: the trajectories settle, but over the reach
# step the Picard iteration of a wide initial box cannot close
STIFF_BEAM = """
name = "ball-beam-stiff"
[plant]
states = ["r", "v"]
inputs = ["theta"]
dynamics = ["v", "-7.0 * sin(theta) - 60.0 * v**3"]
[model]
sample_time = 0.2
[mpc]
horizon = 3
norm = "2"
Q = [[1.0, 0.0], [0.0, 0.1]]
R = [[1.0]]
x_min = [-3.0, -3.0]
x_max = [3.0, 3.0]
u_min = [-0.3]
u_max = [0.3]
[verify]
time_horizon = 1.0
hold = "zoh"
max_depth = 1
step = 0.02
initial_set = { lower = [1.0, 1.0], upper = [1.5, 1.5] }
[[verify.safe]]
lower = [-3.0, -3.0]
upper = [3.0, 3.0]
"""


def _outside(tube, t: np.ndarray, X: np.ndarray, t_max: float, tol: float = 1e-9) -> int:
    """The simulated states (P, K, n) at times t <= t_max in no active box of the tube."""
    count = 0
    for k, tk in enumerate(t):
        if tk > t_max:
            break
        sel = (tube.t_start <= tk + 1e-12) & (tk - 1e-12 <= tube.t_end)
        lo, hi = tube.lower[sel], tube.upper[sel]
        x = X[:, k, :]
        inside = np.any(np.all((x[:, None, :] >= lo[None] - tol)
                               & (x[:, None, :] <= hi[None] + tol), axis=2), axis=1)
        count += int((~inside).sum())
    return count


def _initial(lo: np.ndarray, hi: np.ndarray, P: int, seed: int = 0) -> np.ndarray:
    d = lo.shape[0]
    rng = np.random.default_rng(seed)
    return np.vstack([box_corners(lo, hi), rng.uniform(lo, hi, (P, d))]).reshape(-1, d)


def test_saturating_pitch_with_input_bounds_is_decided_and_its_tube_complete():
    problem = loads_spec(PITCH)
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", None), result.summary()
    assert result.tube.t_end.max() >= problem.verify.time_horizon - 1e-9
    vs = problem.verify
    t, X, U, alive = simulate_many(problem, law, _initial(vs.initial_lower, vs.initial_upper, 60))
    assert np.abs(U).max() >= 0.1 - 1e-9  # the law saturates
    assert _outside(result.tube, t, X, vs.time_horizon) == 0
    assert not violations_many(problem, t, X, U, alive)[0].any()


def test_a_law_past_its_bound_by_rounding_is_checked_per_region_at_once():
    """Saturated regions whose offset exceeds u_max by 1e-10 (the rounding of an mp
    solution): the held input is decided per region, no time refinement (which cannot
    change a held input)."""
    problem = loads_spec(PITCH)
    law = synthesize(problem)
    sat = np.all(np.abs(law.F) < 1e-12, axis=(1, 2))
    assert sat.any()
    G = law.G.copy()
    G[sat] += np.sign(G[sat]) * 1e-10
    object.__setattr__(law, "G", G) if hasattr(law, "__dataclass_fields__") else None
    if not np.array_equal(law.G, G):
        pytest.skip("the law's offsets cannot be replaced in place")
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("robustly_safe", None), result.summary()
    assert result.stats["refinements"] == 0


def test_rate_limited_cart_pendulum_tube_holds_the_law_s_own_loop():
    problem = loads_spec(CART_PENDULUM)
    law = synthesize(problem)
    assert law.n == 5  # theta = (x, u_prev)
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.tube.t_end.max() >= problem.verify.time_horizon - 1e-9
    lo, hi = theta_initial_box(problem)
    T0 = _initial(lo, hi, 60)
    n = problem.plant.n
    t, X, U, alive = simulate_many(problem, law, T0[:, :n], extra0=T0[:, n:])
    assert _outside(result.tube, t, X, problem.verify.time_horizon) == 0
    assert not violations_many(problem, t, X, U, alive)[0].any()


@pytest.mark.slow
def test_rate_limited_cart_pendulum_tracking_a_position_holds_the_law_s_own_loop():
    """theta = (x, u_prev, r): the rate limit binds at the step (|du| = du_max), and the
    tube holds every simulated state of the law's own loop, u_prev and r included."""
    problem = loads_spec(CART_TRACKING)
    law = synthesize(problem)
    assert law.n == 6
    result = verify(problem, law)
    assert result.verdict == "robustly_safe", result.summary()
    assert result.tube.t_end.max() >= problem.verify.time_horizon - 1e-9
    lo, hi = theta_initial_box(problem)
    T0 = _initial(lo, hi, 60)
    n = problem.plant.n
    t, X, U, alive = simulate_many(problem, law, T0[:, :n], extra0=T0[:, n:])
    # the rate limit binds at the step: the first input is u_prev + du_max (u_max is 5)
    assert np.abs(U[:, 0, 0] - T0[:, n]).max() >= 2.0 - 1e-6
    assert _outside(result.tube, t, X, problem.verify.time_horizon) == 0
    assert not violations_many(problem, t, X, U, alive)[0].any()


def test_failed_enclosure_is_named_with_where_the_tube_ends():
    problem = loads_spec(STIFF_BEAM)
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "enclosure"), result.summary()
    assert "a-priori enclosure" in result.detail and "ends there" in result.detail
    assert "t = " in result.detail
    # the simulated loop itself is fine: the enclosure failed, not the design
    vs = problem.verify
    t, X, U, alive = simulate_many(problem, law, _initial(vs.initial_lower, vs.initial_upper, 30))
    assert not violations_many(problem, t, X, U, alive)[0].any()


def test_thin_piece_is_kept_not_dropped_and_enclosed():
    # a sliver 1e-9 thick (a star touching a region on a face, through the 1e-9 slack)
    A = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    b = np.array([1.0, 0.0, 1e-9, 0.0])
    piece = checked_piece(A, b)
    assert piece is not None
    V = piece[2]
    assert V[:, 0].min() <= 0.0 and V[:, 0].max() >= 1.0
    assert V[:, 1].min() <= 0.0 and V[:, 1].max() >= 1e-9
    # an empty one (1e-3 apart) is dropped
    assert checked_piece(A, np.array([1.0, 0.0, -1e-3, 0.0])) is None


def test_bounding_box_lp_failure_on_a_thin_piece_is_no_error(monkeypatch):
    """The box LPs call a thin piece infeasible (issue 38: radius 5.4e-10, SolverError):
    the relaxed rows' box is used instead, and it contains the piece."""
    A = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    b = np.array([1.0, 0.0, 1e-9, 0.0])
    real = vx._box_side

    def flaky(f, A_, b_):
        if np.array_equal(b_, b):
            raise SolverError("the bounding box LP of a polytope is infeasible")
        return real(f, A_, b_)

    monkeypatch.setattr(vx, "vertices", lambda *a, **k: None)
    monkeypatch.setattr(vx, "_box_side", flaky)
    V = checked_vertices(A, b)
    assert V[:, 0].min() <= 0.0 and V[:, 0].max() >= 1.0
    assert V[:, 1].min() <= 0.0 and V[:, 1].max() >= 1e-9


def test_a_bounding_box_corner_is_no_exit_from_the_domain():
    """A star whose points are its polytope's bounding box corners (the enumeration's
    fallback): a domain row that only a corner violates is no exit, not even a possible
    one; a row the polytope itself crosses is an exact exit at a point of the polytope."""
    problem = loads_spec(PITCH)
    law = synthesize(problem)
    eng = LinearReach(problem, law, affine_plant(problem), "zoh", 2)
    d = law.n
    # the simplex a >= -1, sum(a) <= -1 + 0.5 in alpha; its box is [-1, 1.5 - d + ...]
    H = np.vstack([-np.eye(d), np.ones((1, d))])
    h = np.concatenate([np.ones(d), [-d + 0.5]])
    lo, hi = -np.ones(d), -np.ones(d) + 0.5
    star = _Star(np.zeros(d), np.eye(d), H, h, box_corners(lo, hi), np.zeros(d), 0)
    Y = box_corners(lo, hi)
    # the row sum(x) <= -d + 0.5 + 0.2: the corner hi (sum -d + 0.5 d) violates it
    A = np.ones((1, d)) / np.sqrt(d)
    b = np.array([(-d + 0.7) / np.sqrt(d)])
    viol = Y @ A.T - b[None, :]
    assert viol.max() > 0
    assert eng._exit(star, A, b, viol) == (None, None)
    # a row the simplex crosses: an exit at one of its points
    b2 = np.array([(-d + 0.2) / np.sqrt(d)])
    alpha, gap = eng._exit(star, A, b2, Y @ A.T - b2[None, :])
    assert alpha is not None and gap > 0
    assert np.all(H @ alpha <= h + 1e-9)


def test_failed_enclosure_tube_ends_where_the_detail_says():
    """The stiff beam from a start whose first periods close: the enclosure fails later
    (t = 0.1); the detail gives that time, no box lies past it, and every simulated state
    up to it is in the tube (the contract of a partial tube, docs/verification.md)."""
    problem = loads_spec(STIFF_BEAM.replace("lower = [1.0, 1.0], upper = [1.5, 1.5]",
                                            "lower = [2.0, -0.1], upper = [2.5, 0.1]"))
    law = synthesize(problem)
    result = verify(problem, law)
    assert (result.verdict, result.reason) == ("unknown", "enclosure"), result.summary()
    t_fail = float(re.search(r"at t = ([0-9.eE+-]+)", result.detail).group(1))
    assert t_fail > 0 and "ends there" in result.detail
    assert result.tube.num_boxes and result.tube.t_end.max() <= t_fail + 1e-9
    vs = problem.verify
    t, X, U, alive = simulate_many(problem, law, _initial(vs.initial_lower, vs.initial_upper, 60))
    assert _outside(result.tube, t, X, t_fail) == 0
