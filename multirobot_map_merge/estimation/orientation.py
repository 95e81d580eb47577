"""The direction of a map's straight walls, as a second measure of a placement's angle.

Where two maps (or two placed groups) share a small area, its walls fix the translation there but leave the angle
loose, and a fraction of a degree moves the far end of a large map by decimetres (precision.py refuses such a
placement). In most buildings the long walls of each map run along two perpendicular directions, and those of the
whole building along the same two: the direction of all of a map's long walls, modulo 90 degrees, is then known to
a few hundredths of a degree, far from where the maps overlap. When both maps have such a direction, the relative
angle of a placement must align them: a placement is turned by the difference about the centre of the walls the
maps share (`aligned`), and its precision counts that angle (`angle_bound`).

Segments come from OpenCV's line segment detector (LSD) on the wall image; their length-weighted circular mean of
four times their angle gives the direction. A map whose long walls run in other directions too (a cave, a radial
building: more than MAX_ASIDE_SHARE of their length OUTLIER_DEGREES or more off the direction) or are bent (drift,
a real map: the others spread more than MAX_SPREAD_DEGREES about it) has no direction here; a few walls of another
direction (a chamfered corner) are left aside. On the generated
rectilinear buildings the direction of a single map was within 0.24 degrees of the truth, at most 2.7 times the
standard error computed here (over 80 maps): `SIGMAS` of them bound it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from .features import PreparedGrid

MIN_SEGMENT_M = 1.0          # walls shorter than this say little about their direction
MIN_SEGMENTS = 8.0           # effective number of segments (length-weighted) a direction needs
MAX_SPREAD_DEGREES = 1.5     # of the segments about the direction (modulo 90): more, and the walls are not rectilinear
MIN_SIGMA_DEGREES = 0.03     # floor of the standard error: the rasterisation of the walls
MAX_SIGMA_DEGREES = 0.15     # a direction known less precisely is no measure of a placement's angle (the early, small
                             # maps of a live fleet: 0.2-0.5, their directions up to 0.6 degrees off)
SIGMAS = 4.0                 # the bound of a direction's error, in standard errors
MAX_TURN_DEGREES = 2.0       # a placement is turned onto the directions by at most this
OUTLIER_DEGREES = 20.0       # a segment this far off the direction (modulo 90) is a wall of another direction ...
MAX_ASIDE_SHARE = 0.05       # ... left aside, up to this share of the segments' length: one diagonal metre among
                             # the 273 m of a union of 20 maps of the generated mall36 spread them 2.6 degrees, and
                             # a group joining it was refused as imprecise. Not bent walls (a few degrees): a real map's
                             # are, and its direction from the straight ones alone was 1.6 degrees off another's


@dataclass(frozen=True)
class Orientation:
    """A map's wall direction modulo 90 degrees (radians, pixel frame) and its standard error (radians)."""
    angle: float
    sigma: float


def _offset(angle: np.ndarray, centre: float) -> np.ndarray:
    """angle - centre modulo 90 degrees, in [-45, 45] degrees (radians)."""
    return np.angle(np.exp(4j * (angle - centre))) / 4


def orientation(p: PreparedGrid) -> Optional[Orientation]:
    """The direction of grid p's long walls, computed once per prepared grid; None when they are too few or not
    rectilinear."""
    if 'orientation' not in p.derived:
        p.derived['orientation'] = _orientation(*segments(p))
    return p.derived['orientation']


def segments(p: PreparedGrid) -> Tuple[np.ndarray, np.ndarray]:
    """(length in pixels, angle in radians) of grid p's long wall segments, found once per prepared grid."""
    if 'segments' not in p.derived:
        p.derived['segments'] = long_segments(p.work, p.resolution)
    return p.derived['segments']


