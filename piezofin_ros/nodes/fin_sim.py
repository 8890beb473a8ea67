"""``fin_sim``: the simulated hardware, a lifecycle node over
:class:`~piezofin_ros.rig.simulated.SimulatedRig`.

The drive is at zero volts unless the node is active.  On deactivate (and on shutdown) the
drive ramps to zero and the ramp is published, so the last samples show a safe drive.  With
``protocol`` the node runs the paper's trial (``protocol_off_s`` off, ``protocol_on_s`` on,
``protocol_off_s`` off) on each on-command for a new operating point, like the lab's sequencer.  Each
timer tick advances the simulation by one block (``block_s``); the timer period is
``block_s / realtime_factor``, so the simulation runs at ``realtime_factor`` times real time.
With ``publish_clock`` the node publishes ``/clock`` (the time of its last sample) and the rest
of the graph follows with ``use_sim_time``.  Sample times are ``t0 + k / sample_rate_hz`` with
``t0`` the node clock at configure: never the wall clock inside a callback.

Safety does not depend on anything another node can change.  The timer that advances the rig
(and with it the watchdog and every ramp) runs on the steady clock: ``fin_sim`` *is* the time
source, so ``use_sim_time`` is not taken (ignored with a warning at start, refused at run time)
and no ``/clock`` publisher can pace or stop it.  Stops ramp at least at
:data:`~piezofin_ros.rig.simulated.STOP_SLEW_VPP_PER_S` whatever the slew setting; a tripped watchdog
latches until an off command or a lifecycle activate re-arms it.  Simulated faster than real
time, one second of fin time is a few milliseconds of wall time, less than the scheduling jitter
of the commanding process (a Python commander spinning 400 sample blocks a second at x20 was seen
to fall 250 ms behind on a loaded CI machine): the watchdog then waits at least
:data:`WATCHDOG_MIN_WALL_S` of wall time (``command_timeout_s`` is raised to
``WATCHDOG_MIN_WALL_S x realtime_factor`` of fin time, with a log line).  A lifecycle request that
is not a valid transition is refused (the caller gets ``success: false``), never a crash.
With ``model`` (an ``augmented_model.yaml`` written by ``piezofin diagnose --report``) the rig
simulates that model: its fin, plus the fitted effects linearised at each commanded operating point
(see :class:`~piezofin_ros.rig.simulated.SimulatedRig`), so the node streams what the
diagnosed model predicts.
"""

from __future__ import annotations

import collections
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.time import Time
from rclpy.timer import Timer
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64MultiArray

from ..bags.blocks import Block, BlockFormatError
from ..config import setting
from ..physics.amplifier import AmplifierError, load_amplifier
from ..physics.effects import ModelError
from ..physics.fin import MEDIA, Fin, FinConfigError, in_medium, load_fin
from ..physics.model import load_model
from ..physics.planar import slender_planar
from ..physics.swim import Battery, Body, SwimError, load_battery, load_body
from ..physics.waveforms import ProtocolTiming
from ..rig.fish import FreeSwimmer
from ..rig.simulated import (
    STOP_SLEW_VPP_PER_S,
    DriveLimits,
    RigBlock,
    RigConfig,
    SimulatedRig,
    loosened,
)
from ._common import (
    QOS_COMMAND,
    TOPIC_BATTERY,
    TOPIC_CLOCK,
    TOPIC_CMD,
    TOPIC_DRIVE,
    TOPIC_IMU,
    TOPIC_LOADCELL,
    TOPIC_SPEED,
    TOPIC_SUPPLY,
    TOPIC_TIP,
    Inbox,
    MessageRefused,
    StartupError,
    declare,
    drive_command,
    endpoint,
    freeze_parameters,
    imu_msg,
    named_msg,
    run_node,
    speed_msg,
)
from ._diagnostics import ERROR, OK, STALE, WARN, Diagnostics, Report

#: A battery with less than this share of its charge left is WARN on /diagnostics.
BATTERY_LOW = 0.2

#: Simulated faster than real time, the watchdog never trips on less than this much wall time without
#: a command (see the module).  0.5 s until stop 66: a 10 kHz flood at x10 on a 2-core machine loaded by
#: the parallel tests stalled the controller's commands past it in 2 of 4 CI runs (5 s of fin time);
#: a second, as the README's fish driver waits at x5.
WATCHDOG_MIN_WALL_S = 1.0


