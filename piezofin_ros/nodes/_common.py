"""Shared adapter code: block messages, QoS, declared parameters, ``main()`` wrappers."""

from __future__ import annotations

import array
import collections
import contextlib
import copy
import faulthandler
import gc
import importlib
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ..bags.blocks import (
    CHANNEL_OF_FIELD,
    COMMAND_FIELDS,
    COMMAND_OPTIONAL,
    Block,
    check_samples,
    from_layout,
    message_block,
    stamp_of,
    to_layout,
)
from ..config import settings_of
from ..errors import NodeError, PiezofinError

T = TypeVar("T")

#: High-rate sample blocks and estimates: reliable (nothing dropped), 200 blocks of history.
QOS_DATA = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=200,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
#: The estimates: as the blocks, and transient-local, so that a late joiner that asks for it
#: (``ros2 topic echo --once``, a monitor started after the run) reads the latest ones at once; a
#: volatile reader (the controller, the speed loop, the recorder) is sent none from before it joined.
QOS_ESTIMATE = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=200,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
#: A fish's sensor readings (its speed, its battery), as ROS sensor drivers publish them
#: (``qos_profile_sensor_data``): best-effort, so that a late joiner (``ros2 topic echo --once``) is
#: never told of samples "lost" from before it joined (Fast DDS counts a reliable late joiner's
#: pre-match samples so on a busy topic), and the suite's best-effort readers match a driver's
#: reliable publisher and its best-effort one alike; only the newest reading matters.
QOS_SENSOR = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
#: Commands: reliable, short history.
QOS_COMMAND = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: A status (JSON in a String), sent when it changes: transient-local, the latest one kept, so that
#: `ros2 topic echo --once` answers a late joiner at once (volatile, it waited for the next change).
QOS_STATUS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
#: /clock as rosbag2 and the ROS time source expect it.
QOS_CLOCK = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)
#: /diagnostics as diagnostic_updater publishes them (reliable; a monitor that joins reads the next second's)
QOS_DIAGNOSTICS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
)
#: The profiles by the name the topic table (``bags.topics.TOPICS``) gives them.
QOS = {
    "data": QOS_DATA,
    "sensor": QOS_SENSOR,
    "estimate": QOS_ESTIMATE,
    "command": QOS_COMMAND,
    "status": QOS_STATUS,
    "clock": QOS_CLOCK,
    "diagnostics": QOS_DIAGNOSTICS,
}

# Topic names (relative: a node's namespace puts them under one fin), defined with the bags' reader.
from ..bags.topics import (  # noqa: E402, F401 (re-exported: the nodes' contract)
    TOPIC_BATTERY,
    TOPIC_BIAS,
    TOPIC_CLOCK,
    TOPIC_CMD,
    TOPIC_CMD_VEL,
    TOPIC_DEMAND,
    TOPIC_DIAGNOSTICS,
    TOPIC_DRIVE,
    TOPIC_ESTIMATE,
    TOPIC_ESTIMATOR_STATUS,
    TOPIC_IMU,
    TOPIC_LOADCELL,
    TOPIC_LOOP_STATUS,
    TOPIC_MODEL,
    TOPIC_ODOM,
    TOPIC_SPEED,
    TOPIC_STATUS,
    TOPIC_SUPPLY,
    TOPIC_TIP,
    TOPIC_VOLTAGE_CAP,
    TOPIC_WAYPOINT_MARKERS,
    TOPIC_WAYPOINT_PATH,
    TOPIC_WAYPOINT_STATUS,
    TOPICS,
    table_topic,
)


def message_class(type_name: str) -> Any:
    """The rclpy message class of ``pkg/msg/Type`` or ``pkg/Type`` (ImportError/AttributeError if not
    installed)."""
    parts = type_name.strip().split("/")
    return getattr(importlib.import_module(f"{parts[0]}.msg"), parts[-1])


def endpoint(topic: str) -> tuple[Any, str, QoSProfile]:
    """``(message class, topic, QoS)`` of a topic of the table, for ``create_publisher``."""
    t = TOPICS[topic]
    return message_class(t.type), topic, QOS[t.qos]


def reliability_of(topic: str) -> Any:
    """The reliability a subscriber asks of a topic: its profile's in the topic table (a relative or
    absolute name; best-effort for a sensor reading, which matches any publisher), reliable for a
    topic the table does not know."""
    t = table_topic(topic)
    return ReliabilityPolicy.RELIABLE if t is None else QOS[t.qos].reliability


def block_msg(block: Block) -> Float64MultiArray:
    """A :class:`Block` as a ``Float64MultiArray`` (see :mod:`piezofin_ros.bags.blocks`)."""
    dims, data = to_layout(block)
    msg = Float64MultiArray()
    msg.layout.dim = [
        MultiArrayDimension(label=label, size=size, stride=stride) for label, size, stride in dims
    ]
    msg.data = data.tolist()
    return msg


