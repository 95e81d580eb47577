"""Test helper (pure numpy, no rospy): a trinary map turned into the other kinds real SLAM packages publish.

  * probabilistic (Cartographer): occupancy 0..100 instead of -1/0/100. Cells seen often saturate (free 10..25,
    walls 65..90); cells seen once or twice stay near 50 (free 26..49, walls 51..64), which a reader should take as
    unknown; unknown stays -1.
  * thin: walls one cell thick (only the face seen from free space), free space only near walls (a short-range or
    sparse scan), the whole on a canvas mostly unknown (hector_mapping's fixed square canvas).
Imported by mm_sample_map_publisher.py (its ~kinds) and by the merge_maps tests.
"""
from __future__ import annotations

import cv2
import numpy as np

from multirobot_map_merge.grid import Grid

KINDS = ('trinary', 'probabilistic', 'thin')


def probabilistic(grid: Grid, seed: int = 0, uncertain_share: float = 0.15) -> Grid:
    """`grid` as Cartographer publishes it: `uncertain_share` of the free and of the wall cells only weakly seen."""
    rng = np.random.default_rng(seed)
    data = grid.data
    out = np.full(data.shape, -1, np.int8)
    weak = rng.random(data.shape) < uncertain_share
    free, wall = data == 0, data == 100
    out[free] = np.where(weak[free], rng.integers(26, 50, data.shape)[free], rng.integers(10, 26, data.shape)[free])
    out[wall] = np.where(weak[wall], rng.integers(51, 65, data.shape)[wall], rng.integers(65, 91, data.shape)[wall])
    return Grid(out, grid.resolution, grid.origin, grid.frame_id)


def thin(grid: Grid, free_band_m: float = 1.5, canvas_factor: float = 2.0) -> Grid:
    """`grid` with one-cell walls facing free space, free cells only within `free_band_m` of a wall, centred on a
    canvas `canvas_factor` times as large (per side) whose margin is unknown; the map frame stays where it was."""
    data = grid.data
    free, wall = data == 0, data == 100
    near_free = cv2.dilate(free.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    face = wall & near_free
    to_wall = cv2.distanceTransform(np.where(face, 0, 255).astype(np.uint8), cv2.DIST_L2, 3)
    band = free & (to_wall <= free_band_m / grid.resolution)
    h, w = data.shape
    top, left = int(h * (canvas_factor - 1) / 2), int(w * (canvas_factor - 1) / 2)
    out = np.full((h + 2 * top, w + 2 * left), -1, np.int8)
    inner = out[top:top + h, left:left + w]
    inner[band] = 0
    inner[face] = 100
    ox, oy, oyaw = grid.origin
    return Grid(out, grid.resolution, (ox - left * grid.resolution, oy - top * grid.resolution, oyaw),
                grid.frame_id)


def as_kind(grid: Grid, kind: str, seed: int = 0) -> Grid:
    if kind == 'trinary':
        return grid
    if kind == 'probabilistic':
        return probabilistic(grid, seed)
    if kind == 'thin':
        return thin(grid)
    raise ValueError(f"unknown map kind '{kind}' (one of {', '.join(KINDS)})")


def save_raw(grid: Grid, prefix: str) -> str:
    """Write `grid` as a map_server map in raw mode (each pixel is the cell's value, 255 unknown): the one mode that
    keeps probabilities exactly. Returns the yaml path."""
    img = np.ascontiguousarray(grid.data[::-1]).view(np.uint8)
    cv2.imwrite(prefix + '.pgm', img)
    ox, oy, oyaw = grid.origin
    with open(prefix + '.yaml', 'w') as f:
        f.write(f'image: {prefix.rsplit("/", 1)[-1]}.pgm\nmode: raw\nresolution: {grid.resolution}\n'
                f'origin: [{ox}, {oy}, {oyaw}]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n')
    return prefix + '.yaml'
