"""A fish's own drive electronics, as a lab would write them from the README's topic contract: not
``fin_sim``, in a process of its own, at real time.

It obeys ``cmd`` (frequency, peak-to-peak voltage, on), and publishes ``drive`` (its voltage and
current monitors, a ``piezofin_msgs/Drive``: each block of samples with their times, stamped at the
first), ``swim_speed`` (``geometry_msgs/TwistStamped``: its speed sensor's ``twist.linear.x``, stamped
when read) and ``battery`` (``sensor_msgs/BatteryState``) in its namespace.
Nothing of it is what the stack is told: the fin is the nominal M8528-P1 (the stack's prior is the
paper's twin), the amplifier is another switching one (70 % efficient, none recovered, 0.12 W
quiescent), the body has a linear drag term besides the quadratic one and a speed sensor with a
bias, the battery feeds 0.3 W of electronics besides the amplifier.  Its own safety: the drive
ramps to 0 V when no command came for 1 s.  With ``realtime_factor`` other than 1 it simulates its
fish that many times faster than real time and publishes ``/clock`` (the time of its last sample),
as a simulated fish would for a stack on ``use_sim_time``; its watchdog then waits 1 s of wall time
(``realtime_factor`` s of fish time): at x5 a stack that a loaded machine held up for 0.2 s of wall
time is no dead stack (it had tripped the fish's drive three times in a run of 2026-12-06, each
latched for a minute of fish time until the controller's own watchdog re-armed it).  Where it falls
behind its clock (a machine that stalls its process), it slows the clock, as a simulator does, and
does not render the lost time in one burst, in which no command could reach the rig.  Each watchdog
trip is said (a warning).

    python test/fish_driver.py --ros-args -r __ns:=/fish -p truth_file:=truth.csv
    python test/fish_driver.py --ros-args -r __ns:=/fish -p realtime_factor:=5.0
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
import rclpy
from geometry_msgs.msg import TwistStamped
from piezofin_msgs.msg import Drive
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Float64MultiArray

from piezofin_ros.bags.blocks import COMMAND_FIELDS
from piezofin_ros.nodes._common import QOS_COMMAND, QOS_DATA, msg_block
from piezofin_ros.physics.amplifier import SwitchingAmplifier
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.rig.simulated import DriveLimits, SimulatedRig

RATE_HZ, BLOCK = 1000.0, 50
MASS_KG, DRAG_QUAD, DRAG_LIN = 0.5, 0.75, 0.004  # F = q U|U| + l U  (N; m/s)
SPEED_BIAS, SPEED_NOISE = 0.001, 0.002  # m/s
BATTERY_V, ELECTRONICS_W = 7.6, 0.3
AMPLIFIER = SwitchingAmplifier(efficiency=0.7, recovered=0.0, quiescent_w=0.12, bus_v=BATTERY_V)
WATCHDOG_S = 1.0  # of wall time (fish time at real time)
MAX_BEHIND_S = 0.5  # of fish time: a simulated fish this far behind its clock slows the clock
FIN = "M8528-P1"  # the nominal fin, no effect


class FishDriver(Node):
    def __init__(self) -> None:
        super().__init__("fish_driver")
        self.truth_file = self.declare_parameter("truth_file", "").value
        self.factor = float(self.declare_parameter("realtime_factor", 1.0).value)
        if not (math.isfinite(self.factor) and 0.1 <= self.factor <= 20.0):
            raise SystemExit(f"fish_driver: realtime_factor {self.factor!r} must be within [0.1, 20]")
        self.clock = self.create_publisher(Clock, "/clock", 10) if self.factor != 1.0 else None
        self.wall0, self.sim0 = time.monotonic(), time.time()
        self.watchdog_s = WATCHDOG_S * max(1.0, self.factor)  # (fish time)
        limits = DriveLimits(command_timeout_s=self.watchdog_s)
        self.rig = SimulatedRig(load_fin(FIN), seed=11, amplifier=AMPLIFIER, limits=limits)
        self.rng = np.random.default_rng(12)
        self.speed = 0.0
        self.t0 = self.now()
        self.samples = 0
        self.last_cmd = -math.inf
        self.draws: list[float] = []
        self.last_battery = -math.inf
        self.commands: list[tuple[float, float, float]] = []
        self.truth: list[str] = []
        self.drive = self.create_publisher(Drive, "drive", QOS_DATA)
        # (its sensors as ROS sensor drivers publish them: best-effort)
        self.speed_pub = self.create_publisher(TwistStamped, "swim_speed", qos_profile_sensor_data)
        self.battery = self.create_publisher(BatteryState, "battery", qos_profile_sensor_data)
        self.create_subscription(Float64MultiArray, "cmd", self.on_cmd, QOS_COMMAND)
        self.create_timer(BLOCK / RATE_HZ / self.factor, self.step)  # (a wall timer: the node's own clock)
        self.get_logger().info("driving the fin from cmd; publishing drive, swim_speed, battery")

    def now(self) -> float:
        if self.clock is None:
            return self.get_clock().now().nanoseconds * 1e-9
        return self.sim0 + (time.monotonic() - self.wall0) * self.factor

    def on_cmd(self, msg: Float64MultiArray) -> None:
        f, v, on = (msg_block(msg, expect=COMMAND_FIELDS).scalar(n) for n in COMMAND_FIELDS)
        self.rig.command(f, v, on)
        self.last_cmd = self.now()
        self.commands.append((self.now(), f, v))

    def step(self) -> None:
        if self.clock is not None:
            # a simulator that falls behind slows its clock, as Gazebo does: it does not render the
            # lost time in one burst, in which no command can reach the rig (its watchdog, in the rig's
            # time, tripped in such a burst after a stall of the driver's process: a live run of
            # 2026-12-07 whose drive then stayed off for a minute of fish time)
            behind = (self.now() - self.t0) - self.samples / RATE_HZ
            if behind > MAX_BEHIND_S:
                self.wall0 += (behind - MAX_BEHIND_S) / self.factor
        if self.now() - self.last_cmd > self.watchdog_s and self.rig.drive.driving:
            self.get_logger().warning(
                f"no command for {self.now() - self.last_cmd:.1f} s: ramping the drive to zero"
            )
            self.rig.stop()  # (no command for 1 s: the driver's own watchdog)
        while self.samples < (self.now() - self.t0) * RATE_HZ:
            b = self.rig.step(BLOCK)
            for event in b.events:  # (the rig's own watchdog: a latched trip is said)
                self.get_logger().warning(event)
            self.samples += BLOCK
            t = self.t0 + b.t  # (the rig's time from 0: the drive's samples in ROS time)
            drive = Drive(t_s=t.tolist(), voltage_v=b.voltage.tolist(), current_a=b.current.tolist())
            drive.header.stamp.sec, drive.header.stamp.nanosec = int(t[0]), round((t[0] % 1) * 1e9) % 10**9
            self.drive.publish(drive)
            thrust = float(np.mean(b.thrust_true))
            drag = DRAG_QUAD * self.speed * abs(self.speed) + DRAG_LIN * self.speed
            self.speed += (thrust - drag) / MASS_KG * BLOCK / RATE_HZ
            self.rig.swim_speed_m_s = self.speed
            reading = TwistStamped()
            reading.header.stamp = drive.header.stamp  # (read with the block's first sample)
            reading.header.frame_id = "base_link"
            reading.twist.linear.x = self.speed + SPEED_BIAS + SPEED_NOISE * self.rng.normal()
            self.speed_pub.publish(reading)
            self.draws.append(float(np.mean(b.supply_voltage * b.supply_current)))
            self.truth.append(
                f"{t[-1]:.3f},{self.speed:.6f},{thrust:.6e},{self.draws[-1]:.6e},{self.rig.drive.voltage_pp:.1f}"
            )
            if self.clock is not None:
                self.clock.publish(Clock(clock=Time(nanoseconds=round(float(t[-1]) * 1e9)).to_msg()))
            if t[-1] - self.last_battery >= 0.2:  # (its battery monitor: 5 Hz)
                self.last_battery = float(t[-1])
                power = float(np.mean(self.draws)) + ELECTRONICS_W
                self.draws = []
                msg = BatteryState()
                msg.header.stamp.sec = int(t[-1])
                msg.header.stamp.nanosec = int((t[-1] % 1.0) * 1e9)
                msg.voltage, msg.current = BATTERY_V, -power / BATTERY_V
                msg.temperature = msg.charge = msg.capacity = msg.design_capacity = msg.percentage = math.nan
                msg.present = True
                self.battery.publish(msg)

    def close(self) -> None:
        if self.truth_file:
            with open(self.truth_file, "w") as out:
                out.write("t_s,speed_m_s,thrust_n,supply_w,voltage_pp\n")
                out.write("\n".join(self.truth) + "\n")


def main() -> None:
    rclpy.init(args=sys.argv)
    node = FishDriver()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass
    finally:
        node.close()
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    main()
