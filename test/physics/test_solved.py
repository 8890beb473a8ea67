"""The steady amplitude solved once and reused (``model._Solved``): a model whose effects differ
only in knobs the amplitude never reads (:data:`~piezofin_ros.physics.knobs.UNREAD_BY_AMPLITUDE`)
reuses the amplitude solved without them, and predicts bit for bit what it predicts solving it
again.  The optimiser's fit and its sigma ask for such models at the same points in 4 of each 10."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from piezofin_ros.physics.effects import LIBRARY, CapacitanceOffset, Effect, sole_target
from piezofin_ros.physics.fin import load_fin
from piezofin_ros.physics.knobs import UNREAD_BY_AMPLITUDE
from piezofin_ros.physics.model import _SOLVED, Model, Prediction, steady_knobs

FIN = load_fin("M8528-P1")
F = np.array([3.0, 5.5, 8.0, 11.0, 6.2])
V = np.array([200.0, 800.0, 500.0, 650.0, 400.0])
T = np.array([0.0, 600.0, 1200.0, 1800.0, 3600.0])  # (s since the first trial: the drifts move)


def off_neutral(cls: type[Effect], k: float = 0.5) -> Effect:
    """``cls`` at ``k`` of its typical departure from neutral, within its range."""
    return cls.at([min(max(q.neutral + k * q.scale, q.lower), q.upper) for q in cls.params])


#: the library's effects and the optimiser's fitted capacitance (not the library's: a fit's only)
CLASSES = {**LIBRARY, CapacitanceOffset.name: CapacitanceOffset}
#: amplitude-dependent effects under every case: the fixed point and its lowest root both run
MOVING = tuple(off_neutral(LIBRARY[n]) for n in ("electroelastic_softening", "drag_kc", "nonlinear_damping"))
UNREAD = sorted(n for n, c in CLASSES.items() if sole_target(c.at(c.neutral())) in UNREAD_BY_AMPLITUDE)


def test_the_library_has_effects_the_amplitude_never_reads() -> None:
    # (capacitance, the losses, the load cell and the instruments' gains and lags)
    assert {"capacitance_offset", "dielectric_loss", "leakage", "loadcell_gain"} <= set(UNREAD), UNREAD
    assert not {"resonance_offset", "field_coupling", "drag_offset"} & set(UNREAD), UNREAD


@pytest.mark.parametrize("name", UNREAD)
def test_a_knob_the_amplitude_never_reads_leaves_it_as_it_was(name: str) -> None:
    """Solved afresh each time (the cache emptied), the amplitude with the effect is the amplitude
    without it, bit for bit: what the reuse rests on (an effect made to move the fin through one of
    these knobs fails here, and must leave :data:`UNREAD_BY_AMPLITUDE`)."""
    for measured in (None, 0.93 * V):
        _SOLVED.clear()
        _, without = steady_knobs(FIN, MOVING, F, V, measured, time_s=T)
        _SOLVED.clear()
        _, with_it = steady_knobs(FIN, (*MOVING, off_neutral(CLASSES[name], 1.5)), F, V, measured, time_s=T)
        np.testing.assert_array_equal(with_it, without)


def assert_same(a: Prediction, b: Prediction) -> None:
    for f in fields(Prediction):
        np.testing.assert_array_equal(getattr(a, f.name), getattr(b, f.name), err_msg=f.name)


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_a_prediction_is_the_same_whether_its_amplitude_was_reused_or_solved(name: str) -> None:
    """Each effect of the library on top of amplitude-dependent ones: predicted with the cache
    empty, then again after the model without it was solved at the same points, bit for bit the
    same; the amplitude is reused exactly when the effect sets a knob it never reads."""
    model = Model(FIN, (*MOVING, off_neutral(CLASSES[name])))
    for drive_pp, time_s in ((None, None), (0.93 * V, T)):
        _SOLVED.clear()
        fresh = model.predict(F, V, drive_pp, time_s)
        _SOLVED.clear()
        Model(FIN, MOVING).predict(F, V, drive_pp, time_s)
        hits = _SOLVED.hits
        assert_same(model.predict(F, V, drive_pp, time_s), fresh)
        assert (_SOLVED.hits > hits) == (name in UNREAD), name
        hits = _SOLVED.hits
        assert_same(model.predict(F, V, drive_pp, time_s), fresh)  # (its own amplitude, now solved)
        assert _SOLVED.hits == hits + 1


def test_other_points_or_a_moved_fin_are_solved_again_and_the_cache_is_bounded() -> None:
    _SOLVED.clear()
    model = Model(FIN, MOVING)
    first = model.predict(F, V)
    for k in range(3 * _SOLVED.MOST):
        model.predict(F, V * (0.5 + k / (6 * _SOLVED.MOST)))
        assert len(_SOLVED) <= _SOLVED.MOST
    misses = _SOLVED.misses
    stiffer = Model(FIN, (*MOVING, off_neutral(LIBRARY["resonance_offset"])))
    assert not np.array_equal(stiffer.predict(F, V).tip_velocity_rms, first.tip_velocity_rms)
    assert _SOLVED.misses == misses + 1  # (another stiffness: solved, not reused)
    big = np.linspace(2.0, 12.0, _SOLVED.POINTS_MOST + 1)
    size = len(_SOLVED)
    model.predict(big, np.full_like(big, 500.0))
    assert len(_SOLVED) == size  # (too many points to key: solved, not kept)


#: across the resonance at full voltage with a softening spring: where several amplitudes are
#: steady (the fixed point does not settle, the lowest root is scanned for), the lowest must be the
#: one a nearby model's amplitude leads to as well
JUMP_F = np.linspace(3.0, 8.0, 41)
JUMP_V = np.full_like(JUMP_F, 800.0)
SOFT = (LIBRARY["stiffness_nonlinearity"].at([-300.0]), *MOVING)


@pytest.mark.parametrize("effects", [MOVING, SOFT], ids=["moving", "softening"])
def test_a_nearby_models_amplitude_starts_the_fixed_point_and_it_ends_where_rest_would(
    effects: tuple[Effect, ...],
) -> None:
    """A fit's forward differences step one parameter by 1.5e-8: the fixed point starts from the
    amplitude just solved (``_Solved.near``) and ends within 1e-9 of the amplitude solved from
    rest, the lowest root where there are several; a model further than ``NEAR`` starts from rest."""
    for k, e in enumerate(effects):
        for j, q in enumerate(e.params):
            values = list(e.values)
            values[j] = min(values[j] + 1.5e-8 * max(1.0, abs(values[j])), q.upper)
            nearby = (*effects[:k], type(e).at(values), *effects[k + 1 :])
            _SOLVED.clear()
            _, rest = steady_knobs(FIN, nearby, JUMP_F, JUMP_V)
            _SOLVED.clear()
            steady_knobs(FIN, effects, JUMP_F, JUMP_V)
            starts = _SOLVED.starts
            _, warm = steady_knobs(FIN, nearby, JUMP_F, JUMP_V)
            assert _SOLVED.starts == starts + 1, (e.name, q.name)
            np.testing.assert_allclose(warm, rest, rtol=1e-9, atol=0, err_msg=f"{e.name}.{q.name}")
    _SOLVED.clear()
    steady_knobs(FIN, effects, JUMP_F, JUMP_V)
    far = (type(effects[0]).at([v * 1.01 + 1e-3 for v in effects[0].values]), *effects[1:])
    starts = _SOLVED.starts
    steady_knobs(FIN, far, JUMP_F, JUMP_V)
    assert _SOLVED.starts == starts  # (a percent away: from rest)
