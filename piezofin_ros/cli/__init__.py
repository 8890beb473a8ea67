"""The command line (``piezofin``, ``sweep``, ``diagnose``, ``estimate``, ``fins``, ``bag recover``).

:mod:`.main` parses the arguments and runs the science packages on files: it predicts sweeps from a
fin's parameters, estimates thrust and power from recorded bags, diagnoses a sim-to-real gap and
repairs a bag whose writer was killed; :mod:`.plots` draws the figures and tables.  No ROS here:
the same commands run on a laptop without a ROS installation (``ros2 run`` starts the same code).
"""
