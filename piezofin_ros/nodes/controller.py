"""``controller``: runs trials through ``cmd``, reads ``estimate``, reports on ``controller/status``.

Commands are repeated every ``1/heartbeat_hz`` seconds (``fin_sim``'s watchdog ramps the
drive down when they stop) and never exceed this node's own limits.  When a trial's estimate
does not come (the estimator or the rig is gone), the trial is marked missing and logged; after
``max_missing`` in a row the run stops and the drive is commanded off.  At the end the chosen
point (most thrust per watt among trials with at least ``min_thrust_n``) is either held or the
drive is switched off (``after``).

The first trial waits (drive off) until a ``thrust_estimator`` publishes on ``estimate`` and a rig
on ``drive``, at most
``wait_estimator_s`` of wall time: under ``ros2 launch`` the nodes start in any order, and on a
loaded machine the estimator may be the last, which used to cost the first trial its estimate.
Once it is there the drive stays off :data:`ESTIMATOR_SETTLE_S` more, so that the estimator hears
the rig at rest (a fish learns its battery's fixed draw there); ranking by the measured supply watt,
until the estimator's ``thrust_estimator/status`` says it measures it (within the same bound).
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from typing import Any

from rclpy.context import Context
from rclpy.node import Node
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from ..bags.blocks import Block
from ..config import HARD_VOLTAGE_PP_MAX, HARD_VOLTAGE_WINDOW_V, setting
from ..control.driveloop import DriveLoop
from ..control.objective import OBJECTIVES
from ..control.optimise import OperatingBox, Optimiser
from ..control.strategy import ControllerMode, OptimiseStrategy, Strategy, TrialStrategy
from ..control.trials import SOURCES, Mode, TrialPlan, TrialResult, TrialRunner
from ..errors import PiezofinError
from ..estimation.estimator import Estimate
from ..physics.amplifier import WATT, AmplifierError, load_amplifier
from ..physics.effects import ModelError
from ..physics.fin import load_fin
from ..physics.model import load_model
from ..physics.planar import bias_window_v
from ..physics.waveforms import ProtocolTiming
from ._common import (
    TOPIC_BATTERY,
    TOPIC_BIAS,
    TOPIC_CMD,
    TOPIC_DEMAND,
    TOPIC_DRIVE,
    TOPIC_ESTIMATE,
    TOPIC_ESTIMATOR_STATUS,
    TOPIC_MODEL,
    TOPIC_STATUS,
    TOPIC_SUPPLY,
    TOPIC_VOLTAGE_CAP,
    Inbox,
    SilenceWatch,
    StartupError,
    block_msg,
    declare,
    endpoint,
    estimates,
    freeze_parameters,
    run_node,
    scalar,
    supply_measured_on,
)
from ._diagnostics import ERROR, OK, STALE, WARN, Diagnostics, Report


@dataclass(frozen=True)
class ControllerConfig:
    """``controller``'s parameters."""

    mode: str = setting(
        "protocol",
        "protocol or continuous (trials of a grid), frf (a stepped sine that settles at each point, for "
        "`piezofin identify`), or optimise (thrust per watt)",
        choices=tuple(m.value for m in ControllerMode),
    )
    frequencies: tuple[float, ...] = setting((5.5,), "trial frequencies, Hz", items=float)
    voltages: tuple[float, ...] = setting((800.0,), "trial voltages, Vpp", items=float)
    off_s: float = setting(
        ProtocolTiming.off_s, "protocol: time without voltage before and after, s", 0.5, 600.0
    )
    on_s: float = setting(ProtocolTiming.on_s, "protocol: time of sine drive, s", 1.0, 600.0)
    settle_timeout_s: float = setting(30.0, "continuous and frf: longest stay at one point, s", 1.0, 3600.0)
    settle_tolerance: float = setting(
        0.005, "frf: consecutive estimates agreeing this closely (relative) mean settled", 1e-5, 0.5
    )
    voltage_pp_max: float = setting(800.0, "never command more than this, Vpp", 0.0, HARD_VOLTAGE_PP_MAX)
    frequency_min_hz: float = setting(1.0, "lowest frequency, Hz", 0.01, 1000.0)
    frequency_max_hz: float = setting(40.0, "highest frequency, Hz", 0.01, 1000.0)
    heartbeat_hz: float = setting(10.0, "command repetition rate, Hz", 1.0, 1000.0)
    min_thrust_n: float = setting(1e-3, "least thrust of the chosen point, N", 0.0, 10.0)
    source: str = setting("self", f"estimate that ranks points: {', '.join(SOURCES)}", choices=tuple(SOURCES))
    watt: str = setting(
        "supply",
        "the watt of the thrust per watt that ranks points: supply (what the battery pays, through the "
        "estimator's amplifier), supply_measured (the supply topic), fin (mean(v i)) or apparent",
        choices=tuple(WATT),
    )
    objective: str = setting(
        "thrust_per_watt",
        "what chooses a point in that watt (the optimiser and the trial modes): thrust_per_watt (the "
        "paper's), or range (a fish's speed per watt, sqrt(thrust) / (watt + fixed_draw_w)); under a "
        "demand both take the least watt",
        choices=tuple(OBJECTIVES),
    )
    fixed_draw_w: float = setting(
        0.0,
        "optimise, objective range: the draw paid whatever the fin does (a fish's hotel load), W",
        0.0,
        1e3,
    )
    after: str = setting(
        "stop", "after the trials: stop (0 V) or hold (drive the chosen point)", choices=("stop", "hold")
    )
    max_missing: int = setting(2, "missing estimates in a row that stop the run", 1, 1000)
    wait_estimator_s: float = setting(
        20.0,
        "wall time to wait for a thrust_estimator and a rig's drive before the first trial, s (0: none)",
        0.0,
        3600.0,
    )
    amplifier: str = setting(
        "paper-bench",
        "optimise: the amplifier (preset or YAML) whose draw is the supply watt, as the estimator's",
    )
    fin: str = setting("M8528-P1", "fin preset name or YAML path (the optimiser's model)")
    model: str = setting(
        "", "optimise: augmented model YAML from `piezofin diagnose --report` (replaces fin)"
    )
    demand_n: float = setting(0.0, "optimise: thrust demand, N (0: none)", 0.0, 10.0)
    demand_margin_z: float = setting(
        2.0,
        "optimise: a point meets the demand when its thrust less this many sigma of its uncertainty "
        "does (2: met in truth; 0: at the estimate, for a speed loop that closes on the speed)",
        0.0,
        5.0,
    )
    trial_overshoot: float = setting(
        0.0,
        "optimise: no trial at a measured point whose thrust exceeded the demand by more than this, "
        "relative (0: no limit; a fish's speed follows each trial's thrust)",
        0.0,
        10.0,
    )
    voltage_pp: float = setting(
        800.0, "optimise, no demand: the drive voltage, Vpp", 1.0, HARD_VOLTAGE_PP_MAX
    )
    slew_vpp_per_s: float = setting(400.0, "optimise: voltage slew limit, Vpp/s", 1.0, 1e5)
    estimate_timeout_s: float = setting(
        10.0, "optimise: hold after this long without estimates, s", 0.5, 600.0
    )
    duration_s: float = setting(0.0, "optimise: stop after this long (0: never)", 0.0, 1e7)


