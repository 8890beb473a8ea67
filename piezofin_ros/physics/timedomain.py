"""Time-domain engine: Eqs. (9)-(10) integrated for an arbitrary drive-voltage waveform.

State ``(eta, deta/dt)`` of the modal equation (9)::

    (1 + mu) eta'' + (2 zeta wn + gamma |eta'|) eta' + wn^2 eta = theta v(t)

is advanced by the classical fourth-order Runge-Kutta method with a fixed step ``h`` (an
integer number of sub-steps per output sample, so the output grid is exact and the
waveform is sampled once, vectorised, at every stage time).  The loop is compiled with
numba when it is installed (it falls back to plain Python, ~100x slower, when not).  The
outputs follow from the state without further integration:

* tip displacement and velocity ``w(L,t) = phi(L) eta``, ``w_t(L,t) = phi(L) eta'``;
* drive current, Eq. (10): ``i = C_eq dv/dt + theta eta'`` (``dv/dt`` from the waveform);
* instantaneous Lighthill thrust, Eq. (19): ``(1/2) m_v (w_t^2 - U^2 w_x^2)`` at ``x = L``,
  whose mean over a quasi-steady window is the paper's mean thrust.

Why fixed-step RK4: the problem is not stiff (the fastest rate is the in-vacuo
``wn``, a few hundred rad/s, or the drag rate ``2 gamma |eta'|/(1 + mu)``), the output
is wanted on a uniform grid anyway, and a fixed step makes the cost predictable for a
live simulator.  ``default_step`` keeps ``h`` at or below 1/60 of the shortest period
involved, where the RK4 error of the statistics the suite uses is below 1e-6 relative
(checked against ``scipy.integrate.solve_ivp`` in the tests and the benchmark).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError
from ._compile import njit
from .fin import Fin
from .knobs import Knobs
from .waveforms import Waveform

FloatArray = NDArray[Any]  # float64 arrays (numpy's stubs are too strict for dtype=float)


@njit(cache=True)
def _rk4_batch(
    v_nodes: FloatArray,  # (n_trials, 2 * n_steps + 1): v at every half step
    h: float,
    substeps: int,
    inv_mass: float,
    c_lin: float,
    gam: float,
    wn2: float,
    theta: float,
    state0: FloatArray,  # (n_trials, 2)
    eta_out: FloatArray,  # (n_trials, n_out)
    deta_out: FloatArray,  # (n_trials, n_out)
) -> None:
    n_trials, n_out = eta_out.shape
    half = 0.5 * h
    for trial in range(n_trials):
        x = state0[trial, 0]
        y = state0[trial, 1]
        eta_out[trial, 0] = x
        deta_out[trial, 0] = y
        node = 0
        for k in range(1, n_out):
            for _ in range(substeps):
                f0 = theta * v_nodes[trial, node]
                fm = theta * v_nodes[trial, node + 1]
                f1 = theta * v_nodes[trial, node + 2]
                k1x = y
                k1y = (f0 - (c_lin + gam * abs(y)) * y - wn2 * x) * inv_mass
                y2 = y + half * k1y
                k2x = y2
                k2y = (fm - (c_lin + gam * abs(y2)) * y2 - wn2 * (x + half * k1x)) * inv_mass
                y3 = y + half * k2y
                k3x = y3
                k3y = (fm - (c_lin + gam * abs(y3)) * y3 - wn2 * (x + half * k2x)) * inv_mass
                y4 = y + h * k3y
                k4x = y4
                k4y = (f1 - (c_lin + gam * abs(y4)) * y4 - wn2 * (x + h * k3x)) * inv_mass
                x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
                y += h / 6.0 * (k1y + 2.0 * k2y + 2.0 * k3y + k4y)
                node += 2
            eta_out[trial, k] = x
            deta_out[trial, k] = y


@dataclass(frozen=True)
class WindowStats:
    """Quasi-steady statistics of one window (what the paper extracts per operating point)."""

    t_start: float
    t_end: float
    tip_velocity_rms: float  # m/s
    current_rms: float  # A
    power_w: float  # W, mean(v i)
    thrust_n: float  # N, mean Lighthill thrust


@dataclass(frozen=True)
class Trajectory:
    """Sampled response of one trial (uniform grid ``t``, SI units)."""

    fin: Fin
    t: FloatArray
    voltage: FloatArray
    voltage_rate: FloatArray
    eta: FloatArray
    eta_dot: FloatArray
    U: float = 0.0

    @property
    def tip_displacement(self) -> FloatArray:
        return self.fin.phi_tip * self.eta

    @property
    def tip_velocity(self) -> FloatArray:
        return self.fin.phi_tip * self.eta_dot

    @property
    def current(self) -> FloatArray:
        """Drive current, Eq. (10), A."""
        return self.fin.C_eq * self.voltage_rate + self.fin.theta * self.eta_dot

    @property
    def motional_current(self) -> FloatArray:
        """``theta deta/dt = i - C_eq dv/dt``: the part of the current that carries the motion."""
        return self.fin.theta * self.eta_dot

    @property
    def thrust(self) -> FloatArray:
        """Instantaneous Lighthill thrust, Eq. (19) before averaging, N."""
        fin = self.fin
        slope = fin.phi_tip_slope * self.eta
        return 0.5 * fin.m_v * (self.tip_velocity**2 - self.U**2 * slope**2)

    def window(self, t_start: float, t_end: float) -> WindowStats:
        """Statistics over ``t_start <= t < t_end``.

        Choose a whole number of drive periods: otherwise the reactive power
        ``C_eq v dv/dt`` (often far larger than the real power) does not average out of
        ``mean(v i)``.
        """
        sel = (self.t >= t_start) & (self.t < t_end)
        if not np.any(sel):
            raise PhysicsError(f"window [{t_start}, {t_end}) holds no sample")
        v = self.voltage[sel]
        i = self.current[sel]
        return WindowStats(
            t_start,
            t_end,
            float(np.sqrt(np.mean(self.tip_velocity[sel] ** 2))),
            float(np.sqrt(np.mean(i**2))),
            float(np.mean(v * i)),
            float(np.mean(self.thrust[sel])),
        )


def integrate_nodes(
    fin: Fin,
    v_nodes: FloatArray,
    h: float,
    substeps: int,
    state0: FloatArray,
    knobs: Knobs | None = None,
) -> tuple[FloatArray, FloatArray]:
    """RK4 of Eq. (9) from ``state0`` (``(n, 2)``) over voltages given at every half step.

    ``v_nodes`` is ``(n, 2 * substeps * (n_out - 1) + 1)``; returns ``eta`` and ``deta/dt`` at the
    ``n_out`` output samples (the first is ``state0``).  Shared by :func:`simulate_batch` and the
    streaming rig, which calls it block by block with the state carried over.  ``knobs`` scale the
    coefficients (stiffness, added mass, damping, drag, coupling; see :mod:`piezofin_ros.physics.knobs`).
    """
    k = knobs or Knobs()
    n, n_nodes = v_nodes.shape
    n_out = (n_nodes - 1) // (2 * substeps) + 1
    eta = np.empty((n, n_out))
    deta = np.empty((n, n_out))
    _rk4_batch(
        v_nodes,
        h,
        substeps,
        1.0 / (1.0 + fin.mu * float(k.mass)),
        2.0 * fin.zeta * fin.omega_n * float(k.damping),
        fin.gamma * float(k.drag),
        fin.omega_n**2 * float(k.stiffness),
        fin.theta * float(k.coupling),
        np.ascontiguousarray(state0, dtype=float),
        eta,
        deta,
    )
    return eta, deta


def default_step(fin: Fin, max_drive_hz: float = 0.0) -> float:
    """Largest step (s) that keeps 60 steps per shortest period (free vibration or drive)."""
    f_fast = max(fin.f_water_linear, fin.f_sc if fin.rho_w == 0 else 0.0, max_drive_hz)
    return 1.0 / (60.0 * f_fast)


def simulate_batch(
    fin: Fin,
    waveforms: Sequence[Waveform],
    duration: float,
    rate_hz: float = 2000.0,
    *,
    t0: float = 0.0,
    initial_state: FloatArray | None = None,
    max_step: float | None = None,
    U: float = 0.0,
) -> list[Trajectory]:
    """Integrate Eq. (9) for several waveforms on the same fin, as one compiled loop.

    Output samples are at ``t0 + k / rate_hz`` for ``k = 0 .. round(duration * rate_hz)``.
    ``initial_state`` is ``(n, 2)`` (``eta``, ``deta/dt``) or None for rest.
    """
    if not (math.isfinite(duration) and duration > 0):
        raise PhysicsError(f"duration must be finite and > 0 s, got {duration}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise PhysicsError(f"rate must be finite and > 0 Hz, got {rate_hz}")
    n_out = round(duration * rate_hz) + 1
    dt = 1.0 / rate_hz
    drive_hz = max((getattr(w, "frequency_hz", 0.0) for w in waveforms), default=0.0)
    h_max = default_step(fin, drive_hz) if max_step is None else max_step
    substeps = max(1, math.ceil(dt / h_max))
    h = dt / substeps
    n_nodes = 2 * substeps * (n_out - 1) + 1
    t_nodes = t0 + np.arange(n_nodes) * (0.5 * h)
    v_nodes = np.stack([np.asarray(w.value(t_nodes), dtype=float) for w in waveforms])
    n = len(waveforms)
    state0 = np.zeros((n, 2)) if initial_state is None else np.asarray(initial_state, float).reshape(n, 2)
    eta, deta = integrate_nodes(fin, v_nodes, h, substeps, state0)
    t = t_nodes[:: 2 * substeps]
    return [
        Trajectory(
            fin, t, v_nodes[j, :: 2 * substeps].copy(), np.asarray(w.derivative(t), float), eta[j], deta[j], U
        )
        for j, w in enumerate(waveforms)
    ]


def simulate(
    fin: Fin,
    waveform: Waveform,
    duration: float,
    rate_hz: float = 2000.0,
    **kwargs: object,
) -> Trajectory:
    """Integrate Eq. (9)-(10) for one waveform; see :func:`simulate_batch`."""
    return simulate_batch(fin, [waveform], duration, rate_hz, **kwargs)[0]  # type: ignore[arg-type]


# --- the time-domain law of a model with effects (sine drive, one trial per operating point) ----
@njit(cache=True)
def _rk4_law(
    f_hz: FloatArray,  # (n,)
    v_amp: FloatArray,  # (n,) voltage amplitude
    v_clip: FloatArray,  # (n,) the drive clips at +-this (inf: never)
    mass0: FloatArray,  # (n,) 1 + mu M
    mass_kc: FloatArray,  # (n,) mu M M_kc: the added mass per unit KC
    mass_kc2: FloatArray,  # (n,) mu M M_kc2: the added mass per unit KC^2
    wn2: FloatArray,  # (n,) wn^2 S
    k3: FloatArray,  # (n,) wn^2 S c3
    c_lin: FloatArray,  # (n,) 2 zeta wn D
    c_abs: FloatArray,  # (n,) 2 zeta wn D c_abs
    gam: FloatArray,  # (n,) gamma G
    drag_n: FloatArray,  # (n,) drag ~ KC^-n
    theta: FloatArray,  # (n,) theta Q
    kc_per_eta: float,  # KC per unit modal amplitude: 2 pi phi / b
    h: float,
    substeps: int,
    n_out: int,
    eta_out: FloatArray,
    deta_out: FloatArray,
    v_out: FloatArray,
) -> None:  # pragma: no cover - compiled
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
                    mass = mass0[j] + (mass_kc[j] + mass_kc2[j] * kc) * kc
                    drag = gam[j]
                    if drag_n[j] != 0.0:
                        drag = drag * max(kc, 1e-3) ** (-drag_n[j])
                    force = (
                        theta[j] * v
                        - (c_lin[j] + c_abs[j] * abs(xx) + drag * abs(yy)) * yy
                        - wn2[j] * xx
                        - k3[j] * xx**3
                    )
                    ax[stage] = yy
                    ay[stage] = force / mass
                x += h / 6.0 * (ax[0] + 2.0 * ax[1] + 2.0 * ax[2] + ax[3])
                y += h / 6.0 * (ay[0] + 2.0 * ay[1] + 2.0 * ay[2] + ay[3])
                t += h


@dataclass(frozen=True)
class LawRun:
    """Sampled trials of :func:`simulate_law`: one row per operating point (SI units)."""

    t: FloatArray  # (n_out,)
    voltage: FloatArray  # (n, n_out), the drive the fin receives (clipped), as its monitor reads it
    eta: FloatArray
    eta_dot: FloatArray
    current: FloatArray  # as the current monitor reads it
    tip_velocity: FloatArray  # as the vibrometer reads it
    thrust: FloatArray  # instantaneous Lighthill thrust with the law's added mass, N
    loadcell_thrust: FloatArray  # through the transducer law (gain, bias), N


def simulate_law(
    fin: Fin,
    law: Any,
    frequency_hz: ArrayLike,
    voltage_pp: ArrayLike,
    duration: float = 10.0,
    rate_hz: float = 1000.0,
) -> LawRun:
    """Each operating point driven by a sine from rest for ``duration`` with the effects' laws.

    ``law`` is a :class:`~piezofin_ros.physics.effects.TimeLaw` (``model.law(f, v)``), its fields
    floats or arrays over the points.  Fixed-step RK4 (60 steps per shortest period), compiled.
    """
    fb, vb = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
    f, vpp = fb.ravel(), vb.ravel()
    n = f.size

    def col(x: Any) -> FloatArray:
        return np.ascontiguousarray(np.broadcast_to(np.asarray(x, float), (n,)), dtype=float)

    c_lin = 2 * fin.zeta * fin.omega_n * col(law.damping)
    wn2 = fin.omega_n**2 * col(law.stiffness)
    added = fin.mu * col(law.mass)
    theta = fin.theta * col(law.coupling)
    kc_per_eta = 2 * math.pi * fin.phi_tip / fin.b
    n_out = int(duration * rate_hz) + 1
    f_fast = max(fin.f_water_linear * 1.2, float(np.max(f)))
    substeps = max(1, math.ceil(60 * f_fast / rate_hz))
    h = 1.0 / (rate_hz * substeps)
    eta = np.empty((n, n_out))
    deta = np.empty((n, n_out))
    v = np.empty((n, n_out))
    _rk4_law(
        f,
        0.5 * vpp * col(law.voltage_scale),
        col(law.voltage_clip),
        1.0 + added,
        added * col(law.mass_kc),
        added * col(law.mass_kc2),
        wn2,
        wn2 * col(law.c3),
        c_lin,
        c_lin * col(law.c_abs),
        fin.gamma * col(law.drag),
        col(law.drag_n),
        theta,
        kc_per_eta,
        h,
        substeps,
        n_out,
        eta,
        deta,
        v,
    )
    t = np.arange(n_out) / rate_hz
    vdot = np.asarray(np.gradient(v, t, axis=1))
    cap = fin.C_eq * col(law.capacitance)[:, None]
    current = cap * vdot + col(law.loss_conductance)[:, None] * v + theta[:, None] * deta
    tip = fin.phi_tip * deta
    kc = kc_per_eta * np.sqrt(eta**2 + (deta / (2 * math.pi * f[:, None])) ** 2)
    mv_t = (
        fin.m_v
        * col(law.mass)[:, None]
        * (1 + (col(law.mass_kc)[:, None] + col(law.mass_kc2)[:, None] * kc) * kc)
    )
    U = col(law.swim_speed)[:, None]
    thrust = 0.5 * mv_t * (tip**2 - U**2 * (fin.phi_tip_slope * eta) ** 2)
    loadcell = col(law.thrust_gain)[:, None] * thrust + col(law.thrust_bias_n)[:, None]
    # the instruments: each channel's gain and delay (a reading at t is the signal at t - delay)
    v_read = col(law.voltage_gain)[:, None] * v
    tip_read = col(law.tip_gain)[:, None] * _delayed(t, tip, col(law.tip_delay_s))
    i_read = col(law.current_gain)[:, None] * _delayed(t, current, col(law.current_delay_s))
    return LawRun(t, v_read, eta, deta, i_read, tip_read, thrust, loadcell)


def _delayed(t: FloatArray, x: FloatArray, delay: FloatArray) -> FloatArray:
    """Each row of ``x`` read ``delay`` (s) late, by linear interpolation (0 before the start)."""
    if not np.any(delay):
        return x
    return np.stack([np.interp(t - d, t, row, left=0.0) for row, d in zip(x, delay, strict=True)])
