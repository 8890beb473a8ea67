"""The simulated rig: command checks, the drive's safety, streaming = batch physics, load cell."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.timedomain import simulate
from piezofin_ros.physics.waveforms import SineBurst
from piezofin_ros.rig.simulated import (
    HARD_VOLTAGE_PP_MAX,
    DriveLimits,
    RigConfig,
    SimulatedRig,
    check_command,
)

QUIET = RigConfig(voltage_noise_v=0, current_noise_a=0, vibrometer_noise_m_s=0, displacement_noise_m=0)


@pytest.mark.parametrize(
    ("cmd", "accepted", "why"),
    [
        ((5.0, 800.0, 1.0), (5.0, 800.0, True), None),
        ((5.0, 900.0, 1.0), (5.0, 800.0, True), "clamped"),
        ((math.nan, 400.0, 1.0), None, "non-finite"),
        ((5.0, math.inf, 1.0), None, "non-finite"),
        ((-1.0, 400.0, 1.0), None, "outside"),
        ((1e6, 400.0, 1.0), None, "outside"),
        ((5.0, -10.0, 1.0), None, "negative"),
        ((5.0, 400.0, 0.5), None, "'on' must be 0 or 1"),
        ((math.nan, math.nan, 0.0), (0.0, 0.0, False), None),  # off is always safe
    ],
)
def test_check_command(cmd: tuple, accepted: tuple | None, why: str | None) -> None:
    out, reason = check_command(*cmd, DriveLimits())
    if accepted is None:
        assert out is None
    else:
        assert out is not None
        assert (out.frequency_hz, out.voltage_pp, out.on) == accepted
    assert (reason is None) == (why is None)
    if why:
        assert why in reason


def test_limits_cannot_exceed_the_hard_cap() -> None:
    with pytest.raises(ValueError, match="hard cap"):
        DriveLimits(voltage_pp_max=HARD_VOLTAGE_PP_MAX + 1)


def test_streaming_rig_equals_the_batch_engine(m8528: Fin) -> None:
    """With a step drive (infinite slew) and no noise, block-by-block = one simulate() call."""
    rig = SimulatedRig(m8528, QUIET, DriveLimits(slew_vpp_per_s=1e9, command_timeout_s=100.0))
    rig.command(7.0, 600.0, 1)
    blocks = [rig.step(37) for _ in range(60)]  # odd block size: state carried across blocks
    tip = np.concatenate([b.tip_velocity for b in blocks])
    ref = simulate(m8528, SineBurst(7.0, 600.0), duration=60 * 37 / 1000.0, rate_hz=1000.0)
    # The rig's first RK4 step already sees the full amplitude ramped within 1 ns.
    np.testing.assert_allclose(tip, ref.tip_velocity[1:], rtol=0, atol=1e-6 * np.abs(ref.tip_velocity).max())
    cur = np.concatenate([b.current for b in blocks])
    np.testing.assert_allclose(cur, ref.current[1:], rtol=0, atol=1e-6 * np.abs(ref.current).max())


def test_drive_is_continuous_and_slew_limited(m8528: Fin) -> None:
    limits = DriveLimits(slew_vpp_per_s=2000.0)
    rig = SimulatedRig(m8528, QUIET, limits)
    rig.command(9.0, 800.0, 1)
    v = np.concatenate([rig.step(50).voltage for _ in range(20)])
    assert np.max(np.abs(v)) <= 400.0 + 1e-9
    # The amplitude grows at most at 1000 V/s (half the peak-to-peak slew).
    t = np.arange(1, v.size + 1) / 1000.0
    assert np.all(np.abs(v) <= 1000.0 * t + 1e-9)
    # No step: consecutive samples differ by at most the sine's slope x dt.
    assert np.max(np.abs(np.diff(v))) <= 400.0 * 2 * np.pi * 9.0 / 1000.0 * 1.01


def test_watchdog_ramps_down_when_commands_stop(m8528: Fin) -> None:
    rig = SimulatedRig(m8528, QUIET, DriveLimits(command_timeout_s=0.5))
    rig.command(9.0, 800.0, 1)
    blocks = [rig.step(50) for _ in range(30)]  # 1.5 s, no further command
    events = [e for b in blocks for e in b.events]
    assert len(events) == 1
    assert "watchdog" in events[0]
    t = np.concatenate([b.t for b in blocks])
    v = np.concatenate([b.voltage for b in blocks])
    # timeout 0.5 s (+ one block) + ramp 800 V / 4000 V/s = 0.2 s: zero from 0.8 s on.
    assert np.all(v[t > 0.8] == 0.0)
    assert rig.drive.voltage_pp == 0.0


def test_load_cell_reads_mean_thrust_over_its_stiffness(m8528: Fin) -> None:
    cfg = QUIET.replace(loadcell_drift_m_per_s=0.0)
    rig = SimulatedRig(m8528, cfg, DriveLimits(command_timeout_s=100.0))
    rig.command(9.0, 800.0, 1)
    blocks = [rig.step(100) for _ in range(80)]
    last = blocks[-30:]  # 3 s = 27 whole periods at 9 Hz
    x = np.concatenate([b.displacement for b in last])
    thrust = np.concatenate([b.thrust_true for b in last])
    assert cfg.loadcell_stiffness == pytest.approx(6846.09, rel=1e-5)  # 3 E I / l^3 of the paper's beam
    assert np.mean(x) * cfg.loadcell_stiffness == pytest.approx(np.mean(thrust), rel=2e-3)


def test_rig_config_rejects_bad_values() -> None:
    with pytest.raises(ValueError, match=r"rig\.sample_rate_hz"):
        RigConfig(sample_rate_hz=0.0)
    with pytest.raises(ValueError, match=r"rig\.current_noise_a"):
        RigConfig(current_noise_a=math.nan)


def test_protocol_mode_runs_the_papers_trial_on_one_command(m8528: Fin) -> None:
    from piezofin_ros.physics.waveforms import ProtocolTiming

    rig = SimulatedRig(m8528, QUIET, protocol=ProtocolTiming(off_s=2.0, on_s=3.0))
    rig.command(9.0, 800.0, 1)  # one command only: the watchdog must not stop the burst
    blocks = [rig.step(50) for _ in range(200)]  # 10 s
    t = np.concatenate([b.t for b in blocks])
    v = np.concatenate([b.voltage for b in blocks])
    assert np.all(v[t <= 2.0] == 0.0)
    burst = (t > 2.25) & (t < 5.0)
    assert np.max(np.abs(v[burst])) == pytest.approx(400.0, rel=1e-3)
    assert np.all(v[t > 5.25] == 0.0)
    assert rig.trial is None
    assert not any(e for b in blocks for e in b.events)  # no watchdog event
    rig.command(9.0, 800.0, 1)  # the same point again: a heartbeat, not a new trial
    assert rig.trial is None
    rig.command(9.0, 0.0, 0)
    rig.command(9.0, 800.0, 1)  # off, then on: a new trial
    assert rig.trial is not None


def bursting(fin: Fin) -> SimulatedRig:
    """A protocol-mode rig 1 s into a 9 Hz, 800 Vpp trial (0.5 s off, then the burst)."""
    from piezofin_ros.physics.waveforms import ProtocolTiming

    rig = SimulatedRig(fin, QUIET, protocol=ProtocolTiming(off_s=0.5, on_s=5.0))
    rig.command(9.0, 800.0, 1)
    for _ in range(30):
        rig.step(50)
    assert rig.drive.voltage_pp == pytest.approx(800.0)
    return rig


def test_protocol_mode_off_aborts(m8528: Fin) -> None:
    rig = bursting(m8528)
    rig.command(0.0, 0.0, 0)
    v = np.concatenate([rig.step(50).voltage for _ in range(10)])
    assert np.all(v[-200:] == 0.0)
    assert rig.trial is None


def test_limits_tighten_live_and_never_relax(m8528: Fin) -> None:
    from dataclasses import replace

    rig = bursting(m8528)
    lim = rig.drive.limits
    assert "ramps down to 500" in rig.tighten(replace(lim, voltage_pp_max=500.0))
    v = np.concatenate([rig.step(50).voltage for _ in range(10)])
    assert np.max(np.abs(v[-300:])) <= 250.0 + 1e-9  # the running trial is clamped too
    assert np.max(np.abs(np.diff(v))) < (2 * np.pi * 9.0 * 400.0 + 2000.0) / 1000.0  # no step: sine + slew
    with pytest.raises(ValueError, match=r"voltage_pp_max 500 -> 600.*slew_vpp_per_s"):
        rig.tighten(replace(rig.drive.limits, voltage_pp_max=600.0, slew_vpp_per_s=1e5))
    assert "outside the new band" in rig.tighten(replace(rig.drive.limits, frequency_max_hz=8.0))
    v = np.concatenate([rig.step(50).voltage for _ in range(10)])
    assert np.all(v[-200:] == 0.0) and rig.trial is None


STOPS = ("off", "watchdog", "cap lowered", "cap to 0", "stop (deactivate)", "band narrowed")


@settings(max_examples=120, deadline=None)
@given(
    slew=st.floats(1.0, 1e6),
    cap=st.floats(100.0, HARD_VOLTAGE_PP_MAX),
    f=st.floats(0.5, 40.0),
    kind=st.sampled_from(STOPS),
)
def test_every_stop_is_fast_whatever_the_settings(slew: float, cap: float, f: float, kind: str) -> None:
    """From full amplitude at any slew, cap and frequency, every kind of stop is below 1 % of the
    amplitude within 0.5 s (0.5 s after the watchdog's timeout for that one), and never rises."""
    from piezofin_ros.physics.fin import load_fin

    rig = SimulatedRig(load_fin("M8528-P1"), QUIET, DriveLimits(voltage_pp_max=cap, slew_vpp_per_s=1e6))
    rig.command(f, cap, 1)
    rig.step(20)
    rig.tighten(DriveLimits(voltage_pp_max=cap, slew_vpp_per_s=slew))  # a slower slew, taken live
    a0 = rig.drive.amplitude
    assert a0 == pytest.approx(cap / 2)
    limits = rig.drive.limits
    wait = 0.0
    if kind == "off":
        rig.command(f, 0.0, 0)
    elif kind == "watchdog":
        wait = limits.command_timeout_s
    elif kind == "cap lowered":
        rig.tighten(replace(limits, voltage_pp_max=0.01 * cap))
    elif kind == "cap to 0":
        rig.tighten(replace(limits, voltage_pp_max=0.0))
    elif kind == "stop (deactivate)":
        rig.stop()
    elif f + 1.0 <= limits.frequency_max_hz:  # a band above the running frequency
        rig.tighten(replace(limits, frequency_min_hz=f + 0.1, frequency_max_hz=f + 1.0))
    else:  # at the top of the band (hypothesis found f = 40 Hz): a band below it
        rig.tighten(replace(limits, frequency_min_hz=f - 1.0, frequency_max_hz=f - 0.1))
    amps = []
    for _ in range(round((wait + 0.5) / 0.01) + 1):
        rig.step(10)
        amps.append(rig.drive.amplitude)
    assert amps[-1] <= 0.01 * a0 + 1e-9
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(amps))


def test_the_watchdog_latches_until_an_off_command(m8528: Fin) -> None:
    rig = SimulatedRig(m8528, QUIET)
    rig.command(5.0, 800.0, 1)
    for _ in range(40):  # 2 s without a command: tripped, ramped to zero
        rig.step(50)
    assert rig.drive.amplitude == 0.0 and rig.drive.tripped
    accepted, why = rig.command(5.0, 800.0, 1)
    assert not accepted and "re-arm" in (why or "")
    rig.step(300)
    assert rig.drive.amplitude == 0.0
    assert rig.command(5.0, 0.0, 0) == (True, None)  # a deliberate off re-arms
    assert rig.command(5.0, 800.0, 1)[0]
    rig.step(300)
    assert rig.drive.amplitude == pytest.approx(400.0)


@pytest.mark.parametrize("value", [True, False, "400", None, math.nan, -1.0])
def test_limits_refuse_what_is_not_a_number(value: object) -> None:
    with pytest.raises(ValueError, match="voltage_pp_max"):
        DriveLimits(voltage_pp_max=value)  # type: ignore[arg-type]
    DriveLimits(voltage_pp_max=0.0)  # zero is a valid cap: no drive at all
