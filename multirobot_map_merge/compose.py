"""Composition: warp every placed grid into one merged grid.

Cells combine by signed maximum as the original (occupied > free > unknown); warping is nearest-neighbour;
everything outside every map is unknown. Each grid is warped only over its own known part and its own region of
the canvas, so many small maps on a large canvas stay cheap.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import cv2
import numpy as np

from . import transforms as tf
from .features import crop_to_known
from .grid import MAX_CELLS, UNKNOWN, Grid, GridError

# index (pixel centre) coordinates are corner coordinates shifted by half a cell
_TO_CORNER = tf.translation(0.5, 0.5)
_TO_INDEX = tf.translation(-0.5, -0.5)


def warp_into(canvas: np.ndarray, src: np.ndarray, src_to_canvas: np.ndarray) -> None:
    """Max-combine `src` (int8) into `canvas` (int8) through a corner-coordinate cell transform src -> canvas."""
    h, w = src.shape
    corners = tf.apply(src_to_canvas, np.array([[0, 0], [w, 0], [0, h], [w, h]], float))
    x0, y0 = np.floor(corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, canvas.shape[1]), min(y1, canvas.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    index_map = _TO_INDEX @ tf.translation(-x0, -y0) @ src_to_canvas @ _TO_CORNER
    warped = cv2.warpAffine(src.view(np.uint8), index_map[:2], (x1 - x0, y1 - y0), flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=255).view(np.int8)
    region = canvas[y0:y1, x0:x1]
    np.maximum(region, warped, out=region)


def compose(grids: Sequence[Optional[Grid]], transforms: Sequence[Optional[np.ndarray]],
            resolution: Optional[float] = None, frame_id: str = '') -> Optional[Grid]:
    """Merge grids placed by metric transforms (map frame of grid k -> merged frame).

    The merged grid has `resolution` (default: that of the first placed grid whose transform is the identity, else
    of the first placed grid) and its origin is the corner of the smallest canvas holding every known cell.
    Returns None when no grid with a known cell is placed.
    """
    placed = [(g, t) for g, t in zip(grids, transforms) if g is not None and t is not None and not g.is_empty()]
    if resolution is None:
        ref = next((g for g, t in placed if np.allclose(t, np.eye(3))), placed[0][0] if placed else None)
        resolution = ref.resolution if ref is not None else 0.0
    parts = []
    for g, t in placed:
        box = crop_to_known(g.data, margin=0)
        if box is None:
            continue
        r0, r1, c0, c1 = box
        crop_to_merged = t @ g.cell_to_map() @ tf.translation(c0, r0)
        parts.append((g.data[r0:r1, c0:c1], crop_to_merged))
    if not parts:
        return None
    if not (math.isfinite(resolution) and resolution > 0):
        raise GridError(f'merged resolution {resolution} is not a positive number')
    corners = np.vstack([tf.apply(m, np.array([[0, 0], [d.shape[1], 0], [0, d.shape[0]], [d.shape[1], d.shape[0]]],
                                             float)) for d, m in parts])
    lo = np.floor(corners.min(axis=0) / resolution) * resolution
    hi = np.ceil(corners.max(axis=0) / resolution) * resolution
    width, height = (int(round(v)) for v in (hi - lo) / resolution)
    if width * height > MAX_CELLS:
        raise GridError(f'merged grid of {width} x {height} cells is too large: are the transforms sane?')
    canvas = np.full((max(height, 1), max(width, 1)), UNKNOWN, np.int8)
    merged_to_canvas = tf.scaling(1.0 / resolution) @ tf.translation(-lo[0], -lo[1])
    for data, crop_to_merged in parts:
        warp_into(canvas, data, merged_to_canvas @ crop_to_merged)
    return Grid(canvas, resolution, (float(lo[0]), float(lo[1]), 0.0), frame_id)
