"""Every effect's describing function agrees with its time-domain law (issue 15).

For each effect of the library, at a strength the diagnosis meets in practice, the steady state of
the time-domain law (:func:`~piezofin_ros.physics.timedomain.simulate_law`, 10 s from rest, the
last whole periods) and the harmonic balance with the describing function
(:meth:`~piezofin_ros.physics.model.Model.predict`) must move the tip velocity, the current, the
power and the load-cell thrust by the same factor against the paper's model, within 1 %.  (The
ratio cancels the single-term balance's own error, up to 2 % near resonance, which
``test_steady.py`` measures; what is left is the effect's describing function.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.diagnosis.synthetic import _reference_amplitude, draw_strength, library_effect
from piezofin_ros.physics.effects import LIBRARY, Effect, Effects
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.model import Model
from piezofin_ros.physics.timedomain import simulate_law

FIN = load_fin("M8528-P1")
FREQS = np.array([3.0, 6.0, 8.0, 11.0])
VPP = 800.0
#: generator strengths (the units of draw_strength): the middle of the ranges the benchmark draws
STRENGTHS = {
    "resonance_offset": 1.15,
    "stiffness_nonlinearity": 0.2,
    "electroelastic_softening": 0.3,
    "nonlinear_damping": 10.0,
    "added_mass_offset": 1.35,
    "added_mass_kc": 0.5,
    "drag_offset": 2.5,
    "drag_kc": 0.6,
    "dielectric_loss": 0.06,
    "leakage": 0.1,
    "swim_speed": 0.3,
    "amplifier_limit": 0.6,
    "loadcell_offset": 1.0,
    "loadcell_gain": 1.25,
}


def _effect(name: str) -> Effect:
    a_ref = _reference_amplitude(FIN, (VPP,))
    max_current = float(np.max(FIN.C_eq * 2 * math.pi * FREQS * 0.5 * VPP))
    return library_effect(name, STRENGTHS[name], FIN, a_ref, max_current)


def _time_domain(model: Model) -> dict[str, np.ndarray]:
    run = simulate_law(FIN, model.law(FREQS, VPP), FREQS, VPP, duration=12.0, rate_hz=2000.0)
    out: dict[str, list[float]] = {"tip": [], "current": [], "power": [], "thrust": []}
    for j, f in enumerate(FREQS):
        periods = math.floor(6.0 * f)
        sel = run.t >= run.t[-1] - periods / f - 1e-9
        sel[-1] = False  # whole periods: [t_end - n T, t_end)
        t = run.t[sel]
        ref = np.exp(-2j * math.pi * f * t)
        out["tip"].append(float(np.abs(2 * np.mean(run.tip_velocity[j, sel] * ref)) / math.sqrt(2)))
        out["current"].append(float(np.sqrt(np.mean(run.current[j, sel] ** 2))))
        out["power"].append(float(np.mean(run.voltage[j, sel] * run.current[j, sel])))
        out["thrust"].append(float(np.mean(run.loadcell_thrust[j, sel])))
    return {k: np.asarray(v) for k, v in out.items()}


def _balance(model: Model) -> dict[str, np.ndarray]:
    p = model.predict(FREQS, VPP)
    return {"tip": p.tip_velocity_rms, "current": p.current_rms, "power": p.power_w, "thrust": p.thrust_loadcell_n}


@pytest.fixture(scope="module")
def nominal() -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    return _time_domain(Model(FIN)), _balance(Model(FIN))


def test_every_effect_is_tested_and_the_strengths_are_the_benchmarks() -> None:
    assert set(STRENGTHS) == set(LIBRARY)
    rng = np.random.default_rng(0)
    for name, s in STRENGTHS.items():  # inside what the benchmark draws (either sign)
        drawn = [draw_strength(name, rng) for _ in range(200)]
        assert min(drawn) <= s <= max(drawn) or min(drawn) <= 2 - s <= max(drawn), name


@pytest.mark.parametrize("name", sorted(STRENGTHS))
def test_the_describing_function_agrees_with_the_time_domain_law(name: str, nominal: tuple) -> None:
    td0, hb0 = nominal
    model = Model(FIN) + _effect(name)
    td, hb = _time_domain(model), _balance(model)
    for channel in ("tip", "current", "power", "thrust"):
        td_ratio = td[channel] / td0[channel]
        hb_ratio = hb[channel] / hb0[channel]
        err = np.abs(td_ratio / hb_ratio - 1)
        assert np.all(err <= 0.01), (name, channel, td_ratio, hb_ratio)


def test_effects_compose_and_are_immutable() -> None:
    a, b = _effect("drag_offset"), _effect("dielectric_loss")
    both = Model(FIN) + a + b
    assert isinstance(a + b, Effects) and both.names == ("drag_offset", "dielectric_loss")
    assert both.predict(FREQS, VPP).power_w == pytest.approx(Model(FIN, a + b).predict(FREQS, VPP).power_w)
    with pytest.raises(AttributeError):
        a.scale = 3.0  # type: ignore[misc]
