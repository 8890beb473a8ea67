"""The fish's speed loop (issue 27) closed around a swimming body: steps settle within 5 % in 30 s of
fish time, a wrong drag law is corrected, and what it is fed cannot take the demand out of bounds."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.control.speedloop import SpeedLoop, SpeedLoopConfig
from piezofin_ros.errors import ControlError
from piezofin_ros.physics.swim import Body, load_body

DT = 0.1


def swim(
    loop: SpeedLoop,
    truth: Body,
    setpoints: list[tuple[float, float]],
    t_end: float,
    lag_s: float = 2.0,
    noise: float = 0.002,
    sensor=lambda t, u: u,
    seed: int = 0,
    estimates: bool = True,
    windows: bool = False,
    told: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fish time, true speed and demand: the body ``truth`` (its surge equation), a controller that
    meets a new demand with a first-order lag ``lag_s`` (the optimiser's trials), a noisy sensor, and
    (``estimates``) an estimator's thrust every 5 s: the thrust then, or (``windows``) its mean over
    the 5 s window that ends then, the window's length ``told`` (as the estimator's) or not."""
    rng = np.random.default_rng(seed)
    u = thrust = 0.0
    ts, us, ds, given = [], [], [], []
    todo = list(setpoints)
    for k in range(int(t_end / DT)):
        t = k * DT
        while todo and todo[0][0] <= t:
            loop.set_setpoint(todo.pop(0)[1])
        reading = sensor(t, u + noise * rng.standard_normal())
        if reading is not None:
            loop.measure(t, reading)
        given.append(thrust)
        if estimates and windows and k % 50 == 0 and k > 0:
            loop.estimate(t, float(np.mean(given[-50:])), 50 * DT if told else math.nan)
        elif estimates and not windows and k % 50 == 0:  # the estimator's windows: the thrust the fin gives
            loop.estimate(t, thrust)
        demand = loop.update(t)
        thrust += (demand - thrust) * DT / lag_s
        u += DT * truth.acceleration(u, thrust)
        ts.append(t), us.append(u), ds.append(demand)
    return np.array(ts), np.array(us), np.array(ds)


def settled_after(t: np.ndarray, u: np.ndarray, target: float, t0: float, tol: float = 0.05) -> float:
    """Time after ``t0`` from which the speed stays within ``tol`` of ``target``."""
    sel = t >= t0
    out = np.abs(u[sel] / target - 1.0) > tol
    if not out.any():
        return 0.0
    return float(t[sel][np.flatnonzero(out)[-1]] - t0 + DT)


#: A loop tuned for a controller that meets a new demand within seconds (not the default, which
#: waits out the optimiser's trials): twice the body's damping as gain, an 8 s integral.
FAST = SpeedLoopConfig(kp_n_per_m_s=2 * 1000 * 1.1925e-3 * 0.05, ti_s=8.0)  # rho C_D S U at 5 cm/s


@pytest.mark.parametrize(
    ("drag_error", "config", "within_s"),
    [
        (1.0, SpeedLoopConfig(), 30.0),  # the drag law right: the feed-forward alone, the 30 s
        (1.3, SpeedLoopConfig(), 30.0),  # 30 % off: measured 16 / 16 s (16 / 12 s, the secant boosted)
        # (the cautious integral alone, steady_boost 1, took 106 / 92 s: 35 / 52 s with the boost and
        # the secant step, 35 / 50 s when the secant waited for the boost)
        (0.7, SpeedLoopConfig(), 60.0),
        (1.3, FAST, 30.0),  # tuned for a fast actuator: 30 s with the law 30 % off either way
        (0.7, FAST, 30.0),
    ],
    ids=["right", "drag+30%", "drag-30%", "drag+30%-fast", "drag-30%-fast"],
)
def test_steps_settle_within_5_percent(drag_error: float, config: SpeedLoopConfig, within_s: float) -> None:
    """Steps up and down, the controller meeting each new demand within 2 s (first-order lag)."""
    body = load_body("mfc-fish")
    truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
    loop = SpeedLoop(body, config)
    step = within_s + 30.0
    t, u, d = swim(loop, truth, [(0.0, 0.06), (step, 0.04)], 2 * step)
    assert settled_after(t[t < step], u[t < step], 0.06, 0.0) <= within_s
    assert settled_after(t, u, 0.04, step) <= within_s
    assert np.all((d >= loop.config.min_demand_n) & (d <= loop.config.max_demand_n))
    assert "holding 0.04 m/s" in loop.state and loop.kind == "holding"


