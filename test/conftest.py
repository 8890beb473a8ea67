"""Shared fixtures: the paper's three fins; the real ROS 2 command line (``ros_env``)."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from piezofin_ros.physics.fin import Fin, load_fin

from .rosutil import BIN, clean_env

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "ros2-jazzy" / "setup.sh"

PAPER_FINS = ("M8507-P1", "M8514-P1", "M8528-P1")


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


@pytest.fixture(scope="session")
def ros_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a shell where `ros2` runs and this package is built with colcon: the
    system's `ros2` on a ROS machine, else the Jazzy overlay built from ../shared/ros2-jazzy;
    skips (one line saying why) when neither is there."""
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
