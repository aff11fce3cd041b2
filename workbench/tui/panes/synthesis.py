"""Synthesis pane: run the explicit MPC, see the partition, the regions, locate a state."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from rich.markup import escape
from textual import work
from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical
from textual.widget import Widget
from textual.widgets import Button, DataTable, Input, Label, Static

from codev_engine.errors import CodevError
from codev_engine.session import RunReport

from ..design import locate_state, region_rows, shared_laws
from ..handoff import to_ui
from ..messages import CancelRequested, LawExportRequested, RunRequested
from ..parsers import parse_axes, parse_state
from ..views import partition_text
from ..widgets import EntryInput, Plot

if TYPE_CHECKING:
    from codev_engine import ExplicitLaw, Problem


class SynthesisPane(Vertical):
    """The explicit law: progress and cancel, the partition picture, region table, lookup.

    Posts :class:`RunRequested` ``("synthesis")`` and :class:`CancelRequested`. The app
    hands it the law with :meth:`show_law`, the stage in flight with :meth:`show_busy`,
    the progress line with :meth:`show_progress` and the end of a run with
    :meth:`run_finished`.
    """

    _note = ""  # the last run's failure or cancellation, kept until a law arrives
    _law_shown: object = None  # the law whose picture and table are on screen
    # what the app last handed over: the law, whether it is the current spec's, and the
    # stage running (its progress owns the status line meanwhile)
    _law: ExplicitLaw | None = None
    _current = False
    _busy: str | None = None
    _shared_for: object = None  # the law _shared was counted for
    _shared = 0
    _problem: Problem | None = None  # the form's valid spec: its [verify] boxes fix the slice
    _centre_for: object = None  # the law _centre (its domain's centre) was computed for
    _centre: np.ndarray | None = None

    def compose(self) -> ComposeResult:
        with Horizontal(classes="bar"):
            yield Button("Synthesize \\[ctrl+g]", id="synth-run", variant="primary")
            yield Button("Cancel \\[esc]", id="synth-cancel")
            yield Static("no law yet: press Synthesize", id="synth-status", classes="status")
        with Horizontal(id="synth-main"):
            yield Plot("the partition appears here after synthesis", id="partition")
            with Vertical(id="synth-side"):
                # top to bottom is the Tab order: the lookup first (the tab's first field)
                yield Label("locate a state")
                yield EntryInput(id="locate-x", placeholder="e.g. 1.5, -2  (Enter)")
                yield Static("", id="locate-out", classes="small")
                yield Label("axes (2 states)")
                yield EntryInput(id="synth-axes", placeholder="default: the first two states")
                yield Label("section: other states at (n > 2)")
                yield EntryInput(id="synth-at", placeholder="default: as recordings and reports")
                yield Label("export the law as C99 into a folder")
                yield EntryInput(id="law-export-dir", placeholder="e.g. law_c  (Enter: .h and .c)")
                yield Static("", id="law-export-out", classes="small")
        yield DataTable(id="regions", zebra_stripes=True, cursor_type="row")

    def on_mount(self) -> None:
        table = self.query_one("#regions", DataTable)
        table.add_columns("region", "facets", "u = F x + G", "bounding box")

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: *locate a state*.

        Returns
        -------
        Widget
        """
        return self.query_one("#locate-x", Input)

    def reset(self) -> None:
        """Forget what was typed and shown for the design before (another design was opened):
        the lookup and its answer, the marker, the axes and slice, the last run's note."""
        for name in ("#locate-x", "#synth-axes", "#synth-at", "#law-export-dir"):
            self.query_one(name, Input).value = ""
        self.query_one("#locate-out", Static).update("")
        self.query_one("#law-export-out", Static).update("")
        self._marker = None
        self._note = ""
        self._law_shown = None

    # ---- events ----------------------------------------------------------------------

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "synth-run":
            event.stop()
            self.post_message(RunRequested("synthesis"))
        elif event.button.id == "synth-cancel":
            event.stop()
            self.post_message(CancelRequested())

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id == "locate-x":
            event.stop()
            self.locate()
        elif event.input.id in ("synth-axes", "synth-at"):
            event.stop()
            self.refresh_law(force=True)
        elif event.input.id == "law-export-dir":
            event.stop()
            dest = event.value.strip()
            out = self.query_one("#law-export-out", Static)
            if not dest:
                out.update("[red]type a folder first[/red]")
            elif self._law is None:
                out.update("[red]no law yet: synthesize first (ctrl+g)[/red]")
            else:
                out.update(f"exporting to {dest} …")
                self.post_message(LawExportRequested(dest))

    def show_law_export(self, dest: str, *, files: tuple[str, ...] = (), summary: str = "",
                        error: str | None = None) -> None:
        """Show the outcome of a C export: the files written and the search's cost, or why
        it failed.

        Parameters
        ----------
        dest : str
            The folder asked for.
        files : tuple of str
            The files written.
        summary : str
            The method and worst case, from the header.
        error : str, optional
            Why the export failed.
        """
        out = self.query_one("#law-export-out", Static)
        if error is not None:
            out.update(f"[red]export to {dest} failed: {error}[/red]")
        else:
            out.update(f"wrote {', '.join(files)}" + (f" · {summary}" if summary else ""))

    # ---- showing the law -------------------------------------------------------------

    def show_busy(self, stage: str | None) -> None:
        """Note the stage run in flight; nothing is redrawn.

        Parameters
        ----------
        stage : str or None
            The stage running (None: none); while it is set, the progress owns the status
            line.
        """
        self._busy = stage

    def show_progress(self, stage: str, text: str) -> None:
        """Show the progress of the run in flight, if it concerns this pane.

        Parameters
        ----------
        stage : str
            The stage the run is in now (shown while it is ``model`` or ``synthesis``, or
            the run was started for one of them).
        text : str
            The progress line.
        """
        if self._busy in ("model", "synthesis") or stage in ("model", "synthesis"):
            self.query_one("#synth-status", Static).update(f"[cyan]{text}[/cyan]")
        elif self._busy is not None:
            # a verification run past its law: its line, not the "model: 0 · 0.0 s" of the
            # cached stages it loaded on the way (issue 41)
            self.query_one("#synth-status", Static).update(
                f"[cyan]{text} (the Verification tab)[/cyan]")

    def set_problem(self, problem: Problem | None) -> None:
        """Set the spec whose ``[verify] initial_input`` and ``reference`` fix the default
        slice of a law over θ = (x, u_prev, r) (:func:`figures.default_slice_point`, as in
        recordings and reports); the picture is redrawn when that slice moved.

        Parameters
        ----------
        problem : Problem or None
            The form's valid spec (None while it is not valid: the domain's centre).
        """
        law = self._law
        if law is None or law.n <= 2 or law is not self._law_shown:
            self._problem = problem
            return
        before = self._default_at(law)
        self._problem = problem
        if not np.array_equal(before, self._default_at(law)):
            self._draw(law)

    def _default_at(self, law: ExplicitLaw) -> np.ndarray:
        """``figures.default_slice_point(law, problem)``, the one section rule of recordings
        and reports (the states at the centre of ``[verify]``'s initial set, ``u_prev`` and
        ``r`` at the middle of their boxes); the domain's centre (LPs) it falls back to is
        computed once per law, a form check only moves the spec's boxes."""
        from codev_engine.view.figures import default_slice_point

        if self._centre_for is not law:
            self._centre = np.array(default_slice_point(law), dtype=float)
            self._centre_for = law
        return default_slice_point(law, self._problem, centre=self._centre)

    def show_law(self, law: ExplicitLaw | None, *, current: bool) -> None:
        """Show a law, and whether it is the current spec's.

        Parameters
        ----------
        law : ExplicitLaw or None
            The law (None: no law yet).
        current : bool
            Whether it was computed for the spec on screen (else it is shown as stale).
        """
        self._law, self._current = law, current
        self.refresh_law()

    def run_finished(
        self,
        report: RunReport | None,
        error: object,
        *,
        law: ExplicitLaw | None,
        current: bool,
    ) -> None:
        """The run ended (nothing runs now): show its law, or why it has none.

        Parameters
        ----------
        report : RunReport or None
            The run's report (None: the run failed or was cancelled).
        error : object
            ``"cancelled"``, the exception that ended the run, or None.
        law : ExplicitLaw or None
            The law to show after the run, as in :meth:`show_law`.
        current : bool
            As in :meth:`show_law`.
        """
        self._law, self._current, self._busy = law, current, None
        if report is not None and report.law is not None:
            self._note = ""
            self.refresh_law()
        elif error is not None:
            self._note = (
                f"[red]✗ {error}[/red]"
                if error != "cancelled"
                else "[yellow]cancelled: nothing was saved[/yellow]"
            )
            self.query_one("#synth-status", Static).update(self._note)
            self.refresh_law(keep_status=True)

    def refresh_law(self, keep_status: bool = False, force: bool = False) -> None:
        """Redraw the law last handed over (its picture and table only if the law changed).

        Parameters
        ----------
        keep_status : bool
            Leave the status line as it is (a failure or cancellation shown there).
        force : bool
            Redraw the picture and the table even for the same law (new axes or slice).
        """
        law = self._law
        status = self.query_one("#synth-status", Static)
        plot = self.query_one("#partition", Plot)
        table = self.query_one("#regions", DataTable)
        if law is None:
            if not keep_status and self._busy is None:
                note = f"{self._note} · " if self._note else ""
                status.update(f"{note}no law yet: press Synthesize (ctrl+g)")
            plot.set_draw(None, "the partition appears here after synthesis")
            table.clear()
            self._law_shown = None
            return
        if not keep_status and self._busy is None:
            state = (
                "[green]current[/green]"
                if self._current
                else "[yellow]stale: the spec changed since; ctrl+g recomputes[/yellow]"
            )
            norm = law.meta.get("norm", "")
            seconds = law.meta.get("seconds")
            took = f" · synthesised in {seconds:.2f} s" if isinstance(seconds, float) else ""
            # counted with the table, in a worker
            shared = self._shared if law is self._shared_for else 0
            merge = f" · {shared} share a law: Merge regions (F2)" if shared else ""
            status.update(
                f"{law.num_regions} critical regions · n={law.n}, m={law.m}"
                f"{f', norm {norm}' if norm else ''}{took} · {state}{merge}"
            )
        if law is not self._law_shown or force:
            # the picture and the table depend on the law only: a form check (every few
            # keys) must not rebuild them
            self._law_shown = law
            self._name_inputs(law)
            self._draw(law)
            table.clear()
            # the rows need every region's bounding box (LPs, and a kernel compiled on a
            # law's first use: seconds under load): off the UI thread
            self._regions(law)

    def _name_inputs(self, law: ExplicitLaw) -> None:
        """Say what the lookup and the slice take: the law's parameters, by name (a law over
        θ = (x, u_prev, r) takes more numbers than the states)."""
        names = law.parameter_names or tuple(f"x{k}" for k in range(law.n))
        self.query_one("#locate-x", Input).placeholder = f"{', '.join(names)}  (Enter)"
        extra = names[len(law.states):] if law.parameters else ()
        self.query_one("#synth-at", Input).placeholder = (
            f"{', '.join(extra)} (or all {law.n}); default: the middle of [verify] "
            "initial_input and reference"
            if extra
            else "default: the initial set's centre"
        )

    @work(thread=True, exclusive=True, group="regions")
    def _regions(self, law: ExplicitLaw) -> None:
        try:
            rows, shared = region_rows(law), shared_laws(law)
        except (CodevError, OSError) as exc:
            # (a law stored as shards reads them all here: a damaged one is said on the
            # status line, the session has marked it; a worker's error would end the app)
            to_ui(self, self._regions_failed, law, str(exc))
            return
        to_ui(self, self._show_regions, law, rows, shared)

    def _regions_failed(self, law: ExplicitLaw, message: str) -> None:
        if law is not self._law_shown:
            return  # another law is on screen by now
        self._note = f"[red]✗ {escape(message)}[/red]"
        self.query_one("#synth-status", Static).update(self._note)

    def _show_regions(self, law: ExplicitLaw, rows: list[tuple[str, ...]], shared: int) -> None:
        if law is not self._law_shown:
            return  # another law is on screen by now
        self._shared_for, self._shared = law, shared
        table = self.query_one("#regions", DataTable)
        table.clear()
        for row in rows:
            table.add_row(*row)
        self.refresh_law(keep_status=bool(self._note))  # the count of shared laws

    def _draw(self, law: ExplicitLaw) -> None:
        plot = self.query_one("#partition", Plot)
        names = law.parameter_names or tuple(f"x{k}" for k in range(law.n))
        if law.n == 1:
            plot.set_draw(None, "one state: see the region table")
            return
        try:
            axes = self._axes(names)
            at = self._at(law)
        except ValueError as exc:
            plot.set_draw(None, f"✗ {exc}")
            return
        marker = getattr(self, "_marker", None)
        plot.set_draw(lambda w, h: partition_text(law, w, h, axes=axes, at=at, marker=marker))

    def _axes(self, names: tuple[str, ...]) -> tuple[int, int]:
        text = self.query_one("#synth-axes", Input).value
        if not text.strip():
            return 0, 1
        return parse_axes(text, names)

    def _at(self, law: ExplicitLaw) -> np.ndarray | None:
        """The section typed: every parameter, or (a law over θ = (x, u_prev, r)) only
        those after the states, the states then at the default. Nothing typed: the one
        section rule of recordings and reports (``figures.default_slice_point``: the states
        at the centre of ``[verify] initial_set``, ``u_prev`` and ``r`` at the middle of
        ``[verify] initial_input`` and ``reference``); None for a law of two parameters
        (no section)."""
        text = self.query_one("#synth-at", Input).value
        extra = law.n - len(law.states) if law.parameters else 0
        if not text.strip():
            return self._default_at(law) if law.n > 2 else None
        if extra and len(text.replace(",", " ").replace(";", " ").split()) == extra:
            at = self._default_at(law)
            at[law.n - extra :] = parse_state(text, extra)
            return at
        return parse_state(text, law.n)

    def locate(self) -> None:
        """Find the region of the state typed, show its input, and mark it on the picture.

        The region's row is selected in the table; a state that does not parse, or no law
        yet, is reported in place of the answer.
        """
        out = self.query_one("#locate-out", Static)
        law = self._law
        if law is None:
            out.update("[red]no law yet: synthesize first[/red]")
            return
        try:
            x = parse_state(self.query_one("#locate-x", Input).value, law.n)
        except ValueError as exc:
            out.update(f"[red]✗ {exc}[/red]")
            return
        k, u = locate_state(law, x)
        self._marker = x
        if k < 0:
            out.update("outside the law's domain: the MPC is infeasible there")
        else:
            names = law.inputs or tuple(f"u{i}" for i in range(law.m))
            us = ", ".join(f"{nm} = {v:.6g}" for nm, v in zip(names, u, strict=True))
            out.update(f"region [b]{k}[/b] · {us}")
            table = self.query_one("#regions", DataTable)
            if k < table.row_count:
                table.move_cursor(row=k)
        self._draw(law)
