"""Composition: warp every placed grid into one merged grid.

Cells combine by signed maximum as the original (occupied > free > unknown); warping is nearest-neighbour;
everything outside every map is unknown. Each grid is warped only over its own known part and its own region of
the canvas, so many small maps on a large canvas stay cheap.
"""
from __future__ import annotations

import math
from collections import Counter
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np

from . import transforms as tf
from .grid import MAX_CELLS, UNKNOWN, Grid, GridError, crop_to_known

# merged-cell coordinates beyond this cannot be placed to a cell: a double holds 53 bits, and compose subtracts them
MAX_COORDINATE = float(1 << 40)

# index (pixel centre) coordinates are corner coordinates shifted by half a cell
_TO_CORNER = tf.translation(0.5, 0.5)
_TO_INDEX = tf.translation(-0.5, -0.5)


def warp_into(canvas: np.ndarray, src: np.ndarray, src_to_canvas: np.ndarray) -> None:
    """Max-combine `src` (int8) into `canvas` (int8) through a corner-coordinate cell transform src -> canvas."""
    patch = warped_patch(src, src_to_canvas, canvas.shape)
    if patch is not None:
        _combine(canvas, patch)


Patch = Tuple[int, int, np.ndarray]   # (x0, y0, cells): what a grid adds to a canvas, at column x0 and row y0


def warped_patch(src: np.ndarray, src_to_canvas: np.ndarray, canvas_shape: Tuple[int, int]) -> Optional[Patch]:
    """`src` (int8) warped through a corner-coordinate cell transform src -> canvas, over the part of a canvas of
    `canvas_shape` it covers (unknown around it); None when it covers none."""
    h, w = src.shape
    corners = tf.apply(src_to_canvas, np.array([[0, 0], [w, 0], [0, h], [w, h]], float))
    x0, y0 = np.floor(corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, canvas_shape[1]), min(y1, canvas_shape[0])
    if x1 <= x0 or y1 <= y0:
        return None
    index_map = _TO_INDEX @ tf.translation(-x0, -y0) @ src_to_canvas @ _TO_CORNER
    warped = cv2.warpAffine(src.view(np.uint8), index_map[:2], (x1 - x0, y1 - y0), flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=255).view(np.int8)
    return int(x0), int(y0), warped


def _combine(canvas: np.ndarray, patch: Patch) -> None:
    x0, y0, cells = patch
    region = canvas[y0:y0 + cells.shape[0], x0:x0 + cells.shape[1]]
    np.maximum(region, cells, out=region)


class PatchCache:
    """What each grid adds to the merged grid, kept from one compose() to the next while the grid (the same object:
    a Grid is never modified once made) lands on the same cells of a canvas of the same size. The node composes at
    merging_rate, mostly the same maps at the same places: warping them again was most of a composition (30 robots'
    final maps: 21 ms, warpAffine 59 % of it). Holds the grids of the last composition only."""

    def __init__(self) -> None:
        # id of a grid -> [the grid, its known box, where its patch landed, the patch]
        self._kept: Dict[int, list] = {}
        self._used: set = set()

    def _entry(self, grid: Grid) -> list:
        self._used.add(id(grid))
        kept = self._kept.get(id(grid))
        if kept is None or kept[0] is not grid:
            kept = self._kept[id(grid)] = [grid, crop_to_known(grid.data, margin=0), None, None]
        return kept

    def known_box(self, grid: Grid) -> Optional[Tuple[int, int, int, int]]:
        """crop_to_known(grid.data), computed once per grid."""
        return self._entry(grid)[1]

    def patch(self, grid: Grid, src: np.ndarray, src_to_canvas: np.ndarray,
              canvas_shape: Tuple[int, int]) -> Optional[Patch]:
        """warped_patch of `src` (the grid's known part), again only when it lands elsewhere."""
        kept = self._entry(grid)
        where = np.asarray(src_to_canvas, float).tobytes() + repr((src.shape, canvas_shape)).encode()
        if kept[2] != where:
            kept[2], kept[3] = where, warped_patch(src, src_to_canvas, canvas_shape)
        return kept[3]

    def end_composition(self) -> None:
        """Forget the grids the composition that ends did not use (robots gone, maps replaced)."""
        self._kept = {key: kept for key, kept in self._kept.items() if key in self._used}
        self._used = set()


