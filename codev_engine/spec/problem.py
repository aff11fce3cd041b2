"""The problem a spec describes: frozen plain data (plant, model, MPC, verification).

Parsed and validated by :mod:`codev_engine.spec.parse`; the TOML contract is documented in
``docs/spec.md``. All bounds and sets are in *plant* coordinates (absolute values), never
deviations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "design_safe_sets",
    "parameter_names",
    "PlantSpec",
    "Uncertain",
    "ModelSpec",
    "MpcSpec",
    "MixedConstraint",
    "ReferenceSpec",
    "SetSpec",
    "VerifySpec",
    "Problem",
    "SOFT_GROUPS",
]

#: The constraint groups ``mpc.soft`` may name.
SOFT_GROUPS = ("x_min", "x_max", "y_min", "y_max")


def _since_v2(default):
    """A field added after the first spec contract: omitted from session keys while it
    keeps its default, so that the sessions of older specs keep their keys."""
    return field(default=default, metadata={"key_omit_default": True})


@dataclass(frozen=True)
class Uncertain:
    """Named scalars known only within intervals (``[plant] disturbances`` or ``parameters``).

    Attributes
    ----------
    names : tuple of str
        The d names, in the order the spec's table gives them.
    lower, upper : (d,) ndarray
        The intervals, ``lower <= upper`` (finite).
    nominal : (d,) ndarray
        The values the MPC design uses (``[plant] nominal``; default the midpoints for
        parameters, 0 clipped into the interval for disturbances).
    """

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    nominal: np.ndarray

    @property
    def d(self) -> int:
        """How many names."""
        return len(self.names)

    @property
    def centre(self) -> np.ndarray:
        """(d,) midpoints of the intervals."""
        return 0.5 * (self.lower + self.upper)

    @property
    def radius(self) -> np.ndarray:
        """(d,) half-widths of the intervals."""
        return 0.5 * (self.upper - self.lower)


@dataclass(frozen=True)
class PlantSpec:
    """Continuous-time plant ``dx/dt = f(x, u)`` (the spec's ``[plant]`` table).

    Exactly one of ``dynamics`` and the pair ``A``, ``B`` is set -- unless the model section
    gives an explicit discrete model, in which case both may be absent.

    Attributes
    ----------
    states : tuple of str
        The n state names, in order (``x[0]``, ``x[1]``, ...).
    inputs : tuple of str
        The m input names, in order.
    dynamics : tuple of str or None
        ``f(x, u)``: one expression per state, in the state and input names (parsed by
        :func:`codev_engine.spec.expr.parse_expression`).
    A : (n, n) ndarray or None
        Linear plant ``dx/dt = A x + B u``, with ``B``.
    B : (n, m) ndarray or None
        See ``A``.
    disturbances : Uncertain or None
        Bounded disturbances ``w(t)``: any measurable signal with values in the box (names
        usable in ``dynamics``; with ``A``, ``B`` they enter through ``E``).
    parameters : Uncertain or None
        Uncertain constants of ``dynamics``, fixed during a run.
    E : (n, d) ndarray or None
        A matrix plant's disturbance input: ``dx/dt = A x + B u + E w``.
    state_units, input_units : tuple of str
        Optional units, one per state / input (``plant.state_units``, ``plant.input_units``),
        shown on the pictures' axes; () when not given.

    Notes
    -----
    Every stage that designs (linearisation, the MPC, simulation without a disturbance
    signal) uses the nominal values; the verification covers the whole boxes.
    """

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    dynamics: tuple[str, ...] | None = None
    A: np.ndarray | None = None
    B: np.ndarray | None = None
    disturbances: Uncertain | None = _since_v2(None)
    parameters: Uncertain | None = _since_v2(None)
    E: np.ndarray | None = _since_v2(None)
    state_units: tuple[str, ...] = _since_v2(())
    input_units: tuple[str, ...] = _since_v2(())

    def state_label(self, i: int) -> str:
        """The state's name with its unit, ``v (m/s)`` (the name alone without one).

        Parameters
        ----------
        i : int
            The state's index.

        Returns
        -------
        str
        """
        u = self.state_units[i] if i < len(self.state_units) else ""
        return f"{self.states[i]} ({u})" if u else self.states[i]

    def input_label(self, j: int) -> str:
        """The input's name with its unit, ``F (N)`` (the name alone without one).

        Parameters
        ----------
        j : int
            The input's index.

        Returns
        -------
        str
        """
        u = self.input_units[j] if j < len(self.input_units) else ""
        return f"{self.inputs[j]} ({u})" if u else self.inputs[j]

    @property
    def n(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def m(self) -> int:
        """Number of inputs."""
        return len(self.inputs)

    @property
    def uncertain(self) -> bool:
        """True when the plant has disturbances or uncertain parameters."""
        return self.disturbances is not None or self.parameters is not None

    def nominal_values(self) -> dict[str, float]:
        """The nominal value of every disturbance and parameter name."""
        out: dict[str, float] = {}
        for box in (self.disturbances, self.parameters):
            if box is not None:
                out.update(zip(box.names, (float(v) for v in box.nominal), strict=True))
        return out


@dataclass(frozen=True)
class ModelSpec:
    """Discrete-time prediction model settings (the spec's ``[model]`` table).

    Attributes
    ----------
    sample_time : float
        Sample period of the controller (s), > 0.
    method : str
        Discretisation method, one of :data:`codev_engine.spec.choices.METHODS`.
    x_op : (n,) ndarray
        Operating point state: the linearisation point and the MPC reference (the parser
        gives zeros when the spec has none).
    u_op : (m,) ndarray
        Operating point input, as ``x_op``.
    A : (n, n) ndarray or None
        Explicit discrete model ``x+ = A x + B u``, with ``B``; then the plant is not
        discretised.
    B : (n, m) ndarray or None
        See ``A``.
    """

    sample_time: float
    method: str = "zoh"
    x_op: np.ndarray = field(default_factory=lambda: np.zeros(0))
    u_op: np.ndarray = field(default_factory=lambda: np.zeros(0))
    A: np.ndarray | None = None
    B: np.ndarray | None = None


@dataclass(frozen=True)
class MixedConstraint:
    """Mixed stage constraints ``Hx x_k + Hu u_k <= h``, k = 0..N-1 (plant coordinates).

    An item of ``[[mpc.constraints]]``.

    Attributes
    ----------
    Hx : (c, n) ndarray
    Hu : (c, m) ndarray
    h : (c,) ndarray
    """

    Hx: np.ndarray
    Hu: np.ndarray
    h: np.ndarray


@dataclass(frozen=True)
class ReferenceSpec:
    """What the MPC tracks (the spec's ``[mpc.reference]`` table).

    Attributes
    ----------
    signal : str
        ``"y"`` (the outputs ``C x``; needs ``mpc.C``) or ``"x"`` (the states).
    value : (p,) ndarray or None
        A fixed reference (plant coordinates of the signal).
    lower, upper : (p,) ndarray or None
        The box of a free reference: ``r`` is then a parameter of the law.
    """

    signal: str
    value: np.ndarray | None = None
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    @property
    def free(self) -> bool:
        """True when ``r`` is a parameter of the law (a box), False for a fixed value."""
        return self.value is None


@dataclass(frozen=True)
class MpcSpec:
    """MPC design: horizon, norm, weights and bounds (the spec's ``[mpc]`` table).

    Attributes
    ----------
    horizon : int
        Prediction horizon N (steps), >= 1.
    norm : str
        Norm of the stage and terminal costs: ``"1"``, ``"inf"`` or ``"2"``.
    Q : (q, n) ndarray
        State weight: cost ``x'Qx`` for norm ``"2"`` (then q = n, symmetric positive
        semidefinite), ``||Q x||`` for norms ``"1"`` and ``"inf"``.
    R : (r, m) ndarray
        Input weight, as ``Q`` (positive definite for norm ``"2"``).
    P : (p, n) ndarray or None
        Terminal weight on ``x_N``, as ``Q``; None: no terminal cost.
    x_min, x_max : (n,) ndarray
        State bounds in plant coordinates, on the predicted states; +-inf allowed.
    u_min, u_max : (m,) ndarray
        Input bounds in plant coordinates; +-inf allowed.
    simplify : bool
        Merge the regions of the explicit law that share an affine law.
    domain_bound : float
        Half-width of the box around ``x_op`` on which the explicit law is computed along
        the state axes whose ``x_min``/``x_max`` is infinite (or soft).
    control_horizon : int or None
        Nc in 1..N: ``u_k = u_{Nc-1}`` for ``k >= Nc`` (move blocking); None: N.
    terminal_cost : str or None
        ``"lqr"``: ``P`` is the DARE solution for the prediction model and ``(Q, R)``
        (norm ``"2"``; ``P`` is then None here and computed from the model).
    terminal_set : SetSpec or str or None
        ``x_N`` in this set: a polytope ``A x <= b`` (plant coordinates), or ``"lqr"``, the
        maximal positively invariant set of the LQR loop around the target.
    du_min, du_max : (m,) ndarray or None
        Rate bounds ``du_min <= u_k - u_{k-1} <= du_max``, k = 0..N-1 (+-inf allowed).
    Rd : (m, m) ndarray or None
        Weight on ``u_k - u_{k-1}`` (as ``R``: ``(r, m)`` for norms 1/inf).
    C : (p, n) ndarray or None
        Outputs ``y = C x``.
    y_min, y_max : (p,) ndarray or None
        Output bounds on ``y_0..y_N`` (+-inf allowed).
    soft : tuple of str
        The constraint groups made soft (of :data:`SOFT_GROUPS`).
    soft_weight : float
        l1 weight of the slacks (one slack per soft row and step).
    constraints : tuple of MixedConstraint
        Mixed stage constraints.
    reference : ReferenceSpec or None
        What the MPC tracks; None: regulate to the operating point.

    Notes
    -----
    ``domain_bound`` exists because the parameter set of the multi-parametric program must
    be bounded; the online MPC imposes no such bound.

    The law's parameter is ``theta = (x, u_prev, r)``: ``u_prev`` (the input applied at the
    previous sample) when :attr:`has_rates`, ``r`` when the reference is free.
    """

    horizon: int
    norm: str  # "1", "inf" or "2"
    Q: np.ndarray
    R: np.ndarray
    P: np.ndarray | None
    x_min: np.ndarray
    x_max: np.ndarray
    u_min: np.ndarray
    u_max: np.ndarray
    simplify: bool = False
    # Half-width of the exploration box around x_op on state axes whose x_min/x_max is
    # infinite: the explicit law is computed on that box there (the parameter set must be
    # bounded). Spec field ``mpc.domain_bound``, default 100.
    domain_bound: float = 100.0
    control_horizon: int | None = _since_v2(None)
    terminal_cost: str | None = _since_v2(None)
    terminal_set: SetSpec | str | None = _since_v2(None)
    du_min: np.ndarray | None = _since_v2(None)
    du_max: np.ndarray | None = _since_v2(None)
    Rd: np.ndarray | None = _since_v2(None)
    C: np.ndarray | None = _since_v2(None)
    y_min: np.ndarray | None = _since_v2(None)
    y_max: np.ndarray | None = _since_v2(None)
    soft: tuple[str, ...] = _since_v2(())
    soft_weight: float = _since_v2(1e4)
    constraints: tuple[MixedConstraint, ...] = _since_v2(())
    reference: ReferenceSpec | None = _since_v2(None)

    @property
    def has_rates(self) -> bool:
        """True when the law takes the previous input (any of du_min, du_max, Rd given)."""
        return self.du_min is not None or self.du_max is not None or self.Rd is not None

    @property
    def free_reference(self) -> bool:
        """True when the reference is a parameter of the law (a box)."""
        return self.reference is not None and self.reference.free

    @property
    def Nc(self) -> int:
        """The control horizon (N when not given)."""
        return self.horizon if self.control_horizon is None else self.control_horizon


@dataclass(frozen=True)
class SetSpec:
    """A set in state space: a box ``lower <= x <= upper`` or a polytope ``A x <= b``.

    An item of ``[[verify.unsafe]]`` or ``[[verify.safe]]``; the fields of the other kind
    are None.

    Attributes
    ----------
    kind : str
        ``"box"`` or ``"polytope"``.
    lower, upper : (n,) ndarray or None
        The box's sides (a box); +-inf allowed, an infinite side is unbounded.
    A : (k, n) ndarray or None
        The polytope's rows (a polytope).
    b : (k,) ndarray or None
        The polytope's right-hand side.
    """

    kind: str  # "box" or "polytope"
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    A: np.ndarray | None = None
    b: np.ndarray | None = None

    def halfspaces(self) -> tuple[np.ndarray, np.ndarray]:
        """H-representation of the set; infinite box sides are dropped.

        Returns
        -------
        A : (k, n) ndarray
        b : (k,) ndarray
            The set is ``A x <= b``; a box gives one row per finite side (k may be 0).
        """
        if self.kind == "polytope":
            assert self.A is not None and self.b is not None
            return self.A, self.b
        assert self.lower is not None and self.upper is not None
        n = self.lower.shape[0]
        eye = np.eye(n)
        rows, rhs = [], []
        for i in range(n):
            if np.isfinite(self.upper[i]):
                rows.append(eye[i])
                rhs.append(self.upper[i])
            if np.isfinite(self.lower[i]):
                rows.append(-eye[i])
                rhs.append(-self.lower[i])
        return np.array(rows, dtype=float).reshape(-1, n), np.array(rhs, dtype=float)


@dataclass(frozen=True)
class VerifySpec:
    """Closed-loop verification settings (the spec's ``[verify]`` table).

    Attributes
    ----------
    time_horizon : float
        Length of the verified time interval (s); ``inf`` (the spec's ``"inf"``): safety for
        all time, proved by an invariance certificate.
    initial_lower, initial_upper : (n,) ndarray
        The box of initial states.
    hold : str
        Control between samples: ``"zoh"`` (``u`` held from the sampled state over the
        period) or ``"continuous"`` (``u(t)`` from the current state).
    max_depth : int
        Refinement depth of the initial set.
    step : float
        Time step of the reachtube (s).
    input_bounds : bool
        Also require ``u(t)`` to stay within ``[u_min, u_max]`` at all times.
    unsafe : tuple of SetSpec
        Sets the state must never enter.
    safe : tuple of SetSpec
        Sets the state must always stay inside (every one of them).
    max_samples : int
        With an infinite ``time_horizon``: the samples within which an invariance
        certificate must close (else the verdict is ``unknown``, ``no_invariant``).
    initial_input_lower, initial_input_upper : (m,) ndarray or None
        The input applied before ``t = 0`` (``u_prev`` at the first sample), a box, for a
        law with input rates; None: the operating input.
    reference_lower, reference_upper : (p,) ndarray or None
        The reference, an unknown constant in this box, for a law with a free reference;
        None: the whole box of ``mpc.reference``.
    noise_lower, noise_upper : (n,) ndarray or None
        Measurement noise (``measurement_noise``): at each sample the law sees
        ``x(t_k) + v_k`` with ``v_k`` any value in this box (chosen anew at every sample);
        None: the law sees the state exactly.
    time_budget : float or None
        Seconds the verification may take (``time_budget``); past them the verdict is
        ``unknown`` with reason ``"budget"``, the best margins reached and where the proof
        stopped. None: no budget.
    constraints : bool
        ``[verify] constraints = true``: the last ``safe`` sets are the MPC's own hard state
        and output bounds (:func:`design_safe_sets`) and ``input_bounds`` is on; False: the
        design's constraints are not checked between samples.
    """

    time_horizon: float
    initial_lower: np.ndarray
    initial_upper: np.ndarray
    hold: str = "zoh"  # "zoh" or "continuous"
    max_depth: int = 6
    step: float = 0.01
    input_bounds: bool = False
    unsafe: tuple[SetSpec, ...] = ()
    safe: tuple[SetSpec, ...] = ()
    max_samples: int = 1000
    initial_input_lower: np.ndarray | None = _since_v2(None)
    initial_input_upper: np.ndarray | None = _since_v2(None)
    reference_lower: np.ndarray | None = _since_v2(None)
    reference_upper: np.ndarray | None = _since_v2(None)
    noise_lower: np.ndarray | None = _since_v2(None)
    noise_upper: np.ndarray | None = _since_v2(None)
    time_budget: float | None = _since_v2(None)
    constraints: bool = _since_v2(False)

    @property
    def noisy(self) -> bool:
        """Does the law see the state through measurement noise (a box other than {0})?"""
        return self.noise_lower is not None and bool(
            np.any(self.noise_lower != 0) or np.any(self.noise_upper != 0)
        )


@dataclass(frozen=True)
class Problem:
    """A whole validated spec file.

    All arrays are float64 and read-only; bounds and sets are in plant coordinates.

    Attributes
    ----------
    name : str
        Short identifier of the problem (1-64 letters, digits, ``-``, ``_``, ``.``).
    plant : PlantSpec
    model : ModelSpec
    mpc : MpcSpec
    verify : VerifySpec or None
        None when the spec has no ``[verify]`` table.
    path : str or None
        The file name as given (``"<string>"`` for text parsed without one); None for a
        problem built in code.
    source : str
        The TOML text, for hashing and sessions.
    regions : str
        ``[synthesis] regions``: ``"all"`` (the whole explicit law, the default) or
        ``"reached"`` (the regions the verification's reach sets meet, computed on demand;
        ``codev_engine.law_on_demand``).
    """

    name: str
    plant: PlantSpec
    model: ModelSpec
    mpc: MpcSpec
    verify: VerifySpec | None
    path: str | None = None
    source: str = ""  # the TOML text, for hashing and sessions
    regions: str = "all"

    # Equality is the design's: two problems are equal when every field but ``path`` and
    # ``source`` is (the generated __eq__ compared arrays with ``==`` and raised).
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Problem):
            return NotImplemented
        from codev_engine.spec.toml_out import same_design

        return same_design(self, other)

    def own_safe_sets(self) -> tuple[SetSpec, ...]:
        """The ``[[verify.safe]]`` sets the spec gives, without the design's bounds that
        ``[verify] constraints = true`` appends (:func:`design_safe_sets`).

        Returns
        -------
        tuple of SetSpec
        """
        vs = self.verify
        if vs is None:
            return ()
        if not vs.constraints:
            return vs.safe
        return vs.safe[: len(vs.safe) - len(design_safe_sets(self.mpc))]

    def to_toml(self) -> str:
        """The spec file of this problem: TOML that ``loads_spec`` reads back to an equal
        problem (every default written out, floats exact).

        Returns
        -------
        str
        """
        from codev_engine.spec.toml_out import dumps, problem_data

        return dumps(problem_data(self))

    def replace(self, **changes: object) -> Problem:
        """A new problem with some fields changed, checked as a spec file is.

        Parameters
        ----------
        **changes : object
            Keywords of :func:`codev_engine.design` (``horizon=8``, ``R=[[0.1]]``,
            ``verify_reference=...``), or dotted spec fields (``**{"mpc.R": ...}``); a
            section name (``verify=None``) replaces or drops a whole table; ``None``
            drops a field.

        Returns
        -------
        Problem
            Checked like :func:`codev_engine.load_spec` (fields, size, model, feasibility).

        Raises
        ------
        SpecError
            One bad value, naming its keyword.
        """
        # the design API sits above the pipeline's checks, a layer above this data class:
        # found by name on use, as codev_engine.display finds its drawing backend
        import importlib

        return importlib.import_module("codev_engine.design_api").replace(self, **changes)


def design_safe_sets(mpc: MpcSpec) -> tuple[SetSpec, ...]:
    """The MPC's hard state and output bounds as safe sets (``[verify] constraints = true``).

    The design imposes ``x_min <= x <= x_max`` and ``y_min <= C x <= y_max`` on its
    predictions only; as safe sets the verification checks them on the tube, for all t.
    Soft groups (``mpc.soft``) are left out: the design may cross them.

    Parameters
    ----------
    mpc : MpcSpec

    Returns
    -------
    tuple of SetSpec
        A box (infinite sides for absent bounds) when some state bound is finite, then a
        polytope ``[C; -C] x <= [y_max; -y_min]`` (finite rows only) when some output bound
        is; () when the design has no finite hard bound.
    """
    sets: list[SetSpec] = []
    lo = np.where("x_min" in mpc.soft, -np.inf, np.asarray(mpc.x_min, dtype=float))
    hi = np.where("x_max" in mpc.soft, np.inf, np.asarray(mpc.x_max, dtype=float))
    if np.any(np.isfinite(lo)) or np.any(np.isfinite(hi)):
        sets.append(SetSpec("box", lower=_read_only(lo), upper=_read_only(hi)))
    if mpc.C is not None and mpc.y_min is not None and mpc.y_max is not None:
        C = np.asarray(mpc.C, dtype=float)
        ylo = np.where("y_min" in mpc.soft, -np.inf, np.asarray(mpc.y_min, dtype=float))
        yhi = np.where("y_max" in mpc.soft, np.inf, np.asarray(mpc.y_max, dtype=float))
        A = np.vstack([C, -C])
        b = np.concatenate([yhi, -ylo])
        keep = np.isfinite(b)
        if np.any(keep):
            sets.append(SetSpec("polytope", A=_read_only(A[keep]), b=_read_only(b[keep])))
    return tuple(sets)


def _read_only(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


def parameter_names(spec: MpcSpec, states: tuple[str, ...], inputs: tuple[str, ...]
                    ) -> tuple[str, ...]:
    """Names of ``theta``: the states, ``prev_<input>``, ``ref_<state or y index>``.

    Parameters
    ----------
    spec : MpcSpec
    states, inputs : tuple of str

    Returns
    -------
    tuple of str
    """
    names = list(states)
    if spec.has_rates:
        names += [f"prev_{u}" for u in inputs]
    if spec.free_reference:
        ref = spec.reference
        assert ref is not None and ref.lower is not None
        if ref.signal == "x":
            names += [f"ref_{s}" for s in states]
        else:
            names += [f"ref_y{i}" for i in range(ref.lower.shape[0])]
    return tuple(names)
