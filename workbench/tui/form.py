"""The spec as a form: one text entry per spec field, composed back into TOML.

The workbench edits a spec field by field. Each field holds the text the user typed; a
matrix may be typed as TOML (``[[1, 1], [0, 1]]``) or Matlab-style (``1 1; 0 1``). The whole
form is composed into one TOML document and validated by the engine's own loader
(:func:`codev_engine.loads_spec`), so the workbench never disagrees with ``codev run`` about
what is valid, and an error's dotted field (``mpc.Q[0][1]``) is shown next to the entry that
caused it. Nothing typed is ever executed: entries are parsed with ``tomllib`` and ``float``.

No Textual import here: the form is plain data, tested on its own.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from codev_engine.errors import SpecError
from codev_engine.io.toml import toml_key, toml_literal, toml_string
from codev_engine.spec.choices import HOLDS, METHODS, NORMS

if TYPE_CHECKING:
    from codev_engine import Problem

__all__ = [
    "FIELDS",
    "FieldDef",
    "FormCheck",
    "check_form",
    "check_plant",
    "compose",
    "field_for_error",
    "field_toml",
    "form_from_text",
    "size_errors",
    "toml_value",
]

SECTIONS = ("plant", "model", "mpc", "verify")


@dataclass(frozen=True)
class FieldDef:
    """One entry of the form.

    Attributes
    ----------
    path : tuple of str
        Where the value sits in the TOML document: ``("mpc", "Q")``,
        ``("model", "operating_point", "x")``. The dotted form is the entry's id and the name
        the engine's errors use.
    kind : str
        How the text is turned into TOML: ``string``, ``names`` (comma-separated names),
        ``expressions`` (one per line), ``number``, ``integer``, ``choice``, ``bool``,
        ``vector``, ``matrix``, ``sets`` (a TOML array of inline tables), ``table`` (one
        TOML inline table; the braces may be left out) or ``vector_or_box`` (numbers, or
        an inline table ``{ lower = [..], upper = [..] }``).
    label : str
    help : str
        One line shown under the entry.
    choices : tuple of str
        For ``choice``.
    required : bool
        An empty optional entry is left out of the document (the engine's default applies).
    default : str
        What the engine takes for an empty optional entry, as shown in the empty entry
        (``"zoh"``, ``"identity"``; docs/spec.md is the reference).
    words : tuple of str
        Words the field takes instead of a value of its kind, written as TOML strings
        (``P = "lqr"``, ``time_horizon = "inf"``).
    group : str
        The collapsible group of its tab the entry sits in (``""``: none, always shown).
    """

    path: tuple[str, ...]
    kind: str
    label: str
    help: str = ""
    choices: tuple[str, ...] = ()
    required: bool = False
    default: str = ""
    words: tuple[str, ...] = ()
    group: str = ""

    @property
    def name(self) -> str:
        """The dotted path, ``"mpc.Q"``: the entry's id and the engine errors' field."""
        return ".".join(self.path)

    @property
    def section(self) -> str:
        """The TOML section the field is in (``"mpc"``), or ``""`` for a top-level key."""
        return self.path[0] if self.path[0] in SECTIONS else ""


def _f(path: str, kind: str, label: str, help: str = "", **kw: Any) -> FieldDef:
    return FieldDef(tuple(path.split(".")), kind, label, help, **kw)


# the collapsible groups of the tabs (issues 25 and 26), in screen order
G_UNCERTAIN = "Disturbances and uncertain parameters"
G_TRACKING = "Tracking: a reference"
G_RATES = "Input rates and move blocking"
G_OUTPUTS = "Outputs and mixed constraints"
G_SOFT = "Soft constraints"
G_TERMINAL = "Terminal cost and set"
G_LAW = "The law's u_prev and r (rates, reference box)"
G_NOISE = "Measurement noise"
G_UNITS = "Units (labels on the axes)"

#: Every spec field the workbench edits, in screen order (docs/spec.md is the reference).
FIELDS: tuple[FieldDef, ...] = (
    _f("name", "string", "Name", "letters, digits, - _ . (used in file names)", required=True),
    _f("plant.states", "names", "States", "comma-separated names, e.g. x1, x2", required=True),
    _f("plant.inputs", "names", "Inputs", "comma-separated names, e.g. u", required=True),
    _f(
        "plant.dynamics",
        "expressions",
        "Dynamics dx/dt = f(x, u)",
        "one expression per state, in state order (or give A and B below)",
        default="none: A and B",
    ),
    _f(
        "plant.A",
        "matrix",
        "Continuous A",
        "instead of dynamics: dx/dt = A x + B u",
        default="none: the dynamics",
    ),
    _f("plant.B", "matrix", "Continuous B", "n×m, rows separated by ;", default="none"),
    _f("model.sample_time", "number", "Sample time (s)", "controller period dt > 0", required=True),
    _f(
        "model.method",
        "choice",
        "Discretisation",
        "python-control method",
        choices=METHODS,
        default="zoh",
    ),
    _f(
        "model.operating_point.x",
        "vector",
        "Operating point x",
        "linearisation point and MPC reference",
        default="zeros",
    ),
    _f(
        "model.operating_point.u",
        "vector",
        "Operating point u",
        "input at the operating point",
        default="zeros",
    ),
    _f(
        "plant.disturbances",
        "table",
        "Disturbances w",
        "w = [lower, upper], …: any signal in the intervals",
        default="none",
        group=G_UNCERTAIN,
    ),
    _f(
        "plant.parameters",
        "table",
        "Uncertain parameters",
        "k = [lower, upper], …: constants of the dynamics",
        default="none",
        group=G_UNCERTAIN,
    ),
    _f(
        "plant.nominal",
        "table",
        "Nominal values",
        "w = 0, k = 1.5, …: what the MPC design uses",
        default="midpoints; disturbances 0",
        group=G_UNCERTAIN,
    ),
    _f(
        "plant.E",
        "matrix",
        "Disturbance input E",
        "n×d, with A and B: dx/dt = A x + B u + E w",
        default="none",
        group=G_UNCERTAIN,
    ),
    _f(
        "plant.state_units",
        "expressions",
        "State units",
        "one per line, in the order of the states (m/s); labels only",
        default="none",
        group=G_UNITS,
    ),
    _f(
        "plant.input_units",
        "expressions",
        "Input units",
        "one per line, in the order of the inputs (N); labels only",
        default="none",
        group=G_UNITS,
    ),
    _f("mpc.horizon", "integer", "Horizon N", "prediction steps ≥ 1", default="5"),
    _f(
        "mpc.norm",
        "choice",
        "Norm",
        "1 and inf: mp-LP; 2: mp-QP",
        choices=NORMS,
        default="2",
    ),
    _f(
        "mpc.Q",
        "matrix",
        "Q",
        "state weight (norm 2: n×n PSD; else q×n)",
        default="identity",
    ),
    _f(
        "mpc.R",
        "matrix",
        "R",
        "input weight (norm 2: m×m PD; else r×m)",
        default="identity",
    ),
    _f("mpc.x_min", "vector", "x min", "n numbers, -inf allowed", default="-inf (unbounded)"),
    _f("mpc.x_max", "vector", "x max", "n numbers, inf allowed", default="inf (unbounded)"),
    _f("mpc.u_min", "vector", "u min", "m numbers", default="-inf (unbounded)"),
    _f("mpc.u_max", "vector", "u max", "m numbers", default="inf (unbounded)"),
    _f(
        "mpc.domain_bound",
        "number",
        "Domain bound",
        "half-width of the law's box on unbounded state axes",
        default="100",
    ),
    _f(
        "mpc.simplify",
        "bool",
        "Merge regions",
        "merge regions with the same affine law (default off)",
    ),
    _f(
        "mpc.reference.signal",
        "choice",
        "Reference follows",
        "y (needs C) or x; none: regulate to the operating point",
        choices=("y", "x"),
        default="none (regulate)",
        group=G_TRACKING,
    ),
    _f(
        "mpc.reference.value",
        "vector",
        "Fixed reference r",
        "one number per output (or state); or the box below",
        default="none",
        group=G_TRACKING,
    ),
    _f(
        "mpc.reference.lower",
        "vector",
        "Reference box lower",
        "r is a parameter of the law, in this box",
        default="none",
        group=G_TRACKING,
    ),
    _f(
        "mpc.reference.upper",
        "vector",
        "Reference box upper",
        "with the lower side",
        default="none",
        group=G_TRACKING,
    ),
    _f(
        "mpc.control_horizon",
        "integer",
        "Control horizon Nc",
        "moves after Nc repeat the last (move blocking)",
        default="N (no blocking)",
        group=G_RATES,
    ),
    _f(
        "mpc.du_min",
        "vector",
        "Δu min",
        "m numbers: u_k - u_(k-1) ≥ du_min; u_prev joins θ",
        default="-inf (no rate bound)",
        group=G_RATES,
    ),
    _f(
        "mpc.du_max",
        "vector",
        "Δu max",
        "m numbers: u_k - u_(k-1) ≤ du_max",
        default="inf (no rate bound)",
        group=G_RATES,
    ),
    _f(
        "mpc.Rd",
        "matrix",
        "Rd",
        "weight on u_k - u_(k-1) (norm 2: m×m PSD; else r×m)",
        default="none",
        group=G_RATES,
    ),
    _f("mpc.C", "matrix", "Outputs C", "p×n: y = C x", default="none", group=G_OUTPUTS),
    _f("mpc.y_min", "vector", "y min", "p numbers (needs C)", default="-inf (unbounded)",
       group=G_OUTPUTS),
    _f("mpc.y_max", "vector", "y max", "p numbers (needs C)", default="inf (unbounded)",
       group=G_OUTPUTS),
    _f(
        "mpc.constraints",
        "sets",
        "Mixed constraints",
        "TOML list: [{Hx = [[..]], Hu = [[..]], h = [..]}]: Hx x + Hu u ≤ h",
        default="none",
        group=G_OUTPUTS,
    ),
    _f(
        "mpc.soft",
        "names",
        "Soft groups",
        "any of x_min, x_max, y_min, y_max",
        default="none (all hard)",
        group=G_SOFT,
    ),
    _f(
        "mpc.soft_weight",
        "number",
        "Slack weight",
        "price of the slacks (l1; norm 2 adds ε²)",
        default="10000",
        group=G_SOFT,
    ),
    _f(
        "mpc.P",
        "matrix",
        "P",
        "terminal weight, or lqr: the Riccati solution (norm 2)",
        default="none",
        words=("lqr",),
        group=G_TERMINAL,
    ),
    _f(
        "mpc.terminal_set",
        "table",
        "Terminal set",
        "lqr, { A = [[..]], b = [..] } or { lower = [..], upper = [..] }",
        default="none",
        words=("lqr",),
        group=G_TERMINAL,
    ),
    _f(
        "verify.time_horizon",
        "number",
        "Time horizon (s)",
        "length of the verified interval; inf: for all time",
        required=True,
        words=("inf",),
    ),
    _f(
        "verify.max_samples",
        "integer",
        "Max samples",
        "time horizon inf: the samples within which the proof must close",
        default="1000",
    ),
    _f("verify.initial_set.lower", "vector", "Initial set lower", "n numbers", required=True),
    _f("verify.initial_set.upper", "vector", "Initial set upper", "n numbers", required=True),
    _f(
        "verify.hold",
        "choice",
        "Hold",
        "zoh: u held over each sample; continuous: u = F x(t) + G",
        choices=HOLDS,
        default="zoh",
    ),
    _f(
        "verify.max_depth",
        "integer",
        "Max depth",
        "initial-set refinement depth (maxPart)",
        default="6",
    ),
    _f("verify.step", "number", "Tube step (s)", "time step of the reachtube", default="0.01"),
    _f(
        "verify.input_bounds",
        "bool",
        "Check input bounds",
        "u(t) within [u_min, u_max] (default off)",
    ),
    _f(
        "verify.constraints",
        "bool",
        "Check the design's bounds",
        "the MPC's hard x/y/u bounds checked for all t (default off: at samples only)",
    ),
    _f(
        "verify.unsafe",
        "sets",
        "Unsafe sets",
        "TOML list: [{lower = [..], upper = [..]}, {A = [[..]], b = [..]}]",
        default="none",
    ),
    _f(
        "verify.safe",
        "sets",
        "Safe sets",
        "the state must stay inside every one",
        default="none",
    ),
    _f(
        "verify.initial_input",
        "vector_or_box",
        "Initial input u_prev",
        "with input rates: m numbers or { lower = [..], upper = [..] }",
        default="the operating input",
        group=G_LAW,
    ),
    _f(
        "verify.reference",
        "vector_or_box",
        "Reference r",
        "with a reference box: numbers or { lower = [..], upper = [..] }",
        default="the mpc.reference box",
        group=G_LAW,
    ),
    _f(
        "verify.measurement_noise",
        "vector_or_box",
        "Measurement noise v",
        "the law sees x + v: { lower = [..], upper = [..] }, n numbers each",
        default="none",
        group=G_NOISE,
    ),
)

FIELD_BY_NAME: dict[str, FieldDef] = {f.name: f for f in FIELDS}


# --------------------------------------------------------------------------------------------
# TOML values
# --------------------------------------------------------------------------------------------


def toml_value(value: Any) -> str:
    """A TOML literal for a value read by ``tomllib`` (round-trips exactly), as a person
    types it: lists of inline tables one table per line (``sets`` entries).

    Parameters
    ----------
    value : bool, int, float, str, list or dict
        A value as ``tomllib`` returns it (nested lists and tables included).

    Returns
    -------
    str

    Raises
    ------
    TypeError
        A value of another type (TOML has no literal for it).
    """
    return toml_literal(value, readable=True)



def _single_value(lit: str) -> None:
    """``lit`` must be exactly one TOML value (not a value followed by more keys or tables
    on further lines, which would inject fields into the composed document)."""
    doc = tomllib.loads(f"v = {lit}")
    if list(doc) != ["v"]:
        raise ValueError("one value expected (the text goes on after the value)")


def _parses(lit: str) -> bool:
    try:
        _single_value(lit)
    except ValueError:
        return False
    return True


def _number_token(tok: str) -> str:
    """One Matlab-style entry as a TOML number (``float`` parses it; nothing is executed)."""
    v = float(tok)  # ValueError for anything that is not a number
    return toml_value(v)


def entry_to_toml(kind: str, text: str) -> str:
    """The TOML literal of an entry's text, or ``""`` for an empty entry.

    Raises
    ------
    ValueError
        The text cannot be a value of this kind (message for the user).
    """
    s = text.strip()
    if not s:
        return ""
    if kind == "string":
        return s if s[0] in "\"'" else toml_string(s)
    if kind == "names":
        if s.startswith("["):
            return s
        return toml_value([p.strip() for p in re.split(r"[,\s]+", s) if p.strip()])
    if kind == "expressions":
        if s.startswith("["):
            return s
        return toml_value([ln.strip() for ln in s.splitlines() if ln.strip()])
    if kind == "choice":
        return s if s[0] in "\"'" else toml_string(s)
    if kind == "bool":
        low = s.lower()
        if low in ("true", "yes", "on", "1"):
            return "true"
        if low in ("false", "no", "off", "0"):
            return "false"
        raise ValueError("expected true or false")
    if kind == "number" and not _parses(s):
        try:  # '.5', '5.', '1_000' (what Python reads as a number; nothing is evaluated)
            return _number_token(s)
        except ValueError:
            return s  # the TOML error is reported
    if kind in ("number", "integer", "sets"):
        return s
    if kind == "table":
        # `w = [-1, 1], k = [0, 2]` is the inline table without its braces
        return s if s.startswith("{") or "=" not in s else "{ " + s + " }"
    if kind == "vector_or_box":
        return s if s.startswith("{") else entry_to_toml("vector", s)
    if kind in ("vector", "matrix"):
        if s.startswith("["):
            if _parses(s) or s.count("[") != 1 or not s.endswith("]"):
                return s
            s = s[1:-1]  # Matlab brackets: [1 1; 0 1]
        rows = [r for r in re.split(r"[;\n]", s) if r.strip()]
        try:
            parsed = [[_number_token(t) for t in re.split(r"[,\s]+", r.strip()) if t] for r in rows]
        except ValueError:
            raise ValueError(
                "expected numbers: '1 2; 3 4' or TOML '[[1, 2], [3, 4]]'"
                if kind == "matrix"
                else "expected numbers: '1, 2' or TOML '[1, 2]'"
            ) from None
        if kind == "vector":
            return "[" + ", ".join(t for row in parsed for t in row) + "]"
        return "[" + ", ".join("[" + ", ".join(row) + "]" for row in parsed) + "]"
    raise ValueError(f"unknown field kind {kind!r}")


def field_toml(fd: FieldDef, text: str) -> str:
    """The TOML literal of a field's entry: one of its :attr:`FieldDef.words` as a string
    (``lqr`` → ``"lqr"``), else :func:`entry_to_toml` of its kind.

    Parameters
    ----------
    fd : FieldDef
        The field.
    text : str
        The entry's text.

    Returns
    -------
    str
        The literal, or ``""`` for an empty entry.

    Raises
    ------
    ValueError
        The text cannot be a value of this field (message for the user).
    """
    word = text.strip().strip("\"'")
    if fd.words and word in fd.words:
        return toml_string(word)
    return entry_to_toml(fd.kind, text)


def _display(kind: str, value: Any, words: tuple[str, ...] = ()) -> str:
    """How a loaded value is shown in its entry (the inverse of :func:`field_toml`)."""
    if isinstance(value, str) and value in words:
        return value
    if kind == "string" and isinstance(value, str):
        return value
    if kind == "choice" and isinstance(value, str):
        return value
    if kind == "choice" and isinstance(value, float) and math.isinf(value):
        return "inf"
    if kind == "choice" and isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    if kind == "names" and isinstance(value, list) and all(isinstance(v, str) for v in value):
        return ", ".join(value)
    if kind == "expressions" and isinstance(value, list) and all(isinstance(v, str) for v in value):
        return "\n".join(value)
    return toml_value(value)


# --------------------------------------------------------------------------------------------
# Form <-> document
# --------------------------------------------------------------------------------------------


def form_from_text(text: str) -> tuple[dict[str, str], bool]:
    """Entries of the form for a spec's TOML text.

    Parameters
    ----------
    text : str
        The spec document.

    Returns
    -------
    values : dict
        Field name → entry text ("" where the spec leaves the field out).
    has_verify : bool
        Whether the spec has a ``[verify]`` section.

    Raises
    ------
    SpecError
        Invalid TOML, or a field the form has no entry for (e.g. an explicit discrete model:
        edit such specs as text).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"invalid TOML: {exc}") from None
    values: dict[str, str] = {}
    for fd in FIELDS:
        node: Any = data
        for part in fd.path:
            node = node.get(part) if isinstance(node, dict) else None
        values[fd.name] = "" if node is None else _display(fd.kind, node, fd.words)
    known = {fd.path for fd in FIELDS}
    for path in _leaf_paths(data):
        if path not in known and not any(path[: len(k)] == k for k in known):
            raise SpecError(
                "the workbench has no entry for this field; edit the spec file as text",
                field=".".join(path),
            )
    return values, "verify" in data


