"""The objective passed in (issue 40): the optimiser maximises what it is given, thrust per watt
unless told otherwise, and a fish's range (speed per watt of everything it pays) when asked."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from piezofin_ros.control.objective import OBJECTIVES, THRUST_PER_WATT, PerWatt, range_per_charge
from piezofin_ros.control.optimise import Correction, Optimiser
from piezofin_ros.errors import ControlError
from piezofin_ros.physics.fin import Fin

from .test_optimise import LIMITS


def test_each_objective_is_its_closed_form() -> None:
    assert THRUST_PER_WATT(2e-3, 0.1) == pytest.approx(0.02)
    assert THRUST_PER_WATT(2e-3, 0.1, 1e-3) == pytest.approx(0.01)  # (counted up to the demand)
    fish = range_per_charge(0.3)
    assert fish(4e-3, 0.1) == pytest.approx(math.sqrt(4e-3) / 0.4)
    assert fish(4e-3, 0.1, 1e-3) == pytest.approx(math.sqrt(1e-3) / 0.4)
    assert OBJECTIVES["thrust_per_watt"](0.3) is THRUST_PER_WATT
    assert OBJECTIVES["range"](0.3) == fish
    # under a demand every objective ranks points as the least watt does
    power = np.array([0.3, 0.1, 0.2])
    for objective in (THRUST_PER_WATT, fish, PerWatt(2.0, 1.0)):
        assert np.argmax(objective(np.full(3, 5e-3), power, 4e-3)) == np.argmin(power)


@pytest.mark.parametrize("bad", [{"thrust_exponent": 0.0}, {"thrust_exponent": math.nan}, {"fixed_w": -1.0}])
def test_an_objective_out_of_range_is_one_clear_error(bad: dict[str, float]) -> None:
    with pytest.raises(ControlError, match="objective"):
        PerWatt(**bad)


#: the frequencies of the brute force over the optimiser's map (at 400 Vpp, no demand)
BRUTE_F = np.geomspace(LIMITS.frequency_min_hz, LIMITS.frequency_max_hz, 4000)


def choices_against_brute_force(fin: Fin, objectives: Any) -> tuple[dict[str, Any], np.ndarray]:
    """Each objective's choice by a fresh optimiser (no demand, no trial), checked against the brute
    force's best over the same map: named in the status, within 2 % of it.  Returns the choices by
    the objective's name and the map's thrust over :data:`BRUTE_F`."""
    pred = Correction().predict(fin, BRUTE_F, np.full_like(BRUTE_F, 400.0))
    thrust, power = np.asarray(pred.thrust_n), np.asarray(pred.power_w)
    ok = thrust >= 1e-3
    chosen = {}
    for objective in objectives:
        opt = Optimiser(fin, LIMITS, voltage_pp=400.0, objective=objective, identify=False)
        c = opt.choice
        assert c is not None and opt.status()["objective"] == objective.name
        best = float(np.max(objective(thrust[ok], power[ok])))
        # (within 2 %: the optimiser asks the least thrust of its map's lower bound, the brute force of
        # its mean, and thrust per watt is best at that edge)
        assert float(objective(c.thrust_n, c.power_w)) >= 0.98 * best, objective.name
        chosen[objective.name] = c
    return chosen, thrust


def test_the_optimiser_takes_the_maps_best_by_the_objective_it_is_given(m8528: Fin) -> None:
    """No demand, no trial yet: the choice is the map's best frequency at the configured voltage by
    the objective passed in, against a brute force over the same map; a fish whose 0.3 W of hotel
    load dwarfs the fin's watt goes farthest near the most thrust, not at the best thrust per watt."""
    chosen, thrust = choices_against_brute_force(m8528, (THRUST_PER_WATT, range_per_charge(0.3)))
    tpw, fish = chosen[THRUST_PER_WATT.name], chosen[range_per_charge(0.3).name]
    assert fish.thrust_n > tpw.thrust_n and abs(fish.frequency_hz / BRUTE_F[np.argmax(thrust)] - 1) < 0.02
