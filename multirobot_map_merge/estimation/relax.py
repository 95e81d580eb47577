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
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import PreparedGrid, opposed
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
MAX_MOVE_M = 0.2          # metres at a grid's corners: a larger move is no refinement (with 0.5, six early demo
                          # maps under load had a right placement moved 0.37 m off, in 1 of 3 runs of the rostest)


class Limits(NamedTuple):
    """How far and how long a relaxation goes: the largest move kept (metres at a grid's corners), the iterations
    per level at most, and the grids each grid is refined against after the first iteration."""
    max_move_m: float = MAX_MOVE_M
    iterations: int = ITERATIONS
    max_partners: int = MAX_PARTNERS


# at the end of one estimation of final maps (estimator.relax_group): a group that joined a few tenths of a degree
# turned moves further (maze36 of the generated buildings, seed 2: 0.26 m put four maps 3.3-3.9 cells off right;
# groups of 4-6 of the demo's final maps turned 0.6 degrees: 0.29-0.42 m), and a group of 9 that joined 0.6 degrees
# turned over an open atrium (mall36, seed 3) is held by the few walls it shares with the rest, which 6 partners a grid
# left out; it turned back by under a tenth of a degree per iteration
FINAL = Limits(max_move_m=0.5, iterations=10, max_partners=12)
STILL_M, STILL_RAD = 0.002, 5e-5   # a step this small ends a level (a tenth of a degree is 1.7e-3 rad)
PRIOR = 1.0               # weight (in correspondences) keeping a direction no wall constrains where it was


def overlapping_pairs(placed: Sequence[int], footprints: Dict[int, Box],
                      min_area_m2: float = 0.0) -> List[Tuple[int, int]]:
    """The pairs (a, b), a < b, of placed grids whose footprints overlap by min_area_m2 or more."""
    ks = sorted(placed)
    return [(a, b) for n, a in enumerate(ks) for b in ks[n + 1:]
            if overlap_area(footprints.get(a), footprints.get(b)) >= min_area_m2]


