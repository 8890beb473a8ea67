"""The thrust-per-watt optimiser and its drive loop, on plants it does not know (no ROS)."""

from __future__ import annotations

import itertools
import math
import threading
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.bench import evaluation
from piezofin_ros.bench.evaluation import score, true_optimum
from piezofin_ros.bench.plants import Plant, read
from piezofin_ros.control.driveloop import DriveLoop
from piezofin_ros.control.evidence import remembered
from piezofin_ros.control.optimise import Correction, Observation, OperatingBox, Optimiser, Tuning
from piezofin_ros.control.proposal import calibration_point, f_res, is_quiet
from piezofin_ros.estimation.estimator import Estimate
from piezofin_ros.physics.effects import Leakage
from piezofin_ros.physics.fin import Fin, load_fin

from .. import builders

LIMITS = OperatingBox(1.0, 20.0, 50.0, 800.0)


def campaign(
    opt: Optimiser, plant: Plant, n: int, seed: int = 0, t0: float = 0.0
) -> tuple[list[float], float]:
    fractions, t = evaluation.campaign(opt, plant, n, np.random.default_rng(seed), t0)
    for o in opt.observations:
        assert LIMITS.frequency_min_hz <= o.frequency_hz <= LIMITS.frequency_max_hz
        assert LIMITS.voltage_pp_min <= o.voltage_pp <= LIMITS.voltage_pp_max
    return fractions, t


@pytest.mark.fast_cases("None")
@pytest.mark.parametrize("demand", [4e-3, None])
def test_converges_on_a_plant_with_shifted_resonance(m8528: Fin, demand: float | None) -> None:
    """Resonance 40 % lower at 800 Vpp (softening) and 10 % off overall, plus dielectric loss."""
    plant = Plant(m8528, softening=0.4, resonance_scale=0.9, loss_tan_delta=0.1)
    _, _, best = true_optimum(plant, LIMITS, demand)
    model = Optimiser(m8528, LIMITS, demand_n=demand).choice
    assert score(plant, model.frequency_hz, model.voltage_pp, demand) / best < 0.9  # the model alone is off
    fractions, _ = campaign(Optimiser(m8528, LIMITS, demand_n=demand), plant, 10)
    # 98 % of the optimum from the 8th trial on; with a demand 96 % (measured 0.967): the margin that
    # makes the demand hold in truth (2 sigma of a trial's noise and of the fitted model, 1 sigma for
    # the trial that confirms a point: about 2 % of thrust) costs about as much power (a score of 0
    # would mean the demand was missed in truth)
    assert min(fractions[7:]) >= (0.98 if demand is None else 0.96), fractions


@pytest.mark.slow
def test_reconverges_after_a_step_drift(m8528: Fin) -> None:
    plant = Plant(
        m8528, softening=0.2, loss_tan_delta=0.1, resonance_scale=lambda t: 1.0 if t < 60.0 else 0.85
    )
    opt = Optimiser(m8528, LIMITS, demand_n=4e-3)
    before, t = campaign(opt, plant, 9)  # 54 s, before the step
    assert before[-1] >= 0.96  # (the demand's margin: see above; measured 0.962)
    after, _ = campaign(opt, plant, 12, seed=1, t0=t)
    assert opt.changes >= 1  # the step was noticed
    # (the point held before the step misses the demand until the step is noticed; a new point counts
    # once a second trial confirms it)
    assert min(after[7:]) >= 0.95, after


def test_unusable_observations_are_ignored(m8528: Fin) -> None:
    opt = Optimiser(m8528, LIMITS)
    for bad in (
        (math.nan, 5.0, 800.0, 1e-3, 1e-3),
        (1.0, 5.0, 800.0, -1e-3, 1e-3),
        (1.0, 5.0, 800.0, 1e-3, math.inf),
    ):
        assert not opt.observe(*bad)
    assert opt.observations == []


def test_unreachable_demand_gives_the_most_thrust_and_says_so(m8528: Fin) -> None:
    opt = Optimiser(m8528, LIMITS, demand_n=1.0)  # 1 N: far beyond this fin
    assert not opt.choice.feasible
    assert opt.choice.voltage_pp == LIMITS.voltage_pp_max
    assert opt.status()["feasible"] is False


def estimate(t: float, f: float, v: float, thrust: float, power: float, final: float = 0.0) -> Estimate:
    """A running window (2 s) ending at ``t``."""
    return builders.estimate(
        t_start=t - 2.0, t_end=t, frequency_hz=f, voltage_pp=v, thrust_n=thrust, power_w=power, final=final
    )


numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(min_value=-1.0, max_value=1.0),
    st.floats(min_value=0.0, max_value=1e-2),
)


@settings(max_examples=150, deadline=None)
@given(
    st.lists(
        st.tuples(numbers, numbers, numbers, numbers, st.sampled_from([0.0, 1.0])), min_size=1, max_size=12
    )
)
def test_loop_never_commands_beyond_the_limits(
    estimates: list[tuple[float, float, float, float, float]],
) -> None:
    """Random estimates, NaN, infinities and negative values included: every command stays inside."""
    fin = load_fin("M8528-P1")
    limits = OperatingBox(1.0, 20.0, 50.0, 600.0)
    loop = DriveLoop(Optimiser(fin, limits), slew_vpp_per_s=400.0)
    t, v_prev = 0.0, 0.0
    for f, v, thrust, power, final in estimates:
        for _ in range(5):
            t += 0.1
            cf, cv, on = loop.tick(t)
            assert limits.frequency_min_hz <= cf <= limits.frequency_max_hz
            assert 0.0 <= cv <= limits.voltage_pp_max
            assert abs(cv - v_prev) <= 400.0 * 0.1 + 1e-9  # slew-limited
            assert on == (1.0 if cv > 0 else 0.0)
            v_prev = cv
        loop.add_estimate(t, estimate(t, f, v, thrust, power, final))


