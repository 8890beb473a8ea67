"""Speed of the physics core against baselines measured in the same run (ratios, not seconds).

    python benchmarks/bench_physics.py [--points 1000000] [--fsolve-points 300] [--json OUT]

1. Harmonic balance (closed-form quartic, vectorised) against ``scipy.optimize.fsolve`` on
   Eqs. (15)-(18) point by point (the paper's approach), with the largest disagreement.
2. Time-domain engine (compiled fixed-step RK4) on one 30 s protocol trial at a 2 kHz output
   rate against real time and against ``scipy.integrate.solve_ivp`` (RK45) tuned to reach the
   same accuracy, both judged against a DOP853 reference at rtol 1e-12.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.steady import harmonic_balance, harmonic_balance_fsolve
from piezofin_ros.physics.timedomain import simulate, simulate_batch
from piezofin_ros.physics.waveforms import protocol


def best_of(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench_harmonic_balance(n_points: int, n_fsolve: int, rng: np.random.Generator) -> dict[str, float]:
    fin = load_fin("M8528-P1")
    side = math.isqrt(n_points)
    f = np.linspace(0.5, 30.0, side)[:, None]
    v = np.linspace(10.0, 800.0, side)[None, :]
    t_hb = best_of(lambda: harmonic_balance(fin, f, v), 3)
    fs = rng.uniform(0.5, 30.0, n_fsolve)
    vs = rng.uniform(10.0, 800.0, n_fsolve)
    t_fs = best_of(lambda: harmonic_balance_fsolve(fin, fs, vs), 1)
    ours = harmonic_balance(fin, fs, vs)
    ref = harmonic_balance_fsolve(fin, fs, vs)
    amp = ours.modal_amplitude
    diff = max(np.max(np.abs(ours.H0 - ref.H0) / amp), np.max(np.abs(ours.H1 - ref.H1) / amp))
    hb_rate = side * side / t_hb
    fs_rate = n_fsolve / t_fs
    return {
        "hb_points": side * side,
        "hb_points_per_s": hb_rate,
        "fsolve_points_per_s": fs_rate,
        "hb_over_fsolve": hb_rate / fs_rate,
        "max_rel_difference": float(diff),
    }


def bench_time_domain() -> dict[str, float]:
    fin = load_fin("M8528-P1")
    f, vpp, rate, duration = 5.5, 800.0, 2000.0, 30.0
    wave = protocol(f, vpp)
    simulate(fin, wave, 1.0)  # compile (numba) outside the timing
    t_ours = best_of(lambda: simulate(fin, wave, duration, rate), 5)
    ours = simulate(fin, wave, duration, rate)
    t_eval = ours.t

    inv_m = 1.0 / (1.0 + fin.mu)
    c_lin, gam, wn2, th = 2 * fin.zeta * fin.omega_n, fin.gamma, fin.omega_n**2, fin.theta
    amp, w, t_on, t_off = 0.5 * vpp, 2 * math.pi * f, wave.t_start, wave.t_end

    def rhs(t: float, y: np.ndarray) -> list[float]:  # plain floats: fair to solve_ivp
        v = amp * math.sin(w * (t - t_on)) if t_on <= t < t_off else 0.0
        return [y[1], (th * v - (c_lin + gam * abs(y[1])) * y[1] - wn2 * y[0]) * inv_m]

    # The burst switches on and off: cap the step so an adaptive solver cannot jump over it.
    max_step = 0.25 / f
    ref = solve_ivp(
        rhs,
        (0.0, duration),
        [0.0, 0.0],
        method="DOP853",
        t_eval=t_eval,
        rtol=1e-12,
        atol=1e-16,
        max_step=max_step,
    )
    scale = np.max(np.abs(ref.y[1]))
    err_ours = float(np.max(np.abs(ours.eta_dot - ref.y[1])) / scale)

    def run_ivp(rtol: float):  # type: ignore[no-untyped-def]
        return solve_ivp(
            rhs,
            (0.0, duration),
            [0.0, 0.0],
            method="RK45",
            t_eval=t_eval,
            rtol=rtol,
            atol=rtol * 1e-4 * scale,
            max_step=max_step,
        )

    # The loosest rtol whose error is at most the engine's (decades, coarse to fine).
    for rtol in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11):
        err_ivp = float(np.max(np.abs(run_ivp(rtol).y[1] - ref.y[1])) / scale)
        if err_ivp <= err_ours:
            break
    else:
        raise RuntimeError("solve_ivp did not reach the engine's accuracy")
    t_ivp = best_of(lambda: run_ivp(rtol), 1)
    waves = [protocol(fr, v) for fr in np.linspace(1, 11, 11) for v in (400.0, 600.0, 800.0)]
    t_batch = best_of(lambda: simulate_batch(fin, waves, duration, rate), 2)
    return {
        "trial_s": duration,
        "engine_wall_s": t_ours,
        "engine_x_real_time": duration / t_ours,
        "engine_max_rel_error": err_ours,
        "solve_ivp_rtol": rtol,
        "solve_ivp_max_rel_error": err_ivp,
        "solve_ivp_wall_s": t_ivp,
        "engine_over_solve_ivp": t_ivp / t_ours,
        "batch_33_trials_wall_s": t_batch,
        "batch_x_real_time": 33 * duration / t_batch,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--fsolve-points", type=int, default=300)
    ap.add_argument("--json", help="also write the figures to this file")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print("harmonic balance ...", flush=True)
    hb = bench_harmonic_balance(args.points, args.fsolve_points, rng)
    print(
        f"  {hb['hb_points']:,} points: {hb['hb_points_per_s'] / 1e6:.2f} M points/s; "
        f"fsolve {hb['fsolve_points_per_s']:.0f} points/s; ratio {hb['hb_over_fsolve']:,.0f}x; "
        f"max relative difference {hb['max_rel_difference']:.1e}"
    )
    print("time domain ...", flush=True)
    td = bench_time_domain()
    print(
        f"  one {td['trial_s']:.0f} s trial at 2 kHz: {td['engine_wall_s'] * 1e3:.1f} ms = "
        f"{td['engine_x_real_time']:,.0f}x real time (max rel. error {td['engine_max_rel_error']:.1e})"
    )
    print(
        f"  solve_ivp RK45 at rtol {td['solve_ivp_rtol']:g} (error {td['solve_ivp_max_rel_error']:.1e}): "
        f"{td['solve_ivp_wall_s']:.2f} s -> engine {td['engine_over_solve_ivp']:,.0f}x faster"
    )
    print(
        f"  batch of 33 protocol trials: {td['batch_33_trials_wall_s']:.3f} s = "
        f"{td['batch_x_real_time']:,.0f}x real time"
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"harmonic_balance": hb, "time_domain": td}, fh, indent=1)


if __name__ == "__main__":
    main()
