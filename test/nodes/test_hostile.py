"""A hostile or careless graph: no parameter, clock, lifecycle call or timing can defeat the drive's safety.

Every attack comes from another process, as a node of the graph would make it: ``fin_sim`` is
started as ``ros2 run`` starts it, and this process is the attacker (commands, parameter
service, ``/clock``, lifecycle service) and the witness (every drive sample it publishes).
Each test covers a class of attack, not the one value that was found.
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from piezofin_msgs.msg import Estimate as EstimateMsg
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Float64MultiArray

from piezofin_ros.bags.blocks import Block
from piezofin_ros.nodes._common import (
    QOS_CLOCK,
    QOS_COMMAND,
    QOS_DATA,
    QOS_STATUS,
    block_msg,
    msg_block,
    record_msg,
    speed_msg,
)

from ..rosutil import Graph, data_type, graph, start, start_driving_controller, stop

pytestmark = pytest.mark.ros
QUIET = 8.0  # V: 1 % of the 800 Vpp drive's amplitude (400 V)
SAMPLE_BAG = __import__("pathlib").Path(__file__).resolve().parents[2] / "bags" / "sample_M8528-P1.mcap"


@dataclass
class Witness:
    """The attacker's node: publishes commands, calls fin_sim's services, records every drive block."""

    g: Graph
    ns: str
    node: Any = None
    blocks: list[tuple[float, Block]] = field(default_factory=list)  # (arrival, block)

    def __post_init__(self) -> None:
        self.node = self.g.add(rclpy.create_node("attacker", namespace=self.ns, context=self.g.context))
        self.node.create_subscription(
            data_type("drive"),
            "drive",
            lambda m: self.blocks.append((time.monotonic(), msg_block(m))),
            QOS_DATA,
        )
        self.cmd_pub = self.node.create_publisher(Float64MultiArray, "cmd", QOS_COMMAND)
        self.params = self.node.create_client(SetParameters, "fin_sim/set_parameters")
        self.change = self.node.create_client(ChangeState, "fin_sim/change_state")
        self.g.spin_until(self.params.service_is_ready, 30.0, "fin_sim's parameter service")

    def command(self, f: float, vpp: float, on: float) -> float:
        self.cmd_pub.publish(block_msg(Block.from_record({"frequency_hz": f, "voltage_pp_V": vpp, "on": on})))
        return time.monotonic()

    def drive(self, seconds: float, f: float = 10.0, vpp: float = 800.0, rate_hz: float = 10.0) -> float:
        """A controller's heartbeat for ``seconds``; returns the time of the last command."""
        t_end = time.monotonic() + seconds
        last = 0.0
        while time.monotonic() < t_end:
            last = self.command(f, vpp, 1.0)
            self.g.spin_for(1.0 / rate_hz)
        return last

    def drive_until_loud(self, timeout: float = 30.0, f: float = 10.0) -> None:
        """Heartbeat 800 Vpp until the drive is there (a loaded machine takes its time to start)."""
        t_end = time.monotonic() + timeout
        while self.peak_since(time.monotonic() - 0.3) <= 390.0:
            assert time.monotonic() < t_end, "the drive did not reach 800 Vpp"
            self.drive(0.2, f=f)

    def call(self, client: Any, request: Any) -> Any:
        future = client.call_async(request)
        self.g.spin_until(future.done, 20.0, f"a reply from {client.srv_name}")
        return future.result()

    def warm_up(self, client: Any, request: Any, timeout: float = 20.0) -> None:
        """Send an idempotent ``request`` until it is answered.  ``service_is_ready`` says that the
        service sees the client's requests, not that the client hears its replies: a request sent in
        between is answered into the void (the DDS client/service discovery race, ros2/rmw_connextdds
        #132; seen once in a full run here), so the first call that matters follows a warm-up."""
        t_end = time.monotonic() + timeout
        while True:
            future = client.call_async(request)
            t_try = time.monotonic() + 2.0
            while not future.done() and time.monotonic() < t_try:
                self.g.spin_for(0.05)
            if future.done():
                return
            client.remove_pending_request(future)
            assert time.monotonic() < t_end, f"no reply from {client.srv_name} within {timeout} s"

    def set_param(self, name: str, value: Any) -> Any:
        kinds = {bool: "bool", float: "double", int: "integer"}
        kind = kinds[type(value)]
        pv = ParameterValue(type=getattr(ParameterType, f"PARAMETER_{kind.upper()}"))
        setattr(pv, f"{kind}_value", value)
        reply = self.call(self.params, SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)]))
        return reply.results[0]

    def transition(self, tid: int = 0, label: str = "") -> bool:
        return bool(
            self.call(self.change, ChangeState.Request(transition=Transition(id=tid, label=label))).success
        )

    def peak_since(self, t: float) -> float:
        return max((float(np.max(np.abs(b["voltage_V"]))) for a, b in self.blocks if a >= t), default=0.0)

    def loud_until(self) -> float:
        """Arrival time of the last block with a sample above QUIET."""
        return max(a for a, b in self.blocks if np.max(np.abs(b["voltage_V"])) > QUIET)

    def loud_for(self, last: float) -> float:
        """How long the drive stayed loud after the last command, in the fin's own sample times (s):
        the command dated by the fin's samples that had arrived when it was sent (``last``: the
        witness's clock), so one block's delivery late; the drive's last sample above QUIET."""
        t, v = self.samples()
        arrivals = np.concatenate([np.full(b["t_s"].size, a) for a, b in self.blocks])
        return float(np.max(t[np.abs(v) > QUIET])) - float(np.max(t[arrivals <= last]))

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        t = np.concatenate([b["t_s"] for _, b in self.blocks])
        v = np.concatenate([b["voltage_V"] for _, b in self.blocks])
        return t, v


