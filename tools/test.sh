#!/usr/bin/env bash
# The whole test suite: linter, type check of the ROS-free core, then pytest.
# Extra arguments go to pytest.
source "$(dirname "${BASH_SOURCE[0]}")/env.sh"
cd "$ROOT"
# A distinct DDS domain per run, so parallel runs on one machine do not see each other.
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( (RANDOM % 100) + 1 ))}"
echo "== ruff" && ruff check . && ruff format --check .
echo "== mypy (core)" && mypy
echo "== pytest (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)" && python -m pytest "$@" </dev/null
