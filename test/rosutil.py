"""Helpers for tests with real rclpy contexts and executors (imported by the ROS tests only)."""

from __future__ import annotations

import array
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import rclpy
from rclpy.experimental import EventsExecutor


class Graph:
    """One rclpy context and one EventsExecutor; ``spin_until`` with a deadline."""

    def __init__(self, domain_id: int | None = None) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
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
def graph(domain_id: int | None = None) -> Iterator[Graph]:
    """A :class:`Graph` in this process's DDS domain, or in ``domain_id`` (another test's ``ros_env``)."""
    g = Graph(domain_id)
    try:
        yield g
    finally:
        g.close()


def data_type(topic: str) -> Any:
    """The message class of the suite's topic ``topic`` (``drive``, ``/fish/drive``, ...), as the topic
    table declares it."""
    from piezofin_ros.nodes._common import endpoint

    return endpoint(topic.rsplit("/", 1)[-1])[0]


def plotted(
    env: dict[str, str], topics: Sequence[str], messages: int = 3, timeout: float = 60.0
) -> dict[str, dict[str, list[tuple[float, float]]]]:
    """What a generic plotter (PlotJuggler's ROS 2 topic source, with "use the header's stamp") makes
    of ``topics`` in ``env``'s domain: each topic's type as the graph names it, a subscription of that
    type (best-effort, volatile: it matches any publisher), each message's numeric fields flattened
    into series named by their path (``thrust_n``, ``header/stamp/sec``), each point at the message's
    ``header.stamp`` (NaN without a header).  Returns ``{topic: {path: [(stamp s, value)]}}`` once each
    topic gave ``messages`` messages."""
    import importlib

    from rclpy.qos import QoSProfile, ReliabilityPolicy

    def message_class(type_name: str) -> Any:  # ``pkg/msg/Name``, by its generated module
        pkg, _, name = type_name.split("/")
        return getattr(importlib.import_module(f"{pkg}.msg"), name)

    def flat(value: Any, path: str, out: dict[str, float]) -> None:  # by the type's own field list
        if hasattr(value, "get_fields_and_field_types"):
            for k in value.get_fields_and_field_types():
                flat(getattr(value, k), f"{path}/{k}" if path else k, out)
        elif isinstance(value, (list, tuple, array.array)) or getattr(value, "ndim", 0) == 1:
            for i, v in enumerate(value):
                flat(v, f"{path}[{i}]", out)
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            out[path] = float(value)

    series: dict[str, dict[str, list[tuple[float, float]]]] = {t: {} for t in topics}
    counts = dict.fromkeys(topics, 0)
    with graph(int(env.get("ROS_DOMAIN_ID", "0"))) as g:
        node = g.add(rclpy.create_node("_plotter", context=g.context))
        g.spin_until(
            lambda: set(topics) <= {n for n, _ in node.get_topic_names_and_types()}, timeout, "the topics"
        )
        types = dict(node.get_topic_names_and_types())

        def take(topic: str, msg: Any) -> None:
            fields: dict[str, float] = {}
            flat(msg, "", fields)
            stamp = fields.get("header/stamp/sec", math.nan) + fields.get("header/stamp/nanosec", 0.0) * 1e-9
            for path, value in fields.items():
                series[topic].setdefault(path, []).append((stamp, value))
            counts[topic] += 1

        qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
        for t in topics:
            node.create_subscription(message_class(types[t][0]), t, lambda m, t=t: take(t, m), qos)
        g.spin_until(
            lambda: all(n >= messages for n in counts.values()), timeout, f"{messages} messages each"
        )
    return series


def assert_quiet_domain(
    env: dict[str, str], listen_s: float = 1.5, wait_s: float = 25.0, besides: tuple[str, ...] = ()
) -> None:
    """No node runs in ``env``'s DDS domain (hidden ``_`` nodes, such as the ros2 daemon, aside): a
    suite about to start there would otherwise share its ``/clock`` and topics with a process an
    earlier test left running.  Nodes that are going away get ``wait_s`` to leave the graph."""
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env.get("ROS_DOMAIN_ID", "0")))
    probe = rclpy.create_node("_quiet_domain_probe", context=context)
    try:
        time.sleep(listen_s)  # discovery on loopback
        t0 = time.monotonic()
        while True:
            names = sorted(
                f"{ns.rstrip('/')}/{n}"
                for n, ns in probe.get_node_names_and_namespaces()
                if not n.startswith("_")
            )
            names = [name for name in names if name not in besides]  # (nodes the test started)
            if not names:
                return
            if time.monotonic() - t0 > wait_s:
                raise AssertionError(
                    f"ROS domain {env.get('ROS_DOMAIN_ID', '0')} is not empty before the suite starts: "
                    f"{names} (a process an earlier test left running?)"
                )
            time.sleep(0.5)
    finally:
        probe.destroy_node()
        rclpy.shutdown(context=context)


