"""The Hylaa peer of ``benchmarks/paper.py``: the same sampled explicit-MPC closed loop as a
Hylaa hybrid automaton (Hylaa 2.x, LP-star sets, GLPK through swiglpk).

Imported by ``paper.py`` only when ``hylaa`` is importable. Hylaa is only *called* here.

The model (linear/affine plants only, ``codev_engine.reach_linear.affine_plant``):

* variables ``[x (n), (u (m) for zoh), c, a]``: ``c`` is the clock of the sample period
  (``dc/dt = a``), ``a`` the affine constant (``da/dt = 0``, ``a = 1``), as in Hylaa's own
  examples (a clock driven by a constant variable is what Hylaa recognises as a
  time-triggered transition);
* one mode per region ``i`` of the law (all regions by default, or a given subset):

  - hold ``"continuous"``: ``dx/dt = (Ac + Bc F_i) x + (Bc G_i + f0) a``;
  - hold ``"zoh"``: ``dx/dt = Ac x + Bc u + f0 a``, ``du/dt = 0`` (the held input);

* invariant ``c <= Ts - h/2`` **only**. The region's rows ``A_i x <= b_i`` are *not* an invariant:
  in codev's semantics (``docs/verification.md``) the region is chosen at the sample and then
  kept for the whole period even if ``x(t)`` leaves it; an invariant would silently drop those
  trajectories (an under-approximation);
* a transition ``i -> j`` for every pair of modes, guard ``c >= Ts - h/2`` (first row, so
  Hylaa rejects it with one LP between samples; ``h`` the step, see ``build``) and
  ``A_j x <= b_j + 1e-9`` (touching regions get a successor too, as in codev); reset
  ``c := 0`` (and for zoh ``u := F_j x + G_j a``). Hylaa marks these time-triggered
  (single-step semantics);
* the properties as error modes: ``err_unsafe_k`` (guard: the unsafe set), ``err_safe_k``
  (guard: one face of the safe set crossed, ``a_r x >= b_r``), ``err_input`` (``u >= u_max +
  tol`` or ``u <= u_min - tol``, ``tol = 1e-9 (1 + |bound|)`` as in ``codev_engine.simulate``)
  and ``err_undefined`` (at a sample, ``x`` beyond one facet of the law's domain
  ``law.domain_A x <= law.domain_b``, by ``1e-9``);
* initial states: one per region meeting the initial box, ``x`` in box and region, ``c = 0``,
  ``a = 1`` (zoh: ``u = F_j x + G_j``).

Differences of semantics that remain (reported, not hidden):

* Hylaa's default (``APPROX_NONE``) is *simulation-equivalent*: sets are exact at the grid
  times ``k h`` and nothing is claimed between them (codev's tube also covers the times
  between grid points);
* Hylaa's guards are closed (``<=``): touching the boundary of a safe set counts as leaving it
  (codev: only strictly beyond).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import hylaa  # noqa: F401  (import check: this module is only imported when hylaa exists)
import numpy as np
from hylaa import aggstrat, lputil
from hylaa.core import Core
from hylaa.hybrid_automaton import HybridAutomaton
from hylaa.settings import HylaaSettings
from hylaa.stateset import StateSet

from codev_engine.reach.linear import affine_plant

try:  # versions for the report
    from importlib.metadata import version as _version

    HYLAA_VERSION = f"hylaa {_version('hylaa')}, swiglpk {_version('swiglpk')}"
except Exception:  # pragma: no cover
    HYLAA_VERSION = "?"

_TOL = 1e-9


@dataclass
class HylaaOutcome:
    verdict: str  # "safe" (no error mode reachable) / "unsafe" (a concrete error state) / "error"
    reason: str | None  # which error mode: unsafe, safe, input_bounds, undefined
    error_time: float | None
    build_seconds: float
    run_seconds: float  # Core.run wall time (the verdict run)
    setup_seconds: float  # of which Hylaa's setup (time-triggered detection, guard strengthening)
    reach_seconds: float  # of which the reachability loop (Hylaa's run_to_completion timer)
    width: np.ndarray | None  # hull width at the horizon (None if the run stopped early)
    width_seconds: float | None  # wall time of the extra reach-only run, if one was needed
    modes: int
    transitions: int
    init_states: int
    states_at_horizon: int
    note: str = ""
    extra: dict = field(default_factory=dict)


class _Core(Core):
    """Hylaa's Core, recording which error mode was reached first (and when)."""

    errors = None

    def __init__(self, ha, settings):
        super().__init__(ha, settings)
        self.errors = []

    def do_step_pop(self):
        # Hylaa 2.0.2 bug worked around here: when a state takes a time-triggered transition
        # on the very step it reaches the time bound, ``do_step_continuous_post`` ends it
        # with "reached computation time bound" and never clears ``took_tt_transition``; the
        # next state popped off the waiting list then sees the stale flag on its first step
        # and is dropped ("State reached a time-triggered transition"), losing a whole
        # branch. (Seen on the double integrator: one of two branches dropped over the last
        # period, the reach set at the horizon half as wide as the simulations.) A freshly
        # popped state has taken no transition yet, so the flag is cleared here.
        self.took_tt_transition = False
        super().do_step_pop()

    def error_reached(self, state, t, t_lpi):  # noqa: D401 - Hylaa hook
        self.errors.append((t.to_mode.name, list(state.cur_steps_since_start), state.is_concrete))
        super().error_reached(state, t, t_lpi)


