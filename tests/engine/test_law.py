"""ExplicitLaw: save/load round trip, malformed law files, point location and evaluation.

Point location is checked against brute force (every region tested at every point: the
lowest index holding the point wins, else the region nearest within the locator's tolerance)
on 1000-region laws: Voronoi partitions of a box in 2-D and 3-D, 1000 random overlapping
simplices with gaps (where the lowest-index rule matters), and the 1008-region
magnetic-pointer law.
"""

from __future__ import annotations

import functools
import io
import json
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import Delaunay

import codev_engine as ce

LOC_TOL = 1e-9  # the locator's documented tolerance (unit-norm rows)
N_POINTS = 10_000


# ---------------------------------------------------------------------------------------
# laws to test with
# ---------------------------------------------------------------------------------------


def random_affine(k: int, n: int, m: int, rng) -> tuple[np.ndarray, np.ndarray]:
    return rng.normal(size=(k, m, n)), rng.normal(size=(k, m))


def voronoi_law(k: int, d: int, seed: int, m: int = 2) -> ce.ExplicitLaw:
    """The Voronoi partition of k random sites in [-1, 1]^d (a true partition of the box).

    Cell i: ``(s_j - s_i) x <= (|s_j|^2 - |s_i|^2) / 2`` for its Delaunay neighbours j,
    plus the box rows; every row is scaled to unit norm.
    """
    rng = np.random.default_rng(seed)
    S = rng.uniform(-1, 1, size=(k, d))
    indptr, nbrs = Delaunay(S).vertex_neighbor_vertices
    eye = np.eye(d)
    As, bs = [], []
    for i in range(k):
        J = nbrs[indptr[i]:indptr[i + 1]]
        A = np.vstack([S[J] - S[i], eye, -eye])
        b = np.concatenate([(np.sum(S[J] ** 2, axis=1) - S[i] @ S[i]) / 2, np.ones(2 * d)])
        nrm = np.linalg.norm(A, axis=1)
        As.append(A / nrm[:, None])
        bs.append(b / nrm)
    F, G = random_affine(k, d, m, rng)
    return ce.ExplicitLaw(A=As, b=bs, F=F, G=G, states=tuple(f"x{i}" for i in range(d)),
                          inputs=tuple(f"u{j}" for j in range(m)), fingerprint="voronoi",
                          meta={"seed": seed})


def simplex_law(k: int, d: int, seed: int) -> ce.ExplicitLaw:
    """k random small simplices in [-1, 1]^d: they overlap each other and leave gaps."""
    rng = np.random.default_rng(seed)
    As, bs = [], []
    for _ in range(k):
        c = rng.uniform(-1, 1, d)
        V = c + rng.normal(scale=0.08, size=(d + 1, d))
        hull = Delaunay(V)
        # facets from the (single) simplex: rows a x <= beta with outward normals
        A = hull.transform[0, :d, :]  # barycentric: lambda_1..d = T (x - r)
        r = hull.transform[0, d, :]
        # lambda_i >= 0 (i < d) and 1 - sum(lambda) >= 0
        rows = np.vstack([-A, A.sum(axis=0, keepdims=True)])
        rhs = np.concatenate([-A @ r, [1.0 + A.sum(axis=0) @ r]])
        nrm = np.linalg.norm(rows, axis=1)
        As.append(rows / nrm[:, None])
        bs.append(rhs / nrm)
    F, G = random_affine(k, d, 1, rng)
    return ce.ExplicitLaw(A=As, b=bs, F=F, G=G)