@dataclass(frozen=True)
class FinSimConfig:
    """``fin_sim``'s parameters (``rig.*``: :class:`RigConfig`, ``limits.*``: :class:`DriveLimits`)."""

    fin: str = setting("M8528-P1", "fin preset name or YAML path")
    model: str = setting(
        "", "augmented model YAML from `piezofin diagnose --report` (its fin and effects; replaces fin)"
    )
    medium: str = setting(
        "water",
        "water, or air: no hydrodynamic load (the paper's in-air identification tests)",
        choices=MEDIA,
    )
    seed: int = setting(0, "noise seed", 0, 2**31 - 1)
    block_s: float = setting(0.05, "simulated time per published block, s", 0.0005, 1.0)
    realtime_factor: float = setting(1.0, "simulated s per wall s", 0.01, 1000.0)
    publish_clock: bool = setting(False, "publish /clock (sample times)")
    start_time_s: float = setting(
        0.0, "time of the first sample, s (0: the node clock at configure)", 0.0, 1e10
    )
    protocol: bool = setting(False, "run the paper's trial (off, on, off) on each new on-command")
    protocol_off_s: float = setting(ProtocolTiming.off_s, "protocol: time off, s", 0.1, 600.0)
    protocol_on_s: float = setting(ProtocolTiming.on_s, "protocol: time on, s", 0.1, 600.0)
    autostart: bool = setting(True, "configure and activate at start (ros2 run)")
    amplifier: str = setting(
        "paper-bench", "the amplifier driving the fin, whose draw the supply topic streams: preset or YAML"
    )
    wait_subscribers: int = setting(
        0,
        "subscribers each data topic must have before the first sample (the launch: 2, the estimator "
        "and the recorder), so that none misses the first trial's start; 0: start at once",
        0,
        100,
    )
    wait_subscribers_s: float = setting(
        20.0, "wall time to wait for them at most, s (then the samples start anyway, said)", 0.0, 600.0
    )
    body: str = setting(
        "",
        "a free-swimming body (preset or YAML, config/bodies) that the fin's thrust moves, whose speed "
        "Eq. (19) takes and the swim_speed topic reads; empty: the tethered rig",
    )
    battery: str = setting(
        "",
        "the fish's battery (preset or YAML, config/batteries), drained by the amplifier's supply power and "
        "read on the battery topic (sensor_msgs/BatteryState); the drive stops when it is empty; empty: none",
    )
    lab_instruments: bool = setting(
        True,
        "publish the lab's instruments, the vibrometer (tip_velocity) and the load cell (loadcell); a "
        "fish carries neither (config/fish.yaml: false), and its stack runs on the drive alone",
    )
    speed_noise_m_s: float = setting(0.002, "the speed sensor's noise (a body only), m/s RMS", 0.0, 1.0)
    gyro_noise_rad_s: float = setting(
        0.002, "the IMU's yaw-rate noise (a body that turns: one fin), rad/s RMS per reading", 0.0, 1.0
    )
    gyro_bias_rad_s: float = setting(
        0.0005, "the IMU's yaw-rate bias (its heading drifts by it), rad/s", -1.0, 1.0
    )


def _swimming(c: FinSimConfig) -> tuple[Body | None, Battery | None]:
    """The body and the battery the parameters name (one line naming the parameter when they are
    impossible)."""
    try:
        body = load_body(c.body) if c.body else None
    except SwimError as exc:
        raise StartupError(f"parameter body: {exc}") from None
    try:
        battery = load_battery(c.battery) if c.battery else None
    except SwimError as exc:
        raise StartupError(f"parameter battery: {exc}") from None
    if battery is not None and body is None:
        raise StartupError(
            "parameter battery: a battery needs a body (parameter body): the tethered rig has none"
        )
    return body, battery


