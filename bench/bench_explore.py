#!/usr/bin/env python3
"""Exploration benchmark: sim time until the robots have explored 95 % of the reachable area of a generated building.

    scripts/env.sh python bench/bench_explore.py [--robots 1 3 6 12] [--coordination both] [--seeds 0 1 2 3 4]
        [--world-seed 0] [--world-width 24 --world-height 16] [--limit 3000] [--json FILE] [--markdown FILE]
    scripts/env.sh python bench/bench_explore.py --configs 1 3u 3c      # the same sizes as N[u|c] tokens

Runs the fleet simulator's core (fleet_sim.sim.FleetSim, fixed sim steps) and one explorer per robot built from the
explore core exactly as the explore node uses it (same costmap translation, frontier search, goal logic, team
penalty; planning every 1/planner_frequency s of sim time and at once after a goal ends), in one process without
ROS, so the figures do not depend on the machine's load. Configurations: 1 robot; N robots uncoordinated (each
explores greedily on its own map, as explore_lite); N robots coordinated (team goals and the team's merged map
shared in the world frame with the true transforms, i.e. a perfect map merge, once two robots' maps overlap).
Seeds vary the start poses (and laser noise) on one world; the default building is the demo's (24 m x 16 m), the
larger demo uses 48 m x 32 m. Each fleet's time is printed as a ratio of one robot's time on the same seed, and of
the means.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from explore.costmap import Costmap  # noqa: E402
from explore.coverage import KnownRaster, reachable_mask  # noqa: E402
from explore.frontier_search import FrontierSearch  # noqa: E402
from explore.goal_logic import ABORTED, SUCCEEDED, GoalLogic, PlanAction, apply_team_penalty  # noqa: E402
from explore.params import ExploreParams  # noqa: E402
from explore.team import (TeamGoals, costmap_known_at, drop_explored_by_team, mask_known_at,  # noqa: E402
                          rank_with_team, team_frontiers)
from fleet_sim.mapping import compose, relative_pose  # noqa: E402
from multirobot_map_merge import transforms as tf  # noqa: E402
from multirobot_map_merge.grid import Grid  # noqa: E402
from fleet_sim.params import FleetSimParams  # noqa: E402
from fleet_sim.sim import FleetSim  # noqa: E402

# The explore parameters of launch/demo.launch (explore.launch's values, a faster planner for the sim).
DEMO_EXPLORE = dict(planner_frequency=0.5, progress_timeout=30.0, potential_scale=3.0, gain_scale=1.0,
                    min_frontier_size=0.75, team_radius=4.0, path_distance=True)
TARGET = 0.95
MILESTONES = (0.5, 0.75, 0.9)   # shares whose times are printed too: where a fleet loses its time
# The map merge as the bench models it: every MERGE_PERIOD s, robots whose maps share at least MIN_OVERLAP m² of
# known area are merged (map_merge refuses smaller overlaps), transitively; merged maps are placed exactly.
MERGE_PERIOD = 2.0
MIN_OVERLAP = 4.0
Config = Tuple[int, bool]    # (robots, coordinated)


class Explorer:
    """One explorer: the explore node's planning cycle over the core, the robot's map read from the simulator."""

    def __init__(self, name: str, params: ExploreParams) -> None:
        self.name = name
        self.p = params
        self.cm = Costmap(params.probability_map, params.free_threshold, params.occupied_threshold,
                          by_threshold=True)
        self.search = FrontierSearch(self.cm, params.potential_scale, params.gain_scale, params.min_frontier_size,
                                     params.path_distance)
        self.logic = GoalLogic(params.progress_timeout)
        self.team = TeamGoals(name)
        self.goal: Optional[Tuple[float, float]] = None     # map frame
        self.chosen_at = math.inf
        self.goal_distance = math.inf                       # remaining distance to the goal at the latest plan, m
        self.exploring = True
        self.next_tick = 1.0 / params.planner_frequency    # the timer's first tick is one period after start
        self.replan = False
        self.goals_sent = 0
        self.aborted: Dict[str, int] = {}     # move_base's reason -> count
        self.timed_out = 0                    # goals blacklisted by the progress timeout
        self.stop_reason = ''


def label(n_robots: int, coordinated: bool) -> str:
    if n_robots == 1:
        return '1 robot'
    return f"{n_robots} robots, {'coordinated' if coordinated else 'uncoordinated'}"


def run(n_robots: int, coordinated: bool, seed: int, world_seed: int, limit: float, params: ExploreParams,
        world_size: Tuple[float, float] = (24.0, 16.0)) -> Dict[str, Any]:
    sim = FleetSim(FleetSimParams(num_robots=n_robots, seed=seed, world_seed=world_seed,
                                  world_width=world_size[0], world_height=world_size[1]))
    robots, world = sim.robots, sim.world
    reach = reachable_mask(world, [r.start[:2] for r in robots])
    raster = KnownRaster.on_grid(world)
    to_world_cell = np.linalg.inv(world.cell_to_map())
    explorers = [Explorer(r.ns, params) for r in robots]
    period = 1.0 / params.planner_frequency
    t_target = math.nan
    share = 0.0
    next_measure = 0.0
    known: List[np.ndarray] = [np.zeros(world.data.shape, bool) for _ in robots]   # per robot, world cells
    team_known: List[Optional[np.ndarray]] = [None] * n_robots    # what merged teammates know, world cells
    values: List[np.ndarray] = []                                  # per robot, its map's occupancy on world cells
    team_map: List[Optional[Grid]] = [None] * n_robots            # the merged map of each robot's team, world frame
    merged_with: List[set] = [set() for _ in robots]
    wall0 = time.perf_counter()

    def world_goal(j: int) -> Optional[Tuple[float, float]]:
        g = explorers[j].goal
        return None if g is None else compose(robots[j].start, (g[0], g[1], 0.0))[:2]

    def known_at_for(i: int):
        return mask_known_at(team_known[i], to_world_cell @ tf.rigid(*robots[i].start))

    def plan(i: int) -> None:
        ex, robot = explorers[i], robots[i]
        goals: List[Tuple[float, float]] = []
        grid = robot.mapper.to_grid()
        ex.cm.update_full(grid.width, grid.height, grid.resolution, grid.origin[0], grid.origin[1], grid.data,
                          'map')
        x, y, _ = robot.pose_map
        frontiers = ex.search.search_from(x, y)
        if coordinated:
            if team_known[i] is not None:
                frontiers = drop_explored_by_team(frontiers, ex.cm.data, ex.cm.resolution,
                                                  (ex.cm.origin_x, ex.cm.origin_y), known_at_for(i))
            extra = []
            if team_map[i] is not None:
                extra = team_frontiers(team_map[i], ex.cm.table, robot.pose[:2], tf.inverse(tf.rigid(*robot.start)),
                                       params.potential_scale, params.gain_scale, params.min_frontier_size,
                                       params.path_distance,
                                       costmap_known_at(ex.cm.data, ex.cm.resolution, (ex.cm.origin_x, ex.cm.origin_y)))
            for j, other in enumerate(explorers):
                if j != i and j in merged_with[i]:
                    ex.team.update(other.name, world_goal(j), other.chosen_at, sim.t, other.goal_distance)
            active = ex.team.active(sim.t, world_goal(i), ex.chosen_at, params.team_radius, ex.goal_distance)
            goals = [relative_pose(robot.start, (g.point[0], g.point[1], 0.0))[:2] for g in active]
            remaining = [g.distance for g in active]
            heading = ex.goal if ex.goal is not None else (x, y)
            frontiers = apply_team_penalty(rank_with_team(frontiers, extra), goals, params.team_radius, heading,
                                           remaining)
        result = ex.logic.plan(frontiers, ex.cm.resolution, sim.t, team_busy=coordinated and bool(goals))
        ex.timed_out += len(result.blacklisted)
        ex.goal_distance = result.frontier.min_distance if result.frontier is not None else math.inf
        if result.action is PlanAction.WAIT:
            ex.goal, ex.chosen_at = None, math.inf
            robot.cancel()
        elif result.action is PlanAction.STOP:
            ex.exploring, ex.goal, ex.chosen_at = False, None, math.inf
            ex.stop_reason = result.reason
            robot.cancel()
        elif result.action is PlanAction.SEND_GOAL:
            ex.goal, ex.chosen_at = result.target, sim.t
            ex.goals_sent += 1
            outcome = sim.set_goal(i, *result.target)
            if outcome is not None:
                done(i, outcome.status, outcome.text)

    def done(i: int, status: str, text: str) -> None:
        ex = explorers[i]
        if status != 'succeeded':
            ex.aborted[text] = ex.aborted.get(text, 0) + 1
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
            if merged_with[i]:
                team = [values[j] for j in sorted(merged_with[i] | {i})]
                occupied = np.logical_or.reduce([v >= 50 for v in team])
                free = np.logical_or.reduce([(v >= 0) & (v < 50) for v in team])
                merged = np.where(occupied, 100, np.where(free, 0, -1)).astype(np.int8)
                team_map[i] = Grid(merged, world.resolution, world.origin, 'world')
            else:
                team_map[i] = None

    reached_at: Dict[float, float] = {}
    next_merge = 0.0
    while sim.t < limit:
        _, outcomes = sim.step()
        for i, o in outcomes:
            done(i, o.status, o.text)
        measure = sim.t + 1e-9 >= next_measure
        if measure or (coordinated and sim.t + 1e-9 >= next_merge):
            values = [raster.values(r.mapper.to_grid(), r.start) for r in robots]
            known = [v >= 0 for v in values]
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
                known = [raster.known(r.mapper.to_grid(), r.start) for r in robots]
            share = float(np.count_nonzero(np.logical_or.reduce(known) & reach)) / max(int(reach.sum()), 1)
            for level in MILESTONES:
                if share >= level:
                    reached_at.setdefault(level, sim.t)
            if share >= TARGET:
                t_target = sim.t
                break
        if finished:
            break
    aborted: Dict[str, int] = {}
    for ex in explorers:
        for text, k in ex.aborted.items():
            aborted[text] = aborted.get(text, 0) + k
    return {'t95': t_target, 'share': share, 'sim_t': sim.t, 'wall': time.perf_counter() - wall0,
            'goals': sum(ex.goals_sent for ex in explorers), 'aborted': aborted,
            'timed_out': sum(ex.timed_out for ex in explorers),
            'stopped': sum(not ex.exploring for ex in explorers),
            'stop_reasons': sorted({ex.stop_reason for ex in explorers if ex.stop_reason}),
            'milestones': ' '.join(f'{100 * k:.0f}%@{v:.0f}' for k, v in sorted(reached_at.items()))}


def _mean(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return statistics.mean(finite) if len(finite) == len(values) and finite else math.nan


def parse_configs(robots: Sequence[int], coordination: str, tokens: Sequence[str]) -> List[Config]:
    """The fleets to run: ``tokens`` N[u|c] (e.g. 1 3u 3c) if given, else every size of ``robots`` with
    ``coordination`` (coordinated, uncoordinated or both); one robot is one configuration."""
    configs: List[Config] = []
    if tokens:
        for tok in tokens:
            n = int(tok.rstrip('uc'))
            configs.append((n, n > 1 and not tok.endswith('u')))
    else:
        modes = {'coordinated': [True], 'uncoordinated': [False], 'both': [False, True]}[coordination]
        for n in robots:
            configs.extend([(1, False)] if n == 1 else [(n, c) for c in modes])
    out: List[Config] = []
    for c in configs:
        if c not in out:
            out.append(c)
    return out


def _fmt(t: float) -> str:
    return f'{t:.0f}' if math.isfinite(t) else 'never'


def _ratio(t: float, t1: float) -> str:
    return f'{t / t1:.2f}' if math.isfinite(t) and math.isfinite(t1) and t1 > 0 else '-'


def table(results: Dict[Config, List[Dict[str, Any]]], seeds: Sequence[int], title: str) -> str:
    """Markdown: time to the target per seed and mean, then each fleet's ratio to one robot per seed and mean."""
    one = results.get((1, False))
    lines = [title, '', '| configuration | ' + ' | '.join(f'seed {s}' for s in seeds) + ' | mean |',
             '|---|' + '---|' * (len(seeds) + 1)]
    means = {}
    for cfg, rs in results.items():
        means[cfg] = _mean([r['t95'] for r in rs])
        lines.append(f'| {label(*cfg)} | ' + ' | '.join(_fmt(r['t95']) for r in rs) + f' | {_fmt(means[cfg])} |')
    if one is not None and len(results) > 1:
        lines += ['', 'Ratio to one robot (same seed; mean: ratio of the means), and the slowest seed against the '
                  "fleet's mean:", '',
                  '| configuration | ' + ' | '.join(f'seed {s}' for s in seeds) + ' | mean | max / mean |',
                  '|---|' + '---|' * (len(seeds) + 2)]
        for cfg, rs in results.items():
            if cfg == (1, False):
                continue
            ts = [r['t95'] for r in rs]
            spread = f'{max(ts) / means[cfg]:.2f}' if math.isfinite(means[cfg]) else '-'
            lines.append(f'| {label(*cfg)} | ' + ' | '.join(_ratio(t, r1['t95']) for t, r1 in zip(ts, one))
                         + f' | {_ratio(means[cfg], means[(1, False)])} | {spread} |')
    return '\n'.join(lines)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, nargs='+', default=[1, 3], help='fleet sizes (default 1 3)')
    ap.add_argument('--coordination', choices=['coordinated', 'uncoordinated', 'both'], default='both',
                    help='for fleets of more than one robot (default both)')
    ap.add_argument('--configs', nargs='+', default=[], help='fleets as N[u|c] tokens (e.g. 1 3u 3c 6c); '
                    'replaces --robots/--coordination')
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2, 3, 4])
    ap.add_argument('--world-seed', type=int, default=0, help='floor plan of the generated building (default 0)')
    ap.add_argument('--world-width', type=float, default=24.0, help='building width, m (default 24, the demo)')
    ap.add_argument('--world-height', type=float, default=16.0, help='building height, m (default 16)')
    ap.add_argument('--limit', type=float, default=3000.0, help='sim seconds per run before giving up')
    ap.add_argument('--set', nargs='+', default=[], metavar='NAME=VALUE',
                    help="override explore parameters of the demo's set, e.g. path_distance=false")
    ap.add_argument('--json', help='write every run to this file: a list of {robots, coordinated, seed, '
                    'world_width, world_height, t95_s (null: not reached)}')
    ap.add_argument('--markdown', help='also write the tables to this file')
    args = ap.parse_args(argv)
    for tok in args.configs:
        if not tok.rstrip('uc').isdigit() or int(tok.rstrip('uc')) < 1 or tok.count('u') + tok.count('c') > 1:
            ap.error(f'--configs: {tok!r} is not N, Nu or Nc')
    if min(args.robots) < 1:
        ap.error('--robots: fleet sizes must be at least 1')
    configs = parse_configs(args.robots, args.coordination, args.configs)
    explore = dict(DEMO_EXPLORE)
    for item in args.set:
        name, _, value = item.partition('=')
        if name not in ExploreParams.__dataclass_fields__ or not value:
            ap.error(f'--set: {item!r} is not NAME=VALUE of an explore parameter')
        explore[name] = yaml.safe_load(value)
    try:
        params = ExploreParams.from_mapping(explore)
    except ValueError as e:
        ap.error(str(e))
    size = (args.world_width, args.world_height)
    print(f'explore params: {explore}; building {size[0]:g} m x {size[1]:g} m, floor plan seed '
          f'{args.world_seed}; seeds {args.seeds}', flush=True)
    results: Dict[Config, List[Dict[str, Any]]] = {}
    runs: List[Dict[str, Any]] = []
    for n, coord in configs:
        results[(n, coord)] = []
        for seed in args.seeds:
            r = run(n, coord, seed, args.world_seed, args.limit, params, size)
            results[(n, coord)].append(r)
            runs.append({'robots': n, 'coordinated': coord, 'seed': seed, 'world_width': size[0],
                         'world_height': size[1], 't95_s': r['t95'] if math.isfinite(r['t95']) else None})
            aborted = ', '.join(f'{k} x{v}' for k, v in sorted(r['aborted'].items(), key=lambda kv: -kv[1]))
            print(f"{label(n, coord):26s} seed {seed}: t95 {r['t95']:7.1f} s sim  (explored {100 * r['share']:5.1f} "
                  f"% at {r['sim_t']:.0f} s, {r['goals']} goals, {r['timed_out']} timed out, aborted: "
                  f"{aborted or 'none'}; stopped {r['stopped']} {r['stop_reasons']}; {r['milestones']}; "
                  f"{r['wall']:.1f} s wall)",
                  flush=True)
            if args.json:   # after every run, so a long grid keeps what it has measured
                Path(args.json).write_text(json.dumps(runs, indent=1) + '\n')
    title = (f"Exploration of a {size[0]:g} m x {size[1]:g} m building (floor plan seed {args.world_seed}), sim time "
             f"(s) to {TARGET:.0%} of the reachable area, limit {args.limit:g} s:")
    text = table(results, args.seeds, title)
    print('\n' + text)
    if args.markdown:
        Path(args.markdown).write_text(text + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
