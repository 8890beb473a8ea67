r"""Steady state under harmonic voltage: single-term harmonic balance, Eqs. (12)-(20).

Derivation (the paper's Eqs. 15-18, with Eq. 18 corrected)
-----------------------------------------------------------
With ``v = V cos wt``, ``eta = H0 cos wt + H1 sin wt`` and ``i = I0 cos wt + I1 sin wt``,
balancing the first harmonic of Eq. (9) (the fundamental of ``|x| x`` for ``x = X sin`` is
``8/(3 pi) X^2 sin``) gives, with ``A = sqrt(H0^2 + H1^2)``::

    (15)  a H0 + d(A) H1 = theta V          a    = wn^2 - (1 + mu) w^2
    (16)  a H1 - d(A) H0 = 0                d(A) = c0 + k A,  c0 = 2 zeta wn w,
                                            k    = 8/(3 pi) gamma w^2

and Eq. (10) gives the current::

    (17)  I0 = theta w H1
    (18)  I1 = -(C_eq w V + theta w H0)

Eq. (18) as printed reads ``I1 + C_eq w + theta w H0 = 0``: the voltage ``V`` is missing
(the term is ``C_eq dv/dt``), so we use the form that follows from Eq. (10).

Squaring and adding (15) and (16) gives one equation in ``A`` alone::

    f(A) = A^2 (a^2 + (c0 + k A)^2) - (theta V)^2
         = k^2 A^4 + 2 c0 k A^3 + (a^2 + c0^2) A^2 - (theta V)^2 = 0.

All coefficients are >= 0, so ``f`` increases strictly and is convex on ``A > 0``: the
positive root is unique and Newton's method started above it converges monotonically
(and quadratically).  Both ``theta V / sqrt(a^2 + c0^2)`` (drag ignored) and
``sqrt(theta V / k)`` (everything but drag ignored) are upper bounds, so their minimum is
the starting point.  Then ``H0 = theta V a / (a^2 + d^2)``, ``H1 = theta V d / (a^2 + d^2)``.
No iterative equation solver is needed, and the whole computation is array arithmetic,
vectorised over any broadcastable arrays of frequency and voltage.

Outputs
-------
Tip displacement ``w(L,t) = phi(L) eta``, RMS tip velocity ``w phi(L) A / sqrt 2``, RMS
current, mean electrical power ``mean(v i) = V I0 / 2`` (the capacitive current is
reactive, so this is the mechanical dissipation), Lighthill's mean thrust (19)-(20)::

    T = (1/2) m_v [ (w phi(L) A)^2 / 2  -  U^2 (phi'(L) A)^2 / 2 ],

thrust per watt ``T/P`` and the thrust coefficient of Eq. (22).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import PhysicsError
from ._compile import compiled_newton, njit
from .fin import Fin
from .knobs import Knobs
from .modeshape import phi_hat

FloatArray = NDArray[Any]  # float64 arrays (numpy's stubs are too strict for dtype=float)

#: First-harmonic factor of the quadratic drag: ``|sin| sin -> 8/(3 pi) sin``.
DRAG_HARMONIC = 8.0 / (3.0 * np.pi)


@dataclass(frozen=True)
class SteadyState:
    """Harmonic-balance steady state on a grid of operating points (arrays broadcast together).

    ``eta(t) = sum_k a_k cos(k w t) + b_k sin(k w t)`` over the odd harmonic ``orders``
    (``(1,)`` for the paper's single-term balance, where ``a_1 = H0`` and ``b_1 = H1``).
    Attributes are SI: ``frequency_hz`` (Hz), ``voltage_pp`` (V, peak to peak), ``a, b``
    (modal, m sqrt(kg); last axis = harmonic) and ``U`` (m/s), the swimming speed of Eq. (19).
    """

    fin: Fin
    frequency_hz: FloatArray
    voltage_pp: FloatArray
    a: FloatArray
    b: FloatArray
    U: FloatArray
    orders: tuple[int, ...] = (1,)

    @property
    def omega(self) -> FloatArray:
        return 2.0 * np.pi * self.frequency_hz

    @property
    def H0(self) -> FloatArray:
        """Cosine coefficient of the fundamental, Eq. (13)."""
        return self.a[..., 0]

    @property
    def H1(self) -> FloatArray:
        """Sine coefficient of the fundamental, Eq. (13)."""
        return self.b[..., 0]

    @property
    def I0(self) -> FloatArray:
        """Cosine coefficient of the fundamental current, Eq. (17)."""
        return self.fin.theta * self.omega * self.H1

    @property
    def I1(self) -> FloatArray:
        """Sine coefficient of the fundamental current, Eq. (18) with ``V`` restored."""
        return -(self.fin.C_eq * self.omega * 0.5 * self.voltage_pp + self.fin.theta * self.omega * self.H0)

    @property
    def modal_amplitude(self) -> FloatArray:
        """Fundamental amplitude ``A = sqrt(H0^2 + H1^2)``."""
        return np.hypot(self.H0, self.H1)

    def _mean_square(self, weights: FloatArray) -> FloatArray:
        return 0.5 * np.sum(weights * (self.a**2 + self.b**2), axis=-1)

    @property
    def tip_displacement_amplitude(self) -> FloatArray:
        """Amplitude of the fundamental of ``w(L, t)``, m."""
        return self.fin.phi_tip * self.modal_amplitude

    @property
    def tip_velocity_rms(self) -> FloatArray:
        """RMS of ``dw(L, t)/dt`` (all harmonics), m/s."""
        k2 = np.asarray(self.orders, float) ** 2
        return self.fin.phi_tip * self.omega * np.sqrt(self._mean_square(k2))

    @property
    def tip_phase(self) -> FloatArray:
        """Phase of the fundamental tip displacement relative to the voltage, rad (lag < 0)."""
        return np.arctan2(-self.H1, self.H0)

    @property
    def current_rms(self) -> FloatArray:
        """RMS drive current (capacitive plus motional, all harmonics), A."""
        k2 = np.asarray(self.orders, float) ** 2
        higher = self._mean_square(k2) - 0.5 * self.modal_amplitude**2
        motional_higher = (self.fin.theta * self.omega) ** 2 * higher
        return np.sqrt(0.5 * (self.I0**2 + self.I1**2) + motional_higher)

    @property
    def motional_current_rms(self) -> FloatArray:
        """RMS of ``theta deta/dt``, the part of the current that carries the motion, A."""
        k2 = np.asarray(self.orders, float) ** 2
        return self.fin.theta * self.omega * np.sqrt(self._mean_square(k2))

    @property
    def power_w(self) -> FloatArray:
        """Mean electrical power ``mean(v i) = V I0 / 2``, W (only the fundamental draws power)."""
        return 0.25 * self.voltage_pp * self.I0

    @property
    def thrust_n(self) -> FloatArray:
        """Lighthill mean thrust, Eqs. (19)-(20), N (negative when the ``U`` term dominates)."""
        fin = self.fin
        k2 = np.asarray(self.orders, float) ** 2
        ms_velocity = (self.omega * fin.phi_tip) ** 2 * self._mean_square(k2)
        ms_slope = fin.phi_tip_slope**2 * self._mean_square(np.ones_like(k2))
        return 0.5 * fin.m_v * (ms_velocity - self.U**2 * ms_slope)

    @property
    def thrust_per_watt(self) -> FloatArray:
        """Thrust over mean electrical power, N/W (0 where no power is drawn)."""
        p = self.power_w
        return np.divide(self.thrust_n, p, out=np.zeros(np.shape(p)), where=p > 0)

    @property
    def c_tau(self) -> FloatArray:
        """Thrust coefficient of Eq. (22), ``T / ((1/2) rho_w w^2 |w(L)|^2 b L)``.

        ``|w(L)|`` is the amplitude of the fundamental tip displacement.
        """
        fin = self.fin
        denom = 0.5 * fin.rho_w * self.omega**2 * self.tip_displacement_amplitude**2 * fin.b * fin.L
        return np.divide(self.thrust_n, denom, out=np.zeros(np.shape(denom)), where=denom > 0)

    def records(self) -> list[dict[str, float]]:
        """One record per operating point (flattened in C order), the keys of ``sweep --json``."""
        cols = {
            "frequency_hz": self.frequency_hz,
            "voltage_pp": self.voltage_pp,
            "tip_velocity_rms": self.tip_velocity_rms,
            "current_rms": self.current_rms,
            "power_w": self.power_w,
            "thrust_n": self.thrust_n,
            "thrust_per_watt": self.thrust_per_watt,
        }
        flat = {k: np.ravel(v) for k, v in cols.items()}
        return [{k: float(col[i]) for k, col in flat.items()} for i in range(flat["power_w"].size)]


def coefficients(
    fin: Fin, omega: FloatArray, knobs: Knobs | None = None
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``a, c0, k`` of the derivation above, with an effect's coefficient changes (``knobs``) applied."""
    wn = fin.omega_n
    if knobs is None:
        return (
            wn * wn - (1.0 + fin.mu) * omega * omega,
            2.0 * fin.zeta * wn * omega,
            DRAG_HARMONIC * fin.gamma * omega * omega,
        )
    a = wn * wn * knobs.stiffness - (1.0 + fin.mu * knobs.mass) * omega * omega
    c0 = 2.0 * fin.zeta * wn * omega * knobs.damping
    k = DRAG_HARMONIC * fin.gamma * knobs.drag * omega * omega
    return a, c0, k


def solve_amplitude(
    a: FloatArray,
    c0: FloatArray,
    k: FloatArray,
    force: FloatArray,
    max_iter: int = 60,
    guess: FloatArray | None = None,
) -> FloatArray:
    """Unique positive root ``A`` of ``A^2 (a^2 + (c0 + k A)^2) = force^2`` (Newton).

    All arguments broadcast; ``c0, k >= 0``.  Points with ``force == 0`` give ``A = 0``.  Newton
    starts from an upper bound of the root, or from ``guess`` (> 0) where it is below that bound: the
    quartic is convex and increasing for ``A > 0``, so from below the root the first step lands above
    it, and from above it converges monotonically.  A guess near the root (the previous amplitude of
    a fixed-point iteration) saves most of the iterations.
    """
    a, c0, k, force = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (a, c0, k, force)))
    force = np.abs(force)
    lin = np.hypot(a, c0)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound_lin = np.where(lin > 0, force / lin, np.inf)
        bound_drag = np.where(k > 0, np.sqrt(force / k), np.inf)
    amp = np.minimum(bound_lin, bound_drag)
    if not np.all(np.isfinite(amp)):
        raise PhysicsError("undamped operating point: zeta = c_d = 0 at resonance has no steady state")
    if guess is not None:
        g0 = np.broadcast_to(np.asarray(guess, dtype=float), amp.shape)
        amp = np.where(np.isfinite(g0) & (g0 > 0), np.minimum(g0, amp), amp)
    live = force > 0
    amp = np.where(live, amp, 0.0)
    aa = a * a
    if compiled_newton():
        out = np.array(amp, dtype=float)  # (a copy, C-ordered, of its shape: 0-d stays 0-d)
        flat = out.reshape(-1)  # (a view: the kernel writes into out)
        _newton_kernel(*(np.ravel(x) for x in (aa, c0, k, force, live)), flat, max_iter)
        return out
    for _ in range(max_iter):
        d = c0 + k * amp
        s = aa + d * d
        g = amp * amp * s - force * force
        gp = 2.0 * amp * (s + amp * d * k)
        step = np.divide(g, gp, out=np.zeros_like(g), where=live)
        amp = amp - step
        # Monotone convergence from above: stop once the last correction is at round-off.
        if not np.any(np.abs(step) > 1e-15 * amp):
            break
    return amp