def test_loop_holds_then_ramps_down_when_estimates_stop(m8528: Fin) -> None:
    loop = DriveLoop(Optimiser(m8528, LIMITS, demand_n=4e-3), estimate_timeout_s=5.0, slew_vpp_per_s=400.0)
    t = 0.0
    for _ in range(40):  # 4 s: ramp up to the first point
        t += 0.1
        loop.tick(t)
    v_point = loop.command_v
    assert v_point > 0
    for _ in range(100):  # no estimate: after 5 s hold, after 10 s ramp down
        t += 0.1
        _, v, _ = loop.tick(t)
    assert loop.state in ("ramping down", "stopped")
    assert any("holding" in e for e in loop.events) and any("ramping" in e for e in loop.events)
    for _ in range(int(v_point / 40) + 5):
        t += 0.1
        _, v, on = loop.tick(t)
    assert v == 0.0 and on == 0.0 and loop.state == "stopped"
    loop.add_estimate(t, estimate(t, 5.0, 0.0, 1e-3, 1e-3))
    assert loop.state == "driving"  # estimates back: resumes


def test_stopped_for_want_of_estimates_the_loop_drives_again_with_a_back_off(m8528: Fin) -> None:
    """A rig whose watchdog tripped (a stalled heartbeat) gives no estimate until an off re-arms it:
    the loop's off commands while stopped do, and after ``retry_s`` it drives again (said), then waits
    twice as long; an estimate resets the back-off, and a finished run (``halted``) never retries."""
    loop = DriveLoop(Optimiser(m8528, LIMITS), estimate_timeout_s=5.0, slew_vpp_per_s=400.0, retry_s=20.0)
    t, log = 0.0, []
    for _ in range(2000):  # 200 s without a single estimate
        t += 0.1
        _, v, on = loop.tick(t)
        log.append((t, v, on, loop.state))
    on_again = [b for (_, va, *_r), (b, vb, *_s) in itertools.pairwise(log) if va == 0.0 and vb > 0]
    retries = [e for e in loop.events if "driving" in e and "again" in e]
    assert len(on_again) == len(retries) + 1 >= 4, (on_again, loop.events)  # the first start, then retries
    gaps = np.diff(on_again[1:])
    assert all(g2 > 1.5 * g1 for g1, g2 in itertools.pairwise(gaps)), gaps  # backing off
    assert all(on == 0.0 for _, v, on, state in log if state == "stopped")  # stopped: off commands
    loop.add_estimate(t, estimate(t, 5.0, 0.0, 1e-3, 1e-3))
    assert loop._retries == 0 and loop.state == "driving"
    loop.halted, loop.state = True, "ramping down"
    for _ in range(3000):
        t += 0.1
        _, v, on = loop.tick(t)
    assert loop.state == "stopped" and v == 0.0 and "again" not in loop.events[-1]


@pytest.mark.exclusive  # (a wall-clock bound on the heartbeat: phase 2, no CPU-bound test beside it)
def test_a_flood_of_demands_is_one_fit_at_a_time_and_the_last_one_wins(m8528: Fin) -> None:
    """1000 demands as fast as an attacker publishes them: the fit's thread sees a handful, the
    heartbeat never waits, and the loop ends on the last demand."""
    loop = DriveLoop(Optimiser(m8528, LIMITS), slew_vpp_per_s=4000.0, background=True)
    calls = []
    set_demand = loop.optimiser.set_demand
    loop.optimiser.set_demand = lambda d: (calls.append(d), set_demand(d))[1]  # type: ignore[method-assign]
    t, longest = 0.0, 0.0
    for k in range(1000):
        loop.set_demand(1e-3 if k % 2 else 5e-3)
        t0 = time.perf_counter()
        loop.tick(t := t + 0.01)
        longest = max(longest, time.perf_counter() - t0)
    loop.set_demand(3e-3)
    deadline = time.monotonic() + 60.0
    while loop.status()["demand_n"] != 3e-3 and time.monotonic() < deadline:
        time.sleep(0.02)
        loop.tick(t := t + 0.02)
    assert loop.status()["demand_n"] == 3e-3
    assert len(calls) <= 12, len(calls)  # at most one a second of the loop's 10 s, the latest
    assert longest < 0.05, longest  # the heartbeat never waited for a fit