def compose(grids: Sequence[Optional[Grid]], transforms: Sequence[Optional[np.ndarray]],
            resolution: Optional[float] = None, frame_id: str = '',
            left_out: Optional[Dict[int, str]] = None, max_cells: int = MAX_CELLS,
            within: Optional[Tuple[float, float, float, float]] = None,
            cache: Optional[PatchCache] = None) -> Optional[Grid]:
    """Merge grids placed by metric transforms (map frame of grid k -> merged frame).

    The merged grid has `resolution` (default: that of the first placed grid whose transform is the identity, else
    of the first placed grid; when that leaves grids out and more placed grids share another resolution, that one)
    and its origin is the corner of the smallest canvas holding every known cell. Returns None when no grid with a
    known cell is placed. A grid whose placement is not finite, or that would make the merged grid larger than
    `max_cells` (at most MAX_CELLS), is left out (see select_parts); `left_out` (if given) receives its index and
    the reason. With `within` (x0, y0, x1, y1, metres of the merged frame), only the cells of the merged grid that
    meet that box are composed and returned (None if none): the whole merged grid's cells there, without warping the
    rest (but for a cell now and then on a rounding edge of a turned grid: OpenCV rounds within its output window).
    With a `cache` (not with `within`), what each grid adds is reused from the last composition where it is the
    same: the same merged grid. GridError only for a bad `resolution` argument.
    """
    if cache is not None and within is not None:
        raise ValueError('compose: a cache composes whole merged grids, not within a box')
    try:
        return _compose(grids, transforms, resolution, frame_id, left_out, max_cells, within, cache)
    finally:
        if cache is not None:
            cache.end_composition()


def _compose(grids, transforms, resolution, frame_id, left_out, max_cells, within, cache) -> Optional[Grid]:
    placed = [(k, g, t) for k, (g, t) in enumerate(zip(grids, transforms))
              if g is not None and t is not None and not g.is_empty()]
    default = resolution
    if default is None:
        ref = next((g for _, g, t in placed if np.allclose(t, np.eye(3))), placed[0][1] if placed else None)
        default = ref.resolution if ref is not None else 0.0
    parts, metric = [], {}
    with np.errstate(all='ignore'):   # absurd placements overflow to inf / nan: select_parts leaves them out
        for k, g, t in placed:
            box = cache.known_box(g) if cache is not None else crop_to_known(g.data, margin=0)
            if box is None:
                continue
            r0, r1, c0, c1 = box
            d = g.data[r0:r1, c0:c1]
            crop_to_merged = np.asarray(t, float) @ g.cell_to_map() @ tf.translation(c0, r0)
            parts.append((k, g, d, crop_to_merged))
            corners = tf.apply(crop_to_merged, np.array([[0, 0], [d.shape[1], 0], [0, d.shape[0]],
                                                         [d.shape[1], d.shape[0]]], float))
            metric[k] = np.concatenate([corners.min(axis=0), corners.max(axis=0)])   # x0 y0 x1 y1 (m)
    if not parts:
        return None
    if not (math.isfinite(default) and default > 0):
        raise GridError(f'merged resolution {default} is not a positive number')
    max_cells = min(max_cells, MAX_CELLS)
    chosen = default
    keep, reasons = _select(metric, chosen, max_cells)
    if resolution is None and len(keep) < len(metric):
        # the default resolution (the original's rule) may itself come from an absurd map (1 um cells): then the
        # resolution most placed grids share is taken. Not the one that keeps most grids: a coarse absurd one
        # (10 m cells) keeps everything, and blurs every good map to nothing
        shared = Counter(g.resolution for k, g, _ in placed if k in metric)
        common, count = shared.most_common(1)[0]
        if count > shared[chosen]:
            chosen = common
            keep, reasons = _select(metric, chosen, max_cells)
    resolution = chosen
    if left_out is not None:
        left_out.update(reasons)
    parts = [p for p in parts if p[0] in keep]
    if not parts:
        return None
    box = np.array([metric[p[0]] for p in parts]) / resolution
    lo = np.floor(box[:, :2].min(axis=0)) * resolution
    hi = np.ceil(box[:, 2:].max(axis=0)) * resolution
    width, height = (int(round(v)) for v in (hi - lo) / resolution)
    c0, r0, c1, r1 = 0, 0, max(width, 1), max(height, 1)
    if within is not None:
        c0, r0 = max(int(math.floor((within[0] - lo[0]) / resolution)), 0), \
            max(int(math.floor((within[1] - lo[1]) / resolution)), 0)
        c1, r1 = min(int(math.ceil((within[2] - lo[0]) / resolution)), c1), \
            min(int(math.ceil((within[3] - lo[1]) / resolution)), r1)
        if c1 <= c0 or r1 <= r0:
            return None
    canvas = np.full((r1 - r0, c1 - c0), UNKNOWN, np.int8)
    merged_to_canvas = tf.translation(-c0, -r0) @ tf.scaling(1.0 / resolution) @ tf.translation(-lo[0], -lo[1])
    for _, g, data, crop_to_merged in parts:
        to_canvas = merged_to_canvas @ crop_to_merged
        patch = cache.patch(g, data, to_canvas, canvas.shape) if cache is not None else \
            warped_patch(data, to_canvas, canvas.shape)
        if patch is not None:
            _combine(canvas, patch)
    return Grid(canvas, resolution, (float(lo[0]) + c0 * resolution, float(lo[1]) + r0 * resolution, 0.0), frame_id)


