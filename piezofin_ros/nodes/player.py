"""``player``: replay an MCAP bag with its original timing, a rate factor, topic selection, ``/clock``.

Messages are published as the serialised bytes stored in the bag (no decode), but for an older
bag's messages where the suite's topic has another type now (a ``drive`` or an ``estimate`` recorded
as a ``std_msgs/Float64MultiArray``, a ``swim_speed`` as a ``std_msgs/Float64``): each is played as
today's type, so today's nodes hear it.  Pacing uses a steady clock: bag time
``t_bag0 + rate * (steady - steady0)``.  With ``publish_clock`` the node publishes that bag time on
``/clock`` (the bag's own ``/clock`` is not replayed), so nodes with ``use_sim_time`` follow the
recording.  An unreadable file gives one error line naming it; a file damaged part-way is played up
to the damage, which is then reported.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.time import Time
from rosgraph_msgs.msg import Clock

from ..bags import BagError, BagMessage, bag_topics, block_of, decode, read_messages, resolve_bag
from ..bags.topics import F64, F64A, SPEED, table_topic
from ..bags.types import is_record_type, normalise_type
from ..config import setting
from ._common import (
    TOPIC_CLOCK,
    StartupError,
    declare,
    endpoint,
    freeze_parameters,
    message_class,
    named_msg,
    run_node,
    speed_msg,
)
from .recorder import qos_for


@dataclass(frozen=True)
class PlayerConfig:
    """``player``'s parameters."""

    bag: str = setting("", "the .mcap file to play")
    rate: float = setting(1.0, "playback speed factor", 0.01, 1000.0)
    topics: tuple[str, ...] = setting((), "topics to play (default: all)", items=str)
    publish_clock: bool = setting(True, "publish /clock from the bag's time")


class Player(Node):
    def __init__(self, *, context: Context | None = None, node_name: str = "player", **kwargs: object):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        c = declare(self, PlayerConfig)
        self.bag_path, self.rate, topics, self.publish_clock = c.bag, c.rate, c.topics, c.publish_clock
        freeze_parameters(self)
        if not self.bag_path:
            raise StartupError("parameter bag: give the .mcap file to play (-p bag:=run.mcap)")
        self.bag_path = resolve_bag(self.bag_path)
        self._selected = set(topics) if topics else None
        try:
            first = next(read_messages(self.bag_path, self._selected, on_damage=None), None)
            types = bag_topics(self.bag_path)
        except BagError as exc:
            raise StartupError(str(exc)) from None
        if first is None:
            raise StartupError(f"{self.bag_path}: no message to play" + (f" on {topics}" if topics else ""))
        self._messages: Iterator[BagMessage] = read_messages(
            self.bag_path, self._selected, on_damage=lambda d: self.get_logger().warning(str(d))
        )
        self._next: BagMessage | None = None
        self._pubs: dict[str, Any] = {}
        self._skipped: set[str] = set()
        self._upgraded: dict[str, Any] = {}  # topic: the named message its older blocks are played as
        self._clock_pub = self.create_publisher(*endpoint(TOPIC_CLOCK)) if self.publish_clock else None
        self._steady = RosClock(clock_type=ClockType.STEADY_TIME)
        self._t_bag0 = first.log_time_ns
        self._t_wall0: int | None = None
        self.published: dict[str, int] = {}
        self.done = False
        self.error: str | None = None
        for topic, type_name in sorted(types.items()):  # all at once: `ros2 topic echo` finds them early
            if (self._selected is None or topic in self._selected) and not (
                topic == "/clock" and self.publish_clock
            ):
                self._publisher(BagMessage(topic, type_name, 0, b""))
        self._timer = self.create_timer(0.002, self._tick, clock=self._steady)
        self.get_logger().info(f"playing {self.bag_path} at x{self.rate:g}")

    def _publisher(self, m: BagMessage) -> Any:
        pub = self._pubs.get(m.topic)
        if pub is None and m.topic not in self._skipped:
            type_name = m.type_name
            table = table_topic(m.topic)
            older = normalise_type(type_name)
            if table is not None and (
                (is_record_type(table.type) and older == F64A) or (table.type == SPEED and older == F64)
            ):
                type_name = table.type
                self.get_logger().info(f"playing {m.topic} of an older bag ({older}) as {type_name}")
            try:
                pub = self.create_publisher(message_class(type_name), m.topic, qos_for(m.topic, type_name))
                self._pubs[m.topic] = pub
                if type_name != m.type_name:
                    self._upgraded[m.topic] = pub.msg_type
            except (ImportError, AttributeError, ValueError) as exc:
                self._skipped.add(m.topic)
                self.get_logger().warning(f"not playing {m.topic}: type {m.type_name} unavailable ({exc})")
        return pub

    def _upgrade(self, m: BagMessage) -> Any:
        """An older bag's message as the suite's topic is now: a block as its named message (an
        estimate stamped at its window's end, samples at their first), a speed as a ``TwistStamped``
        at the time it was recorded."""
        msg_type = self._upgraded[m.topic]
        if normalise_type(m.type_name) == F64:
            return speed_msg(msg_type, float(decode(m.type_name, m.data).data), m.log_time_ns * 1e-9)
        block = block_of(m.type_name, m.data)
        return named_msg(msg_type, block, block.scalar("t_end") if "t_end" in block.names else None)

    def _tick(self) -> None:
        if self.done:
            return
        now = self._steady.now().nanoseconds
        if self._t_wall0 is None:
            self._t_wall0 = now
        target = self._t_bag0 + round((now - self._t_wall0) * self.rate)
        try:
            while True:
                if self._next is None:
                    self._next = next(self._messages, None)
                    if self._next is None:
                        self._finish()
                        return
                m = self._next
                if m.log_time_ns > target:
                    break
                self._next = None
                if m.topic == "/clock" and self.publish_clock:
                    continue
                pub = self._publisher(m)
                if pub is not None and m.topic in self._upgraded:
                    try:
                        pub.publish(self._upgrade(m))
                    except ValueError as exc:  # (MessageError, BlockFormatError: a block it cannot read)
                        self.get_logger().warning(f"not playing a message of {m.topic}: {exc}", once=True)
                        continue
                    self.published[m.topic] = self.published.get(m.topic, 0) + 1
                elif pub is not None:
                    pub.publish(m.data)
                    self.published[m.topic] = self.published.get(m.topic, 0) + 1
        except BagError as exc:
            self.error = str(exc)
            self.get_logger().error(f"stopped: {exc}")
            self._finish()
            return
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=Time(nanoseconds=target).to_msg()))

    def _finish(self) -> None:
        self.done = True
        total = sum(self.published.values())
        self.get_logger().info(
            f"played {total} messages on {len(self.published)} topics from {self.bag_path}"
        )


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: Player(context=ctx), args, until=lambda node: getattr(node, "done", False))


if __name__ == "__main__":
    sys.exit(main())
