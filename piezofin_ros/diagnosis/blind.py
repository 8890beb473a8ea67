r"""A blind generator: effects written *here*, in forms the library does not have.

:mod:`.synthetic` hides the library's own effects (through their time-domain laws), so it checks
that the diagnosis finds what it knows.  This module checks what a real rig does to it: each
effect below is written from its physics, independently of any describing function, and in a form
that differs from the library's, so the diagnosis can only name the right *family*, with some
model-form error left:

=========================  ====================================================  =====================
effect (``BLIND``)          law here                                              library's form
=========================  ====================================================  =====================
``coupling_saturating``     ``theta x (1 + k tanh(Vpp/400) / tanh(2))``           a power of Vpp
``amplifier_rms_limit``     the amplifier scales its output so that the *true*     capacitive demand
                            RMS current (capacitive, loss and motional) stays      ``C_eq w V``
                            under a limit (an automatic gain control)
``added_mass_kc_mixed``     ``c_m x (1 + a KC + 2 a KC^2)``                        ``KC`` or ``KC^2``
                                                                                  (the pair is exact)
``vibrometer_lowpass``      a first-order low-pass on the tip-velocity reading     gain; pure delay
                            (corner 20-80 Hz: a lag and a gain falling with f)
``current_lowpass``         a first-order low-pass on the current reading (an RC  pure delay
                            of 0.5-2.5 ms: a lag, and a gain that falls with f)
``voltage_monitor``         the drive reads ``g`` times what the fin receives       the same
``vibrometer_reversed``     the tip-velocity reading's sign flipped                 (found by the data
``current_reversed``        the current reading's sign flipped                      check, not fitted)
``warming_capacitance``     ``C_eq x (1 + d (1 - exp(-t / 600 s)))``                linear in t
``warming_resonance``       ``wn x (1 + d (1 - exp(-t / 600 s)))``                  linear in t
``warming_coupling``        ``theta x (1 + d (1 - exp(-t / 600 s)))``               linear in t
``mains``                   a 50 Hz line of 30 uA on the current reading           (none: no gap)
=========================  ====================================================  =====================

Every dataset runs the paper's grid, its trials in a random order (``shuffled``; in the protocol's
order, voltage by voltage and frequencies up, a drift in time looks like a dependence on the drive
and on the frequency: :func:`.synthetic.trial_times`), through the
same time-domain integrator, rig noise and lock-in as :mod:`.synthetic`.  :data:`FAMILY` maps each
effect to the library family the diagnosis should name (``None``: it should find no gap).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from ..errors import DiagnosisError
from ..physics.effects import effect_class
from ..physics.fin import load_fin, preset_names
from ..physics.model import Model
from ..physics.timedomain import simulate_law
from .data import Trials
from .synthetic import DURATION_S, RATE_HZ, _reference_amplitude, default_frequencies, measure, trial_times

FloatArray = NDArray[Any]

#: The family the diagnosis should name for each blind effect (None: no gap to find).
FAMILY: dict[str, str | None] = {
    "coupling_saturating": "coupling",
    "amplifier_rms_limit": "amplifier",
    "added_mass_kc_mixed": "added mass",
    "vibrometer_lowpass": "vibrometer",
    "current_lowpass": "current monitor",
    "voltage_monitor": "voltage monitor",
    "vibrometer_reversed": "vibrometer reversed",
    "current_reversed": "current monitor reversed",
    "warming_capacitance": "drift in time",
    "warming_resonance": "drift in time",
    "warming_coupling": "drift in time",
    "mains": None,
}
BLIND = tuple(FAMILY)
WARMING_S = 600.0  # time constant of the warming drifts


@dataclass(frozen=True)
class BlindCase:
    fin: str
    effect: str  # one of BLIND, or "" for clean data
    strength: float = 0.0
    seed: int = 0
    voltages_pp: tuple[float, ...] = (400.0, 600.0, 800.0)
    shuffled: bool = True  # trials in a random order (else the protocol's: voltage by voltage)

    @property
    def family(self) -> str | None:
        return FAMILY.get(self.effect) if self.effect else None


def draw(effect: str, rng: np.random.Generator) -> float:
    """A strength where the effect is visible above the rig's noise."""
    sign = 1.0 if rng.random() < 0.5 else -1.0
    u = rng.uniform
    table = {
        "coupling_saturating": u(0.2, 0.5),
        "amplifier_rms_limit": u(0.5, 0.8),  # the limit, as a fraction of the largest RMS current
        "added_mass_kc_mixed": u(0.15, 0.4),  # a KC at the reference amplitude
        "vibrometer_lowpass": u(20.0, 80.0),  # corner, Hz
        "current_lowpass": u(0.5, 2.5),  # RC, ms
        "voltage_monitor": 1.0 + sign * u(0.08, 0.2),
        "vibrometer_reversed": 1.0,
        "current_reversed": 1.0,
        "warming_capacitance": sign * u(0.05, 0.15),  # relative change at the end (t >> 600 s)
        "warming_resonance": -u(0.05, 0.12),
        "warming_coupling": sign * u(0.08, 0.2),
        "mains": 30e-6,  # A
    }
    if effect not in table:
        raise DiagnosisError(f"unknown blind effect {effect!r}; known: {', '.join(BLIND)}")
    return float(table[effect])


