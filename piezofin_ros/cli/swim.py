"""``piezofin swim``: how fast and how far a fish goes on one charge, by how it drives its fins.

Each fin (default: the paper's three, as their twins) as the caudal fin of a body, with a battery
and an amplifier (presets in ``config/bodies``, ``config/batteries``, ``config/amplifiers``): the
steady speed, the supply power, the energy per metre, the range on one charge and the cost of
transport of each strategy of :mod:`piezofin_ros.control.swimming`.  The model's steady state, no ROS.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from typing import Any

from ..control.swimming import STRATEGIES, Fish
from ..errors import PiezofinError
from ..files import save_figure
from ..physics.amplifier import load_amplifier
from ..physics.fin import load_fin
from ..physics.model import Model, load_model
from ..physics.swim import battery_presets, body_presets, load_battery, load_body
from .args import PLOT_SUFFIXES, UsageError, add_fins, writable_path

#: The strategy every other is compared with: what a builder without a model does.
BASELINE = "resonance, full voltage"


class SwimUsageError(UsageError):
    pass


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fins(p)
    p.add_argument(
        "--nominal",
        action="store_true",
        help="the nominal fins (default: each as the paper's twin, paper-twin-<fin>)",
    )
    p.add_argument("--body", default="mfc-fish", help=f"body preset or YAML ({', '.join(body_presets())})")
    p.add_argument(
        "--battery",
        default="li-ion-2s-500mah",
        help=f"battery preset or YAML ({', '.join(battery_presets())})",
    )
    p.add_argument(
        "--amplifier", default="fish-switching", help="amplifier preset or YAML (what the fish carries)"
    )
    p.add_argument(
        "--hotel", type=float, help="the fish's draw besides its fins, W (default: the battery file's)"
    )
    p.add_argument("--voltage-max", type=float, default=800.0, help="the drive's limit, Vpp (800)")
    p.add_argument("--plot", help="range and speed of each strategy, per fin (PNG)")
    p.add_argument("--json", action="store_true", help="the table as JSON on standard output")


#: the range gain over the fixed drive that the table says the fixed draw allows (issue 27's goal)
RANGE_GAIN = 0.3


def compute(args: argparse.Namespace) -> dict[str, Any]:
    if not (math.isfinite(args.voltage_max) and 0 < args.voltage_max <= 1000):
        raise SwimUsageError(f"--voltage-max {args.voltage_max}: within (0, 1000] Vpp")
    try:
        body = load_body(args.body)
        battery = load_battery(args.battery)
        if args.hotel is not None:
            battery = dataclasses.replace(battery, hotel_w=args.hotel)
        amplifier = load_amplifier(args.amplifier)
        fins = [load_fin(f) for f in args.fins]
        models = [Model(f) if args.nominal else load_model(f"paper-twin-{f.name}") for f in fins]
    except PiezofinError as exc:
        raise SwimUsageError(str(exc)) from None
    out: dict[str, Any] = {
        "body": dataclasses.asdict(body),
        "battery": {k: v for k, v in dataclasses.asdict(battery).items() if not k.startswith("ocv")},
        "amplifier": amplifier.name,
        "twin": not args.nominal,
        "fins": {},
        # the fixed draw (hotel + the amplifier's quiescent) below which the range strategy beats the
        # fixed drive at resonance by 30 % (issue 27's goal): above it, the fastest drive goes furthest
        "range_gain": {},
    }
    for model in models:
        fish = Fish(model, body, battery, amplifier, args.voltage_max)
        swims = fish.strategies()
        base = swims[BASELINE].range_m
        rows = {}
        for name, s in swims.items():
            tau = body.time_constant_s(s.thrust0_n, s.frequency_hz, model.fin.L)
            rows[name] = {
                **s.record(),
                "speed_body_lengths_s": s.speed_m_s / body.length_m,
                "range_vs_baseline": s.range_m / base - 1.0 if base > 0 else math.nan,
                "settling_time_constant_s": tau,
            }
        out["fins"][model.fin.name] = rows
        out["range_gain"][model.fin.name] = {
            "gain": RANGE_GAIN,
            "fixed_draw_w": battery.hotel_w + float(getattr(amplifier, "quiescent_w", 0.0)),
            "fixed_draw_below_w": fish.fixed_draw_for(RANGE_GAIN),
        }
    return out


def table(r: dict[str, Any]) -> str:
    b, bat = r["body"], r["battery"]
    lines = [
        f"a fish of {b['mass_kg']:g} kg, {b['length_m'] * 100:g} cm (body {b['name']}: drag area "
        f"{b['drag_area_m2']:g} m^2, {b['fins']} fin(s)), battery {bat['name']} ({bat['cells']} cells, "
        f"{bat['capacity_ah'] * 1e3:g} mA h, hotel load {bat['hotel_w']:g} W), amplifier {r['amplifier']}; "
        + ("each fin as the paper's twin" if r["twin"] else "the nominal fins"),
    ]
    head = f"  {'strategy':<26}{'Hz':>7}{'Vpp':>6}{'thrust mN':>11}{'speed cm/s':>12}{'BL/s':>6}"
    head += f"{'supply mW':>11}{'J/m':>8}{'range km':>10}{'vs base':>9}{'CoT':>6}{'tau s':>7}"
    for name, rows in r["fins"].items():
        lines += ["", f"{name}:", head]
        for strategy in STRATEGIES:
            x = rows[strategy]
            cells = (
                f"{x['frequency_hz']:>7.2f}{x['voltage_pp']:>6.0f}{x['thrust0_n'] * 1e3:>11.2f}",
                f"{x['speed_m_s'] * 100:>12.2f}{x['speed_body_lengths_s']:>6.2f}",
                f"{x['supply_w'] * 1e3:>11.1f}{x['energy_per_m_j']:>8.2f}{x['range_m'] / 1e3:>10.2f}",
                f"{x['range_vs_baseline']:>+9.0%}{x['cost_of_transport']:>6.1f}",
                f"{x['settling_time_constant_s']:>7.1f}",
            )
            lines.append(f"  {strategy:<26}" + "".join(cells))
        g = r["range_gain"][name]
        lines.append(
            f"  the range strategy goes {g['gain']:.0%} beyond '{BASELINE}' only with a fixed draw (hotel "
            f"load + the amplifier's quiescent) below {g['fixed_draw_below_w'] * 1e3:.3g} mW; this fish's "
            f"is {g['fixed_draw_w'] * 1e3:.3g} mW"
        )
    lines += [
        "",
        f"vs base: the range against '{BASELINE}'; supply: the amplifier's draw for the fins (the hotel "
        "load comes on top); J/m: the battery's energy per metre; CoT: (supply + hotel) / (m g U); tau: "
        "the body's time constant at that speed",
    ]
    return "\n".join(lines)


def plot(r: dict[str, Any], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(r["fins"])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
    width = 0.8 / len(STRATEGIES)
    x = np.arange(len(names))
    for k, strategy in enumerate(STRATEGIES):
        rng = [r["fins"][n][strategy]["range_m"] / 1e3 for n in names]
        spd = [r["fins"][n][strategy]["speed_body_lengths_s"] for n in names]
        axes[0].bar(x + k * width, rng, width, label=strategy)
        axes[1].bar(x + k * width, spd, width, label=strategy)
    for ax, label in zip(axes, ("range on one charge [km]", "steady speed [body lengths/s]"), strict=True):
        ax.set_xticks(x + 0.4 - width / 2, names)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
    axes[1].axhline(0.3, color="k", ls="--", lw=1, label="Cen & Erturk's fish: 0.3 BL/s")
    axes[1].legend(fontsize=7)
    fig.suptitle(
        f"A fish on each fin ({'twins' if r['twin'] else 'nominal'}), battery {r['battery']['name']}"
    )
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    if args.plot:
        writable_path("--plot", args.plot, PLOT_SUFFIXES)  # (before the work)
    r = compute(args)
    if args.json:
        json.dump(r, sys.stdout, indent=1, default=float)
        sys.stdout.write("\n")
    else:
        print(table(r))
    if args.plot:
        plot(r, args.plot)
        print(f"wrote {args.plot}", file=sys.stderr)
    return 0
