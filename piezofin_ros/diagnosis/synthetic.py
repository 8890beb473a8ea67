r"""A generator of "real" datasets: the time-domain simulator with hidden effects and rig noise.

The diagnosis is checked on data whose cause it is not told.  So that the check is not circular,
the hidden effects are written here *in the time domain*, independently of the harmonic-balance
forms of :mod:`.model`: a cubic spring, a voltage-dependent spring, damping proportional to
``|eta|``, an added mass and a drag that follow the instantaneous Keulegan-Carpenter number,
loss currents, a clipped amplifier, a load cell with offset and gain, a free stream.  Two effects
are deliberately *not* in the library (``wake_modulation``, ``coupling_dispersion``) to measure how
often the tool names a wrong cause with confidence.

Each trial integrates Eq. (9) with the effects for 10 s from rest (fixed-step RK4, compiled with
numba), samples voltage, current and tip velocity at 1 kHz with the rig's noise (0.2 V, 1 uA,
1 mm/s), and runs the estimator's lock-in (:func:`~piezofin_ros.estimation.analyse_window`) on
the whole periods after 3 s, as the paper's protocol does.  The load-cell thrust is the mean
thrust of that window through the transducer (gain, offset) plus its noise (0.1 um on 6.8 kN/m,
with the pre/post baselines).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._compile import njit
from ..estimation import EstimatorConfig, analyse_window
from ..fin import Fin, load_fin, preset_names
from ..rig import RigConfig
from ..steady import harmonic_balance
from .data import Noise, Trials, loadcell_sigma, make_trials, window_sigmas

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
)
OUT_OF_LIBRARY = ("wake_modulation", "coupling_dispersion")


@njit(cache=True)
def _rk4_effects(
    f_hz: FloatArray,  # (n,)
    v_amp: FloatArray,  # (n,) voltage amplitude
    v_clip: FloatArray,  # (n,) amplifier clip level (inf: none)
    mass0: FloatArray,  # (n,) 1 + mu (constant part)
    mu_kc: float,  # added-mass slope: mu * a per unit KC
    wn2: FloatArray,  # (n,)
    k3: float,  # cubic stiffness
    c_lin: float,
    c_abs: float,  # damping proportional to |eta|
    gam: FloatArray,  # (n,) drag
    drag_n: float,  # drag ~ KC^-n
    theta: FloatArray,  # (n,)
    kc_per_eta: float,  # KC per unit modal amplitude: 2 pi phi / b
    h: float,
    substeps: int,
    n_out: int,
    eta_out: FloatArray,
    deta_out: FloatArray,
    v_out: FloatArray,
) -> None:
    n = f_hz.shape[0]
    xs = np.empty(4)  # RK4 stage states and slopes, reused across steps
    ys = np.empty(4)
    ax = np.empty(4)
    ay = np.empty(4)
    for j in range(n):
        w = 2.0 * np.pi * f_hz[j]
        x = 0.0
        y = 0.0
        t = 0.0
        for k in range(n_out):
            vs = min(max(v_amp[j] * np.sin(w * t), -v_clip[j]), v_clip[j])  # the amplifier clips
            eta_out[j, k] = x
            deta_out[j, k] = y
            v_out[j, k] = vs
            if k == n_out - 1:
                break
            for _ in range(substeps):
                for stage in range(4):
                    if stage == 0:
                        xs[0] = x
                        ys[0] = y
                        tt = t
                    elif stage == 1:
                        xs[1] = x + 0.5 * h * ax[0]
                        ys[1] = y + 0.5 * h * ay[0]
                        tt = t + 0.5 * h
                    elif stage == 2:
                        xs[2] = x + 0.5 * h * ax[1]
                        ys[2] = y + 0.5 * h * ay[1]
                        tt = t + 0.5 * h
                    else:
                        xs[3] = x + h * ax[2]
                        ys[3] = y + h * ay[2]
                        tt = t + h
                    xx = xs[stage]
                    yy = ys[stage]
                    v = min(max(v_amp[j] * np.sin(w * tt), -v_clip[j]), v_clip[j])
                    kc = kc_per_eta * np.sqrt(xx * xx + (yy / w) ** 2)
                    mass = mass0[j] + mu_kc * kc
                    drag = gam[j]
                    if drag_n != 0.0:
                        drag = drag * max(kc, 1e-3) ** (-drag_n)
                    force = (
                        theta[j] * v
                        - (c_lin + c_abs * abs(xx) + drag * abs(yy)) * yy
                        - wn2[j] * xx
                        - k3 * xx**3
                    )
                    ax[stage] = yy
                    ay[stage] = force / mass
                x += h / 6.0 * (ax[0] + 2.0 * ax[1] + 2.0 * ax[2] + ax[3])
                y += h / 6.0 * (ay[0] + 2.0 * ay[1] + 2.0 * ay[2] + ay[3])
                t += h


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
        raise ValueError(f"kind must be single, double or outside, got {kind!r}")
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


def simulate_case(case: Case, rig: RigConfig | None = None) -> Generated:
    """Run every trial of ``case`` in the time domain and estimate it like the real suite."""
    fin = load_fin(case.fin)
    rig = rig or RigConfig()
    rng = np.random.default_rng(case.seed)
    f, vpp = case.grid()
    n = f.size
    e = case.effects
    a_ref = _reference_amplitude(fin, case.voltages_pp)
    kc_per_eta = 2 * math.pi * fin.phi_tip / fin.b
    wn2 = np.full(n, fin.omega_n**2)
    mass0 = np.full(n, 1.0 + fin.mu)
    gam = np.full(n, fin.gamma)
    theta = np.full(n, fin.theta)
    mv = np.full(n, fin.m_v)
    k3 = c_abs = mu_kc = drag_n = 0.0
    v_clip = np.full(n, np.inf)
    if "resonance_offset" in e:
        wn2 *= e["resonance_offset"] ** 2
    if "stiffness_nonlinearity" in e:
        # k3 eta^3 has the describing function (3/4) k3 A^2: a stiffness change of `s` at A_ref
        k3 = e["stiffness_nonlinearity"] * fin.omega_n**2 / (0.75 * a_ref**2)
    if "electroelastic_softening" in e:
        wn2 *= np.maximum(1 - e["electroelastic_softening"] * vpp / 800.0, 0.05) ** 2
    c_lin = 2 * fin.zeta * fin.omega_n
    if "nonlinear_damping" in e:
        c_abs = e["nonlinear_damping"] * c_lin / a_ref
    if "added_mass_offset" in e:
        mass0 = np.full(n, 1.0 + fin.mu * e["added_mass_offset"])
        mv *= e["added_mass_offset"]
    if "added_mass_kc" in e:
        mu_kc = fin.mu * e["added_mass_kc"] / (kc_per_eta * a_ref)
    if "drag_offset" in e:
        gam *= e["drag_offset"]
    if "drag_kc" in e:
        drag_n = e["drag_kc"]
    if "coupling_dispersion" in e:
        theta *= (f / np.median(f)) ** e["coupling_dispersion"]
    w = 2 * math.pi * f
    if "amplifier_limit" in e:
        demand = fin.C_eq * w * 0.5 * vpp
        v_clip = e["amplifier_limit"] * np.max(demand) / (fin.C_eq * w)
    rate = 1000.0
    duration = 10.0
    n_out = int(duration * rate) + 1
    f_fast = max(fin.f_water_linear * 1.2, float(np.max(f)))
    substeps = max(1, math.ceil(60 * f_fast / rate))
    h = 1.0 / (rate * substeps)
    eta = np.empty((n, n_out))
    deta = np.empty((n, n_out))
    v = np.empty((n, n_out))
    _rk4_effects(
        f,
        0.5 * vpp,
        v_clip,
        mass0,
        mu_kc,
        wn2,
        k3,
        c_lin,
        c_abs,
        gam,
        drag_n,
        theta,
        kc_per_eta,
        h,
        substeps,
        n_out,
        eta,
        deta,
        v,
    )
    t = np.arange(n_out) / rate
    vdot = np.asarray(np.gradient(v, t, axis=1))
    current = fin.C_eq * vdot + theta[:, None] * deta
    if "dielectric_loss" in e:
        current = current + e["dielectric_loss"] * fin.C_eq * w[:, None] * v
    if "leakage" in e:
        current = current + e["leakage"] * 1e-6 * v
    tip = fin.phi_tip * deta
    kc = kc_per_eta * np.sqrt(eta**2 + (deta / w[:, None]) ** 2)
    mv_t = mv[:, None] * (1 + (mu_kc * kc / fin.mu if mu_kc else 0.0))
    U = swim_speed_m_s(fin, e.get("swim_speed", 0.0))
    thrust_t = 0.5 * mv_t * (tip**2 - U**2 * (fin.phi_tip_slope * eta) ** 2)
    cfg = EstimatorConfig()
    levels = Noise(
        rig.voltage_noise_v, rig.current_noise_a, rig.vibrometer_noise_m_s, rig.displacement_noise_m
    )
    n_base = 2 * cfg.baseline_s * rate  # pre and post baselines
    cols: dict[str, list[float]] = {
        k: []
        for k in (
            "voltage_pp_drive",
            "tip_velocity_rms",
            "tip_phase_rad",
            "current_rms",
            "power_w",
            "thrust_loadcell_n",
        )
    }
    windows = []
    for j in range(n):
        periods = math.floor((duration - cfg.settle_s) * f[j])
        t1 = duration
        t0 = t1 - periods / f[j]
        sel = (t >= t0 - 1e-9) & (t < t1 - 1e-9)
        nsel = int(np.count_nonzero(sel))
        windows.append(nsel)
        vn = v[j, sel] + rig.voltage_noise_v * rng.standard_normal(nsel)
        i_n = current[j, sel] + rig.current_noise_a * rng.standard_normal(nsel)
        u_n = tip[j, sel] + rig.vibrometer_noise_m_s * rng.standard_normal(nsel)
        r = analyse_window(fin, t[sel], vn, i_n, float(f[j]), tip_velocity=u_n)
        thrust = float(np.mean(thrust_t[j, sel]))
        if "wake_modulation" in e:
            thrust *= 1 + e["wake_modulation"] * math.sin(2 * math.pi * f[j] / 4.0)
        thrust = thrust * e.get("loadcell_gain", 1.0) + e.get("loadcell_offset", 0.0) * 1e-3
        sig_t = float(loadcell_sigma(levels, rig.loadcell_stiffness, nsel, n_base))
        cols["voltage_pp_drive"].append(r["voltage_pp"])
        for name in ("tip_velocity_rms", "tip_phase_rad", "current_rms", "power_w"):
            cols[name].append(r[name])
        cols["thrust_loadcell_n"].append(thrust + sig_t * rng.standard_normal())
    noise = window_sigmas(
        levels, windows, n_base, cols["voltage_pp_drive"], cols["tip_velocity_rms"], rig.loadcell_stiffness
    )
    columns = {"frequency_hz": f, "voltage_pp": vpp, **{k: np.asarray(x) for k, x in cols.items()}}
    label = "+".join(f"{k}={x:.3g}" for k, x in e.items()) or "nominal"
    return Generated(case, make_trials(columns, noise, f"synthetic {case.fin} {label} seed {case.seed}"))
