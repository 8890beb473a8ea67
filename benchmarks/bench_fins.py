"""Several fins in one ``bringup``: aborts, dropped samples, one clock, wall time.

    python benchmarks/bench_fins.py --fins 4            # 22 protocol trials per fin, 660 s of fin time

Runs ``bringup --namespaces f0 f1 ...`` as a user does (its own process, default realtime factor),
then reads the bag with ``rosbags`` (an independent reader): every fin's drive samples must be
contiguous (1 ms apart, nothing lost) and identical in time across fins, every controller done.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader


def run(n_fins: int, extra: list[str]) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as tmp:
        bag, status = Path(tmp) / "fins.mcap", Path(tmp) / "status.json"
        names = [f"f{k}" for k in range(n_fins)]
        exe = str(Path(sys.executable).parent / "bringup")
        argv = [exe, "--namespaces", *names, "--bag", str(bag), "--json", str(status), *extra]
        # another rclpy's bootstrap variables break the child's (see the notes on the wheels)
        env = {
            k: v
            for k, v in os.environ.items()
            if k not in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "LD_LIBRARY_PATH")
        }
        t0 = time.monotonic()
        proc = subprocess.run(argv, capture_output=True, text=True, stdin=subprocess.DEVNULL, env=env)
        wall = time.monotonic() - t0
        states = {ns: f["state"] for ns, f in json.loads(status.read_text())["fins"].items()}
        times: dict[str, list[np.ndarray]] = {}
        with AnyReader([bag]) as reader:
            drives = [c for c in reader.connections if c.topic.endswith("/drive")]
            for conn, _, raw in reader.messages(drives):
                m = reader.deserialize(raw, conn.msgtype)
                times.setdefault(conn.topic, []).append(np.asarray(m.t_s))  # (piezofin_msgs/Drive)
    t = {k: np.concatenate(v) for k, v in sorted(times.items())}
    first = next(iter(t.values()))
    gaps = {k: int(np.sum(np.diff(v) > 1.5e-3)) for k, v in t.items()}
    return {
        "exit": proc.returncode,
        "wall_s": round(wall, 1),
        "fin_s": round(float(first[-1] - first[0]), 1),
        "states": states,
        "samples": {k: int(v.size) for k, v in t.items()},
        "gaps": gaps,
        "one_clock": all(np.array_equal(first, v) for v in t.values()),
        "summary": proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr[-500:],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--fins", type=int, default=4)
    args, extra = p.parse_known_args()
    r = run(args.fins, extra)
    print(json.dumps(r, indent=1))
    ok = r["exit"] == 0 and set(r["states"].values()) == {"done"} and not any(r["gaps"].values())  # type: ignore[attr-defined]
    return 0 if ok and r["one_clock"] else 1


if __name__ == "__main__":
    sys.exit(main())
