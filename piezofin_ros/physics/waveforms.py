"""Drive-voltage waveforms for the time-domain engine.

A waveform is anything with vectorised ``value(t)`` (V) and ``derivative(t)`` (V/s) methods
(:class:`Waveform`).  The derivative is needed exactly, not by finite differences, because
the drive current of Eq. (10) is ``i = C_eq dv/dt + theta deta/dt`` and the capacitive
part usually dominates it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError

FloatArray = NDArray[Any]  # float64 arrays (numpy's stubs are too strict for dtype=float)


@runtime_checkable
class Waveform(Protocol):
    """A drive voltage ``v(t)`` with its time derivative."""

    def value(self, t: FloatArray) -> FloatArray: ...

    def derivative(self, t: FloatArray) -> FloatArray: ...


@dataclass(frozen=True)
class SineBurst:
    """``v = (Vpp/2) sin(2 pi f (t - t_start))`` for a whole number of cycles, else 0.

    The burst starts at a zero crossing and lasts ``round(f * duration)`` complete cycles
    (at least one), so it also ends at a zero crossing: the voltage never steps, and the
    capacitive current has no spike.  ``duration = inf`` drives continuously.
    The paper's protocol (10 s off, 10 s on, 10 s off) is ``SineBurst(f, Vpp, 10.0, 10.0)``
    simulated for 30 s.
    """

    frequency_hz: float
    voltage_pp: float
    t_start: float = 0.0
    duration: float = math.inf

    def __post_init__(self) -> None:
        if not (math.isfinite(self.frequency_hz) and self.frequency_hz > 0):
            raise PhysicsError(f"frequency must be finite and > 0 Hz, got {self.frequency_hz}")
        if not (math.isfinite(self.voltage_pp) and self.voltage_pp >= 0):
            raise PhysicsError(f"peak-to-peak voltage must be finite and >= 0 V, got {self.voltage_pp}")

    @property
    def t_end(self) -> float:
        """End of the burst: a whole number of cycles after ``t_start``."""
        if math.isinf(self.duration):
            return math.inf
        cycles = max(1, round(self.frequency_hz * self.duration))
        return self.t_start + cycles / self.frequency_hz

    def _gate(self, t: FloatArray) -> FloatArray:
        return (t >= self.t_start) & (t < self.t_end)

    def value(self, t: ArrayLike) -> FloatArray:
        t = np.asarray(t, dtype=float)
        w = 2 * np.pi * self.frequency_hz
        return np.where(self._gate(t), 0.5 * self.voltage_pp * np.sin(w * (t - self.t_start)), 0.0)

    def derivative(self, t: ArrayLike) -> FloatArray:
        t = np.asarray(t, dtype=float)
        w = 2 * np.pi * self.frequency_hz
        return np.where(self._gate(t), 0.5 * self.voltage_pp * w * np.cos(w * (t - self.t_start)), 0.0)


@dataclass(frozen=True)
class ProtocolTiming:
    """The paper's trial: ``off_s`` without voltage, ``on_s`` of sine, ``off_s`` without voltage.

    The one definition of the protocol's times: the rig's protocol mode, the controller's trial
    plan and the nodes' parameters take their defaults from here.
    """

    off_s: float = 10.0
    on_s: float = 10.0

    def __post_init__(self) -> None:
        for name in ("off_s", "on_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise PhysicsError(f"protocol {name} must be finite and > 0 s, got {value!r}")

    @property
    def trial_s(self) -> float:
        return 2 * self.off_s + self.on_s


def protocol(
    frequency_hz: float,
    voltage_pp: float,
    off_s: float = ProtocolTiming.off_s,
    on_s: float = ProtocolTiming.on_s,
) -> SineBurst:
    """The paper's per-point protocol: ``off_s`` without voltage, ``on_s`` of sine, then off."""
    return SineBurst(frequency_hz, voltage_pp, t_start=off_s, duration=on_s)


@dataclass(frozen=True)
class Sampled:
    """An arbitrary sampled waveform, interpolated by a cubic spline (value and derivative).

    Outside ``[t[0], t[-1]]`` the voltage is held at zero.
    """

    t: FloatArray
    v: FloatArray
    _spline: Any = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        v = np.asarray(self.v, dtype=float)
        if t.ndim != 1 or t.shape != v.shape or t.size < 2:
            raise PhysicsError("t and v must be 1-D arrays of the same length >= 2")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise PhysicsError("sampled waveform contains NaN or infinity")
        if np.any(np.diff(t) <= 0):
            raise PhysicsError("sample times must increase strictly")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "v", v)
        from scipy.interpolate import CubicSpline  # (loaded only by a sampled waveform)

        object.__setattr__(self, "_spline", CubicSpline(t, v))

    def _inside(self, t: FloatArray) -> FloatArray:
        return (t >= self.t[0]) & (t <= self.t[-1])

    def value(self, t: ArrayLike) -> FloatArray:
        t = np.asarray(t, dtype=float)
        return np.where(self._inside(t), self._spline(t), 0.0)

    def derivative(self, t: ArrayLike) -> FloatArray:
        t = np.asarray(t, dtype=float)
        return np.where(self._inside(t), self._spline(t, 1), 0.0)
