"""Running ``codev`` as a real process from the tests (exit status, stderr, no mocks)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def run_codev(*args, cwd: str | Path, timeout: float = 300) -> subprocess.CompletedProcess:
    """``python -m workbench.cli ARGS`` in ``cwd``, output captured; ``CODEV_DEBUG`` is
    cleared so that bad input gives its one-line error, not a traceback."""
    env = {k: v for k, v in os.environ.items() if k != "CODEV_DEBUG"}
    return subprocess.run(
        [sys.executable, "-m", "workbench.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=timeout,
    )
