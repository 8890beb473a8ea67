"""Frequency-response points from a recorded stepped sine: steps found in the drive, lock-in, noise.

A stepped-sine test drives the fin at one frequency until it settles, then steps to the next.
:func:`frf_points` turns the samples of such a test (a bag, or arrays) into one :class:`FrfPoint`
per step, without being told what was commanded, so a real rig's recording works as well as the
simulated rig's:

* **Steps** are found in the drive voltage itself (:func:`find_steps`): upward zero crossings with
  hysteresis give the periods; a period smoothed over ``2 k`` crossings (so the timing jitter of
  the noise is divided by ``2 k``) that leaves the running median of its step by more than
  ``tolerance`` starts a new step.  Steps finer than ``tolerance`` (0.3 %) merge.
* **Amplitudes** are a lock-in over the last half of each step in whole periods: the complex
  fundamental amplitudes ``V``, ``I`` and ``U`` (tip velocity) with ``x ~ Re(X e^{j w t})``, and odd
  harmonics up to the 5th and a constant in the same least squares so that neither leaks into the
  fundamental.
* **Noise** is measured, not assumed: the residual of that fit gives each channel's noise, and the
  standard error of each part of a complex amplitude is ``s sqrt(2 / n)`` for ``n`` samples.  A
  step that has not settled shows as a difference between the third and the last quarter of the
  step; what of it exceeds the noise is added to the error, so an unsettled point weighs less
  instead of biasing the fit.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..bags import block_of, read_messages
from ..bags.blocks import DRIVE_CHANNELS, TIP_CHANNELS, BlockFormatError, check_samples
from ..errors import EstimationError

FloatArray = NDArray[np.float64]

#: Relative change of the smoothed period that starts a new step.
STEP_TOLERANCE = 3e-3
#: Periods of smoothing on each side of a period in :func:`find_steps`; a small step is found up
#: to this many periods late, so the analysis leaves out one more than this at the end of each step.
SMOOTH_PERIODS = 4
GUARD_PERIODS = SMOOTH_PERIODS + 1
#: Fewest whole periods a step must have in its analysed half to give a point.
MIN_PERIODS = 8


class IdentificationError(EstimationError):
    """Data that cannot give what is asked (no steps, no drive, missing channel)."""


@dataclass(frozen=True)
class FrfPoint:
    """One settled step of a stepped sine: complex fundamental amplitudes and their errors.

    ``voltage`` (V), ``current`` (A) and ``tip`` (m/s; NaN without a vibrometer) are complex
    amplitudes on one time reference, ``x(t) ~ Re(X e^{j w t})``; the ``sigma_*`` are the standard
    errors of the real (and of the imaginary) part of each.
    """

    frequency_hz: float
    voltage: complex
    current: complex
    tip: complex
    sigma_voltage: float
    sigma_current: float
    sigma_tip: float
    t_start: float
    t_end: float
    n_periods: int

    @property
    def voltage_pp(self) -> float:
        return 2.0 * abs(self.voltage)

    @property
    def mobility(self) -> complex:
        """Tip velocity per volt ``U / V``, m/(s V) (the paper's velocity FRF)."""
        return self.tip / self.voltage

    @property
    def admittance(self) -> complex:
        """Current per volt ``I / V``, S."""
        return self.current / self.voltage

    @property
    def has_tip(self) -> bool:
        return bool(np.isfinite(self.tip.real))

    def record(self) -> dict[str, float]:
        return {
            "frequency_hz": self.frequency_hz,
            "voltage_pp": self.voltage_pp,
            "mobility_abs": abs(self.mobility) if self.has_tip else math.nan,
            "mobility_phase_rad": float(np.angle(self.mobility)) if self.has_tip else math.nan,
            "admittance_abs": abs(self.admittance),
            "admittance_phase_rad": float(np.angle(self.admittance)),
            "sigma_tip": self.sigma_tip,
            "sigma_current": self.sigma_current,
            "sigma_voltage": self.sigma_voltage,
            "t_start": self.t_start,
            "t_end": self.t_end,
        }


@dataclass(frozen=True)
class Step:
    """A run of drive periods at one frequency: crossing times ``crossings[0] .. crossings[-1]``."""

    crossings: FloatArray

    @property
    def frequency_hz(self) -> float:
        c = self.crossings
        return float((len(c) - 1) / (c[-1] - c[0]))


def _upward_crossings(t: FloatArray, v: FloatArray, hysteresis: float) -> FloatArray:
    """Interpolated times of upward zero crossings, each after ``v`` went below ``-hysteresis``."""
    up = np.flatnonzero((v[:-1] < 0) & (v[1:] >= 0))
    below = np.flatnonzero(v < -hysteresis)
    if up.size == 0 or below.size == 0:
        return np.empty(0)
    # a crossing counts if the signal dipped below -h since the previous counted crossing
    last_below = np.searchsorted(below, up, side="right") - 1  # index into `below` of the last dip
    keep = []
    prev = -1
    for k, lb in zip(up.tolist(), last_below.tolist(), strict=True):
        if lb >= 0 and below[lb] > prev:
            keep.append(k)
            prev = k
    idx = np.asarray(keep, dtype=int)
    if idx.size == 0:
        return np.empty(0)
    t0, t1, v0, v1 = t[idx], t[idx + 1], v[idx], v[idx + 1]
    return t0 - v0 * (t1 - t0) / (v1 - v0)  # type: ignore[no-any-return]


def find_steps(
    t: FloatArray, v: FloatArray, tolerance: float = STEP_TOLERANCE, smooth: int = SMOOTH_PERIODS
) -> list[Step]:
    """The stepped sine's steps, found in the drive voltage (see the module docstring)."""
    amplitude = float(np.percentile(np.abs(v), 99.5)) if v.size else 0.0
    if not amplitude > 0:
        return []
    cross = _upward_crossings(t, v, 0.2 * amplitude)
    if cross.size < 2 * smooth + 2:
        return []
    period = np.diff(cross)
    # a gap (drive off, samples missing) is a step boundary: periods far longer than their neighbours
    n = period.size
    k = smooth
    pad = np.concatenate([np.full(k, period[0]), period, np.full(k, period[-1])])
    smoothed = np.convolve(pad, np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
    steps: list[Step] = []
    start = 0
    ref: list[float] = []  # raw periods of the step so far
    for i in range(n):
        if ref:
            med = float(np.median(ref[-50:]))
            gap = abs(period[i] - med) > 0.25 * med  # the drive stopped, or a large step
            moved = abs(smoothed[i] - med) > tolerance * med and len(ref) > k
            if gap or moved:
                steps.append(Step(cross[start : i + 1]))
                start, ref = (i + 1, []) if gap else (i, [])
                if gap:
                    continue
        ref.append(float(period[i]))
    steps.append(Step(cross[start:]))
    return [s for s in steps if len(s.crossings) > 2 * MIN_PERIODS + GUARD_PERIODS + 1]


def _lockin(tt: FloatArray, x: FloatArray, omega: float, t_ref: float) -> tuple[complex, float]:
    """Fundamental complex amplitude of ``x`` and the standard error of its real/imag parts."""
    orders = np.array([1.0, 3.0, 5.0])
    ph = np.outer(tt - t_ref, omega * orders)
    basis = np.column_stack([np.ones_like(tt), np.cos(ph), np.sin(ph)])
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    resid = x - basis @ coef
    dof = max(tt.size - basis.shape[1], 1)
    s = math.sqrt(float(resid @ resid) / dof)
    return complex(coef[1], -coef[4]), s * math.sqrt(2.0 / tt.size)


def _amplitude(
    t: FloatArray, x: FloatArray, omega: float, t_ref: float, q: tuple[float, float, float]
) -> tuple[complex, float]:
    """Lock-in over ``[q0, q2)`` with the unsettled part added to the error (3rd vs 4th quarter)."""
    sel = (t >= q[0]) & (t < q[2]) & np.isfinite(x)
    if np.count_nonzero(sel) < 16:
        return complex(math.nan, math.nan), math.nan
    value, sigma = _lockin(t[sel], x[sel], omega, t_ref)
    a = (t >= q[0]) & (t < q[1]) & np.isfinite(x)
    b = (t >= q[1]) & (t < q[2]) & np.isfinite(x)
    if np.count_nonzero(a) >= 16 and np.count_nonzero(b) >= 16:
        xa, _ = _lockin(t[a], x[a], omega, t_ref)
        xb, _ = _lockin(t[b], x[b], omega, t_ref)
        drift = abs(xb - xa) / 2.0  # half the change between the quarters: what is left in the mean
        excess = drift**2 - 2.0 * sigma**2  # each quarter's noise alone gives about this much
        if excess > 0:
            sigma = math.sqrt(sigma**2 + excess)
    return value, sigma


def _frequency(t: FloatArray, v: FloatArray, crossings: FloatArray, q: tuple[float, float, float]) -> float:
    """The drive frequency over ``crossings``: the slope of the crossing times against their count,
    refined by the voltage's phase drift between the two quarters (a lock-in at a frequency off by
    ``df`` turns the phase by ``2 pi df`` per second)."""
    k = np.arange(len(crossings), dtype=float)
    period = float(np.polyfit(k, crossings, 1)[0])
    f = 1.0 / period
    for _ in range(2):
        a = (t >= q[0]) & (t < q[1])
        b = (t >= q[1]) & (t < q[2])
        if np.count_nonzero(a) < 16 or np.count_nonzero(b) < 16:
            break
        va, _ = _lockin(t[a], v[a], 2 * math.pi * f, q[0])
        vb, _ = _lockin(t[b], v[b], 2 * math.pi * f, q[0])
        f += float(np.angle(vb / va)) / (2 * math.pi * 0.5 * (q[2] - q[0]))
    return f


def frf_points(
    t: FloatArray,
    voltage: FloatArray,
    current: FloatArray,
    tip_t: FloatArray | None = None,
    tip: FloatArray | None = None,
    tolerance: float = STEP_TOLERANCE,
) -> list[FrfPoint]:
    """One :class:`FrfPoint` per step of a stepped sine in these samples (see the module)."""
    order = np.argsort(t, kind="stable")
    t, voltage, current = t[order], voltage[order], current[order]
    if tip is not None and tip_t is not None:
        o = np.argsort(tip_t, kind="stable")
        tip_t, tip = tip_t[o], tip[o]
    points = []
    for step in find_steps(t, voltage, tolerance):
        c = step.crossings[: len(step.crossings) - GUARD_PERIODS]  # a step may end late: see find_steps
        n = len(c) - 1
        half = c[n - n // 2 :]  # whole periods of the last half
        if len(half) - 1 < MIN_PERIODS:
            continue
        mid = half[(len(half) - 1) // 2]
        q = (float(half[0]), float(mid), float(half[-1]))
        t_ref = float(half[0])
        f = _frequency(t, voltage, half, q)
        w = 2.0 * math.pi * f
        V, sv = _amplitude(t, voltage, w, t_ref, q)
        I_, si = _amplitude(t, current, w, t_ref, q)
        if tip is not None and tip_t is not None:
            U, su = _amplitude(tip_t, tip, w, t_ref, q)
        else:
            U, su = complex(math.nan, math.nan), math.nan
        if not (abs(V) > 0 and math.isfinite(abs(V))):
            continue
        points.append(FrfPoint(f, V, I_, U, sv, si, su, q[0], q[2], len(half) - 1))
    return points


def _concat(chunks: list[tuple[FloatArray, ...]], width: int) -> tuple[FloatArray, ...]:
    if not chunks:
        return tuple(np.empty(0) for _ in range(width))
    return tuple(np.concatenate([c[k] for c in chunks]) for k in range(width))


def read_sweep(
    path: str | os.PathLike[str], namespace: str = "/fin", tolerance: float = STEP_TOLERANCE
) -> list[FrfPoint]:
    """The FRF points of a recorded stepped sine: one fin's ``drive`` and ``tip_velocity`` in a bag.

    Raises :class:`~piezofin_ros.errors.BagError` on an unreadable bag and :class:`IdentificationError`
    when it holds no drive or no step.
    """
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    topics = {f"{ns}/drive": DRIVE_CHANNELS, f"{ns}/tip_velocity": TIP_CHANNELS}
    drive: list[tuple[FloatArray, ...]] = []
    tips: list[tuple[FloatArray, ...]] = []
    skipped = 0
    for m in read_messages(path, topics):
        channels = topics[m.topic]
        try:
            b = check_samples(block_of(m.type_name, m.data), channels)
        except (BlockFormatError, KeyError, ValueError):
            skipped += 1
            continue
        (drive if channels is DRIVE_CHANNELS else tips).append(tuple(np.asarray(b[c], float) for c in channels))
    if not drive:
        raise IdentificationError(f"{path}: no drive samples on {ns}/drive (is the namespace right?)")
    t, v, i = _concat(drive, 3)
    tt, u = _concat(tips, 2) if tips else (None, None)
    points = frf_points(t, v, i, tt, u, tolerance)
    if not points:
        raise IdentificationError(
            f"{path}: no settled stepped-sine step found in {ns}/drive ({t.size} samples); "
            f"each step needs at least {2 * MIN_PERIODS + GUARD_PERIODS + 2} periods"
        )
    return points


def merge(points: Iterable[FrfPoint]) -> list[FrfPoint]:
    """Points in frequency order."""
    return sorted(points, key=lambda p: p.frequency_hz)
