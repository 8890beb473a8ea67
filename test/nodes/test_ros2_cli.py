"""The suite as a ROS user meets it: the real `ros2` command line and `ros2 launch`.

Where a `ros2` is on the PATH (a ROS machine) it is used; otherwise the Jazzy ros2cli and launch
are built from ``../shared/ros2-jazzy`` into ``.ros/ros2-jazzy`` (once, about a minute).  The
package itself is built with ``colcon build --symlink-install`` into ``.ros/ws``, as a user does.
Without either, these tests are skipped with one line saying why.
"""

from __future__ import annotations

import itertools
import os
import re
import signal
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

from ..rosutil import Launch, assert_quiet_domain, errors_in, node_list, plotted, ros2

pytestmark = [pytest.mark.ros, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]


#: what a person plots of a fin, each a field of ``/fin/estimate`` by its name: the thrust of each source,
#: each watt, the thrust per each watt, the drive's frequency, voltage and current, the tip's velocity
PLOTTED = (
    "thrust_n",
    "thrust_self_n",
    "thrust_loadcell_n",
    "power_w",
    "power_apparent_w",
    "power_supply_w",
    "power_supply_measured_w",
    "thrust_per_watt",
    "thrust_per_watt_self",
    "thrust_per_watt_supply",
    "thrust_per_watt_self_supply_measured",
    "frequency_hz",
    "voltage_pp",
    "current_rms",
    "tip_velocity_rms",
    "tip_velocity_rms_self",
    "swim_speed_m_s",
)


