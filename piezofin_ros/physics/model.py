r"""The model: a fin plus effects, and its steady state (the harmonic balance with describing functions).

A :class:`Model` is a :class:`~piezofin_ros.physics.fin.Fin` and a tuple of
:class:`~piezofin_ros.physics.effects.Effect` objects; ``Model(fin)`` is the paper's model.  Its
steady state modifies the coefficients of the single-term harmonic balance (Eqs. 15-18, see
:mod:`.steady`) and of the measurement chain with each effect's describing function.  With
:class:`~.knobs.Knobs` ``s`` (stiffness), ``m`` (added mass), ``c`` (structural damping), ``g``
(drag), ``q`` (coupling) and ``r`` (effective over nominal voltage)::

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

The same model drives the time domain (:func:`.timedomain.simulate_law`, each effect's law), the
streaming rig (:meth:`Model.knobs_at`, the linearisation at the commanded point), the optimiser's
map (a correction is effects fitted on top of a model), the benchmark plants and the diagnosis.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ._compile import load as _load_compiler
from .effects import Effect, Effects, ModelError, OperatingPoint, TimeLaw, effect_class, make, sole_target
from .fin import Fin, FinConfigError, preset_path, presets, read_yaml_file
from .knobs import UNREAD_BY_AMPLITUDE, Knobs
from .steady import coefficients, solve_amplitude

FloatArray = NDArray[Any]


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
    #: the drive's fundamental admittance ``I_1 / V_1`` as the monitors read it, S (complex)
    admittance: FloatArray | None = None

    @property
    def thrust_per_watt(self) -> FloatArray:
        p = self.power_w
        return np.divide(self.thrust_loadcell_n, p, out=np.zeros(np.shape(p)), where=p > 0)


@dataclass(frozen=True)
class Model:
    """A fin plus effects; ``Model(fin)`` is the paper's model.  Compose with ``+``."""

    fin: Fin
    effects: tuple[Effect, ...] = ()
    notes: Mapping[str, Any] = field(default_factory=dict)
    #: one standard deviation of fitted parameters, ``{effect: {parameter: sigma}}`` (from the fit's
    #: Jacobian, :func:`piezofin_ros.diagnosis.attribute.fit`); empty for a model nobody fitted
    uncertainties: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "effects", Effects(self.effects))
        bad = [e for e in self.effects if not isinstance(e, Effect)]
        if bad:
            raise ModelError(f"not effects: {bad!r}")

    def __add__(self, other: Effect | Iterable[Effect]) -> Model:
        more = (other,) if isinstance(other, Effect) else tuple(other)
        return Model(self.fin, Effects(self.effects) + more, self.notes, self.uncertainties)

    @classmethod
    def of(cls, fin: Fin, params: Mapping[str, Sequence[float]] | None = None) -> Model:
        """``Model.of(fin, {"drag_offset": [2.0]})``: effects by name with their values."""
        return cls(fin, tuple(make(name, vals) for name, vals in (params or {}).items()))

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    @property
    def values(self) -> tuple[tuple[float, ...], ...]:
        return tuple(e.values for e in self.effects)

    def without(self, name: str) -> Model:
        kept = tuple(e for e in self.effects if e.name != name)
        sigma = {k: v for k, v in self.uncertainties.items() if k != name}
        return Model(self.fin, kept, self.notes, sigma)

    def parameters(self) -> dict[str, dict[str, float]]:
        return {e.name: e.parameters() for e in self.effects}

    def parameters_text(self, name: str, digits: int = 3) -> str:
        """``"scale = 2.03 +- 0.04"``: an effect's parameters, with their uncertainty when fitted."""
        sigma = self.uncertainties.get(name, {})
        out = []
        for k, v in self.parameters()[name].items():
            pm = f" +- {sigma[k]:.2g}" if k in sigma and math.isfinite(sigma[k]) else ""
            out.append(f"{k} = {v:.{digits}g}{pm}")
        return ", ".join(out)

    def predict(
        self,
        frequency_hz: ArrayLike,
        voltage_pp: ArrayLike,
        drive_pp: ArrayLike | None = None,
        time_s: ArrayLike | None = None,
    ) -> Prediction:
        """Steady state at nominal (commanded) voltages ``voltage_pp``.  With ``drive_pp`` (the measured
        fundamental of the drive, Vpp, as its monitor reads it) the fin is driven by that instead of
        by the model's drive; ``time_s`` (s since the first trial) is when each trial ran (drifts)."""
        return predict(self.fin, self.effects, frequency_hz, voltage_pp, drive_pp=drive_pp, time_s=time_s)

    def knobs_at(self, frequency_hz: float, voltage_pp: float) -> Knobs:
        """The knobs (floats) at this operating point's steady state: the linearisation that the
        streaming rig integrates, so that its steady state is this model's (see :mod:`..rig`)."""
        f, v = np.array([float(frequency_hz)]), np.array([float(voltage_pp)])
        k, _ = steady_knobs(self.fin, self.effects, f, v)
        return Knobs(**{n: float(np.asarray(getattr(k, n))[0]) for n in Knobs.__dataclass_fields__})

    def law(self, frequency_hz: ArrayLike, voltage_pp: ArrayLike, time_s: ArrayLike = 0.0) -> TimeLaw:
        """The time-domain law of every effect, at these (broadcast) operating points."""
        f, v, t = np.broadcast_arrays(
            np.asarray(frequency_hz, float), np.asarray(voltage_pp, float), np.asarray(time_s, float)
        )
        return Effects(self.effects).law(self.fin, f, v, t)

    # --- persistence (safe YAML; loaded by fin_sim, the controller and sweep) ---------------
    def to_mapping(self) -> dict[str, Any]:
        return {
            "fin": self.fin.inputs(),
            "effects": self.parameters(),
            **(
                {"uncertainties": {k: dict(v) for k, v in self.uncertainties.items()}}
                if self.uncertainties
                else {}
            ),
            **({"notes": dict(self.notes)} if self.notes else {}),
        }

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "<mapping>") -> Model:
        if not isinstance(data, Mapping) or "fin" not in data:
            raise ModelError(f"{source}: an augmented model needs a 'fin' mapping")
        fin = Fin.from_mapping(data["fin"], source=source)
        effects = data.get("effects") or {}
        if not isinstance(effects, Mapping):
            raise ModelError(f"{source}: 'effects' must map effect names to parameter mappings")
        out = tuple(_effect_from_mapping(str(name), params, source) for name, params in effects.items())
        unc = _uncertainties_from_mapping(data.get("uncertainties") or {}, out, source)
        return cls(fin, out, dict(data.get("notes") or {}), unc)


