"""The pipeline's front: a spec file read, parsed and checked for the stages that follow.

The stages of codev run in this order::

    spec (parse) -> plant (linearise, discretise) -> mpc (condense) -> mp (solve)
        -> law -> reach (verify) -> view (figures, recordings) / session (cache, replay)

The parser (:mod:`codev_engine.spec.parse`) only validates fields. The two checks that need
a later stage belong to that stage and are run here, after parsing, by :func:`load_spec`:

* :func:`check_model`: a nonlinear plant must be linearisable (finite ``f`` and Jacobians)
  at the operating point -- the model stage's precondition;
* :func:`check_mpc_feasible`: the MPC must be feasible for some state in the state bounds --
  the synthesis stage's precondition (an LP; it loads python-control, so sessions run it only
  when the synthesis is not cached).

Before them, :func:`check_size` refuses work too large to end (docs/spec.md, "Limits"):
it estimates the size of each stage from the fields (states, horizon, samples, tube steps)
before any of it is done, so a typo such as ``step = 1e-12`` is a one-line error naming the
field, not a MemoryError or a run that never ends.

All raise the same ``SpecError`` as a field error would: naming the file and the field.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.spec.parse import parse_spec, read_spec
from codev_engine.spec.problem import Problem

__all__ = [
    "LIMITS",
    "load_spec",
    "loads_spec",
    "check_model",
    "check_mpc_feasible",
    "check_size",
    "program_bytes",
]

#: The documented limits of :func:`check_size` (docs/spec.md, "Limits").
LIMITS = {
    "states": 64,  # n: the plant's states
    "inputs": 64,  # m
    "decisions": 1000,  # control_horizon × m: the MPC's free moves
    "program_bytes": 2**30,  # the condensed program's matrices (float64), full horizon
    "samples": 100_000,  # verify.time_horizon / model.sample_time: controller steps verified
    "tube_steps": 1_000_000,  # verify.time_horizon / verify.step: reachtube time steps
}


def load_spec(path: str | Path, *, check_mpc: bool = True) -> Problem:
    """Read, parse and check a spec TOML file: the problem every stage can run.

    Parameters
    ----------
    path : str or Path
        The spec file.
    check_mpc : bool
        Also check that the MPC is feasible somewhere (an LP on the discretised model, which
        imports python-control). Sessions pass False and check it only when synthesis is not
        cached: a cached law proves it.

    Returns
    -------
    Problem
        The validated problem; ``source`` is the file text and ``path`` is ``str(path)``.

    Raises
    ------
    SpecError
        The first problem found in the file (unreadable file, TOML syntax, unknown or missing
        field, wrong type, shape or value, a plant not linearisable at the operating point,
        an infeasible MPC), naming the file and the dotted field.
    """
    return _checked(read_spec(path), check_mpc=check_mpc)


def loads_spec(text: str, *, path: str = "<string>", check_mpc: bool = True) -> Problem:
    """Parse and check a spec given as TOML text (see :func:`load_spec`).

    Parameters
    ----------
    text : str
        The TOML document.
    path : str, optional
        Name used for ``Problem.path`` and in error messages.
    check_mpc : bool
        See :func:`load_spec`.

    Returns
    -------
    Problem
        The validated problem.

    Raises
    ------
    SpecError
        As :func:`load_spec`.
    """
    return _checked(parse_spec(text, path=path), check_mpc=check_mpc)


def _checked(problem: Problem, *, check_mpc: bool) -> Problem:
    check_size(problem)
    check_model(problem)
    if check_mpc:
        check_mpc_feasible(problem)
    return problem


def check_size(problem: Problem) -> None:
    """Refuse a spec whose work would exceed :data:`LIMITS`, before any of it is done.

    Parameters
    ----------
    problem : Problem
        A parsed problem.

    Raises
    ------
    SpecError
        Naming the field to change: ``plant.states`` / ``plant.inputs`` (too many),
        ``mpc.horizon`` (horizon × m decision variables), ``verify.time_horizon``
        (time_horizon / sample_time controller steps) or ``verify.step`` (time_horizon /
        step reachtube steps).
    """
    file = problem.path or "<string>"
    n, m = problem.plant.n, problem.plant.m

    def refuse(field: str, what: str, value: float, limit: int, fix: str) -> None:
        raise SpecError(
            f"{what} = {value:.3g} exceeds the limit {limit:,}: {fix}", field=field, file=file
        )

    if n > LIMITS["states"]:
        refuse("plant.states", "states", n, LIMITS["states"], "codev handles smaller plants")
    if m > LIMITS["inputs"]:
        refuse("plant.inputs", "inputs", m, LIMITS["inputs"], "codev handles fewer inputs")
    decisions = problem.mpc.Nc * m  # the free moves (move blocking: control_horizon)
    if decisions > LIMITS["decisions"]:
        refuse(
            "mpc.horizon",
            "horizon × inputs (the MPC's decision variables)",
            decisions,
            LIMITS["decisions"],
            "shorten mpc.horizon",
        )
    nbytes = program_bytes(problem)
    if nbytes > LIMITS["program_bytes"]:
        refuse(
            "mpc.horizon",
            "the condensed MPC's matrices (bytes, predictions and constraint rows over the "
            f"{problem.mpc.horizon:,} steps)",
            nbytes,
            LIMITS["program_bytes"],
            "shorten mpc.horizon",
        )
    vs = problem.verify
    if vs is None:
        return
    # time_horizon = "inf": the verifier looks at most max_samples samples far
    horizon = vs.time_horizon
    if not np.isfinite(horizon):
        horizon = vs.max_samples * problem.model.sample_time
    with np.errstate(all="ignore"):
        samples = horizon / problem.model.sample_time
        steps = horizon / vs.step
    if not samples <= LIMITS["samples"]:
        refuse(
            "verify.time_horizon",
            "time_horizon / sample_time (controller steps verified)",
            samples,
            LIMITS["samples"],
            "shorten verify.time_horizon or raise model.sample_time",
        )
    if not steps <= LIMITS["tube_steps"]:
        refuse(
            "verify.step",
            "time_horizon / step (reachtube steps)",
            steps,
            LIMITS["tube_steps"],
            "raise verify.step or shorten verify.time_horizon",
        )


def program_bytes(problem: Problem) -> float:
    """The memory the condensed MPC's largest matrices take, from the fields alone.

    ``mpc.build_program`` forms the predictions ``x_k = Phi_k theta + Gam_k u + d_k`` for
    every step of the **full** horizon N (``Gam_k`` is n × N m before move blocking maps
    it to the Nc m free moves), the dense ``N m × N m`` input weight of norm "2", and a
    constraint matrix with a row per bounded quantity and step and a column per decision
    variable (the free moves, one soft slack per soft row and step, the LP norms' slacks
    per term and step). Counted as float64, an upper estimate within a small factor.

    Parameters
    ----------
    problem : Problem
        A parsed problem.

    Returns
    -------
    float
        Bytes (a float: a typo'd horizon gives astronomic numbers, not an overflow).
    """
    mpc = problem.mpc
    n, m = float(problem.plant.n), float(problem.plant.m)
    N, Nc = float(mpc.horizon), float(mpc.Nc)
    p = float(mpc.C.shape[0]) if mpc.C is not None else 0.0
    mixed = float(sum(np.asarray(c.h).size for c in mpc.constraints))
    q = float(np.asarray(mpc.Q).shape[0]) if mpc.Q is not None else n
    r = float(np.asarray(mpc.R).shape[0]) if mpc.R is not None else m
    per_step = 2 * n + 2 * p + mixed  # bounded rows of one step (states, outputs, mixed)
    soft = per_step * (N + 1) if mpc.soft else 0.0
    if mpc.norm == "2":
        slacks = 0.0
        cost_rows = 0.0
        weight = (N * m) ** 2  # kron(I_N, R)
    else:
        rd = float(np.asarray(mpc.Rd).shape[0]) if mpc.Rd is not None else 0.0
        terms = 2 * N + 1 + (N if rd else 0.0)  # stage, terminal and rate terms
        slacks = N * (q + r + rd) + q if mpc.norm == "1" else terms
        cost_rows = 2 * (N * (q + r + rd) + q)  # |M v| <= t: two rows per row of M
        weight = 0.0
    decisions = Nc * m + soft + slacks
    rows = 2 * Nc * m * (2 if mpc.du_min is not None else 1) + per_step * N + 2 * soft + cost_rows
    predictions = (N + 1) * n * (N + Nc) * m  # Gam over the full horizon, then blocked
    return 8.0 * (predictions + weight + rows * decisions)


def check_model(problem: Problem) -> None:
    """Check that a nonlinear plant is linearisable at the operating point.

    Parameters
    ----------
    problem : Problem
        A parsed problem. Plants given by matrices, and explicit discrete models, pass.

    Raises
    ------
    SpecError
        ``field="model.operating_point"`` when ``f(x_op, u_op)`` or a Jacobian there has
        non-finite entries; the error names the spec's file.
    """
    plant, model = problem.plant, problem.model
    if plant.dynamics is None or model.A is not None:
        return
    from codev_engine.plant import linearize

    file = problem.path or "<string>"
    try:
        with np.errstate(all="ignore"):
            Ac, Bc, f0 = linearize(plant, model.x_op, model.u_op)
    except SpecError as exc:  # the dynamics undefined at the nominal parameters
        raise (exc.with_file(file) if exc.file is None else exc) from None
    for label, arr in (
        ("f(x_op, u_op)", f0),
        ("the state Jacobian", Ac),
        ("the input Jacobian", Bc),
    ):
        if not np.all(np.isfinite(arr)):
            raise SpecError(
                f"the dynamics cannot be linearised at the operating point: {label} has "
                "non-finite entries",
                field="model.operating_point",
                file=file,
            )


def check_mpc_feasible(problem: Problem) -> None:
    """Check that the MPC is feasible for some initial state in the state bounds.

    Parameters
    ----------
    problem : Problem
        A parsed problem.

    Raises
    ------
    SpecError
        ``field="mpc"`` when the MPC is infeasible for every state; the error names the spec's
        file.
    SolverError
        When the LP solver fails.
    """
    # imported here: python-control and scipy (~1 s) only when the check runs
    from codev_engine.mpc import check_feasible

    try:
        check_feasible(problem)
    except SpecError as exc:
        file = problem.path or "<string>"
        raise (exc.with_file(file) if exc.file is None else exc) from None
