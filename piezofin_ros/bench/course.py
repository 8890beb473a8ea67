"""A fish swimming a course in fish time: the simulated rig, the planar body, the yaw loop and
line-of-sight guidance, at a drive that is held fixed or chosen by the optimiser (the steering's and
the range's benchmark, ``benchmarks/bench_course.py``).

Each 50 ms block: the drive (:mod:`.fishrun`'s :class:`~.fishrun.FixedDrive` or
:class:`~.fishrun.OptimisingDrive`) gives its point, the rig drives the fin in truth there with the
offset the yaw loop asks, and the body moves under the block's thrust and offset
(:class:`~piezofin_ros.rig.fish.FreeSwimmer`).  An optimising drive learns from the estimator's
windows (:class:`~piezofin_ros.estimation.estimator.StreamEstimator` on the rig's drive and supply
blocks, as ``thrust_estimator`` reads them: the offset, the self-sensing through the model it was
told, the measured supply watt).  Every 100 ms, as the live nodes do at 10 Hz, guidance asks a yaw
rate for where the fish is (in truth: the odometry's error is the IMU's and the speed sensor's,
apart) and the yaw loop its offset from the IMU's rate.  What it returns is the course as swum: the
time, the distance, how far off the course (the least distance to any leg), and the energy the
amplifier drew and the fish's fixed draw, per metre and per charge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..control.guidance import GuidanceError, LineOfSight
from ..control.yawloop import OffsetRoom, YawLoop
from ..estimation.estimator import StreamEstimator
from ..estimation.selfsense import Calibration
from ..physics.amplifier import Amplifier
from ..physics.model import Model
from ..physics.planar import slender_planar
from ..physics.swim import Battery, Body
from ..rig.fish import FreeSwimmer
from ..rig.simulated import SimulatedRig
from .fishrun import Drive, OptimisingDrive

BLOCK_S = 0.05


@dataclass(frozen=True)
class CourseRun:
    """A course swum (SI): ``path`` is ``(t, x, y)`` every 0.1 s; ``supply_j`` the amplifier's draw;
    ``battery`` the pack that pays it and the fish's fixed draw besides (its ``hotel_w``; None: no
    fixed draw counted, no range)."""

    done: bool
    time_s: float
    distance_m: float
    off_course_rms_m: float
    off_course_max_m: float
    supply_j: float
    path: np.ndarray
    battery: Battery | None = None

    @property
    def joules_per_m(self) -> float:
        """The amplifier's energy per metre, J/m."""
        return self.supply_j / self.distance_m if self.distance_m > 0 else math.nan

    @property
    def joules_per_m_all(self) -> float:
        """The battery's energy per metre, the fixed draw counted (the cost of transport), J/m."""
        if not self.distance_m > 0:
            return math.nan
        hotel_w = self.battery.hotel_w if self.battery is not None else 0.0
        return (self.supply_j + hotel_w * self.time_s) / self.distance_m

    @property
    def speed_m_s(self) -> float:
        return self.distance_m / self.time_s if self.time_s > 0 else math.nan

    @property
    def range_m(self) -> float:
        """How far one charge carries the fish swimming as it swam this course, m (NaN: no battery)."""
        if self.battery is None or not self.time_s > 0:
            return math.nan
        return float(self.battery.range_m(self.supply_j / self.time_s, self.speed_m_s))


def swim_course(
    truth: Model,
    body: Body,
    amplifier: Amplifier,
    course: LineOfSight,
    drive: Drive,
    *,
    told: Model | None = None,
    told_body: Body | None = None,
    told_amplifier: Amplifier | None = None,
    battery: Battery | None = None,
    seed: int = 0,
    most_s: float = 3600.0,
    room: OffsetRoom | None = None,
) -> CourseRun:
    """``course`` swum from rest by the fish ``truth`` (its fin and effects) on ``body`` through
    ``amplifier``, at the points ``drive`` gives (module docstring); stops when done or after
    ``most_s`` of fish time.  The stack is told ``told``, ``told_body`` and ``told_amplifier`` (the
    yaw loop's fin and body, the estimator's calibration and supply model): by default the truth.
    An optimising drive caps its voltage so that the offset the yaw loop wants fits in the MFC's
    window (``room``; by default :class:`~piezofin_ros.control.yawloop.OffsetRoom`'s, under the
    optimiser's box; a fixed drive never)."""
    told, told_body = told or truth, told_body or body
    rig = SimulatedRig(
        truth.fin, amplifier=amplifier, seed=seed, model=truth.knobs_at if truth.effects else None
    )
    fish = FreeSwimmer(body, truth.fin.L, planar=slender_planar(body, truth.fin), fin=truth.fin, seed=seed)
    loop = YawLoop(slender_planar(told_body, told.fin), told.fin)
    estimator = None
    if isinstance(drive, OptimisingDrive):
        room = room or OffsetRoom(most_vpp=drive.optimiser.limits.voltage_pp_max)

        def calibrate(frequency_hz: float, voltage_pp: float) -> Calibration:
            return Calibration.of_law(told.law(frequency_hz, voltage_pp))

        estimator = StreamEstimator(
            told.fin, calibrate=calibrate if told.effects else None, amplifier=told_amplifier or amplifier
        )
    bias, supply_j, off, path = 0.0, 0.0, [], []
    n = round(BLOCK_S * rig.config.sample_rate_hz)
    t = 0.0
    for k in range(round(most_s / BLOCK_S)):
        t = k * BLOCK_S
        f, v = drive.tick(t)
        rig.command(f, v, 1.0 if v > 0 else 0.0, bias)
        rig.swim_speed_m_s = fish.speed_m_s
        b = rig.step(n)
        thrust = float(np.mean(b.thrust_true))
        supply_j += float(np.mean(b.supply_voltage * b.supply_current)) * BLOCK_S
        fish.advance(BLOCK_S, thrust, f, 0.0, rig.drive.bias)
        loop.measure(t, fish.imu_reading()[0])
        if estimator is not None:
            estimator.add_speed(t, fish.speed_reading())
            for e in estimator.add_drive(b.t, b.voltage, b.current) + estimator.add_supply(
                b.t, b.supply_voltage, b.supply_current
            ):
                drive.add_estimate(t, e)
        if k % 2:
            continue
        rate, _ = course.update(fish.x_m, fish.y_m, fish.heading_rad, fish.speed_m_s)
        loop.set_setpoint(rate if rate else 1e-12)  # (0 would reset the integral between corrections)
        bias = loop.update(t, thrust, fish.speed_m_s, v, f)
        if isinstance(drive, OptimisingDrive) and room is not None and room.update(loop.wanted_v, t):
            drive.loop.set_voltage_cap(room.cap)
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
        battery,
    )


def square(side_m: float, to: str = "port") -> list[tuple[float, float]]:
    """A square from the origin along x, each corner turned ``to`` port (anticlockwise: the way a P1
    fin turns fast) or to starboard."""
    if to not in ("port", "starboard"):
        raise GuidanceError(f"a square turns to port or starboard, not {to!r}")
    y = side_m if to == "port" else -side_m
    return [(0.0, 0.0), (side_m, 0.0), (side_m, y), (0.0, y), (0.0, 0.0)]
