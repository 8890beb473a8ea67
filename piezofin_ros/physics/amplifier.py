"""The amplifier that drives the fin, and the watt its supply pays.

Thrust per watt depends on which watt.  The fin takes ``mean(v i)`` (the paper's stated definition,
and what the fin dissipates), but an MFC is a capacitor: most of its current is reactive, and the
amplifier that drives it draws far more from its supply than the fin keeps.  A fish's battery pays
the amplifier; the paper's 60.7 mN/W is reproduced only by an amplifier's draw
(``piezofin diagnose --paper``).  So every power is named by its watt (:data:`WATT`) and the
amplifier is a component with its own parameters and its own law:

* :class:`LinearAmplifier`: a class-B/AB stage from ``+-rail_v`` rails, as on a lab bench (a Trek
  or an audio-style high-voltage amplifier).  The conducting device carries the load current from
  its rail, so the supply gives ``rail_v |i(t)|`` whatever the phase of ``v``: a reactive load costs
  as much as a resistive one of the same current.  Plus ``quiescent_w``.
* :class:`SwitchingAmplifier`: a switching (class-D or flyback) drive from a battery bus, as a fish
  would carry: it delivers ``p = v i`` when ``p > 0`` at ``efficiency``, and when the fin gives
  energy back (``p < 0``) a ``recovered`` fraction of it returns to the bus.  Plus ``quiescent_w``.

The law is the time-domain one (:meth:`Amplifier.draw`, instantaneous supply power of samples);
:meth:`Amplifier.steady` is its closed form on a sinusoidal drive (the model's steady state), and the
tests check one against the other.  The supply bus the rig measures is ``supply_v`` and the current
``draw / supply_v`` (:meth:`Amplifier.supply_current`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError
from .fin import preset_path, presets, read_yaml_file

FloatArray = NDArray[Any]


class AmplifierError(PhysicsError):
    """An amplifier with impossible parameters, or a file that does not describe one."""


#: A watt's law on the steady state: its power from the drive's peak-to-peak voltage, its RMS current,
#: the fin's mean(v i) and the amplifier, W.
WattLaw = Callable[[FloatArray, FloatArray, FloatArray, "Amplifier"], FloatArray]


@dataclass(frozen=True)
class Watt:
    """A watt a thrust per watt can be in, declared once (:data:`WATT`): its name, what it is (and in a
    few words, for table headers), its law on the steady state (what a model gives), how it is read
    from an estimate (the estimate field that holds it, or a function of the other fields for a watt
    no estimate records), whether a meter measures it and the watt a model gives in its place.

    Adding a watt is one entry in :data:`WATT` (``test/test_extending.py`` adds one): the optimiser
    ranks by it (``watt``), an estimate reads it (:meth:`read`), a model predicts it (:meth:`steady`)."""

    name: str
    what: str
    short: str
    field: str  # (the estimate field that records it; "": none, ``derive`` reads it from the others)
    law: WattLaw | None = None  # (None: a measured watt, whose model is ``modelled_as``'s law)
    derive: Callable[[Mapping[str, float]], float] | None = None
    measured: bool = False
    #: the watt a model (the map, a plant in truth) gives for this one: its own, or the modelled one
    #: a meter measures (``supply_measured`` is the ``supply`` a model predicts)
    modelled_as: str = ""

    def __post_init__(self) -> None:
        if (self.law is None) == (not self.modelled_as) or (not self.field) == (self.derive is None):
            raise AmplifierError(
                f"watt {self.name!r}: a law or the watt it is modelled as (one), and an estimate field "
                "or a derive function (one)"
            )

    @property
    def is_fin(self) -> bool:
        """The fin's own watt, ``mean(v i)``: every other is counted beside it."""
        return self is FIN

    @property
    def model(self) -> Watt:
        """The watt a model gives in this one's place."""
        return WATT[self.modelled_as or self.name]

    def steady(
        self, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike, amplifier: Amplifier
    ) -> FloatArray:
        """The steady state's power in this watt (a measured one: its model's), by its law."""
        law = self.model.law
        assert law is not None  # (__post_init__)
        v, i, p = (np.asarray(x, float) for x in (voltage_pp, current_rms, power_w))
        return np.asarray(law(v, i, p, amplifier), float)

    def read(self, estimate: Mapping[str, float]) -> float:
        """This watt in an estimate's fields (NaN where it holds none), W."""
        if self.derive is not None:
            return float(self.derive(estimate))
        return float(estimate.get(self.field, math.nan))


