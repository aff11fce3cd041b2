"""Stage keys: the content hash a stage's artifact is cached under.

A key is the SHA-256 of a canonical JSON document ``{"engine", "stage", "inputs"}``: the
engine version, the stage's name and its inputs as the stage table declares them (spec
sections, run options, the keys of the stages upstream). Floats are written exactly
(``float.hex``), arrays by dtype, shape and the SHA-256 of their little-endian bytes, so a key
is the same on every machine and changes exactly when something the stage reads changes.
"""

from __future__ import annotations

import json
from dataclasses import fields, is_dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from codev_engine.session.options import DEFAULT_OPTIONS, RunOptions
from codev_engine.session.stages import TABLE, StageTable
from codev_engine.session.store import sha
from codev_engine.version import __version__

if TYPE_CHECKING:
    from codev_engine.spec.problem import Problem

__all__ = ["canon", "stage_key", "stage_keys"]


def canon(obj: Any) -> Any:
    """A JSON-able, exact and machine-independent rendering of spec data for hashing.

    Floats as ``float.hex`` (exact), arrays by dtype, shape and the SHA-256 of their
    little-endian bytes, dataclasses as dicts of their fields.

    Parameters
    ----------
    obj : object
        Spec data: dataclasses, arrays, numbers, strings, None, lists, tuples, dicts.

    Returns
    -------
    object
        Nested dicts, lists, strings, ints, bools and None.

    Raises
    ------
    TypeError
        For any other type (nothing is hashed by ``repr``).
    """
    if is_dataclass(obj) and not isinstance(obj, type):
        # a field added to the contract later is left out while it keeps its default, so
        # the keys of sessions made before it existed do not change
        return {
            f.name: canon(getattr(obj, f.name))
            for f in fields(obj)
            if not (
                f.metadata.get("key_omit_default")
                and _is_default(getattr(obj, f.name), f.default)
            )
        }
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.kind == "f":
            a = a.astype("<f8")
        elif a.dtype.kind in "iub":
            a = a.astype("<i8")
        elif a.dtype.kind == "U":
            return {"text": a.tolist()}
        return {"dtype": a.dtype.str, "shape": list(a.shape), "sha256": sha(a.tobytes())}
    if isinstance(obj, bool) or obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj).hex()
    if isinstance(obj, (list, tuple)):
        return [canon(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): canon(v) for k, v in obj.items()}
    raise TypeError(f"cannot hash {type(obj).__name__}")


def _is_default(value: Any, default: Any) -> bool:
    if default is None:
        return value is None
    return type(value) is type(default) and value == default


def stage_key(stage: str, inputs: dict[str, Any]) -> str:
    """The key of a stage with its inputs (see the module docstring).

    Parameters
    ----------
    stage : str
        The stage name.
    inputs : dict
        What the stage's table entry says its key hashes.

    Returns
    -------
    str
        64 hex digits.
    """
    doc = {"engine": __version__, "stage": stage, "inputs": canon(inputs)}
    return sha(json.dumps(doc, sort_keys=True, separators=(",", ":")).encode())


def stage_keys(
    problem: Problem, options: RunOptions = DEFAULT_OPTIONS, table: StageTable = TABLE
) -> dict[str, str]:
    """The key of every stage for a problem and run options (no computation).

    Parameters
    ----------
    problem : Problem
    options : RunOptions
    table : StageTable
        The stages, in order (default: codev's).

    Returns
    -------
    dict
        Stage name -> 64-hex key, in table order; a stage that does not apply to the spec
        (verification without a ``[verify]`` section) is absent.
    """
    keys: dict[str, str] = {}
    for stage in table:
        inputs = stage.inputs(problem, options, keys)
        if inputs is not None:
            keys[stage.name] = stage_key(stage.name, inputs)
    return keys