def _pad(rows: np.ndarray, dims: int) -> np.ndarray:
    """Rows over x (r, n) -> rows over all variables (r, dims)."""
    rows = np.atleast_2d(np.asarray(rows, float))
    out = np.zeros((rows.shape[0], dims))
    out[:, : rows.shape[1]] = rows
    return out


def _region_meets_box(A, b, lo, hi) -> bool:
    from scipy.optimize import linprog

    res = linprog(
        np.zeros(len(lo)),
        A_ub=A,
        b_ub=b + 1e-9,
        bounds=list(zip(lo, hi, strict=True)),
        method="highs",
    )
    return res.status == 0


def build(problem, law, hold: str = "continuous", regions=None, properties: bool = True):
    """Build ``(ha, init_states, info)`` for Hylaa.

    ``regions``: indices of the law's regions to make modes of (default: all). Any subset
    that contains every region visited at a sample is enough; with a smaller one the model
    silently loses trajectories.
    """
    plant = affine_plant(problem)
    if plant is None:
        raise ValueError("Hylaa peer: the plant is not affine")
    Ac, Bc, f0 = (
        np.asarray(plant.Ac, float),
        np.asarray(plant.Bc, float),
        np.asarray(plant.f0, float),
    )
    n, m = Ac.shape[0], Bc.shape[1]
    zoh = hold == "zoh"
    if hold not in ("zoh", "continuous"):
        raise ValueError(hold)
    nu = m if zoh else 0
    ic, ia = n + nu, n + nu + 1  # clock, affine constant
    dims = n + nu + 2
    Ts = float(problem.model.sample_time)
    vs = problem.verify
    h = float(vs.step)
    # The sample fires at c >= Ts - h/2 and the invariant is c <= Ts - h/2 (not Ts): the
    # sample step is the first grid step past Ts - h/2, i.e. t = k Ts exactly (Ts is a
    # multiple of h), and a set that somehow did not take a sample transition there is
    # cut by the invariant before the next step instead of living on with c > Ts. With the
    # threshold at Ts itself, Hylaa's own relaxation (h / num_steps / 1000, ~1e-7) is below
    # GLPK's accuracy on these LPs: seen on magnetic pointer C (zoh), one branch's clock read
    # just under Ts at t = 1.00, the sample was taken one step late (t = 1.01) and a spurious
    # "undefined" error was reported there.
    c_fire = Ts - 0.5 * h
    if abs(Ts / h - round(Ts / h)) > 1e-9 * (Ts / h):
        raise ValueError(f"Hylaa peer: the sample time {Ts} is not a multiple of the step {h}")
    regions = (
        list(range(law.num_regions)) if regions is None else sorted(set(int(r) for r in regions))
    )

    ha = HybridAutomaton("codev_closed_loop")
    modes = {}
    inv_mat = np.zeros((1, dims))
    inv_mat[0, ic] = 1.0
    for i in regions:
        mode = ha.new_mode(f"r{i}")
        a_mat = np.zeros((dims, dims))
        if zoh:
            a_mat[:n, :n] = Ac
            a_mat[:n, n : n + m] = Bc
            a_mat[:n, ia] = f0
        else:
            a_mat[:n, :n] = Ac + Bc @ law.F[i]
            a_mat[:n, ia] = Bc @ law.G[i] + f0
        a_mat[ic, ia] = 1.0
        mode.set_dynamics(a_mat)
        mode.set_invariant(inv_mat, [c_fire])
        modes[i] = mode

    # the sample: c >= Ts - h/2 and x in region j  ->  mode j, c := 0 (zoh: u := F_j x + G_j a)
    clock_row = np.zeros((1, dims))
    clock_row[0, ic] = -1.0
    n_trans = 0
    for i in regions:
        for j in regions:
            t = ha.new_transition(modes[i], modes[j], f"sample->{j}")
            g = np.vstack([clock_row, _pad(law.A[j], dims)])
            rhs = np.concatenate([[-c_fire], np.asarray(law.b[j], float) + _TOL])
            t.set_guard(g, rhs)
            reset = np.identity(dims)
            reset[ic, :] = 0.0
            if zoh:
                reset[n : n + m, :] = 0.0
                reset[n : n + m, :n] = law.F[j]
                reset[n : n + m, ia] = law.G[j]
            t.set_reset(reset)
            n_trans += 1

    err_count = 0
    if properties and vs is not None:
        # unsafe sets (closed): guard = the set
        for k, s in enumerate(vs.unsafe):
            A, b = (np.asarray(a, float) for a in s.halfspaces())
            keep = np.isfinite(b)
            err = ha.new_mode(f"err_unsafe_{k}")
            for i in regions:
                t = ha.new_transition(modes[i], err, f"unsafe{k}")
                t.set_guard(_pad(A[keep], dims), b[keep])
                err_count += 1
        # safe sets: leaving one face (closed guard: touching counts)
        for k, s in enumerate(vs.safe):
            A, b = (np.asarray(a, float) for a in s.halfspaces())
            err = ha.new_mode(f"err_safe_{k}")
            for r in range(A.shape[0]):
                if not np.isfinite(b[r]):
                    continue
                for i in regions:
                    t = ha.new_transition(modes[i], err, f"safe{k}_row{r}")
                    t.set_guard(_pad(-A[r : r + 1], dims), [-b[r]])
                    err_count += 1
        # input bounds, u(t) in force
        if vs.input_bounds:
            err = ha.new_mode("err_input")
            lo = np.asarray(problem.mpc.u_min, float)
            hi = np.asarray(problem.mpc.u_max, float)
            for i in regions:
                for q in range(m):
                    for sign, bound in ((1.0, hi[q]), (-1.0, lo[q])):
                        if not np.isfinite(bound):
                            continue
                        tol = _TOL * (1.0 + abs(bound))
                        # sign * u >= sign * bound + tol   <=>   -sign * u <= -sign * bound - tol
                        row = np.zeros((1, dims))
                        if zoh:
                            row[0, n + q] = -sign
                            rhs = -sign * bound - tol
                        else:
                            row[0, :n] = -sign * law.F[i][q]
                            rhs = -sign * bound - tol + sign * law.G[i][q]
                        if not np.any(row) and rhs < 0:
                            continue  # a constant input within its bounds: never an error
                        t = ha.new_transition(modes[i], err, f"input{q}{'+' if sign > 0 else '-'}")
                        t.set_guard(row, [rhs])
                        err_count += 1
        # undefined at a sample: x beyond a facet of the law's domain
        if law.domain_A is not None:
            err = ha.new_mode("err_undefined")
            DA, Db = np.asarray(law.domain_A, float), np.asarray(law.domain_b, float)
            for i in regions:
                for r in range(DA.shape[0]):
                    g = np.vstack([clock_row, _pad(-DA[r : r + 1], dims)])
                    rhs = np.array([-c_fire, -Db[r] - _TOL * (1.0 + abs(Db[r]))])
                    t = ha.new_transition(modes[i], err, f"undefined_row{r}")
                    t.set_guard(g, rhs)
                    err_count += 1

    # initial states
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    init = []
    for j in regions:
        if not _region_meets_box(np.asarray(law.A[j], float), np.asarray(law.b[j], float), lo, hi):
            continue
        rows, rhs = [], []
        for q in range(n):
            e = np.zeros(dims)
            e[q] = 1.0
            rows += [e, -e]
            rhs += [hi[q], -lo[q]]
        for arow, bval in zip(_pad(law.A[j], dims), np.asarray(law.b[j], float), strict=True):
            rows.append(arow)
            rhs.append(bval + 1e-9)
        for var, val in ((ic, 0.0), (ia, 1.0)):
            e = np.zeros(dims)
            e[var] = 1.0
            rows += [e, -e]
            rhs += [val, -val]
        if zoh:
            for q in range(m):
                e = np.zeros(dims)
                e[n + q] = 1.0
                e[:n] = -law.F[j][q]
                e[ia] = -law.G[j][q]
                rows += [e, -e]
                rhs += [0.0, 0.0]
        mode = modes[j]
        init.append(StateSet(lputil.from_constraints(np.array(rows), np.array(rhs), mode), mode))
    info = {
        "dims": dims,
        "n": n,
        "modes": len(regions),
        "transitions": n_trans,
        "error_transitions": err_count,
        "init_states": len(init),
        "regions": regions,
    }
    return ha, init, info


