"""The plan of an export: what is evaluated (``Deployable``), the search and its cost.

Both searches, the tree (``bst.py``) and the sequential one, return the region
``ExplicitLaw.locate`` returns at every point (see ``bst.py`` for the rule and why).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from codev_engine.deploy.bst import Tree, TreeTooLargeError, build_tree, sequential_tree
from codev_engine.deploy.expected import expected_rows
from codev_engine.errors import SpecError

__all__ = [
    "Deployable", "Export", "ceil_log2", "deployable", "law_labels", "plan", "rom_bytes"
]

METHODS = ("bst", "sequential", "auto")
#: above this many regions a tree leaf checks up to ``BUCKET`` regions (``plan``)
BUCKET_FROM = 2000
BUCKET = 8
#: above this many regions the tree of a large partition (``plan``): leaves of up to
#: ``LARGE["leaf_size"]`` regions, and a node of at most ``LARGE["bucket_max"]`` whose
#: best split keeps over ``LARGE["stop_ratio"]`` of them in one child is a leaf too; a
#: cheaper choice of hyperplane (``budget`` vertex evaluations, ``tries`` LP
#: confirmations a node). ``bst.build_tree`` explains each; measured on
#: ``pop_mpqp_083`` (13,266 regions, d = 5) in ``docs/deploy.md``.
LARGE_FROM = 8000
LARGE = {"leaf_size": 32, "stop_ratio": 0.7, "bucket_max": 128, "budget": 5e5, "tries": 1}


@dataclass(frozen=True)
class Deployable:
    """What the exported code evaluates: regions in ``theta``-space and an affine map each.

    Attributes
    ----------
    A : (N, d) ndarray
        The regions' rows as stored (region after region).
    b : (N,) ndarray
    off : (R + 1,) ndarray of int
    F : (R, m, d) ndarray
    G : (R, m) ndarray
    boxes : (lo, hi), each (R, d) ndarray
        The regions' bounding boxes.
    parameter_names, output_names : tuple of str
    fingerprint : str
    kind : str
        ``"law"`` (u = F theta + G) or ``"mp-solution"`` (z = F theta + G).
    """

    A: np.ndarray
    b: np.ndarray
    off: np.ndarray
    F: np.ndarray
    G: np.ndarray
    boxes: tuple[np.ndarray, np.ndarray]
    parameter_names: tuple[str, ...]
    output_names: tuple[str, ...]
    fingerprint: str
    kind: str

    @property
    def num_regions(self) -> int:
        """The number of regions ``R``."""
        return self.off.size - 1


def deployable(obj) -> Deployable:
    """The regions and maps of an ``ExplicitLaw`` or an ``MpSolution``.

    Parameters
    ----------
    obj : ExplicitLaw or MpSolution

    Returns
    -------
    Deployable

    Raises
    ------
    SpecError
        Neither a law nor a solution, or one without regions.
    """
    from codev_engine.law import ExplicitLaw

    if isinstance(obj, ExplicitLaw):
        if obj.num_regions == 0:
            raise SpecError("the law has no region to export")
        d = obj.F.shape[2]
        off = np.cumsum([0] + [a.shape[0] for a in obj.A]).astype(np.int64)
        names = tuple(obj.parameter_names)
        if len(names) != d:
            names = tuple(f"theta{i}" for i in range(d))
        outs = tuple(obj.inputs) if len(obj.inputs) == obj.m else tuple(
            f"u{i}" for i in range(obj.m)
        )
        return Deployable(
            A=np.vstack(obj.A).astype(float), b=np.concatenate(obj.b).astype(float), off=off,
            F=np.asarray(obj.F, dtype=float), G=np.asarray(obj.G, dtype=float),
            boxes=obj.boxes, parameter_names=names, output_names=outs,
            fingerprint=obj.fingerprint, kind="law",
        )
    from codev_engine.mp.solution import MpSolution

    if isinstance(obj, MpSolution):
        return _from_solution(obj)
    raise SpecError(f"cannot export a {type(obj).__name__} (an ExplicitLaw or MpSolution)")


def _from_solution(sol) -> Deployable:
    """An ``MpSolution``'s regions (the shared rows made explicit) and primal maps."""
    reg = sol.regions
    R = sol.num_regions
    if R == 0:
        raise SpecError("the solution has no region to export")
    rows = [reg.rows(i) for i in range(R)]
    As, bs = [r[0] for r in rows], [r[1] for r in rows]
    off = np.cumsum([0] + [a.shape[0] for a in As]).astype(np.int64)
    F = np.asarray(reg.K, dtype=float)
    G = np.asarray(reg.k, dtype=float)
    d = F.shape[2]
    from codev_engine.geometry.locate import bounding_boxes
    from codev_engine.law import fingerprint_arrays

    domain = None if sol.domain_A is None else (sol.domain_A, sol.domain_b)
    boxes = bounding_boxes(As, bs, domain=domain)
    return Deployable(
        A=np.vstack(As), b=np.concatenate(bs), off=off, F=F, G=G, boxes=boxes,
        parameter_names=tuple(f"theta{i}" for i in range(d)),
        output_names=tuple(f"z{i}" for i in range(F.shape[1])),
        fingerprint=fingerprint_arrays(np.vstack(As), np.concatenate(bs), F, G),
        kind="mp-solution",
    )


