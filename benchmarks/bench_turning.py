"""How fast the paper's twin can turn a fish, and at what supply power: a bias against two fins.

    python benchmarks/bench_turning.py [--fin M8528-P1] [--frequency 5.5] [--body mfc-fish]

The fish is ``--body`` (``mfc-fish``: 25 cm, 450 g, 10 cm deep and 6 cm wide) as a slender ellipsoid
(:func:`~piezofin_ros.physics.planar.slender_planar`; two fins as far apart as it is wide), swimming
on the paper's twin of
``--fin`` at ``--frequency`` through the ``fish-switching`` amplifier.  Each row is a steady turn,
from the yaw balance's closed form (:meth:`~piezofin_ros.physics.planar.PlanarBody.steady_yaw_rate`):

* a **bias** (a DC offset on one fin's drive) at either end of the P1 MFC's rated window
  (-500 V to +1500 V) that the drive's amplitude leaves: the tip's static turn, the side force (the
  thrust turned with it and the tip's lift), the yaw rate, the radius and the supply power (a bias
  is a charge held on a capacitor: the fin draws no more power with it);
* **two fins** side by side, one eased or stopped: the moment of their difference.

Each turn is checked against the planar body's equations integrated in time (surge, sway and yaw,
``PlanarBody.derivatives``): the integrated yaw rate after 60 s is printed beside the closed form's.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from piezofin_ros.control.swimming import Fish
from piezofin_ros.errors import PiezofinError
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.model import load_model
from piezofin_ros.physics.planar import (
    PlanarBody,
    bias_side_force_n,
    bias_tilt_rad,
    bias_window_v,
    fin_yaw_damping,
    slender_planar,
)
from piezofin_ros.physics.swim import load_battery, load_body


def integrated_yaw_rate(
    body: PlanarBody, thrust_n: float, side_n: float, moment_nm: float, k: float
) -> float:
    """The yaw rate after 60 s from straight swimming at the thrust's steady speed, rad/s."""
    u0 = float(body.surge.steady_speed(thrust_n))
    sol = solve_ivp(
        lambda t, s: body.derivatives(tuple(s), (thrust_n, side_n), moment_nm, k),
        (0.0, 60.0),
        [0.0, 0.0, 0.0, u0, 0.0, 0.0],
        rtol=1e-8,
        atol=1e-12,
    )
    return float(sol.y[5, -1])


def turns(fin: str, frequency_hz: float, body: str) -> list[dict[str, Any]]:
    model = load_model(f"paper-twin-{fin}")
    surge = load_body(body)
    width_m = surge.width_m
    fish = Fish(model, surge, load_battery("li-ion-2s-500mah"), load_amplifier("fish-switching"))
    rows: list[dict[str, Any]] = []

    def at(v: float) -> tuple[float, float]:
        r = fish.at(np.array([frequency_hz]), np.array([v]), ranges=False)
        return float(r["thrust0_n"][0]), float(r["supply_w"][0])

    one = slender_planar(surge, model.fin)
    for vpp in (800.0, 400.0):
        thrust, supply = at(vpp)
        speed = float(surge.steady_speed(thrust, frequency_hz, model.fin.L))
        k = fin_yaw_damping(one, model.fin, speed)
        for bias in bias_window_v(vpp):
            side = bias_side_force_n(model.fin, thrust, bias, speed)
            moment = side * one.fin_lever_m
            r = one.steady_yaw_rate(moment, k)
            rows.append(
                {
                    "how": f"bias {bias:+.0f} V on {vpp:.0f} Vpp",
                    "tilt_deg": math.degrees(bias_tilt_rad(model.fin, bias)),
                    "side_mn": side * 1e3,
                    "speed_cm_s": speed * 100,
                    "yaw_deg_s": math.degrees(r),
                    "radius_m": speed / abs(r) if r else math.inf,
                    "supply_mw": supply * 1e3,
                    "integrated_deg_s": math.degrees(integrated_yaw_rate(one, thrust, side, moment, k)),
                }
            )
    two = slender_planar(surge, model.fin, fin_spacing_m=width_m)
    full, supply_full = at(800.0)
    for other in (800.0, 400.0, 0.0):
        eased, supply_eased = at(other) if other > 0 else (0.0, 0.0)
        total = full + eased
        speed = float(surge.steady_speed(total, frequency_hz, model.fin.L))
        k = fin_yaw_damping(two, model.fin, speed, fins=2)
        moment = (full - eased) * two.fin_spacing_m / 2.0
        r = two.steady_yaw_rate(moment, k)
        rows.append(
            {
                "how": f"two fins {width_m * 100:.0f} cm apart, 800 / {other:.0f} Vpp",
                "tilt_deg": 0.0,
                "side_mn": 0.0,
                "speed_cm_s": speed * 100,
                "yaw_deg_s": math.degrees(r),
                "radius_m": speed / abs(r) if r else math.inf,
                "supply_mw": (supply_full + supply_eased) * 1e3,
                "integrated_deg_s": math.degrees(integrated_yaw_rate(two, total, 0.0, moment, k)),
            }
        )
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    head = (
        f"{'turn':34s} {'tilt deg':>8s} {'side mN':>8s} {'cm/s':>5s} {'deg/s':>6s} {'radius m':>8s} "
        f"{'supply mW':>9s} {'integrated deg/s':>16s}"
    )
    lines = [head]
    for r in rows:
        radius = f"{r['radius_m']:8.2f}" if math.isfinite(r["radius_m"]) else f"{'straight':>8s}"
        lines.append(
            f"{r['how']:34s} {r['tilt_deg']:8.2f} {r['side_mn']:8.3f} {r['speed_cm_s']:5.2f} "
            f"{r['yaw_deg_s']:6.2f} {radius} {r['supply_mw']:9.1f} {r['integrated_deg_s']:16.2f}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fin", default="M8528-P1", choices=["M8528-P1", "M8514-P1", "M8507-P1"])
    ap.add_argument("--frequency", type=float, default=5.5, help="drive frequency, Hz")
    ap.add_argument("--body", default="mfc-fish", help="a body preset (config/bodies) or a YAML file")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    try:
        rows = turns(a.fin, a.frequency, a.body)
    except PiezofinError as exc:
        ap.error(str(exc))
    print(f"paper's twin of {a.fin} at {a.frequency:g} Hz on {a.body}:")
    print(table(rows))
    print(f"\n{time.perf_counter() - t0:.2f} s of wall time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
