"""Stamped, self-describing sample blocks: the wire format of every piezofin topic.

A block is a small table: named channels (columns) by samples (rows).  On the wire it is a
``std_msgs/Float64MultiArray`` (so every ROS tool, Foxglove and ``rosbags`` can read it
without custom messages)::

    layout.dim[0] = {label: "t_s,voltage_V,current_A", size: n_channels, stride: n_channels * n}
    layout.dim[1] = {label: "sample",                  size: n,          stride: n}
    layout.data_offset = 0
    data = [t_0 .. t_{n-1}, v_0 .. v_{n-1}, i_0 .. i_{n-1}]        (channel-major)

The first label names the channels with their SI unit after the last underscore.  A block of
one sample (commands, estimates) may omit ``dim[1]``.  Sample times are a channel of their own
(``t_s``, seconds of the ROS clock that stamped them), so a block carries its own time base and
a receiver never has to guess a rate or trust an arrival time.

This module has no ROS dependency: nodes convert messages with :func:`from_layout` and
:func:`to_layout`, and offline tools do the same on bags.
"""

from __future__ import annotations

import array
import dataclasses
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import BagError

FloatArray = NDArray[Any]

#: Channels of each high-rate topic, in wire order.
DRIVE_CHANNELS = ("t_s", "voltage_V", "current_A")
TIP_CHANNELS = ("t_s", "tip_velocity_m_s")
LOADCELL_CHANNELS = ("t_s", "displacement_m")
#: The amplifier's supply bus as its meter reads it (optional: a rig or a fish without one still works).
SUPPLY_CHANNELS = ("t_s", "supply_voltage_V", "supply_current_A")
#: Fields of an actuation command, in wire order (also accepted unlabelled in this order).
COMMAND_FIELDS = ("frequency_hz", "voltage_pp_V", "on")
#: A command's optional fields, after those (unlabelled too): the drive's offset, V (0 without it).
COMMAND_OPTIONAL = ("bias_V",)

#: The physical range of each sampled channel: a reading beyond (or infinite) is no reading of this
#: rig or fish, whoever sent it.  Generous: an MFC is rated -500..+1500 V and draws milliamperes; a
#: fin's tip moves centimetres per second; the load cell's beam deflects micrometres; a fin's
#: amplifier runs from a bus under 2 kV drawing under 10 A (a spoofed supply of 1e300 V gave a
#: measured supply power of 3.9e8 W).  ``t_s`` is checked apart (finite, increasing).
CHANNEL_MOST = {
    "voltage_V": 2000.0,
    "current_A": 1.0,
    "tip_velocity_m_s": 100.0,
    "displacement_m": 0.1,
    "supply_voltage_V": 2000.0,
    "supply_current_A": 10.0,
}

#: Hard bound on a block's size, so a malformed message cannot make a receiver allocate gigabytes.
MAX_VALUES = 1_000_000


class BlockFormatError(BagError, ValueError):
    """A message does not follow the block layout; the text says what is wrong."""


@dataclass(frozen=True)
class Block:
    """``values[c, k]`` is sample ``k`` of channel ``names[c]``."""

    names: tuple[str, ...]
    values: FloatArray

    def __post_init__(self) -> None:
        values = np.asarray(self.values, dtype=float)
        if values.ndim == 1:
            values = values.reshape(len(self.names), -1) if self.names else values.reshape(0, 0)
        if values.ndim != 2 or values.shape[0] != len(self.names):
            raise BlockFormatError(f"{len(self.names)} channel names for values of shape {values.shape}")
        if len(set(self.names)) != len(self.names):
            raise BlockFormatError(f"repeated channel name in {self.names}")
        object.__setattr__(self, "values", values)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.values.shape[1])

    def __getitem__(self, name: str) -> FloatArray:
        try:
            return self.values[self.names.index(name)]  # type: ignore[no-any-return]
        except ValueError:
            raise KeyError(f"block has no channel {name!r} (has {', '.join(self.names)})") from None

    def scalar(self, name: str) -> float:
        """The value of a one-sample block's channel."""
        return float(self[name][0])

    def as_dict(self) -> dict[str, float]:
        """A one-sample block as ``{name: value}``."""
        return {name: float(self.values[c, 0]) for c, name in enumerate(self.names)}

    @classmethod
    def from_columns(cls, **columns: ArrayLike) -> Block:
        """``Block.from_columns(t_s=t, voltage_V=v)``: channels in keyword order."""
        arrays = [np.atleast_1d(np.asarray(c, dtype=float)) for c in columns.values()]
        if len({a.shape for a in arrays}) > 1:
            raise BlockFormatError(f"channels differ in length: {[a.shape for a in arrays]}")
        return cls(tuple(columns), np.stack(arrays) if arrays else np.zeros((0, 0)))

    @classmethod
    def from_record(cls, record: dict[str, float]) -> Block:
        """A one-sample block from ``{name: value}`` (for commands and estimates)."""
        return cls(tuple(record), np.asarray([[float(v)] for v in record.values()]).reshape(len(record), 1))


