"""The fish swims: speed against set-point, settling, energy per metre and range, per strategy.

    python benchmarks/bench_fish.py [--fins M8528-P1 M8514-P1 M8507-P1] [--duration 400]
                                    [--unseen leakage drag_kc ...] [--plot docs/fish.png]
                                    [--json out.json] [--workers 2]

Each fin as the paper's twin (``config/models/paper-twin-<fin>.yaml``) carries the body
``mfc-fish`` with the battery ``li-ion-2s-500mah`` and the amplifier ``fish-switching``, and swims
from rest for ``--duration`` s of fish time with a set-point of 65 % of its fastest steady speed,
stepped to 85 % halfway (:func:`~piezofin_ros.bench.fishrun.swim_run`: the fish stack's science
without ROS, the speed loop with its defaults and ``config/fish.yaml``'s 8 mN cap).  The drives
(:data:`~piezofin_ros.bench.fishrun.STRATEGIES`): the optimising controller on the drive's voltage
and current alone, ranking by the supply watt or by the fin's ``mean(v i)``; the resonance with the
loop's demand turned into a voltage through the model; the paper's grid measured in the tank, its
cheapest point that meets the demand; the resonance at full voltage; the paper's 5.5 Hz / 800 Vpp.

Per step, in truth: the speed's mean error over its second half, the settling time (``settle``:
the speed within 5 % of the set-point from then on), the time from which it is held as a fish's goal
asks (``held``: within 5 % then, every minute's mean after within 5 % and 95 % of the time after;
:meth:`~piezofin_ros.bench.fishrun.Trace.held_s`), the battery's energy per metre and the range on one
charge at that draw (the hotel load included), over the step's second half, and the step's
deepest ``cut`` (issue 39: no trial while swimming may give less than 90 % of the speed loop's
demand): the least share of the demand the thrust in truth gave for a second or more once the speed
had reached half its set-point, and how long (:meth:`~piezofin_ros.bench.fishrun.Trace.cuts`).
``least`` is the fish's own bound: the range at the set-point's speed on the least supply power any
point of the model gives it (:class:`~piezofin_ros.control.swimming.Fish`).

``--unseen EFFECT ...``: each twin also carries, per effect, one the fish's builder is not told
(``bench_unseen.py``'s library outside the optimiser's correction, its values drawn per fin): the
drives still know the twin alone, the fin swims with both.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from piezofin_ros import workers
from piezofin_ros.bench.fishrun import MEASURED, STRATEGIES, Trace, drive_for, swim_run
from piezofin_ros.bench.plants import Plant
from piezofin_ros.control.speedloop import SpeedLoopConfig
from piezofin_ros.control.swimming import Fish
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.model import Model, load_model
from piezofin_ros.physics.swim import load_battery, load_body

FINS = ("M8528-P1", "M8514-P1", "M8507-P1")
STEPS = (0.65, 0.85)  # of the fin's fastest steady speed
CAP_N = 0.008  # config/fish.yaml's loop.max_demand_n


def fish(fin: str, unseen: str | None = None) -> tuple[Fish, Fish, Plant]:
    """The fish its builder knows (the twin) and the fin in truth (the twin, with ``unseen``)."""
    model = load_model(f"paper-twin-{fin}")
    amp = load_amplifier("fish-switching")
    f = Fish(model, load_body("mfc-fish"), load_battery("li-ion-2s-500mah"), amp)
    effects, name = tuple(model.effects), fin
    if unseen is not None:
        from bench_unseen import OUTSIDE  # (this folder's: the effects outside the correction)

        from piezofin_ros.physics.effects import make

        values = OUTSIDE[unseen](np.random.default_rng(zlib.crc32(f"{fin} {unseen}".encode())), model.fin)
        effects += (make(unseen, values),)
        name = f"{fin} + {unseen} {', '.join(f'{v:.3g}' for v in values)}"
    truth = Fish(Model(model.fin, effects), f.body, f.battery, amp)
    return f, truth, Plant(model.fin, effects=effects, amplifier=amp, name=name)


#: Fish the stack is not told (issue 39): another body (more drag, a linear term), another amplifier
#: and battery draw, a speed sensor with a bias, and a fin with effects (the nominal M8528-P1 with
#: softening and more drag; with a dielectric loss, a field-dependent coupling and more added mass).
#: Each is given the paper's twin as its prior (``config/fish.yaml``'s model), wrong on purpose.
STRANGERS: dict[str, dict[str, Any]] = {
    "stranger 1": {
        "effects": {"electroelastic_softening": [0.3], "drag_offset": [2.5]},
        "body": {"mass_kg": 0.55, "added_mass_kg": 0.06, "drag_area_m2": 1.4e-3, "drag_linear_n_s_m": 0.004},
        "amplifier": {"efficiency": 0.75, "recovered": 0.2, "quiescent_w": 0.08, "bus_v": 7.4},
        "speed_bias_m_s": 0.001,
        "speed_noise_m_s": 0.003,
        "setpoints_m_s": (0.066, 0.086),
    },
    "stranger 2": {
        "effects": {"dielectric_loss": [0.06], "field_coupling": [0.25, 2.0], "added_mass_offset": [1.15]},
        "body": {"mass_kg": 0.4, "added_mass_kg": 0.04, "drag_area_m2": 1.5e-3, "drag_linear_n_s_m": 0.002},
        "amplifier": {"efficiency": 0.9, "recovered": 0.6, "quiescent_w": 0.03, "bus_v": 7.4},
        "speed_bias_m_s": -0.0008,
        "speed_noise_m_s": 0.002,
        "setpoints_m_s": (0.046, 0.06),
    },
    # the README's fish driver (test/fish_driver.py), as the live tests run it: the nominal fin, a
    # body whose drag at 5 cm/s is 39 % above the told law's, an amplifier that recovers nothing
    "stranger 3": {
        "effects": {},
        "body": {"mass_kg": 0.5, "added_mass_kg": 0.0, "drag_area_m2": 1.5e-3, "drag_linear_n_s_m": 0.004},
        "amplifier": {"efficiency": 0.7, "recovered": 0.0, "quiescent_w": 0.12, "bus_v": 7.6},
        "speed_bias_m_s": 0.001,
        "speed_noise_m_s": 0.002,
        "setpoints_m_s": (0.05, 0.065),
    },
}


def stranger(name: str) -> tuple[Fish, Fish, Plant, dict[str, Any]]:
    """The fish its builder is told (the twin, the mfc-fish body, fish-switching) and the stranger in
    truth, with what the run needs besides (its sensor)."""
    from dataclasses import replace

    from piezofin_ros.physics.amplifier import SwitchingAmplifier
    from piezofin_ros.physics.effects import make
    from piezofin_ros.physics.fin import load_fin

    spec = STRANGERS[name]
    told = Fish(
        load_model("paper-twin-M8528-P1"),
        load_body("mfc-fish"),
        load_battery("li-ion-2s-500mah"),
        load_amplifier("fish-switching"),
    )
    fin = load_fin("M8528-P1")
    effects = tuple(make(k, v) for k, v in spec["effects"].items())
    amp = SwitchingAmplifier(name=f"{name}'s", **spec["amplifier"])
    body = replace(told.body, name=f"{name}'s body", **spec["body"])
    truth = Fish(Model(fin, effects), body, told.battery, amp)
    plant = Plant(fin, effects=effects, amplifier=amp, name=name)
    return told, truth, plant, spec


def fastest_m_s(f: Fish) -> float:
    freqs = np.geomspace(1.0, 30.0, 400)
    return float(np.max(f.at(freqs, np.full_like(freqs, f.voltage_pp_max), ranges=False)["speed_m_s"]))


def least_supply_w(f: Fish, speed_m_s: float) -> float:
    """The least supply power (all fins) at which the model's fish holds ``speed_m_s``."""
    grid = f.at(
        *np.meshgrid(np.geomspace(1.0, 30.0, 300), np.linspace(50.0, f.voltage_pp_max, 300)), ranges=False
    )
    ok = grid["speed_m_s"] >= speed_m_s
    return float(np.min(grid["supply_w"][ok])) if ok.any() else math.nan


