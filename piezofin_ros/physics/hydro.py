"""Hydrodynamic coefficients: Morison's inertia coefficient and the thrust coefficient.

* Eq. (21): the paper's curve fit of the first-mode inertia coefficient against the
  aspect ratio ``psi = L/b``::

      c_m(psi) = (psi^2 - 0.701 psi + 0.374) / (psi^2 - 1.111 psi + 2.637)

  It tends to 1 (the two-dimensional strip value) as psi grows.  At psi = 2.1, 3.9 and
  5.4 it gives 0.703, 0.951 and 0.998; the paper's text quotes 0.069 for psi = 2.1, a
  typo for about 0.70 (Eq. 21 and Fig. 2 agree on ~0.7).
* Eqs. (22)-(23): Lighthill's mean thrust (19)-(20) with ``U = 0`` divided by
  ``(1/2) rho_w omega^2 |w(L)|^2 b L`` (``|w(L)|`` the tip amplitude) is
  ``(pi/8) c_m / psi``; the paper rounds pi/8 = 0.3927 to 0.393, and its rational form of
  Eq. (23) is that product written out term by term.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: pi/8 to the paper's three digits (Eq. 23).  The exact Lighthill value is pi/8.
C_TAU_FACTOR = 0.393


def inertia_coefficient(psi: ArrayLike) -> NDArray[np.float64]:
    """Morison inertia coefficient ``c_m`` of the first bending mode, Eq. (21)."""
    p = np.asarray(psi, dtype=float)
    return (p**2 - 0.701 * p + 0.374) / (p**2 - 1.111 * p + 2.637)


def thrust_coefficient(psi: ArrayLike) -> NDArray[np.float64]:
    """Thrust coefficient ``c_tau(psi)``, Eq. (23) in its printed rational form."""
    p = np.asarray(psi, dtype=float)
    return (0.393 * p**2 - 0.275 * p + 0.147) / (p**3 - 1.111 * p**2 + 2.637 * p)


def thrust_coefficient_from_cm(c_m: ArrayLike, psi: ArrayLike) -> NDArray[np.float64]:
    """``c_tau = 0.393 c_m / psi``, the left-hand form of Eq. (23)."""
    return C_TAU_FACTOR * np.asarray(c_m, dtype=float) / np.asarray(psi, dtype=float)


def added_mass_ratio(rho_w: float, b: float, c_m: float, m_s: float) -> float:
    """``mu = (pi/4) rho_w b^2 c_m / m_s`` (below Eq. 10): Morison added mass over beam mass."""
    return float(np.pi / 4.0 * rho_w * b**2 * c_m / m_s)


def virtual_mass(rho_w: float, b: float, c_m: float) -> float:
    """Virtual mass per unit length at the tip, ``m_v = (pi/4) rho_w b^2 c_m`` (Eq. 20), kg/m."""
    return float(np.pi / 4.0 * rho_w * b**2 * c_m)
