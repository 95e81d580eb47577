"""Stage 3 of estimation: grow groups of placed grids, matching every newcomer against the union of a group.

A group starts from a seed (the preferred reference, else the grid with the largest known area) and grows in
rounds. In a round every grid not placed yet is matched against the union of the group (union.py) by descriptors
only, cheap and in parallel; the accepted ones join, and the next round matches the rest against the grown union.
A round that adds nobody runs the costly correlation search, on the remaining grids smallest first, each only if
the union or the grid has grown enough since it last searched them (SearchMemo, kept across estimations). Grids that join no group seed the next group; groups are
matched against each other (union against union), and the largest group is the merge. So a grid whose overlap with
every single map is too small, but with the union large, joins; and each newcomer costs one match against the
union, not one per placed map.

Tracking (tracking.py): with the transforms of the last estimate (`previous`, same reference), the grids placed
then are re-checked first; those that still hold form the first group, which the others then join as above.
"""
from __future__ import annotations

import logging
import time
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np

from . import transforms as tf
from .features import FeatureCache, PreparedGrid
from .grid import Grid
from .matching import PairMatch, match_pair, overlap_found
from .settings import EstimationSettings
from .tracking import track
from .union import UnionMap

log = logging.getLogger('rosout.multirobot_map_merge.estimation')

SEARCH_GROWTH = 1.25   # a grid is searched against a union again only once the union has grown by this factor

Progress = Callable[[int, int], None]   # (grids settled, grids in all), called as the estimation goes


@dataclass
class Estimate:
    """transforms[k]: metric map frame of grid k -> merged frame (the reference grid's map frame); None = excluded.
    pairs: how each placed grid was placed (j: the placed grid it overlaps most) and the last refused match of
    every grid left out."""
    transforms: List[Optional[np.ndarray]]
    reference: Optional[int]
    pairs: List[PairMatch] = field(default_factory=list)
    seconds: float = 0.0
    tracked: int = 0   # grids whose previous placement was confirmed (tracking)


def working_resolution(grids: Sequence[Optional[Grid]], settings: EstimationSettings) -> float:
    """The finest resolution among the grids, but not finer than settings.min_work_resolution."""
    res = [g.resolution for g in grids if g is not None]
    return max(min(res), settings.min_work_resolution) if res else settings.min_work_resolution


class Group:
    """Grids placed together: grid index -> metric transform into the frame of the seed grid."""

    def __init__(self, seed: int, grid: Grid, prepared: PreparedGrid, res: float):
        self.seed = seed
        self.union = UnionMap(res)
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

    def paired(self, m: PairMatch, k: int) -> PairMatch:
        """m (member k placed onto the union) restated as a pair of k and the member it overlaps most."""
        anchor = self.union.anchor(k)
        out = PairMatch(k, anchor, m.matches, m.inliers, m.confidence, m.descriptor_matches, m.descriptor_inliers,
                        m.accepted, m.reason, m.best)
        out.transform_m = tf.inverse(self.members[anchor]) @ self.members[k]
        return out


class SearchMemo:
    """The correlation searches that failed: (grid name, names of the group's members) -> (known pixels of the grid,
    known pixels of the union) at that search. Kept across estimations by the pipeline, so that a live fleet
    searches a pair of growing maps again only once one has grown by SEARCH_GROWTH. Bounded."""

    def __init__(self, capacity: int = 4096):
        self._items: Dict[tuple, tuple] = {}
        self._capacity = capacity

    def get(self, key: tuple) -> Optional[tuple]:
        return self._items.get(key)

    def remember(self, key: tuple, sizes: tuple) -> None:
        self._items.pop(key, None)
        self._items[key] = sizes
        while len(self._items) > self._capacity:
            del self._items[next(iter(self._items))]


