"""Uniqueness: a held placement (confirmation.py) is confirmed only where the merge that stands has no other place
for it.

Growth of the common area does not tell an alias from the truth in a building that repeats itself: maps that grow
along a corridor of alike offices keep agreeing at a place shifted by one office (the generated buildings replayed
as growing maps, bench/replay_node.py --generated: 24 of 130 estimations published a map placed wrong). Each
placement about to be confirmed is therefore checked on the union of the grids that stand (published before), where
it lands: refused when it contradicts that union there (a group of new maps placed together through a member whose
place the merge contradicts: its other members with it), or when a search of the union (pair.find_rival) finds
another place that passes the pair rules with RIVAL_SHARE of its support or more, or when the part of the grid that
lands on the union's known area fits another place there as well (pair.as_good: no other place for the whole grid
proves nothing where the rest lies beyond what the union knows; a generated office36 map 22 was so refused, and
later found contradicting). A placement that shares too little with the standing union to be judged there (less than
min_support agreeing walls) is left to the growth rule: it is confirmed only through a grid confirmed with it.

The share comes from the pair matches of partial maps of six generated buildings (bench/pair_aliases.py --rivals,
25 % revealed): a rival of at least 0.3 of the best's support singled out 18 of 22 aliases and 16 of 62 right
placements (those wait until their maps grow out of the repetition); at 0.4, 10 and 4.
"""
from __future__ import annotations

import logging
from typing import Dict, FrozenSet, Optional, Sequence

import cv2
import numpy as np

from .. import transforms as tf
from ..grid import Grid
from .features import FeatureCache, PreparedGrid, prepare
from .pair import RIVAL_PLACES, as_good, find_rival
from .settings import EstimationSettings
from .union import UnionMap
from .verify import too_contradicted, verify

log = logging.getLogger('rosout.multirobot_map_merge.estimation.uniqueness')

RIVAL_SHARE = 0.3
CROP_MARGIN_M = 0.5   # around the part of a grid that lands on the standing union's known area
WHOLE_SHARE = 0.9     # a part this large of the grid's known area is the grid: its own search said it all
CONTRADICTS = 'contradicts the merge that stands'


class StandingCheck:
    """Judges placements on the union of the grids that stand, composed once per set of them (one estimation)."""

    def __init__(self, grids: Sequence[Optional[Grid]], settings: EstimationSettings, cache: FeatureCache,
                 resolution: float):
        self.grids, self.s, self.cache, self.res = grids, settings, cache, resolution
        self._unions: Dict[FrozenSet[int], Optional[PreparedGrid]] = {}

    def _union(self, standing: Dict[int, np.ndarray]) -> Optional[PreparedGrid]:
        key = frozenset(standing)
        if key not in self._unions:
            union = UnionMap(self.res)
            for m, t in standing.items():
                part = self.cache.get(self.grids[m], self.res, self.s.feature)
                if part is not None:
                    union.add(m, self.grids[m], part, t)
            self._unions[key] = union.prepared() if union.members else None
        return self._unions[key]

    def __call__(self, k: int, transform: np.ndarray, standing: Dict[int, np.ndarray],
                 settled: bool = False, keep: int = RIVAL_PLACES) -> Optional[str]:
        """Why grid k, placed by `transform` (metric, the frame of the standing grids' transforms), is not
        confirmed on the union of the `standing` grids: '' if nothing speaks against it, None if it shares too little
        with it to be judged there. With `settled` (maps that no longer change: waiting tells nothing more), a rival
        counts only when it is as good as the placement (pair.as_good), as for a pair. Rivals are searched among
        the `keep` best places of the search."""
        union = self._union(standing)
        part = self.cache.get(self.grids[k], self.res, self.s.feature)
        if union is None or part is None:
            return None
        best = verify(part, union, tf.inverse(union.px_to_map) @ transform @ part.px_to_map, self.s)
        log.debug('grid %d on the merge that stands: support %d, agreement %.2f, %.1f m2', k, best.support,
                  best.agreement, best.overlap_m2)
        if best.support < self.s.min_support or best.overlap_m2 < self.s.min_overlap_m2:
            return None
        if best.agreement < self.s.min_agreement or too_contradicted(best, self.s):
            return (f'{CONTRADICTS}: agreement {best.agreement:.2f} with support {best.support}, '
                    f'{best.deep_conflicts} contradicting walls well inside both')
        # a rival counts from RIVAL_SHARE of the support here, below the support a pair needs
        loose = self.s.replace(min_support=max(int(RIVAL_SHARE * best.support), 1))
        rival = find_rival(part, union, best, loose, keep, enough=(lambda c: as_good(c, best, self.s)) if settled
                           else (lambda c: c.support >= RIVAL_SHARE * best.support))
        if rival is not None:
            return (f'another place on the merge that stands agrees {rival.agreement:.2f} with support '
                    f'{rival.support} (here {best.support})')
        return self._part_elsewhere(k, transform, union, keep)

    def _part_elsewhere(self, k: int, transform: np.ndarray, union: PreparedGrid, keep: int) -> str:
        """Why the part of grid k that lands on the union's known area fits another place of the union as well
        (pair.as_good): '' if it does not. The rest of the grid lies where the union knows nothing, so it neither
        supports nor contradicts the placement; if the shared part is a pattern the union repeats (a corridor
        of alike rooms), nothing singles out this place: the grid may lie at a repeat the union does not hold yet."""
        grid = self.grids[k]
        to_union = tf.inverse(union.px_to_map) @ transform @ grid.cell_to_map()   # grid k's cells -> union pixels
        on = cv2.warpAffine((union.work >= 0).view(np.uint8), to_union[:2], (grid.width, grid.height),
                            flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
        r = max(int(round(CROP_MARGIN_M / grid.resolution)), 1)
        on = cv2.dilate(on, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))) > 0
        known = grid.data >= 0
        if np.count_nonzero(on & known) >= WHOLE_SHARE * np.count_nonzero(known):
            return ''
        shared = prepare(Grid(np.where(on, grid.data, -1), grid.resolution, grid.origin, grid.frame_id), self.res,
                       self.s.feature, lazy=True)
        if shared is None:
            return ''
        best = verify(shared, union, tf.inverse(union.px_to_map) @ transform @ shared.px_to_map, self.s)
        rival = find_rival(shared, union, best, self.s, keep, enough=lambda c: as_good(c, best, self.s))
        if rival is None:
            return ''
        return (f'the part of it on the merge that stands fits another place as well: agreement '
                f'{rival.agreement:.2f}, support {rival.support}, {rival.overlap_m2:.1f} m2 '
                f'(here {best.agreement:.2f}, {best.support}, {best.overlap_m2:.1f} m2)')
