"""The Jupyter design panel: :class:`Workbench`, ipywidgets over a codev session.

The panel holds the design's fields (the MPC's and the verification's), the derived model,
and buttons that run the pipeline up to a stage through the same session machinery as the
TUI (:meth:`codev_engine.session.Session.run`): cached stages load, a changed field marks
the stages it feeds stale, every run is journaled so ``codev replay SESSION`` reproduces
it. A stage runs in a thread; its progress events move the bar, and Cancel raises from the
next one (as the TUI cancels). Results show as the engine's figures; a recording opens in
an embedded Rerun viewer (``rerun-notebook``) with the ``.rrd`` path beside it.
"""

from __future__ import annotations

import threading
import time
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

try:
    import ipywidgets as widgets
    from IPython.display import Markdown
except ImportError as exc:  # pragma: no cover - the notebook extra is not installed
    raise ImportError(
        "the notebook panel needs ipywidgets: pip install 'codev[notebook]'"
    ) from exc

from codev_engine import design_api
from codev_engine.errors import CodevError, SpecError
from codev_engine.pipeline import load_spec
from codev_engine.session import RunOptions, RunReport, Session, stage_keys
from codev_engine.spec.problem import Problem
from codev_engine.spec.toml_out import problem_data, toml_value

__all__ = ["FIELDS", "Workbench"]

#: the fields the panel edits: keyword of ``Problem.replace`` -> its table in the spec
FIELDS: dict[str, str] = {
    "horizon": "mpc", "norm": "mpc", "Q": "mpc", "R": "mpc", "x_min": "mpc", "x_max": "mpc",
    "u_min": "mpc", "u_max": "mpc", "time_horizon": "verify", "hold": "verify",
    "max_depth": "verify", "initial_set": "verify",
}  # fmt: skip
_CHOICES = {"norm": ("1", "inf", "2"), "hold": ("zoh", "continuous")}
_STAGES = ("model", "synthesis", "verification", "recording")
_STYLE = {"cached": "green", "computed": "green", "stale": "darkorange", "missing": "grey",
          "corrupt": "red", "failed": "red", "running": "royalblue"}  # fmt: skip


class _CancelledError(Exception):
    """Raised from the engine's progress callback when Cancel is pressed."""