def fin_sim(ns: str, *extra: str) -> subprocess.Popen[str]:
    return start("fin_sim", "-r", f"__ns:=/{ns}", "-p", "rig.voltage_noise_v:=0.0", *extra)


def finish(proc: subprocess.Popen[str]) -> str:
    return stop(proc)[0]


# ------------------------------------------------------------------------------- time sources
@pytest.mark.exclusive
@pytest.mark.slow
@pytest.mark.parametrize(
    "attack", ["set use_sim_time", "frozen /clock", "racing /clock", "start with use_sim_time"]
)
def test_no_clock_or_time_parameter_silences_the_watchdog(attack: str) -> None:
    """Drive 800 Vpp for 2 s, then stop commanding while attacking fin_sim's notion of time: the
    watchdog (1 s) still ramps the drive below 1 % within 1.37 s of the fin's own time (its samples'
    times: the watchdog, the stop's 0.2 s ramp and a block each for the trip's look and for the
    delivery that dates the command), within 2 s by the witness's clock (an attack that froze the
    fin's time too would show there: loud through the attack's 3 s), and fin_sim keeps publishing.
    By the witness's clock alone, with 0.5 s for delivery, a CI run beside the parallel phase failed
    at 1.56 s (stop 67)."""
    ns = f"t{abs(hash(attack)) % 10_000}"
    extra = ("-p", "use_sim_time:=true") if attack == "start with use_sim_time" else ()
    proc = fin_sim(ns, *extra)
    try:
        with graph() as g:
            w = Witness(g, ns)
            clock = w.node.create_publisher(Clock, "/clock", QOS_CLOCK)
            w.drive_until_loud()
            last_cmd = w.drive(1.0)
            assert w.peak_since(last_cmd - 0.5) > 390.0
            if attack == "set use_sim_time":
                result = w.set_param("use_sim_time", True)
                assert not result.successful and "not taken" in result.reason
            t_attack = time.monotonic()
            fake = 0
            while time.monotonic() - t_attack < 3.0:  # the hostile clock keeps ticking meanwhile
                if attack == "racing /clock":
                    fake += 100_000_000_000  # +100 s per message
                clock.publish(Clock(clock=TimeMsg(sec=fake // 1_000_000_000, nanosec=0)))
                g.spin_for(0.01)
            published_during = sum(1 for a, _ in w.blocks if a > t_attack + 0.5)
            quiet_after = w.loud_until() - last_cmd
    finally:
        out = finish(proc)
    print(
        f"{attack}: below 1 % {quiet_after:.2f} s after the last command, {published_during} blocks meanwhile"
    )
    loud_for = w.loud_for(last_cmd)
    print(f"{attack}: loud {loud_for:.2f} s of the fin's time after the last command")
    # 2.5 s of 20 blocks/s: the timer runs on (half of them at least: a stalled one sends none; 38 of
    # 50 came beside phase 1 in stop 69's CI, where 40 were asked)
    assert published_during >= 25, (published_during, out)
    assert loud_for < 1.0 + 0.2 + 0.17, (loud_for, out)
    assert quiet_after < 1.0 + 1.0, (quiet_after, out)
    if attack == "start with use_sim_time":
        assert "use_sim_time is not taken" in out


@pytest.mark.slow
@pytest.mark.parametrize("name", ["thrust_estimator", "controller", "recorder", "player"])
def test_no_node_takes_use_sim_time_live(name: str, tmp_path) -> None:
    """Switched live, ``use_sim_time`` would move a node's time under its windows, heartbeat or bag:
    every node refuses it from another process, with the reason, and keeps its clock; set at start it
    is taken (the estimator's windows and the controller's heartbeat run on /clock that way)."""
    ns = f"st_{name}"
    extra = {
        "controller": ("-p", "mode:=continuous", "-p", "frequencies:=[6.0]", "-p", "voltages:=[0.0]"),
        "recorder": ("-p", f"path:={tmp_path / 'r.mcap'}"),
        "player": ("-p", "bag:=" + str(SAMPLE_BAG), "-p", "rate:=0.05"),
    }.get(name, ())
    proc = start(name, "-r", f"__ns:=/{ns}", *extra)
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("attacker", context=g.context))
            client = node.create_client(SetParameters, f"/{ns}/{name}/set_parameters")
            g.spin_until(client.service_is_ready, 60.0, f"{name}'s parameter service")
            pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True)
            request = SetParameters.Request(parameters=[ParameterMsg(name="use_sim_time", value=pv)])
            replies = []
            for _ in range(3):  # (the first request may be answered into the void: see Witness.warm_up)
                future = client.call_async(request)
                t_end = time.monotonic() + 5.0
                while not future.done() and time.monotonic() < t_end:
                    g.spin_for(0.05)
                if future.done():
                    replies.append(future.result().results[0])
                    break
                client.remove_pending_request(future)
    finally:
        out = finish(proc)
    assert replies, out[-2000:]
    assert not replies[0].successful and "fixed at start" in replies[0].reason, replies[0]
    assert "Traceback" not in out


@pytest.mark.slow
@pytest.mark.parametrize("gain", [3.0, 1.0])
def test_a_voltage_monitor_reading_above_the_applied_drive_is_said(gain: float, tmp_path) -> None:
    """An augmented model whose voltage monitor reads 3 times what is applied: ``drive`` reads 600 V
    while the drive applies the 200 V its 400 Vpp cap allows, and fin_sim says so (once per 10 s);
    with a true monitor it says nothing."""
    import yaml

    from piezofin_ros.physics.fin import load_fin
    from piezofin_ros.physics.model import Model

    model = tmp_path / "monitor.yaml"
    model.write_text(
        yaml.safe_dump(Model.of(load_fin("M8528-P1"), {"voltage_monitor_gain": [gain]}).to_mapping())
    )
    ns = f"mon{int(gain)}"
    proc = fin_sim(ns, "-p", f"model:={model}", "-p", "limits.voltage_pp_max:=400.0")
    try:
        with graph() as g:
            w = Witness(g, ns)
            w.drive(3.0, f=6.0, vpp=400.0)
            peak = w.peak_since(time.monotonic() - 1.0)
    finally:
        out = finish(proc)
    assert peak == pytest.approx(200.0 * gain, rel=0.02)
    said = out.count("the voltage monitor reads")
    assert (said == 1) if gain > 1 else (said == 0), out[-2000:]


# ------------------------------------------------------------------------------------- stops
@pytest.mark.slow
@pytest.mark.parametrize("stop_kind", ["off", "watchdog", "cap to 0", "deactivate", "shutdown"])
def test_a_slow_slew_never_makes_a_stop_slow(stop_kind: str) -> None:
    """limits.slew_vpp_per_s := 1 is taken live (tighter), yet every kind of stop brings 800 Vpp below
    1 % within 0.5 s of fin time; a ramp published at once holds at most that much, sample times
    stay contiguous (nothing jumps ahead, nothing is lost), and no sample exceeds the cap."""
    ns = f"s{abs(hash(stop_kind)) % 10_000}"
    proc = fin_sim(ns)
    try:
        with graph() as g:
            w = Witness(g, ns)
            w.drive_until_loud()
            result = w.set_param("limits.slew_vpp_per_s", 1.0)
            assert result.successful, result.reason
            w.drive(0.5)
            assert w.peak_since(time.monotonic() - 0.3) > 390.0
            t_stop = time.monotonic()
            if stop_kind == "off":
                w.command(10.0, 0.0, 0.0)
            elif stop_kind == "cap to 0":
                w.command(10.0, 800.0, 1.0)
                result = w.set_param("limits.voltage_pp_max", 0.0)
                assert result.successful, result.reason
            elif stop_kind in ("deactivate", "shutdown"):
                w.command(10.0, 800.0, 1.0)
                label = (
                    Transition.TRANSITION_DEACTIVATE if stop_kind == "deactivate" else 7
                )  # active_shutdown
                assert w.transition(label)
            # "watchdog": simply no more commands
            if stop_kind == "cap to 0":
                g.spin_for(0.5)
                for _ in range(5):  # still commanding: the cap holds
                    w.command(10.0, 800.0, 1.0)
                    g.spin_for(0.1)
            g.spin_for(2.0)
            t, v = w.samples()
            arrival_offset = np.median([b["t_s"][-1] - a for a, b in w.blocks if a < t_stop])
        if stop_kind == "shutdown":  # it ends by itself: waited for (CI once saw its exit take over 2 s)
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=20.0)
    finally:
        out = finish(proc)
    assert np.all(np.abs(v) <= 400.0 + 1e-9)
    dt = np.diff(t)
    assert np.allclose(dt, 1e-3, atol=1e-6), "sample times jumped or a block was lost"
    t_stop_fin = t_stop + arrival_offset  # the stop in fin time (x1: one block of uncertainty)
    loud = t[np.abs(v) > QUIET]
    delay = {"watchdog": 1.0}.get(stop_kind, 0.0)  # the watchdog waits for its timeout first
    print(f"slew 1 Vpp/s, {stop_kind}: below 1 % {loud[-1] - t_stop_fin - delay:.3f} s after the stop")
    assert loud[-1] - t_stop_fin < delay + 0.5 + 0.1, (loud[-1] - t_stop_fin, out)
    assert t[-1] - loud[-1] < 5.0 or stop_kind not in ("deactivate", "shutdown")
    if stop_kind in ("deactivate", "shutdown"):
        assert t[-1] - t_stop_fin < 0.5 + 0.15  # the published ramp is short: nothing far ahead
    if stop_kind == "shutdown":
        assert proc.returncode == 0, out  # lifecycle shutdown ends the process