def msg_block(msg: Any, expect: Sequence[str] | None = None, optional: Sequence[str] = ()) -> Block:
    """Decode a ``Float64MultiArray`` (unlabelled: ``expect``, then as many of ``optional`` as it
    holds), or a named message of the project's own (a field per channel: samples, or single
    values); raises ``BlockFormatError`` with the reason."""
    if not isinstance(msg, Float64MultiArray):
        return message_block(msg, expect)
    dims = [(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim]
    return from_layout(
        dims, msg.data, expect=expect, data_offset=int(msg.layout.data_offset), optional=optional
    )


def named_msg(msg_type: Any, block: Block, stamp_s: float | None = None) -> Any:
    """A named message of the project's own (``piezofin_msgs``) holding ``block``: a ``float64[]`` field
    per channel (every one the message has must be in the block), or a ``float64`` field per value of
    a one-sample block (NaN where the block lacks it: the message's "the data cannot give it").  Its
    ``header.stamp`` is ``stamp_s`` in the fin's time, by default the first sample's ``t_s``."""
    msg = msg_type()
    if stamp_s is None:
        stamp_s = float(block["t_s"][0]) if "t_s" in block.names and block.n else math.nan
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_of(stamp_s)
    names = block.names
    for name, kind in msg_type.get_fields_and_field_types().items():
        if name == "header":
            continue
        channel = CHANNEL_OF_FIELD.get(name, name)
        if kind.startswith("sequence<"):
            samples = array.array("d")
            samples.frombytes(np.ascontiguousarray(block[channel], dtype=float).tobytes())
            setattr(msg, name, samples)
        else:
            setattr(msg, name, float(block.scalar(channel)) if channel in names else math.nan)
    return msg


def sample_msg(topic: str, block: Block) -> Any:
    """The message of the suite's sampled ``topic`` (``drive``, ``tip_velocity``, ``loadcell``,
    ``supply``: its type in the topic table) holding ``block``, stamped at its first sample."""
    return named_msg(endpoint(topic)[0], block)


def record_msg(msg_type: Any, record: dict[str, float], stamp_s: float) -> Any:
    """A one-sample named message (an estimate) holding ``record`` by name (:func:`named_msg`)."""
    return named_msg(msg_type, Block.from_record(record), stamp_s)


# --------------------------------------------------------------------------------- parameters
#: The ROS arguments each context was started with (:func:`run_node`), for :func:`_declare`.
_ARGV: dict[int, Sequence[str]] = {}


def _declare(node: Node, name: str, default: Any, desc: ParameterDescriptor) -> Any:
    """``node.declare_parameter``, with the command line's ``-p`` taking precedence over every
    parameter file, as it follows them.

    rclpy puts a ``-p`` value into the file's ``/**`` entry, which a ``/**/<node>`` entry of the
    same file overrides whatever the order: ``speed_loop --ros-args --params-file config/fish.yaml
    -p speed_m_s:=0.066`` swam at the file's 0.06 m/s, silently (rclcpp applies ``-p`` last).
    """
    if not getattr(node, "_piezofin_command_line", False):
        node._piezofin_command_line = True  # type: ignore[attr-defined]
        for target, pname, raw in command_line_values(_ARGV.get(id(node.context), ())):
            if target in ("", node.get_name()):
                # (a value rcl could not take stays as rcl kept it)
                with contextlib.suppress(ValueError, TypeError):
                    node._parameter_overrides[pname] = Parameter(pname, value=command_line_value(raw))
    return node.declare_parameter(name, default, desc)


def command_line_value(raw: str) -> Any:
    """A ``-p name:=value``'s value as rcl reads it: YAML, and a number where rcl's ``strtod`` reads
    one that YAML 1.1 leaves a string (``1e3``, ``1e400``)."""
    import yaml

    try:
        value = yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw  # (rcl refused it already, or kept the string)
    if isinstance(value, str) and raw.strip()[:1] not in ("'", '"'):  # (quoted: the string it is)
        for number in (int, float):
            try:
                return number(raw)
            except ValueError:
                pass
    return value


def float_param(
    node: Node, name: str, default: float, lo: float, hi: float, description: str, *, read_only: bool = False
) -> float:
    """Declare a double parameter with a range; return its value.

    Integers are accepted too (``-p realtime_factor:=10`` parses as an integer), so the
    descriptor allows dynamic typing and the type and range are checked here for every value.
    """
    desc = ParameterDescriptor(
        description=description,
        floating_point_range=[FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)],
        read_only=read_only,
        dynamic_typing=True,
    )
    value = _declare(node, name, float(default), desc).value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise StartupError(f"parameter {name}: expected a number, got {value!r}")
    if not (math.isfinite(value) and lo <= value <= hi):
        raise StartupError(f"parameter {name}: {value!r} is outside [{lo:g}, {hi:g}]")
    if not isinstance(value, float):  # `-p x:=10`: stored as the double it is
        node.set_parameters([Parameter(name, value=float(value))])
    _keep_double(node, name)
    return float(value)


def _keep_double(node: Node, name: str) -> None:
    """At run time too, an integer set on a double parameter stays a double (``ros2 param set x 10``)."""
    doubles = getattr(node, "_piezofin_doubles", None)
    if doubles is None:
        doubles = node._piezofin_doubles = set()  # type: ignore[attr-defined]

        def to_double(params: list[Parameter]) -> list[Parameter]:
            return [
                Parameter(p.name, value=float(p.value))
                if p.name in doubles and p.type_ == Parameter.Type.INTEGER
                else p
                for p in params
            ]

        node.add_pre_set_parameters_callback(to_double)
    doubles.add(name)


def int_param(node: Node, name: str, default: int, lo: int, hi: int, description: str) -> int:
    desc = ParameterDescriptor(
        description=description, integer_range=[IntegerRange(from_value=lo, to_value=hi, step=1)]
    )
    return int(_declare(node, name, int(default), desc).value)


def str_param(
    node: Node,
    name: str,
    default: str,
    description: str,
    *,
    read_only: bool = False,
    choices: Sequence[str] = (),
) -> str:
    constraints = f"one of: {', '.join(choices)}" if choices else ""
    desc = ParameterDescriptor(
        description=description, read_only=read_only, additional_constraints=constraints
    )
    return str(_declare(node, name, default, desc).value)


def bool_param(node: Node, name: str, default: bool, description: str) -> bool:
    return bool(_declare(node, name, default, ParameterDescriptor(description=description)).value)


def array_param(
    node: Node, name: str, default: list[Any], kind: Parameter.Type, description: str
) -> list[Any]:
    """Declare a typed array parameter (an empty default stays typed); return its value as a list."""
    desc = ParameterDescriptor(description=description)
    value = _declare(node, name, default if default else kind, desc).value
    if value is None:
        return []
    if kind == Parameter.Type.DOUBLE_ARRAY:
        return [float(x) for x in value]
    return list(value)


