"""``piezofin swim`` as a user runs it (issue 27): how fast and how far a fish goes on each paper
fin, by strategy, and one line for every impossible body or battery."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from . import run


def piezofin(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return run.piezofin("swim", *args, cwd=cwd)


def test_a_fish_on_each_paper_fin_by_strategy(tmp_path: Path) -> None:
    run = piezofin("--json", "--plot", str(tmp_path / "swim.png"))
    assert run.returncode == 0, run.stderr
    r = json.loads(run.stdout)
    assert (tmp_path / "swim.png").stat().st_size > 20_000
    assert r["twin"] and set(r["fins"]) == {"M8528-P1", "M8514-P1", "M8507-P1"}
    for name, rows in r["fins"].items():
        best = rows["range"]
        for strategy, x in rows.items():
            # the range strategy is the longest (its grid holds every other point but the resonance's)
            assert x["range_m"] <= best["range_m"] * (1 + 1e-3), (name, strategy)
            assert x["speed_m_s"] > 0 and x["supply_w"] > 0 and x["cost_of_transport"] > 0
            # energy per metre x range: what one charge delivers, most of the pack's 7.4 V x 0.5 A h
            delivered = x["energy_per_m_j"] * x["range_m"]
            assert 0.8 * 7.4 * 0.5 * 3600 < delivered < 1.05 * 7.4 * 0.5 * 3600, (name, strategy, delivered)
    # the anchor: M8528-P1's twin at the paper's point swims Cen & Erturk's 0.3 body lengths/s
    paper = r["fins"]["M8528-P1"]["paper (5.5 Hz, 800 Vpp)"]
    assert paper["speed_body_lengths_s"] == pytest.approx(0.3, rel=0.01)


def test_the_fixed_draw_below_which_the_range_strategy_goes_30_percent_further(tmp_path: Path) -> None:
    """Issue 27's range goal (30 % beyond the fixed drive at resonance) is a matter of the fixed draw:
    the command names, per fin, the fixed draw below which the range strategy reaches it; run with
    that hotel load (and the amplifier's quiescent draw in it), the table shows the gain, and 20 %
    above it, it does not."""
    r = json.loads(piezofin("--fins", "M8528-P1", "--json").stdout)
    g = r["range_gain"]["M8528-P1"]
    assert g["fixed_draw_w"] == pytest.approx(0.25 + 0.05)  # the preset's hotel and quiescent draws
    assert 1e-3 < g["fixed_draw_below_w"] < 0.03, g  # a few mW: well below any fish's electronics
    quiet = tmp_path / "quiet.yaml"  # the fish's amplifier without its quiescent draw
    quiet.write_text(
        "amplifier:\n  kind: switching\n  efficiency: 0.85\n  recovered: 0.5\n"
        "  quiescent_w: 0.0\n  bus_v: 7.4\n"
    )
    for scale, reached in ((0.97, True), (1.2, False)):
        hotel = str(scale * g["fixed_draw_below_w"])
        run = piezofin("--fins", "M8528-P1", "--hotel", hotel, "--amplifier", str(quiet), "--json")
        gain = json.loads(run.stdout)["fins"]["M8528-P1"]["range"]["range_vs_baseline"]
        assert (gain >= 0.3) == reached, (scale, gain)


def test_the_watt_decides_the_range_once_the_fixed_draw_is_gone() -> None:
    """Without a hotel load, a controller that optimises the fin's mean(v i) drives the fin where it
    draws almost nothing and goes nowhere; in the battery's watt, it swims."""
    r = json.loads(piezofin("--fins", "M8528-P1", "--hotel", "0", "--json").stdout)["fins"]["M8528-P1"]
    assert r["range (fin watt)"]["range_m"] < 0.1 * r["range"]["range_m"]


@pytest.mark.parametrize(
    ("option", "text", "words"),
    [
        ("--body", "mass_kg: -1\nlength_m: 0.2\n", "mass_kg"),
        ("--body", "drag_area_m2: 0\n", "drag_area_m2"),
        ("--body", "fins: 7\n", "fins"),
        ("--body", "wings: 2\n", "unknown key"),
        ("--battery", "capacity_ah: 0\n", "capacity_ah"),
        ("--battery", "cells: -2\n", "cells"),
        ("--battery", "hotel_w: .nan\n", "hotel_w"),
        ("--body", "drag_area_m2: 1.0e+300\n", "drag_area_m2"),
        ("--body", "length_m: 1.0e+9\n", "length_m"),
        ("--battery", "[1, 2]\n", "mapping"),
    ],
)
def test_an_impossible_body_or_battery_is_one_line(
    tmp_path: Path,
    option: str,
    text: str,
    words: str,
) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(text)
    run = piezofin(option, str(path))
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and str(path) in lines[0], run.stderr


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (("--body", "no-such-body"), "mfc-fish"),
        (("--battery", "no-such-battery"), "li-ion-2s-500mah"),
        (("--amplifier", "no-such-amp"), "fish-switching"),
        (("--hotel", "-1"), "hotel_w"),
        (("--hotel", "1e308"), "hotel_w"),
        (("--voltage-max", "0"), "--voltage-max"),
        (("--fins", "nope"), "nope"),
    ],
)
def test_bad_arguments_are_one_line(args: tuple[str, ...], words: str) -> None:
    run = piezofin(*args)
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], run.stderr
