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

    ``status`` is "computed", "cached", "skipped" or "failed"; ``outcome`` holds the fields a
    replay compares (regions, verdict, ...), ``details`` the rest (timings, sizes).
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
    """The result of :meth:`Session.run`: what each stage did and the values it produced
    (each stage's value goes to the field its table entry names)."""

    run: int
    stages: list[StageReport]
    problem: Problem
    model: LinearModel | None = None
    law: ExplicitLaw | None = None
    result: VerificationResult | None = None
    recording: Path | None = None
    seconds: float = 0.0

    def stage(self, name: str) -> StageReport | None:
        return next((s for s in self.stages if s.stage == name), None)


@dataclass(frozen=True)
class StageStatus:
    """Cache status of one stage for a spec and options: "cached" (a valid artifact for the
    current inputs), "stale" (computed before, but its inputs changed since), "missing"
    (never computed, or the artifact is gone) or "corrupt" (the artifact fails its check).
    """

    stage: str
    key: str
    status: str
    artifact: str | None
    reason: str | None = None


@dataclass(frozen=True)
class ReplayReport:
    """The result of :meth:`Session.replay`.

    ``mismatches`` lists ``(run, stage, recorded outcome, replayed outcome)``.
    """

    runs: int
    checked: int
    cached: int
    mismatches: list[tuple[int, str, dict, dict]]
    seconds: float

    @property
    def ok(self) -> bool:
        return not self.mismatches
