"""Commands printed for the user to type: spelled so that they work from where the user is."""

from __future__ import annotations

import os
import shlex
import shutil
import sys
from pathlib import Path

__all__ = ["runnable"]


def runnable(tool: str) -> str:
    """How to start ``tool`` (``"codev"``, ``"rerun"``) from the current folder.

    The bare name when it is on ``PATH``; else the script installed beside the running
    interpreter (``.venv/bin/rerun`` in a checkout whose venv is not activated), relative to
    the current folder when it is below it; else ``python -m tool`` with this interpreter.

    Parameters
    ----------
    tool : str
        The command's name.

    Returns
    -------
    str
        A shell-quoted command prefix.
    """
    if shutil.which(tool):
        return tool
    beside = Path(sys.executable).parent / tool
    if beside.is_file() and os.access(beside, os.X_OK):
        try:
            rel = beside.relative_to(Path.cwd())
            return shlex.quote(str(rel))
        except ValueError:
            return shlex.quote(str(beside))
    module = "workbench.cli" if tool == "codev" else tool
    return f"{shlex.quote(sys.executable)} -m {module}"
