r"""A generator of "real" datasets: the time-domain simulator with hidden effects and rig noise.

The diagnosis is checked on data whose cause it is not told.  So that the check is not circular,
the hidden effects act through their *time-domain laws* (:meth:`~piezofin_ros.physics.effects.Effect.law`:
a cubic spring, a voltage-dependent spring, damping proportional to ``|eta|``, an added mass and a
drag that follow the instantaneous Keulegan-Carpenter number, loss currents, a clipped amplifier,
a load cell with offset and gain, a free stream), integrated in the time domain
(:func:`~piezofin_ros.physics.timedomain.simulate_law`), while the diagnosis fits their describing
functions.  Strengths are drawn in the generator's own units (:func:`draw_strength`, e.g. a
stiffness change at the reference amplitude) and converted to the library's parameters by
:func:`library_effect`.  Two effects are deliberately *not* in the library (``wake_modulation``,
``coupling_dispersion``, written here) to measure how often the tool names a wrong cause with
confidence.

Each trial integrates Eq. (9) with the effects for 10 s from rest (fixed-step RK4, compiled with
numba), samples voltage, current and tip velocity at 1 kHz with the rig's noise (0.2 V, 1 uA,
1 mm/s), and runs the estimator's lock-in (:func:`~piezofin_ros.estimation.estimator.analyse_window`) on
the whole periods after 3 s, as the paper's protocol does.  The load-cell thrust is the mean
thrust of that window through the transducer (gain, offset) plus its noise (0.1 um on 6.8 kN/m,
with the pre/post baselines).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import DiagnosisError
from ..estimation.estimator import EstimatorConfig, analyse_window
from ..physics.effects import DF_ABS_DAMPING, Effect, make
from ..physics.fin import Fin, load_fin, preset_names
from ..physics.model import Model
from ..physics.steady import harmonic_balance
from ..physics.timedomain import LawRun, simulate_law
from ..rig.simulated import RigConfig
from .data import SignalNoise, Trials, loadcell_sigma, make_trials, window_sigmas

FloatArray = NDArray[Any]

IN_LIBRARY = (
    "resonance_offset",
    "stiffness_nonlinearity",
    "electroelastic_softening",
    "nonlinear_damping",
    "added_mass_offset",
    "added_mass_kc",
    "drag_offset",
    "drag_kc",
    "dielectric_loss",
    "leakage",
    "swim_speed",
    "amplifier_limit",
    "loadcell_offset",
    "loadcell_gain",
    "field_coupling",
    "amplifier_sag",
    "added_mass_kc2",
    "voltage_monitor_gain",
    "vibrometer_gain",
    "vibrometer_delay",
    "current_monitor_gain",
    "current_monitor_delay",
    "resonance_drift",
    "capacitance_drift",
    "coupling_drift",
)
#: How long one trial of the protocol takes (pre baseline, burst, post baseline, pause), s: the
#: generated trials run in protocol order (voltage by voltage, frequencies up), this far apart.
TRIAL_SPACING_S = 30.0
OUT_OF_LIBRARY = ("wake_modulation", "coupling_dispersion")


@dataclass(frozen=True)
class Case:
    """One dataset: a fin, hidden effects with strengths (generator units), a grid and a seed."""

    fin: str
    effects: dict[str, float] = field(default_factory=dict)
    seed: int = 0
    frequencies_hz: tuple[float, ...] = ()
    voltages_pp: tuple[float, ...] = (400.0, 600.0, 800.0)

    @property
    def out_of_library(self) -> bool:
        return any(e in OUT_OF_LIBRARY for e in self.effects)

    def grid(self) -> tuple[FloatArray, FloatArray]:
        freqs = self.frequencies_hz or default_frequencies(load_fin(self.fin))
        f, v = np.meshgrid(np.asarray(freqs, float), np.asarray(self.voltages_pp, float))
        return f.ravel(), v.ravel()


def default_frequencies(fin: Fin, n: int = 11) -> tuple[float, ...]:
    """The paper's 11 frequencies for M8528-P1 (1-11 Hz), scaled to other fins' resonance."""
    top = round(1.1 * fin.f_water_linear)
    return tuple(float(x) for x in np.linspace(1.0, max(top, 5), n))


def _reference_amplitude(fin: Fin, voltages: tuple[float, ...]) -> float:
    """Peak modal amplitude of the nominal model at the highest voltage."""
    f = np.linspace(0.5, 1.5 * fin.f_water_linear, 200)
    return float(np.max(harmonic_balance(fin, f, max(voltages)).modal_amplitude))


def random_case(rng: np.random.Generator, kind: str = "single", fin: str | None = None) -> Case:
    """A random dataset: ``single`` (one in-library effect), ``double`` (two) or ``outside``.

    Strengths are drawn where the effect is visible above the rig's noise somewhere in the
    sweep (the point of the benchmark is attribution, not detection at the noise floor).
    """
    fin_name = fin or str(rng.choice(preset_names()))
    if kind == "single":
        names = [str(rng.choice(IN_LIBRARY))]
    elif kind == "double":
        names = [str(x) for x in rng.choice(IN_LIBRARY, size=2, replace=False)]
    elif kind == "outside":
        names = [str(rng.choice(OUT_OF_LIBRARY))]
    else:
        raise DiagnosisError(f"kind must be single, double or outside, got {kind!r}")
    return Case(fin_name, {n: draw_strength(n, rng) for n in names}, int(rng.integers(2**31)))


def draw_strength(name: str, rng: np.random.Generator) -> float:
    """A strength in the generator's own units (see :func:`simulate_case`)."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    u = rng.uniform
    table = {
        "resonance_offset": 1.0 + sign * u(0.08, 0.25),
        "stiffness_nonlinearity": -u(0.1, 0.3) if sign < 0 else u(0.1, 0.3),  # peak stiffness change
        "electroelastic_softening": u(0.1, 0.45),
        "nonlinear_damping": u(5.0, 20.0),  # structural damping x (1 + this) at the reference amplitude
        "added_mass_offset": 1.0 + sign * u(0.25, 0.5) if sign > 0 else u(0.55, 0.8),
        "added_mass_kc": u(0.2, 0.8),  # a KC at the reference amplitude
        "drag_offset": u(1.8, 4.0) if sign > 0 else u(0.25, 0.55),
        "drag_kc": u(0.3, 1.0),
        "dielectric_loss": u(0.02, 0.1),
        "leakage": u(0.02, 0.2),  # uS
        # U / (2 pi f_water phi/phi'): U^2 w_x^2 / w_t^2 at the linear resonance, the thrust lost there is
        # this squared (more below it). Below ~0.12-0.17 (0.5-1 m/s on the presets) the U term hides in the
        # load-cell noise: these fins make < 0.04 mN below 2 Hz, where it matters most.
        "swim_speed": u(0.2, 0.4),
        "amplifier_limit": u(0.45, 0.8),  # clip at this fraction of the highest current demand
        "loadcell_offset": sign * u(0.3, 2.0),  # mN
        "loadcell_gain": 1.0 + sign * u(0.15, 0.4),
        "field_coupling": u(0.15, 0.4),
        "amplifier_sag": u(0.45, 0.8),  # sag to this fraction of the highest current demand
        "added_mass_kc2": u(0.2, 0.8),  # a KC^2 at the reference amplitude
        "voltage_monitor_gain": 1.0 + sign * u(0.05, 0.2),
        "vibrometer_gain": 1.0 + sign * u(0.05, 0.2),
        "vibrometer_delay": u(0.5, 3.0),  # ms
        "current_monitor_gain": 1.0 + sign * u(0.05, 0.2),
        "current_monitor_delay": u(0.5, 3.0),  # ms
        "resonance_drift": sign * u(15.0, 40.0),  # %/h
        "capacitance_drift": sign * u(10.0, 40.0),
        "coupling_drift": sign * u(15.0, 40.0),
        "wake_modulation": u(0.15, 0.35),
        "coupling_dispersion": sign * u(0.15, 0.3),
    }
    return float(table[name])


