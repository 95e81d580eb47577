"""Final polish of a chosen placement: a direct search on a symmetric consistency cost.

ICP pairs each wall with its nearest neighbour; on a small common area (a corridor seen from both ends, thin walls
seen from opposite sides, whose pairs ICP drops) it can settle a degree or a few pixels off. Here the placement of
grid i on grid j moves in shrinking steps of rotation and translation while this cost goes down:

    mean, over the walls of either grid that land well inside the other's known area (where the other map looked
    and would have seen them), of min(distance to the other's nearest wall, TAU)^2

Both directions count, so neither grid's extra walls bias the result; walls at the edge of the other's known area
(the ends of its beams) and beyond it say nothing and are left out. The distance is interpolated between pixels:
read at the nearest pixel, the cost is flat in steps and the search stopped in a step's corner, up to half a degree
off on a small common area. Each placement is also tried turned by START_TURN either way, since the cost of a small
common area has nearby minima; the lowest wins. The cost only ranks nearby placements: acceptance stays with the
matcher's verification.
"""
from __future__ import annotations

import math
from typing import Callable, Dict, Sequence, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from .features import PreparedGrid
from .verify import landing_box

TAU = 5.0            # pixels: a wall further than this from the other's walls costs the same however far
FRINGE = 1.5         # pixels: walls this close to the other's unknown area are left out (ends of its beams)
MIN_POINTS = 20      # walls needed on the common area for the cost to mean anything
MAX_POINTS = 3000    # walls sampled per grid
FIRST_STEPS = (math.radians(0.5), 1.0)   # rotation (rad) and translation (pixels) steps to start with
LAST_STEP = 0.1      # pixels: stop when the translation step shrinks below this
MAX_MOVES = 80
MARGIN = 10          # pixels around the other grid within which walls are sampled
BOX_MARGIN = 25      # pixels around where the grid lands first within which the fields are read (a polish
                     # moves it a few pixels; beyond this a wall counts as outside the other grid)
START_TURN = math.radians(0.6)   # each placement is polished from itself and from itself turned by this either way


