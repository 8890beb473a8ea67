"""``thrust_estimator``: :class:`~piezofin_ros.estimation.estimator.StreamEstimator` on the live topics.

Subscribes ``drive`` (required), ``tip_velocity`` and ``loadcell`` (optional: a fish has
neither), ``supply`` or ``battery`` (sensor_msgs/BatteryState: the supply watt measured) and
``swim_speed`` (geometry_msgs/TwistStamped, m/s); publishes one ``estimate``
(piezofin_msgs/Estimate: each quantity by name, stamped at the window's end in the fin's time) per
window, and ``thrust_estimator/status`` (JSON: what it has heard, and where it measures the supply
watt) when that changes and once a second.  All timing comes from the samples' own time stamps, so
a replayed bag gives the estimates recorded live.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.node import Node
from sensor_msgs.msg import BatteryState
from std_msgs.msg import String

from ..bags.blocks import (
    DRIVE_CHANNELS,
    LOADCELL_CHANNELS,
    SUPPLY_CHANNELS,
    TIP_CHANNELS,
    Block,
)
from ..config import setting
from ..errors import PiezofinError
from ..estimation.estimator import Estimate, EstimatorConfig, StreamEstimator
from ..estimation.selfsense import calibrated_by
from ..physics.amplifier import AmplifierError, load_amplifier
from ..physics.fin import MEDIA, load_fin
from ._common import (
    TOPIC_BATTERY,
    TOPIC_DRIVE,
    TOPIC_ESTIMATE,
    TOPIC_ESTIMATOR_STATUS,
    TOPIC_LOADCELL,
    TOPIC_MODEL,
    TOPIC_SPEED,
    TOPIC_SUPPLY,
    TOPIC_TIP,
    Inbox,
    MessageRefused,
    SilenceWatch,
    StartupError,
    battery_reading,
    declare,
    endpoint,
    freeze_parameters,
    json_object,
    record_msg,
    run_node,
    samples,
    speed_reading,
)
from ._diagnostics import OK, STALE, WARN, Diagnostics, Report


@dataclass(frozen=True)
class ThrustEstimatorConfig:
    """``thrust_estimator``'s parameters (and ``estimator.*`` from :class:`EstimatorConfig`)."""

    fin: str = setting("M8528-P1", "fin preset name or YAML path")
    model: str = setting(
        "",
        "augmented model YAML (`piezofin diagnose --report`): its capacitance, loss conductance, coupling "
        "and c_m calibrate the self-sensed and Lighthill thrust (replaces fin)",
    )
    medium: str = setting(
        "water",
        "water, or air (an in-air sweep: no thrust is estimated, only motion and power)",
        choices=MEDIA,
    )
    amplifier: str = setting(
        "paper-bench",
        "the amplifier driving the fin (preset or YAML): its model gives the supply's watt; a supply "
        "topic, where the rig or the fish measures its supply, gives the measured one",
    )
    battery_fixed_draw_w: float = setting(
        -1.0,
        "what the fish's battery (battery topic) feeds besides the fin's drive, W: the supply watt is the "
        "battery's draw less this where no supply topic is read; negative: learnt while the drive is off",
        -1.0,
        1000.0,
    )
    calibration_from_controller: bool = setting(
        True,
        "the self-sensed thrust calibrated by the optimising controller's fitted fin (controller/model, "
        "sent by a controller optimising on self-sensed estimates once its corrected model fits its "
        "trials), where it is of this fin and of this model (or of the fin file); until then, and with "
        "false, by fin or model",
    )


#: The longest ``controller/model`` message read, characters (its JSON is about 400).
MODEL_MESSAGE_MOST = 4096
#: The topic each of :attr:`StreamEstimator.supply_meter`'s answers measures the supply watt on.
_METER_TOPIC = {"supply": TOPIC_SUPPLY, "battery": TOPIC_BATTERY}


#: How often the inbox is looked at, s of wall time, at the most often: 40 times a second (each look
#: wakes the executor: at 100 a second the estimator took 9-11 % of a core at 1 kHz; its windows last
#: seconds, so a block 25 ms late changes nothing); and every 50 ms of the fin's time
#: (:data:`Inbox.NODE_TIME_S`): 20 times a second on a fish in real time (8.6-9.5 % of a core at 40).
POLL_S = 0.025
#: Sample blocks taken from each sampled topic a look: 2,000 a second, where fin_sim at x40 sends 800
#: (what a flood sends beyond is dropped from its own queue, never from the others').
BLOCKS_A_LOOK = 50


