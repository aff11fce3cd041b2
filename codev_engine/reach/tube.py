"""Reachtubes: time-stamped boxes that contain every trajectory.

Contract (also in ``docs/verification.md``): every trajectory of the closed loop from the
initial set, at every time ``t`` with ``t_start[k] <= t <= t_end[k]`` for some ``k``, lies in
one of the boxes ``[lower[k], upper[k]]`` whose interval contains ``t``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.io.npz import NpzFormat, array, load_npz, real, save_npz

__all__ = ["Tube", "TUBE_FORMAT"]

TUBE_FORMAT = "codev-tube/1"
#: tube files of other tools (no tag) are read too
_TUBE_FILE = NpzFormat("tube file", TUBE_FORMAT, "tube", untagged=True)


@dataclass(frozen=True)
class Tube:
    """A reachtube as K boxes with time intervals.

    Attributes
    ----------
    t_start, t_end : (K,) ndarray
    lower, upper : (K, n) ndarray
    branch : (K,) ndarray of int
        Which reach-set branch (initial-set piece / mode sequence) each box belongs to.
    """

    t_start: np.ndarray
    t_end: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    branch: np.ndarray

    @property
    def num_boxes(self) -> int:
        """The number of boxes K."""
        return int(self.t_start.shape[0])

    @classmethod
    def empty(cls, n: int) -> Tube:
        """A tube of no boxes in dimension ``n``.

        Parameters
        ----------
        n : int
            The state dimension.

        Returns
        -------
        Tube
        """
        return cls(np.zeros(0), np.zeros(0), np.zeros((0, n)), np.zeros((0, n)), np.zeros(0, int))

    @classmethod
    def concatenate(cls, tubes: list[Tube], n: int) -> Tube:
        """The boxes of ``tubes``, one tube after the other.

        Parameters
        ----------
        tubes : list of Tube
        n : int
            The state dimension (of the result when ``tubes`` is empty).

        Returns
        -------
        Tube
        """
        if not tubes:
            return cls.empty(n)
        return cls(
            np.concatenate([t.t_start for t in tubes]),
            np.concatenate([t.t_end for t in tubes]),
            np.vstack([t.lower for t in tubes]),
            np.vstack([t.upper for t in tubes]),
            np.concatenate([t.branch for t in tubes]),
        )

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The boxes active at time ``t`` (``t_start <= t <= t_end``).

        Parameters
        ----------
        t : float

        Returns
        -------
        lower, upper : (k, n) ndarray
        """
        sel = (self.t_start <= t) & (t <= self.t_end)
        return self.lower[sel], self.upper[sel]

    def hull_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box of all boxes active at ``t``.

        Parameters
        ----------
        t : float

        Returns
        -------
        lower, upper : (n,) ndarray
            NaN when no box is active at ``t``.
        """
        lo, hi = self.at(t)
        if lo.shape[0] == 0:
            n = self.lower.shape[1]
            return np.full(n, np.nan), np.full(n, np.nan)
        return lo.min(axis=0), hi.max(axis=0)

    def contains(self, t: np.ndarray, X: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Is state ``X[p]`` at time ``t[p]`` inside some box active at ``t[p]``?

        Parameters
        ----------
        t : (P,) array_like
            The times.
        X : (P, n) array_like
            The states.
        tol : float
            Absolute slack on every side of the boxes.

        Returns
        -------
        (P,) ndarray of bool
        """
        t = np.asarray(t, dtype=float)
        X = np.atleast_2d(np.asarray(X, dtype=float))
        out = np.zeros(X.shape[0], dtype=bool)
        order = np.argsort(self.t_start)
        ts, te = self.t_start[order], self.t_end[order]
        lo, hi = self.lower[order], self.upper[order]
        for p in range(X.shape[0]):
            sel = (ts <= t[p]) & (t[p] <= te)
            if np.any(sel):
                inside = np.all((lo[sel] - tol <= X[p]) & (X[p] <= hi[sel] + tol), axis=1)
                out[p] = bool(np.any(inside))
        return out

    def save(self, path: str | os.PathLike) -> Path:
        """Write ``t_start``, ``t_end``, ``lower``, ``upper`` and ``branch`` to an npz
        (format ``TUBE_FORMAT``), atomically.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.
        """
        return save_npz(path, _TUBE_FILE, self.arrays())

    @classmethod
    def load(cls, path: str | os.PathLike) -> Tube:
        """Read a tube written by :meth:`save` (or an untagged file of another tool).

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Tube

        Raises
        ------
        SpecError
            The file is missing or malformed (naming the file and the array).
        """
        return load_npz(path, _TUBE_FILE, cls.from_arrays)

    @classmethod
    def from_arrays(cls, data: dict[str, np.ndarray], prefix: str = "") -> Tube:
        """Validate the arrays ``{prefix}t_start`` ... ``{prefix}branch`` and build the tube.

        Every array is real and finite (``SpecError`` names the array), shapes agree and
        ``t_start <= t_end``, ``lower <= upper`` hold.

        Parameters
        ----------
        data : dict of str to ndarray
            The arrays; ``{prefix}branch`` is optional (all zeros).
        prefix : str
            The prefix of the tube's names (a tube stored inside another artifact).

        Returns
        -------
        Tube

        Raises
        ------
        SpecError
            Naming the array that is missing or wrong.
        """
        ts = real(data, prefix + "t_start", ndim=1)
        K = ts.shape[0]
        te = real(data, prefix + "t_end", shape=(K,))
        lo = real(data, prefix + "lower", ndim=2)
        if lo.shape[0] != K:
            raise SpecError(f"must have {K} rows, got shape {lo.shape}", field=prefix + "lower")
        hi = real(data, prefix + "upper", shape=lo.shape)
        key = prefix + "branch"
        branch = array(data, key) if key in data else np.zeros(K, dtype=np.int64)
        if branch.dtype.kind not in "iu" or branch.shape != (K,):
            raise SpecError(f"must be {K} integers, got {branch.dtype} {branch.shape}", field=key)
        if np.any(ts > te):
            raise SpecError("a box ends before it starts", field=prefix + "t_end")
        if np.any(lo > hi):
            raise SpecError("a box has lower > upper", field=prefix + "upper")
        return cls(ts, te, lo, hi, branch.astype(np.int64))

    def arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The tube as named arrays (the inverse of :meth:`from_arrays`).

        Parameters
        ----------
        prefix : str
            Put before every name.

        Returns
        -------
        dict of str to ndarray
        """
        return {
            prefix + "t_start": self.t_start,
            prefix + "t_end": self.t_end,
            prefix + "lower": self.lower,
            prefix + "upper": self.upper,
            prefix + "branch": self.branch,
        }
