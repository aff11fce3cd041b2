"""``.npz`` artifacts: one checked format, no pickle, every array checked, errors name it.

Each kind of artifact (law, model, solution, tube, verification result, program) is an
:class:`NpzFormat`: what the file is, for messages, and the tag written into its
``format`` array. :func:`save_npz` writes the tag and the arrays atomically (``atomic.py``:
temp file + rename); :func:`load_npz` reads them with ``allow_pickle=False``, checks the tag
and hands the arrays to the caller's builder, which validates them with the typed getters
below (``SpecError`` naming the array, ``field``); the file name is added here.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from codev_engine.errors import SpecError
from codev_engine.io.atomic import write_npz

T = TypeVar("T")

__all__ = [
    "NpzFormat",
    "save_npz",
    "load_npz",
    "read_npz",
    "array",
    "real",
    "text",
    "names",
    "check_identifiers",
    "pair",
    "offsets",
]


@dataclass(frozen=True)
class NpzFormat:
    """One kind of ``.npz`` artifact.

    Attributes
    ----------
    what : str
        What the file is, in error messages: ``"law file"``, ``"tube file"``.
    tag : str or None
        The format tag written as the 0-d text array ``format`` and required on reading
        (``"codev-explicit-law/1"``; bumped on incompatible changes). None: no tag (a
        neutral convention shared with other tools, e.g. mp test sets).
    name : str
        The artifact in ``unsupported {name} format '...'``.
    reads : tuple of str
        Older tags still read (the builder tells them apart by ``data["format"]``).
    untagged : bool
        Also read files without a ``format`` array (written by other tools); a tag, when
        present, must still be known.
    """

    what: str
    tag: str | None = None
    name: str = ""
    reads: tuple[str, ...] = ()
    untagged: bool = False

    def check(self, data: dict[str, np.ndarray]) -> None:
        """Refuse a missing (unless ``untagged``), malformed or unknown ``format`` tag.

        Parameters
        ----------
        data : dict of str to ndarray
            The arrays of the file, as from :func:`read_npz`.

        Raises
        ------
        SpecError
            On the ``format`` array (``field``).
        """
        if self.tag is None or (self.untagged and "format" not in data):
            return
        tag = text(data, "format")
        if tag != self.tag and tag not in self.reads:
            raise SpecError(f"unsupported {self.name} format {tag!r}", field="format")


def save_npz(
    path: str | os.PathLike,
    fmt: NpzFormat,
    arrays: dict[str, np.ndarray],
    *,
    compress: bool = True,
) -> Path:
    """Write ``arrays`` and the format tag of ``fmt`` to ``path`` atomically (no pickle).

    Parameters
    ----------
    path : path-like
        The file to write (replaced whole, or left as it was).
    fmt : NpzFormat
        The artifact's format; its tag, if any, is written as the array ``format``.
    arrays : dict of str to ndarray
        The arrays, by name (numeric or text: no object arrays).
    compress : bool
        Deflate the arrays (see :func:`codev_engine.io.atomic.write_npz`).

    Returns
    -------
    Path
        The path written.
    """
    if fmt.tag is not None:
        arrays = {"format": np.array(fmt.tag), **arrays}
    return write_npz(path, arrays, compress=compress)


def load_npz(path: str | os.PathLike, fmt: NpzFormat, build: Callable[[dict], T]) -> T:
    """Read an artifact of format ``fmt`` and build it with ``build(arrays)``.

    The file is read with :func:`read_npz` (never unpickled), its tag checked
    (:meth:`NpzFormat.check`), then ``build`` validates the arrays (``data`` still holds
    ``format``) and raises ``SpecError`` naming the array.

    Parameters
    ----------
    path : path-like
    fmt : NpzFormat
        The format the file must have.
    build : callable
        ``build(data)`` makes the artifact from the file's arrays (``dict`` of str to
        ndarray), validating them with the getters of this module.

    Returns
    -------
    T
        What ``build`` returns.

    Raises
    ------
    SpecError
        Naming the file, the array (``field``) and what is wrong.
    """
    data = read_npz(path, fmt.what)
    try:
        fmt.check(data)
        return build(data)
    except SpecError as exc:
        raise exc.with_file(str(path)) from None


def read_npz(path: str | os.PathLike, what: str) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file, loaded with ``allow_pickle=False``.

    Parameters
    ----------
    path : path-like
    what : str
        What the file should be ("law file", "tube file", ...), for the error message.

    Raises
    ------
    SpecError
        The file is missing or is not a readable npz (truncated, not a zip, object arrays).
    """
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise SpecError("no such file", file=str(path)) from None
    except IsADirectoryError:
        raise SpecError(f"is a directory, not a {what}", file=str(path)) from None
    except Exception as exc:  # not a zip / npy, or a pickle (refused)
        raise SpecError(
            f"not a readable {what} ({exc.__class__.__name__})", file=str(path)
        ) from None
    if not isinstance(z, np.lib.npyio.NpzFile):  # a bare .npy array
        raise SpecError(f"not a {what}: a single .npy array, not an .npz archive", file=str(path))
    out: dict[str, np.ndarray] = {}
    with z:
        for k in z.files:
            try:
                out[k] = z[k]
            except ValueError as exc:
                if "pickle" in str(exc):  # an object array: never unpickled
                    raise SpecError(
                        "holds Python objects (pickled data), refused: must be a numeric "
                        "or text array",
                        file=str(path),
                        field=k,
                    ) from None
                raise SpecError(
                    f"unreadable array ({exc.__class__.__name__})", file=str(path), field=k
                ) from None
            except Exception as exc:  # a truncated / corrupt member
                raise SpecError(
                    f"unreadable array ({exc.__class__.__name__}): the {what} is damaged",
                    file=str(path),
                    field=k,
                ) from None
    return out


