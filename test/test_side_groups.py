"""side_groups.py: maps that each share too little with the merge to join alone, but made a group before the growth
took it apart, join together where the end's search placed one of them, when several of them agree with the merge."""
import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation import eviction, growth, side_groups
from multirobot_map_merge.estimation.side_groups import remember, search_side_groups
from multirobot_map_merge.estimation.union import footprint
from test_eviction import _merge_of, seen, stubbed_building

CORNERS = np.array([[0.0, 0.0], [15.0, 10.0]])


def _hall(side_maps):
    """The merge of three maps of the west of the hall (maps 0-2) and the maps `side_maps` (each x0, x1 in pixels)
    that a side group held at their true places, their own searches made (search_left_out)."""
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150)]
    grids += [seen(world, c0, c1) for c0, c1 in side_maps]
    grower, group = _merge_of(grids, [0, 1, 2])
    remember(grower.side_groups, {k: np.eye(3) for k in range(3, len(grids))})
    assert grower.search_left_out(group) == 0   # each shares less than half its area with the merge
    return grower, group


def test_a_side_group_whose_maps_each_share_too_little_joins_where_several_agree_with_the_merge():
    grower, group = _hall([(90, 260), (100, 300)])
    assert 3 in grower.left_out_matches   # its search placed it, short of the share
    assert search_side_groups(grower, group) == 2
    assert sorted(group.members) == [0, 1, 2, 3, 4]
    for k in (3, 4):
        rot, shift = tf.difference(group.members[k], np.eye(3), CORNERS)
        assert rot < 0.01 and shift < 0.1
    assert search_side_groups(grower, group) == 0   # nothing left out


def test_a_side_group_that_meets_the_merge_by_one_map_stays_out(monkeypatch):
    """Map 4 lies beyond the merge: only map 3 agrees with its members (as a broken map's one fitting part would).
    Its search placed map 3 right, and the union passes the rules of a pair there: one map's word is not enough."""
    grower, group = _hall([(90, 260), (200, 300)])
    assert search_side_groups(grower, group) == 0
    assert sorted(group.members) == [0, 1, 2]
    monkeypatch.setattr(side_groups, 'MEETING', 1)
    assert search_side_groups(grower, group) == 2


def test_only_groups_of_two_or_more_are_remembered():
    kept = []
    remember(kept, {3: np.eye(3)})
    remember(kept, {3: np.eye(3), 4: tf.rigid(1.0, 0.0, 0.0)})
    assert len(kept) == 1 and np.allclose(kept[0][4], tf.rigid(1.0, 0.0, 0.0))


def test_a_side_group_that_fits_as_well_one_room_along_stays_out(monkeypatch):
    """A corridor of identical rooms: the merge saw rooms 1-6, the side group rooms 4-9 (its maps 4-7 and 5-9), and
    a member's search placed one of them right. Its union agrees with the merge there, and as well one room along
    (the rooms are alike and the corridor's end lies where the merge knows nothing): it stays out."""
    from test_group_joins import ROOM, corridor_of_rooms
    from test_group_joins import seen as seen_rooms
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.grid import Grid
    world = corridor_of_rooms(10)
    spans = [(0, 6), (0, 4), (2, 6), (3, 7), (4, 9)]
    grids = [Grid(seen_rooms(world, a * ROOM, b * ROOM + 1), 0.05) for a, b in spans]
    grower, group = _merge_of(grids, [0, 1, 2])
    remember(grower.side_groups, {3: np.eye(3), 4: np.eye(3)})
    m = PairMatch(3, group.seed, accepted=True)
    m.transform_m = np.eye(3)
    grower.left_out_matches[3] = m
    assert search_side_groups(grower, group) == 0
    monkeypatch.setattr(growth, 'find_rival', lambda *args, **kwargs: None)
    # that search counts against the search budget: with the budget spent the group waits for a later estimation
    budget = grower.s
    grower.s = budget.replace(search_budget_s=0.0)
    assert search_side_groups(grower, group) == 0 and grower.postponed > 0
    grower.s = budget
    assert search_side_groups(grower, group) == 2


