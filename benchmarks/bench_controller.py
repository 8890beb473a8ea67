"""Thrust-per-watt controller against the paper's grid and random search, on plants it does not know.

    python benchmarks/bench_controller.py [--seeds 6] [--plot docs/controller.png]
                                          [--plants ...] [--workers 2] [--ray ADDRESS] [--no-drift]

Plants (``piezofin_ros.bench.plants``), each with measurement noise, parameters drawn per seed: the
nominal model; electroelastic softening (resonance down by 10-40 % at 800 Vpp); dielectric loss
(tan delta 0.05-0.3); and softening, loss and a resonance off by up to 15 % together.  Two tasks:
a thrust demand of 30 % of the fin's nominal maximum, and the paper's convention (best frequency
at 800 Vpp, at least 1 mN).  Three fins.  Methods, on the same plants and noise seeds:

* ``ours``: :class:`~piezofin_ros.control.optimise.Optimiser`, continuous trials of 6 s of fin time;
* ``grid``: the paper's 11 frequencies (1-11 Hz) x 3 voltages (400/600/800 Vpp), 30 s protocol
  trials, best measured point so far;
* ``random``: uniform random points, 6 s continuous trials, best measured point so far.

For each: trials and fin time until the recommended point stays at >= 98 % of the true optimum
(dense evaluation of the plant), and the fraction reached at the end.  A drift run follows: the
resonance falls by 10 % over two minutes after convergence.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from piezofin_ros import workers
from piezofin_ros.bench.evaluation import (
    TRIAL_S_CONTINUOUS,
    TRIAL_S_PROTOCOL,
    campaign,
    run_trial,
    score,
    true_optimum,
)
from piezofin_ros.bench.plants import Plant
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.physics.fin import load_fin

LIMITS = OperatingBox(1.0, 20.0, 50.0, 800.0)
GRID = [(float(f), float(v)) for v in (400.0, 600.0, 800.0) for f in range(1, 12)]


@dataclass
class Run:
    method: str
    fractions: list[float]  # after each trial
    trial_s: float

    def trials_to(self, level: float = 0.98) -> int | None:
        """First trial after which the fraction stays >= level (None: never)."""
        ok = np.asarray(self.fractions) >= level
        for k in range(len(ok)):
            if ok[k:].all():
                return k + 1
        return None


PLANTS = ("nominal", "softening", "loss", "combined")
N_OURS = 15


def plants_for(fin_name: str, rng: np.random.Generator) -> dict[str, Plant]:
    fin = load_fin(fin_name)
    return {
        "nominal": Plant(fin, name="nominal"),
        "softening": Plant(fin, softening=float(rng.uniform(0.1, 0.4)), name="softening"),
        "loss": Plant(fin, loss_tan_delta=float(rng.uniform(0.05, 0.3)), name="loss"),
        "combined": Plant(
            fin,
            softening=float(rng.uniform(0.1, 0.4)),
            loss_tan_delta=float(rng.uniform(0.05, 0.3)),
            resonance_scale=float(rng.uniform(0.85, 1.15)),
            name="combined",
        ),
    }


def best_measured(
    points: list[tuple[float, float, float, float]], demand: float | None
) -> tuple[float, float] | None:
    """The measured point a person would pick: most measured T/P among those meeting the need."""
    need = demand if demand is not None else 1e-3
    ok = [
        (t / p, f, v) for f, v, t, p in points if t >= need and p > 0 and (demand is not None or v == 800.0)
    ]
    if not ok:
        return None
    _, f, v = max(ok)
    return f, v


def run_ours(fin_name: str, plant: Plant, demand: float | None, best: float, seed: int, n: int) -> Run:
    opt = Optimiser(load_fin(fin_name), LIMITS, demand_n=demand)
    fr, _ = campaign(opt, plant, n, np.random.default_rng(seed), best=best)
    return Run("ours", fr, TRIAL_S_CONTINUOUS)


def run_points(
    method: str,
    points: list[tuple[float, float]],
    plant: Plant,
    demand: float | None,
    best: float,
    seed: int,
    trial_s: float,
) -> Run:
    rng = np.random.default_rng(seed)
    seen: list[tuple[float, float, float, float]] = []
    fr = []
    for f, v in points:
        thrust, power = plant.measure(f, v, 0.0, rng)
        seen.append((f, v, thrust, power))
        pick = best_measured(seen, demand)
        fr.append(0.0 if pick is None else score(plant, *pick, demand) / best)
    return Run(method, fr, trial_s)


def random_points(demand: float | None, n: int, rng: np.random.Generator) -> list[tuple[float, float]]:
    f = np.exp(rng.uniform(np.log(LIMITS.frequency_min_hz), np.log(LIMITS.frequency_max_hz), n))
    v = (
        rng.uniform(LIMITS.voltage_pp_min, LIMITS.voltage_pp_max, n)
        if demand is not None
        else np.full(n, 800.0)
    )
    return list(zip(f.tolist(), v.tolist(), strict=True))


def drift_run(fin_name: str, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Softening + loss plant; after 60 s the resonance falls linearly by 10 % over 120 s."""
    fin = load_fin(fin_name)

    def scale(t: float) -> float:
        return 1.0 - 0.10 * min(max((t - 60.0) / 120.0, 0.0), 1.0)

    plant = Plant(fin, softening=0.3, loss_tan_delta=0.15, resonance_scale=scale)
    demand = 0.3 * float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    opt = Optimiser(fin, LIMITS, demand_n=demand)
    rng = np.random.default_rng(seed)
    ts, frac_ours, frac_frozen = [], [], []
    frozen = None
    t = 0.0
    while t < 300.0:
        t = run_trial(opt, plant, t, rng)
        c = opt.choice
        assert c is not None
        if frozen is None and t >= 60.0:
            frozen = (c.frequency_hz, c.voltage_pp)  # what a controller that stops learning would hold
        _, _, best = true_optimum(plant, LIMITS, demand, t=t)
        ts.append(t)
        frac_ours.append(score(plant, c.frequency_hz, c.voltage_pp, demand, t=t) / best)
        frac_frozen.append(score(plant, *frozen, demand, t=t) / best if frozen else np.nan)
    return np.array(ts), np.array(frac_ours), np.array(frac_frozen)


