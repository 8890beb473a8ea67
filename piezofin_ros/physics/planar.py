r"""A fish in the plane: surge, sway and yaw, and the two ways its MFC fins can turn it.

**The body.**  Body axes ``x`` forward and ``y`` to port, the yaw rate ``r`` to port; a rigid body of
mass ``m`` with diagonal added mass (``m_x`` in surge, the :class:`~.swim.Body`'s; ``m_y`` in sway;
``I_a`` in yaw), moving at ``(u, v, r)`` under the fins' force ``(X, Y)`` and moment ``N``:

.. math::

    (m + m_x)\,\dot u &= X - D(u) + (m + m_y)\,v\,r \\
    (m + m_y)\,\dot v &= Y - D_y(v) - (m + m_x)\,u\,r \\
    (I + I_a)\,\dot r &= N - N_r(r)

``D`` is the body's surge drag law (:meth:`.swim.Body.drag_n`).  Sideways the body is resisted by
cross-flow drag on its lateral area (``C_y S_y``: a flat side, ``C_y`` about 1, Hoerner's *Fluid-Dynamic
Drag* ch. 3): a strip at ``x`` moves sideways at ``v + x r``, so for a body of length ``L``

.. math::

    D_y(v) = \tfrac12\rho\,C_y S_y\,v|v|, \qquad
    N_r(r) = \frac{\rho\,C_y S_y L^3}{64}\,r|r| + \tfrac12\rho\,U S_f C_{L\alpha}\,x_f^2\,r,

the first term the strip integral ``int_{-L/2}^{L/2} x (x r)|x r| dx`` times ``rho C_y S_y / 2L``
(the side's area taken as spread evenly along it),
the second the fin's own lift against the sideways flow ``x_f r`` it meets at the lever arm ``x_f``
aft of the centre of mass (a low aspect-ratio plate: ``C_La = pi AR / 2``, Jones's slender-wing
lift, ``AR = b / L_fin``).  The steady yaw rate under a moment ``N`` is the positive root of that
quadratic (:meth:`PlanarBody.steady_yaw_rate`), the turning radius at the speed ``U`` is ``U / r``.

**What turns it.**

* *A bias*: a DC offset ``V_0`` on the drive bends the fin statically; from the paper's modal
  equation (9) the modal coordinate is ``eta_0 = theta V_0 / omega_n^2`` (water adds mass, not
  stiffness) and the tip turns by ``alpha = phi'(L) eta_0`` (:func:`bias_tilt_rad`).  The mean thrust
  turns with the tip, and the tip meets the flow at ``alpha``: a side force ``(T_0 + q S_f C_La)
  alpha`` at the lever arm.  The P1 MFC is rated from -500 V to +1500 V (Smart Material, *MFC
  engineering properties*, ``Vmin``/``Vmax`` for d33 P1), so a drive of ``V_pp`` peak to peak may
  carry a bias from ``-500 + V_pp/2`` to ``1500 - V_pp/2`` (:func:`bias_window_v`): the window is
  not symmetric.
* *Two fins* ``d`` apart, side by side: ``N = (T_port - T_starboard) d / 2``.

Left out, to first order: the hull's Munk moment ``(m_y - m_x) u v`` and its own lift in sway (a
turn's drift angle is small at these rates), and the fin's beat in its lift (quasi-steady, averaged
over a stroke).  The figures are a fish's first estimate, not a measured one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..config import HARD_VOLTAGE_WINDOW_V
from .fin import Fin
from .swim import Body, SwimError

#: The P1 (d33) MFC's rated voltage, V (Smart Material's engineering properties: Vmin, Vmax).
MFC_P1_WINDOW_V = HARD_VOLTAGE_WINDOW_V


@dataclass(frozen=True)
class PlanarBody:
    """A fish's body in surge (``surge``), sway and yaw; SI units, every field checked."""

    surge: Body
    sway_added_mass_kg: float
    lateral_drag_area_m2: float  # C_y S_y
    yaw_inertia_kg_m2: float
    yaw_added_inertia_kg_m2: float
    fin_lever_m: float  # from the centre of mass aft to the fin's centre of force
    fin_spacing_m: float = 0.0  # two fins side by side this far apart (0: one fin)

    def __post_init__(self) -> None:
        for name in ("sway_added_mass_kg", "lateral_drag_area_m2", "yaw_inertia_kg_m2", "fin_lever_m"):
            x = getattr(self, name)
            if not (math.isfinite(x) and x > 0):
                raise SwimError(f"{self.surge.name}: {name} = {x!r} must be finite and > 0")
        for name in ("yaw_added_inertia_kg_m2", "fin_spacing_m"):
            x = getattr(self, name)
            if not (math.isfinite(x) and x >= 0):
                raise SwimError(f"{self.surge.name}: {name} = {x!r} must be finite and >= 0")

    # The laws and their closed forms, side by side (tested against each other).
    @property
    def yaw_drag_n_m_s2(self) -> float:
        """The cross-flow drag's yaw coefficient ``rho C_y S_y L^3 / 64``, N m s^2."""
        return self.surge.rho_w * self.lateral_drag_area_m2 * self.surge.length_m**3 / 64.0

    def sway_drag_n(self, v: float) -> float:
        """``D_y(v) = (1/2) rho C_y S_y v|v|``, N."""
        return 0.5 * self.surge.rho_w * self.lateral_drag_area_m2 * v * abs(v)

    def yaw_damping_nm(self, r: float, linear_n_m_s: float = 0.0) -> float:
        """``N_r(r) = rho C_y S_y L^3 r|r| / 64 + k r``, N m: the body's cross-flow drag in yaw and a
        linear term ``k`` (the fin's lift at a swimming speed, :func:`fin_yaw_damping`)."""
        return self.yaw_drag_n_m_s2 * r * abs(r) + linear_n_m_s * r

    def steady_yaw_rate(self, moment_nm: float, linear_n_m_s: float = 0.0) -> float:
        """The yaw rate at which ``N_r`` balances ``moment_nm``, rad/s (its sign): the positive root of
        ``a r^2 + k r = |N|``."""
        a = self.yaw_drag_n_m_s2
        n = abs(moment_nm)
        k = linear_n_m_s
        # (the root as 2n / (k + sqrt(k^2 + 4an)): no cancellation as a -> 0, and the square root's
        # terms scaled apart, so that neither underflows for the least moments)
        r = 2.0 * n / (k + math.hypot(k, 2.0 * math.sqrt(a) * math.sqrt(n))) if n > 0 else 0.0
        return math.copysign(r, moment_nm)

    def yaw_time_constant_s(self, r: float, linear_n_m_s: float = 0.0) -> float:
        """How fast a yaw-rate step settles about ``r``: ``(I + I_a) / N_r'(r)``, s."""
        inertia = self.yaw_inertia_kg_m2 + self.yaw_added_inertia_kg_m2
        return inertia / (2.0 * self.yaw_drag_n_m_s2 * abs(r) + linear_n_m_s)

    def derivatives(
        self,
        state: tuple[float, ...],
        force_n: tuple[float, float],
        moment_nm: float,
        linear_n_m_s: float = 0.0,
    ) -> tuple[float, ...]:
        """``d/dt (x, y, psi, u, v, r)`` in the earth frame's position and heading, the body's
        velocities: the equations of the module docstring (``linear_n_m_s``, the fin's yaw damping,
        as :func:`fin_yaw_damping` gives it at the speed of the turn: held, not rescaled with ``u``)."""
        _, _, psi, u, v, r = state
        b, m = self.surge, self.surge.mass_kg
        mx, my = m + b.added_mass_kg, m + self.sway_added_mass_kg
        du = (force_n[0] - float(b.drag_n(u)) + my * v * r) / mx
        dv = (force_n[1] - self.sway_drag_n(v) - mx * u * r) / my
        dr = (moment_nm - self.yaw_damping_nm(r, linear_n_m_s)) / (
            self.yaw_inertia_kg_m2 + self.yaw_added_inertia_kg_m2
        )
        c, s = math.cos(psi), math.sin(psi)
        return (u * c - v * s, u * s + v * c, r, du, dv, dr)