# --------------------------------------------------------------------------------- lifecycle
INVALID = {
    "unconfigured": [2, 3, 4, 6, 7, 99],
    "inactive": [1, 4, 5, 7, 99],
    "active": [1, 2, 3, 5, 6, 99],
}


@pytest.mark.slow
def test_every_lifecycle_request_in_every_state_is_answered() -> None:
    """Each transition the state does not have (cleanup while active, ...) and unknown ids and labels
    are refused with a reply, never a crash; the valid ones work; shutdown ends the process cleanly."""
    proc = fin_sim("lc", "-p", "autostart:=false")
    refused: list[tuple[str, int]] = []
    try:
        with graph() as g:
            w = Witness(g, "lc")
            g.spin_until(w.change.service_is_ready, 20.0, "change_state")
            w.warm_up(w.change, ChangeState.Request(transition=Transition(label="no_such_transition")))
            for state, valid in (("unconfigured", 1), ("inactive", 3), ("active", None)):
                for tid in INVALID[state]:
                    if not w.transition(tid):
                        refused.append((state, tid))
                assert not w.transition(label="no_such_transition")
                if valid is not None:
                    assert w.transition(valid), state
            w.drive_until_loud()
            assert w.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
            proc.wait(timeout=10)
            g.spin_for(0.3)
            _, v = w.samples()
    finally:
        out = finish(proc)
    assert refused == [(s, tid) for s, ids in INVALID.items() for tid in ids]
    assert proc.returncode == 0, out
    assert "Traceback" not in out and "refused lifecycle transition" in out
    assert np.max(np.abs(v[-50:])) < QUIET  # shut down through a ramp to zero


