"""The paper's own gap, decided with every fact it gives (``piezofin diagnose --paper``).

The paper publishes no per-trial table, only facts about its three fins (reading notes):

* M8528-P1 operates near 5.5 Hz at 800 Vpp (its largest tip velocity; the linear model: 9.9 Hz);
* the maximum thrust per watt (Lighthill's thrust on the measured motion over the "average
  power") is about 60.7 mN/W for each fin (the model: hundreds to thousands);
* the power near resonance at 800 Vpp goes 1 : 2 : 5 for psi 5.4 : 3.9 : 2.1;
* the T/P band is broader for a larger psi;
* ``c_m`` follows Eq. (21) (0.70, 0.95, 1.00): at a low drive, the in-water resonance is the one the
  fin's Table 2 values and ``c_m(psi)`` give.

A *hypothesis* is a definition of the "average power" (:data:`POWER_DEFINITIONS`: ``mean(v i)`` as
the model assumes, ``Vrms x Irms`` as a meter's "power" of a reactive load reads, or a class-B
amplifier's draw from its rails) and none, one or two effects of the library, with parameters shared
by the three fins (they are one material, one rig, one amplifier).  Each is fitted to all the facts at
once (:func:`fit_hypothesis`, weighted least squares, the facts' tolerances as sigmas); those whose
``chi^2`` the tolerances explain (p >= 0.01) *survive*.  The report lists the survivors, says which
fact eliminates the others (:func:`deciding_facts`), and where the survivors' predictions differ
most: the measurement that would decide between them (:func:`deciding_measurement`).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DiagnosisError
from ..physics.amplifier import PAPER_BENCH
from ..physics.effects import LIBRARY, effect_class
from ..physics.fin import Fin, load_fin
from ..physics.model import Model, Prediction, for_many_predictions
from ..workers import run_tasks
from .space import ParamSpace

FloatArray = NDArray[Any]

PAPER_FINS = ("M8528-P1", "M8514-P1", "M8507-P1")  # psi 2.1, 3.9, 5.4
PAPER_OPERATION_HZ = 5.5
PAPER_MAX_TPW = 0.0607
PAPER_POWER_RATIO = {"M8507-P1": 1.0, "M8514-P1": 2.0, "M8528-P1": 5.0}
#: Class-B rails of the amplifier for the "amplifier draw" definition: the 800 Vpp drive's peak.
RAIL_V = PAPER_BENCH.rail_v


def _power_real(p: Prediction, vpp: FloatArray) -> FloatArray:
    return np.asarray(p.power_w, float)


def _power_apparent(p: Prediction, vpp: FloatArray) -> FloatArray:
    return np.asarray(p.voltage_pp_drive, float) / (2 * math.sqrt(2)) * np.asarray(p.current_rms, float)


def _power_draw(p: Prediction, vpp: FloatArray) -> FloatArray:
    # a class-B stage from +-RAIL_V delivering a sine of peak current I draws (2/pi) RAIL_V I
    return PAPER_BENCH.steady(p.voltage_pp_drive, p.current_rms, p.power_w)


#: What "average power" may have meant: name -> (power of a prediction, description).
POWER_DEFINITIONS: dict[str, tuple[Callable[[Prediction, FloatArray], FloatArray], str]] = {
    "mean(v i)": (_power_real, "the mean of v(t) i(t), as the paper states and the model assumes"),
    "Vrms x Irms": (_power_apparent, "the apparent power a meter reads on a reactive load"),
    "amplifier draw": (_power_draw, f"a class-B amplifier's draw from +-{RAIL_V:g} V rails"),
}


@dataclass(frozen=True)
class Fact:
    name: str
    value: float
    sigma: float
    text: str  # what the paper says


FACTS = (
    Fact("resonance_M8528-P1", PAPER_OPERATION_HZ, 0.5, "M8528-P1 operates near 5.5 Hz at 800 Vpp"),
    *(
        Fact(f"max_tpw_{nm}", PAPER_MAX_TPW, 0.2 * PAPER_MAX_TPW, f"max T/P about 60.7 mN/W ({nm})")
        for nm in PAPER_FINS
    ),
    Fact("power_ratio_M8528-P1", 5.0, 1.5, "power near resonance, psi 2.1 : psi 5.4 about 5 : 1"),
    Fact("power_ratio_M8514-P1", 2.0, 0.6, "power near resonance, psi 3.9 : psi 5.4 about 2 : 1"),
    Fact("band_order", 0.0, 0.1, "the T/P band is broader for a larger psi"),
    *(
        Fact(f"c_m_{nm}", 1.0, 0.03, f"c_m of Eq. (21) for {nm}: its low-drive in-water resonance")
        for nm in PAPER_FINS
    ),
)

# Effects that cannot act in the paper's setup, or move none of its facts, with the reason.
NOT_IN_THE_PAPERS_SETUP = {
    "swim_speed": "quiescent water, U -> 0",
    "loadcell_offset": "T/P uses Lighthill's thrust on the motion, not the load cell",
    "loadcell_gain": "T/P uses Lighthill's thrust on the motion, not the load cell",
    "vibrometer_delay": "a lag of the vibrometer moves no fact (magnitudes only)",
    "resonance_drift": "the facts carry no time",
    "capacitance_drift": "the facts carry no time",
    "coupling_drift": "the facts carry no time",
}
CANDIDATES = tuple(n for n in LIBRARY if n not in NOT_IN_THE_PAPERS_SETUP)


def half_max_band(f: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Lowest and highest frequency around the peak of ``y`` where ``y`` is at least half its
    maximum; NaN when the peak is at an end of the samples (no peak inside them)."""
    ok = np.isfinite(y)
    f, y = f[ok], y[ok]
    if f.size < 3:
        return math.nan, math.nan
    k = int(np.argmax(y))
    if k in (0, f.size - 1):
        return math.nan, math.nan
    above = y >= 0.5 * y[k]
    lo, hi = k, k
    while lo > 0 and above[lo - 1]:
        lo -= 1
    while hi < f.size - 1 and above[hi + 1]:
        hi += 1
    return float(f[lo]), float(f[hi])


