"""The C99 writer of an export: constant tables and one evaluation function.

No dynamic allocation, no library call (``<stdint.h>`` types only), no recursion; every
loop is bounded by the tables. Numbers are written so that they read back exactly (the
shortest round-trip decimal of the double, or of the float with ``--float32``).
"""

from __future__ import annotations

import numpy as np

from codev_engine.deploy.bst import DELTA, LOCATE_TOL
from codev_engine.deploy.escape import c_prefix, comment
from codev_engine.deploy.plan import Export, ceil_log2, rom_bytes

__all__ = ["c_source", "tables"]


def _int_type(values: np.ndarray) -> tuple[str, int]:
    lo = int(values.min(initial=0))
    hi = int(values.max(initial=0))
    if -32768 <= lo and hi <= 32767:
        return "int16_t", 2
    return "int32_t", 4


def tables(ex: Export, float32: bool) -> dict[str, tuple[str, np.ndarray]]:
    """The constant tables of the generated code, ``{name: (C type, array)}``.

    Parameters
    ----------
    ex : Export
    float32 : bool

    Returns
    -------
    dict
        In the order they are written; an empty table holds one unused zero (C99 has no
        empty arrays).
    """
    t, dep = ex.tree, ex.dep
    real = "float" if float32 else "double"
    owner, fast_start, fast, mem_start, mem, group_start = leaf_tables(t)
    out: dict[str, tuple[str, np.ndarray]] = {}

    def put(name, arr, kind):
        arr = np.asarray(arr)
        if kind == "int":
            ctype = _int_type(arr)[0]
        else:
            ctype = real
        out[name] = (ctype, arr)

    if t.box_lo is not None:
        put("box_lo", t.box_lo, "real")
        put("box_hi", t.box_hi, "real")
    if t.num_nodes:
        # the nodes test few distinct hyperplanes (120 for 429 nodes): held once each
        planes, which = np.unique(
            np.column_stack([t.node_a, t.node_b]), axis=0, return_inverse=True
        )
        put("plane_a", planes[:, :-1], "real")
        put("plane_b", planes[:, -1], "real")
        put("node_plane", which.ravel(), "int")
        put("node_next", t.node_next, "int")
    put("leaf_owner", owner, "int")
    put("leaf_fast", fast_start, "int")
    put("fast_rows", fast, "int")
    put("leaf_members", mem_start, "int")
    if group_start is not None:
        put("leaf_group", group_start, "int")
    put("members", mem, "int")
    put("row_start", dep.off, "int")
    put("row_a", dep.A, "real")
    put("row_b", dep.b, "real")
    put("law_F", dep.F, "real")
    put("law_G", dep.G, "real")
    return out


def leaf_tables(t) -> tuple:
    """The leaves as flat tables (shared by the C and the Python writers).

    Parameters
    ----------
    t : Tree

    Returns
    -------
    owner : (L,) ndarray of int
        The owner, -1 none, -2 a general leaf, -3 a group leaf.
    fast_start, fast : ndarrays of int
        Leaf ``l``'s fast-path rows are ``fast[fast_start[l]:fast_start[l + 1]]``.
    mem_start, mem : ndarrays of int
        Leaf ``l``'s members are ``mem[mem_start[l]:mem_start[l + 1]]``; a group leaf's
        regions follow all the members in ``mem``:
    group_start : ndarray of int or None
        ``mem[group_start[l]:group_start[l + 1]]`` (None: no group leaf).
    """
    owner = np.where(t.leaf_general, -2, t.leaf_owner)
    fast_start = np.concatenate([[0], np.cumsum([f.size for f in t.leaf_fast])])
    mem_start = np.concatenate([[0], np.cumsum([m.size for m in t.leaf_members])])
    fast = np.concatenate(t.leaf_fast + [np.zeros(0, dtype=np.int64)])
    mem = np.concatenate(t.leaf_members + [np.zeros(0, dtype=np.int64)])
    groups = [t.group(k) for k in range(t.num_leaves)]
    if not any(g.size for g in groups):
        return owner, fast_start, fast, mem_start, mem, None
    owner = np.where([g.size > 0 for g in groups], -3, owner)
    group_start = mem.size + np.concatenate([[0], np.cumsum([g.size for g in groups])])
    mem = np.concatenate([mem, *groups])
    return owner, fast_start, fast, mem_start, mem, group_start


def _number(x: float, float32: bool) -> str:
    if float32:
        s = repr(float(np.float32(x)))
        s = s if ("e" in s or "." in s) else s + ".0"
        return s + "f"
    s = repr(float(x))
    return s if ("e" in s or "." in s or "inf" in s or "nan" in s) else s + ".0"


