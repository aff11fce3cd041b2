"""The design workbench: a Textual app over ``codev_engine`` and a session folder.

State lives in the session (``codev_engine.session``): the form is validated by the engine's
spec loader as the user types, a valid spec is saved as the session's ``spec.toml`` at once,
and every stage the user runs goes through ``Session.run`` (journaled, cached, replayable by
``codev replay``). Heavy work (synthesis, verification, previews, pictures) runs in thread
workers; progress is read by a 10 Hz timer, never pushed per event, so the keyboard stays
responsive while the engine works.

The app and its panes talk one way each:

- **pane → app: messages.** A pane never imports this module, calls the app or reads its
  attributes; it posts a typed message of :mod:`workbench.tui.messages` (``RunRequested``,
  ``CancelRequested``, ``VerifyToggled``, ``SaveRequested``, ``OpenRequested``,
  ``ExportRequested``; the entries post ``FieldEntry.Edited``), which bubbles up to the app
  and is handled here by an ``on_<message>`` method. The keys bound here go the same way:
  ctrl+g posts ``RunRequested`` for the stage of the tab on screen.
- **app → pane: documented methods with plain data.** The app owns the state (session,
  form check, law, verdict, the stage running) and hands each pane what it shows by calling
  the pane's ``show_*`` / ``set_*`` / ``run_finished`` methods with values (a law, a result,
  whether it is current, the stage running), never itself; a pane keeps what it was handed
  to redraw it (new axes, a located state).

The stylesheet is ``workbench.tcss`` beside this module (``CSS_PATH``).
"""

from __future__ import annotations

import os
import re
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.markup import escape
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.widgets import Footer, Static, TabbedContent, TabPane, Tabs

from codev_engine.errors import CodevError
from codev_engine.session import (
    STAGES,
    RunOptions,
    RunReport,
    Session,
    StageStatus,
    stage_keys,
)

from .form import (
    FIELD_BY_NAME,
    FormCheck,
    check_form,
    check_plant,
    field_for_error,
    with_typed_errors,
)
from .handoff import to_ui, unless_quitting
from .messages import (
    CancelRequested,
    ExportRequested,
    LawExportRequested,
    NewRequested,
    OpenRequested,
    RunRequested,
    SaveRequested,
    SweepRequested,
    VerifyToggled,
)
from .panes.mpc import MpcPane
from .panes.plant import PlantPane
from .panes.session import SessionPane
from .panes.sweep import SweepPane
from .panes.synthesis import SynthesisPane
from .panes.verification import VerificationPane
from .state import Opened, clear_draft, new_design, open_target, templates, write_draft
from .templates import TemplateScreen
from .widgets import FieldEntry, open_groups

if TYPE_CHECKING:
    # the numerical stack loads in the first check's worker, after the first screen
    from codev_engine import ExplicitLaw, Problem, VerificationResult

__all__ = ["STYLESHEET", "CodevApp", "RunCancelledError"]

# every style of the app, its panes and widgets (also for a test app mounting one widget)
STYLESHEET = Path(__file__).with_name("workbench.tcss")

STATUS_STYLE = {
    "cached": ("✓", "green"),
    "stale": ("⟳", "yellow"),
    "missing": ("○", "grey62"),
    "corrupt": ("✗", "red"),
    "running": ("…", "cyan"),
}

# the stage ctrl+g runs on each tab (the MPC tab previews instead)
TAB_STAGE = {
    "plant": "model",
    "synthesis": "synthesis",
    "verification": "verification",
    "session": "recording",
}


# the tab that holds each section's entries, in screen order
SECTION_TAB = {
    "": "Plant (F1)",
    "plant": "Plant (F1)",
    "model": "Plant (F1)",
    "mpc": "MPC (F2)",
    "verify": "Verification (F4)",
}
TAB_ORDER = ("Plant (F1)", "MPC (F2)", "Verification (F4)")

#: a design's name, as the spec loader takes it (the session folder may follow it)
_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


def fields_by_tab(errors: dict[str, str]) -> str:
    """The entries at fault, grouped by the tab that holds them.

    Parameters
    ----------
    errors : dict of str to str
        Field name → message (a :attr:`FormCheck.errors`).

    Returns
    -------
    str
        ``"Plant (F1): name, plant.states · MPC (F2): mpc.norm"``.
    """
    groups: dict[str, list[str]] = {}
    for name in errors:
        fd = FIELD_BY_NAME.get(name)
        tab = SECTION_TAB.get(fd.section if fd is not None else "", "Plant (F1)")
        groups.setdefault(tab, []).append(name)
    return " · ".join(f"{tab}: {', '.join(groups[tab])}" for tab in TAB_ORDER if tab in groups)


class RunCancelledError(Exception):
    """Raised from the engine's progress callback when the user cancels a run."""


