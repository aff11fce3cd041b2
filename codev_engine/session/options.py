"""Run options: what a session run does besides the spec."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from codev_engine.session.stages import STAGES
from codev_engine.session.store import SessionError
from codev_engine.spec.choices import HOLDS

__all__ = ["DEFAULT_OPTIONS", "MAX_DEPTH", "MAX_TRACES", "RunOptions"]

#: the most simulated traces a recording takes (each one simulates the closed loop; the
#: CLI's ``--traces`` and a journal's ``traces`` are bounded by it where they are read)
MAX_TRACES = 1000
#: the largest refinement depth an override takes (``--max-depth``, a journal's
#: ``max_depth``): past it the verification's branch limit ends any run anyway
MAX_DEPTH = 64


@dataclass(frozen=True)
class RunOptions:
    """What a run does besides the spec: the last stage, verification overrides, recording.

    Attributes
    ----------
    upto : str
        Last stage to run (one of ``STAGES``; default the last); stages that need a
        ``[verify]`` section are skipped when the spec has none.
    hold : str or None
        Overrides ``verify.hold``.
    max_depth : int or None
        Overrides ``verify.max_depth``.
    axes : (2,) tuple of int
        State indices of the recording's plane view.
    traces : int
        Simulated traces in the recording.
    sharded : bool
        The law is computed by the sharded search (with a Dask executor: each worker keeps
        and writes its shard; without one, one shard) and stored as a folder of shards,
        read lazily (``law_shards.ShardedLaw``). Part of the synthesis's key.
    """

    upto: str = STAGES[-1]
    hold: str | None = None
    max_depth: int | None = None
    axes: tuple[int, int] = (0, 1)
    traces: int = 16
    sharded: bool = False

    def to_json(self) -> dict[str, Any]:
        """The options as a journal record holds them (``axes`` as a list; ``sharded``
        only when set, so the records of other runs are as before)."""
        out = {
            "upto": self.upto,
            "hold": self.hold,
            "max_depth": self.max_depth,
            "axes": list(self.axes),
            "traces": self.traces,
        }
        if self.sharded:
            out["sharded"] = True
        return out

    @classmethod
    def from_json(
        cls, d: Any, *, where: str = "options", stages: tuple[str, ...] = STAGES
    ) -> RunOptions:
        """Validate the options of a journal record (no field may carry code or junk).

        Parameters
        ----------
        d : object
            The record's ``options``, as read from JSON.
        where : str
            Names the record in errors.
        stages : tuple of str
            The names ``upto`` may take (default: codev's stages).

        Returns
        -------
        RunOptions

        Raises
        ------
        SessionError
            ``d`` is not an object of valid options.
        """
        if not isinstance(d, dict):
            raise SessionError("must be a JSON object", field=where)
        try:
            opts = cls(
                upto=str(d.get("upto", STAGES[-1])),
                hold=d.get("hold"),
                max_depth=d.get("max_depth"),
                axes=tuple(d.get("axes", (0, 1))),  # type: ignore[arg-type]
                traces=d.get("traces", 16),
                sharded=d.get("sharded", False),
            )
        except TypeError:
            raise SessionError("malformed run options", field=where) from None
        opts.check(field_prefix=where, stages=stages)
        return opts

    def check(self, *, field_prefix: str = "options", stages: tuple[str, ...] = STAGES) -> None:
        """Check every option's range.

        Parameters
        ----------
        field_prefix : str
            Prefix of the field named in errors.
        stages : tuple of str
            The names ``upto`` may take (default: codev's stages).

        Raises
        ------
        SessionError
            Naming the first option out of range.
        """
        if self.upto not in stages:
            raise SessionError(f"must be one of {', '.join(stages)}", field=f"{field_prefix}.upto")
        if self.hold is not None and self.hold not in HOLDS:
            raise SessionError("must be zoh or continuous", field=f"{field_prefix}.hold")
        if self.max_depth is not None and (
            not isinstance(self.max_depth, int)
            or isinstance(self.max_depth, bool)
            or self.max_depth < 0
        ):
            raise SessionError("must be a non-negative integer", field=f"{field_prefix}.max_depth")
        if self.max_depth is not None and self.max_depth > MAX_DEPTH:
            raise SessionError(
                f"must be at most {MAX_DEPTH}, got {self.max_depth:,}",
                field=f"{field_prefix}.max_depth",
            )
        if (
            len(self.axes) != 2
            or not all(isinstance(a, int) and not isinstance(a, bool) for a in self.axes)
            or self.axes[0] == self.axes[1]
            or min(self.axes) < 0
        ):
            raise SessionError("must be two distinct state indices", field=f"{field_prefix}.axes")
        if not isinstance(self.traces, int) or isinstance(self.traces, bool) or self.traces < 0:
            raise SessionError("must be a non-negative integer", field=f"{field_prefix}.traces")
        if not isinstance(self.sharded, bool):
            raise SessionError("must be true or false", field=f"{field_prefix}.sharded")
        if self.traces > MAX_TRACES:
            raise SessionError(
                f"must be at most {MAX_TRACES:,} simulated traces, got {self.traces:,}",
                field=f"{field_prefix}.traces",
            )


#: The options of a plain run (every stage, the spec's own hold and depth).
DEFAULT_OPTIONS = RunOptions()
