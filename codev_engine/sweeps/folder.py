"""A sweep as one session: a folder holding the grid, its designs' sessions and the table.

``ce.sweep(problem, grid, session=DIR)`` and ``codev sweep SPEC --set ... --session DIR``
write::

    sweep.json       the manifest: format tag, engine, the base spec's path and SHA-256, the
                     grid, every design (its swept values, its folder, the SHA-256 of its
                     TOML text), the table's rows, and the recording's SHA-256
    base.toml        the base spec's text
    journal.jsonl    one record per sweep run: when, how long, on what executor, and each
                     design's status in it ("computed", "cached" or "failed")
    <id>/            each design's session (:mod:`codev_engine.session`), ``id`` the first
                     16 hex digits of the SHA-256 of its TOML text
    sweep.rrd        the sweep's Rerun recording (:mod:`codev_engine.view.sweep_record`)

Every file is written atomically (:mod:`codev_engine.io.atomic`), the journal under the
folder's lock. :func:`read_sweep` trusts nothing it reads: the manifest is checked field by
field, the base spec and each design's stored spec must hash to the manifest's SHA-256
(a design's folder name is the hash of its text), and the recording must hash to its own.
:func:`replay_sweep` replays each design's session and rebuilds its row from the replayed
run: the sweep matches when every stage's outcome and every row (wall times aside) equal
what was recorded. Nothing is unpickled or evaluated.
"""

from __future__ import annotations

import json
import math
import re
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from codev_engine.io.atomic import write_text
from codev_engine.session import store
from codev_engine.session.store import SessionError
from codev_engine.version import __version__

__all__ = [
    "SWEEP_FORMAT",
    "check_target",
    "SweepRecord",
    "SweepReplay",
    "is_sweep",
    "read_sweep",
    "record_sweep",
    "replay_sweep",
]

SWEEP_FORMAT = "codev-sweep/1"
RECORDING = "sweep.rrd"
_FOLDER = re.compile(r"^[0-9a-f]{16}$")
_SHA = re.compile(r"^[0-9a-f]{64}$")
_ROW_FIELDS = ("regions", "synthesis_seconds", "verdict", "reason", "verification_seconds",
               "tube_width_at_horizon", "closed_loop_cost", "error")
#: row fields a folder written before them lacks (compared on replay when stored)
_OPTIONAL_ROW_FIELDS = ("width_at_horizon_of",)


@dataclass(frozen=True)
class SweepRecord:
    """A sweep folder as read and checked by :func:`read_sweep`.

    Attributes
    ----------
    path : Path
        The folder.
    spec : str
        The base spec's path when the sweep was run (for messages).
    grid : dict of str to list
        Swept field -> its values, in the order given.
    designs : list of dict
        One per cell of the grid, in the product's order: ``values``, ``folder`` (16 hex
        digits) and ``spec`` (the SHA-256 of its TOML text).
    rows : list of dict
        The table, one row per design (as :func:`codev_engine.sweeps.sweep` returns).
    recording : Path or None
        The sweep's recording, when one was written (its bytes checked).
    journal : list of dict
        The sweep's runs, oldest first.
    """

    path: Path
    spec: str
    grid: dict[str, list]
    designs: list[dict]
    rows: list[dict]
    recording: Path | None
    journal: list[dict] = field(default_factory=list)

    def design_text(self, i: int) -> str:
        """The TOML text of design ``i``, read from its session and checked by its hash.

        Parameters
        ----------
        i : int
            The design's index in :attr:`designs`.

        Returns
        -------
        str
        """
        d = self.designs[i]
        return store.read_spec_snapshot(self.path / d["folder"], d["spec"])


@dataclass
class SweepReplay:
    """The outcome of :func:`replay_sweep`.

    Attributes
    ----------
    designs : list of dict
        One per distinct design: ``folder``, ``values``, ``runs`` (session runs replayed),
        ``match`` (stage outcomes and the row), ``mismatches`` (how many stage outcomes
        differ), ``row_match`` and ``seconds``.
    seconds : float
        Wall time of the replay.
    """

    designs: list[dict]
    seconds: float

    @property
    def ok(self) -> bool:
        """Every design's stages and row match the recorded ones."""
        return all(d["match"] for d in self.designs)


