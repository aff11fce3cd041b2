"""Sessions: a design's spec, its journal and its cached stage artifacts in one folder.

Import the public names from here (``from codev_engine.session import Session``); the
modules inside may change.
"""

from codev_engine.session.session import (
    SESSION_FORMAT,
    STAGES,
    ReplayReport,
    RunOptions,
    RunReport,
    Session,
    SessionError,
    StageReport,
    StageStatus,
    stage_keys,
)

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