FIN = Watt(
    "fin",
    "mean(v i): the power the fin takes (the paper's stated definition)",
    "mean(v i)",
    "power_w",
    law=lambda v, i, p, amp: p,
)
#: The watts a thrust per watt can be in, by name.
WATT: dict[str, Watt] = {
    w.name: w
    for w in (
        FIN,
        Watt(
            "apparent",
            "Vrms x Irms: what a power meter reads on a reactive load",
            "Vrms x Irms",
            "power_apparent_w",
            law=lambda v, i, p, amp: v / (2 * math.sqrt(2)) * i,
        ),
        Watt(
            "supply",
            "the amplifier's draw from its supply, through the amplifier's model",
            "the amplifier's draw, modelled",
            "power_supply_w",
            law=lambda v, i, p, amp: amp.steady(v, i, p),
        ),
        Watt(
            "supply_measured",
            "the supply's power as the rig or the fish measures it (the supply topic)",
            "the supply's meter",
            "power_supply_measured_w",
            measured=True,
            modelled_as="supply",
        ),
    )
}


def watt_of(name: str) -> Watt:
    """The registry's watt of that name (:class:`AmplifierError` naming the others if none)."""
    try:
        return WATT[name]
    except KeyError:
        raise AmplifierError(f"unknown watt {name!r}: one of {', '.join(WATT)}") from None


@dataclass(frozen=True)
class Amplifier:
    """The common part: a quiescent draw and the supply bus voltage the rig would measure."""

    kind: ClassVar[str] = ""
    #: parameter -> (unit, lowest, highest, what it is): checked on construction
    limits: ClassVar[dict[str, tuple[str, float, float, str]]] = {}
    name: str = field(default="", kw_only=True, compare=False)

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "name":
                continue
            value = getattr(self, f.name)
            unit, lo, hi, what = self.limits[f.name]
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if not ok or not lo <= value <= hi:
                raise AmplifierError(
                    f"amplifier {self.kind}: {f.name} ({what}) must be a number within "
                    f"[{lo:g}, {hi:g}]{' ' + unit if unit else ''}, got {value!r}"
                )

    @property
    def supply_v(self) -> float:
        raise NotImplementedError

    def draw(self, v: ArrayLike, i: ArrayLike) -> FloatArray:
        """Instantaneous supply power (W) while the output is ``v`` (V) and ``i`` (A)."""
        raise NotImplementedError

    def steady(self, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike) -> FloatArray:
        """Mean supply power on a sinusoidal drive of ``voltage_pp`` whose current has RMS
        ``current_rms`` and whose ``mean(v i)`` is ``power_w`` (the closed form of :meth:`draw`)."""
        raise NotImplementedError

    def mean_draw(self, v: ArrayLike, i: ArrayLike) -> float:
        """Mean supply power over samples spanning whole periods."""
        return float(np.mean(self.draw(v, i)))

    def supply_current(self, v: ArrayLike, i: ArrayLike) -> FloatArray:
        """The supply bus current (A) the rig's meter reads at :attr:`supply_v`."""
        return self.draw(v, i) / self.supply_v

    def as_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind, **asdict(self)}
        d.pop("name")
        return d

    def describe(self) -> str:
        raise NotImplementedError

    def without_quiescent(self) -> Amplifier:
        """This amplifier with no draw at rest (every kind has ``quiescent_w``; a kind without one is
        itself): what the fins' own watts cost, the fixed draw counted apart."""
        if any(f.name == "quiescent_w" for f in fields(self)):
            return replace(self, quiescent_w=0.0)  # type: ignore[call-arg]  # (each kind declares it)
        return self

    def _quiescent(self) -> str:
        q = float(getattr(self, "quiescent_w", 0.0))
        return f", {q:g} W quiescent" if q else ""


def power_above_zero(voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike) -> FloatArray:
    """The mean of the part of ``p(t) = v i`` above zero on a sinusoidal drive of ``voltage_pp`` whose
    current has RMS ``current_rms`` and whose ``mean(v i)`` is ``power_w``, W: with
    ``p(t) = P - S cos(2 w t + phi)``, ``S = Vrms Irms``, it is ``P (1 - a/pi) + S sin(a) / pi``,
    ``a = arccos(P / S)`` (the part below zero has that mean less ``P``).  A kind whose draw treats
    the two directions of the power apart takes its closed form from here."""
    P = np.asarray(power_w, float)
    S = np.asarray(voltage_pp, float) / (2 * math.sqrt(2)) * np.asarray(current_rms, float)
    c = np.clip(np.divide(P, S, out=np.ones_like(S * P), where=S > 0), -1.0, 1.0)
    a = np.arccos(c)
    return np.where(S > 0, P * (1 - a / math.pi) + S * np.sin(a) / math.pi, np.maximum(P, 0.0))  # type: ignore[no-any-return]


