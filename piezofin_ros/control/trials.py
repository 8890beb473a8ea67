"""Trial scheduling for the controller: which command to send when, and what each trial gave.

A :class:`TrialRunner` walks a list of operating points.  In ``protocol`` mode each point is
the paper's trial: ``off_s`` without voltage, ``on_s`` of sine, ``off_s`` without voltage; the
final estimate whose window lies inside the burst is the trial's result.  In ``continuous``
mode the drive moves from point to point without stopping and the first running estimate whose
window starts after the change is the result.  In ``frf`` mode (a stepped sine, for identification)
the drive also moves from point to point without stopping, but stays at each until it has settled:
until two consecutive running estimates at that frequency agree within ``settle_tolerance`` (tip
velocity, or the self-sensed one without a vibrometer), or for ``settle_timeout_s``, when the last
estimate is taken; the dwell adapts to the fin's damping, so the same plan works on a rig whose
fin is unknown.  The runner is a pure state machine driven by ``command(t)`` and
``add_estimate(estimate)``; the ``controller`` node calls them from its timer
and subscription, tests call them directly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum

import numpy as np
from numpy.typing import NDArray

from ..errors import ControlError
from ..estimation.estimator import THRUST_FIELDS, Estimate
from ..physics.amplifier import watt_of
from ..physics.waveforms import ProtocolTiming
from .objective import THRUST_PER_WATT, Objective

#: Which estimate ranks the operating points (a fish has only ``self``): its thrust field.
SOURCES = THRUST_FIELDS


class Mode(str, Enum):
    PROTOCOL = "protocol"
    CONTINUOUS = "continuous"
    FRF = "frf"


@dataclass(frozen=True)
class TrialPlan:
    points: tuple[tuple[float, float], ...]  # (frequency Hz, peak-to-peak V)
    mode: Mode = Mode.PROTOCOL
    off_s: float = ProtocolTiming.off_s
    on_s: float = ProtocolTiming.on_s
    settle_timeout_s: float = 30.0  # continuous: give up on a point after this long
    estimate_timeout_s: float = 10.0  # protocol: wait this long after a trial for its estimate
    settle_tolerance: float = 0.005  # frf: consecutive estimates agreeing this closely mean settled

    def __post_init__(self) -> None:
        if not self.points:
            raise ControlError("the trial plan has no operating point")
        for f, v in self.points:
            if not (math.isfinite(f) and f > 0 and math.isfinite(v) and v >= 0):
                raise ControlError(f"bad operating point ({f} Hz, {v} Vpp)")
        for name in ("off_s", "on_s", "settle_timeout_s", "estimate_timeout_s", "settle_tolerance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ControlError(f"{name} must be finite and > 0, got {value}")

    @classmethod
    def grid(cls, frequencies: Sequence[float], voltages: Sequence[float], **kwargs: object) -> TrialPlan:
        """Every frequency at every voltage (voltage-major, as the paper sweeps)."""
        return cls(tuple((float(f), float(v)) for v in voltages for f in frequencies), **kwargs)  # type: ignore[arg-type]

    @property
    def trial_s(self) -> float:
        return 2 * self.off_s + self.on_s if self.mode is Mode.PROTOCOL else math.nan


@dataclass
class TrialResult:
    index: int
    frequency_hz: float
    voltage_pp: float
    t_start: float
    estimate: Estimate | None = None
    previous: Estimate | None = None  # frf: the last estimate, not yet settled

    def record(self) -> dict[str, float]:
        rec = {
            "trial": float(self.index),
            "frequency_hz": self.frequency_hz,
            "voltage_pp": self.voltage_pp,
            "t_start": self.t_start,
        }
        if self.estimate is not None:
            e = self.estimate
            rec.update(
                current_rms=e.current_rms,
                c_tau=e.c_tau,
                thrust_n=e.thrust_n,
                thrust_self_n=e.thrust_self_n,
                thrust_loadcell_n=e.thrust_loadcell_n,
                tip_velocity_rms=e.tip_velocity_rms,
            )
            # every watt, by name: power_w (the fin's), power_<watt>_w, thrust_per_watt[_self][_<watt>]
            rec.update({k: v for k, v in e.as_dict().items() if k.startswith(("power_", "thrust_per_watt"))})
        return rec


@dataclass
class TrialRunner:
    plan: TrialPlan
    t_begin: float | None = None
    results: list[TrialResult] = field(default_factory=list)
    index: int = 0
    aborted: str | None = None

    @property
    def done(self) -> bool:
        return self.aborted is not None or self.index >= len(self.plan.points)

    def _start(self, t: float) -> None:
        f, v = self.plan.points[self.index]
        self.results.append(TrialResult(self.index, f, v, t))

    def command(self, t: float) -> tuple[float, float, float]:
        """The command ``(frequency_hz, voltage_pp, on)`` to send at time ``t`` (s)."""
        if self.t_begin is None:
            self.t_begin = t
            self._start(t)
        while not self.done:
            r = self.results[-1]
            elapsed = t - r.t_start
            plan = self.plan
            if plan.mode is Mode.PROTOCOL:
                if elapsed < plan.trial_s:
                    on = plan.off_s <= elapsed < plan.off_s + plan.on_s
                    return (r.frequency_hz, r.voltage_pp, 1.0) if on else (r.frequency_hz, 0.0, 0.0)
            elif r.estimate is None and elapsed < plan.settle_timeout_s:
                return (r.frequency_hz, r.voltage_pp, 1.0)
            elif r.estimate is None and r.previous is not None and plan.mode is Mode.FRF:
                r.estimate = r.previous  # not settled within the timeout: the last estimate is the point
            self.index += 1
            if not self.done:
                self._start(t)
        return (0.0, 0.0, 0.0)

    def add_estimate(self, e: Estimate) -> bool:
        """Attach an estimate to the trial it belongs to; True if it was used."""
        for r in reversed(self.results):
            if r.estimate is not None:
                continue
            if self.plan.mode is Mode.PROTOCOL:
                on0 = r.t_start + self.plan.off_s
                if e.final and on0 <= e.t_start < on0 + self.plan.on_s:
                    r.estimate = e
                    return True
            elif self.plan.mode is Mode.CONTINUOUS:
                if e.t_start >= r.t_start and abs(e.frequency_hz - r.frequency_hz) <= 0.02 * r.frequency_hz:
                    r.estimate = e
                    return True
            elif e.t_start >= r.t_start and abs(e.frequency_hz - r.frequency_hz) <= 1e-3 * r.frequency_hz:
                if r.previous is not None and _agree(r.previous, e, self.plan.settle_tolerance):
                    r.estimate = e
                else:
                    r.previous = e
                return True
        return False

    def missing(self, t: float) -> list[TrialResult]:
        """Finished trials whose estimate has not come within ``estimate_timeout_s``."""
        plan = self.plan
        out = []
        for r in self.results:
            if r.estimate is not None:
                continue
            end = r.t_start + (plan.trial_s if plan.mode is Mode.PROTOCOL else plan.settle_timeout_s)
            if t > end + plan.estimate_timeout_s:
                out.append(r)
        return out


def _agree(a: Estimate, b: Estimate, tolerance: float) -> bool:
    """Two estimates of one point agree: the tip velocity (else the self-sensed one) within ``tolerance``."""
    for key in ("tip_velocity_rms", "tip_velocity_rms_self"):
        x, y = getattr(a, key), getattr(b, key)
        if math.isfinite(x) and math.isfinite(y):
            return abs(x - y) <= tolerance * max(abs(x), abs(y))
    return False


def choose(
    results: Sequence[TrialResult],
    source: str = "vibrometer",
    min_thrust_n: float = 0.0,
    watt: str = "fin",
    objective: Objective = THRUST_PER_WATT,
) -> TrialResult | None:
    """The trial with the best ``objective`` (thrust per watt unless told, :mod:`.objective`) in
    ``watt`` (:data:`~piezofin_ros.physics.amplifier.WATT`) among those giving at least
    ``min_thrust_n``.

    If none reaches ``min_thrust_n``, the one with the most thrust.  ``None`` without results.
    """
    thrust_key = SOURCES[source]
    watt_of(watt)  # (an unknown watt: AmplifierError naming the others)
    done = [r for r in results if r.estimate is not None and math.isfinite(getattr(r.estimate, thrust_key))]
    if not done:
        return None
    ok = [r for r in done if getattr(r.estimate, thrust_key) >= min_thrust_n]
    if ok:
        return max(ok, key=lambda r: _score(r, thrust_key, watt, objective))
    return max(done, key=lambda r: getattr(r.estimate, thrust_key))


def _score(r: TrialResult, thrust_key: str, watt: str, objective: Objective) -> float:
    """A trial's ``objective`` (-inf where its watt is not measured)."""
    assert r.estimate is not None
    power = r.estimate.power(watt)
    if not (math.isfinite(power) and power > 0):
        return -math.inf
    return _finite(float(objective(getattr(r.estimate, thrust_key), power)))