@njit(cache=True, error_model="numpy")  # (a division by zero gives inf, as numpy's, not an exception)
def _newton_kernel(
    aa: FloatArray,
    c0: FloatArray,
    k: FloatArray,
    force: FloatArray,
    live: Any,
    amp: FloatArray,
    max_iter: int,
) -> None:  # pragma: no cover - compiled; solve_amplitude's loop, step for step and stopped as it stops
    for _ in range(max_iter):
        going = False
        for p in range(amp.size):
            step = 0.0
            if live[p]:
                d = c0[p] + k[p] * amp[p]
                s = aa[p] + d * d
                step = (amp[p] * amp[p] * s - force[p] * force[p]) / (2.0 * amp[p] * (s + amp[p] * d * k[p]))
            amp[p] = amp[p] - step
            if abs(step) > 1e-15 * amp[p]:
                going = True
        if not going:
            break


@njit(cache=True)
def _single_term_kernel(
    omega: FloatArray,
    force: FloatArray,
    wn: float,
    mass: float,
    zeta: float,
    gamma: float,
    h0: FloatArray,
    h1: FloatArray,
) -> None:  # pragma: no cover - compiled; same algorithm as solve_amplitude, point by point
    for p in range(omega.size):
        w = omega[p]
        F = abs(force[p])
        if F == 0.0:
            h0[p] = 0.0
            h1[p] = 0.0
            continue
        a = wn * wn - mass * w * w
        c0 = 2.0 * zeta * wn * w
        k = DRAG_HARMONIC * gamma * w * w
        lin = math.sqrt(a * a + c0 * c0)
        amp = F / lin if lin > 0.0 else math.inf
        if k > 0.0:
            amp = min(amp, math.sqrt(F / k))
        aa = a * a
        for _ in range(60):
            d = c0 + k * amp
            s = aa + d * d
            step = (amp * amp * s - F * F) / (2.0 * amp * (s + amp * d * k))
            amp -= step
            if abs(step) <= 1e-15 * amp:
                break
        d = c0 + k * amp
        s = aa + d * d
        h0[p] = force[p] * a / s
        h1[p] = force[p] * d / s