# exclusive: a status echo is asked to answer within 2 s of wall time (issue 41).  (Stop 65's CI put its
# two missed echoes down to nice 19 in phase 1; stop 67's, exclusive, showed the cause: `answered_latched`)
@pytest.mark.exclusive
def test_launch_runs_the_suite_answers_the_cli_and_stops_cleanly(
    ros_env: dict[str, str], tmp_path: Path
) -> None:
    from mcap.reader import make_reader

    ros2(ros_env, "daemon", "stop")  # a fresh domain, as a user's first terminal meets it
    launch = Launch(ros_env, tmp_path, "realtime_factor:=10")
    try:
        launch.wait_for("thrust_estimator-2] [INFO]", 60.0)
        launch.wait_for("trial 1.000 Hz 400 Vpp", 60.0)  # an estimate: the graph works
        suite = {"/fin/fin_sim", "/fin/thrust_estimator", "/fin/controller", "/recorder"}
        # the README's line for a fresh domain, once, as typed: the graph asked directly (the CLI's
        # daemon, started by the first command, took seconds to list all five: 2 of 5 a second on)
        direct = ros2(ros_env, "node", "list", "--no-daemon", "--spin-time", "5")
        assert suite <= set(direct.stdout.split()), direct.stdout + direct.stderr
        nodes = node_list(ros_env, suite)
        assert suite <= nodes, nodes
        # the estimate as a plotter sees it: every quantity by its name, stamped in the fin's time
        echoed = ros2(ros_env, "topic", "echo", "--once", "/fin/estimate", "--field", "thrust_self_n")
        assert float(echoed.stdout.split()[0]) > 0.0, echoed.stdout + echoed.stderr
        both = plotted(ros_env, ["/fin/estimate", "/fin/drive"], messages=3)
        plotted_at = time.monotonic()
        series, drive = both["/fin/estimate"], both["/fin/drive"]
        for name in PLOTTED:
            assert name in series, (name, sorted(series))
        for name in ("voltage_v[0]", "current_a[49]", "t_s[0]"):  # the blocks' samples, by name and index
            assert name in drive, (name, sorted(drive)[:10])
        first = drive["t_s[0]"]  # stamped at the first sample's time (to the stamp's nanosecond)
        assert [t for t, _ in first] == pytest.approx([v for _, v in first], abs=1e-6), first
        stamps = [t for t, _ in series["thrust_n"]]
        ends = [v for _, v in series["t_end"]]
        assert stamps == pytest.approx(ends, abs=1e-6), stamps  # the window's end, in the fin's time
        # in time order; one stamp twice only where a trial's whole (final 1) ends where its last
        # running window (final 0) did (stop 61's CI: the trial's end came right after a window)
        finals = [v for _, v in series["final"]]
        assert stamps[0] > 0 and all(b >= a for a, b in itertools.pairwise(stamps)), stamps
        for (a, b), pair in zip(itertools.pairwise(stamps), itertools.pairwise(finals), strict=True):
            assert b > a or pair == (0.0, 1.0), (stamps, finals)
        clock = ros2(ros_env, "topic", "echo", "--once", "/clock", "--field", "clock.sec").stdout
        # fin time, not wall time: the clock at x10 from the last stamp on, however long the command line
        # took to start (4.5 s of wall on a loaded machine: 45 s of fin time)
        ahead = float(clock.split()[0]) - stamps[-1]
        assert -5.0 < ahead < 10.0 * (time.monotonic() - plotted_at) + 30.0, (clock, stamps)
        answered_latched(ros_env, ["/fin/controller/status", "/recorder/status"])
        info = ros2(ros_env, "topic", "info", "-v", "/fin/drive", "--spin-time", "3").stdout
        assert "RELIABLE" in info and "Publisher count: 1" in info, info
        state = ros2(ros_env, "lifecycle", "get", "/fin/fin_sim", "--spin-time", "3")
        assert state.stdout.startswith("active"), state.stdout + state.stderr
        refused = ros2(ros_env, "lifecycle", "set", "/fin/fin_sim", "cleanup", "--spin-time", "3")
        assert "successful" not in refused.stdout.lower() or "unsuccessful" in refused.stdout.lower()
        tighter = ros2(
            ros_env, "param", "set", "/fin/fin_sim", "limits.voltage_pp_max", "400", "--spin-time", "3"
        )
        assert "Set parameter successful" in tighter.stdout, tighter.stdout + tighter.stderr
        looser = ros2(
            ros_env, "param", "set", "/fin/fin_sim", "limits.voltage_pp_max", "600", "--spin-time", "3"
        )
        assert "only tighter limits" in looser.stdout + looser.stderr
        kind = ros2(
            ros_env, "param", "get", "/fin/fin_sim", "limits.voltage_pp_max", "--spin-time", "3"
        ).stdout
        assert "Double value is: 400.0" in kind, kind
        assert launch.proc.poll() is None  # nothing above killed a node
    finally:
        out = launch.interrupt()
    assert not errors_in(out), out[-3000:]
    assert out.count("process has finished cleanly") == 4, out[-3000:]
    bag = next((tmp_path / "bags").glob("piezofin_*.mcap"))
    with open(bag, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 100


#: fish time the live fish is given after its set-point step (the controller's trials: a few of 13 s;
#: on a loaded machine its fits take more fish time at x10, measured: about 400 s to within 5 %)
HOLD_S = 480.0
#: the span at the end of the run over which the speed is averaged, s of fish time
LAST_S = 60.0


def fish_time(env: dict[str, str]) -> float:
    """The fish's time, s (fin_sim's ``/clock``, as `ros2 topic echo` prints it)."""
    out = ros2(env, "topic", "echo", "--once", "/clock", timeout=60.0).stdout
    sec, nsec = re.search(r"sec: (\d+)\s+nanosec: (\d+)", out).groups()  # type: ignore[union-attr]
    return int(sec) + int(nsec) * 1e-9


def answered_latched(env: dict[str, str], topics: Sequence[str]) -> None:
    """Issue 41's goal: ``ros2 topic echo --once`` of each status topic answers within 2 s of its
    subscription (``--timeout 2``: the command line's own start-up, 1-7 s of wall time on CI's loaded
    machine, is not the topic's).  Volatile and sent on change, one such echo after a run waited 20 s
    for nothing; transient-local, an echo that joined before it had discovered the publisher asked a
    volatile profile and waited for the protocol's next trial (4.1 s): each status is now sent at least
    once a second besides.

    The echo first finds the graph itself for 3 s (``--no-daemon --spin-time 3``), then subscribes:
    with the daemon it subscribes from a participant made that instant, and its 2 s then held Fast
    DDS's own discovery, which here finds a publisher within 0.6 s or only after 2.2-2.6 s (one join in
    three, even on a quiet domain with two publishers: measured 2026-12-06), so both of the CI run's
    echoes of ``/recorder/status`` on stop 67 heard nothing.  Found first, each status answered in
    0.1 s, 16 of 16 beside two busy processes.  (Two tries: one 2 s on a machine running three test
    workers on two cores is a scheduler's, twice is the topic's.)"""
    for topic in topics:
        outs = []
        for _ in range(2):
            echo = ["topic", "echo", "--once", "--no-daemon", "--spin-time", "3", "--timeout", "2"]
            run = ros2(env, *echo, topic, timeout=60.0)
            outs.append(run.stdout + run.stderr)
            if "data:" in outs[-1]:
                break
        assert "data:" in outs[-1], (topic, outs)


def echoed_value(env: dict[str, str], topic: str) -> float:
    """The number ``ros2 topic echo --once TOPIC --field data`` prints (NaN: none)."""
    out = ros2(env, "topic", "echo", "--once", topic, "--field", "data", timeout=60.0).stdout
    numbers = re.findall(r"^\s*(-?[0-9][0-9.eE+-]*)\s*$", out, re.M)
    return float(numbers[-1]) if numbers else float("nan")


# exclusive: its status echoes must answer within 2 s of wall time (issue 41), as the suite's launch
# test's (stop 66's CI put two missed echoes down to nice 19; the cause: `answered_latched`)
@pytest.mark.exclusive
def test_the_fish_swims_under_the_real_cli(ros_env: dict[str, str], tmp_path: Path) -> None:
    """Issue 27's example, as a user runs it: `ros2 launch piezofin_ros fish.launch.py`, each node in
    its own process; the set-point set live with `ros2 param set` (a speed that is no speed and any
    other parameter refused), the battery read with `ros2 topic echo`; the bag holds the speed, the
    demand and the battery, and the fish swam, and holds its new set-point within 5 % over the last
    minute of at least 480 s of fish time after the step (it held 3.4 cm/s for 700 s at 5 cm/s
    when the speed loop's every demand moved the drive before a trial ended); then an unreachable
    set-point is said, and the demand never went beyond the loop's 8 mN."""
    from piezofin_ros.bags import decode, read_messages

    launch = Launch(ros_env, tmp_path, "realtime_factor:=10", "speed_m_s:=0.04", file="fish.launch.py")
    fish = {"/fish/fin_sim", "/fish/thrust_estimator", "/fish/controller", "/fish/speed_loop", "/recorder"}
    try:
        launch.wait_for("swimming: body mfc-fish", 60.0)
        launch.wait_for("set-point 0.04 m/s", 60.0)
        nodes = node_list(ros_env, fish)
        assert fish <= nodes, nodes
        taken = ros2(ros_env, "param", "set", "/fish/speed_loop", "speed_m_s", "0.06", "--spin-time", "3")
        assert "Set parameter successful" in taken.stdout, taken.stdout + taken.stderr
        launch.wait_for("set-point 0.06 m/s", 30.0)
        t_set = fish_time(ros_env)
        for name, value in (("speed_m_s", "-1.0"), ("speed_m_s", "nan"), ("loop.max_demand_n", "1.0")):
            refused = ros2(ros_env, "param", "set", "/fish/speed_loop", name, value, "--spin-time", "3")
            assert "Set parameter successful" not in refused.stdout, (name, value, refused.stdout)
        # (reliable, 200 readings a second at x10: Fast DDS told a late reader of "lost" ones first)
        # (150 s: a CI run at a load of 20, this fish at x10 beside another worker's nodes, printed the
        # reading and had not exited in 60 s)
        for _ in range(3):
            speed = ros2(ros_env, "topic", "echo", "--once", "/fish/swim_speed", timeout=150.0)
            assert "twist:" in speed.stdout and "lost" not in speed.stdout + speed.stderr, (
                speed.stdout + speed.stderr
            )
        # the fish's speed and battery as a plotter sees them: by name, stamped in the fish's time
        fish_series = plotted(ros_env, ["/fish/swim_speed", "/fish/battery"], messages=3)
        for topic, name in (("/fish/swim_speed", "twist/linear/x"), ("/fish/battery", "percentage")):
            points = fish_series[topic][name]
            stamps = [t for t, _ in points]
            assert stamps[0] > 0 and all(b > a for a, b in itertools.pairwise(stamps)), (topic, points)
        battery = ros2(ros_env, "topic", "echo", "--once", "/fish/battery", timeout=150.0)
        assert "percentage:" in battery.stdout and "voltage:" in battery.stdout, (
            battery.stdout + battery.stderr
        )
        # where the supply watt is measured, as docs/fish.md's line asks it (fin_sim has a supply meter):
        # first, within the 128 characters the command line prints of a string
        meter = ros2(ros_env, "topic", "echo", "--once", "/fish/thrust_estimator/status", timeout=150.0)
        assert '{"supply_watt_measured_on": "/fish/supply"' in meter.stdout, meter.stdout + meter.stderr
        # the quiet identification trial, when the fish's stack says its speed may drop (issue 39: it
        # came back by itself every 20-22 trials, the fish 60-80 % slower for 20-30 s)
        asked = ros2(
            ros_env, "service", "call", "/fish/controller/identify", "std_srvs/srv/Trigger", timeout=60.0
        )
        assert "success=True" in asked.stdout, asked.stdout + asked.stderr
        launch.wait_for("a quiet identification trial comes after the running one", 30.0)
        deadline = time.monotonic() + 300.0  # (x10 alone: 50 s of wall time; a loaded machine is slower)
        while fish_time(ros_env) < t_set + HOLD_S and time.monotonic() < deadline:
            time.sleep(3.0)
        t_held = fish_time(ros_env)  # (the set-point held until here; the teleop comes after)
        # a teleop as a user types it (issue 42): the fish turns while it comes (its yaw loop asks an
        # offset), and its silence takes the offset back to 0 V (cmd_vel's timeout: 0.5 s of fish and
        # of wall time, so that 10 Hz by the wall holds a fish simulated at x10)
        teleop = subprocess.Popen(
            ["ros2", "topic", "pub", "-r", "10", "/fish/cmd_vel", "geometry_msgs/msg/Twist",
             "{linear: {x: 0.06}, angular: {z: 0.01}}"],
            env=ros_env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 60.0
            turning = 0.0
            while turning <= 0.0 and time.monotonic() < deadline:
                time.sleep(2.0)
                turning = echoed_value(ros_env, "/fish/bias_demand")
            assert turning > 0.0, "the teleop's turn asked no offset"
        finally:
            os.killpg(teleop.pid, signal.SIGINT)
            teleop.wait(timeout=30)
        time.sleep(3.0)  # (30 s of fish time: the timeout, and the offset's slew to 0 V)
        assert echoed_value(ros_env, "/fish/bias_demand") == 0.0
        launch.wait_for("no cmd_vel for", 10.0)
        # an unreachable set-point: taken, said with the fastest speed, and never more than the 8 mN
        # the loop may ask (config/fish.yaml), whatever the speed error (the bag's demands, below)
        far = ros2(ros_env, "param", "set", "/fish/speed_loop", "speed_m_s", "5.0", "--spin-time", "3")
        assert "Set parameter successful" in far.stdout, far.stdout + far.stderr
        launch.wait_for("set-point 5 m/s is beyond the 8 mN per fin the loop may ask for", 30.0)
        time.sleep(5.0)
        answered_latched(
            ros_env, ["/fish/speed_loop/status", "/fish/controller/status", "/fish/thrust_estimator/status"]
        )
        assert launch.proc.poll() is None
    finally:
        out = launch.interrupt()
    assert not errors_in(out) and "Traceback" not in out, out[-3000:]
    assert out.count("process has finished cleanly") == 5, out[-3000:]
    bag = next((tmp_path / "bags").glob("piezofin_*.mcap"))
    counts: dict[str, int] = {}
    speeds: list[float] = []
    speed_times: list[float] = []
    demands: list[float] = []
    carried = ["/fish/swim_speed", "/fish/thrust_demand", "/fish/battery", "/fish/drive", "/fish/estimate"]
    for m in read_messages(bag, [*carried, "/fish/tip_velocity", "/fish/loadcell"]):
        counts[m.topic] = counts.get(m.topic, 0) + 1
        if m.topic == "/fish/thrust_demand":
            demands.append(float(decode(m.type_name, m.data).data))
        if m.topic == "/fish/swim_speed":
            speeds.append(float(decode(m.type_name, m.data).twist.linear.x))
            speed_times.append(m.log_time_ns * 1e-9)  # (fish time: the recorder runs on /clock)
    assert counts.get("/fish/swim_speed", 0) > 100 and counts.get("/fish/battery", 0) > 10, counts
    assert counts.get("/fish/thrust_demand", 0) > 3, counts
    # a fish carries no vibrometer and no load cell (config/fish.yaml's lab_instruments: false): the
    # stack estimated and swam on its drive's voltage and current alone
    assert "/fish/tip_velocity" not in counts and "/fish/loadcell" not in counts, counts
    assert counts.get("/fish/drive", 0) > 100 and counts.get("/fish/estimate", 0) > 10, counts
    assert max(speeds) > 0.005, max(speeds)  # it swam
    assert max(demands) <= 0.008 and max(demands) == pytest.approx(0.008), max(demands)  # asked, capped
    # and holds the new set-point: the speed sensor's mean over the last minute of fish time before
    # the teleop
    t, u = np.array(speed_times), np.array(speeds)
    assert t_held >= t_set + HOLD_S, f"only {t_held - t_set:.0f} s of fish time after the step"
    last = (t >= t_held - LAST_S) & (t <= t_held)
    assert abs(float(np.mean(u[last])) / 0.06 - 1.0) < 0.05, float(np.mean(u[last]))


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (("fish.launch.py", "speed_m_s:=-1"), "speed_loop exited with code 2"),
        (("fish.launch.py", "speed_m_s:=abc"), "launch argument speed_m_s:='abc' is not a number"),
        (("piezofin.launch.py", "realtime_factor:=0"), "fin_sim exited with code 2"),
    ],
)
def test_a_launch_whose_node_fails_stops_whole_and_says_which(
    ros_env: dict[str, str], tmp_path: Path, args: tuple[str, ...], said: str
) -> None:
    """A launch argument a node refuses (a negative set-point, a real-time factor of 0) or that is no
    number: `ros2 launch` stops by itself, exits 1 and names the node or the argument, every other
    node finishes cleanly (none was interrupted into a traceback while importing), and the bag the
    recorder had opened is closed.  Before, the failed node's error line scrolled by and the
    rest ran on: the fish drove its fin with no speed loop until Ctrl-C."""
    assert_quiet_domain(ros_env)
    run = ros2(ros_env, "launch", "piezofin_ros", *args, timeout=120.0, cwd=tmp_path)
    out = run.stdout + run.stderr
    assert run.returncode == 1, out[-3000:]
    assert said in out, out[-3000:]
    # no traceback of ours; launch_ros's own lifecycle client, still waiting for the dead fin_sim's
    # change_state service when the launch stops, may leave one ("cannot use Destroyable": upstream)
    upstream = out.count("InvalidHandle('cannot use Destroyable")
    assert out.count("Traceback") <= upstream, out[-3000:]
    assert not re.search(r'File "[^"]*piezofin_ros/', out), out[-3000:]
    if "exited with code" in said:
        assert "the stack does not run without it, so every node stops" in out, out[-3000:]
        if "recorder]: recording" in out:  # (it may be stopped before it opens one)
            assert re.search(r"recorder\]: closed bags/piezofin_\S+\.mcap", out), out[-3000:]
        died = [line for line in out.splitlines() if "process has died" in line]
        assert len(died) == 1 and said.split()[0] in died[0], died  # the others finished cleanly


