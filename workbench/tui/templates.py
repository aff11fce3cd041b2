"""The *New* dialog: pick what a new design starts from (a blank form or a bundled example).

A modal screen over the workbench: the list of templates
(:func:`~workbench.tui.state.templates`), Enter picks one, Esc keeps the design on screen.
The screen is dismissed with the template's key (or None); the app opens the new design
(:func:`~workbench.tui.state.new_design`) as the Session tab's Open does.
"""

from __future__ import annotations

from rich.markup import escape
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Vertical
from textual.screen import ModalScreen
from textual.widgets import Label, OptionList, Static
from textual.widgets.option_list import Option

__all__ = ["TemplateScreen"]


class TemplateScreen(ModalScreen[str | None]):
    """A list of templates; dismissed with the key picked, or None (Esc).

    Parameters
    ----------
    choices : list of tuple of (str, str)
        ``(key, description)`` per template, in the order shown (the first is highlighted).
    """

    BINDINGS = [Binding("escape", "dismiss_none", "Keep the design on screen")]

    def __init__(self, choices: list[tuple[str, str]]) -> None:
        super().__init__()
        self._choices = choices

    def compose(self) -> ComposeResult:
        width = max((len(k) for k, _ in self._choices), default=5) + 2
        with Vertical(id="new-dialog"):
            yield Label("[b]New design[/b]: start from")
            yield OptionList(
                *(
                    Option(f"{escape(key):<{width}}[dim]{escape(about)}[/dim]", id=key)
                    for key, about in self._choices
                ),
                id="templates",
            )
            yield Static(
                "Enter: a new session with it · Esc: keep the design on screen", classes="small"
            )

    def on_mount(self) -> None:
        self.query_one(OptionList).focus()

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        event.stop()
        self.dismiss(event.option.id)

    def action_dismiss_none(self) -> None:
        """Close the dialog without a choice (the design on screen stays)."""
        self.dismiss(None)
