"""MPC pane: horizon, norm, weights, bounds; a closed-loop preview of the online MPC."""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np
from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widget import Widget
from textual.widgets import Button, Input, Label, Static

from codev_engine.errors import CodevError

from ..design import MpcPreview, mpc_preview, preview_extras, preview_signals
from ..form import FIELDS
from ..handoff import to_ui
from ..parsers import parse_state
from ..views import series_text
from ..widgets import EntryInput, FieldEntry, Plot, field_entries

if TYPE_CHECKING:
    from codev_engine import Problem

MPC_FIELDS = [f.name for f in FIELDS if f.section == "mpc"]


class MpcPane(Horizontal):
    """Left: the MPC fields. Right: the online MPC's closed loop from a chosen state.

    The app hands it the spec to preview with :meth:`set_problem` (at every form check)
    and starts and stops the preview with :meth:`run_preview` and :meth:`cancel_preview`.

    Parameters
    ----------
    values : dict of str to str
        The form's entries at start: field name → text (the pane's own fields are used).

    Attributes
    ----------
    last : MpcPreview or None
        The last preview shown.
    reference_lines : list of (str, float)
        The reference lines drawn on its state plot (``design.preview_signals``).
    """

    def __init__(self, values: dict[str, str]) -> None:
        super().__init__()
        self._values = values
        self._stop = threading.Event()
        self._problem: Problem | None = None  # the valid spec of the last form check
        self._x0_filled = ""  # the default state last filled in (not typed by the user)
        self._shown: tuple[str, str] | None = None  # (the spec previewed, its status line)
        self.last: MpcPreview | None = None
        self.reference_lines: list[tuple[str, float]] = []

    def compose(self) -> ComposeResult:
        with VerticalScroll(classes="form", can_focus=False):
            yield from field_entries(MPC_FIELDS, self._values)
        with Vertical(classes="output"):
            yield Static(
                "Preview: the online MPC (cvxpy + Clarabel) in closed loop with its own "
                "prediction model, before paying for explicit synthesis.",
                classes="small",
            )
            with Horizontal(classes="bar"):
                yield Label("x0 ")
                yield EntryInput(placeholder="initial state, e.g. 9, -5", id="preview-x0")
                yield Label(" steps ")
                yield EntryInput("20", id="preview-steps", restrict=r"[0-9]*", max_length=4)
                # a law over a reference box: the reference the loop follows
                yield Label(" r ", id="preview-r-label")
                yield EntryInput(id="preview-r", placeholder="reference")
                yield Button("Preview \\[ctrl+g]", id="preview-run", variant="primary")
            yield Static("", id="preview-status", classes="status")
            yield Plot("states appear here", id="preview-states")
            yield Plot("inputs appear here", id="preview-inputs")

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "preview-run":
            event.stop()
            self.run_preview()

    def on_mount(self) -> None:
        self._show_reference_entry(None)

    def _show_reference_entry(self, problem: Problem | None) -> None:
        """The reference entry is shown for a design whose law takes a reference (a box),
        with the default it follows as its placeholder."""
        _, r = preview_extras(problem) if problem is not None else (None, None)
        entry = self.query_one("#preview-r", Input)
        entry.display = self.query_one("#preview-r-label").display = r is not None
        if r is not None:
            entry.placeholder = "default: " + ", ".join(f"{v:g}" for v in r)

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id in ("preview-x0", "preview-steps", "preview-r"):
            event.stop()
            self.run_preview()

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: the first entry's editor
        (the horizon).

        Returns
        -------
        Widget
        """
        return self.query_one(FieldEntry).editor

    def reset(self) -> None:
        """Forget the preview of the design before (another design was opened): the state
        and steps typed, the status line and both pictures."""
        self._stop.set()
        self.last = None
        self._shown = None
        self.reference_lines = []
        self.query_one("#preview-x0", Input).value = self._x0_filled = ""
        self.query_one("#preview-steps", Input).value = "20"
        self.query_one("#preview-r", Input).value = ""
        self.query_one("#preview-status", Static).update("")
        self.query_one("#preview-states", Plot).set_draw(None, "states appear here")
        self.query_one("#preview-inputs", Plot).set_draw(None, "inputs appear here")

    def set_problem(self, problem: Problem | None) -> None:
        """Set the spec a preview runs on.

        Parameters
        ----------
        problem : Problem or None
            The form's valid spec; None while the form is not valid (or not checked yet).
        """
        self._problem = problem
        self._show_reference_entry(problem)
        status = self.query_one("#preview-status", Static)
        if problem is not None and "not valid yet" in str(status.render()):
            status.update("")  # the spec is valid now: the refusal is no longer true
        if self._shown is not None and "solving" not in str(status.render()):
            # the preview drawn is of the spec as it was: say so once an entry (R, Q, a
            # bound...) changes it, and take it back when the entry is put back
            source, msg = self._shown
            if problem is None or problem.source != source:
                msg += " · [yellow]stale: the spec changed since (ctrl+g previews again)[/yellow]"
            status.update(msg)

    def on_unmount(self) -> None:
        self._stop.set()  # the app quits: a preview in flight stops at its next solve

    def cancel_preview(self) -> None:
        """Stop the preview in flight before its next MPC solve (none: nothing happens)."""
        self._stop.set()

    def run_preview(self) -> None:
        """Start the preview from the state and steps typed, in a worker thread.

        An empty state is filled in with a default (the initial set's centre, else a point
        off the operating point); a spec that is not valid or a state that does not parse
        is reported in the pane's status line, and nothing runs.
        """
        status = self.query_one("#preview-status", Static)
        problem = self._problem
        if problem is None:
            status.update("[red]✗ the spec is not valid yet (fields marked in red)[/red]")
            return
        x_text = self.query_one("#preview-x0", Input).value
        if not x_text.strip() or x_text == self._x0_filled:
            # empty, or the default filled in before: the default of the spec as it is now
            x0 = _default_state(problem)
            self._x0_filled = ", ".join(f"{v:g}" for v in x0)
            self.query_one("#preview-x0", Input).value = self._x0_filled
        else:
            try:
                x0 = parse_state(x_text, problem.plant.n)
            except ValueError as exc:
                status.update(f"[red]✗ x0: {exc}[/red]")
                return
        reference = None
        _, r_default = preview_extras(problem)
        r_text = self.query_one("#preview-r", Input).value
        if r_default is not None and r_text.strip():
            try:
                reference = parse_state(r_text, r_default.size)
            except ValueError as exc:
                status.update(f"[red]✗ r: {exc}[/red]")
                return
        steps_text = self.query_one("#preview-steps", Input).value or "20"
        steps = max(1, min(int(steps_text), 2000))
        status.update(f"solving the MPC online for {steps} steps…")
        self._stop.clear()
        self._preview(problem, x0, steps, reference)

    @work(thread=True, exclusive=True, group="preview")
    def _preview(
        self, problem: Problem, x0: np.ndarray, steps: int, reference: np.ndarray | None = None
    ) -> None:
        from codev_engine import discretize

        try:
            model = discretize(problem)
            prev = mpc_preview(
                problem, model, x0, steps, should_stop=self._stop.is_set, reference=reference
            )
        except CodevError as exc:
            # (the status widget is looked up on the UI thread, where the DOM lives)
            to_ui(self, self._show_error, f"[red]✗ {exc}[/red]")
            return
        to_ui(self, self._show, prev, problem)

    def _show_error(self, message: str) -> None:
        self.query_one("#preview-status", Static).update(message)

    def _show(self, prev: MpcPreview, problem: Problem) -> None:
        self.last = prev
        k = prev.U.shape[0]
        msg = f"{k} steps"
        if prev.infeasible_at is not None:
            msg += f" · [red]MPC infeasible at step {prev.infeasible_at}[/red]"
        else:
            msg += f" · final state ({', '.join(f'{v:.3g}' for v in prev.X[-1])})"
        if prev.reference is not None:
            msg += f" · following r = {', '.join(f'{v:g}' for v in prev.reference)}"
        self.query_one("#preview-status", Static).update(msg)
        self._shown = (problem.source, msg)
        inputs = problem.plant.inputs
        # the states (and outputs that are not a state), and the reference followed
        Y, labels, lines = preview_signals(problem, prev)
        self.reference_lines = lines
        self.query_one("#preview-states", Plot).set_draw(
            lambda w, h: series_text(prev.t, Y, labels, w, h, lines=lines)
        )
        if k:
            self.query_one("#preview-inputs", Plot).set_draw(
                lambda w, h: series_text(prev.t[:k], prev.U, inputs, w, h, steps=True)
            )
        else:
            self.query_one("#preview-inputs", Plot).set_draw(None, "no input: no step was solved")


def _default_state(problem: Problem) -> np.ndarray:
    """The centre of the initial set, else a point off the operating point."""
    if problem.verify is not None:
        return 0.5 * (problem.verify.initial_lower + problem.verify.initial_upper)
    x = np.array(problem.model.x_op, dtype=float)
    hi = np.where(np.isfinite(problem.mpc.x_max), problem.mpc.x_max, x + 1.0)
    return x + 0.5 * (hi - x)
