"""The SHA-256 of a file, read in blocks: what a manifest records of each file it lists
and checks when the file is read (the sharded law's shards, facets and halos)."""

from __future__ import annotations

import hashlib
import os

__all__ = ["file_sha256"]


def file_sha256(path: str | os.PathLike) -> str:
    """The hex SHA-256 of a file's bytes, read 1 MiB at a time.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    str
        64 hex digits.
    """
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
