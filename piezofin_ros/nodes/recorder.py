"""``recorder``: the suite's topics (or a chosen set) to an MCAP file rosbag2 can play.

Subscriptions are *raw* (rclpy hands over the CDR bytes), so nothing is deserialised or
serialised again: each message goes straight into :class:`~piezofin_ros.bags.writer.BagWriter` with
the node clock's time (the simulated time under ``use_sim_time``).  A topic's channel is written
at its first message, with the QoS its publishers offer then (``ros2 bag play`` offers the same).
Chunks are flushed every ``flush_s`` of log time; SIGINT or SIGTERM closes the file with its
summary, indexes and rosbag2 metadata.

For plotting (Foxglove, PlotJuggler), the one-sample ``cmd`` block is also written field by field
as ``std_msgs/msg/Float64`` channels named ``<topic>/<field>`` (e.g. ``/fin/cmd/voltage_pp_V``): a
series with a name, where the block itself is an array.  These ``plot_fields`` are written to the
bag only, never published.  The ``estimate`` needs none: it is named field by field itself
(``piezofin_msgs/Estimate``).
"""

from __future__ import annotations

import collections
import json
import struct
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import String

from ..bags import BagWriter, block_of, message_definition, normalise_type, qos_profile
from ..bags.gaps import Gap, GapWatch
from ..bags.topics import F64, F64A, SAMPLED, STRING, TOPICS, table_topic
from ..bags.types import is_record_type
from ..config import setting
from ._common import (
    QOS,
    QOS_CLOCK,
    QOS_COMMAND,
    QOS_DATA,
    QOS_STATUS,
    TOPIC_CMD,
    StartupError,
    declare,
    freeze_parameters,
    helper_node,
    message_class,
    never,
    reliability_of,
    run_node,
)
from ._diagnostics import ERROR, OK, Diagnostics, Report

#: The suite's topics per fin (relative names) with their types, and the global ones: as the topic
#: table records them.
SUITE_TOPICS = {n: t.type for n, t in TOPICS.items() if t.recorded and not n.startswith("/")}
GLOBAL_TOPICS = {n: t.type for n, t in TOPICS.items() if t.recorded and n.startswith("/")}


def qos_for(topic: str, type_name: str) -> Any:
    """The QoS a topic is played with: its profile in the topic table when it is one of the suite's
    (of that type), else the data profile for blocks and the command profile for the rest."""
    if topic == "/clock":
        return QOS_CLOCK
    table = table_topic(topic)
    if table is not None and table.type == normalise_type(type_name):
        return QOS[table.qos]
    return QOS_DATA if type_name == F64A else QOS_COMMAND


#: Every topic but ``/clock`` is polled, never queued in the executor: each look takes at most so many
#: messages of each topic, so a flood on one cannot hold the recorder from the others.
POLL_S = 0.01
POLL_MOST = 20  # a look: 2,000 messages a second per topic (a fish's speed at x10: 200)
POLL_DEPTH = 200
#: The sampled topics (sample blocks): a deeper queue, and more a look (fin_sim at x40: 800 blocks/s).
SAMPLED_DEPTH = 500
SAMPLED_MOST = 50
#: Full looks in a row that mean a topic comes faster than it is kept (a backlog drains in fewer).
THIN_LOOKS = 20


#: Topics (relative) whose one-sample blocks are also written field by field, for plotting.
PLOT_TOPICS = (TOPIC_CMD,)
FLOAT64 = F64
_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation header, little endian


def string_cdr(text: str) -> bytes:
    """A serialised ``std_msgs/msg/String``."""
    raw = text.encode()
    return _CDR_LE + struct.pack("<I", len(raw) + 1) + raw + b"\0"


def float64_cdr(value: float) -> bytes:
    """A serialised ``std_msgs/msg/Float64``."""
    return _CDR_LE + struct.pack("<d", value)


def offered_qos(endpoints: list[Any]) -> list[dict[str, Any]]:
    """rosbag2's offered_qos_profiles from ``get_publishers_info_by_topic``."""

    def ns(d: Any) -> int:
        return int(d.nanoseconds)

    out = []
    for e in endpoints:
        q = e.qos_profile
        out.append(
            qos_profile(
                reliability=q.reliability.name.lower(),
                durability=q.durability.name.lower(),
                history=q.history.name.lower(),
                depth=q.depth,
                deadline_ns=ns(q.deadline),
                lifespan_ns=ns(q.lifespan),
                liveliness=q.liveliness.name.lower(),
                liveliness_lease_duration_ns=ns(q.liveliness_lease_duration),
                avoid_ros_namespace_conventions=q.avoid_ros_namespace_conventions,
            )
        )
    return out


