"""codev's front ends over ``codev_engine``: the command line (``cli``, the ``codev``
command) and the design workbench (``tui``, ``codev tui``).

The engine never imports this package.
"""

from __future__ import annotations

__all__ = ["run_workbench"]


def run_workbench(target: str | None, *, session_dir: str | None = None) -> int:
    """Open ``target`` (a spec, a session folder, or None) and run the app; exit status."""
    from workbench.tui.app import CodevApp
    from workbench.tui.state import open_target

    opened = open_target(target, session_dir=session_dir)
    CodevApp(opened).run()
    return 0
