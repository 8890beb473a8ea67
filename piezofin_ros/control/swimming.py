"""How far a fish goes on one charge, by how it drives its fins: the range-per-charge of each
strategy on a fin's model (:mod:`piezofin_ros.physics.swim` for the body and the battery).

A strategy is an operating point of the fins (frequency, voltage).  At each point the model gives
each fin's still-water thrust, its current and ``mean(v i)``; the amplifier turns them into its
supply power; the body's steady speed follows in closed form and the battery's endurance at that
power (plus the hotel load) gives the range.  The strategies:

* ``range``: the point that maximises the range, the power counted in the supply's watts (what the
  suite's controller optimises on a fish: ``watt:=supply``);
* ``range (fin watt)``: the point a controller optimising the fin's ``mean(v i)`` would choose (the
  same objective, the wrong watt), its range then counted as the battery pays it;
* ``resonance, full voltage``: the largest motion (the model's underwater resonance at the highest
  voltage), what a builder without a model does;
* ``paper (5.5 Hz, 800 Vpp)``: the paper's operating point;
* ``grid``: the best of the paper's protocol grid (1-11 Hz x 400/600/800 Vpp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from ..physics.amplifier import Amplifier, watt_of
from ..physics.model import Model
from ..physics.swim import Battery, Body, Swim

FloatArray = NDArray[np.float64]

STRATEGIES = ("range", "range (fin watt)", "resonance, full voltage", "paper (5.5 Hz, 800 Vpp)", "grid")


@dataclass(frozen=True)
class Fish:
    """A fish: its fins' model, its body, its battery and the amplifier between them."""

    model: Model
    body: Body
    battery: Battery
    amplifier: Amplifier
    voltage_pp_max: float = 800.0

    def at(
        self, frequency_hz: FloatArray, voltage_pp: FloatArray, ranges: bool = True
    ) -> dict[str, FloatArray]:
        """Everything a strategy is judged by, at these (broadcast) points (``ranges=False``: without
        the range, which integrates the battery's discharge at each point)."""
        f, v = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
        p = self.model.predict(f, v)
        n = self.body.fins
        thrust0 = np.asarray(p.thrust_n, float)
        speed = self.body.steady_speed(thrust0, f, self.model.fin.L)
        fin_w = n * np.asarray(p.power_w, float)
        supply_w = n * self.amplifier.steady(p.voltage_pp_drive, p.current_rms, p.power_w)
        rng = self.battery.range_m(supply_w, speed) if ranges else np.full(speed.shape, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            energy = np.where(speed > 0, (supply_w + self.battery.hotel_w) / speed, np.inf)
        return {
            "frequency_hz": f,
            "voltage_pp": v,
            "thrust0_n": thrust0,
            "speed_m_s": speed,
            "fin_w": fin_w,
            "supply_w": supply_w,
            "range_m": rng,
            "energy_per_m_j": energy,
            "cost_of_transport": self.body.cost_of_transport(supply_w + self.battery.hotel_w, speed),
        }

    def swim(self, frequency_hz: float, voltage_pp: float) -> Swim:
        r = {
            k: float(np.asarray(x).ravel()[0])
            for k, x in self.at(np.array([frequency_hz]), np.array([voltage_pp])).items()
        }
        return Swim(
            r["frequency_hz"],
            r["voltage_pp"],
            r["thrust0_n"],
            r["speed_m_s"],
            r["supply_w"],
            r["range_m"],
            r["energy_per_m_j"],
            r["cost_of_transport"],
            {"fin_w": r["fin_w"]},
        )

    def best(self, frequencies: FloatArray, voltages: FloatArray, watt: str = "supply") -> Swim:
        """The point of the grid with the longest range, the power counted in ``watt`` (``supply``
        or ``fin``); the range reported is always the battery's."""
        f, v = np.meshgrid(np.asarray(frequencies, float), np.asarray(voltages, float), indexing="ij")
        m = self.at(f, v, ranges=False)  # (the range ranks as speed per watt drawn: one range, at the best)
        power = m["fin_w"] if watt_of(watt).is_fin else m["supply_w"]
        with np.errstate(divide="ignore", invalid="ignore"):
            objective = np.where(m["speed_m_s"] > 0, m["speed_m_s"] / (power + self.battery.hotel_w), -np.inf)
        k = np.unravel_index(int(np.argmax(objective)), objective.shape)
        return self.swim(float(f[k]), float(v[k]))

    def resonance_hz(self, voltage_pp: float, frequencies: FloatArray) -> float:
        """Where the fin moves most at ``voltage_pp`` (its tip velocity's peak), Hz."""
        p = self.model.predict(frequencies, np.full(np.shape(frequencies), voltage_pp))
        return float(np.asarray(frequencies)[int(np.argmax(np.asarray(p.tip_velocity_rms)))])

    def voltage_grid(self) -> FloatArray:
        """The drive amplitudes searched, Vpp: 50 to the limit in steps of 25, or sixteen steps up to
        a limit below 50 (the grid from 50 was empty there: ``swim --voltage-max 30`` crashed)."""
        top = self.voltage_pp_max
        if top >= 50.0:
            return np.arange(50.0, top + 1e-9, 25.0)
        return np.linspace(top / 16, top, 16)

    def _grid_voltages(self) -> FloatArray:
        """The ``grid`` strategy's amplitudes, 400/600/800 Vpp, within the drive's limit."""
        within = [v for v in (400.0, 600.0, 800.0) if v <= self.voltage_pp_max]
        return np.array(within or [self.voltage_pp_max])

    def strategies(self, f_max_hz: float = 30.0) -> dict[str, Swim]:
        """Each of :data:`STRATEGIES` (module docstring)."""
        dense = np.geomspace(1.0, f_max_hz, 240)
        volts = self.voltage_grid()
        top = self.voltage_pp_max
        return {
            "range": self.best(dense, volts, "supply"),
            "range (fin watt)": self.best(dense, volts, "fin"),
            "resonance, full voltage": self.swim(self.resonance_hz(top, dense), top),
            "paper (5.5 Hz, 800 Vpp)": self.swim(5.5, min(800.0, top)),
            "grid": self.best(np.arange(1.0, 12.0), self._grid_voltages(), "supply"),
        }

    def fixed_draw_for(self, gain: float = 0.3) -> float:
        """The fixed draw (the hotel load and the amplifier's quiescent draw together, W) below which
        the ``range`` strategy goes ``gain`` further than ``resonance, full voltage``; NaN if it does
        even at 10 W (bisection in log, to 2 %).

        Above it the fixed draw dominates: the distance per joule grows with the speed, and the
        longest range is the fastest drive, whatever the fins' own watts."""
        dense = np.geomspace(1.0, 30.0, 240)
        volts = self.voltage_grid()
        top = self.voltage_pp_max
        quiet = self.amplifier.without_quiescent()

        def beyond(fixed_w: float) -> float:
            fish = replace(self, battery=replace(self.battery, hotel_w=fixed_w), amplifier=quiet)
            best = fish.best(dense, volts, "supply").range_m
            base = fish.swim(fish.resonance_hz(top, dense), top).range_m
            if base > 0:
                return best / base - 1.0
            return math.inf if best > 0 else -1.0  # (a pack that carries neither: no gain)

        # (up to 10 W, or just below what the pack can deliver at all: a battery takes no more)
        lo, hi = math.log(1e-4), math.log(min(10.0, 0.99 * self.battery.max_power_w()))
        if hi <= lo:
            return math.nan
        if beyond(math.exp(hi)) >= gain:
            return math.nan
        if beyond(math.exp(lo)) < gain:
            return 0.0
        while hi - lo > 0.02:
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if beyond(math.exp(mid)) >= gain else (lo, mid)
        return math.exp(lo)
