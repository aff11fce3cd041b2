"""Widgets shared by the panes: a spec-field entry with its inline error, and a plot.

Their styles are in ``workbench.tcss`` with the rest of the app's.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping

from rich.text import Text
from textual import events, work
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.message import Message
from textual.widget import Widget
from textual.widgets import Collapsible, Input, Label, Select, Static, Switch, TextArea

from .form import FIELD_BY_NAME, FieldDef
from .handoff import to_ui

__all__ = ["EntryInput", "EntryTextArea", "FieldEntry", "Plot", "field_entries", "open_groups"]

#: a multi-line entry grows with its lines up to this many, then scrolls
TEXT_LINES_MAX = 8


class _KeysInOrder:
    """An editor that runs its own key bindings (backspace, delete, arrows, Enter, …) as it
    takes each key, in the order typed.

    Textual runs a widget's bindings only when the key has gone back up to the app, while
    a printable key is inserted at once: under load a backspace typed before a ``5`` was
    applied after it, and one typed before a Tab or an F-key (priority keys, handled as they
    arrive) was applied to the field the focus had moved to (issue 23).
    """

    _keys_queued = 0  # keys posted to the editor and not handled yet

    @property
    def keys_pending(self) -> bool:
        """Whether keys sent to the editor wait in its queue (not taken yet)."""
        return self._keys_queued > 0

    def post_message(self, message: Message) -> bool:
        queued = super().post_message(message)  # type: ignore[misc]
        if queued and isinstance(message, events.Key):
            self._keys_queued += 1
        return queued

    async def on_event(self, event: events.Event) -> None:
        try:
            await super().on_event(event)  # type: ignore[misc]
        finally:
            if isinstance(event, events.Key):
                self._keys_queued = max(0, self._keys_queued - 1)

    async def _on_key(self, event: events.Key) -> None:
        if not event.is_printable:
            for binding in self._bindings.key_to_bindings.get(event.key, ()):  # type: ignore[attr-defined]
                if binding.priority:
                    continue
                if await self.app.run_action(binding.action, self):  # type: ignore[attr-defined]
                    event.stop()
                    event.prevent_default()
                    return
        await super()._on_key(event)  # type: ignore[misc]


class EntryInput(_KeysInOrder, Input):
    """A one-line :class:`~textual.widgets.Input` that takes its keys in the order typed."""


class EntryTextArea(_KeysInOrder, TextArea):
    """A :class:`~textual.widgets.TextArea` that takes its keys in the order typed."""


def _dom_id(name: str) -> str:
    return "f-" + name.replace(".", "-").replace("_", "-")


class FieldEntry(Vertical):
    """One spec field: label, editor (input, text area, select or switch), help / error line.

    Posts :class:`FieldEntry.Edited` with the entry's text on every change.

    Parameters
    ----------
    name : str
        The field's name (a :attr:`~workbench.tui.form.FieldDef.name` of
        :data:`~workbench.tui.form.FIELDS`); the widget's DOM id is made from it.
    text : str
        The entry's text at start.

    Attributes
    ----------
    field : FieldDef
        The field edited.
    """

    class Edited(Message):
        """The user changed the entry's text (not posted for :meth:`FieldEntry.set_text`).

        Parameters
        ----------
        entry : FieldEntry
            The entry that changed.
        name : str
            Its field's name.
        text : str
            Its new text.
        """

        def __init__(self, entry: FieldEntry, name: str, text: str) -> None:
            super().__init__()
            self.entry = entry
            self.name = name
            self.text = text

    def __init__(self, name: str, text: str = "") -> None:
        super().__init__(id=_dom_id(name))
        self.field: FieldDef = FIELD_BY_NAME[name]
        self._text = text
        self._loading = True

    @property
    def field_name(self) -> str:
        """The field's dotted name (``"mpc.Q"``)."""
        return self.field.name

    def compose(self) -> ComposeResult:
        fd = self.field
        star = " *" if fd.required else ""
        yield Label(f"{fd.label}{star}  [dim]{fd.name}[/dim]")
        # an empty optional entry shows the value the engine takes for it
        shown = f"default: {fd.default}" if fd.default else ""
        if fd.kind in ("expressions", "sets"):
            yield EntryTextArea(
                self._text,
                id="editor",
                soft_wrap=False,
                show_line_numbers=False,
                placeholder=shown,
            )
        elif fd.kind == "choice":
            options = [(c, c) for c in fd.choices]
            value = self._text if self._text in fd.choices else Select.NULL
            # blank allowed even for a required choice: it starts empty, not on its first
            # option (the check reports it as required)
            yield Select(
                options,
                value=value,
                id="editor",
                allow_blank=True,
                prompt=shown or "choose: " + ", ".join(fd.choices),
                compact=True,
            )
        elif fd.kind == "bool":
            yield Switch(value=self._text.strip().lower() == "true", id="editor")
        else:
            # the focus puts the cursor at the end: a key typed after F1 adds to the name,
            # it does not replace the selected name
            yield EntryInput(
                self._text, id="editor", compact=True, placeholder=shown, select_on_focus=False
            )
        yield Static(fd.help, classes="help", id="help")

    def on_mount(self) -> None:
        self._loading = False
        for area in self.query(TextArea):
            self._fit(area)

    @property
    def editor(self) -> Widget:
        """The entry's editor: the widget that takes the keys typed into the field."""
        return self.query_one("#editor")

    # ---- value -----------------------------------------------------------------------

    @property
    def text(self) -> str:
        """The entry's current text (a switch's is ``"true"`` or ``"false"``)."""
        return self._text

    def set_text(self, text: str) -> None:
        """Show a new value (from a loaded spec) without posting Edited.

        Parameters
        ----------
        text : str
            The entry's text (a choice not among the field's choices shows the default).
        """
        self._text = text
        editor = self.query_one("#editor")
        self._loading = True
        try:
            if isinstance(editor, Input):
                editor.value = text
            elif isinstance(editor, TextArea):
                editor.text = text
            elif isinstance(editor, Select):
                editor.value = text if text in self.field.choices else Select.NULL
            elif isinstance(editor, Switch):
                editor.value = text.strip().lower() == "true"
        finally:
            self.call_after_refresh(self._done_loading)

    @property
    def keys_pending(self) -> bool:
        """Whether keys typed into the entry's editor are still waiting in its queue."""
        editor = self.query_one("#editor")
        return isinstance(editor, _KeysInOrder) and editor.keys_pending

    def editor_text(self) -> str | None:
        """The editor's text as it is now, ahead of the :class:`Edited` messages on their
        way to the app (keys typed just before a priority key such as ctrl+g).

        Returns
        -------
        str or None
            The text (a choice's value, ``""`` when blank); None for a switch (which
            posts its change at once) or while a loaded value is being shown.
        """
        if self._loading:
            return None
        editor = self.query_one("#editor")
        if isinstance(editor, Input):
            return editor.value
        if isinstance(editor, TextArea):
            return editor.text
        if isinstance(editor, Select):
            value = editor.value
            if value is Select.NULL or value is None:
                # blank, or a loaded value the list cannot show ("Inf"): kept as it is
                return "" if self._text in self.field.choices else None
            return str(value)
        return None

    def _done_loading(self) -> None:
        self._loading = False

    _error: str | None = None

    def set_error(self, message: str | None) -> None:
        """Show an error under the entry in place of its help line.

        Parameters
        ----------
        message : str or None
            The error; None goes back to the help line.
        """
        if message == self._error:
            return  # every form check calls this on every entry
        self._error = message
        self.set_class(message is not None, "-error")
        self.query_one("#help", Static).update(
            Text(f"✗ {message}") if message else Text(self.field.help)
        )

    def _changed(self, text: str) -> None:
        if text == self._text:
            return
        self._text = text
        if not self._loading:
            self.post_message(self.Edited(self, self.field.name, text))

    def on_input_changed(self, event: Input.Changed) -> None:
        event.stop()
        self._changed(event.value)

    def on_text_area_changed(self, event: TextArea.Changed) -> None:
        event.stop()
        self._fit(event.text_area)
        self._changed(event.text_area.text)

    def _fit(self, area: TextArea) -> None:
        """A multi-line entry as tall as its lines (2 to TEXT_LINES_MAX, then it scrolls):
        TORA's four dynamics, a pendulum's unsafe box written over five lines (issue 41)."""
        lines = min(max(area.document.line_count, 2), TEXT_LINES_MAX)
        area.styles.height = lines + 2  # (the tall border's two rows)

    def on_key(self, event: events.Key) -> None:
        """A character typed on a closed choice picks the (next) choice starting with it:
        ``i`` on Norm is ``inf``, no list to open and no arrow keys to time."""
        editor = self.query_one("#editor")
        if not isinstance(editor, Select) or editor.expanded or not event.character:
            return
        c = event.character.lower()
        matches = [ch for ch in self.field.choices if ch.lower().startswith(c)]
        if not matches:
            return
        event.stop()
        event.prevent_default()
        now = editor.value if editor.value in matches else None
        editor.value = matches[(matches.index(now) + 1) % len(matches)] if now else matches[0]

    def on_select_changed(self, event: Select.Changed) -> None:
        event.stop()
        value = event.value
        self._changed("" if value is Select.NULL or value is None else str(value))

    def on_switch_changed(self, event: Switch.Changed) -> None:
        event.stop()
        self._changed("true" if event.value else "false")