@dataclass(frozen=True)
class Export:
    """An export's plan: the tree (or the sequential search) and its certified cost.

    Attributes
    ----------
    dep : Deployable
    tree : Tree
    method : str
        ``"bst"`` or ``"sequential"``.
    depth : int
        Most hyperplane tests on a path of the tree.
    tests : int
        Most hyperplane (row) evaluations of one call, by exhaustive traversal of the tree.
    macs : int
        Most multiply-adds of one call: ``d`` per hyperplane evaluation plus ``m d`` for the
        law.
    expected : float or None
        The mean hyperplane and row evaluations on the states ``plan`` was given
        (``deploy.expected``), None without them.
    """

    dep: Deployable
    tree: Tree
    method: str
    depth: int
    tests: int
    macs: int
    expected: float | None = None


def law_labels(dep: Deployable, decimals: int = 9) -> np.ndarray:
    """A label per region, equal where the affine maps are equal: ``F`` and ``G`` equal
    to ``decimals`` decimals relative to the law's largest entry.

    Parameters
    ----------
    dep : Deployable
    decimals : int

    Returns
    -------
    (R,) ndarray of int
        The lowest region index of each region's group.
    """
    from codev_engine.geometry.polytope import row_keys

    R = dep.num_regions
    M = np.column_stack([dep.F.reshape(R, -1), dep.G.reshape(R, -1)])
    M = M / max(1.0, float(np.abs(M).max(initial=0.0)))
    keys = row_keys(M, decimals)
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return first[inverse.ravel()].astype(np.int64)


def plan(
    obj, method: str = "auto", merge_equal_laws: bool = False, leaf_size: int | None = None,
    states: np.ndarray | None = None,
) -> Export:
    """Build the search of an export.

    Parameters
    ----------
    obj : ExplicitLaw, MpSolution or Deployable
    method : {"auto", "bst", "sequential"}
        ``auto``: the one of fewer worst-case multiply-adds, or with ``states`` the one of
        fewer evaluations on them at the mean (the worst case is still certified and
        stated).
    merge_equal_laws : bool
        Regions with equal affine laws (:func:`law_labels`) share a tree leaf: the tree
        stops splitting where the regions left all have one law, and that leaf runs the
        locator's rule over them (so the code still returns ``locate``'s region and
        its own law). Fewer nodes and leaves; the leaf checks more rows.
    leaf_size : int, optional
        Regions a tree leaf may check (``bst.build_tree``); default 1 up to
        ``BUCKET_FROM`` regions, ``BUCKET`` beyond (a large partition's tree stays small),
        ``LARGE["leaf_size"]`` beyond ``LARGE_FROM`` (where the tree also stops at nodes
        no split makes much smaller: ``LARGE``).
    states : (P, d) ndarray, optional
        Parameter vectors the code will mostly see; default ``meta["operation_states"]``
        of a region of operation (``deploy.operation``: its tube's sample sets' centres).

    Returns
    -------
    Export

    Raises
    ------
    SpecError
        An unknown method, or nothing to export.
    TreeTooLargeError
        ``method="bst"`` and the tree exceeds its node budget (``auto`` then takes the
        sequential search).
    """
    if method not in METHODS:
        raise SpecError(f"unknown method {method!r} (one of {', '.join(METHODS)})")
    dep = obj if isinstance(obj, Deployable) else deployable(obj)
    d, m = dep.F.shape[2], dep.F.shape[1]
    choices = []
    if method in ("bst", "auto"):
        try:
            labels = law_labels(dep) if merge_equal_laws else None
            R = dep.num_regions
            opts = dict(LARGE) if R > LARGE_FROM else {}
            if leaf_size is not None:
                opts["leaf_size"] = leaf_size
            opts.setdefault("leaf_size", 1 if R <= BUCKET_FROM else BUCKET)
            tree = build_tree(dep.A, dep.b, dep.off, dep.boxes, labels=labels, **opts)
            choices.append(("bst", tree))
        except TreeTooLargeError:
            if method == "bst":
                raise

    if method in ("sequential", "auto"):
        # the tree's box when there is one (from the enlarged regions' vertices); without
        # it the sequential search checks only that theta is finite
        lo = choices[0][1].box_lo if choices else None
        hi = choices[0][1].box_hi if choices else None
        choices.append(("sequential", sequential_tree(dep.A, dep.b, dep.off, lo, hi)))
    if states is None:
        states = (getattr(obj, "meta", None) or {}).get("operation_states")
    if states is not None:
        states = np.atleast_2d(np.asarray(states, float))
        states = states[np.all(np.isfinite(states), axis=1)] if states.shape[1] == d else None
    best, best_key = None, ()
    for name, tree in choices:
        c = tree.cost()
        mean = None
        if states is not None and states.shape[0]:
            mean = float(expected_rows(tree, dep.A, dep.b, dep.off, states).mean())
        e = Export(dep, tree, name, c["depth"], c["tests"], c["tests"] * d + m * d, mean)
        # (by the mean on the states when known, the worst case breaking ties)
        key = (e.macs,) if mean is None else (mean, e.macs)
        if best is None or key < best_key:
            best, best_key = e, key
    return best


def rom_bytes(tables: dict[str, tuple[int, int]]) -> int:
    """Total size of constant tables, ``{name: (count, element bytes)}``.

    Parameters
    ----------
    tables : dict

    Returns
    -------
    int
    """
    return int(sum(n * s for n, s in tables.values()))


def ceil_log2(k: int) -> int:
    """``ceil(log2(k))`` (0 for k <= 1).

    Parameters
    ----------
    k : int

    Returns
    -------
    int
    """
    return 0 if k <= 1 else math.ceil(math.log2(k))
