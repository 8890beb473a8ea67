"""``speed_loop``: a fish's speed set-point to the optimising controller's thrust demand.

Subscribes ``swim_speed`` (geometry_msgs/TwistStamped, m/s: the fish's speed sensor) and publishes
``thrust_demand`` (std_msgs/Float64, N per fin) at ``rate_hz`` on the node's clock, with what it is
doing on ``speed_loop/status`` (std_msgs/String).  The set-point is the parameter ``speed_m_s``,
settable live (``ros2 param set /fish/speed_loop speed_m_s 0.06``), or a fish stack's ``cmd_vel``
(``geometry_msgs/Twist``, or ``TwistStamped`` with ``cmd_vel_stamped``): its ``linear.x``, back to 0
when none comes for ``cmd_vel_timeout_s`` (0.5 s), as ROS base controllers stop; everything else is
fixed at start.  The loop itself is :class:`~piezofin_ros.control.speedloop.SpeedLoop`: feed-forward through
the body's drag law, feedback on the measured speed, the demand never above ``loop.max_demand_n``.

On a body with one fin, ``cmd_vel``'s ``angular.z`` (rad/s, to port) is the set-point of the yaw loop
(:class:`~piezofin_ros.control.yawloop.YawLoop`), fed back by ``imu`` (sensor_msgs/Imu), which asks the
drive's offset on ``bias_demand`` (std_msgs/Float64, V) at ``rate_hz``; the controller adds it to
``cmd``.  ``odom`` (nav_msgs/Odometry) lays the speed sensor's track along the IMU's heading.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from typing import Any

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64, String

from ..config import HARD_VOLTAGE_PP_MAX, HARD_VOLTAGE_WINDOW_V, setting
from ..control.drag import RAW_SPAN_S
from ..control.odometry import UNKNOWN, DeadReckoning
from ..control.speedloop import DemandGate, SpeedLoop, SpeedLoopConfig
from ..control.yawloop import OffsetRoom, YawLoop, YawLoopConfig
from ..errors import PiezofinError
from ..estimation.estimator import THRUST_MOST_N
from ..physics.fin import load_fin
from ..physics.model import load_model
from ..physics.planar import slender_planar
from ..physics.swim import SPEED_MOST_M_S, load_body
from ._common import (
    TOPIC_BIAS,
    TOPIC_CMD,
    TOPIC_CMD_VEL,
    TOPIC_DEMAND,
    TOPIC_ESTIMATE,
    TOPIC_IMU,
    TOPIC_LOOP_STATUS,
    TOPIC_ODOM,
    TOPIC_SPEED,
    TOPIC_VOLTAGE_CAP,
    Inbox,
    MessageRefused,
    StartupError,
    declare,
    drive_command,
    endpoint,
    freeze_parameters,
    heading_of,
    msg_block,
    run_node,
    speed_reading,
)
from ._diagnostics import OK, STALE, WARN, Diagnostics, Report

# (cmd_vel, a fish stack's velocity command, and odom, where the fish is: in the topic table,
# bags/topics.py, relative to the fish's namespace: /fish/cmd_vel, /fish/odom)
#: The highest drive frequency an estimate may hold, Hz (a drive's band ends within it: DriveLimits).
FREQUENCY_MOST_HZ = 1000.0
#: The fastest yaw rate any fish's command may ask, rad/s (either way): beyond, it is no command.
YAW_RATE_MOST_RAD_S = 100.0
#: The controller's ``cmd`` is the drive's point for this long (node clock, s; its heartbeat is 10 Hz):
#: after, the latest estimate's.
CMD_FRESH_S = 1.0
#: An estimate's window is at most this long for the speed loop's momentum (``RAW_SPAN_S``), s
WINDOW_MOST_S = RAW_SPAN_S
#: An estimate whose window ended at most this long before it came ends there on the node's clock;
#: later (another clock), it ends when it came, s
WINDOW_LAG_S = 5.0


def _in_plane(xx: float, xy: float, yy: float, heading_var: float) -> list[float]:
    """A 6x6 pose covariance (row-major) of a fish in the plane: x and y, and the heading (NaN: not
    observed); z, roll and pitch unknown."""
    out = [UNKNOWN if k % 7 == 0 else 0.0 for k in range(36)]
    out[0], out[1], out[6], out[7] = xx, xy, xy, yy
    out[35] = UNKNOWN if math.isnan(heading_var) else heading_var
    return out


def _surge_and_yaw(variance: float, yaw_var: float) -> list[float]:
    """A 6x6 twist covariance (row-major) that knows the surge to ``variance`` and the yaw rate to
    ``yaw_var`` (NaN: not observed), nothing of sway, heave, roll or pitch."""
    out = [variance if k == 0 else UNKNOWN if k % 7 == 0 else 0.0 for k in range(36)]
    out[35] = UNKNOWN if math.isnan(yaw_var) else yaw_var
    return out


def velocity_command(msg: Twist | TwistStamped) -> tuple[float, float]:
    """The door's check of a ``cmd_vel``: (forward speed m/s, yaw rate rad/s), each finite and within
    what any fish does (a stamped one's twist)."""
    twist = msg.twist if isinstance(msg, TwistStamped) else msg
    forward, yaw = float(twist.linear.x), float(twist.angular.z)
    if not (math.isfinite(forward) and abs(forward) <= SPEED_MOST_M_S):
        raise MessageRefused(f"linear.x = {forward!r} m/s is no fish's speed (within +-{SPEED_MOST_M_S:g})")
    if not (math.isfinite(yaw) and abs(yaw) <= YAW_RATE_MOST_RAD_S):
        raise MessageRefused(
            f"angular.z = {yaw!r} rad/s is no fish's turn (within +-{YAW_RATE_MOST_RAD_S:g})"
        )
    return forward, yaw


def drive_point(msg: Any) -> tuple[float, float]:
    """The door's check of the controller's ``cmd``: the drive's peak-to-peak voltage and frequency
    it asks (0 V while it asks the drive off), within the hard cap and what a fin is driven at."""
    f, vpp, on, _ = drive_command(msg)
    if on not in (0.0, 1.0):
        raise MessageRefused(f"on = {on!r} is neither 0 nor 1")
    if math.isnan(vpp) or math.isnan(f):
        raise MessageRefused(f"a command of {vpp!r} Vpp at {f!r} Hz")
    _check_drive(vpp, f)
    return (vpp if on == 1.0 else 0.0), f


def _check_drive(vpp: float, f: float) -> None:
    """A drive's peak-to-peak voltage within the hard cap and its frequency within what a fin is
    driven at (NaN: not given), or :class:`MessageRefused`."""
    if not (math.isnan(vpp) or 0.0 <= vpp <= HARD_VOLTAGE_PP_MAX):
        raise MessageRefused(f"a drive of {vpp!r} Vpp is beyond the hard cap ({HARD_VOLTAGE_PP_MAX:g})")
    if not (math.isnan(f) or 0.0 < f <= FREQUENCY_MOST_HZ):
        raise MessageRefused(f"a drive at {f!r} Hz is no fin's (within (0, {FREQUENCY_MOST_HZ:g}] Hz)")


def fin_thrust(msg: Any) -> tuple[float, float, float, float, float]:
    """The door's check of an ``estimate`` for the speed loop: its self-sensed thrust, else its
    Lighthill thrust (a block may hold only what the loop reads), within what a fin gives (NaN: not
    estimated); the drive's peak-to-peak voltage and frequency (NaN where it does not hold them),
    within the hard cap and what a fin is driven at; and its window's length and end (s, the
    samples' clock; NaN where it does not hold them or they are no window's)."""
    block = msg_block(msg)
    names = block.names
    thrust = block.scalar("thrust_self_n") if "thrust_self_n" in names else math.nan
    if not math.isfinite(thrust) and "thrust_n" in names:
        thrust = block.scalar("thrust_n")
    if abs(thrust) > THRUST_MOST_N:  # (inf too)
        raise MessageRefused(
            f"a thrust of {thrust!r} N is beyond what any fin gives (within +-{THRUST_MOST_N:g})"
        )
    vpp = block.scalar("voltage_pp") if "voltage_pp" in names else math.nan
    f = block.scalar("frequency_hz") if "frequency_hz" in names else math.nan
    _check_drive(vpp, f)
    start = block.scalar("t_start") if "t_start" in names else math.nan
    end = block.scalar("t_end") if "t_end" in names else math.nan
    length = end - start  # (NaN, inf or <= 0 from a block that holds no window: not used)
    if not (math.isfinite(length) and 0.0 < length <= WINDOW_MOST_S):
        length = end = math.nan
    return thrust, vpp, f, length, end


def imu_reading(msg: Any) -> tuple[float, float, float, float]:
    """The door's check of an IMU's reading (``sensor_msgs/Imu``): its yaw rate, finite and within
    what any fish turns; its heading (the orientation's yaw; NaN where its quaternion is none), that
    heading's variance and the yaw rate's (each NaN where it gives none)."""
    rate = float(msg.angular_velocity.z)
    if not (math.isfinite(rate) and abs(rate) <= YAW_RATE_MOST_RAD_S):
        raise MessageRefused(
            f"angular_velocity.z = {rate!r} rad/s is no fish's turn (within +-{YAW_RATE_MOST_RAD_S:g})"
        )
    q = msg.orientation
    norm = math.sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w)
    heading = heading_of(q) if math.isfinite(norm) and abs(norm - 1.0) < 1e-3 else math.nan
    return rate, heading, _variance(msg.orientation_covariance), _variance(msg.angular_velocity_covariance)


