#!/usr/bin/env bash
# make demo: merge the package's own sample maps (three robots, unknown initial poses) and report the placement
# error against the samples' ground truth. Output in out/demo/. Run through scripts/env.sh (make demo does).
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
scenario="${1:-three_robots}"
[ -n "$scenario" ] || scenario=three_robots
src="$repo/data/samples/$scenario"
out="$repo/out/demo"
[ -f "$src/truth.json" ] || { echo "demo: no sample scenario '$scenario' in data/samples" >&2; exit 2; }
mkdir -p "$out"
python "$repo/nodes/merge_maps" --output "$out/merged" --transforms-json "$out/transforms.json" "$src"/map_*.yaml
python "$repo/scripts/placement_report.py" "$src/truth.json" "$out/transforms.json"
echo "demo: merged map in $out/merged.yaml (+ .pgm), preview $out/merged.png"
