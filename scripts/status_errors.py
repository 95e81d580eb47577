#!/usr/bin/env python3
"""How far off the map_merge node's published placements were while a recorded run went on (a diagnostic).

    scripts/env.sh python scripts/status_errors.py RUN.bag --summary SUMMARY.json [--degrees D] [--cm C]

The bag holds the robots' maps and map_merge's ~status, as `scripts/demo.sh --record FILE.bag` writes it; the demo's
summary.json gives the robots' true start poses. Every ~status with two robots or more placed is scored as the
demo's summary scores the final placements (explore.coverage.placement_errors: relative to the first placed robot by
name, the rotation and the largest displacement of a robot map's corners, here of its final map). Prints the
statuses whose worst robot is off by more than --degrees or --cm (defaults 0.75 and 15), then the sim time covered
(from the first such status to the last), the share of it spent off, and the worst seen. The demo's summary scores
the end only: a pair of robots that joined the others a degree off can stay so for most of a run (tracking refines
each robot against the maps near it, and each of the pair holds the other).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Dict, List, Tuple

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

from explore.coverage import PlacementTimeline, placement_errors  # noqa: E402
from multirobot_map_merge.grid import GridError  # noqa: E402
from multirobot_map_merge.ros.conversions import grid_from_msg, update_from_msg  # noqa: E402
from multirobot_map_merge.ros.robot_maps import RobotMap  # noqa: E402
from multirobot_map_merge.ros.status import included_poses  # noqa: E402

Pose = Tuple[float, float, float]


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('bag')
    ap.add_argument('--summary', required=True, help="the demo's summary.json (start poses)")
    ap.add_argument('--degrees', type=float, default=0.75, help='rotation error counted as off (default 0.75)')
    ap.add_argument('--cm', type=float, default=15.0, help='corner error counted as off, cm (default 15)')
    args = ap.parse_args(argv)
    maps: Dict[str, RobotMap] = {}
    statuses: List[Tuple[float, Dict[str, Pose]]] = []
    try:
        import rosbag
        starts = {'/' + n.strip('/'): tuple(p)
                  for n, p in json.load(open(args.summary)).get('start_poses', {}).items()}
        # streamed, not listed: a 12-robot run of 650 sim s records 3.4 GB of maps
        for topic, msg, _ in rosbag.Bag(args.bag).read_messages():
            if topic.endswith('/status'):
                statuses.append((msg.header.stamp.to_sec(), {'/' + n: p for n, p in included_poses(msg).items()}))
                continue
            robot_map = maps.setdefault(topic.rsplit('/', 1)[0], RobotMap())
            try:
                robot_map.apply_update(update_from_msg(msg)) if topic.endswith('_updates') \
                    else robot_map.set_full(grid_from_msg(msg))
            except GridError:
                continue
    except Exception as e:   # a missing or broken bag (also one broken part of the way) or summary
        print(f'status_errors: cannot read {args.bag} or {args.summary}: {e}', file=sys.stderr)
        return 2
    grids = {name: m.snapshot() for name, m in maps.items()}
    timeline = PlacementTimeline(args.degrees, args.cm / 100.0)
    for t, poses in statuses:
        timeline.add(t, placement_errors({n: poses[n] for n in sorted(poses)}, starts, grids))
    if timeline.first is None:
        print('no status with two robots placed')
        return 0
    for t, worst in timeline.offs:
        print(f"t {t:7.1f}  worst {worst['robot']}: {worst['rotation_error_deg']:.2f} deg, "
              f"{100 * worst['corner_error_m']:.1f} cm")
    s = timeline.summary(statuses[-1][0])
    share = 100 * s['off_s'] / s['span_s'] if s['span_s'] else 0.0
    print(f"{s['span_s']:.1f} sim s with two robots or more placed: {s['off_s']:.1f} s ({share:.1f} %) off by more "
          f"than {args.degrees:g} deg or {args.cm:g} cm; worst {s['worst_cm']:.1f} cm ({s['worst_cm_robot']}), "
          f"{s['worst_deg']:.2f} deg ({s['worst_deg_robot']})")
    return 0


if __name__ == '__main__':
    sys.exit(main())