def test_background_fits_and_demands_never_run_side_by_side(m8528: Fin, monkeypatch: Any) -> None:
    """The node fits in a worker thread while its executor delivers demands: every change to the
    optimiser runs in that one thread, in order, and a trial that agrees while a fit runs waits and
    is learnt before any demand (a speed loop's demand, which changes all the time, kept the fits
    busy and no trial was ever learnt: issue 27).  (A demand set from the executor's thread once
    refitted beside a running fit.)"""
    threads: list[str] = []
    overlaps: list[str] = []
    running = threading.Lock()
    update = Optimiser._update
    # the fit's thread holds its first fit until the test has sent its windows and its demand: with a
    # 50 ms sleep instead, a loaded machine (-n 2) once let the fit end between two windows
    sent = threading.Event()
    mine: list[Optimiser] = []  # (another test's worker, still fitting, runs this patched class too)

    def slow_update(self: Optimiser, learn: bool = True) -> None:
        if all(self is not m for m in mine):
            return update(self, learn)
        threads.append(threading.current_thread().name)
        if not running.acquire(blocking=False):
            overlaps.append(threads[-1])
            return update(self, learn)
        try:
            if threads[-1].startswith("optimiser"):
                sent.wait(30.0)  # (the window a second thread would need: held open)
            update(self, learn)
        finally:
            running.release()

    monkeypatch.setattr(Optimiser, "_update", slow_update)
    mine.append(Optimiser(m8528, LIMITS))
    loop = DriveLoop(mine[0], slew_vpp_per_s=4000.0, background=True)
    t = 0.0
    for _ in range(5):  # at the first point, settled
        t += 0.1
        loop.tick(t)
    assert loop.target is not None
    f, v = loop.target
    for k in range(6):  # windows that agree: a trial, then two more while its fit runs (the last waits)
        loop.add_estimate(t, estimate(t + 2.0 * k + 2.0, f, v, 1e-3, 1e-2))
    loop.set_demand(4e-3)  # from this (the executor's) thread, while the fit runs
    assert not overlaps  # (no fit here: the demand waits for the fit's thread)
    sent.set()
    deadline = time.monotonic() + 60.0
    while loop.status()["demand_n"] is None and time.monotonic() < deadline:  # the heartbeat goes on
        time.sleep(0.02)
        t += 0.02
        loop.tick(t)
    assert loop.status()["demand_n"] == 4e-3
    # the first trial, the last of the two that came during its fit (the other replaced), then the demand
    assert (loop.trials, loop.skipped, len(loop.optimiser.observations)) == (2, 1, 2)
    assert not overlaps
    assert len(threads) == 3 and all(name.startswith("optimiser") for name in threads), threads


def test_a_fit_slower_than_a_trial_does_not_hold_the_drive_at_the_point_it_learnt(
    m8528: Fin, monkeypatch: Any
) -> None:
    """A fit that takes longer than a trial (fin time at x10 on a loaded machine): each trial that
    agreed while it ran waited and was learnt next, and the loop took that trial before it moved to
    the point the finished fit proposed, so it never moved while trials kept coming.  A live fish
    learnt 4 to 7 trials at its quiet identification point, and the CI run of stop 33 asserted on a
    fit that had seen one other point.  Now it moves as soon as a fit ends: at most the trial and
    the one that waited are learnt at a point."""
    update = Optimiser._update

    def slow_update(self: Optimiser, learn: bool = True) -> None:
        time.sleep(0.3)  # (longer than the trial below: two windows of 2 s fin time at 0.01 s each)
        update(self, learn)

    monkeypatch.setattr(Optimiser, "_update", slow_update)
    plant = Plant(m8528, loss_tan_delta=0.08)
    loop = DriveLoop(Optimiser(m8528, LIMITS, demand_n=3e-3), slew_vpp_per_s=4000.0, background=True)
    rng = np.random.default_rng(1)
    t, last_window = 0.0, 0.0
    deadline = time.monotonic() + 60.0
    while loop.trials < 5 and time.monotonic() < deadline:
        time.sleep(0.001)
        t += 0.1
        f, v, _ = loop.tick(t)
        if loop._t_settled_from is not None and v > 0 and t - last_window >= 1.0:
            last_window = t
            thrust, power = plant.measure(f, v, t, rng)
            loop.add_estimate(t, estimate(t, f, v, thrust, power))
    assert loop.trials >= 5
    points = [(o.frequency_hz, o.voltage_pp) for o in loop.optimiser.observations]
    assert max(points.count(p) for p in points) <= 2, points
    assert len(set(points)) >= 3, points


@pytest.mark.slow
def test_trials_are_known_by_the_point_commanded_not_the_amplitude_measured(m8528: Fin) -> None:
    """The estimator measures the drive's amplitude with its monitor's noise and gain (here 0.3 % off,
    a different draw each window): the optimiser still records each trial at the point the loop
    commanded, so that the trials of a held point add up and ``held`` commands that point again."""
    plant = Plant(m8528, softening=0.2, loss_tan_delta=0.05)
    loop = DriveLoop(Optimiser(m8528, LIMITS, demand_n=4e-3), slew_vpp_per_s=4000.0)
    rng = np.random.default_rng(5)
    t, commanded = 0.0, set()
    for _ in range(60):
        t += 1.0
        f, v, _ = loop.tick(t)
        if loop.target is not None and loop._t_settled_from is not None and v > 0:
            commanded.add(loop.target)
            thrust, power = plant.measure(f, v, t, rng)
            monitor = v * (1.0 + 0.003 * rng.standard_normal())
            loop.add_estimate(t, estimate(t, f, monitor, thrust, power))
    points = {(o.frequency_hz, o.voltage_pp) for o in loop.optimiser.observations}
    assert points <= commanded
    assert len(points) < len(loop.optimiser.observations)  # points measured again
    assert loop.optimiser.incumbent() is not None  # their trials add up: a point counts


