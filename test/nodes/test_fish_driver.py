"""A fish you can plug in: ``ros2 launch piezofin_ros fish.launch.py sim:=false`` with the fish's own
driver (``test/fish_driver.py``: not ``fin_sim``, another fin, amplifier, body, speed sensor and
battery than the stack is told) in a process of its own, at real time: it swims, and is near its
set-point in truth by the end."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ..rosutil import Launch, node_list, ros2, stop

# exclusive: a driver at real time beside the parallel CPU-bound tests; and the suite's launch tests
# beside it saw nodes outlive launch's 5 s stop (two full runs of stop 44)
pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.exclusive]
ROOT = Path(__file__).resolve().parents[2]
#: the README's two lines, as typed
STACK = ("ros2", "launch", "piezofin_ros", "fish.launch.py", "sim:=false", "speed_m_s:=0.05")
DRIVER = ("python", "test/fish_driver.py", "--ros-args", "-r", "__ns:=/fish")
SPEED_M_S = 0.05  # (STACK's set-point)
#: The run, and its last stretch, whose mean speed in truth must be within ``NEAR`` of the set-point.
#: The driver is another fish than the stack is told (its body drags more than the told one, its
#: speed sensor reads 0.1 cm/s high); live, at real time, the stack's first trials overshoot and the
#: speed loop's integral then removes the drag law's error with a time constant of 90 s.  In five
#: runs the fish swam 4.52-4.61 cm/s at 75 s and 4.64-4.88 at 100-120 s in four; of two runs of
#: 200 s one held within 5 % from 86 s, the other crept from -7.6 % at 77 s to -3.8 % at 160 s.
#: Before the stack dropped a wrong prior it swam 12.9-22.7 % slow for good: 10 % tells them apart.
RUN_S, LAST_S, NEAR = 120.0, 20.0, 0.1


def test_the_fish_stack_runs_a_fish_driver_it_did_not_start(ros_env: dict[str, str], tmp_path: Path) -> None:
    assert f"speed_m_s:={SPEED_M_S}" in STACK
    truth, said = tmp_path / "truth.csv", tmp_path / "driver.log"
    # the fish first (its drive at 0 V: the estimator learns the battery's fixed draw there), then the stack
    driver = subprocess.Popen(
        [sys.executable, *DRIVER[1:], "-p", f"truth_file:={truth}"],  # (this venv's python)
        env=ros_env,
        cwd=ROOT,
        stdin=subprocess.DEVNULL,
        stdout=open(said, "w"),  # noqa: SIM115 (closed with the process)
        stderr=subprocess.STDOUT,
    )
    t0 = time.monotonic()
    while "driving the fin from cmd" not in said.read_text() and time.monotonic() - t0 < 60.0:
        time.sleep(0.2)
    try:
        launch = Launch(ros_env, tmp_path, *STACK[4:], file=STACK[3], besides=("/fish/fish_driver",))
    except BaseException:
        stop(driver)
        raise
    try:
        launch.wait_for("the supply watt is measured on /fish/battery", 60.0)
        nodes = node_list(ros_env, {"/fish/speed_loop", "/fish/fish_driver"})
        assert {"/fish/speed_loop", "/fish/fish_driver"} <= nodes, nodes
        # no fin_sim: asked of the graph itself (the CLI's daemon, started by an earlier test in this
        # domain, listed a fin_sim that test had stopped: a CI run of 2026-11-27)
        direct = set(ros2(ros_env, "node", "list", "--no-daemon", "--spin-time", "5").stdout.split())
        assert "/fish/fin_sim" not in direct and "/fish/fish_driver" in direct, direct
        time.sleep(max(0.0, RUN_S - (time.monotonic() - launch.started)))
    finally:  # (the stack first, as the fish's operator would, then the fish)
        try:
            out = launch.interrupt()
        finally:
            stop(driver)
    assert "[ERROR]" not in out and "Traceback" not in out, out[-3000:]
    assert "fin_sim" not in out, out[-3000:]
    rows = np.loadtxt(truth, delimiter=",", skiprows=1, ndmin=2)
    t, speed, volts = rows[:, 0] - rows[0, 0], rows[:, 1], rows[:, 4]
    assert volts.max() <= 800.0 + 1e-6
    assert np.any(volts > 100.0), "the stack never drove the fish"
    # near its set-point in truth by the end (NEAR: see above)
    last = float(np.mean(speed[t > t[-1] - LAST_S]))
    assert abs(last / SPEED_M_S - 1.0) <= NEAR, (last, speed[::200])
