"""A fish swims a square course with the same steering at fixed drives and at the drives the
optimiser chooses: how far off it, in what time, at what energy per metre and range per charge.

    python benchmarks/bench_course.py [--fish M8528-P1 ... "stranger 1"] [--side 20] [--to starboard]
                                      [--drives ...] [--plot docs/fish_course.png] [--workers 2]

Each fish carries its fin on ``mfc-fish`` (25 cm, 450 g) through ``fish-switching``, with the
battery ``li-ion-2s-500mah`` (0.25 W of fixed draw besides the fin), from rest at the course's first
point, heading along its first leg.  ``M8528-P1``, ``M8514-P1``, ``M8507-P1``: the paper's twin of
that fin, told to the stack as it is.  ``stranger 1`` and ``stranger 2``: ``bench_fish.py``'s fish
the stack is not told (a fin with effects outside the correction, another body, amplifier and
speed sensor), the M8528-P1 twin, ``mfc-fish`` and ``fish-switching`` told instead.

It steers by its fin's offset: line-of-sight guidance (:mod:`piezofin_ros.control.guidance`, its
defaults: 2.5 m lookahead, the tightest turns 2.5 m to port and 6.4 m to starboard, each begun that
far before its corner) asks a yaw rate,
the yaw loop (:mod:`piezofin_ros.control.yawloop`, told the stack's fin and body) the offset, the
planar body turns (:func:`piezofin_ros.bench.course.swim_course`).  The square is swum to port
(anticlockwise), the way a P1 fin turns fast; its side is ``--side`` metres, about ten turning
radii: a corner cut on a 2.5 m circle is 1 m off the course at its middle, so a smaller square
cannot be held within a body length.  Off the course is the least distance to any leg, every 0.1 s
of fish time.  ``--to starboard`` swims it the other way, the P1's weak side: 6.4 m is the circle
the optimising stack turns on once it gives up voltage for its offset's room
(:class:`~piezofin_ros.control.yawloop.OffsetRoom`; the fixed drives, at their voltage, turn on far
wider ones: 19 m at 800 Vpp).  A course is given up after its length at :data:`SLOWEST_M_S`.

The drives (:data:`DRIVES`): the paper's point (5.5 Hz, 800 Vpp); the told model's resonance at
full voltage (what a builder without an optimiser drives); the best fixed drive in truth (the point
of the longest range of the fish in truth swimming straight: an oracle no builder has, the least
energy per metre a fixed drive gives); and ours, the optimising controller on the drive's voltage
and current alone (``config/fish.yaml``'s), ranking by the supply watt the fish measures, either by
its range (speed per watt with the 0.25 W fixed draw: the cost of transport) or by the paper's
thrust per watt.  Energy per metre is the battery's (the amplifier's draw and the fixed draw); the
range is one charge at the course's mean draw and speed.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from piezofin_ros import workers
from piezofin_ros.bench.course import CourseRun, square, swim_course
from piezofin_ros.bench.fishrun import Drive, FixedDrive, OptimisingDrive
from piezofin_ros.control.guidance import LineOfSight
from piezofin_ros.control.objective import THRUST_PER_WATT, Objective, range_per_charge
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.control.swimming import Fish
from piezofin_ros.errors import PiezofinError
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.model import load_model
from piezofin_ros.physics.swim import load_battery, load_body

TWINS = ("M8528-P1", "M8514-P1", "M8507-P1")
STRANGERS = ("stranger 1", "stranger 2")
PAPER, RESONANCE, BEST = (
    "paper's point, 5.5 Hz, 800 Vpp",
    "resonance, full voltage",
    "best fixed drive in truth",
)
RANGE, TPW = "ours: range", "ours: thrust per supply watt"
#: the drives, fixed then ours (module docstring)
DRIVES = (PAPER, RESONANCE, BEST, RANGE, TPW)
FIXED = (PAPER, RESONANCE, BEST)
TOP_VPP = 800.0
DENSE_HZ = np.geomspace(1.0, 30.0, 240)


def fish_of(name: str) -> tuple[Fish, Fish]:
    """The fish the stack is told and the fish in truth."""
    if name in STRANGERS:
        try:
            from bench_fish import stranger  # (this folder's: run as a script)
        except ImportError:
            from benchmarks.bench_fish import stranger  # (imported from the package, by the tests)

        told, truth, _, _ = stranger(name)
        return told, truth
    f = Fish(
        load_model(f"paper-twin-{name}"),
        load_body("mfc-fish"),
        load_battery("li-ion-2s-500mah"),
        load_amplifier("fish-switching"),
    )
    return f, f


def drive_of(name: str, told: Fish, truth: Fish) -> tuple[Drive, str]:
    """The drive ``name`` (:data:`DRIVES`) and its point in words."""
    if name == PAPER:
        return FixedDrive(5.5, TOP_VPP), "5.5 Hz, 800 Vpp"
    if name == RESONANCE:
        f = told.resonance_hz(TOP_VPP, DENSE_HZ)
        return FixedDrive(f, TOP_VPP), f"{f:.2f} Hz, 800 Vpp"
    if name == BEST:
        s = truth.best(DENSE_HZ, truth.voltage_grid(), "supply")
        return FixedDrive(s.frequency_hz, s.voltage_pp), f"{s.frequency_hz:.2f} Hz, {s.voltage_pp:.0f} Vpp"
    objective: Objective = range_per_charge(told.battery.hotel_w) if name == RANGE else THRUST_PER_WATT
    opt = Optimiser(
        told.model.fin,
        OperatingBox(1.0, 30.0, 50.0, TOP_VPP),
        TOP_VPP,
        None,
        source="self",
        watt="supply_measured",
        amplifier=told.amplifier,
        model=told.model,
        objective=objective,
    )
    return OptimisingDrive(opt), "its own"


#: A course is given up (not done) after its length at this mean speed: the slowest twin swims 3.5
#: cm/s, and a 20 m square is given an hour as before.
SLOWEST_M_S = 80.0 / 3600.0


def run(task: tuple[str, str, float, str]) -> dict[str, Any]:
    """One fish, one drive, one course (a worker's task)."""
    name, drive_name, side, to = task
    told, truth = fish_of(name)
    drive, point = drive_of(drive_name, told, truth)
    course = LineOfSight(square(side, to))  # (guidance's defaults: each turn at its own radius)
    r = swim_course(
        truth.model,
        truth.body,
        truth.amplifier,
        course,
        drive,
        told=told.model,
        told_body=told.body,
        told_amplifier=told.amplifier,
        battery=truth.battery,
        most_s=course.length_m / SLOWEST_M_S,
    )
    if isinstance(drive, OptimisingDrive):
        held = drive.optimiser.status().get("held") or {}
        if held:
            point = f"{held['frequency_hz']:.2f} Hz, {held['voltage_pp']:.0f} Vpp at the end"
    return {"fish": name, "drive": drive_name, "point": point, "run": r}


def table(results: list[dict[str, Any]]) -> str:
    lines = [
        "| fish | drive | point | done | time | speed | off the course, RMS / most | amplifier | "
        "battery per metre (vs the best fixed) | range per charge |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in dict.fromkeys(r["fish"] for r in results):
        rows = [r for r in results if r["fish"] == name]
        fixed = [r["run"].joules_per_m_all for r in rows if r["drive"] in FIXED and r["run"].done]
        least = min(fixed) if fixed else math.nan
        for r in rows:
            c: CourseRun = r["run"]
            vs = f"{c.joules_per_m_all / least - 1:+.1%}" if fixed else "no fixed drive run"
            lines.append(
                f"| {name} | {r['drive']} | {r['point']} | {'yes' if c.done else 'no'} | {c.time_s:.0f} s | "
                f"{c.speed_m_s * 100:.1f} cm/s | {c.off_course_rms_m:.2f} m / {c.off_course_max_m:.2f} m | "
                f"{c.joules_per_m:.2f} J/m | {c.joules_per_m_all:.2f} J/m ({vs}) | "
                f"{c.range_m / 1000:.2f} km |"
            )
    return "\n".join(lines)


def plot(results: list[dict[str, Any]], side_m: float, path: Path, to: str = "port") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["fish"] for r in results))
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.6 * (len(names) + 1), 4.2), squeeze=False)
    course = np.array(square(side_m, to))
    colours = dict(zip(DRIVES, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    for ax, name in zip(axes[0], names, strict=False):
        ax.plot(course[:, 0], course[:, 1], "k--", lw=1.2, label="the course")
        for r in (r for r in results if r["fish"] == name):
            c = r["run"]
            ax.plot(c.path[:, 1], c.path[:, 2], lw=1.0, color=colours[r["drive"]], label=r["drive"])
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("x, m")
    axes[0][0].set_ylabel("y, m")
    axes[0][0].legend(fontsize=6, loc="center")
    bars = axes[0][-1]
    width = 0.8 / len(DRIVES)
    for k, d in enumerate(DRIVES):
        ys = [next((r["run"].joules_per_m_all for r in results if r["fish"] == n and r["drive"] == d), np.nan)
              for n in names]  # fmt: skip
        bars.bar(np.arange(len(names)) + k * width, ys, width, color=colours[d], label=d)
    bars.set_xticks(np.arange(len(names)) + 0.4 - width / 2, names, rotation=30, fontsize=7)
    bars.set_ylabel("battery energy per metre, J/m (fixed draw counted)")
    bars.set_title("what a metre costs", fontsize=9)
    fig.suptitle(
        f"a {side_m:g} m square to {to}, steered by the fin's offset: the paths swum and their cost",
        fontsize=10,
    )
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=70)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fish", nargs="+", default=[*TWINS, *STRANGERS], choices=[*TWINS, *STRANGERS])
    ap.add_argument("--side", type=float, default=20.0, help="the square's side, m")
    ap.add_argument("--to", choices=("port", "starboard"), default="port",
                    help="the way each corner turns (a P1 fin turns fast to port)")  # fmt: skip
    ap.add_argument("--drives", nargs="+", default=list(DRIVES), choices=DRIVES, metavar="DRIVE",
                    help=f"of: {'; '.join(DRIVES)}")  # fmt: skip
    ap.add_argument("--plot", type=Path, help="draw the paths swum over the course and their cost (PNG)")
    workers.add_arguments(ap)
    a = ap.parse_args(argv)
    if not (a.side > 0 and np.isfinite(a.side)):
        ap.error(f"--side {a.side!r}: a finite side > 0, m")
    tasks = [(name, d, a.side, a.to) for name in a.fish for d in DRIVES if d in a.drives]
    t0 = time.perf_counter()
    try:
        results = workers.run_parsed(run, tasks, a, lambda t: f"{t[0]}, {t[1]}")
    except PiezofinError as exc:
        ap.error(str(exc))
    print(f"a {a.side:g} m square swum to {a.to} on mfc-fish's planar body, steered by the fin's offset:")
    print(table(results))
    if a.plot:
        plot(results, a.side, a.plot, a.to)
        print(f"the paths: {a.plot}")
    sim = sum(r["run"].time_s for r in results)
    print(
        f"\n{len(tasks)} courses, {sim:.0f} s of fish time in {time.perf_counter() - t0:.0f} s of wall time"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
