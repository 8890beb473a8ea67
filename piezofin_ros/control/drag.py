"""The speed loop's two accounts of the body's drag, for its secant step
(:meth:`.speedloop.SpeedLoop._secant`): the fin's thrust less what accelerates the body over an
estimate's window (:func:`moving_drag`), or the thrust itself at a steady speed (:func:`steady_off`)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..physics.swim import Body

#: Raw speed readings kept this long (the slope over an estimate's window, at most this long), s
RAW_SPAN_S = 15.0

#: The momentum's account of the drag is taken only where the readings' noise leaves its share of the
#: thrust known within this (one standard error): a slow fish's small thrust on a noisy sensor is left
#: to the steady account
MOMENTUM_NOISE = 0.1


def moving_drag(
    raw: Sequence[tuple[float, float]],
    window: tuple[float, float] | None,
    e: float,
    given: float,
    setpoint_m_s: float,
    body: Body,
) -> tuple[float, float] | None:
    """The body's drag per fin over an estimate's ``window`` and the speed it was at: the fin's
    thrust ``given`` less what accelerated the body, the told ``body``'s mass (with its added mass)
    times the least-squares slope of the ``raw`` readings ``(t, speed)`` there (the swimmer's
    momentum, Eq. 19); ``e`` the speed's error now.  A speed still falling after an overshoot is no
    steady speed, and a step that waited for one came after the fish had lost 16 % (the README's
    driver fish, live at x5: 5.27 cm/s to 4.21 in 14 s at a point that gave what was asked, its drag
    39 % above the told law's); the momentum's account needs no wait, and at a steady speed it is
    the steady one.  None (the steady account) where:

    * the speed is within 3 % of its set-point;
    * the readings do not cover the window (at least 10, over 60 % of it);
    * the speed there is not within half and twice the set-point: the law's shape, D(U*) / D(U),
      is taken over a factor of 4 at most (from 1.35 cm/s to 4.6, a factor of 12, it asked
      stranger 2 for 7.3 mN where 1.6 were asked);
    * the acceleration's share is more than half the thrust, or its standard error more than
      :data:`MOMENTUM_NOISE` of it (the told mass's error, or the sensor's noise, would be the step).

    The loop gives only an estimate that agrees with the demand (a thrust less an acceleration
    carries the thrust's error, larger in share: a wrong prior's estimate, twice the truth while
    stranger 1 accelerated from rest, asked 7.6 mN where 3.9 were asked), and weighs a window at
    its first look after the estimate came, or never (a window weighed later is of a speed gone)."""
    if window is None or abs(e) <= 0.03 * setpoint_m_s:
        return None
    a = np.asarray([r for r in raw if window[0] <= r[0] <= window[1]], float)
    if len(a) < 10 or a[-1, 0] - a[0, 0] < 0.6 * (window[1] - window[0]):
        return None
    speed = float(a[:, 1].mean())
    if not 0.5 * setpoint_m_s <= speed <= 2.0 * setpoint_m_s:
        return None
    slope, spread = _slope(a)
    mass = (body.mass_kg + body.added_mass_kg) / body.fins
    pushing = mass * slope
    if not (abs(pushing) <= 0.5 * given and mass * spread <= MOMENTUM_NOISE * given):
        return None
    return given - pushing, speed


def steady_off(
    history: Sequence[tuple[float, float]], t: float, e: float, setpoint_m_s: float, span_s: float, body: Body
) -> bool:
    """Whether the speed is steady and off its set-point: more than 3 % off, and over the last
    ``span_s`` (the loop's ``steady_s - filter_s``) of low-passed readings ``history`` ``(t, speed)``
    since the set-point was last changed it moved by at most half its error ``e``, and its trend
    there (a least-squares slope) carried on over the told body's time constant
    ``(m + m_a) / D'(U*)`` would move it by at most half its error.  Over the window a first-order
    approach with that time constant (8.3 s at 5 cm/s on ``mfc-fish``) moves by more than its
    error, so a right drag law's approach is no steady speed.  A window, not a second low-pass: the
    boost's trend (the reading low-passed over ``steady_s``) remembered an overshoot from rest long
    after the speed had come to rest, and the README's driver fish sat 12 % slow from 28 s to 64 s
    before its secant step; with the window, 13-45 s (``bench_fish.py --strangers``, six seeds)."""
    if abs(e) <= 0.03 * setpoint_m_s or len(history) < 3:
        return False
    if t - history[0][0] < 0.9 * span_s:
        return False
    a = np.asarray(history)
    if float(np.ptp(a[:, 1])) > 0.5 * abs(e):
        return False
    rate, _ = _slope(a)
    tau = (body.mass_kg + body.added_mass_kg) / max(float(body.drag_slope_n_s_m(setpoint_m_s)), 1e-12)
    return abs(rate) * tau <= 0.5 * abs(e)


def _slope(a: np.ndarray) -> tuple[float, float]:
    """The least-squares slope of ``a[:, 1]`` on ``a[:, 0]`` and its standard error (NaN with two
    points).  By hand, not ``scipy.stats.linregress``: the speed loop's node would load scipy.stats
    for it (``test_footprint.py``: a node loads nothing it does not use)."""
    x, y = a[:, 0] - a[:, 0].mean(), a[:, 1] - a[:, 1].mean()
    sxx = float(np.dot(x, x))
    slope = float(np.dot(x, y)) / sxx
    dof = len(a) - 2
    spread = math.sqrt(float(np.sum((y - slope * x) ** 2)) / dof / sxx) if dof > 0 else math.nan
    return slope, spread
