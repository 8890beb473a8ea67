#!/usr/bin/env bash
# The test suite: linter, type check of the ROS-free core, then pytest on one worker per core.
#
#   bash tools/test.sh            the whole suite (what CI runs): every test
#   bash tools/test.sh --fast     the fast tier, after each edit: every layer's science and every
#                                 node's logic at small sizes (the tests not marked `slow`)
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
  if [ "$a" = "--fast" ]; then tier=fast; else args+=("$a"); fi
done
if [ "$tier" = fast ]; then
  select=(-m "not slow")
  slowest=10
else
  select=()
  slowest=30
fi
t0=$SECONDS
# One command per line: under `set -e` a failure inside an `a && b && c` list (other than the last
# command) does not stop the script, and a lint error once went on to pytest unnoticed.
echo "== ruff"
ruff check .
ruff format --check .
echo "== mypy (core)"
mypy
t1=$SECONDS
echo "== pytest, $tier tier (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
export PYTHONPYCACHEPREFIX="${PYTHONPYCACHEPREFIX:-$ROOT/.ros/pycache}"  # hundreds of test processes: compile once
unset PYTHONDONTWRITEBYTECODE
python -m pytest -n "${PIEZOFIN_TEST_WORKERS:-auto}" --dist loadgroup --durations="$slowest" --durations-min=1.0 \
  "${select[@]}" "${args[@]}" </dev/null
t2=$SECONDS
echo "== $tier tier: $((t2 - t0)) s (ruff and mypy $((t1 - t0)) s, pytest $((t2 - t1)) s)"