def field_entries(names: Iterable[str], values: Mapping[str, str]) -> list[Widget]:
    """A tab's entries in screen order; those of a :attr:`FieldDef.group` inside one
    :class:`~textual.widgets.Collapsible` per group, collapsed unless one of its entries
    has a value.

    Parameters
    ----------
    names : iterable of str
        The tab's fields, in screen order (a group's fields are consecutive).
    values : Mapping of str to str
        The form's entries at start: field name → text.

    Returns
    -------
    list of Widget
        :class:`FieldEntry` and :class:`~textual.widgets.Collapsible` widgets, to yield
        from a ``compose``.
    """
    # (group or "", its entries) in screen order; an ungrouped entry is a group of its own
    runs: list[tuple[str, list[FieldEntry]]] = []
    for name in names:
        group = FIELD_BY_NAME[name].group
        entry = FieldEntry(name, values.get(name, ""))
        if group and runs and runs[-1][0] == group:
            runs[-1][1].append(entry)
        else:
            runs.append((group, [entry]))
    out: list[Widget] = []
    for group, members in runs:
        if not group:
            out.extend(members)
            continue
        out.append(
            Collapsible(
                *members,
                title=group,
                collapsed=not any(values.get(e.field_name, "").strip() for e in members),
                id="g-" + re.sub(r"[^a-z0-9]+", "-", group.lower()).strip("-"),
                classes="group",
            )
        )
    return out


