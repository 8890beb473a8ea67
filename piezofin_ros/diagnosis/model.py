r"""The model with candidate effects added: a steady state that every effect can modify.

Each unmodelled effect is a small class (:class:`Effect`) with named parameters that *modifies
the coefficients* of the single-term harmonic balance (Eqs. 15-18, see :mod:`piezofin_ros.steady`)
and of the measurement chain, possibly as functions of the operating point and of the tip
amplitude.  With :class:`Knobs` ``s`` (stiffness), ``m`` (added mass), ``c`` (structural damping),
``g`` (drag), ``q`` (coupling) and ``r`` (effective over nominal voltage)::

    a = s wn^2 - (1 + m mu) w^2,   d = c 2 zeta wn w + g (8 / 3 pi) gamma w^2 A,   F = q theta r V

    A^2 (a^2 + d^2) = F^2                                   (the quartic of steady.py)

    U_1 = j w phi(L) (H0 - j H1)                            tip-velocity phasor (V real)
    I_1 = (G_loss + j w C_eq) r V + q theta j w (H0 - j H1)  Eq. (10) plus a loss current
    P   = (1/2) q theta w r V H1 + (1/2) G_loss (r V)^2       mean(v i); G_loss: loss conductance
    T   = gain (1/2) m m_v [u^2 - U^2 (phi'/phi)^2 x^2] + bias   Eqs. (19)-(20), load cell

When a knob depends on the amplitude (``A`` enters through the tip amplitude ``X = phi(L) A``
or the Keulegan-Carpenter number ``KC = 2 pi X / b``), the balance is a fixed point in ``A``: it
is iterated from the nominal solution with under-relaxation in ``log A`` until it settles (on
a softening branch with several solutions this finds the one continued from the nominal model).

Adding an effect is adding one class: declare its parameters, write :meth:`Effect.apply`, and
register it in :data:`LIBRARY`.  Every effect is neutral at its ``neutral`` parameter values, so
the nominal model is the augmented model with no effect.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..fin import Fin, FinConfigError, read_yaml_file
from ..knobs import Knobs
from ..steady import DRAG_HARMONIC, solve_amplitude

FloatArray = NDArray[Any]
V_REF = 800.0  # Vpp: voltage-dependent effects are quoted at this drive


class ModelError(ValueError):
    """An augmented model is malformed (unknown effect, wrong parameter, out of range)."""


@dataclass(frozen=True)
class OperatingPoint:
    """What an effect may depend on, as arrays over trials (SI; ``voltage_pp`` nominal)."""

    fin: Fin
    frequency_hz: FloatArray
    voltage_pp: FloatArray
    tip_amplitude: FloatArray  # X = phi(L) A, m (current iterate)

    @property
    def omega(self) -> FloatArray:
        return 2 * math.pi * self.frequency_hz

    @property
    def kc(self) -> FloatArray:
        """Keulegan-Carpenter number of the tip, ``2 pi X / b``."""
        return 2 * math.pi * self.tip_amplitude / self.fin.b


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


class Effect:
    """One candidate unmodelled effect.  Subclasses set the class attributes and :meth:`apply`."""

    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    params: ClassVar[tuple[Param, ...]] = ()
    amplitude_dependent: ClassVar[bool] = False

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        raise NotImplementedError

    @classmethod
    def neutral(cls) -> NDArray[np.float64]:
        return np.array([q.neutral for q in cls.params], dtype=float)


# --- the library -------------------------------------------------------------------------------


class ResonanceOffset(Effect):
    name = "resonance_offset"
    title = "stiffness off (in-water resonance shifted, linear)"
    params = (Param("scale", "-", 1.0, 0.3, 2.0, 0.1, "natural frequency x scale"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.stiffness = k.stiffness * p[0] ** 2


class Duffing(Effect):
    name = "stiffness_nonlinearity"
    title = "geometric stiffness nonlinearity (Duffing, amplitude-dependent)"
    params = (Param("beta", "-", 0.0, -5000.0, 5000.0, 20.0, "wn^2 x (1 + beta (X/L)^2)"),)
    amplitude_dependent = True

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        x = op.tip_amplitude / op.fin.L
        k.stiffness = k.stiffness * np.maximum(1.0 + p[0] * x * x, 0.01)


class Electroelastic(Effect):
    name = "electroelastic_softening"
    title = "electroelastic softening (stiffness falls with the field)"
    params = (Param("softening", "-", 0.0, -0.5, 0.9, 0.1, "wn x (1 - s Vpp/800)"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.stiffness = k.stiffness * np.maximum(1.0 - p[0] * op.voltage_pp / V_REF, 0.05) ** 2


class NonlinearDamping(Effect):
    name = "nonlinear_damping"
    title = "internal dissipative nonlinearity (damping grows with amplitude)"
    params = (Param("q", "-", 0.0, -1.0, 2000.0, 10.0, "zeta x (1 + q X/L)"),)
    amplitude_dependent = True

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.damping = k.damping * np.maximum(1.0 + p[0] * op.tip_amplitude / op.fin.L, 0.01)


class AddedMassOffset(Effect):
    name = "added_mass_offset"
    title = "inertia coefficient c_m off the curve of Eq. (21)"
    params = (Param("scale", "-", 1.0, 0.1, 4.0, 0.2, "c_m x scale"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.mass = k.mass * p[0]


class AddedMassKC(Effect):
    name = "added_mass_kc"
    title = "amplitude-dependent added mass (Keulegan-Carpenter)"
    params = (Param("a", "-", 0.0, -0.8, 5.0, 0.2, "c_m x (1 + a KC)"),)
    amplitude_dependent = True

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.mass = k.mass * np.maximum(1.0 + p[0] * op.kc, 0.05)


class DragOffset(Effect):
    name = "drag_offset"
    title = "drag coefficient c_d off the assumed value"
    params = (Param("scale", "-", 1.0, 0.0, 20.0, 0.5, "c_d x scale"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.drag = k.drag * p[0]


class DragKC(Effect):
    name = "drag_kc"
    title = "amplitude-dependent drag coefficient (c_d ~ KC^-n, Graham)"
    params = (Param("n", "-", 0.0, -2.0, 2.0, 0.2, "c_d x KC^-n"),)
    amplitude_dependent = True

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.drag = k.drag * np.maximum(op.kc, 1e-3) ** (-p[0])


class DielectricLoss(Effect):
    name = "dielectric_loss"
    title = "dielectric loss of the piezoceramic (tan delta)"
    params = (Param("tan_delta", "-", 0.0, 0.0, 0.5, 0.02, "P += tan(delta) C_eq w V^2 / 2"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.loss_conductance = k.loss_conductance + p[0] * op.fin.C_eq * op.omega


class Leakage(Effect):
    name = "leakage"
    title = "resistive leakage of the drive (frequency-independent loss)"
    params = (Param("conductance", "uS", 0.0, 0.0, 50.0, 1.0, "P += G V^2 / 2"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.loss_conductance = k.loss_conductance + p[0] * 1e-6


class SwimSpeed(Effect):
    name = "swim_speed"
    title = "flow past the fin (U != 0 in Eq. 19)"
    params = (Param("U", "m/s", 0.0, 0.0, 5.0, 0.05, "free-stream speed"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.swim_speed = p[0]


class AmplifierLimit(Effect):
    """The amplifier clips at the voltage where its current limit is reached, ``c = I_max / (C_eq w)``.

    A sine of amplitude ``V`` clipped at ``c < V`` keeps a fundamental of amplitude
    ``(2 V / pi) (asin r + r sqrt(1 - r^2))`` with ``r = c / V`` (its describing function).
    """

    name = "amplifier_limit"
    title = "amplifier current limit (the drive clips at high f x V)"
    params = (
        Param(
            "inv_i_max",
            "1/mA",
            0.0,
            0.0,
            50.0,
            1.0,
            "1 / peak current the amplifier delivers",
            (0.5, 2.0, 8.0, 30.0),
        ),
    )

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        v = 0.5 * op.voltage_pp
        with np.errstate(divide="ignore"):
            clip = np.where(p[0] > 0, 1e-3 / (p[0] * op.fin.C_eq * op.omega), np.inf)
        r = np.clip(clip / np.maximum(v, 1e-12), 0.0, 1.0)
        alpha = np.arcsin(r)
        fundamental = (2 / math.pi) * (alpha + r * np.sqrt(1 - r * r))
        k.voltage = k.voltage * fundamental
        # C dv/dt of the clipped sine: mean square (V w)^2 (2 alpha + sin 2 alpha) / (2 pi), of which
        # the fundamental carries (fundamental V w)^2 / 2; the rest is harmonic current.
        ms = (2 * alpha + np.sin(2 * alpha)) / (2 * math.pi) - 0.5 * fundamental**2
        k.current_harmonics_a2 = k.current_harmonics_a2 + (op.fin.C_eq * op.omega * v) ** 2 * np.maximum(
            ms, 0.0
        )


class LoadcellOffset(Effect):
    name = "loadcell_offset"
    title = "thrust transducer drift not cancelled by the baselines (offset)"
    params = (Param("bias", "mN", 0.0, -50.0, 50.0, 0.2, "added to the load-cell thrust"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.thrust_bias_n = k.thrust_bias_n + p[0] * 1e-3


class LoadcellGain(Effect):
    name = "loadcell_gain"
    title = "thrust transducer calibration (gain)"
    params = (Param("gain", "-", 1.0, 0.1, 5.0, 0.2, "load-cell thrust x gain"),)

    def apply(self, k: Knobs, op: OperatingPoint, p: Sequence[float]) -> None:
        k.thrust_gain = k.thrust_gain * p[0]


LIBRARY: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (
        ResonanceOffset,
        Duffing,
        Electroelastic,
        NonlinearDamping,
        AddedMassOffset,
        AddedMassKC,
        DragOffset,
        DragKC,
        DielectricLoss,
        Leakage,
        SwimSpeed,
        AmplifierLimit,
        LoadcellOffset,
        LoadcellGain,
    )
}


# --- the augmented model -----------------------------------------------------------------------


@dataclass(frozen=True)
class Prediction:
    """Steady-state channels on a set of operating points (arrays, SI)."""

    voltage_pp_drive: FloatArray  # V, the drive the fin receives
    tip_velocity_rms: FloatArray  # m/s, fundamental
    tip_phase_rad: FloatArray  # phase of the tip velocity relative to the drive voltage
    current_rms: FloatArray  # A, fundamental
    power_w: FloatArray  # W
    thrust_n: FloatArray  # N, Lighthill on the motion (what the vibrometer gives)
    thrust_loadcell_n: FloatArray  # N, what the load cell reads

    @property
    def thrust_per_watt(self) -> FloatArray:
        p = self.power_w
        return np.divide(self.thrust_loadcell_n, p, out=np.zeros(np.shape(p)), where=p > 0)


@dataclass(frozen=True)
class Augmented:
    """A fin model plus effects with parameter values; ``Augmented(fin)`` is the nominal model."""

    fin: Fin
    effects: tuple[str, ...] = ()
    values: tuple[tuple[float, ...], ...] = ()
    notes: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if len(self.effects) != len(self.values):
            raise ModelError("one value tuple per effect")
        for name, vals in zip(self.effects, self.values, strict=True):
            cls = effect_class(name)
            if len(vals) != len(cls.params):
                raise ModelError(f"effect {name} takes {len(cls.params)} parameter(s), got {len(vals)}")
            for q, v in zip(cls.params, vals, strict=True):
                if not (math.isfinite(v) and q.lower <= v <= q.upper):
                    raise ModelError(
                        f"effect {name}: parameter {q.name} = {v!r} outside [{q.lower}, {q.upper}] {q.unit}"
                    )

    @classmethod
    def of(cls, fin: Fin, params: Mapping[str, Sequence[float]] | None = None) -> Augmented:
        params = params or {}
        return cls(fin, tuple(params), tuple(tuple(float(x) for x in v) for v in params.values()))

    def parameters(self) -> dict[str, dict[str, float]]:
        return {
            name: {q.name: v for q, v in zip(effect_class(name).params, vals, strict=True)}
            for name, vals in zip(self.effects, self.values, strict=True)
        }

    def predict(
        self, frequency_hz: ArrayLike, voltage_pp: ArrayLike, drive_pp: ArrayLike | None = None
    ) -> Prediction:
        """Steady state at nominal (commanded) voltages ``voltage_pp``.  With ``drive_pp`` (the measured
        fundamental of the drive, Vpp) the fin is driven by that instead of by the model's drive."""
        return predict(
            self.fin,
            self.instances(),
            frequency_hz,
            voltage_pp,
            drive_pp=drive_pp,
        )

    def instances(self) -> list[tuple[Effect, tuple[float, ...]]]:
        return [(effect_class(n)(), v) for n, v in zip(self.effects, self.values, strict=True)]

    def knobs_at(self, frequency_hz: float, voltage_pp: float) -> Knobs:
        """The knobs (floats) at this operating point's steady state: the linearisation that the
        streaming rig integrates, so that its steady state is this model's (see :mod:`..rig`)."""
        f, v = np.array([float(frequency_hz)]), np.array([float(voltage_pp)])
        k, _ = steady_knobs(self.fin, self.instances(), f, v)
        return Knobs(**{n: float(np.asarray(getattr(k, n))[0]) for n in Knobs.__dataclass_fields__})

    # --- persistence (safe YAML; loaded by fin_sim, the controller and sweep) ---------------
    def to_mapping(self) -> dict[str, Any]:
        return {
            "fin": self.fin.inputs(),
            "effects": self.parameters(),
            **({"notes": dict(self.notes)} if self.notes else {}),
        }

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "<mapping>") -> Augmented:
        if not isinstance(data, Mapping) or "fin" not in data:
            raise ModelError(f"{source}: an augmented model needs a 'fin' mapping")
        fin = Fin.from_mapping(data["fin"], source=source)
        effects = data.get("effects") or {}
        if not isinstance(effects, Mapping):
            raise ModelError(f"{source}: 'effects' must map effect names to parameter mappings")
        names, values = [], []
        for name, params in effects.items():
            ecls = effect_class(str(name), source)
            if not isinstance(params, Mapping):
                raise ModelError(f"{source}: effects.{name} must map parameter names to numbers")
            unknown = set(params) - {q.name for q in ecls.params}
            if unknown:
                raise ModelError(f"{source}: effects.{name} has unknown parameter(s) {sorted(unknown)}")
            vals = []
            for q in ecls.params:
                v = params.get(q.name, q.neutral)
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ModelError(f"{source}: effects.{name}.{q.name} must be a number, got {v!r}")
                vals.append(float(v))
            names.append(str(name))
            values.append(tuple(vals))
        try:
            return cls(fin, tuple(names), tuple(values), dict(data.get("notes") or {}))
        except ModelError as exc:
            raise ModelError(f"{source}: {exc}") from None