def harmonic_balance(
    fin: Fin,
    frequency_hz: ArrayLike,
    voltage_pp: ArrayLike,
    U: ArrayLike = 0.0,
    harmonics: int = 1,
    compiled: bool = True,
) -> SteadyState:
    """Steady state at every (frequency, peak-to-peak voltage) point.

    ``harmonics = 1`` is the paper's single-term balance, Eqs. (15)-(18), solved in closed
    form (above).  ``harmonics = n > 1`` keeps the odd harmonics ``1, 3, ..., 2n - 1``
    (:func:`refine_harmonics`): the quadratic drag makes the true periodic response
    non-sinusoidal, and near resonance at high voltage the single-term answer is off by
    up to ~2 % (see the README); three harmonics bring it below 1e-4.
    ``frequency_hz`` and ``voltage_pp`` broadcast (e.g. a column of frequencies against a
    row of voltages gives the whole map).  ``U`` is the swimming speed used in Eq. (19).
    ``compiled=False`` uses the numpy implementation (:func:`solve_amplitude`) instead of the
    numba loop; both run the same Newton iteration and agree to round-off.  The loop runs compiled
    only once a long computation asked for it (:func:`~._compile.compiled_newton`): loading numba
    costs 0.75 s, and numpy solves a sweep of ten thousand points in milliseconds.
    """
    if harmonics < 1:
        raise PhysicsError(f"harmonics must be >= 1, got {harmonics}")
    f = np.asarray(frequency_hz, dtype=float)
    vpp = np.asarray(voltage_pp, dtype=float)
    if np.any(~np.isfinite(f)) or np.any(f <= 0):
        raise PhysicsError("frequencies must be finite and > 0 Hz")
    if np.any(~np.isfinite(vpp)) or np.any(vpp < 0):
        raise PhysicsError("peak-to-peak voltages must be finite and >= 0 V")
    f, vpp = np.broadcast_arrays(f, vpp)
    omega = 2.0 * np.pi * f
    amp_v = 0.5 * vpp
    force = fin.theta * amp_v
    if compiled and compiled_newton():
        h0, h1 = np.empty(f.shape), np.empty(f.shape)  # Fin validation guarantees zeta > 0
        _single_term_kernel(
            np.ravel(omega),
            np.ravel(force),
            fin.omega_n,
            1.0 + fin.mu,
            fin.zeta,
            fin.gamma,
            h0.reshape(-1),
            h1.reshape(-1),
        )
    else:
        a, c0, k = coefficients(fin, omega)
        amp = solve_amplitude(a, c0, k, force)
        d = c0 + k * amp
        s = a * a + d * d
        with np.errstate(invalid="ignore", divide="ignore"):
            h0 = np.where(force > 0, force * a / s, 0.0)
            h1 = np.where(force > 0, force * d / s, 0.0)
    u = np.broadcast_to(np.asarray(U, dtype=float), f.shape)
    state = SteadyState(fin, f, vpp, h0[..., None], h1[..., None], u)
    if harmonics == 1:
        return state
    return refine_harmonics(state, harmonics)


