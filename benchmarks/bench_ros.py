"""Benchmarks of the live suite, each against a baseline measured in the same run.

    python benchmarks/bench_ros.py [--quick] [--skip-main]

1. Recorder write path vs the ``rosbags`` rosbag2 writer (MCAP storage) on the same serialised
   messages; and the recorder node end to end (publisher -> DDS -> raw subscription -> file).
2. The main job's wall time (``bringup`` with its default 22 protocol trials).
3. Cross-process throughput: ``fin_sim`` in another process, faster and faster than real time,
   one subscriber here; where drops begin, with the suite's 50-sample blocks and with one
   sample per message (the design the blocks replace).

Run with the project's environment (``source tools/env.sh``); DDS stays on loopback.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
BIN = Path(sys.executable).parent


def serialised_blocks(n: int) -> list[bytes]:
    from rclpy.serialization import serialize_message

    from piezofin_ros.bags.blocks import Block
    from piezofin_ros.nodes._common import block_msg

    rng = np.random.default_rng(0)
    out = []
    for k in range(n):
        t = k * 0.05 + np.arange(50) / 1000
        out.append(
            bytes(
                serialize_message(
                    block_msg(
                        Block.from_columns(
                            t_s=t, voltage_V=rng.normal(size=50), current_A=rng.normal(size=50)
                        )
                    )
                )
            )
        )
    return out


def bench_writers(n: int) -> dict[str, dict[str, float]]:
    """Our write path and the rosbags writer, same messages, without and with zstd chunks."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
    from rosbags.typesys import Stores, get_typestore

    from piezofin_ros.bags import BagWriter, message_definition

    data = serialised_blocks(n)
    store = get_typestore(Stores.ROS2_JAZZY)
    message_definition("std_msgs/msg/Float64MultiArray")  # build the type store outside the timing
    out = {}
    for compression in ("none", "zstd"):
        tmp = Path(tempfile.mkdtemp())
        t0 = time.perf_counter()
        with BagWriter(tmp / "ours.mcap", compression=compression) as bag:
            bag.add_topic("/fin/drive", "std_msgs/msg/Float64MultiArray")
            for k, d in enumerate(data):
                bag.write("/fin/drive", k * 50_000_000, d)
        ours = time.perf_counter() - t0
        t0 = time.perf_counter()
        w = Writer(tmp / "rosbags", version=9, storage_plugin=StoragePlugin.MCAP)
        if compression == "zstd":
            w.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        with w:
            conn = w.add_connection("/fin/drive", "std_msgs/msg/Float64MultiArray", typestore=store)
            for k, d in enumerate(data):
                w.write(conn, k * 50_000_000, d)
        theirs = time.perf_counter() - t0
        out[compression] = {"ours_msg_s": n / ours, "rosbags_msg_s": n / theirs, "ratio": theirs / ours}
    return out


def bench_recorder_node(n: int) -> dict[str, float]:
    """Publisher and recorder in one process over DDS; bursts of 100, then drain."""
    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray

    from piezofin_ros.nodes._common import QOS_DATA
    from piezofin_ros.nodes.recorder import Recorder

    data = serialised_blocks(n)
    path = Path(tempfile.mkdtemp()) / "rec.mcap"
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    rec = Recorder(
        context=ctx,
        parameter_overrides=[
            Parameter("path", value=str(path)),
            Parameter("topics", value=["/b/drive:std_msgs/msg/Float64MultiArray"]),
        ],
    )
    src = rclpy.create_node("src", context=ctx)
    pub = src.create_publisher(Float64MultiArray, "/b/drive", QOS_DATA)
    ex = EventsExecutor(context=ctx)
    ex.add_node(rec)
    ex.add_node(src)
    while pub.get_subscription_count() < 1:
        ex.spin_once(timeout_sec=0.05)
    t0 = time.perf_counter()
    for start in range(0, n, 100):
        for d in data[start : start + 100]:
            pub.publish(d)
        while rec.counts["/b/drive"] < min(start + 100, n):
            ex.spin_once(timeout_sec=0.05)
    dt = time.perf_counter() - t0
    rec.close()
    ex.shutdown()
    rclpy.shutdown(context=ctx)
    return {"node_msg_s": n / dt, "samples_s": 50 * n / dt}


