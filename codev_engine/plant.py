"""Plant: symbolic dynamics, Jacobian, linearisation and discretisation.

The plant's continuous-time model -- its sympy vector field and Jacobians, and the numeric
callables compiled from them -- is a :class:`PlantModel`, derived once per plant by
:func:`plant_model` and shared by every stage (linearisation, simulation, the reach
engines, the interval enclosures, the workbench). Produces the discrete-time prediction
model ``LinearModel`` used by the MPC.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.io.npz import NpzFormat, load_npz, pair, real, save_npz

if TYPE_CHECKING:
    import sympy

    from codev_engine.spec.problem import PlantSpec, Problem

__all__ = [
    "LinearModel",
    "MODEL_FORMAT",
    "NumericDynamics",
    "PlantModel",
    "SymbolicPlant",
    "clear_plant_models",
    "full_field",
    "discretize",
    "linearize",
    "model_derivations",
    "numeric_dynamics",
    "plant_key",
    "plant_model",
    "symbolic_model",
]

#: format tag of model files (session artifacts); bumped on incompatible changes
MODEL_FORMAT = "codev-model/1"
_MODEL_FILE = NpzFormat("model file", MODEL_FORMAT, "model")


@dataclass(frozen=True)
class LinearModel:
    """Discrete-time affine model in deviation coordinates around the operating point.

    ``dx+ = A dx + B du + c`` with ``dx = x - x_op``, ``du = u - u_op``. ``c`` (n,) is zero
    when the operating point is an equilibrium of the plant.

    Attributes
    ----------
    A : (n, n) ndarray
    B : (n, m) ndarray
    c : (n,) ndarray
    dt : float
        Sample time (s).
    x_op : (n,) ndarray
    u_op : (m,) ndarray
    Ac, Bc : ndarray or None
        The continuous-time linearisation (None for an explicit discrete model).
    """

    A: np.ndarray
    B: np.ndarray
    c: np.ndarray
    dt: float
    x_op: np.ndarray
    u_op: np.ndarray
    Ac: np.ndarray | None = None
    Bc: np.ndarray | None = None

    @property
    def n(self) -> int:
        """The state dimension."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """The input dimension."""
        return self.B.shape[1]

    def save(self, path: str | os.PathLike) -> Path:
        """Write the model to ``path`` (``.npz``, format ``MODEL_FORMAT``, no pickle)
        atomically.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.
        """
        arrays = {
            "A": self.A,
            "B": self.B,
            "c": self.c,
            "dt": np.array(self.dt),
            "x_op": self.x_op,
            "u_op": self.u_op,
        }
        if self.Ac is not None and self.Bc is not None:
            arrays["Ac"], arrays["Bc"] = self.Ac, self.Bc
        return save_npz(path, _MODEL_FILE, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> LinearModel:
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        LinearModel

        Raises
        ------
        SpecError
            The file is missing or malformed (naming the file and the array).
        """
        return load_npz(path, _MODEL_FILE, cls._from_arrays)

    @classmethod
    def _from_arrays(cls, data: dict[str, np.ndarray]) -> LinearModel:
        A = real(data, "A", ndim=2)
        n = A.shape[0]
        if A.shape != (n, n):
            raise SpecError(f"must be square, got shape {A.shape}", field="A")
        B = real(data, "B", ndim=2)
        if B.shape[0] != n:
            raise SpecError(f"must have {n} rows, got shape {B.shape}", field="B")
        m = B.shape[1]
        dt = float(real(data, "dt", shape=()))
        if not dt > 0:
            raise SpecError("must be positive", field="dt")
        pair(data, "Ac", "Bc")
        Ac = real(data, "Ac", shape=(n, n)) if "Ac" in data else None
        Bc = real(data, "Bc", shape=(n, m)) if "Bc" in data else None
        return cls(
            A=A,
            B=B,
            c=real(data, "c", shape=(n,)),
            dt=dt,
            x_op=real(data, "x_op", shape=(n,)),
            u_op=real(data, "u_op", shape=(m,)),
            Ac=Ac,
            Bc=Bc,
        )


