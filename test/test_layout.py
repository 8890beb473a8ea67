"""The package is a correct ament_python package: `colcon build` gives the `ros2 run` layout."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_colcon_build_installs_executables_and_ament_index(tmp_path: Path) -> None:
    colcon = shutil.which("colcon", path=str(Path(sys.executable).parent))
    if colcon is None:
        pytest.skip("colcon is not installed in this environment")
    src = tmp_path / "ws" / "src" / "piezofin_ros"
    src.mkdir(parents=True)
    for item in ("setup.py", "setup.cfg", "package.xml", "resource", "config", "launch", "piezofin_ros"):
        source = ROOT / item
        if source.is_dir():
            shutil.copytree(source, src / item, ignore=shutil.ignore_patterns("__pycache__"))
        elif source.exists():
            shutil.copy2(source, src / item)
    ws = tmp_path / "ws"
    proc = subprocess.run(
        [colcon, "build", "--base-paths", "src"],
        cwd=ws,
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    prefix = ws / "install" / "piezofin_ros"
    # `ros2 run piezofin_ros <exe>` looks in <prefix>/lib/<package>/ ...
    for exe in (
        "piezofin",
        "sweep",
        "fin_sim",
        "thrust_estimator",
        "controller",
        "recorder",
        "player",
        "bringup",
    ):
        assert os.access(prefix / "lib" / "piezofin_ros" / exe, os.X_OK), exe
    # ... for a package registered in the ament index, with its share/ files.
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / "piezofin_ros").exists()
    assert (prefix / "share" / "piezofin_ros" / "package.xml").exists()
    assert sorted(p.name for p in (prefix / "share" / "piezofin_ros" / "config" / "fins").iterdir()) == [
        "M8507-P1.yaml",
        "M8514-P1.yaml",
        "M8528-P1.yaml",
    ]
    share = prefix / "share" / "piezofin_ros"
    assert (share / "config" / "bringup.yaml").exists()
    launch = share / "launch" / "piezofin.launch.py"
    compile(launch.read_text(), str(launch), "exec")  # launch itself is not on PyPI: syntax only
    # The installed executable runs from the install tree and finds the installed presets.
    site = next(prefix.glob("lib/python3*/site-packages"))
    env = {**os.environ, "PYTHONPATH": str(site)}
    env.pop("PIEZOFIN_CONFIG", None)
    run = subprocess.run(
        [str(prefix / "lib" / "piezofin_ros" / "sweep"), "--freq", "9.9", "--vpp", "800"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert "M8528-P1" in run.stdout