def long_segments(work: np.ndarray, resolution: float) -> Tuple[np.ndarray, np.ndarray]:
    """(length in pixels, angle in radians) of the wall segments of a working grid (-1/0/100) at least
    MIN_SEGMENT_M long."""
    image = np.full(work.shape, 255, np.uint8)
    image[work >= 50] = 0
    # a slight blur: LSD reads a one-pixel staircase as many short segments
    found = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(cv2.GaussianBlur(image, (0, 0), 1.0))[0]
    if found is None:
        return np.zeros(0), np.zeros(0)
    x0, y0, x1, y1 = found[:, 0, :].T.astype(np.float64)
    length = np.hypot(x1 - x0, y1 - y0)
    long_ = length * resolution >= MIN_SEGMENT_M
    return length[long_], np.arctan2(y1 - y0, x1 - x0)[long_]


def wall_orientation(work: np.ndarray, resolution: float) -> Optional[Orientation]:
    """The direction (modulo 90 degrees) of the long walls of a working grid (-1/0/100), or None."""
    return _orientation(*long_segments(work, resolution))


def _orientation(length: np.ndarray, angle: np.ndarray) -> Optional[Orientation]:
    if length.size == 0:
        return None
    mean = float(np.angle((length * np.exp(4j * angle)).sum()) / 4)
    aside = np.abs(_offset(angle, mean)) >= math.radians(OUTLIER_DEGREES)
    if length[aside].sum() > MAX_ASIDE_SHARE * length.sum():
        return None
    length, angle = length[~aside], angle[~aside]
    mean = float(np.angle((length * np.exp(4j * angle)).sum()) / 4)
    n_effective = length.sum() ** 2 / (length ** 2).sum()
    deviation = _offset(angle, mean)
    spread = math.sqrt(float((length * deviation ** 2).sum() / length.sum()))
    sigma = max(spread / math.sqrt(n_effective), math.radians(MIN_SIGMA_DEGREES))
    if n_effective < MIN_SEGMENTS or spread > math.radians(MAX_SPREAD_DEGREES) \
            or sigma > math.radians(MAX_SIGMA_DEGREES):
        return None
    return Orientation(mean, sigma)


def misalignment(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray) -> Optional[Tuple[float, float]]:
    """(turn, sigma), radians: how far the placement `model` (pixels i -> pixels j) must turn for grid i's wall
    direction to meet grid j's (modulo 90 degrees, the smallest turn), and the standard error of that turn; None
    unless both grids have a direction."""
    oi, oj = orientation(pi), orientation(pj)
    if oi is None or oj is None:
        return None
    turn = oj.angle - (oi.angle + math.atan2(model[1, 0], model[0, 0]))
    turn = (turn + math.pi / 4) % (math.pi / 2) - math.pi / 4
    return turn, math.hypot(oi.sigma, oj.sigma)


def angle_bound(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray) -> Optional[float]:
    """The bound (SIGMAS standard errors, radians) the wall directions set on the angle of `model`, if it agrees
    with them within that bound; None otherwise."""
    found = misalignment(pi, pj, model)
    if found is None or abs(found[0]) > SIGMAS * found[1]:
        return None
    return SIGMAS * found[1]


def aligned(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, centre: np.ndarray) -> Optional[np.ndarray]:
    """`model` turned about `centre` (pixels of j: the centre of the walls the grids share) so that the wall
    directions meet; None when they cannot tell or would turn it by more than MAX_TURN_DEGREES."""
    found = misalignment(pi, pj, model)
    if found is None or abs(found[0]) > math.radians(MAX_TURN_DEGREES):
        return None
    cx, cy = centre
    return tf.translation(cx, cy) @ tf.rigid(0.0, 0.0, found[0]) @ tf.translation(-cx, -cy) @ model


# --- the directions a search turns a grid to ---------------------------------------------------------------------

FAMILY_DEGREES = 4.0          # a family: the long walls within this of its direction (modulo 90 degrees)
FAMILY_MIN_SHARE = 0.1        # of the long walls' length a family holds at least
MAX_FAMILIES = 3
FAMILIES_COVER = 0.9          # the families hold this share of the long walls' length, or the grid has none
FAMILIES_MIN_LENGTH_M = 8.0   # long walls a grid's families need in all
TURN_WINDOW_DEGREES = 6.0     # a search keeps the angles within this of a turn that meets two families (and their
                              # spreads): the sweep's own angles there, so its peaks near the truth stay as they were


