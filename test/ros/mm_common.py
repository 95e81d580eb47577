"""Shared helpers of the map_merge rostest checkers (imported by the mm_*.py scripts next to it; not a node).

Map specs are strings "<name>=<map yaml>": the yaml relative to the repo's data/samples (or absolute); the name is a
topic for mm_sample_map_publisher.py ("/robot1/map=three_robots/map_00.yaml") and a robot namespace for the checkers
("/robot1=three_robots/map_00.yaml"). A suffix "@kind" publishes the map as another kind of SLAM map
("three_robots/map_01.yaml@probabilistic": see map_kinds.py; seeded by the map's position in the list).
"""
from __future__ import annotations

import json
import math
import os
from typing import Callable, Dict, List, Optional

import numpy as np
import rospy

import map_kinds
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.ros.conversions import yaw_from_quaternion

SAMPLES = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'data', 'samples')


def sample_path(path: str) -> str:
    return path if os.path.isabs(path) else os.path.join(SAMPLES, path)


def split_kind(path: str) -> tuple:
    """(map yaml, kind) of a spec's path: "a.yaml@thin" -> ("a.yaml", "thin"); the kind is "trinary" by default."""
    path, _, kind = path.partition('@')
    return path, kind or 'trinary'


def load_spec(spec: str, frame_id: str = '', seed: int = 0) -> tuple:
    """(name, Grid) of one map spec, as the kind its path names (seeded by `seed`)."""
    name, path = spec.split('=', 1)
    path, kind = split_kind(path)
    return name, map_kinds.as_kind(load_map(sample_path(path), frame_id), kind, seed)


def robot_maps(specs: List[str]) -> Dict[str, Grid]:
    """{robot namespace: Grid} of "ns=file.yaml" specs; each map's frame is '<ns without leading slash>/map'."""
    out = {}
    for k, spec in enumerate(specs):
        ns = spec.split('=', 1)[0]
        out[ns] = load_spec(spec, ns.strip('/') + '/map', seed=k)[1]
    return out


def truth_poses(truth_file: str, specs: List[str]) -> Dict[str, np.ndarray]:
    """{robot namespace: 3x3 pose of its map frame in the ground-truth world} from a truth.json."""
    truth = json.loads(open(sample_path(truth_file)).read())
    by_file = {m['file']: m['pose'] for m in truth['maps']}
    out = {}
    for spec in specs:
        ns, path = spec.split('=', 1)
        x, y, yaw = by_file[os.path.basename(split_kind(path)[0])]
        out[ns] = rigid(x, y, yaw)
    return out


def rigid(x: float, y: float, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def matrix_of(transform) -> np.ndarray:
    """geometry_msgs/Transform (planar) -> 3x3."""
    q = transform.rotation
    return rigid(transform.translation.x, transform.translation.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))


def pose_error(a: np.ndarray, b: np.ndarray) -> tuple:
    """(translation error in metres, rotation error in degrees) between two 3x3 rigid transforms."""
    d = np.linalg.inv(b) @ a
    return float(math.hypot(a[0, 2] - b[0, 2], a[1, 2] - b[1, 2])), abs(math.degrees(math.atan2(d[1, 0], d[0, 0])))


def wait_for(topic: str, msg_type, predicate: Callable, timeout: float, what: str):
    """The first message on `topic` (latched or not) that satisfies predicate; AssertionError after timeout."""
    found = []

    def cb(msg):
        if not found and predicate(msg):
            found.append(msg)
    sub = rospy.Subscriber(topic, msg_type, cb, queue_size=5)
    deadline = rospy.get_time() + timeout
    try:
        while not found and rospy.get_time() < deadline and not rospy.is_shutdown():
            rospy.sleep(0.1)
    finally:
        sub.unregister()
    if not found:
        raise AssertionError(f'no {what} on {topic} within {timeout:.0f} s')
    return found[0]


def merged_array(msg) -> np.ndarray:
    return np.asarray(msg.data, np.int8).reshape(msg.info.height, msg.info.width)


def merged_cell_to_world(msg) -> np.ndarray:
    o = msg.info.origin
    q = o.orientation
    g = rigid(o.position.x, o.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
    return g @ np.diag([msg.info.resolution, msg.info.resolution, 1.0])


def wall_agreement(grid: Grid, world_from_map: np.ndarray, merged_msg, tolerance_cells: int = 1,
                   samples: int = 2000) -> float:
    """Share of the robot map's wall cells that land on (within tolerance of) a wall of the merged map when
    placed by world_from_map: 1.0 when the merged grid holds the map where the transform says."""
    rows, cols = np.nonzero(grid.data >= 65)
    if len(rows) == 0:
        return 0.0
    pick = np.random.default_rng(0).choice(len(rows), size=min(samples, len(rows)), replace=False)
    centres = np.stack([cols[pick] + 0.5, rows[pick] + 0.5, np.ones(len(pick))])
    world = world_from_map @ grid.cell_to_map() @ centres
    cells = np.linalg.inv(merged_cell_to_world(merged_msg)) @ world
    c, r = np.floor(cells[0]).astype(int), np.floor(cells[1]).astype(int)
    data = merged_array(merged_msg)
    walls = data >= 65
    # dilate the merged walls by the tolerance (a few cells of nearest-neighbour resampling)
    k = tolerance_cells
    padded = np.pad(walls, k)
    near = np.zeros_like(walls)
    for dr in range(-k, k + 1):
        for dc in range(-k, k + 1):
            near |= padded[k + dr:k + dr + walls.shape[0], k + dc:k + dc + walls.shape[1]]
    inside = (c >= 0) & (r >= 0) & (c < data.shape[1]) & (r < data.shape[0])
    hits = np.zeros(len(c), bool)
    hits[inside] = near[r[inside], c[inside]]
    return float(hits.mean())


def status_transforms(status) -> Dict[str, Optional[np.ndarray]]:
    return {r.robot_namespace: (matrix_of(r.transform) if r.included else None) for r in status.robots}
