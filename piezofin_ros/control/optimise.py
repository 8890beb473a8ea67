r"""Thrust-per-watt optimiser: the model's map as a prior, corrected by what the fin measures.

The problem
-----------
Choose the drive frequency ``f`` and peak-to-peak voltage ``V`` within :class:`OperatingBox`:

* with a thrust demand ``D``: deliver ``T(f, V) >= D`` in truth with the least electrical power.
  ``T`` increases with ``V`` at any ``f``, so for every ``f`` the least voltage ``V*(f)`` whose
  thrust meets ``D`` *with a margin* (below) is found by bisection and the search is over ``f``;
* without a demand: the paper's convention, the frequency of the highest thrust per watt at the
  configured voltage, among frequencies that give at least ``min_thrust_n`` (default 1 mN);
* when ``D`` cannot be met within the limits: the most thrust available, flagged infeasible;
* the box's voltage capped while a yaw loop's offset needs the room (:meth:`~Optimiser.set_voltage_cap`).

How it learns
-------------
1. **The model, corrected.** The map is the harmonic balance of the fin model (or of a diagnosed
   model, ``model``) plus a :class:`Correction`: nine effects of the one library that real fins show
   (a resonance off, an added mass off ``c_m(psi)``, electroelastic softening, extra drag, a
   coupling that grows with the field, dielectric loss, a leak beside the piezo (on a fish), a
   capacitance off ``C_eq``, and a load-cell gain). After each trial they are fitted, with weak
   priors around the nominal fin, to everything the trial measured: the power, the thrust estimate
   (vibrometer or load cell) and the drive's admittance ``I_1 / V_1``. The admittance carries the
   capacitance and loss conductance (its static part) and ``theta^2`` times the mechanical response
   (its motional part), so on a fish (``source = "self"``, drive only) the same fit *calibrates the
   self-sensing*: the thrust is re-estimated from each trial's admittance with the fitted ``C_eq``,
   loss conductance, coupling at that field and ``c_m`` (:mod:`piezofin_ros.estimation.selfsense`),
   and the fit's covariance gives its error bound. When that bound keeps every trial from counting
   and the map's choice has been measured already, a *calibrating* trial goes where it shrinks the
   bound most (a leak and the loss, which one frequency cannot tell apart, are told apart by
   another).
2. **What the model misses.**  Residuals of the measured log thrust and log power against the
   corrected map are interpolated by a Gaussian process (:mod:`.gp`): near the trials the map
   follows the measurements, far from them it reverts to the model.  When the corrected model keeps
   mispredicting (its residuals exceed ``search_chi2`` times the noise), the optimiser says so
   (``mode = "search"`` with the reason) and searches model-free near the best measured point: the
   next trial maximises the map's thrust per watt plus ``kappa`` of its uncertainty within a trust
   region around the incumbent.
3. **The demand, met in truth.**  A measured point counts only if its thrust estimate, less ``z``
   times its uncertainty (the trial's noise, the calibration of its source), meets the demand, and
   only on the trials that did not choose it: of several noisy trials near the demand the best
   looking is the luckiest (the winner's curse), so a promising point is driven again to confirm
   it.  Trials go where one will count: the least voltage whose map thrust, less ``z`` times the
   model's parametric uncertainty, the process's and one trial's, meets the demand.  The point
   the controller holds (:meth:`Optimiser.incumbent`) is the best that counts.

The rooms: the corrected model (:mod:`.correction`), its fit (:mod:`.fit`), the evidence
(:mod:`.evidence`), the map (:mod:`.thrustmap`), the proposal's rules (:mod:`.proposal`); this
module ties them (:class:`Optimiser`), its knobs in :class:`Tuning`.  A proposal within
``tolerance`` of a measured point measures it again; the incumbent is held unless the map expects
``hold_gain`` more elsewhere; every ``probe_every`` trials a probe at ``f (1 +- probe_step)``.  The
fin has changed (a point measured again, or a trial, ``change_sigma`` off): the earlier trials go.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import ControlError
from ..estimation.estimator import SOURCE, source_of
from ..physics.amplifier import PAPER_BENCH, WATT, Amplifier, watt_of
from ..physics.fin import Fin
from ..physics.model import Model
from .correction import Correction, FloatArray
from .evidence import Counted, Observation, Task, close, count, remembered
from .fit import MODEL_ERROR, Fit, FitProblem, weigh_prior
from .gp import ResidualGP
from .objective import THRUST_PER_WATT, Objective
from .proposal import RULES, Mode, Proposal, is_quiet, mode_of, propose, trimmed
from .response import EstimateNoise
from .thrustmap import Choice, OperatingBox, Surface, best, frontier, surface
from .tuning import Tuning

#: Trials the corrected model must fit before it calibrates an estimator's self-sensing (a wrong prior
#: may be dropped earlier: ``Tuning.prior_drop_after``, ``Optimiser._check_prior``).
CALIBRATES_AFTER = 4

__all__ = [  # (the rooms' types the optimiser's users meet, re-exported)
    "MISFIT_CHI2",
    "MODEL_ERROR",
    "SOURCES",
    "Choice",
    "Correction",
    "Mode",
    "Observation",
    "OperatingBox",
    "Optimiser",
    "Proposal",
    "Surface",
    "Tuning",
]

#: The reduced chi-square against the noise alone beyond which a fish's calibration bound counts the
#: model's misfit (an RMS misfit of twice the noise; below it, scatter the noise model misses, such as
#: a voltage monitor's gain noise of 0.3 %, at chi-square 1.8, would have widened it: ``Optimiser._bound``)
MISFIT_CHI2 = 4.0


#: Which estimate feeds the optimiser: Lighthill on the vibrometer's tip velocity (with the fin's
#: ``c_m``), the drive's own current (a fish), or a load cell.
SOURCES = tuple(SOURCE)


@dataclass
class Optimiser:
    """Propose operating points, learn from their estimates; pure Python (the node drives it)."""

    fin: Fin
    limits: OperatingBox = field(default_factory=OperatingBox)
    voltage_pp: float = 800.0  # the configured voltage (no demand)
    demand_n: float | None = None
    min_thrust_n: float = 1e-3  # without a demand: the least thrust worth having
    source: str = "vibrometer"  # which estimate ``observe`` receives (see SOURCES)
    #: the watt of the thrust per watt (physics/amplifier.py): the map's power in it comes through
    #: ``amplifier`` (supply, and supply_measured, whose trials bring the meter's reading)
    watt: str = "fin"
    #: what it maximises in that watt (:mod:`.objective`): thrust per watt unless told otherwise
    objective: Objective = THRUST_PER_WATT
    amplifier: Amplifier = PAPER_BENCH
    noise: EstimateNoise = field(default_factory=EstimateNoise)
    demand_margin_z: float = 2.0  # the demand is met with this many standard deviations of margin
    #: with a demand, no trial goes to a measured point whose thrust exceeded it by more than this
    #: (relative): a fish's speed follows each trial's thrust (0: any point; the node's setting as it is)
    trial_overshoot: float = 0.0
    identify: bool = True  # begin with a quiet trial below resonance (proposal.identification_point)
    model: Model | None = None  # a diagnosed model: its fin and effects replace ``fin``
    tuning: Tuning = field(default_factory=Tuning)

    # --- state ------------------------------------------------------------------------------------
    changes: int = field(default=0, init=False)  # how many times the fin was seen to change
    prior_dropped: str = field(default="", init=False)  # what was said when ``model`` was dropped
    said: list[str] = field(default_factory=list, init=False, repr=False)  # for the caller, once each
    observations: list[Observation] = field(default_factory=list, init=False)
    fit: Fit = field(init=False)
    gp: ResidualGP = field(default_factory=ResidualGP, init=False)
    self_sensing_bound: float = field(default=math.nan, init=False)  # 2 sigma, relative, calibration
    #: the measured points that count (and those measured once that would: candidates to confirm),
    #: taken once per fit
    counted: list[Counted] = field(default_factory=list, init=False, repr=False)
    candidates: list[Counted] = field(default_factory=list, init=False, repr=False)
    choice: Choice | None = field(default=None, init=False)
    proposal: Proposal = field(default_factory=Proposal, init=False)
    converged: bool = field(default=False, init=False)
    calibrating: list[tuple[float, float]] = field(default_factory=list, init=False, repr=False)
    identify_requested: bool = field(default=False, init=False)
    _held: int = field(default=0, init=False)  # trials proposed at the incumbent once converged

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ControlError(f"source must be one of {', '.join(SOURCES)}, got {self.source!r}")
        if self.watt not in WATT:
            raise ControlError(f"watt must be one of {', '.join(WATT)}, got {self.watt!r}")
        margin, over = self.demand_margin_z, self.trial_overshoot
        if not (margin >= 0 and math.isfinite(margin)) or not (over >= 0 and math.isfinite(over)):
            raise ControlError(
                f"demand_margin_z and trial_overshoot must be finite and >= 0, got {margin}, {over}"
            )
        if self.model is not None:
            self.fin = self.model.fin
        self.fit = Fit(Correction(base=self.model))
        self._update()

    # --- views ------------------------------------------------------------------------------------
    @property
    def overshoot_limit(self) -> float:
        """How far above the demand (relative) a trial's point may have measured (inf: no limit)."""
        return self.trial_overshoot if self.trial_overshoot > 0 else math.inf

    @property
    def problem(self) -> FitProblem:
        """What the fit knows now (the source and the prior may change: a new one each time)."""
        return FitProblem(self.fin, self.noise, self.source, self.tuning.stiffness_sigma, self.model)

    @property
    def correction(self) -> Correction:
        """The fitted correction."""
        return self.fit.correction

    @property
    def task(self) -> Task:
        top, o = self.limits.voltage_pp_max, self
        return Task(o.demand_n, o.min_thrust_n, min(o.voltage_pp, top), o.demand_margin_z, o.objective, top)

    @property
    def mode(self) -> Mode:
        return self.proposal.mode

    @property
    def rule(self) -> str:
        return self.proposal.rule

    @property
    def reason(self) -> str:
        return self.proposal.reason

    RULES = RULES  # (the proposal's rules, in order: see proposal.propose)

    # --- inputs -----------------------------------------------------------------------------------
    def set_demand(self, demand_n: float | None) -> None:
        """A new demand (None or <= 0: none).  Non-finite values are ignored."""
        if demand_n is not None and not math.isfinite(demand_n):
            return
        self.demand_n = demand_n if demand_n is not None and demand_n > 0 else None
        self.converged = False
        self._update(learn=False)  # (the trials are those of the last fit: only the choice moves)

    def set_voltage_cap(self, voltage_pp: float | None) -> None:
        """The box capped (:meth:`.thrustmap.OperatingBox.capped`) for a yaw loop's offset (its room)."""
        if (box := self.limits.capped(voltage_pp)) != self.limits:
            self.limits, self.converged = box, False
            self._update(learn=False)

    def observe(
        self,
        t: float,
        frequency_hz: float,
        voltage_pp: float,
        thrust_n: float,
        power_w: float,
        admittance: complex = complex(math.nan, math.nan),
        power_named_w: float = math.nan,
        voltage_pp_drive: float = math.nan,
    ) -> bool:
        """Add one trial's estimate (``thrust_n`` from ``source``, ``power_w`` the fin's watt and
        ``power_named_w`` the optimiser's ``watt``; ``voltage_pp`` as commanded, which names the
        point, ``voltage_pp_drive`` as the monitor read it); False (and ignored) if unusable."""
        values = (t, frequency_hz, voltage_pp, thrust_n, power_w)
        if not all(math.isfinite(x) for x in values) or thrust_n <= 0 or power_w <= 0 or voltage_pp <= 0:
            return False
        fin_watt = watt_of(self.watt).is_fin
        if not fin_watt and not (math.isfinite(power_named_w) and power_named_w > 0):
            return False  # (no measure of the watt it optimises: a trial it cannot rank)
        named = math.nan if fin_watt else power_named_w
        new = Observation(
            *values,
            source=self.source,
            admittance=complex(admittance),
            power_named_w=named,
            voltage_pp_drive=float(voltage_pp_drive),
        )
        tuning = self.tuning
        apart = self.problem.repeat_disagreement(self.correction, self.observations, new)
        if apart > tuning.change_sigma or (
            # (against the map only once it has settled: before that, every trial teaches it something)
            self.converged and len(self.observations) >= 3 and self._surprise(new) > tuning.change_sigma
        ):
            # The fin no longer behaves as measured (drift, a new load): keep only the new evidence
            # (every earlier trial is of the fin before the change, the one just before it too).
            self.observations = []
            self.changes += 1
            self.gp = ResidualGP(self.gp.length_log_f, self.gp.length_v)
        self.observations.append(new)
        self.observations = remembered(self.observations, t, self.tuning, lambda o: is_quiet(self, o))
        if is_quiet(self, new):
            self.identify_requested = False
        self._update()
        return True

    def fitted_correction(self) -> Correction | None:
        """The fitted correction once the corrected model fits its self-sensed trials (at least
        :data:`CALIBRATES_AFTER` of them, its misfit within ``search_chi2``: the model mode), its base
        the model it was given while that is kept: what calibrates an estimator's self-sensing (the
        controller's ``controller/model``); None before, while the model misfits its trials, and on
        other sources (a vibrometer's or a load cell's reading is fitted as read: an estimator
        calibrated by the fit would feed the fit its own ``c_m`` back)."""
        if (
            not source_of(self.source).self_sensed
            or len(self.observations) < CALIBRATES_AFTER
            or self.proposal.mode is not Mode.MODEL
        ):
            return None
        return self.fit.correction

    def request_identification(self) -> None:
        """Take a quiet identification trial next, whatever the demand (an operator, or a fish's
        stack at a moment its speed may drop: a trial there gives a fraction of the thrust)."""
        self.identify_requested = True

    # --- the fit ----------------------------------------------------------------------------------
    def _check_prior(self) -> None:
        """Drop a given ``model`` the trials contradict (:func:`.fit.weigh_prior`), saying so once."""
        if self.model is None or len(self.observations) < self.tuning.prior_drop_after:
            return
        verdict = weigh_prior(self.problem, self.fit, self.observations, self.tuning)
        if verdict is not None:
            why, self.fit = verdict
            self.prior_dropped = (
                f"the model it was given {why}: the model is dropped, the fin file is the prior from now on"
            )
            self.said.append(self.prior_dropped)
            self.model = None

    def _bound(self) -> float:
        """2 sigma (relative) of the thrust estimate's calibration at the latest trial: the fitted
        parameters' (propagated from their covariance) and, on a fish, the model's own where the
        trials say it misfits, ``MODEL_ERROR`` times the square root of the reduced chi-square against
        the noise alone beyond ``MISFIT_CHI2``.  A model outside the correction's family can fit the
        trials with parameters that compensate one another, whose propagated error is small where
        their bias is not:
        M8514-P1 with a coupling growing as the field to the power 2.27 (chi-square 8) read its
        self-sensed thrust 5.2 % high against a parametric bound of 2.1 % and held 0.9994 of the
        demand in truth (``test_a_fish_whose_model_misfits_counts_the_misfit_in_its_bound``)."""
        if self.fit.covariance is None or not self.observations:
            return math.nan
        last = self.observations[-1]
        if last.load_cell:
            return 0.0
        problem = self.problem

        def log_estimate(c: Correction) -> FloatArray:
            return np.log(problem.thrust_estimates(c, [last]))

        # (on a fish only, whose whole calibration is the fit's; a vibrometer's is c_m alone, which a
        # misfit of the power, a leak's say, does not move: counted there it cost M8528-P1 with a leak
        # 0.60 -> 0.41 of the optimum after 8 trials under a demand, `bench_unseen.py --seeds 1`)
        misfit = self.fit.chi2_noise - MISFIT_CHI2 if source_of(last.source).self_sensed else 0.0
        form = MODEL_ERROR * math.sqrt(max(misfit, 0.0))  # (0 while the model fits)
        return float(2.0 * math.hypot(self.fit.sigma(log_estimate)[0], form))

    def _fit_residual_process(self) -> None:
        obs = self.observations
        if len(obs) < 2:
            self.gp = ResidualGP(self.gp.length_log_f, self.gp.length_v)
            return
        problem = self.problem
        f = np.array([o.frequency_hz for o in obs])
        v = np.array([o.voltage_pp for o in obs])
        p = np.array([o.power_w for o in obs])
        t = problem.thrust_estimates(self.correction, obs)
        r = self.correction.response(self.fin, f, v)
        _, noise_p = problem.measurement_noise(t, p)
        noise_t = problem.thrust_noise(self.correction, obs, t)
        res = np.column_stack([np.log(t / r.thrust_n), np.log(p / r.power_w)])
        self.gp.fit(f, v, res, np.column_stack([noise_t, noise_p]))

    def _count(self) -> None:
        """What counts and what would with one more trial (:func:`.evidence.count`), once per fit."""
        obs = self.observations
        if not obs:
            self.counted, self.candidates = [], []
            return
        problem = self.problem
        thrust = problem.thrust_estimates(self.correction, obs)
        noise = problem.thrust_noise(self.correction, obs, thrust)
        self.counted, self.candidates = count(obs, thrust, noise, self.self_sensing_bound, self.task)

    def surprise(
        self,
        t: float,
        frequency_hz: float,
        voltage_pp: float,
        thrust_n: float,
        power_w: float,
        admittance: complex = complex(math.nan, math.nan),
        power_named_w: float = math.nan,
        voltage_pp_drive: float = math.nan,
    ) -> float:
        """How far (in sigma) a window, given as :meth:`observe` takes it, lies from the map (0 where
        the map has no fit yet or the window is unusable)."""
        if not self.observations or not (thrust_n > 0 and power_w > 0 and voltage_pp > 0):
            return 0.0
        values = (t, frequency_hz, voltage_pp, thrust_n, power_w, self.source, complex(admittance))
        o = Observation(*values, voltage_pp_drive=float(voltage_pp_drive))
        return self._surprise(o)

    def _surprise(self, o: Observation) -> float:
        """How far (in sigma) a new measurement lies from the map's prediction."""
        problem = self.problem
        s = surface(self, o.frequency_hz, o.voltage_pp)
        t = self.thrust_as_fitted(o)
        noise_t = float(problem.thrust_noise(self.correction, [o], np.array([t]))[0])
        _, noise_p = problem.measurement_noise(t, o.power_w)
        dt = abs(math.log(t / max(float(s.thrust_n), 1e-300))) / math.hypot(
            noise_t + MODEL_ERROR, float(s.sigma_thrust)
        )
        dp = abs(math.log(o.power_w / max(float(s.fin_w), 1e-300))) / math.hypot(
            noise_p + MODEL_ERROR, float(s.sigma_power)
        )
        return max(dt, dp)

    # --- what counts ------------------------------------------------------------------------------
    def best_counted(self) -> Counted | None:
        """The best measured point that counts, or None."""
        return max(self.counted, key=lambda c: c.score) if self.counted else None

    def incumbent(self) -> tuple[float, float] | None:
        """The best measured point that counts (what the controller holds), or None."""
        best = self.best_counted()
        return None if best is None else best.observation.point

    def held(self) -> tuple[float, float]:
        """The point to hold now: the incumbent, or the map's choice while nothing counts."""
        inc = self.incumbent()
        assert self.choice is not None
        return inc if inc is not None else (self.choice.frequency_hz, self.choice.voltage_pp)

    # --- the update after each trial --------------------------------------------------------------
    def _update(self, learn: bool = True) -> None:
        """After a trial, ``learn``: the fit, the prior's check, the calibration's bound and the
        residual process, which depend on the trials alone; then what counts under the task and the
        next point.  A new demand changes only the latter (a fish's speed loop sends one every few
        seconds: refitting the same trials for each was half the fish controller's CPU)."""
        if learn:
            self.fit = self.problem.fit(self.observations, self.fit.correction)
            self._check_prior()
            self.self_sensing_bound = self._bound()
            self._fit_residual_process()
        self._count()
        lim = self.limits
        grid = np.geomspace(lim.frequency_min_hz, lim.frequency_max_hz, self.tuning.n_grid)
        surface, feasible = frontier(self, grid)
        choice = best(self, surface, feasible)
        for _ in range(2):  # finer around the grid's best (a grid step is 2 % of f: 3 % of power)
            step = float(grid[1] / grid[0])
            grid = choice.frequency_hz * np.geomspace(1 / step, step, 21)
            grid = np.clip(grid, lim.frequency_min_hz, lim.frequency_max_hz)
            surface, feasible = frontier(self, grid)
            if np.any(feasible) or not choice.feasible:
                choice = best(self, surface, feasible)
        self.choice = choice
        inc = self.incumbent()
        self.proposal = mode_of(self, inc)
        rule, point = propose(self, inc)
        self.proposal = replace(self.proposal, rule=rule, point=point)
        tol = self.tuning.tolerance
        self.calibrating = [  # (the calibrating points still in memory, and this one)
            p for p in self.calibrating if any(close(o.point, p, tol) for o in self.observations)
        ] + ([point] if rule == "calibrate" else [])
        self.converged = inc is not None and close(point, inc, tol)

    # --- outputs ----------------------------------------------------------------------------------
    def propose(self) -> tuple[float, float]:
        """The next operating point to drive (always inside the limits)."""
        assert self.proposal.point is not None
        f, v = self.proposal.point
        tuning = self.tuning
        if self.converged:
            f, v = trimmed(self, self.held())
            self._held += 1
            if tuning.probe_every and self._held % tuning.probe_every == 0:
                # a probe on either side in turn (extremum seeking's dither, one trial at a time), at
                # the voltage that meets the demand there: the fish keeps its thrust while it probes
                sign = -1.0 if (self._held // tuning.probe_every) % 2 else 1.0
                f = f * (1 + sign * tuning.probe_step)
                if self.demand_n is not None:
                    s, ok = frontier(self, np.array([f]))
                    v = float(s.voltage_pp[0]) if ok[0] else v
        return self.limits.clamp(f, v)

    def thrust_as_fitted(self, o: Observation) -> float:
        """``o``'s thrust as the fit reads it: self-sensed, through the fitted calibration (the
        estimator's own uses the fin file's); Lighthill's, with the fitted ``c_m``; a load cell's, as
        read.  What the optimiser believes the fin gave."""
        return float(self.problem.thrust_estimates(self.correction, [o])[0])

    def status(self) -> dict[str, Any]:
        c = self.choice
        assert c is not None
        best = self.best_counted()
        held = None
        if best is not None:
            o = best.observation
            held = {
                "frequency_hz": o.frequency_hz,
                "voltage_pp": o.voltage_pp,
                "thrust_n": best.thrust_n,  # the estimate, re-calibrated
                "power_w": o.named_w,  # in the optimiser's watt
                "power_fin_w": o.power_w,
            }
        return {
            "converged": self.converged,
            "feasible": c.feasible,
            "demand_n": self.demand_n,
            "optimiser_mode": str(self.mode),
            "optimiser_rule": self.rule,
            "optimiser_reason": self.reason,
            "frequency_hz": c.frequency_hz,
            "voltage_pp": c.voltage_pp,
            "predicted_thrust_n": c.thrust_n,
            "predicted_power_w": c.power_w,  # in the optimiser's watt
            "watt": self.watt,
            "objective": self.objective.name,
            "held": held,
            "source": self.source,
            "self_sensing_bound": self.self_sensing_bound,
            "unexplained": dict(zip(("thrust", "power"), self.gp.signal_sigma(), strict=False)),
            "correction": self.correction.fitted(),
            "observations": len(self.observations),
        }
