"""A fish's yaw-rate loop: the turn a fish stack asks (``cmd_vel``'s ``angular.z``) to the drive's offset.

The offset (a DC bias on the caudal fin's drive) tilts the fin and turns the fish
(:mod:`piezofin_ros.physics.planar`).  The loop asks the offset the steady turn needs at the fin's
present thrust and the fish's speed (:func:`~piezofin_ros.physics.planar.bias_for_yaw_rate`: the
feed-forward, the body's yaw balance inverted), and corrects it by proportional-integral feedback on
the IMU's yaw rate, tuned from the same law: the plant's gain ``dr/db`` at the set-point and the yaw's
time constant ``tau`` give ``kp = tau / (g T)`` and ``ki = 1 / (g T)`` for a closed loop of time
constant ``T`` (``time_constant_s``).  The offset stays within what the drive's window leaves the
sine (:func:`~piezofin_ros.physics.planar.bias_window_v`); at either edge the integral stops
winding, and the turn asked beyond what the edges give is said once per edge.  It moves at most at
``slew_v_per_s``, and so that the sine's periods shift by at most ``period_shift`` (1 %): an offset
moving at ``c`` V/s shifts each crossing of the sine (amplitude ``a``, ``w``) and so its period by
``c / (a w)`` relative, which near the estimator's 3 % splits its windows (200 V/s under 400 Vpp at
5 Hz: 3.2 %; at 150 V/s 2.4 %, and in the live stack no estimate came for 20 s at a time, the
controller ramped the drive down and the fish swam its course 1.4 m off).  A fish slower than
``min_speed_m_s`` is not steered.

The P1 MFC's window is not symmetric (-500 V to +1,500 V): a fish turns one way far faster than the
other (docs/fish.md, Turning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ..config import setting
from ..errors import ControlError
from ..physics.fin import Fin
from ..physics.planar import PlanarBody, bias_for_yaw_rate, bias_window_v, fin_yaw_damping


@dataclass(frozen=True)
class YawLoopConfig:
    """The yaw loop's settings (SI)."""

    time_constant_s: float = setting(3.0, "yaw loop: the closed loop's time constant, s", 0.1, 600.0)
    rate_filter_s: float = setting(
        1.0,
        "yaw loop: the IMU's rate low-passed over this long, s (a gyro's noise moved the offset)",
        0.01,
        60.0,
    )
    min_speed_m_s: float = setting(
        0.01,
        "yaw loop: slower than this the fish is not steered (a rudder at rest turns nothing), m/s",
        0.0,
        10.0,
    )
    slew_v_per_s: float = setting(
        500.0, "yaw loop: the offset moves at most this fast, V/s (and see period_shift)", 1.0, 1e5
    )
    period_shift: float = setting(
        0.01,
        "yaw loop: and at most so fast that the sine's periods shift by this much, relative (c / (a w))",
        1e-4,
        0.5,
    )
    max_gap_s: float = setting(
        1.0,
        "yaw loop: no IMU reading for this long: the offset falls back to the feed-forward, s",
        0.05,
        60.0,
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            x = getattr(self, f.name)
            zero_ok = f.name == "min_speed_m_s"
            number = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            if not (number and (x >= 0 if zero_ok else x > 0)):
                raise ControlError(
                    f"yaw loop: {f.name} = {x!r} must be a finite number {'>=' if zero_ok else '>'} 0"
                )


@dataclass
class YawLoop:
    """The offset for a yaw-rate set-point (module docstring).  Feed it the IMU's rates
    (:meth:`measure`) and ask :meth:`update` for the offset at each tick."""

    body: PlanarBody
    fin: Fin
    config: YawLoopConfig = field(default_factory=YawLoopConfig)
    setpoint_rad_s: float = 0.0
    rate_rad_s: float = math.nan  # the IMU's latest
    integral_v: float = 0.0
    bias_v: float = 0.0
    edge: str = ""  # "port" or "starboard": the set-point is beyond what that edge of the window gives
    _t_rate: float = -math.inf
    _t: float = math.nan
    _slew: float = math.inf  # V/s, this tick's

    def set_setpoint(self, rate_rad_s: float) -> None:
        """A new yaw-rate set-point, rad/s (positive: to port); 0 resets the integral."""
        if not math.isfinite(rate_rad_s):
            raise ControlError(f"yaw loop: a set-point of {rate_rad_s!r} rad/s")
        if rate_rad_s == 0.0:
            self.integral_v = 0.0
        self.setpoint_rad_s = float(rate_rad_s)

    def stop(self) -> None:
        """No turn asked and no offset from now (a fish stack fell silent): the drive's own slew takes
        it to 0 V; nothing is left to wind."""
        self.setpoint_rad_s, self.integral_v, self.bias_v, self.edge = 0.0, 0.0, 0.0, ""

    def measure(self, t: float, rate_rad_s: float) -> None:
        """An IMU's yaw rate at ``t``: low-passed (``rate_filter_s``) into :attr:`rate_rad_s`."""
        fresh = t - self._t_rate <= self.config.max_gap_s and math.isfinite(self.rate_rad_s)
        if fresh and t >= self._t_rate:
            w = 1.0 - math.exp(-(t - self._t_rate) / self.config.rate_filter_s)
            self.rate_rad_s += w * (float(rate_rad_s) - self.rate_rad_s)
        else:
            self.rate_rad_s = float(rate_rad_s)
        self._t_rate = t

    def update(
        self, t: float, thrust_n: float, speed_m_s: float, voltage_pp: float, frequency_hz: float = math.nan
    ) -> float:
        """The offset now, V, for the fin's thrust (N), the fish's speed (m/s) and the drive's
        peak-to-peak voltage (its window's room): 0 while the set-point is 0 or the fin gives no
        thrust."""
        dt = 0.0 if math.isnan(self._t) else max(t - self._t, 0.0)
        self._t = t
        self._slew = self.config.slew_v_per_s
        if math.isfinite(frequency_hz) and frequency_hz > 0 and voltage_pp > 0:
            sine = 0.5 * voltage_pp * 2.0 * math.pi * frequency_hz  # (its slope at the crossing, V/s)
            self._slew = min(self._slew, self.config.period_shift * sine)
        low, high = bias_window_v(voltage_pp)
        r = self.setpoint_rad_s
        steerable = math.isfinite(speed_m_s) and speed_m_s >= self.config.min_speed_m_s
        if r == 0.0 or not (math.isfinite(thrust_n) and thrust_n > 0 and steerable):
            self.integral_v, self.edge = 0.0, ""
            return self._slewed(0.0, dt)
        speed = max(speed_m_s, 0.0)
        ff = bias_for_yaw_rate(self.body, self.fin, r, thrust_n, speed)
        if math.isnan(ff):
            ff = high if r > 0 else low
        gain, tau = self._plant(r, thrust_n, speed)
        fresh = t - self._t_rate <= self.config.max_gap_s and math.isfinite(self.rate_rad_s)
        error = r - self.rate_rad_s if fresh else 0.0  # (the set-point less the IMU's rate)
        kp, ki = tau / (gain * self.config.time_constant_s), 1.0 / (gain * self.config.time_constant_s)
        raw = ff + kp * error + self.integral_v + ki * error * dt
        bias = min(max(raw, low), high)
        slewed = self._slewed(bias, dt)
        held = abs(slewed - bias) > 1e-9  # (the slew holds the offset back: the integral waits too)
        if not held and (bias == raw or (raw > high and error < 0) or (raw < low and error > 0)):
            self.integral_v += ki * error * dt  # (no winding against an edge)
        self.edge = "port" if raw > high else "starboard" if raw < low else ""
        return slewed

    def _slewed(self, target_v: float, dt: float) -> float:
        """The offset moved toward ``target_v`` by at most the slew over ``dt``."""
        step = self._slew * dt
        self.bias_v = min(max(target_v, self.bias_v - step), self.bias_v + step)
        return self.bias_v

    def _plant(self, r: float, thrust_n: float, speed_m_s: float) -> tuple[float, float]:
        """The plant at the set-point: ``dr/db`` (rad/s per V, from the feed-forward's slope) and the
        yaw's time constant (s)."""
        dr = max(abs(r) * 1e-3, 1e-6)
        b_hi = bias_for_yaw_rate(self.body, self.fin, r + dr, thrust_n, speed_m_s)
        b_lo = bias_for_yaw_rate(self.body, self.fin, r - dr, thrust_n, speed_m_s)
        slope = (b_hi - b_lo) / (2.0 * dr)  # V per rad/s
        gain = 1.0 / slope if math.isfinite(slope) and slope > 0 else 1e-4
        k = fin_yaw_damping(self.body, self.fin, speed_m_s)
        return gain, self.body.yaw_time_constant_s(r, k)
