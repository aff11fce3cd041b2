"""Sessions: a design's spec, its journal and its cached stage artifacts in one folder.

Import the public names from here (``from codev_engine.session import Session``); the
modules inside may change. They are, from the bottom up:

* :mod:`~codev_engine.session.store`: the folder, its lock, journal, spec snapshots and
  artifact index (atomic writes, checked reads);
* :mod:`~codev_engine.session.stages`: the stage table, each stage declared once;
* :mod:`~codev_engine.session.options`: the run options;
* :mod:`~codev_engine.session.keys`: the content hashes the artifacts are keyed by;
* :mod:`~codev_engine.session.reports`: what a run, a status query and a replay return;
* :mod:`~codev_engine.session.session`: :class:`Session` (run, status, replay, export).
"""

from codev_engine.session.keys import stage_keys
from codev_engine.session.options import RunOptions
from codev_engine.session.reports import ReplayReport, RunReport, StageReport, StageStatus
from codev_engine.session.session import Session
from codev_engine.session.stages import STAGES
from codev_engine.session.store import SESSION_FORMAT, SessionError

__all__ = [
    "SESSION_FORMAT",
    "STAGES",
    "RunOptions",
    "RunReport",
    "ReplayReport",
    "Session",
    "SessionError",
    "StageReport",
    "StageStatus",
    "stage_keys",
]
