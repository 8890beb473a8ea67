"""The fish stack's science in fish time (issue 27): the harness against closed forms, the drive
loop that lets a trial end before a speed loop's next demand, and the fish holding its set-point
on the optimising controller."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from piezofin_ros.bench.fishrun import MEASURED, STRATEGIES, FixedDrive, Trace, drive_for, swim_run
from piezofin_ros.bench.plants import Plant
from piezofin_ros.control.driveloop import DriveLoop
from piezofin_ros.control.optimise import Correction, OperatingBox, Optimiser, Tuning
from piezofin_ros.control.speedloop import DemandGate, SpeedLoopConfig
from piezofin_ros.errors import ControlError
from piezofin_ros.physics.amplifier import load_amplifier
from piezofin_ros.physics.fin import Fin, load_fin
from piezofin_ros.physics.model import load_model
from piezofin_ros.physics.swim import load_battery, load_body

from .test_optimise import LIMITS, estimate

COARSE = Tuning(n_grid=40)  # (a coarse map: fast)


@pytest.fixture(scope="module")
def twin() -> tuple[Plant, object]:
    model = load_model("paper-twin-M8528-P1")
    amp = load_amplifier("fish-switching")
    return Plant(model.fin, effects=model.effects, amplifier=amp), model


def _speed_trace(speed: np.ndarray, dt: float = 0.1) -> Trace:
    """A trace at a set-point of 1 m/s with ``speed`` sampled every ``dt`` (the rest NaN)."""
    n = speed.size
    nan = np.full(n, np.nan)
    return Trace(np.arange(n) * dt, np.ones(n), speed, *[nan] * 10)


def test_a_speed_is_held_from_when_it_arrives_if_every_minute_after_and_95_percent_of_the_time_are() -> None:
    """Issue 39's goal, held from a time: the speed within 5 % then, every minute's mean after within
    5 %, and 95 % of the time after within 5 %; settling (within 5 % from then on) besides.  An
    exponential approach (tau 5 s) enters the band at ``5 ln 20`` s."""
    t = np.arange(6000) * 0.1
    arrive = 5.0 * math.log(20.0)
    approach = 1.0 - np.exp(-t / 5.0)
    assert _speed_trace(approach).held_s(0.0, 600.0) == pytest.approx(arrive, abs=0.1)
    assert _speed_trace(approach).settling_s(0.0, 600.0) == pytest.approx(arrive, abs=0.1)
    # a dip to -7 % for 4 s at 300 s: its minute's mean -0.5 %, 99 % of the time within: held as before,
    # settled only after it
    dip = np.where((t >= 300.0) & (t < 304.0), 0.93, approach)
    assert _speed_trace(dip).held_s(0.0, 600.0) == pytest.approx(arrive, abs=0.1)
    assert _speed_trace(dip).settling_s(0.0, 600.0) == pytest.approx(304.0, abs=0.1)
    # -6 % from 200 to 400 s: minutes off, held only from 400 s (settling the same)
    slow = np.where((t >= 200.0) & (t < 400.0), 0.94, approach)
    assert _speed_trace(slow).held_s(0.0, 600.0) == pytest.approx(400.0, abs=0.1)
    # inside on average but 10 % of the time outside (a 10 s period, 1 s of it at -8 %): minutes within
    # 5 %, the share not: never held (settled only after the last dip, 9 s before the end)
    wobble = np.where((t > 30.0) & (t % 10.0 < 1.0), 0.92, 1.0)
    assert math.isinf(_speed_trace(wobble).held_s(0.0, 600.0))
    assert _speed_trace(wobble).settling_s(0.0, 600.0) == pytest.approx(591.0, abs=0.1)
    # never within 5 %, or within it only in the last minute (too short to judge a minute): never held
    assert math.isinf(_speed_trace(np.full(6000, 0.9)).held_s(0.0, 600.0))
    late = np.where(t < 560.0, 0.9, 1.0)
    assert math.isinf(_speed_trace(late).held_s(0.0, 600.0))
    assert _speed_trace(late).settling_s(0.0, 600.0) == pytest.approx(560.0, abs=0.1)
    # from a step at 100 s: times count from the step
    assert _speed_trace(np.where(t < 100, 0.5, approach)).held_s(100.0, 600.0) == pytest.approx(0.0)


def test_a_cut_is_a_second_or_more_under_90_percent_of_the_demand_once_swimming() -> None:
    """Issue 39's goal, measured: no trial while swimming gives less than 90 % of the demand.  A cut
    counts once the speed has first reached half its set-point, lasts a second or more, and is said
    by where it starts, how long it lasts and the least share of the demand in it; a demand not
    known (NaN: a driver's trace) is no cut."""
    t = np.arange(3000) * 0.1
    speed = np.minimum(t / 100.0, 1.0)  # (half the set-point at 50 s)
    demand = np.full(t.size, 2e-3)
    thrust = np.full(t.size, 2e-3)
    thrust[(t >= 10.0) & (t < 30.0)] = 0.5e-3  # before the fish swims: no cut
    thrust[(t >= 60.0) & (t < 68.0)] = 1.1e-3  # 0.55 for 8 s (the samples 60.0-67.9: 7.9 s)
    thrust[(t >= 70.0) & (t < 70.5)] = 0.2e-3  # half a second: no cut
    thrust[(t >= 100.0) & (t < 103.0)] = 1.81e-3  # 0.905 of it: no cut
    thrust[(t >= 200.0) & (t < 202.0)] = 1.78e-3  # 0.89 for 2 s
    nan = np.full(t.size, np.nan)
    trace = Trace(t, np.ones(t.size), speed, demand, thrust, *[nan] * 8)
    cuts = trace.cuts(0.0, 300.0)
    assert [(a, round(b, 1)) for a, b, _ in cuts] == [(60.0, 7.9), (200.0, 1.9)], cuts
    assert [c[2] for c in cuts] == pytest.approx([0.55, 0.89])
    # counted from a step (the speed already above half): the same cuts, from the step's time
    assert [round(a, 1) for a, _, _ in trace.cuts(55.0, 300.0)] == [5.0, 145.0]
    assert trace.cuts(0.0, 300.0, below=0.5) == []
    assert trace.cuts(0.0, 300.0, least_s=8.0) == []
    unknown = Trace(t, np.ones(t.size), speed, nan, thrust, *[nan] * 8)
    assert unknown.cuts(0.0, 300.0) == []
    assert Trace(t, np.ones(t.size), 0.4 * speed, demand, thrust, *[nan] * 8).cuts(0.0, 300.0) == []


def test_a_fixed_drive_swims_at_the_closed_form_speed_and_pays_its_joules_per_metre(twin) -> None:
    """The harness's body and battery against the closed forms: the steady speed where the drag
    meets the thrust at that speed (Eq. 19's U term), and the battery's energy per metre
    ``(supply + hotel) / U``; from rest it reaches 95 % in about three time constants."""
    plant, model = twin
    body, battery = load_body("mfc-fish"), load_battery("li-ion-2s-500mah")
    f, v = 5.4, 600.0
    trace = swim_run(plant, body, FixedDrive(f, v), [(0.0, 0.05)], 90.0, battery, speed_noise_m_s=0.0)
    p = model.predict(f, v)
    u = float(body.steady_speed(p.thrust_n, f, model.fin.L))
    supply = float(plant.amplifier.steady(p.voltage_pp_drive, p.current_rms, p.power_w))
    assert trace.speed_m_s[-1] == pytest.approx(u, rel=1e-3)
    assert trace.energy_per_m(60.0, 90.0) == pytest.approx((supply + battery.hotel_w) / u, rel=2e-3)
    tau = body.time_constant_s(float(p.thrust_n), f, model.fin.L)
    reached = trace.t[np.argmax(trace.speed_m_s >= 0.95 * u)]
    assert 1.5 * tau < reached < 4.0 * tau, (reached, tau)
    assert trace.soc[-1] < 1.0 and np.all(np.diff(trace.soc) <= 0)


def test_the_gate_sends_a_demand_that_moved_or_went_quiet() -> None:
    gate = DemandGate(0.03, 5.0)
    sent = [gate.due(t, d) for t, d in [(0, 1e-3), (1, 1.02e-3), (2, 1.04e-3), (3, 1.05e-3), (8, 1.05e-3)]]
    assert sent == [True, False, True, False, True]


def _settle_on_a_point(loop: DriveLoop, t: float) -> float:
    for _ in range(20):
        t += 0.1
        loop.tick(t)
    return t


def test_a_demand_waits_for_the_trial_it_would_cut_short(m8528: Fin) -> None:
    """A speed loop's demand moves all the time: a small change waits until the running trial has
    been learnt, a jump (a new set-point) or one that waited ``wait_s`` goes at once.  Taken
    at once, every demand moved the drive before its trial ended and the optimiser learnt nothing."""
    # (no quiet identification trial first: it ends at its first window, _ends_early)
    loop = DriveLoop(Optimiser(m8528, LIMITS, tuning=COARSE, identify=False), slew_vpp_per_s=4000.0)
    loop.set_demand(3e-3)  # the first: at once
    assert loop.optimiser.demand_n == 3e-3
    t = _settle_on_a_point(loop, 0.0)
    assert loop.target is not None
    f, v = loop.target
    loop.add_estimate(t, estimate(t + 5.0, f, v, 3.2e-3, 1e-2))  # half a trial
    loop.set_demand(3.2e-3)
    for _ in range(30):
        t += 0.1
        loop.tick(t)
    assert loop.optimiser.demand_n == 3e-3  # waits for the trial
    loop.add_estimate(t, estimate(t + 10.0, f, v, 3.2e-3, 1e-2))  # the trial agrees: learnt
    assert loop.trials == 1
    loop.tick(t := t + 0.1)
    assert loop.optimiser.demand_n == 3.2e-3  # taken between trials
    t = _settle_on_a_point(loop, t)
    f, v = loop.target
    loop.add_estimate(t, estimate(t + 5.0, f, v, 3.2e-3, 1e-2))
    loop.set_demand(5e-3)  # a jump: at once
    loop.tick(t := t + 1.1)
    assert loop.optimiser.demand_n == 5e-3
    t = _settle_on_a_point(loop, t)
    f, v = loop.target
    loop.add_estimate(t, estimate(t + 5.0, f, v, 5e-3, 1e-2))
    loop.set_demand(5.2e-3)
    for _ in range(int(loop.gate.wait_s / 0.1) + 20):  # no window comes: it waited long enough
        t += 0.1
        loop.tick(t)
    assert loop.optimiser.demand_n == 5.2e-3


def test_every_strategy_is_built_and_an_unknown_one_is_named(twin) -> None:
    plant, model = twin
    amp = plant.amplifier
    for name in STRATEGIES:
        drive = drive_for(name, model, plant, amp, OperatingBox(1.0, 30.0, 50.0, 800.0))
        drive.set_demand(3e-3)
        f, v = drive.tick(0.0)
        assert 1.0 <= f <= 30.0 and v == 0.0  # (every drive ramps up from 0 V)
    with pytest.raises(ControlError, match="one of ours"):
        drive_for("bang-bang", model, plant, amp)


@pytest.mark.slow
def test_the_fish_holds_its_set_point_on_the_optimising_controller_at_the_least_supply(twin) -> None:
    """The issue's goal on the paper's M8528-P1 twin: the optimising controller (drive only, supply
    watt) under the speed loop holds each set-point within 5 % in truth, settled within 30 s of a
    step (from rest, the controller's calibration comes first), at a supply power within 3 % of the
    least any point gives that speed."""
    from benchmarks.bench_fish import least_supply_w  # (the benchmark's bound)

    plant, model = twin
    body, battery = load_body("mfc-fish"), load_battery("li-ion-2s-500mah")
    from piezofin_ros.control.swimming import Fish

    fish = Fish(model, body, battery, plant.amplifier)
    steps = [(0.0, 0.048), (150.0, 0.062)]
    trace = swim_run(
        plant,
        body,
        drive_for("ours (supply watt)", model, plant, plant.amplifier),
        steps,
        300.0,
        battery,
        loop_config=SpeedLoopConfig(max_demand_n=0.008),
    )
    for k, (t0, u) in enumerate(steps):
        t1 = steps[k + 1][0] if k + 1 < len(steps) else 300.0
        mid = 0.5 * (t0 + t1)
        assert abs(trace.mean("speed_m_s", mid, t1) / u - 1.0) < 0.05
        supply = trace.mean("supply_w", mid, t1)
        assert supply <= 1.03 * least_supply_w(fish, u), (supply, least_supply_w(fish, u))
        # the self-sensed thrust as the optimiser's fit reads it (the estimator's own, through the
        # fin file's calibration, reads the twin 30-50 % low): on the thrust in truth (docs/fish.png)
        half = (trace.t >= mid) & (trace.t < t1) & np.isfinite(trace.thrust_fitted_n) & (trace.thrust_n > 0)
        off = np.median(np.abs(trace.thrust_fitted_n[half] / trace.thrust_n[half] - 1.0))
        assert off < 0.05, off
    # (from rest the controller first calibrates: its identification trial and its first map)
    assert trace.settling_s(*steps[1][:1], 300.0) <= 30.0, trace.settling_s(steps[1][0], 300.0)


@pytest.mark.parametrize(("given", "learnt"), [(1.0, False), (1.03, False), (0.25, True), (4.0, True)])
def test_a_trial_the_demand_cuts_short_is_learnt_only_where_it_misses_the_map(
    m8528: Fin, given: float, learnt: bool
) -> None:
    """The last window of a trial a demand jump cuts short: a gross miss (a quarter or four times the
    thrust the fitted map expects there) is learnt, or the fit proposes that point again (a stranger
    fish: 0.5 mN where 2 were asked, twice in 40 s); one the map expects is not (one window of an
    unfinished trial is noisier than a trial: learnt always, it put a twin's second step 6.5 % fast,
    M8507-P1 in ``bench_fish.py``, +3.2 % without)."""
    loop = DriveLoop(Optimiser(m8528, LIMITS, tuning=COARSE, identify=False), slew_vpp_per_s=4000.0)
    loop.set_demand(3e-3)
    t = 0.0
    for _ in range(3):  # three trials that agree with the fin: a fitted map
        t = _settle_on_a_point(loop, t)
        pred = Correction().predict(m8528, *loop.target)
        for _ in range(2):
            t += 5.0
            loop.add_estimate(t, estimate(t, *loop.target, float(pred.thrust_n), float(pred.power_w)))
        loop.tick(t := t + 0.1)
    before, trials = len(loop.optimiser.observations), loop.trials
    t = _settle_on_a_point(loop, t)
    assert loop.target is not None
    pred = Correction().predict(m8528, *loop.target)
    t += 5.0
    loop.add_estimate(t, estimate(t, *loop.target, given * float(pred.thrust_n), float(pred.power_w)))
    loop.set_demand(6e-3)  # a jump: the trial is cut
    loop.tick(t := t + 1.1)
    assert loop.optimiser.demand_n == 6e-3
    assert (loop.trials, len(loop.optimiser.observations)) == (
        (trials + 1, before + 1) if learnt else (trials, before)
    )


def _ticks(loop: DriveLoop, t: float, seconds: float) -> float:
    for _ in range(round(seconds / 0.1)):
        t += 0.1
        loop.tick(t)
    return t


@pytest.mark.parametrize(
    ("identify", "given", "overshoot", "ends"),
    [
        (False, 0.2, 0.1, True),  # a fifth of the demand on a fish: ended at its first window
        (False, 1.0, 0.1, False),  # the demand met: two windows that agree, as every trial
        # the quiet identification trial, low on purpose, under a demand: learnt from its first
        # window, on a fish or a rig (whoever asked the demand waits for it)
        (True, 1.0, 0.1, True),
        (True, 1.0, 0.0, True),
        (False, 0.2, 0.0, False),  # no overshoot limit (a rig, not a fish): its windows as always
    ],
)
def test_a_fish_trial_far_short_of_the_demand_ends_at_its_first_window(
    m8528: Fin, identify: bool, given: float, overshoot: float, ends: bool
) -> None:
    """A fish's speed follows each trial's thrust: a trial whose first window the fit reads more than
    ``hold_margin`` below the demand is learnt from that window and left (a stranger given a wrong
    prior spent 24 s below 90 % of the demand in one such trial, 15 s with this, ``--strangers``),
    and so is a quiet identification trial under a demand (a fish from rest swims 6 s sooner)."""
    opt = Optimiser(
        m8528, LIMITS, tuning=COARSE, identify=identify, demand_margin_z=0.0, trial_overshoot=overshoot
    )
    loop = DriveLoop(opt, slew_vpp_per_s=4000.0)
    loop.set_demand(3e-3)
    t = _settle_on_a_point(loop, 0.0)
    assert loop.target is not None
    pred = Correction().predict(m8528, *loop.target)
    trials = loop.trials
    t += 8.0  # (the estimator's settling and its first window)
    loop.add_estimate(t, estimate(t, *loop.target, given * float(pred.thrust_n), float(pred.power_w)))
    loop.tick(t + 0.1)
    assert (loop.trials == trials + 1) == ends, (loop.trials, loop.target, opt.status()["optimiser_rule"])


def test_the_loops_own_moves_are_not_taken_for_a_dead_estimator(m8528: Fin) -> None:
    """A set-point step makes the speed loop's demand jump again and again while the fish speeds up:
    each jump moved the drive before the estimator's first window at the last point (3 s settling,
    5 s window), and the watchdog, counting from the last estimate, held and then ramped the fish to
    0 V for 30 s.  Silence counts only at a point the drive has reached; the estimator here is alive
    and gives its window 8 s after each arrival."""
    loop = DriveLoop(Optimiser(m8528, LIMITS, tuning=COARSE, identify=False), slew_vpp_per_s=4000.0)
    loop.set_demand(3e-3)
    t, demand = _ticks(loop, 0.0, 2.0), 3e-3
    for _ in range(3):
        for wait in (2.0, 7.0):  # two jumps, each before the window at the point (8 s after arrival)
            t = _ticks(loop, t, wait)
            demand = 5e-3 if demand == 3e-3 else 3e-3
            loop.set_demand(demand)
            before = loop.target
            t = _ticks(loop, t, 1.1)
            assert loop.target != before
        t = _ticks(loop, t, 8.0)  # arrived, then the window
        assert loop.target is not None
        # (the fin's own thrust and watt there: a window is learnt, the trial it began cut or not)
        pred = Correction().predict(m8528, *loop.target)
        loop.add_estimate(t, estimate(t, *loop.target, float(pred.thrust_n), float(pred.power_w)))
    assert not [e for e in loop.events if "no estimate" in e], loop.events
    assert loop.state == "driving" and loop.command_v > 0


def test_moves_without_any_estimate_still_end_in_a_hold_then_a_ramp_down(m8528: Fin) -> None:
    """The other side of the same clock: an estimator that is dead while demands keep jumping (an
    attacker's flip every 2 s) would restart it for ever; after three timeouts with no estimate at
    all the loop holds its point whatever the demands, and ramps down two timeouts later."""
    loop = DriveLoop(Optimiser(m8528, LIMITS, tuning=COARSE), slew_vpp_per_s=4000.0, estimate_timeout_s=5.0)
    t, log = 0.0, []
    for k in range(300):  # 60 s, a demand flip every 2 s, no estimate
        if k % 10 == 0:
            loop.set_demand(5e-3 if k % 20 else 2e-3)
        t = _ticks(loop, t, 0.2)
        log.append((t, loop.state, loop.target, loop.command_v))
    held = [(t, target) for t, state, target, _ in log if state == "holding"]
    assert held and held[0][0] <= 3 * 5.0 + 0.3, loop.events
    assert len({target for _, target in held}) == 1  # held: the demands move it no more
    stopped = [t for t, state, _, v in log if state == "stopped" and v == 0.0]
    assert stopped and stopped[0] <= held[0][0] + 2 * 5.0 + 0.5 + 2.0, loop.events


@pytest.mark.parametrize("overshoot", [0.0, 0.1])
def test_no_trial_goes_to_a_point_measured_far_above_the_demand(m8528: Fin, overshoot: float) -> None:
    """A point whose one trial gave twice the demand at a low power is worth a confirming trial to a
    fin on a rig (the demand met at the least power); to a fish its thrust is speed: with
    ``overshoot`` 0.1 (``config/fish.yaml``'s ``trial_overshoot``) it is not driven again."""
    opt = Optimiser(m8528, LIMITS, demand_n=3e-3, identify=False, tuning=COARSE, trial_overshoot=overshoot)
    f, v = opt.propose()
    p = float(opt.correction.response(m8528, f, v).power_w)
    assert opt.observe(10.0, f, v, 6e-3, 0.5 * p)  # twice the demand, for half the map's power
    again = _close_point(opt.propose(), (f, v))
    assert (opt.rule == "confirm" and again) == (overshoot == 0.0), (opt.rule, opt.status())


@pytest.mark.parametrize(
    ("overshoot", "demand", "trimmed"),
    [
        (0.1, 2.5e-3, True),  # the demand fell 24 % below the incumbent's thrust: trimmed to it
        (0.1, 3.2e-3, False),  # 3 % below: within half the limit, held as measured
        (0.0, 2.5e-3, False),  # no overshoot limit (a rig): the incumbent is held as measured
    ],
)
def test_the_held_point_meets_a_demand_that_fell(
    m8528: Fin, overshoot: float, demand: float, trimmed: bool
) -> None:
    """A fish holds its incumbent between probes; when the speed loop asks less than the incumbent was
    measured to give (by more than half the overshoot limit), the held trial is driven at the voltage
    the fitted model says gives the demand and a quarter of the limit: a point measured under an earlier
    demand kept a stranger 5 % fast every other trial (``bench_fish.py --strangers``)."""
    opt = Optimiser(
        m8528,
        LIMITS,
        demand_n=3e-3,
        identify=False,
        tuning=COARSE,
        demand_margin_z=0.0,
        trial_overshoot=overshoot,
    )
    f, v = opt.propose()
    p = float(opt.correction.response(m8528, f, v).power_w)
    for t in (10.0, 20.0, 30.0):  # the same point three times: it counts, it is the incumbent
        assert opt.observe(t, f, v, 3.3e-3, p)
    best = opt.best_counted()
    assert best is not None and _close_point(best.observation.point, (f, v)), opt.status()
    opt.set_demand(demand)
    opt.converged = True  # (held, as between probes)
    held = opt.propose()
    if not trimmed:
        assert _close_point(held, (f, v)), (held, (f, v))
        return
    assert held[0] == pytest.approx(f) and held[1] < v
    model = opt.correction.predict(m8528, np.array([f, f]), np.array([v, held[1]])).thrust_n
    want = demand * (1 + overshoot / 4) / best.thrust_n  # of the thrust measured at the incumbent
    assert model[1] / model[0] == pytest.approx(want, rel=1e-3)
    assert LIMITS.voltage_pp_min <= held[1] <= LIMITS.voltage_pp_max


def _close_point(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return abs(a[0] / b[0] - 1) < 1e-3 and abs(a[1] / b[1] - 1) < 1e-3


def test_the_benchmarks_fish_controller_is_config_fish_yamls() -> None:
    """``fishrun``'s fish controller settings are the ones the fish's launch gives its controller."""
    import yaml

    from piezofin_ros.bench import fishrun

    root = Path(__file__).resolve().parents[2]
    params = yaml.safe_load((root / "config" / "fish.yaml").read_text())["/**/controller"]["ros__parameters"]
    assert params["demand_margin_z"] == fishrun.FISH_DEMAND_MARGIN_Z
    assert params["trial_overshoot"] == fishrun.FISH_TRIAL_OVERSHOOT


@pytest.mark.parametrize(
    "bad",
    [
        {"demand_margin_z": -1.0},
        {"demand_margin_z": math.nan},
        {"trial_overshoot": -0.1},
        {"trial_overshoot": math.nan},
    ],
)
def test_an_impossible_margin_or_overshoot_is_one_clear_error(m8528: Fin, bad: dict[str, float]) -> None:
    with pytest.raises(ControlError, match="demand_margin_z and trial_overshoot must be finite"):
        Optimiser(m8528, LIMITS, demand_n=3e-3, tuning=COARSE, **bad)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["stranger 1", "stranger 2", "stranger 3"])
def test_a_stranger_given_a_wrong_prior_drops_it_and_holds_its_speed(name: str) -> None:
    """Issue 39's fish (``bench_fish.py --strangers``): the nominal fin with effects, another body,
    amplifier and speed sensor, the paper's twin given as the prior.  With it the fish sat at its 8 mN
    cap 21 % slow (stranger 1) or wandered 4.2-8.2 cm/s for 6 (stranger 2).  The optimiser drops the
    twin once the trials contradict it (said), and the fish holds each set-point within 5 % in truth
    over the step's last minute and 95 % of its second half, at a supply within 3 % of the least that
    holds it; the optimiser's own thrust (its demand met) is the truth's within 10 %, and so is the
    estimator's self-sensed thrust once the fit calibrates it (read 1.5 times the truth through the
    twin it was given: 0.97-1.05 now over each step's last minute)."""
    from benchmarks.bench_fish import STRANGERS, least_supply_w, run, stranger

    result = run((name, MEASURED, 800.0, None))
    trace = result["trace"]
    assert any("the model is dropped" in e for e in trace.events), trace.events
    _, truth, _, _ = stranger(name)
    # from rest, every sample within 5 % after 60 s (75 s on stranger 2).  Measured 35.4, 71.2 and
    # 40.3 s (stranger 3, the README's driver fish, 74.0 s before the speed loop's secant step,
    # `SpeedLoop._secant`, 52.3 s while that step waited for the integral's boost); stranger 2 83 s
    # while a demand above a held point waited 20 s for a trial
    # that never came (`DemandGate.wait_s`, 10 s now); 66 s on stranger 1 before the given model was
    # weighed by its whole cost, 114 s before the speed loop's steady boost.  Stranger 2 reaches the
    # band at 21 s and dips up to 10 % from 48 to 68 s (the twin's map read the first trials 2.6 times
    # low): over `bench_fish.py`'s 750 s step that is held after 19 s by the issue's measure, 95 % of
    # the step within 5 % (`Trace.held_s`)
    within = 75.0 if name == "stranger 2" else 60.0
    assert trace.settling_s(0.0, 400.0) <= within, (name, trace.settling_s(0.0, 400.0))
    for (t0, t1), u in zip([(0.0, 400.0), (400.0, 800.0)], STRANGERS[name]["setpoints_m_s"], strict=True):
        assert abs(trace.mean("speed_m_s", t1 - 60.0, t1) / u - 1.0) < 0.05, (name, u)
        # over the step's second half at least 95 % of the time within 5 % (issue 39's goal; measured 1.0:
        # 0.94 while the held point, measured under an earlier demand, stayed 12 % above a later one)
        half = (trace.t >= 0.5 * (t0 + t1)) & (trace.t < t1)
        share = float(np.mean(np.abs(trace.speed_m_s[half] / u - 1.0) <= 0.05))
        assert share >= 0.95, (name, u, share)
        assert trace.mean("supply_w", t1 - 60.0, t1) <= 1.03 * least_supply_w(truth, u)
        late = (trace.t >= t1 - 60.0) & (trace.t < t1)
        ratio = np.mean(trace.demand_n[late]) / np.mean(trace.thrust_n[late])
        assert abs(ratio - 1.0) < 0.1, (name, ratio)
        sensed = np.mean(trace.thrust_estimate_n[late]) / np.mean(trace.thrust_n[late])
        assert abs(sensed - 1.0) < 0.1, (name, sensed)
        # issue 39's goal: no trial while swimming under 90 % of the demand (`Trace.cuts`).  Met on
        # stranger 3 and on each second step.  Not met on the first minute of strangers 1 and 2 (the
        # twin's map, read high, put a trial where the truth gave 0.58 and 0.55 of the demand for 8.6
        # and 8.0 s, from 19 and 20 s; stranger 2 two more of 0.88 and 0.82 for 3.2 s: the fish's
        # record): held here to no worse, a share of at least 0.5, for at most 10 s, in the first 70 s
        cuts = trace.cuts(t0, t1)
        if name == "stranger 3" or t0 > 0.0:
            assert cuts == [], (name, u, cuts)
        else:
            assert all(share >= 0.5 and length <= 10.0 and start < 70.0 for start, length, share in cuts), (
                name,
                cuts,
            )


def test_the_spread_over_seeds_says_each_steps_held_times_and_cuts() -> None:
    """``bench_fish.py --seeds``: per fish, strategy and step, the held time's least, median and most
    over the draws (``never`` where one never held), and the cuts: in how many draws, the deepest, the
    longest."""
    from benchmarks.bench_fish import spread

    def result(seed: int, held: tuple[float, float], cuts: list[tuple[float, float, float]]) -> dict:
        steps = [
            {"setpoint_m_s": u, "held_s": h, "cuts": c}
            for u, h, c in zip((0.05, 0.065), held, (cuts, []), strict=True)
        ]
        return {"fin": "stranger 9", "strategy": "ours", "seed": seed, "steps": steps}

    text = spread(
        [
            result(0, (40.0, 6.0), [(20.0, 8.0, 0.6)]),
            result(1, (30.0, 5.0), []),
            result(2, (70.0, math.inf), [(15.0, 3.0, 0.5), (80.0, 9.5, 0.85)]),
        ]
    )
    lines = text.strip().splitlines()
    assert lines[0] == "over 3 seeds (held s: least, median, most; cuts):"
    assert "5.00 cm/s  held 30.0, 40.0, 70.0  cuts in 2: deepest 0.50, longest 9.5s" in lines[1]
    assert lines[1].lstrip().startswith("stranger 9,")
    assert lines[2].endswith("6.50 cm/s  held 5.0, 6.0, never  cuts none")


def test_stranger_3_is_the_readme_driver_fish() -> None:
    """``bench_fish.py``'s stranger 3 is the fish of ``test/fish_driver.py`` (the README's driver, run
    live by ``test/nodes/test_fish_driver.py``), so that what the benchmark measures of it is what
    the live stack meets: its body, amplifier and speed sensor."""
    pytest.importorskip("piezofin_msgs.msg", reason="the driver's messages (the ROS workspace) are not built")
    from benchmarks.bench_fish import stranger
    from test import fish_driver as d

    _, truth, plant, spec = stranger("stranger 3")
    body = truth.body
    assert body.mass_kg + body.added_mass_kg == pytest.approx(d.MASS_KG)
    assert 0.5 * body.rho_w * body.drag_area_m2 == pytest.approx(d.DRAG_QUAD)
    assert body.drag_linear_n_s_m == pytest.approx(d.DRAG_LIN)
    assert (spec["speed_bias_m_s"], spec["speed_noise_m_s"]) == (d.SPEED_BIAS, d.SPEED_NOISE)
    amp = plant.amplifier
    for name in ("efficiency", "recovered", "quiescent_w", "bus_v"):
        assert getattr(amp, name) == pytest.approx(getattr(d.AMPLIFIER, name)), name
    assert plant.effects == () and plant.fin == load_fin(d.FIN)
