"""Stage 1 of estimation: per-grid preparation and feature detection.

Grids arrive trinary (-1/0/100: MergingPipeline.feed reads probabilistic maps through admission.trinary_cells).
Each grid is cropped to its known part (hector-style canvases are mostly unknown), brought to the common working
resolution, and described by keypoints + descriptors, its wall pixels and a nearest-wall lookup used by refinement
and verification. Results are cached per grid content, so an unchanged grid is never processed twice.
"""
from __future__ import annotations

import hashlib
import logging
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import NamedTuple, Optional, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from ..admission import FREE_THRESHOLD, OCCUPIED_THRESHOLD, check_thresholds
from ..grid import Grid, crop_to_known
from .validation import must_be_positive

log = logging.getLogger('rosout.multirobot_map_merge.estimation.features')

FEATURE_TYPES = ('akaze', 'orb', 'sift')
# keypoints kept per grid, strongest first: at most this many per m² of its known area, and never fewer than
# KEYPOINTS_KEPT (the dev maps have 2 per m² at the median, the hospital's 4; matching costs the product of two
# grids' counts, and the weakest place no map of the dev set that the others do not, at over a quarter of the time)
KEYPOINTS_PER_M2 = 1.5
KEYPOINTS_KEPT = 400
CROP_MARGIN = 4  # cells kept around the known part, so features at its border see some context


@dataclass
class FeatureSettings:
    feature: str = 'akaze'            # keypoint detector: akaze (as the C++ node), orb (as the thesis) or sift
    min_work_resolution: float = 0.05  # m/pixel: finer maps are matched at this resolution
    # how a grid's occupancies are read for matching (admission.trinary_cells): <= free_threshold free,
    # >= occupied_threshold a wall, the values between (a probabilistic map's uncertain cells) unknown
    free_threshold: int = FREE_THRESHOLD
    occupied_threshold: int = OCCUPIED_THRESHOLD

    def validate(self) -> None:
        if self.feature not in FEATURE_TYPES:
            raise ValueError(f"feature must be one of {', '.join(FEATURE_TYPES)}, not '{self.feature}'")
        must_be_positive(self, 'min_work_resolution')
        check_thresholds(self.free_threshold, self.occupied_threshold)


class WallFields(NamedTuple):
    """What matching reads about a working grid's walls (wall_fields)."""
    walls: np.ndarray           # (M, 2) float pixel coordinates of occupied pixels
    wall_distance: np.ndarray   # float32 distance (pixels) of every pixel to the nearest occupied pixel
    nearest_wall: np.ndarray    # (H, W) index into `walls` of the nearest occupied pixel (-1 if none)
    free_side: np.ndarray       # (H, W, 2) float32 direction towards nearby free space (see free_side_field)
    wall_normals: np.ndarray    # (M, 2) free_side at each wall pixel
    known_depth: np.ndarray     # (H, W) float32 distance (pixels) of every pixel to the nearest unknown one


def wall_fields(work: np.ndarray) -> WallFields:
    """The wall fields of a working grid (occupied: >= 50)."""
    occupied = work >= 50
    wall_rows, wall_cols = np.nonzero(occupied)
    walls = np.column_stack([wall_cols, wall_rows]).astype(np.float64)
    if len(walls):
        dist, labels = cv2.distanceTransformWithLabels(np.where(occupied, 0, 255).astype(np.uint8), cv2.DIST_L2,
                                                       cv2.DIST_MASK_PRECISE, labelType=cv2.DIST_LABEL_PIXEL)
        # labels number the zero pixels in row-major scan order, the order of np.nonzero; int32 as OpenCV gives
        # them (half of int64's bytes in every grid kept and sent to the matching processes)
        nearest = labels - 1
    else:
        dist = np.full(work.shape, np.inf, np.float32)
        nearest = np.full(work.shape, -1, np.int32)
    side = free_side_field(work)
    return WallFields(walls, dist, nearest, side, side[wall_rows, wall_cols].astype(np.float64), known_depth(work))


