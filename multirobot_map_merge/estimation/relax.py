"""Relaxation: the placed grids refined together, on the walls of every overlapping pair at once (tracking).

Tracking refines each placement against the maps near it. Two robots placed together a few tenths of a degree off
(on early, small maps) hold each other there, and a group that joined the merge as a group stays turned as a whole:
live 12-robot runs kept three robots 0.3-0.45 degrees off (20-28 cm at the far corners of their final maps) for
most of the run, every check passing, until the final maps were estimated afresh. Here every grid but the reference
moves at once, by point-to-line least squares over the walls of every overlapping pair (ICP for all pairs together),
so a turned group is pulled into place by all the walls it shares with the others, not held by its own members.

The result is kept only when the walls of the pairs fit better than before, and only as a refinement: a move larger
than MAX_MOVE_M at a grid's corners means something else is wrong (tracking's checks judge that), and nothing moves.
"""
from __future__ import annotations

import logging
import math
import threading
from concurrent.futures import Executor
from typing import Callable, Dict, Iterable, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import PreparedGrid, opposed_xy
from .orientation import MAX_TURN_DEGREES, orientation
from .union import Box, known_corners, overlap_area

log = logging.getLogger('rosout.multirobot_map_merge.estimation.relax')

RADII = (4.0, 3.0, 2.0)   # pixels: correspondence radius of each level (coarse capture first, as ICP)
ITERATIONS = 3            # at most, per level
MAX_POINTS = 2000         # wall pixels sampled per grid: the walls two groups share are a small part of each
                          # grid, and with 400 a turned group's few shared walls did not hold it
ROBUST_SCALE = 0.125      # of the level's radius: residuals beyond it weigh less (Cauchy). Plain least squares let
                          # walls paired with the wrong wall turn a group further off (a fleet's group of 3 maps from
                          # 0.24 to 0.45 degrees, where the walls fit best at the truth)
MIN_PAIRS = 10            # correspondences a pair needs (one way) to take part in an iteration: the pairs that
                          # bridge two groups overlap little, and without them the groups' own walls decided
FIT_PX = 1.0              # pixels: a wall this close to a wall of the other grid of its pair fits
MAX_PARTNERS = 6          # grids each grid is refined against, those it shares most walls with
CHUNK_POINTS = 50_000     # walls whose correspondences are found in one pass (_PairWalls): 18 MB at the peak
MAX_MOVE_M = 0.5          # metres at a grid's corners: a larger move is no refinement. A group that joined a few
                          # tenths of a degree turned is that far off at the far corners of its grown maps: a live
                          # 12-robot run (seed 1) kept robots 8, 11 and 12 0.3 degrees and 18-26 cm off for 115 s,
                          # every relaxation bringing them within 5 cm refused for moves of 0.21-0.24 m (the limit was
                          # 0.2, for a relaxation without robust weights or directions that had moved an early map of
                          # the rostest under load 0.37 m off; on those maps no relaxation moves one 0.2 m now)


class Limits(NamedTuple):
    """How far and how long a relaxation goes: the largest move kept (metres at a grid's corners), the iterations
    per level at most, and the grids each grid is refined against after the first iteration."""
    max_move_m: float = MAX_MOVE_M
    iterations: int = ITERATIONS
    max_partners: int = MAX_PARTNERS


TRACKING = Limits()   # a live fleet's placements, kept from one estimation to the next (tracking.relax_placed)

# at the end of one estimation of final maps (estimator.relax_group): a group that joined a few tenths of a degree
# turned (maze36 of the generated buildings, seed 2; groups of 4-6 of the demo's final maps turned 0.6 degrees), or a
# group of 9 that joined 0.6 degrees turned over an open atrium (mall36, seed 3), is held by the few walls it shares
# with the rest, which 6 partners a grid left out; it turned back by under a tenth of a degree per iteration
FINAL = Limits(iterations=10, max_partners=12)
STILL_M, STILL_RAD = 0.002, 5e-5   # a step this small ends a level (a tenth of a degree is 1.7e-3 rad)
DIRECTION_NOISE_M = 0.025  # a grid's wall direction off by its standard error weighs as a correspondence (one wall
                           # pixel) off by this. The generated classic36: the directions of 12 maps turn their group
                           # from 0.6 to 0.1 degrees off against the few walls it shares with the rest (0.03 with
                           # 0.05, but then the direction of a small map, 0.1-0.17 degrees off, turned well-fitting
                           # maps of a chain, the chain3 sample, by as much)
