"""What the optimiser maximises, passed in: a figure of merit of a point's thrust and watt.

The paper ranks a fin's operating points by thrust per watt.  A fish pays a fixed draw besides (its
electronics: the hotel load) whatever the fin does, and its speed grows as the square root of the
thrust (quadratic drag); it goes farthest on one charge where its speed per watt of everything is
highest, the inverse of its cost of transport.  Both are a :class:`PerWatt`,

.. math::

    J = \\frac{T^{\\,a}}{P + P_0},

with ``a = 1, P_0 = 0`` the paper's thrust per watt and ``a = 1/2, P_0`` the fixed draw a fish's
range.  Under a thrust demand the thrust counts up to the demand only, so every objective becomes
"the least watt that meets it" (the fixed draw changes no choice there: the speed is the demand's).
An objective is any callable ``(thrust_n, power_w, demand_n) -> score`` (higher is better) with a
``name``; :data:`OBJECTIVES` names the ones a node's ``objective`` parameter takes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from ..errors import ControlError

FloatArray = NDArray[Any]


class Objective(Protocol):
    """A figure of merit the optimiser maximises (module docstring)."""

    @property
    def name(self) -> str: ...

    def __call__(self, thrust_n: Any, power_w: Any, demand_n: float | None = None) -> FloatArray: ...


@dataclass(frozen=True)
class PerWatt:
    """``T^a / (P + P_0)``, the thrust capped at a demand (module docstring)."""

    thrust_exponent: float = 1.0  # a: 1 thrust per watt; 1/2 speed per watt on quadratic drag
    fixed_w: float = 0.0  # P_0, W: a draw paid whatever the drive (a fish's hotel load)
    name: str = "thrust per watt"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.thrust_exponent) and 0 < self.thrust_exponent <= 2):
            raise ControlError(f"objective: thrust_exponent {self.thrust_exponent!r} must be within (0, 2]")
        if not (math.isfinite(self.fixed_w) and self.fixed_w >= 0):
            raise ControlError(f"objective: fixed_w {self.fixed_w!r} W must be finite and >= 0")

    def __call__(self, thrust_n: Any, power_w: Any, demand_n: float | None = None) -> FloatArray:
        thrust = np.asarray(thrust_n, float)
        if demand_n is not None:
            thrust = np.minimum(thrust, demand_n)
        watts = np.maximum(np.asarray(power_w, float) + self.fixed_w, 1e-300)
        return np.asarray(np.maximum(thrust, 0.0) ** self.thrust_exponent / watts)


#: The paper's figure of merit, and every optimiser's unless told otherwise.
THRUST_PER_WATT = PerWatt()


def range_per_charge(fixed_w: float) -> PerWatt:
    """A fish's distance per joule, up to a constant: speed (``sqrt(T)`` on quadratic drag) per watt of
    the fin's draw and the fixed draw ``fixed_w`` (W)."""
    return PerWatt(0.5, fixed_w, f"speed per watt with {fixed_w:g} W of fixed draw (range)")


#: Each by the name a node's ``objective`` parameter takes, built from the fixed draw (W).
OBJECTIVES: dict[str, Callable[[float], Objective]] = {
    "thrust_per_watt": lambda fixed_w: THRUST_PER_WATT,
    "range": range_per_charge,
}
