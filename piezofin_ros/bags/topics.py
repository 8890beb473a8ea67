"""The topics of one fin, relative to its namespace: the nodes' contract (docs/reference.md).

Light on purpose (no MCAP, no type store): the nodes import the names from here, the bags' reader
(:mod:`.fin`) reads by them.
"""

from __future__ import annotations

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
TOPIC_BATTERY = "battery"  # sensor_msgs/BatteryState: a fish's battery
TOPIC_LOOP_STATUS = "speed_loop/status"  # std_msgs/String: what the speed loop is doing

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
