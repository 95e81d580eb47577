"""The merging pipeline: feed grids, estimate or set transforms, compose (the original's combine_grids API).

    pipeline = MergingPipeline(EstimationSettings())
    pipeline.feed([grid_a, grid_b, None])
    pipeline.estimate()                 # or pipeline.set_known_poses([...])
    merged = pipeline.compose('world')  # a Grid in the merged frame, or None

Transforms are metric, from each grid's own map frame (the frame its origin is given in) into the merged frame;
`cell_transform(k)` gives the same placement in cells of the reference grid. Not thread safe: one owner.
"""
from __future__ import annotations

import logging
import time
from typing import Dict, List, Optional, Sequence

import numpy as np

from . import transforms as tf
from .admission import admit
from .compose import PatchCache, compose
from .estimation.estimator import Estimate, estimate
from .estimation.features import FeatureCache
from .estimation.growth import Progress
from .estimation.memory import EstimationMemory
from .estimation.settings import EstimationSettings
from .grid import MAX_CELLS, Grid
from .known_poses import InitPose, transforms_from_poses

log = logging.getLogger('rosout.multirobot_map_merge.pipeline')


class MergingPipeline:
    def __init__(self, settings: Optional[EstimationSettings] = None):
        self.settings = settings or EstimationSettings()
        self.settings.validate()
        self.cache = FeatureCache()
        self.memory = EstimationMemory()   # for a live fleet: see memory.py
        self.grids: List[Optional[Grid]] = []        # as estimate sees them: trinary (None: absent, empty, unmatchable)
        self.composable: List[Optional[Grid]] = []   # as compose sees them (None: absent or empty)
        self.transforms: List[Optional[np.ndarray]] = []
        self.reference: Optional[int] = None
        self.last_estimate: Optional[Estimate] = None
        self.compose_seconds = 0.0
        self.patches = PatchCache()   # what each grid added to the last merged grid (compose.PatchCache)
        self.invalid_cells: Dict[int, int] = {}   # grid index -> cells read as unknown by the last feed
        self.refused: Dict[int, str] = {}         # grid index -> why the last feed left it out
        self.left_out: Dict[int, str] = {}        # grid index -> why the last compose left it out

    def feed(self, grids: Sequence[Optional[Grid]], matching: bool = True) -> None:
        """Replace the grids, each admitted (validated, cells normalised) by admission.admit; `invalid_cells`
        counts the cells read as unknown. With `matching` (the grids may be estimated; the default) a grid the
        estimation cannot match is None in `grids` (what estimate sees), with the reason in `refused`; it is still
        composed at a known pose; with `matching` the grids estimate sees are read as trinary through the settings'
        free_threshold and occupied_threshold (compose keeps the values as published). Transforms are kept only if
        the number of grids is unchanged."""
        work = self.settings.min_work_resolution if matching else None
        admitted = [admit(g, work, self.settings.free_threshold, self.settings.occupied_threshold) for g in grids]
        self.invalid_cells = {k: a.invalid_cells for k, a in enumerate(admitted) if a.invalid_cells}
        self.refused = {k: a.refused for k, a in enumerate(admitted) if a.refused}
        self.composable = [a.grid for a in admitted]
        grids = [None if a.refused else (a.grid if a.matching is None else a.matching) for a in admitted]
        if len(grids) != len(self.grids):
            self.transforms = [None] * len(grids)
            self.reference = None
        self.grids = grids

    def estimate(self, preferred_reference: Optional[int] = None,
                 previous: Optional[Sequence[Optional[np.ndarray]]] = None,
                 progress: Optional[Progress] = None, names: Optional[Sequence[str]] = None,
                 now: Optional[float] = None, budget_script: Optional[Sequence[bool]] = None) -> Estimate:
        """Estimate transforms from the grids' content (unknown initial poses); `previous` (transforms of the
        current grids from the last estimate, same reference) are kept while they still hold (tracking.py);
        `progress(settled, total)` is called as grids are placed or set aside; `names` (stable names of the grids,
        e.g. robot namespaces) let the pipeline's memory skip, in the next estimation, work whose answer cannot have
        changed much (memory.py); `now` (s, ROS time in the node) lets it tell how long the maps have not changed
        (confirmation.py); `budget_script` replays a recorded estimation's search budget (estimator.estimate)."""
        if preferred_reference is None:
            preferred_reference = self.reference
        memory = self.memory if names is not None else None
        result = estimate(self.grids, self.settings, self.cache, preferred_reference, previous, progress, memory,
                          names, now, budget_script)
        self.transforms, self.reference, self.last_estimate = list(result.transforms), result.reference, result
        return result

    def set_known_poses(self, poses: Sequence[Optional[InitPose]], legacy: bool = False) -> None:
        if len(poses) != len(self.grids):
            raise ValueError(f'{len(poses)} poses for {len(self.grids)} grids')
        self.transforms = transforms_from_poses(self.composable, poses, legacy)
        self.reference = None

    def set_transforms(self, transforms: Sequence[Optional[np.ndarray]]) -> None:
        if len(transforms) != len(self.grids):
            raise ValueError(f'{len(transforms)} transforms for {len(self.grids)} grids')
        self.transforms = [None if t is None else np.asarray(t, float) for t in transforms]

    def compose(self, frame_id: str = '', max_cells: int = MAX_CELLS) -> Optional[Grid]:
        t0 = time.perf_counter()
        resolution = None
        if self.reference is not None and self.grids[self.reference] is not None:
            resolution = self.grids[self.reference].resolution
        self.left_out = {}
        merged = compose(self.composable, self.transforms, resolution, frame_id, self.left_out, max_cells,
                         cache=self.patches)
        self.compose_seconds = time.perf_counter() - t0
        return merged

    def cell_transform(self, k: int) -> Optional[np.ndarray]:
        """Grid k's cells (corner coordinates) -> cells of the reference grid (or of the first placed grid)."""
        ref = self.reference
        if ref is None:
            ref = next((i for i, t in enumerate(self.transforms)
                        if t is not None and self.composable[i] is not None), None)
        if ref is None or self.transforms[k] is None or self.composable[k] is None:
            return None
        g_ref = self.composable[ref]
        return (tf.inverse(g_ref.cell_to_map()) @ tf.inverse(self.transforms[ref]) @ self.transforms[k]
                @ self.composable[k].cell_to_map())
