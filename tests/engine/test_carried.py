"""The remainder's zonotope about an offset (``reach/carried.py``, issue 38) against the
exact response of a linear system to sampled forcings: every response inside, the offset
used (a one-signed forcing's box is not symmetric about 0)."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from codev_engine.reach.carried import offset_zonotope


def _responses(J, flo, fhi, hs, jump, rng, runs=300, pieces=4):
    """Exact responses (runs, N * pieces + 1, n) to piecewise-constant forcings within the
    bounds (corners and random values per piece) and random steps within ``jump``."""
    N, n = flo.shape
    out = np.zeros((runs, N * pieces + 1, n))
    for r in range(runs):
        psi = np.zeros(n)
        k = 0
        for j in range(N):
            h = hs[j] / pieces
            Ma = np.zeros((2 * n, 2 * n))
            Ma[:n, :n], Ma[:n, n:] = J[j] * h, np.eye(n) * h
            Es = expm(Ma)
            for _ in range(pieces):
                u = rng.uniform(size=n)
                if r % 2 == 0:  # corners
                    u = np.round(u)
                w = flo[j] + u * (fhi[j] - flo[j])
                psi = Es[:n, :n] @ psi + Es[:n, n:] @ w
                k += 1
                out[r, k] = psi
            psi = psi + jump[j] * rng.uniform(-1, 1, n)
            out[r, k] = psi  # (the substep's end, after its step)
    return out


def test_offset_zonotope_holds_every_response_and_keeps_the_offset():
    rng = np.random.default_rng(3)
    N, n, pieces = 6, 3, 4
    J = np.stack([np.array([[-0.3, 0.2, 0.0], [0.0, -0.1, 0.4], [0.1, 0.0, 0.05]])
                  + 0.02 * rng.standard_normal((n, n)) for _ in range(N)])
    # one-signed forcings in the first state (a concave outflow's curvature), symmetric ones
    # in the others
    fhi = np.tile([0.0, 0.02, 0.01], (N, 1))
    flo = np.tile([-0.05, -0.02, -0.01], (N, 1))
    hs = np.full(N, 0.5)
    jump = np.full((N, n), 1e-4)
    sublo, subhi, c, G, zabs = offset_zonotope(J, flo, fhi, hs, jump)
    X = _responses(J, flo, fhi, hs, jump, rng, pieces=pieces)
    for j in range(N):
        seg = X[:, j * pieces : (j + 1) * pieces + 1]
        assert np.all(seg >= sublo[j] - 1e-12) and np.all(seg <= subhi[j] + 1e-12)
        assert np.all(np.abs(X[:, j * pieces]) <= zabs[j] + 1e-12)
    end = X[:, -1] - c
    A = rng.standard_normal((200, n))
    assert np.all(end @ A.T <= np.abs(A @ G).sum(axis=1) + 1e-12)
    # the offset carries the one-signed part: the first state's box lies below 0 at the end
    # and is narrower than the symmetric box |c| + |G| 1 about 0
    half = np.abs(G).sum(axis=1)
    assert c[0] < 0 and c[0] + half[0] < 0.5 * (np.abs(c[0]) + half[0])
    assert X[:, -1, 0].max() <= c[0] + half[0] + 1e-12
