"""Global planner on a robot's own occupancy map, as navfn with allow_unknown would plan on a SLAM map.

Dijkstra on an 8-connected grid of about ``plan_resolution`` cells, computed as a vectorised wavefront: every
iteration relaxes all cells at once with two OpenCV min-filters (4-neighbours, diagonals), so no Python loop runs over
cells; the number of iterations is the number of steps of the longest path needed (a goal in a closed pocket
converges after a few). The path is then read by steepest descent from the start.

Costs: cells within robot_radius + margin of an occupied cell are lethal; a band beyond that costs more (so paths keep
to the middle of corridors, as with costmap inflation); unknown cells are traversable but cost more than known free
ones (navfn also prefers known free space with allow_unknown).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import cv2
import numpy as np

_log = logging.getLogger('rosout.fleet_sim.planner')

_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)
_DIAG = np.array([[1, 0, 1], [0, 1, 0], [1, 0, 1]], np.uint8)
_SQRT2 = math.sqrt(2.0)
MAX_PLAN_CELLS = 1_000_000      # coarse cells (100 m x 100 m at 0.1 m): refuse goals absurdly far away


@dataclass(frozen=True)
class PlannerConfig:
    robot_radius: float = 0.2
    margin: float = 0.05           # lethal distance = robot_radius + margin
    band: float = 0.3              # width of the extra-cost band beyond the lethal distance
    band_cost: float = 4.0         # extra cost per step at the lethal edge (falls linearly to 0 over band)
    unknown_cost: float = 1.0      # extra cost per step on unknown cells
    plan_resolution: float = 0.1   # target size of planning cells
    goal_tolerance: float = 0.25   # a lethal goal cell is replaced by reachable cells within this distance
    pad: float = 1.0               # the planning area reaches this far past the map, start and goal
    window_margin: float = 3.0     # first try: plan within this margin around start and goal

    @property
    def lethal(self) -> float:
        return self.robot_radius + self.margin


@dataclass
class PlanResult:
    path: Optional[np.ndarray]     # (N, 2) map-frame points from the start to the goal (or a cell near it)
    reason: str = ''               # why there is no path
    iterations: int = 0


class PlanningGrid:
    """The coarse cost grid of one map snapshot: reusable for several plans on the same map."""

    def __init__(self, values: np.ndarray, resolution: float, origin: Sequence[float], cfg: PlannerConfig,
                 include: Sequence[Tuple[float, float]] = ()) -> None:
        """values: int8 map (row 0 = lowest y), -1 unknown, >= 50 occupied; origin (x, y) of cell (0, 0)'s corner
        (map yaw must be 0); include: points the planning area must contain (start, goal)."""
        self.cfg = cfg
        res = float(resolution)
        f = max(1, int(round(cfg.plan_resolution / res)))
        self.res = res * f
        h, w = values.shape
        ox, oy = float(origin[0]), float(origin[1])
        # fine-cell bounds of the area: the map plus the points, padded; snapped to the coarse lattice of the map
        pad = int(math.ceil(cfg.pad / res))
        c_lo, r_lo, c_hi, r_hi = 0, 0, w, h
        for x, y in include:
            c, r = math.floor((x - ox) / res), math.floor((y - oy) / res)
            c_lo, r_lo = min(c_lo, c - pad), min(r_lo, r - pad)
            c_hi, r_hi = max(c_hi, c + pad + 1), max(r_hi, r + pad + 1)
        c_lo, r_lo = f * math.floor(c_lo / f), f * math.floor(r_lo / f)
        c_hi, r_hi = f * math.ceil(c_hi / f), f * math.ceil(r_hi / f)
        W, H = c_hi - c_lo, r_hi - r_lo
        if (W // f) * (H // f) > MAX_PLAN_CELLS:
            raise ValueError(f"planning area of {W * res:.0f} m x {H * res:.0f} m is too large")
        fine = np.full((H, W), -1, np.int8)
        fine[-r_lo:-r_lo + h, -c_lo:-c_lo + w] = values
        self.origin = (ox + c_lo * res, oy + r_lo * res)
        self._fine, self._fine_res = fine, res
        occ = fine >= 50
        if occ.any():
            dist = cv2.distanceTransform((~occ).astype(np.uint8), cv2.DIST_L2, 5) * res
        else:
            dist = np.full(occ.shape, np.inf, np.float32)
        hc, wc = H // f, W // f
        # a coarse cell is as close to a wall as its closest fine cell (conservative by < half a coarse cell)
        self.dist = dist.reshape(hc, f, wc, f).min(axis=(1, 3))
        unknown = (fine < 0).reshape(hc, f, wc, f).mean(axis=(1, 3)) > 0.5
        self.lethal = self.dist < cfg.lethal
        excess = np.clip(1.0 - (self.dist - cfg.lethal) / cfg.band, 0.0, 1.0) if cfg.band > 0 else 0.0
        self.cost = (1.0 + cfg.band_cost * excess + cfg.unknown_cost * unknown).astype(np.float32)

    # ------------------------------------------------------------------ coordinates
    def cell(self, x: float, y: float) -> Tuple[int, int]:
        """(col, row) of the coarse cell holding map point (x, y)."""
        return (math.floor((x - self.origin[0]) / self.res), math.floor((y - self.origin[1]) / self.res))

    def centre(self, c: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Map-frame centres (N, 2) of coarse cells (cols c, rows r)."""
        return np.c_[self.origin[0] + (np.asarray(c) + 0.5) * self.res,
                     self.origin[1] + (np.asarray(r) + 0.5) * self.res]

    def occupied_at(self, x: float, y: float) -> bool:
        c = math.floor((x - self.origin[0]) / self._fine_res)
        r = math.floor((y - self.origin[1]) / self._fine_res)
        return bool(self._fine[r, c] >= 50)

    # ------------------------------------------------------------------ planning
    def plan(self, start: Sequence[float], goal: Sequence[float]) -> PlanResult:
        result = self._plan(start, goal, self.lethal)
        if result.path is None and result.reason == 'no path to the goal':
            # A robot standing in a doorway that its own (rotated, noisy) map draws a little narrower than it is
            # finds every way out closed by the margin, although it drove in: it would refuse every goal for
            # ever. Try once more with the robot's radius alone, as move_base's recovery clears the inflation.
            tight = self.dist < self.cfg.robot_radius
            if not np.array_equal(tight, self.lethal):
                retry = self._plan(start, goal, tight)
                retry.iterations += result.iterations
                if retry.path is not None:
                    return retry
        return result

    def _plan(self, start: Sequence[float], goal: Sequence[float], lethal_cells: np.ndarray) -> PlanResult:
        cfg = self.cfg
        hc, wc = lethal_cells.shape
        sc, sr = self.cell(start[0], start[1])
        gc, gr = self.cell(goal[0], goal[1])
        if not (0 <= sc < wc and 0 <= sr < hc and 0 <= gc < wc and 0 <= gr < hc):
            return PlanResult(None, 'start or goal outside the planning area')   # cannot happen: area includes them
        if self.occupied_at(goal[0], goal[1]):
            return PlanResult(None, 'the goal is in an obstacle of the map')
        lethal = lethal_cells.copy()
        cost = self.cost
        if lethal[sr, sc]:
            # the robot stands closer to a wall than the planner allows (it is still clear of it): let it leave
            # through cells no closer to walls than it is now, at a high cost
            yy, xx = np.ogrid[:hc, :wc]
            near = (xx - sc) ** 2 + (yy - sr) ** 2 <= (cfg.lethal / self.res + 1.0) ** 2
            escape = near & lethal & (self.dist >= self.dist[sr, sc] - 1e-6)
            lethal[escape] = False
            cost = cost.copy()
            cost[escape] += 10.0
            lethal[sr, sc] = False
        # goal cells: the goal's own cell, or the free cells within goal_tolerance when it is too close to a wall
        seeds = np.zeros_like(lethal)
        exact = not lethal[gr, gc]
        if exact:
            seeds[gr, gc] = True
        else:
            yy, xx = np.ogrid[:hc, :wc]
            cx, cy = self.origin[0] + (xx + 0.5) * self.res, self.origin[1] + (yy + 0.5) * self.res
            seeds = ((cx - goal[0]) ** 2 + (cy - goal[1]) ** 2 <= cfg.goal_tolerance ** 2) & ~lethal
            if not seeds.any():
                return PlanResult(None, 'the goal is too close to obstacles (no free cell within goal_tolerance)')
        # first in a window around start and goal (most goals are near: cheaper iterations), then everywhere
        rows, cols = np.nonzero(seeds)
        m = int(math.ceil(cfg.window_margin / self.res))
        c0, r0 = max(0, min(sc, int(cols.min())) - m), max(0, min(sr, int(rows.min())) - m)
        c1, r1 = min(wc, max(sc, int(cols.max())) + m + 1), min(hc, max(sr, int(rows.max())) + m + 1)
        iterations = 0
        for c0, r0, c1, r1 in ((c0, r0, c1, r1), (0, 0, wc, hc)):
            win = (slice(r0, r1), slice(c0, c1))
            D, n = _wavefront(seeds[win], lethal[win], cost[win], (sc - c0, sr - r0))
            iterations += n
            if np.isfinite(D[sr - r0, sc - c0]) or (c0, r0, c1, r1) == (0, 0, wc, hc):
                break
        if not np.isfinite(D[sr - r0, sc - c0]):
            return PlanResult(None, 'no path to the goal', iterations)
        cells = _descend(D, cost[win], sc - c0, sr - r0) + np.array([c0, r0])
        pts = self.centre(cells[:, 0], cells[:, 1])
        pts[0] = (start[0], start[1])
        if exact:
            pts = np.vstack([pts, [[goal[0], goal[1]]]]) if len(pts) > 1 else np.array([start[:2], goal[:2]], float)
        return PlanResult(pts, '', iterations)