def _select(metric: Dict[int, np.ndarray], resolution: float, max_cells: int) -> Tuple[List[int], Dict[int, str]]:
    with np.errstate(all='ignore'):
        return select_parts({k: b / resolution for k, b in metric.items()}, max_cells)


def _cells(box: np.ndarray) -> float:
    """Cells of the canvas holding a box (x0, y0, x1, y1 in cells), as compose rounds it."""
    with np.errstate(all='ignore'):   # huge boxes overflow to inf, which compares as too large
        return float(np.prod(np.ceil(box[2:]) - np.floor(box[:2]) + 1.0))


def select_parts(boxes: Dict[int, np.ndarray], max_cells: int = MAX_CELLS) -> Tuple[List[int], Dict[int, str]]:
    """Which placed grids (index -> bounding box in merged cells) can be merged into one canvas of at most
    `max_cells` cells; returns (kept indices, left-out index -> reason).

    A box that is not finite is left out. If all the others together fit, all are kept (the usual case).
    Otherwise the largest group that fits is kept: each grid in turn anchors a group that takes the other grids
    nearest first while the canvas still fits; between groups of the same size the smaller canvas wins. So a
    minority of grids placed absurdly far away (bad origin or pose) cannot push the others out.
    """
    reasons = {k: 'its placement in the merged map is not finite (or beyond 2^40 cells, where a double loses the '
                  'cell)' for k, b in boxes.items() if not np.all(np.abs(b) <= MAX_COORDINATE)}
    finite = {k: b for k, b in boxes.items() if k not in reasons}
    if not finite:
        return [], reasons
    union = lambda bs: np.concatenate([np.min([b[:2] for b in bs], axis=0),   # noqa: E731
                                       np.max([b[2:] for b in bs], axis=0)])
    if _cells(union(list(finite.values()))) <= max_cells:
        return sorted(finite), reasons
    best: List[int] = []
    best_cells = math.inf
    for anchor in sorted(finite):
        if _cells(finite[anchor]) > max_cells:
            continue
        centre = (finite[anchor][:2] + finite[anchor][2:]) / 2.0
        order = sorted((k for k in finite if k != anchor),
                       key=lambda k: float(np.abs((finite[k][:2] + finite[k][2:]) / 2.0 - centre).max()))
        group, box = [anchor], finite[anchor]
        for k in order:
            grown = union([box, finite[k]])
            if _cells(grown) <= max_cells:
                group.append(k)
                box = grown
        if len(group) > len(best) or (len(group) == len(best) and _cells(box) < best_cells):
            best, best_cells = group, _cells(box)
    for k in finite:
        if k not in best:
            w, h = finite[k][2:] - finite[k][:2]
            reasons[k] = (f'its map ({w:.3g} x {h:.3g} merged cells) is too large or placed too far from the others: '
                          f'the merged grid would exceed {max_cells} cells')
    return sorted(best), reasons
