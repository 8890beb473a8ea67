"""Summary tables and plots of trial results (plain matplotlib; no ROS)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..files import save_figure
from ..identification.fit import water_admittance, water_mobility
from ..identification.identify import Identification


def plot_frf(path: str | os.PathLike[str], ident: Identification) -> Path:
    """Fig. 5: measured and identified-model FRFs, (a) in air and (b) under water: the tip velocity
    per volt (magnitude, phase) and, beside it, the current per volt (magnitude, and its real part,
    the conductance, where a loss the model lacks shows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    stages = [("in air", ident.air_points, ident.fin.replace(rho_w=0.0))]
    if ident.water_points:
        stages.append(("under water", ident.water_points, ident.fin))
    fig, axes = plt.subplots(
        4, len(stages), figsize=(5.5 * len(stages), 10.5), sharex="col", squeeze=False, layout="constrained"
    )
    for j, (label, points, fin) in enumerate(stages):
        f_all = np.array([p.frequency_hz for p in points])
        vpp = float(np.median([p.voltage_pp for p in points]))
        dense = np.linspace(f_all.min(), f_all.max(), 600)
        v_dense = np.full_like(dense, vpp)
        ax, axp, axi, axg = axes[:, j]
        ax.set_title(f"({'ab'[j]}) {label}: {ident.fin.name}")
        pts = [p for p in points if p.has_tip]
        if pts:
            f = np.array([p.frequency_hz for p in pts])
            mob = np.array([p.mobility for p in pts])
            err = np.array([p.sigma_tip / abs(p.voltage) for p in pts])
            model = water_mobility(fin, dense, v_dense)
            ax.errorbar(f, np.abs(mob), yerr=err, fmt="o", ms=3, label=f"measured ({vpp:.0f} Vpp)")
            ax.plot(dense, np.abs(model), "-", lw=1.2, label="model, identified parameters")
            axp.plot(f, np.degrees(np.angle(mob)), "o", ms=3)
            axp.plot(dense, np.degrees(np.angle(model)), "-", lw=1.2)
            ax.set_yscale("log")
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no vibrometer in this sweep", ha="center", transform=ax.transAxes)
        ax.set_ylabel("|tip velocity / V| [m/(s V)]")
        axp.set_ylabel("tip phase [deg]")
        adm = np.array([p.admittance for p in points])
        err_i = np.array([p.sigma_current / abs(p.voltage) for p in points])
        model_i = water_admittance(fin, dense, v_dense)
        axi.errorbar(f_all, np.abs(adm) * 1e6, yerr=err_i * 1e6, fmt="o", ms=3, label="measured")
        axi.plot(dense, np.abs(model_i) * 1e6, "-", lw=1.2, label="model")
        axi.set_ylabel("|current / V| [uS]")
        axi.legend(fontsize=8)
        axg.errorbar(f_all, adm.real * 1e6, yerr=err_i * 1e6, fmt="o", ms=3)
        axg.plot(dense, model_i.real * 1e6, "-", lw=1.2)
        axg.set_ylabel("Re(current / V) [uS]\n(a loss shows here)")
        axg.set_xlabel("frequency [Hz]")
        for a_ in (ax, axp, axi, axg):
            a_.grid(alpha=0.3, which="both")
    save_figure(fig, path)
    return path
