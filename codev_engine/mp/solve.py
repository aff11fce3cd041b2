"""Exact multi-parametric LP/QP solver, the front door of both.

``mpsolve`` reduces the program (``reduce.py``: equalities eliminated, pure-parameter rows
moved to the parameter set, rows normalised and de-duplicated) and measures its parameter
set (when its axes are far apart in size, the search runs in balanced units and the law is
mapped back: ``balance.py``), then hands it on:

- **mp-QPs** (H != 0 after the reduction; positive definite, or semi-definite with a
  lexicographic selection of the optimizer, refused when the constraints leave a direction
  of recession) go to the active-set graph search of ``mpqp.py``, from a point inside
  the feasible set;
- **mp-LPs** go to the search on the graph of optimal bases of ``mplp_graph.py`` when
  the cost does not depend on the parameter, else (or when that search cannot be made
  exact) to the geometric exploration of ``mplp.py``.

Then, for both, the **domain**: an H-representation of the feasible parameter set from the
regions' rows (its facets are the regions' facets on its boundary), and the laws are mapped
back to the original variables. See ``docs/algorithm.md`` for the algorithms.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from codev_engine.errors import CodevError, SolverError
from codev_engine.executor import Executor
from codev_engine.geometry.polytope import certified_minimal_rows, rows_in, solve_lp, unique_rows
from codev_engine.mp.balance import BalancedWriter, balanced, parameter_scaling, unbalanced
from codev_engine.mp.coverage import check_coverage, feasibility_rows
from codev_engine.mp.mplp import COUNTERS, explore_facets
from codev_engine.mp.mplp_graph import explore_bases
from codev_engine.mp.mpqp import explore_active_sets
from codev_engine.mp.program import MpProgram
from codev_engine.mp.reduce import Reduced, lifted, parameter_box, reduce_program, start_point
from codev_engine.mp.solution import CriticalRegion, MpSolution, RegionArrays, ShardedSolution

__all__ = ["CriticalRegion", "MpSolution", "ShardedSolution", "mpsolve", "SolveOptions"]


@dataclass(frozen=True)
class SolveOptions:
    """Numerical options of ``mpsolve`` (lengths are relative to the parameter-set size).

    Attributes
    ----------
    region_tol : float
        A region or facet piece whose inscribed ball is smaller than this is treated as
        lower-dimensional.
    step : float
        Distance stepped across a facet to find the neighbour.
    lp_perturbation : float
        Relative size of the generic cost perturbation that makes mp-LP optimizers unique.
    seed : int
        Seed of that perturbation and of point jitter (results are reproducible).
    max_regions : int
        Safety stop (a million regions of the CDC-24 set take about 2.5 GB at the peak of
        the solve; pop_mpqp_002 has 320,636, pop_mpqp_095 5,008,776).
    workers : int or None
        Threads of this process that evaluate mp-QP candidates once the search is large
        (None: the CPUs this process may use; 1: serial), when ``mpsolve`` is given no
        executor. The result does not depend on it.
    mplp : str
        The mp-LP algorithm: ``"auto"`` (the basis graph of ``mplp_graph.py`` when the
        cost does not depend on the parameter, else, or when it cannot be made exact, the
        geometric explorer of ``mplp.py``), ``"bases"`` (the graph only: a
        ``SolverError`` when it cannot be made exact) or ``"facets"`` (the explorer
        only). The laws do not depend on it.
    coverage_samples : int
        Points well inside the feasible parameter set that must each lie in a region once
        the search is done (``coverage.check_coverage``; a ``SolverError`` otherwise, never
        a law with a hole or no region for a feasible program); 0 checks only that a
        solution without regions belongs to a program without a feasible ball.
    """

    region_tol: float = 1e-9
    step: float = 1e-6
    lp_perturbation: float = 1e-5
    seed: int = 0
    max_regions: int = 1_000_000
    workers: int | None = None
    mplp: str = "auto"
    coverage_samples: int = 8


def mpsolve(
    program: MpProgram,
    *,
    options: SolveOptions | None = None,
    progress: Callable[[int], None] | None = None,
    executor: Executor | None = None,
    sharded: bool = False,
    shard_dir: str | os.PathLike | None = None,
    shard_writer=None,
) -> MpSolution | ShardedSolution:
    """Solve an mp-LP / mp-QP exactly.

    Parameters
    ----------
    program : MpProgram
    options : SolveOptions, optional
    progress : callable, optional
        Called with the number of regions found so far each time one is added.
    executor : Executor, optional
        Evaluate the mp-QP search's candidates as tasks on this executor's workers (a Dask
        cluster) instead of threads of this process; the regions are the same, in the same
        order (see ``mpqp.explore_active_sets``). The mp-LP search does not use it.
    sharded : bool
        With a Dask ``executor``: the mp-QP search's state sharded across its workers, the
        regions kept there until the end (``mp/sharded.py``, docs/scale.md); the same
        regions and laws, sorted by active set.
    shard_dir : path-like, optional
        With ``sharded``: the folder in which the search's shard files go (a fresh folder
        in it, removed at the end; default the system's temporary folder). Every worker
        must reach it: on a remote cluster, a shared file system.
    shard_writer : law_shard_writer.ShardWriter, optional
        With ``sharded``: each worker writes its shard's law (``shard_writer.write``, on
        the worker, with the shard's regions: equal laws merged within the shard, the
        feasible set's facets among its rows found there too and written beside it) and
        this process only collects the manifest's entries, writes the manifest with the
        parameter set's rows and opens the law (``shard_writer.open``): no region and no
        facet comes back. Without a sharded walk (a small program, or no compiled kernel)
        the regions are here anyway and are written as one shard. In balanced units
        (``balance.py``) the writer is wrapped (``balance.BalancedWriter``): the shards are
        written in the program's units.

    Returns
    -------
    MpSolution or ShardedSolution
        Empty (no regions) when the program is infeasible for every parameter; a
        ``ShardedSolution`` (the law's shards) with ``shard_writer``.
    """
    opts = options or SolveOptions()
    t0 = time.perf_counter()
    red = reduce_program(program)
    semidefinite = bool(np.any(red.H)) and np.min(np.linalg.eigvalsh(red.H)) <= 1e-12 * max(
        1.0, np.max(np.abs(red.H))
    )
    if semidefinite:
        _check_no_recession(red)
    size = parameter_box(red)
    # axes in units far apart: search in balanced units, map the law back (balance.py; a
    # law the workers write as shards is mapped back by them, shard by shard, as written)
    D = parameter_scaling(size.lo, size.hi)
    if D is not None:
        writer = None if shard_writer is None else BalancedWriter(shard_writer, D)
        try:
            sol = mpsolve(balanced(program, D), options=opts, progress=progress,
                          executor=executor, sharded=sharded, shard_dir=shard_dir,
                          shard_writer=writer)
        except SolverError as exc:
            if "theta=" in str(exc):  # (a point named in the search's units, not the caller's)
                scales = np.array2string(D, precision=3)
                exc.args = (f"{exc} [theta in the search's balanced units: theta / {scales}]",
                            *exc.args[1:])
            raise
        if isinstance(sol, ShardedSolution):  # (written in the program's units already)
            sol.program = program
            sol.stats["parameter_axes_scaled"] = int(np.sum(D != 1.0))
        else:
            sol = unbalanced(sol, program, D)
        sol.seconds = time.perf_counter() - t0
        return sol
    region_tol = opts.region_tol * size.scale
    # the mp-LP's counters are in an mp-QP's stats too, at zero (as when one object
    # measured both programs: the reports keep their keys)
    stats = dict.fromkeys(COUNTERS, 0)
    finish = (_ShardFinish(red, size.scale, shard_writer, program.nz)
              if shard_writer is not None and sharded else None)
    with _search_failures(red):
        regions = _explore(
            red, size, region_tol, opts, progress, stats, semidefinite, executor, sharded,
            shard_dir, finish,
        )
        if isinstance(regions, list):  # (the workers wrote the law's shards)
            return _sharded_result(program, red, size, region_tol, opts, regions,
                                   shard_writer, stats, t0, executor.client)
        facets = (_boundary_facets(red, regions, size.scale) if len(regions)
                  else np.zeros((0, red.At.shape[1] + 1)))
        domain = (_domain_rows(red, facets, size.scale, size.box) if len(regions)
                  else _empty_domain(red))
    # back to the original variables: z = Z0 + Z1 theta + Nz w (the same without equalities)
    _to_original(red, regions, program.nz)
    sol = MpSolution(
        program=program,
        regions=regions,
        domain_A=domain[0],
        domain_b=domain[1],
        seconds=0.0,
        stats=stats,
    )
    stats.update(check_coverage(
        feasibility_rows(red.G, red.S, red.w, red.At, red.bt),
        sol.locate,
        sol.num_regions,
        scale=size.scale,
        region_tol=region_tol,
        kind="mp-QP" if np.any(red.H) else "mp-LP",
        seed=opts.seed,
        samples=max(0, int(opts.coverage_samples)),
    ))
    sol.seconds = time.perf_counter() - t0
    _end_cpu(stats)
    if shard_writer is not None:  # (no sharded walk: the regions are here, one shard)
        stats["domain_facets"] = int(facets.shape[0])
        entry = shard_writer.write(regions, 0, facets)
        law = shard_writer.open([entry], red.At, red.bt, {"stats": stats})
        return ShardedSolution(program, law, shard_writer.op, sol.seconds, stats)
    return sol


def _end_cpu(stats: dict) -> None:
    """``end_client_cpu_seconds``: this process's CPU from the end of a sharded walk to the
    solution (the merge, the domain, the coverage check; or, with the workers writing the
    law, waiting for them and the client's end)."""
    end = stats.pop("_walk_end_cpu", None)
    if end is not None:
        stats["end_client_cpu_seconds"] = (time.process_time() - end
                                           + stats.get("merge_cpu_seconds", 0.0))


class _ShardFinish:
    """Worker side, at the end of a sharded search: a shard's regions (reduced variables,
    merged) to its law file. The feasible set's facets among the shard's rows are found
    here (LPs over the lifted set: the expensive half of the domain), the regions mapped
    back to the original variables, and ``writer.write`` saves the shard."""

    def __init__(self, red: Reduced, scale: float, writer, nz: int):
        self.red, self.scale, self.writer, self.nz = red, scale, writer, nz

    def __call__(self, regions: RegionArrays, j: int) -> dict:
        facets = (_boundary_facets(self.red, regions, self.scale) if len(regions)
                  else np.zeros((0, self.red.At.shape[1] + 1)))
        _to_original(self.red, regions, self.nz)
        # (the shard's facets of the domain stay with it: the client never unites them)
        return self.writer.write(regions, j, facets)


def _to_original(red: Reduced, regions: RegionArrays, nz: int) -> None:
    """The laws back in the original variables: ``z = Z0 + Z1 theta + Nz w`` (in place;
    nothing to do without equalities)."""
    if not (np.array_equal(red.Nz, np.eye(nz)) and not red.Z0.any() and not red.Z1.any()):
        regions.K = red.Z1 + np.einsum("ij,rjk->rik", red.Nz, regions.K)
        regions.k = red.Z0 + regions.k @ red.Nz.T


def _sharded_result(program, red, size, region_tol, opts, shards: list, writer, stats: dict,
                    t0: float, client) -> ShardedSolution:
    """The client's end of a search whose workers wrote the law's shards and each its
    facets of the domain: the manifest (the parameter set's rows, each shard's entry) and
    the coverage check on the sharded law. Nothing here grows with the regions or the
    facets (``law_shards.ShardedLaw.domain_rows`` reads the facets of the shards a set
    meets: docs/scale.md)."""
    cpu0 = time.process_time()
    found = sum(k for _, _, k, _ in shards)
    # (a facet of the feasible set split between cells is in each of them)
    stats["domain_facets"] = sum(int(entry["facets"]) for entry, _, _, _ in shards)
    stats["regions_before_merge"] = found
    # each shard's cell of space (its regions' centres are in it), in the law's variables:
    # ``locate`` asks first the shard whose cell holds the point
    # (an open side as null: the manifest stays strict JSON)
    def side(v: np.ndarray) -> list:
        return [float(x) if np.isfinite(x) else None for x in writer.point(v)]

    entries = [dict(entry, cell_lo=side(lo), cell_hi=side(hi))
               for entry, _, _, (lo, hi) in shards]
    # each cell's halo (copies of the other shards' regions whose boxes reach into it):
    # built by the workers from the shard files, so that a box question reads the shards
    # of the cells it meets alone (law_halo); back here, each halo file's manifest fields
    if len(entries) > 1:
        entries, cpu = writer.halo(client, entries)
        stats["halo_worker_cpu_seconds"] = cpu
        stats["worker_cpu_seconds"] = stats.get("worker_cpu_seconds", 0.0) + cpu
        stats["halo_regions"] = sum(int(e["halo"]) for e in entries)
        stats["halo_bytes"] = sum(int(e["halo_bytes"]) for e in entries)
    # every parameter-set row is a row of the domain (it holds on all of it): kept, none
    # dropped by an LP here (the facets that would imply one are on the workers)
    law = writer.open(entries, red.At, red.bt, {"stats": stats, "regions_before_merge": found})
    offsets = law.offsets

    def locate(X: np.ndarray) -> np.ndarray:
        # each shard's worker locates the points in its own file: the client reads none
        X = writer.point(np.atleast_2d(X))
        found = client.gather([client.submit(writer.locate, j, X, pure=False)
                               for j in range(law.shards)])
        out = np.full(X.shape[0], -1, dtype=np.int64)
        for j, idx in enumerate(found):
            hit = (out < 0) & (idx >= 0)
            out[hit] = idx[hit] + offsets[j]
        return out

    from codev_engine.mp import sharded

    # (a benchmark's prefix, sharded.STOP_AT, covers a part of the parameter set: its
    # centre too, which the check always tries)
    if sharded.STOP_AT is None:
        stats.update(check_coverage(
            feasibility_rows(red.G, red.S, red.w, red.At, red.bt),
            locate,
            law.num_regions,
            scale=size.scale,
            region_tol=region_tol,
            kind="mp-QP",
            seed=opts.seed,
            samples=max(0, int(opts.coverage_samples)),
        ))
    stats["finish_client_cpu_seconds"] = time.process_time() - cpu0
    _end_cpu(stats)
    return ShardedSolution(program, law, writer.op, time.perf_counter() - t0, stats)


#: the failures of a search that are breakdowns of its arithmetic or of a library it calls
#: (a time limit or a cancellation raised through a progress callback is none of these)
_BREAKDOWNS = (
    ArithmeticError, np.linalg.LinAlgError, ValueError, IndexError, AssertionError, RuntimeError,
)


@contextmanager
def _search_failures(red: Reduced) -> Iterator[None]:
    """A breakdown inside the search (``_BREAKDOWNS``, not the engine's own errors) becomes a
    ``SolverError`` whose one line says what to change (the CLI prints it, exit 1): it is a
    limit of the solver on this program, not bad input, and never an "internal error"
    (issue 23: a division by zero in the search on a chain of 8 integrators). The original
    exception is chained (``CODEV_DEBUG=1`` shows it)."""
    kind = "mp-QP" if np.any(red.H) else "mp-LP"
    size = f"{red.G.shape[1]} variables, {red.At.shape[1]} parameters, {red.G.shape[0]} rows"
    try:
        yield
    except CodevError:
        raise
    except MemoryError as exc:
        raise SolverError(
            f"the {kind} search ran out of memory ({size}): lower the region limit "
            "(--max-regions, SolveOptions.max_regions) or make the problem smaller (a shorter "
            "horizon, fewer states or constraints)"
        ) from exc
    except _BREAKDOWNS as exc:
        raise SolverError(
            f"the {kind} search broke down ({exc.__class__.__name__}: {exc}) on a program of "
            f"{size}: make it smaller or better conditioned (a shorter horizon, fewer states "
            "or constraints, weights and bounds of similar magnitude), and please report it "
            "with the CODEV_DEBUG=1 output"
        ) from exc


def _explore(
    red, size, region_tol, opts, progress, stats, semidefinite, executor=None, sharded=False,
    shard_dir=None, finish=None,
) -> RegionArrays | list:
    """The critical regions of the reduced program (mp-LP or mp-QP search)."""
    nz, d = red.G.shape[1], red.At.shape[1]
    if not np.any(red.H):
        found = _solve_mplp(red, size, region_tol, opts, progress, stats)
        regions = RegionArrays.from_regions(found, nz, d)
    else:
        # combinatorial adjacency over active sets (mpqp.py)
        q0 = start_point(red, size.scale, region_tol, np.random.default_rng(opts.seed))
        regions = RegionArrays.from_regions([], nz, d)
        if q0 is not None:
            regions = explore_active_sets(
                red.H,
                red.c,
                red.C,
                red.G,
                red.w,
                red.S,
                red.At,
                red.bt,
                q0,
                scale=size.scale,
                region_tol=region_tol,
                theta_box=size.box,
                max_regions=opts.max_regions,
                workers=opts.workers,
                executor=executor,
                sharded=sharded,
                shard_dir=shard_dir,
                finish=finish,
                semidefinite=semidefinite,
                progress=progress,
                stats=stats,
            )
    return regions


def _solve_mplp(
    red: Reduced,
    size,
    region_tol: float,
    opts: SolveOptions,
    progress: Callable[[int], None] | None,
    stats: dict,
) -> list[CriticalRegion]:
    """The mp-LP's regions: the basis graph when it applies and is exact, else the
    geometric explorer (``SolveOptions.mplp``)."""
    if opts.mplp not in ("auto", "bases", "facets"):
        raise ValueError(f"SolveOptions.mplp must be auto, bases or facets, got {opts.mplp!r}")
    if opts.mplp != "facets":
        if np.any(red.C):
            if opts.mplp == "bases":
                raise SolverError("the basis graph needs a cost without the parameter (C = 0)")
        else:
            found = explore_bases(
                red,
                size,
                region_tol=region_tol,
                lp_perturbation=opts.lp_perturbation,
                seed=opts.seed,
                max_regions=opts.max_regions,
                progress=progress,
                stats=stats,
            )
            if found is not None:
                stats["mplp"] = "bases"
                # ascending by basis, as the mp-QP's regions by active set: the order of the
                # regions a set meets does not depend on where the search started, so the
                # walk on demand (mp.on_demand_lp) hands a reach set's children over in the
                # full law's order (the tube under disturbances depends on it)
                return sorted(found, key=lambda reg: reg.active)
            if opts.mplp == "bases":
                raise SolverError(f"the basis graph is not exact here: {stats['graph_fallback']}")
    stats["mplp"] = "facets"
    return explore_facets(
        red,
        size,
        region_tol=region_tol,
        step=opts.step * size.scale,
        lp_perturbation=opts.lp_perturbation,
        seed=opts.seed,
        max_regions=opts.max_regions,
        progress=progress,
        stats=stats,
    )


def _check_no_recession(red: Reduced) -> None:
    """Semi-definite H: refuse a program with a direction of recession ``d != 0``
    (``H d = 0``, ``G d <= 0``) along which the cost does not grow at every parameter:
    along it the optimizer is not unique or the cost is unbounded below. Directions along
    which the cost grows for every theta (``C'd = 0``, ``c'd > 0``: e.g. the penalised
    slacks of soft constraints) are harmless. Without a harmful one the optimizer set is
    bounded and the lexicographic selection of the mp-QP search is well defined."""
    lam, V = np.linalg.eigh(red.H)
    N = V[:, lam <= 1e-9 * max(1.0, float(np.max(np.abs(lam))))]  # null space of H
    k = N.shape[1]
    GN = red.G @ N
    cN = red.c @ N
    CN = red.C.T @ N  # (d, k): C'd for d = N y
    scale = 1e-9 * max(1.0, float(np.max(np.abs(cN), initial=0.0)))
    # the cone's directions with cost not growing for some theta: c'd <= 0, or C'd != 0
    cones = [(np.vstack([GN, cN[None, :]]), np.zeros(GN.shape[0] + 1), None)]
    for i in range(CN.shape[0]):
        if np.any(np.abs(CN[i]) > 1e-12):
            cones.append((GN, np.zeros(GN.shape[0]), CN[i]))
    for Ac, bc, lin in cones:
        for j in range(k if lin is None else 1):
            for sign in (1.0, -1.0):
                if lin is None:
                    f = np.zeros(k)
                    f[j] = -sign
                else:
                    f = -sign * lin
                y, status, _ = solve_lp(f, Ac, bc, lb=-np.ones(k), ub=np.ones(k))
                if status != "optimal" or y is None:
                    continue
                if sign * (y[j] if lin is None else float(lin @ y)) > max(1e-9, scale):
                    _recession()


def _recession() -> None:
    raise SolverError(
        "H is only semi-definite and the constraints leave a direction of "
        "recession in its null space (the optimizer is not unique or the cost "
        "is unbounded along it): bound those variables"
    )


def _empty_domain(red: Reduced) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((0, red.At.shape[1])), np.zeros(0)


#: regions above which the domain's shared facets are paired by a compiled hash table
#: (numba is loaded by then: the compiled kernel starts at mpqp.JIT_AFTER regions)
_COMPILED_DOMAIN_AFTER = 1000

#: up to this many rows the feasible set's rows go through DAQP's minrep (0.4 s for 5,000
#: rows in 7-D, growing about as the square), each row it drops checked by a proof
_MINREP_ROWS = 5000

#: points of the feasible set kept to rule out boundary candidates without an LP
_SEEN = 256

#: DAQP's iterations for a lifted LP of the domain, per variable (at least 300), after
#: which HiGHS answers: on the magnetic pointer with N = 8 (26 variables, 128 rows) DAQP
#: cycled or ran to its default 10,000 on 290 of 420 such LPs (5.7 s; 1.1 s so, the
#: same domain; so are the bundled examples' and the test set's, bit for bit)
_DOMAIN_LP_ITERATIONS = 10


def _domain_from_regions(
    red: Reduced,
    regions: RegionArrays,
    scale: float,
    box: tuple[np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """H-representation of the feasible parameter set from the regions' rows: its facets,
    and possibly rows that only touch it (up to ``_MINREP_ROWS`` rows, every other
    redundant row is dropped).

    A facet between two regions appears in both with opposite signs and is dropped; each
    remaining row is kept when it is valid for the whole feasible set ``D`` (an LP over the
    lifted set ``{(w, theta) : G w - S theta <= w0, At theta <= bt}``). Such a row is a
    facet of its region lying on the boundary of ``D``, so it is a facet of ``D``: no
    redundancy test among them (DAQP's minrep over the ~100k such rows of ``pop_mpqp_051``
    took about 230 of its ~400 s). The parameter set's rows are in every region whether
    they bound it or not (and region rows equal to one are not told apart from it): each
    is kept unless the other rows imply it (an LP).
    """
    facets = _boundary_facets(red, regions, scale)
    return _domain_rows(red, facets, scale, box)


def _boundary_facets(red: Reduced, regions: RegionArrays, scale: float) -> np.ndarray:
    """The regions' own rows that are valid for the whole feasible set (its facets):
    ``(q, d + 1)`` rows ``[a, beta]`` (``_domain_from_regions``' first step).

    Run on a part of the regions (a shard of the sharded search), it gives the facets of
    the feasible set among that part's rows: a facet between two regions of different
    parts is unpaired in each part, but no LP finds it valid (the region across it is in
    the feasible set), so the union of the parts' answers is the whole's.
    """
    # (the rows the regions share are the parameter set's, dealt with in _domain_rows)
    A, b = regions.A, regions.b
    # a facet between two regions appears with both signs: not on the boundary
    if len(regions) > _COMPILED_DOMAIN_AFTER:
        from codev_engine.mp.active_sets import unpaired_rows

        unpaired = unpaired_rows(A, b, 7)
        cand = np.hstack([A[unpaired], b[unpaired, None]])
    else:
        rows = np.hstack([A, b[:, None]])
        cand = rows[unique_rows(rows, 7)]
        cand = cand[~rows_in(cand, -rows, 7)]
    p, d = red.At.shape
    theta_rows = np.hstack([red.At, red.bt[:, None]])
    cand = cand[~rows_in(cand, theta_rows, 7)]
    nw = red.G.shape[1]
    LA, Lb = lifted(red)
    tol = 1e-9 * scale
    # a row is valid if max a'theta over the lifted set is at most its offset; a point of
    # the set found by an earlier LP clearly beyond it (by far more than the tolerance, so
    # that the LP decides every row near the line) says no at once: two thirds of
    # pop_mpqp_051's 250k candidates, which are mostly shared facets whose rounded rows
    # did not pair
    limit = max(300, _DOMAIN_LP_ITERATIONS * LA.shape[1])
    valid = np.zeros(cand.shape[0], dtype=bool)
    seen = np.empty((_SEEN, d))  # optimal points of earlier LPs (a ring)
    nseen = 0
    for s0 in range(0, cand.shape[0], _SEEN):
        chunk = cand[s0 : s0 + _SEEN]
        beyond = np.zeros(chunk.shape[0], dtype=bool)
        if nseen:
            pts = seen[: min(nseen, _SEEN)]
            beyond = np.any(chunk[:, :-1] @ pts.T > chunk[:, -1:] + 1e-6 * scale, axis=1)
        for j in np.flatnonzero(~beyond):
            a, beta = chunk[j, :-1], chunk[j, -1]
            x, st, _ = solve_lp(np.concatenate([np.zeros(nw), -a]), LA, Lb,
                                iter_limit=limit)
            if st == "optimal":
                valid[s0 + j] = a @ x[nw:] <= beta + tol
                seen[nseen % _SEEN] = x[nw:]
                nseen += 1
    return cand[valid].reshape(-1, d + 1)


def _domain_rows(red: Reduced, facets: np.ndarray, scale: float,
                 box: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The domain from its facets (:func:`_boundary_facets`): the parameter set's rows the
    facets do not imply, and the redundant rows dropped (up to ``_MINREP_ROWS``)."""
    p = red.At.shape[0]
    theta_rows = np.hstack([red.At, red.bt[:, None]])
    tol = 1e-9 * scale
    # a parameter-set row goes if the other rows imply it: one at a time, each without
    # the ones dropped before (of two equal rows one stays). The LPs run inside the
    # parameter box grown by its size: the set without row i goes past row i, if at all,
    # next to where it meets row i, which is in the feasible set and so in the box (an
    # unbounded LP made DAQP hand over to HiGHS, ~1 ms each on problems solved in 2 ms)
    lo, hi = box
    grow = max(scale, 1.0)
    needed = np.ones(p, dtype=bool)
    for i in range(p):
        needed[i] = False
        rows = np.vstack([theta_rows[needed], facets])
        x, st, _ = solve_lp(-red.At[i], rows[:, :-1], rows[:, -1], lb=lo - grow, ub=hi + grow)
        needed[i] = st != "optimal" or red.At[i] @ x > red.bt[i] + tol
    allrows = np.vstack([theta_rows[needed], facets])
    if allrows.shape[0] <= _MINREP_ROWS:
        # redundant rows go, each with a proof (a row that only touches the set, through
        # a vertex, say, has no proof with a margin and stays)
        bound = float(max(np.max(np.abs(lo)), np.max(np.abs(hi))))
        allrows = allrows[certified_minimal_rows(allrows[:, :-1], allrows[:, -1], bound)]
    return allrows[:, :-1], allrows[:, -1]

