#!/usr/bin/env bash
# The main job: the whole suite in one process with simulated hardware, 40x faster than real time,
# on the paper's rig as a twin (M8528-P1 with the effects fitted to the paper's facts, the model
# preset paper-twin-M8528-P1; `--models nominal` runs the nominal fin instead).  The controller runs
# 22 protocol trials (11 frequencies x 2 voltages, 30 s each: 11 minutes of fin time) and chooses by
# thrust per supply watt; everything is recorded to a new bag under bags/; the run ends with a
# summary table, out/bringup.png and out/bringup.json.
# Extra arguments go to `bringup` (e.g. --namespaces left right, --realtime-factor 20, --fins M8514-P1).
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$ROOT"
mkdir -p out bags
twin=(--models paper-twin-M8528-P1)
for arg in "$@"; do
    case "$arg" in --fins | --models) twin=() ;; esac  # the user names the fin or the model
done
bringup "${twin[@]}" --plot out/bringup.png --json out/bringup.json "$@"