def declare(node: Node, cls: type[T], prefix: str = "", base: T | None = None) -> T:
    """Declare a ROS parameter for every field of the settings dataclass ``cls``; return the instance.

    Each field's :func:`~piezofin_ros.config.setting` gives the default (or ``base``'s value), the
    range, the choices and the description, so a node's parameters are declared once, in its
    config dataclass.  Values outside the range or the choices stop the node with one line naming
    the parameter; the dataclass's own validation then runs on the result (its message names the
    field), so an inconsistent combination fails too.
    """
    values: dict[str, Any] = {}
    for f, default, s in settings_of(cls):
        name = f"{prefix}.{f.name}" if prefix else f.name
        if base is not None:
            default = getattr(base, f.name)
        lo, hi = s.bounds
        if isinstance(default, bool):
            value: Any = bool_param(node, name, default, s.description)
        elif isinstance(default, int):
            value = int_param(
                node, name, default, int(max(lo, -(2**31))), int(min(hi, 2**31 - 1)), s.description
            )
        elif isinstance(default, float):
            value = float_param(node, name, default, lo, hi, s.description, read_only=s.read_only)
        elif isinstance(default, str):
            value = str_param(node, name, default, s.description, read_only=s.read_only, choices=s.choices)
            if s.choices and value not in s.choices:
                raise StartupError(f"parameter {name}: {value!r} is not one of {', '.join(s.choices)}")
        elif isinstance(default, tuple):
            kind = Parameter.Type.DOUBLE_ARRAY if s.items is float else Parameter.Type.STRING_ARRAY
            value = tuple(array_param(node, name, list(default), kind, s.description))
        else:
            raise TypeError(f"{cls.__name__}.{f.name}: no ROS parameter type for {default!r}")
        values[f.name] = value
    return cls(**values)


def freeze_parameters(
    node: Node,
    live_prefix: str = "",
    live: Callable[[list[Parameter]], str | None] | None = None,
    *,
    takes_sim_time: bool = True,
) -> None:
    """Refuse every runtime parameter change, with the reason.

    Every value is checked once at start, where it configures the core; changing it under a
    running simulation, estimator or bag would leave the node half reconfigured.  That holds for
    ``use_sim_time`` too: switched live, a node's time jumps between the wall clock and ``/clock``
    under its windows, heartbeat and bag (set it at start, ``-p use_sim_time:=true``); ``fin_sim``
    (``takes_sim_time=False``) never takes it.  Parameters under ``live_prefix`` go to ``live``
    instead, which applies them and returns ``None``, or returns the reason it refuses them.
    """

    def callback(params: list[Parameter]) -> SetParametersResult:
        taken = [p for p in params if live is not None and live_prefix and p.name.startswith(live_prefix)]
        for p in params:
            if p.name == "use_sim_time":
                return SetParametersResult(
                    successful=False,
                    reason="use_sim_time is not taken: this node keeps its own time (the steady clock)"
                    if not takes_sim_time
                    else "use_sim_time is fixed at start (switched live, this node's time would jump); "
                    "restart the node with -p use_sim_time:=true",
                )
            if all(p.name != q.name for q in taken):
                return SetParametersResult(
                    successful=False, reason=f"{p.name} is fixed at start; restart the node to change it"
                )
        if taken and live is not None:
            why = live(taken)
            if why is not None:
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(callback)
    # and said where tools look (`ros2 param describe`, rqt_reconfigure): every parameter but the live
    # ones read-only (rclpy then refuses a change itself: "Trying to set a read-only parameter")
    for name in list(node._parameters):
        if name == "use_sim_time" or (live is not None and live_prefix and name.startswith(live_prefix)):
            continue
        old = node.describe_parameter(name)  # (the node's own descriptor, not a copy)
        if old.read_only:
            continue
        desc = copy.deepcopy(old)
        desc.read_only = True
        desc.description += " (fixed at start: restart the node to change it)"
        if node._parameters[name].type_ == Parameter.Type.NOT_SET:
            # (an empty typed array: rclpy's set_descriptor reads its value, which raises)
            old.read_only, old.description = desc.read_only, desc.description
        else:
            node.set_descriptor(name, desc)


# -------------------------------------------------------------------------------------- inbox
#: A reason a node refuses what another process sent is said at most this often per topic, s.
SAY_EVERY_S = 1.0


#: What changed, for a publisher of an older type (:meth:`Inbox._check_types`).
TYPE_HINTS = {
    **{
        f"piezofin_msgs/msg/{name}": " (a float64[] field per channel, its unit in lower case, e.g. "
        "voltage_v; header.stamp the first sample's time)"
        for name in ("Drive", "TipVelocity", "Loadcell", "Supply")
    },
    "geometry_msgs/msg/TwistStamped": " (the speed in twist.linear.x, m/s; header.stamp when it was read)",
}


