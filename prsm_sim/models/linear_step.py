"""Exact zero-order-hold discretisation of a linear velocity system M q̈ = −C q̇ + B u.

Used by `jones2016`, whose equations are linear with constant coefficients: the step map
is exact for inputs held over the step, so the stiff carrier mode (τ ≈ 10⁻⁵ s) costs
nothing at a 1 ms step. The friction work over a step, ∫ q̇ᵀ C q̇ dt, is exact too
(one matrix exponential, see `_friction_work_form`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LinearStep:
    """Step matrices for state x = (q, q̇), input u (held), step h.

    x⁺ = Phi x + Gam u;  dissipated work over the step = zᵀ W z with z = (q̇, u).
    `speed_modes`: eigen-decomposition of the q̇ block (for batch runs by recursive filters).
    """

    dt_s: float
    Phi: np.ndarray
    Gam: np.ndarray
    W: np.ndarray
    speed_eigvals: np.ndarray
    speed_modes: np.ndarray


def discretise(M: np.ndarray, C: np.ndarray, B: np.ndarray, dt_s: float) -> LinearStep:
    """ZOH step of q̈ = M⁻¹(−C q̇ + B u): exact for piecewise-constant u."""
    from scipy.linalg import expm, solve  # here: `import prsm_sim` stays quick without scipy
    n = M.shape[0]
    m = B.shape[1]
    Ai = -solve(M, C)
    Bi = solve(M, B)
    # augmented generator for z = (q, q̇, u) with u̇ = 0
    F = np.zeros((2 * n + m, 2 * n + m))
    F[:n, n:2 * n] = np.eye(n)
    F[n:2 * n, n:2 * n] = Ai
    F[n:2 * n, 2 * n:] = Bi
    E = expm(F * dt_s)
    Phi = E[:2 * n, :2 * n].copy()
    # q does not feed back (F's q columns are zero), so Φ's q columns are exactly (I, 0); expm gives
    # these to rounding at most, set them exact so that a step may skip them (jones2016.advance_packed)
    Phi[:, :n] = np.vstack([np.eye(n), np.zeros((n, n))])
    Gam = E[:2 * n, 2 * n:]
    W = _friction_work_form(Ai, Bi, C, dt_s)
    lam, vec = np.linalg.eig(Phi[n:2 * n, n:2 * n])
    return LinearStep(dt_s=dt_s, Phi=Phi, Gam=Gam, W=W, speed_eigvals=lam.real, speed_modes=vec.real)


def _friction_work_form(A: np.ndarray, Bi: np.ndarray, C: np.ndarray, h: float) -> np.ndarray:
    """W with ∫₀ʰ q̇ᵀ C q̇ dt = zᵀ W z, z = (q̇₀, u), for q̇' = A q̇ + Bi u.

    With F = [[A, Bi], [0, 0]] the augmented speed–input state obeys z' = F z, so the integrand is
    zᵀ e^{Fᵀt} C̃ e^{Ft} z, C̃ = diag(C, 0), and vec W = ∫₀ʰ e^{Lt} dt vec C̃ with the Kronecker sum
    L = Fᵀ ⊗ I + I ⊗ Fᵀ (vec(X Y Z) = (Zᵀ ⊗ X) vec Y). That integral is the last column of
    exp([[L h, vec C̃ h], [0, 0]]) (Van Loan 1978, "Computing integrals involving the matrix
    exponential", Thm 1). L's eigenvalues are sums of A's (≤ 0) and zeros, so the exponential neither
    overflows on the stiff carrier mode (τ ≈ 10⁻⁵ s, where the block form with −Aᵀ needs e^{+h/τ})
    nor needs A⁻¹: it stays exact as the friction c → 0, where the steady speed −A⁻¹ Bi u diverges
    and a form written about it cancels to nothing.
    """
    from scipy.linalg import expm
    n, m = Bi.shape
    k = n + m
    F = np.zeros((k, k))
    F[:n, :n], F[:n, n:] = A, Bi
    Ct = np.zeros((k, k))
    Ct[:n, :n] = C
    L = np.kron(F.T, np.eye(k)) + np.kron(np.eye(k), F.T)
    aug = np.zeros((k * k + 1, k * k + 1))
    aug[:k * k, :k * k] = L * h
    aug[:k * k, -1] = Ct.ravel(order="F") * h
    W = expm(aug)[:k * k, -1].reshape((k, k), order="F")
    return 0.5 * (W + W.T)
