"""What the controller node runs: one interface, two strategies (a plan of trials, the optimiser).

The ``controller`` node is a thin loop around a :class:`Strategy`: each heartbeat it asks for the
command to send at that time, hands it every estimate that arrives, logs the strategy's events and
publishes its status when the strategy says so.  Two strategies implement it:

* :class:`TrialStrategy` runs a :class:`~.trials.TrialPlan` (the paper's protocol or continuous
  trials), notices trials whose estimate does not come, aborts after ``max_missing`` in a row, and
  at the end chooses the point with the most thrust per watt, then holds it or stops;
* :class:`OptimiseStrategy` runs the thrust-per-watt :class:`~.driveloop.DriveLoop` (trials chosen
  by the optimiser, settling, slew, estimate watchdog) until ``duration_s``, and takes a thrust
  demand.

Plain Python: no ROS, no clock of its own (times come in as arguments), so both are tested
directly and the node adds nothing but topics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, Protocol

from ..estimation.estimator import Estimate
from .driveloop import DriveLoop
from .objective import THRUST_PER_WATT, Objective
from .trials import SOURCES, Mode, TrialResult, TrialRunner, choose, watt_label


class ControllerMode(StrEnum):
    """What the controller does, declared once: a grid of trials, each in one of the trials' modes
    (:class:`~.trials.Mode`), or the thrust-per-watt optimiser."""

    PROTOCOL = "protocol"
    CONTINUOUS = "continuous"
    FRF = "frf"
    OPTIMISE = "optimise"

    @property
    def trial_mode(self) -> Mode | None:
        """The trials' mode it runs (``None``: the optimiser's live loop)."""
        return None if self is ControllerMode.OPTIMISE else Mode(self.value)


Command = tuple[float, float, float]  # (frequency_hz, voltage_pp, on)
OFF: Command = (0.0, 0.0, 0.0)


@dataclass
class Event:
    """A line for the node's log: ``level`` is ``info``, ``warning`` or ``error``."""

    level: str
    text: str


class Strategy(Protocol):
    """The controller's strategy (see the module docstring)."""

    #: a thrust demand is taken (``thrust_demand`` topic)
    takes_demand: bool
    #: the run has ended (the node keeps sending the strategy's last command)
    finished: bool
    #: log lines since the last heartbeat (the node empties it)
    events: list[Event]

    def started(self) -> bool:
        """True once the first command has been asked for."""

    def command(self, t: float) -> Command:
        """The command to send at time ``t`` (s), called once per heartbeat."""

    def add_estimate(self, t: float, e: Estimate) -> bool:
        """Take an estimate received at ``t``; True if the status changed."""

    def set_demand(self, demand_n: float | None) -> None:
        """A new thrust demand, N (``None``: none)."""

    def status_due(self, t: float) -> bool:
        """True when the node should publish the status (on a change, or periodically)."""

    def status(self) -> dict[str, Any]:
        """The JSON-able status the node publishes on ``controller/status``."""

    def planned_s(self) -> float | None:
        """Time the run needs (``None``: until stopped)."""

    def progress(self) -> str:
        """One line for a progress display."""

    def close(self) -> None:
        """The node is stopping: let go of any work in the background."""


