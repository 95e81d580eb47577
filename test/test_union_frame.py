"""A union is its members resampled into the frame of its seed: the same walls agree with a map by different amounts
in different frames. A rule as fine as wall for wall (stronger.WEAK_AGREEMENT) is judged on the members one by one
too (eviction.members_agreement), so that which map seeded the growth does not decide it."""
import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.eviction import members_agreement
from multirobot_map_merge.estimation.features import map_keypoints, prepare
from multirobot_map_merge.estimation.growth import Grower
from multirobot_map_merge.estimation.pair import PairMatch
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.estimation.stronger import WEAK_AGREEMENT
from multirobot_map_merge.estimation.union import UnionMap, footprint
from multirobot_map_merge.estimation.verify import verify
from multirobot_map_merge.mapio import load_map

RES = 0.05
MEMBERS = ['map_00', 'map_24', 'map_28']   # the maps map_21 overlaps in classic36's other group
FRAMES = ['map_00', 'map_24', 'map_28', 'map_01', 'map_09', 'map_13', 'map_16']


def _case(repo_root):
    """map_21 and its members (grids), and the true pose in the world of each map of the case."""
    folder = repo_root / 'test' / 'data' / 'classic_bridge'
    case = json.loads((folder / 'case.json').read_text())
    poses = {n: m['pose'] for n, m in case['maps'].items()}
    poses.update({n: m['pose'] for n, m in case['members_of_map_21']['maps'].items()})
    grids = {n: load_map(str(folder / f'{n}.yaml')) for n in ['map_21'] + MEMBERS}
    return grids, {n: tf.rigid(*p) for n, p in poses.items()}


def test_a_map_agrees_with_the_members_one_by_one_whatever_frame_their_union_is_composed_in(repo_root):
    """map_21 at the truth onto members 00, 24 and 28 (0.04 of its area): their union agrees with it by 0.975-1.000
    as it is composed in one map's frame or another's; the members one by one, 1.000 in every frame."""
    grids, world = _case(repo_root)
    s = EstimationSettings(processes=False)
    names = ['map_21'] + MEMBERS
    prepared = [prepare(grids[n], RES, s.feature) for n in names]
    by_union = []
    for frame in FRAMES:
        placed = {k: tf.inverse(world[frame]) @ world[n] for k, n in enumerate(names)}
        union = UnionMap(RES, lambda k, p: map_keypoints(p))
        for k in range(1, len(names)):
            union.add(k, grids[names[k]], prepared[k], placed[k])
        composed = union.prepared()
        by_union.append(verify(prepared[0], composed, tf.inverse(composed.px_to_map) @ placed[0]
                               @ prepared[0].px_to_map, s).agreement)
        pooled = members_agreement(0, placed[0], union.members, union.footprints,
                                   footprint(grids['map_21'], placed[0]), prepared, s)
        assert pooled >= WEAK_AGREEMENT, (frame, pooled)
    assert min(by_union) < WEAK_AGREEMENT <= max(by_union), by_union


def test_a_map_searched_onto_little_of_its_area_waits_unless_the_members_agree_wall_for_wall(repo_root):
    """The growth's search places map_21 onto the group of its three members in map_00's frame, where their union
    agrees with it less than wall for wall: it joins, as the members one by one agree 1.000. Placed 0.3 m along,
    neither the union nor the members agree so, and it waits."""
    grids, world = _case(repo_root)
    s = EstimationSettings(processes=False)
    names = ['map_21'] + MEMBERS
    prepared = [prepare(grids[n], RES, s.feature) for n in names]
    placed = {k: tf.inverse(world['map_00']) @ world[n] for k, n in enumerate(names)}
    grower = Grower([grids[n] for n in names], prepared, RES, s, ThreadPoolExecutor(max_workers=1), None, None)
    group = grower.group_of(1, {k: placed[k] for k in range(1, len(names))})
    union = group.union.prepared()

    def searched(t: np.ndarray) -> PairMatch:
        m = PairMatch(0, 1, accepted=True, best=verify(prepared[0], union, tf.inverse(union.px_to_map) @ t
                                                       @ prepared[0].px_to_map, s))
        m.transform_m, m.searched = t, True
        return m
    right = searched(placed[0])
    assert right.best.agreement < WEAK_AGREEMENT and not grower.shares_enough(0, right.best.overlap_m2)
    assert not grower._searched_onto_little(right, group)
    off = searched(tf.translation(0.3, 0.0) @ placed[0])
    assert grower._searched_onto_little(off, group)
    assert grower.refused[0].reason.startswith('waits: a search placed it')
