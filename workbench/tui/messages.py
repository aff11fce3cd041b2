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
    "OpenRequested",
    "RunRequested",
    "SaveRequested",
    "VerifyToggled",
]


@dataclass
class RunRequested(Message):
    """Run the pipeline up to ``stage`` (``"model"``, ``"synthesis"``, ``"verification"``
    or ``"recording"``); cached stages are loaded, not recomputed."""

    stage: str


@dataclass
class CancelRequested(Message):
    """Stop the stage run in flight (and the MPC preview); nothing is saved for it."""


@dataclass
class VerifyToggled(Message):
    """The spec's ``[verify]`` section was switched on or off."""

    enabled: bool


@dataclass
class SaveRequested(Message):
    """Save the form as the session's spec (or, if it is not valid, as the draft)."""


@dataclass
class OpenRequested(Message):
    """Open another session folder or spec file, as typed by the user (not resolved yet)."""

    target: str


@dataclass
class ExportRequested(Message):
    """Copy the session's Rerun ``recording`` to ``dest`` (a path as typed by the user)."""

    recording: Path
    dest: str