class FinSim(LifecycleNode):
    """Simulated MFC fin on its rig: publishes ``drive`` and ``supply`` blocks, and with
    ``lab_instruments`` the vibrometer's ``tip_velocity`` and the load cell's ``loadcell``."""

    def __init__(
        self, *, context: Context | None = None, node_name: str = "fin_sim", **kwargs: object
    ) -> None:
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        c = declare(self, FinSimConfig)
        self._fin_name, self._model_path, self._seed, self._medium = c.fin, c.model, c.seed, c.medium
        try:
            self._amplifier = load_amplifier(c.amplifier)
        except AmplifierError as exc:
            raise StartupError(f"parameter amplifier: {exc}") from None
        self._block_s, self._factor, self._publish_clock = c.block_s, c.realtime_factor, c.publish_clock
        self._start_time = c.start_time_s
        self._wait_subscribers, self._wait_subscribers_s = c.wait_subscribers, c.wait_subscribers_s
        self._body, self._battery = _swimming(c)
        self._speed_noise = c.speed_noise_m_s
        instruments = (TOPIC_TIP, TOPIC_LOADCELL) if c.lab_instruments else ()
        self._data_topics = (TOPIC_DRIVE, TOPIC_SUPPLY, *instruments)
        self._gyro = (c.gyro_noise_rad_s, c.gyro_bias_rad_s)
        self._swimmer: FreeSwimmer | None = None
        self._battery_said_t = -math.inf
        self.battery_empty = False
        self._consumers_ok = c.wait_subscribers == 0
        self._waiting_since_ns: int | None = None
        self._protocol, self._protocol_off, self._protocol_on = c.protocol, c.protocol_off_s, c.protocol_on_s
        self.autostart = c.autostart
        self.finalized = False  # lifecycle shutdown: the process ends (run_node)
        self._rig_config = declare(self, RigConfig, "rig")
        self._limits = declare(self, DriveLimits, "limits")
        if self.get_parameter("use_sim_time").value:
            self.set_parameters([Parameter("use_sim_time", value=False)])
            self.get_logger().warning(
                "use_sim_time is not taken: fin_sim is the time source (its drive, watchdog and ramps "
                "run on the steady clock)"
            )
        freeze_parameters(self, "limits.", self._on_limits, takes_sim_time=False)
        self._steady = RosClock(clock_type=ClockType.STEADY_TIME)
        self._guard_change_state()
        self._rig: SimulatedRig | None = None
        self._fin: Fin | None = None
        self._timer: Timer | None = None
        self._running = False  # active: the rig advances (on its own timer, or paced by bringup)
        self.paced = False  # bringup steps every fin from one timer (see step()); no timer of its own
        self._pubs: dict[str, object] = {}
        self.published = {TOPIC_DRIVE: 0, TOPIC_TIP: 0, TOPIC_LOADCELL: 0, TOPIC_SUPPLY: 0}  # samples
        self.blocks_published = 0  # on each data topic
        self.command_log: list[str] = []
        self.command_counts: collections.Counter[str] = collections.Counter()
        self._last_reason_log_ns: dict[str, int] = {}  # per kind (rejected, clamped, ignored)
        self._unlogged: collections.Counter[str] = collections.Counter()
        self.inbox = Inbox(self)  # every message from another process: its failure said, never fatal
        self.inbox.subscribe(Float64MultiArray, TOPIC_CMD, self._on_command, QOS_COMMAND)
        self._clamped_ns = self._monitor_off_ns = -(2**62)  # (steady clock) the last clamp or refusal, ...
        self._last_reason = ""
        self._monitor = (math.nan, math.nan)  # the voltage monitor's reading and the drive's peak, V
        self.diagnostics = Diagnostics(self, c.model or c.fin, stamp=self._fin_time)
        self.diagnostics.add("drive", self._diagnose_drive)
        self.diagnostics.add("voltage monitor", self._diagnose_monitor)
        if self._battery is not None:
            self.diagnostics.add("battery", self._diagnose_battery)

    # ------------------------------------------------------------------------------ lifecycle
    def on_configure(self, state: State) -> TransitionCallbackReturn:
        model = None
        try:
            if self._model_path:
                model = load_model(self._model_path)
                self._fin = model.fin
                if self._medium != "water":
                    raise ModelError("medium:=air takes a fin (parameter fin), not an augmented model")
            else:
                self._fin = in_medium(load_fin(self._fin_name), self._medium)
            if self._body is not None and self._medium != "water":
                raise ModelError("a body swims in water, not with medium:=air")
        except (FinConfigError, ModelError) as exc:
            key = (
                "body"
                if self._body is not None and self._medium != "water"
                else "model"
                if self._model_path
                else "fin"
            )
            self.get_logger().error(f"cannot configure (parameter {key}): {exc}")
            return TransitionCallbackReturn.FAILURE
        t0 = self._start_time or self.get_clock().now().nanoseconds * 1e-9
        protocol = ProtocolTiming(self._protocol_off, self._protocol_on) if self._protocol else None
        self._rig = SimulatedRig(
            self._fin,
            self._rig_config,
            self._effective(self._limits),
            seed=self._seed,
            t0=t0,
            protocol=protocol,
            model=None if model is None else model.knobs_at,
            amplifier=self._amplifier,
        )
        if model is not None:
            effects = ", ".join(f"{k} {v}" for k, v in model.parameters().items()) or "no effect"
            self.get_logger().info(f"augmented model {self._model_path}: {effects}")
        self._n_block = max(1, round(self._block_s * self._rig_config.sample_rate_hz))
        self._pubs = {name: self.create_lifecycle_publisher(*endpoint(name)) for name in self._data_topics}
        self._clock_pub = self.create_publisher(*endpoint(TOPIC_CLOCK)) if self._publish_clock else None
        self._speed_pub = self._battery_pub = self._imu_pub = None
        if self._body is not None:
            turns = self._body.fins == 1  # (one fin: its offset turns the body; two swim straight)
            self._swimmer = FreeSwimmer(
                self._body,
                self._fin.L,
                self._battery,
                self._speed_noise,
                self._seed,
                planar=slender_planar(self._body, self._fin) if turns else None,
                fin=self._fin if turns else None,
                gyro_noise_rad_s=self._gyro[0],
                gyro_bias_rad_s=self._gyro[1],
            )
            self._speed_pub = self.create_lifecycle_publisher(*endpoint(TOPIC_SPEED))
            self._imu_pub = self.create_lifecycle_publisher(*endpoint(TOPIC_IMU)) if turns else None
            if self._battery is not None:
                self._battery_pub = self.create_lifecycle_publisher(*endpoint(TOPIC_BATTERY))
            self.get_logger().info(
                f"swimming: body {self._body.name} ({self._body.mass_kg:g} kg, {self._body.fins} fin(s))"
                + (
                    f", battery {self._battery.name} ({self._battery.capacity_ah * 1e3:g} mA h)"
                    if self._battery
                    else ""
                )
            )
        watchdog = self._rig.drive.limits.command_timeout_s
        if watchdog > self._limits.command_timeout_s:
            self.get_logger().info(
                f"watchdog: {watchdog:g} s of fin time ({WATCHDOG_MIN_WALL_S:g} s of wall time at "
                f"x{self._factor:g}) instead of limits.command_timeout_s {self._limits.command_timeout_s:g} s"
            )
        self.get_logger().info(
            f"configured {self._fin.name}: {self._rig_config.sample_rate_hz:g} Hz samples in blocks of "
            f"{self._n_block}, x{self._factor:g} real time, limit {self._limits.voltage_pp_max:g} Vpp"
        )
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        period = self._n_block / self._rig_config.sample_rate_hz / self._factor
        assert self._rig is not None
        self._rig.rearm()  # activating is the operator's deliberate re-arm of a tripped watchdog
        # the steady clock: nothing another node sets (use_sim_time, /clock) can stop the drive's ticks
        if not self.paced:
            self._timer = self.create_timer(period, self._tick, clock=self._steady)
        self._running = True
        return super().on_activate(state)

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._ramp_down("deactivated")
        self._stop_timer()
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        for pub in self._pubs.values():
            self.destroy_lifecycle_publisher(pub)  # type: ignore[arg-type]
        for pub in (self._speed_pub, self._battery_pub, self._imu_pub):
            if pub is not None:
                self.destroy_lifecycle_publisher(pub)  # type: ignore[arg-type]
        self._speed_pub = self._battery_pub = self._imu_pub = None
        self._swimmer = None
        self._pubs = {}
        self._rig = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        if self._running:
            self._ramp_down("shutting down")
            self._stop_timer()
        self.finalized = True
        return TransitionCallbackReturn.SUCCESS

    def _guard_change_state(self) -> None:
        """A ``change_state`` request for a transition the current state does not have (``cleanup``
        while active, ...) is answered ``success: false`` with a log line; rclpy would raise in the
        service callback, killing the process and leaving the caller without a reply."""
        service = self._service_change_state
        handle = service.callback

        def guarded(request: Any, response: Any) -> Any:
            try:
                return handle(request, response)
            except _rclpy.RCLError as exc:
                label = self._state_machine.current_state[1]
                req = request.transition
                self.get_logger().warning(
                    f"refused lifecycle transition {req.label or req.id} from state {label}: "
                    f"{str(exc).splitlines()[0]}"
                )
                response.success = False
                return response

        service.callback = guarded

    # ------------------------------------------------------------------------------- behaviour
    @property
    def rig(self) -> SimulatedRig | None:
        return self._rig

    def matched(self) -> int:
        """Fewest subscribers on any data topic (wait for the graph to match before activating)."""
        return min((p.get_subscription_count() for p in self._pubs.values()), default=0)  # type: ignore[attr-defined]

    @property
    def block_s(self) -> float:
        """Simulated time per block, s (after configure)."""
        return self._n_block / self._rig_config.sample_rate_hz

    @property
    def active(self) -> bool:
        return self._running

    def _stop_timer(self) -> None:
        self._running = False
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None

    @property
    def realtime_factor(self) -> float:
        return self._factor

    def share_time_origin(self, t0: float) -> None:
        """Start sample times at ``t0`` unless ``start_time_s`` was given (before configure)."""
        if not self._start_time:
            self._start_time = t0

    def step(self) -> None:
        """Advance one block now (bringup's pacer: every fin from one timer, so all share one time)."""
        if self._running:
            self._publish(self._n_block)

    def _on_command(self, msg: Float64MultiArray) -> None:
        if self._rig is None or not self._running:
            self._log_command("ignored: fin_sim is not active (the drive stays at 0 V)")
            return
        if self.battery_empty:
            self._log_command("ignored: the battery is empty (the drive stays at 0 V)")
            return
        try:
            f, v, on, bias = drive_command(msg)
        except BlockFormatError as exc:
            self._log_command(f"rejected: malformed command ({exc})")
            return
        except MessageRefused as exc:
            self._log_command(f"rejected: {exc}")
            return
        _, reason = self._rig.command(f, v, on, bias)
        if reason:
            self._log_command(reason)
        else:
            self.command_counts["accepted"] += 1

    def _on_limits(self, changes: list[Parameter]) -> str | None:
        """Drive limits may be tightened while running (an operator lowering the cap); relaxing one
        needs a restart.  Returns the reason a change is refused, or None once it is applied."""
        values = {f.name: getattr(self._limits, f.name) for f in fields(DriveLimits)}
        for p in changes:
            values[p.name.split(".", 1)[1]] = p.value
        try:
            new = DriveLimits(**values)
        except (TypeError, ValueError) as exc:
            return f"limits: {exc}"
        looser = loosened(new, self._limits)
        if looser:
            return "only tighter limits are taken while running (restart to relax): " + ", ".join(looser)
        what = self._rig.tighten(self._effective(new)) if self._rig is not None else "limits tightened"
        self._limits = new
        changed = ", ".join(f"{p.name} = {p.value:g}" for p in changes)
        self.get_logger().warning(f"{changed}: {what}")
        return None

    def _effective(self, limits: DriveLimits) -> DriveLimits:
        """The limits the rig runs with: simulated faster than real time, the watchdog waits at least
        WATCHDOG_MIN_WALL_S of wall time (in real time, or slower, the limits as set)."""
        floor = WATCHDOG_MIN_WALL_S * self._factor if self._factor > 1.0 else 0.0
        return replace(limits, command_timeout_s=max(limits.command_timeout_s, floor))

    # --------------------------------------------------------------------------- diagnostics
    #: a clamp, a refusal or a monitor at odds with the drive shows as WARN this long after the last one
    DIAGNOSED_S = 2.0

    def _fin_time(self) -> float:
        return self._rig.drive.t if self._rig is not None else self.get_clock().now().nanoseconds * 1e-9

    def _recent(self, ns: int) -> bool:
        return (self._steady.now().nanoseconds - ns) * 1e-9 <= self.DIAGNOSED_S

    def _diagnose_drive(self) -> Report:
        rig = self._rig
        counts = {f"commands {k}": n for k, n in sorted(self.command_counts.items())}
        if rig is None:
            return Report(OK, "not configured: no drive", counts)
        d, lim = rig.drive, rig.drive.limits
        values = {
            "frequency_hz": d.frequency_hz,
            "voltage_pp": d.voltage_pp,
            "target_voltage_pp": 2 * d.target,
            "limits.voltage_pp_max": lim.voltage_pp_max,
            "limits.slew_vpp_per_s": lim.slew_vpp_per_s,
            "watchdog_s": lim.command_timeout_s,
            "tripped": d.tripped,
            **counts,
        }
        if self.battery_empty:
            return Report(ERROR, "the battery is empty: the drive is stopped and takes no command", values)
        if d.tripped:
            return Report(
                ERROR,
                f"watchdog tripped (no command for over {lim.command_timeout_s:g} s): the drive ramped to "
                "0 V; on-commands are refused until an off command re-arms it",
                values,
            )
        if self._recent(self._clamped_ns):
            return Report(WARN, self._last_reason, values)
        if not self._running:
            return Report(OK, "inactive: the drive is off", values)
        if d.voltage_pp == 0 and d.target == 0:
            return Report(OK, "off", values)
        return Report(OK, f"driving {d.frequency_hz:.3g} Hz at {d.voltage_pp:.0f} Vpp", values)

    def _diagnose_monitor(self) -> Report:
        reading, applied = self._monitor
        values = {"reading_peak_V": reading, "applied_peak_V": applied}
        if self._recent(self._monitor_off_ns):
            return Report(
                WARN,
                f"the voltage monitor reads {reading:.0f} V where the drive applies {applied:.0f} V: "
                "its gain is off",
                values,
            )
        return Report(OK, "agrees with the drive", values)

    def _diagnose_battery(self) -> Report:
        fish = self._swimmer
        if fish is None or fish.battery is None:
            return Report(STALE, "not configured: no battery reading yet")
        r = fish.reading()
        values = {
            "voltage_V": r.voltage_v,
            "current_A": r.current_a,
            "percentage": r.percentage * 100,
            "charge_Ah": r.charge_ah,
            "capacity_Ah": r.capacity_ah,
        }
        if r.empty:
            return Report(ERROR, f"empty ({r.voltage_v:.2f} V under load): the drive is stopped", values)
        if r.percentage < BATTERY_LOW:
            return Report(WARN, f"low: {r.percentage * 100:.0f} % left ({r.voltage_v:.2f} V)", values)
        return Report(OK, f"{r.percentage * 100:.0f} % left ({r.voltage_v:.2f} V)", values)

    def _log_command(self, reason: str) -> None:
        """Keep and log the reason; bursts are logged once a second per kind (rejected, clamped,
        ignored) with the count of the rest of that kind, so a flood of one kind never hides
        another."""
        self._clamped_ns, self._last_reason = self._steady.now().nanoseconds, reason
        kind = reason.split(":", 1)[0]
        self.command_counts[kind] += 1
        self.command_log.append(reason)
        if len(self.command_log) > 1000:
            del self.command_log[:500]
        now = self.get_clock().now().nanoseconds
        if now - self._last_reason_log_ns.get(kind, -(2**62)) >= 1_000_000_000:
            rest = self._unlogged.pop(kind, 0)
            extra = f" (and {rest} more {kind} since the last such line)" if rest else ""
            self.get_logger().warning(reason + extra)
            self._last_reason_log_ns[kind] = now
        else:
            self._unlogged[kind] += 1
        self.diagnostics.update()

    def _tick(self) -> None:
        if not self._running:
            return  # a tick queued before deactivation: the drive is stopped
        if not self.consumers_ready():
            return
        self._publish(self._n_block)

    def consumers_ready(self) -> bool:
        """True once every data topic has ``wait_subscribers`` subscribers, or ``wait_subscribers_s``
        of wall time has passed since the first ask (said either way); the rig, and with it the
        fin's time and ``/clock``, does not advance before."""
        if self._consumers_ok:
            return True
        now = self._steady.now().nanoseconds
        if self._waiting_since_ns is None:
            self._waiting_since_ns = now
            self.get_logger().info(
                f"waiting for {self._wait_subscribers} subscriber(s) on each data topic (at most "
                f"{self._wait_subscribers_s:g} s) before the first sample"
            )
        have = self.matched()
        waited = (now - self._waiting_since_ns) * 1e-9
        if have >= self._wait_subscribers:
            self.get_logger().info(f"{have} subscriber(s) on each data topic after {waited:.1f} s: starting")
        elif waited >= self._wait_subscribers_s:
            self.get_logger().warning(
                f"only {have} of {self._wait_subscribers} subscriber(s) on the data topics after "
                f"{waited:.0f} s: starting anyway (a consumer that joins later misses the first samples)"
            )
        else:
            return False
        self._consumers_ok = True
        return True

    def _publish(self, n: int) -> None:
        rig = self._rig
        if rig is None:
            return
        b = rig.step(n)
        for event in b.events:
            self.get_logger().warning(event)
        reading = float(np.max(np.abs(b.voltage))) if b.voltage.size else 0.0
        self._monitor = (reading, float(b.applied_peak_v))
        if reading > 1.05 * b.applied_peak_v + 5.0 * self._rig_config.voltage_noise_v + 1.0:
            self._monitor_off_ns = self._steady.now().nanoseconds
            # a reading above what the drive applies is the monitor's (its gain), never the drive
            cap = rig.drive.limits.voltage_pp_max
            self.get_logger().warning(
                f"the voltage monitor reads {reading:.0f} V where the drive applies {b.applied_peak_v:.0f} V "
                f"(never more than limits.voltage_pp_max {cap:g} Vpp): the monitor's gain is off (an "
                "augmented model's voltage_monitor_gain?)",
                throttle_duration_sec=10.0,
            )
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=Time(nanoseconds=round(float(b.t[-1]) * 1e9)).to_msg()))
        blocks = {
            TOPIC_DRIVE: Block.from_columns(t_s=b.t, voltage_V=b.voltage, current_A=b.current),
            TOPIC_SUPPLY: Block.from_columns(
                t_s=b.t, supply_voltage_V=b.supply_voltage, supply_current_A=b.supply_current
            ),
        }
        if TOPIC_TIP in self._pubs:  # (the lab's instruments: a fish carries neither)
            blocks[TOPIC_TIP] = Block.from_columns(t_s=b.t, tip_velocity_m_s=b.tip_velocity)
            blocks[TOPIC_LOADCELL] = Block.from_columns(t_s=b.t, displacement_m=b.displacement)
        for topic, block in blocks.items():
            pub = self._pubs[topic]
            pub.publish(named_msg(pub.msg_type, block))  # type: ignore[attr-defined]
            self.published[topic] += n
        self.blocks_published += 1
        if self._swimmer is not None:
            self._swim(b, n)
        self.diagnostics.update()  # (a level that changed: on the monitor now, not at the next second)

    def _swim(self, b: RigBlock, n: int) -> None:
        """The body and the battery after this block (:class:`~piezofin_ros.rig.fish.FreeSwimmer`)."""
        rig, fish = self._rig, self._swimmer
        assert rig is not None and fish is not None and self._speed_pub is not None
        supply = float(np.mean(b.supply_voltage * b.supply_current))
        fish.advance(
            n / self._rig_config.sample_rate_hz,
            float(np.mean(b.thrust_true)),
            rig.drive.frequency_hz,
            supply,
            rig.drive.bias,
        )
        rig.swim_speed_m_s = fish.speed_m_s
        pub = self._speed_pub
        pub.publish(speed_msg(pub.msg_type, fish.speed_reading(), float(b.t[-1])))  # type: ignore[attr-defined]
        if self._imu_pub is not None:
            reading = imu_msg(*fish.imu_reading(), fish.gyro_noise_rad_s, float(b.t[-1]))
            self._imu_pub.publish(reading)  # type: ignore[attr-defined]
        if self._battery_pub is None:
            return
        t = float(b.t[-1])
        r = fish.reading()
        if t - self._battery_said_t >= 1.0 or (r.empty and not self.battery_empty):
            self._battery_said_t = t
            msg = BatteryState()
            msg.header.stamp = Time(nanoseconds=round(t * 1e9)).to_msg()
            msg.voltage, msg.current = float(r.voltage_v), -float(r.current_a)  # (negative: discharging)
            msg.charge, msg.capacity, msg.design_capacity = r.charge_ah, r.capacity_ah, r.capacity_ah
            msg.percentage = float(r.percentage)
            msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
            msg.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LION
            msg.power_supply_health = (
                BatteryState.POWER_SUPPLY_HEALTH_DEAD if r.empty else BatteryState.POWER_SUPPLY_HEALTH_GOOD
            )
            msg.present = True
            # as sensor_msgs/BatteryState asks: NaN where nothing measures it, one entry per cell (the
            # model's cells share the pack's voltage alike)
            cells = self._battery.cells if self._battery is not None else 1
            msg.temperature = math.nan
            msg.cell_voltage = [float(r.voltage_v) / cells] * cells
            msg.cell_temperature = [math.nan] * cells
            msg.header.frame_id = "base_link"
            msg.location = "fish body"
            msg.serial_number = f"simulated {self._battery.name}" if self._battery is not None else ""
            self._battery_pub.publish(msg)  # type: ignore[attr-defined]
        if r.empty and not self.battery_empty:
            self.battery_empty = True
            self.get_logger().error(
                f"the battery is empty ({r.voltage_v:.2f} V under load, {fish.distance_m:.0f} m swum on "
                f"{fish.energy_j / 3600:.2f} W h): the drive stops and takes no command"
            )
            rig.stop()

    def _ramp_down(self, why: str) -> None:
        rig = self._rig
        if rig is None:
            return
        rig.stop()
        ramp_s = rig.drive.voltage_pp / max(rig.drive.limits.slew_vpp_per_s, STOP_SLEW_VPP_PER_S)
        n = math.ceil((ramp_s + 0.05) * self._rig_config.sample_rate_hz)
        if rig.drive.voltage_pp > 0:
            self.get_logger().info(f"{why}: ramping the drive from {rig.drive.voltage_pp:.0f} Vpp to 0 V")
        while n > 0:
            step = min(n, self._n_block)
            self._publish(step)
            n -= step

    def close(self) -> None:
        """Ramp the drive down (if still active) and report what was published."""
        if self._running:
            if self.context.ok():
                self._ramp_down("stopping")
            self._stop_timer()
        counts = ", ".join(f"{k} {v}" for k, v in self.published.items())
        commands = ", ".join(f"{k} {v}" for k, v in sorted(self.command_counts.items())) or "none"
        self.get_logger().info(f"published samples: {counts}; commands: {commands}")