def _effect_from_mapping(name: str, params: Any, source: str) -> Effect:
    """``effects.<name>: {param: value}`` of a saved model (missing parameters: neutral)."""
    ecls = effect_class(name, source)
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
    try:
        return ecls.at(vals)
    except ModelError as exc:
        raise ModelError(f"{source}: {exc}") from None


def _uncertainties_from_mapping(
    sigma: Any, effects: Sequence[Effect], source: str
) -> dict[str, dict[str, float]]:
    """``uncertainties.<effect>: {param: sigma}`` of a saved model: numbers >= 0, or NaN (at a bound)."""
    if not isinstance(sigma, Mapping):
        raise ModelError(f"{source}: 'uncertainties' must map effect names to parameter mappings")
    known = {e.name: {q.name for q in e.params} for e in effects}
    for name, params in sigma.items():
        if name not in known or not isinstance(params, Mapping) or set(params) - known[name]:
            raise ModelError(f"{source}: uncertainties.{name} names no fitted parameter of the model")
        for q, v in params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (v >= 0 or math.isnan(v)):
                raise ModelError(f"{source}: uncertainties.{name}.{q} must be a number >= 0, got {v!r}")
    return {str(k): {str(q): float(v) for q, v in ps.items()} for k, ps in sigma.items()}


def model_presets() -> list[str]:
    """Names of the models shipped in ``config/models`` (the paper's twin, ``paper-twin-<fin>``)."""
    return presets("models")


def load_model(path: str) -> Model:
    """Read a model (``augmented_model.yaml`` from ``diagnose --report``) as safe YAML, or a preset by
    name (:func:`model_presets`: ``paper-twin-M8528-P1``).

    Raises :class:`ModelError` naming the file and the problem (missing, unreadable, not YAML,
    unknown effect or parameter, value out of range, bad fin).
    """
    path = str(preset_path(path, "models", "model", ModelError))
    data = read_yaml_file(path, ModelError)
    try:
        return Model.from_mapping(data, source=path)
    except FinConfigError as exc:
        raise ModelError(str(exc) if path in str(exc) else f"{path}: {exc}") from None


#: what a steady amplitude depends on: the fin, the effects that move it, the iterations, the points
_Key = tuple[Fin, tuple[Effect, ...], int, tuple[Any, ...]]
#: the last solved at some points: the kinds of the effects that moved it, their values, the amplitude
_Last = tuple[tuple[type, ...], NDArray[Any], NDArray[Any]]


