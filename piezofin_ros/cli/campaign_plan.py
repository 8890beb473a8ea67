"""What a campaign plans (:class:`CampaignConfig`) and how it names a fin's namespace and files:
shared by the run (:mod:`.campaign`) and the report (:mod:`.campaign_report`), which import it and
not each other.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..physics.fin import Fin, load_fin
from ..physics.model import load_model


@dataclass
class CampaignConfig:
    fins: tuple[str, ...] = ("M8528-P1", "M8514-P1", "M8507-P1")
    models: dict[str, str] = field(default_factory=dict)  # fin name -> augmented model file
    out: Path = Path("out/campaign")
    frequencies: tuple[float, ...] | None = None  # None: each fin's band (protocol_frequencies)
    voltages: tuple[float, ...] = (400.0, 600.0, 800.0)
    trace: tuple[float, float] = (5.5, 800.0)  # Fig. 6
    air_vpp: float = 50.0
    water_vpp: float = 100.0
    sweep_points: int = 21
    realtime_factor: float = 200.0
    _truths: dict[str, Fin] = field(default_factory=dict, repr=False)

    def protocol_frequencies(self, name: str) -> list[float]:
        """The protocol's frequencies for a fin: ``frequencies`` if given, else the paper's 1-11 Hz
        widened to the fin's band (1 Hz steps up to 1.25 times its linear underwater resonance:
        M8514-P1 and M8507-P1 resonate above 11 Hz), plus 5.5 Hz for M8528-P1 (Fig. 6)."""
        if self.frequencies is not None:
            freqs = list(self.frequencies)
        else:
            top = max(11, math.ceil(1.25 * self.truth(name).f_water_linear))
            freqs = [float(f) for f in range(1, top + 1)]
        if name == "M8528-P1" and self.trace[0] not in freqs:
            freqs = sorted([*freqs, self.trace[0]])
        return freqs

    def truth(self, name: str) -> Fin:
        """The fin the rig simulates (the preset, or the twin's fin); each file is read once."""
        if name not in self._truths:
            self._truths[name] = load_model(self.models[name]).fin if name in self.models else load_fin(name)
        return self._truths[name]


def namespace(name: str) -> str:
    """A ROS namespace for a fin name (``M8528-P1`` -> ``m8528_p1``)."""
    ns = re.sub(r"[^a-z0-9_]", "_", name.lower())
    return ns if ns[:1].isalpha() else f"fin_{ns}"


def filename(name: str) -> str:
    """A file-name-safe form of a fin name."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name)
