#!/usr/bin/env python3
"""Replay the estimations of a live run from a rosbag, as the map_merge node makes them (a diagnostic).

    scripts/env.sh python scripts/replay_bag_estimation.py RUN.bag [--every SIM_S] [--summary SUMMARY.json] [--more N]

The bag holds the robots' maps and map updates (and map_merge's ~status), as `scripts/demo.sh --record FILE.bag`
writes it. The robots' maps are rebuilt message by message (full maps and updates, as the node stores them); every
--every sim seconds (default: at each ~status of the bag, i.e. when the node estimated) the estimation runs on the
maps of that moment, with the previous placements, the reference and the memory of the last one, as the node's. It
prints, per estimation: the time, the robots placed (tracked ones marked), the seconds taken, the robots the node
had placed then, and why each robot left out was refused. --more N estimates N more times on the final maps, as the
node goes on doing after the bag ends. With the demo's summary.json, each robot's joinable time
is printed too, so that the reason for a late join shows, and the worst placement error against the ground truth
(its start poses) of each estimation; at the end, per robot, when it was placed for good and its latency (as the
demo's summary counts it, from this replay's placements).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import Dict, List, Optional

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..'))

import numpy as np  # noqa: E402

from explore.coverage import placement_errors  # noqa: E402
from explore.merge_latency import LatencyTracker  # noqa: E402
from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.grid import GridError  # noqa: E402
from multirobot_map_merge.pipeline import MergingPipeline  # noqa: E402
from multirobot_map_merge.ros.conversions import grid_from_msg, update_from_msg  # noqa: E402
from multirobot_map_merge.ros.params import MapMergeParams  # noqa: E402
from multirobot_map_merge.ros.robot_maps import RobotMap  # noqa: E402


def robot_of(topic: str) -> str:
    return topic.rsplit('/', 1)[0]


def worst_error(transforms: Dict[str, np.ndarray], reference: Optional[str], starts: Dict[str, tuple],
                grids: Dict[str, object]) -> str:
    """'; worst robot R: D deg, C cm' against the true start poses (relative to the reference), or ''."""
    order = sorted(transforms, key=lambda n: n != reference)   # the reference first: errors are relative to it
    estimated = {n: tuple(tf.params(transforms[n])[:3]) for n in order}
    rows = placement_errors(estimated, starts, grids)
    if len(rows) < 2:
        return ''
    worst = max(rows, key=lambda r: r['corner_error_m'])
    return (f"; worst {worst['robot']}: {worst['rotation_error_deg']:.2f} deg, "
            f"{100 * worst['corner_error_m']:.1f} cm")


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('bag')
    ap.add_argument('--every', type=float, default=0.0, help='sim seconds between estimations (0: at each status)')
    ap.add_argument('--summary', help="the demo's summary.json (joinable times)")
    ap.add_argument('--more', type=int, default=0, help='estimations on the final maps after the bag ends')
    args = ap.parse_args(argv)
    try:
        import rosbag
        bag = rosbag.Bag(args.bag)
    except Exception as e:   # a missing or broken bag
        print(f'replay_bag_estimation: cannot read {args.bag}: {e}', file=sys.stderr)
        return 2
    joinable: Dict[str, float] = {}
    starts: Dict[str, tuple] = {}
    if args.summary:
        summary = json.load(open(args.summary))
        for row in summary.get('placement', []):
            joinable['/' + row['robot'].strip('/')] = row.get('joinable_sim_s')
        starts = {'/' + n.strip('/'): tuple(p) for n, p in summary.get('start_poses', {}).items()}
    maps: Dict[str, RobotMap] = {}
    order: List[str] = []   # newest first, as the node
    pipeline = MergingPipeline(MapMergeParams().estimation_settings())   # the node's defaults
    transforms: Dict[str, object] = {}
    reference: Optional[str] = None
    next_at = None
    latency = LatencyTracker([])

    def estimate_now(now: float, node_placed: Optional[List[str]]) -> None:
        nonlocal transforms, reference
        names = list(order)
        grids = [maps[n].snapshot() for n in names]
        pipeline.feed(grids)
        preferred = names.index(reference) if reference in names else None
        t0 = time.perf_counter()
        result = pipeline.estimate(preferred_reference=preferred, previous=[transforms.get(n) for n in names],
                                   names=names)
        took = time.perf_counter() - t0
        transforms = {n: t for n, t in zip(names, result.transforms) if t is not None}
        reference = names[result.reference] if result.reference is not None else None
        for n in names:
            latency.add(n)
            if joinable.get(n) is not None:
                latency.joinable(joinable[n], [n])
        latency.included(now, transforms)
        placed = sorted(transforms)
        line = (f't {now:7.1f}  placed {len(placed)}/{len(names)} (tracked {result.tracked}) in {took:.2f} s'
                + (f'; node had {len(node_placed)}' if node_placed is not None else '')
                + worst_error(transforms, reference, starts, dict(zip(names, grids))))
        print(line)
        for p in result.pairs:
            n = names[p.i]
            if n in transforms or not p.reason:
                continue
            when = joinable.get(n)
            print(f'    {n} (joinable {when if when is not None else "-"}) refused against {names[p.j]}: {p.reason}')

    now = 0.0
    for topic, msg, _ in bag.read_messages():
        if topic.endswith('/status'):
            node_placed = sorted(r.robot_namespace for r in msg.robots if r.included)
            if args.every > 0:
                continue
            now = msg.header.stamp.to_sec()
        else:
            node_placed = None
            name = robot_of(topic)
            if name not in maps:
                maps[name] = RobotMap()
                order.insert(0, name)
            try:
                if topic.endswith('_updates'):
                    maps[name].apply_update(update_from_msg(msg))
                else:
                    maps[name].set_full(grid_from_msg(msg))
            except GridError:
                continue
            now = msg.header.stamp.to_sec()
            if args.every <= 0:
                continue
            if next_at is None:
                next_at = now + args.every
            if now < next_at:
                continue
            next_at = now + args.every
        estimate_now(now, node_placed)
    for _ in range(args.more):   # the node goes on estimating on the final maps
        estimate_now(now, None)
    for row in latency.rows():
        late = row['latency_s']
        print(f"{row['robot']}: joinable {row['joinable_sim_s']}, placed {row['merged_sim_s']}, latency "
              + ('- (reference)' if row['latency_reference'] else '-' if late is None else f'{late:.1f}'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
