"""A picture of a merge: every robot's map in its own colour where it was placed, with a legend.

Free space is tinted with the robot's colour, walls are drawn in the full colour over all tints, so which map
went where (and whether two maps' walls coincide) shows at a glance. The legend names each robot (excluded ones
marked and listed) and gives the confidence of every pair used to place the maps. Pure: numpy + OpenCV.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from . import transforms as tf
from .compose import warp_into
from .grid import UNKNOWN, Grid, crop_to_known
from .mapio import save_image

# BGR; distinct on white and on each other (Tableau 10)
PALETTE = [(180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148),
           (75, 86, 140), (194, 119, 227), (34, 189, 188), (207, 190, 23), (127, 127, 127)]
BACKGROUND = (205, 205, 205)   # unknown: map_saver's grey
FREE_TINT = 0.3                # share of the robot colour in its free cells
FREE_MAX, OCCUPIED_MIN = 25, 65  # map_saver's thresholds
MAX_SIDE = 3000                # the picture is scaled down beyond this many pixels
MARGIN = 5                     # pixels of background around the maps

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_WALL_KERNEL = np.ones((3, 3), np.uint8)
_LINE = 18


@dataclass(frozen=True)
class UsedPair:
    a: int
    b: int
    confidence: float


def used_pairs(pairs: Iterable, transforms: Sequence[Optional[np.ndarray]]) -> List[UsedPair]:
    """Accepted pairs whose maps are both placed (as the node's ~status `used`), from PairMatch-like objects
    (i, j, accepted, confidence)."""
    return [UsedPair(p.i, p.j, float(p.confidence)) for p in pairs
            if p.accepted and transforms[p.i] is not None and transforms[p.j] is not None]


def colour(k: int) -> Tuple[int, int, int]:
    return PALETTE[k % len(PALETTE)]


@dataclass
class _Part:
    """The known part of one placed grid: its cells and the transform of its cell corners into the merged frame."""
    k: int
    data: np.ndarray
    to_merged: np.ndarray
    resolution: float


def _parts(placed: Sequence[Tuple[int, Grid, np.ndarray]]) -> List[_Part]:
    parts = []
    for k, grid, t in placed:
        box = crop_to_known(grid.data, margin=0)
        if box is not None:
            r0, r1, c0, c1 = box
            parts.append(_Part(k, grid.data[r0:r1, c0:c1], t @ grid.cell_to_map() @ tf.translation(c0, r0),
                               grid.resolution))
    return parts


def _known_hull(data: np.ndarray) -> np.ndarray:
    """(N, 2) cell-corner points whose convex hull holds every known cell."""
    points = cv2.findNonZero((data >= 0).view(np.uint8))
    hull = cv2.convexHull(points).reshape(-1, 2).astype(float)
    return np.vstack([hull + offset for offset in ((0, 0), (1, 0), (0, 1), (1, 1))])


def _canvas_geometry(parts: Sequence[_Part]) -> Tuple[np.ndarray, int, int]:
    """(merged -> canvas cell transform, width, height) holding every part, with a margin of MARGIN pixels."""
    resolution = min(p.resolution for p in parts)
    # the hull of the known cells, not the grid's rectangle: a rotated map's corners are mostly unknown
    corners = np.vstack([tf.apply(p.to_merged, _known_hull(p.data)) for p in parts])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    extent = max(hi[0] - lo[0], hi[1] - lo[1], resolution)
    resolution = max(resolution, extent / MAX_SIDE)     # keep the picture (and its memory) bounded
    width, height = (int(math.ceil(v / resolution)) + 2 * MARGIN for v in (hi - lo))
    return tf.translation(MARGIN, MARGIN) @ tf.scaling(1.0 / resolution) @ tf.translation(-lo[0], -lo[1]), \
        width, height


def _draw_maps(placed: Sequence[Tuple[int, Grid, np.ndarray]]) -> np.ndarray:
    """BGR image (row 0 = top) of the known parts of the placed grids: tinted free space, then walls on top."""
    parts = _parts(placed)
    if not parts:
        return np.full((200, 200, 3), BACKGROUND, np.uint8)
    to_canvas, width, height = _canvas_geometry(parts)
    image = np.empty((height, width, 3), np.uint8)
    image[:] = BACKGROUND
    tinted = np.zeros((height, width), bool)
    wall_owner = np.full((height, width), -1, np.int16)   # walls go on top of every tint: drawn last
    for part in parts:
        warped = np.full((height, width), UNKNOWN, np.int8)
        warp_into(warped, part.data, to_canvas @ part.to_merged)
        free = (warped >= 0) & (warped <= FREE_MAX)
        # white under the first tint: a free cell seen by one robot reads as that robot's pale colour, by
        # several as their mixture
        base = np.where(tinted[free][:, None], image[free].astype(np.float32), np.float32(255.0))
        image[free] = ((1.0 - FREE_TINT) * base + FREE_TINT * np.array(colour(part.k), np.float32)).astype(np.uint8)
        tinted |= free
        # one-cell walls would vanish among the tints: thicken them by a pixel
        wall = cv2.dilate((warped >= OCCUPIED_MIN).view(np.uint8), _WALL_KERNEL).view(bool)
        wall_owner[wall] = part.k
    for part in parts:
        image[wall_owner == part.k] = colour(part.k)
    return np.ascontiguousarray(image[::-1])


def _legend_lines(names: Sequence[str], placed: Sequence[bool],
                  pairs: Sequence[UsedPair]) -> List[Tuple[str, Optional[Tuple[int, int, int]]]]:
    lines: List[Tuple[str, Optional[Tuple[int, int, int]]]] = [('robots', None)]
    for k, name in enumerate(names):
        lines.append((name if placed[k] else f'{name} (excluded)', colour(k)))
    excluded = [n for n, p in zip(names, placed) if not p]
    lines.append((f'excluded: {", ".join(excluded) if excluded else "none"}', None))
    if pairs:
        lines.append(('pairs used (confidence)', None))
        lines.extend((f'{names[p.a]} - {names[p.b]}: {p.confidence:.2f}', None) for p in pairs)
    return lines


def _draw_legend(lines: Sequence[Tuple[str, Optional[Tuple[int, int, int]]]], height: int) -> np.ndarray:
    scale = 0.45
    text_w = max(cv2.getTextSize(t, _FONT, scale, 1)[0][0] for t, _ in lines)
    panel = np.full((max(height, _LINE * (len(lines) + 1)), text_w + 44, 3), 255, np.uint8)
    for n, (text, swatch) in enumerate(lines):
        y = _LINE * (n + 1)
        x = 10
        if swatch is not None:
            cv2.rectangle(panel, (x, y - 11), (x + 14, y + 1), swatch, -1)
            x += 22
        cv2.putText(panel, text, (x, y), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return panel


def render_overlay(grids: Sequence[Optional[Grid]], transforms: Sequence[Optional[np.ndarray]],
                   names: Sequence[str], pairs: Sequence[UsedPair] = ()) -> np.ndarray:
    """BGR picture: the placed grids (metric transforms: grid map frame -> merged frame) in their colours, +y up,
    and the legend on the right. A grid without a transform (or without a map) is listed as excluded."""
    if not (len(grids) == len(transforms) == len(names)):
        raise ValueError(f'{len(grids)} grids, {len(transforms)} transforms, {len(names)} names')
    placed = [(k, g, np.asarray(t, float)) for k, (g, t) in enumerate(zip(grids, transforms))
              if g is not None and t is not None and not g.is_empty()]
    is_placed = [False] * len(grids)
    for k, _, _ in placed:
        is_placed[k] = True
    maps = _draw_maps(placed)
    legend = _draw_legend(_legend_lines(names, is_placed, pairs), maps.shape[0])
    if legend.shape[0] > maps.shape[0]:
        pad = np.empty((legend.shape[0] - maps.shape[0], maps.shape[1], 3), np.uint8)
        pad[:] = 255
        maps = np.vstack([maps, pad])
    return np.hstack([maps, legend])


def overlay_path(png_path: str) -> str:
    """Where the overlay of a merge previewed at `png_path` goes: beside it, `<stem>_overlay.png`."""
    stem = png_path[:-4] if png_path.lower().endswith('.png') else png_path
    return stem + '_overlay.png'


def save_overlay(path: str, grids: Sequence[Optional[Grid]], transforms: Sequence[Optional[np.ndarray]],
                 names: Sequence[str], pairs: Sequence[UsedPair] = ()) -> str:
    """Render the overlay (see render_overlay) and write it as PNG; returns the path. The demo calls this with
    the robots' final maps and their placements from map_merge's ~status."""
    return save_image(render_overlay(grids, transforms, names, pairs), path)


def save_named_overlay(path: str, maps: Dict[str, Grid], poses: Dict[str, Tuple[float, float, float]],
                       pairs: Iterable[Tuple[str, str, float]] = ()) -> str:
    """The overlay from robot names: `poses[name]` = (x, y, yaw) of the robot's map frame in the merged frame
    (e.g. from map_merge's ~status; robots without one are excluded), `pairs` = (name, name, confidence) of the
    pairs used. Robots are listed in name order. This is what the live demo calls."""
    names = sorted(maps)
    index = {n: k for k, n in enumerate(names)}
    transforms = [tf.rigid(*poses[n]) if n in poses else None for n in names]
    used = [UsedPair(index[a], index[b], float(c)) for a, b, c in pairs if a in index and b in index]
    return save_overlay(path, [maps[n] for n in names], transforms, names, used)