def residuals(fin: Fin, state: SteadyState) -> FloatArray:
    """Residuals of Eqs. (15)-(18) (Eq. 18 with the voltage restored), stacked on axis 0.

    Each row is scaled by its natural size (``theta V`` for the mechanical pair,
    ``C_eq w V`` for the electrical pair), so round-off level is ~1e-16.
    """
    w = state.omega
    if state.orders != (1,):
        raise PhysicsError("Eqs. (15)-(18) are the single-term balance; got harmonics " + str(state.orders))
    V = 0.5 * state.voltage_pp
    H0, H1, I0, I1 = state.H0, state.H1, state.I0, state.I1
    damp = 2 * fin.zeta * fin.omega_n + DRAG_HARMONIC * fin.gamma * w * np.hypot(H0, H1)
    r15 = -(1 + fin.mu) * w**2 * H0 + damp * w * H1 + fin.omega_n**2 * H0 - fin.theta * V
    r16 = -(1 + fin.mu) * w**2 * H1 - damp * w * H0 + fin.omega_n**2 * H1
    r17 = -I0 + fin.theta * w * H1
    r18 = I1 + fin.C_eq * w * V + fin.theta * w * H0
    mech = np.where(V > 0, fin.theta * V, 1.0)
    elec = np.where(V > 0, fin.C_eq * w * V, 1.0)
    return np.stack([r15 / mech, r16 / mech, r17 / elec, r18 / elec])


