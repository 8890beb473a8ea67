r"""Self-sensing: the fin's motion from its drive's voltage and current alone.

By Eq. (10) the drive current is the capacitive current, any loss current, and the motional current
``theta deta/dt``.  A fish with no vibrometer takes the tip velocity from the rest:

    ``U_k = (phi(L) / (theta q)) (I_k - (G + j k w C_eq c) V_k)``

for each odd harmonic ``k``, where ``c`` scales the capacitance, ``G`` is the loss conductance (the
in-phase current of dielectric loss and leakage, which does no motion) and ``q`` scales the coupling
at this field.  With ``c = q = 1`` and ``G = 0`` this is the paper's Eq. (10); each error in them goes
straight into the self-sensed thrust (dielectric loss of tan delta 0.05 read as motion: +30 % near
resonance on M8528-P1).  :class:`Calibration` holds them, and the added-mass factor of ``c_m`` that
enters Lighthill's ``m_v``.  ``thrust_estimator`` takes them from a loaded model (its ``model``
parameter); every estimate carries the drive's admittance ``I_1 / V_1``, from which they can also
be fitted online.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import EstimationError
from ..physics.fin import Fin

FloatArray = NDArray[Any]


@dataclass(frozen=True)
class Calibration:
    """How the drive's current and the thrust differ from the paper's fin (1/0: the paper's)."""

    capacitance: float | FloatArray = 1.0  # x C_eq
    conductance_s: float | FloatArray = 0.0  # S, the loss conductance at the drive frequency
    coupling: float | FloatArray = 1.0  # x theta, at this field
    mass: float | FloatArray = 1.0  # x c_m: the added mass of m_v (Eq. 21)
    mass_kc: float | FloatArray = 0.0  # and x (1 + mass_kc KC + mass_kc2 KC^2) at the tip's motion
    mass_kc2: float | FloatArray = 0.0

    def mass_at(self, fin: Fin, tip_amplitude_m: Any) -> FloatArray:
        """The factor on ``c_m`` at a tip amplitude ``X`` (m): with the Keulegan-Carpenter number
        ``KC = 2 pi X / b``, ``mass x (1 + mass_kc KC + mass_kc2 KC^2)``, as the time domain has it."""
        kc = 2 * np.pi * np.asarray(tip_amplitude_m, float) / fin.b
        return np.asarray(self.mass) * (1 + (np.asarray(self.mass_kc) + np.asarray(self.mass_kc2) * kc) * kc)

    @classmethod
    def of_law(cls, law: Any) -> Calibration:
        """A model's calibration at one operating point, from its time-domain law
        (:meth:`piezofin_ros.physics.model.Model.law`)."""
        names = ("capacitance", "loss_conductance", "coupling", "mass", "mass_kc", "mass_kc2")
        return cls(*(float(getattr(law, n)) for n in names))


NOMINAL = Calibration()


def calibrated_by(model: Any) -> Callable[[float, float], Calibration]:
    """The self-sensing's calibration at any (frequency Hz, Vpp) by a model
    (:class:`~piezofin_ros.physics.model.Model`: the fin file's, an augmented one, or the
    controller's fit)."""

    def calibrate(frequency_hz: float, voltage_pp: float) -> Calibration:
        return Calibration.of_law(model.law(frequency_hz, voltage_pp))

    return calibrate


def self_sensed_tip(
    fin: Fin, current: Any, voltage: Any, omega: Any, calibration: Calibration = NOMINAL
) -> FloatArray:
    """Tip-velocity phasors from the current and voltage phasors at angular frequencies ``omega``."""
    cal = calibration
    static = cal.conductance_s + 1j * np.asarray(omega) * fin.C_eq * cal.capacitance
    motional = np.asarray(current) - static * np.asarray(voltage)
    return np.asarray(fin.phi_tip / (fin.theta * np.asarray(cal.coupling)) * motional)


def lighthill_thrust(
    fin: Fin, tip_rms: Any, calibration: Calibration = NOMINAL, frequency_hz: Any = None
) -> FloatArray:
    """Lighthill's mean thrust ``(1/2) m_v u^2`` (no swimming speed) for an RMS tip velocity ``u`` of
    a sine at ``frequency_hz``, which sets its amplitude for a calibration whose added mass grows with
    it (``mass_kc``, ``mass_kc2``): required then, an :class:`EstimationError` without it."""
    if frequency_hz is None:
        if np.any(np.asarray(calibration.mass_kc) != 0) or np.any(np.asarray(calibration.mass_kc2) != 0):
            raise EstimationError("lighthill_thrust: an added mass that grows with KC needs frequency_hz")
        frequency_hz = np.inf
    amplitude = np.sqrt(2) * np.asarray(tip_rms) / (2 * np.pi * np.asarray(frequency_hz, float))
    mass = calibration.mass_at(fin, amplitude)
    return np.asarray(0.5 * fin.m_v * mass * np.asarray(tip_rms) ** 2)
