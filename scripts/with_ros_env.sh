#!/usr/bin/env bash
# Run a command with the colcon workspace (install/) on the paths, as `source install/setup.bash`
# would, without needing a ROS installation: gldt_msgs' Python bindings and libraries, the
# gldt_ros package and its executables (install/gldt_ros/lib/gldt_ros), and the ament index.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
INSTALL="$ROOT/install"
for pkg in gldt_msgs gldt_ros; do
    [ -d "$INSTALL/$pkg" ] || { echo "with_ros_env: $INSTALL/$pkg missing; run 'make test' or scripts/setup.sh first" >&2; exit 1; }
    PYTHONPATH="$INSTALL/$pkg/lib/python3.11/site-packages${PYTHONPATH:+:$PYTHONPATH}"
    LD_LIBRARY_PATH="$INSTALL/$pkg/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
    AMENT_PREFIX_PATH="$INSTALL/$pkg${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}"
done
PATH="$ROOT/.venv/bin:$INSTALL/gldt_ros/lib/gldt_ros:$PATH"
export PYTHONPATH LD_LIBRARY_PATH AMENT_PREFIX_PATH PATH
exec "$@"
