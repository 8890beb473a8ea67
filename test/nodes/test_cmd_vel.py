"""A fish stack drives the speed loop as ROS base controllers are driven (issue 42): ``cmd_vel`` from
another process sets the set-point, a silence of 0.5 s stops the fish, and a command that is no
command is refused at the door, whatever its field."""

from __future__ import annotations

import itertools
import math
import time
from pathlib import Path

import pytest
import rclpy
from geometry_msgs.msg import Twist
from std_msgs.msg import Float64, String

from piezofin_ros.nodes._common import QOS_COMMAND, QOS_DATA, QOS_STATUS, speed_msg

from ..rosutil import data_type, graph, start, stop

pytestmark = pytest.mark.ros


def twist(forward: float, yaw: float = 0.0) -> Twist:
    msg = Twist()
    msg.linear.x, msg.angular.z = forward, yaw
    return msg


@pytest.mark.slow
def test_cmd_vel_sets_the_speed_and_its_silence_stops_the_fish(tmp_path: Path) -> None:
    log = tmp_path / "speed_loop.log"
    proc = start("speed_loop", "-r", "__ns:=/cv", "-p", "rate_hz:=20.0", log=log)
    demands: list[tuple[float, float]] = []
    states: list[str] = []
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("stack", namespace="cv", context=g.context))
            pub = node.create_publisher(Twist, "cmd_vel", QOS_COMMAND)
            node.create_subscription(
                Float64, "thrust_demand", lambda m: demands.append((time.monotonic(), m.data)), QOS_COMMAND
            )
            node.create_subscription(String, "speed_loop/status", lambda m: states.append(m.data), QOS_STATUS)
            g.spin_until(
                lambda: pub.get_subscription_count() > 0, timeout=60.0, what="the speed loop's cmd_vel"
            )

            def send(msg: Twist, seconds: float) -> None:
                t_end = time.monotonic() + seconds
                while time.monotonic() < t_end:
                    pub.publish(msg)
                    g.spin_for(0.1)  # (10 Hz, as teleop sends)

            send(twist(0.05, yaw=0.3), 1.5)
            assert demands and demands[-1][1] > 0, (demands[-3:], states[-3:])
            asked = demands[-1][1]
            # the class of command that is no command: each field non-finite or absurd, each refused
            for bad in (
                twist(math.nan),
                twist(math.inf),
                twist(1e308),
                twist(-1e3),
                twist(0.05, yaw=math.nan),
            ):
                send(bad, 0.1)
                send(twist(0.05), 0.2)  # (the stack's next good one keeps it swimming)
            assert demands[-1][1] == pytest.approx(asked, rel=0.05), demands[-3:]
            last = time.monotonic()
            g.spin_until(lambda: demands[-1][1] == 0.0, timeout=10.0, what="the stop after cmd_vel's silence")
            stopped = next(t for t, d in demands if t > last and d == 0.0) - last
            assert 0.4 <= stopped <= 0.5 + 0.5, stopped  # (the timeout, then a tick and the DDS hop)
            g.spin_until(lambda: states and "no set-point" in states[-1], timeout=5.0, what="the status")
    finally:
        out = stop(proc)[0] + log.read_text()
    assert "this fish does not turn yet" in out and out.count("does not turn yet") == 1, out[-3000:]
    assert "no cmd_vel for" in out and "set-point 0" in out, out[-3000:]
    # (refusals are said at most once a second per topic, with their count and the latest reason)
    assert "message(s) on /cv/cmd_vel; the latest:" in out and "Traceback" not in out, out[-3000:]


@pytest.mark.slow
def test_odometry_is_dead_reckoned_from_the_speed_sensor_with_its_covariance() -> None:
    """``odom`` (nav_msgs/Odometry) as a fish stack reads it: the distance the speed readings give
    (their trapezoid), the speed as twist, ``odom`` to ``base_link``, stamps that advance, and the
    covariance of the sensor's noise and bias (control/odometry.py), the unobserved axes unknown."""
    from nav_msgs.msg import Odometry

    from piezofin_ros.control.odometry import UNKNOWN

    proc = start("speed_loop", "-r", "__ns:=/odo", "-p", "rate_hz:=20.0", "-p", "speed_bias_m_s:=0.002")
    odoms: list[Odometry] = []
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("sensor", namespace="odo", context=g.context))
            speed = node.create_publisher(data_type("swim_speed"), "swim_speed", QOS_DATA)
            node.create_subscription(Odometry, "odom", odoms.append, QOS_COMMAND)
            g.spin_until(lambda: speed.get_subscription_count() > 0 and odoms, timeout=60.0, what="match")
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:
                speed.publish(speed_msg(data_type("swim_speed"), 0.05, 0.0))
                g.spin_for(0.05)
            swum = time.monotonic() - t0
            g.spin_for(0.3)
    finally:
        stop(proc)
    last = odoms[-1]
    assert last.header.frame_id == "odom" and last.child_frame_id == "base_link"
    assert last.pose.pose.orientation.w == 1.0 and last.twist.twist.linear.x == pytest.approx(0.05)
    x = last.pose.pose.position.x
    assert x == pytest.approx(0.05 * swum, rel=0.1), (x, swum)  # (the first reading starts it: ~50 ms)
    stamps = [o.header.stamp.sec + o.header.stamp.nanosec * 1e-9 for o in odoms]
    assert all(b >= a for a, b in itertools.pairwise(stamps)) and stamps[-1] > stamps[0]
    pose = list(last.pose.covariance)
    assert pose[0] == pytest.approx(0.002**2 * 0.05 * (x / 0.05) + (0.002 * x / 0.05) ** 2, rel=0.3)
    assert all(pose[k] == UNKNOWN for k in (7, 14, 21, 28, 35))
    assert last.twist.covariance[0] == pytest.approx(0.002**2)
