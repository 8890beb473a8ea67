"""The paper's own gap, from the little it reports (``piezofin diagnose --paper``).

The paper gives no per-trial table, only two numbers for M8528-P1 at 800 Vpp (see the reading
notes): a resonance near 5.5 Hz (its representative run; the linear model says 9.9 Hz) and a
maximum of about 60.7 mN/W for Lighthill's thrust over the mean power (the model gives hundreds).
Two numbers cannot rank fourteen effects, so this check asks a narrower question of each
candidate and of each pair: *can it reproduce both numbers at all, and with what parameters?*
It reports the candidates that can, says that the data cannot decide between them, and names
the measurement that would.
"""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from ..physics.effects import LIBRARY
from ..physics.fin import Fin
from ..physics.model import Model
from .space import ParamSpace


@dataclass(frozen=True)
class Fact:
    name: str  # "resonance_hz" or "max_thrust_per_watt"
    voltage_pp: float
    value: float
    sigma: float
    source: str


PAPER_FACTS = (
    Fact(
        "resonance_hz",
        800.0,
        5.5,
        0.5,
        "representative run at 5.5 Hz, 800 Vpp (Fig. 6); 'near' read as +-0.5 Hz",
    ),
    Fact(
        "max_thrust_per_watt",
        800.0,
        0.0607,
        0.006,
        "max Lighthill thrust / mean power, 60.7 mN/W (Fig. 10b); +-10 %",
    ),
)
GRID = np.linspace(1.0, 11.0, 101)  # the paper's sweep, 0.1 Hz
# The paper's fin is clamped in quiescent water (U -> 0 in Eq. 19), and its thrust per watt is
# Lighthill's thrust on the measured motion, not a load-cell reading: these effects cannot be
# the cause of its gap, whatever they would fit.
NOT_IN_THE_PAPERS_SETUP = {
    "swim_speed": "quiescent water, U -> 0",
    "loadcell_offset": "T/P uses Lighthill's thrust on the motion, not the load cell",
    "loadcell_gain": "T/P uses Lighthill's thrust on the motion, not the load cell",
}
CANDIDATES = tuple(n for n in LIBRARY if n not in NOT_IN_THE_PAPERS_SETUP)


def quantities(model: Model, voltage_pp: float) -> dict[str, float]:
    p = model.predict(GRID, np.full(GRID.size, voltage_pp))
    tpw = np.divide(p.thrust_n, p.power_w, out=np.zeros(GRID.size), where=p.power_w > 0)
    return {
        "resonance_hz": float(GRID[np.argmax(p.tip_velocity_rms)]),
        "max_thrust_per_watt": float(np.max(tpw)),
    }


@dataclass(frozen=True)
class FactFit:
    effects: tuple[str, ...]
    parameters: dict[str, dict[str, float]]
    predicted: dict[str, float]
    chi2: float

    @property
    def reproduces(self) -> bool:
        return self.chi2 <= 2.0 * 2  # both facts within ~2 sigma


def fit_facts(fin: Fin, names: tuple[str, ...], facts: tuple[Fact, ...] = PAPER_FACTS) -> FactFit:
    space = ParamSpace(fin, names)
    zlo, zhi = space.z_bounds

    def res(z: np.ndarray) -> np.ndarray:
        try:
            q = quantities(space.model(z), facts[0].voltage_pp)
        except ValueError:
            return np.full(len(facts), 1e3)
        return np.array([(q[f.name] - f.value) / f.sigma for f in facts])

    best = None
    for start in (0.5, 2.0, -0.5, 5.0):
        z0 = np.clip(np.full(len(space.params), start), zlo, zhi)
        sol = optimize.least_squares(res, z0, bounds=(zlo, zhi), diff_step=0.05, max_nfev=80)
        if best is None or sol.cost < best.cost:
            best = sol
    assert best is not None
    m = space.model(best.x)
    return FactFit(names, m.parameters(), quantities(m, facts[0].voltage_pp), float(2 * best.cost))


