"""Robot motion: a disc robot on the true world (collision), unicycle steps, and a path follower (pure pursuit).

Collision is checked against the world grid, never against the robot's map: a robot cannot pass a wall it has not
seen. A position is free when the world cell under the robot centre is at least robot_radius (cell-centre distance)
from every blocking cell (walls and unknown, see world.obstacle_mask).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import cv2
import numpy as np

from multirobot_map_merge.grid import Grid

from .world import obstacle_mask

Pose = Tuple[float, float, float]


class Clearance:
    """Distance (metres) from every world cell centre to the nearest blocking cell centre."""

    def __init__(self, world: Grid, blocked: Optional[np.ndarray] = None) -> None:
        """blocked: the cells that block robots, if not obstacle_mask(world) (e.g. with doors shut)."""
        if abs(world.origin[2]) > 1e-9:
            raise ValueError("world maps with a rotated origin are not supported")
        self.res = world.resolution
        self.origin = world.origin[:2]
        self.blocked = obstacle_mask(world) if blocked is None else blocked
        self.dist = cv2.distanceTransform((~self.blocked).astype(np.uint8), cv2.DIST_L2, 5) * self.res
        self.shape = self.blocked.shape

    def at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Clearance at points (-1 outside the world grid: never free)."""
        c = np.floor((np.asarray(x, float) - self.origin[0]) / self.res).astype(np.int64)
        r = np.floor((np.asarray(y, float) - self.origin[1]) / self.res).astype(np.int64)
        inside = (c >= 0) & (c < self.shape[1]) & (r >= 0) & (r < self.shape[0])
        out = np.full(c.shape, -1.0, np.float32)
        out[inside] = self.dist[r[inside], c[inside]]
        return out

    def free(self, x: float, y: float, radius: float) -> bool:
        return bool(self.at(np.array([x]), np.array([y]))[0] >= radius)

    def segment_free(self, a: Sequence[float], b: Sequence[float], radius: float) -> bool:
        """Every point of segment a-b (sampled every half cell) is free for a robot of ``radius``."""
        n = max(2, int(math.ceil(math.hypot(b[0] - a[0], b[1] - a[1]) / (0.5 * self.res))) + 1)
        s = np.linspace(0.0, 1.0, n)
        return bool((self.at(a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])) >= radius).all())

    def random_free_poses(self, rng: np.random.Generator, n: int, radius: float, min_separation: float = 1.0,
                          margin: float = 0.2, tries: int = 2000) -> list:
        """n poses (x, y, yaw) at least radius + margin from walls, in the largest free region, pairwise at least
        min_separation apart (relaxed if the world is too small)."""
        ok = (self.dist >= radius + margin).astype(np.uint8)
        count, labels = cv2.connectedComponents(ok, connectivity=8)
        if count <= 1:
            raise ValueError(f"the world has no free place for a robot of radius {radius} m")
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        rows, cols = np.nonzero(labels == int(np.argmax(sizes)))
        poses: list = []
        sep = min_separation
        while len(poses) < n:
            for _ in range(tries):
                i = int(rng.integers(rows.size))
                x = self.origin[0] + (cols[i] + 0.5) * self.res
                y = self.origin[1] + (rows[i] + 0.5) * self.res
                if all(math.hypot(x - p[0], y - p[1]) >= sep for p in poses):
                    poses.append((x, y, float(rng.uniform(-math.pi, math.pi))))
                    break
            else:
                sep *= 0.5   # crowded world: accept closer robots rather than fail
        return poses


def integrate(pose: Sequence[float], v: float, w: float, dt: float) -> Pose:
    """Unicycle step (midpoint heading)."""
    mid = pose[2] + 0.5 * w * dt
    return (pose[0] + v * dt * math.cos(mid), pose[1] + v * dt * math.sin(mid),
            math.remainder(pose[2] + w * dt, 2.0 * math.pi))


@dataclass
class FollowerConfig:
    linear_speed: float = 0.5
    angular_speed: float = 1.5
    lookahead: float = 0.4         # pure-pursuit distance along the path
    turn_in_place: float = 0.6     # heading error (rad) above which the robot turns on the spot
    heading_gain: float = 2.5


