"""Launch the suite on a ROS 2 machine (``ros2 launch piezofin_ros piezofin.launch.py``).

One fin per namespace: ``fin_sim`` (a managed node, configured and activated here),
``thrust_estimator`` and ``controller``; one ``recorder``.  With several namespaces the fins run
in one ``fin_sims`` process that steps them together (one time for every fin; each is still its
own lifecycle node, activated at start).  Parameters come from the package's
``config/bringup.yaml``, with ``params_file:=...`` layered on top (it needs to hold only what it
changes).  With ``sim:=false`` no ``fin_sim`` is
started: a rig driver or the fish's drive electronics publishes ``drive`` (and, on a rig,
``tip_velocity`` and ``loadcell``) in the same namespace instead.

    ros2 launch piezofin_ros piezofin.launch.py namespaces:="left right" realtime_factor:=10
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition

from piezofin_ros.nodes.launching import number_argument, stop_if_any_fails

#: What reads each fin's data topics here: its thrust_estimator and the recorder.  fin_sim waits for
#: both before its first sample, so neither misses the first trial's start (nodes start in any order).
CONSUMERS = 2


def _nodes(context, *args, **kwargs):
    default = os.path.join(get_package_share_directory("piezofin_ros"), "config", "bringup.yaml")
    extra = LaunchConfiguration("params_file").perform(context)
    files = [default, extra] if extra else [default]
    namespaces = LaunchConfiguration("namespaces").perform(context).split()
    sim = LaunchConfiguration("sim").perform(context).lower() in ("1", "true", "yes")
    factor = number_argument(context, "realtime_factor")
    # (faster than real time, the nodes run on /clock: fin_sim's, or with sim:=false the driver's)
    use_sim_time = factor != 1.0
    actions = []
    several = sim and len(namespaces) > 1
    if several:
        # one process steps every fin from one timer: one time for all (separate processes drift)
        actions.append(
            Node(
                package="piezofin_ros",
                executable="fin_sims",
                # settings as arguments (constructor overrides): a parameter dict of a node without a
                # name is a `/**` entry, which the files' `/**/fin_sim` entries override
                arguments=[
                    *("--namespaces", *namespaces),
                    *("--realtime-factor", str(factor)),
                    *(["--publish-clock"] if use_sim_time else []),
                    *("--wait-subscribers", str(CONSUMERS)),
                ],
                parameters=files,
                output="screen",
            )
        )
    for k, ns in enumerate(namespaces):
        if sim and not several:
            fin_sim = LifecycleNode(
                package="piezofin_ros",
                executable="fin_sim",
                name="fin_sim",
                namespace=ns,
                parameters=[
                    *files,
                    {
                        "autostart": False,
                        "realtime_factor": factor,
                        "publish_clock": use_sim_time and k == 0,
                        "wait_subscribers": CONSUMERS,
                    },
                ],
                output="screen",
            )
            configure = EmitEvent(
                event=ChangeState(
                    lifecycle_node_matcher=matches_action(fin_sim),
                    transition_id=Transition.TRANSITION_CONFIGURE,
                )
            )
            # Activate once, on the arrival in `inactive` from `configuring` (the start): an operator's
            # `ros2 lifecycle set .../fin_sim deactivate` also arrives in `inactive`, from
            # `deactivating`, and must hold (the handler re-activated it within a second).
            activate = RegisterEventHandler(
                OnStateTransition(
                    target_lifecycle_node=fin_sim,
                    start_state="configuring",
                    goal_state="inactive",
                    handle_once=True,
                    entities=[
                        EmitEvent(
                            event=ChangeState(
                                lifecycle_node_matcher=matches_action(fin_sim),
                                transition_id=Transition.TRANSITION_ACTIVATE,
                            )
                        )
                    ],
                )
            )
            actions += [fin_sim, activate, configure]
        for exe in ("thrust_estimator", "controller"):
            actions.append(
                Node(
                    package="piezofin_ros",
                    executable=exe,
                    name=exe,
                    namespace=ns,
                    parameters=[*files, {"use_sim_time": use_sim_time}],
                    output="screen",
                )
            )
    actions.append(
        Node(
            package="piezofin_ros",
            executable="recorder",
            name="recorder",
            parameters=[*files, {"namespaces": namespaces, "use_sim_time": use_sim_time}],
            output="screen",
        )
    )
    # a node that stops with an error stops them all (the others went on without it)
    nodes = [a for a in actions if isinstance(a, Node)]  # (a LifecycleNode is a Node)
    return actions + stop_if_any_fails(nodes)


def generate_launch_description():
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file",
                default_value="",
                description="ROS 2 parameter file layered on the package's config/bringup.yaml",
            ),
            DeclareLaunchArgument("namespaces", default_value="fin", description="one namespace per fin"),
            DeclareLaunchArgument(
                "sim", default_value="true", description="start fin_sim (false: real drive)"
            ),
            DeclareLaunchArgument(
                "realtime_factor",
                default_value="1.0",
                description="fin_sim speed; other than 1, the nodes run on /clock (with sim:=false, a "
                "driver that simulates its rig this fast publishes it)",
            ),
            OpaqueFunction(function=_nodes),
        ]
    )
