"""Many kinds of buildings (seeded), as ground-truth worlds for generated fleet scenarios.

A building is carved: free space (rooms, corridors, halls, tunnels) is drawn into an unknown canvas, then every
unknown cell within the wall thickness of free space becomes wall, so the walls are closed by construction (no free
cell touches unknown). Doors are free strips across the wall between two free regions; racks, pillars and furniture
are walls placed inside free space only where they cut nothing off. The grid is as fleet_sim.world's floor plans:
origin (0, 0, 0) at the lower-left corner, -1 outside, 0 free, 100 wall; ``grid.extra`` holds 'kind' and 'seed'.

    make_building(kind, seed) -> Grid          kinds: KINDS
"""
from __future__ import annotations

import logging
import math
from typing import Callable, Dict, List, Tuple, Union

import cv2
import numpy as np

from multirobot_map_merge.grid import FREE, OCCUPIED, UNKNOWN, Grid

from .world import free_components, make_floor_plan

_log = logging.getLogger('rosout.fleet_sim.buildings')

RES = 0.05
MARGIN_M = 0.5
ROBOT_RADIUS_M = 0.2


class Canvas:
    """Free space drawn in metres (x right, y up from the lower-left corner) on a grid of RES cells."""

    def __init__(self, width_m: float, height_m: float, rng: np.random.Generator):
        self.rng = rng
        self.m = int(round(MARGIN_M / RES))
        self.free = np.zeros((int(round(height_m / RES)) + 2 * self.m, int(round(width_m / RES)) + 2 * self.m),
                             np.uint8)
        self.solid = np.zeros_like(self.free)    # walls drawn inside free space (racks, pillars, furniture)
        self.width_m, self.height_m = width_m, height_m

    def cell(self, x: float, y: float) -> Tuple[int, int]:
        """(col, row) of a point in metres (row 0 at the lowest y, as Grid's cell_to_map has it)."""
        return int(round(x / RES)) + self.m, int(round(y / RES)) + self.m

    def rect(self, x0: float, y0: float, x1: float, y1: float, into: str = 'free') -> None:
        (c0, r0), (c1, r1) = self.cell(min(x0, x1), min(y0, y1)), self.cell(max(x0, x1), max(y0, y1))
        getattr(self, into)[max(r0, 0):max(r1, 0), max(c0, 0):max(c1, 0)] = 1

    def poly(self, points: List[Tuple[float, float]], into: str = 'free') -> None:
        pts = np.array([self.cell(x, y) for x, y in points], np.int32)
        cv2.fillPoly(getattr(self, into), [pts], 1)

    def line(self, a: Tuple[float, float], b: Tuple[float, float], width_m: float, into: str = 'free') -> None:
        cv2.line(getattr(self, into), self.cell(*a), self.cell(*b), 1, max(1, int(round(width_m / RES))))

    def disc(self, x: float, y: float, r_m: float, into: str = 'free') -> None:
        cv2.circle(getattr(self, into), self.cell(x, y), max(1, int(round(r_m / RES))), 1, -1)

    def turned_rect(self, cx: float, cy: float, length: float, width: float, angle: float,
                    into: str = 'free') -> None:
        """A rectangle of length along `angle` (radians) and width across it, centred on (cx, cy)."""
        c, s = math.cos(angle), math.sin(angle)
        hl, hw = length / 2, width / 2
        self.poly([(cx + c * u - s * v, cy + s * u + c * v) for u, v in ((-hl, -hw), (hl, -hw), (hl, hw), (-hl, hw))],
                  into)

    def grid(self, kind: str, seed: int, wall_m: float) -> Grid:
        """The building: walls of wall_m around the free space, solids inside it; each solid that would cut the free
        space (or the space a robot can use) into pieces is left out, as are free islands it cannot reach."""
        t = max(1, int(round(wall_m / RES)))
        free = self.free.copy()
        free[:self.m, :] = free[-self.m:, :] = 0     # the margin stays outside the building
        free[:, :self.m] = free[:, -self.m:] = 0
        free = largest_part(free)
        data = np.full(free.shape, UNKNOWN, np.int8)
        data[cv2.dilate(free, np.ones((2 * t + 1, 2 * t + 1), np.uint8)) > 0] = OCCUPIED
        data[free > 0] = FREE
        place_solids(data, self.solid)
        grid = Grid(data, RES, (0.0, 0.0, 0.0), frame_id='world')
        grid.extra.update(kind=kind, seed=seed, robot_radius_m=ROBOT_RADIUS_M)
        return grid