PRIOR = 1.0               # weight (in correspondences) keeping a direction no wall constrains where it was


def overlapping_pairs(placed: Sequence[int], footprints: Dict[int, Box], min_area_m2: float = 0.0,
                      key: Optional[Callable[[int], int]] = None) -> List[Tuple[int, int]]:
    """The pairs (a, b), a before b by `key` (by default a < b), of placed grids whose footprints overlap by
    min_area_m2 or more."""
    ks = sorted(placed, key=key)
    return [(a, b) for n, a in enumerate(ks) for b in ks[n + 1:]
            if overlap_area(footprints.get(a), footprints.get(b)) >= min_area_m2]


def _sample(p: PreparedGrid, rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    walls, normals = p.walls, p.wall_normals
    if len(walls) > MAX_POINTS:
        pick = rng.choice(len(walls), MAX_POINTS, replace=False)
        walls, normals = walls[pick], normals[pick]
    return walls, normals


def _draws(seed: int, p: PreparedGrid) -> np.random.Generator:
    """The draws of a grid's sampled walls, by its content (PreparedGrid.draw_key): alike whatever its index."""
    return np.random.default_rng((seed, p.draw_key))


PairSamples = Dict[Tuple[int, int], Tuple[np.ndarray, np.ndarray]]   # each pair (i, j): walls of i and their normals


def _reaching(pairs: Sequence[Tuple[int, int]], samples: Dict[int, Tuple[np.ndarray, np.ndarray]],
              prepared: Sequence[Optional[PreparedGrid]], placed: Dict[int, np.ndarray], reach_px: float,
              pool: Optional[Executor] = None) -> PairSamples:
    """Each pair's sampled walls of grid i that land, as `placed` puts them, within reach_px of a wall of grid j.

    The others can pair with no wall of j while the two grids move less than reach_px (less the correspondence
    radius) relative to each other, and a grid moved further than its limit at its corners is not kept (a rigid
    move is largest at the corners of the known part): most of a grid's walls lie outside the common area of most of
    its pairs (the generated 36-map buildings: 20-25 % of the walls within reach; the dev set's 30 maps, 55 %)."""
    def near(ij: Tuple[int, int]) -> Tuple[np.ndarray, np.ndarray]:
        i, j = ij
        walls, normals = samples[i]
        dst = prepared[j]
        h, w = dst.work.shape
        xy = tf.apply(tf.inverse(placed[j] @ dst.px_to_map) @ placed[i] @ prepared[i].px_to_map, walls)
        inside = np.column_stack([np.clip(xy[:, 0], 0, w - 1), np.clip(xy[:, 1], 0, h - 1)])
        outside = np.hypot(*(xy - inside).T)
        at = np.rint(inside).astype(np.int64)
        # the nearest wall is at least as far as j's known box, and as its nearest wall from the box's edge less the
        # way there; a pixel's distance stands for points within half a pixel's diagonal of it
        bound = np.maximum(outside, dst.wall_distance[at[:, 1], at[:, 0]] - outside - 0.75)
        keep = np.flatnonzero(bound <= reach_px)
        return walls.take(keep, axis=0), normals.take(keep, axis=0)
    return dict(zip(pairs, _each(pool, near, pairs)))


class _PairWalls:
    """The sampled walls of grid i of some pairs (i, j), end to end, the pairs onto one grid j together: their
    correspondences in one pass of numpy operations, not a few dozen calls per pair (the final relaxation of the
    generated radial36, 2,822 pairs' correspondences of up to 2,000 walls each: CPU 1.5-2.0 s pair by pair, 1.4-1.7 s
    so; mall36 0.6-1.0 s, 0.5 s). A relaxation takes its pairs in chunks of CHUNK_POINTS walls (_chunks), one at a
    time: all at once, their walls and temporaries took 200 MB at the peak (pair by pair 2 MB, in chunks 18 MB)."""

    def __init__(self, pairs: Sequence[Tuple[int, int]], samples: PairSamples):
        self.pairs = list(pairs)
        order = sorted(range(len(self.pairs)), key=lambda n: self.pairs[n][1])
        sizes = np.array([len(samples[self.pairs[n]][0]) for n in order], np.int64)
        self.pair_of = np.repeat(np.asarray(order, np.int64), sizes)
        parts = [samples[self.pairs[n]] for n in order]
        self.points = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, 2))
        self.sides = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, 2))
        self.onto: List[Tuple[int, int, int]] = []   # (grid j, start, stop): the points placed onto grid j
        stops = np.cumsum(sizes)
        for n, start, stop in zip(order, stops - sizes, stops):
            j = self.pairs[n][1]
            if self.onto and self.onto[-1][0] == j:
                self.onto[-1] = (j, self.onto[-1][1], int(stop))
            else:
                self.onto.append((j, int(start), int(stop)))

    def correspondences(self, models: np.ndarray, prepared: Sequence[Optional[PreparedGrid]], radius: float):
        """With models[n] placing the pixels of pair n's grid i into the pixels of its grid j: each wall of i paired
        with j's nearest wall seen from the same side within `radius`, as (pair index, i's wall, j's wall, j's unit
        normal there), pixels of j."""
        a, b, c, d, e, f = _coefficients(models, self.pair_of)
        x, y = self.points[:, 0], self.points[:, 1]
        moved = np.column_stack([a * x + b * y + c, d * x + e * y + f])
        xy = np.rint(moved).astype(np.int64)
        at, nearest, normals = [], [], []
        for j, start, stop in self.onto:
            dst = prepared[j]
            h, w = dst.work.shape
            px, py = xy[start:stop, 0], xy[start:stop, 1]
            # flat `take`s, and a negative coordinate fails the bound as a huge unsigned one (as ICP)
            inside = np.flatnonzero((px.view(np.uint64) < w) & (py.view(np.uint64) < h))
            wall = dst.nearest_wall.reshape(-1).take(py.take(inside) * w + px.take(inside))
            found = np.flatnonzero(wall >= 0)
            wall = wall.take(found)
            at.append(start + inside.take(found))
            nearest.append(dst.walls.take(wall, axis=0))
            normals.append(dst.wall_normals.take(wall, axis=0))
        if not at:
            return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2))
        at, nearest, normals = np.concatenate(at), np.concatenate(nearest), np.concatenate(normals)
        gap = nearest - moved.take(at, axis=0)
        close = np.flatnonzero(gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1] <= radius * radius)
        at, nearest, normals = at.take(close), nearest.take(close, axis=0), normals.take(close, axis=0)
        a, b, d, e = (v.take(at) for v in (a, b, d, e))
        sides = self.sides.take(at, axis=0)
        sx, sy = sides[:, 0], sides[:, 1]
        nx, ny = normals[:, 0], normals[:, 1]
        length = np.hypot(nx, ny)
        # a wall's two faces are not one wall; a wall pixel with no free side has no normal
        keep = np.flatnonzero((length > 1e-3) & ~opposed_xy(a * sx + b * sy, d * sx + e * sy, nx, ny))
        at = at.take(keep)
        return (self.pair_of.take(at), moved.take(at, axis=0), nearest.take(keep, axis=0),
                normals.take(keep, axis=0) / length.take(keep)[:, None])

    def models(self, prepared: Sequence[Optional[PreparedGrid]], placed: Dict[int, np.ndarray]) -> np.ndarray:
        """Each pair's transform from the pixels of its grid i to those of its grid j, as `placed` puts them."""
        return np.array([tf.inverse(placed[j] @ prepared[j].px_to_map) @ placed[i] @ prepared[i].px_to_map
                         for i, j in self.pairs]).reshape(-1, 3, 3)


