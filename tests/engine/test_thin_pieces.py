"""Long, thin pieces that DAQP misjudges (issue 38, "no numerical dead end is an error").

Both polytopes come from AFTI-16 (``benchmarks/on_demand.py``) with ``domain_bound = 1000``
at N = 3: a reach set with its attack angle pinned to 0.5 (1e-11 wide, 50 long in speed)
cut by a critical region, where the states are ~500 and the law's domain 1000. DAQP called
them infeasible (its box LPs) or gave a box side 4e-5 short of the minimum, and its minrep
dropped rows that cut the piece; ``checked_piece`` ended the verification in a ValueError.
Each must now give points whose hull contains the polytope (checked by SciPy's HiGHS in
many directions).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from codev_engine.geometry.polytope import normalize_rows
from codev_engine.geometry.vertices import checked_piece

# a thin piece (inscribed radius ~5e-12, flat in the attack angle): its relaxed rows' minrep
# dropped rows that cut it, and the box LPs of the kept rows failed
THIN_A = np.array([
    [0.0, 1.0, 0.0, 0.0],
    [0.0, -1.0, 0.0, 0.0],
    [1.2577743996833752e-06, -9.9988408670575646e-01, -1.5225409012228327e-02,
     -8.4512607378485780e-06],
    [8.3130140551360168e-05, -6.9076777760887453e-01, 7.3188241552269266e-03,
     7.2303962914881847e-01],
    [-1.2577743996833737e-06, 9.9988408670575646e-01, 1.5225409012228335e-02,
     8.4512607380899231e-06],
    [1.2597799796051933e-06, 9.4161850727807317e-01, 2.2629254260521016e-02,
     3.3592038283116910e-01],
    [-1.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, -1.0],
])
THIN_B = np.array([
    5.0000000000510769e-01, -4.9999999999489236e-01, -6.0296173652969454e-01,
    5.8157114141828004e+00, 6.0296818440159794e-01, 3.4639745111416871e+00,
    1.0000000000010000e+03, 1.0000000000010000e+03,
])

# a needle (inscribed radius 4e-7, 480 long): not thin by checked_piece's test, and DAQP's
# box LPs call it infeasible
NEEDLE_A = np.array([
    [2.6769886180567320e-01, 8.6139044202527437e-01, -3.2075806427070440e-02,
     4.3048225099009924e-01],
    [-6.1903049786283120e-06, 9.9807908577555116e-01, 6.1952711764263521e-02,
     2.0430531652225988e-06],
    [6.1903049786283111e-06, -9.9807908577555127e-01, -6.1952711764263528e-02,
     -2.0430531652230744e-06],
    [-4.8767285115419512e-06, -9.9887854119856212e-01, 4.7346170857692937e-02,
     -3.7900010039295035e-06],
    [-1.2577743996833737e-06, 9.9988408670575646e-01, 1.5225409012228335e-02,
     8.4512607380899231e-06],
    [-1.3676060819700386e-06, -9.2936934236716584e-01, -2.3244883134152464e-02,
     -3.6841864892297593e-01],
    [-1.0, 0.0, 0.0, 0.0],
])
NEEDLE_B = np.array([
    -1.3633725528082161e+02, 9.1856960113064257e-01, -9.1856742707772276e-01,
    -1.7878502451588305e-01, 6.0296818440159794e-01, -3.4979906096954667e+00,
    1.0000000000010000e+03,
])


def _assert_encloses(A: np.ndarray, b: np.ndarray, V: np.ndarray) -> None:
    """The hull of V (v, d) reaches every support of ``{A x <= b}``: along the axes, and
    60 random directions (HiGHS through SciPy, its own tolerances); along the axes, by no
    more than 1e-3 relative (``checked_piece`` relaxes the rows by 1e-7 relative to their
    offsets, 1e-4 here, and widens the box as much: a box as wide as the domain fails)."""
    A, b, _ = normalize_rows(A, b)
    d = A.shape[1]
    rng = np.random.default_rng(3)
    dirs = np.vstack([np.eye(d), -np.eye(d), rng.normal(size=(60, d))])
    for f in dirs:
        res = linprog(-f, A_ub=A, b_ub=b, bounds=[(None, None)] * d, method="highs")
        assert res.status == 0
        support = -res.fun
        reach = (V @ f).max()
        assert reach >= support - 1e-9 * (1.0 + abs(support)), f
        if np.count_nonzero(f) == 1:
            assert reach <= support + 1e-3 * (1.0 + abs(support)), f


def test_a_thin_long_piece_keeps_the_rows_that_cut_it():
    piece = checked_piece(THIN_A, THIN_B)
    assert piece is not None  # not empty (HiGHS: an inscribed ball of radius 5e-12)
    _, _, V = piece
    _assert_encloses(THIN_A, THIN_B, V)


def test_a_needle_daqp_calls_infeasible_is_bounded_by_highs():
    piece = checked_piece(NEEDLE_A, NEEDLE_B)
    assert piece is not None
    _, _, V = piece
    _assert_encloses(NEEDLE_A, NEEDLE_B, V)
