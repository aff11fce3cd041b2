"""A sweep's grid: ``FIELD=V1,V2,...`` texts parsed into ``{field: [values]}``, the
Cartesian product of the values, and each design as the base spec's TOML text with the swept
fields set (written back to TOML, never evaluated), named by a short hash of that text."""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
from collections.abc import Mapping, Sequence
from typing import Any

from codev_engine.errors import SpecError
from codev_engine.io.toml import dumps_toml, toml_literal


def parse_sets(items: Sequence[str], *, origin: str = "--set") -> dict[str, list]:
    """``FIELD=V1,V2,...`` texts -> the grid ``{field: [values]}``, each value a TOML value.

    Parameters
    ----------
    items : sequence of str
        One swept field each: ``mpc.horizon=2,4,6``, ``mpc.R=[[0.1]],[[1.0]]``,
        ``mpc.norm="inf","1"``.
    origin : str
        Where the texts came from, named in errors (``--set``, a form field).

    Returns
    -------
    dict of str to list
        In the order given (the first field varies slowest in the sweep).

    Raises
    ------
    SpecError
        A text without ``=`` or a name, a field given twice, values that are not a list of
        TOML values, or no values; one line naming the field.
    """
    grid: dict[str, list] = {}
    for item in items:
        name, eq, text = item.partition("=")
        name = name.strip()
        if not eq or not name:
            raise SpecError(f"expected FIELD=V1,V2,... got {item!r}", field=origin)
        if name in grid:
            raise SpecError("set twice", field=f"{origin} {name}")
        try:
            values = tomllib.loads(f"v = [{text}]")["v"]
        except ValueError:  # TOMLDecodeError, or an integer of more than 4,300 digits
            raise SpecError(
                f"not a list of TOML values: {text!r} (strings need quotes: '\"a\",\"b\"')",
                field=f"{origin} {name}",
            ) from None
        if not values:
            raise SpecError("no values", field=f"{origin} {name}")
        grid[name] = values
    return grid


def design_id(text: str) -> str:
    """The name of a design's session folder: 16 hex digits of the SHA-256 of its text.

    Parameters
    ----------
    text : str
        The design's TOML document.

    Returns
    -------
    str
    """
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def grid_values(grid: Mapping[str, Sequence[Any]]) -> list[dict]:
    """Each design's swept values, in the sweep's order (the first field varies slowest).

    Parameters
    ----------
    grid : mapping of str to sequence

    Returns
    -------
    list of dict
    """
    return _value_rows(grid)


def _value_rows(grid: Mapping[str, Sequence[Any]]) -> list[dict]:
    names = list(grid)
    return [dict(zip(names, combo, strict=True)) for combo in itertools.product(*grid.values())]


def design_texts(problem, grid: Mapping[str, Sequence[Any]]) -> list[str]:
    """The TOML text of every design of ``grid``, each checked by the loader.

    Parameters
    ----------
    problem : Problem
        The base design; its ``source`` is the TOML text edited.
    grid : mapping of str to sequence
        As :func:`sweep`.

    Returns
    -------
    list of str
        One TOML document per design, in the product's order.

    Raises
    ------
    SpecError
        As :func:`sweep`.
    """
    return [text for text, _ in designs(problem, grid)]


def design_cost(problem) -> float:
    """A rough estimate of what a design costs to synthesise and verify, to start the
    costliest designs of a sweep first (only their order on the workers depends on it).

    Parameters
    ----------
    problem : Problem
        The design, as the loader gives it.

    Returns
    -------
    float
        The size of its mp program: the decision variables (the free moves ``Nc m``, and
        for norms "1" and "inf" the slack of every stage's and the terminal cost's rows)
        times the constraint rows of the prediction (``N`` times the finite state and
        input bounds, both sides), plus the prediction's length ``N`` as a tie-break.
    """
    import numpy as np

    mpc = problem.mpc
    N = int(mpc.horizon)
    variables = int(mpc.Nc) * int(problem.plant.m)
    if mpc.norm != "2":
        rows = np.atleast_2d(mpc.Q).shape[0] + np.atleast_2d(mpc.R).shape[0]
        variables += N * rows + (0 if mpc.P is None else np.atleast_2d(mpc.P).shape[0])
    bounds = sum(int(np.count_nonzero(np.isfinite(np.asarray(v, dtype=float))))
                 for v in (mpc.x_min, mpc.x_max, mpc.u_min, mpc.u_max))
    return float(variables * N * max(bounds, 1) + N)


def designs(problem, grid: Mapping[str, Sequence[Any]]) -> list[tuple[str, Any]]:
    """Each design of ``grid``: its TOML text and the loader's problem of it.

    Parameters
    ----------
    problem : Problem
        The base design; its ``source`` is the TOML text edited.
    grid : mapping of str to sequence
        As :func:`sweep`.

    Returns
    -------
    list of (str, Problem)
        In the product's order.

    Raises
    ------
    SpecError
        As :func:`design_texts`.
    """
    from codev_engine.pipeline import loads_spec

    base = tomllib.loads(problem.source)
    file = problem.path or "<string>"
    for name, vals in grid.items():
        if isinstance(vals, (str, bytes)) or not isinstance(vals, Sequence) or not len(vals):
            raise SpecError("a swept field needs a non-empty list of values", file=file,
                            field=name)
        for v in vals:
            try:
                toml_literal(v)
            except TypeError:
                raise SpecError(f"not a TOML value: {type(v).__name__}", file=file,
                                field=name) from None
    out = []
    for values in _value_rows(grid):
        data = json.loads(json.dumps(base))  # a deep copy of plain TOML data
        for name, value in values.items():
            set_field(data, name, value)
        text = dumps_toml(data)
        label = ", ".join(f"{k} = {toml_literal(v)}" for k, v in values.items())
        # the loader's checks, one line each
        out.append((text, loads_spec(text, path=f"{file} [{label}]")))
    return out


def set_field(data: dict, name: str, value: Any) -> None:
    """Set the dotted field ``name`` of a parsed TOML document to ``value`` (in place).

    Parameters
    ----------
    data : dict
        From ``tomllib.loads``.
    name : str
        ``table.key`` or deeper (``verify.initial_set.lower``); missing tables are made.
    value : object
        A TOML value.

    Raises
    ------
    SpecError
        An empty part of the name, or a part that is a value, not a table.
    """
    parts = name.split(".")
    if not all(p.strip() for p in parts):
        raise SpecError("not a dotted field name", field=name)
    node = data
    for i, part in enumerate(parts[:-1]):
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise SpecError("is a value, not a table", field=".".join(parts[: i + 1]))
        node = nxt
    node[parts[-1]] = value
