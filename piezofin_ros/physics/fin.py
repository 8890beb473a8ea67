"""Fin description: the measured inputs of Tables 1-2 and every quantity derived from them.

A :class:`Fin` holds only *inputs* (what one measures or assumes); everything the model
derives from them (``psi``, ``c_m``, ``mu``, ``gamma``, ``m_v``, ``omega_n``, the linear
underwater resonance) is a property, so no number is ever typed in twice.

Modelling choices where the paper is ambiguous or silent (see ``shared/notes``):

* **Which length.** ``L`` is the *overall* overhang length and ``b`` the *overall* width:
  the paper says so for the hydrodynamic load (below Eq. 3) and the aspect ratio
  ``psi = L/b`` then gives 2.08, 3.88, 5.18 (the paper rounds to 2.1, 3.9, 5.4).  The mode
  shape, its integrals and the tip (x = L) of Eq. (19) use the same ``L``.
* **Natural frequency.** ``omega_n = 2 pi f_sc`` with the *measured* in-air short-circuit
  resonance of Table 2 (in air approximates in vacuo, footnote 2).  Eq. (8) with Table 2's
  ``D`` reproduces ``f_sc`` only with the *active* length (40.1, 46.5, 39.4 Hz against
  38.1, 46.4, 35.5 Hz); :meth:`Fin.f_eq8` exposes that check instead of using it.
* **Drag coefficient.** ``c_d`` is not given in the paper (it points to its ref. [34]).
  The default, 8.0, is Graham's (1980, the paper's ref. [28]) flat-plate law for
  oscillatory flow at low Keulegan-Carpenter number, ``c_d ~ 8 KC^(-1/3)``, at KC ~ 1,
  the tip KC of these fins at 400-800 Vpp.  It is an assumption: ``piezofin sweep`` shows
  what it changes, and the diagnosis tool can identify it from data.
* **Inertia coefficient.** ``c_m`` comes from Eq. (21) at the derived ``psi`` unless a
  fin file sets ``c_m`` explicitly (an identified value, which then overrides Eq. 21).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import yaml

from ..errors import PhysicsError
from ..files import open_regular
from . import hydro, modeshape


class FinConfigError(PhysicsError):
    """A fin description is missing a field, has a field of the wrong type or out of range."""


class FieldSpec(NamedTuple):
    unit: str
    low: float
    high: float
    description: str
    low_inclusive: bool = False


#: Every numeric input of a fin: SI unit, admissible range, meaning.
FIELDS: dict[str, FieldSpec] = {
    "L": FieldSpec("m", 1e-3, 2.0, "overall overhang length (Table 1)"),
    "L_active": FieldSpec("m", 1e-3, 2.0, "active (piezo-covered) length (Table 1)"),
    "b": FieldSpec("m", 1e-3, 1.0, "overall width (Table 1)"),
    "b_active": FieldSpec("m", 1e-3, 1.0, "active width (Table 1)"),
    "h": FieldSpec("m", 1e-5, 0.05, "total thickness (Table 1)"),
    "m_s": FieldSpec("kg/m", 1e-4, 100.0, "structural mass per unit length (Table 1)"),
    "f_sc": FieldSpec("Hz", 0.1, 1e4, "in-air short-circuit resonance frequency (Table 2)"),
    "D": FieldSpec("N m^2", 1e-8, 1e4, "bending stiffness (Table 2)"),
    "zeta": FieldSpec("-", 1e-4, 0.5, "modal mechanical damping ratio (Table 2)", True),
    "theta": FieldSpec("C/(m sqrt(kg))", 1e-7, 1.0, "modal electromechanical coupling (Table 2)"),
    "C_eq": FieldSpec("F", 1e-12, 1e-3, "equivalent capacitance (Table 2)"),
    "c_d": FieldSpec("-", 0.0, 100.0, "Morison drag coefficient (assumed, see docs)", True),
    "rho_w": FieldSpec("kg/m^3", 0.0, 2000.0, "density of the surrounding fluid", True),
    "c_m": FieldSpec("-", 0.0, 5.0, "inertia coefficient override (default: Eq. 21)", True),
}


@dataclass(frozen=True)
class Fin:
    """An MFC bimorph fin, in SI units.  Construct from Table-like inputs; see :data:`FIELDS`."""

    name: str
    L: float
    L_active: float
    b: float
    b_active: float
    h: float
    m_s: float
    f_sc: float
    D: float
    zeta: float
    theta: float
    C_eq: float
    c_d: float = 8.0
    rho_w: float = 1000.0
    c_m_override: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise FinConfigError("fin field 'name': expected a non-empty string")
        for key in FIELDS:
            attr = "c_m_override" if key == "c_m" else key
            value = getattr(self, attr)
            if value is None and key == "c_m":
                continue
            _check_number(key, value, FIELDS[key], where=f"fin '{self.name}'")
            object.__setattr__(self, attr, float(value))  # ints from YAML become floats
        if self.L_active > self.L:
            raise FinConfigError(
                f"fin '{self.name}': field 'L_active' = {self.L_active} m exceeds the overall "
                f"length L = {self.L} m"
            )
        if self.b_active > self.b:
            raise FinConfigError(
                f"fin '{self.name}': field 'b_active' = {self.b_active} m exceeds the overall "
                f"width b = {self.b} m"
            )

    # ----- derived quantities (never stored twice) -------------------------------------
    @property
    def psi(self) -> float:
        """Aspect ratio ``psi = L/b`` (overall length over overall width)."""
        return self.L / self.b

    @property
    def c_m(self) -> float:
        """Inertia coefficient: the override if given, else Eq. (21) at ``psi``."""
        if self.c_m_override is not None:
            return float(self.c_m_override)
        return float(hydro.inertia_coefficient(self.psi))

    @property
    def mu(self) -> float:
        """Added-mass ratio ``(pi/4) rho_w b^2 c_m / m_s`` (Eq. 9)."""
        return hydro.added_mass_ratio(self.rho_w, self.b, self.c_m, self.m_s)

    @property
    def gamma(self) -> float:
        """Modal drag ``(1/2) rho_w b c_d int_0^L phi^2|phi| dx`` (Eq. 9; 61 Gauss points)."""
        shape = self.L * (self.m_s * self.L) ** -1.5 * modeshape.DRAG_SHAPE_FACTOR
        return 0.5 * self.rho_w * self.b * self.c_d * shape

    @property
    def m_v(self) -> float:
        """Virtual mass per unit length at the tip (Eq. 20), kg/m."""
        return hydro.virtual_mass(self.rho_w, self.b, self.c_m)

    @property
    def omega_n(self) -> float:
        """In-vacuo natural frequency, rad/s, from the measured ``f_sc`` (not Eq. 8)."""
        return 2.0 * math.pi * self.f_sc

    @property
    def phi_tip(self) -> float:
        """``phi(L) = 2/sqrt(m_s L)`` (Eq. 5, sign: positive), 1/sqrt(kg)."""
        return modeshape.TIP_VALUE / math.sqrt(self.m_s * self.L)

    @property
    def phi_tip_slope(self) -> float:
        """``phi'(L) = 1.3765 phi(L)/L``, 1/(m sqrt(kg))."""
        return self.phi_tip * modeshape.TIP_SLOPE_RATIO / self.L

    @property
    def f_water_linear(self) -> float:
        """Linear underwater resonance ``f_sc / sqrt(1 + mu)``, Hz (small amplitude, no drag)."""
        return self.f_sc / math.sqrt(1.0 + self.mu)

    @property
    def c_tau(self) -> float:
        """Thrust coefficient ``0.393 c_m/psi`` (Eq. 23) of this fin."""
        return float(hydro.thrust_coefficient_from_cm(self.c_m, self.psi))

    def f_eq8(self, length: float | None = None) -> float:
        """Eq. (8) natural frequency from ``D`` with the given length (default: active), Hz."""
        ell = self.L_active if length is None else length
        return modeshape.LAMBDA1**2 * math.sqrt(self.D / (self.m_s * ell**4)) / (2 * math.pi)

    def replace(self, **changes: Any) -> Fin:
        """A copy with some inputs changed (validated again)."""
        if "c_m" in changes:
            changes["c_m_override"] = changes.pop("c_m")
        return dataclasses.replace(self, **changes)

    # ----- serialisation ---------------------------------------------------------------
    def inputs(self) -> dict[str, Any]:
        """The inputs as a YAML/JSON-ready mapping under the paper's symbol names."""
        out: dict[str, Any] = {"name": self.name}
        for key in FIELDS:
            value = self.c_m_override if key == "c_m" else getattr(self, key)
            if value is not None:
                out[key] = value
        return out

    def model_parameters(self) -> dict[str, float | str]:
        """Every parameter the model uses, inputs and derived, SI, under the paper's symbols."""
        return {
            "name": self.name,
            "L": self.L,
            "L_active": self.L_active,
            "b": self.b,
            "b_active": self.b_active,
            "h": self.h,
            "m_s": self.m_s,
            "f_sc": self.f_sc,
            "D": self.D,
            "zeta": self.zeta,
            "theta": self.theta,
            "C_eq": self.C_eq,
            "psi": self.psi,
            "c_m": self.c_m,
            "c_d": self.c_d,
            "rho_w": self.rho_w,
            "mu": self.mu,
            "gamma": self.gamma,
            "m_v": self.m_v,
            "omega_n": self.omega_n,
            "phi_L": self.phi_tip,
            "f_water_linear": self.f_water_linear,
            "c_tau": self.c_tau,
        }

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str = "<mapping>") -> Fin:
        """Build a fin from a mapping of inputs, naming ``source`` and the key on any error."""
        if not isinstance(data, Mapping):
            raise FinConfigError(f"{source}: expected a mapping of fin fields, got {type(data).__name__}")
        unknown = sorted(set(data) - set(FIELDS) - {"name", "description"})
        if unknown:
            raise FinConfigError(
                f"{source}: unknown field(s) {', '.join(map(repr, unknown))}; "
                f"known fields: name, {', '.join(FIELDS)}"
            )
        kwargs: dict[str, Any] = {"name": data.get("name", Path(source).stem)}
        for key, spec in FIELDS.items():
            attr = "c_m_override" if key == "c_m" else key
            if data.get(key) is not None:
                kwargs[attr] = data[key]  # type and range are checked by the constructor
            elif attr not in _OPTIONAL:  # optional fields missing or null take their defaults
                raise FinConfigError(
                    f"{source}: missing field '{key}' ({spec.description}, {spec.unit}, "
                    f"expected in {_range_text(spec)})"
                )
        try:
            return cls(**kwargs)
        except FinConfigError as exc:
            raise FinConfigError(f"{source}: {exc}") from None


