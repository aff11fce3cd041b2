"""Explicit MPC synthesis: spec -> discrete model -> condensed mp-LP/QP -> ExplicitLaw."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.executor import Executor
from codev_engine.formulation import parameter_names
from codev_engine.kernel_cache import prepare
from codev_engine.law import ExplicitLaw, fingerprint_arrays
from codev_engine.law_shard_writer import ShardWriter, update_meta
from codev_engine.law_shards import ShardedLaw
from codev_engine.limits import check_time, limits, stage_deadline
from codev_engine.mp.merge import merge_equal_laws
from codev_engine.mp.program import MpProgram
from codev_engine.mp.solution import ShardedSolution, TooManyRegionsError
from codev_engine.mp.solve import MpSolution, SolveOptions, mpsolve
from codev_engine.mpc import MpcProgram, build_program
from codev_engine.plant import LinearModel, discretize
from codev_engine.spec.problem import Problem

__all__ = [
    "synthesize", "law_from_solution", "problem_fingerprint", "region_limit", "weight_spread",
    "WEIGHT_SPREAD_LIMIT",
]

#: the largest ratio between the cost's weights (:func:`weight_spread`) that is solved:
#: past it the smaller weights' share of the cost is below what the solvers resolve next
#: to the larger ones (rounding of the largest terms, the mp-LP's tie tolerance of 1e-9
#: of the largest cost), and the law would be the larger weights' alone, or, as with the
#: CSTR's Q times 1e12 (R = 0.1), a partition with holes
WEIGHT_SPREAD_LIMIT = 1e12

#: above this spread a failure of the solver names the weights as a likely cause
_SPREAD_NOTED = 1e6

#: a move within this much (relative to ``1 + |bound|``) of an input bound over the whole
#: parameter box is the bound (:func:`snap_saturated`), and this times the weights' spread
#: past 1e3: the law's rounding grows with the KKT system's conditioning
SATURATION_TOL = 1e-12


def weight_spread(spec) -> tuple[float, str]:
    """How far apart in magnitude the cost's weights are.

    Each non-zero row of ``Q``, ``R``, ``P``, ``Rd`` counts with its largest entry (a row
    is one term's scale in norms 1 / inf, and one state's or input's in norm 2), and
    ``soft_weight`` when a constraint is soft. Scaling every weight by one factor leaves
    the spread, and the law, as they are.

    Parameters
    ----------
    spec : MpcSpec
        The design.

    Returns
    -------
    spread : float
        The largest of those scales over the smallest (1 with fewer than two).
    detail : str
        Which fields hold the largest and the smallest, for messages.
    """
    scales: list[tuple[float, str]] = []
    for name in ("Q", "R", "P", "Rd"):
        M = getattr(spec, name, None)
        if M is None or isinstance(M, str):
            continue
        M = np.atleast_2d(np.asarray(M, dtype=float))
        rows = np.max(np.abs(M), axis=1, initial=0.0)
        scales += [(float(v), f"mpc.{name}") for v in rows[rows > 0.0]]
    if spec.soft:
        scales.append((float(spec.soft_weight), "mpc.soft_weight"))
    if len(scales) < 2:
        return 1.0, ""
    big, small = max(scales), min(scales)
    detail = f"largest |{big[1]}| entry {big[0]:.3g}, smallest |{small[1]}| {small[0]:.3g}"
    return big[0] / small[0], detail

def region_limit(program: MpProgram) -> tuple[int, int]:
    """How many critical regions of ``program`` fit in the ``region_bytes`` limit.

    The limit (``codev_engine.limits``; 4 GiB unless ``CODEV_LIMITS`` sets it) is the memory
    the critical regions of one synthesis may take: :func:`synthesize` stops the search past
    this many regions (or the solver's own ``SolveOptions.max_regions``, whichever is
    fewer) with a one-line message naming the fields to change, never a MemoryError.

    A region holds at most every constraint row and the parameter set's rows (``d + 1``
    numbers each) and its optimiser's affine law (``nz × (d + 1)``), in float64; the peak of
    the search holds about twice that (the regions found and their packed copy).

    Parameters
    ----------
    program : MpProgram
        The condensed multi-parametric program.

    Returns
    -------
    regions : int
        The largest number of regions allowed.
    bytes_per_region : int
        The estimate it rests on.
    """
    rows = program.A.shape[0] + program.A_theta.shape[0]
    per = 2 * 8 * (rows + program.nz) * (program.d + 1)
    return max(1, limits()["region_bytes"] // per), per


def problem_fingerprint(mp: MpcProgram) -> str:
    """Hash of everything the explicit law depends on: the condensed program and op point.

    Parameters
    ----------
    mp : MpcProgram
        The condensed MPC (from :func:`codev_engine.mpc.build_program`).

    Returns
    -------
    str
        16 hex digits over the program's arrays (``H``, ``c``, ``C``, ``A``, ``b``, ``F``,
        ``A_theta``, ``b_theta``), ``x_op``, ``u_op`` and the norm; stored as
        ``ExplicitLaw.fingerprint``, so that a law file made for another problem is refused.
    """
    p = mp.program
    return fingerprint_arrays(
        p.H, p.c, p.C, p.A, p.b, p.F, p.A_theta, p.b_theta, mp.x_op, mp.u_op, mp.spec.norm
    )


def law_from_solution(mp: MpcProgram, sol: MpSolution, *, simplify: bool) -> ExplicitLaw:
    """Turn the parametric solution into the state-feedback law in plant coordinates.

    With ``dtheta = theta - theta_op`` and ``u = u_op + z[u0] = u_op + K_u dtheta + k_u``:
    ``F = K_u``, ``G = u_op + k_u - K_u theta_op``; region rows ``A dtheta <= b`` become
    ``A theta <= b + A theta_op``, and so do the domain's rows (``theta = x``,
    ``theta_op = x_op`` unless the law takes the previous input or a reference).

    Parameters
    ----------
    mp : MpcProgram
        The condensed MPC that ``sol`` solves.
    sol : MpSolution
        The solution of ``mp.program``: critical regions in theta with the optimiser
        ``z = K theta + k`` of each.
    simplify : bool
        Merge the regions whose laws ``(F_i, G_i)`` are equal up to round-off (relative
        1e-9) while their union stays convex.

    Returns
    -------
    ExplicitLaw
        ``A``, ``b`` (k regions), ``F`` (k, m, n), ``G`` (k, m), the domain, the fingerprint
        (:func:`problem_fingerprint`) and ``meta`` (norm, horizon, region counts before and
        after merging, solve seconds, solver stats). ``states`` and ``inputs`` are empty:
        the caller names them (:func:`synthesize` does).
    """
    sl = mp.u0_slice
    op = mp.theta_op
    As = [r.A for r in sol.regions]
    bs = [r.b + r.A @ op for r in sol.regions]
    F = np.array([r.K[sl] for r in sol.regions]).reshape(len(As), mp.m, mp.d)
    G = np.array([mp.u_op + r.k[sl] - r.K[sl] @ op for r in sol.regions]).reshape(
        len(As), mp.m
    )
    fm = mp.formulation
    if fm is not None and As:
        F, G, _ = snap_saturated(F, G, mp.spec, fm.theta_lo + op, fm.theta_hi + op)
    merged = len(As)
    if simplify and As:
        As, bs, F, G = merge_equal_laws(As, bs, F, G)
        merged = len(As)
    return ExplicitLaw(
        domain_A=sol.domain_A,
        domain_b=sol.domain_b + sol.domain_A @ op,
        A=As,
        b=bs,
        F=F,
        G=G,
        states=(),
        inputs=(),
        fingerprint=problem_fingerprint(mp),
        meta={
            "norm": mp.spec.norm,
            "horizon": mp.N,
            "regions_before_merge": sol.num_regions,
            "regions": merged,
            "solve_seconds": round(sol.seconds, 6),
            "stats": sol.stats,
        },
    )


def snap_saturated(
    F: np.ndarray, G: np.ndarray, spec, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Make a saturated move exactly its input bound.

    Where an input bound is active the exact law is ``F_ij = 0``, ``G_ij = bound``; the
    law's derivation (the KKT system, conditioned like the weights' spread) leaves it off
    by rounding: with a spread of 1e10 a region's move reached ``u_max + 6e-7`` and
    ``u_min - 2.1e-6`` (``F_ij`` 4e-10, ``G_ij`` 1.4e-7 off). A move whose range over the
    whole parameter box lies within ``SATURATION_TOL (1 + |bound|)`` of a bound (times the
    spread past 1e3) is set to it: a change within the law's rounding, toward the exact
    law (the MPC's inputs are hard-bounded, so its move is never past the bound).

    Parameters
    ----------
    F : (k, m, d) ndarray
    G : (k, m) ndarray
        The regions' laws ``u = F theta + G`` (plant coordinates).
    spec : MpcSpec
        Its ``u_min``, ``u_max`` and weights.
    lo, hi : (d,) ndarray
        The parameter box (plant coordinates); nothing is snapped along an infinite one.

    Returns
    -------
    F, G : ndarray
        Copies, snapped.
    snapped : int
        How many (region, input) moves were set to a bound.
    """
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        return F, G, 0
    F, G = np.array(F, dtype=float), np.array(G, dtype=float)
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    mid = F @ centre + G  # (k, m): the move at the box's centre
    reach = np.abs(F) @ half  # its largest change over the box
    tol = SATURATION_TOL * max(1.0, weight_spread(spec)[0] / 1e3)
    snapped = 0
    for bound in (np.asarray(spec.u_min, float), np.asarray(spec.u_max, float)):
        near = (np.isfinite(bound)[None, :]
                & (np.abs(mid - bound) + reach <= tol * (1.0 + np.abs(bound))))
        i, j = np.nonzero(near)
        F[i, j, :] = 0.0
        G[i, j] = bound[j]
        snapped += i.size
    return F, G, snapped


