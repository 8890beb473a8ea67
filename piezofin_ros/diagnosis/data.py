"""Measured trials as the diagnosis sees them: one row per operating point, with uncertainties.

A :class:`Trials` table comes from a bag (the estimator run offline over the suite's topics,
:func:`from_bags`), from a CSV of per-trial summaries (published data without time series,
:func:`from_csv`), or from the synthetic generator.  Channels a source lacks are NaN
(a CSV has no phase; a fish has no vibrometer and no load cell).

Uncertainties (1 sigma) follow from the measurement noise.  For a bag they are measured on the
bag itself, in the windows where the drive is off: the standard deviation ``s`` of each signal
there, propagated through the lock-in of a window of ``N`` samples (``s sqrt(2/N)`` per phasor
component) and through the load-cell baseline subtraction.  A relative floor (``model_floor``,
default 1 %) covers what the noise does not: the single-harmonic model, window edges.
"""

from __future__ import annotations

import csv
import itertools
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..bags.blocks import (
    COMMAND_FIELDS,
)
from ..bags.fin import TOPIC_CMD, TOPIC_DRIVE, TOPIC_LOADCELL, TOPIC_TIP, FinMessage, read_fin, topic_prefix
from ..errors import DiagnosisError
from ..estimation.estimator import Estimate, EstimatorConfig
from ..estimation.offline import Replayer
from ..identification.signs import Signs
from ..physics.amplifier import PAPER_BENCH, Amplifier
from ..physics.fin import Fin

FloatArray = NDArray[Any]

#: Measured channels the diagnosis compares with the model, with their unit and scale for display.
CHANNELS: dict[str, tuple[str, float, str]] = {
    "voltage_pp_drive": ("V", 1.0, "drive voltage"),
    "tip_velocity_rms": ("mm/s", 1e3, "RMS tip velocity"),
    "tip_phase_rad": ("deg", 180 / math.pi, "tip-velocity phase"),
    "current_rms": ("uA", 1e6, "RMS current"),
    "power_w": ("mW", 1e3, "mean power"),
    "thrust_loadcell_n": ("mN", 1e3, "load-cell thrust"),
}

CSV_COLUMNS = {
    "frequency_hz": ("frequency_hz", "f_hz", "frequency"),
    "voltage_pp": ("voltage_pp", "vpp", "voltage_pp_v"),
    "tip_velocity_rms": ("tip_velocity_rms", "tip_velocity_rms_m_s", "u_rms"),
    "current_rms": ("current_rms", "current_rms_a", "i_rms"),
    "power_w": ("power_w", "mean_power_w", "power"),
    "thrust_loadcell_n": ("thrust_n", "mean_thrust_n", "thrust_loadcell_n", "thrust"),
    "tip_phase_rad": ("tip_phase_rad",),
    "voltage_pp_drive": ("voltage_pp_drive",),
}


class DataError(DiagnosisError):
    """Input data that cannot be diagnosed; the message names the file and the problem."""