def _variance(covariance: Any) -> float:
    """The yaw's variance of a 3x3 covariance as REP 145 gives it (its first element -1: none given)."""
    var = float(covariance[8])
    return var if math.isfinite(var) and var >= 0.0 and covariance[0] != -1.0 else math.nan


@dataclass(frozen=True)
class SpeedLoopNodeConfig:
    """``speed_loop``'s own parameters (and ``loop.*`` from :class:`SpeedLoopConfig`)."""

    body: str = setting("mfc-fish", "the fish's body (preset or YAML): its drag law is the feed-forward")
    speed_m_s: float = setting(0.0, "speed set-point, m/s (settable live; 0: no thrust asked)", 0.0, 10.0)
    rate_hz: float = setting(10.0, "how often the loop runs, Hz (node clock)", 0.5, 100.0)
    deadband: float = setting(
        0.03,
        "a demand is published when it moves by more than this (relative; and at least every 5 s): the "
        "controller's optimiser learns from whole trials, which a demand that never rests would starve",
        0.0,
        1.0,
    )
    cmd_vel_timeout_s: float = setting(
        0.5,
        "a fish stack's cmd_vel (geometry_msgs/Twist, linear.x m/s) sets the set-point; none for this "
        "long (node clock) after one came: the set-point falls to 0, as ROS base controllers stop, s",
        0.05,
        60.0,
    )
    cmd_vel_stamped: bool = setting(
        False, "cmd_vel is geometry_msgs/TwistStamped (nav2's default since Jazzy), not Twist"
    )
    speed_sigma_m_s: float = setting(
        0.002, "odom: the speed sensor's noise per reading, m/s (the covariance it fills)", 0.0, 10.0
    )
    speed_bias_m_s: float = setting(
        0.001,
        "odom: the most the speed sensor's bias may be, m/s (the position's error grows with it)",
        0.0,
        10.0,
    )
    fin: str = setting(
        "M8528-P1", "the caudal fin (preset or YAML): its offset turns the fish (the yaw loop)"
    )
    model: str = setting(
        "", "the fin's augmented model (config/models/; replaces fin): its fin turns the fish"
    )


