r"""Where the gap lies: each stage of the model checked with *measured* inputs.

Feeding every stage with measurements, not with the previous stage's prediction, finds a gap
where it arises instead of where it propagates (a resonance error would otherwise show up as a
thrust error too).  With ``V`` the measured drive amplitude, ``u`` the RMS tip velocity, ``psi``
its phase relative to the voltage and ``U_1 = sqrt(2) u e^{j psi}`` its fundamental phasor:

``drive``   command -> drive voltage: measured ``Vpp`` against the commanded one (amplifier).
``tip``     drive -> tip motion: ``u`` and ``psi`` against the model's steady state at the
            measured ``V`` (Eqs. 15-16); per voltage, the frequency of the largest ``u / V``.
``current`` tip motion and drive -> current, Eq. (10): ``I_1 = j w C_eq V + (theta/phi(L)) U_1``,
            so ``P = (1/2) V (theta/phi(L)) |U_1| cos(psi)``; a surplus is power that does not
            go into motion (electrical loss).
``thrust``  tip motion -> thrust, Eqs. (19)-(21): ``(1/2) m_v u^2`` against the load cell.
``power budget`` tip motion -> dissipation, Eq. (9): ``(1/2)(c_0 + k A) w A^2`` at the measured
            modal amplitude ``A = |U_1| / (phi(L) w)`` against the measured mean power.
``supply``  drive -> supply (where a supply meter was recorded): the supply's measured power against
            the amplifier's model (``physics/amplifier.py``) at the measured drive.  The amplifier is
            not the fin: this stage is said, never explained by the fin's effects.

Each stage's uncertainty is propagated from the channels' sigmas (first order).  A stage has a
gap when its residuals are unlikely under the noise alone: ``chi^2`` over its trials has a
p-value below ``alpha`` (1e-3).  Otherwise the report says "none (inside the noise)".
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from ..physics.model import Model
from ..physics.steady import DRAG_HARMONIC
from .data import Trials

FloatArray = NDArray[Any]
ALPHA = 1e-3


@dataclass(frozen=True)
class StageGap:
    """One stage's comparison, per trial (NaN where the inputs are missing)."""

    stage: str
    quantity: str
    unit: str
    scale: float  # display factor from SI to ``unit``
    measured: FloatArray
    predicted: FloatArray
    sigma: FloatArray
    relative: bool = True  # gaps in percent (else in units, e.g. a phase)

    @property
    def gap(self) -> FloatArray:
        d = self.measured - self.predicted
        if self.unit == "deg":
            d = np.angle(np.exp(1j * d))
        return d

    @property
    def z(self) -> FloatArray:
        return self.gap / self.sigma

    @property
    def valid(self) -> NDArray[np.bool_]:
        return np.isfinite(self.z)

    @property
    def relative_gap(self) -> FloatArray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.gap / np.abs(self.predicted)

    @property
    def chi2(self) -> float:
        return float(np.sum(self.z[self.valid] ** 2))

    @property
    def n(self) -> int:
        return int(np.count_nonzero(self.valid))

    @property
    def p_value(self) -> float:
        return float(stats.chi2.sf(self.chi2, self.n)) if self.n else math.nan

    @property
    def significant(self) -> bool:
        return self.n > 0 and self.p_value < ALPHA

    def summary(self, trials: Trials) -> dict[str, Any]:
        ok = self.valid
        out: dict[str, Any] = {
            "stage": self.stage,
            "quantity": self.quantity,
            "trials": self.n,
            "chi2": self.chi2,
            "p_value": self.p_value,
            "gap": bool(self.significant),
        }
        if not self.n:
            out["verdict"] = "not measured"
            return out
        rel = self.relative_gap[ok]
        units = self.gap[ok] * self.scale
        worst = int(np.flatnonzero(ok)[np.argmax(np.abs(self.z[ok]))])
        out.update(
            median_gap_percent=float(np.median(rel) * 100) if self.relative else None,
            rms_gap_percent=float(np.sqrt(np.mean(rel**2)) * 100) if self.relative else None,
            median_gap=float(np.median(units)),
            rms_gap=float(np.sqrt(np.mean(units**2))),
            unit=self.unit,
            worst={
                "frequency_hz": float(trials.frequency_hz[worst]),
                "voltage_pp": float(trials.voltage_pp[worst]),
                "gap": float(self.gap[worst] * self.scale),
                "z": float(self.z[worst]),
            },
        )
        if not self.significant:
            out["verdict"] = "none (inside the noise)"
        elif self.relative:
            out["verdict"] = (
                f"gap: median {np.median(rel) * 100:+.1f} %, RMS {np.sqrt(np.mean(rel**2)) * 100:.1f} %"
            )
        else:
            out["verdict"] = (
                f"gap: median {np.median(units):+.1f} {self.unit}, RMS {np.sqrt(np.mean(units**2)):.1f} {self.unit}"  # noqa: E501
            )
        return out


