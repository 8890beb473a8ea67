"""The rig set free: a fish's body that the fin's thrust moves, and the battery its amplifier drains.

:class:`FreeSwimmer` follows the simulated rig block by block (:class:`~.simulated.SimulatedRig`):
each block's mean Lighthill thrust (Eq. 19, with the speed the body has, which the rig applies on
the next block) drives the body's surge equation (:class:`~piezofin_ros.physics.swim.Body`), and
the block's supply power (the amplifier's draw, what the rig's supply meter reads) plus the fish's
hotel load drains the battery (:class:`~piezofin_ros.physics.swim.Battery`).  What a fish senses of
it: a speed sensor with white noise (a flow sensor, a DVL) and the battery's voltage, current and
charge (``sensor_msgs/BatteryState`` in the node).  A block is short against the body's time
constant (50 ms against 3-9 s), so one explicit step per block integrates it.

A fish with one fin and a :class:`~piezofin_ros.physics.planar.PlanarBody` also turns: the drive's
offset (its DC bias) tilts the fin, whose side force at its lever arm yaws the body (surge, sway and
yaw, :meth:`~piezofin_ros.physics.planar.PlanarBody.derivatives`, in 10 steps a block: the yaw's time
constant is about 1.3 s on ``mfc-fish``).  It senses its turn with a gyro (an IMU's yaw rate: white
noise and a constant bias) whose rate it integrates into a heading that drifts, as an IMU without a
compass does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..physics.fin import Fin
from ..physics.planar import PlanarBody, bias_side_force_n, bias_tilt_rad, fin_yaw_damping
from ..physics.swim import Battery, Body, SwimError

#: Explicit steps per block of the planar body (module docstring).
PLANAR_STEPS = 10


@dataclass(frozen=True)
class BatteryReading:
    """What a battery monitor reports (SI; ``percentage`` 0-1)."""

    voltage_v: float
    current_a: float  # drawn (positive)
    charge_ah: float
    capacity_ah: float
    percentage: float
    empty: bool


@dataclass
class FreeSwimmer:
    """The body's speed and the battery's charge, advanced by each block of the rig."""

    body: Body
    fin_length_m: float
    battery: Battery | None = None
    speed_noise_m_s: float = 0.002
    seed: int = 0
    speed_m_s: float = 0.0
    soc: float = 1.0
    distance_m: float = 0.0
    energy_j: float = 0.0
    planar: PlanarBody | None = None  # a body that turns (one fin); None: surge only
    fin: Fin | None = None  # the fin whose offset turns it (with ``planar``)
    gyro_noise_rad_s: float = 0.002  # the IMU's yaw rate: white noise per reading, rad/s
    gyro_bias_rad_s: float = 0.0005  # and its constant bias, rad/s (0.03 deg/s)
    heading_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    sway_m_s: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    swum_s: float = 0.0
    _heading_read: float = 0.0  # the IMU's heading: its own rate integrated
    _rng: np.random.Generator = field(init=False, repr=False)
    _gyro_rng: np.random.Generator = field(init=False, repr=False)  # (its own: the speed's stays as it was)
    _last_power_w: float = 0.0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._gyro_rng = np.random.default_rng([self.seed, 1])
        if self.planar is not None and (self.fin is None or self.body.fins != 1):
            raise SwimError(
                f"{self.body.name}: a body that turns needs its one fin (it has {self.body.fins})"
            )

    @property
    def empty(self) -> bool:
        """The battery has reached its cut-off (a fish without one never empties)."""
        return self.battery is not None and self.reading().empty

    def advance(
        self, dt_s: float, thrust_n: float, frequency_hz: float, supply_w: float, bias_v: float = 0.0
    ) -> None:
        """One block of ``dt_s``: its mean thrust per fin (at the present speed), supply power and the
        drive's offset (a body that turns: its side force yaws it)."""
        b = self.body
        heading = self.heading_rad
        turning = self.planar is not None and (bias_v != 0.0 or self.yaw_rate_rad_s or self.sway_m_s)
        if turning:
            self._turn(dt_s, thrust_n, bias_v)
        else:  # (straight: the surge equation alone, one step)
            accel = b.surge_acceleration(b.fins * thrust_n, self.speed_m_s)
            self.speed_m_s = max(self.speed_m_s + accel * dt_s, -1.0)
            self.x_m += self.speed_m_s * math.cos(self.heading_rad) * dt_s
            self.y_m += self.speed_m_s * math.sin(self.heading_rad) * dt_s
        self.distance_m += self.speed_m_s * dt_s
        self.swum_s += dt_s
        self._heading_read += self.heading_rad - heading + self.gyro_bias_rad_s * dt_s
        if self.battery is not None and not self.empty:
            power = max(b.fins * supply_w, 0.0) + self.battery.hotel_w
            current = float(self.battery.current_a(self.soc, power))
            if not math.isfinite(current):  # beyond what the pack can deliver: it collapses
                self.soc = 0.0
            else:
                self.soc = max(self.soc - current * dt_s / (3600.0 * self.battery.capacity_ah), 0.0)
            self.energy_j += power * dt_s
            self._last_power_w = power

    def _turn(self, dt_s: float, thrust_n: float, bias_v: float) -> None:
        """The planar body through one block: the fin's thrust tilted by the offset, its side force
        and moment at the lever arm, the fin's lift damping the yaw at the present speed."""
        assert self.planar is not None and self.fin is not None
        body, fin = self.planar, self.fin
        u = self.speed_m_s
        side = bias_side_force_n(fin, thrust_n, bias_v, u)
        force = (thrust_n * math.cos(bias_tilt_rad(fin, bias_v)), side)
        moment = side * body.fin_lever_m
        k = fin_yaw_damping(body, fin, u)
        state = np.array([self.x_m, self.y_m, self.heading_rad, u, self.sway_m_s, self.yaw_rate_rad_s])
        h = dt_s / PLANAR_STEPS
        for _ in range(PLANAR_STEPS):
            state = state + h * np.asarray(body.derivatives(tuple(state), force, moment, k))
        self.x_m, self.y_m, self.heading_rad = float(state[0]), float(state[1]), float(state[2])
        self.speed_m_s = max(float(state[3]), -1.0)
        self.sway_m_s, self.yaw_rate_rad_s = float(state[4]), float(state[5])

    def imu_reading(self) -> tuple[float, float, float]:
        """The IMU's yaw rate (rad/s: the truth, its bias and noise), its heading (rad: its own rate
        integrated, drifting with the bias) and that heading's variance (rad^2: the bias's drift)."""
        rate = (
            self.yaw_rate_rad_s
            + self.gyro_bias_rad_s
            + self.gyro_noise_rad_s * float(self._rng.standard_normal())
        )
        return rate, self._heading_read, (self.gyro_bias_rad_s * self.swum_s) ** 2

    def speed_reading(self) -> float:
        """The speed sensor's reading (m/s)."""
        return self.speed_m_s + self.speed_noise_m_s * float(self._rng.standard_normal())

    def reading(self) -> BatteryReading:
        """The battery monitor's reading (NaN fields without a battery)."""
        bat = self.battery
        if bat is None:
            return BatteryReading(math.nan, math.nan, math.nan, math.nan, math.nan, False)
        current = float(bat.current_a(self.soc, self._last_power_w))
        voltage = float(bat.terminal_v(self.soc, self._last_power_w)) if math.isfinite(current) else 0.0
        empty = self.soc <= 0.0 or voltage < bat.cells * bat.cutoff_v_per_cell
        return BatteryReading(
            voltage, current, self.soc * bat.capacity_ah, bat.capacity_ah, self.soc, bool(empty)
        )
