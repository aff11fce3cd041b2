"""Safe parser for the dynamics expressions of a spec.

The text is *parsed* with :func:`ast.parse` (``mode="eval"``) and never executed: the syntax
tree is walked node by node and the sympy expression is built from a whitelist of constructs.
``eval``, ``exec``, ``sympy.sympify`` and ``parse_expr`` are never called on user text.

Accepted:

- numeric literals (int, float; no complex, strings or booleans);
- names: the state and input names passed in ``names``, and the constants ``pi`` and ``e``;
- binary ``+ - * / **`` and unary ``+ -``;
- calls of the functions in :data:`FUNCTIONS` with positional arguments and the right arity.

Everything else raises :class:`~codev_engine.errors.SpecError` naming the offending construct.
"""

from __future__ import annotations

import ast
import math
import sys
from collections.abc import Callable, Mapping

import sympy

from codev_engine.errors import SpecError
from codev_engine.spec.choices import RESERVED_NAMES as _RESERVED

__all__ = ["CONSTANTS", "FUNCTIONS", "RESERVED_NAMES", "make_symbol", "parse_expression"]

#: Named constants usable in expressions.
CONSTANTS: dict[str, sympy.Expr] = {"pi": sympy.pi, "e": sympy.E}

# name -> (sympy constructor, minimum arity, maximum arity or None for unbounded)
_FUNCTION_TABLE: dict[str, tuple[Callable[..., sympy.Expr], int, int | None]] = {
    "sin": (sympy.sin, 1, 1),
    "cos": (sympy.cos, 1, 1),
    "tan": (sympy.tan, 1, 1),
    "asin": (sympy.asin, 1, 1),
    "acos": (sympy.acos, 1, 1),
    "atan": (sympy.atan, 1, 1),
    "atan2": (sympy.atan2, 2, 2),
    "sinh": (sympy.sinh, 1, 1),
    "cosh": (sympy.cosh, 1, 1),
    "tanh": (sympy.tanh, 1, 1),
    "exp": (sympy.exp, 1, 1),
    "log": (sympy.log, 1, 1),
    "sqrt": (sympy.sqrt, 1, 1),
    "abs": (sympy.Abs, 1, 1),
    "sign": (sympy.sign, 1, 1),
    "min": (sympy.Min, 2, None),
    "max": (sympy.Max, 2, None),
}

#: Names of the functions usable in expressions.
FUNCTIONS: frozenset[str] = frozenset(_FUNCTION_TABLE)

#: Names that cannot be used as state or input names (``spec.choices.RESERVED_NAMES``, which
#: the parser reads without importing sympy, is the same set)
RESERVED_NAMES: frozenset[str] = frozenset(CONSTANTS) | FUNCTIONS
if RESERVED_NAMES != _RESERVED:  # pragma: no cover - the two lists are edited together
    raise ImportError("spec.choices.RESERVED_NAMES differs from spec.expr's names")

_MAX_LENGTH = 10_000  # characters of one expression
_MAX_EXPONENT = 1_000  # |constant exponent|; stops 9**9**9-style blow-ups
_MAX_DEPTH = 200  # nesting depth of the syntax tree
_MAX_FLOAT = sys.float_info.max  # |constant|: what evaluates to a float

_BINOPS: dict[type[ast.operator], Callable[[sympy.Expr, sympy.Expr], sympy.Expr]] = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
}

_BAD_BINOPS: dict[type[ast.operator], str] = {
    ast.BitXor: "'^' is not a power operator here; use ** for powers",
    ast.Mod: "the operator '%' is not allowed",
    ast.FloorDiv: "the operator '//' is not allowed (use / for division)",
    ast.MatMult: "the operator '@' is not allowed",
    ast.BitAnd: "the operator '&' is not allowed",
    ast.BitOr: "the operator '|' is not allowed",
    ast.LShift: "the operator '<<' is not allowed",
    ast.RShift: "the operator '>>' is not allowed",
}

