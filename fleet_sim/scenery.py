"""What real buildings have and a static floor plan lacks: glass panes, people walking, doors that open and shut.

Pure numpy on the world grid's cells (row 0 = lowest y, as fleet_sim.world). Glass panes are wall cells that the
laser mostly does not see (fleet_sim.laser.glass_no_return); people are discs the laser sees but robots pass
through; a shut door is a wall across a door's gap, for robots and beams alike. All random choices come from the
generator given, so a run is deterministic for its seed.
"""
from __future__ import annotations

import logging
import math
from typing import List, Sequence, Tuple

import cv2
import numpy as np

from multirobot_map_merge.grid import Grid

from .motion import Clearance

_log = logging.getLogger('rosout.fleet_sim.scenery')

PERSON_RADIUS = 0.25     # m
PERSON_SPEED = 0.8       # m/s
DOOR_CLEARANCE = 0.6     # m: a door does not shut while a robot centre is this close to its gap


def wall_runs(blocked: np.ndarray, max_thickness: int = 4) -> np.ndarray:
    """Interior wall cells: blocked cells with free space within ``max_thickness`` cells on two opposite sides
    (left and right, or below and above)."""
    free = ~blocked
    h, w = blocked.shape
    out = np.zeros_like(blocked)
    for axis in (0, 1):
        lo = np.zeros_like(blocked)
        hi = np.zeros_like(blocked)
        for k in range(1, max_thickness + 1):
            if axis == 1:
                lo[:, k:] |= free[:, :-k]
                hi[:, :-k] |= free[:, k:]
            else:
                lo[k:, :] |= free[:-k, :]
                hi[:-k, :] |= free[k:, :]
        out |= blocked & lo & hi
    return out


def glass_mask(world: Grid, blocked: np.ndarray, rng: np.random.Generator, panes: int,
               length_m: Tuple[float, float] = (0.8, 2.0)) -> np.ndarray:
    """``panes`` panes of glass cut from interior walls: pieces of 0.8-2 m of a wall, its whole thickness."""
    res = world.resolution
    walls = wall_runs(blocked)
    mask = np.zeros_like(blocked)
    rows, cols = np.nonzero(walls)
    if rows.size == 0:
        return mask
    for _ in range(panes):
        i = int(rng.integers(rows.size))
        r, c = int(rows[i]), int(cols[i])
        half = max(1, int(round(rng.uniform(*length_m) / res / 2)))
        # along the wall: the axis in which the wall continues through this cell
        horizontal = walls[r, max(0, c - 2):c + 3].sum() >= walls[max(0, r - 2):r + 3, c].sum()
        if horizontal:
            window = (slice(max(0, r - 4), r + 5), slice(max(0, c - half), c + half + 1))
        else:
            window = (slice(max(0, r - half), r + half + 1), slice(max(0, c - 4), c + 5))
        mask[window] |= walls[window]
    return mask


def door_leaves(world: Grid, blocked: np.ndarray, doors_m: Sequence[Sequence[float]],
                max_gap_m: float = 2.0) -> List[np.ndarray]:
    """For each door centre (metres, world frame): the cells (rows, cols) of a 2-cell leaf across its gap, from
    wall to wall along the short axis of the gap; doors whose gap is not found are left out."""
    res = world.resolution
    ox, oy = world.origin[0], world.origin[1]
    h, w = blocked.shape
    reach = int(round(max_gap_m / res))
    leaves = []
    for x, y in doors_m:
        c, r = int(math.floor((x - ox) / res)), int(math.floor((y - oy) / res))
        if not (0 <= r < h and 0 <= c < w) or blocked[r, c]:
            continue
        spans = []
        for dc, dr in ((1, 0), (0, 1)):
            ends = []
            for sign in (-1, 1):
                k = 1
                while k <= reach:
                    rr, cc = r + sign * k * dr, c + sign * k * dc
                    if not (0 <= rr < h and 0 <= cc < w) or blocked[rr, cc]:
                        break
                    k += 1
                ends.append(k)
            spans.append(ends)
        (xl, xh), (yl, yh) = spans
        if xl + xh <= yl + yh and xl <= reach and xh <= reach:      # a gap along x: the wall runs along x
            cols = np.arange(c - xl + 1, c + xh)
            rr, cc = np.meshgrid([r, r + 1], cols, indexing='ij')
        elif yl <= reach and yh <= reach:
            rows = np.arange(r - yl + 1, r + yh)
            rr, cc = np.meshgrid(rows, [c, c + 1], indexing='ij')
        else:
            continue
        ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        leaves.append(np.stack([rr[ok], cc[ok]]))
    return leaves