@dataclass(frozen=True)
class SymbolicPlant:
    """Symbolic continuous-time dynamics ``dx/dt = f(x, u)`` and its Jacobians.

    Attributes
    ----------
    x : tuple of sympy.Symbol, length n
        State symbols, in spec order.
    u : tuple of sympy.Symbol, length m
        Input symbols, in spec order.
    f : (n, 1) sympy.ImmutableMatrix
        The vector field.
    Jx : (n, n) sympy.ImmutableMatrix
        ``df/dx``.
    Ju : (n, m) sympy.ImmutableMatrix
        ``df/du``.
    """

    x: tuple[sympy.Symbol, ...]
    u: tuple[sympy.Symbol, ...]
    f: sympy.ImmutableMatrix

    # The Jacobians as sympy expressions are derived on first use (the workbench shows
    # them, the interval enclosures compile them); the numeric ones never build them
    # (:func:`_compile`), so loading a spec stays polynomial in the expressions' size.
    @functools.cached_property
    def Jx(self) -> sympy.ImmutableMatrix:  # noqa: N802 - the documented name
        """``df/dx`` (n, n)."""
        import sympy

        return sympy.ImmutableMatrix(self.f.jacobian(sympy.Matrix(self.x)))

    @functools.cached_property
    def Ju(self) -> sympy.ImmutableMatrix:  # noqa: N802 - the documented name
        """``df/du`` (n, m)."""
        import sympy

        return sympy.ImmutableMatrix(self.f.jacobian(sympy.Matrix(self.u)))


class NumericDynamics(tuple):
    """Numeric dynamics: unpacks as the pair ``(f, jac_x)``; ``jac_u`` is an attribute.

    ``f(x, u)``: x (n,), u (m,) -> (n,); batched x (P, n), u (P, m) or (m,) -> (P, n).
    ``jac_x(x, u)``: (n, n), batched (P, n, n). ``jac_u(x, u)``: (n, m), batched (P, n, m).

    Parameters
    ----------
    f : callable
        The vector field ``f(x, u)``.
    jac_x : callable
        ``df/dx(x, u)``.
    jac_u : callable
        ``df/du(x, u)``.
    """

    f: Callable[[np.ndarray, np.ndarray], np.ndarray]
    jac_x: Callable[[np.ndarray, np.ndarray], np.ndarray]
    jac_u: Callable[[np.ndarray, np.ndarray], np.ndarray]

    def __new__(cls, f, jac_x, jac_u):
        self = super().__new__(cls, (f, jac_x))
        self.f = f
        self.jac_x = jac_x
        self.jac_u = jac_u
        return self


def _plant_of(problem_or_plant: Problem | PlantSpec) -> PlantSpec:
    plant = getattr(problem_or_plant, "plant", problem_or_plant)
    if not hasattr(plant, "states"):
        raise TypeError(f"expected a Problem or a PlantSpec, got {type(problem_or_plant)!r}")
    return plant


def _no_continuous_plant() -> SpecError:
    return SpecError(
        "the spec has no continuous-time plant (only an explicit discrete model): give "
        "plant.dynamics or plant.A and plant.B",
        field="plant",
    )


def _uncertain_symbols(plant: PlantSpec) -> tuple[tuple, tuple]:
    """The symbols of the disturbances ``w`` and of the parameters ``p`` (may be empty)."""
    from codev_engine.spec.expr import make_symbol

    w = tuple(make_symbol(s) for s in (plant.disturbances.names if plant.disturbances else ()))
    p = tuple(make_symbol(s) for s in (plant.parameters.names if plant.parameters else ()))
    return w, p


