"""Stepped-sine experiments on the simulated rig, without ROS (the tests' and benchmarks' data).

The live suite records the same experiment through ``fin_sim`` and the ``controller``'s ``frf``
mode; this drives :class:`~piezofin_ros.rig.simulated.SimulatedRig` directly, the same model and
instruments, so that identification can be checked on many fins quickly.  ``medium="air"`` is the
paper's in-air test (no hydrodynamic load: ``rho_w = 0``, footnote 2).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..physics import hydro, modeshape
from ..physics.fin import Fin, in_medium
from ..physics.model import Model
from ..rig.simulated import DriveLimits, RigConfig, SimulatedRig
from .frf import FrfPoint, frf_points

FloatArray = NDArray[np.float64]


def settling_time(fin: Fin, medium: str, settled: float = 1e-3) -> float:
    """Time for the linear transient to fall to ``settled`` of its size, s (drag only shortens it)."""
    f = in_medium(fin, medium)
    decay = fin.zeta * fin.omega_n / (1.0 + f.mu)  # envelope rate of the linear underwater mode
    return math.log(1.0 / settled) / decay


@dataclass(frozen=True)
class SweepPlan:
    """A stepped sine: ``frequencies`` (Hz) at ``voltage_pp`` (V), ``dwell_s`` at each."""

    frequencies: tuple[float, ...]
    voltage_pp: float
    dwell_s: float

    @classmethod
    def around(cls, fin: Fin, medium: str, voltage_pp: float, n: int = 31, span: float = 0.35) -> SweepPlan:
        """``n`` points over ``+-span`` of the expected resonance, denser near it, with a dwell that
        settles the slowest step (two settling times, at least 40 periods of the lowest frequency)."""
        f0 = in_medium(fin, medium).f_water_linear
        u = np.linspace(-1.0, 1.0, n)
        freqs = f0 * (1.0 + span * np.sign(u) * np.abs(u) ** 1.5)
        dwell = max(2.0 * settling_time(fin, medium), 40.0 / float(freqs.min()), 2.0)
        return cls(tuple(float(x) for x in freqs), float(voltage_pp), float(dwell))


def stepped_sine(
    fin: Fin,
    plan: SweepPlan,
    medium: str = "water",
    rig: RigConfig | None = None,
    seed: int = 0,
    block_s: float = 0.5,
    model: Model | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Samples ``t, voltage, current, tip_velocity`` of ``plan`` on the simulated rig in ``medium``
    (the fin of ``model`` with its effects, when given: ``fin`` is then ignored)."""
    config = rig or RigConfig()
    limits = DriveLimits(frequency_min_hz=0.1, frequency_max_hz=1000.0, voltage_pp_max=1000.0)
    if model is not None:
        fin = in_medium(model.fin, medium)
        model = Model(fin, model.effects)
    knobs = None if model is None else model.knobs_at
    sim = SimulatedRig(in_medium(fin, medium), config, limits, seed=seed, model=knobs)
    n_block = max(1, round(block_s * config.sample_rate_hz))
    out: list[tuple[FloatArray, ...]] = []
    for f in plan.frequencies:
        sim.command(f, plan.voltage_pp, 1)
        n = round(plan.dwell_s * config.sample_rate_hz)
        while n > 0:
            b = sim.step(min(n_block, n))
            n -= b.t.size
            out.append((b.t, b.voltage, b.current, b.tip_velocity))
            sim.command(f, plan.voltage_pp, 1)  # the heartbeat
    t, v, i, u = (np.concatenate([o[k] for o in out]) for k in range(4))
    return t, v, i, u


def simulate_sweep(
    fin: Fin,
    plan: SweepPlan,
    medium: str = "water",
    rig: RigConfig | None = None,
    seed: int = 0,
    model: Model | None = None,
) -> list[FrfPoint]:
    """The FRF points a stepped sine on the simulated rig gives (see :func:`stepped_sine`)."""
    t, v, i, u = stepped_sine(fin, plan, medium, rig, seed, model=model)
    return frf_points(t, v, i, t, u)


def frequencies_text(values: Sequence[float]) -> str:
    return " ".join(f"{x:.3g}" for x in values)


def random_fin(rng: np.random.Generator, name: str = "random") -> Fin:
    """A valid fin unlike the presets: geometry, resonance, damping, coupling, capacitance, ``c_m``
    (Eq. 21 times 0.85-1.2) and ``c_d`` drawn over the ranges MFC bimorph fins span."""
    L = float(rng.uniform(0.05, 0.12))
    psi = float(rng.uniform(1.8, 6.0))
    b = L / psi
    m_s = float(rng.uniform(0.03, 0.12))
    f_sc = float(rng.uniform(20.0, 60.0))
    L_active = 0.83 * L
    D = (2 * math.pi * f_sc) ** 2 * m_s * L_active**4 / modeshape.LAMBDA1**4
    return Fin(
        name=name,
        L=L,
        L_active=L_active,
        b=b,
        b_active=0.65 * b,
        h=float(rng.uniform(4e-4, 9e-4)),
        m_s=m_s,
        f_sc=f_sc,
        D=D,
        zeta=float(rng.uniform(0.008, 0.03)),
        theta=float(rng.uniform(3e-3, 12e-3)),
        C_eq=float(rng.uniform(4e-9, 25e-9)),
        c_d=float(rng.uniform(3.0, 15.0)),
        c_m_override=float(hydro.inertia_coefficient(psi)) * float(rng.uniform(0.85, 1.2)),
    )