@dataclass(frozen=True)
class Trials:
    """Per-trial measurements (arrays of equal length; NaN where a channel is missing).

    ``voltage_pp`` is the nominal (commanded) drive; ``voltage_pp_drive`` the measured one, if known.
    ``sigma`` holds the 1-sigma uncertainty of each channel in :data:`CHANNELS`.
    """

    frequency_hz: FloatArray
    voltage_pp: FloatArray
    voltage_pp_drive: FloatArray
    tip_velocity_rms: FloatArray
    tip_phase_rad: FloatArray
    current_rms: FloatArray
    power_w: FloatArray
    thrust_loadcell_n: FloatArray
    sigma: dict[str, FloatArray]
    source: str = ""
    #: when each trial started, s since the first (NaN if unknown): drifts in time are fitted on it
    time_s: FloatArray | None = None
    #: the nominal voltages are commands (a bag's ``cmd``, a CSV's ``voltage_pp``); without them they
    #: are the measured drive, and the drive stage (command -> drive) cannot be judged
    commanded: bool = True
    #: what reading the data found (interference, sample rate, a reversed sensor, ...)
    notes: tuple[str, ...] = ()
    #: the supply as its meter read it (the ``supply`` topic; NaN without one), the amplifier's model
    #: of it at the measured drive (the estimator's ``power_supply_w``) and the meter's sigma, W:
    #: the ``supply`` stage (not fitted: the fin's effects do not act on the amplifier's law)
    power_supply_w: FloatArray | None = None
    power_supply_model_w: FloatArray | None = None
    power_supply_sigma_w: FloatArray | None = None

    def __post_init__(self) -> None:
        n = len(self.frequency_hz)
        for name in ("time_s", "power_supply_w", "power_supply_model_w", "power_supply_sigma_w"):
            if getattr(self, name) is None:
                object.__setattr__(self, name, np.full(n, np.nan))
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray) and v.shape != (n,):
                raise DataError(f"{self.source}: column {f.name} has {v.shape} values, expected {n}")
        if n == 0:
            raise DataError(f"{self.source}: no trial")
        bad = ~(np.isfinite(self.frequency_hz) & (self.frequency_hz > 0))
        bad |= ~(np.isfinite(self.voltage_pp) & (self.voltage_pp > 0))
        if np.any(bad):
            raise DataError(
                f"{self.source}: trial(s) {np.flatnonzero(bad).tolist()} lack a valid frequency or voltage"
            )

    def __len__(self) -> int:
        return len(self.frequency_hz)

    def channel(self, name: str) -> FloatArray:
        return np.asarray(getattr(self, name), float)

    def has(self, name: str) -> bool:
        return bool(np.any(np.isfinite(self.channel(name))))

    @property
    def voltages(self) -> FloatArray:
        """Distinct nominal voltages (rounded to 1 V)."""
        return np.unique(np.round(self.voltage_pp))

    def subset(self, index: FloatArray | Sequence[int] | NDArray[np.bool_]) -> Trials:
        idx = np.asarray(index)
        cols = {
            f.name: getattr(self, f.name)[idx]
            for f in fields(self)
            if isinstance(getattr(self, f.name), np.ndarray)
        }
        return replace(self, **cols, sigma={k: v[idx] for k, v in self.sigma.items()})

    def measured_drive(self) -> FloatArray | None:
        """The measured drive (Vpp) if every trial has it, else None (the model then drives the fin)."""
        if np.all(np.isfinite(self.voltage_pp_drive)):
            return self.voltage_pp_drive
        return None

    def records(self) -> list[dict[str, float]]:
        names = ["frequency_hz", "voltage_pp", *CHANNELS]
        out = []
        for i in range(len(self)):
            row = {n: float(self.channel(n)[i]) for n in names}
            row.update({f"{n}_sigma": float(self.sigma[n][i]) for n in CHANNELS})
            row["time_s"] = float(np.asarray(self.time_s)[i])
            out.append(row)
        return out

    def to_csv(self, path: str | os.PathLike[str]) -> None:
        rows = self.records()
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)


def _floor(values: FloatArray, sigma: FloatArray, rel: float, absolute: float = 0.0) -> FloatArray:
    return np.sqrt(sigma**2 + (rel * np.abs(values)) ** 2 + absolute**2)


def make_trials(
    columns: dict[str, FloatArray],
    noise: dict[str, FloatArray],
    source: str,
    model_floor: float = 0.01,
    **extra: Any,
) -> Trials:
    """A table from measured columns and their noise-only sigmas (a relative model floor is added);
    ``extra``: ``time_s``, ``commanded``, ``notes`` of :class:`Trials`."""
    n = len(columns["frequency_hz"])
    nan = np.full(n, np.nan)
    cols = {
        name: np.asarray(columns.get(name, nan), float) for name in ("frequency_hz", "voltage_pp", *CHANNELS)
    }
    sigma = {}
    for name in CHANNELS:
        s = np.asarray(noise.get(name, np.zeros(n)), float)
        if name == "tip_phase_rad":
            sigma[name] = np.sqrt(s**2 + model_floor**2)  # 1 % of a radian ~ 0.6 deg
        else:
            sigma[name] = _floor(cols[name], s, model_floor)
    return Trials(**cols, sigma=sigma, source=source, **extra)  # type: ignore[arg-type]


@dataclass(frozen=True)
class SignalNoise:
    """1-sigma white noise of each signal (V, A, m/s, m) and the load cell's residual drift (N)."""

    voltage: float
    current: float
    tip: float
    loadcell: float
    loadcell_drift: float = 0.0


