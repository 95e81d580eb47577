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
from typing import AbstractSet, Callable, Dict, Hashable, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import PreparedGrid, prepare
from .memory import EstimationMemory, unchanged
from .pair import PairMatch
from .polish import polish
from .refine import icp
from .relax import relax
from .settings import EstimationSettings
from .union import Box, compose_near, footprint, most_overlapping, overlap_area
from .verify import IMPRECISE, pair_confidence, plausible, refusal, verify

log = logging.getLogger('rosout.multirobot_map_merge.estimation.tracking')

CONTEXT_M = 1.0   # metres around a grid's footprint taken from the other grids' union
MAX_PASSES = 3    # checks of the previous placements: after that, every one still failing is dropped
REANCHOR_M = 0.03        # metres at the reference's corners: the reference fitting the others better by more than
REANCHOR_PRECISIONS = 2.0   # this, and than this many times its expected error there, moves the others
# a kept placement tolerates this many times the share of doors and glass (verify.in_gap) a new match does: the maps
# grow while doors open and shut, and a realistic 3-robot demo's check on its final maps dropped a robot it had kept
# right all run for one door (1.3 % of its agreeing walls); a new match stays strict (generated office36: aliases
# shifted by a room fill 3-4.5 %), and a frame that moved contradicts as structure
KEPT_GAP_FACTOR = 2.0
HELD_DROPPED = 'not confirmed yet, and a confirmed placement near it holds only without it'


@dataclass
class Check:
    """The re-check of one previous placement."""
    k: int
    transform: Optional[np.ndarray]   # the (refined) metric placement, None when it no longer holds
    match: PairMatch                  # figures against the union of the others (j: the most overlapping one)
    imprecise: bool = False           # refused for precision alone: every other rule of a pair passed


class Verdict(NamedTuple):
    """What tracking's memory keeps of a check that held (memory.checks, by name)."""
    grid: Grid                   # the grid checked
    transform: np.ndarray        # its placement, as the estimation ended
    seen: Dict[Hashable, str]    # content keys of the maps the check saw (its own, the placed ones near it) by name
    match: PairMatch


def context(k: int, placed: Dict[int, np.ndarray], footprints: Dict[int, Box]) -> Tuple[Optional[Box], List[int]]:
    """The area around grid k's footprint that its check looks at, and the other placed grids that meet it."""
    box = footprints.get(k)
    if box is None:
        return None, []
    area = (box[0] - CONTEXT_M, box[1] - CONTEXT_M, box[2] + CONTEXT_M, box[3] + CONTEXT_M)
    return area, sorted(m for m in placed if m != k and overlap_area(footprints.get(m), area) > 0.0)


def recheck(k: int, grids: Sequence[Optional[Grid]], prepared: Sequence[Optional[PreparedGrid]],
            placed: Dict[int, np.ndarray], footprints: Dict[int, Box], res: float,
            s: EstimationSettings, refine: bool = True,
            failing: str = 'previous placement no longer holds') -> Check:
    """Whether grid k, placed at placed[k], still agrees with the union of the other placed grids near it (refined
    first unless `refine` is False: then the placement is judged as it is); a refusal's reason starts with
    `failing`."""
    box = footprints.get(k)
    others = {m: t for m, t in placed.items() if m != k}
    match = PairMatch(k, most_overlapping(box, footprints, others))
    if box is None or match.j < 0:
        match.reason = 'no placed grid near it'
        return Check(k, None, match)
    area, near = context(k, placed, footprints)   # the grids its verdict will have seen (track)
    union = compose_near(grids, others, near, area, res)
    target = prepare(union, res, None) if union is not None else None
    if target is None:
        match.reason = 'no placed grid near it'
        return Check(k, None, match)
    pk = prepared[k]
    prior = tf.inverse(target.px_to_map) @ placed[k] @ pk.px_to_map
    rng = np.random.default_rng((s.seed, pk.draw_key))
    candidates = [verify(pk, target, prior, s)]
    best = candidates[0]
    if refine:
        # ICP from the prior, kept only if it ranks better: on a small common area ICP can slide off to a worse fit
        candidates.append(verify(pk, target, icp(pk, target, prior, s, rng), s))
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
        match.reason = f'{failing}: {reason}'
        return Check(k, None, match, imprecise=reason.startswith(IMPRECISE))
    metric = target.px_to_map @ best.transform @ tf.inverse(pk.px_to_map)
    match.accepted = True
    match.matches, match.inliers = best.support + best.conflicts, best.support
    match.confidence = pair_confidence(match.inliers, match.matches)
    match.transform_m = tf.inverse(placed[match.j]) @ metric
    return Check(k, metric, match)


