"""Identification accuracy: the suite's fits against the paper's own methods, on many fins.

    python benchmarks/bench_identify.py                 # the 3 presets and 12 random fins (about 2 minutes)
    python benchmarks/bench_identify.py --random 40

For each fin: an in-air stepped sine at 50 Vpp and an underwater one at 100 Vpp on the simulated
rig (time-domain Eqs. 9-10, the default instrument noise), then :func:`identify`.  Per parameter:
the largest relative error of the fit and of the paper's method (peak of |U/V|, half-power points,
FRF amplitude at resonance, the current far from resonance as a capacitance meter reads it,
the resonance shift, the amplitude at resonance), the largest error in stated sigmas, and the
share within one and two sigmas.  Then the held-out check: protocol-like points at 600 Vpp, not
used by the identification, predicted by the identified fin and by the true one.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from piezofin_ros.identification.experiment import SweepPlan, random_fin, simulate_sweep
from piezofin_ros.identification.identify import identify
from piezofin_ros.physics.fin import Fin, load_fin, preset_names
from piezofin_ros.physics.steady import harmonic_balance

PARAMS = ("f_sc", "zeta", "theta", "C_eq", "c_m", "c_d")
TOLERANCE = {"f_sc": 0.005, "zeta": 0.05, "theta": 0.02, "C_eq": 0.02, "c_m": 0.03, "c_d": 0.10}
PAPER_METHOD = {
    "f_sc": "peak of the response",
    "zeta": "half-power points",
    "theta": "FRF amplitude (tip velocity alone)",
    "C_eq": "as a capacitance meter reads, Im(I/V)/w at the farthest point",
    "c_m": "resonance shift",
    "c_d": "amplitude at resonance",
}


def held_out_error(model: Fin, truth: Fin, seed: int) -> float:
    """Largest relative error of tip velocity and current at 5 held-out points (600 Vpp, 3-11 Hz)."""
    measured = simulate_sweep(truth, SweepPlan((3.0, 6.0, 8.0, 9.5, 11.0), 600.0, 25.0), "water", seed=seed)
    f = np.array([p.frequency_hz for p in measured])
    vpp = np.array([p.voltage_pp for p in measured])
    s = harmonic_balance(model, f, vpp, harmonics=3)
    u = model.phi_tip * 2 * np.pi * f * np.asarray(s.modal_amplitude)
    i = np.hypot(np.asarray(s.I0), np.asarray(s.I1))
    return float(
        max(
            np.max(np.abs(u / np.array([abs(p.tip) for p in measured]) - 1)),
            np.max(np.abs(i / np.array([abs(p.current) for p in measured]) - 1)),
        )
    )


def one(fin: Fin, seed: int) -> dict[str, object]:
    t0 = time.perf_counter()
    air = simulate_sweep(fin, SweepPlan.around(fin, "air", 50.0), "air", seed=seed)
    water = simulate_sweep(fin, SweepPlan.around(fin, "water", 100.0, n=21), "water", seed=seed + 1)
    t_sim = time.perf_counter() - t0
    t0 = time.perf_counter()
    ident = identify(air, water, fin.replace(f_sc=10.0, zeta=0.1, theta=1e-3, C_eq=1e-9, c_d=1.0), fin.name)
    t_fit = time.perf_counter() - t0
    values = ident.values()
    out: dict[str, object] = {"fin": fin.name, "t_sim": t_sim, "t_fit": t_fit, "notes": ident.warnings}
    for name in PARAMS:
        truth = fin.c_m if name == "c_m" else float(getattr(fin, name))
        v = values[name]
        out[name] = {
            "err": (v["value"] - truth) / truth,
            "z": (v["value"] - truth) / v["sigma"],
            "paper_err": (v["others"][PAPER_METHOD[name]] - truth) / truth,
        }
    out["held_out_identified"] = held_out_error(ident.fin, fin, seed + 2)
    out["held_out_true"] = held_out_error(fin, fin, seed + 2)
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--random", type=int, default=12, help="random fins besides the presets (default 12)")
    p.add_argument("--json", help="write every fin's result here")
    args = p.parse_args(argv)
    fins = [load_fin(n) for n in preset_names()]
    rng = np.random.default_rng(2026)
    fins += [random_fin(rng, f"random-{k}") for k in range(args.random)]
    rows = []
    for k, fin in enumerate(fins):
        rows.append(one(fin, 100 + 10 * k))
        r = rows[-1]
        print(
            f"{fin.name:>10}: "
            + " ".join(f"{n} {r[n]['err'] * 100:+.3f}%" for n in PARAMS)  # type: ignore[index]
            + f"  held out {r['held_out_identified'] * 100:.2f}% (true fin {r['held_out_true'] * 100:.2f}%)",
            file=sys.stderr,
            flush=True,
        )
    n = len(rows)
    print(f"\n{n} fins ({len(preset_names())} presets, {args.random} random), default noise")
    head = "| parameter | tolerance | largest error, fit | largest error, paper's method | largest |z| |"
    print(head + " within 1 / 2 sigma |")
    print("|---|---|---|---|---|---|")
    for name in PARAMS:
        errs = [abs(r[name]["err"]) for r in rows]  # type: ignore[index]
        perr = [abs(r[name]["paper_err"]) for r in rows]  # type: ignore[index]
        zs = [abs(r[name]["z"]) for r in rows]  # type: ignore[index]
        print(
            f"| `{name}` | {TOLERANCE[name] * 100:g} % | {max(errs) * 100:.3f} % | "
            f"{np.nanmax(perr) * 100:.2f} % ({PAPER_METHOD[name]}) | {max(zs):.1f} | "
            f"{sum(z <= 1 for z in zs)}/{n} / {sum(z <= 2 for z in zs)}/{n} |"
        )
    ident_err = [float(r["held_out_identified"]) for r in rows]  # type: ignore[arg-type]
    true_err = [float(r["held_out_true"]) for r in rows]  # type: ignore[arg-type]
    worst = max(a - b for a, b in zip(ident_err, true_err, strict=True))
    print(
        f"\nheld-out points (600 Vpp, 3-11 Hz): largest error {max(ident_err) * 100:.2f} % with the "
        f"identified fin, {max(true_err) * 100:.2f} % with the true one; worst difference "
        f"{worst * 100:+.3f} points"
    )
    t_sim = [r["t_sim"] for r in rows]
    t_fit = [r["t_fit"] for r in rows]
    print(
        f"time per fin: simulating the two sweeps median {np.median(t_sim):.1f} s, identifying median "
        f"{np.median(t_fit):.2f} s (max {max(t_fit):.2f} s)"  # type: ignore[type-var]
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1, default=float)
    bad = [
        (r["fin"], name)
        for r in rows
        for name in PARAMS
        if not (abs(r[name]["err"]) <= TOLERANCE[name] and math.isfinite(r[name]["z"]))  # type: ignore[index]
    ]
    if bad:
        print(f"outside the tolerance: {bad}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
