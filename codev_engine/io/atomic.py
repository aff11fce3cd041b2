"""Atomic artifact writes: a temporary file in the same folder, then a rename.

A reader never sees a half-written file: either the old artifact or the new one. A writer
killed midway leaves at most a ``.tmp-*`` file (or folder: :func:`atomic_folder`), which no
reader looks at, and which :func:`remove_stale` removes later: while it is written, its
writer holds a lock on it (``flock``, released by the kernel when the writer dies however
it dies: SIGKILL included), so a temporary nobody holds is one nobody will finish.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: temporaries are told stale by age alone
    fcntl = None  # type: ignore[assignment]

__all__ = ["STALE_AFTER", "atomic_folder", "atomic_path", "remove_stale", "remove_stale_beside",
           "write_npz", "write_text"]

#: seconds after which an unlocked ``.tmp-*`` entry is stale (:func:`remove_stale`): the
#: lock is taken microseconds after the entry is made, the margin covers that window (and a
#: clock a little off on a shared file system); where no lock can be taken (not POSIX, or a
#: file system without ``flock``) the age alone decides, and a writer is assumed done or
#: dead after a day
STALE_AFTER = 60.0
_STALE_UNLOCKED = 86400.0
#: the random part of a temporary's name (:func:`_sibling`: 6 bytes in hex)
_TOKEN = "[0-9a-f]{12}"


def _sibling(path: Path, create: Callable[[Path], object], made: list[Path]) -> Path:
    """A new ``.tmp-<random hex><suffix of path>`` beside ``path``, made by ``create`` (which
    must fail with ``FileExistsError`` on a name taken); the missing parents are created.
    Its name is put in ``made`` before it is made: a caller interrupted (Ctrl-C) as it is
    made, before this returns, still knows what to remove."""
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = path.parent / f".tmp-{secrets.token_hex(6)}{path.suffix}"
        made[:] = [tmp]
        try:
            create(tmp)
            return tmp
        except FileExistsError:  # pragma: no cover - 48 random bits
            made.clear()
            continue


@contextmanager
def _held(tmp: Path) -> Iterator[None]:
    """Hold an exclusive ``flock`` on ``tmp`` (a file or a folder) for the ``with`` body:
    the mark of a live writer that :func:`remove_stale` respects. The kernel drops it when
    the descriptor is closed, the writer's death included."""
    if fcntl is None:  # pragma: no cover - not POSIX
        yield
        return
    fd = os.open(tmp, os.O_RDONLY)  # (a folder opens read-only too: flock takes any fd)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            # (a file system without flock on a read-only descriptor, NFS's emulation: the
            # cleaner cannot lock it either, and goes by age alone there)
            pass
        yield
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it is renamed onto ``path``.

    The temporary file is created empty (mode 0666 less the umask, like ``open``), so a
    writer may reopen it by name (e.g. a library that takes a path). When the ``with`` body
    returns, the file is flushed to disk (``fsync``) and renamed onto ``path``; on any
    exception (``KeyboardInterrupt`` included) it is removed, ``path`` is untouched and the
    exception propagates.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write; its missing parent folders are created.

    Yields
    ------
    Path
        ``.tmp-<random hex><suffix of path>`` in the folder of ``path``.

    Notes
    -----
    The temporary file is in the same folder so that the rename is atomic (``os.replace``
    is atomic only within one file system); it keeps the suffix of ``path`` for the
    libraries that choose a format, or append an extension, by the file name.
    """
    path = Path(path)
    made: list[Path] = []
    try:
        tmp = _sibling(path, lambda t: os.close(os.open(t, os.O_CREAT | os.O_EXCL | os.O_WRONLY,
                                                        0o666)), made)
        with _held(tmp):
            yield tmp
            with tmp.open("rb+") as fh:  # the data must be on disk before the rename
                os.fsync(fh.fileno())
            os.replace(tmp, path)
    except BaseException:
        for t in made:
            t.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a new temporary folder next to ``path``; on success it is renamed onto ``path``.

    What a folder artifact (a law written as shards by the workers) needs: the files are
    written in ``.tmp-<random hex><suffix of path>`` and the folder takes its name only once
    the ``with`` body returns, so a folder of that name is never a half-written one. A
    folder (or file) already at ``path`` (a damaged artifact being recomputed) is moved
    aside first and removed after the rename. On any exception (``KeyboardInterrupt``
    included) the temporary folder is removed, ``path`` is untouched and the exception
    propagates.

    Parameters
    ----------
    path : str or os.PathLike
        The folder to write; its missing parent folders are created.

    Yields
    ------
    Path
        The temporary folder, empty, in the folder of ``path`` (the rename of a folder is
        atomic within one file system only).
    """
    path = Path(path)
    made: list[Path] = []
    old = None
    try:
        tmp = _sibling(path, Path.mkdir, made)
        with _held(tmp):
            yield tmp
            if path.exists() or path.is_symlink():
                # (a folder cannot be renamed onto a folder that holds files: the old one
                # goes aside, under a name no reader looks at, and is removed once the new
                # one is in; left by a writer killed in between, remove_stale removes it)
                aside = path.parent / f".tmp-{secrets.token_hex(6)}-old{path.suffix}"
                os.replace(path, aside)
                old = aside
            os.replace(tmp, path)
    except BaseException:
        for t in made:
            shutil.rmtree(t, ignore_errors=True)
        if old is not None and not (path.exists() or path.is_symlink()):
            os.replace(old, path)  # (interrupted between the two renames: put it back)
        raise
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


