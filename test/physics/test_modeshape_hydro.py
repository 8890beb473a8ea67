"""Mode shape (Eqs. 5-8) and hydrodynamic coefficients (Eqs. 21-23) against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy import integrate

from piezofin_ros.physics import hydro, modeshape
from piezofin_ros.physics.modeshape import LAMBDA1, phi_hat


def test_tip_value_of_mass_normalised_mode() -> None:
    # |phi(L)| sqrt(m_s L) = 2 for the first clamped-free mode.
    assert_allclose(abs(modeshape.TIP_VALUE), 2.0, rtol=1e-12)
    # L phi'(L)/phi(L) = 1.3765 for Eq. (5) (the reading notes' 1.3796 is a slip; a one-sided
    # finite difference of phi gives the same 1.3765).
    assert_allclose(modeshape.TIP_SLOPE_RATIO, 1.3765, atol=5e-5)
    fd = (phi_hat(1.0) - phi_hat(1.0 - 1e-7)) / 1e-7 / phi_hat(1.0)
    assert_allclose(modeshape.TIP_SLOPE_RATIO, fd, rtol=1e-5)


def test_clamped_free_boundary_conditions() -> None:
    # Eq. (5) satisfies w(0) = w'(0) = 0 (clamp) and w''(L) = w'''(L) = 0 (free end);
    # lambda is printed with 9 digits, so the free-end conditions hold to ~1e-8.
    assert_allclose(phi_hat(0.0), 0.0, atol=1e-15)
    assert_allclose(phi_hat(0.0, 1), 0.0, atol=1e-15)
    assert_allclose(phi_hat(1.0, 2), 0.0, atol=1e-7)
    assert_allclose(phi_hat(1.0, 3), 0.0, atol=1e-7)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_derivatives_match_finite_differences(order: int) -> None:
    xi = np.linspace(0.05, 0.95, 19)
    h = 1e-5
    numeric = (phi_hat(xi + h, order - 1) - phi_hat(xi - h, order - 1)) / (2 * h)
    assert_allclose(phi_hat(xi, order), numeric, rtol=1e-7, atol=1e-7)


def test_orthogonality_eqs_6_and_7(paper_fin) -> None:
    fin = paper_fin
    x, w = modeshape.gauss_legendre_unit(61)
    x, w = x * fin.L, w * fin.L
    scale = 1.0 / np.sqrt(fin.m_s * fin.L)
    phi = scale * phi_hat(x / fin.L)
    phi4 = scale * phi_hat(x / fin.L, 4) / fin.L**4
    # Eq. (6): int m_s phi^2 = 1
    assert_allclose(np.dot(w, fin.m_s * phi**2), 1.0, rtol=1e-8)
    # Eq. (7) with Eq. (8) on the same length: int phi D phi'''' = omega_n^2
    omega_n_eq8 = LAMBDA1**2 * np.sqrt(fin.D / (fin.m_s * fin.L**4))
    assert_allclose(np.dot(w, phi * fin.D * phi4), omega_n_eq8**2, rtol=1e-8)


def test_gauss_drag_integral_matches_adaptive_quadrature() -> None:
    ref, _ = integrate.quad(lambda s: abs(float(phi_hat(s))) ** 3, 0.0, 1.0, epsabs=1e-13)
    assert_allclose(modeshape.DRAG_SHAPE_FACTOR, ref, rtol=1e-10)


def test_cm_at_the_papers_aspect_ratios() -> None:
    # Eq. (21) at psi = 2.1, 3.9, 5.4 (the text's 0.069 for 2.1 is a typo for ~0.70).
    assert_allclose(hydro.inertia_coefficient([2.1, 3.9, 5.4]), [0.703, 0.951, 0.998], atol=6e-4)
    assert_allclose(hydro.inertia_coefficient(1e6), 1.0, rtol=1e-5)


def test_eq23_equals_0393_cm_over_psi() -> None:
    # Term by term: 0.393 * (psi^2 - 0.701 psi + 0.374) rounded to the printed 3 decimals is
    # 0.393 psi^2 - 0.275 psi + 0.147, and the denominator is psi (psi^2 - 1.111 psi + 2.637).
    assert_allclose(np.round(0.393 * np.array([1.0, -0.701, 0.374]), 3), [0.393, -0.275, 0.147])
    psi = np.linspace(1.5, 20.0, 400)  # the fins' range; the rounding matters only below ~1
    rational = hydro.thrust_coefficient(psi)
    product = hydro.thrust_coefficient_from_cm(hydro.inertia_coefficient(psi), psi)
    assert_allclose(rational, product, rtol=1.5e-3)  # = 0.0005 psi / numerator at psi = 1.5
    assert_allclose(hydro.C_TAU_FACTOR, np.pi / 8, rtol=1e-3)
