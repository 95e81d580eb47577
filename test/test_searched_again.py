"""searched_again.py: a member a search placed is searched again onto the final merge without it; placed elsewhere
by the rules of the maps left out, it moves there, and a member placed right stays. So is a member placed onto a few
maps that the members near it contradict."""
import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.searched_again import in_doubt, search_doubted_again, search_placed_again
from test_eviction import _merge_of, seen, stubbed_building

CORNERS = np.array([[0.0, 0.0], [15.0, 10.0]])


def _merge(placed_3: np.ndarray, searched: bool = True):
    """Maps 0-2 placed right, map 3 placed by `placed_3` (the truth is the identity), as a search placed it or (not
    `searched`) as a match onto a few maps did."""
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150), seen(world, 40, 160)]
    grower, group = _merge_of(grids, [0, 1, 2])
    group.union.add(3, grids[3], grower.prepared[3], placed_3)
    (grower.searched if searched else grower.placed_onto_few).add(3)
    return grower, group


def test_a_searched_member_placed_elsewhere_on_the_final_merge_moves_there():
    grower, group = _merge(tf.rigid(1.5, 0.4, 0.03))
    assert search_placed_again(grower, group) == [3]
    rot, shift = tf.difference(group.members[3], np.eye(3), CORNERS)
    assert rot < 0.01 and shift < 0.1
    assert search_placed_again(grower, group) == []   # now where the search puts it


def test_a_searched_member_placed_right_stays():
    grower, group = _merge(np.eye(3))
    before = group.members[3].copy()
    assert search_placed_again(grower, group) == []
    assert np.allclose(group.members[3], before)


def test_a_member_placed_by_descriptors_is_not_searched_again():
    grower, group = _merge(tf.rigid(1.5, 0.4, 0.03))
    grower.searched.clear()
    assert search_placed_again(grower, group) == []


def test_a_searched_member_placed_elsewhere_that_shares_too_little_there_leaves():
    """Map 3 saw the east of the hall too: at its true place it shares less than half its area with the others."""
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150), seen(world, 100, 300)]
    grower, group = _merge_of(grids, [0, 1, 2])
    group.union.add(3, grids[3], grower.prepared[3], tf.rigid(1.5, 0.4, 0.03))
    grower.searched.add(3)
    assert search_placed_again(grower, group) == [3]
    assert sorted(group.members) == [0, 1, 2] and not grower.refused[3].accepted


def test_a_member_the_search_onto_the_final_merge_finds_two_places_as_good_for_leaves(monkeypatch):
    """Where the search onto the others finds another place as good as the member's (pair.AMBIGUOUS), the merge
    cannot tell where it is: it leaves, with the reason; one whose search is refused for another reason stays."""
    from multirobot_map_merge.estimation.pair import AMBIGUOUS, PairMatch
    for reason, leaves in ((f'{AMBIGUOUS}: another placement agrees 1.00 with support 992 vs 1068', True),
                           ('agreement 0.85 < 0.91', False)):
        grower, group = _merge(np.eye(3))
        monkeypatch.setattr(grower.matcher, 'match_all',
                            lambda calls: [PairMatch(c.i, c.j, reason=reason) for c in calls])
        assert search_placed_again(grower, group) == ([3] if leaves else [])
        assert (3 in group.members) != leaves
        if leaves:
            assert AMBIGUOUS in grower.refused[3].reason and not grower.refused[3].accepted


def test_a_member_placed_onto_a_few_maps_that_the_members_near_it_contradict_is_searched_again():
    """Map 3 joined a group of one or a few maps 1.5 m and 2 degrees off: the members near it contradict it there,
    and the search onto them places it elsewhere (at the truth). Its placement was wrong: it leaves, and does not
    move (the merge may lack the maps at its truth). Placed right, it is not in doubt and stays."""
    from multirobot_map_merge.estimation.searched_again import ELSEWHERE
    grower, group = _merge(tf.rigid(1.5, 0.4, 0.03), searched=False)
    assert in_doubt(grower, group) == [3]
    assert search_doubted_again(grower, group) == [3]
    assert sorted(group.members) == [0, 1, 2]
    assert grower.refused[3].reason == ELSEWHERE and not grower.refused[3].accepted
    grower, group = _merge(np.eye(3), searched=False)
    before = group.members[3].copy()
    assert in_doubt(grower, group) == [] and search_doubted_again(grower, group) == []
    assert np.allclose(group.members[3], before)


def test_a_member_in_doubt_that_leaves_counts_as_evicted_and_the_maps_it_saw_are_searched_again():
    """A member search_doubted_again takes out counts as evicted: a map left out whose last search onto the merge
    found a place over it is searched again, and the member is not (held-out mall36_v, maps in reverse order: map_08
    at an alias made map_01's true place look ambiguous until it left)."""
    from multirobot_map_merge.estimation.union import footprint
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150), seen(world, 40, 160),
             seen(world, 60, 200)]
    grower, group = _merge_of(grids, [0, 1, 2])
    group.union.add(3, grids[3], grower.prepared[3], tf.rigid(1.5, 0.4, 0.03))   # joined a few maps, off
    grower.placed_onto_few.add(3)
    # map 4's last search at the end found a place over member 3, and was refused
    grower.left_out_boxes[4] = footprint(grids[3], group.members[3])
    grower.left_out_members, grower.left_out_evicted = frozenset(group.members), set(grower.evicted)
    grower.left_out_footprints = dict(group.union.footprints)
    assert grower._left_out_todo(group) == []
    assert search_doubted_again(grower, group) == [3] and 3 in grower.evicted
    assert grower._left_out_todo(group) == [4]


def test_a_member_that_joined_a_larger_union_is_not_checked_again():
    """Placed as wrong, but by a match onto more than a few maps (judged on all their walls): not in doubt."""
    grower, group = _merge(tf.rigid(1.5, 0.4, 0.03), searched=False)
    grower.placed_onto_few.clear()
    assert in_doubt(grower, group) == [] and search_doubted_again(grower, group) == []
    assert 3 in group.members