def _leaf_paths(data: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for k, v in data.items():
        if isinstance(v, dict) and (prefix + (k,)) not in {fd.path for fd in FIELDS}:
            out.extend(_leaf_paths(v, prefix + (k,)))
        else:
            out.append(prefix + (k,))
    return out


def compose(values: dict[str, str], *, with_verify: bool = True) -> tuple[str, dict[str, str]]:
    """The TOML document of the form's entries.

    Parameters
    ----------
    values : dict of str to str
        The entries: field name → text (a missing field is empty).
    with_verify : bool
        Include the ``[verify]`` section (its entries are left out otherwise).

    Returns
    -------
    text : str
        The document (entries that fail to convert are left out).
    errors : dict
        Field name → message, for entries whose text is not a value of their kind (checked
        one by one with ``tomllib``, so a typo is pinned to its entry, not to a line of the
        composed document).
    """
    errors: dict[str, str] = {}
    tree: dict[str, Any] = {}
    for fd in FIELDS:
        if fd.section == "verify" and not with_verify:
            continue
        raw = values.get(fd.name, "")
        try:
            lit = field_toml(fd, raw)
            if lit:
                _single_value(lit)
        except ValueError as exc:  # TOMLDecodeError is a ValueError
            msg = str(exc)
            errors[fd.name] = (
                msg
                if not msg.startswith(("Invalid", "Expected", "Unclosed"))
                else f"not a valid value: {msg}"
            )
            continue
        if not lit:
            if fd.required:
                errors[fd.name] = "required"
            continue
        node = tree
        for part in fd.path[:-1]:
            node = node.setdefault(part, {})
        node[fd.path[-1]] = lit
    lines = ["# written by codev tui (docs/spec.md describes every field)"]
    if "name" in tree:
        lines.append(f"name = {tree.pop('name')}")
    for section in SECTIONS:
        if section not in tree:
            # an MPC left at its defaults is still a section the loader requires (a
            # newcomer's blank form otherwise stopped at "fix mpc" with no field marked)
            if section == "mpc" or (section == "verify" and with_verify):
                lines += ["", f"[{section}]"]
            continue
        lines += ["", f"[{section}]"]
        for k, v in tree[section].items():
            lines.append(f"{toml_key(k)} = {_inline(v)}")
    return "\n".join(lines) + "\n", errors


def _inline(v: Any) -> str:
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{toml_key(k)} = {_inline(x)}" for k, x in v.items()) + " }"
    return v


