"""Closed-loop verification: verdicts from sound reachtubes and concrete counterexamples.

Verdicts
--------
``robustly_safe``
    The reachtube is disjoint from every unsafe set, inside every safe set, inside the law's
    domain at every sample, and (with ``input_bounds``) the input stays within its bounds.
``unsafe``
    A concrete simulated trajectory (``counterexample``) violates a property or reaches a
    state where the law is undefined. Every ``unsafe`` is confirmed by an independent
    simulation (scipy ``solve_ivp``, tight tolerances) from the reported initial state.
``unknown``
    With ``reason`` ``"max_depth"`` (refinement budget exhausted while the
    over-approximation still meets a property boundary), ``"over_approximation"`` (a
    merged or disturbed set meets a property, which refining it in time cannot decide, and
    no concrete search found a trajectory that does), ``"infeasible_region"`` (only the
    over-approximation leaves the law's domain) or ``"enclosure"`` (refinement budget
    exhausted on an interval enclosure that meets a singularity: ``detail`` names the
    operation, the expression and the time), or ``"no_invariant"`` (``time_horizon =
    "inf"``: no invariance certificate within ``max_samples``), or ``"limit"`` (the
    exploration grew past ``codev_engine.limits``, branches, reachtube memory or the time
    limit, or the tube's bounds overflowed past 1.8e308: ``detail`` says which and what
    to change), or ``"budget"`` (the verification's time budget, ``[verify] time_budget``
    or ``budget=``, ran out: ``detail`` says where the proof stopped -- time, sample
    period, region -- how much of the horizon and of the initial set it proved, and the
    best margin reached to each property, also in ``stats["margins"]``). A limitation of
    the verifier is a verdict, never an error blamed on the input.

With ``time_horizon = "inf"`` a ``robustly_safe`` verdict has reason ``"invariant"`` and a
``certificate`` (re-checked when loaded): a polytope (affine plants, by LP) or an invariant
ellipsoid around the operating point (nonlinear plants, ``reach.terminal``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from codev_engine.display import Displayable
from codev_engine.errors import RegionLimitError, SolverError, SpecError
from codev_engine.executor import Executor
from codev_engine.io.npz import NpzFormat, array, load_npz, real, save_npz, text
from codev_engine.kernel_cache import prepare
from codev_engine.law import ExplicitLaw
from codev_engine.limits import DeadlineReached, heartbeat, stage_deadline, stoppable, time_over
from codev_engine.limits import budget as time_budget
from codev_engine.reach.tube import Tube
from codev_engine.spec.problem import Problem

__all__ = ["VerificationResult", "Counterexample", "verify", "RESULT_FORMAT", "VERDICTS"]

#: format tag of verification result files; bumped on incompatible changes
RESULT_FORMAT = "codev-verification/1"
_RESULT_FILE = NpzFormat("verification result", RESULT_FORMAT, "result")
VERDICTS = ("robustly_safe", "unsafe", "unknown")
#: What a counterexample does, by kind (``{index}``: which set or input)
VIOLATION_WORDS = {
    "unsafe": "enters unsafe set {index}",
    "safe": "leaves safe set {index}",
    "input_bounds": "input {index} leaves its bounds",
    "undefined": "leaves the law's domain",
}
#: Why a verdict is unknown, in words
UNKNOWN_WORDS = {
    "max_depth": "max_depth reached",
    "over_approximation": "the over-approximation meets a property; no concrete trajectory "
    "found does",
    "infeasible_region": "the reach set leaves the law's domain",
    "law_parameters": "the law also takes the previous input or a reference, which the "
    "reach engines do not track yet",
    "enclosure": "an interval enclosure meets a singularity, or an a-priori enclosure "
    "did not close",
    "no_invariant": "no invariance certificate within max_samples",
    "limit": "the exploration grew past the verifier's limits",
    "budget": "the verification's time budget ran out",
    "invariant": "for all time: an invariance certificate",
    "uncertain": "the reach engines do not follow a nonlinear plant's disturbances or "
    "uncertain parameters yet",
    "noise": "the nonlinear engine does not follow measurement noise here yet "
    "(time_horizon = inf, a law over theta)",
}


def _json_scalar(obj):
    """numpy scalars and arrays in ``stats`` as plain JSON."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    return str(obj)


@dataclass(frozen=True)
class Counterexample:
    """A concrete trajectory that violates the specification.

    Attributes
    ----------
    x0 : (n,) ndarray
        Initial state (inside the initial set).
    t : float
        Time of the violation.
    kind : str
        ``"unsafe"``, ``"safe"``, ``"input_bounds"`` or ``"undefined"``.
    index : int
        Which unsafe/safe set or input (-1 for ``"undefined"``).
    trace : object
        The simulated ``simulate.Trace`` (t, x, u, region).
    extra0 : (d - n,) ndarray
        For a law over ``theta = (x, u_prev, r)``: the initial previous input, then the
        reference (empty for a law in the state alone).
    disturbance : DisturbanceSignal or None
        For a plant with disturbances or uncertain parameters: the signal and the parameter
        values the trajectory was simulated (and confirmed) with.
    """

    x0: np.ndarray
    t: float
    kind: str
    index: int
    trace: object
    extra0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    disturbance: object | None = None

    def describe(self) -> str:
        """The violation in words: ``enters unsafe set 0``, ``input 1 leaves its bounds``."""
        return VIOLATION_WORDS.get(self.kind, self.kind).format(index=self.index)


