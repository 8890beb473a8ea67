"""The diagnosis as a person reads it: a text report and three plots.

* ``measured_vs_model.png``: each channel over frequency, one colour per voltage; measured points with
  their error bars (held-out trials hollow), the nominal model dashed, the augmented model solid;
* ``stage_gaps.png``: each stage's gap mapped over frequency x voltage, in units of its noise;
* ``before_after.png``: held-out gap per channel before and after the chosen effect(s).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..physics.effects import effect_class
from .attribute import Diagnosis
from .data import CHANNELS


def text(d: Diagnosis) -> str:
    t = d.trials
    lines = [
        f"# Sim-to-real diagnosis: {d.fin.name}",
        "",
        f"**Verdict: {d.headline}.**",
        "",
        f"Data: {t.source} ({len(t)} trials, {', '.join(f'{v:.0f}' for v in t.voltages)} Vpp, "
        f"{t.frequency_hz.min():.2f}-{t.frequency_hz.max():.2f} Hz).",
        "",
        "## Where: each stage fed with measured inputs",
        "",
        "| stage | quantity | trials | chi2/n | verdict | largest gap at |",
        "|---|---|---:|---:|---|---|",
    ]
    for s in d.stages:
        m = s.summary(t)
        worst = m.get("worst")
        at = (
            f"{worst['frequency_hz']:.2f} Hz, {worst['voltage_pp']:.0f} Vpp ({worst['gap']:+.3g} {m['unit']})"
            if worst
            else "-"
        )
        chi = f"{m['chi2'] / m['trials']:.1f}" if m["trials"] else "-"
        lines.append(f"| {s.stage} | {s.quantity} | {m['trials']} | {chi} | {m['verdict']} | {at} |")
    if d.resonances:
        lines += ["", "Resonance (largest tip velocity per volt):", ""]
        for r in d.resonances:
            edge = "" if r.interior else " (at the edge of the sweep: a bound, not a peak)"
            lines.append(
                f"- {r.voltage_pp:.0f} Vpp: measured {r.measured_hz:.2f} Hz, model {r.model_hz:.2f} Hz{edge}"
            )
    lines += [
        "",
        "## Which: candidate effects, fitted and judged on held-out trials",
        "",
        f"Split: {d.holdout_text}.",
        "",
    ]
    if d.verdict == "no gap":
        lines.append("**No gap**: every stage agrees with the model within the measurement noise.")
        lines += [f"\nNote: {n}." for n in d.notes]
    elif d.verdict == "unexplained":
        family = f" Most probably an effect of the **{d.family}** family in another form." if d.family else ""
        lines.append(
            "**Unexplained**: no candidate in the library closes the gap." + family + " " + " ".join(d.notes)
        )
    else:
        assert d.chosen is not None
        params = "; ".join(
            f"{name}: {d.final_model.parameters_text(name, 4)}" for name in d.final_model.names
        )
        titles = "; ".join(effect_class(n).title for n in d.chosen.effects)
        lines.append(f"**Explained by {d.chosen.label}** ({titles}). Refitted on all trials: {params}.")
        lines += [f"\nNote: {n}." for n in d.notes]
        if d.ambiguous:
            lines += ["", "Cannot be told apart on this data (criterion within 6 of the chosen):"]
            for c in d.ambiguous:
                lines.append(
                    f"- {c.label} (held-out chi2 {c.chi2_test:.1f} against {d.chosen.chi2_test:.1f})"
                )
            for e in d.experiments:
                lines.append(
                    f"- To separate {e.a} from {e.b}: measure {CHANNELS[e.channel][2]} at {e.frequency_hz:.2f} Hz, "  # noqa: E501
                    f"{e.voltage_pp:.0f} Vpp, where they differ by {e.difference_sigma:.1f} sigma."
                )
    lines += ["", "| rank | candidate | parameters | held-out chi2 | criterion |", "|---:|---|---|---:|---:|"]
    lines.append(
        f"| - | nominal model | - | {d.nominal.chi2_test:.1f} / {d.nominal.n_test} | {d.nominal.criterion:.1f} |"  # noqa: E501
    )
    for j, c in enumerate(d.candidates[:10]):
        ps = "; ".join(c.model.parameters_text(name) for name in c.model.names)
        lines.append(f"| {j + 1} | {c.label} | {ps} | {c.chi2_test:.1f} / {c.n_test} | {c.criterion:.1f} |")
    lines += ["", "## How far: held-out gap before and after", ""]
    lines += [f"After adding {who_short(d)}; shrink of the normalised gap: {d.shrink:.0%}.", ""]
    lines += ["| channel | RMS gap before | after | relative before | after |", "|---|---:|---:|---:|---:|"]
    for g in d.gaps:
        rel = (
            "-"
            if math.isnan(g.rel_before_percent)
            else f"{g.rel_before_percent:.1f} % | {g.rel_after_percent:.1f} %"
        )
        if rel == "-":
            rel = "- | -"
        lines.append(
            f"| {CHANNELS[g.channel][2]} | {g.rms_before:.4g} {g.unit} | {g.rms_after:.4g} {g.unit} | {rel} |"
        )
    return "\n".join(lines) + "\n"


def plots(d: Diagnosis, out_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = d.trials
    paths = []
    chans = [c for c in CHANNELS if t.has(c) and c != "voltage_pp_drive"]
    ncol = 3
    nrow = math.ceil(len(chans) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.2 * nrow), squeeze=False)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    final = d.final_model
    nominal = d.nominal.model
    for ax, name in zip(axes.ravel(), chans, strict=False):
        unit, scale, label = CHANNELS[name]
        for j, v in enumerate(t.voltages):
            sel = np.round(t.voltage_pp) == v
            col = colors[j % len(colors)]
            grid = np.linspace(t.frequency_hz[sel].min(), t.frequency_hz[sel].max(), 200)
            vv = np.full_like(grid, v)
            ax.plot(grid, np.asarray(getattr(nominal.predict(grid, vv), name)) * scale, "--", color=col, lw=1)
            if d.chosen is not None:
                ax.plot(
                    grid, np.asarray(getattr(final.predict(grid, vv), name)) * scale, "-", color=col, lw=1.5
                )
            for held, face in ((False, col), (True, "white")):
                s2 = sel & (d.holdout == held)
                if np.any(s2):
                    ax.errorbar(
                        t.frequency_hz[s2],
                        t.channel(name)[s2] * scale,
                        yerr=t.sigma[name][s2] * scale,
                        fmt="o",
                        ms=4,
                        color=col,
                        mfc=face,
                        label=f"{v:.0f} Vpp" + (" (held out)" if held else ""),
                    )
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel(f"{label} [{unit}]")
    for ax in axes.ravel()[len(chans) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    model_text = f"solid: with {d.chosen.label}" if d.chosen else "no effect chosen"
    fig.suptitle(f"{d.fin.name}: measured (points) vs nominal model (dashed); {model_text}", fontsize=10)
    fig.tight_layout()
    paths.append(out_dir / "measured_vs_model.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    stages = [s for s in d.stages if s.n]
    ncol = min(3, len(stages))
    nrow = math.ceil(len(stages) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.0 * nrow), squeeze=False)
    for ax, s in zip(axes.ravel(), stages, strict=False):
        z = np.clip(s.z, -20, 20)
        sc = ax.scatter(t.frequency_hz, t.voltage_pp, c=z, cmap="RdBu_r", vmin=-20, vmax=20, s=90, marker="s")
        verdict = "gap" if s.significant else "no gap"
        ax.set_title(f"{s.stage}: {s.quantity}\n({verdict}, chi2/n {s.chi2 / s.n:.1f})", fontsize=8)
        ax.set_xlabel("frequency [Hz]")
        ax.set_ylabel("Vpp")
    for ax in axes.ravel()[len(stages) :]:
        ax.axis("off")
    fig.colorbar(sc, ax=axes.ravel().tolist(), label="(measured - model) / sigma, clipped at 20")
    paths.append(out_dir / "stage_gaps.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 3.2))
    gs = [g for g in d.gaps if not math.isnan(g.rel_before_percent)]
    x = np.arange(len(gs))
    ax.bar(x - 0.2, [g.rel_before_percent for g in gs], 0.4, label="nominal model")
    ax.bar(x + 0.2, [g.rel_after_percent for g in gs], 0.4, label=f"with {who_short(d)}")
    ax.set_xticks(x, [CHANNELS[g.channel][2] for g in gs], rotation=20, fontsize=8)
    ax.set_ylabel("held-out RMS gap [% of RMS value]")
    ax.set_yscale("log")
    ax.legend(fontsize=8)
    ax.set_title(f"{d.holdout_text}; shrink {d.shrink:.0%}", fontsize=9)
    fig.tight_layout()
    paths.append(out_dir / "before_after.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def who_short(d: Diagnosis) -> str:
    """The effect(s) the held-out comparison uses: the chosen ones, else the least bad candidate."""
    return d.chosen.label if d.chosen else f"{d.candidates[0].label} (least bad, not an explanation)"


def write(d: Diagnosis, out_dir: str | Path, summary: dict[str, Any]) -> list[Path]:
    """Report, plots, JSON and the augmented model (YAML) into ``out_dir``."""
    import json

    import yaml

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.md").write_text(text(d))
    (out / "diagnosis.json").write_text(json.dumps(summary, indent=1, default=float))
    (out / "augmented_model.yaml").write_text(yaml.safe_dump(d.final_model.to_mapping(), sort_keys=False))
    return [out / "report.md", out / "diagnosis.json", out / "augmented_model.yaml", *plots(d, out)]
