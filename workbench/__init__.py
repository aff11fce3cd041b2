"""codev's design workbench: a Textual app over ``codev_engine`` (``codev tui``).

The engine never imports this package; the workbench talks to the engine only through its
public API (spec loader, ``Session``, the law and result objects).
"""

from __future__ import annotations

__all__ = ["run_workbench"]


def run_workbench(target: str | None, *, session_dir: str | None = None) -> int:
    """Open ``target`` (a spec, a session folder, or None) and run the app; exit status."""
    from .app import CodevApp
    from .state import open_target

    opened = open_target(target, session_dir=session_dir)
    CodevApp(opened).run()
    return 0