class Launch:
    """`ros2 launch ...` in its own session (SIGINT reaches it as Ctrl-C would), output to a file,
    in a domain where nothing else runs."""

    def __init__(
        self,
        env: dict[str, str],
        cwd: Path,
        *args: str,
        log: str = "launch.log",
        file: str = "piezofin.launch.py",
        besides: tuple[str, ...] = (),
    ) -> None:
        assert_quiet_domain(env, besides=besides)  # (``besides``: nodes the test started, by full name)
        self.log = cwd / log
        self.started = time.monotonic()
        self.proc = subprocess.Popen(
            ["ros2", "launch", "piezofin_ros", file, *args],
            env=env,
            cwd=cwd,
            stdin=subprocess.DEVNULL,
            stdout=open(self.log, "w"),  # noqa: SIM115 (closed with the process)
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )

    def output(self) -> str:
        return self.log.read_text()

    def wait_for(self, text: str, timeout: float = 60.0) -> None:
        t0 = time.monotonic()
        while text not in self.output():
            if time.monotonic() - t0 > timeout or self.proc.poll() is not None:
                raise AssertionError(f"{text!r} not in the launch output:\n{self.output()[-3000:]}")
            time.sleep(0.2)

    def interrupt(self) -> str:
        os.killpg(self.proc.pid, signal.SIGINT)  # Ctrl-C in the terminal: the whole process group
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            raise
        return self.output()


def errors_in(out: str) -> list[str]:
    """The ``[ERROR]`` lines of a launch's output but launch's own escalation ("failed to terminate '5'
    seconds after receiving 'SIGINT', escalating to 'SIGTERM'"): a node slower than 5 s to stop on a
    loaded machine (CI's whole run, beside two other workers), which launch then stops with SIGTERM,
    as the node handles it.  A test that allows it still asserts that every process finished cleanly.
    Nor the death launch reports for a child whose status asyncio's child watcher lost ("Unknown child
    process pid N, will report returncode 255", then "process has died [pid N, exit code 255"): the
    status is asyncio's guess, not the node's (once in a whole run, the controller of a clean stop)."""
    lost = set(re.findall(r"Unknown child process pid (\d+), will report returncode 255", out))
    return [
        x
        for x in out.splitlines()
        if "[ERROR]" in x
        and "failed to terminate" not in x
        and not any(f"process has died [pid {pid}, exit code 255" in x for pid in lost)
    ]


def ros2(
    env: dict[str, str], *args: str, timeout: float = 60.0, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """The real ``ros2`` command line, as a user types it (no standard input, output captured)."""
    return subprocess.run(
        ["ros2", *args],
        env=env,
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


def node_list(env: dict[str, str], expected: set[str], timeout: float = 30.0) -> set[str]:
    """`ros2 node list`, asked again until every expected node shows (discovery takes its time)."""
    return listed(env, nodes=expected, timeout=timeout)[0]


def listed(
    env: dict[str, str],
    nodes: Iterable[str] = (),
    topics: Iterable[str] = (),
    timeout: float = 60.0,
    *,
    lifecycle: bool = False,
) -> tuple[set[str], set[str]]:
    """``ros2 node list`` and ``ros2 topic list``, asked again until they show ``nodes`` and ``topics``
    (or ``timeout``): as a user waits before naming a node to ``ros2 lifecycle`` or ``ros2 param``.
    On a loaded machine the CLI's discovery lags the graph by seconds (stop 46's whole run:
    ``lifecycle set /fin/fin_sim`` said "Node not found" of a node that was driving).  ``lifecycle``:
    ``ros2 lifecycle nodes`` instead of ``ros2 node list``, the list ``ros2 lifecycle set`` itself
    looks the node up in (a node with its ``get_state`` service discovered: stop 65's CI, a fin the
    node list showed was "not found" by the service's later discovery)."""
    want_nodes, want_topics = set(nodes), set(topics)
    node_cmd = ("lifecycle", "nodes") if lifecycle else ("node", "list")
    t0 = time.monotonic()
    while True:
        seen_nodes, seen_topics = (
            set(ros2(env, *cmd, "--spin-time", "3").stdout.split()) if want else set()
            for cmd, want in ((node_cmd, want_nodes), (("topic", "list"), want_topics))
        )
        if (want_nodes <= seen_nodes and want_topics <= seen_topics) or time.monotonic() - t0 > timeout:
            return seen_nodes, seen_topics
        time.sleep(0.5)


BIN = Path(sys.executable).parent


def clean_env(**extra: str) -> dict[str, str]:
    """This environment without another ROS venv's bootstrap variables (they break a child's rclpy)."""
    env = {
        k: v for k, v in os.environ.items() if k not in ("_ROS_WHEELS_BOOTSTRAP_COMPLETE", "LD_LIBRARY_PATH")
    }
    env.update(extra)
    return env


def start(exe: str, *ros_args: str, log: Path | None = None, **popen: Any) -> subprocess.Popen[str]:
    """An executable of the package with ``--ros-args``, as ``ros2 run`` starts it (stdout+stderr piped,
    or written to ``log`` where the test reads them while it runs); in this process's clean
    environment, or ``env`` (another test's ``ros_env``: its DDS domain)."""
    env = popen.pop("env", None)
    return subprocess.Popen(
        [str(BIN / exe), "--ros-args", *ros_args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE if log is None else open(log, "w"),
        stderr=subprocess.STDOUT,
        text=True,
        env=clean_env() if env is None else env,
        **popen,
    )


def start_driving_controller(namespace: str, *ros_args: str) -> subprocess.Popen[str]:
    """A ``controller`` in ``namespace`` driving 6 Hz at 800 Vpp continuously, with no estimator to
    wait for (the watchdog and latch tests drive fin_sim alone)."""
    return start(
        "controller",
        "-r",
        f"__ns:=/{namespace}",
        "-p",
        "mode:=continuous",
        "-p",
        "frequencies:=[6.0]",
        "-p",
        "voltages:=[800.0]",
        "-p",
        "wait_estimator_s:=0.0",
        *ros_args,
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
