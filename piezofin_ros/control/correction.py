"""The corrected model: how a real fin differs from its model, as effects of the one library.

:class:`Correction` holds the nine fitted numbers; :data:`PARAMS` declares each once (the library's
effect and parameter it is, its coordinates and prior for the fit), and the correction's model is
built from that table.  A new correction is one row in :data:`PARAMS` and one field of
:class:`Correction`; the two are checked against each other at import.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ControlError
from ..estimation.selfsense import Calibration
from ..physics.effects import (
    AddedMassOffset,
    CapacitanceOffset,
    DielectricLoss,
    DragOffset,
    Effect,
    Electroelastic,
    FieldCoupling,
    Leakage,
    LoadcellGain,
    ResonanceOffset,
)
from ..physics.fin import Fin
from ..physics.model import Model, Prediction
from .lsq import forward_differences
from .response import PlantResponse

FloatArray = NDArray[Any]


@dataclass(frozen=True)
class Correction:
    """How the real fin differs from the model (1/0 = the nominal model): effects of the one library
    fitted on top of the base model, and a load cell's gain (its reading over the model's thrust)."""

    resonance_scale: float = 1.0  # natural frequency x
    added_mass: float = 1.0  # c_m x
    softening: float = 0.0  # resonance x (1 - softening Vpp / 800)
    drag_scale: float = 1.0  # c_d x
    coupling_k: float = 0.0  # theta x (1 + k Vpp / 800)
    loss_tan_delta: float = 0.0
    leakage_us: float = 0.0  # a conductance beside the piezo, uS: a current in phase with the voltage
    capacitance: float = 1.0  # C_eq x
    thrust_gain: float = 1.0

    base: Model | None = None  # a diagnosed model (fin + effects) the correction applies on top of

    def fitted(self) -> dict[str, float]:
        """The fitted numbers (for a status message: plain JSON, without the base model)."""
        return {p.name: float(getattr(self, p.name)) for p in PARAMS}

    @classmethod
    def of_fitted(cls, values: Any, base: Model | None = None) -> Correction:
        """The correction of :meth:`fitted`'s numbers (from another process: each one named, a finite
        number within the range the fit allows it, or one :class:`ControlError` saying which)."""
        if not isinstance(values, dict) or set(values) != {p.name for p in PARAMS}:
            names = ", ".join(p.name for p in PARAMS)
            raise ControlError(f"a correction names exactly {names}")
        out = {}
        for p in PARAMS:
            x, (lo, hi) = values[p.name], p.bounds()
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                raise ControlError(f"correction {p.name} = {x!r}: not a finite number")
            at = x if not p.log else math.log(x) if x > 0 else -math.inf  # (in fit coordinates)
            if not lo <= at <= hi:
                low, high = (math.exp(lo), math.exp(hi)) if p.log else (lo, hi)
                raise ControlError(f"correction {p.name} = {x!r}: outside [{low:.3g}, {high:.3g}]")
            out[p.name] = float(x)
        return cls(**out, base=base)

    def model(self, fin: Fin) -> Model:
        """The base model (``fin`` without one) plus the correction's effects (a load cell's gain
        describes the rig, not the fin: :meth:`response` applies it)."""
        base = self.base if self.base is not None else Model(fin)
        return base + tuple(p.effect(**{p.param: getattr(self, p.name)}) for p in PARAMS if p.of_fin)

    def predict(self, fin: Fin, f: Any, v: Any) -> Prediction:
        return self.model(fin).predict(f, v)

    def response(self, fin: Fin, f: Any, v: Any) -> PlantResponse:
        # (the load-cell effects of a base describe the rig, not the fin: the thrust is Lighthill's)
        p = self.predict(fin, f, v)
        return PlantResponse(
            p.thrust_n * self.thrust_gain, p.power_w, p.tip_velocity_rms, p.current_rms, p.voltage_pp_drive
        )

    def calibration(self, fin: Fin, f: Any, v: Any) -> Calibration:
        """The self-sensing's calibration at these points (:mod:`piezofin_ros.estimation.selfsense`)."""
        law = self.model(fin).law(f, v)
        return Calibration(
            law.capacitance, law.loss_conductance, law.coupling, law.mass, law.mass_kc, law.mass_kc2
        )


