"""The fish stack's example (issue 42): ``waypoints`` swims a course through ``cmd_vel`` and ``odom``,
every node in its own process as ``ros2 run`` starts it, and says where it is as ROS tools read it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import rclpy
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from piezofin_ros.nodes._common import QOS_STATUS

from ..rosutil import graph, start, stop

pytestmark = [pytest.mark.ros, pytest.mark.slow]

FISH_YAML = str(Path(__file__).resolve().parents[2] / "config" / "fish.yaml")
#: docs/fish.md's line, word for word (with the fish running): the node is started with its arguments
TYPED = [
    "ros2", "run", "piezofin_ros", "waypoints", "--ros-args", "-r", "__ns:=/fish", "-p", "use_sim_time:=true",
    "-p", "waypoints:=[0.0, 0.0, 12.0, 0.0, 12.0, 12.0]",
]  # fmt: skip


@pytest.mark.exclusive  # (five processes in a closed loop at x10)
def test_the_fish_swims_a_course_of_waypoints_and_says_where_it_is(tmp_path: Path) -> None:
    """docs/fish.md's line: an L of two 12 m legs, a turn to port between them, at 5 cm/s (the
    default).  fin_sim (the twin's fish at x10), the estimator, the optimising controller, the speed
    loop and ``waypoints``, each in its own process.  The course is done, its progress rises to 1 on
    ``waypoints/status``, off the course (as the odometry has it) by about the fish's 25 cm RMS,
    the markers hold the course and the fish, and at the end the fish is asked to stop."""
    ns = "fish"  # (the line as docs/fish.md types it: exclusive, nothing else runs beside it)
    common = ["-r", f"__ns:=/{ns}", "--params-file", FISH_YAML]
    exes = ("fin_sim", "thrust_estimator", "controller", "speed_loop", "waypoints")
    logs = {e: tmp_path / f"{e}.log" for e in exes}
    typed = TYPED
    procs = [
        start("fin_sim", *common, "-p", "realtime_factor:=10.0", "-p", "publish_clock:=true",
              log=logs["fin_sim"]),
        *(start(e, *common, "-p", "use_sim_time:=true", log=logs[e])
          for e in ("thrust_estimator", "controller", "speed_loop")),
        start("waypoints", *typed[5:], "--params-file", FISH_YAML, log=logs["waypoints"]),  # (as typed)
    ]  # fmt: skip
    statuses: list[dict] = []
    markers: list[MarkerArray] = []
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("watcher", namespace=ns, context=g.context))
            node.create_subscription(
                String, "waypoints/status", lambda m: statuses.append(json.loads(m.data)), QOS_STATUS
            )
            node.create_subscription(MarkerArray, "waypoints/markers", markers.append, QOS_STATUS)
            g.spin_until(lambda: bool(statuses) and statuses[-1]["done"], 240.0, "the course done")
            g.spin_for(2.0)
    finally:
        outs = stop(*procs)
    out = "".join(outs) + "".join(p.read_text() for p in logs.values())
    assert "Traceback" not in out, out[-3000:]
    last = statuses[-1]
    assert last["done"] and last["leg"] == 2 and last["progress"] == pytest.approx(1.0, abs=0.15), last
    # (0.19-0.26 m in four runs, about the 25 cm of the fish: the goal is a body length; at the
    # corner a 2.5 m turn cuts 1 m, and the first half-minute the optimiser identifies at low speed)
    assert last["off_course_rms_m"] < 0.35, last
    progress = [s["progress"] for s in statuses]
    assert max(progress[: len(progress) // 2]) < 0.6  # (it rose along the way)
    kinds = {(m.ns, m.id): m for m in markers[-1].markers}
    assert kinds[("course", 0)].type == Marker.LINE_STRIP and len(kinds[("course", 0)].points) == 3
    assert kinds[("course", 1)].type == Marker.SPHERE_LIST and kinds[("fish", 2)].type == Marker.ARROW
    fish = kinds[("fish", 2)].pose.position
    assert math.hypot(fish.x - 12.0, fish.y - 12.0) < 3.0  # (the fish where the course ends)
    said = logs["waypoints"].read_text()
    assert "course done: 24 m" in said and "RMS off it" in said, said[-2000:]
    assert "set-point 0" in logs["speed_loop"].read_text() or "no set-point" in logs["speed_loop"].read_text()
