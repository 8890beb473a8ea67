"""``/diagnostics`` for every node: what rqt_robot_monitor and the diagnostic aggregators read.

``diagnostic_updater`` (C++ and Python) is not among the ``ros-jazzy-*`` wheels, so this is the small
part of it the nodes need, with its conventions: one ``diagnostic_msgs/DiagnosticArray`` on the
absolute ``/diagnostics`` (whatever the node's namespace) about once a second of wall time (the
steady clock: a node on ``use_sim_time`` whose ``/clock`` stopped, its fin_sim gone, still reports),
stamped on the node's clock (the fin's time),
one ``DiagnosticStatus`` per task named ``"<node name>: <task>"`` with the node's ``hardware_id`` (the
fin it drives or estimates), at OK, WARN, ERROR or STALE, and every figure as a ``KeyValue``.  A task
whose level changes is published at once (:meth:`Diagnostics.update`), not at the next second: a
watchdog trip is on the monitor within the tick that saw it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.time import Time

from ._common import QOS_DIAGNOSTICS, TOPIC_DIAGNOSTICS, endpoint  # noqa: F401 (re-exported)

OK, WARN, ERROR, STALE = (int.from_bytes(x, "little") if isinstance(x, bytes) else int(x) for x in (
    DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE
))  # fmt: skip
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}


@dataclass(frozen=True)
class Report:
    """One task's state: its level, one sentence, and its figures (any values; shown as text)."""

    level: int
    message: str
    values: Mapping[str, Any] = field(default_factory=dict)


def _text(x: Any) -> str:
    if isinstance(x, float):
        return "nan" if math.isnan(x) else f"{x:.6g}"
    return str(x)


class Diagnostics:
    """A node's tasks on ``/diagnostics`` (module docstring).  ``add(task, check)`` with ``check()``
    returning a :class:`Report`; the node calls :meth:`update` where a state may have changed."""

    def __init__(
        self, node: Node, hardware_id: str, period_s: float = 1.0, stamp: Callable[[], float] | None = None
    ) -> None:
        from rclpy.clock import Clock, ClockType

        self._node = node
        self._stamp = stamp  # the stamp, s (None: the node's clock)
        self.hardware_id = hardware_id
        self._tasks: list[tuple[str, Callable[[], Report]]] = []
        self._levels: dict[str, int] = {}
        self._looked = -math.inf  # (time.monotonic) the last look of update()
        self._pub = node.create_publisher(*endpoint(TOPIC_DIAGNOSTICS))
        self._timer = node.create_timer(period_s, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def add(self, task: str, check: Callable[[], Report]) -> None:
        self._tasks.append((task, check))

    @staticmethod
    def _report(check: Callable[[], Report]) -> Report:
        try:
            return check()
        except Exception as exc:  # (a check that fails is an error shown, never a node's end)
            return Report(ERROR, f"the check failed: {type(exc).__name__}: {exc}")

    def _statuses(self) -> list[DiagnosticStatus]:
        out = []
        name = self._node.get_name()
        for task, check in self._tasks:
            r = self._report(check)
            self._levels[task] = r.level
            out.append(
                DiagnosticStatus(
                    level=bytes([r.level]),
                    name=f"{name}: {task}",
                    message=r.message,
                    hardware_id=self.hardware_id,
                    values=[KeyValue(key=str(k), value=_text(v)) for k, v in r.values.items()],
                )
            )
        return out

    def publish(self) -> None:
        """All tasks now (the timer's call)."""
        if not self._tasks:
            return
        msg = DiagnosticArray(status=self._statuses())
        now = (
            self._node.get_clock().now()
            if self._stamp is None
            else Time(nanoseconds=max(0, round(self._stamp() * 1e9)))
        )
        msg.header.stamp = now.to_msg()
        self._pub.publish(msg)

    #: :meth:`update` looks at most this often (wall time): fin_sim calls it with each block, 800 a
    #: second at x40, and a level change still reaches the monitor within a tenth of a second
    LOOK_S = 0.1

    def update(self) -> None:
        """Publish now if any task's level changed since it was last published."""
        now = time.monotonic()
        if now - self._looked < self.LOOK_S:
            return
        self._looked = now
        if any(self._levels.get(task) != self._report(check).level for task, check in self._tasks):
            self.publish()
