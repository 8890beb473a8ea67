"""``/diagnostics`` as rqt_robot_monitor reads it (issue 41): a clamp, a silent estimator and a
watchdog trip, each caused from another process, each on the monitor within 2 s at its level."""

from __future__ import annotations

import signal
import time

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray

from piezofin_ros.nodes._diagnostics import ERROR, LEVEL_NAMES, OK, QOS_DIAGNOSTICS, STALE, WARN
from piezofin_ros.nodes.controller import ESTIMATES_STALE_S

from ..rosutil import graph, start, start_driving_controller, stop

pytestmark = pytest.mark.ros


class Monitor:
    """What a monitor last read of each status, and when each level was first seen."""

    def __init__(self) -> None:
        self.latest: dict[str, tuple[int, str, str, dict[str, str]]] = {}
        self.first: dict[tuple[str, int], float] = {}
        self.arrays = 0

    def take(self, msg: DiagnosticArray) -> None:
        self.arrays += 1
        for s in msg.status:
            level = s.level[0] if isinstance(s.level, bytes) else int(s.level)
            self.latest[s.name] = (level, s.message, s.hardware_id, {kv.key: kv.value for kv in s.values})
            self.first.setdefault((s.name, level), time.monotonic())

    def level(self, name: str) -> int | None:
        return self.latest[name][0] if name in self.latest else None

    def said(self) -> str:
        return "\n".join(f"{n}: {LEVEL_NAMES[v[0]]} {v[1]}" for n, v in sorted(self.latest.items()))


@pytest.mark.slow
def test_a_clamp_a_silent_estimator_and_a_watchdog_trip_each_reach_the_monitor_at_its_level() -> None:
    sim = start(
        "fin_sim",
        "-r",
        "__ns:=/dg",
        "-p",
        "limits.voltage_pp_max:=400.0",
        "-p",
        "limits.command_timeout_s:=0.5",
    )
    est = start("thrust_estimator", "-r", "__ns:=/dg")
    # 800 Vpp asked (fin_sim clamps it to 400), and held after its trial (the drive stays on)
    ctl = start_driving_controller("dg", "-p", "after:=hold")
    mon = Monitor()
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("monitor", context=g.context))
            node.create_subscription(DiagnosticArray, "/diagnostics", mon.take, QOS_DIAGNOSTICS)
            drive, monitor = "fin_sim: drive", "fin_sim: voltage monitor"
            estimates, ctl_drive = "controller: estimates", "controller: drive"
            g.spin_until(
                lambda: mon.level(drive) == WARN and mon.level(estimates) == OK,
                timeout=60.0,
                what="fin_sim's clamp (WARN) and the controller's estimates (OK)",
            )
            _, message, hardware, values = mon.latest[drive]
            assert message.startswith("clamped: 800 Vpp above the limit"), message
            assert hardware == "M8528-P1" and values["limits.voltage_pp_max"] == "400"
            assert mon.level(monitor) == OK and mon.level("thrust_estimator: estimates") == OK
            assert mon.level(ctl_drive) == OK

            est.send_signal(signal.SIGKILL)  # the estimator falls silent
            killed = time.monotonic()
            est.wait(timeout=10)
            g.spin_until(
                lambda: mon.level(estimates) == STALE, timeout=ESTIMATES_STALE_S + 10.0, what="STALE"
            )
            took = mon.first[(estimates, STALE)] - killed
            assert took <= ESTIMATES_STALE_S + 2.0, (took, mon.said())
            assert "is thrust_estimator running?" in mon.latest[estimates][1]

            ctl.send_signal(signal.SIGKILL)  # no more commands: the watchdog trips
            killed = time.monotonic()
            ctl.wait(timeout=10)
            assert mon.level(ctl_drive) == OK, mon.said()  # (its trial, or the point it holds)
            g.spin_until(lambda: mon.level(drive) == ERROR, timeout=20.0, what="the watchdog trip (ERROR)")
            took = mon.first[(drive, ERROR)] - killed
            assert took <= 1.0 + 2.0, (took, mon.said())  # (a trip waits at least 1 s of wall time)
            assert "watchdog tripped" in mon.latest[drive][1]
            assert mon.latest[drive][3]["tripped"] == "True"
            g.spin_for(2.5)  # about once a second, with the trip still said
            arrays = mon.arrays
            g.spin_for(2.0)
            assert mon.arrays >= arrays + 1 and mon.level(drive) == ERROR
    finally:
        outs = stop(sim, est, ctl)
    assert not any("Traceback" in o for o in outs), outs


@pytest.mark.slow
def test_an_estimator_with_no_driver_says_so_in_its_log_and_on_the_monitor(tmp_path) -> None:
    """``sim:=false`` with no rig driver: 35 s went by without a word.  Now the estimator's status is
    STALE from its first second, and its log says within 10 s that nothing publishes its drive."""
    log = tmp_path / "estimator.log"
    est = start("thrust_estimator", "-r", "__ns:=/nodriver", log=log)
    mon = Monitor()
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("monitor", context=g.context))
            node.create_subscription(DiagnosticArray, "/diagnostics", mon.take, QOS_DIAGNOSTICS)
            name = "thrust_estimator: estimates"
            g.spin_until(lambda: mon.level(name) == STALE, timeout=60.0, what="the estimator's STALE")
            assert mon.latest[name][1] == "waiting for the first block on /nodriver/drive", mon.said()
            g.spin_until(lambda: "no publisher" in log.read_text(), timeout=40.0, what="the warning")
    finally:
        stop(est)
    said = log.read_text()
    assert "[WARN]" in said and "/nodriver/drive: nothing, and no publisher, after 10 s" in said, said
