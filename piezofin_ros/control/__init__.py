"""Choosing frequency and voltage, free of ROS: trial schedules, the thrust-per-watt optimiser and
its drive loop, and the plants (fins unknown to the controller) it is benchmarked on.

* :mod:`.trials`: the paper's protocol and continuous trials, estimate matching, the choice;
* :mod:`.optimise`: the corrected model map, its fit after every trial, change detection, the
  live drive loop (settling, slew, estimate watchdog);
* :mod:`.plants`: a model plus drift and measurement noise, for the benchmark and the tests.

Imports :mod:`piezofin_ros.physics` only (and the estimate type of :mod:`..estimation`).
"""