def bench_main_job() -> dict[str, float]:
    out = Path(tempfile.mkdtemp())
    t0 = time.perf_counter()
    run = subprocess.run(
        [BIN / "bringup", "--bag", str(out / "main.mcap")],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    wall = time.perf_counter() - t0
    m = re.search(r"simulated (\d+) s in ([\d.]+) s", run.stdout)
    if run.returncode != 0 or m is None:
        raise RuntimeError(run.stdout[-2000:] + run.stderr[-2000:])
    trials = len(re.findall(r"^\s+\d+\s+[\d.]+\s+\d+\s", run.stdout, flags=re.M))
    return {"trials": trials, "sim_s": float(m.group(1)), "loop_s": float(m.group(2)), "process_s": wall}


def bench_crossprocess(factor: float, block_s: float, seconds: float) -> dict[str, float]:
    from typing import Any

    import rclpy
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from rclpy.experimental import EventsExecutor

    from piezofin_ros.nodes._common import QOS_DATA, endpoint

    env = {
        k: v for k, v in os.environ.items() if k not in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "LD_LIBRARY_PATH")
    }
    ns = f"/x{os.getpid()}"
    proc = subprocess.Popen(
        [
            BIN / "fin_sim",
            "--ros-args",
            "-r",
            f"__ns:={ns}",
            "-p",
            "autostart:=false",
            "-p",
            f"realtime_factor:={factor}",
            "-p",
            f"block_s:={block_s}",
        ],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("count", context=ctx)
    counts = {"drive": 0, "tip_velocity": 0, "loadcell": 0}

    def counter(topic: str):
        def cb(msg: Any) -> None:
            counts[topic] += len(msg.t_s)

        return cb

    for topic in counts:
        node.create_subscription(endpoint(topic)[0], f"{ns}/{topic}", counter(topic), QOS_DATA)
    ex = EventsExecutor(context=ctx)
    ex.add_node(node)
    change = node.create_client(ChangeState, f"{ns}/fin_sim/change_state")
    try:
        deadline = time.monotonic() + 20
        while not change.service_is_ready() and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        if not change.service_is_ready():
            raise RuntimeError(
                f"fin_sim did not start: {proc.communicate(timeout=5)[0] if proc.poll() is not None else ''}"
            )
        for tr in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
            if tr == Transition.TRANSITION_ACTIVATE:
                while not all(node.count_publishers(f"{ns}/{t}") for t in counts):
                    ex.spin_once(timeout_sec=0.05)
                t_wait = time.monotonic()
                while time.monotonic() - t_wait < 0.5:
                    ex.spin_once(timeout_sec=0.05)
            fut = change.call_async(ChangeState.Request(transition=Transition(id=tr)))
            while not fut.done():
                ex.spin_once(timeout_sec=0.05)
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            ex.spin_once(timeout_sec=0.05)
        proc.send_signal(signal.SIGINT)
        t_stop = time.monotonic()
        while proc.poll() is None and time.monotonic() - t_stop < 20:
            ex.spin_once(timeout_sec=0.05)
        end = time.monotonic()
        while time.monotonic() - end < 1.0:  # drain what is in flight
            ex.spin_once(timeout_sec=0.05)
        out = proc.communicate(timeout=20)[0]
    finally:
        if proc.poll() is None:
            proc.kill()
        ex.shutdown()
        rclpy.shutdown(context=ctx)
    published = {k: int(v) for k, v in re.findall(r"(\w+) (\d+)", out.split("published samples:")[-1])}
    pub = published.get("drive", 0)
    lost = sum(published.get(k, 0) - counts[k] for k in counts)
    return {
        "factor": factor,
        "samples_per_msg": round(block_s * 1000),
        "achieved_samples_s": pub / seconds,
        "msgs_s": 3 * pub / seconds / max(1, round(block_s * 1000)),
        "lost": lost,
        "published": 3 * pub,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller runs")
    ap.add_argument("--skip-main", action="store_true", help="do not time the main job")
    args = ap.parse_args()
    n = 5_000 if args.quick else 30_000
    ws = bench_writers(n)
    for compression, w in ws.items():
        print(
            f"write path, {compression:>4} chunks: ours {w['ours_msg_s']:,.0f} msg/s, rosbags writer "
            f"{w['rosbags_msg_s']:,.0f} msg/s: ratio {w['ratio']:.2f} ({n} 50-sample drive blocks)"
        )
    w = ws["zstd"]
    r = bench_recorder_node(n // 3)
    print(
        f"recorder node over DDS (one process): {r['node_msg_s']:,.0f} msg/s = "
        f"{r['samples_s']:,.0f} samples/s ({r['node_msg_s'] / w['ours_msg_s']:.2f} of the bare write path)"
    )
    if not args.skip_main:
        m = bench_main_job()
        print(
            f"main job: {m['trials']} protocol trials, {m['sim_s']:.0f} s simulated, "
            f"run loop {m['loop_s']:.1f} s, whole process {m['process_s']:.1f} s "
            f"(x{m['sim_s'] / m['loop_s']:.0f} real time)"
        )
    seconds = 4.0 if args.quick else 8.0
    print("cross-process (fin_sim -> one Python subscriber, reliable, depth 200):")
    print(f"  {'samples/msg':>11} {'factor':>6} {'samples/s/topic':>15} {'msgs/s':>8} {'lost':>6}")
    for block_s, factors in ((0.05, (1, 10, 30, 100, 200, 400, 1000)), (0.001, (1, 2, 4, 8, 16))):
        for factor in factors:
            c = bench_crossprocess(factor, block_s, seconds)
            print(
                f"  {c['samples_per_msg']:>11d} {factor:>6g} {c['achieved_samples_s']:>15,.0f} "
                f"{c['msgs_s']:>8,.0f} {c['lost']:>6d}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
