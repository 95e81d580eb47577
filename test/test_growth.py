"""Growing the merge: newcomers matched against the union of the placed maps, tracking of previous placements,
and the union's pooled keypoints (estimation/: estimator.py, union.py, tracking.py)."""
import gc
import json
import math

import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.estimator import estimate
from multirobot_map_merge.estimation.features import map_keypoints, pooled_keypoints, prepare
from multirobot_map_merge.estimation.pair import match_pair
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import load_map

EARLY_JOINS_M = 0.4   # max_corner_error_m for the live demos' early maps below (the default is 0.25)


def _sample(repo_root, name):
    folder = repo_root / 'data' / 'samples' / name
    truth = json.loads((folder / 'truth.json').read_text())
    grids = [load_map(str(folder / m['file'])) for m in truth['maps']]
    return grids, [tf.rigid(*m['pose']) for m in truth['maps']]


def _demo_late_group(repo_root):
    """(names, grids, true poses of their map frames) of test/data/demo_late_group, robot_1 to robot_6 in order."""
    folder = repo_root / 'test' / 'data' / 'demo_late_group'
    starts = json.loads((folder / 'start_poses.json').read_text())
    names = sorted(starts)
    return names, [load_map(str(folder / f'{n}.yaml')) for n in names], [tf.rigid(*starts[n]) for n in names]


def _error(estimated: np.ndarray, poses, k: int, ref: int):
    """(degrees, metres) between the estimated placement of map k and the truth, relative to map ref."""
    d = tf.inverse(tf.inverse(poses[ref]) @ poses[k]) @ estimated
    return math.degrees(abs(math.atan2(d[1, 0], d[0, 0]))), float(np.hypot(*d[:2, 2]))


def test_newcomer_too_small_for_any_pair_joins_the_union(repo_root):
    """Map n (data/samples/union_join) overlaps each of a, b and c by less than a pair needs; against their union it
    is placed, within 0.5 degrees and 10 cm, whichever order the maps come in."""
    grids, poses = _sample(repo_root, 'union_join')
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    for j in range(3):
        pair = match_pair(3, j, prepared[3], prepared[j], s)
        assert not pair.accepted, f'map n alone with map {j} should not be enough: {pair.reason}'
    for order in ([0, 1, 2, 3], [3, 2, 1, 0], [1, 3, 0, 2]):
        result = estimate([grids[k] for k in order], s)
        assert all(t is not None for t in result.transforms), order
        ref = order[result.reference]
        at = order.index(3)
        rot, dist = _error(result.transforms[at], poses, 3, ref)
        assert rot < 0.5 and dist < 0.1, (order, rot, dist)


def _rotated(grid: Grid, degrees: float) -> Grid:
    """The same map turned by `degrees` in its own frame (as a SLAM failure would leave it)."""
    turned = tf.rigid(0.0, 0.0, math.radians(degrees)) @ tf.rigid(*grid.origin)
    x, y, yaw, _ = tf.params(turned)
    return Grid(grid.data, grid.resolution, (x, y, yaw), grid.frame_id)


def test_tracking_keeps_placements_and_drops_one_that_no_longer_holds(repo_root):
    grids, poses = _sample(repo_root, 'three_robots')
    s = EstimationSettings()
    fresh = estimate(grids, s, preferred_reference=0)
    assert all(t is not None for t in fresh.transforms)
    # unchanged maps: both other placements are confirmed by tracking and stay where they were
    again = estimate(grids, s, preferred_reference=0, previous=fresh.transforms)
    assert again.tracked == 2 and again.reference == 0
    for k in (1, 2):
        rot, dist = _error(again.transforms[k], poses, k, 0)
        assert rot < 0.5 and dist < 0.1
    # robot 2's map turned by 20 degrees in its frame: its old placement no longer holds and is dropped at once;
    # it is placed again where its turned map belongs, or left out, never where it was
    broken = list(grids)
    broken[2] = _rotated(grids[2], 20.0)
    after = estimate(broken, s, preferred_reference=0, previous=fresh.transforms)
    assert after.tracked == 1
    assert any(p.i == 2 and 'no longer holds' in p.reason for p in after.pairs) or after.transforms[2] is not None
    if after.transforms[2] is not None:
        turned_pose = poses[2] @ tf.inverse(tf.rigid(0.0, 0.0, math.radians(20.0)))
        rot, dist = _error(after.transforms[2], poses[:2] + [turned_pose], 2, 0)
        assert rot < 1.0 and dist < 0.15, (rot, dist)
    rot, dist = _error(after.transforms[1], poses, 1, 0)
    assert rot < 0.5 and dist < 0.1


def test_previous_placements_with_another_reference_are_not_tracked(repo_root):
    grids, _ = _sample(repo_root, 'three_robots')
    s = EstimationSettings()
    fresh = estimate(grids, s, preferred_reference=0)
    other = estimate(grids, s, preferred_reference=1, previous=fresh.transforms)
    assert other.tracked == 0 and other.reference == 1


def test_pooled_keypoints_count_a_corner_seen_twice_once(repo_root):
    grids, _ = _sample(repo_root, 'three_robots')
    p = prepare(grids[0], 0.05, 'akaze')
    own = map_keypoints(p)
    alone, _, _ = pooled_keypoints([(*own, np.eye(3))], p.px_to_map, p.work.shape)
    twice, descriptors, _ = pooled_keypoints([(*own, np.eye(3)), (*own, np.eye(3))], p.px_to_map, p.work.shape)
    assert len(alone) == len(p.keypoints) and len(twice) == len(alone) and len(descriptors) == len(twice)
    # the same map placed 5 m further along x brings those of its keypoints into the union that land in it
    shift_px = 5.0 / p.resolution
    shifted, _, _ = pooled_keypoints([(*own, tf.translation(5.0, 0.0))], p.px_to_map, p.work.shape)
    expected = alone[alone[:, 0] + shift_px < p.work.shape[1]] + (shift_px, 0.0)
    assert 0 < len(shifted) < len(alone)
    assert np.allclose(np.sort(shifted[:, 0]), np.sort(expected[:, 0]), atol=1e-6)


@pytest.mark.parametrize('name', ['three_robots', 'chain3'])
def test_growth_places_the_samples_in_any_order(repo_root, name):
    grids, poses = _sample(repo_root, name)
    for order in ([0, 1, 2], [2, 1, 0], [1, 2, 0]):
        result = estimate([grids[k] for k in order], EstimationSettings())
        ref = order[result.reference]
        for i, k in enumerate(order):
            assert result.transforms[i] is not None, (order, k)
            rot, dist = _error(result.transforms[i], poses, k, ref)
            assert rot < 0.5 and dist < 0.15, (order, k, rot, dist)


def test_estimation_reports_progress_up_to_every_map(repo_root):
    grids, _ = _sample(repo_root, 'three_robots')
    seen = []
    estimate(grids + [None], EstimationSettings(), progress=lambda done, total: seen.append((done, total)))
    assert seen and seen[-1] == (3, 3) and all(a <= b for (a, _), (b, _) in zip(seen, seen[1:]))


def _cut(grid: Grid, share: float) -> Grid:
    """The map as it was before its last rows of known cells were seen: about `share` of its known cells unknown."""
    data = grid.data.copy()
    known_per_row = (data >= 0).sum(axis=1)
    rows = np.flatnonzero(np.cumsum(known_per_row[::-1]) <= share * known_per_row.sum())
    data[grid.height - 1 - rows] = -1
    return Grid(data, grid.resolution, grid.origin, grid.frame_id)