class Doors:
    """Doors that open and shut at random times (exponential, mean ``period`` s), all open at the start."""

    def __init__(self, world: Grid, blocked: np.ndarray, rng: np.random.Generator, share: float,
                 period: float) -> None:
        self.world, self.static = world, blocked
        self.rng, self.period = rng, period
        leaves = door_leaves(world, blocked, world.extra.get('doors', []))
        n = int(round(share * len(leaves)))
        pick = rng.choice(len(leaves), size=n, replace=False) if n else []
        self.leaves = [leaves[int(i)] for i in sorted(pick)]
        self.shut = [False] * len(self.leaves)
        self.next_change = [float(rng.exponential(period)) for _ in self.leaves]
        self.changes = 0

    def update(self, t: float, robots_xy: Sequence[Sequence[float]]) -> bool:
        """Opens or shuts the doors due at sim time ``t`` (a door does not shut with a robot in its way, it tries
        again a little later); True if any changed."""
        changed = False
        res, (ox, oy) = self.world.resolution, self.world.origin[:2]
        for i, leaf in enumerate(self.leaves):
            if t < self.next_change[i]:
                continue
            if not self.shut[i]:
                xs = ox + (leaf[1] + 0.5) * res
                ys = oy + (leaf[0] + 0.5) * res
                if any(np.min(np.hypot(xs - p[0], ys - p[1])) < DOOR_CLEARANCE for p in robots_xy):
                    self.next_change[i] = t + 2.0
                    continue
            self.shut[i] = not self.shut[i]
            self.next_change[i] = t + float(self.rng.exponential(self.period))
            self.changes += 1
            changed = True
        return changed

    def blocked(self) -> np.ndarray:
        """The world's blocked cells with the shut doors."""
        out = self.static.copy()
        for leaf, shut in zip(self.leaves, self.shut):
            if shut:
                out[leaf[0], leaf[1]] = True
        return out


class People:
    """People walking in straight lines between random free places of the world (not through walls)."""

    def __init__(self, clearance: Clearance, rng: np.random.Generator, count: int) -> None:
        self.clear, self.rng = clearance, rng
        self.pos = np.array([p[:2] for p in clearance.random_free_poses(rng, count, PERSON_RADIUS, 1.0)]) \
            if count else np.zeros((0, 2))
        self.goal = self.pos.copy()
        self._places = np.argwhere(clearance.dist >= PERSON_RADIUS + 0.1)    # (row, col) a person fits in
        self._wait = np.zeros(count)       # s a person stands before choosing where to go next

    def step(self, dt: float) -> None:
        for i in range(len(self.pos)):
            d = self.goal[i] - self.pos[i]
            dist = float(np.hypot(*d))
            if dist < 1e-6:
                self._wait[i] -= dt
                if self._wait[i] <= 0.0:
                    self.goal[i] = self._next_goal(self.pos[i])
                    self._wait[i] = float(self.rng.uniform(0.0, 3.0))   # people stop a while, then walk on
                continue
            move = min(dist, PERSON_SPEED * dt)
            nxt = self.pos[i] + d / dist * move
            if self.clear.free(nxt[0], nxt[1], PERSON_RADIUS):
                self.pos[i] = nxt
            else:                                # a door shut in the way: turn back
                self.goal[i] = self.pos[i]

    def _next_goal(self, p: np.ndarray, tries: int = 10) -> np.ndarray:
        res, (ox, oy) = self.clear.res, self.clear.origin
        for _ in range(tries if len(self._places) else 0):
            r, c = self._places[int(self.rng.integers(len(self._places)))]
            x, y = ox + (c + 0.5) * res, oy + (r + 0.5) * res
            if math.hypot(x - p[0], y - p[1]) > 1.0 and self.clear.segment_free(p, (x, y), PERSON_RADIUS):
                return np.array([x, y])
        return p.copy()

    def draw(self, blocked: np.ndarray, world: Grid, keep_free: Sequence[Sequence[float]],
             keep_radius: float) -> np.ndarray:
        """``blocked`` with the people drawn in, except within ``keep_radius`` of the ``keep_free`` points (the
        robots: a laser never starts inside a person)."""
        if not len(self.pos):
            return blocked
        res, (ox, oy) = world.resolution, world.origin[:2]
        people = np.zeros(blocked.shape, np.uint8)
        for x, y in self.pos:
            cv2.circle(people, (int((x - ox) / res), int((y - oy) / res)), int(round(PERSON_RADIUS / res)), 1, -1)
        for x, y in keep_free:
            cv2.circle(people, (int((x - ox) / res), int((y - oy) / res)), int(math.ceil(keep_radius / res)), 0, -1)
        return blocked | people.astype(bool)
