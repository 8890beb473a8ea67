"""The optimiser on fins it has never seen, and on a fish that senses only its own drive (no ROS).

Plants carry effects outside the optimiser's correction (``benchmarks/bench_unseen.py`` runs the
whole library of them against the paper's grid, random search and model-free GP-BO); readings come
as ``thrust_estimator`` gives them, the thrust with the paper's ``c_m`` (vibrometer) or self-sensed
with the paper's ``C_eq`` and ``theta`` (a fish).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.bench.evaluation import campaign, run_trial, score, true_optimum
from piezofin_ros.bench.plants import Plant, read
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.physics.effects import AddedMassOffset, DragOffset, make
from piezofin_ros.physics.fin import load_fin

LIMITS = OperatingBox(1.0, 20.0, 50.0, 800.0)


def demand_of(fin_name: str) -> float:
    """30 % of the fin's nominal maximum thrust at 800 Vpp (the benchmark's demand)."""
    fin = load_fin(fin_name)
    return 0.3 * float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))


#: The hidden fins of the issue: effects the earlier optimiser's correction did not contain.
ISSUE = {
    "M8528-P1": lambda fin: Plant(fin, softening=0.35, loss_tan_delta=0.05),
    "M8514-P1": lambda fin: Plant(fin, effects=(make("field_coupling", [0.3, 1.0]), DragOffset(1.8))),
    "M8507-P1": lambda fin: Plant(fin, effects=(AddedMassOffset(1.25),)),
}


#: The least fraction of the true optimum held in trials 11 and 12 (66-72 s of fin time), by source and
#: task.  Measured (seed 1): load cell 0.96-0.98 with a demand, 0.99-1.0 without; vibrometer
#: 0.86-0.96 with, 0.985-1.0 without; fish 0.77-0.93 with, 0.95-0.99 without.  With a demand the
#: margin (2 sigma of a trial's noise, of the model's parameters and, on a fish, of the self-sensing's
#: calibration) costs its own size in power, and more on a fish.
LEAST = {
    ("loadcell", "demand"): 0.95,
    ("loadcell", "none"): 0.97,
    ("vibrometer", "demand"): 0.85,
    ("vibrometer", "none"): 0.97,
    ("self", "demand"): 0.75,
    ("self", "none"): 0.94,
}


@pytest.mark.fast_cases("M8528-P1-none-loadcell", "M8507-P1-none-self")
@pytest.mark.parametrize("source", ["loadcell", "vibrometer", "self"])
@pytest.mark.parametrize("task", ["demand", "none"])
@pytest.mark.parametrize("fin_name", list(ISSUE))
def test_the_issues_hidden_fins(fin_name: str, task: str, source: str) -> None:
    """Each hidden fin of the issue, each task, with a load cell, a vibrometer and on a fish: the
    point held meets the demand (or the least thrust) in truth at every trial from the first point
    that counts on (the earlier optimiser: 0 of 4 fish runs met the demand in truth), and reaches
    ``LEAST`` of the true optimum by the 11th trial (the earlier optimiser: 0.71-1.00)."""
    fin = load_fin(fin_name)
    plant = ISSUE[fin_name](fin)
    demand = demand_of(fin_name) if task == "demand" else None
    _, _, best = true_optimum(plant, LIMITS, demand)
    opt = Optimiser(fin, LIMITS, demand_n=demand, source=source)
    rng, t, fractions = np.random.default_rng(1), 0.0, []
    for _ in range(12):
        t = run_trial(opt, plant, t, rng)
        if opt.incumbent() is not None:
            f, v = opt.held()
            met = float(plant.steady(f, v).thrust_n) >= (demand if demand is not None else 1e-3)
            assert met, (f, v, opt.status())
        fractions.append(score(plant, *opt.held(), demand) / best)
    assert min(fractions[10:]) >= LEAST[source, task], fractions
    assert opt.changes == 0  # the fin does not change: a change seen would be a false alarm


@pytest.mark.slow
def test_a_fish_calibrates_its_self_sensing_from_the_drive_alone() -> None:
    """Dielectric loss of tan delta 0.1 and a coupling 30 % stronger at 800 Vpp: the raw self-sensed
    thrust is off by tens of per cent; the fit of the drive's admittance finds the loss and the
    coupling, and the re-estimated thrust agrees with the truth within its stated bound."""
    fin = load_fin("M8528-P1")
    plant = Plant(fin, loss_tan_delta=0.1, effects=(make("field_coupling", [0.3, 1.0]),))
    opt = Optimiser(fin, LIMITS, demand_n=demand_of("M8528-P1"), source="self")
    campaign(opt, plant, 8, np.random.default_rng(2))
    c = opt.correction
    assert c.loss_tan_delta == pytest.approx(0.1, abs=0.015)
    assert c.coupling_k == pytest.approx(0.3, abs=0.06)
    last = opt.observations[-1]
    truth = float(plant.steady(last.frequency_hz, last.voltage_pp).thrust_n)
    raw = read(plant, last.frequency_hz, last.voltage_pp, 0.0, np.random.default_rng(3), "self").thrust_n
    assert abs(raw / truth - 1) > 0.15
    estimate = float(opt.problem.thrust_estimates(c, [last])[0])
    bound = opt.status()["self_sensing_bound"]
    assert 0 < bound < 0.2  # (drive only: the coupling, the stiffness and c_m trade off)
    assert abs(estimate / truth - 1) <= max(bound, 0.01) + 0.01
    assert abs(estimate / truth - 1) < abs(raw / truth - 1) / 3


@pytest.mark.slow
def test_the_status_says_which_mode_and_why() -> None:
    """On a fin the corrected model describes, the status says "model"; where it keeps mispredicting,
    "search" with the misfit in the reason: an amplifier clipping its output far into the band, seen
    by a rig whose estimates carry no drive voltage (the fit then takes the commanded one; with the
    monitor's, the fin's correction describes the clipped drive too and the residual process takes
    the clipping on the commanded map)."""
    fin = load_fin("M8528-P1")
    opt = Optimiser(fin, LIMITS, demand_n=demand_of("M8528-P1"))
    assert opt.status()["optimiser_mode"] == "model" and "no trial" in opt.status()["optimiser_reason"]
    campaign(opt, Plant(fin, softening=0.2, loss_tan_delta=0.05), 6, np.random.default_rng(4))
    assert opt.status()["optimiser_mode"] == "model", opt.status()["optimiser_reason"]
    clipped = Plant(fin, effects=(make("amplifier_limit", [8.0]),))
    opt = Optimiser(fin, LIMITS, voltage_pp=800.0)
    modes = []
    for seed in range(8):
        f, v = opt.propose()
        r = read(clipped, f, v, 0.0, np.random.default_rng(10 + seed), opt.source)
        assert r.voltage_pp < v or f < 5.0  # (clipped far into the band)
        opt.observe(6.0 * (seed + 1), f, v, r.thrust_n, r.power_w, r.admittance)  # (no drive voltage)
        modes.append(opt.status()["optimiser_mode"])
    assert "search" in modes, opt.status()
    status = opt.status()
    assert status["optimiser_mode"] != "search" or "misses the trials by" in status["optimiser_reason"]
    assert math.isfinite(status["unexplained"]["thrust"])


@pytest.mark.slow
def test_a_point_counts_on_the_trials_that_did_not_choose_it() -> None:
    """The winner's curse: of several noisy trials near the demand, the one that looks best is the
    luckiest.  With a load cell (the thrust itself, 0.5 % noise) the point held meets the demand in
    truth at every trial of 8 runs, each with its own noise.  (Counting a point on the trial that chose
    it, 9 of 27 load-cell runs of ``bench_unseen`` ended on a point 0.1-0.2 % short of the demand.)"""
    fin = load_fin("M8528-P1")
    plant = Plant(fin, softening=0.2, loss_tan_delta=0.05)
    demand = demand_of("M8528-P1")
    _, _, best = true_optimum(plant, LIMITS, demand)
    finals = []
    for seed in range(8):
        opt = Optimiser(fin, LIMITS, demand_n=demand, source="loadcell")
        rng, t = np.random.default_rng(100 + seed), 0.0
        for _ in range(10):
            t = run_trial(opt, plant, t, rng)
            if opt.incumbent() is not None:
                f, v = opt.held()
                assert float(plant.steady(f, v).thrust_n) >= demand, (seed, f, v, opt.status())
        finals.append(score(plant, *opt.held(), demand) / best)
        assert opt.changes == 0, seed  # (held points re-measured 10 times: no false alarm)
    assert min(finals) >= 0.95, finals
