"""Map files in ROS 1 map_server format: load (map_server), save (map_saver) and PNG previews.

Loading follows map_server's image_loader.cpp / main.cpp (noetic):
  * every pixel's value is the mean of its channels; in trinary mode an alpha channel is averaged in too, in scale
    mode it is left out of the mean (images with an alpha channel only);
  * negate flips the mean (255 - mean) before p = (255 - mean) / 255;
  * p > occupied_thresh -> 100, p < free_thresh -> 0 (both strict), else trinary -> -1, scale -> -1 if
    alpha == 0 else trunc(1 + 98 * (p - free) / (occ - free)), raw -> trunc(mean) stored as int8 (255 -> -1);
  * image row 0 is the top (highest y), so rows are flipped.
Deliberate differences from map_server: palette PNGs are read by colour (map_server reads the palette index), 16-bit
images are reduced to 8 bits, and 3-channel images have no alpha (map_server takes the last colour byte as alpha).
"""
from __future__ import annotations

import logging
import math
import os
from typing import Any, Dict, Tuple

import cv2
import numpy as np
import yaml

from .grid import Grid, GridError

_log = logging.getLogger('rosout.mapio')

PGM_FREE, PGM_OCCUPIED, PGM_UNKNOWN = 254, 0, 205
MODES = ('trinary', 'scale', 'raw')


class MapFileError(Exception):
    """A map YAML or its image cannot be read or is invalid; the message names the file and the reason."""


# ---------------------------------------------------------------------------------------------------------------
# loading
# ---------------------------------------------------------------------------------------------------------------

def _number(meta: Dict[str, Any], key: str, path: str) -> float:
    if key not in meta:
        raise MapFileError(f"{path}: missing field '{key}'")
    v = meta[key]
    # bool is an int subclass in Python; 'resolution: true' is not a number
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise MapFileError(f"{path}: field '{key}' is not a number: {v!r}")
    if not math.isfinite(v):
        raise MapFileError(f"{path}: field '{key}' is not finite: {v!r}")
    return float(v)


def read_map_yaml(yaml_path: str) -> Dict[str, Any]:
    """Parse and validate a map YAML; returns a dict with image (absolute path), resolution, origin, negate,
    occupied_thresh, free_thresh and mode."""
    try:
        with open(yaml_path, 'r', encoding='utf-8') as f:
            text = f.read()
    except FileNotFoundError:
        raise MapFileError(f"{yaml_path}: map file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise MapFileError(f"{yaml_path}: cannot read map file: {e}") from None
    try:
        meta = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise MapFileError(f"{yaml_path}: invalid YAML: {e}") from None
    if not isinstance(meta, dict):
        raise MapFileError(f"{yaml_path}: not a YAML mapping of map fields")

    resolution = _number(meta, 'resolution', yaml_path)
    if resolution <= 0.0:
        raise MapFileError(f"{yaml_path}: resolution must be > 0, got {resolution}")

    if 'negate' not in meta:
        raise MapFileError(f"{yaml_path}: missing field 'negate'")
    negate = meta['negate']
    if isinstance(negate, bool):
        negate = int(negate)
    if not isinstance(negate, int):
        raise MapFileError(f"{yaml_path}: field 'negate' is not an integer: {negate!r}")

    occ = _number(meta, 'occupied_thresh', yaml_path)
    free = _number(meta, 'free_thresh', yaml_path)

    # map_server: a missing mode means trinary, an unknown one is fatal
    mode = meta.get('mode', 'trinary')
    if mode is None:
        mode = 'trinary'
    if not isinstance(mode, str) or mode not in MODES:
        raise MapFileError(f"{yaml_path}: invalid mode {mode!r} (expected one of {', '.join(MODES)})")

    if 'origin' not in meta:
        raise MapFileError(f"{yaml_path}: missing field 'origin'")
    origin = meta['origin']
    if not isinstance(origin, (list, tuple)) or len(origin) != 3 or \
            any(isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) for v in origin):
        raise MapFileError(f"{yaml_path}: field 'origin' must be [x, y, yaw] of finite numbers, got {origin!r}")

    if 'image' not in meta:
        raise MapFileError(f"{yaml_path}: missing field 'image'")
    image = meta['image']
    if not isinstance(image, str) or not image:
        raise MapFileError(f"{yaml_path}: field 'image' must be a non-empty file name, got {image!r}")
    if not os.path.isabs(image):
        # map_server: relative to the folder of the yaml file
        image = os.path.join(os.path.dirname(os.path.abspath(yaml_path)), image)

    return {'image': image, 'resolution': resolution, 'origin': tuple(float(v) for v in origin),
            'negate': negate, 'occupied_thresh': occ, 'free_thresh': free, 'mode': mode}