@dataclass(frozen=True)
class FormCheck:
    """The result of validating the form: the problem, or the errors per entry.

    Attributes
    ----------
    text : str
        The composed TOML document that was validated.
    problem : Problem or None
        The validated spec; None if the form is not valid.
    errors : dict of str to str
        Field name → message, for the entries at fault.
    general : str or None
        An error that names no entry (the MPC is infeasible, ...).
    """

    text: str
    problem: Problem | None
    errors: dict[str, str]
    general: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the form is a valid spec (``problem`` is set)."""
        return self.problem is not None


def field_for_error(field: str | None) -> str | None:
    """The entry an engine error's dotted field belongs to (``mpc.Q[0][1]`` → ``mpc.Q``).

    A sub-table (``model.operating_point``, ``verify.initial_set``) maps to its first entry;
    a whole section (``mpc``: the MPC is infeasible; ``verify``) or an unknown field maps to
    None (a general error, not pinned on an arbitrary entry).

    Parameters
    ----------
    field : str or None
        The dotted field of a :class:`~codev_engine.errors.SpecError` (None: it names
        none).

    Returns
    -------
    str or None
        The name of the entry (a :attr:`FieldDef.name`), or None.
    """
    if not field:
        return None
    base = re.sub(r"\[\d+\]", "", field)
    if base in SECTIONS:
        return None
    best = None
    for fd in FIELDS:
        if base == fd.name or base.startswith(fd.name + "."):
            if best is None or len(fd.name) > len(best):
                best = fd.name
    if best is None:
        # a whole table (verify.initial_set, model.operating_point): its first entry
        best = next((fd.name for fd in FIELDS if fd.name.startswith(base + ".")), None)
    return best


# --------------------------------------------------------------------------------------------
# Sizes: every entry whose shape no longer fits the states and inputs
# --------------------------------------------------------------------------------------------


def _parsed(fd: FieldDef, text: str) -> Any:
    """The entry's value as TOML reads it, or None (empty or not a value: reported elsewhere)."""
    try:
        lit = field_toml(fd, text)
        return tomllib.loads(f"v = {lit}")["v"] if lit else None
    except (ValueError, RecursionError):
        return None


