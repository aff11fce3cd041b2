"""Session pane: where the work is saved, cache status per stage, the journal, Rerun export."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widget import Widget
from textual.widgets import Button, DataTable, Input, Label, Static

from codev_engine import CodevError
from codev_engine.session import RunReport, Session, StageStatus

from ...commands import runnable
from ..messages import (
    ExportRequested,
    NewRequested,
    OpenRequested,
    RunRequested,
    SaveRequested,
)
from ..widgets import EntryInput


class SessionPane(VerticalScroll):
    """The session folder is the workbench's state: open, save, status, journal, export.

    Posts :class:`OpenRequested`, :class:`NewRequested`, :class:`SaveRequested`,
    :class:`RunRequested`
    ``("recording")`` and, once a recording exists and a copy is asked for,
    :class:`ExportRequested`. The app hands it the session and the stages' status with
    :meth:`show_session`, the end of a run with :meth:`run_finished` and the copy's
    outcome with :meth:`show_export`.
    """

    _journal_stamp: tuple | None = None  # (file, mtime, size) of the journal on screen

    def compose(self) -> ComposeResult:
        yield Static("", id="session-path", classes="small")
        with Horizontal(classes="bar"):
            yield EntryInput(id="open-path", placeholder="a session folder or a spec .toml")
            yield Button("Open", id="open")
            yield Button("Save \\[ctrl+s]", id="save")
            yield Button("New… \\[ctrl+n]", id="new")
        yield Label("Stages for the current spec")
        yield DataTable(id="stages", cursor_type="row")
        yield Label("Journal (every stage run, replayable with codev replay)")
        yield DataTable(id="journal", cursor_type="row", zebra_stripes=True)
        # the copy's path before the button that uses it (Tab goes top to bottom, left to right)
        with Horizontal(classes="bar"):
            yield EntryInput(id="export-path", placeholder="also copy it to FILE.rrd (optional)")
            yield Button("Export Rerun recording \\[ctrl+g]", id="export", variant="primary")
        yield Static("", id="export-out", classes="small")

    def on_mount(self) -> None:
        self.query_one("#stages", DataTable).add_columns("stage", "status", "artifact / reason")
        self.query_one("#journal", DataTable).add_columns(
            "run", "stage", "status", "seconds", "outcome"
        )

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: the folder or spec to open.

        Returns
        -------
        Widget
        """
        return self.query_one("#open-path", Input)

    def reset(self) -> None:
        """Forget what was typed and shown for the design before (another design was opened):
        the recording's copy path (a copy of the new design's recording must not overwrite
        the old one's), the export line, the journal shown, the path opened."""
        for name in ("#open-path", "#export-path"):
            self.query_one(name, Input).value = ""
        self.query_one("#export-out", Static).update("")
        self._journal_stamp = None

    def on_button_pressed(self, event: Button.Pressed) -> None:
        event.stop()
        if event.button.id == "open":
            self.open_path()
        elif event.button.id == "save":
            self.post_message(SaveRequested())
        elif event.button.id == "new":
            self.post_message(NewRequested())
        elif event.button.id == "export":
            self.post_message(RunRequested("recording"))

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id == "open-path":
            event.stop()
            self.open_path()

    def open_path(self) -> None:
        """Ask the app to open the folder or spec typed (:class:`OpenRequested`).

        An empty entry is answered with a warning, and nothing is posted.
        """
        text = self.query_one("#open-path", Input).value.strip()
        if not text:
            self.notify("type a session folder or a spec file to open", severity="warning")
            return
        self.post_message(OpenRequested(text))

    def show_session(self, session: Session, statuses: Mapping[str, StageStatus]) -> None:
        """Show ``session``: its folder, each stage's status for the current spec, and its
        journal (read again only when the file changed).

        Parameters
        ----------
        session : Session
        statuses : Mapping of str to StageStatus
            Each stage's status for the current spec, by stage name, in pipeline order
            (empty while the spec is not valid).
        """
        self.query_one("#session-path", Static).update(
            f"Session [b]{session.path}[/b] — the spec is saved to {session.spec_path().name} "
            f"as you edit; `codev replay {session.path}` re-runs every stage headless."
        )
        stages = self.query_one("#stages", DataTable)
        stages.clear()
        for st in statuses.values():
            stages.add_row(st.stage, st.status, st.artifact or st.reason or "")
        # the journal changes only when a stage runs, not at every form check
        file = session.path / "journal.jsonl"
        try:
            st = file.stat()
            stamp: tuple = (file, st.st_mtime_ns, st.st_size)
        except OSError:
            stamp = (file, None, None)
        if stamp == self._journal_stamp:
            return
        self._journal_stamp = stamp
        journal = self.query_one("#journal", DataTable)
        journal.clear()
        try:
            records = session.journal()
        except CodevError as exc:
            journal.add_row("-", "-", "unreadable", "-", str(exc))
            return
        for rec in records[-200:]:
            journal.add_row(
                str(rec["run"]),
                rec["stage"],
                rec["status"],
                f"{rec['seconds']:.3f}",
                json.dumps(rec["outcome"], sort_keys=True),
            )
        if records:
            journal.move_cursor(row=journal.row_count - 1)

    def run_finished(self, report: RunReport | None, error: object) -> None:
        """The run ended: show its recording, if it made one, or ask for its copy.

        With a destination typed, :class:`ExportRequested` is posted (the app answers with
        :meth:`show_export`); without, the recording's path is shown.

        Parameters
        ----------
        report : RunReport or None
            The run's report (None: the run failed or was cancelled).
        error : object
            ``"cancelled"``, the exception that ended the run, or None; not shown here (the
            app notifies it).
        """
        if report is None or report.recording is None:
            return
        path = Path(report.recording)
        dest = self.query_one("#export-path", Input).value.strip()
        if dest:
            self.post_message(ExportRequested(path, dest))
        else:
            self.show_export(path)

    def show_export(
        self,
        recording: Path,
        dest: str = "",
        *,
        copied: Path | None = None,
        error: str | None = None,
    ) -> None:
        """Show where ``recording`` is, and the outcome of copying it to ``dest``: the
        copy's path, or the reason it failed.

        Parameters
        ----------
        recording : Path
            The recording in the session folder.
        dest : str
            Where the copy was asked for (empty: none).
        copied : Path, optional
            The copy, once made.
        error : str, optional
            Why the copy failed.
        """
        path = recording
        lines = [f"recording: {path}"]
        if copied is not None:
            lines.append(f"copied to {copied}")
            path = copied
        elif error is not None:
            lines.append(f"[red]✗ cannot copy to {dest}: {error}[/red]")
        lines.append(
            f"open it with:  {runnable('codev')} view {path}   (or: {runnable('rerun')} {path})"
        )
        self.query_one("#export-out", Static).update("\n".join(lines))
