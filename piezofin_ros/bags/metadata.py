"""What rosbag2 needs besides the messages: offered QoS profiles and the ``rosbag2`` metadata record
(version 9, ``ros_distro: jazzy``), as rosbag2_storage_mcap reads them."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import yaml

#: The rosbag2 metadata version of ROS 2 Jazzy (QoS policies as strings).
ROSBAG2_VERSION = 9
ROS_DISTRO = "jazzy"
#: RMW_DURATION_INFINITE as rosbag2 writes it.
INFINITE_DURATION = {"sec": 9223372036, "nsec": 854775807}


def _duration(ns: int | None) -> dict[str, int]:
    if ns is None or ns >= 9223372036854775807 or ns < 0:
        return dict(INFINITE_DURATION)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_profile(
    *,
    reliability: str = "reliable",
    durability: str = "volatile",
    history: str = "keep_last",
    depth: int = 10,
    deadline_ns: int | None = None,
    lifespan_ns: int | None = None,
    liveliness: str = "automatic",
    liveliness_lease_duration_ns: int | None = None,
    avoid_ros_namespace_conventions: bool = False,
) -> dict[str, Any]:
    """One offered QoS profile as rosbag2 (metadata version 9) stores it; ``None`` durations are
    infinite.  Policy names are those of ``rmw_qos_*_policy_to_str`` (``reliable``, ``best_effort``,
    ``volatile``, ``transient_local``, ``keep_last``, ``keep_all``, ``automatic``, ...)."""
    return {
        "history": history,
        "depth": int(depth),
        "reliability": reliability,
        "durability": durability,
        "deadline": _duration(deadline_ns),
        "lifespan": _duration(lifespan_ns),
        "liveliness": liveliness,
        "liveliness_lease_duration": _duration(liveliness_lease_duration_ns),
        "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions),
    }


def qos_yaml(profiles: Iterable[dict[str, Any]]) -> str:
    """A channel's ``offered_qos_profiles`` string (a YAML list of :func:`qos_profile` dicts)."""

    items = list(profiles)
    return yaml.safe_dump(items, sort_keys=False) if items else ""


def rosbag2_metadata(
    file_name: str,
    topics: dict[str, tuple[str, str, int]],
    start_ns: int,
    end_ns: int,
    custom: dict[str, str] | None = None,
) -> str:
    """The ``serialized_metadata`` YAML of rosbag2's ``BagMetadata`` (version 9, every field its
    decoder requires); ``topics`` maps name -> (type, offered QoS YAML, message count)."""

    count = sum(n for _, _, n in topics.values())
    duration = {"nanoseconds": max(0, end_ns - start_ns)}
    start = {"nanoseconds_since_epoch": start_ns}
    doc = {
        "version": ROSBAG2_VERSION,
        "storage_identifier": "mcap",
        "duration": duration,
        "starting_time": start,
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": name,
                    "type": type_name,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": yaml.safe_load(qos) or [],
                    "type_description_hash": "",
                },
                "message_count": n,
            }
            for name, (type_name, qos, n) in topics.items()
        ],
        "compression_format": "",
        "compression_mode": "",
        "relative_file_paths": [file_name],
        "files": [{"path": file_name, "starting_time": start, "duration": duration, "message_count": count}],
        "custom_data": {str(k): str(v) for k, v in (custom or {}).items()},
        "ros_distro": ROS_DISTRO,
    }
    return yaml.safe_dump(doc, sort_keys=False)
