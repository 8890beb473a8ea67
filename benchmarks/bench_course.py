"""A fish swims a square course at fixed drives with the same steering: how far off it, in what
time, at what supply energy per metre.

    python benchmarks/bench_course.py [--side 20] [--fin M8528-P1] [--plot docs/fish_course.png]

The fish is ``mfc-fish`` (25 cm, 450 g) carrying ``--fin`` through the ``fish-switching`` amplifier,
from rest at the course's first point, heading along its first leg.  It steers by its fin's offset:
line-of-sight guidance (:mod:`piezofin_ros.control.guidance`, its defaults: 1.5 m lookahead, the
tightest turns 2.5 m to port and 20 m to starboard) asks a yaw rate, the yaw loop
(:mod:`piezofin_ros.control.yawloop`, given the right fin) the offset, the planar body turns
(:func:`piezofin_ros.bench.course.swim_course`).  The square is swum to port (anticlockwise), the
way a P1 fin turns fast; its side is ``--side`` metres, about ten turning radii: a corner cut on a
2.5 m circle is 1 m off the course at its middle, so a smaller square cannot be held within a body
length.  Drives: the paper's point (5.5 Hz, 800 Vpp), the fin's thrust resonance (by harmonic
balance) at 800 and 400 Vpp, and the paper's frequency at 500 Vpp.  Off the course is the least
distance to any leg, every 0.1 s of fish time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from piezofin_ros.bench.course import CourseRun, square, swim_course
from piezofin_ros.control.guidance import LineOfSight
from piezofin_ros.errors import PiezofinError
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.steady import harmonic_balance
from piezofin_ros.physics.swim import load_body


def resonance_hz(fin_name: str, voltage_pp: float = 800.0) -> float:
    """The frequency of the most thrust at ``voltage_pp`` (harmonic balance, 0.25 Hz steps), Hz."""
    fin = load_fin(fin_name)
    grid = np.arange(2.0, 20.0, 0.25)
    return float(grid[int(np.argmax([float(harmonic_balance(fin, f, voltage_pp).thrust_n) for f in grid]))])


def runs(fin_name: str, side_m: float) -> list[tuple[str, CourseRun]]:
    fin, body, amp = load_fin(fin_name), load_body("mfc-fish"), load_amplifier("fish-switching")
    fr = resonance_hz(fin_name)
    drives = [
        ("paper's point, 5.5 Hz, 800 Vpp", 5.5, 800.0),
        (f"resonance, {fr:g} Hz, 800 Vpp", fr, 800.0),
        (f"resonance, {fr:g} Hz, 400 Vpp", fr, 400.0),
        ("5.5 Hz, 500 Vpp", 5.5, 500.0),
    ]
    return [(name, swim_course(fin, body, amp, LineOfSight(square(side_m)), f, v)) for name, f, v in drives]


def table(rows: list[tuple[str, CourseRun]]) -> str:
    least = min(r.joules_per_m for _, r in rows)
    lines = [
        "| drive | done | time | speed | off the course, RMS / most | supply energy per metre |",
        "|---|---|---|---|---|---|",
    ]
    for name, r in rows:
        lines.append(
            f"| {name} | {'yes' if r.done else 'no'} | {r.time_s:.0f} s | {r.speed_m_s * 100:.1f} cm/s | "
            f"{r.off_course_rms_m:.2f} m / {r.off_course_max_m:.2f} m | {r.joules_per_m:.2f} J/m "
            f"({r.joules_per_m / least - 1:+.0%}) |"
        )
    return "\n".join(lines)


def plot(rows: list[tuple[str, CourseRun]], side_m: float, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 6.0))
    course = np.array(square(side_m))
    ax.plot(course[:, 0], course[:, 1], "k--", lw=1.5, label="the course")
    for name, r in rows:
        ax.plot(r.path[:, 1], r.path[:, 2], lw=1.2, label=f"{name}: {r.off_course_rms_m:.2f} m RMS off")
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title(f"mfc-fish on a {side_m:g} m square, steered by its fin's offset")
    ax.legend(fontsize=7, loc="center")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--side", type=float, default=20.0, help="the square's side, m")
    ap.add_argument("--fin", default="M8528-P1", choices=["M8528-P1", "M8514-P1", "M8507-P1"])
    ap.add_argument("--plot", type=Path, help="draw the paths swum over the course (PNG)")
    a = ap.parse_args(argv)
    if not (a.side > 0 and np.isfinite(a.side)):
        ap.error(f"--side {a.side!r}: a finite side > 0, m")
    t0 = time.perf_counter()
    try:
        rows = runs(a.fin, a.side)
    except PiezofinError as exc:
        ap.error(str(exc))
    print(f"mfc-fish on {a.fin}, a {a.side:g} m square swum to port, fish-switching amplifier:")
    print(table(rows))
    if a.plot:
        plot(rows, a.side, a.plot)
        print(f"the paths: {a.plot}")
    sim: Any = sum(r.time_s for _, r in rows)
    print(f"\n{sim:.0f} s of fish time in {time.perf_counter() - t0:.1f} s of wall time")
    return 0


if __name__ == "__main__":
    sys.exit(main())
