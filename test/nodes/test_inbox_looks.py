"""How often a node's inbox looks at its polled topics, when it looks in the node's own time
(``Inbox(node_time_s=...)``: the controller, the estimator, the speed loop, the waypoint follower).

Each look wakes the executor: 100 a second of wall time cost a fish's controller about 2 % of a core
and took it over its footprint goal (CI, 2026-11-29: 10.9 % against 10).  In the fish's time a look
every 50 ms is what its 10 Hz loops need, so on a fish in real time it looks 20 times a second; in a
simulation at x10 on ``use_sim_time`` it looks as often as 100 times a second of wall time (the yaw
loop's offset late by 0.5 s of fish time at 20 looks made the turn fall 16 % short); and when the
clock stops (fin_sim gone, a frozen ``/clock``) or goes back, it goes on looking 20 times a second.
Real rclpy nodes on real DDS; the clock is published by another node.
"""

from __future__ import annotations

import time
from typing import Any

import pytest
import rclpy
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64

from piezofin_ros.errors import NodeError
from piezofin_ros.nodes._common import Inbox

from ..rosutil import graph

pytestmark = [pytest.mark.ros]  # (a loaded machine's timers fire late: fewer looks, never more)


def looks_per_second(g: Any, box: Inbox, seconds: float, during: Any = None) -> float:
    """The looks a second of wall time over ``seconds`` (``during()`` called between spins)."""
    counted = [0]
    poll = box._poll

    def counting() -> None:
        counted[0] += 1
        poll()

    box._timer.callback = counting
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if during is not None:
            during()
        g.executor.spin_once(timeout_sec=0.005)
    box._timer.callback = poll
    return counted[0] / (time.monotonic() - t0)


@pytest.mark.slow
@pytest.mark.exclusive  # (a rate of timers: at a load of 15 in CI's first phase, 49 looks a second at x10)
def test_a_node_in_real_time_looks_every_50_ms_and_a_simulation_at_x10_every_10_ms() -> None:
    with graph() as g:
        node = g.add(rclpy.create_node("looker", context=g.context))
        box = Inbox(node, node_time_s=Inbox.NODE_TIME_S)
        got: list[float] = []
        box.latest(Float64, "looked_at", lambda m: got.append(m.data))
        fast = looks_per_second(g, box, 0.8)  # (from the most often, until the rate is measured)
        looks_per_second(g, box, 0.5)  # (the rate measured after a second)
        settled = looks_per_second(g, box, 3.0)
        print(f"real time: {fast:.0f} looks a second at the start, {settled:.1f} after")
        assert fast > 50 and 15 < settled < 22, (fast, settled)
        pub = node.create_publisher(Float64, "looked_at", 10)
        pub.publish(Float64(data=1.5))
        g.spin_until(lambda: got == [1.5], 2.0, "a message taken at the slower looks")

        sim = g.add(
            rclpy.create_node(
                "sim_looker",
                context=g.context,
                parameter_overrides=[Parameter("use_sim_time", Parameter.Type.BOOL, True)],
            )
        )
        clock_node = g.add(rclpy.create_node("clock_x10", context=g.context))
        clock = clock_node.create_publisher(Clock, "/clock", 10)
        sim_box = Inbox(sim, node_time_s=Inbox.NODE_TIME_S)
        sim_box.latest(Float64, "looked_at", lambda m: None)
        start, t_sim = time.monotonic(), [1000.0]

        def tick(rate: float) -> None:  # the clock, advancing ``rate`` times the wall, at 100 Hz
            now = time.monotonic()
            if now - tick.last < 0.01:  # type: ignore[attr-defined]
                return
            t_sim[0] += rate * (now - tick.last)  # type: ignore[attr-defined]
            tick.last = now  # type: ignore[attr-defined]
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = int(t_sim[0]), int((t_sim[0] % 1) * 1e9)
            clock.publish(msg)

        tick.last = start  # type: ignore[attr-defined]
        looks_per_second(g, sim_box, 1.5, lambda: tick(10.0))
        x10 = looks_per_second(g, sim_box, 2.5, lambda: tick(10.0))
        looks_per_second(g, sim_box, 1.5, lambda: tick(0.0))
        frozen = looks_per_second(g, sim_box, 2.5, lambda: tick(0.0))
        looks_per_second(g, sim_box, 1.5, lambda: tick(-3.0))
        backwards = looks_per_second(g, sim_box, 2.5, lambda: tick(-3.0))
        print(f"x10: {x10:.0f} looks a second; frozen: {frozen:.1f}; backwards: {backwards:.1f}")
        assert 50 < x10 <= 105, x10
        assert 15 < frozen < 22 and 15 < backwards < 22, (frozen, backwards)


def test_a_node_may_not_look_less_often_in_its_time_than_in_the_walls() -> None:
    with graph() as g:
        node = g.add(rclpy.create_node("looker_wrong", context=g.context))
        with pytest.raises(NodeError, match="node_time_s"):
            Inbox(node, 0.1, node_time_s=0.05)
