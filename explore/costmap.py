"""explore_lite's costmap client grid, without ROS.

A ``Costmap2D``-like byte grid fed from ``nav_msgs/OccupancyGrid`` messages and ``map_msgs/OccupancyGridUpdate``
patches. Occupancy values are translated to cost bytes through the original 256-entry table (explore.md §4.2).

Invalid occupancies (outside -1 and 0..100, i.e. bytes 101..254) are read as unknown (NO_INFORMATION) by the
Costmap, the package's one rule for them (multirobot_map_merge/admission.py); update_full and update_partial return
how many there were so that the node can warn. `translation_table()` itself keeps the original's entries.

Conventions: ``data`` is a uint8 array of shape (size_y, size_x), row-major as the original
(flat index = my * size_x + mx); row 0 is at the origin (lowest y). The origin's yaw is ignored, as in the original.
"""
from __future__ import annotations

import logging
import math
import threading
from typing import Optional, Sequence, Tuple, Union

import numpy as np

_log = logging.getLogger('rosout.' + __name__)

# costmap_2d cost values
FREE_SPACE = 0
INSCRIBED_INFLATED_OBSTACLE = 253
LETHAL_OBSTACLE = 254
NO_INFORMATION = 255
OCCUPIED_MAX = 100   # occupancy values are -1 and 0..100

# Refuse grids above 2**28 cells (256 MiB of bytes): such a message is malformed, not a map.
MAX_CELLS = 1 << 28

CellData = Union[np.ndarray, Sequence[int], bytes, bytearray]


class CostmapError(ValueError):
    """A map or map update cannot be applied; the grid is left unchanged."""


class InvalidMapError(CostmapError):
    """A full map message is malformed (size, resolution, origin or data type)."""


class InvalidUpdateError(CostmapError):
    """A partial update is malformed (negative corner, short data) or arrived before any full map."""


