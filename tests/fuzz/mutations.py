"""Hypothesis strategies of hostile inputs: specs (mutated bundled examples), session folders
and law files. Shared by the fuzz properties and the held-out fuzzer (tests/fuzz/heldout.py).

Text that would run if executed writes the canary file ``CANARY`` (the placeholder is replaced
by an absolute path in the example's temporary folder before the file is written).
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from hypothesis import strategies as st

from tests.fuzz.contract import Raw, toml_dumps

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"

#: bundled examples whose ``codev run`` takes a few seconds at most (the default budget)
CHEAP = (
    "double_integrator.toml",
    "cruise_control.toml",
    "vanderpol.toml",
    "mass_spring_soft.toml",
    "double_integrator_lqr.toml",
    "two_carts_mixed.toml",
)
ALL = tuple(sorted(p.name for p in EXAMPLES.glob("*.toml")))

CANARY = "CANARY"  # replaced by the example's canary path

# ---- hostile atoms ---------------------------------------------------------------------------


def big_int(digits: int, sign: str = "") -> Raw:
    """A ``digits``-digit TOML integer written as text (never through ``int``)."""
    return Raw(sign + "7" + "3" * (digits - 1))


BIG_NUMBERS = [
    big_int(400), big_int(400, "-"), big_int(5001), big_int(5001, "-"), big_int(20),
    1e308, -1e308, 1.7976931348623157e308, 5e-324, -5e-324, 1e-300,
    float("nan"), float("inf"), float("-inf"), "nan", "inf", "-inf", "1e308", "NaN",
    0, 0.0, -0.0, -1, -1.0, 1, 2**63 - 1, -(2**63), 2**64, 10**18,
    Raw("0x7fffffffffffffff"), Raw("1e400"), Raw("-1e400"), Raw("1_000_000_000"),
]

HUGE_HORIZONS = [10**3, 10**4, 10**6, 10**9, 2**31, 2**63 - 1, 0, -1, -(10**6)]

HOSTILE_EXPRESSIONS = [
    f'__import__("os").system("touch {CANARY}")',
    f'open("{CANARY}", "w")',
    f'exec("open(\'{CANARY}\', \'w\')")',
    f'eval("open(\'{CANARY}\', \'w\')")',
    f'(lambda: open("{CANARY}", "w"))()',
    "lambda x: x",
    "x1.__class__.__bases__[0].__subclasses__()",
    "().__class__.__base__.__subclasses__()",
    "x1.real",
    "x1^2",
    "x1 ** 10**10",
    "x1 ** 1e308",
    "exp(exp(exp(exp(1000))))",
    "exp(1e308)",
    "10**10**10",
    "1/0",
    "log(0)",
    "sqrt(-1)",
    "9" * 5001,
    "9" * 400 + " * x1",
    "1e308 * 1e308 * x1",
    "x1 if x1 else x2",
    "[x1 for x1 in range(10**9)]",
    "x1 and x2",
    "x1 < x2",
    "f'{x1}'",
    "x1[0]",
    "max()",
    "min(x1)",
    "sin(x1, x2)",
    "sin(x=x1)",
    "'*' * 10**9",
    "",
    " ",
    "x1 +",
    "((((((((((x1",
    "\x00",
    "u; import os",
    "x1 # comment",
    "Symbol('x')",
    "S('x')",
    "Integer(10)**Integer(10)**Integer(10)",
]


def nested_expressions() -> st.SearchStrategy[str]:
    return st.builds(
        lambda fn, depth: fn * depth + "u" + ")" * depth,
        st.sampled_from(["tanh(", "sin(", "exp(", "sqrt(", "abs(", "max(u, ", "log("]),
        st.sampled_from([5, 12, 30, 60, 200, 1000, 5000]),
    ) | st.builds(
        lambda depth: "(" * depth + "u" + ")" * depth, st.sampled_from([100, 1000, 100_000]),
    ) | st.builds(
        lambda k: " + ".join(f"x1**{i}" for i in range(k)), st.sampled_from([50, 400, 3000]),
    ) | st.builds(
        lambda k: "*".join(["(x1 + u)"] * k), st.sampled_from([20, 60, 200]),
    )


HOSTILE_NAMES = [
    "__import__", "lambda", "os", "exec", "e", "pi", "sin", "x.y", "x-1", "1x", "", " ",
    "x" * 10_000, "é", "𝑥", "x\x00", "x\n", 'x"', "x'", "import", "None", "True", "_",
    "__class__", "self", "np", "math", "sys", "float", "CANARY",
]

unicode_text = st.text(
    st.characters(blacklist_categories=("Cs",)), min_size=0, max_size=40
)


def deep_list(depth: int, leaf=1.0) -> Raw:
    """``[[[...1.0...]]]`` nested ``depth`` deep, as TOML text (no recursion here)."""
    return Raw("[" * depth + repr(leaf) + "]" * depth)


def deep_table(depth: int, leaf=1.0) -> Raw:
    """``{a = {a = ...}}`` nested ``depth`` deep, as TOML text."""
    return Raw("{a = " * depth + repr(leaf) + "}" * depth)


def hostile_values() -> st.SearchStrategy:
    """Any value, wrong in type, size or depth, for any field."""
    return st.one_of(
        st.sampled_from(BIG_NUMBERS),
        st.sampled_from(HUGE_HORIZONS),
        st.sampled_from(HOSTILE_EXPRESSIONS),
        nested_expressions(),
        st.sampled_from(HOSTILE_NAMES),
        unicode_text,
        st.builds(deep_list, st.sampled_from([2, 3, 50, 500, 3000])),
        st.builds(deep_table, st.sampled_from([2, 50, 500])),
        st.sampled_from([True, False, [], {}, [[]], [[1.0]], [1.0], ["x1"], {"x": 1}]),
        st.lists(st.sampled_from(BIG_NUMBERS), min_size=1, max_size=3),
        st.lists(st.lists(st.sampled_from(BIG_NUMBERS), min_size=1, max_size=3), min_size=1,
                 max_size=3),
        st.floats(allow_nan=True, allow_infinity=True),
        st.integers(min_value=-(2**70), max_value=2**70),
    )


# ---- specs -----------------------------------------------------------------------------------


def load_example(name: str) -> dict:
    return tomllib.loads((EXAMPLES / name).read_text())


def paths(doc, prefix=()) -> list[tuple]:
    """Every path (keys and list indices) into a parsed spec, tables and leaves."""
    out = []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append(prefix + (k,))
            out.extend(paths(v, prefix + (k,)))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            out.append(prefix + (i,))
            out.extend(paths(v, prefix + (i,)))
    return out


def _get(doc, path):
    for p in path:
        doc = doc[p]
    return doc


def mutate(doc: dict, data, *, values: st.SearchStrategy | None = None, k: int | None = None,
           draw_k=None) -> dict:
    """Apply 1..3 random mutations (replace, delete, add a key, wrap, duplicate) to a copy of
    ``doc``, drawing from Hypothesis' ``data``."""
    import copy

    doc = copy.deepcopy(doc)
    values = values if values is not None else hostile_values()
    count = data.draw(st.integers(1, 3), label="mutations") if k is None else k
    for _ in range(count):
        ps = paths(doc)
        if not ps:
            break
        path = data.draw(st.sampled_from(ps), label="path")
        parent = _get(doc, path[:-1])
        key = path[-1]
        op = data.draw(st.sampled_from(["replace", "replace", "replace", "delete", "add",
                                        "wrap", "dup"]), label="op")
        if op == "replace":
            parent[key] = data.draw(values, label="value")
        elif op == "delete":
            del parent[key]
        elif op == "add":
            target = parent[key] if isinstance(parent[key], dict) else parent
            if isinstance(target, dict):
                name = data.draw(st.sampled_from(HOSTILE_NAMES) | unicode_text, label="key")
                target[name] = data.draw(values, label="value")
            else:
                target.append(data.draw(values, label="value"))
        elif op == "wrap":
            parent[key] = [parent[key]]
        elif op == "dup":
            v = parent[key]
            if isinstance(v, list):
                parent[key] = v * data.draw(st.sampled_from([2, 10, 1000]), label="times")
    return doc


