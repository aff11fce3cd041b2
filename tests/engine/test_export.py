"""The exported C (and Python) against the law: compiled by the system C compiler with
``-Wall -Wextra -Werror -pedantic -std=c99`` and called through ctypes.

At random states in and around the domain, at points on the regions' facets (shared
facets, where a discontinuous mp-LP law jumps, and the domain's boundary) and at their
vertices, at states outside the domain and at non-finite ones: the C returns the region
``ExplicitLaw.locate`` returns (0 mismatches), ``u`` within 1e-12 of ``law.evaluate``
(relative to ``|F||theta| + |G|``), and leaves ``u`` untouched where it returns -1. The
header's worst case equals the exhaustive traversal of the tree, and a counting build of
the same code never exceeds it. Laws: the three norms, merged and unmerged, degenerate
mp-LPs (R = 0), a Voronoi partition, overlapping simplices with gaps (where the lowest
index rule decides), and an ``MpSolution``.
"""

from __future__ import annotations

import ctypes
import functools
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.deploy.plan import ceil_log2, law_labels, plan
from codev_engine.geometry.vertices import vertices_many
from tests.engine.test_law import simplex_law, voronoi_law
from workbench.cli import main

ROOT = Path(__file__).resolve().parents[2]
CC = shutil.which("gcc") or shutil.which("cc")
needs_cc = pytest.mark.skipif(
    CC is None, reason="no C compiler (gcc or cc) on PATH: the exported C cannot be compiled"
)
FLAGS = ["-O2", "-Wall", "-Wextra", "-Werror", "-pedantic", "-std=c99"]
N_RANDOM = 10_000
SENTINEL = 777.0


# ---------------------------------------------------------------------------------------
# laws
# ---------------------------------------------------------------------------------------


def _variant(name: str, norm: str, simplify: bool, extra: dict[str, str] | None = None):
    text = (ROOT / "examples" / name).read_text()
    text = re.sub(r'^norm = ".*"$', f'norm = "{norm}"', text, flags=re.M)
    for key, value in (extra or {}).items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, flags=re.M)
    return ce.synthesize(ce.loads_spec(text), simplify=simplify)


@functools.cache
def law(key: str) -> ce.ExplicitLaw:
    if key == "voronoi":
        return voronoi_law(300, 3, seed=4)
    if key == "simplices":
        return simplex_law(200, 2, seed=5)
    if key == "servo_theta":  # theta = (angle, speed, prev_V, ref_y0)
        return ce.synthesize(ce.load_spec(ROOT / "examples" / "dc_motor_servo.toml"))
    name, norm, simp, *rest = key.split(":")
    extra = {"R": "[[0.0]]"} if rest == ["R0"] else {}
    if norm == "2":
        extra["Q"] = "[[1.0, 0.0], [0.0, 1.0]]"
    return _variant(f"{name}.toml", norm, simp == "merged", extra)


LAWS = [
    "double_integrator:inf:merged",
    "double_integrator:inf:unmerged",
    "double_integrator:1:unmerged",
    "double_integrator:2:unmerged",
    "double_integrator:2:merged",
    "double_integrator:1:unmerged:R0",  # a degenerate mp-LP (no input weight)
    "double_integrator:inf:unmerged:R0",
    "magnetic_pointer_c:inf:unmerged",
    "voronoi",
    "simplices",
    "servo_theta",  # a law over (x, u_prev, r): d = 4 > n = 2
]


# ---------------------------------------------------------------------------------------
# compiling and calling the export
# ---------------------------------------------------------------------------------------

DRIVER = """#include "{name}.h"
void {name}_batch(int P, const {real} *X, {real} *U, int *idx)
{{
    int p;
    for (p = 0; p < P; ++p) {{
        idx[p] = {name}_evaluate(X + p * {up}_NTHETA, U + p * {up}_NU);
    }}
}}
"""