def test_a_confirmed_placement_is_checked_again_when_the_maps_around_it_have_changed(repo_root, monkeypatch):
    """Tracking's memory: a verdict on a placement stands while its map has barely changed, also while the maps
    near it change; it is made once more when the maps it saw have stopped changing (the merge a run ends with
    rests on the final maps); a large change of its own map makes it again at once."""
    from multirobot_map_merge.estimation import tracking
    from multirobot_map_merge.estimation.memory import GROWTH, EstimationMemory
    grids, _ = _sample(repo_root, 'three_robots')
    s, memory, names = EstimationSettings(), EstimationMemory(), ['a', 'b', 'c']
    checked = []
    real_recheck = tracking.recheck
    monkeypatch.setattr(tracking, 'recheck', lambda k, *args: checked.append(k) or real_recheck(k, *args))
    state = {'previous': None}

    def rechecks(maps):
        checked.clear()
        result = estimate(maps, s, preferred_reference=0, previous=state['previous'], memory=memory, names=names)
        assert all(t is not None for t in result.transforms)
        state['previous'] = result.transforms
        return sorted(set(checked))

    small = [grids[0], _cut(grids[1], GROWTH / 3), grids[2]]
    # the first estimation places b and c for the first time: the next one confirms them (confirmation.py)
    first = estimate(small, s, preferred_reference=0, previous=[None] * 3, memory=memory, names=names)
    assert first.held == 2
    state['previous'] = first.transforms
    assert rechecks(small) == [0, 1, 2]    # no verdict yet: every placement is checked
    assert rechecks(small) == []           # nothing changed: the verdicts stand
    assert rechecks(grids) == []           # map b grew a little and may grow on: they still stand
    assert rechecks(grids) == [0, 1, 2]    # map b has stopped changing: the verdicts that saw it are made again
    assert rechecks(grids) == []
    assert rechecks([grids[0], _cut(grids[1], 2 * GROWTH), grids[2]]) == [1]   # b lost cells it knew
    assert rechecks(grids) == [1]          # b grew by more than GROWTH: made again at once; a and c wait
    assert rechecks(grids) == []           # ... and saw this map b before: theirs stand


def test_the_reference_moves_the_others_only_by_more_than_its_shared_walls_leave_open():
    """Re-anchoring: the reference grid, checked against the other placed grids, fits them elsewhere; the others
    move by the inverse of that fit when the move at its corners is larger than twice the error its shared walls
    leave there, and stay when it is within it (a small map's wobble, not an early misplacement)."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.tracking import Check, reanchoring
    from multirobot_map_merge.estimation.verify import Placement
    box = (0.0, 0.0, 10.0, 8.0)
    off = tf.rigid(0.05, -0.02, math.radians(0.8))     # 13 cm at the far corner
    for expected, moves in ((0.02, True), (0.05, True), (0.10, False), (0.30, False)):
        match = PairMatch(0, 1)
        match.best = Placement(np.eye(3), corner_error_m=expected)
        found = reanchoring(Check(0, off, match), box)
        assert (found is not None) == moves, (expected, found)
        if found is not None:
            assert np.allclose(found[0] @ off, np.eye(3))
            assert found[1] == pytest.approx(0.8, abs=1e-6)
    match = PairMatch(0, 1)
    match.best = Placement(np.eye(3), corner_error_m=0.0)
    assert reanchoring(Check(0, tf.rigid(0.01, 0.0, 0.0), match), box) is None   # below REANCHOR_M


def _group_unions(repo_root):
    """Unions of two groups of a live demo (world seed 0, seed 4, 33 sim s), each composed at the robots' true poses
    in the world frame, so the truth between them is the identity: a (robots 1, 2, 5), b (robots 3, 4, 6) and c
    (robots 3, 4). They share 10 m2 of a corridor; the building repeats itself along it."""
    folder = repo_root / 'test' / 'data' / 'demo_group_unions'
    s = EstimationSettings()
    return s, {k: prepare(load_map(str(folder / f'union_{k}.yaml')), 0.05, s.feature) for k in 'abc'}


def _off(m):
    """(degrees, metres at 5 m) of a match's placement from the identity."""
    rot, shift = tf.difference(m.transform_m, np.eye(3), np.array([[0.0, 0.0], [5.0, 5.0]]))
    return math.degrees(abs(rot)), shift


def test_two_groups_are_searched_although_their_descriptors_found_a_contradicting_overlap(repo_root):
    """Descriptors place union b half a turn away at the far end of the corridor, over 30 m2 agreeing 0.67: for a
    single map that says where it overlaps and that it contradicts there (a broken map), so no search follows. Two
    groups are searched anyway (as growth.py matches groups), and the search places them right."""
    s, u = _group_unions(repo_root)
    kept = match_pair(0, 1, u['b'], u['a'], s, onto_union=True)
    assert not kept.accepted and 'agreement' in kept.reason and _off(kept)[1] > 10.0
    searched = match_pair(0, 1, u['b'], u['a'], s, onto_union=True, between_groups=True)
    assert searched.accepted, searched.reason
    rot, shift = _off(searched)
    assert rot < 1.0 and shift < 0.15


def test_a_search_candidate_that_icp_leaves_half_a_metre_off_is_polished_into_place(repo_root, monkeypatch):
    """Searched onto union a, union c's best candidates settle 1.5 degrees and 0.45 m off, where part of the walls
    disagree (agreement 0.77). Between groups, polished when no candidate passes, the place passes, near the
    truth; without that the pair is refused."""
    import multirobot_map_merge.estimation.pair as pair
    s, u = _group_unions(repo_root)
    rescued = match_pair(0, 1, u['c'], u['a'], s, onto_union=True, descriptors=False, between_groups=True)
    assert rescued.accepted, rescued.reason
    rot, shift = _off(rescued)
    assert rot < 1.0 and shift < 0.15
    monkeypatch.setattr(pair, 'RESCUE_PLACES', 0)
    unpolished = match_pair(0, 1, u['c'], u['a'], s, onto_union=True, descriptors=False, between_groups=True)
    assert not unpolished.accepted and 'agreement' in unpolished.reason


def test_a_grid_blind_to_a_union_is_matched_again_only_for_new_members_its_descriptors_agree_with(repo_root):
    """A grid whose descriptors found no candidate on a union is matched against it again only when a new member's
    descriptors hold a rigid model with its own: two overlapping sample maps do, a map of random walls with none."""
    from concurrent.futures import ThreadPoolExecutor

    from multirobot_map_merge.estimation.growth import Grower
    grids, _ = _sample(repo_root, 'three_robots')
    rng = np.random.default_rng(3)
    noise = np.where(rng.random(grids[0].data.shape) < 0.02, 100, 0).astype(np.int8)
    grids = [grids[0], grids[1], Grid(noise, grids[0].resolution, grids[0].origin)]
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    with ThreadPoolExecutor(2) as pool:
        grower = Grower(grids, prepared, 0.05, s, pool, None, None)
        assert grower._descriptors_agree(0, 1)
        assert not any(grower._descriptors_agree(a, b) for a, b in ((0, 2), (2, 0), (1, 2), (2, 1)))


def test_what_was_tried_against_a_group_that_has_gone_does_not_count_for_a_new_one(repo_root):
    """The growth keeps which grid was matched against which group's union; a group that has gone (absorbed by
    another) leaves its id to the next object made, and a new group seeded there counted the gone one's matches as
    its own (hospital36: two groups so, out of 52), so a grid was not matched against it. Here new groups are made
    until one gets the id of a group matched against and dropped: grid 2 is still worth matching against it."""
    from multirobot_map_merge.estimation.memory import EstimationMemory
    from multirobot_map_merge.estimation.pair import PairMatch
    grids, _ = _sample(repo_root, 'three_robots')
    grower = _grower_of(grids, EstimationSettings())
    grower.match = lambda group, ks, search: [PairMatch(k, group.seed, reason='no rigid model') for k in ks]
    reused, gone_ids = None, set()
    for _ in range(200):   # CPython gives a freed object's memory to a later one of its size
        grower.memory = EstimationMemory()   # what earlier groups of grid 0 alone were tried against: forgotten
        gone = grower.group(0)
        grower.grow(gone, [2], search=False)
        assert not grower._worth_matching(2, gone)
        gone_ids.add(id(gone))
        del gone
        gc.collect()
        new = grower.group(1)
        if id(new) in gone_ids:
            reused = new
            break
    assert reused is not None, 'no group got the id of one that had gone'
    assert grower._worth_matching(2, reused)


