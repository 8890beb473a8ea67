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
