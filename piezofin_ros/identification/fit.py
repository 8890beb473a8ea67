r"""The paper's identification (Sec. 3.2): Table 2 from an in-air sweep, ``c_m`` and ``c_d`` from an
underwater one.

**In air** (in vacuo, footnote 2), Eqs. (10)-(11) give the tip velocity and the current per volt,

.. math::

    \frac{U}{V} = \frac{j\omega\,\phi(L)\,\theta}{\omega_n^2-\omega^2+2j\zeta\omega_n\omega},\qquad
    \frac{I}{V} = j\omega C_{eq} + \frac{j\omega\,\theta^2}{\omega_n^2-\omega^2+2j\zeta\omega_n\omega}.

:func:`identify_air` fits ``f_sc``, ``zeta``, ``theta`` and ``C_eq`` to both (complex least squares,
each point weighted by its measured error, :mod:`.frf`), and reports beside the fit the paper's own
estimates: the resonance, ``zeta`` by the half-power points (for a velocity FRF the half-power band
is exactly ``2 zeta f_sc``), ``theta`` from the FRF amplitude at resonance and, separately, from the
motional current alone (the admittance fit), and ``C_eq`` from the current far from resonance.
``D`` follows from Eq. (8) with the *active* length (which reproduces Table 2's ``D``; the
overall length is stated beside it).  ``phi(L) = 2 / sqrt(m_s L)`` needs the measured length and
mass per length (Table 1), which a frequency response cannot give.

**Under water**, with the in-air parameters fixed, :func:`identify_water` fits ``c_m`` (through
``mu``) and ``c_d`` (through ``gamma``) to the tip velocity per volt with the harmonic balance of
Eqs. (15)-(18) refined to three harmonics (:func:`~piezofin_ros.physics.steady.harmonic_balance`),
since the drag makes the response amplitude dependent.  Beside it, the paper's closed forms:
``c_m`` from the resonance shift, ``f_w = f_sc / sqrt(1 + mu)`` (the velocity FRF is in phase with
the drive at ``f_w`` whatever the damping), and ``c_d`` from the amplitude there,
``A (2 zeta w_n w + (8/3pi) gamma w^2 A) = theta V``.

Uncertainties are one standard deviation from the fit's Jacobian with the measured errors, scaled
by the reduced chi-square when it exceeds 1.  Each result states what the data cannot identify:
too few points near resonance, a sweep that does not cross the half-power level on both sides, a
drive too small for the drag to matter.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import optimize

from ..physics import hydro, modeshape
from ..physics.fin import Fin
from ..physics.steady import DRAG_HARMONIC, harmonic_balance
from .frf import FrfPoint, IdentificationError

FloatArray = NDArray[np.float64]

#: The paper's estimate of ``f_sc``: the peak of the velocity FRF (of the motional admittance without
#: a vibrometer).
PEAK = "peak of the response"
#: A reduced chi-square above this says the model does not describe the data (the sigmas are then
#: scaled by it, but the values themselves are suspect).
POOR_FIT_CHI2 = 10.0
#: Table 1: what a frequency response cannot give, measured with a ruler and a balance.
GEOMETRY = ("L", "L_active", "b", "b_active", "h", "m_s")


@dataclass(frozen=True)
class Estimate:
    """One identified value: ``value`` with one-sigma ``sigma`` (NaN: not identifiable), the
    method, and other estimates of the same quantity by the paper's methods."""

    value: float
    sigma: float
    unit: str
    method: str
    others: dict[str, float] = field(default_factory=dict)

    @property
    def relative(self) -> float:
        return self.sigma / abs(self.value) if self.value else math.nan


@dataclass(frozen=True)
class Identified:
    """A stage's identified parameters, its residual and what it could not identify."""

    values: dict[str, Estimate]
    chi2_per_dof: float
    n_points: int
    warnings: list[str]

    def __getitem__(self, name: str) -> Estimate:
        return self.values[name]


def air_mobility(f: FloatArray, f_sc: float, zeta: float, theta: float, phi_tip: float) -> NDArray[Any]:
    """``U / V`` in air (Eq. 11 times ``j w phi(L)``), m/(s V)."""
    w, wn = 2 * np.pi * f, 2 * np.pi * f_sc
    return 1j * w * phi_tip * theta / (wn**2 - w**2 + 2j * zeta * wn * w)  # type: ignore[no-any-return]


