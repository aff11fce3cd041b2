"""The explicit MPC law: a polyhedral partition with an affine law per critical region.

``u = F_i x + G_i`` for ``x`` in region ``i = {x : A_i x <= b_i}``, all in plant
coordinates. Saved as a plain ``.npz`` (no pickle): the regions' rows are concatenated
with an offset array.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from codev_engine.display import Displayable
from codev_engine.errors import SpecError
from codev_engine.geometry.locate import PointLocator, bounding_boxes
from codev_engine.geometry.polytope import Polytope
from codev_engine.io.npz import NpzFormat, check_identifiers, load_npz, offsets, save_npz
from codev_engine.io.npz import names as _names
from codev_engine.io.npz import pair as _pair
from codev_engine.io.npz import real as _real
from codev_engine.io.npz import text as _text

__all__ = ["ExplicitLaw", "LAW_FORMAT"]

#: format tag written into every law file; bumped on incompatible changes
LAW_FORMAT = "codev-explicit-law/1"
#: what a law file's fingerprint may hold (codev writes 16 hex digits; empty: none)
_FINGERPRINT_RE = re.compile(r"[A-Za-z0-9_-]{0,64}")
_LAW_FILE = NpzFormat("law file", LAW_FORMAT, "law")


@dataclass
class ExplicitLaw(Displayable):
    """Piecewise-affine state feedback on a polyhedral partition.

    Attributes
    ----------
    A : list of (r_i, n) ndarray
        Region rows (unit norm), ``A_i x <= b_i``.
    b : list of (r_i,) ndarray
    F : (k, m, n) ndarray
    G : (k, m) ndarray
    states, inputs : tuple of str
    parameters : tuple of str
        Names of ``theta`` when it is longer than the state (the states, ``prev_<input>``,
        ``ref_<signal>``); empty when ``theta = x``.
    fingerprint : str
        Hash of the MPC problem the law was computed for (model, weights, bounds); used to
        refuse a law file that belongs to another problem.
    meta : dict
        Free-form JSON-able metadata (problem name, norm, seconds, solver stats).
    domain_A, domain_b : ndarray
        The law's domain (the MPC's feasible set, the union of the regions) as
        ``domain_A x <= domain_b`` (see ``MpSolution``).
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
    parameters: tuple[str, ...] = ()
    _locator: PointLocator | None = field(default=None, repr=False, compare=False)
    _boxes: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False, compare=False)

    # ---- shape -----------------------------------------------------------------------

    @property
    def num_regions(self) -> int:
        """The number of critical regions ``k``."""
        return len(self.A)

    @property
    def n(self) -> int:
        """The length of ``theta`` (the state dimension unless the law also takes the
        previous input or a reference): from ``F``, or the names when there is no region."""
        if self.F.ndim == 3 and self.F.shape[0]:
            return self.F.shape[2]
        return len(self.parameter_names)

    @property
    def m(self) -> int:
        """The input dimension (from ``F``, or the input names when there is no region)."""
        return self.F.shape[1] if self.F.ndim == 3 and self.F.shape[0] else len(self.inputs)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the law's parameter ``theta`` (length ``n``), in order.

        The states, then ``prev_<input>`` when the law takes the previous input, then
        ``ref_<signal>`` when it takes a reference; the regions, ``F`` and ``locate`` /
        ``evaluate`` all live in this ``theta`` space.
        """
        return self.parameters or self.states

    @property
    def regions(self) -> list[Polytope]:
        """The critical regions as ``Polytope`` objects (H-representations)."""
        return [Polytope(a, b) for a, b in zip(self.A, self.b, strict=True)]

    # ---- evaluation ------------------------------------------------------------------

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes of the regions, lower (k, n) and upper (k, n).

        Finite: where a region's LP fails, its box falls back on the domain's box (see
        ``bounding_boxes``).
        """
        if self._boxes is None:
            domain = None if self.domain_A is None else (self.domain_A, self.domain_b)
            if self.num_regions:
                self._boxes = bounding_boxes(self.A, self.b, domain=domain)
            else:  # (no region: a feasible set without interior) (0, n), not (0, 0)
                empty = np.zeros((0, self.n))
                self._boxes = (empty, empty.copy())
        return self._boxes

    @property
    def locator(self) -> PointLocator:
        """The point locator on the regions, built on first use from :attr:`boxes`."""
        if self._locator is None:
            self._locator = PointLocator(self.A, self.b, boxes=self.boxes)
        return self._locator

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index of each state.

        Parameters
        ----------
        X : (P, n) or (n,) array_like
            Parameters ``theta`` (the states, then ``u_prev`` and ``r`` when the law takes
            them; see :attr:`parameter_names`).

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

    # ---- what the reach engines ask (the interface an on-demand law shares) ----------

    def regions_meeting(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """The regions whose bounding box meets the box ``[lo, hi]`` (within 1e-9).

        Parameters
        ----------
        lo, hi : (n,) ndarray

        Returns
        -------
        (q,) ndarray of int
            Ascending; every region that meets the box is among them.
        """
        blo, bhi = self.boxes
        return np.flatnonzero(np.all(blo <= hi + 1e-9, axis=1) & np.all(bhi >= lo - 1e-9, axis=1))

    def domain_rows(
        self, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Rows of the law's domain that describe it inside the box ``[lo, hi]``: here
        :attr:`domain_A`, :attr:`domain_b` whatever the box (None when unknown).

        Parameters
        ----------
        lo, hi : (n,) ndarray

        Returns
        -------
        (A, b) or None
        """
        if self.domain_A is None:
            return None
        return self.domain_A, self.domain_b

    def _check_dim(self, X: np.ndarray) -> None:
        if X.shape[1] != self.n:
            what = "states" if not self.parameters else f"theta = ({', '.join(self.parameters)})"
            raise ValueError(f"expected {what} of dimension {self.n}, got {X.shape[1]}")

    def section(self, values: np.ndarray) -> ExplicitLaw:
        """The law in the state alone, with the other parameters fixed.

        For a law whose ``theta = (x, u_prev, r)`` is longer than the state: the rows
        ``A_x x <= b - A_e e`` and the feedback ``u = F_x x + (G + F_e e)`` at ``e =
        values``. A law with ``theta = x`` is returned as it is.

        Parameters
        ----------
        values : (n - len(states),) array_like
            The fixed values of the parameters after the states, in the order of
            :attr:`parameter_names`.

        Returns
        -------
        ExplicitLaw
            In the states; ``meta["section"]`` names the fixed values. Regions the section
            misses are kept (empty sets: ``locate`` never returns them).
        """
        nx = len(self.states)
        if not self.parameters or nx == self.n:
            return self
        e = np.asarray(values, dtype=float).reshape(self.n - nx)
        A = [a[:, :nx] for a in self.A]
        b = [bb - a[:, nx:] @ e for a, bb in zip(self.A, self.b, strict=True)]
        F = self.F[:, :, :nx]
        G = self.G + np.einsum("kij,j->ki", self.F[:, :, nx:], e)
        meta = dict(self.meta)
        meta["section"] = {
            name: float(v) for name, v in zip(self.parameters[nx:], e, strict=True)
        }
        dA = db = None
        if self.domain_A is not None:
            dA = self.domain_A[:, :nx]
            db = self.domain_b - self.domain_A[:, nx:] @ e
        return ExplicitLaw(A=A, b=b, F=F, G=G, states=self.states, inputs=self.inputs,
                           fingerprint=self.fingerprint, meta=meta, domain_A=dA, domain_b=db)

    # ---- persistence -----------------------------------------------------------------

    def save(self, path: str | os.PathLike) -> Path:
        """Write the law to ``path`` (``.npz``, format ``LAW_FORMAT``) atomically.

        The bounding boxes are saved too once computed, so that a loaded law need not
        solve their LPs again.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
            The path written.

        Raises
        ------
        SpecError
            A name that is not an identifier (``load`` would refuse the file).
        """
        for key in ("states", "inputs", "parameters"):
            check_identifiers(getattr(self, key), key)
        path = Path(path)
        offsets = np.cumsum([0] + [a.shape[0] for a in self.A])
        n = self.n
        arrays = {
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
        if self.parameters:
            arrays["parameters"] = np.array(self.parameters, dtype=str)
        if self._boxes is not None:
            arrays["box_lo"], arrays["box_hi"] = self._boxes
        if self.domain_A is not None:
            arrays["domain_A"], arrays["domain_b"] = self.domain_A, self.domain_b
        return save_npz(path, _LAW_FILE, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> ExplicitLaw:
        """Read a law written by :meth:`save`.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        ExplicitLaw

        Raises
        ------
        SpecError
            The file is missing or malformed (naming the file and the array).
        """
        return load_npz(path, _LAW_FILE, cls._from_arrays)

    @classmethod
    def _from_arrays(cls, data: dict[str, np.ndarray]) -> ExplicitLaw:
        """Validate the arrays of a law file and build the law (``SpecError`` names the array).

        Every array is checked here, in one place: presence, dtype kind (numbers are real
        floats or integers -- never complex, bool, text or objects; the offsets are
        integers; the names are text), shape, finiteness, and the consistency of the
        shapes with each other (the format tag is checked by ``load_npz``).
        """
        F = _real(data, "F", ndim=3)
        k, m, n = F.shape
        G = _real(data, "G", shape=(k, m))
        A = _real(data, "A", ndim=2)
        if k and A.shape[1] != n:
            raise SpecError(f"has {A.shape[1]} columns, F has {n}", field="A")
        b = _real(data, "b", shape=(A.shape[0],))
        off = offsets(data, "offsets", k, A.shape[0])
        # identifiers only, as the spec's: they reach exported code, figures, recordings
        parameters = (
            _names(data, "parameters", n if k else None, identifiers=True)
            if "parameters" in data
            else ()
        )
        states = _names(data, "states", n if k and not parameters else None, identifiers=True)
        inputs = _names(data, "inputs", m if k else None, identifiers=True)
        cols = n if k else None  # the columns of domain_A and the boxes (any: no regions)
        fingerprint = _text(data, "fingerprint")
        if not _FINGERPRINT_RE.fullmatch(fingerprint):
            shown = ascii(fingerprint[:40]) + ("..." if len(fingerprint) > 40 else "")
            raise SpecError(
                f"fingerprint {shown} is not a hash (up to 64 ASCII letters, digits, '_' or "
                "'-'): refused",
                field="fingerprint",
            )
        meta_text = _text(data, "meta")
        try:
            meta = json.loads(meta_text)
        except (ValueError, RecursionError) as exc:
            reason = getattr(exc, "msg", type(exc).__name__)
            raise SpecError(f"not valid JSON ({reason})", field="meta") from None
        if not isinstance(meta, dict):
            raise SpecError("must be a JSON object", field="meta")
        law = cls(
            A=[A[off[i] : off[i + 1]] for i in range(k)],
            b=[b[off[i] : off[i + 1]] for i in range(k)],
            F=F,
            G=G,
            states=states,
            inputs=inputs,
            fingerprint=fingerprint,
            meta=meta,
            parameters=parameters,
        )
        _pair(data, "domain_A", "domain_b")
        if "domain_A" in data:
            law.domain_A = _real(data, "domain_A", ndim=2)
            if cols is not None and law.domain_A.shape[1] != cols:
                raise SpecError(
                    f"must have {cols} columns, got shape {law.domain_A.shape}", field="domain_A"
                )
            law.domain_b = _real(data, "domain_b", shape=law.domain_A.shape[:1])
        _pair(data, "box_lo", "box_hi")
        if "box_lo" in data:
            lo = _real(data, "box_lo", ndim=2)
            if lo.shape[0] != k or (cols is not None and lo.shape[1] != cols):
                want = f"({k}, {cols})" if cols is not None else f"({k}, d)"
                raise SpecError(f"must have shape {want}, got {lo.shape}", field="box_lo")
            hi = _real(data, "box_hi", shape=lo.shape)
            if np.any(lo > hi):
                raise SpecError("box_lo exceeds box_hi", field="box_hi")
            law._boxes = (lo, hi)
        return law

    # ---- display -----------------------------------------------------------------------

    def summary(self) -> str:
        """A few lines of text: the regions and dimensions, and the problem's metadata."""
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
