#!/usr/bin/env bash
# make demo [DEMO_ARGS="--robots N --world MAP.yaml --world-seed S --seed S --speedup X ..."]
#
# Live demo (default): the fleet simulator runs N robots (default 3) at random starts in a generated building (or any
# map_server YAML), one explorer per robot explores it, map_merge merges the robot maps without known initial poses.
# Headless, sim time at --speedup x real time; prints a progress line; ends when exploration is finished or at a
# limit; writes out/demo/merged.{yaml,pgm,png} and out/demo/summary.{txt,json} (explored share, times, placement
# error of the merge against the simulator's ground truth). Full roslaunch output: out/demo/roslaunch.log.
#
# Options (also as --opt=value):
#   --robots N          robots, 1..12 (default 3)
#   --world FILE.yaml   world map (map_server YAML; occupied and unknown cells are walls); default: generated,
#                       24 m x 16 m, or 48 m x 32 m for more than 6 robots
#   --world-seed S      floor plan of the generated world (default 0)
#   --seed S            start poses and laser noise (default 0)
#   --speedup X         sim time / real time (default 5; 2 for more than 6 robots, which 2 cores sustain)
#   --no-coordination   explorers ignore each other (plain explore_lite behaviour)
#   --realistic         robots as real ones: fleet_sim's realistic profile (270-degree 30 m laser with range noise,
#                       glass, people walking, doors that open and shut, SLAM pose drift with loop closures)
#   --limit-sim S       give up after S s of sim time (default 1200)
#   --limit-wall S      give up after S s of real time (default 240; 900 for more than 6 robots)
#   --out DIR           output directory (default out/demo)
#   --record FILE.bag   also record the robots' maps, map updates and map_merge's status into a rosbag, and
#                       map_merge's estimations (their exact inputs) into FILE.estimations/ (recording.py)
#   --offline [NAME]    instead: merge the sample maps data/samples/NAME (default three_robots) offline and report
#                       their placement error (no ROS master)
# Runs itself through scripts/env.sh (the venv and the catkin devel space), as make demo does.
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# run directly, it would find neither the venv nor the catkin devel space (roslaunch: "demo.launch is neither a
# launch file in package multirobot_map_merge ..."): through env.sh, as make demo runs it
[ -n "${MMM_REPO:-}" ] || exec "$repo/scripts/env.sh" bash "${BASH_SOURCE[0]}" "$@"

# The Makefile passes DEMO_ARGS as one word: split it.
# shellcheck disable=SC2048,SC2086
set -- $*

robots=3 world="" world_seed=0 seed=0 speedup="" coordinate=true realistic=false limit_sim=1200 limit_wall=""
out="$repo/out/demo" offline="" scenario=three_robots record=""
usage() { sed -n '2,27p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; }
need() { [ $# -ge 2 ] && [ -n "$2" ] || { echo "demo: $1 needs a value" >&2; exit 2; }; }
while [ $# -gt 0 ]; do
  opt=$1 val=""
  case $opt in --*=*) val=${opt#*=}; opt=${opt%%=*}; set -- "$opt" "$val" "${@:2}";; esac
  case $opt in
    --robots) need "$@"; robots=$2; shift;;
    --world) need "$@"; world=$2; shift;;
    --world-seed) need "$@"; world_seed=$2; shift;;
    --seed) need "$@"; seed=$2; shift;;
    --speedup) need "$@"; speedup=$2; shift;;
    --no-coordination) coordinate=false;;
    --realistic) realistic=true;;
    --limit-sim) need "$@"; limit_sim=$2; shift;;
    --limit-wall) need "$@"; limit_wall=$2; shift;;
    --out) need "$@"; out=$2; shift;;
    --record) need "$@"; record=$2; shift;;
    --offline) offline=1; if [ $# -ge 2 ] && [[ $2 != --* ]]; then scenario=$2; shift; fi;;
    -h|--help) usage; exit 0;;
    *) echo "demo: unknown option '$1' (see --help)" >&2; exit 2;;
  esac
  shift
done
is_int() { [[ $1 =~ ^[0-9]+$ ]]; }
is_num() { [[ $1 =~ ^[0-9]+([.][0-9]*)?$ ]]; }
is_int "$robots" && [ "$robots" -ge 1 ] && [ "$robots" -le 12 ] || { echo "demo: --robots must be 1..12" >&2; exit 2; }
many=$([ "$robots" -gt 6 ] && echo 1 || true)
: "${speedup:=$([ -n "$many" ] && echo 2 || echo 5)}" "${limit_wall:=$([ -n "$many" ] && echo 900 || echo 240)}"
is_int "$world_seed" && is_int "$seed" || { echo "demo: seeds must be non-negative integers" >&2; exit 2; }
is_num "$speedup" && is_num "$limit_sim" && is_num "$limit_wall" \
  || { echo "demo: --speedup and the limits must be positive numbers" >&2; exit 2; }
