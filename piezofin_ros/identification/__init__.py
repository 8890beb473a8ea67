"""Identifying a fin from experiments, as the paper's Sec. 3.2 does, free of ROS.

* :mod:`.frf`: frequency-response points from a recorded stepped sine (steps found in the drive,
  lock-in, measured noise);
* :mod:`.fit`: ``f_sc``, ``zeta``, ``theta``, ``C_eq`` and ``D`` from an in-air sweep, ``c_m`` and
  ``c_d`` from an underwater one, each with its uncertainty and what the data cannot identify;
* :mod:`.experiment`: the stepped sine on the simulated rig (tests, benchmarks, the campaign).

Imports :mod:`piezofin_ros.physics`, :mod:`..bags` and :mod:`..rig` only.
"""