@pytest.mark.parametrize("drag_error", [0.5, 0.7, 1.0, 2.0])
def test_a_steady_speed_off_its_set_point_winds_the_integral_faster(drag_error: float) -> None:
    """The integral winds ``steady_boost`` times faster only where the speed's own trend would leave
    it more than 2 % off: a drag law off by a factor of 0.5-2 is removed, from rest and after a step
    together, in at most 70 % of the time the cautious integral alone takes (measured: 44 / 84 s
    against 117 / 136 s at 0.5, 43 / 53 against 106 / 92 s at 0.7, 102 / 122 s against 191 / 150 s
    at 2), and with the law right the steps settle as fast as without it (an
    exponential approach is no error to wind on: 12 / 12 s against 12 / 13 s).  The boost alone: the
    secant step (``steady_secant``), which no longer waits for it, is off in both."""
    body = load_body("mfc-fish")
    truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
    times = {}
    for boost in (1.0, SpeedLoopConfig().steady_boost):
        loop = SpeedLoop(body, SpeedLoopConfig(steady_boost=boost, steady_secant=0.0))
        t, u, d = swim(loop, truth, [(0.0, 0.06), (200.0, 0.04)], 400.0)
        times[boost] = (
            settled_after(t[t < 200.0], u[t < 200.0], 0.06, 0.0),
            settled_after(t, u, 0.04, 200.0),
        )
        assert np.all((d >= loop.config.min_demand_n) & (d <= loop.config.max_demand_n))
    cautious, boosted = times[1.0], times[SpeedLoopConfig().steady_boost]
    if drag_error == 1.0:
        assert max(boosted) <= 15.0 and max(boosted) <= max(cautious) + 1.0, times
    else:
        assert sum(boosted) <= 0.7 * sum(cautious), times


def test_a_secant_step_at_a_steady_speed_removes_a_wrong_drag_law_sooner() -> None:
    """Where the speed is steady and off (``drag.steady_off``: over a window of its readings),
    the steady part of the demand moves half way to the estimated thrust times ``D(U*)/D(U)``
    (``steady_secant``).  Over drag laws 0.5-2 times the told one, behind a controller meeting each
    demand with a lag of 2 or 8 s, from rest and after a step down: in all, 30 % less time to settle
    within 5 % (measured 922 s against 1,312 s over the 20 cases; the slowest 93 s against 121 s),
    the right law's steps as they were (12 / 12 s).  One case takes longer (the law 0.7 times, lag
    8 s: from rest 71 s against 48 s).  Taken only while the integral was boosted (2026-12-06), it
    gave 1,121 s, the slowest 89 s.  On the README's driver fish behind the optimiser's trials
    (``bench_fish.py``'s stranger 3) it is held from rest after 13-45 s over six seeds, where the
    boosted secant took 13-70 s and the integral alone 74 s (one seed)."""
    body = load_body("mfc-fish")
    times: dict[float, list[float]] = {0.0: [], 0.5: []}
    for drag_error in (0.5, 0.7, 1.0, 1.4, 2.0):
        truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
        for lag in (2.0, 8.0):
            for secant in times:
                loop = SpeedLoop(body, SpeedLoopConfig(steady_secant=secant))
                t, u, d = swim(loop, truth, [(0.0, 0.06), (200.0, 0.04)], 400.0, lag_s=lag)
                times[secant] += [
                    settled_after(t[t < 200.0], u[t < 200.0], 0.06, 0.0),
                    settled_after(t, u, 0.04, 200.0),
                ]
                assert np.all((d >= loop.config.min_demand_n) & (d <= loop.config.max_demand_n))
    without, with_ = np.array(times[0.0]), np.array(times[0.5])
    assert with_.sum() <= 0.8 * without.sum(), times
    assert with_.max() <= without.max(), times
    right = slice(8, 10)  # (the law right, lag 2 s: from rest, after the step)
    assert np.all(with_[right] <= without[right] + 1.0), times