def plant_task(task: tuple[str, str, int, int]) -> list[tuple[tuple[str, str, str], Run]]:
    """One plant of one fin, task and seed: ours, the grid and random search on the same plant and
    noise.  The seed's generator is replayed up to this plant (its draws do not depend on the runs),
    so the task gives the same numbers whether it runs alone, on a worker or on a cluster."""
    fin_name, task_name, seed, index = task
    fin = load_fin(fin_name)
    max_thrust = float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    demand = 0.3 * max_thrust if task_name == "demand" else None
    rng = np.random.default_rng(1000 * seed + 7)
    plants = list(plants_for(fin_name, rng).items())
    for _ in range(index):  # the random points of the plants before this one
        random_points(demand, 33, rng)
    pname, plant = plants[index]
    _, _, best = true_optimum(plant, LIMITS, demand)
    runs = [
        run_ours(fin_name, plant, demand, best, seed, N_OURS),
        run_points("grid", GRID, plant, demand, best, seed, TRIAL_S_PROTOCOL),
        run_points("random", random_points(demand, 33, rng), plant, demand, best, seed, TRIAL_S_CONTINUOUS),
    ]
    return [((task_name, pname, r.method), r) for r in runs]


def tasks_for(fins: list[str], seeds: int, plants: list[str]) -> list[tuple[str, str, int, int]]:
    """Every (fin, task, seed, plant index) of a run: the workers' tasks, in the table's order."""
    return [
        (fin_name, task, seed, index)
        for fin_name in fins
        for task in ("demand", "no demand")
        for seed in range(seeds)
        for index in range(len(PLANTS))
        if PLANTS[index] in plants
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--plot", default="docs/controller.png")
    ap.add_argument("--fins", nargs="+", default=["M8528-P1", "M8514-P1", "M8507-P1"])
    ap.add_argument("--plants", nargs="+", default=list(PLANTS), choices=PLANTS)
    ap.add_argument("--no-drift", action="store_true", help="skip the drift run (a table only)")
    workers.add_arguments(ap)
    args = ap.parse_args()
    t0 = time.perf_counter()
    tasks = tasks_for(args.fins, args.seeds, args.plants)
    done = workers.run_parsed(
        plant_task,
        tasks,
        args,
        lambda t: f"{t[0]} {t[1]} seed {t[2]} {PLANTS[t[3]]}",
        prefix="  bench_controller: ",
    )
    results: dict[tuple[str, str, str], list[Run]] = {}
    for runs in done:
        for key, r in runs:
            results.setdefault(key, []).append(r)

    print(f"{len(args.fins)} fins x {args.seeds} seeds per plant and task; median [worst] over runs")
    print(
        f"{'task':<10} {'plant':<10} {'method':<7} {'trials to 98 %':>16} {'fin time to 98 %':>18} "
        f"{'reached 98 %':>12} {'final fraction':>16}"
    )
    for (task, pname, method), runs in results.items():
        k = [r.trials_to() for r in runs]
        reached = [x for x in k if x is not None]
        trials = f"{np.median(reached):.0f} [{max(reached)}]" if reached else "-"
        fin_s = (
            f"{np.median(reached) * runs[0].trial_s:.0f} s [{max(reached) * runs[0].trial_s:.0f}]"
            if reached
            else "-"
        )
        final = [r.fractions[-1] for r in runs]
        print(
            f"{task:<10} {pname:<10} {method:<7} {trials:>16} {fin_s:>18} {len(reached):>5}/{len(runs):<6} "
            f"{np.median(final):>8.3f} [{min(final):.3f}]"
        )
    if args.no_drift:
        print(f"({time.perf_counter() - t0:.0f} s)")
        return 0
    ts, ours, frozen = drift_run(args.fins[0], seed=3)
    after = ts > 200.0
    print(
        f"drift (resonance -10 % over 120 s, {args.fins[0]}, demand): ours {np.min(ours[after]):.3f} of the "
        f"moving optimum after the drift (lowest during it {np.nanmin(ours[(ts > 60) & (ts <= 200)]):.3f}); "
        f"a controller that stopped learning at 60 s: {np.nanmin(frozen[after]):.3f}"
    )
    print(f"({time.perf_counter() - t0:.0f} s)")
    if args.plot:
        plot(args.plot, results, ts, ours, frozen)
        print(f"plot: {args.plot}")
    return 0


def plot(path: str, results: dict, ts: np.ndarray, ours: np.ndarray, frozen: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4), constrained_layout=True)
    colors = {"ours": "C0", "grid": "C1", "random": "C2"}
    for ax, task in zip(axes[:2], ("demand", "no demand"), strict=True):
        for method, c in colors.items():
            runs = [r for (tk, _, m), rs in results.items() if tk == task and m == method for r in rs]
            fin_time = np.arange(1, 34) * runs[0].trial_s
            fr = np.array([np.pad(r.fractions, (0, 33 - len(r.fractions)), mode="edge") for r in runs])
            ax.plot(fin_time, np.median(fr, axis=0), color=c, label=f"{method} (median)")
            ax.fill_between(fin_time, np.min(fr, axis=0), np.max(fr, axis=0), color=c, alpha=0.15)
        ax.axhline(0.98, color="k", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("fin time [s]")
        ax.set_ylabel("fraction of the true optimum (T/P)")
        ax.set_title(f"{task}: all plants, fins, seeds")
        ax.legend(fontsize=8)
    axes[2].plot(ts, ours, label="ours (keeps learning)")
    axes[2].plot(ts, frozen, label="held from 60 s")
    axes[2].axvspan(60, 180, color="0.9", label="resonance -10 %")
    axes[2].set_ylim(0.5, 1.05)
    axes[2].set_xlabel("time [s]")
    axes[2].set_title("drift")
    axes[2].legend(fontsize=8)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
