"""A flood from another process: ``python test/flood.py TOPIC KIND RATE SECONDS`` publishes on TOPIC
at RATE messages a second (paced; as fast as it can when it cannot keep up) for SECONDS, then prints
how many it sent.  KIND: ``speed`` (std_msgs/Float64 of plausible speeds), ``demand`` (Float64 of
plausible thrust demands), ``supply``, ``drive``, ``tip`` or ``loadcell`` (blocks of plausible
samples at times of their own), ``estimate`` (plausible estimates), ``cmd`` (0 V commands), ``twist``
(geometry_msgs/Twist: a teleop's speeds straight ahead, every eighth no speed at all: NaN, inf,
+-1e9, 1e308), ``bias`` (Float64 offsets of 0 V: a fish swimming straight), ``cap`` (Float64 voltage
caps of 2,000 Vpp: none, as a straight fish's yaw loop sends), ``imu`` (sensor_msgs/Imu: a gyro
at rest) or ``status`` (std_msgs/String: an estimator's status that names no supply meter, and
strings that are no status).

Not a test module: the flood tests start it as an attacker would be, in a process of its own.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from piezofin_ros.bags.blocks import Block
from piezofin_ros.estimation.estimator import Estimate
from piezofin_ros.nodes._common import block_msg, record_msg, sample_msg, speed_msg


def messages(kind: str) -> list:
    rng = np.random.default_rng(1)
    if kind == "speed":
        from geometry_msgs.msg import TwistStamped

        return [speed_msg(TwistStamped, float(x), 1.0) for x in rng.uniform(0.0, 0.2, 64)]
    if kind == "demand":
        return [Float64(data=float(x)) for x in rng.uniform(1e-4, 8e-3, 64)]
    if kind == "estimate":
        from piezofin_msgs.msg import Estimate as EstimateMsg

        names = Estimate.field_names()
        return [record_msg(EstimateMsg, dict.fromkeys(names, float(x)), 1.0) for x in rng.uniform(0, 1e-3, 8)]
    if kind == "twist":
        from geometry_msgs.msg import Twist

        speeds = rng.uniform(0.0, 0.1, 64)
        speeds[::8] = [np.nan, np.inf, -np.inf, 1e9, -1e9, 1e308, np.nan, np.inf]
        out = []
        for k, x in enumerate(speeds):
            msg = Twist()
            msg.linear.x = float(x)
            msg.angular.z = (
                float(x) if k % 8 == 0 else 0.0
            )  # (straight: the offset's window is test_safety's)
            out.append(msg)
        return out
    if kind == "bias":
        return [Float64(data=0.0)]
    if kind == "cap":
        return [Float64(data=2000.0)]
    if kind == "imu":
        from sensor_msgs.msg import Imu

        msg = Imu()
        msg.orientation.w = 1.0
        return [msg]
    if kind == "status":
        from std_msgs.msg import String

        named = json.dumps({"supply_watt_measured_on": "", "estimates": 0})
        return [String(data=x) for x in (named, "not JSON", "[1, 2]", json.dumps({"estimates": 3}))]
    if kind == "cmd":
        return [block_msg(Block.from_record({"frequency_hz": 5.0, "voltage_pp_V": 0.0, "on": 0.0}))]
    t = 1e6 + np.arange(20) * 1e-3  # (times of its own, far from the fin's)
    topic, columns = {
        "supply": ("supply", {"supply_voltage_V": np.full(20, 7.4), "supply_current_A": np.full(20, 0.01)}),
        "drive": ("drive", {"voltage_V": np.zeros(20), "current_A": np.zeros(20)}),
        "tip": ("tip_velocity", {"tip_velocity_m_s": np.zeros(20)}),
        "loadcell": ("loadcell", {"displacement_m": np.zeros(20)}),
    }[kind]
    return [sample_msg(topic, Block.from_columns(t_s=t, **columns))]


def main(topic: str, kind: str, rate: float, seconds: float) -> int:
    msgs = messages(kind)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("_flood", context=context)
    pub = node.create_publisher(
        type(msgs[0]), topic, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )
    t_wait = time.monotonic() + 10.0
    while pub.get_subscription_count() == 0 and time.monotonic() < t_wait:
        time.sleep(0.05)
    sent = 0
    t0 = time.monotonic()
    while (now := time.monotonic()) < t0 + seconds:
        due = int(rate * (now - t0))
        while sent < due:
            pub.publish(msgs[sent % len(msgs)])
            sent += 1
        time.sleep(0.0005)
    print(f"sent {sent} in {time.monotonic() - t0:.1f} s", flush=True)
    node.destroy_node()
    rclpy.shutdown(context=context)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])))