def stage_gaps(trials: Trials, model: Model) -> list[StageGap]:
    """Every stage that the table's channels allow, in the order of the signal chain."""
    fin = model.fin
    f = trials.frequency_hz
    w = 2 * math.pi * f
    measured = trials.measured_drive()
    s = trials.sigma
    out: list[StageGap] = []
    pred = model.predict(f, trials.voltage_pp, drive_pp=measured, time_s=trials.time_s)
    if measured is not None and trials.commanded:
        out.append(
            StageGap(
                "drive",
                "drive voltage (Vpp)",
                "V",
                1.0,
                measured,
                pred.voltage_pp_drive,
                s["voltage_pp_drive"],
            )
        )
    v_in = measured if measured is not None else pred.voltage_pp_drive
    u, ph = trials.tip_velocity_rms, trials.tip_phase_rad
    out.append(
        StageGap("tip", "RMS tip velocity", "mm/s", 1e3, u, pred.tip_velocity_rms, s["tip_velocity_rms"])
    )
    out.append(
        StageGap(
            "tip",
            "tip-velocity phase",
            "deg",
            180 / math.pi,
            ph,
            pred.tip_phase_rad,
            s["tip_phase_rad"],
            relative=False,
        )
    )
    amp_v = 0.5 * v_in
    u1 = math.sqrt(2) * u  # fundamental amplitude of the tip velocity
    g = fin.theta / fin.phi_tip
    p_motion = 0.5 * amp_v * g * u1 * np.cos(ph)
    su, sph = s["tip_velocity_rms"], s["tip_phase_rad"]
    sig_pm = 0.5 * amp_v * g * math.sqrt(2) * np.hypot(su * np.cos(ph), u * np.sin(ph) * sph)
    out.append(
        StageGap(
            "current",
            "power from the motion, Eq. (10)",
            "mW",
            1e3,
            trials.power_w,
            p_motion,
            np.hypot(sig_pm, s["power_w"]),
        )
    )
    i1 = 1j * w * fin.C_eq * amp_v + g * u1 * np.exp(1j * ph)
    i_pred = np.abs(i1) / math.sqrt(2)
    out.append(
        StageGap("current", "RMS current, Eq. (10)", "uA", 1e6, trials.current_rms, i_pred, s["current_rms"])
    )
    t_pred = 0.5 * fin.m_v * u**2
    out.append(
        StageGap(
            "thrust",
            "load-cell thrust vs Lighthill",
            "mN",
            1e3,
            trials.thrust_loadcell_n,
            t_pred,
            np.hypot(s["thrust_loadcell_n"], 2 * t_pred * su / np.where(u > 0, u, np.nan)),
        )
    )
    amp = u1 / (fin.phi_tip * w)
    c0 = 2 * fin.zeta * fin.omega_n * w
    kd = DRAG_HARMONIC * fin.gamma * w * w
    p_mech = 0.5 * (c0 + kd * amp) * w * amp**2
    rel_u = su / np.where(u > 0, u, np.nan)
    sig_mech = p_mech * rel_u * (2 + kd * amp / (c0 + kd * amp))
    out.append(
        StageGap(
            "power budget",
            "power vs dissipation at the measured motion",
            "mW",
            1e3,
            trials.power_w,
            p_mech,
            np.hypot(sig_mech, s["power_w"]),
        )
    )
    supply = np.asarray(trials.power_supply_w, float)
    if np.any(np.isfinite(supply)):
        out.append(
            StageGap(
                "supply",
                "supply power vs the amplifier's model",
                "mW",
                1e3,
                supply,
                np.asarray(trials.power_supply_model_w, float),
                np.asarray(trials.power_supply_sigma_w, float),
            )
        )
    return out


@dataclass(frozen=True)
class Resonance:
    voltage_pp: float
    measured_hz: float
    model_hz: float
    interior: bool  # the measured peak is not at the edge of the sweep


def _peak(f: FloatArray, y: FloatArray) -> tuple[float, bool]:
    order = np.argsort(f)
    f, y = f[order], y[order]
    j = int(np.nanargmax(y))
    if 0 < j < len(f) - 1:
        x0, x1, x2 = f[j - 1 : j + 2]
        y0, y1, y2 = y[j - 1 : j + 2]
        # vertex of the parabola through three points (non-uniform spacing)
        den = (x0 - x1) * (x0 - x2) * (x1 - x2)
        a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if a < 0:
            return float(np.clip(-b / (2 * a), x0, x2)), True
        return float(x1), True
    return float(f[j]), False


def resonances(trials: Trials, model: Model, fine: int = 400) -> list[Resonance]:
    """Per voltage, the frequency of the largest measured ``u / V`` and the model's (on a fine grid)."""
    out: list[Resonance] = []
    if not trials.has("tip_velocity_rms"):
        return out
    for v in trials.voltages:
        sel = np.round(trials.voltage_pp) == v
        if np.count_nonzero(sel) < 3:
            continue
        f = trials.frequency_hz[sel]
        fm, interior = _peak(f, trials.tip_velocity_rms[sel])
        grid = np.linspace(f.min(), f.max(), fine)
        pred = model.predict(grid, np.full(fine, v))
        out.append(Resonance(float(v), fm, float(grid[np.argmax(pred.tip_velocity_rms)]), interior))
    return out
