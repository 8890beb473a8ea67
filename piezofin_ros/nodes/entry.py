"""The nodes' console scripts (``ros2 run piezofin_ros <node>``): a Ctrl-C that comes while a node is
still importing its modules ends it quietly, exit 0, as it would once running.

``ros2 launch`` stops every node when one fails (:mod:`.launching`); a node stopped in its first
second was still importing scipy, and Python printed a ``KeyboardInterrupt`` traceback for each.
Once :func:`~._common.run_node` runs, it answers Ctrl-C itself.
"""

from __future__ import annotations

import importlib
import signal
import sys
from functools import partial
from types import FrameType


def _interrupted(signum: int, frame: FrameType | None) -> None:
    sys.exit(0)  # (SystemExit unwinds the import: no traceback)


def _run(module: str, function: str = "main") -> int:
    signal.signal(signal.SIGINT, _interrupted)
    try:
        main = getattr(importlib.import_module(f"{__package__}.{module}"), function)
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return int(main())


# (each a callable that setup.py's console_scripts name)
fin_sim = partial(_run, "fin_sim")
fin_sims = partial(_run, "fin_sim", "fins_main")
thrust_estimator = partial(_run, "thrust_estimator")
controller = partial(_run, "controller")
recorder = partial(_run, "recorder")
player = partial(_run, "player")
speed_loop = partial(_run, "speed_loop")
bringup = partial(_run, "bringup")
