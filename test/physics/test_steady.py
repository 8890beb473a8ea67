"""Harmonic balance (Eqs. 15-20) against Eq. (11), its own residuals, fsolve and energy balance."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from piezofin_ros.physics import _compile, steady
from piezofin_ros.physics._compile import NUMBA
from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.model import _SOLVED, load_model
from piezofin_ros.physics.steady import (
    DRAG_HARMONIC,
    frf_in_air,
    harmonic_balance,
    harmonic_balance_fsolve,
    residuals,
)

BAND = np.linspace(0.5, 60.0, 600)[:, None]
VOLTAGES = np.array([400.0, 600.0, 800.0])


def test_in_vacuo_limit_is_eq11(paper_fin: Fin) -> None:
    fin = paper_fin.replace(rho_w=0.0)  # mu = gamma = 0
    assert fin.mu == 0
    assert fin.gamma == 0
    state = harmonic_balance(fin, BAND, VOLTAGES)
    tip = fin.phi_tip * (state.H0 - 1j * state.H1) / (0.5 * state.voltage_pp)
    assert_allclose(tip, np.broadcast_to(frf_in_air(fin, BAND), tip.shape), rtol=1e-12)


def test_residuals_of_15_to_18_at_round_off(paper_fin: Fin) -> None:
    state = harmonic_balance(paper_fin, BAND, VOLTAGES)
    r = residuals(paper_fin, state)
    assert r.shape == (4, *state.power_w.shape)
    assert np.max(np.abs(r)) < 1e-12


def test_agrees_with_fsolve_pointwise(paper_fin: Fin) -> None:
    f = np.array([1.0, 4.0, 7.5, paper_fin.f_water_linear, 11.0, 25.0])[:, None]
    ours = harmonic_balance(paper_fin, f, VOLTAGES)
    ref = harmonic_balance_fsolve(paper_fin, f, VOLTAGES)
    # Relative to the amplitude (H0 crosses zero at resonance).
    for attr, size in (
        ("H0", ours.modal_amplitude),
        ("H1", ours.modal_amplitude),
        ("I0", ours.current_rms),
        ("I1", ours.current_rms),
    ):
        err = np.abs(getattr(ours, attr) - getattr(ref, attr)) / size
        assert np.max(err) < 1e-9, attr


def test_power_equals_mechanical_dissipation(paper_fin: Fin) -> None:
    # (15) H1 - (16) H0  =>  d(A) A^2 = theta V H1: the electrical power V I0 / 2 is exactly the
    # fundamental-harmonic dissipation of the linear damping and the Morison drag.
    s = harmonic_balance(paper_fin, BAND, VOLTAGES)
    w, a = s.omega, s.modal_amplitude
    fin = paper_fin
    dissipated = fin.zeta * fin.omega_n * w**2 * a**2 + 0.5 * DRAG_HARMONIC * fin.gamma * w**3 * a**3
    assert_allclose(s.power_w, dissipated, rtol=1e-11)


def test_ctau_eq22_is_pi_over_8_cm_over_psi(paper_fin: Fin) -> None:
    s = harmonic_balance(paper_fin, BAND, VOLTAGES)
    assert_allclose(s.c_tau, np.pi / 8 * paper_fin.c_m / paper_fin.psi, rtol=1e-12)
    assert_allclose(s.c_tau, paper_fin.c_tau, rtol=1e-3)  # 0.393 vs pi/8


def test_swimming_speed_term_of_eq19(m8528: Fin) -> None:
    still = harmonic_balance(m8528, BAND, VOLTAGES)
    swim = harmonic_balance(m8528, BAND, VOLTAGES, U=0.1)
    slope_ms = 0.5 * (m8528.phi_tip_slope * still.modal_amplitude) ** 2
    assert_allclose(still.thrust_n - swim.thrust_n, 0.5 * m8528.m_v * 0.01 * slope_ms, rtol=1e-9)
    # The steady state itself does not depend on U in this model.
    assert_allclose(swim.power_w, still.power_w)


def test_small_voltage_is_the_linear_underwater_frf(paper_fin: Fin) -> None:
    fin = paper_fin
    f = BAND[:, 0]
    w = 2 * np.pi * f
    lin = (
        fin.theta
        * fin.phi_tip
        * w
        / np.abs(fin.omega_n**2 - (1 + fin.mu) * w**2 + 2j * fin.zeta * fin.omega_n * w)
    )
    s1 = harmonic_balance(fin, f, 1e-6)
    s2 = harmonic_balance(fin, f, 2e-6)
    amp1 = s1.tip_velocity_rms * np.sqrt(2) / 0.5e-6  # per volt of amplitude
    assert_allclose(amp1, lin, rtol=1e-5)
    assert_allclose(s2.tip_velocity_rms / s1.tip_velocity_rms, 2.0, rtol=1e-5)
    assert_allclose(s2.power_w / s1.power_w, 4.0, rtol=1e-5)
    assert_allclose(s2.thrust_n / s1.thrust_n, 4.0, rtol=1e-5)


def test_drag_makes_high_voltage_sublinear(m8528: Fin) -> None:
    s = harmonic_balance(m8528, m8528.f_water_linear, np.array([400.0, 800.0]))
    ratio = s.tip_velocity_rms[1] / s.tip_velocity_rms[0]
    assert 1.0 < ratio < 2.0  # quadratic drag: doubling V less than doubles the motion


def test_zero_voltage_and_bad_inputs(m8528: Fin) -> None:
    s = harmonic_balance(m8528, [1.0, 5.0], 0.0)
    assert np.all(s.power_w == 0)
    assert np.all(s.thrust_per_watt == 0)
    with pytest.raises(ValueError, match="frequencies"):
        harmonic_balance(m8528, [0.0], 400.0)
    with pytest.raises(ValueError, match="voltages"):
        harmonic_balance(m8528, [1.0], np.nan)


def test_multi_harmonic_reduces_to_single_term_without_drag(paper_fin: Fin) -> None:
    fin = paper_fin.replace(c_d=0.0)
    one = harmonic_balance(fin, BAND, VOLTAGES)
    three = harmonic_balance(fin, BAND, VOLTAGES, harmonics=3)
    assert_allclose(three.H0, one.H0, rtol=1e-10, atol=1e-18)
    assert_allclose(three.b[..., 1:], 0.0, atol=1e-18)


@pytest.mark.skipif(not NUMBA, reason="numba is not installed: only the numpy path exists")
def test_compiled_and_numpy_paths_agree(paper_fin: Fin, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(_compile, "_ASKED", True)  # (compiled once a long computation asks)
    assert _compile.compiled_newton()
    fast = harmonic_balance(paper_fin, BAND, VOLTAGES)
    slow = harmonic_balance(paper_fin, BAND, VOLTAGES, compiled=False)
    assert_allclose(fast.a, slow.a, rtol=1e-13, atol=1e-13 * np.max(np.abs(slow.a)))
    assert_allclose(fast.b, slow.b, rtol=1e-13, atol=1e-13 * np.max(np.abs(slow.b)))


@pytest.mark.skipif(not NUMBA, reason="numba is not installed: only the numpy path exists")
def test_the_compiled_newton_gives_the_numpy_amplitudes_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """``solve_amplitude``'s compiled loop (once a long computation asks: ``for_many_predictions``) stops
    where the numpy loop stops and computes each step in the same order: the same bits, in every
    shape, with and without a guess, at zero drive, against a stiffness-, damping- or drag-free point;
    and so the same predictions of a model whose effects depend on the amplitude."""
    rng = np.random.default_rng(7)
    n = 64
    cases = [(np.full((2, 3), 4e3), 1.0, 20.0, 0.5, None), (np.float64(-3e2), 2.0, 0.0, 1.0, np.float64(0.1))]
    for i in range(60):
        a = rng.normal(0, 1e3, n) * rng.choice([1.0, 1e-3, 0.0], n)
        k = np.abs(rng.normal(0, 1e3, n)) * rng.choice([1.0, 0.0], n)
        c0 = np.where((a == 0) & (k == 0), 1.0, np.abs(rng.normal(0, 10, n)) * rng.choice([1.0, 0.0], n))
        force = np.abs(rng.normal(0, 1, n)) * rng.choice([1.0, 0.0], n)
        guess = np.abs(rng.normal(0, 1, n)) * rng.choice([1.0, 0.0, np.nan], n) if i % 2 else None
        cases.append((a, c0, k, force, guess))
    model = load_model("paper-twin-M8528-P1")
    grid = np.meshgrid(np.linspace(2.0, 12.0, 21), [150.0, 800.0])

    def run(compiled: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
        monkeypatch.setattr(steady, "compiled_newton", lambda: compiled)
        _SOLVED.clear()
        p = model.predict(*grid)
        return [steady.solve_amplitude(a, c0, k, f, guess=g) for a, c0, k, f, g in cases], [
            p.tip_velocity_rms,
            p.current_rms,
            p.power_w,
            p.thrust_n,
        ]

    (amps0, pred0), (amps1, pred1) = run(False), run(True)
    for x, y in zip(amps0 + pred0, amps1 + pred1, strict=True):
        assert x.shape == y.shape and x.tobytes() == y.tobytes()
