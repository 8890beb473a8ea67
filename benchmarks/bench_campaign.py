"""The paper's whole campaign, as a user runs it, timed (goal: within 5 minutes on this machine).

    python benchmarks/bench_campaign.py            # runs `piezofin campaign paper -o out/campaign --force`
    python benchmarks/bench_campaign.py --docs     # and copies the figures and report to docs/campaign/

Three fins, each through the live suite (one `bringup` process per fin and stage, in parallel):
in-air and underwater stepped sines of 21 points, the identification, and the thrust protocol at
400/600/800 Vpp over 1-11 Hz widened to each fin's band (42, 60 and 48 trials of 30 s: 4,500 s of
fin time).  Prints the wall time of the whole command (start-up included) and the report's table of
the paper's facts.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(ROOT / "out" / "campaign"))
    p.add_argument("--docs", action="store_true", help="copy the figures and report.md to docs/campaign/")
    args = p.parse_args(argv)
    exe = shutil.which("piezofin", path=str(Path(sys.executable).parent)) or "piezofin"
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "MPLBACKEND": "Agg"}
    t0 = time.monotonic()
    argv = [exe, "campaign", "paper", "-o", args.out, "--force"]
    proc = subprocess.run(argv, stdin=subprocess.DEVNULL, env=env)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        print(f"campaign failed (exit {proc.returncode})", file=sys.stderr)
        return 1
    out = Path(args.out)
    report = json.loads((out / "report.json").read_text())
    print(f"\nwall time of `piezofin campaign paper`: {wall:.0f} s (goal 300 s)")
    for f in report["facts"]:
        print(f"| {f['fact']} | {f['paper']} | {f['suite']} | {f['verdict']} |")
    if args.docs:
        dest = ROOT / "docs" / "campaign"
        dest.mkdir(parents=True, exist_ok=True)
        for name in [*report["figures"], "report.md"]:
            shutil.copy(out / name, dest / name)
        print(f"copied {len(report['figures'])} figures and report.md to {dest}")
    return 0 if wall <= 300 else 1


if __name__ == "__main__":
    sys.exit(main())
