"""The values a spec's choice fields accept (``mpc.norm``, ``model.method``, ``verify.hold``).

A module of its own, with no imports, so that the workbench can offer the choices without
loading the spec loader (which loads sympy).
"""

from __future__ import annotations

__all__ = ["HOLDS", "METHODS", "NORMS", "REGIONS", "RESERVED_NAMES"]

#: Accepted values of ``mpc.norm`` (after normalisation).
NORMS: tuple[str, ...] = ("1", "inf", "2")
#: Accepted values of ``model.method`` (python-control / scipy discretisation methods).
METHODS: tuple[str, ...] = ("zoh", "foh", "tustin", "bilinear", "euler", "backward_diff", "impulse")
#: Accepted values of ``verify.hold``.
HOLDS: tuple[str, ...] = ("zoh", "continuous")
#: Accepted values of ``synthesis.regions``: the whole partition, or the regions the
#: verification reaches (computed on demand, ``law_on_demand.py``).
REGIONS: tuple[str, ...] = ("all", "reached")
#: Names of the expression language's constants and functions (``spec.expr``: ``CONSTANTS``
#: and ``FUNCTIONS``, which it checks against this), which cannot name a state or an input;
#: here so that a spec without dynamics is read without sympy.
RESERVED_NAMES: frozenset[str] = frozenset({
    "pi", "e", "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh",
    "exp", "log", "sqrt", "abs", "sign", "min", "max",
})
