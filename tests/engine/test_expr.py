"""Tests of the safe expression parser (codev_engine.expr)."""

from __future__ import annotations

import ast
import builtins
import inspect
from pathlib import Path

import pytest
import sympy

from codev_engine.errors import SpecError
from codev_engine.spec import expr as expr_module
from codev_engine.spec.expr import FUNCTIONS, RESERVED_NAMES, make_symbol, parse_expression

X1, X2, U = make_symbol("x1"), make_symbol("x2"), make_symbol("u")
NAMES = {"x1": X1, "x2": X2, "u": U}


def parse(text: str) -> sympy.Expr:
    return parse_expression(text, NAMES, field="plant.dynamics[0]")


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("x2", X2),
        ("u", U),
        ("3", sympy.Integer(3)),
        ("2.5 * x1", sympy.Float(2.5) * X1),
        ("x1 + x2 - u", X1 + X2 - U),
        ("x1 / 2", X1 / 2),
        ("x1 ** 2", X1**2),
        ("-x1", -X1),
        ("+x1", X1),
        ("-(x1 + u) * 2", -2 * (X1 + U)),
        ("-9.81*sin(x1) - 0.1*x2 + u", -sympy.Float(9.81) * sympy.sin(X1) - 0.1 * X2 + U),
        ("cos(x1) + tan(x2)", sympy.cos(X1) + sympy.tan(X2)),
        ("asin(x1) + acos(x1) + atan(x1)", sympy.asin(X1) + sympy.acos(X1) + sympy.atan(X1)),
        ("atan2(x1, x2)", sympy.atan2(X1, X2)),
        ("sinh(x1) + cosh(x1) + tanh(x1)", sympy.sinh(X1) + sympy.cosh(X1) + sympy.tanh(X1)),
        ("exp(x1) + log(x2) + sqrt(u)", sympy.exp(X1) + sympy.log(X2) + sympy.sqrt(U)),
        ("abs(x1)", sympy.Abs(X1)),
        ("sign(x1)", sympy.sign(X1)),
        ("min(x1, x2)", sympy.Min(X1, X2)),
        ("max(x1, x2, u)", sympy.Max(X1, X2, U)),
        ("pi * e * x1", sympy.pi * sympy.E * X1),
        ("  x1  ", X1),
        ("2**10", sympy.Integer(1024)),
    ],
)
def test_valid_expressions(text, expected):
    got = parse(text)
    assert isinstance(got, sympy.Expr)
    assert sympy.simplify(got - expected) == 0


def test_symbols_are_the_given_ones():
    got = parse("x1 + u")
    assert got.free_symbols == {X1, U}


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("y + 1", "unknown name 'y' (known: x1, x2, u, pi, e)"),
        ("foo(x1)", "unknown function 'foo'"),
        ("x1 ^ 2", "use ** for powers"),
        ("x1.real", "attribute access"),
        ("(1).__class__", "attribute access"),
        ("x1[0]", "subscripts"),
        ("lambda: 1", "lambda"),
        ("[x for x in (1, 2)]", "comprehensions"),
        ("x1 < 2", "comparisons"),
        ("x1 and u", "boolean operators"),
        ("not x1", "boolean operators"),
        ("x1 if u else x2", "conditional"),
        ("x1 % 2", "'%'"),
        ("x1 // 2", "'//'"),
        ("x1 @ x2", "'@'"),
        ("~x1", "'~'"),
        ("x1 & u", "'&'"),
        ("'text'", "strings are not allowed"),
        ("True", "booleans are not allowed"),
        ("1j", "complex numbers"),
        ("1e999", "not finite"),
        ("(x1, x2)", "tuples"),
        ("[x1]", "lists"),
        ("{x1: 1}", "dicts"),
        ("sin", "'sin' is a function"),
        ("x1(2)", "'x1' is not a function"),
        ("pi(2)", "'pi' is not a function"),
        ("sin(x1, x2)", "sin() takes 1 argument, got 2"),
        ("sin()", "sin() takes 1 argument, got 0"),
        ("atan2(x1)", "atan2() takes 2 arguments, got 1"),
        ("min(x1)", "min() takes at least 2 arguments, got 1"),
        ("max()", "max() takes at least 2 arguments, got 0"),
        ("sin(x=x1)", "keyword arguments"),
        ("sin(*x1)", "starred"),
        ("x1.sin()", "attribute access"),
        ("__import__('os')", "unknown function '__import__'"),
        ("eval('1')", "unknown function 'eval'"),
        ("open('/etc/passwd')", "unknown function 'open'"),
        ("globals", "unknown name 'globals'"),
        ("(x := 1)", "assignment"),
        ("f'{x1}'", "strings"),
        ("1/0", "division by zero"),
        ("log(0)", "undefined or infinite"),
        ("sqrt(-1)", "complex value"),
        ("9**9**9", "exponent"),
        ("x1 +", "invalid expression"),
        ("x1 = 2", "invalid expression"),
        ("import os", "invalid expression"),
        ("", "empty expression"),
        ("   ", "empty expression"),
        ("-" * 400 + "x1", "nested too deeply"),
    ],
)
def test_rejected_expressions(text, fragment):
    with pytest.raises(SpecError) as info:
        parse(text)
    assert fragment in info.value.reason
    assert info.value.field == "plant.dynamics[0]"


def test_non_string_rejected():
    with pytest.raises(SpecError, match="expected an expression string"):
        parse_expression(3, NAMES, field="f")  # type: ignore[arg-type]


def test_long_expression_rejected():
    with pytest.raises(SpecError, match="longer than"):
        parse(" + ".join(["x1"] * 5000))


def test_injection_is_not_executed(tmp_path):
    target = tmp_path / "pwned"
    existed = Path("/tmp/pwned").exists()
    for text in (
        "__import__('os').system('touch /tmp/pwned')",
        f"__import__('os').system('touch {target}')",
        f"().__class__.__base__.__subclasses__()[0]('touch {target}')",
        f"exec(\"open('{target}', 'w')\")",
    ):
        with pytest.raises(SpecError):
            parse(text)
    assert not target.exists()
    if not existed:
        assert not Path("/tmp/pwned").exists()


def test_parser_never_evaluates(monkeypatch):
    """Parsing works with eval/exec/compile made unusable."""

    def boom(*args, **kwargs):
        raise AssertionError("eval/exec/compile called")

    monkeypatch.setattr(builtins, "eval", boom)
    monkeypatch.setattr(builtins, "exec", boom)
    monkeypatch.setattr(sympy, "sympify", boom)
    monkeypatch.setattr(sympy, "parse_expr", boom)
    assert parse("-9.81*sin(x1) + max(x2, u) ** 2") is not None


def test_module_has_no_dangerous_calls():
    """Static check: expr.py never calls eval/exec/compile/sympify/parse_expr."""
    tree = ast.parse(inspect.getsource(expr_module))
    banned = {"eval", "exec", "compile", "sympify", "parse_expr", "__import__", "S"}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            assert name not in banned, f"expr.py calls {name}"


def test_reserved_names():
    assert {"pi", "e", "sin", "atan2", "min", "max", "abs"} <= RESERVED_NAMES
    assert "sign" in FUNCTIONS