def fill_canary(text: str, canary: Path) -> str:
    return text.replace(CANARY, str(canary))


def spec_text(doc: dict) -> str:
    return toml_dumps(doc)


@st.composite
def text_mutation(draw, text: str) -> str:
    """A byte-ish mutation of TOML text: insert unicode, truncate, duplicate a line."""
    op = draw(st.sampled_from(["insert", "truncate", "dupline", "replace_char"]))
    i = draw(st.integers(0, len(text)))
    if op == "insert":
        return text[:i] + draw(unicode_text) + text[i:]
    if op == "truncate":
        return text[:i]
    if op == "dupline":
        lines = text.splitlines(keepends=True)
        j = draw(st.integers(0, max(0, len(lines) - 1)))
        return "".join(lines[: j + 1] + lines[j:])
    c = draw(st.characters(blacklist_categories=("Cs",)))
    return text[:i] + c + text[i + 1:]


# ---- JSON (session files) -------------------------------------------------------------------


def json_hostile() -> st.SearchStrategy:
    return st.one_of(
        st.sampled_from([None, True, 0, -1, 2**64, 10**400, 1e308, "", "x" * 10_000, [], {},
                         "../../etc/passwd", "/etc/passwd", "artifacts/../../x.npz",
                         "model", "synthesis", "verification", "recording", "computed",
                         "cached", "failed", "0.1.0", "9.9.9", "zoh", "continuous"]),
        unicode_text,
        st.integers(),
        st.floats(allow_nan=False, allow_infinity=False),
        st.sampled_from([3, 500, 5000]).map(lambda d: _Json("[" * d + "0" + "]" * d)),
        st.sampled_from([3, 500]).map(lambda d: _Json('{"a": ' * d + "0" + "}" * d)),
    )