class Inbox:
    """The one door by which a node takes messages from other processes.

    Each subscription made here has a ``check`` that turns the message into what the node uses
    (a :class:`Block`, a number within its range) or raises with the reason; the handler sees
    only what passed.  What fails is counted per topic (``refused``) and said at most once a
    second per topic, with the count.  A handler that still fails on a message the check passed
    with an arithmetic or a value error (an overflow, a division by zero, the core's refusal) is
    counted (``failed``) and said the same way: the message is lost, the node lives (one
    ``swim_speed`` of 1e308 killed the estimator with an ``OverflowError``, and the launch with it).
    Other exceptions are bugs and propagate.
    """

    #: How often the polled subscriptions are looked at by default, s of wall time (the estimator's
    #: blocks: 20 a second per topic at x1, 800 at x40).
    POLL_S = 0.01
    #: How often the publishers of the polled topics are asked their type, s of wall time.
    TYPES_S = 2.0

    #: How often a node whose messages matter in its own time looks (``node_time_s``), s of its time:
    #: a set-point 50 ms late at most, for a loop of 10 Hz.
    NODE_TIME_S = 0.05
    #: How often the rate of the node's clock against the wall is measured (``node_time_s``), s.
    RATE_S = 1.0

    def __init__(self, node: Node, poll_s: float = POLL_S, *, node_time_s: float | None = None) -> None:
        """``poll_s``: how often the polled subscriptions are looked at, s of wall time (a node whose
        messages come a few a second looks less often: each look wakes the executor, 100 a second
        cost the controller about 2 % of a core).  ``node_time_s``: look every ``node_time_s`` of
        the node's own time instead, as measured against the wall every :data:`RATE_S`: a set-point
        that matters in a fish's time (a yaw loop's offset, late by 0.5 s of fish time at x10 when
        looked at 20 times a second of wall time); every ``poll_s`` of wall time at the most often (a
        simulation run fast), every ``node_time_s`` at the least (a clock stopped or going back)."""
        from rclpy.clock import Clock, ClockType

        if node_time_s is not None and not node_time_s >= poll_s:
            raise NodeError(f"inbox: node_time_s {node_time_s} must be at least poll_s {poll_s}")
        self._node = node
        self.poll_s = poll_s
        self.node_time_s = node_time_s
        self._timer: Any = None
        self._rate_at: tuple[float, int] | None = None  # (time.monotonic, the node's clock in ns)
        self._clock = Clock(clock_type=ClockType.STEADY_TIME)
        self._said: dict[str, int] = {}
        self._helper: Node | None = None
        self._polls: list[tuple[Any, str, Callable[[Any], None], Callable[[Any], Any] | None, int]] = []
        self.refused: collections.Counter[str] = collections.Counter()
        self.refused_at = -math.inf  # (time.monotonic) the latest refusal
        self.failed: collections.Counter[str] = collections.Counter()
        self.polled_count: collections.Counter[str] = collections.Counter()  # messages taken by polls
        self._types_at = -math.inf  # (time.monotonic) the last look at the publishers' types
        self.wrong_types: set[tuple[str, str]] = set()  # (topic, type) a publisher sends that is not read
        self._unnamed: collections.Counter[tuple[str, str]] = collections.Counter()

    def refused_recently(self, within_s: float = 2.0) -> bool:
        """Whether a message was refused in the last ``within_s`` of wall time."""
        return time.monotonic() - self.refused_at <= within_s

    def latest(
        self,
        msg_type: Any,
        topic: str,
        handler: Callable[[Any], None],
        check: Callable[[Any], Any] | None = None,
    ) -> Any:
        """A set-point or reading of which only the newest value matters (a speed, a thrust demand):
        :meth:`polled` with a queue of one."""
        return self.polled(msg_type, topic, handler, check, depth=1, most=1)

    def polled(
        self,
        msg_type: Any,
        topic: str,
        handler: Callable[[Any], None],
        check: Callable[[Any], Any] | None = None,
        *,
        depth: int,
        most: int,
    ) -> Any:
        """A subscription looked at every ``poll_s`` s of wall time: up to ``most`` of its queued
        messages (oldest first) go through ``check`` to ``handler`` as :meth:`subscribe`'s do.

        Its queue (``depth`` deep) lives in the middleware and is never seen by the executor, so a
        flood costs this node at most ``most`` messages per look, whatever its rate, and the timers
        (the controller's heartbeat) keep their turn: a 3-4 kHz ``thrust_demand`` flood held the
        controller's executor and fin_sim's watchdog tripped; a ``swim_speed`` flood starved the
        estimator; a 10 kHz flood of ``estimate`` tripped it again.  What a flood pushes out of the
        queue is the flood's or lost with it (a reliable publisher's messages are never dropped for
        a slow reader at a normal rate).  The subscription belongs to a hidden helper node of the
        same context (``_<node>_inbox``, never spun), on the topic's resolved name."""
        from rclpy.clock import Clock, ClockType
        from rclpy.qos import QoSProfile as Q

        node = self._node
        if self._helper is None:
            self._helper = helper_node(node, "inbox")
            # one timer looks at every polled subscription, in the order they were made (from the
            # most often: a simulation's clock may run fast from its start)
            self._timer = node.create_timer(
                self.poll_s, self._poll, clock=Clock(clock_type=ClockType.STEADY_TIME)
            )
        qos = Q(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability_of(topic))
        sub = self._helper.create_subscription(msg_type, node.resolve_topic_name(topic), never, qos)
        self._polls.append((sub, topic, handler, check, most))
        return sub

    def _follow_clock(self, node_time_s: float) -> None:
        """The looks' period from the node's clock's rate against the wall (``node_time_s``)."""
        wall, now = time.monotonic(), self._node.get_clock().now().nanoseconds
        if self._rate_at is None:
            self._rate_at = (wall, now)
            return
        if wall - self._rate_at[0] < self.RATE_S:
            return
        rate = (now - self._rate_at[1]) * 1e-9 / (wall - self._rate_at[0])
        self._rate_at = (wall, now)
        period = min(max(node_time_s / rate if rate > 0 else node_time_s, self.poll_s), node_time_s)
        before = self._timer.timer_period_ns * 1e-9
        if abs(period - before) > 0.1 * before:
            self._timer.timer_period_ns = int(period * 1e9)

    def _poll(self) -> None:
        if self.node_time_s is not None:
            self._follow_clock(self.node_time_s)
        if time.monotonic() - self._types_at >= self.TYPES_S:
            self._types_at = time.monotonic()
            self._check_types()
        for sub, topic, handler, check, most in self._polls:
            for _ in range(most):
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, False)
                if taken is None:
                    break
                self.polled_count[topic] += 1
                self._deliver(topic, taken[0], handler, check)

    def _check_types(self) -> None:
        """One error line per topic and type when a publisher sends a type this node does not read (a
        rig driver written before the blocks were named), and per topic when it publishes best-effort
        what this node reads reliable (a block): DDS never matches them, so nothing would arrive and
        nothing would say why."""
        for sub, topic, *_ in self._polls:
            want = f"{sub.msg_type.__module__.split('.')[0]}/msg/{sub.msg_type.__name__}"
            name = self._node.resolve_topic_name(topic)
            for info in self._node.get_publishers_info_by_topic(name):
                unmatched = (
                    reliability_of(topic) == ReliabilityPolicy.RELIABLE
                    and info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
                )
                got = "best-effort" if info.topic_type == want and unmatched else info.topic_type
                if got == want or (name, got) in self.wrong_types:
                    continue
                key = (name, got)
                if info.node_name.startswith("_NODE_NAME_UNKNOWN") and self._unnamed[key] < 3:
                    self._unnamed[key] += 1  # (its node's name comes later in discovery: a look or two)
                    continue
                self.wrong_types.add(key)
                who = (
                    f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                    if not info.node_name.startswith("_NODE_NAME_UNKNOWN")
                    else "a node of unknown name"
                )
                if got == "best-effort":
                    self._node.get_logger().error(
                        f"{who} publishes {name} best-effort, which this node's reliable reader never "
                        f"matches: every sample of {topic} counts, publish it reliable "
                        "(docs/reference.md, Topics)"
                    )
                    continue
                self._node.get_logger().error(
                    f"{who} publishes {name} as {info.topic_type}, which this node does not read: "
                    f"{topic} is {want} now{TYPE_HINTS.get(want, '')} (docs/reference.md, Topics)"
                )

    def close(self) -> None:
        self._polls.clear()
        if self._helper is not None:
            self._helper.destroy_node()
            self._helper = None

    def subscribe(
        self,
        msg_type: Any,
        topic: str,
        handler: Callable[[Any], None],
        qos: QoSProfile,
        check: Callable[[Any], Any] | None = None,
        **kwargs: Any,
    ) -> Any:
        def on_message(msg: Any) -> None:
            self._deliver(topic, msg, handler, check)

        return self._node.create_subscription(msg_type, topic, on_message, qos, **kwargs)

    def _deliver(
        self, topic: str, msg: Any, handler: Callable[[Any], None], check: Callable[[Any], Any] | None
    ) -> None:
        try:
            value = msg if check is None else check(msg)
        # (RecursionError: a message nested deeper than a check's parser recurses is the message's)
        except (
            PiezofinError,
            ValueError,
            TypeError,
            ArithmeticError,
            KeyError,
            IndexError,
            RecursionError,
        ) as exc:
            self.refused[topic] += 1
            self.refused_at = time.monotonic()
            self._say(
                topic, f"refused {self.refused[topic]} message(s) on {self._name(topic)}; the latest: {exc}"
            )
            return
        try:
            handler(value)
        except (PiezofinError, ValueError, ArithmeticError) as exc:
            self.failed[topic] += 1
            self._say(
                topic,
                f"could not use {self.failed[topic]} message(s) on {self._name(topic)}; the latest: "
                f"{type(exc).__name__}: {exc}",
            )

    def _name(self, topic: str) -> str:
        return self._node.resolve_topic_name(topic)

    def _say(self, topic: str, text: str) -> None:
        now = self._clock.now().nanoseconds
        if now - self._said.get(topic, -(10**18)) >= SAY_EVERY_S * 1e9:
            self._said[topic] = now
            self._node.get_logger().warning(text)