def full_field(plant: PlantSpec) -> tuple[sympy.ImmutableMatrix, tuple, tuple, tuple, tuple]:
    """The vector field ``f(x, u, w, p)`` as parsed, before the nominal values are put in.

    Parameters
    ----------
    plant : PlantSpec

    Returns
    -------
    f : (n, 1) sympy.ImmutableMatrix
    x, u, w, p : tuple of sympy.Symbol
        The state, input, disturbance and parameter symbols (``w``, ``p`` may be empty).

    Raises
    ------
    SpecError
        If the plant has no continuous-time dynamics.
    """
    import sympy

    from codev_engine.spec.expr import make_symbol, parse_expression

    x = tuple(make_symbol(s) for s in plant.states)
    u = tuple(make_symbol(s) for s in plant.inputs)
    w, p = _uncertain_symbols(plant)
    if plant.dynamics is not None:
        names = dict(
            zip(
                (
                    *plant.states,
                    *plant.inputs,
                    *(plant.disturbances.names if plant.disturbances else ()),
                    *(plant.parameters.names if plant.parameters else ()),
                ),
                (*x, *u, *w, *p),
                strict=True,
            )
        )
        exprs = [
            parse_expression(text, names, field=f"plant.dynamics[{i}]")
            for i, text in enumerate(plant.dynamics)
        ]
        f = sympy.ImmutableMatrix(len(exprs), 1, exprs)
    elif plant.A is not None and plant.B is not None:
        A = sympy.Matrix(np.asarray(plant.A, dtype=float).tolist())
        B = sympy.Matrix(np.asarray(plant.B, dtype=float).tolist())
        fm = A * sympy.Matrix(x) + B * sympy.Matrix(u)
        if plant.E is not None and w:
            fm = fm + sympy.Matrix(np.asarray(plant.E, dtype=float).tolist()) * sympy.Matrix(w)
        f = sympy.ImmutableMatrix(fm)
    else:
        raise _no_continuous_plant()
    return f, x, u, w, p


def _derive(plant: PlantSpec) -> SymbolicPlant:
    """Parse the dynamics (or ``A x + B u``) and differentiate: the one derivation.

    Disturbances and uncertain parameters take their nominal values: this is the model the
    design stages use (the verifier reads the uncertain field, :attr:`PlantModel.uncertain`).
    """
    import sympy

    if plant.dynamics is not None or (plant.A is not None and plant.B is not None):
        f, x, u, w, p = full_field(plant)
        if w or p:
            nominal = plant.nominal_values()
            names = [*(plant.disturbances.names if plant.disturbances else ()),
                     *(plant.parameters.names if plant.parameters else ())]
            # an exact zero for a zero nominal disturbance (the term drops out)
            values = {
                s: (sympy.S.Zero if nominal[nm] == 0 else sympy.Float(nominal[nm]))
                for s, nm in zip((*w, *p), names, strict=True)
            }
            f = sympy.ImmutableMatrix(f.subs(values))
            if f.has(sympy.zoo, sympy.oo, -sympy.oo, sympy.nan):
                shown = ", ".join(f"{nm} = {nominal[nm]:g}" for nm in names)
                raise SpecError(
                    f"the dynamics are undefined at the nominal values ({shown}): division "
                    "by zero? Give an interval whose nominal value (plant.nominal, else the "
                    "midpoint of a parameter) keeps them finite",
                    field="plant.parameters" if p else "plant.disturbances",
                )
    else:
        raise _no_continuous_plant()
    return SymbolicPlant(x=x, u=u, f=f)