#: Inputs with a default in :class:`Fin` (``c_d``, ``rho_w``, ``c_m``): a fin file may omit them.
_OPTIONAL = frozenset(f.name for f in dataclasses.fields(Fin) if f.default is not dataclasses.MISSING)


def _range_text(spec: FieldSpec) -> str:
    return f"{'[' if spec.low_inclusive else '('}{spec.low:g}, {spec.high:g}]"


def _check_number(key: str, value: Any, spec: FieldSpec, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FinConfigError(
            f"{where}: field '{key}' must be a number in {spec.unit} ({spec.description}), "
            f"got {type(value).__name__} {value!r}"
        )
    ok_low = value >= spec.low if spec.low_inclusive else value > spec.low
    if not (math.isfinite(value) and ok_low and value <= spec.high):
        raise FinConfigError(
            f"{where}: field '{key}' = {value!r} {spec.unit} is out of range; expected "
            f"{_range_text(spec)} {spec.unit} ({spec.description})"
        )


#: Where a fin is tested: ``water`` (the fin as described) or ``air`` (the paper's in-air tests,
#: which approximate in vacuo, footnote 2: no hydrodynamic load, ``rho_w = 0`` so ``mu = gamma = 0``).
MEDIA = ("water", "air")


def in_medium(fin: Fin, medium: str) -> Fin:
    """The fin as tested in ``medium`` (see :data:`MEDIA`)."""
    if medium not in MEDIA:
        raise FinConfigError(f"medium must be one of {', '.join(MEDIA)}, got {medium!r}")
    return fin.replace(rho_w=0.0) if medium == "air" else fin


# ----- presets and files ------------------------------------------------------------------
class SafeLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` (no code execution) that also reads ``1e-3`` as a float (YAML 1.2).

    PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent, so ``1e-3``
    would load as the *string* "1e-3"; physical parameters are written that way all the time.
    Aliases (``*name``) are refused: no configuration needs them, and nested aliases make a few
    hundred bytes expand into a structure that takes exponential time to walk ("billion laughs").
    """

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, "aliases (*name) are not accepted", mark)
        return super().compose_node(parent, index)


SafeLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
        |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


def safe_load_yaml(text: str) -> Any:
    """Parse YAML without executing anything (safe loader, YAML 1.2 floats, no aliases)."""
    return yaml.load(text, Loader=SafeLoader)


#: Largest YAML file read.  Fin, model and parameter files are a few kB; a larger file is refused
#: before it is parsed, so no file can hold a loader (and a SIGTERM) for long.
MAX_YAML_BYTES = 256 * 1024


def read_yaml_file(
    path: str | os.PathLike[str], error: type[ValueError] = FinConfigError, max_bytes: int = MAX_YAML_BYTES
) -> Any:
    """Read and parse a YAML configuration file; any problem raises ``error`` naming the file.

    Bounded by ``max_bytes`` (:data:`MAX_YAML_BYTES`); an unsafe tag, an alias, nesting beyond the parser's
    recursion, an integer beyond Python's digit limit or bytes that are not UTF-8 are one error.
    """
    with open_regular(path, error) as fh:  # a FIFO, a device or a directory: refused, never waited on
        try:
            raw = fh.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{path}: cannot read ({exc.strerror or exc})") from None
    path = Path(path)
    if len(raw) > max_bytes:
        raise error(f"{path}: larger than {max_bytes // 1024} KiB, not a configuration file")
    try:
        return safe_load_yaml(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise error(f"{path}: not a text (UTF-8) file") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    except RecursionError:
        raise error(f"{path}: nested too deeply") from None
    except ValueError as exc:  # e.g. an integer beyond Python's digit limit
        raise error(f"{path}: {exc}") from None


def config_dir() -> Path:
    """The package's ``config/`` directory: source checkout, colcon/pip install, or $PIEZOFIN_CONFIG."""
    env = os.environ.get("PIEZOFIN_CONFIG")
    candidates = [Path(env)] if env else []
    here = Path(__file__).resolve()
    candidates.append(here.parents[2] / "config")  # source checkout / editable install
    # Installed trees: <prefix>/lib/pythonX.Y/site-packages/piezofin_ros/physics/fin.py
    #                  -> <prefix>/share/piezofin_ros/config (colcon and pip data_files)
    candidates += [p / "share" / "piezofin_ros" / "config" for p in here.parents]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "piezofin_ros" / "config")
    for cand in candidates:
        if (cand / "fins").is_dir():
            return cand
    raise FileNotFoundError(
        "cannot find the piezofin_ros config directory (looked in: "
        + ", ".join(str(c) for c in candidates[:3])
        + ", ...); set PIEZOFIN_CONFIG"
    )


def presets(folder: str) -> list[str]:
    """Names of the YAML presets shipped in ``config/<folder>``."""
    return sorted(p.stem for p in (config_dir() / folder).glob("*.yaml"))


def preset_names() -> list[str]:
    """Names of the fins shipped in ``config/fins``."""
    return presets("fins")


def preset_path(name_or_path: str | os.PathLike[str], folder: str, kind: str, error: type[Exception]) -> Path:
    """A file by path, or a preset by name (no suffix, no such file) from ``config/<folder>``;
    ``error`` naming the ``kind`` and the presets when it is neither."""
    text = str(name_or_path)
    if "\0" in text:
        raise error(f"{kind} {text!r}: not a usable file name (a NUL byte)")
    path = Path(text)
    if not path.suffix and not path.exists():
        path = config_dir() / folder / f"{text}.yaml"
        if not path.exists():
            raise error(
                f"unknown {kind} '{text}': not a file and not a preset ({', '.join(presets(folder))})"
            )
    return path


def load_fin(name_or_path: str | os.PathLike[str]) -> Fin:
    """Load a preset by name (``M8528-P1``) or a fin YAML file by path, validated.

    Raises :class:`FinConfigError` with the file and the offending key on any problem.
    """
    path = preset_path(name_or_path, "fins", "fin", FinConfigError)
    data = read_yaml_file(path)
    if isinstance(data, Mapping) and "fin" in data and isinstance(data["fin"], Mapping):
        data = data["fin"]
    return Fin.from_mapping(data, source=str(path))