def never(msg: Any) -> None:  # (a polled subscription's callback: no executor calls it)
    pass


def helper_node(node: Node, role: str) -> Node:
    """A hidden node (``_<node>_<role>``) beside ``node``, in its context and namespace, that no
    executor spins: it holds the subscriptions ``node`` polls (:meth:`Inbox.polled`, the recorder)."""
    return Node(
        f"_{node.get_name()}_{role}",
        namespace=node.get_namespace(),
        context=node.context,
        use_global_arguments=False,  # (a `-r __node:=` is for the node itself)
        start_parameter_services=False,
        enable_rosout=False,
    )


class MessageRefused(NodeError, ValueError):
    """A message from another process that is no reading of what its topic carries."""


def drive_command(msg: Any) -> tuple[float, float, float, float]:
    """A drive command as ``cmd`` carries it (:data:`~piezofin_ros.bags.blocks.COMMAND_FIELDS`, then
    the optional offset): its frequency (Hz), peak-to-peak voltage, on (0/1) and offset (V, 0 when it
    holds none), one sample; else ``BlockFormatError`` (not the layout) or :class:`MessageRefused`.
    Its values are judged where it is read: by the drive's limits (``fin_sim``), by what a fin is
    driven at (``speed_loop``'s ``drive_point``)."""
    cmd = msg_block(msg, expect=COMMAND_FIELDS, optional=COMMAND_OPTIONAL)
    if cmd.n != 1:
        raise MessageRefused(f"a command holds one sample, got {cmd.n}")
    f, vpp, on = (cmd.scalar(name) for name in COMMAND_FIELDS)
    return f, vpp, on, (cmd.scalar("bias_V") if "bias_V" in cmd.names else 0.0)


def scalar(lo: float, hi: float, unit: str) -> Callable[[Any], float]:
    """A check for a ``std_msgs/Float64``: its value, finite and within ``[lo, hi]`` (``unit``)."""

    def check(msg: Any) -> float:
        x = float(msg.data)
        if not (math.isfinite(x) and lo <= x <= hi):
            raise MessageRefused(f"{x!r} {unit} is not within [{lo:g}, {hi:g}] {unit}")
        return x

    return check


