"""The controller's trial runner: schedule, estimate matching, choice."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from piezofin_ros.control.objective import range_per_charge
from piezofin_ros.control.trials import Mode, TrialPlan, TrialRunner, choose
from piezofin_ros.estimation.estimator import Estimate

from .. import builders


def estimate(t_start: float, f: float, thrust: float, power: float, final: float = 1.0) -> Estimate:
    """A trial (5 s at 800 Vpp) from ``t_start``, its thrusts per watt filled."""
    return builders.estimate(
        t_start=t_start,
        t_end=t_start + 5,
        frequency_hz=f,
        voltage_pp=800.0,
        thrust_n=thrust,
        power_w=power,
        final=final,
        thrust_per_watt=thrust / power,
        thrust_per_watt_self=thrust / power,
        c_tau=0.13,
    )


def test_protocol_schedule_is_off_on_off() -> None:
    runner = TrialRunner(TrialPlan.grid([5.0, 9.0], [800.0]))
    cmds = {t: runner.command(100.0 + t) for t in (0.0, 9.9, 10.0, 19.9, 20.0, 29.9, 30.0, 40.0, 60.0)}
    assert cmds[0.0][2] == 0 and cmds[9.9][2] == 0
    assert cmds[10.0] == (5.0, 800.0, 1.0) and cmds[19.9] == (5.0, 800.0, 1.0)
    assert cmds[20.0][2] == 0 and cmds[29.9][2] == 0
    assert cmds[40.0] == (9.0, 800.0, 1.0)  # second trial's burst
    assert cmds[60.0] == (0.0, 0.0, 0.0)
    assert runner.done


def test_estimates_attach_to_their_trial_and_timeouts_are_reported() -> None:
    runner = TrialRunner(TrialPlan.grid([5.0, 9.0], [800.0]))
    runner.command(0.0)
    assert not runner.add_estimate(estimate(13.0, 5.0, 1e-3, 1e-3, final=0.0))  # running window: ignored
    assert runner.add_estimate(estimate(13.0, 5.0, 1e-3, 1e-3))
    runner.command(35.0)  # trial 1 starts here (the first took 30 s)
    assert runner.missing(74.9) == []  # 35 + 30 s trial + 10 s estimate timeout
    assert [r.index for r in runner.missing(75.1)] == [1]


def test_continuous_mode_moves_on_when_the_estimate_comes() -> None:
    runner = TrialRunner(TrialPlan.grid([5.0, 9.0], [800.0], mode=Mode.CONTINUOUS))
    assert runner.command(0.0) == (5.0, 800.0, 1.0)
    assert runner.add_estimate(estimate(3.0, 5.0, 1e-3, 1e-3, final=0.0))
    assert runner.command(8.0) == (9.0, 800.0, 1.0)  # no stop between points


def test_frf_mode_stays_until_the_point_has_settled() -> None:
    """A stepped sine for identification: the point ends when two running estimates agree (0.5 %),
    not at the first one; an estimate of another frequency (a window spanning the step) is not used;
    a point that never settles ends at the timeout with its last estimate."""
    plan = TrialPlan.grid([5.0, 9.0, 12.0], [100.0], mode=Mode.FRF, settle_timeout_s=40.0)
    runner = TrialRunner(plan)
    assert runner.command(0.0) == (5.0, 100.0, 1.0)
    for k, u in enumerate((0.050, 0.060, 0.0640, 0.0642)):  # a transient dying out
        assert runner.add_estimate(replace(estimate(3.0 + 5 * k, 5.0, 1e-3, 1e-3, 0.0), tip_velocity_rms=u))
        settled = k == 3
        assert (runner.results[0].estimate is not None) == settled
        assert runner.command(8.0 + 5 * k) == ((9.0, 100.0, 1.0) if settled else (5.0, 100.0, 1.0))
    assert runner.results[0].estimate.tip_velocity_rms == 0.0642
    t1 = runner.results[1].t_start
    assert not runner.add_estimate(estimate(t1 + 1.0, 7.0, 1e-3, 1e-3, 0.0))  # spans the step: 7 Hz
    for k in range(6):  # never agrees within 0.5 %
        runner.add_estimate(
            replace(estimate(t1 + 3 + 5 * k, 9.0, 1e-3, 1e-3, 0.0), tip_velocity_rms=0.1 + 0.01 * k)
        )
    assert runner.command(t1 + 39.0) == (9.0, 100.0, 1.0)
    assert runner.command(t1 + 40.0) == (12.0, 100.0, 1.0)  # timeout: the last estimate is the point
    assert runner.results[1].estimate.tip_velocity_rms == pytest.approx(0.15)
    assert [r.index for r in runner.missing(t1 + 200.0)] == [2]  # a timed-out frf point is not missing


def test_choose_most_thrust_per_watt_above_the_demand() -> None:
    runner = TrialRunner(TrialPlan.grid([2.0, 5.0, 9.0], [800.0]))
    runner.command(0.0)
    for k, (f, thrust, power) in enumerate([(2.0, 1e-4, 1e-6), (5.0, 2e-3, 1e-3), (9.0, 1.5e-2, 2e-2)]):
        runner.command(30.0 * k)
        runner.add_estimate(estimate(30.0 * k + 13, f, thrust, power))
    assert choose(runner.results, min_thrust_n=1e-3).frequency_hz == 5.0
    assert choose(runner.results, min_thrust_n=0.0).frequency_hz == 2.0
    assert choose(runner.results, min_thrust_n=1.0).frequency_hz == 9.0  # none meets it: most thrust
    # by the objective given (control/objective.py): a fish paying 0.3 W besides goes farthest on the
    # most thrust, sqrt(15 mN) / 0.32 W against sqrt(2 mN) / 0.301 W
    fish = range_per_charge(0.3)
    assert choose(runner.results, min_thrust_n=1e-3, objective=fish).frequency_hz == 9.0


@pytest.mark.parametrize(
    "bad", [{"points": ()}, {"points": ((math.nan, 800.0),)}, {"points": ((5.0, 800.0),), "on_s": 0}]
)
def test_bad_plans_are_rejected(bad: dict) -> None:
    with pytest.raises(ValueError):  # noqa: PT011 (each message is checked in the node tests)
        TrialPlan(**bad)