class Grower:
    """Grows groups over one estimation; owns the bookkeeping of which grid was tried against which union."""

    def __init__(self, grids: Sequence[Optional[Grid]], prepared: Sequence[Optional[PreparedGrid]], res: float,
                 settings: EstimationSettings, pool: Executor, reference: Optional[int],
                 progress: Optional[Progress], memo: Optional['SearchMemo'] = None,
                 names: Optional[Sequence] = None):
        self.grids, self.prepared, self.res, self.s, self.pool = grids, prepared, res, settings, pool
        self.reference = reference
        self.progress = progress
        self.total = sum(p is not None for p in prepared)
        self.tried: Dict[tuple, int] = {}       # (grid, group id) -> union version of the last descriptor match
        self.searched = memo if memo is not None else SearchMemo()
        self.names = list(names) if names is not None else list(range(len(prepared)))
        self.refused: Dict[int, PairMatch] = {}  # grid -> its last refused match
        self.contradicting: set = set()          # grids that overlap a group's union but contradict it
        self.settled = 0

    def match(self, k: int, group: Group, search: bool) -> PairMatch:
        """Grid k onto the group's union: by descriptors, or (search) by the correlation search alone. A group of
        one is matched as a pair."""
        return match_pair(k, group.seed, self.prepared[k], group.union.prepared(), self.s, search=search,
                          onto_union=len(group.members) > 1, descriptors=not search)

    def grow(self, group: Group, unplaced: List[int]) -> None:
        """Add to the group every grid of `unplaced` (removed from it) that can be placed against its union."""
        while unplaced:
            batch = [k for k in unplaced if self._worth_matching(k, group)]
            if batch:
                group.union.prepared()   # once, before the workers share it
                for k in batch:
                    self.tried[(k, id(group))] = group.union.version
                results = list(self.pool.map(lambda k: self.match(k, group, search=False), batch))
                if self._admit(group, unplaced, results):
                    continue
            if not self._search(group, unplaced):
                return

    def _worth_matching(self, k: int, group: Group) -> bool:
        """Whether grid k is to be matched against the group's union (again): not if it was matched against this
        union already, nor if its last match found where it overlaps the union (and contradicts it) and the union
        has not changed there since (the same descriptors against the same walls give the same verdict)."""
        tried = self.tried.get((k, id(group)))
        if tried is None:
            return True
        if tried == group.union.version:
            return False
        last = self.refused.get(k)
        if last is None or last.j != group.seed or not overlap_found(last.best, self.s, len(group.members) > 1):
            return True
        return group.union.changed_under(self.prepared[k], last.best.transform, since=tried)

    def _admit(self, group: Group, unplaced: List[int], results: List[PairMatch]) -> bool:
        added = False
        for m in sorted(results, key=lambda m: -m.weight):
            if m.accepted:
                group.join(m.i, self.grids[m.i], self.prepared[m.i], m)
                unplaced.remove(m.i)
                self.refused.pop(m.i, None)
                self._settle(1)
                added = True
            else:
                self.refused[m.i] = m
                if len(group.members) > 1 and m.best is not None and m.best.support >= self.s.min_support \
                        and m.best.overlap_m2 >= self.s.min_overlap_m2:
                    self.contradicting.add(m.i)
        return added

    def _search(self, group: Group, unplaced: List[int]) -> bool:
        """The correlation search, smallest grid first, on grids the union has grown for since their last search;
        stops at the first grid it places (the others are matched against the grown union first)."""
        known = group.union.known_pixels
        members = frozenset(self.names[m] for m in group.members)
        for k in sorted(unplaced, key=lambda k: self.prepared[k].known_pixels):
            key = (self.names[k], members)
            last = self.searched.get(key)
            if last is not None and self.prepared[k].known_pixels < SEARCH_GROWTH * last[0] \
                    and known < SEARCH_GROWTH * last[1]:
                continue   # searched before (maybe in an earlier estimation), and neither has grown much since
            refused = self.refused.get(k)
            if refused is not None and refused.j == group.seed \
                    and overlap_found(refused.best, self.s, len(group.members) > 1):
                continue   # the descriptors found the overlap and the maps disagree there
            self.searched.remember(key, (self.prepared[k].known_pixels, known))
            m = self.match(k, group, search=True)
            if self._admit(group, unplaced, [m]):
                return True
        return False

    def merge_groups(self, groups: List[Group], unplaced: List[int]) -> List[Group]:
        """Match groups against each other (the smaller union onto the larger) until no two merge; a merged group
        grows again with the grids still unplaced."""
        changed = True
        while changed and len(groups) > 1:
            changed = False
            groups.sort(key=lambda g: -len(g.members))
            for a in range(len(groups)):
                for b in range(a + 1, len(groups)):
                    big, small = groups[a], groups[b]
                    if len(small.members) == 1 and self.tried.get((small.seed, id(big))) == big.union.version:
                        continue   # a single grid was matched against this union already
                    m = self._match_groups(small, big)
                    if m.accepted:
                        # the merged frame stays that of the preferred reference's group
                        if self.reference in small.members:
                            small.absorb(big, tf.inverse(m.transform_m), m)
                            groups[a] = small
                        else:
                            big.absorb(small, m.transform_m, m)
                        groups.pop(b)
                        self.grow(groups[a], unplaced)
                        changed = True
                        break
                if changed:
                    break
        return groups

    def _match_groups(self, small: Group, big: Group) -> PairMatch:
        self.tried[(small.seed, id(big))] = big.union.version
        return match_pair(small.seed, big.seed, small.union.prepared(), big.union.prepared(), self.s,
                          onto_union=len(big.members) > 1)

    def _settle(self, n: int) -> None:
        self.settled += n
        if self.progress is not None:
            self.progress(min(self.settled, self.total), self.total)


