r"""Effects: what a real fin does that the paper's model does not, as immutable, composable objects.

An effect carries its parameters (:class:`Param`: unit, bounds, the neutral value at which it
vanishes, a typical size) and two descriptions of the same physics, side by side:

* its **time-domain law** (:meth:`Effect.law`): how it changes the instantaneous equations,
  written in the canonical form of :class:`TimeLaw`::

      m(t) eta'' + c_lin D (1 + c_abs |eta|) eta' + g(t) |eta'| eta' + wn^2 S (eta + c3 eta^3)
          = theta Q v_c,   v_c = clip(s v, v_clip)   (s: an amplifier's sag)
      m(t) = 1 + mu M (1 + M_kc KC(t) + M_kc2 KC(t)^2),   g(t) = gamma G KC(t)^-n,
      KC(t) = 2 pi phi(L) |eta(t)| / b
      i = C C_eq dv_c/dt + G_loss v_c + theta Q eta'
      load cell = gain (1/2) m_v M (1 + M_kc KC + M_kc2 KC^2) (w_t^2 - U^2 w_x^2) + bias
      readings: g_v v_c,  g_u u(t - tau_u),  g_i i(t - tau_i)   (the instruments)

  (``|eta(t)|`` the instantaneous amplitude ``sqrt(eta^2 + (eta'/w)^2)``; integrated by
  :func:`piezofin_ros.physics.timedomain.simulate_law`; every coefficient may depend on the trial's
  frequency, voltage and start time, which is how drifts enter);
* its **describing function** (:meth:`Effect.describe`): the same law seen by the single-term
  harmonic balance, as changes of the balance's coefficients (:class:`~.knobs.Knobs`) at an
  operating point and a tip amplitude ``X = phi(L) A``.  For ``c3 eta^3`` it is
  ``(3/4) c3 A^2``; for ``|eta| eta'`` it is ``(4 / 3 pi) A eta'``; for the clipped sine the
  fundamental ``(2 V / pi)(asin r + r sqrt(1 - r^2))``, ``r = v_clip / V``.

``test/physics/test_effects.py`` checks, for every effect, that the two agree: the steady state
of the time-domain law moves the tip velocity, current, power and thrust as the describing
function says, within 1 %.

Effects are frozen dataclasses whose fields are their parameters (``Duffing(beta=40.0)``); they
compose with ``+`` into :class:`Effects`, and a fin plus effects is a
:class:`~piezofin_ros.physics.model.Model`.  :data:`LIBRARY` maps each effect's name to its class
(the names are those of saved models, ``effects: {drag_offset: {scale: 2.0}}``).  Every effect is
neutral at its ``neutral`` values, so the paper's model is the model with no effect.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, TypeVar

import numpy as np
from numpy.typing import NDArray

from ..errors import PhysicsError
from .fin import Fin
from .knobs import Knobs

FloatArray = NDArray[Any]
V_REF = 800.0  # Vpp: voltage-dependent effects are quoted at this drive
AMPLIFIER = "amplifier"  # the family of the effects between the command and the fin (applied first)
VOLTAGE_MONITOR = "voltage monitor"  # the family of the instrument that reads the drive
#: Describing functions: ``|x| x`` (quadratic drag) -> ``8/(3 pi) X``, ``|x| x'`` -> ``4/(3 pi) X``,
#: ``x^3`` -> ``3/4 X^2``.
DF_ABS_DAMPING = 4.0 / (3.0 * math.pi)
DF_CUBIC = 0.75


class ModelError(PhysicsError):
    """A model or an effect is malformed (unknown effect, wrong parameter, out of range)."""


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    neutral: float  # the value at which the effect vanishes
    lower: float
    upper: float
    scale: float  # typical size of a departure (prior width and fit scaling)
    description: str = ""
    starts: tuple[float, ...] = ()  # starting values for the fit (default: neutral +- scale/2)


_D = TypeVar("_D")


def replace(obj: _D, **changes: Any) -> _D:
    """:func:`dataclasses.replace` for the knobs, the time-domain law and the operating point, which
    compute nothing at construction: the fields copied and ``changes`` set (a name that is no field
    refused as dataclasses refuses it), at a fifth of the cost.  An amplitude-dependent model calls
    it a dozen times a solve, the optimiser's map thousands of solves a fit: it was a fifth of a
    fish controller's CPU.  A class with a ``__post_init__`` goes through dataclasses'."""
    cls = type(obj)
    if hasattr(cls, "__post_init__"):
        return dataclasses.replace(obj, **changes)  # type: ignore[type-var]
    unknown = changes.keys() - cls.__dataclass_fields__.keys()  # type: ignore[attr-defined]
    if unknown:
        raise TypeError(f"{cls.__name__}.__init__() got an unexpected keyword argument {min(unknown)!r}")
    new = object.__new__(cls)
    new.__dict__.update(obj.__dict__, **changes)
    return new


@dataclass(frozen=True)
class OperatingPoint:
    """What a describing function may depend on, as arrays over trials (SI; ``voltage_pp`` nominal)."""

    fin: Fin
    frequency_hz: FloatArray
    voltage_pp: FloatArray
    tip_amplitude: FloatArray  # X = phi(L) A, m (0 for the time-domain law: it has no amplitude)
    time_s: FloatArray | float = 0.0  # when the trial ran, s since the first (drifts)

    @property
    def omega(self) -> FloatArray:
        return 2 * math.pi * self.frequency_hz

    @property
    def kc(self) -> FloatArray:
        """Keulegan-Carpenter number of the tip, ``2 pi X / b``."""
        return 2 * math.pi * self.tip_amplitude / self.fin.b


@dataclass(frozen=True)
class TimeLaw:
    """The coefficients of the canonical time-domain equations (module docstring), per trial.

    Each is a float or an array over trials; the nominal model is ``TimeLaw()``.  Factors
    multiply the paper's coefficients; ``c3`` (1/m^2 kg), ``c_abs`` (1/(m sqrt kg)) and
    ``mass_kc`` are relative to the linear term they extend.
    """

    stiffness: FloatArray | float = 1.0  # S, x wn^2
    c3: FloatArray | float = 0.0  # cubic spring: wn^2 S (eta + c3 eta^3)
    damping: FloatArray | float = 1.0  # D, x 2 zeta wn
    c_abs: FloatArray | float = 0.0  # damping x (1 + c_abs |eta|)
    mass: FloatArray | float = 1.0  # M, added mass x (mu and m_v)
    mass_kc: FloatArray | float = 0.0  # added mass x (1 + mass_kc KC(t) + mass_kc2 KC(t)^2)
    mass_kc2: FloatArray | float = 0.0
    drag: FloatArray | float = 1.0  # G, x gamma
    drag_n: FloatArray | float = 0.0  # drag x KC(t)^-n
    coupling: FloatArray | float = 1.0  # Q, x theta
    voltage_scale: FloatArray | float = 1.0  # the amplifier's output / its command (a sag)
    voltage_clip: FloatArray | float = math.inf  # V, the drive clips at +-this
    capacitance: FloatArray | float = 1.0  # x C_eq
    loss_conductance: FloatArray | float = 0.0  # S
    thrust_gain: FloatArray | float = 1.0
    thrust_bias_n: FloatArray | float = 0.0
    swim_speed: FloatArray | float = 0.0  # m/s
    # the instruments: reading / true value of each channel, and its lag (s)
    voltage_gain: FloatArray | float = 1.0
    tip_gain: FloatArray | float = 1.0
    tip_delay_s: FloatArray | float = 0.0
    current_gain: FloatArray | float = 1.0
    current_delay_s: FloatArray | float = 0.0


E = TypeVar("E", bound="Effect")


class Effect:
    """One effect.  Subclasses are frozen dataclasses registered with :func:`register`."""

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    #: what it belongs to, for a report that can name the family when no form of it fits well
    family: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    amplitude_dependent: ClassVar[bool] = False

    def __post_init__(self) -> None:
        for q, v in zip(self.params, self.values, strict=True):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ModelError(f"effect {self.name}: parameter {q.name} must be a number, got {v!r}")
            if not (math.isfinite(v) and q.lower <= v <= q.upper):
                raise ModelError(
                    f"effect {self.name}: parameter {q.name} = {v!r} outside [{q.lower}, {q.upper}] {q.unit}"
                )

    @property
    def values(self) -> tuple[float, ...]:
        """The parameters' values, in ``params``' order (each field is one: :func:`declared`); read
        by name, not by ``dataclasses.astuple``, which deep-copies: 9 us a call, and a course calls
        it 190,000 times."""
        return tuple(float(getattr(self, q.name)) for q in self.params)

    @classmethod
    def neutral(cls) -> NDArray[np.float64]:
        return np.array([q.neutral for q in cls.params], dtype=float)

    @classmethod
    def at(cls: type[E], values: Iterable[float]) -> E:
        vals = [float(v) for v in values]
        if len(vals) != len(cls.params):
            raise ModelError(f"effect {cls.name} takes {len(cls.params)} parameter(s), got {len(vals)}")
        return cls(*vals)

    def parameters(self) -> dict[str, float]:
        return {q.name: v for q, v in zip(self.params, self.values, strict=True)}

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        """The describing function: the balance's coefficients with this effect, at ``op``."""
        raise NotImplementedError

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        """The time-domain law: the canonical equations' coefficients with this effect."""
        raise NotImplementedError

    def __add__(self, other: Effect | Effects) -> Effects:
        return Effects((self,)) + other


