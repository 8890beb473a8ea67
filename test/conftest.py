"""Shared fixtures: the paper's three fins; the real ROS 2 command line (``ros_env``)."""

from __future__ import annotations

import fcntl
import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from piezofin_ros.physics.fin import Fin, load_fin

from .rosutil import BIN, clean_env

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "ros2-jazzy" / "setup.sh"

PAPER_FINS = ("M8507-P1", "M8514-P1", "M8528-P1")


#: A test of the fast tier (not marked ``slow``) should take at most this long; longer ones are named.
FAST_TEST_S = 5.0
_tier_seconds: dict[str, float] = {}  # "fast", "slow": summed wall time; "fast cpu", "slow cpu"
_fast_but_slow: dict[str, float] = {}  # a fast-tier test's wall time (setup, call, teardown)
_cpu_by_test: dict[str, float] = {}


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Sums each tier's test time (setup, call and teardown; on the controller under xdist)."""
    tier = "slow" if "slow" in report.keywords else "fast"
    _tier_seconds[tier] = _tier_seconds.get(tier, 0.0) + report.duration
    cpu = dict(report.user_properties).get("cpu_s")
    if cpu is not None:
        _cpu_by_test[report.nodeid] = float(cpu)
        _tier_seconds[f"{tier} cpu"] = _tier_seconds.get(f"{tier} cpu", 0.0) + float(cpu)
    if tier == "fast":
        _fast_but_slow[report.nodeid] = _fast_but_slow.get(report.nodeid, 0.0) + report.duration


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """The tiers' times, and the fast tier's tests that outgrew it (mark them ``slow`` or shrink them)."""
    if not _tier_seconds:
        return
    tr = terminalreporter
    tr.write_sep("=", "test time by tier (summed over workers)")
    for tier in ("fast", "slow"):
        if tier in _tier_seconds:
            which = "marked slow" if tier == "slow" else "not marked slow"
            cpu = _tier_seconds.get(f"{tier} cpu", 0.0)
            tr.write_line(f"{tier} tier ({which}): {_tier_seconds[tier]:.0f} s, {cpu:.0f} s of CPU")
    top = sorted(_cpu_by_test.items(), key=lambda kv: -kv[1])[:15]
    if top and len(_cpu_by_test) > 15:
        tr.write_line("most CPU (the test's processes and their children, s):")
        for nodeid, cpu in top:
            tr.write_line(f"  {cpu:7.1f}  {nodeid}")
    over = sorted(((t, n) for n, t in _fast_but_slow.items() if t > FAST_TEST_S), reverse=True)
    for t, n in over:
        tr.write_line(
            f"fast-tier test over {FAST_TEST_S:.0f} s: {n} ({t:.1f} s): mark it slow or make it smaller"
        )


