"""A compiler from sympy expressions to sound, batched interval evaluators.

:func:`compile_interval` compiles sympy expressions (as built by
:mod:`codev_engine.spec.expr` and their derivatives) once into a flat program over
registers of the kernels of :mod:`codev_engine.reach.interval`; an
:class:`IntervalFunction` runs it on boxes. Constant subexpressions are folded at compile
time with the same kernels, and identical subtrees are shared.

A compiled function evaluates one box (or each box of a batch of at most 6) with the scalar
kernels on Python floats (``math``), about 0.5 us per operation, and larger batches with the
array kernels (numpy), about 1 us per box for a cart-pole Jacobian. The two kernel sets
implement the same formulas with the same margins. Soundness: each operation encloses the
exact image of its operands (the argument in :mod:`codev_engine.reach.interval`), so the
program encloses the expressions (composition).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import sympy

from codev_engine.reach.interval import (
    _INF,
    _MAXF,
    _SCALAR,
    Array,
    Interval,
    IntervalDomainError,
    Pair,
    _FallbackError,
    _k_abs,
    _k_acos,
    _k_add,
    _k_asin,
    _k_atan,
    _k_atan2,
    _k_cos,
    _k_cosh,
    _k_dirac,
    _k_div,
    _k_divc,
    _k_exp,
    _k_heaviside,
    _k_ipow,
    _k_log,
    _k_max,
    _k_min,
    _k_mul,
    _k_neg,
    _k_recip,
    _k_rpow,
    _k_scale,
    _k_sign,
    _k_sin,
    _k_sinh,
    _k_sqr,
    _k_sqrt,
    _k_sub,
    _k_tan,
    _k_tanh,
    _number_interval,
)

__all__ = ["IntervalFunction", "compile_interval"]

_SCALAR_MAX_BATCH = 6  # batches up to this size are evaluated box by box on Python floats

_UNARY_FUNCS: dict[type, Callable[..., Pair]] = {
    sympy.sin: _k_sin,
    sympy.cos: _k_cos,
    sympy.tan: _k_tan,
    sympy.asin: _k_asin,
    sympy.acos: _k_acos,
    sympy.atan: _k_atan,
    sympy.sinh: _k_sinh,
    sympy.cosh: _k_cosh,
    sympy.tanh: _k_tanh,
    sympy.exp: _k_exp,
    sympy.log: _k_log,
    sympy.Abs: _k_abs,
    sympy.sign: _k_sign,
}


@dataclass(frozen=True)
class _Op:
    kernel: Callable[..., Pair]
    a: int  # input register
    b: int  # second input register, or -1
    params: tuple
    out: int
    what: str  # the sympy subexpression, for error messages


class _Compiler:
    def __init__(self, symbols: Sequence[sympy.Symbol]):
        self.regs: list[Pair | None] = [None] * len(symbols)
        self.const: list[bool] = [False] * len(symbols)
        self.ops: list[_Op] = []
        self.memo: dict[sympy.Basic, int] = {s: i for i, s in enumerate(symbols)}
        if len(self.memo) != len(symbols):
            raise ValueError("the symbols must be distinct")

    # -- registers -------------------------------------------------------------------
    def constant(self, lo: Any, hi: Any) -> int:
        self.regs.append((np.float64(lo), np.float64(hi)))
        self.const.append(True)
        return len(self.regs) - 1

    def emit(self, kernel: Callable[..., Pair], a: int, b: int = -1, params=(), what="") -> int:
        inputs = (a,) if b < 0 else (a, b)
        if all(self.const[i] for i in inputs):  # fold constants with the same kernel
            args = [x for i in inputs for x in self.regs[i]]
            with np.errstate(all="ignore"):
                try:
                    lo, hi = kernel(*args, *params)
                except IntervalDomainError as exc:
                    raise IntervalDomainError(f"{exc.reason} in {what}") from None
            return self.constant(lo, hi)
        self.regs.append(None)
        self.const.append(False)
        out = len(self.regs) - 1
        self.ops.append(_Op(kernel, a, b, tuple(params), out, what))
        return out

    # -- expressions -----------------------------------------------------------------
    def compile(self, expr: sympy.Basic) -> int:
        expr = sympy.sympify(expr)
        reg = self.memo.get(expr)
        if reg is None:
            reg = self._compile(expr)
            self.memo[expr] = reg
        return reg

    def _compile(self, e: sympy.Basic) -> int:
        what = str(e)
        if e.is_Symbol:
            raise ValueError(f"the symbol {e} is not among the compiled function's symbols")
        if e.is_Number or isinstance(e, sympy.NumberSymbol):
            if not (e.is_real and e.is_finite):
                raise ValueError(f"cannot enclose the constant {e}")
            return self.constant(*_number_interval(e))
        if e.is_Add:
            return self._add(e)
        if e.is_Mul:
            return self._mul(e)
        if e.is_Pow:
            return self._pow(e.base, e.exp, what)
        func = e.func
        if func in _UNARY_FUNCS:
            (arg,) = e.args
            return self.emit(_UNARY_FUNCS[func], self.compile(arg), what=what)
        if func in (sympy.Min, sympy.Max):
            kernel = _k_min if func is sympy.Min else _k_max
            regs = [self.compile(a) for a in e.args]
            r = regs[0]
            for s in regs[1:]:
                r = self.emit(kernel, r, s, what=what)
            return r
        if func is sympy.atan2:
            y, x = e.args
            return self.emit(_k_atan2, self.compile(y), self.compile(x), what=what)
        if func is sympy.Heaviside:
            h0 = 0.5 if len(e.args) < 2 else float(e.args[1])
            if not math.isfinite(h0):
                raise ValueError(f"cannot enclose {e}")
            return self.emit(_k_heaviside, self.compile(e.args[0]), params=(h0,), what=what)
        if func is sympy.DiracDelta:
            order = 0 if len(e.args) < 2 else int(e.args[1])
            return self.emit(_k_dirac, self.compile(e.args[0]), params=(order,), what=what)
        raise NotImplementedError(f"no interval rule for {func.__name__} (in {what})")

    def _add(self, e: sympy.Add) -> int:
        r: int | None = None
        for term in e.args:
            coeff, _ = term.as_coeff_Mul()
            negative = coeff.is_number and coeff.is_negative
            t = self.compile(-term if negative else term)
            if r is None:
                r = self.emit(_k_neg, t, what=str(term)) if negative else t
            else:
                r = self.emit(_k_sub if negative else _k_add, r, t, what=str(e))
        assert r is not None
        return r

    def _mul(self, e: sympy.Mul) -> int:
        coeff, rest = e.as_coeff_Mul()
        num: list[sympy.Expr] = []
        den: list[sympy.Expr] = []
        for f in sympy.Mul.make_args(rest):
            if f.is_Pow and f.exp.is_number and f.exp.is_negative:
                den.append(sympy.Pow(f.base, -f.exp, evaluate=False))
            else:
                num.append(f)
        what = str(e)
        r = self._product(num, what) if num else None
        if den:
            d = self._product(den, what)
            if r is None:
                return self.emit(_k_div, self.constant(*_number_interval(coeff)), d, what=what)
            r = self.emit(_k_div, r, d, what=what)
        assert r is not None
        return self._scale(r, coeff, what)

    def _product(self, factors: list[sympy.Expr], what: str) -> int:
        regs = [self.compile(f) for f in factors]
        r = regs[0]
        for s in regs[1:]:
            r = self.emit(_k_mul, r, s, what=what)
        return r

    def _scale(self, r: int, coeff: sympy.Number, what: str) -> int:
        """``coeff * register``, as tightly as the constant allows."""
        if coeff == 1:
            return r
        if coeff == -1:
            return self.emit(_k_neg, r, what=what)
        if coeff == 0:
            return self.constant(0.0, 0.0)
        lo, hi = _number_interval(coeff)
        if lo == hi:
            return self.emit(_k_scale, r, params=(lo,), what=what)
        if coeff.is_Rational:
            p, q = (
                _number_interval(sympy.Integer(coeff.p)),
                _number_interval(sympy.Integer(coeff.q)),
            )
            if p[0] == p[1] and q[0] == q[1]:  # p and q exact: (r * p) / q
                if p[0] not in (1.0, -1.0):
                    r = self.emit(_k_scale, r, params=(p[0],), what=what)
                elif p[0] == -1.0:
                    r = self.emit(_k_neg, r, what=what)
                return self.emit(_k_divc, r, params=(q[0],), what=what)
        return self.emit(_k_mul, r, self.constant(lo, hi), what=what)

    def _pow(self, base: sympy.Expr, ex: sympy.Expr, what: str) -> int:
        if ex.is_number:
            if ex.is_Float and (2.0 * float(ex)).is_integer() and abs(float(ex)) <= 2.0**52:
                ex = sympy.Rational(int(2.0 * float(ex)), 2)  # x**2.0, x**0.5 are exact
            if ex.is_Integer:
                n = int(ex)
                b = self.compile(base)
                if n < 0:
                    p = self._pow_int_reg(b, -n, what)
                    return self.emit(_k_recip, p, what=what)
                return self._pow_int_reg(b, n, what)
            if ex.is_Rational and ex.q == 2:  # half-integer powers through sqrt
                root = self.emit(_k_sqrt, self.compile(base), what=what)
                p = self._pow_int_reg(root, abs(int(ex.p)), what)
                return p if ex.p > 0 else self.emit(_k_recip, p, what=what)
            if ex.is_real:
                rl, rh = _number_interval(ex)
                if rl == 0.0 or rh == 0.0 or (rl < 0.0) != (rh < 0.0):
                    raise ValueError(f"cannot enclose the exponent of {what}")
                return self.emit(_k_rpow, self.compile(base), params=(rl, rh), what=what)
        # Non-constant exponent: b**e = exp(e log b), b > 0.
        lg = self.emit(_k_log, self.compile(base), what=what)
        prod = self.emit(_k_mul, self.compile(ex), lg, what=what)
        return self.emit(_k_exp, prod, what=what)

    def _pow_int_reg(self, b: int, n: int, what: str) -> int:
        if n == 0:
            return self.constant(1.0, 1.0)
        if n == 1:
            return b
        if n == 2:
            return self.emit(_k_sqr, b, what=what)
        return self.emit(_k_ipow, b, params=(n,), what=what)


class IntervalFunction:
    """A compiled interval evaluator of sympy expressions (see :func:`compile_interval`).

    Made by :func:`compile_interval`, not directly.

    Parameters
    ----------
    symbols : tuple of sympy.Symbol
        The argument symbols, in the order of the box coordinates (the attribute
        ``symbols``).
    shape : tuple of int
        The output shape: ``(rows, cols)`` for a matrix, ``(k,)`` for a list, ``()`` for
        one expression (the attribute ``shape``).
    compiler : _Compiler
        The compiled program: its registers (the arguments first, then constants and
        results) and its operations.
    outs : sequence of int
        The output registers, flat, in the C order of ``shape``.

    Notes
    -----
    A finite box, and each box of a batch of at most 6, is evaluated with scalar kernels on
    Python floats (``math``); larger batches with the array kernels (numpy). Both implement
    the same operations with the same margins. The scalar run falls back to the array
    kernels when a bound overflows or is infinite.
    """

    def __init__(
        self,
        symbols: tuple[sympy.Symbol, ...],
        shape: tuple[int, ...],
        compiler: _Compiler,
        outs: Sequence[int],
    ):
        self.symbols = symbols
        self.shape = shape
        self._k = len(symbols)
        self._regs = list(compiler.regs)
        self._sregs = [None if r is None else (float(r[0]), float(r[1])) for r in compiler.regs]
        self._ops = tuple((op.kernel, op.a, op.b, op.params, op.out) for op in compiler.ops)
        self._sops = tuple(
            (_SCALAR[op.kernel], op.a, op.b, op.params, op.out) for op in compiler.ops
        )
        self._what = tuple(op.what for op in compiler.ops)
        self._size = len(outs)
        # Constant outputs are written once into templates.
        tmpl_lo, tmpl_hi = [0.0] * self._size, [0.0] * self._size
        self._var_outs: list[tuple[int, int]] = []
        for j, r in enumerate(outs):
            if compiler.const[r]:
                tmpl_lo[j], tmpl_hi[j] = self._sregs[r]
            else:
                self._var_outs.append((j, r))
        self._tmpl_lo, self._tmpl_hi = tmpl_lo, tmpl_hi

    @property
    def n_ops(self) -> int:
        """Number of operations of the compiled program."""
        return len(self._ops)

    def __repr__(self) -> str:
        return f"IntervalFunction(symbols={self.symbols}, shape={self.shape}, n_ops={self.n_ops})"

    def __call__(self, lo: Any, hi: Any = None) -> tuple[Array, Array]:
        """Enclose the expressions over a box or a batch of boxes.

        Parameters
        ----------
        lo, hi : (k,) or (P, k) array_like
            Box bounds, ``k = len(symbols)``, ``lo <= hi`` (infinite bounds allowed). ``lo``
            may also be an :class:`Interval` of shape (k,) or (P, k), ``hi`` then omitted.

        Returns
        -------
        lo, hi : ndarray
            Enclosures of shape ``shape`` (one box) or ``(P, *shape)`` (a batch). Entries
            whose computation overflowed into NaN are ``[-inf, inf]``.

        Raises
        ------
        IntervalDomainError
            If an operation is applied outside its domain on some box (``.boxes`` gives the
            offending indices of a batch). With a batch, one bad box fails the whole call.
        ValueError
            On bad shapes, NaN or ``lo > hi``.
        """
        if hi is None:
            if not isinstance(lo, Interval):
                raise TypeError("give lo and hi, or one Interval")
            lo, hi = lo.lo, lo.hi
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        k = self._k
        if lo.shape != hi.shape or lo.ndim not in (1, 2) or lo.shape[-1] != k:
            raise ValueError(
                f"lo and hi must both have shape ({k},) or (P, {k}); got {lo.shape}, {hi.shape}"
            )
        single = lo.ndim == 1
        P = 1 if single else lo.shape[0]
        if P <= _SCALAR_MAX_BATCH:
            # (finite, ordered boxes checked at once: the per-box check is then skipped)
            checked = bool(np.all((lo >= -_MAXF) & (lo <= hi) & (hi <= _MAXF)))
            done = self._scalar_batch(lo.reshape(P, k).tolist(), hi.reshape(P, k).tolist(), single,
                                      checked)
            if done is not None:
                return done
        elif not np.all(lo <= hi):
            raise ValueError("the box needs lo <= hi (and no NaN)")
        out_lo, out_hi = self._array(lo.reshape(-1, k), hi.reshape(-1, k), single)
        if single:
            return out_lo.reshape(self.shape), out_hi.reshape(self.shape)
        return out_lo.reshape(-1, *self.shape), out_hi.reshape(-1, *self.shape)

    def _domain_error(self, exc: IntervalDomainError, idx: int, P: int | None):
        boxes = None
        if P is not None and exc.mask is not None:
            boxes = np.flatnonzero(np.broadcast_to(np.asarray(exc.mask), (P,)))
        return IntervalDomainError(f"{exc.reason} in {self._what[idx]}", mask=exc.mask, boxes=boxes)

    def _scalar_batch(
        self, lol: list[list[float]], hil: list[list[float]], single: bool,
        checked: bool = False,
    ) -> tuple[Array, Array] | None:
        """A few boxes, one by one with the scalar kernels; None when the array kernels must
        do it (an infinite bound, an overflow, or a domain error in a batch, for ``.boxes``).
        ``checked``: every box is already known finite and ordered."""
        outs_lo, outs_hi = [], []
        for bl, bh in zip(lol, hil, strict=True):
            if not checked and not all(
                -_MAXF <= a <= b <= _MAXF for a, b in zip(bl, bh, strict=True)
            ):
                if not all(a <= b for a, b in zip(bl, bh, strict=True)):
                    raise ValueError("the box needs lo <= hi (and no NaN)")
                return None
            try:
                out_lo, out_hi = self._scalar(bl, bh)
            except IntervalDomainError:
                if single:
                    raise
                return None
            except (_FallbackError, OverflowError, ValueError):
                return None
            outs_lo.append(out_lo)
            outs_hi.append(out_hi)
        shape = self.shape if single else (len(outs_lo), *self.shape)
        return (
            np.array(outs_lo, dtype=np.float64).reshape(shape),
            np.array(outs_hi, dtype=np.float64).reshape(shape),
        )

    def _scalar(self, lol: list[float], hil: list[float]) -> tuple[list[float], list[float]]:
        """One finite box with the scalar kernels; raises _FallbackError or OverflowError."""
        regs = self._sregs.copy()
        for i in range(self._k):
            regs[i] = (lol[i], hil[i])
        idx = 0
        try:
            for idx, (kernel, a, b, params, out) in enumerate(self._sops):  # noqa: B007
                ra = regs[a]
                if b < 0:
                    regs[out] = kernel(ra[0], ra[1], *params)
                else:
                    rb = regs[b]
                    regs[out] = kernel(ra[0], ra[1], rb[0], rb[1], *params)
        except IntervalDomainError as exc:
            raise self._domain_error(exc, idx, None) from None
        out_lo, out_hi = self._tmpl_lo.copy(), self._tmpl_hi.copy()
        for j, r in self._var_outs:
            out_lo[j], out_hi[j] = regs[r]
        return out_lo, out_hi

    def _array(self, lo: Array, hi: Array, single: bool) -> tuple[Array, Array]:
        """A batch (P, k) of boxes with the array kernels -> (P, size) bounds."""
        P = lo.shape[0]
        regs = self._regs.copy()
        lt, ht = lo.T, hi.T
        for i in range(self._k):
            regs[i] = (lt[i], ht[i])
        idx = 0
        try:
            with np.errstate(all="ignore"):
                for idx, (kernel, a, b, params, out) in enumerate(self._ops):  # noqa: B007
                    ra = regs[a]
                    if b < 0:
                        regs[out] = kernel(ra[0], ra[1], *params)
                    else:
                        rb = regs[b]
                        regs[out] = kernel(ra[0], ra[1], rb[0], rb[1], *params)
        except IntervalDomainError as exc:
            raise self._domain_error(exc, idx, None if single else P) from None
        out_lo = np.empty((P, self._size))
        out_hi = np.empty((P, self._size))
        out_lo[:] = self._tmpl_lo
        out_hi[:] = self._tmpl_hi
        for j, r in self._var_outs:
            rl, rh = regs[r]
            out_lo[:, j] = rl
            out_hi[:, j] = rh
        # NaN (an overflow turned into inf - inf or 0 * inf) -> the whole line.
        np.fmax(out_lo, -_INF, out=out_lo)
        np.fmin(out_hi, _INF, out=out_hi)
        return out_lo, out_hi


def compile_interval(
    exprs: sympy.MatrixBase | Sequence[sympy.Expr] | sympy.Expr,
    symbols: Sequence[sympy.Symbol],
    *,
    cse: bool = True,
) -> IntervalFunction:
    """Compile sympy expressions into a sound, batched interval evaluator.

    Parameters
    ----------
    exprs : sympy Matrix (r, c), sequence of k expressions, or one expression
        Built from numbers, ``pi``, ``E``, ``+ - * /``, ``**``, ``sin cos tan asin acos atan
        atan2 sinh cosh tanh exp log sqrt Abs sign Min Max`` and the derivatives sympy makes
        of them (``Heaviside``, ``DiracDelta``).
    symbols : sequence of sympy.Symbol, length k
        The arguments, in the order of the box coordinates. Every free symbol of ``exprs``
        must be among them.
    cse : bool
        Run ``sympy.cse`` first (identical subtrees are shared in any case).

    Returns
    -------
    IntervalFunction
        ``F(lo, hi) -> (lo, hi)``: boxes (k,) or (P, k) -> enclosures of shape ``(r, c)``
        or ``(P, r, c)`` for a matrix, ``(k,)`` or ``(P, k)`` for a sequence, ``()`` or
        ``(P,)`` for one expression.

    Raises
    ------
    NotImplementedError
        For a function without an interval rule.
    ValueError
        For a free symbol not in ``symbols`` or a non-real constant.
    IntervalDomainError
        For a constant subexpression outside its domain (``log(-1)``).
    """
    if isinstance(exprs, sympy.MatrixBase):
        shape: tuple[int, ...] = tuple(exprs.shape)
        flat = list(exprs)
    elif isinstance(exprs, sympy.Basic):
        shape = ()
        flat = [exprs]
    else:
        flat = [sympy.sympify(e) for e in exprs]
        shape = (len(flat),)
    symbols = tuple(symbols)
    comp = _Compiler(symbols)
    if cse and flat:
        replacements, reduced = sympy.cse(flat)
        for sym, sub in replacements:
            comp.memo[sym] = comp.compile(sub)
        flat = reduced
    outs = [comp.compile(e) for e in flat]
    return IntervalFunction(symbols, shape, comp, outs)