def run(task: tuple[str, str, float, str | None] | tuple[str, str, float, str | None, int]) -> dict[str, Any]:
    """One fish, one strategy, ``duration`` s of fish time, each twin with an ``unseen`` effect or none;
    a fifth element draws another seed of the fish's noise (0: the tables' own)."""
    fin, strategy, duration, unseen = task[:4]
    draw = task[4] if len(task) > 4 else 0
    extra: dict[str, Any] = {}
    if fin in STRANGERS:
        f, truth, plant, spec = stranger(fin)
        body = truth.body  # (the stranger swims with its own body; the speed loop is told mfc-fish)
        extra = {
            "estimator_model": f.model,
            "speed_bias_m_s": spec["speed_bias_m_s"],
            "speed_noise_m_s": spec["speed_noise_m_s"],
            "measured_supply": True,
            "setpoints_m_s": spec["setpoints_m_s"],
        }
    else:
        f, truth, plant = fish(fin, unseen)
        body = f.body
    top = fastest_m_s(truth)
    half = duration / 2
    first, second = extra.pop("setpoints_m_s", (STEPS[0] * top, STEPS[1] * top))
    schedule = [(0.0, first), (half, second)]
    t0 = time.perf_counter()
    trace = swim_run(
        plant,
        body,
        drive_for(strategy, f.model, plant, f.amplifier),
        schedule,
        duration,
        f.battery,
        loop_config=SpeedLoopConfig(max_demand_n=CAP_N),
        seed=zlib.crc32(plant.name.encode()) % 1000 + draw,
        told_body=f.body,
        **extra,
    )
    wall = time.perf_counter() - t0
    steps = []
    for k, (t_step, u_set) in enumerate(schedule):
        t_end = schedule[k + 1][0] if k + 1 < len(schedule) else duration
        mid = 0.5 * (t_step + t_end)
        u = trace.mean("speed_m_s", mid, t_end)
        supply = trace.mean("supply_w", mid, t_end)
        least = least_supply_w(truth, u_set)
        steps.append(
            {
                "setpoint_m_s": u_set,
                "speed_m_s": u,
                "error": u / u_set - 1.0,
                "settling_s": trace.settling_s(t_step, t_end),
                "held_s": trace.held_s(t_step, t_end),
                "cuts": trace.cuts(t_step, t_end),
                "supply_w": supply,
                "energy_per_m_j": trace.energy_per_m(mid, t_end),
                "range_m": float(f.battery.range_m(supply, u)),
                "least_supply_w": least,
                "range_least_m": float(f.battery.range_m(least, u_set)),
                "cost_of_transport": float(f.body.cost_of_transport(supply + f.battery.hotel_w, u)),
            }
        )
    return {
        "fin": plant.name,
        "strategy": strategy,
        "steps": steps,
        "wall_s": wall,
        "trace": trace,
        "seed": draw,
    }