@dataclass(frozen=True)
class LinearAmplifier(Amplifier):
    kind: ClassVar[str] = "linear"
    limits: ClassVar[dict[str, tuple[str, float, float, str]]] = {
        "rail_v": ("V", 1.0, 5000.0, "each rail, +- this"),
        "quiescent_w": ("W", 0.0, 1000.0, "the draw with no output"),
    }
    rail_v: float = 400.0
    quiescent_w: float = 0.0

    @property
    def supply_v(self) -> float:
        return self.rail_v

    def draw(self, v: ArrayLike, i: ArrayLike) -> FloatArray:
        return self.quiescent_w + self.rail_v * np.abs(np.asarray(i, float))

    def steady(self, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike) -> FloatArray:
        # mean |I sin| = 2 I / pi with I = sqrt(2) I_rms
        return self.quiescent_w + self.rail_v * (2 * math.sqrt(2) / math.pi) * np.asarray(current_rms, float)

    def describe(self) -> str:
        return f"a linear (class-B) amplifier from +-{self.rail_v:g} V rails{self._quiescent()}"


@dataclass(frozen=True)
class SwitchingAmplifier(Amplifier):
    kind: ClassVar[str] = "switching"
    limits: ClassVar[dict[str, tuple[str, float, float, str]]] = {
        "efficiency": ("", 0.01, 1.0, "of the power it delivers"),
        "recovered": ("", 0.0, 1.0, "fraction of the energy the fin returns that reaches the bus"),
        "quiescent_w": ("W", 0.0, 1000.0, "the draw with no output"),
        "bus_v": ("V", 0.1, 1000.0, "the supply bus (battery) voltage"),
    }
    efficiency: float = 0.85
    recovered: float = 0.5
    quiescent_w: float = 0.0
    bus_v: float = 7.4

    @property
    def supply_v(self) -> float:
        return self.bus_v

    def draw(self, v: ArrayLike, i: ArrayLike) -> FloatArray:
        p = np.asarray(v, float) * np.asarray(i, float)
        return self.quiescent_w + np.maximum(p, 0.0) / self.efficiency + self.recovered * np.minimum(p, 0.0)

    def steady(self, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike) -> FloatArray:
        above = power_above_zero(voltage_pp, current_rms, power_w)
        below = above - np.asarray(power_w, float)  # (the part below zero: the mean less P)
        return self.quiescent_w + above / self.efficiency - self.recovered * below

    def describe(self) -> str:
        return (
            f"a switching amplifier from a {self.bus_v:g} V bus, {self.efficiency:.0%} efficient, "
            f"{self.recovered:.0%} of the returned energy recovered{self._quiescent()}"
        )


KINDS: dict[str, type[Amplifier]] = {c.kind: c for c in (LinearAmplifier, SwitchingAmplifier)}

#: The amplifier when none is named: the paper's bench, a class-B stage from the 800 Vpp drive's peak
#: (config/amplifiers/paper-bench.yaml holds the same; the tests check they agree).
PAPER_BENCH = LinearAmplifier(rail_v=400.0, name="paper-bench")


def amplifier_from_mapping(data: Any, source: str = "amplifier") -> Amplifier:
    """An amplifier from ``{kind: linear|switching, <its parameters>}``; one error naming the key."""
    if not isinstance(data, Mapping):
        raise AmplifierError(f"{source}: expected a mapping with 'kind' and the amplifier's parameters")
    kind = data.get("kind")
    if not isinstance(kind, str) or kind not in KINDS:  # (a list or a mapping is no kind, nor hashable)
        raise AmplifierError(f"{source}: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    cls = KINDS[str(kind)]
    known = [f.name for f in fields(cls) if f.name != "name"]
    extra = sorted(str(k) for k in data if k not in (*known, "kind", "name"))
    if extra:
        raise AmplifierError(f"{source}: unknown key(s) {', '.join(extra)} for a {kind} amplifier ({known})")
    try:
        return cls(name=str(data.get("name", "")), **{k: data[k] for k in known if k in data})
    except AmplifierError as exc:
        raise AmplifierError(f"{source}: {exc}") from None


def amplifier_presets() -> list[str]:
    return presets("amplifiers")


def load_amplifier(name_or_path: str | os.PathLike[str]) -> Amplifier:
    """A preset by name (``paper-bench``, ``fish-switching``) or an amplifier YAML by path."""
    path = preset_path(name_or_path, "amplifiers", "amplifier", AmplifierError)
    data = read_yaml_file(path, AmplifierError)
    if isinstance(data, Mapping) and isinstance(data.get("amplifier"), Mapping):
        data = data["amplifier"]
    amp = amplifier_from_mapping(data, str(path))
    return amp if amp.name else type(amp)(**{**asdict(amp), "name": path.stem})


def power_in(
    watt: str, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike, amplifier: Amplifier
) -> FloatArray:
    """The steady state's power in ``watt`` (a model's ``supply_measured`` is its ``supply``)."""
    return watt_of(watt).steady(voltage_pp, current_rms, power_w, amplifier)
