"""``waypoints``: a course of points swum by line-of-sight guidance (the fish stack's example).

Subscribes ``odom`` (nav_msgs/Odometry: where the fish is, the speed loop's dead reckoning) and
publishes ``cmd_vel`` (geometry_msgs/Twist: ``speed_m_s`` forward, the yaw rate line-of-sight
guidance asks, :class:`~piezofin_ros.control.guidance.LineOfSight`) at ``rate_hz`` on the node's clock,
what it is doing on ``waypoints/status`` (std_msgs/String, JSON: the leg, along and across it, off the
course, the distance to go, done) and the course and the fish as ``visualization_msgs/MarkerArray`` on
``waypoints/markers`` for RViz and Foxglove (in ``frame_id``, ``odom``).  The course is the parameter
``waypoints``: ``[x0, y0, x1, y1, ...]`` in metres, or a ``nav_msgs/Path`` on ``waypoints/path`` (a
fish stack's planner, or ``ros2 topic pub --once``), which replaces the course being swum from its
first point (the same course sent again keeps its progress); a path in another frame, with a pose
that is not finite, fewer than two points or more than :data:`MOST_POINTS` is refused at the door,
naming why, and the course goes on.  With neither
it waits, silent.  Once the last point is reached it asks the fish to stop (one ``cmd_vel`` of zero)
and falls silent; a fish stack's ``cmd_vel`` timeout stops it as well if this node ends.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import Point, Twist
from nav_msgs.msg import Odometry, Path
from rclpy.context import Context
from rclpy.node import Node
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from ..config import setting
from ..control.guidance import LineOfSight
from ..errors import PiezofinError
from ._common import (
    TOPIC_CMD_VEL,
    TOPIC_ODOM,
    TOPIC_WAYPOINT_MARKERS,
    TOPIC_WAYPOINT_PATH,
    TOPIC_WAYPOINT_STATUS,
    Inbox,
    MessageRefused,
    StartupError,
    declare,
    endpoint,
    heading_of,
    run_node,
)
from ._diagnostics import OK, STALE, Diagnostics, Report


@dataclass(frozen=True)
class WaypointsConfig:
    """``waypoints``'s parameters (guidance's defaults are its own: :class:`LineOfSight`'s)."""

    waypoints: tuple[float, ...] = setting(
        (),
        "the course: x0, y0, x1, y1, ... in metres in the odom frame (at least two points; none: the "
        "first nav_msgs/Path on waypoints/path)",
        items=float,
    )
    speed_m_s: float = setting(0.05, "the speed asked on the course, m/s", 0.0, 10.0)
    lookahead_m: float = setting(
        LineOfSight.lookahead_m,
        "line of sight: the point steered for, this far ahead on the leg, m (about the tightest turn "
        "asked: shorter, slow fish overshot each corner)",
        0.01,
        1e4,
    )
    acceptance_m: float = setting(
        LineOfSight.acceptance_m,
        "a waypoint is reached within this distance, or within the radius of its turn if larger, m",
        0.01,
        1e4,
    )
    gain_per_s: float = setting(
        LineOfSight.gain_per_s, "the yaw rate asked per radian of heading error, 1/s (at least)", 1e-4, 100.0
    )
    port_radius_m: float = setting(
        LineOfSight.port_radius_m,
        "the tightest turn to port asked, m (the paper's twin turns on 1.8 m at its offset's edge)",
        0.01,
        1e4,
    )
    starboard_radius_m: float = setting(
        LineOfSight.starboard_radius_m,
        "the tightest turn to starboard asked, m (the P1 window leaves the offset little room: the "
        "fish gives up voltage for it, voltage_cap, down to a 6.4 m circle on the paper's twin)",
        0.01,
        1e4,
    )
    heading_distance_m: float = setting(
        LineOfSight.heading_distance_m,
        "a faster fish turns its heading error away within this distance swum: the gain is at least "
        "the speed over it, m",
        0.01,
        1e4,
    )
    turn_lead: float = setting(
        LineOfSight.turn_lead,
        "each turn begins earlier by this share of the distance the fish swims in 1 / the gain (its "
        "heading's lag)",
        0.0,
        10.0,
    )
    rate_hz: float = setting(10.0, "how often cmd_vel is sent, Hz (node clock)", 0.5, 100.0)
    frame_id: str = setting("odom", "the frame of the course and the markers")


#: The most points a course may have (a path of more is refused): a planner's path is tens to
#: thousands of poses; each tick measures the fish against every leg
MOST_POINTS = 10_000


