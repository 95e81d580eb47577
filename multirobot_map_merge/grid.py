"""The occupancy grid type shared by the whole package (no ROS import).

Conventions (those of nav_msgs/OccupancyGrid):
  * ``data`` is an int8 array of shape (height, width); ``data[row, col]``; row 0 is the row at the map origin
    (lowest y in the grid's own frame). Values: -1 unknown, 0 free .. 100 occupied.
  * ``origin`` = (x, y, yaw): the pose, in the map frame, of the outer corner of cell (0, 0).
    Cell (col, row) covers [col, col + 1) x [row, row + 1) in cell units; its centre is at (col + 0.5, row + 0.5).
  * ``frame_id`` is the map frame the origin is expressed in (may be empty).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Tuple

import numpy as np

UNKNOWN = -1
FREE = 0
OCCUPIED = 100

# Grids larger than this (cells) are refused as malformed: 2**28 cells = 256 MiB of int8.
MAX_CELLS = 1 << 28


class GridError(ValueError):
    """A grid (or a message describing one) is malformed."""


@dataclass
class Grid:
    data: np.ndarray
    resolution: float
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_id: str = ""
    stamp: float = 0.0
    extra: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.data = np.ascontiguousarray(self.data, dtype=np.int8)
        self.resolution = float(self.resolution)
        self.origin = tuple(float(v) for v in self.origin)
        validate_geometry(self.data.shape[1] if self.data.ndim == 2 else -1,
                          self.data.shape[0] if self.data.ndim == 2 else -1,
                          self.resolution, self.origin)

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    def known_mask(self) -> np.ndarray:
        return self.data >= 0

    def is_empty(self) -> bool:
        return self.data.size == 0

    def cell_to_map(self) -> np.ndarray:
        """3x3 matrix from cell coordinates (corner convention) to metric map-frame coordinates."""
        ox, oy, oyaw = self.origin
        c, s = math.cos(oyaw), math.sin(oyaw)
        r = self.resolution
        return np.array([[c * r, -s * r, ox], [s * r, c * r, oy], [0.0, 0.0, 1.0]])

    def copy(self) -> "Grid":
        return Grid(self.data.copy(), self.resolution, self.origin, self.frame_id, self.stamp, dict(self.extra))


def validate_geometry(width: int, height: int, resolution: float, origin) -> None:
    """Raise GridError unless the size, resolution and origin describe a usable grid."""
    if width < 0 or height < 0:
        raise GridError(f"data is not a 2-D array (width {width}, height {height})")
    if width * height > MAX_CELLS:
        raise GridError(f"grid of {width} x {height} cells is larger than the limit of {MAX_CELLS} cells")
    if not (math.isfinite(resolution) and resolution > 0.0):
        raise GridError(f"resolution {resolution} is not a positive finite number")
    if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
        raise GridError(f"origin {tuple(origin)} is not finite")


def crop_to_known(data: np.ndarray, margin: int = 0):
    """(row0, row1, col0, col1) of the known part plus a margin, or None if nothing is known."""
    known = data >= 0
    rows = np.flatnonzero(known.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(known[rows[0]:rows[-1] + 1].any(axis=0))
    h, w = data.shape
    return (max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h),
            max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w))
