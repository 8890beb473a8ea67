"""The simulated test rig: a safe drive, the fin (Eqs. 9-10), the instruments and the load cell.

This is what ``fin_sim`` streams, block by block, and what offline tools can run without
ROS.  It reproduces the paper's set-up (Sec. 3):

* **Drive** (:class:`Drive`): a phase-continuous sine on an offset (a DC bias, to steer), whose
  amplitude and offset follow the command at a bounded slew rate, so the voltage never steps and
  never leaves the MFC's window (:attr:`DriveLimits.voltage_min_v`, ``voltage_max_v``); a burst
  started from rest begins at a zero crossing.  Commands are checked by :func:`check_command`
  (rejected or clamped, with the reason); a watchdog ramps the drive to zero when commands stop.
* **Fin**: the time-domain engine's RK4 step (:mod:`piezofin_ros.physics.timedomain`), advanced
  incrementally with its state carried across blocks.  With a ``model`` (a diagnosed
  :class:`~piezofin_ros.physics.model.Model` model's ``knobs_at``) the coefficients of
  Eqs. (9)-(10) and of the load cell are those of the model's steady state at the commanded
  operating point (:mod:`piezofin_ros.physics.knobs`): amplitude-dependent effects are linearised there
  (describing function), so the stream's steady state is the model's (within the 2 % of the
  single-harmonic balance) while transients follow the linearisation; an amplifier limit clips
  the drive for real, and its harmonics drive the fin too.
* **Instruments**: white Gaussian noise on the amplifier's voltage and current monitors, the
  laser Doppler vibrometer and the optical displacement sensor (:class:`RigConfig`).
* **Thrust transducer**: the fin hangs on an aluminium cantilever (254 x 25.4 x 6.35 mm,
  E = 69 GPa, so ``k = 3 E I / l^3`` = 6.85 kN/m).  Its tip deflection follows the
  instantaneous Lighthill thrust through a second-order low-pass (the cantilever's own mode,
  ``loadcell_fn_hz``), plus a slow linear drift, which the paper's pre/post baseline cancels.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from ..config import HARD_VOLTAGE_PP_MAX, HARD_VOLTAGE_WINDOW_V, setting
from ..errors import RigError
from ..physics.amplifier import PAPER_BENCH, Amplifier
from ..physics.effects import clip_ratio
from ..physics.fin import Fin
from ..physics.knobs import Knobs
from ..physics.planar import bias_window_v
from ..physics.timedomain import default_step, integrate_nodes
from ..physics.waveforms import ProtocolTiming

FloatArray = NDArray[Any]


#: Every stop (off, the watchdog, a lowered cap, lifecycle deactivate/shutdown) ramps the amplitude
#: The lagging instruments of an augmented model read this far back at most (s).
LAG_HISTORY_S = 0.05
#: down at least this fast, whatever ``slew_vpp_per_s`` is set to: from the hard cap to zero in
#: 0.25 s.  A slower configured slew only slows the way *up* and commanded changes, never a stop.
STOP_SLEW_VPP_PER_S = 4000.0
#: A stop takes the offset to zero at least this fast: from the window's top (1,500 V) in 0.25 s, as
#: the amplitude from the hard cap (a fin of 20 nF draws 0.1 mA on the way).
STOP_BIAS_V_PER_S = 6000.0


@dataclass(frozen=True)
class DriveLimits:
    """Limits every command is checked against (SI units)."""

    frequency_min_hz: float = setting(0.5, "drive limits: lowest frequency, Hz", 0.01, 1000.0)
    frequency_max_hz: float = setting(40.0, "drive limits: highest frequency, Hz", 0.01, 1000.0)
    voltage_pp_max: float = setting(
        800.0, "drive limits: highest voltage, Vpp (0: no drive at all)", 0.0, HARD_VOLTAGE_PP_MAX
    )
    slew_vpp_per_s: float = setting(
        4000.0, "drive limits: amplitude slew on the way up, Vpp/s (0 -> 800 Vpp in 0.2 s)", 1.0, 1e6
    )
    command_timeout_s: float = setting(
        1.0, "drive limits: watchdog, ramp to zero after this long without a command, s", 0.01, 60.0
    )
    voltage_min_v: float = setting(
        HARD_VOLTAGE_WINDOW_V[0],
        "drive limits: the lowest instantaneous voltage, offset and sine together, V (the P1 MFC's -500)",
        HARD_VOLTAGE_WINDOW_V[0],
        0.0,
    )
    voltage_max_v: float = setting(
        HARD_VOLTAGE_WINDOW_V[1],
        "drive limits: the highest instantaneous voltage, offset and sine together, V (the P1 MFC's 1500)",
        0.0,
        HARD_VOLTAGE_WINDOW_V[1],
    )

    #: the limits that may be 0 (a cap of 0: no drive; the window's edges) or below it
    _AT_LEAST: ClassVar[dict[str, float]] = {
        "voltage_pp_max": 0.0,
        "voltage_max_v": 0.0,
        "voltage_min_v": HARD_VOLTAGE_WINDOW_V[0],
    }

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            # bool is an int in Python: `true` must not become a 1 Vpp cap or a 1 s watchdog
            number = isinstance(value, (int, float)) and not isinstance(value, bool)
            least = self._AT_LEAST.get(f.name)
            if not (number and math.isfinite(value) and (value >= least if least is not None else value > 0)):
                bound = f">= {least:g}" if least is not None else "> 0"
                raise RigError(f"{f.name} must be a finite number {bound}, got {value!r}")
        if self.voltage_pp_max > HARD_VOLTAGE_PP_MAX:
            raise RigError(
                f"voltage_pp_max {self.voltage_pp_max} V exceeds the hard cap of {HARD_VOLTAGE_PP_MAX} V "
                "(MFC P1 rating -500..+1500 V, symmetric drive)"
            )
        low, high = HARD_VOLTAGE_WINDOW_V
        for name, lo, hi in (("voltage_min_v", low, 0.0), ("voltage_max_v", 0.0, high)):
            if not lo <= getattr(self, name) <= hi:
                raise RigError(
                    f"{name} {getattr(self, name):g} V must lie within [{lo:g}, {hi:g}] V: the window "
                    f"holds 0 V and lies within the MFC's rating [{low:g}, {high:g}] V"
                )
        half = 0.5 * self.voltage_pp_max
        if not (self.voltage_min_v <= -half and half <= self.voltage_max_v):
            raise RigError(
                f"the window [{self.voltage_min_v:g}, {self.voltage_max_v:g}] V must hold a drive of "
                f"voltage_pp_max {self.voltage_pp_max:g} Vpp with no offset: lower voltage_pp_max to "
                f"{2 * min(-self.voltage_min_v, self.voltage_max_v):g} or widen the window"
            )
        if self.frequency_min_hz >= self.frequency_max_hz:
            raise RigError(
                f"frequency_min_hz ({self.frequency_min_hz}) must be below frequency_max_hz "
                f"({self.frequency_max_hz})"
            )


def loosened(new: DriveLimits, old: DriveLimits) -> list[str]:
    """The limits ``new`` relaxes against ``old`` (empty: every limit as tight or tighter).

    Tighter means: a lower voltage cap, a slower slew, a shorter watchdog, a narrower band, a narrower
    window.
    """
    out = []
    for name, looser in (
        ("voltage_pp_max", new.voltage_pp_max > old.voltage_pp_max),
        ("slew_vpp_per_s", new.slew_vpp_per_s > old.slew_vpp_per_s),
        ("command_timeout_s", new.command_timeout_s > old.command_timeout_s),
        ("frequency_min_hz", new.frequency_min_hz < old.frequency_min_hz),
        ("frequency_max_hz", new.frequency_max_hz > old.frequency_max_hz),
        ("voltage_min_v", new.voltage_min_v < old.voltage_min_v),
        ("voltage_max_v", new.voltage_max_v > old.voltage_max_v),
    ):
        if looser:
            out.append(f"{name} {getattr(old, name):g} -> {getattr(new, name):g}")
    return out


@dataclass(frozen=True)
class DriveCommand:
    """A checked actuation command: sine at ``frequency_hz`` and ``voltage_pp`` (V) on an offset
    ``bias_v`` (V), or off."""

    frequency_hz: float
    voltage_pp: float
    on: bool
    bias_v: float = 0.0


OFF = DriveCommand(0.0, 0.0, False)


def check_command(
    frequency_hz: float, voltage_pp: float, on: float, limits: DriveLimits, bias_v: float = 0.0
) -> tuple[DriveCommand | None, str | None]:
    """Check a raw command; returns ``(command or None if rejected, reason or None)``.

    Off is always accepted (it is the safe state), whatever the other fields hold.  An on
    command with a non-finite field, a frequency outside the band or a negative voltage is
    rejected; a voltage above the limit is clamped to it, and then an offset that would take the
    sine out of the window (``voltage_min_v + a <= bias_v <= voltage_max_v - a``, ``a`` half the
    peak-to-peak voltage) to the window's edge.  Either way the reason is returned for the log.
    """
    if not math.isfinite(on) or on not in (0.0, 1.0):
        return None, f"rejected: 'on' must be 0 or 1, got {on!r}"
    if on == 0.0:
        return OFF, None
    if not (math.isfinite(frequency_hz) and math.isfinite(voltage_pp) and math.isfinite(bias_v)):
        return None, (
            f"rejected: non-finite frequency {frequency_hz!r} Hz, voltage {voltage_pp!r} V "
            f"or offset {bias_v!r} V"
        )
    if not limits.frequency_min_hz <= frequency_hz <= limits.frequency_max_hz:
        return None, (
            f"rejected: frequency {frequency_hz:g} Hz outside "
            f"[{limits.frequency_min_hz:g}, {limits.frequency_max_hz:g}] Hz"
        )
    if voltage_pp < 0:
        return None, f"rejected: negative peak-to-peak voltage {voltage_pp:g} V"
    reasons = []
    if voltage_pp > limits.voltage_pp_max:
        reasons.append(f"clamped: {voltage_pp:g} Vpp above the limit, driving {limits.voltage_pp_max:g} Vpp")
        voltage_pp = limits.voltage_pp_max
    low, high = bias_window(voltage_pp, limits)
    if not low <= bias_v <= high:
        clamped = min(max(bias_v, low), high)
        reasons.append(
            f"clamped: an offset of {bias_v:g} V takes {voltage_pp:g} Vpp out of the window "
            f"[{limits.voltage_min_v:g}, {limits.voltage_max_v:g}] V, driving {clamped:g} V"
        )
        bias_v = clamped
    return DriveCommand(frequency_hz, voltage_pp, True, bias_v), "; ".join(reasons) or None


def bias_window(voltage_pp: float, limits: DriveLimits) -> tuple[float, float]:
    """The offsets a drive of ``voltage_pp`` may carry within the limits' window, V (never empty for a
    voltage within ``voltage_pp_max``: the window holds it with no offset)."""
    return bias_window_v(voltage_pp, (limits.voltage_min_v, limits.voltage_max_v))


@dataclass
class Drive:
    """Phase-continuous, slew-limited sine on an offset, ``v = b(t) + a(t) sin(phase(t))``, advanced
    in time.

    ``a`` is the amplitude (V, half the peak-to-peak voltage), ``b`` the offset (V, a DC bias).  Each
    moves toward its target at ``limits.slew_vpp_per_s / 2`` V/s; the frequency changes at once but
    the phase stays continuous, so ``v`` is continuous and ``dv/dt`` exact (needed for the
    capacitive current).  A *stop* (:meth:`stop`: off, watchdog, a lowered cap) ramps down at least
    at :data:`STOP_SLEW_VPP_PER_S`, so no setting can make a stop slow; off, the watchdog and
    lifecycle take the offset to zero too.  At every instant the offset is held where the sine stays
    within the window (``voltage_min_v + a(t) <= b(t) <= voltage_max_v - a(t)``), whichever of the
    two ramps is the faster: as the amplitude grows the offset yields, and ``v`` stays continuous.

    The watchdog *latches*: once it has ramped the drive to zero, on-commands are refused until
    an off command re-arms it (:attr:`tripped`).  A commander that merely resumes its stream
    of on-commands (a paused process continued, a healed network, a stale publisher) cannot
    restart the drive; one that deliberately stops and starts again can.
    """

    limits: DriveLimits = field(default_factory=DriveLimits)
    t: float = 0.0  # s, time up to which the drive has been rendered
    amplitude: float = 0.0  # V
    target: float = 0.0  # V
    frequency_hz: float = 0.0
    phase: float = 0.0  # rad at time t
    last_command_t: float = -math.inf
    stopping: bool = False  # ramping down for a stop: at least STOP_SLEW_VPP_PER_S
    tripped: bool = False  # the watchdog cut the drive; an off command re-arms it
    bias: float = 0.0  # V, the offset at time t
    bias_target: float = 0.0  # V

    def apply(self, command: DriveCommand, t: float) -> None:
        """Take a checked command at time ``t`` (``>= self.t``; applied from ``self.t`` on)."""
        self.last_command_t = t
        if not command.on:
            self.tripped = False  # a deliberate off re-arms a tripped watchdog
            self.stop()
            return
        if self.tripped:
            return  # latched: see the class docstring (SimulatedRig.command says why)
        if self.amplitude == 0.0:
            self.phase = 0.0  # start from rest at a zero crossing
        self.frequency_hz = command.frequency_hz
        self.stopping = False
        self.target = 0.5 * min(command.voltage_pp, self.limits.voltage_pp_max, HARD_VOLTAGE_PP_MAX)
        low, high = bias_window(2.0 * self.target, self.limits)
        self.bias_target = min(max(command.bias_v, low), high)

    def stop(self, cap_vpp: float = 0.0, *, keep_bias: bool = False) -> None:
        """Ramp down to ``cap_vpp`` (default zero) at the stop rate, if above it, and the offset to
        zero (kept by a lowered cap: ``keep_bias``)."""
        if self.target > 0.5 * cap_vpp:
            self.target = 0.5 * cap_vpp
        if not keep_bias:
            self.bias_target = 0.0
        self.stopping = True

    @property
    def driving(self) -> bool:
        """Whether the drive is asked for anything but 0 V (a sine or an offset)."""
        return self.target > 0.0 or self.bias_target != 0.0

    def watchdog(self, t: float) -> str | None:
        """Ramp to zero if no command came for ``command_timeout_s`` and latch; returns the reason once."""
        if self.driving and t - self.last_command_t > self.limits.command_timeout_s:
            self.stop()
            self.tripped = True
            return (
                f"watchdog: no command for {t - self.last_command_t:.3g} s "
                f"(> {self.limits.command_timeout_s:g} s), ramping the drive to zero; "
                "on-commands are refused until an off command (on = 0) re-arms it"
            )
        return None

    def render(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``v(t)``, ``dv/dt(t)``, the amplitude ``a(t)`` and the offset ``b(t)`` at times ``t``
        (>= ``self.t``), then advance to ``t[-1]``."""
        t = np.asarray(t, dtype=float)
        tau = t - self.t
        amp, amp_rate = self._ramp(
            self.amplitude, self.target, tau, self.target < self.amplitude, 0.5 * STOP_SLEW_VPP_PER_S
        )
        free, free_rate = self._ramp(
            self.bias, self.bias_target, tau, abs(self.bias_target) < abs(self.bias), STOP_BIAS_V_PER_S
        )
        # the offset yields to the amplitude where together they would leave the window (unless a
        # tightened window left the drive outside it: then both ramp to rest, never stepping in)
        low, high = self.limits.voltage_min_v + amp, self.limits.voltage_max_v - amp
        if low[0] - 1e-9 <= free[0] <= high[0] + 1e-9:
            bias = np.clip(free, low, high)
            bias_rate = np.where(free > high, -amp_rate, np.where(free < low, amp_rate, free_rate))
        else:
            bias, bias_rate = free, free_rate
        w = 2.0 * math.pi * self.frequency_hz
        ph = self.phase + w * tau
        s, c = np.sin(ph), np.cos(ph)
        v = bias + amp * s
        dv = bias_rate + amp_rate * s + amp * w * c
        self.t = float(t[-1])
        self.amplitude = float(amp[-1]) if abs(float(amp[-1]) - self.target) > 1e-12 else self.target
        self.bias = float(bias[-1]) if abs(float(bias[-1]) - self.bias_target) > 1e-12 else self.bias_target
        self.phase = float(math.fmod(ph[-1], 2.0 * math.pi))
        return v, dv, amp, bias

    def _ramp(
        self, now: float, target: float, tau: FloatArray, toward_rest: bool, stop_v_per_s: float
    ) -> tuple[FloatArray, FloatArray]:
        """A value and its rate, ramping from ``now`` to ``target`` at the slew (V/s: half the
        Vpp/s), at least ``stop_v_per_s`` where a stop takes it toward rest."""
        gap = target - now
        slew = 0.5 * self.limits.slew_vpp_per_s
        if toward_rest and self.stopping:
            slew = max(slew, stop_v_per_s)
        ramp_time = abs(gap) / slew
        value = now + math.copysign(slew, gap) * np.minimum(tau, ramp_time)
        return value, np.where(tau < ramp_time, math.copysign(slew, gap), 0.0)

    @property
    def voltage_pp(self) -> float:
        """Present peak-to-peak amplitude, V."""
        return 2.0 * self.amplitude


