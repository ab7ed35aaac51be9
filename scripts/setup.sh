#!/usr/bin/env bash
# One-step, idempotent set-up of the GL-DT workspace: Python 3.11 venv with ROS 2 Jazzy from PyPI,
# the gldt_core package (editable) and its extras, and a colcon build of gldt_msgs + gldt_ros.
#
# Usage: scripts/setup.sh [EXTRAS]     (EXTRAS: pip extras of gldt-core, default "test,train")
#
# Every step is skipped when its inputs have not changed since it last succeeded (a stamp file
# under .setup-stamps/ holds the hash of those inputs), so a rerun costs seconds. A step that fails
# prints one line "setup: <step>: <cause>" and leaves no stamp, so the next run redoes it.
set -uo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMPS="$ROOT/.setup-stamps"
LOGS="$ROOT/log/setup"
EXTRAS="${1:-test,train}"
mkdir -p "$STAMPS" "$LOGS"

fail() { echo "setup: $1: $2" >&2; exit 1; }

# Hash of the given files and of the given extra strings; decides whether a step must rerun.
inputs_hash() { { for f in "$@"; do if [ -e "$f" ]; then cat "$f"; else echo "$f"; fi; done; } | sha256sum | cut -c1-16; }

step_done() { [ -f "$STAMPS/$1" ] && [ "$(cat "$STAMPS/$1")" = "$2" ]; }
mark_done() { echo "$2" > "$STAMPS/$1"; }

# Run a command with its output in a log; on failure name the step and the most telling line.
run_logged() {
    local step="$1"; shift
    local log="$LOGS/$step.log"
    if ! "$@" >"$log" 2>&1; then
        local cause
        cause=$(grep -E -m1 -i "could not find a version|no matching distribution|connection|network is unreachable|temporary failure|name resolution|could not find a package configuration|error:|failed" "$log" | cut -c1-220)
        fail "$step" "${cause:-command failed: $*} (full log: ${log#$ROOT/})"
    fi
}

# 1. Tools the build needs.
PYTHON="${PYTHON:-}"
if [ -n "$PYTHON" ] && ! "$PYTHON" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
    fail "python" "PYTHON=$PYTHON is not a Python 3.11 interpreter (the ROS 2 Jazzy wheels on PyPI are built for CPython 3.11)"
fi
if [ -z "$PYTHON" ]; then
    for candidate in python3.11 python3; do
        if command -v "$candidate" >/dev/null 2>&1 && "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
            PYTHON="$(command -v "$candidate")"; break
        fi
    done
fi
[ -n "$PYTHON" ] || fail "python" "Python 3.11 not found (the ROS 2 Jazzy wheels on PyPI are built for CPython 3.11); install python3.11 or set PYTHON=/path/to/python3.11"
command -v cmake >/dev/null 2>&1 || fail "tools" "cmake not found (needed to build gldt_msgs); install it, e.g. apt-get install cmake"
command -v g++ >/dev/null 2>&1 || fail "tools" "g++ not found (needed to build gldt_msgs); install it, e.g. apt-get install g++"
command -v make >/dev/null 2>&1 || fail "tools" "make not found; install it, e.g. apt-get install make"