def load_augmented(path: str) -> Augmented:
    """Read an augmented model (``augmented_model.yaml`` from ``diagnose --report``) as safe YAML.

    Raises :class:`ModelError` naming the file and the problem (missing, unreadable, not YAML,
    unknown effect or parameter, value out of range, bad fin).
    """
    data = read_yaml_file(path, ModelError)
    try:
        return Augmented.from_mapping(data, source=path)
    except FinConfigError as exc:
        raise ModelError(str(exc) if path in str(exc) else f"{path}: {exc}") from None


@dataclass(frozen=True)
class ParamSpace:
    """The stacked parameters of several effects, as one vector for an optimiser.

    The optimiser works in scaled units ``z = (x - neutral) / scale``; :meth:`model` builds the
    :class:`Augmented` model of a scaled vector (clipped into the bounds).
    """

    fin: Fin
    names: tuple[str, ...]

    @property
    def params(self) -> list[Param]:
        return [q for n in self.names for q in effect_class(n).params]

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

    def model(self, z: ArrayLike) -> Augmented:
        lo, hi = self.z_bounds
        x = self.neutral + np.clip(np.asarray(z, float), lo, hi) * self.scale
        vals, j = [], 0
        for n in self.names:
            size = len(effect_class(n).params)
            vals.append(tuple(float(v) for v in x[j : j + size]))
            j += size
        return Augmented(self.fin, self.names, tuple(vals))