def _rows_cols(value: Any) -> tuple[int, int] | None:
    if not isinstance(value, list) or not value or not all(isinstance(r, list) for r in value):
        return None
    lengths = {len(r) for r in value}
    return (len(value), lengths.pop()) if len(lengths) == 1 else None


def size_errors(values: dict[str, str], *, with_verify: bool = True) -> dict[str, str]:
    """Every entry whose size does not fit the states and inputs typed.

    The engine's loader stops at its first error; after a change of the number of states
    ``n`` or inputs ``m`` every vector and matrix that no longer fits is flagged at once
    (the dynamics, ``A``, ``B``, ``Q``, ``R``, ``P``, the bounds, the operating point, the
    initial set and the sets).

    Parameters
    ----------
    values : dict of str to str
        The entries: field name → text.
    with_verify : bool
        Check the ``[verify]`` entries too.

    Returns
    -------
    dict of str to str
        Field name → message (empty when ``n`` or ``m`` cannot be read yet).
    """
    names = {}
    for key in ("plant.states", "plant.inputs"):
        v = _parsed(FIELD_BY_NAME[key], values.get(key, ""))
        if not isinstance(v, list) or not v or not all(_is_name(x) for x in v):
            return {}  # the names themselves are wrong: the loader says why
        names[key] = v
    n, m = len(names["plant.states"]), len(names["plant.inputs"])
    norm = values.get("mpc.norm", "").strip().strip("\"'") or "2"  # (the spec's default)
    square = norm == "2"
    x, u = (n, "state"), (m, "input")
    vectors = {
        "model.operating_point.x": x,
        "model.operating_point.u": u,
        "mpc.x_min": x,
        "mpc.x_max": x,
        "mpc.u_min": u,
        "mpc.u_max": u,
        "mpc.du_min": u,
        "mpc.du_max": u,
        "verify.initial_set.lower": x,
        "verify.initial_set.upper": x,
        "verify.initial_input": u,
        "verify.measurement_noise": x,
    }
    # (rows or None for any, columns)
    matrices = {
        "plant.A": (n, n),
        "plant.B": (n, m),
        "mpc.Q": (n if square else None, n),
        "mpc.R": (m if square else None, m),
        "mpc.P": (n if square else None, n),
        "mpc.Rd": (m if square else None, m),
        "mpc.C": (None, n),
    }
    outputs = _rows_cols(_parsed(FIELD_BY_NAME["mpc.C"], values.get("mpc.C", "")))
    if outputs is not None:
        vectors["mpc.y_min"] = vectors["mpc.y_max"] = (outputs[0], "output")
    errors: dict[str, str] = {}
    for fd in FIELDS:
        if fd.section == "verify" and not with_verify:
            continue
        value = _parsed(fd, values.get(fd.name, ""))
        if value is None:
            continue
        if fd.name == "plant.dynamics" and isinstance(value, list) and len(value) != n:
            errors[fd.name] = f"expected {n} expressions (one per state), got {len(value)}"
        elif fd.name in vectors and isinstance(value, list):
            k, per = vectors[fd.name]
            if len(value) != k:
                errors[fd.name] = f"expected {k} numbers (one per {per}), got {len(value)}"
        elif fd.name in matrices:
            shape = _rows_cols(value)
            rows, cols = matrices[fd.name]
            if shape is not None and (shape[1] != cols or (rows is not None and shape[0] != rows)):
                want = f"{rows}×{cols}" if rows is not None else f"{cols} columns"
                errors[fd.name] = f"expected {want}, got {shape[0]}×{shape[1]}"
        elif fd.name == "plant.E":
            shape = _rows_cols(value)
            if shape is not None and shape[0] != n:
                errors[fd.name] = f"expected {n} rows (one per state), got {shape[0]}"
        elif fd.kind == "sets" and isinstance(value, list):
            for i, item in enumerate(value):
                bad = _set_size(item, n)
                if bad:
                    errors[fd.name] = f"{fd.name}[{i}].{bad}"  # as the loader words it
                    break
    return errors