def test_launch_without_the_simulator_and_with_a_layered_params_file(
    ros_env: dict[str, str], tmp_path: Path
) -> None:
    changes = tmp_path / "mine.yaml"  # only what changes: layered on the package's bringup.yaml
    changes.write_text("/**/controller:\n  ros__parameters:\n    frequencies: [5.0, 6.0]\n")
    launch = Launch(ros_env, tmp_path, "sim:=false", f"params_file:={changes}")
    try:
        from piezofin_ros.nodes.recorder import GLOBAL_TOPICS, SUITE_TOPICS

        # a fin's topics as the table records them (supply, battery, imu too) and /clock
        launch.wait_for(f"recording {len(SUITE_TOPICS) + len(GLOBAL_TOPICS)} topics", 60.0)
        # the controller is up, with its voltages [400, 800] from bringup.yaml and frequencies from mine
        launch.wait_for("4 protocol trials", 60.0)
        nodes = node_list(ros_env, {"/fin/thrust_estimator", "/fin/controller", "/recorder"})
        assert {"/fin/thrust_estimator", "/fin/controller", "/recorder"} <= nodes, nodes
        # no fin_sim: asked of the graph itself (the CLI's daemon, started by an earlier test in this
        # domain, listed the fin_sim that test had stopped: two CI runs of 2026-12-06, whose launch
        # here had started its 3 processes only)
        direct = set(ros2(ros_env, "node", "list", "--no-daemon", "--spin-time", "5").stdout.split())
        assert "/fin/fin_sim" not in direct, direct
    finally:
        out = launch.interrupt()
    assert not errors_in(out), out[-3000:]
    assert out.count("process has finished cleanly") == 3, out[-3000:]