def swim_speed_m_s(fin: Fin, reduced: float) -> float:
    """The swimming speed (m/s) of a reduced speed ``U / (2 pi f_water_linear phi_tip/phi_tip')``."""
    return reduced * 2 * math.pi * fin.f_water_linear * fin.phi_tip / fin.phi_tip_slope


@dataclass(frozen=True)
class Generated:
    case: Case
    trials: Trials


def library_effect(name: str, strength: float, fin: Fin, a_ref: float, max_current_a: float) -> Effect:
    """The library effect a generator strength stands for (generator units: :func:`draw_strength`).

    ``a_ref``: the nominal peak modal amplitude (strengths of amplitude-dependent effects are quoted
    there); ``max_current_a``: the largest capacitive current the grid asks of the amplifier.
    """
    s = strength
    x_ref = fin.phi_tip * a_ref / fin.L  # tip amplitude over length at a_ref
    kc_ref = 2 * math.pi * fin.phi_tip * a_ref / fin.b
    values = {
        "resonance_offset": s,
        "stiffness_nonlinearity": s / x_ref**2,  # a stiffness change of s at a_ref
        "electroelastic_softening": s,
        "nonlinear_damping": s * DF_ABS_DAMPING / x_ref,  # damping x (1 + s) at the reference amplitude
        "added_mass_offset": s,
        "added_mass_kc": s / kc_ref,  # a KC = s at the reference amplitude
        "drag_offset": s,
        "drag_kc": s,
        "dielectric_loss": s,
        "leakage": s,
        "swim_speed": swim_speed_m_s(fin, s),
        "amplifier_limit": 1e-3 / (s * max_current_a),  # clip at s of the highest current demand
        "loadcell_offset": s,
        "loadcell_gain": s,
        "amplifier_sag": 1e-3 / (s * max_current_a),
        "added_mass_kc2": s / kc_ref**2,
    }
    if name == "field_coupling":
        return make(name, [s, 1.0])  # Rayleigh's law
    return make(name, [values.get(name, s)])  # instruments and drifts: in the library's units


