"""One pair of prepared grids through every stage: candidates, refinement, verification, the acceptance rules.

For a pair (i, j): rigid hypotheses from descriptor matches (hypotheses.py), or from a correlation search when
they find no plausible placement (search.py); each screened, refined by ICP (refine.py) and verified (verify.py);
ICP results at one place are verified once (verify.same_place); the best one turned by quarter turns to look for a
symmetric alias, polished (polish.py; so is a near miss), then judged by the acceptance rules, with ambiguity
(another distinct placement nearly as good) and the original's confidence threshold last.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, List, Optional

import numpy as np

from .. import transforms as tf
from .features import PreparedGrid, nonzero_2d
from .hypotheses import hypotheses, putative_matches, quick_agreement
from .neighbours import NeighbourCache
from .orientation import aligned
from .polish import polish, slid
from .precision import covariance
from .refine import icp
from .search import correlate_candidates
from .verify import (IMPRECISE, Placement, distinct, landing_box, overlap_found, pair_confidence, plausible, refusal,
                     same_place, verify, warp_into)

if TYPE_CHECKING:
    from .settings import EstimationSettings

log = logging.getLogger('rosout.multirobot_map_merge.estimation.pair')

POLISH_STARTS = 3       # nearby estimates of a small-overlap placement polished, the best kept
LIGHT_ICP_POINTS = 400  # walls of the ICP that brings a turned placement in before it is screened
RESCUE_PLACES = 3       # distinct places polished when no candidate is plausible (see rescued)
RESCUE_SINGLE = 1       # places polished when a search of a single grid found no candidate that passes
OTHER_PLACES = 3        # distinct places besides the best kept in metric form (PairMatch.other_places_m)
RIVAL_PLACES = 40       # best places of find_rival's search refined, by default
SLID_PEAKS = 4          # places at the best's angle refined by slid_alternatives
SEARCH_POSTPONED = 'search postponed: the search budget of this estimation is spent'
# a join of two groups is refused beside a distinct place where their unions overlap with this many times its
# support and contradict (overlap_found): on the generated 36-map buildings (seeds 0-8) the hospital's wings of
# identical rooms joined at 21-93 m2 beside such a place 4.4-22 times larger, right or wrong alike (false merges in 4
# of 9 seeds, 8-10 maps each, half a turn or 28-53 m off), and in one seed a maze's groups joined a quarter turn off;
# refused, no group joins wrong there, and 12-17 of hospital36's 27 maps are placed
ELSEWHERE_SUPPORT = 4.0
# but only where the unions nearly fit at that place (NEAR_MISS's agreement), or the join is less precise than this
# share of max_corner_error_m: in a maze the walls' lattice lines up a cell's width along at 0.61-0.74 agreement, which
# says nothing of where two groups meet (the held-out maze36_v: a side group of six joined at 0.09-0.14 m expected at
# the far corners, right), while joins there 0.21-0.22 m uncertain were 0.10-0.27 m off (maze36_u, seeds 1 and 2)
ELSEWHERE_PRECISION = 0.6
AMBIGUOUS = 'ambiguous'   # the start of the reason of a match refused beside another place as good
NEAR_MISS = dict(min_agreement=0.8, max_deep_conflicts=0.05)   # rules a best candidate passes to be polished


@dataclass
class PairMatch:
    i: int
    j: int
    # Brown-Lowe statistics on verified correspondences: matches = wall pixels of both maps in the common area,
    # inliers = those with a wall of the other map near them (the placement's support); see pair_confidence()
    matches: int = 0
    inliers: int = 0
    confidence: float = 0.0
    descriptor_matches: int = 0     # putative descriptor matches (ratio test), as the original counts them
    descriptor_inliers: int = 0     # of those, consistent with the final placement
    accepted: bool = False
    reason: str = ''
    best: Optional[Placement] = None
    transform_m: Optional[np.ndarray] = None   # metric: map frame of i -> map frame of j
    alternatives: List[Placement] = field(default_factory=list, repr=False)
    # metric (like transform_m) places of the best distinct other candidates with the support and common area of an
    # acceptable placement: onto a union in a repetitive building, the best can be an alias while the true place,
    # contradicted by one broken member, ranks below it (eviction.py judges the members there too)
    other_places_m: List[np.ndarray] = field(default_factory=list, repr=False)
    searched: bool = False   # a correlation search ran: the descriptors found no plausible placement
    imprecise_only: bool = False   # refused as imprecise, and by no other rule

    @property
    def weight(self) -> float:
        return float(self.best.support) if self.best is not None else 0.0


def accepted_at(i: int, j: int, c: Placement, transform_m: np.ndarray) -> PairMatch:
    """An accepted match of grid (or union) i onto j made of a verification `c` at `transform_m` (metric: i's frame
    -> j's), where the estimation judged a placement itself rather than by match_pair."""
    m = PairMatch(i, j, c.support + c.conflicts, c.support, accepted=True, best=c)
    m.confidence = pair_confidence(m.inliers, m.matches)
    m.transform_m = transform_m
    return m


def symmetric_alternatives(pi: PreparedGrid, pj: PreparedGrid, best: Placement) -> List[np.ndarray]:
    """The best placement turned by 90, 180 and 270 degrees about the middle of the common area.

    Buildings repeat themselves; a placement that is as good after such a turn means the match is ambiguous.
    """
    box = landing_box(pi, pj, best.transform, 0)
    if box is None:
        return []
    x0, y0, x1, y1 = box
    warped = warp_into(pi.work.view(np.uint8), best.transform, box, 255).view(np.int8)
    rows, cols = nonzero_2d((warped >= 0) & (pj.work[y0:y1, x0:x1] >= 0))
    if rows.size == 0:
        return []
    cx, cy = cols.mean() + x0, rows.mean() + y0
    out = []
    for quarter in (1, 2, 3):
        turn = tf.translation(cx, cy) @ tf.rigid(0.0, 0.0, quarter * math.pi / 2) @ tf.translation(-cx, -cy)
        out.append(turn @ best.transform)
    return out


def slid_alternatives(pi: PreparedGrid, pj: PreparedGrid, best: Placement, s: EstimationSettings) -> List[np.ndarray]:
    """The best places of grid i on grid j at the angle of `best` other than it (a correlation at that angle
    alone, as the search's).

    Descriptors see a small part of each map: in a building that repeats itself at one angle (rows of racks, rooms
    along a corridor) their only model can be an alias slid by the period, and nothing else is tried where no search
    runs. Held-out warehouse36_u: map_05 placed onto map_01 by its descriptors 3.9 m along the racks (agreement 0.997
    over 106 m2), where the truth agrees 1.00 over 109 m2; this correlation's best peak is the truth. With the
    refinement of its places it costs 7 % of the CPU of an estimation of the dev set's 30 maps."""
    t = best.transform
    return correlate_candidates(pi, pj, s.search_factor, peaks_per_angle=SLID_PEAKS, keep=SLID_PEAKS,
                                penalty=s.search_penalty, free_reward=s.search_free_reward,
                                wanted=lambda model: distinct(model, t, pi, s),
                                angles=[math.atan2(t[1, 0], t[0, 0])])


def find_rival(pi: PreparedGrid, pj: PreparedGrid, best: Placement, s: EstimationSettings,
               keep: int = RIVAL_PLACES, enough: Optional[Callable[[Placement], bool]] = None) -> Optional[Placement]:
    """Another place for grid i on grid j that passes the rules of `plausible` (not the precision rule), however
    much smaller its common area, searched by correlation away from `best` (`keep` candidates refined); with
    `enough`, the first such place that it also finds enough.

    Not an acceptance rule: small consistent placements are common (a corner of one map fitting a corner of the
    other), and on the saved maps of 199 live-demo runs such a rival, with 100-177 agreeing wall cells, existed
    for 19 right placements with 153-2175. scripts/evidence_report.py uses it to show true ambiguity."""
    rng = np.random.default_rng(s.seed)
    models = correlate_candidates(pi, pj, s.search_factor, s.search_sweep_degrees, peaks_per_angle=4,
                                  keep=keep, penalty=s.search_penalty,
                                  free_reward=s.search_free_reward,
                                  wanted=lambda model: distinct(model, best.transform, pi, s), threads=s.threads)
    for model in models:
        if quick_agreement(pi, pj, model, s, rng) < s.screen_min_agreement:
            continue
        c = verify(pi, pj, icp(pi, pj, model, s, rng), s)
        if plausible(c, s) and distinct(c.transform, best.transform, pi, s) and (enough is None or enough(c)):
            return c
    return None


def overlap_elsewhere(best: Placement, others: List[Placement], pi: PreparedGrid, s: EstimationSettings,
                      onto_union: bool = False) -> Optional[Placement]:
    """A distinct place among `others` where two unions overlap with ELSEWHERE_SUPPORT times the support of `best`
    and contradict (overlap_found), and which makes a join at `best` a guess: the unions nearly fit there (NEAR_MISS's
    agreement), or `best` is less precise than ELSEWHERE_PRECISION of max_corner_error_m; None if there is none.

    Every such place is asked, the near misses first: the largest may only line up a maze's lattice of walls while a
    smaller one, still several times the join's, nearly fits."""
    larger = [c for c in others if c.support >= ELSEWHERE_SUPPORT * best.support
              and distinct(c.transform, best.transform, pi, s) and overlap_found(c, s, onto_union)]
    near = max((c for c in larger if c.agreement >= NEAR_MISS['min_agreement']), key=lambda c: c.support,
               default=None)
    if near is not None or best.corner_error_m <= ELSEWHERE_PRECISION * s.max_corner_error_m:
        return near
    return max(larger, key=lambda c: c.support, default=None)


def as_good(c: Placement, best: Placement, s: EstimationSettings) -> bool:
    """Whether placement c agrees almost as well as `best` (ambiguity_ratio): it agrees at least as well over almost
    as large a common area, or it scores almost as well, or, when the best scores zero or less, it has almost as
    much support.

    The first: two alike parts of a building (the two ends of one room, two rooms) hold different numbers of walls,
    so the support of a place says how much wall its common area holds as much as how well it fits: two robots at
    the two ends of one long room each saw their own end, one end fitted the other after a half turn with 318
    agreeing walls over 16.8 m2, and the truth, slid along the room, agreed as fully over 13.8 m2 with 147 (live,
    3 sim s). The last: when the best's contradictions at the fringe of the other map's view outweigh its support
    (a tiny early map whose walls end where the other's beams end), a ratio of scores says nothing (it asked a rival
    to score higher than the best): a live run placed a map of one room corner 90 degrees and 50 m off (support
    123, score -127) over a plausible place at another corner with more support (139, score -341)."""
    best_score = best.score(s.conflict_weight)
    if c.agreement >= best.agreement and c.overlap_m2 >= s.ambiguity_ratio * best.overlap_m2:
        return True
    if best_score > 0:
        return c.score(s.conflict_weight) >= s.ambiguity_ratio * best_score
    return c.support >= s.ambiguity_ratio * best.support


def rescued(pi: PreparedGrid, pj: PreparedGrid, candidates: List[Placement], s: EstimationSettings,
            rng: np.random.Generator, places_max: int = RESCUE_PLACES) -> List[Placement]:
    """The places of the best candidates with the support and common area of an acceptable placement, each polished
    from its estimates (as the final polish); those that then pass the rules of `plausible`. From a search candidate
    a few tenths of a degree and of a metre off, ICP settles in a minimum half a metre and a degree away where part
    of the walls disagree (seen matching two groups' unions: agreement 0.5-0.8 there, 1.0 at the truth); the
    polish's symmetric cost reaches the truth."""
    large = sorted((c for c in candidates if c.support >= s.min_support and c.overlap_m2 >= s.min_overlap_m2),
                   key=lambda c: -c.score(s.conflict_weight))
    out: List[Placement] = []
    places: List[np.ndarray] = []
    for c in large:
        if len(places) >= places_max:
            break
        if any(not distinct(c.transform, t, pi, s) for t in places):
            continue
        places.append(c.transform)
        starts = [e.transform for e in large if not distinct(e.transform, c.transform, pi, s)][:POLISH_STARTS]
        polished = verify(pi, pj, polish(pi, pj, starts, rng), s)
        if plausible(polished, s):
            out.append(polished)
    return out


def other_places(best: Placement, others: List[Placement], pi: PreparedGrid, s: EstimationSettings,
                 most: int = OTHER_PLACES) -> List[np.ndarray]:
    """The pixel transforms of up to `most` candidates among `others` (best first) with the support and common area
    of an acceptable placement, each distinct from the best and from those before it."""
    places: List[np.ndarray] = []
    for c in others:
        if len(places) >= most:
            break
        if c.support >= s.min_support and c.overlap_m2 >= s.min_overlap_m2 \
                and all(distinct(c.transform, t, pi, s) for t in [best.transform] + places):
            places.append(c.transform)
    return places


def turned_to_directions(pi: PreparedGrid, pj: PreparedGrid, c: Placement, s: EstimationSettings,
                         onto_union: bool) -> Optional[Placement]:
    """Placement c, which the shared walls leave imprecise, turned about their centre so that both grids' wall
    directions meet (orientation.py), if it then passes the rules; None otherwise."""
    found = covariance(pi, pj, c.transform, s.verify_tolerance)
    model = aligned(pi, pj, c.transform, found[1]) if found is not None else None
    if model is None:
        return None
    # turned about the middle of the shared walls, it can be left a pixel or two aside: moved into place (held-out
    # classic36 in the first drawn order: map_21, searched onto the merge by 15.6 m2, was turned 0.06 degrees and
    # left 0.086 m off, agreeing 0.988; moved, 0.03 m off and 1.000)
    turned = verify(pi, pj, slid(pi, pj, model, np.random.default_rng(s.seed)), s)
    return turned if plausible(turned, s) and not refusal(turned, pi, pj, s, onto_union) else None


def match_pair(i: int, j: int, pi: PreparedGrid, pj: PreparedGrid, s: EstimationSettings,
               search: bool = True, onto_union: bool = False, descriptors: bool = True,
               between_groups: bool = False, search_spent: bool = False, distinct_places: bool = False,
               neighbours: Optional[NeighbourCache] = None) -> PairMatch:
    """Match grids i and j; the result's transform_m maps metric points of map i into map j.

    With search=False, only descriptor matches propose placements (cheap); otherwise a correlation search adds
    candidates when they found no plausible one. With descriptors=False, only the search does (the caller has
    matched descriptors already and found nothing plausible). With `onto_union`, j is the union of a placed group
    (see refusal). A search is not made when the descriptors found where the maps overlap and they contradict
    there (a broken map: a search finds the same). With `between_groups` (i and j are the unions of two groups,
    growth.py), it is, and a join is refused beside a distinct place where the unions overlap far more and contradict
    (ELSEWHERE_SUPPORT). When a search found no candidate that passes, the best places are polished and judged again
    (`rescued`): RESCUE_PLACES of them between groups (few matches), the best one after any other search (ICP slides
    a small overlap along a corridor: in a replayed demo run a robot was placed 10 sim s sooner).

    With `search_spent` (the caller's search budget has run out), a match that would need the search is refused as
    postponed (SEARCH_POSTPONED), not judged on the descriptors' candidates alone: the search's candidates can
    outrank them or make them ambiguous, so a match accepted without them could be one that the same maps refuse,
    or place elsewhere, when there is time to search.

    With `distinct_places`, the search refines after its best peaks the best peak of each of its best places that
    those miss (search.Places): for a map whose descriptors found an alias in a repetitive building, where the alias
    scores high at several angles and crowds the truth out of the best peaks.

    `neighbours` keeps descriptor distances for the matches of one estimation (neighbours.py).
    """
    result = PairMatch(i, j)
    rng = np.random.default_rng((s.seed, pi.draw_key, pj.draw_key))
    verified: List[Placement] = []   # one per place ICP reached

    def refine(model: np.ndarray, screen: bool = True, draws: Optional[np.random.Generator] = None
               ) -> Optional[Placement]:
        draws = rng if draws is None else draws
        if screen and quick_agreement(pi, pj, model, s, draws) < s.screen_min_agreement:
            return None
        if not screen:
            # far off until ICP pulls it in: screened after a light ICP (few walls) instead
            model = icp(pi, pj, model, light, draws)
            if quick_agreement(pi, pj, model, s, draws) < s.screen_min_agreement:
                return None
        # RANSAC's next hypothesis is often the first again, from the matches its inlier threshold left out, and
        # search candidates of one place are many: their ICP stops where an earlier one ended, and they take its
        # verification (they still count as estimates of that place for the polish)
        model = icp(pi, pj, model, s, draws, [c.transform for c in verified])
        twin = next((c for c in verified if same_place(model, c.transform, pi)), None)
        if twin is not None:
            return dataclasses.replace(twin, transform=model)
        verified.append(verify(pi, pj, model, s))
        return verified[-1]

    def refine_all(models, screen: bool = True) -> List[Placement]:
        return [c for c in (refine(m, screen) for m in models) if c is not None]

    light = s.replace(icp_max_points=LIGHT_ICP_POINTS)
    pairs = putative_matches(pi, pj, s.ratio, not onto_union, neighbours) if descriptors else np.zeros((0, 2), np.int64)
    result.descriptor_matches = len(pairs)
    p, q = (pi.keypoints[pairs[:, 0]], pj.keypoints[pairs[:, 1]]) if len(pairs) else (np.zeros((0, 2)),) * 2

    def by_score(c: Placement):
        # a placement that agrees beats any that does not, however large
        return plausible(c, s), c.score(s.conflict_weight)

    def first(candidates: List[Placement]) -> Optional[Placement]:
        # the best by score, unless a distinct place that agrees ranks higher without the conflicts at the fringe
        # (Placement.rank); between estimates of one place the score chooses
        top = max(candidates, key=by_score, default=None)
        if top is None or not plausible(top, s):
            return top
        evident = max((c for c in candidates if plausible(c, s)), key=lambda c: c.rank(s.conflict_weight))
        return evident if distinct(evident.transform, top.transform, pi, s) else top

    candidates = refine_all(hypotheses(p, q, s, rng))
    best = first(candidates)
    searched = False
    if search and (best is None or not plausible(best, s)) \
            and (between_groups or not overlap_found(best, s, onto_union)):
        if search_spent:
            result.reason = SEARCH_POSTPONED
            return result
        # too few good descriptor matches (small overlaps): search placements by correlation instead;
        # not when the overlap was found and the maps contradict there (a broken map): a search finds the same
        candidates += refine_all(correlate_candidates(pi, pj, s.search_factor, s.search_sweep_degrees,
                                                      keep=s.search_keep, penalty=s.search_penalty,
                                                      free_reward=s.search_free_reward, threads=s.threads,
                                                      distinct_places=distinct_places))
        best = first(candidates)
        searched = True
    if best is None:
        result.reason = 'no rigid model'
        return result
    if (between_groups or searched) and s.polish and not plausible(best, s):
        candidates += rescued(pi, pj, candidates, s, rng, RESCUE_PLACES if between_groups else RESCUE_SINGLE)
        best = first(candidates)
    elif s.polish and not plausible(best, s):
        # a near miss: on a small common area (or onto a union) ICP can stop a pixel off, where thin walls miss
        # each other and contradict; polished, it is judged again (ICP from the other estimates of that place, which
        # might have landed closer, stopped once they reached it)
        near = max((c for c in candidates if plausible(c, s.replace(**NEAR_MISS))), key=lambda c: c.agreement,
                   default=None)
        polished = verify(pi, pj, polish(pi, pj, [near.transform], rng), s) if near is not None else None
        if polished is not None and plausible(polished, s):
            candidates.append(polished)
            best = polished
    if plausible(best, s):
        # only worth the extra work for a placement that could be accepted
        candidates += refine_all(symmetric_alternatives(pi, pj, best), screen=False)
        if not searched:
            # other places only, refined with draws of their own: the best's place and its polish stay as they were
            draws = np.random.default_rng((s.seed, pi.draw_key, pj.draw_key, 1))
            slid = (refine(model, draws=draws) for model in slid_alternatives(pi, pj, best, s))
            candidates += [c for c in slid if c is not None and distinct(c.transform, best.transform, pi, s)]
    candidates.sort(key=by_score, reverse=True)
    lead = first(candidates)
    candidates.insert(0, candidates.pop(next(n for n, c in enumerate(candidates) if c is lead)))
    if s.polish and plausible(candidates[0], s):
        # ICP can settle in a nearby minimum, a degree off on a small common area and even on a large one; the
        # other plausible estimates of the same place are polished too, and the most consistent result is kept
        same = [c.transform for c in candidates[1:] if plausible(c, s)
                and not distinct(c.transform, candidates[0].transform, pi, s)][:POLISH_STARTS - 1]
        starts = [candidates[0].transform]
        for t in same:
            if not any(same_place(t, u, pi) for u in starts):
                starts.append(t)
        polished = verify(pi, pj, polish(pi, pj, starts, rng), s)
        candidates[0] = polished if plausible(polished, s) else candidates[0]
    reason = refusal(candidates[0], pi, pj, s, onto_union)
    if reason.startswith(IMPRECISE):
        turned = turned_to_directions(pi, pj, candidates[0], s, onto_union)
        if turned is not None:
            candidates[0], reason = turned, ''
    best = candidates[0]
    result.best = best
    result.alternatives = candidates[1:]
    if len(pairs):
        result.descriptor_inliers = int((np.hypot(*(tf.apply(best.transform, p) - q).T) < s.ransac_threshold).sum())
    result.matches, result.inliers = best.support + best.conflicts, best.support
    result.confidence = pair_confidence(result.inliers, result.matches)
    result.transform_m = pj.px_to_map @ best.transform @ tf.inverse(pi.px_to_map)
    result.other_places_m = [pj.px_to_map @ t @ tf.inverse(pi.px_to_map)
                             for t in other_places(best, candidates[1:], pi, s)]

    rival = next((c for c in candidates[1:] if distinct(c.transform, best.transform, pi, s) and plausible(c, s)
                  and as_good(c, best, s)), None)
    result.searched = searched
    # the rules after precision, judged also when the match is imprecise: between groups the grower judges such a
    # match again where the groups meet (growth.Grower.joins_where_met)
    later = ''
    if rival is not None:
        later = (f'{AMBIGUOUS}: another placement agrees {rival.agreement:.2f} with support {rival.support} vs '
                 f'{best.support}')
    if not later and between_groups:
        # two unions that overlap far more elsewhere, where they contradict: a small join beside it is a guess
        elsewhere = overlap_elsewhere(best, candidates[1:], pi, s, onto_union)
        if elsewhere is not None:
            later = (f'the unions overlap elsewhere: a place with support {elsewhere.support} (here '
                     f'{best.support}) agrees {elsewhere.agreement:.2f} and contradicts')
    if not later and result.confidence < s.confidence:
        later = f'confidence {result.confidence:.2f} < {s.confidence:.2f}'
    result.reason = reason or later
    result.imprecise_only = reason.startswith(IMPRECISE) and not later
    result.accepted = not result.reason
    log.debug('pair %d-%d: %d descriptor matches (%d inliers), %d wall correspondences (%d inliers), confidence '
              '%.3f, agreement %.3f, overlap %.1f m2%s, %s', i, j, result.descriptor_matches, result.descriptor_inliers,
              result.matches, result.inliers, result.confidence, best.agreement, best.overlap_m2,
              f', expected error at the far corners {best.corner_error_m:.2f} m' if best.corner_error_m else '',
              'accepted' if result.accepted else result.reason)
    return result
