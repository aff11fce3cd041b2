"""Greedy merging of regions that share an affine law (MPT3's ``simplify``, greedy).

Two polytopes P, Q with the same law are replaced by their union when the union is
convex. The test (Bemporad, Fukuda & Torrisi, 2001): the *envelope* -- the rows of P valid
on Q together with the rows of Q valid on P -- equals P u Q. Since env contains P u Q,
it suffices that every part of env outside P lies in Q.
"""

from __future__ import annotations

import numpy as np

from codev_engine.geometry.locate import bounding_boxes
from codev_engine.geometry.polytope import certified_minimal_rows, chebyshev_ball, solve_lp

__all__ = ["merge_equal_laws", "merge_regions"]


def _valid_on(
    A: np.ndarray, b: np.ndarray, PA: np.ndarray, Pb: np.ndarray, tol: float
) -> np.ndarray:
    """Which rows ``A x <= b`` hold on all of the polytope ``PA x <= Pb``."""
    out = np.empty(A.shape[0], dtype=bool)
    for i in range(A.shape[0]):
        x, st, _ = solve_lp(-A[i], PA, Pb)
        out[i] = st == "optimal" and A[i] @ x <= b[i] + tol
    return out


def _union_if_convex(PA, Pb, QA, Qb, tol, bound):
    """Envelope of P and Q when P u Q is convex, else None. ``bound`` >= max |x|_inf over
    P and Q."""
    vp = _valid_on(PA, Pb, QA, Qb, tol)
    vq = _valid_on(QA, Qb, PA, Pb, tol)
    EA = np.vstack([PA[vp], QA[vq]])
    Eb = np.concatenate([Pb[vp], Qb[vq]])
    # every piece of env outside P, i.e. env with one violated P-row reversed, must be in Q
    for i in np.flatnonzero(~vp):
        SA = np.vstack([EA, -PA[i][None, :]])
        Sb = np.concatenate([Eb, [-Pb[i]]])
        _, r = chebyshev_ball(SA, Sb)
        if r <= tol:
            continue  # that piece is flat: nothing to check
        for j in np.flatnonzero(~vq):
            x, st, _ = solve_lp(-QA[j], SA, Sb)
            if st != "optimal" or QA[j] @ x > Qb[j] + tol:
                return None
    # a row minrep drops goes only with a proof: a needed row dropped would stretch the
    # merged region over its neighbours, with this law
    keep = certified_minimal_rows(EA, Eb, bound)
    return EA[keep], Eb[keep]


def merge_regions(
    As: list[np.ndarray],
    bs: list[np.ndarray],
    keys: list[bytes],
    tol: float = 1e-8,
) -> tuple[list[np.ndarray], list[np.ndarray], list[int]]:
    """Merge regions with equal ``keys`` (their laws) while the union stays convex.

    Parameters
    ----------
    As, bs : lists of (r_i, d), (r_i,) arrays
    keys : list of bytes
        Equal keys mean equal affine laws.
    tol : float

    Returns
    -------
    As, bs : lists
        The merged regions.
    source : list of int
        For each merged region, the index of one original region (its law).
    """
    groups: dict[bytes, list[int]] = {}
    for i, k in enumerate(keys):
        groups.setdefault(k, []).append(i)
    outA, outb, src = [], [], []
    for members in groups.values():
        polys = [(As[i], bs[i], i) for i in members]
        changed = True
        while changed and len(polys) > 1:
            changed = False
            lo_hi = [_box(a, b) for a, b, _ in polys]
            for i in range(len(polys)):
                for j in range(i + 1, len(polys)):
                    (li, hi_), (lj, hj) = lo_hi[i], lo_hi[j]
                    if np.any(li > hj + tol) or np.any(lj > hi_ + tol):
                        continue  # boxes apart: cannot touch
                    bound = float(np.max(np.abs([li, hi_, lj, hj])))
                    u = _union_if_convex(
                        polys[i][0], polys[i][1], polys[j][0], polys[j][1], tol, bound
                    )
                    if u is not None:
                        polys[i] = (u[0], u[1], polys[i][2])
                        del polys[j]
                        changed = True
                        break
                if changed:
                    break
        for a, b, i in polys:
            outA.append(a)
            outb.append(b)
            src.append(i)
    return outA, outb, src


def _box(A, b):
    lo, hi = bounding_boxes([A], [b])
    return lo[0], hi[0]


def merge_equal_laws(
    As: list[np.ndarray], bs: list[np.ndarray], F: np.ndarray, G: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
    """Regions whose affine laws are equal up to round-off merged where their union is
    convex (:func:`merge_regions` with the law as the key).

    Two laws share a key when ``(F_i, G_i)`` agree to 9 decimals relative to the largest
    entry of all of them (at least 1): the same function up to the solver's round-off.

    Parameters
    ----------
    As, bs : list of (r_i, d) and (r_i,) ndarray
        The regions ``A_i theta <= b_i``.
    F : (k, m, d) ndarray
    G : (k, m) ndarray

    Returns
    -------
    As, bs : lists
        The merged regions.
    F : (k', m, d) ndarray
    G : (k', m) ndarray
    """
    if not As:
        return As, bs, F, G
    scale = max(1.0, float(np.max(np.abs(F), initial=0)), float(np.max(np.abs(G), initial=0)))
    keys = [
        np.round(np.concatenate([f.ravel(), g]) / scale, 9).tobytes()
        for f, g in zip(F, G, strict=True)
    ]
    As, bs, src = merge_regions(As, bs, keys)
    return As, bs, F[src], G[src]