def test_ros2_run_refuses_a_mistyped_parameter(ros_env: dict[str, str]) -> None:
    run = ros2(ros_env, "run", "piezofin_ros", "fin_sim", "--ros-args", "-p", "realtime_factr:=10.0")
    assert run.returncode != 0
    assert "unknown parameter realtime_factr" in run.stderr + run.stdout
    assert "Traceback" not in run.stderr + run.stdout


@pytest.mark.parametrize("node", ["fin_sim", "thrust_estimator", "controller"])
def test_ros2_run_refuses_an_impossible_amplifier(ros_env: dict[str, str], tmp_path: Path, node: str) -> None:
    """Every node that takes ``amplifier`` stops on one that cannot exist with one line naming the
    parameter and the field: negative rails, an efficiency above 1, a kind nobody makes, no preset."""
    files = {
        "rail_v": "kind: linear\nrail_v: -400\n",
        "efficiency": "amplifier:\n  kind: switching\n  efficiency: 1.5\n",
        "kind": "kind: class-z\n",
    }
    cases = [(str(tmp_path / f"{k}.yaml"), k) for k in files] + [("no-such-amp", "unknown amplifier")]
    for k, text in files.items():
        (tmp_path / f"{k}.yaml").write_text(text)
    for value, words in cases:
        run = ros2(ros_env, "run", "piezofin_ros", node, "--ros-args", "-p", f"amplifier:={value}")
        out = run.stderr + run.stdout
        assert run.returncode != 0, out
        assert "parameter amplifier: " in out and words in out and "Traceback" not in out, out