@dataclass
class VerificationResult(Displayable):
    """Outcome of :func:`verify` (see the module docstring for the verdicts).

    Attributes
    ----------
    verdict : str
        ``"robustly_safe"``, ``"unsafe"`` or ``"unknown"`` (``VERDICTS``).
    reason : str or None
        None when robustly safe (``"invariant"`` for all time); the counterexample's kind
        when unsafe; when unknown, one of ``UNKNOWN_WORDS`` (``"max_depth"``,
        ``"over_approximation"``, ``"infeasible_region"``, ``"enclosure"``, ...).
    tube : Tube
        The reachtube (when unsafe, only its boxes that start by the violation's time).
    hold : {"zoh", "continuous"}
        The hold the closed loop was verified with.
    counterexample : Counterexample or None
        A confirmed violating trajectory (unsafe only).
    stats : dict
        Counters of the run (``branches``, ``refinements``, ``boxes``, ``partitions``,
        ``method``, ``seconds``, ...), for reports.
    detail : str or None
        Why, in words, when the reason needs more than its name (``"enclosure"``: the
        operation, the expression and the time, e.g. ``division by an interval containing
        0 in -8750/T at t = 0.35``).
    certificate : dict or None
        With ``time_horizon = "inf"`` and verdict ``robustly_safe`` (reason
        ``"invariant"``): the invariant set's rows ``H`` (r, n), ``h`` (r,) and the points
        ``points`` (p, n) with their error half-widths ``pads`` (p, n) whose boxes hold
        every state at the closing sample (``stats["certificate"]`` says which samples).
        Re-checked by LP when a saved result is loaded.
    """

    verdict: str
    reason: str | None
    tube: Tube
    hold: str
    counterexample: Counterexample | None = None
    stats: dict = field(default_factory=dict)
    detail: str | None = None
    certificate: dict | None = None

    @property
    def seconds(self) -> float:
        """Wall time of the verification (``stats["seconds"]``, 0 when absent)."""
        return float(self.stats.get("seconds", 0.0))

    def width_at(self, t: float) -> np.ndarray:
        """Width of the hull of the tube's boxes active at ``t``.

        Parameters
        ----------
        t : float

        Returns
        -------
        (n,) ndarray
            NaN when no box is active at ``t``.
        """
        lo, hi = self.tube.hull_at(t)
        return hi - lo

    def save(self, path: str | os.PathLike) -> Path:
        """Write the result (verdict, stats, tube, counterexample trace) to an ``.npz``.

        Atomic and pickle-free (format ``RESULT_FORMAT``); :meth:`load` reads it back.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.
        """
        arrays: dict[str, np.ndarray] = {
            "verdict": np.array(self.verdict),
            "reason": np.array(self.reason or ""),
            "hold": np.array(self.hold),
            "stats": np.array(json.dumps(self.stats, default=_json_scalar)),
            "detail": np.array(self.detail or ""),
            **{
                f"cert_{k}": np.asarray(v, dtype=float)
                for k, v in (self.certificate or {}).items()
            },
            **self.tube.arrays("tube_"),
        }
        ce = self.counterexample
        if ce is not None:
            tr = ce.trace
            undefined = getattr(tr, "undefined_at", None)
            arrays.update(
                cex_x0=np.asarray(ce.x0, dtype=float),
                **({"cex_extra0": np.asarray(ce.extra0, dtype=float)} if ce.extra0.size else {}),
                cex_t=np.array(float(ce.t)),
                cex_kind=np.array(ce.kind),
                cex_index=np.array(int(ce.index)),
                trace_t=tr.t,
                trace_x=tr.x,
                trace_u=tr.u,
                trace_region=np.asarray(tr.region, dtype=np.int64),
                trace_undefined_at=np.array(np.nan if undefined is None else float(undefined)),
            )
            if ce.disturbance is not None:
                arrays.update(
                    cex_w_piece=np.array(float(ce.disturbance.piece)),
                    cex_w_values=np.asarray(ce.disturbance.values, dtype=float),
                    cex_parameters=np.asarray(ce.disturbance.parameters, dtype=float),
                )
                if ce.disturbance.noise is not None:
                    arrays["cex_noise"] = np.asarray(ce.disturbance.noise, dtype=float)
        return save_npz(path, _RESULT_FILE, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> VerificationResult:
        """Read a result written by :meth:`save`.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        VerificationResult

        Raises
        ------
        SpecError
            The file is missing or malformed (naming the file and the array).
        """
        return load_npz(path, _RESULT_FILE, cls._from_arrays)

    @classmethod
    def _from_arrays(cls, data: dict[str, np.ndarray]) -> VerificationResult:
        from codev_engine.reach.simulate import Trace

        verdict = text(data, "verdict")
        if verdict not in VERDICTS:
            raise SpecError(f"unknown verdict {verdict!r}", field="verdict")
        hold = text(data, "hold")
        if hold not in ("zoh", "continuous"):
            raise SpecError(f"unknown hold {hold!r}", field="hold")
        try:
            stats = json.loads(text(data, "stats"))
        except (ValueError, RecursionError):
            raise SpecError("not valid JSON", field="stats") from None
        if not isinstance(stats, dict):
            raise SpecError("must be a JSON object", field="stats")
        tube = Tube.from_arrays(data, "tube_")
        n = tube.lower.shape[1]
        cex = None
        if "cex_x0" in data:
            x0 = real(data, "cex_x0", shape=(n,))
            t = real(data, "trace_t", ndim=1)
            K = t.shape[0]
            x = real(data, "trace_x", ndim=2)
            if x.shape[0] != K or x.shape[1] != n:
                raise SpecError(f"must have shape ({K}, {n}), got {x.shape}", field="trace_x")
            u = array(data, "trace_u")  # NaN at the end of an undefined trajectory
            if u.dtype.kind != "f" or u.ndim != 2 or u.shape[0] != K:
                raise SpecError(f"must be ({K}, m) floats", field="trace_u")
            region = array(data, "trace_region")
            if region.dtype.kind not in "iu" or region.shape != (K,):
                raise SpecError(f"must be {K} integers", field="trace_region")
            undefined = float(array(data, "trace_undefined_at"))
            trace = Trace(
                t=t,
                x=x,
                u=u.astype(float),
                region=region.astype(np.int64),
                x0=x0,
                hold=hold,
                undefined_at=None if np.isnan(undefined) else undefined,
            )
            kind = text(data, "cex_kind")
            extra0 = real(data, "cex_extra0", ndim=1) if "cex_extra0" in data else np.zeros(0)
            signal = None
            if "cex_w_piece" in data:
                from codev_engine.reach.simulate import DisturbanceSignal

                piece = float(real(data, "cex_w_piece", shape=()))
                if not piece > 0:
                    raise SpecError("must be positive", field="cex_w_piece")
                values = real(data, "cex_w_values", ndim=2)
                if values.shape[0] < 1:
                    raise SpecError("must have at least one row", field="cex_w_values")
                noise = None
                if "cex_noise" in data:
                    noise = real(data, "cex_noise", ndim=2)
                    if noise.shape[0] < 1 or noise.shape[1] != n:
                        raise SpecError(f"must be (S, {n}) with S >= 1", field="cex_noise")
                signal = DisturbanceSignal(piece, values, real(data, "cex_parameters", ndim=1),
                                           noise)
            cex = Counterexample(
                x0=x0,
                t=float(real(data, "cex_t", shape=())),
                kind=kind,
                index=int(real(data, "cex_index", shape=())),
                trace=trace,
                extra0=extra0,
                disturbance=signal,
            )
        reason = text(data, "reason") or None
        detail = (text(data, "detail") or None) if "detail" in data else None
        certificate = None
        if "cert_P" in data:
            P = real(data, "cert_P", ndim=2)
            n = P.shape[0]
            certificate = {
                "P": P,
                "centre": real(data, "cert_centre", shape=(n,)),
                "lower": real(data, "cert_lower", ndim=2),
                "upper": real(data, "cert_upper", ndim=2),
            }
            if not check_certificate(certificate):
                raise SpecError(
                    "the invariance certificate does not hold (a box outside the ellipsoid)",
                    field="cert_lower",
                )
        elif "cert_H" in data:
            H = real(data, "cert_H", ndim=2)
            r = H.shape[0]
            certificate = {
                "H": H,
                "h": real(data, "cert_h", shape=(r,)),
                "points": real(data, "cert_points", ndim=2),
                "pads": real(data, "cert_pads", ndim=2),
            }
            if not check_certificate(certificate):
                raise SpecError(
                    "the invariance certificate does not hold (a point outside the set)",
                    field="cert_points",
                )
        return cls(verdict, reason, tube, hold, cex, stats, detail, certificate)

    def summary(self) -> str:
        """The verdict and why, the tube's size and the time; the counterexample, if any."""
        line = f"verdict: {self.verdict}"
        if self.counterexample is not None and self.verdict == "unsafe":
            line += f" ({self.counterexample.describe()})"
        elif self.reason:
            line += f" ({UNKNOWN_WORDS.get(self.reason, self.reason)})"
            if self.detail:
                line += f" [{self.detail}]"
        line += f"; hold {self.hold}; {self.tube.num_boxes} boxes"
        line += f"; {self.stats.get('branches', 0)} branches in {self.seconds:.3f} s"
        if self.counterexample is not None:
            ce = self.counterexample
            line += (
                f"\ncounterexample: x0 = {np.array2string(ce.x0, precision=6)}, "
                f"{ce.kind} at t = {ce.t:.4f}"
            )
        return line


def check_certificate(certificate: dict) -> bool:
    """Re-check an invariance certificate by LP: every point's box lies in ``H x <= h``.

    For each row ``H_r``, the LP ``max sum_i lam_i (H_r p_i + |H_r| pad_i)`` over the
    simplex (the largest value of the row over the convex hull of the widened points) must
    be at most ``h_r``; a polytope that holds those boxes holds their convex hull.

    Parameters
    ----------
    certificate : dict
        ``H`` (r, n), ``h`` (r,), ``points`` (p, n), ``pads`` (p, n), as in
        :attr:`VerificationResult.certificate`.

    Returns
    -------
    bool
        True when the containment holds (False also for inconsistent shapes or values).
    """
    from codev_engine.geometry.polytope import solve_lp

    if "P" in certificate:  # an ellipsoid (reach.terminal): every box's corners inside it
        from codev_engine.reach.terminal import ellipsoid_holds

        P = np.asarray(certificate.get("P"), float)
        c = np.asarray(certificate.get("centre"), float)
        lo = np.asarray(certificate.get("lower"), float)
        hi = np.asarray(certificate.get("upper"), float)
        n = P.shape[0] if P.ndim == 2 else -1
        if (P.ndim != 2 or P.shape != (n, n) or c.shape != (n,) or lo.ndim != 2
                or lo.shape[1:] != (n,) or hi.shape != lo.shape
                or not np.all(np.linalg.eigvalsh(0.5 * (P + P.T)) > 0)):
            return False
        return ellipsoid_holds(P, c, lo, hi)
    H = np.asarray(certificate.get("H"), float)
    h = np.asarray(certificate.get("h"), float)
    P = np.asarray(certificate.get("points"), float)
    pads = np.asarray(certificate.get("pads"), float)
    if (
        H.ndim != 2
        or h.shape != (H.shape[0],)
        or P.ndim != 2
        or P.shape[1] != H.shape[1]
        or pads.shape != P.shape
        or P.shape[0] == 0
        or not all(np.all(np.isfinite(a)) for a in (H, h, P, pads))
        or np.any(pads < 0)
    ):
        return False
    p = P.shape[0]
    vals = P @ H.T + pads @ np.abs(H).T  # (p, r)
    ones = np.ones((1, p))
    for r in range(H.shape[0]):
        lam, st, _ = solve_lp(
            -vals[:, r], np.zeros((0, p)), np.zeros(0), Aeq=ones, beq=np.ones(1), lb=np.zeros(p)
        )
        if st != "optimal":
            return False
        best = float(vals[:, r] @ lam)
        # the LP's own tolerance: the value of the best vertex decides when it is larger
        if max(best, float(vals[:, r].max())) > h[r]:
            return False
    return True


def check_law_matches(problem: Problem, law: ExplicitLaw, *, file: str | None = None) -> None:
    """Refuse a law computed for a different problem (fingerprint mismatch)."""
    from codev_engine.mpc import build_program
    from codev_engine.plant import discretize
    from codev_engine.synthesis import problem_fingerprint

    mp = build_program(problem.mpc, discretize(problem))
    if law.n != mp.d or law.m != problem.plant.m:
        raise SpecError(
            f"the law has n={law.n}, m={law.m} but the spec's law takes theta of length "
            f"{mp.d} and m={problem.plant.m}",
            file=file,
        )
    fp = problem_fingerprint(mp)
    if law.fingerprint and law.fingerprint != fp:
        raise SpecError(
            "the law was computed for a different problem (fingerprint mismatch)", file=file
        )


def verify(
    problem: Problem,
    law: ExplicitLaw,
    *,
    hold: str | None = None,
    max_depth: int | None = None,
    progress: Callable[[dict], None] | None = None,
    executor: Executor | None = None,
    cells: int = 1,
    budget: float | None = None,
) -> VerificationResult:
    """Verify the sampled closed loop of ``problem``'s plant with ``law``.

    Parameters
    ----------
    problem : Problem
        Must have a ``[verify]`` section.
    law : ExplicitLaw
    hold : {"zoh", "continuous"}, optional
        Default ``problem.verify.hold``.
    max_depth : int, optional
        Refinement budget; default ``problem.verify.max_depth``.
    progress : callable, optional
        Called with a dict of counters after each branch period: ``branches``,
        ``samples`` (the sample reached), ``boxes`` (the reachtube's boxes so far), ...
    executor : Executor, optional
        Where the nonlinear engine's cells of the initial set (and their refinements) run:
        as tasks on a Dask cluster, a bounded window in flight, taken in the serial order,
        so the verdict, tube and counterexample are the serial ones. Default: in this
        process. The linear engine (one star set per branch) runs in this process.
    cells : int
        The nonlinear engine cuts the initial set into ``cells`` parts along each axis
        before refining (``cells ** n`` cells: more, smaller tasks for an executor; the
        tube differs, the argument is the same). Default 1; the linear engine ignores it.
    budget : float, optional
        Seconds the verification may take; default ``problem.verify.time_budget`` (None:
        none). Past them the verdict is ``unknown`` with reason ``"budget"`` and a
        ``detail`` saying where the proof stopped and the best margins reached (also
        ``stats["margins"]``). Unlike a time limit (``codev --time-limit``), it is the
        verification's own and always ends in a verdict.

    Returns
    -------
    VerificationResult

    Notes
    -----
    ``progress`` is also called between the engine's reports, with the last counters and
    ``doing`` (what a long step is doing: an LP, a vertex enumeration, an enclosure, a
    simulation), once a second has passed without a report (``limits.heartbeat``).
    """
    if budget is not None and not (np.isfinite(budget) and budget > 0):
        raise SpecError(f"must be a positive number of seconds, got {budget:g}",
                        field="budget")
    if budget is None and problem.verify is not None:
        budget = problem.verify.time_budget
    # CODEV_LIMITS=time=... and the budget: checked at each branch period
    prepare()  # a fresh installation's kernels, announced, before the stage's clocks start
    with stage_deadline(), time_budget(budget), heartbeat(progress) as beating:
        try:
            return _verify(problem, law, hold, max_depth, beating, executor, cells)
        except RegionLimitError as exc:
            # (a law on demand past the region limit outside the reach engines, which end
            # in a "limit" finding with their tube: a search, a certificate's simulation)
            result = VerificationResult("unknown", "limit", Tube.empty(problem.plant.n),
                                        hold or problem.verify.hold, None,
                                        {"branches": 0, "boxes": 0},
                                        f"{exc}; no reachtube is kept (the tube is empty)")
            result.attach_display(problem=problem, law=law)
            return result


def _verify(problem, law, hold, max_depth, progress, executor, cells) -> VerificationResult:
    # the reach engines (scipy, the plant model): imported when a verification runs, not
    # when a cached result is loaded
    from codev_engine.reach.linear import LinearReach, affine_plant

    if problem.verify is None:
        raise SpecError("the spec has no [verify] section", file=problem.path, field="verify")
    vs = problem.verify
    hold = hold or vs.hold
    if hold not in ("zoh", "continuous"):
        raise SpecError(f"unknown hold {hold!r}", field="verify.hold")
    depth = vs.max_depth if max_depth is None else max_depth
    if int(cells) < 1:
        raise SpecError(f"must be a positive number of cells per axis, got {cells}",
                        field="cells")
    t0 = time.perf_counter()
    if vs.noisy and affine_plant(problem) is None and (
        not np.isfinite(vs.time_horizon) or law.n > problem.plant.n
    ):
        # measurement noise on a nonlinear plant: followed by the nonlinear engine over a
        # bounded horizon only -- elsewhere a limitation, so a verdict; a counterexample is
        # still sought under concrete noise sequences (and signals)
        return _limited(problem, law, hold, t0, "noise",
                        "measurement noise on a nonlinear plant is verified over a bounded "
                        "horizon, for a law over the state only")
    if law.n > problem.plant.n and (
        hold != "zoh" or not np.isfinite(vs.time_horizon) or affine_plant(problem) is None
    ):
        # theta = (x, u_prev, r): the closed loop's state is longer than the plant's. The
        # linear engine follows it under zoh over a bounded horizon; elsewhere this is a
        # limitation of the verifier, so a verdict and not an error (and no certificate
        # on x alone, which would be unsound for a law that depends on u_prev)
        stats = {"seconds": time.perf_counter() - t0, "branches": 0, "boxes": 0}
        why = ("the hold is continuous" if hold != "zoh" else "time_horizon is inf"
               if not np.isfinite(vs.time_horizon) else "the plant is not affine")
        result = VerificationResult(
            "unknown", "law_parameters", Tube.empty(problem.plant.n), hold, None, stats,
            f"the law takes theta = (x, u_prev, r) ({law.n} dimensions, the plant's "
            f"{problem.plant.n}), which is followed under zoh over a bounded horizon on an "
            f"affine plant only, and {why}; no reachtube is computed (the tube is empty)")
        result.attach_display(problem=problem, law=law)
        return result
    unbounded = not np.isfinite(vs.time_horizon)
    if unbounded:
        # safety for all time: explore up to max_samples samples for a certificate (and
        # simulate that long for counterexamples)
        bounded = vs.max_samples * float(problem.model.sample_time)
        problem = replace(problem, verify=replace(vs, time_horizon=bounded))
        vs = problem.verify
    plant = affine_plant(problem)
    certificate = None
    searched = False  # the concrete search of an uncertain nonlinear plant ran already
    why = "invariance certificates are computed for affine plants only"
    if unbounded and plant is None:
        # a nonlinear plant: an invariant ellipsoid around the operating point
        # (reach.terminal) entered by the nonlinear engine's bounded tube
        found, why = _ellipsoid_certificate(problem, law, hold, depth, progress, executor,
                                            cells, t0)
        if isinstance(found, VerificationResult):
            return found
    if unbounded and plant is None:
        # no claim, but a counterexample is still looked for
        tube = Tube.empty(problem.plant.n)
        cex = _search(problem, law, hold)
        stats = {"branches": 0, "boxes": 0, "seconds": time.perf_counter() - t0}
        if cex is not None:
            return VerificationResult("unsafe", cex.kind, tube, hold, cex, stats)
        return VerificationResult(
            "unknown",
            "no_invariant",
            tube,
            hold,
            None,
            stats,
            f"no invariance certificate: {why}; no reachtube is kept (the tube is empty)",
        )
    if plant is not None:
        eng = LinearReach(
            problem, law, plant, hold, depth, unbounded=unbounded, progress=progress
        )
        with np.errstate(all="ignore"):  # an overflow is checked on the tube below
            eng.run()
        certificate = eng.certificate
        findings, tubes, stats = eng.findings, eng.tubes, dict(eng.stats)
        c0, V0 = eng.c0, eng.V0
        stats["partitions"] = 1
        stats["method"] = "exact-flow star sets"
    else:
        from codev_engine.reach.parameter_split import split_run

        if _uncertain(problem):
            # refute first: under disturbances, parameters or noise the nonlinear engine's
            # proof can take minutes where a concrete search under extreme and switching
            # signals and the parameter box's corners takes a second; a counterexample it
            # finds is replayed (DOP853) and stands for itself, whatever the proof says
            # (docs/verification.md, "Refuting first")
            cex = _stoppable_search(lambda: _search(problem, law, hold))
            searched = True
            if cex is not None:
                stats = {"seconds": time.perf_counter() - t0, "branches": 0, "boxes": 0,
                         "refuted_first": True}
                result = VerificationResult("unsafe", cex.kind, Tube.empty(problem.plant.n),
                                            hold, cex, stats)
                result.attach_display(problem=problem, law=law)
                return result
        # uncertain parameters: a piece of their box whose proof fails is split (exact: a
        # parameter is constant during a run); without parameters one run, as before
        findings, tubes, stats, c0, V0 = split_run(problem, law, hold, depth, progress,
                                                   executor, cells)
    tube = Tube.concatenate(tubes, problem.plant.n)
    stats["boxes"] = tube.num_boxes
    verdict, reason, cex = "robustly_safe", None, None
    concrete = [f for f in findings if f.alpha is not None]
    for f in concrete:
        with np.errstate(all="ignore"):
            cex = _confirm(problem, law, hold, c0 + V0 @ f.alpha)
        if cex is not None:
            verdict, reason = "unsafe", cex.kind
            break
    detail = None
    if verdict != "unsafe" and findings:
        verdict = "unknown"
        reason, detail = _unknown_reason(findings, concrete, depth)
        if "complete_until" in stats and reason not in ("budget", "limit"):
            # the linear engine's merged run stops at its first undecided finding (under
            # disturbances, or for all time), a parameter split at a concrete finding:
            # past that time the tube is partial
            detail += ("; the exploration stopped there: the tube is partial after "
                       f"t = {stats['complete_until']:.6g}")
        # a possible violation is worth a few concrete simulations (under disturbances,
        # also the adjoint's extreme signals towards the properties at the findings' times)
        # (the searches in turn, the first replayed counterexample ends them; the input
        # rows' search first when the tube's undecided boxes break the input bounds only)
        # (the concrete search ran before the proof when ``searched``: it would find the
        # same nothing again)
        searches = [] if searched else [lambda: _search(problem, law, hold)]
        if plant is not None:
            searches += [lambda: _adjoint_search(problem, law, hold, [f.t for f in findings]),
                         lambda: _input_search(problem, law, hold, tube=tube)]
            if _inputs_only(problem, tube, findings):
                searches = [searches[2], searches[0], searches[1]]
        cex = None
        if time_over() is not None:  # past the time limit: no searches after it
            searches = []
        for search in searches:
            with np.errstate(all="ignore"):  # simulations of a diverging loop
                cex = _stoppable_search(search)
            if cex is not None or time_over() is not None:
                break
        if cex is not None:
            verdict, reason, detail = "unsafe", cex.kind, None
    if verdict == "unknown" and reason == "budget":
        # how far the proof got: where it stopped, the share proved, the best margins
        detail = _budget_answer(problem, tube, stats,
                                next(f for f in findings if f.kind == "budget"))
    if verdict != "unsafe" and not _finite(tube):
        # bounds past 1e308 (huge sets, disturbances or gains): inf and NaN prove nothing
        verdict, reason, certificate = "unknown", "limit", None
        detail = ("the reachtube's bounds overflowed (values past 1.8e308): narrow "
                  "verify.initial_set or plant.disturbances / plant.parameters")
    if unbounded and verdict == "robustly_safe":
        c = stats.get("certificate")
        if c is None or certificate is None or not check_certificate(certificate):
            verdict, reason, certificate = "unknown", "no_invariant", None
            detail = (f"no invariance certificate within max_samples = {vs.max_samples} "
                      "samples; the tube holds every trajectory up to t = "
                      f"{vs.time_horizon:.6g} (those samples), not after")
            cex = _search(problem, law, hold)
            if cex is not None:
                verdict, reason, detail = "unsafe", cex.kind, None
        else:
            reason = "invariant"
            detail = (
                f"every reach set at sample {c['closed_sample']} (t = {c['closed_time']:g}) "
                f"lies in the set anchored at sample {c['anchor_sample']} "
                f"(t = {c['anchor_time']:g}): the tube repeats with period {c['period']:g}"
            )
    if verdict != "robustly_safe":
        certificate = None
    if verdict == "unsafe" and cex is not None and tube.num_boxes:
        # exploration stopped at the counterexample: the tube is partial, keep what
        # precedes it (docs/verification.md)
        keep = tube.t_start <= cex.t
        tube = Tube(
            tube.t_start[keep],
            tube.t_end[keep],
            tube.lower[keep],
            tube.upper[keep],
            tube.branch[keep],
        )
        stats["boxes"] = tube.num_boxes
    stats["seconds"] = time.perf_counter() - t0
    result = VerificationResult(verdict, reason, tube, hold, cex, stats, detail, certificate)
    result.attach_display(problem=problem, law=law)  # state names and sets in the picture
    return result


def _unknown_reason(findings: list, concrete: list, depth: int | None = None
                    ) -> tuple[str, str]:
    """The reason and ``detail`` of an ``unknown`` from the engine's findings.

    The reasons in order: ``limit`` (the run stopped: partial tube), ``enclosure`` (an
    a-priori enclosure failed: that piece's tube ends there), ``infeasible_region`` (the
    over-approximation may leave the law's domain; the tube goes on, or, when a state of
    the reach set was shown to leave it but no simulation reproduced the exit, ends
    there), ``max_depth``, ``over_approximation`` (a merged or disturbed set meets a
    property, no concrete trajectory found does). ``detail`` names the time and the
    cause, and says where the tube ends when it is partial (docs/verification.md, "The tube file").

    Parameters
    ----------
    findings : list of Finding
        Not empty.
    concrete : list of Finding
        The findings with a concrete initial state that no simulation confirmed: the run
        stopped at the first of them.
    depth : int, optional
        The refinement depth the run had (``verify.max_depth``), named by a ``max_depth``.

    Returns
    -------
    reason, detail : str
    """
    kinds = {f.kind for f in findings}

    def first(kind: str):
        return min((f for f in findings if f.kind == kind), key=lambda f: f.t)

    if "budget" in kinds:  # (the detail is completed by the caller: the margins)
        reason, f = "budget", first("budget")
        detail = f"{f.detail}; the tube ends at t = {f.t:.6g}"
    elif "limit" in kinds:
        reason, f = "limit", first("limit")
        detail = f"{f.detail}; the tube ends at t = {f.t:.6g}"
    elif "enclosure" in kinds:
        reason, f = "enclosure", first("enclosure")
        detail = f.detail or f"an a-priori enclosure failed at t = {f.t:.6g}"
        if "tube" not in detail:
            detail += "; the tube of that piece of the initial set ends there"
    elif "undefined" in kinds:
        reason, f = "infeasible_region", first("undefined")
        detail = f.detail or f"at t = {f.t:.6g} the reach set may leave the law's domain"
    elif "max_depth" in kinds:
        reason, f = "max_depth", first("max_depth")
        detail = f.detail or (f"a possible violation at t = {f.t:.6g} was not decided "
                              f"within verify.max_depth = {depth} refinements: raise "
                              "verify.max_depth or shrink verify.initial_set")
    elif "over_approximation" in kinds:
        # a merged or disturbed set still meets a property after the time refinements such
        # a set gets (they cannot remove what the merge or the disturbance adds)
        reason, f = "over_approximation", first("over_approximation")
        detail = f"{f.detail}; no concrete search found a trajectory that does"
    else:
        # a property's violation on an over-approximated set (a hull under disturbances:
        # no initial state to replay) that no concrete search reproduced
        f = min(findings, key=lambda f: f.t)
        reason = "over_approximation"
        what = VIOLATION_WORDS.get(f.kind, f.kind).format(index=f.index)
        detail = (f"at t = {f.t:.6g} the over-approximation (a merged or disturbed reach set: "
                  f"no initial state to replay) {what.replace('enters', 'meets')}, and no "
                  "concrete search found a trajectory that does; the tube of that branch "
                  "ends there")
    if concrete:
        c = min(concrete, key=lambda f: f.t)
        detail += (f"; a {c.kind} violation found on the reach set at t = {c.t:.6g} was not "
                   "reproduced by simulation, and the exploration stopped there: the tube "
                   f"is partial after t = {c.t:.6g}")
    return reason, detail


def _stoppable_search(search: Callable[[], Counterexample | None]) -> Counterexample | None:
    """``search()``, stopped (no counterexample) when the deadline passes inside it: the
    concrete searches' simulations beat (``limits.beat``), so a budget or a time limit
    ends a long search too, and the verdict says what the proof reached."""
    try:
        with stoppable():
            return search()
    except (DeadlineReached, RegionLimitError):  # (a law on demand at its region limit)
        return None


def _budget_answer(problem: Problem, tube: Tube, stats: dict, finding) -> str:
    """The ``detail`` of a verification stopped by its budget: where (the engine's words),
    how far it got and the best margins (``stats["margins"]``, set here), then what to
    change (``reach.margin``)."""
    from codev_engine.reach.margin import budget_detail, property_margins

    stats["margins"] = property_margins(problem, tube)
    where, _, fix = finding.detail.partition(": raise")
    detail = budget_detail(problem, tube, stats, where)
    return detail + (f"; to go further raise{fix}" if fix else "")


def _finite(tube: Tube) -> bool:
    """Every bound of the tube is a finite number."""
    return bool(np.all(np.isfinite(tube.lower)) and np.all(np.isfinite(tube.upper)))


def _ellipsoid_certificate(problem: Problem, law: ExplicitLaw, hold: str, depth: int,
                           progress, executor, cells: int, t0: float
                           ) -> tuple[VerificationResult | None, str]:
    """Safety for all time of a nonlinear plant: an invariant ellipsoid around the operating
    point (:func:`codev_engine.reach.terminal.terminal_ellipsoids`) that every reach set of
    the nonlinear engine's bounded tube lies in at some sample (docs/verification.md).

    Parameters
    ----------
    problem : Problem
        Its ``time_horizon`` already the bound ``max_samples * sample_time``.
    law : ExplicitLaw
    hold : {"zoh", "continuous"}
    depth : int
    progress, executor, cells
        As for :func:`verify`.
    t0 : float
        ``time.perf_counter()`` at the start of the verification.

    Returns
    -------
    result : VerificationResult or None
        ``robustly_safe`` / ``invariant`` with the certificate, or None.
    why : str
        When None: why no certificate.
    """
    from codev_engine.reach.nonlinear import NonlinearReach
    from codev_engine.reach.terminal import terminal_ellipsoids

    vs = problem.verify
    ells, why = terminal_ellipsoids(with_hold(problem, hold), law)
    if not ells:
        return None, why
    Ts = float(problem.model.sample_time)
    k = 30
    while True:
        k = min(2 * k, vs.max_samples)
        bounded = replace(problem, verify=replace(vs, time_horizon=k * Ts))
        serial = executor is None or executor.kind == "serial"
        # (in this process: each set of the tube stops where it enters an ellipsoid)
        eng = NonlinearReach(bounded, law, hold, depth, progress=progress,
                             absorb=_in_ellipsoids(ells) if serial else None)
        eng.run(executor, cells=cells)
        stop = [f for f in eng.findings if f.kind in ("budget", "limit")]
        if stop:  # the run stopped (a limit, the budget): that is the verdict's cause
            tube = Tube.concatenate(eng.tubes, problem.plant.n)
            stats = {**eng.stats, "boxes": tube.num_boxes}
            detail = f"{stop[0].detail}; the tube ends at t = {stop[0].t:.6g}"
            if stop[0].kind == "budget":
                detail = _budget_answer(bounded, tube, stats, stop[0])
            stats["seconds"] = time.perf_counter() - t0
            result = VerificationResult("unknown", stop[0].kind, tube, hold, None, stats,
                                        detail)
            result.attach_display(problem=problem, law=law)
            return result, ""
        if eng.findings:
            return None, ("the bounded tube meets a property before it enters an invariant "
                          f"ellipsoid (within {k} samples)")
        tube = Tube.concatenate(eng.tubes, problem.plant.n)
        if eng.absorb is not None:
            if (eng.absorbed and eng.open_sets == 0 and eng.absorb_mask is not None
                    and eng.absorb_mask.any()):
                # every set entered the ellipsoids: one holds all of them
                e = ells[int(np.flatnonzero(eng.absorb_mask)[0])]
                j = max(a[0] for a in eng.absorbed)
                lo = np.vstack([a[1] for a in eng.absorbed])
                hi = np.vstack([a[2] for a in eng.absorbed])
                # a set stopped at the sample it entered e: from then on its states are in
                # e at the samples and in e's period box between them. That box, from the
                # first entry on, keeps the tube's contract (every state in an active box)
                first = min(a[0] for a in eng.absorbed) * Ts
                end = max(float(tube.t_end.max()) if tube.num_boxes else 0.0, j * Ts)
                band = Tube(np.array([first]), np.array([end]), e.box_lo[None].copy(),
                            e.box_hi[None].copy(),
                            np.array([int(tube.branch.max()) + 1 if tube.num_boxes else 0]))
                tube = Tube.concatenate([tube, band], problem.plant.n)
                return _ellipsoid_result(problem, law, hold, eng, tube, e, j, lo, hi, t0,
                                         per_set=True), ""
            if k >= vs.max_samples:
                return None, (f"the bounded tube did not enter an invariant ellipsoid within "
                              f"max_samples = {vs.max_samples} samples")
            continue  # (some sets reached the horizon outside: a longer tube)
        for j in range(1, k + 1):
            tj = j * Ts
            # every box whose interval meets t_j, with a tolerance for the rounding of the
            # boxes' times (more boxes only make the containment harder)
            tol = 1e-9 * Ts
            sel = (tube.t_start <= tj + tol) & (tube.t_end >= tj - tol)
            if not sel.any():
                continue
            lo, hi = tube.lower[sel], tube.upper[sel]
            for e in ells:
                if e.contains_boxes(lo, hi):
                    return _ellipsoid_result(problem, law, hold, eng, tube, e, j, lo, hi,
                                             t0), ""
        if k >= vs.max_samples:
            return None, (f"the bounded tube did not enter an invariant ellipsoid within "
                          f"max_samples = {vs.max_samples} samples")


def _in_ellipsoids(ells: list) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``inside(lo, hi) -> (e,) bool``: which of the ellipsoids hold the box
    (:func:`codev_engine.reach.terminal.ellipsoid_holds`), for ``NonlinearReach``'s
    ``absorb``.

    Parameters
    ----------
    ells : list of TerminalEllipsoid

    Returns
    -------
    callable
    """
    from codev_engine.reach.terminal import ellipsoid_holds, ellipsoid_reach

    # each ellipsoid's bounding box (c +- sqrt(diag(P^-1)), widened): a box not inside it is
    # not inside the ellipsoid (a quick refusal; refusing is always sound)
    reach = [ellipsoid_reach(e.P) for e in ells]

    def inside(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        return np.array([
            bool(np.all(lo >= e.centre - r) and np.all(hi <= e.centre + r))
            and ellipsoid_holds(e.P, e.centre, lo[None], hi[None])
            for e, r in zip(ells, reach, strict=True)
        ])

    return inside


def _ellipsoid_result(problem: Problem, law: ExplicitLaw, hold: str, eng, tube: Tube, e,
                      j: int, lo: np.ndarray, hi: np.ndarray, t0: float,
                      per_set: bool = False) -> VerificationResult:
    """``robustly_safe`` / ``invariant`` with the ellipsoid ``e`` and the boxes ``[lo, hi]``
    that lie in it (the certificate, re-checked when loaded).

    Parameters
    ----------
    problem : Problem
    law : ExplicitLaw
    hold : str
    eng : NonlinearReach
        The run (its counters).
    tube : Tube
    e : TerminalEllipsoid
    j : int
        The closing sample (with ``per_set``: the last sample at which a set entered).
    lo, hi : (p, n) ndarray
    t0 : float
        ``time.perf_counter()`` at the start.
    per_set : bool
        Each set of the tube stopped at the sample it entered ``e`` (``lo, hi`` those
        sets' boxes), rather than every reach set at sample ``j``.

    Returns
    -------
    VerificationResult
    """
    Ts = float(problem.model.sample_time)
    tj = j * Ts
    stats = dict(eng.stats)
    stats["partitions"] = 1
    stats["boxes"] = tube.num_boxes
    stats["certificate"] = {
        "kind": "ellipsoid", "closed_sample": j, "closed_time": tj,
        "region": int(e.region), "rho": float(e.rho), "margin": float(e.margin),
        "per_set": bool(per_set),
    }
    stats["seconds"] = time.perf_counter() - t0
    certificate = {"P": e.P, "centre": e.centre, "lower": lo, "upper": hi}
    where = (f"each reach set lies, at a sample up to {j} (t = {tj:g}), in an invariant "
             "ellipsoid" if per_set else
             f"every reach set at sample {j} (t = {tj:g}) lies in an invariant ellipsoid")
    detail = (
        f"{where} around the operating point (region {e.region}, contraction "
        f"{e.rho:.4g}, margin {e.margin:.3g}): every later state stays in it at the "
        "samples and in its period's enclosure between them"
    )
    result = VerificationResult("robustly_safe", "invariant", tube, hold, None, stats, detail,
                                certificate)
    result.attach_display(problem=problem, law=law)
    return result


def _limited(problem: Problem, law: ExplicitLaw, hold: str, t0: float, reason: str,
             detail: str) -> VerificationResult:
    """``unknown`` with ``reason`` (a limitation of the engines) unless the concrete search
    finds a replayed counterexample."""
    vs = problem.verify
    bounded = problem
    if not np.isfinite(vs.time_horizon):
        bounded = replace(problem, verify=replace(
            vs, time_horizon=vs.max_samples * float(problem.model.sample_time)))
    cex = _search(bounded, law, hold)
    stats = {"seconds": time.perf_counter() - t0, "branches": 0, "boxes": 0}
    tube = Tube.empty(problem.plant.n)
    if cex is not None:
        result = VerificationResult("unsafe", cex.kind, tube, hold, cex, stats)
    else:
        result = VerificationResult("unknown", reason, tube, hold, None, stats,
                                    f"{detail}; no reachtube is computed (the tube is empty)")
    result.attach_display(problem=problem, law=law)
    return result


def _uncertain(problem: Problem) -> bool:
    """Disturbances (that can change the field), uncertain parameters or measurement
    noise: searched under signals."""
    from codev_engine.plant import field_uncertain

    return bool(field_uncertain(problem) or (problem.verify is not None
                                             and problem.verify.noisy))


def _confirm(
    problem: Problem, law: ExplicitLaw, hold: str, x0: np.ndarray, signals=None
) -> Counterexample | None:
    """Simulate from x0 (independent integrator); a Counterexample if it violates.

    For an uncertain plant each of ``signals`` (default :func:`_signals` of one
    trajectory: the box's centre, its corners held constant, bang-bang and random pieces) is
    replayed until one violates; the counterexample keeps it. With measurement noise and no
    ``signals``, the noise sequences of :func:`_search` from x0 (adversaries included).
    """
    from codev_engine.plant import field_uncertain
    from codev_engine.reach.simulate import first_violation, simulate, theta_initial_box

    n = problem.plant.n
    lo, hi = theta_initial_box(problem)  # x0 may be theta0 = (x0, u_prev0, r)
    theta0 = np.clip(np.asarray(x0, dtype=float), lo[: np.size(x0)], hi[: np.size(x0)])
    if signals is None and problem.verify.noisy:
        return _search(problem, law, hold, X0=theta0[None, :])
    x0, extra0 = theta0[:n], theta0[n:]
    if signals is None:
        signals = _signal_list(problem) if field_uncertain(problem) else [None]
    for sig in signals:
        try:
            try:
                trace = simulate(problem, law, x0, hold=hold,
                                 extra0=extra0 if extra0.size else None, disturbance=sig)
            except SolverError:  # not finite (a singularity): no confirmed counterexample
                continue
            v = first_violation(problem, law, trace)
        except RegionLimitError:  # (a law on demand at its region limit: none confirmed)
            return None
        if v is None:
            continue
        return Counterexample(x0=x0, t=float(v.t), kind=v.kind, index=int(v.index),
                              trace=trace, extra0=extra0, disturbance=sig)
    return None


def _signals(problem: Problem, P: int, seed: int = 0):
    """``P`` concrete disturbance signals and parameter values for the search.

    Returns ``(piece, W (P, K, d), Q (P, q))``: row 0 the centre of the boxes, then every
    corner held constant, then bang-bang signals (a random corner on each piece), then
    uniformly random ones; pieces of about the reach step, a multiple of the RK4 step of
    :func:`~codev_engine.reach.simulate.simulate_many` (so the search simulates the signal
    the replay does). Parameters: centre, corners, random.
    """
    pl, vs = problem.plant, problem.verify
    Ts = float(problem.model.sample_time)
    S = max(1, int(np.ceil(Ts / (vs.step / 10.0) - 1e-9)))
    h = Ts / S
    piece = h * max(1, round(vs.step / h))
    K = int(np.ceil(vs.time_horizon / piece)) + 1
    rng = np.random.default_rng(seed)

    def draws(box, per_piece: bool):
        if box is None:
            return np.zeros((P, K if per_piece else 1, 0))
        d = box.d
        lo, hi = np.asarray(box.lower, float), np.asarray(box.upper, float)
        corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(d)],
                                       indexing="ij")).reshape(d, -1).T
        L = K if per_piece else 1
        out = np.empty((P, L, d))
        out[0] = 0.5 * (lo + hi)
        c = min(corners.shape[0], max(0, P - 1))
        out[1 : 1 + c] = corners[:c, None, :]
        rest = P - 1 - c
        half = rest // 2
        bang = rng.integers(0, 2, (half, L, d))
        out[1 + c : 1 + c + half] = np.where(bang == 1, hi, lo)
        out[1 + c + half :] = rng.uniform(lo, hi, (rest - half, L, d))
        return out

    W = draws(pl.disturbances, True)
    Q = draws(pl.parameters, False)[:, 0, :]
    if pl.parameters is not None and pl.disturbances is not None:
        Q = Q[rng.permutation(P)]  # parameter draws not tied to signal kinds
        Q[0] = np.asarray(pl.parameters.centre, float)
    return piece, W, Q


def _signal_list(problem: Problem, P: int = 16) -> list:
    """:func:`_signals` as :class:`DisturbanceSignal` objects (for :func:`_confirm`)."""
    from codev_engine.reach.simulate import DisturbanceSignal

    piece, W, Q = _signals(problem, P)
    return [DisturbanceSignal(piece, W[p], Q[p]) for p in range(P)]


def noise_sequences(problem: Problem, P: int, seed: int = 0) -> np.ndarray:
    """``P`` concrete measurement-noise sequences, one value per sample time.

    Row 0 the box's centre, then its corners held constant, then bang-bang sequences (a
    random corner at each sample), then uniformly random ones.

    Parameters
    ----------
    problem : Problem
        With ``verify.measurement_noise``.
    P : int
    seed : int

    Returns
    -------
    (P, S, n) ndarray
        ``S`` = the sample times up to the horizon.
    """
    vs = problem.verify
    lo, hi = np.asarray(vs.noise_lower, float), np.asarray(vs.noise_upper, float)
    n = lo.shape[0]
    Ts = float(problem.model.sample_time)
    S = int(np.ceil(vs.time_horizon / Ts - 1e-9)) + 1
    rng = np.random.default_rng(seed + 7)
    out = np.empty((P, S, n))
    out[0] = 0.5 * (lo + hi)
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)],
                                   indexing="ij")).reshape(n, -1).T
    c = min(corners.shape[0], max(0, P - 1))
    out[1 : 1 + c] = corners[:c, None, :]
    rest = P - 1 - c
    half = rest // 2
    out[1 + c : 1 + c + half] = np.where(rng.integers(0, 2, (half, S, n)) == 1, hi, lo)
    out[1 + c + half :] = rng.uniform(lo, hi, (rest - half, S, n))
    return out


def noise_adversary(problem: Problem, law: ExplicitLaw, directions: np.ndarray,
                    seed: int = 0) -> Callable:
    """A feedback adversary for :func:`~codev_engine.reach.simulate.simulate_many`: at each
    sample, the noise value (a corner of the box, or its centre) whose region and law push
    the next state furthest along the trajectory's direction.

    The next state is predicted by the discretised model ``A x + B u``; the candidate
    values meet region boundaries where a noisy state may select a neighbouring region with
    a very different input (docs/verification.md, "Measurement noise").

    Parameters
    ----------
    problem : Problem
        With ``verify.measurement_noise``.
    law : ExplicitLaw
    directions : (P, n) ndarray
        One direction per trajectory (rows of the ``X0`` given to ``simulate_many``).
    seed : int
        For the sample of corners when there are more than 32.

    Returns
    -------
    callable
        ``(k, X (q, n), idx (q,)) -> (q, n)``.
    """
    from codev_engine.plant import discretize

    vs = problem.verify
    lo, hi = np.asarray(vs.noise_lower, float), np.asarray(vs.noise_upper, float)
    n = lo.shape[0]
    if n <= 5:
        cand = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)],
                                    indexing="ij")).reshape(n, -1).T
    else:
        rng = np.random.default_rng(seed)
        cand = np.where(rng.integers(0, 2, (32, n)) == 1, hi, lo)
    cand = np.vstack([0.5 * (lo + hi), cand])  # (c, n)
    lm = discretize(problem)
    B = np.asarray(lm.B, float)[:n]
    dirs = np.asarray(directions, float)

    def choose(_k: int, X: np.ndarray, idx: np.ndarray) -> np.ndarray:
        q, c = X.shape[0], cand.shape[0]
        Y = (X[:, None, :] + cand[None, :, :]).reshape(q * c, n)
        if law.n > n:  # theta = (x, u_prev, r): the adversary looks at the state part only
            Y = np.hstack([Y, np.zeros((q * c, law.n - n))])
        reg = law.locate(Y)
        U = np.einsum("pij,pj->pi", law.F[np.maximum(reg, 0)], Y) + law.G[np.maximum(reg, 0)]
        score = (U @ B.T * np.repeat(dirs[idx], c, axis=0)).sum(axis=1)
        score = np.where(reg < 0, np.inf, score)  # leaving the law's domain is a violation
        best = np.argmax(score.reshape(q, c), axis=1)
        return cand[best]

    return choose


def _search(
    problem: Problem, law: ExplicitLaw, hold: str, samples: int = 64,
    X0: np.ndarray | None = None,
) -> Counterexample | None:
    """Concrete simulations from corners, centre and random initial states (or from the
    rows of ``X0``); with measurement noise, each under noise sequences (:func:`noise_sequences`
    and :func:`noise_adversary`), every violation replayed before it is reported."""
    from codev_engine.reach.simulate import theta_initial_box

    lo, hi = theta_initial_box(problem)  # (x0, u_prev0, r): the law's parameters
    n = lo.shape[0]
    nx = problem.plant.n
    if X0 is None:
        corners = np.array(
            np.meshgrid(*[[lo[i], hi[i]] for i in range(n)], indexing="ij")
        ).reshape(n, -1).T
        rng = np.random.default_rng(0)
        X0 = np.vstack([0.5 * (lo + hi), corners[: 4 * samples],
                        rng.uniform(lo, hi, (samples, n))])
    if problem.verify.noisy:
        # each initial state under fixed sequences and under adversaries with random
        # directions; the sequences the adversaries chose are replayed like the others
        per = 8
        reps = X0.shape[0] * per
        seqs = noise_sequences(problem, reps)
        X0r = np.repeat(X0, per, axis=0)
        dirs = np.random.default_rng(3).normal(size=(reps, nx))
        cex = None
        for noise in (seqs, noise_adversary(problem, law, dirs)):
            cex = _search_runs(problem, law, hold, X0r, noise)
            if cex is not None:
                return cex
        return None
    return _search_runs(problem, law, hold, X0, None)


def _search_runs(problem: Problem, law: ExplicitLaw, hold: str, X0: np.ndarray,
                 noise) -> Counterexample | None:
    """Simulate from the rows of X0 (under signals when uncertain, and ``noise``); the
    first replayed violation."""
    from codev_engine.plant import field_uncertain
    from codev_engine.reach.simulate import simulate_many, theta_initial_box, violations_many

    lo, _ = theta_initial_box(problem)
    n = lo.shape[0]
    nx = problem.plant.n
    dist = None
    if field_uncertain(problem):
        # every initial state under every signal kind: centre, constant corners, bang-bang
        # and random pieces (_signals), each replayed exactly before it is reported
        per = 8 if noise is None else 1
        piece, W, Q = _signals(problem, X0.shape[0] * per)
        X0 = np.repeat(X0, per, axis=0)
        dist = (piece, W, Q)
    ap = _search_plant(problem)
    dt = _search_step(problem, dist[0] if dist is not None else None) if ap else None
    with np.errstate(all="ignore"):
        try:
            runs = simulate_many(problem, law, X0[:, :nx], hold=hold,
                                 extra0=X0[:, nx:] if n > nx else None,
                                 disturbance=dist, noise=noise, affine=ap, dt=dt, dt_out=dt)
            t, X, U, alive = runs
        except SolverError:  # a trajectory is not finite: search the others
            if dist is not None or noise is not None:
                return None
            X0 = X0[[_finite_run(problem, law, hold, x) for x in X0]]
            if X0.shape[0] == 0:
                return None
            try:
                t, X, U, alive = simulate_many(problem, law, X0[:, :nx], hold=hold,
                                               extra0=X0[:, nx:] if n > nx else None)
            except SolverError:
                return None
    bad, _ = violations_many(problem, t, X, U, alive)
    from codev_engine.reach.simulate import DisturbanceSignal

    replayed = dist is not None or noise is not None
    for p in np.flatnonzero(bad)[: 20 if replayed else None]:
        signals = None
        if replayed:
            if dist is not None:
                sig = DisturbanceSignal(dist[0], dist[1][p], dist[2][p])
            else:
                sig = DisturbanceSignal(float(problem.model.sample_time), np.zeros((1, 0)),
                                        np.zeros(0))
            if noise is not None:
                sig = replace(sig, noise=runs.noise[p])
            signals = [sig]
        cex = _confirm(problem, law, hold, X0[p], signals)
        if cex is not None:
            return cex
    return None


def _adjoint_search(problem: Problem, law: ExplicitLaw, hold: str, times: list[float]
                    ) -> Counterexample | None:
    """Counterexamples under the adjoint's bang-bang signals (``reach.adversary``): from the
    initial set's centre and corners, each signal pushing a safe set's row, the way into an
    unsafe set's row or a state axis to its extreme at the first of ``times`` (where the
    tube met a property) and at the next one a sample period or more later. Affine plants
    with disturbances, a law over the state alone, no measurement noise; every violation
    replayed (:func:`_confirm`) before it is reported. None when none is found (or the
    case is not covered)."""
    from codev_engine.plant import disturbances_matter
    from codev_engine.reach.adversary import adjoint_signals
    from codev_engine.reach.simulate import (
        DisturbanceSignal,
        simulate_many,
        violations_many,
    )

    pl, vs = problem.plant, problem.verify
    if not disturbances_matter(pl) or law.n != pl.n or vs.noisy:
        return None
    n = pl.n
    T = float(vs.time_horizon)
    ts: list[float] = []
    for t in sorted(float(t) for t in times if 0.0 < t <= T):
        if not ts or t >= ts[-1] + float(problem.model.sample_time):
            ts.append(t)  # (at most one target per sample period, two in all)
    ts = ts[:2]
    if not ts:
        return None
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)],
                                   indexing="ij")).reshape(n, -1).T
    if corners.shape[0] > 16:
        corners = corners[np.random.default_rng(0).choice(corners.shape[0], 16, replace=False)]
    X0 = np.vstack([0.5 * (lo + hi), corners])
    dirs = [np.eye(n), -np.eye(n)]
    for st in vs.safe:
        dirs.append(st.halfspaces()[0])
    for st in vs.unsafe:
        dirs.append(-np.asarray(st.halfspaces()[0], float))
    D = np.vstack(dirs)
    D = D[np.linalg.norm(D, axis=1) > 0]
    X0r, L = np.repeat(X0, D.shape[0], axis=0), np.tile(D, (X0.shape[0], 1))
    dt = float(vs.step)
    for tq in ts:
        try:
            piece, W, Q, Xs = adjoint_signals(problem, law, X0r, L, hold=hold, t_target=tq,
                                              iterations=3, dt=dt)
            ap = _search_plant(problem)
            sdt = float(vs.step) if ap else None
            with np.errstate(all="ignore"):
                t, X, U, alive = simulate_many(problem, law, Xs, hold=hold,
                                               disturbance=(piece, W, Q), affine=ap,
                                               dt=sdt, dt_out=sdt)
        except (SolverError, ValueError):
            continue
        bad, _ = violations_many(problem, t, X, U, alive)
        for p in np.flatnonzero(bad)[:20]:
            cex = _confirm(problem, law, hold, Xs[p], [DisturbanceSignal(piece, W[p], Q[p])])
            if cex is not None:
                return cex
    return None


def _input_search(problem: Problem, law: ExplicitLaw, hold: str, per_period: int = 5,
                  max_periods: int = 40, tube: Tube | None = None) -> Counterexample | None:
    """Counterexamples of ``input_bounds`` under the adjoint's bang-bang signals.

    The input of region ``i`` is ``F_i x + G_i``: a signal that pushes ``±F_i[j]' x`` to
    its extreme at a time ``t`` drives input ``j`` of a trajectory that is in region ``i``
    at ``t`` towards its bound (under the continuous hold a state can cross into the
    saturated region during a period while the law of the last sample is in force). Targets
    at ``per_period`` times in each of the first ``max_periods`` sample periods, from the
    initial set's centre and corners (16 at most), one batch (``t_target`` per trajectory);
    every violation replayed (:func:`_confirm`) before it is reported. The search claims
    nothing: it only turns an ``unknown`` into a replayed ``unsafe``.

    Parameters
    ----------
    problem : Problem
        An affine plant with disturbances, ``verify.input_bounds``, a law over the state
        alone and no measurement noise (otherwise None is returned).
    law : ExplicitLaw
    hold : {"zoh", "continuous"}
    per_period : int
        Target times per sample period (at ``(j + 1) / (per_period + 1)`` of it).
    max_periods : int
        At most this many periods from ``t = 0`` get targets.
    tube : Tube, optional
        The verification's tube: the rows are those of the regions holding its boxes'
        centres and corners and the initial states (located, so a law computed on demand
        and the full law give the same rows and the same counterexample); without it,
        every region's rows.

    Returns
    -------
    Counterexample or None
    """
    from codev_engine.plant import disturbances_matter
    from codev_engine.reach.adversary import adjoint_signals
    from codev_engine.reach.simulate import (
        DisturbanceSignal,
        simulate_many,
        violations_many,
    )

    pl, vs = problem.plant, problem.verify
    if not disturbances_matter(pl) or law.n != pl.n or vs.noisy or not vs.input_bounds:
        return None
    n = pl.n
    Ts = float(problem.model.sample_time)
    T = float(vs.time_horizon)
    if not np.isfinite(T):
        return None
    lo, hi = np.asarray(vs.initial_lower, float), np.asarray(vs.initial_upper, float)
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(n)],
                                   indexing="ij")).reshape(n, -1).T
    if corners.shape[0] > 16:
        corners = corners[np.random.default_rng(0).choice(corners.shape[0], 16, replace=False)]
    X0 = np.vstack([0.5 * (lo + hi), corners])
    if tube is None:
        F = np.asarray(law.F, float)
    else:
        # the regions where the loop goes, by the points of the tube (located: a law on
        # demand holds only the regions computed so far, which its rows alone would miss,
        # and the full law's every row would make a batch of its size)
        pts = [X0]
        if tube.num_boxes:
            blo, bhi = np.asarray(tube.lower, float), np.asarray(tube.upper, float)
            pts += [0.5 * (blo + bhi), blo, bhi]
        P = np.unique(np.vstack(pts), axis=0)
        P = P[np.all(np.isfinite(P), axis=1)]
        reg = np.unique(law.locate(P)) if P.shape[0] else np.zeros(0, int)
        F = np.asarray(law.F, float)[reg[reg >= 0]]
    rows = F.reshape(-1, n)
    rows = rows[np.linalg.norm(rows, axis=1) > 1e-12]
    if rows.shape[0] == 0:
        return None
    rows = np.unique(np.round(rows, 12), axis=0)
    D = np.vstack([rows, -rows])
    periods = min(int(np.ceil(T / Ts - 1e-9)), max_periods)
    times = np.array([(k + (j + 1) / (per_period + 1)) * Ts for k in range(periods)
                      for j in range(per_period)])
    times = times[times <= T]
    if times.size == 0:
        return None
    a, b, c = np.meshgrid(np.arange(X0.shape[0]), np.arange(D.shape[0]),
                          np.arange(times.size), indexing="ij")
    a, b, c = a.ravel(), b.ravel(), c.ravel()
    dt = float(vs.step)
    try:
        piece, W, Q, Xs = adjoint_signals(problem, law, X0[a], D[b], hold=hold,
                                          t_target=times[c], iterations=2, dt=dt)
        ap = _search_plant(problem)
        sdt = float(vs.step) if ap else None
        with np.errstate(all="ignore"):
            t, X, U, alive = simulate_many(problem, law, Xs, hold=hold,
                                           disturbance=(piece, W, Q), affine=ap, dt=sdt,
                                           dt_out=sdt)
    except (SolverError, ValueError):
        return None
    bad, _ = violations_many(problem, t, X, U, alive)
    for p in np.flatnonzero(bad)[:20]:
        cex = _confirm(problem, law, hold, Xs[p], [DisturbanceSignal(piece, W[p], Q[p])])
        if cex is not None:
            return cex
    return None


def _inputs_only(problem: Problem, tube: Tube, findings: list) -> bool:
    """Do the tube's boxes at the undecided findings (``max_depth``, ``over_approximation``:
    a held input's range, a merged set's box) all satisfy the state
    properties, so that only the input bounds can have kept them undecided? (It orders the
    concrete searches; it claims nothing.)

    Parameters
    ----------
    problem : Problem
    tube : Tube
        The tube with the undecided boxes (the engine appends them at the findings' times).
    findings : list of Finding

    Returns
    -------
    bool
        False without ``verify.input_bounds``, with findings of other kinds than
        ``max_depth`` and ``over_approximation`` or without a box at some finding's time.
    """
    vs = problem.verify
    if not vs.input_bounds or not findings or any(
        f.kind not in ("max_depth", "over_approximation") for f in findings
    ):
        return False
    if tube.num_boxes == 0:
        return False
    rows = [(np.asarray(A, float), np.asarray(b, float), False)
            for A, b in (st.halfspaces() for st in vs.safe)]
    rows += [(np.asarray(A, float), np.asarray(b, float), True)
             for A, b in (st.halfspaces() for st in vs.unsafe)]
    for f in findings:
        sel = np.abs(tube.t_start - f.t) <= 1e-9 * max(1.0, abs(f.t))
        if not sel.any():
            return False
        lo, hi = tube.lower[sel], tube.upper[sel]
        for A, b, unsafe in rows:
            Ap, An = np.maximum(A, 0.0), np.minimum(A, 0.0)
            if unsafe:  # the boxes may meet {A x <= b}: every row's minimum within b
                low = lo @ Ap.T + hi @ An.T
                if np.any(np.all(low <= b, axis=1)):
                    return False
            else:  # some box may leave {A x <= b}
                high = hi @ Ap.T + lo @ An.T
                if np.any(high > b):
                    return False
    return True


def _search_plant(problem: Problem):
    """The affine plant whose exact flow the searches simulate (``simulate_many``'s
    ``affine``), or None (a nonlinear plant, uncertain parameters: RK4).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    AffinePlant or None
    """
    from codev_engine.reach.linear import affine_plant

    if problem.plant.parameters is not None:
        return None
    return affine_plant(problem)


def _search_step(problem: Problem, piece: float | None = None) -> float:
    """The step of the searches' exact-flow simulations: at most ``verify.step / 4`` (the
    states and inputs are checked at every step, as densely as the RK4 searches' output),
    dividing the sample time and (given) the signals' ``piece``, a multiple of the RK4 step
    ``sample_time / ceil(10 sample_time / verify.step)`` (:func:`_signals`).

    Parameters
    ----------
    problem : Problem
    piece : float, optional

    Returns
    -------
    float
    """
    import math

    vs = problem.verify
    Ts = float(problem.model.sample_time)
    target = vs.step / 4.0
    S10 = max(1, int(np.ceil(Ts / (vs.step / 10.0) - 1e-9)))
    if piece is None:
        return target
    k = max(1, int(round(piece / (Ts / S10))))
    g = math.gcd(k, S10)
    e = max(q for q in range(1, g + 1) if g % q == 0 and Ts * q / S10 <= target * (1 + 1e-9)
            or q == 1)
    return Ts * e / S10


def with_hold(problem: Problem, hold: str) -> Problem:
    """A copy of ``problem`` whose verify section uses ``hold``."""
    assert problem.verify is not None
    return replace(problem, verify=replace(problem.verify, hold=hold))


def _finite_run(problem: Problem, law: ExplicitLaw, hold: str, x0: np.ndarray) -> bool:
    """Does the fast simulation from x0 stay finite?"""
    from codev_engine.reach.simulate import simulate_many

    nx = problem.plant.n
    try:
        simulate_many(problem, law, x0[None, :nx], hold=hold,
                      extra0=x0[None, nx:] if x0.shape[0] > nx else None)
    except SolverError:
        return False
    return True
