"""Fleet coordination of explorers (an extension; explore_lite has none): teammates' goals and the team's map.

Each explorer publishes its current goal in a shared frame (``team_frame``) and keeps the latest goal of every
teammate here. Planning demotes frontiers near those goals (``goal_logic.apply_team_penalty``) and, with a merged
map of the team, skips frontiers whose far side a teammate has already mapped (``drop_explored_by_team``).

Who yields: when two robots head for the same area, the robot nearer to it (its remaining distance to its goal, which
each explorer publishes with the goal) keeps it; when a distance is unknown, the robot that chose its goal first. A
teammate's goal within ``radius`` of this robot's own current goal is ignored if this robot wins (ties: the larger
name yields), so exactly one of the two moves on instead of both switching back and forth. By distance rather than
by time because a robot far away that happens to choose a frontier first would otherwise keep a teammate standing
next to it away.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from multirobot_map_merge.grid import Grid

from .costmap import FREE_SPACE, NO_INFORMATION, translate
from .frontier_search import Frontier, search_frontiers

Point2 = Tuple[float, float]

# A teammate goal not refreshed for this long (ROS time, s) is dropped: its robot has died or lost the topic.
# Explorers re-publish their goal at every planning cycle.
STALE_AFTER = 60.0


@dataclass(frozen=True)
class TeamGoal:
    sender: str        # node name of the publishing explorer
    point: Point2      # goal in the team frame
    chosen_at: float   # ROS time the goal was chosen (the message stamp), s
    received_at: float  # ROS time of the latest message, s
    distance: float = math.inf   # the sender's remaining distance to its goal, m (inf: unknown)


class TeamGoals:
    """Latest goal per teammate; thread-safe (subscriber threads write, the planning thread reads)."""

    def __init__(self, own_name: str, stale_after: float = STALE_AFTER) -> None:
        self.own_name = own_name
        self.stale_after = stale_after
        self._lock = threading.Lock()
        self._goals: Dict[str, TeamGoal] = {}

    def update(self, sender: str, point: Optional[Point2], chosen_at: float, received_at: float,
               distance: float = math.inf) -> bool:
        """Store a teammate's goal (``point`` None: the teammate has no goal any more) and its remaining distance to
        it (inf: unknown). Own messages and non-finite points are ignored; returns True if stored."""
        if sender == self.own_name:
            return False
        with self._lock:
            if point is None:
                self._goals.pop(sender, None)
                return True
            if not (math.isfinite(point[0]) and math.isfinite(point[1]) and math.isfinite(chosen_at)):
                return False
            d = float(distance) if distance >= 0.0 else math.inf   # NaN and negative: unknown
            self._goals[sender] = TeamGoal(sender, (float(point[0]), float(point[1])), chosen_at, received_at, d)
            return True

    def active(self, now: float, own_goal: Optional[Point2] = None, own_chosen_at: float = math.inf,
               radius: float = 0.0, own_distance: float = math.inf) -> List[TeamGoal]:
        """Teammates' goals that count now: not stale, and not yielding to this robot's own goal (see module doc).

        ``own_goal`` is in the team frame (None if this robot has no goal or it cannot be expressed there);
        ``own_distance`` is this robot's remaining distance to it (inf: unknown).
        """
        with self._lock:
            for k in [k for k, g in self._goals.items() if now - g.received_at > self.stale_after]:
                del self._goals[k]
            goals = sorted(self._goals.values(), key=lambda g: g.sender)
        if own_goal is None:
            return goals

        def yields(g: TeamGoal) -> bool:
            return (claim_key(g.distance, g.chosen_at, g.sender, own_distance)
                    > claim_key(own_distance, own_chosen_at, self.own_name, g.distance))
        return [g for g in goals if not (_near(g.point, own_goal, radius) and yields(g))]

    def senders(self) -> List[str]:
        with self._lock:
            return sorted(self._goals)


def claim_key(distance: float, chosen_at: float, name: str, other_distance: float) -> Tuple[float, float, str]:
    """Order of two claims on one area (the smaller keeps it): the remaining distance when both robots published
    one, else the time the goal was chosen; the name breaks ties. Both robots compute the same order."""
    by_distance = math.isfinite(distance) and math.isfinite(other_distance)
    return (distance if by_distance else 0.0, chosen_at, name)


def _near(a: Point2, b: Point2, radius: float) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) < radius


# --- what the team has mapped ---------------------------------------------------------------------------------------
# A frontier is skipped when most of the unknown space just beyond it is known in the team's merged map, i.e. a
# teammate has already seen it. The samples lie BEYOND_CELLS cells outward from each frontier cell (away from its
# free neighbour), so a merged map that places this robot's own map a cell off cannot make them look known.
BEYOND_CELLS = 3
KNOWN_BY_TEAM = 0.5

KnownAt = Callable[[np.ndarray], np.ndarray]   # (N, 2) points in the robot's map frame -> (N,) bool known


def beyond_points(points: np.ndarray, data: np.ndarray, resolution: float, origin: Point2) -> np.ndarray:
    """For frontier cell centres ``points`` (world coordinates of the costmap ``data``), the points BEYOND_CELLS
    cells outward (away from the first free 4-neighbour), kept only where the costmap itself is unknown there."""
    if len(points) == 0:
        return np.zeros((0, 2))
    h, w = data.shape
    c = np.floor((points[:, 0] - origin[0]) / resolution).astype(np.int64)
    r = np.floor((points[:, 1] - origin[1]) / resolution).astype(np.int64)
    step = np.zeros((len(points), 2), np.int64)
    found = np.zeros(len(points), bool)
    for dc, dr in ((-1, 0), (1, 0), (0, -1), (0, 1)):   # the original's nhood4 order
        nc, nr = c + dc, r + dr
        ok = ~found & (nc >= 0) & (nc < w) & (nr >= 0) & (nr < h)
        free = np.zeros(len(points), bool)
        free[ok] = data[nr[ok], nc[ok]] == FREE_SPACE
        step[free] = (-dc, -dr)
        found |= free
    bc, br = c + BEYOND_CELLS * step[:, 0], r + BEYOND_CELLS * step[:, 1]
    inside = found & (bc >= 0) & (bc < w) & (br >= 0) & (br < h)
    keep = np.zeros(len(points), bool)
    keep[inside] = data[br[inside], bc[inside]] == NO_INFORMATION
    keep |= found & ~inside          # beyond the edge of the own map: unknown to this robot
    return np.column_stack([origin[0] + (bc[keep] + 0.5) * resolution, origin[1] + (br[keep] + 0.5) * resolution])


def known_by_team(frontier: Frontier, data: np.ndarray, resolution: float, origin: Point2,
                  known_at: KnownAt) -> float:
    """Fraction (0..1) of the samples beyond ``frontier`` that the team map knows (0 without samples)."""
    pts = beyond_points(frontier.points, data, resolution, origin)
    if len(pts) == 0:
        return 0.0
    return float(np.count_nonzero(known_at(pts))) / len(pts)


def drop_explored_by_team(frontiers: Sequence[Frontier], data: np.ndarray, resolution: float, origin: Point2,
                          known_at: KnownAt, max_known: float = KNOWN_BY_TEAM) -> List[Frontier]:
    """The frontiers (order kept) whose space beyond is not already mapped by the team."""
    return [f for f in frontiers if known_by_team(f, data, resolution, origin, known_at) < max_known]


def mask_known_at(known: np.ndarray, to_cell: np.ndarray) -> KnownAt:
    """known_at() for a boolean cell mask and the 3x3 transform from the robot's map frame to its cells (corner
    convention); points off the mask are unknown."""
    def known_at(pts: np.ndarray) -> np.ndarray:
        cell = to_cell @ np.vstack([pts[:, 0], pts[:, 1], np.ones(len(pts))])
        c, r = np.floor(cell[0]).astype(np.int64), np.floor(cell[1]).astype(np.int64)
        ok = (c >= 0) & (c < known.shape[1]) & (r >= 0) & (r < known.shape[0])
        out = np.zeros(len(pts), bool)
        out[ok] = known[r[ok], c[ok]]
        return out
    return known_at


def grid_known_at(grid: Grid, team_from_map: np.ndarray) -> KnownAt:
    """known_at() for a team map ``grid`` and the 3x3 transform from the robot's map frame into the grid's frame."""
    return mask_known_at(grid.data >= 0, np.linalg.inv(grid.cell_to_map()) @ team_from_map)


# --- the team map's frontiers -----------------------------------------------------------------------------------------
# A robot sees in its own map only the frontiers of the space it has mapped itself. Choosing among those alone, a
# robot keeps finishing small leftovers near it while a large unexplored part of the building, which only the team
# map shows, is left to the one teammate that happens to be there. So the team map's frontiers are ranked together
# with the robot's own (rank_with_team); the team penalty then leaves to a teammate what it reaches first. A team
# frontier that the robot's own map already knows beyond (the merged map lags behind, or places a map wrongly) is
# not trusted: its own map is what it saw.


def team_frontiers(grid: Grid, table: np.ndarray, robot_in_team: Point2, own_from_team: np.ndarray,
                   potential_scale: float, gain_scale: float, min_frontier_size: float, path_distance: bool,
                   own_known_at: Optional[KnownAt] = None) -> List[Frontier]:
    """Frontiers of the team map ``grid`` (occupancy, cost bytes through ``table``) searched from the robot's
    position there, in cost order, expressed in the robot's map frame (``own_from_team``: 3x3); those whose far
    side ``own_known_at`` (points of the robot's map frame) mostly knows are left out."""
    if grid.is_empty() or grid.resolution <= 0.0:
        return []
    res = grid.resolution
    to_cell = np.linalg.inv(grid.cell_to_map())
    c, r, _ = to_cell @ np.array([robot_in_team[0], robot_in_team[1], 1.0])
    if not (0 <= c < grid.width and 0 <= r < grid.height):
        return []
    data = translate(grid.data, table).reshape(grid.data.shape)
    # searched in the grid's own axes (origin at its corner cell), then moved into the robot's map frame
    found = search_frontiers(data, res, (0.0, 0.0), (int(c), int(r)), potential_scale, gain_scale,
                             min_frontier_size, path_distance)
    m = own_from_team @ grid.cell_to_map() @ np.diag([1.0 / res, 1.0 / res, 1.0])

    def move(p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, float).reshape(-1, 2)
        return p @ m[:2, :2].T + m[:2, 2]
    out = []
    for f in found:
        points = move(f.points)
        if own_known_at is not None and len(points) and own_known_at(points).mean() >= KNOWN_BY_TEAM:
            continue
        initial = move(f.initial)
        # the true centroid: the original's (the cells' sum over one more cell than it sums) is pulled towards the
        # grid's corner, metres off for a small frontier far from it, often into a wall
        centroid = np.vstack([points, initial]).mean(axis=0)
        out.append(replace(f, points=points, centroid=(float(centroid[0]), float(centroid[1])),
                           initial=(float(initial[0, 0]), float(initial[0, 1])), middle=tuple(move(f.middle)[0])))
    return out


def rank_with_team(own: Sequence[Frontier], team: Sequence[Frontier]) -> List[Frontier]:
    """The robot's own frontiers and the team map's (``team_frontiers``, same frame) in one cost order; stable, so
    on equal costs its own come first, and NaN costs last."""
    return sorted([*own, *team], key=lambda f: (math.isnan(f.cost), f.cost))


def costmap_known_at(data: np.ndarray, resolution: float, origin: Point2) -> KnownAt:
    """known_at() of a cost grid (the robot's own map): points on a cell other than NO_INFORMATION."""
    to_cell = np.array([[1.0 / resolution, 0.0, -origin[0] / resolution],
                        [0.0, 1.0 / resolution, -origin[1] / resolution], [0.0, 0.0, 1.0]])
    return mask_known_at(data != NO_INFORMATION, to_cell)
