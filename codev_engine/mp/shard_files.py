"""The sharded search's checked files: arrays in an ``.npz`` with their SHA-256, written
atomically (``os.replace`` of a fsynced temporary file), refused on reading when torn or
altered (``SolverError`` naming the file). The rounds (``sharded.py``) and the end's cut by
space (``shard_space.py``) both write and read them: one module, so neither imports the
other's internals.
"""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import numpy as np

from codev_engine.errors import SolverError
from codev_engine.io.atomic import write_npz
from codev_engine.mp.solution import RegionArrays

__all__: list[str] = []


def _digest(arrays: dict[str, np.ndarray]) -> str:
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _write(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` as an .npz at ``path``, atomically, with their SHA-256."""
    write_npz(path, {"sha256": np.array(_digest(arrays)), **arrays}, compress=False)


def _read(path: Path) -> dict[str, np.ndarray]:
    """A file of :func:`_write`, checked; ``SolverError`` naming it when it is not whole."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise SolverError(f"{path}: unreadable shard file ({exc})") from exc
    digest = str(arrays.pop("sha256", ""))
    if digest != _digest(arrays):
        raise SolverError(f"{path}: shard file fails its checksum (torn or altered)")
    return arrays


def _read_parts(folder: Path) -> list[RegionArrays]:
    """The regions of one shard's checked ``part-<round>.npz`` files, round by round."""
    parts = []
    files = sorted(folder.glob("part-*.npz"), key=lambda p: int(p.stem.split("-")[1]))
    for path in files:
        a = _read(path)
        if a["K"].shape[0]:
            parts.append(regions_of(a))
    return parts


#: a RegionArrays' arrays, as the checked files name them
_FIELDS = ("A", "b", "offsets", "K", "k", "active", "active_offsets", "implied", "shared_A",
           "shared_b")


def region_arrays(regions: RegionArrays) -> dict[str, np.ndarray]:
    """The arrays of ``regions`` by name, for :func:`_write` (:func:`regions_of` reads them)."""
    return {name: getattr(regions, name) for name in _FIELDS}


def regions_of(a: dict[str, np.ndarray]) -> RegionArrays:
    """The regions in a file's arrays (:func:`region_arrays`' names)."""
    return RegionArrays(*(a[name] for name in _FIELDS))
