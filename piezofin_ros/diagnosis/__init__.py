"""Sim-to-real gap diagnosis: where the model and the measurements disagree, why, and how far
adding the missing effect closes the gap.  Plain numpy/scipy; no ROS.

* :mod:`.data`: measured trials (from bags, CSV or the generator) with their uncertainties;
* :mod:`.model`: the effect library and the augmented steady-state model;
* :mod:`.stages`: the gap of each stage of the model, fed with measured inputs;
* :mod:`.attribute`: fit, held-out scoring and ranking of candidate effects;
* :mod:`.synthetic`: "real" datasets with hidden effects, simulated in the time domain;
* :mod:`.report`: plots and the written report.
"""
