"""The map: the corrected model times the residual process's correction over the operating box,
with the demand's margin; the frontier the task asks for at each frequency, and its best point.

Each function reads what :class:`MapInputs` names of the optimiser (its fit, residual process, task
and watt) and changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from ..config import HARD_VOLTAGE_PP_MAX
from ..errors import ControlError
from ..estimation.estimator import source_of
from ..physics.amplifier import Amplifier, power_in, watt_of
from ..physics.fin import Fin
from .correction import Correction, FloatArray
from .fit import Fit, FitProblem
from .gp import ResidualGP
from .objective import THRUST_PER_WATT, Objective


@dataclass(frozen=True)
class OperatingBox:
    """Where the optimiser may search: a band of frequencies and a range of voltages.

    Not the drive's safety limits (:class:`~piezofin_ros.rig.simulated.DriveLimits`, enforced by the
    rig on every command whatever the controller says): the box the optimiser proposes points in,
    which the controller node sets inside its own ``voltage_pp_max``.  ``voltage_pp_max`` can never
    exceed the MFC's hard cap.
    """

    frequency_min_hz: float = 1.0
    frequency_max_hz: float = 20.0
    voltage_pp_min: float = 50.0
    voltage_pp_max: float = 800.0

    def __post_init__(self) -> None:
        vals = (self.frequency_min_hz, self.frequency_max_hz, self.voltage_pp_min, self.voltage_pp_max)
        if not all(math.isfinite(x) and x > 0 for x in vals):
            raise ControlError(f"limits must be finite and > 0, got {vals}")
        if self.frequency_min_hz >= self.frequency_max_hz or self.voltage_pp_min >= self.voltage_pp_max:
            raise ControlError("limits: each minimum must be below its maximum")
        if self.voltage_pp_max > HARD_VOLTAGE_PP_MAX:
            raise ControlError(
                f"voltage_pp_max {self.voltage_pp_max} V exceeds the hard cap {HARD_VOLTAGE_PP_MAX} V"
            )

    def clamp(self, f: float, v: float) -> tuple[float, float]:
        """The nearest point inside the box (NaN goes to the lower corner: the safe side)."""
        f = (
            self.frequency_min_hz
            if not math.isfinite(f)
            else min(max(f, self.frequency_min_hz), self.frequency_max_hz)
        )
        v = (
            self.voltage_pp_min
            if not math.isfinite(v)
            else min(max(v, self.voltage_pp_min), self.voltage_pp_max)
        )
        return f, v


@dataclass(frozen=True)
class Choice:
    frequency_hz: float
    voltage_pp: float
    thrust_n: float  # predicted
    power_w: float  # predicted
    feasible: bool  # the demand can be met

    @property
    def thrust_per_watt(self) -> float:
        return self.thrust_n / self.power_w if self.power_w > 0 else 0.0


@dataclass(frozen=True)
class Surface:
    """The map on a set of points: mean thrust and power, the thrust's lower bound, and the log
    standard deviations (the process's, no measurement noise) of thrust and power."""

    frequency_hz: FloatArray
    voltage_pp: FloatArray
    thrust_n: FloatArray
    power_w: FloatArray
    thrust_low_n: FloatArray
    sigma_thrust: FloatArray
    sigma_power: FloatArray
    power_fin_w: FloatArray | None = None  # the fin's watt, where ``power_w`` is another (else None)

    @property
    def fin_w(self) -> FloatArray:
        return self.power_w if self.power_fin_w is None else self.power_fin_w

    def objective(self, demand_n: float | None, objective: Objective = THRUST_PER_WATT) -> FloatArray:
        """The figure of merit (:mod:`.objective`) at each point, the thrust counted up to the demand."""
        return objective(self.thrust_n, self.power_w, demand_n)


class MapInputs(Protocol):
    """What the map reads of the optimiser."""

    fin: Fin
    limits: OperatingBox
    voltage_pp: float
    demand_n: float | None
    min_thrust_n: float
    source: str
    watt: str
    objective: Objective
    amplifier: Amplifier
    demand_margin_z: float
    fit: Fit
    gp: ResidualGP
    self_sensing_bound: float

    @property
    def problem(self) -> FitProblem: ...

    @property
    def correction(self) -> Correction: ...


def model_sigma(opt: MapInputs, f: Any, v: Any) -> FloatArray:
    """Standard deviation of the corrected model's log thrust at the points, from the fitted
    parameters' covariance (0 before the first fit)."""
    f, v = np.broadcast_arrays(np.asarray(f, float), np.asarray(v, float))

    def log_thrust(c: Correction) -> FloatArray:
        return np.log(np.maximum(c.response(opt.fin, f, v).thrust_n, 1e-300))

    # (a load cell's gain: the truth only where the load cell is the reference)
    return opt.fit.sigma(log_thrust, skip="" if source_of(opt.source).load_cell else "thrust_gain")


def surface(opt: MapInputs, f: Any, v: Any, model_sigma: Any = 0.0) -> Surface:
    """The corrected model times the residual process's correction, with the demand's bound:
    the true thrust less ``z`` times the map's uncertainty (the residual process's, and the
    model's own, ``model_sigma``, from :func:`model_sigma`)."""
    f, v = np.broadcast_arrays(np.asarray(f, float), np.asarray(v, float))
    r = opt.correction.response(opt.fin, f, v)
    mean, var = opt.gp.predict(f, v)
    shape = f.shape
    m_t, m_p = mean[:, 0].reshape(shape), mean[:, -1].reshape(shape)
    s_t, s_p = np.sqrt(var[:, 0]).reshape(shape), np.sqrt(var[:, -1]).reshape(shape)
    thrust = r.thrust_n * np.exp(m_t)
    # the truth's margin (the map's uncertainty), and where a trial there will count (evidence):
    # its estimate less z times its noise and calibration must meet the demand, which one more
    # sigma of the noise makes likely (84 %) for the trial that confirms the point
    noise_t, _ = opt.problem.measurement_noise(thrust, 1.0)
    bound = np.nan_to_num(opt.self_sensing_bound) / 2.0
    truth = opt.demand_margin_z * np.sqrt(s_t**2 + np.asarray(model_sigma) ** 2)
    count_margin = opt.demand_margin_z * np.hypot(noise_t, bound) + noise_t
    low = thrust * np.exp(-np.maximum(truth, count_margin))
    power = r.power_w * np.exp(m_p)
    if not watt_of(opt.watt).is_fin and r.current_rms is not None and r.voltage_pp is not None:
        named = power_in(opt.watt, r.voltage_pp, r.current_rms, power, opt.amplifier)
        return Surface(f, v, thrust, named, low, s_t, s_p, power)
    return Surface(f, v, thrust, power, low, s_t, s_p)


def frontier(opt: MapInputs, f: FloatArray) -> tuple[Surface, FloatArray]:
    """At each frequency, the point the task asks for: the configured voltage (no demand), or
    the least voltage whose thrust meets the demand with the margin.  Also: feasible there."""
    lim = opt.limits
    if opt.demand_n is None:
        v = np.full_like(f, min(max(opt.voltage_pp, lim.voltage_pp_min), lim.voltage_pp_max))
        s = surface(opt, f, v, model_sigma(opt, f, v))
        return s, s.thrust_low_n >= opt.min_thrust_n  # (the least thrust, with the margin too)
    vmax = np.full_like(f, lim.voltage_pp_max)
    # the model's uncertainty in log thrust, taken at full voltage for every voltage of a frequency
    # (it barely changes with V, and a bisection that re-derived it would cost 8 maps a step)
    sigma = model_sigma(opt, f, vmax)
    top = surface(opt, f, vmax, sigma)
    feasible = top.thrust_low_n >= opt.demand_n
    lo, hi = np.full_like(f, lim.voltage_pp_min), vmax.copy()
    for _ in range(24):  # bisection on V (to 0.5 mV): T increases with V at every f
        mid = 0.5 * (lo + hi)
        ok = surface(opt, f, mid, sigma).thrust_low_n >= opt.demand_n
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
    return surface(opt, f, np.where(feasible, hi, lim.voltage_pp_max), sigma), feasible


def best(opt: MapInputs, s: Surface, feasible: FloatArray, optimism: float = 0.0) -> Choice:
    """The best frontier point (the most thrust if none is feasible); ``optimism``: plus that many
    standard deviations of the map's log thrust per watt."""
    if not np.any(feasible):
        i = int(np.argmax(s.thrust_n))
        feasible_here = False
    else:
        score = s.objective(opt.demand_n, opt.objective) * np.exp(
            optimism * np.hypot(s.sigma_thrust, s.sigma_power)
        )
        i = int(np.argmax(np.where(feasible, score, -np.inf)))
        feasible_here = True
    return Choice(
        float(s.frequency_hz[i]),
        float(s.voltage_pp[i]),
        float(s.thrust_n[i]),
        float(s.power_w[i]),
        feasible_here,
    )


def gain(opt: MapInputs, here: tuple[float, float], there: tuple[float, float]) -> float:
    """The map's relative gain in the task's objective from ``here`` to ``there`` (both on the map,
    so that the map's bias cancels; with a demand, where both meet it, the power's ratio)."""
    s = surface(opt, np.array([here[0], there[0]]), np.array([here[1], there[1]]))
    obj = s.objective(opt.demand_n, opt.objective)
    return float(obj[1] / max(float(obj[0]), 1e-300) - 1.0)