class SpeedLoopNode(Node):
    """The speed loop on the live topics."""

    def __init__(self, *, context: Context | None = None, node_name: str = "speed_loop", **kwargs: object):
        super().__init__(node_name, context=context, **kwargs)  # type: ignore[arg-type]
        own = declare(self, SpeedLoopNodeConfig)
        try:
            body = load_body(own.body)
            self.loop = SpeedLoop(body, declare(self, SpeedLoopConfig, "loop"))
            fin = load_model(own.model).fin if own.model else load_fin(own.fin)
            # one fin turns the fish by its offset (two swim straight: no yaw loop)
            self.yaw = YawLoop(slender_planar(body, fin), fin, declare(self, YawLoopConfig, "yaw"))
            yaw = self.yaw.config
            self.room = OffsetRoom(least_vpp=yaw.room_least_vpp, engage_s=yaw.room_engage_s)
        except PiezofinError as exc:
            raise StartupError(str(exc)) from None
        self._turns = body.fins == 1
        # (the latest estimate's thrust, voltage and frequency: the yaw loop's plant)
        self._thrust_n = self._voltage_pp = self._frequency_hz = math.nan
        # (the drive's point as the controller asks it, and when: the offset's room and slew)
        self._asked: tuple[float, float, float] = (math.nan, math.nan, -math.inf)
        freeze_parameters(self, "speed_m_s", self._on_setpoint)
        self._pub = self.create_publisher(*endpoint(TOPIC_DEMAND))
        self._status = self.create_publisher(*endpoint(TOPIC_LOOP_STATUS))
        # every message from another process: its failure said, never fatal (looked at every 50 ms
        # of the fish's time)
        self.inbox = Inbox(self, node_time_s=Inbox.NODE_TIME_S)
        # the newest reading only, polled: a flood costs one reading per look
        self.inbox.latest(endpoint(TOPIC_SPEED)[0], TOPIC_SPEED, self._on_speed, speed_reading)
        self.inbox.polled(
            endpoint(TOPIC_ESTIMATE)[0], TOPIC_ESTIMATE, self._on_estimate, fin_thrust, depth=200, most=20
        )
        # the IMU's yaw rate: the yaw loop's feedback; its offset goes to the controller's drive
        self.inbox.latest(endpoint(TOPIC_IMU)[0], TOPIC_IMU, self._on_imu, imu_reading)
        self.inbox.latest(endpoint(TOPIC_CMD)[0], TOPIC_CMD, self._on_cmd, drive_point)
        self._bias_pub = self.create_publisher(*endpoint(TOPIC_BIAS))
        # and the most voltage the drive may have so that the offset it wants fits in the window
        self._cap_pub = self.create_publisher(*endpoint(TOPIC_VOLTAGE_CAP))
        # a fish stack's velocity command (teleop, nav2): its forward speed is the set-point
        self._cmd_vel_timeout_s = own.cmd_vel_timeout_s
        self._cmd_vel_t = math.nan  # (node clock, s) the latest cmd_vel; NaN: none yet, or timed out
        self._cmd_vel_wall = -math.inf  # (time.monotonic) the latest cmd_vel
        self._cmd_vel_said: set[str] = set()
        self.inbox.latest(
            TwistStamped if own.cmd_vel_stamped else Twist, TOPIC_CMD_VEL, self._on_cmd_vel, velocity_command
        )
        # where the fish is, dead-reckoned from its speed (control/odometry.py), as ROS tools read it
        self.odometry = DeadReckoning(own.speed_sigma_m_s, own.speed_bias_m_s)
        self._odom = self.create_publisher(*endpoint(TOPIC_ODOM))
        self.create_timer(1.0 / own.rate_hz, self._tick)
        self.refused = 0
        self._said = self._published = ""
        self._said_at = -math.inf
        self._gate = DemandGate(own.deadband)
        self.get_logger().info(
            f"body {body.name}: {body.mass_kg:g} kg, drag area {body.drag_area_m2:g} m^2, "
            f"{body.fins} fin(s); "
            f"at most {self.loop.config.max_demand_n * 1e3:g} mN per fin on "
            f"{self.resolve_topic_name(TOPIC_DEMAND)}, fastest {self.loop.fastest_m_s():.3g} m/s"
        )
        self.diagnostics = Diagnostics(self, body.name)
        self.diagnostics.add("speed loop", self._diagnose)
        self._set(own.speed_m_s)

    def _diagnose(self) -> Report:
        loop = self.loop
        values = {
            "setpoint_m_s": loop.setpoint_m_s,
            "speed_m_s": loop.speed_m_s,
            "demand_n": loop.demand_n,
            "thrust_estimate_n": loop.thrust_estimate_n,
            "cap_n": loop.cap_n,
            "state": loop.kind,
        }
        level = {"silent": STALE, "unread": STALE, "lies": WARN, "saturated": WARN}.get(loop.kind, OK)
        return Report(level, loop.state, values)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _set(self, speed: float) -> None:
        said = self.loop.set_setpoint(speed)
        if said:
            self.get_logger().warning(said)
        else:
            self.get_logger().info(f"set-point {speed:.3g} m/s")

    def _on_setpoint(self, params: list[Parameter]) -> str | None:
        value = params[-1].value
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
            or value < 0
        ):
            return f"speed_m_s {value!r}: a finite speed >= 0 m/s"
        self._set(float(value))
        return None

    def destroy_node(self) -> None:
        self.inbox.close()  # (its hidden helper node, which holds the polled subscriptions)
        super().destroy_node()

    def _on_cmd_vel(self, command: tuple[float, float]) -> None:
        """A velocity command: its forward speed becomes the set-point (what this fish cannot do, it
        says once: swim backwards, turn, beyond its fastest)."""
        forward, yaw_rate = command
        now = self._now()
        self._cmd_vel_t = now if now > 0.0 else math.nan  # (use_sim_time before /clock: no time yet)
        self._cmd_vel_wall = time.monotonic()
        if forward < 0:
            self._say_once(
                "backwards", f"cmd_vel asks {forward:.3g} m/s: this fish does not swim backwards (0)"
            )
        if yaw_rate != 0 and not self._turns:
            self._say_once(
                "turn", f"cmd_vel asks {yaw_rate:.3g} rad/s of yaw: a fish of two fins does not turn"
            )
        elif yaw_rate != self.yaw.setpoint_rad_s:
            self.yaw.set_setpoint(yaw_rate)
        speed = max(forward, 0.0)
        top = self.loop.fastest_m_s()
        if speed > top:
            self._say_once(
                "fast", f"cmd_vel asks {speed:.3g} m/s: beyond the fastest this fish swims, {top:.3g}"
            )
        if abs(speed - self.loop.setpoint_m_s) > 1e-6:
            self.loop.set_setpoint(speed)  # (beyond its fastest: said once above, the loop at its cap)

    def _say_once(self, key: str, text: str) -> None:
        if key not in self._cmd_vel_said:
            self._cmd_vel_said.add(key)
            self.get_logger().warning(text)

    def _publish_odometry(self) -> None:
        """``odom`` (nav_msgs/Odometry): ``odom`` to ``base_link``, the track laid along the IMU's
        heading (along x without one), its covariance filled; what it does not observe unknown."""
        o, msg = self.odometry, Odometry()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.header.frame_id, msg.child_frame_id = "odom", "base_link"
        msg.pose.pose.position.x, msg.pose.pose.position.y = o.x_m, o.y_m
        msg.pose.pose.orientation.z = math.sin(0.5 * o.heading_rad)
        msg.pose.pose.orientation.w = math.cos(0.5 * o.heading_rad)
        msg.pose.covariance = _in_plane(*o.position_covariance(), o.heading_var)
        msg.twist.twist.linear.x, msg.twist.twist.angular.z = o.speed_m_s, o.yaw_rate_rad_s
        msg.twist.covariance = _surge_and_yaw(o.speed_var_m2_s2, o.yaw_rate_var)
        self._odom.publish(msg)

    def _cmd_vel_expired(self, t: float) -> None:
        """No cmd_vel for ``cmd_vel_timeout_s`` after one came, of the node's clock and of wall time
        alike (a simulation faster than real time): stop swimming (set-point 0), said."""
        # (and as long of wall time: a teleop's 10 Hz by the wall is 1 Hz of a simulation at x10)
        if (
            math.isnan(self._cmd_vel_t)
            or t - self._cmd_vel_t <= self._cmd_vel_timeout_s
            or time.monotonic() - self._cmd_vel_wall <= self._cmd_vel_timeout_s
        ):
            return
        self.get_logger().warning(
            f"no cmd_vel for {t - self._cmd_vel_t:.2f} s (> {self._cmd_vel_timeout_s:g} s): set-point 0, "
            "no thrust asked"
        )
        self._cmd_vel_t = math.nan
        self.loop.set_setpoint(0.0)
        self.yaw.stop()  # (the offset at once: the drive's slew ramps it, as it ramps a stop)

    def _on_speed(self, reading: tuple[float, float]) -> None:
        # (the loop runs on its node clock: a reading counts when it arrives, whatever its stamp)
        speed_m_s = reading[1]
        now = self._now()
        self.odometry.add(now, speed_m_s)
        if not self.loop.measure(now, speed_m_s):
            self.refused += 1
            self.get_logger().warning(
                f"refused a speed reading of {speed_m_s!r} m/s (not a finite speed)",
                throttle_duration_sec=5.0,
            )

    def _on_estimate(self, estimate: tuple[float, float, float, float, float]) -> None:
        """The fin's thrust as the estimator gives it (self-sensed on a fish): what a speed reading is
        judged against, and with the drive's voltage and frequency the yaw loop's plant.  Its window
        ends when its samples say where that is on this node's clock (at most :data:`WINDOW_LAG_S`
        before now: one clock, the fish's), else now (an estimator on another clock)."""
        thrust, vpp, f, length, end = estimate  # (an estimate that cannot give one keeps the last)
        if math.isfinite(thrust) and math.isfinite(vpp) and math.isfinite(f):
            self._thrust_n, self._voltage_pp, self._frequency_hz = thrust, vpp, f
        now = self._now()
        lag = now - end if 0.0 <= now - end <= WINDOW_LAG_S else 0.0  # (NaN: 0)
        self.loop.estimate(now, thrust, length, lag)

    def _on_imu(self, reading: tuple[float, float, float, float]) -> None:
        rate, heading, var, rate_var = reading
        self.yaw.measure(self._now(), rate)
        self.odometry.turn(heading, var)
        self.odometry.spin(rate, rate_var)

    def _on_cmd(self, point: tuple[float, float]) -> None:
        self._asked = (*point, self._now())

    def _drive_now(self, t: float) -> tuple[float, float]:
        """The drive's peak-to-peak voltage and frequency for the yaw loop: as the controller asks
        them (within the last :data:`CMD_FRESH_S`), else as the latest estimate read them.  An
        estimate comes a window (8 s) after the drive changed: turning, the controller moved from
        6.25 Hz, 444 Vpp to 2.2 Hz, 800 Vpp, and the loop, on the estimate's point, moved the offset
        at 2.8 % of the new sine's slope and placed the window's edge 180 V beyond the drive's."""
        vpp, f, at = self._asked
        if t - at <= CMD_FRESH_S:
            return vpp, f
        return (self._voltage_pp if math.isfinite(self._voltage_pp) else 0.0), self._frequency_hz

    def _steer(self, t: float) -> None:
        """The offset the yaw loop asks now, on ``bias_demand`` (V; 0 while the fish swims straight),
        and once per edge of the window what turn it cannot give."""
        if not self._turns:
            return
        vpp, f = self._drive_now(t)
        bias = self.yaw.update(t, self._thrust_n, self.loop.speed_m_s, vpp, f)
        self._bias_pub.publish(Float64(data=bias))
        was = self.room.cap
        if self.room.update(self.yaw.wanted_v, t) and math.inf in (was, self.room.cap):  # (begins, ends)
            topic = self.resolve_topic_name(TOPIC_VOLTAGE_CAP)
            self.get_logger().info(
                f"the drive capped at {self.room.cap:.0f} Vpp on {topic}: the offset the yaw loop wants, "
                f"{self.yaw.wanted_v:.0f} V, fits in the MFC's window with that sine (it follows the "
                "offset from now on)"
                if math.isfinite(self.room.cap)
                else "the drive's voltage no longer capped for the offset's room"
            )
        low, high = HARD_VOLTAGE_WINDOW_V  # (no cap: the whole window, as a finite number)
        self._cap_pub.publish(Float64(data=min(self.room.cap, high - low)))
        if self.yaw.edge:
            self._say_once(
                f"edge {self.yaw.edge}",
                f"cmd_vel asks {self.yaw.setpoint_rad_s:.3g} rad/s of yaw: beyond the turn to "
                f"{self.yaw.edge} this fin gives at {vpp:.0f} Vpp (its offset at the window's edge, "
                f"{bias:.0f} V)",
            )

    def _tick(self) -> None:
        t = self._now()
        if t == 0.0:
            return  # use_sim_time and no /clock yet
        self._cmd_vel_expired(t)
        self._steer(t)
        self._publish_odometry()
        demand = self.loop.update(t)
        for said in self.loop.widened:  # (a wrong prior acted on: said once, each time)
            self.get_logger().warning(said)
        self.loop.widened.clear()
        kind = self.loop.kind
        if self._gate.due(t, demand) or kind != self._published:
            self._pub.publish(Float64(data=demand))
            self._status.publish(String(data=self.loop.state))
            self._published = kind
        self.diagnostics.update()
        # A new kind of state is said at once, at most one line a second of wall time (a sensor that
        # flips between kinds cannot flood the log), and the kind that lasts is always said: one that
        # came too soon after the last line is said at the next tick after the second is over.
        wall = time.monotonic()
        if kind != self._said and wall - self._said_at >= 1.0:
            if kind in ("silent", "lies", "saturated"):  # (one severity per call site: rclpy's rule)
                self.get_logger().warning(self.loop.state)
            else:
                self.get_logger().info(self.loop.state)
            self._said, self._said_at = kind, wall


def main(args: list[str] | None = None) -> int:
    return run_node(lambda ctx: SpeedLoopNode(context=ctx), args)


if __name__ == "__main__":
    sys.exit(main())
