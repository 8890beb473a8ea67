"""Frequency-response points from a recorded stepped sine: steps found in the drive, lock-in, noise.

A stepped-sine test drives the fin at one frequency until it settles, then steps to the next.
:func:`frf_points` turns the samples of such a test (a bag, or arrays) into one :class:`FrfPoint`
per step, without being told what was commanded, so a real rig's recording works as well as the
simulated rig's:

* **Steps** are found in the drive voltage itself (:func:`find_steps`): the phase of its analytic
  signal (Hilbert transform), fitted by a line over blocks of ``BLOCK_S`` (0.2 s), gives each
  block's frequency from every sample (far more precise than zero crossings, which the voltage
  noise moves).  A block that leaves the median of its step by more than ``tolerance`` (0.3 %) and
  by more than five times the blocks' own scatter starts a new step; a block with the drive off
  ends one.  Finer steps merge.
* **Amplitudes** are a lock-in over the last half of each step (whole periods, the last block left
  out), at the frequency refined by the voltage's phase drift: the complex
  fundamental amplitudes ``V``, ``I`` and ``U`` (tip velocity) with ``x ~ Re(X e^{j w t})``, and odd
  harmonics up to the 5th and a constant in the same least squares so that neither leaks into the
  fundamental.
* **Noise** is measured, not assumed: the residual of that fit gives each channel's noise, and the
  standard error of each part of a complex amplitude is ``s sqrt(2 / n)`` for ``n`` samples.  A
  step that has not settled shows as a difference between the third and the last quarter of the
  step; when it exceeds what the noise makes 99 % of the time, half of it is added to the error,
  so an unsettled point weighs less instead of biasing the fit.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from ..bags.fin import TOPIC_DRIVE, TOPIC_TIP, Skipped, read_fin, topic_prefix
from ..bags.reader import Damage
from ..errors import EstimationError

FloatArray = NDArray[np.float64]
_log = logging.getLogger(__name__)

#: Relative change of a block's frequency that starts a new step.
STEP_TOLERANCE = 3e-3
#: Length of the blocks whose frequencies :func:`find_steps` compares, s.  The block in which the
#: drive steps belongs to either side, so the analysis leaves one block out at the end of a step.
BLOCK_S = 0.2
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
    """A stretch of drive at one frequency, ``t_start`` to ``t_end`` (s)."""

    t_start: float
    t_end: float
    frequency_hz: float


def _block_frequencies(t: FloatArray, v: FloatArray, n: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per block of ``n`` samples: start time, amplitude and frequency from the slope of the
    analytic signal's phase (least squares over the block: every sample counts, so the frequency
    is far more precise than from zero crossings)."""
    analytic = signal.hilbert(v - np.mean(v))
    phase = np.unwrap(np.angle(analytic))
    amp = np.abs(analytic)
    m = t.size // n
    tb = t[: m * n].reshape(m, n)
    pb = phase[: m * n].reshape(m, n)
    tc = tb - tb.mean(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.sum(tc * (pb - pb.mean(axis=1, keepdims=True)), axis=1) / np.sum(tc * tc, axis=1)
    return tb[:, 0], np.median(amp[: m * n].reshape(m, n), axis=1), slope / (2 * math.pi)


def find_steps(
    t: FloatArray, v: FloatArray, tolerance: float = STEP_TOLERANCE, block_s: float = BLOCK_S
) -> list[Step]:
    """The stepped sine's steps, found in the drive voltage (see the module docstring)."""
    if t.size < 64:
        return []
    dt = float(np.median(np.diff(t)))
    n = max(16, round(block_s / dt))
    t0, amp, freq = _block_frequencies(t, v, n)
    on = amp > 0.3 * float(np.percentile(amp, 99))
    on &= np.isfinite(freq) & (freq > 0)
    # the blocks' own scatter (noise on the voltage): a block must leave its step's median by five
    # of it, and by ``tolerance``, to start a new step
    good = freq[on]
    jitter = 1.4826 * float(np.median(np.abs(np.diff(good)))) / math.sqrt(2.0) if good.size > 2 else 0.0
    local = _local_jitter(freq, on)
    steps: list[Step] = []
    cur: list[int] = []

    def close() -> None:
        if len(cur) >= 2:
            steps.append(Step(float(t0[cur[0]]), float(t0[cur[-1]]) + n * dt, float(np.median(freq[cur]))))

    for j in range(freq.size):
        if not on[j]:
            close()
            cur = []
            continue
        if cur:
            med = float(np.median(freq[cur[-25:]]))
            if abs(freq[j] - med) > max(tolerance * med, 5.0 * max(jitter, local[j])):
                close()
                cur = []
        cur.append(j)
    close()
    return [s for s in steps if (s.t_end - s.t_start) * s.frequency_hz >= 2 * MIN_PERIODS + 2]


def _local_jitter(freq: FloatArray, on: NDArray[np.bool_]) -> FloatArray:
    """Each block's scatter of frequency among the blocks of its band (bands 10 % wide in frequency;
    0 where a band holds fewer than 8 pairs of blocks): a block of under a period (0.2 s at 4 Hz)
    reads its frequency 0.5-1 % off, about ten times the scatter of the sweep's faster steps, and
    against theirs a 4 Hz step was cut into pieces too short to keep (a campaign on a twin with a
    heavier added mass lost it)."""
    out = np.zeros(freq.size)
    pair = on[1:] & on[:-1]
    if not np.any(pair):
        return out
    diff = np.abs(np.diff(freq))[pair]
    f = freq[1:][pair]
    band = np.floor(np.log(f) / math.log(1.1))
    for b in np.unique(band):
        d = diff[band == b]
        if d.size >= 8:
            lo, hi = 1.1**b, 1.1 ** (b + 1)
            near = on & (freq >= lo) & (freq < hi)
            out[near] = 1.4826 * float(np.median(d)) / math.sqrt(2.0)
    return out


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


def _span(t: FloatArray, x: FloatArray, t0: float, t1: float) -> tuple[FloatArray, FloatArray]:
    """The finite samples of ``x`` with ``t0 <= t < t1`` (``t`` sorted: two binary searches)."""
    i, j = np.searchsorted(t, [t0, t1])
    tt, xx = t[i:j], x[i:j]
    ok = np.isfinite(xx)
    return (tt, xx) if ok.all() else (tt[ok], xx[ok])


def _amplitude(
    t: FloatArray, x: FloatArray, omega: float, t_ref: float, q: tuple[float, float, float]
) -> tuple[complex, float]:
    """Lock-in over ``[q0, q2)`` with the unsettled part added to the error (3rd vs 4th quarter)."""
    tt, xx = _span(t, x, q[0], q[2])
    if tt.size < 16:
        return complex(math.nan, math.nan), math.nan
    value, sigma = _lockin(tt, xx, omega, t_ref)
    ta, xa_ = _span(t, x, q[0], q[1])
    tb, xb_ = _span(t, x, q[1], q[2])
    if ta.size >= 16 and tb.size >= 16:
        xa, _ = _lockin(ta, xa_, omega, t_ref)
        xb, _ = _lockin(tb, xb_, omega, t_ref)
        # noise alone makes |xb - xa| about 2 sigma (each half has twice the variance), beyond
        # 6 sigma 1 % of the time: a larger change is a transient, and half of it is in the mean
        change = abs(xb - xa)
        if change > 6.0 * sigma:
            sigma = math.hypot(sigma, change / 2.0)
    return value, sigma


def _frequency(t: FloatArray, v: FloatArray, f: float, q: tuple[float, float, float]) -> float:
    """The drive frequency over ``[q0, q2)``, refined from ``f`` by the voltage's phase drift between
    the two halves (a lock-in at a frequency off by ``df`` turns the phase by ``2 pi df`` per second)."""
    ta, va_ = _span(t, v, q[0], q[1])
    tb, vb_ = _span(t, v, q[1], q[2])
    if ta.size < 16 or tb.size < 16:
        return f
    for _ in range(2):
        va, _ = _lockin(ta, va_, 2 * math.pi * f, q[0])
        vb, _ = _lockin(tb, vb_, 2 * math.pi * f, q[0])
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
        end = step.t_end - BLOCK_S  # the last block may hold the next step's start
        n = int(0.5 * (end - step.t_start) * step.frequency_hz)  # whole periods in the last half
        if n < MIN_PERIODS:
            continue
        n -= n % 2
        span = n / step.frequency_hz
        q = (end - span, end - 0.5 * span, end)
        f = _frequency(t, voltage, step.frequency_hz, q)
        w = 2.0 * math.pi * f
        V, sv = _amplitude(t, voltage, w, q[0], q)
        I_, si = _amplitude(t, current, w, q[0], q)
        if tip is not None and tip_t is not None:
            U, su = _amplitude(tip_t, tip, w, q[0], q)
        else:
            U, su = complex(math.nan, math.nan), math.nan
        if not (abs(V) > 0 and math.isfinite(abs(V))):
            continue
        points.append(FrfPoint(f, V, I_, U, sv, si, su, q[0], q[2], n))
    return points


def _concat(chunks: list[tuple[FloatArray, ...]], width: int) -> tuple[FloatArray, ...]:
    if not chunks:
        return tuple(np.empty(0) for _ in range(width))
    return tuple(np.concatenate([c[k] for c in chunks]) for k in range(width))


def read_sweep(
    path: str | os.PathLike[str],
    namespace: str = "/fin",
    tolerance: float = STEP_TOLERANCE,
    on_damage: Callable[[Damage], None] | None = None,
) -> list[FrfPoint]:
    """The FRF points of a recorded stepped sine: one fin's ``drive`` and ``tip_velocity`` in a bag.

    A damaged bag gives what it still holds; each damage goes to ``on_damage`` (default: a logged
    warning).  Raises :class:`~piezofin_ros.errors.BagError` on an unreadable bag and
    :class:`IdentificationError` when it holds no drive or no step.
    """
    drive: list[tuple[FloatArray, ...]] = []
    tips: list[tuple[FloatArray, ...]] = []
    skipped = Skipped()
    for m in read_fin(path, namespace, (TOPIC_DRIVE, TOPIC_TIP), skipped=skipped, on_damage=on_damage):
        assert m.block is not None
        rows = tuple(np.asarray(row, float) for row in m.block.values)
        (drive if m.kind == TOPIC_DRIVE else tips).append(rows)
    ns = topic_prefix(namespace)
    if skipped.count:  # a damaged or foreign message is said, not dropped silently
        _log.warning(
            "%s: %d message(s) on %s/drive, %s/tip_velocity skipped: %s",
            path,
            skipped.count,
            ns,
            ns,
            skipped.lines[0],
        )
    if not drive:
        raise IdentificationError(f"{path}: no drive samples on {ns}/drive (is the namespace right?)")
    t, v, i = _concat(drive, 3)
    tt, u = _concat(tips, 2) if tips else (None, None)
    points = frf_points(t, v, i, tt, u, tolerance)
    if not points:
        raise IdentificationError(
            f"{path}: no settled stepped-sine step found in {ns}/drive ({t.size} samples); "
            f"each step needs at least {2 * MIN_PERIODS + 2} periods and {2 * BLOCK_S:g} s"
        )
    return points