class _Solved:
    """The steady amplitudes last solved, by what they depend on (an LRU of :attr:`MOST`): the fin,
    the effects that move it (not those that set only a knob the amplitude never reads,
    :data:`~.knobs.UNREAD_BY_AMPLITUDE`), the points and the iterations.  A fit's forward
    differences in the capacitance, the losses and the load cell's gain, and each fit's sigma,
    solve the same amplitudes again at the same points: 4 of its 10 models.  Arrays of more than
    :attr:`POINTS_MOST` points are solved each time (their key would cost).  Thread-safe: the
    controller fits in a worker while its node may predict.

    And where the effects that move it differ from the last solved at the same points by
    :attr:`NEAR` at most (relative, or absolute below 1): that amplitude, as the fixed point's start
    (:meth:`solved`).  A fit's forward differences step each parameter by 1.5e-8: from the amplitude
    just solved the fixed point settles in one or two turns, where from rest it took eight.
    """

    MOST = 64
    POINTS_MOST = 4096
    NEAR = 1e-6

    def __init__(self) -> None:
        self._amps: OrderedDict[_Key, FloatArray] = OrderedDict()
        # by (fin, iterations, points): the last effects that moved it (kinds, values) and its amplitude
        self._last: OrderedDict[tuple[Fin, int, tuple[Any, ...]], _Last] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = self.misses = self.starts = 0

    def key(
        self,
        fin: Fin,
        effects: Effects,
        arrays: tuple[FloatArray | None, ...],
        iterations: int,
    ) -> _Key | None:
        if arrays[0] is None or arrays[0].size > self.POINTS_MOST:
            return None
        moving = tuple(e for e in effects if sole_target(e) not in UNREAD_BY_AMPLITUDE)
        parts = tuple(
            None if a is None else (a.shape, np.ascontiguousarray(a, float).tobytes()) for a in arrays
        )
        key = (fin, moving, iterations, parts)
        try:
            hash(key)
        except TypeError:  # (an effect or a fin holding an array: solved each time)
            return None
        return key

    def __len__(self) -> int:
        return len(self._amps)

    def clear(self) -> None:
        with self._lock:
            self._amps.clear()
            self._last.clear()

    def solved(self, key: _Key | None, solve: Callable[[FloatArray | None], FloatArray]) -> FloatArray:
        """The amplitude kept for ``key``; else ``solve(near)``, kept (``near``: the amplitude last
        solved at the same points for effects of the same kinds within :attr:`NEAR` of these, or
        None).  ``key`` None: solved each time, nothing kept."""
        if key is None:
            return solve(None)
        with self._lock:
            amp = self._amps.get(key)
            if amp is not None:
                self._amps.move_to_end(key)
                self.hits += 1
                return amp.copy()
            self.misses += 1
        fin, moving, iterations, parts = key
        where = (fin, iterations, parts)
        kinds = tuple(type(e) for e in moving)
        values = np.array([v for e in moving for v in e.values], float)
        with self._lock:
            last = self._last.get(where)
        near = None
        if (
            last is not None
            and kinds == last[0]
            and values.shape == last[1].shape
            and np.all(np.abs(values - last[1]) <= self.NEAR * np.maximum(np.abs(last[1]), 1.0))
        ):
            near = last[2].copy()
        amp = solve(near)
        with self._lock:
            self.starts += near is not None
            self._amps[key] = np.array(amp, dtype=float)
            while len(self._amps) > self.MOST:
                self._amps.popitem(last=False)
            self._last[where] = (kinds, values, np.array(amp, dtype=float))
            self._last.move_to_end(where)
            while len(self._last) > self.MOST:
                self._last.popitem(last=False)
        return np.array(amp, dtype=float)


_SOLVED = _Solved()


def for_many_predictions() -> None:
    """Before a long run of predictions (a diagnosis's or the paper's fits): the steady amplitude's
    Newton iteration then runs compiled in this process (numba, loaded now: 60 MB and under a second),
    a quarter less time per fit, the same amplitudes bit for bit.  A node never calls it."""
    _load_compiler()


