"""The controller on fins it has never seen: effects outside its correction, and a fish's drive alone.

    python benchmarks/bench_unseen.py [--seeds 2] [--fins M8528-P1 M8514-P1 M8507-P1] [--plot docs/unseen.png]
                                      [--watt supply_measured] [--workers 2] [--ray ADDRESS]

Plants: each fin with one effect of the library that the optimiser's correction does not contain
(amplitude-dependent damping, a Duffing spring, drag and added mass that vary with KC, a coupling
growing as the field squared, an amplifier that sags or clips under its current limit) or a
frequency-independent leak (outside it until the correction took a leak term, 2026-11-25: kept, as
the check that the fit finds it), drawn per seed, on a background of the effects it does contain
(softening up to 0.3, dielectric loss up to tan delta 0.1), with measurement noise (0.5 % + 5 uN / 5
uW, each plant its own draws); and the issue's three hidden fins. Two tasks (a demand of 30 % of the
fin's nominal maximum thrust; the best frequency at 800 Vpp) and three sources: ``loadcell`` (a
rig's load cell: the thrust itself, with noise), ``vibrometer`` (Lighthill on the tip velocity with
the paper's ``c_m``) and ``self`` (a fish: the drive's voltage and current alone, self-sensed with
the paper's ``C_eq`` and ``theta``).

Methods on the same plants and noise, each holding the best measured point that meets the task with
the same margin (measured thrust less 2 standard deviations of its noise):

* ``ours``: :class:`~piezofin_ros.control.optimise.Optimiser`, 6 s continuous trials;
* ``grid``: the paper's 11 frequencies x 3 voltages, 30 s protocol trials;
* ``random``: uniform random points, 6 s trials;
* ``gp-bo``: model-free Bayesian optimisation (the same Gaussian process on log thrust and log power,
  no physics; three random points, then the most optimistic point that meets the demand), 6 s trials.

Scored on the plant itself: the held point's thrust per watt over the true optimum (dense evaluation),
0 when its true thrust misses the demand.  ``--watt`` names the watt (default the fin's, mean(v i)):
with ``supply_measured`` every plant has an amplifier of its own, drawn (a linear stage from +-300 to
+-600 V rails with 0-0.2 W quiescent, or a switching drive 60-95 % efficient recovering 0-80 % with
0-0.1 W), which no method is told: they rank trials by the supply meter's reading (the optimiser's map
assumes the paper's bench), and the score is the plant's true supply watt.  Goal (issue 18): >= 98 %
within 8 trials or 60 s of fin time in >= 95 % of runs, the demand met in truth.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from piezofin_ros import workers
from piezofin_ros.bench.evaluation import (
    TRIAL_S_CONTINUOUS,
    TRIAL_S_PROTOCOL,
    campaign,
    score,
    true_optimum,
)
from piezofin_ros.bench.plants import Plant, read
from piezofin_ros.control.gp import ResidualGP
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.physics.amplifier import (
    WATT,
    Amplifier,
    LinearAmplifier,
    SwitchingAmplifier,
    load_amplifier,
)
from piezofin_ros.physics.effects import AddedMassOffset, DragOffset, make
from piezofin_ros.physics.fin import Fin, load_fin

LIMITS = OperatingBox(1.0, 20.0, 50.0, 800.0)
GRID = [(float(f), float(v)) for v in (400.0, 600.0, 800.0) for f in range(1, 12)]
N_TRIALS = 12
MARGIN_Z = 2.0
#: The amplifier every method is told (the estimator's model): the paper's bench.
TOLD = load_amplifier("paper-bench")


def _i_ref_ma(fin: Fin) -> float:
    """The capacitive current at 10 Hz and 800 Vpp, mA (the amplifiers' limits are drawn around it)."""
    return 2 * math.pi * 10.0 * fin.C_eq * 400.0 * 1e3


#: The effects outside the optimiser's correction (and ``leakage``, inside it since it took a leak
#: term), with how each one's parameters are drawn.
OUTSIDE: dict[str, Callable[[np.random.Generator, Fin], list[float]]] = {
    "nonlinear_damping": lambda rng, fin: [rng.uniform(10.0, 60.0)],
    "stiffness_nonlinearity": lambda rng, fin: [rng.uniform(-20.0, 20.0)],
    "drag_kc": lambda rng, fin: [rng.uniform(-0.5, 0.5)],
    "added_mass_kc": lambda rng, fin: [rng.uniform(0.1, 0.5)],
    "field_coupling": lambda rng, fin: [rng.uniform(0.1, 0.4), rng.uniform(1.6, 2.5)],  # not Rayleigh's p = 1
    "leakage": lambda rng, fin: [rng.uniform(0.02, 0.1) * fin.C_eq / 1.93e-8],
    "amplifier_sag": lambda rng, fin: [rng.uniform(0.8, 1.6) / _i_ref_ma(fin)],
    "amplifier_limit": lambda rng, fin: [rng.uniform(0.8, 1.6) / _i_ref_ma(fin)],
}


def unseen_plant(fin: Fin, effect: str, rng: np.random.Generator) -> Plant:
    """``fin`` with ``effect`` (drawn), softening up to 0.3 and dielectric loss up to tan delta 0.1."""
    values = OUTSIDE[effect](rng, fin)
    return Plant(
        fin,
        softening=float(rng.uniform(0.0, 0.3)),
        loss_tan_delta=float(rng.uniform(0.0, 0.1)),
        effects=(make(effect, values),),
        name=f"{effect} {', '.join(f'{v:.3g}' for v in values)}",
    )


def unseen_amplifier(rng: np.random.Generator) -> Amplifier:
    """An amplifier nobody is told: a linear stage or a switching drive, its parameters drawn."""
    if rng.uniform() < 0.5:
        return LinearAmplifier(
            rail_v=float(rng.uniform(300.0, 600.0)), quiescent_w=float(rng.uniform(0.0, 0.2))
        )
    return SwitchingAmplifier(
        efficiency=float(rng.uniform(0.6, 0.95)),
        recovered=float(rng.uniform(0.0, 0.8)),
        quiescent_w=float(rng.uniform(0.0, 0.1)),
    )


#: The hidden fins of the issue (effects outside the correction the optimiser had then).
ISSUE_PLANTS: dict[str, Callable[[Fin], Plant]] = {
    "M8528-P1": lambda fin: Plant(
        fin, softening=0.35, loss_tan_delta=0.05, name="issue: softening 0.35, tan d 0.05"
    ),
    "M8514-P1": lambda fin: Plant(
        fin,
        effects=(make("field_coupling", [0.3, 1.0]), DragOffset(1.8)),
        name="issue: field coupling 0.3, c_d x 1.8",
    ),
    "M8507-P1": lambda fin: Plant(fin, effects=(AddedMassOffset(1.25),), name="issue: c_m x 1.25"),
}


@dataclass
class Run:
    method: str
    fractions: list[float]  # after each trial
    trial_s: float
    #: ours, from the drive alone: the calibrated self-sensed thrust of the held point against the
    #: truth there, relative, after the last trial (NaN otherwise)
    sensed_error: float = math.nan
    plant: str = ""  # (ours: the fin and its plant, to name the worst run)

    def trials_to(self, level: float = 0.98) -> int | None:
        """First trial after which the fraction stays >= level (None: never)."""
        ok = np.asarray(self.fractions) >= level
        for k in range(len(ok)):
            if ok[k:].all():
                return k + 1
        return None

    def success(self) -> bool:
        k = self.trials_to()
        return k is not None and (k <= 8 or k * self.trial_s <= 60.0)


class Held:
    """The best measured point that meets the task with the margin (what a baseline holds)."""

    def __init__(self, demand: float | None, noise_rel: float) -> None:
        self.demand, self.noise_rel, self.best = demand, noise_rel, None
        self.value = -math.inf

    def add(self, f: float, v: float, thrust: float, power: float) -> None:
        low = thrust * math.exp(-MARGIN_Z * self.noise_rel)
        if power <= 0:
            return
        if self.demand is not None:
            value = self.demand / power if low >= self.demand else -math.inf
        else:
            value = thrust / power if low >= 1e-3 and v == 800.0 else -math.inf
        if value > self.value:
            self.value, self.best = value, (f, v)


def _power(r: Any, watt: str) -> float:
    return float(r.power_w if watt == "fin" else r.power_named_w)


def run_points(
    method: str,
    points: list[tuple[float, float]],
    plant: Plant,
    demand: float | None,
    best: float,
    source: str,
    seed: int,
    trial_s: float,
    watt: str = "fin",
) -> Run:
    rng = np.random.default_rng(seed)
    held = Held(demand, plant.noise.thrust_rel)
    fr = []
    for f, v in points:
        r = read(plant, f, v, 0.0, rng, source, watt=watt, amplifier=TOLD)
        held.add(f, v, r.thrust_n, _power(r, watt))
        fr.append(0.0 if held.best is None else score(plant, *held.best, demand, watt=watt) / best)
    return Run(method, fr, trial_s)


def random_points(demand: float | None, n: int, rng: np.random.Generator) -> list[tuple[float, float]]:
    f = np.exp(rng.uniform(np.log(LIMITS.frequency_min_hz), np.log(LIMITS.frequency_max_hz), n))
    v = (
        rng.uniform(LIMITS.voltage_pp_min, LIMITS.voltage_pp_max, n)
        if demand is not None
        else np.full(n, 800.0)
    )
    return list(zip(f.tolist(), v.tolist(), strict=True))


def run_gpbo(
    plant: Plant, demand: float | None, best: float, source: str, seed: int, watt: str = "fin"
) -> Run:
    """Model-free Bayesian optimisation on the measured log thrust and log power."""
    rng = np.random.default_rng(seed)
    held = Held(demand, plant.noise.thrust_rel)
    points = random_points(demand, 3, rng)
    seen: list[tuple[float, float, float, float]] = []
    fr = []
    gp = ResidualGP()
    for k in range(N_TRIALS):
        if k >= len(points) and not seen:
            points += random_points(demand, 1, rng)
        elif k >= len(points):
            f = np.array([s[0] for s in seen])
            v = np.array([s[1] for s in seen])
            y = np.log(np.array([[s[2], s[3]] for s in seen]))
            mu = y.mean(0)
            gp.fit(f, v, y - mu, np.full_like(y, plant.noise.thrust_rel))
            cand = random_points(demand, 2000, rng)
            cf, cv = np.array(cand).T
            mean, var = gp.predict(cf, cv)
            log_t, log_p = mean[:, 0] + mu[0], mean[:, 1] + mu[1]
            need = demand if demand is not None else 1e-3
            meets = log_t - MARGIN_Z * np.sqrt(var[:, 0] + plant.noise.thrust_rel**2) >= math.log(need)
            objective = (math.log(demand) if demand is not None else log_t) - log_p
            optimism = objective + np.sqrt(var[:, 0] + var[:, 1])
            pick = (
                int(np.argmax(np.where(meets, optimism, -np.inf))) if np.any(meets) else int(np.argmax(log_t))
            )
            points.append((float(cf[pick]), float(cv[pick])))
        f0, v0 = points[k]
        r = read(plant, f0, v0, 0.0, rng, source, watt=watt, amplifier=TOLD)
        power = _power(r, watt)
        if r.thrust_n > 0 and power > 0:
            seen.append((f0, v0, r.thrust_n, power))
        held.add(f0, v0, r.thrust_n, power)
        fr.append(0.0 if held.best is None else score(plant, *held.best, demand, watt=watt) / best)
    return Run("gp-bo", fr, TRIAL_S_CONTINUOUS)


def run_ours(
    fin: Fin, plant: Plant, demand: float | None, best: float, source: str, seed: int, watt: str = "fin"
) -> Run:
    opt = Optimiser(fin, LIMITS, demand_n=demand, source=source, watt=watt, amplifier=TOLD)
    fr, t = campaign(opt, plant, N_TRIALS, np.random.default_rng(seed), best=best)
    error = math.nan
    if source == "self" and (held := opt.status().get("held")):
        truth = float(plant.steady(held["frequency_hz"], held["voltage_pp"], t=t).thrust_n)
        error = held["thrust_n"] / truth - 1.0 if truth > 0 else math.nan
    return Run("ours", fr, TRIAL_S_CONTINUOUS, error)


def plant_task(
    case: tuple[str, str, int, list[str], str],
) -> tuple[list[tuple[tuple[str, str, str], Run]], list[str]]:
    """:func:`plant_runs` of one (fin, effect, seed, sources): a worker's task."""
    return plant_runs(*case)


def plant_runs(
    fin_name: str, effect: str, seed: int, sources: list[str], watt: str = "fin"
) -> tuple[list[tuple[tuple[str, str, str], Run]], list[str]]:
    """Every method on one plant, both tasks, each source (one worker's share)."""
    fin = load_fin(fin_name)
    max_thrust = float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    rng = np.random.default_rng(zlib.crc32(f"{fin_name} {effect} {seed}".encode()))
    plant = ISSUE_PLANTS[fin_name](fin) if effect == "issue" else unseen_plant(fin, effect, rng)
    if watt != "fin":
        plant = replace(plant, amplifier=unseen_amplifier(rng))
    out, failures = [], []
    seed = zlib.crc32(f"{fin_name} {effect} {seed} trials".encode())  # (each plant its own noise)
    for task, demand in (("demand", 0.3 * max_thrust), ("no demand", None)):
        _, _, best = true_optimum(plant, LIMITS, demand, watt=watt)
        for source in sources:
            runs = [
                run_ours(fin, plant, demand, best, source, seed, watt),
                run_gpbo(plant, demand, best, source, seed, watt),
                run_points("grid", GRID, plant, demand, best, source, seed, TRIAL_S_PROTOCOL, watt),
                run_points(
                    "random",
                    random_points(demand, 33, rng),
                    plant,
                    demand,
                    best,
                    source,
                    seed,
                    TRIAL_S_CONTINUOUS,
                    watt,
                ),
            ]
            runs[0] = replace(runs[0], plant=f"{fin_name} {plant.name}")
            out += [((source, task, r.method), r) for r in runs]
            if not runs[0].success():
                failures.append(
                    f"{fin_name} {plant.name} {task} {source}: "
                    + " ".join(f"{x:.2f}" for x in runs[0].fractions)
                )
            if abs(runs[0].sensed_error) > 0.05:
                failures.append(
                    f"{fin_name} {plant.name} {task} {source}: the held point's self-sensed thrust "
                    f"{100 * runs[0].sensed_error:+.1f} % against the truth, after calibration"
                )
    return out, failures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--fins", nargs="+", default=["M8528-P1", "M8514-P1", "M8507-P1"])
    ap.add_argument("--sources", nargs="+", default=["loadcell", "vibrometer", "self"])
    ap.add_argument("--effects", nargs="+", default=list(OUTSIDE))
    ap.add_argument("--watt", default="fin", choices=list(WATT), help="the watt of the thrust per watt")
    workers.add_arguments(ap)
    ap.add_argument("--plot", default="")
    args = ap.parse_args()
    t0 = time.perf_counter()
    cases = [
        (fin_name, effect, seed, list(args.sources), args.watt)
        for fin_name in args.fins
        for effect in [*args.effects, "issue"]
        for seed in (range(args.seeds) if effect != "issue" else [0])
    ]
    results: dict[tuple[str, str, str], list[Run]] = {}
    failures: list[str] = []
    done = workers.run_parsed(
        plant_task, cases, args, lambda c: f"{c[0]} {c[1]} seed {c[2]}", prefix="  plants "
    )
    for runs, missed in done:  # in the cases' order: the same table on any number of workers
        for key, r in runs:
            results.setdefault(key, []).append(r)
        failures += missed
    print(
        f"{len(args.fins)} fins x ({len(args.effects)} effects x {args.seeds} seeds + the issue's hidden "
        f"fin), thrust per {args.watt} watt"
        + (" (each plant its own amplifier, nobody told it)" if args.watt != "fin" else "")
    )
    print(
        "| source | task | method | reach 98 % within 8 trials or 60 s | median trials (fin time) to 98 % "
        "| final fraction: median [worst] | demand missed in truth at the end |"
    )
    print("|---|---|---|---|---|---|---|")
    for (source, task, method), runs in results.items():
        k = [r.trials_to() for r in runs]
        reached = [x for x in k if x is not None]
        ok = sum(r.success() for r in runs)
        median = (
            f"{np.median(reached):.0f} ({np.median(reached) * runs[0].trial_s:.0f} s)" if reached else "-"
        )
        final = [r.fractions[-1] for r in runs]
        missed = f"{sum(x == 0.0 for x in final)}/{len(runs)}" if task == "demand" else ""
        print(
            f"| {source} | {task} | {method} | {ok}/{len(runs)} ({100 * ok / len(runs):.0f} %) | {median} | "
            f"{np.median(final):.3f} [{min(final):.3f}] | {missed} |"
        )
    for (source, task, method), runs in results.items():
        if method == "ours":
            at8 = [r.fractions[min(7, len(r.fractions) - 1)] for r in runs]
            print(
                f"{source}, {task}, {method}: after 8 trials, median {np.median(at8):.3f} "
                f"[worst {min(at8):.3f}, {runs[int(np.argmin(at8))].plant}]"
            )
        errors = np.abs([r.sensed_error for r in runs if math.isfinite(r.sensed_error)])
        if errors.size:
            print(
                f"{source}, {task}, {method}: the held point's calibrated self-sensed thrust against the "
                f"truth: within 5 % in {np.sum(errors <= 0.05)}/{errors.size}, "
                f"median {100 * np.median(errors):.1f} %, worst {100 * errors.max():.1f} %"
            )
    print(f"ours, runs that missed the goal ({len(failures)}):")
    for line in failures:
        print("  " + line)
    print(f"({time.perf_counter() - t0:.0f} s)")
    if args.plot:
        plot(args.plot, results)
        print(f"plot: {args.plot}")
    return 0


def plot(path: str, results: dict[tuple[str, str, str], list[Run]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    order = ["loadcell", "vibrometer", "self"]
    sources = sorted({s for s, _, _ in results}, key=lambda s: order.index(s) if s in order else len(order))
    tasks = sorted({t for _, t, _ in results})  # ("demand", "no demand")
    fig, axes = plt.subplots(
        len(tasks),
        len(sources),
        figsize=(3.6 * len(sources), 2.9 * len(tasks)),
        sharex=True,
        sharey=True,
        squeeze=False,
        constrained_layout=True,
    )
    colors = {"ours": "C0", "gp-bo": "C3", "grid": "C1", "random": "C2"}
    for (i, task), (j, source) in ((it, js) for it in enumerate(tasks) for js in enumerate(sources)):
        ax = axes[i, j]
        for method, c in colors.items():
            runs = results.get((source, task, method), [])
            if not runs:
                continue
            n = max(len(r.fractions) for r in runs)
            fin_time = np.arange(1, n + 1) * runs[0].trial_s
            fr = np.array([np.pad(r.fractions, (0, n - len(r.fractions)), mode="edge") for r in runs])
            ax.plot(fin_time, np.median(fr, axis=0), color=c, label=method)
            ax.fill_between(fin_time, np.percentile(fr, 5, axis=0), np.max(fr, axis=0), color=c, alpha=0.12)
        ax.axhline(0.98, color="k", lw=0.8, ls="--")
        ax.axvline(60.0, color="k", lw=0.6, ls=":")
        ax.set_xscale("log")
        ax.set_ylim(0, 1.05)
        ax.set_title(f"{source}, {task}", fontsize=10)
        if i == len(tasks) - 1:
            ax.set_xlabel("fin time [s]")
        if j == 0:
            ax.set_ylabel("held point / true optimum")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    fig.suptitle(
        "line: median over the plants; band: 5th percentile to best; dashed: 98 %; dotted: 60 s",
        fontsize=9,
    )
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