# ------------------------------------------------------------------ watchdog: latch and pace
@pytest.mark.exclusive
@pytest.mark.slow
def test_a_tripped_watchdog_latches_until_an_off_command() -> None:
    """The controller is SIGSTOPped while driving 800 Vpp (the watchdog trips), then SIGCONTinued: it
    resumes its heartbeat of on-commands, which fin_sim refuses; only a deliberate off re-arms it."""
    proc = fin_sim("latch")
    ctl = start_driving_controller("latch")
    try:
        with graph() as g:
            w = Witness(g, "latch")
            g.spin_until(lambda: w.peak_since(time.monotonic() - 0.3) > 390.0, 60.0, "the controller driving")
            ctl.send_signal(signal.SIGSTOP)
            g.spin_for(2.0)  # watchdog 1 s + ramp
            ctl.send_signal(signal.SIGCONT)
            t_cont = time.monotonic()
            g.spin_for(3.0)
            peak_after_resume = w.peak_since(t_cont)
            stop(ctl)  # (its last word is off, which re-arms too: here the operator's own off does)
            w.command(6.0, 0.0, 0.0)  # the operator's deliberate off re-arms ...
            g.spin_for(0.2)
            t_rearm = time.monotonic()
            w.drive(1.0, f=6.0, vpp=400.0)  # ... and a new on-command drives again
            peak_rearmed = w.peak_since(t_rearm + 0.3)
    finally:
        stop(ctl)
        out = finish(proc)
    assert peak_after_resume < QUIET, out
    assert "re-arm" in out
    assert 190.0 < peak_rearmed <= 200.0 + 1e-9


@pytest.mark.exclusive
@pytest.mark.alone  # a claim in wall time at x20: a busy neighbour delays the trip itself (CI: 0.88 s)
@pytest.mark.slow
def test_fast_simulation_does_not_trip_on_scheduling_jitter() -> None:
    """At x20, 1 s of fin time is 50 ms of wall time.  A commander 200 ms late (a busy executor) does
    not trip the watchdog; one that stops does, within WATCHDOG_MIN_WALL_S of wall time plus the ramp.

    The commander here spins 400 sample blocks a second between its commands and is itself late on a
    loaded machine (CI once saw 250 ms): its real gaps are measured, and the claim is checked for
    the gaps it actually left, below the wall floor."""
    from piezofin_ros.nodes.fin_sim import WATCHDOG_MIN_WALL_S as floor

    proc = fin_sim("jit", "-p", "realtime_factor:=20")
    try:
        with graph() as g:
            w = Witness(g, "jit")
            w.drive_until_loud()
            t0 = time.monotonic()
            sent = []
            while time.monotonic() < t0 + 3.0:  # 200 ms gaps: 4 s of fin time each
                sent.append(w.command(10.0, 800.0, 1.0))
                g.spin_for(0.2)
            last = sent[-1]
            lowest = min(float(np.max(np.abs(b["voltage_V"]))) for a, b in w.blocks if t0 + 0.5 < a < last)
            g.spin_for(1.5)
            stopped_after = w.loud_until() - last
    finally:
        out = finish(proc)
    gap = float(np.max(np.diff(sent)))
    print(
        f"x20, commands 200 ms apart (longest gap {gap * 1e3:.0f} ms, floor {floor * 1e3:.0f} ms): "
        f"lowest peak {lowest:.1f} V; stopped: quiet {stopped_after:.3f} s later"
    )
    assert gap < floor - 0.1, f"the commander itself stalled {gap:.3f} s: not the jitter this test is about"
    assert lowest > 390.0, out  # never tripped while commanded
    assert "instead of limits.command_timeout_s" in out
    assert stopped_after < floor + 0.1 + 0.15, stopped_after  # wall floor + ramp (at x20) + a block


