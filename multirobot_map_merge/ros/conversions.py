"""nav_msgs/OccupancyGrid and map_msgs/OccupancyGridUpdate <-> Grid (imports message types, not rospy).

Origin orientation: the yaw is taken from the quaternion after normalisation. An all-zero quaternion (what a
default-constructed message holds, and what several map publishers send) is read as identity, as the original
map_merge does (it ignores orientation altogether). A non-finite quaternion is a GridError. Roll/pitch are ignored:
an occupancy grid is planar; grid_from_msg records the tilted quaternion in ``grid.extra['tilted_origin']`` so that
the caller can warn naming the robot (throttled), as the map_merge node does.

Speed (measured, 2000 x 2000 grid): genpy packs int8[] with struct.pack(*data), so it needs a sequence of Python
ints; bytes are refused for int8[] ("Only uint8[] can be a string"). ``ndarray.tolist()`` (~30 ms) + serialize
(~50 ms) beats passing the ndarray itself (~250 ms to serialize). On receipt, genpy gives a tuple; np.fromiter
(~85 ms) is the fastest conversion without numpy_msg; an ndarray (numpy_msg) is taken as is. A numpy_msg
OccupancyGrid (``packed_class`` of grid_to_msg) serializes its ndarray as bytes, the same bytes on the wire:
0.02 ms instead of 2.8 ms for 170 000 cells, 0.06 instead of 17 ms for a million. Its generated serializer calls
``data.tostring()``, which numpy deprecates: the cells are a PackedCells array, whose tostring is tobytes.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple, Union

import genpy
import numpy as np
from geometry_msgs.msg import Transform
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import OccupancyGrid

from .. import transforms as tf
from ..grid import Grid, GridError, validate_geometry

StampLike = Union[None, float, int, genpy.Time]


def _data_array(data: Union[Sequence[int], bytes, np.ndarray], expected: int, what: str) -> np.ndarray:
    """Message int8[] field -> flat int8 array of ``expected`` length (GridError otherwise)."""
    n = len(data)
    if n != expected:
        raise GridError(f"{what}: data has {n} cells, expected {expected}")
    if isinstance(data, np.ndarray):
        flat = data.reshape(-1)
        if flat.dtype != np.int8:
            if flat.size and (flat.min() < -128 or flat.max() > 127):
                raise GridError(f"{what}: data holds values that are not int8")
            return flat.astype(np.int8)
        # never alias the message (numpy_msg arrays are even read-only views): grids are edited in place later
        return flat.copy()
    if isinstance(data, (bytes, bytearray, memoryview)):
        return np.frombuffer(data, dtype=np.int8).copy()
    try:
        return np.fromiter(data, dtype=np.int8, count=n)
    except (OverflowError, ValueError, TypeError) as e:
        raise GridError(f"{what}: data holds values that are not int8: {e}") from None


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw of a quaternion (identity for all zeros); GridError if non-finite."""
    if not all(math.isfinite(v) for v in (x, y, z, w)):
        raise GridError(f"origin orientation ({x}, {y}, {z}, {w}) is not finite")
    norm2 = x * x + y * y + z * z + w * w
    if norm2 < 1e-12:
        return 0.0
    # atan2 of two degree-2 forms: scale-invariant, so no explicit normalisation needed
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def is_pure_yaw(x: float, y: float, z: float, w: float) -> bool:
    """True unless the quaternion has a roll or pitch part (an all-zero or non-finite one counts as pure yaw)."""
    norm2 = x * x + y * y + z * z + w * w
    return not (math.isfinite(norm2) and norm2 >= 1e-12 and (x * x + y * y) / norm2 > 1e-6)


def _to_sec(stamp) -> float:
    return float(stamp.secs) + 1e-9 * float(stamp.nsecs)


def _to_time(stamp: StampLike, default: float) -> genpy.Time:
    if stamp is None:
        stamp = default
    if isinstance(stamp, genpy.Time):
        return genpy.Time(stamp.secs, stamp.nsecs)
    if isinstance(stamp, genpy.Duration) or not math.isfinite(float(stamp)) or float(stamp) < 0:
        raise GridError(f"stamp {stamp!r} is not a valid time")
    return genpy.Time.from_sec(float(stamp))