def _coefficients(models: np.ndarray, of: np.ndarray) -> Tuple[np.ndarray, ...]:
    """The six coefficients of the affine part of models[of[n]], each as an array over n."""
    return tuple(models[:, row, col].take(of) for row in (0, 1) for col in (0, 1, 2))


def _chunks(pairs: Sequence[Tuple[int, int]], samples: PairSamples) -> List[List[Tuple[int, int]]]:
    """The pairs in chunks of about CHUNK_POINTS walls (a pair is never split), the pairs onto one grid together."""
    out: List[List[Tuple[int, int]]] = []
    size = 0
    for ij in sorted(pairs, key=lambda ij: ij[1]):
        if not out or size + len(samples[ij][0]) > CHUNK_POINTS:
            out.append([])
            size = 0
        out[-1].append(ij)
        size += len(samples[ij][0])
    return out


def _each(pool: Optional[Executor], f: Callable, items: Sequence) -> Iterable:
    """f of each item, in their order: on the threads of `pool` if there is one."""
    return pool.map(f, items) if pool is not None else map(f, items)


def _fits(chunks: List[List[Tuple[int, int]]], samples: PairSamples,
          prepared: Sequence[Optional[PreparedGrid]], placed: Dict[int, np.ndarray],
          pool: Optional[Executor] = None) -> int:
    """Walls, over every pair, within FIT_PX of a wall of the other grid seen from the same side."""
    def fitting(chunk: List[Tuple[int, int]]) -> int:
        walls = _PairWalls(chunk, samples)
        return len(walls.correspondences(walls.models(prepared, placed), prepared, FIT_PX)[0])
    return sum(_each(pool, fitting, chunks))


