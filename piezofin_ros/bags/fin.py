"""One fin's topics in a bag, read in one place: the topic names of the nodes' contract, and one
pass that decodes and checks each message, counting (and describing, up to a bound) what it skips.

Every reader of a fin's recording goes through :func:`read_fin`: the estimator's offline replay,
the diagnosis' noise scan (both in one pass, :func:`read_fin` feeding several consumers), the
identification's stepped sine and the campaign's time trace.  A sampled topic's block is checked
(:func:`~.blocks.check_samples`) and holds its channels only (a ``Float64MultiArray`` block of an
older bag, or a named one); a command keeps its fields; ``swim_speed`` gives its value and stamp
(a ``geometry_msgs/TwistStamped``, or an older bag's unstamped ``std_msgs/Float64``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field

from .blocks import COMMAND_FIELDS, COMMAND_OPTIONAL, Block, BlockFormatError, check_samples
from .reader import Damage, read_messages
from .topics import (  # noqa: F401 (re-exported: a reader of a fin's bag needs the names too)
    SAMPLED,
    TOPIC_CMD,
    TOPIC_DEMAND,
    TOPIC_DRIVE,
    TOPIC_ESTIMATE,
    TOPIC_LOADCELL,
    TOPIC_SPEED,
    TOPIC_STATUS,
    TOPIC_SUPPLY,
    TOPIC_TIP,
    topic_prefix,
)
from .types import MessageError, block_of, decode

#: Skipped messages are counted; only this many lines describing them are kept.
MAX_SKIPPED_LINES = 100


@dataclass(frozen=True)
class FinMessage:
    """One usable message of a fin: its topic ``kind`` (relative to the namespace, e.g. ``"drive"``),
    its log time, and its content: a :class:`~.blocks.Block` or, for ``swim_speed``, a value and the
    time it was measured (its stamp, s; NaN in bags before the speed was stamped)."""

    kind: str
    time_ns: int
    block: Block | None = None
    value: float = float("nan")
    stamp_s: float = float("nan")


@dataclass
class Skipped:
    """What a read could not use: counted, and the first :data:`MAX_SKIPPED_LINES` described."""

    count: int = 0
    lines: list[str] = field(default_factory=list)

    def add(self, topic: str, time_ns: int, why: object) -> None:
        self.count += 1
        if len(self.lines) < MAX_SKIPPED_LINES:  # memory bounded by what is kept, whatever the file
            self.lines.append(f"{topic} at {time_ns * 1e-9:.3f} s: {why}")


def read_fin(
    path: str | os.PathLike[str],
    namespace: str,
    kinds: Iterable[str],
    *,
    skipped: Skipped | None = None,
    on_damage: Callable[[Damage], None] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Iterator[FinMessage]:
    """The usable messages of ``kinds`` (topics relative to ``namespace``) in recording order.

    A message that does not decode or fails its check is left out and added to ``skipped``; each
    damage of the file goes to ``on_damage`` (default: a logged warning); ``progress`` hears which
    split of a rosbag2 directory is being read.
    """
    ns = topic_prefix(namespace)
    topics = {f"{ns}/{k}": k for k in kinds}
    extra: dict[str, object] = {"progress": progress}
    if on_damage is not None:
        extra["on_damage"] = on_damage
    for m in read_messages(path, topics, **extra):  # type: ignore[arg-type]
        kind = topics[m.topic]
        try:
            if kind == TOPIC_SPEED:
                msg = decode(m.type_name, m.data)
                if hasattr(msg, "twist"):  # geometry_msgs/TwistStamped (a std_msgs/Float64 before)
                    stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                    speed = float(msg.twist.linear.x)
                    yield FinMessage(
                        kind, m.log_time_ns, value=speed, stamp_s=stamp if stamp > 0 else math.nan
                    )
                else:
                    yield FinMessage(kind, m.log_time_ns, value=float(msg.data))
                continue
            if kind == TOPIC_CMD:
                block = block_of(m.type_name, m.data, expect=COMMAND_FIELDS, optional=COMMAND_OPTIONAL)
            elif kind in SAMPLED:
                block = check_samples(block_of(m.type_name, m.data), SAMPLED[kind])
            else:
                block = block_of(m.type_name, m.data)
        except (BlockFormatError, MessageError, KeyError, ValueError, IndexError, AttributeError) as exc:
            if skipped is not None:
                skipped.add(m.topic, m.log_time_ns, exc)
            continue
        yield FinMessage(kind, m.log_time_ns, block)
