"""Settings declared once: a dataclass field that carries its range, choices and description.

A node's configuration is a frozen dataclass whose fields are made with :func:`setting`; the same
declaration gives the default, the range and the text that ``ros2 param describe`` shows (the node
declares its ROS parameters from it, :func:`piezofin_ros.nodes._common.declare`), the reference
table in ``docs/reference.md`` (checked by a test), and the checks a value passes::

    @dataclass(frozen=True)
    class PlayerConfig:
        bag: str = setting("", "the .mcap file to play")
        rate: float = setting(1.0, "playback speed factor", 0.01, 1000.0)

ROS-free: the science packages use it for their own settings (the rig's instruments and limits,
the estimator's windows), which a node declares under a prefix (``rig.*``, ``limits.*``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import Field, dataclass, field, fields
from typing import Any

#: Hard cap on the peak-to-peak drive voltage that no configuration can exceed.  Smart Material's
#: MFC datasheet rates the P1 (d33) types for -500 V .. +1500 V; a symmetric bipolar sine is
#: therefore limited to +-500 V, i.e. 1000 Vpp.  The paper drives at most 800 Vpp.  (Here, among the
#: settings, so that the nodes a fish runs know it without loading the simulated rig.)
HARD_VOLTAGE_PP_MAX = 1000.0
#: The window no instantaneous drive voltage may leave, whatever its offset (a DC bias that bends the
#: fin to steer): the P1 (d33) MFC's rating, -500 V .. +1500 V (Smart Material, *MFC engineering
#: properties*, Vmin and Vmax), which is not symmetric.
HARD_VOLTAGE_WINDOW_V = (-500.0, 1500.0)


@dataclass(frozen=True)
class Setting:
    """What a field declares besides its default."""

    description: str
    lo: float | None = None  # inclusive range of a number
    hi: float | None = None
    choices: tuple[str, ...] = ()  # the values a string may take
    items: type | None = None  # element type of a tuple (float or str): a ROS array parameter
    read_only: bool = False

    @property
    def bounds(self) -> tuple[float, float]:
        """The inclusive range of a number, an open end infinite."""
        return (-math.inf if self.lo is None else self.lo, math.inf if self.hi is None else self.hi)


def setting(
    default: Any,
    description: str,
    lo: float | None = None,
    hi: float | None = None,
    *,
    choices: Sequence[str] = (),
    items: type | None = None,
    read_only: bool = False,
) -> Any:
    """A dataclass field with its setting (arrays are tuples, with ``items`` their element type)."""
    if isinstance(default, tuple) and items is None:
        raise TypeError(f"setting {description!r}: a tuple needs items= (float or str)")
    return field(
        default=default, metadata={"setting": Setting(description, lo, hi, tuple(choices), items, read_only)}
    )


def settings_of(cls: type) -> list[tuple[Field[Any], Any, Setting]]:
    """(field, default, setting) of every field of a settings dataclass, in declaration order."""
    out = []
    for f in fields(cls):
        s = f.metadata.get("setting")
        if s is None:
            raise TypeError(f"{cls.__name__}.{f.name} is not declared with setting()")
        out.append((f, f.default, s))
    return out
