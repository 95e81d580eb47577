"""split.py: after a member leaves, a group whose members no longer hold together through members that agree as
pairs (the halves a broken seed placed by its two parts) falls apart into them; one that holds together stays."""
import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.split import parts_of, split
from test_eviction import _merge_of, seen, stubbed_building


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
    # the half keeps its own placements, in the frame of its seed
    other = 5 - new[0].seed
    assert np.allclose(new[0].members[other], np.eye(3), atol=1e-9)


def test_a_group_that_holds_together_stays_whole():
    world = stubbed_building()
    grids = [seen(world, 0, 170), seen(world, 0, 120), seen(world, 20, 150), seen(world, 100, 260)]
    grower, group = _merge_of(grids, [0, 1, 2, 3])
    assert len(parts_of(grower, group)) == 1
    assert split(grower, group) == [] and sorted(group.members) == [0, 1, 2, 3]


def test_the_part_with_the_reference_is_kept():
    grower, group = _halves(np.eye(3))
    grower.reference = 3
    new = split(grower, group)
    assert sorted(group.members) == [2, 3] and sorted(new[0].members) == [0, 1]
    assert np.allclose(group.members[group.seed], np.eye(3))   # the kept part's seed frames the group
