"""The one checked ``.npz`` artifact format (codev_engine.io.npz): tags, no pickle."""

from __future__ import annotations

import numpy as np
import pytest

from codev_engine.errors import SpecError
from codev_engine.io.npz import NpzFormat, load_npz, real, save_npz
from codev_engine.reach.tube import TUBE_FORMAT, Tube

THING = NpzFormat("thing file", "codev-thing/2", "thing", reads=("codev-thing/1",))


def _x(data: dict) -> np.ndarray:
    return real(data, "x", ndim=1)


def test_save_writes_the_tag_and_load_builds(tmp_path):
    path = save_npz(tmp_path / "a" / "t.npz", THING, {"x": np.arange(3.0)})
    with np.load(path, allow_pickle=False) as z:
        assert str(z["format"]) == "codev-thing/2"
        assert sorted(z.files) == ["format", "x"]
    np.testing.assert_array_equal(load_npz(path, THING, _x), [0.0, 1.0, 2.0])
    assert [p.name for p in path.parent.iterdir()] == ["t.npz"]  # no temporary left


def test_an_older_readable_tag_reaches_the_builder(tmp_path):
    path = tmp_path / "old.npz"
    np.savez(path, format=np.array("codev-thing/1"), x=np.ones(2))
    seen = load_npz(path, THING, lambda d: str(d["format"]))
    assert seen == "codev-thing/1"


@pytest.mark.parametrize(
    ("arrays", "reason"),
    [
        ({"format": np.array("codev-thing/99")}, "unsupported thing format 'codev-thing/99'"),
        ({"format": np.array(1.0)}, "must be a single string"),
        ({"x": np.ones(2)}, "missing array"),
    ],
)
def test_a_bad_tag_is_refused_naming_file_and_field(tmp_path, arrays, reason):
    path = tmp_path / "bad.npz"
    np.savez(path, **arrays)
    with pytest.raises(SpecError) as info:
        load_npz(path, THING, _x)
    err = info.value
    assert err.field == "format" and err.file == str(path)
    assert reason in err.reason


def test_the_builder_error_gets_the_file_name(tmp_path):
    path = save_npz(tmp_path / "t.npz", THING, {"x": np.array([1.0, np.nan])})
    with pytest.raises(SpecError) as info:
        load_npz(path, THING, _x)
    assert (info.value.file, info.value.field) == (str(path), "x")
    assert "non-finite" in info.value.reason


def test_untagged_format_has_no_format_array(tmp_path):
    neutral = NpzFormat("program file (.npz)")
    path = save_npz(tmp_path / "p.npz", neutral, {"x": np.ones(1)})
    with np.load(path, allow_pickle=False) as z:
        assert z.files == ["x"]
    assert load_npz(path, neutral, _x).shape == (1,)


def test_tube_reads_files_without_tag_but_not_with_a_foreign_one(tmp_path):
    arrays = dict(t_start=np.zeros(1), t_end=np.ones(1), lower=np.zeros((1, 2)),
                  upper=np.ones((1, 2)))
    np.savez(tmp_path / "plain.npz", **arrays)
    assert Tube.load(tmp_path / "plain.npz").num_boxes == 1
    np.savez(tmp_path / "tagged.npz", format=np.array(TUBE_FORMAT), **arrays)
    assert Tube.load(tmp_path / "tagged.npz").num_boxes == 1
    np.savez(tmp_path / "law.npz", format=np.array("codev-explicit-law/1"), **arrays)
    with pytest.raises(SpecError, match="unsupported tube format 'codev-explicit-law/1'"):
        Tube.load(tmp_path / "law.npz")


class _Trap:
    """Unpickling this object would create the file ``marker``."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))


@pytest.mark.parametrize("key", ["format", "x"])
def test_pickled_arrays_are_never_unpickled(tmp_path, key):
    marker = tmp_path / "UNPICKLED"
    arrays = {"format": np.array("codev-thing/2"), "x": np.ones(2)}
    arrays[key] = np.array([_Trap(str(marker))], dtype=object)
    path = tmp_path / "obj.npz"
    np.savez(path, **arrays)
    with pytest.raises(SpecError, match="pickled") as info:
        load_npz(path, THING, _x)
    assert info.value.field == key
    assert not marker.exists()