def test_kept_placements_give_way_once_to_an_estimate_afresh_from_the_final_maps(repo_root, monkeypatch):
    """Tracking checks each placement against the maps near it, so small turns between neighbours can add up; once
    the maps stop changing, the kept placements are compared once with an estimate afresh from those final maps (in
    the estimation after the one that checks them on those maps), which replaces them when it moves one by more than
    the noise (it places every map they did, same frame). The verdicts on the placements it did not move stand."""
    from multirobot_map_merge.estimation import estimator, tracking
    from multirobot_map_merge.estimation.memory import EstimationMemory
    from multirobot_map_merge.estimation.pair import PairMatch
    grids, poses = _sample(repo_root, 'three_robots')
    s, memory, names = EstimationSettings(), EstimationMemory(), ['a', 'b', 'c']
    fresh = estimate(grids, s, preferred_reference=0)
    runs = []
    real = estimator._estimate
    monkeypatch.setattr(estimator, '_estimate', lambda *args: runs.append(args[4] is None) or real(*args))
    # checks that confirm whatever they are given, as neighbour checks can confirm a chain that turns a little
    rechecked = []
    monkeypatch.setattr(tracking, 'recheck', lambda k, grids, prepared, placed, *rest: rechecked.append(k) or
                        tracking.Check(k, placed[k], PairMatch(k, 0, accepted=True)))
    # nor are they refined together (relax.py would turn c back): the estimate afresh is what this is about
    monkeypatch.setattr(tracking, 'relax', lambda *args, **kwargs: None)
    previous = list(fresh.transforms)
    previous[2] = tf.rigid(0.0, 0.0, math.radians(1.0)) @ previous[2]   # map c kept 1 degree off
    previous[1] = tf.rigid(0.02, 0.0, 0.0) @ previous[1]   # and map b 2 cm, within the noise
    kept = estimate(grids, s, preferred_reference=0, previous=previous, memory=memory, names=names)
    assert runs == [False] and kept.tracked == 2
    assert np.allclose(kept.transforms[2], previous[2])
    # the same maps again: they have stopped changing; tracking checks the placements on these final maps
    runs.clear()
    checked = estimate(grids, s, preferred_reference=0, previous=kept.transforms, memory=memory, names=names)
    assert runs == [False] and np.allclose(checked.transforms[2], previous[2])
    # and once more: now the estimate afresh runs and replaces the kept placements
    runs.clear()
    final = estimate(grids, s, preferred_reference=0, previous=checked.transforms, memory=memory, names=names)
    assert runs == [False, True] and final.reference == 0
    # seeded as merge_maps seeds, restated in the kept frame
    afresh = tf.relative_to(estimate(grids, s).transforms, 0)
    for k in range(3):
        assert np.allclose(final.transforms[k], afresh[k], atol=1e-9), k
    rot, dist = _error(final.transforms[2], poses, 2, 0)
    assert rot < 0.5 and dist < 0.1
    # only once for these maps; the verdict on map b, which the estimate afresh moved within the noise, stands for
    # its new placement, and only map c is checked again
    runs.clear()
    rechecked.clear()
    again = estimate(grids, s, preferred_reference=0, previous=final.transforms, memory=memory, names=names)
    assert runs == [False] and np.allclose(again.transforms[2], afresh[2])
    assert rechecked == [2]


def test_an_estimate_afresh_that_fits_the_walls_worse_does_not_replace_the_kept_placements(repo_root, monkeypatch):
    """The estimate afresh can be the worse one (a live 12-robot run's turned a group by 0.2 degrees, 20 cm, and
    replaced placements that were right, until the maps changed again): it replaces kept placements it moves beyond
    the noise only when the walls of their pairs fit better."""
    import dataclasses
    from multirobot_map_merge.estimation import estimator
    from multirobot_map_merge.estimation.memory import EstimationMemory
    grids, poses = _sample(repo_root, 'three_robots')
    s, memory, names = EstimationSettings(), EstimationMemory(), ['a', 'b', 'c']
    right = estimate(grids, s, preferred_reference=0)
    real = estimator._estimate
    runs = []

    def turned_afresh(*args):
        out = real(*args)
        runs.append(args[4] is None)
        if args[4] is None:   # the estimate afresh: map c turned 1 degree about its own origin
            transforms = list(out.transforms)
            transforms[2] = transforms[2] @ tf.rigid(0.0, 0.0, math.radians(1.0))
            out = dataclasses.replace(out, transforms=transforms)
        return out
    monkeypatch.setattr(estimator, '_estimate', turned_afresh)
    previous = list(right.transforms)
    for _ in range(3):   # placed, checked on the final maps, then compared with the estimate afresh
        result = estimate(grids, s, preferred_reference=0, previous=previous, memory=memory, names=names)
        previous = list(result.transforms)
    assert runs == [False, False, False, True]
    rot, dist = _error(result.transforms[2], poses, 2, 0)
    assert rot < 0.3 and dist < 0.1, (rot, dist)   # the estimate afresh put it 1 degree off


@pytest.mark.parametrize('turned', [False, True])
def test_a_grid_only_the_estimate_afresh_places_joins_the_kept_placements(repo_root, monkeypatch, turned):
    """When the kept placements and the estimate afresh from the final maps each place a grid the other does not,
    the kept ones stand and the grid only the estimate afresh placed joins them where the kept grids near it agree
    (before, it stayed out for good once the maps had stopped changing); placed afresh a quarter turn off, it stays
    out."""
    import dataclasses
    from multirobot_map_merge.estimation import estimator
    from multirobot_map_merge.estimation.memory import EstimationMemory
    grids, poses = _sample(repo_root, 'three_robots')
    s, memory, names = EstimationSettings(), EstimationMemory(), ['a', 'b', 'c']
    right = estimate(grids, s, preferred_reference=0)
    assert all(t is not None for t in right.transforms)
    real = estimator._estimate
    runs = []

    def each_lacking_one(*args):
        out = real(*args)
        runs.append(args[4] is None)
        transforms = list(out.transforms)
        transforms[1 if args[4] is None else 2] = None   # afresh without map b; kept without map c
        if args[4] is None and turned:
            transforms[2] = transforms[2] @ tf.rigid(0.0, 0.0, math.pi / 2)
        return dataclasses.replace(out, transforms=transforms)
    monkeypatch.setattr(estimator, '_estimate', each_lacking_one)
    previous = [right.transforms[0], right.transforms[1], None]
    for _ in range(3):   # placed, checked on the final maps, then compared with the estimate afresh
        result = estimate(grids, s, preferred_reference=0, previous=previous, memory=memory, names=names)
        previous = list(result.transforms)
    assert runs == [False, False, False, True]
    assert result.transforms[1] is not None   # kept
    # map c placed for the first time here: held until a later estimation confirms it (confirmation.py)
    held = memory.held.get('c')
    if turned:
        assert held is None and result.transforms[2] is None
        return
    assert held is not None
    rot, dist = _error(held.transform, poses, 2, 0)
    assert rot < 0.3 and dist < 0.1, (rot, dist)


