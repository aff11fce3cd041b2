"""The Python writer of an export: a module that needs numpy only (for its tables).

The generated ``evaluate(theta)`` walks the same tables as the C code, in Python floats
(doubles, no fused multiply-add), so it returns the same region and the same numbers.
"""

from __future__ import annotations

import numpy as np

from codev_engine.deploy.bst import DELTA, LOCATE_TOL
from codev_engine.deploy.c_code import leaf_tables
from codev_engine.deploy.escape import comment, py_names, py_str
from codev_engine.deploy.plan import Export

__all__ = ["python_source"]


def _lit(a: np.ndarray) -> str:
    a = np.asarray(a)
    if a.dtype.kind in "iub":
        return repr(a.astype(int).tolist())
    return repr(a.astype(float).tolist())


def python_source(ex: Export) -> str:
    """The source of the Python module of an export.

    Parameters
    ----------
    ex : Export

    Returns
    -------
    str
        The law's names and fingerprint are Python literals (``escape.py_names``,
        ``py_str``) and, in the raw docstring, escaped text (``escape.comment``): whatever
        the law file holds, the module is codev's.
    """
    dep, t = ex.dep, ex.tree
    d, m = dep.F.shape[2], dep.F.shape[1]
    delta = DELTA["double"] * (1.0 + np.abs(t.node_b))
    owner, fast_start, fast, mem_start, mem, group_start = leaf_tables(t)
    names, outputs = py_names(dep.parameter_names), py_names(dep.output_names)
    shown_names = ", ".join(comment(n) for n in dep.parameter_names)
    shown_outputs = ", ".join(comment(n) for n in dep.output_names)
    return f'''r"""The explicit {'law' if dep.kind == 'law' else 'mp solution'} of codev\
 as Python (generated; do not edit).

fingerprint: {comment(dep.fingerprint) or '(none)'}
regions: {dep.num_regions}; search: {ex.method}; worst case per call: {ex.tests} row
evaluations, {ex.macs} multiply-adds (exhaustive traversal of the tree).
theta: {shown_names} (PARAMETER_NAMES)
outputs: {shown_outputs} (OUTPUT_NAMES)

``evaluate(theta)`` returns ``(region, u)``: the region ``ExplicitLaw.locate`` returns
(lowest index holding theta, else the nearest within {LOCATE_TOL:g}, else -1) and
``u = F theta + G`` (None outside the domain).
"""

import math

import numpy as np

NTHETA = {d}
NU = {m}
PARAMETER_NAMES = {names}
OUTPUT_NAMES = {outputs}
FINGERPRINT = {py_str(dep.fingerprint)}
TOL = {LOCATE_TOL!r}

BOX_LO = {None if t.box_lo is None else _lit(t.box_lo)}
BOX_HI = {None if t.box_hi is None else _lit(t.box_hi)}
NODE_A = {_lit(t.node_a)}
NODE_B = {_lit(t.node_b)}
NODE_D = {_lit(delta)}
NODE_NEXT = {_lit(t.node_next)}
LEAF_OWNER = {_lit(owner)}
LEAF_FAST = {_lit(fast_start)}
FAST_ROWS = {_lit(fast)}
LEAF_MEMBERS = {_lit(mem_start)}
MEMBERS = {_lit(mem)}
LEAF_GROUP = {None if group_start is None else _lit(group_start)}
ROW_START = {_lit(dep.off)}
ROW_A = {_lit(dep.A)}
ROW_B = {_lit(dep.b)}
LAW_F = np.array({_lit(dep.F)}, dtype=float).reshape({dep.F.shape!r})
LAW_G = np.array({_lit(dep.G)}, dtype=float).reshape({dep.G.shape!r})


def _row(j, x):
    a = -ROW_B[j]
    for t in range(NTHETA):
        a += ROW_A[j][t] * x[t]
    return a


def _violation(i, x):
    v = -1.0
    for j in range(ROW_START[i], ROW_START[i + 1]):
        a = _row(j, x)
        if j == ROW_START[i] or a > v:
            v = a
        if v > TOL:  # (neither holds nor near: the rule decides the same)
            return v
    return v


def locate(theta):
    """The region of one parameter vector (length NTHETA), -1 outside the domain."""
    x = [float(v) for v in theta]
    if len(x) != NTHETA:
        raise ValueError(f"expected {{NTHETA}} parameters, got {{len(x)}}")
    for t in range(NTHETA):
        if BOX_LO is None:
            if not math.isfinite(x[t]):
                return -1
        elif not (BOX_LO[t] <= x[t] <= BOX_HI[t]):
            return -1
    near = False
    k = 0 if NODE_B else -1
    while k >= 0:
        s = -NODE_B[k]
        for t in range(NTHETA):
            s += NODE_A[k][t] * x[t]
        if -NODE_D[k] <= s <= NODE_D[k]:
            near = True
        k = NODE_NEXT[k][1 if s > 0.0 else 0]
    leaf = -1 - k
    q0, q1 = LEAF_MEMBERS[leaf], LEAF_MEMBERS[leaf + 1]
    if not near and LEAF_OWNER[leaf] == -3:  # a group leaf: only its regions (one law)
        q0, q1 = LEAF_GROUP[leaf], LEAF_GROUP[leaf + 1]
    elif not near and LEAF_OWNER[leaf] != -2:
        r = LEAF_OWNER[leaf]
        if r < 0:
            return -1
        v = -1.0
        for q in range(LEAF_FAST[leaf], LEAF_FAST[leaf + 1]):
            a = _row(FAST_ROWS[q], x)
            if q == LEAF_FAST[leaf] or a > v:
                v = a
        return r if v <= TOL else -1
    r, best = -1, 0.0
    for q in range(q0, q1):
        j = MEMBERS[q]
        v = _violation(j, x)
        if v <= 0.0:
            return j
        if v <= TOL and (r < 0 or v < best):
            r, best = j, v
    return r


def evaluate(theta):
    """``(region, u)`` for one parameter vector; ``u`` is None outside the domain."""
    r = locate(theta)
    if r < 0:
        return r, None
    x = np.asarray(theta, dtype=float)
    return r, LAW_F[r] @ x + LAW_G[r]
'''