def simulate_case(case: Case, rig: RigConfig | None = None) -> Generated:
    """Run every trial of ``case`` in the time domain and estimate it like the real suite."""
    fin = load_fin(case.fin)
    rig = rig or RigConfig()
    rng = np.random.default_rng(case.seed)
    f, vpp = case.grid()
    when = trial_times(vpp)
    e = case.effects
    a_ref = _reference_amplitude(fin, case.voltages_pp)
    max_current = float(np.max(fin.C_eq * 2 * math.pi * f * 0.5 * vpp))
    hidden = [library_effect(k, s, fin, a_ref, max_current) for k, s in e.items() if k in IN_LIBRARY]
    model = Model(fin, tuple(hidden))
    law = model.law(f, vpp, when)
    if "coupling_dispersion" in e:  # out of the library: the coupling follows the frequency
        law = replace(law, coupling=law.coupling * (f / np.median(f)) ** e["coupling_dispersion"])
    run = simulate_law(fin, law, f, vpp, duration=DURATION_S, rate_hz=RATE_HZ)
    factor = None
    if "wake_modulation" in e:  # out of the library: the wake modulates the thrust
        factor = 1 + e["wake_modulation"] * np.sin(2 * math.pi * f / 4.0)
    label = "+".join(f"{k}={x:.3g}" for k, x in e.items()) or "nominal"
    trials = measure(
        fin, run, f, vpp, when, rng, f"synthetic {case.fin} {label} seed {case.seed}", rig, factor
    )
    return Generated(case, trials)