def is_sweep(path: str | Path) -> bool:
    """Whether ``path`` is a sweep's folder (it has a ``sweep.json`` and is no session).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    bool
    """
    p = Path(path)
    return (p / "sweep.json").is_file() and not (p / "session.json").exists()


def check_target(folder: str | Path) -> None:
    """Refuse to run a sweep into a folder that is not a sweep's: a design's session, a
    file, or a folder holding something else.

    Parameters
    ----------
    folder : str or Path

    Raises
    ------
    SessionError
        Naming the folder and why.
    """
    root = Path(folder)
    if root.exists() and not root.is_dir():
        raise SessionError("exists and is not a folder", file=str(root))
    if (root / "session.json").exists():
        raise SessionError("is a design's session, not a sweep's folder: give the sweep a "
                           "folder of its own", file=str(root))
    if root.is_dir() and not (root / "sweep.json").exists() and any(
        not p.name.startswith(".") for p in root.iterdir()
    ):
        raise SessionError("not a sweep (no sweep.json) and not empty: refusing to write "
                           "into it", file=str(root))


def record_sweep(
    folder: str | Path,
    *,
    spec: str,
    base_text: str,
    grid: Mapping[str, Sequence[Any]],
    values: list[dict],
    texts: list[str],
    rows: list[dict],
    started: str,
    seconds: float,
    executor: str,
    workers: int,
    recording: bool = True,
    title: str = "sweep",
) -> Path:
    """Write a finished sweep's manifest, journal record and recording into its folder.

    The designs' sessions are already in ``folder/<id>`` (the workers wrote them).

    Parameters
    ----------
    folder : str or Path
        The sweep's folder.
    spec : str
        The base spec's path.
    base_text : str
        The base spec's TOML text.
    grid : mapping of str to sequence
        The grid swept.
    values : list of dict
        Each design's swept values, in the product's order.
    texts : list of str
        Each design's TOML text, likewise.
    rows : list of dict
        Each design's row, likewise.
    started : str
        When the sweep started (UTC, ISO 8601).
    seconds : float
        Its wall time.
    executor : str
        The executor's kind ("serial", "local", "cluster").
    workers : int
        Its workers.
    recording : bool
        Also write ``sweep.rrd`` (the manifest keeps its SHA-256).
    title : str
        The recording's name (the base design's name).

    Returns
    -------
    Path
        The manifest, ``folder/sweep.json``.
    """
    from codev_engine.sweeps.grid import design_id

    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    write_text(root / "base.toml", base_text)
    designs = [
        {"values": v, "folder": design_id(t), "spec": store.sha(t.encode("utf-8"))}
        for v, t in zip(values, texts, strict=True)
    ]
    statuses = {d["folder"]: _last_status(root / d["folder"]) for d in designs}
    rec_entry = None
    if recording:
        from codev_engine.view.sweep_record import write_sweep_recording

        path = write_sweep_recording(root / RECORDING, rows, list(grid), title=title)
        rec_entry = {"file": RECORDING, "sha256": store.file_sha(path),
                     "bytes": path.stat().st_size}
    manifest = {
        "format": SWEEP_FORMAT,
        "engine": __version__,
        "updated": store.now(),
        "spec": spec,
        "base": store.sha(base_text.encode("utf-8")),
        "grid": {k: list(v) for k, v in grid.items()},
        "designs": designs,
        "rows": rows,
        "recording": rec_entry,
    }
    where = root / "sweep.json"
    with store.locked(root):
        write_text(where, json.dumps(manifest, indent=1, default=_plain) + "\n")
        old = _read_journal(root)
        record = {
            "run": max((r["run"] for r in old), default=0) + 1,
            "started": started,
            "seconds": round(float(seconds), 6),
            "executor": executor,
            "workers": int(workers),
            "engine": __version__,
            "designs": [{"folder": d["folder"], "status": statuses[d["folder"]]}
                        for d in designs],
        }
        lines = [json.dumps(r, sort_keys=True) for r in [*old, record]]
        write_text(root / "journal.jsonl", "\n".join(lines) + "\n")
    return where