class Pacer:
    """Steps several fins together from one steady-clock timer, so all share one time.

    Each tick advances every active fin by one block, while ``ready()`` (default: always; bringup
    waits for its slowest consumer).  Used by ``fin_sims`` and by ``bringup``.
    """

    def __init__(self, fin_sims: list[FinSim], ready: Callable[[], bool] | None = None) -> None:
        durations = {round(sim.block_s, 9) for sim in fin_sims}
        factors = {sim.realtime_factor for sim in fin_sims}
        if len(durations) != 1 or len(factors) != 1:
            raise StartupError(
                f"fins stepped together need one block_s and one realtime_factor (got block_s "
                f"{sorted(durations)}, realtime_factor {sorted(factors)})"
            )
        self.fin_sims = fin_sims
        self.ready = ready
        self.steps = 0
        self.waits = 0  # ticks skipped because not ready
        for sim in fin_sims:
            sim.paced = True
        self._clock = RosClock(clock_type=ClockType.STEADY_TIME)
        self.last_step_ns = self._clock.now().nanoseconds
        self._timer = fin_sims[0].create_timer(durations.pop() / factors.pop(), self._tick, clock=self._clock)

    def _tick(self) -> None:
        waiting = [sim for sim in self.fin_sims if sim.active and not sim.consumers_ready()]  # ask each
        if waiting or (self.ready is not None and not self.ready()):
            self.waits += 1
            return
        for sim in self.fin_sims:
            sim.step()
        self.steps += 1
        self.last_step_ns = self._clock.now().nanoseconds

    def stalled_s(self) -> float:
        return (self._clock.now().nanoseconds - self.last_step_ns) * 1e-9