def _sample(p: PreparedGrid, rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    walls, normals = p.walls, p.wall_normals
    if len(walls) > MAX_POINTS:
        pick = rng.choice(len(walls), MAX_POINTS, replace=False)
        walls, normals = walls[pick], normals[pick]
    return walls, normals


def _correspondences(src: Tuple[np.ndarray, np.ndarray], dst: PreparedGrid, model: np.ndarray, radius: float):
    """src walls (pixels of their grid) placed by `model` into dst's pixels, paired with dst's nearest wall seen from
    the same side within `radius`: (src points, dst points, dst unit normals), dst pixels."""
    points, sides = src
    moved = tf.apply(model, points)
    h, w = dst.work.shape
    xy = np.rint(moved).astype(np.int64)
    x, y = xy[:, 0], xy[:, 1]
    # flat `take`s, and a negative coordinate fails the bound as a huge unsigned one (as ICP: the relaxation pairs
    # every two overlapping grids, 432 pairs of 30 maps, and this was most of its time)
    inside = np.flatnonzero((x.view(np.uint64) < w) & (y.view(np.uint64) < h))
    wall = dst.nearest_wall.reshape(-1).take(y.take(inside) * w + x.take(inside))
    found = np.flatnonzero(wall >= 0)
    inside, wall = inside.take(found), wall.take(found)
    nn = dst.walls.take(wall, axis=0)
    gap = nn - moved.take(inside, axis=0)
    dx, dy = gap[:, 0], gap[:, 1]
    close = np.flatnonzero(dx * dx + dy * dy <= radius * radius)
    inside, wall, nn = inside.take(close), wall.take(close), nn.take(close, axis=0)
    normals = dst.wall_normals.take(wall, axis=0)
    length = np.hypot(normals[:, 0], normals[:, 1])
    # a wall's two faces are not one wall; a wall pixel with no free side has no normal
    keep = np.flatnonzero((length > 1e-3) & ~opposed(sides.take(inside, axis=0) @ model[:2, :2].T, normals))
    inside, nn, normals = inside.take(keep), nn.take(keep, axis=0), normals.take(keep, axis=0)
    return moved.take(inside, axis=0), nn, normals / length.take(keep)[:, None]


def _weights(residuals: np.ndarray, frame: np.ndarray, radius: float) -> np.ndarray:
    """Cauchy weights of point-to-line residuals (metres) at a level of correspondence radius `radius` (pixels of
    `frame`, a grid's pixels -> metres)."""
    scale = ROBUST_SCALE * radius * np.sqrt(abs(np.linalg.det(frame[:2, :2])))
    return 1.0 / (1.0 + (residuals / scale) ** 2)


def _fits(pairs, samples, prepared, placed) -> int:
    """Walls, over every pair, within FIT_PX of a wall of the other grid seen from the same side."""
    n = 0
    for i, j in pairs:
        model = tf.inverse(prepared[j].px_to_map) @ tf.inverse(placed[j]) @ placed[i] @ prepared[i].px_to_map
        n += len(_correspondences(samples[i], prepared[j], model, FIT_PX)[0])
    return n


def relax(placed: Dict[int, np.ndarray], reference: int, grids: Sequence[Optional[Grid]],
          prepared: Sequence[Optional[PreparedGrid]], footprints: Dict[int, Box],
          min_overlap_m2: float = 0.0, seed: int = 0, limits: Limits = Limits()) -> Optional[Dict[int, np.ndarray]]:
    """The placements (grid -> metric transform into the reference's frame) refined together, the reference fixed;
    None when they stay as they are (no pair to refine on, no better fit, or a move beyond limits.max_move_m at the
    corners of a grid's known part). Pairs whose footprints share less than `min_overlap_m2` (the common area a match
    needs) hold too little of each other's walls to count."""
    moving = [k for k in placed if k != reference and prepared[k] is not None]
    pairs = overlapping_pairs([k for k in placed if prepared[k] is not None], footprints, min_overlap_m2)
    if not moving or not pairs:
        return None
    rng = np.random.default_rng(seed)
    samples = {k: _sample(prepared[k], rng) for k in placed if prepared[k] is not None}
    idle: set = set()   # pairs with too few of i's walls near j's at the widest radius, none nearer later
    to_px = {k: tf.inverse(prepared[k].px_to_map) for k in samples}
    column = {k: 3 * n for n, k in enumerate(moving)}
    out = {k: np.asarray(t, float).copy() for k, t in placed.items()}
    first, found = True, {}   # the first iteration: correspondences of each pair
    fitted = list(pairs)      # every pair judges the result
    before = 0                # walls fitting at the placements given, over the pairs fitted
    for radius in RADII:
        for _ in range(limits.iterations):
            # the walls' centre of each grid in the merged frame: turns about it keep the system well conditioned
            centre = {k: tf.apply(out[k] @ prepared[k].px_to_map, samples[k][0]).mean(axis=0) for k in samples}
            back = {k: tf.inverse(out[k]) for k in samples}
            h = PRIOR * np.eye(3 * len(moving))
            g = np.zeros(3 * len(moving))
            # one way per pair (i's walls onto j's, j's normals): the pair's other way adds little but the time
            for i, j in pairs:
                if (i, j) in idle:
                    continue
                model = to_px[j] @ back[j] @ out[i] @ prepared[i].px_to_map
                p, q, n = _correspondences(samples[i], prepared[j], model, radius)
                if first:
                    # the walls fitting before (_fits) are those of these within FIT_PX: the same pairs, the same test
                    gap = q - p
                    before += int(np.count_nonzero(gap[:, 0] * gap[:, 0] + gap[:, 1] * gap[:, 1] <= FIT_PX * FIT_PX))
                if len(p) < MIN_PAIRS:
                    if radius == RADII[0]:
                        idle.add((i, j))
                    continue
                if first:
                    found[(i, j)] = len(p)
                # into the merged frame (metres): the residual along j's wall normal, and its derivatives by a
                # small shift and turn of grid i (about its centre) and of grid j
                frame = out[j] @ prepared[j].px_to_map
                p, q = tf.apply(frame, p), tf.apply(frame, q)
                n = n @ frame[:2, :2].T
                n /= np.hypot(n[:, 0], n[:, 1])[:, None]
                r = ((p - q) * n).sum(axis=1)
                w = _weights(r, frame, radius)
                at, jacobians = [], []
                for k, on, sign in ((i, p, 1.0), (j, q, -1.0)):
                    if k in column:
                        rel = on - centre[k]
                        at.append(column[k])
                        jacobians.append(sign * np.column_stack([n[:, 0], n[:, 1],
                                                                 rel[:, 0] * n[:, 1] - rel[:, 1] * n[:, 0]]))
                # the pair's block of the normal equations in one product
                jac = np.hstack(jacobians) if len(jacobians) > 1 else jacobians[0]
                hb, gb = jac.T @ (w[:, None] * jac), jac.T @ (w * r)
                for a, ca in enumerate(at):
                    g[ca:ca + 3] += gb[3 * a:3 * a + 3]
                    for b, cb in enumerate(at):
                        h[ca:ca + 3, cb:cb + 3] += hb[3 * a:3 * a + 3, 3 * b:3 * b + 3]
            if first:
                # from here on each grid is refined against the few grids it shares most walls with: a fleet's
                # large maps all overlap (30 robots of a hospital: 432 pairs), and the others add time, not accuracy
                first = False
                ranked = sorted(found, key=lambda ij: -found[ij])
                kept: Dict[int, int] = {}
                strong = set()
                for i, j in ranked:
                    if kept.get(i, 0) < limits.max_partners or kept.get(j, 0) < limits.max_partners:
                        strong.add((i, j))
                        kept[i], kept[j] = kept.get(i, 0) + 1, kept.get(j, 0) + 1
                pairs = [ij for ij in pairs if ij in strong]
            step = -np.linalg.solve(h, g)
            for k, c in column.items():
                dx, dy, dt = step[c:c + 3]
                cx, cy = centre[k]
                out[k] = tf.translation(cx + dx, cy + dy) @ tf.rigid(0.0, 0.0, dt) @ tf.translation(-cx, -cy) @ out[k]
            if np.abs(step[0::3]).max(initial=0) < STILL_M and np.abs(step[1::3]).max(initial=0) < STILL_M \
                    and np.abs(step[2::3]).max(initial=0) < STILL_RAD:
                break
    moved = max(tf.difference(out[k], placed[k], known_corners(grids[k]))[1] for k in moving)
    after = _fits(fitted, samples, prepared, out)
    if moved > limits.max_move_m or after <= before:
        log.debug('relaxation not kept: walls fitting %d -> %d, moved up to %.2f m', before, after, moved)
        return None
    log.debug('relaxed %d placements on %d of %d pairs: walls fitting %d -> %d, moved up to %.3f m', len(moving),
              len(pairs), len(fitted), before, after, moved)
    return out
