"""Random but plausible building floor plans (and map files) as ground-truth worlds for the simulator.

The world grid's frame has its origin at the grid's lower-left corner (origin (0, 0, 0)); values -1 outside the
building, 0 free, 100 wall or furniture. Layout: outer walls, a main corridor (plus a cross corridor in wide
buildings), rooms on both sides of the corridor in one or two rows, doors of at least door_min_m, furniture blocks
that never cut the free space (or the space the simulated move_base lets a robot of robot_radius_m use) into pieces.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import List, Optional, Tuple

import cv2
import numpy as np

from multirobot_map_merge.grid import FREE, OCCUPIED, UNKNOWN, Grid
from multirobot_map_merge.mapio import load_map

from .planner import PlannerConfig

_log = logging.getLogger('rosout.fleet_sim.world')

Rect = Tuple[int, int, int, int]   # c0, r0, c1, r1 in cells, half-open


@dataclass
class _Plan:
    data: np.ndarray
    rng: np.random.Generator
    res: float

    def cells(self, metres: float) -> int:
        return int(round(metres / self.res))

    def wall_h(self, row: int, c0: int, c1: int, t: int) -> None:
        r0 = row - t // 2
        self.data[r0:r0 + t, c0:c1] = OCCUPIED

    def wall_v(self, col: int, r0: int, r1: int, t: int) -> None:
        c0 = col - t // 2
        self.data[r0:r1, c0:c0 + t] = OCCUPIED

    def thickness(self) -> int:
        return int(self.rng.integers(1, 4))   # 1-3 cells

    def door_h(self, row: int, c0: int, c1: int, width: int) -> Tuple[int, int]:
        """Cut a door of ``width`` cells into a horizontal wall somewhere in (c0, c1); returns its centre."""
        clear = self.cells(0.3)
        lo, hi = c0 + clear, c1 - clear - width
        if hi < lo:
            return (-1, -1)
        a = int(self.rng.integers(lo, hi + 1))
        self.data[row - 2:row + 3, a:a + width] = FREE
        return (a + width // 2, row)

    def door_mid_h(self, row: int, c0: int, c1: int, width: int) -> Tuple[int, int]:
        """A door of ``width`` cells in the middle of (c0, c1), if it fits between the walls at its ends."""
        a = (c0 + c1 - width) // 2
        if a - 2 < c0 or a + width + 2 > c1:
            return (-1, -1)
        self.data[row - 2:row + 3, a:a + width] = FREE
        return (a + width // 2, row)

    def door_v(self, col: int, r0: int, r1: int, width: int) -> Tuple[int, int]:
        clear = self.cells(0.3)
        lo, hi = r0 + clear, r1 - clear - width
        if hi < lo:
            return (-1, -1)
        a = int(self.rng.integers(lo, hi + 1))
        self.data[a:a + width, col - 2:col + 3] = FREE
        return (col, a + width // 2)


def _split(rng: np.random.Generator, lo: int, hi: int, min_w: int, max_w: int) -> List[int]:
    """Cut points strictly inside (lo, hi) so every piece is within [min_w, ~max_w]."""
    cuts, a = [], lo
    while hi - a > max_w:
        w = int(rng.integers(min_w, max_w + 1))
        if hi - (a + w) < min_w:
            break
        a += w
        cuts.append(a)
    return cuts


def free_components(data: np.ndarray, robot_radius_cells: int = 0) -> int:
    """Number of 4-connected free regions (after eroding free space by a robot radius, if given)."""
    free = (data == FREE).astype(np.uint8)
    if robot_radius_cells > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * robot_radius_cells + 1,) * 2)
        free = cv2.erode(free, k, borderValue=0)
    n, _ = cv2.connectedComponents(free, connectivity=4)
    return n - 1


def make_floor_plan(seed: int, width_m: float = 24.0, height_m: float = 16.0, resolution: float = 0.05,
                    margin_m: float = 0.5, door_min_m: float = 0.9, robot_radius_m: float = 0.2,
                    furniture_per_room: int = 2, clearance_m: Optional[float] = None) -> Grid:
    """A deterministic random building of width_m x height_m (walls included), surrounded by unknown margin_m.

    ``clearance_m``: the distance from walls that a robot keeps on its way to every part of the free space (no
    furniture is placed where it would close the way); default: what the simulated move_base's planner needs.

    ``grid.extra`` holds 'rooms' and 'corridors' (lists of [x0, y0, x1, y1] in metres, free interior) and 'doors'
    (door centres [x, y] in metres)."""
    if width_m < 8.0 or height_m < 8.0:
        raise ValueError("a floor plan needs at least 8 m x 8 m")
    rng = np.random.default_rng(seed)
    m = int(round(margin_m / resolution))
    W = int(round(width_m / resolution)) + 2 * m
    H = int(round(height_m / resolution)) + 2 * m
    p = _Plan(np.full((H, W), UNKNOWN, np.int8), rng, resolution)
    d = p.data
    t_out = int(rng.integers(2, 4))
    x0, y0, x1, y1 = m, m, W - m, H - m            # outer wall outer edge
    d[y0:y1, x0:x1] = OCCUPIED
    ix0, iy0, ix1, iy1 = x0 + t_out, y0 + t_out, x1 - t_out, y1 - t_out   # interior, half-open
    d[iy0:iy1, ix0:ix1] = FREE

    door_lo, door_hi = p.cells(door_min_m), p.cells(max(door_min_m, 1.2))
    door_w = lambda: int(rng.integers(door_lo, door_hi + 1))   # noqa: E731
    rooms: List[Rect] = []
    doors: List[Tuple[int, int]] = []

    # main corridor (horizontal), somewhere around the middle
    cw = p.cells(rng.uniform(1.5, 2.2))
    cy0 = int(rng.integers(iy0 + (iy1 - iy0) // 3, iy0 + 2 * (iy1 - iy0) // 3 - cw))
    cy1 = cy0 + cw
    corridors: List[Rect] = [(ix0, cy0, ix1, cy1)]
    # cross corridor (vertical) in wide buildings splits the blocks left / right
    xsplits: List[Tuple[int, int]] = [(ix0, ix1)]
    vc = None
    if (ix1 - ix0) * resolution >= 14.0:
        vw = p.cells(rng.uniform(1.4, 2.0))
        vx0 = int(rng.integers(ix0 + (ix1 - ix0) // 3, ix0 + 2 * (ix1 - ix0) // 3 - vw))
        vc = (vx0, vx0 + vw)
        xsplits = [(ix0, vx0), (vx0 + vw, ix1)]
        corridors.append((vx0, iy0, vx0 + vw, iy1))

    # blocks above and below the main corridor
    for side in ('below', 'above'):
        by0, by1 = (iy0, cy0) if side == 'below' else (cy1, iy1)
        if by1 - by0 < p.cells(2.5):
            continue
        edge = cy0 if side == 'below' else cy1          # wall line between block and corridor
        for bx0, bx1 in xsplits:
            t = p.thickness()
            p.wall_h(edge, bx0, bx1, t)
            if vc is not None:                         # walls along the cross corridor
                vx = vc[0] if bx1 == vc[0] else vc[1]
                p.wall_v(vx, by0, by1, p.thickness())
            depth = by1 - by0
            rows: List[Tuple[int, int]] = [(by0, by1)]
            if depth * resolution > 7.5:                # two rows of rooms: back row through the front rooms
                cut = int(by0 + depth * rng.uniform(0.4, 0.6))
                rows = [(by0, cut), (cut, by1)]
                p.wall_h(cut, bx0, bx1, p.thickness())
            row_cuts = [_split(rng, bx0, bx1, p.cells(3.0), p.cells(6.0)) for _ in rows]
            front_i = len(rows) - 1 if side == 'below' else 0
            for (ra, rb), cuts in zip(rows, row_cuts):
                xs = [bx0] + cuts + [bx1]
                for cut in cuts:
                    p.wall_v(cut, ra, rb, p.thickness())
                for a, b in zip(xs[:-1], xs[1:]):
                    rooms.append((a, ra, b, rb))
                    if (ra, rb) == rows[front_i]:
                        doors.append(p.door_h(edge, a, b, door_w()))
                    else:
                        # back room: door into the front row, between two of its dividers
                        fx = [a] + [c for c in row_cuts[front_i] if a < c < b] + [b]
                        k = int(np.argmax(np.diff(fx)))
                        row = rb if side == 'below' else ra
                        door = p.door_h(row, fx[k], fx[k + 1], door_w())
                        if door[0] < 0:
                            # too narrow for a door with clearance (a front divider close by): the narrowest
                            # door in the middle, drawing nothing from rng so other plans stay as they were
                            door = p.door_mid_h(row, fx[k], fx[k + 1], door_lo)
                        doors.append(door)
                    if vc is not None and rng.random() < 0.5 and (a == vc[1] or b == vc[0]):
                        doors.append(p.door_v(vc[1] if a == vc[1] else vc[0], ra, rb, door_w()))
                for cut in cuts:                        # some rooms connect to their neighbour
                    if rng.random() < 0.3:
                        doors.append(p.door_v(cut, ra, rb, door_w()))
    doors = [dc for dc in doors if dc[0] >= 0]

    # furniture: blocks in rooms, a pillar or two in the corridor; never cut the free space into pieces, not even
    # for the robots' planner: it keeps robot_radius + its margin from the walls of the robot's map, on planning
    # cells that count as close to a wall as their closest map cell. A way past furniture that only the bare radius
    # fits through is closed to it: the room behind it stays unexplored, or the planner sends the robot on a detour
    # through unknown space around the building. Checked at the bare radius too: a pocket too small for the
    # planner's clearance vanishes in its erosion, not in the robot's.
    if clearance_m is None:
        planner = PlannerConfig(robot_radius=robot_radius_m)
        clearance_m = planner.lethal + planner.plan_resolution / 2
    radii = sorted({max(1, int(round(r / resolution))) for r in (robot_radius_m, clearance_m)})

    def connected() -> bool:
        return free_components(d) == 1 and all(free_components(d, r) == 1 for r in radii)
    keep_clear = p.cells(1.0)
    door_arr = np.array(doors, float).reshape(-1, 2)
    for (a, ra, b, rb) in rooms + corridors[:1]:
        in_corridor = (a, ra, b, rb) == corridors[0]
        n = int(rng.integers(0, furniture_per_room + 1)) if not in_corridor else int(rng.integers(0, 3))
        for _ in range(n):
            if in_corridor:
                fw = fh = p.cells(rng.uniform(0.3, 0.5))
            else:
                fw, fh = p.cells(rng.uniform(0.4, 1.6)), p.cells(rng.uniform(0.4, 1.2))
            if b - a - 6 <= fw or rb - ra - 6 <= fh:
                continue
            fc = int(rng.integers(a + 3, b - 3 - fw))
            fr = int(rng.integers(ra + 3, rb - 3 - fh))
            if door_arr.size:
                cx = np.clip(door_arr[:, 0], fc, fc + fw)
                cy = np.clip(door_arr[:, 1], fr, fr + fh)
                if np.min(np.hypot(door_arr[:, 0] - cx, door_arr[:, 1] - cy)) < keep_clear:
                    continue
            before = d[fr:fr + fh, fc:fc + fw].copy()
            d[fr:fr + fh, fc:fc + fw] = OCCUPIED
            if not connected():
                d[fr:fr + fh, fc:fc + fw] = before     # it would cut something off: leave it out

    if not connected():
        raise RuntimeError(f"floor plan {seed} is not connected")   # a bug in the generator, not bad luck

    def metres(r: Rect) -> List[float]:
        return [round(v * resolution, 6) for v in r]
    grid = Grid(d, resolution, (0.0, 0.0, 0.0), frame_id='world')
    grid.extra.update(seed=seed, rooms=[metres(r) for r in rooms], corridors=[metres(c) for c in corridors],
                      doors=[[round((c + 0.5) * resolution, 6), round((r + 0.5) * resolution, 6)] for c, r in doors],
                      robot_radius_m=robot_radius_m)
    _log.debug("floor plan %d: %d rooms, %d doors", seed, len(rooms), len(doors))
    return grid


def load_world(yaml_path: str) -> Grid:
    """A world from a map_server map; see obstacle_mask for how its cells block robots and beams."""
    return load_map(yaml_path, frame_id='world')


def obstacle_mask(grid: Grid, occupied_from: int = 50) -> np.ndarray:
    """Cells that block robots and laser beams: walls (>= occupied_from) and unknown (outside the building)."""
    return (grid.data < 0) | (grid.data >= occupied_from)
