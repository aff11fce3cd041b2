"""The double integrator (examples/double_integrator.toml) with other [verify] sections.

Shared by the verification, figure and workbench tests (import as ``tests.di_variants``).
"""

from __future__ import annotations

from pathlib import Path

import codev_engine as ce

DI_PATH = Path(__file__).resolve().parents[1] / "examples" / "double_integrator.toml"

# the nominal (centre) trajectory from (9, -5) with u = 1 passes (-0.375, -2.5) at t = 2.5:
# the box is entered, the verdict is unsafe
UNSAFE_ON_PATH = """
[verify]
time_horizon = 9.0
max_depth = 6
step = 0.01
initial_set = { lower = [8.99, -5.01], upper = [9.01, -4.99] }

[[verify.unsafe]]
lower = [-0.6, -2.7]
upper = [-0.2, -2.3]
"""

# A box that meets the hull of the tube's segment [1.0, 1.01] but no trajectory: at t = 1
# the reach set is the parallelogram {x1 = a + b + 0.5, x2 = b + 1} (a in [8.99, 9.01],
# b in [-5.01, -4.99]), so x1 >= 4.51 forces x2 <= -3.99 + s over [1, 1 + s]; the corner
# (4.52, -3.98) of the segment box is ~0.04 from the reach set: unknown without refinement.
HULL_CORNER = """
[verify]
time_horizon = 3.0
step = 0.01
initial_set = { lower = [8.99, -5.01], upper = [9.01, -4.99] }

[[verify.unsafe]]
lower = [4.51, -3.985]
upper = [4.53, -3.975]
"""


def di_spec(verify_section: str) -> ce.Problem:
    """The double integrator's plant, model and MPC with another [verify] section."""
    text = DI_PATH.read_text()
    return ce.loads_spec(text[: text.index("[verify]")] + verify_section, path="<test>")
