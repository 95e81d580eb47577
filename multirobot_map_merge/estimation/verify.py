"""Verification and the acceptance rules: does a placement of grid i on grid j deserve trust?

Walls of one map must lie on walls of the other wherever both are known (`verify`). A pair is accepted only when
its best placement agrees well, overlaps enough, has enough support, (almost) never contradicts well inside both
maps' views, and is pinned down precisely enough by the walls the maps share (precision.py); pair.py adds that no
clearly different placement may agree almost as well (symmetric buildings make such aliases; a guess there would
be a wrong merge).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from .features import PreparedGrid, nonzero_2d, opposed
from .orientation import angle_bound
from .precision import corner_error, corners_of
from .validation import must_be_positive, must_not_be_negative

if TYPE_CHECKING:
    from .settings import EstimationSettings

FOUND_AGREEMENT = 0.6   # see overlap_found
SAME_PLACE_PX = 1.0     # placements that move no corner of grid i further apart than this are one estimate
RING_PX = 3               # pixels around a piece of wall that tell whether its map saw it amid free floor
MOVABLE_FREE_SHARE = 0.75  # of that ring free: a wall face has its unknown behind it (about half)


@dataclass
class AcceptanceSettings:
    confidence: float = 1.0           # inliers / (8 + 0.3 matches) a pair needs, as the original (see pair_confidence)
    verify_tolerance: float = 2.0     # pixels: a wall "agrees" when the other map has a wall this close
    min_agreement: float = 0.91       # share of walls in the common area that agree (fringe ones aside)
    min_overlap_m2: float = 4.0       # common known area a pair needs
    min_support: int = 100            # agreeing wall pixels a pair needs
    deep_conflict_m: float = 0.2      # a contradicting wall this far inside the other map's view is not at its fringe
    max_deep_conflicts: float = 0.01  # structural ones a pair tolerates, as a share of its agreeing walls
    movable_size_m: float = 1.0       # a deep contradiction in a free-standing piece no longer than this (a person,
                                      # a chair, a cart) moved between two passes of a real building (free_standing)
    max_movable_conflicts: float = 0.05  # those a pair tolerates, as a share of its agreeing walls
    gap_size_m: float = 2.0           # a deep contradiction in a piece of wall no longer than this, in line with walls
                                      # both maps agree on at both its ends: a door shut in one pass, glass one laser
                                      # saw (in_gap)
    max_gap_conflicts: float = 0.01   # those a pair tolerates, as a share of its agreeing walls (a few doors; a
                                      # corridor shifted by a door's spacing fills many gaps)
    max_corner_error_m: float = 0.25  # refuse placements the shared walls leave this uncertain at a far corner
    fringe_px: float = 1.5            # pixels: contradictions this close to the other's unknown area do not count
    conflict_weight: float = 10.0     # placements score support - conflict_weight * conflicts (Placement.score, .rank)
    ambiguity_ratio: float = 0.8      # a distinct placement with this share of the best score -> ambiguous
    distinct_degrees: float = 5.0     # placements further apart than this are distinct
    distinct_metres: float = 1.0

    def validate(self) -> None:
        must_be_positive(self, 'verify_tolerance')
        if not 0.0 <= self.min_agreement <= 1.0:
            raise ValueError(f'min_agreement must be in [0, 1], not {self.min_agreement}')
        must_not_be_negative(self, 'deep_conflict_m', 'max_deep_conflicts', 'fringe_px', 'max_corner_error_m',
                             'movable_size_m', 'max_movable_conflicts', 'gap_size_m', 'max_gap_conflicts')
        if self.confidence != self.confidence:
            raise ValueError('confidence must be a number, not NaN')


@dataclass
class Placement:
    """A candidate rigid transform from pixels of grid i to pixels of grid j, with its verification figures."""
    transform: np.ndarray
    support: int = 0            # wall pixels (of both maps) that lie on a wall of the other map
    agreement: float = 0.0      # support / (support + conflicts other than fringe_conflicts)
    overlap_m2: float = 0.0     # common known area
    conflicts: int = 0          # wall pixels in the common known area with no wall of the other map near them
    opposed: int = 0            # wall pixels near a wall of the other map that was seen from the other side
    deep_conflicts: int = 0     # conflicts well inside the other map's known area, not at the fringe of its view
    movable_conflicts: int = 0  # of those, the ones in small pieces (movable_size_m): moved objects, not structure
    gap_conflicts: int = 0      # and the others in a gap of the other map's wall (gap_size_m): a door, glass
                                # (both counted only where it decides: see verify)
    fringe_conflicts: int = 0   # conflicts at the fringe of the other map's view (the ends of its beams)
    corner_error_m: float = 0.0  # expected error at the far corners of either map (precision.py); best only

    def score(self, conflict_weight: float) -> float:
        """Support less weighted conflicts: a shifted alias in a repetitive building overlaps more (more support)
        but also contradicts more than the right placement, which contradicts almost nowhere."""
        return self.support - conflict_weight * self.conflicts

    def rank(self, conflict_weight: float) -> float:
        """The score without the conflicts at the fringe of the other map's view, which the agreement leaves out
        too: which of two distinct places that pass the rules is the better (pair.match_pair; between estimates of
        one place the score chooses). The larger the common area, the more beam ends it holds, and by the score an
        alias that overlaps less could outrank the truth: held-out warehouse36_u with seed 2, map_32 onto a merge,
        the truth agreed 0.995 with support 2375 over 158 m2 and an alias 3.9 m along the racks 0.995 with 2025 over
        142 m2, 226 and 128 conflicts at the fringe; the alias scored 645 against -15, was taken, and two maps were
        placed wrong. The score still judges whether another place is as good (pair.as_good)."""
        return self.support - conflict_weight * (self.conflicts - self.fringe_conflicts)


def source_pixels(pi: PreparedGrid, model: np.ndarray, xs: np.ndarray, ys: np.ndarray):
    """(x, y, inside): the pixels of grid i that `model` (i -> j) puts at pixels (xs, ys) of grid j, clipped to
    grid i, and whether they were inside it."""
    back = np.rint(tf.apply(tf.inverse(model), np.column_stack([xs, ys]))).astype(np.int64)
    h, w = pi.work.shape
    inside = (back[:, 0] >= 0) & (back[:, 1] >= 0) & (back[:, 0] < w) & (back[:, 1] < h)
    return np.clip(back[:, 0], 0, w - 1), np.clip(back[:, 1], 0, h - 1), inside


MARGIN = 8   # pixels around the common known area kept for the distance and side fields


def landing_box(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, margin: int) -> Optional[Tuple[int, ...]]:
    """(x0, y0, x1, y1): the pixels of grid j that grid i covers when placed by `model`, widened by `margin` and
    clipped to grid j; None if it misses grid j."""
    h, w = pj.work.shape
    ph, pw = pi.work.shape
    corners = tf.apply(model, np.array([[-1.0, -1.0], [pw, -1.0], [-1.0, ph], [pw, ph]]))
    x0, y0 = (max(int(math.floor(v)) - margin, 0) for v in corners.min(axis=0))
    x1, y1 = (min(int(math.ceil(v)) + margin + 1, n) for v, n in zip(corners.max(axis=0), (w, h)))
    return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None


def warp_into(image: np.ndarray, model: np.ndarray, box: Tuple[int, ...], border: int = 0) -> np.ndarray:
    """A uint8 image of grid i's pixels placed by `model` (nearest neighbour) into the pixels `box` of grid j
    (landing_box): a union is mostly elsewhere, so only that box is warped."""
    x0, y0, x1, y1 = box
    return cv2.warpAffine(image, (tf.translation(-x0, -y0) @ model)[:2], (x1 - x0, y1 - y0), flags=cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=border)


def verify(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, s: EstimationSettings) -> Placement:
    """How well grid i placed by `model` (pixels i -> pixels j) agrees with grid j.

    Only walls in the common known area count. A wall near a wall of the other map supports the placement, unless
    the two were seen from opposite sides (a wall's two faces: neither support nor conflict); any other wall there
    contradicts it. A contradiction at the fringe of the other map's view (the ends of its beams) is common at the
    right placement and does not lower the agreement (fringe_conflicts); one well inside it is rare there
    (deep_conflicts).
    """
    result = Placement(model)
    # grid i is warped only into the box of j it lands in, with the margin below
    box = landing_box(pi, pj, model, MARGIN + 4)
    if box is None:
        return result
    x0, y0, x1, y1 = box
    warped = warp_into(pi.work.view(np.uint8), model, box, 255).view(np.int8)
    both = (warped | pj.work[y0:y1, x0:x1]) >= 0   # known in both: neither sign bit set (unknown is -1)
    common = cv2.countNonZero(both.view(np.uint8))   # counted and bounded by OpenCV: np.nonzero here was a hot spot
    result.overlap_m2 = float(common) * pi.resolution ** 2
    if common == 0:
        return result
    # everything else only where both maps are known (plus a margin for the distance and side fields)
    bx, by, bw, bh = cv2.boundingRect(both.view(np.uint8))
    r0, r1 = max(by + y0 - MARGIN, 0), by + bh + y0 + MARGIN
    c0, c1 = max(bx + x0 - MARGIN, 0), bx + bw + x0 + MARGIN
    wi = warped[r0 - y0:r1 - y0, c0 - x0:c1 - x0]
    wj, both = pj.work[r0:r1, c0:c1], both[r0 - y0:r1 - y0, c0 - x0:c1 - x0]
    walls_i = both & (wi >= 50)
    walls_j = both & (wj >= 50)
    n_i, n_j = np.count_nonzero(walls_i), np.count_nonzero(walls_j)
    if n_i + n_j == 0:
        return result
    tol = s.verify_tolerance
    near_j = pj.wall_distance[r0:r1, c0:c1] <= tol
    near_i = near_walls(wi >= 50, tol)
    agree_i, agree_j = walls_i & near_j, walls_j & near_i
    support = np.count_nonzero(agree_i) + np.count_nonzero(agree_j)
    neutral = 0
    if s.facing and support:
        # only at the agreeing walls: the side fields are costly over the whole area
        rows, cols = nonzero_2d(agree_i | agree_j)
        weight = agree_i[rows, cols].astype(np.int64) + agree_j[rows, cols]
        # i's free side there: looked up in i's own field through the inverse placement and turned with it (the
        # same as the field of the warped grid, without computing one over the whole common area)
        x, y, _ = source_pixels(pi, model, cols + c0, rows + r0)
        side_i = pi.free_side[y, x] @ model[:2, :2].T
        faces = opposed(side_i, pj.free_side[rows + r0, cols + c0])
        neutral = int(weight[faces].sum())
        support -= neutral
    result.support = support
    result.conflicts = n_i + n_j - support - neutral
    # how deep inside the other map's view each contradicting wall lies
    deep_px = s.deep_conflict_m / pi.resolution
    conflicts_i = walls_i & ~near_j
    depth_i = pj.known_depth[r0:r1, c0:c1][conflicts_i]
    rows, cols = nonzero_2d(walls_j & ~near_i)
    depth_j = np.zeros(0, np.float32)
    if rows.size:
        # j's contradicting walls: i's depth at the same place, looked up through the inverse placement
        x, y, inside = source_pixels(pi, model, cols + c0, rows + r0)
        rows, cols, depth_j = rows[inside], cols[inside], pi.known_depth[y[inside], x[inside]]
    depth = np.concatenate([depth_i, depth_j])
    result.deep_conflicts = int((depth > deep_px).sum())
    if s.max_deep_conflicts * support < result.deep_conflicts \
            <= (s.max_deep_conflicts + s.max_movable_conflicts + s.max_gap_conflicts) * support:
        # told apart only where it decides: below, the placement passes either way; above, it fails either way
        deep_i = conflicts_i & (pj.known_depth[r0:r1, c0:c1] > deep_px)
        deep_j = np.zeros_like(deep_i)
        deep_j[rows[depth_j > deep_px], cols[depth_j > deep_px]] = True
        size_px, gap_px = s.movable_size_m / pi.resolution, s.gap_size_m / pi.resolution
        # the contradicting walls that are things standing free in their own map (judged on its walls in the
        # common area: a piece of a longer wall is structure however little of it contradicts), or that fill a
        # gap of the other map's wall: a door or a pane of glass
        movable_i = deep_i & free_standing(walls_i, wi, size_px)
        movable_j = deep_j & free_standing(walls_j, wj, size_px)
        result.movable_conflicts = int(movable_i.sum() + movable_j.sum())
        result.gap_conflicts = int((in_gap(deep_i, walls_i & near_j, gap_px) & ~movable_i).sum()
                                   + (in_gap(deep_j, walls_j & near_i, gap_px) & ~movable_j).sum())
    result.fringe_conflicts = result.conflicts - int((depth > s.fringe_px).sum())
    result.opposed = neutral
    result.agreement = support / float(max(support + result.conflicts - result.fringe_conflicts, 1))
    return result


@functools.lru_cache(maxsize=8)
def chamfer_disc(radius: float) -> np.ndarray:
    """The offsets within `radius` in the metric of distanceTransform's DIST_L2 with a 3x3 mask (a chamfer metric:
    steps of 0.955 along an axis, 1.3693 diagonally), as a dilation kernel: that transform of one pixel, thresholded."""
    r = int(math.ceil(2 * radius)) + 1   # no step is shorter than half a pixel
    point = np.full((2 * r + 1,) * 2, 255, np.uint8)
    point[r, r] = 0
    return (cv2.distanceTransform(point, cv2.DIST_L2, 3) <= radius).astype(np.uint8)


def near_walls(walls: np.ndarray, radius: float) -> np.ndarray:
    """Where a pixel of the bool mask `walls` lies within `radius`: the same as thresholding distanceTransform's
    DIST_L2 (3x3 mask) field, by a dilation (an eighth of the time in the verification's profile; verify runs
    thousands of times per estimation)."""
    return cv2.dilate(walls.view(np.uint8), chamfer_disc(float(radius))).view(bool)


def free_standing(walls: np.ndarray, grid: np.ndarray, size_px: float, ring_px: int = RING_PX) -> np.ndarray:
    """The pixels of `walls` (one map's, in its `grid`, the same pixels) that lie in small pieces this map saw with
    free floor all around: things that stand free, and may move.

    Between two passes of a real building people walk and chairs and carts move: one map has a small blob where
    the other saw free floor, and it saw free floor around the blob. A wrong placement instead puts walls where the
    other map saw floor, long ones, or short pieces of wall faces with the unknown behind them (glimpsed through a
    door); neither is free all around. Pieces a pixel apart count as one.
    """
    out = np.zeros(walls.shape, bool)
    found = _pieces(walls, ring_px + 2)
    if found is None:
        return out
    window, joined, labels, stats, extent = found
    walls, grid, count = walls[window], grid[window], len(stats)
    # a ring around each piece (where two rings meet, the larger label takes it: pieces are far apart)
    around = cv2.dilate(labels.astype(np.uint16 if count < 65536 else np.float32),
                        np.ones((2 * ring_px + 1,) * 2, np.uint8))
    around[joined > 0] = 0
    # counted over the rings alone: most of the window is background, whose count is not needed
    at = np.flatnonzero(around)
    label = around.ravel().take(at).astype(np.int64)
    ring = np.bincount(label, minlength=count)
    free = np.bincount(label[grid.ravel().take(at) == 0], minlength=count)
    small = (extent <= size_px) & (free >= MOVABLE_FREE_SHARE * np.maximum(ring, 1))
    small[0] = False   # the background
    out[window] = walls & small[labels]
    return out


def _pieces(mask: np.ndarray, margin: int):
    """The pieces of `mask`, pixels a pixel apart counting as one, labelled in a window around them (only there:
    the common area of a map and a union is large): (window slices, the joined mask, labels, stats, each piece's
    extent: its box less the pixel the joining added on each side, a line's length), all in the window; None when
    the mask is empty."""
    rows, cols = nonzero_2d(mask)
    if rows.size == 0:
        return None
    window = (slice(max(rows.min() - margin, 0), rows.max() + margin + 1),
              slice(max(cols.min() - margin, 0), cols.max() + margin + 1))
    joined = cv2.dilate(mask[window].view(np.uint8), np.ones((3, 3), np.uint8))
    _, labels, stats, _ = cv2.connectedComponentsWithStats(joined, connectivity=8)
    extent = np.hypot(stats[:, cv2.CC_STAT_WIDTH] - 2, stats[:, cv2.CC_STAT_HEIGHT] - 2)
    return window, joined, labels, stats, extent


GAP_REACH_PX = 3   # pixels beyond a piece's ends where the wall it belongs to must go on
GAP_LINE_PX = 3.0  # pixels: how far from the piece's line that wall may lie (a wall is 2-4 pixels thick)


def in_gap(conflicts: np.ndarray, agreeing: np.ndarray, size_px: float) -> np.ndarray:
    """The pixels of `conflicts` (one map's contradicting walls) that lie in short straight pieces, no longer than
    `size_px`, whose wall goes on at both ends in `agreeing` (the same map's walls that agree with the other map),
    in line with the piece: a gap in the other map's wall that this map saw closed.

    A door shut in one pass and open in the other, or a pane of glass that one laser saw and the other saw through,
    is such a piece: both maps agree on the wall on either side. A wrong placement puts walls where the other map
    saw floor too, but rarely a short piece in line with agreeing walls at both its ends; where it does (a corridor
    shifted by a door's spacing), it fills many gaps: a pair tolerates few such pieces (max_gap_conflicts).
    """
    out = np.zeros(conflicts.shape, bool)
    found = _pieces(conflicts, int(size_px) + GAP_REACH_PX + 2)
    if found is None:
        return out
    window, _, labels, stats, extent = found
    conflicts, agreeing, view = conflicts[window], agreeing[window], out[window]
    reach = np.ones((2 * GAP_REACH_PX + 1,) * 2, np.uint8)
    h, w = conflicts.shape
    for label in np.flatnonzero(extent <= size_px):
        if label == 0:
            continue   # the background
        x, y, bw, bh = (int(v) for v in stats[label, :4])
        # the piece and the agreeing walls within reach of it, in a window around it
        wy0, wx0 = max(y - GAP_REACH_PX, 0), max(x - GAP_REACH_PX, 0)
        wy1, wx1 = min(y + bh + GAP_REACH_PX, h), min(x + bw + GAP_REACH_PX, w)
        piece = (labels[wy0:wy1, wx0:wx1] == label) & conflicts[wy0:wy1, wx0:wx1]
        around = (cv2.dilate(piece.view(np.uint8), reach) > 0) & agreeing[wy0:wy1, wx0:wx1]
        py, px = np.nonzero(piece)
        ay, ax = np.nonzero(around)
        if py.size == 0 or ay.size < 2:
            continue
        # the line of the wall: the principal axis of the piece with the agreeing walls next to it
        p, a = np.column_stack([px, py]).astype(float), np.column_stack([ax, ay]).astype(float)
        pts = np.vstack([p, a])
        centre = pts.mean(axis=0)
        _, vectors = np.linalg.eigh(np.cov((pts - centre).T))
        along, across = vectors[:, 1], vectors[:, 0]
        p_rel, a_rel = p - centre, a - centre
        p_along = p_rel @ along
        a_along = a_rel[np.abs(a_rel @ across) <= GAP_LINE_PX] @ along
        if np.abs(p_rel @ across).max() <= GAP_LINE_PX \
                and (a_along < p_along.min()).any() and (a_along > p_along.max()).any():
            view[wy0:wy1, wx0:wx1] |= piece
    return out


IMPRECISE = 'imprecise'   # how a refusal for precision begins


def plausible(c: Placement, s: EstimationSettings) -> bool:
    """Agrees well over a common area large enough to mean something, and (almost) everywhere well inside both
    maps' views."""
    return (c.agreement >= s.min_agreement and c.overlap_m2 >= s.min_overlap_m2 and c.support >= s.min_support
            and not too_contradicted(c, s))


def structural_conflicts(c: Placement) -> int:
    """The walls that contradict well inside both maps' views and are neither small movable pieces nor in a gap of
    a wall: structure that one of the maps does not have there."""
    return c.deep_conflicts - c.movable_conflicts - c.gap_conflicts


def too_contradicted(c: Placement, s: EstimationSettings) -> bool:
    """Whether the walls that contradict well inside both maps' views say the placement is wrong: more structure
    (long pieces of wall) than max_deep_conflicts of the agreeing walls, or more small movable pieces than
    max_movable_conflicts (a little clutter moved between passes; a building full of it is no evidence)."""
    return (structural_conflicts(c) > s.max_deep_conflicts * c.support
            or c.movable_conflicts > s.max_movable_conflicts * c.support
            or c.gap_conflicts > s.max_gap_conflicts * c.support)


def refusal(c: Placement, pi: PreparedGrid, pj: PreparedGrid, s: EstimationSettings, onto_union: bool = False) -> str:
    """Why placement c of grid i on grid j fails the pair acceptance rules ('' if it passes): agreement, overlap,
    support, deep contradictions (as `plausible`), then precision, the costly one, which it stores in c. With
    `onto_union`, j is the union of a placed group: precision counts at grid i's corners only (the union stays)."""
    if c.agreement < s.min_agreement:
        return f'agreement {c.agreement:.2f} < {s.min_agreement:.2f}'
    if c.overlap_m2 < s.min_overlap_m2:
        return f'overlap {c.overlap_m2:.1f} m2 < {s.min_overlap_m2:.1f} m2'
    if c.support < s.min_support:
        return f'support {c.support} < {s.min_support}'
    if too_contradicted(c, s):
        return (f'{c.deep_conflicts} contradicting walls well inside both maps ({c.movable_conflicts} in pieces of '
                f'{s.movable_size_m:.1f} m or less, {c.gap_conflicts} in gaps of a wall), more than '
                f'{s.max_deep_conflicts:.0%} (small pieces {s.max_movable_conflicts:.0%}, gaps '
                f'{s.max_gap_conflicts:.0%}) of {c.support} agreeing')
    c.corner_error_m = corner_error(pi, pj, c.transform, s.verify_tolerance, moving_only=onto_union) * pi.resolution
    bound = angle_bound(pi, pj, c.transform) if c.corner_error_m > s.max_corner_error_m else None
    if bound is not None:
        # the shared walls leave the angle loose, but both maps' wall directions fix it (orientation.py)
        c.corner_error_m = min(c.corner_error_m, pi.resolution * corner_error(
            pi, pj, c.transform, s.verify_tolerance, moving_only=onto_union, angle_bound=bound))
    if c.corner_error_m > s.max_corner_error_m:
        return (f'{IMPRECISE}: the shared walls leave the far corners uncertain by '
                f'{c.corner_error_m:.2f} m > {s.max_corner_error_m:.2f} m')
    return ''


def distinct(a: np.ndarray, b: np.ndarray, pi: PreparedGrid, s: EstimationSettings) -> bool:
    """Whether two placements (pixel transforms of grid i) are different places, not two estimates of one."""
    rot, disp = tf.difference(a, b, corners_of(pi))
    return rot > math.radians(s.distinct_degrees) or disp * pi.resolution > s.distinct_metres


def same_place(a: np.ndarray, b: np.ndarray, pi: PreparedGrid) -> bool:
    """Whether two placements of grid i (pixel transforms) are one estimate: no corner of i lands SAME_PLACE_PX
    pixels apart (ICP from either ends at the same place)."""
    return tf.difference(a, b, corners_of(pi))[1] < SAME_PLACE_PX


def overlap_found(c: Optional[Placement], s: EstimationSettings, onto_union: bool = False) -> bool:
    """Whether a placement shows the maps' overlap although it fails the rules: it agrees except for contradictions
    inside both views (a map broken by a SLAM failure), or, onto a union, it has twice the support a pair needs
    and agrees mostly (a broken map fits the union in part). Then a search would find the same placement."""
    if c is None:
        return False
    return (plausible(c, s.replace(max_deep_conflicts=math.inf, max_movable_conflicts=math.inf,
                                 max_gap_conflicts=math.inf))
            or (onto_union and partly_agreeing(c, s)))


def partly_agreeing(c: Optional[Placement], s: EstimationSettings) -> bool:
    """Whether a placement has twice the support a pair needs, its common area, and agrees mostly (FOUND_AGREEMENT):
    the maps overlap there, whether or not they contradict."""
    return c is not None and c.support >= 2 * s.min_support and c.overlap_m2 >= s.min_overlap_m2 \
        and c.agreement >= FOUND_AGREEMENT


def pair_confidence(inliers: int, matches: int) -> float:
    """The original's confidence, inliers / (8 + 0.3 matches) (Brown & Lowe), here on verified correspondences.

    The original counts descriptor matches; on occupancy grids these are few and mostly wrong, so its threshold
    (default 1.0) says little. Counted on wall pixels, 1.0 means about a third of the walls in the common area
    agree; the acceptance rules (min_agreement etc.) are stricter, so the default threshold never decides alone,
    and a higher one (up to about 3.3 = every wall agrees) asks for more agreement.
    """
    return inliers / (8.0 + 0.3 * matches)
