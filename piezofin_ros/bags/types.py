"""ROS 2 message types without ROS: the Jazzy type store (``rosbags``) with the project's own messages,
message definitions as rosbag2 stores them, and CDR decoding (:func:`decode`, :func:`block_of`)
independent of rclpy."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ..errors import BagError
from .blocks import Block, from_layout, message_block

_TYPESTORE: Any = None

#: The project's own messages: ``piezofin_msgs/msg/<Name>`` is defined by ``piezofin_ros/msg/<Name>.msg``
#: (rosidl builds the same files into ROS: ``interfaces/piezofin_msgs``), read here without ROS.
OWN_PACKAGE = "piezofin_msgs"
MSG_DIR = Path(__file__).resolve().parents[1] / "msg"


def own_definitions() -> dict[str, str]:
    """``{"piezofin_msgs/msg/<Name>": its .msg text}`` of every message of the project's own."""
    return {f"{OWN_PACKAGE}/msg/{p.stem}": p.read_text() for p in sorted(MSG_DIR.glob("*.msg"))}


def typestore() -> Any:
    """The ``rosbags`` type store of ROS 2 Jazzy with the project's own messages (built once; ~50 ms)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        store = get_typestore(Stores.ROS2_JAZZY)
        for name, text in own_definitions().items():
            store.register(get_types_from_msg(text, name))
        _TYPESTORE = store
    return _TYPESTORE


def is_record_type(type_name: str) -> bool:
    """Whether ``type_name`` is one of the project's own named, stamped messages (a header and a field
    per channel: ``float64`` values, or ``float64[]`` samples), which :func:`block_of` reads as a block."""
    return normalise_type(type_name).startswith(f"{OWN_PACKAGE}/")


def normalise_type(name: str) -> str:
    """``std_msgs/Float64`` or ``std_msgs/msg/Float64`` -> ``std_msgs/msg/Float64``."""
    parts = name.strip().split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise MessageError(f"not a ROS message type name: {name!r}")
    return "/".join(parts)


def message_definition(type_name: str) -> str:
    """The concatenated ``ros2msg`` definition text of a message type (as rosbag2 stores it)."""
    store = typestore()
    type_name = normalise_type(type_name)
    if type_name not in store.fielddefs:
        raise MessageError(f"unknown message type {type_name!r} (not in the ROS 2 Jazzy type store)")
    text, _ = store.generate_msgdef(type_name, ros_version=2)
    return str(text)


class MessageError(BagError, ValueError):
    """A message's bytes are not a valid CDR message of its type (the readers skip and count it)."""


def decode(type_name: str, data: bytes) -> Any:
    """Deserialise CDR bytes with the ``rosbags`` type store (independent of rclpy)."""
    try:
        return typestore().deserialize_cdr(data, normalise_type(type_name))
    except SerdeError as exc:
        raise MessageError(f"not a valid {type_name} message ({exc})") from None


def block_of(
    type_name: str, data: bytes, expect: tuple[str, ...] | None = None, optional: tuple[str, ...] = ()
) -> Block:
    """Decode a ``Float64MultiArray`` message, or one of the project's own named messages (one sample
    of each named field), into a :class:`~piezofin_ros.bags.blocks.Block`."""
    msg = decode(type_name, data)
    if is_record_type(type_name):
        return message_block(msg, expect)
    dims = [(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim]
    return from_layout(
        dims, msg.data, expect=expect, data_offset=int(msg.layout.data_offset), optional=optional
    )
