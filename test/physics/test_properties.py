"""Property tests over random valid fins and drives (hypothesis)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.physics.fin import Fin
from piezofin_ros.physics.steady import harmonic_balance
from piezofin_ros.physics.timedomain import simulate
from piezofin_ros.physics.waveforms import protocol


@st.composite
def fins(draw: st.DrawFn) -> Fin:
    L = draw(st.floats(0.02, 0.5))
    b = draw(st.floats(max(L / 10, 0.005), min(L * 2, 1.0)))
    return Fin(
        name="random",
        L=L,
        L_active=L * draw(st.floats(0.5, 1.0)),
        b=b,
        b_active=b * draw(st.floats(0.5, 1.0)),
        h=draw(st.floats(1e-4, 5e-3)),
        m_s=draw(st.floats(0.005, 1.0)),
        f_sc=draw(st.floats(2.0, 500.0)),
        D=draw(st.floats(1e-4, 1.0)),
        zeta=draw(st.floats(0.002, 0.2)),
        theta=draw(st.floats(1e-4, 0.05)),
        C_eq=draw(st.floats(1e-9, 1e-6)),
        c_d=draw(st.one_of(st.just(0.0), st.floats(0.1, 30.0))),
        rho_w=draw(st.sampled_from([0.0, 1.2, 1000.0, 1025.0])),
    )


frequencies = st.floats(0.1, 200.0)
voltages = st.one_of(st.just(0.0), st.floats(1e-3, 1500.0))  # not subnormal volts


@settings(max_examples=300, deadline=None)
@given(fins(), frequencies, voltages, voltages)
def test_thrust_and_power_nonnegative_and_monotone_in_voltage(
    fin: Fin, f: float, v1: float, v2: float
) -> None:
    lo, hi = sorted((v1, v2))
    s = harmonic_balance(fin, f, np.array([lo, hi]))
    for arr in (s.thrust_n, s.power_w, s.tip_velocity_rms, s.current_rms, s.thrust_per_watt):
        assert np.all(np.isfinite(arr))
    assert np.all(s.thrust_n >= 0)
    assert np.all(s.power_w >= 0)
    assert s.thrust_n[1] >= s.thrust_n[0]
    if hi > lo * 1.001 and hi > 0 and fin.rho_w > 0:  # no fluid, no thrust
        assert s.thrust_n[1] > s.thrust_n[0]


@settings(max_examples=40, deadline=None)
@given(fins(), st.floats(0.5, 30.0), st.floats(1.0, 1500.0))
def test_time_domain_is_finite_and_thrust_positive(fin: Fin, f: float, vpp: float) -> None:
    tr = simulate(fin, protocol(f, vpp, off_s=0.2, on_s=1.0), 1.5)
    assert np.all(np.isfinite(tr.tip_velocity))
    assert np.all(np.isfinite(tr.current))
    assert np.all(tr.thrust >= 0)
    # Over the whole record v = 0 at both ends, so the capacitor's stored energy returns and
    # mean(v i) is dissipation plus the fin's residual mechanical energy: >= 0, up to the
    # discrete-sum error on the reactive power C V^2 w / 2.
    reactive = fin.C_eq * (vpp / 2) ** 2 * 2 * np.pi * f / 2
    assert tr.window(0.0, 1.6).power_w >= -1e-4 * reactive
