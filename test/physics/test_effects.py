"""Every effect's describing function agrees with its time-domain law (issue 15).

Two checks, for each effect of the library:

1. **The describing function is the law's.**  Under a sinusoidal motion ``eta = A sin(w t)`` and
   drive ``V sin(w t)``, the fundamental of each term of the canonical time-domain law
   (:class:`~piezofin_ros.physics.effects.TimeLaw`, projected numerically over one period) equals the
   coefficient :meth:`~piezofin_ros.physics.effects.Effect.describe` gives the harmonic balance, to
   0.1 %, at frequencies, voltages and amplitudes across the fin's band.
2. **The steady states agree.**  At a strength the diagnosis meets in practice, the steady state of the
   time-domain law (:func:`~piezofin_ros.physics.timedomain.simulate_law`, 12 s from rest, whole
   periods at the end) and the harmonic balance with the describing function
   (:meth:`~piezofin_ros.physics.model.Model.predict`) agree in tip velocity, current, power and
   load-cell thrust within 1 % beyond the single-term balance's own accuracy, which the paper's model
   without any effect shows at the same points (up to 1.8 % in power near resonance, from the
   harmonics quadratic drag makes; ``test_steady.py`` measures it).  Errors are relative to the larger
   of the value with and without the effect, so that a thrust the effect nearly cancels (swim speed)
   is judged on the thrust's scale.  The single-term balance has a domain, and one point here is
   outside it: at 3 Hz a cubic spring's third harmonic resonates (``3 f`` near the resonance), the
   time-domain tip velocity carries 14 % of harmonics, and the balance misses the power by 10 %.  The
   test names that point and checks that its reason holds there (harmonics over 10 %).
"""

from __future__ import annotations

import math
from dataclasses import fields

import numpy as np
import pytest

from piezofin_ros.diagnosis.synthetic import _reference_amplitude, draw_strength, library_effect
from piezofin_ros.physics.effects import LIBRARY, Effect, Effects, OperatingPoint, TimeLaw
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.knobs import Knobs
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
    "field_coupling": 0.3,
    "amplifier_sag": 0.6,
    "added_mass_kc2": 0.5,
    "voltage_monitor_gain": 1.1,
    "vibrometer_gain": 1.1,
    "vibrometer_delay": 2.0,
    "current_monitor_gain": 1.1,
    "current_monitor_delay": 2.0,
    "resonance_drift": 25.0,
    "capacitance_drift": 25.0,
    "coupling_drift": 25.0,
}
#: when the trials run (s since the first): drifts are judged half an hour into a run
WHEN = 1800.0
#: (effect, frequency) outside the single-term balance's domain, with the reason
OUTSIDE_DOMAIN = {
    ("stiffness_nonlinearity", 3.0): "superharmonic resonance of the cubic spring (3 f near f_res)",
    # an added mass ~ KC^2 turns the drag's third harmonic (3 f = 9 Hz, near f_res = 9.85 Hz) into a
    # modulation of the mass at 2 f: the balance misses the small power there by 3.4 % (nominal 0.8 %)
    ("added_mass_kc2", 3.0): "drag superharmonic (3 f near f_res) modulating a KC^2 added mass",
}
#: the harmonics (rms over the fundamental) of the tip velocity that put a point outside the domain
#: (the nominal model has 5 % there)
HARMONICS_OUTSIDE = {"stiffness_nonlinearity": 0.10, "added_mass_kc2": 0.07}


def _effect(name: str) -> Effect:
    a_ref = _reference_amplitude(FIN, (VPP,))
    max_current = float(np.max(FIN.C_eq * 2 * math.pi * FREQS * 0.5 * VPP))
    return library_effect(name, STRENGTHS[name], FIN, a_ref, max_current)


# --- 1. the describing function is the fundamental of the law ----------------------------------


