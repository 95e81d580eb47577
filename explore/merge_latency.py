"""Merge latency of a live fleet, against the ground truth (no ROS): when each robot's map could have joined the
merged map, and when it did.

A robot is *joinable* once its map, placed at its true pose, overlaps the union of the other robots' maps (each at
its true pose) by at least ``MIN_SHARED_M2`` and by at least ``MIN_FRACTION`` of its own known area: the shared
scorer's pair thresholds (../shared/eval, truth.json ``overlap``: 4 m², 5 %), applied to the union. Known areas
are compared on a coarse world raster (``explore.coverage.KnownRaster``, 0.1 m cells like the scorer's), cheap
enough to redo every few seconds for a dozen robots.

``LatencyTracker`` turns the joinable robots and map_merge's included robots over time into, per robot,
``joinable_sim_s`` (first time joinable), ``merged_sim_s`` (start of the last unbroken stretch in the merged map that
lasts until the end) and ``latency_s`` (their difference; None for the reference robot, the first one merged, whose
frame the merge starts from).
"""
from __future__ import annotations

from typing import Dict, Iterable, List, Mapping, Optional, Tuple

import numpy as np

from multirobot_map_merge.grid import Grid

from .coverage import KnownRaster

Pose = Tuple[float, float, float]   # x, y, yaw of a map frame in the world frame
MIN_SHARED_M2 = 4.0
MIN_FRACTION = 0.05


def union_overlaps(known: Mapping[str, np.ndarray], cell_m: float) -> Dict[str, Tuple[float, float]]:
    """Per robot: (area in m² its known raster shares with the union of the others', its own known area in m²)."""
    if not known:
        return {}
    count = np.zeros(next(iter(known.values())).shape, np.uint16)
    for mask in known.values():
        count += mask
    area = cell_m * cell_m
    out = {}
    for name, mask in known.items():
        own = int(mask.sum())
        shared = int(np.count_nonzero(count[mask] >= 2))   # known by this robot and by at least one other
        out[name] = (shared * area, own * area)
    return out


def is_joinable(shared_m2: float, own_m2: float, min_shared_m2: float = MIN_SHARED_M2,
                min_fraction: float = MIN_FRACTION) -> bool:
    return own_m2 > 0 and shared_m2 >= min_shared_m2 and shared_m2 >= min_fraction * own_m2


def joinable_robots(raster: KnownRaster, maps: Mapping[str, Tuple[Grid, Pose]],
                    min_shared_m2: float = MIN_SHARED_M2, min_fraction: float = MIN_FRACTION) -> List[str]:
    """Robots (of ``maps``: name -> (map, true pose of its frame)) whose map overlaps the union of the others'."""
    known = {name: raster.known(grid, pose) for name, (grid, pose) in maps.items()}
    return [name for name, (shared, own) in union_overlaps(known, raster.cell_m).items()
            if is_joinable(shared, own, min_shared_m2, min_fraction)]


class LatencyTracker:
    """Joinable and merged times per robot from observations in time order (sim seconds)."""

    def __init__(self, names: Iterable[str]) -> None:
        self.names = list(names)
        self.joinable_at: Dict[str, Optional[float]] = {n: None for n in self.names}
        self.merged_since: Dict[str, Optional[float]] = {n: None for n in self.names}   # None: not merged now

    def add(self, name: str) -> None:
        """Track one more robot (one seen only later, as in a replay)."""
        if name not in self.joinable_at:
            self.names.append(name)
            self.joinable_at[name], self.merged_since[name] = None, None

    def joinable(self, t: float, names: Iterable[str]) -> None:
        for n in names:
            if n in self.joinable_at and self.joinable_at[n] is None:
                self.joinable_at[n] = t

    def included(self, t: float, names: Iterable[str]) -> None:
        """The robots in the merged map at time t (every other robot is out of it from t on)."""
        now = set(names)
        for n in self.names:
            if n not in now:
                self.merged_since[n] = None
            elif self.merged_since[n] is None:
                self.merged_since[n] = t

    def reference(self) -> Optional[str]:
        """The first robot merged (by name order among equal times); None if none is merged."""
        merged = [(t, i) for i, t in enumerate(self.merged_since.values()) if t is not None]
        return self.names[min(merged)[1]] if merged else None

    def rows(self) -> List[Dict[str, object]]:
        ref = self.reference()
        rows = []
        for n in self.names:
            joinable, merged = self.joinable_at[n], self.merged_since[n]
            latency = None if n == ref or joinable is None or merged is None else merged - joinable
            rows.append({'robot': n, 'joinable_sim_s': joinable, 'merged_sim_s': merged, 'latency_s': latency,
                         'latency_reference': n == ref})
        return rows
