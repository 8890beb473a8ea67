r"""Thrust, power and thrust per watt from measured signals, over quasi-steady windows.

Two layers, both free of ROS:

* :func:`analyse_window` turns one window of samples (a whole number of drive periods) into an
  :class:`Estimate`.  It is a pure function, used live, on bags and in the tests.
* :class:`StreamEstimator` takes blocks of samples as they arrive (drive voltage and current,
  tip velocity, load-cell displacement, swimming speed), finds the quasi-steady windows in the
  drive signal itself and emits estimates.  It never needs to be told what was commanded, so it
  works the same behind ``fin_sim``, a rig driver or a fish's own drive electronics.

What is estimated (per window of ``N`` whole periods at ``f = w / 2 pi``)
-------------------------------------------------------------------------
The voltage, current and tip velocity are projected on the odd harmonics ``k = 1, 3, 5``
of the drive frequency (a lock-in: exact for a periodic steady state, and it rejects the white
measurement noise that would bias a mean square).  With ``U_k`` the complex amplitudes of the tip
velocity:

* RMS tip velocity ``u = sqrt(sum |U_k|^2 / 2)``;
* Lighthill's mean thrust, Eqs. (19)-(20): ``T = (1/2) m_v [u^2 - U^2 (phi'(L)/phi(L))^2 w_rms^2]``,
  ``w_rms^2 = sum |U_k|^2 / (2 (k w)^2)``, with ``m_v = (pi/4) rho_w b^2 c_m(psi)`` (Eq. 21);
* RMS current ``sqrt(sum |I_k|^2 / 2)`` from the same lock-in, like the tip velocity: white noise,
  mains pickup or any interference that is not at an odd harmonic of the drive does not enter it
  (a plain sample RMS takes 50 Hz pickup of 30 uA for a current gap);
* mean electrical power ``P = mean(v i)`` over a period, by Parseval from the same harmonics:
  ``P = sum_k Re(V_k conj(I_k)) / 2``.  A plain ``mean(v i)`` over samples leaks the reactive
  power ``C_eq v dv/dt`` (often 10x the real power) whenever the window misses a period
  boundary, even by a fraction of a sample; the projection does not;
* thrust per watt ``T / P`` and the thrust coefficient of Eq. (22),
  ``c_tau = T / ((1/2) rho_w w^2 |w(L)|^2 b L)`` with ``|w(L)| = |U_1| / w``;
* **self-sensed** tip velocity and thrust, from the drive alone: by Eq. (10) the motional
  current is ``i - C_eq dv/dt = theta deta/dt``, so ``U_k^self = (phi(L)/theta)(I_k - j k w C_eq V_k)``,
  with the capacitance, loss conductance, coupling and ``c_m`` of a :class:`~.selfsense.Calibration`
  when one is given (a loaded model's: ``thrust_estimator``'s ``model`` parameter).  A fish with no
  vibrometer and no load cell gets the same Lighthill thrust from this.  The fundamental
  admittance ``I_1 / V_1`` is reported too, so that a consumer can calibrate online;
* **load-cell** thrust as the paper measures it: mean deflection during the window minus the
  baseline (pre and post, each ``baseline_s`` long, with the drive off), times the transducer
  stiffness.  The baseline is the line through the two baselines' means, read at the window's mean
  time, so a linear drift cancels even though the window (after ``settle_s``) is not centred
  between them; the paper's plain average would leave ``drift x offset`` (2 nm/s x 1.5 s x
  6.8 kN/m = 20 uN on the simulated rig).  With the pre baseline only, its mean is used.

Windows
-------
A drive period runs between two upward zero crossings of the voltage (with hysteresis against
noise); where a DC offset holds the drive off zero (no crossing for 2.5 periods, or 2.5 s before the
first), between upward crossings of its middle, followed period by period until zero lies inside the
swing again; a crossing counts once the voltage has swung above and below the level since the last.
A middle that steps (by more than ``tolerance`` of a period's timing: an offset's step, not its
drift) ends the segment, and timing starts again at the new middle's first crossing.
Consecutive periods of the same length and amplitude (within ``tolerance``) form a
*segment* (a period that differs from the first one but not from the median of the last five
continues it, so a ramp's tail or a slow drift does not split a trial); a burst of the paper's
protocol is one segment, and so is steady continuous driving.
The first ``settle_s`` of a segment are skipped (the transient).  While a segment lasts, an
estimate is emitted every ``window_s`` of settled periods (``final = 0``); when it ends (the drive
stops or changes) one estimate over all its settled periods follows (``final = 1``), once the post
baseline of the load cell has been recorded.  A window's lock-in follows its periods as timed where
they slip from its mean frequency (:data:`PHASE_SLIP_RAD`).
"""

from __future__ import annotations

import bisect
import itertools
import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..config import setting
from ..errors import EstimationError
from ..physics.amplifier import PAPER_BENCH, WATT, Amplifier, watt_of
from ..physics.fin import MEDIA, Fin
from ..physics.swim import SPEED_MOST_M_S
from .selfsense import NOMINAL, Calibration, self_sensed_tip

FloatArray = NDArray[Any]