def _law_fundamentals(law: TimeLaw, f: float, vpp: float, amp: float) -> dict[str, float]:
    """The balance's coefficients that the law's terms have under ``eta = amp sin(w t)``."""
    n = 8192
    th = 2 * math.pi * np.arange(n) / n
    s, c = np.sin(th), np.cos(th)
    w = 2 * math.pi * f
    eta, eta_dot = amp * s, amp * w * c
    kc = 2 * math.pi * FIN.phi_tip * np.sqrt(eta**2 + (eta_dot / w) ** 2) / FIN.b

    def fund(x: np.ndarray, basis: np.ndarray) -> float:
        return float(2 * np.mean(x * basis))

    g = float(law.drag) * np.maximum(kc, 1e-3) ** (-float(law.drag_n))
    mass_kc = float(law.mass_kc) * kc + float(law.mass_kc2) * kc**2
    v = 0.5 * vpp
    clipped = np.clip(v * s, -float(law.voltage_clip), float(law.voltage_clip))
    dv = np.gradient(clipped, th, edge_order=2) * w  # dv/dt of the clipped drive
    i_cap = FIN.C_eq * float(law.capacitance) * dv
    i_fund = fund(i_cap, c) * c + fund(i_cap, s) * s
    return {
        "stiffness": fund(float(law.stiffness) * (eta + float(law.c3) * eta**3), s) / amp,
        "damping": fund(float(law.damping) * (1 + float(law.c_abs) * np.abs(eta)) * eta_dot, c) / (amp * w),
        "mass": float(np.mean(float(law.mass) * (1 + mass_kc))),
        "drag": fund(g * np.abs(eta_dot) * eta_dot, c) / fund(np.abs(eta_dot) * eta_dot, c),
        "coupling": float(law.coupling),
        "voltage": fund(clipped, s) / v,
        "loss_conductance": float(law.loss_conductance),
        "thrust_gain": float(law.thrust_gain),
        "thrust_bias_n": float(law.thrust_bias_n),
        "swim_speed": float(law.swim_speed),
        "current_harmonics_a2": float(np.mean((i_cap - i_fund) ** 2)),
        # terms that are factors of the law as they are of the balance
        **{
            q: float(getattr(law, q))
            for q in (
                "capacitance",
                "voltage_scale",
                "voltage_gain",
                "tip_gain",
                "tip_delay_s",
                "current_gain",
                "current_delay_s",
            )
        },
    }


OPERATING_POINTS = [
    (f, vpp, x) for f in (2.0, 5.5, 9.0, 14.0) for vpp in (300.0, 800.0) for x in (1e-3, 6e-3, 15e-3)
]


@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_the_describing_function_is_the_fundamental_of_the_time_domain_law(name: str) -> None:
    effect = _effect(name)
    assert effect.values != tuple(effect.neutral()), "the effect must be away from neutral"
    moved = set()
    for f, vpp, x in OPERATING_POINTS:
        ff, vv = np.array([f]), np.array([vpp])
        law = Effects((effect,)).law(FIN, ff, vv, WHEN)
        law = TimeLaw(
            **{q.name: np.asarray(getattr(law, q.name), float).reshape(-1)[0] for q in fields(TimeLaw)}
        )
        expected = _law_fundamentals(law, f, vpp, x / FIN.phi_tip)
        knobs = Effects((effect,)).describe(OperatingPoint(FIN, ff, vv, np.array([x]), WHEN))
        scale = {"loss_conductance": FIN.C_eq * 2 * math.pi * f, "thrust_bias_n": 1e-3, "swim_speed": 0.1}
        scale["current_harmonics_a2"] = (FIN.C_eq * 2 * math.pi * f * 0.5 * vpp) ** 2
        scale["tip_delay_s"] = scale["current_delay_s"] = 1e-3
        for q in fields(Knobs):
            got = float(np.asarray(getattr(knobs, q.name)).reshape(-1)[0])
            want = expected[q.name]
            if got != getattr(Knobs(), q.name):
                moved.add(q.name)
            tol = 1e-3 * max(abs(want), scale.get(q.name, 0.0))
            assert got == pytest.approx(want, abs=tol), (name, q.name, f, vpp, x)
    assert moved, f"{name} changes no coefficient of the balance"


# --- 2. the steady states agree ----------------------------------------------------------------


