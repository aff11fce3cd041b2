"""A :class:`~codev_engine.spec.problem.Problem` written back as spec data and TOML text.

:func:`problem_data` gives the nested dict the TOML parser reads (``tomllib.loads`` of a
spec gives the same shape), :func:`dumps` writes such a dict as TOML, and
:func:`same_design` compares two problems field by field. Together:
``parse_spec(dumps(problem_data(p)))`` is a problem ``same_design`` as ``p`` -- every
float is written by ``repr`` (exact), every default the parser would fill in is written out,
so nothing depends on the defaults staying the same.
"""

from __future__ import annotations

import math
from dataclasses import fields, is_dataclass
from typing import Any

import numpy as np

# The problem's classes are not imported, not even for type checking: Problem.to_toml
# imports this module, and the import graph stays without cycles (tests/contract).
Problem = SetSpec = Uncertain = Any

__all__ = ["dumps", "problem_data", "same_design", "toml_value"]

#: fields of a Problem that say where it came from, not what it is
_ORIGIN = ("path", "source")


def problem_data(problem: Problem) -> dict[str, Any]:
    """The spec data of a problem: the nested dict the TOML parser reads.

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    dict
        ``{"name", "plant", "model", "mpc", ["verify"], "synthesis"}`` with lists of floats
        for vectors and lists of rows for matrices.
    """
    p, mo, mpc, v = problem.plant, problem.model, problem.mpc, problem.verify
    plant: dict[str, Any] = {"states": list(p.states), "inputs": list(p.inputs)}
    if p.dynamics is not None:
        plant["dynamics"] = list(p.dynamics)
    if p.A is not None:
        plant["A"], plant["B"] = _mat(p.A), _mat(p.B)
    nominal: dict[str, float] = {}
    for key, box in (("disturbances", p.disturbances), ("parameters", p.parameters)):
        if box is not None:
            plant[key] = _intervals(box)
            nominal.update(zip(box.names, map(float, box.nominal), strict=True))
    if nominal:
        plant["nominal"] = nominal
    if p.E is not None:
        plant["E"] = _mat(p.E)
    for key in ("state_units", "input_units"):
        if getattr(p, key, ()):
            plant[key] = list(getattr(p, key))
    model: dict[str, Any] = {
        "sample_time": float(mo.sample_time),
        "method": mo.method,
        "operating_point": {"x": _vec(mo.x_op), "u": _vec(mo.u_op)},
    }
    if mo.A is not None:
        model["A"], model["B"] = _mat(mo.A), _mat(mo.B)
    m: dict[str, Any] = {"horizon": mpc.horizon, "norm": mpc.norm, "Q": _mat(mpc.Q),
                         "R": _mat(mpc.R)}  # fmt: skip
    if mpc.terminal_cost == "lqr":
        m["P"] = "lqr"
    elif mpc.P is not None:
        m["P"] = _mat(mpc.P)
    for key in ("x_min", "x_max", "u_min", "u_max", "du_min", "du_max", "y_min", "y_max"):
        value = getattr(mpc, key)
        if value is not None:
            m[key] = _vec(value)
    m["simplify"] = bool(mpc.simplify)
    m["domain_bound"] = float(mpc.domain_bound)
    if mpc.control_horizon is not None:
        m["control_horizon"] = mpc.control_horizon
    if mpc.terminal_set is not None:
        ts = mpc.terminal_set
        m["terminal_set"] = ts if isinstance(ts, str) else _set(ts)
    if mpc.Rd is not None:
        m["Rd"] = _mat(mpc.Rd)
    if mpc.C is not None:
        m["C"] = _mat(mpc.C)
    if mpc.soft:
        m["soft"] = list(mpc.soft)
    m["soft_weight"] = float(mpc.soft_weight)
    if mpc.constraints:
        m["constraints"] = [
            {"Hx": _mat(c.Hx), "Hu": _mat(c.Hu), "h": _vec(c.h)} for c in mpc.constraints
        ]
    if mpc.reference is not None:
        ref = mpc.reference
        r: dict[str, Any] = {"signal": ref.signal}
        if ref.value is not None:
            r["value"] = _vec(ref.value)
        else:
            r["lower"], r["upper"] = _vec(ref.lower), _vec(ref.upper)
        m["reference"] = r
    out: dict[str, Any] = {"name": problem.name, "plant": plant, "model": model, "mpc": m}
    if v is not None:
        ver: dict[str, Any] = {
            # the parser reads the string "inf" (TOML's inf is a float, read the same)
            "time_horizon": "inf" if math.isinf(v.time_horizon) else float(v.time_horizon),
            "hold": v.hold,
            "max_depth": v.max_depth,
            "step": float(v.step),
            "initial_set": {"lower": _vec(v.initial_lower), "upper": _vec(v.initial_upper)},
            "input_bounds": bool(v.input_bounds),
            "max_samples": v.max_samples,
        }
        for key, lo, hi in (
            ("initial_input", v.initial_input_lower, v.initial_input_upper),
            ("reference", v.reference_lower, v.reference_upper),
            ("measurement_noise", v.noise_lower, v.noise_upper),
        ):
            if lo is not None:
                ver[key] = {"lower": _vec(lo), "upper": _vec(hi)}
        if v.time_budget is not None:
            ver["time_budget"] = float(v.time_budget)
        if v.unsafe:
            ver["unsafe"] = [_set(s) for s in v.unsafe]
        # the design's bounds are appended by the parser: write the flag, not their sets
        own = problem.own_safe_sets()
        if v.constraints:
            ver["constraints"] = True
        if own:
            ver["safe"] = [_set(s) for s in own]
        out["verify"] = ver
    out["synthesis"] = {"regions": problem.regions}
    return out