def read_image(image_path: str) -> np.ndarray:
    """Read an image as uint8 with 1, 3 (BGR) or 4 (BGRA) channels; MapFileError if it cannot be read."""
    if not os.path.isfile(image_path):
        raise MapFileError(f"{image_path}: image file not found")
    img = cv2.imread(image_path, cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise MapFileError(f"{image_path}: unreadable or unsupported image")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)   # what SDL/libpng do with 16-bit samples
    elif img.dtype != np.uint8:
        raise MapFileError(f"{image_path}: unsupported pixel type {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (3, 4)):
        raise MapFileError(f"{image_path}: unsupported image layout {img.shape}")
    return img


def image_to_data(img: np.ndarray, mode: str = 'trinary', negate: int = 0,
                  occupied_thresh: float = 0.65, free_thresh: float = 0.196) -> np.ndarray:
    """Pixels (row 0 = top) -> int8 grid data (row 0 = bottom) with map_server semantics."""
    if mode not in MODES:
        raise ValueError(f"invalid mode {mode!r}")
    img = np.asarray(img)
    if img.ndim == 2:
        color_avg = img.astype(np.float64)
        alpha_zero = np.zeros(img.shape, dtype=bool)
    else:
        n = img.shape[2]
        has_alpha = n == 4
        # trinary averages the alpha channel in with the colours (map_server keeps that legacy behaviour)
        avg_n = n - 1 if (has_alpha and mode != 'trinary') else n
        color_avg = img[:, :, :avg_n].astype(np.int32).sum(axis=2) / float(avg_n)
        alpha_zero = img[:, :, 3] == 0 if has_alpha else np.zeros(img.shape[:2], dtype=bool)
    if negate:
        color_avg = 255.0 - color_avg
    if mode == 'raw':
        # C++ double -> unsigned char truncates; the byte is then reinterpreted as int8
        out = np.trunc(color_avg).astype(np.uint8).view(np.int8)
        return np.ascontiguousarray(out[::-1])

    occ = (255.0 - color_avg) / 255.0   # same two IEEE operations as map_server, so threshold ties agree
    out = np.full(occ.shape, -1, dtype=np.int8)
    is_occ = occ > occupied_thresh
    is_free = ~is_occ & (occ < free_thresh)
    out[is_occ] = 100
    out[is_free] = 0
    if mode == 'scale':
        mid = ~is_occ & ~is_free & ~alpha_zero
        span = occupied_thresh - free_thresh
        ratio = (occ[mid] - free_thresh) / span if span != 0.0 else np.zeros(int(mid.sum()))
        out[mid] = np.trunc(1.0 + 98.0 * ratio).astype(np.int8)
    return np.ascontiguousarray(out[::-1])


def load_map(yaml_path: str, frame_id: str = '') -> Grid:
    """Load a map_server map (YAML + PGM/PNG) into a Grid; raises MapFileError naming the file and the reason."""
    meta = read_map_yaml(yaml_path)
    img = read_image(meta['image'])
    data = image_to_data(img, meta['mode'], meta['negate'], meta['occupied_thresh'], meta['free_thresh'])
    try:
        grid = Grid(data, meta['resolution'], meta['origin'], frame_id=frame_id)
    except GridError as e:
        raise MapFileError(f"{yaml_path}: {e}") from None
    grid.extra['map_file'] = os.path.abspath(yaml_path)
    _log.debug("loaded %s: %d x %d @ %.3f m/cell", yaml_path, grid.width, grid.height, grid.resolution)
    return grid


# ---------------------------------------------------------------------------------------------------------------
# saving
# ---------------------------------------------------------------------------------------------------------------

def data_to_image(data: np.ndarray, occupied_thresh: int = 65, free_thresh: int = 25) -> np.ndarray:
    """Grid data (row 0 = bottom) -> map_saver grey levels (row 0 = top): 0..free -> 254, >= occ -> 0, else 205."""
    data = np.asarray(data, dtype=np.int8)
    img = np.full(data.shape, PGM_UNKNOWN, dtype=np.uint8)
    img[data >= occupied_thresh] = PGM_OCCUPIED
    img[(data >= 0) & (data <= free_thresh)] = PGM_FREE   # map_saver tests free first, so it wins on overlap
    return np.ascontiguousarray(img[::-1])


def _write_atomic(path: str, payload: bytes) -> None:
    # a reader (map_server, the merger) must never see half a file
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, 'wb') as f:
            f.write(payload)
        os.replace(tmp, path)
    except OSError as e:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise MapFileError(f"{path}: cannot write: {e}") from None


def save_map(grid: Grid, prefix: str, occupied_thresh: int = 65, free_thresh: int = 25) -> Tuple[str, str]:
    """Write ``<prefix>.pgm`` (binary P5) and ``<prefix>.yaml`` as map_saver does; returns (yaml_path, pgm_path)."""
    pgm_path, yaml_path = prefix + '.pgm', prefix + '.yaml'
    img = data_to_image(grid.data, occupied_thresh, free_thresh)
    header = b"P5\n# CREATOR: map_saver.cpp %.3f m/pix\n%d %d\n255\n" % (grid.resolution, grid.width, grid.height)
    _write_atomic(pgm_path, header + img.tobytes())
    ox, oy, oyaw = grid.origin
    text = (f"image: {os.path.basename(pgm_path)}\nresolution: {grid.resolution:f}\n"
            f"origin: [{ox:f}, {oy:f}, {oyaw:f}]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n\n")
    _write_atomic(yaml_path, text.encode('utf-8'))
    return yaml_path, pgm_path


def save_png(grid: Grid, path: str, occupied_thresh: int = 65, free_thresh: int = 25) -> str:
    """Write a PNG preview with map_saver's grey levels, +y up; returns the path."""
    return save_image(data_to_image(grid.data, occupied_thresh, free_thresh), path)


def save_image(img: np.ndarray, path: str) -> str:
    """Write an image (grey or BGR, uint8) as PNG, atomically; returns the path."""
    ok, buf = cv2.imencode('.png', img)
    if not ok:
        raise MapFileError(f"{path}: PNG encoding failed")
    _write_atomic(path, buf.tobytes())
    return path
