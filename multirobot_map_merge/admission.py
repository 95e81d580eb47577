"""Admission: the one place where a grid entering the merge is validated and normalised (no ROS import).

Every grid the merge uses (node, both loops; offline merge_maps) passes `admit` through MergingPipeline.feed:
  * cell values: ROS defines -1 (unknown) and 0..100; any other value (-128..-2, 101..127) is read as unknown (-1).
    The grid is kept; the number of such cells is reported so that the caller can warn (throttled, naming the robot).
  * cell values, for matching only (feed(matching=True)): SLAM packages publish trinary maps (gmapping,
    slam_toolbox, map_server: -1/0/100) or probabilities (Cartographer: 0..100, cells seen once near 50). The
    estimation reads every grid as trinary, through two thresholds (map_saver's and explore_lite's): <= free_threshold
    is free, >= occupied_threshold a wall, the values between unknown (too uncertain to match). A trinary grid is
    unchanged. The composed grid keeps the values as published (compose.py combines them as the original).
  * size, for matching only (feed(matching=True), what estimation uses): a grid whose known part, at the
    estimation's working resolution, would exceed MAX_MATCH_PIXELS (e.g. 1 km cells) or span fewer than 2 pixels in a
    direction (one known row; or 1 um cells) is left out ("refused"): such a map cannot be matched, and the feature
    detectors fail on it, which would stop the estimation of the others. It is still composed at a known pose.
Geometry (a 2-D array of at most MAX_CELLS cells, finite positive resolution, finite origin) is already an invariant
of Grid (GridError at construction). Placement problems (non-finite, or a merged grid over MAX_CELLS) are handled
where placements meet, in compose: the robot is left out of that cycle.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from .grid import FREE, OCCUPIED, UNKNOWN, Grid, crop_to_known

# A map larger than this at the working resolution (8192 x 8192 pixels, 410 m square at 5 cm; 16 x the largest dev
# map) cannot be matched in a useful time: estimating it would stall the placement of every robot.
MAX_MATCH_PIXELS = 1 << 26

# map_saver's and explore_lite's thresholds: occupancy <= 25 is free, >= 65 occupied
FREE_THRESHOLD = 25
OCCUPIED_THRESHOLD = 65


@dataclass(frozen=True)
class Admission:
    grid: Optional[Grid]      # the grid to compose (cells normalised), None when there is none (or it is empty)
    invalid_cells: int = 0    # cells read as unknown because their value was outside {-1} and 0..100
    refused: str = ''         # why the grid cannot be matched ('' when it can, or when not asked)
    matching: Optional[Grid] = None   # the grid to match, trinary (`grid` itself when it is); None when not asked


def clean_cells(data: np.ndarray) -> Tuple[np.ndarray, int]:
    """(data with every value outside {-1} and 0..100 set to -1, how many were); `data` itself when all are valid."""
    if data.size == 0 or (int(data.min()) >= UNKNOWN and int(data.max()) <= OCCUPIED):
        return data, 0   # the common case: two reductions, no copy
    bad = (data < UNKNOWN) | (data > OCCUPIED)
    out = data.copy()
    out[bad] = UNKNOWN
    return out, int(np.count_nonzero(bad))


def check_thresholds(free_threshold: int, occupied_threshold: int) -> None:
    """ValueError unless 0 <= free_threshold < occupied_threshold <= 100 (integers)."""
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in (free_threshold, occupied_threshold)) or \
            not FREE <= free_threshold < occupied_threshold <= OCCUPIED:
        raise ValueError(f'need integers 0 <= free_threshold ({free_threshold!r}) < occupied_threshold '
                         f'({occupied_threshold!r}) <= 100')


def trinary_cells(data: np.ndarray, free_threshold: int = FREE_THRESHOLD,
                  occupied_threshold: int = OCCUPIED_THRESHOLD) -> np.ndarray:
    """Valid cells (-1, 0..100) read as -1/0/100: <= free_threshold free, >= occupied_threshold occupied, the rest
    unknown; `data` itself when that changes nothing (a trinary grid: one pass, no copy)."""
    between = (data > FREE) & (data < OCCUPIED)
    if not between.any():
        return data
    out = np.full(data.shape, UNKNOWN, np.int8)
    out[(data >= FREE) & (data <= free_threshold)] = FREE
    out[data >= occupied_threshold] = OCCUPIED
    return out


def known_extent(data: np.ndarray) -> Tuple[int, int]:
    """(rows, cols) of the bounding box of the known cells, (0, 0) when none."""
    box = crop_to_known(data, margin=0)
    return (0, 0) if box is None else (int(box[1] - box[0]), int(box[3] - box[2]))


def matching_refusal(data: np.ndarray, resolution: float, min_work_resolution: float) -> str:
    """Why a grid (cells already clean) cannot be matched, or ''. The working resolution of an estimation is
    max(finest resolution, min_work_resolution): so a grid is shrunk by exactly resolution / min_work_resolution when
    finer than min_work_resolution, and enlarged by at most resolution / min_work_resolution otherwise."""
    rows, cols = known_extent(data)
    if rows == 0:
        return ''   # nothing known: the estimation skips it
    most = max(resolution / min_work_resolution, 1.0)    # working pixels per cell, per axis, at most
    least = min(resolution / min_work_resolution, 1.0)   # and at least
    if rows * cols * most * most > MAX_MATCH_PIXELS:
        return (f'its known part ({cols} x {rows} cells of {resolution:g} m) would be {rows * cols * most * most:.3g} '
                f'pixels at the working resolution {min_work_resolution:g} m (limit {MAX_MATCH_PIXELS}): not matched')
    if min(rows, cols) * least < 2.0:
        return (f'its known part ({cols} x {rows} cells of {resolution:g} m) spans less than 2 pixels at the '
                f'working resolution {min_work_resolution:g} m: too small to be matched')
    return ''


def admit(grid: Optional[Grid], min_work_resolution: Optional[float] = None, free_threshold: int = FREE_THRESHOLD,
          occupied_threshold: int = OCCUPIED_THRESHOLD) -> Admission:
    """Validate and normalise one grid for the merge (see the module doc for the rules); with
    `min_work_resolution` (for matching) also read it as trinary through the thresholds and refuse grids the
    estimation cannot match."""
    if grid is None or grid.is_empty():
        return Admission(None)
    data, invalid = clean_cells(grid.data)
    if invalid:
        grid = _with_data(grid, data)
    if not min_work_resolution:
        return Admission(grid, invalid)
    cells = trinary_cells(data, free_threshold, occupied_threshold)
    matching = grid if cells is data else _with_data(grid, cells)
    return Admission(grid, invalid, matching_refusal(cells, grid.resolution, min_work_resolution), matching)


def _with_data(grid: Grid, data: np.ndarray) -> Grid:
    return Grid(data, grid.resolution, grid.origin, grid.frame_id, grid.stamp, dict(grid.extra))


def describe_invalid(count: int) -> str:
    return (f'{count} cell(s) with values outside -1 and 0..100 (ROS occupancy) read as unknown')
