"""The law of the region of operation (issue 39, Deliver 4): the regions a verified closed
loop reaches, computed on demand, exported as C (compiled by gcc here) and Python, with the
certificate checked at export that every reach set at a sample lies in their union.

- on states of the tube's sample sets the C and the Python code return a region and the
  law on demand's input;
- outside the union of the regions they return -1 and leave u untouched (never
  extrapolate), whatever the full law would do there;
- the header states the region of operation and the verdict;
- a tube that leaves the MPC's feasible set, a full law or a law over more than the state
  are refused in one line naming ``synthesis.regions``.
"""

from __future__ import annotations

import ctypes
import importlib.util
import shutil
import subprocess

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.deploy.export import export_c, export_python
from codev_engine.deploy.operation import operation_law, operation_note
from codev_engine.deploy.plan import plan
from codev_engine.errors import SpecError
from codev_engine.law_on_demand import OnDemandLaw
from codev_engine.pipeline import load_spec, loads_spec
from tests.conftest import EXAMPLES_DIR as EXAMPLES
from tests.engine.test_on_demand import _disturbed_spec

CC = shutil.which("gcc") or shutil.which("cc")
DRIVER = """#include "opc.h"
void opc_batch(int P, const double *X, double *U, int *idx)
{
    int p;
    for (p = 0; p < P; ++p) {
        idx[p] = opc_evaluate(X + p * OPC_NTHETA, U + p * OPC_NU);
    }
}
"""
SENTINEL = 777.0