def test_ros2_run_refuses_an_impossible_body_or_battery(ros_env: dict[str, str], tmp_path: Path) -> None:
    """Issue 27: a body of negative mass, a battery of no capacity, a battery with no body to carry
    it, an unknown preset: `fin_sim` and `speed_loop` stop with one line naming the parameter."""
    (tmp_path / "body.yaml").write_text("mass_kg: -1\n")
    (tmp_path / "battery.yaml").write_text("capacity_ah: 0\n")
    cases = [
        ("fin_sim", ("-p", f"body:={tmp_path / 'body.yaml'}"), "parameter body: ", "mass_kg"),
        (
            "fin_sim",
            ("-p", "body:=mfc-fish", "-p", f"battery:={tmp_path / 'battery.yaml'}"),
            "parameter battery: ",
            "capacity_ah",
        ),
        ("fin_sim", ("-p", "battery:=li-ion-2s-500mah"), "parameter battery: ", "needs a body"),
        ("fin_sim", ("-p", "body:=no-such-body"), "parameter body: ", "mfc-fish"),
        ("speed_loop", ("-p", f"body:={tmp_path / 'body.yaml'}"), "mass_kg", "body.yaml"),
        (
            "speed_loop",
            ("-p", "loop.min_demand_n:=0.5", "-p", "loop.max_demand_n:=0.1"),
            "min_demand_n",
            "below",
        ),
    ]
    for node, args, said, words in cases:
        # (judged on what it says, not on how fast a loaded machine starts Python: 4 s here alone,
        # and in two CI runs at a load of 20 one of them said nothing, or had not exited, in 60 s)
        run = ros2(ros_env, "run", "piezofin_ros", node, "--ros-args", *args, timeout=180.0)
        out = run.stderr + run.stdout
        assert run.returncode != 0, out
        assert said in out and words in out and "Traceback" not in out, (node, args, out)