def brute_locate(law: ce.ExplicitLaw, X: np.ndarray, near_tol: float = 1e-7,
                 with_near: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Brute force over every region.

    Returns
    -------
    idx : (P,) int
        Lowest index of a region holding each point, else the region whose rows it violates
        least (within LOC_TOL), -1 for none.
    near : (P,) bool
        Points within ``near_tol`` of a boundary row of a region they (almost) belong to:
        there rounding may legitimately decide (all False unless ``with_near``).
    """
    nrm = [np.linalg.norm(A, axis=1) for A in law.A]
    Aall = np.vstack([A / n[:, None] for A, n in zip(law.A, nrm, strict=True)])
    ball = np.concatenate([b / n for b, n in zip(law.b, nrm, strict=True)])
    starts = np.cumsum([0] + [A.shape[0] for A in law.A])[:-1]
    idx = np.full(X.shape[0], -1)
    near = np.zeros(X.shape[0], dtype=bool)
    chunk = max(1, 4_000_000 // Aall.shape[0])
    for c0 in range(0, X.shape[0], chunk):
        S = X[c0:c0 + chunk] @ Aall.T - ball  # (c, all rows)
        smax = np.maximum.reduceat(S, starts, axis=1)  # (c, regions)
        inside = smax <= 0.0
        nearest = np.where(smax <= LOC_TOL, smax, np.inf).argmin(axis=1)
        found = np.where(np.any(smax <= LOC_TOL, axis=1), nearest, -1)
        idx[c0:c0 + chunk] = np.where(inside.any(axis=1), inside.argmax(axis=1), found)
        if with_near:
            tight = np.maximum.reduceat((np.abs(S) <= near_tol).view(np.int8), starts, axis=1)
            near[c0:c0 + chunk] = np.any((smax <= near_tol) & (tight > 0), axis=1)
    return idx, near


LOCATION_LAWS = {
    "voronoi2d": lambda: voronoi_law(1000, 2, seed=1),
    "voronoi3d": lambda: voronoi_law(1000, 3, seed=2),
    "simplices2d": lambda: simplex_law(1000, 2, seed=3),
    "simplices3d": lambda: simplex_law(1000, 3, seed=4),
}
#: laws synthesised from examples/ (through the session fixture ``example_law``)
EXAMPLE_LOCATION_LAWS = {"magnetic_pointer_a": "magnetic_pointer_a.toml"}


@functools.cache
def location_law(name: str) -> ce.ExplicitLaw:
    return LOCATION_LAWS[name]()


#: sampling box per law (a little larger than the union of its regions)
SAMPLE_BOX = {
    "voronoi2d": 1.1,
    "voronoi3d": 1.1,
    "simplices2d": 1.4,
    "simplices3d": 1.4,
    "magnetic_pointer_a": 10.5,  # state bounds +-10
}


def law_bbox(name: str) -> tuple[np.ndarray, np.ndarray]:
    d = 3 if name == "magnetic_pointer_a" else location_law(name).n
    h = SAMPLE_BOX[name]
    return np.full(d, -h), np.full(d, h)


# ---------------------------------------------------------------------------------------
# point location and evaluation
# ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(LOCATION_LAWS) + list(EXAMPLE_LOCATION_LAWS))
def test_locate_agrees_with_brute_force(name, example_law):
    if name in EXAMPLE_LOCATION_LAWS:
        law = example_law(EXAMPLE_LOCATION_LAWS[name])[1]
    else:
        law = location_law(name)
    assert law.num_regions >= 1000
    lo, hi = law_bbox(name)
    X = np.random.default_rng(11).uniform(lo, hi, size=(N_POINTS, lo.shape[0]))
    got = law.locate(X)
    want, _ = brute_locate(law, X, with_near=False)
    differ = np.flatnonzero(got != want)
    # a point within 1e-7 of a boundary row may legitimately be decided by rounding
    differ = differ[~brute_locate(law, X[differ])[1]]
    assert differ.size == 0, (
        f"{name}: {differ.size} of {N_POINTS} points located differently from brute force, "
        f"e.g. x={X[differ[0]].tolist()}: locate={got[differ[0]]}, brute force={want[differ[0]]}"
    )
    assert np.any(want >= 0) and np.any(want < 0)  # both kinds of points were tested


@pytest.mark.parametrize("name", ["voronoi2d", "voronoi3d", "simplices2d"])
def test_evaluate_is_the_located_affine_law(name):
    law = location_law(name)
    lo, hi = law_bbox(name)
    X = np.random.default_rng(12).uniform(lo, hi, size=(N_POINTS, lo.shape[0]))
    want_idx, _ = brute_locate(law, X, with_near=False)
    U = law.evaluate(X)
    assert U.shape == (N_POINTS, law.m)
    inside = want_idx >= 0
    # (location itself is tested above; here skip the points it may decide by rounding)
    ok = law.locate(X) == want_idx
    ok[~ok] = ~brute_locate(law, X[~ok])[1]
    want = np.einsum("pij,pj->pi", law.F[want_idx[inside]], X[inside]) + law.G[want_idx[inside]]
    np.testing.assert_allclose(U[inside & ok], want[ok[inside]], rtol=1e-12, atol=1e-12)
    assert np.all(np.isnan(U[~inside & ok]))
    assert np.array_equal(law(X[:50]), U[:50], equal_nan=True)


def test_voronoi_is_a_partition():
    """Harness check: every point of the box is in exactly one Voronoi cell."""
    law = location_law("voronoi2d")
    X = np.random.default_rng(13).uniform(-1, 1, size=(2000, 2))
    counts = np.zeros(X.shape[0], dtype=int)
    for A, b in zip(law.A, law.b, strict=True):
        counts += np.all(X @ A.T <= b + LOC_TOL, axis=1)
    assert np.all(counts[~brute_locate(law, X)[1]] == 1)


def test_evaluate_outside_is_nan():
    law = location_law("voronoi2d")
    X = np.array([[5.0, 0.0], [0.0, -1.5], [1e9, 1e9], [-1.0000001, 0.0], [np.nan, 0.0],
                  [np.inf, 0.0], [-np.inf, -np.inf]])
    assert np.all(law.locate(X) == -1)
    U = law.evaluate(X)
    assert U.shape == (X.shape[0], law.m)
    assert np.all(np.isnan(U))
    # a single point (n,) is accepted
    assert law.evaluate(np.array([0.1, 0.2])).shape == (1, law.m)
    assert np.all(np.isfinite(law.evaluate(np.array([0.1, 0.2]))))


def test_empty_law_locates_nothing():
    law = ce.ExplicitLaw(A=[], b=[], F=np.zeros((0, 1, 2)), G=np.zeros((0, 1)),
                         states=("a", "b"), inputs=("u",))
    X = np.random.default_rng(0).normal(size=(10, 2))
    assert np.all(law.locate(X) == -1)
    assert law.evaluate(X).shape == (10, 1)
    assert np.all(np.isnan(law.evaluate(X)))


def test_wrong_dimension_is_an_error():
    law = location_law("voronoi2d")
    with pytest.raises(ValueError):
        law.locate(np.zeros((3, 3)))


# ---------------------------------------------------------------------------------------
# save / load
# ---------------------------------------------------------------------------------------


def assert_same_law(a: ce.ExplicitLaw, b: ce.ExplicitLaw, X: np.ndarray) -> None:
    assert a.num_regions == b.num_regions
    for Aa, Ab, ba, bb in zip(a.A, b.A, a.b, b.b, strict=True):
        np.testing.assert_array_equal(Aa, Ab)
        np.testing.assert_array_equal(ba, bb)
    np.testing.assert_array_equal(a.F, b.F)
    np.testing.assert_array_equal(a.G, b.G)
    assert a.states == b.states and a.inputs == b.inputs
    assert a.fingerprint == b.fingerprint
    assert a.meta == b.meta
    np.testing.assert_array_equal(a.locate(X), b.locate(X))
    np.testing.assert_array_equal(a.evaluate(X), b.evaluate(X))


@pytest.mark.parametrize("fname", ["double_integrator.toml", "magnetic_pointer_c.toml",
                                   "navigation.toml"])
@pytest.mark.parametrize("located_before_save", [False, True])
def test_round_trip_synthesised(tmp_path, fname, located_before_save, example_law):
    law = example_law(fname)[1]
    lo, hi = np.min(law.boxes[0], axis=0), np.max(law.boxes[1], axis=0)
    X = np.random.default_rng(5).uniform(lo - 1, hi + 1, size=(2000, lo.shape[0]))
    fresh = ce.ExplicitLaw(A=law.A, b=law.b, F=law.F, G=law.G, states=law.states,
                           inputs=law.inputs, fingerprint=law.fingerprint,
                           meta=json.loads(json.dumps(law.meta)))
    if located_before_save:
        fresh.locate(X[:1])  # computes (and saves) the bounding boxes
    path = fresh.save(tmp_path / "sub" / "law.npz")
    assert path.exists()
    loaded = ce.ExplicitLaw.load(path)
    assert_same_law(fresh, loaded, X)
    assert np.any(loaded.locate(X) >= 0) and np.any(loaded.locate(X) < 0)
    # saving the loaded law again gives the same law
    again = ce.ExplicitLaw.load(loaded.save(tmp_path / "again.npz"))
    assert_same_law(fresh, again, X)


def test_round_trip_voronoi(tmp_path):
    law = location_law("voronoi3d")
    X = np.random.default_rng(6).uniform(-1.1, 1.1, size=(N_POINTS, 3))
    loaded = ce.ExplicitLaw.load(law.save(tmp_path / "v.npz"))
    assert_same_law(law, loaded, X)


def test_round_trip_empty_law(tmp_path):
    law = ce.ExplicitLaw(A=[], b=[], F=np.zeros((0, 1, 2)), G=np.zeros((0, 1)),
                         states=("a", "b"), inputs=("u",), meta={"regions": 0})
    loaded = ce.ExplicitLaw.load(law.save(tmp_path / "empty.npz"))
    assert loaded.num_regions == 0
    assert loaded.states == ("a", "b") and loaded.inputs == ("u",)
    assert np.all(loaded.locate(np.zeros((4, 2))) == -1)


def test_save_is_atomic_and_overwrites(tmp_path):
    a = location_law("voronoi2d")
    b = voronoi_law(50, 2, seed=9)
    path = tmp_path / "law.npz"
    a.save(path)
    b.save(path)
    assert ce.ExplicitLaw.load(path).num_regions == 50
    assert [p.name for p in tmp_path.iterdir()] == ["law.npz"]  # no temporary files left


# ---- malformed files ------------------------------------------------------------------


_GOOD: dict[str, bytes] = {}


@pytest.fixture
def good_bytes(example_law) -> bytes:
    """A valid law file (the double integrator, with bounding boxes) as bytes."""
    if "di" not in _GOOD:
        law = example_law("double_integrator.toml")[1]
        fresh = ce.ExplicitLaw(A=law.A, b=law.b, F=law.F, G=law.G, states=law.states,
                               inputs=law.inputs, fingerprint=law.fingerprint, meta=law.meta)
        fresh.locate(np.zeros((1, 2)))  # so that the file carries box_lo / box_hi too
        with tempfile.TemporaryDirectory() as d:
            _GOOD["di"] = fresh.save(Path(d) / "good.npz").read_bytes()
    return _GOOD["di"]


def arrays_of(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def write_npz(path: Path, arrays: dict) -> Path:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


def assert_spec_error(path) -> None:
    """Loading must raise SpecError and nothing else (not even a subclass-less ValueError)."""
    try:
        ce.ExplicitLaw.load(path)
    except ce.SpecError:
        return
    except Exception as exc:  # pragma: no cover - this is the failure being tested
        pytest.fail(f"load raised {type(exc).__name__} instead of SpecError: {exc}")
    pytest.fail("load accepted a malformed law file")


def test_good_file_loads(tmp_path, good_bytes, example_law):
    p = tmp_path / "good.npz"
    p.write_bytes(good_bytes)
    law = ce.ExplicitLaw.load(p)
    assert law.num_regions == example_law("double_integrator.toml")[1].num_regions
    # and re-written with plain np.savez from its arrays it still loads (harness check)
    law2 = ce.ExplicitLaw.load(write_npz(tmp_path / "re.npz", arrays_of(good_bytes)))
    assert law2.num_regions == law.num_regions


def test_missing_file_is_a_spec_error(tmp_path):
    assert_spec_error(tmp_path / "nope.npz")


def test_directory_is_a_spec_error(tmp_path):
    assert_spec_error(tmp_path)


@pytest.mark.parametrize("frac", [0.0, 0.01, 0.1, 0.5, 0.9, 0.99])
def test_truncated_file_is_a_spec_error(tmp_path, frac, good_bytes):
    data = good_bytes
    p = tmp_path / "trunc.npz"
    p.write_bytes(data[: int(frac * len(data))])
    assert_spec_error(p)


def test_truncated_by_one_byte_is_a_spec_error(tmp_path, good_bytes):
    data = good_bytes
    p = tmp_path / "trunc.npz"
    p.write_bytes(data[:-1])
    assert_spec_error(p)


@pytest.mark.parametrize("seed", range(6))
def test_random_bytes_are_a_spec_error(tmp_path, seed):
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 256, size=int(rng.integers(1, 5000)), dtype=np.uint8).tobytes()
    if seed % 2:  # looks like a zip / npy from the first bytes
        raw = (b"PK\x03\x04" if seed % 4 == 1 else b"\x93NUMPY") + raw
    p = tmp_path / "rand.npz"
    p.write_bytes(raw)
    assert_spec_error(p)


@pytest.mark.parametrize("seed", range(6))
def test_corrupted_bytes_are_a_spec_error(tmp_path, seed, good_bytes):
    """Flip bytes inside the compressed payload (CRC / zlib errors)."""
    data = bytearray(good_bytes)
    rng = np.random.default_rng(100 + seed)
    for pos in rng.integers(40, len(data) // 2, size=4):
        data[pos] ^= 0xFF
    p = tmp_path / "flip.npz"
    p.write_bytes(bytes(data))
    try:
        ce.ExplicitLaw.load(p)
    except ce.SpecError:
        return
    except Exception as exc:
        pytest.fail(f"load raised {type(exc).__name__} instead of SpecError: {exc}")
    # the flips may have hit bytes that do not matter (zip padding): then the law must be
    # intact -- anything else would be a silently corrupted law
    good = tmp_path / "good.npz"
    good.write_bytes(good_bytes)
    assert_same_law(ce.ExplicitLaw.load(p), ce.ExplicitLaw.load(good),
                    np.random.default_rng(0).uniform(-10, 10, (500, 2)))


def test_plain_text_and_npy_files_are_spec_errors(tmp_path):
    p = tmp_path / "text.npz"
    p.write_text("name = 'not a law'\n")
    assert_spec_error(p)
    q = tmp_path / "arr.npz"
    with open(q, "wb") as fh:
        np.save(fh, np.arange(10.0))
    assert_spec_error(q)
    r = tmp_path / "zip.npz"
    with zipfile.ZipFile(r, "w") as zf:
        zf.writestr("readme.txt", "hello")
    assert_spec_error(r)


KEYS = ["format", "A", "b", "offsets", "F", "G", "states", "inputs", "fingerprint", "meta"]


@pytest.mark.parametrize("key", KEYS)
def test_missing_array_is_a_spec_error(tmp_path, key, good_bytes):
    arrays = arrays_of(good_bytes)
    del arrays[key]
    assert_spec_error(write_npz(tmp_path / "m.npz", arrays))


def _mutations() -> dict[str, callable]:
    def set_(key, fn):
        def mut(arrs):
            arrs[key] = fn(arrs[key])
            return arrs

        return mut

    def nan_at(a):
        a = a.astype(float).copy()
        a.flat[a.size // 2] = np.nan
        return a

    def inf_at(a):
        a = a.astype(float).copy()
        a.flat[0] = np.inf
        return a

    return {
        "nan_A": set_("A", nan_at),
        "nan_b": set_("b", nan_at),
        "nan_F": set_("F", nan_at),
        "nan_G": set_("G", nan_at),
        "inf_b": set_("b", inf_at),
        "inf_A": set_("A", inf_at),
        "nan_box_lo": set_("box_lo", nan_at),
        "nan_box_hi": set_("box_hi", nan_at),
        "box_wrong_shape": set_("box_lo", lambda a: a[:-1]),
        "wrong_format": set_("format", lambda a: np.array("codev-explicit-law/999")),
        "format_number": set_("format", lambda a: np.array(1.0)),
        "offsets_not_from_0": set_("offsets", lambda a: a + 1),
        "offsets_decreasing": set_("offsets", lambda a: np.concatenate([a[:1], a[2:3], a[1:2],
                                                                         a[3:]])),
        "offsets_short": set_("offsets", lambda a: a[:-1]),
        "offsets_float": set_("offsets", lambda a: a.astype(float)),
        "offsets_2d": set_("offsets", lambda a: a[None, :]),
        "A_wrong_columns": set_("A", lambda a: np.hstack([a, a[:, :1]])),
        "A_1d": set_("A", lambda a: a.ravel()),
        "b_2d": set_("b", lambda a: a[:, None]),
        "F_2d": set_("F", lambda a: a[:, 0, :]),
        "F_text": set_("F", lambda a: np.full(a.shape, "x")),
        "G_wrong_shape": set_("G", lambda a: a[:-1]),
        "G_text": set_("G", lambda a: np.full(a.shape, "nan?")),
        "meta_not_json": set_("meta", lambda a: np.array("{not json")),
        "A_complex": set_("A", lambda a: a.astype(complex) + 1j),
    }


MUTATIONS = _mutations()


@pytest.mark.parametrize("name", list(MUTATIONS))
def test_malformed_content_is_a_spec_error(tmp_path, name, good_bytes):
    arrays = MUTATIONS[name](arrays_of(good_bytes))
    assert_spec_error(write_npz(tmp_path / f"{name}.npz", arrays))


def test_pickled_object_array_is_a_spec_error(tmp_path, good_bytes):
    arrays = arrays_of(good_bytes)
    arrays["meta"] = np.array([{"x": 1}], dtype=object)
    assert_spec_error(write_npz(tmp_path / "obj.npz", arrays))


# ---- more malformed content: every array's dtype kind, shape and finiteness -----------


def _more_mutations() -> dict[str, callable]:
    def set_(key, fn):
        def mut(arrs):
            arrs[key] = fn(arrs[key])
            return arrs

        return mut

    def drop(key):
        def mut(arrs):
            del arrs[key]
            return arrs

        return mut

    def inf_at(a):
        a = a.astype(float).copy()
        a.flat[-1] = -np.inf
        return a

    def half_offsets(a):
        a = a.astype(float).copy()
        a[1] += 0.5
        return a

    return {
        "offsets_non_integer": set_("offsets", half_offsets),
        "offsets_complex": set_("offsets", lambda a: a.astype(complex)),
        "offsets_text": set_("offsets", lambda a: a.astype(str)),
        "offsets_bool": set_("offsets", lambda a: a.astype(bool)),
        "offsets_beyond_rows": set_("offsets", lambda a: np.concatenate([a[:-1], [a[-1] + 3]])),
        "b_complex": set_("b", lambda a: a + 0.5j),
        "F_complex": set_("F", lambda a: a.astype(complex)),  # imaginary part 0: still no
        "G_complex": set_("G", lambda a: a + 1j),
        "F_bool": set_("F", lambda a: a != 0),
        "A_text": set_("A", lambda a: a.astype(str)),
        "b_text": set_("b", lambda a: a.astype(str)),
        "states_short": set_("states", lambda a: a[:1]),
        "states_long": set_("states", lambda a: np.append(a, "extra")),
        "states_numbers": set_("states", lambda a: np.arange(a.size, dtype=float)),
        "states_2d": set_("states", lambda a: a[None, :]),
        "inputs_long": set_("inputs", lambda a: np.append(a, "v")),
        "fingerprint_number": set_("fingerprint", lambda a: np.array(3.0)),
        "fingerprint_list": set_("fingerprint", lambda a: np.array([str(a), str(a)])),
        "meta_number": set_("meta", lambda a: np.array(2.0)),
        "meta_json_list": set_("meta", lambda a: np.array("[1, 2]")),
        "meta_deep": set_("meta", lambda a: np.array("[" * 100_000 + "]" * 100_000)),
        "inf_box_hi": set_("box_hi", inf_at),
        "box_complex": set_("box_hi", lambda a: a + 1j),
        "box_text": set_("box_lo", lambda a: a.astype(str)),
        "box_hi_wrong_shape": set_("box_hi", lambda a: a[:, :1]),
        "box_transposed": set_("box_lo", lambda a: a.T),
        "box_1d": set_("box_hi", lambda a: a.ravel()),
        "box_reversed": lambda arrs: {**arrs, "box_lo": arrs["box_hi"], "box_hi": arrs["box_lo"]},
        "box_lo_alone": drop("box_hi"),
        "box_hi_alone": drop("box_lo"),
        "nan_domain_A": set_("domain_A", lambda a: a * np.nan),
        "inf_domain_b": set_("domain_b", inf_at),
        "domain_A_wrong_columns": set_("domain_A", lambda a: np.hstack([a, a[:, :1]])),
        "domain_A_1d": set_("domain_A", lambda a: a.ravel()),
        "domain_b_short": set_("domain_b", lambda a: a[:-1]),
        "domain_b_2d": set_("domain_b", lambda a: a[:, None]),
        "domain_complex": set_("domain_A", lambda a: a + 1j),
        "domain_text": set_("domain_b", lambda a: a.astype(str)),
        "domain_A_alone": drop("domain_b"),
        "domain_b_alone": drop("domain_A"),
    }


MORE_MUTATIONS = _more_mutations()


@pytest.mark.parametrize("name", list(MORE_MUTATIONS))
def test_more_malformed_content_is_a_spec_error(tmp_path, name, good_file_with_domain):
    arrays = MORE_MUTATIONS[name](arrays_of(good_file_with_domain))
    path = write_npz(tmp_path / f"{name}.npz", arrays)
    assert_spec_error(path)
    with pytest.raises(ce.SpecError) as err:
        ce.ExplicitLaw.load(path)
    # one line, naming the file and the array
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg
    assert err.value.field and err.value.field in arrays_of(good_file_with_domain)


@pytest.fixture
def good_file_with_domain(example_law) -> bytes:
    """A valid law file (the double integrator) with bounding boxes and the domain."""
    if "di_domain" not in _GOOD:
        law = example_law("double_integrator.toml")[1]
        assert law.domain_A is not None
        fresh = ce.ExplicitLaw(A=law.A, b=law.b, F=law.F, G=law.G, states=law.states,
                               inputs=law.inputs, fingerprint=law.fingerprint, meta=law.meta,
                               domain_A=law.domain_A, domain_b=law.domain_b)
        fresh.locate(np.zeros((1, 2)))
        with tempfile.TemporaryDirectory() as d:
            _GOOD["di_domain"] = fresh.save(Path(d) / "good.npz").read_bytes()
    arrays = arrays_of(_GOOD["di_domain"])
    assert {"box_lo", "box_hi", "domain_A", "domain_b"} <= set(arrays)
    return _GOOD["di_domain"]


def test_valid_variants_load(tmp_path, good_bytes):
    """Integer arrays for numbers, unnamed states/inputs, no boxes / no domain: all fine."""
    arrays = arrays_of(good_bytes)
    law = ce.ExplicitLaw.load(write_npz(tmp_path / "good.npz", arrays))
    X = np.random.default_rng(0).uniform(-10, 10, (500, 2))
    variants = {
        "int_G": {**arrays, "G": np.round(arrays["G"]).astype(np.int32)},
        "uint_offsets": {**arrays, "offsets": arrays["offsets"].astype(np.uint16)},
        "unnamed": {**arrays, "states": np.array([], dtype=str),
                    "inputs": np.array([], dtype=str)},
        "no_boxes": {k: v for k, v in arrays.items() if not k.startswith("box")},
        "no_domain": {k: v for k, v in arrays.items() if not k.startswith("domain")},
    }
    for name, arrs in variants.items():
        got = ce.ExplicitLaw.load(write_npz(tmp_path / f"{name}.npz", arrs))
        assert got.num_regions == law.num_regions, name
        np.testing.assert_array_equal(got.locate(X), law.locate(X))
        if name == "unnamed":
            assert got.states == () and got.inputs == ()
        if name == "int_G":
            np.testing.assert_array_equal(got.G, np.round(law.G))
    # an unnamed law round-trips
    unnamed = ce.ExplicitLaw(A=law.A, b=law.b, F=law.F, G=law.G)
    again = ce.ExplicitLaw.load(unnamed.save(tmp_path / "unnamed2.npz"))
    np.testing.assert_array_equal(again.locate(X), law.locate(X))


def test_empty_law_with_boxes_round_trips(tmp_path):
    law = ce.ExplicitLaw(A=[], b=[], F=np.zeros((0, 1, 2)), G=np.zeros((0, 1)),
                         states=("a", "b"), inputs=("u",))
    law.locate(np.zeros((1, 2)))  # computes (empty) boxes, saved too
    loaded = ce.ExplicitLaw.load(law.save(tmp_path / "empty.npz"))
    assert loaded.num_regions == 0 and loaded.states == ("a", "b")
    assert np.all(loaded.locate(np.zeros((3, 2))) == -1)


def test_a_law_without_regions_meets_no_box():
    # (the slow fuzzer: a sample time of 9.2e18 s leaves the feasible set no interior, the
    # law no region, and its (0, 0) boxes broke the reach engine's box test)
    import codev_engine as ce

    text = (Path(__file__).resolve().parents[2] / "examples" / "double_integrator.toml").read_text()
    text = text.replace("sample_time = 1.0", "sample_time = 9_223_372_036_854_775_807")
    law = ce.synthesize(ce.loads_spec(text))
    assert law.num_regions == 0
    lo, hi = law.boxes
    assert lo.shape == hi.shape == (0, 2)
    assert law.regions_meeting(np.zeros(2), np.ones(2)).size == 0
    assert ce.verify(ce.loads_spec(text), law).verdict == "unsafe"
