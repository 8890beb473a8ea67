"""The map's frontier (``control/thrustmap.py``): the least voltage that meets the demand at each
frequency, found in a handful of maps and placed exactly where a 24-step bisection placed it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.bench.plants import Plant
from piezofin_ros.control import thrustmap
from piezofin_ros.control.optimise import Optimiser
from piezofin_ros.control.thrustmap import BISECTIONS, least_root
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.model import load_model

from .test_optimise import LIMITS, campaign


def bisection(opt: Optimiser, f: np.ndarray) -> np.ndarray:
    """The frontier's voltages as a bisection finds them (what the frontier was until 2026-11-28)."""
    lim = opt.limits
    vmax = np.full_like(f, lim.voltage_pp_max)
    sigma = thrustmap.model_sigma(opt, f, vmax)
    feasible = thrustmap.surface(opt, f, vmax, sigma).thrust_low_n >= opt.demand_n
    lo, hi = np.full_like(f, lim.voltage_pp_min), vmax.copy()
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        ok = thrustmap.surface(opt, f, mid, sigma).thrust_low_n >= opt.demand_n
        hi, lo = np.where(ok, mid, hi), np.where(ok, lo, mid)
    return np.where(feasible, hi, lim.voltage_pp_max)


@pytest.mark.parametrize("demand", [3e-4, 3e-3, 8e-3, 0.5])  # (0.5 N: met nowhere)
@pytest.mark.parametrize("model", ["nominal", "twin"])
def test_the_frontier_is_the_bisections_in_fewer_maps(
    m8528: Fin, model: str, demand: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same voltages, bit for bit, as the bisection (the nominal model in the fin's watt is flat
    in frequency: a choice among equal points must not move with the search's rounding), and the
    twin's amplitude-dependent model alike; in at most 20 maps where it took 26, most of them of the
    few frequencies not yet settled (the twin at 0.3 mN: 20 maps of 60, 57 x 6, 54, 49, 40, 15, ...
    points; on the fish's course the controller's CPU fell by a third)."""
    given = None if model == "nominal" else load_model("paper-twin-M8528-P1")
    opt = Optimiser(m8528, LIMITS, demand_n=demand, model=given, amplifier=load_amplifier("fish-switching"))
    f = np.geomspace(LIMITS.frequency_min_hz, LIMITS.frequency_max_hz, 60)
    want = bisection(opt, f)
    maps = []
    surface = thrustmap.surface
    monkeypatch.setattr(thrustmap, "surface", lambda *a, **k: maps.append(1) or surface(*a, **k))
    s, feasible = thrustmap.frontier(opt, f)
    assert np.array_equal(s.voltage_pp, want)
    assert np.all(s.thrust_low_n[feasible] >= demand)
    assert np.all(s.voltage_pp[~feasible] == LIMITS.voltage_pp_max)
    assert np.any(feasible) == (demand < 8e-3 or (model == "nominal" and demand < 0.5)), feasible
    assert len(maps) <= 20, len(maps)


def test_the_least_root_is_the_least_voltage_seen_to_meet_it() -> None:
    """On laws that are not the thrust's square (a power of 3.7, a kink at the root, a step): the
    answer always meets the demand and lies within the tolerance of the least voltage that does; in
    a few maps on a smooth law, and on the kink at a third of a bisection's rate at worst."""
    v_min, v_max = 50.0, 800.0
    roots = np.array([60.0, 123.4, 400.0, 799.0, 50.0])
    laws = {
        "V^3.7": lambda v, r: 3.7 * np.log(v / r),
        "a kink": lambda v, r: np.where(v < r, 0.2, 5.0) * np.log(v / r),
        "a step": lambda v, r: np.where(v >= r, 1.0, -1.0) * (1.0 + np.abs(np.log(v / r))),
    }
    for name, law in laws.items():
        maps = []
        tol = 1e-6 if name == "a kink" else 1e-9

        def gap(at: np.ndarray, v: np.ndarray, law=law, maps=maps) -> np.ndarray:
            maps.append(1)
            return law(v, roots[at])

        g_max = law(np.full(roots.size, v_max), roots)
        v = least_root(gap, g_max >= 0, v_min, v_max, g_max, tol=tol)
        assert np.all(law(v, roots) >= 0), name
        assert v == pytest.approx(np.maximum(roots, v_min), rel=10 * tol), name
        assert len(maps) <= {"V^3.7": 10, "a kink": 61, "a step": 40}[name], (name, len(maps))
    # (met nowhere: the most voltage, untried)
    out = least_root(
        lambda at, v: np.full(int(np.sum(at)), -1.0), np.zeros(3, bool), v_min, v_max, -np.ones(3)
    )
    assert np.all(out == v_max) and not math.isnan(float(out[0]))


@pytest.mark.fast_cases("None")
@pytest.mark.parametrize("given", [None, "paper-twin-M8528-P1"])
def test_the_models_uncertainty_is_tabled_once_a_fit_and_read_where_it_was_derived(
    m8528: Fin, given: str | None
) -> None:
    """After six trials on a plant off the model (a fitted covariance: a sigma that varies across
    the band), the frontier's sigma at full voltage comes from one table a fit (each demand and each
    of a demand's three maps derived it anew: most of a demand's cost on a fish): the value itself on
    the first map's grid, within 3 % of it between (a 2 % step in frequency), and derived again
    only after the next fit."""
    model = None if given is None else load_model(given)
    opt = Optimiser(m8528, LIMITS, demand_n=3e-3, model=model, amplifier=load_amplifier("fish-switching"))
    campaign(opt, Plant(m8528, softening=0.3, resonance_scale=0.9, loss_tan_delta=0.1), 6)
    vmax = LIMITS.voltage_pp_max
    grid = np.geomspace(LIMITS.frequency_min_hz, LIMITS.frequency_max_hz, opt.tuning.n_grid)
    exact = thrustmap.model_sigma(opt, grid, np.full_like(grid, vmax))
    assert np.ptp(exact) > 0.2 * np.max(exact) > 0, exact  # (a sigma that varies: a table that may be wrong)
    np.testing.assert_array_equal(thrustmap.tabled_sigma(opt, grid, vmax), exact)
    between = np.sqrt(grid[1:] * grid[:-1])
    want = thrustmap.model_sigma(opt, between, np.full_like(between, vmax))
    np.testing.assert_allclose(thrustmap.tabled_sigma(opt, between, vmax), want, rtol=0.03)
    derived = []
    model_sigma = thrustmap.model_sigma
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(thrustmap, "model_sigma", lambda *a, **k: derived.append(1) or model_sigma(*a, **k))
        for demand in (1e-3, 2e-3, 4e-3):
            opt.set_demand(demand)
        assert derived == []  # (three demands, nine maps: the table of this fit)
        campaign(opt, Plant(m8528, softening=0.3, resonance_scale=0.9, loss_tan_delta=0.1), 1, seed=1, t0=1e3)
        assert derived, "a new fit derives its table again"
