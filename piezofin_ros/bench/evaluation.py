"""Scoring an optimiser on a plant (the benchmark's and the tests' scaffolding, no ROS).

:func:`run_trial` runs one simulated trial, :func:`score` is a point's true objective on a plant,
:func:`true_optimum` the plant's optimum on a dense grid, and :func:`campaign` a run of trials with
the fraction of the optimum reached after each.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..control.optimise import OperatingBox, Optimiser
from ..physics.amplifier import watt_of
from .plants import Plant, read

FloatArray = NDArray[Any]


#: Fin time of one trial: continuous driving (2 s settle + two 2 s windows that must agree) and
#: the paper's protocol (10 s off, 10 s on, 10 s off).
TRIAL_S_CONTINUOUS = 6.0
TRIAL_S_PROTOCOL = 30.0


def run_trial(opt: Optimiser, plant: Plant, t: float, rng: np.random.Generator) -> float:
    """One simulated trial of ``TRIAL_S_CONTINUOUS``: propose, read ``plant`` as the estimator would
    from the optimiser's source, observe; the new time."""
    f, v = opt.propose()
    r = read(plant, f, v, t, rng, opt.source, opt.fin, opt.watt, opt.amplifier)
    t += TRIAL_S_CONTINUOUS
    opt.observe(t, f, v, r.thrust_n, r.power_w, r.admittance, r.power_named_w, r.voltage_pp)
    return t


def score(
    plant: Plant,
    f: float,
    v: float,
    demand_n: float | None,
    min_thrust_n: float = 1e-3,
    t: float = 0.0,
    watt: str = "fin",
) -> float:
    """True objective of a point on a plant: thrust per watt (``watt``: the supply is the plant's true
    amplifier's draw), 0 if it misses the demand in truth."""
    r = plant.steady(f, v, t)
    thrust, power = float(r.thrust_n), float(r.power(_true(watt), plant.amplifier))
    need = demand_n if demand_n is not None else min_thrust_n
    if thrust < need or power <= 0:
        return 0.0
    return (min(thrust, demand_n) if demand_n is not None else thrust) / power


def true_optimum(
    plant: Plant,
    limits: OperatingBox,
    demand_n: float | None,
    voltage_pp: float = 800.0,
    min_thrust_n: float = 1e-3,
    t: float = 0.0,
    watt: str = "fin",
) -> tuple[float, float, float]:
    """Dense evaluation of the plant: ``(f, V, objective)`` of its optimum (2000 x 600 grid)."""
    f = np.geomspace(limits.frequency_min_hz, limits.frequency_max_hz, 2000)
    if demand_n is None:
        v = np.full_like(f, voltage_pp)
    else:
        f, v = np.meshgrid(f, np.linspace(limits.voltage_pp_min, limits.voltage_pp_max, 600))
    r = plant.steady(f, v, t)
    need = demand_n if demand_n is not None else min_thrust_n
    thrust = np.minimum(r.thrust_n, demand_n) if demand_n is not None else r.thrust_n
    obj = np.where(
        r.thrust_n >= need, thrust / np.maximum(r.power(_true(watt), plant.amplifier), 1e-300), 0.0
    )
    i = np.unravel_index(int(np.argmax(obj)), obj.shape)
    return float(f[i]), float(v[i]), float(obj[i])


def campaign(
    opt: Optimiser,
    plant: Plant,
    n: int,
    rng: np.random.Generator,
    t0: float = 0.0,
    best: float | None = None,
) -> tuple[list[float], float]:
    """``n`` trials; the fraction of the true optimum the held point (:meth:`Optimiser.held`) reaches
    after each, and the time at the end.  ``best``: the optimum's objective (default: recomputed at
    each trial's time, for a plant that drifts)."""
    t, fractions = t0, []
    for _ in range(n):
        t = run_trial(opt, plant, t, rng)
        f, v = opt.held()
        top = (
            best if best is not None else true_optimum(plant, opt.limits, opt.demand_n, t=t, watt=opt.watt)[2]
        )
        fractions.append(score(plant, f, v, opt.demand_n, t=t, watt=opt.watt) / top)
    return fractions, t


def _true(watt: str) -> str:
    """The watt in truth: the supply the plant's amplifier truly draws, whichever model estimates it."""
    return watt_of(watt).model.name