def _peak(f: FloatArray, y: FloatArray) -> float:
    """Frequency of the largest ``y``, refined by the parabola through its neighbours."""
    k = int(np.nanargmax(y))
    if 0 < k < f.size - 1:
        y0, y1, y2 = y[k - 1 : k + 2]
        den = y0 - 2 * y1 + y2
        if den < 0:
            return float(f[k] + 0.5 * (y0 - y2) / den * (f[1] - f[0]))
    return float(f[k])


def _grid(fin: Fin) -> FloatArray:
    """The paper's 1-11 Hz sweep, widened to the fin's band (its in-water resonance x 1.3)."""
    return np.linspace(1.0, max(11.0, 1.3 * fin.f_water_linear), 41)


@dataclass
class Fins:
    """The three fins and their grids (computed once)."""

    fins: dict[str, Fin] = field(default_factory=lambda: {nm: load_fin(nm) for nm in PAPER_FINS})

    def grid(self, name: str) -> FloatArray:
        return _grid(self.fins[name])

    def low_grid(self, name: str) -> FloatArray:
        return np.linspace(0.6, 1.4, 41) * self.fins[name].f_water_linear

    def low_peak(self, name: str) -> float:
        """The nominal model's in-water resonance at 100 Vpp (what c_m of Eq. 21 gives)."""
        if name not in self._low:
            f = self.low_grid(name)
            p = Model(self.fins[name]).predict(f, np.full(f.size, 100.0))
            self._low[name] = _peak(f, np.asarray(p.tip_velocity_rms))
        return self._low[name]

    _low: dict[str, float] = field(default_factory=dict)


