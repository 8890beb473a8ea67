"""The optimiser's knobs, in one object (:class:`Tuning`), read by each of its rooms."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Tuning:
    """The optimiser's knobs, each with the default the benchmarks were measured with."""

    search_chi2: float = 4.0  # the model mispredicts when its residuals exceed this (per datum)
    kappa: float = 1.0  # the search's optimism, in standard deviations of the map
    trust_region: float = 0.15  # the search stays within f (1 +- this) of the incumbent
    memory_s: float = 300.0  # forget measurements older than this, but for the anchors:
    #: of the trials older than ``memory_s``, the newest at each frequency more than
    #: ``anchor_spacing`` (relative) from every later trial's stays, up to this many, until a change
    #: clears everything: the spread in frequency that calibrates a fish's self-sensing (aged out,
    #: M8507-P1 held at one point saw its estimate's bound double and the estimate creep 8-30 % high)
    memory_anchors: int = 4
    anchor_spacing: float = 0.05
    change_sigma: float = 4.0  # this many sigma off a point's earlier trials (or the map): a change
    tolerance: float = 0.01  # a proposal this close (relative, see evidence.close) to a measured point
    hold_gain: float = 0.01  # the incumbent is held unless the map expects this much more elsewhere
    probe_every: int = 2  # once converged, every this many trials a probe beside the incumbent
    probe_step: float = 0.03  # at f (1 +- this)
    n_grid: int = 160  # frequencies in the map's first pass
    #: On a fish (drive only) the stiffness cannot be told from the coupling (the motional admittance
    #: is theta^2 times the mechanical response): it is held to the fin file's, within this (log) sigma.
    stiffness_sigma: float = 0.05
    #: on a fish under a demand (a ``trial_overshoot``), no calibrating trial where the map expects
    #: less thrust than the demand by more than this (relative), and the quiet identification trial
    #: only from rest or when asked: its speed follows each trial's thrust (a re-identifying trial
    #: dropped it 60-80 % for 20-30 s every 320-470 s)
    hold_margin: float = 0.1
    #: A diagnosed ``model`` given as the prior whose corrected fit misses the trials by more than
    #: their noise while the fin file alone, corrected, fits them this many times better (chi-square),
    #: is dropped for good (the paper's twin given to a fish whose fin was the nominal one, its
    #: softening and KC added mass outside the correction, kept the fit 3-9 sigma off for 60 trials)
    prior_drop_ratio: float = 2.0
    #: from this many trials on (the quiet identification trial and one more): at 4, stranger 2 of
    #: ``bench_course.py``, its fin resonating at 9.3 Hz where the twin given says 5.5, swam its first
    #: 55 s at 4.6 Hz (6.9 cm/s against 17.7) and paid 8.5 % more per metre than the best fixed drive;
    #: at 2 it leaves 4.6 Hz at 29 s (+4.9 %).  No fish under a demand of ``bench_fish.py`` (the twins,
    #: the 9 with an effect not told, the strangers) dropped its prior by the misfit otherwise than at 4
    prior_drop_after: int = 2
    #: ... or, within the noise, when the fit's whole cost (its weighed misfit and how far its
    #: parameters left their prior, squared sigmas summed: twice the negative log posterior) exceeds
    #: the fin file's by more than this: a wrong model fits a few trials only by moving its
    #: parameters far (the strangers' twin: 5.8 and 13.2 against the fin file's 1.8 and 0.9 after two
    #: and three trials; a right one costs 0.0-1.0 where the fin file costs 3-14), over the first
    #: ``fit.PRIOR_COST_TRIALS`` trials
    prior_drop_cost: float = 3.0
    #: a calibrating trial is taken when it shrinks the calibration's variance at the map's choice to
    #: less than this fraction of what one more trial at the choice would
    calibrate_gain: float = 0.5
    #: and no more than this many calibrating trials are in memory
    max_calibrating_trials: int = 3