def make_settings(problem, *, stop_on_error: bool = True, approx: str = "none", quiet=True):
    vs = problem.verify
    h = float(vs.step)
    settings = HylaaSettings(h, float(vs.time_horizon))
    # HylaaSettings uses ceil(T / h), which floating point can push one step too far
    # (1.1 / 0.01 = 110.00000000000001 -> 111): use the nearest integer.
    settings.num_steps = int(round(float(vs.time_horizon) / h))
    settings.stdout = HylaaSettings.STDOUT_NONE if quiet else HylaaSettings.STDOUT_NORMAL
    settings.aggstrat = aggstrat.Unaggregated()  # exact: no aggregation of successors
    settings.process_urgent_guards = True  # check the error guards at the start of a period too
    settings.stop_on_concrete_error = stop_on_error
    settings.make_counterexample = False
    settings.approx_model = {
        "none": HylaaSettings.APPROX_NONE,
        "chull": HylaaSettings.APPROX_CHULL,
        "lgg": HylaaSettings.APPROX_LGG,
    }[approx]
    return settings


def _states(core) -> list:
    out, seen = [], set()
    stack = list(core.aggdag.roots)
    while stack:
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        out.append(node.stateset)
        for op in node.op_list:
            child = getattr(op, "child_node", None)
            if child is not None:
                stack.append(child)
    return out


