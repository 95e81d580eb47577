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
(its start poses; relative to the first placed robot by name, as the summary measures it) of each estimation; at
the end, per robot, when it was placed for good and its latency (as the demo's summary counts it, from this
replay's placements).

--pace SPEEDUP replays the node's cadence instead (to compare its timing settings offline, without the noise of
live runs): an estimation starts with the maps of that moment, takes its replayed wall time times --contention
(the live node shares the CPU with the simulator and the explorers: a 6-robot demo's estimations take 2-3 times
their replayed time) times SPEEDUP in sim time, counts its placements when it ends, and the next one starts after
the estimation period and the node's rest (ESTIMATION_REST), or at once when a new robot's first map came; the
search budget shrinks by the contention, as the live node's wall-clock budget buys fewer searches.

--evidence (with --summary) also prints, per robot, when its true placement (the start poses) onto the union of the
other robots' maps at their true poses first passed the acceptance rules, checked at each estimation: the earliest
an estimation could have placed it. From joinable to evidence the maps lack what the rules ask for, from evidence to
placed the estimations did not find or keep it.
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
from multirobot_map_merge.compose import compose  # noqa: E402
from multirobot_map_merge.estimation.features import prepare  # noqa: E402
from multirobot_map_merge.estimation.settings import EstimationSettings  # noqa: E402
from multirobot_map_merge.estimation.verify import refusal, verify  # noqa: E402
from multirobot_map_merge.grid import Grid, GridError  # noqa: E402
from multirobot_map_merge.pipeline import MergingPipeline  # noqa: E402
from multirobot_map_merge.ros.conversions import grid_from_msg, update_from_msg  # noqa: E402
from multirobot_map_merge.ros.node import ESTIMATION_REST  # noqa: E402
from multirobot_map_merge.ros.params import MapMergeParams  # noqa: E402
from multirobot_map_merge.ros.robot_maps import RobotMap  # noqa: E402


def robot_of(topic: str) -> str:
    return topic.rsplit('/', 1)[0]


def worst_error(transforms: Dict[str, np.ndarray], starts: Dict[str, tuple], grids: Dict[str, object]) -> str:
    """'; worst robot R: D deg, C cm' against the true start poses, or ''. Relative to the first placed robot by
    name, as the demo's summary measures them, so that the two compare (one recording's final placements: 22.2 cm
    relative to the node's reference, 10.3 cm as the summary measures)."""
    order = sorted(transforms)
    estimated = {n: tuple(tf.params(transforms[n])[:3]) for n in order}
    rows = placement_errors(estimated, starts, grids)
    if len(rows) < 2:
        return ''
    worst = max(rows, key=lambda r: r['corner_error_m'])
    return (f"; worst {worst['robot']}: {worst['rotation_error_deg']:.2f} deg, "
            f"{100 * worst['corner_error_m']:.1f} cm")