def points_of_path(msg: Any, frame_id: str) -> list[tuple[float, float]]:
    """The door's check of a ``nav_msgs/Path``: its poses' (x, y), in ``frame_id`` (a path stamped in
    no frame is taken as in it), 2 to :data:`MOST_POINTS` of them, each finite; consecutive repeats
    (a planner's path may hold the same pose twice) are dropped."""
    frames = [str(msg.header.frame_id), *(str(p.header.frame_id) for p in msg.poses)]
    other = next((f for f in frames if f not in ("", frame_id)), None)
    if other is not None:
        raise MessageRefused(f"a path in frame {other!r}: the course is in {frame_id!r} (no transforms here)")
    if not 2 <= len(msg.poses) <= MOST_POINTS:
        raise MessageRefused(f"a path of {len(msg.poses)} poses: a course is 2 to {MOST_POINTS} points")
    points: list[tuple[float, float]] = []
    for k, pose in enumerate(msg.poses):
        x, y = float(pose.pose.position.x), float(pose.pose.position.y)
        if not (math.isfinite(x) and math.isfinite(y)):
            raise MessageRefused(f"a path whose pose {k} is at ({x!r}, {y!r}): no point")
        if not points or (x, y) != points[-1]:
            points.append((x, y))
    return points


def pose_of(msg: Any) -> tuple[float, float, float, float]:
    """The door's check of an ``odom``: (x, y, heading, speed) in metres, radians and m/s, each
    finite."""
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    heading = heading_of(q)
    pose = (float(p.x), float(p.y), heading, float(msg.twist.twist.linear.x))
    if not all(math.isfinite(v) and abs(v) < 1e7 for v in pose):
        raise MessageRefused(f"a pose of {pose!r} is no fish's (x, y within 1e7 m, a finite heading)")
    return pose


