"""Sweep pane: a grid of spec values around the current design, and its table of outcomes."""

from __future__ import annotations

from collections.abc import Sequence

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widget import Widget
from textual.widgets import Button, DataTable, Input, Label, Static

from ..messages import CancelRequested, SweepRequested
from ..widgets import EntryInput

__all__ = ["SweepPane", "sweep_cell"]

#: the verdict cell's colour
VERDICT_STYLE = {"robustly_safe": "bold green", "unsafe": "bold red", "unknown": "bold yellow",
                 "error": "bold magenta"}

#: the table's outcome columns: (row field, heading)
COLUMNS = (
    ("regions", "regions"),
    ("verdict", "verdict"),
    ("reason", "reason"),
    ("synthesis_seconds", "synth s"),
    ("verification_seconds", "verify s"),
    ("tube_width_at_horizon", "width at T"),
    ("width_at_horizon_of", "width of"),
    ("closed_loop_cost", "cost"),
)


def sweep_cell(v: object) -> str:
    """A table cell: 4 significant digits for floats, "-" for None, TOML-like lists.

    Parameters
    ----------
    v : object

    Returns
    -------
    str
    """
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(sweep_cell(x) for x in v) + "]"
    return str(v)


class SweepPane(VerticalScroll):
    """Designs × outcomes: the grid typed, then one row per design as it finishes.

    Posts :class:`SweepRequested` (the grid's text) and :class:`CancelRequested`. The app
    hands it the designs to come with :meth:`start`, each finished row with
    :meth:`show_row`, a whole recorded sweep with :meth:`show_rows`, and the end of a run
    with :meth:`finished`.
    """

    _fields: tuple[str, ...] = ()
    _rows: list[dict | None]

    def compose(self) -> ComposeResult:
        yield Label("Sweep the current design: FIELD=V1,V2,... per swept field, separated by ';' "
                    "(TOML values; strings quoted)")
        with Horizontal(classes="bar"):
            yield EntryInput(id="sweep-grid",
                             placeholder="e.g. mpc.horizon=2,3; mpc.R=[[0.5]],[[1.0]]")
            yield Label("workers", classes="inline")
            yield EntryInput(id="sweep-workers", placeholder="serial",
                             tooltip="local Dask worker processes for the designs; empty: "
                                     "one after another here (or $CODEV_SCHEDULER's cluster)")
            yield Button("Run sweep \\[ctrl+g]", id="sweep-run", variant="primary")
            yield Button("Cancel \\[esc]", id="sweep-cancel")
        yield Static("no sweep yet", id="sweep-status", classes="status")
        yield DataTable(id="sweep-table", cursor_type="row", zebra_stripes=True)
        yield Static("", id="sweep-out", classes="small")

    def on_mount(self) -> None:
        self._rows = []

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: the grid's entry.

        Returns
        -------
        Widget
        """
        return self.query_one("#sweep-grid", Input)

    def grid_text(self) -> str:
        """The grid as typed.

        Returns
        -------
        str
        """
        return self.query_one("#sweep-grid", Input).value

    def workers_text(self) -> str:
        """The workers field as typed (empty: serial).

        Returns
        -------
        str
        """
        return self.query_one("#sweep-workers", Input).value.strip()

    def set_grid_text(self, text: str) -> None:
        """Put a grid in the entry (the recorded sweep's, when a design is opened).

        Parameters
        ----------
        text : str
        """
        self.query_one("#sweep-grid", Input).value = text

    def reset(self) -> None:
        """Forget the sweep shown (another design was opened)."""
        self._fields, self._rows = (), []
        self.query_one("#sweep-table", DataTable).clear(columns=True)
        self.query_one("#sweep-status", Static).update("no sweep yet")
        self.query_one("#sweep-out", Static).update("")

    def on_button_pressed(self, event: Button.Pressed) -> None:
        event.stop()
        if event.button.id == "sweep-run":
            self.post_message(SweepRequested(self.grid_text(), self.workers_text()))
        elif event.button.id == "sweep-cancel":
            self.post_message(CancelRequested())

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id in ("sweep-grid", "sweep-workers"):
            event.stop()
            self.post_message(SweepRequested(self.grid_text(), self.workers_text()))

    # ---- what the app hands over ------------------------------------------------------

    def start(self, fields: Sequence[str], values: Sequence[dict], where: str) -> None:
        """A sweep starts: its designs listed, their outcomes to come.

        Parameters
        ----------
        fields : sequence of str
            The swept fields.
        values : sequence of dict
            Each design's values, in the table's order.
        where : str
            The sweep's folder.
        """
        self._fields = tuple(fields)
        self._rows = [{"values": v} for v in values]
        self._redraw()
        self.query_one("#sweep-status", Static).update(
            f"sweeping {len(values)} designs into {where} · 0 done · Esc cancels")
        self.query_one("#sweep-out", Static).update("")

    def show_row(self, i: int, row: dict) -> None:
        """Design ``i`` finished.

        Parameters
        ----------
        i : int
        row : dict
            Its row (``ce.sweep``'s).
        """
        if 0 <= i < len(self._rows):
            self._rows[i] = row
        done = sum(1 for r in self._rows if r is not None and "regions" in r)
        self._redraw()
        self.query_one("#sweep-status", Static).update(
            f"{done}/{len(self._rows)} designs done · Esc cancels")

    def show_rows(self, fields: Sequence[str], rows: Sequence[dict], note: str) -> None:
        """Show a whole sweep (recorded, or just finished).

        Parameters
        ----------
        fields : sequence of str
        rows : sequence of dict
        note : str
            The status line.
        """
        self._fields = tuple(fields)
        self._rows = list(rows)
        self._redraw()
        self.query_one("#sweep-status", Static).update(note)

    def finished(self, note: str, out: str = "") -> None:
        """The sweep ended (done, failed or cancelled).

        Parameters
        ----------
        note : str
            The status line.
        out : str
            Where it is saved and how to replay and view it.
        """
        self.query_one("#sweep-status", Static).update(note)
        self.query_one("#sweep-out", Static).update(out)

    def rows(self) -> list[list[str]]:
        """The table's cells as shown, row by row (for tests and copies).

        Returns
        -------
        list of list of str
        """
        table = self.query_one("#sweep-table", DataTable)
        return [[str(c) for c in table.get_row_at(i)] for i in range(table.row_count)]

    def _redraw(self) -> None:
        table = self.query_one("#sweep-table", DataTable)
        table.clear(columns=True)
        table.add_columns(*self._fields, *(head for _k, head in COLUMNS))
        for row in self._rows:
            if row is None:
                continue
            cells = [sweep_cell(row["values"].get(f)) for f in self._fields]
            if "regions" not in row:  # not finished yet
                cells += ["…"] + [""] * (len(COLUMNS) - 1)
            elif row.get("error"):
                cells += [sweep_cell(row.get("regions")), "error", str(row["error"])]
                cells += [sweep_cell(row.get(k)) for k, _h in COLUMNS[3:]]
            else:
                cells += [sweep_cell(row.get(k)) for k, _h in COLUMNS]
            shown: list[str | Text] = list(cells)
            at = len(self._fields) + 1  # the verdict's column
            shown[at] = Text(cells[at], style=VERDICT_STYLE.get(cells[at], ""))
            table.add_row(*shown)
