"""What a session run, status query and replay return: plain data."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from codev_engine.law import ExplicitLaw
    from codev_engine.plant import LinearModel
    from codev_engine.reach.verification import VerificationResult
    from codev_engine.spec.problem import Problem

__all__ = ["ReplayReport", "RunReport", "StageReport", "StageStatus"]


@dataclass(frozen=True)
class StageReport:
    """What one stage did in a run.

    Attributes
    ----------
    stage : str
    status : str
        "computed", "cached", "skipped" or "failed".
    key : str
        The stage key.
    seconds : float
        Wall time of the stage (loading or computing, describing).
    outcome : dict
        The fields a replay compares (regions, verdict, ...); for "failed", the error.
    details : dict
        The rest (timings, sizes).
    artifact : str or None
        The artifact's path relative to the session folder.
    note : str or None
        Why a cached artifact was not used.
    """

    stage: str
    status: str
    key: str
    seconds: float
    outcome: dict[str, Any]
    details: dict[str, Any] = field(default_factory=dict)
    artifact: str | None = None
    note: str | None = None

    def to_json(self) -> dict[str, Any]:
        """The report as the ``data`` of a "done" event."""
        return {
            "stage": self.stage,
            "status": self.status,
            "key": self.key,
            "seconds": round(self.seconds, 6),
            "outcome": self.outcome,
            "details": self.details,
            "artifact": self.artifact,
            "note": self.note,
        }


@dataclass
class RunReport:
    """The result of :meth:`Session.run`: what each stage did and the values it produced.

    Each stage's value goes to the field its table entry names.

    Attributes
    ----------
    run : int
        The run's number in the journal (0 when not journaled).
    stages : list of StageReport
        In the order run.
    problem : Problem
    model : LinearModel or None
    law : ExplicitLaw or None
    result : VerificationResult or None
    recording : Path or None
        The recording inside the session.
    seconds : float
        Wall time of the run.
    """

    run: int
    stages: list[StageReport]
    problem: Problem
    model: LinearModel | None = None
    law: ExplicitLaw | None = None
    result: VerificationResult | None = None
    recording: Path | None = None
    seconds: float = 0.0

    def stage(self, name: str) -> StageReport | None:
        """The report of stage ``name``, or None if the run did not reach it.

        Parameters
        ----------
        name : str

        Returns
        -------
        StageReport or None
        """
        return next((s for s in self.stages if s.stage == name), None)


@dataclass(frozen=True)
class StageStatus:
    """Cache status of one stage for a spec and options.

    Attributes
    ----------
    stage : str
    key : str
        The stage key for the spec and options.
    status : str
        "cached" (a valid artifact for the current inputs), "stale" (computed before, but
        its inputs changed since), "missing" (never computed, or the artifact is gone) or
        "corrupt" (the artifact fails its check).
    artifact : str or None
        The artifact's path relative to the session folder ("cached", "corrupt").
    reason : str or None
        Why it is not "cached".
    """

    stage: str
    key: str
    status: str
    artifact: str | None
    reason: str | None = None


@dataclass(frozen=True)
class ReplayReport:
    """The result of :meth:`Session.replay`.

    Attributes
    ----------
    runs : int
        Runs replayed.
    checked : int
        Stage records compared.
    cached : int
        Of those, stages loaded from the cache.
    mismatches : list of tuple
        ``(run, stage, recorded outcome, replayed outcome)``.
    seconds : float
        Wall time of the replay.
    """

    runs: int
    checked: int
    cached: int
    mismatches: list[tuple[int, str, dict, dict]]
    seconds: float

    @property
    def ok(self) -> bool:
        """Every replayed outcome matches the recorded one."""
        return not self.mismatches