def _compile(
    exprs: list[sympy.Expr],
    args: tuple[sympy.Symbol, ...],
    *,
    wrt: tuple[sympy.Symbol, ...] = (),
    modules: str = "numpy",
):
    """Compile expressions (and their Jacobian) into one function, in time polynomial in
    their size.

    Each distinct sub-expression becomes one assignment of the generated code (a
    straight-line program over the DAG, not the tree), and the Jacobian with respect to
    ``wrt`` is derived by forward differentiation of those assignments: every derivative
    taken is of one node in its direct arguments. Neither the expressions' tree nor the
    sympy Jacobian is ever built: ``tanh(tanh(...(x)...))`` nested 200 deep compiles in
    well under a second, where ``sympy.lambdify(..., dummify=True)`` of its sympy
    derivative took 36 s at depth 10 (rebuilding the tree over assumption-free dummies
    re-derives each node's assumptions, exponentially).

    The arguments are renamed ``_a0, _a1, ...`` (real, as the spec's symbols) and the
    assignments ``_s0, _s1, ...``: no name of the spec can shadow one of the generated
    code's (``numpy``, a state called ``x0`` against sympy's own temporaries).

    Parameters
    ----------
    exprs : list of sympy.Expr
        The expressions, in the symbols ``args``.
    args : tuple of sympy.Symbol
        The compiled function's arguments, in order.
    wrt : tuple of sympy.Symbol
        When given, the function returns ``len(exprs) * len(wrt)`` values instead, the
        Jacobian's entries row by row.
    modules : str
        ``"numpy"`` or ``"math"``, as for ``sympy.lambdify``.

    Returns
    -------
    callable
        ``fn(*values) -> list`` of one value per expression (or Jacobian entry).
    """
    import sympy

    safe = {a: sympy.Symbol(f"_a{i}", real=True) for i, a in enumerate(args)}
    steps: list[tuple[sympy.Symbol, sympy.Expr]] = []
    value: dict[sympy.Basic, sympy.Expr] = {}  # node -> its symbol (or atom)

    def node_of(root: sympy.Basic) -> sympy.Expr:
        # iterative post-order over the DAG: no recursion, each distinct node once
        stack = [(root, False)]
        while stack:
            e, ready = stack.pop()
            if e in value:
                continue
            if e in safe:
                value[e] = safe[e]
            elif not e.args:
                value[e] = e  # a number or constant
            elif not ready:
                stack.append((e, True))
                stack.extend((a, False) for a in e.args if a not in value)
            else:
                t = sympy.Symbol(f"_s{len(steps)}", real=True)
                steps.append((t, e.func(*(value[a] for a in e.args))))
                value[e] = t
        return value[root]

    outputs = [node_of(e) for e in exprs]
    if wrt:
        outputs = _forward_jacobian(steps, outputs, [safe[z] for z in wrt])
    if modules == "numpy":
        # Derivatives of sign() are DiracDelta: zero almost everywhere, and numpy has no
        # such function. Replace by 0 (the a.e. derivative).
        steps = [(t, e.replace(sympy.DiracDelta, lambda *a: sympy.S.Zero)) for t, e in steps]
    return sympy.lambdify(
        tuple(safe[a] for a in args),
        outputs,
        modules=modules,
        dummify=False,
        cse=lambda _exprs: (steps, outputs),
    )


def _forward_jacobian(
    steps: list[tuple[sympy.Symbol, sympy.Expr]],
    outputs: list[sympy.Expr],
    wrt: list[sympy.Symbol],
) -> list[sympy.Expr]:
    """Append to ``steps`` the forward derivatives of its assignments; return the
    Jacobian of ``outputs`` with respect to ``wrt`` (row by row)."""
    import sympy

    zero = sympy.S.Zero
    # d[symbol] = {j: expression of d symbol / d wrt[j]} (absent: zero)
    d: dict[sympy.Symbol, dict[int, sympy.Expr]] = {z: {j: sympy.S.One} for j, z in enumerate(wrt)}
    for t, e in list(steps):
        grad: dict[int, list[sympy.Expr]] = {}
        for s in sorted(e.free_symbols, key=str):  # the same code in every process
            ds = d.get(s)
            if not ds:
                continue
            partial = sympy.diff(e, s)  # one node in its direct arguments: shallow
            if partial == zero:
                continue
            for j, dj in ds.items():
                grad.setdefault(j, []).append(partial * dj)
        entry = {}
        for j, terms in grad.items():
            g = sympy.Symbol(f"_s{len(steps)}", real=True)
            steps.append((g, sympy.Add(*terms)))
            entry[j] = g
        d[t] = entry
    return [d.get(o, {}).get(j, zero) for o in outputs for j in range(len(wrt))]


