"""The rig set free (issue 27): the simulated rig's blocks move a body and drain a battery; the
speed it reaches is the body's closed-form steady speed, the charge it uses is the supply's."""

from __future__ import annotations

import math

import pytest

from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.steady import harmonic_balance
from piezofin_ros.physics.swim import load_battery, load_body
from piezofin_ros.rig.fish import FreeSwimmer
from piezofin_ros.rig.simulated import SimulatedRig


def test_the_rig_swims_to_the_bodys_steady_speed_and_drains_what_the_supply_draws() -> None:
    fin = load_fin("M8528-P1")
    body, battery = load_body("mfc-fish"), load_battery("li-ion-2s-500mah")
    amp = load_amplifier("fish-switching")
    rig = SimulatedRig(fin, amplifier=amp)
    fish = FreeSwimmer(body, fin.L, battery)
    f, vpp, n = 6.0, 600.0, 50
    energy = 0.0
    for _ in range(int(40.0 / 0.05)):  # 40 s: the drive's ramp, then about 8 time constants
        rig.command(f, vpp, 1)
        rig.swim_speed_m_s = fish.speed_m_s
        b = rig.step(n)
        supply = float((b.supply_voltage * b.supply_current).mean())
        fish.advance(n / 1000.0, float(b.thrust_true.mean()), f, supply)
        energy += (supply + battery.hotel_w) * n / 1000.0
    t0 = float(harmonic_balance(fin, f, vpp).thrust_n)
    assert fish.speed_m_s == pytest.approx(float(body.steady_speed(t0, f, fin.L)), rel=0.02)
    # the charge used is the energy drawn over the pack's voltage (within the curve's slope there)
    used_ah = (1.0 - fish.soc) * battery.capacity_ah
    assert used_ah * 3600 * float(battery.emf_v(fish.soc)) == pytest.approx(energy, rel=0.03)
    r = fish.reading()
    assert not r.empty and 0.99 < r.percentage < 1.0 and r.voltage_v < float(battery.emf_v(fish.soc))


def test_an_empty_battery_is_said_and_a_fish_without_one_never_empties() -> None:
    body = load_body("mfc-fish")
    small = load_battery("li-ion-2s-500mah")
    fish = FreeSwimmer(body, 0.09, small)
    for _ in range(2000):
        fish.advance(10.0, 0.0, 5.0, 20.0)  # 20 W: the pack empties within minutes
    assert fish.empty and fish.reading().empty
    free = FreeSwimmer(body, 0.09, None)
    free.advance(1.0, 0.001, 5.0, 1.0)
    assert not free.empty and math.isnan(free.reading().voltage_v)


def test_an_offset_turns_the_fish_at_the_planar_bodys_steady_yaw_rate() -> None:
    """Issue 42: the rig's drive with an offset yaws a body that turns; after 40 s its yaw rate is
    the planar body's closed form at the speed it swims (the fin's tilted thrust and lift at its lever
    arm against the body's cross-flow drag and the fin's lift), and its IMU reads that rate with its
    bias and integrates a heading that drifts by the bias alone."""
    from piezofin_ros.physics.planar import bias_side_force_n, fin_yaw_damping, slender_planar

    fin = load_fin("M8528-P1")
    body = load_body("mfc-fish")
    planar = slender_planar(body, fin)
    rig = SimulatedRig(fin, amplifier=load_amplifier("fish-switching"))
    fish = FreeSwimmer(body, fin.L, planar=planar, fin=fin, gyro_noise_rad_s=0.0)
    f, vpp, bias, n = 5.5, 800.0, 1100.0, 50
    rates = []
    for _ in range(int(40.0 / 0.05)):
        rig.command(f, vpp, 1, bias)
        rig.swim_speed_m_s = fish.speed_m_s
        b = rig.step(n)
        fish.advance(n / 1000.0, float(b.thrust_true.mean()), f, 0.0, rig.drive.bias)
        rates.append(fish.imu_reading()[0])
    thrust = float(harmonic_balance(fin, f, vpp).thrust_n)
    u = fish.speed_m_s
    moment = bias_side_force_n(fin, thrust, bias, u) * planar.fin_lever_m
    expected = planar.steady_yaw_rate(moment, fin_yaw_damping(planar, fin, u))
    assert math.degrees(expected) > 1.0  # (the nominal fin: 1.7 deg/s; the twin, docs/fish-record.md: 2.4)
    assert fish.yaw_rate_rad_s == pytest.approx(expected, rel=0.03)
    assert rates[-1] == pytest.approx(fish.yaw_rate_rad_s + fish.gyro_bias_rad_s, rel=1e-9)
    _, heading, var = fish.imu_reading()
    assert heading - fish.heading_rad == pytest.approx(fish.gyro_bias_rad_s * 40.0, rel=1e-6)
    assert var == pytest.approx((fish.gyro_bias_rad_s * 40.0) ** 2)
    # it swims a circle: the radius is the speed over the yaw rate
    assert math.hypot(fish.x_m, fish.y_m) > 1.0 and fish.heading_rad > 0.9 and fish.y_m > 0.5


def test_a_fish_that_turns_swims_straight_as_before_without_an_offset() -> None:
    fin = load_fin("M8528-P1")
    body = load_body("mfc-fish")
    from piezofin_ros.physics.planar import slender_planar

    straight = FreeSwimmer(body, fin.L)
    turning = FreeSwimmer(body, fin.L, planar=slender_planar(body, fin), fin=fin)
    for _ in range(200):
        for fish in (straight, turning):
            fish.advance(0.05, 0.004, 5.5, 0.05)
    assert turning.speed_m_s == straight.speed_m_s and turning.heading_rad == 0.0
    assert turning.x_m == pytest.approx(straight.distance_m) and turning.y_m == 0.0
