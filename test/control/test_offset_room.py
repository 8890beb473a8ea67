"""The room the offset needs (issue 42): a fish turning to starboard on a P1 fin asks an offset the
MFC's window (-500 V to +1,500 V) leaves only to a smaller sine, so the drive's voltage is capped,
the optimiser choosing within the cap (no ROS)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.bench import evaluation
from piezofin_ros.bench.plants import Plant
from piezofin_ros.control.driveloop import DriveLoop
from piezofin_ros.control.optimise import Optimiser, Tuning
from piezofin_ros.control.yawloop import OffsetRoom
from piezofin_ros.physics.fin import Fin, load_fin
from piezofin_ros.physics.planar import MFC_P1_WINDOW_V

from .test_optimise import LIMITS

LOW, HIGH = MFC_P1_WINDOW_V


def room_of(b: float) -> float:
    """The most peak-to-peak sine around an offset ``b`` inside the window, on its short side (to
    starboard: below the middle); inf on the other."""
    return max(2.0 * (b - LOW), 0.0) if b < 0.5 * (LOW + HIGH) else math.inf


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(min_value=-2000.0, max_value=3000.0), min_size=1, max_size=60))
def test_the_cap_leaves_the_wanted_offset_in_the_window(wanted: list[float]) -> None:
    """Whatever the offsets wanted, in any order: the cap leaves the last one its room on the window's
    short side (``b`` less half the cap above -500 V), unless that room is below the least voltage
    (then the least); it wastes at most two steps of it; above the box's top, and on the long side
    (to port, where a smaller sine loses more turn than it gains), there is no cap."""
    room = OffsetRoom(least_vpp=300.0, step_v=50.0, most_vpp=800.0)
    for b in wanted:
        room.update(b)
        r = room_of(b)
        if room.cap == math.inf:  # (the box's top, 800 Vpp)
            assert r >= 800.0, (b, r)
        elif r < 300.0:
            assert room.cap == 300.0
        else:
            assert r - 100.0 <= room.cap <= r, (b, r, room.cap)


def test_an_offset_wandering_at_a_step_moves_the_cap_once() -> None:
    """A yaw loop's offset wanders with the IMU's noise: at a step's edge (-225 V leaves 550 Vpp) a
    wandering of 10 V moves the cap once, down, not at each tick."""
    room = OffsetRoom(least_vpp=300.0, step_v=50.0, most_vpp=800.0)
    assert room.update(-225.0) and room.cap == 550.0
    rng = np.random.default_rng(0)
    moves = sum(room.update(-225.0 + 10.0 * rng.uniform(-1.0, 1.0)) for _ in range(500))
    assert moves == 1 and room.cap == 500.0  # (down at the first offset below; never up again)
    room.update(0.0)  # the turn is over: no cap
    assert room.cap == math.inf
    assert not room.update(1400.0)  # (to port, even beyond the window: no cap)
    assert not room.update(math.nan)  # (no offset known: as none)


def test_a_cap_begins_only_once_the_offset_has_wanted_room_for_a_while() -> None:
    """A starboard correction after a turn to port wants room for a few seconds; a turn to starboard
    for minutes (a quarter circle of 6.4 m at 5.7 cm/s: 176 s).  Capped at each correction, stranger
    2 swam its port square at +15 % energy per metre (the optimiser choosing anew within each cap);
    so a cap begins only once the room has been short for ``engage_s`` (10 s), then follows at once."""
    room = OffsetRoom(step_v=100.0, most_vpp=800.0, engage_s=10.0)
    for k in range(50):  # 5 s short of room, then straight again
        assert not room.update(-300.0, 0.1 * k)
    assert not room.update(0.0, 5.0) and room.cap == math.inf
    moved = [room.update(-300.0, 10.0 + 0.1 * k) for k in range(120)]  # 12 s
    assert moved.index(True) == 100 and room.cap == 400.0  # (at 10 s: 2 (-300 + 500))
    assert room.update(-150.0, 22.1) and room.cap == 600.0  # (once begun, it follows)
    assert room.update(0.0, 22.2) and room.cap == math.inf


@pytest.fixture(scope="module")
def trained() -> Optimiser:
    """An optimiser on the M8528-P1 fin, a demand of 10 mN, after three trials on a plant like it."""
    m8528 = load_fin("M8528-P1")
    opt = Optimiser(m8528, LIMITS, demand_n=10e-3, tuning=Tuning(n_grid=40))
    evaluation.campaign(opt, Plant(m8528, resonance_scale=0.97), 3, np.random.default_rng(1), 0.0)
    return opt


def test_the_optimiser_chooses_within_the_cap_and_the_box_comes_back(trained: Optimiser) -> None:
    opt = trained
    before = (opt.choice.frequency_hz, opt.choice.voltage_pp) if opt.choice else None
    assert before is not None and before[1] > 200.0  # (10 mN needs more than 200 Vpp on this fin)
    opt.set_voltage_cap(200.0)
    assert opt.limits.voltage_pp_max == 200.0
    assert opt.choice is not None and opt.choice.voltage_pp <= 200.0
    assert not opt.choice.feasible  # (the most thrust 400 Vpp gives, flagged: the demand is not met)
    assert opt.propose()[1] <= 200.0
    assert all(c.observation.voltage_pp <= 200.0 for c in opt.counted)
    opt.set_voltage_cap(None)
    assert opt.limits == LIMITS
    assert (opt.choice.frequency_hz, opt.choice.voltage_pp) == pytest.approx(before)
    opt.set_voltage_cap(1.0)  # (never below twice the box's least voltage)
    assert opt.limits.voltage_pp_max == 2.0 * LIMITS.voltage_pp_min
    opt.set_voltage_cap(math.nan)
    assert opt.limits == LIMITS


def test_the_drive_loop_keeps_the_command_under_the_cap_from_the_next_tick(m8528: Fin) -> None:
    opt = Optimiser(m8528, LIMITS, identify=False, tuning=Tuning(n_grid=40))
    loop = DriveLoop(opt, slew_vpp_per_s=4000.0)
    loop.set_demand(3e-3)
    t = 0.0
    for _ in range(20):
        t += 0.1
        loop.tick(t)
    assert loop.command_v > 500.0
    loop.set_voltage_cap(350.0)
    _, v, _ = loop.tick(t := t + 0.1)
    assert v <= 350.0  # at once, whatever the fit's thread
    for _ in range(3):
        _, v, _ = loop.tick(t := t + 0.1)
    assert loop.target is not None and loop.target[1] <= 350.0 and v <= 350.0  # the optimiser's point
    loop.set_voltage_cap(None)
    for _ in range(10):
        _, v, _ = loop.tick(t := t + 0.1)
    assert loop.target[1] > 500.0 and v > 500.0