class CodevApp(App):
    """``codev tui``: plant → MPC → synthesis → verification, saved as a session.

    Parameters
    ----------
    opened : Opened
        The session and form entries to start with (:func:`~workbench.tui.state.open_target`).
    traces : int
        Simulated traces in the session's Rerun recording (:class:`RunOptions` ``traces``).
    sessions_root : str or Path
        Where *New* puts a new design's session folder.

    Attributes
    ----------
    session : Session
        The session edits are saved to and stages run in.
    values : dict of str to str
        The form's entries: field name → text.
    has_verify : bool
        Whether the ``[verify]`` section is on.
    options : RunOptions
        The options of every stage run (``upto`` set per run).
    check : FormCheck or None
        The last form check (None before the first).
    statuses : dict of str to StageStatus
        Each stage's status for the checked spec.
    keys : dict of str to str
        Each stage's key for the checked spec.
    law : ExplicitLaw or None
        The law shown (the latest computed or loaded: it may be stale).
    result : VerificationResult or None
        The verdict shown (likewise).
    law_key, result_key : str or None
        The stage keys they were computed for (stale when not the checked spec's ``keys``).
    result_problem : Problem or None
        The spec the verdict was computed for (its names label the pictures).
    busy : str or None
        The stage the run in flight was started for (``upto``); None when nothing runs.
    progress : tuple of (str, int, float) or None
        The run's stage, count (regions, branches) and the stage's start time, read by the
        10 Hz timer.
    """

    TITLE = "codev workbench"
    CSS_PATH = STYLESHEET
    # The workbench's keys are priority keys, handled in the order they arrive. A key that
    # is not goes first to the focused widget and comes back up to the app later: an F3 so
    # delayed was overtaken by the ctrl+g pressed after it, which ran the previous tab's
    # stage (issue 23, seen in tmux under load). The keys typed into an entry before a
    # ctrl+g still wait in the entry's queue: ctrl+g runs after them (action_go).
    BINDINGS = [
        Binding("f1", "show('plant')", "Plant", priority=True),
        Binding("f2", "show('mpc')", "MPC", priority=True),
        Binding("f3", "show('synthesis')", "Synthesis", priority=True),
        Binding("f4", "show('verification')", "Verify", priority=True),
        Binding("f5", "show('session')", "Session", priority=True),
        Binding("f6", "show('sweep')", "Sweep", priority=True),
        Binding("ctrl+g", "go", "Run stage", priority=True),
        Binding("escape", "cancel", "Cancel", show=False),
        Binding("ctrl+s", "save", "Save", priority=True),
        Binding("ctrl+n", "new", "New", priority=True),
        Binding("ctrl+q", "quit", "Quit", priority=True),
        # Tab and shift+Tab move the focus at once, in the order the keys came: as a
        # widget's own (non-priority) binding the move waited in the entry's queue while
        # the characters typed after it were still sent to the entry (seen in tmux: "4",
        # Tab, "0.9" gave a time horizon of 40.9)
        Binding("tab", "focus_next", "Next field", show=False, priority=True),
        Binding("shift+tab", "focus_previous", "Previous field", show=False, priority=True),
    ]

    def __init__(
        self, opened: Opened, *, traces: int = 16, sessions_root: str | Path = "sessions"
    ) -> None:
        super().__init__()
        self.sessions_root = Path(sessions_root)
        self.session: Session = opened.session
        self.values: dict[str, str] = dict(opened.values)
        self.has_verify: bool = opened.has_verify
        self.start_note = opened.note
        self._dirty = opened.save_now  # the form differs from the session's spec.toml
        # (a session whose law is stored as shards keeps them: codev run --sharded)
        self.options = RunOptions(traces=traces, sharded=_stores_shards(self.session))
        self.check: FormCheck | None = None
        self.statuses: dict[str, StageStatus] = {}
        self.keys: dict[str, str] = {}
        # the values shown, and the stage keys they were computed for
        self.law: ExplicitLaw | None = None
        self.law_key: str | None = None
        self.result: VerificationResult | None = None
        self.result_key: str | None = None
        self.result_problem: Problem | None = None
        # the stage run in flight
        self.busy: str | None = None
        self.progress: tuple[str, int, float] | None = None  # (stage, count, started)
        self.doing: str | None = None  # what the running stage's long step is doing
        #: the critical regions a law on demand has computed so far (regions = "reached"),
        #: from the verification's progress events; None otherwise
        self.regions_known: int | None = None
        self._cancel = threading.Event()
        self._check_timer: Any = None
        # the model key of the plant report shown or being derived
        self._plant_report_key: str | None = None
        self._checking = False  # a form check is in flight (its answer not applied yet)
        self._check_seq = 0  # the latest check started (older answers are dropped)
        self._pending_run: str | None = None  # ctrl+g pressed before the check answered
        # the spec without its unfinished [verify] section, when that is all that is wrong:
        # the model and the synthesis run on it
        self._before_verify: Problem | None = None
        # a new untitled session is renamed after the design until its first run
        self._follow_name = opened.follow_name

    # ---- layout ----------------------------------------------------------------------

    def compose(self) -> ComposeResult:
        yield Static("", id="pipeline")
        with TabbedContent(initial="plant", id="tabs"):
            with TabPane("Plant \\[F1]", id="plant"):
                yield PlantPane(self.values)
            with TabPane("MPC \\[F2]", id="mpc"):
                yield MpcPane(self.values)
            with TabPane("Synthesis \\[F3]", id="synthesis"):
                yield SynthesisPane()
            with TabPane("Verification \\[F4]", id="verification"):
                yield VerificationPane(self.values, self.has_verify)
            with TabPane("Session \\[F5]", id="session"):
                yield SessionPane()
            with TabPane("Sweep \\[F6]", id="sweep"):
                yield SweepPane()
        yield Footer()

    def on_mount(self) -> None:
        # the tab bar is no Tab stop (F1-F6 and the mouse switch tabs): keys typed at start
        # go to the first field, and Tab moves between fields only
        for tabs in self.query(Tabs):
            tabs.can_focus = False
        self.screen.set_focus(self.query_one(PlantPane).first_field())
        self._show_pipeline()
        self.set_interval(0.1, self._tick)
        if self.start_note:
            self.notify(self.start_note, timeout=6)
        self._show_recorded_sweep()
        self._run_check()

    def on_unmount(self) -> None:
        # quitting while a stage or a sweep runs: its thread stops at its next progress
        # event, where it ran to its end (a thread cannot be stopped from outside, and the
        # event loop waits for it before the app exits: minutes for a long synthesis). Its
        # results would be dropped anyway (handoff.to_ui)
        self._cancel.set()

    # ---- the form --------------------------------------------------------------------

    def on_field_entry_edited(self, event: FieldEntry.Edited) -> None:
        self.values[event.name] = event.text
        self._dirty = True
        self._schedule_check()

    def on_verify_toggled(self, event: VerifyToggled) -> None:
        self.has_verify = event.enabled
        self._dirty = True
        self._schedule_check()

    def _schedule_check(self) -> None:
        if self._check_timer is not None:
            self._check_timer.stop()
        self._check_timer = self.set_timer(0.15, self._run_check)

    def _schedule_check_now(self) -> None:
        if self._check_timer is not None:
            self._check_timer.stop()
        self._run_check()

    def _run_check(self) -> None:
        self._check_timer = None
        self._checking = True
        self._check_seq += 1
        self._check_worker(dict(self.values), self.has_verify, self._dirty, self._check_seq)

    @work(thread=True, exclusive=True, group="check")
    def _check_worker(
        self, values: dict[str, str], has_verify: bool, dirty: bool, seq: int = 0
    ) -> None:
        chk = check_form(values, with_verify=has_verify, path=str(self.session.spec_path()))
        # the plant report needs the plant and model entries only (issue 23): checked alone
        # when the whole form is not valid yet
        plant: tuple[Problem, str] | None = None
        before_verify: Problem | None = None
        if not chk.ok:
            pchk = check_plant(values)
            if pchk.ok and pchk.problem is not None:
                plant = (pchk.problem, stage_keys(pchk.problem, self.options)["model"])
            # a plant entry's own message under it now, whatever the other tabs hold
            chk = with_typed_errors(chk, pchk, values)
            if has_verify and chk.errors and all(k.startswith("verify.") for k in chk.errors):
                # only [verify] is unfinished: the MPC preview and the synthesis need none of it
                before_verify = check_form(
                    values, with_verify=False, path=str(self.session.spec_path())
                ).problem
        statuses: dict[str, StageStatus] = {}
        keys: dict[str, str] = {}
        try:
            if chk.ok:
                assert chk.problem is not None
                if dirty or not self.session.spec_path().exists():
                    self.session.save_spec(chk.problem)
                clear_draft(self.session)
                keys = stage_keys(chk.problem, self.options)
                statuses = {s.stage: s for s in self.session.status(chk.problem, self.options)}
            else:
                write_draft(self.session, values, has_verify)
        except (CodevError, OSError) as exc:
            to_ui(self, self.notify, f"session: {exc}", severity="error")
        if before_verify is not None:
            # the law of the spec before its [verify] section is current, not stale
            every = stage_keys(before_verify, self.options)
            keys = {k: every[k] for k in ("model", "synthesis") if k in every}
        loaded = self._load_cached(chk, statuses, keys)
        to_ui(self, self._apply_check, chk, statuses, keys, loaded, plant, before_verify, seq)

    def _load_cached(
        self, chk: FormCheck, statuses: dict[str, StageStatus], keys: dict[str, str]
    ) -> dict[str, Any]:
        """Cached results for the current spec that the screens do not show yet (e.g. the
        user put Q back to a value synthesised before)."""
        out: dict[str, Any] = {}
        for stage, shown in (("synthesis", self.law_key), ("verification", self.result_key)):
            st = statuses.get(stage)
            if st is None or st.status != "cached" or st.artifact is None:
                continue
            if shown == keys.get(stage):
                continue
            try:
                # (the stage's loader, through the session: a law file, or the folder of a
                # law stored as shards, which marks it damaged if a shard read later is)
                out[stage] = self.session.load(stage, self.session.path / st.artifact,
                                               chk.problem)
            except (CodevError, OSError):
                continue
        return out

    def _apply_check(
        self,
        chk: FormCheck,
        statuses: dict[str, StageStatus],
        keys: dict[str, str],
        loaded: dict[str, Any],
        plant_only: tuple[Problem, str] | None = None,
        before_verify: Problem | None = None,
        seq: int = 0,
    ) -> None:
        if not self.query("#pipeline"):
            return  # the app is closing: its screen is gone
        if seq != self._check_seq:
            # an older check (its worker was replaced, but a thread runs to its end): the
            # form has changed since; the latest check's answer is on its way
            return
        self._checking = self._check_timer is not None
        self.statuses = statuses
        self.keys = keys
        for entry in self.query(FieldEntry):
            entry.set_error(chk.errors.get(entry.field_name))
        open_groups(self)  # an entry in error is never hidden in a collapsed group
        previous = self.check.general if self.check is not None else None
        if chk.general and chk.general != previous:  # once, not at every key
            self.notify(chk.general, severity="error", timeout=8)
        self.check = chk
        if "synthesis" in loaded:
            self.law, self.law_key = loaded["synthesis"], keys.get("synthesis")
        if "verification" in loaded:
            self.result, self.result_key = loaded["verification"], keys.get("verification")
            self.result_problem = chk.problem
        self._show_pipeline()
        self._before_verify = before_verify
        self.query_one(MpcPane).set_problem(chk.problem if chk.ok else before_verify)
        self.query_one(SynthesisPane).set_problem(chk.problem if chk.ok else before_verify)
        self._show_results()
        self.query_one(SessionPane).show_session(self.session, self.statuses)
        plant = self.query_one(PlantPane)
        # the report depends on the model stage's inputs only: re-derived when they change
        if chk.ok and chk.problem is not None:
            report_of: tuple[Problem, str | None] | None = (chk.problem, keys.get("model"))
        else:
            report_of = plant_only
        if report_of is not None:
            if report_of[1] != self._plant_report_key:
                self._plant_report_key = report_of[1]
                plant.show_report(report_of[0])
        elif plant.show_invalid(chk):
            self._plant_report_key = None  # the report was replaced by a message
        self._follow_design_name(chk)
        if self._pending_run is not None and not self._checking:
            stage, self._pending_run = self._pending_run, None
            self.run_stage(stage)

    def _follow_design_name(self, chk: FormCheck) -> None:
        """A new session (``sessions/untitled``) is renamed after the design's name, until
        its first stage run; an existing folder of that name is never touched."""
        if not self._follow_name or self._checking or self.busy is not None:
            return
        name = self.values.get("name", "").strip()
        if "name" in chk.errors or not _NAME_RE.fullmatch(name):
            return
        old = self.session.path
        new = old.parent / name
        if new == old or new.exists():
            return
        try:
            if self.session.journal():
                self._follow_name = False  # a stage ran here: the folder keeps its name
                return
            old.rename(new)
            self.session = Session.open(new)
        except (CodevError, OSError):
            self._follow_name = False
            return
        self._show_pipeline()
        self.query_one(SessionPane).show_session(self.session, self.statuses)

    def _show_pipeline(self) -> None:
        """The top line: the session and each stage's cache status for the current spec."""
        bar = self.query_one("#pipeline", Static)
        head = f"[b]codev[/b] {escape(str(self.session.path))} │ "
        chk = self.check
        if chk is None:
            bar.update(head + "checking the spec…")
            return
        if not chk.ok:
            bad = fields_by_tab(chk.errors) or chk.general or "?"
            bar.update(head + f"[red]✗ spec not valid[/red] — fix {escape(bad)}")
            return
        parts = []
        for stage in STAGES:
            if self.busy is not None and stage == self.busy:
                icon, colour = STATUS_STYLE["running"]
                parts.append(f"[{colour}]{icon} {stage} running[/{colour}]")
                continue
            st = self.statuses.get(stage)
            if st is None:
                continue
            icon, colour = STATUS_STYLE.get(st.status, ("?", "white"))
            parts.append(f"[{colour}]{icon} {stage} {st.status}[/{colour}]")
        bar.update(head + "  ".join(parts) + "   [dim]✓ spec saved[/dim]")

    def law_current(self) -> bool:
        """Whether the law shown was computed for the spec on screen.

        Returns
        -------
        bool
        """
        return self.law is not None and self.law_key == self.keys.get("synthesis")

    def result_current(self) -> bool:
        """Whether the verdict shown was computed for the spec on screen.

        Returns
        -------
        bool
        """
        return self.result is not None and self.result_key == self.keys.get("verification")

    def _show_results(self) -> None:
        """Hand the law and the verdict shown, and whether they are current, to their panes."""
        self.query_one(SynthesisPane).show_law(self.law, current=self.law_current())
        self.query_one(VerificationPane).show_result(
            self.result, problem=self.result_problem, current=self.result_current()
        )

    def _show_busy(self) -> None:
        for pane in (self.query_one(SynthesisPane), self.query_one(VerificationPane)):
            pane.show_busy(self.busy)

    # ---- stages ----------------------------------------------------------------------

    @unless_quitting
    def on_run_requested(self, event: RunRequested) -> None:
        self.run_stage(event.stage)

    @unless_quitting
    def on_cancel_requested(self, event: CancelRequested) -> None:
        self.action_cancel()

    def run_stage(self, upto: str) -> None:
        """Run the pipeline up to a stage in a worker (cached stages are loaded).

        Refused with a notification while a run is in flight, while the spec is not valid,
        or for a verification stage of a spec without ``[verify]``.

        Parameters
        ----------
        upto : str
            The last stage: ``"model"``, ``"synthesis"``, ``"verification"`` or
            ``"recording"``.
        """
        if self.busy is not None:
            self.notify(f"{self.busy} is running: wait, or cancel it (Esc)", severity="warning")
            return
        chk = self.check
        if chk is None or self._checking or self._check_timer is not None:
            # the form is being checked, or its check is scheduled (the keys just typed):
            # run once the answer is in
            self._pending_run = upto
            if self._check_timer is not None:
                self._schedule_check_now()
            self.notify(f"{upto} starts once the spec is checked", timeout=3)
            return
        problem = chk.problem
        if problem is None and upto in ("model", "synthesis"):
            problem = self._before_verify  # the stage needs none of the [verify] fields
        if problem is None:
            where = fields_by_tab(chk.errors)
            if upto == "model" and self._plant_report_key is not None:
                self.notify(
                    "the plant and model are valid: the derived model is on the right. "
                    f"The later stages need: {where}",
                    severity="warning",
                    timeout=8,
                )
                return
            msg = f"fix the fields marked in red — {where}" if where else chk.general
            self.notify(f"the spec is not valid yet: {msg}", severity="error", timeout=8)
            return
        if upto in ("verification", "recording") and problem.verify is None:
            self.notify(
                "the spec has no [verify] section: switch it on in the Verification tab",
                severity="error",
            )
            return
        self.busy = upto
        self._cancel.clear()
        self.progress = (upto, 0, time.perf_counter())
        self._show_pipeline()
        self._show_busy()
        self._stage_worker(problem, replace(self.options, upto=upto))

    @work(thread=True, exclusive=True, group="stage")
    def _stage_worker(self, problem: Problem, options: RunOptions) -> None:
        _lower_priority()

        def on_event(stage: str, event: str, data: dict) -> None:
            if self._cancel.is_set():
                raise RunCancelledError
            if event == "start":
                self.progress, self.doing = (stage, 0, time.perf_counter()), None
                self.regions_known = None
            elif event == "progress":
                p = self.progress
                self.progress = (
                    stage,
                    int(data.get("count", 0)),
                    p[2] if p else time.perf_counter(),
                )
                self.doing = data.get("doing")  # a long step's heartbeat (limits.beat)
                self.regions_known = data.get("regions")

        warnings: list[str] = []
        try:
            report = self.session.run(
                problem, options, on_event=on_event, warn=warnings.append, raise_errors=False
            )
        except RunCancelledError:
            to_ui(self, self._finish, None, "cancelled", warnings)
        except CodevError as exc:
            to_ui(self, self._finish, None, exc, warnings)
        except Exception as exc:  # an engine bug must not take the app (and the session) down
            to_ui(self, self._finish, None, exc, warnings)
        else:
            to_ui(self, self._finish, report, None, warnings)

    def _finish(self, report: RunReport | None, error: object, warnings: list[str]) -> None:
        stage = self.busy or ""
        self.busy = None
        self.progress = None  # the panes hear it in run_finished
        for w in warnings:
            self.notify(w, severity="warning", timeout=8)
        if error == "cancelled":
            self.notify(f"{stage} cancelled; nothing was saved for it", severity="warning")
        elif error is not None:
            field = getattr(error, "field", None)
            entry = field_for_error(field)
            msg = getattr(error, "reason", None) or str(error)
            if entry is not None:
                for e in self.query(FieldEntry):
                    if e.field_name == entry:
                        e.set_error(msg)
                open_groups(self)
            self.notify(f"{stage}: {error}", severity="error", timeout=10)
        if report is not None:
            self._take_report(report)
        self.query_one(SynthesisPane).run_finished(
            report, error, law=self.law, current=self.law_current()
        )
        self.query_one(VerificationPane).run_finished(
            report,
            error,
            result=self.result,
            problem=self.result_problem,
            current=self.result_current(),
        )
        self.query_one(SessionPane).run_finished(report, error)
        self._schedule_check()  # statuses and the journal moved on

    def _take_report(self, report: RunReport) -> None:
        if report.law is not None:
            sr = report.stage("synthesis")
            self.law, self.law_key = report.law, sr.key if sr else None
        if report.result is not None:
            sr = report.stage("verification")
            self.result, self.result_key = report.result, sr.key if sr else None
            self.result_problem = report.problem
        failed = next((s for s in report.stages if s.status == "failed"), None)
        if failed is not None:
            self.notify(
                f"{failed.stage} failed: {failed.outcome.get('message', '')}",
                severity="error",
                timeout=10,
            )
        else:
            done = report.stages[-1] if report.stages else None
            if done is not None:
                self.notify(f"{done.stage}: {done.status} in {done.seconds:.2f} s", timeout=4)

    # ---- the Sweep tab -----------------------------------------------------------------

    def sweep_folder(self) -> Path:
        """Where the current design's sweep is kept: ``<session>/sweep`` (one sweep session,
        :mod:`codev_engine.sweeps.folder`; a new grid replaces its table, the designs'
        sessions stay as caches).

        Returns
        -------
        Path
        """
        return self.session.path / "sweep"

    def _show_recorded_sweep(self) -> None:
        from codev_engine.sweeps.folder import read_sweep

        folder = self.sweep_folder()
        if not (folder / "sweep.json").is_file():
            return
        pane = self.query_one(SweepPane)
        try:
            recorded = read_sweep(folder)
        except CodevError as exc:
            pane.finished(f"the recorded sweep cannot be read: {exc}")
            return
        pane.set_grid_text("; ".join(
            f"{k}=" + ", ".join(_toml_value(v) for v in vals)
            for k, vals in recorded.grid.items()))
        pane.show_rows(list(recorded.grid), recorded.rows,
                       f"recorded sweep: {len(recorded.rows)} designs "
                       f"({len(recorded.journal)} run(s))")
        pane.finished(f"recorded sweep: {len(recorded.rows)} designs "
                      f"({len(recorded.journal)} run(s))", self._sweep_out(folder))

    def _sweep_out(self, folder: Path) -> str:
        from workbench.commands import runnable

        codev = runnable("codev")
        return (f"saved in {folder} · replay it: {codev} replay {folder} · "
                f"view it: {codev} view {folder / 'sweep.rrd'}")

    @unless_quitting
    def on_sweep_requested(self, event: SweepRequested) -> None:
        self.run_sweep(event.grid, event.workers)

    def run_sweep(self, text: str, workers: str = "") -> None:
        """Sweep the current design over the grid typed, in a worker; rows fill in as the
        designs finish.

        Refused with a notification while a run is in flight, while the spec is not valid,
        or for a grid the loader rejects (one line naming the field).

        Parameters
        ----------
        text : str
            ``FIELD=V1,V2,...`` items separated by ``;`` or new lines.
        workers : str, optional
            The number of local Dask worker processes to run the designs on; empty (default):
            serial in this process, or the cluster of ``$CODEV_SCHEDULER`` when set.
        """
        from codev_engine.sweeps import design_texts, grid_values, parse_sets

        if self.busy is not None:
            self.notify(f"{self.busy} is running: wait, or cancel it (Esc)", severity="warning")
            return
        chk = self.check
        if chk is None or not chk.ok or chk.problem is None:
            self.notify("the spec is not valid yet: the sweep varies a valid design",
                        severity="error", timeout=8)
            return
        items = [t.strip() for t in text.replace("\n", ";").split(";") if t.strip()]
        if not items:
            self.notify("type the fields to sweep: e.g. mpc.horizon=2,3; mpc.R=[[0.5]],[[1.0]]",
                        severity="warning", timeout=8)
            return
        n_workers = None
        if workers.strip():
            try:
                n_workers = int(workers)
                if n_workers < 1:
                    raise ValueError
            except ValueError:
                self.notify(f"sweep: workers: must be a positive whole number (or empty for "
                            f"serial), got {workers.strip()!r}", severity="error", timeout=10)
                return
        problem = chk.problem
        try:
            grid = parse_sets(items, origin="sweep")
            design_texts(problem, grid)  # every design through the loader, before any runs
        except CodevError as exc:
            self.notify(f"sweep: {exc}", severity="error", timeout=10)
            return
        folder = self.sweep_folder()
        self.busy = "sweep"
        self._cancel.clear()
        self._show_pipeline()
        pane = self.query_one(SweepPane)
        pane.start(list(grid), grid_values(grid), str(folder))
        self._sweep_worker(pane, problem, grid, folder, n_workers)

    @work(thread=True, exclusive=True, group="stage")
    def _sweep_worker(self, pane: SweepPane, problem: Problem, grid: dict, folder: Path,
                      workers: int | None = None) -> None:
        # (the pane is found on the UI thread: a thread that starts late, behind the
        # executor's other threads, could find the DOM already pruned by a quit)
        _lower_priority()
        from codev_engine.executor import Executor
        from codev_engine.sweeps import sweep

        t0 = time.perf_counter()

        def progress(i: int, row: dict) -> None:
            to_ui(self, pane.show_row, i, row)
            interrupt()

        def interrupt() -> None:  # polled inside the current design too (Esc stops it)
            if self._cancel.is_set():
                raise RunCancelledError

        try:
            # a local cluster lives for this sweep only (closed on cancel or failure too)
            with Executor(workers=workers) as executor:
                if executor.kind == "local":
                    _start_cluster(executor)
                rows = sweep(problem, grid, executor=executor, progress=progress,
                             session=folder, interrupt=interrupt)
        except RunCancelledError:
            to_ui(self, self._sweep_finished, None, "cancelled", 0.0, folder)
        except Exception as exc:  # an engine bug must not take the app down
            to_ui(self, self._sweep_finished, None, exc, 0.0, folder)
        else:
            to_ui(self, self._sweep_finished, rows, None, time.perf_counter() - t0, folder)

    def _sweep_finished(self, rows: list[dict] | None, error: object, seconds: float,
                        folder: Path) -> None:
        self.busy = None
        self._show_pipeline()
        pane = self.query_one(SweepPane)
        if error == "cancelled":
            pane.finished(f"sweep cancelled: the designs done are cached in {folder}, the "
                          "table was not saved")
            self.notify("sweep cancelled", severity="warning")
            return
        if error is not None or rows is None:
            pane.finished(f"sweep failed: {error}")
            self.notify(f"sweep: {error}", severity="error", timeout=10)
            return
        verdicts: dict[str, int] = {}
        for r in rows:
            v = "error" if r["error"] else str(r["verdict"])
            verdicts[v] = verdicts.get(v, 0) + 1
        note = (f"{len(rows)} designs in {seconds:.2f} s: "
                + ", ".join(f"{n} {v}" for v, n in verdicts.items()) + f" · saved in {folder}")
        pane.finished(note, self._sweep_out(folder))
        self.notify(f"sweep: {note}", timeout=6)

    def _tick(self) -> None:
        """10 Hz: show the running stage's progress (the worker only stores counters)."""
        if self.busy is None or self.progress is None or not self.is_running:
            # nothing runs, or the app is quitting: its panes are being pruned, leaves first
            # (the #pipeline line still up said nothing of the status lines already gone)
            return
        stage, count, started = self.progress
        elapsed = time.perf_counter() - started
        unit = {"synthesis": "regions", "verification": "branches"}.get(stage, "")
        doing = f" · {self.doing}" if self.doing else ""
        if self.regions_known is not None:  # (regions = "reached": the law grows as it runs)
            doing = f" · {self.regions_known} regions computed so far{doing}"
        text = (f"{stage}: {count} {unit}{doing} · {elapsed:.1f} s · Esc cancels"
                .replace("  ", " "))
        self.query_one(SynthesisPane).show_progress(stage, text)
        self.query_one(VerificationPane).show_progress(stage, text)

    # ---- actions ---------------------------------------------------------------------

    def action_show(self, tab: str) -> None:
        tabs = self.query_one("#tabs", TabbedContent)
        if tabs.active == tab:
            return
        # drop the focus first: a focused widget left in the hidden pane would pull the tabs
        # back to it (TabbedContent shows the pane holding the focus)
        self.screen.set_focus(None)
        tabs.active = tab
        # then straight into the tab's first field (set now, not after a refresh: a key
        # typed right after F2 is already queued behind this one)
        self.screen.set_focus(self._pane(tab).first_field())

    def _pane(self, tab: str) -> Any:
        return self.query_one(
            {
                "plant": PlantPane,
                "mpc": MpcPane,
                "synthesis": SynthesisPane,
                "verification": VerificationPane,
                "session": SessionPane,
                "sweep": SweepPane,
            }[tab]
        )

    def action_go(self) -> None:
        # the tab on screen when the key came; the run waits for the keys typed before it,
        # still queued in the focused entry (a priority key overtakes them)
        tab = self.query_one("#tabs", TabbedContent).active
        self._go_after_keys(tab, time.perf_counter() + 2.0)

    def _go_after_keys(self, tab: str, deadline: float) -> None:
        if not self.is_running:
            return  # quitting: the timer fired while the panes are being pruned
        if time.perf_counter() < deadline and any(e.keys_pending for e in self.query(FieldEntry)):
            self.set_timer(0.01, lambda: self._go_after_keys(tab, deadline))
            return
        self._go(tab)

    def _take_unseen_edits(self) -> bool:
        """Take into the form the editors' text that has not reached the app yet (the
        :class:`FieldEntry.Edited` messages on their way), and check the form now if any.

        Returns
        -------
        bool
            Whether an entry had such a change.
        """
        changed = False
        for entry in self.query(FieldEntry):
            text = entry.editor_text()
            if text is not None and text != self.values.get(entry.field_name, ""):
                self.values[entry.field_name] = text
                changed = True
        if changed:
            self._dirty = True
            self._schedule_check_now()
        return changed

    def _go(self, tab: str) -> None:
        self._take_unseen_edits()
        if tab == "mpc":
            self.query_one(MpcPane).run_preview()
            return
        if tab == "sweep":
            pane = self.query_one(SweepPane)
            self.run_sweep(pane.grid_text(), pane.workers_text())
            return
        # the same message as the tab's run button: one way in for every run
        self.post_message(RunRequested(TAB_STAGE.get(tab, "model")))

    def action_cancel(self) -> None:
        if self.busy is not None:
            self._cancel.set()
            self.notify(f"cancelling {self.busy}…", timeout=3)
        self.query_one(MpcPane).cancel_preview()

    @unless_quitting
    def on_save_requested(self, event: SaveRequested) -> None:
        self.action_save()

    def action_save(self) -> None:
        chk = self.check
        if chk is None or not chk.ok or chk.problem is None:
            write_draft(self.session, self.values, self.has_verify)
            self.notify(
                "the spec is not valid: your entries are kept in the session's draft "
                "(restored on the next start)",
                severity="warning",
            )
            return
        self.session.save_spec(chk.problem)
        self.notify(f"saved {self.session.spec_path()}")

    # ---- the Session tab: opening another target, exporting the recording ---------------

    @unless_quitting
    def on_open_requested(self, event: OpenRequested) -> None:
        try:
            opened = open_target(event.target)
        except CodevError as exc:
            self.notify(str(exc), severity="error", timeout=8)
            return
        self.load(opened)

    @unless_quitting
    def on_new_requested(self, event: NewRequested) -> None:
        self.action_new()

    def action_new(self) -> None:
        """Offer the templates of a new design (:class:`TemplateScreen`); the one picked is
        opened in a new session folder, every pane reset as by Open."""
        if self.busy is not None:
            self.notify("a stage is running: cancel it first", severity="warning")
            return
        if isinstance(self.screen, TemplateScreen):
            return
        self.push_screen(TemplateScreen(templates()), self._new_from)

    def _new_from(self, template: str | None) -> None:
        if template is None:
            return
        try:
            opened = new_design(template, sessions_root=self.sessions_root)
        except CodevError as exc:
            self.notify(str(exc), severity="error", timeout=8)
            return
        self.load(opened)
        # a new design starts where the plant is typed, on its first field
        self.action_show("plant")
        self.screen.set_focus(self._pane("plant").first_field())

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """The app's keys wait while a dialog (the *New* templates) is on screen: the
        workbench's widgets are not on that screen; and once the app quits (a key still
        queued then would act on panes being pruned)."""
        if action in ("go", "save", "new", "show", "cancel") and (
            not self.is_running or isinstance(self.screen, TemplateScreen)
        ):
            return None
        return True

    @unless_quitting
    def on_export_requested(self, event: ExportRequested) -> None:
        pane = self.query_one(SessionPane)
        try:
            out = self.session.export(event.recording, event.dest)
        except OSError as exc:
            pane.show_export(event.recording, event.dest, error=str(exc.strerror or exc))
            return
        pane.show_export(event.recording, event.dest, copied=out)

    @unless_quitting
    def on_law_export_requested(self, event: LawExportRequested) -> None:
        law = self.law
        if law is None:
            self.query_one(SynthesisPane).show_law_export(event.dest, error="no law yet")
            return
        dest = Path(event.dest).expanduser()
        if not dest.is_absolute():
            dest = Path.cwd() / dest
        self._law_export_worker(self.query_one(SynthesisPane), law, dest, event.dest)

    @work(thread=True, exclusive=True, group="export")
    def _law_export_worker(self, pane: SynthesisPane, law: ExplicitLaw, dest: Path,
                           typed: str) -> None:
        # the tree can take seconds (and compiles a kernel once): off the UI thread (the
        # pane found on it, as for the sweep: no DOM query in a thread)
        import re

        from codev_engine import export_c
        from codev_engine.deploy.escape import prefix_for

        # named after the design, made a prefix export_c accepts (no keyword, header...)
        name = prefix_for(str(law.meta.get("problem", "")))
        from codev_engine.kernel_cache import LATER, ready

        if not ready(LATER):  # the tree's kernels, once: said here (stderr is not seen)
            to_ui(self, self.notify,
                  "preparing the C export's kernels, once (about 15 s, then cached)")
        try:
            if hasattr(law, "merged"):  # (a law stored as shards: one C table, merged here)
                law = law.merged()
            h, c = export_c(law, dest, name=name)
        except (CodevError, OSError, ValueError) as exc:
            to_ui(self, pane.show_law_export, typed, error=str(exc))
            return
        text = h.read_text(encoding="utf-8")
        up = name.upper()
        nums = {k: re.search(rf"#define {up}_{k} (\d+)", text) for k in ("WORST_MACS", "ROM_BYTES")}
        summary = ", ".join(
            f"{label} {m.group(1)}"
            for label, m in (("worst case multiply-adds", nums["WORST_MACS"]),
                             ("ROM bytes", nums["ROM_BYTES"]))
            if m
        )
        to_ui(self, pane.show_law_export, typed, files=(str(h), c.name), summary=summary)

    def load(self, opened: Opened) -> None:
        """Switch to another session / spec (the Session tab's Open).

        Refused with a notification while a run is in flight. The entries, the
        ``[verify]`` switch and the results shown are replaced, and the form is checked.

        Parameters
        ----------
        opened : Opened
            The session and entries to switch to.
        """
        if self.busy is not None:
            self.notify("a stage is running: cancel it first", severity="warning")
            return
        self.session = opened.session
        self.values = dict(opened.values)
        self.has_verify = opened.has_verify
        self._dirty = opened.save_now
        self._follow_name = opened.follow_name
        self.law = self.result = None
        self.law_key = self.result_key = self.result_problem = None
        self._plant_report_key = None
        self._pending_run = None
        # nothing of the design before stays: its check, statuses, messages and every
        # pane's own state (preview, lookup, pictures, the recording's copy path)
        self.check = None
        self.statuses, self.keys = {}, {}
        self.clear_notifications()
        for pane in (
            self.query_one(MpcPane),
            self.query_one(SynthesisPane),
            self.query_one(VerificationPane),
            self.query_one(SessionPane),
            self.query_one(SweepPane),
        ):
            pane.reset()
        self._show_recorded_sweep()
        self.query_one(MpcPane).set_problem(None)
        self.query_one(SynthesisPane).set_problem(None)
        self._show_pipeline()
        for entry in self.query(FieldEntry):
            entry.set_text(self.values.get(entry.field_name, ""))
            entry.set_error(None)
        open_groups(self, errors=False, filled=True)  # the groups the design uses
        self.query_one(VerificationPane).set_enabled(self.has_verify)
        self._show_results()
        if opened.note:
            self.notify(opened.note)
        self._schedule_check_now()


