"""Opening a workbench target: a session folder, a spec file, or nothing (no Textual here).

The session is the workbench's state. Whatever the user opens, edits are written to a session
folder as they happen (``spec.toml`` when the form is valid, ``tui-draft.json`` with the raw
entries when it is not), so a crash loses nothing and ``codev replay DIR`` reproduces every
stage run from the workbench.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from codev_engine import SpecError
from codev_engine.io.atomic import write_text
from codev_engine.session import Session, SessionError

from ..bundled import example_files
from .form import FIELDS, form_from_text

__all__ = [
    "DRAFT",
    "EMPTY",
    "Opened",
    "clear_draft",
    "new_design",
    "open_target",
    "read_draft",
    "templates",
    "write_draft",
]

#: the template of a blank form (the others are the bundled examples, by file stem)
EMPTY = "empty"

#: Raw form entries of an edit that is not a valid spec yet (restored on the next start).
DRAFT = "tui-draft.json"
DRAFT_FORMAT = "codev-tui-draft/1"


@dataclass
class Opened:
    """What the workbench starts with (or switches to): a session and the form's entries.

    Attributes
    ----------
    session : Session
        The session the edits are saved to.
    values : dict of str to str
        The form's entries: field name → text (see :data:`~workbench.tui.form.FIELDS`).
    has_verify : bool
        Whether the spec has its ``[verify]`` section switched on.
    note : str or None
        Shown once at start (a restored draft, a new session).
    save_now : bool
        Write the form to the session's ``spec.toml`` at once (a spec file was opened into
        the session); otherwise ``spec.toml`` is written on the first edit, so merely
        opening a session never rewrites its spec.
    follow_name : bool
        A new session (``sessions/untitled``, or a *New* design's): the workbench renames
        it after the design's name as soon as one is typed, until a stage has run in it.
    """

    session: Session
    values: dict[str, str]
    has_verify: bool
    note: str | None = None
    save_now: bool = False
    follow_name: bool = False


def _blank() -> tuple[dict[str, str], bool]:
    return {fd.name: "" for fd in FIELDS}, True


def open_target(
    target: str | None, *, session_dir: str | None = None, sessions_root: str | Path = "sessions"
) -> Opened:
    """Resolve ``codev tui [TARGET] [--session DIR]``.

    - a session folder: open it, with its ``spec.toml`` (or the draft left by a crash);
    - a spec file: open (or create) ``--session`` or ``sessions/<spec name>`` and start from
      the file's text;
    - nothing: ``--session`` or ``sessions/untitled``, from its spec, else a blank form.

    Parameters
    ----------
    target : str or None
        A session folder or a spec file, as given on the command line (or typed in the
        Session tab); None for neither.
    session_dir : str, optional
        The ``--session`` folder, for a spec file or no target (not with a session
        folder).
    sessions_root : str or Path
        Where a session named after the spec (or ``untitled``) goes when ``session_dir``
        is not given.

    Returns
    -------
    Opened

    Raises
    ------
    SpecError
        An unreadable spec or session (the CLI prints it and exits 2); a
        :class:`~codev_engine.session.SessionError` for a session folder given with
        ``session_dir``.
    """
    root = Path(sessions_root)
    if target is not None and Path(target).is_dir():
        if session_dir is not None:
            raise SessionError("give a session folder or --session, not both", field="--session")
        session = Session.open(target)
        return _from_session(session)
    if target is not None:
        path = Path(target)
        values, has_verify = _read_form(path)
        name = values.get("name") or path.stem
        folder = Path(session_dir) if session_dir else root / _safe(name)
        existed = (folder / "session.json").exists()
        session = Session.open_or_create(folder)
        note = (
            f"opened session {folder} with {path}"
            if existed
            else f"new session {folder} for {path}"
        )
        return Opened(session, values, has_verify, note, save_now=True)
    folder = Path(session_dir) if session_dir else root / "untitled"
    existed = (folder / "session.json").exists()
    session = Session.open_or_create(folder)
    if existed:
        return _from_session(session)
    values, has_verify = _blank()
    return Opened(
        session,
        values,
        has_verify,
        f"new session {folder}: fill in the plant, or open a spec (Session tab)",
        follow_name=session_dir is None,
    )


def templates() -> list[tuple[str, str]]:
    """What a new design can start from: a blank form, or a copy of a bundled example.

    Returns
    -------
    list of tuple of (str, str)
        ``(key, description)``: :data:`EMPTY` first, then each bundled spec
        (``workbench.examples``, i.e. ``examples/*.toml``) by file stem, described by the
        first comment line of the file.
    """
    out = [(EMPTY, "a blank form: type the plant from scratch")]
    for f in example_files():
        if not f.name.endswith(".toml"):
            continue
        about = ""
        for line in f.read_text(encoding="utf-8").splitlines():
            if line.startswith("#"):
                about = line.lstrip("#").strip()
                break
        out.append((f.name[: -len(".toml")], about))
    return out


def new_design(template: str, *, sessions_root: str | Path = "sessions") -> Opened:
    """A new design in a new session folder, from a template of :func:`templates`.

    The folder is ``sessions_root/<the design's name>`` (``untitled`` for the blank form),
    with ``-2``, ``-3``, … appended when that folder exists: nothing of another session is
    reused. The session follows the design's name as it is edited (``follow_name``),
    until a stage runs in it.

    Parameters
    ----------
    template : str
        :data:`EMPTY`, or the stem of a bundled example (``"double_integrator"``).
    sessions_root : str or Path
        Where the new session folder goes.

    Returns
    -------
    Opened
        The session, and the form's entries (the example's fields, or all empty). A copy
        of an example is saved as the session's ``spec.toml`` at the first check
        (``save_now``).

    Raises
    ------
    SpecError
        An unknown template, or an example the form cannot show (naming the file).
    """
    root = Path(sessions_root)
    if template == EMPTY:
        values, has_verify = _blank()
        base, source = "untitled", None
    else:
        files = {f.name: f for f in example_files()}
        source = files.get(f"{template}.toml")
        if source is None:
            known = ", ".join(k for k, _ in templates())
            raise SpecError(f"no template {template!r} (known: {known})")
        try:
            values, has_verify = form_from_text(source.read_text(encoding="utf-8"))
        except SpecError as exc:
            raise exc.with_file(source.name) if exc.file is None else exc from None
        base = _safe(values.get("name") or template)
    folder = root / base
    k = 2
    while folder.exists():
        folder, k = root / f"{base}-{k}", k + 1
    session = Session.open_or_create(folder)
    note = (
        f"new design in {folder}: fill in the plant"
        if source is None
        else f"new design in {folder}, a copy of the example {source.name}"
    )
    return Opened(session, values, has_verify, note, save_now=source is not None, follow_name=True)


def _safe(name: str) -> str:
    """A folder name for a spec name: never a path (``/``), never ``.``/``..`` or hidden.

    The one rule of session folders (``sessions/<this>``): a spec opened, a *New* design,
    an ``untitled`` session renamed after its design (whose names already pass it), and
    the bundled ``sessions/double-integrator`` (``examples/double_integrator.toml``)."""
    safe = "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in name)
    return safe.lstrip(".") or "untitled"


def _read_form(path: Path) -> tuple[dict[str, str], bool]:
    """The form entries of a spec file; ``SpecError`` naming the file otherwise."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SpecError("file not found", file=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"cannot read the spec: {exc}", file=str(path)) from None
    try:
        return form_from_text(text)
    except SpecError as exc:
        raise exc.with_file(str(path)) if exc.file is None else exc from None


def _from_session(session: Session) -> Opened:
    draft = read_draft(session)
    if draft is not None:
        values, has_verify = draft
        return Opened(
            session, values, has_verify, "restored unsaved edits from the last workbench run"
        )
    spec = session.spec_path()
    if spec.is_file():
        values, has_verify = _read_form(spec)
        return Opened(session, values, has_verify, None)
    values, has_verify = _blank()
    return Opened(session, values, has_verify, "the session has no spec yet: fill in the form")


def read_draft(session: Session) -> tuple[dict[str, str], bool] | None:
    """The draft of unsaved entries left in a session by an invalid form.

    Parameters
    ----------
    session : Session

    Returns
    -------
    tuple of (dict of str to str, bool) or None
        The entries (every field of the form) and whether ``[verify]`` is on; None if there
        is no draft or it is unusable (it is only a convenience, never an error).
    """
    file = session.path / DRAFT
    try:
        data = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError, RecursionError):
        return None
    if not isinstance(data, dict) or data.get("format") != DRAFT_FORMAT:
        return None
    entries = data.get("values")
    if not isinstance(entries, dict):
        return None
    values = {fd.name: entries.get(fd.name, "") for fd in FIELDS}
    if not all(isinstance(v, str) for v in values.values()):
        return None
    has_verify = data.get("has_verify", True)
    if not isinstance(has_verify, bool):
        return None
    return values, has_verify


def write_draft(session: Session, values: dict[str, str], has_verify: bool) -> None:
    """Save the raw entries (atomically) while the form is not a valid spec.

    Parameters
    ----------
    session : Session
        The draft goes to its folder, as :data:`DRAFT`.
    values : dict of str to str
        The form's entries: field name → text (fields missing are saved empty).
    has_verify : bool
        Whether the ``[verify]`` section is on.
    """
    data = {
        "format": DRAFT_FORMAT,
        "has_verify": has_verify,
        "values": {fd.name: values.get(fd.name, "") for fd in FIELDS},
    }
    write_text(session.path / DRAFT, json.dumps(data, indent=1) + "\n")


def clear_draft(session: Session) -> None:
    """Drop the draft once the form is valid again (its spec is then ``spec.toml``).

    Parameters
    ----------
    session : Session
        The session whose draft is removed (none: nothing happens).
    """
    try:
        (session.path / DRAFT).unlink()
    except FileNotFoundError:
        pass