@dataclass
class TrialStrategy:
    """A plan of trials, then the chosen point (held or not)."""

    runner: TrialRunner
    source: str = "self"
    min_thrust_n: float = 1e-3
    max_missing: int = 2
    after: str = "stop"  # stop (0 V) or hold (drive the chosen point)
    watt: str = "fin"  # the watt of the thrust per watt that chooses (physics/amplifier.py, WATT)
    objective: Objective = THRUST_PER_WATT  # what chooses, in that watt (control/objective.py)
    takes_demand: bool = False
    finished: bool = False
    chosen: TrialResult | None = None
    events: list[Event] = field(default_factory=list)
    _reported_missing: set[int] = field(default_factory=set)
    _changed: bool = False

    def started(self) -> bool:
        return self.runner.t_begin is not None or self.runner.done

    def command(self, t: float) -> Command:
        runner = self.runner
        cmd = OFF
        if not runner.done:
            before = runner.index
            cmd = runner.command(t)
            self._changed |= runner.index != before
        if not self.finished:  # the last trials' estimates may go missing after the plan has run
            for r in runner.missing(t):
                if r.index in self._reported_missing:
                    continue
                self._reported_missing.add(r.index)
                self.events.append(
                    Event(
                        "warning",
                        f"no estimate for trial {r.index} ({r.frequency_hz:g} Hz, {r.voltage_pp:g} Vpp): "
                        "is thrust_estimator running?",
                    )
                )
            if runner.aborted is None and self._missing_in_a_row() >= self.max_missing:
                runner.aborted = f"{self.max_missing} trials in a row without an estimate"
                self.events.append(Event("error", f"stopping the run and the drive: {runner.aborted}"))
        if runner.done and not self.finished and (runner.aborted or self._all_settled()):
            self._finish()  # an aborted run does not wait for the trial it was in
        if self.finished:
            c = self.chosen
            if self.after == "hold" and c is not None and runner.aborted is None:
                return (c.frequency_hz, c.voltage_pp, 1.0)
            return OFF
        return cmd

    def _missing_in_a_row(self) -> int:
        n = 0
        for r in reversed(self.runner.results):
            if r.index in self._reported_missing and r.estimate is None:
                n += 1
            elif r.estimate is not None:
                break
        return n

    def _all_settled(self) -> bool:
        return all(r.estimate is not None or r.index in self._reported_missing for r in self.runner.results)

    def _finish(self) -> None:
        self.finished = True
        self._changed = True
        self.chosen = choose(self.runner.results, self.source, self.min_thrust_n, self.watt, self.objective)
        if self.chosen is not None:
            e = self.chosen.estimate
            assert e is not None
            self.events.append(
                Event(
                    "info",
                    f"chosen: {self.chosen.frequency_hz:g} Hz, {self.chosen.voltage_pp:g} Vpp: "
                    f"{getattr(e, SOURCES[self.source]) * 1e3:.3f} mN, {e.power(self.watt) * 1e3:.3f} mW "
                    f"({self.watt}), {e.thrust_per(self.watt, self.source) * 1e3:.1f} "
                    f"{watt_label(self.watt)}",
                )
            )

    def add_estimate(self, t: float, e: Estimate) -> bool:
        return self.runner.add_estimate(e)

    def set_demand(self, demand_n: float | None) -> None:
        raise NotImplementedError("a plan of trials takes no thrust demand")

    def status_due(self, t: float) -> bool:
        due, self._changed = self._changed, False
        return due

    def status(self) -> dict[str, Any]:
        r = self.runner
        state = "aborted" if r.aborted else ("done" if self.finished else "running")
        return {
            "mode": r.plan.mode.value,
            "state": state,
            "reason": r.aborted,
            "trial": min(r.index, len(r.plan.points)),
            "n_trials": len(r.plan.points),
            "source": self.source,
            "watt": self.watt,
            "results": [x.record() for x in r.results],
            "chosen": self.chosen.record() if self.chosen is not None else None,
        }

    def planned_s(self) -> float | None:
        plan = self.runner.plan
        per_trial = plan.trial_s if plan.mode is Mode.PROTOCOL else plan.settle_timeout_s
        return len(plan.points) * (per_trial + plan.estimate_timeout_s)

    def progress(self) -> str:
        return f"trial {self.runner.index}/{len(self.runner.plan.points)}"

    def close(self) -> None:
        pass


@dataclass
class OptimiseStrategy:
    """The thrust-per-watt optimiser's drive loop, for ``duration_s`` (0: until stopped)."""

    loop: DriveLoop
    duration_s: float = 0.0
    after: str = "stop"
    takes_demand: bool = True
    finished: bool = False
    events: list[Event] = field(default_factory=list)
    _start_t: float | None = None
    _last_status_t: float = -math.inf
    _changed: bool = False

    def started(self) -> bool:
        return self._start_t is not None

    def command(self, t: float) -> Command:
        loop = self.loop
        if self._start_t is None:
            self._start_t = t
        if self.duration_s and t - self._start_t >= self.duration_s and not self.finished:
            self.finished = True
            self._changed = True
            self.events.append(Event("info", f"done after {self.duration_s:g} s: {loop.optimiser.choice}"))
        if self.finished and self.after == "stop":
            loop.halted = True
            loop.state = "ramping down" if loop.state != "stopped" else "stopped"
        cmd = loop.tick(t)
        self.events += [Event("warning", text) for text in loop.events]
        loop.events.clear()
        return cmd

    def add_estimate(self, t: float, e: Estimate) -> bool:
        self.loop.add_estimate(t, e)
        return False  # the status goes out once a second

    def set_demand(self, demand_n: float | None) -> None:
        self.loop.set_demand(demand_n)

    def status_due(self, t: float) -> bool:
        if self._changed or t - self._last_status_t >= 1.0:
            self._changed = False
            self._last_status_t = t
            return True
        return False

    def status(self) -> dict[str, Any]:
        return {"mode": str(ControllerMode.OPTIMISE), "finished": self.finished, **self.loop.status()}

    def planned_s(self) -> float | None:
        return self.duration_s or None

    def progress(self) -> str:
        return f"{self.loop.trials} optimiser trials"

    def close(self) -> None:
        self.loop.close()
