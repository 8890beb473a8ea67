"""The physics of the fin, free of ROS: the paper's model and the effects a real fin adds.

* :mod:`.fin`, :mod:`.modeshape`, :mod:`.hydro`: a fin's inputs and derived quantities (mode
  shape, aspect-ratio-corrected ``c_m(psi)``, added mass, drag);
* :mod:`.steady`: the harmonic balance of Eqs. (12)-(20), closed form and multi-harmonic;
* :mod:`.timedomain`, :mod:`.waveforms`: Eqs. (9)-(10) integrated for any drive, and with the
  effects' time-domain laws;
* :mod:`.effects`, :mod:`.knobs`: effects as immutable objects with their time-domain law and
  describing function side by side;
* :mod:`.model`: a fin plus effects, its steady state and persistence: the one model the rig,
  the optimiser, the plants and the diagnosis use.

Nothing here imports from another package of ``piezofin_ros``.
"""
