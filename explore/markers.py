"""``~frontiers`` visualisation as the original (explore.md §9): message building only, no publishing."""
from __future__ import annotations

from typing import Any, Callable, Sequence

from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from .frontier_search import Frontier

BLUE = ColorRGBA(0.0, 0.0, 1.0, 1.0)
RED = ColorRGBA(1.0, 0.0, 0.0, 1.0)
GREEN = ColorRGBA(0.0, 1.0, 0.0, 1.0)


def frontier_markers(frontiers: Sequence[Frontier], frame_id: str, stamp: Any,
                     blacklisted: Callable[[Frontier], bool], last_count: int) -> MarkerArray:
    """Two markers per frontier (ids 2k: POINTS of its cells, blue or red if blacklisted; 2k+1: green SPHERE at its
    first cell, smaller for costlier frontiers), then DELETE markers for the ids of the last array beyond these."""
    array = MarkerArray()
    m = Marker()
    m.header.frame_id = frame_id
    m.header.stamp = stamp
    m.ns = 'frontiers'
    m.frame_locked = True
    m.action = Marker.ADD
    min_cost = frontiers[0].cost if frontiers else 0.0
    mid = 0
    for f in frontiers:
        pts = Marker(header=m.header, ns=m.ns, id=mid, type=Marker.POINTS, action=Marker.ADD, frame_locked=True)
        pts.scale.x = pts.scale.y = pts.scale.z = 0.1
        pts.points = [Point(float(x), float(y), 0.0) for x, y in f.points]
        pts.color = RED if blacklisted(f) else BLUE
        array.markers.append(pts)
        mid += 1
        sph = Marker(header=m.header, ns=m.ns, id=mid, type=Marker.SPHERE, action=Marker.ADD, frame_locked=True)
        sph.pose.position = Point(f.initial[0], f.initial[1], 0.0)
        # costlier frontiers get smaller spheres (0.5 when cost is 0, as the original's division gives inf)
        scale = abs(min_cost * 0.4 / f.cost) if f.cost != 0.0 else float('inf')
        scale = min(scale, 0.5) if scale == scale else 0.5
        sph.scale.x = sph.scale.y = sph.scale.z = scale
        sph.color = GREEN
        array.markers.append(sph)
        mid += 1
    last = array.markers[-1] if array.markers else m
    for stale in range(mid, last_count):
        d = Marker(header=last.header, ns=last.ns, id=stale, type=last.type, action=Marker.DELETE,
                   frame_locked=True, pose=last.pose, scale=last.scale, color=last.color)
        array.markers.append(d)
    return array