def air_admittance(f: FloatArray, f_sc: float, zeta: float, theta: float, c_eq: float) -> NDArray[Any]:
    """``I / V`` in air (Eq. 10 with Eq. 11), S."""
    w, wn = 2 * np.pi * f, 2 * np.pi * f_sc
    return 1j * w * c_eq + 1j * w * theta**2 / (wn**2 - w**2 + 2j * zeta * wn * w)  # type: ignore[no-any-return]


def _columns(points: Sequence[FrfPoint]) -> dict[str, NDArray[Any]]:
    return {
        "f": np.array([p.frequency_hz for p in points]),
        "V": np.array([p.voltage for p in points]),
        "I": np.array([p.current for p in points]),
        "U": np.array([p.tip for p in points]),
        "sv": np.array([p.sigma_voltage for p in points]),
        "si": np.array([p.sigma_current for p in points]),
        "su": np.array([p.sigma_tip for p in points]),
    }


def _residual(
    measured: NDArray[Any], model_per_volt: NDArray[Any], c: dict[str, NDArray[Any]], sig: NDArray[Any]
) -> FloatArray:
    """Weighted complex residual of ``measured - model x V`` (the voltage's own error propagated)."""
    s = np.sqrt(sig**2 + np.abs(model_per_volt) ** 2 * c["sv"] ** 2)
    r = (measured - model_per_volt * c["V"]) / s
    return np.concatenate([r.real, r.imag])  # type: ignore[no-any-return]


def _fit(
    residual: Callable[[FloatArray], FloatArray],
    x0: FloatArray,
    bounds: tuple[Sequence[float], Sequence[float]],
) -> tuple[FloatArray, FloatArray, float, int]:
    """Least squares in parameters scaled by ``x0``; returns value, one-sigma, chi2/dof, dof."""
    scale = np.abs(x0)

    def scaled(z: FloatArray) -> FloatArray:
        return residual(z * scale)

    lo = np.asarray(bounds[0]) / scale
    hi = np.asarray(bounds[1]) / scale
    z0 = np.clip(np.ones_like(x0), lo + 1e-12, hi - 1e-12)
    sol = optimize.least_squares(
        scaled, z0, bounds=(lo, hi), x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12
    )
    dof = max(sol.fun.size - x0.size, 1)
    chi2 = float(sol.fun @ sol.fun) / dof
    jac = sol.jac
    try:
        cov = np.linalg.inv(jac.T @ jac) * max(chi2, 1.0)
        sigma = np.sqrt(np.clip(np.diag(cov), 0, None)) * scale
    except np.linalg.LinAlgError:
        sigma = np.full(x0.size, math.nan)
    at_bound = (np.abs(sol.x - lo) < 1e-9) | (np.abs(sol.x - hi) < 1e-9)
    sigma = np.where(at_bound, math.nan, sigma)
    return sol.x * scale, sigma, chi2, dof


def half_power(f: FloatArray, mag: FloatArray) -> tuple[float, float, float] | None:
    """Peak frequency and the half-power frequencies of a sampled ``|FRF|`` (linear interpolation
    of ``|FRF|^2``); ``None`` when the samples do not cross the level on both sides of the peak."""
    order = np.argsort(f)
    f, m2 = f[order], mag[order] ** 2
    k = int(np.argmax(m2))
    if 0 < k < f.size - 1:  # parabola through the three highest points, in f
        y0, y1, y2 = m2[k - 1 : k + 2]
        x0, x1, x2 = f[k - 1 : k + 2]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2**2 * (y0 - y1) + x1**2 * (y2 - y0) + x0**2 * (y1 - y2)) / den
        peak_f = float(-b / (2 * a)) if a < 0 else float(f[k])
        peak = float(max(m2[k], np.polyval([a, b, (y0 - a * x0**2 - b * x0)], peak_f)))
    else:
        return None
    level = peak / 2.0
    left = np.flatnonzero(m2[:k] < level)
    right = np.flatnonzero(m2[k:] < level)
    if left.size == 0 or right.size == 0:
        return None
    i = int(left[-1])
    j = int(right[0]) + k

    def cross(a: int, b: int) -> float:
        return float(f[a] + (level - m2[a]) * (f[b] - f[a]) / (m2[b] - m2[a]))

    return peak_f, cross(i, i + 1), cross(j - 1, j)


