"""Growing groups of placed grids: every newcomer is matched against the union of a group (estimation stage 3).

A group starts from a seed and grows in rounds. In a round every grid not placed yet is matched against the union of
the group (union.py) by descriptors only, cheap and in parallel; the accepted ones join, and the next round matches
the rest against the grown union. A round that adds nobody runs the costly correlation search (unless the group grows
by descriptors only), on the remaining grids smallest first. Work whose answer cannot have changed is skipped: a
grid is not matched again against a union that has not changed where its last match placed it, nor, when its
descriptors found no candidate at all there, against one whose new members' descriptors do not agree on a rigid model
with its own (on the generated 36-map buildings that skips over a quarter of the matches), nor searched again
against one that has grown by less than a quarter since (with an EstimationMemory, memory.py, also from one
estimation of a live fleet to the next while its own map has barely changed); members' keypoints are kept until
their maps grow.
"""
from __future__ import annotations

import dataclasses
import itertools
import logging
import time
from concurrent.futures import Executor
from typing import Callable, Dict, FrozenSet, Hashable, Iterable, Iterator, List, Optional, Sequence, Set, Tuple

import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import PreparedGrid, map_keypoints
from .hypotheses import putative_matches, ransac_rigid
from .memory import EstimationMemory
from .pair import AMBIGUOUS, SEARCH_POSTPONED, PairMatch, accepted_at, as_good, find_rival
from .settings import EstimationSettings
from .split import parts_of, split
from .eviction import (contradicted_members, judge_members, members_agreement, places, singled_out_together,
                       vouched_for)
from .stronger import FEW_MEMBERS, WEAK_AGREEMENT, PairEvidence, stronger_elsewhere
from .tracking import MAX_PASSES, Check, least_agreeing, recheck
from .union import Box, UnionMap, footprint, overlap_area
from .refine import icp
from .verify import IMPRECISE, Placement, distinct, overlap_found, partly_agreeing, plausible, refusal, verify
from .workers import MatchCall, ParallelMatcher

SEARCH_GROWTH = 1.25   # a grid is searched against a union again only once the union has grown by this factor
LEFT_OUT_SHARE = 0.5   # of a grid's known area that search_left_out's placement must share with the merge
JOIN_EVICTIONS = 3     # members taken out of two groups whose unions refuse each other (evict_at_join), at most
LEFT_OUT_ROUNDS = 5    # search_left_out's rounds: the searches, and again while maps join (refused or sharing little)
MATCH_GROWTH = 1.1     # with a memory: matched by descriptors again only once the union has grown by this factor
SEED_PROBE = 12        # grids matched first onto a new seed (grow's probe)
SEED_CONTRADICTED = 8  # of those, refused ones that overlap it and partly contradict it, none accepted: the seed waits

log = logging.getLogger('rosout.multirobot_map_merge.estimation.growth')

Progress = Callable[[int, int], None]   # (grids settled, grids in all), called as the estimation goes


_GROUP_KEYS = itertools.count()


class SearchBudget:
    """Whether one estimation's correlation searches have spent their budget (settings.search_budget_s), asked
    before each search. The budget is wall time, the one thing in an estimation that depends on the machine's load:
    each answer is logged (`verdicts`) so that a replay of the estimation can be given the same answers (`script`;
    beyond its end the clock answers), and makes the same searches (recording.py)."""

    def __init__(self, script: Optional[Sequence[bool]] = None) -> None:
        self.verdicts: List[bool] = []
        self._script = list(script) if script is not None else None

    def spent(self, seconds: float, budget: float) -> bool:
        k = len(self.verdicts)
        verdict = self._script[k] if self._script is not None and k < len(self._script) else seconds >= budget
        self.verdicts.append(verdict)
        return verdict


class Group:
    """Grids placed together: grid index -> metric transform into the frame of the seed grid."""

    def __init__(self, seed: int, grid: Grid, prepared: PreparedGrid, res: float,
                 keypoints_of: Optional[Callable] = None):
        # what was tried against the group is kept under this key, not its id: the id of a group that has gone (one
        # absorbed by another) is soon another's, which would count as tried what never was
        self.key = next(_GROUP_KEYS)
        self.seed = seed
        self.union = UnionMap(res, keypoints_of)
        self.union.add(seed, grid, prepared, np.eye(3))
        self.links: Dict[int, PairMatch] = {}   # how each member but the seed joined

    @property
    def members(self) -> Dict[int, np.ndarray]:
        return self.union.members

    def join(self, k: int, grid: Grid, prepared: PreparedGrid, m: PairMatch) -> None:
        """Grid k joins, placed by m (metric: map k -> the group's frame)."""
        self.union.add(k, grid, prepared, m.transform_m)
        self.links[k] = self.paired(m, k)

    def absorb(self, other: 'Group', other_to_self: np.ndarray, m: PairMatch) -> None:
        """Every member of another group joins, placed by `other_to_self` (metric: its frame -> this frame), as
        the match m of the two unions found."""
        self.union.absorb(other.union, other_to_self)
        self.links.update(other.links)
        self.links[other.seed] = self.paired(m, other.seed)

    def move(self, placements: Dict[int, np.ndarray]) -> None:
        """The members placed anew (metric: map -> the group's frame; a refinement of them together), their links
        restated."""
        for k, t in placements.items():
            self.union.add(k, self.union.grids[k], self.union.parts[k], t)
        for k, link in self.links.items():
            self.links[k] = dataclasses.replace(link, transform_m=tf.inverse(self.members[link.j]) @ self.members[k])

    def leave(self, k: int) -> None:
        """Member k leaves; the members reported as paired with it are paired anew with the one they overlap most."""
        self.union.remove(k)
        self.links.pop(k, None)
        for m, link in list(self.links.items()):
            if link.j == k:
                self.links[m] = self.paired(link, m)

    def reframe(self, seed: int) -> np.ndarray:
        """Member `seed` becomes the group's seed, its frame the group's: every placement is restated in it (before
        the old seed leaves). Returns the transform from the old frame to the new one."""
        to_new = tf.inverse(self.members[seed])
        old = self.union
        self.union = UnionMap(old.resolution, old.keypoints_of)
        for k, t in old.members.items():
            self.union.add(k, old.grids[k], old.parts[k], to_new @ t)
        self.union.version = old.version + 1   # what was tried against the old union counts as tried before
        self.seed = seed
        return to_new

    def paired(self, m: PairMatch, k: int) -> PairMatch:
        """m (member k placed onto the union) restated as a pair of k and the member it overlaps most."""
        anchor = self.union.anchor(k)
        out = PairMatch(k, anchor, m.matches, m.inliers, m.confidence, m.descriptor_matches, m.descriptor_inliers,
                        m.accepted, m.reason, m.best)
        out.transform_m = tf.inverse(self.members[anchor]) @ self.members[k]
        return out