#: no estimate for this long (wall time) is STALE on /diagnostics (they come every second or faster)
ESTIMATES_STALE_S = 3.0
#: the drive held off this long (fin time) after an estimator appears, so that it hears the rig at
#: rest: a fish learns its battery's fixed draw there (stop 45 saw a stack that drove 0.2 s after the
#: estimator appeared learn none, and rank by the amplifier's model)
ESTIMATOR_SETTLE_S = 1.0
#: An offset on bias_demand older than this (node clock, s) is dropped: a yaw loop that fell silent
#: leaves the fin straight.
BIAS_FRESH_S = 1.0


def fitted_model_message(fin: str, base: str, c: Any, opt: Any, t_s: float) -> dict[str, object]:
    """``controller/model``'s JSON: the fin, the base model the correction applies on (the
    ``model`` parameter; "": the fin file), the fitted numbers, what they rest on, and the fin time
    (the node's clock) from which an estimator's windows take it."""
    return {
        "fin": fin,
        "base": base,
        "t_s": t_s,
        "correction": c.fitted(),
        "trials": len(opt.observations),
        "misfit_sigma": math.sqrt(max(opt.fit.chi2, 0.0)),
    }


class Controller(Node):
    def __init__(self, *, context: Context | None = None, node_name: str = "controller", **kwargs: object):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        c = self.config = declare(self, ControllerConfig)
        freeze_parameters(self)
        try:
            self.amplifier = load_amplifier(c.amplifier)
        except AmplifierError as exc:
            raise StartupError(f"parameter amplifier: {exc}") from None
        self._created = time.monotonic()
        self._waiting_logged = False
        self._estimator_seen: float | None = None  # (the fin time it appeared)
        # where the estimator measures the supply watt, by its status (None: no status heard yet)
        self._measured_on: str | None = None
        self._meter_waiting = ""  # (what was said while waiting for it: "waiting", then "gave up")
        self.strategy: Strategy
        if ControllerMode(c.mode).trial_mode is None:
            self.strategy, summary = self._optimiser(c)
        else:
            self.strategy, summary = self._trials(c)
        self._cmd_pub = self.create_publisher(*endpoint(TOPIC_CMD))
        self._status_pub = self.create_publisher(*endpoint(TOPIC_STATUS))
        self._status_wall = -math.inf  # (time.monotonic) when the status was last published
        # the fitted fin, once the corrected model fits its trials: an estimator's self-sensing follows it
        self._model_pub = self.create_publisher(*endpoint(TOPIC_MODEL)) if self.loop is not None else None
        self._model_sent: object = None  # (the correction last sent)
        # every message from another process: its failure said, never fatal.  Looked at every 50 ms of
        # the fish's time: 20 times a second on a fish, not 100, 2 % of a core less; and as often as
        # 100 times a second of wall time at x10 (at 20, the yaw loop's offset came up to 0.5 s of
        # fish time late: the turn fell 16 % short and the course went 1 m off its line).
        self.inbox = Inbox(self, node_time_s=Inbox.NODE_TIME_S)
        # polled (a flood of estimates held the executor, and the heartbeat with it: the watchdog tripped)
        self.inbox.polled(
            endpoint(TOPIC_ESTIMATE)[0], TOPIC_ESTIMATE, self._on_estimate, estimates, depth=200, most=20
        )
        self.inbox.latest(
            endpoint(TOPIC_ESTIMATOR_STATUS)[0],
            TOPIC_ESTIMATOR_STATUS,
            self._on_estimator_status,
            supply_measured_on,
        )
        if self.strategy.takes_demand:
            # the newest demand only, polled: a 3-4 kHz flood held the executor and the heartbeat with it
            self.inbox.latest(Float64, TOPIC_DEMAND, self._on_demand, scalar(0.0, 10.0, "N"))
        # a yaw loop's offset (the speed loop's, or a fish stack's), V: added to the drive it sends
        self._bias = (0.0, -math.inf)  # (the offset, when it came: node clock, s)
        low, high = HARD_VOLTAGE_WINDOW_V
        self.inbox.latest(Float64, TOPIC_BIAS, self._on_bias, scalar(low, high, "V"))
        self._cap_at = -math.inf  # (node clock, s) the latest voltage cap; none older than BIAS_FRESH_S
        if self.loop is not None:
            # and the most voltage that leaves the offset its room: the optimiser's box under it
            self.inbox.latest(
                Float64, TOPIC_VOLTAGE_CAP, self._on_voltage_cap, scalar(0.0, high - low, "Vpp")
            )
            # the quiet identification trial, when the fish's stack says its speed may drop (never by a
            # timer that ages evidence out: a fish fell to 1.2-2.6 cm/s for 20-30 s every 320-470 s)
            self.create_service(Trigger, "~/identify", self._on_identify)
        self._timer = self.create_timer(1.0 / c.heartbeat_hz, self._tick)
        # the heartbeat runs on ROS time: with use_sim_time it stops with /clock (fin_sim gone)
        self._silence = SilenceWatch(
            self, "time (the heartbeat)", "with use_sim_time: is fin_sim publishing /clock?"
        )
        self._estimate_wall = -math.inf  # (time.monotonic) the latest estimate taken
        self.diagnostics = Diagnostics(self, c.model or c.fin)
        self.diagnostics.add("drive", self._diagnose_drive)
        self.diagnostics.add("estimates", self._diagnose_estimates)
        if self.loop is not None:
            self.diagnostics.add("fin model", self._diagnose_model)
        self.get_logger().info(summary)

    def _diagnose_drive(self) -> Report:
        status = self.strategy.status()
        values = {k: v for k, v in status.items() if isinstance(v, (int, float, str, bool)) or v is None}
        loop = self.loop
        if loop is None:
            runner, mode, chosen = self.runner, self.config.mode, self.chosen
            if runner.aborted:
                return Report(ERROR, f"{mode}: stopped, {runner.aborted}", values)
            if not self.finished:
                return Report(OK, f"{mode}: trial {runner.index + 1} of {len(runner.plan.points)}", values)
            if self.config.after == "hold" and chosen is not None:
                held = f"{chosen.frequency_hz:.3g} Hz at {chosen.voltage_pp:.0f} Vpp"
                return Report(OK, f"{mode}: done, holding the point chosen, {held}", values)
            return Report(OK, f"{mode}: done, the drive is off", values)
        state = loop.state
        f, v = loop.target if loop.target is not None else (math.nan, math.nan)
        if loop.halted:
            return Report(OK, "finished: the drive is off", values)
        if state == "holding":
            return Report(WARN, f"no estimates: holding {f:.3g} Hz, {v:.0f} Vpp", values)
        if state in ("ramping down", "stopped"):
            return Report(ERROR, f"no estimates: drive {state} (it retries)", values)
        return Report(OK, f"driving {f:.3g} Hz at {loop.command_v:.0f} Vpp ({loop.trials} trials)", values)

    def _diagnose_model(self) -> Report:
        """Whether the fin model it was given still explains the trials (issue 39: a wrong prior)."""
        assert self.loop is not None
        opt = self.loop.optimiser
        given = self.config.model or self.config.fin
        values = {
            "given": given,
            "trials": len(opt.observations),
            "self_sensing_bound": opt.self_sensing_bound,
            "optimiser_mode": str(opt.mode),
        }
        if opt.prior_dropped:
            return Report(WARN, opt.prior_dropped, values)
        return Report(OK, f"{given}, corrected by {len(opt.observations)} trials", values)

    def _diagnose_estimates(self) -> Report:
        ago = time.monotonic() - self._estimate_wall
        topic = self.resolve_topic_name(TOPIC_ESTIMATE)
        values = {
            "seconds since the latest (wall time)": ago,
            "publishers": self.count_publishers(TOPIC_ESTIMATE),
        }
        if not math.isfinite(ago):
            return Report(STALE, f"none yet on {topic}", values)
        if ago > ESTIMATES_STALE_S:
            return Report(STALE, f"none for {ago:.0f} s on {topic}: is thrust_estimator running?", values)
        return Report(OK, f"taking estimates from {topic}", values)

    def _optimiser(self, c: ControllerConfig) -> tuple[Strategy, str]:
        """The thrust-per-watt optimiser's strategy (``mode:=optimise``), and what it says at start."""
        try:
            model = load_model(c.model) if c.model else None
        except ModelError as exc:
            raise StartupError(f"parameter model: {exc}") from None
        try:
            box = OperatingBox(c.frequency_min_hz, c.frequency_max_hz, 50.0, c.voltage_pp_max)
            fin = model.fin if model is not None else load_fin(c.fin)
            optimiser = Optimiser(
                fin,
                box,
                c.voltage_pp,
                c.demand_n or None,
                min_thrust_n=c.min_thrust_n,
                source=c.source,
                watt=c.watt,
                objective=OBJECTIVES[c.objective](c.fixed_draw_w),
                amplifier=self.amplifier,
                model=model,
                demand_margin_z=c.demand_margin_z,
                trial_overshoot=c.trial_overshoot,
            )
        except PiezofinError as exc:
            raise StartupError(f"optimiser: {exc}") from None
        if model is not None:
            self.get_logger().info(
                f"optimiser starts from the augmented model {c.model} ({', '.join(model.names)})"
            )
        loop = DriveLoop(optimiser, c.source, c.slew_vpp_per_s, c.estimate_timeout_s, background=True)
        # the fits run in a thread beside the executor's: a CPU-bound thread holds the GIL for the
        # whole switch interval (5 ms) each time the executor's thread lets go of it, and a callback
        # lets go of it many times (the convoy effect): under a flood of demands the heartbeat fell
        # seconds behind and fin_sim's watchdog tripped.  A short interval bounds that wait.
        sys.setswitchinterval(min(sys.getswitchinterval(), 0.0005))
        goal = (
            f"demand {c.demand_n * 1e3:.2f} mN" if c.demand_n else f"best frequency at {c.voltage_pp:g} Vpp"
        )
        summary = f"optimising {optimiser.objective.name} ({c.watt} watt) from {c.source} estimates, {goal}"
        return OptimiseStrategy(loop, c.duration_s, c.after), summary

    def _trials(self, c: ControllerConfig) -> tuple[Strategy, str]:
        """A plan of trials (``mode:=protocol``, ``continuous`` or ``frf``), and what it says at start."""
        bad = [f for f in c.frequencies if not (math.isfinite(f) and 0 < f <= c.frequency_max_hz)]
        bad += [v for v in c.voltages if not (math.isfinite(v) and 0 <= v <= c.voltage_pp_max)]
        if bad:
            raise StartupError(
                f"parameters frequencies/voltages: {bad} outside (0, {c.frequency_max_hz:g}] Hz / "
                f"[0, {c.voltage_pp_max:g}] Vpp"
            )
        try:
            plan = TrialPlan.grid(
                c.frequencies,
                c.voltages,
                mode=ControllerMode(c.mode).trial_mode or Mode.PROTOCOL,  # (never the optimiser's here)
                off_s=c.off_s,
                on_s=c.on_s,
                settle_timeout_s=c.settle_timeout_s,
                settle_tolerance=c.settle_tolerance,
            )
        except PiezofinError as exc:
            raise StartupError(f"trial plan: {exc}") from None
        objective = OBJECTIVES[c.objective](c.fixed_draw_w)
        strategy = TrialStrategy(
            TrialRunner(plan), c.source, c.min_thrust_n, c.max_missing, c.after, c.watt, objective
        )
        n = len(plan.points)
        fin_time = f", {n * plan.trial_s:.0f} s of fin time" if plan.mode is Mode.PROTOCOL else ""
        return strategy, f"{n} {c.mode} trials{fin_time}, choosing by {objective.name} ({c.watt} watt)"

    # what tests, bringup and users look at: the strategy's own state
    @property
    def finished(self) -> bool:
        return self.strategy.finished

    @property
    def loop(self) -> DriveLoop | None:
        return self.strategy.loop if isinstance(self.strategy, OptimiseStrategy) else None

    @property
    def runner(self) -> TrialRunner:
        assert isinstance(self.strategy, TrialStrategy), "the optimiser runs no plan of trials"
        return self.strategy.runner

    @property
    def chosen(self) -> TrialResult | None:
        return self.strategy.chosen if isinstance(self.strategy, TrialStrategy) else None

    def planned_s(self) -> float | None:
        """Fin time the run needs (None: an optimiser without ``duration_s`` runs until stopped)."""
        return self.strategy.planned_s()

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _send(self, f: float, v: float, on: float) -> None:
        """One command: the drive's point and, while a yaw loop asks one (within the last
        :data:`BIAS_FRESH_S`), its offset, within the room the sine leaves in the MFC's window (a rig
        driver without an offset reads the first three values)."""
        v = min(max(v, 0.0), self.config.voltage_pp_max)  # belt and braces: the plan was checked at start
        record = {"frequency_hz": f, "voltage_pp_V": v, "on": on}
        bias, at = self._bias
        if on and bias != 0.0 and self._now() - at <= BIAS_FRESH_S:
            low, high = bias_window_v(v)
            record["bias_V"] = min(max(bias, low), high)
        self._cmd_pub.publish(block_msg(Block.from_record(record)))

    def _on_bias(self, bias_v: float) -> None:
        self._bias = (bias_v, self._now())

    def _on_voltage_cap(self, voltage_pp: float) -> None:  # (within the window's span: checked at the door)
        assert self.loop is not None
        self._cap_at = self._now()
        self.loop.set_voltage_cap(voltage_pp)

    def _voltage_cap_expired(self, t: float) -> None:
        """A cap older than :data:`BIAS_FRESH_S` goes (a yaw loop that fell silent holds no drive down)."""
        if self.loop is not None and math.isfinite(self._cap_at) and t - self._cap_at > BIAS_FRESH_S:
            self._cap_at = -math.inf
            self.loop.set_voltage_cap(None)

    def _estimator_ready(self) -> bool:
        """True :data:`ESTIMATOR_SETTLE_S` after an estimator publishes ``estimate`` and a rig
        ``drive``, and once the estimator measures the supply watt where that ranks the points
        (:meth:`_meter_pending`); or once ``wait_estimator_s`` passed without them; else drive off.
        The rig too: a fish's own driver, started apart from the launch, was discovered 1.7 s after
        the estimator on a loaded machine, the drive was on by then, and the estimator never heard
        the battery at rest (so never measured the supply watt: ``test_fish_driver.py`` in one CI
        run)."""
        if (
            self._estimator_seen is None
            and self.count_publishers(TOPIC_ESTIMATE) > 0
            and self.count_publishers(TOPIC_DRIVE) > 0
        ):
            self._estimator_seen = self._now()
        if self._estimator_seen is not None:
            if self._now() - self._estimator_seen >= ESTIMATOR_SETTLE_S and not self._meter_pending():
                return True
            self._send(0.0, 0.0, 0.0)
            return False
        waited = time.monotonic() - self._created
        if waited >= self.config.wait_estimator_s:
            if self._waiting_logged:
                missing = "thrust_estimator" if self.count_publishers(TOPIC_ESTIMATE) == 0 else "rig driver"
                self.get_logger().warning(
                    f"no {missing} after {self.config.wait_estimator_s:g} s: starting without one"
                    + (
                        f" (nothing publishes {self.resolve_topic_name(TOPIC_DRIVE)})"
                        if missing == "rig driver"
                        else ""
                    )
                )
                self._waiting_logged = False
            return True
        if not self._waiting_logged:
            self._waiting_logged = True
            self.get_logger().info(
                f"waiting for a thrust_estimator on {self.resolve_topic_name(TOPIC_ESTIMATE)} and a rig "
                f"on {self.resolve_topic_name(TOPIC_DRIVE)} (at most {self.config.wait_estimator_s:g} s), "
                "drive off"
            )
        self._send(0.0, 0.0, 0.0)
        return False

    def _on_estimator_status(self, measured_on: str) -> None:
        self._measured_on = measured_on

    def _meter_pending(self) -> bool:
        """True while the points are ranked by a measured watt (``watt`` supply_measured: a fish's
        battery), a battery or supply meter publishes, and the estimator's status does not yet
        say it measures that watt: the drive stays off, so that the estimator learns the battery's
        fixed draw at rest.  Its discovery of the fish's driver is its own: Fast DDS finds a
        publisher within 0.6 s or after 2.2-2.6 s, so the controller's own view of the driver, and
        its 1 s settle, left the estimator at rest too briefly in three CI runs (no supply watt
        measured for the whole run).  At most ``wait_estimator_s`` from the start, then said."""
        if not WATT[self.config.watt].measured or self._measured_on:
            return False
        if self.count_publishers(TOPIC_BATTERY) + self.count_publishers(TOPIC_SUPPLY) == 0:
            return False
        log = self.get_logger()
        if time.monotonic() - self._created >= self.config.wait_estimator_s:
            if self._meter_waiting != "gave up" and self.config.wait_estimator_s > 0:  # (0: asked not to)
                self._meter_waiting = "gave up"
                log.warning(
                    f"the thrust_estimator has not measured the supply watt after "
                    f"{self.config.wait_estimator_s:g} s (its status on "
                    f"{self.resolve_topic_name(TOPIC_ESTIMATOR_STATUS)}): starting, ranked by the amplifier "
                    "model's watt till it does"
                )
            return False
        if not self._meter_waiting:
            self._meter_waiting = "waiting"
            log.info(
                "waiting for the thrust_estimator to measure the supply watt (the battery's fixed draw "
                f"is learnt with the drive off; at most {self.config.wait_estimator_s:g} s), drive off"
            )
        return True

    def _tick(self) -> None:
        t = self._now()
        if t == 0.0:
            return  # use_sim_time and no /clock yet
        self._silence.heard()
        strategy = self.strategy
        if not strategy.started() and not self._estimator_ready():
            return
        self._voltage_cap_expired(t)
        command = strategy.command(t)
        self._publish_model()  # (before the command that moves the drive to the fit's next point)
        log = self.get_logger()
        for event in strategy.events:  # one call site per severity: rclpy's logger requires it
            if event.level == "error":
                log.error(event.text)
            elif event.level == "warning":
                log.warning(event.text)
            else:
                log.info(event.text)
        strategy.events.clear()
        self._send(*command)
        self.diagnostics.update()
        # (and once a second of wall time whatever: a `ros2 topic echo --once` that joins before its
        # node has discovered the publisher asks a volatile profile, and a protocol's status, sent on
        # change, had it wait for the next trial: 4.1 s in the launch test, or forever once done)
        if strategy.status_due(t) or time.monotonic() - self._status_wall >= 1.0:
            self._publish_status()

    def _publish_model(self) -> None:
        """``controller/model``: the fitted correction, each time it changes once the corrected model
        fits its trials (``Optimiser.fitted_correction``), with the base it applies on (the model this
        controller was given while it keeps it; none once dropped: the fin file)."""
        loop = self.loop
        if loop is None or self._model_pub is None:
            return
        opt = loop.optimiser
        c = opt.fitted_correction()
        if c is None or c is self._model_sent:
            return
        self._model_sent = c
        base = self.config.model if c.base is not None else ""
        message = fitted_model_message(opt.fin.name, base, c, opt, self._now())
        self._model_pub.publish(String(data=json.dumps(message)))

    def _on_demand(self, d: float) -> None:  # (within [0, 10] N: checked at the door)
        self.strategy.set_demand(d or None)  # (the loop coalesces a flood: one fit at a time)
        self.get_logger().info(
            f"thrust demand {d * 1e3:.2f} mN" if d else "no thrust demand", throttle_duration_sec=2.0
        )

    def _on_estimate(self, e: Estimate) -> None:
        self._estimate_wall = time.monotonic()
        if self.strategy.add_estimate(self._now(), e):
            self._publish_status()

    def _on_identify(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        loop = self.loop
        assert loop is not None
        loop.optimiser.request_identification()
        response.success = True
        response.message = (
            "a quiet identification trial comes after the running one (the thrust drops while it runs)"
        )
        self.get_logger().info(f"asked on {self.resolve_service_name('~/identify')}: {response.message}")
        return response

    def status(self) -> dict[str, object]:
        return self.strategy.status()

    def _publish_status(self) -> None:
        self._status_wall = time.monotonic()
        self._status_pub.publish(String(data=json.dumps(self.status(), allow_nan=True)))

    def destroy_node(self) -> None:
        self.inbox.close()  # (its hidden helper node, which holds the polled subscriptions)
        super().destroy_node()

    def close(self) -> None:
        if self.context.ok():
            self._send(0.0, 0.0, 0.0)  # leave the drive off
        self.strategy.close()  # (a fit queued behind the running one would hold the exit)


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: Controller(context=ctx), args)


if __name__ == "__main__":
    sys.exit(main())
