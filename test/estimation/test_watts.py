"""Thrust per watt in every watt: the fin's mean(v i), the apparent power, the supply through the
amplifier's model and the supply as its meter reads it, from the simulated rig's streams."""

from __future__ import annotations

import math

import numpy as np
import pytest

from piezofin_ros.estimation.estimator import Estimate, StreamEstimator, tpw_field
from piezofin_ros.physics.amplifier import WATT, LinearAmplifier, SwitchingAmplifier
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.model import Model
from piezofin_ros.rig.simulated import SimulatedRig

AMPLIFIERS = {
    "bench": LinearAmplifier(rail_v=400.0, quiescent_w=0.5),
    "fish": SwitchingAmplifier(efficiency=0.8, recovered=0.4, quiescent_w=0.05, bus_v=7.4),
}


def drive(rig_amp, est_amp, f: float = 6.0, vpp: float = 800.0, supply: bool = True) -> Estimate:
    """8 s of steady drive through the estimator: its running estimate."""
    fin = load_fin("M8528-P1")
    rig = SimulatedRig(fin, seed=4, amplifier=rig_amp)
    est = StreamEstimator(fin, amplifier=est_amp)
    out = []
    for _ in range(200):
        rig.command(f, vpp, 1)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
        if supply:
            out += est.add_supply(b.t, b.supply_voltage, b.supply_current)
    running = [e for e in out if not e.final]
    assert running, "no running estimate"
    return running[-1]


@pytest.mark.parametrize("name", list(AMPLIFIERS))
def test_every_watt_of_a_window_against_the_model_and_the_meter(name: str) -> None:
    amp = AMPLIFIERS[name]
    e = drive(amp, amp)
    p = Model(load_fin("M8528-P1")).predict([6.0], [800.0])
    supply = float(amp.steady(p.voltage_pp_drive, p.current_rms, p.power_w)[0])
    assert e.power_supply_w == pytest.approx(supply, rel=0.03)  # the model's steady state, 3 harmonics
    assert e.power_supply_measured_w == pytest.approx(e.power_supply_w, rel=0.01)  # the meter agrees
    assert e.power_apparent_w == pytest.approx(e.voltage_pp / (2 * math.sqrt(2)) * e.current_rms, rel=0.01)
    assert e.power_w < e.power_apparent_w  # a capacitor: the fin keeps a small part of what flows
    for watt in WATT:
        for source in ("vibrometer", "self"):
            thrust = e.thrust_n if source == "vibrometer" else e.thrust_self_n
            want = thrust / e.power(watt) if source == "self" else math.nan  # no vibrometer streamed
            got = getattr(e, tpw_field(watt, source))
            assert got == pytest.approx(e.thrust_per(watt, source), rel=1e-12, nan_ok=True)
            assert got == pytest.approx(want, rel=1e-12, nan_ok=True)


def test_a_rig_without_a_supply_meter_still_gives_the_modelled_supply() -> None:
    e = drive(AMPLIFIERS["bench"], AMPLIFIERS["bench"], supply=False)
    assert math.isnan(e.power_supply_measured_w) and math.isnan(e.thrust_per_watt_self_supply_measured)
    assert all(math.isfinite(e.power(w)) for w in ("fin", "apparent", "supply"))


def test_a_wrong_amplifier_model_shows_as_a_supply_gap() -> None:
    """The estimator told the bench's amplifier while the fish's drives: the modelled supply is off the
    measured one by far more than the meter's noise, the fin's watt not at all."""
    right = drive(AMPLIFIERS["fish"], AMPLIFIERS["fish"])
    wrong = drive(AMPLIFIERS["fish"], AMPLIFIERS["bench"])
    assert wrong.power_w == pytest.approx(right.power_w, rel=1e-12)
    assert wrong.power_supply_measured_w == pytest.approx(right.power_supply_measured_w, rel=1e-12)
    assert wrong.power_supply_w > 3 * wrong.power_supply_measured_w


def test_in_air_no_thrust_is_estimated_only_motion_and_power() -> None:
    """An in-air sweep (the paper's identification tests): no fluid, so no Lighthill thrust and no thrust
    per watt (the estimator had logged 193,787 mN/W there); the motion and every watt still are."""
    from piezofin_ros.errors import EstimationError
    from piezofin_ros.physics.fin import in_medium

    fin = load_fin("M8528-P1")
    rig = SimulatedRig(in_medium(fin, "air"), seed=4)
    est = StreamEstimator(fin, medium="air")
    out = []
    for _ in range(200):
        rig.command(38.0, 50.0, 1)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current) + est.add_tip(b.t, b.tip_velocity)
    e = out[-1]
    assert math.isnan(e.thrust_n) and math.isnan(e.thrust_self_n) and math.isnan(e.c_tau)
    assert all(math.isnan(getattr(e, tpw_field(w, s))) for w in WATT for s in ("vibrometer", "self"))
    assert e.tip_velocity_rms > 0 and e.power_w > 0 and e.power_supply_w > 0
    with pytest.raises(EstimationError, match="medium"):
        StreamEstimator(fin, medium="vacuum")


