"""Worked example: a node added in one place (its settings, a ``Node``, a ``main``), and what
follows by itself from ``nodes/_common.py``: its parameters declared with their ranges, a mistyped or
out-of-range one refused in one line, every message from another process checked at one door, and
Ctrl-C ending it cleanly.  The other recipes (an amplifier kind, an objective, a drag law) are
``test/test_extending.py``."""

from __future__ import annotations

import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Float64

from piezofin_ros.bags.topics import TOPIC_SPEED
from piezofin_ros.config import setting
from piezofin_ros.nodes._common import QOS, Inbox, declare, endpoint, run_node, speed_msg, speed_reading

from ..rosutil import clean_env, graph, stop

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------------------ a node
@dataclass(frozen=True)
class OdometerConfig:
    """A node's parameters, declared once: :func:`~piezofin_ros.nodes._common.declare` makes each field
    a ROS parameter with its default, range and description."""

    rate_hz: float = setting(2.0, "how often the distance swum is published, Hz", 0.1, 50.0)


class Odometer(Node):
    """A node the package does not have: the distance swum, integrated from the speed sensor
    (``swim_speed``), published on ``distance_m`` (a package node would declare that topic in
    ``bags/topics.py``'s ``TOPICS``, as ``swim_speed`` is)."""

    def __init__(self, *, context: Any = None) -> None:
        super().__init__("odometer", context=context)
        self.config = declare(self, OdometerConfig)
        self.distance_m = 0.0
        self._last: tuple[float, float] | None = None  # (s of wall time, m/s)
        self.inbox = Inbox(self)  # every message from another process through one door, checked there
        self.inbox.latest(endpoint(TOPIC_SPEED)[0], TOPIC_SPEED, self._on_speed, speed_reading)
        self._pub = self.create_publisher(Float64, "distance_m", 10)
        self.create_timer(1.0 / self.config.rate_hz, lambda: self._pub.publish(Float64(data=self.distance_m)))

    def _on_speed(self, reading: tuple[float, float]) -> None:
        now, (_, speed) = time.monotonic(), reading
        if self._last is not None:
            self.distance_m += self._last[1] * (now - self._last[0])
        self._last = (now, speed)


def odometer_main() -> int:
    """What a row of ``nodes/entry.py``'s ``EXECUTABLES`` names: ``ros2 run piezofin_ros <name>``."""
    return run_node(lambda ctx: Odometer(context=ctx))


@pytest.mark.ros
@pytest.mark.slow
def test_a_node_is_its_settings_and_a_main_that_run_node_runs() -> None:
    """The recipe: a settings dataclass, a ``Node`` that declares it and reads other processes
    through its ``Inbox``, and a ``main`` that hands it to ``run_node`` (with a row in
    ``EXECUTABLES`` for its console script).  By itself, in its own process as ``ros2 run`` starts
    it: a parameter out of its range or mistyped ends it with one line and exit 2; a hostile speed
    is refused at the door, said, and the node lives; its timer publishes what it integrated; Ctrl-C
    ends it with exit 0 and no traceback."""

    def odometer(*ros_args: str) -> subprocess.Popen[str]:
        code = "import sys; from test.nodes.test_extending_a_node import odometer_main as m; sys.exit(m())"
        return subprocess.Popen(
            [sys.executable, "-c", code, "--ros-args", "-r", "__ns:=/worked", *ros_args],
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=clean_env(),
        )

    for bad, said in (("rate_hz:=500.0", "rate_hz"), ("rate_hzz:=5.0", "rate_hzz")):
        proc = odometer("-p", bad)
        out, _ = proc.communicate(timeout=60)
        assert proc.returncode == 2 and said in out and "Traceback" not in out, out
    proc = odometer("-p", "rate_hz:=10.0")
    distances: list[float] = []
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("sensor", namespace="worked", context=g.context))
            msg_type, topic, _ = endpoint(TOPIC_SPEED)
            pub = node.create_publisher(msg_type, topic, QOS["sensor"])
            node.create_subscription(Float64, "distance_m", lambda m: distances.append(m.data), 10)
            g.spin_until(lambda: pub.get_subscription_count() > 0 and distances, 60.0, "the odometer")
            pub.publish(speed_msg(msg_type, 1e308, 0.0))  # hostile: refused at the door
            g.spin_for(0.3)  # (the newest only is read: the next one would take its place)
            t0 = time.monotonic()
            while time.monotonic() - t0 < 2.0:
                pub.publish(speed_msg(msg_type, 0.1, 0.0))
                g.spin_for(0.05)
            g.spin_for(0.3)
            alive = proc.poll() is None
    finally:
        out = stop(proc)[0]
    assert alive and proc.returncode == 0 and "Traceback" not in out, out
    assert "refused 1 message(s)" in out, out
    assert distances[-1] == pytest.approx(0.2, rel=0.15)  # 0.1 m/s for 2 s