def _is_name(x: Any) -> bool:
    return isinstance(x, str) and re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", x) is not None


def _set_size(item: Any, n: int) -> str | None:
    if not isinstance(item, dict):
        return None
    for key in ("lower", "upper"):
        v = item.get(key)
        if isinstance(v, list) and len(v) != n:
            return f"{key}: expected {n} numbers (one per state), got {len(v)}"
    shape = _rows_cols(item.get("A"))
    if shape is not None and shape[1] != n:
        return f"A: expected {n} columns, got {shape[1]}"
    return None


def check_plant(values: dict[str, str], path: str = "<workbench>") -> FormCheck:
    """Validate the plant and model entries alone (the Plant tab's report needs no more).

    The document is the ``[plant]`` and ``[model]`` entries with a placeholder name and the
    engine's default MPC (``norm = "inf"``, the other fields' defaults), so an MPC or verify
    entry still to fill in does not hold back the derived model.

    Parameters
    ----------
    values : dict of str to str
        The entries: field name → text (only ``plant.*`` and ``model.*`` are read).
    path : str
        The spec's name in the engine's messages.

    Returns
    -------
    FormCheck
        Its problem carries the plant and model typed; errors name plant or model entries.
    """
    own = {k: v for k, v in values.items() if k.split(".")[0] in ("plant", "model")}
    own["name"] = "plant"
    own["mpc.norm"] = "inf"
    if not own.get("model.sample_time", "").strip():
        # a placeholder, so that the loader still reads the plant entries typed (their own
        # message, e.g. a dynamics expression's, shows before the sample time is given);
        # the problem is then not the user's: not returned
        own["model.sample_time"] = "1"
        chk = check_form(own, with_verify=False, path=path)
        errors = {k: v for k, v in chk.errors.items() if k.startswith("plant.")}
        return FormCheck(chk.text, None, {**errors, "model.sample_time": "required"})
    chk = check_form(own, with_verify=False, path=path)
    errors = {k: v for k, v in chk.errors.items() if k.split(".")[0] in ("plant", "model")}
    return FormCheck(chk.text, chk.problem, errors, chk.general)


