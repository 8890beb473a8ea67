"""Launch a fish on the suite (``ros2 launch piezofin_ros fish.launch.py``): the example to copy.

One fin in the namespace ``fish``: ``fin_sim`` as a free-swimming body with its battery (replace it
with the fish's drive electronics, which publish ``drive``, ``swim_speed`` and ``battery``), the
``thrust_estimator`` on the drive alone, the optimising ``controller`` in supply watts, the
``speed_loop`` that turns a speed set-point into the controller's thrust demand, and the
``recorder``.  Parameters: the package's ``config/bringup.yaml``, then ``config/fish.yaml``, then
``params_file:=...``, then the launch arguments (``speed_m_s``).  With ``sim:=false`` no
``fin_sim`` is started: the fish's driver publishes ``drive``, ``swim_speed`` and ``battery`` in
the namespace ``fish`` and obeys ``cmd`` (the README's topic contract).

    ros2 launch piezofin_ros fish.launch.py realtime_factor:=10 speed_m_s:=0.05
    ros2 launch piezofin_ros fish.launch.py sim:=false params_file:=my_fish.yaml
    ros2 launch piezofin_ros fish.launch.py sim:=false realtime_factor:=5   # a simulated driver's /clock
    ros2 param set /fish/speed_loop speed_m_s 0.07
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from piezofin_ros.nodes.launching import number_argument, stop_if_any_fails

NAMESPACE = "fish"
#: Each data topic's readers before fin_sim's first sample: the estimator and the recorder.
CONSUMERS = 2


def _nodes(context, *args, **kwargs):
    config = os.path.join(get_package_share_directory("piezofin_ros"), "config")
    files = [os.path.join(config, "bringup.yaml"), os.path.join(config, "fish.yaml")]
    extra = LaunchConfiguration("params_file").perform(context)
    files += [extra] if extra else []
    factor = number_argument(context, "realtime_factor")
    speed = number_argument(context, "speed_m_s")
    sim = LaunchConfiguration("sim").perform(context).lower() in ("1", "true", "yes")
    # (faster than real time, the nodes run on /clock: fin_sim's, or with sim:=false the fish driver's)
    use_sim_time = factor != 1.0
    nodes = []
    if sim:
        own = {
            "autostart": True,
            "realtime_factor": factor,
            "publish_clock": use_sim_time,
            "wait_subscribers": CONSUMERS,
        }
        nodes.append(
            Node(
                package="piezofin_ros",
                executable="fin_sim",
                name="fin_sim",
                namespace=NAMESPACE,
                parameters=[*files, own],
                output="screen",
            )
        )
    for exe in ("thrust_estimator", "controller", "speed_loop"):
        own = {"use_sim_time": use_sim_time}
        if exe == "speed_loop":
            own["speed_m_s"] = speed
        nodes.append(
            Node(
                package="piezofin_ros",
                executable=exe,
                name=exe,
                namespace=NAMESPACE,
                parameters=[*files, own],
                output="screen",
            )
        )
    nodes.append(
        Node(
            package="piezofin_ros",
            executable="recorder",
            name="recorder",
            parameters=[*files, {"namespaces": [NAMESPACE], "use_sim_time": use_sim_time}],
            output="screen",
        )
    )
    # a node that stops with an error stops them all (a fish without its speed loop swam on)
    return nodes + stop_if_any_fails(nodes)


def generate_launch_description():
    return LaunchDescription(
        [
            DeclareLaunchArgument(
                "params_file", default_value="", description="a parameter file layered on top"
            ),
            DeclareLaunchArgument(
                "sim",
                default_value="true",
                description="start fin_sim (false: the fish's driver publishes drive, swim_speed, battery)",
            ),
            DeclareLaunchArgument(
                "realtime_factor",
                default_value="1.0",
                description="fin_sim speed; other than 1, the nodes run on /clock (with sim:=false, a "
                "driver that simulates its fish this fast publishes it)",
            ),
            DeclareLaunchArgument("speed_m_s", default_value="0.06", description="the speed set-point, m/s"),
            OpaqueFunction(function=_nodes),
        ]
    )
