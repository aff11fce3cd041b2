"""Tests of the sound interval arithmetic (codev_engine.reach.interval), the sympy -> interval
compiler (reach.interval_function) and the plant enclosures (reach.enclosure).

Soundness is checked against sampled values of the exact function. numpy's own value at a
sample carries rounding error, so a sample found outside the enclosure (beyond a loose
tolerance) is re-evaluated exactly with mpmath (``sympy.evalf`` at 40 digits), and only the
exact value has to lie inside.
"""

from __future__ import annotations

import math
import time
from fractions import Fraction
from pathlib import Path

import mpmath
import numpy as np
import pytest
import sympy

from codev_engine.pipeline import load_spec, loads_spec
from codev_engine.plant import numeric_dynamics
from codev_engine.reach import interval as iv
from codev_engine.reach import interval_function as ivf
from codev_engine.reach.enclosure import plant_enclosures, plant_hessian
from codev_engine.reach.interval import Interval, IntervalDomainError
from codev_engine.reach.interval_function import compile_interval
from codev_engine.spec.expr import make_symbol, parse_expression

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
A, B, C = make_symbol("a"), make_symbol("b"), make_symbol("c")
SYMS = (A, B, C)
NAMES = {"a": A, "b": B, "c": C}


# ---------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------


def exact(expr: sympy.Expr, point) -> sympy.Expr:
    """The value of ``expr`` at ``point`` (floats, exact binary values) to 40 digits."""
    subs = {s: sympy.Float(float(v), 60) for s, v in zip(SYMS, point, strict=False)}
    return sympy.N(expr.subs(subs), 40)


def inside(lo: float, hi: float, value: sympy.Expr) -> bool:
    """Exact containment of a (real) sympy number in [lo, hi]."""
    if value.is_real is not True or not value.is_finite:
        return False
    return bool(sympy.Float(lo, 60) <= value <= sympy.Float(hi, 60))


def samples(lo: np.ndarray, hi: np.ndarray, rng, n: int = 1000) -> np.ndarray:
    """n uniform points of the box, its corners, and 0 where the box contains it."""
    k = len(lo)
    pts = [lo + (hi - lo) * rng.random((n, k))]
    corners = np.array(np.meshgrid(*[[lo[i], hi[i]] for i in range(k)])).reshape(k, -1).T
    pts.append(corners)
    zero = np.clip(np.zeros(k), lo, hi)
    pts.append(zero[None])
    return np.vstack(pts)


def on_arrays(f, lo, hi):
    """Evaluate one box with the array kernels (larger batches than _SCALAR_MAX_BATCH use
    them)."""
    n = ivf._SCALAR_MAX_BATCH + 1
    lo, hi = f(np.tile(np.asarray(lo, float), (n, 1)), np.tile(np.asarray(hi, float), (n, 1)))
    return lo[0], hi[0]


