"""The diagnosis's view of the model: the stacked parameters of candidate effects, as one vector.

The model itself (a fin plus effects, its steady state, persistence) is
:mod:`piezofin_ros.physics.model`; the effects are :mod:`piezofin_ros.physics.effects`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..physics.effects import Effect, Param, effect_class, make
from ..physics.fin import Fin
from ..physics.model import Model


@dataclass(frozen=True)
class ParamSpace:
    """The stacked parameters of several effects, as one vector for an optimiser.

    The optimiser works in scaled units ``z = (x - neutral) / scale``; :meth:`model` builds the
    :class:`Model` model of a scaled vector (clipped into the bounds).
    """

    fin: Fin
    names: tuple[str, ...]

    @property
    def params(self) -> list[Param]:
        return [q for n in self.names for q in effect_class(n).params]

    @property
    def sizes(self) -> list[int]:
        return [len(effect_class(n).params) for n in self.names]

    def _column(self, attr: str) -> NDArray[np.float64]:
        return np.array([getattr(q, attr) for q in self.params], dtype=float)

    @property
    def neutral(self) -> NDArray[np.float64]:
        return self._column("neutral")

    @property
    def scale(self) -> NDArray[np.float64]:
        return self._column("scale")

    @property
    def z_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n, s = self.neutral, self.scale
        return (self._column("lower") - n) / s, (self._column("upper") - n) / s

    def to_z(self, x: ArrayLike) -> NDArray[np.float64]:
        return (np.asarray(x, float) - self.neutral) / self.scale

    def to_x(self, z: ArrayLike) -> NDArray[np.float64]:
        """Physical parameter values of a scaled vector (clipped into the bounds)."""
        lo, hi = self.z_bounds
        return self.neutral + np.clip(np.asarray(z, float), lo, hi) * self.scale

    def effects(self, x: ArrayLike) -> tuple[Effect, ...]:
        """The effects at physical values ``x`` (stacked in the order of ``names``)."""
        x = np.asarray(x, float)
        out, j = [], 0
        for n, size in zip(self.names, self.sizes, strict=True):
            out.append(make(n, x[j : j + size]))
            j += size
        return tuple(out)

    def model(self, z: ArrayLike, uncertainties: Mapping[str, Mapping[str, float]] | None = None) -> Model:
        """The model at scaled vector ``z`` (with the fit's ``uncertainties``, if given)."""
        return Model(self.fin, self.effects(self.to_x(z)), uncertainties=uncertainties or {})