@pytest.mark.exclusive
@pytest.mark.slow
@pytest.mark.parametrize("factor", [1.0, 4.0])
def test_the_wall_floor_is_for_a_fast_simulation_only(factor: float) -> None:
    """A 0.25 s watchdog, and a commander that stops: in real time it trips after 0.25 s of the fin's
    time (the floor is no excuse there); at x4 it waits WATCHDOG_MIN_WALL_S of wall time (4 s of fin
    time), said once at start.  Timed in the fin's own sample times: its last loud sample after the
    last command the fin took."""
    from piezofin_ros.nodes.fin_sim import WATCHDOG_MIN_WALL_S as floor

    ns = f"floor{int(factor)}"
    proc = fin_sim(ns, "-p", "limits.command_timeout_s:=0.25", "-p", f"realtime_factor:={factor:g}")
    try:
        with graph() as g:
            w = Witness(g, ns)
            w.drive_until_loud()
            last = w.drive(0.5)
            g.spin_for(floor + 1.5)
    finally:
        out = finish(proc)
    loud_for = w.loud_for(last)  # fin time, s
    said = "instead of limits.command_timeout_s 0.25 s" in out
    print(f"x{factor:g}: loud {loud_for:.2f} s of fin time after the last command; floor said: {said}")
    if factor == 1.0:
        assert not said, out
        # the watchdog, a stop's ramp (0.2 s), a block each for the trip's look and for the delivery that
        # dated the command (0.49 s measured; the floor of 0.5 s there was would give 0.7 at least)
        assert loud_for < 0.25 + 0.2 + 0.17, loud_for
    else:
        assert said and f"watchdog: {floor * factor:g} s of fin time" in out, out
        assert loud_for > floor * factor - 0.5, loud_for


# ------------------------------------------------------------------------------- silence
@pytest.mark.exclusive
@pytest.mark.slow
def test_estimator_and_controller_speak_when_fin_sim_is_killed(tmp_path: Path) -> None:
    """fin_sim (the /clock source at x10) is SIGKILLed: within 5 s both the estimator and the
    controller say that their input stopped (their ROS-time timers stopped with the clock).

    The controller runs one protocol trial with a 600 s burst (60 s of wall time), so that the fin is
    driven when it is killed; a ``continuous`` point ends at its first running estimate (8 s of fin
    time, under a second of wall time), which the witness could miss on a slow graph."""
    sim = start("fin_sim", "-r", "__ns:=/quiet", "-p", "realtime_factor:=10.0", "-p", "publish_clock:=true")
    logs = tmp_path / "estimator.log", tmp_path / "controller.log"
    said = ("/quiet/drive: nothing for", "time (the heartbeat): nothing for")
    est = start("thrust_estimator", "-r", "__ns:=/quiet", "-p", "use_sim_time:=true", log=logs[0])
    ctl = start(
        "controller",
        "-r",
        "__ns:=/quiet",
        "-p",
        "use_sim_time:=true",
        "-p",
        "mode:=protocol",
        "-p",
        "on_s:=600.0",
        log=logs[1],
    )
    try:
        with graph() as g:
            w = Witness(g, "quiet")
            g.spin_until(lambda: w.peak_since(time.monotonic() - 0.3) > 390.0, 60.0, "driving")
            g.spin_for(2.0)
            sim.send_signal(signal.SIGKILL)
            sim.wait(timeout=10)
            killed = time.monotonic()
            while time.monotonic() - killed < 5.0 and not all(
                line in log.read_text() for line, log in zip(said, logs, strict=True)
            ):
                time.sleep(0.1)
    finally:
        stop(est, ctl, sim)  # sim too: a failed run must not leave it driving
    out_est, out_ctl = (log.read_text() for log in logs)
    assert said[0] in out_est, out_est
    assert said[1] in out_ctl, out_ctl


# ---------------------------------------------------------------------------- in one process
def test_booleans_and_strings_are_not_limits() -> None:
    """`ros2 param set ... limits.voltage_pp_max true` would have become a 1 Vpp cap: refused, as any
    value that is not a number; zero is a valid cap (no drive at all)."""
    from rclpy.parameter import Parameter

    from piezofin_ros.nodes.fin_sim import FinSim

    with graph() as g:
        sim = g.add(FinSim(context=g.context, namespace="b"))
        sim.trigger_configure()
        for name in ("voltage_pp_max", "slew_vpp_per_s", "command_timeout_s", "frequency_max_hz"):
            for bad in (True, False, "400"):
                [result] = sim.set_parameters([Parameter(f"limits.{name}", value=bad)])
                assert not result.successful, (name, bad)
        assert sim.rig.drive.limits.voltage_pp_max == 800.0
        [result] = sim.set_parameters([Parameter("limits.voltage_pp_max", value=0)])
        assert result.successful, result.reason
        assert sim.rig.drive.limits.voltage_pp_max == 0.0


@pytest.mark.slow
def test_an_aborted_run_finishes_and_stops_the_drive() -> None:
    """No estimator: the controller's trials get no estimate, it aborts after max_missing and
    finishes at once (before, it waited for the trial in progress forever and bringup never exited)."""
    from piezofin_ros.nodes.controller import Controller
    from piezofin_ros.nodes.fin_sim import FinSim

    from .test_safety import params

    with graph() as g:
        g.add(FinSim(context=g.context, namespace="ab", parameter_overrides=params(realtime_factor=20.0)))
        ctl = g.add(
            Controller(
                context=g.context,
                namespace="ab",
                parameter_overrides=params(
                    frequencies=[5.0, 6.0, 7.0],
                    off_s=0.5,
                    on_s=1.0,
                    max_missing=1,
                    use_sim_time=False,
                    wait_estimator_s=1.0,
                ),
            )
        )
        g.spin_until(lambda: ctl.finished, 60.0, "the controller to finish")
    status = ctl.status()
    assert status["state"] == "aborted" and "without an estimate" in status["reason"]