def remove_stale(
    folder: str | os.PathLike,
    older_than: float = STALE_AFTER,
    *,
    names: re.Pattern[str] | None = None,
) -> list[str]:
    """Remove the ``.tmp-*`` entries of ``folder`` that no live writer holds.

    What a writer killed midway left (SIGKILL, SIGTERM, a power cut; Ctrl-C removes its
    own): a temporary file, a temporary folder, or a folder artifact's old copy moved aside.
    No reader looks at them; this frees their space. An entry is removed when nobody holds
    its lock (:func:`atomic_path` and :func:`atomic_folder` hold it from the moment it is
    made until it is renamed) and it was last modified more than ``older_than`` seconds ago
    (the lock is taken just after the entry is made). A temporary that a concurrent live
    writer is writing is never removed.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder to clean (not recursively: a temporary folder goes whole); a missing
        folder has nothing to clean.
    older_than : float
        Seconds since the entry's last modification.
    names : re.Pattern, optional
        Only the ``.tmp-*`` names it matches whole (:func:`remove_stale_beside`: in a
        folder codev does not own, only the temporaries codev's writes make there).

    Returns
    -------
    list of str
        The names removed.
    """
    folder = Path(folder)
    try:
        entries = [p for p in folder.iterdir() if p.name.startswith(".tmp-")
                   and (names is None or names.fullmatch(p.name))]
    except OSError:  # (missing, or not a folder)
        return []
    removed = []
    now = time.time()
    for p in entries:
        try:
            st = p.lstat()
        except OSError:  # (renamed or removed meanwhile by its writer)
            continue
        age = now - st.st_mtime
        if age < older_than:
            continue
        if p.is_symlink() or not (p.is_dir() or p.is_file()):
            continue  # (none of ours: a writer makes files and folders only)
        try:
            fd = os.open(p, os.O_RDONLY)
        except OSError:
            continue
        try:
            try:
                if fcntl is None:  # pragma: no cover - not POSIX
                    raise OSError(errno.ENOLCK, "no flock")
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    continue  # (held: a live writer)
                if age < _STALE_UNLOCKED:  # (no lock to tell: by age alone)
                    continue
            # (removed while locked: a writer cannot take it meanwhile, and would find it
            # gone if it tried; its name is random, no writer makes it again)
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)
            removed.append(p.name)
        finally:
            os.close(fd)
    return removed


def remove_stale_beside(*paths: str | os.PathLike) -> list[str]:
    """Remove the stale temporaries that atomic writes of ``paths`` left beside them.

    For the files written into a folder that is the user's, not codev's (an export, a
    report, a recording copied out): there only the names :func:`atomic_path` and
    :func:`atomic_folder` make for such a path (``.tmp-<12 hex digits>[-old]<its
    suffix>``) are candidates, another program's ``.tmp-*`` never; each is removed as
    :func:`remove_stale` removes (nobody holds its lock, older than ``STALE_AFTER``).

    Parameters
    ----------
    *paths : str or os.PathLike
        The files about to be written.

    Returns
    -------
    list of str
        The paths removed.
    """
    removed = []
    for path in map(Path, paths):
        ours = re.compile(rf"\.tmp-{_TOKEN}(?:-old)?{re.escape(path.suffix)}")
        removed += [str(path.parent / name)
                    for name in remove_stale(path.parent, names=ours)]
    return removed


def write_npz(
    path: str | os.PathLike, arrays: dict[str, np.ndarray], compress: bool = True
) -> Path:
    """Write ``arrays`` to ``path`` as an ``.npz``, atomically (no pickle).

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (see :func:`atomic_path`).
    arrays : dict of str to ndarray
        The arrays, by name; numeric or string arrays only, since the readers load with
        ``allow_pickle=False``.
    compress : bool
        Deflate the arrays (zlib writes ~30 MB/s here and shrinks floating-point data little:
        the 5M regions of pop_mpqp_095 took 5 minutes to write, 8.7 GB deflated).

    Returns
    -------
    Path
        The path written.
    """
    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        (np.savez_compressed if compress else np.savez)(fh, **arrays)
    return Path(path)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` as UTF-8, atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (see :func:`atomic_path`).
    text : str
        The whole content of the file.

    Returns
    -------
    Path
        The path written.
    """
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
