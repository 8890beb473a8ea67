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
import logging
import os
import signal
import sys
from functools import partial
from types import FrameType
from typing import NoReturn


def _interrupted(signum: int, frame: FrameType | None) -> None:
    name = os.path.basename(sys.argv[0]) if sys.argv and sys.argv[0] else "node"
    with contextlib.suppress(OSError, ValueError):
        said = f"{name}: interrupted while starting ({signal.Signals(signum).name}): nothing started"
        print(said, file=sys.stderr)
    _flush()
    os._exit(0)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # (a closed or broken pipe: nothing to say)
            stream.flush()


def finish(code: int) -> NoReturn:
    """End a node's process with ``code`` once its ``main`` has returned, without the interpreter's
    finalisation.

    By then what matters is done and watched (:func:`~._common.run_node`: the drive ramped down, the
    bag closed, the ROS entities destroyed and the context shut down).  What finalisation still ran was the
    middleware's destructors, and under a CI run's load ``fin_sims`` hung there over 6 s after a clean
    teardown: ``ros2 launch`` escalated to SIGTERM and the backstop ended it with status 1, failing the
    two-fin launch test's clean exit.  Python's own buffers are flushed first (``logging`` and the
    standard streams); ``atexit`` handlers do not run (the nodes register none)."""
    logging.shutdown()
    _flush()
    os._exit(code)


def _run(module: str, function: str = "main") -> int:
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupted)  # (replaced by the node's StopFlag once rclpy is up)
    main = getattr(importlib.import_module(f"{__package__}.{module}"), function)
    from . import _common

    _common.ENDS_AFTER_RUN = True  # (the process ends at finish: run_node's teardown leaves out the rest)
    finish(int(main()))


#: Every executable of the package, ``ros2 run piezofin_ros <name>``: the module of this package that
#: holds it and its function.  Declared once: setup.py's console_scripts are read from this table
#: (with ``ast``, not importing the package), and so are the tests' lists of executables.
EXECUTABLES: dict[str, tuple[str, str]] = {
    "fin_sim": ("fin_sim", "main"),
    "fin_sims": ("fin_sim", "fins_main"),
    "thrust_estimator": ("thrust_estimator", "main"),
    "controller": ("controller", "main"),
    "recorder": ("recorder", "main"),
    "player": ("player", "main"),
    "speed_loop": ("speed_loop", "main"),
    "waypoints": ("waypoints", "main"),
    "bringup": ("bringup", "main"),
}


def __getattr__(name: str) -> partial[int]:
    """``piezofin_ros.nodes.entry:<name>``, the callable a console script names (PEP 562)."""
    if name in EXECUTABLES:
        return partial(_run, *EXECUTABLES[name])
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
