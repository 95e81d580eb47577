#!/usr/bin/env bash
# Idempotent set-up for a fresh Debian 12 machine (run as root, or with sudo available):
#   1. apt packages listed in scripts/apt-packages.txt (installed only if some are missing)
#   2. .venv from /usr/bin/python3 (--system-site-packages) + requirements.txt (redone when it changes)
#   3. catkin workspace .ws/ (src/multirobot_map_merge -> repo root), rebuilt only when
#      package.xml, CMakeLists.txt, setup.py or msg/* change.
# Prints one line when everything is already up to date.
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WS="$REPO/.ws"
VENV="$REPO/.venv"
SYS_PY=/usr/bin/python3
PKG_NAME=multirobot_map_merge
did=()

log() { echo "[bootstrap] $*"; }
run_quiet() {  # run_quiet LOGFILE CMD...: keep output in LOGFILE, show its tail on failure
  local logf=$1; shift
  if ! "$@" >"$logf" 2>&1; then
    tail -n 60 "$logf" >&2
    echo "[bootstrap] FAILED: $* (full log: $logf)" >&2
    exit 1
  fi
}

# One bootstrap at a time per checkout (several `make test` may start together).
mkdir -p "$WS"
exec 9>"$WS/.bootstrap.lock"
flock 9

# --- 1. apt ------------------------------------------------------------------
missing_apt_packages() {  # prints the packages of $@ that are not fully installed
  local p st
  for p in "$@"; do
    st=$(dpkg-query -W -f='${db:Status-Abbrev}' "$p" 2>/dev/null || true)
    [[ "$st" == ii* ]] || echo "$p"
  done
}

SUDO=()
[[ $(id -u) -eq 0 ]] || SUDO=(sudo)
mapfile -t APT_PKGS < <(sed -e 's/#.*//' -e 's/[[:space:]]//g' -e '/^$/d' "$REPO/scripts/apt-packages.txt")
mapfile -t MISSING < <(missing_apt_packages "${APT_PKGS[@]}")
if ((${#MISSING[@]})); then
  log "apt-get install ${#MISSING[@]} missing package(s) (log: .ws/apt.log): ${MISSING[*]}"
  run_quiet "$WS/apt-update.log" "${SUDO[@]}" apt-get -o DPkg::Lock::Timeout=600 update
  run_quiet "$WS/apt.log" "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive \
    apt-get -o DPkg::Lock::Timeout=600 install -y --no-install-recommends "${APT_PKGS[@]}"
  mapfile -t MISSING < <(missing_apt_packages "${APT_PKGS[@]}")
  if ((${#MISSING[@]})); then echo "[bootstrap] still missing: ${MISSING[*]}" >&2; exit 1; fi
  did+=(apt)
fi

# --- 2. venv -----------------------------------------------------------------
req_hash=$(sha256sum "$REPO/requirements.txt" | cut -d' ' -f1)
stamp="$VENV/.requirements.sha256"
# Recreate a venv that is missing, was made elsewhere (moved repo) or cannot see the system rospy.
if [[ ! -x "$VENV/bin/python" ]] || ! grep -qxF "command = $SYS_PY -m venv --system-site-packages $VENV" "$VENV/pyvenv.cfg" 2>/dev/null \
   || ! "$VENV/bin/python" -c 'import rospy' >/dev/null 2>&1; then
  log "creating .venv (from $SYS_PY, --system-site-packages)"
  rm -rf "$VENV"
  "$SYS_PY" -m venv --system-site-packages "$VENV"
fi
if [[ "$(cat "$stamp" 2>/dev/null || true)" != "$req_hash" ]]; then
  log "pip install -r requirements.txt"
  run_quiet "$VENV/pip.log" "$VENV/bin/python" -m pip install --disable-pip-version-check \
    -r "$REPO/requirements.txt"
  echo "$req_hash" >"$stamp"
  did+=(venv)
fi

# --- 3. catkin workspace -----------------------------------------------------
mkdir -p "$WS/src"
# The package in the workspace is a directory of links to the repository's top-level entries, not one link to the
# repository: the repository holds .ws itself, and rosrun's `find -L` would otherwise walk into the workspace and
# list every node several times. Hidden entries (.ws, .venv, .git) are left out by the glob.
pkg_src="$WS/src/$PKG_NAME"
[[ -L "$pkg_src" ]] && rm -f "$pkg_src"
mkdir -p "$pkg_src"
for entry in "$REPO"/*; do
  name=$(basename "$entry")
  [[ "$(readlink "$pkg_src/$name" 2>/dev/null || true)" == "../../../$name" ]] || ln -sfn "../../../$name" "$pkg_src/$name"
done
for link in "$pkg_src"/*; do [[ -e "$link" ]] || rm -f "$link"; done
build_hash=$(
  cd "$REPO"
  { echo "$REPO venv-python package-links"; ls nodes; sha256sum package.xml CMakeLists.txt setup.py; find msg -maxdepth 1 -type f -print0 2>/dev/null \
      | sort -z | xargs -0r sha256sum; } | sha256sum | cut -d' ' -f1
)
build_stamp="$WS/.build.sha256"
if [[ ! -f "$WS/devel/setup.bash" || "$(cat "$build_stamp" 2>/dev/null || true)" != "$build_hash" ]]; then
  # A workspace configured from another path (moved/copied repo) cannot be reused.
  if [[ -f "$WS/build/CMakeCache.txt" ]] && ! grep -qx "CMAKE_CACHEFILE_DIR:INTERNAL=$WS/build" "$WS/build/CMakeCache.txt"; then
    rm -rf "$WS/build" "$WS/devel"
  fi
  log "catkin_make (log: .ws/catkin_make.log)"
  rm -f "$build_stamp"
  # node entry points of an older layout (catkin does not remove them; rosrun would find each node twice)
  rm -rf "$WS/devel/lib/$PKG_NAME"
  # The venv's python (made from /usr/bin/python3; the pyenv python3 on PATH cannot import catkin): the node
  # relay scripts catkin writes into devel/ get it as their interpreter, so nodes see the pinned numpy/OpenCV.
  run_quiet "$WS/catkin_make.log" env PATH="/usr/bin:/bin:$PATH" PYTHONDONTWRITEBYTECODE=1 \
    catkin_make -C "$WS" --force-cmake -DPYTHON_EXECUTABLE="$VENV/bin/python3" -DCATKIN_ENABLE_TESTING=OFF
  echo "$build_hash" >"$build_stamp"
  did+=(catkin)
fi

if ((${#did[@]})); then
  log "done (${did[*]})"
else
  log "up to date (apt, .venv, .ws)"
fi
