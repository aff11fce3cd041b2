"""Handing a worker thread's result to the UI thread, safely at shutdown.

A thread worker cannot be stopped: a table's rows, a picture or a report may be ready after
the app began to close and pruned the panes' widgets. Applied then, the result's
``query_one`` raises ``NoMatches`` inside the worker, and Textual ends the app with
``WorkerFailed`` (seen in CI on a test that quit while the region table was still being
filled). The app stops running (``is_running``) before it removes any widget, so a result
that arrives later is dropped: there is nothing left to show it on. The same holds for a
pane's request (run, sweep, save, export...) the app takes from its queue while it quits
(:func:`unless_quitting`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

from textual.app import App
from textual.message_pump import MessagePump

_Handler = TypeVar("_Handler", bound=Callable[..., Any])


def to_ui(node: MessagePump, callback: Callable[..., Any], *args: Any, **kwargs: Any) -> None:
    """Run ``callback(*args, **kwargs)`` on the UI thread, unless the app has stopped running.

    Parameters
    ----------
    node : MessagePump
        The app, or the widget whose worker hands the result over.
    callback : callable
        What applies the result to the widgets; runs on the UI thread.
    *args, **kwargs
        Its arguments.
    """
    app = node if isinstance(node, App) else node.app

    def if_running() -> None:
        # checked on the UI thread: the flag cannot change while this runs
        if app.is_running:
            callback(*args, **kwargs)

    if not app.is_running:
        return
    try:
        app.call_from_thread(if_running)
    except RuntimeError:
        # the loop closed between the check and the call: only a stopped app gets here
        if app.is_running:
            raise


def unless_quitting(handler: _Handler) -> _Handler:
    """Make an app's message handler do nothing once the app has stopped running.

    The app's message loop runs on while a quit prunes the panes (its own queue closes
    last): a request a pane posted just before the quit (a button, ctrl+g) would be handled
    then, and its handler's ``query_one`` raise ``NoMatches`` on a pane already gone.

    Parameters
    ----------
    handler : callable
        ``handler(app, message)``, a method of the app.

    Returns
    -------
    callable
        The handler, skipped while ``app.is_running`` is False.
    """

    @functools.wraps(handler)
    def guarded(app: App, *args: Any, **kwargs: Any) -> Any:
        if not app.is_running:
            return None
        return handler(app, *args, **kwargs)

    return guarded  # type: ignore[return-value]