def track(previous: Sequence[Optional[np.ndarray]], reference: int, grids: Sequence[Optional[Grid]],
          prepared: Sequence[Optional[PreparedGrid]], res: float, s: EstimationSettings, pool: Executor,
          memory: EstimationMemory, names: Sequence, contents: Sequence[Optional[str]],
          held: AbstractSet[int] = frozenset()) -> Tuple[Dict[int, np.ndarray], List[Check]]:
    """The previous placements (same reference, same merged frame) that still hold, refined, and the checks;
    `contents` are the grids' content keys (features.content_key), memory.latest those of the last estimation.
    Empty when the reference itself no longer agrees with the others: then nothing is kept. A placement confirmed
    by an earlier estimation stands without a new check while its map has barely changed since (memory.py); it is
    checked once more when the maps around it have stopped changing (verdict_stands).

    `held`: placements not confirmed yet (confirmation.py), tracked with the others. When the confirmed placements
    that fail their checks fail only beside held ones, and the rest of the merge supports them more than those held
    ones (held_in_doubt), they stay and the held ones are dropped: the new placement that contradicts the merge is
    the one in doubt (a replayed 12-robot run held robots 5 and 7 28 m along a corridor of alike rooms; robot_4's
    check beside them failed, and robots 4 and 3 left the merge for five estimations)."""
    placed = {k: np.asarray(t, float) for k, t in enumerate(previous)
              if t is not None and k < len(prepared) and prepared[k] is not None}
    if reference not in placed or len(placed) < 2:
        return {}, []
    footprints = {k: box for k, box in ((k, footprint(grids[k], t)) for k, t in placed.items()) if box is not None}
    kept_settings = s.replace(max_gap_conflicts=KEPT_GAP_FACTOR * s.max_gap_conflicts)

    # maps the same as in the last estimation: the maps around a placement have stopped changing when all have
    settled = {names[k] for k in placed if memory.latest.get(names[k]) == contents[k]}

    def seen(k: int) -> Dict[Hashable, str]:
        """The contents of the maps a check of grid k looks at: its own and the placed ones near it."""
        return {names[m]: contents[m] for m in [k] + context(k, placed, footprints)[1]}

    def check(k: int) -> Check:
        verdict = memory.checks.get(names[k])
        near = seen(k)
        if verdict is not None and verdict_stands(verdict, grids[k], placed[k], near, settled.issuperset(near)):
            return Check(k, placed[k], verdict.match)
        c = recheck(k, grids, prepared, placed, footprints, res, kept_settings)
        rechecked[k] = c
        if c.transform is None:   # its map frame may have moved (a SLAM failure): nothing learnt of it stands
            memory.checks.drop(names[k])
            memory.keypoints.drop(names[k])
            memory.shown.drop(names[k])
        return c

    checks: Dict[int, Check] = {}
    rechecked: Dict[int, Check] = {}   # the checks made anew (not standing from memory), the last of each grid
    to_check = [k for k in placed if k != reference]
    for _ in range(MAX_PASSES):
        for c in pool.map(check, to_check):
            checks[c.k] = c
        failed = [k for k in placed if k != reference and checks[k].transform is None]
        if not failed:
            break
        # one wrong map makes its neighbours contradict too: drop the worst, then check the others without it; a
        # check sees only the placed grids near its own, so only those that saw the worst one can come out otherwise
        # (the others would be made again on the same maps: a fleet's final check of 24 placements made 47)
        doubted = held_in_doubt([k for k in failed if k not in held], placed, footprints, held,
                                lambda k, without: recheck(k, grids, prepared, without, footprints, res,
                                                           kept_settings))
        dropped = list(doubted) or [least_agreeing([checks[k] for k in failed]).k]
        for k in dropped:
            del placed[k]
            if k in doubted:
                checks[k] = Check(k, None, PairMatch(k, doubted[k], reason=HELD_DROPPED))
        to_check = [k for k in placed if k != reference and any(
            overlap_area(footprints.get(d), context(k, placed, footprints)[0]) > 0.0 for d in dropped)]
    else:
        for k in [k for k in placed if k != reference and checks[k].transform is None]:
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
        correction = reanchoring(ref, footprints.get(reference))
        if correction is not None:
            log.info('re-anchored the placed grids on the reference grid %d (%.2f deg, %.2f m)', reference,
                     *correction[1:])
            for k in placed:
                if k != reference:
                    placed[k] = correction[0] @ placed[k]
    relaxed = relax_placed(placed, reference, grids, prepared, footprints, s, memory, names)
    for c in checks.values():
        if c.transform is None:
            log.info('grid %d: %s', c.k, c.match.reason)
    # the new verdicts, with the placements this estimation ends with (the next one starts from them); a verdict
    # that stood keeps what it saw then, so that small changes cannot add up unchecked
    for k in placed:
        if k in rechecked and rechecked[k].transform is not None:
            memory.checks.put(names[k], Verdict(grids[k], placed[k], seen(k), rechecked[k].match))
        elif k in relaxed and k != reference:
            # a verdict that stood holds for the placement refined with the others: the walls of every pair fit
            # better there (relax.py), and a verdict lost at each relaxation would make every check again
            move_verdict(memory, names[k], placed[k])
    return placed, list(checks.values())


def move_verdict(memory: EstimationMemory, name: Hashable, transform: np.ndarray) -> None:
    """Let the verdict on `name`'s placement, if any, stand for `transform`, a refinement of that placement."""
    verdict = memory.checks.get(name)
    if verdict is not None:
        memory.checks.put(name, verdict._replace(transform=transform))


