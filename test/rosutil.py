"""Helpers for tests with real rclpy contexts and executors (imported by the ROS tests only)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rclpy.experimental import EventsExecutor


class Graph:
    """One rclpy context and one EventsExecutor; ``spin_until`` with a deadline."""

    def __init__(self) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.nodes: list[Any] = []

    def add(self, node: Any) -> Any:
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, done: Callable[[], bool], timeout: float, what: str = "condition") -> float:
        t0 = time.monotonic()
        while not done():
            if time.monotonic() - t0 > timeout:
                raise TimeoutError(f"{what} not reached within {timeout} s")
            self.executor.spin_once(timeout_sec=0.05)
        return time.monotonic() - t0

    def spin_for(self, seconds: float) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            self.executor.spin_once(timeout_sec=0.02)

    def close(self) -> None:
        for node in self.nodes:
            close = getattr(node, "close", None)
            if close is not None:
                close()
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        if self.context.ok():
            rclpy.shutdown(context=self.context)


@contextmanager
def graph() -> Iterator[Graph]:
    g = Graph()
    try:
        yield g
    finally:
        g.close()


BIN = Path(sys.executable).parent


def clean_env(**extra: str) -> dict[str, str]:
    """This environment without another ROS venv's bootstrap variables (they break a child's rclpy)."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "LD_LIBRARY_PATH")
    }
    env.update(extra)
    return env


def start(exe: str, *ros_args: str, **popen: Any) -> subprocess.Popen[str]:
    """An executable of the package with ``--ros-args``, as ``ros2 run`` starts it (stdout+stderr piped)."""
    return subprocess.Popen(
        [str(BIN / exe), "--ros-args", *ros_args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=clean_env(),
        **popen,
    )


def stop(*procs: subprocess.Popen[str]) -> list[str]:
    """SIGINT to each process still running (as Ctrl-C would), wait for it; returns each one's output."""
    outs = []
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
        try:
            out, _ = p.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            p.kill()
            out, _ = p.communicate()
        except ValueError:  # its output was read already
            out = ""
        outs.append(out or "")
    return outs