# ----------------------------------------------------------------------------- the recorder
@pytest.mark.exclusive
@pytest.mark.slow
def test_a_recorder_killed_at_any_moment_leaves_a_recoverable_bag(tmp_path) -> None:
    """SIGKILL 0-4 s after the recorder created its file (it never leaves a 0-byte file: the header is
    written at once, the first message flushed at once): every bag is recoverable.  (The loss bound
    of flush_s is measured mid-run by test_crossprocess, against a witness subscribed all along:
    here the unrecorded tail also holds DDS's time to match the new recorder, seconds on a busy
    machine, which is not a loss.)"""
    from piezofin_ros.bags import block_of, read_messages, recover

    sim = start("fin_sim", "-r", "__ns:=/rk")
    lost: list[float] = []
    try:
        for k, after in enumerate((0.0, 0.3, 1.0, 2.0, 3.0, 4.0)):
            bag = tmp_path / f"k{k}.mcap"
            rec = start("recorder", "-p", f"path:={bag}", "-p", "namespaces:=[rk]", "-p", "flush_s:=1.0")
            deadline = time.monotonic() + 30.0
            while not bag.exists() and time.monotonic() < deadline:
                time.sleep(0.005)
            time.sleep(after)
            rec.send_signal(signal.SIGKILL)
            killed = time.time()
            rec.wait(timeout=10)
            assert bag.stat().st_size > 0
            report = recover(bag)  # raises if it cannot: every one must be recoverable
            drive = [
                block_of(m.type_name, m.data)["t_s"][-1] for m in read_messages(report.output, ["/rk/drive"])
            ]
            if drive:  # (before DDS matched the recorder to fin_sim there was nothing to record)
                lost.append(killed - drive[-1])
    finally:
        stop(sim)
    print(f"recorders killed 0-4 s after creating their file: all 6 recoverable, unrecorded tails {lost}")
    assert lost  # some recorded before the kill


@pytest.mark.slow
def test_a_full_disk_stops_the_recorder_with_one_line_and_a_recoverable_bag(tmp_path) -> None:
    """The file-size limit (RLIMIT_FSIZE) makes writes fail as a full disk does (EFBIG, like ENOSPC)."""
    import resource

    from piezofin_ros.bags import recover

    def small_disk() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000))

    bag = tmp_path / "full.mcap"
    sim = start("fin_sim", "-r", "__ns:=/fd", "-p", "realtime_factor:=10.0")
    rec = start(
        "recorder",
        "-p",
        f"path:={bag}",
        "-p",
        "namespaces:=[fd]",
        "-p",
        "flush_s:=0.2",
        preexec_fn=small_disk,
    )
    try:
        rec.wait(timeout=60)
    finally:
        out_rec, _ = stop(rec, sim)
    assert rec.returncode == 1, out_rec
    assert "Traceback" not in out_rec
    assert sum("cannot write" in line for line in out_rec.splitlines()) == 1, out_rec
    report = recover(bag)
    assert report.messages > 50