# The fitted parameters: each one of the library's declared parameters, fitted within its range
# there (narrowed where the optimiser knows more), a small margin inside the bounds (exp(log(x)) may
# round across them).  The prior mean is the nominal fin (0 in fit coordinates).  The stiffness may
# move 30 % (a fin that drifts, a warm day): the quiet identification trial below resonance measures
# it where a vibrometer or a load cell is there; so a resonance that moves in water is read as added
# mass (the in-water resonance reveals c_m), and with it every Lighthill thrust; the softening
# separates what moves with the voltage.  On a fish the drive alone cannot tell the stiffness from
# the coupling: it is held to the fin file's (``Tuning.stiffness_sigma``, 5 %: ``piezofin identify``
# measures it in air).
@dataclass(frozen=True)
class Fitted:
    """One fitted parameter of the :class:`Correction`: the library's declared parameter it is
    (``effect.param``), fitted in log coordinates or not, its prior sigma there, and the range the
    optimiser allows, within the library's own (``None``: the library's)."""

    name: str
    effect: type[Effect]
    param: str
    log: bool
    prior_sigma: float
    within: tuple[float, float] | None = None

    @property
    def of_fin(self) -> bool:
        """An effect of the fin (in its model), not of the rig's load cell."""
        return self.effect is not LoadcellGain

    def bounds(self) -> tuple[float, float]:
        """The range in fit coordinates: the library's, narrowed to ``within``."""
        q = next(q for q in self.effect.params if q.name == self.param)
        lo, hi = (q.lower, q.upper) if self.within is None else self.within
        if not q.lower <= lo < hi <= q.upper:
            raise ControlError(f"{self.name}: [{lo}, {hi}] is not within the library's {q.lower}-{q.upper}")
        return (math.log(lo), math.log(hi)) if self.log else (lo, hi)


PARAMS = (
    Fitted("resonance_scale", ResonanceOffset, "scale", True, 0.3),
    Fitted("added_mass", AddedMassOffset, "scale", True, 0.3, (0.3, 4.0)),
    Fitted("softening", Electroelastic, "softening", False, 0.3, (0.0, 0.8)),  # a fin only softens
    Fitted("drag_scale", DragOffset, "scale", True, 0.7, (0.1, 10.0)),  # (log: not down to 0)
    Fitted("coupling_k", FieldCoupling, "k", False, 0.3),
    Fitted("loss_tan_delta", DielectricLoss, "tan_delta", False, 0.3),
    Fitted("leakage_us", Leakage, "conductance", False, 0.1),
    Fitted("capacitance", CapacitanceOffset, "scale", True, 0.05),
    Fitted("thrust_gain", LoadcellGain, "gain", True, 0.3, (0.2, 5.0)),
)
if [p.name for p in PARAMS] != [f.name for f in fields(Correction) if f.name != "base"]:
    raise ControlError("optimiser: Correction's fields and PARAMS are out of step")  # (a developer's slip)
PRIOR_SIGMA = np.array([p.prior_sigma for p in PARAMS])
#: the index of each fitted parameter in the fit's vector
INDEX = {p.name: k for k, p in enumerate(PARAMS)}
LOWER = np.array([p.bounds()[0] for p in PARAMS]) + 1e-9
UPPER = np.array([p.bounds()[1] for p in PARAMS]) - 1e-9


def correction_of(x: FloatArray, base: Model | None = None) -> Correction:
    """The correction at the fit's vector ``x`` (log coordinates where :data:`PARAMS` says)."""
    values = {p.name: (math.exp(v) if p.log else float(v)) for p, v in zip(PARAMS, x, strict=True)}
    return Correction(**values, base=base)


def vector_of(c: Correction) -> FloatArray:
    """The fit's vector of a correction (the inverse of :func:`correction_of`)."""
    return np.array([math.log(getattr(c, p.name)) if p.log else getattr(c, p.name) for p in PARAMS])


def jacobian(
    fn: Callable[[FloatArray], FloatArray],
    x: FloatArray,
    steps: FloatArray,
    at_x: FloatArray | None = None,
    skip: tuple[bool, ...] = (),
) -> FloatArray:
    """Forward differences of ``fn`` at the correction's vector ``x`` in each parameter (backwards
    where the step would cross the parameter's upper bound), shaped ``(*fn(x).shape, len(x))``;
    ``at_x`` is ``fn(x)`` when the caller has it, and a parameter flagged in ``skip`` gets zeros."""
    return forward_differences(fn, x, steps, UPPER, at_x, skip)