def steady_knobs(
    fin: Fin,
    effects: Iterable[Effect],
    f: FloatArray,
    vpp: FloatArray,
    measured: FloatArray | None = None,
    iterations: int = 16,
    time_s: FloatArray | float = 0.0,
) -> tuple[Knobs, FloatArray]:
    """The knobs (arrays shaped like ``f``) at the steady state, and its modal amplitude ``A``.

    ``f`` and ``vpp`` are broadcast arrays; ``measured``, if given, the drive that moves the fin.
    With amplitude-dependent effects ``A`` solves ``A = A_lin(knobs(A))`` (the describing function):
    an under-relaxed fixed-point iteration, and where it does not settle (a softening spring's
    jump region, where several amplitudes are steady), the *lowest* root, found by a scan in log A
    and bisection: the steady state a trial reaches when it starts from rest, as the protocol does.
    """
    phi = fin.phi_tip
    effects = Effects(effects)
    amp_dep = effects.amplitude_dependent

    t_all = np.broadcast_to(np.asarray(time_s, float), f.shape)

    def knobs(ff: FloatArray, vv: FloatArray, tt: FloatArray, x: FloatArray, mm: FloatArray | None) -> Knobs:
        return effects.describe(OperatingPoint(fin, ff, vv, x, tt), mm)

    def solve(
        ff: FloatArray, vv: FloatArray, tt: FloatArray, mm: FloatArray | None, amp: FloatArray
    ) -> FloatArray:
        """The linear steady amplitude with the knobs frozen at amplitude ``amp``."""
        k = knobs(ff, vv, tt, phi * amp, mm)
        return solve_amplitude(*coefficients(fin, 2 * math.pi * ff, k), _force(fin, k, vv, mm), guess=amp)

    key = _SOLVED.key(fin, effects, (f, vpp, t_all, measured), iterations)
    amp = _SOLVED.solved(
        key, lambda near: _solve_steady(f, vpp, t_all, measured, amp_dep, iterations, solve, near)
    )
    k = knobs(f, vpp, t_all, phi * amp, None if measured is None else np.broadcast_to(measured, f.shape))
    kk = Knobs(
        **{n: np.broadcast_to(np.asarray(getattr(k, n), float), f.shape) for n in Knobs.__dataclass_fields__}
    )
    return kk, amp


def _solve_steady(
    f: FloatArray,
    vpp: FloatArray,
    t_all: FloatArray,
    measured: FloatArray | None,
    amp_dep: bool,
    iterations: int,
    solve: Callable[[FloatArray, FloatArray, FloatArray, FloatArray | None, FloatArray], FloatArray],
    near: FloatArray | None = None,
) -> FloatArray:
    """:func:`steady_knobs`'s amplitude: the linear one, then the fixed point where an effect depends
    on it (started from ``near``, the amplitude of nearly the same model, where given), and the
    lowest root where that does not settle."""
    if amp_dep and near is not None and near.shape == f.shape and np.all(near > 0):
        amp = near
    else:
        amp = solve(f, vpp, t_all, measured, np.zeros_like(f))
    if amp_dep:
        amp = _fixed_point(lambda x: solve(f, vpp, t_all, measured, x), amp, iterations)
        bad = ~(np.abs(solve(f, vpp, t_all, measured, amp) - amp) <= 1e-6 * amp)
        if np.any(bad):
            amp = np.array(amp, dtype=float)
            fb, vb, tb = f[bad], vpp[bad], t_all[bad]
            mb = None if measured is None else np.broadcast_to(measured, f.shape)[bad]
            amp[bad] = _lowest_root(
                lambda x, j: solve(fb[j], vb[j], tb[j], None if mb is None else mb[j], x), amp[bad]
            )
    return amp


