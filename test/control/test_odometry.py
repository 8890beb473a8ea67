"""The fish's dead reckoning against its closed forms: the distance of a known speed, and the
variance of the sensor's noise and bias."""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.control.odometry import UNKNOWN, DeadReckoning
from piezofin_ros.errors import ControlError


def test_a_constant_speed_gives_its_distance_and_the_variance_grows_as_its_closed_form() -> None:
    odo = DeadReckoning(speed_sigma_m_s=0.002, speed_bias_m_s=0.001)
    dt, T, u = 0.05, 100.0, 0.06
    for t in np.arange(0.0, T + dt / 2, dt):
        odo.add(float(t), u)
    assert odo.x_m == pytest.approx(u * T, rel=1e-9)
    assert odo.swum_s == pytest.approx(T, rel=1e-9)
    assert odo.x_var_m2 == pytest.approx(0.002**2 * dt * T + (0.001 * T) ** 2, rel=1e-9)


def test_a_ramp_is_integrated_exactly_and_a_silence_counts_at_most_its_bound() -> None:
    odo = DeadReckoning(max_gap_s=1.0)
    for t in np.linspace(0.0, 10.0, 201):  # U = 0.01 t: x = 0.005 t^2 (the trapezoid is exact)
        odo.add(float(t), 0.01 * float(t))
    assert odo.x_m == pytest.approx(0.5, rel=1e-12)
    odo.add(40.0, 0.1)  # 30 s without a reading: counted as 1 s
    assert odo.swum_s == pytest.approx(11.0) and odo.x_m == pytest.approx(0.5 + 0.1, rel=1e-12)
    odo.add(39.0, 5.0)  # (a reading from before the last: ignored)
    odo.add(math.nan, 0.1)
    assert odo.x_m == pytest.approx(0.6, rel=1e-12)


@pytest.mark.parametrize(
    "bad", [{"speed_sigma_m_s": -1.0}, {"speed_bias_m_s": math.nan}, {"max_gap_s": math.inf}]
)
def test_an_impossible_sensor_is_one_clear_error(bad: dict[str, float]) -> None:
    with pytest.raises(ControlError, match="odometry"):
        DeadReckoning(**bad)


def test_stretches_are_laid_along_the_imus_heading_and_its_error_goes_across_the_track() -> None:
    """Issue 42: with an IMU's heading the fish's track bends; the heading's variance puts the
    position off across the track by the distance swum times its standard deviation, rotated onto
    the heading."""
    odo = DeadReckoning(speed_sigma_m_s=0.0, speed_bias_m_s=0.0)
    for k in range(21):  # 1 m along x
        odo.add(0.5 * k, 0.1)
    odo.turn(math.pi / 2, 1e-4)
    for k in range(21, 41):  # 1 m along y
        odo.add(0.5 * k, 0.1)
    assert (odo.x_m, odo.y_m, odo.distance_m) == pytest.approx((1.0, 1.0, 2.0))
    xx, xy, yy = odo.position_covariance()
    assert xx == pytest.approx(2.0**2 * 1e-4) and yy == pytest.approx(0.0, abs=1e-18)
    assert xy == pytest.approx(0.0, abs=1e-18)
    odo.turn(math.nan, 1e-4)  # (a reading that is none: kept as it was)
    assert odo.heading_rad == math.pi / 2
    assert DeadReckoning().position_covariance()[2] == UNKNOWN  # (no IMU: across unknown)


def test_the_imus_yaw_rate_is_the_twists_turn_once_heard() -> None:
    """The twist's yaw rate: none observed (0, its variance NaN) until the IMU gives one; a reading
    that is none (not finite, a negative variance) leaves it as it was."""
    odo = DeadReckoning()
    assert odo.yaw_rate_rad_s == 0.0 and math.isnan(odo.yaw_rate_var)
    odo.spin(0.02, 1e-6)
    for rate, var in ((math.nan, 1e-6), (0.5, -1.0), (0.5, math.inf)):
        odo.spin(rate, var)
    assert (odo.yaw_rate_rad_s, odo.yaw_rate_var) == (0.02, 1e-6)