def test_a_diagnosed_model_is_the_optimisers_starting_map(m8528: Fin) -> None:
    """With the fin's diagnosed effects (the softening and loss the plant has), the first choice is
    already near the plant's optimum; an empty augmented model is the paper's map."""
    from piezofin_ros.physics.model import Model

    plant = Plant(m8528, softening=0.4, loss_tan_delta=0.1)
    empty = Optimiser(m8528, LIMITS, model=Model.of(m8528)).choice
    nominal = Optimiser(m8528, LIMITS).choice
    assert empty is not None and nominal is not None
    assert empty.frequency_hz == pytest.approx(nominal.frequency_hz, rel=1e-3)
    diagnosed = Model.of(m8528, {"electroelastic_softening": [0.4], "dielectric_loss": [0.1]})
    first = Optimiser(m8528, LIMITS, model=diagnosed).choice
    assert first is not None
    _, _, best = true_optimum(plant, LIMITS, None)
    assert score(plant, first.frequency_hz, first.voltage_pp, None) / best > 0.97
    assert score(plant, nominal.frequency_hz, nominal.voltage_pp, None) / best < 0.95  # what it saves


@pytest.mark.fast_cases("supply-told")
@pytest.mark.parametrize(
    ("watt", "told", "true"),
    [
        ("supply", "paper-bench", "paper-bench"),
        ("supply_measured", "paper-bench", "fish-switching"),
        ("supply_measured", "fish-switching", "rails-300"),
    ],
    ids=["supply-told", "measured-fish-unknown", "measured-rails-unknown"],
)
@pytest.mark.parametrize("demand", [None, 4e-3])
def test_converges_in_the_watt_it_is_told(m8528: Fin, watt: str, told: str, true: str, demand) -> None:
    """Thrust per supply watt: the amplifier the optimiser is told (``supply``: the estimator's model
    of it), or the supply's meter reading of an amplifier it was not told (``supply_measured``).  The
    optimum in truth (the plant's own amplifier) is reached as in the fin's watt, the demand met."""
    from piezofin_ros.physics.amplifier import LinearAmplifier, load_amplifier

    amps = {"rails-300": LinearAmplifier(rail_v=300.0, quiescent_w=0.05)}
    amp = amps.get(true) or load_amplifier(true)
    plant = Plant(m8528, softening=0.4, resonance_scale=0.9, loss_tan_delta=0.1, amplifier=amp)
    opt = Optimiser(m8528, LIMITS, demand_n=demand, watt=watt, amplifier=load_amplifier(told))
    f_fin = true_optimum(plant, LIMITS, demand)[0]
    f_watt = true_optimum(plant, LIMITS, demand, watt=watt)[0]
    fractions, _ = campaign(opt, plant, 10)
    assert min(fractions[7:]) >= (0.98 if demand is None else 0.96), fractions  # > 0: the demand is met
    if demand is None:
        assert f_watt > 1.5 * f_fin  # (the watt moves the optimum: this is not the fin-watt test again)
    assert opt.status()["watt"] == watt


def test_the_proposal_says_which_rule_chose_each_point(m8528: Fin) -> None:
    """Issue 29's house: ``_update`` set the next point six times and the last write won.  The rules
    are now one ordered list, and each proposal names the rule that chose it: the quiet
    identification trial first, then the map (its optimum, a held incumbent, a point measured
    before), a confirming trial when a point's one trial beat the incumbent, and on a fish a
    calibrating trial when its calibration keeps every trial from counting."""
    from piezofin_ros.control.optimise import Mode

    plant = Plant(m8528.replace(f_sc=0.93 * m8528.f_sc))
    opt = Optimiser(m8528, LIMITS)
    assert [name for name, _ in Optimiser.RULES] == ["identify", "confirm", "calibrate", "map"]
    assert opt.rule == "identify" and opt.status()["optimiser_rule"] == "identify"
    seen = []
    rng = np.random.default_rng(3)
    for _ in range(8):
        evaluation.campaign(opt, plant, 1, rng, 60.0 * len(opt.observations))
        seen.append(opt.rule)
        assert opt.mode in (Mode.MODEL, Mode.SEARCH) and opt.status()["optimiser_mode"] in ("model", "search")
    assert seen[0] != "identify" and "map" in seen, seen  # the quiet trial once, then the map's points


@pytest.mark.parametrize("effect", ["amplifier_limit", "amplifier_sag"])
def test_the_self_sensed_thrust_is_taken_at_the_voltage_the_fin_got(m8528: Fin, effect: str) -> None:
    """An amplifier that clips or sags gives the fin less than commanded.  The optimiser re-estimates
    each trial's self-sensed thrust from the drive's admittance: taken at the commanded voltage it
    read the motional current (V_cmd / V_drive) times too strong, and the thrust that squared (+227 %
    on M8514-P1 with a current limit in ``bench_unseen``); at the monitor's voltage it is the truth."""
    from piezofin_ros.bench.plants import read
    from piezofin_ros.physics.effects import make

    plant = Plant(m8528, effects=(make(effect, [4.0]),))  # (1/mA: 0.25 mA, below the 0.39 mA at 8 Hz)
    f, v = 8.0, 800.0
    r = read(plant, f, v, 0.0, np.random.default_rng(1), "self")
    assert r.voltage_pp < 0.9 * v  # (the amplifier gives less than commanded)
    truth = float(plant.steady(f, v).thrust_n)
    opt = Optimiser(m8528, LIMITS, source="self", identify=False)
    assert opt.observe(6.0, f, v, r.thrust_n, r.power_w, r.admittance, math.nan, r.voltage_pp)
    o = opt.observations[-1]
    assert (o.voltage_pp, o.drive_vpp) == (v, r.voltage_pp)  # known by the point commanded

    estimated = float(opt.problem.thrust_estimates(Correction(), [o])[0])  # (the paper's calibration)
    assert estimated == pytest.approx(truth, rel=0.02)
    assert r.thrust_n == pytest.approx(truth, rel=0.02)  # (as the estimator read it)