def _wavefront(seeds: np.ndarray, lethal: np.ndarray, cost: np.ndarray, start: Tuple[int, int],
               check_every: int = 8) -> Tuple[np.ndarray, int]:
    """Cost-to-goal of every cell (inf: unreachable), by synchronous Bellman-Ford relaxation (iteration i settles
    every cell whose best path has at most i steps) until convergence, or until the start has settled (or nearly:
    an optimal path has at most sqrt(2) times the steps of the shortest-in-steps one, which the first finite value
    at the start reveals)."""
    D = np.full(seeds.shape, np.inf, np.float32)
    D[seeds] = 0.0
    cost = cost.astype(np.float32)
    cost_d = (cost * _SQRT2).astype(np.float32)
    wall = np.where(lethal, np.inf, 0.0).astype(np.float32)   # max() with it keeps lethal cells at inf
    m4, md = np.empty_like(D), np.empty_like(D)
    sc, sr = start
    reached_at = None
    it = 0
    limit = seeds.size + 10
    while it < limit:
        it += 1
        # all in place: one iteration is a handful of passes over the grid in C
        cv2.erode(D, _CROSS, dst=m4, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)
        cv2.erode(D, _DIAG, dst=md, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)
        m4 += cost
        md += cost_d
        np.minimum(m4, md, out=m4)
        np.minimum(m4, D, out=m4)
        np.maximum(m4, wall, out=m4)
        if reached_at is None and m4[sr, sc] < np.inf:
            reached_at = it
        # every step costs >= 1, so a path cheaper than D[start] has fewer steps than that: after that many
        # iterations D[start] is final
        if reached_at is not None and (it >= 1.5 * reached_at + 4 or it >= m4[sr, sc]):
            D = m4
            break
        if it % check_every == 0 and np.array_equal(m4, D):
            D = m4
            break
        D, m4 = m4, D
    return D, it