def identify_air(points: Sequence[FrfPoint], geometry: Fin) -> Identified:
    """``f_sc``, ``zeta``, ``theta``, ``C_eq`` and ``D`` from an in-air stepped sine (module docstring)."""
    if len(points) < 4:
        raise IdentificationError(f"an in-air sweep needs at least 4 points, got {len(points)}")
    c = _columns(points)
    f, V, I_, U = c["f"], c["V"], c["I"], c["U"]
    phi = geometry.phi_tip
    has_tip = np.isfinite(U.real)
    warnings: list[str] = []
    # --- the paper's estimates, which also start the fit
    if np.count_nonzero(has_tip) >= 4:
        mob = np.abs(U[has_tip] / V[has_tip])
        hp = half_power(f[has_tip], mob)
        k = int(np.argmax(mob))
        f_peak = float(f[has_tip][k])
    else:
        motional = np.abs(I_ / V - 1j * 2 * np.pi * f * np.median((I_ / V).imag / (2 * np.pi * f)))
        hp = half_power(f, motional)
        f_peak = float(f[int(np.argmax(motional))])
        mob = None
    if hp is not None:
        f_peak, f1, f2 = hp
        zeta_hp = (f2 - f1) / (2.0 * f_peak)
    else:
        zeta_hp = math.nan
        warnings.append(
            "zeta (half-power): the sweep does not cross the half-power level on both sides of the "
            "resonance; sweep wider around it"
        )
    zeta0 = zeta_hp if math.isfinite(zeta_hp) and zeta_hp > 0 else 0.02
    wn0 = 2 * np.pi * f_peak
    if mob is not None:
        theta0 = float(np.max(mob)) * 2 * zeta0 * wn0 / phi
    else:
        # at resonance Re(I/V) = theta^2 / (2 zeta w_n)
        theta0 = math.sqrt(max(float(np.max((I_ / V).real)), 1e-15) * 2 * zeta0 * wn0)
    far = int(np.argmax(np.abs(f - f_peak)))
    w_far = 2 * np.pi * f[far]
    c_far = float((I_[far] / V[far]).imag / w_far - theta0**2 / (wn0**2 - w_far**2))
    c_eq0 = c_far if c_far > 0 else float(np.abs(I_[far] / V[far]) / w_far)

    def model(x: FloatArray, use_tip: bool, use_current: bool) -> FloatArray:
        f_sc, zeta, theta, c_eq = x
        parts = []
        if use_tip and np.any(has_tip):
            sel = has_tip
            parts.append(
                _residual(U[sel], air_mobility(f[sel], f_sc, zeta, theta, phi), _sub(c, sel), c["su"][sel])
            )
        if use_current:
            parts.append(_residual(I_, air_admittance(f, f_sc, zeta, theta, c_eq), c, c["si"]))
        return np.concatenate(parts)

    x0 = np.array([f_peak, zeta0, theta0, c_eq0])
    bounds = ([0.5 * f_peak, 1e-5, 1e-9, 1e-13], [2.0 * f_peak, 0.5, 1.0, 1e-2])
    x, sx, chi2, _ = _fit(lambda z: model(z, True, True), x0, bounds)
    others_theta: dict[str, float] = {}
    others_c: dict[str, float] = {}
    if np.any(has_tip):
        xu, *_ = _fit(
            lambda z: model(np.array([z[0], z[1], z[2], x[3]]), True, False),
            x[:3].copy(),
            (bounds[0][:3], bounds[1][:3]),
        )
        others_theta["FRF amplitude (tip velocity alone)"] = float(xu[2])
    xi, *_ = _fit(lambda z: model(z, False, True), x.copy(), bounds)
    others_theta["motional current (current alone)"] = float(xi[2])
    others_c["as a capacitance meter reads, Im(I/V)/w at the farthest point"] = float(
        (I_[far] / V[far]).imag / w_far
    )
    others_c["fit of the current alone"] = float(xi[3])
    m_s, ell = geometry.m_s, geometry.L_active
    d_of = modeshape_d(x[0], m_s, ell)
    values = {
        "f_sc": Estimate(float(x[0]), float(sx[0]), "Hz", "fit of Eqs. (10)-(11)", {PEAK: f_peak}),
        "zeta": Estimate(float(x[1]), float(sx[1]), "-", "fit of Eq. (11)", {"half-power points": zeta_hp}),
        "theta": Estimate(float(x[2]), float(sx[2]), "C/(m sqrt(kg))", "fit of Eqs. (10)-(11)", others_theta),
        "C_eq": Estimate(float(x[3]), float(sx[3]), "F", "fit of Eq. (10)", others_c),
        "D": Estimate(
            d_of,
            2.0 * d_of * float(sx[0]) / float(x[0]),
            "N m^2",
            f"Eq. (8) with the active length {ell * 1e3:.1f} mm",
            {
                f"Eq. (8) with the overall length {geometry.L * 1e3:.1f} mm": modeshape_d(
                    x[0], m_s, geometry.L
                )
            },
        ),
    }
    zeta_fit = float(x[1])
    in_band = int(np.count_nonzero(np.abs(f - x[0]) <= zeta_fit * x[0]))
    if in_band < 3 and math.isfinite(zeta_hp):
        warnings.append(
            f"zeta (half-power points): only {in_band} point(s) inside the half-power band "
            f"{x[0] * (1 - zeta_fit):.2f}-{x[0] * (1 + zeta_fit):.2f} Hz, so the paper's method is coarse "
            f"({zeta_hp:.4g}); the fit uses the whole curve. Add points there to check it"
        )
    if chi2 > POOR_FIT_CHI2:
        warnings.append(
            f"the in-air model does not fit these points (chi2/n {chi2:.3g}): is this a low-voltage stepped "
            "sine in air, settled at each point?"
        )
    for name in ("f_sc", "zeta", "theta", "C_eq"):
        e = values[name]
        if not math.isfinite(e.sigma):
            warnings.append(f"{name}: not identified (the fit ends on a bound)")
        elif e.relative > 0.05:
            warnings.append(
                f"{name}: poorly identified ({e.relative:.0%} uncertainty); add points near the resonance"
            )
    return Identified(values, chi2, len(points), warnings)