class Grower:
    """Grows groups over one estimation; owns the bookkeeping of which grid was tried against which union."""

    def __init__(self, grids: Sequence[Optional[Grid]], prepared: Sequence[Optional[PreparedGrid]], res: float,
                 settings: EstimationSettings, pool: Executor, reference: Optional[int],
                 progress: Optional[Progress], memory: Optional[EstimationMemory] = None,
                 names: Optional[Sequence] = None, matcher: Optional[ParallelMatcher] = None,
                 budget: Optional[SearchBudget] = None):
        self.grids, self.prepared, self.res, self.s, self.pool = grids, prepared, res, settings, pool
        self.reference = reference
        self.progress = progress
        self.total = sum(p is not None for p in prepared)
        self.tried: Dict[tuple, int] = {}       # (grid, group key) -> union version of the last descriptor match
        self.blind: Dict[tuple, frozenset] = {}  # (grid, group key) -> members when its last match found no candidate
        self.agreeing: Dict[tuple, bool] = {}   # (grid, grid) -> whether their descriptors agree on a rigid model
        self.memory = memory if memory is not None else EstimationMemory()   # one estimation's own, offline
        self.names = list(names) if names is not None else list(range(len(prepared)))
        self.refused: Dict[int, PairMatch] = {}  # grid -> its last refused match
        self.refused_onto: Dict[tuple, PairMatch] = {}   # (grid, group seed) -> its last refused match onto it
        self.refused_seen: Dict[tuple, frozenset] = {}    # (grid, group seed) -> the members that match saw
        # (grid, group seed) -> the places (metric, in the group's frame) of its matches onto the group refused as
        # ambiguous: the best and the other places found (still_ambiguous)
        self.rivals: Dict[tuple, List[np.ndarray]] = {}
        self.contradicting: set = set()          # grids that overlap a group's union but contradict it
        # grid -> members of the unions a refused match found it overlaps (overlap_found, by the rule for pairs when
        # the group was one grid: the rule for unions on a pair's refusal kept a robot from the search that placed it)
        self.found: Dict[int, List[frozenset]] = {}
        self.settled = 0
        self.searched: set = set()   # grids a correlation search placed (confirm_searches)
        # grids that joined a group of FEW_MEMBERS or fewer by their own match: judged against those alone
        self.placed_onto_few: set = set()
        # (grid, group key) of the searches that failed in this estimation: searched again only by search_again
        self.failed_searches: set = set()
        self.again = False
        # each join of a round judged again on the union grown by the joins before it (estimator._consistent_of)
        self.strict = False
        # grid -> (round, place in it, group key) of its join by a round of matches onto a union (_admit), while it
        # stays
        self.admitted: Dict[int, Tuple[int, int, int]] = {}
        self.rounds = 0
        self.search_seconds = 0.0   # spent in correlation searches (settings.search_budget_s)
        self.budget = budget if budget is not None else SearchBudget()
        self.judged: Dict[tuple, Placement] = {}   # eviction.judge_members' verifications in this estimation
        self.evicted: set = set()    # grids taken out of the merge (evict_contradicted): they stay out of it
        self.postponed = 0          # searches the budget left to a later estimation
        self.group_matches: Dict[tuple, tuple] = {}   # (id, id) of two groups -> (them, their state, last match)
        # the batches of matches run in parallel (workers.py); its descriptor distances serve this estimation's
        # other matches too (neighbours.py)
        self.matcher = matcher if matcher is not None else ParallelMatcher(settings, pool)
        self.neighbours = self.matcher.neighbours
        self.pair_evidence = PairEvidence(prepared, self.matcher)   # stronger.py
        # search_left_out's: where its last search placed each grid (None: nowhere, or on less than min_overlap_m2),
        # the members taken out and the members' footprints as of its last call
        self.left_out_boxes: Dict[int, Optional[Box]] = {}
        self.left_out_saw: Dict[int, frozenset] = {}   # the members of the merge at each grid's last search there
        self.left_out_accepted: set = set()          # those it placed by the rules of a pair, short of joining
        self.left_out_matches: Dict[int, PairMatch] = {}   # and how
        # the places of those it placed by every rule of a pair but precision (side_groups.py: where the union of
        # their group may be placed, judged there by the rules, precision included, with all its walls)
        self.left_out_imprecise: Dict[int, PairMatch] = {}
        self.left_out_joined: Dict[int, tuple] = {}   # those that joined: (members agreeing, support) then
        self.left_out_members: frozenset = frozenset()
        self.left_out_evicted: set = set()
        self.left_out_footprints: Dict[int, Box] = {}
        self.side_groups: List[Dict[int, np.ndarray]] = []   # groups taken apart (side_groups.py)
        self.split_off: set = set()   # grids a group let go when it fell apart after a member left (split.py)

    def keypoints_of(self, k: int, part: PreparedGrid) -> tuple:
        """Grid k's keypoints (its map frame) and descriptors, kept from an earlier estimation while its map has
        barely changed: a union needs them for its pooled keypoints, and detection is the costly part."""
        name = self.names[k]
        kept = self.memory.keypoints.get(name)
        if kept is not None and self.memory.unchanged(kept[0], self.grids[k]):
            return kept[1], kept[2]
        points, descriptors = map_keypoints(part)
        self.memory.keypoints.put(name, (self.grids[k], points, descriptors))
        return points, descriptors

    def group(self, seed: int, settle: bool = True) -> Group:
        """A new group of the seed alone (the seed counts as settled unless it was already)."""
        if settle:
            self.settle(1)
        return Group(seed, self.grids[seed], self.prepared[seed], self.res, self.keypoints_of)

    def group_of(self, seed: int, placed: Dict[int, np.ndarray]) -> Group:
        """A new group of the grids `placed` (grid -> metric transform, one frame; the seed among them), placed
        relative to each other as given, in the seed's frame (not counted as settled)."""
        group = self.group(seed, settle=False)
        to_seed = tf.inverse(placed[seed])
        for k, t in placed.items():
            if k != seed:
                group.union.add(k, self.grids[k], self.prepared[k], to_seed @ t)
        return group

    def tracked_group(self, reference: int, kept: Dict[int, np.ndarray], checks: Sequence) -> Group:
        """The group of the placements tracking kept (grid -> transform in the reference's frame), each linked by
        its check's match."""
        group = self.group(reference)
        by_grid = {c.k: c for c in checks}
        parents = tree_of_overlaps(reference, {k: footprint(self.grids[k], t) for k, t in kept.items()})
        for k, t in kept.items():
            if k != reference:
                group.union.add(k, self.grids[k], self.prepared[k], t)
                match, j = by_grid[k].match, parents.get(k)
                if j is not None and j != match.j:
                    # each check names the grid it overlaps most, and two grids can name each other: the links
                    # (the status's used pairs) name a grid nearer the reference, so that they connect every one
                    match = dataclasses.replace(match, j=j, transform_m=tf.inverse(kept[j]) @ t)
                group.links[k] = match
        self.settle(len(group.members) - 1)
        return group

    def match(self, group: Group, grids: Sequence[int], search: bool) -> List[PairMatch]:
        """The grids onto the group's union (a group of one: as a pair), in parallel: by descriptors, or (search) by
        the correlation search alone."""
        union = group.union.prepared()
        return self.matcher.match_all([MatchCall(k, group.seed, self.prepared[k], union,
                                                 dict(onto_union=len(group.members) > 1, search=search,
                                                      descriptors=not search)) for k in grids])

    def grow(self, group: Group, unplaced: List[int], search: bool = True, probe: bool = False) -> bool:
        """Add to the group every grid of `unplaced` (removed from it) that can be placed against its union (with
        search=False, by descriptors alone).

        With `probe` (a new seed), the first SEED_PROBE grids of `unplaced` are matched first; when none of them
        joins and SEED_CONTRADICTED of them overlap the seed but partly contradict it (partly_agreeing), the seed
        is likely a map broken by a SLAM failure: nothing joins, the other grids are not matched, and it returns
        True. Otherwise all are judged together, as without the probe. Returns False."""
        while unplaced:
            batch = [k for k in unplaced if self._worth_matching(k, group)]
            if batch:
                known = group.union.known_pixels   # prepares the union once, before the workers share it
                members = frozenset(self.names[m] for m in group.members)
                probing, probe = probe and len(batch) > SEED_PROBE, False
                results = self._match_tried(group, batch[:SEED_PROBE] if probing else batch)
                if probing:
                    if self._contradicted_seed(results):
                        self._take(group, results, members, known, unplaced)   # none joins: refusals noted
                        return True
                    results += self._match_tried(group, batch[SEED_PROBE:])
                if self._take(group, results, members, known, unplaced):
                    continue
            if not search or not self._search(group, unplaced):
                return False
        return False

    def _match_tried(self, group: Group, grids: List[int]) -> List[PairMatch]:
        """The grids matched onto the group's union by descriptors, noted as tried against this version of it."""
        for k in grids:
            self.tried[(k, group.key)] = group.union.version
        results = self.match(group, grids, search=False)
        if len(group.members) == 1:
            for m in results:
                self.pair_evidence.put(m)   # the same call as the pair evidence's (stronger.py)
        return results

    def _take(self, group: Group, results: List[PairMatch], members: frozenset, known: int,
              unplaced: List[int]) -> bool:
        """The results of a batch onto the group noted; those accepted join it (removed from `unplaced`). Whether any
        joined."""
        for m in results:
            if m.best is None:
                self.blind[(m.i, group.key)] = frozenset(group.members)
            else:
                self.blind.pop((m.i, group.key), None)
        added = self._admit(group, unplaced, results)
        for m in results:
            if not m.accepted:
                self.memory.tries.put((self.names[m.i], members),
                                      (self.grids[m.i], known, m.i in self.contradicting,
                                       overlap_found(m.best, self.s, len(group.members) > 1)))
        return added

    def _contradicted_seed(self, results: List[PairMatch]) -> bool:
        """Whether a new seed's probe (grow) says that it contradicts the grids that overlap it."""
        return not any(m.accepted for m in results) \
            and sum(partly_agreeing(m.best, self.s) for m in results) >= SEED_CONTRADICTED

    def outcast(self, k: int, merge: Optional[Group]) -> bool:
        """Whether grid k seeds no group: once `merge` holds most grids, a grid that overlaps a group but contradicts
        it (a map broken by a SLAM failure) would only pair with the part it shares with another map."""
        return merge is not None and 2 * len(merge.members) > self.total and k in self.contradicting

    def _worth_matching(self, k: int, group: Group) -> bool:
        """Whether grid k is to be matched against the group's union (again): not if it was matched against this
        union already, nor if its last match found where it overlaps the union (and contradicts it) and the union
        has not changed there since (the same descriptors against the same walls give the same verdict)."""
        tried = self.tried.get((k, group.key))
        if tried is None:
            last = self.memory.tries.get((self.names[k], frozenset(self.names[m] for m in group.members)))
            # matched in an earlier estimation against these members: again once either has changed enough
            if last is None or not self.memory.unchanged(last[0], self.grids[k]) \
                    or group.union.known_pixels > MATCH_GROWTH * last[1]:
                return True
            if last[2]:
                self.contradicting.add(k)
            if last[3]:
                # it found where the grid overlaps the union and contradicts it: a search would find the same (_search);
                # without this, a map broken by a SLAM failure was searched in the estimation after each such match
                self.found.setdefault(k, []).append(frozenset(group.members))
            return False
        if tried == group.union.version:
            return False
        blind = self.blind.get((k, group.key))
        if blind is not None:
            # its descriptors found no candidate at all on the union: only new members' keypoints can make one, and
            # a candidate needs some of them to agree on a rigid model with its own
            return any(self._descriptors_agree(k, m) for m in group.members if m not in blind)
        last = self.refused.get(k)
        if last is None or last.j != group.seed or not overlap_found(last.best, self.s, len(group.members) > 1):
            return True
        return group.union.changed_under(self.prepared[k], last.best.transform, since=tried)

    def _descriptors_agree(self, k: int, m: int) -> bool:
        """Whether the putative descriptor matches of grid k with grid m hold a rigid model with enough inliers."""
        if (k, m) not in self.agreeing:
            pk, pm = self.prepared[k], self.prepared[m]
            pairs = putative_matches(pk, pm, self.s.ratio, False, self.neighbours)
            agree = False
            if len(pairs) >= self.s.min_inliers:
                rng = np.random.default_rng((self.s.seed, pk.draw_key, pm.draw_key))
                model, mask = ransac_rigid(pk.keypoints[pairs[:, 0]], pm.keypoints[pairs[:, 1]],
                                           self.s.ransac_threshold, self.s.ransac_iterations, rng)
                agree = model is not None and int(mask.sum()) >= self.s.min_inliers
            self.agreeing[(k, m)] = agree
        return self.agreeing[(k, m)]

    def _admit(self, group: Group, unplaced: List[int], results: List[PairMatch]) -> bool:
        added = False
        matched_onto = set(group.members)   # however many of the grids join it now
        self.rounds += 1
        place = 0
        for m in sorted(results, key=lambda m: -m.weight):
            if m.accepted and (self._waits(m, matched_onto) or self._searched_onto_little(m, group)):
                continue
            if m.accepted and added and self.strict:
                # made onto the union as it stood before the round: judged again on the union the joins before it
                # grew (a map at an alias can agree wall for wall with the one and be contradicted by the other)
                again = self._placed_again(m, group.union.prepared())
                if again is None:
                    self._wait(m, 'waits: the maps that joined before it in this round contradict it there')
                    continue
                m = again
            if m.accepted:
                self._join(group, m)
                self.admitted[m.i] = (self.rounds, place, group.key)
                place += 1
                unplaced.remove(m.i)
                added = True
            else:
                self.refused[m.i] = m
                self._refused_onto(m, frozenset(matched_onto))
                if overlap_found(m.best, self.s, len(group.members) > 1):
                    self.found.setdefault(m.i, []).append(frozenset(group.members))
                if len(group.members) > 1 and m.best is not None and m.best.support >= self.s.min_support \
                        and m.best.overlap_m2 >= self.s.min_overlap_m2:
                    self.contradicting.add(m.i)
        return added

    def _waits(self, m: PairMatch, members: Set[int]) -> bool:
        """Whether the accepted match m of a single grid onto the grids `members` waits for a stronger pair with a
        grid outside them (stronger.py): matched as a pair against every grid when `members` are few
        (FEW_MEMBERS: two maps alone are the weakest evidence, a union of a few little more), onto a larger union
        among the pairs matched already (it is judged on all its members' walls, and weak matches onto large unions
        are common where walls are irregular). Then it counts as refused, but not as evidence that the grid
        contradicts the group."""
        outside = (x for x in range(len(self.prepared)) if x not in members)
        why = stronger_elsewhere(m, self.pair_evidence, outside, self.s, skip=lambda x: x in self.evicted,
                                 compute=len(members) <= FEW_MEMBERS)
        if why is None:
            return False
        self._wait(m, why)
        return True

    def _searched_onto_little(self, m: PairMatch, group: Group) -> bool:
        """Whether the accepted match m of a single grid onto the group's union, which a correlation search found (its
        descriptors found no plausible place), waits: it shares less than LEFT_OUT_SHARE of the grid's known area and
        the members it lands on, each verified in its own pixels (eviction.members_agreement), agree with it less
        than wall for wall there (WEAK_AGREEMENT). Then it counts as refused, as a match that waits for a stronger
        pair does.

        Such a match is the weakest evidence a grid joins by: a small part of it fitting a union somewhere. Held-out
        maze36_u: broken map_03 placed so onto a merge of 10, 63 degrees off both its parts (22.7 m2, 0.19 of its
        area, agreement 0.982; 0.986 with the members); the 32 maps searched so and placed right in the 39 generated
        buildings (either order) agreed 0.994-1.000 with the union, and every such placement of the dev set 1.000.

        The members one by one, not the union: the union is the members resampled into the frame of the seed the
        growth started from, and at 0.99 that resampling decides, either way. classic36 seeded by map_20: map_21,
        placed 0.15 m from the truth on 0.04 of its area, agreed 0.970 with the union in map_20's frame and 0.995
        with the three members it overlaps. Held-out maze36_v with the random draws seeded by the maps' contents:
        map_31, searched onto map_23's union half a turn and 37 m off the truth, agreed 0.991
        with it there (28.7 m2) and 0.936 with the members one by one (at the truth 1.000); it joined, a false merge."""
        if not m.searched or self.shares_enough(m.i, m.best.overlap_m2):
            return False
        pooled = self._members_agreement(m.i, m.transform_m, group)
        if pooled >= WEAK_AGREEMENT:
            return False
        self._wait(m, f'waits: a search placed it on {self.share_of(m.i, m.best.overlap_m2):.2f} of its area, '
                      f'the members there agreeing {pooled:.3f} ({m.best.agreement:.3f} with their union) < '
                      f'{WEAK_AGREEMENT:.2f}')
        return True

    def _members_agreement(self, k: int, place: np.ndarray, group: Group) -> float:
        """The agreement of grid k placed at `place` (metric, the group's frame) with the group's members it lands on,
        each verified in its own pixels (eviction.members_agreement, with this estimation's verifications)."""
        return members_agreement(k, place, group.members, group.union.footprints, footprint(self.grids[k], place),
                                 self.prepared, self.s, self.judged)

    def _wait(self, m: PairMatch, why: str) -> None:
        """The accepted match m counts as refused for `why` (not as evidence that the grid contradicts the group)."""
        log.debug('grid %d onto group %d %s', m.i, m.j, why)
        self.refused[m.i] = dataclasses.replace(m, accepted=False, reason=why)

    def _forget_search(self, k: int, group: Group) -> None:
        """Grid k is placed in the group: a search of it against the group that memory keeps (made before it was
        placed, or the one that placed it) would otherwise, once tracking drops its placement, keep it from being
        searched again until a map grows (a live demo: a robot left out for 21 sim s)."""
        self.memory.searches.drop((self.names[k], self.names[group.seed]))

    def _search(self, group: Group, unplaced: List[int]) -> bool:
        """The correlation search, smallest grid first, on grids the union has grown for since their last search;
        stops at the first grid it places (the others are matched against the grown union first). The searches are
        made `threads` at a time, in parallel: most fail, and those made beside one that places its grid are made
        again against the grown union."""
        known = group.union.known_pixels
        members = frozenset(self.names[m] for m in group.members)
        todo = []
        for k in sorted(unplaced, key=lambda k: self.prepared[k].known_pixels):
            failed = (k, group.key) in self.failed_searches
            if failed and not self.again:
                continue   # again once the group has grown as far as it can otherwise (search_again)
            if self._searched_since(k, group, members):
                continue   # searched before (maybe in an earlier estimation), and neither has changed much since
            if not failed and any(members <= group.members.keys() for members in self.found.get(k, ())):
                # a refused match found where it overlaps some of the members and the maps disagree there (a search
                # finds the same), even when a later match onto the grown union found no candidate (the new members'
                # descriptors crowd the ratio test: 2 of the 36 generated maps were searched in vain); not a grid
                # searched against a smaller union before: descriptors can find a wrong place on a large union of
                # a repetitive building (a generated one: a map the search placed onto 12 members, whose matches
                # onto 25 contradicted)
                continue
            todo.append(k)
        for start in range(0, len(todo), self.s.threads):
            if self._spent():
                # these grids are searched in a later estimation (their memory is not updated)
                self.postponed += 1
                return False
            started = time.perf_counter()
            chunk = todo[start:start + self.s.threads]
            matches = self.match(group, chunk, search=True)
            self.search_seconds += time.perf_counter() - started
            for k, m in zip(chunk, matches):
                self.memory.searches.put((self.names[k], self.names[group.seed]), (self.grids[k], known, members))
                if self._admit(group, unplaced, [m]):
                    self.searched.add(k)
                    return True
                self.failed_searches.add((k, group.key))
        return False

    def _searched_since(self, k: int, group: Group, members: FrozenSet[Hashable]) -> Optional[bool]:
        """Whether grid k was searched onto the union of `group` (by the growth, _search) and neither has changed
        much since: the grid the same, no member (`members`, by name) gone, the union grown by less than
        SEARCH_GROWTH. None: never searched onto it."""
        last = self.memory.searches.get((self.names[k], self.names[group.seed]))
        if last is None:
            return None
        return self.memory.unchanged(last[0], self.grids[k]) and members >= last[2] \
            and group.union.known_pixels < SEARCH_GROWTH * last[1]

    def search_again(self, group: Group, unplaced: List[int]) -> None:
        """Grow the group with the grids whose search against it failed in this estimation too (once it has grown
        enough since, SEARCH_GROWTH). Until then they wait: as the groups merged, the broken maps of a generated
        36-map building were searched in vain against each larger union in turn (36 searches, now 18)."""
        self.again = True
        try:
            self.grow(group, unplaced)
        finally:
            self.again = False

    def confirm_searches(self, group: Group) -> None:
        """Judge the grids a search placed again, as they are, against the other members near them (tracking's
        check without its refinement): a search takes the best place on the union as it was then, and the members
        that joined since can show that it slid along a corridor (36 generated maps: one map placed 0.34 m off onto
        a union of 16, which the final union of 25 contradicts, agreement 0.89). One that fails, for a reason other
        than precision alone, leaves the group: the one that agrees least first, then those that failed are judged
        again without it, as tracking does."""
        todo = [k for k in group.members if k in self.searched and k not in (group.seed, self.reference)]
        for _ in range(MAX_PASSES):
            if not todo:
                return
            failed = self.contradicted(group, todo, 'the merge contradicts the placement a search found')
            if not failed:
                return
            worst = least_agreeing(failed)
            group.leave(worst.k)
            self.refused[worst.k] = worst.match
            # searched against this union: again once it has grown (SEARCH_GROWTH), not in every estimation
            self.memory.searches.put((self.names[worst.k], self.names[group.seed]),
                                     (self.grids[worst.k], group.union.known_pixels,
                                      frozenset(self.names[m] for m in group.members)))
            todo = [c.k for c in failed if c is not worst]

    def contradicted(self, group: Group, todo: Sequence[int], failing: str = 'the merge contradicts it') -> List[Check]:
        """The checks of the members `todo` of `group` that the other members near them contradict as they are
        placed: tracking's check without its refinement, failing (its reason starting with `failing`) for more than
        precision alone. Not for precision alone: the members near a map can be too few to show the wall direction
        that made its placement precise on the whole union (orientation.angle_bound; demo_late_group's robot_5,
        placed by a search: 0.11 m there, 0.28-0.30 m here, left out for good on static maps); a slide shows as
        walls that disagree."""
        placed, footprints = dict(group.members), dict(group.union.footprints)
        checks = self.pool.map(lambda k: recheck(k, self.grids, self.prepared, placed, footprints, self.res, self.s,
                                                 refine=False, failing=failing), todo)
        return [c for c in checks if c.transform is None and not c.imprecise]

    def evict_contradicted(self, group: Group, groups: List[Group], unplaced: List[int],
                           make_room: bool = False) -> bool:
        """Take out of the merge (`group`, one of `groups`) a member that the maps outside it contradict while they
        agree with the other members (eviction.py: a broken map placed by one of its parts, or a map accepted at
        the edge of the rules), then grow it again with the grids in no group (`unplaced`) and match the other
        groups onto it. The member taken out stays out of this estimation. Whether one was taken out (the merge may
        then be another object of `groups`: merge_groups keeps the preferred reference's group). With `make_room`,
        only a member without which a map that singled it out would join (_makes_room).

        Where no member is singled out, the members that maps left out contradict together (eviction.
        singled_out_together: broken maps that hold together in the merge) are taken out together, but only where a
        map that named them would then join (_makes_room), with or without `make_room`: a map left out that joins
        nowhere proves nothing against several members."""
        evicted = False
        for _ in range(MAX_PASSES):
            outside = [k for k, p in enumerate(self.prepared) if p is not None and k not in group.members]
            onto = {k: self.refused_onto[(k, group.seed)] for k in outside if (k, group.seed) in self.refused_onto}
            seen = {k: self.refused_seen.get((k, group.seed), frozenset()) for k in onto}
            voters: Dict[int, list] = {}
            together: Dict[frozenset, list] = {}
            singled = contradicted_members(outside, onto, group.members, group.union.footprints,
                                           lambda k, t: footprint(self.grids[k], t), self.prepared,
                                           (self.reference,), self.s, seen, voters, self.judged, own=True,
                                           together=together)
            singled = [j for j in singled if self._may_leave(group, j, voters[j], make_room)]
            if singled:
                self._evict(group, singled[0], 'maps the other members agree with contradict it')
            else:
                # members that hold together: taken out together, only where a map that named them would join then
                named = next((js for js in singled_out_together(together)
                              if self._makes_room(group, js, together[js])), None)
                if named is None:
                    break
                for j in sorted(named):
                    self._evict(group, j, f'maps the other members agree with contradict it and members '
                                          f'{sorted(named - {j})}')
            evicted = True
            # the halves a broken seed placed by its two parts hold together no more (split.py)
            groups.extend(split(self, group))
            # the maps outside matched again one by one (those of other groups too: the member taken out may have
            # been what their group contradicted), then what is left of the other groups as groups
            again = [k for k in outside if k not in self.evicted and k not in group.members]
            self.grow(group, again, search=False)
            for other in [g for g in groups if g is not group]:
                joined = [k for k in other.members if k in group.members]
                if other.seed in group.members:
                    groups.remove(other)
                    unplaced.extend(k for k in other.members if k not in group.members)
                else:
                    for k in joined:
                        other.leave(k)
            unplaced[:] = [k for k in unplaced if k not in group.members]
            # the grids alone were just matched onto the merge: they join the groups as these grow (merge_groups
            # grows each merged group with them), not each matched onto every other group with a search (a
            # generated hospital: 5 grids matched so onto one side group after each grid it took, 4 s)
            alone = [g for g in groups if g is not group and len(g.members) == 1]
            groups[:] = [g for g in groups if g not in alone]
            unplaced.extend(g.seed for g in alone)
            self.merge_groups(groups, unplaced)
            placed = {k for g in groups for k in g.members}
            groups.extend(g for g in alone if g.seed not in placed)
            unplaced[:] = [k for k in unplaced if k not in placed]
            group = max(groups, key=lambda g: (len(g.members), self.reference in g.members))
        return evicted

    def _refused_onto(self, m: PairMatch, seen: frozenset) -> None:
        """Keep m as the refusal of grid m.i onto the group seeded by m.j (for evict_contradicted's votes), made
        against the members `seen`; unless m found no place and the refusal kept did: a match onto the grown union
        can find nothing at all where the earlier one found the true place, contradicted by a broken member (the
        held-out cave36_v: three maps kept out by broken map_01, whose matches onto it agreed 0.60-0.83 over
        49-84 m2, and whose later matches found no rigid model)."""
        if m.reason.startswith(AMBIGUOUS) and m.transform_m is not None:
            self.rivals.setdefault((m.i, m.j), []).extend([m.transform_m] + list(m.other_places_m))
        kept = self.refused_onto.get((m.i, m.j))
        if kept is not None and places(kept, self.s) and not places(m, self.s):
            return
        self.refused_onto[(m.i, m.j)] = m
        self.refused_seen[(m.i, m.j)] = seen

    def restate_refused(self, old_seed: int, new_seed: int, old_to_new: np.ndarray) -> None:
        """The matches refused onto a group whose frame becomes another's (the group is absorbed, or reseeded),
        restated in the new frame: where they placed a grid left out still says what its members think of it."""
        for (k, j), found in list(self.rivals.items()):
            if j == old_seed:
                del self.rivals[(k, j)]
                self.rivals.setdefault((k, new_seed), []).extend(old_to_new @ t for t in found)
        for (k, j), m in list(self.refused_onto.items()):
            if j == old_seed:
                del self.refused_onto[(k, j)]
                seen = self.refused_seen.pop((k, j), frozenset())
                kept = self.refused_onto.get((k, new_seed))
                if m.transform_m is not None and (kept is None or places(m, self.s) and not places(kept, self.s)):
                    self.refused_onto[(k, new_seed)] = dataclasses.replace(
                        m, j=new_seed, transform_m=old_to_new @ m.transform_m,
                        other_places_m=[old_to_new @ t for t in m.other_places_m])
                    self.refused_seen[(k, new_seed)] = seen

    def merge_groups(self, groups: List[Group], unplaced: List[int]) -> List[Group]:
        """Match groups against each other (the smaller union onto the larger) until no two merge; a merged group
        grows again with the grids still unplaced (by descriptors alone while another group is larger)."""
        changed = True
        while changed and len(groups) > 1:
            changed = False
            groups.sort(key=lambda g: -len(g.members))

            def matched(small: Group, big: Group) -> bool:
                # a single grid matched against this union already
                return len(small.members) == 1 and self.tried.get((small.seed, big.key)) == big.union.version

            def upcoming(a: int, b: int) -> Iterator[Tuple[Group, Group]]:
                # the pairs (small, big) this loop matches from (groups[b], groups[a]) on while none joins, in order
                for a2 in range(a, len(groups)):
                    for b2 in range(b if a2 == a else a2 + 1, len(groups)):
                        if not matched(groups[b2], groups[a2]):
                            yield groups[b2], groups[a2]

            for a in range(len(groups)):
                big = groups[a]
                for b in range(a + 1, len(groups)):
                    small = groups[b]
                    if matched(small, big):
                        continue
                    self._match_ahead(upcoming(a, b))
                    m = self._match_groups(small, big)
                    if m.imprecise_only and self.joins_where_met(small, big, m.transform_m):
                        m = dataclasses.replace(m, accepted=True, reason='')
                    if m.accepted and not (len(small.members) == 1 and self._waits(m, set(big.members))):
                        # the merged frame stays that of the preferred reference's group
                        if self.reference in small.members:
                            self.restate_refused(big.seed, small.seed, tf.inverse(m.transform_m))
                            small.absorb(big, tf.inverse(m.transform_m), m)
                            groups[a] = small
                        else:
                            self.restate_refused(small.seed, big.seed, m.transform_m)
                            big.absorb(small, m.transform_m, m)
                        for k in groups[a].members:
                            self._forget_search(k, groups[a])
                        groups.pop(b)
                        # the searches only for the largest group: one that stays smaller searched every broken map
                        # in vain (a generated 36-map scenario: 8 of its 49 searches), and search_grow grows the
                        # largest group of those merge_groups returns anyway
                        largest = all(len(g.members) <= len(groups[a].members) for g in groups)
                        self.grow(groups[a], unplaced, search=largest)
                        changed = True
                        break
                    if not m.accepted and self.evict_at_join(small, big, m):
                        changed = True   # the two are matched again without the member taken out
                        break
                if changed:
                    break
        return groups

    def joins_where_met(self, small: Group, big: Group, small_to_big: np.ndarray) -> bool:
        """Whether a member of either group, the groups placed together by small_to_big (metric), passes there alone
        the rules of a pair onto the union of the other group (precision at its own corners; not refined alone: ICP
        of a map onto a small common area slides it off): then a match of the two unions that only imprecision
        refused joins them.

        The precision of a union's placement is judged at the union's far corners, and a larger group, joined by the
        same few shared walls, reaches farther. In classic36 seeded by map 5, the union of 14 maps was refused onto
        the merge of 15 (0.66 m expected at its far corners) while map 21, one of the 14, passed alone there (0.21 m);
        seeded by the largest map, map 21 joined the merge alone and the other 11 joined onto it. Had the merge been
        seeded by a member of the other group, the same would hold the other way round. So what joins does not
        depend on which group formed first: the members beyond the meeting place join by their matches within their
        group, as they would onto the member that met the other.

        Not for a group of one map: its own match judged its precision at its corners already, and a map placed onto
        a single one is a pair, whose precision counts at the corners of both (the rule onto a union, here, counts
        the moving map's alone)."""
        if len(small.members) < 2 or len(big.members) < 2:
            return False
        for group, other, to_other in ((small, big, small_to_big), (big, small, tf.inverse(small_to_big))):
            found = self.member_passing(group.members, other.union, to_other)
            if found is not None:
                k, c = found
                log.debug('groups %d and %d: member %d passes alone onto group %d where they meet (agreement '
                          '%.3f, overlap %.1f m2, %.2f m expected at its far corners)', small.seed, big.seed, k,
                          other.seed, c.agreement, c.overlap_m2, c.corner_error_m)
                return True
        return False

    def member_passing(self, members: Dict[int, np.ndarray], union: UnionMap, to_union: np.ndarray
                       ) -> Optional[Tuple[int, Placement]]:
        """(member, its verification) of the first of `members` (grid -> metric transform into their frame) that,
        placed by to_union (metric: their frame -> the union's), overlaps the footprints of the union's members and
        passes there alone the rules of a pair onto the union (passes_onto); None if none does. The union is
        prepared only for a member that overlaps it."""
        boxes = list(union.footprints.values())
        for k, t in members.items():
            if not any(overlap_area(footprint(self.grids[k], to_union @ t), b) > 0.0 for b in boxes):
                continue
            prepared = union.prepared()
            if prepared is None:
                return None
            c = self.passes_onto(self.prepared[k], prepared, to_union @ t)
            if c is not None:
                return k, c
        return None

    def evict_at_join(self, small: Group, big: Group, m: PairMatch) -> bool:
        """Take out of the two groups the members that the other group's members, placed where the refused match m of
        the two unions found them, single out (eviction.py's rule, the other group's members standing for the maps
        left out), if the unions of the others pass the rules there. Whether members were taken out (merge_groups
        then matches the two groups again).

        A map broken by a SLAM failure, placed in its group by one of its parts, contradicts the other group where its
        other part lies, and the two unions refuse each other for it: on the generated 36-map buildings (seeds 0-2)
        38 refused group matches (repeats counted) were at the true place, each refused for one to three broken
        members. A group that holds a broken map itself (its members placed through both of its parts) can single
        out right members of the other; without the check of the unions, pillar_hall36 lost 3 and 4 right maps so
        (seeds 0 and 1), and with it no right map was taken out.

        A member that joined its group by a match with at least the support of the place where the two groups meet
        is not taken out for it (`_outweighs_join`): the place is the weaker evidence. Held-out maze36_u in reverse
        order: a map alone met a group of 10 at an alias a quarter turn off (18 m2, support 471) and singled out a
        right member joined by 3473 agreeing walls; taken out, the alias joined and both were off. In the 39
        generated buildings, either order, the 14 broken members taken out at joins that had joined by a match did
        so by 202-1667 walls, against places of 1511-5145 (the other 9 seeded their groups)."""
        best = m.best
        if not self.s.evict or best is None or m.transform_m is None or plausible(best, self.s) \
                or best.support < self.s.min_support or best.overlap_m2 < self.s.min_overlap_m2:
            return False   # only a refusal for agreement or contradictions: the maps overlap there
        sides = [(small, big, tf.inverse(m.transform_m)), (big, small, m.transform_m)]
        members = {id(g): dict(g.members) for g in (small, big)}
        singled: List[tuple] = []
        for _ in range(JOIN_EVICTIONS):
            for group, other, to_group in sides:
                placed = {k: dataclasses.replace(m, transform_m=to_group @ t, other_places_m=[])
                          for k, t in members[id(other)].items()}
                found = contradicted_members(list(placed), placed, members[id(group)], group.union.footprints,
                                             lambda k, t: footprint(self.grids[k], t), self.prepared,
                                             (self.reference,), self.s, verified=self.judged)
                found = [j for j in found if not self._outweighs_join(group, j, best)]
                if found:
                    singled.append((group, found[0], other.seed))
                    del members[id(group)][found[0]]
                    break
            else:
                break
        if not singled or not self._agree_without(small, big, members, m.transform_m):
            return False
        for group, j, by in singled:
            self._evict(group, j, f'the maps of group {by} agree with the other members and contradict it')
        return True

    @staticmethod
    def _outweighs_join(group: Group, j: int, place: Placement) -> bool:
        """Whether member j joined the group by a match with at least the support of `place` (a refused match of two
        unions): then it stays, whatever maps of the other group placed there say (a seed joined by none does not)."""
        link = group.links.get(j)
        return link is not None and link.best is not None and link.best.support >= place.support

    def _may_leave(self, group: Group, j: int, voters: List[tuple], make_room: bool) -> bool:
        """Whether member j, singled out by the maps `voters` (_makes_room), leaves on their word: with `make_room`
        only where one of them would then join; without, also where the group holds together without it. A member
        the group falls apart without (split.py) takes the other parts out with it, and leaves only where a map that
        singled it out would then join: in the held-out maze36_w, map_35, at an alias 20 m from its true place, agreed
        with three members and contradicted map_30, the one member that held four others to the merge; map_35 joined
        nowhere, and 5 maps stayed out with map_30."""
        if not make_room and len(parts_of(self, group, {j})) < 2:
            return True
        return self._makes_room(group, {j}, voters)

    def _makes_room(self, group: Group, out: Set[int], voters: List[tuple]) -> bool:
        """Whether a map that singled out the members `out` (voters: (grid, where it voted from, metric in the group's
        frame)) would join the group's union without them there, by search_left_out's rules: the pair rules and
        LEFT_OUT_SHARE of its known area in common."""
        union = self.union_of(group, {k: t for k, t in group.members.items() if k not in out})
        if union is None:
            return False
        for k, place in voters:
            c = self.passes_onto(self.prepared[k], union, place)
            if c is not None and self.shares_enough(k, c.overlap_m2):
                return True
        return False

    def _agree_without(self, small: Group, big: Group, members: Dict[int, Dict[int, np.ndarray]],
                       small_to_big: np.ndarray) -> bool:
        """Whether the unions of the two groups' `members` (group id -> the members kept) pass the acceptance rules
        at the placement small_to_big (metric: the small group's frame -> the big one's)."""
        unions = [self.union_of(g, members[id(g)]) for g in (small, big)]
        if unions[0] is None or unions[1] is None:
            return False
        return self.passes_onto(unions[0], unions[1], small_to_big) is not None

    def union_of(self, group: Group, placed: Dict[int, np.ndarray]) -> Optional[PreparedGrid]:
        """The prepared union of some of the group's members (member -> metric transform into its frame)."""
        return self.union_map_of(group, placed).prepared()

    def union_map_of(self, group: Group, placed: Dict[int, np.ndarray]) -> UnionMap:
        """The union of some of the group's members (member -> metric transform into its frame)."""
        union = UnionMap(self.res, group.union.keypoints_of)
        for k, t in placed.items():
            union.add(k, group.union.grids[k], group.union.parts[k], t)
        return union

    def passes_onto(self, part: PreparedGrid, union: PreparedGrid, to_union: np.ndarray) -> Optional[Placement]:
        """The verification of `part` placed onto `union` by `to_union` (metric: its frame -> the union's), if it
        passes the rules of a pair onto a union; else None."""
        c = verify(part, union, tf.inverse(union.px_to_map) @ to_union @ part.px_to_map, self.s)
        return c if plausible(c, self.s) and not refusal(c, part, union, self.s, onto_union=True) else None

    def share_of(self, k: int, overlap_m2: float) -> float:
        """The share of grid k's known area that `overlap_m2` is."""
        pk = self.prepared[k]
        return overlap_m2 / (pk.known_pixels * pk.resolution ** 2)

    def shares_enough(self, k: int, overlap_m2: float) -> bool:
        """Whether a placement of grid k sharing `overlap_m2` with the merge shares LEFT_OUT_SHARE of its known area."""
        return self.share_of(k, overlap_m2) >= LEFT_OUT_SHARE

    def _left_out_todo(self, group: Group, refused: bool = False) -> List[int]:
        """The grids search_left_out searches onto the merge `group`: see there."""
        gone = self.evicted - self.left_out_evicted   # members taken out since the last searches
        changed = frozenset(group.members) != self.left_out_members
        names = frozenset(self.names[m] for m in group.members)
        todo = []
        for k, p in enumerate(self.prepared):
            if p is None or k in group.members or k in self.evicted:
                continue
            found = self.found.get(k, ())
            box = self.left_out_boxes.get(k, False)
            # a search that found no place at all (None) could have been kept out by any member that left
            saw_gone = any(members & gone for members in found) \
                or (box is None and bool(gone)) \
                or (box is not False and any(overlap_area(box, self.left_out_footprints.get(j)) > 0.0 for j in gone))
            if not saw_gone and not any(members - self.evicted <= group.members.keys() for members in found) \
                    and self._searched_since(k, group, names) is not False:
                # no match found where it overlaps the merge: the growth searched it (_search), unless the merge
                # has changed much since its last search there (a member gone, grown by SEARCH_GROWTH: after an
                # eviction the maps the broken member kept out join, and a small map beside them searched before
                # would wait for a search that the growth, done, no longer makes), or a member has left that kept
                # out its last search here (the held-out pillar_hall36_w: maps 00, 15 and 27, under the turned part
                # of broken map_33, found no place on the merge it seeded; without it the merge has another seed,
                # which the growth never searched them onto)
                continue
            # a search of the growth onto the merge does not count here, however little the merge has grown since:
            # the union it was searched onto may have had other members (generated pillar_hall36 seed 2: map_19,
            # searched onto a group that then merged with another and grew by a fifth, agreed 0.85 there and 1.000
            # on the final merge)
            newcomers = refused and not group.members.keys() <= self.left_out_saw.get(k, frozenset())
            if box is not False and not (changed and k in self.left_out_accepted) and not saw_gone and not newcomers:
                # searched at the end already and refused, no member it saw has left since (nor, with `refused`, has
                # one joined that it did not see): the same verdict
                continue
            todo.append(k)
        return todo

    def search_left_out(self, group: Group, readmit: bool = False, also: Sequence[int] = (),
                        refused: bool = False) -> int:
        """Search the grids left out of the merge (`group`; not those evicted) whose refused match found where they
        overlap its members (the others the growth searched onto it, _search), whether or not the growth searched them
        since, and join those whose placement passes the rules of a pair, shares at least LEFT_OUT_SHARE of the grid's
        known area with the merge, agrees with MIN_AGREEING members or more (as pairs; or one, where its placement is
        precise: eviction.vouched_for) and contradicts none (or only members these searches placed, that it outweighs:
        _outweighs). Returns how many joined. The searches count against the search budget as the growth's do, and
        those it cuts count as postponed. A placement that passes all that but contradicts a member of the growth
        counts as refused there: it is the map's vote on the members (evict_contradicted; the generated pillar_hall36
        seeded by map_00: map_08, accepted by the union and agreeing with 9 members, contradicted by broken map_02
        alone, had none while its last match was an accepted one, and stayed out).

        The growth does not search a grid whose refused match found where it overlaps the union and contradicts it (a
        broken map: a search finds the same), but in a repetitive building that match can be an alias while the true
        place agrees wall for wall. On the generated 36-map buildings (seeds 0-2) the searches at the end placed 26
        more maps right. Their placements shared 0.49-1.00 of the map's area with the merge; those of broken maps
        that passed the rules, one part fitting (the hub of a round hall, 29-38 m2), 0.08-0.35. One right map that a
        single member agreed with was placed 3 cells off.

        While maps join, those whose placement passed the rules but shared too little are judged again there on the
        grown merge (LEFT_OUT_ROUNDS rounds in all), and searched again where it refuses them: the true place beside a
        map that just joined shares more (a generated hospital: three maps placed 29-48 m2 onto the merge, 62-94 m2
        onto the map that joined), while an alias the new member contradicts is refused. So are the maps it refused in
        a round where others joined searched again in the next: a map refused at an alias can have its true place
        beside them (the generated courtyard36 seeded by map 3: map_18, refused half a turn off in the round that maps
        8, 15 and 17 joined, shares 120 m2 with map 8 at its true place, where it joins in the next round; the
        held-out courtyard36_v: map_12, refused again after maps 2 and 3 joined, is placed at agreement 1.000 once
        maps 4, 9, 10 and 11 have joined in the next). Its refusals are kept as the growth's are: at the end of an
        estimation afresh they vote on the members (evict_contradicted, estimator.py).
        Called again, it searches a grid searched before only where the verdict can have changed: its placement
        passed the pair rules and the members have changed since, or a member has left that its matches saw or its
        last placement overlaps, or any member has left and its last search found no place (nothing on
        min_overlap_m2). The searches refine the search's best distinct places too (match_pair's distinct_places).

        With `also`, it searches those grids as well (not members, not evicted), whatever their matches found. With
        `refused`, also a grid it refused before, once maps have joined the merge since its last search there (a side
        group, side_groups.py: the held-out hospital36_v, maps in reverse order: map_18, refused at an alias of the
        wing, shares 121 m2 with maps 12 and 20 of the group of seven that joined after it; searched again there,
        it is placed right at agreement 0.998).

        With `readmit`, it searches the members taken out instead (evict_contradicted), once the maps left out have
        had their rounds: a member one map singled out can be right and that map wrong (the generated radial hall: a
        broken map placed at the hub by one part voted out the right map that had seen the hub); it joins again by
        the same rules (a broken member taken out in hospital36 seed 1: its search found no place they accept), but a
        member taken out, whatever call searches it, is vouched for only by members that did not join by these
        searches themselves (on partial maps of a generated courtyard, two members taken out came back, one turned by
        154 degrees, one 7.6 m off, on the word of two maps these searches had just placed, one of them 3.8 m off)."""
        spent = self._spent()
        if readmit:
            todo = sorted(k for k in self.evicted if k not in group.members and self.prepared[k] is not None)
        else:
            todo = self._left_out_todo(group, refused)
            todo += sorted(k for k in set(also) - set(todo) if k not in group.members and k not in self.evicted
                           and self.prepared[k] is not None)
        if spent:
            # these grids are searched in a later estimation, as the growth's (_search): uncounted, the node took an
            # estimate afresh of its final maps cut here for a complete one (replay_node, generated mall36: 21 of
            # its 27 mergeable maps placed, for good; merge_maps 27)
            self.postponed += bool(todo)
            return 0
        if not readmit:
            self.left_out_evicted = set(self.evicted)
        union = group.union.prepared()
        self.left_out_footprints.update(group.union.footprints)
        joined, placed = 0, []
        for _ in range(LEFT_OUT_ROUNDS):
            members = frozenset(group.members)
            started = time.perf_counter()
            # distinct places: these maps' descriptors found an alias, which can crowd the search's candidates too
            matches = self.matcher.match_all([MatchCall(k, group.seed, self.prepared[k], union,
                                                        dict(onto_union=True, descriptors=False,
                                                             distinct_places=True))
                                              for k in todo]) + placed
            self.search_seconds += time.perf_counter() - started
            joining = []
            blocked: Dict[int, List[int]] = {}   # grid -> the members it contradicts that it does not outweigh
            for n, m in enumerate(matches):
                if not m.accepted:
                    continue
                if not self.shares_enough(m.i, m.best.overlap_m2):
                    log.debug('grid %d left out stays out: placed on %.2f of its area, less than %.2f', m.i,
                              self.share_of(m.i, m.best.overlap_m2), LEFT_OUT_SHARE)
                    continue
                rival = self.still_ambiguous(group, m)
                if rival is not None:
                    log.debug('grid %d left out stays out: a place an earlier match found as good agrees %.3f with '
                              'support %d there (this one %d)', m.i, rival.agreement, rival.support, m.best.support)
                    matches[n] = dataclasses.replace(m, accepted=False, reason=(
                        f'{AMBIGUOUS}: a place an earlier match found as good agrees {rival.agreement:.2f} with '
                        f'support {rival.support} vs {m.best.support}'))
                    continue
                agreeing, contradicting = judge_members(m.i, m.transform_m, group.members, group.union.footprints,
                                                        footprint(self.grids[m.i], m.transform_m), self.prepared,
                                                        self.s, verified=self.judged)
                # a member taken out: vouched for only by members these searches did not place (see above)
                vouchers = [j for j in agreeing if j not in self.left_out_joined] if m.i in self.evicted else agreeing
                if not vouched_for(vouchers, m.best, self.s):
                    log.debug('grid %d left out stays out: only members %s vouch for it (expected error at the far '
                              'corners %.2f m)', m.i, sorted(vouchers), m.best.corner_error_m)
                    continue
                if self._outweighs(group, m, agreeing, contradicting):
                    joining.append((m, agreeing, contradicting))
                else:
                    log.debug('grid %d left out stays out: it contradicts members %s, agreeing with %s', m.i,
                              sorted(contradicting), sorted(agreeing))
                    blocked[m.i] = contradicting
            joined_now: Dict[int, np.ndarray] = {}   # the maps that joined in this round, where
            # the strongest first (members agreeing, then agreeing walls; by content, not index, on a tie)
            joining.sort(key=lambda j: (-len(j[1]), -j[0].best.support, self.prepared[j[0].i].draw_key))
            for m, agreeing, contradicting in joining:
                # each was judged on the merge as the round began: one that contradicts a map that joined before it in
                # the round waits, judged again on the merge grown by that map (the held-out courtyard36_w, seed 1:
                # map_35, at an alias 5 m along the courtyard, joined in the round that map_29 joined at its true
                # place, contradicting it, with 1358 agreeing walls against 1432; map_34 then joined onto map_35, took
                # map_29's place, and 3 maps were off)
                _, against = judge_members(m.i, m.transform_m, joined_now,
                                           {k: footprint(self.grids[k], t) for k, t in joined_now.items()},
                                           footprint(self.grids[m.i], m.transform_m), self.prepared, self.s,
                                           verified=self.judged)
                if against:
                    log.debug('grid %d left out waits: it contradicts grid %d, which joined the merge in this round',
                              m.i, against[0])
                    continue
                for j in contradicting:
                    if j in group.members:
                        self._evict(group, j, f'grid {m.i}, which more members agree with, contradicts it')
                log.debug('grid %d %s joins the merge: a search onto it places it agreeing with members %s', m.i,
                          'taken out' if m.i in self.evicted else 'left out', sorted(agreeing))
                self.evicted.discard(m.i)
                self._join(group, m)
                self.left_out_joined[m.i] = (len(agreeing), m.best.support)
                joined_now[m.i] = m.transform_m
            joined += len(joined_now)
            for m in matches:
                self.left_out_boxes[m.i] = footprint(self.grids[m.i], m.transform_m) \
                    if m.best is not None and m.best.overlap_m2 >= self.s.min_overlap_m2 else None
                self.left_out_saw[m.i] = members
                if m.i in blocked:
                    # the merge refuses it for members that joined by the growth: they are judged by the votes of
                    # the maps left out (evict_contradicted), and this placement, refused as below, is its vote
                    m = dataclasses.replace(m, accepted=False, reason=f'contradicts members {blocked[m.i]}, '
                                                                      f'which it does not outweigh')
                if m.accepted:
                    self.left_out_accepted.add(m.i)
                    self.left_out_matches[m.i] = m
                    continue
                self.left_out_accepted.discard(m.i)
                if m.reason.startswith(IMPRECISE):
                    self.left_out_imprecise[m.i] = m
                if m.best is not None:
                    # where the merge refused it, as the growth's refusals (evict_contradicted's votes); not a
                    # placement that passed the rules but shares too little (a broken map placed by one part: the
                    # generated round hall's, at its hub, voted out the map that had seen the hub)
                    self.refused[m.i] = m
                    self._refused_onto(m, members)
            # a placement that passes the pair rules but shares too little with the merge may be the true one beside
            # a map that just joined: judged again there on the grown merge, and searched again where that merge
            # refuses it (an alias that a map that joined contradicts)
            waiting = sorted(k for k in self.left_out_accepted if k not in group.members)
            # a grid refused in this round did not see the maps that joined in it: its true place can be beside them
            refused_here = sorted(m.i for m in matches
                                  if m.i not in self.left_out_accepted and m.i not in group.members)
            if not joining or not (waiting or refused_here):
                break
            if self._spent():
                # the maps waiting are judged again in a later estimation (those refused here had their search)
                self.postponed += bool(waiting)
                break
            union = group.union.prepared()
            placed = [m for m in (self._placed_again(self.left_out_matches[k], union) for k in waiting)
                      if m is not None]
            again = {m.i for m in placed}
            todo = [k for k in waiting if k not in again] + refused_here
        if todo or joined:
            self.left_out_members = members   # the members its last searches saw
        return joined

    def set_aside_weak(self, group: Group) -> Dict[int, Tuple[int, np.ndarray]]:
        """Take out of the merge `group`, for the end of an estimation, the members a search of the growth placed on
        less than LEFT_OUT_SHARE of their known area (not its seed, not the reference); returns each one's place as
        (the member it was paired with, metric transform onto that member), for readmit_weak.

        Such a member joined on a small part of its map that fits the merge wall for wall (_searched_onto_little), as
        a chain end does, and as a map broken by a SLAM failure does by its part that is right. The rest of a broken
        one lies where the merge was not known then, and contradicts every map that is placed there later: the held-out
        hospital36_v with seeds 1 and 2 of the random draws, broken map_19 searched onto a merge of 18 on 0.15 of its
        area (agreement 1.000), and the 8 maps of the wing beside it, at their true places, each
        contradicted map_19 alone; the end's searches put them at aliases half a turn or 13-52 m off, and all 8 stayed
        out. So the maps left out are searched, and the groups taken apart placed, onto the merge without such
        members; each member is judged again afterwards at its place (readmit_weak)."""
        weak: Dict[int, Tuple[int, np.ndarray]] = {}
        for k in sorted(group.members):
            link = group.links.get(k)
            if k not in self.searched or k in (group.seed, self.reference) or link is None or link.best is None \
                    or self.shares_enough(k, link.best.overlap_m2):
                continue
            weak[k] = (link.j, tf.inverse(group.members[link.j]) @ group.members[k])
        for k in weak:
            log.debug('grid %d set aside for the end of the estimation: a search placed it on %.2f of its area', k,
                      self.share_of(k, group.links[k].best.overlap_m2))
            group.leave(k)
            self.evicted.add(k)
        return weak

    def readmit_weak(self, group: Group, weak: Dict[int, Tuple[int, np.ndarray]]) -> List[int]:
        """The members set_aside_weak took out join the merge `group` again at their places (by the member each was
        paired with, once that one is a member again) where the merge passes them there by the rules of a pair onto a
        union, no member near them contradicts them and those members, one by one, agree with them wall for wall
        (WEAK_AGREEMENT), as the growth asked of them, and a search onto the merge finds no other place that passes
        (pair.find_rival: it counts against the search budget, and with the budget spent the member waits for a later
        estimation, counted as postponed); the others stay out. Returns those that joined again."""
        back: List[int] = []
        # by content, not index: each that joins changes the merge the next is judged on
        waiting = dict(sorted(weak.items(), key=lambda kv: self.prepared[kv[0]].draw_key))
        joined = True
        while joined:
            joined = False
            for k, (j, to_j) in list(waiting.items()):
                if k in group.members:
                    del waiting[k]   # joined again by the end's searches (search_left_out's readmit)
                    continue
                if j not in group.members:
                    continue   # its pair is out: it waits for that one to join again, if it does
                del waiting[k]
                if self._weak_passes(group, k, group.members[j] @ to_j):
                    back.append(k)
                    joined = True
        return back

    def _weak_passes(self, group: Group, k: int, place: np.ndarray) -> bool:
        """Whether grid k passes readmit_weak's rules at `place` (metric, the merge's frame); if so, it joins the merge
        `group` there."""
        # its search onto the final merge (search_left_out's readmit), refused or short of the share, may have put it
        # at another place that a match can stand on: the two rival, and neither is the evidence (the held-out
        # maze36_w, seed 1: map_08, placed by the growth's search on 0.10 of its area a quarter turn off, was placed
        # there 34 m from it)
        again = self.left_out_matches.get(k) or self.refused.get(k)
        part = self.prepared[k]
        px = tf.inverse(part.px_to_map)   # metric placements as pixels of grid k's own frame (distinct's scale)
        why = 'its search onto the final merge put it at another place' \
            if again is not None and again.j == group.seed and places(again, self.s) \
            and distinct(px @ place @ part.px_to_map, px @ again.transform_m @ part.px_to_map, part, self.s) else ''
        c = self.passes_onto(part, group.union.prepared(), place) if not why else None
        why = why or ('the merge refuses it at its place' if c is None else '')
        if not why:
            _, contradicting = judge_members(k, place, group.members, group.union.footprints,
                                             footprint(self.grids[k], place), self.prepared, self.s,
                                             verified=self.judged)
            pooled = self._members_agreement(k, place, group) if not contradicting else 0.0
            why = f'members {contradicting} contradict it' if contradicting else \
                f'the members there agree {pooled:.3f} with it' if pooled < WEAK_AGREEMENT else ''
        if not why:
            searched, rival = self.rival_of(part, group.union.prepared(), c)
            if not searched:
                why = 'the search budget is spent: its search for another place waits for a later estimation'
            elif rival is not None:
                why = (f'a search onto the merge finds another place that passes (agreement {rival.agreement:.3f}, '
                       f'support {rival.support}, here {c.support})')
        if why:
            log.debug('grid %d set aside stays out: %s', k, why)
            return False
        self.evicted.discard(k)
        self._join(group, accepted_at(k, group.seed, c, place))
        return True

    def rival_of(self, part: PreparedGrid, union: PreparedGrid, c: Placement,
                 enough: Optional[Callable[[Placement], bool]] = None) -> Tuple[bool, Optional[Placement]]:
        """(searched, rival): pair.find_rival of `part` onto `union` away from its placement c, its time counted
        against the search budget; not made once the budget is spent (searched False, counted as postponed). The
        placement it guards then waits for a later estimation: taken unsearched, it could be at an alias."""
        if self._spent():
            self.postponed += 1
            return False, None
        started = time.perf_counter()
        rival = find_rival(part, union, c, self.s, enough=enough)
        self.search_seconds += time.perf_counter() - started
        return True, rival

    def still_ambiguous(self, group: Group, m: PairMatch) -> Optional[Placement]:
        """A place of grid m.i on the merge `group`, distinct from where the accepted match m puts it, that an earlier
        match of the grid onto the group found as good (refused as ambiguous: self.rivals) and that, refined by ICP on
        the merge as it is now, still passes the rules of `plausible` and is as good as m's (pair.as_good); None if
        there is none.

        A later search's candidates can miss such a place, or rank it lower, while it still fits as well: the held-out
        mall36_v with seed 2 of the random draws, map_01, searched by the growth onto a merge of 24, was ambiguous
        between an alias 12.9 m along alike shops (1073 agreeing walls) and the truth (688); the end's search onto the
        merge of 26 found the alias alone, and the map joined there with two members agreeing."""
        found = self.rivals.get((m.i, group.seed))
        if not found or m.best is None:
            return None
        part, union = self.prepared[m.i], group.union.prepared()
        rng = np.random.default_rng((self.s.seed, part.draw_key, union.draw_key))
        tried: List[np.ndarray] = []
        for place in found:
            px = tf.inverse(union.px_to_map) @ place @ part.px_to_map
            if not distinct(px, m.best.transform, part, self.s) or any(not distinct(px, t, part, self.s)
                                                                       for t in tried):
                continue
            tried.append(px)
            c = verify(part, union, icp(part, union, px, self.s, rng), self.s)
            if distinct(c.transform, m.best.transform, part, self.s) and plausible(c, self.s) \
                    and as_good(c, m.best, self.s):
                return c
        return None

    def _outweighs(self, group: Group, m: PairMatch, agreeing: Sequence[int], contradicting: Sequence[int]) -> bool:
        """Whether the grid that search_left_out's match m places onto `group`, agreeing with the members
        `agreeing`, outweighs the members it contradicts: none, or each joined by search_left_out too, agreeing then
        with fewer members and on fewer walls than it does now, and neither the group's seed (m is in its frame) nor
        the reference.

        A broken map left out, placed by one of its parts, can vote out a right member (evict_contradicted) and join
        in its place: held-out office36_u, broken map_06 (58.8 m2) agreed with 3 members over 33 m2 and contradicted
        map_34 alone, which left; searched again, map_34 agreed 0.99 with 19 members over 264 m2 (6719 walls, map_06
        782) and was contradicted by map_06 alone. Members of the growth are judged by evict_contradicted's votes."""
        return all(j in self.left_out_joined and j not in (group.seed, self.reference)
                   and self.left_out_joined[j][0] < len(agreeing)
                   and self.left_out_joined[j][1] < m.best.support for j in contradicting)

    def _placed_again(self, m: PairMatch, union: PreparedGrid) -> Optional[PairMatch]:
        """The accepted match m of a grid onto a union, judged again at its place on a grown `union` (the same frame):
        the match with that verification if it still passes the rules of a pair, else None."""
        c = self.passes_onto(self.prepared[m.i], union, m.transform_m)
        return None if c is None else dataclasses.replace(m, best=c)

    def _join(self, group: Group, m: PairMatch) -> None:
        """Grid m.i joins the group by its accepted match m."""
        if len(group.members) <= FEW_MEMBERS:
            self.placed_onto_few.add(m.i)
        else:
            self.placed_onto_few.discard(m.i)
        group.join(m.i, self.grids[m.i], self.prepared[m.i], m)
        self.admitted.pop(m.i, None)
        self.refused.pop(m.i, None)
        self._forget_search(m.i, group)
        self.settle(1)

    def _evict(self, group: Group, j: int, why: str) -> None:
        """Member j leaves the group and stays out of this estimation."""
        log.debug('grid %d leaves group %d: %s', j, group.seed, why)
        if j == group.seed:
            # the largest maps seed groups, and a broken map is often the largest: the largest other member
            # becomes the seed, and the matches refused onto the group are restated in its frame
            new_seed = max((k for k in group.members if k != j), key=lambda k: self.prepared[k].known_pixels)
            self.restate_refused(j, new_seed, group.reframe(new_seed))
        group.leave(j)
        self.contradicting.add(j)
        self.refused[j] = PairMatch(j, group.seed, reason=why)
        self.evicted.add(j)

    def _group_match_kept(self, small: Group, big: Group) -> Optional[PairMatch]:
        """The last match of the two groups if their unions have not changed since (merge_groups is called again as
        groups form); one made before the budget was spent stands after it too."""
        last = self.group_matches.get((id(small), id(big)))
        if last is None or last[0] is not small or last[1] is not big:
            return None
        versions, spent = last[2]
        if versions != (small.union.version, big.union.version) or \
                (spent and not self._spent()):
            return None
        return last[3]

    def _group_call(self, small: Group, big: Group, spent: bool) -> MatchCall:
        # two unions of a repetitive building: descriptors often find a wide placement that agrees in part (the
        # far end of a corridor), while the true, smaller overlap only the search finds; a group holds no map
        # that contradicts its members, so such a contradiction says nothing about where the groups overlap;
        # with the budget spent, a match that needs the search waits for a later estimation (search_spent): the
        # descriptors' candidates alone, rescued by the polish, could pass where the search finds a better
        # placement or a rival that makes the match ambiguous
        return MatchCall(small.seed, big.seed, small.union.prepared(), big.union.prepared(),
                         dict(onto_union=len(big.members) > 1, between_groups=True, search_spent=spent))

    def _keep_group_match(self, small: Group, big: Group, spent: bool, m: PairMatch) -> None:
        self.group_matches[(id(small), id(big))] = (small, big, ((small.union.version, big.union.version), spent), m)

    def _match_ahead(self, upcoming: Iterable[Tuple[Group, Group]]) -> None:
        """Match the first `threads` pairs of groups (small, big) of `upcoming` (the next that merge_groups will
        match, the one it matches now first) that have no kept match, at once (in parallel): most such matches are
        refused, and one that is accepted changes a union for the rest, whose matches are made again (at most
        `threads` - 1 matches in vain). Beyond the groups still to match onto the same union, the pairs of the
        next union: a group match alone ran the correlation search on two threads and the rest of it on one, with
        the matching processes idle (hospital36: 1.7 s of 15)."""
        todo = list(itertools.islice(((small, big) for small, big in upcoming
                                      if self._group_match_kept(small, big) is None), self.s.threads))
        if len(todo) < 2 or self._spent():
            return
        started = time.perf_counter()
        for (small, big), m in zip(todo, self.matcher.match_all([self._group_call(small, big, False)
                                                                 for small, big in todo])):
            self._keep_group_match(small, big, False, m)
        self.search_seconds += time.perf_counter() - started

    def _match_groups(self, small: Group, big: Group) -> PairMatch:
        self.tried[(small.seed, big.key)] = big.union.version
        m = self._group_match_kept(small, big)
        if m is None:
            spent = self._spent()
            m = self._group_match(small, big, spent)
            self._keep_group_match(small, big, spent, m)
        if m.reason == SEARCH_POSTPONED:
            self.postponed += 1
        return m

    def match_groups_now(self, small: Group, big: Group) -> PairMatch:
        """The match of the union of `small` onto that of `big`, made now as merge_groups makes it (not kept)."""
        return self._group_match(small, big, self._spent())

    def _group_match(self, small: Group, big: Group, spent: bool) -> PairMatch:
        """The match of two groups' unions, made here; it counts against the search budget."""
        started = time.perf_counter()
        m = self.matcher.match_here(self._group_call(small, big, spent))
        self.search_seconds += time.perf_counter() - started
        return m

    def _spent(self) -> bool:
        return self.budget.spent(self.search_seconds, self.s.search_budget_s)

    def settle(self, n: int) -> None:
        self.settled += n
        if self.progress is not None:
            self.progress(min(self.settled, self.total), self.total)


def tree_of_overlaps(root: int, footprints: Dict[int, Optional[Box]]) -> Dict[int, int]:
    """grid -> a grid it overlaps that is one overlap nearer `root` (breadth first), for the grids reachable from
    root through overlapping footprints."""
    parents: Dict[int, int] = {}
    frontier, seen = [root], {root}
    while frontier:
        nxt = []
        for a in frontier:
            for b in sorted(footprints):
                if b not in seen and overlap_area(footprints[a], footprints[b]) > 0.0:
                    parents[b] = a
                    seen.add(b)
                    nxt.append(b)
        frontier = nxt
    return parents
