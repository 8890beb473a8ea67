"""The proposal's rules: where the next trial goes, the first rule of :data:`RULES` that has a point.

In order: a quiet identification trial while none is in memory (:func:`identification_point`); a
confirming trial of a point whose one trial beat the incumbent (:func:`candidate`); on a fish, a
calibrating trial where it shrinks the self-sensing's calibration bound most
(:func:`calibration_point`); else the map's point of the optimiser's mode (:func:`map_point`).  Each
rule reads what :class:`ProposalInputs` names of the optimiser (its fit, map and evidence) and
changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Protocol

import numpy as np

from ..estimation.estimator import source_of
from .correction import PRIOR_SIGMA, FloatArray, correction_of, jacobian, vector_of
from .evidence import Counted, Observation, close
from .thrustmap import Choice, MapInputs, best, frontier, gain
from .tuning import Tuning

Point = tuple[float, float]


class Mode(StrEnum):
    """How the optimiser proposes: from the corrected model's map, or searching near the incumbent
    when the model mispredicts the trials."""

    MODEL = "model"
    SEARCH = "search"


class ProposalInputs(MapInputs, Protocol):
    """What the rules read of the optimiser: the map's inputs, and its evidence and state."""

    tuning: Tuning
    identify: bool
    identify_requested: bool
    observations: list[Observation]
    candidates: list[Counted]
    calibrating: list[Point]

    @property
    def overshoot_limit(self) -> float: ...

    choice: Choice | None

    @property
    def mode(self) -> Mode: ...

    def best_counted(self) -> Counted | None: ...


@dataclass(frozen=True)
class Proposal:
    """The next trial: the mode the map is read in and why, the rule that chose the point."""

    mode: Mode = Mode.MODEL
    reason: str = "no trial yet: the model's optimum"
    rule: str = "map"  # (one of RULES)
    point: tuple[float, float] | None = None


def mode_of(opt: ProposalInputs, inc: Point | None) -> Proposal:
    """The mode the map is read in after a fit: the model's while the corrected model fits the trials
    (within ``search_chi2``), a search near the best measured point while it misses them."""
    n = len(opt.observations)
    chi = math.sqrt(opt.fit.chi2)
    if n == 0:
        return Proposal(Mode.MODEL, "no trial yet: the model's optimum")
    if opt.fit.chi2 > opt.tuning.search_chi2 and n >= 2:
        return Proposal(
            Mode.SEARCH,
            f"the corrected model misses the trials by {chi:.1f} sigma (RMS): "
            "searching near the best measured point"
            + ("" if inc is not None else " (none meets the task yet: the map's optimum)"),
        )
    return Proposal(Mode.MODEL, f"the corrected model fits the {n} trial(s) ({chi:.1f} sigma RMS)")


def f_res(opt: ProposalInputs) -> float:
    """The fin's in-water resonance as its file gives it, Hz."""
    return opt.fin.omega_n / (2 * math.pi * math.sqrt(1 + opt.fin.mu))


def is_quiet(opt: ProposalInputs, o: Observation) -> bool:
    """Whether ``o`` is a quiet identification trial (well below the resonance)."""
    return o.frequency_hz <= 0.7 * f_res(opt)


def identification_point(opt: ProposalInputs, inc: Point | None = None) -> Point | None:
    """A quiet trial well below the resonance, if none is in memory: there the tip moves as
    ``theta V / K`` and the motional current as ``theta^2 V / K``, which fix the coupling and the
    stiffness; the resonance then gives the added mass, hence ``c_m`` and every thrust estimate
    (without it a softer fin and a heavier added mass look alike).  None when there is one.  On a
    fish under a demand only from rest or when asked (``Optimiser.request_identification``): a trial
    there gives a fraction of the thrust, and its speed follows each trial's."""
    if not (opt.identify or opt.identify_requested):
        return None
    f_quiet = max(0.5 * f_res(opt), opt.limits.frequency_min_hz)
    if f_quiet >= 0.7 * f_res(opt) or any(is_quiet(opt, o) for o in opt.observations):
        return None
    swimming = opt.demand_n is not None and math.isfinite(opt.overshoot_limit)  # (see trial_overshoot)
    if swimming and opt.observations and not opt.identify_requested:
        return None
    lim = opt.limits
    return f_quiet, min(max(0.5 * lim.voltage_pp_max, lim.voltage_pp_min), lim.voltage_pp_max)