class WaypointsNode(Node):
    """Line-of-sight guidance on the live topics."""

    def __init__(self, *, context: Context | None = None, node_name: str = "waypoints", **kwargs: object):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        c = declare(self, WaypointsConfig)
        self.config = c
        flat = c.waypoints
        if len(flat) % 2:
            raise StartupError(
                f"parameter waypoints: {len(flat)} numbers: x and y of each point (an even count)"
            )
        self.course: LineOfSight | None = None
        if flat:
            try:
                self.course = self._course([(flat[k], flat[k + 1]) for k in range(0, len(flat), 2)])
            except PiezofinError as exc:
                raise StartupError(f"parameter {exc}") from None
        self.pose: tuple[float, float, float, float] | None = None  # (x, y, heading, speed)
        self.off_course_m: list[float] = []
        self._cmd = self.create_publisher(*endpoint(TOPIC_CMD_VEL))
        self._status = self.create_publisher(*endpoint(TOPIC_WAYPOINT_STATUS))
        self._markers = self.create_publisher(*endpoint(TOPIC_WAYPOINT_MARKERS))
        self.inbox = Inbox(self, node_time_s=Inbox.NODE_TIME_S)
        self.inbox.latest(Odometry, TOPIC_ODOM, self._on_odom, pose_of)
        self.inbox.latest(Path, TOPIC_WAYPOINT_PATH, self._on_path, self._path_course)
        self._stopped = False
        self._ticks = 0
        self.create_timer(1.0 / c.rate_hz, self._tick)
        self.diagnostics = Diagnostics(self, "the course")
        self.diagnostics.add("course", self._diagnose)
        if self.course is not None:
            self._say_course("")
        else:
            self.get_logger().info(
                f"no waypoints: waiting for a nav_msgs/Path on {self.resolve_topic_name(TOPIC_WAYPOINT_PATH)}"
            )

    def _course(self, points: list[tuple[float, float]]) -> LineOfSight:
        c = self.config
        return LineOfSight(
            points,
            c.lookahead_m,
            c.acceptance_m,
            c.gain_per_s,
            c.port_radius_m,
            c.starboard_radius_m,
            c.heading_distance_m,
            c.turn_lead,
        )

    def _path_course(self, msg: Any) -> LineOfSight:
        """The door's check of a path: the course it gives (refused, naming why, if none)."""
        try:
            return self._course(points_of_path(msg, self.config.frame_id))
        except PiezofinError as exc:
            raise MessageRefused(f"a path that is no course: {exc}") from None

    def _say_course(self, source: str) -> None:
        assert self.course is not None
        self.get_logger().info(
            f"a course of {len(self.course.waypoints)} points{source}, {self.course.length_m:.3g} m, at "
            f"{self.config.speed_m_s:g} m/s: cmd_vel on {self.resolve_topic_name(TOPIC_CMD_VEL)}"
        )

    def _on_odom(self, pose: tuple[float, float, float, float]) -> None:
        self.pose = pose

    def _on_path(self, course: LineOfSight) -> None:
        """A new course replaces the one being swum, from its first leg (a course done is swum again);
        the course being swum, sent again (a planner publishes its plan again and again), changes
        nothing: from its first leg, a fish on a square's third leg had turned back to the first."""
        if self.course is not None and list(course.waypoints) == list(self.course.waypoints):
            return
        self.course, self._stopped, self.off_course_m = course, False, []
        self._say_course(f" from {self.resolve_topic_name(TOPIC_WAYPOINT_PATH)}")

    def _diagnose(self) -> Report:
        if self.course is None:
            return Report(STALE, "no course yet: waiting for waypoints or a path", {})
        if self.pose is None:
            return Report(STALE, "no odom yet: nothing asked", {})
        leg = self.course.where(*self.pose[:2])
        said = "course done" if self.course.done else f"leg {leg.index}, {leg.to_go_m:.3g} m to go"
        return Report(OK, said, {"leg": leg.index, "to_go_m": leg.to_go_m, "across_m": leg.across_m})

    def _tick(self) -> None:
        if self.pose is None or self._stopped or self.course is None:
            return
        x, y, heading, speed = self.pose
        rate, leg = self.course.update(x, y, heading, speed)
        off = self.course.off_course_m(x, y)
        self.off_course_m.append(off)
        twist = Twist()
        if self.course.done:
            self._stopped = True  # (one zero, then silence: the speed loop's timeout holds the stop)
            self.get_logger().info(
                f"course done: {self.course.length_m:.3g} m, {rms(self.off_course_m):.3g} m RMS off it"
            )
        else:
            twist.linear.x, twist.angular.z = self.config.speed_m_s, rate
        self._cmd.publish(twist)
        status = {
            "leg": leg.index,
            "legs": len(self.course.waypoints) - 1,
            "along_m": leg.along_m,
            "across_m": leg.across_m,
            "off_course_m": off,
            "off_course_rms_m": rms(self.off_course_m),
            "to_go_m": leg.to_go_m,
            "progress": 1.0 - leg.to_go_m / self.course.length_m,
            "yaw_rate_rad_s": rate,
            "done": self.course.done,
        }
        self._status.publish(String(data=json.dumps(status)))
        if self._ticks % max(round(self.config.rate_hz), 1) == 0 or self.course.done:
            self._markers.publish(self._marker_array())
        self._ticks += 1
        self.diagnostics.update()

    def _marker_array(self) -> MarkerArray:
        """The course (a line through its points), its points (spheres) and the fish (an arrow)."""
        assert self.course is not None
        stamp = self.get_clock().now().to_msg()
        out = MarkerArray()
        for k, kind in enumerate((Marker.LINE_STRIP, Marker.SPHERE_LIST, Marker.ARROW)):
            m = Marker()
            m.header.frame_id, m.header.stamp = self.config.frame_id, stamp
            m.ns, m.id, m.type, m.action = "course", k, kind, Marker.ADD
            m.pose.orientation.w = 1.0
            m.color.a = 1.0
            if kind == Marker.ARROW:
                assert self.pose is not None
                x, y, heading, _ = self.pose
                m.ns = "fish"
                m.pose.position.x, m.pose.position.y = x, y
                m.pose.orientation.z, m.pose.orientation.w = math.sin(0.5 * heading), math.cos(0.5 * heading)
                m.scale.x, m.scale.y, m.scale.z = 0.25, 0.06, 0.1  # (mfc-fish: 25 cm long)
                m.color.r = 1.0
            else:
                m.points = [Point(x=float(px), y=float(py)) for px, py in self.course.waypoints]
                m.scale.x = 0.05 if kind == Marker.LINE_STRIP else 0.3
                m.scale.y = m.scale.z = 0.3
                m.color.b = 1.0 if kind == Marker.LINE_STRIP else 0.0
                m.color.g = 0.0 if kind == Marker.LINE_STRIP else 1.0
            out.markers.append(m)
        return out

    def destroy_node(self) -> None:
        self.inbox.close()
        super().destroy_node()


def rms(values: list[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values)) if values else math.nan


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: WaypointsNode(context=ctx), args)


if __name__ == "__main__":
    sys.exit(main())
