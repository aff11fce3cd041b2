"""Sound interval enclosures of a plant's dynamics, Jacobians and second derivatives.

Compiled (:func:`~codev_engine.reach.interval_function.compile_interval`) from the plant's
shared symbolic model (:func:`codev_engine.plant.plant_model`), once per plant model: the
reach engine of every verification of the same plant reuses them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import sympy

from codev_engine.plant import PlantModel, SymbolicPlant, plant_key, plant_model
from codev_engine.reach.interval import Array
from codev_engine.reach.interval_function import IntervalFunction, compile_interval

if TYPE_CHECKING:
    from codev_engine.plant import _PlantKey
    from codev_engine.spec.problem import PlantSpec, Problem

__all__ = ["PlantEnclosures", "plant_enclosures", "plant_hessian", "uncertain_enclosures"]


@dataclass(frozen=True)
class PlantEnclosures:
    """Compiled interval enclosures of a plant's ``f``, ``df/dx`` and ``df/du``.

    Each method takes a state box ``xlo, xhi`` of shape (n,) or (P, n) and an input box
    ``ulo, uhi`` of shape (m,) or (P, m) (a single input box is broadcast over a batch of
    state boxes and vice versa) and returns ``(lo, hi)``:

    - ``f(...)``: (n,) or (P, n);
    - ``jac_x(...)``: (n, n) or (P, n, n);
    - ``jac_u(...)``: (n, m) or (P, n, m).

    Attributes
    ----------
    sym : SymbolicPlant
        The symbolic model the functions were compiled from.
    f_fn, jac_x_fn, jac_u_fn : IntervalFunction
        The compiled functions over the symbols ``(*x, *u)`` (boxes of length n + m).
    """

    sym: SymbolicPlant
    f_fn: IntervalFunction
    jac_x_fn: IntervalFunction
    jac_u_fn: IntervalFunction

    @property
    def n(self) -> int:
        """The state dimension."""
        return len(self.sym.x)

    @property
    def m(self) -> int:
        """The input dimension."""
        return len(self.sym.u)

    def box(self, xlo: Any, xhi: Any, ulo: Any, uhi: Any) -> tuple[Array, Array]:
        """The joint box over ``z = (x, u)``, batch shapes broadcast.

        Parameters
        ----------
        xlo, xhi : (n,) or (P, n) array_like
            The state box.
        ulo, uhi : (m,) or (P, m) array_like
            The input box.

        Returns
        -------
        lo, hi : (n + m,) or (P, n + m) ndarray

        Raises
        ------
        ValueError
            When a side is not of shape (d,) or (P, d).
        """
        n, m = self.n, self.m
        parts = [np.asarray(a, dtype=np.float64) for a in (xlo, xhi, ulo, uhi)]
        if (parts[0].ndim == 2 and parts[0].shape == parts[1].shape and parts[0].shape[1] == n
                and parts[2].shape == parts[3].shape and parts[2].shape[-1] == m
                and (parts[2].ndim == 1 or parts[2].shape[0] == parts[0].shape[0])):
            # (the common case: a batch of states, one input box or one per state)
            P = parts[0].shape[0]
            lo, hi = np.empty((P, n + m)), np.empty((P, n + m))
            lo[:, :n], hi[:, :n] = parts[0], parts[1]
            lo[:, n:], hi[:, n:] = parts[2], parts[3]
            return lo, hi
        for a, d, name in zip(parts, (n, n, m, m), ("xlo", "xhi", "ulo", "uhi"), strict=True):
            if a.ndim not in (1, 2) or a.shape[-1] != d:
                raise ValueError(f"{name} must have shape ({d},) or (P, {d}), got {a.shape}")
        if all(a.ndim == 1 for a in parts):
            return np.concatenate([parts[0], parts[2]]), np.concatenate([parts[1], parts[3]])
        batch = np.broadcast_shapes(*(a.shape[:-1] for a in parts))
        full = [np.broadcast_to(a, (*batch, a.shape[-1])) for a in parts]
        return (
            np.concatenate([full[0], full[2]], axis=-1),
            np.concatenate([full[1], full[3]], axis=-1),
        )

    def f(self, xlo: Any, xhi: Any, ulo: Any, uhi: Any) -> tuple[Array, Array]:
        """Enclosure of ``f(x, u)`` over the box.

        Parameters
        ----------
        xlo, xhi : (n,) or (P, n) array_like
            The state box.
        ulo, uhi : (m,) or (P, m) array_like
            The input box.

        Returns
        -------
        lo, hi : (n,) or (P, n) ndarray
        """
        return self.f_fn(*self.box(xlo, xhi, ulo, uhi))

    def jac_x(self, xlo: Any, xhi: Any, ulo: Any, uhi: Any) -> tuple[Array, Array]:
        """Enclosure of ``df/dx`` over the box.

        Parameters
        ----------
        xlo, xhi : (n,) or (P, n) array_like
            The state box.
        ulo, uhi : (m,) or (P, m) array_like
            The input box.

        Returns
        -------
        lo, hi : (n, n) or (P, n, n) ndarray
        """
        return self.jac_x_fn(*self.box(xlo, xhi, ulo, uhi))

    def jac_u(self, xlo: Any, xhi: Any, ulo: Any, uhi: Any) -> tuple[Array, Array]:
        """Enclosure of ``df/du`` over the box.

        Parameters
        ----------
        xlo, xhi : (n,) or (P, n) array_like
            The state box.
        ulo, uhi : (m,) or (P, m) array_like
            The input box.

        Returns
        -------
        lo, hi : (n, m) or (P, n, m) ndarray
        """
        return self.jac_u_fn(*self.box(xlo, xhi, ulo, uhi))


def plant_enclosures(problem_or_plant: Problem | PlantSpec) -> PlantEnclosures:
    """Interval enclosures of a plant's dynamics and Jacobians (compiled once per plant).

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec
        A plant with continuous-time dynamics (expressions or ``A``, ``B`` matrices).

    Returns
    -------
    PlantEnclosures
        ``f``, ``jac_x``, ``jac_u`` over (state box, input box); see the class.

    Raises
    ------
    SpecError
        If the plant has no continuous-time dynamics.
    """
    return _enclosures(plant_model(problem_or_plant))


def plant_hessian(problem_or_plant: Problem | PlantSpec) -> IntervalFunction:
    """An interval enclosure of the second derivatives of a plant's ``f`` (compiled once).

    Parameters
    ----------
    problem_or_plant : Problem or PlantSpec
        A plant with continuous-time dynamics.

    Returns
    -------
    IntervalFunction
        Over the symbols ``(*x, *u)`` (boxes of length ``k = n + m``); the output is the flat
        list of ``d^2 f_i / dz_a dz_b`` (``z = (x, u)``) in the order ``(i, a, b)``, so it
        reshapes to ``(n, k, k)`` (``(P, n, k, k)`` for a batch).

    Notes
    -----
    For a non-smooth ``f`` the second derivatives hold ``DiracDelta`` terms, whose enclosure is
    ``[0, inf]`` (or ``[-inf, inf]``) over a box meeting the kink: the bound then becomes
    infinite, which callers must treat as "no second-order bound".
    """
    return _hessian(plant_model(problem_or_plant))


# Keyed by the model object (plant_model returns the same one for equal plants); the
# compiled functions are immutable, so every caller can share them.
@functools.lru_cache(maxsize=16)
def _enclosures(model: PlantModel) -> PlantEnclosures:
    sym, args = model.sym, model.args
    return PlantEnclosures(
        sym=sym,
        f_fn=compile_interval(list(sym.f), args),
        jac_x_fn=compile_interval(sym.Jx, args),
        jac_u_fn=compile_interval(sym.Ju, args),
    )


@functools.lru_cache(maxsize=16)
def _hessian(model: PlantModel) -> IntervalFunction:
    args = model.args
    exprs = [sympy.diff(fi, za, zb) for fi in model.sym.f for za in args for zb in args]
    return compile_interval(exprs, args)


def uncertain_enclosures(
    problem: Problem,
) -> tuple[PlantEnclosures, IntervalFunction, np.ndarray, np.ndarray, np.ndarray]:
    """Enclosures of ``f(x, u, w, p)``, the field before the nominal values are put in.

    Parameters
    ----------
    problem : Problem
        With disturbances or uncertain parameters.

    Returns
    -------
    enc : PlantEnclosures
        ``f``, ``jac_x`` and ``jac_u`` over (x, (u, w, p)): ``jac_u`` is (n, m + e).
    hess : IntervalFunction
        The second derivatives over ``(x, u, w, p)`` (as :func:`plant_hessian`).
    lower, upper, nominal : (e,) ndarray
        The ``(w, p)`` box and its nominal values.

    Notes
    -----
    The compiled functions are keyed by the field's expressions and names, not by the boxes'
    values: the pieces of a split parameter box (``reach/parameter_split.py``, each a problem
    with its own box and nominal) share one derivation and compilation.
    """
    pl = problem.plant
    enc, hess = _uncertain_field(plant_key(pl, box_values=False))
    boxes = [b for b in (pl.disturbances, pl.parameters) if b is not None]
    lo = np.concatenate([np.asarray(b.lower, float) for b in boxes])
    hi = np.concatenate([np.asarray(b.upper, float) for b in boxes])
    nom = np.concatenate([np.asarray(b.nominal, float) for b in boxes])
    return enc, hess, lo, hi, nom


@functools.lru_cache(maxsize=16)
def _uncertain_field(key: _PlantKey) -> tuple[PlantEnclosures, IntervalFunction]:
    from codev_engine.plant import full_field

    f, xs, us, ws, ps = full_field(key.plant)
    args = (*xs, *us, *ws, *ps)
    ext = sympy.Matrix([*us, *ws, *ps])
    hess = compile_interval([sympy.diff(fi, za, zb) for fi in f for za in args for zb in args],
                            args)
    enc = PlantEnclosures(
        sym=_AugSym(xs, (*us, *ws, *ps)),  # type: ignore[arg-type]
        f_fn=compile_interval(list(f), args),
        jac_x_fn=compile_interval(f.jacobian(sympy.Matrix(xs)), args),
        jac_u_fn=compile_interval(f.jacobian(ext), args),
    )
    return enc, hess


@dataclass(frozen=True)
class _AugSym:
    """The symbols a :class:`PlantEnclosures` reads its sizes from (x, and u with w, p)."""

    x: tuple
    u: tuple
