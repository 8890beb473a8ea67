r"""Thrust-per-watt optimiser: the model's map, corrected by what the fin measures.

The problem
-----------
Choose the drive frequency ``f`` and peak-to-peak voltage ``V`` within :class:`OperatingBox`:

* with a thrust demand ``D``: deliver ``T(f, V) >= D`` with the least electrical power (the most
  thrust per watt at that thrust).  ``T`` increases strictly with ``V`` at any ``f`` (a property
  the tests check on the model), so for every ``f`` the least voltage ``V*(f)`` that gives ``D`` is
  found by bisection and the search is one-dimensional: ``min_f P(f, V*(f))``;
* without a demand: the paper's convention, the frequency of the highest thrust per watt at the
  configured voltage, among frequencies that give at least ``min_thrust_n`` (default 1 mN: without
  it the nominal model's optimum is the lowest frequency, where thrust and power are both a few
  micro-units and the power is below the current monitor's noise);
* when ``D`` cannot be met within the limits: the most thrust available, flagged infeasible.

How it learns
-------------
The map comes from the harmonic balance of the fin model, through a *correction*: five
parameters a real fin changes (:class:`Correction`): the resonance (``resonance_scale``), its
fall with drive voltage (``softening``, electroelastic), the drag coefficient (``drag_scale``), a
dielectric loss ``P += (1/2) tan(delta) C_eq w (V/2)^2`` and a thrust gain.  After each trial
the correction is fitted to the measurements (log thrust and log power, weighted by the
measurement noise) with weak priors around the nominal fin, so one trial already moves the map
and the fit stays well posed.  The next trial goes to the corrected map's optimum; when that
optimum stops moving (within ``tolerance``) the point is held, and every ``probe_every`` trials
a probe at ``f (1 +- probe_step)`` keeps the fit informed.  A measurement more than
``change_sigma`` off the fit's prediction means the fin has changed (drift, temperature, a new
load): the older measurements are dropped and the fit starts again from the latest, so a
drifting fin is followed without a restart.

With ``model`` (an :class:`~piezofin_ros.physics.model.Model` model saved by ``piezofin
diagnose``) the map starts from the diagnosed model instead of the paper's: its fin and effects,
with the same five corrections applied on top as effects of the same library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from ..config import HARD_VOLTAGE_PP_MAX
from ..errors import ControlError
from ..physics.effects import DielectricLoss, DragOffset, Electroelastic, ResonanceOffset
from ..physics.fin import Fin
from ..physics.model import Model
from .plants import EstimateNoise, PlantResponse

FloatArray = NDArray[Any]


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
class Correction:
    """How the real fin differs from the model (1/0 = the nominal model): four effects of the one
    library fitted on top of the base model, and a thrust gain (estimate over model)."""

    resonance_scale: float = 1.0
    softening: float = 0.0
    drag_scale: float = 1.0
    loss_tan_delta: float = 0.0
    thrust_gain: float = 1.0

    base: Model | None = None  # a diagnosed model (fin + effects) the correction applies on top of

    def fitted(self) -> dict[str, float]:
        """The five fitted numbers (for a status message: plain JSON, without the base model)."""
        return {f.name: float(getattr(self, f.name)) for f in fields(self) if f.name != "base"}

    def model(self, fin: Fin) -> Model:
        """The base model (``fin`` without one) plus the correction's effects."""
        base = self.base if self.base is not None else Model(fin)
        return (
            base
            + ResonanceOffset(self.resonance_scale)
            + Electroelastic(self.softening)
            + DragOffset(self.drag_scale)
            + DielectricLoss(self.loss_tan_delta)
        )

    def response(self, fin: Fin, f: Any, v: Any) -> PlantResponse:
        # (the load-cell effects of a base describe the rig, not the fin: the thrust is Lighthill's)
        p = self.model(fin).predict(f, v)
        return PlantResponse(p.thrust_n * self.thrust_gain, p.power_w, p.tip_velocity_rms)


# (vector -> Correction) with log parameters where a scale is positive; priors (mean, sigma).
_PRIOR_MEAN = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
_PRIOR_SIGMA = np.array([0.3, 0.3, 0.7, 0.3, 0.3])
# (inside the library's bounds of each effect: exp(log(x)) may round across them)
_LOWER = np.array([math.log(0.3) + 1e-12, 0.0, math.log(0.1), 0.0, math.log(0.2)])
_UPPER = np.array([math.log(2.0) - 1e-12, 0.8, math.log(10.0), 0.5, math.log(5.0)])


def _correction(x: FloatArray, base: Model | None = None) -> Correction:
    return Correction(math.exp(x[0]), float(x[1]), math.exp(x[2]), float(x[3]), math.exp(x[4]), base)


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