def _toml_value(v: object) -> str:
    from codev_engine.io.toml import toml_literal

    return toml_literal(v)


def _start_cluster(executor) -> None:
    """Start a local Dask cluster from inside the app.

    The app holds ``sys.stderr`` (a capture with no usable file descriptor), which
    multiprocessing's resource tracker, started with the first worker, hands to the process
    it spawns: "bad value(s) in fds_to_keep", and no worker starts. So the cluster starts
    with ``sys.stderr`` on the null device (the tracker and the workers keep it: their
    messages must not land on the app's screen either).

    Parameters
    ----------
    executor : Executor
        A ``local`` executor; its client is started here.
    """
    import contextlib
    import os

    with open(os.devnull, "w") as null, contextlib.redirect_stderr(null):
        executor.client  # noqa: B018 - starts the cluster and its client


def _lower_priority(niceness: int = 10) -> None:
    """Give the calling worker thread (and the threads and processes it starts: the mp-QP
    pool) a lower CPU priority than the UI thread, so keys are answered at once even when
    the engine's workers keep every core busy. Linux schedules threads as tasks, so this
    does not touch the UI thread; elsewhere it is a no-op."""
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + niceness)
    except (AttributeError, OSError):
        pass


def _stores_shards(session: Session) -> bool:
    """The session's latest run stored its law as shards (``Session.last_options``)."""
    try:
        return session.last_options().sharded
    except CodevError:  # (a malformed journal: reported where the stages read it)
        return False
