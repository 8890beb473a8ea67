"""A fingerprint of the optimiser's and the fish loop's behaviour, for a change that must not change it.

Runs fixed-seed scenarios (every thrust source, with and without a demand, a measured supply, the
range objective, a prior that is dropped, a fin that changes, and a 200 s fish run with two
set-points through the drive loop and the speed loop) and prints one hash per scenario of every rule,
mode, choice, held point, bound, fitted correction and proposal (the fish: its speed and supply).

    python tools/fingerprint.py                      # this tree's hashes
    python tools/fingerprint.py --against ../before  # and another tree's (a git worktree), compared

With ``--against`` it exits 1 when any hash differs and names the scenarios.  Used for the
optimiser's split into rooms (issue 40): identical on all ten.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import subprocess
import sys
from pathlib import Path

_AGAINST = """
import runpy, sys
sys.meta_path = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
sys.path.insert(0, {tree!r})
sys.argv = ["fingerprint", "--trials", {trials!r}, "--json"]
runpy.run_path({me!r}, run_name="__main__")
"""


def scenarios(trials: int) -> dict[str, str]:
    import numpy as np

    from piezofin_ros.bench import evaluation
    from piezofin_ros.bench.fishrun import drive_for, swim_run
    from piezofin_ros.bench.plants import Plant
    from piezofin_ros.control.objective import range_per_charge
    from piezofin_ros.control.optimise import OperatingBox, Optimiser
    from piezofin_ros.control.speedloop import SpeedLoopConfig
    from piezofin_ros.physics.amplifier import load_amplifier
    from piezofin_ros.physics.effects import DragOffset, Leakage
    from piezofin_ros.physics.fin import load_fin
    from piezofin_ros.physics.model import load_model
    from piezofin_ros.physics.swim import load_battery, load_body

    fin = load_fin("M8528-P1")
    box = OperatingBox(1.0, 20.0, 50.0, 800.0)
    twin = load_model("paper-twin-M8528-P1")
    fish = {"demand_n": 3e-3, "source": "self", "trial_overshoot": 0.1, "demand_margin_z": 0.0}
    changing = Plant(
        fin, softening=0.5, resonance_scale=lambda t: 1.0 if t < 40 else 0.8, effects=(DragOffset(3.0),)
    )
    ranged = {"demand_n": 3e-3, "objective": range_per_charge(0.5), "watt": "supply"}
    cases = {
        "vibrometer": (Plant(fin, loss_tan_delta=0.02), {}, 1),
        "vibrometer, demand": (Plant(fin), {"demand_n": 4e-3}, 1),
        "self, demand, a leak": (
            Plant(fin, loss_tan_delta=0.03, effects=(Leakage(0.08),)),
            {"demand_n": 3e-3, "source": "self"},
            1,
        ),
        "a fish, supply watt": (Plant(fin, effects=(DragOffset(1.5),)), {**fish, "watt": "supply"}, 1),
        "load cell": (Plant(fin), {"source": "loadcell", "demand_n": 2e-3}, 1),
        "twin prior, drag": (Plant(fin, effects=(DragOffset(1.3),)), {**fish, "model": twin}, 1),
        "twin prior, nominal fin": (Plant(fin), {**fish, "model": twin}, 2),
        "a fin that changes": (changing, {}, 2),
        "range objective": (Plant(fin), ranged, 1),
    }
    out = {}
    for name, (plant, kw, times) in cases.items():
        opt = Optimiser(fin, box, **kw)  # type: ignore[arg-type]
        rng, t, trace = np.random.default_rng(5), 0.0, [[opt.rule, str(opt.mode)]]
        for _ in range(trials * times):
            t = evaluation.run_trial(opt, plant, t, rng)
            st = opt.status()
            bound = opt.self_sensing_bound
            trace.append([
                opt.rule, st["optimiser_mode"], round(st["frequency_hz"], 9), round(st["voltage_pp"], 6),
                json.dumps(st["held"], sort_keys=True, default=str),
                round(bound, 9) if math.isfinite(bound) else None,
                {k: round(v, 9) for k, v in st["correction"].items()},
                opt.converged, len(opt.observations), opt.changes, opt.prior_dropped, opt.propose(),
            ])  # fmt: skip
        out[name] = hashlib.sha1(json.dumps(trace, sort_keys=True, default=str).encode()).hexdigest()[:12]
    amp = load_amplifier("fish-switching")
    plant = Plant(twin.fin, effects=twin.effects, amplifier=amp)
    run = swim_run(
        plant,
        load_body("mfc-fish"),
        drive_for("ours (supply watt)", twin, plant, amp),
        [(0.0, 0.048), (100.0, 0.062)],
        200.0 * trials / 12,  # (200 s of fish time at the default 12 trials)
        load_battery("li-ion-2s-500mah"),
        loop_config=SpeedLoopConfig(max_demand_n=0.008),
    )
    both = np.concatenate([np.asarray(run.speed_m_s), np.asarray(run.supply_w)])
    out["a fish swims, two set-points"] = hashlib.sha1(both.tobytes()).hexdigest()[:12]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--trials", type=int, default=12, help="trials per scenario (the fish: 20 s each)")
    p.add_argument("--against", type=Path, help="another tree (a git worktree) to compare with")
    p.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.against is not None and not (args.against / "piezofin_ros" / "__init__.py").exists():
        p.error(f"--against {args.against}: no piezofin_ros there (a git worktree of the project)")
    here = scenarios(args.trials)
    if args.json:
        print(json.dumps(here))
        return 0
    other: dict[str, str] = {}
    if args.against is not None:
        code = _AGAINST.format(
            tree=str(args.against.resolve()), trials=str(args.trials), me=os.path.abspath(__file__)
        )
        run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
        if run.returncode != 0:
            print(run.stderr[-2000:], file=sys.stderr)
            return 2
        other = json.loads(run.stdout.strip().splitlines()[-1])
    width = max(map(len, here))
    for name, h in here.items():
        mark = "" if not other else ("  same" if other.get(name) == h else f"  DIFFERS ({other.get(name)})")
        print(f"{name:<{width}}  {h}{mark}")
    differ = [n for n in here if other and other.get(n) != here[n]]
    if other:
        print(
            f"{len(here) - len(differ)} of {len(here)} identical"
            + (f"; differ: {', '.join(differ)}" if differ else "")
        )
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
