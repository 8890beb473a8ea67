"""The recorder's hole finder (:class:`~piezofin_ros.bags.gaps.GapWatch`) on blocks as a rig sends them,
and on any blocks another process may send: it counts each hole's samples, and never raises.

Two blocks of denormal times (1e-320 s apart) after a stream's last sample made a hole of infinitely
many samples, and the ``OverflowError`` killed the recorder (2026-12-06): the class here is every
block of finite times in order, as :func:`~piezofin_ros.bags.blocks.sample_span` passes them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from piezofin_ros.bags.blocks import Block
from piezofin_ros.bags.gaps import HORIZON_S, MIN_PERIOD_S, GapWatch

rclpy_serialization = pytest.importorskip("rclpy.serialization", reason="rclpy serialises the blocks")


def cdr(t: list[float] | np.ndarray) -> bytes:
    """A drive block of these sample times as the wire carries it (``Float64MultiArray``)."""
    from piezofin_ros.nodes._common import block_msg

    t = np.asarray(t, dtype=float)
    block = Block.from_columns(t_s=t, voltage_V=np.zeros(t.size), current_A=np.zeros(t.size))
    return rclpy_serialization.serialize_message(block_msg(block))


def test_a_hole_in_a_steady_stream_is_counted_and_another_stream_makes_none() -> None:
    g = GapWatch()
    dt = 1e-3
    assert g.see("drive", cdr(np.arange(50) * dt)) is None
    assert g.see("drive", cdr(50 * dt + np.arange(50) * dt)) is None  # (contiguous)
    gap = g.see("drive", cdr(130 * dt + np.arange(50) * dt))  # (30 samples never came)
    assert gap is not None and gap.samples == 30
    assert gap.from_t_s == pytest.approx(100 * dt) and gap.to_t_s == pytest.approx(129 * dt)
    assert g.see("drive", cdr(1e6 + np.arange(50) * dt)) is None  # (another process's times)
    assert g.see("drive", cdr(180 * dt + np.arange(50) * dt)) is None  # (the first stream goes on)
    assert g.lost == {"drive": 30} and g.holes == {"drive": 1}


#: any finite time, and more often the neighbourhoods of a stream (seconds) and of 0 (denormals)
times = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False),
    st.floats(-10.0, 10.0),
    st.floats(-1e-300, 1e-300, allow_subnormal=True),
)


@settings(max_examples=1500, deadline=None)
@given(st.lists(st.lists(times, min_size=1, max_size=4).map(sorted), min_size=1, max_size=12))
def test_no_blocks_of_finite_times_in_order_make_it_raise_or_count_absurdly(
    blocks: list[list[float]],
) -> None:
    g = GapWatch()
    for t in [[-2.0, -1.0], *blocks]:  # (a stream before them, which the denormal pair followed)
        gap = g.see("drive", cdr(t))
        if gap is not None:
            assert 1 <= gap.samples <= HORIZON_S / MIN_PERIOD_S, gap


def test_the_denormal_pair_that_killed_the_recorder() -> None:
    g = GapWatch()
    assert g.see("drive", cdr([-2.0, -1.0])) is None
    assert g.see("drive", cdr([1e-320, 2e-320])) is None
    assert g.see("drive", cdr([3e-320])) is None  # (one sample: the stream's own period)
