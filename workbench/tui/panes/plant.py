"""Plant pane: states, inputs, dynamics, sampling; the derived linear model beside them."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rich.markdown import Markdown
from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, VerticalScroll
from textual.widget import Widget
from textual.widgets import Static

from codev_engine.errors import CodevError

from ..design import plant_report
from ..form import FIELDS, FormCheck
from ..handoff import to_ui
from ..widgets import FieldEntry, field_entries

if TYPE_CHECKING:
    from codev_engine import Problem

PLANT_FIELDS = [f.name for f in FIELDS if f.section in ("", "plant", "model")]


class PlantPane(Horizontal):
    """Left: the plant and model fields. Right: Jacobian, linearisation, discrete model.

    The app shows the report of a valid spec with :meth:`show_report`, and a message in its
    place with :meth:`show_invalid` while a plant or model entry is wrong.

    Parameters
    ----------
    values : dict of str to str
        The form's entries at start: field name → text (the pane's own fields are used).

    Attributes
    ----------
    report_text : str
        The markdown shown (tests and copy-paste read it).
    """

    def __init__(self, values: dict[str, str]) -> None:
        super().__init__()
        self._values = values
        self.report_text = ""

    def compose(self) -> ComposeResult:
        # the form column scrolls with the focus: it is no Tab stop of its own
        with VerticalScroll(classes="form", can_focus=False):
            yield from field_entries(PLANT_FIELDS, self._values)
        with VerticalScroll(classes="output"):
            yield Static("checking the spec…", id="plant-report")

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: the first entry's editor
        (the spec's name).

        Returns
        -------
        Widget
        """
        return self.query_one(FieldEntry).editor

    def show_invalid(self, chk: FormCheck) -> bool:
        """Replace the report by a message if a plant or model entry is wrong.

        Parameters
        ----------
        chk : FormCheck
            The form check that failed.

        Returns
        -------
        bool
            Whether the report was replaced (False: no plant or model entry is at fault,
            the report stays).
        """
        if not any(k in PLANT_FIELDS for k in chk.errors):
            return False
        self.report_text = "The derived model appears once the fields marked in red are fixed."
        self.query_one("#plant-report", Static).update(self.report_text)
        return True

    def show_report(self, problem: Problem) -> None:
        """Derive the plant report of a valid spec in a worker thread, and show it.

        Parameters
        ----------
        problem : Problem
            The spec (see :func:`~workbench.tui.design.plant_report`); an engine error
            deriving the report is shown in its place.
        """
        self.query_one("#plant-report", Static).update("deriving the linear model…")
        self._report(problem)

    @work(thread=True, exclusive=True, group="plant-report")
    def _report(self, problem: Problem) -> None:
        try:
            text, _model = plant_report(problem)
            body: object = Markdown(text)
        except CodevError as exc:
            text = f"✗ {exc}"
            body = f"[red]✗ {exc}[/red]"
        to_ui(self, self._show, body, text)

    def _show(self, body: object, text: str) -> None:
        self.report_text = text
        self.query_one("#plant-report", Static).update(body)