def synthesize(
    problem: Problem,
    *,
    model: LinearModel | None = None,
    simplify: bool | None = None,
    options: SolveOptions | None = None,
    progress: Callable[[int], None] | None = None,
    executor: Executor | None = None,
    sharded: bool = False,
    shard_dir: str | os.PathLike | None = None,
    out_shards: str | os.PathLike | None = None,
) -> ExplicitLaw | ShardedLaw:
    """Compute the explicit MPC law of a problem.

    Parameters
    ----------
    problem : Problem
        From ``load_spec``.
    model : LinearModel, optional
        A discrete model to use instead of discretising ``problem``.
    simplify : bool, optional
        Merge regions sharing a law; default ``problem.mpc.simplify``.
    options : SolveOptions, optional
        Settings of the multi-parametric solver; its defaults when omitted.
    progress : callable, optional
        Called with the number of regions found so far.
    executor : Executor, optional
        Where the mp-QP search evaluates its candidates (``mpsolve``); the law is the same.
    sharded, shard_dir
        With a Dask ``executor``: the mp-QP search sharded across its workers, its files in
        ``shard_dir`` (``mpsolve``; docs/scale.md); the same law.
    out_shards : path-like, optional
        With ``sharded``: the law's folder of shards, each written by the worker that
        found its regions (``law_shard_writer.ShardWriter``; every worker must reach the
        folder); the law returned is read from it, lazily.

    Returns
    -------
    ExplicitLaw or ShardedLaw
        In plant coordinates; ``law.meta['seconds']`` is the total wall time. A
        ``ShardedLaw`` with ``sharded`` and ``out_shards``.

    Raises
    ------
    SpecError
        When the problem cannot be condensed or solved as given (the plant is not
        linearisable at the operating point, weights of the wrong shape, an empty or
        unbounded parameter set).
    SolverError
        When the multi-parametric solver gives up: numerical trouble, or more regions than
        ``options.max_regions`` or than fit in the ``region_bytes`` limit (see
        :func:`region_limit`; the message names the fields to change), or the cost's
        weights span more than ``WEIGHT_SPREAD_LIMIT`` (:func:`weight_spread`; a failure
        with weights spanning more than 1e6 names them too).
    """
    prepare()  # a fresh installation's kernels, announced, outside the law's seconds
    with stage_deadline():
        return _synthesize(problem, model, simplify, options, progress, executor,
                           {"sharded": sharded, "shard_dir": shard_dir},
                           out_shards if sharded else None)