def _vectorised(
    compiled, n: int, m: int, out_shape: tuple[int, ...]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    size = int(np.prod(out_shape))

    def call(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if x.shape[-1:] != (n,) or x.ndim > 2:
            raise ValueError(f"x must have shape ({n},) or (P, {n}), got {x.shape}")
        if u.shape[-1:] != (m,) or u.ndim > 2:
            raise ValueError(f"u must have shape ({m},) or (P, {m}), got {u.shape}")
        batch = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        values = compiled(*(x[..., i] for i in range(n)), *(u[..., j] for j in range(m)))
        out = np.empty((*batch, size))
        for k, v in enumerate(values):
            out[..., k] = np.broadcast_to(np.asarray(v, dtype=float), batch)
        return out.reshape(*batch, *out_shape)

    return call


def _matrix_dynamics(plant: PlantSpec) -> NumericDynamics:
    """Exact matrix products of a plant given by ``A``, ``B`` (``+ E w_nominal``)."""
    n, m = plant.n, plant.m
    A = np.array(plant.A, dtype=float)
    B = np.array(plant.B, dtype=float)
    drift = _nominal_drift(plant)

    def f(x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        if drift is None:
            return x @ A.T + u @ B.T
        return x @ A.T + u @ B.T + drift

    def jac_x(x, u):
        batch = np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1])
        return np.broadcast_to(A, (*batch, n, n)).copy()

    def jac_u(x, u):
        batch = np.broadcast_shapes(np.shape(x)[:-1], np.shape(u)[:-1])
        return np.broadcast_to(B, (*batch, n, m)).copy()

    return NumericDynamics(f, jac_x, jac_u)


def _nominal_drift(plant: PlantSpec) -> np.ndarray | None:
    """``E w_nominal`` (n,) of a matrix plant, None when there is none or it is zero."""
    if plant.E is None or plant.disturbances is None:
        return None
    drift = np.asarray(plant.E, dtype=float) @ np.asarray(plant.disturbances.nominal, float)
    return drift if np.any(drift != 0.0) else None


@dataclass(frozen=True, eq=False)
class PlantModel:
    """A plant's continuous-time model, derived once and shared by every stage.

    Made by :func:`plant_model` (one per plant, cached by value). The symbolic model is
    derived when the model is made; each compiled callable is compiled on first use and
    kept (they are pure functions of their arguments: safe to share).

    Attributes
    ----------
    plant : PlantSpec
        The plant it was derived from (one of the equal plants that share it).
    sym : SymbolicPlant
        ``f`` (n, 1), ``Jx`` (n, n), ``Ju`` (n, m) over the symbols ``x``, ``u``.
    """

    plant: PlantSpec
    sym: SymbolicPlant

    @property
    def n(self) -> int:
        """The state dimension."""
        return len(self.sym.x)

    @property
    def m(self) -> int:
        """The input dimension."""
        return len(self.sym.u)

    @property
    def args(self) -> tuple[sympy.Symbol, ...]:
        """The symbols ``(*x, *u)``: the argument order of every compiled function."""
        return (*self.sym.x, *self.sym.u)

    @functools.cached_property
    def numeric(self) -> NumericDynamics:
        """``f``, ``jac_x``, ``jac_u`` with numpy broadcasting (see :func:`numeric_dynamics`)."""
        plant, n, m = self.plant, self.n, self.m
        if plant.dynamics is None and plant.A is not None and plant.B is not None:
            return _matrix_dynamics(plant)
        sym, args = self.sym, self.args
        f = list(sym.f)
        return NumericDynamics(
            _vectorised(_compile(f, args), n, m, (n,)),
            _vectorised(_compile(f, args, wrt=sym.x), n, m, (n, n)),
            _vectorised(_compile(f, args, wrt=sym.u), n, m, (n, m)),
        )

    @functools.cached_property
    def vector_field(
        self,
    ) -> tuple[
        Callable[[np.ndarray, np.ndarray], np.ndarray],
        Callable[[np.ndarray, np.ndarray], np.ndarray],
    ]:
        """``(f_point, f_batch)``: ``f`` for one point and for a batch, for integrators.

        ``f_point(x (n,), u (m,)) -> (n,)``, ``f_batch(X (P, n), U (P, m)) -> (P, n)``. The
        same vector field as ``numeric.f``, compiled without its general broadcasting
        wrapper, which dominates the cost of the many small calls an integrator makes
        (about 5x faster per call).
        """

        if self.plant.dynamics is None:
            f = self.numeric.f
            return f, f
        n = self.n
        compiled = _compile(list(self.sym.f), self.args)

        def f_point(x, u):
            return np.array(compiled(*x, *u), dtype=float)

        def f_batch(X, U):
            values = compiled(*X.T, *U.T)
            out = np.empty((X.shape[0], n))
            for k, v in enumerate(values):
                out[:, k] = v  # constants broadcast
            return out

        return f_point, f_batch

    @functools.cached_property
    def uncertain(self) -> Callable[..., np.ndarray]:
        """``f(X (P, n), U (P, m), W (P, d), Q (P, q)) -> (P, n)``: the vector field with
        the disturbances ``W`` and the parameters ``Q`` as arguments (their spec order)."""

        f, x, u, w, p = full_field(self.plant)
        n = self.n
        compiled = _compile(list(f), (*x, *u, *w, *p))

        def call(X, U, W, Q):
            P = X.shape[0]
            values = compiled(*X.T, *U.T, *W.T, *Q.T)
            out = np.empty((P, n))
            for k, v in enumerate(values):
                out[:, k] = v
            return out

        return call

    @functools.cached_property
    def uncertain_point(self) -> Callable[..., np.ndarray]:
        """``f(x (n,), u (m,), w (d,), q (q,)) -> (n,)``: :attr:`uncertain` for one point,
        without the batch's arrays (the many small calls of an adaptive integrator)."""

        f, x, u, w, p = full_field(self.plant)
        compiled = _compile(list(f), (*x, *u, *w, *p))

        def call(x, u, w, q):
            return np.array(compiled(*x, *u, *w, *q), dtype=float)

        return call

    @functools.cached_property
    def scalar_field(self) -> Callable[..., list[float]]:
        """``f`` on Python floats: ``scalar_field(*x, *u) -> n floats`` (not rigorous).

        Compiled with ``math`` (fastest for one point); when that cannot evaluate (a
        function ``math`` lacks, or a domain error at the probe point), ``f_point``.
        """

        try:
            fm = _compile(list(self.sym.f), self.args, modules="math")
            fm(*([0.1] * (self.n + self.m)))
            return fm
        except Exception:
            fp, n = self.vector_field[0], self.n
            return lambda *z: fp(np.array(z[:n]), np.array(z[n:])).tolist()


@dataclass(frozen=True)
class _PlantKey:
    """A plant by value (PlantSpec holds arrays, so it is not hashable itself)."""

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    dynamics: tuple[str, ...] | None
    A: tuple[tuple[int, ...], bytes] | None
    B: tuple[tuple[int, ...], bytes] | None
    uncertain: tuple
    plant: PlantSpec = field(compare=False, repr=False)


def _matrix_key(a: np.ndarray | None) -> tuple[tuple[int, ...], bytes] | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=float)
    return a.shape, a.tobytes()