def harmonic_balance_fsolve(fin: Fin, frequency_hz: ArrayLike, voltage_pp: ArrayLike) -> SteadyState:
    """Reference solver: Eqs. (15)-(18) point by point with ``scipy.optimize.fsolve``.

    This is how the paper solved them (MATLAB's ``solve``, trust-region dogleg); it is
    kept as the baseline of the speed benchmark and as an independent check in the tests.
    """
    from scipy import optimize  # (here: the nodes import this module, and not scipy's 45 MB)

    f, vpp = np.broadcast_arrays(np.asarray(frequency_hz, float), np.asarray(voltage_pp, float))
    out = np.zeros((2, *f.shape))
    wn2 = fin.omega_n**2
    for idx in np.ndindex(f.shape):
        w = float(2 * np.pi * f[idx])
        V = float(0.5 * vpp[idx])
        F = fin.theta * V
        # Unknowns in units of an a-priori amplitude (the smaller of the drag-free and the
        # drag-only bounds), started from the drag-free solution's phase.
        z = complex(wn2 - (1 + fin.mu) * w**2, 2 * fin.zeta * fin.omega_n * w)
        k = float(DRAG_HARMONIC * fin.gamma * w)
        bound_drag = np.sqrt(F / (k * w)) if k > 0 else np.inf
        scale = float(min(F / abs(z), bound_drag)) if F > 0 else 1.0

        def eqs(x: FloatArray, w: float = w, F: float = F, scale: float = scale, k: float = k) -> list[float]:
            h0, h1 = x * scale
            damp = 2 * fin.zeta * fin.omega_n + k * np.hypot(h0, h1)
            r15 = -(1 + fin.mu) * w**2 * h0 + damp * w * h1 + wn2 * h0 - F
            r16 = -(1 + fin.mu) * w**2 * h1 - damp * w * h0 + wn2 * h1
            return [r15 / max(F, 1e-300), r16 / max(F, 1e-300)]

        x0 = np.array([z.real, z.imag]) / abs(z) if F > 0 else np.zeros(2)
        x, _, ier, _ = optimize.fsolve(eqs, x0, xtol=1e-12, full_output=True)
        if ier != 1 and np.max(np.abs(eqs(x))) > 1e-10:
            raise PhysicsError(f"fsolve did not converge at {f[idx]} Hz, {vpp[idx]} Vpp")
        h0, h1 = x * scale  # Eqs. (17)-(18) are explicit in the currents once H0, H1 are known.
        out[(slice(None), *idx)] = (h0, h1)
    return SteadyState(fin, f, vpp, out[0][..., None], out[1][..., None], np.zeros(f.shape))