def _initialiser(arr: np.ndarray, ctype: str, float32: bool) -> str:
    if arr.size == 0:
        return "{0}"
    if arr.ndim == 1:
        if ctype in ("float", "double"):
            items = [_number(v, float32) for v in arr]
        else:
            items = [str(int(v)) for v in arr]
        lines, line = [], []
        for it in items:
            line.append(it)
            if len(line) == 6:
                lines.append(", ".join(line))
                line = []
        if line:
            lines.append(", ".join(line))
        return "{\n    " + ",\n    ".join(lines) + "\n}"
    return "{" + ", ".join(_initialiser(a, ctype, float32) for a in arr) + "}"


def _dims(arr: np.ndarray) -> str:
    if arr.size == 0:
        return "[1]"
    return "".join(f"[{n}]" for n in arr.shape)


def c_source(ex: Export, name: str, float32: bool) -> tuple[str, str]:
    """The header and the source of an export.

    Parameters
    ----------
    ex : Export
    name : str
        The prefix of every C name (checked by ``escape.c_prefix``).
    float32 : bool

    Returns
    -------
    header, source : str
        The law's names and fingerprint appear in comments only, escaped
        (``escape.comment``): whatever the law file holds, the code is codev's.
    """
    c_prefix(name)
    dep, t = ex.dep, ex.tree
    real = "float" if float32 else "double"
    up = name.upper()
    d, m = dep.F.shape[2], dep.F.shape[1]
    tabs = tables(ex, float32)
    sizes = {
        k: (max(1, a.size), 4 if c in ("float", "int32_t") else 8 if c == "double" else 2)
        for k, (c, a) in tabs.items()
    }
    rom = rom_bytes(sizes)
    R = dep.num_regions
    what = "u" if dep.kind == "law" else "z"
    params = "\n".join(
        f" *   theta[{i}] = {comment(n)}" for i, n in enumerate(dep.parameter_names)
    )
    outs = "\n".join(f" *   {what}[{i}] = {comment(n)}" for i, n in enumerate(dep.output_names))
    fingerprint = comment(dep.fingerprint) or "(none)"
    guard = f"{up}_H"
    box_text = (
        f"{2 * d} comparisons against the box of all regions"
        if t.box_lo is not None
        else f"{d} checks that theta is finite"
    )
    method_text = (
        "a binary search tree (Toendel, Johansen & Bemporad 2003)"
        if ex.method == "bst"
        else "a sequential search over the regions"
    )
    kind = "law" if dep.kind == "law" else "mp solution"
    header = f"""/* {name}.h -- the explicit {kind} as C99, generated by codev (do not edit).
 *
 * fingerprint: {fingerprint}
 * regions: {R}, search: {method_text}
 * parameter theta (length {d}), in this order:
{params}
 * output ({m}):
{outs}
 *
 * Worst case of one call (exhaustive traversal of the tree, certified):
 *   hyperplane tests on the path: {ex.depth} (2*ceil(log2(regions)) + n = \
{2 * ceil_log2(R) + d})
 *   hyperplane / row evaluations: {ex.tests}
 *   multiply-adds: {ex.macs} ({d} per evaluation + {m * d} for the affine map)
 *   plus {box_text}
 * ROM (constant tables): {rom} bytes; no RAM beyond a few locals; no library calls.
 *
 * Region choice (the rule of ExplicitLaw.locate, tolerance {LOCATE_TOL:g}): region i's
 * violation is v_i = max_j (A_i theta - b_i)_j over its stored rows. The region is the
 * lowest index with v_i <= 0; if none, the one with the smallest v_i <= {LOCATE_TOL:g}
 * (lowest index on ties); else -1 (outside the domain: u is left unchanged).
 */
#ifndef {guard}
#define {guard}

#define {up}_NTHETA {d}
#define {up}_NU {m}
#define {up}_NREGIONS {R}
#define {up}_WORST_TESTS {ex.tests}
#define {up}_WORST_MACS {ex.macs}
#define {up}_ROM_BYTES {rom}

/* Returns the region index (>= 0) and writes {what}; returns -1 outside the domain and
   leaves {what} unchanged. */
int {name}_evaluate(const {real} theta[{up}_NTHETA], {real} {what}[{up}_NU]);

#endif
"""
    decl = []
    for k, (c, a) in tabs.items():
        decl.append(f"static const {c} {k}{_dims(a)} = {_initialiser(a, c, float32)};")
    zero = "0.0f" if float32 else "0.0"
    one = "1.0f" if float32 else "1.0"
    delta = _number(DELTA["float" if float32 else "double"], float32)
    tol = _number(LOCATE_TOL, float32)
    if t.box_lo is not None:
        entry = f"""    for (t = 0; t < {d}; ++t) {{
        if (!(theta[t] >= box_lo[t] && theta[t] <= box_hi[t])) {{
            return -1; /* outside the box of all regions (or not a number) */
        }}
    }}
"""
    else:
        entry = f"""    for (t = 0; t < {d}; ++t) {{
        if (!(theta[t] - theta[t] == {zero})) {{
            return -1; /* infinite or not a number */
        }}
    }}
"""
    walk = ""
    group = ""
    if "leaf_group" in tabs:
        group = """    if (!near && leaf_owner[leaf] == -3) {
        /* a group leaf, not near: only its regions (one law) can hold theta */
        q0 = leaf_group[leaf];
        q1 = leaf_group[leaf + 1];
    }
"""
    if t.num_nodes:
        walk = f"""    k = 0;
    while (k >= 0) {{
        {up}_TICK();
        h = node_plane[k];
        s = -plane_b[h];
        for (t = 0; t < {d}; ++t) {{
            s += plane_a[h][t] * theta[t];
        }}
        /* near: |s| <= delta (1 + |b|) */
        v = {delta} * ({one} + (plane_b[h] < {zero} ? -plane_b[h] : plane_b[h]));
        if (s <= v && s >= -v) {{
            near = 1;
        }}
        k = node_next[k][s > {zero} ? 1 : 0];
    }}
    leaf = -1 - k;
"""
    else:
        walk = "    leaf = 0;\n"
    source = f"""/* {name}.c -- generated by codev (do not edit); see {name}.h. */
#include <stdint.h>
#include "{name}.h"

/* -D{up}_COUNT counts the hyperplane / row evaluations of every call in {name}_count (a
   check of the worst case in the header); without it the macro is empty */
#ifdef {up}_COUNT
long {name}_count = 0;
#define {up}_TICK() (++{name}_count)
#else
#define {up}_TICK() ((void)0)
#endif

{chr(10).join(decl)}

/* the largest violation of region i's rows (-1 without rows), summed as
   -b_j + A_j0 theta_0 + A_j1 theta_1 + ... (the locator's order); once a row exceeds the
   tolerance the region neither holds nor is near theta: that row's value is returned
   (the rule decides the same, the remaining rows are not evaluated) */
static {real} violation(int32_t i, const {real} theta[{up}_NTHETA])
{{
    int32_t j;
    int t;
    {real} v = -1, a;
    for (j = row_start[i]; j < row_start[i + 1]; ++j) {{
        {up}_TICK();
        a = -row_b[j];
        for (t = 0; t < {d}; ++t) {{
            a += row_a[j][t] * theta[t];
        }}
        if (j == row_start[i] || a > v) {{
            v = a;
        }}
        if (v > {tol}) {{
            return v;
        }}
    }}
    return v;
}}

int {name}_evaluate(const {real} theta[{up}_NTHETA], {real} {what}[{up}_NU])
{{
    int32_t k, leaf, r = -1, q, j, h, q0, q1;
    int t, near = 0, i;
    {real} s, v, best = {zero};
    (void)s;
    (void)k;
    (void)h;
{entry}{walk}    q0 = leaf_members[leaf];
    q1 = leaf_members[leaf + 1];
{group}    if (!near && leaf_owner[leaf] >= -1) {{
        /* more than delta inside every tested half-space: only the owner can hold theta */
        r = leaf_owner[leaf];
        if (r < 0) {{
            return -1;
        }}
        v = -1;
        for (q = leaf_fast[leaf]; q < leaf_fast[leaf + 1]; ++q) {{
            j = fast_rows[q];
            {up}_TICK();
            s = -row_b[j];
            for (t = 0; t < {d}; ++t) {{
                s += row_a[j][t] * theta[t];
            }}
            if (q == leaf_fast[leaf] || s > v) {{
                v = s;
            }}
        }}
        if (v > {tol}) {{
            return -1;
        }}
    }} else {{
        /* near a tested hyperplane: the rule over every region the leaf may hold (on a
           group leaf's fast path: over its regions of one law) */
        for (q = q0; q < q1; ++q) {{
            j = members[q];
            v = violation(j, theta);
            if (v <= {zero}) {{
                r = j;
                break;
            }}
            if (v <= {tol} && (r < 0 || v < best)) {{
                r = j;
                best = v;
            }}
        }}
        if (r < 0) {{
            return -1;
        }}
    }}
    for (i = 0; i < {m}; ++i) {{
        s = {zero};
        for (t = 0; t < {d}; ++t) {{
            s += law_F[r][i][t] * theta[t];
        }}
        {what}[i] = s + law_G[r][i];
    }}
    return (int)r;
}}
"""
    return header, source
