"""Messages and recordings, free of ROS: the self-describing block layout of every topic
(:mod:`.blocks`) and MCAP files as rosbag2 writes and reads them: :mod:`.writer` (the ``ros2``
profile, zstd chunks flushed every ``flush_s``, statistics), :mod:`.reader` (every intact message,
damage reported and skipped, bounded memory), :mod:`.recovery` (a killed writer's file made
whole), :mod:`.metadata` (offered QoS and the rosbag2 metadata record) and :mod:`.types` (the Jazzy
type store and CDR).  Readable without a ROS installation; the public names are importable from
here (``from piezofin_ros.bags import BagWriter, read_messages``).
"""

from ..errors import BagError
from .metadata import ROS_DISTRO, ROSBAG2_VERSION, qos_profile, qos_yaml, rosbag2_metadata
from .reader import MCAP_MAGIC, BagMessage, Damage, bag_topics, read_messages
from .recovery import Recovery, recover
from .types import MessageError, block_of, decode, message_definition, normalise_type, typestore
from .writer import BagConfigError, BagWriter

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
    "rosbag2_metadata",
    "typestore",
]
