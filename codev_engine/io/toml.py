"""TOML written back from parsed values: the one writer of TOML literals and documents.

``tomllib`` reads TOML but the standard library cannot write it. The sweep writes each
design as the base spec with its swept fields set, and the workbench writes its form and its
sweep grid; all go through :func:`toml_literal`, so a value that ``tomllib.loads`` gives is
written back to text that ``tomllib.loads`` reads equal (floats by ``repr``, which
round-trips; inf and nan by name; strings with TOML's basic-string escapes). Nothing here
evaluates anything.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from typing import Any

__all__ = ["toml_literal", "toml_key", "toml_string", "dumps_toml"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def toml_string(s: str, *, ascii_only: bool = False) -> str:
    """A TOML basic string for ``s``.

    Parameters
    ----------
    s : str
    ascii_only : bool
        Escape every character outside ASCII (``\\u00fc``) instead of writing it as it is.

    Returns
    -------
    str
        ``s`` quoted: JSON's escapes are TOML's, but TOML also forbids a raw DEL (U+007F),
        which JSON leaves as it is.
    """
    return json.dumps(s, ensure_ascii=ascii_only).replace("\x7f", "\\u007f")


def toml_key(k: str, *, ascii_only: bool = False) -> str:
    """A TOML key: bare when it may be, else quoted.

    Parameters
    ----------
    k : str
    ascii_only : bool
        As in :func:`toml_string`.

    Returns
    -------
    str
    """
    return k if _BARE_KEY.fullmatch(k) else toml_string(k, ascii_only=ascii_only)


def toml_literal(value: Any, *, readable: bool = False) -> str:
    """A TOML literal for a value as ``tomllib`` returns it (read back equal).

    Parameters
    ----------
    value : bool, int, float, str, list, tuple or dict
        Nested lists and tables included; numpy scalars and arrays are taken as their
        ``tolist()``.
    readable : bool
        The layout a person types (the workbench's form): characters outside ASCII as they
        are, inline tables spaced (``{ a = 1 }``), a list of tables one table per line.
        False (default): compact and ASCII only (``{a = 1}``, ``\\u00fc``), the layout of
        a sweep's design texts, whose hash names the design's folder and must not change.

    Returns
    -------
    str

    Raises
    ------
    TypeError
        A value of another type (TOML has no literal for it: dates are not used by specs).
    """
    if hasattr(value, "tolist") and not isinstance(value, (list, dict)):
        value = value.tolist()  # numpy scalars and arrays as Python values
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return toml_string(value, ascii_only=not readable)
    if isinstance(value, dict):
        inner = ", ".join(
            f"{toml_key(k, ascii_only=not readable)} = {toml_literal(v, readable=readable)}"
            for k, v in value.items()
        )
        return "{ " + inner + " }" if readable else "{" + inner + "}"
    if isinstance(value, (list, tuple)):
        items = [toml_literal(v, readable=readable) for v in value]
        if readable and value and all(isinstance(v, dict) for v in value):
            return "[\n" + "".join(f"  {item},\n" for item in items) + "]"
        return "[" + ", ".join(items) + "]"
    raise TypeError(f"no TOML literal for {type(value).__name__}")


def dumps_toml(data: Mapping[str, Any]) -> str:
    """Write parsed TOML data back as a TOML document (``tomllib.loads`` reads it equal).

    Parameters
    ----------
    data : mapping
        Values as ``tomllib.loads`` gives them (see :func:`toml_literal`).

    Returns
    -------
    str
        Top-level values first, then one ``[table]`` per top-level table, the values in
        it inline, compact and ASCII only (``toml_literal``'s default layout).

    Raises
    ------
    TypeError
        A value TOML cannot hold.
    """
    def key(k: str) -> str:
        return toml_key(k, ascii_only=True)

    lines = [f"{key(k)} = {toml_literal(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            lines.append(f"\n[{key(k)}]")
            lines.extend(f"{key(k2)} = {toml_literal(v2)}" for k2, v2 in v.items())
    return "\n".join(lines) + "\n"