def test_the_momentum_takes_the_secant_step_while_the_speed_still_moves() -> None:
    """Told each estimate's window, the loop takes the body's drag there as the fin's thrust less the
    told mass times the speed's slope over the window (``drag.moving_drag``), and need not wait for
    a steady speed.  Over the secant test's 20 cases (drag laws 0.5-2 times the told one, lags of 2
    and 8 s, from rest and after a step down), estimates as window means both ways: 8.5 % less time
    to settle in all (measured 858 s against 938 s), no case slower by more than 0.1 s, a drag law
    1.4 times the told one (the README's driver fish has 1.39 at 5 cm/s) from rest after 21 / 26 s
    (29 / 39 s).  The live driver fish at x5 (``test_fish_driver.py``) fell from 5.27 cm/s to 4.21
    after its first trials, 14 s at a point that gave what was asked, before its speed was steady
    enough for a step.  Where the readings' noise leaves the momentum's share of the thrust unknown
    by more than 10 % (``drag.MOMENTUM_NOISE``: a slow fish's small thrust), the steady account is
    taken: without that, the law half the told one behind an 8 s lag settled its step 31 s later."""
    body = load_body("mfc-fish")
    times: dict[bool, list[float]] = {False: [], True: []}
    for drag_error in (0.5, 0.7, 1.0, 1.4, 2.0):
        truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
        for lag in (2.0, 8.0):
            for told in times:
                loop = SpeedLoop(body, SpeedLoopConfig())
                # (the same windows' means both ways; their window not told: the steady account only)
                setpoints = [(0.0, 0.06), (200.0, 0.04)]
                t, u, d = swim(loop, truth, setpoints, 400.0, lag_s=lag, windows=True, told=told)
                times[told] += [
                    settled_after(t[t < 200.0], u[t < 200.0], 0.06, 0.0),
                    settled_after(t, u, 0.04, 200.0),
                ]
                assert np.all((d >= loop.config.min_demand_n) & (d <= loop.config.max_demand_n))
    steady, moving = np.array(times[False]), np.array(times[True])
    assert moving.sum() <= 0.95 * steady.sum(), times
    assert np.all(moving <= steady + 1.0), times
    driver = 12  # (the law 1.4 times, lag 2 s, from rest)
    assert moving[driver] <= 0.8 * steady[driver], times


def test_a_creep_near_the_edge_on_a_noisy_sensor_is_boosted() -> None:
    """A live fish crept from 4.6 to 4.8 cm/s of 5 over 80 s: its sensor's noise (0.2 cm/s at 20 Hz)
    puts the speed's trend about 1 % of the set-point up and down, across the boost's 2 % edge every
    few seconds, and the boost, which waited ``steady_s`` each time, wound the integral 4 times faster
    in 20 % of that time (these six seeds).  Once begun it now goes on until the trend is within
    1.5 %: twice that share."""

    def boosted_share(seed: int) -> float:
        loop = SpeedLoop(load_body("mfc-fish"), SpeedLoopConfig())
        loop.set_setpoint(0.05)
        rng = np.random.default_rng(seed)
        fast = []
        for k in range(80 * 20):
            t = k / 20
            loop.measure(t, 0.0466 + 0.00003 * t + 0.002 * rng.standard_normal())
            if k % 2 == 0:  # (the node's 10 Hz, the fin giving what is asked)
                loop.estimate(t, max(loop.demand_n, 1e-3))
                before, e = loop.integral_n, loop.setpoint_m_s - loop.speed_m_s
                loop.update(t)
                if t >= 20.0:
                    rate = (loop.integral_n - before) / (loop.kp() / loop.config.ti_s * e * 0.1)
                    fast.append(rate > 2.0)
        return float(np.mean(fast))

    shares = [boosted_share(seed) for seed in range(6)]
    assert np.mean(shares) >= 0.33, shares


@pytest.mark.parametrize(
    "bad",
    [
        {"steady_boost": 0.5},
        {"steady_boost": math.nan},
        {"steady_s": 0.0},
        {"steady_secant": 1.5},
        {"secant_every_s": 0.0},
    ],
)
def test_a_boost_out_of_its_range_is_refused_naming_it(bad: dict[str, float]) -> None:
    with pytest.raises(ControlError, match=f"speed loop: {next(iter(bad))} = .* must be finite, within"):
        SpeedLoopConfig(**bad)


@pytest.mark.parametrize("drag_error", [1.3, 0.7])
def test_with_no_thrust_estimate_the_integral_still_winds(drag_error: float) -> None:
    """A stack with no estimator (or a drive that never rests for one of its windows: a voltage loop
    at a fixed frequency): after ``unjudged_after_s`` with no estimate, the integral winds on the
    speed alone.  Before, with nothing to judge the fin by, it never wound: the fish stayed 8-12 %
    off its set-point for good with the drag law 30 % off (``bench_fish.py``'s voltage loop on the
    strangers: 9-13 % slow)."""
    body = load_body("mfc-fish")
    truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
    loop = SpeedLoop(body, SpeedLoopConfig())
    t, u, _ = swim(loop, truth, [(0.0, 0.06), (200.0, 0.04)], 400.0, estimates=False)
    assert settled_after(t[t < 200.0], u[t < 200.0], 0.06, 0.0) <= 120.0
    assert settled_after(t, u, 0.04, 200.0) <= 120.0
    assert abs(np.mean(u[-500:]) / 0.04 - 1) < 0.02