@contextmanager
def _machine(exclusive: bool) -> Iterator[None]:
    """A readers-writer lock across the test workers: an ``exclusive`` test waits for the running
    tests to end and runs alone (the others queue behind it at the turnstile); the rest run side by
    side.  Latency bounds (a watchdog within 1 s of a kill, no drop at 1 kHz) are then measured on a
    machine that only their own processes load, as a user's robot would be."""
    d = ROOT / ".ros"
    d.mkdir(parents=True, exist_ok=True)
    # (a lock of each phase's own: tools/test.sh runs the two phases side by side)
    name = os.environ.get("PIEZOFIN_TEST_LOCK", "tests")
    with open(d / f"{name}.turnstile", "w") as turnstile, open(d / f"{name}.lock", "w") as lock:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        finally:
            fcntl.flock(turnstile, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _cpu_s() -> float:
    """CPU seconds of this process and of its children that have ended."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Under pytest-xdist, each test (its fixtures' setup and teardown too) takes the machine lock.
    Each test's CPU time (its processes' too) goes to its report: the terminal summary's table."""
    item.user_properties.append(("cpu_start_s", _cpu_s()))
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        yield
        return
    # (phase 2 runs the exclusive tests two at a time: there, only those marked ``alone`` run alone)
    marker = "alone" if os.environ.get("PIEZOFIN_EXCLUSIVE_TOGETHER") else "exclusive"
    with _machine(exclusive=item.get_closest_marker(marker) is not None):
        yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    outcome = yield
    report = outcome.get_result()
    start = dict(item.user_properties).get("cpu_start_s")
    if start is not None and report.when == "teardown":
        report.user_properties.append(("cpu_s", _cpu_s() - float(start)))


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """``@pytest.mark.fast_cases("id", ...)`` on a parametrized test: the cases named stay in the fast
    tier, every other case is marked ``slow`` (the whole suite runs them all).  A test marked ``alone``
    must be ``exclusive`` too (tools/test.sh runs the alone ones in a phase of their own, after the
    parallel one, which takes every test not exclusive: one not exclusive would run in both)."""
    lone = [
        i.nodeid for i in items if i.get_closest_marker("alone") and not i.get_closest_marker("exclusive")
    ]
    if lone:
        raise pytest.UsageError(f"marked alone but not exclusive: {', '.join(lone)}")
    for item in items:
        keep = item.get_closest_marker("fast_cases")
        callspec = getattr(item, "callspec", None)
        if keep is not None and callspec is not None and callspec.id not in keep.args:
            item.add_marker(pytest.mark.slow)


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist each worker gets a DDS domain of its own (``ROS_DOMAIN_ID`` + its number),
    set before any rclpy context or child process exists, so parallel ROS tests never see each
    other's graphs."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    if worker.startswith("gw"):
        base = int(os.environ.get("ROS_DOMAIN_ID", "0"))
        k = int(worker[2:])
        os.environ["ROS_DOMAIN_ID"] = str(base + 1 + k * 2)
        # a campaign's bringups, each in a domain of its own, draw from a block of the worker's own,
        # counted down from 232, above every worker's domain and its ROS CLI domain (`ros_env`): 6
        # domains a worker up to 16 workers, then fewer (a campaign's stage needs 3); before, the
        # blocks 215 + (k % 3) * 6 repeated from a fourth worker on (tools/test.sh's phase 2, the
        # exclusive tests on workers of their own, runs no campaign)
        count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
        size = max(3, min(6, 100 // max(count, 1)))
        first = 233 - size * (k + 1)
        os.environ["PIEZOFIN_ROS_DOMAINS"] = f"{first}-{first + size - 1}"


@pytest.fixture(params=PAPER_FINS)
def paper_fin(request: pytest.FixtureRequest) -> Fin:
    return load_fin(request.param)


@pytest.fixture
def m8528() -> Fin:
    return load_fin("M8528-P1")


def _sourced(*scripts: Path) -> dict[str, str]:
    """The environment after sourcing ``scripts`` (after activating the project's venv)."""
    lines = [f"source {BIN / 'activate'}", "set +u", *(f"source {s}" for s in scripts), "env -0"]
    out = subprocess.run(
        ["bash", "-c", "; ".join(lines)], capture_output=True, env=clean_env(), check=True, timeout=60
    ).stdout
    env = dict(item.split("=", 1) for item in out.decode().split("\0") if "=" in item)
    env.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    return env


@contextmanager
def _one_at_a_time(name: str) -> Iterator[None]:
    """One test process at a time (pytest-xdist's workers share the project's ``.ros/``)."""
    lock = ROOT / ".ros" / f"{name}.lock"
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


@pytest.fixture(scope="session")
def ros_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a shell where `ros2` runs and this package is built with colcon: the
    system's `ros2` on a ROS machine, else the Jazzy overlay built from ../shared/ros2-jazzy;
    skips (one line saying why) when neither is there.  Built once; parallel test workers wait for
    the one building it."""
    with _one_at_a_time("ros_env"):
        return _ros_env(tmp_path_factory)


def _ros_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    overlay: list[Path] = []
    if shutil.which("ros2", path=os.environ.get("PATH")) is None:
        if not SHARED.exists():
            pytest.skip("no ros2 on the PATH and no ../shared/ros2-jazzy to build it from")
        out = ROOT / ".ros" / "ros2-jazzy"
        build = subprocess.run(
            ["bash", str(SHARED), str(BIN.parent), str(out)], capture_output=True, text=True, env=clean_env()
        )
        if build.returncode != 0:
            pytest.fail(f"building ros2cli and launch failed:\n{build.stderr[-2000:]}")
        overlay.append(out / "install" / "local_setup.bash")
    ws = ROOT / ".ros" / "ws"
    (ws / "src").mkdir(parents=True, exist_ok=True)
    link = ws / "src" / "piezofin_ros"
    if not link.exists():
        link.symlink_to(ROOT)
    colcon = subprocess.run(
        [str(BIN / "colcon"), "build", "--symlink-install", "--base-paths", "src"],
        cwd=ws,
        capture_output=True,
        text=True,
        env=_sourced(*overlay),
        timeout=300,
    )
    assert colcon.returncode == 0, colcon.stdout[-2000:] + colcon.stderr[-2000:]
    env = _sourced(*overlay, ws / "install" / "local_setup.bash")
    env["ROS_DOMAIN_ID"] = str((int(os.environ.get("ROS_DOMAIN_ID", "0")) + 101) % 200 + 1)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["ROS_LOG_DIR"] = str(tmp_path_factory.mktemp("roslog"))
    return env