def speed_reading(msg: Any) -> tuple[float, float]:
    """A speed sensor's ``geometry_msgs/TwistStamped``: (its stamp, s, NaN when unset; its
    ``twist.linear.x``, m/s, finite and within what any fish swims)."""
    from ..physics.swim import SPEED_MOST_M_S

    u = float(msg.twist.linear.x)
    if not (math.isfinite(u) and abs(u) <= SPEED_MOST_M_S):
        raise MessageRefused(f"{u!r} m/s is not within [{-SPEED_MOST_M_S:g}, {SPEED_MOST_M_S:g}] m/s")
    stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
    return (stamp if stamp > 0 else math.nan), u


def speed_msg(msg_type: Any, speed_m_s: float, stamp_s: float) -> Any:
    """A speed sensor's reading (``geometry_msgs/TwistStamped``, ``base_link``) at ``stamp_s``."""
    msg = msg_type()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_of(stamp_s)
    msg.header.frame_id = "base_link"
    msg.twist.linear.x = float(speed_m_s)
    return msg


def heading_of(q: Any) -> float:
    """The yaw of a ``geometry_msgs/Quaternion``, rad (the heading of a fish in the plane)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def imu_msg(
    yaw_rate_rad_s: float, heading_rad: float, heading_var: float, rate_sigma: float, stamp_s: float
) -> Any:
    """An IMU's reading (``sensor_msgs/Imu``, ``base_link``) at ``stamp_s``: its heading as the
    orientation (yaw only) and its yaw rate, each with its variance; what it does not measure (roll,
    pitch, their rates) marked unknown (1e6), its linear acceleration not given (``-1``, REP 145)."""
    from sensor_msgs.msg import Imu

    from ..control.odometry import UNKNOWN

    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_of(stamp_s)
    msg.header.frame_id = "base_link"
    msg.orientation.z, msg.orientation.w = math.sin(0.5 * heading_rad), math.cos(0.5 * heading_rad)
    msg.orientation_covariance = [UNKNOWN, 0.0, 0.0, 0.0, UNKNOWN, 0.0, 0.0, 0.0, float(heading_var)]
    msg.angular_velocity.z = float(yaw_rate_rad_s)
    msg.angular_velocity_covariance = [UNKNOWN, 0.0, 0.0, 0.0, UNKNOWN, 0.0, 0.0, 0.0, rate_sigma**2]
    msg.linear_acceleration_covariance[0] = -1.0
    return msg


def samples(channels: tuple[str, ...]) -> Callable[[Any], Block]:
    """A check for a block of samples on ``channels``: its layout, its times and each value's
    physical range (:func:`~piezofin_ros.bags.blocks.check_samples`)."""

    def check(msg: Any) -> Block:
        return check_samples(msg_block(msg, expect=channels), channels)

    return check


#: The most a fish's battery reads: volts at its terminals, amperes either way.
BATTERY_MOST_V, BATTERY_MOST_A = 1000.0, 1000.0


def battery_reading(msg: Any) -> tuple[float, float, float]:
    """A ``sensor_msgs/BatteryState``'s (stamp s, terminal voltage V, current A), each within what a
    fish's battery reads (NaN, as the message's "unmeasured", is refused with the reason)."""
    voltage, current = float(msg.voltage), float(msg.current)
    if not (math.isfinite(voltage) and 0.0 < voltage <= BATTERY_MOST_V):
        raise MessageRefused(f"voltage = {voltage!r} V is no battery's (within (0, {BATTERY_MOST_V:g}])")
    if not (math.isfinite(current) and abs(current) <= BATTERY_MOST_A):
        raise MessageRefused(f"current = {current!r} A is no battery's (within +-{BATTERY_MOST_A:g})")
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, voltage, current


def estimates(msg: Any) -> Any:
    """A check for an ``estimate`` (``piezofin_msgs/Estimate``): an
    :class:`~piezofin_ros.estimation.estimator.Estimate` with every field within what a fin gives
    (:func:`~piezofin_ros.estimation.estimator.check_estimate`)."""
    from ..estimation.estimator import Estimate, check_estimate

    return check_estimate(msg_block(msg, expect=Estimate.field_names()).as_dict())


def json_object(msg: Any, most: int, what: str) -> dict[str, Any]:
    """The JSON object a ``std_msgs/String`` carries (``what`` names it in the refusal): at most
    ``most`` characters, else :class:`MessageRefused`.  Not JSON, not an object, or nested deeper than
    Python's parser recurses (``[[[...]]]``: 3 kB of it raised ``RecursionError`` past the door and
    killed the estimator, 2026-12-06), refused alike."""
    data = str(msg.data)
    if len(data) > most:
        raise MessageRefused(f"{len(data)} characters: {what} holds a few hundred")
    try:
        value = json.loads(data)
    except RecursionError:
        raise MessageRefused(f"JSON nested too deep for {what}") from None
    except ValueError as exc:
        raise MessageRefused(f"not JSON ({exc})") from None
    if not isinstance(value, dict):
        raise MessageRefused(f"{what} is a JSON object, not {type(value).__name__}")
    return value


#: The longest ``thrust_estimator/status`` read, characters (its JSON is about 500).
ESTIMATOR_STATUS_MOST = 4096


def supply_measured_on(msg: Any) -> str:
    """A check for ``thrust_estimator/status`` (``std_msgs/String``, JSON): the topic the estimator
    measures the supply watt on ("": none, the amplifier's model alone)."""
    on = json_object(msg, ESTIMATOR_STATUS_MOST, "an estimator's status").get("supply_watt_measured_on")
    if not isinstance(on, str):
        raise MessageRefused("an estimator's status names supply_watt_measured_on: a topic or ''")
    return on


# ------------------------------------------------------------------------------------ silence
class SilenceWatch:
    """Says so, within ``after_s`` of wall time, when something a node lives on stops arriving.

    Runs on the steady clock, so it speaks even when the silence is the simulated clock itself
    (``fin_sim`` killed: ``/clock`` stops, and with it every timer on ROS time).  One warning when
    the silence starts (only after the first arrival), one line when it ends.  With a ``topic``,
    one warning too when nothing has ever come and nothing publishes it ``first_s`` after the start
    (``sim:=false`` with no rig driver sat 35 s without a word).
    """

    def __init__(
        self,
        node: Node,
        what: str,
        hint: str,
        after_s: float = 3.0,
        topic: str | None = None,
        first_s: float = 10.0,
    ) -> None:
        from rclpy.clock import Clock, ClockType

        self._node, self._what, self._hint, self._after_s = node, what, hint, after_s
        self._clock = Clock(clock_type=ClockType.STEADY_TIME)
        self._last_ns: int | None = None
        self._topic, self._first_s = topic, first_s
        self._start_ns = self._clock.now().nanoseconds
        self.silent = False
        node.create_timer(min(1.0, after_s / 3), self._check, clock=self._clock)

    def heard(self) -> None:
        self._last_ns = self._clock.now().nanoseconds
        if self.silent:
            self.silent = False
            self._node.get_logger().info(f"{self._what}: back")

    def _check(self) -> None:
        if self._last_ns is None and self._topic is not None:
            waited = (self._clock.now().nanoseconds - self._start_ns) * 1e-9
            if waited >= self._first_s and self._node.count_publishers(self._topic) == 0:
                self._topic = None  # (said once)
                self._node.get_logger().warning(
                    f"{self._what}: nothing, and no publisher, after {waited:.0f} s; {self._hint}"
                )
        if self._last_ns is None or self.silent:
            return
        quiet_s = (self._clock.now().nanoseconds - self._last_ns) * 1e-9
        if quiet_s >= self._after_s:
            self.silent = True
            self._node.get_logger().warning(f"{self._what}: nothing for {quiet_s:.1f} s; {self._hint}")


# --------------------------------------------------------------------------------------- main
class StartupError(NodeError):
    """A node cannot start (bad configuration); the text is shown without a traceback."""


class TeardownWatchdog:
    """Ends the process with its status when tearing down its ROS entities (after every node's
    ``close()``) takes more than ``TEARDOWN_S``, with every thread's stack on standard error.

    On a loaded machine ``fin_sims`` once stayed alive more than 15 s after closing both fins
    (``ros2 launch`` escalated to SIGTERM, which a stopping node ignores, then SIGKILL: exit -9).
    What the node must do is done by then; the stacks say where the middleware waited."""

    TEARDOWN_S = 3.0

    def __init__(self, status: int) -> None:
        self.status = status
        self._timer = threading.Timer(self.TEARDOWN_S, self._expire)
        self._timer.daemon = True

    def start(self) -> TeardownWatchdog:
        self._timer.start()
        return self

    def cancel(self) -> None:
        self._timer.cancel()

    def _expire(self) -> None:
        sys.stderr.write(
            f"piezofin: tearing down the ROS entities took over {self.TEARDOWN_S:g} s (the threads' stacks "
            f"below): exiting with status {self.status}\n"
        )
        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
        sys.stderr.flush()
        os._exit(self.status)


#: a turn of a node's spin loop, or its close(), taking this long is stuck: its threads' stacks go
#: to standard error (a stopping node that does not stop is otherwise killed without a word)
STALL_S = 8.0
#: the stall watch is armed again at most this often (s), for STALL_S more: each arming wakes
#: faulthandler's thread (0.4 ms), and armed every turn it cost a node 4-5 % of a core
REARM_S = 1.0


#: Set by a console script (``entry``) whose process ends as soon as :func:`run_node` returns: the
#: garbage collection and the context's destruction at the end of the teardown are left out.  Under a
#: CI run's load the collection alone (an rclpy logger's ``__del__``) took over 3 s after the nodes had
#: closed and been destroyed, and the two-fin launch escalated to SIGTERM; the process's end frees it all.
ENDS_AFTER_RUN = False


class StopFlag:
    """SIGINT/SIGTERM set a flag that the spin loop checks between callbacks.

    rclpy's own handler chains to Python's default, which raises ``KeyboardInterrupt`` at any
    bytecode, possibly in the middle of a callback (half a block published, a bag write cut
    short).  With this flag a node always finishes the callback it is in, then closes cleanly.
    """

    def __init__(self) -> None:
        self.signal: int | None = None
        self._previous: dict[int, Any] = {}

    def install(self) -> StopFlag:
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: object) -> None:
        self.signal = signum

    def restore(self) -> None:
        """Put the previous handlers back, unless a signal came: then the process is on its way out,
        and a second SIGINT (``ros2 launch`` sends its own after the terminal's Ctrl-C) must not
        turn a clean exit into death by signal (launch's ``process has died ... exit code -2``)."""
        if self.signal is not None:  # (rclpy's shutdown may have put Python's default back)
            for sig in self._previous:
                signal.signal(sig, signal.SIG_IGN)
            return
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)

    def __bool__(self) -> bool:
        return self.signal is not None


