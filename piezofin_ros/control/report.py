"""The controller's results as a person reads them: the trial table, the stepped sine's table and
the trials' plot (thrust per watt in the watt named), shared by ``bringup`` and the CLI.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..estimation.estimator import per_watt_field, source_of, tpw_field
from ..files import save_figure
from ..physics.amplifier import PAPER_BENCH, Amplifier, power_in, watt_of
from ..physics.model import Model


def _fmt(x: float | None, scale: float, digits: int) -> str:
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x * scale:.{digits}f}"


def _tpw(r: dict[str, float], watt: str, source: str) -> float | None:
    """A record's thrust per watt in ``watt`` of ``source`` (None where records of older bags lack it;
    a watt no estimate field records, from its thrust and its power)."""
    if not watt_of(watt).field:
        return per_watt_field(r, watt, source)
    return r.get(tpw_field(watt, source))


def _or_nan(x: float | None) -> float:
    return math.nan if x is None else float(x)


def trial_table(
    records: Sequence[dict[str, float]],
    chosen: dict[str, float] | None,
    watt: str = "fin",
    source: str = "vibrometer",
) -> str:
    """A fixed-width table of trial records (the controller's status ``results``): thrusts, then the
    power and thrust per watt of ``source`` in the fin's watt and, when it is another, in ``watt``."""
    watts = ["fin"] if watt_of(watt).is_fin else ["fin", watt]
    head = f"{'trial':>5} {'f [Hz]':>7} {'Vpp':>5} {'T [mN]':>8} {'T_self':>8} {'T_cell':>8}"
    for w in watts:
        head += f" {'P_' + w + ' [mW]':>{max(13, len(w) + 8)}} {'T/P_' + w:>{max(10, len(w) + 4)}}"
    lines = [
        f"(T/P in mN/W of the {'self-sensed' if source_of(source).self_sensed else source} thrust; "
        + "; ".join(f"{w}: {watt_of(w).short}" for w in watts)
        + ")",
        head,
        "-" * len(head),
    ]
    for r in records:
        mark = " <- chosen" if chosen is not None and r["trial"] == chosen["trial"] else ""
        row = (
            f"{int(r['trial']):>5} {r['frequency_hz']:>7.2f} {r['voltage_pp']:>5.0f} "
            f"{_fmt(r.get('thrust_n'), 1e3, 3):>8} {_fmt(r.get('thrust_self_n'), 1e3, 3):>8} "
            f"{_fmt(r.get('thrust_loadcell_n'), 1e3, 3):>8}"
        )
        for w in watts:
            row += (
                f" {_fmt(watt_of(w).read(r), 1e3, 3):>{max(13, len(w) + 8)}}"
                f" {_fmt(_tpw(r, w, source), 1e3, 1):>{max(10, len(w) + 4)}}"
            )
        lines.append(row + mark)
    return "\n".join(lines)


def frf_table(records: Sequence[dict[str, float]]) -> str:
    """A stepped sine's points: frequency, voltage, RMS tip velocity and current, dwell."""
    head = f"{'point':>5} {'f [Hz]':>8} {'Vpp':>5} {'u [mm/s]':>9} {'I [uA]':>8} {'dwell [s]':>9}"
    lines = [head, "-" * len(head)]
    starts = [r["t_start"] for r in records] + [math.nan]
    for r, t_next in zip(records, starts[1:], strict=True):
        dwell = t_next - r["t_start"]
        lines.append(
            f"{int(r['trial']):>5} {r['frequency_hz']:>8.3f} {r['voltage_pp']:>5.0f} "
            f"{_fmt(r.get('tip_velocity_rms'), 1e3, 2):>9} {_fmt(r.get('current_rms'), 1e6, 2):>8} "
            f"{_fmt(dwell, 1.0, 1):>9}"
        )
    lines.append("(a stepped sine: `piezofin identify --air/--water <bag>` fits the fin to it)")
    return "\n".join(lines)


def plot_trials(
    path: str | os.PathLike[str],
    model: Model,
    records: Sequence[dict[str, float]],
    chosen: dict[str, float] | None,
    title: str = "",
    watt: str = "fin",
    amplifier: Amplifier = PAPER_BENCH,
    model_name: str = "",
) -> Path:
    """Measured thrust, power and thrust per watt (in ``watt``) against frequency, beside the curves
    of the model that ran (``model``, named in the legends as ``model_name``: a twin's trials under the
    nominal fin's curves read as a gap that is not there), its power in ``watt`` through
    ``amplifier``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    volts = sorted({r["voltage_pp"] for r in records})
    freqs = [r["frequency_hz"] for r in records]
    f_dense = np.linspace(max(0.2, min(freqs) * 0.8), max(freqs) * 1.1, 300)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    name = model_name or ("the paper's model" if not model.effects else "the model")
    for j, v in enumerate(volts):
        c = colors[j % len(colors)]
        pred = model.predict(f_dense, np.full_like(f_dense, v))
        power = power_in(watt, pred.voltage_pp_drive, pred.current_rms, pred.power_w, amplifier)
        rs = [r for r in records if r["voltage_pp"] == v and "thrust_n" in r]
        f = [r["frequency_hz"] for r in rs]
        readers: tuple[Callable[[dict[str, float]], float | None], ...] = (
            lambda r: r["thrust_n"],
            watt_of(watt).read,
            lambda r: _tpw(r, watt, "vibrometer"),
        )
        models = (pred.thrust_n, power, np.asarray(pred.thrust_n) / power)
        scale = 1e3  # (mN, mW, mN/W)
        for ax, read, mkey in zip(axes, readers, models, strict=True):
            ax.plot(f_dense, np.asarray(mkey) * scale, color=c, lw=1, alpha=0.6, label=f"{name}, {v:.0f} Vpp")
            ys = [_or_nan(read(r)) * scale for r in rs]
            ax.plot(f, ys, "o", color=c, label=f"measured {v:.0f} Vpp")
            if ax is axes[0]:
                cell = [r["thrust_loadcell_n"] * scale for r in rs]
                ax.plot(f, cell, "x", color=c, label=f"load cell {v:.0f} Vpp")
    if chosen is not None and "thrust_n" in chosen:
        axes[2].plot(
            chosen["frequency_hz"],
            _or_nan(_tpw(chosen, watt, "vibrometer")) * 1e3,
            "*",
            ms=16,
            color="k",
            label="chosen",
        )
    labels = ("mean thrust [mN]", f"mean power, {watt} watt [mW]", f"thrust per {watt} watt [mN/W]")
    for ax, ylabel in zip(axes, labels, strict=True):
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[1].set_yscale("log")
    for ax in axes:
        ax.legend(fontsize=7)
    fig.suptitle(title or f"{model.fin.name}: protocol trials")
    save_figure(fig, path)
    return path
