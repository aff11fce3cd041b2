"""The explicit MPC law: a polyhedral partition with an affine law per critical region.

``u = F_i x + G_i`` for ``x`` in region ``i = {x : A_i x <= b_i}``, all in plant
coordinates. Saved as a plain ``.npz`` (no pickle): the regions' rows are concatenated
with an offset array.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import SpecError
from .locate import PointLocator, bounding_boxes
from .polytope import Polytope

__all__ = ["ExplicitLaw", "LAW_FORMAT"]

#: format tag written into every law file; bumped on incompatible changes
LAW_FORMAT = "codev-explicit-law/1"


@dataclass
class ExplicitLaw:
    """Piecewise-affine state feedback on a polyhedral partition.

    Attributes
    ----------
    A : list of (r_i, n) ndarray
        Region rows (unit norm), ``A_i x <= b_i``.
    b : list of (r_i,) ndarray
    F : (k, m, n) ndarray
    G : (k, m) ndarray
    states, inputs : tuple of str
    fingerprint : str
        Hash of the MPC problem the law was computed for (model, weights, bounds); used to
        refuse a law file that belongs to another problem.
    meta : dict
        Free-form JSON-able metadata (problem name, norm, seconds, solver stats).
    domain_A, domain_b : ndarray
        The law's domain (the MPC's feasible set, the union of the regions) as
        ``domain_A x <= domain_b``, non-redundant.
    """

    A: list[np.ndarray]
    b: list[np.ndarray]
    F: np.ndarray
    G: np.ndarray
    states: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    fingerprint: str = ""
    meta: dict = field(default_factory=dict)
    domain_A: np.ndarray | None = None
    domain_b: np.ndarray | None = None
    _locator: PointLocator | None = field(default=None, repr=False, compare=False)
    _boxes: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    # ---- shape -----------------------------------------------------------------------

    @property
    def num_regions(self) -> int:
        return len(self.A)

    @property
    def n(self) -> int:
        return self.F.shape[2] if self.F.ndim == 3 and self.F.shape[0] else len(self.states)

    @property
    def m(self) -> int:
        return self.F.shape[1] if self.F.ndim == 3 and self.F.shape[0] else len(self.inputs)

    @property
    def regions(self) -> list[Polytope]:
        """The critical regions as ``Polytope`` objects (H-representations)."""
        return [Polytope(a, b) for a, b in zip(self.A, self.b, strict=True)]

    # ---- evaluation ------------------------------------------------------------------

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes of the regions, lower (k, n) and upper (k, n)."""
        if self._boxes is None:
            self._boxes = bounding_boxes(self.A, self.b)
        return self._boxes

    @property
    def locator(self) -> PointLocator:
        if self._locator is None:
            self._locator = PointLocator(self.A, self.b, boxes=self.boxes)
        return self._locator

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index of each state.

        Parameters
        ----------
        X : (P, n) or (n,) array_like

        Returns
        -------
        (P,) ndarray of int
            -1 where the state is outside the law's domain (the MPC is infeasible there).
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        self._check_dim(X)
        return self.locator.locate(X)

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """The control ``u = F_i x + G_i``.

        Parameters
        ----------
        X : (P, n) or (n,) array_like

        Returns
        -------
        (P, m) ndarray
            NaN rows outside the law's domain.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        idx = self.locate(X)
        U = np.full((X.shape[0], self.m), np.nan)
        inside = idx >= 0
        U[inside] = np.einsum("pij,pj->pi", self.F[idx[inside]], X[inside]) + self.G[idx[inside]]
        return U

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.evaluate(X)

    def _check_dim(self, X: np.ndarray) -> None:
        if X.shape[1] != self.n:
            raise ValueError(f"expected states of dimension {self.n}, got {X.shape[1]}")

    # ---- persistence -----------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write the law to ``path`` (``.npz``) atomically; returns the path written."""
        path = Path(path)
        offsets = np.cumsum([0] + [a.shape[0] for a in self.A])
        n = self.n
        arrays = {
            "format": np.array(LAW_FORMAT),
            "A": np.vstack(self.A) if self.A else np.zeros((0, n)),
            "b": np.concatenate(self.b) if self.b else np.zeros(0),
            "offsets": offsets.astype(np.int64),
            "F": self.F,
            "G": self.G,
            "states": np.array(self.states, dtype=str),
            "inputs": np.array(self.inputs, dtype=str),
            "fingerprint": np.array(self.fingerprint),
            "meta": np.array(json.dumps(self.meta, default=_json_default)),
        }
        if self._boxes is not None:
            arrays["box_lo"], arrays["box_hi"] = self._boxes
        if self.domain_A is not None:
            arrays["domain_A"], arrays["domain_b"] = self.domain_A, self.domain_b
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".npz")
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(fh, **arrays)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> ExplicitLaw:
        """Read a law written by ``save``; any malformed file raises ``SpecError``."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except FileNotFoundError:
            raise SpecError("no such file", file=str(path)) from None
        except Exception as exc:  # zip/npy errors of every kind: not a law file
            raise SpecError(
                f"not a readable law file ({exc.__class__.__name__})", file=str(path)
            ) from None
        try:
            if str(data["format"]) != LAW_FORMAT:
                raise SpecError(f"unsupported law format {str(data['format'])!r}", file=str(path))
            A, b, off = data["A"], data["b"], data["offsets"]
            F, G = data["F"].astype(float), data["G"].astype(float)
            k = F.shape[0]
            ok = (
                A.ndim == 2
                and b.ndim == 1
                and off.ndim == 1
                and off.shape[0] == k + 1
                and off[0] == 0
                and off[-1] == A.shape[0] == b.shape[0]
                and np.all(np.diff(off) >= 0)
                and F.ndim == 3
                and G.shape == F.shape[:2]
                and (k == 0 or A.shape[1] == F.shape[2])
            )
            if not ok:
                raise SpecError("inconsistent array shapes", file=str(path))
            for arr in (A, b, F, G):
                if not np.all(np.isfinite(arr)):
                    raise SpecError("non-finite numbers", file=str(path))
            law = cls(
                A=[A[off[i] : off[i + 1]] for i in range(k)],
                b=[b[off[i] : off[i + 1]] for i in range(k)],
                F=F,
                G=G,
                states=tuple(str(s) for s in data["states"]),
                inputs=tuple(str(s) for s in data["inputs"]),
                fingerprint=str(data["fingerprint"]),
                meta=json.loads(str(data["meta"])),
            )
            if "domain_A" in data:
                law.domain_A = data["domain_A"].astype(float)
                law.domain_b = data["domain_b"].astype(float)
                if law.domain_A.ndim != 2 or law.domain_b.shape != law.domain_A.shape[:1]:
                    raise SpecError("inconsistent domain arrays", file=str(path))
            if "box_lo" in data:
                law._boxes = (data["box_lo"], data["box_hi"])
            return law
        except KeyError as exc:
            raise SpecError(f"missing array {exc.args[0]!r}", file=str(path)) from None

    # ---- display -----------------------------------------------------------------------

    def summary(self) -> str:
        rows = [f"explicit law: {self.num_regions} regions, n={self.n}, m={self.m}"]
        for key in ("problem", "norm", "horizon", "seconds"):
            if key in self.meta:
                rows.append(f"  {key}: {self.meta[key]}")
        return "\n".join(rows)

    def __repr__(self) -> str:
        return f"ExplicitLaw(num_regions={self.num_regions}, n={self.n}, m={self.m})"


def fingerprint_arrays(*arrays: np.ndarray | float | str) -> str:
    """A stable hash of numbers and strings (used for law/problem fingerprints)."""
    h = hashlib.sha256()
    for a in arrays:
        arr = np.ascontiguousarray(np.asarray(a))
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()[:16]


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(type(obj).__name__)