def first_evidence(names: List[str], grids: List[Optional[Grid]], starts: Dict[str, tuple],
                   settings: EstimationSettings, known: Dict[str, float]) -> List[str]:
    """The robots not in `known` whose true placement onto the union of the others (true poses) passes the
    acceptance rules for a match onto a union now."""
    truth = {n: tf.rigid(*starts[n][:3]) for n, g in zip(names, grids) if n in starts and g is not None}
    grid_of = dict(zip(names, grids))
    out = []
    for n in truth:
        others = [m for m in truth if m != n]
        if n in known or not others:
            continue
        union = compose([grid_of[m] for m in others], [truth[m] for m in others], settings.min_work_resolution)
        pu = prepare(union, settings.min_work_resolution, None) if union is not None else None
        pn = prepare(grid_of[n], settings.min_work_resolution, None)
        if pu is None or pn is None:
            continue
        model = np.linalg.inv(pu.px_to_map) @ truth[n] @ pn.px_to_map
        if not refusal(verify(pn, pu, model, settings), pn, pu, settings, onto_union=True):
            out.append(n)
    return out


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('bag')
    ap.add_argument('--every', type=float, default=0.0, help='sim seconds between estimations (0: at each status)')
    ap.add_argument('--summary', help="the demo's summary.json (joinable times)")
    ap.add_argument('--more', type=int, default=0, help='estimations on the final maps after the bag ends')
    ap.add_argument('--pace', type=float, default=0.0, metavar='SPEEDUP',
                    help="estimate at the node's cadence for a run at this speed-up (0: at each status)")
    ap.add_argument('--contention', type=float, default=2.5,
                    help='with --pace: live wall time of an estimation / its replayed wall time')
    ap.add_argument('--evidence', action='store_true',
                    help='print when each true placement first passed the acceptance rules (needs --summary)')
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
    params = MapMergeParams()
    settings = params.estimation_settings()   # the node's defaults
    if args.pace > 0:
        settings = settings.replace(search_budget_s=settings.search_budget_s / args.contention)
    pipeline = MergingPipeline(settings)
    transforms: Dict[str, object] = {}
    reference: Optional[str] = None
    next_at = None
    latency = LatencyTracker([])
    evident: Dict[str, float] = {}   # robot -> first sim time its true placement passed the rules (--evidence)

    def estimate_now(now: float, node_placed: Optional[List[str]]) -> float:
        """Estimate on the maps of `now`; returns the sim time at which its result counts."""
        nonlocal transforms, reference
        names = list(order)
        grids = [maps[n].snapshot() for n in names]
        pipeline.feed(grids)
        preferred = names.index(reference) if reference in names else None
        t0 = time.perf_counter()
        result = pipeline.estimate(preferred_reference=preferred, previous=[transforms.get(n) for n in names],
                                   names=names)
        took = time.perf_counter() - t0
        if args.evidence:
            for n in first_evidence(names, grids, starts, settings, evident):
                evident[n] = now
        done = now + took * args.contention * args.pace if args.pace > 0 else now
        transforms = {n: t for n, t in zip(names, result.transforms) if t is not None}
        reference = names[result.reference] if result.reference is not None else None
        for n in names:
            latency.add(n)
            if joinable.get(n) is not None:
                latency.joinable(joinable[n], [n])
        latency.included(done, transforms)
        placed = sorted(transforms)
        line = ((f't {now:7.2f}-{done:.2f}' if args.pace > 0 else f't {now:7.1f}')
                + f'  placed {len(placed)}/{len(names)} (tracked {result.tracked}) in {took:.2f} s'
                + (f'; node had {len(node_placed)}' if node_placed is not None else '')
                + worst_error(transforms, starts, dict(zip(names, grids))))
        print(line)
        for p in result.pairs:
            n = names[p.i]
            if n in transforms or not p.reason:
                continue
            when = joinable.get(n)
            print(f'    {n} (joinable {when if when is not None else "-"}) refused against {names[p.j]}: {p.reason}')
        return done

    now = 0.0
    arrived, busy_until = False, None
    for topic, msg, _ in bag.read_messages():
        if topic.endswith('/status'):
            node_placed = sorted(r.robot_namespace for r in msg.robots if r.included)
            if args.every > 0 or args.pace > 0:
                continue
            now = msg.header.stamp.to_sec()
        else:
            node_placed = None
            name = robot_of(topic)
            if name not in maps:
                maps[name] = RobotMap()
                order.insert(0, name)
                arrived = True   # the node estimates at once when a robot's first map comes
            try:
                if topic.endswith('_updates'):
                    maps[name].apply_update(update_from_msg(msg))
                else:
                    maps[name].set_full(grid_from_msg(msg))
            except GridError:
                continue
            now = msg.header.stamp.to_sec()
            if args.pace > 0:
                if arrived and busy_until is not None:
                    next_at = min(next_at, max(busy_until, now))
                arrived = False
                if next_at is None or now >= next_at:
                    done = estimate_now(now, None)
                    took = done - now
                    busy_until = done
                    # the next one: after the period, and after a rest of ESTIMATION_REST times its duration
                    next_at = max(now + 1.0 / params.estimation_rate, done + ESTIMATION_REST * took)
                continue
            if args.every <= 0:
                continue
            if next_at is None:
                next_at = now + args.every
            if now < next_at:
                continue
            next_at = now + args.every
        estimate_now(now, node_placed)
    if args.pace > 0 and next_at is not None:   # the one due after the last map (a new one, or the period)
        now = estimate_now(max(next_at, now), None)
    for _ in range(args.more):   # the node goes on estimating on the final maps
        now = estimate_now(now, None)
    for row in latency.rows():
        late = row['latency_s']
        print(f"{row['robot']}: joinable {row['joinable_sim_s']}, placed {row['merged_sim_s']}, latency "
              + ('- (reference)' if row['latency_reference'] else '-' if late is None else f'{late:.1f}')
              + (f", evidence {evident.get(row['robot'], '-')}" if args.evidence else ''))
    return 0


if __name__ == '__main__':
    sys.exit(main())
