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

from typing import Any

from ..errors import NodeError


class NodeFailed(NodeError):
    """A node of a launched stack exited with an error: the launch stops (``ros2 launch`` exits 1)."""


class LaunchArgumentError(NodeError, ValueError):
    """A launch argument that cannot be what it names (a speed that is no number)."""


def stop_if_it_fails(action: Any, what: str) -> Any:
    """An event handler that stops the launch when ``action``'s process exits with a code other than
    0 (a clean exit, Ctrl-C included) while the launch runs, naming ``what``.  It raises: launch
    says "Caught exception in launch", shuts every other process down as Ctrl-C would, and returns
    1."""
    from launch.actions import RegisterEventHandler
    from launch.event_handlers import OnProcessExit

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
    from launch.substitutions import LaunchConfiguration

    text = LaunchConfiguration(name).perform(context)
    try:
        return float(text)
    except ValueError:
        raise LaunchArgumentError(f"launch argument {name}:={text!r} is not a number") from None