def walls_fitting(placements: Sequence[Dict[int, np.ndarray]], prepared: Sequence[Optional[PreparedGrid]],
                  pairs: Sequence[Tuple[int, int]], seed: int = 0) -> List[int]:
    """For each set of placements (grid -> metric transform, one frame), the walls of the given pairs that fit (as
    relax counts them, on the same sampled walls): which of several estimates of the same maps fits them better."""
    samples = {k: _sample(prepared[k], _draws(seed, prepared[k])) for k in {k for ij in pairs for k in ij}}
    of_pairs = {ij: samples[ij[0]] for ij in pairs}
    chunks = _chunks(pairs, of_pairs)
    return [_fits(chunks, of_pairs, prepared, placed) for placed in placements]


def _normal_equations(pair: np.ndarray, p: np.ndarray, q: np.ndarray, n: np.ndarray, walls: _PairWalls,
                      prepared: Sequence[Optional[PreparedGrid]], out: Dict[int, np.ndarray],
                      centre: Dict[int, np.ndarray], column: Dict[int, int], h: np.ndarray, g: np.ndarray,
                      radius: float) -> None:
    """Add to (h, g) the pairs' point-to-line terms (correspondences from _PairWalls.correspondences, pixels of j):
    the residual along j's wall normal in the merged frame (metres), Cauchy weighted, and its derivatives by a small
    shift and turn of grid i (about its centre) and of grid j."""
    frames = np.array([out[j] @ prepared[j].px_to_map for _, j in walls.pairs])
    a, b, c, d, e, f = _coefficients(frames, pair)
    px, py = a * p[:, 0] + b * p[:, 1] + c, d * p[:, 0] + e * p[:, 1] + f
    qx, qy = a * q[:, 0] + b * q[:, 1] + c, d * q[:, 0] + e * q[:, 1] + f
    nx, ny = a * n[:, 0] + b * n[:, 1], d * n[:, 0] + e * n[:, 1]
    length = np.hypot(nx, ny)
    nx, ny = nx / length, ny / length
    r = (px - qx) * nx + (py - qy) * ny
    scale = ROBUST_SCALE * radius * np.sqrt(np.abs(np.linalg.det(frames[:, :2, :2])))
    w = 1.0 / (1.0 + (r / scale.take(pair)) ** 2)
    centres = np.array([[centre[i], centre[j]] for i, j in walls.pairs]).reshape(-1, 4)
    turn_i = (px - centres[:, 0].take(pair)) * ny - (py - centres[:, 1].take(pair)) * nx
    turn_j = (qx - centres[:, 2].take(pair)) * ny - (qy - centres[:, 3].take(pair)) * nx
    # each run of one pair's correspondences (_PairWalls keeps a pair's walls end to end): the sums of the weighted
    # products of (nx, ny, turn_i, turn_j) with (nx, ny, turn_i, turn_j, r), in one pass, not a call per product
    # and a loop per pair (the final relaxation of the generated radial36, serially: these terms 0.48 -> 0.29 s)
    rows = np.stack([nx, ny, turn_i, turn_j, r])
    runs = np.flatnonzero(np.diff(pair)) + 1
    runs = np.concatenate([[0], runs]) if pair.size else runs
    sums = np.add.reduceat((rows[:4, None, :] * w * rows[None, :, :]).reshape(20, -1), runs, axis=1)
    sums = sums.reshape(4, 5, -1).transpose(2, 0, 1)   # run, (x, y, turn_i, turn_j), (x, y, turn_i, turn_j, r)
    square = np.triu(sums[:, :, :4])
    square = square + np.triu(square, 1).transpose(0, 2, 1)   # the upper triangle's sums, mirrored
    ks = pair.take(runs)
    ci = np.array([column.get(walls.pairs[k][0], -1) for k in ks], np.int64)
    cj = np.array([column.get(walls.pairs[k][1], -1) for k in ks], np.int64)
    own_i, own_j = [0, 1, 2], [0, 1, 3]   # grid i moves by (x, y, turn_i), grid j by (x, y, turn_j)
    blocks = [(ci, ci, square[:, own_i][:, :, own_i]), (cj, cj, square[:, own_j][:, :, own_j])]
    cross = -square[:, own_i][:, :, own_j]
    both = (ci >= 0) & (cj >= 0)
    blocks += [(ci[both], cj[both], cross[both]), (cj[both], ci[both], cross[both].transpose(0, 2, 1))]
    size = len(g)
    three = np.arange(3)
    flat, values = [], []
    for r0, c0, block in blocks:
        moving = r0 >= 0   # the reference grid (no column) stays
        rr = r0[moving, None, None] + three[None, :, None]
        cc = c0[moving, None, None] + three[None, None, :]
        flat.append((rr * size + cc).ravel())
        values.append(block[moving].ravel())
    h += np.bincount(np.concatenate(flat), np.concatenate(values), minlength=size * size).reshape(size, size)
    # the gradient: (x r, y r, turn_i r) for grid i, less (x r, y r, turn_j r) for grid j
    moving_i, moving_j = ci >= 0, cj >= 0
    at = np.concatenate([(ci[moving_i, None] + three).ravel(), (cj[moving_j, None] + three).ravel()])
    gradient = np.concatenate([sums[moving_i][:, own_i, 4].ravel(), -sums[moving_j][:, own_j, 4].ravel()])
    g += np.bincount(at, gradient, minlength=size)


