"""The committed sample bag (two protocol trials of M8528-P1 at 800 Vpp, recorded by `bringup`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from piezofin_ros.estimation.offline import replay_estimates
from piezofin_ros.physics.fin import load_fin

SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_M8528-P1.mcap"


def test_rosbags_reads_the_sample_bag_completely() -> None:
    with AnyReader([SAMPLE]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        t = []
        for conn, _, raw in reader.messages(
            connections=[c for c in reader.connections if c.topic == "/fin/drive"]
        ):
            msg = reader.deserialize(raw, conn.msgtype)
            n = msg.layout.dim[1].size
            t.append(np.asarray(msg.data[:n]))
    assert types["/fin/drive"] == "std_msgs/msg/Float64MultiArray"
    assert types["/clock"] == "rosgraph_msgs/msg/Clock"
    assert types["/fin/controller/status"] == "std_msgs/msg/String"
    samples = np.concatenate(t)
    assert samples.size >= 60_000  # two 30 s trials at 1 kHz
    assert np.allclose(np.diff(samples), 1e-3, atol=1e-6)  # contiguous: no block lost


def test_offline_replay_reproduces_the_live_estimates() -> None:
    replay = replay_estimates(SAMPLE, load_fin("M8528-P1"))
    assert len(replay.recorded) >= 2
    assert replay.skipped == []
    assert replay.max_relative_difference() <= 1e-12


def test_estimate_cli() -> None:
    exe = Path(sys.executable).parent / "piezofin"
    run = subprocess.run([exe, "estimate", str(SAMPLE)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "reproduces the" in run.stderr
    assert "9.900" in run.stdout


@pytest.mark.parametrize("content", [None, b"", b"\x89MCAP0\r\ntruncated"])
def test_estimate_cli_on_bad_files(tmp_path: Path, content: bytes | None) -> None:
    bad = tmp_path / "bad.mcap"
    if content is not None:
        bad.write_bytes(content)
    exe = Path(sys.executable).parent / "piezofin"
    run = subprocess.run([exe, "estimate", str(bad)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert str(bad) in run.stderr
    assert "Traceback" not in run.stderr