def command_line_values(argv: Sequence[str]) -> list[tuple[str, str, str]]:
    """``(node or "", name, value)`` of every ``-p [node:]name:=value`` in the ROS arguments of ``argv``."""
    out, ros = [], False
    for k, arg in enumerate(argv):
        if arg == "--ros-args":
            ros = True
        elif arg == "--":
            ros = False
        elif ros and arg in ("-p", "--param") and k + 1 < len(argv):
            target, _, value = argv[k + 1].partition(":=")
            node, _, name = target.rpartition(":")
            out.append((node, name, value))
    return out


def command_line_parameters(argv: Sequence[str]) -> list[tuple[str, str]]:
    """``(node or "", name)`` of every ``-p [node:]name:=value`` in the ROS arguments of ``argv``."""
    return [(node, name) for node, name, _ in command_line_values(argv)]


def check_parameter_names(node: Node, argv: Sequence[str]) -> None:
    """A ``-p`` name the node does not have is an error (rclpy ignores it silently: a typo would
    run with the default).  Names for another node (``-p other:name:=...``) are left alone."""
    unknown = sorted(
        name
        for target, name in command_line_parameters(argv)
        if target in ("", node.get_name()) and not node.has_parameter(name)
    )
    if unknown:
        known = ", ".join(sorted(n for n in node._parameters if n != "use_sim_time" and "." not in n))
        raise StartupError(
            f"unknown parameter {', '.join(unknown)} for {node.get_fully_qualified_name()} "
            f"(it has: {known}, and dotted groups; `ros2 param list` shows them all)"
        )