def estimate(grids: Sequence[Optional[Grid]], settings: EstimationSettings, cache: Optional[FeatureCache] = None,
             preferred_reference: Optional[int] = None,
             previous: Optional[Sequence[Optional[np.ndarray]]] = None,
             progress: Optional[Progress] = None, memo: Optional[SearchMemo] = None,
             names: Optional[Sequence] = None) -> Estimate:
    """Estimate where every grid goes. Grids that are None, empty or unmatched get no transform. With `previous`
    (the last estimate's transforms, same grid order, same reference), the placements that still hold are kept
    (tracking.py) and only the other grids are searched. `memo` (with `names`, stable names of the grids) keeps
    the failed correlation searches from one estimation to the next."""
    settings.validate()
    t0 = time.perf_counter()
    cache = cache or FeatureCache()
    res = working_resolution(grids, settings)
    usable = [g if g is not None and not g.is_empty() else None for g in grids]
    transforms: List[Optional[np.ndarray]] = [None] * len(grids)
    with ThreadPoolExecutor(max_workers=settings.threads) as pool:
        prepared = list(pool.map(lambda g: cache.get(g, res, settings.feature) if g is not None else None, usable))
        present = [k for k, p in enumerate(prepared) if p is not None]
        if not present:
            return Estimate(transforms, None, seconds=time.perf_counter() - t0)
        grower = Grower(usable, prepared, res, settings, pool, preferred_reference, progress, memo, names)
        groups: List[Group] = []
        checks = []
        if preferred_reference in present and previous is not None and len(previous) == len(grids) \
                and previous[preferred_reference] is not None \
                and np.allclose(previous[preferred_reference], np.eye(3)):
            kept, checks = track(previous, preferred_reference, usable, prepared, res, settings, pool)
            if kept:
                first = Group(preferred_reference, usable[preferred_reference], prepared[preferred_reference], res)
                by_grid = {c.k: c for c in checks}
                for k, t in kept.items():
                    if k != preferred_reference:
                        first.union.add(k, usable[k], prepared[k], t)
                        first.links[k] = by_grid[k].match
                groups.append(first)
                grower._settle(len(first.members))
        tracked = len(groups[0].members) - 1 if groups else 0
        placed = {k for g in groups for k in g.members}
        unplaced = sorted((k for k in present if k not in placed), key=lambda k: -prepared[k].known_pixels)
        if groups:
            grower.grow(groups[0], unplaced)
        while unplaced:
            if groups and 2 * len(groups[0].members) > len(present):
                # the first group will be the merge: a grid that overlaps it but contradicts it cannot join it,
                # whatever group it would form with others (a map broken by a SLAM failure): set it aside
                unplaced[:] = [k for k in unplaced if k not in grower.contradicting]
                if not unplaced:
                    break
            seed = preferred_reference if preferred_reference in unplaced else unplaced[0]
            unplaced.remove(seed)
            grower._settle(1)
            group = Group(seed, usable[seed], prepared[seed], res)
            grower.grow(group, unplaced)
            groups.append(group)
        groups = grower.merge_groups(groups, unplaced)

    chosen = max(groups, key=lambda g: (len(g.members), preferred_reference in g.members))
    # the merged frame is the frame of the chosen group's seed
    for k, t in chosen.members.items():
        transforms[k] = t
    pairs = list(chosen.links.values()) + [m for k, m in grower.refused.items() if k not in chosen.members]
    pairs += [c.match for c in checks if c.transform is None and c.k not in chosen.members
              and c.k not in grower.refused]
    seconds = time.perf_counter() - t0
    log.debug('estimated %d grids: %d placed around grid %d (%d kept from the last estimate), %d groups, %.2f s',
              len(grids), len(chosen.members), chosen.seed, tracked, len(groups), seconds)
    return Estimate(transforms, chosen.seed, pairs, seconds, tracked)
