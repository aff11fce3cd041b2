"""Parameters in balanced units: a diagonal power-of-two rescaling of ``theta``.

Every length of the mp searches (the region tolerance, the step across a facet, the
thinness of a ball) is relative to **one** number, the parameter set's largest width
(``reduce.parameter_box``). A plant in badly matched units (a position in mm next to a
velocity in km/s: widths 2e4 and 2e-2) then has a step across a facet as wide as the whole
short axis; the mp-LP search of such a double integrator found one region that missed most
of the feasible set (issue 38). The cure is at the cause: the search runs on
``theta = D theta_s`` with ``D`` diagonal, so that no axis of the parameter box is much
narrower than the widest one, and the regions and laws are mapped back.

``D``'s entries are powers of two, so the program's columns times ``D`` and the laws'
``K D^-1`` are exact in floating point (a region's rows are made unit-norm again after
``A D^-1``, which rounds by an ulp). An axis within ``BALANCE_RATIO`` of the widest keeps
``D_i = 1``: the problems in sensible units are solved exactly as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from codev_engine.mp.program import MpProgram
from codev_engine.mp.reduce import (  # (the rule is reduce's: its box LPs use it too)
    BALANCE_RATIO,
    parameter_box,
    parameter_scaling,
    reduce_program,
)
from codev_engine.mp.solution import MpSolution, RegionArrays

__all__ = ["BALANCE_RATIO", "BalancedWriter", "balanced", "parameter_scaling",
           "program_scaling", "regions_back", "rows_back", "unbalanced"]

def program_scaling(program: MpProgram) -> np.ndarray | None:
    """``parameter_scaling`` of the program's parameter box (after ``reduce_program``).

    Parameters
    ----------
    program : MpProgram

    Returns
    -------
    (d,) ndarray or None
    """
    size = parameter_box(reduce_program(program))
    return parameter_scaling(size.lo, size.hi)


def balanced(program: MpProgram, D: np.ndarray) -> MpProgram:
    """The program in ``theta_s = D^-1 theta``: every parameter column times ``D`` (exact).

    Parameters
    ----------
    program : MpProgram
    D : (d,) ndarray
        Powers of two.

    Returns
    -------
    MpProgram
    """
    eq = program.Aeq is not None
    return MpProgram(
        H=program.H, c=program.c, C=program.C * D, A=program.A, b=program.b,
        F=program.F * D, A_theta=program.A_theta * D, b_theta=program.b_theta,
        Aeq=program.Aeq, beq=program.beq, Feq=program.Feq * D if eq else None,
        name=program.name,
    )


def rows_back(A: np.ndarray, b: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``A theta_s <= b`` in ``theta``: ``A D^-1``, made unit-norm again.

    Parameters
    ----------
    A : (q, d) ndarray
    b : (q,) ndarray
    D : (d,) ndarray

    Returns
    -------
    A, b : (q, d), (q,) ndarrays
    """
    A = A / D
    if A.shape[0] == 0:
        return A, b
    norm = np.linalg.norm(A, axis=1)
    norm[norm == 0.0] = 1.0
    return A / norm[:, None], b / norm


def regions_back(ra: RegionArrays, D: np.ndarray) -> RegionArrays:
    """Regions and laws of ``theta_s`` in ``theta``: rows ``A D^-1`` (unit rows again), laws
    ``K D^-1`` (exact).

    Parameters
    ----------
    ra : RegionArrays
        In ``theta_s``.
    D : (d,) ndarray

    Returns
    -------
    RegionArrays
    """
    A, b = rows_back(ra.A, ra.b, D)
    sA, sb = rows_back(ra.shared_A, ra.shared_b, D)
    return RegionArrays(A, b, ra.offsets, ra.K / D, ra.k, ra.active, ra.active_offsets,
                        ra.implied, sA, sb)