def _compiled(law, note, tmp, method: str = "auto"):
    h, c = export_c(law, tmp, name="opc", note=note, method=method)
    (tmp / "driver.c").write_text(DRIVER)
    so = tmp / "opc.so"
    run = subprocess.run([CC, "-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-std=c99",
                          "-shared", "-fPIC", "-o", str(so), str(c), str(tmp / "driver.c")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    lib = ctypes.CDLL(str(so))
    nu = law.m if hasattr(law, "m") else law.dep.F.shape[1]  # (a law or a planned export)

    def call(X):
        X = np.ascontiguousarray(X, dtype=np.float64)
        U = np.full((X.shape[0], nu), SENTINEL)
        idx = np.empty(X.shape[0], dtype=np.intc)
        ptr = np.ctypeslib.ndpointer
        lib.opc_batch.argtypes = [ctypes.c_int, ptr(np.float64), ptr(np.float64),
                                  ptr(np.intc)]
        lib.opc_batch(X.shape[0], X, U, idx)
        return idx.astype(int), U

    return h.read_text(), call


def _inside_any(law, X, tol=1e-9) -> np.ndarray:
    return np.array([any(np.max(A @ x - b) <= tol for A, b in zip(law.A, law.b, strict=True))
                     for x in X])


def _check_export(problem, tmp_path, outside_box) -> None:
    od = OnDemandLaw(problem)
    result = ce.verify(problem, od)
    law, cert = operation_law(problem, od, result)
    assert cert["verdict"] == result.verdict and cert["sets"] > 0
    assert law.num_regions == od.num_regions
    note = operation_note(problem, cert)
    header, call = _compiled(law, note, tmp_path)
    assert "REGION OF OPERATION" in header and f"Verdict it rests on: {result.verdict}" in header
    rng = np.random.default_rng(0)
    # states of the tube's sample sets: a region, and the law on demand's input
    tube = result.tube
    k = np.ceil(tube.t_start / problem.model.sample_time - 1e-9)
    hit = k * problem.model.sample_time <= tube.t_end + 1e-12
    lo, hi = tube.lower[hit], tube.upper[hit]
    pick = rng.integers(0, lo.shape[0], 500)
    X = lo[pick] + rng.uniform(size=(500, law.n)) * (hi[pick] - lo[pick])
    idx, U = call(X)
    assert np.all(idx >= 0)
    # (the exported law's regions are the law on demand's, in the full law's order)
    assert np.allclose(U, law.evaluate(X), atol=1e-9)
    assert np.allclose(U[:50], od.evaluate(X[:50]), atol=1e-9)
    # outside the union of the regions: -1 and u untouched
    olo, ohi = outside_box
    Y = olo + rng.uniform(size=(1000, law.n)) * (ohi - olo)
    out = ~_inside_any(law, Y)
    assert out.sum() > 10
    idy, V = call(Y)
    assert np.all(idy[out] == -1) and np.all(V[out] == SENTINEL)
    # the Python module walks the same tables
    path = export_python(law, tmp_path / "opc.py", note=note)
    spec = importlib.util.spec_from_file_location("opc", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert "REGION OF OPERATION" in mod.__doc__
    for x, i in zip(Y[:200], idy[:200], strict=True):
        r, u = mod.evaluate(x)
        assert r == i and (u is None) == (i < 0)


@pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on PATH")
def test_region_of_operation_compiles_and_never_extrapolates(tmp_path):
    problem = load_spec(EXAMPLES / "double_integrator_lqr.toml")
    _check_export(problem, tmp_path, (np.array([-30.0, -10.0]), np.array([30.0, 10.0])))


@pytest.mark.slow
@pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on PATH")
def test_region_of_operation_of_a_chain_is_a_part_of_its_law(tmp_path):
    from tests.engine.test_mpqp_chain import chain_spec

    n = 6
    text = chain_spec(n) + f"""
[verify]
time_horizon = 2.5
initial_set = {{ lower = {[-0.02] * n}, upper = {[0.02] * n} }}
input_bounds = true
"""
    problem = loads_spec(text, check_mpc=False)
    # (around the tube, where the chain's full law has regions the loop never reaches)
    _check_export(problem, tmp_path, (np.full(n, -1.0), np.full(n, 1.0)))


def test_what_is_not_a_region_of_operation_is_refused():
    problem = load_spec(EXAMPLES / "double_integrator_lqr.toml")
    full = ce.synthesize(problem)
    with pytest.raises(SpecError, match="synthesis.regions: .*computed on demand"):
        operation_law(problem, full, None)
    # a tube that leaves the MPC's feasible set (verdict unsafe, reason undefined)
    bad = loads_spec(_disturbed_spec(3), check_mpc=False)
    od = OnDemandLaw(bad)
    result = ce.verify(bad, od)
    assert result.reason == "undefined"
    with pytest.raises(SpecError, match="leaves the MPC's feasible set"):
        operation_law(bad, od, result)
    servo = load_spec(EXAMPLES / "dc_motor_servo.toml")
    with pytest.raises(SpecError, match="over the state alone"):
        operation_law(servo, OnDemandLaw(servo), None)


def test_codev_export_of_a_session_verified_on_demand(tmp_path, capsys):
    from codev_engine.session import RunOptions, Session
    from workbench.cli import main

    spec = tmp_path / "lqr.toml"
    spec.write_text((EXAMPLES / "double_integrator_lqr.toml").read_text()
                    + '\n[synthesis]\nregions = "reached"\n')
    Session.create(tmp_path / "s").run(load_spec(spec), RunOptions(upto="verification"))
    out = tmp_path / "op.py"
    assert main(["export", str(tmp_path / "s"), "--python", str(out)]) == 0
    assert "REGION OF OPERATION" in out.read_text()
    capsys.readouterr()
    # a session of the full law: one line, exit 2
    plain = tmp_path / "plain.toml"
    plain.write_text((EXAMPLES / "double_integrator_lqr.toml").read_text())
    Session.create(tmp_path / "f").run(load_spec(plain), RunOptions(upto="synthesis"))
    assert main(["export", str(tmp_path / "f"), "--python", str(out)]) == 2
    err = capsys.readouterr().err
    assert 'regions = "reached"' in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.skipif(CC is None, reason="no C compiler (gcc or cc) on PATH")
def test_region_of_operation_of_the_quadrotor_agrees_with_the_online_mpc(tmp_path):
    """Issue 39's quadrotor target: 12 states at hover, 4 inputs, N = 10, P = "lqr",
    verified over 5 s on demand; its region of operation exported as C compiles (gcc
    -Werror), and on states of the tube's sample sets the compiled law is the online MPC's
    first input (cvxpy + Clarabel, an independent controller)."""
    from benchmarks.on_demand import quadrotor
    from codev_engine.mpc import OnlineMpc
    from codev_engine.plant import discretize

    problem = quadrotor(10)
    od = OnDemandLaw(problem)
    result = ce.verify(problem, od)
    assert result.verdict == "robustly_safe", result.summary()
    law, cert = operation_law(problem, od, result)
    assert cert["sets"] > 0 and law.num_regions == od.num_regions
    # the default search: the sequential one, by the mean on the tube's sample sets (all
    # in the first region, whose 98 rows it checks first; the tree's path and leaf take
    # 135), the certified worst case stated as ever
    auto = plan(law)
    assert auto.method == "sequential" and auto.expected < 100
    # the tree (its regions of 49-98 rows in 12 dimensions are kept by their boxes, their
    # vertices are not enumerated; ``bst._enlarged_vertices``), exact too
    ex = plan(law, "bst")
    assert ex.tree.num_nodes > 0 and ex.expected > auto.expected
    header, call = _compiled(ex, operation_note(problem, cert), tmp_path)
    assert "REGION OF OPERATION" in header and "binary search tree" in header
    tube = result.tube
    Ts = problem.model.sample_time
    k = np.ceil(tube.t_start / Ts - 1e-9)
    hit = k * Ts <= tube.t_end + 1e-12
    lo, hi = tube.lower[hit], tube.upper[hit]
    rng = np.random.default_rng(0)
    pick = rng.integers(0, lo.shape[0], 120)
    X = lo[pick] + rng.uniform(size=(120, law.n)) * (hi[pick] - lo[pick])
    X = np.vstack([X, lo[pick[:20]], hi[pick[:20]]])  # (and corners of sample boxes)
    idx, U = call(X)
    assert np.all(idx >= 0), "a state of the tube outside the region of operation"
    online = OnlineMpc(problem.mpc, discretize(problem))
    worst = 0.0
    for x, u in zip(X, U, strict=True):
        sol = online.solve(x)
        assert sol.feasible
        worst = max(worst, float(np.max(np.abs(u - sol.u0))))
    assert worst <= 1e-5, f"the exported law and the online MPC differ by {worst:g}"
    # the tree returns the locator's region (the sequential search's) on the tube's states
    # and around them; outside the regions of operation -1, u untouched
    assert np.all(idx == law.locate(X))
    blo, bhi = law.boxes
    Y = np.vstack([blo.min(axis=0) + rng.uniform(size=(1500, law.n))
                   * (bhi.max(axis=0) - blo.min(axis=0)),
                   lo[pick] + rng.uniform(-20.0, 20.0, size=(120, law.n)) * (hi[pick] - lo[pick])])
    idy, V = call(Y)
    assert np.all(idy == law.locate(Y))
    out = ~_inside_any(law, Y)
    assert out.sum() > 100 and (~out).sum() > 10
    assert np.all(idy[out] == -1) and np.all(V[out] == SENTINEL)
