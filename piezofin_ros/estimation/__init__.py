"""Thrust, power and thrust per watt from the drive's voltage and current (and, where there is
one, a vibrometer and a load cell), free of ROS.

* :mod:`.estimator`: windows, lock-in, Lighthill with ``c_m(psi)``, Parseval power, self-sensing
  through Eq. (10), load-cell baselines, the streaming estimator;
* :mod:`.offline`: the same estimator replayed over a recorded bag.
"""