def loadcell_sigma(
    noise: SignalNoise, stiffness: float, n_on: ArrayLike, n_baseline: ArrayLike
) -> FloatArray:
    """Thrust sigma (N) of a mean over ``n_on`` samples minus a baseline over ``n_baseline``."""
    on, base = np.asarray(n_on, float), np.asarray(n_baseline, float)
    return np.asarray(stiffness * noise.loadcell * np.sqrt(1 / on + 1 / base) + noise.loadcell_drift)


def window_sigmas(
    noise: SignalNoise,
    n_samples: ArrayLike,
    n_baseline: ArrayLike,
    voltage_pp_drive: ArrayLike,
    tip_velocity_rms: ArrayLike,
    loadcell_stiffness: float,
) -> dict[str, FloatArray]:
    """Noise-only sigma of each channel for lock-in windows of ``n_samples`` samples.

    A phasor component of a window of ``N`` samples carries ``s sqrt(2/N)`` of a white noise ``s``.
    """
    n = np.asarray(n_samples, float)
    vd, u = np.asarray(voltage_pp_drive, float), np.asarray(tip_velocity_rms, float)
    lock = np.sqrt(2.0 / n)
    tip = noise.tip * lock / math.sqrt(2)
    return {
        "voltage_pp_drive": 2 * noise.voltage * lock,
        "tip_velocity_rms": tip,
        "tip_phase_rad": np.divide(tip, u, out=np.full(n.shape, np.inf), where=u > 0),
        "current_rms": noise.current / np.sqrt(n),
        "power_w": 0.25 * vd * noise.current * lock,
        "thrust_loadcell_n": loadcell_sigma(noise, loadcell_stiffness, n, n_baseline),
    }


def from_estimates(
    estimates: Iterable[Estimate],
    noise: SignalNoise,
    sample_rate_hz: float = 1000.0,
    commands: Sequence[tuple[float, float, float]] = (),
    source: str = "",
    baseline_s: float = 5.0,
    loadcell_stiffness: float = EstimatorConfig().loadcell_stiffness_n_per_m,
    notes: Sequence[str] = (),
) -> Trials:
    """One row per *final* estimate (a whole trial), with sigmas from the noise levels.

    ``commands`` are ``(t, frequency_hz, voltage_pp)`` as commanded; the nominal voltage of a trial is
    the last command before it.  Without any command the nominal voltages are the measured drive
    (``commanded`` False, and a note says so).  ``time_s`` is each trial's start (the estimate's).
    """
    rows = [e for e in estimates if e.final == 1.0 and math.isfinite(e.power_w)]
    if not rows:
        raise DataError(
            f"{source}: no completed trial (a trial needs the drive on for > 3 s and off after it)"
        )
    f = np.array([e.frequency_hz for e in rows])
    v_drive = np.array([e.voltage_pp for e in rows])
    nominal = v_drive.copy()
    cmd = sorted(commands)
    for j, e in enumerate(rows):
        before = [c for c in cmd if c[0] <= e.t_start and c[2] > 0]
        if before:
            nominal[j] = before[-1][2]
    said = list(notes)
    if not cmd:
        said.append(
            "no command messages: the nominal voltages are the measured drive, so the drive stage "
            "(command -> amplifier output) is not judged and the drive-voltage channel is not fitted"
        )
    n = np.array([max((e.t_end - e.t_start) * sample_rate_hz, 1.0) for e in rows])
    u = np.array([e.tip_velocity_rms for e in rows])
    nb = baseline_s * sample_rate_hz * np.array([max(e.loadcell_baselines, 1.0) for e in rows])
    sig = window_sigmas(noise, n, nb, v_drive, u, loadcell_stiffness)
    cols = {
        "frequency_hz": f,
        "voltage_pp": nominal,
        "voltage_pp_drive": v_drive,
        "tip_velocity_rms": u,
        "tip_phase_rad": np.array([e.tip_phase_rad for e in rows]),
        "current_rms": np.array([e.current_rms for e in rows]),
        "power_w": np.array([e.power_w for e in rows]),
        "thrust_loadcell_n": np.array([e.thrust_loadcell_n for e in rows]),
    }
    supply = np.array([e.power_supply_measured_w for e in rows])
    return make_trials(
        cols,
        sig,
        source,
        time_s=np.array([e.t_start for e in rows]),
        commanded=bool(cmd),
        notes=tuple(said),
        power_supply_w=supply,
        power_supply_model_w=np.array([e.power_supply_w for e in rows]),
        # the meter's noise averages out over a trial: the sigma is the model floor's 1 %
        power_supply_sigma_w=0.01 * np.abs(supply),
    )