def battery_drive(fixed_given: float | None, hotel_w: float = 0.25, off_s: float = 4.0) -> list[Estimate]:
    """A fish without a supply meter: ``off_s`` with the drive off, then 6 Hz 800 Vpp; its battery read
    once a second (terminal 7.4 V, current negative as BatteryState counts a discharge): the supply's
    draw, plus a hotel load, through the pack."""
    fin = load_fin("M8528-P1")
    amp = AMPLIFIERS["fish"]
    rig = SimulatedRig(fin, seed=4, amplifier=amp)
    est = StreamEstimator(fin, amplifier=amp, fixed_draw_w=fixed_given)
    out: list[Estimate] = []
    since, draws = 0.0, []
    for k in range(int((off_s + 10.0) / 0.05)):
        on = k * 0.05 >= off_s
        rig.command(6.0 if on else 0.0, 800.0 if on else 0.0, 1 if on else 0)
        b = rig.step(50)
        out += est.add_drive(b.t, b.voltage, b.current)
        draws.append(float(np.mean(b.supply_voltage * b.supply_current)))
        if b.t[-1] - since >= 1.0:
            since = float(b.t[-1])
            power = float(np.mean(draws)) + hotel_w
            draws = []
            out += est.add_battery(since, 7.4, -power / 7.4)
    return [e for e in out if not e.final]


def test_a_fish_measures_its_supply_watt_on_its_battery() -> None:
    """Issue 39: the estimator's amplifier model read 0.77 and 1.18 times two fishes' true draw; a fish
    measures its battery: the draw less the fixed draw (given, or learnt with the drive off less the
    amplifier's own draw at 0 V, which the supply watt counts)."""
    for given in (None, 0.25):
        running = battery_drive(given)
        e = running[-1]
        # the meter's window is the battery's readings in it (1 Hz): within 2 % of the model on the
        # amplifier the rig drove, which the battery paid
        assert e.power_supply_measured_w == pytest.approx(e.power_supply_w, rel=0.02), given
        assert e.thrust_per_watt_self_supply_measured == pytest.approx(
            e.thrust_self_n / e.power_supply_measured_w, rel=1e-12
        )


def test_a_battery_whose_fixed_draw_is_not_known_measures_nothing() -> None:
    """Never driven off, the fixed draw is never learnt: no supply watt from the battery (the model's
    stays; the controller ranks by it and says so)."""
    e = battery_drive(None, off_s=0.0)[-1]
    assert math.isnan(e.power_supply_measured_w) and math.isfinite(e.power_supply_w)


@pytest.mark.parametrize("ahead_s", [0.0, 0.05, 0.3])
def test_the_fixed_draw_is_learnt_from_readings_that_come_before_the_drive_data(ahead_s: float) -> None:
    """Stop 45's flaky fish run: a battery reading stamped a moment past the drive data the estimator
    had (its message came first) was passed over, and a stack that drove 0.3 s after start learnt no
    fixed draw.  Now every reading is placed when the drive reaches its time: those with the drive
    off count, those with it on do not, whichever came first; one stamped far ahead (a clock gone
    wrong) holds nothing up."""
    fin = load_fin("M8528-P1")
    amp = AMPLIFIERS["fish"]
    est = StreamEstimator(fin, amplifier=amp)
    idle = amp.mean_draw(np.zeros(2), np.zeros(2))
    hotel_w, block_s = 0.25, 0.05
    est.add_battery(1e9, 7.4, -1.0)  # far ahead: never placed, never in the way
    for k in range(40):  # 0.6 s off, then on
        t = (k + np.arange(1, 51) / 50.0) * block_s
        on = t[0] >= 0.6
        v = 300.0 * np.sin(2 * np.pi * 6.0 * t) if on else np.zeros_like(t)
        reading_t = float(t[-1]) + ahead_s  # (stamped ahead of the block it comes before)
        if k % 4 == 0:  # 5 Hz
            draw = hotel_w + idle + (1.0 if reading_t >= 0.6 else 0.0)
            est.add_battery(reading_t, 7.4, -draw / 7.4)
        est.add_drive(t, v, 1e-4 * v)
    assert est.battery_fixed_draw_w == pytest.approx(hotel_w, rel=1e-9)
    assert est.supply_meter == "battery"