def fin_lift_slope(fin: Fin) -> float:
    """``C_La = pi AR / 2`` of the fin as a low aspect-ratio plate (span ``b``, chord ``L``), 1/rad."""
    return math.pi * (fin.b / fin.L) / 2.0


def fin_yaw_damping(body: PlanarBody, fin: Fin, speed_m_s: float, fins: int = 1) -> float:
    """The fins' linear yaw damping at a swimming speed, ``(1/2) rho U S_f C_La x_f^2`` each, N m s."""
    return fins * 0.5 * fin.rho_w * abs(speed_m_s) * fin.L * fin.b * fin_lift_slope(fin) * body.fin_lever_m**2


def bias_tilt_rad(fin: Fin, bias_v: float) -> float:
    """The fin tip's static turn under a DC offset ``bias_v`` (Eq. 9 at rest): ``phi'(L) theta V_0 /
    omega_n^2``, rad (positive with the offset)."""
    return abs(fin.phi_tip_slope) * fin.theta * bias_v / fin.omega_n**2


def bias_window_v(voltage_pp: float, window_v: tuple[float, float] = MFC_P1_WINDOW_V) -> tuple[float, float]:
    """The offsets a drive of ``voltage_pp`` may carry inside the MFC's rated ``window_v``, V (empty
    where the drive alone exceeds it: lowest > highest)."""
    half = 0.5 * voltage_pp
    return window_v[0] + half, window_v[1] - half


