"""The swimming fish (issue 27): the body's surge, the battery, and Eq. (19)'s ``U`` term, against
closed forms and independent integrations; impossible bodies and batteries are one line."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import integrate, optimize

from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.steady import harmonic_balance
from piezofin_ros.physics.swim import (
    Battery,
    Body,
    SwimError,
    bending_speed,
    load_battery,
    load_body,
    thrust_at_speed,
)


def test_the_u_term_is_eq_19_of_the_steady_state() -> None:
    """``T_0 (1 - (U/c)^2)``, ``c = omega L / 1.3796``, is the steady state's own Eq. (19) with its
    ``U`` term (single harmonic: the closed form's assumption), at every speed and frequency."""
    fin = load_fin("M8528-P1")
    f = np.array([3.0, 5.5, 9.0])
    for U in (0.0, 0.1, 0.8, 2.0):
        s = harmonic_balance(fin, f, 800.0, U=U)
        t0 = harmonic_balance(fin, f, 800.0).thrust_n
        np.testing.assert_allclose(thrust_at_speed(t0, f, fin.L, U), s.thrust_n, rtol=1e-9, atol=1e-15)
    # a fin beating at 5 Hz gives nothing beyond c
    assert float(bending_speed(5.0, fin.L)) == pytest.approx(
        2 * math.pi * 5 * fin.phi_tip / fin.phi_tip_slope
    )


@settings(max_examples=30, deadline=None)
@given(
    thrust=st.floats(1e-4, 0.05),
    f=st.floats(1.0, 20.0),
    area=st.floats(5e-4, 1e-2),
    linear=st.floats(0.0, 0.05),
    fins=st.integers(1, 2),
)
def test_the_steady_speed_is_where_the_surge_equation_rests(thrust, f, area, linear, fins) -> None:
    """The closed form against the surge equation integrated from rest (scipy), and the time
    constant against the integration's 63 % point."""
    body = Body(drag_area_m2=area, drag_linear_n_s_m=linear, fins=fins)
    L = 0.09
    U = float(body.steady_speed(thrust, f, L))
    assert body.acceleration(U, thrust, f, L) == pytest.approx(0.0, abs=1e-12)
    tau = body.time_constant_s(thrust, f, L)
    sol = integrate.solve_ivp(
        lambda t, y: [body.acceleration(float(y[0]), thrust, f, L)],
        (0, 40 * tau),
        [0.0],
        rtol=1e-9,
        atol=1e-12,
    )
    assert float(sol.y[0, -1]) == pytest.approx(U, rel=1e-5)
    assert 0 < tau < math.inf


@settings(max_examples=60, deadline=None)
@given(
    thrust=st.floats(0.0, 1e308),
    linear=st.floats(0.0, 0.05),
    f=st.one_of(st.none(), st.floats(0.5, 50.0)),
)
def test_the_steady_speed_is_finite_and_exact_at_any_thrust(thrust, linear, f) -> None:
    """Any thrust a caller may hold (a hostile estimate of 1e300 N reached it through the speed
    loop): a finite speed, without an overflow's warning, that balances the drag to the last bits
    (the root of its quadratic to 80 digits), and that grows
    with the thrust."""
    import warnings
    from decimal import Decimal, localcontext

    body = Body(drag_linear_n_s_m=linear)
    L = 0.09
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        U = float(body.steady_speed(thrust, f, L))
        U_more = float(body.steady_speed(min(thrust * 2.0, 1.7e308), f, L))
    assert math.isfinite(U) and U >= 0.0 and U_more >= U * (1 - 1e-12)  # (near c: to the last bit)
    if thrust == 0.0:
        assert U == 0.0
        return
    # the same root to 80 digits: a U^2 + b U - T = 0, U = 2T / (b + sqrt(b^2 + 4aT))
    with localcontext() as ctx:
        ctx.prec = 80
        c = math.inf if f is None else float(bending_speed(f, L))
        T = Decimal(thrust) * body.fins
        a = (T / Decimal(c) ** 2 if math.isfinite(c) else 0) + Decimal(body.rho_w) * Decimal(
            body.drag_area_m2
        ) / 2
        b = Decimal(body.drag_linear_n_s_m)
        exact = 2 * T / (b + (b * b + 4 * a * T).sqrt())
    assert pytest.approx(float(exact), rel=1e-12) == U


@settings(max_examples=30, deadline=None)
@given(
    thrust=st.floats(1e-4, 0.05),
    U=st.floats(-0.5, 0.5),
    area=st.floats(5e-4, 1e-2),
    linear=st.floats(0.0, 0.05),
    fins=st.integers(1, 2),
)
def test_the_drag_law_its_slope_and_its_balance_agree(thrust, U, area, linear, fins) -> None:
    """The drag law once, its closed forms beside it (issue 40: written four times before): the slope
    against the law's central difference, the speed without Eq. (19)'s term against a root of
    ``D(U) = n T`` (scipy) and as the limit of a fin beating ever faster, the surge equation's
    rest there, and the loop's time constant against the slope."""
    body = Body(drag_area_m2=area, drag_linear_n_s_m=linear, fins=fins)
    h = 1e-6
    numeric = (float(body.drag_n(U + h)) - float(body.drag_n(U - h))) / (2 * h)
    assert float(body.drag_slope_n_s_m(U)) == pytest.approx(
        numeric, rel=1e-6, abs=2e-5
    )  # (U |U| at 0: h rho A)
    U0 = float(body.steady_speed(thrust))
    root = optimize.brentq(lambda u: float(body.drag_n(u)) - fins * thrust, 0.0, 10.0, xtol=1e-14)
    assert pytest.approx(root, rel=1e-9) == U0
    assert pytest.approx(float(body.steady_speed(thrust, 1e6, 1.0)), rel=1e-9) == U0
    assert body.acceleration(U0, thrust) == pytest.approx(0.0, abs=1e-12)
    assert body.surge_acceleration(fins * thrust, U0) == pytest.approx(0.0, abs=1e-12)
    tau = body.time_constant_s(thrust)
    assert tau == pytest.approx((body.mass_kg + body.added_mass_kg) / float(body.drag_slope_n_s_m(U0)))


def _endurance_by_quadrature(battery: Battery, power: float) -> float:
    """One charge's endurance at constant power, by scipy's quadrature of ``3600 C / I(q)`` down to
    the state of charge where the terminal voltage meets the cut-off."""
    p = power + battery.hotel_w
    cut = battery.cells * battery.cutoff_v_per_cell

    def slack(q: float) -> float:
        v = float(battery.terminal_v(q, p))
        return v - cut if math.isfinite(v) else -1.0

    q_end = 0.0 if slack(0.0) >= 0 else float(optimize.brentq(slack, 0.0, 1.0))
    kinks = [q for q in battery.ocv_soc if q_end < q < 1.0]  # (the curve is a table: linear between)
    value, _ = integrate.quad(
        lambda q: 3600 * battery.capacity_ah / float(battery.current_a(q, p)),
        q_end,
        1.0,
        points=kinks,
        limit=200,
    )
    return value


@pytest.mark.parametrize("power", [0.0, 0.05, 1.0, 10.0])
def test_the_battery_lasts_what_its_charge_and_its_voltage_curve_give(power: float) -> None:
    battery = load_battery("li-ion-2s-500mah")
    assert battery.endurance_s(power) == pytest.approx(_endurance_by_quadrature(battery, power), rel=3e-3)
    # a flat curve and no resistance: the energy over the power
    flat = Battery(
        ocv_v_per_cell=(3.7,) * 12, internal_resistance_ohm=0.1, hotel_w=0.0, cutoff_v_per_cell=3.0
    )
    if power > 0:  # a constant EMF: a constant current I, with E I - R I^2 = P
        i = (7.4 - math.sqrt(7.4**2 - 4 * 0.1 * power)) / (2 * 0.1)
        assert 7.4 * i - 0.1 * i * i == pytest.approx(power)
        assert flat.endurance_s(power) == pytest.approx(3600 * 0.5 / i, rel=1e-9)
    # the voltage falls with the charge and under load
    assert battery.terminal_v(0.2, 1.0) < battery.terminal_v(0.8, 1.0) < battery.terminal_v(0.8, 0.0)


def test_the_anchor_body_swims_cen_and_erturks_speed_on_the_papers_point() -> None:
    """The preset's drag area is set so that the paper's M8528-P1 (its twin) at 5.5 Hz, 800 Vpp
    swims 0.3 body lengths per second (config/bodies/mfc-fish.yaml)."""
    from piezofin_ros.physics.model import load_model

    body, model = load_body("mfc-fish"), load_model("paper-twin-M8528-P1")
    t0 = float(model.predict(5.5, 800.0).thrust_n)
    assert float(body.steady_speed(t0, 5.5, model.fin.L)) / body.length_m == pytest.approx(0.3, rel=0.01)


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: Body(mass_kg=-1.0), "mass_kg"),
        (lambda: Body(drag_area_m2=0.0), "drag_area_m2"),
        (lambda: Body(length_m=math.nan), "length_m"),
        (lambda: Body(fins=0), "fins"),
        (lambda: Battery(capacity_ah=0.0), "capacity_ah"),
        (lambda: Battery(cells=0), "cells"),
        (lambda: Battery(internal_resistance_ohm=-0.1), "internal_resistance_ohm"),
        (lambda: Battery(hotel_w=math.inf), "hotel_w"),
        # numbers, but no fish (a drag area of 1e300 m^2 printed 150-digit joules per metre)
        (lambda: Body(drag_area_m2=1e300), r"drag_area_m2 = 1e\+300 must be finite and within \[1e-08, 10\]"),
        (lambda: Body(mass_kg=1e6), "mass_kg"),
        (lambda: Body(rho_w=1.0), r"rho_w = 1.0 must be finite and within \[500, 2000\]"),
        (lambda: Body(added_mass_kg=1e9), "added_mass_kg"),
        (lambda: Battery(hotel_w=1e308), "hotel_w"),
        (lambda: Battery(capacity_ah=1e12), "capacity_ah"),
        (lambda: Battery(ocv_v_per_cell=(4.2,) + (3.0,) * 11), "ocv_v_per_cell"),
    ],
)
def test_an_impossible_body_or_battery_is_one_line_naming_the_field(make, words) -> None:
    with pytest.raises(SwimError, match=words):
        make()
