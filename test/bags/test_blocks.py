"""The block wire format: round trips and precise rejections."""

from __future__ import annotations

import numpy as np
import pytest

from piezofin_ros.bags.blocks import (
    COMMAND_FIELDS,
    DRIVE_CHANNELS,
    Block,
    BlockFormatError,
    check_samples,
    from_layout,
    to_layout,
)


def test_round_trip_keeps_names_and_values() -> None:
    t = 10.0 + np.arange(50) / 1000.0
    b = Block.from_columns(t_s=t, voltage_V=np.sin(t), current_A=np.cos(t) * 1e-4)
    dims, data = to_layout(b)
    assert dims == [("t_s,voltage_V,current_A", 3, 150), ("sample", 50, 50)]
    back = from_layout(dims, data, expect=DRIVE_CHANNELS)
    assert back.names == DRIVE_CHANNELS
    np.testing.assert_array_equal(back["voltage_V"], np.sin(t))


def test_unlabelled_command_in_documented_order() -> None:
    b = from_layout([], [5.5, 800.0, 1.0], expect=COMMAND_FIELDS)
    assert b.as_dict() == {"frequency_hz": 5.5, "voltage_pp_V": 800.0, "on": 1.0}


@pytest.mark.parametrize(
    ("dims", "data", "match"),
    [
        ([("t_s,voltage_V,current_A", 3, 6), ("sample", 2, 2)], [0.0] * 5, "holds 5"),
        ([("t_s,voltage_V", 3, 6), ("sample", 2, 2)], [0.0] * 6, "names 2 channels"),
        ([("t_s,voltage_V,current_A", 3, 9), ("sample", 2, 2)], [0.0] * 6, "stride"),
        ([("t_s,,current_A", 3, 3)], [0.0] * 3, "empty channel"),
        ([("a", 1, 1), ("b", 1, 1), ("c", 1, 1)], [0.0], "at most 2"),
        ([("t_s,voltage_V", 2, 2)], [0.0] * 2, "missing channel"),
        ([], [1.0, 2.0], "must hold 3"),
    ],
)
def test_malformed_layouts_are_rejected_with_the_reason(dims: list, data: list, match: str) -> None:
    with pytest.raises(BlockFormatError, match=match):
        from_layout(dims, data, expect=DRIVE_CHANNELS if dims else COMMAND_FIELDS)


def test_sample_checks() -> None:
    ok = Block.from_columns(t_s=[0.0, 0.001], voltage_V=[1.0, np.nan], current_A=[0.0, 0.0])
    assert check_samples(ok, DRIVE_CHANNELS).n == 2  # a NaN value is allowed (sensor dropout)
    for bad_t, why in (([0.0, 0.0], "increase"), ([0.0, np.inf], "non-finite")):
        bad = Block.from_columns(t_s=bad_t, voltage_V=[1.0, 2.0], current_A=[0.0, 0.0])
        with pytest.raises(BlockFormatError, match=why):
            check_samples(bad, DRIVE_CHANNELS)