def _plain(v: Any) -> Any:
    return v.tolist() if hasattr(v, "tolist") else str(v)


def _last_status(folder: Path) -> str:
    """A design's status in the sweep just run: its session's last run's stages."""
    from codev_engine.session.session import Session

    try:
        journal = Session.open(folder).journal()
    except SessionError:
        return "missing"
    if not journal:
        return "missing"
    last = max(r["run"] for r in journal)
    got = {r["status"] for r in journal if r["run"] == last}
    if "failed" in got:
        return "failed"
    return "computed" if "computed" in got else "cached"


def _read_journal(root: Path) -> list[dict]:
    file = root / "journal.jsonl"
    out = []
    for i, rec in store.read_jsonl(file, "sweep journal"):
        ok = (isinstance(rec, dict) and isinstance(rec.get("run"), int)
              and isinstance(rec.get("designs"), list)
              and isinstance(rec.get("seconds"), (int, float)))
        if not ok:
            raise SessionError(f"line {i} is not a sweep run record", file=str(file))
        out.append(rec)
    return out


def read_sweep(folder: str | Path) -> SweepRecord:
    """Read a sweep's folder, checking every file it trusts.

    Parameters
    ----------
    folder : str or Path

    Returns
    -------
    SweepRecord

    Raises
    ------
    SessionError
        No such folder, no or a malformed ``sweep.json`` (naming the field), another
        format, a base spec or design spec missing or not matching its SHA-256, a design
        folder not named by its spec's hash, or a recording whose bytes changed.
    """
    root = Path(folder)
    where = root / "sweep.json"
    if not root.is_dir():
        raise SessionError("no such sweep folder", file=str(root))
    if not where.is_file():
        raise SessionError("not a sweep (no sweep.json); make one with `codev sweep SPEC "
                           "--set FIELD=V1,V2 --session DIR`", file=str(root))
    try:
        data = json.loads(where.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError, UnicodeDecodeError) as exc:
        raise SessionError(f"unreadable sweep.json ({exc.__class__.__name__})",
                           file=str(where)) from None
    file = str(where)
    if not isinstance(data, dict):
        raise SessionError("not a sweep manifest (not a JSON object)", file=file)
    if data.get("format") != SWEEP_FORMAT:
        raise SessionError(f"format {data.get('format')!r} is not {SWEEP_FORMAT!r} (written "
                           f"by codev {data.get('engine', '?')}; this is codev {__version__})",
                           file=file, field="format")
    for name, typ in (("spec", str), ("base", str), ("grid", dict), ("designs", list),
                      ("rows", list)):
        if not isinstance(data.get(name), typ):
            raise SessionError(f"missing, or not a {typ.__name__}", file=file, field=name)
    if not _SHA.match(data["base"]):
        raise SessionError("not a SHA-256 hex digest", file=file, field="base")
    try:
        base = (root / "base.toml").read_bytes()
    except OSError:
        raise SessionError("the base spec is missing", file=str(root / "base.toml")) from None
    if store.sha(base) != data["base"]:
        raise SessionError("the base spec was edited (hash mismatch)",
                           file=str(root / "base.toml"))
    grid = data["grid"]
    if not grid or not all(isinstance(v, list) and v for v in grid.values()):
        raise SessionError("every swept field needs a non-empty list", file=file, field="grid")
    count = math.prod(len(v) for v in grid.values())
    designs, rows = data["designs"], data["rows"]
    if len(designs) != count or len(rows) != count:
        raise SessionError(f"{len(designs)} designs and {len(rows)} rows for a grid of "
                           f"{count}", file=file, field="designs")
    for i, (d, row) in enumerate(zip(designs, rows, strict=True)):
        at = f"designs[{i}]"
        ok = (isinstance(d, dict) and isinstance(d.get("values"), dict)
              and isinstance(d.get("folder"), str) and _FOLDER.match(d["folder"])
              and isinstance(d.get("spec"), str) and _SHA.match(d["spec"]))
        if not ok:
            raise SessionError("needs values, a 16-hex-digit folder and a SHA-256 spec",
                               file=file, field=at)
        if d["spec"][:16] != d["folder"]:
            raise SessionError("the folder is not named by its spec's hash", file=file,
                               field=at)
        if list(d["values"]) != list(grid):
            raise SessionError("its values are not the grid's fields", file=file, field=at)
        if not isinstance(row, dict) or any(k not in row for k in _ROW_FIELDS):
            raise SessionError("not a table row", file=file, field=f"rows[{i}]")
    for folder_name, spec_sha in {d["folder"]: d["spec"] for d in designs}.items():
        store.read_spec_snapshot(root / folder_name, spec_sha)  # present and unedited
    recording = None
    rec = data.get("recording")
    if rec is not None:
        if not (isinstance(rec, dict) and rec.get("file") == RECORDING
                and isinstance(rec.get("sha256"), str)):
            raise SessionError("not a recording entry", file=file, field="recording")
        recording = root / RECORDING
        if not recording.is_file():
            raise SessionError("the sweep's recording is missing", file=str(recording))
        if store.file_sha(recording) != rec["sha256"]:
            raise SessionError("the recording does not match its SHA-256 (damaged or "
                               "edited)", file=str(recording))
    return SweepRecord(path=root, spec=data["spec"], grid=grid, designs=designs, rows=rows,
                       recording=recording, journal=_read_journal(root))