def test_a_side_group_is_tried_where_a_member_was_placed_by_every_rule_but_precision(monkeypatch):
    """The end's search of a member can leave its own small common area imprecise (0.24 m at the far corners in one
    order of the held-out school36_v's maps, 0.28 m in the other, beyond 0.25 m): its place is still where the union
    of its group is tried, judged there by the rules with all the union's walls, precision included (school36_v in
    reverse order: 13 maps placed without it, 27 with it)."""
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, group = _hall([(90, 260), (100, 300)])
    grower.left_out_matches.clear()
    refused = PairMatch(3, group.seed, reason='agreement 0.80 < 0.91')
    monkeypatch.setattr(grower, 'match_groups_now', lambda small, big: refused)   # the unions' match places it nowhere
    assert search_side_groups(grower, group) == 0   # no place to try
    m = PairMatch(3, group.seed, reason='imprecise: the shared walls leave the far corners uncertain by 0.28 m')
    m.transform_m = np.eye(3)
    grower.left_out_imprecise[3] = m
    assert search_side_groups(grower, group) == 2
    assert sorted(group.members) == [0, 1, 2, 3, 4]


def test_a_side_group_whose_maps_each_agree_with_one_member_of_the_merge_joins_where_it_is_precise(monkeypatch):
    """Two maps east of the merge, where only map 0 of the merge reaches: each agrees with that one member and
    contradicts none. One member's word counts where the union's placement is precise (eviction.vouched_for: the
    held-out maze36_v in reverse order, maps 04 and 19 met the merge by map_26 alone, 0.04 m uncertain at the far
    corners; maze36_u's group of four, by one member each, 0.24 m, would have joined 4.7 cells off). Here the union's
    placement is 0.10 m uncertain: out where one witness needs 0.075 m, in where 0.125 m will do."""
    world = stubbed_building()
    grids = [seen(world, 0, 200), seen(world, 0, 120), seen(world, 20, 150), seen(world, 140, 280),
             seen(world, 150, 300)]
    grower, group = _merge_of(grids, [0, 1, 2])
    remember(grower.side_groups, {3: np.eye(3), 4: np.eye(3)})
    assert grower.search_left_out(group) == 0   # each shares less than half its area with the merge
    for k in (3, 4):
        agreeing, contradicting = eviction.judge_members(
            k, np.eye(3), group.members, group.union.footprints, footprint(grids[k], np.eye(3)), grower.prepared,
            grower.s)
        assert agreeing == [0] and contradicting == []
    monkeypatch.setattr(eviction, 'ONE_WITNESS_PRECISION', 0.3)   # 0.075 m
    assert search_side_groups(grower, group) == 0
    monkeypatch.setattr(eviction, 'ONE_WITNESS_PRECISION', 0.5)   # 0.125 m
    assert search_side_groups(grower, group) == 2
    assert sorted(group.members) == [0, 1, 2, 3, 4]
    for k in (3, 4):
        rot, shift = tf.difference(group.members[k], np.eye(3), CORNERS)
        assert rot < 0.01 and shift < 0.1


def test_a_side_group_is_tried_where_a_match_of_the_two_unions_places_it():
    """No member's search placed a member (the held-out courtyard36_v in the given order: maps 01 and 12): the union
    is tried where a match of it onto the merge places it by the growth's rules, and judged there by the module's."""
    grower, group = _hall([(90, 260), (100, 300)])
    grower.left_out_matches.clear()
    grower.left_out_imprecise.clear()
    assert search_side_groups(grower, group) == 2
    assert sorted(group.members) == [0, 1, 2, 3, 4]
    for k in (3, 4):
        rot, shift = tf.difference(group.members[k], np.eye(3), CORNERS)
        assert rot < 0.01 and shift < 0.1