# 2. The virtual environment (recreated when broken, e.g. after the base Python moved).
if ! "$VENV/bin/python" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' >/dev/null 2>&1; then
    rm -rf "$VENV" "$STAMPS"/*
    mkdir -p "$STAMPS"
    "$PYTHON" -m venv "$VENV" >"$LOGS/venv.log" 2>&1 || { rm -rf "$VENV"; fail "venv" "python -m venv failed (is python3.11-venv installed?) (log: log/setup/venv.log)"; }
fi
PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)

# 3. Python packages: ROS 2 wheels, then gldt-core with its extras.
ros_hash=$(inputs_hash "$ROOT/scripts/requirements-ros.txt")
if ! step_done ros-wheels "$ros_hash"; then
    echo "setup: installing ROS 2 Jazzy wheels from PyPI (first run: about a minute)"
    run_logged pip-ros "${PIP[@]}" install -r "$ROOT/scripts/requirements-ros.txt"
    mark_done ros-wheels "$ros_hash"
fi
core_hash=$(inputs_hash "$ROOT/pyproject.toml" "extras=$EXTRAS")
if ! step_done gldt-core "$core_hash"; then
    echo "setup: installing gldt-core[$EXTRAS] (editable)"
    run_logged pip-core "${PIP[@]}" install -e "$ROOT[$EXTRAS]"
    mark_done gldt-core "$core_hash"
fi

# 3b. boxmot, the reference trackers the tests compare ours with (ByteTrack) and `gldt bench
# tracking` runs as peers, with the test extra. boxmot declares torch, torchvision and more as
# dependencies; resolving them would pull a CUDA torch over the CPU one of the train extra, so it
# goes in without its dependencies, plus the two it imports that the venv lacks (lapx, rich).
# Its trackers import torch, which the train extra brings.
BOXMOT_PINS=("boxmot==25.0.0")
BOXMOT_DEPS=("lapx==0.11.1" "rich")
if [[ ",$EXTRAS," == *",test,"* ]]; then
    peers_hash=$(inputs_hash "${BOXMOT_PINS[@]}" "${BOXMOT_DEPS[@]}" "$STAMPS/gldt-core")
    if ! step_done boxmot "$peers_hash"; then
        echo "setup: installing ${BOXMOT_PINS[*]} (without its dependencies) and ${BOXMOT_DEPS[*]}"
        run_logged pip-boxmot "${PIP[@]}" install --no-deps "${BOXMOT_PINS[@]}"
        run_logged pip-boxmot-deps "${PIP[@]}" install "${BOXMOT_DEPS[@]}"
        "$VENV/bin/python" -c 'import torch' >/dev/null 2>&1 \
            || fail "boxmot" "its trackers import torch, which the train extra installs (scripts/setup.sh test,train)"
        "$VENV/bin/python" -c 'from boxmot import BotSort, ByteTrack, OcSort' >"$LOGS/boxmot-import.log" 2>&1 \
            || fail "boxmot" "import failed: $(grep -E -m1 'Error' "$LOGS/boxmot-import.log" | cut -c1-200) (full log: log/setup/boxmot-import.log)"
        mark_done boxmot "$peers_hash"
    fi
fi

# 4. The wheels' CMake exports carry the wheel build machine's Python paths; point them here.
cmake_hash=$(inputs_hash "$STAMPS/ros-wheels")
if ! step_done cmake-paths "$cmake_hash"; then
    run_logged cmake-paths "$VENV/bin/python" "$ROOT/scripts/fix_cmake_paths.py" "$VENV"
    mark_done cmake-paths "$cmake_hash"
fi

# 5. colcon build of the interface package and the ROS package into install/.
src_hash=$( (cd "$ROOT" && find msg_defs src/gldt_ros colcon.meta -type f ! -name '*.pyc' -print0 | sort -z | xargs -0 sha256sum) | sha256sum | cut -c1-16)
build_hash="$src_hash-$(cat "$STAMPS/ros-wheels")"
if ! step_done colcon "$build_hash" || [ ! -f "$ROOT/install/setup.bash" ]; then
    echo "setup: colcon build (gldt_msgs, gldt_ros)"
    (
        cd "$ROOT" || exit 1
        export PATH="$VENV/bin:$PATH" CMAKE_PREFIX_PATH="$VENV" AMENT_PREFIX_PATH="$VENV"
        "$VENV/bin/colcon" --log-base log build --base-paths msg_defs src/gldt_ros \
            --build-base build --install-base install --metas colcon.meta \
            --event-handlers console_direct- --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python"
    ) >"$LOGS/colcon.log" 2>&1 || {
        cause=$(grep -E -m1 "CMake Error|Error|error:|Failed" "$LOGS/colcon.log" | cut -c1-220)
        fail "colcon build" "${cause:-failed} (full log: log/setup/colcon.log)"
    }
    mark_done colcon "$build_hash"
fi
echo "setup: ready (venv: .venv, ROS workspace: install/)"