def bias_side_force_n(fin: Fin, thrust0_n: float, bias_v: float, speed_m_s: float) -> float:
    """The side force a bias gives at the fin, N: the mean thrust turned with the tip, and the tip's
    lift against the flow at ``alpha``, ``(T_0 + (1/2) rho U^2 S_f C_La) sin(alpha)``."""
    q = 0.5 * fin.rho_w * speed_m_s**2
    return (thrust0_n + q * fin.L * fin.b * fin_lift_slope(fin)) * math.sin(bias_tilt_rad(fin, bias_v))


def bias_for_yaw_rate(
    body: PlanarBody, fin: Fin, yaw_rate_rad_s: float, thrust0_n: float, speed_m_s: float
) -> float:
    """The offset that holds the steady yaw rate ``yaw_rate_rad_s`` at the thrust ``thrust0_n`` and
    the speed ``speed_m_s``, V: :meth:`PlanarBody.steady_yaw_rate`, :func:`bias_side_force_n` and
    :func:`bias_tilt_rad` inverted in closed form (the moment the yaw damping needs at that rate, its
    side force at the lever arm, the tip's turn that gives it); NaN where no tilt gives that force."""
    k = fin_yaw_damping(body, fin, speed_m_s)
    side = body.yaw_damping_nm(yaw_rate_rad_s, k) / body.fin_lever_m
    q = 0.5 * fin.rho_w * speed_m_s**2
    per_sine = thrust0_n + q * fin.L * fin.b * fin_lift_slope(fin)
    if per_sine <= 0 or abs(side) > per_sine:
        return math.nan
    return math.asin(side / per_sine) * fin.omega_n**2 / (abs(fin.phi_tip_slope) * fin.theta)


def slender_planar(body: Body, fin: Fin, fin_spacing_m: float = 0.0, c_y: float = 1.0) -> PlanarBody:
    """A planar body for ``body`` as a slender ellipsoid its ``length_m`` long, ``height_m`` deep and
    ``width_m`` wide, its fin(s) at its tail:

    * lateral drag area ``C_y pi L h / 4`` (the side's ellipse);
    * sway added mass by strips, each an ellipse moving along its width (``rho pi (h/2)^2`` per metre,
      Newman's *Marine Hydrodynamics* ch. 4), tapering as the ellipsoid: ``rho pi (h/2)^2 2L/3``;
      the yaw added inertia the same strips' ``x^2`` moment, ``rho pi (h/2)^2 L^3 / 30``;
    * the yaw inertia of a uniform ellipsoid, ``m (L^2 + w^2) / 20``;
    * the lever arm from the middle to the fin's middle, ``(L + L_fin) / 2``."""
    if not (math.isfinite(c_y) and c_y > 0):
        raise SwimError(f"{body.name}: c_y = {c_y!r} must be finite and > 0")
    L, rho, height_m, width_m = body.length_m, body.rho_w, body.height_m, body.width_m
    strip = rho * math.pi * (height_m / 2.0) ** 2
    return PlanarBody(
        surge=body,
        sway_added_mass_kg=strip * 2.0 * L / 3.0,
        lateral_drag_area_m2=c_y * math.pi * L * height_m / 4.0,
        yaw_inertia_kg_m2=body.mass_kg * (L**2 + width_m**2) / 20.0,
        yaw_added_inertia_kg_m2=strip * L**3 / 30.0,
        fin_lever_m=0.5 * (L + fin.L),
        fin_spacing_m=fin_spacing_m,
    )