def random_blind(rng: np.random.Generator, effect: str | None = None) -> BlindCase:
    name = effect if effect is not None else str(rng.choice(BLIND))
    fin = str(rng.choice(preset_names()))
    return BlindCase(fin, name, draw(name, rng) if name else 0.0, int(rng.integers(2**31)))


def _lowpass(t: FloatArray, x: FloatArray, corner_hz: float) -> FloatArray:
    """A first-order low-pass (bilinear transform of ``1 / (1 + s / w_c)``), from rest."""
    fs = 1.0 / float(t[1] - t[0])
    b, a = signal.bilinear([1.0], [1.0 / (2 * math.pi * corner_hz), 1.0], fs)
    return np.asarray(signal.lfilter(b, a, x))


def simulate_blind(case: BlindCase) -> Trials:
    """Run the paper's grid with the blind effect, as the suite would measure it."""
    fin = load_fin(case.fin)
    rng = np.random.default_rng(case.seed)
    freqs = np.asarray(default_frequencies(fin), float)
    f, vpp = (x.ravel() for x in np.meshgrid(freqs, np.asarray(case.voltages_pp, float)))
    when = trial_times(vpp, rng if case.shuffled else None)
    law = Model(fin).law(f, vpp, when)
    e, s = case.effect, case.strength
    warming = 1.0 + s * (1.0 - np.exp(-when / WARMING_S))
    if e == "coupling_saturating":
        law = replace(law, coupling=1.0 + s * np.tanh(vpp / 400.0) / math.tanh(2.0))
    elif e == "added_mass_kc_mixed":
        kc_ref = 2 * math.pi * fin.phi_tip * _reference_amplitude(fin, case.voltages_pp) / fin.b
        a = s / kc_ref
        law = replace(law, mass_kc=a, mass_kc2=2 * a)
    elif e == "warming_capacitance":
        law = replace(law, capacitance=warming)
    elif e == "warming_resonance":
        law = replace(law, stiffness=warming**2)
    elif e == "warming_coupling":
        law = replace(law, coupling=warming)
    elif e == "amplifier_rms_limit":
        free = simulate_law(fin, law, f, vpp, duration=DURATION_S, rate_hz=RATE_HZ)
        tail = free.t >= DURATION_S - 2.0
        i_rms = np.sqrt(np.mean(free.current[:, tail] ** 2, axis=1))
        limit = s * float(np.max(i_rms))
        law = replace(law, voltage_scale=np.minimum(1.0, limit / i_rms))
    run = simulate_law(fin, law, f, vpp, duration=DURATION_S, rate_hz=RATE_HZ)

    def readings(
        j: int, t: FloatArray, v: FloatArray, i: FloatArray, u: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        if e == "vibrometer_lowpass":
            u = _lowpass(t, u, s)
        elif e == "current_lowpass":
            i = _lowpass(t, i, 1.0 / (2 * math.pi * s * 1e-3))
        elif e == "voltage_monitor":
            v = s * v
        elif e == "vibrometer_reversed":
            u = -u
        elif e == "current_reversed":
            i = -i
        elif e == "mains":
            i = i + s * np.sin(2 * math.pi * 50.0 * (t + when[j]) + 0.3)
        return v, i, u

    label = f"{e}={s:.3g}" if e else "clean"
    return measure(
        fin, run, f, vpp, when, rng, f"blind {case.fin} {label} seed {case.seed}", readings=readings
    )


def named_family(d: Any) -> str | None:
    """The family a diagnosis points at: its chosen effects' (one family), the family of the least-bad
    candidate it states, a reversed sensor it found, or None (no gap, or no family)."""
    for note in d.notes:
        if "vibrometer's sign is reversed" in note:
            return "vibrometer reversed"
        if "current monitor's sign is reversed" in note:
            return "current monitor reversed"
    if d.chosen is not None:
        fams = {effect_class(n).family for n in d.chosen.effects}
        return fams.pop() if len(fams) == 1 else " + ".join(sorted(fams))
    return d.family or None
