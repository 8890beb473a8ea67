"""Worked examples: a new concept added in one place, and what follows by itself.

Each test adds what docs/reference.md's "Extending" table says a newcomer adds (an amplifier kind, a
watt, an objective, a drag law), here in the test instead of in the package, and shows the rest of the
code taking it with no other line changed: the loader, the registry's property test, the estimator,
the optimiser, the fish's surge step.  Read one as the recipe; it fails if that recipe stops being
enough.  A node's recipe, which needs rclpy and DDS, is ``test/nodes/test_extending_a_node.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pytest
from numpy.typing import ArrayLike
from scipy import optimize

from piezofin_ros.control.correction import Correction
from piezofin_ros.control.objective import THRUST_PER_WATT
from piezofin_ros.control.optimise import Optimiser
from piezofin_ros.physics import amplifier as amplifiers
from piezofin_ros.physics.amplifier import (
    Amplifier,
    AmplifierError,
    SwitchingAmplifier,
    Watt,
    amplifier_from_mapping,
    power_above_zero,
    power_in,
)
from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.swim import Body, bending_speed
from piezofin_ros.rig.fish import FreeSwimmer

from .control.test_objective import BRUTE_F, choices_against_brute_force
from .control.test_optimise import LIMITS
from .estimation.test_watts import drive
from .physics.test_amplifier import test_the_closed_form_is_the_time_domain_law_on_a_sine as amplifier_law


# ------------------------------------------------------------------------------ an amplifier kind
@dataclass(frozen=True)
class TransformerAmplifier(Amplifier):
    """A kind the package does not have: a transformer-coupled stage that pays ``|v i| / efficiency``
    both ways (the energy the fin returns is burnt, not recovered).  Its law and its closed form:"""

    kind: ClassVar[str] = "transformer"
    limits: ClassVar[dict[str, tuple[str, float, float, str]]] = {
        "efficiency": ("", 0.01, 1.0, "of the power it moves either way"),
        "quiescent_w": ("W", 0.0, 1000.0, "the draw with no output"),
        "bus_v": ("V", 0.1, 1000.0, "the supply bus voltage"),
    }
    efficiency: float = 0.7
    quiescent_w: float = 0.0
    bus_v: float = 12.0

    @property
    def supply_v(self) -> float:
        return self.bus_v

    def draw(self, v: ArrayLike, i: ArrayLike) -> Any:
        return self.quiescent_w + np.abs(np.asarray(v, float) * np.asarray(i, float)) / self.efficiency

    def steady(self, voltage_pp: ArrayLike, current_rms: ArrayLike, power_w: ArrayLike) -> Any:
        # mean |p| = the mean above zero, plus the mean below it (that less P): 2 above - P
        above = power_above_zero(voltage_pp, current_rms, power_w)
        return self.quiescent_w + (2 * above - np.asarray(power_w, float)) / self.efficiency

    def describe(self) -> str:
        return f"a transformer-coupled stage, {self.efficiency:.0%} efficient either way"


def test_an_amplifier_kind_is_one_class_in_the_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """The recipe: a subclass with its ``limits``, ``draw`` (the law) and ``steady`` (its closed form),
    and its row in ``KINDS`` (here patched in).  By itself: a YAML of its kind loads, refused values
    are one error naming the parameter, the registry's property test checks its closed form against
    its law on random sines, and ``without_quiescent`` drops its fixed draw."""
    monkeypatch.setitem(amplifiers.KINDS, TransformerAmplifier.kind, TransformerAmplifier)
    amp = amplifier_from_mapping({"kind": "transformer", "efficiency": 0.8, "quiescent_w": 0.05})
    assert isinstance(amp, TransformerAmplifier) and amp.bus_v == 12.0
    with pytest.raises(AmplifierError, match="efficiency"):
        amplifier_from_mapping({"kind": "transformer", "efficiency": 2.0})
    amplifier_law()  # the registry's own property test, every kind in it (hypothesis: 60 sines)
    assert amp.without_quiescent().quiescent_w == 0.0


# ------------------------------------------------------------------------------ a watt
#: A watt the package does not have: the amplifier's heat, what it draws and does not hand the fin (its
#: supply's watt less the fin's), which a sealed hull must shed.  No estimate field records it: it is
#: read from the two that do.
HEAT = Watt(
    "heat",
    "the amplifier's heat: its draw less what the fin takes",
    "the amplifier's heat",
    field="",
    law=lambda v, i, p, amp: amp.steady(v, i, p) - p,
    derive=lambda r: r.get("power_supply_w", math.nan) - r.get("power_w", math.nan),
)


def test_a_watt_is_one_entry_in_the_registry(monkeypatch: pytest.MonkeyPatch, m8528: Fin) -> None:
    """The recipe: a ``Watt`` in ``WATT`` (here patched in) with its law on the steady state and how an
    estimate gives it (the field that records it, or a function of those there are).  By itself:
    ``power_in`` is its law; the optimiser ranks by it (its choice is the brute force's best thrust
    per heat watt over the same map, and another point than the fin's watt chooses); the stream
    estimator's estimates read it and the thrust per it."""
    monkeypatch.setitem(amplifiers.WATT, HEAT.name, HEAT)
    amp = SwitchingAmplifier(efficiency=0.8, recovered=0.5, quiescent_w=0.05)
    r = Correction().response(m8528, BRUTE_F, np.full_like(BRUTE_F, 400.0))
    assert r.voltage_pp is not None and r.current_rms is not None
    heat = power_in("heat", r.voltage_pp, r.current_rms, r.power_w, amp)
    np.testing.assert_allclose(heat, amp.steady(r.voltage_pp, r.current_rms, r.power_w) - r.power_w)
    assert np.all(heat > 0)  # (80 % efficient: a fifth of what it moves, and its quiescent draw)
    chosen = {}
    for watt in ("heat", "fin"):
        opt = Optimiser(m8528, LIMITS, voltage_pp=400.0, watt=watt, amplifier=amp, identify=False)
        assert opt.choice is not None
        chosen[watt] = opt.choice
    ok = np.asarray(r.thrust_n) >= 1e-3
    best = float(np.max(np.asarray(r.thrust_n)[ok] / heat[ok]))
    c = chosen["heat"]
    assert c.thrust_n / c.power_w >= 0.98 * best  # (the Choice's power is in the watt it ranks by)
    assert abs(c.frequency_hz / chosen["fin"].frequency_hz - 1) > 0.05, chosen
    e = drive(amp, amp, supply=False)  # (the stream estimator's running estimate of a steady drive)
    assert e.power("heat") == pytest.approx(e.power_supply_w - e.power_w, rel=1e-12) and e.power("heat") > 0
    assert e.thrust_per("heat", "self") == pytest.approx(e.thrust_self_n / e.power("heat"), rel=1e-12)


# ------------------------------------------------------------------------------ an objective
@dataclass(frozen=True)
class ThrustSquaredPerWatt:
    """An objective the package does not have: ``T^2 / P`` (more thrust for its watt, between the
    paper's thrust per watt and the most thrust).  Any callable with a ``name`` is one."""

    name: str = "thrust squared per watt"

    def __call__(self, thrust_n: Any, power_w: Any, demand_n: float | None = None) -> Any:
        thrust = np.asarray(thrust_n, float)
        if demand_n is not None:  # under a demand the thrust counts up to it (the least watt then)
            thrust = np.minimum(thrust, demand_n)
        return thrust**2 / np.asarray(power_w, float)


def test_an_objective_is_one_callable_the_optimiser_takes(m8528: Fin) -> None:
    """The recipe: a callable ``(thrust_n, power_w, demand_n) -> score`` with a ``name``, passed to the
    optimiser (and, for a node's ``objective`` parameter, a row in ``OBJECTIVES``).  By itself: the
    optimiser's map ranks by it (its choice is the brute force's best over the same map), its status
    names it, and it chooses another point than thrust per watt does."""
    chosen, _ = choices_against_brute_force(m8528, (ThrustSquaredPerWatt(), THRUST_PER_WATT))
    assert chosen[ThrustSquaredPerWatt.name].thrust_n > chosen[THRUST_PER_WATT.name].thrust_n


# ------------------------------------------------------------------------------ a drag law
@dataclass(frozen=True)
class PowerLawBody(Body):
    """A drag law the package does not have: ``D = k U |U|^(n-1)`` (``n`` 1.8, a rough fit of skin
    friction), with its slope and, as Eq. (19)'s speed term leaves no closed root, a numerical one."""

    drag_k: float = 0.9  # N (s/m)^n
    drag_exponent: float = 1.8

    def drag_n(self, U: ArrayLike) -> Any:
        u = np.asarray(U, float)
        return self.drag_k * u * np.abs(u) ** (self.drag_exponent - 1)

    def drag_slope_n_s_m(self, U: ArrayLike) -> Any:
        return self.drag_exponent * self.drag_k * np.abs(np.asarray(U, float)) ** (self.drag_exponent - 1)

    def steady_speed(
        self, thrust0_n: ArrayLike, frequency_hz: ArrayLike | None = None, fin_length_m: float | None = None
    ) -> Any:
        c = float(bending_speed(frequency_hz, fin_length_m))
        t0 = max(float(thrust0_n), 0.0) * self.fins
        if t0 == 0.0:
            return np.float64(0.0)
        return np.float64(
            optimize.brentq(lambda u: float(self.drag_n(u)) - t0 * (1 - (u / c) ** 2), 0.0, min(c, 20.0))
        )


def test_a_drag_law_is_one_body_the_fish_swims_with() -> None:
    """The recipe: a ``Body`` whose ``drag_n`` is the law, ``drag_slope_n_s_m`` its slope and
    ``steady_speed`` the speed it balances (closed, or numerical where there is no closed root).  By
    itself: the closed forms meet the law (the same checks as the package's own law), the surge
    equation rests there, the speed loop's time constant follows the slope, and the fish rig's surge
    step swims to that speed."""
    body = PowerLawBody()
    thrust, f, fin_l = 3e-3, 5.0, 0.085  # N per fin, Hz, m (the paper's fin)
    U = 0.05
    h = 1e-6
    numeric = (float(body.drag_n(U + h)) - float(body.drag_n(U - h))) / (2 * h)
    assert float(body.drag_slope_n_s_m(U)) == pytest.approx(numeric, rel=1e-6)
    U0 = float(body.steady_speed(thrust, f, fin_l))
    assert body.acceleration(U0, thrust, f, fin_l) == pytest.approx(0.0, abs=1e-9)
    tau = body.time_constant_s(thrust, f, fin_l)
    c = float(bending_speed(f, fin_l))
    slope = float(body.drag_slope_n_s_m(U0)) + 2 * body.fins * thrust * U0 / c**2
    assert tau == pytest.approx((body.mass_kg + body.added_mass_kg) / slope)
    fish = FreeSwimmer(body, fin_length_m=fin_l, speed_noise_m_s=0.0)
    dt = 0.05
    for _ in range(round(20 * tau / dt)):  # the rig's step: each block's thrust at the present speed
        t = thrust * (1 - (fish.speed_m_s / c) ** 2)
        fish.advance(dt, t, f, supply_w=0.0)
    assert fish.speed_m_s == pytest.approx(U0, rel=1e-3)
    assert pytest.approx(float(Body().steady_speed(thrust, f, fin_l)), rel=0.05) != U0  # another law