def _time_domain(model: Model) -> dict[str, np.ndarray]:
    run = simulate_law(FIN, model.law(FREQS, VPP, WHEN), FREQS, VPP, duration=12.0, rate_hz=2000.0)
    out: dict[str, list[float]] = {"tip": [], "current": [], "power": [], "thrust": [], "harmonics": []}
    for j, f in enumerate(FREQS):
        periods = math.floor(6.0 * f)
        sel = run.t >= run.t[-1] - periods / f - 1e-9
        sel[-1] = False  # whole periods: [t_end - n T, t_end)
        t = run.t[sel]
        tip = run.tip_velocity[j, sel]
        fundamental = np.abs(2 * np.mean(tip * np.exp(-2j * math.pi * f * t))) / math.sqrt(2)
        rms = float(np.sqrt(np.mean(tip**2)))
        out["tip"].append(float(fundamental))
        out["harmonics"].append(math.sqrt(max(rms**2 - fundamental**2, 0.0)) / fundamental)
        out["current"].append(float(np.sqrt(np.mean(run.current[j, sel] ** 2))))
        out["power"].append(float(np.mean(run.voltage[j, sel] * run.current[j, sel])))
        out["thrust"].append(float(np.mean(run.loadcell_thrust[j, sel])))
    return {k: np.asarray(v) for k, v in out.items()}


def _balance(model: Model) -> dict[str, np.ndarray]:
    p = model.predict(FREQS, VPP, time_s=WHEN)
    return {
        "tip": p.tip_velocity_rms,
        "current": p.current_rms,
        "power": p.power_w,
        "thrust": p.thrust_loadcell_n,
    }


CHANNELS = ("tip", "current", "power", "thrust")


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def nominal() -> tuple[dict[str, np.ndarray], dict[str, float]]:
    td0, hb0 = _time_domain(Model(FIN)), _balance(Model(FIN))
    own = {ch: float(np.max(np.abs(hb0[ch] / td0[ch] - 1))) for ch in CHANNELS}
    assert own["tip"] < 0.01 and own["power"] < 0.02  # the balance's own accuracy, as test_steady says
    return td0, own


def test_every_effect_is_tested_and_the_strengths_are_the_benchmarks() -> None:
    assert set(STRENGTHS) == set(LIBRARY)
    rng = np.random.default_rng(0)
    for name, s in STRENGTHS.items():  # inside what the benchmark draws (either sign)
        drawn = [draw_strength(name, rng) for _ in range(200)]
        assert min(drawn) <= s <= max(drawn) or min(drawn) <= 2 - s <= max(drawn), name


@pytest.mark.parametrize("name", sorted(STRENGTHS))
def test_the_steady_states_of_the_law_and_of_the_describing_function_agree(name: str, nominal: tuple) -> None:
    td0, own = nominal
    model = Model(FIN) + _effect(name)
    td, hb = _time_domain(model), _balance(model)
    inside = np.array([(name, float(f)) not in OUTSIDE_DOMAIN for f in FREQS])
    if not np.all(inside):  # the reason holds
        assert np.all(td["harmonics"][~inside] > HARMONICS_OUTSIDE[name]), (name, td["harmonics"])
    for channel in CHANNELS:
        err = np.abs(hb[channel] - td[channel]) / np.maximum(np.abs(td[channel]), np.abs(td0[channel]))
        assert np.all(err[inside] <= own[channel] + 0.01), (name, channel, err, own[channel])


def test_effects_compose_and_are_immutable() -> None:
    a, b = _effect("drag_offset"), _effect("dielectric_loss")
    both = Model(FIN) + a + b
    assert isinstance(a + b, Effects) and both.names == ("drag_offset", "dielectric_loss")
    assert both.predict(FREQS, VPP).power_w == pytest.approx(Model(FIN, a + b).predict(FREQS, VPP).power_w)
    with pytest.raises(AttributeError):
        a.scale = 3.0  # type: ignore[misc]