def best_point(
    fin: Fin,
    correction: Correction,
    limits: OperatingBox,
    demand_n: float | None,
    voltage_pp: float,
    min_thrust_n: float = 1e-3,
    n_grid: int = 160,
) -> Choice:
    """The optimum of the corrected map (see the module docstring)."""
    f = np.geomspace(limits.frequency_min_hz, limits.frequency_max_hz, n_grid)
    if demand_n is None:
        v = min(max(voltage_pp, limits.voltage_pp_min), limits.voltage_pp_max)
        r = correction.response(fin, f, v)
        ok = r.thrust_n >= min_thrust_n
        if not np.any(ok):
            i = int(np.argmax(r.thrust_n))
            return Choice(float(f[i]), v, float(r.thrust_n[i]), float(r.power_w[i]), False)
        i = int(np.argmax(np.where(ok, r.thrust_per_watt, -np.inf)))
        lo, hi = f[max(i - 1, 0)], f[min(i + 1, n_grid - 1)]

        def negative_tpw(x: float) -> float:
            rx = correction.response(fin, x, v)
            return -float(rx.thrust_per_watt) if float(rx.thrust_n) >= min_thrust_n else 0.0

        res = optimize.minimize_scalar(
            negative_tpw, bounds=(lo, hi), method="bounded", options={"xatol": 1e-3 * lo}
        )
        fb = float(res.x) if -res.fun >= r.thrust_per_watt[i] else float(f[i])
        rb = correction.response(fin, fb, v)
        return Choice(fb, v, float(rb.thrust_n), float(rb.power_w), True)
    vmax = correction.response(fin, f, limits.voltage_pp_max)
    feasible = vmax.thrust_n >= demand_n
    if not np.any(feasible):
        i = int(np.argmax(vmax.thrust_n))
        return Choice(
            float(f[i]), limits.voltage_pp_max, float(vmax.thrust_n[i]), float(vmax.power_w[i]), False
        )
    lo = np.full_like(f, limits.voltage_pp_min)
    hi = np.full_like(f, limits.voltage_pp_max)
    for _ in range(40):  # bisection on V: T increases with V at every f
        mid = 0.5 * (lo + hi)
        ok = correction.response(fin, f, mid).thrust_n >= demand_n
        hi = np.where(ok, mid, hi)
        lo = np.where(ok, lo, mid)
    r = correction.response(fin, f, hi)
    power = np.where(feasible, r.power_w, np.inf)
    i = int(np.argmin(power))
    return Choice(float(f[i]), float(hi[i]), float(r.thrust_n[i]), float(r.power_w[i]), True)


@dataclass(frozen=True)
class Observation:
    t: float
    frequency_hz: float
    voltage_pp: float
    thrust_n: float
    power_w: float


