"""The command line (``piezofin``, ``sweep``, ``diagnose``): :mod:`.main` parses and runs,
:mod:`.plots` draws.  No ROS: it reads and writes files, and runs the science packages.
"""
