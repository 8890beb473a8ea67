"""The corrected model's fit to the trials: what each trial measured, its noise, the weighted
misfit, and the frozen result with its covariance.

:class:`FitProblem` is what the optimiser knows when it fits (the fin, the noise of the estimates,
the estimate's source, the prior); :meth:`FitProblem.fit` returns a :class:`Fit`, frozen, whose
:meth:`Fit.sigma` propagates the parameters' covariance to any quantity of the corrected model.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..estimation.estimator import source_of
from ..estimation.selfsense import lighthill_thrust, self_sensed_tip
from ..physics.fin import Fin
from ..physics.model import Model
from .correction import (
    INDEX,
    LOWER,
    PARAMS,
    PRIOR_SIGMA,
    UPPER,
    Correction,
    FloatArray,
    correction_of,
    jacobian,
    vector_of,
)
from .evidence import Observation, same_point
from .lsq import Solution, least_squares
from .response import EstimateNoise
from .tuning import Tuning

#: ``solve(fun, x0, lower, upper, scale, max_nfev)``: a bounded least-squares solver
Residuals = Callable[[FloatArray], FloatArray]
Solver = Callable[[Residuals, FloatArray, FloatArray, FloatArray, FloatArray, int], Solution]

#: Relative model error weighed into the fit beside the measurement noise (the map is a model).
MODEL_ERROR = 0.02


@dataclass(frozen=True)
class Fit:
    """A fitted correction, the covariance of its parameters (``None`` before any trial, or where
    the information is singular), its reduced chi-square as weighed (with the model error) and
    against the measurement noise alone."""

    correction: Correction
    covariance: FloatArray | None = None
    chi2: float = 0.0
    chi2_noise: float = 0.0
    #: how far the fitted parameters lie from the prior's, in its sigmas squared and summed (the
    #: penalty the fit paid beside its misfit)
    prior_cost: float = 0.0
    #: what the map derives from this fit alone, made once per fit and kept with it
    #: (:func:`.thrustmap.tabled_sigma`'s tables; never passed on: a fit made from this one, by
    #: ``dataclasses.replace``, starts without them)
    derived: dict[Any, Any] = field(default_factory=dict, init=False, compare=False, repr=False)

    def sigma(self, log_value: Callable[[Correction], FloatArray], skip: str = "") -> FloatArray:
        """Standard deviation of ``log_value(correction)`` from the parameters' covariance (first
        order: finite differences in each parameter but ``skip``; 0 before the first fit)."""
        base = np.asarray(log_value(self.correction), float)
        if self.covariance is None:
            return np.zeros(base.shape)
        grad = jacobian(
            lambda xk: np.asarray(log_value(correction_of(xk, self.correction.base)), float),
            vector_of(self.correction),
            1e-4 * PRIOR_SIGMA,
            base,
            skip=tuple(p.name == skip for p in PARAMS),
        )
        var = np.einsum("...i,ij,...j->...", grad, self.covariance, grad)
        return np.asarray(np.sqrt(np.maximum(var, 0.0)))


@dataclass(frozen=True)
class FitProblem:
    """What the fit knows: the fin, the estimates' noise, their source (``vibrometer``, ``self``,
    ``loadcell``), the base model the correction applies on (``None``: the fin file's) and, on a
    fish, how far the stiffness may move from the fin file's (log sigma)."""

    fin: Fin
    noise: EstimateNoise
    source: str
    stiffness_sigma: float
    base: Model | None = None

    # --- noise ----------------------------------------------------------------------------------
    def measurement_noise(self, thrust_n: Any, power_w: Any) -> tuple[Any, Any]:
        """Measurement noise of log thrust and log power (relative + absolute floor)."""
        n = self.noise
        return (
            np.hypot(n.thrust_rel, n.thrust_abs_n / np.asarray(thrust_n)),
            np.hypot(n.power_rel, n.power_abs_w / np.asarray(power_w)),
        )

    def thrust_noise(self, c: Correction, obs: Sequence[Observation], thrust: FloatArray) -> FloatArray:
        """Noise of each trial's log thrust estimate: the estimate's own, and for a self-sensed one the
        admittance's noise magnified by the ratio of the whole current to its motional part."""
        power = np.array([o.power_w for o in obs])
        noise, noise_p = self.measurement_noise(np.maximum(thrust, 1e-300), power)
        noise = np.array(noise, float, ndmin=1)
        noise_p = np.array(noise_p, float, ndmin=1)
        for k, o in enumerate(obs):
            if o.self_sensed:
                cal = c.calibration(self.fin, o.frequency_hz, o.drive_vpp)
                w = 2 * math.pi * o.frequency_hz
                y = o.admittance
                m = y - complex(float(cal.conductance_s), w * self.fin.C_eq * float(cal.capacitance))
                # the thrust goes as |m|^2: its log moves by 2 (Re m dG + Im m dB) / |m|^2, where the
                # conductance is the power's (2 P / V^2, the power's noise) and the susceptance the
                # admittance's own
                d_g = float(noise_p[k]) * abs(y.real)
                d_b = self.noise.admittance_rel * abs(y)
                spread = 2.0 * math.hypot(m.real * d_g, m.imag * d_b) / max(abs(m) ** 2, 1e-300)
                noise[k] = math.hypot(noise[k], spread)
        return noise

    def repeat_disagreement(
        self, correction: Correction, observations: Sequence[Observation], o: Observation
    ) -> float:
        """How far (in sigma of the trials' noise) a new trial at an operating point already measured
        lies from the earlier trials there: the model-free sign that the fin changed (0 if none)."""
        same = [q for q in observations if same_point(q, o)]
        if not same:
            return 0.0
        both = [*same, o]
        thrust = self.thrust_estimates(correction, both)
        noise_t = self.thrust_noise(correction, both, thrust)
        power = np.array([q.power_w for q in both])
        _, noise_p = self.measurement_noise(thrust, power)
        out = 0.0
        for y, sd in ((np.log(thrust), noise_t), (np.log(power), np.asarray(noise_p, float))):
            earlier = float(np.mean(y[:-1]))
            spread = math.sqrt(float(sd[-1]) ** 2 + float(np.mean(sd[:-1] ** 2)) / len(same))
            out = max(out, abs(float(y[-1]) - earlier) / spread)
        return out

    # --- what the trials say ----------------------------------------------------------------------
    def thrust_estimates(self, c: Correction, obs: Sequence[Observation]) -> FloatArray:
        """Each trial's thrust, re-estimated with the correction: the self-sensed thrust from the
        admittance with the fitted calibration, Lighthill's with the fitted ``c_m``, the load cell's
        as read."""
        out = np.array([o.thrust_n for o in obs], float)
        selfs = [k for k, o in enumerate(obs) if o.self_sensed]
        lighthill = [k for k, o in enumerate(obs) if not (o.load_cell or o.self_sensed)]
        out[lighthill] *= c.added_mass  # (Lighthill's with the base fin's c_m: the fitted one's)
        if selfs:
            f = np.array([obs[k].frequency_hz for k in selfs])
            v_amp = 0.5 * np.array([obs[k].drive_vpp for k in selfs])
            y = np.array([obs[k].admittance for k in selfs])
            cal = c.calibration(self.fin, f, 2 * v_amp)
            tip = self_sensed_tip(self.fin, y * v_amp, v_amp, 2 * math.pi * f, cal)
            out[selfs] = lighthill_thrust(self.fin, np.abs(tip) / math.sqrt(2), cal, f)
        return out

    def residuals(
        self, c: Correction, obs: Sequence[Observation], model_error: float = MODEL_ERROR
    ) -> FloatArray:
        """Each trial's misfit in noise units: log power, the thrust reading (vibrometer: Lighthill
        with the base fin's ``c_m``; load cell: as read) and the admittance's susceptance, each at
        the voltage the fin got (the correction is the fin's; an amplifier that clips is the residual
        process's, on the commanded map)."""
        f = np.array([o.frequency_hz for o in obs])
        v = np.array([o.drive_vpp for o in obs])
        t_meas = np.array([o.thrust_n for o in obs])
        p_meas = np.array([o.power_w for o in obs])
        pred = c.predict(self.fin, f, v)
        sig_t, sig_p = self.measurement_noise(t_meas, p_meas)
        with np.errstate(divide="ignore", invalid="ignore"):
            rp = (np.log(p_meas) - np.log(np.maximum(pred.power_w, 1e-300))) / (sig_p + model_error)
            reading = np.where(
                [o.load_cell for o in obs],
                pred.thrust_n * c.thrust_gain,
                pred.thrust_n / c.added_mass,
            )
            rt = (np.log(t_meas) - np.log(np.maximum(reading, 1e-300))) / (sig_t + model_error)
        rt = np.where([o.self_sensed for o in obs], 0.0, rt)
        y = np.array([o.admittance for o in obs])
        has_y = np.array([o.has_admittance for o in obs])
        rb = np.zeros(len(obs))
        if np.any(has_y):
            assert pred.admittance is not None
            b_pred = np.imag(pred.admittance)
            rb[has_y] = (y[has_y].imag - b_pred[has_y]) / (
                (self.noise.admittance_rel + model_error / 4) * np.abs(y[has_y]) + 1e-12
            )
        return np.concatenate([rt, rp, rb])

    # --- the fit ----------------------------------------------------------------------------------
    @property
    def prior_sigma(self) -> FloatArray:
        """The priors' widths; on a fish the stiffness is the fin file's (``stiffness_sigma``)."""
        sigma = PRIOR_SIGMA.copy()
        if source_of(self.source).self_sensed:
            sigma[INDEX["resonance_scale"]] = self.stiffness_sigma
        else:
            # a leak is fitted on a fish, where its current would read as motion; with a vibrometer or
            # a load cell it moves only the power, and fitted there it let three M8528-P1 plants'
            # maps (drag or coupling off the correction's family) hold points 2-3 % short of the
            # demand in truth (`bench_unseen.py --watt supply_measured`): held at none
            sigma[INDEX["leakage_us"]] = 1e-6
        return sigma

    def fit(self, obs: Sequence[Observation], start: Correction, solve: Solver = least_squares) -> Fit:
        """The correction that fits ``obs`` best under the priors, from ``start`` (and early, with
        four trials or fewer, from the nominal fin too: its basin may be the right one); ``solve``
        is the bounded least-squares solver (:func:`.lsq.least_squares`; the tests pass scipy's)."""
        if not obs:
            return Fit(Correction(base=self.base))
        prior = self.prior_sigma

        def residuals(x: FloatArray) -> FloatArray:
            return np.concatenate([self.residuals(correction_of(x, self.base), obs), x / prior])

        x0 = np.clip(vector_of(start), LOWER, UPPER)
        starts = [x0] if len(obs) > 4 else [x0, np.clip(np.zeros(len(PARAMS)), LOWER, UPPER)]
        best = None
        for x in starts:
            res = solve(residuals, x, LOWER, UPPER, prior, 200)
            if best is None or res.cost < best.cost:
                best = res
        assert best is not None
        n_data = data_points(obs)
        chi2 = float(np.sum(np.asarray(best.fun)[: 3 * len(obs)] ** 2)) / max(n_data, 1)
        covariance, chi2_noise = self._covariance(best.x, obs, n_data)
        prior_cost = float(np.sum((np.asarray(best.x, float) / prior) ** 2))
        return Fit(correction_of(best.x, self.base), covariance, chi2, chi2_noise, prior_cost)

    def _covariance(
        self, x: FloatArray, obs: Sequence[Observation], n_data: int
    ) -> tuple[FloatArray | None, float]:
        """The fitted parameters' covariance against the measurement noise alone (the fit weighs in
        a model error too, which would inflate it), scaled up by the reduced chi-square when the
        trials scatter more than the noise (a model outside the correction's family); and that
        chi-square (the model's misfit, which a fish's calibration bound counts)."""
        prior = self.prior_sigma

        def weighted(xx: FloatArray) -> FloatArray:
            misfit = self.residuals(correction_of(xx, self.base), obs, 0.0)
            return np.concatenate([misfit, xx / prior])

        r0 = weighted(x)
        jac = jacobian(weighted, x, 1e-5 * PRIOR_SIGMA, r0)
        chi2 = float(np.sum(r0[: 3 * len(obs)] ** 2)) / max(n_data, 1)
        try:
            return np.asarray(np.linalg.inv(jac.T @ jac) * max(1.0, chi2)), chi2
        except np.linalg.LinAlgError:
            return None, chi2


def data_points(obs: Sequence[Observation]) -> int:
    """How many numbers the trials ``obs`` give a fit: thrust and power each, and an admittance."""
    return 2 * len(obs) + sum(o.has_admittance for o in obs)


#: A given model is weighed by its whole cost against the fin file's (``Tuning.prior_drop_cost``) over
#: this many first trials (the strangers of ``bench_fish.py`` drop theirs at the second and third): a
#: right model's summed misfit grows about 0.1 a trial, and the fin file's fit each trial would cost
#: the controller
PRIOR_COST_TRIALS = 8


def weigh_prior(
    problem: FitProblem, given: Fit, obs: Sequence[Observation], tuning: Tuning
) -> tuple[str, Fit] | None:
    """Whether the trials ``obs`` contradict the given model that ``given`` corrects (the base of
    ``problem``): why, and the fin file's own fit to them, or None.  They do where the given model's
    corrected fit misses them beyond the noise and the fin file's fits them ``prior_drop_ratio``
    times better, or, over the first :data:`PRIOR_COST_TRIALS`, where it fits them only with its
    parameters so far from its own that its whole cost (weighed misfit and distance from the prior,
    twice the negative log posterior) exceeds the fin file's by ``prior_drop_cost``."""
    n = len(obs)
    n_data = data_points(obs)
    cost = given.chi2 * n_data + given.prior_cost
    early = n <= PRIOR_COST_TRIALS
    if given.chi2 <= 1.0 and (cost <= tuning.prior_drop_cost or not early):
        return None  # (within the noise, near its own parameters: nothing contradicts it)
    plain = replace(problem, base=None).fit(obs, Correction())
    plain_cost = plain.chi2 * n_data + plain.prior_cost
    chi, plain_chi = math.sqrt(given.chi2), math.sqrt(plain.chi2)
    if given.chi2 > 1.0 and plain.chi2 * tuning.prior_drop_ratio < given.chi2:
        return (
            f"misses the {n} trials by {chi:.1f} sigma (RMS) however corrected; the fin file alone, "
            f"corrected, by {plain_chi:.1f}"
        ), plain
    if early and cost - plain_cost > tuning.prior_drop_cost:
        return (
            f"fits the {n} trials ({chi:.1f} sigma RMS) only with its parameters "
            f"{math.sqrt(given.prior_cost):.1f} sigma from its own (cost {cost:.1f}); the fin file "
            f"alone, corrected, fits them ({plain_chi:.1f} sigma) at {plain_cost:.1f}"
        ), plain
    return None