def mutate_json(obj, data):
    """One mutation of a parsed JSON object (replace / delete / add at a random path)."""
    import copy

    obj = copy.deepcopy(obj)
    ps = paths(obj)
    if not ps:
        return data.draw(json_hostile(), label="json")
    path = data.draw(st.sampled_from(ps), label="jpath")
    parent = _get(obj, path[:-1])
    op = data.draw(st.sampled_from(["replace", "replace", "delete", "add"]), label="jop")
    if op == "replace":
        parent[path[-1]] = data.draw(json_hostile(), label="jvalue")
    elif op == "delete":
        del parent[path[-1]]
    elif isinstance(parent, dict):
        parent[data.draw(unicode_text, label="jkey")] = data.draw(json_hostile(), label="jv")
    else:
        parent.append(data.draw(json_hostile(), label="jv"))
    return obj


class _Json(str):
    """Literal JSON text (deep nesting written without recursion)."""


def dumps_json(obj) -> str:
    """JSON text of ``obj``, ``_Json`` values written as they are."""
    marks: dict[str, str] = {}

    def walk(v):
        if isinstance(v, _Json):
            mark = f"@@raw{len(marks)}@@"
            marks[mark] = str(v)
            return mark
        if isinstance(v, dict):
            return {k: walk(x) for k, x in v.items()}
        if isinstance(v, list):
            return [walk(x) for x in v]
        return v

    text = json.dumps(walk(obj))
    for mark, raw in marks.items():
        text = text.replace(json.dumps(mark), raw)
    return text


@st.composite
def byte_mutation(draw, raw: bytes) -> bytes:
    """Truncate, flip, insert or delete bytes."""
    op = draw(st.sampled_from(["truncate", "flip", "insert", "delete", "empty", "invalid_utf8"]))
    if op == "empty" or not raw:
        return b""
    i = draw(st.integers(0, len(raw) - 1))
    if op == "truncate":
        return raw[:i]
    if op == "flip":
        return raw[:i] + bytes([raw[i] ^ draw(st.integers(1, 255))]) + raw[i + 1:]
    if op == "insert":
        return raw[:i] + draw(st.binary(min_size=1, max_size=16)) + raw[i:]
    if op == "delete":
        return raw[:i] + raw[i + draw(st.integers(1, 64)):]
    return raw[:i] + b"\xff\xfe\xc3" + raw[i:]
