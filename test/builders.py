"""Builders the tests share: one :class:`Estimate` from what a test cares about, the rest neutral."""

from __future__ import annotations

import math
from typing import Any

from piezofin_ros.estimation.estimator import Estimate


def estimate(
    *,
    t_start: float,
    t_end: float,
    frequency_hz: float,
    voltage_pp: float,
    thrust_n: float,
    power_w: float,
    final: float = 0.0,
    **more: Any,
) -> Estimate:
    """An estimate over ``[t_start, t_end]`` at a point: the thrust (vibrometer and self-sensed alike)
    and the fin's watt given, a tip velocity of 0.1 m/s, no load cell, the fish at rest; ``more``
    sets any other field by name."""
    nan = math.nan
    fields: dict[str, Any] = {
        "t_start": t_start,
        "t_end": t_end,
        "final": final,
        "n_periods": (t_end - t_start) * frequency_hz,
        "frequency_hz": frequency_hz,
        "voltage_pp": voltage_pp,
        "current_rms": 1e-4,
        "power_w": power_w,
        "tip_velocity_rms": 0.1,
        "thrust_n": thrust_n,
        "thrust_per_watt": nan,
        "c_tau": nan,
        "tip_velocity_rms_self": 0.1,
        "thrust_self_n": thrust_n,
        "thrust_per_watt_self": nan,
        "thrust_loadcell_n": nan,
        "loadcell_baselines": 0.0,
        "swim_speed_m_s": 0.0,
    }
    unknown = set(more) - set(Estimate.field_names())
    if unknown:
        raise TypeError(f"no Estimate field {', '.join(sorted(unknown))}")
    return Estimate(**{**fields, **more})
