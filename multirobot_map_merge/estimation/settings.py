"""Settings of the estimation pipeline: one object feeding validation, the offline tool and the node."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from .features import FEATURE_TYPES
from .search import FREE_REWARD, PENALTY


@dataclass
class EstimationSettings:
    feature: str = 'akaze'            # keypoint detector: akaze (as the C++ node), orb (as the thesis) or sift
    confidence: float = 1.0           # inliers / (8 + 0.3 matches) a pair needs, as the original (see pair_confidence)
    min_work_resolution: float = 0.05  # m/pixel: finer maps are matched at this resolution
    ratio: float = 0.8                # descriptor ratio test
    ransac_threshold: float = 3.0     # pixels
    ransac_iterations: int = 2000
    max_hypotheses: int = 5           # rigid models tried per pair
    min_inliers: int = 4              # RANSAC inliers a model needs
    screen_points: int = 600          # wall pixels sampled to screen a hypothesis before refining it
    screen_tolerance: float = 4.0     # pixels
    screen_min_agreement: float = 0.5
    icp_radii: tuple = (6.0, 4.0, 3.0, 2.0)  # pixels: correspondence radius of each ICP level
    icp_iterations: int = 6           # at most, per level
    icp_max_points: int = 2000
    verify_tolerance: float = 2.0     # pixels: a wall "agrees" when the other map has a wall this close
    min_agreement: float = 0.91       # share of walls in the common area that agree (fringe ones aside)
    min_overlap_m2: float = 4.0       # common known area a pair needs
    min_support: int = 100            # agreeing wall pixels a pair needs
    deep_conflict_m: float = 0.2      # a contradicting wall this far inside the other map's view is not at its fringe
    max_deep_conflicts: float = 0.01  # such contradictions a pair tolerates, as a share of its agreeing walls
    max_corner_error_m: float = 0.25  # refuse placements the shared walls leave this uncertain at a far corner
    fringe_px: float = 1.5            # pixels: contradictions this close to the other's unknown area do not count
    conflict_weight: float = 10.0     # placements rank by support - conflict_weight * conflicts
    ambiguity_ratio: float = 0.8      # a distinct placement with this share of the best score -> ambiguous
    facing: bool = True               # walls seen from opposite sides neither support a placement nor pair in ICP
    polish_below_support: int = 300   # polish placements with fewer agreeing walls than this (polish.py); 0: never
    polish_below_overlap_m2: float = 15.0  # and those with a common area smaller than this (a small map's angle)
    distinct_degrees: float = 5.0     # placements further apart than this are distinct
    distinct_metres: float = 1.0
    search_factor: int = 4            # working pixels per pixel of the correlation search
    search_sweep_degrees: float = 3.0  # rotation step of the search for maps without straight walls
    search_penalty: float = PENALTY   # correlation search: cost of a wall on the other's open floor
    search_free_reward: float = FREE_REWARD  # correlation search: reward of floor both maps saw free
    search_keep: int = 8              # correlation search: candidates refined
    search_budget_s: float = math.inf  # correlation searches of one estimation stop after this many seconds
    threads: int = 2                  # pairs matched in parallel
    seed: int = 0

    def validate(self) -> None:
        """Raise ValueError naming the first bad setting."""
        if self.feature not in FEATURE_TYPES:
            raise ValueError(f"feature must be one of {', '.join(FEATURE_TYPES)}, not '{self.feature}'")
        positive = ('min_work_resolution', 'ratio', 'ransac_threshold', 'ransac_iterations', 'max_hypotheses',
                    'icp_iterations', 'icp_max_points', 'verify_tolerance', 'threads')
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be positive, not {getattr(self, name)}')
        if not 0.0 <= self.min_agreement <= 1.0:
            raise ValueError(f'min_agreement must be in [0, 1], not {self.min_agreement}')
        for name in ('deep_conflict_m', 'max_deep_conflicts', 'fringe_px', 'max_corner_error_m', 'search_penalty',
                     'search_free_reward', 'search_keep', 'search_budget_s'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must not be negative, not {getattr(self, name)}')
        if self.confidence != self.confidence:
            raise ValueError('confidence must be a number, not NaN')

    def replace(self, **changes) -> 'EstimationSettings':
        return dataclasses.replace(self, **changes)
