"""A saturated move is its input bound exactly (``synthesis.snap_saturated``), whatever the
weights' spread.

With weights 1e10 apart (a soft bound priced 1e4 next to state weights 1e-5, 1e-6: the
double integrator of ``test_scaled_formulations`` with its states in units 10^2.5 and 10^3
smaller) the law's derivation, conditioned like the spread, left saturated regions'
moves off their bound by rounding: up to ``u_max + 6e-7`` and ``u_min - 2.1e-6``, past
verification's input-bound tolerance (``1e-7 (1 + |bound|)``, docs/verification.md) and
in the exported code. Now the law's moves stay within ``[u_min, u_max]`` there, the law
is still the MPC's (``test_scaled_formulations``' oracle), and a move that merely comes
near a bound is not touched.
"""

from __future__ import annotations

import numpy as np

import codev_engine as ce
from codev_engine.deploy.export import export_python
from codev_engine.pipeline import loads_spec
from codev_engine.synthesis import snap_saturated, weight_spread
from tests.engine.test_export import _load_module

SPREAD = """
name = "spread_1e10"
[plant]
states = ["p", "v"]
inputs = ["u"]
A = [[0.0, 0.31622776601683794], [0.0, 0.0]]
B = [[0.0], [1000.0]]
[model]
sample_time = 0.2
[mpc]
horizon = 3
norm = "2"
Q = [[1e-05, 0.0], [0.0, 1e-06]]
R = [[0.5]]
x_min = [-1581.1388300841895, -2000.0]
x_max = [1581.1388300841895, 2000.0]
u_min = [-1.0]
u_max = [1.0]
domain_bound = 1897.3665961010274
soft = ["x_min", "x_max"]
soft_weight = 10000.0
"""


def test_saturated_moves_are_the_bound_at_a_spread_of_1e10(tmp_path):
    problem = loads_spec(SPREAD)
    assert weight_spread(problem.mpc)[0] == 1e10
    law = ce.synthesize(problem)
    lo, hi = law.boxes
    rng = np.random.default_rng(0)
    X = np.concatenate([a + (b - a) * rng.uniform(size=(400, 2)) for a, b in zip(lo, hi,
                                                                                strict=True)])
    U = law.evaluate(X)[:, 0]
    U = U[np.isfinite(U)]
    assert U.max() == 1.0 and U.min() == -1.0  # (reached, never passed: 6e-7 and 2.1e-6 were)
    saturated = np.all(law.F[:, 0, :] == 0.0, axis=1) & (np.abs(law.G[:, 0]) == 1.0)
    assert saturated.sum() >= 2
    # the exported code computes the same moves: within the bounds too
    mod = _load_module(export_python(law, tmp_path / "law.py", method="sequential"))
    got = np.array([mod.evaluate(x)[1][0] for x in X[::40] if law.locate(x[None])[0] >= 0])
    assert got.size > 100 and got.max() <= 1.0 and got.min() >= -1.0


def test_snapping_is_within_the_laws_rounding_and_only_there():
    """Of rows (a saturated move off by rounding, a move that varies, a move near the
    bound by more than rounding) only the first is set to the bound, and at a spread of 1
    the rounding allowed is 1e-12, so the same 1.4e-7 is left as it is."""
    problem = loads_spec(SPREAD)
    F = np.array([[[4e-10, 0.0]], [[1e-3, 0.0]], [[0.0, 0.0]]])
    G = np.array([[1.0 - 1.4e-7], [0.5], [1.0 - 1e-3]])
    lo, hi = np.array([-1581.0, -2000.0]), np.array([1581.0, 2000.0])
    F2, G2, k = snap_saturated(F, G, problem.mpc, lo, hi)
    assert k == 1 and G2[0, 0] == 1.0 and not F2[0].any()
    np.testing.assert_array_equal(F2[1:], F[1:])
    np.testing.assert_array_equal(G2[1:], G[1:])
    plain = loads_spec(SPREAD.replace("Q = [[1e-05, 0.0], [0.0, 1e-06]]", "Q = [[1.0, 0.0], "
                                      "[0.0, 1.0]]").replace("soft_weight = 10000.0",
                                                             "soft_weight = 1.0"))
    assert snap_saturated(F, G, plain.mpc, lo, hi)[2] == 0


def test_a_law_on_demand_snaps_its_saturated_moves_too():
    from codev_engine.law_on_demand import OnDemandLaw

    od = OnDemandLaw(loads_spec(SPREAD))
    lo, hi = np.array([-1500.0, -1900.0]), np.array([1500.0, 1900.0])
    od.regions_meeting(lo, hi)  # (grown over most of the domain)
    X = np.random.default_rng(1).uniform(lo, hi, size=(20000, 2))
    U = od.evaluate(X)[:, 0]
    U = U[np.isfinite(U)]
    assert U.size > 10000 and U.max() == 1.0 and U.min() == -1.0
