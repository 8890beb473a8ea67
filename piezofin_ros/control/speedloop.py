"""A fish's speed loop: a speed set-point (m/s) to the thrust demand the optimising controller meets
(``thrust_demand``), feed-forward through the body's drag law and feedback on the measured speed.

The demand is

.. math::

    T_d = \\frac{D(U^*)}{n} + K_p\\,e + \\frac{K_p}{T_i}\\int e\\,dt, \\qquad e = U^* - U_{measured},

with ``D`` the body's drag (:class:`~piezofin_ros.physics.swim.Body`), ``n`` its fins, a
proportional gain of half the body's own damping at the set-point by default (``K_p = D'(U^*) / 2n``:
a loop gain of 1/2, stable behind the optimising controller, which meets a new demand only after its
trials, tens of seconds) and an integral that removes what the drag law gets wrong, winding only
while the fin gives what is asked (the estimator's thrust at least 85 % of the demand), or, where no
estimate has come in ``unjudged_after_s`` of its first set-point (a stack with no estimator, or a
drive that never rests long enough for an estimator's window), as any PI loop winds.  Cautious by
design (an integral time of 30 s behind trials of tens of seconds), the integral removes a drag law
30 % off in 90-110 s; it winds ``steady_boost`` times faster while the speed's own trend would
still leave it more than 2 % off (its lag is past: what is left is the drag law's error), which
leaves a right drag law's steps as they were; and where the speed is off it takes a secant step,
at most every ``secant_every_s``: the steady part of the demand moves ``steady_secant`` of the way
to the body's drag times the drag law's shape ``D(U^*)/D(U)`` (only the law's shape is the told
body's).  The drag is the fin's estimated thrust less the told mass times the speed's slope over
the estimate's window (the body's momentum: :func:`.drag.moving_drag`), or, where the window is not
told or the readings too noisy for the slope, the thrust itself where the speed is steady (over a
window of its readings: :func:`.drag.steady_off`).  Safe whatever it is fed:

* the demand stays within ``[min_demand_n, max_demand_n]`` while there is a set-point (the
  integral stops winding at either end; a demand never falls to 0, which the optimiser would read
  as "no demand" and answer with its best thrust per watt at full voltage);
* a set-point the allowed demand cannot reach is said, with the fastest speed it can give;
* a speed sensor that falls silent (no reading for ``sensor_timeout_s``) leaves the feed-forward
  alone (no integral, no proportional action on a stale reading), said; a reading that is not a
  finite speed is refused;
* a sensor that lies (its speed far from what the fin's estimated thrust gives through the drag
  law, for ``disagreement_s``) is said; the demand stays clamped.  Judged on the estimate (what the
  fin gives), not the demand (what was asked: the fin may not be able to give it).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from ..config import setting, settings_of
from ..errors import ControlError
from ..physics.swim import SPEED_MOST_M_S, Body
from .drag import RAW_SPAN_S, moving_drag, steady_off

#: Within 5 % of its set-point this long since it was set, the drag law's error is in the integral:
#: a speed off after that is a trial's or a probe's, and a secant step on it is none of the law's
#: (M8507-P1 with a KC added mass, a probe's dip taken for the law 330 s into a step: +7 %, -5 %
#: for 100 s where it had recovered within 5 %), s
LEARNT_AFTER_S = 60.0


@dataclass(frozen=True)
class SpeedLoopConfig:
    """The loop's settings (SI); the ``speed_loop`` node's ``loop.*`` parameters."""

    max_demand_n: float = setting(0.01, "the most thrust the loop may ask of each fin, N", 1e-6, 1.0)
    min_demand_n: float = setting(
        1e-4, "the least thrust asked while there is a set-point, N (0 would read as no demand)", 1e-7, 1.0
    )
    kp_n_per_m_s: float = setting(
        0.0, "proportional gain, N per m/s per fin (0: half the body's damping at the set-point)", 0.0, 100.0
    )
    ti_s: float = setting(30.0, "integral time, s", 0.1, 600.0)
    sensor_timeout_s: float = setting(
        2.0, "a speed sensor silent this long leaves the feed-forward alone, s", 0.1, 60.0
    )
    disagreement: float = setting(
        0.5, "relative speed error against the drag law that is said (a sensor that lies)", 0.01, 10.0
    )
    disagreement_s: float = setting(20.0, "for this long, s", 0.1, 3600.0)
    filter_s: float = setting(
        2.0,
        "the speed reading's low-pass time constant, s (0: none): the proportional action on a raw "
        "reading turned the sensor's noise into demands that jumped by 30 % every second",
        0.0,
        60.0,
    )

    unjudged_after_s: float = setting(
        30.0,
        "no thrust estimate this long after the first set-point: the integral winds on the speed alone, "
        "as any PI loop (with no estimate to judge by, it never wound: a fish 13 % slow for good), s",
        1.0,
        3600.0,
    )

    steady_boost: float = setting(
        4.0,
        "the integral winds this many times faster while the speed's own trend would still leave it "
        "more than 2 % off its set-point (steady_s), the fin giving what is asked: the speed's lag is "
        "past, what is left is the drag law's error, which the cautious integral alone took 80-110 s "
        "to remove (1: never)",
        1.0,
        20.0,
    )
    steady_s: float = setting(
        10.0,
        "the speed's trend is its reading low-passed over filter_s against the same over this long; "
        "the integral winds steady_boost times faster once that trend, carried on for twice this "
        "long, has left the speed more than 2 % off on the same side for this long, and until it "
        "leaves it within 1.5 %; the secant step judges a steady speed over this less filter_s of "
        "readings, s",
        1.0,
        600.0,
    )

    steady_secant: float = setting(
        0.5,
        "where the speed is more than 3 % off and a thrust estimate is fresh, the steady part of the "
        "demand moves this share of the way to the body's drag times the drag law's shape D(U*)/D(U) "
        "(the secant): the drag is the fin's thrust less the told mass times the speed's slope over "
        "the estimate's window, or, where that is not known, the thrust at a steady speed (over the "
        "last steady_s - filter_s of readings); 0: never",
        0.0,
        1.0,
    )
    secant_every_s: float = setting(20.0, "a secant step at most this often, s", 1.0, 3600.0)
    secant_fresh_s: float = setting(
        5.5,
        "a secant step only on a thrust estimate at most this old (the estimator's 5 s windows), s",
        0.1,
        60.0,
    )

    widen_after_s: float = setting(
        60.0,
        "saturated this long while the fin gives what is asked (by its estimate) and the fish is short "
        "of its set-point: the estimates read high against the speed; the most asked grows by 25 %, s",
        1.0,
        3600.0,
    )
    max_widening: float = setting(
        3.0,
        "the most the loop may ask grows to at most this many times max_demand_n (1: never): the drive's "
        "own limits hold whatever is asked",
        1.0,
        100.0,
    )

    def __post_init__(self) -> None:
        for name in (
            "max_demand_n",
            "min_demand_n",
            "ti_s",
            "sensor_timeout_s",
            "disagreement",
            "disagreement_s",
        ):
            x = getattr(self, name)
            if not (math.isfinite(x) and x > 0):
                raise ControlError(f"speed loop: {name} = {x!r} must be finite and > 0")
        if self.min_demand_n >= self.max_demand_n:
            raise ControlError(f"speed loop: min_demand_n {self.min_demand_n!r} must be below max_demand_n")
        if not (math.isfinite(self.kp_n_per_m_s) and self.kp_n_per_m_s >= 0):
            raise ControlError(
                f"speed loop: kp_n_per_m_s = {self.kp_n_per_m_s!r} must be >= 0 (0: the body's)"
            )
        for f, _, s in settings_of(type(self)):  # (every other setting within its declared range)
            x = getattr(self, f.name)
            lo, hi = s.bounds
            if not (math.isfinite(x) and lo <= x <= hi):
                raise ControlError(f"speed loop: {f.name} = {x!r} must be finite, within [{lo:g}, {hi:g}]")


@dataclass
class SpeedLoop:
    """The loop (module docstring); :meth:`update` once per tick with the time and the latest reading."""

    body: Body
    config: SpeedLoopConfig = field(default_factory=SpeedLoopConfig)
    setpoint_m_s: float = 0.0
    integral_n: float = 0.0
    demand_n: float = 0.0
    state: str = "no set-point"
    #: what the loop is doing, in one word (``state`` says it with its figures): ``idle`` (no
    #: set-point), ``unread`` (no speed reading yet), ``silent`` (the sensor stopped), ``lies`` (the
    #: sensor at odds with the drag law), ``saturated`` (at the most thrust allowed), ``holding``
    kind: str = "idle"
    _last_t: float = math.nan
    _first_t: float = math.nan  # (the first update with a set-point)
    _speed: float = math.nan
    _speed_slow: float = math.nan  # (the reading low-passed over steady_s: is the speed steady?)
    _off_since: float = math.nan  # (since when its trend leaves it off: see _boost)
    _speed_t: float = -math.inf
    _disagree_since: float = math.nan
    _thrust: float = math.nan  # the fin's estimated thrust (what it gives), N
    _thrust_t: float = -math.inf
    #: the most the loop asks now, N: ``max_demand_n``, widened (up to ``max_widening`` times) while
    #: the fish stays short of its set-point with the fin giving what is asked (the estimates read
    #: high: a fin model given that is wrong; issue 39's fish sat at its 8 mN cap 12-23 % slow)
    cap_n: float = math.nan
    widened: list[str] = field(default_factory=list)  # what was said each time it widened
    _saturated_since: float = math.nan
    _secant_t: float = -math.inf  # (the last secant step: _secant)
    _within_since: float = math.nan  # (since when the speed is within 5 % of its set-point: _secant)
    _law_learnt: bool = False  # (held a minute since the set-point changed: no more secant steps)
    _history: deque[tuple[float, float]] = field(default_factory=deque)
    #: the raw readings of the last :data:`RAW_SPAN_S` (the speed's slope over an estimate's window)
    _raw: deque[tuple[float, float]] = field(default_factory=deque)
    #: the latest estimate's window, ``(start, end)`` on the loop's clock, until the next look
    _window: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        self.cap_n = self.config.max_demand_n

    def set_setpoint(self, speed_m_s: float) -> str:
        """A new set-point (m/s, >= 0); returns what is said about it ("" when it is reachable)."""
        if not (math.isfinite(speed_m_s) and speed_m_s >= 0):
            raise ControlError(f"speed set-point {speed_m_s!r}: a finite speed >= 0 m/s")
        if float(speed_m_s) != self.setpoint_m_s:
            self._history.clear()  # (a speed steady before the step is no steady speed off this one)
            self._within_since, self._law_learnt = math.nan, False
        self.setpoint_m_s = float(speed_m_s)
        top = self.fastest_m_s()
        if self.feed_forward_n(speed_m_s) > self.cap_n:
            most = self.cap_n * 1e3
            return (
                f"set-point {speed_m_s:.3g} m/s is beyond the {most:.3g} mN per fin the loop may ask for: "
                f"it will swim at most {top:.3g} m/s"
            )
        return ""

    def fastest_m_s(self) -> float:
        """The speed the largest allowed demand gives through the drag law (U term neglected), m/s."""
        return float(self.body.steady_speed(self.cap_n))

    def feed_forward_n(self, speed_m_s: float) -> float:
        """Thrust per fin that holds ``speed_m_s`` against the drag law (the ``U`` term of Eq. 19 is
        under 1 % at a fish's speeds and is left to the integral), N."""
        return float(self.body.drag_n(speed_m_s)) / self.body.fins

    def measure(self, t: float, speed_m_s: float) -> bool:
        """A speed reading at time ``t``, low-passed (``filter_s``); False (ignored) unless it is a
        finite speed."""
        if not math.isfinite(speed_m_s) or not math.isfinite(t) or abs(speed_m_s) > SPEED_MOST_M_S:
            return False
        dt = t - self._speed_t
        x = float(speed_m_s)
        fresh = 0 <= dt <= self.config.sensor_timeout_s  # (a reading after a silence starts afresh)
        if fresh and self.config.filter_s > 0:  # (first order)
            self._speed += dt / (self.config.filter_s + dt) * (x - self._speed)
        else:
            self._speed = x
        if fresh:
            self._speed_slow += dt / (self.config.steady_s + dt) * (x - self._speed_slow)
        else:
            self._speed_slow = x
            self._history.clear()
        self._history.append((float(t), self._speed))
        if not fresh:
            self._raw.clear()
        self._raw.append((float(t), x))
        while len(self._raw) > 2 and self._raw[1][0] <= t - RAW_SPAN_S:
            self._raw.popleft()
        span = self._steady_span()
        while len(self._history) > 2 and self._history[1][0] <= t - span:
            self._history.popleft()
        self._speed_t = float(t)
        return True

    def estimate(self, t: float, thrust_n: float, window_s: float = math.nan, lag_s: float = 0.0) -> None:
        """The fin's estimated thrust (an estimate's self-sensed or Lighthill thrust) at time ``t``:
        the mean over the estimator's window of ``window_s`` that ended ``lag_s`` before (NaN: the
        window not known)."""
        if math.isfinite(thrust_n) and thrust_n >= 0 and math.isfinite(t):
            self._thrust, self._thrust_t = float(thrust_n), float(t)
            known = math.isfinite(window_s) and 0.0 < window_s <= RAW_SPAN_S and 0.0 <= lag_s <= RAW_SPAN_S
            end = float(t) - lag_s
            self._window = (end - window_s, end) if known else None

    @property
    def speed_m_s(self) -> float:
        """The speed as the loop reads it (low-passed; NaN: no reading yet), m/s."""
        return self._speed

    @property
    def thrust_estimate_n(self) -> float:
        """The fin's latest estimated thrust (NaN: none yet), N."""
        return self._thrust

    def kp(self) -> float:
        if self.config.kp_n_per_m_s > 0:
            return self.config.kp_n_per_m_s
        slope = float(self.body.drag_slope_n_s_m(max(self.setpoint_m_s, 1e-3)))
        return 0.5 * slope / self.body.fins  # (a loop gain of 1/2: stable behind a trial's delay)

    def update(self, t: float) -> float:
        """The thrust demand per fin at time ``t`` (N), clamped to ``[0, max_demand_n]``."""
        dt = 0.0 if math.isnan(self._last_t) else max(0.0, min(t - self._last_t, 1.0))
        self._last_t = t
        cfg = self.config
        # (an estimate's window is weighed at the first look after it came, or never: the speed moves on)
        window, self._window = self._window, None
        if self.setpoint_m_s <= 0.0:
            self.integral_n, self.demand_n, self.state = 0.0, 0.0, "no set-point: no thrust asked"
            self.kind = "idle"
            return 0.0
        ff = self.feed_forward_n(self.setpoint_m_s)
        fresh = t - self._speed_t <= cfg.sensor_timeout_s
        cap = self.cap_n
        if not fresh:
            self.demand_n = min(max(ff, cfg.min_demand_n), cap)
            self.kind = "silent" if math.isfinite(self._speed_t) else "unread"
            self.state = (
                f"speed sensor silent for {t - self._speed_t:.1f} s: feed-forward only "
                f"({self.demand_n * 1e3:.3g} mN per fin)"
                if math.isfinite(self._speed_t)
                else "no speed reading yet: feed-forward only"
            )
            return self.demand_n
        e = self.setpoint_m_s - self._speed
        if abs(e) > 0.05 * self.setpoint_m_s:
            self._within_since = math.nan
        elif math.isnan(self._within_since):
            self._within_since = t
        self._law_learnt = self._law_learnt or t - self._within_since >= LEARNT_AFTER_S
        kp = self.kp()
        raw = ff + kp * e + self.integral_n
        # the integral winds only while the demand is inside its bounds (or moving back inside), and
        # while the fin gives what is asked: a speed error while the controller is still on its way
        # to a new demand (its trials take tens of seconds) is no error of the drag law.  A fin that
        # gives more (the controller meets a demand with a margin) winds it: the speed is what counts
        delivered = t - self._thrust_t <= 60.0 and self._thrust >= 0.85 * self.demand_n
        if math.isnan(self._first_t):
            self._first_t = t
        unjudged = not math.isfinite(self._thrust_t) and t - self._first_t >= cfg.unjudged_after_s
        if (delivered or unjudged) and (raw < cap or e < 0) and (raw > cfg.min_demand_n or e > 0):
            boost = self._boost(t, e)
            self.integral_n += kp / cfg.ti_s * e * dt * boost
            if delivered:
                self._secant(t, e, ff, window)
        self.demand_n = min(max(ff + kp * e + self.integral_n, cfg.min_demand_n), cap)
        self.kind, self.state = self._judge(t, e)
        self._widen(t, e, delivered)
        return self.demand_n

    def _secant(self, t: float, e: float, ff: float, window: tuple[float, float] | None) -> None:
        """The body's drag is the fin's thrust less what accelerates it (:func:`.drag.moving_drag`,
        over the ``window`` of an estimate that came since the last look), or at a steady speed the
        thrust itself (:func:`.drag.steady_off`): where the speed is off and an estimate of the
        thrust is fresh, the steady part of the demand (feed-forward and integral) moves
        ``steady_secant`` of the way to that drag times the drag law's shape, ``D D(U*) / D(U)``, at
        most every ``secant_every_s``.  Only the law's shape is the told body's: its scale, which the
        integral would learn at its own pace, cancels.  The estimate's scale does not: it is the
        drive's once the controller's fit calibrates the estimator, and before that it may read a fin
        it was not told high, so the estimate is taken only where it agrees with the demand within
        25 %, else the account that moves the demand less; the half step bounds the rest.  The
        cautious integral alone, boosted only once the speed's lag is past, left the README's driver
        fish (its drag 39 % above the told law's at 5 cm/s) 8-13 % slow from 24 s to 60 s from rest;
        a secant step taken only while boosted, 12 % slow from 28 s to 64 s (its trend's low-pass
        remembered the overshoot: :func:`.drag.steady_off`)."""
        cfg = self.config
        if (
            cfg.steady_secant <= 0.0
            or self._law_learnt
            or t - self._secant_t < cfg.secant_every_s
            or t - self._thrust_t > cfg.secant_fresh_s
            or not 0.3 * self.setpoint_m_s < self._speed < 3.0 * self.setpoint_m_s
        ):
            return
        # (the thrust the fin gives: the estimate where it agrees with the demand the controller meets,
        # within 25 %; else the account that moves the demand less, the fish being slow or fast: the
        # estimate reads through the estimator's calibration, a wrong prior's until the controller's
        # fit reaches it, and read stranger 1's fin 1.45 times high at 66 s, an overshoot to +9 %)
        given = self._thrust
        agrees = 0.8 <= given / max(self.demand_n, 1e-12) <= 1.25
        if not agrees:
            given = min(given, self.demand_n) if e > 0 else max(given, self.demand_n)
        moving = moving_drag(self._raw, window, e, given, self.setpoint_m_s, self.body) if agrees else None
        if moving is not None:
            drag, speed = moving
        elif steady_off(self._history, t, e, self.setpoint_m_s, self._steady_span(), self.body):
            drag, speed = given, self._speed
        else:
            return
        drag_now = self.feed_forward_n(speed)  # (per fin, as ff)
        if not (math.isfinite(drag_now) and drag_now > 0.0):
            return
        target = drag * ff / drag_now
        step = cfg.steady_secant * (target - (ff + self.integral_n))
        if step * e <= 0.0:  # (a step away from the set-point, as an estimate read low asks, is none)
            return
        self.integral_n = min(max(self.integral_n + step, cfg.min_demand_n - ff), self.cap_n - ff)
        self._secant_t = t

    def _steady_span(self) -> float:
        """How long a steady speed is judged over (:func:`.drag.steady_off`), s."""
        return max(self.config.steady_s - self.config.filter_s, 1.0)

    def _boost(self, t: float, e: float) -> float:
        """How many times faster the integral winds now: ``steady_boost`` where the speed's trend,
        carried on for twice ``steady_s``, still leaves it more than 2 % off on the same side (the
        speed's lag is past: what is left is the drag law's), else 1.  Once that has begun, it goes on
        until the trend leaves it within 1.5 %: a trend near the 2 % edge, its reading's noise (0.2
        cm/s at 20 Hz, the trend's about 1 % of a 5 cm/s set-point) crossing it every few seconds,
        seldom lasted ``steady_s`` and the integral seldom sped up (a live fish 4-7 % slow for 80 s:
        boosted 20 % of that time, 40 % now)."""
        cfg = self.config
        rate = (self._speed - self._speed_slow) / max(cfg.steady_s - cfg.filter_s, 1.0)
        ahead = e - rate * 2.0 * cfg.steady_s
        edge = 0.02 if math.isnan(self._off_since) else 0.015
        if not (abs(ahead) > edge * self.setpoint_m_s and ahead * e > 0):
            self._off_since = math.nan
            return 1.0
        if math.isnan(self._off_since):
            self._off_since = t
        return cfg.steady_boost if t - self._off_since >= cfg.steady_s else 1.0

    def _widen(self, t: float, e: float, delivered: bool) -> None:
        """A loop saturated while the fin gives what it asks (by the estimates) and the fish is still
        short by more than the sensor's share (2 %), and 5 % slower than that thrust gives through
        the drag law, is a contradiction, not a state to sit in: the estimated thrust reads high
        against the speed (or the body drags more than its law says: at a steady speed only their
        ratio shows).  After ``widen_after_s`` of it, the most asked
        grows by 25 % (up to ``max_widening`` times ``max_demand_n``), said each time."""
        short = e > 0.02 * self.setpoint_m_s
        # (and slower than the estimated thrust gives through the drag law: a set-point beyond what
        # the fin gives, estimated right, is no contradiction)
        expected = float(self.body.steady_speed(self._thrust)) if delivered else math.nan
        slow = self._speed < 0.95 * expected
        if not (self.kind == "saturated" and delivered and short and slow):
            self._saturated_since = math.nan
            return
        if math.isnan(self._saturated_since):
            self._saturated_since = t
        most = self.config.max_widening * self.config.max_demand_n
        if t - self._saturated_since < self.config.widen_after_s or self.cap_n >= most:
            return
        before, self.cap_n = self.cap_n, min(1.25 * self.cap_n, most)
        self._saturated_since = t
        self.widened.append(
            f"saturated at {before * 1e3:.3g} mN per fin for {self.config.widen_after_s:.0f} s with the fin "
            f"giving it by its estimate and the fish {e * 100:.2g} cm/s short: its thrust estimates read "
            f"high against the speed (the fin model it was given, or the body's drag, is not this "
            f"fish's); asking up to {self.cap_n * 1e3:.3g} mN"
        )

    def _judge(self, t: float, e: float) -> tuple[str, str]:
        """What is said of the loop now (its kind and its sentence): holding, saturated, or a sensor
        at odds with the drag law."""
        judged = t - self._thrust_t <= 60.0  # (an estimate of the fin's thrust in the last minute)
        expected = float(self.body.steady_speed(self._thrust)) if judged else math.nan
        off = abs(self._speed - expected) / max(expected, 1e-3) if judged else 0.0
        if off > self.config.disagreement:
            if math.isnan(self._disagree_since):
                self._disagree_since = t
        else:
            self._disagree_since = math.nan
        if not math.isnan(self._disagree_since) and t - self._disagree_since >= self.config.disagreement_s:
            return "lies", (
                f"the speed sensor reads {self._speed:.3g} m/s where the fin's {self._thrust * 1e3:.3g} mN "
                f"gives {expected:.3g} m/s through the drag law, for {t - self._disagree_since:.0f} s: a "
                "sensor that lies, a fouled body, or a drag law that is wrong"
            )
        if self.demand_n >= self.cap_n and e > 0:
            most = self.cap_n * 1e3
            return "saturated", f"at the most thrust allowed ({most:.3g} mN per fin): {e:+.3g} m/s short"
        return "holding", f"holding {self.setpoint_m_s:.3g} m/s ({e:+.2g} m/s)"


@dataclass
class DemandGate:
    """When a demand is worth sending: when it moved by more than ``deadband`` (relative) since the
    last one sent, and at least every ``keepalive_s``.  The controller's optimiser learns from whole
    trials, which a demand that never rests would starve (each new demand is a new fit and a new
    point); the keep-alive tells it the loop is there."""

    deadband: float = 0.03
    keepalive_s: float = 5.0
    sent_t: float = -math.inf
    sent: float = math.nan

    def due(self, t: float, demand_n: float) -> bool:
        """True (and remembered as sent) when ``demand_n`` at ``t`` is to be sent."""
        moved = not abs(demand_n - self.sent) <= self.deadband * max(abs(self.sent), 1e-4)  # (NaN: first)
        if moved or t - self.sent_t >= self.keepalive_s:
            self.sent_t, self.sent = t, demand_n
            return True
        return False
