"""No two regions of an mp-QP's partition overlap (issue 43: exact synthesis, no overlaps).

chain5 (``test_mpqp_same._chain5``) had 9 pairs of regions whose interiors overlapped
(Chebyshev radius 5e-9 to 7e-8, the region tolerance 4e-9), e.g. the active sets
``(0, 22, 33, 43)`` and ``(12, 22, 33, 43)``: constraints 0 (``u_0 <= 1``) and 12
(``u_0 <= 4 - 2 x_4``) have the same row in z, so the two regions meet on ``x_4 = 1.5``,
where both active sets are optimal (primal degeneracy; the same optimizer). Neither region
was wrongly accepted: each active set is optimal on its side. But their active rows are
nearly dependent (multipliers with coefficients of 3e9), and the slack of the twin, computed
as ``d_i + M_iA lambda_A``, lost up to 1.4e-7 to rounding, so each region reached past
``x_4 = 1.5``. That slack does not depend on the multipliers at all (``g_12 = g_0``): taken
from the dependency (``mpqp._Kernel._dependent_slacks``), it is the facet itself.

The default run takes chain5's program on small random boxes around those facets (a few
dozen regions each; every one overlapped before) and the rows themselves; the slow one the
whole of chain5.
"""

from __future__ import annotations

import numpy as np
import pytest

import codev_engine as ce
from codev_engine.mp import mpqp_kernel
from codev_engine.mp.reduce import parameter_box, reduce_program
from tests.engine.overlaps import overlapping_pairs
from tests.engine.test_mpqp_same import _chain5, _kernel
from tests.engine.test_mpsolve import compare

#: points of chain5's degenerate facets where regions overlapped: on ``x_4 = 1.5`` (the
#: twins 0 and 12) and where ``-u_1 <= 1``, ``-(u_0 + u_1)/sqrt(2) <= ...`` and ``-u_0 <= 1``
#: are dependent (constraints 1, 3 and 27)
FACET_POINTS = [
    [-0.3874, -2.0, 1.8362, -1.8661, 1.5],
    [-1.3767, -1.1305, 1.3727, -1.4988, 1.5],
    [-1.6385, -1.1644, 2.0, -1.6042, 1.5],
    [0.2964, 2.0, -1.5715, 1.3251, -1.0],
]


def _tolerance(program: ce.MpProgram) -> float:
    """The search's region tolerance (absolute) for ``program`` (default options)."""
    return ce.SolveOptions().region_tol * parameter_box(reduce_program(program)).scale


def _on_box(program: ce.MpProgram, lo: np.ndarray, hi: np.ndarray) -> ce.MpProgram:
    d = program.d
    return ce.MpProgram(H=program.H, c=program.c, C=program.C, A=program.A, b=program.b,
                        F=program.F, A_theta=np.vstack([np.eye(d), -np.eye(d)]),
                        b_theta=np.concatenate([hi, -lo]))


def test_the_check_finds_an_overlap():
    """The helper itself: two squares that share a side do not overlap, a third that
    reaches 1e-6 into one does (and a sliver of 1e-12 does not count)."""
    A = np.vstack([np.eye(2), -np.eye(2)])
    left = (A, np.array([0.0, 1.0, 1.0, 1.0]))
    right = (A, np.array([1.0, 1.0, 0.0, 1.0]))
    past = (A, np.array([1.0, 1.0, 1e-6, 1.0]))
    touch = (A, np.array([1.0, 1.0, 1e-12, 1.0]))
    def pairs(*regions):
        return overlapping_pairs(([r[0] for r in regions], [r[1] for r in regions]), 1e-9)

    assert pairs(left, right) == []
    assert pairs(left, touch) == []
    got = pairs(left, right, past)
    assert [(i, j) for i, j, _ in got] == [(0, 2), (1, 2)]
    assert got[0][2] == pytest.approx(5e-7, rel=1e-6)


def test_a_twins_slack_is_the_facet_itself():
    """The slack of constraint 12 (``u_0 <= 4 - 2 x_4``) where its twin 0 (``u_0 <= 1``)
    is active is ``3 - 2 x_4`` exactly, and the other way round: the region of each active
    set ends on ``x_4 = 1.5`` (numpy and compiled kernel). It was 1.5000000063 and
    1.4999998775 (the multipliers' coefficients are 3e9)."""
    kernel = _kernel(_chain5())
    e4 = np.eye(5)[4]
    for act, sign in [((0, 22, 33, 43), 1.0), ((12, 22, 33, 43), -1.0)]:
        status, rows, *_ = kernel.evaluate_numpy(act)
        assert status == "full"
        got = mpqp_kernel.evaluate(np.array(act, dtype=np.int64), kernel.box[0],
                                   *kernel._jit_args)
        for A, b in [rows, got[1:3]]:
            # the facet: sign * x_4 <= sign * 1.5
            at = np.flatnonzero(np.abs(A @ (sign * e4) - 1.0) < 1e-6)
            facet = at[np.abs(b[at] - sign * 1.5) < 1e-3]
            assert facet.size == 1, act
            np.testing.assert_allclose(A[facet[0]], sign * e4, atol=1e-13)
            assert b[facet[0]] == pytest.approx(sign * 1.5, abs=1e-13), act


@pytest.mark.parametrize("k", range(len(FACET_POINTS)))
def test_no_overlaps_near_degenerate_facets(k):
    """chain5's program on a random box of half-width 0.05 around a point of a degenerate
    facet (20 to 50 regions, thin ones among them): no two regions overlap, and at random
    points and probes across the regions' facets there is no hole and the law is the
    online optimum (``test_mpsolve.compare``: Clarabel)."""
    rng = np.random.default_rng(43 + k)
    centre = np.array(FACET_POINTS[k]) + rng.normal(size=5) * 0.02
    program = _on_box(_chain5(), np.maximum(centre - 0.05, -2.0),
                      np.minimum(centre + 0.05, 2.0))
    sol = ce.mpsolve(program, options=ce.SolveOptions(workers=1))
    assert sol.num_regions > 10
    pairs = overlapping_pairs(sol.regions, _tolerance(program))
    assert pairs == [], [(sol.regions[i].active, sol.regions[j].active, r)
                         for i, j, r in pairs[:5]]
    problems = compare(program, sol, seed=k).problems
    assert not any(problems.values()), {what: items[:3] for what, items in problems.items()
                                        if items}


@pytest.mark.slow  # (the solve and ~200k pairs of boxes that meet: ~30 s)
def test_chain5_has_no_overlapping_regions():
    program = _chain5()
    sol = ce.mpsolve(program, options=ce.SolveOptions(workers=1))
    assert sol.num_regions == 1407
    pairs = overlapping_pairs(sol.regions, _tolerance(program))
    assert pairs == [], [(sol.regions[i].active, sol.regions[j].active, r)
                         for i, j, r in pairs[:5]]
