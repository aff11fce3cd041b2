"""What a verdict claims, as plain data: the one statement every output renders.

A verdict alone ("robustly safe") does not say what was proved. :func:`build_claim` states it
from the spec (and the result): the system, the initial set (with the ``u_prev`` and reference
boxes of a law over theta), the uncertainty covered (disturbance, parameter and noise boxes),
each property checked (unsafe sets, safe sets, input bounds, the law's domain), the time
(``[0, T]`` or all time with the certificate), the hold -- and, just as visibly, the design's
own constraints that were **not** checked (the MPC imposes its bounds on its predictions
only). The CLI text, ``--json``, the TUI, the notebook, the recording and the HTML report all
render this one :class:`Claim`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.spec.problem import Problem, SetSpec, design_safe_sets, parameter_names

if TYPE_CHECKING:
    from codev_engine.reach.verification import VerificationResult

__all__ = ["CertificateBand", "Claim", "build_claim", "certificate_band", "describe_set",
           "width_at_end"]


@dataclass(frozen=True)
class Claim:
    """The statement a verification makes (or was asked to make), in words.

    Attributes
    ----------
    system : str
        The spec's name, its states and inputs.
    verdict : str or None
        The result's verdict; None before verification.
    initial : tuple of str
        The initial set, one item per box: the states, then ``u_prev`` and ``r`` when the
        law takes them.
    uncertainty : tuple of str
        The disturbance, parameter and measurement-noise boxes covered (may be empty).
    checked : tuple of str
        Each property checked, one item each.
    time : str
        ``for all t in [0, T] s`` or ``for all t >= 0 (certificate ...)``.
    hold : str
        How the input is applied between samples.
    not_checked : tuple of str
        The design's constraints the verdict says nothing about (may be empty).
    """

    system: str
    verdict: str | None
    initial: tuple[str, ...]
    uncertainty: tuple[str, ...]
    checked: tuple[str, ...]
    time: str
    hold: str
    not_checked: tuple[str, ...]

    def as_dict(self) -> dict:
        """The claim as JSON-ready data (lists of strings).

        Returns
        -------
        dict
        """
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    def lines(self, *, bold: bool = False) -> list[str]:
        """The claim as ``- label: text`` lines (markdown list items).

        Parameters
        ----------
        bold : bool
            Labels in ``**bold**`` (markdown renderers); plain for a terminal.

        Returns
        -------
        list of str
        """
        def item(label: str, text: str) -> str:
            return f"- **{label}**: {text}" if bold else f"- {label}: {text}"

        out = [item("system", self.system)]
        out += [item("initial set", s) for s in self.initial]
        out += [item("for every", s) for s in self.uncertainty]
        out.append(item("time", self.time))
        out.append(item("hold", self.hold))
        out += [item("checked", s) for s in self.checked]
        out += [item("NOT checked", s) for s in self.not_checked] or [
            item("NOT checked", "nothing: every constraint of the design is checked")
        ]
        return out


def _g(x: float) -> str:
    return f"{float(x):.6g}"


def _box(names: tuple[str, ...], lo: np.ndarray, hi: np.ndarray) -> str:
    return ", ".join(f"{s} in [{_g(a)}, {_g(b)}]" for s, a, b in zip(names, lo, hi, strict=True))


def describe_set(s: SetSpec, names: tuple[str, ...]) -> str:
    """A set in words: a box by its finite sides (``v >= 11``), a polytope by its rows.

    Parameters
    ----------
    s : SetSpec
    names : tuple of str
        The n state names.

    Returns
    -------
    str
    """
    if s.kind == "box":
        parts = []
        for name, a, b in zip(names, s.lower, s.upper, strict=True):
            if np.isfinite(a) and np.isfinite(b):
                parts.append(f"{_g(a)} <= {name} <= {_g(b)}")
            elif np.isfinite(a):
                parts.append(f"{name} >= {_g(a)}")
            elif np.isfinite(b):
                parts.append(f"{name} <= {_g(b)}")
        return ", ".join(parts) if parts else "the whole state space"
    A, b = np.asarray(s.A, dtype=float), np.asarray(s.b, dtype=float)
    if A.shape[0] > 4:
        return f"{A.shape[0]} half-spaces A x <= b"
    rows = []
    for a_row, bi in zip(A, b, strict=True):
        terms = [f"{_g(c)} {name}" for c, name in zip(a_row, names, strict=True) if c != 0]
        rows.append(" + ".join(terms).replace("+ -", "- ") + f" <= {_g(bi)}")
    return " and ".join(rows)


def _inside(a: SetSpec, b: SetSpec) -> bool:
    """Is box ``a`` within box ``b`` (False for polytopes: not decided here)?"""
    if a.kind != "box" or b.kind != "box":
        return False
    return bool(np.all(a.lower >= b.lower) and np.all(a.upper <= b.upper))


def _certificate_words(result: VerificationResult | None) -> str:
    if result is None or result.verdict != "robustly_safe" or result.reason != "invariant":
        verdict = "not proved" if result is not None else "to be proved"
        return f"for all t >= 0 (asked; {verdict} by an invariance certificate)"
    c = result.stats.get("certificate", {}) or {}
    closed = f"sample {c.get('closed_sample')} (t = {float(c.get('closed_time', 0.0)):.4g} s)"
    if c.get("kind") == "ellipsoid":
        how = f"every reach set at {closed} lies in an invariant ellipsoid"
    else:
        how = (f"every reach set at {closed} lies in the set of sample "
               f"{c.get('anchor_sample')}; the tube repeats with period "
               f"{float(c.get('period', 0.0)):.4g} s")
    return f"for all t >= 0 (invariance certificate: {how})"


def build_claim(problem: Problem, result: VerificationResult | None = None) -> Claim:
    """The claim of ``problem``'s verification (and of ``result``, when given).

    Parameters
    ----------
    problem : Problem
        With a ``[verify]`` section.
    result : VerificationResult, optional
        Its verdict, hold and certificate; without it, the claim the spec asks for.

    Returns
    -------
    Claim
    """
    p, vs, mpc = problem.plant, problem.verify, problem.mpc
    if vs is None:
        raise ValueError("the spec has no [verify] section: nothing is claimed")
    states, inputs = p.states, p.inputs
    system = (f"{problem.name} (state{'s' if len(states) > 1 else ''} {', '.join(states)}; "
              f"input{'s' if len(inputs) > 1 else ''} {', '.join(inputs)})")
    initial = [_box(states, vs.initial_lower, vs.initial_upper)]
    # u_prev and r by the law's parameter names (prev_V, ref_y0), as the pictures' sections
    theta = parameter_names(mpc, states, inputs)[len(states):]
    prev = theta[: len(inputs)] if mpc.has_rates else ()
    refs = theta[len(prev):]
    if vs.initial_input_lower is not None:
        initial.append("input before t = 0: " + _box(
            prev or tuple(f"prev_{u}" for u in inputs), vs.initial_input_lower,
            vs.initial_input_upper))
    ref_lo, ref_hi = vs.reference_lower, vs.reference_upper
    if ref_lo is None and mpc.free_reference and mpc.reference is not None:
        ref_lo, ref_hi = mpc.reference.lower, mpc.reference.upper
    if ref_lo is not None:
        names = refs if len(refs) == len(ref_lo) else tuple(f"r{k}" for k in range(len(ref_lo)))
        initial.append("reference (a constant): " + _box(names, ref_lo, ref_hi))
    uncertainty = []
    if p.disturbances is not None:
        from codev_engine.plant import disturbances_matter

        u = p.disturbances
        uncertainty.append("disturbance signal " + _box(u.names, u.lower, u.upper)
                           + (" at every t" if disturbances_matter(p) else
                              ": cannot change the plant (a zero-width box or a zero input), "
                              "verified as the nominal plant"))
    if p.parameters is not None:
        u = p.parameters
        uncertainty.append("parameter value " + _box(u.names, u.lower, u.upper))
    if vs.noise_lower is not None and vs.noisy:
        uncertainty.append("measurement noise " + _box(
            tuple(f"v_{s}" for s in states), vs.noise_lower, vs.noise_upper)
            + " at every sample (the law sees x + v)")

    own = len(problem.own_safe_sets())
    checked = [f"never enters unsafe set {i}: {describe_set(s, states)}"
               for i, s in enumerate(vs.unsafe)]
    for j, s in enumerate(vs.safe):
        what = "stays inside safe set"
        if j >= own:
            what = "stays inside the design's hard bounds (safe set"
            checked.append(f"{what} {j}): {describe_set(s, states)}")
        else:
            checked.append(f"{what} {j}: {describe_set(s, states)}")
    hold = result.hold if result is not None else vs.hold
    if vs.input_bounds:
        lo, hi = np.asarray(mpc.u_min, float), np.asarray(mpc.u_max, float)
        checked.append("the input stays within its bounds: " + _box(inputs, lo, hi))
    # both holds locate the region at the samples only (continuous: fixed for the period)
    checked.append("the law is defined at every sample (the state is in the explicit law's "
                   "domain)")

    T = vs.time_horizon
    time = f"for all t in [0, {_g(T)}] s" if math.isfinite(T) else _certificate_words(result)
    dt = _g(problem.model.sample_time)
    hold_words = (f"zoh: u from the sampled state, held for each period of {dt} s"
                  if hold == "zoh" else f"continuous: u(t) from x(t) (law sampled every {dt} s)")

    not_checked = []
    if not vs.constraints:
        for s in design_safe_sets(mpc):
            if any(_inside(own_set, s) for own_set in vs.safe):
                continue  # a safe set of the spec within these bounds checks them already
            field = "mpc.x_min/x_max" if s.kind == "box" else "mpc.y_min/y_max on y = C x"
            not_checked.append(f"the design's bounds {describe_set(s, states)} ({field}): "
                               "imposed on the predictions only; [verify] constraints = true "
                               "checks them for all t")
    if not vs.input_bounds:
        lo, hi = np.asarray(mpc.u_min, float), np.asarray(mpc.u_max, float)
        if np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)):
            not_checked.append("the input bounds " + _box(inputs, lo, hi)
                               + " (mpc.u_min/u_max); [verify] input_bounds = true checks them")
    if mpc.soft:
        not_checked.append(f"the soft constraints ({', '.join(mpc.soft)}): the design may "
                           "cross them")
    if mpc.du_min is not None or mpc.du_max is not None:
        not_checked.append("the input rate bounds (mpc.du_min/du_max)")
    if mpc.constraints:
        not_checked.append(f"the mixed constraints ([[mpc.constraints]], {len(mpc.constraints)} "
                           "blocks)")
    return Claim(
        system=system,
        verdict=result.verdict if result is not None else None,
        initial=tuple(initial),
        uncertainty=tuple(uncertainty),
        checked=tuple(checked),
        time=time,
        hold=hold_words,
        not_checked=tuple(not_checked),
    )


@dataclass(frozen=True)
class CertificateBand:
    """Where every state lies after an invariance certificate closed (kind ``invariant``).

    The tube's part over one period ``[t_anchor, t_closed]``, shifted by multiples of the
    period, covers every later time (docs/verification.md, "Safety for all time"); so the
    hull of its boxes holds every state for all ``t >= t_anchor``. Drawn from ``t_closed``
    on instead of a repeated tube.

    Attributes
    ----------
    t_anchor, t_closed : float
        The anchor and the closing sample's times (s).
    lower, upper : (n,) ndarray
        The hull of the tube's boxes over ``[t_anchor, t_closed]``.
    """

    t_anchor: float
    t_closed: float
    lower: np.ndarray
    upper: np.ndarray


def certificate_band(result: VerificationResult) -> CertificateBand | None:
    """The band that holds every state after the certificate closed (None without a
    periodic certificate: no certificate, or the nonlinear engine's ellipsoid).

    Parameters
    ----------
    result : VerificationResult

    Returns
    -------
    CertificateBand or None
    """
    c = result.stats.get("certificate") or {}
    if result.certificate is None or c.get("kind") != "invariant" or "anchor_time" not in c:
        return None
    t0, t1 = float(c["anchor_time"]), float(c["closed_time"])
    tube = result.tube
    ts, te = np.asarray(tube.t_start, dtype=float), np.asarray(tube.t_end, dtype=float)
    eps = 1e-9 * max(1.0, abs(t1))
    # the boxes that cover [t0, t1] (each box's interval meets it)
    keep = (te > t0 + eps) & (ts < t1 - eps)
    if not np.any(keep):
        return None
    return CertificateBand(t0, t1, np.min(tube.lower[keep], axis=0),
                           np.max(tube.upper[keep], axis=0))


def ellipsoid_box(result: VerificationResult) -> tuple[np.ndarray, np.ndarray] | None:
    """The bounding box of an invariant ellipsoid certificate (the nonlinear engine's,
    kind ``ellipsoid``), or None without one.

    The ellipsoid ``{x : (x - c)' P (x - c) <= 1}`` holds every state at every sample from
    its closing sample on; its box is ``c +- sqrt(diag(P^-1))`` (the support of ``+-e_i``),
    widened for the inverse's rounding (relative 1e-6 and ``cond(P)`` times the epsilon).

    Parameters
    ----------
    result : VerificationResult

    Returns
    -------
    (lower, upper) : pair of (n,) ndarray, or None
    """
    cert = result.certificate
    if cert is None or "P" not in cert:
        return None
    from codev_engine.reach.terminal import ellipsoid_reach

    c = np.asarray(cert["centre"], dtype=float)
    reach = ellipsoid_reach(cert["P"])
    return c - reach, c + reach


#: what :func:`width_at_end` measured, in words (CLI, ``--json``'s ``width_at.of``, the
#: sweep's ``width_at_horizon_of``, the recording's and the report's summary)
WIDTH_OF_LAST_BOX = "tube's last box"
WIDTH_OF_REPEAT = "tube's last box, a repeat of the certificate's period"
WIDTH_OF_BAND = "certificate band"
WIDTH_OF_ELLIPSOID = "invariant ellipsoid's box"
WIDTH_OF_BOX_AND_ELLIPSOID = "tube's last box and the invariant ellipsoid's box"
WIDTH_OF_NONE = "none"


def width_at_end(problem: Problem, result: VerificationResult) -> tuple[float, np.ndarray, str]:
    """The width, per state, of the set known to hold the state at the end of the view.

    Parameters
    ----------
    problem : Problem
    result : VerificationResult

    Returns
    -------
    t : float
        The end: ``time_horizon``, or the shown horizon for ``"inf"``.
    width : (n,) ndarray
        NaN where nothing is known (no box active at ``t``).
    which : str
        The set measured: :data:`WIDTH_OF_LAST_BOX` (the hull of the tube's boxes active
        at ``t``, the last of each branch), :data:`WIDTH_OF_REPEAT` (the same, when a
        certificate closed before ``t`` and the tube after it repeats its period: sound,
        but not the reach set of ``t`` -- designs compare only on the same kind),
        :data:`WIDTH_OF_BAND` (a tube that stops at the closing sample of a certificate,
        ``time_horizon = "inf"``: :func:`certificate_band`), :data:`WIDTH_OF_ELLIPSOID`
        (the nonlinear engine's invariant ellipsoid closed by ``t``, a sample time:
        :func:`ellipsoid_box`), :data:`WIDTH_OF_BOX_AND_ELLIPSOID` (the hull of both, when
        some of the sets stopped in the ellipsoid before ``t`` and others go on) or
        :data:`WIDTH_OF_NONE` (no box at ``t``: a tube stopped by a violation or a limit).
    """
    from codev_engine.reach.simulate import shown_horizon

    T = shown_horizon(problem)
    tube = result.tube
    covered = tube.num_boxes and float(np.max(tube.t_end)) >= T * (1 - 1e-12)
    band = certificate_band(result)
    if not covered and band is not None and T >= band.t_closed:
        # "inf": the tube stops at the closing sample; the band holds every later state
        return T, band.upper - band.lower, WIDTH_OF_BAND
    # the tube's boxes at T (a finite horizon's tube, repeated after a certificate, is sound
    # and tighter pointwise than the band)
    width = result.width_at(T)
    ell = ellipsoid_box(result)
    if ell is not None:
        # every state at every sample from the closing one on is in the ellipsoid (T, the
        # shown horizon of "inf", is a sample time); before it, a set that stopped in the
        # ellipsoid (per_set) has no box at T, so the hull of both holds the states
        c = result.stats.get("certificate") or {}
        t_closed = float(c.get("closed_time", np.inf))
        k = T / float(problem.model.sample_time)
        at_sample = abs(k - round(k)) <= 1e-9 * max(1.0, k)  # (between samples: in B only)
        if at_sample and T >= t_closed * (1 - 1e-12):
            return T, ell[1] - ell[0], WIDTH_OF_ELLIPSOID
        if at_sample and c.get("per_set"):
            lo, hi = tube.hull_at(T)
            if np.all(np.isfinite(lo)):
                return (T, np.maximum(hi, ell[1]) - np.minimum(lo, ell[0]),
                        WIDTH_OF_BOX_AND_ELLIPSOID)
            return T, ell[1] - ell[0], WIDTH_OF_ELLIPSOID
    if not np.any(np.isfinite(width)):
        return T, width, WIDTH_OF_NONE
    if band is not None and T > band.t_closed * (1 + 1e-12):
        return T, width, WIDTH_OF_REPEAT
    return T, width, WIDTH_OF_LAST_BOX