def test_ros2_run_estimator_with_a_model_file(ros_env: dict[str, str], tmp_path: Path) -> None:
    """`ros2 run piezofin_ros thrust_estimator --ros-args -p model:=...`: a file that is no model stops
    it with one line naming the parameter; a diagnosed model starts it on that model's fin."""
    import yaml

    from piezofin_ros.physics.fin import load_fin
    from piezofin_ros.physics.model import Model

    bad = tmp_path / "bad.yaml"
    bad.write_text("fin: {}\neffects: {warp_drive: {}}\n")
    run = ros2(ros_env, "run", "piezofin_ros", "thrust_estimator", "--ros-args", "-p", f"model:={bad}")
    assert run.returncode != 0
    assert "parameter model: " in run.stderr + run.stdout and "bad.yaml" in run.stderr + run.stdout
    assert "Traceback" not in run.stderr + run.stdout
    good = tmp_path / "model.yaml"
    good.write_text(yaml.safe_dump(Model.of(load_fin("M8514-P1"), {"dielectric_loss": [0.05]}).to_mapping()))
    proc = subprocess.Popen(
        ["ros2", "run", "piezofin_ros", "thrust_estimator", "--ros-args", "-p", f"model:={good}"],
        env=ros_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline()
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert "M8514-P1" in first, first + out
    assert "Traceback" not in first + out


#: (two fins at x10 are seven processes: beside the other workers, in CI, an estimator heard
#: nothing for 120 s and five processes outlived launch's 5 s after SIGINT; in phase 2, alone)
TWO_FINS = pytest.param("two_fins", marks=[pytest.mark.exclusive, pytest.mark.alone])


@pytest.mark.parametrize("case", [TWO_FINS, "without_sim"])
def test_launch_testing(ros_env: dict[str, str], tmp_path: Path, case: str) -> None:
    """The launch tests in test/launch/, run by launch_testing's own `launch_test`."""
    assert_quiet_domain(ros_env)
    run = subprocess.run(
        ["launch_test", str(ROOT / "test" / "launch" / f"{case}.py")],
        env=ros_env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=400,
        stdin=subprocess.DEVNULL,
    )
    out = run.stdout + run.stderr
    assert run.returncode == 0, out[-6000:]
    assert "FAILED" not in out and "Ran " in out, out[-3000:]


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("--params-file", "config/fish.yaml", "-p", "speed_m_s:=0.066"), "0.066"),
        (("-p", "speed_m_s:=0.066", "--params-file", "config/fish.yaml"), "0.066"),  # (as rclcpp: -p last)
        (("--params-file", "config/fish.yaml", "-p", "speed_loop:speed_m_s:=0.07", "-p", "x:s:=1"), "0.07"),
        (("--params-file", "config/fish.yaml"), "0.06"),
        (("--params-file", "config/fish.yaml", "-p", "speed_m_s:=66e-3"), "0.066"),  # (strtod's, not YAML's)
    ],
)
def test_the_command_line_overrides_a_parameter_file(
    ros_env: dict[str, str], tmp_path: Path, args: tuple[str, ...], expected: str
) -> None:
    """Issue 39: ``-p speed_m_s:=0.066`` after ``--params-file config/fish.yaml`` was silently
    overridden by the file's ``/**/speed_loop`` entry (rclpy puts ``-p`` into the file's ``/**``)."""
    log = tmp_path / "speed_loop.log"
    with open(log, "w") as out:
        proc = subprocess.Popen(
            ["ros2", "run", "piezofin_ros", "speed_loop", "--ros-args", *args],
            env=ros_env,
            cwd=ROOT,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
    try:
        t0 = time.monotonic()
        while "set-point" not in log.read_text() and proc.poll() is None and time.monotonic() - t0 < 60:
            time.sleep(0.2)
    finally:
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            raise
    said = re.search(r"set-point (\S+) m/s", log.read_text())
    assert said and said.group(1) == expected, log.read_text()[-2000:]
