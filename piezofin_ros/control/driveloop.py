"""The controller's live loop around the optimiser: trials, settling, slew, estimate watchdog."""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from ..estimation.estimator import source_of
from ..physics.amplifier import watt_of
from .evidence import Observation
from .optimise import Optimiser
from .proposal import is_quiet

#: A trial the demand cuts short is learnt from its last window only where that window lies this many
#: sigma off the map (a gross miss, which the fit must hear of, or it proposes the point again); one
#: window of an unfinished trial is noisier than a trial, and learnt always it put a twin's second
#: step 6.5 % fast (M8507-P1, ``bench_fish.py``: +3.2 % before)
CUT_SIGMA = 3.0


@dataclass
class DemandGate:
    """Which demand the loop takes, and when (:class:`DriveLoop`'s docstring): the latest one, at most
    once per ``hold_s``, after a trial was learnt unless it jumps by ``jump`` or waited ``wait_s``."""

    #: a demand is taken at most once per this much time (the latest one): a demand that flips
    #: faster than a trial would move the drive every fit and teach the optimiser nothing
    hold_s: float = 1.0
    #: a demand this far (relative) from the one in force is taken without waiting for a trial
    jump: float = 0.25
    #: nor one that has waited this long for a trial to end, s (20 s until 2026-11-29: a fish holding a
    #: confirmed point runs no trial, and a speed loop's demand rising 15 % above it waited the whole
    #: 20 s; stranger 2 from rest dipped 10 % for 36 s, held after 83 s, 21 s now; 5 s cut trials short)
    wait_s: float = 10.0
    wanted: float | None = None  # the latest demand set
    due: bool = False  # set since the last taken
    queued: bool = False  # taken, its fit not begun: a demand set now queues a new fit
    since: float | None = None  # when the demand waiting was first ready to be weighed
    trials_at: int = -1  # trials learnt when the last demand was taken (-1: none taken yet)
    in_force: float | None = None
    taken_t: float = -math.inf
    #: the voltage cap set (inf: none; :meth:`DriveLoop.set_voltage_cap`), and whether it waits: taken
    #: at the next look, before the demand
    cap: float = math.inf
    cap_due: bool = False

    def want(self, demand_n: float | None) -> None:
        self.wanted = demand_n if demand_n is not None and demand_n > 0 else None
        self.due = True

    def ready(self, t: float, trials: int, mid_trial: bool) -> bool:
        """Whether the demand waiting may be taken now, ``trials`` learnt, a trial half measured or not."""
        if not self.due or self.queued or t - self.taken_t < self.hold_s:
            return False
        if self.since is None:
            self.since = t
        new, old = self.wanted, self.in_force
        jump = (new is None) != (old is None) or (
            new is not None and old is not None and abs(new / old - 1.0) > self.jump
        )
        between = trials > self.trials_at and not mid_trial
        return self.trials_at < 0 or jump or between or t - self.since >= self.wait_s

    def take(self, t: float, trials: int) -> float | None:
        """The demand taken at ``t``."""
        self.due, self.taken_t, self.since = False, t, None
        self.trials_at, self.in_force = trials, self.wanted
        return self.wanted


