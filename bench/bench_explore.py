#!/usr/bin/env python3
"""Exploration benchmark: sim time until the robots have explored 95 % of the reachable area of the demo world.

    scripts/env.sh python bench/bench_explore.py [--seeds 0 1 2 3 4] [--world-seed 0] [--limit 3000]
                                                  [--configs 1 3u 3c] [--markdown FILE]

Runs the fleet simulator's core (fleet_sim.sim.FleetSim, fixed sim steps) and one explorer per robot built from the
explore core exactly as the explore node uses it (same costmap translation, frontier search, goal logic, team
penalty; planning every 1/planner_frequency s of sim time and at once after a goal ends), in one process without
ROS, so the figures do not depend on the machine's load. Configurations: 1 robot; 3 robots uncoordinated (each
explores greedily on its own map, as explore_lite); 3 robots coordinated (team goals shared in the world frame
with the true transforms, i.e. a perfect map merge). Seeds vary the start poses (and laser noise) on one world.
Targets: 3 robots reach 95 % in at most 45 % of one robot's time; coordinated at most 80 % of uncoordinated.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from explore.costmap import Costmap  # noqa: E402
from explore.coverage import explored_mask, reachable_mask  # noqa: E402
from explore.frontier_search import FrontierSearch  # noqa: E402
from explore.goal_logic import ABORTED, SUCCEEDED, GoalLogic, PlanAction, apply_team_penalty  # noqa: E402
from explore.params import ExploreParams  # noqa: E402
from explore.team import TeamGoals, drop_explored_by_team  # noqa: E402
from fleet_sim.mapping import compose, relative_pose  # noqa: E402
from fleet_sim.params import FleetSimParams  # noqa: E402
from fleet_sim.sim import FleetSim  # noqa: E402

# The explore parameters of launch/demo.launch (explore.launch's values, a faster planner for the sim).
DEMO_EXPLORE = dict(planner_frequency=0.5, progress_timeout=30.0, potential_scale=3.0, gain_scale=1.0,
                    min_frontier_size=0.75, team_radius=3.0)
TARGET = 0.95
# The map merge as the bench models it: every MERGE_PERIOD s, robots whose maps share at least MIN_OVERLAP m² of
# known area are merged (map_merge refuses smaller overlaps), transitively; merged maps are placed exactly.
MERGE_PERIOD = 2.0
MIN_OVERLAP = 4.0
CONFIGS = {'1': (1, False), '3u': (3, False), '3c': (3, True)}
LABELS = {'1': '1 robot', '3u': '3 robots, uncoordinated', '3c': '3 robots, coordinated'}


class Explorer:
    """One explorer: the explore node's planning cycle over the core, the robot's map read from the simulator."""

    def __init__(self, name: str, params: ExploreParams) -> None:
        self.name = name
        self.p = params
        self.cm = Costmap(params.probability_map, params.free_threshold, params.occupied_threshold,
                          by_threshold=True)
        self.search = FrontierSearch(self.cm, params.potential_scale, params.gain_scale, params.min_frontier_size)
        self.logic = GoalLogic(params.progress_timeout)
        self.team = TeamGoals(name)
        self.goal: Optional[Tuple[float, float]] = None     # map frame
        self.chosen_at = math.inf
        self.exploring = True
        self.next_tick = 1.0 / params.planner_frequency    # the timer's first tick is one period after start
        self.replan = False
        self.goals_sent = 0


def run(n_robots: int, coordinated: bool, seed: int, world_seed: int, limit: float,
        params: ExploreParams) -> Dict[str, float]:
    sim = FleetSim(FleetSimParams(num_robots=n_robots, seed=seed, world_seed=world_seed))
    robots, world = sim.robots, sim.world
    reach = reachable_mask(world, [r.start[:2] for r in robots])
    everywhere = np.ones(world.data.shape, bool)
    to_world_cell = np.linalg.inv(world.cell_to_map())
    explorers = [Explorer(r.ns, params) for r in robots]
    period = 1.0 / params.planner_frequency
    t_target = math.nan
    share = 0.0
    next_measure = 0.0
    known: List[np.ndarray] = [np.zeros(world.data.shape, bool) for _ in robots]   # per robot, world cells
    team_known: List[Optional[np.ndarray]] = [None] * n_robots    # what merged teammates know, world cells
    merged_with: List[set] = [set() for _ in robots]
    wall0 = time.perf_counter()

    def world_goal(j: int) -> Optional[Tuple[float, float]]:
        g = explorers[j].goal
        return None if g is None else compose(robots[j].start, (g[0], g[1], 0.0))[:2]

    def known_at_for(i: int):
        mask, (x, y, yaw) = team_known[i], robots[i].start
        c, s_ = math.cos(yaw), math.sin(yaw)
        m = to_world_cell @ np.array([[c, -s_, x], [s_, c, y], [0.0, 0.0, 1.0]])

        def known_at(pts: np.ndarray) -> np.ndarray:
            cell = m @ np.vstack([pts[:, 0], pts[:, 1], np.ones(len(pts))])
            cc, rr = np.floor(cell[0]).astype(np.int64), np.floor(cell[1]).astype(np.int64)
            ok = (cc >= 0) & (cc < mask.shape[1]) & (rr >= 0) & (rr < mask.shape[0])
            out = np.zeros(len(pts), bool)
            out[ok] = mask[rr[ok], cc[ok]]
            return out
        return known_at

    def plan(i: int) -> None:
        ex, robot = explorers[i], robots[i]
        grid = robot.mapper.to_grid()
        ex.cm.update_full(grid.width, grid.height, grid.resolution, grid.origin[0], grid.origin[1], grid.data,
                          'map')
        x, y, _ = robot.pose_map
        frontiers = ex.search.search_from(x, y)
        if coordinated:
            if team_known[i] is not None:
                frontiers = drop_explored_by_team(frontiers, ex.cm.data, ex.cm.resolution,
                                                  (ex.cm.origin_x, ex.cm.origin_y), known_at_for(i))
            for j, other in enumerate(explorers):
                if j != i and j in merged_with[i]:
                    ex.team.update(other.name, world_goal(j), other.chosen_at, sim.t)
            active = ex.team.active(sim.t, world_goal(i), ex.chosen_at, params.team_radius)
            goals = [relative_pose(robot.start, (g.point[0], g.point[1], 0.0))[:2] for g in active]
            frontiers = apply_team_penalty(frontiers, goals, params.team_radius)
        result = ex.logic.plan(frontiers, ex.cm.resolution, sim.t)
        if result.action is PlanAction.STOP:
            ex.exploring, ex.goal, ex.chosen_at = False, None, math.inf
            robot.cancel()
        elif result.action is PlanAction.SEND_GOAL:
            ex.goal, ex.chosen_at = result.target, sim.t
            ex.goals_sent += 1
            outcome = sim.set_goal(i, *result.target)
            if outcome is not None:
                done(i, outcome.status)

    def done(i: int, status: str) -> None:
        ex = explorers[i]
        ex.logic.on_goal_done(SUCCEEDED if status == 'succeeded' else ABORTED, ex.goal)
        ex.replan = True   # the node replans at once after every terminal status

    def merge() -> None:
        """Components of the overlap graph; each robot's team map = the other robots of its component."""
        cell_area = world.resolution ** 2
        parent = list(range(n_robots))

        def find(a: int) -> int:
            while parent[a] != a:
                a = parent[a]
            return a
        for a in range(n_robots):
            for b in range(a + 1, n_robots):
                if np.count_nonzero(known[a] & known[b]) * cell_area >= MIN_OVERLAP:
                    parent[find(a)] = find(b)
        for i in range(n_robots):
            merged_with[i] = {j for j in range(n_robots) if j != i and find(j) == find(i)}
            team_known[i] = np.logical_or.reduce([known[j] for j in merged_with[i]]) if merged_with[i] else None

    next_merge = 0.0
    while sim.t < limit:
        _, outcomes = sim.step()
        for i, o in outcomes:
            done(i, o.status)
        measure = sim.t + 1e-9 >= next_measure
        if measure or (coordinated and sim.t + 1e-9 >= next_merge):
            known = [explored_mask(world, everywhere, [(r.mapper.to_grid(), r.start)]) for r in robots]
        if coordinated and sim.t + 1e-9 >= next_merge:
            next_merge += MERGE_PERIOD
            merge()
        for i, ex in enumerate(explorers):
            if not ex.exploring:
                continue
            if ex.replan or sim.t + 1e-9 >= ex.next_tick:
                if sim.t + 1e-9 >= ex.next_tick:
                    ex.next_tick += period
                ex.replan = False
                plan(i)
        finished = not any(ex.exploring for ex in explorers)
        if measure or finished:
            next_measure += 1.0
            if finished:
                known = [explored_mask(world, everywhere, [(r.mapper.to_grid(), r.start)]) for r in robots]
            share = float(np.count_nonzero(np.logical_or.reduce(known) & reach)) / max(int(reach.sum()), 1)
            if share >= TARGET:
                t_target = sim.t
                break
        if finished:
            break
    return {'t95': t_target, 'share': share, 'sim_t': sim.t, 'wall': time.perf_counter() - wall0,
            'goals': sum(ex.goals_sent for ex in explorers),
            'stopped': sum(not ex.exploring for ex in explorers)}


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return statistics.mean(finite) if len(finite) == len(values) and finite else math.nan


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2, 3, 4])
    ap.add_argument('--world-seed', type=int, default=0, help='floor plan of the demo world (default 0)')
    ap.add_argument('--limit', type=float, default=3000.0, help='sim seconds per run before giving up')
    ap.add_argument('--configs', nargs='+', default=list(CONFIGS), choices=list(CONFIGS))
    ap.add_argument('--markdown', help='also write the table to this file')
    args = ap.parse_args(argv)
    params = ExploreParams(**DEMO_EXPLORE)
    results: Dict[str, List[Dict[str, float]]] = {}
    for key in args.configs:
        n, coord = CONFIGS[key]
        results[key] = []
        for seed in args.seeds:
            r = run(n, coord, seed, args.world_seed, args.limit, params)
            results[key].append(r)
            print(f"{LABELS[key]:26s} seed {seed}: t95 {r['t95']:7.1f} s sim  (explored {100 * r['share']:5.1f} %, "
                  f"{r['goals']} goals, {r['wall']:.1f} s wall)", flush=True)
    lines = [f"Exploration of the demo world (floor plan seed {args.world_seed}), sim time to {TARGET:.0%} of the "
             f"reachable area, seeds {' '.join(map(str, args.seeds))}:", '',
             '| configuration | ' + ' | '.join(f'seed {s}' for s in args.seeds) + ' | mean |',
             '|---|' + '---|' * (len(args.seeds) + 1)]
    means = {}
    for key, rs in results.items():
        means[key] = _mean([r['t95'] for r in rs])
        lines.append(f'| {LABELS[key]} | ' + ' | '.join(f"{r['t95']:.0f}" for r in rs) + f' | {means[key]:.0f} |')
    lines.append('')
    if '1' in means and '3u' in means:
        ratio = min(means['3u'], means.get('3c', math.inf)) / means['1']
        lines.append(f"3 robots / 1 robot: uncoordinated {means['3u'] / means['1']:.2f}"
                     + (f", coordinated {means['3c'] / means['1']:.2f}" if '3c' in means else '')
                     + f" (target <= 0.45: {'met' if ratio <= 0.45 else 'NOT met'})")
    if '3u' in means and '3c' in means:
        ratio = means['3c'] / means['3u']
        lines.append(f"coordinated / uncoordinated: {ratio:.2f} "
                     f"(target <= 0.80: {'met' if ratio <= 0.8 else 'NOT met'})")
    text = '\n'.join(lines)
    print('\n' + text)
    if args.markdown:
        Path(args.markdown).write_text(text + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
