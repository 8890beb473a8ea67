"""The rig set free: a fish's body that the fin's thrust moves, and the battery its amplifier drains.

:class:`FreeSwimmer` follows the simulated rig block by block (:class:`~.simulated.SimulatedRig`):
each block's mean Lighthill thrust (Eq. 19, with the speed the body has, which the rig applies on
the next block) drives the body's surge equation (:class:`~piezofin_ros.physics.swim.Body`), and
the block's supply power (the amplifier's draw, what the rig's supply meter reads) plus the fish's
hotel load drains the battery (:class:`~piezofin_ros.physics.swim.Battery`).  What a fish senses of
it: a speed sensor with white noise (a flow sensor, a DVL) and the battery's voltage, current and
charge (``sensor_msgs/BatteryState`` in the node).  A block is short against the body's time
constant (50 ms against 3-9 s), so one explicit step per block integrates it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..physics.swim import Battery, Body


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
    _rng: np.random.Generator = field(init=False, repr=False)
    _last_power_w: float = 0.0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    @property
    def empty(self) -> bool:
        """The battery has reached its cut-off (a fish without one never empties)."""
        return self.battery is not None and self.reading().empty

    def advance(self, dt_s: float, thrust_n: float, frequency_hz: float, supply_w: float) -> None:
        """One block of ``dt_s``: its mean thrust per fin (at the present speed) and supply power."""
        b = self.body
        accel = b.surge_acceleration(b.fins * thrust_n, self.speed_m_s)
        self.speed_m_s = max(self.speed_m_s + accel * dt_s, -1.0)
        self.distance_m += self.speed_m_s * dt_s
        if self.battery is not None and not self.empty:
            power = max(b.fins * supply_w, 0.0) + self.battery.hotel_w
            current = float(self.battery.current_a(self.soc, power))
            if not math.isfinite(current):  # beyond what the pack can deliver: it collapses
                self.soc = 0.0
            else:
                self.soc = max(self.soc - current * dt_s / (3600.0 * self.battery.capacity_ah), 0.0)
            self.energy_j += power * dt_s
            self._last_power_w = power

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
