"""What the package's launch files share: a stack runs whole or not at all.

Under ``ros2 launch`` a node that stops with an error (a parameter out of its range, a body of
negative mass, a crash) used to leave the others running: ``fish.launch.py speed_m_s:=-1`` printed
the speed loop's one error line among the others' and went on driving the fin with no speed loop,
its controller optimising with no demand, until Ctrl-C.  Now the whole launch stops with one more
line naming the node, and ``ros2 launch`` exits with 1.

``launch`` is imported when a launch file calls these (it is not on PyPI: the package imports
without it).
"""

from __future__ import annotations

import signal
import time
from typing import Any

from ..errors import NodeError


class NodeFailed(NodeError):
    """A node of a launched stack exited with an error: the launch stops (``ros2 launch`` exits 1)."""


class LaunchArgumentError(NodeError, ValueError):
    """A launch argument that cannot be what it names (a speed that is no number)."""


def stop_if_any_fails(actions: list[Any], *, wait_s: float = 30.0) -> list[Any]:
    """Event handlers that stop the launch when one of ``actions``' processes exits with a code other
    than 0 (a clean exit, Ctrl-C included) while the launch runs, naming its executable.  They raise:
    launch says "Caught exception in launch", shuts every other process down as Ctrl-C would, and
    returns 1.

    The stop waits (at most ``wait_s``) until each other node is past its start, that is, catches
    SIGTERM (:mod:`.entry` installs the handlers first, Python none of its own) or has ended.  A
    SIGINT that comes earlier lands in the interpreter's own start (its site, the console script's
    imports) and prints a ``KeyboardInterrupt`` traceback no program can catch: stop 61's CI saw the
    controller's, interrupted in the script's ``import importlib.metadata`` under a load of 20."""
    return [_stop_if_it_fails(action, actions, wait_s) for action in actions]


def _stop_if_it_fails(action: Any, actions: list[Any], wait_s: float) -> Any:
    from launch.actions import OpaqueFunction, RegisterEventHandler, TimerAction
    from launch.event_handlers import OnProcessExit

    what = action.node_executable

    def on_exit(event: Any, context: Any) -> Any:
        code = event.returncode
        if not code or context.is_shutdown:  # (once stopping, the others' exits are its doing)
            return None
        others = [a for a in actions if a is not action]
        deadline = time.monotonic() + wait_s

        def stop_once_started(context: Any) -> Any:
            if context.is_shutdown:
                return None
            if time.monotonic() < deadline and not all(_past_start(a) for a in others):
                return [TimerAction(period=0.05, actions=[OpaqueFunction(function=stop_once_started)])]
            raise NodeFailed(
                f"{what} exited with code {code} (its lines above say why): the stack does not run "
                "without it, so every node stops"
            )

        return [OpaqueFunction(function=stop_once_started)]

    return RegisterEventHandler(OnProcessExit(target_action=action, on_exit=on_exit))


def _past_start(action: Any) -> bool:
    details = action.process_details
    if details is None:
        return False  # (not started yet: launch would signal it the moment it starts)
    return past_start(int(details["pid"]))


def past_start(pid: int) -> bool:
    """Whether process ``pid`` catches SIGTERM (a node's :mod:`.entry` installs that handler before
    any import; Python installs none of its own) or has ended.  Where there is no ``/proc`` to ask:
    yes."""
    try:
        with open(f"/proc/{pid}/status") as status:
            fields = dict(line.split(":", 1) for line in status if ":" in line)
    except OSError:  # (ended and reaped, or no /proc)
        return True
    if fields.get("State", "").strip().startswith("Z"):  # (ended, not yet reaped)
        return True
    return bool(int(fields.get("SigCgt", "0").strip(), 16) & (1 << (signal.SIGTERM - 1)))


def number_argument(context: Any, name: str) -> float:
    """The launch argument ``name`` as a number, or one line naming it (``speed_m_s:=abc`` said "could
    not convert string to float: 'abc'")."""
    from launch.substitutions import LaunchConfiguration

    text = LaunchConfiguration(name).perform(context)
    try:
        return float(text)
    except ValueError:
        raise LaunchArgumentError(f"launch argument {name}:={text!r} is not a number") from None