@dataclass
class Optimiser:
    """Propose operating points, learn from their estimates; pure Python (the node drives it)."""

    fin: Fin
    limits: OperatingBox = field(default_factory=OperatingBox)
    voltage_pp: float = 800.0  # the configured voltage (no demand)
    demand_n: float | None = None
    min_thrust_n: float = 1e-3  # without a demand: the least thrust worth having
    demand_margin: float = 0.005  # aim this much above the demand, so noise and drift rarely miss it
    noise: EstimateNoise = field(default_factory=EstimateNoise)
    memory_s: float = 300.0  # forget measurements older than this
    change_sigma: float = 3.0  # a measurement this many sigma off the fit means the fin changed
    changes: int = 0
    tolerance: float = 0.02
    probe_every: int = 4
    probe_step: float = 0.06
    observations: list[Observation] = field(default_factory=list)
    correction: Correction = field(default_factory=Correction)
    choice: Choice | None = None
    converged: bool = False
    model: Model | None = None  # a diagnosed model: its fin and effects replace ``fin``
    _held: int = 0
    _probe_sign: float = 1.0

    def __post_init__(self) -> None:
        if self.model is not None:
            self.fin = self.model.fin
            self.correction = replace(self.correction, base=self.model)
        self.choice = best_point(
            self.fin, self.correction, self.limits, self._target(), self.voltage_pp, self.min_thrust_n
        )

    def _target(self) -> float | None:
        return None if self.demand_n is None else self.demand_n * (1.0 + self.demand_margin)

    def set_demand(self, demand_n: float | None) -> None:
        """A new demand (None or <= 0: none).  Non-finite values are ignored."""
        if demand_n is not None and not math.isfinite(demand_n):
            return
        self.demand_n = demand_n if demand_n is not None and demand_n > 0 else None
        self.converged = False
        self._update()

    def observe(
        self, t: float, frequency_hz: float, voltage_pp: float, thrust_n: float, power_w: float
    ) -> bool:
        """Add one trial's estimate; False (and ignored) if it is not usable."""
        values = (t, frequency_hz, voltage_pp, thrust_n, power_w)
        if not all(math.isfinite(x) for x in values) or thrust_n <= 0 or power_w <= 0 or voltage_pp <= 0:
            return False
        new = Observation(*values)
        if len(self.observations) >= 3 and self._surprise(new) > self.change_sigma:
            # The fin no longer behaves as fitted (drift, a new load): keep only the latest evidence.
            self.observations = self.observations[-1:]
            self.changes += 1
        self.observations.append(new)
        recent = [o for o in self.observations if o.t >= t - self.memory_s]
        self.observations = recent or self.observations[-2:]
        self._update()
        return True

    def _sigmas(self, thrust_n: Any, power_w: Any) -> tuple[Any, Any]:
        """Noise of log thrust and log power (relative + absolute floor) plus 2 % model error."""
        n = self.noise
        sig_t = np.hypot(n.thrust_rel, n.thrust_abs_n / np.asarray(thrust_n)) + 0.02
        sig_p = np.hypot(n.power_rel, n.power_abs_w / np.asarray(power_w)) + 0.02
        return sig_t, sig_p

    def _surprise(self, o: Observation) -> float:
        """How far (in sigma) a new measurement lies from the current fit's prediction."""
        r = self.correction.response(self.fin, o.frequency_hz, o.voltage_pp)
        sig_t, sig_p = self._sigmas(o.thrust_n, o.power_w)
        dt = abs(math.log(o.thrust_n / max(float(r.thrust_n), 1e-300))) / float(sig_t)
        dp = abs(math.log(o.power_w / max(float(r.power_w), 1e-300))) / float(sig_p)
        return max(dt, dp)

    def _fit(self) -> Correction:
        obs = self.observations
        if not obs:
            return Correction(base=self.model)
        f = np.array([o.frequency_hz for o in obs])
        v = np.array([o.voltage_pp for o in obs])
        lt = np.log([o.thrust_n for o in obs])
        lp = np.log([o.power_w for o in obs])
        sig_t, sig_p = self._sigmas(np.exp(lt), np.exp(lp))

        def residuals(x: FloatArray) -> FloatArray:
            r = _correction(x, self.model).response(self.fin, f, v)
            with np.errstate(divide="ignore"):
                rt = (lt - np.log(np.maximum(r.thrust_n, 1e-300))) / sig_t
                rp = (lp - np.log(np.maximum(r.power_w, 1e-300))) / sig_p
            return np.concatenate([rt, rp, (x - _PRIOR_MEAN) / _PRIOR_SIGMA])

        c = self.correction
        x = [
            math.log(c.resonance_scale),
            c.softening,
            math.log(c.drag_scale),
            c.loss_tan_delta,
            math.log(c.thrust_gain),
        ]
        x0 = np.clip(x, _LOWER + 1e-9, _UPPER - 1e-9)
        best = None
        for start in (x0, np.zeros(5)):  # warm start, and the nominal model in case it is a better basin
            res = optimize.least_squares(residuals, start, bounds=(_LOWER, _UPPER), x_scale=_PRIOR_SIGMA)
            if best is None or res.cost < best.cost:
                best = res
        assert best is not None
        return _correction(best.x, self.model)

    def _update(self) -> None:
        self.correction = self._fit()
        new = best_point(
            self.fin, self.correction, self.limits, self._target(), self.voltage_pp, self.min_thrust_n
        )
        old = self.choice
        self.choice = new
        last = self.observations[-1] if self.observations else None
        near_last = last is not None and _close(new, last.frequency_hz, last.voltage_pp, self.tolerance)
        if near_last and old is not None and _close(new, old.frequency_hz, old.voltage_pp, self.tolerance):
            self.converged = True
        elif not near_last:
            self.converged = False

    def propose(self) -> tuple[float, float]:
        """The next operating point to drive (always inside the limits)."""
        assert self.choice is not None
        c = self.choice
        f, v = c.frequency_hz, c.voltage_pp
        if self.converged:
            self._held += 1
            if self.probe_every and self._held % self.probe_every == 0:
                self._probe_sign = -self._probe_sign
                f = f * (1 + self._probe_sign * self.probe_step)
        return self.limits.clamp(f, v)

    def status(self) -> dict[str, Any]:
        c = self.choice
        assert c is not None
        return {
            "converged": self.converged,
            "feasible": c.feasible,
            "demand_n": self.demand_n,
            "frequency_hz": c.frequency_hz,
            "voltage_pp": c.voltage_pp,
            "predicted_thrust_n": c.thrust_n,
            "predicted_power_w": c.power_w,
            "correction": self.correction.fitted(),
            "observations": len(self.observations),
        }


def _close(c: Choice, f: float, v: float, tol: float) -> bool:
    return abs(c.frequency_hz - f) <= tol * f and abs(c.voltage_pp - v) <= tol * max(v, 1.0)
