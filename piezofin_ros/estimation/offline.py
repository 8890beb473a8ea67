"""The estimator offline on a recorded bag: the same core as the live node, fed from the file.

:func:`replay_estimates` feeds a bag's ``drive``, ``tip_velocity``, ``loadcell`` and
``swim_speed`` messages of one fin to a :class:`~piezofin_ros.estimation.estimator.StreamEstimator` in
log-time order, and returns its estimates with those the live ``thrust_estimator`` recorded.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..bags import BagError, block_of, decode, read_messages
from ..bags.blocks import (
    DRIVE_CHANNELS,
    LOADCELL_CHANNELS,
    SUPPLY_CHANNELS,
    TIP_CHANNELS,
    BlockFormatError,
    check_samples,
)
from ..physics.amplifier import PAPER_BENCH, Amplifier
from ..physics.fin import Fin
from .estimator import OPTIONAL_FIELDS, Estimate, EstimatorConfig, StreamEstimator

#: Skipped messages are counted; only this many lines describing them are kept.
MAX_SKIPPED_LINES = 100


@dataclass(frozen=True)
class Replay:
    replayed: list[Estimate]
    recorded: list[Estimate]
    messages: int
    skipped: list[str]  # one line per message that could not be used (the first MAX_SKIPPED_LINES)
    n_skipped: int = 0  # all of them

    def skipped_lines(self, most: int = 20) -> list[str]:
        """The first ``most`` skipped lines and one line counting the rest."""
        rest = self.n_skipped - min(most, len(self.skipped))
        return self.skipped[:most] + ([f"... and {rest} more messages"] if rest > 0 else [])

    def max_relative_difference(self) -> float:
        """Largest relative difference of any finite field between replayed and recorded estimates."""
        if len(self.replayed) != len(self.recorded):
            return float("inf")
        worst = 0.0
        for a, b in zip(self.replayed, self.recorded, strict=True):
            for name, x in a.as_dict().items():
                y = getattr(b, name)
                if x != x and y != y:  # both NaN
                    continue
                if y != y and name in OPTIONAL_FIELDS:  # recorded before the field existed
                    continue
                if x != x or y != y:
                    return float("inf")
                scale = max(abs(x), abs(y), 1e-300)
                worst = max(worst, abs(x - y) / scale)
        return worst


def topic_prefix(namespace: str) -> str:
    """``"/fin"`` for ``"fin"``, ``"/fin/"`` or ``"/fin"``; ``""`` for the root namespace."""
    return "/" + namespace.strip("/") if namespace.strip("/") else ""


def replay_estimates(
    path: str | os.PathLike[str],
    fin: Fin,
    namespace: str = "/fin",
    config: EstimatorConfig | None = None,
    amplifier: Amplifier = PAPER_BENCH,
) -> Replay:
    """Run the estimator over one fin's topics in a bag (raises :class:`BagError` on an unreadable file)."""
    ns = topic_prefix(namespace)
    names = ("drive", "tip_velocity", "loadcell", "supply", "swim_speed", "estimate")
    topics = {f"{ns}/{t}": t for t in names}
    est = StreamEstimator(fin, config, amplifier=amplifier)
    replayed: list[Estimate] = []
    recorded: list[Estimate] = []
    skipped: list[str] = []
    n = n_skipped = 0
    last_t = float("nan")
    for m in read_messages(path, topics):
        n += 1
        kind = topics[m.topic]
        try:
            if kind == "swim_speed":
                est.add_speed(last_t, float(decode(m.type_name, m.data).data))
                continue
            block = block_of(m.type_name, m.data)
            if kind == "estimate":
                recorded.append(Estimate.from_dict(block.as_dict()))
            elif kind == "drive":
                b = check_samples(block, DRIVE_CHANNELS)
                last_t = float(b["t_s"][-1])
                replayed += est.add_drive(b["t_s"], b["voltage_V"], b["current_A"])
            elif kind == "supply":
                b = check_samples(block, SUPPLY_CHANNELS)
                replayed += est.add_supply(b["t_s"], b["supply_voltage_V"], b["supply_current_A"])
            elif kind == "tip_velocity":
                b = check_samples(block, TIP_CHANNELS)
                replayed += est.add_tip(b["t_s"], b["tip_velocity_m_s"])
            else:
                b = check_samples(block, LOADCELL_CHANNELS)
                replayed += est.add_loadcell(b["t_s"], b["displacement_m"])
        except (BlockFormatError, KeyError, ValueError, AssertionError) as exc:
            n_skipped += 1
            if len(skipped) < MAX_SKIPPED_LINES:  # memory bounded by what is kept, whatever the file
                skipped.append(f"{m.topic} at {m.log_time_ns * 1e-9:.3f} s: {exc}")
    if n == 0:
        raise BagError(f"{path}: no message on {', '.join(topics)} (is the namespace right?)")
    return Replay(replayed + est.flush(), recorded, n, skipped, n_skipped)
