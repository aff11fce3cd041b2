"""The Python design API: a :class:`~codev_engine.spec.problem.Problem` from keywords.

::

    import control as ct
    import codev_engine as ce
    sys = ct.ss([[0, 1], [0, 0]], [[0], [1]], [[1, 0]], 0)
    problem = ce.design(sys, sample_time=0.5, norm="2", horizon=5, u_min=[-1], u_max=[1])
    problem = problem.replace(horizon=8)

:func:`design` builds the dict the TOML parser gets from a spec file (``tomllib.loads``)
and runs the same code on it (:func:`codev_engine.spec.parse.build_spec`, then the
pipeline's checks), so a design is checked exactly as a file is, with the same messages; only
the names differ: an error names the keyword the caller wrote (``horizon``, ``system.A``)
where the file's would name its field (``mpc.horizon``, ``plant.A``).

Keywords are the spec's fields (docs/spec.md) without their table: ``horizon``, ``Q``,
``x_max``, ``initial_set``, ``unsafe``, ``sample_time``, ``dynamics``, ``regions``... The
names two tables share take a table: ``reference`` is ``mpc.reference`` and
``verify_reference`` is ``verify.reference`` (``constraints`` and ``verify_constraints``
likewise); ``plant.A`` / ``model.A`` are dotted (or come
from the system). Any field may be given dotted (``**{"mpc.R": [[0.1]]}``), and a table
whole (``verify={...}``; ``verify=None`` drops it). ``None`` leaves a field out.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.pipeline import check_model, check_mpc_feasible, check_size
from codev_engine.spec.parse import FIELDS, build_spec
from codev_engine.spec.problem import Problem
from codev_engine.spec.toml_out import problem_data

__all__ = ["KEYWORDS", "design", "replace"]

_TABLES = ("plant", "model", "mpc", "verify", "synthesis")
#: the keyword of a field two tables share (the other one is written dotted)
_SHARED = {"verify.reference": "verify_reference", "verify.constraints": "verify_constraints"}


def _keywords() -> dict[str, str]:
    """Keyword -> dotted field, for every field whose name is its table's alone."""
    seen: dict[str, list[str]] = {}
    for table in _TABLES:
        for key in FIELDS[table]:
            seen.setdefault(key, []).append(f"{table}.{key}")
    out = {"name": "name"}
    for key, dotted in seen.items():
        if len(dotted) == 1:
            out[key] = dotted[0]
    out["reference"] = "mpc.reference"  # the MPC's: what the law tracks
    out["constraints"] = "mpc.constraints"  # the MPC's: how its bounds are imposed
    out.update({kw: dotted for dotted, kw in _SHARED.items()})
    return out


#: every flat keyword of :func:`design` -> the spec field it sets
KEYWORDS: dict[str, str] = _keywords()
_DOTTED = {f"{t}.{k}" for t in _TABLES for k in FIELDS[t]}
_FIELD_RE = re.compile(r"\b(?:plant|model|mpc|verify|synthesis)\.[A-Za-z_]+\b")