def _vec(a: Any) -> list[float]:
    return [float(x) for x in np.asarray(a, dtype=float).reshape(-1)]


def _mat(a: Any) -> list[list[float]]:
    return [[float(x) for x in row] for row in np.asarray(a, dtype=float)]


def _intervals(box: Uncertain) -> dict[str, list[float]]:
    return {
        name: [float(lo), float(hi)]
        for name, lo, hi in zip(box.names, box.lower, box.upper, strict=True)
    }


def _set(s: SetSpec) -> dict[str, Any]:
    if s.kind == "box":
        return {"lower": _vec(s.lower), "upper": _vec(s.upper)}
    return {"A": _mat(s.A), "b": _vec(s.b)}


# --- TOML text --------------------------------------------------------------------------------


def dumps(data: dict[str, Any]) -> str:
    """TOML text of spec data (:func:`problem_data`'s shape).

    Top-level scalars first, then one ``[section]`` per table; a list of tables inside a
    section is written as ``[[section.key]]`` blocks, everything deeper inline.

    Parameters
    ----------
    data : dict
        Strings, bools, ints, floats (``inf`` allowed, never NaN), lists and dicts.

    Returns
    -------
    str
        A TOML document that ``tomllib.loads`` reads back to ``data`` (ints and floats kept).
    """
    lines = [f"{_key(k)} = {toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for section, table in data.items():
        if not isinstance(table, dict):
            continue
        lines += ["", f"[{_key(section)}]"]
        blocks = []
        for k, v in table.items():
            if isinstance(v, list) and v and all(isinstance(i, dict) for i in v):
                blocks.append((k, v))
            else:
                lines.append(f"{_key(k)} = {toml_value(v)}")
        for k, items in blocks:
            for item in items:
                lines += ["", f"[[{_key(section)}.{_key(k)}]]"]
                lines += [f"{_key(ik)} = {toml_value(iv)}" for ik, iv in item.items()]
    return "\n".join(lines) + "\n"


def _key(k: str) -> str:
    bare = k.replace("_", "").replace("-", "").isalnum() and k.isascii() and k != ""
    return k if bare else _string(k)


def _string(s: str) -> str:
    out = ['"']
    for ch in s:
        code = ord(ch)
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif code < 0x20 or code == 0x7F:  # control characters are escaped in TOML
            out.append(f"\\u{code:04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_value(v: Any) -> str:
    """One value as TOML text (inline: ``[1.0, inf]``, ``{ lower = [0.0] }``).

    Parameters
    ----------
    v : bool, int, float, str, list or dict

    Returns
    -------
    str
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            raise ValueError("NaN has no place in a spec")
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # shortest text that reads back to the same double
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(i) for i in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{_key(k)} = {toml_value(i)}" for k, i in v.items()) + " }"
    raise TypeError(f"cannot write a {type(v).__name__} as TOML")


# --- equality ---------------------------------------------------------------------------------


def same_design(a: Problem, b: Problem) -> bool:
    """Whether two problems state the same design (every field but ``path`` and ``source``).

    Arrays are equal when their shapes and values are (``inf`` equal to ``inf``).

    Parameters
    ----------
    a, b : Problem

    Returns
    -------
    bool
    """
    return all(
        _equal(getattr(a, f.name), getattr(b, f.name))
        for f in fields(a)
        if f.name not in _ORIGIN
    )


def _equal(x: Any, y: Any) -> bool:
    if is_dataclass(x) and not isinstance(x, type):
        return type(x) is type(y) and all(
            _equal(getattr(x, f.name), getattr(y, f.name)) for f in fields(x)
        )
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        if not (isinstance(x, np.ndarray) and isinstance(y, np.ndarray)):
            return False
        return x.shape == y.shape and bool(np.array_equal(x, y))
    if isinstance(x, tuple | list):
        return (
            isinstance(y, tuple | list)
            and len(x) == len(y)
            and all(_equal(i, j) for i, j in zip(x, y, strict=True))
        )
    return type(x) is type(y) and x == y