@dataclass(frozen=True)
class Estimate:
    """Estimates over one window ``[t_start, t_end)`` (s, ROS time of the samples).  SI units.

    NaN marks what the data cannot give (no vibrometer, no load-cell baseline, ...).
    """

    t_start: float
    t_end: float
    final: float  # 1: whole segment (trial); 0: running window
    n_periods: float
    frequency_hz: float
    voltage_pp: float  # V, 2 |V_1|
    current_rms: float  # A
    power_w: float  # W, mean(v i)
    tip_velocity_rms: float  # m/s, vibrometer
    thrust_n: float  # N, Lighthill (vibrometer)
    thrust_per_watt: float  # N/W (vibrometer)
    c_tau: float  # Eq. (22), from the Lighthill thrust
    tip_velocity_rms_self: float  # m/s, from the motional current
    thrust_self_n: float  # N, Lighthill from the motional current
    thrust_per_watt_self: float  # N/W
    thrust_loadcell_n: float  # N, load cell with the pre/post baseline
    loadcell_baselines: float  # 0, 1 (pre only) or 2 (pre and post)
    swim_speed_m_s: float  # U used in Eq. (19)
    tip_phase_rad: float = math.nan  # phase of the fundamental tip velocity relative to the voltage's
    admittance_re: float = math.nan  # S, the drive's fundamental I_1 / V_1: conductance
    admittance_im: float = math.nan  # S, and susceptance (what self-sensing is calibrated from)
    # the other watts (physics/amplifier.py, WATT): power_w above is the fin's, mean(v i)
    power_apparent_w: float = math.nan  # W, Vrms x Irms
    power_supply_w: float = math.nan  # W, the amplifier's draw through its model
    power_supply_measured_w: float = math.nan  # W, the supply topic's mean(V I), or the battery's draw
    # less its fixed draw (StreamEstimator.add_battery); NaN: neither measured
    thrust_per_watt_apparent: float = math.nan  # N/W, vibrometer thrust per apparent watt
    thrust_per_watt_supply: float = math.nan
    thrust_per_watt_supply_measured: float = math.nan
    thrust_per_watt_self_apparent: float = math.nan  # N/W, self-sensed thrust per apparent watt
    thrust_per_watt_self_supply: float = math.nan
    thrust_per_watt_self_supply_measured: float = math.nan

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))

    def power(self, watt: str) -> float:
        """The power in ``watt`` (``fin``, ``apparent``, ``supply``, ``supply_measured``: any of
        :data:`~piezofin_ros.physics.amplifier.WATT`), W."""
        return watt_of(watt).read(self.__dict__)

    def thrust_per(self, watt: str, source: str = "vibrometer") -> float:
        """Thrust per watt in ``watt``, of the ``vibrometer`` or the ``self``-sensed thrust (NaN where the
        data cannot give it)."""
        return per_watt_field(self.as_dict(), watt, source)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_dict(cls, record: dict[str, float]) -> Estimate:
        missing = [n for n in cls.field_names() if n not in record and n not in OPTIONAL_FIELDS]
        if missing:
            raise KeyError(f"estimate lacks field(s) {', '.join(missing)}")
        return cls(**{n: float(record.get(n, math.nan)) for n in cls.field_names()})


#: The most thrust any fin of this kind gives, N (a fin gives millinewtons).
THRUST_MOST_N = 10.0


def _most_of(name: str) -> float:
    """The largest magnitude field ``name`` of an estimate can have on any fin of this kind (generous)."""
    if name.startswith("thrust_per_watt"):
        return 1e3  # N/W (the paper: 0.06; the fin's own watt: a few)
    if name.startswith("thrust") and name.endswith("_n"):
        return THRUST_MOST_N
    if name.startswith("power"):
        return 1e4  # W
    if name.startswith("tip_velocity"):
        return 100.0  # m/s
    if name.startswith("admittance"):
        return 1.0  # S
    return {
        "current_rms": 1.0,
        "voltage_pp": 4000.0,
        "frequency_hz": 1e4,
        "swim_speed_m_s": SPEED_MOST_M_S,
        "c_tau": 1e3,
        "tip_phase_rad": 100.0,
        "final": 1.0,
        "loadcell_baselines": 2.0,
    }.get(name, 1e12)  # times, periods


def check_estimate(record: dict[str, float]) -> Estimate:
    """An estimate as another process sends it: every field present, and each finite (NaN: not
    estimated) and within what any fin of this kind can give; else :class:`EstimationError` naming
    the field (an estimate of 1e308 N must not steer a controller or a speed loop)."""
    try:
        e = Estimate.from_dict(record)
    except KeyError as exc:
        raise EstimationError(str(exc).strip("'\"")) from None
    for name, value in e.as_dict().items():
        if abs(value) > _most_of(name):  # (inf too; NaN passes: not estimated)
            raise EstimationError(
                f"{name} = {value!r} is beyond what any fin gives (within +-{_most_of(name):g})"
            )
    return e


#: Fields added after the first recordings: older bags lack them, and they read as NaN.
OPTIONAL_FIELDS = (
    "tip_phase_rad",
    "admittance_re",
    "admittance_im",
    *(f for f in Estimate.field_names() if f.startswith(("power_", "thrust_per_watt_")) and f != "power_w"),
)


@dataclass(frozen=True)
class Source:
    """Where a thrust estimate comes from, declared once (:data:`SOURCE`): its estimate field, how it
    is read, and the base name of its thrust-per-watt fields (``""``: none in an estimate)."""

    name: str
    what: str
    thrust_field: str
    #: from the drive's voltage and current alone (a fish: no vibrometer, no load cell)
    self_sensed: bool = False
    #: a load cell's reading (its gain is what a fit corrects), not Lighthill's on a tip velocity
    #: (whose ``c_m`` is)
    load_cell: bool = False
    per_watt: str = ""


#: The thrust sources, by name.
SOURCE: dict[str, Source] = {
    s.name: s
    for s in (
        Source(
            "vibrometer", "Lighthill on the vibrometer's tip velocity", "thrust_n", per_watt="thrust_per_watt"
        ),
        Source(
            "self",
            "Lighthill on the tip velocity sensed from the drive's own current",
            "thrust_self_n",
            self_sensed=True,
            per_watt="thrust_per_watt_self",
        ),
        Source(
            "loadcell", "the load cell's reading, its baselines removed", "thrust_loadcell_n", load_cell=True
        ),
    )
}
#: The sources an estimate has thrusts per watt of: name -> its thrust field.
THRUST_FIELDS = {name: s.thrust_field for name, s in SOURCE.items() if s.per_watt}


def source_of(name: str) -> Source:
    """The registry's source of that name (:class:`EstimationError` naming the others if none)."""
    try:
        return SOURCE[name]
    except KeyError:
        raise EstimationError(f"unknown thrust source {name!r}: one of {', '.join(SOURCE)}") from None


def tpw_field(watt: str, source: str = "vibrometer") -> str:
    """The estimate field of thrust per watt in ``watt`` for ``source`` (``thrust_per_watt`` is the
    vibrometer's in the fin's watt, for the bags recorded before the other watts)."""
    base = source_of(source).per_watt
    if not base:
        raise EstimationError(
            f"an estimate has no thrust per watt of the {source} (one of {', '.join(THRUST_FIELDS)})"
        )
    return base if watt_of(watt).is_fin else f"{base}_{watt}"


#: A watt below this share of the apparent watt (``v_rms i_rms``) is rounding, not a loss: no piezo's
#: loss tangent is within orders of it (an MFC's is about 0.01-0.05).  A thrust per such a watt is no
#: figure: a lossless drive's mean(v i) of 1e-20 W once gave a thrust per watt of 1e15 N/W
#: (``test_inbox.py``'s capacitive fin, its sign and size set by the samples' rounding).
ROUNDING_WATT = 1e-9


