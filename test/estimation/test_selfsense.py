"""Self-sensing on a fin the paper's model does not describe: dielectric loss, a coupling that grows
with the field, an added mass off c_m(psi) and growing with the motion.  The nominal self-sensing is
wrong by tens of per cent; calibrated with the fin's own capacitance, loss, coupling and c_m (at the
motion's Keulegan-Carpenter number) it agrees with the vibrometer."""

from __future__ import annotations

import numpy as np
import pytest

from piezofin_ros.estimation.estimator import Estimate, EstimatorConfig, StreamEstimator
from piezofin_ros.estimation.selfsense import Calibration
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.model import Model
from piezofin_ros.rig.simulated import SimulatedRig

FIN = load_fin("M8528-P1")
MODEL = Model.of(  # the last: the twin's added mass, growing with KC^2 (the estimator's thrust too)
    FIN,
    {
        "dielectric_loss": [0.08],
        "field_coupling": [0.3, 1.0],
        "added_mass_offset": [1.2],
        "added_mass_kc2": [0.25],
    },
)


def calibrate(frequency_hz: float, voltage_pp: float) -> Calibration:
    return Calibration.of_law(MODEL.law(frequency_hz, voltage_pp))


def finals(calibrated: bool, est: StreamEstimator | None = None) -> list[Estimate]:
    """Two continuous points on the rig streaming MODEL, through the streaming estimator (``est``,
    or a new one calibrated or not)."""
    rig = SimulatedRig(FIN, model=MODEL.knobs_at, seed=3, t0=100.0)
    if est is None:
        est = StreamEstimator(FIN, EstimatorConfig(), calibrate if calibrated else None)
    out: list[Estimate] = []
    for f, vpp in ((6.0, 800.0), (9.5, 500.0)):
        for k in range(round(12.0 / 0.05)):
            rig.command(f, vpp, 1 if k * 0.05 < 11.0 else 0)
            b = rig.step(50)
            out += est.add_drive(b.t, b.voltage, b.current)
            out += est.add_tip(b.t, b.tip_velocity)
    return [e for e in out + est.flush() if e.final]


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def both() -> tuple[list[Estimate], list[Estimate]]:
    return finals(False), finals(True)


def test_the_nominal_self_sensing_is_wrong_on_such_a_fin(both) -> None:
    nominal, _ = both
    truth = MODEL.predict([e.frequency_hz for e in nominal], [e.voltage_pp for e in nominal])
    error = np.array([e.thrust_self_n for e in nominal]) / truth.thrust_n - 1
    assert np.all(np.abs(error) > 0.1), error  # loss read as motion, the coupling and c_m off


def test_the_calibrated_self_sensing_agrees_with_the_truth_and_the_vibrometer(both) -> None:
    _, calibrated = both
    assert len(calibrated) == 2
    truth = MODEL.predict([e.frequency_hz for e in calibrated], [e.voltage_pp for e in calibrated])
    for e, thrust in zip(calibrated, truth.thrust_n, strict=True):
        assert e.thrust_self_n == pytest.approx(float(thrust), rel=0.02)
        assert e.thrust_n == pytest.approx(float(thrust), rel=0.02)  # Lighthill with the model's c_m
        assert e.thrust_self_n == pytest.approx(e.thrust_n, rel=0.02)


def test_the_estimate_carries_the_drive_admittance(both) -> None:
    nominal, _ = both
    truth = MODEL.predict([e.frequency_hz for e in nominal], [e.voltage_pp for e in nominal])
    measured = np.array([complex(e.admittance_re, e.admittance_im) for e in nominal])
    assert np.allclose(measured, truth.admittance, rtol=5e-3)


def test_the_estimators_load_cell_stiffness_is_the_simulated_rigs() -> None:
    """(``thrust_estimator`` no longer loads the simulated rig to learn it: the two defaults agree.)"""
    from piezofin_ros.rig.simulated import RigConfig

    assert EstimatorConfig().loadcell_stiffness_n_per_m == pytest.approx(RigConfig().loadcell_stiffness)


def test_lighthill_thrust_with_a_kc_dependent_added_mass_needs_the_frequency() -> None:
    """Without the frequency the tip's amplitude, hence KC, is unknown: an error, not KC = 0."""
    from piezofin_ros.errors import EstimationError
    from piezofin_ros.estimation.selfsense import lighthill_thrust

    for cal in (Calibration(mass_kc=0.5), Calibration(mass_kc2=0.25)):
        with pytest.raises(EstimationError, match="frequency_hz"):
            lighthill_thrust(FIN, 0.05, cal)
    # the closed form: (1/2) m_v c (1 + a KC + b KC^2) u^2, KC = 2 pi X / b, X = sqrt(2) u / (2 pi f)
    u, f, cal = 0.05, 4.0, Calibration(mass=1.3, mass_kc=0.5, mass_kc2=0.25)
    kc = 2 * np.pi * (np.sqrt(2) * u / (2 * np.pi * f)) / FIN.b
    expected = 0.5 * FIN.m_v * 1.3 * (1 + 0.5 * kc + 0.25 * kc**2) * u**2
    assert float(lighthill_thrust(FIN, u, cal, f)) == pytest.approx(expected, rel=1e-12)
    assert float(lighthill_thrust(FIN, u)) == pytest.approx(0.5 * FIN.m_v * u**2, rel=1e-12)


def test_a_stream_of_calibrations_cannot_grow_the_estimator(both) -> None:
    """``calibrate_from`` (the controller's fitted fin, a message from the network): 20,000 of them,
    each from a time of its own, grow the estimator by no more than a few kilobytes (it kept every
    one); the calibration sent last for the windows' times still applies, as alone."""
    import tracemalloc

    from piezofin_ros.estimation.selfsense import NOMINAL

    est = StreamEstimator(FIN, EstimatorConfig())
    tracemalloc.start()
    try:
        for k in range(200):
            est.calibrate_from(1e6 + k, lambda f, v: NOMINAL)
        before = tracemalloc.get_traced_memory()[0]
        for k in range(200, 20_000):
            est.calibrate_from(1e6 + k, lambda f, v: NOMINAL)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert grown < 20_000, grown
    est.calibrate_from(0.0, calibrate)
    got = [e.thrust_self_n for e in finals(False, est)]
    assert got == [e.thrust_self_n for e in both[1]]
