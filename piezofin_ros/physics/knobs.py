"""Knobs: multiplicative (and additive) changes to the model's coefficients at an operating point.

The nominal model of the paper (Eqs. 9-10, 19-20) is ``Knobs()``.  Effects' describing functions
(:mod:`piezofin_ros.physics.effects`) set them as functions of frequency, voltage and amplitude;
the steady state (harmonic balance) and the streaming rig (:class:`~piezofin_ros.rig.simulated.SimulatedRig`)
both read them, so a model fitted by ``piezofin diagnose`` drives the simulator the same way::

    (1 + mass mu) eta'' + (damping 2 zeta wn + drag gamma |eta'|) eta' + stiffness wn^2 eta
        = coupling theta (voltage voltage_scale v)
    i = capacitance C_eq d(voltage v)/dt + loss_conductance (voltage v) + coupling theta eta'
    readings: voltage_gain v, tip_gain u(t - tip_delay_s), current_gain i(t - current_delay_s)
    load cell = thrust_gain (1/2) mass m_v (w_t^2 - U^2 w_x^2) + thrust_bias_n,  U = swim_speed
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from numpy.typing import NDArray

FloatArray = NDArray[Any]


#: The knobs the steady amplitude never reads: only the readings and the current do (see the
#: equations above).  An effect that sets one of these alone (its ``target``) leaves the amplitude
#: as it was, so :func:`~piezofin_ros.physics.model.steady_knobs` reuses the amplitude it solved
#: without it (a fit's columns in the capacitance, the losses and the load cell's gain).
#: ``test/physics/test_solved.py`` holds each to it.
UNREAD_BY_AMPLITUDE = frozenset(
    {
        "capacitance",
        "loss_conductance",
        "thrust_gain",
        "thrust_bias_n",
        "tip_gain",
        "tip_delay_s",
        "current_gain",
        "current_delay_s",
        "current_harmonics_a2",
    }
)


@dataclass(frozen=True)
class Knobs:
    """Multiplicative (and additive) modifications of the model's coefficients, per operating point."""

    stiffness: FloatArray | float = 1.0  # x wn^2
    mass: FloatArray | float = 1.0  # x mu and x m_v (the same added mass, Eq. 20)
    damping: FloatArray | float = 1.0  # x 2 zeta wn w
    drag: FloatArray | float = 1.0  # x gamma
    coupling: FloatArray | float = 1.0  # x theta
    voltage: FloatArray | float = 1.0  # effective / nominal drive voltage (amplifier)
    loss_conductance: FloatArray | float = 0.0  # S, in-phase current not converted to motion
    thrust_gain: FloatArray | float = 1.0  # load cell reading / true thrust
    thrust_bias_n: FloatArray | float = 0.0  # N, load cell offset
    swim_speed: FloatArray | float = 0.0  # m/s, U of Eq. (19)
    current_harmonics_a2: FloatArray | float = 0.0  # A^2, mean square of the current's higher harmonics
    capacitance: FloatArray | float = 1.0  # x C_eq
    voltage_scale: FloatArray | float = 1.0  # the amplifier scales its whole output (a sag, not a clip)
    # the instruments: reading / true value of each channel, and its lag (s)
    voltage_gain: FloatArray | float = 1.0
    tip_gain: FloatArray | float = 1.0
    tip_delay_s: FloatArray | float = 0.0
    current_gain: FloatArray | float = 1.0
    current_delay_s: FloatArray | float = 0.0
