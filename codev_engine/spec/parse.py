"""The spec parser: TOML text -> a validated :class:`~codev_engine.spec.problem.Problem`.

The TOML contract is documented in ``docs/spec.md``. The parser validates every field of the
file before any work starts, so a bad spec fails fast with one ``SpecError`` naming the file,
the field and the reason. It runs no later stage: whether the plant is linearisable and the
MPC feasible is checked by the stages that need it (``codev_engine.pipeline``).
"""

from __future__ import annotations

import difflib
import keyword
import math
import re
import sys
import tomllib
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.spec.choices import HOLDS, METHODS, NORMS, REGIONS, RESERVED_NAMES
from codev_engine.spec.problem import (
    SOFT_GROUPS,
    MixedConstraint,
    ModelSpec,
    MpcSpec,
    PlantSpec,
    Problem,
    ReferenceSpec,
    SetSpec,
    Uncertain,
    VerifySpec,
    design_safe_sets,
    parameter_names,
)

__all__ = ["read_spec", "parse_spec", "build_spec", "FIELDS"]


# --------------------------------------------------------------------------------------------
# Loader
# --------------------------------------------------------------------------------------------


_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")
_IDENT_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
DEFAULT_HORIZON = 5  # mpc.horizon when the spec leaves it out (docs/spec.md)
DEFAULT_NORM = "2"  # mpc.norm when the spec leaves it out: the quadratic cost (docs/spec.md)
_MAX_COUNT = 10**9  # the largest count field (mpc.horizon, verify.max_depth, ...) read
_SYM_TOL = 1e-9  # relative tolerance of the symmetry / definiteness checks (norm "2")

_TOP = ("name", "plant", "model", "mpc", "verify", "synthesis")
_PLANT = (
    "states", "inputs", "dynamics", "A", "B", "disturbances", "parameters", "nominal", "E",
    "state_units", "input_units",
)  # fmt: skip
_MODEL = ("sample_time", "method", "operating_point", "A", "B")
_MPC = (
    "horizon", "norm", "Q", "R", "P", "x_min", "x_max", "u_min", "u_max", "simplify",
    "domain_bound", "control_horizon", "terminal_set", "du_min", "du_max", "Rd", "C",
    "y_min", "y_max", "soft", "soft_weight", "constraints", "reference",
)  # fmt: skip
_VERIFY = (
    "time_horizon", "hold", "max_depth", "step", "initial_set", "input_bounds", "unsafe", "safe",
    "max_samples", "initial_input", "reference", "measurement_noise", "time_budget",
    "constraints",
)  # fmt: skip
#: every field of every table, by table ("" holds the top level's)
FIELDS: dict[str, tuple[str, ...]] = {
    "": _TOP, "plant": _PLANT, "model": _MODEL, "mpc": _MPC, "verify": _VERIFY,
    "synthesis": ("regions",),
}  # fmt: skip


def read_spec(path: str | Path) -> Problem:
    """Read a spec TOML file and validate its fields.

    Only the fields are checked here (types, shapes, values, names). The checks that need a
    later stage -- the plant is linearisable at the operating point, the MPC is feasible
    somewhere -- are run by that stage; :func:`codev_engine.pipeline.load_spec` runs them all.

    Parameters
    ----------
    path : str or Path
        The spec file.

    Returns
    -------
    Problem
        The validated problem; ``source`` is the file text and ``path`` is ``str(path)``.

    Raises
    ------
    SpecError
        The first problem found in the file (unreadable file, TOML syntax, unknown or missing
        field, wrong type, shape or value), naming the file and the dotted field.
    """
    file = str(path)
    try:
        raw = Path(path).read_bytes()
    except FileNotFoundError:
        raise SpecError("file not found", file=file) from None
    except OSError as exc:
        raise SpecError(f"cannot read the file: {exc.strerror or exc}", file=file) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(
            f"the file is not UTF-8 text ({exc.reason} at byte {exc.start})", file=file
        ) from None
    return parse_spec(text, path=file)


