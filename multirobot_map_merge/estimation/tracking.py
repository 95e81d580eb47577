"""Tracking: a grid placed by the last estimation keeps its placement while the evidence still holds.

Robot map frames do not move (SLAM keeps its origin), so a right placement stays right while the maps grow. Each
estimation re-checks every previous placement against the union of the other placed grids near it: ICP from the
old placement (kept only if it fits better) and the polish, then the same acceptance rules as a new match (the
refined placement if it passes, else the old one if that still passes). A placement that fails is dropped in that
same estimation and its grid goes back to the search; the thesis (§4.5) shows why a kept placement must never
outlive its evidence. A wrong map makes its neighbours contradict too, so when several fail, the one that agrees
least is dropped and the others are checked again without it (at most MAX_PASSES rounds).
"""
from __future__ import annotations

import logging
import math
from concurrent.futures import Executor
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import PreparedGrid, prepare
from .memory import EstimationMemory, unchanged
from .pair import PairMatch
from .polish import polish
from .refine import icp
from .settings import EstimationSettings
from .union import Box, compose_near, footprint, most_overlapping
from .verify import pair_confidence, plausible, refusal, verify

log = logging.getLogger('rosout.multirobot_map_merge.estimation.tracking')

CONTEXT_M = 1.0   # metres around a grid's footprint taken from the other grids' union
MAX_PASSES = 3    # checks of the previous placements: after that, every one still failing is dropped
REANCHOR_RAD = math.radians(0.1)   # the reference fitting the others better by this much moves the others
REANCHOR_M = 0.03


@dataclass
class Check:
    """The re-check of one previous placement."""
    k: int
    transform: Optional[np.ndarray]   # the (refined) metric placement, None when it no longer holds
    match: PairMatch                  # figures against the union of the others (j: the most overlapping one)


def recheck(k: int, grids: Sequence[Optional[Grid]], prepared: Sequence[Optional[PreparedGrid]],
            placed: Dict[int, np.ndarray], footprints: Dict[int, Box], res: float,
            s: EstimationSettings) -> Check:
    """Whether grid k, placed at placed[k], still agrees with the union of the other placed grids near it."""
    box = footprints.get(k)
    others = {m: t for m, t in placed.items() if m != k}
    match = PairMatch(k, most_overlapping(box, footprints, others))
    if box is None or match.j < 0:
        match.reason = 'no placed grid near it'
        return Check(k, None, match)
    area = (box[0] - CONTEXT_M, box[1] - CONTEXT_M, box[2] + CONTEXT_M, box[3] + CONTEXT_M)
    union = compose_near(grids, others, footprints, area, res)
    target = prepare(union, res, None) if union is not None else None
    if target is None:
        match.reason = 'no placed grid near it'
        return Check(k, None, match)
    pk = prepared[k]
    prior = tf.inverse(target.px_to_map) @ placed[k] @ pk.px_to_map
    rng = np.random.default_rng(s.seed + 7919 * k)
    # ICP from the prior, kept only if it ranks better: on a small common area ICP can slide off to a worse fit
    candidates = [verify(pk, target, model, s) for model in (prior, icp(pk, target, prior, s, rng))]
    best = max(candidates, key=lambda c: (plausible(c, s), c.score(s.conflict_weight)))
    # then the polish, whatever the common area: the small corrections a kept placement needs as its map grows
    # are what ICP misses (a live run kept a robot 0.6 degrees off with every shared wall agreeing)
    polished = verify(pk, target, polish(pk, target, [best.transform], rng), s)
    best = polished if plausible(polished, s) else best
    reason = refusal(best, pk, target, s, onto_union=True)
    if reason and best is not candidates[0]:
        best = candidates[0]
        reason = refusal(best, pk, target, s, onto_union=True)
    match.best = best
    if reason:
        match.reason = f'previous placement no longer holds: {reason}'
        return Check(k, None, match)
    metric = target.px_to_map @ best.transform @ tf.inverse(pk.px_to_map)
    match.accepted = True
    match.matches, match.inliers = best.support + best.conflicts, best.support
    match.confidence = pair_confidence(match.inliers, match.matches)
    match.transform_m = tf.inverse(placed[match.j]) @ metric
    return Check(k, metric, match)


def track(previous: Sequence[Optional[np.ndarray]], reference: int, grids: Sequence[Optional[Grid]],
          prepared: Sequence[Optional[PreparedGrid]], res: float, s: EstimationSettings, pool: Executor,
          memory: EstimationMemory, names: Sequence) -> Tuple[Dict[int, np.ndarray], List[Check]]:
    """The previous placements (same reference, same merged frame) that still hold, refined, and the checks.
    Empty when the reference itself no longer agrees with the others: then nothing is kept. A placement confirmed
    by an earlier estimation whose map has barely changed since (memory.py) stands without a new check."""
    placed = {k: np.asarray(t, float) for k, t in enumerate(previous)
              if t is not None and k < len(prepared) and prepared[k] is not None}
    if reference not in placed or len(placed) < 2:
        return {}, []
    footprints = {k: box for k, box in ((k, footprint(grids[k], t)) for k, t in placed.items()) if box is not None}

    def check(k: int) -> Check:
        confirmed = memory.checks.get(names[k])
        if confirmed is not None and np.allclose(confirmed[1], placed[k]) and unchanged(confirmed[0], grids[k]):
            return Check(k, placed[k], confirmed[2])
        c = recheck(k, grids, prepared, placed, footprints, res, s)
        if c.transform is not None:
            memory.checks.put(names[k], (grids[k], c.transform, c.match))
        else:   # its map frame may have moved (a SLAM failure): nothing learnt of it stands
            memory.checks.drop(names[k])
            memory.keypoints.drop(names[k])
        return c

    checks: Dict[int, Check] = {}
    to_check = [k for k in placed if k != reference]
    for _ in range(MAX_PASSES):
        for c in pool.map(check, to_check):
            checks[c.k] = c
        failed = [k for k in to_check if checks[k].transform is None]
        if not failed:
            break
        # one wrong map makes its neighbours contradict too: drop the worst, then check the others without it
        worst = min(failed, key=lambda k: checks[k].match.best.agreement if checks[k].match.best else -1.0)
        del placed[worst]
        to_check = [k for k in placed if k != reference]
        if not to_check:
            break
    else:
        for k in [k for k in to_check if checks[k].transform is None]:
            del placed[k]
    for k in placed:
        if k != reference:
            placed[k] = checks[k].transform
    if len(placed) > 1:
        ref = check(reference)
        if ref.transform is None:
            log.info('the reference grid %d no longer agrees with the others (%s): placements searched anew',
                     reference, ref.match.reason)
            return {}, list(checks.values()) + [ref]
        box = footprints.get(reference)
        corners = np.array([[box[0], box[1]], [box[2], box[3]]]) if box is not None else np.zeros((0, 2))
        rot, shift = tf.difference(ref.transform, np.eye(3), corners)
        if rot > REANCHOR_RAD or shift > REANCHOR_M:
            # the others agree among themselves and the reference fits them better elsewhere: an early placement
            # (small maps) was off; the reference stays the frame, so the others move
            log.info('re-anchored the placed grids on the reference grid %d (%.2f deg, %.2f m)', reference,
                     math.degrees(rot), shift)
            correction = tf.inverse(ref.transform)
            for k in placed:
                if k != reference:
                    placed[k] = correction @ placed[k]
    for c in checks.values():
        if c.transform is None:
            log.info('grid %d: %s', c.k, c.match.reason)
    return placed, list(checks.values())