class _Directions:
    """The grids' wall directions (orientation.py) as terms of the relaxation: each grid's direction, placed, meets the
    building's (one more unknown, modulo 90 degrees), weighted by how precisely it is known. A group bridged to the
    rest by a small common area is held there only loosely by the walls, which may turn it by most of a degree (the
    generated classic36: 12 maps 0.84 degrees off); the directions of its maps, all together, turn it back. A grid
    whose direction is off by more than orientation.MAX_TURN_DEGREES (a wing of another direction) takes no part."""

    def __init__(self, placed: Dict[int, np.ndarray], reference: int, prepared: Sequence[Optional[PreparedGrid]],
                 at: int, pool: Optional[Executor] = None):
        ks = [k for k in placed if prepared[k] is not None]
        self.of = {k: o for k, o in zip(ks, _each(pool, lambda k: orientation(prepared[k]), ks)) if o is not None}
        self.at = at   # the building's direction: its row and column in the normal equations
        self.unknowns = 1 if len(self.of) >= 2 else 0
        self.building = None
        if self.unknowns:
            first = reference if reference in self.of else min(self.of)
            self.building = self._placed(first, placed[first], prepared)

    def _placed(self, k: int, t: np.ndarray, prepared: Sequence[Optional[PreparedGrid]]) -> float:
        m = t @ prepared[k].px_to_map
        return self.of[k].angle + math.atan2(m[1, 0], m[0, 0])

    def add(self, out: Dict[int, np.ndarray], prepared: Sequence[Optional[PreparedGrid]], column: Dict[int, int],
            h: np.ndarray, g: np.ndarray) -> None:
        if not self.unknowns:
            return
        d = self.at
        for k in self.of:
            r = (self._placed(k, out[k], prepared) - self.building + math.pi / 4) % (math.pi / 2) - math.pi / 4
            if abs(r) > math.radians(MAX_TURN_DEGREES):
                continue
            w = (DIRECTION_NOISE_M / self.of[k].sigma) ** 2
            h[d, d] += w
            g[d] -= w * r
            c = column.get(k)
            if c is not None:
                h[c + 2, c + 2] += w
                h[c + 2, d] -= w
                h[d, c + 2] -= w
                g[c + 2] += w * r

    def step(self, step: np.ndarray) -> None:
        if self.unknowns:
            self.building += float(step[self.at])


