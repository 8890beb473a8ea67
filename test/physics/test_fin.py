"""Fin presets (Tables 1-2), derived quantities and validation of fin files."""

from __future__ import annotations

from pathlib import Path

import pytest
from numpy.testing import assert_allclose

from piezofin_ros.physics.fin import FIELDS, Fin, FinConfigError, load_fin, preset_names, safe_load_yaml


def test_presets_are_the_papers_three() -> None:
    assert preset_names() == ["M8507-P1", "M8514-P1", "M8528-P1"]


@pytest.mark.parametrize(
    ("name", "psi", "f_water", "f_eq8_active"),
    [("M8507-P1", 5.18, 12.1, 39.4), ("M8514-P1", 3.88, 15.8, 46.5), ("M8528-P1", 2.08, 9.9, 40.1)],
)
def test_derived_quantities(name: str, psi: float, f_water: float, f_eq8_active: float) -> None:
    fin = load_fin(name)
    assert_allclose(fin.psi, psi, atol=0.005)
    # Linear underwater resonance f_sc / sqrt(1 + mu), from the inputs alone.
    assert_allclose(fin.f_water_linear, f_water, atol=0.05)
    # Table 2's D reproduces f_sc only with the active length (the notes' check of Eq. 8).
    assert_allclose(fin.f_eq8(), f_eq8_active, atol=0.05)
    assert_allclose(fin.mu, 3.141592653589793 / 4 * 1000 * fin.b**2 * fin.c_m / fin.m_s)
    assert_allclose(fin.m_v, fin.mu * fin.m_s)


def test_cm_override_replaces_eq21(m8528: Fin) -> None:
    fin = m8528.replace(c_m=0.69)
    assert fin.c_m == 0.69
    assert fin.mu < m8528.mu


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "fin.yaml"
    p.write_text(text)
    return p


def _preset_text(drop: str | None = None, **changes: str) -> str:
    fin = load_fin("M8528-P1").inputs()
    fin.update(changes)
    if drop:
        fin.pop(drop)
    return "\n".join(f"{k}: {v}" for k, v in fin.items())


def test_user_fin_round_trip(tmp_path: Path) -> None:
    fin = load_fin(_write(tmp_path, _preset_text(name="mine")))
    assert fin.name == "mine"
    assert fin.model_parameters()["psi"] == load_fin("M8528-P1").psi


@pytest.mark.parametrize("key", sorted(k for k in FIELDS if k not in ("c_d", "rho_w", "c_m")))
def test_missing_field_is_named(tmp_path: Path, key: str) -> None:
    with pytest.raises(FinConfigError, match=f"missing field '{key}'"):
        load_fin(_write(tmp_path, _preset_text(drop=key)))


@pytest.mark.parametrize(
    ("key", "value", "pattern"),
    [
        ("zeta", "1.5", r"field 'zeta' = 1.5 .* out of range; expected \[0.0001, 0.5\]"),
        ("L", "-0.1", r"field 'L' = -0.1 m is out of range"),
        ("theta", ".nan", r"field 'theta' = nan"),
        ("C_eq", "'19 nF'", r"field 'C_eq' must be a number in F"),
        ("m_s", "true", r"field 'm_s' must be a number"),
        ("L_active", "0.5", r"'L_active' = 0.5 m exceeds the overall length"),
    ],
)
def test_bad_values_name_the_key_and_range(tmp_path: Path, key: str, value: str, pattern: str) -> None:
    with pytest.raises(FinConfigError, match=pattern):
        load_fin(_write(tmp_path, _preset_text(**{key: value})))


def test_unknown_key_is_rejected(tmp_path: Path) -> None:
    with pytest.raises(FinConfigError, match=r"unknown field.*'zeta_percent'"):
        load_fin(_write(tmp_path, _preset_text(zeta_percent="1.3")))


def test_yaml_12_floats_and_no_code_execution(tmp_path: Path) -> None:
    assert safe_load_yaml("x: 1e-3") == {"x": 1e-3}
    evil = _preset_text() + "\nh: !!python/object/apply:os.system ['echo pwned']"
    with pytest.raises(FinConfigError, match="not valid YAML"):
        load_fin(_write(tmp_path, evil))


def test_unknown_preset_and_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(FinConfigError, match=r"unknown fin 'M9999'.*M8528-P1"):
        load_fin("M9999")
    with pytest.raises(FinConfigError, match="cannot read"):
        load_fin(tmp_path)
    with pytest.raises(FinConfigError, match="expected a mapping"):
        load_fin(_write(tmp_path, "- 1\n- 2\n"))


def test_optional_fields_take_the_documented_defaults(tmp_path: Path) -> None:
    text = "\n".join(line for line in _preset_text().splitlines() if not line.startswith(("c_d:", "rho_w:")))
    fin = load_fin(_write(tmp_path, text))
    assert fin.c_d == 8.0  # assumed: Graham (1980) flat plate at KC ~ 1, see fin.py
    assert fin.rho_w == 1000.0
    assert fin.c_m_override is None
    # The assumption matters: drag scales gamma linearly.
    assert fin.replace(c_d=4.0).gamma == pytest.approx(fin.gamma / 2)