def settled(seconds: float) -> str:
    """A settling time as the table says it: ``never`` where the speed did not settle within 5 %."""
    return f"{seconds:.1f}" if math.isfinite(seconds) else "never"


def worst_cut(cuts: list[tuple[float, float, float]]) -> str:
    """A step's deepest cut as the table says it: its share of the demand and its length (``none``:
    the thrust in truth never under 90 % of the demand for a second while swimming)."""
    if not cuts:
        return "none"
    _, length, share = min(cuts, key=lambda c: c[2])
    return f"{share:.2f} {length:.1f}s"


def spread(results: list[dict[str, Any]]) -> str:
    """Per fish, strategy and step, over the seeds: the held time's least, median and most, and how many
    seeds had a cut, the deepest and the longest (a held time from rest is one draw of the noise: the
    same stack held stranger 3 after 13-45 s over six seeds of 1,500 s runs)."""
    lines = [f"\nover {len({r['seed'] for r in results})} seeds (held s: least, median, most; cuts):"]
    for fin in dict.fromkeys(r["fin"] for r in results):
        for strategy in dict.fromkeys(r["strategy"] for r in results if r["fin"] == fin):
            runs = [r for r in results if (r["fin"], r["strategy"]) == (fin, strategy)]
            for k, step in enumerate(runs[0]["steps"]):
                held = np.array([r["steps"][k]["held_s"] for r in runs])
                cuts = [c for r in runs for c in r["steps"][k]["cuts"]]
                cut = "none"
                if cuts:
                    cut = (
                        f"in {sum(bool(r['steps'][k]['cuts']) for r in runs)}: deepest "
                        f"{min(c[2] for c in cuts):.2f}, longest {max(c[1] for c in cuts):.1f}s"
                    )
                lines.append(
                    f"  {fin + ',' if k == 0 else '':16s} {strategy if k == 0 else '':34s} "
                    f"{step['setpoint_m_s'] * 100:5.2f} cm/s  held {settled(float(np.min(held)))}, "
                    f"{settled(float(np.median(held)))}, {settled(float(np.max(held)))}  cuts {cut}"
                )
    return "\n".join(lines)