def test_the_clipped_sine_fundamental_against_its_closed_form_and_its_inverse() -> None:
    """The clipped sine's describing function (a Fourier coefficient computed here on 20,000 samples)
    and ``clip_ratio``, the streaming rig's inverse of it, one place for both."""
    from piezofin_ros.physics.effects import clip_ratio, clipped_fundamental

    phase = np.linspace(0.0, 2 * math.pi, 20_000, endpoint=False)
    for r in (0.0, 0.1, 0.37, 0.8, 0.999, 1.0):
        clipped = np.clip(np.sin(phase), -r, r)
        fourier = 2 * float(np.mean(clipped * np.sin(phase)))
        assert float(clipped_fundamental(r)) == pytest.approx(fourier, abs=1e-6)
        assert clip_ratio(float(clipped_fundamental(r))) == pytest.approx(r, abs=1e-9)
    assert clip_ratio(1.5) == 1.0 and clip_ratio(-0.1) == 0.0


def test_an_effect_parameter_is_declared_once() -> None:
    """Issue 29's house: each parameter was declared twice (a positional ``Param`` and a field).  Now
    the field carries its ``Param``; a field declared without it is refused at class creation."""
    from dataclasses import dataclass

    from piezofin_ros.physics.effects import LIBRARY, declared, param

    for cls in LIBRARY.values():
        assert [q.name for q in cls.params] == [f.name for f in fields(cls)]
        assert all(getattr(cls(), q.name) == q.neutral for q in cls.params)  # the default: neutral

    @dataclass(frozen=True)
    class Good(Effect):
        gain: float = param("-", 1.0, 0.5, 2.0, 0.1, "x gain")

    assert declared(Good).params[0].upper == 2.0

    @dataclass(frozen=True)
    class Bad(Effect):
        gain: float = 1.0

    with pytest.raises(TypeError, match="param"):
        declared(Bad)


@pytest.mark.parametrize(
    "field_effect", [{"electroelastic_softening": [0.3]}, {"field_coupling": [0.3, 2.0]}]
)
def test_a_field_dependent_effect_sees_the_voltage_the_fin_gets(field_effect: dict) -> None:
    """Softening and a field-dependent coupling follow the field applied to the fin: behind an
    amplifier that sags, a fin at 800 Vpp commanded behaves as the same fin driven at what the
    amplifier gives it, and so it does when the drive is the monitor's reading.  (They once saw
    the command: under a sag, the optimiser's fit at the monitor's voltage read the softening as
    added mass, and a fish's self-sensed thrust was 15-25 % high, two demands missed in truth.)"""
    fin = load_fin("M8514-P1")
    f = np.linspace(14.0, 20.0, 7)
    sagging = Model.of(fin, {"amplifier_sag": [5.0], **field_effect})
    plain = Model.of(fin, field_effect)
    behind = sagging.predict(f, 800.0)
    drive = np.asarray(behind.voltage_pp_drive, float)
    assert np.all(drive < 0.9 * 800.0)  # (the amplifier sags at every frequency here: 475-680 Vpp)
    for p in (plain.predict(f, drive), plain.predict(f, 800.0, drive_pp=drive)):
        for name in ("thrust_n", "tip_velocity_rms", "power_w", "current_rms"):
            np.testing.assert_allclose(getattr(behind, name), getattr(p, name), rtol=1e-9, err_msg=name)
    # the time domain's law takes the same field (the fundamental of a clipped drive too)
    law = sagging.law(f, 800.0)
    assert np.allclose(law.stiffness, plain.law(f, drive).stiffness)
    assert np.allclose(law.coupling, plain.law(f, drive).coupling)


def test_an_effects_values_are_its_fields_in_its_params_order() -> None:
    """``Effect.values`` reads each parameter by name (a course reads them 190,000 times): for every
    effect of the library, at values inside its bounds, the same as its dataclass fields in order."""
    import dataclasses

    for name, cls in LIBRARY.items():
        inside = [
            q.lower + 0.37 * (q.upper - q.lower) if math.isfinite(q.upper - q.lower) else q.neutral + 0.5
            for q in cls.params
        ]
        effect = cls.at(inside)
        assert effect.values == tuple(float(v) for v in dataclasses.astuple(effect)), name
        assert effect.values == pytest.approx(inside), name
