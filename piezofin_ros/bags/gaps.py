"""Holes in a stream of sample blocks: what a recorder did not get, said and kept in the bag.

Sampled topics (``drive``, ``tip_velocity``, ``loadcell``, ``supply``) carry their sample times
(``t_s``), and a rig or ``fin_sim`` samples at a steady rate, so a block that starts later than one
sample period after the previous block's end marks samples that never reached the reader: its
queue overflowed while it was busy (a flood on another topic), or the publisher dropped them.
:class:`GapWatch` finds each hole from the bytes of each block (:func:`~.blocks.sample_span`), with
the samples it held.

A topic may carry more than one stream: another process publishing blocks of times of its own (an
attacker's flood, a second rig by mistake), a replay, a restarted rig.  Each block continues the
stream it follows (the one whose last sample is the latest before the block's first, within
:data:`HORIZON_S`); a block that follows none starts a stream of its own (at most
:data:`MAX_STREAMS` per topic, the least recently continued forgotten), so one stream's blocks never
make holes in another's.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

from .blocks import sample_span

#: A block starting later than this many sample periods after its stream's last sample is a hole.
HOLE_PERIODS = 1.5
#: The longest hole a stream can have, s of the stream's time: a block further ahead starts a stream.
HORIZON_S = 3600.0
#: Streams remembered per topic.
MAX_STREAMS = 8
#: The shortest sample period a stream can have, s (10 MHz: no rig samples faster).  Below it, as at
#: 0, no hole is counted: two blocks of denormal times (1e-320 s apart) after a stream's last sample
#: made a hole of infinitely many samples, and the recorder died of the ``OverflowError`` (2026-12-06).
MIN_PERIOD_S = 1e-7


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
    """Per topic, its streams' last sample time and period; :meth:`see` returns the hole a block
    reveals in the stream it continues."""

    def __init__(self) -> None:
        self._streams: dict[str, list[list[float]]] = {}  # topic -> [[last t, period, last used]]
        self._used = 0
        self.lost: dict[str, int] = {}  # topic -> samples in holes
        self.holes: dict[str, int] = {}  # topic -> holes

    def see(self, topic: str, data: bytes, named: bool = False) -> Gap | None:
        """The hole this block (its CDR bytes; ``named``: a named message of samples, else a
        ``Float64MultiArray`` block) makes in its stream, if any."""
        span = sample_span(data, named)
        if span is None:
            return None
        t0, t1, n = span
        self._used += 1
        streams = self._streams.setdefault(topic, [])
        ahead = [s for s in streams if s[0] < t0 <= s[0] + HORIZON_S]
        if not ahead:  # a stream of its own (or a repeat of what a stream holds already)
            if not any(s[0] >= t1 >= s[0] - HORIZON_S for s in streams):
                if len(streams) >= MAX_STREAMS:
                    streams.remove(min(streams, key=lambda s: s[2]))
                streams.append([t1, (t1 - t0) / (n - 1) if n > 1 else 0.0, self._used])
            return None
        stream = max(ahead, key=lambda s: s[0])
        last, period = stream[0], stream[1]
        if n > 1:
            period = (t1 - t0) / (n - 1)
        stream[:] = [t1, period, self._used]
        if not period >= MIN_PERIOD_S:  # (0, a period no rig samples at)
            return None
        missing = round((t0 - last) / period) - 1  # (finite: t0 - last is within HORIZON_S)
        if (t0 - last) <= HOLE_PERIODS * period or missing < 1:
            return None
        self.lost[topic] = self.lost.get(topic, 0) + missing
        self.holes[topic] = self.holes.get(topic, 0) + 1
        return Gap(topic, last + period, t0 - period, missing)

    @property
    def total_lost(self) -> int:
        return sum(self.lost.values())
