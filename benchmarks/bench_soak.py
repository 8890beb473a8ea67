"""Soak: the live graph across processes at the default rate, for a long time.

    python benchmarks/bench_soak.py [--minutes 10] [--warmup 60]

``fin_sim`` (1 kHz, real time), ``thrust_estimator``, ``controller`` (continuous trials at 800 Vpp,
cycling frequencies) and ``recorder`` each run as their own process, as ``ros2 run`` starts them.
This process subscribes to every data topic and reports:

* **drops**: samples missing from the sample-time sequence of each topic (``t_s`` must advance by
  exactly one sample period, block after block), live and in the recorded bag;
* **memory**: each process's resident set (``VmRSS``) after warm-up and at the end, and its growth;
* **estimator latency**: the wall time from the arrival here of the drive block holding a running
  estimate's last sample to the arrival of that estimate (p50, p90, p99, max); final estimates wait
  for the load cell's post-burst baseline by design and are not counted.

The baseline of the same run is the warm-up: growth and latency are judged against it (ratios).
``test_crossprocess.py`` runs a 30 s version.  DDS stays on loopback.
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
BIN = Path(sys.executable).parent
NS = "soak"
RATE_HZ = 1000.0


def _env() -> dict[str, str]:
    drop = ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "LD_LIBRARY_PATH")
    return {k: v for k, v in os.environ.items() if k not in drop}


def rss_kib(pid: int) -> int:
    """Resident set size of a process, KiB (``/proc``; 0 once it has gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


@dataclass
class SoakResult:
    seconds: float
    warmup_s: float
    samples: dict[str, int]
    drops_live: dict[str, int]
    samples_in_bag: int
    drops_in_bag: int
    rss_warm_kib: dict[str, int]
    rss_end_kib: dict[str, int]
    rss_growth: dict[str, float]
    estimates: int
    latency_s: dict[str, float]

    def table(self) -> str:
        lines = [
            f"soak {self.seconds:.0f} s (warm-up {self.warmup_s:.0f} s), 1 kHz, 4 processes",
            "samples received: " + ", ".join(f"{k} {v}" for k, v in self.samples.items()),
            "drops live: " + ", ".join(f"{k} {v}" for k, v in self.drops_live.items()),
            f"drive samples in the bag: {self.samples_in_bag}, drops in the bag: {self.drops_in_bag}",
            "memory (RSS after warm-up -> end): "
            + ", ".join(
                f"{k} {self.rss_warm_kib[k] / 1024:.1f} -> {self.rss_end_kib[k] / 1024:.1f} MiB "
                f"({100 * self.rss_growth[k]:+.1f} %)"
                for k in self.rss_warm_kib
            ),
            f"running estimates: {self.estimates}; latency "
            + ", ".join(f"{k} {v * 1e3:.1f} ms" for k, v in self.latency_s.items()),
        ]
        return "\n".join(lines)


def drops(t_blocks: list[np.ndarray], period: float) -> int:
    """Samples missing from a sequence of sample-time blocks (gaps of more than one period)."""
    if not t_blocks:
        return 0
    t = np.concatenate(t_blocks)
    steps = np.round(np.diff(t) / period)
    return int(np.sum(np.maximum(steps - 1, 0)) + np.sum(steps < 1))  # holes, and repeats/reversals


def soak(seconds: float, warmup_s: float, directory: Path, progress: bool = True) -> SoakResult:
    import rclpy
    from rclpy.experimental import EventsExecutor

    from piezofin_ros.bags import block_of, read_messages
    from piezofin_ros.nodes._common import QOS_DATA, endpoint, msg_block

    bag = directory / "soak.mcap"
    on_s = max(10.0, seconds / 3)
    commands = {
        "fin_sim": ["-p", "seed:=11"],
        # (the estimator keeps its samples for a bounded horizon, max_window_s + settle_s + 2 baseline_s
        # + post_delay_s + channel_timeout_s + 5 s: 81 s by default, so its memory grows until then; here
        # 19 s, within the warm-up, so that what grows after it is a leak)
        "thrust_estimator": [
            "-p", "estimator.window_s:=2.0", "-p", "estimator.settle_s:=2.0",
            "-p", "estimator.max_window_s:=5.0", "-p", "estimator.baseline_s:=2.0",
        ],
        "controller": [
            "-p", "mode:=continuous", "-p", "frequencies:=[5.0, 6.0, 7.0, 8.0]",
            "-p", "voltages:=[800.0]", "-p", f"on_s:={min(on_s, 600.0)}", "-p", "after:=hold",
        ],
        "recorder": ["-p", f"path:={bag}", "-p", f"namespaces:=[{NS}]", "-p", "topics:=[drive]"],
    }  # fmt: skip
    procs: dict[str, subprocess.Popen[bytes]] = {}
    for exe, args in commands.items():
        procs[exe] = subprocess.Popen(
            [str(BIN / exe), "--ros-args", "-r", f"__ns:=/{NS}", *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=_env(),
        )
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("soak_monitor", namespace=NS, context=context)
    executor = EventsExecutor(context=context)
    executor.add_node(node)
    blocks: dict[str, list[np.ndarray]] = {"drive": [], "tip_velocity": [], "loadcell": []}
    drive_arrivals: list[tuple[float, float]] = []  # (last sample time, wall arrival)
    estimates: list[tuple[float, float]] = []  # (t_end, wall arrival)
    counting = [False]

    def on_data(topic: str, msg: Any) -> None:
        if not counting[0]:
            return
        t = np.asarray(msg_block(msg)["t_s"])
        blocks[topic].append(t)
        if topic == "drive":
            drive_arrivals.append((float(t[-1]), time.monotonic()))

    def on_estimate(msg: Any) -> None:
        if counting[0]:
            b = msg_block(msg)
            if not b["final"][0]:  # a final estimate waits for the load cell's post baseline by design
                estimates.append((float(b["t_end"][0]), time.monotonic()))

    for topic in blocks:
        node.create_subscription(endpoint(topic)[0], topic, lambda m, t=topic: on_data(t, m), QOS_DATA)
    node.create_subscription(endpoint("estimate")[0], "estimate", on_estimate, QOS_DATA)
    rss_warm: dict[str, int] = {}
    try:
        t0 = time.monotonic()
        counting[0] = True
        next_report = t0
        while (now := time.monotonic()) - t0 < seconds:
            executor.spin_once(timeout_sec=0.05)
            if not rss_warm and now - t0 >= warmup_s:
                rss_warm = {name: rss_kib(p.pid) for name, p in procs.items()}
            if progress and now >= next_report:
                n_drive = sum(len(b) for b in blocks["drive"])
                print(
                    f"  {now - t0:5.0f}/{seconds:.0f} s: {n_drive} drive samples, {len(estimates)} estimates",
                    file=sys.stderr,
                    flush=True,
                )
                next_report = now + 30.0
            dead = [name for name, p in procs.items() if p.poll() is not None]
            if dead:
                raise RuntimeError(f"process(es) {dead} exited during the soak")
        counting[0] = False
        rss_end = {name: rss_kib(p.pid) for name, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs.values():
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    period = 1.0 / RATE_HZ
    # A block straddling the start or the end of counting is whole: drops are holes inside the run.
    bag_t = [np.asarray(block_of(m.type_name, m.data)["t_s"]) for m in read_messages(bag, [f"/{NS}/drive"])]
    live_drive = np.concatenate(blocks["drive"])
    in_bag = np.concatenate(bag_t)
    # over the span both saw (the recorder subscribes a little after the monitor starts counting)
    lo, hi = max(live_drive[0], in_bag[0]), min(live_drive[-1], in_bag[-1])
    span = in_bag[(in_bag >= lo) & (in_bag <= hi)]
    live_span = live_drive[(live_drive >= lo) & (live_drive <= hi)]
    arrival_t = [a[0] for a in drive_arrivals]
    latencies = []
    for t_end, wall in estimates:
        i = bisect.bisect_left(arrival_t, t_end - 0.5 * period)
        if i < len(drive_arrivals):
            latencies.append(wall - drive_arrivals[i][1])
    lat = np.asarray(latencies)
    pct = {f"p{q}": float(np.percentile(lat, q)) for q in (50, 90, 99)} if lat.size else {}
    if lat.size:
        pct["max"] = float(lat.max())
    return SoakResult(
        seconds=seconds,
        warmup_s=warmup_s,
        samples={k: int(sum(b.size for b in v)) for k, v in blocks.items()},
        drops_live={k: drops(v, period) for k, v in blocks.items()},
        samples_in_bag=int(span.size),
        drops_in_bag=drops([span], period) + max(0, live_span.size - span.size),
        rss_warm_kib=rss_warm,
        rss_end_kib=rss_end,
        rss_growth={k: (rss_end[k] - rss_warm[k]) / max(rss_warm[k], 1) for k in rss_warm},
        estimates=len(estimates),
        latency_s=pct,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--warmup", type=float, default=60.0, help="seconds before the memory baseline")
    ap.add_argument("--json", help="also write the result here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        result = soak(args.minutes * 60.0, args.warmup, Path(d))
    print(result.table())
    if args.json:
        Path(args.json).write_text(json.dumps(asdict(result), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