class Compiled:
    """The exported C of a law, compiled into a shared library (with a batch driver)."""

    def __init__(self, obj, tmp: Path, *, float32=False, method="auto", count=False,
                 merge=False):
        name = "lawc"
        self.h, c = ce.export_c(obj, tmp, name=name, float32=float32, method=method,
                                merge_equal_laws=merge)
        real = "float" if float32 else "double"
        (tmp / "driver.c").write_text(DRIVER.format(name=name, real=real, up=name.upper()))
        so = tmp / "lawc.so"
        extra = [f"-D{name.upper()}_COUNT"] if count else []
        cmd = [CC, *FLAGS, *extra, "-shared", "-fPIC", "-o", str(so), str(c),
               str(tmp / "driver.c")]
        run = subprocess.run(cmd, capture_output=True, text=True)
        assert run.returncode == 0, run.stderr
        self.lib = ctypes.CDLL(str(so))
        self.dtype = np.float32 if float32 else np.float64
        self.header = self.h.read_text()
        self.n = int(re.search(r"#define LAWC_NTHETA (\d+)", self.header).group(1))
        self.m = int(re.search(r"#define LAWC_NU (\d+)", self.header).group(1))
        self.count = ctypes.c_long.in_dll(self.lib, "lawc_count") if count else None

    def define(self, key: str) -> int:
        return int(re.search(rf"#define LAWC_{key} (\d+)", self.header).group(1))

    def __call__(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        X = np.ascontiguousarray(X, dtype=self.dtype)
        P = X.shape[0]
        U = np.full((P, self.m), SENTINEL, dtype=self.dtype)
        idx = np.empty(P, dtype=np.intc)
        ptr = np.ctypeslib.ndpointer
        f = self.lib.lawc_batch
        f.argtypes = [ctypes.c_int, ptr(self.dtype), ptr(self.dtype), ptr(np.intc)]
        f(P, X, U, idx)
        return idx.astype(int), U.astype(float)


# ---------------------------------------------------------------------------------------
# points
# ---------------------------------------------------------------------------------------


def random_points(lw, count: int, seed: int) -> np.ndarray:
    lo, hi = lw.boxes
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    span = hi - lo
    rng = np.random.default_rng(seed)
    return rng.uniform(lo - 0.2 * span, hi + 0.2 * span, size=(count, lo.size))


def facet_points(lw, per_facet: int, seed: int, cap: int = 20_000) -> np.ndarray:
    """Points on every region's facets (convex combinations of the facet's vertices, as
    rounded), and the vertices."""
    rng = np.random.default_rng(seed)
    pts = []
    for A, b, V in zip(lw.A, lw.b, vertices_many(lw.A, lw.b, 1e-9), strict=True):
        if V is None or V.shape[0] == 0:
            continue
        pts.append(V)
        for j in range(A.shape[0]):
            on = V[np.abs(V @ A[j] - b[j]) < 1e-9]
            if on.shape[0]:
                pts.append(rng.dirichlet(np.ones(on.shape[0]), size=per_facet) @ on)
    X = np.vstack(pts)
    if X.shape[0] > cap:
        X = X[rng.choice(X.shape[0], cap, replace=False)]
    return X


def outside_points(lw, n: int) -> np.ndarray:
    lo, hi = lw.boxes
    far = 10.0 * (np.abs(lo).max() + np.abs(hi).max() + 1.0)
    rows = [np.full(n, far), np.full(n, -far), np.full(n, np.nan), np.full(n, np.inf)]
    mixed = np.zeros(n)
    mixed[0] = np.nan
    return np.vstack(rows + [mixed])


def scale(lw, idx: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``|F_i| |theta| + |G_i|`` per point (the size of the sums that make u)."""
    return np.einsum("pij,pj->pi", np.abs(lw.F[idx]), np.abs(X)) + np.abs(lw.G[idx])


def _load_module(path: Path):
    import importlib.util

    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def assert_agrees(lw, C: Compiled, X: np.ndarray, rtol: float = 1e-12) -> None:
    idx, U = C(X)
    ref = lw.locate(X)
    bad = np.flatnonzero(idx != ref)
    assert bad.size == 0, f"{bad.size} of {X.shape[0]} regions differ, e.g. {X[bad[:3]]}"
    inside = ref >= 0
    assert np.all(U[~inside] == SENTINEL), "u written outside the domain"
    if np.any(inside):
        want = lw.evaluate(X[inside])
        err = np.abs(U[inside] - want) / np.maximum(scale(lw, ref[inside], X[inside]), 1e-300)
        assert err.max() <= rtol, f"u off by {err.max():.3g} (relative)"


# ---------------------------------------------------------------------------------------
# tests
# ---------------------------------------------------------------------------------------


@needs_cc
@pytest.mark.parametrize("key", LAWS)
def test_c_returns_the_region_and_law_of_locate(key, tmp_path):
    lw = law(key)
    C = Compiled(lw, tmp_path, method="bst")
    assert_agrees(lw, C, random_points(lw, N_RANDOM, seed=1))
    assert_agrees(lw, C, facet_points(lw, 3, seed=2))
    X = outside_points(lw, lw.n)
    idx, U = C(X)
    assert np.all(idx == -1) and np.all(U == SENTINEL)
    assert np.all(lw.locate(X) == -1)


@needs_cc
@pytest.mark.parametrize("key", ["double_integrator:1:unmerged:R0", "simplices"])
def test_sequential_search_agrees_too(key, tmp_path):
    lw = law(key)
    C = Compiled(lw, tmp_path, method="sequential")
    assert "sequential search" in C.header
    assert_agrees(lw, C, random_points(lw, 2000, seed=3))
    assert_agrees(lw, C, facet_points(lw, 2, seed=4, cap=3000))
    idx, U = C(outside_points(lw, lw.n))
    assert np.all(idx == -1) and np.all(U == SENTINEL)


@needs_cc
@pytest.mark.parametrize("key", ["double_integrator:2:unmerged", "magnetic_pointer_c:inf:unmerged"])
def test_float32_within_1e5(key, tmp_path):
    """float: the region of locate except within float rounding of a facet; u within 1e-5
    (relative to |F||theta| + |G|) wherever the region is the same."""
    lw = law(key)
    C = Compiled(lw, tmp_path, float32=True)
    assert "float theta[" in C.header
    X = random_points(lw, N_RANDOM, seed=6).astype(np.float32).astype(float)
    idx, U = C(X)
    ref = lw.locate(X)
    same = idx == ref
    for p in np.flatnonzero(~same):  # only at a facet: the C's region within 1e-5 of X
        k = idx[p] if idx[p] >= 0 else ref[p]
        v = np.max(lw.A[k] @ X[p] - lw.b[k])
        assert abs(v) <= 1e-5 * (1.0 + np.abs(X[p]).sum()), (p, idx[p], ref[p], v)
    assert same.mean() > 0.999
    inside = same & (ref >= 0)
    sc = np.maximum(scale(lw, ref[inside], X[inside]), 1e-300)
    err = np.abs(U[inside] - lw.evaluate(X[inside])) / sc
    assert err.max() <= 1e-5
    assert np.all(U[idx < 0] == SENTINEL)


@needs_cc
@pytest.mark.parametrize(
    "key", ["double_integrator:1:unmerged:R0", "magnetic_pointer_c:inf:unmerged"]
)
def test_worst_case_is_the_deepest_path(key, tmp_path):
    """The header's worst case is the exhaustive traversal of the tree's tables, and no call
    of a counting build exceeds it (the deepest tests are within the target)."""
    lw = law(key)
    ex = plan(lw, "bst")
    t = ex.tree
    # walk the tables from the root: every leaf once, its depth and its rows
    nrows = np.diff(t.row_off)
    worst = depth = 0
    stack = [(0, 0)] if t.num_nodes else [(-1, 0)]
    seen = 0
    while stack:
        k, dep = stack.pop()
        if k < 0:
            leaf = -1 - k
            seen += 1
            members = int(nrows[t.leaf_members[leaf]].sum())
            fast = members if t.leaf_general[leaf] else t.leaf_fast[leaf].size
            if t.group(leaf).size:
                fast = int(nrows[t.group(leaf)].sum())
            worst = max(worst, dep + max(fast, members))
            depth = max(depth, dep)
            continue
        for child in t.node_next[k]:
            stack.append((int(child), dep + 1))
    assert seen == t.num_leaves
    assert (ex.depth, ex.tests) == (depth, worst)
    assert ex.macs == worst * lw.n + lw.n * lw.m
    assert depth <= 2 * ceil_log2(lw.num_regions) + lw.n
    C = Compiled(lw, tmp_path, method="bst", count=True)
    assert C.define("WORST_TESTS") == worst
    assert f"hyperplane tests on the path: {depth}" in C.header
    most = 0
    for X in (random_points(lw, 3000, seed=8), facet_points(lw, 2, seed=9, cap=3000)):
        for p in range(X.shape[0]):
            C.count.value = 0
            C(X[p : p + 1])
            most = max(most, C.count.value)
    assert 0 < most <= worst


@needs_cc
@pytest.mark.parametrize(
    "key", ["double_integrator:inf:unmerged", "magnetic_pointer_c:inf:unmerged"]
)
def test_equal_laws_share_leaves_and_locate_still_decides(key, tmp_path):
    """``merge_equal_laws``: the tree stops where the regions left have one law (fewer
    leaves); such a leaf runs the rule over them, so C and Python still return locate's
    region and its own u, and the header's worst case is still the traversal's."""
    lw = law(key)
    plain, merged = plan(lw, "bst"), plan(lw, "bst", merge_equal_laws=True)
    labels = law_labels(merged.dep)
    assert np.unique(labels).size < lw.num_regions  # the law repeats affine maps
    t = merged.tree
    groups = [t.group(k) for k in range(t.num_leaves)]
    assert any(g.size > 1 for g in groups)
    for g in groups:
        assert np.unique(labels[g]).size <= 1
        assert np.all(np.diff(g) > 0)
    assert t.num_leaves < plain.tree.num_leaves
    assert (merged.depth, merged.tests) == (t.cost()["depth"], t.cost()["tests"])
    C = Compiled(lw, tmp_path, method="bst", merge=True, count=True)
    assert C.define("WORST_TESTS") == merged.tests
    X = np.vstack([random_points(lw, 5000, seed=21), facet_points(lw, 2, seed=22, cap=5000)])
    assert_agrees(lw, C, X)
    most = 0
    for p in range(0, X.shape[0], 7):
        C.count.value = 0
        C(X[p : p + 1])
        most = max(most, C.count.value)
    assert 0 < most <= merged.tests
    idx, U = C(outside_points(lw, lw.n))
    assert np.all(idx == -1) and np.all(U == SENTINEL)
    path = ce.export_python(lw, tmp_path / "merged_law.py", method="bst",
                            merge_equal_laws=True)
    mod = _load_module(path)
    pts = X[:: max(1, X.shape[0] // 400)]
    assert [mod.locate(x) for x in pts] == list(lw.locate(pts))


@needs_cc
def test_header_names_theta_and_the_fingerprint(tmp_path):
    lw = law("magnetic_pointer_c:inf:unmerged")
    C = Compiled(lw, tmp_path)
    assert lw.fingerprint in C.header
    for i, name in enumerate(lw.parameter_names):
        assert f"theta[{i}] = {name}" in C.header
    assert C.define("NTHETA") == lw.F.shape[2]
    assert C.define("ROM_BYTES") > 0


@needs_cc
def test_mp_solution_exports_its_primal(tmp_path):
    from tests.engine.test_mpsolve import random_program

    prog = random_program(3, lp=False)
    sol = ce.mpsolve(prog)
    C = Compiled(sol, tmp_path)
    X = np.random.default_rng(1).uniform(-2, 2, size=(3000, prog.d))
    idx, Z = C(X)
    ref = sol.locate(X)
    assert np.array_equal(idx, ref)
    inside = ref >= 0
    assert np.any(inside)
    assert np.allclose(Z[inside], sol.primal(X[inside]), rtol=1e-12, atol=1e-12)
    # the same through the command line, from the saved solution
    f = sol.save(tmp_path / "sol.npz")
    assert main(["export", str(f), "--c", str(tmp_path / "cli"), "--name", "sol"]) == 0
    header = (tmp_path / "cli" / "sol.h").read_text()
    assert "mp solution" in header and f"#define SOL_NTHETA {prog.d}" in header


def test_python_export_agrees_with_locate(tmp_path):
    lw = law("magnetic_pointer_c:inf:unmerged")
    path = ce.export_python(lw, tmp_path / "lawpy.py")
    sys.path.insert(0, str(tmp_path))
    try:
        import lawpy
    finally:
        sys.path.remove(str(tmp_path))
    X = np.vstack([random_points(lw, 300, seed=10), facet_points(lw, 1, seed=11, cap=300)])
    ref = lw.locate(X)
    U = lw.evaluate(X)
    for p in range(X.shape[0]):
        r, u = lawpy.evaluate(X[p])
        assert r == ref[p]
        if r >= 0:
            assert np.allclose(u, U[p], rtol=1e-12, atol=1e-12)
        else:
            assert u is None
    assert lawpy.PARAMETER_NAMES == lw.parameter_names
    assert "import numpy" in path.read_text() and "codev" not in lawpy.__dict__


def test_cli_exports_and_refuses_bad_input(tmp_path, capsys):
    lw = law("double_integrator:inf:merged")
    f = lw.save(tmp_path / "law.npz")
    out = tmp_path / "c"
    assert main(["export", str(f), "--c", str(out), "--name", "di", "--python",
                 str(tmp_path / "di.py")]) == 0
    assert (out / "di.h").exists() and (out / "di.c").exists() and (tmp_path / "di.py").exists()
    capsys.readouterr()
    (tmp_path / "junk.npz").write_text("not a zip")
    for argv in (
        ["export", str(tmp_path / "missing.npz"), "--c", str(out)],
        ["export", str(f), "--c", str(out), "--name", "9lives"],
        ["export", str(f)],
        ["export", str(tmp_path / "junk.npz"), "--c", str(out)],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and err.startswith("codev: error:"), err


@needs_cc
@pytest.mark.slow
def test_magnetic_pointer_1008_regions_1e5_states(tmp_path, request):
    if "slow" not in (request.config.getoption("markexpr") or "") and not os.environ.get(
        "CODEV_SLOW"
    ):
        pytest.skip("10^5 states through the 1008-region tree: run with -m slow")
    lw = ce.synthesize(ce.load_spec(ROOT / "examples" / "magnetic_pointer_a.toml"))
    C = Compiled(lw, tmp_path, method="bst")
    assert_agrees(lw, C, random_points(lw, 100_000, seed=12))
    assert_agrees(lw, C, facet_points(lw, 3, seed=13, cap=100_000))


@needs_cc
@pytest.mark.parametrize("key", ["magnetic_pointer_c:inf:unmerged", "simplices"])
def test_buckets_of_a_few_regions_agree_and_certify(key, tmp_path):
    """Leaves of up to 4 proper regions (``leaf_size``, what a large partition gets): a
    smaller tree, the same regions as locate, the worst case still the traversal's."""
    lw = law(key)
    ex = plan(lw, "bst", leaf_size=4)
    t = ex.tree
    assert max(g.size for g in t.leaf_group) > 1
    assert t.num_leaves < plan(lw, "bst").tree.num_leaves
    assert ex.tests == t.cost()["tests"]
    C = Compiled(ex, tmp_path, count=True)
    assert C.define("WORST_TESTS") == ex.tests
    X = np.vstack([random_points(lw, 5000, seed=31), facet_points(lw, 2, seed=32, cap=5000)])
    assert_agrees(lw, C, X)
    most = 0
    for p in range(0, X.shape[0], 5):
        C.count.value = 0
        C(X[p : p + 1])
        most = max(most, C.count.value)
    assert 0 < most <= ex.tests


@needs_cc
def test_candidates_filtered_by_the_cell_keep_the_tree_exact(monkeypatch, tmp_path):
    """A large law (no table of extents; forced here) scores only the candidate hyperplanes
    that cut the points known in the node's cell: fewer scored, the same regions as
    locate on random states and on facets, the worst case still the traversal's."""
    import codev_engine.deploy.bst as bst

    monkeypatch.setattr(bst, "TABLE_ENTRIES", 0)
    lw = law("magnetic_pointer_c:inf:unmerged")
    ex = plan(lw, "bst", leaf_size=4)
    st = ex.tree.stats
    assert 0 < st["scored"] < st["candidates"]
    assert ex.tests == ex.tree.cost()["tests"]
    C = Compiled(ex, tmp_path)
    X = np.vstack([random_points(lw, 20_000, seed=51), facet_points(lw, 2, seed=52, cap=20_000)])
    assert_agrees(lw, C, X)


@needs_cc
@pytest.mark.parametrize(
    ("key", "table"),
    [("voronoi", False), ("magnetic_pointer_c:inf:unmerged", True),
     ("magnetic_pointer_c:inf:unmerged", False)],
)
def test_regions_kept_by_their_boxes_keep_the_tree_exact(key, table, monkeypatch, tmp_path):
    """A region whose vertices are not enumerated (too many rows in high dimension: the
    quadrotor's region of operation, d = 12; forced here on every region) is sorted by its
    box's support and located by points inside it: the tree still returns locate's
    region on random states and on facets, with or without the table of extents."""
    import codev_engine.deploy.bst as bst

    monkeypatch.setattr(bst, "SUBSET_MAX", 0)
    monkeypatch.setattr(bst, "HULL_MAX_VERTICES", 0)
    if not table:
        monkeypatch.setattr(bst, "TABLE_ENTRIES", 0)
    lw = law(key)
    ex = plan(lw, "bst")
    assert ex.tree.stats["boxed"] == lw.num_regions and ex.tree.num_nodes > 0
    assert ex.tests == ex.tree.cost()["tests"]
    C = Compiled(ex, tmp_path)
    X = np.vstack([random_points(lw, 5000, seed=61), facet_points(lw, 2, seed=62, cap=5000)])
    assert_agrees(lw, C, X)


def test_most_vertices_by_the_upper_bound_theorem():
    from codev_engine.deploy.bst import max_vertices

    assert [max_vertices(k, 2) for k in (3, 4, 7)] == [3, 4, 7]  # polygons
    assert max_vertices(6, 3) == 8 and max_vertices(8, 3) == 12  # 2k - 4
    assert max_vertices(8, 4) == 20  # the dual of the cyclic polytope C(8, 4)
    assert max_vertices(12, 12) == 1 and max_vertices(50, 12) > 10**6


def _traversal_worst(t) -> tuple[int, int]:
    """The deepest path and the most rows of one call, by walking the node table from
    the root (independent of ``Tree.cost``)."""
    nrows = np.diff(t.row_off)
    worst = depth = 0
    stack = [(0, 0)] if t.num_nodes else [(-1, 0)]
    while stack:
        k, dep = stack.pop()
        if k < 0:
            leaf = -1 - k
            members = int(nrows[t.leaf_members[leaf]].sum())
            fast = members if t.leaf_general[leaf] else t.leaf_fast[leaf].size
            if t.group(leaf).size:
                fast = int(nrows[t.group(leaf)].sum())
            worst = max(worst, dep + max(fast, members))
            depth = max(depth, dep)
            continue
        for child in t.node_next[k]:
            stack.append((int(child), dep + 1))
    return depth, worst


@needs_cc
@pytest.mark.parametrize("key", ["voronoi", "magnetic_pointer_c:inf:unmerged"])
def test_nodes_no_split_shrinks_become_buckets_and_stay_exact(key, monkeypatch, tmp_path):
    """The large-partition policy (``plan.LARGE``, forced here on a law of a few hundred
    regions, with no table of extents as a large law has none): a node whose best split
    keeps most of its regions in one child is a bucket leaf, larger than ``leaf_size``;
    the C still returns locate's region on random states and on facets, and the
    header's worst case is the exhaustive traversal's, never exceeded by a counting
    build."""
    import codev_engine.deploy.bst as bst
    import codev_engine.deploy.plan as plan_mod

    monkeypatch.setattr(bst, "TABLE_ENTRIES", 0)
    monkeypatch.setattr(plan_mod, "LARGE_FROM", 0)
    monkeypatch.setattr(plan_mod, "LARGE", {"leaf_size": 2, "stop_ratio": 0.6,
                                            "bucket_max": 24, "budget": 5e5, "tries": 1})
    lw = law(key)
    ex = plan(lw, "bst")
    t = ex.tree
    st = t.stats
    assert st.get("stopped", 0) + st.get("stopped_est", 0) > 0
    assert max(g.size for g in t.leaf_group) > 2
    assert max(g.size for g in t.leaf_group) <= 24
    depth, worst = _traversal_worst(t)
    assert (ex.depth, ex.tests) == (depth, worst)
    C = Compiled(ex, tmp_path, count=True)
    assert C.define("WORST_TESTS") == worst
    X = np.vstack([random_points(lw, 20_000, seed=61), facet_points(lw, 2, seed=62, cap=20_000)])
    assert_agrees(lw, C, X)
    most = 0
    for p in range(0, X.shape[0], 7):
        C.count.value = 0
        C(X[p : p + 1])
        most = max(most, C.count.value)
    assert 0 < most <= worst


def test_cutting_keeps_the_hyperplanes_through_the_cell_points():
    """``prune_kernel.cutting``: a hyperplane cuts when the points in the cell (vertices
    and witnesses) lie on both sides; points outside the cell do not count."""
    from codev_engine.deploy.prune_kernel import cutting

    # two unit squares' vertices: [0, 1]^2 and [5, 6] x [0, 1]; the cell x <= 2
    sq = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    V = np.vstack([sq, sq + [5.0, 0.0]])
    vstart, vcount = np.array([0, 4]), np.array([4, 4])
    CA, Cb = np.array([[1.0, 0.0]]), np.array([2.0])
    # x = 0.5 (through the first square), x = 5.5 (through the second, outside the cell),
    # y = 0.5 (through both), x = 3 (between)
    HA = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 0.0]])
    Hb = np.array([0.5, 5.5, 0.5, 3.0])
    W = np.zeros((2, 1, 2))
    Wn = np.zeros(2, dtype=np.int64)
    cand = np.arange(4)
    cut, n = cutting(V, vstart, vcount, np.array([0, 1]), CA, Cb, 1e-9, W, Wn, HA, Hb, cand,
                     np.full(4, 1e-7))
    assert n == 4 and cut.tolist() == [True, False, True, False]
    # a witness of the second region inside the cell at x = 1.8 (its part there): x = 1.5 cuts
    W[1, 0] = [1.8, 0.5]
    Wn[1] = 1
    cut, n = cutting(V, vstart, vcount, np.array([0, 1]), CA, Cb, 1e-9, W, Wn,
                     np.array([[1.0, 0.0]]), np.array([1.5]), np.array([0]), np.full(1, 1e-7))
    assert n == 5 and cut.tolist() == [True]


