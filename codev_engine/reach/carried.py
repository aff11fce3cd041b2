"""A linear system's response to a bounded forcing, carried as a zonotope (issue 38).

The nonlinear engine (``reach/nonlinear_flow.py``) splits the deviation from its centre under
disturbances and uncertain parameters as ``x - z = Phi (D d + M e) + psi_w + psi``; ``psi_w``
is the response of the linearisation to the disturbances' and parameters' first-order
forcing, which this module bounds by a zonotope (docs/verification.md, "The disturbances'
linear part, carried as a zonotope"). ``offset_zonotope`` does the same for the remainder
``psi``'s second-order forcing, a signed interval per substep, about the response of its
midpoint (docs/verification.md, "The remainder per axis"). Pure functions of numpy arrays.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

__all__ = ["carried_zonotope", "offset_zonotope"]


def carried_zonotope(
    J: np.ndarray, frc: np.ndarray, hs: np.ndarray, jump: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The response of ``psi' = J_j psi + phi(t)``, ``psi(0) = 0``, ``|phi| <= frc_j``
    (and, with ``jump``, a step of at most ``jump_j`` element-wise at each substep's end).

    On substep ``j`` (length ``h``) ``psi`` goes to ``exp(J_j h) psi(t_j) + int_0^h exp(J_j
    (h - s)) phi(s) ds`` for any measurable ``phi`` within the bound, and the integral lies
    in the box ``K_j frc_j``, ``K_j = int_0^h exp(|J_j| s) ds`` (``|exp(J t)| <= exp(|J|
    t)`` element-wise; ``K_j`` is the top-right block of the exponential of ``[[|J_j| h, I
    h], [0, 0]]``): one generator per axis and substep, the earlier ones mapped by
    ``exp(J_j h)``. Over the substep ``|psi| <= exp(|J_j| h) |psi(t_j)| + K_j frc_j``.
    Products are padded by ``1e-10`` of their magnitudes (far above the rounding of
    ``expm`` and of the sums), the pads added as generators. A jump ``|v| <= jump_j`` at
    the end of substep ``j`` is one more generator per axis, ``diag(jump_j)``, and is
    counted in ``zsub_j`` too (the substep's box then also holds its end after the jump).

    Parameters
    ----------
    J : (N, n, n) ndarray
        The linear part's Jacobian per substep.
    frc : (N, n) ndarray
        Element-wise bounds of the forcing's magnitude per substep (for the disturbances
        and parameters: ``|df/d(w, p)| xdev`` at the centre, nominal values).
    hs : (N,) ndarray
        Substep lengths.
    jump : (N, n) ndarray, optional
        Element-wise bounds of a step added at each substep's end (None: none).

    Returns
    -------
    zsub : (N, n) ndarray
        Half-widths of a box holding ``psi`` over each substep.
    G : (n, n N) ndarray
        Generators: ``psi`` at the last substep's end lies in ``{G t : |t|_inf <= 1}``.
    zbox : (N, n) ndarray
        Half-widths of a box holding ``psi(t_j)`` at each substep's start.
    """
    N, n = frc.shape
    Aa = np.zeros((N, 2 * n, 2 * n))
    Aa[:, :n, :n] = np.abs(J) * hs[:, None, None]
    Aa[:, :n, n:] = np.eye(n)[None] * hs[:, None, None]
    Ea = np.abs(expm(Aa)) * (1 + 1e-10)
    Eabs, K = Ea[:, :n, :n], Ea[:, :n, n:]
    E = expm(J * hs[:, None, None])
    box = np.einsum("jik,jk->ji", K, frc) * (1 + 1e-10) + 1e-300
    G = np.zeros((n, 0))
    zbox = np.empty((N, n))
    zsub = np.empty((N, n))
    for j in range(N):
        zb = np.abs(G).sum(axis=1) * (1 + 1e-12)
        zbox[j] = zb
        zsub[j] = (Eabs[j] @ zb + box[j]) * (1 + 1e-10)
        pad = 1e-10 * (np.abs(E[j]) @ zb + box[j])
        step = box[j] + pad
        if jump is not None:
            zsub[j] = zsub[j] + jump[j]
            step = step + jump[j]  # (two generators' sum along one axis: one generator)
        G = np.hstack([E[j] @ G, np.diag(step)])
    return zsub, G, zbox