@dataclass
class DriveLoop:
    """The controller's loop around an :class:`Optimiser`: trials, settling, slew, safety.

    ``tick(t)`` returns the command to send at time ``t``; ``add_estimate(t, e)`` takes each
    running-window estimate.  A trial is settled when two consecutive windows at the point agree
    within ``settle_tolerance`` (or after ``max_windows``); its last window is the observation.
    The commanded voltage moves at most ``slew_vpp_per_s`` and never leaves the limits.  When no
    estimate comes for ``estimate_timeout_s`` at a point the drive has reached, the loop holds that
    point (it takes no new one); after twice that it ramps the drive down to zero (each with a
    message in ``events``), and resumes if they come back.  The loop's own moves (a demand taken
    before the estimator's settling and first window at the last point) restart that clock: they
    starved a live estimator, which the loop then took for a dead one (issue 27: a fish ramped to
    0 V for 30 s after each set-point step).  After three times the timeout with no estimate at all,
    whatever the moves, it holds.

    Stopped for want of estimates, it tries the drive again after ``retry_s`` (doubling each time
    up to 8 times that, back to ``retry_s`` once an estimate comes): the off-commands it sent while
    stopped re-arm a rig whose watchdog tripped (a heartbeat that stalled), which would otherwise
    give no estimate ever again.  ``halted`` (a finished run) never retries.

    Demands are taken (:class:`DemandGate`) at most once per ``hold_s``, the latest one, and at most one
    waits for the fit's thread: a flood of them is a fit a second, not a fit per message. And a demand
    waits for the trial it would cut short: once one is taken, the next is taken after a trial has been
    learnt (and none is half-measured), unless it moves the demand by more than ``jump`` (a new
    set-point) or has waited ``wait_s``. A speed loop's demand moves all the time (its feedback on a noisy
    speed); taken at once, each new demand moved the drive to a new point before its trial ended, no
    trial was ever learnt, and the optimiser held its first guess (the fish of issue 27 swam at 3.4 cm/s
    for 700 s when asked for 5).
    """

    optimiser: Optimiser
    source: str = "self"  # "self" (drive only, as on a fish) or "vibrometer"; the optimiser's too
    slew_vpp_per_s: float = 400.0
    estimate_timeout_s: float = 10.0
    settle_tolerance: float = 0.03
    max_windows: int = 3
    state: str = "driving"  # driving, holding, ramping down, stopped
    target: tuple[float, float] | None = None
    command_v: float = 0.0
    trials: int = 0
    skipped: int = 0  # trials that agreed while a fit ran, replaced by a later one before learnt
    discrepancy: float = math.nan  # self-sensed vs vibrometer thrust, relative, last settled window
    events: list[str] = field(default_factory=list)
    _t_last: float | None = None
    _t_settled_from: float | None = None
    _last_estimate_t: float | None = None
    _windows: list[tuple[float, float]] = field(default_factory=list)
    _partial: tuple[Any, ...] | None = None  # the trial's last window as an observation, till it settles
    background: bool = False  # fit in a worker thread (the node: the heartbeat must not wait)
    _next: tuple[float, float] | None = None
    _pending: list[Future[None]] = field(default_factory=list)  # the fit thread's work, in order
    _executor: ThreadPoolExecutor | None = None
    _learnt: dict[str, Any] | None = None
    retry_s: float = 30.0  # stopped without estimates: drive again after this long (doubling)
    halted: bool = False  # the run is over: stopped stays stopped
    _stopped_since: float | None = None
    _retries: int = 0
    gate: DemandGate = field(default_factory=DemandGate)  # which demand is taken when
    _waiting: tuple[Any, ...] | None = None  # a trial that agreed while a fit ran: learnt next
    _supply_modelled: bool = False  # ranking by the model's supply watt (none measured)

    def __post_init__(self) -> None:
        self.optimiser.source = self.source  # (it reads the same estimate)
        if self.background:
            # the fit's thread is started here, not by the first heartbeat's submit: starting a
            # thread and handing it the GIL cost that heartbeat up to 50 ms (the CI run of stop 33)
            self._worker().submit(lambda: None).result()

    def tick(self, t: float) -> tuple[float, float, float]:
        if self._t_last is None:
            self._t_last = self._last_estimate_t = t
        assert self._last_estimate_t is not None
        dt = max(0.0, t - self._t_last)
        self._t_last = t
        said = self.optimiser.said  # (appended by the fit's thread: taken one at a time)
        while said:
            self.events.append(said.pop(0))
        # the point the finished fit proposed first, then the trial that waited: taken the other way
        # round, a fit slower than a trial (x10 on a loaded machine) kept the drive where it was for as
        # long as trials came, each learnt there (a live fish, 4 to 7 trials at its first point)
        if self.state != "holding":  # (holding: the point stays, whatever the fits propose)
            self._take_next()
        self._submit_demand(t)
        if self.target is None:
            self.target = self.optimiser.propose()
        f, v_target = self.target
        # (a new point needs the estimator's settling and a window from when the drive got there:
        # the estimator is silent only at a point the drive has reached, so that the loop's own moves,
        # a slow fit or a long ramp are not taken for a dead estimator; and blind, whatever the moves)
        blind = t - self._last_estimate_t
        settled = self._t_settled_from
        quiet = 0.0 if settled is None else t - max(self._last_estimate_t, settled)
        if self.state in ("driving", "holding") and quiet > 2 * self.estimate_timeout_s:
            self.state = "ramping down"
            self.events.append(f"no estimate for {quiet:.1f} s at {f:.2f} Hz: ramping the drive down to 0 V")
        elif self.state == "driving" and max(quiet, blind / 3) > self.estimate_timeout_s:
            self.state = "holding"
            why = (
                f"{quiet:.1f} s at {f:.2f} Hz"
                if quiet > self.estimate_timeout_s
                else f"{blind:.1f} s of moves"
            )
            self.events.append(f"no estimate for {why}: holding {f:.2f} Hz, {v_target:.0f} Vpp")
        if self.state == "stopped" and not self.halted and self._stopped_since is not None:
            wait = self.retry_s * 2 ** min(self._retries, 3)
            if t - self._stopped_since >= wait:
                self._retries += 1
                self.state = "driving"
                self._last_estimate_t = t
                self._t_settled_from = None
                self._stopped_since = None
                self.events.append(
                    f"no estimate for {wait:.0f} s with the drive off: driving {f:.2f} Hz again "
                    f"(retry {self._retries}; the off commands re-armed a tripped watchdog)"
                )
        goal = 0.0 if self.state in ("ramping down", "stopped") else v_target
        step = self.slew_vpp_per_s * dt
        self.command_v += min(max(goal - self.command_v, -step), step)
        # (the optimiser's box takes a cap in the fit's thread: the command at once)
        top = min(self.optimiser.limits.voltage_pp_max, self.gate.cap)
        self.command_v = min(max(self.command_v, 0.0), top)
        if self.state == "ramping down" and self.command_v == 0.0:
            self.state = "stopped"
            self._stopped_since = t
        if settled is None and self.command_v == v_target and self.state in ("driving", "holding"):
            self._t_settled_from = t
        return (f, self.command_v, 1.0 if self.command_v > 0 else 0.0)

    def add_estimate(self, t: float, e: Any) -> bool:
        """Use a running-window estimate (an :class:`~piezofin_ros.estimation.estimator.Estimate`)."""
        self._last_estimate_t = t
        self._retries = 0
        if self.state != "driving" and not self.halted:
            self.events.append(f"estimates are back: resuming from {self.state}")
            self.state = "driving"
            self._stopped_since = None
        thrust = getattr(e, source_of(self.source).thrust_field)
        if self.target is None or self._t_settled_from is None:
            return False
        f, _ = self.target
        if e.final or e.t_start < self._t_settled_from or abs(e.frequency_hz - f) > 0.02 * f:
            return False  # a window from before the drive reached this point
        if math.isfinite(e.thrust_n) and math.isfinite(e.thrust_self_n) and e.thrust_n > 0:
            # (at the settled point only: a window over a ramp compares two transients)
            self.discrepancy = e.thrust_self_n / e.thrust_n - 1.0
        power = e.power_w
        if not (math.isfinite(thrust) and math.isfinite(power)):
            return False
        admittance = complex(getattr(e, "admittance_re", math.nan), getattr(e, "admittance_im", math.nan))
        # the point as commanded, which is how the optimiser knows it again (``held`` commands it, its
        # trials group by it): the measured amplitude drifts with the monitor's gain and noise
        named = self._named_watt(e)
        args = (e.t_end, f, self.target[1], thrust, power, admittance, named, e.voltage_pp)
        self._windows.append((thrust, power))
        self._partial = args
        w = self._windows
        agree = len(w) >= 2 and all(
            abs(a / b - 1) <= self.settle_tolerance for a, b in zip(w[-1], w[-2], strict=True)
        )
        if not (agree or self._ends_early(args) or len(w) >= self.max_windows):
            return True
        self._windows, self._partial = [], None
        if self.background:
            # the fit takes a few tenths of a second: off the heartbeat's thread, so that the drive's
            # commands keep coming (fin_sim's watchdog would trip at x10).  While it runs, the latest
            # trial that agreed waits, and goes before any demand (a demand that changes all the
            # time, a speed loop's, would otherwise keep the fits busy and no trial would be learnt);
            # one it replaces is counted only (faster than real time windows come faster than fits)
            if all(job.done() for job in self._pending):
                self._pending.append(self._worker().submit(self._learn, *args))
            else:
                self.skipped += self._waiting is not None
                self._waiting = args
        else:
            self._learn(*args)
            self._take_next()
        return True

    def _ends_early(self, args: tuple[Any, ...]) -> bool:
        """Whether a trial under a demand ends at this window (``observe``'s arguments), before two
        windows agree:

        * a quiet identification trial, at its first window: whoever asked the demand waits for it
          (a fish from rest crawls at a fifth of its demand), and its observation is one window
          either way (a second only shows the first was settled, which below the resonance, after
          the estimator's settling, it is): a fish from rest then swims 6 s sooner;
        * on a fish (a ``trial_overshoot``), a trial whose window the fit reads more than
          ``hold_margin`` below the demand: its speed follows the trial's thrust (a wrong prior's
          trial giving a fifth of the demand had run two more windows)."""
        opt = self.optimiser
        if opt.demand_n is None:
            return False
        t, f, v, thrust, power, admittance, _, drive = args
        o = Observation(t, f, v, thrust, power, opt.source, admittance, voltage_pp_drive=drive)
        if is_quiet(opt, o):
            return True
        return (
            math.isfinite(opt.overshoot_limit)
            and opt.thrust_as_fitted(o) < (1.0 - opt.tuning.hold_margin) * opt.demand_n
        )

    def _named_watt(self, e: Any) -> float:
        """The estimate's watt in the optimiser's ``watt`` (NaN: the fin's); on ``supply_measured``
        with nothing measuring the supply (no supply topic, no battery, or its fixed draw not known
        yet) the amplifier's model is the fallback, said each time it starts and ends."""
        watt = watt_of(self.optimiser.watt)
        named = math.nan if watt.is_fin else e.power(watt.name)
        if watt.measured and not math.isfinite(named):
            named = e.power(watt.model.name)
            if not self._supply_modelled:
                self.events.append(
                    "no measured supply watt in the estimates: ranking by the amplifier model's "
                    "till one comes"
                )
            self._supply_modelled = True
        elif watt.measured and self._supply_modelled:
            self._supply_modelled = False
            self.events.append("the supply watt is measured again: ranking by it")
        return named

    def set_demand(self, demand_n: float | None) -> None:
        """A new demand: taken by the heartbeat (:meth:`tick`) when it is due (class docstring), by
        the fit's thread after the running fit (never beside it).  Demands that come faster than they
        are taken are coalesced: the one waiting takes the latest.  The first is taken at once."""
        if demand_n is not None and not math.isfinite(demand_n):
            return  # (as the optimiser: ignored)
        self.gate.want(demand_n)
        if not self.background and self.gate.trials_at < 0:
            self._submit_demand(self._t_last if self._t_last is not None else 0.0)
            self._take_next()

    def set_voltage_cap(self, voltage_pp: float | None) -> None:
        """Cap the optimiser's voltage (:meth:`.optimise.Optimiser.set_voltage_cap`: a yaw loop's
        offset needs the room), None: no cap.  Taken by the heartbeat as a demand is, before it, by
        the fit's thread; the command never exceeds the cap from the next tick on."""
        capped = self.optimiser.limits.capped(voltage_pp).voltage_pp_max  # (its floor and top: the box's)
        cap = math.inf if voltage_pp is None or math.isnan(voltage_pp) else capped
        if cap != self.gate.cap:  # (a yaw loop sends its cap at 10 Hz: a fit only when it moves)
            self.gate.cap, self.gate.cap_due = cap, True

    def _submit_demand(self, t: float) -> None:
        """The trial waiting, else a new voltage cap, else the latest demand when it is due, to the fit's
        thread (or at once, without one)."""
        if self._waiting is not None:  # (no demand goes before it)
            if all(job.done() for job in self._pending):
                args, self._waiting = self._waiting, None
                self._pending.append(self._worker().submit(self._learn, *args))
            return
        if self.gate.cap_due and not self.gate.queued:
            self.gate.cap_due, cap = False, self.gate.cap
            if self.background:
                self._pending.append(self._worker().submit(self._capped, cap))
            else:
                self._capped(cap)
            return
        if self.gate.ready(t, self.trials, mid_trial=bool(self._windows)):
            # a trial the demand cuts short is learnt from its last window, not lost: one that gave
            # far less than asked slows the fish, the speed loop's demand jumps and cuts it, and,
            # unlearnt, the fit proposed the same point again (a stranger fish, issue 39: 0.5 mN
            # where 2 were asked, twice in 40 s, the speed 40 % down each time)
            cut, self._partial, self._windows = self._partial, None, []
            taken = self.gate.take(t, self.trials)
            if self.background:
                self.gate.queued = True
                self._pending.append(self._worker().submit(self._latest_demand, cut))
            else:
                self._demand(taken, cut)

    def _latest_demand(self, cut: tuple[Any, ...] | None = None) -> None:
        self.gate.queued = False  # (a demand set from now on queues a new fit)
        self._demand(self.gate.wanted, cut)

    def _demand(self, demand_n: float | None, cut: tuple[Any, ...] | None = None) -> None:
        if cut is not None and self.optimiser.surprise(*cut) > CUT_SIGMA:
            self.optimiser.observe(*cut)
            self.trials += 1
        self.optimiser.set_demand(demand_n)
        self._refit_done()

    def _capped(self, voltage_pp: float | None) -> None:
        self.optimiser.set_voltage_cap(voltage_pp)
        self._refit_done()

    def _learn(self, *observation: Any) -> None:
        self.optimiser.observe(*observation)
        self._refit_done()
        self.trials += 1

    def _refit_done(self) -> None:
        """After the optimiser refitted: its next point, and its status for the heartbeat to read
        while the next fit runs."""
        self._next = self.optimiser.propose()
        self._learnt = self.optimiser.status()

    def close(self) -> None:
        """Drop the fits not yet begun (a stopping node's exit waits only for the one running)."""
        if self._executor is not None:
            self._executor.shutdown(wait=False, cancel_futures=True)

    def _worker(self) -> ThreadPoolExecutor:
        if self._executor is None:
            self._executor = ThreadPoolExecutor(1, thread_name_prefix="optimiser")
        return self._executor

    def _take_next(self) -> None:
        """Move to the point the last fit proposed (once it is there)."""
        if not all(job.done() for job in self._pending):
            return
        for job in self._pending:
            job.result()  # (an error in the fit surfaces here, in the heartbeat)
        self._pending.clear()
        new, self._next = self._next, None
        if new is not None and new != self.target:
            self.target = new
            self._t_settled_from = None
            self._windows, self._partial = [], None  # (the windows of the point left)

    def status(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "trials": self.trials,
            "target": self.target,
            "command_vpp": self.command_v,
            "self_vs_vibrometer": self.discrepancy,
            "windows_skipped": self.skipped,
            **(self._learnt if self._learnt is not None else self.optimiser.status()),
        }
