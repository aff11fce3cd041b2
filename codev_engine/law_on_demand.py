"""An explicit MPC law whose critical regions are computed where they are asked for.

:class:`OnDemandLaw` has the interface the reach engines read from an ``ExplicitLaw``
(``A``, ``b``, ``F``, ``G``, ``boxes``, ``num_regions``, ``locate``, ``evaluate``, and the
two questions :meth:`regions_meeting` and :meth:`domain_rows`), but it holds only the
regions computed so far: asked for the regions meeting a box, it computes the missing ones
by the restricted walk of ``mp.on_demand`` (the full search's graph and kernel, so each
region has the full law's rows and law). Regions are appended, never reordered: an index
once returned stays valid while the law grows. In plant coordinates, as ``ExplicitLaw``
(``law_from_solution``'s mapping). Norm 2 (an mp-QP, ``mp.on_demand``) and norms 1 and inf
(an mp-LP, ``mp.on_demand_lp``); see issue 39.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from codev_engine.errors import RegionLimitError, SolverError, SpecError
from codev_engine.formulation import parameter_names
from codev_engine.geometry.locate import PointLocator, bounding_boxes
from codev_engine.geometry.polytope import box_halfspaces
from codev_engine.io.npz import NpzFormat, array, load_npz, save_npz, text
from codev_engine.mp.balance import balanced, program_scaling, rows_back
from codev_engine.mp.on_demand import OnDemandRegions
from codev_engine.mp.on_demand_lp import OnDemandBases
from codev_engine.mp.reduce import parameter_box
from codev_engine.mp.solution import RegionArrays, TooManyRegionsError
from codev_engine.mp.solve import SolveOptions
from codev_engine.mpc import build_program
from codev_engine.plant import LinearModel, discretize
from codev_engine.spec.problem import Problem
from codev_engine.synthesis import problem_fingerprint, region_limit, snap_saturated
from codev_engine.version import __version__

__all__ = ["OnDemandLaw", "law_for"]

#: the region cache's file format (``OnDemandLaw.save``)
REGIONS_FORMAT = "codev-regions/1"
_REGIONS_FILE = NpzFormat("region cache", REGIONS_FORMAT, "region cache")
#: the integer arrays of a region cache (every other one is real)
_INT_ARRAYS = ("acts", "acts_len", "kind", "region", "moves", "moves_len", "lower_len",
               "reg_len", "numpy_acts", "numpy_len", "flags")
_REAL_ARRAYS = ("lower_A", "lower_b", "reg_A", "reg_b", "reg_K", "reg_k", "box_lo", "box_hi")

#: tolerance of the bounding-box test of the full law's reach engines (``regions_meeting``)
_BOX_TOL = 1e-9


class OnDemandLaw:
    """A piecewise-affine MPC law on the critical regions computed so far.

    Parameters
    ----------
    problem : Problem
        A design (norm 2: a strictly convex mp-QP; norms 1 and inf: an mp-LP).
    model : LinearModel, optional
        A discrete model to use instead of discretising ``problem``.
    options : SolveOptions, optional
        The multi-parametric solver's tolerances.

    Raises
    ------
    SpecError
        For an mp-QP with a singular Hessian, or an mp-LP whose cost depends on the
        parameter (field ``synthesis.regions``): not computed on demand.

    Attributes
    ----------
    A, b : list of ndarray
        The rows of the regions found so far (``A_i theta <= b_i``, unit rows).
    F : (k, m, d) ndarray
    G : (k, m) ndarray
        The affine law of each region found so far.
    states, inputs, parameters : tuple of str
        As for ``ExplicitLaw``.
    fingerprint : str
        The problem's fingerprint (``synthesis.problem_fingerprint``).
    meta : dict
        ``on_demand``, ``norm``, ``horizon``, ``problem``; ``regions`` the regions computed.
    max_regions : int
        The region limit the full synthesis honours (``options.max_regions`` or what fits
        in the ``region_bytes`` limit, whichever is fewer): a walk that needs more ends in
        a ``RegionLimitError`` (the reach engines' ``unknown``, reason ``limit``).
    complete : bool
        The whole partition is known (a small law, after the replay of the full search's
        start): the law then answers as the full law does, vectorised and without LPs.
    """

    #: the reach engines and the front ends tell this law from a full one by it
    on_demand = True
    #: the domain is not known as a whole: :meth:`domain_rows` gives its rows near a set
    domain_A = None
    domain_b = None

    def __init__(
        self,
        problem: Problem,
        *,
        model: LinearModel | None = None,
        options: SolveOptions | None = None,
    ):
        model = model if model is not None else discretize(problem)
        mp = build_program(problem.mpc, model)
        try:
            # norms 1 and inf: the basis graph of the mp-LP (mp.on_demand_lp)
            walk = OnDemandRegions if mp.spec.norm == "2" else OnDemandBases
            # the walk runs in balanced units when the parameter's axes are far apart, as
            # the full search does (mp/balance.py): theta - theta_op = D theta_s
            self._D = program_scaling(mp.program)
            program = mp.program if self._D is None else balanced(mp.program, self._D)
            self._solver = walk(program, options)
        except SolverError as exc:
            raise SpecError(str(exc), field="synthesis.regions") from None
        self._mp = mp
        self._op = np.asarray(mp.theta_op, float)
        self.states = tuple(problem.plant.states)
        self.inputs = tuple(problem.plant.inputs)
        self.parameters: tuple[str, ...] = ()
        if mp.d > mp.n:
            self.parameters = parameter_names(problem.mpc, self.states, self.inputs)
        self.fingerprint = problem_fingerprint(mp)
        opts = options or SolveOptions()
        # the full synthesis' limit (synthesis.synthesize): the solver's, or the regions
        # that fit in limits' region_bytes, whichever is fewer
        most, per = region_limit(mp.program)
        self.max_regions = min(opts.max_regions, most)
        self._limit_fix = (
            f"raise CODEV_LIMITS=region_bytes (about {per / 1024:.0f} KB a region)"
            if most < opts.max_regions else "raise SolveOptions.max_regions")
        self._solver.max_regions = self.max_regions
        # what the cached regions depend on besides the program: the kernel's tolerance and
        # seed (the replay's start), and the engine (its rounding)
        self._cache_key = (f"{self.fingerprint} region_tol={opts.region_tol!r} "
                           f"seed={opts.seed!r} engine={__version__}")
        if self._D is not None:
            # (regions cached by a walk in other units, before issue 38, are not these)
            self._cache_key += f" balance={self._D.tolist()!r}"
        #: candidates the walk had evaluated when last saved or loaded (:attr:`grown`)
        self._saved_candidates = 0
        self.meta: dict = {"on_demand": True, "norm": mp.spec.norm, "horizon": mp.N,
                           "problem": problem.name, "regions": 0}
        d, m = mp.d, mp.m
        self.A: list[np.ndarray] = []
        self.b: list[np.ndarray] = []
        self.F = np.zeros((0, m, d))
        self.G = np.zeros((0, m))
        self._boxes: tuple[np.ndarray, np.ndarray] | None = (np.zeros((0, d)), np.zeros((0, d)))
        self._last: tuple[bytes, np.ndarray] | None = None  # the last box asked, its answer
        self._stacked: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        #: once the whole partition is known (:attr:`complete`): the regions in the full
        #: law's order (by active set / basis), their boxes, locator and domain
        self._whole: dict | None = None

    # ---- shape -------------------------------------------------------------------------

    @property
    def num_regions(self) -> int:
        """The number of regions computed so far."""
        return len(self.A)

    @property
    def n(self) -> int:
        """The length of ``theta``."""
        return self._mp.d

    @property
    def m(self) -> int:
        """The input dimension."""
        return self._mp.m

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of ``theta`` (the states, then ``prev_<input>``, ``ref_<signal>``)."""
        return self.parameters or self.states

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding boxes of the regions computed so far, lower and upper (k, d)."""
        if self._boxes is None:
            lo, hi = self._solver.boxes
            if self._D is not None:
                lo, hi = lo * self._D, hi * self._D
            self._boxes = (lo + self._op, hi + self._op)
        return self._boxes

    @property
    def stats(self) -> dict:
        """The walk's counters (``mp.on_demand.OnDemandRegions.stats``)."""
        return dict(self._solver.stats)

    # ---- the questions of the reach engines ----------------------------------------------

    def regions_meeting(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Every region that meets the box ``[lo, hi]`` (computed if need be).

        Parameters
        ----------
        lo, hi : (d,) ndarray
            The box, in ``theta``.

        Returns
        -------
        (q,) ndarray of int
            Region indices, ascending by active set (the full law's order); a superset of
            the regions the full law's bounding-box test would offer that meet the box
            (once the law is :attr:`complete`, exactly the full law's answer).
        """
        whole = self._whole_law()
        if whole is not None:
            # the full law's answer (ExplicitLaw.regions_meeting), in its order
            blo, bhi = whole["boxes"]
            lo, hi = np.asarray(lo, float), np.asarray(hi, float)
            hit = np.all(blo <= hi + 1e-9, axis=1) & np.all(bhi >= lo - 1e-9, axis=1)
            return whole["order"][hit]
        lo = np.asarray(lo, float) - _BOX_TOL
        hi = np.asarray(hi, float) + _BOX_TOL
        key = np.concatenate([lo, hi]).tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        A, b = box_halfspaces(*self._walk_box(lo, hi))
        try:
            found = np.array(self._solver.meeting(A, b), dtype=int)
        except TooManyRegionsError:
            self._sync()
            raise RegionLimitError(
                f"the regions computed on demand reached the region limit of the full "
                f"synthesis ({self.max_regions:,}): {self.num_regions:,} critical regions "
                f"computed and more are needed; {self._limit_fix}, shrink "
                "verify.initial_set or shorten verify.time_horizon") from None
        self._sync()
        self._last = (key, found)
        return found

    @property
    def complete(self) -> bool:
        """The whole partition is known (then the law answers as the full law does).

        Asking replays the full search's start if no set was asked about yet (the first
        walk would)."""
        return self._whole_law() is not None

    def _whole_law(self) -> dict | None:
        """The full law's data once the walk knows the whole partition, else None.

        A walk that has found every region (a small law: the replay of the full search's
        start went to its end) needs no more LPs: the regions meeting a box are those
        whose bounding box meets it, a point is located among all regions, and the domain
        is the full law's (``solve._domain_from_regions``) -- the full law's answers, in
        its order, so the verification is the full law's."""
        if self._whole is not None:
            return self._whole
        solver = self._solver
        try:
            solver.start()
        except TooManyRegionsError:
            return None  # (a limit below the replay: the walk's error comes with a set)
        if not solver.complete:
            return None
        from codev_engine.mp.solve import _domain_from_regions

        self._sync()
        regs = solver.regions
        order = np.array(sorted(range(len(regs)), key=lambda i: regs[i].active), dtype=int)
        red, op = solver._red, self._op
        packed = RegionArrays.from_regions([regs[i] for i in order])
        dA, db = _domain_from_regions(red, packed, solver.scale, parameter_box(red).box)
        dA, db = self._rows_out(dA, db)
        domain = (dA, db + dA @ op)
        A = [self.A[i] for i in order]
        b = [self.b[i] for i in order]
        boxes = bounding_boxes(A, b, domain=domain)
        self._whole = {"order": order, "boxes": boxes, "domain": domain,
                       "locator": PointLocator(A, b, boxes=boxes)}
        lo, hi = boxes
        inv = np.empty_like(order)
        inv[order] = np.arange(order.size)
        self._boxes = (lo[inv], hi[inv])
        return self._whole

    def domain_rows(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the law's domain (the MPC's feasible set) that describe it inside the
        box ``[lo, hi]``: every row holds on the whole domain, and a point of the box is in
        the domain when it satisfies them all.

        The rows of the regions meeting the box that hold on the whole domain (its facets
        that cut the box are among them), and the parameter set's; when no region meets
        the box, one row valid on the domain that the whole box violates (when one is
        found; else none, and the engine finds no region for the set).

        Parameters
        ----------
        lo, hi : (d,) ndarray

        Returns
        -------
        A : (q, d) ndarray
        b : (q,) ndarray
        """
        whole = self._whole_law()
        if whole is not None:
            return whole["domain"]
        idx = self.regions_meeting(lo, hi)
        op = self._op
        if idx.size:
            A, b = self._rows_out(*self._solver.boundary_rows(list(idx)))
            return A, b + A @ op
        Ab, bb = box_halfspaces(*self._walk_box(lo, hi))
        sep = self._solver.separating_row(Ab, bb)
        if sep is None:
            return np.zeros((0, self.n)), np.zeros(0)
        A, b = self._rows_out(sep[0][None, :], np.array([sep[1]]))
        return A, b + A @ op

    # ---- evaluation ---------------------------------------------------------------------

    def locate(self, X: np.ndarray) -> np.ndarray:
        """Region index of each ``theta`` (-1 outside the domain), computing the regions
        around a point when none of those known holds it well inside.

        A point inside a known region by more than a small margin is in no other
        (regions are interior-disjoint); elsewhere the regions meeting a small box around
        it are computed and ``PointLocator``'s rule (the full law's) picks among them in
        the full law's order.

        Parameters
        ----------
        X : (P, d) or (d,) array_like

        Returns
        -------
        (P,) ndarray of int
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != self.n:
            raise ValueError(f"expected theta of dimension {self.n}, got {X.shape[1]}")
        whole = self._whole_law()
        if whole is not None:  # (the full law's locator, in its order)
            j = whole["locator"].locate(X)
            return np.where(j >= 0, whole["order"][np.maximum(j, 0)], -1)
        out = np.full(X.shape[0], -1, dtype=int)
        margin = 1e-8 * self._solver.scale
        pad = 1e-7 * self._solver.scale
        if self._D is not None:
            pad = pad * self._D  # (a box in proportion to each axis)
        for p, x in enumerate(X):
            if not np.all(np.isfinite(x)):
                continue
            inside = self._well_inside(x, margin)
            if inside >= 0:
                out[p] = inside
                continue
            cand = self.regions_meeting(x - pad, x + pad)
            if cand.size:
                loc = PointLocator([self.A[i] for i in cand], [self.b[i] for i in cand],
                                   grid=False)
                j = int(loc.locate(x[None, :])[0])
                out[p] = -1 if j < 0 else int(cand[j])
        return out

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """The control ``u = F_i theta + G_i`` (NaN rows outside the domain).

        Parameters
        ----------
        X : (P, d) or (d,) array_like

        Returns
        -------
        (P, m) ndarray
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        idx = self.locate(X)
        U = np.full((X.shape[0], self.m), np.nan)
        ok = idx >= 0
        U[ok] = np.einsum("pij,pj->pi", self.F[idx[ok]], X[ok]) + self.G[idx[ok]]
        return U

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.evaluate(X)

    def section(self, values: np.ndarray):
        """The regions computed so far in the state alone, the other parameters fixed at
        ``values`` (``ExplicitLaw.section`` of them): what a picture of a law over ``theta
        = (x, u_prev, r)`` draws. Marked ``on_demand`` (the pictures say "regions
        reached"); the section of a law with ``theta = x`` is the law itself.

        Parameters
        ----------
        values : (n - len(states),) array_like

        Returns
        -------
        ExplicitLaw or OnDemandLaw
        """
        from codev_engine.law import ExplicitLaw

        if not self.parameters or len(self.states) == self.n:
            return self
        now = ExplicitLaw(A=list(self.A), b=list(self.b), F=self.F.copy(), G=self.G.copy(),
                          states=self.states, inputs=self.inputs,
                          parameters=self.parameters, fingerprint=self.fingerprint,
                          meta=dict(self.meta))
        out = now.section(values)
        out.on_demand = True  # (an instance's flag: it draws the regions reached)
        return out

    def summary(self) -> str:
        """One line: the regions computed so far and the dimensions."""
        return (f"explicit law on demand: {self.num_regions} regions computed, n={self.n}, "
                f"m={self.m}")

    def __repr__(self) -> str:
        return f"OnDemandLaw(num_regions={self.num_regions}, n={self.n}, m={self.m})"

    # ---- persistence ---------------------------------------------------------------------

    @property
    def grown(self) -> bool:
        """Regions were computed since the law was last saved or loaded."""
        return self._solver.stats["candidates"] != self._saved_candidates

    def save(self, path: str | os.PathLike) -> Path:
        """Write the regions computed so far and the walk's cache to ``path`` (``.npz``,
        format ``REGIONS_FORMAT``), atomically.

        The file holds the MPC's fingerprint (with the solver's tolerance and seed and the
        engine's version) and a SHA-256 of its arrays: :meth:`load` refuses a cache made
        for another MPC or damaged.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        Path
        """
        arrays = self._solver.state()
        arrays["fingerprint"] = np.array(self._cache_key)
        arrays["checksum"] = np.array(_checksum(arrays))
        out = save_npz(path, _REGIONS_FILE, arrays)
        self._saved_candidates = self._solver.stats["candidates"]
        return out

    @classmethod
    def load(cls, path: str | os.PathLike, problem: Problem, *,
             model: LinearModel | None = None, options: SolveOptions | None = None
             ) -> OnDemandLaw:
        """The law of ``problem`` with the regions of a cache written by :meth:`save`.

        Parameters
        ----------
        path : path-like
        problem : Problem
        model, options
            As for the constructor (the cache must have been made with the same).

        Returns
        -------
        OnDemandLaw

        Raises
        ------
        SpecError
            Naming the file and the array: not a region cache, made for another MPC (or
            another engine, tolerance or seed), or damaged (its checksum or its arrays do
            not hold). A cache is never half trusted: the caller recomputes.
        """
        law = cls(problem, model=model, options=options)
        load_npz(path, _REGIONS_FILE, law._adopt)
        return law

    def _adopt(self, data: dict[str, np.ndarray]) -> None:
        """Check a region cache's arrays and take its regions (``SpecError`` names one)."""
        key = text(data, "fingerprint")
        if key != self._cache_key:
            raise SpecError(f"made for another MPC or engine ({key[:60]!r}; this one is "
                            f"{self._cache_key[:60]!r})", field="fingerprint")
        arrays = {}
        for name in _INT_ARRAYS:
            a = array(data, name)
            if a.dtype.kind not in "iu" or a.ndim != 1:
                raise SpecError(f"must be a vector of integers, got {a.dtype} {a.shape}",
                                field=name)
            arrays[name] = a.astype(np.int64)
        for name in _REAL_ARRAYS:
            a = array(data, name)
            if a.dtype.kind != "f":
                raise SpecError(f"must hold real numbers, got dtype {a.dtype}", field=name)
            arrays[name] = a
        if text(data, "checksum") != _checksum(arrays | {"fingerprint": data["fingerprint"]}):
            raise SpecError("its arrays do not match their SHA-256 (damaged or edited)",
                            field="checksum")
        self._solver.restore(arrays)
        self._sync()
        self._last = None
        self._whole = None
        self._saved_candidates = self._solver.stats["candidates"]

    # ---- growth --------------------------------------------------------------------------

    def _sync(self) -> None:
        """Append the regions the walk found since the last call, in plant coordinates."""
        regs = self._solver.regions
        k = len(self.A)
        if len(regs) == k:
            return
        mp, op = self._mp, self._op
        sl = mp.u0_slice
        new = regs[k:]
        rows = [self._rows_out(r.A, r.b) for r in new]
        self.A += [A for A, _ in rows]
        self.b += [b + A @ op for A, b in rows]
        K = [r.K if self._D is None else r.K / self._D for r in new]
        F = np.array([Kr[sl] for Kr in K]).reshape(len(new), mp.m, mp.d)
        G = np.array([mp.u_op + r.k[sl] - Kr[sl] @ op
                      for r, Kr in zip(new, K, strict=True)]).reshape(len(new), mp.m)
        fm = mp.formulation
        if fm is not None:  # (a saturated move is its bound, as in a full law's synthesis)
            F, G, _ = snap_saturated(F, G, mp.spec, fm.theta_lo + op, fm.theta_hi + op)
        self.F = np.concatenate([self.F, F])
        self.G = np.concatenate([self.G, G])
        self._boxes = None
        self._stacked = None
        self.meta["regions"] = len(self.A)

    def _walk_box(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The box ``[lo, hi]`` (theta) in the walk's parameter: ``(theta - op) / D`` (exact:
        ``D`` holds powers of two)."""
        lo = np.asarray(lo, float) - self._op
        hi = np.asarray(hi, float) - self._op
        if self._D is None:
            return lo, hi
        return lo / self._D, hi / self._D

    def _rows_out(self, A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows in the walk's parameter as rows in ``theta - op`` (unit rows)."""
        return (A, b) if self._D is None else rows_back(A, b, self._D)

    def _well_inside(self, x: np.ndarray, margin: float) -> int:
        """A known region that holds ``x`` with every row by more than ``margin``, or -1."""
        if not self.A:
            return -1
        if self._stacked is None:
            sizes = np.array([a.shape[0] for a in self.A])
            off = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            self._stacked = (np.vstack(self.A), np.concatenate(self.b), off)
        A, b, off = self._stacked
        worst = np.maximum.reduceat(A @ x - b, off)
        best = int(np.argmin(worst))
        return best if worst[best] < -margin else -1


def _checksum(arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 over the arrays of a region cache, by name: dtype, shape and bytes."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        if name in ("checksum", "format"):
            continue
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def law_for(problem: Problem, regions: str, **kwargs):
    """The law a verification of ``problem`` runs on: the full law (``regions = "all"``,
    :func:`codev_engine.synthesis.synthesize`) or an :class:`OnDemandLaw` (``"reached"``).

    Parameters
    ----------
    problem : Problem
    regions : {"all", "reached"}
    **kwargs
        Passed on to ``synthesize`` (``progress``, ``executor``, ...) for ``"all"``; only
        ``model`` and ``options`` for ``"reached"``.

    Returns
    -------
    ExplicitLaw or OnDemandLaw
    """
    if regions == "reached":
        keep = {k: v for k, v in kwargs.items() if k in ("model", "options")}
        return OnDemandLaw(problem, **keep)
    from codev_engine.synthesis import synthesize

    return synthesize(problem, **kwargs)
