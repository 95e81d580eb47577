#!/usr/bin/env bash
# Usage: scripts/env.sh CMD [ARGS...]   (from any directory; run `make setup` first)
# Runs CMD with the catkin devel space (.ws/devel) sourced, .venv/bin first on PATH (so
# `python`, `python3` and `#!/usr/bin/env python3` nodes started by roslaunch/rostest use the
# venv with the pinned OpenCV/numpy), and ROS_HOME/ROS_LOG_DIR under .ws/ros_home.
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS="$REPO/.ws"
if [[ ! -f "$WS/devel/setup.bash" || ! -x "$REPO/.venv/bin/python" ]]; then
  echo "env.sh: $WS/devel or $REPO/.venv missing: run 'make setup' in $REPO first" >&2
  exit 1
fi
if [[ $# -eq 0 ]]; then
  echo "usage: $0 CMD [ARGS...]" >&2
  exit 2
fi
# setup.bash parses the positional parameters a plain `source` passes on (--extend, ...): hide the command's
cmd=("$@")
set --
# shellcheck disable=SC1091
source "$WS/devel/setup.bash"
set -- "${cmd[@]}"
export VIRTUAL_ENV="$REPO/.venv"
export PATH="$VIRTUAL_ENV/bin:$PATH"
export ROS_HOME="$WS/ros_home"
export ROS_LOG_DIR="$ROS_HOME/log"
export PYTHONDONTWRITEBYTECODE="${PYTHONDONTWRITEBYTECODE:-1}"
export MMM_REPO="$REPO"
mkdir -p "$ROS_LOG_DIR"
exec "$@"