@pytest.mark.slow
def test_bringup_on_a_full_disk_stops_at_once_and_says_its_bag_is_incomplete(tmp_path) -> None:
    """Issue 29: under a file-size limit every bag was cut, yet bringup (and the campaign above it)
    went on to the end and exited 0.  Now the run stops when its recorder cannot write, says so,
    and exits 1, which the campaign turns into one line naming the log."""
    import resource

    from ..rosutil import BIN, clean_env

    def small_disk() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))

    bag = tmp_path / "cut.mcap"
    args = ["--frequencies", "5", "9", "--voltages", "800", "--bag", str(bag), "--realtime-factor", "20"]
    proc = subprocess.run(
        [str(BIN / "bringup"), *args],
        capture_output=True,
        text=True,
        timeout=240,
        stdin=subprocess.DEVNULL,
        env=clean_env(),
        preexec_fn=small_disk,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 1, out
    assert "Traceback" not in out
    assert "stopping: the recorder cannot write" in out and "is incomplete" in out, out
    assert "/fin: M8528-P1, done" not in out  # (the two trials did not run to their end)


@pytest.mark.slow
def test_several_fins_in_bringup_share_one_clock_drop_nothing_and_exit() -> None:
    """Three fins in one bringup (a CPU-bound machine runs them slower than asked: the pacer waits
    for the consumers instead of dropping): every controller done, every drive sample in the bag
    (read by rosbags), the same sample times for every fin, and the process exits on its own."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from bench_fins import run

    r = run(3, ["--frequencies", "5", "9", "--voltages", "800"])
    assert r["exit"] == 0, r["summary"]
    assert r["states"] == {"/f0": "done", "/f1": "done", "/f2": "done"}
    assert r["gaps"] == {"/f0/drive": 0, "/f1/drive": 0, "/f2/drive": 0}  # nothing dropped
    assert r["one_clock"]  # lock-step: identical sample times
    assert min(r["samples"].values()) >= 60_000  # two 30 s protocol trials


# ------------------------------------------------------------------------------- input floods
@pytest.mark.exclusive
@pytest.mark.slow
def test_a_flood_of_thrust_demands_neither_stops_the_fin_nor_floods_the_log() -> None:
    """An attacker publishes ``thrust_demand`` at 100 Hz for 8 s, cycling valid demands that flip
    faster than any trial and values that are not demands at all (NaN, +-inf, negative, 1e9 N,
    1e-300).  The optimising controller's heartbeat goes on (fin_sim's watchdog never trips, the
    drive never goes quiet), what it says about the flood is throttled, and it ends on the last
    valid demand."""
    from std_msgs.msg import Float64

    from piezofin_ros.nodes._common import QOS_COMMAND as QOS

    ns = "flood"
    sim = fin_sim(ns)
    est = start("thrust_estimator", "-r", f"__ns:=/{ns}", "-p", "estimator.window_s:=2.0")
    ctl = start(
        "controller", "-r", f"__ns:=/{ns}", "-p", "mode:=optimise", "-p", "demand_n:=0.004",
        "-p", "source:=self", "-p", "slew_vpp_per_s:=4000.0",
    )  # fmt: skip
    values = [1e-3, 1e9, float("nan"), 5e-3, float("inf"), -1.0, float("-inf"), 0.0, 1e-300, 3e-3]
    try:
        with graph() as g:
            w = Witness(g, ns)
            pub = w.node.create_publisher(Float64, "thrust_demand", QOS)
            g.spin_until(lambda: w.peak_since(time.monotonic() - 0.3) > 50.0, 60.0, "the controller driving")
            t0 = time.monotonic()
            k = 0
            while time.monotonic() < t0 + 8.0:  # 100 Hz, paced (several a step when spinning lags)
                while k < 100.0 * (time.monotonic() - t0):
                    pub.publish(Float64(data=values[k % len(values)]))
                    k += 1
                g.spin_for(0.005)
            pub.publish(Float64(data=0.004))  # the last word: a valid demand
            t1 = time.monotonic()
            g.spin_for(3.0)
            windows = np.arange(t0, t1 + 2.5, 0.5)
            quietest = min(
                max(
                    (float(np.max(np.abs(b["voltage_V"]))) for t, b in w.blocks if a <= t < a + 0.5),
                    default=0,
                )
                for a in windows
            )
    finally:
        out_ctl, out_est, out_sim = stop(ctl, est, sim)
    said = [line for line in out_ctl.splitlines() if "thrust demand" in line]
    print(f"{k} demands in 8 s: controller lines about them {len(said)}; quietest 0.5 s: {quietest:.0f} V")
    assert k >= 790  # 100 Hz
    assert "watchdog:" not in out_sim, out_sim[-2000:]
    assert quietest > QUIET, out_ctl[-2000:]
    assert len(said) <= 20, said[:5]
    # each kind of value that is no demand refused at the door, said with a count (at most once a second)
    assert "thrust_demand; the latest:" in out_ctl and "is not within [0, 10] N" in out_ctl, out_ctl[-2000:]
    assert "Traceback" not in out_ctl + out_est + out_sim


# ------------------------------------------------------------------------- a fish's speed sensor
@pytest.mark.slow
def test_a_speed_sensor_that_stops_or_lies_is_said_the_demand_stays_allowed_and_the_bag_keeps_it(
    tmp_path,
) -> None:
    """Issue 27's bad input, across processes: ``speed_loop`` and the ``recorder`` each in its own
    process, this one the fish's speed sensor and estimator, then an attacker on ``swim_speed``.  In
    turn the sensor reads true, stops, reads values that are no speed (NaN, +-inf, beyond 100 m/s),
    lies slow (a still fish where the fin's thrust gives 5 cm/s), lies fast, then reads true again
    (the tests' clocks are scaled: the sensor times out after 1 s, a lie is said after 2 s and the
    reading's low-pass is 0.5 s, so that a lie of 5 m/s is forgotten within the last phase).
    Every demand stays within ``[min_demand_n, max_demand_n]`` (a lie cannot make the drive ask for
    more than the loop may), each kind of trouble is one line as it starts and is on the status topic,
    the loop holds again once the sensor is honest, and every reading, lies included, is in the bag."""
    from std_msgs.msg import Float64, String

    from piezofin_ros.bags import decode, read_messages
    from piezofin_ros.nodes._common import TOPIC_DEMAND, TOPIC_ESTIMATE, TOPIC_LOOP_STATUS, TOPIC_SPEED

    ns, bag, most, least = "liar", tmp_path / "fish.mcap", 0.004, 1e-4
    loop = start(
        "speed_loop", "-r", f"__ns:=/{ns}", "-p", "speed_m_s:=0.05", "-p", "rate_hz:=20.0",
        "-p", f"loop.max_demand_n:={most}", "-p", f"loop.min_demand_n:={least}",
        "-p", "loop.sensor_timeout_s:=1.0", "-p", "loop.disagreement_s:=2.0", "-p", "loop.filter_s:=0.5",
    )  # fmt: skip
    rec = start("recorder", "-r", f"__ns:=/{ns}", "-p", f"path:={bag}")
    sent: list[float] = []
    demands: list[tuple[str, float]] = []  # (phase, demand)
    states: list[tuple[str, str]] = []  # (phase, status)
    not_speeds = [math.nan, math.inf, -math.inf, 1e9, -1e9, 101.0, 1e308]
    phases: list[tuple[str, float, Any]] = [  # (name, seconds, reading at step k: None = silent)
        ("true", 4.0, lambda k: 0.05),
        ("stopped", 3.0, lambda k: None),
        ("true again", 4.0, lambda k: 0.05),
        ("no speed", 3.0, lambda k: not_speeds[k % len(not_speeds)]),
        ("lies slow", 4.0, lambda k: 0.0),
        ("lies fast", 4.0, lambda k: 5.0),
        ("true at last", 5.0, lambda k: 0.05),
    ]
    now = ["start"]  # the phase under way, as the witness's callbacks read it
    try:
        with graph() as g:
            node = g.add(rclpy.create_node("sensor", namespace=ns, context=g.context))
            speed = node.create_publisher(data_type(TOPIC_SPEED), TOPIC_SPEED, QOS_DATA)
            estimate = node.create_publisher(EstimateMsg, TOPIC_ESTIMATE, QOS_DATA)
            node.create_subscription(
                Float64, TOPIC_DEMAND, lambda m: demands.append((now[0], m.data)), QOS_COMMAND
            )
            node.create_subscription(
                String, TOPIC_LOOP_STATUS, lambda m: states.append((now[0], m.data)), QOS_COMMAND
            )
            kept: list[int] = []  # the recorder's count of speed readings in its bag, once a second
            node.create_subscription(
                String,
                "recorder/status",
                lambda m: kept.append(json.loads(m.data)["per_topic"].get(f"/{ns}/{TOPIC_SPEED}", 0)),
                QOS_STATUS,
            )
            g.spin_until(lambda: speed.get_subscription_count() >= 2, 30.0, "speed_loop and recorder")
            g.spin_until(lambda: bool(demands), 30.0, "a first demand")
            # true readings until the recorder has one in its bag: in DDS a volatile reader that has not
            # yet matched the writer (its side of discovery lags the writer's) never gets what came before
            warm_up, now[0] = 0, "true"  # (the first phase's, which reads the same)
            while not (kept and kept[-1] > 0):
                speed.publish(speed_msg(data_type(TOPIC_SPEED), 0.05, 0.0))
                warm_up += 1
                g.spin_for(0.05)
                assert warm_up < 600, "the recorder kept no speed reading in 30 s"
            # the fin gives what holds 5 cm/s against the drag law (the estimator's self-sensed thrust)
            fin = record_msg(EstimateMsg, {"thrust_self_n": 1.49e-3}, 1.0)
            for name, seconds, reading in phases:
                now[0] = name
                t_end, k = time.monotonic() + seconds, 0
                while time.monotonic() < t_end:
                    if k % 10 == 0:
                        estimate.publish(fin)
                    r = reading(k)
                    if r is not None:
                        speed.publish(speed_msg(data_type(TOPIC_SPEED), r, 0.0))
                        sent.append(r)
                    k += 1
                    g.spin_for(0.05)
            # every reading in the bag before the stop (a reading lost on the way is repaired at the
            # writer's next heartbeat, which may come seconds later on a loaded machine)
            # (a warm-up reading sent before the recorder's side matched never comes: then 10 s at most)
            t_end = time.monotonic() + 10.0
            while kept[-1] < warm_up + len(sent) and time.monotonic() < t_end:
                g.spin_for(0.1)
    finally:
        out_loop, out_rec = stop(loop, rec)
    for name, _, _ in phases:
        asked = [d for p, d in demands if p == name]
        assert asked and all(least <= d <= most for d in asked), (name, asked)
    said = {name: " | ".join(s for p, s in states if p == name) for name, _, _ in phases}
    assert "holding 0.05 m/s" in said["true"], said
    assert "speed sensor silent" in said["stopped"], said
    assert "speed sensor silent" in said["no speed"], said  # refused readings are no readings
    assert "a sensor that lies" in said["lies slow"] and "a sensor that lies" in said["lies fast"], said
    assert "holding 0.05 m/s" in said["true at last"], said
    assert min(d for p, d in demands if p == "lies fast") == least  # it reads fast: the least thrust
    assert "swim_speed; the latest: nan m/s is not within" in out_loop, out_loop  # (refused at the door)
    assert "speed sensor silent" in out_loop and "a sensor that lies" in out_loop, out_loop
    assert len(out_loop.splitlines()) <= 40, out_loop  # one line per kind, at most one a second
    assert "Traceback" not in out_loop + out_rec, out_loop + out_rec
    recorded = [
        float(decode(m.type_name, m.data).twist.linear.x)
        for m in read_messages(bag, [f"/{ns}/{TOPIC_SPEED}"])
    ]
    # every reading, NaN and lies included, in order, after the warm-up's that reached the recorder
    warm = len(recorded) - len(sent)
    assert 1 <= warm <= warm_up and recorded[:warm] == [0.05] * warm, (warm, warm_up, recorded[:warm])
    np.testing.assert_array_equal(recorded[warm:], sent)
