"""A fish swimming a course in fish time: the simulated rig, the planar body, the yaw loop and
line-of-sight guidance, at a drive held fixed (the steering's benchmark, ``benchmarks/bench_course.py``).

Each 50 ms block: the rig drives the fin at the drive's point and the offset the yaw loop asks; the
body moves under the block's thrust and offset (:class:`~piezofin_ros.rig.fish.FreeSwimmer`); every
100 ms, as the live nodes do at 10 Hz, guidance asks a yaw rate for where the fish is (in truth: the
odometry's error is the IMU's and the speed sensor's, apart) and the yaw loop its offset from the IMU's
rate.  What it returns is the course as swum: the time, the distance, how far off the course (the
least distance to any leg), and the supply energy the amplifier drew, per metre.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.guidance import LineOfSight
from ..control.yawloop import YawLoop
from ..physics.amplifier import Amplifier
from ..physics.fin import Fin
from ..physics.planar import slender_planar
from ..physics.swim import Body
from ..rig.fish import FreeSwimmer
from ..rig.simulated import SimulatedRig

BLOCK_S = 0.05


@dataclass(frozen=True)
class CourseRun:
    """A course swum (SI): ``path`` is ``(t, x, y)`` every 0.1 s."""

    done: bool
    time_s: float
    distance_m: float
    off_course_rms_m: float
    off_course_max_m: float
    supply_j: float
    path: np.ndarray

    @property
    def joules_per_m(self) -> float:
        return self.supply_j / self.distance_m if self.distance_m > 0 else math.nan

    @property
    def speed_m_s(self) -> float:
        return self.distance_m / self.time_s if self.time_s > 0 else math.nan


def swim_course(
    fin: Fin,
    body: Body,
    amplifier: Amplifier,
    course: LineOfSight,
    frequency_hz: float,
    voltage_pp: float,
    *,
    seed: int = 0,
    most_s: float = 3600.0,
) -> CourseRun:
    """``course`` swum at the drive ``frequency_hz``, ``voltage_pp`` from rest (module docstring);
    stops when done or after ``most_s`` of fish time."""
    rig = SimulatedRig(fin, amplifier=amplifier, seed=seed)
    planar = slender_planar(body, fin)
    fish = FreeSwimmer(body, fin.L, planar=planar, fin=fin, seed=seed)
    loop = YawLoop(planar, fin)
    bias, supply_j, off, path = 0.0, 0.0, [], []
    n = round(BLOCK_S * rig.config.sample_rate_hz)
    t = 0.0
    for k in range(round(most_s / BLOCK_S)):
        t = k * BLOCK_S
        rig.command(frequency_hz, voltage_pp, 1, bias)
        rig.swim_speed_m_s = fish.speed_m_s
        b = rig.step(n)
        thrust = float(np.mean(b.thrust_true))
        supply_j += float(np.mean(b.supply_voltage * b.supply_current)) * BLOCK_S
        fish.advance(BLOCK_S, thrust, frequency_hz, 0.0, rig.drive.bias)
        loop.measure(t, fish.imu_reading()[0])
        if k % 2:
            continue
        rate, _ = course.update(fish.x_m, fish.y_m, fish.heading_rad, fish.speed_m_s)
        loop.set_setpoint(rate if rate else 1e-12)  # (0 would reset the integral between corrections)
        bias = loop.update(t, thrust, fish.speed_m_s, voltage_pp, frequency_hz)
        off.append(course.off_course_m(fish.x_m, fish.y_m))
        path.append((t, fish.x_m, fish.y_m))
        if course.done:
            break
    errors = np.asarray(off)
    return CourseRun(
        course.done,
        t,
        fish.distance_m,
        float(np.sqrt(np.mean(errors**2))),
        float(errors.max()),
        supply_j,
        np.asarray(path),
    )


def square(side_m: float) -> list[tuple[float, float]]:
    """A square swum to port (anticlockwise) from the origin: the way a P1 fin turns fast."""
    return [(0.0, 0.0), (side_m, 0.0), (side_m, side_m), (0.0, side_m), (0.0, 0.0)]
