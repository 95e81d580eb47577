"""match_memo.py: the matches of an estimation afresh are kept for the estimation made again (the audit), known by
the grids' indices, the options, and what was matched (a grid, or a union's members and placements)."""
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation import workers
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.estimation.match_memo import MatchMemo
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.estimation.union import UnionMap
from multirobot_map_merge.estimation.workers import MatchCall, ParallelMatcher
from test_eviction import RES, seen, stubbed_building


@pytest.fixture
def counted(monkeypatch):
    made = []
    match_pair = workers.match_pair

    def counting(i, j, pi, pj, s, **options):
        made.append((i, j))
        return match_pair(i, j, pi, pj, s, **options)
    monkeypatch.setattr(workers, 'match_pair', counting)
    return made


def test_a_match_of_the_same_grids_is_made_once_and_handed_out_as_a_copy(counted):
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 130, 300)]
    prepared = [prepare(g, RES, 'akaze') for g in grids]
    with ThreadPoolExecutor(1) as pool:
        matcher = ParallelMatcher(EstimationSettings(processes=False), pool, MatchMemo())
        first = matcher.match_here(MatchCall(1, 0, prepared[1], prepared[0]))
        first.best.corner_error_m = 99.0   # a caller restates what it got
        again = matcher.match_all([MatchCall(1, 0, prepared[1], prepared[0])])[0]
        other = matcher.match_here(MatchCall(1, 0, prepared[1], prepared[0], dict(search=False)))
    assert counted == [(1, 0), (1, 0)]   # the same call once; another option is another match
    assert again is not first and again.accepted == first.accepted
    assert np.allclose(again.transform_m, first.transform_m) and again.best.corner_error_m != 99.0
    assert first.searched and not other.searched   # made without the search, as asked


def test_a_union_of_the_same_members_at_the_same_places_is_the_same_for_a_match(counted):
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 130, 300), seen(world, 60, 240)]
    prepared = [prepare(g, RES, 'akaze') for g in grids]

    def union(shift: float):
        u = UnionMap(RES)
        u.add(0, grids[0], prepared[0], np.eye(3))
        u.add(1, grids[1], prepared[1], tf.translation(shift, 0.0))
        return u.prepared()
    same, moved = union(0.0), union(0.1)
    assert same is not union(0.0) and same.derived['signature'] == union(0.0).derived['signature']
    assert moved.derived['signature'] != same.derived['signature']
    with ThreadPoolExecutor(1) as pool:
        matcher = ParallelMatcher(EstimationSettings(processes=False), pool, MatchMemo())
        for onto in (same, union(0.0), moved):
            matcher.match_here(MatchCall(2, 0, prepared[2], onto, dict(onto_union=True)))
    assert counted == [(2, 0), (2, 0)]
