"""Strictly convex mp-QP by combinatorial adjacency: a graph search over active sets.

For ``H > 0`` the optimizer is unique and, for an active set ``A`` with linearly
independent rows, the KKT conditions give affine multipliers and slacks (the least-distance
form, ``M = G H^-1 G'`` and ``d(theta) = w + S theta + G H^-1 (c + C theta)``)::

    lambda_A(theta) = -M_AA^-1 d_A(theta)          (must be >= 0)
    slack_I(theta)  = d_I(theta) + M_IA lambda_A    (must be >= 0, I the other rows)

``A`` is *optimal* when that polyhedron (intersected with the parameter set) is non-empty;
it is a critical region of the partition when it is full-dimensional. The optimal active
sets, lower-dimensional ones included, are connected by adding or removing one constraint;
where LICQ breaks (dependent rows, or more rows than variables) the subsets of the set are
explored instead. Exploring that graph from one optimal active set reaches every critical
region, degenerate facets included (several constraints changing on one hyperplane, which
defeats exploration "across the facet"). This is the combinatorial-adjacency idea of
Arnstroem & Axehill (CDC 2024, ParametricDAQP), written here for numpy: one small solve and
one Chebyshev-ball LP per candidate active set.
"""

from __future__ import annotations

from collections.abc import Callable

import daqp
import numpy as np
from scipy.linalg import cho_solve

from .errors import SolverError
from .mpsolution import CriticalRegion
from .polytope import chebyshev_ball, minimal_rows

__all__ = ["explore_active_sets"]


def explore_active_sets(
    H: np.ndarray,
    c: np.ndarray,
    C: np.ndarray,
    G: np.ndarray,
    w: np.ndarray,
    S: np.ndarray,
    At: np.ndarray,
    bt: np.ndarray,
    theta0: np.ndarray,
    *,
    scale: float,
    region_tol: float,
    max_regions: int,
    progress: Callable[[int], None] | None = None,
    stats: dict | None = None,
) -> list[CriticalRegion]:
    """All full-dimensional critical regions of ``min 0.5 z'Hz + (c + C theta)'z s.t.
    G z <= w + S theta, At theta <= bt`` (H positive definite, rows of G unit norm).

    Parameters
    ----------
    theta0 : (d,) ndarray
        A feasible parameter (the search starts from the optimal active set there).
    scale : float
        Size of the parameter set (tolerances are relative to it).

    Returns
    -------
    list of CriticalRegion
        In the variables z; ``active`` holds the active set.
    """
    stats = {} if stats is None else stats
    nz, d = G.shape[1], At.shape[1]
    m = G.shape[0]
    Hinv_Gt = np.linalg.solve(H, G.T)  # (nz, m)
    M = G @ Hinv_Gt  # (m, m)
    Hinv_c = np.linalg.solve(H, c)
    Hinv_C = np.linalg.solve(H, C)
    D0 = w + G @ Hinv_c  # d(theta) = D0 + D1 theta
    D1 = S + G @ Hinv_C
    # rows that cannot be active together: exact opposites (a variable's two bounds)
    opposite = {}
    for i in range(m):
        j = np.flatnonzero(np.abs(G + G[i]).max(axis=1) <= 1e-12)
        opposite[i] = set(int(x) for x in j)
    nonempty_tol = 1e-8 * scale
    Dfull = np.hstack([D0[:, None], D1])  # (m, d+1)
    negZ0 = -np.hstack([Hinv_c[:, None], Hinv_C])
    idx = np.arange(m)
    nt = At.shape[0]
    zeros_t = np.zeros(nt, dtype=np.intp)

    def region(act: tuple[int, ...]):
        """(status, rows, law): status 'licq', 'empty', 'lower' or 'full'."""
        A = np.array(act, dtype=np.intp)
        na = A.size
        if na > nz:
            return "licq", None, None, None
        if na:
            # rows of G_A (unit norm) dependent, or nearly: LICQ broken
            Rq = np.linalg.qr(G[A].T, mode="r")
            if np.min(np.abs(np.diag(Rq))) < 1e-9:
                return "licq", None, None, None
            MA = M[A]
            MAA = MA[:, A]
            try:
                Lc = np.linalg.cholesky(MAA)
            except np.linalg.LinAlgError:
                return "licq", None, None, None
            Lam = cho_solve((Lc, True), -Dfull[A])  # (na, d+1)
        else:
            MA = np.zeros((0, m))
            Lam = np.zeros((0, d + 1))
        mask = np.ones(m, dtype=bool)
        mask[A] = False
        inact = idx[mask]
        Sl = Dfull[inact] + MA[:, inact].T @ Lam
        # lambda >= 0  <=>  -Lam1 theta <= Lam0 ;  slack >= 0  <=>  -Sl1 theta <= Sl0
        Ar = np.vstack([-Lam[:, 1:], -Sl[:, 1:], At])
        br = np.concatenate([Lam[:, 0], Sl[:, 0], bt])
        # which constraint each row belongs to: +i+1 "i may leave", -(i+1) "i may enter"
        src = np.concatenate([A + 1, -(inact + 1), zeros_t])
        norms = np.linalg.norm(Ar, axis=1)
        zero = norms <= 1e-12
        if np.any(br[zero] < -1e-12):
            return "empty", None, None, None
        Ar, br, src = Ar[~zero] / norms[~zero, None], br[~zero] / norms[~zero], src[~zero]
        stats["lps"] = stats.get("lps", 0) + 1
        centre, rho = chebyshev_ball(Ar, br)
        if not rho >= -nonempty_tol:
            return "empty", None, None, None
        if not rho > region_tol:
            # lower-dimensional: its neighbours are the constraints tight at a point of it
            tight = Ar @ centre - br >= -max(rho, 0.0) - 1e-7 * scale
            return "lower", None, None, src[tight]
        keep = minimal_rows(Ar, br)
        # DAQP's minrep was seen dropping a parameter-set row that is not redundant
        # (pop_mpqp_085: a region reaching theta_2 = 106 in a box of +-10); those rows
        # are few and cheap to keep: every region stays inside the parameter set
        keep = np.union1d(keep, np.flatnonzero(src == 0))
        # the neighbours: constraints of the facets, and of rows on a facet's hyperplane
        # (several constraints changing on one hyperplane: a degenerate facet)
        facets = np.hstack([Ar[keep], br[keep, None]])
        allrows = np.hstack([Ar, br[:, None]])
        near = np.abs(allrows[:, None, :] - facets[None, :, :]).max(axis=2) <= 1e-9 * (
            1.0 + np.abs(facets[None, :, -1])
        )
        moves = src[np.any(near, axis=1)]
        # z = -H^-1 (c + C theta) - H^-1 G_A' lambda_A(theta)
        Z = negZ0 - Hinv_Gt[:, A] @ Lam
        return "full", (Ar[keep], br[keep]), (Z[:, 1:], Z[:, 0]), moves

    act0 = _active_set_at(H, c, C, G, w, S, theta0)
    regions: list[CriticalRegion] = []
    explored = {act0}
    stack = [act0]
    while stack:
        act = stack.pop()
        status, rows, law, moves = region(act)
        stats["candidates"] = stats.get("candidates", 0) + 1
        if status in ("empty",):
            continue
        if status == "full":
            regions.append(CriticalRegion(A=rows[0], b=rows[1], K=law[0], k=law[1], active=act))
            if progress is not None:
                progress(len(regions))
            if len(regions) > max_regions:
                raise SolverError(f"more than {max_regions} regions")
        if status == "licq":
            leave, enter = list(act), []  # its subsets are the way on
        else:
            # across the facets of a full-dimensional region, or the constraints tight
            # on a lower-dimensional one
            leave = [int(v) - 1 for v in moves if v > 0]
            enter = [int(-v) - 1 for v in moves if v < 0]
        for i in leave:
            new = tuple(x for x in act if x != i)
            if new not in explored:
                explored.add(new)
                stack.append(new)
        if status == "licq" or len(act) >= nz + 1:
            continue
        blocked = set(act)
        for i in act:
            blocked |= opposite[i]
        for i in enter:
            if i in blocked:
                continue
            new = tuple(sorted(act + (i,)))
            if new not in explored:
                explored.add(new)
                stack.append(new)
    stats["explored"] = len(explored)
    return _merge_equal_laws(regions, scale, stats)


