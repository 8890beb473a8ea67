"""The controller's two strategies behind one interface, without ROS (issue 15)."""

from __future__ import annotations

from piezofin_ros.control.driveloop import DriveLoop
from piezofin_ros.control.optimise import OperatingBox, Optimiser
from piezofin_ros.control.strategy import OFF, OptimiseStrategy, Strategy, TrialStrategy
from piezofin_ros.control.trials import Mode, TrialPlan, TrialRunner
from piezofin_ros.physics.fin import load_fin


def _run(strategy: Strategy, until: float, dt: float = 0.1) -> list[tuple[float, float, float, float]]:
    sent = []
    t = 0.0
    while t <= until:
        sent.append((t, *strategy.command(t)))
        t = round(t + dt, 9)
    return sent


def _plan_strategy(**kwargs: object) -> TrialStrategy:
    plan = TrialPlan.grid([5.0, 7.0, 9.0], [400.0], mode=Mode.PROTOCOL, off_s=1.0, on_s=2.0)
    return TrialStrategy(TrialRunner(plan), **kwargs)  # type: ignore[arg-type]


def test_a_plan_without_estimates_aborts_after_max_missing_and_stays_off() -> None:
    s = _plan_strategy(max_missing=2)
    assert not s.started() and s.planned_s() == 3 * (4.0 + 10.0)
    sent = _run(s, 60.0)
    assert s.started() and s.finished and s.runner.aborted == "2 trials in a row without an estimate"
    assert [e.level for e in s.events] == ["warning", "warning", "error"]
    # trial 1 ended at 8 s and its estimate was due 10 s later: from then on the drive is off
    assert all((f, v, on) == OFF for t, f, v, on in sent if t > 18.0)
    assert max(v for *_, v, _ in sent) == 400.0 and s.status_due(60.0)
    assert s.status()["state"] == "aborted" and s.progress() == "trial 3/3"


def test_the_optimiser_strategy_takes_a_demand_and_stops_after_its_duration() -> None:
    fin = load_fin("M8528-P1")
    loop = DriveLoop(Optimiser(fin, OperatingBox(1.0, 20.0, 50.0, 800.0), 800.0, None), "self", 400.0, 10.0)
    s = OptimiseStrategy(loop, duration_s=5.0, after="stop")
    assert s.takes_demand and not _plan_strategy().takes_demand and s.planned_s() == 5.0
    s.set_demand(2e-3)
    assert loop.optimiser.demand_n == 2e-3
    sent = _run(s, 8.0)
    assert s.finished and [e.text for e in s.events if e.text.startswith("done after 5 s")]
    assert 0 < max(v for *_, v, _ in sent) <= 800.0
    assert sent[-1][2] < max(v for *_, v, _ in sent)  # ramping down after the duration
    assert s.status()["mode"] == "optimise" and s.status()["finished"] is True