def modeshape_d(f_sc: float, m_s: float, length: float) -> float:
    """``D`` from Eq. (8): ``w_n = lambda^2 sqrt(D / (m_s l^4))``."""
    wn = 2 * math.pi * f_sc
    return wn**2 * m_s * length**4 / modeshape.LAMBDA1**4


def _sub(c: dict[str, NDArray[Any]], sel: NDArray[Any]) -> dict[str, NDArray[Any]]:
    return {k: v[sel] for k, v in c.items()}


def water_mobility(fin: Fin, f: FloatArray, vpp: FloatArray) -> NDArray[Any]:
    """``U / V`` under water: the fundamental of the three-harmonic balance, m/(s V)."""
    s = harmonic_balance(fin, f, vpp, harmonics=3)
    w = 2 * np.pi * f
    eta = s.H0 - 1j * s.H1  # eta = H0 cos + H1 sin = Re((H0 - j H1) e^{jwt}) for v = V cos
    return 1j * w * fin.phi_tip * eta / (0.5 * vpp)  # type: ignore[no-any-return]


def identify_water(points: Sequence[FrfPoint], air: Fin, min_drag_share: float = 0.05) -> Identified:
    """``c_m`` and ``c_d`` from an underwater stepped sine, the in-air parameters of ``air`` fixed."""
    c = _columns(points)
    has_tip = np.isfinite(c["U"].real)
    if np.count_nonzero(has_tip) < 4:
        raise IdentificationError(
            "an underwater sweep needs at least 4 points with the tip velocity, "
            f"got {np.count_nonzero(has_tip)}"
        )
    c = _sub(c, has_tip)
    f, V, U = c["f"], c["V"], c["U"]
    vpp = 2 * np.abs(V)
    mob = U / V
    warnings: list[str] = []
    area = 0.25 * math.pi * air.rho_w * air.b**2 / air.m_s  # mu per unit c_m
    # resonance: where the velocity is in phase with the drive (phase crosses zero, falling)
    ph = np.angle(mob)
    order = np.argsort(f)
    fo, po = f[order], ph[order]
    cross = np.flatnonzero((po[:-1] > 0) & (po[1:] <= 0))
    if cross.size:
        i = int(cross[0])
        f_w = float(fo[i] + po[i] * (fo[i + 1] - fo[i]) / (po[i] - po[i + 1]))
    else:
        f_w = float(f[int(np.argmax(np.abs(mob)))])
        warnings.append(
            "c_m (resonance shift): the phase does not cross zero in the sweep; sweep across the resonance"
        )
    mu_w = (air.f_sc / f_w) ** 2 - 1.0
    cm_shift = mu_w / area if mu_w > 0 else math.nan
    # c_d from the amplitude at resonance (closed form of Eq. 15-16 with a = 0)
    k = int(np.argmin(np.abs(f - f_w)))
    w = 2 * np.pi * f[k]
    amp = abs(U[k]) / (w * air.phi_tip)
    gamma1 = air.replace(c_d=1.0).gamma
    c0 = 2 * air.zeta * air.omega_n * w
    force = air.theta * abs(V[k])
    cd_amp = (force / amp - c0) / (DRAG_HARMONIC * gamma1 * w**2 * amp)
    cm0 = cm_shift if math.isfinite(cm_shift) and cm_shift > 0 else float(hydro.inertia_coefficient(air.psi))
    cd0 = cd_amp if cd_amp > 0 else 1.0

    def residual(x: FloatArray) -> FloatArray:
        fin = air.replace(c_m=float(x[0]), c_d=float(x[1]))
        return _residual(U, water_mobility(fin, f, vpp), c, c["su"])

    x, sx, chi2, _ = _fit(residual, np.array([cm0, cd0]), ([1e-4, 0.0], [5.0, 100.0]))
    # how much of the damping at resonance is drag: too little and c_d is not identifiable
    fit = air.replace(c_m=float(x[0]), c_d=float(x[1]))
    s = harmonic_balance(fit, f_w, float(np.median(vpp)), harmonics=1)
    wr = 2 * np.pi * f_w
    drag = DRAG_HARMONIC * fit.gamma * wr**2 * float(s.modal_amplitude)
    share = drag / (drag + 2 * air.zeta * air.omega_n * wr)
    if chi2 > POOR_FIT_CHI2:
        warnings.append(
            f"the underwater model does not fit these points (chi2/n {chi2:.3g}): an effect the fin model "
            "lacks (try `piezofin diagnose`), or steps that had not settled"
        )
    rel_cd = sx[1] / x[1] if x[1] > 0 else math.inf
    if share < min_drag_share or not rel_cd <= 0.1:
        warnings.append(
            f"c_d: the drag is only {share:.1%} of the damping at resonance at {np.median(vpp):.0f} Vpp; "
            f"the drive is too small to identify it (+-{rel_cd:.0%}): sweep at a higher voltage"
        )
    near = np.count_nonzero(np.abs(f - f_w) <= 0.5 * _half_band(fit, f_w, float(np.median(vpp))))
    if near < 3:
        warnings.append(
            f"c_m: only {near} point(s) near the underwater resonance {f_w:.2f} Hz; add points there"
        )
    values = {
        "c_m": Estimate(
            float(x[0]),
            float(sx[0]),
            "-",
            "fit of the harmonic balance",
            {"resonance shift": cm_shift, "Eq. (21)": float(hydro.inertia_coefficient(air.psi))},
        ),
        "c_d": Estimate(
            float(x[1]), float(sx[1]), "-", "fit of the harmonic balance", {"amplitude at resonance": cd_amp}
        ),
        "f_w": Estimate(f_w, math.nan, "Hz", "phase crossing of U/V", {"drag share of the damping": share}),
    }
    return Identified(values, chi2, len(points), warnings)


def _half_band(fin: Fin, f_w: float, vpp: float) -> float:
    """Width of the underwater half-power band at ``vpp`` (single-term balance), Hz."""
    ff = np.linspace(0.3 * f_w, 2.0 * f_w, 400)
    s = harmonic_balance(fin, ff, vpp)
    m = np.asarray(s.tip_velocity_rms) ** 2
    above = ff[m >= 0.5 * m.max()]
    return float(above[-1] - above[0]) if above.size else f_w