def _shard_writer(problem: Problem, mp: MpcProgram, simplify: bool, folder) -> ShardWriter:
    """What the sharded search's workers write the law's shards with: the law of
    :func:`law_from_solution`, named as :func:`_synthesize` names it."""
    states, inputs = tuple(problem.plant.states), tuple(problem.plant.inputs)
    sl = mp.u0_slice
    return ShardWriter(
        directory=str(folder), op=np.asarray(mp.theta_op, float),
        rows=(int(sl.start or 0), int(sl.stop)), u_op=np.asarray(mp.u_op, float),
        simplify=bool(simplify), fingerprint=problem_fingerprint(mp), states=states,
        inputs=inputs,
        parameters=parameter_names(problem.mpc, states, inputs) if mp.d > mp.n else (),
        meta={"norm": mp.spec.norm, "horizon": mp.N, "problem": problem.name},
    )


_TIME_FIX = "shorten mpc.horizon or bound fewer states and inputs in [mpc]"
#: what a message about a law too large to enumerate suggests, when it applies
REACHED_HINT = ("a verification can run on the critical regions its reach sets meet alone, "
                "computed on demand: [synthesis] regions = \"reached\" (codev verify/run "
                "--regions reached)")


def _walked_on_demand(mp: MpcProgram) -> bool:
    """The regions of this MPC can be computed on demand: an mp-QP (``mp.on_demand``) or
    an mp-LP (norms 1 and inf, ``mp.on_demand_lp``)."""
    return mp.spec.norm in ("1", "2", "inf")


