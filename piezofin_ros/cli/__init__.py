"""The command line (``piezofin``, ``sweep``, ``diagnose``, ``estimate``, ``fins``, ``bag recover``).

:mod:`.main` parses the arguments and runs the science packages on files: it predicts sweeps from a
fin's parameters, estimates thrust and power from recorded bags, diagnoses a sim-to-real gap and
repairs a bag whose writer was killed; :mod:`.args` holds what every command shares (exit statuses,
the one-line error, argument checks), :mod:`.plots` draws the identification's figure, and the
campaign is :mod:`.campaign_plan` (what it plans), :mod:`.campaign` (the run) and
:mod:`.campaign_report` (the report).  The controller's tables and plots, which ``bringup`` prints
too, live below both (:mod:`piezofin_ros.control.report`).  No ROS here:
the same commands run on a laptop without a ROS installation (``ros2 run`` starts the same code).
"""
