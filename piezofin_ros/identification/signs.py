"""A reversed sensor, found from the physics that fixes the sign conventions (docs/reference.md).

A fin only absorbs power.  The mean electrical power ``mean(v i) = (1/2) Re(V conj(I))`` is
positive, and so is the power into the motion, ``(1/2) Re(F conj(U))`` with the modal force
``F = theta V / phi(L)`` in phase with the drive (Eqs. 9-11, ``theta > 0``, ``phi(L) > 0``): in
every medium and at every frequency ``Re(U / V) >= 0`` and ``Re(I / V) >= 0``, whatever the
damping, the drag or the added mass.  So a rig whose readings break them has a reversed sensor:

* the tip's power negative with the drive's positive: the vibrometer's sign is reversed (it looks at
  the fin from the other side, the sign the paper's Eq. (5) prints);
* the drive's power negative with the tip's positive: the current monitor's sign is reversed;
* both negative: the voltage channel's (or both other sensors').

Each is decided by the weighted majority of the points (:func:`reversed_majority`), so that a few
points near zero power, where noise decides the sign, do not.  Identification
(:mod:`.identify`) and diagnosis (:func:`piezofin_ros.diagnosis.data.conventions`) both decide
with this and say it in these words.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def reversed_majority(power: ArrayLike) -> bool:
    """``sum(p) / sum(|p|) < -0.5`` over the finite ``power``: most of it, by weight, is negative."""
    p = np.asarray(power, float)
    p = p[np.isfinite(p)]
    if p.size == 0:
        return False
    return float(np.sum(p) / max(float(np.sum(np.abs(p))), 1e-300)) < -0.5


@dataclass(frozen=True)
class Signs:
    """Which readings look reversed: ``tip`` (its power), ``power`` (the drive's ``mean(v i)``)."""

    tip: bool
    power: bool
    has_tip: bool = True

    @classmethod
    def check(cls, tip_power: ArrayLike, drive_power: ArrayLike) -> Signs:
        """From the power into the motion (any positive multiple of ``Re(U conj(V))``; NaN without a
        vibrometer) and the drive's mean power, point by point."""
        tp = np.asarray(tip_power, float)
        return cls(reversed_majority(tp), reversed_majority(drive_power), bool(np.any(np.isfinite(tp))))

    @property
    def any(self) -> bool:
        return self.tip or self.power

    @property
    def which(self) -> str:
        """The sensor, in words ("" when none is reversed)."""
        if self.tip and self.power:
            return (
                "the voltage channel's sign is reversed (or both the vibrometer's and the current monitor's)"
            )
        if self.tip:
            return "the vibrometer's sign is reversed (it looks at the fin from the other side)"
        if self.power and self.has_tip:
            return "the current monitor's sign is reversed"
        if self.power:  # no vibrometer (a fish): the phase cannot tell the current from the voltage
            return (
                "the current monitor's sign is reversed (or the voltage channel's: without a vibrometer "
                "they look alike)"
            )
        return ""

    @property
    def symptom(self) -> str:
        """What gave it away."""
        return "tip phase off by about 180 deg" if self.tip else "mean(v i) < 0"