def quantities(models: dict[str, Model], definition: str, fins: Fins) -> dict[str, float]:
    """The facts' quantities for one hypothesis (a model per fin, one power definition)."""
    power_of = POWER_DEFINITIONS[definition][0]
    out: dict[str, float] = {}
    bands: dict[str, float] = {}
    p_res: dict[str, float] = {}
    for nm, model in models.items():
        f, fl = fins.grid(nm), fins.low_grid(nm)
        # one prediction for the sweep at 800 Vpp and the low drive's (100 Vpp) around resonance:
        # a model's cost is mostly per call, not per point
        both = model.predict(np.concatenate([f, fl]), np.repeat([800.0, 100.0], [f.size, fl.size]))
        p, low = _part(both, slice(0, f.size)), _part(both, slice(f.size, None))
        v = np.full(f.size, 800.0)
        power = power_of(p, v)
        tpw = np.divide(p.thrust_n, power, out=np.zeros(f.size), where=power > 0)
        f_res = _peak(f, np.asarray(p.tip_velocity_rms))
        out[f"resonance_{nm}"] = f_res
        out[f"max_tpw_{nm}"] = float(np.max(tpw))
        p_res[nm] = float(np.interp(f_res, f, power))
        lo, hi = half_max_band(f, tpw)
        bands[nm] = (hi - lo) / _peak(f, tpw) if math.isfinite(lo) else math.nan
        # c_m: the in-water resonance at a low drive (100 Vpp) against the nominal model's
        out[f"c_m_{nm}"] = _peak(fl, np.asarray(low.tip_velocity_rms)) / fins.low_peak(nm)
    for nm in ("M8528-P1", "M8514-P1"):
        out[f"power_ratio_{nm}"] = p_res[nm] / p_res["M8507-P1"] if p_res["M8507-P1"] > 0 else math.inf
    b = [bands[nm] for nm in PAPER_FINS]  # psi up
    # how far the band order is from "broader for larger psi": the largest relative inversion
    out["band_order"] = (
        max(0.0, *(math.log(x / y) for x, y in itertools.pairwise(b)))
        if all(math.isfinite(x) and x > 0 for x in b)
        else 1.0  # no peak of T/P inside the band: no band to order
    )
    return out


def _part(p: Prediction, part: slice) -> Prediction:
    """The prediction at a slice of its points."""
    arrays = {f.name: getattr(p, f.name) for f in fields(p)}
    return replace(p, **{name: x[part] for name, x in arrays.items() if x is not None})


def _residuals(q: dict[str, float]) -> FloatArray:
    r = []
    for fact in FACTS:
        x = q[fact.name]
        if fact.name.startswith(("max_tpw", "power_ratio")):  # ratios: judged in log, symmetric
            d = math.log(max(x, 1e-12) / fact.value) * fact.value
        else:
            d = x - fact.value
        r.append(d / fact.sigma)
    return np.asarray(r, float)


@dataclass(frozen=True)
class Hypothesis:
    definition: str
    effects: tuple[str, ...]
    parameters: dict[str, dict[str, float]]
    predicted: dict[str, Any]
    residuals: tuple[float, ...]  # per fact, in sigmas
    #: one standard deviation of each parameter, from the fit's Jacobian (the facts' tolerances as
    #: sigmas); NaN where the facts do not determine it
    sigmas: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def k(self) -> int:
        return sum(len(effect_class(e).params) for e in self.effects)

    @property
    def chi2(self) -> float:
        return float(np.sum(np.square(self.residuals)))

    @property
    def p_value(self) -> float:
        from scipy import stats  # (here: the paper's constants are read by every command line's parser)

        return float(stats.chi2.sf(self.chi2, max(len(FACTS) - self.k, 1)))

    @property
    def survives(self) -> bool:
        return self.p_value >= 0.01

    @property
    def label(self) -> str:
        return f"[{self.definition}] " + (" + ".join(self.effects) if self.effects else "no effect")


def fit_hypothesis(definition: str, names: tuple[str, ...], fins: Fins | None = None) -> Hypothesis:
    """The effects' parameters (shared by the three fins) that best reproduce every fact."""
    fins = fins or _fins()
    for_many_predictions()
    spaces = {nm: ParamSpace(fin, names) for nm, fin in fins.fins.items()}

    def evaluate(z: FloatArray) -> dict[str, float]:
        return quantities({nm: sp.model(z) for nm, sp in spaces.items()}, definition, fins)

    def res(z: FloatArray) -> FloatArray:
        try:
            r = _residuals(evaluate(z))
        except (ValueError, FloatingPointError, ZeroDivisionError):
            return np.full(len(FACTS), 1e3)
        return np.where(np.isfinite(r), r, 1e3)

    if names:
        from scipy import optimize

        first = next(iter(spaces.values()))
        zlo, zhi = first.z_bounds
        best = None
        for start in (0.5, -0.5):
            z0 = np.clip(np.full(len(first.params), start), zlo + 1e-9, zhi - 1e-9)
            with np.errstate(all="ignore"):
                sol = optimize.least_squares(res, z0, bounds=(zlo, zhi), diff_step=0.05, max_nfev=40)
            if best is None or sol.cost < best.cost:
                best = sol
        assert best is not None
        z = best.x
        sigma_z = _sigma_of(np.asarray(best.jac, float))
    else:
        z = sigma_z = np.empty(0)
    q = evaluate(z)
    space = next(iter(spaces.values()))
    m = space.model(z)
    sigma_x = sigma_z * space.scale
    sigmas: dict[str, dict[str, float]] = {}
    j = 0
    for e in m.effects:
        sigmas[e.name] = {k: float(sigma_x[j + i]) for i, k in enumerate(e.parameters())}
        j += len(e.parameters())
    return Hypothesis(definition, names, m.parameters(), q, tuple(float(x) for x in res(z)), sigmas)


