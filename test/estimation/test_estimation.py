"""The estimator against the core's steady state, the load cell within its noise, self-sensing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.estimation.estimator import Estimate, EstimatorConfig, StreamEstimator, analyse_window
from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.steady import harmonic_balance
from piezofin_ros.physics.timedomain import simulate
from piezofin_ros.physics.waveforms import SineBurst
from piezofin_ros.rig.simulated import DriveLimits, RigConfig, SimulatedRig


def run_protocol(
    fin: Fin,
    points: list[tuple[float, float]],
    config: RigConfig | None = None,
    seed: int = 1,
    block: int = 50,
) -> tuple[list[Estimate], SimulatedRig]:
    """The paper's protocol (10 s off, 10 s on, 10 s off) per point, through the streaming estimator."""
    rig = SimulatedRig(fin, config, seed=seed, t0=500.0)
    cfg = EstimatorConfig(loadcell_stiffness_n_per_m=rig.config.loadcell_stiffness)
    est = StreamEstimator(fin, cfg)
    out: list[Estimate] = []
    dt = block / rig.config.sample_rate_hz
    for f, vpp in points:
        for k in range(round(30.0 / dt)):
            on = 10.0 <= k * dt < 20.0
            rig.command(f, vpp, 1 if on else 0)
            b = rig.step(block)
            out += est.add_drive(b.t, b.voltage, b.current)
            out += est.add_tip(b.t, b.tip_velocity)
            out += est.add_loadcell(b.t, b.displacement)
    return out + est.flush(), rig


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def protocol_run() -> tuple[list[Estimate], SimulatedRig]:
    from piezofin_ros.physics.fin import load_fin

    return run_protocol(load_fin("M8528-P1"), [(5.5, 800.0), (9.9, 800.0), (8.0, 400.0)])


def test_one_final_estimate_per_trial_with_both_baselines(protocol_run) -> None:
    estimates, _ = protocol_run
    finals = [e for e in estimates if e.final]
    assert [round(e.frequency_hz, 3) for e in finals] == [5.5, 9.9, 8.0]
    assert all(e.loadcell_baselines == 2 for e in finals)
    for e, start in zip(finals, (510.0, 540.0, 570.0), strict=True):
        # The window is whole periods inside the burst, after the 3 s transient.
        assert start + 3.0 <= e.t_start < start + 3.0 + 1.0 / e.frequency_hz + 0.25
        assert e.t_end <= start + 10.0 + 1e-3
        assert e.n_periods == pytest.approx((e.t_end - e.t_start) * e.frequency_hz, abs=1e-6)


def test_lighthill_thrust_matches_the_steady_state(protocol_run) -> None:
    estimates, rig = protocol_run
    for e in (e for e in estimates if e.final):
        hb = harmonic_balance(rig.fin, e.frequency_hz, e.voltage_pp, harmonics=3)
        assert e.voltage_pp == pytest.approx(float(hb.voltage_pp), rel=1e-3)
        assert e.tip_velocity_rms == pytest.approx(float(hb.tip_velocity_rms), rel=2e-3)
        assert e.thrust_n == pytest.approx(float(hb.thrust_n), rel=4e-3)
        assert e.c_tau == pytest.approx(rig.fin.c_tau, rel=1e-2)  # Eq. (22) = (pi/8) c_m / psi
        # Power: within the current monitor's noise (1 uA x V_rms / sqrt(N)) plus 0.5 %.
        n = (e.t_end - e.t_start) * rig.config.sample_rate_hz
        sigma_p = rig.config.current_noise_a * e.voltage_pp / (2 * math.sqrt(2)) / math.sqrt(n)
        assert abs(e.power_w - float(hb.power_w)) <= 4 * sigma_p + 5e-3 * float(hb.power_w)


def test_load_cell_thrust_within_the_simulated_noise(protocol_run) -> None:
    estimates, rig = protocol_run
    cfg = rig.config
    for e in (e for e in estimates if e.final):
        n_on = (e.t_end - e.t_start) * cfg.sample_rate_hz
        n_base = 5.0 * cfg.sample_rate_hz
        # mean(on) - (pre + post)/2 of white noise: sigma^2 (1/n_on + 1/(2 n_base)).
        sigma_t = cfg.loadcell_stiffness * cfg.displacement_noise_m * math.sqrt(1 / n_on + 1 / (2 * n_base))
        assert abs(e.thrust_loadcell_n - e.thrust_n) <= 5 * sigma_t + 3e-3 * e.thrust_n, (e, sigma_t)


def test_a_linear_load_cell_drift_cancels(m8528: Fin) -> None:
    """The window starts after the transient, so it is not centred between the baselines: the
    paper's plain average of pre and post would leave drift x 1.5 s x stiffness (0.5 mN here)."""
    cfg = RigConfig(loadcell_drift_m_per_s=5e-8)
    estimates, _ = run_protocol(m8528, [(2.0, 400.0), (9.9, 800.0)], cfg)
    finals = [e for e in estimates if e.final]
    assert len(finals) == 2
    for e in finals:
        n_on = (e.t_end - e.t_start) * cfg.sample_rate_hz
        n_base = 5.0 * cfg.sample_rate_hz
        sigma_t = cfg.loadcell_stiffness * cfg.displacement_noise_m * math.sqrt(1 / n_on + 1 / n_base)
        assert abs(e.thrust_loadcell_n - e.thrust_n) <= 5 * sigma_t + 3e-3 * e.thrust_n, (e, sigma_t)
    leak = 5e-8 * 1.0 * cfg.loadcell_stiffness  # what even 1 s of asymmetry would leave
    assert leak > 20 * sigma_t