DURATION_S = 10.0  # each trial: the drive on from rest for this long
RATE_HZ = 1000.0  # samples per second

#: What the instruments make of a trial's true signals: ``(j, t, v, i, u) -> (v, i, u)`` for trial ``j``.
Readings = Callable[
    [int, FloatArray, FloatArray, FloatArray, FloatArray], tuple[FloatArray, FloatArray, FloatArray]
]


def measure(
    fin: Fin,
    run: LawRun,
    f: FloatArray,
    vpp: FloatArray,
    when: FloatArray,
    rng: np.random.Generator,
    source: str,
    rig: RigConfig | None = None,
    thrust_factor: FloatArray | None = None,
    readings: Readings | None = None,
) -> Trials:
    """The trials of a time-domain run as the suite measures them: each channel through ``readings``
    (default: as the run reads it) with the rig's noise, the estimator's lock-in over the whole
    periods after ``settle_s``, the load cell's mean thrust (times ``thrust_factor``) with its noise."""
    rig = rig or RigConfig()
    cfg = EstimatorConfig()
    levels = SignalNoise(
        rig.voltage_noise_v, rig.current_noise_a, rig.vibrometer_noise_m_s, rig.displacement_noise_m
    )
    n_base = 2 * cfg.baseline_s * RATE_HZ  # pre and post baselines
    names = ("voltage_pp_drive", "tip_velocity_rms", "tip_phase_rad", "current_rms", "power_w")
    cols: dict[str, list[float]] = {k: [] for k in (*names, "thrust_loadcell_n")}
    windows = []
    t = run.t
    for j in range(f.size):
        periods = math.floor((DURATION_S - cfg.settle_s) * f[j])
        t0 = DURATION_S - periods / f[j]
        sel = (t >= t0 - 1e-9) & (t < DURATION_S - 1e-9)
        nsel = int(np.count_nonzero(sel))
        windows.append(nsel)
        v, i, u = run.voltage[j], run.current[j], run.tip_velocity[j]
        if readings is not None:
            v, i, u = readings(j, t, v, i, u)
        vn = v[sel] + rig.voltage_noise_v * rng.standard_normal(nsel)
        i_n = i[sel] + rig.current_noise_a * rng.standard_normal(nsel)
        u_n = u[sel] + rig.vibrometer_noise_m_s * rng.standard_normal(nsel)
        r = analyse_window(fin, t[sel], vn, i_n, float(f[j]), tip_velocity=u_n)
        thrust = float(np.mean(run.loadcell_thrust[j, sel]))
        if thrust_factor is not None:
            thrust *= float(thrust_factor[j])
        sig_t = float(loadcell_sigma(levels, rig.loadcell_stiffness, nsel, n_base))
        cols["voltage_pp_drive"].append(r["voltage_pp"])
        for name in names[1:]:
            cols[name].append(r[name])
        cols["thrust_loadcell_n"].append(thrust + sig_t * rng.standard_normal())
    noise = window_sigmas(
        levels, windows, n_base, cols["voltage_pp_drive"], cols["tip_velocity_rms"], rig.loadcell_stiffness
    )
    columns = {"frequency_hz": f, "voltage_pp": vpp, **{k: np.asarray(x) for k, x in cols.items()}}
    return make_trials(columns, noise, source, time_s=when)


def trial_times(voltage_pp: FloatArray, rng: np.random.Generator | None = None) -> FloatArray:
    """When each trial of a grid starts (s), TRIAL_SPACING_S apart: in protocol order (voltage by voltage,
    frequencies up), or in a random order with ``rng`` (as an experiment that must tell a drift in time
    from a dependence on the drive runs its trials)."""
    order = np.argsort(np.round(np.asarray(voltage_pp, float)), kind="stable")
    if rng is not None:
        order = rng.permutation(order.size)
    t = np.empty(len(order))
    t[order] = np.arange(len(order)) * TRIAL_SPACING_S
    return t
