"""What the package's launch files share: a stack runs whole or not at all.

Under ``ros2 launch`` a node that stops with an error (a parameter out of its range, a body of
negative mass, a crash) used to leave the others running: ``fish.launch.py speed_m_s:=-1`` printed
the speed loop's one error line among the others' and went on driving the fin with no speed loop,
its controller optimising with no demand, until Ctrl-C.  Now the whole launch stops with one more
line naming the node, and ``ros2 launch`` exits with 1.
"""

from __future__ import annotations

from typing import Any

from launch.actions import RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.substitutions import LaunchConfiguration


class NodeFailed(RuntimeError):
    """A node of a launched stack exited with an error: the launch stops (``ros2 launch`` exits 1)."""


def stop_if_it_fails(action: Any, what: str) -> RegisterEventHandler:
    """An event handler that stops the launch when ``action``'s process exits with a code other than
    0 (a clean exit, Ctrl-C included) while the launch runs, naming ``what``.  It raises: launch
    says "Caught exception in launch", shuts every other process down as Ctrl-C would, and returns
    1."""

    def on_exit(event: Any, context: Any) -> None:
        code = event.returncode
        if code and not context.is_shutdown:  # (once stopping, the others' exits are its doing)
            raise NodeFailed(
                f"{what} exited with code {code} (its lines above say why): the stack does not run "
                "without it, so every node stops"
            )

    return RegisterEventHandler(OnProcessExit(target_action=action, on_exit=on_exit))


def number_argument(context: Any, name: str) -> float:
    """The launch argument ``name`` as a number, or one line naming it (``speed_m_s:=abc`` said "could
    not convert string to float: 'abc'")."""
    text = LaunchConfiguration(name).perform(context)
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"launch argument {name}:={text!r} is not a number") from None