def translation_table(probability_map: bool = False, free_threshold: int = 25,
                      occupied_threshold: int = 65, by_threshold: bool = False) -> np.ndarray:
    """The 256-entry occupancy (reinterpreted as uint8) → cost table.

    Default: the original's table — 0 → 0, 1..98 → 1 + floor(251·(i−1)/97), 99 → 253, 100 → 254, 255 (−1) → 255
    and the same formula modulo 256 for the invalid values 101..254 (explore.md §4.2).

    ``probability_map``: occupancies 0..free_threshold → FREE_SPACE, occupied_threshold..100 → LETHAL_OBSTACLE and
    the values strictly between → NO_INFORMATION (uncertain cells are treated as not yet explored, like map_server's
    trinary mode), so maps whose free cells are not exactly 0 (Cartographer) still have frontiers. A ternary map
    (−1/0/100) translates to the same costs either way. Invalid values keep the original's entries.

    ``by_threshold`` (the explore node's default; ignored with ``probability_map``): occupancies 0..free_threshold →
    FREE_SPACE and occupied_threshold..100 → LETHAL_OBSTACLE, the values in between keep the original's ramp (neither
    free nor unknown). Only exact FREE_SPACE and NO_INFORMATION matter to the frontier search, so this finds the
    frontiers of probabilistic maps without turning a costmap's inflation band into unknown space; a ternary map
    translates as the original, and free_threshold 0 gives the original's frontiers for any map.
    """
    i = np.arange(256, dtype=np.int64)
    table = ((1 + (251 * (i - 1)) // 97) % 256).astype(np.uint8)
    table[0] = FREE_SPACE
    table[99] = INSCRIBED_INFLATED_OBSTACLE
    table[100] = LETHAL_OBSTACLE
    table[255] = NO_INFORMATION
    if probability_map or by_threshold:
        if not 0 <= free_threshold < occupied_threshold <= 100:
            raise ValueError(f"need 0 <= free_threshold ({free_threshold}) < occupied_threshold "
                             f"({occupied_threshold}) <= 100")
        if probability_map:
            table[:101] = NO_INFORMATION
        table[:free_threshold + 1] = FREE_SPACE
        table[occupied_threshold:101] = LETHAL_OBSTACLE
    return table


ORIGINAL_TABLE = translation_table()
INVALID = slice(OCCUPIED_MAX + 1, NO_INFORMATION)   # bytes 101..254: int8 values 101..127 and -128..-2


def count_invalid(values: np.ndarray) -> int:
    """How many occupancy bytes are invalid (101..254)."""
    return int(np.count_nonzero((values > OCCUPIED_MAX) & (values < NO_INFORMATION)))


def as_occupancy_bytes(data: CellData) -> np.ndarray:
    """Flat uint8 view/copy of occupancy values, reinterpreting int8 as unsigned (−1 → 255) like static_cast."""
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.uint8)
    arr = np.asarray(data)
    if arr.size == 0:
        return np.zeros(0, dtype=np.uint8)
    if arr.dtype == np.int8 or arr.dtype == np.uint8:
        return arr.reshape(-1).view(np.uint8)
    if arr.dtype.kind not in 'iu':
        raise InvalidMapError(f"occupancy data must be integers, got dtype {arr.dtype}")
    # The low byte is what the int8 message field holds; out-of-range ints cannot come from a message.
    return (arr.reshape(-1).astype(np.int64) & 0xFF).astype(np.uint8)


def translate(data: CellData, table: Optional[np.ndarray] = None) -> np.ndarray:
    """Translate occupancy values (any shape, int8 semantics) to cost bytes, flat uint8."""
    return (ORIGINAL_TABLE if table is None else table)[as_occupancy_bytes(data)]


class Costmap:
    """The explorer's grid plus its geometry; thread-safe through ``lock`` (held by updates and by the search)."""

    def __init__(self, probability_map: bool = False, free_threshold: int = 25, occupied_threshold: int = 65,
                 by_threshold: bool = False) -> None:
        self.table = translation_table(probability_map, free_threshold, occupied_threshold, by_threshold)
        self.table[INVALID] = NO_INFORMATION   # invalid occupancies read as unknown (module doc)
        self.lock = threading.RLock()
        self.data = np.zeros((0, 0), dtype=np.uint8)
        self.resolution = 0.0
        self.origin_x = 0.0
        self.origin_y = 0.0
        self.frame_id = ''
        self.has_map = False

    @property
    def size_x(self) -> int:
        return int(self.data.shape[1])

    @property
    def size_y(self) -> int:
        return int(self.data.shape[0])

    # -- geometry (costmap_2d semantics) ---------------------------------------------------------------------------

    def world_to_map(self, wx: float, wy: float) -> Optional[Tuple[int, int]]:
        """Cell (mx, my) containing world point (wx, wy), or None outside the grid (truncation as costmap_2d)."""
        if not (math.isfinite(wx) and math.isfinite(wy)) or self.resolution <= 0.0:
            return None
        if wx < self.origin_x or wy < self.origin_y:
            return None
        mx = int((wx - self.origin_x) / self.resolution)
        my = int((wy - self.origin_y) / self.resolution)
        if mx < self.size_x and my < self.size_y:
            return mx, my
        return None

    def map_to_world(self, mx: float, my: float) -> Tuple[float, float]:
        """World coordinates of the centre of cell (mx, my)."""
        return self.origin_x + (mx + 0.5) * self.resolution, self.origin_y + (my + 0.5) * self.resolution

    def index(self, mx: int, my: int) -> int:
        """Flat row-major index of cell (mx, my)."""
        return my * self.size_x + mx

    # -- message application ---------------------------------------------------------------------------------------

    def update_full(self, width: int, height: int, resolution: float, origin_x: float, origin_y: float,
                    data: CellData, frame_id: str = '') -> int:
        """Apply a full OccupancyGrid: re-allocate to width×height and translate min(width·height, len(data)) cells;
        returns the number of invalid occupancies read as unknown.

        Cells without data are NO_INFORMATION (the original leaves its uninitialised default, in practice 0;
        unknown is the honest value). Extra data is ignored. Raises InvalidMapError and leaves the grid unchanged on
        a negative/huge size, a non-positive or non-finite resolution, a non-finite origin or non-integer data.
        """
        width, height = int(width), int(height)
        if width < 0 or height < 0 or width * height > MAX_CELLS:
            raise InvalidMapError(f"invalid map size {width} x {height}")
        if not (math.isfinite(resolution) and resolution > 0.0):
            raise InvalidMapError(f"map resolution {resolution} is not a positive finite number")
        if not (math.isfinite(origin_x) and math.isfinite(origin_y)):
            raise InvalidMapError(f"map origin ({origin_x}, {origin_y}) is not finite")
        values = as_occupancy_bytes(data)
        n = width * height
        grid = np.full(n, NO_INFORMATION, dtype=np.uint8)
        m = min(n, values.size)
        grid[:m] = self.table[values[:m]]
        if values.size < n:
            _log.warning("full map has %d values for %d x %d cells; the rest is unknown", values.size, width, height)
        _log.debug("received full new map, resizing to: %d, %d", width, height)
        with self.lock:
            self.data = grid.reshape(height, width)
            self.resolution = float(resolution)
            self.origin_x = float(origin_x)
            self.origin_y = float(origin_y)
            self.frame_id = frame_id
            self.has_map = True
        return count_invalid(values[:m])

    def update_partial(self, x: int, y: int, width: int, height: int, data: CellData, frame_id: str = '') -> int:
        """Apply an OccupancyGridUpdate patch, clipped to the grid; size, resolution and origin never change.
        Returns the number of invalid occupancies (read as unknown) in the copied part.

        Raises InvalidUpdateError (grid and frame unchanged) for a negative corner (the original logs ERROR and drops
        it), fewer than width·height values (the original reads past the buffer), or no full map yet. A patch that
        sticks out of the grid logs WARN and its in-grid part is copied with the patch's own row stride (the original
        uses a wrong stride when clipped on the right; this port fixes that).
        """
        x, y, width, height = int(x), int(y), int(width), int(height)
        if x < 0 or y < 0:
            raise InvalidUpdateError(f"negative coordinates, invalid update. x: {x}, y: {y}")
        if width < 0 or height < 0:
            raise InvalidUpdateError(f"negative update size {width} x {height}")
        values = as_occupancy_bytes(data)
        if values.size < width * height:
            raise InvalidUpdateError(f"update of {width} x {height} cells carries only {values.size} values")
        with self.lock:
            if not self.has_map:
                raise InvalidUpdateError("partial update received before any full map")
            sx, sy = self.size_x, self.size_y
            xn, yn = x + width, y + height
            if xn > sx or yn > sy:
                _log.warning("received update doesn't fully fit into existing map, only part will be copied. "
                             "received: [%d, %d], [%d, %d] map is: [0, %d], [0, %d]", x, xn, y, yn, sx, sy)
            cw, ch = max(0, min(xn, sx) - x), max(0, min(yn, sy) - y)
            invalid = 0
            if cw and ch:
                patch = values[:width * height].reshape(height, width)[:ch, :cw]
                self.data[y:y + ch, x:x + cw] = self.table[patch]
                invalid = count_invalid(patch)
            self.frame_id = frame_id
        return invalid