def test_each_watt_is_declared_once_in_its_registry() -> None:
    """Issue 40: the watts were strings in about ten places (three same-keyed dicts, ``watt != "fin"``
    in six modules, "supply_measured means supply" written three times).  Now one table: each watt's
    estimate field is an Estimate field that ``read`` returns, a measured watt is modelled by one that is
    not, and ``power_in`` is each watt's own law (the measured one: its model's); a watt with neither
    a law nor a model, or with neither a field nor a way to read it, is refused at its declaration."""
    from dataclasses import fields

    from piezofin_ros.errors import PiezofinError
    from piezofin_ros.physics.amplifier import AmplifierError, Watt, power_in, watt_of

    names = {f.name for f in fields(Estimate)}
    assert [w for w in WATT.values() if w.is_fin] == [WATT["fin"]]
    amp = SwitchingAmplifier(efficiency=0.8, recovered=0.5, quiescent_w=0.05)
    v, i, p = np.array([400.0, 800.0]), np.array([1e-3, 3e-3]), np.array([0.05, 0.2])
    for w in WATT.values():
        assert w.field in names and w.read({w.field: 0.25}) == 0.25 and math.isnan(w.read({}))
        assert not w.model.measured and (w.model is w) == (not w.measured)
        np.testing.assert_array_equal(power_in(w.name, v, i, p, amp), w.model.steady(v, i, p, amp))
    np.testing.assert_allclose(power_in("apparent", v, i, p, amp), v / (2 * math.sqrt(2)) * i)
    np.testing.assert_array_equal(power_in("supply_measured", v, i, p, amp), amp.steady(v, i, p))
    with pytest.raises(PiezofinError, match="unknown watt 'volts'"):
        watt_of("volts")
    for bad in (
        {"field": "power_w"},  # (neither a law nor a model)
        {"field": "power_w", "law": WATT["fin"].law, "modelled_as": "supply"},  # (both)
        {"field": "", "law": WATT["fin"].law},  # (no way to read it)
        {"field": "power_w", "law": WATT["fin"].law, "derive": lambda r: 0.0},  # (two)
    ):
        with pytest.raises(AmplifierError, match="'volts'"):
            Watt("volts", "", "", **bad)  # type: ignore[arg-type]


def test_each_thrust_source_is_declared_once_in_its_registry() -> None:
    """The sources were three tuples and ``source == "self"`` in eight places: now one table.  Each
    source's thrust is an Estimate field, and so is each of its thrusts per watt; the load cell has
    none, and asking for one is an error that names the sources that have them."""
    from dataclasses import fields

    from piezofin_ros.control.evidence import Observation
    from piezofin_ros.errors import PiezofinError
    from piezofin_ros.estimation.estimator import SOURCE, THRUST_FIELDS, source_of
    from piezofin_ros.physics.amplifier import WATT

    names = {f.name for f in fields(Estimate)}
    for s in SOURCE.values():
        assert s.thrust_field in names
        if s.per_watt:
            assert THRUST_FIELDS[s.name] == s.thrust_field
            assert all(tpw_field(w, s.name) in names for w in WATT)
        else:
            with pytest.raises(
                PiezofinError, match=r"no thrust per watt of the loadcell \(one of vibrometer, self\)"
            ):
                tpw_field("fin", s.name)
    assert [s.name for s in SOURCE.values() if s.self_sensed] == ["self"]
    y = complex(1e-4, 2e-3)
    assert Observation(0, 6, 400, 1e-3, 0.1, "self", y).self_sensed
    assert not Observation(0, 6, 400, 1e-3, 0.1, "self").self_sensed  # (no admittance: read as it came)
    assert Observation(0, 6, 400, 1e-3, 0.1, "loadcell").load_cell
    with pytest.raises(PiezofinError, match="unknown thrust source 'laser'"):
        source_of("laser")


@pytest.mark.parametrize("phase_error", [0.0, 1e-15, -1e-15, 1e-12])
def test_a_drive_that_draws_no_real_power_has_no_thrust_per_watt(phase_error: float) -> None:
    """A purely capacitive drive (the current a quarter period ahead of the voltage, within rounding):
    its mean(v i) is rounding, of either sign, and a thrust per it is no figure.  The estimator once
    published 1e15 N/W for it (``test_inbox.py``'s real fin after the attack, a CI run); every per-watt
    field of the fin's watt is now NaN, and the apparent and supply watts keep theirs."""
    from piezofin_ros.estimation.estimator import analyse_window

    fin = load_fin("M8528-P1")
    t = np.arange(1000) * 1e-3  # 5 periods of 5 Hz
    v = 200.0 * np.sin(2 * np.pi * 5 * t)
    i = 1e-5 * np.cos(2 * np.pi * 5 * t + phase_error)
    r = analyse_window(fin, t, v, i, 5.0)
    assert abs(r["power_w"]) <= 1e-9 * r["power_apparent_w"]
    assert math.isnan(r["thrust_per_watt_self"]) and math.isnan(r[tpw_field("fin", "self")])
    assert math.isfinite(r["thrust_per_watt_self_apparent"]) and math.isfinite(
        r["thrust_per_watt_self_supply"]
    )
    record = {k: v for k, v in r.items() if math.isfinite(v) and abs(v) < 1e12}
    assert set(r) - set(record) <= {
        k for k in r if k.startswith(("thrust_per_watt", "thrust_n", "c_tau", "tip_"))
    }