def largest_part(free: np.ndarray) -> np.ndarray:
    """The largest 4-connected part of free space that a robot can use (free islands left out)."""
    r = max(1, int(round(ROBOT_RADIUS_M / RES)))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)
    usable = cv2.erode(free, k, borderValue=0)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(usable, connectivity=4)
    if n < 2:
        raise RuntimeError('a building without free space')
    core = (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)
    reach = cv2.dilate(core, k) & free       # the cells a robot in the core part sweeps
    n, labels, stats, _ = cv2.connectedComponentsWithStats(reach, connectivity=4)
    return (labels == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))).astype(np.uint8)


def place_solids(data: np.ndarray, solid: np.ndarray) -> None:
    """Solid blobs into free space, one at a time, each kept only if the free space stays one piece for a robot."""
    n, labels = cv2.connectedComponents(solid, connectivity=8)
    r = max(1, int(round(ROBOT_RADIUS_M / RES)))
    for k in range(1, n):
        rows, cols = np.nonzero(labels == k)
        before = data[rows, cols].copy()
        data[rows, cols] = np.where(before == FREE, OCCUPIED, before)
        if free_components(data) != 1 or free_components(data, r) != 1:
            data[rows, cols] = before


def _rooms_along(cv: Canvas, x0: float, x1: float, y_edge: float, depth: float, width: float, side: int,
                 door: float = 1.0, door_at: float = 0.5, wall: float = 0.15, furniture: int = 2) -> None:
    """A row of rooms of the same width x depth along a horizontal corridor edge at y_edge (side +1: rooms above,
    -1: below), each with a door of `door` m at `door_at` of its width and up to `furniture` pieces of furniture
    of its own (rooms alike, as in a real building, but not copies of each other)."""
    n = int((x1 - x0 + wall) // (width + wall))
    for i in range(n):
        a = x0 + i * (width + wall)
        b = a + width
        near, far = y_edge + side * wall, y_edge + side * (wall + depth)
        cv.rect(a, near, b, far)
        dx = a + door_at * (width - door)
        cv.rect(dx, y_edge - side * 0.05, dx + door, near + side * 0.05)
        for _ in range(int(cv.rng.integers(0, furniture + 1))):
            fw, fd = float(cv.rng.uniform(0.5, min(1.8, width / 2))), float(cv.rng.uniform(0.5, min(1.2, depth / 3)))
            fx = float(cv.rng.uniform(a + 0.4, b - 0.4 - fw))
            fy = far - side * float(cv.rng.uniform(0.3, depth / 2))      # the back half: the door stays clear
            cv.rect(fx, fy, fx + fw, fy - side * fd, 'solid')


def hospital(rng: np.random.Generator) -> Canvas:
    """Wings of identical rooms off long parallel corridors, joined by a corridor at one or both ends."""
    n_wings = int(rng.integers(2, 4))
    room_w, room_d = float(rng.uniform(3.2, 4.0)), float(rng.uniform(4.0, 5.0))
    cw, length = float(rng.uniform(2.0, 2.6)), float(rng.uniform(36.0, 46.0))
    wing_h = 2 * room_d + cw + 0.6
    cv = Canvas(length + 5.0, n_wings * wing_h + 1.0, rng)
    ends = 'both' if rng.random() < 0.5 else 'left'
    for w in range(n_wings):
        y = 0.5 + w * wing_h + room_d + 0.3
        cv.rect(3.0, y, length + 2.5, y + cw)
        _rooms_along(cv, 3.2, length + 2.3, y, room_d, room_w, -1)
        _rooms_along(cv, 3.2, length + 2.3, y + cw, room_d, room_w, +1)
    cv.rect(0.5, 0.5 + room_d + 0.3, 2.8, (n_wings - 1) * wing_h + 0.5 + room_d + 0.3 + cw)
    for w in range(n_wings):                                   # corridors reach the joining corridor
        y = 0.5 + w * wing_h + room_d + 0.3
        cv.rect(2.7, y, 3.1, y + cw)
        if ends == 'both' and w < n_wings - 1:
            cv.rect(length + 2.5, y, length + 4.5, y + wing_h + cw)
    return cv


def warehouse(rng: np.random.Generator) -> Canvas:
    """An open hall with rows of racks (long, 1 m deep) and cross aisles, a few offices along one wall."""
    w, h = float(rng.uniform(40.0, 50.0)), float(rng.uniform(26.0, 32.0))
    cv = Canvas(w, h, rng)
    office_d = 4.0
    cv.rect(0.5, 0.5, w - 0.5, h - 0.5 - office_d - 0.2)
    _rooms_along(cv, 0.7, w - 0.7, h - 0.5 - office_d - 0.2, office_d, float(rng.uniform(4.0, 6.0)), +1, door=1.2)
    aisle, depth = float(rng.uniform(2.6, 3.4)), float(rng.uniform(1.0, 1.4))
    vertical = rng.random() < 0.5
    span = (w if vertical else h - office_d) - 6.0
    n_cross = int(rng.integers(1, 3))
    x = 3.0
    while x + depth < span:
        lo, hi = 3.0, (h - office_d - 3.0 if vertical else w - 3.0)
        cuts = np.sort(rng.uniform(lo + 4.0, hi - 4.0, n_cross))
        a = lo
        for c in list(cuts) + [hi]:
            if c - 1.2 - a > 2.0:
                (cv.rect(x, a, x + depth, c - 1.2, 'solid') if vertical else cv.rect(a, x, c - 1.2, x + depth, 'solid'))
            a = c + 1.2
        x += depth + aisle
    return cv


def office(rng: np.random.Generator) -> Canvas:
    """Blocks of small rooms (2.5-3.5 m) between a grid of corridors."""
    nx_, ny = int(rng.integers(3, 5)), int(rng.integers(2, 4))
    room = float(rng.uniform(2.5, 3.5))
    per_x, per_y = int(rng.integers(2, 4)), 2
    cw = float(rng.uniform(1.6, 2.0))
    bw, bh = per_x * (room + 0.15) + 0.15, per_y * (room + 0.15) + 0.15   # a wall gap on every side
    cv = Canvas(nx_ * (bw + cw) + cw + 1.0, ny * (bh + cw) + cw + 1.0, rng)
    for i in range(nx_ + 1):
        x = 0.5 + i * (bw + cw)
        cv.rect(x, 0.5, x + cw, 0.5 + ny * (bh + cw) + cw)
    for j in range(ny + 1):
        y = 0.5 + j * (bh + cw)
        cv.rect(0.5, y, 0.5 + nx_ * (bw + cw) + cw, y + cw)
    for i in range(nx_):
        for j in range(ny):
            bx, by = 0.5 + cw + i * (bw + cw), 0.5 + cw + j * (bh + cw)
            for a in range(per_x):
                for b in range(per_y):
                    x0, y0 = bx + 0.15 + a * (room + 0.15), by + 0.15 + b * (room + 0.15)
                    cv.rect(x0, y0, x0 + room, y0 + room)
                    door = float(rng.uniform(0.9, 1.1))
                    dx = x0 + float(rng.uniform(0.2, room - door - 0.2))
                    if b == 0:
                        cv.rect(dx, y0 - 0.3, dx + door, y0 + 0.1)
                    else:
                        cv.rect(dx, y0 + room - 0.1, dx + door, y0 + room + 0.3)
                    if rng.random() < 0.8:
                        cv.rect(x0 + 0.4, y0 + room / 2 - 0.4, x0 + 1.2, y0 + room / 2 + 0.4, 'solid')
    return cv


def cave(rng: np.random.Generator) -> Canvas:
    """Irregular caverns and passages: smoothed random noise above a threshold, joined by winding tunnels."""
    w, h = float(rng.uniform(40.0, 48.0)), float(rng.uniform(28.0, 34.0))
    cv = Canvas(w, h, rng)
    coarse = rng.standard_normal((int(h / 1.5) + 2, int(w / 1.5) + 2)).astype(np.float32)
    field = cv2.resize(coarse, (cv.free.shape[1], cv.free.shape[0]), interpolation=cv2.INTER_CUBIC)
    field = cv2.GaussianBlur(field, (0, 0), 1.0 / RES)
    cv.free[field > np.quantile(field, 0.55)] = 1
    points = [(float(rng.uniform(3, w - 3)), float(rng.uniform(3, h - 3))) for _ in range(10)]
    for a, b in zip(points[:-1], points[1:]):      # tunnels that wander, so the caverns are one cave
        mid = ((a[0] + b[0]) / 2 + float(rng.normal(0, 3)), (a[1] + b[1]) / 2 + float(rng.normal(0, 3)))
        cv.line(a, mid, float(rng.uniform(1.4, 2.2)))
        cv.line(mid, b, float(rng.uniform(1.4, 2.2)))
    for _ in range(int(rng.integers(8, 16))):         # boulders
        cv.disc(float(rng.uniform(2, w - 2)), float(rng.uniform(2, h - 2)), float(rng.uniform(0.3, 0.8)), 'solid')
    return cv


def pillar_hall(rng: np.random.Generator) -> Canvas:
    """Two or three large halls side by side with a regular grid of pillars (each hall its own size and grid
    offset, as the halls of one building differ), joined by wide openings."""
    n = int(rng.integers(2, 4))
    widths, heights = rng.uniform(14.0, 22.0, n), rng.uniform(18.0, 28.0, n)
    pitch, size = float(rng.uniform(4.5, 6.5)), float(rng.uniform(0.4, 0.7))
    cv = Canvas(float(widths.sum()) + 0.3 * n + 1.0, float(heights.max()) + 1.0, rng)
    x0 = 0.5
    for i, (hw, hh) in enumerate(zip(widths.tolist(), heights.tolist())):
        cv.rect(x0, 0.5, x0 + hw, 0.5 + hh)
        ox, oy = rng.uniform(2.0, pitch, 2).tolist()
        for x in np.arange(x0 + ox, x0 + hw - 1.5, pitch):
            for y in np.arange(0.5 + oy, 0.5 + hh - 1.5, pitch):
                cv.rect(x - size / 2, y - size / 2, x + size / 2, y + size / 2, 'solid')
        if i:
            y = float(rng.uniform(2.0, min(hh, heights[i - 1]) - 6.0))
            cv.rect(x0 - 0.4, y, x0 + 0.1, y + float(rng.uniform(2.5, 4.0)))
        x0 += hw + 0.3
    return cv


def courtyard(rng: np.random.Generator) -> Canvas:
    """A ring corridor around a closed courtyard, rooms between the corridor and the outer wall and a few on the
    courtyard side."""
    w, h = float(rng.uniform(36.0, 46.0)), float(rng.uniform(28.0, 34.0))
    cw, d = float(rng.uniform(2.0, 2.6)), float(rng.uniform(4.0, 5.0))
    cv = Canvas(w, h, rng)
    x0, y0, x1, y1 = 0.5 + d + 0.2, 0.5 + d + 0.2, w - 0.5 - d - 0.2, h - 0.5 - d - 0.2   # corridor's outer edge
    for a, b, c, e in ((x0, y0, x1, y0 + cw), (x0, y1 - cw, x1, y1), (x0, y0, x0 + cw, y1), (x1 - cw, y0, x1, y1)):
        cv.rect(a, b, c, e)
    rw = float(rng.uniform(3.5, 5.5))
    _rooms_along(cv, x0, x1, y0, d, rw, -1)
    _rooms_along(cv, x0, x1, y1, d, rw, +1)
    for x_edge, side in ((x0, -1), (x1, +1)):                  # rooms on the left and right: the same, turned
        n = int((y1 - y0 - 0.15) // (rw + 0.15))
        for i in range(n):
            a = y0 + i * (rw + 0.15)
            near, far = x_edge + side * 0.15, x_edge + side * (0.15 + d)
            cv.rect(near, a, far, a + rw)
            cv.rect(x_edge - side * 0.05, a + rw / 2 - 0.5, near + side * 0.05, a + rw / 2 + 0.5)
    inner = (x0 + cw + 0.15, y0 + cw + 0.15, x1 - cw - 0.15, y1 - cw - 0.15)
    _rooms_along(cv, inner[0], inner[2], y0 + cw, float(rng.uniform(3.0, 4.0)), rw + 1.0, +1, furniture=0)
    return cv


def campus(rng: np.random.Generator) -> Canvas:
    """Three or four wings (a corridor and rooms each side), apart, joined in a chain by long narrow passages."""
    n = int(rng.integers(3, 5))
    W, H = 52.0, 38.0
    cv = Canvas(W, H, rng)
    slots = [(3.0, 2.0), (W / 2 + 3.0, 2.0), (3.0, H / 2 + 2.0), (W / 2 + 3.0, H / 2 + 2.0)]
    wings = []                                     # (slot, left port, right port) of each wing
    for s in rng.permutation(4)[:n]:
        x, y = slots[int(s)]
        length, cw, d = float(rng.uniform(14.0, 19.0)), float(rng.uniform(1.8, 2.4)), float(rng.uniform(3.5, 4.5))
        yc = y + d + 0.2
        cv.rect(x - 2.5, yc, x + length + 2.5, yc + cw)       # the corridor runs past the rooms to its ports
        rw = float(rng.uniform(3.0, 5.0))
        _rooms_along(cv, x + 0.2, x + length - 0.2, yc, d, rw, -1)
        _rooms_along(cv, x + 0.2, x + length - 0.2, yc + cw, d, rw, +1)
        wings.append((int(s), (x - 1.5, yc + cw / 2), (x + length + 1.5, yc + cw / 2)))
    for a, b in zip(wings[:-1], wings[1:]):
        if a[0] % 2 == b[0] % 2:                   # one above the other: both right ports, the leg right of both
            pa, pb = a[2], b[2]
            leg = max(pa[0], pb[0])
        else:                                      # side by side: the facing ports, the leg at the left one's
            pa, pb = (a[2], b[1]) if a[0] % 2 == 0 else (a[1], b[2])
            leg = pa[0] if a[0] % 2 == 0 else pb[0]
        width = float(rng.uniform(1.4, 1.8))
        for p, q in ((pa, (leg, pa[1])), ((leg, pa[1]), (leg, pb[1])), ((leg, pb[1]), pb)):
            cv.line(p, q, width)
    return cv


def classic(rng: np.random.Generator) -> Grid:
    """fleet_sim.world's floor plan (rooms on both sides of a main corridor), 48 m x 32 m."""
    return make_floor_plan(int(rng.integers(1 << 30)), 48.0, 32.0, resolution=RES)


def mall(rng: np.random.Generator) -> Canvas:
    """A wide concourse with shops (deep rooms with wide fronts) on both sides and kiosks down its middle."""
    L = float(rng.uniform(42.0, 50.0))
    cw, d = float(rng.uniform(6.0, 8.0)), float(rng.uniform(6.0, 8.0))
    cv = Canvas(L + 1.0, 2 * d + cw + 1.6, rng)
    y = 0.8 + d
    cv.rect(0.5, y, L + 0.5, y + cw)
    for side, edge in ((-1, y), (+1, y + cw)):
        x = 0.7
        while x < L - 5.0:
            sw = float(rng.uniform(4.0, 8.0))
            cv.rect(x, edge + side * 0.2, min(x + sw, L + 0.3), edge + side * (0.2 + d))
            cv.rect(x + 0.8, edge - side * 0.05, min(x + sw, L + 0.3) - 0.8, edge + side * 0.25)
            x += sw + 0.2
    for x in np.arange(5.0, L - 3.0, float(rng.uniform(7.0, 10.0))):
        cv.disc(float(x), y + cw / 2, float(rng.uniform(0.6, 1.0)), 'solid')
    return cv


def tunnels(rng: np.random.Generator) -> Canvas:
    """A mine: a tree of narrow tunnels at any angle, with small chambers at some junctions."""
    w, h = float(rng.uniform(40.0, 48.0)), float(rng.uniform(30.0, 36.0))
    cv = Canvas(w, h, rng)
    nodes = [(w / 2, h / 2)]
    for _ in range(28):
        a = nodes[int(rng.integers(len(nodes)))]
        ang, length = float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(5.0, 10.0))
        b = (float(np.clip(a[0] + length * math.cos(ang), 2.0, w - 2.0)),
             float(np.clip(a[1] + length * math.sin(ang), 2.0, h - 2.0)))
        cv.line(a, b, float(rng.uniform(1.3, 1.9)))
        if rng.random() < 0.3:
            cv.disc(b[0], b[1], float(rng.uniform(1.5, 2.5)))
        nodes.append(b)
    return cv


def school(rng: np.random.Generator) -> Canvas:
    """An L of corridors with large classrooms (7-9 m) on both sides and an empty gym at the corner."""
    cw = float(rng.uniform(2.4, 3.0))
    d = float(rng.uniform(6.5, 8.0))
    L = float(rng.uniform(30.0, 36.0))
    gym = float(rng.uniform(12.0, 15.0))
    top = 0.5 + 2 * d + cw + float(rng.uniform(10.0, 16.0))
    cv = Canvas(L + gym + d + 1.5, top + 0.5, rng)
    y = 0.5 + d + 0.2
    x = gym + 0.5 + L - cw                                                  # the L's other leg
    cv.rect(gym + 0.5, y, gym + 0.5 + L, y + cw)
    cv.rect(x, y, x + cw, top - 0.5)
    _rooms_along(cv, gym + 0.7, gym + 0.5 + L, y, d, float(rng.uniform(7.0, 9.0)), -1, door=1.4, door_at=0.1)
    _rooms_along(cv, gym + 0.7, x - 0.15, y + cw, d, float(rng.uniform(7.0, 9.0)), +1, door=1.4, door_at=0.9)
    cv.rect(0.5, 0.5, gym + 0.3, 0.5 + gym)                                 # the gym, a door into the corridor
    cv.rect(gym + 0.2, y + 0.3, gym + 0.6, y + cw - 0.3)
    _rooms_along_v(cv, y + cw + d + 0.3, top - 0.5, x, d, float(rng.uniform(7.0, 9.0)), -1)
    _rooms_along_v(cv, 0.6, top - 0.5, x + cw, d, float(rng.uniform(7.0, 9.0)), +1)
    return cv


def _rooms_along_v(cv: Canvas, y0: float, y1: float, x_edge: float, depth: float, width: float, side: int) -> None:
    """Rooms along a vertical corridor edge at x_edge (side -1: to its left), a door in the middle of each."""
    n = int((y1 - y0) // (width + 0.15))
    for i in range(n):
        a = y0 + i * (width + 0.15)
        near, far = x_edge + side * 0.15, x_edge + side * (0.15 + depth)
        cv.rect(near, a, far, a + width)
        cv.rect(x_edge - side * 0.05, a + width / 2 - 0.6, near + side * 0.05, a + width / 2 + 0.6)


def radial(rng: np.random.Generator) -> Canvas:
    """A round hub with four to six wings at uneven angles, rooms along both sides of each wing."""
    W = H = 48.0
    cv = Canvas(W, H, rng)
    cx, cy = W / 2, H / 2
    cv.disc(cx, cy, float(rng.uniform(4.0, 5.5)))
    n = int(rng.integers(4, 6))
    angles = (np.arange(n) + rng.uniform(-0.2, 0.2, n)) * 2 * math.pi / n + rng.uniform(0, 2 * math.pi)
    for ang in angles:
        cw, length, d = float(rng.uniform(2.0, 2.6)), float(rng.uniform(13.0, 18.0)), float(rng.uniform(3.5, 4.5))
        c, s = math.cos(ang), math.sin(ang)
        cv.turned_rect(cx + c * (length / 2 + 2), cy + s * (length / 2 + 2), length + 4, cw, ang)
        rw = float(rng.uniform(3.0, 4.5))
        for k in range(int((length - 4.0) // (rw + 0.15))):
            u = 7.0 + k * (rw + 0.15) + rw / 2
            for side in (-1, 1):
                v = side * (cw / 2 + 0.15 + d / 2)
                cv.turned_rect(cx + c * u - s * v, cy + s * u + c * v, rw, d, ang)
                vd = side * (cw / 2 + 0.075)
                cv.turned_rect(cx + c * u - s * vd, cy + s * u + c * vd, 1.0, 0.45, ang)
    return cv


def maze(rng: np.random.Generator) -> Canvas:
    """A labyrinth of 2.4-3 m cells (a random spanning tree, a few loops added): every junction looks alike."""
    cell = float(rng.uniform(2.4, 3.0))
    nx_, ny = int(rng.integers(13, 17)), int(rng.integers(9, 12))
    cv = Canvas(nx_ * cell + 1.0, ny * cell + 1.0, rng)
    wall = 0.15
    seen = {(0, 0)}
    stack = [(0, 0)]
    while stack:                                   # depth-first carving: long winding passages
        i, j = stack[-1]
        nbrs = [(i + a, j + b) for a, b in ((1, 0), (-1, 0), (0, 1), (0, -1))
                if 0 <= i + a < nx_ and 0 <= j + b < ny and (i + a, j + b) not in seen]
        if not nbrs:
            stack.pop()
            continue
        n = nbrs[int(rng.integers(len(nbrs)))]
        _maze_join(cv, (i, j), n, cell, wall)
        seen.add(n)
        stack.append(n)
    for _ in range(nx_ * ny // 8):                # loops
        i, j = int(rng.integers(nx_ - 1)), int(rng.integers(ny))
        _maze_join(cv, (i, j), (i + 1, j), cell, wall)
    return cv


def _maze_join(cv: Canvas, a: Tuple[int, int], b: Tuple[int, int], cell: float, wall: float) -> None:
    (i0, j0), (i1, j1) = min(a, b), max(a, b)
    cv.rect(0.5 + i0 * cell + wall, 0.5 + j0 * cell + wall, 0.5 + (i1 + 1) * cell - wall, 0.5 + (j1 + 1) * cell - wall)


KINDS: Dict[str, Callable[[np.random.Generator], Union[Canvas, Grid]]] = {
    'hospital': hospital, 'warehouse': warehouse, 'office': office, 'cave': cave, 'pillar_hall': pillar_hall,
    'courtyard': courtyard, 'campus': campus, 'classic': classic, 'mall': mall, 'tunnels': tunnels,
    'school': school, 'radial': radial, 'maze': maze,
}
WALL_M = (0.1, 0.15)     # wall thickness drawn (m)


def make_building(kind: str, seed: int) -> Grid:
    """A deterministic building of the given kind (one of KINDS) for this seed."""
    if kind not in KINDS:
        raise ValueError(f'unknown building kind {kind!r} (one of {", ".join(KINDS)})')
    rng = np.random.default_rng([seed, sorted(KINDS).index(kind)])
    drawn = KINDS[kind](rng)
    if isinstance(drawn, Grid):
        grid = drawn
        grid.extra.update(kind=kind, seed=seed)
    else:
        grid = drawn.grid(kind, seed, float(rng.uniform(*WALL_M)))
    _log.debug('building %s %d: %dx%d cells', kind, seed, grid.width, grid.height)
    return grid