def candidate(opt: ProposalInputs, inc: Point | None = None) -> Point | None:
    """The best point whose one trial meets the task and would beat the incumbent, if any, and
    that the map does not expect to beat by more than 5 % (the map's choice is tried first).  Under
    a demand, only a point measured within half of the overshoot limit above it, as the held point
    is trimmed (:func:`trimmed`): a point confirmed 10 % above the demand by the fit, 14 % in truth,
    put a stranger's speed 7 % high for 15 s (``bench_fish.py --strangers``)."""
    best = opt.best_counted()
    cap = math.inf if opt.demand_n is None else opt.demand_n * (1.0 + opt.overshoot_limit / 2)
    better = [c for c in opt.candidates if (best is None or c.score > best.score) and c.thrust_n <= cap]
    if not better or opt.choice is None:
        return None
    point = max(better, key=lambda c: c.score).observation.point
    # (both on the map, as thrustmap.gain: a measured objective against the map's is off by the
    # map's bias, which an amplifier the optimiser is not told makes several-fold in a measured
    # supply's watts, and then no point was ever confirmed: stop 33's vibrometer demand miss)
    choice = (opt.choice.frequency_hz, opt.choice.voltage_pp)
    return point if gain(opt, point, choice) <= 0.05 else None


def calibration_point(opt: ProposalInputs, inc: Point | None) -> Point | None:
    """On a fish under a demand, while no trial counts and the calibration's share of the demand's
    margin exceeds a trial's noise at the map's choice: the trial that shrinks the self-sensing's
    calibration bound at the choice the most, if it shrinks its variance below ``calibrate_gain``
    of what a trial at the choice would.  Without it, a leak and the dielectric loss that trade off
    at one frequency kept M8528-P1 at the map's 9.87 Hz, 800 Vpp for every trial, its bound at 115 %
    and nothing counted (the trials repeat the choice's admittance, which does not tell the two
    apart; one elsewhere does).  When it waited for the choice to have been measured, M8514-P1 with
    drag varying with KC walked down the frontier from 800 Vpp one trial at a time as the bound fell
    (136, 79, 50, 21, 17 %), 0.745 of the optimum after 8 trials; calibrating from the first it holds
    0.99 from the 4th.  At most ``max_calibrating_trials`` are in memory.

    A first-order design: each candidate's trial is the corrected model's prediction there, its
    information (its residuals' Jacobian, as the fit weighs it) is added to the fit's, and the
    variance of the choice's log thrust estimate is propagated through the sum."""
    tuning, fit, problem = opt.tuning, opt.fit, opt.problem
    if (
        not source_of(opt.source).self_sensed
        or opt.demand_n is None
        or inc is not None
        or opt.choice is None
        or fit.covariance is None
        or not opt.demand_margin_z > 0
    ):
        return None
    # (a model that cannot fit the fin extrapolates its calibration into each far trial: past
    # three calibrating trials in memory M8528-P1 with drag ~ KC took seven of twelve, and its
    # self-sensed thrust ended 11 % off where it held)
    taken = sum(any(close(o.point, p, tuning.tolerance) for p in opt.calibrating) for o in opt.observations)
    if taken >= tuning.max_calibrating_trials:
        return None
    correction = fit.correction
    choice = (opt.choice.frequency_hz, opt.choice.voltage_pp)
    lim = opt.limits
    f = np.geomspace(lim.frequency_min_hz, lim.frequency_max_hz, 16)
    v = np.array([0.5 * (lim.voltage_pp_min + lim.voltage_pp_max), lim.voltage_pp_max])
    ff, vv = (a.ravel() for a in np.meshgrid(f, v))
    ff, vv = np.concatenate([[choice[0]], ff]), np.concatenate([[choice[1]], vv])
    pred = correction.predict(opt.fin, ff, vv)
    thrust = np.asarray(pred.thrust_n, float)
    power = np.asarray(pred.power_w, float)
    admittance = np.asarray(pred.admittance, complex)
    if math.isfinite(opt.overshoot_limit):  # (a fish's speed follows the trial's thrust)
        keep = (thrust <= opt.demand_n * (1.0 + opt.overshoot_limit)) & (
            thrust >= opt.demand_n * (1.0 - tuning.hold_margin)
        )
        keep[0] = True
        ff, vv, thrust, power, admittance = (a[keep] for a in (ff, vv, thrust, power, admittance))
    trials = [
        Observation(0.0, float(a), float(b), float(t), float(p), source="self", admittance=complex(y))
        for a, b, t, p, y in zip(ff, vv, thrust, power, admittance, strict=True)
    ]
    if not all(math.isfinite(o.thrust_n) and o.thrust_n > 0 and o.power_w > 0 for o in trials):
        return None
    # only where the calibration is what keeps a trial from counting: its share of the margin
    # (one sigma of the calibration at the choice) exceeds a trial's noise there (with no margin,
    # a speed loop's, it never does)
    there = [o for o in opt.observations if close(o.point, choice, tuning.tolerance)]
    at_choice = there[-1:] or trials[:1]  # (measured there before, or as the map predicts it)
    estimate = problem.thrust_estimates(correction, at_choice)
    noise = float(problem.thrust_noise(correction, at_choice, estimate)[0])
    at = at_choice[0]
    sigma = float(fit.sigma(lambda c: np.log(problem.thrust_estimates(c, [at])))[0])
    if not sigma > noise:
        return None
    n = len(trials)

    def residuals_and_estimate(xk: FloatArray) -> FloatArray:
        ck = correction_of(xk, correction.base)
        estimate = np.log(problem.thrust_estimates(ck, trials[:1]))
        return np.concatenate([problem.residuals(ck, trials, 0.0), estimate])

    both = jacobian(residuals_and_estimate, vector_of(correction), 1e-4 * PRIOR_SIGMA)
    jac, grad = both[: 3 * n].reshape(3, n, -1), both[3 * n]
    try:
        info = np.linalg.inv(fit.covariance)
        var = np.array([grad @ np.linalg.solve(info + jac[:, i, :].T @ jac[:, i, :], grad) for i in range(n)])
    except np.linalg.LinAlgError:
        return None
    best = int(np.argmin(var))
    if best == 0 or not var[best] < tuning.calibrate_gain * var[0]:
        return None
    return float(ff[best]), float(vv[best])


