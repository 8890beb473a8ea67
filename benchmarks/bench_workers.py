"""The worker engine's overhead against the ideal speed-up: one benchmark's tasks on 1 and N workers.

    python benchmarks/bench_workers.py [--seeds 1] [--workers 2] [--ray]

The tasks are ``bench_controller.py``'s (one plant of one fin, task and seed each: ours, the grid and
random search), run two or three ways in the same run: in this process one after another (the
baseline, what a user's loop would do, and what ``--workers 1`` does), on ``--workers`` local worker
processes and, with ``--ray``, on a local Ray instance with as many CPUs.  Reported: each
wall time, the speed-up over the baseline, its ratio to the ideal (``N``x), and whether every result
is identical to the baseline's (the tables built from them are then identical too).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_controller import PLANTS, plant_task, tasks_for

from piezofin_ros import workers


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--fins", nargs="+", default=["M8528-P1", "M8514-P1", "M8507-P1"])
    ap.add_argument("--workers", type=int, default=workers.default_workers())
    ap.add_argument("--ray", action="store_true", help="also on a local Ray instance")
    args = ap.parse_args()
    tasks = tasks_for(args.fins, args.seeds, list(PLANTS))
    print(f"{len(tasks)} tasks of bench_controller.py; {args.workers} workers", flush=True)

    def timed(label: str, **kw: object) -> tuple[float, list]:
        t0 = time.perf_counter()
        out = workers.run_tasks(plant_task, tasks, **kw)  # type: ignore[arg-type]
        dt = time.perf_counter() - t0
        print(f"  {label}: {dt:.1f} s", file=sys.stderr, flush=True)
        return dt, out

    base_s, base = timed("in this process", workers=1)
    rows = [("in this process, one after another (baseline)", 1, base_s, base)]
    n_s, n = timed(f"{args.workers} workers", workers=args.workers)
    rows.append((f"{args.workers} local worker processes", args.workers, n_s, n))
    if args.ray:
        r_s, r = timed("ray", workers=args.workers, ray_address="local")
        rows.append((f"Ray, local instance, {args.workers} CPUs (start-up included)", args.workers, r_s, r))
    print("| engine | wall [s] | speed-up | of the ideal | results identical to the baseline |")
    print("|---|---|---|---|---|")
    for label, k, s, out in rows:
        same = "yes" if repr(out) == repr(base) else "NO"
        print(f"| {label} | {s:.1f} | {base_s / s:.2f}x | {base_s / s / k:.0%} | {same} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