def _merge_equal_laws(
    regions: list[CriticalRegion], scale: float, stats: dict
) -> list[CriticalRegion]:
    """One region per affine law where the union is provably convex.

    Where LICQ fails on a full-dimensional set (more constraints tight than independent),
    several active sets give the same law on overlapping regions (the multipliers are not
    unique). Regions with equal laws are merged pairwise while the union is convex
    (``merge.merge_regions``, an exact envelope test), which removes the overlaps.
    """
    from .merge import merge_regions

    keys = [
        np.round(np.hstack([r.K, r.k[:, None]]) / (1e-7 * max(scale, 1.0)), 0).tobytes()
        for r in regions
    ]
    if len(set(keys)) == len(keys):
        return regions
    As, bs, src = merge_regions([r.A for r in regions], [r.b for r in regions], keys)
    stats["merged"] = len(regions) - len(As)
    return [
        CriticalRegion(A=a, b=b, K=regions[i].K, k=regions[i].k, active=regions[i].active)
        for a, b, i in zip(As, bs, src, strict=True)
    ]


def _active_set_at(H, c, C, G, w, S, theta) -> tuple[int, ...]:
    m = G.shape[0]
    x, _, flag, info = daqp.solve(
        H,
        c + C @ theta,
        G,
        w + S @ theta,
        np.full(m, -1e30),
        np.zeros(m, dtype=np.int32),
        iter_limit=10_000,
        primal_tol=1e-11,
        dual_tol=1e-12,
    )
    if flag != 1:
        raise SolverError(f"could not solve the QP at the start parameter (DAQP flag {flag})")
    lam = np.asarray(info["lam"])
    return tuple(int(i) for i in np.flatnonzero(lam > 0))
