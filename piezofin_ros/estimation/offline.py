"""The estimator offline on a recorded bag: the same core as the live node, fed from the file.

:func:`replay_estimates` feeds a bag's ``drive``, ``tip_velocity``, ``loadcell`` and
``swim_speed`` messages of one fin to a :class:`~piezofin_ros.estimation.estimator.StreamEstimator` in
log-time order, and returns its estimates with those the live ``thrust_estimator`` recorded.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass

from ..bags import BagError
from ..bags.blocks import BlockFormatError
from ..bags.fin import (
    TOPIC_DRIVE,
    TOPIC_ESTIMATE,
    TOPIC_LOADCELL,
    TOPIC_SPEED,
    TOPIC_SUPPLY,
    TOPIC_TIP,
    FinMessage,
    Skipped,
    read_fin,
    topic_prefix,
)
from ..physics.amplifier import PAPER_BENCH, Amplifier
from ..physics.fin import Fin
from .estimator import OPTIONAL_FIELDS, Estimate, EstimatorConfig, StreamEstimator


@dataclass(frozen=True)
class Replay:
    replayed: list[Estimate]
    recorded: list[Estimate]
    messages: int
    skipped: list[str]  # one line per message that could not be used (the first bags.fin.MAX_SKIPPED_LINES)
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


class Replayer:
    """The estimator fed message by message (:func:`~piezofin_ros.bags.fin.read_fin`'s), keeping
    the live estimates recorded beside; :meth:`result` gives the :class:`Replay`."""

    KINDS = (TOPIC_DRIVE, TOPIC_TIP, TOPIC_LOADCELL, TOPIC_SUPPLY, TOPIC_SPEED, TOPIC_ESTIMATE)

    def __init__(self, fin: Fin, config: EstimatorConfig | None = None, amplifier: Amplifier = PAPER_BENCH):
        self.estimator = StreamEstimator(fin, config, amplifier=amplifier)
        self.replayed: list[Estimate] = []
        self.recorded: list[Estimate] = []
        self.skipped = Skipped()
        self.messages = 0  # usable ones (read_fin's); those it skipped are in ``skipped`` too
        self._errors = 0  # of the usable ones, those the estimator refused
        self._last_t = float("nan")

    def add(self, m: FinMessage, topic: str = "") -> None:
        self.messages += 1
        est, b = self.estimator, m.block
        try:
            if m.kind == TOPIC_SPEED:  # (from its stamp, as live; from the latest drive sample unstamped)
                est.add_speed(m.stamp_s if math.isfinite(m.stamp_s) else self._last_t, m.value)
                return
            assert b is not None
            if m.kind == TOPIC_ESTIMATE:
                self.recorded.append(Estimate.from_dict(b.as_dict()))
            elif m.kind == TOPIC_DRIVE:
                self._last_t = float(b["t_s"][-1])
                self.replayed += est.add_drive(b["t_s"], b["voltage_V"], b["current_A"])
            elif m.kind == TOPIC_SUPPLY:
                self.replayed += est.add_supply(b["t_s"], b["supply_voltage_V"], b["supply_current_A"])
            elif m.kind == TOPIC_TIP:
                self.replayed += est.add_tip(b["t_s"], b["tip_velocity_m_s"])
            else:
                self.replayed += est.add_loadcell(b["t_s"], b["displacement_m"])
        except (BlockFormatError, KeyError, ValueError, AssertionError) as exc:
            self._errors += 1
            self.skipped.add(topic or m.kind, m.time_ns, exc)

    def result(self, path: str | os.PathLike[str], namespace: str, kinds: Iterable[str] = KINDS) -> Replay:
        """The replay of ``path``; :class:`BagError` if it held no message of the fin's ``kinds``."""
        s = self.skipped
        read = self.messages + s.count - self._errors  # every message of the fin's topics
        if read == 0:
            topics = ", ".join(f"{topic_prefix(namespace)}/{k}" for k in kinds)
            raise BagError(f"{path}: no message on {topics} (is the namespace right?)")
        return Replay(self.replayed + self.estimator.flush(), self.recorded, read, s.lines, s.count)


def replay_estimates(
    path: str | os.PathLike[str],
    fin: Fin,
    namespace: str = "/fin",
    config: EstimatorConfig | None = None,
    amplifier: Amplifier = PAPER_BENCH,
) -> Replay:
    """Run the estimator over one fin's topics in a bag (raises :class:`BagError` on an unreadable
    file, or one without any of the fin's messages)."""
    replayer = Replayer(fin, config, amplifier)
    for m in read_fin(path, namespace, Replayer.KINDS, skipped=replayer.skipped):
        replayer.add(m)
    return replayer.result(path, namespace)