def open_groups(root: Widget, *, errors: bool = True, filled: bool = False) -> None:
    """Expand the collapsed groups under ``root`` that hold an entry in error (or filled).

    Parameters
    ----------
    root : Widget
        The app or a pane.
    errors : bool
        Expand a group with an entry marked in error.
    filled : bool
        Expand a group with an entry that has text, and collapse one without (a design
        just opened).
    """
    for group in root.query(Collapsible):
        entries = list(group.query(FieldEntry))
        if filled:
            group.collapsed = not any(e.text.strip() for e in entries)
        if errors and any(e.has_class("-error") for e in entries):
            group.collapsed = False


class Plot(Static):
    """A picture drawn to the widget's size by ``draw(width, height) -> Text`` in a thread.

    Redrawn on resize and on :meth:`set_draw`; the last picture stays up meanwhile, so a slow
    partition never blocks the keyboard.

    Parameters
    ----------
    placeholder : str
        Shown until a drawing is set, and when it is unset without a placeholder of its own.
    **kwargs
        Passed to :class:`textual.widgets.Static` (``id``, ``classes``, ...).
    """

    def __init__(self, placeholder: str = "", **kwargs) -> None:
        super().__init__(placeholder, **kwargs)
        self._draw: Callable[[int, int], Text] | None = None
        self._placeholder = placeholder
        self._drawn = 0  # the latest picture asked for (see _show)
        self._asked_size: tuple[int, int] | None = None  # the size it was asked for
        self._shown_request = 0  # the request whose picture is up

    def set_draw(self, draw: Callable[[int, int], Text] | None, placeholder: str = "") -> None:
        """Draw the picture with ``draw``, now and on every resize, in a worker thread.

        Parameters
        ----------
        draw : callable or None
            ``draw(width, height) -> rich.text.Text``, with the size in cells left for the
            picture; an exception it raises is shown in place of the picture. None: no
            picture, the placeholder is shown.
        placeholder : str
            Shown when ``draw`` is None (empty: the widget's placeholder).
        """
        self._draw = draw
        if draw is None:
            self.update(placeholder or self._placeholder)
        else:
            self._redraw()

    def on_resize(self) -> None:
        if self._draw is not None:
            self._redraw()

    def _redraw(self) -> None:
        w, h = self.content_size.width, self.content_size.height
        if w < 12 or h < 4 or self._draw is None:
            return
        self._drawn += 1
        self._asked_size = (w, h)
        self._render_in_thread(self._draw, w, h, self._drawn)

    @property
    def up_to_date(self) -> bool:
        """Whether the picture up is the latest drawing's, for the widget's size as laid out
        now: False while its thread draws, and from a resize until its new picture is up
        (a screenshot taken then showed a picture of the size before)."""
        w, h = self.content_size.width, self.content_size.height
        if self._draw is None or w < 12 or h < 4:
            return True  # a placeholder, or too small to draw (the picture is not redrawn)
        return self._shown_request == self._drawn and self._asked_size == (w, h)

    @work(thread=True, exclusive=True, group="plot")
    def _render_in_thread(
        self, draw: Callable[[int, int], Text], w: int, h: int, request: int
    ) -> None:
        # leave room for the axes (margin ~7 cells, two caption lines)
        try:
            text = draw(max(w - 8, 4), max(h - 3, 2))
        except Exception as exc:  # a picture must never take the app down
            text = Text(f"(cannot draw: {type(exc).__name__}: {exc})", style="red")
        to_ui(self, self._show, request, text)

    def _show(self, request: int, text: Text) -> None:
        # a thread cannot be stopped: a picture for an older size or drawing may finish
        # after the latest one, and must not replace it (seen as a plot one row short
        # after the last resize)
        if request == self._drawn:
            self.update(text)
            self._shown_request = request