def _synthesize(problem, model, simplify, options, progress, executor, how=None,
                out_shards=None) -> ExplicitLaw | ShardedLaw:
    t0 = time.perf_counter()
    spread, which = weight_spread(problem.mpc)
    if spread > WEIGHT_SPREAD_LIMIT:
        raise SolverError(
            f"the cost's weights span {spread:.1e} ({which}), more than the "
            f"{WEIGHT_SPREAD_LIMIT:.0e} the solver resolves in double precision: bring them "
            "closer (the law does not change when every weight is scaled by one factor)"
        )
    model = model if model is not None else discretize(problem)
    mp = build_program(problem.mpc, model)
    check_time("synthesis", _TIME_FIX)

    def checked(count: int, **extra) -> None:  # the deadline, at each region found
        check_time("synthesis", _TIME_FIX)
        if progress is not None:
            progress(count, **extra)

    options = options if options is not None else SolveOptions()
    most, per = region_limit(mp.program)
    capped = most < options.max_regions
    if capped:
        options = replace(options, max_regions=most)
    simplify = problem.mpc.simplify if simplify is None else simplify
    writer = None if out_shards is None else _shard_writer(problem, mp, simplify, out_shards)
    try:
        sol = mpsolve(mp.program, options=options, progress=checked, executor=executor,
                      shard_writer=writer, **(how or {}))
    except TooManyRegionsError:
        raise SolverError(
            f"synthesis stopped past {options.max_regions:,} critical regions "
            + (f"(about {per / 1024:.0f} KB each, {most * per / 2**20:,.0f} MB in all)"
               if capped else "(the solver's safety stop)")
            + ": the explicit law is too large; shorten mpc.horizon, bound fewer states or "
            "inputs in [mpc], or use fewer states"
            + (f"; {REACHED_HINT}" if _walked_on_demand(mp) else "")
        ) from None
    except SolverError as exc:
        if spread <= _SPREAD_NOTED:
            raise
        raise SolverError(
            f"{exc}; the cost's weights span {spread:.1e} ({which}): weights closer in "
            "magnitude may solve"
        ) from exc
    if isinstance(sol, ShardedSolution):  # (the workers wrote the law's shards)
        return update_meta(out_shards, {
            "regions": sol.num_regions, "solve_seconds": round(sol.seconds, 6),
            "seconds": round(time.perf_counter() - t0, 6)})
    law = law_from_solution(mp, sol, simplify=simplify)
    law.states = tuple(problem.plant.states)
    law.inputs = tuple(problem.plant.inputs)
    if mp.d > mp.n:
        law.parameters = parameter_names(problem.mpc, law.states, law.inputs)
    law.meta["problem"] = problem.name
    law.meta["seconds"] = round(time.perf_counter() - t0, 6)
    return law
