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
    #: The bound of the fit this value ended on (then it is no estimate), else ``None``.
    bound: float | None = None

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
    #: Why the values are not to be trusted (a fit that does not fit, a value on a bound), each with
    #: its likely cause; empty for a fit that can be used.
    problems: list[str] = field(default_factory=list)
    #: chi2/n of each channel at the fit (``tip``, ``current``): which one misfits.
    channel_chi2: dict[str, float] = field(default_factory=dict)

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
) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]]:
    """Least squares in parameters scaled by ``x0``; returns value (the bound itself where it ended
    on one), one-sigma (NaN on a bound), chi2/dof and which values ended on a bound."""
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
    # On a bound: there, or near it (within a thousandth of the range) with the bound inside one
    # sigma, so the data cannot tell the value from the bound.  The solver's iterates stay strictly
    # inside the bounds and stop where the cost stops falling, short of the bound by an amount that
    # varies with scipy's version (c_d 99.985 against 100, sigma 6e9: the swapped sweeps' fit).
    gap = np.minimum(np.abs(sol.x - lo), np.abs(sol.x - hi))
    near = gap < 1e-3 * (hi - lo)
    unresolved = ~(sigma / scale < gap)  # (a sigma that is NaN counts as unresolved)
    at_bound = (gap < 1e-9) | (near & unresolved)
    sigma = np.where(at_bound, math.nan, sigma)
    edge = np.where(np.abs(sol.x - lo) < np.abs(sol.x - hi), lo, hi)
    return np.where(at_bound, edge, sol.x) * scale, sigma, chi2, at_bound


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
    x, sx, chi2, on_bound = _fit(lambda z: model(z, True, True), x0, bounds)
    # each channel alone: the paper's separate estimates, and a check of the joint fit's honesty
    alone: dict[str, tuple[FloatArray, FloatArray]] = {}
    if np.any(has_tip):
        xu, su, *_ = _fit(
            lambda z: model(np.array([z[0], z[1], z[2], x[3]]), True, False),
            x[:3].copy(),
            (bounds[0][:3], bounds[1][:3]),
        )
        alone["tip"] = (np.append(xu, math.nan), np.append(su, math.nan))
    xi, si, *_ = _fit(lambda z: model(z, False, True), x.copy(), bounds)
    alone["current"] = (xi, si)
    channel_chi2 = _channel_chi2(x, has_tip, lambda z, tip, cur: model(z, tip, cur))
    # the paper's own estimates of the resonance and the damping disagree with the fit as well when
    # the resonance is bent (a fin that changes with its motion)
    paper = np.array([f_peak, zeta_hp if math.isfinite(zeta_hp) else math.nan, math.nan, math.nan])
    sx = _with_disagreement(x, sx, chi2, {**alone, "paper": (paper, paper)})
    others_theta: dict[str, float] = {}
    if "tip" in alone:
        others_theta["FRF amplitude (tip velocity alone)"] = float(alone["tip"][0][2])
    others_theta["motional current (current alone)"] = float(xi[2])
    meter = float((I_[far] / V[far]).imag / w_far)
    others_c: dict[str, float] = {
        "as a capacitance meter reads, Im(I/V)/w at the farthest point": meter,
        "fit of the current alone": float(xi[3]),
    }
    m_s, ell = geometry.m_s, geometry.L_active
    d_of = modeshape_d(x[0], m_s, ell)

    def bound(k: int) -> float | None:
        return _edge(x[k], bounds, k) if on_bound[k] else None

    values = {
        "f_sc": Estimate(float(x[0]), float(sx[0]), "Hz", "fit of Eqs. (10)-(11)", {PEAK: f_peak}, bound(0)),
        "zeta": Estimate(
            float(x[1]), float(sx[1]), "-", "fit of Eq. (11)", {"half-power points": zeta_hp}, bound(1)
        ),
        "theta": Estimate(
            float(x[2]), float(sx[2]), "C/(m sqrt(kg))", "fit of Eqs. (10)-(11)", others_theta, bound(2)
        ),
        "C_eq": Estimate(float(x[3]), float(sx[3]), "F", "fit of Eq. (10)", others_c, bound(3)),
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
    problems: list[str] = []
    if chi2 > POOR_FIT_CHI2:
        problems.append(
            f"the in-air model does not fit these points (chi2/n {chi2:.3g}): "
            + _air_misfit_cause(channel_chi2, float(np.median(2 * np.abs(V))), x[0], f, has_tip, model, x)
        )
    for name in ("f_sc", "zeta", "theta", "C_eq"):
        e = values[name]
        if e.bound is not None:
            problems.append(f"{name} = {_g(e.value)} {e.unit} is the fit's bound, not an estimate")
        elif e.relative > 0.05:
            warnings.append(
                f"{name}: poorly identified ({e.relative:.0%} uncertainty); add points near the resonance"
            )
    return Identified(values, chi2, len(points), warnings, problems, channel_chi2)


def _g(x: float) -> str:
    return f"{x:.4g}"


def _channel_chi2(
    x: FloatArray, has_tip: NDArray[np.bool_], residual: Callable[[FloatArray, bool, bool], FloatArray]
) -> dict[str, float]:
    """chi2/n of each channel at the joint fit ``x`` (n: the channel's real numbers)."""
    out = {}
    if np.any(has_tip):
        r = residual(x, True, False)
        out["tip"] = float(r @ r) / r.size
    r = residual(x, False, True)
    out["current"] = float(r @ r) / r.size
    return out


def _with_disagreement(
    x: FloatArray, sigma: FloatArray, chi2: float, alone: dict[str, tuple[FloatArray, FloatArray]]
) -> FloatArray:
    """The joint fit's sigmas, widened by how far each channel alone would put the value, when the
    model does not describe the data (reduced chi-square above :data:`BIASED_CHI2`).

    The tip velocity alone and the current alone each give ``f_sc``, ``zeta`` and ``theta`` (the
    current alone also ``C_eq``), and the paper's methods give ``f_sc`` (the peak) and ``zeta`` (the
    half-power points).  When one channel holds an effect the model lacks (a loss in the current,
    say), the joint fit sits between them, biased by up to its distance from the one that is right;
    when the resonance is bent, the peak leaves the fit's ``f_sc``.  Scaling by the reduced
    chi-square does not cover either (the misfit is systematic, not noise), so each distance is
    added in quadrature: the stated sigma does not claim more than the bias allows.
    """
    if chi2 <= BIASED_CHI2:
        return sigma
    out = sigma.copy()
    for value, _ in alone.values():
        d = np.where(np.isfinite(value), np.abs(value - x), 0.0)
        out = np.hypot(out, d)
    return out


#: A reduced chi-square above this: the model misses something, and the values may be biased.
BIASED_CHI2 = 2.0


#: A sweep above this drive is asked to be repeated lower when its resonance misfits (an
#: amplitude-dependent fin; the paper's in-air sweeps were at low voltage).
LOW_VOLTAGE_PP = 20.0


def _air_misfit_cause(
    chi2: dict[str, float],
    vpp: float,
    f_sc: float,
    f: FloatArray,
    has_tip: NDArray[np.bool_],
    model: Callable[[FloatArray, bool, bool], FloatArray],
    x: FloatArray,
) -> str:
    """The likely cause of an in-air misfit, from which channel misfits and where."""
    tip, cur = chi2.get("tip", math.nan), chi2["current"]
    said = "; ".join(f"{k} {v:.3g}" for k, v in chi2.items())
    if math.isfinite(tip) and cur > 10.0 * max(tip, 1.0):
        return (
            f"the current misfits (chi2/n by channel: {said}): a loss the model lacks (a dielectric "
            "loss, tan delta, or a leakage adds a current in phase with the voltage), or a current "
            "monitor that lags; `piezofin diagnose` tells them apart"
        )
    # where the misfit lies: at the resonance (a fin that changes with its motion), or all along
    per_point = _per_point(model(x, False, True))
    if np.any(has_tip):
        per_point[has_tip] += _per_point(model(x, True, False))
    near = np.abs(f - f_sc) <= 0.05 * f_sc
    share = float(per_point[near].sum() / max(per_point.sum(), 1e-300))
    where = f"{share:.0%} of it within 5 % of the resonance"
    if share > 0.5 and vpp > 1.2 * LOW_VOLTAGE_PP:
        return (
            f"the resonance misfits (chi2/n by channel: {said}; {where}): an amplitude-dependent "
            f"fin (a stiffness or damping that changes with the motion) bends it at {vpp:.0f} Vpp; "
            f"repeat the sweep at a lower voltage (at most {LOW_VOLTAGE_PP:.0f} Vpp)"
        )
    if share > 0.5:
        return (
            f"the resonance misfits (chi2/n by channel: {said}; {where}): steps that had not settled "
            "there (a longer dwell), or a fin that changes with its motion even at this drive"
        )
    return (
        f"the points misfit all along (chi2/n by channel: {said}; {where}): is this an in-air "
        "stepped sine, settled at each point? (an underwater sweep has its resonance far lower, and a "
        "protocol run is no stepped sine)"
    )


def _per_point(r: FloatArray) -> FloatArray:
    """A complex residual's squared size per point (``r`` is its real parts, then its imaginary)."""
    n = r.size // 2
    return r[:n] ** 2 + r[n:] ** 2  # type: ignore[no-any-return]


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


def water_admittance(fin: Fin, f: FloatArray, vpp: FloatArray) -> NDArray[Any]:
    """``I / V`` under water (Eq. 10: ``i = C_eq dv/dt + theta deta/dt``), the fundamental of the
    three-harmonic balance, S; in air (``rho_w = 0``) it is :func:`air_admittance`."""
    s = harmonic_balance(fin, f, vpp, harmonics=3)
    w = 2 * np.pi * f
    eta = s.H0 - 1j * s.H1
    return 1j * w * fin.C_eq + 1j * w * fin.theta * eta / (0.5 * vpp)  # type: ignore[no-any-return]


def identify_water(
    points: Sequence[FrfPoint],
    air: Fin,
    min_drag_share: float = 0.05,
    air_sigma: dict[str, float] | None = None,
) -> Identified:
    """``c_m`` and ``c_d`` from an underwater stepped sine, the in-air parameters of ``air`` fixed.

    With ``air_sigma`` (the in-air sigmas of ``f_sc``, ``zeta``, ``theta``), their uncertainty is
    carried into ``c_m`` and ``c_d``: the fit is repeated with each moved by its sigma, and the
    shifts are added in quadrature to the fit's own sigmas (the in-air values are held fixed, so the
    fit alone would not know them)."""
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

    bounds = ([1e-4, 0.0], [5.0, 100.0])
    x, sx, chi2, on_bound = _fit(residual, np.array([cm0, cd0]), bounds)
    for name, sigma_air in (air_sigma or {}).items():
        if not (math.isfinite(sigma_air) and sigma_air > 0) or np.any(on_bound):
            continue
        moved = air.replace(**{name: float(getattr(air, name)) + sigma_air})

        def residual_moved(z: FloatArray, moved: Fin = moved) -> FloatArray:
            model = water_mobility(moved.replace(c_m=float(z[0]), c_d=float(z[1])), f, vpp)
            return _residual(U, model, c, c["su"])

        xm, *_ = _fit(residual_moved, x.copy(), bounds)
        sx = np.hypot(sx, xm - x)
    # how much of the damping at resonance is drag: too little and c_d is not identifiable
    fit = air.replace(c_m=float(x[0]), c_d=float(x[1]))
    s = harmonic_balance(fit, f_w, float(np.median(vpp)), harmonics=1)
    wr = 2 * np.pi * f_w
    drag = DRAG_HARMONIC * fit.gamma * wr**2 * float(s.modal_amplitude)
    share = drag / (drag + 2 * air.zeta * air.omega_n * wr)
    problems: list[str] = []
    if chi2 > POOR_FIT_CHI2:
        problems.append(
            f"the underwater model does not fit these points (chi2/n {chi2:.3g}): an effect the fin model "
            "lacks (try `piezofin diagnose`), steps that had not settled, or an in-air fit that is off"
        )
    for k, name in enumerate(("c_m", "c_d")):
        if on_bound[k]:
            problems.append(f"{name} = {_g(float(x[k]))} is the fit's bound, not an estimate")
    rel_cd = sx[1] / x[1] if x[1] > 0 else math.inf
    if share < min_drag_share or not rel_cd <= 0.1:
        how = f"+-{rel_cd:.0%}" if math.isfinite(rel_cd) else "no sigma"
        warnings.append(
            f"c_d: the drag is only {share:.1%} of the damping at resonance at {np.median(vpp):.0f} Vpp; "
            f"the drive is too small to identify it ({how}): sweep at a higher voltage"
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
            _edge(x[0], bounds, 0) if on_bound[0] else None,
        ),
        "c_d": Estimate(
            float(x[1]),
            float(sx[1]),
            "-",
            "fit of the harmonic balance",
            {"amplitude at resonance": cd_amp},
            _edge(x[1], bounds, 1) if on_bound[1] else None,
        ),
        "f_w": Estimate(f_w, math.nan, "Hz", "phase crossing of U/V", {"drag share of the damping": share}),
    }
    return Identified(values, chi2, len(points), warnings, problems, {"tip": chi2})


def _edge(value: float, bounds: tuple[Sequence[float], Sequence[float]], k: int) -> float:
    """The bound ``value`` sits on."""
    lo, hi = float(bounds[0][k]), float(bounds[1][k])
    return lo if abs(value - lo) <= abs(value - hi) else hi


def _half_band(fin: Fin, f_w: float, vpp: float) -> float:
    """Width of the underwater half-power band at ``vpp`` (single-term balance), Hz."""
    ff = np.linspace(0.3 * f_w, 2.0 * f_w, 400)
    s = harmonic_balance(fin, ff, vpp)
    m = np.asarray(s.tip_velocity_rms) ** 2
    above = ff[m >= 0.5 * m.max()]
    return float(above[-1] - above[0]) if above.size else f_w