def test_self_sensed_thrust_matches_the_vibrometer(protocol_run) -> None:
    estimates, _ = protocol_run
    for e in estimates:
        assert e.thrust_self_n == pytest.approx(e.thrust_n, rel=5e-3)
        assert e.tip_velocity_rms_self == pytest.approx(e.tip_velocity_rms, rel=3e-3)


def test_running_windows_in_continuous_driving(m8528: Fin) -> None:
    """No off periods: an estimate every window_s, then a new segment when the frequency changes."""
    rig = SimulatedRig(m8528, seed=3)
    est = StreamEstimator(m8528, EstimatorConfig(window_s=4.0))
    out: list[Estimate] = []
    for k in range(600):  # 30 s: 15 s at 6 Hz then 15 s at 9 Hz
        rig.command(6.0 if k < 300 else 9.0, 700.0, 1)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
    out += est.flush()
    running = [e for e in out if not e.final]
    assert [round(e.frequency_hz, 2) for e in running] == [6.0, 6.0, 9.0, 9.0]
    assert all(e.loadcell_baselines == 0 and math.isnan(e.thrust_loadcell_n) for e in out)
    assert all(math.isnan(e.thrust_n) for e in out)  # no vibrometer here
    for e in running:
        hb = harmonic_balance(m8528, e.frequency_hz, 700.0, harmonics=3)
        assert e.thrust_self_n == pytest.approx(float(hb.thrust_n), rel=1e-2)


def test_swim_speed_term_of_eq19(m8528: Fin) -> None:
    """With U given, the thrust loses (1/2) m_v U^2 mean(w_x^2): compare with the steady state's U."""
    f, vpp, U = 9.0, 800.0, 0.15
    tr = simulate(m8528, SineBurst(f, vpp), duration=12.0, rate_hz=1000.0)
    win = (tr.t >= 4.0) & (tr.t < 4.0 + 72 / f)
    r = analyse_window(
        m8528,
        tr.t[win],
        tr.voltage[win],
        tr.current[win],
        f,
        tip_velocity=tr.tip_velocity[win],
        swim_speed_m_s=U,
    )
    hb = harmonic_balance(m8528, f, vpp, U=U, harmonics=3)
    assert float(hb.thrust_n) < float(harmonic_balance(m8528, f, vpp, harmonics=3).thrust_n)
    assert r["thrust_n"] == pytest.approx(float(hb.thrust_n), rel=2e-3)
    assert r["thrust_self_n"] == pytest.approx(float(hb.thrust_n), rel=2e-3)


def test_power_does_not_leak_reactive_power_off_the_period_grid(paper_fin: Fin) -> None:
    """Windows that are not whole periods: mean(v i) leaks reactive power, the estimate does not."""
    f = 7.3
    tr = simulate(paper_fin, SineBurst(f, 800.0), duration=15.0, rate_hz=1000.0)
    hb = harmonic_balance(paper_fin, f, 800.0, harmonics=3)
    for extra in (0.0, 0.13, 0.3, 0.77):  # fraction of a period beyond 50 whole ones
        win = (tr.t >= 5.0) & (tr.t < 5.0 + (50 + extra) / f)
        r = analyse_window(paper_fin, tr.t[win], tr.voltage[win], tr.current[win], f)
        naive = float(np.mean(tr.voltage[win] * tr.current[win]))
        assert r["power_w"] == pytest.approx(float(hb.power_w), rel=2e-3)
        if extra in (0.13, 0.3):
            assert abs(naive - float(hb.power_w)) > 10 * abs(r["power_w"] - float(hb.power_w))


def test_channels_that_lag_or_never_come(m8528: Fin) -> None:
    """Drive only: estimates still come (NaN where the vibrometer/load cell would be)."""
    rig = SimulatedRig(m8528, seed=2, limits=DriveLimits())
    est = StreamEstimator(m8528)
    out: list[Estimate] = []
    for k in range(600):
        rig.command(9.0, 800.0, 1 if 200 <= k < 400 else 0)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
    finals = [e for e in out if e.final]
    assert len(finals) == 1
    assert math.isnan(finals[0].thrust_loadcell_n)
    assert finals[0].thrust_self_n > 0


def test_a_trial_whose_frequency_moved_within_the_tolerance_keeps_its_amplitude(paper_fin: Fin) -> None:
    """A controller moves the drive 2 % in frequency (6.25 to 6.13 Hz at 446 Vpp: within the 3 % that
    splits a trial) and holds it 35 s: the trial's final estimate spans both, and its lock-in follows
    the periods as timed.  Locked to the window's mean frequency instead, 5 periods of phase slip
    averaged the sine away: the live fish read 84 Vpp for 446 and fed that to its optimiser."""
    rig, est = SimulatedRig(paper_fin, seed=2), StreamEstimator(paper_fin)
    finals: list[Estimate] = []
    for k in range(1000):  # 50 s
        f = 6.25 if k < 200 else 6.13
        rig.command(f, 446.0, 1 if k < 900 else 0)
        b = rig.step(50)
        finals += [e for e in est.add_drive(b.t, b.voltage, b.current) if e.final]
    finals += [e for e in est.flush() if e.final]
    assert len(finals) == 1
    e = finals[0]
    assert e.t_start < 10.0 and e.t_end > 40.0 and 6.13 < e.frequency_hz < 6.25
    assert e.voltage_pp == pytest.approx(446.0, rel=5e-3)
    t, vi = est.drive.slice(e.t_start, e.t_end)
    fixed = analyse_window(paper_fin, t, vi[:, 0], vi[:, 1], e.frequency_hz)
    assert fixed["voltage_pp"] < 0.5 * 446.0  # (the mean frequency alone: the sine averaged away)
