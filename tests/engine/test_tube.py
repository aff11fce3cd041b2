"""Reachtubes (codev_engine.tube): time-stamped boxes, their queries and the .npz format."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.errors import SpecError
from codev_engine.reach.tube import TUBE_FORMAT, Tube


def _tube() -> Tube:
    """Three boxes in 2-D: [0, 1] and [1, 2] in sequence, a second branch over [0.5, 1.5]."""
    return Tube(
        t_start=np.array([0.0, 1.0, 0.5]),
        t_end=np.array([1.0, 2.0, 1.5]),
        lower=np.array([[0.0, 0.0], [1.0, -1.0], [5.0, 5.0]]),
        upper=np.array([[1.0, 1.0], [2.0, 0.0], [6.0, 7.0]]),
        branch=np.array([0, 0, 1]),
    )


def _assert_same(a: Tube, b: Tube) -> None:
    for name in ("t_start", "t_end", "lower", "upper", "branch"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)


# ---------------------------------------------------------------------------------------
# save / load
# ---------------------------------------------------------------------------------------


def test_save_load_round_trip(tmp_path):
    tube = _tube()
    path = tube.save(tmp_path / "sub" / "dir" / "t.npz")  # parents are created
    assert path.is_file()
    back = Tube.load(path)
    _assert_same(tube, back)
    assert back.num_boxes == 3
    with np.load(path, allow_pickle=False) as z:
        assert {"t_start", "t_end", "lower", "upper", "branch"} <= set(z.files)
        assert str(z["format"]) == TUBE_FORMAT
    # no temporary file left next to it
    assert [p.name for p in path.parent.iterdir()] == ["t.npz"]


def test_round_trip_preserves_bits(tmp_path):
    rng = np.random.default_rng(3)
    K, n = 50, 4
    t0 = np.sort(rng.uniform(0, 10, K))
    lo = rng.normal(size=(K, n))
    tube = Tube(t0, t0 + 0.1 / 3, lo, lo + rng.uniform(0, 1e-13, (K, n)), np.arange(K))
    back = Tube.load(tube.save(tmp_path / "t.npz"))
    _assert_same(tube, back)


def test_empty_tube_round_trip(tmp_path):
    tube = Tube.empty(3)
    assert tube.num_boxes == 0
    back = Tube.load(tube.save(tmp_path / "e.npz"))
    assert back.num_boxes == 0 and back.lower.shape == (0, 3)
    assert not back.contains(np.array([0.0]), np.zeros((1, 3))).any()


def test_load_without_branch_defaults_to_zero(tmp_path):
    path = tmp_path / "nb.npz"
    np.savez(
        path,
        t_start=np.array([0.0]),
        t_end=np.array([1.0]),
        lower=np.zeros((1, 2)),
        upper=np.ones((1, 2)),
    )
    tube = Tube.load(path)
    assert tube.branch.shape == (1,) and tube.branch[0] == 0


def test_save_overwrites(tmp_path):
    path = tmp_path / "t.npz"
    Tube.empty(2).save(path)
    _tube().save(path)
    assert Tube.load(path).num_boxes == 3


def test_verify_tube_round_trip(tmp_path, example_law):
    from codev_engine.reach.verification import verify

    problem, law = example_law("double_integrator.toml")
    tube = verify(problem, law).tube
    back = Tube.load(tube.save(tmp_path / "di.npz"))
    _assert_same(tube, back)
    assert back.lower.shape == (tube.num_boxes, problem.plant.n)


# ---------------------------------------------------------------------------------------
# corrupt files
# ---------------------------------------------------------------------------------------


def test_load_garbage_raises_spec_error(tmp_path):
    path = tmp_path / "bad.npz"
    path.write_bytes(b"this is not a zip file at all\x00\x01\x02")
    with pytest.raises(SpecError, match="tube") as info:
        Tube.load(path)
    assert str(path) in str(info.value)


def test_load_truncated_file_raises_spec_error(tmp_path):
    good = _tube().save(tmp_path / "good.npz")
    data = good.read_bytes()
    bad = tmp_path / "truncated.npz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(SpecError):
        Tube.load(bad)


def test_load_missing_file_raises_spec_error(tmp_path):
    with pytest.raises(SpecError):
        Tube.load(tmp_path / "nope.npz")


def test_load_missing_array_raises_spec_error(tmp_path):
    path = tmp_path / "m.npz"
    np.savez(path, t_start=np.array([0.0]), t_end=np.array([1.0]), lower=np.zeros((1, 2)))
    with pytest.raises(SpecError, match="upper"):
        Tube.load(path)


@pytest.mark.parametrize(
    "arrays",
    [
        # t_end has another length
        dict(t_start=np.zeros(2), t_end=np.ones(3), lower=np.zeros((2, 2)), upper=np.ones((2, 2))),
        # lower has another number of rows
        dict(t_start=np.zeros(2), t_end=np.ones(2), lower=np.zeros((3, 2)), upper=np.ones((3, 2))),
        # upper's shape differs from lower's
        dict(t_start=np.zeros(2), t_end=np.ones(2), lower=np.zeros((2, 2)), upper=np.ones((2, 3))),
    ],
)
def test_load_inconsistent_shapes_raises_spec_error(tmp_path, arrays):
    path = tmp_path / "s.npz"
    np.savez(path, **arrays)
    with pytest.raises(SpecError, match="shape"):
        Tube.load(path)


def test_load_pickled_object_array_raises_spec_error(tmp_path):
    path = tmp_path / "p.npz"
    obj = np.empty(1, dtype=object)
    obj[0] = {"evil": 1}
    np.savez(path, t_start=obj, t_end=np.ones(1), lower=np.zeros((1, 2)), upper=np.ones((1, 2)))
    with pytest.raises(SpecError):
        Tube.load(path)


def test_load_zip_that_is_not_an_npz(tmp_path):
    path = tmp_path / "z.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("readme.txt", "hello")
    with pytest.raises(SpecError):
        Tube.load(path)


def test_spec_error_is_a_codev_error():
    assert issubclass(SpecError, ce.CodevError)


# ---------------------------------------------------------------------------------------
# queries
# ---------------------------------------------------------------------------------------


def test_at_selects_active_boxes_with_closed_intervals():
    tube = _tube()
    lo, hi = tube.at(0.25)
    np.testing.assert_array_equal(lo, [[0.0, 0.0]])
    lo, _ = tube.at(1.0)  # both ends are inclusive: all three boxes
    assert lo.shape == (3, 2)
    lo, _ = tube.at(2.0)
    np.testing.assert_array_equal(lo, [[1.0, -1.0]])
    lo, hi = tube.at(2.5)
    assert lo.shape == (0, 2) and hi.shape == (0, 2)


def test_hull_at():
    tube = _tube()
    lo, hi = tube.hull_at(0.25)
    np.testing.assert_array_equal(lo, [0.0, 0.0])
    np.testing.assert_array_equal(hi, [1.0, 1.0])
    lo, hi = tube.hull_at(0.75)  # boxes 0 and 2
    np.testing.assert_array_equal(lo, [0.0, 0.0])
    np.testing.assert_array_equal(hi, [6.0, 7.0])
    lo, hi = tube.hull_at(1.0)  # all three
    np.testing.assert_array_equal(lo, [0.0, -1.0])
    np.testing.assert_array_equal(hi, [6.0, 7.0])
    lo, hi = tube.hull_at(1.75)  # box 1 only
    np.testing.assert_array_equal(lo, [1.0, -1.0])
    np.testing.assert_array_equal(hi, [2.0, 0.0])
    lo, hi = tube.hull_at(-0.1)  # nothing active: NaN
    assert lo.shape == (2,) and np.all(np.isnan(lo)) and np.all(np.isnan(hi))


def test_contains():
    tube = _tube()
    t = np.array([0.5, 0.5, 0.5, 0.0, 1.0, 1.0, 1.5, 1.5, 2.0, 2.0, 2.5, -1.0, 0.75])
    X = np.array(
        [
            [0.5, 0.5],  # inside box 0
            [1.5, 0.5],  # outside box 0 and box 2
            [5.5, 6.0],  # inside box 2 (other branch)
            [0.0, 1.0],  # on box 0's boundary (closed)
            [1.0, 0.0],  # on the boundary of boxes 0 and 1 at their shared time
            [1.5, -0.5],  # in box 1 at its start time
            [1.5, -0.5],  # box 1 mid-interval
            [0.5, 0.5],  # box 0 is over at 1.5
            [2.0, -1.0],  # corner of box 1 at its end
            [5.5, 6.0],  # box 2 is over at 2.0
            [1.5, -0.5],  # no box active at 2.5
            [0.5, 0.5],  # nor at -1
            [3.0, 3.0],  # between the two branches' boxes at 0.75: in neither
        ]
    )
    expected = [True, False, True, True, True, True, True, False, True, False, False, False, False]
    np.testing.assert_array_equal(tube.contains(t, X), expected)


def test_contains_tolerance():
    tube = _tube()
    t = np.array([0.5, 0.5, 0.5])
    X = np.array([[1.0 + 1e-10, 0.5], [-5e-10, 0.5], [1.0 + 2e-9, 0.5]])
    np.testing.assert_array_equal(tube.contains(t, X), [False, False, False])
    np.testing.assert_array_equal(tube.contains(t, X, 1e-9), [True, True, False])


def test_contains_accepts_one_state_and_keeps_order():
    tube = _tube()
    assert tube.contains(np.array([0.5]), np.array([0.5, 0.5])).tolist() == [True]
    # contains sorts the boxes internally; the answers stay in the caller's order
    rng = np.random.default_rng(0)
    t = rng.uniform(0, 2, 200)
    X = rng.uniform(-1, 7, (200, 2))
    got = tube.contains(t, X)
    for p in range(200):
        lo, hi = tube.at(t[p])
        want = bool(np.any(np.all((lo <= X[p]) & (X[p] <= hi), axis=1)))
        assert got[p] == want


def test_concatenate():
    a, b = _tube(), Tube.empty(2)
    c = Tube.concatenate([a, b, a], 2)
    assert c.num_boxes == 6
    np.testing.assert_array_equal(c.lower[3:], a.lower)
    assert Tube.concatenate([], 2).num_boxes == 0
    assert Tube.concatenate([], 2).lower.shape == (0, 2)