@dataclass
class PreparedGrid:
    """A grid ready for matching. Pixel coordinates are (x = column, y = row) of the working image.

    Its wall fields (WallFields: walls, wall_distance, nearest_wall, free_side, wall_normals, known_depth) are
    computed on first use, and detection at describe(): in a live fleet most maps change between two estimations,
    and a map whose placement stands on tracking's verdict is not matched (a replay of the 30-robot node: 0.25-0.34 s
    of an estimation's 0.8-2 s of CPU prepared 30 grids while 19-23 of its 24 placements stood)."""
    work: np.ndarray            # int8 working grid (-1/0/100), cropped and resampled
    px_to_map: np.ndarray       # 3x3: working pixel centre -> metric point of the grid's own map frame
    keypoints: np.ndarray       # (N, 2) float pixel coordinates
    descriptors: Optional[np.ndarray]
    resolution: float           # working resolution (m/pixel)
    feature: Optional[str] = None    # the detector describe() runs while keypoints is None
    # a union's: (a member's descriptors, the rows of it pooled here) in the order of `descriptors` (neighbours.py)
    descriptor_parts: Optional[list] = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)
    derived: dict = field(default_factory=dict, repr=False, compare=False)   # what later stages derive, kept
    _fields: Optional[WallFields] = field(default=None, repr=False, compare=False)
    _fields_lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    @property
    def draw_key(self) -> int:
        """The grid's content as a number: it seeds the random draws of the grid's matches (with the other grid's
        and the settings' seed), so that they draw alike whatever place the grids have in the order they came in
        (merge_maps' files, a node's robots). Seeded by the grids' places in that order, the same 36 maps gave 15 or
        27 placed maps by the order of their files (the held-out school36_u)."""
        key = self.derived.get('draw_key')
        if key is None:
            digest = hashlib.blake2b(self.work.tobytes(), digest_size=8)
            digest.update(np.asarray(self.work.shape, np.int64).tobytes())
            key = self.derived['draw_key'] = int.from_bytes(digest.digest(), 'little')
        return key

    def wall_fields(self) -> WallFields:
        """The wall fields, computed once (thread safe)."""
        fields = self._fields
        if fields is None:
            with self._fields_lock:
                if self._fields is None:
                    self._fields = wall_fields(self.work)
                fields = self._fields
        return fields

    walls = property(lambda self: self.wall_fields().walls)
    wall_distance = property(lambda self: self.wall_fields().wall_distance)
    nearest_wall = property(lambda self: self.wall_fields().nearest_wall)
    free_side = property(lambda self: self.wall_fields().free_side)
    wall_normals = property(lambda self: self.wall_fields().wall_normals)
    known_depth = property(lambda self: self.wall_fields().known_depth)

    def __getstate__(self) -> dict:
        # sent to the matching processes (workers.py): without the lock, which the copy gets afresh
        state = dict(self.__dict__)
        del state['_lock'], state['_fields_lock']
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock, self._fields_lock = threading.Lock(), threading.Lock()

    @property
    def known_pixels(self) -> int:
        return int((self.work >= 0).sum())

    def describe(self) -> 'PreparedGrid':
        """Detect keypoints and descriptors now if they were left for later (prepare(..., lazy=True)): a placement
        that tracking confirms needs none, so a live fleet whose robots are all placed runs no detector."""
        with self._lock:
            if self.keypoints is None:
                self.keypoints, self.descriptors = detect(self.work, self.feature, self.resolution)
        return self

    def nearest(self, pts: np.ndarray):
        """Nearest wall pixel and its distance for each point (distance inf outside the image or with no walls)."""
        h, w = self.work.shape
        x = np.rint(pts[:, 0]).astype(np.int64)
        y = np.rint(pts[:, 1]).astype(np.int64)
        inside = (x >= 0) & (y >= 0) & (x < w) & (y < h)
        nn = np.zeros_like(pts)
        dist = np.full(len(pts), np.inf)
        if len(self.walls):
            idx = self.nearest_wall[y[inside], x[inside]]
            nn[inside] = self.walls[idx]
            dist[inside] = np.hypot(*(nn[inside] - pts[inside]).T)
        return nn, dist


def resample(data: np.ndarray, scale: float) -> np.ndarray:
    """Resample an int8 grid by `scale` (output pixels per input cell), keeping thin walls when shrinking."""
    if abs(scale - 1.0) < 1e-9:
        return data
    h, w = data.shape
    size = (max(int(round(w * scale)), 1), max(int(round(h * scale)), 1))
    if scale > 1.0:
        return cv2.resize(data.view(np.uint8), size, interpolation=cv2.INTER_NEAREST).view(np.int8)
    occ = cv2.resize((data == 100).astype(np.float32), size, interpolation=cv2.INTER_AREA) > 0.0
    free = cv2.resize((data == 0).astype(np.float32), size, interpolation=cv2.INTER_AREA) >= 0.5
    out = np.full(occ.shape, -1, np.int8)
    out[free] = 0
    out[occ] = 100
    return out


