"""The workbench's partition of a law of more than two states is the section recordings and
reports draw (``figures.default_slice_point``: the centre of ``[verify] initial_set``), and its
title says so (issue 40)."""

from __future__ import annotations

import dataclasses

import numpy as np
from pilot_tools import SIZE, run, settle

from codev_engine.view.figures import default_slice_point
from workbench.tui.app import CodevApp
from workbench.tui.state import open_target

#: three states, symmetric bounds (the domain's centre is 0) and an initial set off the
#: origin: the section through the initial set's centre is not the domain's
TRIPLE = """
name = "triple"
[plant]
states = ["p", "v", "a"]
inputs = ["j"]
dynamics = ["v", "a", "j"]
[model]
sample_time = 0.5
[mpc]
horizon = 1
norm = "inf"
Q = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
R = [[0.5]]
x_min = [-5.0, -5.0, -5.0]
x_max = [5.0, 5.0, 5.0]
u_min = [-1.0]
u_max = [1.0]
[verify]
time_horizon = 1.0
initial_set = { lower = [0.1, -0.3, 0.4], upper = [0.3, -0.1, 0.6] }
"""


def test_the_partition_is_the_section_of_recordings_and_reports(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "triple.toml"
    spec.write_text(TRIPLE, encoding="utf-8")
    app = CodevApp(open_target(str(spec), session_dir="s"))

    async def scenario():
        async with app.run_test(size=SIZE) as pilot:
            await settle(pilot, app)
            await pilot.press("f3", "ctrl+g")
            await settle(pilot, app, timeout=120)
            law, problem = app.law, app.check.problem
            assert law is not None and law.n == 3
            pane = app.query_one("SynthesisPane")
            # nothing typed: the point recordings and reports fix (a at 0.5), not the
            # domain's centre (a at 0)
            at = pane._at(law)
            assert np.allclose(at, default_slice_point(law, problem))
            assert np.allclose(at, [0.2, -0.2, 0.5])
            plot = app.query_one("#partition")
            title = plot._draw(60, 12).plain.split("\n")[0]
            assert title.startswith(f"the partition, {law.num_regions} regions")
            assert title.endswith("section at a = 0.5"), title
            # the spec's initial set moves: the section follows it
            vs = dataclasses.replace(problem.verify, initial_lower=np.array([0.1, -0.3, -0.7]),
                                     initial_upper=np.array([0.3, -0.1, -0.5]))
            pane.set_problem(dataclasses.replace(problem, verify=vs))
            assert plot._draw(60, 12).plain.split("\n")[0].endswith("section at a = -0.6")
            # a value typed for the state off the plane wins
            app.query_one("#synth-at").value = "0, 0, 1.5"
            pane.refresh_law(force=True)
            assert plot._draw(60, 12).plain.split("\n")[0].endswith("section at a = 1.5")

    run(scenario())