def effect_class(name: str, source: str = "") -> type[Effect]:
    try:
        return LIBRARY[name]
    except KeyError:
        where = f"{source}: " if source else ""
        raise ModelError(f"{where}unknown effect {name!r}; known: {', '.join(LIBRARY)}") from None


def steady_knobs(
    fin: Fin,
    effects: Sequence[tuple[Effect, Sequence[float]]],
    f: FloatArray,
    vpp: FloatArray,
    measured: FloatArray | None = None,
    iterations: int = 40,
) -> tuple[Knobs, FloatArray]:
    """The knobs (arrays shaped like ``f``) at the steady state, and its modal amplitude ``A``.

    ``f`` and ``vpp`` are broadcast arrays; ``measured``, if given, the drive that moves the fin.
    With amplitude-dependent effects ``A`` solves ``A = A_lin(knobs(A))`` (the describing function):
    an under-relaxed fixed-point iteration, and where it does not settle (a softening spring's
    jump region, where several amplitudes are steady), the *lowest* root, found by a scan in log A
    and bisection: the steady state a trial reaches when it starts from rest, as the protocol does.
    """
    phi = fin.phi_tip
    amp_dep = any(e.amplitude_dependent for e, _ in effects)

    def knobs(ff: FloatArray, vv: FloatArray, x: FloatArray) -> Knobs:
        k = Knobs()
        op = OperatingPoint(fin, ff, vv, x)
        for e, p in effects:
            e.apply(k, op, p)
        return k

    def solve(ff: FloatArray, vv: FloatArray, mm: FloatArray | None, amp: FloatArray) -> FloatArray:
        """The linear steady amplitude with the knobs frozen at amplitude ``amp``."""
        k = knobs(ff, vv, phi * amp)
        return solve_amplitude(*_coefficients(fin, 2 * math.pi * ff, k, vv, mm))

    amp = solve(f, vpp, measured, np.zeros_like(f))
    if amp_dep:
        for _ in range(iterations):
            new = solve(f, vpp, measured, amp)
            ok = (new > 0) & (amp > 0)
            # under-relaxed in log A: softening branches overshoot otherwise
            nxt = np.where(
                ok, np.exp(0.5 * np.log(np.where(ok, new, 1)) + 0.5 * np.log(np.where(ok, amp, 1))), new
            )
            done = np.all(np.abs(nxt - amp) <= 1e-9 * np.maximum(amp, 1e-30))
            amp = nxt
            if done:
                break
        bad = ~(np.abs(solve(f, vpp, measured, amp) - amp) <= 1e-6 * amp)
        if np.any(bad):
            amp = np.array(amp, dtype=float)
            fb, vb = f[bad], vpp[bad]
            mb = None if measured is None else np.broadcast_to(measured, f.shape)[bad]
            amp[bad] = _lowest_root(
                lambda x, j: solve(fb[j], vb[j], None if mb is None else mb[j], x), amp[bad]
            )
    k = knobs(f, vpp, phi * amp)
    kk = Knobs(
        **{n: np.broadcast_to(np.asarray(getattr(k, n), float), f.shape) for n in Knobs.__dataclass_fields__}
    )
    return kk, amp


