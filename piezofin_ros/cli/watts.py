"""``piezofin watts``: the best thrust per watt of each fin in each watt, and T/P against frequency
(the paper's Fig. 10) with the paper's 60.7 mN/W marked.  The model's steady state, no ROS."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

import numpy as np

from ..errors import PiezofinError
from ..files import save_figure
from ..physics.amplifier import Amplifier, load_amplifier, power_in, watt_of
from ..physics.fin import load_fin
from ..physics.model import Model, load_model
from .args import PLOT_SUFFIXES, UsageError, add_fins, parse_frequencies, writable_path


class WattsError(UsageError):
    pass


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_fins(p)
    p.add_argument(
        "--amplifiers",
        nargs="+",
        default=["paper-bench", "fish-switching"],
        help="amplifier presets or YAML, one supply watt each (default: paper-bench fish-switching)",
    )
    p.add_argument(
        "--freq", nargs="+", default=["1:16:0.25"], help="frequencies, Hz: values and/or start:stop:step"
    )
    p.add_argument("--voltages", nargs="+", type=float, default=[400.0, 600.0, 800.0], help="Vpp searched")
    p.add_argument("--min-thrust", type=float, default=1e-3, help="least thrust of a best point, N (1 mN)")
    p.add_argument(
        "--twin",
        action="store_true",
        help="each fin as the paper's twin (model preset paper-twin-<fin>: its effects fitted to the paper)",
    )
    p.add_argument("--plot", help="T/P against frequency at the highest voltage, per watt (PNG)")
    p.add_argument("--json", action="store_true", help="the table as JSON on standard output")


def _watts(amplifiers: list[Amplifier]) -> list[tuple[str, str, Amplifier | None]]:
    """(label, watt, amplifier) of every column: the fin's, the apparent, one supply per amplifier."""
    cols: list[tuple[str, str, Amplifier | None]] = [("fin", "fin", None), ("apparent", "apparent", None)]
    cols += [(f"supply ({a.name})", "supply", a) for a in amplifiers]
    return cols


def compute(args: argparse.Namespace) -> dict[str, Any]:
    try:
        fins = [load_fin(f) for f in args.fins]
        amps = [load_amplifier(a) for a in args.amplifiers]
        models = [load_model(f"paper-twin-{f.name}") if args.twin else Model(f) for f in fins]
    except PiezofinError as exc:
        raise WattsError(str(exc)) from None
    freqs = np.asarray(parse_frequencies(args.freq), float)
    if not (math.isfinite(args.min_thrust) and 0 <= args.min_thrust <= 1.0):  # (nan or -1: no floor, unsaid)
        raise WattsError(f"--min-thrust {args.min_thrust}: a thrust within [0, 1] N")
    volts = np.asarray(args.voltages, float)
    if not (np.all(np.isfinite(volts)) and np.all(volts > 0) and np.all(volts <= 1000)):
        raise WattsError(f"--voltages {args.voltages}: each must be within (0, 1000] Vpp")
    f, v = (x.ravel() for x in np.meshgrid(freqs, volts, indexing="ij"))
    out: dict[str, Any] = {
        "watts": {},
        "curves": {},
        "frequencies_hz": freqs.tolist(),
        "v_curve": float(volts.max()),
    }
    out["twin"] = bool(args.twin)
    for fin, model in zip(fins, models, strict=True):
        p = model.predict(f, v)
        thrust = np.asarray(p.thrust_n, float)
        best: dict[str, Any] = {}
        curves: dict[str, list[float]] = {}
        for label, watt, amp in _watts(amps):
            power = power_in(watt, p.voltage_pp_drive, p.current_rms, p.power_w, amp or amps[0])
            ok = (power > 0) & (thrust >= args.min_thrust)
            if not np.any(ok):  # no point gives the least thrust: the best of all, said
                ok = power > 0
            tpw = np.where(ok, thrust / np.maximum(power, 1e-300), -np.inf)
            j = int(np.argmax(tpw))
            best[label] = (
                {
                    "frequency_hz": float(f[j]),
                    "voltage_pp": float(v[j]),
                    "thrust_per_watt": float(tpw[j]),
                    "thrust_n": float(thrust[j]),
                    "below_min_thrust": bool(thrust[j] < args.min_thrust),
                }
                if math.isfinite(tpw[j])
                else None
            )
            top = v == volts.max()
            curves[label] = (thrust[top] / np.maximum(power[top], 1e-300)).tolist()
        out["watts"][fin.name] = best
        out["curves"][fin.name] = curves
    return out