#: symbolic derivations made so far (read by tests through :func:`model_derivations`)
_derivations = 0


@functools.lru_cache(maxsize=16)
def _model_of(key: _PlantKey) -> PlantModel:
    global _derivations
    _derivations += 1
    return PlantModel(plant=key.plant, sym=_derive(key.plant))


def plant_model(problem_or_plant: Problem | PlantSpec) -> PlantModel:
    """The plant's model: derived on the first call for a plant, then shared.

    Plants are compared by value (states, inputs, dynamics, ``A`` and ``B``), so equal plants
    of different ``Problem`` objects (a re-loaded spec, ``dataclasses.replace``) share one
    model; the last 16 plants are kept.

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec

    Returns
    -------
    PlantModel

    Raises
    ------
    SpecError
        If the plant has no continuous-time dynamics, or an expression is invalid.
    """
    return _model_of(plant_key(problem_or_plant))


def plant_key(problem_or_plant: Problem | PlantSpec, *, box_values: bool = True) -> _PlantKey:
    """A plant by value, hashable: the key of :func:`plant_model`'s cache.

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec
    box_values : bool
        Key the disturbances' and parameters' boxes by their values too (False: by their
        names alone, for what does not depend on the boxes' values, such as the field over
        ``(x, u, w, p)`` that the pieces of a split parameter box share).

    Returns
    -------
    _PlantKey
        Equal for equal plants; it holds the plant itself (not compared).
    """
    plant = _plant_of(problem_or_plant)
    dyn = None if plant.dynamics is None else tuple(plant.dynamics)
    return _PlantKey(
        tuple(plant.states),
        tuple(plant.inputs),
        dyn,
        _matrix_key(plant.A),
        _matrix_key(plant.B),
        _uncertain_key(plant, box_values),
        plant,
    )


def _uncertain_key(plant: PlantSpec, box_values: bool = True) -> tuple:
    """The disturbances, parameters and ``E`` by value (empty when there are none; the
    boxes by their names alone without ``box_values``)."""
    out: list = []
    for box in (getattr(plant, "disturbances", None), getattr(plant, "parameters", None)):
        if box is None:
            out.append(None)
        elif box_values:
            out.append((box.names, _matrix_key(box.lower), _matrix_key(box.upper),
                        _matrix_key(box.nominal)))
        else:
            out.append((box.names,))
    out.append(_matrix_key(getattr(plant, "E", None)))
    return tuple(out) if any(v is not None for v in out) else ()


