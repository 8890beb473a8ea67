"""``piezofin watts`` as a user runs it: the best thrust per watt in each watt, against the paper's facts
and the diagnosis's draw, and one line for every bad input."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from piezofin_ros.diagnosis.paper import PAPER_FINS, Fins, quantities
from piezofin_ros.physics.model import Model

from . import run


def piezofin(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return run.piezofin("watts", *args, cwd=cwd)


def test_the_best_point_moves_with_the_watt(tmp_path: Path) -> None:
    run = piezofin("--json", "--plot", str(tmp_path / "fig10.png"))
    assert run.returncode == 0, run.stderr
    best = json.loads(run.stdout)["watts"]
    assert (tmp_path / "fig10.png").stat().st_size > 20_000
    draw = quantities({n: Model(f) for n, f in Fins().fins.items()}, "amplifier draw", Fins())
    for name in PAPER_FINS:
        b = best[name]
        # the fin's mean(v i): 14-51 times the paper's 60.7 mN/W; the amplifier's draw: the diagnosis's
        assert 0.8 < b["fin"]["thrust_per_watt"] / 60.7e-3 / 10 < 6
        bench = b["supply (paper-bench)"]
        assert bench["voltage_pp"] == 800.0  # a class-B stage: its best is at the highest drive
        assert bench["thrust_per_watt"] == pytest.approx(draw[f"max_tpw_{name}"], rel=0.02)
        assert bench["thrust_per_watt"] < b["apparent"]["thrust_per_watt"] < b["fin"]["thrust_per_watt"]
    # M8528-P1: 5.5 Hz per fin watt, 10 Hz per supply watt
    assert best["M8528-P1"]["fin"]["frequency_hz"] == pytest.approx(5.5)
    assert best["M8528-P1"]["supply (paper-bench)"]["frequency_hz"] == pytest.approx(10.0)


@pytest.mark.fast_cases("args0---voltages", "args5-efficiency")
@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--voltages", "-3"], "--voltages"),
        (["--voltages", "nan"], "--voltages"),
        (["--fins", "nope"], "nope"),
        (["--freq", "abc"], "--freq"),
        (["--plot", "/proc/x.png"], "--plot"),
        (["--amplifiers", "{bad}"], "efficiency"),
        (["--amplifiers", "{neg}"], "rail_v"),
        (["--amplifiers", "class-z"], "unknown amplifier"),
    ],
)
def test_bad_input_is_one_line(tmp_path: Path, args: list[str], words: str) -> None:
    (tmp_path / "bad.yaml").write_text("kind: switching\nefficiency: 1.2\n")
    (tmp_path / "neg.yaml").write_text("amplifier:\n  kind: linear\n  rail_v: -400\n")
    args = [
        a.replace("{bad}", str(tmp_path / "bad.yaml")).replace("{neg}", str(tmp_path / "neg.yaml"))
        for a in args
    ]
    run = piezofin(*args)
    assert run.returncode == 2, run.stdout + run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("piezofin: error:") and words in lines[0], run.stderr
