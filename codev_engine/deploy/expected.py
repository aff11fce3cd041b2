"""The rows an exported search evaluates on given parameter vectors (its expected cost).

The certified worst case (``Tree.cost``) bounds every call; near an operating point the
calls are far from it: the region of operation of a verified tube is mostly one or two
regions, and a sequential search that checks them first beats a tree whose leaves there
check many members (``benchmarks/README.md``, the quadrotor's region of operation).
:func:`expected_rows` counts, for each vector, the hyperplane and row evaluations the
generated code makes (the rule of ``python_code.locate``: a test per node, the fast path's
rows, or each member's rows up to the first one past the tolerance), so that ``plan``'s
``auto`` can choose by the mean on the states the loop visits. It claims nothing: the
header keeps the certified worst case.
"""

from __future__ import annotations

import numpy as np

from codev_engine.deploy.bst import LOCATE_TOL, Tree

__all__ = ["expected_rows"]


def _members_rows(A: np.ndarray, b: np.ndarray, off: np.ndarray, members, x) -> int:
    """Rows the members' loop evaluates: each member up to its first row past the
    tolerance, and all of the first member that holds ``x`` (the loop returns there)."""
    n = 0
    for j in members:
        v = A[off[j]:off[j + 1]] @ x - b[off[j]:off[j + 1]]
        over = np.flatnonzero(v > LOCATE_TOL)
        if over.size:
            n += int(over[0]) + 1
            continue
        n += v.size
        if v.size == 0 or v.max() <= 0.0:
            break
    return n


def expected_rows(tree: Tree, A: np.ndarray, b: np.ndarray, off: np.ndarray,
                  X: np.ndarray) -> np.ndarray:
    """Hyperplane and row evaluations of one call of the search at each vector.

    Parameters
    ----------
    tree : Tree
        The tree or the sequential search (``bst.sequential_tree``).
    A : (N, d) ndarray
    b : (N,) ndarray
    off : (R + 1,) ndarray of int
        The regions' rows (``plan.Deployable``).
    X : (P, d) ndarray
        Parameter vectors inside the box of the search.

    Returns
    -------
    (P,) ndarray of int
    """
    X = np.atleast_2d(np.asarray(X, float))
    out = np.zeros(X.shape[0], dtype=np.int64)
    for p, x in enumerate(X):
        n, k = 0, 0 if tree.num_nodes else -1
        while k >= 0:
            n += 1
            s = float(tree.node_a[k] @ x - tree.node_b[k])
            k = int(tree.node_next[k][1 if s > 0.0 else 0])
        leaf = -1 - k
        if tree.leaf_general[leaf]:
            n += _members_rows(A, b, off, tree.leaf_members[leaf], x)
        elif tree.group(leaf).size:
            n += _members_rows(A, b, off, tree.group(leaf), x)
        elif tree.leaf_owner[leaf] >= 0:
            n += int(tree.leaf_fast[leaf].size)
        out[p] = n
    return out
