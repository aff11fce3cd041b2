"""codev's front ends over ``codev_engine``: the command line (``cli``, the ``codev``
command) and the design workbench (``tui``, ``codev tui``).

The engine never imports this package.
"""

from __future__ import annotations

__all__ = ["run_workbench"]


def run_workbench(target: str | None, *, session_dir: str | None = None) -> int:
    """Open a design in the terminal workbench and run it until the user quits.

    Parameters
    ----------
    target : str or None
        A spec file, a session folder, or None for an empty design.
    session_dir : str, optional
        The session folder to work in (default ``sessions/<spec name>``).

    Returns
    -------
    int
        The exit status (0).

    Raises
    ------
    SpecError, SessionError
        When ``target`` cannot be opened (the CLI prints one line and exits 2).
    """
    from workbench.tui.app import CodevApp
    from workbench.tui.state import open_target

    opened = open_target(target, session_dir=session_dir)
    # before the app takes the terminal: a fresh installation compiles its solver kernels
    # here, announced, not in the middle of the first synthesis or sweep
    from codev_engine.kernels import prepare

    prepare()
    CodevApp(opened).run()
    return 0