def run_node(
    factory: Callable[[rclpy.context.Context], Any],
    args: list[str] | None = None,
    until: Callable[[Any], bool] | None = None,
    start: Callable[[Any], None] | None = None,
    after_start: Callable[[list[Any]], object] | None = None,
) -> int:
    """``ros2 run`` entry point body: init, build, spin with the EventsExecutor, clean up.

    ``factory`` builds one node or a list of nodes (one process, one executor).  Spins until
    SIGINT/SIGTERM (see :class:`StopFlag`), or until ``until(node)`` is true for every node, then
    calls each node's ``close()``.  ``start(node)`` runs for each node after its parameter names
    were checked, then ``after_start(nodes)`` once (what it returns is kept alive while spinning).
    Configuration errors exit with status 2 and one readable line; Ctrl-C and SIGTERM exit 0; a
    node that gave up (its ``exit_code`` attribute set, e.g. the recorder on a full disk) exits
    with that status.
    """
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    context = rclpy.Context()
    argv = args if args is not None else sys.argv
    rclpy.init(args=argv, context=context, signal_handler_options=SignalHandlerOptions.NO)
    _ARGV[id(context)] = argv
    stop = StopFlag().install()
    nodes: list[Any] = []
    executor = built = None
    keep: object = None
    code: int | None = None
    try:
        built = factory(context)
        nodes = list(built) if isinstance(built, (list, tuple)) else [built]
        for node in nodes:
            check_parameter_names(node, argv)
        if start is not None:
            for node in nodes:
                start(node)  # after the checks: nothing is driven with a mistyped parameter
        keep = after_start(nodes) if after_start is not None else None  # (kept alive while spinning)
        executor = EventsExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        # spin_once in a loop, not spin(): with rclpy 7.1's EventsExecutor.spin() a lifecycle
        # node's services do not answer clients in other processes (measured), spin_once does.
        armed = -math.inf
        while context.ok() and not stop and not (until is not None and all(until(n) for n in nodes)):
            # a turn of the loop that takes STALL_S (a callback or the middleware that never returns:
            # then neither SIGINT nor SIGTERM reaches the flag, and `ros2 launch` ends in SIGKILL)
            # leaves every thread's stack on standard error (armed at most every REARM_S for
            # STALL_S + REARM_S: it fires only after a turn of STALL_S at least)
            if (now := time.monotonic()) - armed >= REARM_S:
                faulthandler.dump_traceback_later(STALL_S + REARM_S)
                armed = now
            executor.spin_once(timeout_sec=0.1)
            code = next((n.exit_code for n in nodes if getattr(n, "exit_code", None) is not None), None)
            if code is not None:
                break
    except (PiezofinError, ValueError, ParameterException) as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = 2
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        faulthandler.dump_traceback_later(STALL_S)  # (and a close() that never returns)
        for node in nodes:
            close = getattr(node, "close", None)
            if close is not None:
                close()  # (what matters is done here: the drive ramped down, the bag closed)
        if code is None:
            code = next((n.exit_code for n in nodes if getattr(n, "exit_code", None) is not None), None)
        faulthandler.cancel_dump_traceback_later()
        watchdog = TeardownWatchdog(int(code or 0)).start()
        # and a backstop that needs no Python thread: a C++ destructor or the interpreter's own
        # exit can block holding the GIL (the Timer above cannot run then) with SIGINT and SIGTERM
        # ignored (see StopFlag.restore); faulthandler's watchdog thread dumps the stacks and ends
        # the process (status 1) however the teardown or the exit hangs.  Left armed: the
        # interpreter cancels it once it has exited cleanly.
        faulthandler.dump_traceback_later(2 * TeardownWatchdog.TEARDOWN_S, exit=True)
        # The executor first, then the nodes (as bringup does): destroyed while the executor still
        # held them in use, a node's entities were finalised inside the executor's shutdown, and a CI
        # run's recorder hung there (a middleware thread's callback into the executor, which held its
        # lock, against the executor waiting on the middleware), ending in the backstop's status 1.
        if executor is not None:
            executor.shutdown()
        for node in nodes:
            node.destroy_node()
        if context.ok():
            rclpy.shutdown(context=context)
        # the executor's and the nodes' destructors run here, watched, not at an unwatched return
        del keep  # (what after_start returned)
        executor = built = node = close = None  # (each holds a node: the loops' variables too)
        nodes.clear()
        if not ENDS_AFTER_RUN:  # (a console script's process ends at once: no destructor need run)
            gc.collect()
            context.destroy()  # (the context's middleware state, watched here rather than at the exit)
        watchdog.cancel()
        stop.restore()
        _ARGV.pop(id(context), None)
    return int(code) if code is not None else 0