def paper_gap(
    fin: Fin, progress: Callable[[str], None] | None = None, workers: int | None = None
) -> dict[str, Any]:
    """Fit the paper's facts with every effect and every pair, on ``workers`` processes (default:
    one per core; 1 runs in this process)."""
    say = progress or (lambda _m: None)
    nominal = quantities(Model(fin), 800.0)
    combos = [(n,) for n in CANDIDATES] + list(itertools.combinations(CANDIDATES, 2))
    workers = workers or os.cpu_count() or 1
    fits: list[FactFit] = []
    if workers == 1:
        for j, names in enumerate(combos):
            say(f"paper facts: {' + '.join(names)} ({j + 1}/{len(combos)})")
            fits.append(fit_facts(fin, names))
    else:
        with ProcessPoolExecutor(workers) as pool:
            jobs = [pool.submit(fit_facts, fin, names) for names in combos]
            for j, job in enumerate(as_completed(jobs)):
                fits.append(job.result())
                say(f"paper facts: {' + '.join(fits[-1].effects)} ({j + 1}/{len(combos)})")
    singles = [r for r in fits if len(r.effects) == 1]
    pairs = [r for r in fits if len(r.effects) == 2 and r.reproduces]
    return {
        "facts": [f.__dict__ for f in PAPER_FACTS],
        "nominal": nominal,
        "singles": sorted(singles, key=lambda r: (r.chi2, r.effects)),
        "pairs": sorted(pairs, key=lambda r: (r.chi2, r.effects)),
    }


def paper_text(fin: Fin, r: dict[str, Any]) -> str:
    nom = r["nominal"]
    lines = [
        f"# The paper's own gap: {fin.name} at 800 Vpp",
        "",
        "| quantity | paper | nominal model |",
        "|---|---:|---:|",
        f"| resonance (largest tip velocity) | 5.5 Hz | {nom['resonance_hz']:.1f} Hz |",
        f"| max thrust / power | 60.7 mN/W | {nom['max_thrust_per_watt'] * 1e3:.0f} mN/W |",
        "",
        "Not tried, as they cannot act in the paper's setup: "
        + "; ".join(f"{n} ({why})" for n, why in NOT_IN_THE_PAPERS_SETUP.items())
        + ".",
        "",
        "## One effect alone",
        "",
        "| effect | parameters | resonance | max T/P | reproduces both |",
        "|---|---|---:|---:|---|",
    ]
    for s in r["singles"]:
        ps = "; ".join(", ".join(f"{k}={v:.3g}" for k, v in p.items()) for p in s.parameters.values())
        lines.append(
            f"| {s.effects[0]} | {ps} | {s.predicted['resonance_hz']:.1f} Hz | "
            f"{s.predicted['max_thrust_per_watt'] * 1e3:.0f} mN/W | {'yes' if s.reproduces else 'no'} |"
        )
    lines += [
        "",
        f"## Pairs that reproduce both numbers: {len(r['pairs'])} of {math.comb(len(CANDIDATES), 2)}",
        "",
    ]
    for p in r["pairs"][:25]:
        ps = "; ".join(
            f"{n}: " + ", ".join(f"{k}={v:.3g}" for k, v in q.items()) for n, q in p.parameters.items()
        )
        lines.append(f"- {' + '.join(p.effects)} ({ps})")
    if len(r["pairs"]) > 25:
        lines.append(f"- ... and {len(r['pairs']) - 25} more")
    ok_single = [s.effects[0] for s in r["singles"] if s.reproduces]
    lines += [
        "",
        "## What this little data decides, and what it cannot",
        "",
        (
            f"- One effect alone reproduces both numbers: {', '.join(ok_single)}."
            if ok_single
            else "- No single effect reproduces both numbers: the resonance shift and the low thrust per watt need "  # noqa: E501
            "(at least) two causes, one that softens or loads the fin and one that costs power without motion."  # noqa: E501
        ),
        "- Two numbers cannot tell the candidates apart: every pair listed fits them within about 2 sigma, with two "  # noqa: E501
        "parameters for two numbers.  What separates them:",
        "  - the resonance at 400 and 600 Vpp (an electroelastic or geometric softening moves it with the drive; a "  # noqa: E501
        "linear stiffness or added-mass error does not);",
        "  - the power against the motion (stage 'current'): a loss current shows up without motion, a dissipative "  # noqa: E501
        "nonlinearity only with it;",
        "  - the load-cell thrust against Lighthill's from the tip velocity (stage 'thrust').",
        "- The paper's Figs. 7-9 hold those sweeps; digitised into a CSV, `piezofin diagnose sweep.csv` runs the full diagnosis.",  # noqa: E501
    ]
    return "\n".join(lines) + "\n"