@pytest.mark.parametrize("quiescent_w", [0.0, 0.1])
def test_a_point_is_confirmed_whatever_amplifier_the_supply_meter_reads(quiescent_w: float) -> None:
    """In a measured supply's watts the map's power comes through the amplifier it is told (the
    paper's bench) and the trials' through the one the meter reads.  Whether a point is worth a
    confirming trial is judged on the map at both points: judged as a measured objective against the
    map's choice, a switching drive's 0.1 W quiescent draw (7 times the draw the map expected) made
    every point look 7 times worse than the map expected, no point was ever confirmed, and the
    controller held the map's unmeasured choice, which missed the demand in truth (``bench_unseen
    --watt supply_measured``, M8507-P1 with a current limit: 0.987 of the demand)."""
    from piezofin_ros.physics.amplifier import SwitchingAmplifier, load_amplifier

    fin = load_fin("M8507-P1")
    amp = SwitchingAmplifier(efficiency=0.77, recovered=0.69, quiescent_w=quiescent_w)
    plant = Plant(fin, softening=0.03, loss_tan_delta=0.09, amplifier=amp)
    demand = 0.3 * float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    told = load_amplifier("paper-bench")
    opt = Optimiser(fin, LIMITS, demand_n=demand, source="vibrometer", watt="supply_measured", amplifier=told)
    rng, t, rules = np.random.default_rng(1), 0.0, []
    for _ in range(8):
        t = evaluation.run_trial(opt, plant, t, rng)
        rules.append(opt.rule)
    assert "confirm" in rules and opt.incumbent() is not None, (rules, opt.status())
    f, v = opt.held()
    assert float(plant.steady(f, v).thrust_n) >= demand  # (a measured point, twice)


@pytest.mark.parametrize("frequency_hz", [5.0, 8.0, 9.9, 12.0])
def test_a_self_sensed_thrusts_noise_is_what_its_admittance_and_power_give(
    m8528: Fin, frequency_hz: float
) -> None:
    """The noise the optimiser gives a self-sensed thrust is the scatter of 600 trials' estimates,
    within -5/+25 % (the estimate's own floor adds a little), below, at and above the resonance.
    The admittance's conductance is the power's (0.5 %), not the susceptance's 0.1 %: with 0.1 % on
    both the noise at the resonance was 0.96 % where the trials scatter 1.21 %, and a held point's
    repeats raised false "the fin changed" alarms that wiped its trials."""
    plant = Plant(m8528, loss_tan_delta=0.05)
    problem = Optimiser(m8528, LIMITS, source="self").problem
    plant_own = Correction(loss_tan_delta=0.05)  # (the plant's own: the scatter is the noise alone)
    rng = np.random.default_rng(0)
    trials = []
    for _ in range(600):
        r = read(plant, frequency_hz, 600.0, 0.0, rng, "self", m8528)
        trials.append(
            Observation(
                0.0, frequency_hz, 600.0, r.thrust_n, r.power_w, "self", r.admittance, math.nan, r.voltage_pp
            )
        )
    estimates = problem.thrust_estimates(plant_own, trials)
    predicted = float(np.mean(problem.thrust_noise(plant_own, trials, estimates)))
    scatter = float(np.std(np.log(estimates)))
    assert 0.95 <= predicted / scatter <= 1.25, (predicted, scatter)


def test_a_self_sensed_thrust_takes_the_added_mass_at_the_motions_kc() -> None:
    """On the paper's twin (its added mass grows with KC), the optimiser's self-sensed thrust from an
    exact admittance is the twin's thrust, from a quiet 2 Hz, 400 Vpp to 800 Vpp at the resonance.
    With c_m taken at KC = 0, as it was, it read 36-68 % low (on the KC^2 twin 6-50 %, and the fish
    on M8507-P1 swam 11 % fast)."""
    from piezofin_ros.physics.model import load_model

    twin = load_model("paper-twin-M8507-P1")
    opt = Optimiser(twin.fin, LIMITS, source="self", model=twin)
    f, v = np.array([2.0, 2.6, 4.0, 6.0]), np.array([400.0, 800.0, 800.0, 800.0])
    p = twin.predict(f, v)
    obs = [
        Observation(0.0, a, b, math.nan, w, "self", complex(y))
        for a, b, w, y in zip(f, v, p.power_w, p.admittance, strict=True)
    ]
    estimates = opt.problem.thrust_estimates(opt.correction, obs)
    assert np.allclose(estimates, p.thrust_n, rtol=0.01), estimates / p.thrust_n