Dim = tuple[str, int, int]  # (label, size, stride), as in std_msgs/MultiArrayDimension


def to_layout(block: Block) -> tuple[list[Dim], FloatArray]:
    """Dimensions and flat data of a ``Float64MultiArray`` holding ``block``."""
    nc, n = block.values.shape
    dims = [(",".join(block.names), nc, nc * n), ("sample", n, n)]
    return dims, np.ascontiguousarray(block.values).ravel()


def from_layout(
    dims: Sequence[Dim],
    data: ArrayLike,
    *,
    expect: Sequence[str] | None = None,
    data_offset: int = 0,
    optional: Sequence[str] = (),
) -> Block:
    """Decode a ``Float64MultiArray`` into a :class:`Block`, checking every size.

    ``expect`` names the channels the receiver needs; they must all be present (others are
    kept).  An unlabelled message (no ``dim``) is accepted only with ``expect``, as one
    sample in that order, which is what a person typing ``ros2 topic pub`` writes, followed by
    as many of ``optional`` as it holds.
    Raises :class:`BlockFormatError` with the reason on any inconsistency.
    """
    values = np.asarray(data, dtype=float).ravel()
    if values.size > MAX_VALUES:
        raise BlockFormatError(f"{values.size} values exceed the limit of {MAX_VALUES}")
    if data_offset != 0:
        raise BlockFormatError(f"data_offset must be 0, got {data_offset}")
    if len(dims) == 0:
        if expect is None:
            raise BlockFormatError("message has no layout (dim is empty)")
        names = (*expect, *optional)
        if not len(expect) <= values.size <= len(names):
            held = f"{len(expect)} to {len(names)}" if optional else f"{len(expect)}"
            raise BlockFormatError(
                f"unlabelled message must hold {held} values ({', '.join(names)}), got {values.size}"
            )
        return Block(names[: values.size], values.reshape(values.size, 1))
    if len(dims) > 2:
        raise BlockFormatError(f"block has at most 2 dimensions, got {len(dims)}")
    label, nc, stride0 = dims[0]
    names = tuple(s.strip() for s in label.split(",")) if label.strip() else ()
    if len(names) != nc:
        raise BlockFormatError(f"dim[0] names {len(names)} channels ({label!r}) but its size is {nc}")
    if any(not s for s in names):
        raise BlockFormatError(f"empty channel name in {label!r}")
    n = dims[1][1] if len(dims) == 2 else 1
    if len(dims) == 2 and dims[1][2] != n:
        raise BlockFormatError(f"dim[1] stride {dims[1][2]} != size {n}")
    if stride0 != nc * n:
        raise BlockFormatError(f"dim[0] stride {stride0} != {nc} channels x {n} samples")
    if values.size != nc * n:
        raise BlockFormatError(f"layout says {nc} x {n} = {nc * n} values, message holds {values.size}")
    block = Block(names, values.reshape(nc, n))
    if expect is not None:
        missing = [c for c in expect if c not in names]
        if missing:
            raise BlockFormatError(f"missing channel(s) {', '.join(missing)} (has {', '.join(names)})")
    return block


def check_samples(block: Block, channels: Sequence[str]) -> Block:
    """Validate a high-rate block: at least one sample, finite, strictly increasing ``t_s``, and
    every value within its channel's physical range (:data:`CHANNEL_MOST`).

    Returns a block holding only ``channels`` (in that order).  NaN *values* are allowed (a sensor
    may drop out); infinite values, values beyond the range, and non-finite or non-increasing times
    are not.
    """
    if block.n == 0:
        raise BlockFormatError("block holds no sample")
    t = block["t_s"]
    if not np.all(np.isfinite(t)):
        raise BlockFormatError("non-finite sample time")
    if block.n > 1 and np.any(np.diff(t) <= 0):
        raise BlockFormatError("sample times do not increase strictly")
    for c in channels:
        most = CHANNEL_MOST.get(c)
        if most is not None:
            x = block[c]
            with np.errstate(invalid="ignore"):
                beyond = np.abs(x) > most  # (NaN: a dropout, not beyond)
            if np.any(beyond):
                worst = float(x[beyond][0])
                raise BlockFormatError(f"{c} = {worst!r} is beyond its physical range (within +-{most:g})")
    return Block(tuple(channels), np.stack([block[c] for c in channels]))


def sample_span(data: bytes, named: bool = False) -> tuple[float, float, int] | None:
    """``(first t_s, last t_s, samples)`` of a serialised (CDR) block whose first channel is ``t_s``,
    read from the bytes without decoding the block (a recorder looks at every block it writes): a
    ``Float64MultiArray`` block, or with ``named`` a named message of samples (a header, then ``t_s``);
    ``None`` for anything else (another layout, a command, garbage)."""
    if data[:2] != b"\x00\x01":  # little-endian CDR (what every ROS 2 middleware here writes)
        return None
    if named:
        return _named_span(data)
    try:
        off = 4
        (ndim,) = struct.unpack_from("<I", data, off)
        off += 4
        if ndim not in (1, 2):
            return None
        sizes = []
        first_label = b""
        for k in range(ndim):
            (length,) = struct.unpack_from("<I", data, off)
            off += 4
            if k == 0:
                first_label = data[off : off + min(length, 4)]
            off += length
            off = 4 + ((off - 4 + 3) & ~3)
            size, _stride = struct.unpack_from("<II", data, off)
            off += 8
            sizes.append(size)
        off += 4  # data_offset
        (count,) = struct.unpack_from("<I", data, off)
        off += 4
        off = 4 + ((off - 4 + 7) & ~7)
        if not first_label.startswith(b"t_s,"):
            return None
        n = sizes[1] if ndim == 2 else 1
        if count < n:
            return None
        return _times_at(data, off, n)
    except struct.error:
        return None


