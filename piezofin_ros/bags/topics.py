"""The topics of one fin, relative to its namespace: the nodes' contract (docs/reference.md).

Light on purpose (no MCAP, no type store, no ROS): the nodes import the names from here, the bags'
reader (:mod:`.fin`) reads by them.  :data:`TOPICS` declares each topic once (its type, the QoS
profile's name, who publishes it, whether the recorder records it): the nodes create their
publishers from it (``nodes._common.endpoint``), the recorder takes its list from it, and a test
checks the docs' table against it.
"""

from __future__ import annotations

from dataclasses import dataclass

from .blocks import DRIVE_CHANNELS, LOADCELL_CHANNELS, SUPPLY_CHANNELS, TIP_CHANNELS

TOPIC_DRIVE = "drive"
TOPIC_TIP = "tip_velocity"
TOPIC_LOADCELL = "loadcell"
TOPIC_SUPPLY = "supply"
TOPIC_CMD = "cmd"
TOPIC_ESTIMATE = "estimate"
TOPIC_SPEED = "swim_speed"
TOPIC_STATUS = "controller/status"
TOPIC_DEMAND = "thrust_demand"
#: std_msgs/String (JSON): the controller's fitted fin, once its corrected model fits its trials
TOPIC_MODEL = "controller/model"
TOPIC_BATTERY = "battery"  # sensor_msgs/BatteryState: a fish's battery
TOPIC_LOOP_STATUS = "speed_loop/status"  # std_msgs/String: what the speed loop is doing
#: std_msgs/String (JSON): what the estimator hears, and where it measures the supply watt
TOPIC_ESTIMATOR_STATUS = "thrust_estimator/status"
TOPIC_CMD_VEL = "cmd_vel"  # geometry_msgs/Twist (or TwistStamped): a fish stack's velocity command
TOPIC_ODOM = "odom"  # nav_msgs/Odometry: the speed loop's dead reckoning
TOPIC_IMU = "imu"  # sensor_msgs/Imu: a fish's yaw rate and heading
TOPIC_BIAS = "bias_demand"  # std_msgs/Float64: the drive's offset the yaw loop asks, V
#: std_msgs/Float64: the most peak-to-peak voltage the drive may have so that the offset the yaw loop
#: wants fits in the MFC's window with the sine (control/yawloop.py's OffsetRoom), Vpp
TOPIC_VOLTAGE_CAP = "voltage_cap"
TOPIC_WAYPOINT_STATUS = "waypoints/status"  # std_msgs/String: the course's progress (JSON)
TOPIC_WAYPOINT_MARKERS = "waypoints/markers"  # visualization_msgs/MarkerArray: the course and the fish
TOPIC_WAYPOINT_PATH = "waypoints/path"  # nav_msgs/Path: a course from a fish stack's planner
TOPIC_CLOCK = "/clock"
TOPIC_DIAGNOSTICS = "/diagnostics"

F64A = "std_msgs/msg/Float64MultiArray"
F64 = "std_msgs/msg/Float64"
#: A speed sensor's reading: ``twist.linear.x`` (m/s, forward), stamped when measured; bags before it
#: hold it as a ``std_msgs/Float64``
SPEED = "geometry_msgs/msg/TwistStamped"
STRING = "std_msgs/msg/String"
#: The project's own messages, named and stamped (piezofin_ros/msg/): bags before them hold F64A blocks
ESTIMATE = "piezofin_msgs/msg/Estimate"
DRIVE = "piezofin_msgs/msg/Drive"
TIP = "piezofin_msgs/msg/TipVelocity"
LOADCELL = "piezofin_msgs/msg/Loadcell"
SUPPLY = "piezofin_msgs/msg/Supply"


@dataclass(frozen=True)
class Topic:
    """A topic of the suite: its name (relative to a fin's namespace, or absolute), its ROS type, the
    name of its QoS profile (``nodes._common.QOS``), who publishes it, and whether the recorder
    records it with the suite."""

    name: str
    type: str
    qos: str
    publisher: str
    recorded: bool = True


