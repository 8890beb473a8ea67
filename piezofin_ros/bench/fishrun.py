"""A fish swimming in fish time, without ROS: the fish stack's science wired as its nodes wire it.

:func:`swim_run` steps what ``launch/fish.launch.py`` runs, each part the same code the node
adapts: the fin (a :class:`~.plants.Plant`, its steady response at the drive's point), the body and
the battery (:class:`~piezofin_ros.rig.fish.FreeSwimmer`, Eq. 19's ``U`` term on the thrust), the
speed sensor's noise, the estimator's segments and running windows with its default settings
(the drive's voltage and current alone: the self-sensed thrust and the supply watt,
:func:`~.plants.read`), the speed loop with its deadband
(:class:`~.speedloop.SpeedLoop`, :class:`~.speedloop.DemandGate`) and a drive:

* :class:`OptimisingDrive`: the controller (:class:`~.driveloop.DriveLoop` around an
  :class:`~.optimise.Optimiser`), its demand from the speed loop;
* :class:`FixedDrive`: one operating point whatever the speed (the fixed drive a builder starts
  with; no speed loop can move it);
* :class:`VoltageDrive`: a fixed frequency, the voltage that gives the speed loop's demand on the
  nominal model (``T`` goes as ``V^2``), the loop's feedback closing what the model misses (what a
  builder with a speed loop and no optimiser would write);
* :class:`TableDrive`: the paper's protocol grid measured once in the tank (load cell, supply
  meter), then the cheapest point of it whose thrust meets the speed loop's demand.

:func:`drive_for` builds each of :data:`STRATEGIES`.

What it leaves out, against the live stack: the time-domain waveform within a block (the fin's
steady response replaces it: the body's time constant, 3-9 s, is long against a stroke), DDS and
the executors' timing (the fit is instantaneous here, a few tenths of a second there).  The
benchmark (``benchmarks/bench_fish.py``) and the README's figure run it; the live stack's test
checks the same behaviour under the real ``ros2`` CLI.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, Protocol

import numpy as np
from numpy.typing import NDArray

from ..control.correction import Correction
from ..control.driveloop import DriveLoop
from ..control.optimise import Observation, OperatingBox, Optimiser
from ..control.speedloop import DemandGate, SpeedLoop, SpeedLoopConfig
from ..errors import ControlError
from ..estimation.estimator import Estimate, EstimatorConfig
from ..estimation.selfsense import Calibration
from ..physics.amplifier import Amplifier
from ..physics.model import Model
from ..physics.swim import Battery, Body, thrust_at_speed
from ..rig.fish import FreeSwimmer
from .plants import Plant, read

FloatArray = NDArray[np.float64]

#: the speed loop's period (s), as the node's default ``rate_hz``
LOOP_DT_S = 0.1
#: The fish's controller (``config/fish.yaml``'s ``demand_margin_z`` and ``trial_overshoot``; a test
#: checks they agree).  Its demand comes from a speed loop, which closes on the speed: a margin on
#: the thrust only makes the fish fast (2 sigma of a 16 % self-sensing bound: +19 % of thrust), and
#: the loop's feedback takes what the self-sensing misses.  And a trial's thrust moves the speed: no
#: trial at a measured point more than 10 % above the demand (with drag as U^2, 5 % of speed).
FISH_DEMAND_MARGIN_Z = 0.0
FISH_TRIAL_OVERSHOOT = 0.1


class Drive(Protocol):
    """What drives the fin: the point at each tick, the windows it learns from, the demands."""

    def tick(self, t: float) -> tuple[float, float]: ...
    def add_estimate(self, t: float, e: Estimate) -> None: ...
    def set_demand(self, demand_n: float) -> None: ...


@dataclass
class FixedDrive:
    """One operating point, always (the speed loop's demands are ignored); the voltage slews to
    ``_target`` (the subclasses move it, from 0 V until their first demand)."""

    frequency_hz: float
    voltage_pp: float
    slew_vpp_per_s: float = 400.0
    _v: float = 0.0
    _t: float | None = None
    takes_demand: ClassVar[bool] = False

    def __post_init__(self) -> None:
        self._target = 0.0 if self.takes_demand else self.voltage_pp

    def tick(self, t: float) -> tuple[float, float]:
        dt = 0.0 if self._t is None else t - self._t
        self._t = t
        step = self.slew_vpp_per_s * dt
        self._v += min(max(self._target - self._v, -step), step)
        return self.frequency_hz, self._v

    def add_estimate(self, t: float, e: Estimate) -> None:
        pass

    def set_demand(self, demand_n: float) -> None:
        pass


@dataclass
class VoltageDrive(FixedDrive):
    """A fixed frequency, the voltage that gives the demand on ``thrust_at_max_n`` (the model's thrust
    there at ``voltage_pp``, the most it may apply): ``V = V_max sqrt(T_d / T_max)``."""

    thrust_at_max_n: float = math.nan
    takes_demand: ClassVar[bool] = True

    def set_demand(self, demand_n: float) -> None:
        ratio = max(demand_n, 0.0) / self.thrust_at_max_n
        self._target = min(self.voltage_pp * math.sqrt(ratio), self.voltage_pp)  # (V_max: ``voltage_pp``)


@dataclass
class TableDrive(FixedDrive):
    """The cheapest of measured points ``(f, V, thrust N, power W)`` whose thrust meets the demand
    (the most thrust when none does); it moves only when the demand does."""

    table: tuple[tuple[float, float, float, float], ...] = ()
    takes_demand: ClassVar[bool] = True

    def set_demand(self, demand_n: float) -> None:
        meets = [p for p in self.table if p[2] >= demand_n]
        f, v, _, _ = min(meets, key=lambda p: p[3]) if meets else max(self.table, key=lambda p: p[2])
        self.frequency_hz, self._target = f, v


@dataclass
class OptimisingDrive:
    """The controller: a :class:`DriveLoop` (fits in the caller's thread) around an optimiser."""

    optimiser: Optimiser
    loop: DriveLoop = field(init=False)

    def __post_init__(self) -> None:
        self.loop = DriveLoop(self.optimiser, self.optimiser.source)

    def tick(self, t: float) -> tuple[float, float]:
        f, v, _ = self.loop.tick(t)
        return f, v

    def add_estimate(self, t: float, e: Estimate) -> None:
        self.loop.add_estimate(t, e)

    def set_demand(self, demand_n: float) -> None:
        self.loop.set_demand(demand_n)


@dataclass
class Trace:
    """A run, sampled every ``LOOP_DT_S`` (SI; ``thrust_n`` per fin, in truth at the body's speed)."""

    t: FloatArray
    setpoint_m_s: FloatArray
    speed_m_s: FloatArray
    demand_n: FloatArray
    thrust_n: FloatArray
    thrust_estimate_n: FloatArray  # the estimator's self-sensed thrust (the fin file's calibration)
    thrust_fitted_n: FloatArray  # the same window as the optimiser's fit reads it (NaN: no optimiser)
    frequency_hz: FloatArray
    voltage_pp: FloatArray
    supply_w: FloatArray  # the fins' amplifier draw (the hotel load on top)
    soc: FloatArray
    distance_m: FloatArray
    energy_j: FloatArray  # from the battery: supply and hotel
    events: list[str] = field(default_factory=list)

    def settling_s(self, t_step: float, t_end: float, band: float = 0.05) -> float:
        """Time from ``t_step`` until the speed stays within ``band`` of the set-point (in truth) up to
        ``t_end``; inf if it never does."""
        sel = (self.t >= t_step) & (self.t < t_end)
        t, u, s = self.t[sel], self.speed_m_s[sel], self.setpoint_m_s[sel]
        outside = np.abs(u - s) > band * np.maximum(s, 1e-9)
        if not outside.any():
            return 0.0
        last = int(np.flatnonzero(outside)[-1])
        return math.inf if last == len(t) - 1 else float(t[last + 1] - t_step)

    def held_s(
        self, t_step: float, t_end: float, band: float = 0.05, minute_s: float = 60.0, share: float = 0.95
    ) -> float:
        """Time from ``t_step`` until the speed is held as a fish's goal asks: within ``band`` of the
        set-point then, its mean over every ``minute_s`` after within ``band``, and at least ``share``
        of the time after within ``band`` (in truth, up to ``t_end``, with a whole minute left to
        judge); inf if never.  Never earlier than the speed's first entry into the band, and never
        later than :meth:`settling_s` where a minute is left after it (from there every sample is
        within the band): a trial that puts the speed 6 % off for 4 s after ten minutes within 1 % is
        no unsettled fish."""
        sel = (self.t >= t_step) & (self.t < t_end)
        t, u, s = self.t[sel], self.speed_m_s[sel], self.setpoint_m_s[sel]
        n = len(t)
        w = round(minute_s / float(t[1] - t[0])) if n > 1 else n + 1
        if n < w:
            return math.inf
        err = u / np.maximum(s, 1e-12) - 1.0
        inside = np.abs(err) <= band
        c = np.concatenate([[0.0], np.cumsum(err)])
        minutes = np.abs((c[w:] - c[:-w]) / w) <= band  # (the minute from each sample on)
        bad = np.flatnonzero(~minutes)
        first = 0 if bad.size == 0 else int(bad[-1]) + 1  # every minute from here on is within
        after = np.cumsum(inside[::-1])[::-1] / np.arange(n, 0, -1)  # (share within, from each sample)
        i = np.arange(n)
        ok = np.flatnonzero(inside & (i >= first) & (i <= n - w) & (after >= share))
        return math.inf if ok.size == 0 else float(t[ok[0]] - t_step)

    def cuts(
        self, t_step: float, t_end: float, below: float = 0.9, least_s: float = 1.0
    ) -> list[tuple[float, float, float]]:
        """Where a trial cut the thrust while swimming (issue 39's goal: none by more than 10 % below
        the demand): each stretch from ``t_step`` to ``t_end``, once the speed has first reached half
        its set-point, where the thrust in truth stays under ``below`` times the speed loop's demand
        for ``least_s`` or longer; as (its start after ``t_step``, its length, the least share of the
        demand in it), s, s, 1.  None where the demand is not known (NaN)."""
        sel = (self.t >= t_step) & (self.t < t_end)
        t, u, s = self.t[sel], self.speed_m_s[sel], self.setpoint_m_s[sel]
        demand, thrust = self.demand_n[sel], self.thrust_n[sel]
        swimming = np.flatnonzero(u >= 0.5 * s)
        if swimming.size == 0:
            return []
        share = thrust / np.where(demand > 0, demand, np.nan)
        low = np.zeros(t.size, bool)
        low[swimming[0] :] = share[swimming[0] :] < below  # (NaN: not judged)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], low.astype(np.int8), [0]])))
        out = []
        for a, b in zip(edges[::2], edges[1::2], strict=True):  # (each stretch [a, b))
            length = float(t[b - 1] - t[a])
            if length >= least_s:
                out.append((float(t[a] - t_step), length, float(np.min(share[a:b]))))
        return out

    def mean(self, name: str, t0: float, t1: float) -> float:
        sel = (self.t >= t0) & (self.t < t1)
        return float(np.mean(getattr(self, name)[sel]))

    def energy_per_m(self, t0: float, t1: float) -> float:
        """The battery's joules per metre between ``t0`` and ``t1``."""
        i0, i1 = np.searchsorted(self.t, [t0, t1])
        i1 = min(i1, len(self.t) - 1)
        d = self.distance_m[i1] - self.distance_m[i0]
        return float((self.energy_j[i1] - self.energy_j[i0]) / d) if d > 0 else math.inf


def _window(
    plant: Plant,
    fin_of_estimator: Any,
    amplifier: Amplifier,
    f: float,
    v: float,
    t0: float,
    t1: float,
    rng: np.random.Generator,
    U: float,
    estimator_model: Model | None = None,
    meter: np.random.Generator | None = None,
) -> Estimate:
    """The estimator's window ``[t0, t1)`` at the drive's point: self-sensed thrust (calibrated by
    ``estimator_model`` where the estimator has one) and the watts (the supply as its meter reads it,
    the battery's, with ``meter``'s noise)."""
    cal = None if estimator_model is None else Calibration.of_law(estimator_model.law(f, v))
    r = read(plant, f, v, t1, rng, "self", fin_of_estimator, "supply", amplifier, cal)
    measured = math.nan
    if meter is not None:
        measured = read(plant, f, v, t1, meter, "self", fin_of_estimator, "supply_measured").power_named_w
    nan = dict.fromkeys((x.name for x in fields(Estimate)), math.nan)
    return Estimate(
        **{
            **nan,
            "t_start": t0,
            "t_end": t1,
            "final": 0.0,
            "frequency_hz": f,
            "voltage_pp": r.voltage_pp,  # (as the monitor reads it)
            "power_w": r.power_w,
            "thrust_self_n": r.thrust_n,
            "swim_speed_m_s": U,
            "admittance_re": r.admittance.real,
            "admittance_im": r.admittance.imag,
            "power_supply_w": r.power_named_w,
            "power_supply_measured_w": measured,
        }
    )


def _as_fitted(drive: Drive, e: Estimate, voltage_pp: float) -> float:
    """An estimate's self-sensed thrust as an optimising drive's fit reads it, at the point commanded
    (``voltage_pp``); NaN for other drives."""
    if not isinstance(drive, OptimisingDrive):
        return math.nan
    opt = drive.optimiser
    o = Observation(
        e.t_end,
        e.frequency_hz,
        voltage_pp,
        e.thrust_self_n,
        e.power_w,
        source=opt.source,
        admittance=complex(e.admittance_re, e.admittance_im),
        voltage_pp_drive=e.voltage_pp,
    )
    return opt.thrust_as_fitted(o)


def swim_run(
    plant: Plant,
    body: Body,
    drive: Drive,
    schedule: Sequence[tuple[float, float]],
    duration_s: float,
    battery: Battery | None = None,
    amplifier: Amplifier | None = None,
    loop_config: SpeedLoopConfig | None = None,
    deadband: float = 0.03,
    speed_noise_m_s: float = 0.002,
    seed: int = 0,
    estimator_model: Model | None = None,
    speed_bias_m_s: float = 0.0,
    measured_supply: bool = False,
    told_body: Body | None = None,
    calibrate_estimator: bool = True,
) -> Trace:
    """Swim for ``duration_s`` of fish time from rest; ``schedule``: (time, set-point m/s) steps.

    ``plant`` is the fin in truth (its amplifier the one that drains the battery: ``amplifier``
    overrides it); the estimator uses the plant's nominal fin (the paper's ``C_eq``, ``theta``,
    ``c_m``), as the live estimator its fin file, or the calibration of ``estimator_model`` (the
    live estimator's ``model``: the prior the fish is given, right or wrong).  The speed sensor
    reads ``speed_bias_m_s`` high besides its noise; ``measured_supply``: the estimates carry the
    supply watt as the fish's battery measures it (the true amplifier's draw, with a meter's noise).
    ``told_body``: the body the speed loop is told, where it is not the one that swims.
    ``calibrate_estimator``: the estimator's self-sensing follows an optimising drive's fit once the
    corrected model fits its trials (the live estimator's ``calibration_from_controller``).
    """
    amp = amplifier or plant.amplifier
    rng = np.random.default_rng(seed)
    swimmer = FreeSwimmer(body, plant.fin.L, battery, speed_noise_m_s, seed)
    loop = SpeedLoop(told_body or body, loop_config or SpeedLoopConfig())
    gate = DemandGate(deadband)
    steps = sorted(schedule)
    n = round(duration_s / LOOP_DT_S)
    out = {k: np.full(n, np.nan) for k in Trace.__annotations__ if k != "events"}
    window_start, point, fitted = 0.0, (math.nan, math.nan), math.nan
    followed: Correction | None = None  # (the fit the estimator's calibration follows)
    fitted_from: tuple[float, Model] | None = None  # (and the fin time it applies from)
    estimator = EstimatorConfig()
    steady_at, thrust0, supply = (math.nan, math.nan), 0.0, 0.0
    model = plant.model()
    meter = np.random.default_rng(seed + 1) if measured_supply else None
    events: list[str] = []
    for k in range(n):
        t = k * LOOP_DT_S
        while steps and steps[0][0] <= t:
            said = loop.set_setpoint(steps.pop(0)[1])
            events.append(f"{t:.1f} s: set-point {loop.setpoint_m_s:.3g} m/s" + (f": {said}" if said else ""))
        f, v = drive.tick(t)
        # the estimator's segments: a drive that moves starts a new one, whose first ``settle_s`` is
        # skipped; then a running window every ``window_s`` (a drive that never rests has none)
        if (f, v) != point:
            point, window_start = (f, v), t + estimator.settle_s
        elif v > 0 and t - window_start >= estimator.window_s - 1e-9:
            if fitted_from is not None and window_start >= fitted_from[0]:  # (windows from the fit's time)
                estimator_model = fitted_from[1]
            e = _window(
                plant, plant.fin, amp, f, v, window_start, t, rng, swimmer.speed_m_s, estimator_model, meter
            )
            loop.estimate(t, e.thrust_self_n, e.t_end - e.t_start)
            drive.add_estimate(t, e)
            fitted = _as_fitted(drive, e, v)
            window_start = t
            if isinstance(drive, OptimisingDrive) and calibrate_estimator:
                # (the controller's ``controller/model``: the estimator calibrated by the fitted fin)
                c = drive.optimiser.fitted_correction()
                if c is not None and c is not followed:
                    followed, fitted_from = c, (t, c.model(drive.optimiser.fin))
        if v > 0:
            if (f, v) != steady_at:  # (a drive at rest is one model evaluation, not one a tick)
                p = model.predict(f, v)
                steady_at = (f, v)
                thrust0 = float(p.thrust_n)
                supply = float(amp.steady(p.voltage_pp_drive, p.current_rms, p.power_w))
            thrust = float(thrust_at_speed(thrust0, f, plant.fin.L, swimmer.speed_m_s))
        else:
            thrust, supply = 0.0, 0.0
        swimmer.advance(LOOP_DT_S, thrust, f, supply)
        loop.measure(t, swimmer.speed_reading() + speed_bias_m_s)
        demand = loop.update(t)
        events += [f"{t:.1f} s: {said}" for said in loop.widened]
        loop.widened.clear()
        if gate.due(t, demand):
            drive.set_demand(demand)
        out["t"][k], out["setpoint_m_s"][k], out["speed_m_s"][k] = t, loop.setpoint_m_s, swimmer.speed_m_s
        out["demand_n"][k], out["thrust_n"][k] = demand, thrust
        out["thrust_estimate_n"][k] = loop.thrust_estimate_n
        out["thrust_fitted_n"][k] = fitted
        out["frequency_hz"][k], out["voltage_pp"][k], out["supply_w"][k] = f, v, supply * body.fins
        out["soc"][k], out["distance_m"][k], out["energy_j"][k] = (
            swimmer.soc,
            swimmer.distance_m,
            swimmer.energy_j,
        )
    if isinstance(drive, OptimisingDrive):
        events += drive.loop.events
    return Trace(**out, events=events)  # type: ignore[arg-type]


#: The benchmark's drives (:func:`drive_for`).
STRATEGIES = (
    "ours (supply watt)",
    "ours (fin watt)",
    "resonance, voltage from the loop",
    "grid, point from the loop",
    "resonance, full voltage",
    "paper (5.5 Hz, 800 Vpp)",
)


#: The fish stack as ``config/fish.yaml`` runs it: ranking by the supply watt its battery measures.
MEASURED = "ours (measured supply watt)"

#: The optimising drives and the watt each ranks by (a name is a label, never parsed).
OURS = {"ours (supply watt)": "supply", "ours (fin watt)": "fin", MEASURED: "supply_measured"}


def drive_for(
    name: str,
    known: Model,
    plant: Plant,
    amplifier: Amplifier,
    limits: OperatingBox | None = None,
) -> Drive:
    """The drive of strategy ``name`` (:data:`STRATEGIES`): ``known`` is the model the fish's builder
    has (the controller's, the baselines' resonance), ``plant`` the fin in truth (what the grid's
    tank campaign measures), ``amplifier`` the fish's (what the optimiser's supply watt models)."""
    box = limits or OperatingBox(1.0, 30.0, 50.0, 800.0)
    top = box.voltage_pp_max
    freqs = np.geomspace(box.frequency_min_hz, box.frequency_max_hz, 400)
    res = float(freqs[int(np.argmax(known.predict(freqs, np.full_like(freqs, top)).tip_velocity_rms))])
    if name in OURS:
        opt = Optimiser(
            known.fin,
            box,
            top,
            None,
            source="self",
            watt=OURS[name],
            amplifier=amplifier,
            model=known,
            demand_margin_z=FISH_DEMAND_MARGIN_Z,
            trial_overshoot=FISH_TRIAL_OVERSHOOT,
        )
        return OptimisingDrive(opt)
    if name == "resonance, voltage from the loop":
        return VoltageDrive(res, top, thrust_at_max_n=float(known.predict(res, top).thrust_n))
    if name == "grid, point from the loop":
        f, v = np.meshgrid(np.arange(1.0, 12.0), np.array([400.0, 600.0, 800.0]))
        r = plant.steady(f.ravel(), v.ravel())
        supply = r.power("supply", plant.amplifier)
        table = tuple(
            (float(a), float(b), float(c), float(d))
            for a, b, c, d in zip(f.ravel(), v.ravel(), np.ravel(r.thrust_n), np.ravel(supply), strict=True)
        )
        return TableDrive(float(f.ravel()[0]), top, table=table)
    if name == "resonance, full voltage":
        return FixedDrive(res, top)
    if name == "paper (5.5 Hz, 800 Vpp)":
        return FixedDrive(5.5, min(800.0, top))
    raise ControlError(f"unknown strategy {name!r}: one of {', '.join((*STRATEGIES, MEASURED))}")
