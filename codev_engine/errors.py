"""Exception hierarchy of the engine.

Infeasibility of an optimisation problem is a *result*, not an exception; exceptions are
for bad input (``SpecError``) and for solver breakdowns (``SolverError``).
"""

from __future__ import annotations

__all__ = ["CodevError", "DamagedFileError", "RegionLimitError", "SolverError", "SpecError"]


class CodevError(Exception):
    """Base class of every error the engine raises on purpose."""


class SpecError(CodevError, ValueError):
    """A problem specification (or any user input file) is invalid.

    Parameters
    ----------
    reason : str
        What is wrong, in words a user understands.
    file : str, optional
        The file the bad input came from.
    field : str, optional
        The dotted field name inside that file (``mpc.Q``, ``verify.initial_set.lower``).
    """

    def __init__(self, reason: str, *, file: str | None = None, field: str | None = None):
        self.reason = reason
        self.file = file
        self.field = field
        super().__init__(self._format())

    def _format(self) -> str:
        where = ": ".join(p for p in (self.file, self.field) if p)
        return f"{where}: {self.reason}" if where else self.reason

    def __reduce__(self):
        # pickled whole (file and field kept) when it travels back from a Dask worker
        return (_spec_error, (type(self), self.reason, self.file, self.field))

    def with_file(self, file: str) -> SpecError:
        """Return a copy that names ``file`` (used when the loader knows the path).

        Parameters
        ----------
        file : str
            The file the bad input came from.

        Returns
        -------
        SpecError
            The same reason and field, with ``file`` set.
        """
        return SpecError(self.reason, file=file, field=self.field)


class DamagedFileError(SpecError):
    """A checked file found damaged when it was read: its bytes are not the ones its
    manifest records (a shard of a law read lazily, ``law_shards.ShardedLaw``).

    ``file`` names it. A session whose cached artifact holds the file marks that artifact
    damaged (``session.store.mark_damaged``), so that its next run recomputes it: the file
    is checked when read, not when the artifact is opened.

    Parameters
    ----------
    reason : str
        What is wrong with the file (its size or SHA-256 is not the manifest's).
    file : str, optional
        The damaged file.
    field : str, optional
        Unused by the readers (as ``SpecError``).

    Attributes
    ----------
    artifact : str or None
        The session artifact marked damaged for it (set by the session), else None.
    """

    artifact: str | None = None


class SolverError(CodevError, RuntimeError):
    """A numerical solver failed in a way the engine could not recover from."""


class RegionLimitError(CodevError):
    """A law computed on demand (``law_on_demand.OnDemandLaw``) reached the region limit
    the full synthesis honours: the reach engines end in an ``unknown`` (``limit``) finding
    with its message (how many regions were computed, the field to raise), never a hang
    or a MemoryError."""


def _spec_error(cls: type, reason: str, file: str | None, field: str | None) -> SpecError:
    return cls(reason, file=file, field=field)