def _merge(a: Trials, b: Trials) -> Trials:
    cols = {
        f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)])
        for f in fields(a)
        if isinstance(getattr(a, f.name), np.ndarray)
    }
    sigma = {k: np.concatenate([a.sigma[k], b.sigma[k]]) for k in a.sigma}
    notes = a.notes + tuple(n for n in b.notes if n not in a.notes)
    return Trials(
        **cols,
        sigma=sigma,
        source=f"{a.source}, {b.source}",
        commanded=a.commanded and b.commanded,
        notes=notes,
    )


@dataclass(frozen=True)
class Line:
    """A narrow-band interference found with the drive off (mains pickup, a pump, ...)."""

    channel: str  # "voltage" | "current" | "tip"
    frequency_hz: float
    amplitude: float  # SI (V, A, m/s), of the sine


@dataclass(frozen=True)
class Scan:
    """What one pass over a fin's raw topics measures besides the trials."""

    noise: SignalNoise
    commands: list[tuple[float, float, float]]  # (t, f, Vpp) that switched the drive on
    sample_rate_hz: float  # of the drive, from its sample times
    lines: list[Line]


#: A spectral peak is a line when it stands this far above the median of its spectrum (white noise
#: reaches 3.3x the median once in 10^4 bins).
LINE_FACTOR = 8.0
UNITS = {"voltage": ("V", 1.0), "current": ("uA", 1e6), "tip": ("mm/s", 1e3)}


