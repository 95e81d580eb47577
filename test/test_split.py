"""split.py: after a member leaves, a group whose members no longer hold together through members that agree as
pairs (the halves a broken seed placed by its two parts) falls apart into them; one that holds together stays."""
import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.split import parts_of, split
from multirobot_map_merge.estimation.eviction import verified_against
from multirobot_map_merge.grid import Grid
from test_eviction import RES, _merge_of, seen, stubbed_building


def _halves(shift_east: np.ndarray):
    """Maps 0-1 of the west of the hall, maps 2-3 of its east (placed by `shift_east`), no map between them."""
    world = stubbed_building()
    grids = [seen(world, 0, 120), seen(world, 10, 130), seen(world, 180, 300), seen(world, 170, 290)]
    grower, group = _merge_of(grids, [0, 1])
    for k in (2, 3):
        group.union.add(k, grids[k], grower.prepared[k], shift_east)
    return grower, group


def test_a_group_in_two_halves_falls_apart_into_them():
    east = tf.rigid(0.3, -0.2, 0.2)   # turned as a broken seed's other part would have placed them
    grower, group = _halves(east)
    assert parts_of(grower, group) == [{0, 1}, {2, 3}]
    new = split(grower, group)
    assert sorted(group.members) == [0, 1] and len(new) == 1 and sorted(new[0].members) == [2, 3]
    assert grower.split_off == {2, 3}   # let go: searched onto the final merge at the end (estimator.group_mates)
    # the half keeps its own placements, in the frame of its seed
    other = 5 - new[0].seed
    assert np.allclose(new[0].members[other], np.eye(3), atol=1e-9)


def test_a_group_that_holds_together_stays_whole():
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150), seen(world, 100, 260)]
    grower, group = _merge_of(grids, [0, 1, 2, 3])
    assert len(parts_of(grower, group)) == 1
    assert split(grower, group) == [] and sorted(group.members) == [0, 1, 2, 3] and not grower.split_off


def test_the_part_with_the_reference_is_kept():
    grower, group = _halves(np.eye(3))
    grower.reference = 3
    new = split(grower, group)
    assert sorted(group.members) == [2, 3] and sorted(new[0].members) == [0, 1]
    assert np.allclose(group.members[group.seed], np.eye(3))   # the kept part's seed frames the group


def _halves_met_by_few_walls(west: np.ndarray):
    """A hall whose west maps (0: columns 0-190, 1: 0-120) and east maps (2: the north of 160-300, 3: its south, 4:
    200-300) are placed in one group, the west ones by `west`. Map 0 shares with maps 2 and 3 a strip (columns
    160-190) with 45 wall pixels each: too few for a pair to judge, enough for map 0 onto the union of the east."""
    world = np.zeros((200, 300), np.int8)
    world[0, :] = world[-1, :] = world[:, 0] = world[:, -1] = 100
    world[0:60, 100] = world[140:200, 220] = world[0:15, 175] = world[185:200, 175] = 100

    def part(c0, c1, r0=0, r1=200):
        data = np.full(world.shape, -1, np.int8)
        data[r0:r1, c0:c1] = world[r0:r1, c0:c1]
        return Grid(data, RES)
    grids = [part(0, 190), part(0, 120), part(160, 300, 0, 110), part(160, 300, 90, 200), part(200, 300)]
    grower, group = _merge_of(grids, [2, 3, 4])
    for k in (0, 1):
        group.union.add(k, grids[k], grower.prepared[k], west)
    return grower, group


def test_parts_that_meet_where_a_member_passes_alone_onto_the_other_hold_together():
    """As two groups join where a member of one passes alone onto the other's union (growth.joins_where_met), the
    parts stay together when no pair links them but such a member does; placed wrong, they fall apart."""
    grower, group = _halves_met_by_few_walls(np.eye(3))
    s = grower.s
    for east in (2, 3):   # no pair of a west and an east map judges the placement
        c = verified_against(0, np.eye(3), east, np.eye(3), grower.prepared, s)
        assert c.support + c.conflicts < s.min_support
    assert parts_of(grower, group) == [{0, 1, 2, 3, 4}]
    assert split(grower, group) == []
    grower, group = _halves_met_by_few_walls(tf.rigid(0.3, 0.0, 0.0))   # the west 0.3 m off
    assert parts_of(grower, group) == [{2, 3, 4}, {0, 1}]
