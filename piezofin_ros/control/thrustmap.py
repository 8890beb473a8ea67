"""The map: the corrected model times the residual process's correction over the operating box,
with the demand's margin; the frontier the task asks for at each frequency, and its best point.

Each function reads what :class:`MapInputs` names of the optimiser (its fit, residual process, task
and watt) and changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
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
    #: the ``voltage_pp_max`` configured, while :meth:`capped` holds it lower (0: not capped)
    voltage_pp_uncapped: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.frequency_min_hz, self.frequency_max_hz, self.voltage_pp_min, self.voltage_pp_max)
        if not all(math.isfinite(x) and x > 0 for x in vals):
            raise ControlError(f"limits must be finite and > 0, got {vals}")
        if self.frequency_min_hz >= self.frequency_max_hz or self.voltage_pp_min >= self.voltage_pp_max:
            raise ControlError("limits: each minimum must be below its maximum")
        uncapped = self.voltage_pp_uncapped
        if uncapped != 0.0 and not self.voltage_pp_max <= uncapped <= HARD_VOLTAGE_PP_MAX:
            raise ControlError(
                f"limits: voltage_pp_uncapped {uncapped!r} must be 0 or in [voltage_pp_max, hard cap]"
            )
        if self.voltage_pp_max > HARD_VOLTAGE_PP_MAX:
            raise ControlError(
                f"voltage_pp_max {self.voltage_pp_max} V exceeds the hard cap {HARD_VOLTAGE_PP_MAX} V"
            )

    def capped(self, voltage_pp: float | None) -> OperatingBox:
        """The box as configured with its voltage capped at ``voltage_pp`` (None or NaN: the box as
        configured), never below twice its least voltage."""
        top = self.voltage_pp_uncapped or self.voltage_pp_max
        if voltage_pp is None or math.isnan(voltage_pp) or voltage_pp >= top:
            return replace(self, voltage_pp_max=top, voltage_pp_uncapped=0.0)
        cap = max(float(voltage_pp), min(2.0 * self.voltage_pp_min, top))
        return replace(self, voltage_pp_max=cap, voltage_pp_uncapped=top)

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


#: Frequencies in the table of the model's uncertainty at one voltage (the first map's grid,
#: ``Tuning.n_grid``: there the table is the value itself; between, a 2 % step in frequency).
SIGMA_TABLE_POINTS = 160


def tabled_sigma(opt: MapInputs, f: FloatArray, voltage_pp: float) -> FloatArray:
    """:func:`model_sigma` at one voltage, interpolated in log frequency from a table over the
    box's band made once per fit and voltage.  The frontier asks for it at every demand (a fish's
    speed loop sends one every few seconds) and at each of its three maps: derived anew each time,
    it was most of a map's cost (9 parameters' differences of the model on every grid)."""
    lim = opt.limits
    key = ("sigma", lim, float(voltage_pp), opt.source, id(opt.fin))
    table = opt.fit.derived.get(key)
    if table is None:
        grid = np.geomspace(lim.frequency_min_hz, lim.frequency_max_hz, SIGMA_TABLE_POINTS)
        sigma = model_sigma(opt, grid, np.full_like(grid, voltage_pp))
        table = opt.fit.derived[key] = (np.log(grid), np.asarray(sigma, float), opt.fin)
    log_f, sigma, _ = table  # (the fin kept with its id, so the id is never another's)
    return np.interp(np.log(np.asarray(f, float)), log_f, sigma)


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


#: The halvings of the operating box's voltage range that place the frontier's voltage (to 0.5 mV).
BISECTIONS = 24


def frontier(opt: MapInputs, f: FloatArray) -> tuple[Surface, FloatArray]:
    """At each frequency, the point the task asks for: the configured voltage (no demand), or
    the least voltage whose thrust meets the demand with the margin.  Also: feasible there."""
    lim = opt.limits
    if opt.demand_n is None:
        at = min(max(opt.voltage_pp, lim.voltage_pp_min), lim.voltage_pp_max)
        s = surface(opt, f, np.full_like(f, at), tabled_sigma(opt, f, at))
        return s, s.thrust_low_n >= opt.min_thrust_n  # (the least thrust, with the margin too)
    vmax = np.full_like(f, lim.voltage_pp_max)
    # the model's uncertainty in log thrust, taken at full voltage for every voltage of a frequency
    # (it barely changes with V, and a search that re-derived it would cost 8 maps a step)
    sigma = tabled_sigma(opt, f, lim.voltage_pp_max)
    demand = float(opt.demand_n)

    def gap(at: FloatArray, v: FloatArray) -> FloatArray:  # log(thrust with the margin / demand)
        low = surface(opt, f[at], v, sigma[at]).thrust_low_n
        return np.log(np.maximum(low, 1e-300) / demand)

    def meets(v: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:  # (both in one map)
        ok = surface(opt, np.tile(f, 2), np.concatenate([v, w]), np.tile(sigma, 2)).thrust_low_n >= demand
        return ok[: f.size], ok[f.size :]

    g_top = gap(np.ones(f.shape, bool), vmax)
    feasible = g_top >= 0.0
    v_min, step = lim.voltage_pp_min, (lim.voltage_pp_max - lim.voltage_pp_min) / 2**BISECTIONS
    v = least_root(gap, feasible, v_min, lim.voltage_pp_max, g_top, tol=0.5 * step / lim.voltage_pp_max)
    # on the grid a bisection of 24 halvings answered on (to 0.5 mV at 800 V): the least grid point
    # that meets the demand, as it found it, so that the map's choice is the same as before; where the
    # objective is flat (the nominal model in the fin's watt: thrust and power both as (w A)^2),
    # rounding at the 1e-9 level chose among equal points, and a moved rounding moved the choice
    k = np.clip(np.ceil((v - v_min) / step), 1, 2**BISECTIONS)
    for _ in range(8):  # (once or twice: the root is within half a step)
        k = np.where(feasible, k, 2**BISECTIONS)
        here, below = meets(v_min + k * step, v_min + np.maximum(k - 1, 1) * step)
        up, down = feasible & ~here, feasible & here & below & (k > 1)
        if not (np.any(up) or np.any(down)):
            break
        k = k + up - down
    return surface(opt, f, np.where(feasible, v_min + k * step, lim.voltage_pp_max), sigma), feasible


def least_root(
    gap: Any, where: Any, v_min: float, v_max: float, g_max: FloatArray, tol: float = 1e-7
) -> FloatArray:
    """Per element ``where``, the least ``v`` in ``[v_min, v_max]`` at which ``gap(at, v) >= 0``, for
    a ``gap`` that rises with ``v`` (the log of the thrust over the demand) and is ``>= 0`` at
    ``v_max`` (``g_max``); ``v_max`` elsewhere.  Regula falsi in log V with the Illinois rule,
    started from thrust as V squared: the log-log line is nearly straight, so a handful of maps
    where a bisection took 24; a bisection step wherever two points did not halve the bracket (a
    law with a kink at its root), so at worst a third of a bisection's rate.  The answer is always a
    voltage seen to meet the demand, within ``tol`` (relative) of the least that does."""
    out = np.full(g_max.shape, v_max, float)
    idx = np.flatnonzero(where)
    if idx.size == 0:
        return out
    at = np.zeros(g_max.shape, bool)
    at[idx] = True
    g_lo = gap(at, np.full(idx.size, v_min))
    done = g_lo >= 0.0  # (the least voltage meets it already)
    out[idx[done]] = v_min
    idx, g_lo = idx[~done], g_lo[~done]
    x_lo, x_hi = np.full(idx.size, math.log(v_min)), np.full(idx.size, math.log(v_max))
    g_hi = g_max[idx]
    x = x_hi - 0.5 * g_hi  # (thrust as V squared: the first guess)
    last = np.zeros(idx.size, int)  # the end the last point replaced: +1 the high, -1 the low
    width = np.full((2, idx.size), np.inf)  # the bracket's width one and two points ago
    for _ in range(60):
        if idx.size == 0:
            break
        # a bisection where two points did not halve the bracket (a law with a kink at its root)
        x = np.where(x_hi - x_lo > 0.5 * width[1], 0.5 * (x_lo + x_hi), x)
        width = np.stack([x_hi - x_lo, width[0]])
        x = np.clip(x, x_lo + 0.01 * (x_hi - x_lo), x_hi - 0.01 * (x_hi - x_lo))
        at = np.zeros(g_max.shape, bool)
        at[idx] = True
        g = gap(at, np.exp(x))
        up = g >= 0.0
        # the new point replaces the end on its side; the other end, kept twice, has its gap halved
        g_lo = np.where(up & (last == 1), 0.5 * g_lo, g_lo)
        g_hi = np.where(~up & (last == -1), 0.5 * g_hi, g_hi)
        x_hi, g_hi = np.where(up, x, x_hi), np.where(up, g, g_hi)
        x_lo, g_lo = np.where(up, x_lo, x), np.where(up, g_lo, g)
        last = np.where(up, 1, -1)
        settled = (x_hi - x_lo < tol) | (up & (g < tol))  # (thrust rises faster than the voltage)
        out[idx[settled]] = np.exp(x_hi[settled])
        keep = ~settled
        idx, x_lo, x_hi, g_lo, g_hi, last = (a[keep] for a in (idx, x_lo, x_hi, g_lo, g_hi, last))
        width = width[:, keep]
        x = x_hi - g_hi * (x_hi - x_lo) / (g_hi - g_lo)
    out[idx] = np.exp(x_hi)  # (not settled in 60 maps: the least seen to meet it)
    return out


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