def _sigma_of(jac: FloatArray) -> FloatArray:
    """One sigma of each fitted coordinate from the Jacobian of residuals in sigmas (NaN: undetermined)."""
    try:
        cov = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.full(jac.shape[1], math.nan)
    d = np.diag(cov)
    return np.where(d > 0, np.sqrt(np.abs(d)), math.nan)


def _fit_job(args: tuple[str, tuple[str, ...]]) -> Hypothesis:
    return fit_hypothesis(*args, fins=_fins())


def _fit_all(
    jobs: list[tuple[str, tuple[str, ...]]],
    say: Callable[[str], None],
    workers: int | None,
    ray_address: str | None,
) -> list[Hypothesis]:
    """Each ``(definition, effects)`` hypothesis fitted, on ``workers`` processes or on Ray, with a
    line said as each ends."""
    return run_tasks(
        _fit_job,
        jobs,
        workers=workers,
        ray_address=ray_address,
        say=say,
        label=lambda job: f"[{job[0]}] " + (" + ".join(job[1]) or "no effect"),
    )


@functools.cache
def _fins() -> Fins:
    """The three fins, read once per process (when first needed, not at import)."""
    return Fins()


def paper_gap(
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    candidates: Sequence[str] = CANDIDATES,
    definitions: Sequence[str] = tuple(POWER_DEFINITIONS),
    pairs_of: int = 5,
    ray_address: str | None = None,
) -> dict[str, Any]:
    """Every hypothesis: each definition with no effect, each single effect, and the pairs of its
    ``pairs_of`` best singles; fitted on ``workers`` processes (default: one per core), or on Ray
    (``ray_address``, :func:`piezofin_ros.workers.run_tasks`).  The result does not depend on either."""
    say = progress or (lambda _m: None)

    def run(jobs: list[tuple[str, tuple[str, ...]]], stage: str) -> list[Hypothesis]:
        return _fit_all(jobs, lambda line: say(f"paper facts, {stage}: {line}"), workers, ray_address)

    singles = run([(d, names) for d in definitions for names in [(), *((n,) for n in candidates)]], "singles")
    pairs_jobs = []
    for d in definitions:
        ranked = sorted((h for h in singles if h.definition == d and h.effects), key=lambda h: h.chi2)
        best = [h.effects[0] for h in ranked[:pairs_of]]
        pairs_jobs += [(d, tuple(sorted(p))) for p in itertools.combinations(best, 2)]
    pairs = run(pairs_jobs, "pairs")
    every = sorted(singles + pairs, key=lambda h: (not h.survives, h.chi2, len(h.effects), h.label))
    return {
        "facts": FACTS,
        "hypotheses": every,
        "candidates": tuple(candidates),
        "definitions": tuple(definitions),
    }


def deciding_facts(hypotheses: Sequence[Hypothesis]) -> list[tuple[Fact, int]]:
    """Per fact, how many hypotheses it alone rules out (its residual beyond 3 sigma)."""
    return [(fact, sum(1 for h in hypotheses if abs(h.residuals[j]) > 3)) for j, fact in enumerate(FACTS)]


