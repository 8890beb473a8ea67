"""The drive with an offset (a DC bias, to steer a fish): the MFC's window holds whatever is commanded.

Issue 42: the P1 MFC is rated from -500 V to +1500 V, so a drive may carry an offset, but the
instantaneous voltage ``v = b + a sin`` must never leave the window, under any command, any order of
commands, a lowered cap, a tightened window or any stop; the offset ramps as the amplitude does, and
every stop takes it to zero as fast as the amplitude.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.config import HARD_VOLTAGE_WINDOW_V
from piezofin_ros.estimation.estimator import Estimate, EstimatorConfig, StreamEstimator
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import Fin, load_fin
from piezofin_ros.rig.simulated import DriveLimits, RigConfig, SimulatedRig, bias_window, check_command

QUIET = RigConfig(voltage_noise_v=0, current_noise_a=0, vibrometer_noise_m_s=0, displacement_noise_m=0)
LOW, HIGH = HARD_VOLTAGE_WINDOW_V


@pytest.mark.parametrize(
    ("cmd", "accepted", "why"),
    [
        ((5.0, 800.0, 1.0, 1100.0), (800.0, 1100.0), None),  # the window's top: 1500 - 400
        ((5.0, 800.0, 1.0, -100.0), (800.0, -100.0), None),  # its bottom: -500 + 400
        ((5.0, 800.0, 1.0, 1200.0), (800.0, 1100.0), "out of the window"),
        ((5.0, 800.0, 1.0, -1e9), (800.0, -100.0), "out of the window"),
        ((5.0, 1e6, 1.0, 1e9), (800.0, 1100.0), "above the limit"),  # the cap first, then the offset
        ((5.0, 0.0, 1.0, 1500.0), (0.0, 1500.0), None),  # an offset alone, up to the window's edge
        ((5.0, 400.0, 1.0, math.nan), None, "non-finite"),
        ((5.0, 400.0, 1.0, math.inf), None, "non-finite"),
        ((5.0, 400.0, 1.0, -math.inf), None, "non-finite"),
        ((math.nan, math.nan, 0.0, math.nan), (0.0, 0.0), None),  # off is always safe
    ],
)
def test_an_offset_is_checked_against_the_window(cmd: tuple, accepted: tuple | None, why: str | None) -> None:
    out, reason = check_command(*cmd[:3], DriveLimits(), cmd[3])
    if accepted is None:
        assert out is None
    else:
        assert out is not None and (out.voltage_pp, out.bias_v) == accepted
    assert (reason is None) == (why is None), reason
    if why:
        assert why in (reason or "")


def test_a_window_that_cannot_hold_the_cap_or_leaves_the_rating_is_refused() -> None:
    with pytest.raises(ValueError, match="lower voltage_pp_max to 600"):
        DriveLimits(voltage_min_v=-300.0)  # 800 Vpp needs -400 V
    for low, high in ((-600.0, 1500.0), (-500.0, 1600.0), (10.0, 1500.0), (-500.0, -10.0)):
        with pytest.raises(ValueError, match="voltage_m"):
            DriveLimits(voltage_min_v=low, voltage_max_v=high)
    DriveLimits(voltage_min_v=-60.0, voltage_max_v=360.0, voltage_pp_max=120.0)  # a P2's window


def run(rig: SimulatedRig, seconds: float, command: tuple[float, ...] = ()) -> np.ndarray:
    """The drive's samples over ``seconds``, ``command`` repeated every 0.1 s (a controller's heartbeat)."""
    out = []
    for k in range(round(seconds / 0.01)):
        if command and k % 10 == 0:
            rig.command(*command)
        out.append(rig.step(10).voltage)
    return np.concatenate(out)


COMMAND = st.tuples(
    st.sampled_from([0.5, 5.5, 40.0]),  # Hz
    st.one_of(st.floats(0.0, 1000.0), st.sampled_from([1e9, -1.0])),  # Vpp (clamped or refused)
    st.sampled_from([1.0, 1.0, 1.0, 0.0]),  # on, mostly
    st.one_of(st.floats(-2000.0, 2000.0), st.sampled_from([1e308, -1e308, math.nan])),  # offset, V
    st.floats(0.0, 0.4),  # s held
)


@settings(max_examples=80, deadline=None)
@given(
    commands=st.lists(COMMAND, min_size=1, max_size=6),
    slew=st.floats(1.0, 1e6),
    window=st.tuples(st.floats(LOW, -400.0), st.floats(400.0, HIGH)),
    then=st.sampled_from(["watchdog", "off", "stop (deactivate)", "cap lowered"]),
)
def test_no_command_sequence_takes_the_drive_out_of_its_window(
    commands: list[tuple[float, float, float, float, float]],
    slew: float,
    window: tuple[float, float],
    then: str,
) -> None:
    """Any commands, in any order, at any slew and window: every sample within the window, no step
    beyond what the sine and the two ramps give, and after the stop the drive at 0 V within 0.5 s
    (0.5 s after the watchdog's timeout for that one); a lowered cap keeps the offset."""
    limits = DriveLimits(slew_vpp_per_s=slew, voltage_min_v=window[0], voltage_max_v=window[1])
    rig = SimulatedRig(load_fin("M8528-P1"), QUIET, limits)
    v = []
    for f, vpp, on, bias, held in commands:
        rig.command(f, vpp, on, bias)
        v.append(run(rig, held + 0.01))
    if then == "off":
        rig.command(5.0, 0.0, 0)
    elif then == "stop (deactivate)":
        rig.stop()
    elif then == "cap lowered":
        kept = rig.drive.bias_target
        rig.tighten(replace(limits, voltage_pp_max=100.0))
        assert rig.drive.bias_target == kept
    after = run(rig, (limits.command_timeout_s if then == "watchdog" else 0.0) + 0.5)
    v.append(after)
    every = np.concatenate(v)
    assert window[0] - 1e-9 <= every.min() and every.max() <= window[1] + 1e-9
    steepest = (0.5 * 1000.0) * 2 * math.pi * 40.0 + 2.0 * max(slew, 4000.0)  # V/s: sine, both ramps
    assert np.max(np.abs(np.diff(every))) <= steepest * 1e-3 * 1.01
    if then != "cap lowered":
        assert np.all(after[-50:] == 0.0) and rig.drive.bias == 0.0


def test_a_tightened_window_ramps_a_drive_outside_it_to_zero_without_a_step(m8528: Fin) -> None:
    rig = SimulatedRig(m8528, QUIET)
    before = run(rig, 1.0, (5.0, 400.0, 1, 1200.0))
    assert before.max() == pytest.approx(1400.0, abs=1.0)
    said = rig.tighten(replace(rig.drive.limits, voltage_max_v=1000.0))
    assert "leaves the new window" in said and "ramping to zero" in said
    after = run(rig, 0.5)
    assert np.max(np.abs(np.diff(np.concatenate([before, after])))) < 50.0  # no step: ramps
    assert np.all(after[-100:] == 0.0)
    assert rig.command(5.0, 400.0, 1, 1200.0)[1] is not None  # clamped to the new window
    assert run(rig, 1.0, (5.0, 400.0, 1, 1200.0)).max() == pytest.approx(1000.0)


def test_the_offset_ramps_at_the_slew_and_yields_to_the_amplitude(m8528: Fin) -> None:
    """An offset and a sine asked at once: each ramps at the slew (1,000 V/s here), the offset
    yields where together they would leave the window, and both reach their targets."""
    rig = SimulatedRig(m8528, QUIET, DriveLimits(slew_vpp_per_s=2000.0))
    v, bias = [], []
    for k in range(200):  # 2 s
        if k % 10 == 0:
            rig.command(5.0, 800.0, 1, 1100.0)
        v.append(rig.step(10).voltage)
        bias.append(rig.drive.bias)
    t = 0.01 * np.arange(1, 201)
    assert np.concatenate(v).max() <= 1500.0 + 1e-9
    assert np.all(np.array(bias) <= 1000.0 * t + 1e-6)  # from 0 to 1,100 V at 1,000 V/s: 1.1 s
    assert bias[108] < 1100.0 and bias[111] == pytest.approx(1100.0)
    assert rig.drive.bias == pytest.approx(1100.0) and rig.drive.amplitude == pytest.approx(400.0)
    assert bias_window(800.0, rig.drive.limits) == (-100.0, 1100.0)


def biased_run(fin: Fin, bias_v: float) -> tuple[list[Estimate], np.ndarray]:
    """Running estimates of 20 s at 6 Hz, 300 Vpp on the offset; and the rig's samples (t, v, i, the
    supply's watt as its meter reads it)."""
    switching = load_amplifier("fish-switching")  # (its draw follows v i: the offset moves it)
    rig = SimulatedRig(fin, seed=3, amplifier=switching)
    est = StreamEstimator(fin, EstimatorConfig(window_s=4.0), amplifier=switching)
    out: list[Estimate] = []
    samples = []
    for _ in range(400):
        rig.command(6.0, 300.0, 1, bias_v)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
        samples.append(np.stack([b.t, b.voltage, b.current, b.supply_voltage * b.supply_current]))
    return [e for e in out + est.flush() if not e.final], np.concatenate(samples, axis=1)


def test_the_estimator_reads_a_biased_drive_as_the_same_sine(m8528: Fin) -> None:
    """An offset held beyond the amplitude leaves no zero crossing: the estimator times the periods
    from the drive's middle instead, and a linear fin's estimate is the unbiased one's."""
    (plain, _), (biased, samples) = biased_run(m8528, 0.0), biased_run(m8528, 800.0)
    assert len(biased) >= 2 and len(plain) >= 2
    for p, b in zip(plain[-2:], biased[-2:], strict=True):
        assert b.frequency_hz == pytest.approx(6.0, rel=1e-3)
        assert b.voltage_pp == pytest.approx(p.voltage_pp, rel=2e-3)
        assert b.thrust_self_n == pytest.approx(p.thrust_self_n, rel=1e-2)
        # the fin's watt is the sine's (the offset's DC times the current monitor's noise left out);
        # the supply's as its meter reads it, the amplifier drawing on the whole voltage
        assert b.power_w == pytest.approx(p.power_w, rel=5e-2)
        t, _, _, supply = samples
        inside = (t > b.t_start) & (t <= b.t_end)
        assert b.power_supply_w == pytest.approx(float(np.mean(supply[inside])), rel=1e-2)


@pytest.mark.parametrize("offset_slew", [0.0, 55.0, 157.0, 5000.0])
def test_the_estimator_follows_an_offset_through_a_change_of_the_drive(
    m8528: Fin, offset_slew: float
) -> None:
    """A turning fish's drive moves from 6.25 Hz, 444 Vpp to 2.2 Hz, 800 Vpp under a 600 V offset, which
    then moves to the window's edge (1,100 V) at ``offset_slew`` V/s (0: it stays; 55: the yaw loop's
    1 % of the new sine's slope; 157: of the old one's; 5,000: a step).  Every running estimate is of
    the drive as it was, and they come on: the first of the new point within the drive's ramp, the
    offset's move, the estimator's settling and window, and four periods of the new sine (to find the
    middle of a swing that left it, to time from it, to end the settling, and one spare).

    In the live turn (test_cmd_vel) no estimate came for 20 s after such a change and the controller
    ramped the drive down: timing a period across the middle's step gave one of 26 ms, whose swing
    set a wrong middle, and the next, as long as the offset stayed."""
    rig, est = SimulatedRig(m8528, seed=1), StreamEstimator(m8528)
    out: list[Estimate] = []
    bias = 600.0
    for k in range(800):  # 40 s
        t = 0.05 * k
        f, v = (6.25, 444.0) if t < 20.0 else (2.2, 800.0)
        if t >= 20.0:
            bias = min(bias + offset_slew * 0.05, 1100.0)
        rig.command(f, v, 1, bias)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
    before = [e for e in out if e.t_end <= 20.0 + 1e-6]
    after = [e for e in out if e.t_start >= 20.0]
    assert len(before) >= 3 and len(before) + len(after) == len(out)  # (none across the change)
    assert all(e.frequency_hz == pytest.approx(6.25, rel=2e-3) for e in before[1:])
    moved = 500.0 / offset_slew if offset_slew else 0.0
    due = 20.0 + 356.0 / 4000.0 + moved + est.config.settle_s + est.config.window_s + 4.0 / 2.2
    assert after and after[0].t_end <= due, [(e.t_start, e.t_end) for e in after]
    assert len(after) >= int((40.0 - due) / (est.config.window_s + 1.0))
    for e in after:
        assert e.frequency_hz == pytest.approx(2.2, rel=2e-3)
        assert e.voltage_pp == pytest.approx(800.0, rel=2e-2)