class Workbench:
    """An interactive design panel for a problem, over a session folder.

    Parameters
    ----------
    design : Problem or str or Path
        A problem (``ce.design``, ``ce.load_spec``), a spec file, or a session folder.
    session : str or Path, optional
        The session folder (created if needed); default the folder given as ``design``, or
        ``sessions/<name>`` in the working folder.

    Attributes
    ----------
    fields : dict of str to ipywidgets.Widget
        The editable fields by keyword (``fields["horizon"].value = 8``); the text fields
        take TOML values (``[[1, 0], [0, 1]]``, ``inf``), an empty one drops the field.
    buttons : dict of str to ipywidgets.Button
        ``"synthesis"``, ``"verification"``, ``"recording"`` (run up to that stage) and
        ``"cancel"``.
    problem : Problem or None
        The design the fields state (None while a field is not valid: see ``message``).
    law, result : ExplicitLaw, VerificationResult or None
        The last ones computed or loaded.
    recording : Path or None
        The last recording (inside the session).
    report : RunReport or None
        The last run's report; ``error`` what ended it (``"cancelled"``, an exception).
    """

    def __init__(self, design: Problem | str | Path, *, session: str | Path | None = None):
        if isinstance(design, Problem):
            base = design
        elif (Path(design) / "session.json").is_file():
            session = session or design
            base = Session.open(design).problem()
        else:
            base = load_spec(design)
        self.session = Session.open_or_create(session or Path("sessions") / base.name)
        # (a session whose law is stored as shards keeps them: codev run --sharded)
        try:
            sharded = self.session.last_options().sharded
        except CodevError:  # (a malformed journal: reported where the stages read it)
            sharded = False
        self._options = RunOptions(sharded=sharded)
        self._base = base
        self.problem: Problem | None = base
        self.law: Any = None
        self.result: Any = None
        self.recording: Path | None = None
        self.report: RunReport | None = None
        self.error: object = None
        self.busy: str | None = None
        self._keys: dict[str, str] = {}
        self._shown: dict[str, str | None] = {"synthesis": None, "verification": None}
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self._build()
        self._refresh()
        self._load_cached()

    # ---- the widgets -----------------------------------------------------------------

    def _build(self) -> None:
        data = problem_data(self._base)
        self.fields = {}
        for kw, table in FIELDS.items():
            value = data.get(table, {}).get(kw)
            desc = f"{kw}"
            if kw == "horizon":
                w: Any = widgets.BoundedIntText(value=value, min=1, max=10**6, description=desc)
            elif kw == "max_depth":
                w = widgets.BoundedIntText(
                    value=value if value is not None else 6, min=0, max=64, description=desc
                )
            elif kw in _CHOICES:
                w = widgets.Dropdown(options=_CHOICES[kw], value=value or _CHOICES[kw][0],
                                     description=desc)  # fmt: skip
            else:
                w = widgets.Text(value="" if value is None else toml_value(value),
                                 description=desc, continuous_update=False)  # fmt: skip
            w.layout = widgets.Layout(width="340px")
            w.observe(self._edited, names="value")
            self.fields[kw] = w
        if self._base.verify is None:
            for kw, table in FIELDS.items():
                if table == "verify":
                    self.fields[kw].disabled = True
        self.buttons = {
            "synthesis": widgets.Button(description="Synthesise", button_style="primary"),
            "verification": widgets.Button(description="Verify", button_style="info"),
            "recording": widgets.Button(description="Record", button_style="info"),
            "cancel": widgets.Button(description="Cancel", button_style="warning",
                                     disabled=True),
        }  # fmt: skip
        for stage in ("synthesis", "verification", "recording"):
            self.buttons[stage].on_click(lambda _b, s=stage: self.run(s))
        self.buttons["cancel"].on_click(lambda _b: self.cancel())
        self.status = widgets.HTML()
        self.message = widgets.HTML()
        self.bar = widgets.FloatProgress(value=0.0, min=0.0, max=1.0, description="idle")
        self.progress = widgets.Label()
        self.model_out = widgets.Output()
        self.law_out = widgets.Output()
        self.result_out = widgets.Output()
        self.rrd_path = widgets.HTML()
        self.viewer_box = widgets.VBox()
        mpc = [w for kw, w in self.fields.items() if FIELDS[kw] == "mpc"]
        ver = [w for kw, w in self.fields.items() if FIELDS[kw] == "verify"]
        design = widgets.VBox([widgets.HTML("<b>MPC</b>"), *mpc,
                               widgets.HTML("<b>Verification</b>"), *ver],
                              layout=widgets.Layout(flex="0 0 360px"))  # fmt: skip
        self.law_out.layout = widgets.Layout(flex="1 1 auto", overflow="auto")
        self.tabs = widgets.Tab(children=[
            widgets.HBox([design, self.law_out]), self.model_out, self.result_out,
            widgets.VBox([self.rrd_path, self.viewer_box]),
        ])  # fmt: skip
        for i, title in enumerate(("Design", "Model", "Verification", "Recording")):
            self.tabs.set_title(i, title)
        run = widgets.HBox([*self.buttons.values(), self.bar, self.progress])
        self.widget = widgets.VBox(
            [self.status, run, self.message, self.tabs], layout=widgets.Layout(width="100%")
        )
        self.widget.add_class("codev-workbench")
        self._show_model()

    def _ipython_display_(self) -> None:
        from IPython.display import display

        display(self.widget)

    # ---- the fields ------------------------------------------------------------------

    def values(self) -> dict[str, Any]:
        """The fields' values as keywords of ``Problem.replace`` (text read as TOML).

        Returns
        -------
        dict
            Keyword -> value; an empty text field gives None (the field left out).

        Raises
        ------
        SpecError
            A text field that is not a TOML value, naming its keyword.
        """
        out: dict[str, Any] = {}
        for kw, w in self.fields.items():
            if w.disabled:
                continue
            value = w.value
            if isinstance(value, str) and kw not in _CHOICES:
                text = value.strip()
                if not text:
                    out[kw] = None
                    continue
                try:  # TOML, the spec's syntax: never Python, never code
                    value = tomllib.loads(f"v = {text}")["v"]
                except tomllib.TOMLDecodeError as exc:
                    raise SpecError(f"not a TOML value ({exc})", field=kw) from None
            out[kw] = value
        return out

    def _edited(self, _change: dict) -> None:
        try:
            self.problem = design_api.replace(self._base, check_mpc=False, **self.values())
            self.message.value = ""
        except SpecError as exc:
            self.problem = None
            self.message.value = f"<span style='color:red'>✗ {_escape(str(exc))}</span>"
        self._refresh()

    # ---- status and stale marks --------------------------------------------------------

    def statuses(self) -> dict[str, str]:
        """Each stage's status for the fields as they are: cached, stale, missing, ...

        Returns
        -------
        dict
            Stage name -> status (the session's; ``"running"`` for the stage running).
        """
        if self.problem is None:
            return {}
        out = {s.stage: s.status for s in self.session.status(self.problem, self._options)}
        if self.busy is not None:
            out[self.busy] = "running"
        return out

    def _refresh(self) -> None:
        """The status line, and the stale marks on the pictures shown."""
        head = f"<b>codev</b> {_escape(str(self.session.path))} │ "
        if self.problem is None:
            self.status.value = head + "<span style='color:red'>✗ the design is not valid</span>"
            self._keys = {}
        else:
            self._keys = stage_keys(self.problem, self._options)
            parts = [
                f"<span style='color:{_STYLE.get(st, 'black')}'>{stage} {st}</span>"
                for stage, st in self.statuses().items()
            ]
            self.status.value = head + " · ".join(parts)
        for stage, out in (("synthesis", self.law_out), ("verification", self.result_out)):
            stale = self._shown[stage] is not None and self._shown[stage] != self._keys.get(stage)
            if stale:
                out.add_class("codev-stale")
                out.layout.border = "2px dashed darkorange"
            else:
                out.remove_class("codev-stale")
                out.layout.border = None

    def stale(self, stage: str) -> bool:
        """Whether the picture shown for ``stage`` was computed for other fields.

        Parameters
        ----------
        stage : str
            ``"synthesis"`` or ``"verification"``.

        Returns
        -------
        bool
        """
        shown = self._shown.get(stage)
        return shown is not None and shown != self._keys.get(stage)

    # ---- running stages ----------------------------------------------------------------

    def run(self, upto: str) -> None:
        """Run the pipeline up to a stage in a thread (cached stages load).

        Parameters
        ----------
        upto : str
            ``"model"``, ``"synthesis"``, ``"verification"`` or ``"recording"``.
        """
        if self.busy is not None:
            self._say(f"{self.busy} is running: wait, or cancel it", "darkorange")
            return
        if self.problem is None:
            self._say("fix the design first (see the message above)", "red")
            return
        if upto in ("verification", "recording") and self.problem.verify is None:
            self._say("the design has no verification section", "red")
            return
        # the feasibility check the field edits skip (an LP) is the session's: it runs it
        # for the stages not cached, so a cached stage returns at once
        problem = self.problem
        stages = list(_STAGES[: _STAGES.index(upto) + 1])
        self.busy, self.error = upto, None
        self._cancel.clear()
        self.buttons["cancel"].disabled = False
        self.bar.value, self.bar.description, self.bar.bar_style = 0.0, upto, ""
        self._refresh()
        self._thread = threading.Thread(
            target=self._work, args=(problem, upto, stages), name="codev-stage", daemon=True
        )
        self._thread.start()

    def _work(self, problem: Problem, upto: str, stages: list[str]) -> None:
        t0 = time.perf_counter()
        done: list[str] = []

        def on_event(stage: str, event: str, data: dict) -> None:
            if self._cancel.is_set():
                raise _CancelledError
            if event == "done":
                done.append(stage)
                self.bar.value = len(done) / len(stages)
            elif event in ("start", "progress"):
                count = data.get("count")
                what = f" · {count} found" if count is not None else ""
                self.progress.value = f"{stage}{what} · {time.perf_counter() - t0:.1f} s"

        report, error = None, None
        try:
            report = self.session.run(
                problem, replace(self._options, upto=upto), on_event=on_event, raise_errors=False
            )
        except _CancelledError:
            error = "cancelled"
        except CodevError as exc:
            error = exc
        except Exception as exc:  # an engine bug must not leave the panel busy
            error = exc
        self._finish(report, error, time.perf_counter() - t0)

    def _finish(self, report: RunReport | None, error: object, seconds: float) -> None:
        stage, self.busy = self.busy, None
        self.report, self.error = report, error
        self.buttons["cancel"].disabled = True
        if error == "cancelled":
            self.bar.bar_style = "warning"
            self._say(f"{stage} cancelled: nothing was saved for it", "darkorange")
        elif error is not None:
            self.bar.bar_style = "danger"
            self._say(f"✗ {stage}: {error}", "red")
        if report is not None:
            self._take(report)
            failed = next((s for s in report.stages if s.status == "failed"), None)
            if failed is not None:
                self.bar.bar_style = "danger"
                self._say(f"✗ {failed.stage} failed: {failed.outcome.get('message', '')}",
                          "red")  # fmt: skip
            else:
                self.bar.value, self.bar.bar_style = 1.0, "success"
                said = ", ".join(f"{s.stage} {s.status}" for s in report.stages)
                self._say(f"run {report.run}: {said} in {report.seconds:.2f} s", "green")
        self.progress.value = f"{stage} · {seconds:.2f} s"
        self._refresh()

    def _take(self, report: RunReport) -> None:
        sr = report.stage("synthesis")
        if report.law is not None and sr is not None:
            self._show("synthesis", report.law, sr.key)
        sr = report.stage("verification")
        if report.result is not None and sr is not None:
            self._show("verification", report.result, sr.key)
        if report.recording is not None:
            self._show_recording(Path(report.recording))

    def _show(self, stage: str, value: Any, key: str) -> None:
        out = self.law_out if stage == "synthesis" else self.result_out
        if stage == "synthesis":
            self.law = value
        else:
            self.result = value
        if self._shown[stage] == key and out.outputs:
            return  # that picture is on screen: a cached stage costs no redraw
        self._shown[stage] = key
        _replace_output(out, value)  # the engine's own figure and summary

    def _load_cached(self) -> None:
        """The cached law and verdict of the design as it is, shown at once."""
        if self.problem is None:
            return
        for st in self.session.status(self.problem, self._options):
            if st.stage not in ("synthesis", "verification") or st.status != "cached" \
                    or st.artifact is None:
                continue
            try:
                # (the stage's loader, through the session: a law file, or the folder of a
                # law stored as shards, which marks it damaged if a shard read later is)
                value = self.session.load(st.stage, self.session.path / st.artifact,
                                          self.problem)
                self._show(st.stage, value, st.key)
            except (CodevError, OSError):
                continue
        self._refresh()

    def _show_model(self) -> None:
        try:
            from workbench.tui.design import plant_report

            text, _model = plant_report(self._base)
        except CodevError as exc:
            text = f"✗ {exc}"
        _replace_output(self.model_out, Markdown(text))

    def _show_recording(self, path: Path) -> None:
        self.recording = path
        self.rrd_path.value = f"recording: <code>{_escape(str(path.resolve()))}</code>"
        try:
            import rerun_notebook
        except ImportError:
            self.viewer_box.children = [widgets.HTML(
                "open it with <code>rerun FILE.rrd</code> (the embedded viewer needs "
                "<code>pip install 'codev[notebook]'</code>)")]  # fmt: skip
            return
        viewer = rerun_notebook.Viewer(width="auto", height=480)
        data = path.read_bytes()

        def ready(_w: Any, content: Any, _buffers: Any) -> None:
            if content == "ready":  # the viewer's page has loaded: hand it the file
                viewer.send_rrd(data)

        viewer.on_msg(ready)
        self.viewer_box.children = [viewer]

    def cancel(self) -> None:
        """Cancel the stage running (it stops at its next progress event)."""
        self._cancel.set()

    def wait(self, timeout: float | None = None) -> RunReport | None:
        """Wait for the stage running to end (for scripts and tests driving the panel).

        Parameters
        ----------
        timeout : float, optional
            Seconds; None waits as long as it takes.

        Returns
        -------
        RunReport or None
            The run's report (None: it failed or was cancelled, see ``error``).
        """
        if self._thread is not None:
            self._thread.join(timeout)
        return self.report

    def _say(self, text: str, colour: str) -> None:
        self.message.value = f"<span style='color:{colour}'>{_escape(text)}</span>"


def _replace_output(out: Any, obj: object) -> None:
    """Show ``obj`` alone in an Output widget, from any thread.

    Not ``clear_output()``: from a thread it is a message to the front end, whose cleared
    outputs sync back after (and over) the ones appended here -- the partition never showed
    in JupyterLab. Both steps here set the widget's ``outputs`` on this side.
    """
    out.outputs = ()
    out.append_display_data(obj)


def _escape(text: str) -> str:
    import html

    return html.escape(text, quote=True)
