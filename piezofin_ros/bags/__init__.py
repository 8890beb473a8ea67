"""Messages and recordings, free of ROS: the self-describing block layout of every topic
(:mod:`.blocks`) and MCAP files as rosbag2 writes and reads them: :mod:`.writer` (the ``ros2``
profile, zstd chunks flushed every ``flush_s``, statistics), :mod:`.reader` (every intact message,
damage reported and skipped, bounded memory), :mod:`.recovery` (a killed writer's file made
whole), :mod:`.metadata` (offered QoS and the rosbag2 metadata record) and :mod:`.types` (the Jazzy
type store and CDR).  Readable without a ROS installation; the public names are importable from
here (``from piezofin_ros.bags import BagWriter, read_messages``).
"""

from importlib import import_module
from typing import TYPE_CHECKING, Any

# The public names, and the submodule each lives in.  They are imported when first used (PEP 562),
# so a node that needs only the block layout (``from ..bags.blocks import Block``) does not load the
# MCAP writer, zstd and the type store: ``thrust_estimator`` and ``controller`` run on a fish.
_WHERE = {
    "BagError": "..errors",
    "ROS_DISTRO": ".metadata",
    "ROSBAG2_VERSION": ".metadata",
    "qos_profile": ".metadata",
    "qos_yaml": ".metadata",
    "rosbag2_metadata": ".metadata",
    "MCAP_MAGIC": ".reader",
    "BagMessage": ".reader",
    "Damage": ".reader",
    "bag_topics": ".reader",
    "read_messages": ".reader",
    "resolve_bag": ".reader",
    "Recovery": ".recovery",
    "recover": ".recovery",
    "MessageError": ".types",
    "block_of": ".types",
    "decode": ".types",
    "message_definition": ".types",
    "normalise_type": ".types",
    "typestore": ".types",
    "BagConfigError": ".writer",
    "BagWriter": ".writer",
}

if TYPE_CHECKING:
    from ..errors import BagError
    from .metadata import ROS_DISTRO, ROSBAG2_VERSION, qos_profile, qos_yaml, rosbag2_metadata
    from .reader import MCAP_MAGIC, BagMessage, Damage, bag_topics, read_messages, resolve_bag
    from .recovery import Recovery, recover
    from .types import MessageError, block_of, decode, message_definition, normalise_type, typestore
    from .writer import BagConfigError, BagWriter


def __getattr__(name: str) -> Any:
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(where, __name__), name)
    globals()[name] = value
    return value


__all__ = [
    "MCAP_MAGIC",
    "ROSBAG2_VERSION",
    "ROS_DISTRO",
    "BagConfigError",
    "BagError",
    "BagMessage",
    "BagWriter",
    "Damage",
    "MessageError",
    "Recovery",
    "bag_topics",
    "block_of",
    "decode",
    "message_definition",
    "normalise_type",
    "qos_profile",
    "qos_yaml",
    "read_messages",
    "recover",
    "resolve_bag",
    "rosbag2_metadata",
    "typestore",
]