def _start(node: FinSim) -> None:
    if not node.autostart:
        return
    if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
        raise StartupError(f"{node.get_fully_qualified_name()} failed to configure (see the log line above)")
    node.trigger_activate()


def main(args: list[str] | None = None) -> int:
    return run_node(
        lambda context: FinSim(context=context),
        args,
        until=lambda node: node.finalized,
        start=_start,
    )


def fins_main(args: list[str] | None = None) -> int:
    """``fin_sims --namespaces left right [--realtime-factor F] [--publish-clock] [--ros-args ...]``:
    one ``fin_sim`` per namespace in one process, configured and activated at start and stepped
    together by one :class:`Pacer`: every fin has the same sample times, and with
    ``--publish-clock`` the first one publishes ``/clock``.  Parameters (``--params-file``, ``-p``)
    apply to every fin; the options override them.  Each fin is a lifecycle node of its own
    (``ros2 lifecycle set /left/fin_sim deactivate``)."""
    import argparse
    import time

    from rclpy.utilities import remove_ros_args

    argv = list(args if args is not None else sys.argv)
    parser = argparse.ArgumentParser(prog="fin_sims", description=fins_main.__doc__.splitlines()[0])  # type: ignore[union-attr]
    parser.add_argument("--namespaces", nargs="+", required=True, help="one namespace per fin")
    parser.add_argument("--realtime-factor", type=float, help="simulated s per wall s (every fin)")
    parser.add_argument("--publish-clock", action="store_true", help="the first fin publishes /clock")
    parser.add_argument(
        "--wait-subscribers", type=int, help="subscribers each fin's data topics need before the first sample"
    )
    opts = parser.parse_args(remove_ros_args(argv)[1:])
    t0 = time.time()  # one time origin for every fin

    def build(context: Any) -> list[FinSim]:
        fins = []
        for k, ns in enumerate(opts.namespaces):
            extra = [Parameter("autostart", value=True)]
            extra.append(Parameter("publish_clock", value=opts.publish_clock and k == 0))  # one /clock
            if opts.realtime_factor is not None:
                extra.append(Parameter("realtime_factor", value=float(opts.realtime_factor)))
            if opts.wait_subscribers is not None:
                extra.append(Parameter("wait_subscribers", value=int(opts.wait_subscribers)))
            fins.append(FinSim(context=context, namespace=ns, parameter_overrides=extra))
        for sim in fins:
            sim.share_time_origin(t0)
            sim.paced = True  # before activation: the Pacer's timer, not one per fin
        return fins

    return run_node(
        build,
        argv,
        until=lambda node: node.finalized,
        start=_start,
        after_start=lambda nodes: Pacer(nodes),
    )


if __name__ == "__main__":
    sys.exit(main())