#: Every topic of the suite, declared once.
TOPICS: dict[str, Topic] = {
    t.name: t
    for t in (
        Topic(TOPIC_DRIVE, DRIVE, "data", "fin_sim, or a rig or fish driver"),
        Topic(TOPIC_TIP, TIP, "data", "fin_sim, or a rig driver with a vibrometer"),
        Topic(TOPIC_LOADCELL, LOADCELL, "data", "fin_sim, or a rig driver with a load cell"),
        Topic(TOPIC_SUPPLY, SUPPLY, "data", "fin_sim, or a driver with a supply meter"),
        Topic(TOPIC_CMD, F64A, "command", "controller"),
        Topic(TOPIC_ESTIMATE, ESTIMATE, "estimate", "thrust_estimator"),
        Topic(TOPIC_ESTIMATOR_STATUS, STRING, "status", "thrust_estimator"),
        Topic(TOPIC_SPEED, SPEED, "sensor", "fin_sim with a body, or a fish driver"),
        Topic(TOPIC_STATUS, STRING, "status", "controller"),
        Topic(TOPIC_MODEL, STRING, "status", "controller (optimising)"),
        Topic(TOPIC_DEMAND, F64, "command", "speed_loop, or a fish stack"),
        Topic(TOPIC_BIAS, F64, "command", "speed_loop (its yaw loop), or a fish stack"),
        Topic(TOPIC_VOLTAGE_CAP, F64, "command", "speed_loop (its yaw loop), or a fish stack"),
        Topic(
            TOPIC_BATTERY,
            "sensor_msgs/msg/BatteryState",
            "sensor",
            "fin_sim with a battery, or a fish driver",
        ),
        Topic(TOPIC_IMU, "sensor_msgs/msg/Imu", "sensor", "fin_sim with a body that turns, or a fish driver"),
        Topic(TOPIC_LOOP_STATUS, STRING, "status", "speed_loop"),
        Topic(
            TOPIC_CMD_VEL, "geometry_msgs/msg/Twist", "command", "a fish stack (waypoints)", recorded=False
        ),
        Topic(TOPIC_WAYPOINT_STATUS, STRING, "status", "waypoints"),
        Topic(TOPIC_WAYPOINT_PATH, "nav_msgs/msg/Path", "command", "a fish stack's planner, or a person"),
        Topic(
            TOPIC_WAYPOINT_MARKERS,
            "visualization_msgs/msg/MarkerArray",
            "status",
            "waypoints",
            recorded=False,
        ),
        Topic(TOPIC_ODOM, "nav_msgs/msg/Odometry", "command", "speed_loop", recorded=False),
        Topic(TOPIC_CLOCK, "rosgraph_msgs/msg/Clock", "clock", "fin_sim with publish_clock, player"),
        Topic(
            TOPIC_DIAGNOSTICS,
            "diagnostic_msgs/msg/DiagnosticArray",
            "diagnostics",
            "every node",
            recorded=False,
        ),
    )
}


def table_topic(topic: str) -> Topic | None:
    """The table's entry of a topic name, relative or absolute (``/left/estimate``: ``estimate``)."""
    for name, t in TOPICS.items():
        if topic == name or topic.endswith(f"/{name.lstrip('/')}"):
            return t
    return None


#: The sample channels of each sampled topic, in wire order.
SAMPLED = {
    TOPIC_DRIVE: DRIVE_CHANNELS,
    TOPIC_TIP: TIP_CHANNELS,
    TOPIC_LOADCELL: LOADCELL_CHANNELS,
    TOPIC_SUPPLY: SUPPLY_CHANNELS,
}


def topic_prefix(namespace: str) -> str:
    """``"/fin"`` for ``"fin"``, ``"/fin/"`` or ``"/fin"``; ``""`` for the root namespace."""
    return "/" + namespace.strip("/") if namespace.strip("/") else ""
