"""A session's folder on disk: metadata, lock, journal, spec snapshots and artifact index.

This module knows the files and how to trust them, not what a stage computes::

    session.json          format tag, the engine that created it, creation time
    spec.toml             the spec of the latest run (or the workbench's edit)
    specs/<sha[:16]>.toml every spec a run used or spec.toml held, by the SHA-256 of its text
    journal.jsonl         one JSON object per stage executed
    artifacts/<stage>-<key[:16]>.<ext>   a stage's cached result (a file, or a folder of
                          files with a manifest: a law written as shards)
    artifacts/index.json  artifact name -> stage, key, SHA-256, size, engine
    .lock                 serialises read-modify-write of the journal and the index

Every file is written atomically (temporary file, then rename: :mod:`codev_engine.io.atomic`);
a writer killed midway leaves a ``.tmp-*`` entry, which no reader looks at and the next run
removes (:func:`remove_temporaries`: those no live writer holds). An artifact enters the
index only after its rename, and is trusted only if the index lists it
under the same key and its bytes still hash to the indexed SHA-256. A folder artifact is
renamed into place whole (:func:`codev_engine.io.atomic.atomic_folder`); the index holds the
SHA-256 of its manifest, which holds the SHA-256 and the size of each of its files. Opening
it checks what is cheap and catches a torn or swapped folder: the manifest's SHA-256, and
every file it lists there with its size (``os.stat``, no byte read: a law of 13 GB is not
read to be opened). Each file's SHA-256 is checked by its reader when it first reads it
(``law_shards.ShardedLaw``); one found damaged then (``errors.DamagedFileError``) marks the
artifact damaged in the index (:func:`mark_damaged`), and the next run recomputes it. Reads
never unpickle or run anything: JSON, TOML text and hashes only.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import stat
from collections.abc import Collection, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from codev_engine.errors import SpecError
from codev_engine.io.atomic import remove_stale, write_text
from codev_engine.version import __version__

__all__ = [
    "SESSION_FORMAT",
    "SessionError",
    "append_journal",
    "artifact_path",
    "check_artifact",
    "create_folder",
    "file_sha",
    "locked",
    "mark_damaged",
    "now",
    "read_journal",
    "read_jsonl",
    "read_meta",
    "read_spec_snapshot",
    "register_artifact",
    "remove_temporaries",
    "save_spec_text",
    "sha",
    "snapshot_path",
    "spec_path",
]

SESSION_FORMAT = "codev-session/1"
#: the manifest of a folder artifact: ``{"shards": [{"file", "sha256", "bytes"}, ...]}`` (a
#: law written as shards: ``codev_engine.law_shards.MANIFEST``, whose format it is; a manifest
#: written before ``bytes`` was recorded is checked without sizes)
FOLDER_MANIFEST = "shards.json"


class SessionError(SpecError):
    """A session folder that cannot be used as asked (bad input: exit status 2).

    Parameters
    ----------
    reason : str
        What is wrong.
    file : str, optional
        The session file or folder concerned.
    field : str, optional
        The field of that file (or the run option) that is wrong.
    """


# --------------------------------------------------------------------------------------------
# Hashes, time, lock
# --------------------------------------------------------------------------------------------


def sha(data: bytes) -> str:
    """SHA-256 of ``data`` as 64 lowercase hex digits.

    Parameters
    ----------
    data : bytes

    Returns
    -------
    str
    """
    return hashlib.sha256(data).hexdigest()


def file_sha(path: Path) -> str:
    """SHA-256 of a file's bytes (64 hex digits), read in 1 MiB blocks.

    Parameters
    ----------
    path : Path

    Returns
    -------
    str
    """
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def now() -> str:
    """The current UTC time, ISO 8601 to the second (journal and metadata timestamps)."""
    return datetime.now(UTC).isoformat(timespec="seconds")


@contextlib.contextmanager
def locked(folder: Path) -> Iterator[None]:
    """Serialise read-modify-write of the journal and index between processes (POSIX).

    Parameters
    ----------
    folder : Path
        The session folder; its ``.lock`` is held (``flock``) for the ``with`` body.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX: atomic renames still protect files
        yield
        return
    with (folder / ".lock").open("a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


# --------------------------------------------------------------------------------------------
# The folder
# --------------------------------------------------------------------------------------------


def read_meta(path: Path) -> dict[str, Any]:
    """The ``session.json`` of an existing session.

    Parameters
    ----------
    path : Path
        The session folder.

    Returns
    -------
    dict
        Its metadata: ``format``, ``engine``, ``created``.

    Raises
    ------
    SessionError
        ``path`` is missing, not a folder, has no readable ``session.json``, or one of
        another format.
    """
    if not path.exists():
        raise SessionError("no such session folder", file=str(path))
    if not path.is_dir():
        raise SessionError("not a folder (a session is a folder)", file=str(path))
    meta_file = path / "session.json"
    if not meta_file.is_file():
        raise SessionError(
            "not a codev session (no session.json); create one with "
            "`codev run SPEC --session DIR`",
            file=str(path),
        )
    try:
        meta = json.loads(meta_file.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:
        raise SessionError(
            f"unreadable session.json ({exc.__class__.__name__})", file=str(meta_file)
        ) from None
    if not isinstance(meta, dict) or not isinstance(meta.get("format"), str):
        raise SessionError("not a codev session file (no format)", file=str(meta_file))
    if meta["format"] != SESSION_FORMAT:
        raise SessionError(
            f"session format {meta['format']!r} is not {SESSION_FORMAT!r} (written by "
            f"codev {meta.get('engine', '?')}; this is codev {__version__})",
            file=str(meta_file),
            field="format",
        )
    return meta


def create_folder(path: Path) -> dict[str, Any]:
    """Make ``path`` (new, or an empty folder) a session.

    Parameters
    ----------
    path : Path
        The folder; created with its parents if missing.

    Returns
    -------
    dict
        The ``session.json`` written.

    Raises
    ------
    SessionError
        ``path`` is a file, or a folder holding anything but an interrupted creation's
        leftovers.
    """
    if path.exists() and not path.is_dir():
        raise SessionError("exists and is not a folder", file=str(path))
    if path.is_dir() and not _empty(path):
        raise SessionError(
            "not a codev session (no session.json) and not empty: refusing to write into it",
            file=str(path),
        )
    path.mkdir(parents=True, exist_ok=True)
    meta = {"format": SESSION_FORMAT, "engine": __version__, "created": now()}
    write_text(path / "session.json", json.dumps(meta, indent=2) + "\n")
    (path / "artifacts").mkdir(exist_ok=True)
    return meta


def remove_temporaries(folder: Path) -> list[str]:
    """Remove what killed writers left in the session: the ``.tmp-*`` files and folders of
    its folder, ``specs/`` and ``artifacts/`` that no live writer holds
    (:func:`codev_engine.io.atomic.remove_stale`; a run's writes hold theirs, so a
    concurrent run loses nothing). No reader looks at them: this frees their space.

    Parameters
    ----------
    folder : Path
        The session folder.

    Returns
    -------
    list of str
        The paths removed, relative to ``folder``.
    """
    removed = []
    for sub in (".", "specs", "artifacts"):
        removed += [str(Path(sub) / name) for name in remove_stale(folder / sub)]
    return removed


def _empty(folder: Path) -> bool:
    """Nothing in ``folder`` but what an interrupted :func:`create_folder` leaves behind
    (temporary files, an empty ``artifacts/``)."""
    for p in folder.iterdir():
        if p.name.startswith(".tmp-") and p.is_file():
            continue
        if p.name == "artifacts" and p.is_dir() and not any(p.iterdir()):
            continue
        return False
    return True


# --------------------------------------------------------------------------------------------
# The journal
# --------------------------------------------------------------------------------------------

_RECORD_FIELDS = {
    "run": int,
    "stage": str,
    "key": str,
    "spec": str,
    "options": dict,
    "started": str,
    "seconds": (int, float),
    "status": str,
    "outcome": dict,
    "details": dict,
    "engine": str,
}


def read_journal(folder: Path, stages: Collection[str]) -> list[dict[str, Any]]:
    """Every journal record, oldest first.

    Parameters
    ----------
    folder : Path
        The session folder.
    stages : collection of str
        The stage names a record may carry.

    Returns
    -------
    list of dict
        The records, each checked field by field; empty without a journal.

    Raises
    ------
    SessionError
        An unreadable journal, or a line that is not a valid record.
    """
    file = folder / "journal.jsonl"
    records = []
    for i, rec in read_jsonl(file, "journal"):
        _check_record(rec, f"{file}:{i}", stages)
        records.append(rec)
    return records


def read_jsonl(file: Path, what: str) -> list[tuple[int, object]]:
    """The JSON values of a JSON-lines file (a journal), blank lines skipped.

    Parameters
    ----------
    file : Path
    what : str
        What the file is, for messages ("journal", "sweep journal").

    Returns
    -------
    list of (int, object)
        Each value with its line number (from 1); empty when the file does not exist.

    Raises
    ------
    SessionError
        An unreadable file, or a line that is not valid JSON (naming the file and line).
    """
    if not file.exists():
        return []
    try:
        lines = file.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError(f"unreadable {what} ({exc})", file=str(file)) from None
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append((i, json.loads(line)))
        except (ValueError, RecursionError):
            raise SessionError(f"line {i} is not valid JSON", file=str(file)) from None
    return out


def append_journal(folder: Path, records: list[dict[str, Any]], stages: Collection[str]) -> int:
    """Add one run's records to the journal under the next run number.

    The whole file is rewritten atomically under the lock, so concurrent runs get distinct
    numbers and no record is lost.

    Parameters
    ----------
    folder : Path
        The session folder.
    records : list of dict
        The run's records; their ``run`` is set to the number given.
    stages : collection of str
        The stage names a record may carry (the journal is read back first).

    Returns
    -------
    int
        The run number.
    """
    with locked(folder):
        old = read_journal(folder, stages)
        run = max((r["run"] for r in old), default=0) + 1
        for r in records:
            r["run"] = run
        lines = [json.dumps(r, sort_keys=True) for r in old + records]
        write_text(folder / "journal.jsonl", "\n".join(lines) + "\n")
    return run


def _check_record(rec: Any, where: str, stages: Collection[str]) -> None:
    """A journal record must have the expected fields with the expected types."""
    if not isinstance(rec, dict):
        raise SessionError("a journal record must be a JSON object", file=where)
    for name, typ in _RECORD_FIELDS.items():
        if name not in rec:
            raise SessionError("missing field", file=where, field=name)
        if not isinstance(rec[name], typ) or isinstance(rec[name], bool):
            raise SessionError("wrong type", file=where, field=name)
    if rec["stage"] not in stages:
        raise SessionError(f"unknown stage {rec['stage']!r}", file=where, field="stage")
    if rec["status"] not in ("computed", "cached", "failed"):
        raise SessionError(f"unknown status {rec['status']!r}", file=where, field="status")
    if len(rec["spec"]) != 64 or any(c not in "0123456789abcdef" for c in rec["spec"]):
        raise SessionError("not a SHA-256 hex digest", file=where, field="spec")


# --------------------------------------------------------------------------------------------
# Specs
# --------------------------------------------------------------------------------------------


def spec_path(folder: Path) -> Path:
    """The session's current spec, ``spec.toml``.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    Path
    """
    return folder / "spec.toml"


def snapshot_path(folder: Path, spec_sha: str) -> Path:
    """Where the spec whose text has SHA-256 ``spec_sha`` is kept.

    Parameters
    ----------
    folder : Path
    spec_sha : str
        64 hex digits.

    Returns
    -------
    Path
        ``specs/<spec_sha[:16]>.toml``.
    """
    return folder / "specs" / f"{spec_sha[:16]}.toml"


def save_spec_text(folder: Path, text: str) -> str:
    """Make ``text`` the session's ``spec.toml``.

    Every spec that was ever ``spec.toml`` keeps a snapshot (the one replaced included), so
    an edit saved by the workbench loses nothing.

    Parameters
    ----------
    folder : Path
    text : str
        The spec's TOML.

    Returns
    -------
    str
        The SHA-256 of ``text``.
    """
    spec_sha = sha(text.encode())
    _snapshot(folder, text)
    current = spec_path(folder)
    try:
        old: str | None = current.read_text("utf-8")
    except (OSError, UnicodeDecodeError):
        old = None  # absent or unreadable: nothing worth keeping
    if old == text:
        return spec_sha
    if old is not None and old.strip():
        _snapshot(folder, old)
    write_text(current, text)
    return spec_sha


def _snapshot(folder: Path, text: str) -> None:
    snap = snapshot_path(folder, sha(text.encode()))
    if not snap.exists():
        write_text(snap, text)


def read_spec_snapshot(folder: Path, spec_sha: str) -> str:
    """The text of the snapshot with SHA-256 ``spec_sha``, checked against it.

    Parameters
    ----------
    folder : Path
    spec_sha : str
        64 hex digits, as a journal record's ``spec``.

    Returns
    -------
    str

    Raises
    ------
    SessionError
        The snapshot is missing, unreadable, or its text no longer hashes to ``spec_sha``.
    """
    snap = snapshot_path(folder, spec_sha)
    try:
        text = snap.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise SessionError("the spec this run used is missing", file=str(snap)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError(f"unreadable spec ({exc})", file=str(snap)) from None
    if sha(text.encode()) != spec_sha:
        raise SessionError("the stored spec was edited (hash mismatch)", file=str(snap))
    return text


# --------------------------------------------------------------------------------------------
# Artifacts
# --------------------------------------------------------------------------------------------


def artifact_path(folder: Path, stage: str, key: str, ext: str) -> Path:
    """Where a stage's artifact for a key goes.

    Parameters
    ----------
    folder : Path
    stage : str
    key : str
        The stage key (64 hex digits).
    ext : str
        The stage's extension, without the dot.

    Returns
    -------
    Path
        ``artifacts/<stage>-<key[:16]>.<ext>``.
    """
    return folder / "artifacts" / f"{stage}-{key[:16]}.{ext}"


def _index(folder: Path) -> dict[str, dict[str, Any]]:
    file = folder / "artifacts" / "index.json"
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except (OSError, ValueError, RecursionError, UnicodeDecodeError):
        return {}  # a damaged index only costs recomputation
    return data if isinstance(data, dict) else {}


def register_artifact(folder: Path, path: Path, stage: str, key: str) -> str:
    """Enter a completely written artifact in the index.

    Parameters
    ----------
    folder : Path
    path : Path
        The artifact (renamed into place already).
    stage, key : str
        Its stage and key.

    Returns
    -------
    str
        The artifact's SHA-256 (a folder's: its manifest's).
    """
    if path.is_dir():  # (a folder: its manifest's hash, which holds its files' hashes)
        digest = file_sha(path / FOLDER_MANIFEST)
        size = sum(p.stat().st_size for p in path.iterdir() if p.is_file())
    else:
        digest, size = file_sha(path), path.stat().st_size
    with locked(folder):
        index = _index(folder)
        index[path.name] = {
            "stage": stage,
            "key": key,
            "sha256": digest,
            "bytes": size,
            "engine": __version__,
        }
        if path.is_dir():
            index[path.name]["folder"] = True
        write_text(folder / "artifacts" / "index.json", json.dumps(index, indent=1, sort_keys=True))
    return digest


def check_artifact(folder: Path, path: Path, key: str) -> str | None:
    """Why the artifact at ``path`` cannot be used for ``key``.

    The file must be regular, listed in the index under ``key``, and hash to the indexed
    SHA-256; a folder must be listed as one, not marked damaged (:func:`mark_damaged`), its
    manifest hash to the indexed SHA-256 and each of its files be there with the size the
    manifest records (their SHA-256 is their reader's to check, when it reads them).
    (Whether its loader accepts it is the stage's business.)

    Parameters
    ----------
    folder : Path
    path : Path
    key : str

    Returns
    -------
    str or None
        None when it can be used, "missing" when there is no file, else the reason.
    """
    if not path.exists():
        return "missing"
    entry = _index(folder).get(path.name)
    if path.is_dir() and not path.is_symlink():
        if not isinstance(entry, dict) or entry.get("key") != key or not entry.get("folder"):
            return "not in the artifact index (an interrupted write?)"
        return _check_folder(path, entry)
    if not path.is_file():
        return "not a regular file"
    if not isinstance(entry, dict) or entry.get("key") != key:
        return "not in the artifact index (an interrupted write?)"
    if isinstance(entry.get("damaged"), str):  # (found when read, by an earlier run)
        return entry["damaged"]
    if entry.get("sha256") != file_sha(path):
        return "its content does not match the recorded SHA-256 (damaged or edited)"
    return None


def _check_folder(path: Path, entry: dict[str, Any]) -> str | None:
    """Why a folder artifact cannot be used, from what is cheap to check: its manifest must
    hash to the index's SHA-256 and every file it lists must be there with the size it
    records (a stat each: no file is read). A torn or swapped folder is found here; a file
    damaged in place, its size kept, is found by its reader's SHA-256 when first read
    (:func:`mark_damaged` then, and the next run recomputes it)."""
    if isinstance(entry.get("damaged"), str):  # (found when read, by an earlier run)
        return entry["damaged"]
    manifest = path / FOLDER_MANIFEST
    if not manifest.is_file():
        return f"no {FOLDER_MANIFEST} (an interrupted write?)"
    try:
        text = manifest.read_bytes()  # (read once: hashed, then parsed)
    except OSError as exc:
        return f"its {FOLDER_MANIFEST} is unreadable ({exc.__class__.__name__})"
    if entry.get("sha256") != sha(text):
        return f"its {FOLDER_MANIFEST} does not match the recorded SHA-256 (damaged or edited)"
    from codev_engine.law_shards import manifest_files

    try:
        listed = manifest_files(json.loads(text.decode("utf-8"))["shards"])
    except (OSError, ValueError, RecursionError, UnicodeDecodeError, KeyError, TypeError,
            AttributeError):
        return f"its {FOLDER_MANIFEST} does not list its files"
    for name, size in listed:
        file = path / name
        try:
            st = None if Path(name).name != name else file.stat()
        except OSError:
            st = None
        if st is None or not stat.S_ISREG(st.st_mode):
            return f"{name} is missing"
        if size is not None and st.st_size != size:  # (None: a manifest without sizes)
            return (f"{name}: its size is not the one its manifest records ({st.st_size} "
                    f"bytes, not {size}: damaged, truncated or swapped)")
    return None


def mark_damaged(folder: Path, file: str | os.PathLike, why: str) -> str | None:
    """Mark the artifact that holds ``file`` damaged in the index, so that the next run
    recomputes it: ``file`` was found damaged when read (``errors.DamagedFileError``: a
    shard of a law, whose SHA-256 is checked when read, not when the artifact is opened).

    Parameters
    ----------
    folder : Path
        The session folder.
    file : path-like
        The damaged file: an artifact, or a file of a folder artifact.
    why : str
        What its reader found (the reason the next run's warning gives).

    Returns
    -------
    str or None
        The artifact's name, or None when ``file`` is no artifact of this session's index
        (a law from elsewhere: nothing to mark).
    """
    file = Path(file)
    artifacts = folder / "artifacts"
    for path in (file, file.parent):
        if path.parent.resolve() != artifacts.resolve():
            continue
        with locked(folder):
            index = _index(folder)
            entry = index.get(path.name)
            if not isinstance(entry, dict):
                return None
            part = f"{file.name}: " if path != file else ""
            entry["damaged"] = f"{part}{why} (found when read)"
            write_text(artifacts / "index.json", json.dumps(index, indent=1, sort_keys=True))
        return path.name
    return None
