"""A fish's odometry, dead-reckoned from its speed sensor and its IMU's heading: where it swam, and
how well that is known.

Each stretch swum (the speed it measures, ``U_k dt_k``) is laid along the heading its IMU gives then
(none heard: along x, the heading unknown).  Two errors of the speed sensor grow into the distance
along the track differently:

* its noise ``sigma`` (white, per reading): ``var = sigma^2 sum dt_k^2``, which grows as ``sigma^2 dt T``;
* its bias, bounded by ``b``: ``(b T)^2``, which grows with the time ``T`` swum and soon dominates.

and the heading's own error (its variance ``s_psi^2``, as the IMU reports it: a gyro's bias drifts it)
puts the position off across the track by ``d s_psi`` after a distance ``d``.
:class:`DeadReckoning` keeps them; the speed loop node publishes them as ``nav_msgs/Odometry`` with the
covariance filled, rotated onto the heading (without an IMU: across and the heading unknown).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ControlError

#: The variance of an axis nothing observes (sideways, the heading), as robot_localization reads it.
UNKNOWN = 1e6


@dataclass
class DeadReckoning:
    """Position along the heading from speed readings (SI; module docstring)."""

    speed_sigma_m_s: float = 0.002  # the sensor's noise per reading, m/s
    speed_bias_m_s: float = 0.001  # the most its bias may be, m/s
    max_gap_s: float = 1.0  # a longer gap between readings counts this much (a sensor that fell silent)
    x_m: float = 0.0
    y_m: float = 0.0
    heading_rad: float = 0.0
    heading_var: float = math.nan  # rad^2, as the IMU reports it; NaN: no IMU heard (unknown)
    distance_m: float = 0.0
    speed_m_s: float = 0.0
    yaw_rate_rad_s: float = 0.0  # as the IMU reports it (to port); 0 with its variance NaN: none heard
    yaw_rate_var: float = math.nan  # (rad/s)^2, as the IMU reports it; NaN: not observed
    swum_s: float = 0.0
    _noise_var: float = 0.0
    _t: float = math.nan

    def __post_init__(self) -> None:
        for name in ("speed_sigma_m_s", "speed_bias_m_s", "max_gap_s"):
            x = getattr(self, name)
            if not (math.isfinite(x) and x >= 0):
                raise ControlError(f"odometry: {name} = {x!r} must be finite and >= 0")

    def add(self, t: float, speed_m_s: float) -> None:
        """A speed reading at ``t`` (s): the distance since the last one at the mean of their speeds."""
        if not (math.isfinite(t) and math.isfinite(speed_m_s)):
            return
        if math.isfinite(self._t) and t > self._t:
            dt = min(t - self._t, self.max_gap_s)
            ds = 0.5 * (self.speed_m_s + speed_m_s) * dt
            self.x_m += ds * math.cos(self.heading_rad)
            self.y_m += ds * math.sin(self.heading_rad)
            self.distance_m += ds
            self.swum_s += dt
            self._noise_var += (self.speed_sigma_m_s * dt) ** 2
        if not math.isfinite(self._t) or t >= self._t:
            self._t, self.speed_m_s = t, float(speed_m_s)

    def turn(self, heading_rad: float, heading_var: float) -> None:
        """The IMU's heading (rad) and its variance (rad^2): the next stretches are laid along it."""
        if math.isfinite(heading_rad) and math.isfinite(heading_var) and heading_var >= 0:
            self.heading_rad, self.heading_var = float(heading_rad), float(heading_var)

    def spin(self, rate_rad_s: float, rate_var: float) -> None:
        """The IMU's yaw rate (rad/s, to port) and its variance ((rad/s)^2): the twist's turn."""
        if math.isfinite(rate_rad_s) and math.isfinite(rate_var) and rate_var >= 0:
            self.yaw_rate_rad_s, self.yaw_rate_var = float(rate_rad_s), float(rate_var)

    @property
    def x_var_m2(self) -> float:
        """The variance along the track, m^2: the speed sensor's noise and bias (module docstring)."""
        return self._noise_var + (self.speed_bias_m_s * self.swum_s) ** 2

    def position_covariance(self) -> tuple[float, float, float]:
        """``(xx, xy, yy)`` of the position, m^2: along the track as :attr:`x_var_m2`, across it the
        heading's error over the distance swum, rotated onto the heading (``yy`` unknown without an
        IMU)."""
        along = self.x_var_m2
        if math.isnan(self.heading_var):
            return along, 0.0, UNKNOWN
        across = self.distance_m**2 * self.heading_var
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        return (
            c * c * along + s * s * across,
            c * s * (along - across),
            s * s * along + c * c * across,
        )

    @property
    def speed_var_m2_s2(self) -> float:
        return self.speed_sigma_m_s**2