def _times_at(data: bytes, off: int, n: int) -> tuple[float, float, int] | None:
    """``(first, last, n)`` of ``n`` sample times stored as doubles from ``off``; ``None`` when there is
    none or they are not finite and in order (``struct.error`` past the end, for the caller)."""
    if n < 1:
        return None
    t0, t1 = struct.unpack_from("<d", data, off)[0], struct.unpack_from("<d", data, off + 8 * (n - 1))[0]
    if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
        return None
    return t0, t1, n


#: The channel each field of a named message (``piezofin_msgs``) holds: a message's fields are lower case
#: (``voltage_v``), the channels name their unit as it is written (``voltage_V``).
CHANNEL_OF_FIELD = {
    c.lower(): c
    for c in (
        *DRIVE_CHANNELS,
        *TIP_CHANNELS,
        *LOADCELL_CHANNELS,
        *SUPPLY_CHANNELS,
        *COMMAND_FIELDS,
        *COMMAND_OPTIONAL,
    )
}


def field_of(channel: str) -> str:
    """The field of a named message that holds ``channel`` (``voltage_V``: ``voltage_v``)."""
    return channel.lower()


def _named_span(data: bytes) -> tuple[float, float, int] | None:
    """:func:`sample_span` of a named message of samples: ``std_msgs/Header`` (stamp, frame_id), then
    ``float64[] t_s``."""
    try:
        off = 4 + 8  # the encapsulation, then the stamp's sec and nanosec
        (length,) = struct.unpack_from("<I", data, off)
        off = 4 + ((off + 4 + length - 4 + 3) & ~3)  # frame_id, aligned to 4
        (n,) = struct.unpack_from("<I", data, off)
        off = 4 + ((off + 4 - 4 + 7) & ~7)  # the doubles, aligned to 8
        return _times_at(data, off, n)
    except struct.error:
        return None


def message_fields(msg: Any) -> dict[str, Any]:
    """The fields of a message of the project's own (``piezofin_msgs``, as rclpy or rosbags decodes it)
    but its header, by name."""
    if dataclasses.is_dataclass(msg):  # rosbags' (its __msgtype__ is no field of the message)
        names = [f.name for f in dataclasses.fields(msg) if not f.name.startswith("_")]
    else:  # rclpy's
        names = list(msg.get_fields_and_field_types())
    return {n: getattr(msg, n) for n in names if n != "header"}


def message_block(msg: Any, expect: Sequence[str] | None = None) -> Block:
    """A named message as a :class:`Block`: a block of samples (a ``float64[]`` field per channel, each
    as long as the others) or, of scalar fields, a one-sample block (an estimate); the channels named
    as the blocks name them, ``expect``'s present.  Raises :class:`BlockFormatError` with the reason."""
    fields = message_fields(msg)
    arrays = {n: v for n, v in fields.items() if not isinstance(v, (int, float))}
    if arrays and len(arrays) != len(fields):
        raise BlockFormatError(f"a message of samples and single values mixed: {', '.join(fields)}")
    if arrays:
        columns = {  # (rclpy's array.array('d') without a copy; rosbags' numpy arrays as they are)
            CHANNEL_OF_FIELD.get(name, name): np.frombuffer(value, dtype=float)
            if isinstance(value, array.array)
            else np.asarray(value, dtype=float).ravel()
            for name, value in arrays.items()
        }
        sizes = {c: a.size for c, a in columns.items()}
        if sum(sizes.values()) > MAX_VALUES:
            raise BlockFormatError(f"{sum(sizes.values())} values exceed the limit of {MAX_VALUES}")
        if len(set(sizes.values())) > 1:
            raise BlockFormatError(f"its fields differ in length: {sizes}")
        block = Block(tuple(columns), np.stack(list(columns.values())))
    else:
        block = Block.from_record({CHANNEL_OF_FIELD.get(n, n): float(v) for n, v in fields.items()})
    missing = [c for c in expect or () if c not in block.names]
    if missing:
        raise BlockFormatError(f"missing field(s) {', '.join(missing)} (has {', '.join(block.names)})")
    return block


def stamp_of(seconds: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of a ``builtin_interfaces/Time`` for a time in seconds (0 for NaN or < 0)."""
    if not (math.isfinite(seconds) and seconds > 0.0):
        return 0, 0
    ns = round(seconds * 1e9)
    return ns // 1_000_000_000, ns % 1_000_000_000