def deciding_measurement(a: Hypothesis, b: Hypothesis, fins: Fins | None = None) -> str:
    """Where two hypotheses' predictions of what a rig measures differ most (relative)."""
    fins = fins or _fins()
    if a.definition != b.definition:
        return (
            f"record v(t) and i(t) and compute both mean(v i) and Vrms x Irms (and the amplifier's supply "
            f"current): '{a.definition}' against '{b.definition}' is a question of definition, not of the fin"
        )
    best = (0.0, "")
    for nm, fin in fins.fins.items():
        ma, mb = (
            Model.of(fin, {k: list(v.values()) for k, v in a.parameters.items()}),
            Model.of(fin, {k: list(v.values()) for k, v in b.parameters.items()}),
        )
        f = fins.grid(nm)
        for vpp in (200.0, 400.0, 600.0, 800.0):
            pa, pb = ma.predict(f, np.full(f.size, vpp)), mb.predict(f, np.full(f.size, vpp))
            for ch, label in (
                ("tip_velocity_rms", "tip velocity"),
                ("power_w", "mean(v i)"),
                ("current_rms", "RMS current"),
            ):
                ya, yb = np.asarray(getattr(pa, ch)), np.asarray(getattr(pb, ch))
                d = np.abs(ya - yb) / np.maximum(np.maximum(np.abs(ya), np.abs(yb)), 1e-30)
                j = int(np.argmax(d))
                if d[j] > best[0]:
                    best = (
                        float(d[j]),
                        f"the {label} of {nm} at {f[j]:.1f} Hz, {vpp:.0f} Vpp ({d[j]:.0%} apart)",
                    )
    return best[1] or "nothing the rig measures tells them apart"


def paper_text(r: dict[str, Any]) -> str:
    hyps: list[Hypothesis] = r["hypotheses"]
    nominal = {h.definition: h for h in hyps if not h.effects}
    survivors = [h for h in hyps if h.survives]
    lines = [
        "# The paper's own gap: every fact, all three fins at once",
        "",
        "| fact (the paper) | value | " + " | ".join(f"nominal model, {d}" for d in nominal) + " |",
        "|---|---:|" + "---:|" * len(nominal),
    ]
    for fact in FACTS:
        cells = " | ".join(_fmt(fact.name, h.predicted[fact.name]) for h in nominal.values())
        lines.append(
            f"| {fact.text} | {_fmt(fact.name, fact.value)} +- {_fmt(fact.name, fact.sigma)} | {cells} |"
        )
    lines += [
        "",
        "Not tried, as they cannot act in the paper's setup or move none of its facts: "
        + "; ".join(f"{n} ({why})" for n, why in NOT_IN_THE_PAPERS_SETUP.items() if n in LIBRARY)
        + ".",
        "",
        f"Hypotheses: {len(POWER_DEFINITIONS)} definitions of the average power x (no effect, "
        f"{len(r['candidates'])} single effects, pairs of the 5 best singles), parameters shared by the "
        f"three fins, fitted to the {len(FACTS)} facts; a hypothesis survives when p >= 0.01.",
        "",
        f"## Surviving every fact: {len(survivors)} of {len(hyps)}",
        "",
    ]
    if survivors:
        lines += ["| hypothesis | parameters | chi2 | p |", "|---|---|---:|---:|"]
        for h in survivors[:15]:
            lines.append(f"| {h.label} | {_params(h)} | {h.chi2:.1f} | {h.p_value:.2g} |")
    else:
        lines.append(
            "None: no definition of the power with at most two effects of the library reproduces every fact."
        )
    lines += [
        "",
        "## The closest that do not survive",
        "",
        "| hypothesis | parameters | chi2 | worst fact |",
        "|---|---|---:|---|",
    ]
    for h in [h for h in hyps if not h.survives][:10]:
        j = int(np.argmax(np.abs(h.residuals)))
        lines.append(
            f"| {h.label} | {_params(h)} | {h.chi2:.1f} | {FACTS[j].text}: "
            f"{_fmt(FACTS[j].name, h.predicted[FACTS[j].name])} ({h.residuals[j]:+.1f} sigma) |"
        )
    lines += ["", "## Which facts decide", ""]
    for fact, n in sorted(deciding_facts(hyps), key=lambda x: -x[1]):
        lines.append(f"- {fact.text}: rules out {n} of {len(hyps)} hypotheses on its own (beyond 3 sigma)")
    lines += ["", "## The measurement that would decide", ""]
    stated = next((h for h in hyps if h.definition == "mean(v i)"), None)  # the best with the paper's
    rivals = survivors[1:4] or [h for h in hyps if not h.survives][:1]
    if stated is not None and survivors and stated not in rivals and stated is not survivors[0]:
        rivals.append(stated)
    for other in rivals if survivors else []:
        lines.append(f"- {survivors[0].label} or {other.label}: {deciding_measurement(survivors[0], other)}")
    figs = "the paper's Figs. 7-9, digitised into a CSV (`piezofin diagnose sweep.csv`)"
    lines.append(f"- {figs} would test every hypothesis trial by trial, with the current's phase")
    return "\n".join(lines) + "\n"


