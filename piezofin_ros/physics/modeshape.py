"""First clamped-free bending mode of a uniform cantilever: Eqs. (5)-(8) of the paper.

The mass-normalised eigenfunction (Eq. 5) is

    phi(x) = 1/sqrt(m_s L) * [cos(l x/L) - cosh(l x/L) + s (sin(l x/L) - sinh(l x/L))]
    s = (sin l - sinh l) / (cos l + cosh l),   l = lambda = 1.87510407.

As printed, Eq. (5) is negative at the tip (phi(L) sqrt(m_s L) = -2).  The sign of a mode
shape is arbitrary; we multiply Eq. (5) by -1 so that a positive modal coordinate ``eta``
means a positive tip deflection.  Every quantity the model uses is either even in ``phi``
(Eq. 6, 7, mu, gamma, thrust) or is defined with this sign convention (tip displacement
``w(L, t) = phi(L) eta(t)``), so nothing else depends on the choice.

All functions work on the dimensionless shape ``phi_hat(xi) = phi(xi L) sqrt(m_s L)``,
``xi = x/L``, so that the integrals below are pure numbers computed once.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError

#: First root of 1 + cos(l) cosh(l) = 0 (clamped-free), as given below Eq. (5).
LAMBDA1 = 1.87510407

#: Number of Gauss-Legendre points the paper uses for the drag integral in gamma.
GAUSS_POINTS = 61

_S = (np.sin(LAMBDA1) - np.sinh(LAMBDA1)) / (np.cos(LAMBDA1) + np.cosh(LAMBDA1))


def phi_hat(xi: ArrayLike, derivative: int = 0) -> NDArray[np.float64]:
    """Dimensionless mode shape of Eq. (5) and its derivatives with respect to ``xi = x/L``.

    ``phi(x) = phi_hat(x/L) / sqrt(m_s L)`` and
    ``d^k phi/dx^k = phi_hat^(k)(x/L) / (L^k sqrt(m_s L))``.
    Sign: positive at the tip (Eq. 5 times -1, see the module docstring).
    """
    if derivative not in range(5):
        raise PhysicsError(f"derivative order must be 0..4, got {derivative}")
    z = LAMBDA1 * np.asarray(xi, dtype=float)
    # d^k/dz^k of cos, cosh, sin, sinh: cycle of period 4 (cos, sin) or 2 (cosh, sinh).
    cos_k = (np.cos, lambda u: -np.sin(u), lambda u: -np.cos(u), np.sin)[derivative % 4]
    sin_k = (np.sin, np.cos, lambda u: -np.sin(u), lambda u: -np.cos(u))[derivative % 4]
    cosh_k = (np.cosh, np.sinh)[derivative % 2]
    sinh_k = (np.sinh, np.cosh)[derivative % 2]
    shape = cos_k(z) - cosh_k(z) + _S * (sin_k(z) - sinh_k(z))
    return -(LAMBDA1**derivative) * shape


@lru_cache(maxsize=8)
def gauss_legendre_unit(n: int = GAUSS_POINTS) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauss-Legendre nodes and weights mapped to [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def integral_phi_hat(power: float, n: int = GAUSS_POINTS, absolute: bool = True) -> float:
    """``int_0^1 |phi_hat(xi)|^power dxi`` by n-point Gauss-Legendre quadrature.

    With ``power = 3`` this is the shape factor of gamma (Eq. 9, 61 points as in the paper):
    ``int_0^L phi^2 |phi| dx = L (m_s L)^(-3/2) * integral_phi_hat(3)``.
    """
    xi, w = gauss_legendre_unit(n)
    p = phi_hat(xi)
    values = np.abs(p) ** power if absolute else p**power
    return float(np.dot(w, values))


#: phi_hat(1): |phi(L)| sqrt(m_s L) = 2 for the mass-normalised first mode.
TIP_VALUE = float(phi_hat(1.0))
#: phi_hat'(1) / phi_hat(1): the tip slope ratio L phi'(L)/phi(L) = 1.3765 (Eq. 5; the
#: project's reading notes print 1.3796, which Eq. 5 does not give).
TIP_SLOPE_RATIO = float(phi_hat(1.0, 1) / phi_hat(1.0))
#: int_0^1 |phi_hat|^3 dxi with the paper's 61 Gauss points (gamma's shape factor).
DRAG_SHAPE_FACTOR = integral_phi_hat(3.0)