@pytest.mark.parametrize('afresh_right', [True, False])
def test_the_estimate_afresh_stands_where_the_kept_placements_contradict_what_only_it_places(repo_root, monkeypatch,
                                                                                             afresh_right):
    """When the kept placements and the estimate afresh each place a grid the other does not and disagree on a grid
    both place, the estimate afresh stands if the kept placements contradict the grids only it placed while the
    grids only they hold agree with it; else the kept placements stand. The live replay of the generated pillar
    hall ended with three maps 5.3 m off (two groups joined a pillar's period apart on early maps): the final maps
    estimated afresh placed them right and five more, which those three contradicted, and the kept placements
    stood. Here map a is placed only by the kept placements, maps d and e (the halves of map c, the reference) only
    afresh, and one side places map b a quarter turn off, the other right; afresh, that side places map d with b
    and not map e: the kept placements contradict one map placed afresh, too few to overrule them."""
    import dataclasses
    from multirobot_map_merge.estimation import estimator
    from multirobot_map_merge.estimation.memory import EstimationMemory
    grids, poses = _sample(repo_root, 'three_robots')
    halves = [grids[2].data.copy(), grids[2].data.copy()]
    halves[0][:, :grids[2].width // 2] = -1
    halves[1][:, grids[2].width // 2:] = -1
    grids = grids + [Grid(h, grids[2].resolution, grids[2].origin) for h in halves]
    poses = poses + [poses[2], poses[2]]
    s, memory, names = EstimationSettings(), EstimationMemory(), ['a', 'b', 'c', 'd', 'e']
    right = estimate(grids, s, preferred_reference=2)
    assert right.reference == 2 and all(t is not None for t in right.transforms)
    centre = right.transforms[1] @ grids[1].cell_to_map() @ np.array([grids[1].width / 2, grids[1].height / 2, 1.0])
    quarter = tf.translation(*centre[:2]) @ tf.rigid(0.0, 0.0, math.pi / 2) @ tf.translation(*-centre[:2])
    real = estimator._estimate
    runs = []

    def disputed(*args):
        out = real(*args)
        afresh = args[4] is None
        runs.append(afresh)
        transforms = list(right.transforms)
        for k in (0,) if afresh else (3, 4):   # a kept only, d and e afresh only
            transforms[k] = None
        if afresh != afresh_right:   # the wrong side: map b a quarter turn off (afresh, map d with it, not e)
            for k in (1, 3) if afresh else (1,):
                transforms[k] = quarter @ transforms[k]
            if afresh:
                transforms[4] = None
        return dataclasses.replace(out, transforms=transforms, reference=2)
    monkeypatch.setattr(estimator, '_estimate', disputed)
    previous = list(right.transforms[:3]) + [None, None]
    for _ in range(3):   # placed, checked on the final maps, then compared with the estimate afresh
        result = estimate(grids, s, preferred_reference=2, previous=previous, memory=memory, names=names)
        previous = list(result.transforms)
    assert runs == [False, False, False, True]
    # map a, kept only, stays either way; map b is where the side that stands put it, or held there (placed anew)
    assert result.transforms[0] is not None
    held = memory.held.get('b')
    placed_b = held.transform if held is not None else result.transforms[1]
    rot, dist = _error(placed_b, poses, 1, 2)
    assert rot < 0.3 and dist < 0.1, (rot, dist)


def test_a_group_grown_after_an_earlier_one_is_matched_against_it(repo_root):
    """The six maps of a live demo at 15 sim s (seed 1): robots 4 and 6 pair by descriptors and, the largest group
    then, search the others in vain; robots 1-3 grow next around the reference, robot 3, and overlap 4 and 6 by
    10 m2. The two groups are matched with each other, so 4 and 6 (and robot 5, which needs their walls) join in
    this estimation, each right; before, they waited for the next one."""
    names, grids, poses = _demo_late_group(repo_root)
    ref = names.index('robot_3')
    # the joins of these early maps (10-13 m2 each) leave the far corners 0.30-0.33 m uncertain, over the default
    # bound since the precision rule's calibration (bench/calibrate_precision.py): with a laxer bound, they test
    # the matching of the two groups
    found = estimate(grids, EstimationSettings(max_corner_error_m=EARLY_JOINS_M), preferred_reference=ref)
    assert found.reference == ref
    placed = {names[k] for k, t in enumerate(found.transforms) if t is not None}
    assert {'robot_4', 'robot_6'} <= placed, placed
    for k, t in enumerate(found.transforms):
        if t is not None:
            rot, shift = _error(t, poses, k, ref)
            assert rot < 1.0 and shift < 0.15, (names[k], rot, shift)


def test_a_placement_tracking_drops_is_searched_again_at_once(repo_root):
    """A robot's early map that only the correlation search places onto the union of four others (live demo, seed
    2). Tracking drops its placement when that is off (here shifted by 1 m); the robot goes back to the search in
    the same estimation, although memory remembers the search that placed it and neither map has changed."""
    from multirobot_map_merge.estimation.memory import EstimationMemory
    folder = repo_root / 'test' / 'data' / 'demo_early_small_map'
    grids = [load_map(str(folder / f'{n}.yaml')) for n in ('union', 'robot_1')]
    # its placement leaves the far corners 0.37 m uncertain: see test_a_group_grown_after_an_earlier_one_...
    s, memory, names = EstimationSettings(max_corner_error_m=EARLY_JOINS_M), EstimationMemory(), ['union', 'robot_1']
    estimate(grids, s, preferred_reference=0, previous=[None, None], memory=memory, names=names)
    placed = memory.held['robot_1'].transform   # placed for the first time: held until confirmed (confirmation.py)
    off = tf.rigid(1.0, 0.0, 0.0) @ placed
    again = estimate(grids, s, preferred_reference=0, previous=[np.eye(3), off], memory=memory, names=names)
    assert again.tracked == 0 and again.transforms[1] is not None
    rot, shift = _error(again.transforms[1], [np.eye(3), placed], 1, 0)
    assert rot < 0.5 and shift < 0.1, (rot, shift)


def test_a_grid_found_to_contradict_some_members_is_not_searched_against_their_grown_union(repo_root):
    """A grid whose descriptors found where it overlaps a member and contradicts it there (a broken map) is not
    searched against the union once it has grown, even when its last match onto the grown union found no candidate
    (the new members' descriptors crowd its ratio test: 4 of the 36 generated maps); a search would find the same
    contradiction. A grid with no such evidence is searched."""
    from concurrent.futures import ThreadPoolExecutor

    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    grids, poses = _sample(repo_root, 'three_robots')
    grids = grids + [grids[2], grids[2]]   # 3 and 4: stand-ins for grids the union does not place
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    contradicting = Placement(np.eye(3), support=900, agreement=0.97, overlap_m2=30.0, deep_conflicts=40)
    with ThreadPoolExecutor(2) as pool:
        grower = Grower(grids, prepared, 0.05, s, pool, None, None)
        group = grower.group(0)
        grower._admit(group, [3], [PairMatch(3, 0, reason='deep conflicts', best=contradicting)])
        group.union.add(1, grids[1], prepared[1], tf.inverse(poses[0]) @ poses[1])
        unplaced = [3, 4]
        grower._admit(group, unplaced, [PairMatch(k, 0, reason='no rigid model') for k in unplaced])
        searched = []
        grower.match = lambda g, ks, search: [searched.append(k) or PairMatch(k, g.seed, reason='none') for k in ks]
        assert not grower._search(group, unplaced)
    assert searched == [4]


@pytest.mark.parametrize('agreement, pooled, share, joins', [(0.985, 0.985, 0.2, False), (1.0, 1.0, 0.2, True),
                                                          (0.985, 0.985, 0.6, True), (1.0, 0.936, 0.2, False),
                                                          (0.970, 0.995, 0.2, True)])
def test_a_grid_a_search_placed_on_a_small_part_of_it_joins_only_where_the_members_agree_wall_for_wall(
        repo_root, monkeypatch, agreement, pooled, share, joins):
    """A match that a correlation search found (the grid's descriptors found no place) on less than half of the
    grid's known area joins only where the members it lands on, each in its own pixels, agree 0.99 or better with it,
    however well their union agrees; otherwise it waits, without counting as a contradiction (held-out maze36_u:
    broken map_03 joined so, 63 degrees off, agreeing 0.982 over 0.19 of its area; maze36_v: map_31 half a turn off,
    0.991 with the union, 0.936 with the members). A descriptor match, or a search placement over more of the grid,
    joins as before."""
    from concurrent.futures import ThreadPoolExecutor

    from multirobot_map_merge.estimation import growth
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    monkeypatch.setattr(growth, 'members_agreement', lambda *args, **kwargs: pooled)
    grids, poses = _sample(repo_root, 'three_robots')
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    area = prepared[2].known_pixels * prepared[2].resolution ** 2
    best = Placement(np.eye(3), support=300, agreement=agreement, overlap_m2=share * area)
    for searched in (True, False):
        with ThreadPoolExecutor(2) as pool:
            grower = Grower(grids, prepared, 0.05, s, pool, None, None)
            group = grower.group(0)
            group.union.add(1, grids[1], prepared[1], tf.inverse(poses[0]) @ poses[1])
            m = PairMatch(2, 0, accepted=True, best=best, searched=searched)
            m.transform_m = tf.inverse(poses[0]) @ poses[2]
            unplaced = [2]
            assert grower._admit(group, unplaced, [m]) == (joins or not searched)
        assert (2 in group.members) == (joins or not searched)
        if searched and not joins:
            assert grower.refused[2].reason.startswith('waits: a search placed it') and 2 not in grower.contradicting


def test_a_match_that_found_a_contradicting_overlap_keeps_the_grid_from_the_search_in_later_estimations(repo_root):
    """A live node's memory: a grid whose descriptor match found where it overlaps the union and contradicts it there
    (a broken map) is not searched in the next estimation either, while neither has changed enough for that match
    to be made again (a 30-robot reveal searched each broken map in the estimation after each such match: 50
    searches, 27 now). A grid whose match found no overlap is searched."""
    from concurrent.futures import ThreadPoolExecutor

    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.memory import EstimationMemory
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    grids, poses = _sample(repo_root, 'three_robots')
    grids = grids + [grids[2], grids[2]]   # 3 and 4: stand-ins for grids the union does not place
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    memory, names = EstimationMemory(), ['a', 'b', 'c', 'broken', 'other']
    contradicting = Placement(np.eye(3), support=900, agreement=0.97, overlap_m2=30.0, deep_conflicts=40)
    refusals = {3: PairMatch(3, 0, reason='deep conflicts', best=contradicting),
                4: PairMatch(4, 0, reason='no rigid model')}
    calls = []
    with ThreadPoolExecutor(2) as pool:
        for estimation in range(2):
            grower = Grower(grids, prepared, 0.05, s, pool, 0, None, memory, names)
            group = grower.group(0)
            group.union.add(1, grids[1], prepared[1], tf.inverse(poses[0]) @ poses[1])
            grower.match = lambda g, ks, search, n=estimation: [
                calls.append((n, k, search)) or (PairMatch(k, g.seed, reason='none') if search else refusals[k])
                for k in ks]
            grower.grow(group, [3, 4])
    # the first estimation matches both and searches only the grid without a found overlap, as the second does
    assert calls == [(0, 3, False), (0, 4, False), (0, 4, True)], calls


def test_a_pair_refusal_counts_as_a_found_overlap_only_by_the_rule_for_pairs(repo_root):
    """Final maps of a live demo run (demo_lost_robot) with the correlation search scored as in earlier versions:
    robot_2, searched against robot_1 alone, is refused with support and agreement (511, 0.68) that would count as a
    found overlap onto a union of maps, not for a pair. Judged by the rule for the match it came from, that refusal
    does not keep robot_2 from the search onto the union of robot_1 and robot_3 once robot_3 has joined, which
    places it right (judged by the rule for unions, it did)."""
    folder = repo_root / 'test' / 'data' / 'demo_lost_robot'
    starts = json.loads((folder / 'start_poses.json').read_text())
    names = ['robot_1', 'robot_2', 'robot_3']
    grids = [load_map(str(folder / f'{n}.yaml')) for n in names]
    found = estimate(grids, EstimationSettings(search_penalty=1.0, search_free_reward=0.0), preferred_reference=0)
    assert found.transforms[1] is not None
    rot, shift = _error(found.transforms[1], [tf.rigid(*starts[n]) for n in names], 1, 0)
    assert rot < 0.5 and shift < 0.1, (rot, shift)


def _grower_of(grids, s):
    from concurrent.futures import ThreadPoolExecutor
    from multirobot_map_merge.estimation.growth import Grower
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    return Grower(grids, prepared, 0.05, s, ThreadPoolExecutor(max_workers=2), 0, None)


def _three_placed_and_three_more(repo_root, placed: str, more: str):
    """A grower of the three maps of sample `placed` and then those of sample `more`, and a group of the first three
    placed by their truth."""
    grids, poses = _sample(repo_root, placed)
    grower = _grower_of(grids + _sample(repo_root, more)[0], EstimationSettings())
    group = grower.group(0)
    for k in (1, 2):
        group.union.add(k, grids[k], grower.prepared[k], tf.inverse(poses[0]) @ poses[k])
    return grower, group


@pytest.mark.parametrize('shift_m', [0.0, 0.4])
def test_a_search_placement_the_final_merge_contradicts_leaves_it(repo_root, shift_m):
    """Robot 2 placed by a search, at the truth or slid by 0.4 m (as a search onto an early union can leave a map
    along a corridor): judged against the others as they are at the end, the right one stays, the slid one leaves
    the merge, reported with the reason, and its link is gone."""
    grids, poses = _sample(repo_root, 'three_robots')
    s = EstimationSettings()
    grower = _grower_of(grids, s)
    group = grower.group(0)
    for k in (1, 2):
        placement = tf.inverse(poses[0]) @ poses[k]
        if k == 2:
            placement = tf.rigid(shift_m, -shift_m, 0.0) @ placement
        group.union.add(k, grids[k], grower.prepared[k], placement)
    grower.searched.add(2)
    grower.confirm_searches(group)
    if shift_m:
        assert set(group.members) == {0, 1}
        assert 'contradicts the placement a search found' in grower.refused[2].reason
    else:
        assert set(group.members) == {0, 1, 2}, grower.refused.get(2)


def _joined_by_a_search(repo_root, s, share, shift_m=0.0):
    """Sample three_robots: robots 0 and 1 placed by their truth, robot 2 joined by a search on `share` of its known
    area (at the truth, or slid by shift_m), then the members a search placed on little of their maps set aside:
    (grower, group, set aside, poses, robot 2's match)."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    grids, poses = _sample(repo_root, 'three_robots')
    grower = _grower_of(grids, s)
    group = grower.group(0)
    group.union.add(1, grids[1], grower.prepared[1], tf.inverse(poses[0]) @ poses[1])
    area = grower.prepared[2].known_pixels * grower.prepared[2].resolution ** 2
    m = PairMatch(2, 0, accepted=True, searched=True,
                  best=Placement(np.eye(3), support=300, agreement=1.0, overlap_m2=share * area))
    m.transform_m = tf.rigid(shift_m, -shift_m, 0.0) @ tf.inverse(poses[0]) @ poses[2]
    grower._join(group, m)
    grower.searched.add(2)
    return grower, group, grower.set_aside_weak(group), poses, m


@pytest.mark.parametrize('share, shift_m, found_m, set_aside, back', [
    (0.2, 0.0, 0.0, True, True), (0.2, 0.4, 0.4, True, False), (0.6, 0.4, 0.4, False, False),
    (0.2, 0.0, None, True, True), (0.2, 0.0, 3.0, True, False)])
def test_a_member_a_search_placed_on_little_of_its_map_is_set_aside_for_the_end_and_judged_again_at_its_place(
        repo_root, share, shift_m, found_m, set_aside, back):
    """Robot 2 joined by a search on `share` of its known area (at the truth, or slid by 0.4 m): on less than half
    of it, it is taken out of the merge for the end's searches and comes back at its place only where its search onto
    the final merge put it nowhere else (`found_m` from the truth, None: no place; the held-out maze36_w, seed 1:
    map_08, placed by the growth's search on 0.10 of its area a quarter turn off, was put 34 m from there), the merge
    passes it there and the members agree with it wall for wall (the slid one stays out); on more, it stays."""
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, group, weak, poses, m = _joined_by_a_search(repo_root, EstimationSettings(), share, shift_m)
    assert (2 not in group.members) == set_aside and (2 in grower.evicted) == set_aside
    if not set_aside:
        assert weak == {}
        return
    if found_m is not None:
        # what the end's search of it (search_left_out's readmit) found: refused for the share, as at first
        again = PairMatch(2, 0, reason='shares too little', best=m.best)
        again.transform_m = tf.rigid(found_m, -found_m, 0.0) @ tf.inverse(poses[0]) @ poses[2]
        grower.refused[2] = again
    joined = grower.readmit_weak(group, weak)
    assert (joined == [2]) == back and (2 in group.members) == back and (2 in grower.evicted) != back
    if back:
        degrees, metres = _error(group.members[2], poses, 2, 0)
        assert degrees < 0.01 and metres < 0.01


@pytest.mark.parametrize('budget_s', [0.0, math.inf])
def test_a_member_set_aside_waits_for_a_later_estimation_once_the_search_budget_is_spent(repo_root, budget_s):
    """readmit_weak's search for another place of a member set aside counts against the search budget like every
    other search: with the budget spent, robot 2 (joined by a search on 0.2 of its area, at the truth) is not searched
    and so not taken back unsearched; it stays out and the search counts as postponed (a later estimation, with a
    larger budget, makes it). With budget to spare it joins again, and the search's time is counted."""
    grower, group, weak, _, _ = _joined_by_a_search(repo_root, EstimationSettings(search_budget_s=budget_s), 0.2)
    assert 2 in weak
    joined = grower.readmit_weak(group, weak)
    spent = budget_s == 0.0
    assert (joined == []) == spent and (2 in group.members) != spent and grower.postponed == int(spent)
    assert (grower.search_seconds > 0.0) != spent


def test_a_place_an_earlier_match_found_as_good_keeps_a_later_placement_ambiguous(repo_root):
    """test/data/office_alias (rooms every 8.5 m along a corridor): a 6 m band of the robot's map fits the union of 26
    maps at several places along the corridor, and its search is refused as ambiguous. Accepted at its best place
    later (a search whose candidates missed the others), the places that match found keep it ambiguous while one
    still fits as well (Grower.still_ambiguous). The whole map, placed at the truth, fits nowhere else: the band's
    places, remembered for it, do not make it ambiguous."""
    import dataclasses

    from multirobot_map_merge.estimation.pair import AMBIGUOUS
    from multirobot_map_merge.estimation.verify import distinct
    folder = repo_root / 'test' / 'data' / 'office_alias'
    truth = json.loads((folder / 'truth.json').read_text())
    robot, union = (load_map(str(folder / m['file'])) for m in truth['maps'])
    true_m = tf.inverse(tf.rigid(*truth['maps'][1]['pose'])) @ tf.rigid(*truth['maps'][0]['pose'])
    known = np.argwhere(robot.data >= 0)
    middle = int(known[:, 0].min() + 0.45 * np.ptp(known[:, 0]))
    band = np.full_like(robot.data, -1)
    band[middle - 60:middle + 60] = robot.data[middle - 60:middle + 60]
    s = EstimationSettings()
    grower = _grower_of([union, Grid(band, robot.resolution, robot.origin, robot.frame_id), robot], s)
    group = grower.group(0)
    m = match_pair(1, 0, grower.prepared[1], group.union.prepared(), s, onto_union=True, descriptors=False,
                   distinct_places=True)
    assert m.reason.startswith(AMBIGUOUS), m.reason
    grower._refused_onto(m, frozenset(group.members))
    rival = grower.still_ambiguous(group, dataclasses.replace(m, accepted=True, reason=''))
    assert rival is not None and distinct(rival.transform, m.best.transform, grower.prepared[1], s)
    whole = match_pair(2, 0, grower.prepared[2], group.union.prepared(), s, onto_union=True, descriptors=False,
                       distinct_places=True)
    assert whole.accepted, whole.reason
    assert _error(whole.transform_m, [np.eye(3), None, true_m], 2, 0)[1] < 0.2
    grower.rivals[(2, 0)] = list(grower.rivals[(1, 0)])
    assert grower.still_ambiguous(group, whole) is None


@pytest.mark.parametrize('band', [True, False])
def test_a_member_set_aside_stays_out_where_its_part_fits_the_final_merge_elsewhere_too(repo_root, band):
    """test/data/office_alias (rooms every 8.5 m along a corridor): the robot's map joined the union by a search on
    little of its area, at the truth, and was set aside for the end. A 4 m band of it fits the union wall for wall at
    the truth (members agreeing 0.994) and at another place along the corridor too, passing the rules of a pair
    there: it stays out (the held-out
    maze36_w, seed 2: map_31, a quarter turn off on 0.30 of its area, 662 agreeing walls, joined again although the
    truth passed the same rules with 131). The whole map fits nowhere else: it joins again."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    folder = repo_root / 'test' / 'data' / 'office_alias'
    truth = json.loads((folder / 'truth.json').read_text())
    robot, union = (load_map(str(folder / m['file'])) for m in truth['maps'])
    true_m = tf.inverse(tf.rigid(*truth['maps'][1]['pose'])) @ tf.rigid(*truth['maps'][0]['pose'])
    if band:
        known = np.argwhere(robot.data >= 0)
        middle = int(known[:, 0].min() + 0.45 * np.ptp(known[:, 0]))
        data = np.full_like(robot.data, -1)
        data[middle - 40:middle + 40] = robot.data[middle - 40:middle + 40]
        robot = Grid(data, robot.resolution, robot.origin, robot.frame_id)
    s = EstimationSettings()
    grower = _grower_of([union, robot], s)
    group = grower.group(0)
    area = grower.prepared[1].known_pixels * grower.prepared[1].resolution ** 2
    m = PairMatch(1, 0, accepted=True, searched=True,
                  best=Placement(np.eye(3), support=300, agreement=1.0, overlap_m2=0.3 * area))
    m.transform_m = true_m
    grower._join(group, m)
    grower.searched.add(1)
    weak = grower.set_aside_weak(group)
    assert 1 in weak and 1 not in group.members
    joined = grower.readmit_weak(group, weak)
    assert (joined == [1]) != band and (1 in group.members) != band


def test_a_search_placement_the_members_near_it_leave_imprecise_stays(repo_root):
    """test/data/demo_late_group's robot_5, placed by a search onto robots 1-3: the building's wall direction, read on
    that whole union, makes it precise (0.11 m at the far corners); the members near it alone leave it 0.28-0.30 m
    uncertain. That is less evidence, not a contradiction: it stays (it was left out for good on static maps)."""
    _, grids, poses = _demo_late_group(repo_root)
    grower = _grower_of(grids, EstimationSettings())
    group = grower.group(1)
    for k in (0, 2, 4):
        group.union.add(k, grids[k], grower.prepared[k], tf.inverse(poses[1]) @ poses[k])
    grower.searched.add(4)
    grower.confirm_searches(group)
    assert set(group.members) == {0, 1, 2, 4}, grower.refused.get(4)


def test_the_estimation_confirms_the_search_placements_of_the_merge_it_ends_with(repo_root, monkeypatch):
    from multirobot_map_merge.estimation.growth import Grower
    grids, _ = _sample(repo_root, 'three_robots')
    confirmed = []
    monkeypatch.setattr(Grower, 'confirm_searches', lambda self, group: confirmed.append(set(group.members)))
    result = estimate(grids, EstimationSettings())
    assert confirmed == [{k for k, t in enumerate(result.transforms) if t is not None}]


def test_groups_merged_beside_a_larger_one_grow_by_descriptors_alone(repo_root, monkeypatch):
    """merge_groups: two single grids that merge while a group of three is larger grow without the costly search
    (a generated 36-map scenario searched every broken map in vain against such a group); merged into the largest,
    the search runs."""
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, big = _three_placed_and_three_more(repo_root, 'chain3', 'three_robots')
    first, second = grower.group(3), grower.group(4)

    def match_groups(self, small, onto):
        accept = {small.seed, onto.seed} == {3, 4} or (onto is big and len(small.members) == 2)
        m = PairMatch(small.seed, onto.seed, accepted=accept)
        m.transform_m = np.eye(3)
        return m

    grown = []
    monkeypatch.setattr(Grower, '_match_groups', match_groups)
    monkeypatch.setattr(Grower, 'grow', lambda self, group, unplaced, search=True:
                        grown.append((len(group.members), search)))
    merged = grower.merge_groups([big, first, second], [5])
    assert grown[0] == (2, False)
    assert grown[-1] == (5, True) and len(merged) == 1


def test_the_last_group_match_onto_a_union_is_made_together_with_the_first_onto_the_next(repo_root, monkeypatch):
    """merge_groups: where one group is left to match onto a union, the match that follows it (onto the next
    union) is made with it in one batch (the matching processes work on both at once) and kept: merge_groups uses it
    when it gets there instead of matching again, and makes no match alone."""
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, big = _three_placed_and_three_more(repo_root, 'chain3', 'three_robots')
    pair = grower.group(3)
    pair.union.add(4, grower.grids[4], grower.prepared[4], np.eye(3))
    single = grower.group(5)
    grower.tried[(5, big.key)] = big.union.version   # grid 5 was matched onto the big union already
    batches, alone = [], []

    def match_all(calls):
        batches.append([(c.i, c.j) for c in calls])
        return [PairMatch(c.i, c.j, reason='refused') for c in calls]

    monkeypatch.setattr(grower.matcher, 'match_all', match_all)
    monkeypatch.setattr(Grower, '_group_match', lambda self, small, onto, spent:
                        alone.append((small.seed, onto.seed)) or PairMatch(small.seed, onto.seed, reason='refused'))
    merged = grower.merge_groups([big, pair, single], [])
    assert len(merged) == 3
    assert batches == [[(3, 0), (5, 3)]] and alone == []


def test_a_failed_search_waits_for_search_again_which_a_found_overlap_does_not_stop(repo_root):
    """A grid whose search against a group failed in this estimation is not searched against it again as the group
    grows (the broken maps of a generated building were searched in vain against every larger union), until
    search_again, once the group has grown as far as it can otherwise. There a descriptor match that found a
    contradicting overlap since (a wrong place on a large union of a repetitive building) does not stop it."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    grids, poses = _sample(repo_root, 'three_robots')
    grids = grids + [grids[2]]   # 3: a stand-in for a grid no search places
    s = EstimationSettings()
    grower = _grower_of(grids, s)
    group = grower.group(0)
    searched = []
    grower.match = lambda g, ks, search: [(searched.append(k) if search else None) or PairMatch(k, g.seed, reason='x')
                                          for k in ks]
    unplaced = [3]
    assert not grower._search(group, unplaced) and searched == [3]
    group.union.add(1, grids[1], grower.prepared[1], tf.inverse(poses[0]) @ poses[1])   # grown by far more than
    group.union.add(2, grids[2], grower.prepared[2], tf.inverse(poses[0]) @ poses[2])   # SEARCH_GROWTH
    assert not grower._search(group, unplaced) and searched == [3]
    contradicting = Placement(np.eye(3), support=900, agreement=0.97, overlap_m2=30.0, deep_conflicts=40)
    grower._admit(group, unplaced, [PairMatch(3, 0, reason='deep conflicts', best=contradicting)])
    grower.search_again(group, unplaced)
    assert searched == [3, 3] and not grower.again


def test_members_of_a_group_that_cannot_join_regroup_without_its_seed(repo_root, monkeypatch):
    """search_grow: a group that cannot join the merge (its seed a broken map, in the generated 36-map buildings)
    is taken apart; its other members regroup by descriptors without the seed and are matched onto the merge as a
    group, before any of them is searched alone; the seed is searched alone. A regrouped group that does not join
    is tried member by member in the end."""
    from multirobot_map_merge.estimation.estimator import search_grow
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, merge = _three_placed_and_three_more(repo_root, 'three_robots', 'chain3')
    failed = grower.group(3)
    for k in (4, 5):
        failed.union.add(k, grower.grids[k], grower.prepared[k], np.eye(3))
    events = []

    def match(self, k, group, search):
        events.append(('search' if search else 'match', k, frozenset(group.members)))
        m = PairMatch(k, group.seed, accepted=not search and {k, group.seed} == {4, 5})
        m.transform_m = np.eye(3)
        return m

    def match_groups(self, small, onto):
        events.append(('groups', frozenset(small.members), frozenset(onto.members)))
        return PairMatch(small.seed, onto.seed, reason='none')

    monkeypatch.setattr(Grower, 'match', lambda self, group, grids, search: [match(self, k, group, search)
                                                                             for k in grids])
    monkeypatch.setattr(Grower, '_match_groups', match_groups)
    monkeypatch.setattr(Grower, '_match_ahead', lambda self, upcoming: None)
    groups = search_grow(grower, [merge, failed], 0)
    assert set(groups[0].members) == {0, 1, 2}
    regrouped = events.index(('groups', frozenset({4, 5}), frozenset({0, 1, 2})))
    searched = {e[1]: n for n, e in reversed(list(enumerate(events))) if e[0] == 'search'}   # grid: first search
    assert set(searched) == {3, 4, 5}
    assert searched[4] > regrouped and searched[5] > regrouped


@pytest.mark.parametrize('overlapping', [True, False])
def test_a_seed_the_largest_grids_partly_contradict_waits_for_the_others(repo_root, monkeypatch, overlapping):
    """descriptor_groups: a new seed is matched onto the largest grids first (Grower.grow's probe). When none joins
    and enough of them overlap it but partly contradict it (the broken maps that are radial36's largest), the other
    grids are not matched onto it: it waits, the next grid seeds and grows, the waiting one is matched onto that group
    like any grid and seeds only after it. When the refusals found no overlap, the seed is matched with every grid."""
    from multirobot_map_merge.estimation import growth
    from multirobot_map_merge.estimation.estimator import descriptor_groups
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement
    grids, _ = _sample(repo_root, 'three_robots')
    grower = _grower_of(grids + grids + grids[:1], EstimationSettings())   # 7 grids; their matches made up below
    monkeypatch.setattr(growth, 'SEED_PROBE', 2)
    monkeypatch.setattr(growth, 'SEED_CONTRADICTED', 2)
    order = sorted(range(7), key=lambda k: -grower.prepared[k].known_pixels)
    broken, healthy = order[0], order[1]
    partly = Placement(np.eye(3), support=900, agreement=0.8, overlap_m2=40.0) if overlapping else None
    matched = []

    def match(self, group, ks, search):
        out = []
        for k in ks:
            matched.append((group.seed, k))
            accepted = group.seed != broken and k != broken
            m = PairMatch(k, group.seed, accepted=accepted, reason='' if accepted else 'agreement 0.80 < 0.91',
                          best=None if accepted else partly)
            m.transform_m = np.eye(3)
            out.append(m)
        return out

    monkeypatch.setattr(Grower, 'match', match)
    groups = descriptor_groups(grower, list(range(7)))
    onto_broken = [k for seed, k in matched if seed == broken]
    if overlapping:
        assert onto_broken == order[1:3]
        assert [g.seed for g in groups] == [healthy, broken]
        assert (healthy, broken) in matched
    else:
        assert sorted(onto_broken) == sorted(order[1:])
        assert [g.seed for g in groups] == [broken, healthy]
    assert sorted(k for g in groups for k in g.members) == list(range(7))


def test_tracking_checks_again_only_the_placements_that_saw_the_map_it_dropped(monkeypatch):
    """After the worst failing placement is dropped, a check whose maps did not include it would be the same check
    on the same maps: only the placements near the dropped one are checked again, and the verdicts are those of
    checking them all again."""
    from concurrent.futures import ThreadPoolExecutor
    from multirobot_map_merge.estimation import tracking
    from multirobot_map_merge.estimation.memory import EstimationMemory
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.verify import Placement

    grids = [Grid(np.zeros((20, 20), np.int8), 0.05) for _ in range(5)]   # 1 m squares of free floor
    # 0 the reference; 1 wrong, which makes its neighbour 2 fail too; 3 and 4 far from both
    previous = [tf.translation(x, 0.0) for x in (0.0, 0.5, 1.2, 10.0, 11.5)]
    made = []

    def recheck(k, grids, prepared, placed, footprints, res, s, refine=True, failing='no longer holds'):
        made.append(k)
        fails = k == 1 or (k == 2 and 1 in placed)
        match = PairMatch(k, 0, best=Placement(np.eye(3), agreement=0.5 if k == 1 else (0.8 if fails else 1.0)))
        if fails:
            match.reason = failing
        return tracking.Check(k, None if fails else placed[k], match)

    monkeypatch.setattr(tracking, 'recheck', recheck)
    monkeypatch.setattr(tracking, 'relax_placed', lambda *a: set())
    with ThreadPoolExecutor(1) as pool:
        placed, checks = tracking.track(previous, 0, grids, [object()] * 5, 0.05, EstimationSettings(), pool,
                                        EstimationMemory(), list('abcde'), ['same'] * 5)
    assert sorted(placed) == [0, 2, 3, 4]   # 1 dropped, 2 holds without it
    assert sorted(made) == [0, 1, 2, 2, 3, 4]   # 3 and 4 once (before: twice), the reference at the end


def test_a_group_that_was_the_largest_once_is_tried_member_by_member_when_another_outgrows_it(repo_root,
                                                                                              monkeypatch):
    """search_grow: the first largest group (4, 5) joins nothing; the grids it left grow a larger group (0-3) that
    refuses it as a whole (a group grown by a broken seed's two parts). Its members are then matched onto the merge
    one by one, and those that fit join; before, they stayed out as a group."""
    from multirobot_map_merge.estimation.estimator import search_grow
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.pair import PairMatch
    grower, _ = _three_placed_and_three_more(repo_root, 'three_robots', 'chain3')
    first = grower.group(4)
    first.union.add(5, grower.grids[5], grower.prepared[5], np.eye(3))
    onto = []

    def match(k, group):
        onto.append((k, frozenset(group.members)))
        m = PairMatch(k, group.seed, accepted=0 in group.members and k != 5, reason='' if 0 in group.members else 'no')
        m.transform_m = np.eye(3)
        return m

    monkeypatch.setattr(Grower, 'match', lambda self, group, grids, search: [match(k, group) for k in grids])
    monkeypatch.setattr(Grower, '_match_groups', lambda self, small, big: PairMatch(small.seed, big.seed, reason='no'))
    monkeypatch.setattr(Grower, '_match_ahead', lambda self, upcoming: None)
    groups = [first] + [grower.group(k) for k in (0, 1, 2, 3)]
    groups = search_grow(grower, groups, None)
    assert set(groups[0].members) == {0, 1, 2, 3, 4}
    assert (4, frozenset({0, 1, 2, 3})) in onto and (5, frozenset({0, 1, 2, 3, 4})) in onto
    assert not any(len(g.members) > 1 for g in groups[1:])


def test_a_grid_that_joins_a_few_maps_is_noted_and_one_that_joins_more_is_not(repo_root):
    """Grower._join notes the grids that joined a group of stronger.FEW_MEMBERS maps or fewer (searched_again checks
    them on the final merge); a grid that joins a larger one is judged on all its walls, and is not noted."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.stronger import FEW_MEMBERS
    grids, poses = _sample(repo_root, 'chain3')
    grids, poses = grids + _sample(repo_root, 'three_robots')[0], poses + _sample(repo_root, 'three_robots')[1]
    grower = _grower_of(grids, EstimationSettings())
    group = grower.group(0)
    for k in range(1, len(grids)):
        m = PairMatch(k, 0, accepted=True)
        m.transform_m = tf.inverse(poses[0]) @ poses[k]
        few = len(group.members) <= FEW_MEMBERS
        grower._join(group, m)
        assert (k in grower.placed_onto_few) == few, k
    assert grower.placed_onto_few == set(range(1, FEW_MEMBERS + 1))


def test_an_estimation_afresh_checks_the_maps_placed_onto_a_few_on_its_relaxed_merge(repo_root, monkeypatch):
    """merge_maps' estimation (search_left_out) judges the members placed onto a few maps once the merge is relaxed;
    the node's (search_left_out off: tracking checks every placement in the estimations after) does not."""
    from multirobot_map_merge.estimation import estimator
    grids, _ = _sample(repo_root, 'three_robots')
    calls = []
    relax = estimator.relax_group
    monkeypatch.setattr(estimator, 'relax_group',
                        lambda group, *a, **kw: calls.append('relaxed') or relax(group, *a, **kw))
    monkeypatch.setattr(estimator, 'search_doubted_again',
                        lambda grower, group: calls.append(set(group.members)) or [])
    result = estimate(grids, EstimationSettings())
    assert calls == ['relaxed', {k for k, t in enumerate(result.transforms) if t is not None}]
    calls.clear()
    estimate(grids, EstimationSettings(search_left_out=False))
    assert calls == ['relaxed']


def test_the_node_estimates_its_final_maps_afresh_as_merge_maps_does(repo_root, monkeypatch):
    """The node's estimations make no searches of the maps left out and no evictions (they judge partial maps;
    tracking checks the kept placements); its one estimate afresh of the final maps, once they have stopped changing,
    makes them, as merge_maps (a generated hospital replayed as growing maps ended with 13 of its 27 mergeable maps
    placed; with them, 27), and is seeded as merge_maps seeds, not by the kept reference (the growth depends on its
    seed: the generated mall36 seeded by its map 21 or 30 places 22 of its 27 mergeable maps; merge_maps, seeding
    by the largest map, 27)."""
    from multirobot_map_merge.estimation import estimator
    from multirobot_map_merge.estimation.memory import EstimationMemory
    from multirobot_map_merge.ros.params import MapMergeParams
    grids, _ = _sample(repo_root, 'three_robots')
    s = MapMergeParams().estimation_settings().replace(processes=False)
    assert not (s.evict or s.relax_final or s.search_left_out)
    memory, names = EstimationMemory(), ['a', 'b', 'c']
    calls = []
    real = estimator._estimate
    monkeypatch.setattr(estimator, '_estimate',
                        lambda *args: calls.append((args[4] is None, args[1], args[3])) or real(*args))
    previous = estimate(grids, s, preferred_reference=0).transforms
    for _ in range(3):   # tracked; tracked and checked on the final maps; and estimated afresh
        calls.clear()
        previous = estimate(grids, s, preferred_reference=0, previous=previous, memory=memory,
                            names=names).transforms
    assert [afresh for afresh, _, _ in calls] == [False, True]
    assert calls[0][1:] == (s, 0)
    assert calls[1][1:] == (s.replace(evict=True, search_left_out=True), None)
    assert all(t is not None for t in previous)


@pytest.mark.parametrize('name', ['three_robots', 'chain3'])
def test_the_same_maps_in_any_order_are_placed_alike_to_the_last_digit(repo_root, name):
    """The random draws of a match (RANSAC, ICP's samples) are seeded by the grids' contents, not by their places in
    the order they came in: the maps given in another order are placed relative to each other exactly alike."""
    grids, _ = _sample(repo_root, name)
    relative = []
    for order in ([0, 1, 2], [2, 1, 0], [1, 2, 0]):
        result = estimate([grids[k] for k in order], EstimationSettings())
        placed = {k: result.transforms[i] for i, k in enumerate(order)}
        relative.append({k: tf.inverse(placed[0]) @ t for k, t in placed.items()})
    for other in relative[1:]:
        for k in range(3):
            assert np.allclose(other[k], relative[0][k], rtol=0.0, atol=1e-9), (k, other[k] - relative[0][k])



def test_a_member_back_in_at_the_end_lets_the_maps_left_out_vote_again(repo_root, monkeypatch):
    """A member taken out that joins again at the end (search_left_out's readmit) can be the second member a map left
    out agrees with: the maps left out vote again on the merge with it (evict_contradicted with make_room). The held-out
    pillar_hall36_w: a broken group's vote took map_12 out; back at the end, maps 0, 15 and 21 agreed with it and
    map_35 and voted out broken map_33, which had kept seven maps out."""
    from multirobot_map_merge.estimation import growth
    grids, _ = _sample(repo_root, 'three_robots')
    for back in (0, 1):
        events = []
        search, evict = growth.Grower.search_left_out, growth.Grower.evict_contradicted

        def searched(self, group, readmit=False, _search=search, _back=back, **options):
            joined = _search(self, group, readmit=readmit, **options)
            events.append('readmit' if readmit else 'search')
            return _back if readmit else joined

        def evicted(self, group, groups, unplaced, make_room=False, _evict=evict):
            events.append(('evict', make_room))
            return _evict(self, group, groups, unplaced, make_room=make_room)

        monkeypatch.setattr(growth.Grower, 'search_left_out', searched)
        monkeypatch.setattr(growth.Grower, 'evict_contradicted', evicted)
        estimate(grids, EstimationSettings())
        after = events[events.index('readmit') + 1:]
        assert (('evict', True) in after) == bool(back)
        monkeypatch.undo()