_BAD_NODES: dict[type[ast.AST], str] = {
    ast.Attribute: "attribute access ('.') is not allowed",
    ast.Subscript: "subscripts ('[...]') are not allowed",
    ast.Lambda: "lambda expressions are not allowed",
    ast.ListComp: "comprehensions are not allowed",
    ast.SetComp: "comprehensions are not allowed",
    ast.DictComp: "comprehensions are not allowed",
    ast.GeneratorExp: "comprehensions are not allowed",
    ast.Compare: "comparisons are not allowed",
    ast.BoolOp: "boolean operators (and, or) are not allowed",
    ast.IfExp: "conditional expressions (... if ... else ...) are not allowed",
    ast.List: "lists are not allowed",
    ast.Tuple: "tuples are not allowed (check the commas)",
    ast.Set: "sets are not allowed",
    ast.Dict: "dicts are not allowed",
    ast.JoinedStr: "strings are not allowed",
    ast.NamedExpr: "assignment expressions (:=) are not allowed",
    ast.Starred: "starred arguments are not allowed",
    ast.Await: "await is not allowed",
    ast.Yield: "yield is not allowed",
    ast.YieldFrom: "yield is not allowed",
    ast.Slice: "slices are not allowed",
}


def _show(text: str, limit: int = 80) -> str:
    """``repr`` of an expression for messages, shortened if long."""
    return repr(text) if len(text) <= limit else repr(text[: limit - 3] + "...")


class _Builder:
    """Walks an ``ast`` expression tree and builds the sympy expression."""

    def __init__(self, text: str, names: Mapping[str, sympy.Symbol], field: str | None):
        self.text = text
        self.names = names
        self.field = field

    def fail(self, reason: str) -> SpecError:
        return SpecError(f"in expression {_show(self.text)}: {reason}", field=self.field)

    def known(self) -> str:
        return ", ".join([*self.names, *CONSTANTS])

    def build(self, node: ast.AST, depth: int = 0) -> sympy.Expr:
        if depth > _MAX_DEPTH:
            raise self.fail("expression is nested too deeply")
        if isinstance(node, ast.Constant):
            return self.constant(node.value)
        if isinstance(node, ast.Name):
            return self.name(node.id)
        if isinstance(node, ast.UnaryOp):
            operand = self.build(node.operand, depth + 1)
            if isinstance(node.op, ast.USub):
                return -operand
            if isinstance(node.op, ast.UAdd):
                return operand
            if isinstance(node.op, ast.Not):
                raise self.fail("boolean operators (not) are not allowed")
            raise self.fail("the operator '~' is not allowed")
        if isinstance(node, ast.BinOp):
            op = type(node.op)
            if op in _BAD_BINOPS:
                raise self.fail(_BAD_BINOPS[op])
            left = self.build(node.left, depth + 1)
            right = self.build(node.right, depth + 1)
            if op is ast.Pow:
                return self.power(left, right)
            if op in _BINOPS:
                return _BINOPS[op](left, right)
            raise self.fail(f"the operator {op.__name__} is not allowed")  # pragma: no cover
        if isinstance(node, ast.Call):
            return self.call(node, depth)
        if isinstance(node, ast.Attribute | ast.Subscript):
            # Report a bad name inside first (``__import__('os').system`` -> ``__import__``).
            self.build(node.value, depth + 1)
        for kind, reason in _BAD_NODES.items():
            if isinstance(node, kind):
                raise self.fail(reason)
        raise self.fail(f"unsupported construct ({type(node).__name__})")

    def constant(self, value: object) -> sympy.Expr:
        if isinstance(value, bool):
            raise self.fail(f"booleans are not allowed ({value!r})")
        if isinstance(value, int):
            if abs(value) > _MAX_FLOAT:  # would overflow every numeric evaluation
                raise self.fail(
                    f"the integer of {len(str(abs(value)))} digits is too large (at most "
                    "about 1.8e308)"
                )
            return sympy.Integer(value)
        if isinstance(value, float):
            if not math.isfinite(value):
                raise self.fail(f"the number {value!r} is not finite")
            return sympy.Float(value)
        if isinstance(value, complex):
            raise self.fail(f"complex numbers are not allowed ({value!r})")
        if isinstance(value, str | bytes):
            raise self.fail(f"strings are not allowed ({value!r})")
        raise self.fail(f"the constant {value!r} is not allowed")

    def name(self, name: str) -> sympy.Expr:
        if name in self.names:
            return self.names[name]
        if name in CONSTANTS:
            return CONSTANTS[name]
        if name in FUNCTIONS:
            raise self.fail(f"{name!r} is a function; call it as {name}(...)")
        raise self.fail(f"unknown name {name!r} (known: {self.known()})")

    def power(self, base: sympy.Expr, exponent: sympy.Expr) -> sympy.Expr:
        if exponent.is_number:
            try:
                big = abs(float(exponent)) > _MAX_EXPONENT
            except TypeError:  # pragma: no cover - complex exponent; rejected later anyway
                big = False
            if big:
                raise self.fail(f"the exponent {exponent} is too large (|exponent| <= 1000)")
        return base**exponent

    def call(self, node: ast.Call, depth: int) -> sympy.Expr:
        func = node.func
        if not isinstance(func, ast.Name):
            if isinstance(func, ast.Attribute):
                self.build(func.value, depth + 1)
                raise self.fail("attribute access ('.') is not allowed")
            raise self.fail("only calls of named functions are allowed")
        fname = func.id
        if fname not in _FUNCTION_TABLE:
            if fname in self.names or fname in CONSTANTS:
                raise self.fail(f"{fname!r} is not a function")
            allowed = ", ".join(sorted(FUNCTIONS))
            raise self.fail(f"unknown function {fname!r} (allowed: {allowed})")
        if node.keywords:
            raise self.fail(f"keyword arguments are not allowed (in the call of {fname})")
        if any(isinstance(a, ast.Starred) for a in node.args):
            raise self.fail(f"starred arguments are not allowed (in the call of {fname})")
        ctor, lo, hi = _FUNCTION_TABLE[fname]
        nargs = len(node.args)
        if nargs < lo or (hi is not None and nargs > hi):
            if hi is None:
                want = f"at least {lo} arguments"
            elif lo == hi:
                want = f"{lo} argument" + ("s" if lo != 1 else "")
            else:  # pragma: no cover - no such function yet
                want = f"{lo} to {hi} arguments"
            raise self.fail(f"{fname}() takes {want}, got {nargs}")
        args = [self.build(a, depth + 1) for a in node.args]
        return ctor(*args)