def relax_placed(placed: Dict[int, np.ndarray], reference: int, grids: Sequence[Optional[Grid]],
                 prepared: Sequence[Optional[PreparedGrid]], footprints: Dict[int, Box], s: EstimationSettings,
                 memory: EstimationMemory, names: Sequence) -> set:
    """Refine the kept placements together (relax.py), in place; the grids moved. Again only once a placed map has
    grown or changed as much as a verdict on it allows (memory.unchanged), or the placed maps are others: on maps
    that barely changed it would find what it found last time."""
    if len(placed) < 3:
        return set()   # two grids: the pair's own check refines them together
    last = memory.relaxed
    if last is not None and set(last) == {names[k] for k in placed} \
            and all(memory.unchanged(last[names[k]], grids[k]) for k in placed):
        return set()
    memory.relaxed = {names[k]: grids[k] for k in placed}
    out = relax(placed, reference, grids, prepared, footprints, s.min_overlap_m2, s.seed)
    if out is None:
        return set()
    moved = {k for k in placed if not np.allclose(out[k], placed[k])}
    placed.update(out)
    return moved


def held_in_doubt(failed: Sequence[int], placed: Dict[int, np.ndarray], footprints: Dict[int, Box],
                  held: AbstractSet[int], check: Callable[[int, Dict[int, np.ndarray]], Check]) -> Dict[int, int]:
    """The held placements near the confirmed ones that `failed` their checks, each with the confirmed one it
    contradicts, when every one of those holds without them (`check(k, placed without them)`) on more agreeing walls
    than those held ones hold on without it; none otherwise. A confirmed placement that fails without them too
    leaves the merge itself in doubt (a generated hospital replayed as a growing fleet: four maps published in four
    frames, the held ones in yet others; the reference's check failing beside them starts the estimation afresh);
    held ones that the published maps alone support as much are as likely right as the confirmed one (a confirmed
    placement can be wrong too), and the rule for any failed check decides. A held one counts only the support of
    the published maps: held maps that grow together support each other (the replayed 12-robot run: robots 5 and 7
    on 1517 and 1539 agreeing walls with each other, on none without)."""
    out: Dict[int, int] = {}
    for k in failed:
        near = [m for m in context(k, placed, footprints)[1] if m in held]
        if not near:
            return {}
        own = check(k, {m: t for m, t in placed.items() if m not in near})
        if own.transform is None:
            return {}
        theirs = [check(m, {n: t for n, t in placed.items() if n != k and (n == m or n not in held)}) for m in near]
        if sum(c.match.best.support for c in theirs if c.transform is not None) >= own.match.best.support:
            return {}
        out.update((m, k) for m in near if m not in out)
    return out


def least_agreeing(failed: Sequence[Check]) -> Check:
    """Of failed checks, the one whose placement agrees least with the others (a wrong map makes its neighbours
    contradict too: it is dropped first, and the others checked again without it)."""
    return min(failed, key=lambda c: c.match.best.agreement if c.match.best is not None else -1.0)


def reanchoring(ref: Check, box: Optional[Box]) -> Optional[Tuple[np.ndarray, float, float]]:
    """(correction for the other placements, degrees, metres) when the reference grid, checked against the others,
    fits them better elsewhere: the others agree among themselves, and an early placement (small maps) was off; the
    reference stays the frame, so the others move. None when the move at the reference's corners is within
    REANCHOR_M, or within REANCHOR_PRECISIONS times the error its shared walls leave there: live runs re-anchored
    by 0.1-0.5 degrees back and forth, and each time carried a weakly placed map along a corridor it could not
    slide back from."""
    corners = np.array([[box[0], box[1]], [box[2], box[3]]]) if box is not None else np.zeros((0, 2))
    rot, shift = tf.difference(ref.transform, np.eye(3), corners)
    expected = ref.match.best.corner_error_m if ref.match.best is not None else 0.0
    if shift <= max(REANCHOR_M, REANCHOR_PRECISIONS * expected):
        return None
    return tf.inverse(ref.transform), math.degrees(rot), shift


def verdict_stands(verdict: Verdict, grid: Grid, transform: np.ndarray, seen: Dict[Hashable, str],
                   settled: bool) -> bool:
    """Whether a verdict still stands for `grid` placed by `transform`, the maps near it now being `seen`: the grid
    has barely changed (memory.py) and is placed where it was; and, once the maps around it have stopped changing
    (`settled`), they are the maps the check saw. That last check runs once at the end of a run, so that the merge
    it ends with rests on the final maps: a live run kept a placement made on early maps 18 cm off to the end, and
    a check on the final maps put it within 4-10 cm. (Checking again whenever a map nearby grows cost a fleet of 30
    robots a quarter more estimation time while they explore.)"""
    if not (unchanged(verdict.grid, grid) and np.allclose(verdict.transform, transform)):
        return False
    return not settled or verdict.seen == seen