def refine_harmonics(
    state: SteadyState, harmonics: int, samples: int = 128, max_iter: int = 30
) -> SteadyState:
    """Multi-harmonic balance of Eq. (9) (odd harmonics ``1 .. 2n-1``), started from ``state``.

    Alternating frequency-time scheme: the drag ``gamma |eta'| eta'`` is evaluated on
    ``samples`` points per period, projected on the harmonics, and Newton's method (with the
    exact Jacobian ``2 gamma |eta'|`` projected the same way) drives the harmonic residuals
    to zero.  Vectorised over all operating points (batched ``numpy.linalg.solve``).
    """
    fin = state.fin
    shape = state.frequency_hz.shape
    orders = np.arange(1, 2 * harmonics, 2)
    m = orders.size
    w = state.omega.reshape(-1, 1)  # (P, 1)
    force = (fin.theta * 0.5 * state.voltage_pp).reshape(-1)
    n_pts = w.shape[0]
    phase = 2 * np.pi * np.arange(samples) / samples
    cos_k = np.cos(np.outer(orders, phase))  # (m, N)
    sin_k = np.sin(np.outer(orders, phase))
    kw = orders[None, :] * w  # (P, m)
    stiff = fin.omega_n**2 - (1 + fin.mu) * kw**2  # (P, m)
    c_lin = 2 * fin.zeta * fin.omega_n
    x = np.zeros((n_pts, 2 * m))
    x[:, 0] = state.H0.reshape(-1)
    x[:, m] = state.H1.reshape(-1)
    # Velocity basis: eta' = sum_k kw (b_k cos - a_k sin) -> d eta'/d a_k, d eta'/d b_k.
    dv_da = -kw[:, :, None] * sin_k[None]  # (P, m, N)
    dv_db = kw[:, :, None] * cos_k[None]
    dv = np.concatenate([dv_da, dv_db], axis=1)  # (P, 2m, N)
    proj = np.concatenate([cos_k, sin_k]) * (2.0 / samples)  # (2m, N)
    for _ in range(max_iter):
        vel = np.einsum("pj,pjn->pn", x, dv)
        drag = fin.gamma * np.abs(vel) * vel
        a_c, b_s = x[:, :m], x[:, m:]
        lin_c = stiff * a_c + c_lin * kw * b_s
        lin_s = stiff * b_s - c_lin * kw * a_c
        res = np.concatenate([lin_c, lin_s], axis=1) + drag @ proj.T
        res[:, 0] -= force
        jac_drag = np.einsum("in,pn,pjn->pij", proj, 2 * fin.gamma * np.abs(vel), dv)
        jac = np.zeros((n_pts, 2 * m, 2 * m))
        idx = np.arange(m)
        jac[:, idx, idx] = stiff
        jac[:, idx, m + idx] = c_lin * kw
        jac[:, m + idx, m + idx] = stiff
        jac[:, m + idx, idx] = -c_lin * kw
        jac += jac_drag
        step = np.linalg.solve(jac, res[..., None])[..., 0]
        x -= step
        scale = np.maximum(np.abs(x).max(axis=1), 1e-300)
        if np.all(np.abs(step).max(axis=1) <= 1e-13 * scale):
            break
    a = x[:, :m].reshape((*shape, m))
    b = x[:, m:].reshape((*shape, m))
    orders_t = tuple(int(k) for k in orders)
    return SteadyState(fin, state.frequency_hz, state.voltage_pp, a, b, state.U, orders_t)


def frf_in_air(fin: Fin, frequency_hz: ArrayLike, x: float | None = None) -> NDArray[np.complex128]:
    """Displacement FRF ``alpha(w, x) = theta phi(x) / (wn^2 - w^2 + 2j zeta wn w)``, Eq. (11), m/V."""
    w = 2 * np.pi * np.asarray(frequency_hz, dtype=float)
    xi = 1.0 if x is None else x / fin.L
    phi = float(phi_hat(xi)) / np.sqrt(fin.m_s * fin.L)
    return fin.theta * phi / (fin.omega_n**2 - w**2 + 2j * fin.zeta * fin.omega_n * w)