def with_typed_errors(chk: FormCheck, part: FormCheck, values: dict[str, str]) -> FormCheck:
    """``chk`` with the messages ``part`` (a check of some entries on their own, e.g.
    :func:`check_plant`) gives entries that are typed and that ``chk`` says nothing about.

    The loader stops at the form's first fault, and the whole form's check never reaches it
    while another tab's entry is still empty: a dynamics expression's message would wait for
    the MPC and verify tabs (issue 41). Empty entries keep ``chk``'s word ("required").

    Parameters
    ----------
    chk : FormCheck
        The whole form's check (not valid).
    part : FormCheck
        A check of some entries alone.
    values : dict of str to str
        The entries.

    Returns
    -------
    FormCheck
    """
    extra = {k: v for k, v in part.errors.items()
             if k not in chk.errors and values.get(k, "").strip()}
    if not extra:
        return chk
    return FormCheck(chk.text, chk.problem, {**chk.errors, **extra}, chk.general)


def check_form(
    values: dict[str, str], *, with_verify: bool, check_mpc: bool = False, path: str = "<workbench>"
) -> FormCheck:
    """Compose and validate the form with the engine's spec loader.

    The engine stops at the first error, so at most one entry error comes from it; entry
    syntax errors are all reported.

    Parameters
    ----------
    values : dict of str to str
        The entries: field name → text.
    with_verify : bool
        Whether the ``[verify]`` section is on (see :func:`compose`).
    check_mpc : bool
        Also check that the MPC is feasible for some state in the state bounds (an LP;
        passed to :func:`~codev_engine.pipeline.loads_spec`).
    path : str
        The spec's name in the engine's messages.

    Returns
    -------
    FormCheck
        The problem, or the errors: per entry, or one general error.
    """
    text, errors = compose(values, with_verify=with_verify)
    for name, msg in size_errors(values, with_verify=with_verify).items():
        errors.setdefault(name, msg)
    if errors:
        return FormCheck(text, None, errors)
    try:
        from codev_engine.pipeline import loads_spec  # sympy: loaded on the first check

        problem = loads_spec(text, path=path, check_mpc=check_mpc)
    except SpecError as exc:
        entry = field_for_error(exc.field)
        if entry is None:
            return FormCheck(
                text, None, {}, exc.reason if exc.field is None else f"{exc.field}: {exc.reason}"
            )
        where = exc.field if exc.field and exc.field != entry else None
        msg = f"{where}: {exc.reason}" if where else exc.reason
        return FormCheck(text, None, {entry: msg})
    return FormCheck(text, problem, {})