class Effects(tuple[Effect, ...]):
    """Several effects, applied in order (``a + b + c``)."""

    def __add__(self, other: Any) -> Effects:  # type: ignore[override]
        if isinstance(other, Effect):
            return Effects((*self, other))
        return Effects((*self, *other))

    def __iter__(self) -> Iterator[Effect]:
        return super().__iter__()

    @property
    def amplitude_dependent(self) -> bool:
        return any(e.amplitude_dependent for e in self)

    # The amplifier's effects come first, at the voltage commanded; every other effect sees the
    # fundamental the fin gets: a field softens the fin and strengthens its coupling as it is applied.
    # (Each once saw the command: under a sagging amplifier a fit at the monitor's voltage, as the
    # optimiser's, then read its softening as added mass, and a fish's self-sensed thrust 15-25 % high.)

    def describe(self, op: OperatingPoint, drive_pp: FloatArray | None = None) -> Knobs:
        """The knobs at ``op``; ``drive_pp``: the drive as its monitor read it, which the fin gets
        (over the monitor's gain) in place of the amplifier's output."""
        k = _describe_in_turn(Knobs(), (e for e in self if e.family == AMPLIFIER), op)
        if drive_pp is None:
            v_fin = op.voltage_pp * np.asarray(k.voltage) * np.asarray(k.voltage_scale)
        else:
            monitor = Knobs()
            for e in self:
                if e.family == VOLTAGE_MONITOR:
                    monitor = e.describe(monitor, op)
            v_fin = np.asarray(drive_pp, float) / np.asarray(monitor.voltage_gain)
        at_fin = replace(op, voltage_pp=np.broadcast_to(v_fin, np.shape(op.voltage_pp)))
        return _describe_in_turn(k, (e for e in self if e.family != AMPLIFIER), at_fin)

    def law(
        self, fin: Fin, frequency_hz: FloatArray, voltage_pp: FloatArray, time_s: FloatArray | float = 0.0
    ) -> TimeLaw:
        law = TimeLaw()
        for e in self:
            if e.family == AMPLIFIER:
                law = e.law(law, fin, frequency_hz, voltage_pp, time_s)
        # (the time domain scales the command, then clips it: the fundamental of that)
        amplitude = 0.5 * np.asarray(voltage_pp, float) * np.asarray(law.voltage_scale, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(amplitude > 0, np.asarray(law.voltage_clip, float) / amplitude, 1.0)
        at_fin = 2.0 * amplitude * clipped_fundamental(r)
        for e in self:
            if e.family != AMPLIFIER:
                law = e.law(law, fin, frequency_hz, at_fin, time_s)
        return law


#: Every effect by name (the names of saved models and of the diagnosis's candidates).
LIBRARY: dict[str, type[Effect]] = {}


def param(
    unit: str,
    neutral: float,
    lower: float,
    upper: float,
    scale: float,
    description: str = "",
    starts: tuple[float, ...] = (),
) -> Any:
    """An effect's parameter, declared once: the dataclass field (its default the neutral value)
    that carries its :class:`Param` (unit, bounds, scale, description, fit starts)."""
    return field(default=neutral, metadata={PARAM: (unit, neutral, lower, upper, scale, description, starts)})


#: The key of a field's metadata that :func:`param` fills.
PARAM = "piezofin_param"


def declared(cls: type[E]) -> type[E]:
    """Class decorator (under ``@dataclass``): the effect's ``params``, read from its fields (each
    made by :func:`param`)."""
    found = []
    for f in fields(cls):  # type: ignore[arg-type]
        if PARAM not in f.metadata:
            raise TypeError(f"{cls.__name__}.{f.name}: declare it with param(...)")
        found.append(Param(f.name, *f.metadata[PARAM]))
    cls.params = tuple(found)
    return cls


def register(cls: type[E]) -> type[E]:
    """Class decorator: a frozen dataclass effect (its ``params`` :func:`declared`) into :data:`LIBRARY`."""
    LIBRARY[cls.name] = declared(cls)
    return cls


def effect_class(name: str, source: str = "") -> type[Effect]:
    try:
        return LIBRARY[name]
    except KeyError:
        where = f"{source}: " if source else ""
        raise ModelError(f"{where}unknown effect {name!r}; known: {', '.join(LIBRARY)}") from None


def make(name: str, values: Iterable[float]) -> Effect:
    """The effect ``name`` with ``values`` (in the order of its params)."""
    return effect_class(name).at(values)


class Coefficient(Effect):
    """An effect that changes one coefficient alike in the time-domain law and in the balance.

    For these (linear) effects the describing function *is* the law: ``target`` names the field of
    both :class:`TimeLaw` and :class:`~.knobs.Knobs`, ``how`` says whether :meth:`amount` multiplies
    it (``scale``), adds to it (``add``) or replaces it (``set``).  Subclasses define :meth:`amount`.
    """

    target: ClassVar[str] = ""
    how: ClassVar[str] = "scale"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        raise NotImplementedError

    def _apply(self, obj: Any, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> Any:
        old, x = getattr(obj, self.target), self.amount(fin, omega, voltage_pp)
        new = old * x if self.how == "scale" else (old + x if self.how == "add" else x)
        return replace(obj, **{self.target: new})

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return self._apply(k, op.fin, op.omega, op.voltage_pp)  # type: ignore[no-any-return]

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        omega = 2 * math.pi * np.asarray(frequency_hz, float)
        return self._apply(law, fin, omega, voltage_pp)  # type: ignore[no-any-return]


# --- the library -------------------------------------------------------------------------------


@register
@dataclass(frozen=True)
class ResonanceOffset(Coefficient):
    name = "resonance_offset"
    title = "stiffness off (in-water resonance shifted, linear)"
    family = "stiffness"
    scale: float = param("-", 1.0, 0.3, 2.0, 0.1, "natural frequency x scale")
    target = "stiffness"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.scale**2


@declared
@dataclass(frozen=True)
class CapacitanceOffset(Coefficient):
    """The drive's capacitance off ``C_eq`` (a fin's own MFC, temperature, the cable).  Not in the
    diagnosis library (not registered): the controller's self-sensing calibration fits it from the
    drive's admittance, where the diagnosis names a drift in time or the current monitor."""

    name = "capacitance_offset"
    title = "capacitance off C_eq"
    family = "electrical loss"
    scale: float = param("-", 1.0, 0.5, 2.0, 0.05, "C_eq x scale")
    target = "capacitance"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.scale


@register
@dataclass(frozen=True)
class Duffing(Effect):
    """A cubic spring ``c3 eta^3``, whose describing function is ``(3/4) c3 A^2``."""

    name = "stiffness_nonlinearity"
    title = "geometric stiffness nonlinearity (Duffing, amplitude-dependent)"
    family = "stiffness"
    amplitude_dependent = True
    beta: float = param("-", 0.0, -5000.0, 5000.0, 20.0, "wn^2 x (1 + beta (X/L)^2)")

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        x = op.tip_amplitude / op.fin.L
        return replace(k, stiffness=k.stiffness * np.maximum(1.0 + self.beta * x * x, 0.01))

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        # beta (phi A / L)^2 = (3/4) c3 A^2
        return replace(law, c3=law.c3 + self.beta * (fin.phi_tip / fin.L) ** 2 / DF_CUBIC)


@register
@dataclass(frozen=True)
class Electroelastic(Coefficient):
    name = "electroelastic_softening"
    title = "electroelastic softening (stiffness falls with the field)"
    family = "stiffness"
    softening: float = param("-", 0.0, -0.5, 0.9, 0.1, "wn x (1 - s Vpp/800)")
    target = "stiffness"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return np.maximum(1.0 - self.softening * np.asarray(voltage_pp, float) / V_REF, 0.05) ** 2


@register
@dataclass(frozen=True)
class NonlinearDamping(Effect):
    """Damping ``(1 + c_abs |eta|)``, whose describing function is ``1 + c_abs (4 / 3 pi) A``."""

    name = "nonlinear_damping"
    title = "internal dissipative nonlinearity (damping grows with amplitude)"
    family = "damping"
    amplitude_dependent = True
    q: float = param("-", 0.0, -1.0, 2000.0, 10.0, "zeta x (1 + q X/L)")

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return replace(k, damping=k.damping * np.maximum(1.0 + self.q * op.tip_amplitude / op.fin.L, 0.01))

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        # q phi A / L = c_abs (4 / 3 pi) A (on top of the damping the other effects set)
        return replace(law, c_abs=law.c_abs + self.q * fin.phi_tip / fin.L / DF_ABS_DAMPING)


@register
@dataclass(frozen=True)
class AddedMassOffset(Coefficient):
    name = "added_mass_offset"
    title = "inertia coefficient c_m off the curve of Eq. (21)"
    family = "added mass"
    scale: float = param("-", 1.0, 0.1, 4.0, 0.2, "c_m x scale")
    target = "mass"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.scale


@register
@dataclass(frozen=True)
class AddedMassKC(Effect):
    """Added mass ``x (1 + a KC(t))``; a sine's instantaneous amplitude is constant, so the
    describing function is the law at the amplitude."""

    name = "added_mass_kc"
    title = "amplitude-dependent added mass (Keulegan-Carpenter)"
    family = "added mass"
    amplitude_dependent = True
    a: float = param("-", 0.0, -0.8, 5.0, 0.2, "c_m x (1 + a KC)")

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return replace(k, mass=k.mass * np.maximum(1.0 + self.a * op.kc, 0.05))

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        return replace(law, mass_kc=law.mass_kc + self.a)


@register
@dataclass(frozen=True)
class DragOffset(Coefficient):
    name = "drag_offset"
    title = "drag coefficient c_d off the assumed value"
    family = "drag"
    scale: float = param("-", 1.0, 0.0, 20.0, 0.5, "c_d x scale")
    target = "drag"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.scale


@register
@dataclass(frozen=True)
class DragKC(Effect):
    name = "drag_kc"
    title = "amplitude-dependent drag coefficient (c_d ~ KC^-n, Graham)"
    family = "drag"
    amplitude_dependent = True
    n: float = param("-", 0.0, -2.0, 2.0, 0.2, "c_d x KC^-n")

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return replace(k, drag=k.drag * np.maximum(op.kc, 1e-3) ** (-self.n))

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        return replace(law, drag_n=law.drag_n + self.n)


@register
@dataclass(frozen=True)
class DielectricLoss(Coefficient):
    name = "dielectric_loss"
    title = "dielectric loss of the piezoceramic (tan delta)"
    family = "electrical loss"
    tan_delta: float = param("-", 0.0, 0.0, 0.5, 0.02, "P += tan(delta) C_eq w V^2 / 2")
    target = "loss_conductance"
    how = "add"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.tan_delta * fin.C_eq * omega


@register
@dataclass(frozen=True)
class Leakage(Coefficient):
    name = "leakage"
    title = "resistive leakage of the drive (frequency-independent loss)"
    family = "electrical loss"
    conductance: float = param("uS", 0.0, 0.0, 50.0, 1.0, "P += G V^2 / 2")
    target = "loss_conductance"
    how = "add"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.conductance * 1e-6


@register
@dataclass(frozen=True)
class SwimSpeed(Coefficient):
    name = "swim_speed"
    title = "flow past the fin (U != 0 in Eq. 19)"
    family = "flow"
    U: float = param("m/s", 0.0, 0.0, 5.0, 0.05, "free-stream speed")
    target = "swim_speed"
    how = "set"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.U


def clipped_fundamental(r: FloatArray | float) -> FloatArray:
    """The describing function of a sine clipped at ``r`` of its amplitude (``0 <= r <= 1``): its
    fundamental's share of the sine's, ``(2 / pi) (asin r + r sqrt(1 - r^2))``."""
    r = np.clip(np.asarray(r, float), 0.0, 1.0)
    return (2 / math.pi) * (np.arcsin(r) + r * np.sqrt(1 - r * r))  # type: ignore[no-any-return]


def clip_ratio(fundamental: float) -> float:
    """The clip level ``r`` whose :func:`clipped_fundamental` is ``fundamental`` (its inverse; the
    streaming rig clips its drive where the model says the amplifier does)."""
    if fundamental >= 1.0:
        return 1.0
    if fundamental <= 0.0:
        return 0.0
    from scipy import optimize  # (here: a fish's controller imports this module, and not scipy's 45 MB)

    return float(optimize.brentq(lambda r: float(clipped_fundamental(r)) - fundamental, 0.0, 1.0, xtol=1e-12))


def amplifier_clip(inv_i_max: float, fin: Fin, omega: FloatArray) -> FloatArray:
    """The voltage amplitude at which an amplifier of peak current ``1 / inv_i_max`` mA clips."""
    with np.errstate(divide="ignore"):
        return np.where(inv_i_max > 0, 1e-3 / (inv_i_max * fin.C_eq * omega), np.inf)


@register
@dataclass(frozen=True)
class AmplifierLimit(Effect):
    """The amplifier clips at the voltage where its current limit is reached, ``c = I_max / (C_eq w)``.

    A sine of amplitude ``V`` clipped at ``c < V`` keeps a fundamental of amplitude
    ``(2 V / pi) (asin r + r sqrt(1 - r^2))`` with ``r = c / V`` (its describing function).
    """

    name = "amplifier_limit"
    title = "amplifier current limit (the drive clips at high f x V)"
    family = AMPLIFIER
    inv_i_max: float = param(
        "1/mA",
        0.0,
        0.0,
        50.0,
        1.0,
        "1 / peak current the amplifier delivers",
        (0.5, 2.0, 8.0, 30.0),
    )

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        v = 0.5 * op.voltage_pp
        clip = amplifier_clip(self.inv_i_max, op.fin, op.omega)
        r = np.clip(clip / np.maximum(v, 1e-12), 0.0, 1.0)
        alpha = np.arcsin(r)
        fundamental = clipped_fundamental(r)
        # C dv/dt of the clipped sine: mean square (V w)^2 (2 alpha + sin 2 alpha) / (2 pi), of which
        # the fundamental carries (fundamental V w)^2 / 2; the rest is harmonic current.
        ms = (2 * alpha + np.sin(2 * alpha)) / (2 * math.pi) - 0.5 * fundamental**2
        harmonics = (op.fin.C_eq * op.omega * v) ** 2 * np.maximum(ms, 0.0)
        return replace(
            k,
            voltage=k.voltage * fundamental,
            current_harmonics_a2=k.current_harmonics_a2 + harmonics,
        )

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        clip = amplifier_clip(self.inv_i_max, fin, 2 * math.pi * np.asarray(frequency_hz, float))
        return replace(law, voltage_clip=np.minimum(law.voltage_clip, clip))


@register
@dataclass(frozen=True)
class LoadcellOffset(Coefficient):
    name = "loadcell_offset"
    title = "thrust transducer drift not cancelled by the baselines (offset)"
    family = "load cell"
    bias: float = param("mN", 0.0, -50.0, 50.0, 0.2, "added to the load-cell thrust")
    target = "thrust_bias_n"
    how = "add"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.bias * 1e-3


@register
@dataclass(frozen=True)
class LoadcellGain(Coefficient):
    name = "loadcell_gain"
    title = "thrust transducer calibration (gain)"
    family = "load cell"
    gain: float = param("-", 1.0, 0.1, 5.0, 0.2, "load-cell thrust x gain")
    target = "thrust_gain"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return self.gain


# --- missing physics ----------------------------------------------------------------------------


@register
@dataclass(frozen=True)
class FieldCoupling(Coefficient):
    """The electromechanical coupling grows with the field (an MFC nonlinearity: the piezoelectric
    coefficient rises with the drive amplitude, linearly in Rayleigh's law, ``p = 1``), quoted at the
    drive's amplitude; not a stiffness change."""

    name = "field_coupling"
    title = "field-dependent piezoelectric coupling (theta grows with the drive)"
    family = "coupling"
    k: float = param("-", 0.0, -0.5, 2.0, 0.1, "theta x (1 + k (Vpp/800)^p)")
    p: float = param("-", 1.0, 0.3, 3.0, 0.3, "how the coupling grows with the field (1: Rayleigh's law)")
    target = "coupling"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return np.maximum(1.0 + self.k * (np.asarray(voltage_pp, float) / V_REF) ** self.p, 0.05)


def sag_ratio(inv_i_max: float, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray:
    """Output over command of an amplifier that scales its whole output down so that the capacitive
    current stays under ``1 / inv_i_max`` mA (1 where it does not need to)."""
    demand = fin.C_eq * omega * 0.5 * np.asarray(voltage_pp, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(demand * inv_i_max > 1e-3, 1e-3 / (inv_i_max * demand), 1.0)
    return np.asarray(r, float)


@register
@dataclass(frozen=True)
class AmplifierSag(Coefficient):
    """An amplifier that keeps its sine clean but lowers its whole output to stay under a current
    limit (an automatic gain control), where a clipping amplifier flattens the peaks."""

    name = "amplifier_sag"
    title = "amplifier sags its output under a current limit (no clipping)"
    family = AMPLIFIER
    inv_i_max: float = param(
        "1/mA",
        0.0,
        0.0,
        50.0,
        1.0,
        "1 / current the amplifier holds",
        (0.5, 2.0, 8.0, 30.0),
    )
    target = "voltage_scale"

    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return sag_ratio(self.inv_i_max, fin, omega, voltage_pp)


@register
@dataclass(frozen=True)
class AddedMassKC2(Effect):
    """Added mass ``x (1 + a KC(t)^2)``: growing faster than linearly with the amplitude."""

    name = "added_mass_kc2"
    title = "added mass growing with the square of the Keulegan-Carpenter number"
    family = "added mass"
    amplitude_dependent = True
    a: float = param("-", 0.0, -0.8, 20.0, 0.2, "c_m x (1 + a KC^2)")

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return replace(k, mass=k.mass * np.maximum(1.0 + self.a * op.kc**2, 0.05))

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        return replace(law, mass_kc2=law.mass_kc2 + self.a)


# --- the instruments ------------------------------------------------------------------------------
# Each multiplies or delays what one channel reads, not what the fin does.  Sign conventions (the
# suite's and a rig driver's, docs/reference.md): the tip velocity is positive in the direction
# the tip moves under a positive voltage well below resonance (so it leads the voltage by 90 deg
# there), and the current is positive into the terminal the voltage is measured at (so mean(v i)
# is the power the fin draws, > 0).  A reversed sensor is found from the data itself
# (diagnosis.data.conventions), not fitted.


class _Instrument(Coefficient):
    def amount(self, fin: Fin, omega: FloatArray, voltage_pp: FloatArray) -> FloatArray | float:
        return float(self.values[0]) * (1e-3 if self.how == "add" else 1.0)


@register
@dataclass(frozen=True)
class VoltageMonitorGain(_Instrument):
    name = "voltage_monitor_gain"
    title = "voltage monitor calibration (gain: the drive is not what it reads)"
    family = VOLTAGE_MONITOR
    gain: float = param("-", 1.0, 0.3, 3.0, 0.05, "drive reading x gain")
    target = "voltage_gain"


@register
@dataclass(frozen=True)
class VibrometerGain(_Instrument):
    name = "vibrometer_gain"
    title = "vibrometer calibration (gain)"
    family = "vibrometer"
    gain: float = param("-", 1.0, 0.2, 5.0, 0.05, "tip-velocity reading x gain")
    target = "tip_gain"


@register
@dataclass(frozen=True)
class VibrometerDelay(_Instrument):
    name = "vibrometer_delay"
    title = "vibrometer lag (a phase growing with frequency)"
    family = "vibrometer"
    delay: float = param("ms", 0.0, -20.0, 20.0, 0.5, "tip-velocity reading delayed by this")
    target = "tip_delay_s"
    how = "add"


@register
@dataclass(frozen=True)
class CurrentMonitorGain(_Instrument):
    name = "current_monitor_gain"
    title = "current monitor calibration (gain)"
    family = "current monitor"
    gain: float = param("-", 1.0, 0.2, 5.0, 0.05, "current reading x gain")
    target = "current_gain"


@register
@dataclass(frozen=True)
class CurrentMonitorDelay(_Instrument):
    """A lagging current monitor: ``mean(v i)`` picks up ``(1/2) V^2 w^2 C_eq tau``, a loss growing as f^2."""

    name = "current_monitor_delay"
    title = "current monitor lag (a power loss growing as f^2)"
    family = "current monitor"
    delay: float = param("ms", 0.0, -20.0, 20.0, 0.2, "current reading delayed by this")
    target = "current_delay_s"
    how = "add"


# --- drifts in time -------------------------------------------------------------------------------
# Quoted per hour of the run (the trial's start since the first trial's); a trial is short
# against them, so each sees its own value, constant.


class _Drift(Effect):
    target: ClassVar[str] = ""
    square: ClassVar[bool] = False  # the drifting quantity enters squared (a frequency)

    def _factor(self, time_s: FloatArray | float) -> FloatArray:
        x = np.maximum(1.0 + float(self.values[0]) * 1e-2 * np.asarray(time_s, float) / 3600.0, 0.05)
        return np.asarray(x**2 if self.square else x)

    def describe(self, k: Knobs, op: OperatingPoint) -> Knobs:
        return replace(k, **{self.target: getattr(k, self.target) * self._factor(op.time_s)})

    def law(
        self,
        law: TimeLaw,
        fin: Fin,
        frequency_hz: FloatArray,
        voltage_pp: FloatArray,
        time_s: FloatArray | float = 0.0,
    ) -> TimeLaw:
        return replace(law, **{self.target: getattr(law, self.target) * self._factor(time_s)})


def sole_target(e: Effect) -> str | None:
    """The one knob ``e`` sets, where its describing function sets that one alone (a coefficient's or
    a drift's, not overridden); None for any other effect."""
    describe = type(e).describe
    if describe is Coefficient.describe or describe is _Drift.describe:
        return str(type(e).target)  # type: ignore[attr-defined]
    return None


def _describe_in_turn(k: Knobs, effects: Iterable[Effect], op: OperatingPoint) -> Knobs:
    """Each effect's describing function in turn, a run of coefficients (each setting its target
    alone, as :meth:`Coefficient.describe` does, the same arithmetic in the same order) copied into
    the knobs once: a dozen copies a solve were a tenth of a fish controller's fit."""
    pending: dict[str, Any] = {}
    omega = None
    for e in effects:
        cls = type(e)
        if cls.describe is Coefficient.describe and cls._apply is Coefficient._apply:  # type: ignore[attr-defined]
            c: Coefficient = e  # type: ignore[assignment]
            if omega is None:
                omega = op.omega
            old = pending[c.target] if c.target in pending else getattr(k, c.target)
            x = c.amount(op.fin, omega, op.voltage_pp)
            pending[c.target] = old * x if c.how == "scale" else (old + x if c.how == "add" else x)
            continue
        if pending:
            k, pending = replace(k, **pending), {}
        k = e.describe(k, op)
    return replace(k, **pending) if pending else k


@register
@dataclass(frozen=True)
class ResonanceDrift(_Drift):
    name = "resonance_drift"
    title = "resonance drifting over the run (warming, water uptake)"
    family = "drift in time"
    rate: float = param("%/h", 0.0, -200.0, 200.0, 5.0, "natural frequency x (1 + rate t)")
    target = "stiffness"
    square = True


@register
@dataclass(frozen=True)
class CapacitanceDrift(_Drift):
    name = "capacitance_drift"
    title = "capacitance drifting over the run (the MFC warming)"
    family = "drift in time"
    rate: float = param("%/h", 0.0, -200.0, 200.0, 5.0, "C_eq x (1 + rate t)")
    target = "capacitance"


@register
@dataclass(frozen=True)
class CouplingDrift(_Drift):
    name = "coupling_drift"
    title = "coupling drifting over the run (the MFC warming, depoling)"
    family = "drift in time"
    rate: float = param("%/h", 0.0, -200.0, 200.0, 5.0, "theta x (1 + rate t)")
    target = "coupling"