def _fixed_point(g: Callable[[FloatArray], FloatArray], amp: FloatArray, iterations: int) -> FloatArray:
    """``A = g(A)`` per point, in ``x = log A``: secant steps on ``h(x) = log g(e^x) - x``, safeguarded
    by the under-relaxed step ``x + h/2`` where the secant is undefined or jumps by more than the
    relaxed step would (softening branches overshoot otherwise).  Stops at 1e-9 relative."""
    new = g(amp)
    ok = (new > 0) & (amp > 0)
    x = np.log(np.where(ok, amp, 1.0))
    h = np.where(ok, np.log(np.where(ok, new, 1.0)) - x, 0.0)
    x_prev = h_prev = None
    for _ in range(iterations):
        step = 0.5 * h
        if x_prev is not None and h_prev is not None:
            dh = h - h_prev
            with np.errstate(divide="ignore", invalid="ignore"):
                sec = -h * (x - x_prev) / dh
            good = np.isfinite(sec) & (np.abs(dh) > 0) & (np.abs(sec) <= 4 * np.abs(step) + 1e-12)
            step = np.where(good, sec, step)
        x_prev, h_prev = x, h
        x = x + np.where(ok, step, 0.0)
        amp_new = np.where(ok, np.exp(x), new)
        new = g(amp_new)
        ok = (new > 0) & (amp_new > 0)
        h = np.where(ok, np.log(np.where(ok, new, 1.0)) - np.log(np.where(ok, amp_new, 1.0)), 0.0)
        done = np.all(np.abs(amp_new - amp) <= 1e-9 * np.maximum(amp, 1e-30))
        amp = amp_new
        if done:
            break
    return amp


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
    for _ in range(32):  # the bracket is a factor 1.26 wide: 32 halvings reach 1e-10
        mid = 0.5 * (lo + hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            above = np.log(g(np.exp(mid), idx)) > mid
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    return np.where(found, np.exp(0.5 * (lo + hi)), guess)


def _drive(k: Knobs, vpp: FloatArray, measured: FloatArray | None) -> FloatArray:
    """The drive the fin receives (Vpp): the model's amplifier output, or the monitor's reading over
    its gain."""
    return vpp * k.voltage * k.voltage_scale if measured is None else measured / k.voltage_gain


def _force(fin: Fin, k: Knobs, vpp: FloatArray, measured: FloatArray | None) -> FloatArray:
    """``theta V`` of the quartic (steady.py) with the knobs applied."""
    return fin.theta * k.coupling * 0.5 * _drive(k, vpp, measured)


def predict(
    fin: Fin,
    effects: Iterable[Effect],
    frequency_hz: ArrayLike,
    voltage_pp: ArrayLike,
    *,
    drive_pp: ArrayLike | None = None,
    iterations: int = 16,
    time_s: ArrayLike | None = None,
) -> Prediction:
    """Steady state of ``fin`` with ``effects`` (instances with parameter values), vectorised, as the
    instruments read it.

    ``voltage_pp`` is the nominal drive; ``drive_pp``, if given, the measured one (as the voltage
    monitor reads it) that moves the fin; ``time_s``, when each point ran (NaN: 0).
    """
    effects = Effects(effects)
    f, vpp = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
    measured = None if drive_pp is None else np.broadcast_to(np.asarray(drive_pp, float), f.shape)
    when = 0.0 if time_s is None else np.nan_to_num(np.broadcast_to(np.asarray(time_s, float), f.shape))
    w = 2 * math.pi * f
    phi = fin.phi_tip
    kk, amp = steady_knobs(fin, effects, f, vpp, measured, iterations, when)
    a, c0, kd = coefficients(fin, w, kk)
    force = _force(fin, kk, vpp, measured)
    d = c0 + kd * amp
    v_amp = 0.5 * _drive(kk, vpp, measured)
    den = a * a + d * d
    with np.errstate(invalid="ignore", divide="ignore"):
        h0 = np.where(den > 0, force * a / den, 0.0)
        h1 = np.where(den > 0, force * d / den, 0.0)
    vel = 1j * w * (h0 - 1j * h1)  # modal velocity phasor
    tip = phi * vel
    cap = fin.C_eq * kk.capacitance
    current = (kk.loss_conductance + 1j * w * cap) * v_amp + fin.theta * kk.coupling * vel
    u_ms = 0.5 * np.abs(tip) ** 2
    x_ms = 0.5 * (fin.phi_tip_slope * amp) ** 2
    thrust = 0.5 * fin.m_v * kk.mass * (u_ms - kk.swim_speed**2 * x_ms)
    # what the instruments read: gains, and lags as phases (a reading at t is the signal at t - tau)
    tip_read = kk.tip_gain * tip * np.exp(-1j * w * kk.tip_delay_s)
    i_read = kk.current_gain * current * np.exp(-1j * w * kk.current_delay_s)
    v_read = kk.voltage_gain * v_amp
    return Prediction(
        voltage_pp_drive=vpp * kk.voltage * kk.voltage_scale * kk.voltage_gain,
        tip_velocity_rms=np.abs(tip_read) / math.sqrt(2),
        tip_phase_rad=np.angle(tip_read),
        current_rms=kk.current_gain * np.sqrt(0.5 * np.abs(current) ** 2 + kk.current_harmonics_a2),
        power_w=0.5 * v_read * np.real(i_read),
        thrust_n=thrust,
        thrust_loadcell_n=kk.thrust_gain * thrust + kk.thrust_bias_n,
        admittance=np.divide(i_read, v_read, out=np.full(np.shape(i_read), np.nan + 0j), where=v_read != 0),
    )
