"""The nodes' console scripts (``ros2 run piezofin_ros <node>``): a SIGINT or SIGTERM that comes while a
node is still importing its modules or starting ends it quietly, exit 0, as it would once running.

``ros2 launch`` stops every node when one fails (:mod:`.launching`); a node stopped in its first
second is still importing scipy.  Raising there (Python's ``KeyboardInterrupt``, or a ``SystemExit``
from a handler) does not always unwind: a signal handled inside a compiled extension's module
initialisation (scipy's HiGHS wrapper, measured) turns into ``ImportError: initialization failed``
and a traceback.  Until the node's own handlers take over (:class:`~._common.StopFlag`, installed as
soon as rclpy is initialised), the process holds nothing to close (no node, no file, no DDS
participant), so the handler says so in one line and ends it at once, without unwinding anything.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal
import sys
from functools import partial
from types import FrameType


def _interrupted(signum: int, frame: FrameType | None) -> None:
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "node"
    with contextlib.suppress(OSError, ValueError):
        said = f"{name}: interrupted while starting ({signal.Signals(signum).name}): nothing started"
        print(said, file=sys.stderr)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # (a closed or broken pipe: nothing to say)
            stream.flush()
    os._exit(0)


def _run(module: str, function: str = "main") -> int:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupted)  # (replaced by the node's StopFlag once rclpy is up)
    main = getattr(importlib.import_module(f"{__package__}.{module}"), function)
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