def _runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``[start, stop)`` of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def find_lines(x: FloatArray, rate_hz: float, channel: str, most: int = 3) -> list[Line]:
    """Lines in one contiguous record: Hann-windowed amplitude spectrum, peaks over ``LINE_FACTOR``
    times its median, the strongest ``most``, each refined by a local least-squares sine fit."""
    n = x.size
    if n < 256:
        return []
    win = np.hanning(n)
    amp = 2 * np.abs(np.fft.rfft((x - x.mean()) * win)) / win.sum()
    amp[0] = 0.0
    floor = float(np.median(amp[1:]))
    freqs = np.fft.rfftfreq(n, 1 / rate_hz)
    peaks = [
        k
        for k in range(2, amp.size - 1)
        if amp[k] > LINE_FACTOR * floor and amp[k] >= amp[k - 1] and amp[k] >= amp[k + 1]
    ]
    peaks = sorted(peaks, key=lambda k: -amp[k])[:most]
    t = np.arange(n) / rate_hz
    out = []
    for k in peaks:
        # the sine's frequency between the bins, then its amplitude by least squares over the first
        # and the last third: a line is steady; a fin ringing down after a burst is not interference
        a, b, c = amp[k - 1], amp[k], amp[k + 1]
        f = freqs[k] + 0.5 * (a - c) / (a - 2 * b + c) * (freqs[1] - freqs[0])
        thirds = [slice(0, n // 3), slice(n - n // 3, n)]
        amps = [_sine_amplitude(t[s], x[s], f) for s in thirds]
        if max(amps) <= 2 * min(amps):
            out.append(Line(channel, float(f), _sine_amplitude(t, x, f)))
    return out


def _sine_amplitude(t: FloatArray, x: FloatArray, f: float) -> float:
    basis = np.column_stack([np.ones(t.size), np.cos(2 * np.pi * f * t), np.sin(2 * np.pi * f * t)])
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return float(np.hypot(coef[1], coef[2]))


def _without_lines(x: FloatArray, t: FloatArray, lines: Sequence[Line]) -> FloatArray:
    """``x`` minus its mean and the lines' sines (fitted on this record)."""
    cols = [np.ones_like(t)]
    for ln in lines:
        cols += [np.cos(2 * np.pi * ln.frequency_hz * t), np.sin(2 * np.pi * ln.frequency_hz * t)]
    basis = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return np.asarray(x - basis @ coef)


class Scanner:
    """The raw samples and commands a noise scan needs, gathered message by message
    (:func:`~piezofin_ros.bags.fin.read_fin`'s); :func:`scan_bag` reads a bag through it."""

    KINDS = (TOPIC_DRIVE, TOPIC_TIP, TOPIC_LOADCELL, TOPIC_CMD)

    def __init__(self) -> None:
        self.parts: dict[str, list[FloatArray]] = {k: [] for k in ("t", "v", "i", "tt", "u", "tl", "d")}
        self.commands: list[tuple[float, float, float]] = []

    def add(self, m: FinMessage) -> None:
        b, parts = m.block, self.parts
        if b is None:
            return
        if m.kind == TOPIC_CMD:
            freq, vpp, on = (b.scalar(name) for name in COMMAND_FIELDS)
            if math.isfinite(freq) and math.isfinite(vpp) and on > 0:
                self.commands.append((m.time_ns * 1e-9, freq, vpp))
        elif m.kind == TOPIC_DRIVE:
            parts["t"].append(b["t_s"])
            parts["v"].append(b["voltage_V"])
            parts["i"].append(b["current_A"])
        elif m.kind == TOPIC_TIP:
            parts["tt"].append(b["t_s"])
            parts["u"].append(b["tip_velocity_m_s"])
        elif m.kind == TOPIC_LOADCELL:
            parts["tl"].append(b["t_s"])
            parts["d"].append(b["displacement_m"])


def scan_bag(path: str | os.PathLike[str], namespace: str, threshold_v: float = 10.0) -> Scan:
    """One pass over a fin's raw topics: the noise of each signal where the drive is off (more than
    2 s after and 0.5 s before any ``|v| >= threshold``), net of any interference line found there,
    the commands ``(t, f, Vpp)`` that switched the drive on, and the drive's sample rate."""
    scanner = Scanner()
    for m in read_fin(path, namespace, Scanner.KINDS):  # (malformed data: the replay reports it)
        scanner.add(m)
    return scanned(scanner, path, namespace, threshold_v)


def scanned(
    scanner: Scanner, path: str | os.PathLike[str], namespace: str, threshold_v: float = 10.0
) -> Scan:
    """The :class:`Scan` of what ``scanner`` gathered from ``path`` (see :func:`scan_bag`)."""
    ns = topic_prefix(namespace)
    parts, commands = scanner.parts, scanner.commands
    cat = {k: np.concatenate(v) if v else np.empty(0) for k, v in parts.items()}
    t, v = cat["t"], cat["v"]
    if t.size < 100:
        raise DataError(f"{path}: too few drive samples on {ns}/drive to measure the noise")
    dt = np.diff(t)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    if dt.size < 10:
        raise DataError(f"{path}: the drive's sample times on {ns}/drive do not increase")
    step = float(np.median(dt))
    rate = 1.0 / step
    t_on = t[np.abs(v) >= threshold_v]
    quiet_mask = np.ones(t.size, bool)
    if t_on.size:
        pos = np.searchsorted(t_on, t)
        prev = np.where(pos > 0, t - t_on[np.maximum(pos - 1, 0)], np.inf)
        nxt = np.where(pos < t_on.size, t_on[np.minimum(pos, t_on.size - 1)] - t, np.inf)
        quiet_mask = (prev > 2.0) & (nxt > 0.5)
    quiet_t = t[quiet_mask]
    if quiet_t.size < 100:
        raise DataError(f"{path}: no stretch with the drive off to measure the noise (need > 0.1 s)")
    lo, hi = quiet_t.min(), quiet_t.max()

    def quiet(tt: FloatArray, x: FloatArray) -> FloatArray:
        """Samples of another channel that fall on a quiet drive sample."""
        if tt.size == 0:
            return np.empty(0)
        idx = np.clip(np.searchsorted(quiet_t, tt), 0, quiet_t.size - 1)
        near = np.abs(quiet_t[idx] - tt) < 1.5 * step
        return x[near & (tt >= lo) & (tt <= hi) & np.isfinite(x)]

    white, lines = _drive_noise(t, {"voltage": v, "current": cat["i"]}, quiet_mask, step)

    lc = quiet(cat["tl"], cat["d"])
    # the load cell drifts: its white noise from first differences, which a slow drift does not reach
    lc_white = float(np.std(np.diff(lc)) / math.sqrt(2)) if lc.size > 10 else math.nan
    noise = SignalNoise(
        voltage=white["voltage"],
        current=white["current"],
        tip=std(quiet(cat["tt"], cat["u"])),
        loadcell=lc_white,
    )
    return Scan(noise, commands, rate, lines)


def _drive_noise(
    t: FloatArray, channels: dict[str, FloatArray], quiet_mask: NDArray[np.bool_], step: float
) -> tuple[dict[str, float], list[Line]]:
    """Each drive channel's white noise where the drive is off, net of the interference lines found in
    its longest contiguous quiet stretch (no gap in the sample times), and the lines."""
    gaps = np.concatenate([[False], np.abs(np.diff(t) - step) > 0.5 * step])
    splits = []
    for a, b in _runs(quiet_mask & np.isfinite(channels["voltage"])):
        cut = [a, *(np.flatnonzero(gaps[a + 1 : b]) + a + 1).tolist(), b]
        splits += [(x, y) for x, y in itertools.pairwise(cut) if y - x >= 256]
    lines: list[Line] = []
    white = {}
    for name, x in channels.items():
        if not splits:
            white[name] = std(x[quiet_mask])
            continue
        longest = max(splits, key=lambda r: r[1] - r[0])
        found = find_lines(x[longest[0] : longest[1]], 1.0 / step, name)
        lines += found
        white[name] = float(
            np.std(np.concatenate([_without_lines(x[a:b], t[a:b], found) for a, b in splits]))
        )
    return white, lines


def std(x: FloatArray) -> float:
    return float(np.std(x)) if x.size > 10 else math.nan


def interference_notes(lines: Sequence[Line], trials: Trials) -> list[str]:
    """One note per line: what it is, and which trials' lock-in it reaches (an odd harmonic 1, 3 or 5
    of the drive within a tenth of a hertz of it)."""
    out = []
    for ln in lines:
        unit, scale = UNITS[ln.channel]
        f = trials.frequency_hz
        hit = np.zeros(len(trials), bool)
        for k in (1, 3, 5):
            hit |= np.abs(k * f - ln.frequency_hz) < 0.1
        where = (
            "every trial's lock-in rejects it (it is at no odd harmonic of a drive frequency)"
            if not hit.any()
            else "it reaches the lock-in of the trials at "
            + ", ".join(sorted({f"{x:g} Hz" for x in f[hit]}))
            + " (an odd harmonic of the drive falls on it)"
        )
        out.append(
            f"interference on the {ln.channel} channel: a {ln.frequency_hz:.2f} Hz line of "
            f"{ln.amplitude * scale:.3g} {unit} with the drive off (mains pickup?); {where}"
        )
    return out


def from_bags(
    paths: Sequence[str | os.PathLike[str]],
    fin: Fin,
    namespace: str = "/fin",
    progress: Any = None,
    amplifier: Amplifier = PAPER_BENCH,
) -> tuple[Trials, list[str]]:
    """Trials of one fin from one or more bags (MCAP files or rosbag2 directories); returns the
    table and the lines the replay skipped.  Each bag's sample rate comes from its sample times;
    ``amplifier`` is the model of the amplifier that drove it (the ``supply`` stage, with a meter)."""
    tables: list[Trials] = []
    skipped: list[str] = []
    for j, path in enumerate(paths):
        if progress:
            progress(f"reading {path} ({j + 1}/{len(paths)})")
        # one pass: the estimator's replay and the noise scan take each message as it is read
        replayer, scanner = Replayer(fin, amplifier=amplifier), Scanner()
        wanted = {*Replayer.KINDS, *Scanner.KINDS}
        for m in read_fin(path, namespace, wanted, skipped=replayer.skipped, progress=progress):
            if m.kind in Replayer.KINDS:
                replayer.add(m)
            if m.kind in Scanner.KINDS:
                scanner.add(m)
        replay = replayer.result(path, namespace, sorted(wanted))
        skipped += [f"{path}: {s}" for s in replay.skipped_lines()]
        scan = scanned(scanner, path, namespace)
        table = from_estimates(
            replay.replayed,
            scan.noise,
            sample_rate_hz=scan.sample_rate_hz,
            commands=scan.commands,
            source=str(path),
        )
        said = interference_notes(scan.lines, table)
        if abs(scan.sample_rate_hz - 1000.0) > 1.0:
            said.append(f"{path}: the drive is sampled at {scan.sample_rate_hz:.4g} Hz (its sample times)")
        tables.append(replace(table, notes=table.notes + tuple(said)))
    out = tables[0]
    for t in tables[1:]:
        out = _merge(out, t)
    assert out.time_s is not None
    return replace(out, time_s=out.time_s - np.nanmin(out.time_s)), skipped


def from_csv(path: str | os.PathLike[str], relative_sigma: float = 0.02, model_floor: float = 0.01) -> Trials:
    """Per-trial summaries (one row per trial; SI units; header names as in :data:`CSV_COLUMNS`).

    Columns ``<channel>_sigma`` give uncertainties; otherwise ``relative_sigma`` of each value.  An
    optional ``time_s`` column (each trial's start, s) lets drifts in time be fitted.
    """
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise DataError(f"{path}: cannot read as CSV ({exc})") from None
    if not rows:
        raise DataError(f"{path}: no data row")
    header = {h.strip().lower(): h for h in rows[0] if h}
    cols: dict[str, FloatArray] = {}
    noise: dict[str, FloatArray] = {}
    for key, aliases in CSV_COLUMNS.items():
        found = next((header[a] for a in aliases if a in header), None)
        if found is None:
            continue
        cols[key] = _floats(path, rows, found)
        sig = header.get(f"{key}_sigma")
        if sig is not None:
            noise[key] = _floats(path, rows, sig)
        elif key in CHANNELS:
            noise[key] = relative_sigma * np.abs(cols[key])
    for need in ("frequency_hz", "voltage_pp"):
        if need not in cols:
            raise DataError(f"{path}: no column for {need} (accepted names: {', '.join(CSV_COLUMNS[need])})")
    if not any(k in cols for k in CHANNELS):
        raise DataError(f"{path}: no measured column (accepted: {', '.join(CHANNELS)})")
    extra: dict[str, Any] = {}
    if "time_s" in header:  # when each trial started (s): drifts in time are fitted on it
        extra["time_s"] = _floats(path, rows, header["time_s"])
    return make_trials(cols, noise, str(path), model_floor, **extra)


def _floats(path: str | os.PathLike[str], rows: list[dict[str, str]], column: str) -> FloatArray:
    out = []
    for j, r in enumerate(rows):
        text = (r.get(column) or "").strip()
        try:
            out.append(float(text) if text else math.nan)
        except ValueError:
            raise DataError(f"{path}: row {j + 2}, column {column}: not a number: {text!r}") from None
    return np.array(out)


__all__ = [
    "CHANNELS",
    "DataError",
    "SignalNoise",
    "Trials",
    "from_bags",
    "from_csv",
    "from_estimates",
    "make_trials",
]


def conventions(trials: Trials) -> tuple[Trials, list[str]]:
    """A reversed sensor (:mod:`piezofin_ros.identification.signs`), found in the trials, corrected.

    The power into the motion is a positive multiple of ``u cos(psi)`` (the tip phase ``psi``
    against the drive), the drive's is ``mean(v i)``; a reversed vibrometer is corrected by turning
    the tip phase through 180 deg, a reversed current monitor by turning the power's sign.
    """
    notes: list[str] = []
    u, ph, p = trials.tip_velocity_rms, trials.tip_phase_rad, trials.power_w
    signs = Signs.check(u * np.cos(ph), p)
    if not signs.any:
        return trials, notes
    cols: dict[str, Any] = {}
    if signs.tip:
        cols["tip_phase_rad"] = np.angle(-np.exp(1j * ph))
    if signs.power:
        cols["power_w"] = -p
    fix = " and ".join(x for x, on in (("tip phase + 180 deg", signs.tip), ("power x -1", signs.power)) if on)
    notes.append(
        f"{signs.which}: the fin would be giving power back ({signs.symptom}); corrected ({fix}) "
        "before the diagnosis. Sign conventions: docs/reference.md"
    )
    return replace(trials, **cols), notes
