"""Verification pane: sets, horizon, hold, depth; the verdict, the reachtube, the trace."""

from __future__ import annotations

from typing import TYPE_CHECKING

from textual.app import ComposeResult
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.widget import Widget
from textual.widgets import Button, Input, Label, Static, Switch

from codev_engine.session import RunReport

from ..form import FIELDS
from ..messages import CancelRequested, RunRequested, VerifyToggled
from ..parsers import parse_axes, parse_state_name
from ..views import plane_text, tube_time_text
from ..widgets import EntryInput, FieldEntry, Plot, field_entries

if TYPE_CHECKING:
    from codev_engine import Problem, VerificationResult

VERIFY_FIELDS = [f.name for f in FIELDS if f.section == "verify"]

VERDICT_TEXT = {
    "robustly_safe": (
        "ROBUSTLY SAFE",
        "-safe",
        "every trajectory from the initial set has every property checked",
    ),
    "unsafe": ("UNSAFE", "-unsafe", "a concrete trajectory violates the specification"),
    "unknown": ("UNKNOWN", "-unknown", "nothing proved"),
}
REASONS = {
    "max_depth": "the reachtube could not be made tight enough within max depth; "
    "raise max depth or shrink the initial set",
    "infeasible_region": "the reach set leaves the MPC's feasible region (the law is "
    "undefined there)",
}


def _claim_lines(problem: Problem, result: VerificationResult) -> list[str]:
    """The claim (codev_engine.reach.claim) in four banner lines: from, over, checked, not."""
    from rich.markup import escape

    from codev_engine.reach.claim import build_claim

    c = build_claim(problem, result)
    lines = [escape(f"from {'; '.join(c.initial + c.uncertainty)} · {c.time} · {c.hold}"),
             escape("checked: " + "; ".join(c.checked))]
    if c.not_checked:
        lines.append("[b]NOT checked[/b]: " + escape("; ".join(c.not_checked)))
    return lines