def disturbances_matter(problem_or_plant: Problem | PlantSpec) -> bool:
    """Can the disturbances change the plant's field over their box?

    False without disturbances, and when every axis of the box either has zero width (the
    disturbance is its one value, which is the nominal one) or does not enter the field
    (a matrix plant's column of ``E`` is zero; an expression plant's derivative in it is
    identically zero). Then ``f(x, u, w) = f(x, u, w_nominal)`` for every ``w`` in the box:
    the plant is the nominal model, and the verification is the nominal one (docs/spec.md,
    "Disturbances").

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec

    Returns
    -------
    bool
    """
    plant = _plant_of(problem_or_plant)
    box = plant.disturbances
    if box is None:
        return False
    wide = np.asarray(box.upper, float) > np.asarray(box.lower, float)
    if not np.any(wide):
        return False
    if plant.dynamics is None:
        E = getattr(plant, "E", None)
        return E is None or bool(np.any(np.asarray(E, float)[:, wide] != 0.0))
    return _depends_on(plant_key(plant), tuple(bool(v) for v in wide))


@functools.lru_cache(maxsize=16)
def _depends_on(key: _PlantKey, wide: tuple[bool, ...]) -> bool:
    """Does the expression field depend on a disturbance marked ``wide``? (a derivative
    sympy cannot show to be zero counts as a dependence)"""
    import sympy

    f, _, _, w, _ = full_field(key.plant)
    cols = [s for s, keep in zip(w, wide, strict=True) if keep]
    J = f.jacobian(sympy.Matrix(cols))
    return J.is_zero_matrix is not True


def field_uncertain(problem_or_plant: Problem | PlantSpec) -> bool:
    """Uncertain parameters, or disturbances that can change the field
    (:func:`disturbances_matter`): what the verification must cover beyond the nominal
    model. (``PlantSpec.uncertain`` says whether the spec declares them.)

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec

    Returns
    -------
    bool
    """
    plant = _plant_of(problem_or_plant)
    return plant.parameters is not None or disturbances_matter(plant)


def model_derivations() -> int:
    """How many symbolic derivations of a plant model this process has run."""
    return _derivations


def clear_plant_models() -> None:
    """Forget the cached plant models (the next :func:`plant_model` derives again)."""
    _model_of.cache_clear()


def symbolic_model(problem_or_plant: Problem | PlantSpec) -> SymbolicPlant:
    """The symbolic dynamics and Jacobians of the plant (of its shared :class:`PlantModel`).

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec

    Returns
    -------
    SymbolicPlant
        ``f`` (n, 1) from the parsed ``dynamics`` expressions, or ``A x + B u`` for a
        matrix plant; ``Jx`` (n, n) and ``Ju`` (n, m) by ``sympy`` differentiation.

    Raises
    ------
    SpecError
        If the plant has no continuous-time dynamics, or an expression is invalid.
    """
    return plant_model(problem_or_plant).sym


def numeric_dynamics(problem_or_plant: Problem | PlantSpec) -> NumericDynamics:
    """Fast numeric versions of ``f``, ``df/dx`` and ``df/du`` (of the shared model).

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec

    Returns
    -------
    NumericDynamics
        Unpacks as ``f, jac_x = numeric_dynamics(plant)``; also has ``.jac_u``.

        - ``f(x, u)``: x (n,), u (m,) -> (n,); vectorised: x (P, n), u (P, m) -> (P, n)
          (u of shape (m,) is broadcast).
        - ``jac_x(x, u)``: (n, n), vectorised (P, n, n).
        - ``jac_u(x, u)``: (n, m), vectorised (P, n, m).

        For a matrix plant these are exact matrix products; for ``dynamics`` they are built
        with ``sympy.lambdify(..., modules="numpy")`` from the parsed (whitelisted) sympy
        expressions -- never from user text.
    """
    return plant_model(problem_or_plant).numeric


