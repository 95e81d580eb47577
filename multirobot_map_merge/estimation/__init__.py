"""Estimation: where each robot's map lies in the merged map, without known initial poses.

The stages, in the order a map goes through them (a stage's settings are declared in its module; settings.py
composes them into the one EstimationSettings):
  features.py    prepare a grid: crop, resample to the working resolution, walls, distance fields, keypoints
  hypotheses.py  candidate screen: descriptor matches, rigid RANSAC hypotheses, a cheap wall-agreement screen
                 (neighbours.py keeps each keypoint's nearest descriptors among each map's for one estimation)
  search.py      correlation search: candidates where descriptors found none (small or featureless overlaps)
  refine.py      refinement: ICP on walls; polish.py then settles each plausible placement in its best minimum
  verify.py      verification and the acceptance rules (agreement, overlap, support, contradictions, precision.py)
  pair.py        one pair matched through all the stages above
  growth.py      the merge grown from a seed map, newcomers matched against the union of the placed ones
                 (union.py); in place of the original's spanning tree over all pairs
  tracking.py    placements of the last estimation re-checked against the union of the others (memory.py keeps
                 what need not be redone while a map has not changed)
  estimator.py   the orchestrator: tracking, then growth
"""
from .estimator import Estimate, estimate, working_resolution
from .settings import EstimationSettings

__all__ = ['Estimate', 'EstimationSettings', 'estimate', 'working_resolution']