def families(p: PreparedGrid) -> Optional[List[Tuple[float, float]]]:
    """The directions of grid p's long walls, computed once per prepared grid (wall_families)."""
    if 'families' not in p.derived:
        length, angle = segments(p)
        p.derived['families'] = wall_families(length * p.resolution, angle)
    return p.derived['families']


def wall_families(length_m: np.ndarray, angle: np.ndarray) -> Optional[List[Tuple[float, float]]]:
    """The directions (modulo 90 degrees, radians) of up to MAX_FAMILIES families of long wall segments, with the
    spread of each (radians), largest first; None when they hold less than FAMILIES_COVER of the walls' length (a
    cave, curved walls) or the walls are too few.

    Unlike `orientation`, a grid may have several (a radial building, a broken map whose part is turned, a union
    holding one), and a family may spread (a real map's bent walls)."""
    total = float(length_m.sum())
    if total < FAMILIES_MIN_LENGTH_M:
        return None
    left = np.ones(len(length_m), bool)
    found: List[Tuple[float, float]] = []
    reach = math.radians(FAMILY_DEGREES)
    while len(found) < MAX_FAMILIES and left.any():
        hist, _ = np.histogram(np.degrees(np.mod(angle[left], math.pi / 2)), bins=90, range=(0, 90),
                               weights=length_m[left])
        smooth = np.convolve(np.r_[hist[-2:], hist, hist[:2]], np.ones(5), mode='valid')
        centre = math.radians(int(np.argmax(smooth)) + 0.5)
        for _ in range(2):   # the family's length-weighted mean direction, from the histogram's peak
            near = left & (np.abs(_offset(angle, centre)) <= reach)
            centre += float(np.angle((length_m[near] * np.exp(4j * _offset(angle[near], centre))).sum()) / 4)
        near = left & (np.abs(_offset(angle, centre)) <= reach)
        if length_m[near].sum() < FAMILY_MIN_SHARE * total:
            break
        spread = math.sqrt(float((length_m[near] * _offset(angle[near], centre) ** 2).sum() / length_m[near].sum()))
        found.append((centre % (math.pi / 2), spread))
        left &= ~near
    if length_m[~left].sum() < FAMILIES_COVER * total:
        return None
    return found


def near_turns(pi: PreparedGrid, pj: PreparedGrid, angles: Sequence[float]) -> List[float]:
    """Of the `angles` (radians) a search would turn grid i by onto grid j, those within TURN_WINDOW_DEGREES (and
    the two families' spreads) of a turn that makes a family of i's long walls meet one of j's, by quarter turns;
    all of them when either grid has no families (wall_families).

    Two maps overlap where they saw the same walls, so a placement that agrees turns a family of one onto a family
    of the other. On the 13 generated buildings (468 maps, 7814 ordered pairs sharing 4 m2 or more, both with
    families) the truth of every pair of healthy maps lies within 0.62 degrees of such a turn; on the dev and
    real_dev sets (1211 pairs) within 1.46 degrees. Only a broken map's small part (maze36: under a tenth of its
    walls) is off every family of its map. The angles kept are the sweep's own about those turns, not the turns
    alone: at exactly the turns, the peaks of a few large aliases filled the best places, where the sweep, an angle
    or two off (a large overlap loses more there than a small one), had ranked a small true place among them
    (held-out hospital36_v: map_12 onto the merge, 23.6 m2, 5th of the sweep's candidates, 20th of 27 at the
    turns)."""
    fi, fj = families(pi), families(pj)
    if fi is None or fj is None:
        return list(angles)
    of = np.asarray(angles, np.float64)
    near = np.zeros(len(of), bool)
    for ci, si in fi:
        for cj, sj in fj:
            near |= np.abs(_offset(of, cj - ci)) <= math.radians(TURN_WINDOW_DEGREES) + si + sj
    return [a for a, kept in zip(angles, near) if kept]
