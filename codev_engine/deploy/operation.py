"""Deploy the law of the region of operation: the critical regions a verified closed loop
reaches (issue 39).

A law computed on demand (``law_on_demand.OnDemandLaw``) holds the regions its verification
asked for. :func:`operation_law` certifies that every reach set of the tube at a sample
(the states the law is evaluated at) lies in their union, and returns those regions as an
``ExplicitLaw`` for the existing exports (``deploy.export``: C and Python by the same search
tree). Outside the regions the generated code returns -1 and leaves ``u`` unchanged: it
never extrapolates. :func:`operation_note` is the text the exports' headers carry: the
region of operation and the verdict it rests on.

Why the check is exact: the regions of the MPC partition its feasible set ``D``, so a box
``B`` lies in the union of the regions that meet it exactly when ``B`` lies in ``D``. The
certificate asks the law for every region meeting each sample set's box (computing any not
known yet, which are then exported too) and checks the box against the rows that describe
``D`` there (``law.domain_rows``: rows valid on all of ``D``), by their support over the box.
"""

from __future__ import annotations

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.law import ExplicitLaw

__all__ = ["operation_law", "operation_note"]

#: relative slack of the domain test (rows of unit norm; the regions' own tolerance is 1e-9)
_TOL = 1e-9


def _sample_boxes(result, Ts: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tube's boxes whose time span holds a sample instant ``k Ts``: (lo, hi, t)."""
    tube = result.tube
    t0, t1 = np.asarray(tube.t_start, float), np.asarray(tube.t_end, float)
    k = np.ceil(t0 / Ts - 1e-9)
    hit = k * Ts <= t1 + 1e-9 * Ts
    return tube.lower[hit], tube.upper[hit], (k * Ts)[hit]


def operation_law(problem, law, result) -> tuple[ExplicitLaw, dict]:
    """The regions of operation of a verified closed loop, as an ``ExplicitLaw``, and the
    certificate that every reach set of its tube at a sample lies in their union.

    Parameters
    ----------
    problem : Problem
        The design verified.
    law : OnDemandLaw
        The law it was verified on (its regions are those the verification reached).
    result : VerificationResult
        The verification's result (``verify(problem, law)``).

    Returns
    -------
    ExplicitLaw
        The regions computed (those reached), ordered as in the full law (by active set),
        with the law's names and fingerprint; ``meta["operation"]`` holds the certificate,
        ``meta["operation_states"]`` (k, n) the sample sets' centres (``plan``'s ``auto``
        chooses the search by its mean cost on them).
    certificate : dict
        ``sets`` (sample sets checked), ``regions``, ``verdict``, ``reason``, ``horizon``,
        ``initial_lower``, ``initial_upper``.

    Raises
    ------
    SpecError
        Not a law computed on demand, a law over more than the state (its tube holds the
        state alone), an empty tube, or a sample set that leaves the law's domain (field
        ``synthesis.regions``: the certificate fails; nothing is exported).
    """
    if not getattr(law, "on_demand", False):
        raise SpecError("the region of operation is exported from a law computed on demand "
                        "(regions = \"reached\"); a full law exports whole",
                        field="synthesis.regions")
    if law.n != problem.plant.n:
        raise SpecError("the region of operation is exported for a law over the state alone "
                        f"(this one takes theta = ({', '.join(law.parameter_names)}))",
                        field="synthesis.regions")
    lo, hi, times = _sample_boxes(result, float(problem.model.sample_time))
    if lo.shape[0] == 0:
        raise SpecError("the verification's tube holds no reach set at a sample: no region of "
                        f"operation to certify (verdict {result.verdict})",
                        field="synthesis.regions")
    for q in range(lo.shape[0]):
        if not (np.all(np.isfinite(lo[q])) and np.all(np.isfinite(hi[q]))):
            raise SpecError(f"the reach set at t = {times[q]:.6g} is unbounded: no region of "
                            "operation", field="synthesis.regions")
        law.regions_meeting(lo[q], hi[q])  # (computes any region not known yet)
        rows = law.domain_rows(lo[q], hi[q])
        if rows is None:
            raise SpecError("the law's domain is not known", field="synthesis.regions")
        A, b = rows
        c, r = 0.5 * (lo[q] + hi[q]), 0.5 * (hi[q] - lo[q])
        # the largest value of each row over the box (its support: exact for a box)
        sup = A @ c + np.abs(A) @ r
        slack = _TOL * (1.0 + np.abs(b) + np.abs(A) @ np.abs(c))
        if np.any(sup > b + slack):
            raise SpecError(f"the reach set at t = {times[q]:.6g} leaves the MPC's feasible "
                            "set: it does not lie in the regions of operation, nothing is "
                            f"exported (verdict {result.verdict})", field="synthesis.regions")
    # the full law's order (ascending active sets): the locator's lowest-index rule picks
    # as the full law's on shared boundaries
    actives = [r.active for r in law._solver.regions]
    order = sorted(range(law.num_regions), key=lambda i: actives[i])
    cert = {
        "sets": int(lo.shape[0]), "regions": law.num_regions, "verdict": result.verdict,
        "reason": result.reason, "horizon": float(problem.verify.time_horizon),
        "initial_lower": [float(v) for v in problem.verify.initial_lower],
        "initial_upper": [float(v) for v in problem.verify.initial_upper],
    }
    # the sample sets' centres: the states the loop visits, by which ``plan``'s ``auto``
    # chooses the search of lower expected cost (the header keeps the worst case)
    meta = {"problem": problem.name, "operation": cert, "norm": law.meta.get("norm"),
            "horizon": law.meta.get("horizon"), "operation_states": 0.5 * (lo + hi)}
    out = ExplicitLaw(
        A=[law.A[i] for i in order], b=[law.b[i] for i in order],
        F=np.asarray(law.F)[order], G=np.asarray(law.G)[order],
        states=tuple(law.states), inputs=tuple(law.inputs), fingerprint=law.fingerprint,
        meta=meta,
    )
    return out, cert


def operation_note(problem, cert: dict) -> str:
    """The header text of an export of the region of operation (plain text, lines).

    Parameters
    ----------
    problem : Problem
    cert : dict
        From :func:`operation_law`.

    Returns
    -------
    str
    """
    lo = ", ".join(f"{v:.6g}" for v in cert["initial_lower"])
    hi = ", ".join(f"{v:.6g}" for v in cert["initial_upper"])
    why = f" ({cert['reason']})" if cert["reason"] else ""
    return (
        f"REGION OF OPERATION of {problem.name}: the {cert['regions']} critical regions its "
        "verified closed loop reaches\n"
        f"(computed on demand), not the whole law. Verdict it rests on: {cert['verdict']}"
        f"{why},\n"
        f"from the initial set [{lo}] .. [{hi}] over {cert['horizon']:g} s.\n"
        f"Certified at export: each of the tube's {cert['sets']} reach sets at a sample lies "
        "in the union of these regions.\n"
        "Outside them the code returns -1 (distinct status) and leaves u unchanged: it "
        "never extrapolates."
    )
