"""The evidence: the trials the optimiser has seen, which of them count towards the task, and
whether a new one says the fin has changed.

A measured point counts only on the trials that did not choose it: the first trial at a point is
what made it look best, and of several noisy trials near the demand the best is the luckiest (the
winner's curse); the trials after it are independent.  :func:`count` is a pure function of the
trials, their re-estimated thrust and noise and the task; the optimiser takes it once per fit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..estimation.estimator import source_of
from .objective import Objective
from .tuning import Tuning

#: Trials this close (relative, see :func:`close`) are at the same operating point.
SAME_POINT = 1e-3


@dataclass(frozen=True)
class Observation:
    t: float
    frequency_hz: float
    voltage_pp: float
    thrust_n: float  # the estimate of ``source``
    power_w: float  # the fin's watt, mean(v i): what the fit explains
    source: str = "vibrometer"
    admittance: complex = complex(math.nan, math.nan)  # I_1 / V_1, S
    power_named_w: float = math.nan  # the optimiser's watt (NaN: the fin's)
    #: the drive's voltage as its monitor read it (NaN: the commanded ``voltage_pp``); an amplifier
    #: that sags or clips gives less than commanded, and the self-sensed thrust is the current's
    #: motional part at the voltage the fin got
    voltage_pp_drive: float = math.nan

    @property
    def point(self) -> tuple[float, float]:
        """The operating point commanded: (frequency Hz, Vpp)."""
        return (self.frequency_hz, self.voltage_pp)

    @property
    def self_sensed(self) -> bool:
        """Its thrust was sensed from the drive's current alone, and the admittance that gives it is there
        (the fit re-estimates it with its calibration)."""
        return source_of(self.source).self_sensed and self.has_admittance

    @property
    def load_cell(self) -> bool:
        return source_of(self.source).load_cell

    @property
    def drive_vpp(self) -> float:
        """The voltage the fin got: the monitor's reading, else the commanded one."""
        ok = math.isfinite(self.voltage_pp_drive) and self.voltage_pp_drive > 0
        return self.voltage_pp_drive if ok else self.voltage_pp

    @property
    def named_w(self) -> float:
        """The power in the watt the optimiser optimises."""
        return self.power_named_w if math.isfinite(self.power_named_w) else self.power_w

    @property
    def has_admittance(self) -> bool:
        return math.isfinite(self.admittance.real) and math.isfinite(self.admittance.imag)


def close(a: tuple[float, float], b: tuple[float, float], tol: float) -> bool:
    """Within ``tol`` in frequency and a quarter of it in voltage (the power goes as V^2)."""
    return abs(a[0] - b[0]) <= tol * b[0] and abs(a[1] - b[1]) <= 0.25 * tol * max(b[1], 1.0)


def same_point(a: Observation, b: Observation) -> bool:
    """Two trials at one operating point (their trials add up)."""
    return close(a.point, b.point, SAME_POINT)


@dataclass(frozen=True)
class Task:
    """What a point must give to count: the demand (``None``: the configured voltage's most thrust
    per watt, at least ``min_thrust_n``), with ``demand_margin_z`` standard deviations of margin, ranked by
    ``objective``."""

    demand_n: float | None
    min_thrust_n: float
    voltage_pp: float
    demand_margin_z: float
    objective: Objective
    voltage_pp_max: float = math.inf  # (a capped box: points measured above it are out of reach)


class Counted(NamedTuple):
    """A measured point that meets the task: its figure of merit, its first trial, its thrust (the
    re-estimated trials' geometric mean)."""

    score: float
    observation: Observation
    thrust_n: float


def count(
    obs: Sequence[Observation], thrust: Any, noise: Any, bound: float, task: Task
) -> tuple[list[Counted], list[Counted]]:
    """Measured points that meet ``task`` with the margin: each trial's thrust as re-estimated
    (``thrust``), its log noise (``noise``) and the calibration's 2-sigma bound (``bound``, NaN: none).

    Two lists: the points measured again, counted on the trials after the first; and the points
    measured once whose first trial alone meets the task (candidates for a confirming trial)."""
    half = float(np.nan_to_num(bound)) / 2.0
    groups: list[list[int]] = []  # the trials at each point (held points are measured again and again)
    for k, o in enumerate(obs):
        for g in groups:
            if same_point(obs[g[0]], o):
                g.append(k)
                break
        else:
            groups.append([k])
    counted: list[Counted] = []
    candidates: list[Counted] = []
    for same in groups:
        confirmed = len(same) > 1
        out = counted if confirmed else candidates
        o = obs[same[0]]
        if o.voltage_pp > task.voltage_pp_max * (1.0 + 1e-9):
            continue
        use = same[1:] if confirmed else same
        t = float(np.exp(np.mean(np.log(thrust[use]))))
        noise_t = float(np.sqrt(np.mean(noise[use] ** 2) / len(use)))
        low = t * math.exp(-task.demand_margin_z * math.hypot(noise_t, half))
        if task.demand_n is not None:
            if low >= task.demand_n:
                out.append(Counted(float(task.objective(task.demand_n, o.named_w, task.demand_n)), o, t))
        elif low >= task.min_thrust_n and abs(o.voltage_pp - task.voltage_pp) <= 0.01 * task.voltage_pp:
            out.append(Counted(float(task.objective(t, o.named_w)), o, t))
    return counted, candidates


def remembered(
    observations: Sequence[Observation], t: float, tuning: Tuning, quiet: Callable[[Observation], bool]
) -> list[Observation]:
    """The trials kept at ``t``: those of the last ``memory_s``, the latest ``quiet`` identification
    trial (what fixes the coupling and the stiffness: aged out, it was taken again, under a demand,
    every 20-22 trials) and up to ``tuning.memory_anchors`` anchors, each the newest aged trial at a
    frequency more than ``anchor_spacing`` from every kept one's: they keep the fit's spread while a
    fish holds one point.  In time order; a change of the fin clears them all (the optimiser)."""
    obs = list(observations)
    last_quiet = next((o for o in reversed(obs) if quiet(o)), None)
    kept = [o for o in obs if o.t >= t - tuning.memory_s or o is last_quiet]
    anchors = 0
    for o in reversed(obs):  # (the newest first)
        if anchors >= tuning.memory_anchors:
            break
        far = all(abs(math.log(o.frequency_hz / k.frequency_hz)) > tuning.anchor_spacing for k in kept)
        if far and not any(o is k for k in kept):
            anchors += 1
            kept.append(o)
    return sorted(kept, key=lambda o: o.t) if kept else obs[-2:]
