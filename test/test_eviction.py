"""eviction.py: a member of the merge that the maps left out contradict, while they agree with the other members
(a map broken by a SLAM failure, placed by one of its parts), is singled out; one map's word is not enough."""
import numpy as np

from multirobot_map_merge.estimation.eviction import contradicted_members, judge_members
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.estimation.pair import PairMatch
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.estimation.union import footprint
from multirobot_map_merge.estimation.verify import Placement
from multirobot_map_merge.grid import Grid

RES = 0.05


def building() -> np.ndarray:
    """A 15 m x 10 m hall with its outer walls and two short wall stubs (all free floor inside)."""
    world = np.zeros((200, 300), np.int8)
    world[0, :] = world[-1, :] = world[:, 0] = world[:, -1] = 100
    world[0:60, 100] = world[140:200, 220] = 100
    return world


def seen(world: np.ndarray, c0: int, c1: int) -> Grid:
    data = np.full(world.shape, -1, np.int8)
    data[:, c0:c1] = world[:, c0:c1]
    return Grid(data, RES)


def scene():
    world = building()
    broken = seen(world, 0, 300)
    broken.data[40:160, 160] = 100       # its turned part: a wall across the floor that the others saw free
    grids = [broken, seen(world, 0, 170), seen(world, 130, 300), seen(world, 60, 240), seen(world, 70, 250)]
    prepared = [prepare(g, RES, None) for g in grids]
    members = {0: np.eye(3), 1: np.eye(3), 2: np.eye(3)}
    footprints = {k: footprint(grids[k], t) for k, t in members.items()}
    refused = {k: PairMatch(k, 0, reason='agreement 0.85 < 0.91', best=Placement(np.eye(3), support=800,
                                                                                 overlap_m2=60.0))
               for k in (3, 4)}
    for m in refused.values():
        m.transform_m = np.eye(3)
    return grids, prepared, members, footprints, refused


def test_a_map_left_out_agrees_with_the_members_but_the_broken_one():
    grids, prepared, members, footprints, _ = scene()
    s = EstimationSettings()
    agreeing, contradicting = judge_members(3, np.eye(3), members, footprints, footprint(grids[3], np.eye(3)),
                                            prepared, s)
    assert sorted(agreeing) == [1, 2] and contradicting == [0]


def test_the_member_two_maps_left_out_single_out_leaves_and_one_map_is_not_enough():
    grids, prepared, members, footprints, refused = scene()
    s = EstimationSettings()

    def single_out(left_out, keep=()):
        return contradicted_members(left_out, refused, members, footprints, lambda k, t: footprint(grids[k], t),
                                    prepared, keep, s)
    assert single_out([3, 4]) == [0]
    assert single_out([3]) == []          # two members agree with it: not enough alone
    assert single_out([3, 4], keep=(0,)) == []   # the node's reference robot stays


def test_a_map_whose_match_found_an_alias_is_judged_at_its_other_places():
    """Onto a union of a repetitive building the best place of a map left out can be an alias, the true place,
    contradicted by the broken member, ranked below it (a generated hospital): the members are judged there too."""
    grids, prepared, members, footprints, refused = scene()
    s = EstimationSettings()
    alias = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])   # 3 m along the hall
    for m in refused.values():
        m.transform_m = alias

    def single_out():
        return contradicted_members([3, 4], refused, members, footprints, lambda k, t: footprint(grids[k], t),
                                    prepared, (), s)
    assert single_out() == []            # at the alias the map contradicts more than one member: no one singled out
    for m in refused.values():
        m.other_places_m = [np.eye(3)]
    assert single_out() == [0]