def _hull_at_horizon(core, n: int, num_steps: int):
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    count = 0
    for st in _states(core):
        if st.mode.a_csr is None or st.cur_steps_since_start[0] != num_steps:
            continue
        count += 1
        lpi = st.lpi
        dims = st.mode.a_csr.shape[0]
        for q in range(n):
            d = np.zeros(dims)
            d[q] = 1.0
            col = lpi.cur_vars_offset + q
            vmin = lpi.minimize(direction_vec=d, columns=[col])[0]
            vmax = lpi.minimize(direction_vec=-d, columns=[col])[0]
            lo[q] = min(lo[q], vmin)
            hi[q] = max(hi[q], vmax)
    return (hi - lo if count else None), count


def _timer(result, name: str) -> float:
    top = getattr(result, "top_level_timer", None)
    if top is None:
        return float("nan")
    found = top.get_children_recursive(name)
    return float(sum(t.total_secs for t in found)) if found else float("nan")


def regions_from_tube(problem, law, vres) -> list[int]:
    """Regions that can be visited at a sample, from codev's (sound) tube: every region
    whose bounding box meets a tube box active at a sample time ``k Ts <= T``.

    A superset of the regions any trajectory is in at a sample, *as long as the tube is
    complete* (verdict not ``unsafe``: an unsafe tube stops at the counterexample).
    """
    tube = vres.tube
    Ts = float(problem.model.sample_time)
    T = float(problem.verify.time_horizon)
    blo, bhi = law.boxes
    keep = np.zeros(law.num_regions, dtype=bool)
    k = 0
    while k * Ts <= T + 1e-9 * Ts:
        lo, hi = tube.at(k * Ts)
        for a, b in zip(lo, hi, strict=True):
            keep |= np.all(blo <= b + 1e-9, axis=1) & np.all(bhi >= a - 1e-9, axis=1)
        k += 1
    return [int(i) for i in np.flatnonzero(keep)]