def per_watt_field(record: dict[str, float], watt: str, source: str = "vibrometer") -> float:
    """Thrust of ``source`` per ``watt`` from an estimate's fields: NaN where the watt is not positive
    beyond rounding (:data:`ROUNDING_WATT`) or the thrust is not finite."""
    thrust = record[source_of(source).thrust_field]
    power = watt_of(watt).read(record)
    apparent = record.get("power_apparent_w", math.nan)
    floor = ROUNDING_WATT * apparent if math.isfinite(apparent) and apparent > 0 else 0.0
    return thrust / power if power > floor and math.isfinite(thrust) else math.nan


def with_watts(record: dict[str, float]) -> dict[str, float]:
    """``record`` with every thrust per watt an estimate records filled from its thrusts and powers (a
    watt no estimate field records is read from the others when asked: ``Estimate.thrust_per``)."""
    for watt in (name for name, w in WATT.items() if w.field):
        for source in THRUST_FIELDS:
            record[tpw_field(watt, source)] = per_watt_field(record, watt, source)
    return record


@dataclass(frozen=True)
class EstimatorConfig:
    """Windowing and baseline settings (s, V)."""

    on_threshold_v: float = setting(10.0, "estimator: |v| above this means the drive is on, V", 0.01, 1000.0)
    off_hold_s: float = setting(
        0.5, "estimator: the drive is off after this long below the threshold, s", 0.01, 60.0
    )
    settle_s: float = setting(3.0, "estimator: transient skipped at the start of a segment, s", 0.0, 600.0)
    window_s: float = setting(
        5.0, "estimator: running estimates every this much settled time, s", 0.1, 3600.0
    )
    max_window_s: float = setting(
        60.0, "estimator: a final estimate uses at most the last this-much of its segment, s", 0.1, 3600.0
    )
    min_periods: int = setting(3, "estimator: fewest whole periods in a window", 1, 10000)
    tolerance: float = setting(
        0.03, "estimator: relative change of period or amplitude that starts a new segment", 1e-4, 0.5
    )
    baseline_s: float = setting(5.0, "estimator: load-cell pre/post baseline length, s", 0.1, 600.0)
    post_delay_s: float = setting(
        1.0, "estimator: wait after the drive stops before the post baseline, s", 0.0, 600.0
    )
    channel_timeout_s: float = setting(
        2.0, "estimator: how long (drive time) to wait for a lagging channel, s", 0.01, 600.0
    )
    harmonics: int = setting(3, "estimator: number of odd harmonics in the lock-in (1, 3, 5)", 1, 10)
    loadcell_stiffness_n_per_m: float = setting(
        6846.09375, "estimator: load cell stiffness, N/m (the paper's cantilever, 3 E I / l^3)", 1e-3, 1e9
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise EstimationError(f"estimator.{f.name} must be a finite number > 0, got {value!r}")


#: Points of the period the supply's watt is computed on (from the lock-in's harmonics).
PERIOD_POINTS = 256


def _lock_in(phase: FloatArray, orders: FloatArray, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The constant ``c`` of each column of ``x`` (a drive's offset, a leak's DC current) and its
    complex amplitudes ``X_k`` (``(len(orders), n_columns)``): ``x ~ c + sum_k Re(X_k e^{j k phase})``
    at each sample's ``phase`` (rad).

    Least squares on ``[1, cos, sin]``; over whole periods of uniform samples this is the
    Fourier projection (a lock-in), and it still works on a window that is a sample short.
    """
    ph = np.outer(phase, orders)
    basis = np.column_stack([np.ones_like(phase), np.cos(ph), np.sin(ph)])
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    m = len(orders)
    return coef[0], coef[1 : 1 + m] - 1j * coef[1 + m :]


def drive_phase(t: FloatArray, crossings: FloatArray) -> FloatArray:
    """The drive's phase at ``t`` (rad, 0 at ``crossings[0]``), ``2 pi`` more at each of its upward
    crossings: linear between them, and beyond them at the nearest period's rate."""
    c = np.asarray(crossings, dtype=float)
    k = np.interp(t, c, np.arange(c.size, dtype=float))
    k = np.where(t < c[0], (t - c[0]) / (c[1] - c[0]), k)
    k = np.where(t > c[-1], c.size - 1 + (t - c[-1]) / (c[-1] - c[-2]), k)
    return 2.0 * math.pi * k


#: The phase (rad) by which a window's timed periods may slip from its mean frequency before its
#: lock-in follows them.  Below it, the crossings' own errors may be most of the slip: a noisy
#: crossing's jitter is ``noise / amplitude`` (2.5 mrad for 1 V on 400 V), and a moving offset's
#: middle, a period behind, moves each crossing by up to ``pi`` times the yaw loop's period shift
#: (31-63 mrad); followed from 0.05-0.15 rad, the course's stranger 2 cost 0.8 % more energy per
#: metre.  A slip of ``s`` costs a fixed-frequency lock-in about ``s^2 / 6`` of the amplitude (1.5 %).
PHASE_SLIP_RAD = 0.3


def analyse_window(
    fin: Fin,
    t: ArrayLike,
    voltage: ArrayLike,
    current: ArrayLike,
    frequency_hz: float,
    *,
    tip_velocity: ArrayLike | None = None,
    tip_t: ArrayLike | None = None,
    swim_speed_m_s: float = 0.0,
    harmonics: int = 3,
    calibration: Calibration = NOMINAL,
    amplifier: Amplifier = PAPER_BENCH,
    crossings: ArrayLike | None = None,
) -> dict[str, float]:
    """Estimates over one window of drive samples that spans whole periods of ``frequency_hz``.

    ``crossings``, the drive's upward crossings that bound the window's periods (at least two), lock
    the harmonics to the periods as timed (:func:`drive_phase`) where they slip from
    ``frequency_hz`` by more than :data:`PHASE_SLIP_RAD`: a drive whose frequency moved within the
    window by less than the estimator's tolerance (a controller's step of 2 %, held 42 s: 5 periods
    of phase slip) read 84 Vpp for 446.

    ``tip_velocity`` may have its own sample times ``tip_t`` (default: ``t``).  Returns the
    fields of :class:`Estimate` that a window determines (not the window bookkeeping or the
    load cell).  ``calibration`` corrects the self-sensing and ``c_m`` (:mod:`.selfsense`);
    ``amplifier`` gives the supply's watt (its law on the lock-in's period of ``v`` and ``i``).
    """
    t = np.asarray(t, dtype=float)
    v = np.asarray(voltage, dtype=float)
    i = np.asarray(current, dtype=float)
    if t.size < 4 or t.shape != v.shape or t.shape != i.shape:
        raise EstimationError(
            "a window needs at least 4 drive samples, with t, voltage and current of equal length"
        )
    w = 2.0 * math.pi * frequency_hz
    orders = np.arange(1, 2 * harmonics, 2, dtype=float)
    cross = None if crossings is None else np.asarray(crossings, dtype=float)
    if cross is not None and (
        cross.size < 2 or np.any(np.diff(cross) <= 0) or not np.all(np.isfinite(cross))
    ):
        raise EstimationError("crossings must be at least two finite times, increasing")

    if cross is not None:  # (the periods as timed, where they slipped from the mean frequency)
        slip = w * (cross - cross[0]) - 2.0 * math.pi * np.arange(cross.size)
        cross = cross if float(np.max(np.abs(slip))) > PHASE_SLIP_RAD else None

    def phase(times: FloatArray) -> FloatArray:
        return w * (times - t[0]) if cross is None else drive_phase(times, cross)

    (v0, _), harmonics_vi = _lock_in(phase(t), orders, np.column_stack([v, i]))
    V, I_ = harmonics_vi.T
    # Parseval: mean(v i) over a period, of the sine's harmonics.  A drive's offset V0 times the
    # current's DC is left out: a current monitor's offset (microamperes) times hundreds of volts
    # would swamp the fin's tens of microwatts (measured: +-30 nA of noise at 800 V, +-30 %), and an
    # MFC at DC draws nanoamperes.
    power = float(0.5 * np.sum(np.real(V * np.conj(I_))))
    v_rms, i_rms = (float(np.sqrt(np.sum(np.abs(X) ** 2) / 2.0)) for X in (V, I_))  # (of the sine)
    phases = np.outer(np.arange(PERIOD_POINTS) * 2 * math.pi / PERIOD_POINTS, orders)
    # one period of v and i, rebuilt, the voltage on its offset: an amplifier's draw follows it whole
    period = np.array([v0, 0.0]) + np.real(np.exp(1j * phases) @ np.column_stack([V, I_]))
    supply = amplifier.mean_draw(period[:, 0], period[:, 1])
    slope_ratio = fin.phi_tip_slope / fin.phi_tip
    U2 = swim_speed_m_s**2

    def lighthill(Uk: FloatArray) -> tuple[float, float, float]:
        ms_u = float(np.sum(np.abs(Uk) ** 2) / 2.0)
        ms_w = float(np.sum(np.abs(Uk) ** 2 / (2.0 * (orders * w) ** 2)))
        amp_w1 = abs(Uk[0]) / w
        mass = float(calibration.mass_at(fin, amp_w1))  # (the fundamental's amplitude sets KC)
        thrust = 0.5 * fin.m_v * mass * (ms_u - U2 * slope_ratio**2 * ms_w)
        denom = 0.5 * fin.rho_w * w**2 * amp_w1**2 * fin.b * fin.L
        c_tau = thrust / denom if denom > 0 else math.nan
        return math.sqrt(ms_u), thrust, c_tau

    u_self, thrust_self, _ = lighthill(self_sensed_tip(fin, I_, V, orders * w, calibration))
    admittance = I_[0] / V[0] if abs(V[0]) > 0 else complex(math.nan, math.nan)
    out = {
        "frequency_hz": frequency_hz,
        "voltage_pp": 2.0 * float(abs(V[0])),
        "current_rms": i_rms,  # the lock-in's harmonics
        "power_w": power,
        "power_apparent_w": v_rms * i_rms,
        "power_supply_w": supply,
        "tip_velocity_rms": math.nan,
        "thrust_n": math.nan,
        "thrust_per_watt": math.nan,
        "c_tau": math.nan,
        "tip_velocity_rms_self": u_self,
        "thrust_self_n": thrust_self,
        "thrust_per_watt_self": math.nan,  # (every thrust per watt: with_watts, below)
        "swim_speed_m_s": swim_speed_m_s,
        "tip_phase_rad": math.nan,
        "admittance_re": float(admittance.real),
        "admittance_im": float(admittance.imag),
    }
    if tip_velocity is not None:
        tu = t if tip_t is None else np.asarray(tip_t, dtype=float)
        u = np.asarray(tip_velocity, dtype=float)
        ok = np.isfinite(u)
        if np.count_nonzero(ok) >= 2 * len(orders) + 1:
            Uk = _lock_in(phase(tu[ok]), orders, u[ok])[1]
            u_rms, thrust, c_tau = lighthill(Uk)
            out.update(
                tip_velocity_rms=u_rms,
                thrust_n=thrust,
                c_tau=c_tau,
                tip_phase_rad=float(np.angle(Uk[0] / V[0])) if abs(V[0]) > 0 else math.nan,
            )
    return with_watts(out)


def _bounds(periods: list[tuple[float, float, float]]) -> tuple[float, ...]:
    """The crossings that bound ``periods`` ((t0, t1, vpp) each); none where they are not contiguous
    (the window is then locked to its mean frequency)."""
    if any(a != b for (_, a, _), (b, _, _) in itertools.pairwise(periods)):
        return ()
    return (periods[0][0], *(b for _, b, _ in periods))


def _upward_crossings(v: FloatArray, since: int) -> list[int]:
    """The indices ``k > since`` where ``v`` crosses zero upward (``v[k-1] < 0 <= v[k]``)."""
    return (np.flatnonzero((v[since:-1] < 0) & (v[since + 1 :] >= 0)) + since + 1).tolist()


def _baseline_at(baselines: list[tuple[float, float]], t: float) -> float:
    """The load cell's zero at time ``t`` from (mean time, mean deflection) of its baselines:
    the line through two of them (a linear drift cancels), or the value of one."""
    if len(baselines) == 1 or baselines[-1][0] <= baselines[0][0]:
        return float(np.mean([x for _, x in baselines]))
    (t0, x0), (t1, x1) = baselines[0], baselines[-1]
    return x0 + (x1 - x0) * (t - t0) / (t1 - t0)


#: A new period is compared with the median of this many previous periods of its segment.
REFERENCE_PERIODS = 5
#: battery readings kept ahead of the drive data (a minute at 10 Hz)
_UNPLACED_MOST = 600


class _Channel:
    """Time-ordered samples of one topic (columns share the times), pruned from the front."""

    def __init__(self) -> None:
        self._t: deque[FloatArray] = deque()
        self._x: deque[FloatArray] = deque()
        self.latest = -math.inf
        self.seen = False
        self.dropped = 0  # samples at or before the latest time (duplicates, out of order)

    def append(self, t: FloatArray, x: FloatArray) -> None:
        self.seen = True
        keep = t > self.latest
        if not np.all(keep):
            self.dropped += int(np.count_nonzero(~keep))
            t, x = t[keep], x[keep]
        if t.size:
            self._t.append(t)
            self._x.append(x)
            self.latest = float(t[-1])

    def slice(self, t0: float, t1: float) -> tuple[FloatArray, FloatArray]:
        ts, xs = [], []
        for t, x in zip(self._t, self._x, strict=True):
            if t[-1] < t0 or t[0] >= t1:
                continue
            sel = (t >= t0) & (t < t1)
            ts.append(t[sel])
            xs.append(x[sel])
        if not ts:
            return np.empty(0), np.empty((0, *self._x[0].shape[1:]) if self._x else (0,))
        return np.concatenate(ts), np.concatenate(xs)

    def prune(self, before: float) -> None:
        while self._t and self._t[0][-1] < before:
            self._t.popleft()
            self._x.popleft()


@dataclass
class _Pending:
    t_start: float
    t_end: float
    n_periods: int
    final: bool
    pre: tuple[float, float] | None  # load-cell pre-baseline window (the drive off before it), if any
    post: tuple[float, float] | None = None
    post_open: bool = False  # the post baseline may still be cut short by a restart
    await_off: bool = False  # ended by a change: a stop that follows soon still gives a post baseline
    crossings: tuple[float, ...] = ()  # the drive's upward crossings that bound its periods


@dataclass
class _Segment:
    pre: tuple[float, float] | None  # load-cell pre-baseline window (the drive off before it), if any
    periods: list[tuple[float, float, float]] = field(default_factory=list)  # (t0, t1, vpp)
    next_window: int = 0  # index of the first period of the next running window


#: The calibrations kept that wait for their time (``StreamEstimator.calibrate_from``).
_LATER_MOST = 16


class StreamEstimator:
    """Incremental estimator: feed blocks with ``add_*``; each call returns new estimates.

    All times are the samples' own (ROS clock) times, so live data and a replayed bag give the
    same estimates.  ``fin`` supplies ``m_v``, ``C_eq``, ``theta`` and ``phi(L)``.
    """

    def __init__(
        self,
        fin: Fin,
        config: EstimatorConfig | None = None,
        calibrate: Callable[[float, float], Calibration] | None = None,
        amplifier: Amplifier = PAPER_BENCH,
        medium: str = "water",
        fixed_draw_w: float | None = None,
    ) -> None:
        if fixed_draw_w is not None and not (math.isfinite(fixed_draw_w) and fixed_draw_w >= 0):
            raise EstimationError(f"fixed_draw_w must be a finite number >= 0 W, got {fixed_draw_w!r}")
        if medium not in MEDIA:
            raise EstimationError(f"medium must be one of {', '.join(MEDIA)}, got {medium!r}")
        self.medium = medium  # in air there is no fluid to push: no thrust is estimated
        self.fin = fin
        self.config = config or EstimatorConfig()
        self.calibrate = calibrate  # (frequency Hz, Vpp) -> the self-sensing's calibration there
        # (calibrate_from) (fin time from, arrival, calibration), by time: at most _LATER_MOST
        self._later: list[tuple[float, int, Callable[[float, float], Calibration]]] = []
        self._arrivals = 0
        self.amplifier = amplifier
        self.drive = _Channel()
        self.tip = _Channel()
        self.loadcell = _Channel()
        self.supply = _Channel()  # the supply's meter (voltage, current), where the rig has one
        self.battery = _Channel()  # the fish's battery (terminal voltage, current), where it has one
        self.fixed_draw_w = fixed_draw_w  # what the battery feeds besides the fin's drive (None: learnt)
        self._idle_draws: deque[float] = deque(maxlen=60)  # the battery's draw with the drive off, W
        # battery readings newer than the drive data, by time: placed (off or on) once the drive
        # reaches them (at most _UNPLACED_MOST: a clock far ahead cannot grow it)
        self._unplaced: list[tuple[float, float]] = []
        self._speed: deque[tuple[float, float]] = deque(maxlen=10_000)
        self._on = False
        self._last_above = -math.inf
        self._off_since = -math.inf  # time since which the drive has been off and settled
        self._first_t = math.nan
        self._prev = (math.nan, math.nan)  # last drive sample (t, v)
        self._vmin = math.inf
        self._vmax = -math.inf
        self._mid = 0.0  # V, the drive's middle (its offset): the last period's, or the last MID_S's
        self._mid_since = math.nan  # when the swing _vmin.._vmax began to be gathered
        self._mid_old = 0.0
        self._period_s = math.nan  # the last period's length, s (how long a crossing may be awaited)
        self._moments = [0.0, 0.0, 0.0]  # the period so far: count, sum, sum of squares (relative to _mid)
        self._last_cross = math.nan
        self._partial = False  # (the next crossing is a new middle's first: _restart_timing)
        self._segment: _Segment | None = None
        self._pending: list[_Pending] = []
        self._last_final: _Pending | None = None  # ended by a change, may still get a post baseline

    # ----------------------------------------------------------------------------- inputs
    def add_drive(self, t: ArrayLike, voltage: ArrayLike, current: ArrayLike) -> list[Estimate]:
        t = np.asarray(t, dtype=float)
        v = np.asarray(voltage, dtype=float)
        i = np.asarray(current, dtype=float)
        if t.size == 0:
            return []
        keep = t > self.drive.latest
        t, v, i = t[keep], v[keep], i[keep]
        if t.size == 0:
            return []
        if math.isnan(self._first_t):
            self._first_t = float(t[0])
            self._off_since = float(t[0])
        self.drive.append(t, np.column_stack([v, i]))
        self._segment_drive(t, np.nan_to_num(v))
        self._place_battery(self.drive.latest)
        self._prune()
        return self._finish_ready()

    def add_tip(self, t: ArrayLike, tip_velocity: ArrayLike) -> list[Estimate]:
        self.tip.append(np.asarray(t, dtype=float), np.asarray(tip_velocity, dtype=float))
        return self._finish_ready()

    def add_loadcell(self, t: ArrayLike, displacement: ArrayLike) -> list[Estimate]:
        self.loadcell.append(np.asarray(t, dtype=float), np.asarray(displacement, dtype=float))
        return self._finish_ready()

    def add_supply(self, t: ArrayLike, voltage: ArrayLike, current: ArrayLike) -> list[Estimate]:
        """The supply bus: its voltage (V) and current (A) as the rig's meter reads them."""
        v, i = np.asarray(voltage, dtype=float), np.asarray(current, dtype=float)
        self.supply.append(np.asarray(t, dtype=float), np.column_stack([v, i]))
        return self._finish_ready()

    def add_battery(self, t: float, voltage: float, current: float) -> list[Estimate]:
        """A reading of the fish's battery: its terminal voltage (V) and current (A; either sign, as
        ``sensor_msgs/BatteryState`` counts a discharge negative).

        Where no supply meter is read, the supply watt is measured here: the battery's draw over the
        window less its fixed draw (what it feeds besides the fin's amplifier: the fish's
        electronics).  That fixed draw is ``fixed_draw_w`` where it is given, else learnt as the
        median draw while the drive is off (two readings at least) less the amplifier model's own
        draw at 0 V, which the supply watt counts; until it is known, no supply watt is measured
        from the battery.
        """
        draw = abs(float(voltage) * float(current))
        if not (math.isfinite(t) and math.isfinite(draw)):
            return []
        bisect.insort(self._unplaced, (float(t), draw))
        del self._unplaced[: max(0, len(self._unplaced) - _UNPLACED_MOST)]
        self._place_battery(self.drive.latest)
        self.battery.append(np.array([float(t)]), np.array([[float(voltage), float(current)]]))
        return self._finish_ready()

    def _place_battery(self, until: float) -> None:
        """The battery readings up to ``until`` (drive data reaches them, the drive still off since
        ``_off_since``): those while the drive was off are idle draws, the others are passed over."""
        k = bisect.bisect_right(self._unplaced, (until, math.inf))
        if not self._on:
            self._idle_draws.extend(draw for t, draw in self._unplaced[:k] if self._off_since <= t)
        del self._unplaced[:k]

    @property
    def battery_fixed_draw_w(self) -> float:
        """The fixed draw the battery's watt is measured above, W (NaN: not known yet)."""
        if self.fixed_draw_w is not None:
            return self.fixed_draw_w
        if len(self._idle_draws) < 2:
            return math.nan
        idle = self.amplifier.mean_draw(np.zeros(2), np.zeros(2))  # (the model's, at 0 V)
        return max(float(np.median(self._idle_draws)) - idle, 0.0)

    @property
    def supply_meter(self) -> str:
        """Where the supply watt is measured: ``supply`` (its meter), ``battery``, or ``""`` (none: the
        amplifier's model alone)."""
        if self.supply.seen:
            return "supply"
        return "battery" if self.battery.seen and math.isfinite(self.battery_fixed_draw_w) else ""

    def add_speed(self, t: float, speed_m_s: float) -> None:
        """Swimming speed ``U`` (m/s) from the fish stack, applied in Eq. (19); a time that is not
        finite is ignored, a speed beyond :data:`~piezofin_ros.physics.swim.SPEED_MOST_M_S` (or not
        finite) refused with :class:`EstimationError`."""
        if not (math.isfinite(speed_m_s) and abs(speed_m_s) <= SPEED_MOST_M_S):
            raise EstimationError(
                f"a swimming speed of {speed_m_s!r} m/s is no fish's (within +-{SPEED_MOST_M_S:g})"
            )
        if math.isfinite(t):
            self._speed.append((t, speed_m_s))

    def flush(self) -> list[Estimate]:
        """End of data: close the open segment and emit everything pending with what is there."""
        if self._segment is not None:
            self._end_segment(self.drive.latest, by_off=False)
        for p in self._pending:
            p.await_off = p.post_open = False
        out = [self._compute(p) for p in self._pending]
        self._pending = []
        return [e for e in out if e is not None]

    # ------------------------------------------------------------------------ segmentation
    def _segment_drive(self, t: FloatArray, v: FloatArray) -> None:
        cfg = self.config
        above = np.abs(v) > cfg.on_threshold_v
        if np.any(above):
            first_above = float(t[np.argmax(above)])
            if not self._on:
                self._place_battery(first_above - 0.1)  # (the readings before: taken with it off)
                self._on = True
                self._mid_since = first_above  # (a middle is looked for from here)
                self._on_event(first_above)
            self._last_above = float(t[len(above) - 1 - np.argmax(above[::-1])])
        # Upward zero crossings with hysteresis (v must have gone above h and below -h since the last
        # one: a middle moved just after a crossing does not time a second one at once); of
        # the drive's middle where an offset holds it off zero (``_mid``, :meth:`_new_middle`).
        h = 0.5 * cfg.on_threshold_v
        t_prev, v_prev = self._prev
        tt = np.concatenate([[t_prev], t]) if math.isfinite(t_prev) else t
        vv = (np.concatenate([[v_prev], v]) if math.isfinite(t_prev) else v) - self._mid
        if not math.isfinite(self._mid_since):
            self._mid_since = float(tt[0])
        start, cand, i = 0, _upward_crossings(vv, 0), 0
        while i < len(cand):
            k, i = cand[i], i + 1
            seg = vv[start:k]
            if seg.size:
                self._vmin = min(self._vmin, float(seg.min()))
                self._vmax = max(self._vmax, float(seg.max()))
                self._gather(seg)
            start = k
            if self._vmin >= -h or self._vmax <= h:  # (a crossing ends a swing above and below)
                continue
            tc = float(tt[k - 1] - vv[k - 1] * (tt[k] - tt[k - 1]) / (vv[k] - vv[k - 1]))
            swing = self._swing()
            if self._partial:  # (a new middle's first crossing: from the move to it is no period)
                self._partial = False
            elif math.isfinite(self._last_cross) and self._on:
                self._period_s = tc - self._last_cross
                self._on_period(self._last_cross, tc, swing)
            if self._mid != 0.0:  # (offset: the middle followed period by period)
                self._new_middle(tc)
                shift = self._mid - self._mid_old
                if shift != 0.0:  # (the crossings after k: of the new middle)
                    vv -= shift
                    cand, i = _upward_crossings(vv, k), 0
                    self._restart_timing(shift, swing)
            self._last_cross = math.nan if self._partial else tc
            self._vmin, self._vmax = math.inf, -math.inf
            self._moments = [0.0, 0.0, 0.0]
            self._mid_since = tc
        rest = vv[start:]
        if rest.size:
            self._vmin = min(self._vmin, float(rest.min()))
            self._vmax = max(self._vmax, float(rest.max()))
            self._gather(rest)
        # (no crossing for 2.5 periods of the last, or MID_S before the first, and the swing since
        # not across the middle: the level left the swing; a swing across it will cross it)
        wait = min(self.MID_S, 2.5 * self._period_s) if math.isfinite(self._period_s) else self.MID_S
        across = self._vmin < -h and self._vmax > h
        if (
            self._on
            and float(tt[-1]) - self._mid_since > wait
            and self._vmax - self._vmin > 2.0 * h
            and not across
        ):
            swing = self._vmax - self._vmin
            self._new_middle(float(tt[-1]))  # (no crossing while on: a drive held off zero)
            self._restart_timing(self._mid - self._mid_old, swing)
        self._prev = (float(t[-1]), float(v[-1]))
        if self._on and float(t[-1]) - self._last_above > cfg.off_hold_s:
            self._on, self._partial = False, False
            self._last_cross = math.nan
            self._mid, self._period_s = 0.0, math.nan
            if self._segment is not None:
                self._end_segment(self._last_above, by_off=True)
            self._off_since = self._last_above + cfg.post_delay_s

    #: Where no crossing of the middle came for this long before a first period (s; beyond the
    #: slowest period of the drive's band, 2 s), or 2.5 periods after one, the middle is taken from
    #: the swing seen since.
    MID_S = 2.5

    def _gather(self, v: FloatArray) -> None:
        """A period's samples so far: their count, sum and sum of squares (its swing, :meth:`_swing`)."""
        m = self._moments
        m[0] += v.size
        m[1] += float(np.sum(v))
        m[2] += float(np.sum(v * v))

    def _swing(self) -> float:
        """The period's peak-to-peak voltage, as a sine's: ``2 sqrt(2)`` times its samples' standard
        deviation (their max less their min where it has too few).  An offset that moves by ``d``
        over the period adds ``d^2 / 12`` to the variance, not ``d`` to the swing: a yaw loop's
        offset, moving tens of volts a period, splits no segment (max less min, it split every one
        and no estimate came for 20 s)."""
        n, total, squares = self._moments
        if n < 8:
            return self._vmax - self._vmin
        var = max(squares / n - (total / n) ** 2, 0.0)
        return 2.0 * math.sqrt(2.0 * var)

    def _new_middle(self, t: float) -> None:
        """Take the middle of the swing gathered since ``_mid_since`` (relative to the old middle) as
        the level whose crossings time the periods from ``t`` on, zero again once zero lies well
        inside the swing (its middle half); and start gathering again."""
        self._mid_old = self._mid
        if math.isfinite(self._vmin) and math.isfinite(self._vmax):
            low, high = self._mid + self._vmin, self._mid + self._vmax
            mid = 0.5 * (low + high)
            self._mid = 0.0 if abs(mid) < 0.25 * (high - low) else mid
        self._vmin, self._vmax = math.inf, -math.inf
        self._moments = [0.0, 0.0, 0.0]
        self._mid_since = t

    def _restart_timing(self, shift: float, swing: float) -> None:
        """After the middle moved by ``shift`` (V) on a sine of ``swing`` (V peak-to-peak): where that
        moves a crossing by more than the tolerance of a period (``shift / (pi swing)``: a step of
        the offset, not the drift a yaw loop gives it; a period so far off would split the segment
        anyway), no period is timed across the move.  The segment ends, and timing starts again at
        the new middle's first crossing (whose swing, above and below it, sets the middle again).
        Timing across a step once gave a period of 26 ms, whose swing set a wrong middle, and the
        next; no estimate came while the offset stayed."""
        if abs(shift) <= self.config.tolerance * math.pi * swing:
            return
        self._partial, self._last_cross, self._period_s = True, math.nan, math.nan
        if self._segment is not None:
            pre = self._segment.pre if not self._segment.periods else None
            self._end_segment(self._mid_since, by_off=False)
            self._segment = _Segment(pre)

    def _on_event(self, t_on: float) -> None:
        cfg = self.config
        guard = 0.1
        for p in self._pending:  # a restart cuts the post baseline of earlier trials short
            if p.post is not None and p.post_open and p.post[1] > t_on - guard:
                p.post = (p.post[0], t_on - guard) if t_on - guard - p.post[0] >= 1.0 else None
                p.post_open = False
            p.await_off = False
        self._last_final = None
        pre = (t_on - guard - cfg.baseline_s, t_on - guard)
        ok = self._off_since <= pre[0] and self._first_t <= pre[0]
        self._segment = _Segment(pre if ok else None)
        self._last_cross = math.nan

    def _on_period(self, t0: float, t1: float, vpp: float) -> None:
        cfg = self.config
        seg = self._segment
        if seg is None:
            return
        # The drive changed if a period differs from the segment's first period and from the
        # median of its last few: a segment whose first period was the tail of a ramp, or whose
        # amplitude wanders slowly (an amplifier's sag, warming), is not split in two; a step or
        # a ramp of the drive still splits it.
        if (
            seg.periods
            and self._changed(seg.periods[:1], t1 - t0, vpp)
            and self._changed(seg.periods[-REFERENCE_PERIODS:], t1 - t0, vpp)
        ):
            # A segment still in its transient (a ramp) hands its pre baseline on; the next
            # settled segment is the same trial.
            transient = seg.periods[-1][1] - seg.periods[0][0] < cfg.settle_s
            self._end_segment(t0, by_off=False)
            seg = self._segment = _Segment(seg.pre if transient else None)
        seg.periods.append((t0, t1, vpp))
        settled = [p for p in seg.periods[seg.next_window :] if p[0] >= seg.periods[0][0] + cfg.settle_s]
        if settled and self._last_final is not None:
            self._last_final.await_off = False  # the drive settled elsewhere: no post baseline
            self._last_final = None
        if settled and settled[-1][1] - settled[0][0] >= cfg.window_s and len(settled) >= cfg.min_periods:
            self._pending.append(
                _Pending(
                    settled[0][0],
                    settled[-1][1],
                    len(settled),
                    final=False,
                    pre=seg.pre,
                    crossings=_bounds(settled),
                )
            )
            seg.next_window = len(seg.periods)

    def _changed(self, reference: list[tuple[float, float, float]], period: float, vpp: float) -> bool:
        """A period differs from the median of ``reference`` periods by more than ``tolerance``."""
        tol = self.config.tolerance
        ref = float(np.median([b - a for a, b, _ in reference]))
        rv = float(np.median([x for _, _, x in reference]))
        return abs(period - ref) > tol * ref or abs(vpp - rv) > tol * rv + 2.0

    def _end_segment(self, t_off: float, *, by_off: bool) -> None:
        cfg = self.config
        seg, self._segment = self._segment, None
        post = (t_off + cfg.post_delay_s, t_off + cfg.post_delay_s + cfg.baseline_s) if by_off else None
        periods = seg.periods if seg is not None else []
        settled = []
        if periods:
            t_settled = periods[0][0] + cfg.settle_s
            settled = [p for p in periods if p[0] >= t_settled and p[1] >= periods[-1][1] - cfg.max_window_s]
        if len(settled) < cfg.min_periods:
            last = self._last_final
            if by_off and last is not None and last.await_off:
                last.post, last.post_open, last.await_off = post, True, False  # ramp-down ended the trial
                self._last_final = None
            return
        pending = _Pending(
            settled[0][0],
            settled[-1][1],
            len(settled),
            final=True,
            pre=seg.pre if seg is not None else None,
            post=post,
            post_open=post is not None,
            await_off=not by_off,
            crossings=_bounds(settled),
        )
        self._pending.append(pending)
        if self._last_final is not None:
            self._last_final.await_off = False
        self._last_final = None if by_off else pending

    # ------------------------------------------------------------------------- estimation
    def _ready(self, p: _Pending) -> bool:
        if p.await_off:
            return False
        now = self.drive.latest
        timeout = self.config.channel_timeout_s
        for lagging in (self.tip, self.supply, self.battery):
            if lagging.seen and lagging.latest < p.t_end and now < p.t_end + timeout:
                return False
        need = p.post[1] if p.post is not None else p.t_end
        if p.post is not None and p.post_open and now < need:
            return False  # the drive may still restart and cut the baseline short
        return not (self.loadcell.seen and self.loadcell.latest < need and now < need + timeout)

    def _finish_ready(self) -> list[Estimate]:
        out, keep = [], []
        for p in self._pending:
            if self._ready(p):
                e = self._compute(p)
                if e is not None:
                    out.append(e)
            else:
                keep.append(p)
        self._pending = keep
        return out

    def _speed_at(self, t0: float, t1: float) -> float:
        inside = [u for (t, u) in self._speed if t0 <= t < t1]
        if inside:
            return float(np.mean(inside))
        before = [u for (t, u) in self._speed if t < t1]
        return before[-1] if before else 0.0

    def calibrate_from(self, t_s: float, calibrate: Callable[[float, float], Calibration]) -> None:
        """The self-sensing's calibration for the windows that start at ``t_s`` (fin time) or later: a
        live run and its replay, however late the calibration reaches each, estimate alike.  At most
        ``_LATER_MOST`` are kept, the earliest sent let go first (a segment's last window starts
        where the segment settled, before windows already estimated, so none is let go by time): a
        stream of them, each from a time of its own, cannot grow the estimator."""
        self._arrivals += 1
        later = [*self._later, (float(t_s), self._arrivals, calibrate)]
        if len(later) > _LATER_MOST:
            later.remove(min(later, key=lambda c: c[1]))
        self._later = sorted(later, key=lambda c: c[0])

    def _calibration_at(self, t_start: float) -> Callable[[float, float], Calibration] | None:
        """The calibration of a window that starts at ``t_start``."""
        later = [c for t, _, c in self._later if t <= t_start]
        return later[-1] if later else self.calibrate

    def _compute(self, p: _Pending) -> Estimate | None:
        t, vi = self.drive.slice(p.t_start, p.t_end)
        if t.size < 4:
            return None
        freq = p.n_periods / (p.t_end - p.t_start)
        tt, u = self.tip.slice(p.t_start, p.t_end)
        speed = self._speed_at(p.t_start, p.t_end)
        cal = NOMINAL  # (a calibration's field: the window's peak-to-peak drive)
        calibrate = self._calibration_at(p.t_start)
        if calibrate is not None:
            cal = calibrate(freq, float(np.ptp(vi[:, 0])))
        r = analyse_window(
            self.fin,
            t,
            vi[:, 0],
            vi[:, 1],
            freq,
            tip_velocity=u if tt.size else None,
            tip_t=tt if tt.size else None,
            swim_speed_m_s=speed,
            harmonics=self.config.harmonics,
            calibration=cal,
            amplifier=self.amplifier,
            crossings=p.crossings or None,
        )
        if self.medium == "air":  # Lighthill's thrust needs a fluid: in air it means nothing
            r.update(dict.fromkeys(("thrust_n", "thrust_self_n", "c_tau"), math.nan))
            r = with_watts(r)
        ts, vi_s = self.supply.slice(p.t_start, p.t_end)
        ok = np.all(np.isfinite(vi_s), axis=1) if ts.size else np.zeros(0, bool)
        if np.count_nonzero(ok) >= 4:
            r["power_supply_measured_w"] = float(np.mean(vi_s[ok, 0] * vi_s[ok, 1]))
            r = with_watts(r)
        elif self.supply_meter == "battery":
            tb, vi_b = self.battery.slice(p.t_start, p.t_end)
            if tb.size:  # (readings of 1 Hz: the window's own, however few)
                draw = float(np.mean(np.abs(vi_b[:, 0] * vi_b[:, 1])))
                r["power_supply_measured_w"] = max(draw - self.battery_fixed_draw_w, 0.0)
                r = with_watts(r)
        thrust_lc, n_base = math.nan, 0
        baselines: list[tuple[float, float]] = []  # (mean time, mean deflection)
        for win in (p.pre, p.post):
            if win is None:
                continue
            tb, x = self.loadcell.slice(*win)
            ok = np.isfinite(x)
            if np.count_nonzero(ok) >= 10:
                baselines.append((float(np.mean(tb[ok])), float(np.mean(x[ok]))))
        t_on, x_on = self.loadcell.slice(p.t_start, p.t_end)
        ok = np.isfinite(x_on)
        if baselines and np.count_nonzero(ok) >= 10:
            n_base = len(baselines)
            base = _baseline_at(baselines, float(np.mean(t_on[ok])))
            thrust_lc = (float(np.mean(x_on[ok])) - base) * self.config.loadcell_stiffness_n_per_m
        return Estimate(
            t_start=p.t_start,
            t_end=p.t_end,
            final=1.0 if p.final else 0.0,
            n_periods=float(p.n_periods),
            thrust_loadcell_n=thrust_lc,
            loadcell_baselines=float(n_base),
            **r,
        )

    def _prune(self) -> None:
        cfg = self.config
        horizon = (
            cfg.max_window_s + cfg.settle_s + 2 * cfg.baseline_s + cfg.post_delay_s + cfg.channel_timeout_s
        )
        oldest = self.drive.latest - horizon - 5.0
        for p in self._pending:
            oldest = min(oldest, p.pre[0] if p.pre else p.t_start)
        for ch in (self.drive, self.tip, self.loadcell, self.supply, self.battery):
            ch.prune(oldest)