def known_depth(work: np.ndarray) -> np.ndarray:
    """Distance (pixels) of every pixel to the nearest unknown pixel; outside the image counts as unknown."""
    known = np.pad(np.where(work >= 0, 255, 0).astype(np.uint8), 1)
    return cv2.distanceTransform(known, cv2.DIST_L2, 3)[1:-1, 1:-1]


def free_side_field(work: np.ndarray) -> np.ndarray:
    """(H, W, 2) direction (unnormalised, x then y) from each pixel towards the free space next to it.

    A robot maps only the face of a wall it sees, so a wall pixel's free side tells from where it was seen; near
    zero for a wall with free space on both sides.
    """
    free = cv2.GaussianBlur((work == 0).astype(np.float32), (0, 0), 2.0)
    return np.dstack([cv2.Sobel(free, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(free, cv2.CV_32F, 0, 1, ksize=3)])


def nonzero_2d(mask: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """np.nonzero of a 2-D array (rows, columns, row-major order), several times faster: numpy's is slow in 2-D,
    and the verification and the search call it thousands of times."""
    flat = np.flatnonzero(mask)
    return np.divmod(flat, mask.shape[1])


def opposed(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Where two free-side directions point against each other: the walls there were seen from opposite sides."""
    return opposed_xy(a[..., 0], a[..., 1], b[..., 0], b[..., 1])


def opposed_xy(ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    """opposed() of directions given as coordinate arrays (no (N, 2) temporaries: ICP calls it per step)."""
    return ax * bx + ay * by < -0.3 * np.sqrt((ax * ax + ay * ay) * (bx * bx + by * by)) - 1e-6


def feature_image(work: np.ndarray) -> np.ndarray:
    """8-bit image for the detector: free white, unknown grey, occupied black (probabilities shaded)."""
    img = np.full(work.shape, 128, np.uint8)
    known = work >= 0
    img[known] = (255 - work[known].astype(np.int32) * 255 // 100).astype(np.uint8)
    return img


def make_detector(kind: str):
    if kind == 'akaze':
        # a lower threshold than OpenCV's default: map corners are few and weak
        return cv2.AKAZE_create(threshold=0.0005)
    if kind == 'orb':
        return cv2.ORB_create(nfeatures=4000, scaleFactor=1.2, nlevels=4, edgeThreshold=15, patchSize=15,
                              fastThreshold=10)
    if kind == 'sift':
        return cv2.SIFT_create()
    raise ValueError(f"unknown feature type '{kind}' (choose from {', '.join(FEATURE_TYPES)})")


def prepare(grid: Grid, work_resolution: float, feature: Optional[str], lazy: bool = False) -> Optional[PreparedGrid]:
    """Crop, resample and describe one grid (no keypoints if feature is None; with `lazy`, only at describe());
    None if no cell is known."""
    box = crop_to_known(grid.data, CROP_MARGIN)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    scale = grid.resolution / work_resolution
    work = resample(grid.data[r0:r1, c0:c1], scale)
    # working pixel u covers cells [u/scale, (u+1)/scale) of the crop: its centre is cell c0 + (u + 0.5)/scale
    px_to_cell = np.array([[1.0 / scale, 0.0, c0 + 0.5 / scale], [0.0, 1.0 / scale, r0 + 0.5 / scale], [0, 0, 1.0]])
    px_to_map = grid.cell_to_map() @ px_to_cell

    pts, descriptors = (None, None) if lazy else detect(work, feature, work_resolution)
    prepared = PreparedGrid(work, px_to_map, pts, descriptors, work_resolution, feature)
    if not lazy:
        prepared.wall_fields()
    return prepared


def detect(work: np.ndarray, feature: Optional[str], resolution: float = 0.05):
    """(keypoints (N, 2), descriptors) of a working grid (`resolution` m/pixel), the strongest KEYPOINTS_PER_M2 of
    its known area (at least KEYPOINTS_KEPT); none without a feature type (walls only)."""
    keypoints, descriptors = (make_detector(feature).detectAndCompute(feature_image(work), None) if feature
                              else ((), None))
    kept = max(KEYPOINTS_KEPT, int(KEYPOINTS_PER_M2 * np.count_nonzero(work >= 0) * resolution ** 2))
    if len(keypoints) > kept:
        order = np.sort(np.argsort([-k.response for k in keypoints], kind='stable')[:kept])
        keypoints = [keypoints[i] for i in order]
        descriptors = descriptors[order]
    return np.array([k.pt for k in keypoints], np.float64).reshape(-1, 2), _word_aligned(descriptors)


def _word_aligned(descriptors: Optional[np.ndarray]) -> Optional[np.ndarray]:
    """Binary descriptors zero-padded to a multiple of 8 bytes: the Hamming distance is the same, and OpenCV
    counts bits 8 bytes at a time (AKAZE's 61 bytes: its matching 1.1-1.3 times faster at 64)."""
    if descriptors is None or descriptors.dtype != np.uint8 or descriptors.shape[1] % 8 == 0:
        return descriptors
    padded = np.zeros((descriptors.shape[0], -(-descriptors.shape[1] // 8) * 8), np.uint8)
    padded[:, :descriptors.shape[1]] = descriptors
    return padded


def content_key(grid: Grid) -> str:
    h = hashlib.blake2b(grid.data.tobytes(), digest_size=16)
    h.update(repr((grid.data.shape, grid.resolution, grid.origin)).encode())
    return h.hexdigest()


class FeatureCache:
    """Prepared grids by content; bounded, thread safe. Unchanged grids are not recomputed."""

    def __init__(self, capacity: int = 256):
        self._items: "OrderedDict[tuple, Optional[PreparedGrid]]" = OrderedDict()
        self._capacity = capacity
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, grid: Grid, work_resolution: float, feature: str) -> Optional[PreparedGrid]:
        key = (content_key(grid), round(work_resolution, 9), feature)
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                self.hits += 1
                return self._items[key]
        prepared = prepare(grid, work_resolution, feature, lazy=True)
        with self._lock:
            self.misses += 1
            self._items[key] = prepared
            while len(self._items) > self._capacity:
                self._items.popitem(last=False)
        return prepared



def map_keypoints(p: PreparedGrid):
    """p's keypoints as points of its grid's map frame (metres), and their descriptors (detected now if need be)."""
    p.describe()
    return tf.apply(p.px_to_map, p.keypoints), p.descriptors


def pooled_keypoints(parts, px_to_map: np.ndarray, shape, radius: float = 3.0):
    """Keypoints and descriptors of a union image, pooled from those of the grids it is composed of.

    `parts` are (keypoints in the grid's map frame (metres), descriptors, metric transform of that map frame into
    the union's). Each part's keypoints are brought into the union's pixels (rotation-invariant descriptors stay
    valid); a keypoint within `radius` pixels of one already taken is the same corner seen again and left out, so
    that the ratio test still finds one nearest neighbour per corner. No detection runs on the union. Returns the
    keypoints, their descriptors, and (each part's descriptors, the rows of it taken) in that order."""
    h, w = shape
    taken = np.zeros((h // int(radius) + 1, w // int(radius) + 1), bool)
    points, descriptors, taken_rows = [], [], []
    to_px = np.linalg.inv(px_to_map)
    for keypoints, part_descriptors, t in parts:
        if part_descriptors is None or not len(keypoints):
            continue
        pts = tf.apply(to_px @ t, keypoints)
        inside = (pts[:, 0] >= 0) & (pts[:, 1] >= 0) & (pts[:, 0] < w) & (pts[:, 1] < h)
        cells = (pts[inside] // radius).astype(np.int64)
        fresh = ~taken[cells[:, 1], cells[:, 0]]
        # a part's own keypoints closer than radius to each other all stay: they are distinct in that part
        taken[cells[fresh, 1], cells[fresh, 0]] = True
        idx = np.flatnonzero(inside)[fresh]
        points.append(pts[idx])
        descriptors.append(part_descriptors[idx])
        taken_rows.append((part_descriptors, idx))
    if not points:
        return np.zeros((0, 2)), None, []
    return np.vstack(points), np.vstack(descriptors), taken_rows