@pytest.mark.parametrize("drag_error", [1.0, 1.3, 0.7])
def test_behind_the_optimisers_trials_the_loop_does_not_oscillate(drag_error: float) -> None:
    """The live fish: the controller meets a new demand only from its next 30 s trial (and then with
    the fin's own 3 s), the fin gives at most 5.3 mN.  The default loop settles within 5 % and stays
    there (before: a limit cycle between 1.5 and 7.5 cm/s in the live stack)."""
    body = load_body("mfc-fish")
    truth = dataclasses.replace(body, drag_area_m2=body.drag_area_m2 * drag_error)
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.008))
    loop.set_setpoint(0.05)
    rng = np.random.default_rng(0)
    u = thrust = held = 0.0
    next_trial, speeds = 0.0, []
    for k in range(int(600.0 / DT)):
        t = k * DT
        loop.measure(t, u + 0.002 * rng.standard_normal())
        demand = loop.update(t)
        if t >= next_trial:
            held, next_trial = min(demand, 0.0053), t + 30.0
        thrust += (held - thrust) * DT / 3.0
        if k % 50 == 0:
            loop.estimate(t, thrust)
        u += DT * truth.acceleration(u, thrust)
        speeds.append(u)
    late = np.array(speeds[-int(200.0 / DT) :])
    assert np.all(np.abs(late / 0.05 - 1) <= 0.05), (late.min(), late.max())


def test_an_unreachable_set_point_is_said_and_the_demand_stays_allowed() -> None:
    body = load_body("mfc-fish")
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.003))
    said = loop.set_setpoint(0.5)
    assert "beyond" in said and f"{loop.fastest_m_s():.3g} m/s" in said
    _, u, d = swim(loop, body, [], 60.0)
    assert d.max() == pytest.approx(0.003) and u[-1] == pytest.approx(loop.fastest_m_s(), rel=0.02)
    assert "at the most thrust allowed" in loop.state and loop.kind == "saturated"


def test_a_silent_sensor_leaves_the_feed_forward_and_says_so() -> None:
    body = load_body("mfc-fish")
    loop = SpeedLoop(body)
    _, u, d = swim(loop, body, [(0.0, 0.05)], 80.0, sensor=lambda t, x: x if t < 30 else None)
    assert d[-1] == pytest.approx(loop.feed_forward_n(0.05))
    assert "speed sensor silent" in loop.state and loop.kind == "silent"
    assert abs(u[-1] / 0.05 - 1) < 0.02  # the drag law is right here: the feed-forward alone holds it


def test_a_lying_sensor_is_said_and_cannot_push_the_demand_out_of_bounds() -> None:
    body = load_body("mfc-fish")
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.008))
    _, _, d = swim(loop, body, [(0.0, 0.05)], 90.0, sensor=lambda t, x: 0.0)  # reads "still" for ever
    assert d.max() <= 0.008 and "a sensor that lies" in loop.state and loop.kind == "lies"


@settings(max_examples=200, deadline=None)
@given(
    readings=st.lists(
        st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-1.0, 1.0)),
        min_size=1,
        max_size=50,
    ),
    setpoint=st.floats(0.0, 10.0),
)
def test_whatever_it_reads_the_demand_stays_within_its_bounds(readings, setpoint) -> None:
    loop = SpeedLoop(Body(), SpeedLoopConfig(max_demand_n=0.004))
    loop.set_setpoint(setpoint)
    for k, r in enumerate(readings):
        loop.measure(0.1 * k, r)
        d = loop.update(0.1 * k)
        assert (0.0 if setpoint == 0 else 1e-4) <= d <= 0.004 and math.isfinite(d)


