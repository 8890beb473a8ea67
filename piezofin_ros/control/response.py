"""What a fin gives at its operating points, and how noisy one trial's estimate of it is: the types
the optimiser's map and the benchmark plants share (the optimiser does not import the plants).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..physics.amplifier import Amplifier, power_in, watt_of

FloatArray = NDArray[Any]


@dataclass(frozen=True)
class PlantResponse:
    """Steady thrust (N), electrical power (W) and RMS tip velocity (m/s) on a grid."""

    thrust_n: FloatArray
    power_w: FloatArray
    tip_velocity_rms: FloatArray
    current_rms: FloatArray | None = None  # A (what the other watts need; None: not modelled)
    voltage_pp: FloatArray | None = None  # V, the drive the fin receives

    @property
    def thrust_per_watt(self) -> FloatArray:
        p = self.power_w
        return np.divide(self.thrust_n, p, out=np.zeros(np.shape(p)), where=p > 0)

    def power(self, watt: str, amplifier: Amplifier) -> FloatArray:
        """The power in ``watt`` (the supply through ``amplifier``)."""
        if watt_of(watt).is_fin or self.current_rms is None or self.voltage_pp is None:
            return np.asarray(self.power_w, float)
        return power_in(watt, self.voltage_pp, self.current_rms, self.power_w, amplifier)


@dataclass(frozen=True)
class EstimateNoise:
    """Measurement noise of one trial's estimate: relative (1 sigma) plus absolute floors."""

    thrust_rel: float = 0.005
    thrust_abs_n: float = 5e-6
    power_rel: float = 0.005
    power_abs_w: float = 5e-6
    admittance_rel: float = 0.001  # of |I_1 / V_1|, on its susceptance
