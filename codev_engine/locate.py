"""Vectorised point location in a polyhedral partition.

A uniform grid over the partition's bounding box lists, per cell, the regions whose
bounding box meets the cell. A query finds its cell and tests the candidates of that cell
in rounds: round r tests every still-unlocated point against its r-th candidate at once,
so the work is numpy-vectorised over points and proportional to the (small) number of
candidates per cell rather than to the number of regions.
"""

from __future__ import annotations

import numpy as np

from .polytope import solve_lp

__all__ = ["PointLocator", "bounding_boxes"]


def bounding_boxes(As: list[np.ndarray], bs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding boxes of bounded polytopes -> lower (R, d), upper (R, d)."""
    R = len(As)
    d = As[0].shape[1] if R else 0
    lo = np.empty((R, d))
    hi = np.empty((R, d))
    eye = np.eye(d)
    for i, (A, b) in enumerate(zip(As, bs, strict=True)):
        for j in range(d):
            x, st, _ = solve_lp(eye[j], A, b)
            lo[i, j] = x[j] if st == "optimal" else -np.inf
            x, st, _ = solve_lp(-eye[j], A, b)
            hi[i, j] = x[j] if st == "optimal" else np.inf
    return lo, hi


class PointLocator:
    """Locate points in the regions ``{x : A_i x <= b_i}``.

    Parameters
    ----------
    As, bs : lists of (k_i, d) and (k_i,) arrays
        The regions (bounded).
    tol : float
        A point within ``tol`` of a region (row-wise, unit-norm rows) counts as inside;
        on shared boundaries the lowest region index wins.
    boxes : (lower, upper), optional
        Precomputed bounding boxes (R, d) each.
    """

    def __init__(
        self,
        As: list[np.ndarray],
        bs: list[np.ndarray],
        tol: float = 1e-9,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.num_regions = len(As)
        self.tol = tol
        if self.num_regions == 0:
            return
        self.d = As[0].shape[1]
        kmax = max(a.shape[0] for a in As)
        R, d = self.num_regions, self.d
        self.Apad = np.zeros((R, kmax, d))
        self.bpad = np.ones((R, kmax))
        for i, (A, b) in enumerate(zip(As, bs, strict=True)):
            self.Apad[i, : A.shape[0]] = A
            self.bpad[i, : A.shape[0]] = b
        lo, hi = boxes if boxes is not None else bounding_boxes(As, bs)
        self.box_lo, self.box_hi = lo, hi
        self.lo = lo.min(axis=0)
        self.hi = hi.max(axis=0)
        span = np.maximum(self.hi - self.lo, 1e-12)
        # about 16 cells per region overall, at most 256 per axis
        g = int(np.clip(np.ceil((16 * R) ** (1.0 / d)), 1, 256))
        self.g = g
        self.cell = span / g
        half = 0.5 * self.cell
        clo = np.clip(np.floor((lo - self.lo) / self.cell - 1e-9), 0, g - 1).astype(int)
        chi = np.clip(np.floor((hi - self.lo) / self.cell + 1e-9), 0, g - 1).astype(int)
        lists: list[list[int]] = [[] for _ in range(g**d)]
        strides = g ** np.arange(d)
        for i in range(R):
            ranges = [np.arange(clo[i, j], chi[i, j] + 1) for j in range(d)]
            mesh = np.stack(np.meshgrid(*ranges, indexing="ij"), axis=-1).reshape(-1, d)
            # drop cells that one of the region's rows separates from it entirely
            centres = self.lo + (mesh + 0.5) * self.cell
            A, b = As[i], bs[i]
            lowest = centres @ A.T - np.abs(A) @ half
            meets = np.all(lowest <= b + tol, axis=1)
            for c in mesh[meets] @ strides:
                lists[int(c)].append(i)
        counts = np.array([len(x) for x in lists])
        self.start = np.concatenate([[0], np.cumsum(counts)])
        self.cands = np.array([r for x in lists for r in x], dtype=int)
        self.strides = strides

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index per row of ``X`` (P, d) -> (P,) int, -1 outside every region."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        P = X.shape[0]
        out = np.full(P, -1, dtype=int)
        if self.num_regions == 0:
            return out
        finite = np.all(np.isfinite(X), axis=1)
        inbox = finite & np.all((X >= self.lo - self.tol) & (X <= self.hi + self.tol), axis=1)
        pts = np.flatnonzero(inbox)
        cidx = np.clip(np.floor((X[pts] - self.lo) / self.cell), 0, self.g - 1).astype(int)
        cell = cidx @ self.strides
        first = self.start[cell]
        count = self.start[cell + 1] - first
        r = 0
        alive = count > 0
        while np.any(alive):
            sel = np.flatnonzero(alive)
            reg = self.cands[first[sel] + r]
            xs = X[pts[sel]]
            viol = np.einsum("pkd,pd->pk", self.Apad[reg], xs) - self.bpad[reg]
            hit = np.all(viol <= self.tol, axis=1)
            out[pts[sel[hit]]] = reg[hit]
            alive[sel[hit]] = False
            r += 1
            alive &= count > r
        return out