@dataclass(frozen=True)
class RigConfig:
    """The instruments and the thrust transducer.  Noise values are white, RMS per sample.

    Defaults (stated, not measured: the paper gives no noise figures): voltage monitor 0.2 V,
    current monitor 1 uA, vibrometer 1 mm/s, optical displacement sensor 0.1 um, drift 2 nm/s.
    """

    sample_rate_hz: float = setting(1000.0, "rig: sample rate of every channel, Hz", 100.0, 20000.0)
    voltage_noise_v: float = setting(0.2, "rig: voltage monitor noise, V RMS", 0.0, 100.0)
    current_noise_a: float = setting(1e-6, "rig: current monitor noise, A RMS", 0.0, 1e-2)
    vibrometer_noise_m_s: float = setting(1e-3, "rig: vibrometer noise, m/s RMS", 0.0, 1.0)
    displacement_noise_m: float = setting(1e-7, "rig: load-cell displacement sensor noise, m RMS", 0.0, 1e-3)
    loadcell_length_m: float = setting(0.254, "rig: thrust cantilever length, m", 1e-3, 10.0)
    loadcell_width_m: float = setting(0.0254, "rig: thrust cantilever width, m", 1e-4, 1.0)
    loadcell_thickness_m: float = setting(0.00635, "rig: thrust cantilever thickness, m", 1e-5, 0.1)
    loadcell_modulus_pa: float = setting(69e9, "rig: thrust cantilever Young's modulus, Pa", 1e6, 1e12)
    loadcell_fn_hz: float = setting(60.0, "rig: load cell natural frequency, Hz", 1.0, 5000.0)
    loadcell_zeta: float = setting(0.05, "rig: load cell damping ratio", 1e-4, 2.0)
    loadcell_drift_m_per_s: float = setting(2e-9, "rig: load cell drift, m/s (either sign)", -1e-6, 1e-6)
    swim_speed_m_s: float = setting(0.0, "rig: U of Eq. (19), m/s (0 on the tethered rig)", 0.0, 10.0)
    supply_noise_a: float = setting(1e-5, "rig: the supply's current meter noise, A RMS", 0.0, 1.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise RigError(f"rig.{f.name} must be a finite number, got {value!r}")
            if f.name == "loadcell_drift_m_per_s":
                continue  # either sign
            may_be_zero = "noise" in f.name or f.name == "swim_speed_m_s"
            if value < 0 or (value == 0 and not may_be_zero):
                raise RigError(f"rig.{f.name} must be {'>= 0' if may_be_zero else '> 0'}, got {value!r}")

    @property
    def loadcell_stiffness(self) -> float:
        """Tip stiffness of the transducer cantilever, ``3 E I / l^3`` with ``I = b h^3 / 12``, N/m."""
        inertia = self.loadcell_width_m * self.loadcell_thickness_m**3 / 12.0
        return 3.0 * self.loadcell_modulus_pa * inertia / self.loadcell_length_m**3

    def replace(self, **changes: Any) -> RigConfig:
        return replace(self, **changes)


@dataclass(frozen=True)
class RigBlock:
    """One block of rig output on the uniform grid ``t`` (s).  Measured channels carry noise."""

    t: FloatArray
    voltage: FloatArray  # V
    current: FloatArray  # A
    tip_velocity: FloatArray  # m/s
    displacement: FloatArray  # m, load-cell deflection
    thrust_true: FloatArray  # N, instantaneous Lighthill thrust (noise free, for tests)
    events: tuple[str, ...] = ()
    supply_voltage: FloatArray = field(default_factory=lambda: np.empty(0))  # V, the amplifier's bus
    supply_current: FloatArray = field(default_factory=lambda: np.empty(0))  # A, its meter (with noise)
    applied_peak_v: float = 0.0  # V, the largest |v| the drive truly applied (the monitor may read more)


@dataclass
class _Trial:
    command: DriveCommand
    t_on: float
    t_off: float
    t_end: float


class SimulatedRig:
    """Streams the rig's measurements block by block; deterministic for a given ``seed``.

    With ``protocol`` set, the rig runs the paper's trial on its own, like the lab's sequencer:
    an *on* command for a new operating point starts one trial (off, on, off) that runs to its
    end without further commands (repeats of the same command are heartbeats; an *off* command
    aborts the trial and ramps down).  Send *off* then *on* to repeat a point.

    >>> rig = SimulatedRig(load_fin("M8528-P1"))
    >>> rig.command(5.5, 800, 1)
    >>> block = rig.step(100)            # the next 100 samples (0.1 s at 1 kHz)
    """

    def __init__(
        self,
        fin: Fin,
        config: RigConfig | None = None,
        limits: DriveLimits | None = None,
        *,
        seed: int = 0,
        t0: float = 0.0,
        protocol: ProtocolTiming | None = None,
        model: Callable[[float, float], Knobs] | None = None,
        amplifier: Amplifier | None = None,
    ) -> None:
        self.fin = fin
        self.amplifier = amplifier or PAPER_BENCH  # the supply's law
        #: a free-swimming body's speed (:mod:`.fish`), which Eq. (19) then uses; None: the config's
        self.swim_speed_m_s: float | None = None
        self.model = model
        self._knobs = Knobs()
        self._history: dict[str, tuple[FloatArray, FloatArray]] = {}  # recent samples, for the lags
        self._knobs_at: tuple[float, float] | None = None
        self.protocol = protocol
        self.trial: _Trial | None = None
        self._last_trial_command: DriveCommand | None = None
        self.config = config or RigConfig()
        self.drive = Drive(limits or DriveLimits(), t=t0)
        self._rng = np.random.default_rng(seed)
        self._supply_rng = np.random.default_rng([seed, 1])  # its own: the other channels' noise as before
        self._state = np.zeros((1, 2))
        self._t0 = t0
        self._k = 0  # samples emitted so far
        fs = self.config.sample_rate_hz
        wc = 2 * math.pi * self.config.loadcell_fn_hz
        num, den = [wc**2], [1.0, 2 * self.config.loadcell_zeta * wc, wc**2]
        bz, az, _ = signal.cont2discrete((num, den), 1.0 / fs, method="bilinear")
        self._lc_b, self._lc_a = np.ravel(bz), np.ravel(az)
        self._lc_zi = np.zeros(2)
        self._events: list[str] = []

    @property
    def t(self) -> float:
        """Time of the last emitted sample (s)."""
        return self._t0 + self._k / self.config.sample_rate_hz

    @property
    def elapsed(self) -> float:
        """Simulated time since the first sample's origin ``t0`` (s)."""
        return self._k / self.config.sample_rate_hz

    def command(
        self, frequency_hz: float, voltage_pp: float, on: float, bias_v: float = 0.0
    ) -> tuple[bool, str | None]:
        """Check and apply a raw command now; returns ``(accepted, reason)``."""
        cmd, reason = check_command(frequency_hz, voltage_pp, on, self.drive.limits, bias_v)
        if cmd is None:
            return False, reason
        if cmd.on and self.drive.tripped:
            return False, (
                "rejected: the watchdog tripped (commands had stopped); send off (on = 0) to re-arm it "
                "before driving again"
            )
        if self.protocol is None:
            self.drive.apply(cmd, self.t)
        elif not cmd.on:
            self.trial = self._last_trial_command = None
            self.drive.apply(OFF, self.t)
        elif cmd != self._last_trial_command:
            p = self.protocol
            t_on = self.t + p.off_s
            self.trial = _Trial(cmd, t_on, t_on + p.on_s, t_on + p.on_s + p.off_s)
            self._last_trial_command = cmd
            self.drive.apply(OFF, self.t)
        return True, reason

    def tighten(self, limits: DriveLimits) -> str:
        """Apply tighter limits now (an operator lowering the cap on a running fin); returns what
        happened.  A drive above the new cap ramps down to it at the stop rate; a drive or a
        protocol trial outside the new band ramps to zero.  Raises ``ValueError`` naming every limit
        that would be relaxed: loosening needs a restart, with the new value checked at start."""
        looser = loosened(limits, self.drive.limits)
        if looser:
            raise RigError("only tighter limits are taken while running: " + ", ".join(looser))
        d = self.drive
        d.limits = limits
        in_band = limits.frequency_min_hz <= d.frequency_hz <= limits.frequency_max_hz
        trial_in_band = self.trial is None or (
            limits.frequency_min_hz <= self.trial.command.frequency_hz <= limits.frequency_max_hz
        )
        if (d.target > 0.0 and not in_band) or not trial_in_band:
            self.stop()
            return f"limits tightened; {d.frequency_hz:g} Hz is outside the new band: ramping to zero"
        outside = not (
            limits.voltage_min_v + d.amplitude - 1e-9 <= d.bias <= limits.voltage_max_v - d.amplitude + 1e-9
        )
        if outside or d.bias_target != min(max(d.bias_target, limits.voltage_min_v), limits.voltage_max_v):
            self.stop()
            return (
                f"limits tightened; the drive ({d.bias:g} V +- {d.amplitude:g} V) leaves the new window "
                f"[{limits.voltage_min_v:g}, {limits.voltage_max_v:g}] V: ramping to zero"
            )
        if d.target > 0.5 * limits.voltage_pp_max:
            d.stop(limits.voltage_pp_max, keep_bias=True)
            return f"limits tightened; the drive ramps down to {limits.voltage_pp_max:g} Vpp"
        return "limits tightened"

    def _sequence(self) -> None:
        """Protocol mode: switch the drive at the trial's times (at block boundaries)."""
        trial = self.trial
        if trial is None:
            return
        t = self.t
        if trial.t_on <= t < trial.t_off:
            self.drive.apply(trial.command, t)  # also keeps the watchdog fed during the burst
        elif t >= trial.t_off:
            self.drive.apply(OFF, t)
            if t >= trial.t_end:
                self.trial = None
        else:
            self.drive.last_command_t = t

    def stop(self) -> None:
        """Ramp to zero at the stop rate (lifecycle deactivate, shutdown) and forget any running
        trial.  A tripped watchdog stays latched (see :meth:`rearm`)."""
        self.trial = self._last_trial_command = None
        self.drive.stop()

    def rearm(self) -> None:
        """Clear a tripped watchdog (lifecycle activate: an operator's deliberate action)."""
        self.drive.tripped = False

    def _update_knobs(self) -> Knobs:
        """The model's knobs at the commanded operating point (kept while the drive ramps down)."""
        d = self.drive
        if self.model is None or d.target <= 0.0:
            return self._knobs
        point = (d.frequency_hz, 2.0 * d.target)
        if point != self._knobs_at:
            knobs = self.model(*point)
            values = [float(getattr(knobs, n)) for n in Knobs.__dataclass_fields__]
            if all(math.isfinite(x) for x in values):
                self._knobs = knobs
            else:  # keep the last good coefficients rather than integrate NaN
                self._events.append(f"model: no finite steady state at {point[0]:g} Hz, {point[1]:g} Vpp")
            self._knobs_at = point
        return self._knobs

    def _lagged(self, name: str, t: FloatArray, x: FloatArray, delay_s: float) -> FloatArray:
        """``x`` read ``delay_s`` late: interpolated in this block and the end of the previous one
        (nothing is kept or copied for an instrument without a lag, the rule on every block)."""
        if delay_s == 0.0:
            self._history.pop(name, None)
            return x
        t_prev, x_prev = self._history.get(name, (np.empty(0), np.empty(0)))
        tt, xx = np.concatenate([t_prev, t]), np.concatenate([x_prev, x])
        keep = tt > t[-1] - LAG_HISTORY_S
        self._history[name] = (tt[keep], xx[keep])
        return np.interp(t - delay_s, tt, xx, left=0.0)

    def step(self, n: int) -> RigBlock:
        """Advance by ``n`` samples and return them."""
        cfg, fin = self.config, self.fin
        events = []
        self._sequence()
        reason = self.drive.watchdog(self.t)
        if reason:
            events.append(reason)
        kn = self._update_knobs()
        events += self._events
        self._events.clear()
        dt = 1.0 / cfg.sample_rate_hz
        h_max = default_step(fin, self.drive.frequency_hz) / math.sqrt(max(float(kn.stiffness), 1.0))
        substeps = max(1, math.ceil(dt / h_max))
        h = dt / substeps
        k0 = self._k
        nodes = self._t0 + (k0 + np.arange(2 * substeps * n + 1) / (2 * substeps)) * dt
        v_nodes, dv_nodes, amp_nodes, bias_nodes = self.drive.render(nodes)
        if float(kn.voltage_scale) != 1.0:  # the amplifier sags: its whole output scaled
            v_nodes = v_nodes * float(kn.voltage_scale)
            dv_nodes = dv_nodes * float(kn.voltage_scale)
            bias_nodes = bias_nodes * float(kn.voltage_scale)
        if float(kn.voltage) < 1.0:  # the amplifier clips its swing: same fundamental as the model's drive
            r = clip_ratio(float(kn.voltage))
            swing = v_nodes - bias_nodes
            inside = np.abs(swing) < r * amp_nodes
            v_nodes = bias_nodes + np.clip(swing, -r * amp_nodes, r * amp_nodes)
            dv_nodes = np.where(inside, dv_nodes, 0.0)
        eta, deta = integrate_nodes(fin, v_nodes[None, :], h, substeps, self._state, kn)
        self._state = np.array([[eta[0, -1], deta[0, -1]]])
        self._k += n
        t = self._t0 + (k0 + np.arange(1, n + 1)) * dt
        v = v_nodes[2 * substeps :: 2 * substeps]
        dv = dv_nodes[2 * substeps :: 2 * substeps]
        eta_s, deta_s = eta[0, 1:], deta[0, 1:]
        tip = fin.phi_tip * deta_s
        cap = fin.C_eq * float(kn.capacitance)
        current = cap * dv + float(kn.loss_conductance) * v + fin.theta * float(kn.coupling) * deta_s
        U = float(kn.swim_speed) or (
            cfg.swim_speed_m_s if self.swim_speed_m_s is None else self.swim_speed_m_s
        )
        thrust = 0.5 * fin.m_v * float(kn.mass) * (tip**2 - U**2 * (fin.phi_tip_slope * eta_s) ** 2)
        reading = float(kn.thrust_gain) * thrust
        if kn.thrust_bias_n and self._knobs_at:
            # the offset the baselines miss comes with the burst: scaled by the drive's envelope
            on = np.minimum(amp_nodes[2 * substeps :: 2 * substeps] / (0.5 * self._knobs_at[1]), 1.0)
            reading = reading + float(kn.thrust_bias_n) * on
        force_filtered, self._lc_zi = signal.lfilter(self._lc_b, self._lc_a, reading, zi=self._lc_zi)
        x = force_filtered / cfg.loadcell_stiffness + cfg.loadcell_drift_m_per_s * (t - self._t0)
        rng = self._rng
        # the instruments (gains and lags of an augmented model's measurement chain)
        tip_read = float(kn.tip_gain) * self._lagged("tip", t, tip, float(kn.tip_delay_s))
        i_read = float(kn.current_gain) * self._lagged("current", t, current, float(kn.current_delay_s))
        return RigBlock(
            t=t,
            voltage=float(kn.voltage_gain) * v + cfg.voltage_noise_v * rng.standard_normal(n),
            current=i_read + cfg.current_noise_a * rng.standard_normal(n),
            tip_velocity=tip_read + cfg.vibrometer_noise_m_s * rng.standard_normal(n),
            displacement=x + cfg.displacement_noise_m * rng.standard_normal(n),
            thrust_true=thrust,
            events=tuple(events),
            applied_peak_v=float(np.max(np.abs(v))) if v.size else 0.0,
            supply_voltage=np.full(n, self.amplifier.supply_v),
            supply_current=self.amplifier.supply_current(v, current)
            + cfg.supply_noise_a * self._supply_rng.standard_normal(n),
        )