def map_point(opt: ProposalInputs, inc: Point | None) -> Point:
    """The map's point of the optimiser's mode: a search near the incumbent (``search``), the
    incumbent held when the map expects too little elsewhere (``hold_gain``), or the map's optimum;
    moved onto a point measured before when it is that close (its trials add up)."""
    assert opt.choice is not None
    tuning = opt.tuning
    point = (opt.choice.frequency_hz, opt.choice.voltage_pp)
    if opt.mode == Mode.SEARCH and inc is not None:
        f0 = inc[0]
        local = np.geomspace(f0 * (1 - tuning.trust_region), f0 * (1 + tuning.trust_region), 31)
        local = local[(local >= opt.limits.frequency_min_hz) & (local <= opt.limits.frequency_max_hz)]
        if local.size:
            s, ok = frontier(opt, local)
            pick = best(opt, s, ok, optimism=tuning.kappa)
            point = (pick.frequency_hz, pick.voltage_pp)
    elif opt.mode == Mode.MODEL and inc is not None and gain(opt, inc, point) < tuning.hold_gain:
        point = inc  # the map expects too little elsewhere to be worth a new point's trials
    near = [o for o in opt.observations if close(o.point, point, tuning.tolerance)]
    return near[-1].point if near else point


#: The proposal's rules, first match wins (the last always has a point).
RULES: tuple[tuple[str, Callable[[ProposalInputs, Point | None], Point | None]], ...] = (
    ("identify", identification_point),
    ("confirm", candidate),
    ("calibrate", calibration_point),
    ("map", map_point),
)


def propose(opt: ProposalInputs, inc: Point | None) -> tuple[str, Point]:
    """The next point and the rule that chose it: the first of :data:`RULES` that has one."""
    for name, rule in RULES[:-1]:
        point = rule(opt, inc)
        if point is not None:
            return name, point
    return "map", map_point(opt, inc)


def trimmed(opt: ProposalInputs, point: Point) -> Point:
    """The held point, its voltage lowered to meet the demand where the incumbent's measured thrust
    exceeds it by more than half the overshoot limit (a fish under a demand only), aiming a quarter
    of the limit above the demand: the voltage at which the fitted model's thrust falls by the ratio
    of that aim to the thrust measured there (within 20 % of the voltage; the square root of the
    ratio, thrust as the amplitude squared, where the model does not rise with the voltage there).
    The model's ratio, not the square law: M8507-P1 with a KC-dependent added mass lost 27 % of its
    thrust for 4 % of voltage at 2.4 Hz, and trimmed by the square law took 167 s to settle (44 s
    with the model's, ``bench_fish.py --unseen added_mass_kc``).  Without it the point
    measured under an earlier, larger demand stayed the incumbent as the speed loop asked less: a
    stranger's fish held 12 % more thrust than asked every other trial, its speed 5 % fast, and
    "settled" 544 s after its set-point step (5 s with it, ``bench_fish.py --strangers``)."""
    best = opt.best_counted()
    over = opt.overshoot_limit
    if opt.demand_n is None or not math.isfinite(over) or best is None or point != best.observation.point:
        return point
    if best.thrust_n <= opt.demand_n * (1.0 + over / 2):
        return point
    f, v = point
    share = opt.demand_n * (1.0 + over / 4) / best.thrust_n  # (of the thrust measured there)
    vs = v * np.linspace(0.8, 1.0, 41)
    model = np.asarray(opt.fit.correction.predict(opt.fin, np.full_like(vs, f), vs).thrust_n, float)
    if np.all(np.diff(model) > 0) and model[0] > 0:
        trim = float(np.interp(share * model[-1], model, vs))
    else:
        trim = v * math.sqrt(share)
    return opt.limits.clamp(f, trim)