def watt_label(watt: str) -> str:
    """How a thrust per watt in ``watt`` is printed: ``mN/W (supply)``."""
    return f"mN/W ({watt_of(watt).name})"


def _finite(x: float) -> float:
    return x if math.isfinite(x) else -math.inf


def parse_frequencies(spec: Sequence[str], option: str = "--freq") -> NDArray[np.float64]:
    """``start:stop:step`` (stop included, like the paper's 1-11 Hz) and/or plain values, Hz; a
    :class:`ControlError` naming ``option`` for anything else (the CLI and ``bringup`` share it)."""
    values: list[float] = []
    for item in spec:
        parts = item.split(":")
        try:
            nums = [float(p) for p in parts]
        except ValueError:
            raise ControlError(f"{option}: cannot read {item!r}; use values or start:stop:step") from None
        if len(nums) == 1:
            values.append(nums[0])
        elif len(nums) == 3:
            start, stop, step = nums
            if not step > 0 or stop < start:
                raise ControlError(f"{option} {item!r}: need start <= stop and step > 0")
            n = int(np.floor((stop - start) / step + 1e-9)) + 1
            if n > 1_000_000:
                raise ControlError(f"{option} {item!r}: {n} points is too many (max 1e6)")
            values.extend(np.round(start + step * np.arange(n), 12))
        else:
            raise ControlError(f"{option}: cannot read {item!r}; use values or start:stop:step")
    freqs = np.asarray(values, dtype=float)
    if freqs.size == 0 or np.any(~np.isfinite(freqs)) or np.any(freqs <= 0):
        raise ControlError(f"{option}: frequencies must be finite and > 0 Hz")
    return freqs
