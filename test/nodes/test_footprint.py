"""The nodes a fish runs are small: what they import, and their CPU and memory at 1 kHz real time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = (
    "numba",
    "llvmlite",
    "mcap",
    "zstandard",
    "rosbags",
    "scipy.optimize",
    "scipy.sparse",
    "scipy.signal",
    "scipy.stats",
    "matplotlib",
)


@pytest.mark.parametrize(
    ("node", "allowed"),
    [
        ("thrust_estimator", ()),
        ("controller", ()),
        ("speed_loop", ()),
        ("waypoints", ()),
        ("recorder", ("mcap", "zstandard", "rosbags")),
    ],
)
def test_a_node_loads_nothing_it_does_not_use(node: str, allowed: tuple[str, ...]) -> None:
    """numba (60 MB), the MCAP writer and scipy.signal are loaded only by what uses them: fin_sim
    compiles its loop on first call, the recorder writes bags; a fish's estimator and controller do
    neither (before: each node loaded them all, about 200 MB).  Nor do they load ``scipy.optimize``
    (45 MB, 450 modules): the controller's fit is ``control/lsq.py`` (before stop 47 the controller
    peaked at 117-120 MB, against the goal of 120)."""
    code = f"import sys, piezofin_ros.nodes.{node}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
    loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert [m for m in loaded if m not in allowed] == []


@pytest.mark.exclusive
@pytest.mark.alone  # (a share of a core measured: beside another test, 10.6 % once)
@pytest.mark.ros
@pytest.mark.slow
def test_estimator_and_controller_fit_a_fish_at_1_khz() -> None:
    """`benchmarks/bench_footprint.py` for 40 s: thrust_estimator, controller (optimising, drive
    only) and speed_loop beside fin_sim at 1 kHz in real time, each in its own process, each under
    10 % of a core and 120 MB resident at its peak.  (The controller's CPU comes in a burst per 6 s
    trial, a fit of 0.2-0.4 s: a 20 s window held three or four of them, and read 6.4-11.5 % where
    60 s read 6.1 %.)"""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
    from bench_footprint import CPU_GOAL, FISH_NODES, RSS_GOAL_MB, measure

    rows = measure(seconds=40.0)
    print("\n".join(r.row() for r in rows))
    nodes = {r.name: r for r in rows}
    for name in FISH_NODES[:3]:  # (waypoints: with --fish)
        assert nodes[name].cpu_percent < CPU_GOAL, rows
        assert nodes[name].peak_mb < RSS_GOAL_MB, rows
        assert nodes[name].cpu_percent > 0.1, rows  # (it was running: a dead node measures nothing)