def offset_zonotope(
    J: np.ndarray, flo: np.ndarray, fhi: np.ndarray, hs: np.ndarray, jump: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The response of ``psi' = J_j psi + phi(t)``, ``psi(0) = 0``, ``flo_j <= phi <= fhi_j``,
    plus a step ``|v| <= jump_j`` at each substep's end: a zonotope about an offset.

    ``phi = m_j + r``, ``m_j`` the interval's midpoint, ``|r| <= r_j`` its half-width: the
    midpoint's response ``c`` is a point, ``c(t_{j+1}) = exp(J_j h) c(t_j) + L_j m_j`` with
    ``L_j = int_0^h exp(J_j s) ds`` (the top-right block of the exponential of ``[[J_j h,
    I h], [0, 0]]``), its rounding (``1e-10`` of the products' magnitudes) one more step;
    the rest is :func:`carried_zonotope` of ``r_j``. A one-signed forcing (a concave
    outflow's curvature) so costs half the symmetric zonotope's width plus a shift.

    Parameters
    ----------
    J : (N, n, n) ndarray
        The linear part's Jacobian per substep.
    flo, fhi : (N, n) ndarray
        Element-wise bounds of the forcing per substep (finite).
    hs : (N,) ndarray
        Substep lengths.
    jump : (N, n) ndarray
        Element-wise bounds of the step at each substep's end.

    Returns
    -------
    sublo, subhi : (N, n) ndarray
        A box holding ``psi`` over each substep (its end included).
    c : (n,) ndarray
        The offset: ``psi`` at the last substep's end lies in ``c + {G t : |t|_inf <= 1}``.
    G : (n, k) ndarray
        The generators.
    zabs : (N, n) ndarray
        Bounds of ``|psi(t_j)|`` at each substep's start.
    """
    N, n = flo.shape
    mid = 0.5 * (flo + fhi)
    rad = np.maximum(fhi - mid, mid - flo) * (1 + 1e-12) + 1e-300
    Ma = np.zeros((N, 2 * n, 2 * n))
    Ma[:, :n, :n] = J * hs[:, None, None]
    Ma[:, :n, n:] = np.eye(n)[None] * hs[:, None, None]
    Es = expm(Ma)
    E, L = Es[:, :n, :n], Es[:, :n, n:]
    c = np.zeros(n)
    cabs = np.empty((N, n))
    cfull = np.empty((N, n))  # (c(t_{j+1}))
    padc = np.empty((N, n))
    for j in range(N):
        cabs[j] = np.abs(c)
        padc[j] = 1e-10 * (np.abs(E[j]) @ np.abs(c) + np.abs(L[j]) @ np.abs(mid[j])) + 1e-300
        c = E[j] @ c + L[j] @ mid[j]
        cfull[j] = c
    steps = jump + padc
    _, G, zbox = carried_zonotope(J, rad, hs, steps)
    # over substep j: psi - c_j = (exp(J t) - I) c_j + exp(J t) (psi(t_j) - c_j) + int
    # exp(J (t - s)) phi ds, with |exp(J t) - I| <= exp(|J| h) - I and |exp(J t)| <= exp(|J|
    # h) element-wise (the series), K_j as in carried_zonotope, plus the step at its end
    Aa = np.zeros((N, 2 * n, 2 * n))
    Aa[:, :n, :n] = np.abs(J) * hs[:, None, None]
    Aa[:, :n, n:] = np.eye(n)[None] * hs[:, None, None]
    Ea = np.abs(expm(Aa)) * (1 + 1e-10)
    zabs = (cabs + zbox) * (1 + 1e-12)
    fmax = np.maximum(np.abs(flo), np.abs(fhi))
    Ea1 = Ea[:, :n, :n] - np.eye(n)[None]  # (exp(|J| h) >= I: rounded up, still above)
    half = (
        np.einsum("jik,jk->ji", Ea1, cabs)
        + np.einsum("jik,jk->ji", Ea[:, :n, :n], zbox)
        + np.einsum("jik,jk->ji", Ea[:, :n, n:], fmax)
    ) * (1 + 1e-10) + steps + 1e-12 * cabs
    cs = np.vstack([np.zeros((1, n)), cfull[:-1]]) if N else cfull
    return cs - half, cs + half, c, G, zabs
