#!/usr/bin/env bash
# The main job: steady-state sweep of the default fin (M8528-P1) at 400/600/800 Vpp, 1-11 Hz,
# with a plot in out/.  Extra arguments go to `piezofin sweep`.
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
mkdir -p "$ROOT/out"
piezofin sweep --fin M8528-P1 --vpp 400 600 800 --freq 1:11:0.1 --plot "$ROOT/out/sweep_M8528-P1.png" "$@"
