"""Plants: the fin as a black box that maps an operating point to thrust and power.

The controller's benchmark and tests need fins that differ from the model the controller
starts from, in the ways the paper says real fins do (see the reading notes):

* ``softening``: the resonance drops with the drive amplitude (electroelastic softening: the
  MFC's stiffness falls with the electric field).  ``wn`` becomes ``wn (1 - softening * Vpp / 800)``,
  so the resonance moves by ``softening`` (e.g. 0.4 = 40 %) at 800 Vpp and proportionally less
  below.  Closed form, like the nominal balance.
* ``loss_tan_delta``: dielectric loss of the piezoceramic, ``P_loss = (1/2) tan(delta) C_eq w V^2``
  (``V`` the voltage amplitude), which the nominal model has not: it is what makes the measured
  thrust per watt peak near resonance.
* ``resonance_scale``: ``f_sc`` times a factor, constant or a function of time (drift).

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

from .fin import Fin
from .steady import harmonic_balance, solve_amplitude

FloatArray = NDArray[Any]
V_REF = 800.0


@dataclass(frozen=True)
class PlantResponse:
    """Steady thrust (N), electrical power (W) and RMS tip velocity (m/s) on a grid."""

    thrust_n: FloatArray
    power_w: FloatArray
    tip_velocity_rms: FloatArray

    @property
    def thrust_per_watt(self) -> FloatArray:
        p = self.power_w
        return np.divide(self.thrust_n, p, out=np.zeros(np.shape(p)), where=p > 0)


@dataclass(frozen=True)
class Noise:
    """Measurement noise of one trial's estimate: relative (1 sigma) plus absolute floors."""

    thrust_rel: float = 0.005
    thrust_abs_n: float = 5e-6
    power_rel: float = 0.005
    power_abs_w: float = 5e-6


@dataclass(frozen=True)
class Plant:
    fin: Fin
    softening: float = 0.0
    loss_tan_delta: float = 0.0
    resonance_scale: float | Callable[[float], float] = 1.0
    noise: Noise = field(default_factory=Noise)
    name: str = "plant"

    def _scale(self, t: float) -> float:
        s = self.resonance_scale
        return float(s(t)) if callable(s) else float(s)

    def steady(self, frequency_hz: ArrayLike, voltage_pp: ArrayLike, t: float = 0.0) -> PlantResponse:
        """Noise-free steady state at time ``t`` (only drift depends on it)."""
        f, v = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
        fin = self.fin.replace(f_sc=self.fin.f_sc * self._scale(t))
        if self.softening == 0.0:
            hb = harmonic_balance(fin, f, v)
            thrust, power, tip = hb.thrust_n, hb.power_w, hb.tip_velocity_rms
        else:
            thrust, power, tip = self._softened(fin, f, v)
        w = 2 * math.pi * f
        power = power + 0.5 * self.loss_tan_delta * self.fin.C_eq * w * (0.5 * v) ** 2
        return PlantResponse(np.asarray(thrust), np.asarray(power), np.asarray(tip))

    def _softened(self, fin: Fin, f: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        w = 2 * math.pi * f
        wn = fin.omega_n * np.maximum(1.0 - self.softening * v / V_REF, 0.05)
        c0 = 2 * fin.zeta * wn * w
        k = 8.0 / (3.0 * math.pi) * fin.gamma * w**2
        amp = solve_amplitude(wn**2 - (1.0 + fin.mu) * w**2, c0, k, fin.theta * 0.5 * v)
        thrust = 0.25 * fin.m_v * (w * fin.phi_tip * amp) ** 2
        power = 0.5 * (c0 + k * amp) * w * amp**2  # = mean(v i): the dissipation of Eq. (9)
        tip = w * fin.phi_tip * amp / math.sqrt(2)
        return thrust, power, tip

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