def test_a_fish_tells_a_leak_from_the_dielectric_loss_and_holds_its_demand(m8528: Fin) -> None:
    """A fin whose drive leaks (0.08 uS beside the piezo, twice its dielectric loss's conductance):
    from the drive alone, one frequency's admittance cannot tell the leak from the loss, and the
    controller held the map's 9.87 Hz, 800 Vpp for every trial with its calibration bound at 115 %,
    nothing counting.  The leak is in the correction, and a calibrating trial elsewhere separates the
    two: within 10 trials it holds a point that meets the demand in truth, its self-sensed thrust
    within 5 % of the truth."""
    demand = 0.3 * float(np.max(Plant(m8528).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    plant = Plant(m8528, loss_tan_delta=0.03, effects=(Leakage(0.08),))
    opt = Optimiser(m8528, LIMITS, demand_n=demand, source="self")
    rng, t, rules = np.random.default_rng(3), 0.0, []
    for _ in range(10):
        t = evaluation.run_trial(opt, plant, t, rng)
        rules.append(opt.rule)
    assert "calibrate" in rules, rules
    assert opt.correction.leakage_us == pytest.approx(0.08, rel=0.2)
    held = opt.status()["held"]
    assert held is not None, rules
    truth = float(plant.steady(held["frequency_hz"], held["voltage_pp"]).thrust_n)
    assert truth >= demand
    assert held["thrust_n"] == pytest.approx(truth, rel=0.05)
    assert opt.self_sensing_bound < 0.1


def test_a_fish_without_a_margin_takes_no_calibrating_trial(m8528: Fin) -> None:
    """A speed loop's fish asks for its thrust with no margin (``demand_margin_z: 0``): the
    calibration then keeps no trial from counting, and a calibrating trial (800 Vpp far from the
    demand) would only move the fish's speed, as it moved M8514-P1's 5 % in ``bench_fish``.  Where
    the leak's fish of the test above takes one (its second trial, the map's choice measured, a
    bound of 115 %), the same optimiser with no margin does not."""
    demand = 0.3 * float(np.max(Plant(m8528).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    plant = Plant(m8528, loss_tan_delta=0.03, effects=(Leakage(0.08),))
    opt = Optimiser(m8528, LIMITS, demand_n=demand, source="self")
    rng, t = np.random.default_rng(3), 0.0
    for _ in range(2):
        t = evaluation.run_trial(opt, plant, t, rng)
    assert opt.rule == "calibrate" and opt.self_sensing_bound > 1.0
    assert calibration_point(opt, opt.incumbent()) is not None
    opt.demand_margin_z = 0.0
    assert calibration_point(opt, opt.incumbent()) is None


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_a_fish_calibrates_from_its_first_trials_not_one_frontier_step_at_a_time(seed: int) -> None:
    """``bench_unseen``'s worst fish under a demand (supply watts): M8514-P1 with a drag coefficient
    varying with KC and a switching amplifier nobody is told.  The calibration's bound after the
    first trials (136 %) put the map's choice at 800 Vpp; the calibrating trial waited for the
    choice to have been measured, which it never was as the bound fell and the choice walked down
    the frontier one trial at a time: 0.745 of the optimum after 8 trials.  Calibrating while
    nothing counts, it holds at least 0.95 from the 6th trial, the demand met in truth."""
    from piezofin_ros.physics.amplifier import SwitchingAmplifier
    from piezofin_ros.physics.effects import make

    fin = load_fin("M8514-P1")
    demand = 0.3 * float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    plant = Plant(
        fin,
        softening=0.0112,
        loss_tan_delta=0.030,
        effects=(make("drag_kc", [0.0519]),),
        amplifier=SwitchingAmplifier(efficiency=0.632, recovered=0.355, quiescent_w=0.0864),
    )
    _, _, best = true_optimum(plant, LIMITS, demand, watt="supply")
    opt = Optimiser(fin, LIMITS, demand_n=demand, source="self", watt="supply")
    rng, t, rules, held = np.random.default_rng(seed), 0.0, [], []
    for _ in range(8):
        t = evaluation.run_trial(opt, plant, t, rng)
        rules.append(opt.rule)
        held.append(opt.held())
    assert "calibrate" in rules[:3], rules
    for f, v in held[5:]:  # trials 6 to 8
        assert score(plant, f, v, demand, watt="supply") / best >= 0.95, (rules, held)
        assert float(plant.steady(f, v).thrust_n) >= demand


@pytest.mark.slow
def test_a_fish_whose_model_misfits_counts_the_misfit_in_its_bound() -> None:
    """``bench_unseen``'s one demand missed in truth (stop 36, supply watts): M8514-P1 whose coupling
    grows as the field to the power 2.27, where the correction's law is linear.  The fit fell into a
    basin where a strong coupling, a heavy added mass and extra drag compensate (reduced chi-square
    8 against the noise alone); the parametric bound at the held point, 254 Vpp, was 2.1 % while the
    self-sensed thrust read 5.2 % high, and from the 9th trial it held 0.9994 of the demand in truth.
    The bound now counts the misfit (the model error times the square root of the chi-square beyond
    4): every point it holds once one counts meets the demand in truth, and the bound covers the
    held estimate's true error."""
    from piezofin_ros.physics.amplifier import LinearAmplifier
    from piezofin_ros.physics.effects import make

    fin = load_fin("M8514-P1")
    demand = 0.3 * float(np.max(Plant(fin).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    plant = Plant(
        fin,
        softening=0.2279,
        loss_tan_delta=0.01076,
        effects=(make("field_coupling", [0.3679, 2.273]),),
        amplifier=LinearAmplifier(rail_v=375.8, quiescent_w=0.0313),
    )
    opt = Optimiser(fin, LIMITS, demand_n=demand, source="self", watt="supply")
    rng, t, held = np.random.default_rng(3440327350), 0.0, []
    for _ in range(12):
        t = evaluation.run_trial(opt, plant, t, rng)
        if opt.incumbent() is not None:
            f, v = opt.incumbent()
            held.append((f, v, float(plant.steady(f, v).thrust_n) / demand))
    assert held and all(short >= 1.0 for *_, short in held), held
    status = opt.status()
    truth = float(plant.steady(status["held"]["frequency_hz"], status["held"]["voltage_pp"]).thrust_n)
    assert abs(status["held"]["thrust_n"] / truth - 1.0) <= status["self_sensing_bound"], status


@pytest.mark.slow
def test_a_fish_whose_model_cannot_fit_takes_at_most_three_calibrating_trials(m8528: Fin) -> None:
    """M8528-P1 with a drag coefficient growing strongly with KC (c_d ~ KC^-0.49): the correction
    cannot fit it, each calibrating trial's predicted gain is an extrapolation, and without a cap
    seven of twelve trials calibrated while the self-sensed thrust at the held point ended 11 % off
    the truth.  At most three calibrating trials are in memory, and the held point meets the demand
    in truth with its self-sensed thrust within 8 % (5.5 % measured)."""
    from piezofin_ros.physics.effects import make

    demand = 0.3 * float(np.max(Plant(m8528).steady(np.linspace(1, 20, 400), 800.0).thrust_n))
    plant = Plant(m8528, softening=0.111, loss_tan_delta=0.0163, effects=(make("drag_kc", [0.486]),))
    opt = Optimiser(m8528, LIMITS, demand_n=demand, source="self")
    rng, t, rules = np.random.default_rng(2947486774), 0.0, []
    for _ in range(12):
        t = evaluation.run_trial(opt, plant, t, rng)
        rules.append(opt.rule)
    assert 1 <= rules.count("calibrate") <= Tuning.max_calibrating_trials, rules
    held = opt.status()["held"]
    assert held is not None, rules
    truth = float(plant.steady(held["frequency_hz"], held["voltage_pp"]).thrust_n)
    assert truth >= demand
    assert held["thrust_n"] == pytest.approx(truth, rel=0.08)


@pytest.mark.slow
@pytest.mark.parametrize("plant_kw", [{}, {"softening": 0.3, "loss_tan_delta": 0.08, "resonance_scale": 0.9}])
def test_a_swimming_fish_takes_no_trial_far_below_its_demand(m8528: Fin, plant_kw: dict[str, Any]) -> None:
    """Issue 39: the quiet identification trial (about 5 Hz, 400 Vpp, 0.3 mN) was taken again each time
    the earlier one aged out of the memory: every 20-22 trials the fish fell 60-80 % for 20-30 s.  Now
    only the first trial (from rest) and one asked for (``request_identification``) may give less than
    the demand by more than ``hold_margin``; the quiet trial stays in the fit."""
    plant = Plant(m8528, **plant_kw)
    demand = 4e-3
    opt = Optimiser(m8528, LIMITS, demand_n=demand, source="self", demand_margin_z=0.0, trial_overshoot=0.1)
    rng = np.random.default_rng(3)
    t, truths = 0.0, []
    for _ in range(70):  # 420 s of trials: beyond the 300 s memory
        f, v = opt.propose()
        truths.append(float(plant.steady(f, v, t).thrust_n))
        t = evaluation.run_trial(opt, plant, t, rng)
    quiet = [k for k, x in enumerate(truths) if x < 0.5 * demand]
    assert quiet == [0], [round(x * 1e3, 2) for x in truths]  # the one from rest
    assert any(is_quiet(opt, o) for o in opt.observations)  # still in the fit after 420 s
    # (the map's own trials aim at the demand: the fit's error, not the design, may miss it by a little)
    low = [x for x in truths[1:] if x < (1 - opt.tuning.hold_margin) * demand]
    assert len(low) <= 3, [round(x * 1e3, 2) for x in truths]
    opt.request_identification()
    opt.observe(t + 6, *opt.held(), demand, 1e-3)  # (a trial that was running when asked)
    f, _ = opt.propose()
    assert f <= 0.7 * f_res(opt)  # asked: the quiet trial next


def test_the_memory_keeps_the_newest_aged_trial_at_each_frequency_no_later_one_is_near(m8528: Fin) -> None:
    """The memory past ``memory_s``: the latest quiet trial, and up to ``memory_anchors`` anchors,
    the newest aged trial at each frequency more than ``anchor_spacing`` from every kept one's."""
    opt = Optimiser(m8528, LIMITS, demand_n=2e-3, source="self", tuning=Tuning(memory_anchors=2))
    r = f_res(opt)

    def trial(t: float, at: float) -> Observation:
        return Observation(t, at * r, 400.0 if at < 0.7 else 700.0, 1e-3, 0.01, source="self")

    aged = [trial(0, 0.5), trial(10, 1.0), trial(20, 1.8), trial(30, 1.55), trial(40, 1.2), trial(50, 1.02)]
    recent = [trial(400 + 10 * k, at) for k, at in enumerate([1.0, 1.01, 0.99])]
    opt.observations = aged + recent
    assert is_quiet(opt, aged[0]) and not any(is_quiet(opt, o) for o in aged[1:] + recent)
    kept = remembered(opt.observations, 450.0, opt.tuning, lambda o: is_quiet(opt, o))
    # (the quiet one; 1.02 is near 1.0; 1.2 and 1.55 the two anchors, the newest; 1.8 beyond the two)
    assert [o.t for o in kept] == [0, 30, 40, 400, 410, 420]
    none = Optimiser(m8528, LIMITS, demand_n=2e-3, source="self", tuning=Tuning(memory_anchors=0))
    none.observations = aged + recent
    assert [o.t for o in remembered(none.observations, 450.0, none.tuning, lambda o: is_quiet(none, o))] == [
        0,
        400,
        410,
        420,
    ]


@pytest.mark.slow
def test_a_fish_held_at_one_point_keeps_the_spread_that_calibrates_it() -> None:
    """Issue 39: M8507-P1's twin on a fish, its demand high for its first six trials (from rest, at
    3.1 Hz), then half that, held near 2.1 Hz.  As the first trials aged out of the 300 s memory the
    fit kept only trials within 10 % of one frequency: its calibration's bound grew 0.11 -> 0.51 and
    the self-sensed thrust read up to 11 % off the truth (in ``bench_fish.py``, seed 0, it crept 26-33 %
    high for 264 s).  The newest aged trial at each frequency no later one is near stays (up to
    ``Tuning.memory_anchors``): the bound stays within 0.13 and the estimate within 4 %."""
    from piezofin_ros.physics.model import load_model

    twin = load_model("paper-twin-M8507-P1")
    plant, demand = Plant(twin.fin, effects=tuple(twin.effects)), 0.35e-3
    opt = Optimiser(
        twin.fin, LIMITS, demand_n=demand, source="self", demand_margin_z=0.0, trial_overshoot=0.1, model=twin
    )
    rng, t, rows = np.random.default_rng(3), 0.0, []
    for k in range(80):  # 480 s of trials
        opt.set_demand(demand * (2.0 if k < 6 else 1.0))
        t = evaluation.run_trial(opt, plant, t, rng)
        o = opt.observations[-1]
        truth = float(plant.steady(o.frequency_hz, o.voltage_pp, t).thrust_n)
        rows.append((t, opt.thrust_as_fitted(o) / truth - 1, opt.self_sensing_bound))
    before = max(bound for t, _, bound in rows if 250 <= t <= 310)
    late = [(t, round(err, 3), round(bound, 3)) for t, err, bound in rows if t > 320]
    assert max(bound for *_, bound in late) <= 1.5 * before, (before, late)
    assert max(abs(err) for _, err, _ in late) <= 0.08, late
    assert len(opt.observations) > sum(o.t >= t - opt.tuning.memory_s for o in opt.observations) + 1


@pytest.mark.slow
def test_a_wrong_prior_that_fits_only_far_from_its_own_parameters_is_dropped_early() -> None:
    """The paper's twin given to a fish whose fin is the nominal M8528-P1, softer and dragging more
    (``bench_fish.py --strangers``'s stranger 1): the corrected twin fits its first trials within their
    noise, but only by moving its parameters 2-3 sigma from its own, where the fin file fits them near
    its own.  Its whole cost (misfit and prior) exceeds the fin file's by more than ``prior_drop_cost``
    within three trials, and it is dropped, said; by the misfit alone, at the fourth or fifth (on the
    live fish a trial at 9.2 Hz then read 2.8 times the truth through the twin: 20 s of its first
    minute lost, settled from rest in 66 s; now 46 s)."""
    from piezofin_ros.physics.effects import make
    from piezofin_ros.physics.model import load_model

    twin, fin = load_model("paper-twin-M8528-P1"), load_fin("M8528-P1")
    plant = Plant(fin, effects=(make("electroelastic_softening", [0.3]), make("drag_offset", [2.5])))

    def trials_to_drop(tuning: Tuning) -> int:
        opt = Optimiser(
            fin, LIMITS, demand_n=2.5e-3, source="self", model=twin, trial_overshoot=0.3, tuning=tuning
        )
        rng, t = np.random.default_rng(1), 0.0
        for n in range(1, 4):
            t = evaluation.run_trial(opt, plant, t, rng)
            if opt.model is None:
                assert opt.prior_dropped in opt.said and "only with its parameters" in opt.prior_dropped
                return n
        return 99  # (not within three)

    assert trials_to_drop(Tuning()) <= 3
    assert trials_to_drop(Tuning(prior_drop_cost=math.inf)) == 99  # (the misfit alone: at the 5th)


@pytest.mark.slow
def test_a_right_prior_is_kept() -> None:
    """The same optimiser on the fish whose fin is the twin it was given: six trials, the twin kept
    (its cost 0.0-1.0 in ``bench_fish``, where the fin file's is 3-14)."""
    from piezofin_ros.physics.model import load_model

    twin = load_model("paper-twin-M8528-P1")
    plant = Plant(twin.fin, effects=tuple(twin.effects))
    opt = Optimiser(twin.fin, LIMITS, demand_n=2.5e-3, source="self", model=twin, trial_overshoot=0.3)
    rng, t = np.random.default_rng(1), 0.0
    for _ in range(6):
        t = evaluation.run_trial(opt, plant, t, rng)
    assert opt.model is twin and not opt.prior_dropped
