#!/usr/bin/env bash
# The main job: the whole suite in one process on the default fin (M8528-P1) with simulated
# hardware, 40x faster than real time.  The controller runs 22 protocol trials (11 frequencies
# x 2 voltages, 30 s each: 11 minutes of fin time); everything is recorded to a new bag under
# bags/; the run ends with a summary table, out/bringup.png and out/bringup.json.
# Extra arguments go to `bringup` (e.g. --namespaces left right, --realtime-factor 20).
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$ROOT"
mkdir -p out bags
bringup --plot out/bringup.png --json out/bringup.json "$@"