def default_bag_path(directory: str = "bags") -> Path:
    """``bags/piezofin_YYYYmmdd-HHMMSS.mcap`` (local time at start; a new name every second)."""
    return Path(directory) / time.strftime("piezofin_%Y%m%d-%H%M%S.mcap")


@dataclass(frozen=True)
class RecorderConfig:
    """``recorder``'s parameters."""

    path: str = setting("", "output .mcap file (default bags/piezofin_<time>.mcap); never overwritten")
    topics: tuple[str, ...] = setting(
        (), "topics to record (default: the suite's), name or name:type", items=str
    )
    namespaces: tuple[str, ...] = setting((), "fins to record (default: this node's namespace)", items=str)
    compression: str = setting("zstd", "chunk compression: zstd, lz4 or none")
    chunk_kib: int = setting(1024, "chunk size, KiB", 16, 65536)
    flush_s: float = setting(1.0, "longest log time between chunk flushes, s", 0.05, 600.0)
    discover: bool = setting(False, "also record any other topic that appears")
    plot_fields: bool = setting(True, "also write cmd field by field (Float64) for plotting")


class Recorder(Node):
    def __init__(self, *, context: Context | None = None, node_name: str = "recorder", **kwargs: object):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        c = declare(self, RecorderConfig)
        path, topics, namespaces, compression = c.path, c.topics, c.namespaces, c.compression
        chunk_kib, flush_s, self.discover, self.plot_fields = (
            c.chunk_kib,
            c.flush_s,
            c.discover,
            c.plot_fields,
        )
        freeze_parameters(self)
        self.path = Path(path) if path else default_bag_path()
        try:
            self.bag = BagWriter(
                self.path,
                compression=compression,
                chunk_size=chunk_kib * 1024,
                flush_s=flush_s,
                metadata={"fin_namespaces": ",".join(namespaces)},
            )
        except FileExistsError:
            raise StartupError(
                f"parameter path: {self.path} exists; the recorder never overwrites a bag"
            ) from None
        except (ValueError, OSError) as exc:
            raise StartupError(f"cannot open the bag {self.path}: {exc}") from None
        self._subs: dict[str, Any] = {}
        self._types: dict[str, str] = {}
        self._plot = {f"{p}/{t}" for p in self._prefixes(namespaces) for t in PLOT_TOPICS}
        self._untyped: set[str] = set()
        self._early: list[tuple[str, bytes]] = []
        self.received: collections.Counter[str] = collections.Counter()  # messages taken, per topic
        # samples that never reached the recorder (a flood starved its queue): found, kept, said
        self.gaps = GapWatch()
        self._sampled = {f"{p}/{t}" for p in self._prefixes(namespaces) for t in SAMPLED}
        self._gap_topic = f"{self.get_fully_qualified_name()}/gaps"
        self._unsaid: list[Gap] = []
        self._helper: Node | None = None
        self._polled: list[str] = []  # topics taken by _poll, in the order they were added
        self._full_looks: collections.Counter[str] = collections.Counter()  # in a row, per polled topic
        self._thinned: collections.Counter[str] = collections.Counter()  # looks past THIN_LOOKS in a row
        self._thinned_said: dict[str, int] = {}
        self._status_pub = self.create_publisher(String, "~/status", QOS_STATUS)
        self.create_timer(1.0, self._report, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.exit_code: int | None = None  # set when recording had to stop (run_node exits with it)
        wanted = self._wanted(topics, namespaces)
        for topic, type_name in wanted.items():
            self.add_topic(topic, type_name)
        self.create_timer(0.5, self._discover)
        self.diagnostics = Diagnostics(self, str(self.path))
        self.diagnostics.add("bag", self._diagnose)
        self.get_logger().info(f"recording {len(self._subs)} topics to {self.path}")

    def _diagnose(self) -> Report:
        total = sum(self.bag.counts.values())
        values = {"path": self.path, "messages": total, "topics": len(self.bag.counts)}
        if self.exit_code is not None:
            return Report(ERROR, f"cannot write to {self.path}: recording stopped", values)
        return Report(OK, f"recording {total} messages on {len(self.bag.counts)} topics", values)

    def _wanted(self, topics: Sequence[str], namespaces: Sequence[str]) -> dict[str, str]:
        if topics:
            out = {}
            for entry in topics:
                name, _, type_name = entry.partition(":")
                out[self.resolve_topic_name(name)] = type_name or ""
            return out
        out = {f"{p}/{t}": ty for p in self._prefixes(namespaces) for t, ty in SUITE_TOPICS.items()}
        out.update(GLOBAL_TOPICS)
        return out

    def _prefixes(self, namespaces: Sequence[str]) -> list[str]:
        prefixes = [ns.rstrip("/") if ns.startswith("/") else "/" + ns.strip("/") for ns in namespaces]
        return prefixes or [self.get_namespace().rstrip("/")]

    def add_topic(self, topic: str, type_name: str = "") -> bool:
        """Subscribe to ``topic`` (type looked up in the graph when not given); False if unknown yet."""
        if topic in self._subs:
            return True
        if not type_name:
            types = dict(self.get_topic_names_and_types()).get(topic)
            if not types:
                if topic not in self._untyped:
                    self.get_logger().info(f"{topic}: type not known yet, waiting for a publisher")
                self._untyped.add(topic)
                return False
            type_name = types[0]
        try:
            cls = message_class(type_name)
            message_definition(type_name)  # in the type store: the bag can describe it
        except (ImportError, AttributeError, ValueError) as exc:
            self.get_logger().error(f"cannot record {topic}: {exc}")
            return False
        self._untyped.discard(topic)
        self._types[topic] = normalise_type(type_name)
        kind = normalise_type(type_name)
        if topic != "/clock":
            self._subs[topic] = self._polled_subscription(cls, topic)
            return True
        self._subs[topic] = self.create_subscription(
            cls,
            topic,
            partial(self._write, topic),
            qos_for(topic, kind),
            raw=True,
        )
        return True

    def _polled_subscription(self, cls: Any, topic: str) -> Any:
        """A topic taken by a poll every :data:`POLL_S` s of wall time, at most :data:`POLL_MOST`
        messages a look (:data:`SAMPLED_MOST` for sample blocks), from a queue in the middleware
        (:data:`POLL_DEPTH`, :data:`SAMPLED_DEPTH` deep).

        The executor never sees these messages, so a flood on one topic (10 kHz of ``swim_speed``)
        cannot queue up in front of the others' (it cost 42 s of drive samples at x10): the recorder
        keeps up to its share of the flooded topic a second, the rest is dropped and said once a
        second, and a hole in a sampled topic is found and kept (:class:`GapWatch`)."""
        if self._helper is None:
            self._helper = helper_node(self, "poll")
            self.create_timer(POLL_S, self._poll, clock=Clock(clock_type=ClockType.STEADY_TIME))
        depth = SAMPLED_DEPTH if topic in self._sampled else POLL_DEPTH
        qos = QoSProfile(depth=depth, reliability=reliability_of(topic))
        self._polled.append(topic)
        return self._helper.create_subscription(cls, topic, never, qos, raw=True)

    def _poll(self, drain: bool = False) -> None:
        """A look at each polled topic; ``drain``: take everything waiting (the last look, at close)."""
        for topic in self._polled:
            sub = self._subs[topic]
            for _ in range(self._most(topic) if not drain else 2 * SAMPLED_DEPTH):  # (bounded: a flood)
                with sub.handle:
                    taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    self._full_looks[topic] = 0
                    break
                self._write(topic, taken[0])
            else:  # a full look: more may be waiting; many in a row, and the queue overflows
                self._full_looks[topic] += 1
                if self._full_looks[topic] >= THIN_LOOKS:
                    self._thinned[topic] += 1

    def _most(self, topic: str) -> int:
        return SAMPLED_MOST if topic in self._sampled else POLL_MOST

    def _discover(self) -> None:
        for topic in list(self._untyped):
            self.add_topic(topic)
        if not self.discover:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic not in self._subs and types and not topic.endswith(("/transition_event", "/rosout")):
                self.add_topic(topic, types[0])

    def _write(self, topic: str, data: bytes) -> None:
        self.received[topic] += 1
        if self.bag.closed:
            return
        now = self.get_clock().now().nanoseconds
        if now == 0:  # use_sim_time and no /clock yet: keep the message until time starts
            self._early.append((topic, data))
            return
        try:
            if self._early:
                for early_topic, early_data in self._early:
                    self._record(early_topic, now, early_data)
                self._early.clear()
            self._record(topic, now, data)
        except OSError as exc:
            self._give_up(exc)

    def _record(self, topic: str, time_ns: int, data: bytes) -> None:
        if not self.bag.has_topic(topic):  # the first message: its publishers are known now
            qos = offered_qos(self.get_publishers_info_by_topic(topic))
            self.bag.add_topic(topic, self._types[topic], qos)
        self.bag.write(topic, time_ns, data)
        if topic in self._sampled:
            try:
                gap = self.gaps.see(topic, data, named=is_record_type(self._types[topic]))
            except (ValueError, ArithmeticError):  # (what another process sent: recorded, not judged)
                gap = None
            if gap is not None:
                self._keep_gap(gap, time_ns)
        if self.plot_fields and topic in self._plot:
            self._record_fields(topic, time_ns, data)

    def _record_fields(self, topic: str, time_ns: int, data: bytes) -> None:
        try:
            block = block_of(self._types[topic], data)
        except (
            ValueError,
            ArithmeticError,
        ):  # MessageError, BlockFormatError: whatever another node published
            return  # not a block: the message itself is recorded, there is nothing to plot
        if block.n != 1:
            return
        for name, value in zip(block.names, block.values[:, 0], strict=True):
            field = f"{topic}/{name}"
            if not self.bag.has_topic(field):
                self.bag.add_topic(field, FLOAT64)  # never published: no QoS offered
            self.bag.write(field, time_ns, float64_cdr(float(value)))

    def _keep_gap(self, gap: Gap, time_ns: int) -> None:
        """A hole in a sampled topic: in the bag at once (``<recorder>/gaps``), said within a second."""
        if not self.bag.has_topic(self._gap_topic):
            self.bag.add_topic(self._gap_topic, STRING)  # never published: no QoS offered
        self.bag.write(self._gap_topic, time_ns, string_cdr(gap.to_json()))
        self._unsaid.append(gap)

    def _report(self) -> None:
        """At most once a second: the holes found since the last report, and the status on change."""
        if self._unsaid:
            lost = collections.Counter[str]()
            for g in self._unsaid:
                lost[g.topic] += g.samples
            span = f"fin time {self._unsaid[0].from_t_s:.2f}-{self._unsaid[-1].to_t_s:.2f} s"
            self.get_logger().warning(
                f"lost {sum(lost.values())} samples in {len(self._unsaid)} hole(s) ("
                + ", ".join(f"{t} {n}" for t, n in sorted(lost.items()))
                + f"; {span}): they never reached the recorder (its queue overflowed: a flood on "
                f"another topic?); each hole is in the bag on {self._gap_topic}"
            )
            self._unsaid.clear()
        for topic, full in self._thinned.items():
            if full != self._thinned_said.get(topic, 0):
                self._thinned_said[topic] = full
                rate = self._most(topic) / POLL_S
                self.get_logger().warning(
                    f"{topic} comes faster than {rate:.0f} messages a second (a flood?): kept that many a "
                    f"second, the rest was dropped ({full * POLL_S:.1f} s of it so far)"
                )
        # (every look, changed or not: a `ros2 topic echo --once` that joins before its node has
        # discovered this publisher asks a volatile profile, and would wait for the next change)
        self._status_pub.publish(String(data=json.dumps(self.status(), sort_keys=True)))

    def status(self) -> dict[str, Any]:
        """The bag, its messages, and the samples it lost (per topic) with the holes they were in."""
        return {
            "path": str(self.path),
            "recording": not self.bag.closed,
            "messages": sum(self.bag.counts.values()),
            "per_topic": dict(sorted(self.bag.counts.items())),
            "lost_samples": dict(sorted(self.gaps.lost.items())),
            "holes": sum(self.gaps.holes.values()),
            "thinned": dict(sorted(self._thinned.items())),  # topics that came faster than kept
        }

    def _give_up(self, exc: OSError) -> None:
        """A write failed (disk full, file-size limit, I/O error): stop recording, say so, exit 1.
        What was flushed before stays readable (``piezofin bag recover``)."""
        self.get_logger().error(
            f"cannot write to {self.path} ({exc.strerror or exc}): recording stopped; the file holds "
            f"what was flushed before (`piezofin bag recover {self.path}` makes it a complete bag)"
        )
        self.bag.abandon()
        self.exit_code = 1
        self.diagnostics.update()

    def destroy_node(self) -> None:
        if self._helper is not None:
            self._helper.destroy_node()
            self._helper = None
        super().destroy_node()

    @property
    def counts(self) -> dict[str, int]:
        return dict(self.bag.counts)

    def close(self) -> None:
        if not self.bag.closed:
            try:
                self._poll(drain=True)  # what came since the last look is kept too
                for topic, data in self._early:  # the clock never started: keep them at time 0
                    self._record(topic, 0, data)
                self.bag.set_custom("lost_samples", json.dumps(dict(sorted(self.gaps.lost.items()))))
                self.bag.close()
            except OSError as exc:
                self._give_up(exc)
                return
            total = sum(self.bag.counts.values())
            lost = self.gaps.total_lost
            holes = sum(self.gaps.holes.values())
            said = (
                f"; lost {lost} samples in {holes} hole(s) (on {self._gap_topic})"
                if lost
                else ", no sample lost"
            )
            self.get_logger().info(
                f"closed {self.path}: {total} messages on {len(self.bag.counts)} topics{said}"
            )


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: Recorder(context=ctx), args)


if __name__ == "__main__":
    sys.exit(main())