def linearize(
    plant: PlantSpec, x_op: np.ndarray, u_op: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Continuous-time linearisation at an operating point.

    Parameters
    ----------
    plant : PlantSpec
    x_op : (n,) array_like
    u_op : (m,) array_like

    Returns
    -------
    Ac : (n, n) ndarray
        ``df/dx(x_op, u_op)``.
    Bc : (n, m) ndarray
        ``df/du(x_op, u_op)``.
    f0 : (n,) ndarray
        ``f(x_op, u_op)`` (zero iff the operating point is an equilibrium).
    """
    plant = _plant_of(plant)
    x_op = np.asarray(x_op, dtype=float).reshape(plant.n)
    u_op = np.asarray(u_op, dtype=float).reshape(plant.m)
    if plant.dynamics is None:
        if plant.A is None or plant.B is None:
            raise _no_continuous_plant()
        Ac = np.array(plant.A, dtype=float)
        Bc = np.array(plant.B, dtype=float)
        drift = _nominal_drift(plant)
        f0 = Ac @ x_op + Bc @ u_op
        return Ac, Bc, f0 if drift is None else f0 + drift
    f, jac_x = (nd := numeric_dynamics(plant))
    return jac_x(x_op, u_op), nd.jac_u(x_op, u_op), f(x_op, u_op)


def discretize(problem: Problem) -> LinearModel:
    """The discrete-time prediction model of a problem.

    With an explicit discrete model (``model.A``/``model.B``) that model is used as given
    (``c = 0``, ``Ac``/``Bc`` None). Otherwise the plant is linearised at the operating point
    and sampled with python-control (``model.method``, ``model.sample_time``). When the
    operating point is not an equilibrium (``f0 = f(x_op, u_op) != 0``), ``f0`` is sampled as
    an extra constant input, so ``c`` is its effect over one sample period (with the same
    method; for "zoh" exactly ``integral_0^dt exp(Ac s) ds f0``).

    Parameters
    ----------
    problem : Problem

    Returns
    -------
    LinearModel
        ``dx+ = A dx + B du + c`` in deviations from ``(x_op, u_op)``: A (n, n), B (n, m),
        c (n,).

    Notes
    -----
    "zoh", "impulse" and "euler"/"backward_diff" keep the plant state as the model state.
    "foh" and "tustin"/"bilinear" are used as python-control returns them (their ``A``, ``B``
    are the state-space realisation of the sampled transfer function with ``C = I``; its
    output, not its state, equals the plant state).
    """
    spec = problem.model
    n, m = problem.plant.n, problem.plant.m
    x_op = np.array(spec.x_op, dtype=float).reshape(n) if spec.x_op.size else np.zeros(n)
    u_op = np.array(spec.u_op, dtype=float).reshape(m) if spec.u_op.size else np.zeros(m)
    dt = float(spec.sample_time)
    if spec.A is not None and spec.B is not None:
        return LinearModel(
            A=np.array(spec.A, dtype=float),
            B=np.array(spec.B, dtype=float),
            c=np.zeros(n),
            dt=dt,
            x_op=x_op,
            u_op=u_op,
        )
    Ac, Bc, f0 = linearize(problem.plant, x_op, u_op)
    if not (np.all(np.isfinite(Ac)) and np.all(np.isfinite(Bc)) and np.all(np.isfinite(f0))):
        raise SpecError(
            "the dynamics cannot be linearised at the operating point (non-finite values)",
            field="model.operating_point",
        )
    affine = bool(np.any(f0 != 0.0))
    Bin = np.hstack([Bc, f0[:, None]]) if affine else Bc
    import control  # ~0.4 s to import (matplotlib): only when discretising

    sys = control.ss(Ac, Bin, np.eye(n), np.zeros((n, Bin.shape[1])))
    with np.errstate(all="ignore"):  # an overflow is checked below, quietly
        sampled = sys.sample(dt, method=spec.method)
        A = np.array(sampled.A, dtype=float)
        Bd = np.array(sampled.B, dtype=float)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(Bd))):
        raise SpecError(
            f"the sampled model overflows (exp(A dt) past 1e308 over model.sample_time = "
            f"{dt:g} s, with the linearisation's largest entry {float(np.max(np.abs(Ac))):.3g}): "
            "shorten model.sample_time, or change the plant",
            field="model.sample_time",
        )
    B = Bd[:, :m].copy()
    c = Bd[:, m].copy() if affine else np.zeros(n)
    return LinearModel(A=A, B=B, c=c, dt=dt, x_op=x_op, u_op=u_op, Ac=Ac, Bc=Bc)