def grid_from_msg(msg: OccupancyGrid) -> Grid:
    """OccupancyGrid -> Grid; GridError on inconsistent size, bad resolution or origin."""
    info = msg.info
    w, h = int(info.width), int(info.height)
    p = info.origin.position
    q = info.origin.orientation
    origin = (float(p.x), float(p.y), yaw_from_quaternion(q.x, q.y, q.z, q.w))
    # geometry first, so an absurd width x height is refused before anything is allocated
    validate_geometry(w, h, float(info.resolution), origin)
    data = _data_array(msg.data, w * h, f"map of {w} x {h} cells")
    grid = Grid(data.reshape(h, w), float(info.resolution), origin, frame_id=msg.header.frame_id,
                stamp=_to_sec(msg.header.stamp))
    if not is_pure_yaw(q.x, q.y, q.z, q.w):
        grid.extra['tilted_origin'] = (float(q.x), float(q.y), float(q.z), float(q.w))
    return grid


class PackedCells(np.ndarray):
    """The int8 cells of a numpy_msg message: tostring() (what genpy's numpy serializer calls) is tobytes()."""

    def tostring(self) -> bytes:
        return self.tobytes()


def grid_to_msg(grid: Grid, stamp: StampLike = None, frame_id: Optional[str] = None,
                packed_class: Optional[type] = None) -> OccupancyGrid:
    """Grid -> a fresh OccupancyGrid; stamp (seconds or genpy.Time) and frame_id default to the grid's. With
    `packed_class` (rospy.numpy_msg.numpy_msg(OccupancyGrid)), a message of that class holding a copy of the cells
    as an int8 array (see the module doc)."""
    t = _to_time(stamp, grid.stamp)
    msg = packed_class() if packed_class is not None else OccupancyGrid()
    msg.header.stamp = t
    msg.header.frame_id = grid.frame_id if frame_id is None else frame_id
    msg.info.map_load_time = genpy.Time(t.secs, t.nsecs)
    msg.info.resolution = grid.resolution
    msg.info.width, msg.info.height = grid.width, grid.height
    ox, oy, oyaw = grid.origin
    msg.info.origin.position.x, msg.info.origin.position.y = ox, oy
    msg.info.origin.orientation.z = math.sin(oyaw / 2.0)
    msg.info.origin.orientation.w = math.cos(oyaw / 2.0)
    if packed_class is not None:
        # a copy: the message is kept (latched, re-sent) while the grid may change
        msg.data = grid.data.reshape(-1).astype(np.int8).view(PackedCells)
    else:
        msg.data = grid.data.reshape(-1).tolist()   # fastest form genpy's int8[] packer accepts (see module doc)
    return msg


@dataclass
class GridUpdate:
    """A validated map_msgs/OccupancyGridUpdate: data is int8 (height, width), row 0 at cell row y."""
    x: int
    y: int
    width: int
    height: int
    data: np.ndarray
    stamp: float = 0.0
    frame_id: str = ""


def update_from_msg(msg: OccupancyGridUpdate) -> GridUpdate:
    """OccupancyGridUpdate -> GridUpdate; GridError on negative x/y or a data length != width * height."""
    x, y, w, h = int(msg.x), int(msg.y), int(msg.width), int(msg.height)
    if x < 0 or y < 0:
        raise GridError(f"update at negative coordinates x {x}, y {y}")
    validate_geometry(w, h, 1.0, (0.0, 0.0, 0.0))
    data = _data_array(msg.data, w * h, f"update of {w} x {h} cells")
    return GridUpdate(x, y, w, h, data.reshape(h, w), _to_sec(msg.header.stamp), msg.header.frame_id)


def update_to_msg(update: GridUpdate) -> OccupancyGridUpdate:
    """GridUpdate -> a fresh OccupancyGridUpdate."""
    msg = OccupancyGridUpdate()
    msg.header.stamp = _to_time(update.stamp, 0.0)
    msg.header.frame_id = update.frame_id
    msg.x, msg.y, msg.width, msg.height = update.x, update.y, update.width, update.height
    msg.data = np.asarray(update.data, dtype=np.int8).reshape(-1).tolist()
    return msg


def transform_msg(m: np.ndarray) -> Transform:
    """A geometry_msgs/Transform of a metric 2-D transform (3x3)."""
    x, y, yaw, _ = tf.params(m)
    t = Transform()
    t.translation.x, t.translation.y = x, y
    t.rotation.z, t.rotation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return t


def center_origin(merged: Grid) -> Tuple[float, float, float]:
    """The original's origin (§7.3 step 7): canvas centred on world_frame, resolution as float32 widened."""
    res = float(np.float32(merged.resolution))
    return (-(merged.width / 2.0) * res, -(merged.height / 2.0) * res, 0.0)


def restamped(msg: OccupancyGrid, stamp) -> OccupancyGrid:
    """A fresh copy of a merged map message (of its class) with a new stamp; the (never modified) data is shared."""
    out = type(msg)()
    out.header.frame_id = msg.header.frame_id
    out.header.stamp = stamp
    out.info = copy.deepcopy(msg.info)
    out.info.map_load_time = stamp
    out.data = msg.data
    return out