_NEIGHBOURS = [(dc, dr, math.hypot(dc, dr)) for dc in (-1, 0, 1) for dr in (-1, 0, 1) if dc or dr]


def _descend(D: np.ndarray, cost: np.ndarray, c: int, r: int) -> np.ndarray:
    """Cells from (c, r) down the cost-to-goal field to a goal cell (D == 0). Each step goes to the neighbour n
    minimising D[n] + step * cost[here] among those with a lower D (relaxation guarantees one), so it ends."""
    h, w = D.shape
    out = [(c, r)]
    d = float(D[r, c])
    for _ in range(D.size):
        if d <= 0.0:
            break
        k = float(cost[r, c])
        best, bc, br = math.inf, -1, -1
        for dc, dr, step in _NEIGHBOURS:
            nc, nr = c + dc, r + dr
            if 0 <= nc < w and 0 <= nr < h:
                dn = float(D[nr, nc])
                v = dn + step * k
                if dn < d and v < best:
                    best, bc, br = v, nc, nr
        if bc < 0:
            break   # not converged here (cannot happen after relaxation); keep what we have
        c, r, d = bc, br, float(D[br, bc])
        out.append((c, r))
    return np.array(out, np.int64)


def plan_path(values: np.ndarray, resolution: float, origin: Sequence[float], start: Sequence[float],
              goal: Sequence[float], cfg: PlannerConfig = PlannerConfig()) -> PlanResult:
    """One plan on a map snapshot; see PlanningGrid."""
    try:
        grid = PlanningGrid(values, resolution, origin, cfg, include=[tuple(start[:2]), tuple(goal[:2])])
    except ValueError as e:
        return PlanResult(None, str(e))
    return grid.plan(start, goal)