@dataclass(frozen=True)
class BalancedWriter:
    """A sharded search's law writer (``law_shard_writer.ShardWriter``) for a search in balanced
    units: what the workers hand it in ``theta_s`` is written in ``theta = D theta_s``, so
    the law's shards are the program's law, in its own units.

    Attributes
    ----------
    writer : law_shard_writer.ShardWriter
        Writes in ``theta`` (its ``op`` added after the rescaling).
    D : (d,) ndarray
        Powers of two.
    """

    writer: object
    D: np.ndarray

    @property
    def op(self) -> np.ndarray:
        """The writer's ``op`` (in ``theta``)."""
        return self.writer.op

    def write(self, regions: RegionArrays, j: int, facets: np.ndarray | None = None) -> dict:
        """Worker side: shard ``j``'s regions (and facets) of ``theta_s`` written in
        ``theta`` (``ShardWriter.write``).

        Parameters
        ----------
        regions : RegionArrays
            In ``theta_s`` (the laws in the program's original variables).
        j : int
            The shard.
        facets : (q, d + 1) ndarray, optional
            Rows ``[a, beta]``, ``a theta_s <= beta``.

        Returns
        -------
        dict
            The shard's manifest entry.
        """
        if facets is not None and facets.shape[0]:
            A, b = rows_back(facets[:, :-1], facets[:, -1], self.D)
            facets = np.hstack([A, b[:, None]])
        return self.writer.write(regions_back(regions, self.D), j, facets, scale=self.D)

    def point(self, X: np.ndarray) -> np.ndarray:
        """Points of ``theta_s`` in the law's variables: ``D theta_s + op``.

        Parameters
        ----------
        X : (P, d) or (d,) ndarray

        Returns
        -------
        ndarray
            ``X``'s shape.
        """
        return self.writer.point(np.asarray(X, float) * self.D)

    def locate(self, j: int, X: np.ndarray) -> np.ndarray:
        """Worker side: ``ShardWriter.locate``.

        Parameters
        ----------
        j : int
        X : (P, d) ndarray
            In the law's variables already (:meth:`point`).

        Returns
        -------
        (P,) ndarray of int
        """
        return self.writer.locate(j, X)

    def halo(self, client, entries: list[dict]) -> tuple[list[dict], float]:
        """Client side: ``ShardWriter.halo`` (the shards are in ``theta`` already).

        Parameters
        ----------
        client : distributed.Client
        entries : list of dict

        Returns
        -------
        entries : list of dict
        cpu : float
        """
        return self.writer.halo(client, entries)

    def open(self, entries: list[dict], set_A: np.ndarray, set_b: np.ndarray,
             meta: dict | None = None):
        """Client side: ``ShardWriter.open`` with the parameter set's rows of ``theta_s``
        in ``theta``; the stats say how many axes were rescaled.

        Parameters
        ----------
        entries : list of dict
            :meth:`write`'s answers, in shard order.
        set_A, set_b : (p, d), (p,) ndarrays
            The parameter set's rows in ``theta_s``.
        meta : dict, optional

        Returns
        -------
        law_shards.ShardedLaw
        """
        A, b = rows_back(np.asarray(set_A, float), np.asarray(set_b, float), self.D)
        meta = dict(meta or {})
        if isinstance(meta.get("stats"), dict):
            meta["stats"]["parameter_axes_scaled"] = int(np.sum(self.D != 1.0))
        return self.writer.open(entries, A, b, meta)


def unbalanced(sol: MpSolution, program: MpProgram, D: np.ndarray) -> MpSolution:
    """A solution of ``balanced(program, D)`` as a solution of ``program``.

    Parameters
    ----------
    sol : MpSolution
        Regions, laws and domain in ``theta_s``.
    program : MpProgram
        The original program.
    D : (d,) ndarray

    Returns
    -------
    MpSolution
        Regions ``A D^-1 theta <= b`` (unit rows), laws ``K D^-1`` (exact), the domain
        likewise; the stats say how many axes were rescaled (``parameter_axes_scaled``).
    """
    regions = regions_back(sol.regions, D)
    dA, db = (None, None) if sol.domain_A is None else rows_back(sol.domain_A,
                                                                  sol.domain_b, D)
    stats = dict(sol.stats)
    stats["parameter_axes_scaled"] = int(np.sum(D != 1.0))
    return MpSolution(program=program, regions=regions, domain_A=dA, domain_b=db,
                      seconds=sol.seconds, stats=stats)