def table(results: list[dict[str, Any]]) -> str:
    lines = []
    for fin in dict.fromkeys(r["fin"] for r in results):
        lines.append(f"\n{fin}:")
        lines.append(
            f"  {'strategy':34s} {'set cm/s':>8s} {'speed':>6s} {'err':>6s} {'settle s':>8s} {'held s':>7s} "
            f"{'supply mW':>9s} {'least mW':>8s} {'J/m':>6s} {'range km':>8s} {'CoT':>5s} {'cut':>10s}"
        )
        for r in (r for r in results if r["fin"] == fin):
            for k, s in enumerate(r["steps"]):
                name = r["strategy"] if k == 0 else ""
                lines.append(
                    f"  {name:34s} {s['setpoint_m_s'] * 100:8.2f} {s['speed_m_s'] * 100:6.2f} "
                    f"{s['error'] * 100:+5.1f}% {settled(s['settling_s']):>8s} {settled(s['held_s']):>7s} "
                    f"{s['supply_w'] * 1e3:9.1f} "
                    f"{s['least_supply_w'] * 1e3:8.1f} {s['energy_per_m_j']:6.2f} {s['range_m'] / 1e3:8.2f} "
                    f"{s['cost_of_transport']:5.2f} {worst_cut(s['cuts']):>10s}"
                )
    return "\n".join(lines)


def plot_strangers(results: list[dict[str, Any]], path: Path) -> None:
    """Per stranger: the speed in truth per strategy against the set-point; what the speed loop asks,
    the thrust in truth and the stack's self-sensed estimate (ours)."""
    import matplotlib.pyplot as plt

    fins = list(dict.fromkeys(r["fin"] for r in results))
    fig, ax = plt.subplots(2, len(fins), figsize=(6 * len(fins), 7), constrained_layout=True, squeeze=False)
    for k, fin in enumerate(fins):
        mine = [r for r in results if r["fin"] == fin]
        ours: Trace = next(r["trace"] for r in mine if r["strategy"].startswith("ours"))
        for r in mine:
            tr: Trace = r["trace"]
            ax[0, k].plot(
                tr.t,
                tr.speed_m_s * 100,
                lw=1.4 if r["strategy"].startswith("ours") else 0.8,
                label=r["strategy"],
            )
        sp = ours.setpoint_m_s * 100
        ax[0, k].plot(ours.t, sp, "k--", lw=1, label="set-point")
        ax[0, k].fill_between(ours.t, sp * 0.95, sp * 1.05, color="k", alpha=0.08, label="within 5 %")
        ax[0, k].set_ylabel("speed in truth, cm/s")
        ax[0, k].set_title(f"{fin}: the paper's twin given as its fin's model")
        ax[0, k].legend(fontsize=7)
        ax[1, k].plot(ours.t, ours.demand_n * 1e3, label="demand (speed loop)")
        ax[1, k].plot(ours.t, ours.thrust_n * 1e3, label="thrust in truth")
        ax[1, k].plot(
            ours.t,
            ours.thrust_estimate_n * 1e3,
            ".",
            ms=2,
            label="self-sensed by the estimator (the twin's calibration, then the fit's)",
        )
        ax[1, k].plot(
            ours.t,
            ours.thrust_fitted_n * 1e3,
            ".",
            ms=2,
            label="self-sensed, as the optimiser's fit reads it",
        )
        ax[1, k].set_title(
            "ours: what the speed loop asks, what the fin gives, what the estimator reads", fontsize=9
        )
        ax[1, k].set_ylabel("thrust per fin, mN")
        ax[1, k].set_xlabel("fish time, s")
        ax[1, k].legend(fontsize=7)
    fig.savefig(path, dpi=90)


