"""Plants: the fin as a black box that maps an operating point to thrust and power.

The controller's benchmark and tests need fins that differ from the model the controller
starts from, in the ways the paper says real fins do (see the reading notes).  A plant is a
:class:`~piezofin_ros.physics.model.Model` (a fin plus effects of the one library) with a
resonance that may drift in time and measurement noise:

* ``softening``: the resonance drops with the drive amplitude (electroelastic softening: the
  MFC's stiffness falls with the electric field), the library's ``electroelastic_softening``:
  ``wn`` becomes ``wn (1 - softening * Vpp / 800)``, so the resonance moves by ``softening``
  (e.g. 0.4 = 40 %) at 800 Vpp and proportionally less below;
* ``loss_tan_delta``: dielectric loss of the piezoceramic, ``dielectric_loss``:
  ``P_loss = (1/2) tan(delta) C_eq w V^2`` (``V`` the voltage amplitude), which the nominal model
  has not: it is what makes the measured thrust per watt peak near resonance;
* ``resonance_scale``: the natural frequency times a factor (``resonance_offset``), constant or a
  function of time (drift).

:meth:`Plant.measure` adds measurement noise like the estimator's (relative and absolute).
Everything is vectorised over arrays of frequency and voltage.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..control.response import EstimateNoise, PlantResponse
from ..estimation.estimator import source_of
from ..estimation.selfsense import Calibration, lighthill_thrust, self_sensed_tip
from ..physics.amplifier import PAPER_BENCH, Amplifier, power_in, watt_of
from ..physics.effects import DielectricLoss, Effect, Electroelastic, ResonanceOffset
from ..physics.fin import Fin
from ..physics.model import Model

FloatArray = NDArray[Any]


@dataclass(frozen=True)
class Plant:
    fin: Fin
    softening: float = 0.0
    loss_tan_delta: float = 0.0
    resonance_scale: float | Callable[[float], float] = 1.0
    noise: EstimateNoise = field(default_factory=EstimateNoise)
    name: str = "plant"
    #: any further effects of the library (outside the optimiser's correction: a field-dependent
    #: coupling, extra drag or added mass, an amplifier's sag, ...)
    effects: tuple[Effect, ...] = ()
    #: the amplifier that truly drives it: the supply the plant's meter reads and its true supply watt
    amplifier: Amplifier = PAPER_BENCH

    def _scale(self, t: float) -> float:
        s = self.resonance_scale
        return float(s(t)) if callable(s) else float(s)

    def model(self, t: float = 0.0) -> Model:
        """The fin plus this plant's effects at time ``t`` (only drift depends on it)."""
        return Model(
            self.fin,
            (
                ResonanceOffset(self._scale(t)),
                Electroelastic(self.softening),
                DielectricLoss(self.loss_tan_delta),
                *self.effects,
            ),
        )

    def steady(self, frequency_hz: ArrayLike, voltage_pp: ArrayLike, t: float = 0.0) -> PlantResponse:
        """Noise-free steady state at time ``t``."""
        p = self.model(t).predict(frequency_hz, voltage_pp)
        return PlantResponse(
            np.asarray(p.thrust_n),
            np.asarray(p.power_w),
            np.asarray(p.tip_velocity_rms),
            np.asarray(p.current_rms),
            np.asarray(p.voltage_pp_drive),
        )

    def measure(
        self, frequency_hz: float, voltage_pp: float, t: float, rng: np.random.Generator
    ) -> tuple[float, float]:
        """One trial's noisy ``(thrust N, power W)``."""
        r = self.steady(frequency_hz, voltage_pp, t)
        n = self.noise
        thrust = (
            float(r.thrust_n) * (1 + n.thrust_rel * rng.standard_normal())
            + n.thrust_abs_n * rng.standard_normal()
        )
        power = (
            float(r.power_w) * (1 + n.power_rel * rng.standard_normal())
            + n.power_abs_w * rng.standard_normal()
        )
        return thrust, power


@dataclass(frozen=True)
class Reading:
    """What the controller receives from one trial: the thrust estimate of its source, the power and
    the drive's admittance ``I_1 / V_1`` (S)."""

    thrust_n: float
    power_w: float
    admittance: complex
    power_named_w: float = math.nan  # in the watt asked for (``read``'s ``watt``)
    voltage_pp: float = math.nan  # the drive's, as the voltage monitor reads it


def read(
    plant: Plant,
    frequency_hz: float,
    voltage_pp: float,
    t: float,
    rng: np.random.Generator,
    source: str = "vibrometer",
    fin: Fin | None = None,
    watt: str = "fin",
    amplifier: Amplifier | None = None,
    calibration: Calibration | None = None,
) -> Reading:
    """One trial as ``thrust_estimator`` reports it, with noise: the thrust of ``source`` computed with
    the estimator's fin (``fin``, default the plant's own, i.e. the paper's ``c_m``, ``C_eq`` and
    ``theta`` without the plant's effects): Lighthill on the tip velocity (``vibrometer``), on the
    self-sensed tip velocity (``self``; with the estimator's ``calibration`` where it has one, as
    ``thrust_estimator`` with a ``model``), or the load cell's reading (``loadcell``)."""
    fin = fin or plant.fin
    p = plant.model(t).predict(frequency_hz, voltage_pp)
    n = plant.noise
    power = (
        float(p.power_w) * (1 + n.power_rel * rng.standard_normal()) + n.power_abs_w * rng.standard_normal()
    )
    v_amp = 0.5 * float(np.asarray(p.voltage_pp_drive))  # (as the voltage monitor reads it)
    y = complex(np.asarray(p.admittance))
    y = complex(2.0 * power / v_amp**2, y.imag + n.admittance_rel * abs(y) * rng.standard_normal())
    how = source_of(source)
    if how.self_sensed and calibration is not None:
        tip = self_sensed_tip(fin, y * v_amp, v_amp, 2 * np.pi * frequency_hz, calibration)
        thrust = float(lighthill_thrust(fin, abs(complex(tip)) / np.sqrt(2), calibration, frequency_hz))
    elif how.self_sensed:
        tip = self_sensed_tip(fin, y * v_amp, v_amp, 2 * np.pi * frequency_hz)
        thrust = float(lighthill_thrust(fin, abs(complex(tip)) / np.sqrt(2)))
    else:
        thrust = float(p.thrust_loadcell_n if how.load_cell else lighthill_thrust(fin, p.tip_velocity_rms))
        thrust = thrust * (1 + n.thrust_rel * rng.standard_normal()) + n.thrust_abs_n * rng.standard_normal()
    named = math.nan
    named_watt = watt_of(watt)
    if not named_watt.is_fin:
        # the estimator's watts from the monitors (its own amplifier model for ``supply``); the supply's
        # meter reads the plant's true amplifier (``supply_measured``)
        i_rms = abs(y) * v_amp / math.sqrt(2)
        if named_watt.measured:
            truth = float(
                named_watt.model.steady(2 * v_amp, float(p.current_rms), float(p.power_w), plant.amplifier)
            )
            named = truth * (1 + n.power_rel * rng.standard_normal())
        else:
            named = float(power_in(watt, 2 * v_amp, i_rms, power, amplifier or plant.amplifier))
    return Reading(thrust, power, y, named, 2 * v_amp)