class VerificationPane(Horizontal):
    """Left: the [verify] fields. Right: run, verdict banner, tube vs time, plane view.

    Posts :class:`RunRequested` ``("verification")``, :class:`CancelRequested` and
    :class:`VerifyToggled`. The app hands it the verdict with :meth:`show_result`, the
    switch's state with :meth:`set_enabled`, the stage in flight with :meth:`show_busy`,
    the progress line with :meth:`show_progress` and the end of a run with
    :meth:`run_finished`.

    Parameters
    ----------
    values : dict of str to str
        The form's entries at start: field name → text (the pane's own fields are used).
    enabled : bool
        Whether the ``[verify]`` section is on at start.
    """

    # what the app last handed over: the result, the problem it was computed for, whether
    # it is the current spec's, and the stage running
    _result: VerificationResult | None = None
    _problem: Problem | None = None
    _current = False
    _busy: str | None = None

    def __init__(self, values: dict[str, str], enabled: bool) -> None:
        super().__init__()
        self._values = values
        self._enabled = enabled

    def compose(self) -> ComposeResult:
        with VerticalScroll(classes="form", can_focus=False):
            with Horizontal(classes="bar"):
                yield Switch(value=self._enabled, id="verify-enabled")
                yield Label(" verify the closed loop (\\[verify])")
            yield from field_entries(VERIFY_FIELDS, self._values)
        with Vertical(classes="output"):
            with Horizontal(classes="bar"):
                yield Button("Verify \\[ctrl+g]", id="verify-run", variant="primary")
                yield Button("Cancel \\[esc]", id="verify-cancel")
                yield Static("", id="verify-status", classes="status")
            yield Static("no verdict yet: press Verify", id="verdict", classes="banner")
            with Horizontal(classes="bar"):
                yield Label("state ")
                yield EntryInput(id="tube-state", placeholder="e.g. x1")
                yield Label("  plane ")
                yield EntryInput(id="plane-axes", placeholder="e.g. x1, x2")
            with Vertical(classes="plots"):
                yield Plot("the reachtube against time appears here", id="tube-time")
                yield Plot("the reachtube in the state plane appears here", id="tube-plane")
            yield Static("", id="cex", classes="small")

    def on_mount(self) -> None:
        self.set_enabled(self._enabled)

    def first_field(self) -> Widget:
        """The widget the focus goes to when the tab is shown: the first entry's editor
        (the time horizon), or the ``[verify]`` switch while the section is off.

        Returns
        -------
        Widget
        """
        if self._enabled:
            return self.query_one(FieldEntry).editor
        return self.query_one("#verify-enabled", Switch)

    def reset(self) -> None:
        """Forget what was typed and shown for the design before (another design was opened):
        the state and plane typed, the status line, the counterexample line."""
        for name in ("#tube-state", "#plane-axes"):
            self.query_one(name, Input).value = ""
        self.query_one("#verify-status", Static).update("")
        self.query_one("#cex", Static).update("")
        self._result_shown = None

    def set_enabled(self, enabled: bool) -> None:
        """Switch the [verify] section on or off (a loaded spec) without posting
        :class:`VerifyToggled`.

        Parameters
        ----------
        enabled : bool
            On: the section's entries can be edited; off: they are disabled.
        """
        self._enabled = enabled
        self.query_one("#verify-enabled", Switch).value = enabled
        for entry in self.query(FieldEntry):
            entry.disabled = not enabled

    def on_switch_changed(self, event: Switch.Changed) -> None:
        if event.switch.id == "verify-enabled":
            event.stop()
            for entry in self.query(FieldEntry):
                entry.disabled = not event.value
            if self._enabled != event.value:  # the user's, not set_enabled's
                self._enabled = event.value
                self.post_message(VerifyToggled(event.value))

    def on_button_pressed(self, event: Button.Pressed) -> None:
        if event.button.id == "verify-run":
            event.stop()
            self.post_message(RunRequested("verification"))
        elif event.button.id == "verify-cancel":
            event.stop()
            self.post_message(CancelRequested())

    def on_input_submitted(self, event: Input.Submitted) -> None:
        if event.input.id in ("tube-state", "plane-axes"):
            event.stop()
            self.refresh_result(force=True)

    def show_busy(self, stage: str | None) -> None:
        """Note the stage run in flight; nothing is redrawn.

        Parameters
        ----------
        stage : str or None
            The stage running (None: none); a verification or recording run puts a
            "verifying" line in the banner until its first progress line.
        """
        self._busy = stage
        if stage in ("verification", "recording"):
            banner = self.query_one("#verdict", Static)
            banner.remove_class("-safe", "-unsafe", "-unknown", "-stale")
            banner.update(f"[cyan]running {stage}…  Esc cancels[/cyan]")

    def show_progress(self, stage: str, text: str) -> None:
        """Show the progress of the run in flight, if it was started for this pane.

        Parameters
        ----------
        stage : str
            The stage the run is in now (the line is shown for any stage of a run started
            for ``verification`` or ``recording``).
        text : str
            The progress line.
        """
        if self._busy in ("verification", "recording"):
            self.query_one("#verify-status", Static).update(f"[cyan]{text}[/cyan]")
            self.query_one("#verdict", Static).update(f"[cyan]running: {text}[/cyan]")

    def show_result(
        self, result: VerificationResult | None, *, problem: Problem | None, current: bool
    ) -> None:
        """Show a verdict with its pictures, and whether it is the current spec's.

        Parameters
        ----------
        result : VerificationResult or None
            The verdict, reachtube and counterexample (None: no verdict yet).
        problem : Problem or None
            The spec ``result`` was computed for: its state names and sets label the
            pictures.
        current : bool
            Whether it was computed for the spec on screen (else it is shown as stale).
        """
        self._result, self._problem, self._current = result, problem, current
        self.refresh_result()

    def run_finished(
        self,
        report: RunReport | None,
        error: object,
        *,
        result: VerificationResult | None,
        problem: Problem | None,
        current: bool,
    ) -> None:
        """The run ended (nothing runs now): show its outcome and the verdict after it.

        Parameters
        ----------
        report : RunReport or None
            The run's report (None: the run failed or was cancelled); a failed
            verification stage in it is shown in the status line.
        error : object
            ``"cancelled"``, the exception that ended the run, or None.
        result : VerificationResult or None
            The verdict to show after the run, as in :meth:`show_result`.
        problem : Problem or None
            As in :meth:`show_result`.
        current : bool
            As in :meth:`show_result`.
        """
        self._result, self._problem, self._current = result, problem, current
        self._busy = None
        status = self.query_one("#verify-status", Static)
        if error == "cancelled":
            status.update("[yellow]cancelled[/yellow]")
        elif error is not None:
            status.update(f"[red]✗ {error}[/red]")
        elif report is not None:
            sr = report.stage("verification")
            if sr is not None and sr.status == "failed":
                status.update(f"[red]✗ {sr.outcome.get('message', 'failed')}[/red]")
            elif sr is not None:
                status.update(f"{sr.status} in {sr.seconds:.2f} s")
        self.refresh_result()

    _result_shown: object = None  # the result whose pictures are on screen

    def refresh_result(self, force: bool = False) -> None:
        """Redraw the result last handed over (its pictures only if the result changed).

        Parameters
        ----------
        force : bool
            Redraw the pictures even for the same result (a new state or plane typed).
        """
        result = self._result
        banner = self.query_one("#verdict", Static)
        tplot = self.query_one("#tube-time", Plot)
        pplot = self.query_one("#tube-plane", Plot)
        cex_out = self.query_one("#cex", Static)
        banner.remove_class("-safe", "-unsafe", "-unknown", "-stale")
        if result is None:
            banner.update("no verdict yet: press Verify (ctrl+g)")
            tplot.set_draw(None, "the reachtube against time appears here")
            pplot.set_draw(None, "the reachtube in the state plane appears here")
            cex_out.update("")
            self._result_shown = None
            return
        title, cls, meaning = VERDICT_TEXT.get(result.verdict, (result.verdict, "", ""))
        # the engine's words for every other reason (limit, enclosure, noise, ...); imported
        # here, not at the top, to keep the engine's reach modules off the first screen
        from codev_engine.reach.verification import UNKNOWN_WORDS

        code = result.reason or ""
        reason = REASONS.get(code, UNKNOWN_WORDS.get(code, code))
        if getattr(result, "detail", None):
            reason = f"{reason} ({result.detail})" if reason else str(result.detail)
        lines = [f"{title} — {meaning}" + (f": {reason}" if reason and cls != "-unsafe" else "")]
        lines.append(
            f"hold {result.hold} · {result.tube.num_boxes} boxes · "
            f"{result.stats.get('branches', '?')} branches · verified in {result.seconds:.2f} s"
        )
        problem = self._problem
        if problem is not None and problem.verify is not None:
            lines += _claim_lines(problem, result)
        if not self._current:
            lines.append("⟳ stale: the spec changed since this verdict; ctrl+g re-verifies")
            banner.add_class("-stale")
        banner.add_class(cls)
        banner.update("\n".join(lines))
        if result is self._result_shown and not force:
            return  # the pictures depend on the result only (a form check must not redraw)
        self._result_shown = result
        names = problem.plant.states if problem is not None else ()
        try:
            state = self._state(names)
            axes = self._axes(names)
        except ValueError as exc:
            cex_out.update(f"[red]✗ {exc}[/red]")
            return
        tplot.set_draw(lambda w, h: tube_time_text(result, w, h, state=state, problem=problem))
        n = result.tube.lower.shape[1]
        if n >= 2:
            pplot.set_draw(lambda w, h: plane_text(result, w, h, axes=axes, problem=problem))
        else:
            pplot.set_draw(None, "one state: no plane view")
        cex = result.counterexample
        if cex is not None:
            x0 = ", ".join(f"{v:.6g}" for v in cex.x0)
            cex_out.update(
                f"[red]counterexample[/red]: from x0 = ({x0}), {cex.describe()} "
                f"at t = {cex.t:.4g} s — "
                "drawn in its own colour; replay it with `codev verify --json`"
            )
        else:
            cex_out.update("")

    def _state(self, names: tuple[str, ...]) -> int:
        return parse_state_name(self.query_one("#tube-state", Input).value, names)

    def _axes(self, names: tuple[str, ...]) -> tuple[int, int]:
        text = self.query_one("#plane-axes", Input).value
        if not text.strip() or len(names) < 2:
            return 0, 1
        return parse_axes(text, names)