def _params(h: Hypothesis) -> str:
    return (
        "; ".join(f"{n}: " + ", ".join(f"{k}={v:.3g}" for k, v in p.items()) for n, p in h.parameters.items())
        or "-"
    )


def _fmt(name: str, x: float) -> str:
    if name.startswith("resonance"):
        return f"{x:.2f} Hz"
    if name.startswith("max_tpw"):
        return f"{x * 1e3:.1f} mN/W"
    return f"{x:.2f}"


def summary_json(r: dict[str, Any]) -> dict[str, Any]:
    return {
        "facts": [f.__dict__ for f in FACTS],
        "hypotheses": [
            {
                "definition": h.definition,
                "effects": list(h.effects),
                "parameters": h.parameters,
                "chi2": h.chi2,
                "p_value": h.p_value,
                "survives": h.survives,
                "residuals_sigma": dict(zip((f.name for f in FACTS), h.residuals, strict=True)),
            }
            for h in r["hypotheses"]
        ],
    }


# ------------------------------------------------------------------------------------ the twin
@dataclass(frozen=True)
class Twin:
    """The paper's rig as a twin: the hypothesis that explains its facts best, and its rivals."""

    hypothesis: Hypothesis
    rivals: tuple[Hypothesis, ...]  # the others that survive every fact, best first
    tried: int  # hypotheses weighed for it

    def models(self, fins: Fins | None = None) -> dict[str, Model]:
        """Each paper fin with the twin's effects (shared by the three), their sigmas and provenance."""
        fins = fins or _fins()
        h = self.hypothesis
        notes = {
            "twin": "the paper's rig as a twin (`piezofin diagnose --paper --twin DIR`)",
            "hypothesis": h.label,
            "watt": f"{PAPER_BENCH.describe()}: config/amplifiers/paper-bench.yaml",
            "chi2": round(h.chi2, 3),
            "p_value": round(h.p_value, 4),
            "fin": "the paper's Tables 1-2 (the preset); the effects fitted to the paper's ten facts",
        }
        out = {}
        for nm, fin in fins.fins.items():
            m = Model.of(fin, {k: list(v.values()) for k, v in h.parameters.items()})
            out[nm] = Model(m.fin, m.effects, notes, h.sigmas)
        return out


def paper_twin(
    result: dict[str, Any],
    progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    candidates: Sequence[str] = CANDIDATES,
    ray_address: str | None = None,
    most_effects: int = 5,
) -> Twin:
    """The twin from :func:`paper_gap`'s hypotheses: the best that survives with the amplifier's draw
    with every one and every two further candidate effects (all of them: a greedy step through the
    most probable triple misses the best quadruple on the paper's facts), then forward selection
    from the most probable so far (it with each further effect, while the p-value rises, up to
    ``most_effects``).  The p-value is the chi2 on its own degrees of freedom.  The most probable of
    all is the twin, the other survivors its rivals."""
    say = progress or (lambda _m: None)
    survivors = [h for h in result["hypotheses"] if h.survives and h.definition == "amplifier draw"]
    if not survivors:
        raise DiagnosisError("no hypothesis with the amplifier's draw survives the paper's facts: no twin")
    base = survivors[0]
    further = [c for c in candidates if c not in base.effects]
    every, tried = list(survivors), len(result["hypotheses"])

    def fit(names: list[tuple[str, ...]], stage: str) -> list[Hypothesis]:
        nonlocal tried
        jobs = [("amplifier draw", n) for n in dict.fromkeys(tuple(sorted(n)) for n in names)]
        tried += len(jobs)
        return _fit_all(jobs, lambda line: say(f"paper twin, {stage}: {line}"), workers, ray_address)

    names = [(*base.effects, c) for c in further]
    names += [(*base.effects, *pair) for pair in itertools.combinations(further, 2)]
    every += fit([n for n in names if len(n) <= most_effects], "one or two more effects")
    best = min(every, key=lambda h: (-h.p_value, h.chi2))
    while len(best.effects) < most_effects:
        more = fit([(*best.effects, c) for c in candidates if c not in best.effects], "one more effect")
        every += more
        top = min(more, key=lambda h: (-h.p_value, h.chi2), default=best)
        if top.p_value <= best.p_value:
            break
        best = top
    every.sort(key=lambda h: (-h.p_value, h.chi2))
    return Twin(every[0], tuple(h for h in every[1:] if h.survives), tried)