def parse_spec(text: str, *, path: str = "<string>") -> Problem:
    """Parse a spec given as TOML text and validate its fields (see :func:`read_spec`).

    Parameters
    ----------
    text : str
        The TOML document.
    path : str, optional
        Name used for ``Problem.path`` and in error messages.

    Returns
    -------
    Problem
        The validated problem.

    Raises
    ------
    SpecError
        As :func:`read_spec`.
    """
    file = str(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        if "line" not in msg:  # "(at end of document)"
            msg += f" (line {max(1, len(text.splitlines()))}, end of file)"
        raise SpecError(f"invalid TOML: {msg}", file=file) from None
    except RecursionError:
        raise SpecError("invalid TOML: arrays or tables nested too deeply", file=file) from None
    except ValueError as exc:  # tomllib's int(): more digits than sys.get_int_max_str_digits()
        raise SpecError(f"invalid TOML: {_too_many_digits(text, exc)}", file=file) from None
    return build_spec(data, source=text, path=file)


def build_spec(data: dict[str, Any], *, source: str, path: str | None = None) -> Problem:
    """Validate spec data already read (the dict ``tomllib`` gives) into a problem.

    The same checks and messages as :func:`parse_spec`, which calls it: the design API
    (:mod:`codev_engine.design_api`) builds this dict from keywords.

    Parameters
    ----------
    data : dict
        The spec's tables, as ``tomllib.loads`` returns them.
    source : str
        The TOML text of ``data``, kept as ``Problem.source``.
    path : str, optional
        ``Problem.path`` and the file errors name (None: errors name only the field).

    Returns
    -------
    Problem

    Raises
    ------
    SpecError
        The first bad field, named by its dotted name.
    """
    if not isinstance(data, dict):
        raise SpecError(f"expected a table, got {_kind(data)}", file=path)
    try:
        problem = _build(data, source, path or "<string>")
    except SpecError as exc:
        raise (exc.with_file(path) if exc.file is None and path else exc) from None
    if path is None:
        import dataclasses

        problem = dataclasses.replace(problem, path=None)
    return problem


def _too_many_digits(text: str, exc: ValueError) -> str:
    """The reason of tomllib's ``ValueError`` on an integer too long to convert, located."""
    digits = sys.get_int_max_str_digits() or 4300
    found = re.search(rf"[0-9_]{{{digits + 1},}}", text)
    if found is None:  # pragma: no cover - tomllib raises no other ValueError
        return f"a value cannot be read ({exc})"
    line = text.count("\n", 0, found.start()) + 1
    column = found.start() - (text.rfind("\n", 0, found.start()) + 1) + 1
    return (
        f"an integer with more than {digits:,} digits (at line {line}, column {column}); "
        "write large numbers as floats (1e30)"
    )


# --- building the problem -------------------------------------------------------------------


def _build(data: dict[str, Any], text: str, file: str) -> Problem:
    _table(data, "", required=("name", "plant", "model", "mpc"), optional=("verify", "synthesis"))
    name = _spec_name(data["name"], "name")
    plant_t = _table(
        data["plant"], "plant", required=("states", "inputs"), optional=_PLANT[2:]
    )
    model_t = _table(
        data["model"],
        "model",
        required=("sample_time",),
        optional=("method", "operating_point", "A", "B"),
    )
    states = _names(plant_t["states"], "plant.states")
    inputs = _names(plant_t["inputs"], "plant.inputs")
    clash = sorted(set(states) & set(inputs))
    if clash:
        raise SpecError(f"{clash[0]!r} is both a state and an input", field="plant.inputs")
    n, m = len(states), len(inputs)

    model = _model(model_t, n, m)
    plant = _plant(plant_t, states, inputs, explicit=model.A is not None)
    mpc = _mpc(
        _table(
            data["mpc"],
            "mpc",
            required=(),
            optional=_MPC,
        ),
        n,
        m,
    )
    _distinct_theta(mpc, states, inputs)
    verify = None
    if "verify" in data:
        verify = _verify(data["verify"], n)
        verify = _verify_theta(data["verify"], verify, mpc, m)
        verify = _verify_constraints(data["verify"], verify, mpc)
        if mpc.has_rates and verify.hold == "continuous":
            raise SpecError(
                'input rates (du_min, du_max, Rd) need a sampled controller: hold = "continuous" '
                "has no previous input",
                field="verify.hold",
            )
        if plant.dynamics is None and plant.A is None:
            raise SpecError(
                "verification needs the continuous-time plant: give plant.dynamics or "
                "plant.A and plant.B (an explicit discrete model is not enough)",
                field="verify",
            )
    synthesis_t = _table(data.get("synthesis", {}), "synthesis", optional=("regions",))
    regions = _choice(synthesis_t.get("regions", "all"), "synthesis.regions", REGIONS)
    return Problem(
        name=name, plant=plant, model=model, mpc=mpc, verify=verify, path=file, source=text,
        regions=regions,
    )


def _distinct_theta(mpc: MpcSpec, states: tuple[str, ...], inputs: tuple[str, ...]) -> None:
    """Refuse names that make two entries of theta share a name (a state ``prev_u`` beside
    an input ``u`` with input rates, or ``ref_x1`` beside a state ``x1`` with a free
    reference): the law, its printout, its export and the workbench's axes go by name."""
    names = parameter_names(mpc, states, inputs)
    seen: set[str] = set()
    for name in names:
        if name in seen:
            raise SpecError(
                f"the state name {name!r} is also the name the law gives a parameter of theta "
                "(prev_<input> with input rates, ref_<state> or ref_y<i> with a free reference):"
                " rename the state",
                field="plant.states",
            )
        seen.add(name)


def _plant(
    t: dict[str, Any], states: tuple[str, ...], inputs: tuple[str, ...], *, explicit: bool
) -> PlantSpec:
    n, m = len(states), len(inputs)
    has_dyn = "dynamics" in t
    has_ab = "A" in t or "B" in t
    if has_dyn and has_ab:
        key = "A" if "A" in t else "B"
        raise SpecError(
            "give either dynamics or the matrices A and B, not both", field=f"plant.{key}"
        )
    dynamics = A = B = None
    disturbances = _uncertain(t, "disturbances", (*states, *inputs))
    taken = (*states, *inputs, *(disturbances.names if disturbances else ()))
    parameters = _uncertain(t, "parameters", taken)
    disturbances, parameters = _nominal(t, disturbances, parameters)
    if parameters is not None and not has_dyn:
        raise SpecError(
            "uncertain parameters appear in dynamics expressions: give plant.dynamics",
            field="plant.parameters",
        )
    if has_dyn and "E" in t:
        raise SpecError(
            "E goes with the matrices A and B; with dynamics, use the disturbance names in "
            "the expressions",
            field="plant.E",
        )
    E = None
    if "E" in t:
        if disturbances is None:
            raise SpecError(
                "E needs the disturbances it multiplies: give plant.disturbances",
                field="plant.E",
            )
        E = _matrix(t["E"], "plant.E", n, disturbances.d)
    elif disturbances is not None and not has_dyn:
        raise SpecError(
            "a matrix plant's disturbances enter through E (n x d, dx/dt = A x + B u + E w): "
            "give plant.E",
            field="plant.E",
        )
    if has_dyn:
        dyn = t["dynamics"]
        if not isinstance(dyn, list):
            raise SpecError(
                f"expected a list of {_count(n, 'expression string')}, got {_kind(dyn)}",
                field="plant.dynamics",
            )
        if len(dyn) != n:
            raise SpecError(
                f"expected {_count(n, 'expression')} (one per state: {', '.join(states)}), "
                f"got {len(dyn)}",
                field="plant.dynamics",
            )
        # sympy (~1 s of imports) only for a spec with dynamics
        from codev_engine.spec.expr import make_symbol, parse_expression

        symbols = {s: make_symbol(s) for s in (*states, *inputs)}
        for box in (disturbances, parameters):
            symbols.update({s: make_symbol(s) for s in (box.names if box else ())})
        for i, item in enumerate(dyn):
            f = f"plant.dynamics[{i}]"
            if not isinstance(item, str):
                raise SpecError(f"expected an expression string, got {_kind(item)}", field=f)
            parse_expression(item, symbols, field=f)
        dynamics = tuple(dyn)
    elif has_ab:
        for key in ("A", "B"):
            if key not in t:
                raise SpecError(
                    "missing required field (A and B go together)", field=f"plant.{key}"
                )
        A = _matrix(t["A"], "plant.A", n, n)
        B = _matrix(t["B"], "plant.B", n, m)
    elif not explicit:
        raise SpecError(
            "missing the dynamics: give plant.dynamics, or plant.A and plant.B, "
            "or an explicit discrete model (model.A, model.B)",
            field="plant.dynamics",
        )
    return PlantSpec(
        states=states,
        inputs=inputs,
        dynamics=dynamics,
        A=A,
        B=B,
        disturbances=disturbances,
        parameters=parameters,
        E=E,
        state_units=_units(t, "state_units", states),
        input_units=_units(t, "input_units", inputs),
    )


def _units(t: dict[str, Any], key: str, names: tuple[str, ...]) -> tuple[str, ...]:
    """``plant.state_units`` / ``plant.input_units``: one label per name ("" for none),
    shown on the axes; plain text, never evaluated."""
    field = f"plant.{key}"
    if key not in t:
        return ()
    value = t[key]
    if not isinstance(value, list) or not all(isinstance(u, str) for u in value):
        raise SpecError(f"expected a list of strings (one unit per name), got {_kind(value)}",
                        field=field)
    if len(value) != len(names):
        raise SpecError(f"expected {len(names)} units (one per name: {', '.join(names)}), "
                        f"got {len(value)}", field=field)
    for i, u in enumerate(value):
        if len(u) > 32 or any(not c.isprintable() for c in u):
            raise SpecError("a unit is at most 32 printable characters", field=f"{field}[{i}]")
    return tuple(value)


def _uncertain(t: dict[str, Any], key: str, taken: tuple[str, ...]) -> Uncertain | None:
    """``plant.disturbances`` / ``plant.parameters``: ``{ name = [lower, upper], ... }``."""
    field = f"plant.{key}"
    if key not in t:
        return None
    value = t[key]
    if not isinstance(value, dict):
        raise SpecError(
            f"expected a table of intervals {{ name = [lower, upper] }}, got {_kind(value)}",
            field=field,
        )
    if not value:
        raise SpecError("the table is empty (leave the field out instead)", field=field)
    names = _names(list(value), field)
    lower, upper = [], []
    for name in names:
        f = f"{field}.{name}"
        if name in taken:
            raise SpecError(
                f"{name!r} is already a state, input or disturbance name", field=f
            )
        iv = _vector(value[name], f, 2)
        if iv[0] > iv[1]:
            raise SpecError(
                f"expected [lower, upper] with lower <= upper, got [{iv[0]:g}, {iv[1]:g}]",
                field=f,
            )
        if not math.isfinite(float(iv[1]) - float(iv[0])):  # +-1e308: bounds overflow
            raise SpecError(
                f"the interval [{iv[0]:g}, {iv[1]:g}] is too wide to compute with (its "
                "width passes 1.8e308)",
                field=f,
            )
        lower.append(iv[0])
        upper.append(iv[1])
    lo, hi = np.array(lower, dtype=float), np.array(upper, dtype=float)
    nominal = 0.5 * (lo + hi) if key == "parameters" else np.clip(0.0, lo, hi)
    return Uncertain(names, _frozen(lo), _frozen(hi), nominal)


def _nominal(
    t: dict[str, Any], disturbances: Uncertain | None, parameters: Uncertain | None
) -> tuple[Uncertain | None, Uncertain | None]:
    """``plant.nominal``: the design values of some disturbances and parameters."""
    field = "plant.nominal"
    value = t.get("nominal", {})
    if not isinstance(value, dict):
        raise SpecError(f"expected a table {{ name = value }}, got {_kind(value)}", field=field)
    boxes = [b for b in (disturbances, parameters) if b is not None]
    known = [nm for b in boxes for nm in b.names]
    if value and not known:
        raise SpecError(
            "nominal values need plant.disturbances or plant.parameters", field=field
        )
    for name in value:
        if name not in known:
            close = difflib.get_close_matches(str(name), known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise SpecError(
                f"{name!r} is not a disturbance or parameter (known: {', '.join(known)}){hint}",
                field=f"{field}.{name}",
            )
    out = []
    for box in (disturbances, parameters):
        if box is None:
            out.append(None)
            continue
        nom = np.array(box.nominal, dtype=float)
        for j, name in enumerate(box.names):
            if name in value:
                v = _number(value[name], f"{field}.{name}")
                if not box.lower[j] <= v <= box.upper[j]:
                    raise SpecError(
                        f"must lie in the interval [{box.lower[j]:g}, {box.upper[j]:g}], "
                        f"got {v:g}",
                        field=f"{field}.{name}",
                    )
                nom[j] = v
        out.append(Uncertain(box.names, box.lower, box.upper, _frozen(nom)))
    return out[0], out[1]


def _model(t: dict[str, Any], n: int, m: int) -> ModelSpec:
    dt = _positive(t["sample_time"], "model.sample_time")
    method = _choice(t.get("method", "zoh"), "model.method", METHODS)
    x_op, u_op = np.zeros(n), np.zeros(m)
    if "operating_point" in t:
        op = _table(t["operating_point"], "model.operating_point", optional=("x", "u"))
        if "x" in op:
            x_op = _vector(op["x"], "model.operating_point.x", n)
        if "u" in op:
            u_op = _vector(op["u"], "model.operating_point.u", m)
    A = B = None
    if "A" in t or "B" in t:
        for key in ("A", "B"):
            if key not in t:
                raise SpecError(
                    "missing required field (A and B go together)", field=f"model.{key}"
                )
        A = _matrix(t["A"], "model.A", n, n)
        B = _matrix(t["B"], "model.B", n, m)
    return ModelSpec(
        sample_time=dt, method=method, x_op=_frozen(x_op), u_op=_frozen(u_op), A=A, B=B
    )


def _mpc(t: dict[str, Any], n: int, m: int) -> MpcSpec:
    # documented defaults (docs/spec.md): horizon 5, Q and R identities
    horizon = _integer(t.get("horizon", DEFAULT_HORIZON), "mpc.horizon", minimum=1)
    norm = _norm(t.get("norm", DEFAULT_NORM), "mpc.norm")
    square = norm == "2"
    Q = _matrix(t["Q"], "mpc.Q", n if square else None, n) if "Q" in t else _frozen(np.eye(n))
    R = _matrix(t["R"], "mpc.R", m if square else None, m) if "R" in t else _frozen(np.eye(m))
    P, terminal_cost = None, None
    if "P" in t and t["P"] == "lqr":
        if not square:
            raise SpecError(
                f'P = "lqr" needs norm "2" (the Riccati solution is a quadratic cost), not '
                f'"{norm}"',
                field="mpc.P",
            )
        terminal_cost = "lqr"
    elif "P" in t:
        if isinstance(t["P"], str):
            raise SpecError(f'expected "lqr" or a matrix, got {_kind(t["P"])}', field="mpc.P")
        P = _matrix(t["P"], "mpc.P", n if square else None, n)
    if square:
        _psd(Q, "Q", "mpc.Q", definite=False)
        _psd(R, "R", "mpc.R", definite=True)
        if P is not None:
            _psd(P, "P", "mpc.P", definite=False)
    x_min, x_max = _bounds(t, "x", n)
    u_min, u_max = _bounds(t, "u", m)
    simplify = _boolean(t.get("simplify", False), "mpc.simplify")
    domain_bound = _positive(t.get("domain_bound", 100.0), "mpc.domain_bound")
    control_horizon = None
    if "control_horizon" in t:
        control_horizon = _integer(t["control_horizon"], "mpc.control_horizon", minimum=1)
        if control_horizon > horizon:
            raise SpecError(
                f"must be at most the horizon ({horizon}), got {control_horizon}",
                field="mpc.control_horizon",
            )
    terminal_set: SetSpec | str | None = None
    if "terminal_set" in t:
        ts = t["terminal_set"]
        if ts == "lqr":
            terminal_set = "lqr"
        elif isinstance(ts, dict):
            terminal_set = _set(ts, "mpc.terminal_set", n)
        else:
            raise SpecError(
                f'expected "lqr" or a table {{ A = [[...]], b = [...] }}, got {_kind(ts)}',
                field="mpc.terminal_set",
            )
    du_min = du_max = None
    if "du_min" in t or "du_max" in t:
        du_min, du_max = _bounds(t, "du", m)
        for i in range(m):
            if not du_min[i] <= 0.0 <= du_max[i]:
                raise SpecError(
                    f"the rate bounds must allow a constant input (du_min[{i}] <= 0 <= "
                    f"du_max[{i}]), got [{du_min[i]:g}, {du_max[i]:g}]",
                    field=f"mpc.du_min[{i}]" if du_min[i] > 0 else f"mpc.du_max[{i}]",
                )
    Rd = None
    if "Rd" in t:
        Rd = _matrix(t["Rd"], "mpc.Rd", m if square else None, m)
        if square:
            _psd(Rd, "Rd", "mpc.Rd", definite=False)
    C = _matrix(t["C"], "mpc.C", None, n) if "C" in t else None
    y_min = y_max = None
    if "y_min" in t or "y_max" in t:
        if C is None:
            key = "y_min" if "y_min" in t else "y_max"
            raise SpecError("output bounds need the outputs: give mpc.C", field=f"mpc.{key}")
        y_min, y_max = _bounds(t, "y", C.shape[0])
    soft = _soft(t.get("soft", []), x_min, x_max, y_min, y_max)
    soft_weight = _positive(t.get("soft_weight", 1e4), "mpc.soft_weight")
    constraints = _constraints(t.get("constraints", []), n, m)
    reference = None
    if "reference" in t:
        reference = _reference(t["reference"], n, C)
    return MpcSpec(
        horizon=horizon,
        norm=norm,
        Q=Q,
        R=R,
        P=P,
        x_min=x_min,
        x_max=x_max,
        u_min=u_min,
        u_max=u_max,
        simplify=simplify,
        domain_bound=domain_bound,
        control_horizon=control_horizon,
        terminal_cost=terminal_cost,
        terminal_set=terminal_set,
        du_min=du_min,
        du_max=du_max,
        Rd=Rd,
        C=C,
        y_min=y_min,
        y_max=y_max,
        soft=soft,
        soft_weight=soft_weight,
        constraints=constraints,
        reference=reference,
    )


def _soft(
    value: Any,
    x_min: np.ndarray,
    x_max: np.ndarray,
    y_min: np.ndarray | None,
    y_max: np.ndarray | None,
) -> tuple[str, ...]:
    field = "mpc.soft"
    if not isinstance(value, list):
        raise SpecError(f"expected a list of constraint groups, got {_kind(value)}", field=field)
    groups = {"x_min": x_min, "x_max": x_max, "y_min": y_min, "y_max": y_max}
    out: list[str] = []
    for i, g in enumerate(value):
        if not isinstance(g, str) or g not in SOFT_GROUPS:
            allowed = ", ".join(f'"{c}"' for c in SOFT_GROUPS)
            raise SpecError(f"expected one of {allowed}, got {_kind(g)}", field=f"{field}[{i}]")
        if g in out:
            raise SpecError(f"{g!r} is listed twice", field=f"{field}[{i}]")
        bounds = groups[g]
        if bounds is None or not np.any(np.isfinite(bounds)):
            raise SpecError(f"{g!r} names no constraint (no finite mpc.{g})", field=f"{field}[{i}]")
        out.append(g)
    return tuple(out)


def _constraints(value: Any, n: int, m: int) -> tuple[MixedConstraint, ...]:
    field = "mpc.constraints"
    if not isinstance(value, list):
        raise SpecError(
            f"expected an array of tables ([[mpc.constraints]] blocks), got {_kind(value)}",
            field=field,
        )
    out = []
    for i, item in enumerate(value):
        f = f"{field}[{i}]"
        c = _table(item, f, required=("h",), optional=("Hx", "Hu"))
        if "Hx" not in c and "Hu" not in c:
            raise SpecError("give Hx, Hu or both (Hx x_k + Hu u_k <= h)", field=f)
        h = c["h"]
        if not isinstance(h, list) or not h:
            raise SpecError(f"expected a non-empty list of numbers, got {_kind(h)}", field=f"{f}.h")
        k = len(h)
        hv = _vector(h, f"{f}.h", k)
        Hx = _matrix(c["Hx"], f"{f}.Hx", k, n) if "Hx" in c else _frozen(np.zeros((k, n)))
        Hu = _matrix(c["Hu"], f"{f}.Hu", k, m) if "Hu" in c else _frozen(np.zeros((k, m)))
        out.append(MixedConstraint(Hx=Hx, Hu=Hu, h=hv))
    return tuple(out)


def _reference(value: Any, n: int, C: np.ndarray | None) -> ReferenceSpec:
    field = "mpc.reference"
    t = _table(value, field, required=("signal",), optional=("value", "lower", "upper"))
    signal = _choice(t["signal"], f"{field}.signal", ("y", "x"))
    if signal == "y" and C is None:
        raise SpecError('signal = "y" follows the outputs: give mpc.C', field=f"{field}.signal")
    p = n if signal == "x" else int(C.shape[0])  # type: ignore[union-attr]
    box = "lower" in t or "upper" in t
    if "value" in t and box:
        raise SpecError("give either value (fixed) or lower/upper (a box), not both", field=field)
    if "value" in t:
        return ReferenceSpec(signal=signal, value=_vector(t["value"], f"{field}.value", p))
    if not box:
        raise SpecError("give value (a fixed reference) or lower and upper (a box)", field=field)
    for key in ("lower", "upper"):
        if key not in t:
            raise SpecError(
                "missing required field (lower and upper go together)", field=f"{field}.{key}"
            )
    lower = _vector(t["lower"], f"{field}.lower", p)
    upper = _vector(t["upper"], f"{field}.upper", p)
    _ordered(lower, upper, f"{field}.lower", "lower", "upper")
    return ReferenceSpec(signal=signal, lower=lower, upper=upper)


def _verify(value: Any, n: int) -> VerifySpec:
    t = _table(
        value,
        "verify",
        required=("time_horizon", "initial_set"),
        optional=tuple(k for k in _VERIFY if k not in ("time_horizon", "initial_set")),
    )
    raw = t["time_horizon"]
    if isinstance(raw, str) and raw.strip().lower() == "inf":
        raw = math.inf  # safety for all time: an invariance certificate or unknown
    if isinstance(raw, float) and math.isinf(raw) and raw > 0:
        horizon = math.inf
    else:
        horizon = _positive(raw, "verify.time_horizon")
    max_samples = _integer(t.get("max_samples", 1000), "verify.max_samples", minimum=1)
    hold = _choice(t.get("hold", "zoh"), "verify.hold", HOLDS)
    max_depth = _integer(t.get("max_depth", 6), "verify.max_depth", minimum=0)
    step = _positive(t.get("step", 0.01), "verify.step")
    if horizon < step:
        raise SpecError(
            f"horizon shorter than one step (time_horizon = {horizon:g} < step = {step:g})",
            field="verify.time_horizon",
        )
    init = _table(t["initial_set"], "verify.initial_set", required=("lower", "upper"))
    lower = _vector(init["lower"], "verify.initial_set.lower", n)
    upper = _vector(init["upper"], "verify.initial_set.upper", n)
    _ordered(lower, upper, "verify.initial_set.lower", "lower", "upper")
    input_bounds = _boolean(t.get("input_bounds", False), "verify.input_bounds")
    unsafe = _sets(t.get("unsafe", []), "verify.unsafe", n)
    safe = _sets(t.get("safe", []), "verify.safe", n)
    noise: dict[str, np.ndarray] = {}
    if "measurement_noise" in t:
        f = "verify.measurement_noise"
        b = _table(t["measurement_noise"], f, required=("lower", "upper"))
        nlo = _vector(b["lower"], f"{f}.lower", n)
        nhi = _vector(b["upper"], f"{f}.upper", n)
        _ordered(nlo, nhi, f"{f}.lower", "lower", "upper")
        noise = {"noise_lower": nlo, "noise_upper": nhi}
    budget = None
    if "time_budget" in t:  # seconds of the verification; past them a verdict (unknown)
        budget = _positive(t["time_budget"], "verify.time_budget")
    return VerifySpec(
        time_horizon=horizon,
        initial_lower=_frozen(lower),
        initial_upper=_frozen(upper),
        hold=hold,
        max_depth=max_depth,
        step=step,
        input_bounds=input_bounds,
        unsafe=unsafe,
        safe=safe,
        max_samples=max_samples,
        time_budget=budget,
        **noise,
    )


def _verify_constraints(t: dict[str, Any], verify: VerifySpec, mpc: MpcSpec) -> VerifySpec:
    """``constraints = true``: the MPC's hard bounds become properties checked for all t."""
    import dataclasses

    if not _boolean(t.get("constraints", False), "verify.constraints"):
        return verify
    extra = design_safe_sets(mpc)
    return dataclasses.replace(
        verify, safe=verify.safe + extra, input_bounds=True, constraints=True
    )


def _verify_theta(t: dict[str, Any], verify: VerifySpec, mpc: MpcSpec, m: int) -> VerifySpec:
    """``initial_input`` and ``reference``: the law's parameters after the state."""
    import dataclasses

    changes: dict[str, np.ndarray] = {}
    if "initial_input" in t:
        field = "verify.initial_input"
        if not mpc.has_rates:
            raise SpecError(
                "the law takes no previous input (give du_min, du_max or Rd in [mpc])",
                field=field,
            )
        lo, hi = _value_or_box(t["initial_input"], field, m)
        bad = np.flatnonzero((lo < mpc.u_min) | (hi > mpc.u_max))
        if bad.size:
            i = int(bad[0])
            raise SpecError(
                f"input {i} is outside the input bounds [{mpc.u_min[i]:g}, {mpc.u_max[i]:g}] "
                "(the law's domain in the previous input)",
                field=field,
            )
        changes.update(initial_input_lower=lo, initial_input_upper=hi)
    if "reference" in t:
        field = "verify.reference"
        ref = mpc.reference
        if ref is None or not ref.free:
            raise SpecError(
                "the law takes no reference (give [mpc.reference] with lower and upper)",
                field=field,
            )
        assert ref.lower is not None and ref.upper is not None
        lo, hi = _value_or_box(t["reference"], field, ref.lower.shape[0])
        if np.any(lo < ref.lower) or np.any(hi > ref.upper):
            raise SpecError("must lie inside the box of mpc.reference", field=field)
        changes.update(reference_lower=lo, reference_upper=hi)
    return dataclasses.replace(verify, **changes) if changes else verify


def _value_or_box(value: Any, field: str, k: int) -> tuple[np.ndarray, np.ndarray]:
    """A list of k numbers (one value) or ``{ lower, upper }``."""
    if isinstance(value, dict):
        b = _table(value, field, required=("lower", "upper"))
        lo = _vector(b["lower"], f"{field}.lower", k)
        hi = _vector(b["upper"], f"{field}.upper", k)
        _ordered(lo, hi, f"{field}.lower", "lower", "upper")
        return lo, hi
    v = _vector(value, field, k)
    return v, v


def _sets(value: Any, field: str, n: int) -> tuple[SetSpec, ...]:
    if not isinstance(value, list):
        name = field.rsplit(".", 1)[-1]
        raise SpecError(
            f"expected an array of tables ([[verify.{name}]] blocks), got {_kind(value)}",
            field=field,
        )
    return tuple(_set(item, f"{field}[{i}]", n) for i, item in enumerate(value))


def _set(value: Any, field: str, n: int) -> SetSpec:
    t = _table(value, field, optional=("lower", "upper", "A", "b"))
    box = "lower" in t or "upper" in t
    poly = "A" in t or "b" in t
    if box and poly:
        raise SpecError(
            "give either lower/upper (a box) or A/b (a polytope A x <= b), not both", field=field
        )
    if not box and not poly:
        raise SpecError(
            "empty set description: give lower/upper (a box) or A/b (a polytope)", field=field
        )
    if box:
        for key in ("lower", "upper"):
            if key not in t:
                raise SpecError(
                    "missing required field (lower and upper go together)", field=f"{field}.{key}"
                )
        lower = _vector(t["lower"], f"{field}.lower", n, allow_inf=True)
        upper = _vector(t["upper"], f"{field}.upper", n, allow_inf=True)
        _no_wrong_inf(lower, f"{field}.lower", "lower", +1)
        _no_wrong_inf(upper, f"{field}.upper", "upper", -1)
        _ordered(lower, upper, f"{field}.lower", "lower", "upper")
        return SetSpec(kind="box", lower=_frozen(lower), upper=_frozen(upper))
    for key in ("A", "b"):
        if key not in t:
            raise SpecError("missing required field (A and b go together)", field=f"{field}.{key}")
    A = _matrix(t["A"], f"{field}.A", None, n)
    b = _vector(t["b"], f"{field}.b", A.shape[0])
    return SetSpec(kind="polytope", A=A, b=_frozen(b))


# --- field validators -----------------------------------------------------------------------


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _count(k: int, word: str) -> str:
    return f"{k} {word}" + ("" if k == 1 else "s")


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, int):
        if abs(value) >= 10**15:  # not thousands of digits in a one-line message
            return f"an integer of {len(str(abs(value)))} digits"
        return f"an integer ({value})"
    if isinstance(value, float):
        return f"a float ({value!r})"
    if isinstance(value, str):
        return f"a string ({value!r})" if len(value) <= 40 else "a string"
    if isinstance(value, list):
        return f"a list of {_count(len(value), 'item')}"
    if isinstance(value, dict):
        return "a table"
    return f"a {type(value).__name__}"


def _table(
    value: Any, field: str, *, required: Iterable[str] = (), optional: Iterable[str] = ()
) -> dict[str, Any]:
    where = f"[{field}]" if field else "the top level"
    if not isinstance(value, dict):
        raise SpecError(f"expected a table, got {_kind(value)}", field=field or None)
    required, optional = tuple(required), tuple(optional)
    allowed = required + optional
    for key in value:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise SpecError(
                f"unknown field {key!r} in {where} (allowed: {', '.join(allowed)}){hint}",
                field=_join(field, key),
            )
    for key in required:
        if key not in value:
            raise SpecError(f"missing required field {key!r} in {where}", field=_join(field, key))
    return value


def _spec_name(value: Any, field: str) -> str:
    if not isinstance(value, str):
        raise SpecError(f"expected a string, got {_kind(value)}", field=field)
    if not _NAME_RE.fullmatch(value):
        raise SpecError(
            f"invalid name {value!r}: use 1-64 letters, digits, '-', '_' or '.', starting with "
            "a letter or digit",
            field=field,
        )
    return value


def _names(value: Any, field: str) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise SpecError(f"expected a list of names, got {_kind(value)}", field=field)
    if not value:
        raise SpecError("the list of names is empty", field=field)
    seen: set[str] = set()
    for i, name in enumerate(value):
        f = f"{field}[{i}]"
        if not isinstance(name, str):
            raise SpecError(f"expected a name (string), got {_kind(name)}", field=f)
        if not _IDENT_RE.fullmatch(name):
            raise SpecError(
                f"invalid name {name!r}: use letters, digits and '_', starting with a letter",
                field=f,
            )
        if keyword.iskeyword(name):
            raise SpecError(f"{name!r} is a reserved word and cannot be a name", field=f)
        if name in RESERVED_NAMES:
            raise SpecError(
                f"{name!r} is a constant or function of the expression language and cannot be "
                "a name",
                field=f,
            )
        if name in seen:
            raise SpecError(f"duplicate name {name!r}", field=f)
        seen.add(name)
    return tuple(value)


def _number(value: Any, field: str, *, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(f"expected a number, got {_kind(value)}", field=field)
    try:
        x = float(value)
    except OverflowError:  # a TOML integer of hundreds of digits
        raise SpecError(
            f"the number is too large ({_kind(value)}; at most about 1.8e308)", field=field
        ) from None
    if math.isnan(x):
        raise SpecError("NaN is not allowed", field=field)
    if math.isinf(x) and not allow_inf:
        raise SpecError("infinite values are only allowed in bounds and box sets", field=field)
    return x


def _positive(value: Any, field: str) -> float:
    x = _number(value, field)
    if x <= 0:
        raise SpecError(f"must be > 0, got {x:g}", field=field)
    return x


def _integer(value: Any, field: str, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SpecError(f"expected an integer, got {_kind(value)}", field=field)
    if value < minimum:
        shown = value if value > -(10**15) else _kind(value)
        raise SpecError(f"must be >= {minimum}, got {shown}", field=field)
    if value > _MAX_COUNT:  # larger counts are never work that ends (pipeline.check_size)
        raise SpecError(f"must be <= {_MAX_COUNT:,}, got {_kind(value)}", field=field)
    return value


def _boolean(value: Any, field: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"expected true or false, got {_kind(value)}", field=field)
    return value


def _choice(value: Any, field: str, choices: tuple[str, ...]) -> str:
    allowed = ", ".join(f'"{c}"' for c in choices)
    if not isinstance(value, str) or value not in choices:
        raise SpecError(f"expected one of {allowed}, got {_kind(value)}", field=field)
    return value


def _norm(value: Any, field: str) -> str:
    if isinstance(value, str) and value.strip().lower() in NORMS:
        return value.strip().lower()
    if not isinstance(value, bool) and isinstance(value, int) and value in (1, 2):
        return str(value)
    if isinstance(value, float) and math.isinf(value) and value > 0:
        return "inf"
    raise SpecError(f'expected "1", "inf" or "2", got {_kind(value)}', field=field)


def _vector(value: Any, field: str, n: int, *, allow_inf: bool = False) -> np.ndarray:
    if not isinstance(value, list):
        raise SpecError(
            f"expected a list of {_count(n, 'number')}, got {_kind(value)}", field=field
        )
    if len(value) != n:
        raise SpecError(f"expected a list of {_count(n, 'number')}, got {len(value)}", field=field)
    out = np.array(
        [_number(v, f"{field}[{i}]", allow_inf=allow_inf) for i, v in enumerate(value)], dtype=float
    ).reshape(n)
    return _frozen(out)


def _matrix(value: Any, field: str, rows: int | None, cols: int) -> np.ndarray:
    """A finite (rows, cols) matrix given as a list of rows; ``rows=None``: any number >= 1."""
    want = (
        f"a {rows}×{cols} matrix" if rows is not None else f"a matrix with {_count(cols, 'column')}"
    )
    if not isinstance(value, list):
        raise SpecError(f"expected {want} (a list of rows), got {_kind(value)}", field=field)
    if not value:
        raise SpecError(f"expected {want}, got an empty list", field=field)
    if not any(isinstance(r, list) for r in value):
        raise SpecError(
            f"expected {want} written as a list of rows like [[...], [...]], got a flat list of "
            f"{_count(len(value), 'item')}",
            field=field,
        )
    for i, row in enumerate(value):
        if not isinstance(row, list):
            raise SpecError(f"expected {want}; row {i} is {_kind(row)}, not a list", field=field)
    lengths = sorted({len(r) for r in value})
    if len(lengths) > 1:
        raise SpecError(
            f"expected {want}, got rows of different lengths ({', '.join(map(str, lengths))})",
            field=field,
        )
    shape = (len(value), lengths[0])
    if shape[1] != cols or (rows is not None and shape[0] != rows):
        raise SpecError(f"expected {want}, got {shape[0]}×{shape[1]}", field=field)
    out = np.array(
        [
            [_number(v, f"{field}[{i}][{j}]") for j, v in enumerate(row)]
            for i, row in enumerate(value)
        ],
        dtype=float,
    ).reshape(shape)
    return _frozen(out)


def _psd(M: np.ndarray, name: str, field: str, *, definite: bool) -> None:
    scale = float(np.max(np.abs(M))) if M.size else 0.0
    S = M / scale if scale > 0 else M  # relative checks; no overflow of entries near 1e308
    asym = np.abs(S - S.T)
    if np.max(asym) > _SYM_TOL:
        i, j = np.unravel_index(int(np.argmax(asym)), asym.shape)
        raise SpecError(
            f'{name} must be symmetric for norm "2" ({name}[{i}][{j}] = {M[i, j]:g} but '
            f"{name}[{j}][{i}] = {M[j, i]:g})",
            field=field,
        )
    eig = np.linalg.eigvalsh(0.5 * (S + S.T))
    top = float(np.max(np.abs(eig)))
    low = float(np.min(eig))
    if scale > 0:
        top, low = top * scale, low * scale
    if definite and not low > _SYM_TOL * top:
        raise SpecError(
            f'{name} must be positive definite for norm "2" (smallest eigenvalue {low:.3g})',
            field=field,
        )
    if not definite and low < -_SYM_TOL * top:
        raise SpecError(
            f'{name} must be positive semidefinite for norm "2" (smallest eigenvalue {low:.3g})',
            field=field,
        )


def _bounds(t: Mapping[str, Any], var: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    lo_key, hi_key = f"{var}_min", f"{var}_max"
    lo = (
        _vector(t[lo_key], f"mpc.{lo_key}", n, allow_inf=True)
        if lo_key in t
        else _frozen(np.full(n, -np.inf))
    )
    hi = (
        _vector(t[hi_key], f"mpc.{hi_key}", n, allow_inf=True)
        if hi_key in t
        else _frozen(np.full(n, np.inf))
    )
    _no_wrong_inf(lo, f"mpc.{lo_key}", lo_key, +1)
    _no_wrong_inf(hi, f"mpc.{hi_key}", hi_key, -1)
    for v, key in ((lo, lo_key), (hi, hi_key)):
        big = np.flatnonzero(np.isfinite(v) & (np.abs(v) > BOUND_MAX))
        if big.size:
            raise SpecError(
                f"{v[big[0]]:g} is past {BOUND_MAX:g}: the MPC's rows cannot be normalised or "
                "solved with it; write inf (or leave the field out) for no bound",
                field=f"mpc.{key}[{big[0]}]",
            )
    _ordered(lo, hi, f"mpc.{lo_key}", lo_key, hi_key)
    return lo, hi


#: the largest finite bound of ``[mpc]`` (x, u, du, y): past it, products of the program's
#: rows overflow double precision; ``inf`` says "no bound"
BOUND_MAX = 1e100


def _no_wrong_inf(v: np.ndarray, field: str, name: str, sign: int) -> None:
    bad = np.flatnonzero(np.isinf(v) & (np.sign(v) == sign))
    if bad.size:
        i = int(bad[0])
        what = "a lower bound cannot be +inf" if sign > 0 else "an upper bound cannot be -inf"
        raise SpecError(f"{name}[{i}] = {v[i]}: {what}", field=f"{field}[{i}]")


def _ordered(lo: np.ndarray, hi: np.ndarray, field: str, lo_name: str, hi_name: str) -> None:
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        i = int(bad[0])
        raise SpecError(
            f"{lo_name}[{i}] = {lo[i]:g} is greater than {hi_name}[{i}] = {hi[i]:g}",
            field=field,
        )


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a