class _OneWay:
    """Walls of `src` against the distance field of `dst`."""

    def __init__(self, src: PreparedGrid, dst: PreparedGrid, model: np.ndarray, rng: np.random.Generator) -> None:
        # only walls that land on dst (with a margin for the moves) can count: a union's walls are mostly elsewhere
        moved = tf.apply(model, src.walls)
        h, w = dst.work.shape
        pick = np.flatnonzero((moved[:, 0] >= -MARGIN) & (moved[:, 1] >= -MARGIN)
                              & (moved[:, 0] < w + MARGIN) & (moved[:, 1] < h + MARGIN))
        if pick.size > MAX_POINTS:
            pick = rng.choice(pick, MAX_POINTS, replace=False)
        # one row of float32 points: OpenCV transforms them and reads the fields at them (bilinear, in one call)
        # 5 times as fast as numpy's indexing; the fields only around where the points land (a union is mostly
        # elsewhere), as float32 (what OpenCV reads)
        self.points = np.ascontiguousarray(src.walls[pick].astype(np.float32).reshape(1, -1, 2))
        box = landing_box(src, dst, model, BOX_MARGIN) if pick.size else None
        if box is None:
            self.points = self.points[:, :0]
            return
        self.x0, self.y0, x1, y1 = box
        self.deep = (dst.known_depth[self.y0:y1, self.x0:x1] > FRINGE).astype(np.float32)
        self.distance = np.minimum(dst.wall_distance[self.y0:y1, self.x0:x1], TAU).astype(np.float32)

    def cost(self, model: np.ndarray) -> Tuple[float, int]:
        if self.points.shape[1] == 0:
            return 0.0, 0
        moved = cv2.transform(self.points, (tf.translation(-self.x0, -self.y0) @ model)[:2].astype(np.float32))
        # outside the field: not deep (left out); the distance is interpolated between pixels (1/32 pixel steps)
        deep = cv2.remap(self.deep, moved, None, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        d = cv2.remap(self.distance, moved, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=TAU)
        n = int(np.count_nonzero(deep))
        return (float(np.dot((d * d).ravel(), deep.ravel())), n) if n else (0.0, 0)


def _cost(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, rng: np.random.Generator
          ) -> Callable[[np.ndarray], float]:
    """The symmetric wall-distance cost of placements of grid i on grid j near `model` (see the module)."""
    forward, backward = _OneWay(pi, pj, model, rng), _OneWay(pj, pi, tf.inverse(model), rng)

    def cost(m: np.ndarray) -> float:
        a, na = forward.cost(m)
        b, nb = backward.cost(tf.inverse(m))
        return (a + b) / (na + nb) if na + nb >= MIN_POINTS else math.inf
    return cost


def polish(pi: PreparedGrid, pj: PreparedGrid, models: Sequence[np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """Of the placements (pixels i -> pixels j) near each of `models` (estimates of one place) with the lowest
    symmetric wall-distance cost, the lowest: on a small common area ICP settles in several nearby minima."""
    cost = _cost(pi, pj, models[0], rng)
    best, best_cost = models[0], math.inf
    for given in models:
        # turn about the middle of i's walls as placed, so that rotation and translation steps are independent
        centre = tf.apply(given, pi.walls).mean(axis=0) if len(pi.walls) else np.zeros(2)
        for turn in (0.0, START_TURN, -START_TURN):
            model = _turned(given, centre, np.array([turn, 0.0, 0.0]))
            found = _turned(model, centre, descend(cost, lambda p, m=model: _turned(m, centre, p)))
            found_cost = cost(found)
            if found_cost < best_cost:
                best, best_cost = found, found_cost
    return best


def slid(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`model` (pixels i -> pixels j) moved, not turned, to the lowest symmetric wall-distance cost nearby: for a
    placement whose angle something other than the shared walls fixed (orientation.aligned, which turns it about the
    middle of a small common area and leaves it shifted)."""
    cost = _cost(pi, pj, model, rng)
    return _turned(model, np.zeros(2), descend(cost, lambda p: _turned(model, np.zeros(2), p),
                                                first_steps=(0.0, FIRST_STEPS[1])))


def _turned(model: np.ndarray, centre: np.ndarray, p: np.ndarray) -> np.ndarray:
    """model followed by a turn of p[0] radians about centre and a shift of (p[1], p[2]) pixels."""
    c, s = math.cos(p[0]), math.sin(p[0])
    step = np.array([[c, -s, centre[0] - c * centre[0] + s * centre[1] + p[1]],
                     [s, c, centre[1] - s * centre[0] - c * centre[1] + p[2]], [0.0, 0.0, 1.0]])
    return step @ model


def descend(cost: Callable[[np.ndarray], float], moved: Callable[[np.ndarray], np.ndarray],
            first_steps: Tuple[float, float] = FIRST_STEPS, max_moves: int = MAX_MOVES) -> np.ndarray:
    """Pattern search from the zero step: the step (rotation, x, y) with the lowest cost, starting with
    `first_steps` (radians, pixels) and halving them until the translation step is below LAST_STEP."""
    known: Dict[tuple, float] = {}

    def cost_at(q: np.ndarray) -> float:
        # a step back to where the search came from is tried again after each move: a sixth of the evaluations
        key = tuple(q)
        if key not in known:
            known[key] = cost(moved(q))
        return known[key]

    best = cost_at(np.zeros(3))
    p = np.zeros(3)
    if not math.isfinite(best):
        return p
    steps = np.array([first_steps[0], first_steps[1], first_steps[1]])
    for _ in range(max_moves):
        for k in range(3):
            for sign in (1.0, -1.0):
                q = p.copy()
                q[k] += sign * steps[k]
                c = cost_at(q)
                if c < best - 1e-9:
                    best, p = c, q
                    break
            else:
                continue
            break
        else:
            steps /= 2.0
            if steps[1] < LAST_STEP:
                break
    return p
