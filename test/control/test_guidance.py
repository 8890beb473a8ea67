"""Line-of-sight guidance (issue 42): a course of points to a yaw rate, held to the geometry, and a
fish that swims a square with it within a body length of the course."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest

from piezofin_ros.bench.course import square, swim_course
from piezofin_ros.bench.fishrun import FixedDrive
from piezofin_ros.control.guidance import GuidanceError, LineOfSight, wrap
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.model import Model
from piezofin_ros.physics.swim import load_body

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("points", "named"),
    [
        ([], "at least 2 points"),
        ([(0.0, 0.0)], "at least 2 points"),
        ([(0.0, 0.0), (math.nan, 1.0)], "waypoints[1]"),
        ([(0.0, 0.0), (1.0, math.inf)], "waypoints[1]"),
        ([(0.0, 0.0), (1e300 * 10, 1.0)], "waypoints[1]"),
        ([(0.0, 0.0), (1.0, 1.0), (1.0, 1.0)], "waypoints[2]"),
        ([(0.0, 0.0), ("1", 1.0)], "waypoints[1]"),
        ([(0.0, 0.0, 0.0), (1.0, 1.0)], "waypoints[0]"),
    ],
)
def test_a_course_that_is_none_is_refused_naming_the_point(points: list, named: str) -> None:
    with pytest.raises(GuidanceError, match=named.replace("[", r"\[").replace("]", r"\]")):
        LineOfSight(points)


@pytest.mark.parametrize("field", ["lookahead_m", "acceptance_m", "gain_per_s", "port_radius_m"])
@pytest.mark.parametrize("value", [0.0, -1.0, math.nan, math.inf])
def test_a_setting_that_is_none_is_refused_naming_it(field: str, value: float) -> None:
    with pytest.raises(GuidanceError, match=field):
        LineOfSight(square(10.0), **{field: value})


@pytest.mark.parametrize("field", ["heading_distance_m", "turn_lead"])
@pytest.mark.parametrize("value", [-1.0, math.nan, math.inf, "5", True])
def test_a_heading_distance_or_turn_lead_that_is_none_is_refused_naming_it(field: str, value: object) -> None:
    with pytest.raises(GuidanceError, match=field):
        LineOfSight(square(10.0), **{field: value})  # type: ignore[arg-type]
    assert LineOfSight(square(10.0), turn_lead=0.0).turn_lead == 0.0  # (no lead: the turn at R)
    with pytest.raises(GuidanceError, match="heading_distance_m"):
        LineOfSight(square(10.0), heading_distance_m=0.0)


def test_the_line_of_sight_is_the_legs_angle_less_the_offset_over_the_lookahead() -> None:
    los = LineOfSight([(0.0, 0.0), (10.0, 0.0), (10.0, 10.0)], lookahead_m=2.0, gain_per_s=0.1)
    leg = los.where(3.0, 1.0)  # 3 m along, 1 m to port
    assert (leg.along_m, leg.across_m) == pytest.approx((3.0, 1.0))
    assert leg.heading_rad == pytest.approx(-math.atan(0.5)) and leg.to_go_m == pytest.approx(17.0)
    rate, _ = los.update(3.0, 1.0, 0.0, speed_m_s=0.1)
    assert rate == pytest.approx(-0.1 / 6.4)  # (to starboard: as tight as its 6.4 m radius allows)
    rate, _ = los.update(3.0, -0.1, 0.0, speed_m_s=0.05)
    assert rate == pytest.approx(0.1 * math.atan(0.05))  # (a small error: the gain's)
    rate, _ = los.update(3.0, -0.1, 0.0, speed_m_s=0.15)  # (faster than 0.75 m x 0.1/s: within 0.75 m)
    assert rate == pytest.approx(0.15 / 0.75 * math.atan(0.05))
    # the 2.5 m turn begins earlier by half the distance swum in 1 / the gain: 0.25 m at 5 cm/s,
    # 0.375 m at 10 cm/s (the gain then 0.133/s)
    los.update(7.2, 0.0, 0.0, speed_m_s=0.05)  # 2.8 m before the corner
    assert los.leg == 1
    los.update(7.2, 0.0, 0.0, speed_m_s=0.1)
    assert los.leg == 2 and not los.done
    rate, _ = los.update(10.0, 9.0, math.pi / 2, speed_m_s=0.1)
    assert los.done and rate == 0.0
    assert wrap(3 * math.pi) == pytest.approx(math.pi) and los.off_course_m(5.0, -1.0) == pytest.approx(1.0)


@pytest.mark.parametrize("turn", ["port", "starboard"])
def test_each_turn_begins_its_own_radius_before_its_corner(turn: str) -> None:
    """A corner to starboard is reached ``starboard_radius_m`` before it, one to port
    ``port_radius_m`` before it (a mixed course: each turn's arc where it begins), the course's end
    within the acceptance or the port radius; the course's turn at each point read from its legs."""
    side = 1.0 if turn == "port" else -1.0
    course = [(0.0, 0.0), (20.0, 0.0), (20.0, 20.0 * side), (40.0, 20.0 * side), (40.0, 0.0)]
    los = LineOfSight(course, port_radius_m=2.5, starboard_radius_m=6.4, turn_lead=0.0)
    first, second = (2.5, 6.4) if turn == "port" else (6.4, 2.5)
    assert (los.turn_radius_m(1), los.turn_radius_m(2), los.turn_radius_m(4)) == (first, second, 2.5)
    for radius, (x, y), heading in ((first, course[1], 0.0), (second, course[2], side * math.pi / 2)):
        before = los.leg
        back = (x - (radius + 0.05) * math.cos(heading), y - (radius + 0.05) * math.sin(heading))
        los.update(*back, heading, speed_m_s=0.05)
        assert los.leg == before, f"taken {radius + 0.05} m before a {radius} m turn"
        nearer = (x - (radius - 0.05) * math.cos(heading), y - (radius - 0.05) * math.sin(heading))
        los.update(*nearer, heading, speed_m_s=0.05)
        assert los.leg == before + 1, f"not taken {radius - 0.05} m before a {radius} m turn"


@pytest.mark.slow  # (7 s)
def test_a_fish_steered_by_its_offset_swims_a_square_within_a_body_length() -> None:
    """The issue's goal on a 20 m square (about ten turning radii; a smaller one cannot be held: a
    corner cut on a 2.5 m circle lies 1 m off): the fish swims it, steered by its fin's offset alone,
    off the course by less than its 25 cm length RMS, at the paper's point (5.5 Hz, 800 Vpp: 5.5 cm/s;
    0.16 m RMS, 0.19 m with no turn lead, and 1.27 J/m of the amplifier's draw, as
    benchmarks/bench_course.py's fixed drives measure it)."""
    fin, body = load_fin("M8528-P1"), load_body("mfc-fish")
    amplifier, drive = load_amplifier("fish-switching"), FixedDrive(5.5, 800.0)
    run = swim_course(Model(fin), body, amplifier, LineOfSight(square(20.0)), drive)
    assert run.done and run.distance_m == pytest.approx(80.0, rel=0.1)
    assert run.off_course_rms_m <= body.length_m, run.off_course_rms_m
    assert 1.0 < run.joules_per_m < 1.6, run.joules_per_m


@pytest.mark.slow
@pytest.mark.parametrize("fish", ["M8528-P1", "stranger 2"])
def test_the_optimiser_ranking_by_range_swims_the_square_as_cheaply_as_the_best_fixed_drive(
    fish: str,
) -> None:
    """Issue 42's range goal (benchmarks/bench_course.py's runs): the optimising controller, on the
    drive's voltage and current alone and ranking by speed per watt with the battery's fixed draw
    (the cost of transport), swims the 20 m square within a body length at a battery energy per metre
    within 5 % of the best fixed drive in truth (an oracle's point, chosen on the fish in truth
    swimming straight), its exploration included. Measured: the M8528-P1 twin +0.9 %; stranger 2,
    given the twin (its fin resonating at 9.3 Hz where the twin says 5.5), +4.9 %: +8.5 % while the
    twin was dropped only at the fourth trial (``Tuning.prior_drop_after``), the fish at 4.6 Hz and
    7 cm/s for its first 55 s."""
    from benchmarks.bench_course import BEST, RANGE, run

    ours, best = (run((fish, d, 20.0, "port"))["run"] for d in (RANGE, BEST))
    for r in (ours, best):
        assert r.done and r.off_course_rms_m <= 0.25, (r.done, r.off_course_rms_m)
    cost = (ours.joules_per_m_all, best.joules_per_m_all)
    assert cost[0] <= 1.05 * cost[1], cost
    assert ours.range_m >= 0.95 * best.range_m, (ours.range_m, best.range_m)


@pytest.mark.slow
@pytest.mark.parametrize("fish", ["M8507-P1", "stranger 2"])
def test_a_slow_and_a_fast_fish_swim_the_square_within_a_body_length(fish: str) -> None:
    """The two fish that missed the goal before the turn lead and the heading's distance
    (benchmarks/bench_course.py): the M8507-P1 twin at 3.7 cm/s (0.28 m RMS before, 0.18 m now) and
    stranger 2 at its best fixed drive, 18 cm/s (0.33 m before, 0.16 m now), where a gain of 0.1/s
    left it each corner 0.6 m outside the next leg."""
    from benchmarks.bench_course import BEST, run

    r = run((fish, BEST, 20.0, "port"))["run"]
    assert r.done and r.off_course_rms_m <= 0.25, (r.done, r.off_course_rms_m)


@pytest.mark.slow  # (60 s)
def test_a_square_to_starboard_is_swum_by_giving_up_voltage_for_the_offsets_room() -> None:
    """Issue 42: to starboard the P1's window leaves the offset -100 V under 800 Vpp, a 19 m circle on
    the M8528-P1 twin.  The optimising stack caps its voltage for the room its yaw loop's offset
    wants (``OffsetRoom``, down to 400 Vpp and -300 V: 6.4 m) and swims the 20 m square to starboard
    0.60 m off RMS (2.4 body lengths: the middle of a 6.4 m turn lies 1.9 m inside both legs); with no
    cap, 10.9 m."""
    command = [
        sys.executable,
        "benchmarks/bench_course.py",
        "--fish", "M8528-P1",
        "--drives", "ours: range",
        "--to", "starboard",
    ]  # fmt: skip
    out = subprocess.run(
        command, cwd=ROOT, capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL
    )
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr[-3000:]
    assert "a 20 m square swum to starboard" in out.stdout, out.stdout
    row = next(line for line in out.stdout.splitlines() if line.startswith("| M8528-P1 | ours: range |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    rms = float(cells[6].split(" m /")[0])
    assert cells[3] == "yes" and rms <= 1.0, row
