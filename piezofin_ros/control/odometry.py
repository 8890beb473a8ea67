"""A fish's odometry, dead-reckoned from its speed sensor: how far it swam, and how well that is known.

The fish swims straight (it does not turn yet): its position along its heading is the integral of the
speed it measures, ``x = sum U_k dt_k``.  Two errors of the sensor grow into it differently:

* its noise ``sigma`` (white, per reading): ``var = sigma^2 sum dt_k^2``, which grows as ``sigma^2 dt T``;
* its bias, bounded by ``b``: ``(b T)^2``, which grows with the time ``T`` swum and soon dominates.

:class:`DeadReckoning` keeps both; the speed loop node publishes them as ``nav_msgs/Odometry`` with the
covariance filled (the axes it does not observe, across and the heading, marked unknown).
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
    speed_m_s: float = 0.0
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
            self.x_m += 0.5 * (self.speed_m_s + speed_m_s) * dt
            self.swum_s += dt
            self._noise_var += (self.speed_sigma_m_s * dt) ** 2
        if not math.isfinite(self._t) or t >= self._t:
            self._t, self.speed_m_s = t, float(speed_m_s)

    @property
    def x_var_m2(self) -> float:
        """The position's variance, m^2: the noise's and the bias's (module docstring)."""
        return self._noise_var + (self.speed_bias_m_s * self.swum_s) ** 2

    @property
    def speed_var_m2_s2(self) -> float:
        return self.speed_sigma_m_s**2