def _all_within(twin: Twin) -> str:
    """Whether any hypothesis tried puts every fact within its tolerance.  (One that did would have
    chi2 <= 10 on at least 5 degrees of freedom, p >= 0.07: a survivor, so the survivors suffice.)"""
    every = (twin.hypothesis, *twin.rivals)
    inside = [h for h in every if max(abs(r) for r in h.residuals) <= 1]
    if inside:
        return (
            f"{len(inside)} of the {twin.tried} hypotheses put all {len(FACTS)} facts within their tolerance."
        )
    closest = min(every, key=lambda h: max(abs(r) for r in h.residuals))
    worst = max(abs(r) for r in closest.residuals)
    return (
        f"None of the {twin.tried} hypotheses puts all {len(FACTS)} facts within their tolerance; the "
        f"closest, {closest.label}, has every one within {worst:.2f} of it."
    )


def twin_text(twin: Twin) -> str:
    h = twin.hypothesis
    amp = PAPER_BENCH
    lines = [
        "# The paper's rig as a twin",
        "",
        f"The twin: the paper's three fins (Tables 1-2) with {' and '.join(h.effects) or 'no effect'}, "
        f"shared by the three, and the watt of {amp.describe()} (config/amplifiers/paper-bench.yaml). "
        f"Chosen among {twin.tried} hypotheses weighed against the paper's {len(FACTS)} facts: "
        f"chi2 {h.chi2:.1f} on {len(FACTS) - h.k} degrees of freedom, p = {h.p_value:.2g}.",
        "",
        "| parameter | value | 1 sigma | from |",
        "|---|---:|---:|---|",
    ]
    for name, params in h.parameters.items():
        for k, v in params.items():
            sd = h.sigmas.get(name, {}).get(k, math.nan)
            lines.append(
                f"| {name}.{k} | {v:.4g} | {sd:.2g} | fitted to the facts (the Jacobian, the facts' "
                "tolerances as sigmas) |"
            )
    lines.append(f"| amplifier rail_v | {amp.rail_v:g} V | - | the 800 Vpp drive's peak: the bench's rails |")
    lines += [
        "",
        "| fact (the paper) | paper | twin | residual | within its tolerance |",
        "|---|---:|---:|---:|---|",
    ]
    for fact, r in zip(FACTS, h.residuals, strict=True):
        within = "yes" if abs(r) <= 1 else ("within 2 sigma" if abs(r) <= 2 else "no")
        lines.append(
            f"| {fact.text} | {_fmt(fact.name, fact.value)} +- {_fmt(fact.name, fact.sigma)} | "
            f"{_fmt(fact.name, h.predicted[fact.name])} | {r:+.2f} sigma | {within} |"
        )
    n_in = sum(abs(r) <= 1 for r in h.residuals)
    lines += [
        "",
        f"{n_in} of {len(FACTS)} facts within their tolerance, every one within "
        f"{max(abs(r) for r in h.residuals):.1f} of it. Max T/P per the supply watt: "
        + ", ".join(f"{nm} {h.predicted[f'max_tpw_{nm}'] * 1e3:.1f} mN/W" for nm in PAPER_FINS)
        + f" (the paper: about {PAPER_MAX_TPW * 1e3:.1f}).",
        "",
        _all_within(twin),
        "",
        "## What the facts cannot decide",
        "",
    ]
    if twin.rivals:
        for other in twin.rivals[:5]:
            lines.append(
                f"- {other.label} (p = {other.p_value:.2g}) also survives; what would decide: "
                f"{deciding_measurement(h, other)}"
            )
    else:
        lines.append("- no other hypothesis survives every fact")
    lines.append(
        "- the paper's Figs. 7-9, digitised into a CSV (`piezofin diagnose sweep.csv`), and the amplifier's "
        "supply current recorded beside v(t) and i(t) would test the twin trial by trial"
    )
    return "\n".join(lines) + "\n"
