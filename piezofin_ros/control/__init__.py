"""Choosing frequency and voltage, free of ROS: trial schedules, the optimiser and the objective it
is given, its drive loop, and the fish's speed loop (the benchmarks' harness, the plants it is
scored on, is :mod:`piezofin_ros.bench`).

* :mod:`.trials`: the paper's protocol and continuous trials, estimate matching, the choice;
* :mod:`.optimise`: the corrected model map, its fit after every trial, change detection, the
  live drive loop (settling, slew, estimate watchdog);
* :mod:`.objective`: what the optimiser maximises (thrust per watt unless told);
* :mod:`.speedloop`: a fish's speed set-point to a thrust demand.

Imports :mod:`piezofin_ros.physics` only (and the estimate type of :mod:`..estimation`).
"""
