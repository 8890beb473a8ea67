r"""A fish that swims on its fins: the body's surge, the battery that the amplifier drains, and
what a builder asks of them: how fast, and how far on one charge.

**Thrust at a swimming speed.**  Lighthill's mean thrust, Eq. (19) with its ``U`` term, at the tip
``x = L`` of a clamped fin whose tip moves as ``w(L, t)`` (fundamental at ``omega``):

.. math::

    T(U) = \tfrac12 m_v\,[\overline{w_t^2} - U^2\,\overline{w_x^2}]
         = T_0\,\Bigl[1 - \Bigl(\frac{U}{c}\Bigr)^2\Bigr],\qquad
    c = \frac{\omega\,\phi(L)}{\phi'(L)} = \frac{\omega L}{1.3765},

since the slope at the tip is ``phi'(L)/phi(L)`` times its displacement (the first mode, Eq. 5)
and ``w_t = omega w`` for the fundamental: the faster the fish, the less each stroke gives, and a
fin beating at ``f`` gives nothing beyond ``c`` (2 m/s for M8528-P1 at 5 Hz).

**The body.**  Surge of a rigid body of mass ``m`` and added mass ``m_a`` carrying ``n`` fins,

.. math::

    (m + m_a)\,\dot U = n\,T(U) - \tfrac12\rho\,C_D S\,U|U| - b\,U,

a quadratic (form) drag with the drag area ``C_D S`` and an optional linear (skin friction at low
Reynolds number) term ``b``.  Its steady speed solves ``n T_0 (1 - U^2/c^2) = (1/2) rho C_D S U^2
+ b U`` in closed form (:meth:`Body.steady_speed`), and it settles with the time constant
``(m + m_a) / (dD/dU + 2 n T_0 U / c^2)`` at that speed.

**The battery.**  ``cells`` in series, each with an open-circuit voltage that falls with the state
of charge (a table, interpolated), an internal resistance ``R`` and a capacity in A h.  Drawing a
power ``P`` (the amplifier's supply power plus the fish's hotel load: the microcontroller, the
sensors) takes the current ``I = (E - sqrt(E^2 - 4 R P)) / (2 R)`` at the EMF ``E``, and the
terminal voltage is ``E - R I``: it falls with the charge and under load.  One charge lasts
``integral 3600 C dq / I(q, P)`` from full to where the terminal voltage reaches the cut-off
(:meth:`Battery.endurance_s`), and a fish at a steady speed ``U`` goes ``U`` times that: the range.
The cost of transport is ``P / (m g U)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError
from . import modeshape
from .fin import preset_path, presets, read_yaml_file

FloatArray = NDArray[np.float64]
G = 9.81
#: ``phi'(L) / phi(L)`` of the first clamped-free mode, times ``L`` (Eq. 5: 1.3765).
TIP_SLOPE_L = modeshape.TIP_SLOPE_RATIO


class SwimError(PhysicsError):
    """A body or a battery that cannot be (negative mass, zero capacity, ...): one line, the field."""


def bending_speed(frequency_hz: ArrayLike | None, length_m: float | None) -> FloatArray:
    """``c = omega L / 1.3765``: the swimming speed at which a fin beating at ``f`` gives no thrust
    (infinite without a frequency: Eq. (19)'s speed term left out)."""
    if frequency_hz is None or length_m is None:
        return np.asarray(np.inf)
    return 2 * math.pi * np.asarray(frequency_hz, float) * length_m / TIP_SLOPE_L  # type: ignore[no-any-return]


def thrust_at_speed(
    thrust0_n: ArrayLike, frequency_hz: ArrayLike | None, length_m: float | None, U: ArrayLike
) -> FloatArray:
    """Eq. (19) with its ``U`` term: ``T_0 (1 - (U / c)^2)`` (module docstring), N."""
    c = bending_speed(frequency_hz, length_m)
    return np.asarray(thrust0_n, float) * (1.0 - (np.asarray(U, float) / c) ** 2)  # type: ignore[no-any-return]


#: The most each field may be (SI, generous: any fish, from a robot to an AUV, is well inside).  A
#: number beyond is no body or battery: a drag area of 1e300 m^2 printed a table of 150-digit joules
#: per metre and a speed of 0.00, and a hotel load of 1e308 W an infinite one.
MOST = {
    "mass_kg": 1e3,
    "added_mass_kg": 1e3,
    "length_m": 20.0,
    "height_m": 10.0,
    "width_m": 10.0,
    "drag_area_m2": 10.0,
    "drag_linear_n_s_m": 1e3,
    "rho_w": 2e3,
    "capacity_ah": 1e4,
    "internal_resistance_ohm": 100.0,
    "cutoff_v_per_cell": 10.0,
    "hotel_w": 1e4,
}
#: The least (beyond "> 0"): a water that is no water, and a body or battery too small to be one (a
#: body of 1e-300 kg printed a 300-digit cost of transport, a drag area of 1e-300 "below nan mW").
LEAST = {
    "rho_w": 500.0,
    "mass_kg": 1e-3,
    "length_m": 1e-3,
    "height_m": 1e-3,
    "width_m": 1e-3,
    "drag_area_m2": 1e-8,
    "capacity_ah": 1e-4,
    "internal_resistance_ohm": 1e-4,
    "cutoff_v_per_cell": 0.5,
}
#: The fastest a fish's speed reading may be, m/s (either way): beyond, it is no speed of any fish
#: (one reading of 1e308 m/s overflowed Eq. (19)'s U^2 term and killed the estimator).
SPEED_MOST_M_S = 20.0
#: An open-circuit voltage per cell beyond this is no cell of any chemistry, V.
MOST_CELL_V = 10.0


def _positive(source: str, name: str, value: Any, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SwimError(f"{source}: {name} must be a number, got {value!r}")
    x = float(value)
    most, least = MOST.get(name, math.inf), LEAST.get(name, 0.0)
    if not math.isfinite(x) or x < least or (x == 0 and not allow_zero) or x > most:
        low = f"[{least:g}" if allow_zero or least > 0 else f"({least:g}"
        raise SwimError(f"{source}: {name} = {value!r} must be finite and within {low}, {most:g}]")
    return x


@dataclass(frozen=True)
class Body:
    """The fish's body in surge (module docstring).  SI units; every field is checked."""

    name: str = "body"
    mass_kg: float = 0.45
    added_mass_kg: float = 0.045  # surge added mass of a slender body, about 10 % of its mass
    length_m: float = 0.25  # body length (speeds are quoted in body lengths per second)
    height_m: float = 0.10  # depth, top to bottom (the side's area, the sway added mass: planar.py)
    width_m: float = 0.06  # side to side (the yaw inertia; two fins' spacing)
    drag_area_m2: float = 1.8e-3  # C_D S
    drag_linear_n_s_m: float = 0.0  # b
    fins: int = 1
    rho_w: float = 1000.0
    source: str = ""  # where the numbers come from

    def __post_init__(self) -> None:
        where = self.name or "body"
        for name in ("mass_kg", "length_m", "height_m", "width_m", "drag_area_m2", "rho_w"):
            _positive(where, name, getattr(self, name))
        for name in ("added_mass_kg", "drag_linear_n_s_m"):
            _positive(where, name, getattr(self, name), allow_zero=True)
        if isinstance(self.fins, bool) or not isinstance(self.fins, int) or not 1 <= self.fins <= 4:
            raise SwimError(f"{where}: fins = {self.fins!r} must be 1, 2, 3 or 4")

    # The drag law and its closed forms, side by side (each tested against the others): the law, its
    # slope, the speed it balances and the surge equation.  Every other module takes them from here.
    def drag_n(self, U: ArrayLike) -> FloatArray:
        """``D(U) = (1/2) rho C_D S U |U| + b U``, N."""
        u = np.asarray(U, float)
        return 0.5 * self.rho_w * self.drag_area_m2 * u * np.abs(u) + self.drag_linear_n_s_m * u  # type: ignore[no-any-return]

    def drag_slope_n_s_m(self, U: ArrayLike) -> FloatArray:
        """``dD/dU = rho C_D S |U| + b``, N s/m: the body's own damping at ``U``."""
        return self.rho_w * self.drag_area_m2 * np.abs(np.asarray(U, float)) + self.drag_linear_n_s_m  # type: ignore[no-any-return]

    def steady_speed(
        self, thrust0_n: ArrayLike, frequency_hz: ArrayLike | None = None, fin_length_m: float | None = None
    ) -> FloatArray:
        """The speed at which ``fins`` fins of still-water thrust ``thrust0_n`` (each, at
        ``frequency_hz``) balance the drag, m/s (0 without thrust): the positive root of
        ``D(U) = n T_0 (1 - (U/c)^2)``; without a frequency, of ``D(U) = n T_0`` (no speed term).
        As ``2 T / (b + sqrt(b^2 + 4 a T))`` with numerator and denominator divided by ``sqrt(T)``, and
        ``sqrt(a)`` as the ``hypot`` of its two terms' roots: no cancellation at a small thrust, no
        overflow at an absurd one (1e300 N overflowed ``4 a T``), every float of thrust to the last bits."""
        t0 = np.maximum(np.asarray(thrust0_n, float), 0.0) * self.fins
        c = bending_speed(frequency_hz, fin_length_m)
        b = self.drag_linear_n_s_m
        with np.errstate(divide="ignore", invalid="ignore"):  # (no thrust: 0 below)
            r = np.sqrt(t0)
            sqrt_a = np.hypot(r / c, math.sqrt(0.5 * self.rho_w * self.drag_area_m2))
            u = 2.0 * r / (b / r + np.hypot(b / r, 2.0 * sqrt_a))
        u = np.where(t0 > 0, u, 0.0)
        return u[()]  # type: ignore[no-any-return]  # (a scalar's a NumPy scalar, as before)

    def surge_acceleration(self, thrust_n: float, U: float) -> float:
        """The surge equation: ``dU/dt = (T - D(U)) / (m + m_a)`` for the fins' total thrust ``T`` at
        the speed ``U`` (negative where a fin slower than the fish drags), m/s^2."""
        return (thrust_n - float(self.drag_n(U))) / (self.mass_kg + self.added_mass_kg)

    def acceleration(
        self, U: float, thrust0_n: float, frequency_hz: float | None = None, fin_length_m: float | None = None
    ) -> float:
        """``dU/dt`` at speed ``U`` with ``fins`` fins of still-water thrust ``thrust0_n`` each (Eq. (19)'s
        speed term at ``frequency_hz``; none without one), m/s^2."""
        t = self.fins * float(thrust_at_speed(max(thrust0_n, 0.0), frequency_hz, fin_length_m, U))
        return self.surge_acceleration(t, U)

    def time_constant_s(
        self, thrust0_n: float, frequency_hz: float | None = None, fin_length_m: float | None = None
    ) -> float:
        """How fast a speed step settles: ``(m + m_a)`` over the slope of net drag at the steady speed."""
        U = float(self.steady_speed(thrust0_n, frequency_hz, fin_length_m))
        c = float(bending_speed(frequency_hz, fin_length_m))
        slope = float(self.drag_slope_n_s_m(U)) + 2 * self.fins * thrust0_n * U / c**2
        return (self.mass_kg + self.added_mass_kg) / slope if slope > 0 else math.inf

    def cost_of_transport(self, power_w: ArrayLike, U: ArrayLike) -> FloatArray:
        """``P / (m g U)`` (dimensionless; infinite at rest)."""
        u = np.asarray(U, float)
        return np.divide(
            np.asarray(power_w, float), self.mass_kg * G * u, out=np.full(u.shape, np.inf), where=u > 0
        )  # type: ignore[no-any-return]


#: A lithium-ion cell's open-circuit voltage against its state of charge (typical of LiCoO2 / NMC
#: cells at room temperature; stated, not measured here).
LI_ION_OCV = (
    (0.0, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0),
    (3.00, 3.30, 3.45, 3.55, 3.62, 3.68, 3.73, 3.79, 3.86, 3.95, 4.06, 4.20),
)


@dataclass(frozen=True)
class Battery:
    """``cells`` in series (module docstring); ``hotel_w`` is what the fish draws besides its fins."""

    name: str = "battery"
    cells: int = 2
    capacity_ah: float = 0.5
    internal_resistance_ohm: float = 0.15  # the pack's
    cutoff_v_per_cell: float = 3.2
    hotel_w: float = 0.25
    ocv_soc: tuple[float, ...] = LI_ION_OCV[0]
    ocv_v_per_cell: tuple[float, ...] = LI_ION_OCV[1]
    source: str = ""

    def __post_init__(self) -> None:
        where = self.name or "battery"
        if isinstance(self.cells, bool) or not isinstance(self.cells, int) or not 1 <= self.cells <= 24:
            raise SwimError(f"{where}: cells = {self.cells!r} must be a whole number within 1-24")
        _positive(where, "capacity_ah", self.capacity_ah)
        _positive(where, "internal_resistance_ohm", self.internal_resistance_ohm)
        _positive(where, "cutoff_v_per_cell", self.cutoff_v_per_cell)
        _positive(where, "hotel_w", self.hotel_w, allow_zero=True)
        try:
            soc, ocv = np.asarray(self.ocv_soc, float), np.asarray(self.ocv_v_per_cell, float)
        except (TypeError, ValueError):
            raise SwimError(f"{where}: ocv_soc and ocv_v_per_cell must be lists of numbers") from None
        if soc.ndim != 1 or not np.all(np.isfinite(soc)) or not np.all(np.isfinite(ocv)):
            raise SwimError(f"{where}: ocv_soc and ocv_v_per_cell must be finite numbers")
        if np.any(ocv <= 0) or np.any(ocv > MOST_CELL_V):
            raise SwimError(f"{where}: ocv_v_per_cell must be within (0, {MOST_CELL_V:g}] V per cell")
        if soc.size < 2 or soc.shape != ocv.shape or np.any(np.diff(soc) <= 0) or soc[0] != 0 or soc[-1] != 1:
            raise SwimError(f"{where}: ocv_soc must rise from 0 to 1, one ocv_v_per_cell for each")
        if np.any(~np.isfinite(ocv)) or np.any(np.diff(ocv) < 0) or ocv[-1] <= self.cutoff_v_per_cell:
            raise SwimError(
                f"{where}: ocv_v_per_cell must not fall with the charge and end above the cut-off"
            )
        most = self.max_power_w()
        if self.hotel_w >= most:  # (a hotel of 1e4 W on a 0.5 A h pack printed "+nan%")
            raise SwimError(
                f"{where}: hotel_w = {self.hotel_w:g} W is more than the pack delivers above its cut-off "
                f"when full ({most:.3g} W)"
            )

    def max_power_w(self) -> float:
        """The most the full pack delivers with its terminals at or above the cut-off, W: ``E I - r I^2``
        at the current that brings the terminals to the cut-off, or at ``E / 2r`` if that comes first."""
        e = float(self.emf_v(1.0))
        v_cut = self.cells * self.cutoff_v_per_cell
        r = self.internal_resistance_ohm
        current = min((e - v_cut) / r, e / (2 * r))
        return max(e * current - r * current * current, 0.0)

    def emf_v(self, soc: ArrayLike) -> FloatArray:
        """The pack's open-circuit voltage at the state of charge ``soc`` (0-1), V."""
        return self.cells * np.interp(np.asarray(soc, float), self.ocv_soc, self.ocv_v_per_cell)  # type: ignore[no-any-return]

    def current_a(self, soc: ArrayLike, power_w: ArrayLike) -> FloatArray:
        """The current that delivers ``power_w`` at the terminals (NaN beyond the pack's maximum power)."""
        e, p, r = self.emf_v(soc), np.asarray(power_w, float), self.internal_resistance_ohm
        disc = e * e - 4 * r * p
        with np.errstate(invalid="ignore"):
            return np.where(disc >= 0, (e - np.sqrt(np.maximum(disc, 0.0))) / (2 * r), np.nan)  # type: ignore[no-any-return]

    def terminal_v(self, soc: ArrayLike, power_w: ArrayLike) -> FloatArray:
        """The voltage the fish's electronics see while drawing ``power_w``, V."""
        return self.emf_v(soc) - self.internal_resistance_ohm * self.current_a(soc, power_w)  # type: ignore[no-any-return]

    def endurance_s(self, power_w: float, n: int = 400) -> float:
        """How long one charge delivers ``power_w`` (plus the hotel load), from full to the cut-off, s."""
        p = float(power_w) + self.hotel_w
        if not p > 0:
            return math.inf
        soc = np.linspace(1.0, 0.0, n + 1)
        current = self.current_a(soc, p)
        ok = np.isfinite(current) & (self.terminal_v(soc, p) >= self.cells * self.cutoff_v_per_cell)
        if not ok[0]:
            return 0.0
        last = int(np.argmin(ok)) if not ok.all() else n  # the first step past the cut-off
        dq = 3600.0 * self.capacity_ah / n
        return float(np.sum(dq / (0.5 * (current[:last] + current[1 : last + 1])))) if last > 0 else 0.0

    def range_m(self, power_w: ArrayLike, U: ArrayLike) -> FloatArray:
        """The distance one charge carries a fish at ``U`` drawing ``power_w`` for its fins, m."""
        p, u = np.broadcast_arrays(np.asarray(power_w, float), np.asarray(U, float))
        out = np.array([u_k * self.endurance_s(p_k) for p_k, u_k in zip(p.ravel(), u.ravel(), strict=True)])
        return out.reshape(p.shape)


def _from_mapping(cls: type[Any], data: Any, source: str, kind: str) -> Any:
    if not isinstance(data, Mapping):
        raise SwimError(f"{source}: expected a mapping of the {kind}'s fields")
    known = [f.name for f in fields(cls)]
    extra = sorted(str(k) for k in data if k not in known)
    if extra:
        raise SwimError(f"{source}: unknown key(s) {', '.join(extra)} for a {kind} ({', '.join(known)})")
    values = dict(data)
    for key in ("ocv_soc", "ocv_v_per_cell"):
        if key in values:
            if not isinstance(values[key], Sequence) or isinstance(values[key], str):
                raise SwimError(f"{source}: {key} must be a list of numbers")
            values[key] = tuple(values[key])
    try:
        return cls(**values)
    except SwimError as exc:
        raise SwimError(f"{source}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise SwimError(f"{source}: {exc}") from None


def load_body(name_or_path: str | os.PathLike[str]) -> Body:
    """A body preset by name (``config/bodies``) or a YAML file by path."""
    path = preset_path(name_or_path, "bodies", "body", SwimError)
    body: Body = _from_mapping(Body, _named(read_yaml_file(path, SwimError), path.stem), str(path), "body")
    return body


def load_battery(name_or_path: str | os.PathLike[str]) -> Battery:
    """A battery preset by name (``config/batteries``) or a YAML file by path."""
    path = preset_path(name_or_path, "batteries", "battery", SwimError)
    battery: Battery = _from_mapping(
        Battery, _named(read_yaml_file(path, SwimError), path.stem), str(path), "battery"
    )
    return battery


def _named(data: Any, name: str) -> Any:
    """A file's mapping, named after the file unless it names itself."""
    return {"name": name, **data} if isinstance(data, Mapping) else data


def body_presets() -> list[str]:
    return presets("bodies")


def battery_presets() -> list[str]:
    return presets("batteries")


@dataclass(frozen=True)
class Swim:
    """A fish at one operating point of its fins: the steady speed, the powers and what they give."""

    frequency_hz: float
    voltage_pp: float
    thrust0_n: float  # each fin, in still water
    speed_m_s: float
    supply_w: float  # the amplifier's draw for all fins
    range_m: float
    energy_per_m_j: float
    cost_of_transport: float
    extra: dict[str, float] = field(default_factory=dict)

    def record(self) -> dict[str, float]:
        return {**{k: v for k, v in asdict(self).items() if k != "extra"}, **self.extra}