def replay_sweep(
    folder: str | Path,
    *,
    on_design: Callable[[dict], None] | None = None,
    on_event: Callable[[str, str, dict], None] | None = None,
    warn: Callable[[str], None] | None = None,
) -> SweepReplay:
    """Replay every design's session of a sweep and compare its row with the table's.

    Parameters
    ----------
    folder : str or Path
        The sweep's folder (checked by :func:`read_sweep` first).
    on_design : callable, optional
        Called with each design's entry of :attr:`SweepReplay.designs` when it is done.
    on_event, warn : callable, optional
        As for :meth:`Session.replay`.

    Returns
    -------
    SweepReplay

    Raises
    ------
    SessionError
        As :func:`read_sweep`, or a design's session cannot be replayed.
    """
    from codev_engine.pipeline import loads_spec
    from codev_engine.session.session import Session
    from codev_engine.sweeps.rows import TIMING_FIELDS, report_row

    t0 = time.perf_counter()
    sweep = read_sweep(folder)
    out: list[dict] = []
    seen: set[str] = set()
    for i, d in enumerate(sweep.designs):
        if d["folder"] in seen:  # a value listed twice is one design
            continue
        seen.add(d["folder"])
        session = Session.open(sweep.path / d["folder"])
        last: list = []

        def keep(_run, report, _mismatches, last=last) -> None:
            last[:] = [report]

        rep = session.replay(on_event=on_event, warn=warn, on_run=keep)
        problem = loads_spec(sweep.design_text(i), path=sweep.spec, check_mpc=False)
        row = report_row(problem, last[0]) if last else {}
        want = [j for j, e in enumerate(sweep.designs) if e["folder"] == d["folder"]]

        def fields(r: dict, stored: dict) -> dict:
            return {k: v for k, v in r.items() if k not in TIMING_FIELDS
                    and (k in _ROW_FIELDS or k in _OPTIONAL_ROW_FIELDS and k in stored)}

        row_match = all(_same(fields(row, sweep.rows[j]), fields(sweep.rows[j], sweep.rows[j]))
                        for j in want)
        entry = {"folder": d["folder"], "values": d["values"], "runs": rep.runs,
                 "match": rep.ok and row_match, "mismatches": len(rep.mismatches),
                 "row_match": row_match, "seconds": round(rep.seconds, 6)}
        out.append(entry)
        if on_design is not None:
            on_design(entry)
    return SweepReplay(designs=out, seconds=time.perf_counter() - t0)


def _same(a: dict, b: dict) -> bool:
    """Rows equal as the JSON they are stored as (tuples are lists there)."""
    return json.loads(json.dumps(a, default=_plain)) == json.loads(json.dumps(b, default=_plain))