def offsets(data: dict[str, np.ndarray], key: str, count: int, rows: int) -> np.ndarray:
    """Offsets of ``count`` consecutive blocks over ``rows`` rows: integers, shape
    ``(count + 1,)``, rising from 0 to ``rows``.

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    key : str
        The array's name.
    count : int
        The number of blocks.
    rows : int
        The number of rows the blocks cover.

    Returns
    -------
    (count + 1,) ndarray of int64

    Raises
    ------
    SpecError
        Naming ``key``, when the array is missing or not such offsets.
    """
    off = array(data, key)
    if off.dtype.kind not in "iu":
        raise SpecError(f"must be integers, got dtype {off.dtype}", field=key)
    if off.shape != (count + 1,):
        raise SpecError(f"must have shape ({count + 1},), got {off.shape}", field=key)
    if np.any(off < 0) or np.any(off > rows):
        raise SpecError(f"must lie in [0, {rows}]", field=key)
    off = off.astype(np.int64, copy=False)
    if off[0] != 0 or off[-1] != rows or np.any(np.diff(off) < 0):
        raise SpecError(f"must increase from 0 to {rows}", field=key)
    return off


def array(data: dict[str, np.ndarray], key: str) -> np.ndarray:
    """The array ``key``.

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    key : str
        The array's name.

    Returns
    -------
    ndarray

    Raises
    ------
    SpecError
        Naming ``key``, when it is missing.
    """
    if key not in data:
        raise SpecError("missing array", field=key)
    return data[key]