@needs_cc
@pytest.mark.slow
def test_a_test_set_mp_qp_tree_on_1e5_states(tmp_path):
    """pop_mpqp_043 of the mp test set (899 regions, d = 4; its vertex-sorted tree passed
    90,000 nodes): the cell-sorted tree with buckets, 10^5 states and every facet."""
    from tests.engine.test_mp_testset import TESTSET

    f = TESTSET / "pop_mpqp_043.npz"
    if not f.is_file():
        pytest.skip(f"mp_testset not found: {f}")
    keys = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta")
    with np.load(f, allow_pickle=False) as z:
        sol = ce.mpsolve(ce.MpProgram(**{k: z[k] for k in keys}, name=f.stem))
    ex = plan(sol, "bst", leaf_size=8)
    assert ex.method == "bst" and ex.tests == ex.tree.cost()["tests"]
    C = Compiled(ex, tmp_path)
    X = np.random.default_rng(41).uniform(-10.5, 10.5, size=(100_000, ex.dep.F.shape[2]))
    idx, Z = C(X)
    ref = sol.locate(X)
    assert np.array_equal(idx, ref)
    inside = ref >= 0
    assert inside.sum() > 10_000
    assert np.allclose(Z[inside], sol.primal(X[inside]), rtol=1e-12, atol=1e-12)
    lw_like = type("L", (), {})()
    lw_like.A = [ex.dep.A[ex.dep.off[i] : ex.dep.off[i + 1]] for i in range(sol.num_regions)]
    lw_like.b = [ex.dep.b[ex.dep.off[i] : ex.dep.off[i + 1]] for i in range(sol.num_regions)]
    Xf = facet_points(lw_like, 1, seed=42, cap=100_000)
    assert np.array_equal(C(Xf)[0], sol.locate(Xf))