def relax(placed: Dict[int, np.ndarray], reference: int, grids: Sequence[Optional[Grid]],
          prepared: Sequence[Optional[PreparedGrid]], footprints: Dict[int, Box],
          min_overlap_m2: float = 0.0, seed: int = 0, limits: Limits = TRACKING,
          pool: Optional[Executor] = None) -> Optional[Dict[int, np.ndarray]]:
    """The placements (grid -> metric transform into the reference's frame) refined together, the reference fixed;
    None when they stay as they are (no pair to refine on, no better fit, or a move beyond limits.max_move_m at the
    corners of a grid's known part). Pairs whose footprints share less than `min_overlap_m2` (the common area a match
    needs) hold too little of each other's walls to count. The chunks of pairs of an iteration are shared among the
    threads of `pool`, each adding its own terms: numpy's array operations release the GIL (the final relaxation of
    large30 and radial36: 25-35 % less wall time, 5-20 % more CPU)."""
    moving = [k for k in placed if k != reference and prepared[k] is not None]
    pairs = overlapping_pairs([k for k in placed if prepared[k] is not None], footprints, min_overlap_m2,
                              key=lambda k: prepared[k].draw_key)
    if not moving or not pairs:
        return None
    samples = {k: _sample(prepared[k], _draws(seed, prepared[k])) for k in placed if prepared[k] is not None}
    idle: set = set()   # pairs with too few of i's walls near j's at the widest radius, none nearer later
    column = {k: 3 * n for n, k in enumerate(moving)}
    directions = _Directions(placed, reference, prepared, len(column) * 3, pool)
    out = {k: np.asarray(t, float).copy() for k, t in placed.items()}
    first = True              # the first iteration: every pair, and the correspondences of each counted
    # each of a pair may move limits.max_move_m at most; every grid is at the working resolution
    reaching = _reaching(pairs, samples, prepared, placed,
                         RADII[0] + 2 * limits.max_move_m / prepared[moving[0]].resolution, pool)
    fitted = _chunks(pairs, reaching)   # every pair judges the result
    chunks = fitted           # the pairs refined on, as long as no more go idle
    before = 0                # walls fitting at the placements given, over the pairs fitted
    held = threading.local()  # each thread's last chunk's arrays (see terms)
    for radius in RADII:
        for _ in range(limits.iterations):
            # the walls' centre of each grid in the merged frame: turns about it keep the system well conditioned
            centre = {k: tf.apply(out[k] @ prepared[k].px_to_map, samples[k][0]).mean(axis=0) for k in samples}
            h = PRIOR * np.eye(3 * len(moving) + directions.unknowns)
            g = np.zeros(3 * len(moving) + directions.unknowns)
            directions.add(out, prepared, column, h, g)
            counted: Dict[Tuple[int, int], int] = {}

            def terms(chunk: List[Tuple[int, int]]) -> Tuple[list, int, np.ndarray, np.ndarray]:
                # one chunk's pairs: their counts, the walls fitting before, their normal equations
                walls = _PairWalls(chunk, reaching)
                # one way per pair (i's walls onto j's, j's normals): the pair's other way adds little but the time
                pair, p, q, n = walls.correspondences(walls.models(prepared, out), prepared, radius)
                count = np.bincount(pair, minlength=len(walls.pairs))
                fitting = 0
                if first:
                    # the walls fitting before (_fits) are those of these within FIT_PX: the same pairs, the same test
                    gap = q - p
                    fitting = int(np.count_nonzero(gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1] <= FIT_PX * FIT_PX))
                hc, gc = np.zeros_like(h), np.zeros_like(g)
                use = np.flatnonzero(count.take(pair) >= MIN_PAIRS)
                if use.size:
                    _normal_equations(pair.take(use), p.take(use, axis=0), q.take(use, axis=0), n.take(use, axis=0),
                                      walls, prepared, out, centre, column, hc, gc, radius)
                # kept until this thread's next chunk: freed at once, they left the heap's top free, which the
                # allocator gave back and faulted in again for the next chunk (8 times the page faults; large30's
                # relaxation 1.1 -> 1.7 s)
                held.last = walls, pair, p, q, n
                return list(zip(walls.pairs, count.tolist())), fitting, hc, gc

            for counts, fitting, hc, gc in _each(pool, terms, chunks):
                counted.update(counts)
                before += fitting
                h += hc
                g += gc
            refined = [ij for ij in pairs if ij in counted]   # in the order of `pairs`
            if radius == RADII[0]:
                idle.update(ij for ij in refined if counted[ij] < MIN_PAIRS)
            active = [ij for ij in refined if ij not in idle]
            if first:
                # from here on each grid is refined against the few grids it shares most walls with: a fleet's
                # large maps all overlap (30 robots of a hospital: 432 pairs), and the others add time, not accuracy
                first = False
                found = {ij: counted[ij] for ij in refined if counted[ij] >= MIN_PAIRS}
                ranked = sorted(found, key=lambda ij: -found[ij])
                kept: Dict[int, int] = {}
                strong = set()
                for i, j in ranked:
                    if kept.get(i, 0) < limits.max_partners or kept.get(j, 0) < limits.max_partners:
                        strong.add((i, j))
                        kept[i], kept[j] = kept.get(i, 0) + 1, kept.get(j, 0) + 1
                active = [ij for ij in active if ij in strong]
            if len(active) < len(refined):
                chunks = _chunks(active, reaching)
            step = -np.linalg.solve(h, g)
            for k, c in column.items():
                dx, dy, dt = step[c:c + 3]
                cx, cy = centre[k]
                out[k] = tf.translation(cx + dx, cy + dy) @ tf.rigid(0.0, 0.0, dt) @ tf.translation(-cx, -cy) @ out[k]
            directions.step(step)
            if np.abs(step[0::3]).max(initial=0) < STILL_M and np.abs(step[1::3]).max(initial=0) < STILL_M \
                    and np.abs(step[2::3]).max(initial=0) < STILL_RAD:
                break
    moved = max(tf.difference(out[k], placed[k], known_corners(grids[k]))[1] for k in moving)
    after = _fits(fitted, reaching, prepared, out, pool)
    if moved > limits.max_move_m or after <= before:
        log.debug('relaxation not kept: walls fitting %d -> %d, moved up to %.2f m', before, after, moved)
        return None
    log.debug('relaxed %d placements on %d of %d pairs: walls fitting %d -> %d, moved up to %.3f m', len(moving),
              sum(map(len, chunks)), len(pairs), before, after, moved)
    return out
