"""What the panes ask of the app: typed Textual messages, posted by a pane, handled by the app.

A pane never calls the app or reads its attributes: it posts one of these messages (they
bubble up to :class:`~workbench.tui.app.CodevApp`, which handles each in an ``on_<message>``
method) and the app answers by calling the pane's documented ``show_*`` methods with plain
data (see the app module's docstring).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from textual.message import Message

__all__ = [
    "CancelRequested",
    "ExportRequested",
    "LawExportRequested",
    "NewRequested",
    "OpenRequested",
    "RunRequested",
    "SaveRequested",
    "VerifyToggled",
]


@dataclass
class RunRequested(Message):
    """Run the pipeline up to a stage; cached stages are loaded, not recomputed.

    Attributes
    ----------
    stage : str
        The last stage to run: ``"model"``, ``"synthesis"``, ``"verification"`` or
        ``"recording"``.
    """

    stage: str


@dataclass
class SweepRequested(Message):
    """Sweep the current design over a grid of spec values (the Sweep tab's run).

    Attributes
    ----------
    grid : str
        The grid as typed: ``FIELD=V1,V2,...`` items separated by ``;`` or new lines.
    workers : str
        The workers field as typed: empty for serial (or ``$CODEV_SCHEDULER``'s cluster),
        else the number of local Dask worker processes.
    """

    grid: str
    workers: str = ""


@dataclass
class CancelRequested(Message):
    """Stop the stage run in flight (and the MPC preview); nothing is saved for it."""


@dataclass
class VerifyToggled(Message):
    """The spec's ``[verify]`` section was switched on or off by the user.

    Attributes
    ----------
    enabled : bool
        Whether the section is now on.
    """

    enabled: bool


@dataclass
class SaveRequested(Message):
    """Save the form as the session's spec (or, if it is not valid, as the draft)."""


@dataclass
class OpenRequested(Message):
    """Open another session folder or spec file.

    Attributes
    ----------
    target : str
        The path as typed by the user (not resolved yet: the app resolves it with
        :func:`~workbench.tui.state.open_target`).
    """

    target: str


@dataclass
class NewRequested(Message):
    """Start a new design: the app offers the templates (a blank form or a bundled example)
    and resets every pane as :class:`OpenRequested` does."""


@dataclass
class ExportRequested(Message):
    """Copy the session's Rerun recording to a file the user named.

    Attributes
    ----------
    recording : Path
        The recording in the session folder.
    dest : str
        Where to copy it, as typed by the user.
    """

    recording: Path
    dest: str


@dataclass
class LawExportRequested(Message):
    """Write the law on screen as C99 (a header and a source) into a folder.

    Attributes
    ----------
    dest : str
        The folder, as typed by the user (created if missing).
    """

    dest: str