def real(
    data: dict[str, np.ndarray],
    key: str,
    *,
    ndim: int | None = None,
    shape: tuple[int, ...] | None = None,
) -> np.ndarray:
    """A finite real array (float or integer dtype) of the given ndim / shape, as float.

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    key : str
        The array's name.
    ndim : int, optional
        The number of dimensions it must have.
    shape : tuple of int, optional
        The shape it must have.

    Returns
    -------
    ndarray of float

    Raises
    ------
    SpecError
        Naming ``key``, when it is missing, not real, of another shape or not finite.
    """
    arr = array(data, key)
    if arr.dtype.kind not in "fiu":
        raise SpecError(f"must hold real numbers, got dtype {arr.dtype}", field=key)
    if shape is not None and arr.shape != shape:
        raise SpecError(f"must have shape {shape}, got {arr.shape}", field=key)
    if ndim is not None and arr.ndim != ndim:
        raise SpecError(f"must be {ndim}-dimensional, got shape {arr.shape}", field=key)
    arr = arr.astype(float, copy=False)  # (no second copy of a solution's gigabytes of rows)
    flat = arr.reshape(-1)
    for i in range(0, flat.size, _FINITE_CHUNK):  # (a bool per entry at once: 1 GB on 036)
        if not np.all(np.isfinite(flat[i : i + _FINITE_CHUNK])):
            raise SpecError("non-finite numbers (NaN or inf)", field=key)
    return arr


#: entries checked for NaN / inf at a time by :func:`real`
_FINITE_CHUNK = 1 << 22


def text(data: dict[str, np.ndarray], key: str) -> str:
    """A single string (0-d text array).

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    key : str
        The array's name.

    Returns
    -------
    str

    Raises
    ------
    SpecError
        Naming ``key``, when it is missing or not a 0-d text array.
    """
    arr = array(data, key)
    if arr.dtype.kind != "U" or arr.ndim != 0:
        raise SpecError(
            f"must be a single string, got dtype {arr.dtype} shape {arr.shape}", field=key
        )
    return str(arr)


#: a name codev writes into a law file (the spec's names, ``prev_<input>``, ``ref_<...>``)
IDENTIFIER_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def names(
    data: dict[str, np.ndarray],
    key: str,
    count: int | None,
    *,
    identifiers: bool = False,
) -> tuple[str, ...]:
    """A 1-D text array of ``count`` names (or none: unnamed); any count if ``None``.

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    key : str
        The array's name.
    count : int or None
        The number of names required (an empty array is always accepted).
    identifiers : bool
        Each name must be an identifier (``IDENTIFIER_RE``: ASCII letters, digits and
        '_', not starting with a digit): names that reach generated code, figures and
        recordings hold nothing else (no quote, newline or control character).

    Returns
    -------
    tuple of str

    Raises
    ------
    SpecError
        Naming ``key`` (and the name's index), when it is missing, not a list of names, of
        another length or, with ``identifiers``, holds a name that is not an identifier.
    """
    arr = array(data, key)
    if arr.ndim != 1 or (arr.dtype.kind != "U" and arr.size):
        raise SpecError(
            f"must be a list of names, got dtype {arr.dtype} shape {arr.shape}", field=key
        )
    if count is not None and arr.size not in (0, count):
        raise SpecError(f"must have {count} names, got {arr.size}", field=key)
    out = tuple(str(s) for s in arr)
    if identifiers:
        check_identifiers(out, key)
    return out


def check_identifiers(values: tuple[str, ...], key: str) -> None:
    """Refuse a name that is not an identifier (``IDENTIFIER_RE``).

    Parameters
    ----------
    values : tuple of str
        The names.
    key : str
        The array they are (or will be) stored as, for the message.

    Raises
    ------
    SpecError
        Naming ``key[i]`` and showing the name escaped (``ascii``, cut at 40 characters).
    """
    for i, name in enumerate(values):
        if not isinstance(name, str) or not IDENTIFIER_RE.fullmatch(name):
            shown = ascii(str(name)[:40]) + ("..." if len(str(name)) > 40 else "")
            raise SpecError(
                f"name {shown} is not an identifier (ASCII letters, digits and '_', not "
                "starting with a digit): refused",
                field=f"{key}[{i}]",
            )


def pair(data: dict[str, np.ndarray], a: str, b: str) -> None:
    """``a`` and ``b`` come together or not at all.

    Parameters
    ----------
    data : dict of str to ndarray
        The arrays of the file, as from :func:`read_npz`.
    a, b : str
        The two arrays' names.

    Raises
    ------
    SpecError
        Naming the one that is missing.
    """
    if (a in data) != (b in data):
        raise SpecError("missing array", field=b if a in data else a)