def design(system: Any = None, /, *, check_mpc: bool = True, **keywords: Any) -> Problem:
    """A checked design problem from a python-control system (or matrices, or expressions)
    and the spec's fields as keywords.

    Parameters
    ----------
    system : control.StateSpace or (A, B) or None
        The plant. A continuous ``StateSpace`` (``dt = 0``) or a pair ``(A, B)`` of
        arrays, shapes (n, n) and (n, m), is ``dx/dt = A x + B u`` (``plant.A``,
        ``plant.B``); a discrete one (``dt > 0``) is the explicit model ``x+ = A x + B u``
        sampled every ``dt`` (``model.A``, ``model.B``; it cannot be verified, which needs
        the continuous plant). The system's ``C`` (p, n) becomes ``mpc.C`` when output
        bounds or an output reference are given without ``C``. None: the plant from
        ``dynamics=`` expressions (with ``states=`` and ``inputs=``), as in a spec file.
    check_mpc : bool
        Also check that the MPC is feasible somewhere (an LP), as ``load_spec`` does.
    **keywords : object
        The spec's fields (see the module docstring); arrays may be numpy arrays.
        ``name`` defaults to ``"design"``, ``states`` to the system's state names when
        they are identifiers (else ``x1..xn``), ``inputs`` likewise (``u1..um``).

    Returns
    -------
    Problem
        Its ``source`` is its TOML (:meth:`Problem.to_toml`); its ``path`` is None.

    Raises
    ------
    SpecError
        The first bad value, naming its keyword (``horizon``, ``Q``, ``system.A``) and the
        reason the spec file's loader gives.
    """
    data: dict[str, Any] = {"name": "design", "plant": {}, "model": {}, "mpc": {}}
    names: dict[str, str] = {}  # dotted field -> the name errors give it
    _from_system(system, data, names, keywords)
    _apply(data, keywords, names)
    return _checked(data, names, check_mpc=check_mpc)


def replace(problem: Problem, /, *, check_mpc: bool = True, **changes: Any) -> Problem:
    """A new problem: ``problem`` with some fields changed (keywords of :func:`design`).

    Parameters
    ----------
    problem : Problem
    check_mpc : bool
        As for :func:`design`.
    **changes : object
        As :func:`design`'s keywords; ``None`` drops a field.

    Returns
    -------
    Problem
        Checked as :func:`design` checks; its ``path`` is None.

    Raises
    ------
    SpecError
        As :func:`design`.
    """
    data = problem_data(problem)
    names: dict[str, str] = {}
    _apply(data, changes, names)
    return _checked(data, names, check_mpc=check_mpc)


# --- building the spec data -------------------------------------------------------------------


def _from_system(
    system: Any, data: dict[str, Any], names: dict[str, str], keywords: dict[str, Any]
) -> None:
    if system is None:
        return
    if hasattr(system, "num") and hasattr(system, "den") and not hasattr(system, "A"):
        raise SpecError(
            "a transfer function has no state: give its state-space form, control.ss(sys)",
            field="system",
        )
    if isinstance(system, tuple | list):
        if len(system) != 2:
            raise SpecError(
                f"expected a pair (A, B), got {len(system)} items", field="system"
            )
        A, B, C, D, dt = system[0], system[1], None, None, 0
    elif hasattr(system, "A") and hasattr(system, "B"):
        A, B = system.A, system.B
        C, D, dt = getattr(system, "C", None), getattr(system, "D", None), system.dt
    else:
        raise SpecError(
            "expected a python-control StateSpace, a pair (A, B) of arrays, or None with "
            f"dynamics=[...], got a {type(system).__name__}",
            field="system",
        )
    if dt is True:
        raise SpecError(
            "a discrete system needs its sample time: give dt (control.ss(A, B, C, D, dt))",
            field="system.dt",
        )
    discrete = dt is not None and dt is not False and dt != 0
    table = "model" if discrete else "plant"
    data[table]["A"], data[table]["B"] = _plain(A), _plain(B)
    names[f"{table}.A"], names[f"{table}.B"] = "system.A", "system.B"
    if discrete:
        data["model"]["sample_time"] = _plain(dt)
        names["model.sample_time"] = "system.dt"
    n, m = _rows(A), _rows(B[0] if _rows(B) else None) or 1  # the parser checks shapes
    data["plant"]["states"] = _labels(getattr(system, "state_labels", None), "x", n)
    data["plant"]["inputs"] = _labels(getattr(system, "input_labels", None), "u", m)
    outputs = ("y_min", "y_max", "mpc.y_min", "mpc.y_max")
    ref = keywords.get("reference", keywords.get("mpc.reference"))
    wants_y = any(k in keywords for k in outputs) or (
        isinstance(ref, Mapping) and ref.get("signal") == "y"
    )
    if C is not None and wants_y and "C" not in keywords and "mpc.C" not in keywords:
        if D is not None and np.any(np.asarray(D, dtype=float) != 0):
            raise SpecError(
                "the outputs have a direct feedthrough D != 0, which the MPC's outputs "
                "y = C x do not model: give C= for outputs without it",
                field="system.D",
            )
        data["mpc"]["C"] = _plain(C)
        names["mpc.C"] = "system.C"