def random_box(rng, k: int, kind: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A box whose coordinates are narrow, medium, wide (several periods), touching or
    containing 0, or points."""
    lo, hi = np.empty(k), np.empty(k)
    for i in range(k):
        t = kind or rng.choice(["narrow", "medium", "wide", "zero", "point"])
        c = rng.uniform(-3, 3)
        if t == "narrow":
            r = 10 ** rng.uniform(-8, -1)
            lo[i], hi[i] = c - r, c + r
        elif t == "medium":
            r = rng.uniform(0.1, 2.0)
            lo[i], hi[i] = c - r, c + r
        elif t == "wide":
            r = rng.uniform(3.0, 15.0)
            lo[i], hi[i] = c - r, c + r
        elif t == "zero":
            r = rng.uniform(0.0, 2.0)
            lo[i], hi[i] = rng.choice([(0.0, r), (-r, 0.0), (-r, r), (-r, 0.5 * r)])
        else:
            lo[i] = hi[i] = c
    return lo, hi


def assert_sound(expr: sympy.Expr, lo: np.ndarray, hi: np.ndarray, elo, ehi, pts, values):
    """Every sampled value lies in [elo, ehi]; suspects are checked exactly."""
    elo, ehi = float(elo), float(ehi)
    assert elo <= ehi or (math.isnan(elo) and False), (expr, elo, ehi)
    values = np.broadcast_to(np.asarray(values, dtype=float), (len(pts),))
    finite = np.isfinite(values)
    tol = 1e-9 * (1.0 + np.abs(values))
    out = finite & ((values < elo - tol) | (values > ehi + tol))
    # Worst suspects (and a few non-finite numpy values) are checked exactly.
    excess = np.where(out, np.maximum(elo - values, values - ehi) / tol, -1.0)
    suspects = [int(i) for i in np.argsort(-excess)[:5] if excess[i] > 0]
    suspects += [int(i) for i in np.flatnonzero(~finite)[:3]]
    for i in suspects:
        v = exact(expr, pts[i])
        assert inside(elo, ehi, v), (
            f"{expr} over lo={lo.tolist()} hi={hi.tolist()}: enclosure [{elo!r}, {ehi!r}] "
            f"misses the exact value {v} at {pts[i].tolist()} (numpy: {values[i]!r})"
        )


# ---------------------------------------------------------------------------------------
# the floating-point assumption
# ---------------------------------------------------------------------------------------

ULP_FUNCS = [
    ("sin", np.sin, math.sin, mpmath.sin, (-50, 50)),
    ("cos", np.cos, math.cos, mpmath.cos, (-50, 50)),
    ("tan", np.tan, math.tan, mpmath.tan, (-1.5, 1.5)),
    ("asin", np.arcsin, math.asin, mpmath.asin, (-1, 1)),
    ("acos", np.arccos, math.acos, mpmath.acos, (-1, 1)),
    ("atan", np.arctan, math.atan, mpmath.atan, (-20, 20)),
    ("sinh", np.sinh, math.sinh, mpmath.sinh, (-30, 30)),
    ("cosh", np.cosh, math.cosh, mpmath.cosh, (-30, 30)),
    ("tanh", np.tanh, math.tanh, mpmath.tanh, (-5, 5)),
    ("exp", np.exp, math.exp, mpmath.exp, (-700, 700)),
    ("log", np.log, math.log, mpmath.log, (1e-5, 1e5)),
    ("pow", lambda x: np.power(x, 1.37), lambda x: math.pow(x, 1.37),
     lambda x: mpmath.power(x, mpmath.mpf(1.37)), (0, 100)),
]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "npf", "mf", "mpf", "dom"), ULP_FUNCS, ids=[f[0] for f in ULP_FUNCS]
)
def test_libm_error_within_four_ulp(name, npf, mf, mpf, dom):
    """The soundness margin (module docstring, item 2) assumes <= 4 ulp from numpy/math."""
    rng = np.random.default_rng(1)
    x = rng.uniform(*dom, 300)
    x[:2] = dom  # the ends of the domain too
    got_np = npf(x)
    with mpmath.workdps(40):
        for xi, gi in zip(x, got_np, strict=True):
            true = mpf(mpmath.mpf(float(xi)))
            ulp = np.spacing(abs(float(true))) if float(true) != 0 else 5e-324
            assert abs(mpmath.mpf(float(gi)) - true) <= 4 * ulp, (name, "numpy", xi)
            assert abs(mpmath.mpf(mf(float(xi))) - true) <= 4 * ulp, (name, "math", xi)


# ---------------------------------------------------------------------------------------
# elementary operations
# ---------------------------------------------------------------------------------------

UNARY = {
    "sin": (iv.sin, np.sin, None),
    "cos": (iv.cos, np.cos, None),
    "tan": (iv.tan, np.tan, (-1.5, 1.5)),
    "asin": (iv.asin, np.arcsin, (-1.0, 1.0)),
    "acos": (iv.acos, np.arccos, (-1.0, 1.0)),
    "atan": (iv.atan, np.arctan, None),
    "sinh": (iv.sinh, np.sinh, None),
    "cosh": (iv.cosh, np.cosh, None),
    "tanh": (iv.tanh, np.tanh, None),
    "exp": (iv.exp, np.exp, None),
    "log": (iv.log, np.log, (1e-3, 50.0)),
    "sqrt": (iv.sqrt, np.sqrt, (0.0, 50.0)),
    "abs": (iv.abs_, np.abs, None),
    "sign": (iv.sign, np.sign, None),
    "sqr": (lambda x: x**2, np.square, None),
    "cube": (lambda x: x**3, lambda x: x**3, None),
    "pow4": (lambda x: x**4, lambda x: x**4, None),
    "inv2": (lambda x: x**-2, lambda x: x**-2.0, (0.1, 10.0)),
    "pow1.5": (lambda x: x**1.5, lambda x: x**1.5, (0.0, 20.0)),
    "pow-0.7": (lambda x: x**-0.7, lambda x: x**-0.7, (0.01, 20.0)),
}


def unary_boxes(rng, dom, n):
    """Random intervals (many kinds), clipped to ``dom`` when given."""
    boxes = []
    for kind in ["narrow", "medium", "wide", "zero", "point"] * (n // 5):
        lo, hi = random_box(rng, 1, kind)
        if dom is not None:
            lo, hi = np.clip(lo, *dom), np.clip(hi, *dom)
        boxes.append((lo[0], hi[0]))
    return np.array(boxes)


@pytest.mark.parametrize("name", list(UNARY))
def test_unary_sound_and_tight(name):
    """Both the array kernels (a batch) and the scalar kernels (one box) are sound, and not
    loose: the enclosure is within 1e-3 of the sampled range (1e-12 relative for the
    functions other than sin and cos, whose extremes are sampled: endpoints and 0)."""
    fn, npf, dom = UNARY[name]
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    boxes = unary_boxes(rng, dom, 60)
    x = make_symbol("x")
    expr = {"abs": sympy.Abs(x), "sign": sympy.sign(x), "sqr": x**2, "cube": x**3,
            "pow4": x**4, "inv2": x**-2, "pow1.5": x**sympy.Rational(3, 2),
            "pow-0.7": x**sympy.Float(-0.7)}.get(name)  # fmt: skip
    expr = expr if expr is not None else getattr(sympy, name)(x)
    batch = fn(Interval(boxes[:, 0], boxes[:, 1]))
    compiled = compile_interval([expr], (x,))
    monotone = name not in ("sin", "cos")
    for j, (lo, hi) in enumerate(boxes):
        if name == "tan" and np.ceil(lo / np.pi - 0.5 - 1e-9) <= hi / np.pi - 0.5 + 1e-9:
            continue  # contains a pole: tested elsewhere
        zero = np.clip(0.0, lo, hi)  # the minimum of |x|, x**2, cosh
        pts = np.concatenate([np.linspace(lo, hi, 1001), rng.uniform(lo, hi, 200), [zero]])
        with np.errstate(all="ignore"):
            vals = npf(pts)
        single = compiled(np.array([lo]), np.array([hi]))  # scalar kernels
        for elo, ehi in ((batch.lo[j], batch.hi[j]), (single[0][0], single[1][0])):
            assert_sound(expr, np.array([lo]), np.array([hi]), elo, ehi, pts[:, None], vals)
            scale = 1.0 + np.max(np.abs(vals))
            slack = 1e-12 * scale if monotone else 1e-3
            assert ehi - np.max(vals) <= slack and np.min(vals) - elo <= slack, (
                name, lo, hi, elo, ehi, vals.min(), vals.max())  # fmt: skip


def test_specific_tight_values():
    x = Interval(-1.0, 2.0) ** 2
    assert x.lo == 0.0 and 4.0 <= x.hi <= np.nextafter(4.0, 5)
    e = iv.exp(Interval(0.0, 1.0))
    assert e.lo <= 1.0 and 1.0 - e.lo <= 20 * np.spacing(1.0)
    assert e.hi >= math.e and e.hi - math.e <= 20 * np.spacing(math.e)
    assert (Interval(-2.0, 3.0) ** 3).lo <= -8.0 <= (Interval(-2.0, 3.0) ** 3).lo + 1e-13
    assert iv.cosh(Interval(-1.0, 2.0)).lo == 1.0
    s = iv.sin(Interval(1.0, 2.0))  # contains pi/2
    assert s.hi == 1.0 and s.lo <= math.sin(1.0) <= s.lo + 4e-15
    c = iv.cos(Interval(-0.1, 0.1))
    assert c.hi == 1.0 and c.lo <= math.cos(0.1) <= c.lo + 4e-15
    c = iv.cos(Interval(3.0, 3.5))  # contains pi
    assert c.lo == -1.0
    w = iv.sin(Interval(-20.0, 20.0))
    assert (w.lo, w.hi) == (-1.0, 1.0)
    n = iv.cos(Interval(0.1, 0.2))  # monotone piece: both bounds within ulps
    assert n.lo <= math.cos(0.2) <= n.lo + 4e-15 and n.hi >= math.cos(0.1) >= n.hi - 4e-15
    assert iv.sign(Interval(-1.0, 0.0)).hi == 0.0 and iv.abs_(Interval(-1.0, 2.0)).lo == 0.0
    sq = iv.sqrt(Interval(0.0, 4.0))
    assert sq.lo == 0.0 and 2.0 <= sq.hi <= np.nextafter(2.0, 3)
    # a point: outward by one float for correctly rounded operations
    t = Interval(0.1) + Interval(0.2)
    assert t.lo < Fraction(0.1) + Fraction(0.2) < t.hi and t.hi - t.lo <= 2 * np.spacing(0.3)


def test_binary_operations_sound():
    """+ - * / min max atan2 over random pairs of intervals (including ones touching 0)."""
    rng = np.random.default_rng(7)
    n = 400
    a_lo, a_hi = np.array([random_box(rng, 1) for _ in range(n)])[:, :, 0].T
    b_lo, b_hi = np.array([random_box(rng, 1) for _ in range(n)])[:, :, 0].T
    a, b = Interval(a_lo, a_hi), Interval(b_lo, b_hi)
    t = rng.random((2, 300, 1))
    xa = a_lo + (a_hi - a_lo) * t[0]
    xb = b_lo + (b_hi - b_lo) * t[1]
    xa = np.vstack([xa, a_lo, a_lo, a_hi, a_hi])
    xb = np.vstack([xb, b_lo, b_hi, b_lo, b_hi])
    ops = {
        "add": (a + b, xa + xb),
        "sub": (a - b, xa - xb),
        "mul": (a * b, xa * xb),
        "min": (iv.minimum(a, b), np.minimum(xa, xb)),
        "max": (iv.maximum(a, b), np.maximum(xa, xb)),
        "atan2": (iv.atan2(a, b), np.arctan2(xa, xb)),
    }
    for name, (enc, vals) in ops.items():
        tol = 1e-15 * (1 + np.abs(vals))
        assert np.all(enc.lo - tol <= vals) and np.all(vals <= enc.hi + tol), name
    ok = (b_lo > 0) | (b_hi < 0)
    q = a[ok] / b[ok]
    vals = xa[:, ok] / xb[:, ok]
    assert np.all(q.lo <= vals * (1 + 1e-15) + 1e-300) or np.all(
        (q.lo - 1e-15 * np.abs(vals) <= vals) & (vals <= q.hi + 1e-15 * np.abs(vals))
    )
    # exact checks at the endpoints with Fractions (correctly rounded ops + one ulp)
    for i in range(50):
        fa, fb = Fraction(float(xa[-1, i])), Fraction(float(xb[-1, i]))
        p = Interval(xa[-1, i]) * Interval(xb[-1, i])
        s = Interval(xa[-1, i]) + Interval(xb[-1, i])
        assert Fraction(float(p.lo)) <= fa * fb <= Fraction(float(p.hi))
        assert Fraction(float(s.lo)) <= fa + fb <= Fraction(float(s.hi))


def test_atan2_cut_and_quadrants():
    assert (iv.atan2(Interval(-1.0, 1.0), Interval(-2.0, -1.0)).hi) >= math.pi
    full = iv.atan2(Interval(-1.0, 1.0), Interval(-2.0, -1.0))
    assert full.lo <= -math.pi and full.hi >= math.pi
    r = iv.atan2(Interval(1.0, 2.0), Interval(-1.0, 1.0))  # upper half plane, above the origin
    assert r.lo <= math.atan2(1.0, 1.0) and r.hi >= math.atan2(1.0, -1.0) and r.hi < 3.0
    r = iv.atan2(Interval(-1.0, 1.0), Interval(1.0, 2.0))  # right half plane, across y = 0
    assert r.lo <= math.atan2(-1, 1) and r.hi >= math.atan2(1, 1) and r.hi < 1.0


def test_interval_sum_and_matmul_sound():
    rng = np.random.default_rng(3)
    lo = rng.normal(size=(5, 40)) * 10.0 ** rng.integers(-5, 5, (5, 40))
    x = Interval(lo, lo + rng.random((5, 40)))
    s = x.sum(axis=-1)
    for r in range(5):
        exact_lo = sum(Fraction(float(v)) for v in x.lo[r])
        exact_hi = sum(Fraction(float(v)) for v in x.hi[r])
        assert Fraction(float(s.lo[r])) <= exact_lo and exact_hi <= Fraction(float(s.hi[r]))
    M = Interval(rng.normal(size=(3, 4)), None)
    M = Interval(M.lo - 0.1, M.lo + 0.1)
    v = Interval(rng.normal(size=4))
    y = M @ v
    assert y.shape == (3,)
    for _ in range(200):
        Ms = M.lo + (M.hi - M.lo) * rng.random((3, 4))
        assert np.all(y.contains(Ms @ v.lo))
    assert (v @ M.lo.T).shape == (3,)


def test_constants_enclosed():
    for value in (sympy.pi, sympy.E, sympy.Rational(1, 3), sympy.Integer(2**60 + 1)):
        enc = Interval.of(value)
        v = sympy.N(value, 50)
        assert inside(float(enc.lo), float(enc.hi), v)
        assert enc.hi - enc.lo <= 4 * np.spacing(abs(float(v)))
    f = compile_interval([sympy.Rational(1, 3) * A, A / 3, sympy.pi * A, sympy.sqrt(2) * A], SYMS)
    lo, hi = f(np.array([3.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0]))
    for j, value in enumerate([1, 1, 3 * sympy.pi, 3 * sympy.sqrt(2)]):
        assert inside(lo[j], hi[j], sympy.N(value, 50))
    assert lo[0] == hi[0] == 1.0 or hi[0] - lo[0] <= 4e-16  # 3 * (1/3) via (3 * 1) / 3
    # a decimal literal is enclosed as the decimal, not only as its binary float
    g = compile_interval([parse_expression("0.1 * a", NAMES), parse_expression("0.1", NAMES)], SYMS)
    for lo, hi in (g([1.0, 0, 0], [1.0, 0, 0]), on_arrays(g, [1.0, 0, 0], [1.0, 0, 0])):
        for j in range(2):
            assert Fraction(float(lo[j])) < Fraction(1, 10) < Fraction(float(hi[j]))


def test_exact_coefficients():
    """Integer and rational coefficients of either sign (scale / divide by exact floats)."""
    exprs = [-2 * A, -A / 3, sympy.Rational(-2, 3) * A, 3 * A, sympy.Rational(5, 7) * A * B]
    f = compile_interval(exprs, SYMS)
    rng = np.random.default_rng(8)
    for _ in range(8):
        lo = rng.uniform(-2, 2, 3)
        hi = lo + rng.uniform(0, 1, 3) * rng.integers(0, 2)
        encs = (f(lo, hi), on_arrays(f, lo, hi))
        for p in samples(lo, hi, rng, 3):
            for j, e in enumerate(exprs):
                v = exact(e, p)
                for elo, ehi in encs:
                    assert inside(elo[j], ehi[j], v), (e, lo, hi, elo[j], ehi[j])


# ---------------------------------------------------------------------------------------
# domain errors
# ---------------------------------------------------------------------------------------


def test_domain_errors():
    with pytest.raises(IntervalDomainError, match="log"):
        iv.log(Interval(-1.0, 1.0))
    with pytest.raises(IntervalDomainError, match="log"):
        iv.log(Interval(0.0, 1.0))
    with pytest.raises(IntervalDomainError, match="sqrt"):
        iv.sqrt(Interval(-1.0, 0.0))
    assert iv.sqrt(Interval(0.0, 1.0)).lo == 0.0
    with pytest.raises(IntervalDomainError, match="pole"):
        iv.tan(Interval(1.0, 2.0))
    with pytest.raises(IntervalDomainError, match="pole"):
        iv.tan(Interval(-2.0, -1.0))
    with pytest.raises(IntervalDomainError, match="division"):
        Interval(1.0, 2.0) / Interval(-1.0, 1.0)
    with pytest.raises(IntervalDomainError, match="division"):
        Interval(1.0, 2.0) ** -2 * Interval(0.0) + 1 / Interval(0.0, 1.0)
    with pytest.raises(IntervalDomainError, match="asin"):
        iv.asin(Interval(0.5, 1.5))
    with pytest.raises(IntervalDomainError, match="acos"):
        iv.acos(Interval(-1.5, 0.0))
    with pytest.raises(IntervalDomainError, match="sqrt"):
        Interval(-1.0, 1.0) ** 0.5
    with pytest.raises(IntervalDomainError, match="power"):
        Interval(-1.0, 1.0) ** 1.5
    with pytest.raises(IntervalDomainError, match="power"):
        Interval(0.0, 1.0) ** -0.3
    assert isinstance(IntervalDomainError("x"), ValueError)


@pytest.mark.parametrize(
    ("text", "lo", "hi", "match"),
    [
        ("log(a)", [-1, 0, 0], [1, 0, 0], "log"),
        ("sqrt(a - 1)", [-1, 0, 0], [0, 0, 0], "sqrt"),
        ("tan(a)", [1, 0, 0], [2, 0, 0], "pole"),
        ("b / a", [-1, 0, 0], [1, 1, 0], "division"),
        ("a**(1/3)", [-1, 0, 0], [1, 0, 0], "power"),
        ("asin(2*a)", [0, 0, 0], [1, 0, 0], "asin"),
    ],
)
def test_compiled_domain_errors(text, lo, hi, match):
    f = compile_interval([parse_expression(text, NAMES)], SYMS)
    lo, hi = np.array(lo, float), np.array(hi, float)
    with pytest.raises(IntervalDomainError, match=match) as single:
        f(lo, hi)  # scalar kernels
    assert single.value.boxes is None
    good = np.array([0.1, 1.0, 0.0]) if text in ("tan(a)", "asin(2*a)") else lo + 5.0
    batch_lo = np.vstack([good, lo, good])
    batch_hi = np.vstack([good + 0.1, hi, good + 0.1])
    f(batch_lo[[0, 2]], batch_hi[[0, 2]])  # the good boxes alone are fine
    with pytest.raises(IntervalDomainError, match=match) as batch:
        f(batch_lo, batch_hi)  # array kernels
    assert batch.value.boxes.tolist() == [1]


# ---------------------------------------------------------------------------------------
# random expressions
# ---------------------------------------------------------------------------------------

UNARY_NAMES = ["sin", "cos", "tan", "asin", "acos", "atan", "sinh", "cosh", "tanh", "exp",
               "log", "sqrt", "abs", "sign"]  # fmt: skip


def random_text(rng, depth: int) -> str:
    """A random expression over a, b, c from the whitelist of the parser."""
    if depth == 0 or rng.random() < 0.2:
        r = rng.random()
        if r < 0.6:
            return str(rng.choice(["a", "b", "c"]))
        if r < 0.8:
            return repr(round(float(rng.uniform(-3, 3)), 2))
        return str(rng.choice(["pi", "e", "2", "(1/3)", "3"]))
    r = rng.random()
    sub = lambda: random_text(rng, depth - 1)  # noqa: E731
    if r < 0.35:
        return f"{rng.choice(UNARY_NAMES)}({sub()})"
    if r < 0.75:
        return f"({sub()} {rng.choice(['+', '-', '*', '/'])} {sub()})"
    if r < 0.87:
        ex = rng.choice(["2", "3", "4", "-1", "-2", "0.5", "1.5", "(1/3)", "2.0", "-0.5"])
        return f"({sub()})**{ex}"
    return f"{rng.choice(['atan2', 'min', 'max'])}({sub()}, {sub()})"


def parse(text: str) -> sympy.Expr | None:
    """The parsed expression, or None when sympy itself rejects it (e.g. ``Min`` of a
    non-real constant such as ``acos(pi)`` raises ValueError while it is built)."""
    try:
        return parse_expression(text, NAMES)
    except ValueError:
        return None


def test_random_expressions_sound():
    """Random whitelist expressions (depth <= 4) over random boxes: every sampled value of
    the exact function lies in the enclosure, for one box (scalar kernels) and for a batch
    (array kernels)."""
    rng = np.random.default_rng(2024)
    checked = 0
    for _ in range(140):
        expr = parse(random_text(rng, int(rng.integers(1, 5))))
        if expr is None:
            continue
        try:
            f = compile_interval([expr], SYMS)
        except IntervalDomainError:  # a constant such as asin(e) or (-1)**(1/3)
            continue
        g = sympy.lambdify(SYMS, expr, modules="numpy")
        boxes = [random_box(rng, 3) for _ in range(4)]
        blo = np.array([b[0] for b in boxes])
        bhi = np.array([b[1] for b in boxes])
        try:
            batch = f(np.tile(blo, (5, 1)), np.tile(bhi, (5, 1)))  # 20 boxes: array kernels
        except IntervalDomainError as exc:
            assert exc.boxes is not None and len(exc.boxes) >= 1
            batch = None
        for j, (lo, hi) in enumerate(boxes):
            try:
                single = f(lo, hi)
            except IntervalDomainError:
                assert batch is None, "a box failed alone but not in the batch"
                continue
            pts = samples(lo, hi, rng)
            with np.errstate(all="ignore"):
                vals = g(*pts.T)
            encs = [(single[0][0], single[1][0])]
            if batch is not None:
                encs.append((batch[0][j, 0], batch[1][j, 0]))
            for elo, ehi in encs:
                assert_sound(expr, lo, hi, elo, ehi, pts, vals)
            checked += 1
    assert checked > 200  # most boxes are in the domain


ELEMENTARY = [
    ("sin(a)", (-30, 30)), ("cos(a)", (-30, 30)), ("tan(a)", (-1.5, 1.5)),
    ("asin(a)", (-1, 1)), ("acos(a)", (-1, 1)), ("atan(a)", (-20, 20)),
    ("sinh(a)", (-20, 20)), ("cosh(a)", (-20, 20)), ("tanh(a)", (-5, 5)),
    ("exp(a)", (-50, 50)), ("log(a)", (1e-3, 100)), ("sqrt(a)", (0, 100)),
    ("a**3", (-10, 10)), ("a**(1/3)", (0, 100)), ("a**1.5", (0, 100)), ("a**(-2)", (0.1, 10)),
    ("a + b", (-10, 10)), ("a - b", (-10, 10)), ("a * b", (-10, 10)), ("a / b", (0.1, 10)),
    ("a**2", (-10, 10)), ("1 / a", (0.1, 10)), ("atan2(a, b)", (0.1, 10)),
]  # fmt: skip


@pytest.mark.parametrize(("text", "dom"), ELEMENTARY, ids=[t for t, _ in ELEMENTARY])
def test_point_boxes_exact_elementary(text, dom):
    """Each operation alone on point boxes, scalar and array kernels: the exact value
    (mpmath, or Fractions for the correctly rounded ones) is inside, by outward rounding."""
    expr = parse_expression(text, NAMES)
    f = compile_interval([expr], SYMS)
    rng = np.random.default_rng(len(text))
    pts = rng.uniform(*dom, (40, 3))
    batch = f(pts, pts)  # more than _SCALAR_MAX_BATCH boxes: array kernels
    for i, p in enumerate(pts):
        v = exact(expr, p)
        for elo, ehi in (f(p, p), (batch[0][i], batch[1][i])):
            assert inside(float(elo[0]), float(ehi[0]), v), (text, p, elo, ehi, v)
            assert ehi[0] - elo[0] <= 1e-13 * max(1.0, abs(float(v)))


def test_point_boxes_tight():
    """lo == hi: the enclosure contains the exact value and is ~1e-12 wide (relative)."""
    texts = [
        "sin(a) * cos(b) + exp(-c**2)",
        "a**3 - 2*a*b + b**2 / (1 + c**2)",
        "atan2(b, a) + tanh(c) - sqrt(1 + a**2)",
        "log(1 + a**2) * sinh(b) / cosh(c)",
        "-9.81*sin(a) - 0.1*b + c",
        "max(a, b) - min(b, c) + abs(a) * sign(b)",
        "asin(a / (1 + abs(a))) + acos(b / (2 + abs(b))) + atan(c) + tan(a / 2)",
        "(1 + a**2)**(1/3) + (2 + sin(b))**1.5 + e**c + pi * a",
    ]
    rng = np.random.default_rng(5)
    for text in texts:
        expr = parse_expression(text, NAMES)
        f = compile_interval([expr], SYMS)
        for _ in range(12):
            p = rng.uniform(-1.4, 1.4, 3)
            for lo, hi in (f(p, p), on_arrays(f, p, p)):  # scalar and array kernels
                v = exact(expr, p)
                elo, ehi = float(lo.ravel()[0]), float(hi.ravel()[0])
                assert inside(elo, ehi, v), (text, p, elo, ehi, v)
                assert ehi - elo <= 1e-12 * max(1.0, abs(float(v))), (text, p, ehi - elo)


def test_scalar_and_array_kernels_agree():
    """The two implementations of each operation follow the same formulas."""
    rng = np.random.default_rng(11)
    for _ in range(60):
        expr = parse(random_text(rng, 3))
        if expr is None:
            continue
        try:
            f = compile_interval([expr], SYMS)
        except IntervalDomainError:
            continue
        lo, hi = random_box(rng, 3)
        try:
            s = f(lo, hi)
        except IntervalDomainError:
            continue
        a = f._array(lo[None], hi[None], True)
        np.testing.assert_allclose(s[0].ravel(), a[0].ravel(), rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(s[1].ravel(), a[1].ravel(), rtol=1e-13, atol=1e-13)


def test_overflow_gives_sound_infinite_bounds():
    f = compile_interval([sympy.exp(sympy.exp(A)), sympy.exp(sympy.exp(A)) * B], SYMS)
    for lo, hi in (f([6.0, 0.0, 0.0], [7.0, 0.0, 0.0]), on_arrays(f, [6.0, 0, 0], [7.0, 0, 0])):
        lo, hi = lo.reshape(-1, 2), hi.reshape(-1, 2)
        assert np.all(lo[:, 0] >= 1e150) and np.all(hi[:, 0] == np.inf)
        assert np.all(lo[:, 1] == -np.inf) and np.all(hi[:, 1] == np.inf)  # 0 * inf -> NaN
    g = compile_interval([sympy.cosh(A) - sympy.sinh(A)], SYMS)
    lo, hi = g([800.0, 0.0, 0.0], [801.0, 0.0, 0.0])
    assert lo == -np.inf and hi == np.inf


def test_infinite_boxes():
    f = compile_interval([sympy.sin(A) + sympy.atan(B), sympy.exp(-(A**2))], SYMS)
    lo, hi = f([-np.inf, 0.0, 0.0], [np.inf, np.inf, 0.0])
    assert lo[0] <= -1.0 and hi[0] >= 1.0 + math.pi / 2 and np.isfinite(hi[0])
    assert lo[1] == 0.0 and 1.0 <= hi[1] < 1.0 + 1e-12


def test_nonsmooth_derivatives():
    """Heaviside (d Max) is the Clarke gradient [0, 1] across the kink; DiracDelta (d sign)
    is [0, inf] over a box meeting 0 and 0 elsewhere."""
    f = compile_interval(
        [sympy.diff(sympy.Max(A, B), A), sympy.diff(sympy.sign(A), A), sympy.diff(sympy.Abs(A), A)],
        SYMS,
    )
    lo, hi = f([-1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    assert lo[0] == 0.0 and -1e-300 <= lo[1] <= 0.0 and lo[2] == -1.0
    assert hi.tolist() == [1.0, np.inf, 1.0]
    h = compile_interval([sympy.Heaviside(A)], SYMS)
    for box, want in (([0, 0], [0.5, 0.5]), ([0, 1], [0.5, 1]), ([-1, 0], [0, 0.5])):
        lo, hi = [box[0], 0, 0], [box[1], 0, 0]
        for elo, ehi in (h(lo, hi), on_arrays(h, lo, hi)):
            assert [float(elo[0]), float(ehi[0])] == want
    for lo, hi in (f([0.5, 0, 0], [1.0, 0, 0]), on_arrays(f, [0.5, 0, 0], [1.0, 0, 0])):
        np.testing.assert_allclose(lo, [1.0, 0.0, 1.0], atol=1e-300)
        np.testing.assert_allclose(hi, [1.0, 0.0, 1.0], atol=1e-300)
    lo, hi = on_arrays(f, [-1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
    assert lo[0] == 0.0 and -1e-300 <= lo[1] <= 0.0 and hi.tolist() == [1.0, np.inf, 1.0]


def test_hessian_enclosure():
    """Second-order terms compile too (the verifier's remainder term)."""
    expr = sympy.sin(A) * sympy.exp(B) + A**3 * C + sympy.Abs(A - B) * C
    hess = sympy.hessian(expr, SYMS)
    H = compile_interval(hess, SYMS)
    g = sympy.lambdify(SYMS, hess.replace(sympy.DiracDelta, lambda *a: 0), modules="numpy")
    rng = np.random.default_rng(4)
    lo, hi = np.array([0.2, -0.5, 1.0]), np.array([0.7, 0.1, 1.5])  # |a - b| smooth here
    for elo, ehi in (H(lo, hi), on_arrays(H, lo, hi)):
        assert elo.shape == (3, 3)
        for p in samples(lo, hi, rng, 200):
            v = np.array(g(*p), dtype=float)
            assert np.all((elo <= v) & (v <= ehi))


def test_shapes_and_validation():
    M = sympy.Matrix([[A, B], [C, 1], [A * B, 0]])
    f = compile_interval(M, SYMS)
    assert f.shape == (3, 2)
    lo, hi = f(np.zeros(3), np.ones(3))
    assert lo.shape == hi.shape == (3, 2)
    lo, hi = f(np.zeros((7, 3)), np.ones((7, 3)))
    assert lo.shape == (7, 3, 2) and lo[:, 1, 1].tolist() == [1.0] * 7
    lo, hi = f(Interval(np.zeros((1, 3)), np.ones((1, 3))))
    assert lo.shape == (1, 3, 2)
    assert compile_interval(A + B, SYMS)(np.zeros(3), np.ones(3))[1].shape == ()
    with pytest.raises(ValueError, match="shape"):
        f(np.zeros(2), np.ones(2))
    with pytest.raises(ValueError, match="lo <= hi"):
        f(np.ones(3), np.zeros(3))
    with pytest.raises(ValueError, match="lo <= hi"):
        f(np.ones((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="not among"):
        compile_interval([A + make_symbol("z")], SYMS)
    with pytest.raises(NotImplementedError, match="asinh"):
        compile_interval([sympy.asinh(A)], SYMS)


# ---------------------------------------------------------------------------------------
# plants
# ---------------------------------------------------------------------------------------

CARTPOLE = """\
name = "cartpole"

[plant]
states = ["p", "v", "th", "w"]
inputs = ["F"]
dynamics = [
  "v",
  "(F + 0.1*sin(th)*(0.5*w**2 - 9.81*cos(th))) / (1.0 + 0.1*sin(th)**2)",
  "w",
  "(-F*cos(th) - 0.1*0.5*w**2*cos(th)*sin(th) + 1.1*9.81*sin(th)) / (0.5*(1.0 + 0.1*sin(th)**2))",
]

[model]
sample_time = 0.05

[mpc]
horizon = 3
norm = "2"
Q = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
R = [[0.1]]
u_min = [-10.0]
u_max = [10.0]
"""


@pytest.mark.parametrize("source", ["cartpole", "double_integrator.toml", "navigation.toml"])
def test_plant_enclosures_contain_samples(source):
    problem = loads_spec(CARTPOLE) if source == "cartpole" else load_spec(EXAMPLES / source)
    enc = plant_enclosures(problem)
    nd = numeric_dynamics(problem)
    n, m = enc.n, enc.m
    rng = np.random.default_rng(9)
    P = 20
    xc = rng.uniform(-2, 2, (P, n))
    xr = 10.0 ** rng.uniform(-4, 0, (P, n))
    xlo, xhi = xc - xr, xc + xr
    ulo, uhi = -np.ones(m), np.ones(m)  # one input box broadcast over the batch
    F, Jx, Ju = (
        enc.f(xlo, xhi, ulo, uhi),
        enc.jac_x(xlo, xhi, ulo, uhi),
        enc.jac_u(xlo, xhi, ulo, uhi),
    )
    assert F[0].shape == (P, n) and Jx[0].shape == (P, n, n) and Ju[0].shape == (P, n, m)
    for p in range(P):
        t = rng.random((300, n))
        xs = np.vstack([xlo[p] + (xhi[p] - xlo[p]) * t, xlo[p], xhi[p]])
        us = rng.uniform(-1, 1, (len(xs), m))
        for (elo, ehi), vals in ((F, nd.f(xs, us)), (Jx, nd.jac_x(xs, us)), (Ju, nd.jac_u(xs, us))):
            tol = 1e-12 * (1 + np.abs(vals))
            assert np.all(elo[p] - tol <= vals) and np.all(vals <= ehi[p] + tol)
        single = enc.jac_x(xlo[p], xhi[p], ulo, uhi)  # scalar kernels, unbatched shapes
        assert single[0].shape == (n, n)
        np.testing.assert_allclose(single[0], Jx[0][p], rtol=1e-13, atol=1e-13)
    with pytest.raises(ValueError, match="xlo"):
        enc.f(np.zeros(n + 1), np.zeros(n + 1), ulo, uhi)


@pytest.mark.parametrize("source", ["cartpole", "pendulum.toml", "vanderpol.toml", "tora.toml"])
def test_plant_hessian_contains_samples(source):
    """The second derivatives of f (the nonlinear verifier's second-order remainder) are
    enclosed over random boxes: compared with sympy's derivatives at sampled points."""
    problem = loads_spec(CARTPOLE) if source == "cartpole" else load_spec(EXAMPLES / source)
    from codev_engine.plant import symbolic_model

    sym = symbolic_model(problem)
    args = (*sym.x, *sym.u)
    n, k = len(sym.x), len(args)
    exact = sympy.lambdify(
        args, [sympy.diff(fi, a, b) for fi in sym.f for a in args for b in args], "numpy"
    )
    H = plant_hessian(problem)
    rng = np.random.default_rng(4)
    P = 12
    zc = rng.uniform(-2, 2, (P, k))
    zr = 10.0 ** rng.uniform(-4, 0, (P, k))
    lo, hi = H(zc - zr, zc + zr)
    assert lo.shape == (P, n * k * k)
    for p in range(P):
        t = rng.random((200, k))
        zs = np.vstack([zc[p] - zr[p] + 2 * zr[p] * t, zc[p] - zr[p], zc[p] + zr[p]])
        vals = np.array([np.broadcast_to(v, zs.shape[:1]) for v in exact(*zs.T)]).T
        tol = 1e-12 * (1 + np.abs(vals))
        assert np.all(lo[p] - tol <= vals) and np.all(vals <= hi[p] + tol)


def test_performance_report():
    """Not a timed assertion: prints the cost of f and Jx of a 4-state cart-pole."""
    enc = plant_enclosures(loads_spec(CARTPOLE))
    x = np.array([0.0, 0.1, 0.2, -0.1])
    u = np.array([1.0])
    lines = [f"ops: f {enc.f_fn.n_ops}, Jx {enc.jac_x_fn.n_ops}"]
    for P in (1, 1000):
        xlo = np.tile(x - 0.01, (P, 1)) if P > 1 else x - 0.01
        xhi = np.tile(x + 0.01, (P, 1)) if P > 1 else x + 0.01
        for name, fn in (("f", enc.f), ("Jx", enc.jac_x)):
            fn(xlo, xhi, u, u)
            reps = 200 if P == 1 else 5
            t0 = time.perf_counter()
            for _ in range(reps):
                fn(xlo, xhi, u, u)
            dt = (time.perf_counter() - t0) / reps
            lines.append(f"{name} batch {P}: {dt * 1e6:.1f} us/call, {dt / P * 1e6:.2f} us/box")
    print("\n".join(lines))