class PathFollower:
    """Drives along a polyline: steer at a look-ahead point that the robot can reach in a straight, collision-free
    line (so it does not cut corners into walls), turn on the spot for large heading errors."""

    def __init__(self, path: np.ndarray, cfg: FollowerConfig) -> None:
        self.path = np.asarray(path, float)
        self.cfg = cfg
        self.index = 0           # path point closest to the robot so far (never goes back)
        seg = np.diff(self.path, axis=0)
        self._cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])

    @property
    def end(self) -> np.ndarray:
        return self.path[-1]

    def remaining(self) -> np.ndarray:
        return self.path[self.index:]

    def command(self, pose: Sequence[float], dt: float,
                line_free=None) -> Tuple[float, float]:
        """(v, w) for the next step from ``pose`` (same frame as the path). ``line_free(a, b)`` tells whether the
        straight line a-b is clear (None: always)."""
        cfg = self.cfg
        x, y, yaw = pose
        p = self.path
        # advance the closest index within a window ahead (monotonic progress along the path)
        hi = min(len(p), self.index + 40)
        d = np.hypot(p[self.index:hi, 0] - x, p[self.index:hi, 1] - y)
        self.index += int(np.argmin(d))
        # look-ahead: the farthest point within `lookahead` of path length that is reachable in a straight line
        target_i = int(np.searchsorted(self._cum, self._cum[self.index] + cfg.lookahead, side='right')) - 1
        target_i = max(min(target_i, len(p) - 1), min(self.index + 1, len(p) - 1))
        if line_free is not None:
            while target_i > self.index + 1 and not line_free((x, y), p[target_i]):
                target_i -= 1
        tx, ty = p[target_i]
        dist_end = math.hypot(p[-1, 0] - x, p[-1, 1] - y)
        dx, dy = tx - x, ty - y
        if math.hypot(dx, dy) < 1e-6:
            return 0.0, 0.0
        err = math.remainder(math.atan2(dy, dx) - yaw, 2.0 * math.pi)
        w_max = cfg.angular_speed
        if abs(err) > cfg.turn_in_place:
            w = math.copysign(min(w_max, abs(err) / dt), err)   # do not overshoot within one step
            return 0.0, w
        w = max(-w_max, min(w_max, cfg.heading_gain * err))
        v = cfg.linear_speed * max(0.0, math.cos(err))
        v = min(v, dist_end / dt)   # stop on the end point rather than overshoot it
        return v, w


def step_with_collision(pose: Pose, v: float, w: float, dt: float, clearance: Clearance,
                        radius: float) -> Tuple[Pose, bool]:
    """Move by (v, w) for dt unless the robot would hit a world wall; then only turn. Returns (pose, blocked)."""
    new = integrate(pose, v, w, dt)
    if v == 0.0 or clearance.free(new[0], new[1], radius):
        return new, False
    return (pose[0], pose[1], math.remainder(pose[2] + w * dt, 2.0 * math.pi)), True


def path_blocked_index(occupied, resolution: float, origin: Sequence[float], path: np.ndarray,
                       radius: float) -> Optional[int]:
    """Index of the first path point with an occupied map cell within ``radius``, or None. ``occupied(cols, rows)``
    tells which grid cells (any integers) are occupied; the grid's cell (0, 0) has its corner at ``origin``."""
    if len(path) == 0:
        return None
    r = int(math.ceil(radius / resolution))
    off = np.arange(-r, r + 1)
    oc, orr = np.meshgrid(off, off)
    disc = (oc ** 2 + orr ** 2) * resolution ** 2 <= radius ** 2
    oc, orr = oc[disc], orr[disc]
    c = np.floor((path[:, 0] - origin[0]) / resolution).astype(np.int64)
    rr = np.floor((path[:, 1] - origin[1]) / resolution).astype(np.int64)
    hit = occupied(c[:, None] + oc[None, :], rr[:, None] + orr[None, :]).any(axis=1)
    return int(np.argmax(hit)) if hit.any() else None


def values_occupied(values: np.ndarray):
    """An ``occupied(cols, rows)`` test on an int8 map (>= 50 occupied, outside the array: free)."""
    def occupied(cols: np.ndarray, rows: np.ndarray) -> np.ndarray:
        h, w = values.shape
        inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
        out = np.zeros(np.shape(cols), bool)
        out[inside] = values[rows[inside], cols[inside]] >= 50
        return out
    return occupied