def plot(results: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if all(r["fin"] in STRANGERS for r in results):
        plot_strangers(results, path)
        return
    fin = results[0]["fin"]
    mine = [r for r in results if r["fin"] == fin]
    fig, ax = plt.subplots(4, 1, figsize=(9, 11), constrained_layout=True)
    ours: Trace = next(r["trace"] for r in mine if r["strategy"].startswith("ours"))
    for r in mine:
        tr: Trace = r["trace"]
        ax[0].plot(
            tr.t,
            tr.speed_m_s * 100,
            lw=1.6 if r["strategy"].startswith("ours (s") else 0.9,
            label=r["strategy"],
        )
    ax[0].plot(ours.t, ours.setpoint_m_s * 100, "k--", lw=1, label="set-point")
    ax[0].set_ylabel("speed, cm/s (in truth)")
    ax[0].set_title(f"{fin} (paper twin) in body mfc-fish, set-point stepped: speed per strategy")
    ax[0].legend(fontsize=7, ncol=2)
    ax[1].plot(ours.t, ours.demand_n * 1e3, label="demand (speed loop)")
    ax[1].plot(ours.t, ours.thrust_n * 1e3, label="thrust in truth")
    # the estimator reads the current's motional part through the fin file's coupling and c_m (here
    # the nominal fin's, 30-50 % low on the twin) until the optimiser's fit, calibrated from the
    # trials, fits four of them: then through the fit's (controller/model), on the red dots
    ax[1].plot(
        ours.t,
        ours.thrust_estimate_n * 1e3,
        ".",
        ms=2,
        label="self-sensed by the estimator (the fin file's calibration, then the fit's)",
    )
    ax[1].plot(
        ours.t, ours.thrust_fitted_n * 1e3, ".", ms=2, label="self-sensed, as the optimiser's fit reads it"
    )
    ax[1].set_ylabel("thrust per fin, mN")
    ax[1].set_title("ours (supply watt): what the speed loop asks, what the fin gives")
    ax[1].legend(fontsize=7)
    ax2 = ax[2].twinx()
    ax[2].plot(ours.t, ours.soc * 100, color="C2", label="charge")
    ax2.plot(ours.t, ours.supply_w * 1e3, color="C3", lw=0.7, label="supply")
    ax[2].set_ylabel("battery charge, %")
    ax2.set_ylabel("fins' supply draw, mW")
    ax[2].set_xlabel("fish time, s")
    ax[2].set_title("ours (supply watt): the battery (the 0.25 W hotel load drains it too)")
    fins = list(dict.fromkeys(r["fin"] for r in results))
    width = 0.8 / len(STRATEGIES)
    for j, name in enumerate(STRATEGIES):
        ranges = [
            next(
                (r["steps"][-1]["range_m"] / 1e3 for r in results if r["fin"] == f and r["strategy"] == name),
                0,
            )
            for f in fins
        ]
        ax[3].bar(np.arange(len(fins)) + j * width, ranges, width, label=name)
    ax[3].set_xticks(np.arange(len(fins)) + 0.4 - width / 2, fins)
    ax[3].set_ylabel("range on one charge, km")
    ax[3].set_title("range at the second set-point (85 % of the fastest), per strategy")
    ax[3].legend(fontsize=7, ncol=2)
    fig.savefig(path, dpi=90)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fins", nargs="+", default=list(FINS))
    ap.add_argument("--strategies", nargs="+", default=list(STRATEGIES))
    ap.add_argument("--duration", type=float, default=400.0, help="fish time per run, s")
    ap.add_argument(
        "--unseen", nargs="*", default=[], metavar="EFFECT", help="also each twin with each of these effects"
    )
    ap.add_argument(
        "--strangers",
        action="store_true",
        help="the fish the stack is not told (STRANGERS), the paper's twin given as their prior",
    )
    ap.add_argument(
        "--seeds",
        type=int,
        default=1,
        help="draws of the fish's noise per run (the tables: the first; more: their spread as well)",
    )
    ap.add_argument("--plot", type=Path)
    ap.add_argument("--json", type=Path)
    workers.add_arguments(ap)
    a = ap.parse_args(argv)
    bad = [s for s in a.strategies if s not in (*STRATEGIES, MEASURED)]
    if bad:
        ap.error(f"unknown strategy {bad[0]!r}: one of {', '.join((*STRATEGIES, MEASURED))}")
    if a.strangers:
        a.fins = list(STRANGERS)
        if a.strategies == list(STRATEGIES):
            a.strategies = [MEASURED, "resonance, voltage from the loop"]
    if a.unseen:
        from bench_unseen import OUTSIDE

        if unknown := [e for e in a.unseen if e not in OUTSIDE]:
            ap.error(f"unknown effect {unknown[0]!r}: one of {', '.join(OUTSIDE)}")
    if a.seeds < 1:
        ap.error(f"--seeds must be 1 or more, got {a.seeds}")
    tasks = [
        (fin, s, a.duration, u, k)
        for fin in a.fins
        for u in [None, *a.unseen]
        for s in a.strategies
        for k in range(a.seeds)
    ]
    t0 = time.perf_counter()
    results = workers.run_parsed(
        run,
        tasks,
        a,
        lambda t: f"{t[0]}{' + ' + t[3] if t[3] else ''} {t[1]}{f' seed +{t[4]}' if t[4] else ''}",
    )
    print(table([r for r in results if r["seed"] == 0]))
    if a.seeds > 1:
        print(spread(results))
    wall = time.perf_counter() - t0
    runs = f"{len(tasks)} run{'s' if len(tasks) != 1 else ''}"
    print(f"\n{runs} of {a.duration:g} s of fish time in {wall:.2f} s of wall time")
    if a.json:
        a.json.write_text(
            json.dumps([{k: v for k, v in r.items() if k != "trace"} for r in results], indent=1)
        )
    if a.plot:
        plot([r for r in results if r["seed"] == 0], a.plot)
        print(f"plot: {a.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