def _rows(M: Any) -> int:
    """How many rows a matrix-like value has (0 for anything else: a ragged list, a
    number), without numpy's error on ragged lists."""
    try:
        return len(M) if not isinstance(M, str | bytes | Mapping) else 0
    except TypeError:
        return 0


def _labels(labels: Any, stem: str, k: int) -> list[str]:
    """The system's signal names when every one is a plain identifier (python-control's
    defaults ``x[0]`` are not): else ``x1..xn`` (``u`` alone for one input)."""
    if isinstance(labels, list | tuple) and len(labels) == k:
        if all(isinstance(s, str) and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", s) for s in labels):
            return list(labels)
    if stem == "u" and k == 1:
        return ["u"]
    return [f"{stem}{i + 1}" for i in range(k)]


def _apply(data: dict[str, Any], keywords: Mapping[str, Any], names: dict[str, str]) -> None:
    """Set each keyword's field in ``data`` (None: drop it) and remember its name."""
    for kw, value in keywords.items():
        if kw in _TABLES:
            if value is None:
                data.pop(kw, None)
            else:
                data[kw] = _plain(value)
            continue
        dotted = KEYWORDS.get(kw) or (kw if kw in _DOTTED else None)
        if dotted is None:
            known = [*KEYWORDS, *_DOTTED, *_TABLES]
            close = difflib.get_close_matches(kw, known, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise SpecError(f"unknown keyword {kw!r}{hint} (the fields of docs/spec.md)",
                            field=kw)  # fmt: skip
        names[dotted] = kw
        if dotted == "name":
            data["name"] = _plain(value)
            continue
        table, key = dotted.split(".", 1)
        if value is None:
            data.get(table, {}).pop(key, None)
            continue
        section = data.setdefault(table, {})
        if not isinstance(section, dict):
            raise SpecError("the table was set to a non-table", field=table)
        section[key] = _plain(value)


def _plain(value: Any) -> Any:
    """numpy and tuples as the TOML parser's types (lists, floats, ints, dicts)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def _checked(data: dict[str, Any], names: dict[str, str], *, check_mpc: bool) -> Problem:
    try:
        problem = build_spec(data, source="")
        check_size(problem)
        check_model(problem)
        if check_mpc:
            check_mpc_feasible(problem)
    except SpecError as exc:
        raise _renamed(exc, names) from None
    import dataclasses

    # its TOML is its source: a session stores it, and loads_spec reads it back equal
    return dataclasses.replace(problem, source=problem.to_toml(), path=None)


def _renamed(exc: SpecError, names: dict[str, str]) -> SpecError:
    """The error with the caller's names for the spec's fields (``mpc.Q[0][1]`` ->
    ``Q[0][1]``), in its field and its reason."""

    def name_of(dotted: str) -> str:
        if dotted in names:
            return names[dotted]
        flat = [kw for kw, d in KEYWORDS.items() if d == dotted]
        return flat[0] if flat else dotted

    field = exc.field
    if field is not None:
        head = re.match(r"[A-Za-z_]+(?:\.[A-Za-z_]+)?", field)
        if head and (head.group(0) in _DOTTED or head.group(0) == "name"):
            field = name_of(head.group(0)) + field[head.end():]
    reason = _FIELD_RE.sub(lambda m: name_of(m.group(0)), exc.reason)
    missing = re.fullmatch(r"missing required field '(\w+)' in \[(\w+)\]", reason)
    if missing and field is not None:
        reason = f"missing required keyword {field!r}"
    return SpecError(reason, field=field)
