"""The drive's hard limits, in a module of their own: every node imports them, and the nodes a fish
runs must not load the simulated rig to know them."""

from __future__ import annotations

#: Hard cap on the peak-to-peak drive voltage that no configuration can exceed.  Smart Material's
#: MFC datasheet rates the P1 (d33) types for -500 V .. +1500 V; a symmetric bipolar sine is
#: therefore limited to +-500 V, i.e. 1000 Vpp.  The paper drives at most 800 Vpp.
HARD_VOLTAGE_PP_MAX = 1000.0
