#!/usr/bin/env bash
# The whole test suite: linter, type check of the ROS-free core, then pytest.
# Extra arguments go to pytest.
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$ROOT"
# A distinct DDS domain per run, so parallel runs on one machine do not see each other.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}"
# One command per line: under `set -e` a failure inside an `a && b && c` list (other than the last
# command) does not stop the script, and a lint error once went on to pytest unnoticed.
echo "== ruff"
ruff check .
ruff format --check .
echo "== mypy (core)"
mypy
echo "== pytest (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
python -m pytest "$@" </dev/null