@needs_cc
@pytest.mark.slow
def test_a_1e4_region_mp_qp_gets_its_tree(tmp_path):
    """pop_mpqp_083 (13,266 regions, d = 5; its tree gave up at 1,500 s CPU before the
    large-partition policy, ``plan.LARGE``): the tree is built, the header's worst case is
    the traversal's, the C returns locate's region on 10^5 random states and on 10^5
    facet points, and a counting build stays within the header (~4 min)."""
    from tests.engine.test_mp_testset import TESTSET

    f = TESTSET / "pop_mpqp_083.npz"
    if not f.is_file():
        pytest.skip(f"mp_testset not found: {f}")
    keys = ("H", "c", "C", "A", "b", "F", "A_theta", "b_theta")
    with np.load(f, allow_pickle=False) as z:
        sol = ce.mpsolve(ce.MpProgram(**{k: z[k] for k in keys}, name=f.stem))
    assert sol.num_regions > 10_000
    ex = plan(sol, "bst")
    assert ex.method == "bst"
    assert (ex.depth, ex.tests) == _traversal_worst(ex.tree)
    C = Compiled(ex, tmp_path, count=True)
    assert C.define("WORST_TESTS") == ex.tests
    lo, hi = ex.dep.boxes
    lo, hi = lo.min(axis=0), hi.max(axis=0)
    X = np.random.default_rng(71).uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo),
                                          size=(100_000, lo.size))
    idx, Z = C(X)
    ref = sol.locate(X)
    assert np.array_equal(idx, ref)
    inside = ref >= 0
    assert inside.sum() > 1000
    assert np.allclose(Z[inside], sol.primal(X[inside]), rtol=1e-12, atol=1e-12)
    lw_like = type("L", (), {})()
    lw_like.A = [ex.dep.A[ex.dep.off[i] : ex.dep.off[i + 1]] for i in range(sol.num_regions)]
    lw_like.b = [ex.dep.b[ex.dep.off[i] : ex.dep.off[i + 1]] for i in range(sol.num_regions)]
    Xf = facet_points(lw_like, 1, seed=72, cap=100_000)
    assert np.array_equal(C(Xf)[0], sol.locate(Xf))
    most = 0
    for p in range(0, Xf.shape[0], 10):
        C.count.value = 0
        C(Xf[p : p + 1])
        most = max(most, C.count.value)
    assert 0 < most <= ex.tests


def test_a_tree_past_its_budget_leaves_the_sequential_search(monkeypatch, tmp_path, capsys):
    """The voronoi law needs over 7,000 nodes: with a budget of 1,000, ``auto`` takes the
    sequential search and ``bst`` says why in one line (exit 1: not the input's fault)."""
    import codev_engine.deploy.bst as bst

    monkeypatch.setattr(bst, "NODES_PER_REGION", 0)
    lw = law("voronoi")
    assert plan(lw, "auto").method == "sequential"
    with pytest.raises(bst.TreeTooLargeError):
        plan(lw, "bst")
    f = lw.save(tmp_path / "v.npz")
    assert main(["export", str(f), "--c", str(tmp_path), "--method", "bst"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "sequential search" in err


@needs_cc
def test_header_names_u_prev_and_the_reference(tmp_path):
    lw = law("servo_theta")
    C = Compiled(lw, tmp_path)
    assert C.define("NTHETA") == 4
    for i, name in enumerate(("angle", "speed", "prev_V", "ref_y0")):
        assert f"theta[{i}] = {name}" in C.header
