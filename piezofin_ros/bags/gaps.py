"""Holes in a stream of sample blocks: what a recorder did not get, said and kept in the bag.

Sampled topics (``drive``, ``tip_velocity``, ``loadcell``, ``supply``) carry their sample times
(``t_s``), and a rig or ``fin_sim`` samples at a steady rate, so a block that starts later than one
sample period after the previous block's end marks samples that never reached the reader: its
queue overflowed while it was busy (a flood on another topic), or the publisher dropped them.
:class:`GapWatch` finds each hole from the bytes of each block (:func:`~.blocks.sample_span`), with
the samples it held; a block that starts earlier (a replay, a restarted rig) starts afresh.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

from .blocks import sample_span

#: A block starting later than this many sample periods after the last one's end is a hole.
HOLE_PERIODS = 1.5


@dataclass(frozen=True)
class Gap:
    """Samples of ``topic`` from ``from_t_s`` to ``to_t_s`` (the times of the first and the last
    missing sample, s of the fin's clock) that the reader never got: ``samples`` of them."""

    topic: str
    from_t_s: float
    to_t_s: float
    samples: int

    def to_json(self) -> str:
        return json.dumps(asdict(self))


class GapWatch:
    """Per topic, the last sample time and period; :meth:`see` returns the hole a block reveals."""

    def __init__(self) -> None:
        self._last: dict[str, tuple[float, float]] = {}  # topic -> (last t, sample period)
        self.lost: dict[str, int] = {}  # topic -> samples in holes
        self.holes: dict[str, int] = {}  # topic -> holes

    def see(self, topic: str, data: bytes) -> Gap | None:
        span = sample_span(data)
        if span is None:
            return None
        t0, t1, n = span
        previous = self._last.get(topic)
        period = (t1 - t0) / (n - 1) if n > 1 else (previous[1] if previous else 0.0)
        self._last[topic] = (t1, period)
        if previous is None or period <= 0:
            return None
        last, _ = previous
        if t0 <= last:  # a replay, a restarted rig: a new stream
            return None
        missing = round((t0 - last) / period) - 1
        if (t0 - last) <= HOLE_PERIODS * period or missing < 1:
            return None
        self.lost[topic] = self.lost.get(topic, 0) + missing
        self.holes[topic] = self.holes.get(topic, 0) + 1
        return Gap(topic, last + period, t0 - period, missing)

    @property
    def total_lost(self) -> int:
        return sum(self.lost.values())