def table(r: dict[str, Any]) -> str:
    from ..diagnosis.paper import PAPER_MAX_TPW  # (scipy.stats and .optimize: a second, for one number)

    labels = list(next(iter(r["watts"].values())))
    width = max(22, *(len(x) + 2 for x in labels))
    lines = [
        ("the paper's twin (config/models/paper-twin-*.yaml): " if r.get("twin") else "the nominal fins: ")
        + "best thrust per watt, mN/W (at Hz, Vpp), among points of at least the least thrust; the paper: "
        f"about {PAPER_MAX_TPW * 1e3:.1f} mN/W for every fin",
        f"{'fin':<10}" + "".join(f"{x:>{width}}" for x in labels),
    ]
    for name, best in r["watts"].items():
        cells = [
            f"{b['thrust_per_watt'] * 1e3:.1f} ({b['frequency_hz']:g}, {b['voltage_pp']:.0f})"
            + ("*" if b["below_min_thrust"] else "")
            if b
            else "-"
            for b in best.values()
        ]
        lines.append(f"{name:<10}" + "".join(f"{c:>{width}}" for c in cells))
    if any(b and b["below_min_thrust"] for best in r["watts"].values() for b in best.values()):
        lines.append("* no point of this fin gives the least thrust: its best point of all")
    amps = [x[len("supply (") : -1] for x in labels if x.startswith("supply")]
    lines.append(
        f"watts: fin: {watt_of('fin').short}; apparent: {watt_of('apparent').short}; supply (amplifier): "
        f"the amplifier's draw from its supply ({', '.join(amps)}: config/amplifiers/)"
    )
    return "\n".join(lines)


def plot(r: dict[str, Any], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..diagnosis.paper import PAPER_MAX_TPW

    labels = list(next(iter(r["curves"].values())))
    # one log scale for every panel: the watts differ 5 to 5,000 times, and the panels show by how much
    fig, axes = plt.subplots(
        1, len(labels), figsize=(3.6 * len(labels), 3.6), constrained_layout=True, sharey=True, squeeze=False
    )
    axes = axes[0]
    f = np.asarray(r["frequencies_hz"])
    for ax, label in zip(axes, labels, strict=True):
        for name, curves in r["curves"].items():
            ax.plot(f, np.asarray(curves[label]) * 1e3, label=name)
        ax.axhline(PAPER_MAX_TPW * 1e3, color="k", ls="--", lw=1, label="paper: 60.7 mN/W")
        ax.set_yscale("log")
        ax.set_title(f"per {label} watt", fontsize=10)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"thrust per {label} watt [mN/W]", fontsize=8)
        ax.yaxis.set_tick_params(labelleft=True)  # (sharey hides the others' tick labels)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    which = "the paper's twin" if r.get("twin") else "the nominal fins"
    fig.suptitle(
        f"Thrust per watt at {r['v_curve']:.0f} Vpp in each watt, {which}"
        " (the paper's Fig. 10: about 60.7 mN/W)"
    )
    save_figure(fig, path)


def run(args: argparse.Namespace) -> int:
    if args.plot:
        writable_path("--plot", args.plot, PLOT_SUFFIXES)  # (before the work)
    r = compute(args)
    if args.json:
        json.dump({"watts": r["watts"]}, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(table(r))
    if args.plot:
        plot(r, args.plot)
        print(f"wrote {args.plot}", file=sys.stderr)
    return 0
