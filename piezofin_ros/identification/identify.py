"""A fin from two sweeps: the in-air and the underwater stages together, the fin file they give, and
the table that says how each value was found and how well.

:func:`identify` runs :func:`~.fit.identify_air` then :func:`~.fit.identify_water` and builds the
:class:`~piezofin_ros.physics.fin.Fin` the rest of the suite loads (Table 1 from the geometry given,
Table 2, ``c_m`` and ``c_d`` identified).  :meth:`Identification.fin_yaml` writes it with each
value's uncertainty and method as a comment; :func:`load_geometry` reads Table 1 from a fin file or a
preset (any Table 2 values in it are ignored).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from ..physics.fin import FIELDS, Fin, FinConfigError, load_fin, read_yaml_file
from .fit import GEOMETRY, Identified, identify_air, identify_water
from .frf import FrfPoint, IdentificationError
from .signs import Signs

#: Table 2 placeholders for a fin whose geometry only is known (replaced by the identification).
_PLACEHOLDERS = {"f_sc": 10.0, "D": 1.0, "zeta": 0.01, "theta": 1e-3, "C_eq": 1e-9}


def load_geometry(name_or_path: str | os.PathLike[str]) -> Fin:
    """Table 1 (``L, L_active, b, b_active, h, m_s``; optional ``rho_w``) from a preset or a YAML file.

    A file may hold the geometry only; Table 2 values in it are not used.
    """
    text = str(name_or_path)
    if not os.path.exists(text):
        return load_fin(text)  # a preset name (or a clear error naming the presets)
    data = read_yaml_file(text)
    if isinstance(data, Mapping) and isinstance(data.get("fin"), Mapping):
        data = data["fin"]
    if not isinstance(data, Mapping):
        raise FinConfigError(f"{text}: expected a mapping of fin fields")
    missing = [k for k in GEOMETRY if k not in data]
    if missing:
        raise FinConfigError(
            f"{text}: the geometry needs {', '.join(missing)} "
            f"({'; '.join(f'{k}: {FIELDS[k].description}, {FIELDS[k].unit}' for k in missing)})"
        )
    merged = {**_PLACEHOLDERS, **{k: v for k, v in data.items() if k in (*GEOMETRY, "name", "rho_w")}}
    merged.setdefault("name", os.path.splitext(os.path.basename(text))[0])
    return Fin.from_mapping(merged, source=text)


@dataclass(frozen=True)
class Identification:
    """Both stages and the fin they give (``water`` is ``None`` without an underwater sweep)."""

    geometry: Fin
    air: Identified
    water: Identified | None
    fin: Fin
    air_points: tuple[FrfPoint, ...]
    water_points: tuple[FrfPoint, ...]
    #: Reversed sensors found and corrected before the fit, in words.
    corrections: tuple[str, ...] = ()
    #: Checks across the two stages that failed (see :func:`identify`).
    checks: tuple[str, ...] = ()

    @property
    def warnings(self) -> list[str]:
        return self.air.warnings + (self.water.warnings if self.water else [])

    @property
    def problems(self) -> list[str]:
        """Why this fin is not to be trusted, each with its likely cause (empty: it can be used)."""
        return [*self.checks, *self.air.problems, *(self.water.problems if self.water else [])]

    @property
    def trusted(self) -> bool:
        return not self.problems

    def values(self) -> dict[str, Any]:
        """Every identified value with its sigma, unit, method and the other estimates (JSON-able)."""
        out: dict[str, Any] = {}
        for stage in (self.air, self.water):
            if stage is None:
                continue
            for name, e in stage.values.items():
                out[name] = {
                    "value": e.value,
                    "sigma": e.sigma,
                    "unit": e.unit,
                    "method": e.method,
                    "others": {k: float(v) for k, v in e.others.items()},
                    "bound": e.bound,  # the fit's bound it ended on (no estimate), or null
                }
        return out

    def table(self) -> str:
        """The identified parameters, one line each: value +- sigma, method, other estimates."""
        lines = [
            f"# {self.fin.name}: identified from {len(self.air_points)} in-air and "
            f"{len(self.water_points)} underwater points (+- one sigma)"
        ]
        for stage, label in ((self.air, "in air"), (self.water, "under water")):
            if stage is None:
                continue
            lines.append(f"{label}: chi2/n {stage.chi2_per_dof:.2f} over {stage.n_points} points")
            for name, e in stage.values.items():
                sig = f" +- {_fmt(e.sigma)}" if math.isfinite(e.sigma) else ""
                sig = f" (the fit's bound {_fmt(e.bound)}: no estimate)" if e.bound is not None else sig
                others = "; ".join(f"{k}: {_fmt(v)}" for k, v in e.others.items())
                lines.append(
                    f"  {name:<6} {_fmt(e.value)}{sig} {e.unit}  "
                    f"({e.method}{'; ' + others if others else ''})"
                )
        for w in self.corrections:
            lines.append(f"corrected: {w}")
        for w in self.warnings:
            lines.append(f"note: {w}")
        for w in self.problems:
            lines.append(f"NOT TRUSTED: {w}")
        return "\n".join(lines)

    def fin_yaml(self) -> str:
        """The fin file: Table 1 as given, Table 2, ``c_m`` and ``c_d`` as identified."""
        values = self.values()
        lines = [
            f"# {self.fin.name}: identified by `piezofin identify` from stepped-sine sweeps",
            "# (in air: f_sc, zeta, theta, C_eq, D; under water: c_m, c_d).  SI units; +- is one sigma.",
            *(f"# corrected: {w}" for w in self.corrections),
            *(f"# note: {w}" for w in self.warnings),
            *(f"# NOT TRUSTED: {w}" for w in self.problems),
        ]
        for key in ("name", *FIELDS):
            value = self.fin.inputs().get(key)
            if value is None:
                continue
            note = ""
            if key in values:
                v = values[key]
                sig = f" +- {_fmt(v['sigma'])}" if math.isfinite(v["sigma"]) else " (sigma: not identified)"
                note = f"  # identified{sig}: {v['method']}"
            elif key in GEOMETRY or key == "rho_w":
                note = "  # given (Table 1)"
            lines.append(f"{key}: {value if isinstance(value, str) else repr(float(value))}{note}")
        return "\n".join(lines) + "\n"


def _fmt(x: float) -> str:
    return f"{x:.5g}" if math.isfinite(x) else "nan"


#: An in-air resonance this far (as a ratio, either way) from the one the geometry's fin file states
#: is not that fin's in air.
FAR_FROM_GEOMETRY = 1.5


def known_resonance(name_or_path: str | os.PathLike[str]) -> float | None:
    """The ``f_sc`` a preset or a fin file states beside its geometry (``None`` for Table 1 alone)."""
    text = str(name_or_path)
    if not os.path.exists(text):
        return float(load_fin(text).f_sc)
    data = read_yaml_file(text)
    if isinstance(data, Mapping) and isinstance(data.get("fin"), Mapping):
        data = data["fin"]
    value = data.get("f_sc") if isinstance(data, Mapping) else None
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) and value > 0 else None


def correct_signs(points: Sequence[FrfPoint], label: str) -> tuple[list[FrfPoint], str]:
    """The points with a reversed sensor (:mod:`.signs`) turned back, and what was corrected ("" if
    nothing): the voltage for both, else the tip velocity or the current."""
    tip_power = [(p.tip * p.voltage.conjugate()).real for p in points]
    drive_power = [(p.current * p.voltage.conjugate()).real for p in points]
    signs = Signs.check(tip_power, drive_power)
    if not signs.any:
        return list(points), ""
    if signs.tip and signs.power:
        field, what = "voltage", "voltage x -1"
    elif signs.tip:
        field, what = "tip", "tip velocity x -1"
    else:
        field, what = "current", "current x -1"
    fixed = [replace(p, **{field: -getattr(p, field)}) for p in points]
    return fixed, (
        f"{label}: {signs.which}: the fin would be giving power back ({signs.symptom}); "
        f"corrected ({what}) before the fit. Sign conventions: docs/reference.md"
    )


def identify(
    air_points: Sequence[FrfPoint],
    water_points: Sequence[FrfPoint] | None,
    geometry: Fin,
    name: str | None = None,
    expected_f_sc: float | None = None,
) -> Identification:
    """Identify a fin from its in-air (and underwater) sweep points, Table 1 from ``geometry``.

    A reversed sensor is corrected first and said (:attr:`Identification.corrections`); what makes
    the result untrustworthy is in :attr:`Identification.problems`, with its likely cause: a fit
    that does not fit, a value on a bound of the fit, an underwater resonance that is not below the
    in-air one (the sweeps swapped?), an in-air resonance far from ``expected_f_sc`` (the one the
    geometry's fin file states, when it does).
    """
    air_points, said_air = correct_signs(air_points, "in air")
    corrections = [said_air] if said_air else []
    air = identify_air(air_points, geometry)
    v = {k: e.value for k, e in air.values.items()}
    try:
        fin = geometry.replace(
            name=name or geometry.name,
            f_sc=v["f_sc"],
            D=v["D"],
            zeta=v["zeta"],
            theta=v["theta"],
            C_eq=v["C_eq"],
        )
    except FinConfigError as exc:
        raise IdentificationError(f"the in-air sweep gives no valid fin: {exc}") from None
    problems: list[str] = []
    if expected_f_sc and not 1 / FAR_FROM_GEOMETRY <= v["f_sc"] / expected_f_sc <= FAR_FROM_GEOMETRY:
        below = v["f_sc"] < expected_f_sc
        problems.append(
            f"the in-air resonance {v['f_sc']:.3g} Hz is far from the {expected_f_sc:.3g} Hz that the "
            "geometry's fin file states: "
            + ("is --air an underwater sweep (the bags swapped)?" if below else "is this its fin?")
        )
    water = None
    if water_points:
        water_points, said_water = correct_signs(water_points, "under water")
        corrections += [said_water] if said_water else []
        sigma = {k: air.values[k].sigma for k in ("f_sc", "zeta", "theta")}
        water = identify_water(water_points, fin, air_sigma=sigma)
        f_w = water["f_w"].value
        if f_w >= v["f_sc"]:
            problems.append(
                f"the underwater resonance {f_w:.3g} Hz is not below the in-air one {v['f_sc']:.3g} Hz, "
                "as added mass makes it: are --air and --water swapped?"
            )
        fin = fin.replace(c_m=water["c_m"].value, c_d=water["c_d"].value)
    return Identification(
        geometry,
        air,
        water,
        fin,
        tuple(air_points),
        tuple(water_points or ()),
        tuple(corrections),
        tuple(problems),
    )
