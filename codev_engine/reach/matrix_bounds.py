"""Sound bounds on the matrix expressions of the one-period enclosure.

:mod:`codev_engine.reach.nonlinear_flow` bounds the flow of a nonlinear plant over a period
with interval matrices (the Jacobian over a box), matrix exponentials of non-negative
matrices and a Gronwall bound; :mod:`codev_engine.reach.terminal` pads a float sum. The
helpers here round outward: every float sum or product is widened by ``GAMMA`` per term,
scaled by the size of its *terms* (a cancelling sum's rounding error scales with the terms,
not with the result), and ``down2`` / ``up2`` move a value two floats outward.
(:mod:`codev_engine.reach.interval` holds the interval arithmetic of expressions.)
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "GAMMA", "add_pad", "down2", "expabs_vec", "gronwall", "imat_add_point", "imatvec",
    "norm2", "up2",
]


def norm2(mats: np.ndarray) -> np.ndarray:
    """Spectral norms of a batch of matrices.

    Parameters
    ----------
    mats : (P, r, c) ndarray

    Returns
    -------
    (P,) ndarray
        ``inf`` where an entry is not finite (an enclosure that met a singularity).
    """
    fin = np.all(np.isfinite(mats), axis=(1, 2))
    out = np.full(mats.shape[0], np.inf)
    if fin.any():
        out[fin] = np.linalg.norm(mats[fin], 2, axis=(1, 2))
    return out


def gronwall(rho: float, mu: float, a: float, S: float, h: float, b: float) -> float:
    """Bound of ``|r(h)|_W`` for ``r' = Jc r + w``, ``|w|_W <= a (S + |r|_W) + b``,
    ``|r(0)|_W <= rho`` (Gronwall's inequality, rounded up).

    Parameters
    ----------
    rho : float
        Bound of the initial deviation.
    mu : float
        Logarithmic norm of ``Jc`` in the metric ``W``.
    a : float
        Gain of the forcing in the deviation.
    S : float
        Size the forcing's gain applies to besides the deviation.
    h : float
        Time span.
    b : float
        Constant part of the forcing's bound.

    Returns
    -------
    float
    """
    k = mu + a
    grow = np.exp(k * h)
    integ = h if abs(k * h) < 1e-12 else (grow - 1.0) / k
    return float(grow * rho + integ * (a * S + b)) * (1 + 1e-12)


GAMMA = 4 * 2.0**-52  # per-term rounding allowance for short float sums and products


def imat_add_point(Al: np.ndarray, Ah: np.ndarray, Bl: np.ndarray, Bh: np.ndarray,
                   F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[A] + [B] F`` for interval matrices ``[A]``, ``[B]`` and a point matrix ``F``.

    Float sums are widened by the size of their *terms* (a cancelling sum's rounding error
    scales with the terms, not with the result).

    Parameters
    ----------
    Al, Ah : (..., n, n) ndarray
        Bounds of ``[A]``.
    Bl, Bh : (..., n, m) ndarray
        Bounds of ``[B]``.
    F : (m, n) ndarray

    Returns
    -------
    lo, hi : (..., n, n) ndarray
    """
    Fp, Fn = np.maximum(F, 0), np.minimum(F, 0)
    lo = Al + Bl @ Fp + Bh @ Fn
    hi = Ah + Bh @ Fp + Bl @ Fn
    k = F.shape[0] + 2
    mag = np.maximum(np.abs(Al), np.abs(Ah)) + np.maximum(np.abs(Bl), np.abs(Bh)) @ np.abs(F)
    pad = k * GAMMA * mag + 1e-300
    return lo - pad, hi + pad


def imatvec(Al: np.ndarray, Ah: np.ndarray, xl: np.ndarray,
            xh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interval matrices times interval vectors, widened by the size of the summed terms.

    Parameters
    ----------
    Al, Ah : (..., n, k) ndarray
        Bounds of the matrices.
    xl, xh : (..., k) ndarray
        Bounds of the vectors.

    Returns
    -------
    lo, hi : (..., n) ndarray
    """
    xl, xh = xl[..., None, :], xh[..., None, :]
    cands = np.stack([Al * xl, Al * xh, Ah * xl, Ah * xh])
    lo = cands.min(axis=0).sum(axis=-1)
    hi = cands.max(axis=0).sum(axis=-1)
    pad = (xl.shape[-1] + 2) * GAMMA * np.abs(cands).max(axis=0).sum(axis=-1) + 1e-300
    return lo - pad, hi + pad


def expabs_vec(A: np.ndarray, z: np.ndarray) -> np.ndarray | None:
    """Upper bounds of ``exp(A) z`` for non-negative ``A`` (N, q, q) and ``z`` (N, q).

    The Taylor series, every term non-negative (so float sums round by a relative
    ``(k + q) u`` at most, covered by the ``1e-9`` inflation), cut once the terms shrink
    geometrically (ratio ``|A|_inf / (k + 1) <= 1/2``) and are below ``1e-17`` of the sum;
    the tail is at most twice the last term's max-norm, added to every entry.

    Parameters
    ----------
    A : (N, q, q) ndarray
        Non-negative matrices.
    z : (N, q) ndarray
        Non-negative vectors.

    Returns
    -------
    ndarray or None
        (N, q) bounds, or None when an entry is not finite or the series is too long.
    """
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(z))):
        return None
    an = float(np.abs(A).sum(axis=2).max()) if A.size else 0.0
    total = z.copy()
    term = z.copy()
    for k in range(1, 200):
        term = np.einsum("jab,jb->ja", A, term) / k
        total = total + term
        tn = float(term.max()) if term.size else 0.0
        if an / (k + 1) <= 0.5 and tn <= 1e-17 * float(total.max() + 1e-300):
            return total * (1 + 1e-9) + 2.0 * tn * (1 + 1e-9) + 1e-300
    return None


def add_pad(*terms: np.ndarray) -> np.ndarray:
    """Rounding allowance of a short float sum of these terms (element-wise).

    Parameters
    ----------
    *terms : ndarray
        The sum's terms, of one shape (or broadcastable).

    Returns
    -------
    ndarray
        A bound of the sum's rounding error, per element.
    """
    return (len(terms) + 1) * GAMMA * sum(np.abs(t) for t in terms) + 1e-300


def down2(x: Any) -> Any:
    """Two floats down: a lower bound of a value rounded once or twice to nearest.

    Parameters
    ----------
    x : float or ndarray

    Returns
    -------
    float or ndarray
    """
    return np.nextafter(np.nextafter(x, -np.inf), -np.inf)


def up2(x: Any) -> Any:
    """Two floats up: an upper bound of a value rounded once or twice to nearest.

    Parameters
    ----------
    x : float or ndarray

    Returns
    -------
    float or ndarray
    """
    return np.nextafter(np.nextafter(x, np.inf), np.inf)
