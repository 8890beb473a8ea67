r"""Which effect causes the gap, and how far adding it closes the gap on held-out trials.

Procedure (:func:`diagnose`: the named steps of :data:`PIPELINE`, each a function of a :class:`Work`)
-----------------------------------------------------------------------------------------------------
0. **Where.**  The gap in each stage of the chain (:mod:`.stages`) and the resonances.
1. **Split.**  With several voltages, the highest is held out and the rest train (the model must
   *extrapolate* in amplitude, where nonlinear effects differ most); with one voltage, every third
   frequency is held out.
2. **Fit.**  Each candidate (every effect of the library alone, then the best one paired with each other
   effect, and the best ``pairs_of`` (3) paired among themselves) is fitted
   on the training trials by noise-weighted least squares (``scipy.optimize.least_squares``, bounded,
   two starts) over every measured channel: drive voltage, tip velocity and phase, current, power,
   load-cell thrust.  A weak prior (ten times each parameter's typical size) keeps unidentified
   parameters from wandering.
3. **Score.**  On the held-out trials, ``chi^2 = sum ((measured - predicted) / sigma)^2``; the
   ranking criterion adds ``k ln n`` for ``k`` parameters and ``n`` held-out residuals (a BIC-style
   penalty, so an extra parameter must buy a ``chi^2`` drop of ``ln n``, about 4).
4. **Decide.**
   * no stage has a gap: "no gap";
   * the best candidate leaves a held-out ``chi^2`` that the noise explains (p >= 1e-3), or removes
     at least ``close_fraction`` (95 %) of the held-out ``chi^2`` and leaves a reduced ``chi^2``
     below ``max_reduced_chi2`` (3): "explained", naming it;
   * otherwise "unexplained", with the best candidate quoted only as the least bad;
   * a pair is named only if each member is material: taking it out (the other kept as fitted) must
     move some trial's prediction by more than ``material_sigma`` (3) of its noise; a member that
     does not is a correction to its partner's form (a describing function's error at large
     amplitude), not a second cause, and the partner alone is named, with a note;
   * candidates whose criterion is within ``ambiguity`` (6, a likelihood ratio of 20) of the best
     "cannot be told apart on this data", and the report proposes the operating point where
     their fitted predictions differ most in units of the expected noise.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize, stats

from ..physics.effects import LIBRARY, effect_class
from ..physics.fin import Fin
from ..physics.model import Model, for_many_predictions
from .data import CHANNELS, Trials, conventions
from .space import ParamSpace
from .stages import Resonance, StageGap, resonances, stage_gaps

FloatArray = NDArray[Any]
FIT_CHANNELS = tuple(CHANNELS)


def _wrap(x: FloatArray) -> FloatArray:
    return np.angle(np.exp(1j * x))


def predicted_channels(model: Model, trials: Trials) -> dict[str, FloatArray]:
    """The model's value of every channel for the table's trials (measured voltage as input where known)."""
    pred = model.predict(
        trials.frequency_hz, trials.voltage_pp, drive_pp=trials.measured_drive(), time_s=trials.time_s
    )
    return {name: np.asarray(getattr(pred, name), float) for name in FIT_CHANNELS}


def residuals(model: Model, trials: Trials) -> dict[str, FloatArray]:
    """``(measured - predicted) / sigma`` per channel (NaN where not measured)."""
    pred = predicted_channels(model, trials)
    out = {}
    for name in FIT_CHANNELS:
        if name == "voltage_pp_drive" and not trials.commanded:
            out[name] = np.full(len(trials), np.nan)  # the drive against itself: not a measurement
            continue
        d = trials.channel(name) - pred[name]
        if name == "tip_phase_rad":
            d = _wrap(d)
        out[name] = d / trials.sigma[name]
    return out


def _stack(res: dict[str, FloatArray]) -> FloatArray:
    r = np.concatenate([res[k] for k in FIT_CHANNELS])
    return r[np.isfinite(r)]


def chi2(model: Model, trials: Trials) -> tuple[float, int]:
    r = _stack(residuals(model, trials))
    return float(np.sum(r * r)), int(r.size)


@dataclass(frozen=True)
class Candidate:
    effects: tuple[str, ...]
    model: Model
    chi2_train: float
    chi2_test: float
    n_test: int
    k: int
    criterion: float

    @property
    def label(self) -> str:
        return " + ".join(self.effects) if self.effects else "nominal model"


def fit(
    fin: Fin,
    names: Sequence[str],
    train: Trials,
    start: dict[str, tuple[float, ...]] | None = None,
    only_start: bool = False,
) -> Model:
    """Least-squares parameters of ``names`` on ``train`` (bounded, two starts and ``start``, weak
    prior); with ``only_start``, from ``start`` alone."""
    space = ParamSpace(fin, tuple(names))
    params = space.params
    zlo, zhi = space.z_bounds

    def fun(z: FloatArray) -> FloatArray:
        try:
            r = _stack(residuals(space.model(z), train))
        except (ValueError, FloatingPointError):
            return np.full(n_res, 1e6)
        if r.size != n_res or not np.all(np.isfinite(r)):
            return np.full(n_res, 1e6)
        return np.concatenate([r, z / 10.0])

    n_res = _stack(residuals(Model(fin), train)).size
    starts = []
    if start:
        x0 = np.concatenate([np.asarray(start.get(n, effect_class(n).neutral()), float) for n in names])
        starts.append(space.to_z(x0))
    if not (starts and only_start):
        if len(params) == 1 and params[0].starts:
            starts += list(space.to_z(params[0].starts)[:, None])
        else:
            starts += [np.full(len(params), 0.5), np.full(len(params), -0.5)]
    best, best_cost = None, math.inf
    for z0 in starts:
        z0 = np.clip(z0, zlo + 1e-9 * (zhi - zlo), zhi - 1e-9 * (zhi - zlo))
        with np.errstate(all="ignore"):
            sol = optimize.least_squares(
                fun, z0, bounds=(zlo, zhi), x_scale=1.0, max_nfev=60 * len(params), method="trf"
            )
        if sol.cost < best_cost:
            best, best_cost = sol, sol.cost
    assert best is not None
    return space.model(best.x, uncertainties(space, best, n_res))


def uncertainties(space: ParamSpace, sol: optimize.OptimizeResult, n_res: int) -> dict[str, dict[str, float]]:
    """One standard deviation of each fitted parameter, from the fit's Jacobian.

    The residuals are in units of the noise, so the covariance of the scaled parameters is
    ``(J^T J)^-1`` (the prior rows included, as in the fit), inflated by the reduced ``chi^2``
    when the fit is worse than the noise (as lmfit and ``scipy.optimize.curve_fit`` do); mapped to
    physical units by each parameter's scale.  A parameter the data do not constrain has a large
    one (the prior's width, ten times its typical size); one at a bound, NaN.
    """
    jac = np.asarray(sol.jac, float)
    k = jac.shape[1]
    dof = max(n_res - k, 1)
    red = float(np.sum(sol.fun[:n_res] ** 2)) / dof
    cov = np.linalg.pinv(jac.T @ jac) * max(red, 1.0)
    sigma = space.scale * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    lo, hi = space.z_bounds
    sigma[(sol.active_mask != 0) | (sol.x <= lo) | (sol.x >= hi)] = math.nan
    out, j = {}, 0
    for name, size in zip(space.names, space.sizes, strict=True):
        params = effect_class(name).params
        out[name] = {q.name: float(sigma[j + i]) for i, q in enumerate(params)}
        j += size
    return out


def split(trials: Trials) -> tuple[NDArray[np.bool_], str]:
    """Held-out mask and its description."""
    volts = trials.voltages
    if volts.size >= 2:
        test = np.round(trials.voltage_pp) == volts[-1]
        return test, f"fit on {', '.join(f'{v:.0f}' for v in volts[:-1])} Vpp, judged on {volts[-1]:.0f} Vpp"
    order = np.argsort(trials.frequency_hz)
    test = np.zeros(len(trials), bool)
    test[order[1::3]] = True
    return test, "fit on two frequencies in three, judged on the third"


@dataclass(frozen=True)
class ChannelGap:
    channel: str
    unit: str
    rms_before: float  # in unit
    rms_after: float
    rel_before_percent: float
    rel_after_percent: float
    n: int


def channel_gaps(before: Model, after: Model, trials: Trials) -> list[ChannelGap]:
    """Per channel, the RMS gap in units and relative to the RMS of the measurement (percent)."""
    pb, pa = predicted_channels(before, trials), predicted_channels(after, trials)
    out = []
    for name, (unit, scale, _) in CHANNELS.items():
        m = trials.channel(name)
        ok = np.isfinite(m) & np.isfinite(pb[name]) & np.isfinite(pa[name])
        if not np.any(ok):
            continue
        db, da = m[ok] - pb[name][ok], m[ok] - pa[name][ok]
        if name == "tip_phase_rad":
            db, da = _wrap(db), _wrap(da)
            rb = ra = math.nan
        else:
            ref = math.sqrt(float(np.mean(m[ok] ** 2))) or 1e-30
            rb = float(np.sqrt(np.mean(db**2)) / ref * 100)
            ra = float(np.sqrt(np.mean(da**2)) / ref * 100)
        out.append(
            ChannelGap(
                name,
                unit,
                float(np.sqrt(np.mean(db**2)) * scale),
                float(np.sqrt(np.mean(da**2)) * scale),
                rb,
                ra,
                int(ok.sum()),
            )
        )
    return out


def shrink(before: float, after: float) -> float:
    """Fraction of the held-out gap removed, in noise units: ``1 - sqrt(chi2_after / chi2_before)``
    (the RMS normalised residual; 0 when nothing changes, 1 when nothing is left)."""
    return 1.0 - math.sqrt(after / before) if before > 0 else math.nan


@dataclass(frozen=True)
class Experiment:
    """Where two candidates' predictions differ most (in units of the expected noise)."""

    frequency_hz: float
    voltage_pp: float
    channel: str
    difference_sigma: float
    a: str
    b: str


def separating_experiment(
    a: Candidate, b: Candidate, trials: Trials, f_max: float | None = None, v_max: float = 1000.0
) -> Experiment:
    """The operating point (frequency x voltage, within the drive's limits) best telling ``a`` from ``b``."""
    f_hi = f_max or 1.5 * float(np.max(trials.frequency_hz))
    f = np.linspace(0.5, f_hi, 60)
    v = np.linspace(100.0, v_max, 19)
    ff, vv = (x.ravel() for x in np.meshgrid(f, v))
    pa, pb = a.model.predict(ff, vv), b.model.predict(ff, vv)
    best = (0.0, 0, "")
    for name in FIT_CHANNELS:
        if not trials.has(name):
            continue
        ya, yb = np.asarray(getattr(pa, name)), np.asarray(getattr(pb, name))
        if name == "tip_phase_rad":
            d = np.abs(_wrap(ya - yb)) / 0.02
        else:
            med_rel = float(
                np.nanmedian(trials.sigma[name] / np.maximum(np.abs(trials.channel(name)), 1e-30))
            )
            floor = float(np.nanmin(trials.sigma[name]))
            d = np.abs(ya - yb) / np.hypot(med_rel * np.maximum(np.abs(ya), np.abs(yb)), floor)
        j = int(np.nanargmax(d))
        if d[j] > best[0]:
            best = (float(d[j]), j, name)
    return Experiment(float(ff[best[1]]), float(vv[best[1]]), best[2], best[0], a.label, b.label)


def largest_move(model: Model, effect: str, trials: Trials) -> float:
    """The largest change of any prediction, in units of its noise, when ``effect`` is taken out of
    ``model`` (the other effects kept as fitted)."""
    rest = model.without(effect)
    full, without = predicted_channels(model, trials), predicted_channels(rest, trials)
    moves = [0.0]
    for name in FIT_CHANNELS:
        d = without[name] - full[name]
        if name == "tip_phase_rad":
            d = _wrap(d)
        z = np.abs(d) / trials.sigma[name]
        if np.any(np.isfinite(z)):
            moves.append(float(np.nanmax(z)))
    return max(moves)


def _params_text(model: Model, effect: str) -> str:
    return model.parameters_text(effect)


@dataclass(frozen=True)
class Diagnosis:
    fin: Fin
    trials: Trials
    stages: list[StageGap]
    resonances: list[Resonance]
    holdout: NDArray[np.bool_]
    holdout_text: str
    candidates: list[Candidate]  # ranked, best first
    nominal: Candidate
    verdict: str  # "no gap" | "explained" | "unexplained"
    chosen: Candidate | None
    ambiguous: list[Candidate]
    experiments: list[Experiment]
    gaps: list[ChannelGap]  # held out, before/after the best candidate
    shrink: float
    final_model: Model  # refitted on all trials
    notes: list[str] = field(default_factory=list)
    #: when nothing explains the gap but the least bad candidate removes most of it: its family
    #: ("added mass", "current monitor", ...), the probable cause in another form
    family: str = ""
    #: the share of the held-out gap the family's least-bad candidate removes
    family_removed: float = math.nan
    #: reversed sensors found in the data and corrected before the diagnosis, in words
    corrections: list[str] = field(default_factory=list)

    @property
    def headline(self) -> str:
        """The verdict in one sentence, leading with what was found: a sensor corrected, the family."""
        fixed = "; ".join(c.split(": the fin would")[0] for c in self.corrections)
        lead = f"found and corrected: {fixed}; after it, " if fixed else ""
        if self.verdict == "no gap":
            return lead + "no gap: every stage agrees with the model within the measurement noise"
        if self.verdict == "explained" and self.chosen is not None:
            return lead + f"explained by {self.chosen.label}" + (" (ambiguous)" if self.ambiguous else "")
        if self.family:
            return lead + (
                f"the {self.family} family, in another form: {self.family_removed:.0%} of the gap removed "
                "by its best form in the library, which does not close it"
            )
        return lead + "unexplained: no candidate in the library closes the gap"

    @property
    def confident(self) -> bool:
        return self.verdict == "explained" and not self.ambiguous

    @property
    def named(self) -> tuple[str, ...]:
        return self.chosen.effects if self.chosen else ()


@dataclass(frozen=True)
class Settings:
    """The decision rules' thresholds (module docstring, step 4)."""

    library: tuple[str, ...] = tuple(LIBRARY)
    pairs_of: int = 3
    partners: int = 8
    ambiguity: float = 6.0
    close_fraction: float = 0.95
    max_reduced_chi2: float = 3.0
    material_sigma: float = 3.0


@dataclass
class Work:
    """What flows through the pipeline: the inputs, and what each step adds."""

    trials: Trials
    fin: Fin
    settings: Settings
    say: Callable[[str], None]
    nominal_model: Model = field(init=False)
    stages: list[StageGap] = field(default_factory=list)
    resonances: list[Resonance] = field(default_factory=list)
    test: NDArray[np.bool_] = field(init=False)
    test_text: str = ""
    train: Trials = field(init=False)
    held: Trials = field(init=False)
    nominal: Candidate = field(init=False)
    n_train: int = 0
    penalty: float = 0.0
    singles: list[Candidate] = field(default_factory=list)
    candidates: list[Candidate] = field(default_factory=list)
    fitting: list[Candidate] = field(default_factory=list)
    best: Candidate = field(init=False)
    verdict: str = ""
    chosen: Candidate | None = None
    ambiguous: list[Candidate] = field(default_factory=list)
    experiments: list[Experiment] = field(default_factory=list)
    gaps: list[ChannelGap] = field(default_factory=list)
    shrink: float = math.nan
    final: Model = field(init=False)
    notes: list[str] = field(default_factory=list)
    family: str = ""
    family_removed: float = math.nan
    corrections: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.nominal_model = Model(self.fin)

    def candidate(
        self,
        combo: tuple[str, ...],
        start: dict[str, tuple[float, ...]] | None = None,
        only_start: bool = False,
    ) -> Candidate:
        """Fit ``combo`` on the training trials and score it on the held-out ones."""
        m = fit(self.fin, combo, self.train, start, only_start)
        c_tr, _ = chi2(m, self.train)
        c_te, n = chi2(m, self.held)
        k = sum(len(effect_class(e).params) for e in combo)
        return Candidate(combo, m, c_tr, c_te, n, k, c_te + k * self.penalty)

    def adequate(self, c: Candidate) -> bool:
        """The candidate explains the held-out gap (module docstring, step 4)."""
        s, nominal = self.settings, self.nominal
        if not c.n_test or c.criterion >= nominal.criterion:
            return False
        if float(stats.chi2.sf(c.chi2_test, c.n_test)) >= 1e-3:
            return True
        return (
            c.chi2_test <= (1 - s.close_fraction) * nominal.chi2_test
            and c.chi2_test / c.n_test <= s.max_reduced_chi2
        )


def read(w: Work) -> None:
    """Step 0a: what reading the data found, and a reversed sensor corrected."""
    w.notes += list(w.trials.notes)
    w.trials, said = conventions(w.trials)
    w.notes += said
    w.corrections = list(said)


def where(w: Work) -> None:
    """Step 0: where the gap lies (each stage of the chain, the resonances)."""
    w.stages = stage_gaps(w.trials, w.nominal_model)
    w.resonances = resonances(w.trials, w.nominal_model)


def split_trials(w: Work) -> None:
    """Step 1: training and held-out trials, and the nominal model's scores on them."""
    w.test, w.test_text = split(w.trials)
    w.train, w.held = w.trials.subset(~w.test), w.trials.subset(w.test)
    c_tr0, w.n_train = chi2(w.nominal_model, w.train)
    c_te0, n_te = chi2(w.nominal_model, w.held)
    w.penalty = math.log(max(n_te, 2))
    w.nominal = Candidate((), w.nominal_model, c_tr0, c_te0, n_te, 0, c_te0)


def fit_singles(w: Work) -> None:
    """Step 2a: every effect of the library alone, ranked."""
    names = w.settings.library
    for j, name in enumerate(names):
        w.say(f"fitting {name} ({j + 1}/{len(names)})")
        w.singles.append(w.candidate((name,)))
    w.singles.sort(key=lambda c: c.criterion)


def fit_pairs(w: Work) -> None:
    """Step 2b: the best single with every other effect (forward selection), the best ``pairs_of``
    together.  Pairs among the ``partners`` best singles are fitted from three starts (the singles'
    values and two defaults); the others from the singles' values alone, which is where a second
    cause that alone explains little starts anyway (a third of the cost)."""
    singles = w.singles
    combos = {tuple(sorted((singles[0].effects[0], c.effects[0]))) for c in singles[1:]}
    combos |= {
        tuple(sorted((a.effects[0], b.effects[0])))
        for a, b in itertools.combinations(singles[: w.settings.pairs_of], 2)
    }
    by_name = {c.effects[0]: c for c in singles}
    rank = {c.effects[0]: j for j, c in enumerate(singles)}
    w.candidates = list(singles)
    for j, (a, b) in enumerate(sorted(combos)):
        w.say(f"fitting {a} + {b} (pair {j + 1}/{len(combos)})")
        start = {a: by_name[a].model.values[0], b: by_name[b].model.values[0]}
        cheap = max(rank[a], rank[b]) > w.settings.partners
        w.candidates.append(w.candidate((a, b), start, only_start=cheap))
    w.candidates.sort(key=lambda c: c.criterion)


def choose_explanation(w: Work) -> None:
    """Step 3: the smallest adequate explanation (one effect if one suffices, else a pair), and a
    pair only if each member is material."""
    w.fitting = [c for c in w.singles if w.adequate(c)] or [
        c for c in w.candidates if len(c.effects) == 2 and w.adequate(c)
    ]
    w.best = w.fitting[0] if w.fitting else w.candidates[0]
    if not (w.fitting and len(w.best.effects) == 2):
        return
    # A pair names two causes only if each is material: without it (the other kept as fitted),
    # some trial's prediction must move by more than `material_sigma` of its noise.  Otherwise the
    # small member is a correction to the other's form (e.g. a describing function's error at
    # large amplitude), not a second cause.
    moves = {e: largest_move(w.best.model, e, w.trials) for e in w.best.effects}
    minor = [e for e in w.best.effects if moves[e] < w.settings.material_sigma]
    if len(minor) == 1:
        (keep,) = [e for e in w.best.effects if e != minor[0]]
        pair = w.best
        w.best = next(c for c in w.singles if c.effects == (keep,))
        w.notes.append(
            f"{minor[0]} ({_params_text(pair.model, minor[0])}) lowers the held-out chi2 of {keep} from "
            f"{w.best.chi2_test:.0f} to {pair.chi2_test:.0f} but moves no prediction by more than "
            f"{moves[minor[0]]:.1f} sigma: a correction to the form of {keep}, not a second cause, so it "
            "is not named"
        )


def decide(w: Work) -> None:
    """Step 4: the verdict (no gap, explained, unexplained), with the reasons."""
    nominal, best = w.nominal, w.best
    has_gap = any(s.significant for s in w.stages if s.stage != "supply")  # (the amplifier, not the fin)
    for s in w.stages:
        if s.stage == "supply" and s.significant:
            gap = float(np.nanmedian(s.relative_gap)) * 100
            w.notes.append(
                f"the supply draws {gap:+.1f} % (median) against the amplifier's model at the measured "
                "drive: "
                "the amplifier is not the one the estimator was told (piezofin diagnose --amplifier, the "
                "estimator's amplifier parameter), or its law differs; the fin's stages are judged apart"
            )
    if not has_gap and float(stats.chi2.sf(nominal.chi2_test, nominal.n_test)) >= 1e-3:
        w.verdict, w.chosen = "no gap", None
    elif w.fitting:
        w.verdict, w.chosen = "explained", best
    else:
        w.verdict, w.chosen = "unexplained", None
        w.notes.append(
            f"no candidate closes the gap: the best, {best.label}, leaves a held-out chi2 of "
            f"{best.chi2_test:.0f} over {best.n_test} residuals (nominal model: {nominal.chi2_test:.0f})"
        )
        family_of_the_least_bad(w)
        if w.n_train and float(stats.chi2.sf(nominal.chi2_train, w.n_train)) >= 1e-3:
            w.notes.append(
                f"the training trials show no gap (nominal chi2 {nominal.chi2_train:.0f} over {w.n_train} "
                f"residuals; {w.test_text}): the gap is only in the held-out trials, so no effect could be "
                "learnt from the others. Trials between the training and the held-out conditions, where the "
                "gap starts, would let it be fitted"
            )


#: The least-bad candidate names its family when it removes at least this share of the gap.
FAMILY_SHRINK = 0.8


def family_of_the_least_bad(w: Work) -> None:
    """When nothing explains the gap but the least-bad candidate removes most of it (held-out shrink
    >= ``FAMILY_SHRINK``) and all its effects are of one family, that family is the probable cause,
    in a form the library lacks: say so, with how well the form fits."""
    best = w.best
    families = {effect_class(e).family for e in best.effects}
    gone = shrink(w.nominal.chi2_test, best.chi2_test)
    if len(families) != 1 or not gone >= FAMILY_SHRINK:
        # a pair across families is no family; the best single may still be one
        best = w.singles[0]
        families = {effect_class(best.effects[0]).family}
        gone = shrink(w.nominal.chi2_test, best.chi2_test)
        if not gone >= FAMILY_SHRINK:
            return
    (w.family,) = families
    w.family_removed = gone
    titles = " + ".join(effect_class(e).title for e in best.effects)
    w.notes.append(
        f"the gap is most probably in the {w.family} family: {titles} removes {gone:.0%} of it, but its "
        f"form fits the held-out trials only to chi2/n {best.chi2_test / max(best.n_test, 1):.1f}, "
        "so the real law is of that family in another form (model-form error)"
    )


def separate(w: Work) -> None:
    """Step 5: candidates that cannot be told apart, and the experiments that would."""
    if w.chosen is None:
        return
    best = w.best
    for c in w.candidates:
        if (
            c is best
            or len(c.effects) != len(best.effects)
            or c.criterion - best.criterion > w.settings.ambiguity
        ):
            continue
        w.ambiguous.append(c)  # as simple as the chosen one and (almost) as good
    w.experiments = [separating_experiment(best, c, w.trials) for c in w.ambiguous[:3]]


def how_far(w: Work) -> None:
    """Step 6: the held-out gap per channel before and after the best candidate."""
    w.gaps = channel_gaps(w.nominal_model, w.best.model, w.held)
    w.shrink = shrink(w.nominal.chi2_test, w.best.chi2_test)


def refit(w: Work) -> None:
    """Step 7: the chosen effects refitted on all trials (the saved model, with +-)."""
    w.final = w.best.model
    if w.chosen is not None:
        w.say("refitting the chosen effect(s) on all trials")
        start = dict(zip(w.best.effects, w.best.model.values, strict=True))
        w.final = fit(w.fin, w.best.effects, w.trials, start)


#: The diagnosis, step by step (each reads and adds to a :class:`Work`).
PIPELINE: tuple[tuple[str, Callable[[Work], None]], ...] = (
    ("read", read),
    ("where", where),
    ("split", split_trials),
    ("fit singles", fit_singles),
    ("fit pairs", fit_pairs),
    ("choose", choose_explanation),
    ("decide", decide),
    ("separate", separate),
    ("how far", how_far),
    ("refit", refit),
)


def diagnose(
    trials: Trials,
    fin: Fin,
    *,
    library: Sequence[str] | None = None,
    pairs_of: int = 3,
    partners: int = 8,
    ambiguity: float = 6.0,
    close_fraction: float = 0.95,
    max_reduced_chi2: float = 3.0,
    material_sigma: float = 3.0,
    progress: Callable[[str], None] | None = None,
) -> Diagnosis:
    """Where, which and how far: the steps of :data:`PIPELINE`; see the module docstring."""
    settings = Settings(
        tuple(library or LIBRARY),
        pairs_of,
        partners,
        ambiguity,
        close_fraction,
        max_reduced_chi2,
        material_sigma,
    )
    w = Work(trials, fin, settings, progress or (lambda _msg: None))
    for_many_predictions()
    for _name, step in PIPELINE:
        step(w)
    return Diagnosis(
        fin,
        w.trials,  # as read: a reversed sensor corrected
        w.stages,
        w.resonances,
        w.test,
        w.test_text,
        w.candidates,
        w.nominal,
        w.verdict,
        w.chosen,
        w.ambiguous,
        w.experiments,
        w.gaps,
        w.shrink,
        w.final,
        w.notes,
        w.family,
        w.family_removed,
        w.corrections,
    )


def summary_json(d: Diagnosis) -> dict[str, Any]:
    """Everything the report says, as plain JSON types."""

    def cand(c: Candidate) -> dict[str, Any]:
        return {
            "effects": list(c.effects),
            "parameters": c.model.parameters(),
            "uncertainties": {k: dict(v) for k, v in c.model.uncertainties.items()},
            "chi2_train": c.chi2_train,
            "chi2_heldout": c.chi2_test,
            "heldout_residuals": c.n_test,
            "parameters_count": c.k,
            "criterion": c.criterion,
        }

    return {
        "fin": d.fin.name,
        "source": d.trials.source,
        "trials": len(d.trials),
        "verdict": d.verdict,
        "headline": d.headline,
        "corrections": d.corrections,
        "confident": d.confident,
        "named": list(d.named),
        "family": d.family or None,
        "notes": d.notes,
        "where": [s.summary(d.trials) for s in d.stages],
        "resonances": [r.__dict__ for r in d.resonances],
        "holdout": d.holdout_text,
        "which": {
            "chosen": cand(d.chosen) if d.chosen else None,
            "cannot_tell_apart": [cand(c) for c in d.ambiguous],
            "separating_experiments": [e.__dict__ for e in d.experiments],
            "ranking": [cand(c) for c in d.candidates],
            "nominal": cand(d.nominal),
        },
        "how_far": {
            "heldout_shrink": d.shrink,
            "channels": [g.__dict__ for g in d.gaps],
        },
        "augmented_model": d.final_model.to_mapping(),
    }