@settings(max_examples=60, deadline=None)
@given(
    estimates=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=20),
    share=st.floats(0.05, 5.0),
    setpoint=st.floats(0.01, 0.5),
    windows=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=4),
    lag=st.floats(allow_nan=True, allow_infinity=True),
    wobble=st.floats(0.0, 0.9),
)
def test_whatever_thrust_it_is_told_the_secant_keeps_the_demand_within_its_bounds(
    estimates, share, setpoint, windows, lag, wobble
) -> None:
    """A speed off its set-point, steady or moving (so the secant steps, on the steady account or
    the momentum's), and thrust estimates of any float, 1e300 N or a tiny one included, over windows
    and lags of any float: the demand stays within its bounds and finite."""
    loop = SpeedLoop(Body(), SpeedLoopConfig(max_demand_n=0.004))
    loop.set_setpoint(setpoint)
    for k in range(1200):
        t = 0.1 * k
        loop.measure(t, share * setpoint * (1.0 + wobble * math.sin(0.2 * t)))
        if k % 50 == 0:
            n = k // 50
            loop.estimate(t, estimates[n % len(estimates)], windows[n % len(windows)], lag)
        d = loop.update(t)
        # (within what it may ask: max_demand_n, widened at most max_widening times where it sits
        # saturated while the estimates say the fin gives it and the fish is short)
        assert 1e-4 <= d <= loop.cap_n <= 0.004 * loop.config.max_widening
        assert math.isfinite(d) and math.isfinite(loop.integral_n)


@pytest.mark.parametrize("bad", [-0.1, math.nan, math.inf])
def test_a_set_point_that_is_no_speed_is_refused(bad: float) -> None:
    with pytest.raises(ControlError, match="set-point"):
        SpeedLoop(Body()).set_setpoint(bad)


def test_a_fin_that_cannot_give_the_demand_is_no_lying_sensor() -> None:
    """The demand asks more than the fin gives (the live fish at 8 mN, its fin 3.5 mN at most): the
    speed the estimated thrust gives is what the sensor is judged against, so nothing is blamed."""
    body = load_body("mfc-fish")
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.008))
    capped = dataclasses.replace(body)  # the same body, its fin capped below
    rng = np.random.default_rng(1)
    u = 0.0
    loop.set_setpoint(0.12)  # its drag alone asks 8.6 mN
    for k in range(2000):
        t = 0.1 * k
        loop.measure(t, u + 0.002 * rng.standard_normal())
        thrust = min(loop.update(t), 0.0035)
        loop.estimate(t, thrust)
        u += 0.1 * capped.acceleration(u, thrust)
    assert "lies" not in loop.state and "at the most thrust allowed" in loop.state


def test_a_loop_saturated_on_estimates_that_read_high_widens_what_it_asks() -> None:
    """Issue 39: a fish given a fin model that reads its thrust 1.6 times high sat at its 8 mN cap,
    12-23 % slow, for ever.  Saturated with the fin giving what is asked (by its estimate) and the fish
    slower than that thrust gives through the drag law, the loop asks more, 25 % at a time (said), up
    to ``max_widening`` times its cap; the fish reaches its set-point."""
    body = load_body("mfc-fish")
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.004))
    rng = np.random.default_rng(2)
    u, thrust, said = 0.0, 0.0, []
    loop.set_setpoint(0.08)  # its drag asks 3.8 mN in truth: 6.1 mN as the fin's estimates read it
    for k in range(6000):
        t = 0.1 * k
        loop.measure(t, u + 0.002 * rng.standard_normal())
        demand = loop.update(t)
        said += loop.widened
        loop.widened.clear()
        thrust += (demand / 1.6 - thrust) * 0.1 / 2.0  # the fin gives the demand as its estimate reads it
        loop.estimate(t, 1.6 * thrust)
        u += 0.1 * body.acceleration(u, thrust)
    assert said and "read high against the speed" in said[0], said
    assert 0.004 < loop.cap_n <= 3 * 0.004
    assert abs(u / 0.08 - 1.0) < 0.03 and loop.kind == "holding", (u, loop.state)


def test_a_set_point_beyond_a_fin_estimated_right_widens_nothing() -> None:
    """The same saturation with estimates that are right: the speed is what the thrust gives, so the
    cap is what binds, and stays (the unreachable set-point is said, as before)."""
    body = load_body("mfc-fish")
    loop = SpeedLoop(body, SpeedLoopConfig(max_demand_n=0.004))
    _, u, d = swim(loop, body, [(0.0, 0.12)], 300.0)
    assert loop.cap_n == 0.004 and d.max() == pytest.approx(0.004) and not loop.widened
    assert u[-1] == pytest.approx(loop.fastest_m_s(), rel=0.03)
