"""Line-of-sight guidance: a course of waypoints to the speed and the yaw rate a fish is asked.

The marine standard (Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, 2011,
ch. 10.3): on the leg from waypoint ``p_k`` to ``p_k+1`` (its angle ``a_k``), the fish at ``(x, y)``
lies ``s`` along the leg and ``e`` across it (to port positive).  It steers for a point a lookahead
``D`` ahead on the leg: the heading asked is ``a_k - atan(e / D)``, and the yaw rate asked turns the
heading error ``wrap(psi_d - psi)`` away at the gain ``k`` (1/s), within the yaw rate the fish can
give each way.  ``k`` is ``gain_per_s``, or the speed over ``heading_distance_m`` where that is more:
a fast fish turns its heading within the same distance swum as a slow one, not within the same
time (at 0.1/s a fish at 18 cm/s swam 1.8 m per time constant, finished each corner 0.6 m outside the
next leg and took 8 m to come back).  A waypoint is reached within the acceptance radius (at least
the tightest turn asked the way the course turns there, where the turn's arc begins), widened by
``turn_lead`` of the distance the fish swims in ``1 / k`` (its heading answers the rate asked with
that lag: the turn begins that much later), or once the fish is past it along its leg; then the next
leg.  The course's last waypoint reached, it is done.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from ..errors import ControlError

#: The farthest a course's point may lie from the odometry's origin, m (beyond: no fish's course).
COURSE_MOST_M = 1e7


class GuidanceError(ControlError):
    """A course or a setting guidance cannot take: the text names the field."""


def wrap(angle: float) -> float:
    """``angle`` in ``(-pi, pi]``, rad."""
    return math.atan2(math.sin(angle), math.cos(angle))


@dataclass(frozen=True)
class Leg:
    """Where the fish is against its leg: along (m, from the leg's start), across (m, to port),
    the heading asked (rad) and the distance to the course's end (m)."""

    index: int
    along_m: float
    across_m: float
    heading_rad: float
    to_go_m: float


@dataclass
class LineOfSight:
    """A course and how it is swum (module docstring); SI units, every field checked."""

    waypoints: Sequence[tuple[float, float]]
    #: (the tightest turn to port asked: at 1.5 m the twins of M8514-P1 and M8507-P1, swimming at 5.3
    #: and 3.7 cm/s, overshot each corner and swam a 20 m square 1.28 and 1.96 m off RMS; 0.26 and
    #: 0.28 m at 2.5, benchmarks/bench_course.py; a fish at 12-18 cm/s went from 0.24-0.29 to 0.28-0.33)
    lookahead_m: float = 2.5
    acceptance_m: float = 2.0  # (about the fish's turning radius: the turn begins that far before)
    gain_per_s: float = 0.1
    port_radius_m: float = 2.5  # the tightest turn asked each way, m (module docstring)
    #: (the P1's window leaves the offset -100 V under 800 Vpp, a 19 m circle on the paper's twin; the
    #: fish stack gives up voltage for the offset's room, down to 400 Vpp and -300 V: 6.4 m,
    #: control.yawloop.OffsetRoom)
    starboard_radius_m: float = 6.4
    #: (0.75 m: the distance a 7.5 cm/s fish swims in 1 / gain_per_s at the default gain; a fixed
    #: 0.2/s instead put M8507-P1 0.43 m and M8514-P1 up to 0.64 m off a 20 m square,
    #: benchmarks/bench_course.py)
    heading_distance_m: float = 0.75
    #: (half the heading's lag: a 20 m square swum 0.16-0.19 m off RMS by the twins, 0.23-0.28 m with
    #: no lead; the whole lag overshot M8528-P1's corners inward, 0.19 m)
    turn_lead: float = 0.5
    leg: int = 1  # heading for waypoints[leg], from waypoints[leg - 1]
    done: bool = False
    _lengths: list[float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        points = [tuple(p) for p in self.waypoints]
        if len(points) < 2:
            raise GuidanceError(f"waypoints: a course needs at least 2 points, got {len(points)}")
        for k, p in enumerate(points):
            if len(p) != 2 or not all(isinstance(c, (int, float)) and abs(c) <= COURSE_MOST_M for c in p):
                raise GuidanceError(
                    f"waypoints[{k}] = {p!r}: a point is two numbers (x, y) within +-{COURSE_MOST_M:g} m"
                )
        for k in range(1, len(points)):
            if math.dist(points[k - 1], points[k]) < 1e-6:
                raise GuidanceError(f"waypoints[{k}] = {points[k]!r} repeats the point before it: no leg")
        positive = (
            "lookahead_m", "acceptance_m", "gain_per_s", "port_radius_m", "starboard_radius_m",
            "heading_distance_m",
        )  # fmt: skip
        for name in (*positive, "turn_lead"):
            x = getattr(self, name)
            number = isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            least = ">" if name in positive else ">="
            if not (number and (x > 0 if name in positive else x >= 0)):
                raise GuidanceError(f"{name} = {x!r} must be a finite number {least} 0")
        self.waypoints = [(float(x), float(y)) for x, y in points]
        self._lengths = [math.dist(self.waypoints[k - 1], self.waypoints[k]) for k in range(1, len(points))]

    @property
    def length_m(self) -> float:
        """The course's length, m."""
        return sum(self._lengths)

    def off_course_m(self, x: float, y: float) -> float:
        """How far the fish at ``(x, y)`` is from the course: the least distance to any of its legs,
        m (the cross-track error a course is judged by; the leg it steers for may be the next one)."""
        best = math.inf
        for (x0, y0), (x1, y1), length in zip(
            self.waypoints, self.waypoints[1:], self._lengths, strict=False
        ):
            u = ((x - x0) * (x1 - x0) + (y - y0) * (y1 - y0)) / length**2
            u = min(max(u, 0.0), 1.0)
            best = min(best, math.hypot(x - (x0 + u * (x1 - x0)), y - (y0 + u * (y1 - y0))))
        return best

    def turn_radius_m(self, k: int) -> float:
        """The radius of the turn at ``waypoints[k]``, m: the tightest asked that way
        (``port_radius_m`` or ``starboard_radius_m``), the turn's arc beginning that far before the
        point; ``port_radius_m`` at the course's end, where there is no turn."""
        if k >= len(self.waypoints) - 1:
            return self.port_radius_m
        (x0, y0), (x1, y1), (x2, y2) = self.waypoints[k - 1 : k + 2]
        cross = (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1)
        return self.starboard_radius_m if cross < 0 else self.port_radius_m

    def gain_at(self, speed_m_s: float) -> float:
        """The yaw rate asked per radian of heading error at ``speed_m_s``, 1/s (module docstring)."""
        return max(self.gain_per_s, abs(speed_m_s) / self.heading_distance_m)

    def where(self, x: float, y: float) -> Leg:
        """The fish at ``(x, y)`` against its present leg."""
        (x0, y0), (x1, y1) = self.waypoints[self.leg - 1], self.waypoints[self.leg]
        a = math.atan2(y1 - y0, x1 - x0)
        dx, dy = x - x0, y - y0
        along = dx * math.cos(a) + dy * math.sin(a)
        across = -dx * math.sin(a) + dy * math.cos(a)
        rest = sum(self._lengths[self.leg :])
        to_go = max(self._lengths[self.leg - 1] - along, 0.0) + rest
        return Leg(self.leg, along, across, wrap(a - math.atan2(across, self.lookahead_m)), to_go)

    def update(self, x: float, y: float, heading_rad: float, speed_m_s: float = 0.0) -> tuple[float, Leg]:
        """The yaw rate to ask (rad/s, to port) for the fish at ``(x, y)`` heading ``heading_rad`` at
        ``speed_m_s``, and where it is; a waypoint reached moves to the next leg (:attr:`done` after
        the last)."""
        if not all(math.isfinite(v) for v in (x, y, heading_rad, speed_m_s)):
            raise GuidanceError(f"the fish at ({x!r}, {y!r}) heading {heading_rad!r}: not a pose")
        gain = self.gain_at(speed_m_s)
        lead = self.turn_lead * abs(speed_m_s) / gain
        while not self.done:
            here = self.where(x, y)
            past = here.along_m >= self._lengths[self.leg - 1]
            accept = max(self.acceptance_m, self.turn_radius_m(self.leg)) + lead
            if not (past or math.dist((x, y), self.waypoints[self.leg]) <= accept):
                break
            if self.leg == len(self.waypoints) - 1:
                self.done = True
            else:
                self.leg += 1
        here = self.where(x, y)
        if self.done:
            return 0.0, here
        rate = gain * wrap(here.heading_rad - heading_rad)
        u = max(abs(speed_m_s), 0.01)  # (from rest: as at 1 cm/s)
        return min(max(rate, -u / self.starboard_radius_m), u / self.port_radius_m), here
