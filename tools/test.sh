#!/usr/bin/env bash
# The test suite: linter, type check of the ROS-free core, then pytest on parallel workers.
#
#   bash tools/test.sh --fast     the fast tier, after each edit: every layer's science and every
#                                 node's logic at small sizes (the tests not marked `slow`)
#   bash tools/test.sh            the whole suite: every test but the long scenarios
#   bash tools/test.sh --long     every test, the long scenarios too (marked `long`: the soak, the
#                                 full fuzz); CI runs this
#
# Other arguments go to pytest (`bash tools/test.sh --fast -k steady`, `bash tools/test.sh -n 0`).
# Both print the slowest tests and the time of each step.
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$ROOT"
# A distinct DDS domain per run, so parallel runs on one machine do not see each other (each
# pytest-xdist worker then takes its own domain above it: test/conftest.py).
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}"
tier=whole
args=()
for a in "$@"; do
  case "$a" in
    --fast) tier=fast ;;
    --long) tier=long ;;
    *) args+=("$a") ;;
  esac
done
case "$tier" in
  fast) select="not slow and not long"; slowest=10 ;;
  whole) select="not long"; slowest=30 ;;
  long) select="not within_long"; slowest=30 ;;  # (a within_long test's cases run in its long superset)
esac
t0=$SECONDS
# One command per line: under `set -e` a failure inside an `a && b && c` list (other than the last
# command) does not stop the script, and a lint error once went on to pytest unnoticed.
echo "== ruff"
ruff check .
ruff format --check .
echo "== mypy (the package, nodes included)"
mypy
t1=$SECONDS
export PYTHONPYCACHEPREFIX="${PYTHONPYCACHEPREFIX:-$ROOT/.ros/pycache}"  # hundreds of test processes: compile once
unset PYTHONDONTWRITEBYTECODE
# Two phases.  1: every test but those marked `exclusive`, on parallel workers (pytest-xdist; each
# worker on its own DDS domain).  2: the `exclusive` ones (wall-clock latency bounds: a watchdog
# within 1 s of a kill, no drop at 1 kHz), two at a time and never beside the CPU-bound tests (each
# loads under a third of a core: measured by the CPU column of the summary).
echo "== pytest, $tier tier, phase 1: in parallel (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
rc1=0
# One worker more than the cores: half of a test's time is spent waiting (a node's start-up, a live
# graph in real time), and the third worker fills it (measured: docs/testing.md).
workers="${PIEZOFIN_TEST_WORKERS:-$(( $(nproc) + 1 ))}"
python -m pytest -n "$workers" --dist loadgroup --durations="$slowest" --durations-min=1.0 \
  -m "not exclusive${select:+ and ($select)}" "${args[@]}" </dev/null || rc1=$?
t2=$SECONDS
rc2=0
if [ "$tier" != fast ]; then
  echo "== pytest, $tier tier, phase 2: the exclusive tests, two at a time"
  PIEZOFIN_EXCLUSIVE_TOGETHER=1 python -m pytest -n 2 --durations="$slowest" --durations-min=1.0 -m "exclusive${select:+ and ($select)}" \
    "${args[@]}" </dev/null || rc2=$?
  [ "$rc2" -eq 5 ] && rc2=0  # none selected (e.g. -k matched none of them)
fi
t3=$SECONDS
echo "== $tier tier: $((t3 - t0)) s (ruff and mypy $((t1 - t0)) s, pytest in parallel $((t2 - t1)) s, exclusive $((t3 - t2)) s)"
[ "$rc1" -eq 5 ] && rc1=0
exit $(( rc1 != 0 ? rc1 : rc2 ))