def parse_expression(
    text: str, names: Mapping[str, sympy.Symbol], *, field: str | None = None
) -> sympy.Expr:
    """Parse one dynamics expression into a sympy expression, safely.

    Parameters
    ----------
    text : str
        The expression, e.g. ``"-9.81*sin(th) - 0.1*w + T"``.
    names : mapping of str to sympy.Symbol
        The names the expression may use (states and inputs), besides ``pi`` and ``e``.
    field : str, optional
        Dotted spec field the text came from (``plant.dynamics[1]``), for error messages.

    Returns
    -------
    sympy.Expr
        The expression, built only from the whitelisted constructs.

    Raises
    ------
    SpecError
        On a syntax error or any construct outside the whitelist; the reason names it.
    """
    if not isinstance(text, str):
        raise SpecError(f"expected an expression string, got {type(text).__name__}", field=field)
    if len(text) > _MAX_LENGTH:
        raise SpecError(f"expression longer than {_MAX_LENGTH} characters", field=field)
    if not text.strip():
        raise SpecError("empty expression", field=field)
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        where = f" at column {exc.offset}" if exc.offset else ""
        raise SpecError(
            f"invalid expression {_show(text)}: {exc.msg}{where}", field=field
        ) from None
    except (ValueError, RecursionError, MemoryError) as exc:  # e.g. null bytes, deep nesting
        raise SpecError(f"invalid expression {_show(text)}: {exc}", field=field) from None
    builder = _Builder(text, names, field)
    try:
        expr = builder.build(tree.body)
    except RecursionError:
        raise builder.fail("expression is nested too deeply") from None
    if expr.has(sympy.zoo, sympy.oo, -sympy.oo, sympy.nan):
        raise builder.fail("the expression is undefined or infinite (division by zero?)")
    if expr.has(sympy.I):
        raise builder.fail("the expression has a complex value")
    for number in expr.atoms(sympy.Number):  # e.g. 10**400 or 1e308*10, folded by sympy
        if not abs(number) <= _MAX_FLOAT:
            raise builder.fail(
                "a constant is too large to evaluate as a float (at most about 1.8e308)"
            )
    return expr


def make_symbol(name: str) -> sympy.Symbol:
    """Return the sympy symbol of a state or input name.

    Every module builds its symbols through this function, so that the symbols of one name
    are equal everywhere (sympy compares symbols by name *and* assumptions).

    Parameters
    ----------
    name : str
        A state or input name of the spec.

    Returns
    -------
    sympy.Symbol
        Real-valued, so ``abs``, ``sign`` and their derivatives simplify as for real
        numbers.
    """
    return sympy.Symbol(name, real=True)
