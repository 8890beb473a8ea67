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
other (docs/fish-record.md, Turning).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ..config import setting
from ..errors import ControlError
from ..physics.fin import Fin
from ..physics.planar import MFC_P1_WINDOW_V, PlanarBody, bias_for_yaw_rate, bias_window_v, fin_yaw_damping


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
    room_least_vpp: float = setting(
        400.0,
        "yaw loop: for the room its offset needs, the drive's voltage is never capped below this, Vpp",
        0.0,
        1e4,
    )
    room_engage_s: float = setting(
        10.0,
        "yaw loop: the drive's voltage is capped for its offset's room once it wanted more for this long, s",
        0.0,
        3600.0,
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
    wanted_v: float = 0.0  # the offset it would ask in a window without edges (:class:`OffsetRoom`)
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
        self.setpoint_rad_s, self.integral_v, self.bias_v, self.edge, self.wanted_v = 0.0, 0.0, 0.0, "", 0.0

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
            self.integral_v, self.edge, self.wanted_v = 0.0, "", 0.0
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
        self.wanted_v = raw
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


@dataclass
class OffsetRoom:
    """The most peak-to-peak voltage the drive may have so that the offset a yaw loop wants
    (:attr:`YawLoop.wanted_v`) fits in the MFC's window with the sine, on the window's short side:
    ``2 (b - lo)`` where ``lo`` is the edge nearer 0 V
    (:func:`~piezofin_ros.physics.planar.bias_window_v` turned round), for the optimiser's box
    (:meth:`~piezofin_ros.control.driveloop.DriveLoop.set_voltage_cap`).

    The P1's window (-500 V to +1,500 V) leaves an offset of -100 V under 800 Vpp: on the twin of
    M8528-P1 at 5.5 Hz a turn to starboard of 0.23 deg/s on a circle of 19 m, where 400 Vpp and
    -300 V give 0.35 deg/s on 6.4 m (slower, 4.0 cm/s against 7.5: docs/fish-record.md, Turning).  To port
    the window leaves +1,100 V, and a smaller sine loses more yaw rate than its offset gains (2.4
    deg/s at 800 Vpp, 1.5 at 400): no cap.  Below ``least_vpp`` (the yaw loop's
    ``room_least_vpp``) the yaw rate falls again (0.27 deg/s at 300 Vpp, 0.17 at 200): never below
    it.  The cap moves in steps of ``step_v``: down as soon as the room is below it, up only once the
    room is a step above the next (a wandering offset does not move the box at every tick).  Above
    ``most_vpp`` (the box's own top), or the room the window leaves with no offset (1,000 Vpp on a
    P1), there is no cap: :attr:`cap` is inf.  A cap begins only once the room has been short for
    ``engage_s`` (the yaw loop's ``room_engage_s``): a starboard correction after a turn to port
    wants it for seconds, a turn to starboard for minutes, and capped at each correction stranger 2
    swam a square to port at +15 % energy per metre (the optimiser choosing anew within each cap);
    once begun, it follows the room at once."""

    least_vpp: float = YawLoopConfig.room_least_vpp
    step_v: float = 100.0
    most_vpp: float = math.inf
    window_v: tuple[float, float] = MFC_P1_WINDOW_V
    engage_s: float = YawLoopConfig.room_engage_s
    cap: float = math.inf
    _short_since: float = math.nan  # when the room first fell short of the box (NaN: it is not)

    def update(self, wanted_v: float, t: float | None = None) -> bool:
        """The cap for the offset wanted at ``t`` (s; None: at once, no ``engage_s``), V; True if it
        moved."""
        lo, hi = self.window_v
        room, middle = math.inf, 0.5 * (lo + hi)
        if math.isfinite(wanted_v) and abs(lo) <= abs(hi) and wanted_v < middle:  # (the short side: lo)
            room = max(2.0 * (wanted_v - lo), 0.0)
        elif math.isfinite(wanted_v) and abs(hi) < abs(lo) and wanted_v > middle:  # (or hi)
            room = max(2.0 * (hi - wanted_v), 0.0)
        step = self.step_v
        below = max(math.floor(room / step) * step, self.least_vpp) if math.isfinite(room) else math.inf
        if below < self.cap:
            new = below
        else:
            above = room - step
            up = max(math.floor(above / step) * step, self.least_vpp) if math.isfinite(above) else math.inf
            new = max(up, self.cap)
        if new >= min(self.most_vpp, 2.0 * min(abs(lo), abs(hi))):  # (or what no offset leaves)
            new = math.inf
        if new == math.inf:
            self._short_since = math.nan
        elif self.cap == math.inf and t is not None:  # (a cap begins once the room was short engage_s)
            if math.isnan(self._short_since):
                self._short_since = t
            if t - self._short_since < self.engage_s:
                return False
        moved, self.cap = new != self.cap, new
        return moved
