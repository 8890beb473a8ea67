"""The simulated test rig, free of ROS: a safe drive (checks, slew, watchdog), the fin, the
instruments and the load cell, streamed block by block (:mod:`.simulated`).  A real rig driver
replaces it behind the same topics.  Imports :mod:`piezofin_ros.physics` only.
"""