def run(problem, law, hold: str = "continuous", regions=None, approx: str = "none", quiet=True):
    """Build and run the model; a ``HylaaOutcome``."""
    t0 = time.perf_counter()
    ha, init, info = build(problem, law, hold, regions)
    build_s = time.perf_counter() - t0
    n = info["n"]
    settings = make_settings(problem, stop_on_error=True, approx=approx, quiet=quiet)
    core = _Core(ha, settings)
    t0 = time.perf_counter()
    result = core.run(init)
    run_s = time.perf_counter() - t0
    setup_s, reach_s = _timer(result, "setup"), _timer(result, "run_to_completion")
    verdict, reason, et = "safe", None, None
    concrete = [e for e in core.errors if e[2]]
    if result.has_concrete_error and concrete:
        name, steps, _ = concrete[0]
        verdict = "unsafe"
        reason = {"err_input": "input_bounds", "err_undefined": "undefined"}.get(
            name, name.split("_")[1] if name.startswith("err_") else name
        )
        et = steps[0] * settings.step_size
    elif result.has_aggregated_error:
        verdict, reason = "unknown", "aggregated"
    width, at_h = _hull_at_horizon(core, n, settings.num_steps)
    width_s = None
    note = ""
    if verdict == "unsafe":
        # the verdict run stopped at the error: a reach-only run (no error modes) for the width
        ha2, init2, _ = build(problem, law, hold, regions, properties=False)
        settings2 = make_settings(problem, stop_on_error=False, approx=approx, quiet=quiet)
        core2 = _Core(ha2, settings2)
        t1 = time.perf_counter()
        core2.run(init2)
        width_s = time.perf_counter() - t1
        width, at_h = _hull_at_horizon(core2, n, settings2.num_steps)
        note = "width from a second, reach-only run (the verdict run stopped at the error)"
    return HylaaOutcome(
        verdict=verdict,
        reason=reason,
        error_time=et,
        build_seconds=build_s,
        run_seconds=run_s,
        setup_seconds=setup_s,
        reach_seconds=reach_s,
        width=width,
        width_seconds=width_s,
        modes=info["modes"],
        transitions=info["transitions"] + info["error_transitions"],
        init_states=info["init_states"],
        states_at_horizon=at_h,
        note=note,
        extra={"approx": approx, "num_steps": settings.num_steps, "step": settings.step_size},
    )


def _main(argv=None) -> int:
    """Subprocess entry point (``paper.py`` runs Hylaa this way, with a wall-clock limit).

    ``python hylaa_peer.py SPEC LAW.pickle HOLD REGIONS OUT.json [APPROX]`` where LAW.pickle
    is the pickled ``ExplicitLaw`` written by ``paper.py`` (the ``.npz`` law file does not
    carry the domain) and REGIONS is ``all`` or a comma-separated list of region indices.
    """
    import json
    import pickle
    import sys

    import codev_engine as ce

    args = sys.argv[1:] if argv is None else argv
    spec, law_path, hold, regions, out = args[:5]
    approx = args[5] if len(args) > 5 else "none"
    problem = ce.load_spec(spec)
    with open(law_path, "rb") as fh:
        law = pickle.load(fh)
    regs = None if regions == "all" else [int(r) for r in regions.split(",") if r]
    o = run(problem, law, hold, regions=regs, approx=approx)
    row = {k: v for k, v in o.__dict__.items()}
    row["width"] = None if o.width is None else [float(w) for w in o.width]
    row["hylaa_version"] = HYLAA_VERSION
    with open(out, "w") as fh:
        json.dump(row, fh)
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