mkdir -p "$out"
out="$(cd "$out" && pwd)"

if [ -n "$offline" ]; then
  src="$repo/data/samples/$scenario"
  [ -f "$src/truth.json" ] || { echo "demo: no sample scenario '$scenario' in data/samples" >&2; exit 2; }
  python "$repo/nodes/merge_maps" --output "$out/merged" --transforms-json "$out/transforms.json" "$src"/map_*.yaml
  python "$repo/scripts/placement_report.py" "$src/truth.json" "$out/transforms.json"
  echo "demo: merged map in $out/merged.yaml (+ .pgm), preview $out/merged.png, overlay $out/merged_overlay.png"
  exit 0
fi

if [ -n "$world" ]; then
  [ -f "$world" ] || { echo "demo: world file '$world' not found" >&2; exit 2; }
  world="$(cd "$(dirname "$world")" && pwd)/$(basename "$world")"
fi
# A master of our own on a free port: never disturb (or join) another ROS system on this machine.
port=$(python -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI="http://127.0.0.1:$port"
export ROS_HOSTNAME=127.0.0.1
rm -f "$out/summary.txt" "$out/summary.json"
echo "demo: $robots robots, world ${world:-generated (seed $world_seed)}, seed $seed, speed-up $speedup," \
     "coordination $coordinate$([ "$realistic" = true ] && echo ', realistic robots'); log in $out/roslaunch.log"
set +e
rec_pid="" core_pid=""
stop_recorder() {   # also on Ctrl-C or an error: no recorder or master of ours is left running
  [ -n "$rec_pid" ] || return 0
  pkill -INT -P "$rec_pid" 2>/dev/null; kill -INT "$rec_pid" 2>/dev/null; wait "$rec_pid" 2>/dev/null
  kill -INT "$core_pid" 2>/dev/null; wait "$core_pid" 2>/dev/null
  rec_pid=""
}
trap stop_recorder EXIT
if [ -n "$record" ]; then
  mkdir -p "$(dirname "$record")"
  export MAP_MERGE_RECORD_ESTIMATIONS="${record%.bag}.estimations"
  rm -rf "$MAP_MERGE_RECORD_ESTIMATIONS"
  # The recorder subscribes before the fleet starts, so that the bag holds every map and update from the first
  # (started with the launch, it connected after 1-2 s of real time, 5-10 sim s; until then only the latched
  # latest map of each robot reached it). Its own master (with rosout) first; roslaunch then uses that one.
  topics=(/map_merge/map_merge/status)
  for n in $(seq "$robots"); do topics+=("/robot_$n/map" "/robot_$n/map_updates"); done
  # in sessions of their own: a Ctrl-C stops the launch first (its nodes unregister from this master), then the
  # EXIT trap stops these two
  setsid roscore -p "$port" >"$out/roscore.log" 2>&1 &
  core_pid=$!
  for _ in $(seq 100); do rostopic list >/dev/null 2>&1 && break; sleep 0.1; done
  rosparam set /use_sim_time true   # as the launch sets it: the bag's times are sim times
  setsid rosbag record -q -O "$record" "${topics[@]}" >/dev/null 2>&1 &
  rec_pid=$!
  for _ in $(seq 100); do rostopic info "/robot_$robots/map_updates" 2>/dev/null | grep -q '^ \* /record' && break
    sleep 0.1; done
fi
# Hard stop a little after the supervisor's own real-time limit, whatever happens.
timeout --signal=INT --kill-after=15 "$(python -c "print(int(float('$limit_wall') + 40))")" \
  roslaunch -p "$port" multirobot_map_merge demo.launch num_robots:="$robots" world:="$world" \
    world_seed:="$world_seed" seed:="$seed" speedup:="$speedup" coordinate:="$coordinate" realistic:="$realistic" out:="$out" \
    limit_sim:="$limit_sim" limit_wall:="$limit_wall" 2>&1 \
  | tee "$out/roslaunch.log" | grep --line-buffered -E '^\[demo\]|^demo:|has died|FATAL|ERROR|Traceback' \
  | grep --line-buffered -v 'REQUIRED process \[demo_supervisor'
if [ -n "$rec_pid" ]; then
  stop_recorder
  echo "demo: maps recorded in $record, map_merge's estimations in $MAP_MERGE_RECORD_ESTIMATIONS"
fi
set -e
if [ ! -f "$out/summary.txt" ]; then
  echo "demo: the demo ended without a summary; see $out/roslaunch.log and the node logs in \$ROS_LOG_DIR" >&2
  exit 1
fi