def _lowest_root(
    g: Callable[[FloatArray, Any], FloatArray], guess: FloatArray, span: tuple[float, float] = (1e-4, 1e3)
) -> FloatArray:
    """Lowest ``A > 0`` with ``g(A) = A`` per point (``g(x, j)``: ``x`` shaped like the index ``j``).

    Scanned on a log grid ``span`` x ``guess`` for the first crossing of ``log g(A) - log A`` from
    above, then bisected in log A.  Points with no crossing keep ``guess``.
    """
    n = guess.size
    grid = guess[:, None] * np.geomspace(*span, 72)[None, :]
    rows = np.repeat(np.arange(n), grid.shape[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(g(grid.ravel(), rows)).reshape(grid.shape) - np.log(grid)
    down = (r[:, :-1] > 0) & (r[:, 1:] <= 0)
    found = down.any(axis=1)
    first = np.argmax(down, axis=1)
    idx = np.arange(n)
    lo, hi = np.log(grid[idx, first]), np.log(grid[idx, first + 1])
    for _ in range(40):  # the bracket is a factor 1.2 wide: 40 halvings reach round-off
        mid = 0.5 * (lo + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            above = np.log(g(np.exp(mid), idx)) > mid
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    return np.where(found, np.exp(0.5 * (lo + hi)), guess)


def _drive(k: Knobs, vpp: FloatArray, measured: FloatArray | None) -> FloatArray:
    return vpp * k.voltage if measured is None else measured


def _coefficients(
    fin: Fin, w: FloatArray, k: Knobs, vpp: FloatArray, measured: FloatArray | None
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``a, c0, k, force`` of the quartic (steady.py) with the knobs applied."""
    a = fin.omega_n**2 * k.stiffness - (1 + fin.mu * k.mass) * w * w
    c0 = 2 * fin.zeta * fin.omega_n * w * k.damping
    kd = DRAG_HARMONIC * fin.gamma * k.drag * w * w
    return a, c0, kd, fin.theta * k.coupling * 0.5 * _drive(k, vpp, measured)


def predict(
    fin: Fin,
    effects: Iterable[tuple[Effect, Sequence[float]]],
    frequency_hz: ArrayLike,
    voltage_pp: ArrayLike,
    *,
    drive_pp: ArrayLike | None = None,
    iterations: int = 40,
) -> Prediction:
    """Steady state of ``fin`` with ``effects`` (instances with parameter values), vectorised.

    ``voltage_pp`` is the nominal drive; ``drive_pp``, if given, the measured one that moves the fin.
    """
    f, vpp = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
    measured = None if drive_pp is None else np.broadcast_to(np.asarray(drive_pp, float), f.shape)
    w = 2 * math.pi * f
    phi = fin.phi_tip
    kk, amp = steady_knobs(fin, list(effects), f, vpp, measured, iterations)
    a, c0, kd, force = _coefficients(fin, w, kk, vpp, measured)
    d = c0 + kd * amp
    v_amp = 0.5 * _drive(kk, vpp, measured)
    den = a * a + d * d
    with np.errstate(invalid="ignore", divide="ignore"):
        h0 = np.where(den > 0, force * a / den, 0.0)
        h1 = np.where(den > 0, force * d / den, 0.0)
    vel = 1j * w * (h0 - 1j * h1)  # modal velocity phasor
    tip = phi * vel
    current = (kk.loss_conductance + 1j * w * fin.C_eq) * v_amp + fin.theta * kk.coupling * vel
    power = 0.5 * v_amp * np.real(current)
    u_ms = 0.5 * np.abs(tip) ** 2
    x_ms = 0.5 * (fin.phi_tip_slope * amp) ** 2
    thrust = 0.5 * fin.m_v * kk.mass * (u_ms - kk.swim_speed**2 * x_ms)
    return Prediction(
        voltage_pp_drive=vpp * kk.voltage,
        tip_velocity_rms=np.sqrt(u_ms),
        tip_phase_rad=np.angle(tip),
        current_rms=np.sqrt(0.5 * np.abs(current) ** 2 + kk.current_harmonics_a2),
        power_w=power,
        thrust_n=thrust,
        thrust_loadcell_n=kk.thrust_gain * thrust + kk.thrust_bias_n,
    )
