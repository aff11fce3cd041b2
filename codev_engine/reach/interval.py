"""Sound interval arithmetic: outward-rounded kernels and the :class:`Interval` type.

The verifier needs enclosures of ``f(x, u)``, of its Jacobians and of higher-order terms
over boxes. This module provides the arithmetic:

- the *kernels*: functions of endpoint arrays ``(lo, hi) -> (lo, hi)`` (numpy, batched),
  and the same operations on Python floats (``math``, for one box at a time: ``_SCALAR``
  maps each array kernel to its scalar twin; same formulas, same margins);
- :class:`Interval`: a vectorised interval (two float arrays ``lo``, ``hi`` of any shape) with
  outward-rounded arithmetic and elementary functions (module functions :func:`sin`,
  :func:`exp`, ...).

Built on it: :mod:`codev_engine.reach.interval_function` compiles sympy expressions into
programs of these kernels (:func:`~codev_engine.reach.interval_function.compile_interval`),
and :mod:`codev_engine.reach.enclosure` compiles a plant's ``f``, ``df/dx``, ``df/du`` and
second derivatives. The soundness argument below covers all three.

Soundness argument
------------------
An interval ``[lo, hi]`` stands for the set of reals between its endpoints (infinite
endpoints mean unbounded). Every operation returns an interval that contains the exact real
image of its input intervals. We assume IEEE-754 binary64 in the default rounding mode
(round to nearest, no flush-to-zero), which is what numpy uses.

1. *Correctly rounded operations* (``+ - * /`` and ``sqrt``): IEEE-754 guarantees that the
   computed result is the float nearest to the exact result, so the exact result lies
   strictly between the float's two neighbours. Each such lower bound is moved one float
   down (``np.nextafter(lo, -inf)``) and each upper bound one float up. This also covers
   overflow (an exact result above the largest float rounds to ``inf``; ``nextafter(inf,
   -inf)`` is the largest float) and gradual underflow.
2. *Transcendental functions* (``sin``, ``exp``, ``log``, ``pow``, ...) are not correctly
   rounded. numpy's implementations (glibc, or Intel SVML / numpy SIMD kernels on AVX-512
   machines) document a maximum error of 4 ulp, Python's ``math`` (glibc) 1-2 ulp. Their
   results are widened by the relative amount ``2**-49`` (at least 7.5 ulp of the result,
   after the rounding of the widening itself) plus the absolute amount ``1e-300`` (for
   results in the subnormal range). ``test_interval.py`` checks the 4-ulp assumption
   against mpmath on the host, for numpy and for ``math``.
3. *Ranges of functions* over an input interval are computed exactly in real arithmetic from
   the endpoint values: monotone functions from the two endpoints; ``x**2n``, ``cosh`` and
   ``abs`` through the interval of ``|x|``; ``sin``/``cos`` from the endpoints plus the
   extrema ``+-1`` when the interval may contain a point ``pi/2 + k pi``. That test is made
   with a margin of ``1e-9`` periods, far above the floating-point error of ``x / (2 pi)``
   for ``|x| <= 1e6``; for larger arguments the result is ``[-1, 1]``. Clamping to the true
   range of a function (``[-1, 1]`` for ``sin``, ``>= 1`` for ``cosh``, ...) keeps results
   tight and is sound.
4. *Constants*: a float literal of a spec (a ``sympy.Float``) is taken to mean the decimal
   number the user wrote, so it is enclosed with the same relative margin as a
   transcendental result (this also covers the few roundings of sympy's 53-bit ``Float``
   arithmetic when it folds constants); integers and rationals are exact when the float is
   (checked with :class:`fractions.Fraction`), else enclosed by the neighbours of the
   correctly rounded float; ``pi`` and ``e`` by the neighbours of ``math.pi``, ``math.e``.
   Exception: an integer or half-integer float *exponent* is exact (``x**2.0`` is ``x**2``,
   ``x**1.5`` is ``sqrt(x)**3``).
   Constant subexpressions (``sqrt(2)``, ``log(2)``) are evaluated at compile time with the
   same interval operations.
5. *Composition*: an interval operation applied to enclosures of its arguments encloses the
   image, so an expression evaluated operation by operation is enclosed (the result can be
   wider than the true range because of the dependency problem, never narrower).

Domain and special values
-------------------------
- Division by an interval containing 0, ``log`` of an interval reaching ``<= 0``, ``sqrt`` of
  one reaching ``< 0``, ``asin``/``acos`` outside ``[-1, 1]``, ``tan`` over an interval that
  may contain a pole (within ``1e-9`` periods) or of an argument beyond ``1e6``, a negative
  base of a non-integer power and a base reaching 0 of a negative power all raise
  :class:`IntervalDomainError` (for the whole batch; ``.boxes`` lists the offending boxes).
- A NaN produced inside (``0 * inf`` or ``inf - inf`` after an overflow) propagates through
  every operation and becomes ``[-inf, inf]`` in the outputs of a compiled function: sound,
  and visibly useless.
- ``atan2(y, x)`` is ``[-pi, pi]`` when the box meets the branch cut ``{x <= 0, y = 0}``
  (which includes the origin); elsewhere it is the hull of the four corner values.
- Derivatives of the non-smooth functions: ``Heaviside`` (the derivative of ``Min``/``Max``)
  is ``[0, 1]`` over a box meeting 0 (the Clarke gradient); ``DiracDelta(x)`` (the derivative
  of ``sign``) is ``[0, inf]`` over a box meeting 0 and exactly 0 elsewhere;
  ``DiracDelta(x, k >= 1)`` is ``[-inf, inf]`` over a box meeting 0.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction
from typing import Any

import numpy as np
import sympy

from codev_engine.errors import CodevError

__all__ = [
    "Interval",
    "IntervalDomainError",
    "abs_",
    "acos",
    "asin",
    "atan",
    "atan2",
    "cos",
    "cosh",
    "exp",
    "log",
    "maximum",
    "minimum",
    "sign",
    "sin",
    "sinh",
    "sqrt",
    "tan",
    "tanh",
]

Array = np.ndarray
Pair = tuple[Any, Any]  # (lo, hi): float arrays or numpy float scalars


class IntervalDomainError(CodevError, ValueError):
    """An interval operation was applied outside its domain (or near a singularity).

    The parameters are kept as attributes of the same names.

    Parameters
    ----------
    reason : str
        What went wrong, e.g. ``"log of an interval reaching <= 0"``.
    mask : ndarray of bool, optional
        Where (elementwise over the operands' broadcast shape) the violation occurred.
    boxes : (k,) ndarray of int, optional
        For an error raised by a compiled function on a batch of boxes: the indices of the
        offending boxes (None for a single box).
    """

    def __init__(self, reason: str, *, mask: Any = None, boxes: Array | None = None):
        self.reason = reason
        self.mask = mask
        self.boxes = boxes
        super().__init__(reason)


# ---------------------------------------------------------------------------------------
# Constants and rounding helpers
# ---------------------------------------------------------------------------------------

_INF = math.inf
_NAN = math.nan
_MAXF = float(np.finfo(np.float64).max)
_REL = 2.0**-49  # relative widening of transcendental results (>= 7.5 ulp)
_TINY = 1e-300  # absolute widening of transcendental results (subnormal range)
_DOWN = 1.0 - _REL  # exact in binary64
_UP = 1.0 + _REL
_PI_UP = math.nextafter(math.pi, _INF)  # > pi
_HALF_PI_UP = math.nextafter(math.pi / 2, _INF)  # > pi/2
_INV_2PI = 1.0 / (2.0 * math.pi)
_INV_PI = 1.0 / math.pi
_TRIG_MARGIN = 1e-9  # periods; >> the error of x/(2 pi) for |x| <= _TRIG_BIG
_TRIG_BIG = 1e6  # beyond this |argument|, sin/cos give [-1, 1] and tan raises


def _dn(x: Any) -> Any:
    """One float down (lower bound of a correctly rounded result)."""
    return np.nextafter(x, -_INF)


def _up(x: Any) -> Any:
    """One float up (upper bound of a correctly rounded result)."""
    return np.nextafter(x, _INF)


def _tdn(x: Any) -> Any:
    """Lower bound of a transcendental result ``x`` (any sign, not ``+inf``)."""
    return x - (np.abs(x) * _REL + _TINY)


def _tup(x: Any) -> Any:
    """Upper bound of a transcendental result ``x`` (any sign, not ``-inf``)."""
    return x + (np.abs(x) * _REL + _TINY)


def _tdn_ovf(x: Any) -> Any:
    """As :func:`_tdn` for a result that may have overflowed to ``+inf``."""
    return _tdn(np.minimum(x, _MAXF))


def _tup_ovf(x: Any) -> Any:
    """As :func:`_tup` for a result that may have overflowed to ``-inf``."""
    return _tup(np.maximum(x, -_MAXF))


def _check(bad: Any, reason: str) -> None:
    """Raise :class:`IntervalDomainError` if any element of the boolean ``bad`` is set."""
    if np.any(bad):
        raise IntervalDomainError(reason, mask=np.asarray(bad))


def _nan_of(*xs: Any) -> Any:
    """Boolean: any of the arrays is NaN (elementwise)."""
    bad = np.isnan(xs[0])
    for x in xs[1:]:
        bad = bad | np.isnan(x)
    return bad


# ---------------------------------------------------------------------------------------
# Kernels: functions of (lo, hi) endpoint arrays returning (lo, hi)
# ---------------------------------------------------------------------------------------


def _k_neg(al: Any, ah: Any) -> Pair:
    return -ah, -al


def _k_add(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    return _dn(al + bl), _up(ah + bh)


def _k_sub(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    return _dn(al - bh), _up(ah - bl)


def _k_mul(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    p1, p2, p3, p4 = al * bl, al * bh, ah * bl, ah * bh
    lo = np.minimum(np.minimum(p1, p2), np.minimum(p3, p4))
    hi = np.maximum(np.maximum(p1, p2), np.maximum(p3, p4))
    return _dn(lo), _up(hi)


def _k_div(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    _check((bl <= 0.0) & (bh >= 0.0), "division by an interval containing 0")
    q1, q2, q3, q4 = al / bl, al / bh, ah / bl, ah / bh
    lo = np.minimum(np.minimum(q1, q2), np.minimum(q3, q4))
    hi = np.maximum(np.maximum(q1, q2), np.maximum(q3, q4))
    return _dn(lo), _up(hi)


def _k_recip(bl: Any, bh: Any) -> Pair:
    _check((bl <= 0.0) & (bh >= 0.0), "division by an interval containing 0")
    return _dn(1.0 / bh), _up(1.0 / bl)


def _k_scale(al: Any, ah: Any, c: float) -> Pair:
    """Multiplication by an exactly representable float ``c`` (not 0)."""
    if c > 0.0:
        return _dn(al * c), _up(ah * c)
    return _dn(ah * c), _up(al * c)


def _k_divc(al: Any, ah: Any, q: float) -> Pair:
    """Division by an exactly representable nonzero float ``q``."""
    if q > 0.0:
        return _dn(al / q), _up(ah / q)
    return _dn(ah / q), _up(al / q)


def _k_abs(al: Any, ah: Any) -> Pair:
    # max(al, -ah, 0) is al when al >= 0, -ah when ah <= 0, else 0; NaN propagates.
    return np.maximum(np.maximum(al, -ah), 0.0), np.maximum(-al, ah)


def _k_sqr(al: Any, ah: Any) -> Pair:
    ml, mh = _k_abs(al, ah)
    return np.maximum(_dn(ml * ml), 0.0), _up(mh * mh)


def _k_ipow(al: Any, ah: Any, n: int) -> Pair:
    """``x**n`` for an integer ``n >= 3``."""
    if n % 2 == 0:
        al, ah = _k_abs(al, ah)
        lo = np.maximum(_tdn_ovf(np.power(al, float(n))), 0.0)
        return lo, _tup(np.power(ah, float(n)))
    return _tdn_ovf(np.power(al, float(n))), _tup_ovf(np.power(ah, float(n)))


def _k_rpow(al: Any, ah: Any, rl: float, rh: float) -> Pair:
    """``x**r`` for a non-integer exponent in ``[rl, rh]`` (same sign, not 0) and ``x >= 0``
    (``x > 0`` for a negative exponent)."""
    if rl > 0.0:
        _check(al < 0.0, f"power {rl:g} of an interval reaching below 0")
    else:
        _check(al <= 0.0, f"power {rl:g} of an interval reaching 0 or below")
    if rl == rh:
        a, b = np.power(al, rl), np.power(ah, rl)
        lo, hi = (a, b) if rl > 0.0 else (b, a)
    else:  # x**r is monotone in x and in r: the extremes are at the corners
        c1, c2, c3, c4 = np.power(al, rl), np.power(al, rh), np.power(ah, rl), np.power(ah, rh)
        lo = np.minimum(np.minimum(c1, c2), np.minimum(c3, c4))
        hi = np.maximum(np.maximum(c1, c2), np.maximum(c3, c4))
    return np.maximum(_tdn_ovf(lo), 0.0), _tup(hi)


def _k_sqrt(al: Any, ah: Any) -> Pair:
    _check(al < 0.0, "sqrt of an interval reaching below 0")
    return np.maximum(_dn(np.sqrt(al)), 0.0), _up(np.sqrt(ah))


def _k_exp(al: Any, ah: Any) -> Pair:
    lo = np.maximum(np.minimum(np.exp(al), _MAXF) * _DOWN - _TINY, 0.0)
    return lo, np.exp(ah) * _UP + _TINY


def _k_log(al: Any, ah: Any) -> Pair:
    _check(al <= 0.0, "log of an interval reaching 0 or below")
    return _tdn(np.log(al)), _tup(np.log(ah))


def _trig(al: Any, ah: Any, fl: Any, fh: Any, phase: float) -> Pair:
    """Range of sin (phase 0.25) or cos (phase 0) over [al, ah] given the endpoint values.

    In units of periods, ``t = x / (2 pi) - phase`` has its maxima at the integers and its
    minima at the half-integers.
    """
    lo = _tdn(np.minimum(fl, fh))
    hi = _tup(np.maximum(fl, fh))
    ta = al * _INV_2PI - (phase + _TRIG_MARGIN)
    tb = ah * _INV_2PI - (phase - _TRIG_MARGIN)
    big = np.maximum(-al, ah) > _TRIG_BIG
    has_max = (np.ceil(ta) <= tb) | big
    has_min = (np.ceil(ta + 0.5) <= tb + 0.5) | big
    # NaN endpoints make every comparison false, so lo/hi stay NaN.
    lo = np.where(has_min, -1.0, np.maximum(lo, -1.0))
    hi = np.where(has_max, 1.0, np.minimum(hi, 1.0))
    return lo, hi


def _k_sin(al: Any, ah: Any) -> Pair:
    return _trig(al, ah, np.sin(al), np.sin(ah), 0.25)


def _k_cos(al: Any, ah: Any) -> Pair:
    return _trig(al, ah, np.cos(al), np.cos(ah), 0.0)


def _k_tan(al: Any, ah: Any) -> Pair:
    # Poles at x = pi/2 + k pi, i.e. at the integers of t = x / pi - 1/2.
    ta = al * _INV_PI - (0.5 + _TRIG_MARGIN)
    tb = ah * _INV_PI - (0.5 - _TRIG_MARGIN)
    _check(
        (np.ceil(ta) <= tb) | (np.maximum(-al, ah) > _TRIG_BIG),
        "tan over an interval that may contain a pole (pi/2 + k pi)",
    )
    return _tdn(np.tan(al)), _tup(np.tan(ah))


def _k_asin(al: Any, ah: Any) -> Pair:
    _check((al < -1.0) | (ah > 1.0), "asin of an interval reaching outside [-1, 1]")
    lo = np.maximum(_tdn(np.arcsin(al)), -_HALF_PI_UP)
    return lo, np.minimum(_tup(np.arcsin(ah)), _HALF_PI_UP)


def _k_acos(al: Any, ah: Any) -> Pair:
    _check((al < -1.0) | (ah > 1.0), "acos of an interval reaching outside [-1, 1]")
    lo = np.maximum(_tdn(np.arccos(ah)), 0.0)
    return lo, np.minimum(_tup(np.arccos(al)), _PI_UP)


def _k_atan(al: Any, ah: Any) -> Pair:
    lo = np.maximum(_tdn(np.arctan(al)), -_HALF_PI_UP)
    return lo, np.minimum(_tup(np.arctan(ah)), _HALF_PI_UP)


def _k_sinh(al: Any, ah: Any) -> Pair:
    return _tdn_ovf(np.sinh(al)), _tup_ovf(np.sinh(ah))


def _k_cosh(al: Any, ah: Any) -> Pair:
    ml, mh = _k_abs(al, ah)
    return np.maximum(_tdn_ovf(np.cosh(ml)), 1.0), _tup(np.cosh(mh))


def _k_tanh(al: Any, ah: Any) -> Pair:
    lo = np.maximum(_tdn(np.tanh(al)), -1.0)
    return lo, np.minimum(_tup(np.tanh(ah)), 1.0)


def _k_sign(al: Any, ah: Any) -> Pair:
    # sign is nondecreasing and exact.
    return np.sign(al), np.sign(ah)


def _k_min(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    return np.minimum(al, bl), np.minimum(ah, bh)


def _k_max(al: Any, ah: Any, bl: Any, bh: Any) -> Pair:
    return np.maximum(al, bl), np.maximum(ah, bh)


def _k_atan2(yl: Any, yh: Any, xl: Any, xh: Any) -> Pair:
    """``atan2(y, x)`` with values in ``[-pi, pi]``."""
    # The box meets the branch cut {x <= 0, y = 0} (or the origin): no better than [-pi, pi].
    cut = (yl <= 0.0) & (yh >= 0.0) & (xl <= 0.0)
    # Elsewhere atan2 is continuous on the box and its extremes are at corners.
    c1, c2, c3, c4 = np.arctan2(yl, xl), np.arctan2(yl, xh), np.arctan2(yh, xl), np.arctan2(yh, xh)
    lo = np.maximum(_tdn(np.minimum(np.minimum(c1, c2), np.minimum(c3, c4))), -_PI_UP)
    hi = np.minimum(_tup(np.maximum(np.maximum(c1, c2), np.maximum(c3, c4))), _PI_UP)
    return np.where(cut, -_PI_UP, lo), np.where(cut, _PI_UP, hi)


def _k_heaviside(al: Any, ah: Any, h0: float = 0.5) -> Pair:
    """Heaviside step (sympy convention: value ``h0`` at 0, default 1/2)."""
    neg = al < 0.0  # the interval has points with value 0
    zero = (al <= 0.0) & (ah >= 0.0)  # ... the point 0, value h0
    pos = ah > 0.0  # ... points with value 1
    lo = np.minimum(
        np.minimum(np.where(neg, 0.0, _INF), np.where(zero, h0, _INF)), np.where(pos, 1.0, _INF)
    )
    hi = np.maximum(
        np.maximum(np.where(neg, 0.0, -_INF), np.where(zero, h0, -_INF)), np.where(pos, 1.0, -_INF)
    )
    nan = _nan_of(al, ah)
    return np.where(nan, _NAN, lo), np.where(nan, _NAN, hi)


def _k_dirac(al: Any, ah: Any, order: int = 0) -> Pair:
    meets = (al <= 0.0) & (ah >= 0.0)
    nan = _nan_of(al, ah)
    lo = np.where(meets, 0.0 if order == 0 else -_INF, 0.0)
    hi = np.where(meets, _INF, 0.0)
    return np.where(nan, _NAN, lo), np.where(nan, _NAN, hi)


# ---------------------------------------------------------------------------------------
# Scalar kernels: the same operations on Python floats, for fast single-box evaluation
# ---------------------------------------------------------------------------------------
#
# They mirror the array kernels above operation by operation (same formulas, same margins,
# libm through ``math`` instead of numpy). Invariant: every register holds finite floats.
# A result that would leave the finite floats (overflow), and a DiracDelta meeting 0, raise
# ``_FallbackError``, and the whole evaluation is redone with the array kernels, which handle
# infinities; ``math``'s OverflowError is treated the same way.


class _FallbackError(Exception):
    """Internal: redo this evaluation with the array kernels."""


_nextafter = math.nextafter
_ceil = math.ceil


def _s_neg(al: float, ah: float) -> tuple[float, float]:
    return -ah, -al


def _s_add(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    lo = _nextafter(al + bl, -_INF)
    hi = _nextafter(ah + bh, _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_sub(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    lo = _nextafter(al - bh, -_INF)
    hi = _nextafter(ah - bl, _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_mul(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    p1, p2, p3, p4 = al * bl, al * bh, ah * bl, ah * bh
    lo = _nextafter(min(p1, p2, p3, p4), -_INF)
    hi = _nextafter(max(p1, p2, p3, p4), _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_div(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    if bl <= 0.0 <= bh:
        raise IntervalDomainError("division by an interval containing 0", mask=True)
    q1, q2, q3, q4 = al / bl, al / bh, ah / bl, ah / bh
    lo = _nextafter(min(q1, q2, q3, q4), -_INF)
    hi = _nextafter(max(q1, q2, q3, q4), _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_recip(bl: float, bh: float) -> tuple[float, float]:
    if bl <= 0.0 <= bh:
        raise IntervalDomainError("division by an interval containing 0", mask=True)
    lo = _nextafter(1.0 / bh, -_INF)
    hi = _nextafter(1.0 / bl, _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_scale(al: float, ah: float, c: float) -> tuple[float, float]:
    if c > 0.0:
        lo, hi = _nextafter(al * c, -_INF), _nextafter(ah * c, _INF)
    else:
        lo, hi = _nextafter(ah * c, -_INF), _nextafter(al * c, _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_divc(al: float, ah: float, q: float) -> tuple[float, float]:
    if q > 0.0:
        lo, hi = _nextafter(al / q, -_INF), _nextafter(ah / q, _INF)
    else:
        lo, hi = _nextafter(ah / q, -_INF), _nextafter(al / q, _INF)
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_abs(al: float, ah: float) -> tuple[float, float]:
    return max(al, -ah, 0.0), max(-al, ah)


def _s_sqr(al: float, ah: float) -> tuple[float, float]:
    ml, mh = max(al, -ah, 0.0), max(-al, ah)
    hi = _nextafter(mh * mh, _INF)
    if hi > _MAXF:
        raise _FallbackError
    return max(_nextafter(ml * ml, -_INF), 0.0), hi


def _s_tdn(x: float) -> float:
    return x - (abs(x) * _REL + _TINY)


def _s_tup(x: float) -> float:
    return x + (abs(x) * _REL + _TINY)


def _s_ipow(al: float, ah: float, n: int) -> tuple[float, float]:
    fn = float(n)
    if n % 2 == 0:
        ml, mh = max(al, -ah, 0.0), max(-al, ah)
        lo, hi = max(_s_tdn(math.pow(ml, fn)), 0.0), _s_tup(math.pow(mh, fn))
    else:
        lo, hi = _s_tdn(math.pow(al, fn)), _s_tup(math.pow(ah, fn))
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_rpow(al: float, ah: float, rl: float, rh: float) -> tuple[float, float]:
    if rl > 0.0:
        if al < 0.0:
            raise IntervalDomainError(f"power {rl:g} of an interval reaching below 0", mask=True)
    elif al <= 0.0:
        raise IntervalDomainError(f"power {rl:g} of an interval reaching 0 or below", mask=True)
    if rl == rh:
        a, b = math.pow(al, rl), math.pow(ah, rl)
        lo, hi = (a, b) if rl > 0.0 else (b, a)
    else:
        c = (math.pow(al, rl), math.pow(al, rh), math.pow(ah, rl), math.pow(ah, rh))
        lo, hi = min(c), max(c)
    hi = _s_tup(hi)
    if hi > _MAXF:
        raise _FallbackError
    return max(_s_tdn(lo), 0.0), hi


def _s_sqrt(al: float, ah: float) -> tuple[float, float]:
    if al < 0.0:
        raise IntervalDomainError("sqrt of an interval reaching below 0", mask=True)
    return max(_nextafter(math.sqrt(al), -_INF), 0.0), _nextafter(math.sqrt(ah), _INF)


def _s_exp(al: float, ah: float) -> tuple[float, float]:
    hi = math.exp(ah) * _UP + _TINY  # OverflowError -> fallback
    if hi > _MAXF:
        raise _FallbackError
    return max(math.exp(al) * _DOWN - _TINY, 0.0), hi


def _s_log(al: float, ah: float) -> tuple[float, float]:
    if al <= 0.0:
        raise IntervalDomainError("log of an interval reaching 0 or below", mask=True)
    return _s_tdn(math.log(al)), _s_tup(math.log(ah))


def _s_trig(al: float, ah: float, fl: float, fh: float, phase: float) -> tuple[float, float]:
    ta = al * _INV_2PI - (phase + _TRIG_MARGIN)
    tb = ah * _INV_2PI - (phase - _TRIG_MARGIN)
    if _ceil(ta) <= tb:
        hi = 1.0
    else:
        hi = min(_s_tup(max(fl, fh)), 1.0)
    if _ceil(ta + 0.5) <= tb + 0.5:
        lo = -1.0
    else:
        lo = max(_s_tdn(min(fl, fh)), -1.0)
    return lo, hi


def _s_sin(al: float, ah: float) -> tuple[float, float]:
    if -al > _TRIG_BIG or ah > _TRIG_BIG:
        return -1.0, 1.0
    return _s_trig(al, ah, math.sin(al), math.sin(ah), 0.25)


def _s_cos(al: float, ah: float) -> tuple[float, float]:
    if -al > _TRIG_BIG or ah > _TRIG_BIG:
        return -1.0, 1.0
    return _s_trig(al, ah, math.cos(al), math.cos(ah), 0.0)


def _s_tan(al: float, ah: float) -> tuple[float, float]:
    ta = al * _INV_PI - (0.5 + _TRIG_MARGIN)
    tb = ah * _INV_PI - (0.5 - _TRIG_MARGIN)
    if -al > _TRIG_BIG or ah > _TRIG_BIG or _ceil(ta) <= tb:
        raise IntervalDomainError(
            "tan over an interval that may contain a pole (pi/2 + k pi)", mask=True
        )
    return _s_tdn(math.tan(al)), _s_tup(math.tan(ah))


def _s_asin(al: float, ah: float) -> tuple[float, float]:
    if al < -1.0 or ah > 1.0:
        raise IntervalDomainError("asin of an interval reaching outside [-1, 1]", mask=True)
    return max(_s_tdn(math.asin(al)), -_HALF_PI_UP), min(_s_tup(math.asin(ah)), _HALF_PI_UP)


def _s_acos(al: float, ah: float) -> tuple[float, float]:
    if al < -1.0 or ah > 1.0:
        raise IntervalDomainError("acos of an interval reaching outside [-1, 1]", mask=True)
    return max(_s_tdn(math.acos(ah)), 0.0), min(_s_tup(math.acos(al)), _PI_UP)


def _s_atan(al: float, ah: float) -> tuple[float, float]:
    return max(_s_tdn(math.atan(al)), -_HALF_PI_UP), min(_s_tup(math.atan(ah)), _HALF_PI_UP)


def _s_sinh(al: float, ah: float) -> tuple[float, float]:
    lo, hi = _s_tdn(math.sinh(al)), _s_tup(math.sinh(ah))  # OverflowError -> fallback
    if lo < -_MAXF or hi > _MAXF:
        raise _FallbackError
    return lo, hi


def _s_cosh(al: float, ah: float) -> tuple[float, float]:
    ml, mh = max(al, -ah, 0.0), max(-al, ah)
    hi = _s_tup(math.cosh(mh))  # OverflowError -> fallback
    if hi > _MAXF:
        raise _FallbackError
    return max(_s_tdn(math.cosh(ml)), 1.0), hi


def _s_tanh(al: float, ah: float) -> tuple[float, float]:
    return max(_s_tdn(math.tanh(al)), -1.0), min(_s_tup(math.tanh(ah)), 1.0)


def _s_sgn(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


def _s_sign(al: float, ah: float) -> tuple[float, float]:
    return _s_sgn(al), _s_sgn(ah)


def _s_min(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    return min(al, bl), min(ah, bh)


def _s_max(al: float, ah: float, bl: float, bh: float) -> tuple[float, float]:
    return max(al, bl), max(ah, bh)


def _s_atan2(yl: float, yh: float, xl: float, xh: float) -> tuple[float, float]:
    if yl <= 0.0 <= yh and xl <= 0.0:
        return -_PI_UP, _PI_UP
    c = (math.atan2(yl, xl), math.atan2(yl, xh), math.atan2(yh, xl), math.atan2(yh, xh))
    return max(_s_tdn(min(c)), -_PI_UP), min(_s_tup(max(c)), _PI_UP)


def _s_heaviside(al: float, ah: float, h0: float = 0.5) -> tuple[float, float]:
    vals = []
    if al < 0.0:
        vals.append(0.0)
    if al <= 0.0 <= ah:
        vals.append(h0)
    if ah > 0.0:
        vals.append(1.0)
    return min(vals), max(vals)


def _s_dirac(al: float, ah: float, order: int = 0) -> tuple[float, float]:
    if al <= 0.0 <= ah:
        raise _FallbackError  # an infinite bound: the array kernels handle it
    return 0.0, 0.0


_SCALAR: dict[Callable[..., Pair], Callable[..., tuple[float, float]]] = {
    _k_neg: _s_neg,
    _k_add: _s_add,
    _k_sub: _s_sub,
    _k_mul: _s_mul,
    _k_div: _s_div,
    _k_recip: _s_recip,
    _k_scale: _s_scale,
    _k_divc: _s_divc,
    _k_abs: _s_abs,
    _k_sqr: _s_sqr,
    _k_ipow: _s_ipow,
    _k_rpow: _s_rpow,
    _k_sqrt: _s_sqrt,
    _k_exp: _s_exp,
    _k_log: _s_log,
    _k_sin: _s_sin,
    _k_cos: _s_cos,
    _k_tan: _s_tan,
    _k_asin: _s_asin,
    _k_acos: _s_acos,
    _k_atan: _s_atan,
    _k_sinh: _s_sinh,
    _k_cosh: _s_cosh,
    _k_tanh: _s_tanh,
    _k_sign: _s_sign,
    _k_min: _s_min,
    _k_max: _s_max,
    _k_atan2: _s_atan2,
    _k_heaviside: _s_heaviside,
    _k_dirac: _s_dirac,
}


# ---------------------------------------------------------------------------------------
# Interval type
# ---------------------------------------------------------------------------------------


def _number_interval(value: Any) -> tuple[float, float]:
    """A sound float enclosure of a real number given as int, float, Fraction or sympy number.

    Python and numpy floats are exact (they are their binary value); ``sympy.Float`` is read
    as a decimal literal and widened relatively (see the module docstring).
    """
    if isinstance(value, bool):
        raise TypeError("booleans are not intervals")
    if isinstance(value, float | np.floating):
        v = float(value)
        return v, v
    if isinstance(value, sympy.Float):
        v = float(value)
        if not math.isfinite(v):
            raise ValueError(f"non-finite constant {value}")
        if v == 0.0:
            return 0.0, 0.0
        return float(_tdn(v)), float(_tup(v))
    if isinstance(value, sympy.Rational):  # includes sympy.Integer
        value = Fraction(int(value.p), int(value.q))
    if isinstance(value, int | np.integer | Fraction):
        frac = Fraction(value)
        v = float(frac)  # correctly rounded
        if Fraction(v) == frac:
            return v, v
        return math.nextafter(v, -_INF), math.nextafter(v, _INF)
    if isinstance(value, sympy.Expr) and value.is_number and value.is_real:
        # pi, E and other named constants: the nearest float is within half an ulp.
        v = float(value.evalf(40))
        return math.nextafter(v, -_INF), math.nextafter(v, _INF)
    raise TypeError(f"cannot make an interval from {value!r}")


def _as_pair(x: Any) -> Pair:
    if isinstance(x, Interval):
        return x.lo, x.hi
    if isinstance(x, np.ndarray):
        x = np.asarray(x, dtype=np.float64)
        return x, x
    lo, hi = _number_interval(x)
    return np.float64(lo), np.float64(hi)


class Interval:
    """A vectorised closed interval ``[lo, hi]`` with outward-rounded arithmetic.

    Parameters
    ----------
    lo : array_like
        Lower bounds (any shape).
    hi : array_like, optional
        Upper bounds, broadcastable with ``lo``; default ``lo`` (a point interval: the float
        values themselves are exact).

    Attributes
    ----------
    lo, hi : ndarray of float64
        The endpoints, of the broadcast shape. ``lo <= hi`` elementwise (checked).

    Notes
    -----
    ``+ - * / **`` and unary ``-``, ``abs`` are supported with other intervals and with
    numbers (a Python or numpy float is exact; a ``sympy.Float`` is read as a decimal literal
    and slightly widened). ``x ** n`` for an integer ``n`` is tight (``[-1, 2] ** 2`` is
    ``[0, 4]``); ``x ** r`` for a non-integer float requires ``x >= 0``; an interval exponent
    uses ``exp(y log x)``. The elementary functions are module functions (:func:`sin`, ...).
    Domain violations raise :class:`IntervalDomainError`.
    """

    __slots__ = ("hi", "lo")
    __array_priority__ = 1000  # ndarray op Interval -> Interval's reflected operator

    def __init__(self, lo: Any, hi: Any = None):
        lo = np.asarray(lo, dtype=np.float64)
        hi = lo if hi is None else np.asarray(hi, dtype=np.float64)
        if lo.shape != hi.shape:
            lo, hi = np.broadcast_arrays(lo, hi)
        if not np.all(lo <= hi):
            raise ValueError("an interval needs lo <= hi (and no NaN)")
        self.lo = lo
        self.hi = hi

    @classmethod
    def _raw(cls, pair: Pair) -> Interval:
        """Wrap a kernel result without checks (NaN endpoints are allowed)."""
        self = cls.__new__(cls)
        lo, hi = np.asarray(pair[0], dtype=np.float64), np.asarray(pair[1], dtype=np.float64)
        if lo.shape != hi.shape:
            lo, hi = np.broadcast_arrays(lo, hi)
        self.lo, self.hi = lo, hi
        return self

    @classmethod
    def of(cls, value: Any) -> Interval:
        """A sound enclosure of a number.

        Parameters
        ----------
        value : int, float, Fraction or sympy number
            A Python or numpy float is exact; a ``sympy.Float`` is read as the decimal
            literal it was written as, and widened; ``sympy.pi``, ``sympy.Rational(1, 3)``
            and other real constants are enclosed by neighbouring floats.

        Returns
        -------
        Interval
            A 0-d interval containing ``value``.

        Raises
        ------
        TypeError
            For a bool or anything that is not a real number.
        """
        return cls(*_number_interval(value))

    # -- properties ------------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, ...]:
        """The shape of the endpoint arrays."""
        return self.lo.shape

    @property
    def width(self) -> Array:
        """``hi - lo`` (rounded to nearest; for information, not for sound bounds)."""
        return self.hi - self.lo

    @property
    def mid(self) -> Array:
        """The midpoint ``(lo + hi) / 2`` (a float inside the interval when finite)."""
        return np.clip(self.lo + 0.5 * (self.hi - self.lo), self.lo, self.hi)

    def contains(self, x: Any) -> Array:
        """Elementwise ``lo <= x <= hi``.

        Parameters
        ----------
        x : array_like
            Points, broadcastable with the interval.

        Returns
        -------
        ndarray of bool
        """
        x = np.asarray(x, dtype=np.float64)
        return (self.lo <= x) & (x <= self.hi)

    def __getitem__(self, key: Any) -> Interval:
        return Interval._raw((self.lo[key], self.hi[key]))

    def __len__(self) -> int:
        return len(self.lo)

    def __repr__(self) -> str:
        if self.lo.ndim == 0:
            return f"Interval([{self.lo!r}, {self.hi!r}])"
        return f"Interval(lo={self.lo!r}, hi={self.hi!r})"

    # -- arithmetic ------------------------------------------------------------------
    def __neg__(self) -> Interval:
        return Interval._raw(_k_neg(self.lo, self.hi))

    def __pos__(self) -> Interval:
        return self

    def __abs__(self) -> Interval:
        return Interval._raw(_k_abs(self.lo, self.hi))

    def _bin(self, other: Any, kernel: Callable[..., Pair], reflected: bool = False) -> Interval:
        try:
            ol, oh = _as_pair(other)
        except TypeError:
            return NotImplemented
        with np.errstate(all="ignore"):
            if reflected:
                return Interval._raw(kernel(ol, oh, self.lo, self.hi))
            return Interval._raw(kernel(self.lo, self.hi, ol, oh))

    def __add__(self, other: Any) -> Interval:
        return self._bin(other, _k_add)

    def __radd__(self, other: Any) -> Interval:
        return self._bin(other, _k_add, True)

    def __sub__(self, other: Any) -> Interval:
        return self._bin(other, _k_sub)

    def __rsub__(self, other: Any) -> Interval:
        return self._bin(other, _k_sub, True)

    def __mul__(self, other: Any) -> Interval:
        return self._bin(other, _k_mul)

    def __rmul__(self, other: Any) -> Interval:
        return self._bin(other, _k_mul, True)

    def __truediv__(self, other: Any) -> Interval:
        return self._bin(other, _k_div)

    def __rtruediv__(self, other: Any) -> Interval:
        return self._bin(other, _k_div, True)

    def __pow__(self, exponent: Any) -> Interval:
        with np.errstate(all="ignore"):
            if isinstance(exponent, Interval):
                return exp(exponent * log(self))
            if isinstance(exponent, sympy.Basic):
                exponent = sympy.sympify(exponent)
                if exponent.is_Integer:
                    return Interval._raw(_pow_int(self.lo, self.hi, int(exponent)))
                if exponent.is_Rational and exponent.q == 2 and exponent.p == 1:
                    return Interval._raw(_k_sqrt(self.lo, self.hi))
                rl, rh = _number_interval(exponent)
                return Interval._raw(_k_rpow(self.lo, self.hi, rl, rh))
            if isinstance(exponent, int | np.integer) and not isinstance(exponent, bool):
                return Interval._raw(_pow_int(self.lo, self.hi, int(exponent)))
            if isinstance(exponent, float | np.floating):
                r = float(exponent)
                if r.is_integer() and abs(r) <= 2.0**53:
                    return Interval._raw(_pow_int(self.lo, self.hi, int(r)))
                if r == 0.5:
                    return Interval._raw(_k_sqrt(self.lo, self.hi))
                if not math.isfinite(r):
                    raise ValueError(f"non-finite exponent {r}")
                return Interval._raw(_k_rpow(self.lo, self.hi, r, r))
        return NotImplemented

    def __rpow__(self, base: Any) -> Interval:
        return exp(self * log(Interval(*_as_pair(base))))

    def __matmul__(self, other: Any) -> Interval:
        """Interval matrix product (sound: products enclosed, sums by :meth:`sum`)."""
        other = other if isinstance(other, Interval) else Interval(*_as_pair(other))
        a, b = self, other
        if a.lo.ndim == 1:
            a = a[None, :]
        vec = b.lo.ndim == 1
        if vec:
            b = b[:, None]
        prod = a[..., :, :, None] * b[..., None, :, :]  # (..., i, k, j)
        out = prod.sum(axis=-2)
        if vec:
            out = out[..., 0]
        if self.lo.ndim == 1:
            out = out[..., 0, :] if not vec else out[..., 0]
        return out

    def __rmatmul__(self, other: Any) -> Interval:
        return Interval(*_as_pair(other)) @ self

    def sum(self, axis: int = -1) -> Interval:
        """Sound sum along ``axis``.

        The floating-point sum of ``k`` terms in any order has an error of at most
        ``gamma_{k-1} * sum(|terms|)`` with ``gamma_j = j u / (1 - j u)``, ``u = 2**-53``;
        the float sums are widened by twice that bound plus an absolute ``k * 2**-1074``
        (underflow).

        Parameters
        ----------
        axis : int
            The axis summed over.

        Returns
        -------
        Interval
            Of the shape without ``axis``; ``[0, 0]`` for an empty axis.
        """
        k = self.lo.shape[axis]
        if k == 0:
            zero = np.zeros(np.delete(np.array(self.lo.shape), axis % self.lo.ndim))
            return Interval(zero)
        u = 2.0**-53
        j = max(k - 1, 1)
        gamma = 2.0 * (j * u) / (1.0 - j * u)
        with np.errstate(all="ignore"):
            slo = np.sum(self.lo, axis=axis)
            shi = np.sum(self.hi, axis=axis)
            alo = np.sum(np.abs(self.lo), axis=axis)
            ahi = np.sum(np.abs(self.hi), axis=axis)
            eps = k * 5e-324
            lo = _dn(slo - _up(alo * gamma) - eps)
            hi = _up(shi + _up(ahi * gamma) + eps)
        return Interval._raw((lo, hi))


def _pow_int(al: Any, ah: Any, n: int) -> Pair:
    if n == 0:
        one = np.ones(np.broadcast_shapes(np.shape(al), np.shape(ah)))
        return one, one
    if n < 0:
        return _k_recip(*_pow_int(al, ah, -n))
    if n == 1:
        return al, ah
    if n == 2:
        return _k_sqr(al, ah)
    return _k_ipow(al, ah, n)


def _unary(kernel: Callable[..., Pair], doc: str) -> Callable[[Any], Interval]:
    def fn(x: Any) -> Interval:
        lo, hi = _as_pair(x)
        with np.errstate(all="ignore"):
            return Interval._raw(kernel(lo, hi))

    fn.__doc__ = doc + _UNARY_DOC
    return fn


#: the sections every unary function's docstring ends with
_UNARY_DOC = """

Parameters
----------
x : Interval, ndarray or number
    The argument: an array is a point interval (its floats are exact), a number is
    enclosed soundly (see :meth:`Interval.of`).

Returns
-------
Interval
    An enclosure of the image of ``x``, elementwise (outward rounded where the
    operation is not exact).
"""

sin = _unary(_k_sin, "Interval sine (tight: extrema inside the interval are included).")
cos = _unary(_k_cos, "Interval cosine (tight: extrema inside the interval are included).")
tan = _unary(_k_tan, "Interval tangent; raises IntervalDomainError if a pole may be inside.")
asin = _unary(_k_asin, "Interval arcsine; the argument must lie in [-1, 1].")
acos = _unary(_k_acos, "Interval arccosine; the argument must lie in [-1, 1].")
atan = _unary(_k_atan, "Interval arctangent.")
sinh = _unary(_k_sinh, "Interval hyperbolic sine.")
cosh = _unary(_k_cosh, "Interval hyperbolic cosine (tight minimum 1 at 0).")
tanh = _unary(_k_tanh, "Interval hyperbolic tangent.")
exp = _unary(_k_exp, "Interval exponential.")
log = _unary(_k_log, "Interval natural logarithm; the argument must be > 0.")
sqrt = _unary(_k_sqrt, "Interval square root; the argument must be >= 0.")
abs_ = _unary(_k_abs, "Interval absolute value (exact).")
sign = _unary(_k_sign, "Interval sign (exact; sign(0) = 0).")


def _binary(kernel: Callable[..., Pair], doc: str) -> Callable[[Any, Any], Interval]:
    def fn(a: Any, b: Any) -> Interval:
        al, ah = _as_pair(a)
        bl, bh = _as_pair(b)
        with np.errstate(all="ignore"):
            return Interval._raw(kernel(al, ah, bl, bh))

    fn.__doc__ = doc + _BINARY_DOC
    return fn


#: the sections every binary function's docstring ends with
_BINARY_DOC = """

Parameters
----------
a, b : Interval, ndarray or number
    The arguments, broadcast together: an array is a point interval (its floats are
    exact), a number is enclosed soundly (see :meth:`Interval.of`).

Returns
-------
Interval
    An enclosure of the image of ``(a, b)``, elementwise (outward rounded where the
    operation is not exact).
"""

minimum = _binary(_k_min, "Elementwise interval minimum (exact).")
maximum = _binary(_k_max, "Elementwise interval maximum (exact).")
atan2 = _binary(
    _k_atan2, "Interval ``atan2(y, x)``, ``y = a``, ``x = b``, in [-pi, pi] (conservative at "
    "the cut)."
)
