"""Long, thin pieces that DAQP misjudges (issue 38, "no numerical dead end is an error").

The polytopes come from AFTI-16 (``benchmarks/on_demand.py``) with ``domain_bound = 1000``
at N = 3 and 5: a reach set with its attack angle pinned to 0.5 (1e-11 wide, 50 long in
speed) cut by a critical region, where the states are ~500 and the law's domain 1000. DAQP
called them infeasible (its box LPs) or gave a box side 4e-5 short of the minimum, its
minrep dropped rows that cut the piece (``checked_piece`` ended the verification in a
ValueError), and its Chebyshev radius called one empty (dropped: states lost). Each must now
give points whose hull contains the polytope (checked by SciPy's HiGHS in many directions).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from codev_engine.geometry.polytope import chebyshev_ball, normalize_rows
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


# a piece DAQP calls empty (Chebyshev radius -3.2e-5; HiGHS: +2.4e-5) within the law's
# domain box |x| <= 1000: it was dropped, and the states in it were lost (AFTI-16, N = 5:
# 4 of 216 simulated trajectories left the robustly_safe verdict's tube at t = 1.25)
DROPPED_A = np.vstack([np.array([
    [0.0, -1.0, 0.0, 0.0],
    [-4.7632323166793792e-06, 9.9882636667213265e-01, 4.8434380378541184e-02,
     3.8993356040068941e-06],
    [4.8767285115419520e-06, 9.9887854119856212e-01, -4.7346170857692979e-02,
     3.7900010036961260e-06],
    [-2.0975774856023682e-05, 1.2432424392266346e+00, -5.2593529769998952e-03,
     -9.8012300267964236e-01],
    [-1.4379739399589947e-04, 2.7293854512385419e+01, 4.1561845977299394e-01,
     1.1904754270670090e-04],
]), np.eye(4), -np.eye(4)])
DROPPED_B = np.concatenate([np.array([
    -4.9999984999489300e-01, 8.2737481617613529e-01, 1.7878520695203115e-01,
    -7.7822053177759303e+00, 1.0232319285506062e+03,
]), np.full(8, 1000.0)])


def test_a_piece_daqp_calls_empty_is_kept_when_highs_finds_it():
    piece = checked_piece(DROPPED_A, DROPPED_B)
    assert piece is not None
    _, _, V = piece
    _assert_encloses(DROPPED_A, DROPPED_B, V)


# a sliver along a region's face (the double integrator, norm 1, N = 10 over 9 s: a set cut
# by the face y = -2 relaxed by 1e-9 on both sides): DAQP's Chebyshev radius 9.2e-10 with
# a centre strictly inside, HiGHS's 1.001e-9 (above _THIN within its tolerances). The
# centre proves it is not empty: kept, relaxed, and bounded by DAQP's proved box LPs
SLIVER_A = np.array([
    [1.0, 0.0],
    [0.0, 1.0],
    [0.7071067811865476, 0.7071067811865476],
    [0.7071067811865476, -0.7071067811865476],
    [-0.7071067811865476, 0.7071067811865476],
    [0.16439898730535726, 0.9863939238321439],
    [0.19611613513818407, 0.9805806756909202],
    [0.1414213562373095, 0.9899494936611666],
    [0.12403473458920847, 0.9922778767136677],
    [0.447213595499958, 0.894427190999916],
    [0.0, -1.0],
    [-0.16439898730535726, -0.9863939238321439],
    [-0.19611613513818402, -1.176696810829104],
    [-0.37139067635410383, -1.299867367239363],
    [0.0, 1.0],
    [0.3162277660168379, 1.2649110640673515],
    [0.0, -1.0],
    [0.3713906763541037, 1.299867367239363],
    [0.3713906763541037, 1.2998673672393632],
    [0.3713906763541036, 1.299867367239363],
    [0.3713906763541032, 1.2998673672393628],
    [0.3713906763541041, 1.2998673672393632],
    [0.37139067635410233, 1.2998673672393621],
    [0.3713906763540924, 1.2998673672393564],
    [0.3713906763541618, 1.2998673672393979],
    [0.19611613513818404, 1.176696810829104],
    [0.3713906763541038, 1.299867367239363],
    [0.37139067635410306, 1.2998673672393628],
    [0.37139067635410444, 1.2998673672393635],
    [0.371390676354109, 1.2998673672393661],
    [0.37139067635405937, 1.2998673672393366],
])
SLIVER_B = np.array([
    -1.4599999878818994, -1.9899999969650004, -2.4395183843791437,
    0.3747666004639064, -0.3480469135916834, -2.20294642490603,
    -2.23768509657424, -2.1764746677740705, -2.155723682645931,
    -2.432841951386148, 2.000000001, 2.2193863296223233,
    3.1378581632133953, 3.6210590954552955, -1.999999998998,
    -2.3717082441235964, 3.0000000010020003, -2.228344057121837,
    -2.228344057121837, -2.2283440571218365, -2.2283440571218365,
    -2.2283440571218387, -2.2283440571218462, -2.2283440571217925,
    -2.2283440571217197, -2.647567823363033, -2.228344057121836,
    -2.228344057121836, -2.2283440571218383, -2.2283440571218764,
    -2.2283440571217907,
])


def test_a_sliver_along_a_face_is_kept_and_enclosed():
    A, b, _ = normalize_rows(SLIVER_A, SLIVER_B)
    centre, radius = chebyshev_ball(A, b)
    assert 0.0 < radius <= 1e-9  # thin by DAQP: the path under test
    piece = checked_piece(SLIVER_A, SLIVER_B)
    assert piece is not None
    H, h, V = piece
    _assert_encloses(SLIVER_A, SLIVER_B, V)
    # relaxed: the kept rows hold the centre with room to spare (a superset with interior)
    assert np.all(H @ centre - h < -1e-8)