class ThrustEstimator(Node):
    """Turns sample blocks into thrust, power and thrust-per-watt estimates."""

    def __init__(
        self, *, context: Context | None = None, node_name: str = "thrust_estimator", **kwargs: object
    ):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        own = declare(self, ThrustEstimatorConfig)
        calibrate = None
        self.core_model: Any = None  # (the augmented model given, which a controller's fit may apply on)
        try:
            if own.model:
                self.core_model = _model_of(own.model)
                self.fin, calibrate = self.core_model.fin, calibrated_by(self.core_model)
            else:
                self.fin = load_fin(own.fin)
            config = declare(self, EstimatorConfig, "estimator")
            amplifier = load_amplifier(own.amplifier)
        except AmplifierError as exc:
            raise StartupError(f"parameter amplifier: {exc}") from None
        except PiezofinError as exc:
            raise StartupError(str(exc)) from None
        freeze_parameters(self)
        fixed = own.battery_fixed_draw_w if own.battery_fixed_draw_w >= 0 else None
        self.core = StreamEstimator(self.fin, config, calibrate, amplifier, own.medium, fixed)
        self._meter = ""  # where the supply watt is measured, as last said
        self.estimates: list[Estimate] = []
        self._pub = self.create_publisher(*endpoint(TOPIC_ESTIMATE))
        self._estimate_type = self._pub.msg_type
        # what it hears and where it measures the supply watt: a controller holds its first drive until
        # the supply watt is measured (the battery's fixed draw is learnt with the drive off), and a
        # person asks `ros2 topic echo --once .../thrust_estimator/status`
        self._status_pub = self.create_publisher(*endpoint(TOPIC_ESTIMATOR_STATUS))
        self.create_timer(1.0, self._publish_status, clock=Clock(clock_type=ClockType.STEADY_TIME))
        # every message from another process through one door: checked there, refused with the reason
        self.inbox = inbox = Inbox(self, POLL_S, node_time_s=Inbox.NODE_TIME_S)
        # every sampled topic polled, each at most BLOCKS_A_LOOK blocks a look: a flood on one (a spoofed
        # supply at 10 kHz) cannot hold the executor from the others (it starved the drive's)
        for topic, handler, channels in (
            (TOPIC_DRIVE, self._on_drive, DRIVE_CHANNELS),
            (TOPIC_TIP, self._on_tip, TIP_CHANNELS),
            (TOPIC_LOADCELL, self._on_loadcell, LOADCELL_CHANNELS),
            (TOPIC_SUPPLY, self._on_supply, SUPPLY_CHANNELS),
        ):
            inbox.polled(endpoint(topic)[0], topic, handler, samples(channels), depth=500, most=BLOCKS_A_LOOK)
        # the newest speed only, polled: a flood of it costs one reading per look (it starved the drive's)
        inbox.latest(endpoint(TOPIC_SPEED)[0], TOPIC_SPEED, self._on_speed, speed_reading)
        inbox.polled(BatteryState, TOPIC_BATTERY, self._on_battery, battery_reading, depth=50, most=10)
        self._model_name = own.model  # (what a controller's fitted fin must apply on, or "": the fin file)
        self.calibration = f"the model {own.model}" if own.model else f"the fin file {own.fin}"
        if own.calibration_from_controller:
            inbox.latest(endpoint(TOPIC_MODEL)[0], TOPIC_MODEL, self._on_model, self._fitted_model)
        self._last_t = float("nan")
        self.received = {TOPIC_DRIVE: 0, TOPIC_TIP: 0, TOPIC_LOADCELL: 0, TOPIC_SUPPLY: 0}  # blocks
        self.battery_readings = 0
        drive = self.resolve_topic_name(TOPIC_DRIVE)
        self._silence = SilenceWatch(self, drive, "is fin_sim (or the rig driver) running?", topic=drive)
        self.diagnostics = Diagnostics(self, self.fin.name, stamp=self._fin_time)
        self.diagnostics.add("estimates", self._diagnose)
        self.get_logger().info(
            f"{self.fin.name} (psi {self.fin.psi:.2f}, c_m {self.fin.c_m:.3f}), {amplifier.describe()}: "
            f"estimating from {self.resolve_topic_name(TOPIC_DRIVE)} to "
            f"{self.resolve_topic_name(TOPIC_ESTIMATE)}"
        )

    def _fin_time(self) -> float:
        """The fin's time: its latest drive sample's (the node's clock before the first), s."""
        return self._last_t if self._last_t == self._last_t else self.get_clock().now().nanoseconds * 1e-9

    def status(self) -> dict[str, Any]:
        """``thrust_estimator/status``: the blocks and readings heard, the estimates made, where the
        supply watt is measured (a topic's full name; "": the amplifier's model alone) above which
        fixed draw, and what calibrates the self-sensed thrust."""
        core = self.core
        fixed = core.battery_fixed_draw_w
        heard = {self.resolve_topic_name(k): n for k, n in self.received.items()}
        heard[self.resolve_topic_name(TOPIC_BATTERY)] = self.battery_readings
        meter = self.resolve_topic_name(_METER_TOPIC[self._meter]) if self._meter else ""
        known = math.isfinite(fixed)
        return {  # (what a person asks first, first: `ros2 topic echo` prints 128 characters of it)
            "supply_watt_measured_on": meter,
            "battery_fixed_draw_w": round(fixed, 6) if known else None,
            "fixed_draw": "given" if core.fixed_draw_w is not None else "learnt" if known else "not known",
            "estimates": len(self.estimates),
            "refused": self.rejected,
            "heard": heard,
            "fin": self.fin.name,
            "self_sensing_calibrated_by": self.calibration,
        }

    def _publish_status(self) -> None:
        self._status_pub.publish(String(data=json.dumps(self.status())))

    def _diagnose(self) -> Report:
        drive = self.resolve_topic_name(TOPIC_DRIVE)
        last = self.estimates[-1] if self.estimates else None
        values: dict[str, object] = {
            "estimates": len(self.estimates),
            **{f"blocks on {self.resolve_topic_name(k)}": n for k, n in self.received.items()},
            "refused": self.rejected,
            "supply watt measured on": self._meter or "nothing (the amplifier's model)",
            "self-sensing calibrated by": self.calibration,
        }
        if last is not None:
            values.update(
                frequency_hz=last.frequency_hz,
                voltage_pp=last.voltage_pp,
                thrust_n=last.thrust_n,
                thrust_self_n=last.thrust_self_n,
                power_w=last.power_w,
                power_supply_w=last.power_supply_w,
            )
        if self.received[TOPIC_DRIVE] == 0:
            return Report(STALE, f"waiting for the first block on {drive}", values)
        if self._silence.silent:
            return Report(STALE, f"nothing on {drive}: is fin_sim (or the rig driver) running?", values)
        if self.rejected and self.inbox.refused_recently():
            return Report(WARN, "refusing messages (their reasons are in the log)", values)
        return Report(OK, f"estimating from {drive}: {len(self.estimates)} estimates", values)

    @property
    def rejected(self) -> int:
        """Blocks and readings refused at the door (their reasons were said)."""
        return sum(self.inbox.refused.values())

    def _fitted_model(self, msg: Any) -> tuple[Any, float, str]:
        """The door's check of ``controller/model``: JSON of this fin, on this estimator's own model
        (or, "", the fin file alone; never a path from the network), its correction each within the
        fit's range; the model it makes, and what it rests on."""
        from ..control.correction import Correction

        m = json_object(msg, MODEL_MESSAGE_MOST, "a fitted model's message")
        if not isinstance(m.get("fin"), str) or not isinstance(m.get("base"), str):
            raise MessageRefused("a fitted model is a JSON object with a fin and a base")
        if m["fin"] != self.fin.name:
            raise MessageRefused(f"a fit of {m['fin'][:40]!r}: this estimator's fin is {self.fin.name}")
        if m["base"] not in ("", self._model_name):
            raise MessageRefused(
                f"a fit on the model {m['base'][:80]!r}: this estimator knows "
                + (f"{self._model_name} and " if self._model_name else "")
                + "the fin file"
            )
        try:
            base = self.core_model if m["base"] else None
            c = Correction.of_fitted(m.get("correction"), base)
        except PiezofinError as exc:
            raise MessageRefused(str(exc)) from None
        t_s = m.get("t_s")
        if (
            isinstance(t_s, bool)
            or not isinstance(t_s, (int, float))
            or not (math.isfinite(t_s) and t_s >= 0)
        ):
            raise MessageRefused(f"t_s = {t_s!r}: the fin time the fit applies from, finite and >= 0, s")
        trials, misfit = m.get("trials"), m.get("misfit_sigma")
        said = f"{trials} trials" if isinstance(trials, int) and not isinstance(trials, bool) else "trials"
        if isinstance(misfit, (int, float)) and math.isfinite(misfit):
            said += f", {misfit:.1f} sigma RMS"
        return (
            c.model(self.fin),
            float(t_s),
            f"the controller's fitted fin ({said}; on {m['base'] or 'the fin file'})",
        )

    def _on_model(self, fitted: tuple[Any, float, str]) -> None:
        model, t_s, said = fitted
        self.core.calibrate_from(t_s, calibrated_by(model))  # (windows from the fit's time on)
        first = not self.calibration.startswith("the controller's")
        self.calibration = said
        if first:
            self.get_logger().info(f"self-sensed thrust calibrated by {said} from now on")

    def _on_drive(self, b: Block) -> None:
        self.received[TOPIC_DRIVE] += 1
        self._silence.heard()
        if self.received[TOPIC_DRIVE] == 1:
            self.diagnostics.update()
        self._last_t = float(b["t_s"][-1])
        self._emit(self.core.add_drive(b["t_s"], b["voltage_V"], b["current_A"]))

    def _on_tip(self, b: Block) -> None:
        self.received[TOPIC_TIP] += 1
        self._emit(self.core.add_tip(b["t_s"], b["tip_velocity_m_s"]))

    def _on_loadcell(self, b: Block) -> None:
        self.received[TOPIC_LOADCELL] += 1
        self._emit(self.core.add_loadcell(b["t_s"], b["displacement_m"]))

    def _on_supply(self, b: Block) -> None:
        self.received[TOPIC_SUPPLY] += 1
        self._emit(self.core.add_supply(b["t_s"], b["supply_voltage_V"], b["supply_current_A"]))

    def _on_battery(self, reading: tuple[float, float, float]) -> None:
        t, voltage, current = reading
        if t == 0.0:  # (a driver that leaves the stamp empty: the reading is now's)
            t = self._fin_time()
        self.battery_readings += 1
        self._emit(self.core.add_battery(t, voltage, current))

    def _on_speed(self, reading: tuple[float, float]) -> None:
        # The speed applies from its stamp on (the fin's time), or from the latest drive sample where
        # the sensor left the stamp unset.
        stamp, speed_m_s = reading
        self.core.add_speed(stamp if math.isfinite(stamp) else self._fin_time(), speed_m_s)

    def _meter_said(self) -> None:
        """Where the supply watt is measured, said (and sent on ``status``) as soon as it changes: the
        battery's fixed draw learnt with the drive off, or a supply meter heard.  (Once measured it
        stays so; only a supply meter heard later moves it from the battery.)"""
        core = self.core
        if self._meter == "supply" or (self._meter == "battery" and not core.supply.seen):
            return
        meter = core.supply_meter
        if meter == self._meter:
            return
        self._meter = meter
        self.get_logger().info(
            f"the supply watt is measured on {self.resolve_topic_name(TOPIC_SUPPLY)}"
            if meter == "supply"
            else f"the supply watt is measured on {self.resolve_topic_name(TOPIC_BATTERY)}: its draw "
            f"less {core.battery_fixed_draw_w * 1e3:.0f} mW of fixed draw"
            + (" (learnt with the drive off)" if core.fixed_draw_w is None else "")
        )
        self._publish_status()

    def _emit(self, estimates: list[Estimate]) -> None:
        self._meter_said()
        for e in estimates:
            self.estimates.append(e)
            self._pub.publish(record_msg(self._estimate_type, e.as_dict(), e.t_end))
            if e.final and self.core.medium == "air":
                self.get_logger().info(
                    f"trial {e.frequency_hz:.3f} Hz {e.voltage_pp:.0f} Vpp (in air: no thrust): tip velocity "
                    f"{e.tip_velocity_rms * 1e3:.2f} mm/s, current {e.current_rms * 1e6:.1f} uA, "
                    f"fin mean(v i) {e.power_w * 1e3:.3f} mW"
                )
            elif e.final:
                measured = e.power_supply_measured_w
                supply = f"{e.power_supply_w * 1e3:.1f} mW" + (
                    f" (measured {measured * 1e3:.1f})" if math.isfinite(measured) else ""
                )
                self.get_logger().info(
                    f"trial {e.frequency_hz:.3f} Hz {e.voltage_pp:.0f} Vpp: thrust {e.thrust_n * 1e3:.3f} mN "
                    f"(self {e.thrust_self_n * 1e3:.3f}, load cell {e.thrust_loadcell_n * 1e3:.3f}); "
                    f"fin mean(v i) {e.power_w * 1e3:.3f} mW, {e.thrust_per_watt * 1e3:.1f} mN/W; "
                    f"supply {supply}, {e.thrust_per_watt_supply * 1e3:.1f} mN/W"
                )

    def destroy_node(self) -> None:
        self.inbox.close()  # (its hidden helper node, which holds the polled subscriptions)
        super().destroy_node()

    def close(self) -> None:
        """Flush the last open window (end of a replay or of the run)."""
        self._emit(self.core.flush())


def _model_of(path: str) -> Any:
    """The augmented model of the ``model`` parameter.  (The model and its steady state load only here:
    an estimator without one stays small, for a fish.)"""
    from ..physics.model import load_model

    try:
        return load_model(path)
    except PiezofinError as exc:
        raise StartupError(f"parameter model: {exc}") from None


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: ThrustEstimator(context=ctx), args)


if __name__ == "__main__":
    sys.exit(main())
