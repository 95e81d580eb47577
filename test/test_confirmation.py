"""Confirmation (estimation/confirmation.py): with a memory (the node), a grid placed for the first time is published
once the next estimation confirms it on the maps of then."""
import json

import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.confirmation import (HELD, STATIC_AFTER_S, anchor_on_published, hold_new,
                                                          keep_standing, remember_shown)
from multirobot_map_merge.estimation.estimator import Estimate
from multirobot_map_merge.estimation.memory import EstimationMemory
from multirobot_map_merge.grid import Grid
from multirobot_map_merge.mapio import load_map
from multirobot_map_merge.pipeline import MergingPipeline

NAMES = ['a', 'b', 'c']


def _chain(repo_root):
    folder = repo_root / 'data' / 'samples' / 'chain3'
    truth = json.loads((folder / 'truth.json').read_text())
    return [load_map(str(folder / m['file'])) for m in truth['maps']]


def _estimate(pipeline, grids, now=None):
    pipeline.feed(grids)
    return pipeline.estimate(preferred_reference=0 if pipeline.reference is None else pipeline.reference,
                             previous=pipeline.transforms if len(pipeline.transforms) == len(grids) else None,
                             names=NAMES, now=now)


def _free_strip(x0, width_m, height_m):
    """A grid of free cells only, in the merged frame itself, from x0 along x."""
    return Grid(np.zeros((int(round(height_m / 0.05)), int(round(width_m / 0.05))), np.int8), 0.05, (x0, 0.0, 0.0))


def _placed(result):
    return {NAMES[k] for k, t in enumerate(result.transforms) if t is not None}


def _reasons(result):
    return {NAMES[p.i]: p.reason for p in result.pairs if p.reason}


def test_new_placements_are_published_once_the_next_estimation_confirms_them(repo_root):
    grids = _chain(repo_root)
    pipeline = MergingPipeline()
    first = _estimate(pipeline, grids)
    assert _placed(first) == {'a'}
    assert _reasons(first) == {'b': HELD, 'c': HELD}
    second = _estimate(pipeline, grids)
    assert _placed(second) == {'a', 'b', 'c'}
    assert second.tracked == 2
    # offline (no names, no memory) every placement is published at once
    once = MergingPipeline()
    once.feed(grids)
    assert sum(t is not None for t in once.estimate(preferred_reference=0).transforms) == 3


def test_with_a_clock_maps_unchanged_between_two_estimations_confirm_only_once_static_for_long(repo_root):
    """A few robots' maps can all stay the same between two estimations while they explore (SLAM publishes a map
    every few seconds): with the time, the same maps confirm a new placement only once unchanged for STATIC_AFTER_S;
    a map grown where it meets the placed maps confirms it at once, as without a clock."""
    grids = _chain(repo_root)
    pipeline = MergingPipeline()
    assert _placed(_estimate(pipeline, grids, now=100.0)) == {'a'}
    waited = 0.0
    while waited + 2.0 < STATIC_AFTER_S:
        waited += 2.0
        assert _reasons(_estimate(pipeline, grids, now=100.0 + waited)) == {'b': HELD, 'c': HELD}, waited
    assert _placed(_estimate(pipeline, grids, now=100.0 + STATIC_AFTER_S)) == {'a', 'b', 'c'}


def test_a_held_placement_is_confirmed_once_its_common_area_with_the_published_maps_has_grown(repo_root):
    """Map a (the reference) first without the last quarter of its rows: b, placed on the 24.8 of the 30.4 m2 it
    shares with a, is held. With one cell more of b, far from a, held still (a check of its place on maps that
    changed elsewhere sees nothing new). With the whole of a: confirmed. c, held with b, meets a not at all and
    shares with b what it did when first held: held until the maps have not changed for STATIC_AFTER_S."""
    grids = _chain(repo_root)
    a, b = grids[0], grids[1]
    part = a.data.copy()
    part[-len(part) // 4:] = -1
    early = [Grid(part, a.resolution, a.origin, a.frame_id), b, grids[2]]
    edited = b.data.copy()
    edited[0, 0] = 0 if edited[0, 0] != 0 else 100
    elsewhere = [early[0], Grid(edited, b.resolution, b.origin, b.frame_id), grids[2]]
    pipeline = MergingPipeline()
    assert _placed(_estimate(pipeline, early, now=0.0)) == {'a'}
    first = pipeline.memory.held['b'].common['a']
    assert 20.0 < first < 28.0, first
    assert _reasons(_estimate(pipeline, elsewhere, now=2.0)) == {'b': HELD, 'c': HELD}
    assert _reasons(_estimate(pipeline, grids, now=4.0)) == {'c': HELD}
    assert _reasons(_estimate(pipeline, grids, now=6.0)) == {'c': HELD}
    assert _placed(_estimate(pipeline, grids, now=4.0 + STATIC_AFTER_S)) == {'a', 'b', 'c'}


def test_a_held_placement_that_does_not_hold_on_the_next_maps_is_not_published(repo_root):
    """Map c's frame moves by 3 m between two estimations (its held placement is now wrong): it is placed anew and
    held again (and b, whose map has not changed while another has, with it), then published at its new place once
    the maps stay the same; a map that matches nothing is neither published nor held."""
    grids = _chain(repo_root)
    pipeline = MergingPipeline()
    _estimate(pipeline, grids)
    held_c = pipeline.memory.held['c'].transform
    c = grids[2]
    moved = Grid(c.data.copy(), c.resolution, (c.origin[0] + 3.0, c.origin[1], c.origin[2]))
    second = _estimate(pipeline, [grids[0], grids[1], moved])
    assert _placed(second) == {'a'}
    assert _reasons(second) == {'b': HELD, 'c': HELD}
    third = _estimate(pipeline, [grids[0], grids[1], moved])
    assert _placed(third) == {'a', 'b', 'c'}
    # its cells where they were held first: the frame moved, the map did not
    corners = np.array([[0.0, 0.0], [c.width, 0.0], [0.0, c.height], [c.width, c.height]])
    rot, disp = tf.difference(third.transforms[2] @ moved.cell_to_map(), held_c @ c.cell_to_map(), corners)
    assert disp < 0.1, disp

    blank = Grid(np.zeros_like(c.data), c.resolution, c.origin)   # all free: nothing to match
    fourth = MergingPipeline()
    _estimate(fourth, grids)
    _estimate(fourth, grids)
    assert _placed(_estimate(fourth, [grids[0], grids[1], blank])) == {'a', 'b'}
    assert not fourth.memory.held


def test_a_room_placed_next_door_half_a_turn_off_is_never_published(repo_root):
    """Four maps of a live 12-robot run (seed 1): robots 3, 4 and 6 merged, robot_12's map one room with a door at
    each end. At 7.2 sim s a search fits robot_12 into the room next to robot_6's through a door, 179 degrees from
    the truth, on 0.27 of its area: agreeing 0.992 with the merge's union there, 0.981 with the members one by one.
    It waits (growth: a search's placement on little of a map joins only where the members agree wall for wall), so
    it is not even held; on the maps of 10.2 sim s no placement holds, and it is never published."""
    folder = repo_root / 'test' / 'data' / 'demo_room_through_door'
    meta = json.loads((folder / 'start_poses.json').read_text())
    names = meta['robots']
    start = {n: tf.rigid(*meta['start_poses'][n][:3]) for n in names}
    true = [tf.inverse(start[names[0]]) @ start[n] for n in names]
    published = true[:3] + [None]

    def maps(when):
        return [load_map(str(folder / f'{n}_{when}.yaml')) for n in names]

    pipeline = MergingPipeline()
    pipeline.feed(maps('early'))
    early = pipeline.estimate(preferred_reference=0, previous=published, names=names)
    assert early.transforms[3] is None and early.held == 0
    searched = next(m for m in early.pairs if m.i == 3)
    assert searched.searched and searched.reason.startswith('waits: a search placed it')
    rot, _ = tf.difference(early.transforms[0] @ searched.transform_m, true[3], np.zeros((1, 2)))
    assert abs(np.degrees(rot)) > 170   # the placement that would have been published
    pipeline.feed(maps('later'))
    later = pipeline.estimate(preferred_reference=0, previous=early.transforms, names=names)
    assert later.transforms[3] is None
    assert all(later.transforms[k] is not None for k in range(3))


def test_a_room_placed_a_quarter_turn_off_is_not_confirmed_by_maps_grown_elsewhere(repo_root):
    """Three maps of a live 12-robot run (seed 2): robot_5's map (one room, 20 m2) published alone; robots 6 and 2,
    right relative to each other, fit it a quarter turn off, 43 m from the truth (agreement 0.99 over 19 m2). By 7
    sim s robot 6's map has grown away from that room: the placement still holds, on the same common area, and the
    node published it (90.8 degrees off). It stays held; on the maps of 8 sim s it no longer holds."""
    folder = repo_root / 'test' / 'data' / 'demo_room_quarter_turn'
    meta = json.loads((folder / 'start_poses.json').read_text())
    names = meta['robots']
    start = {n: tf.rigid(*meta['start_poses'][n][:3]) for n in names}

    def maps(when):
        return [load_map(str(folder / f'{n}_{when}.yaml')) for n in names]

    def turned_onto_robot_5(result):
        """The robots placed more than 10 degrees off relative to robot_5."""
        if result.transforms[0] is None:
            return []
        to_5 = tf.inverse(result.transforms[0])
        out = []
        for k, t in enumerate(result.transforms[1:], 1):
            if t is not None:
                rot, _ = tf.difference(to_5 @ t, tf.inverse(start[names[0]]) @ start[names[k]], np.zeros((1, 2)))
                if abs(np.degrees(rot)) > 10:
                    out.append(names[k])
        return out

    pipeline = MergingPipeline()
    published = [np.eye(3), None, None]
    pipeline.feed(maps('first'))
    first = pipeline.estimate(preferred_reference=0, previous=published, names=names)
    assert first.held == 2
    held = pipeline.memory.held['robot_6'].transform
    rot, _ = tf.difference(held, tf.inverse(start['robot_5']) @ start['robot_6'], np.zeros((1, 2)))
    assert abs(abs(np.degrees(rot)) - 90) < 5   # the placement that would have been published
    pipeline.feed(maps('elsewhere'))
    elsewhere = pipeline.estimate(preferred_reference=0, previous=first.transforms, names=names)
    assert [t is not None for t in elsewhere.transforms] == [True, False, False]
    assert elsewhere.held == 2
    pipeline.feed(maps('later'))
    later = pipeline.estimate(preferred_reference=pipeline.reference, previous=pipeline.transforms, names=names)
    assert turned_onto_robot_5(later) == []


def test_the_merge_moves_to_a_group_that_outgrew_it_only_once_that_group_shows_more(repo_root):
    """Two robots of one building are merged; four robots of another (a group that does not overlap them) appear and
    outnumber them. Their placements are held, so the merge stays with the two published ones (in their frame), not
    with the larger group's seed alone; once the next estimation confirms the four, the merge moves to them."""
    samples = repo_root / 'data' / 'samples'
    pair = [load_map(str(samples / 'three_robots' / f'map_0{i}.yaml')) for i in (0, 1)]
    four = [load_map(str(samples / 'union_join' / f'map_0{i}.yaml')) for i in range(4)]
    names = ['a0', 'a1', 'b0', 'b1', 'b2', 'b3']
    pipeline = MergingPipeline()

    def estimate(grids):
        pipeline.feed(grids)
        result = pipeline.estimate(preferred_reference=pipeline.reference or 0, previous=pipeline.transforms,
                                   names=names)
        return result, {names[k] for k, t in enumerate(result.transforms) if t is not None}

    estimate(pair + [None] * 4)
    shown, placed = estimate(pair + [None] * 4)
    assert placed == {'a0', 'a1'}
    outgrown, placed = estimate(pair + four)
    assert placed == {'a0', 'a1'} and outgrown.reference == 0
    assert np.allclose(outgrown.transforms[1], shown.transforms[1])
    assert {names[p.i]: p.reason for p in outgrown.pairs if p.reason} == {n: HELD for n in names[2:]}
    assert outgrown.held == 3   # the group's seed is not held: it is the frame of the others
    moved, placed = estimate(pair + four)
    assert placed == {'b0', 'b1', 'b2', 'b3'} and moved.reference == 2


def test_held_placements_are_confirmed_when_their_group_takes_another_seed():
    """A group's seed is its largest map: two maps of a held group can take turns. Its held placements, restated in
    the frame of the new seed, are confirmed where they stayed (on maps grown meanwhile); the old seed is held
    anew."""
    small = [Grid(np.zeros((40, 40), np.int8), 0.05, (0.0, 0.0, 0.0))] * 4      # 2 m x 2 m, all free
    grown = [Grid(np.zeros((200, 200), np.int8), 0.05, (0.0, 0.0, 0.0))] * 4    # 10 m x 10 m
    names = ['r', 'a', 'b', 'c']
    to_b, to_c = tf.rigid(1.5, 0.2, 0.3), tf.rigid(-0.4, 2.0, -1.1)
    memory = EstimationMemory()
    first = [None, np.eye(3), to_b, to_c]   # placed around a
    assert hold_new(first, 1, [], [np.eye(3), None, None, None], memory, names, small, False) == 2
    # the next estimation, on grown maps, seeds the group with b: the same placements in b's frame
    second = [None, tf.inverse(to_b), np.eye(3), tf.inverse(to_b) @ to_c]
    pairs = []
    assert hold_new(second, 2, pairs, [np.eye(3), None, None, None], memory, names, grown, False) == 1
    assert second[3] is not None and second[1] is None
    assert [names[p.i] for p in pairs] == ['a'] and pairs[0].reason == HELD


def test_a_group_that_outgrew_the_merge_gathers_its_confirmations_over_estimations():
    """The published merge shows three grids (r, x, y); a group of three new ones (seed a) outgrows it. b's common
    area with a grows first, c's an estimation later: the merge moves to the group once both are confirmed, b
    kept confirmed meanwhile (had it been held anew, the group could show at most two of its three at once)."""
    def free(size_m, origin=(0.0, 0.0)):
        n = int(round(size_m / 0.05))
        return Grid(np.zeros((n, n), np.int8), 0.05, (origin[0], origin[1], 0.0))

    names = ['r', 'x', 'y', 'a', 'b', 'c']
    published = [np.eye(3), tf.rigid(30.0, 0.0, 0.0), tf.rigid(60.0, 0.0, 0.0), None, None, None]
    standing = ({0: published[0], 1: published[1], 2: published[2]}, [])
    to_b, to_c = tf.rigid(1.0, 1.0, 0.0), tf.rigid(-1.0, -1.0, 0.0)   # in a's frame
    small, grown = free(2.0), free(4.0)   # b or c: common area with a (4 m x 4 m) 4 m2, then 9 m2
    memory = EstimationMemory()

    def estimate(b, c):
        grids = [free(4.0)] * 3 + [free(4.0), b, c]
        result = Estimate([None, None, None, np.eye(3), to_b.copy(), to_c.copy()], 3, standing=standing)
        result.held = hold_new(result.transforms, 3, result.pairs, published, memory, names, grids, False)
        moved = not keep_standing(result, published, 0, memory)
        return moved, result.held

    assert estimate(small, small) == (False, 2)
    assert estimate(grown, small) == (False, 1)   # b confirmed, not shown: 2 < 3
    assert estimate(grown, grown) == (True, 0)


def test_held_grids_grown_together_do_not_confirm_each_other_but_a_confirmed_one_confirms_its_neighbour():
    """r stands; b (held) meets r, c (held) meets only b. When b and c grow into each other, and b not towards r,
    neither is confirmed: their place relative to r has met nothing new. When b's common area with r grows too, b
    is confirmed, and c with it, in the same estimation."""
    names = ['r', 'b', 'c']
    published = [np.eye(3), None, None]
    r = _free_strip(0.0, 4.0, 4.0)

    def hold(b, c, memory):
        transforms = [np.eye(3)] * 3
        return hold_new(transforms, 0, [], published, memory, names, [r, b, c], False), transforms

    for b_now, placed in ((_free_strip(2.0, 6.0, 2.0), [True, False, False]),    # b grew away from r, into c
                          (_free_strip(0.0, 8.0, 2.0), [True, True, True])):     # b grew towards r too
        memory = EstimationMemory()
        # b shares 4 m2 with r, c none
        assert hold(_free_strip(2.0, 2.0, 2.0), _free_strip(6.0, 2.0, 2.0), memory)[0] == 2
        held, transforms = hold(b_now, _free_strip(5.0, 3.0, 4.0), memory)
        assert [t is not None for t in transforms] == placed


def test_two_maps_shown_together_before_are_confirmed_together_where_they_were():
    """p and q were shown together in p's frame; the merge moved to a larger group (seed a) and left them out. Now
    they join a's group, held; p's common area with a grows, q meets a not at all and shares with p what it did:
    q is confirmed with p where a merge showed it relative to p before, and held if placed elsewhere."""
    def free(x0, y0, width_m, height_m):   # all free cells, in the merged frame itself
        return Grid(np.zeros((int(round(height_m / 0.05)), int(round(width_m / 0.05))), np.int8), 0.05,
                    (x0, y0, 0.0))

    names = ['a', 'p', 'q']
    a, q = free(0.0, 0.0, 4.0, 4.0), free(5.0, 3.0, 4.0, 2.0)
    p_then, p_now = free(2.0, 3.0, 4.0, 2.0), free(2.0, 1.0, 4.0, 4.0)   # shares with a 2 m2, then 6 m2
    for q_shown, placed in ((np.eye(3), [True, True, True]), (tf.rigid(1.0, 0.0, 0.0), [True, True, False])):
        memory = EstimationMemory()
        remember_shown([None, np.eye(3), q_shown], 1, memory, names)   # in p's frame
        published = [np.eye(3), None, None]
        assert hold_new([np.eye(3)] * 3, 0, [], published, memory, names, [a, p_then, q], False) == 2
        transforms = [np.eye(3)] * 3
        hold_new(transforms, 0, [], published, memory, names, [a, p_now, q], False)
        assert [t is not None for t in transforms] == placed


def test_a_new_placement_is_confirmed_only_where_the_merge_that_stands_has_no_other_place_for_it():
    """r stands; b (held) meets r, c (held) meets only b, and both grow so that the growth rule alone confirms both
    (the test above). The check on the merge that stands (uniqueness.StandingCheck, stubbed here) decides: a
    place that contradicts the merge refuses b and c placed with it; a rival place for c refuses c alone; b too
    little in common with the merge to be judged there waits, and c with it (confirmed only by a grid confirmed
    now); nothing against either confirms both."""
    from multirobot_map_merge.estimation.uniqueness import CONTRADICTS

    names = ['r', 'b', 'c']
    published = [np.eye(3), None, None]
    r = _free_strip(0.0, 4.0, 4.0)
    cases = (({1: f'{CONTRADICTS}: agreement 0.80', 2: ''}, [True, False, False]),
             ({1: '', 2: 'another place on the merge that stands agrees 1.00'}, [True, True, False]),
             ({1: None, 2: None}, [True, False, False]),
             ({1: '', 2: None}, [True, True, True]))
    for verdicts, placed in cases:
        judged = []

        def check(k, transform, standing, settled, keep=40):
            if settled:   # the second look, with the grids confirmed now (second_look's test)
                assert set(standing) == {0, 1, 2} - {k}
                return ''
            assert set(standing) == {0}
            judged.append(k)
            return verdicts[k]

        memory = EstimationMemory()
        assert hold_new([np.eye(3)] * 3, 0, [], published, memory, names,
                        [r, _free_strip(2.0, 2.0, 2.0), _free_strip(6.0, 2.0, 2.0)], False, check) == 2
        assert judged == []   # nothing confirmed yet: nothing judged
        transforms = [np.eye(3)] * 3
        grown = [r, _free_strip(0.0, 8.0, 2.0), _free_strip(5.0, 3.0, 4.0)]
        hold_new(transforms, 0, [], published, memory, names, grown, False, check)
        assert [t is not None for t in transforms] == placed, verdicts


def test_grids_confirmed_together_are_judged_again_on_the_merge_they_make():
    """r stands; b (held) meets r, c (held) meets only b, and both grow so that both are confirmed (the tests
    above). Judged again on r and the other one confirmed now (where a rival counts when it is as good: settled), a
    rival place for c refuses c alone; b contradicting that merge refuses c, placed with it; c not judged there
    confirms both. A grid confirmed alone is not judged again."""
    from multirobot_map_merge.estimation.uniqueness import CONTRADICTS

    names = ['r', 'b', 'c']
    published = [np.eye(3), None, None]
    r = _free_strip(0.0, 4.0, 4.0)
    rival = 'another place on the merge that stands agrees 1.00'
    cases = (({1: '', 2: ''}, {1: '', 2: rival}, [True, True, False]),
             ({1: '', 2: ''}, {1: f'{CONTRADICTS}: agreement 0.80', 2: ''}, [True, False, False]),
             ({1: '', 2: ''}, {1: '', 2: None}, [True, True, True]),
             ({1: '', 2: rival}, {}, [True, True, False]))
    for first, again, placed in cases:
        judged_again = []

        def check(k, transform, standing, settled, keep=40):
            if not settled:
                assert set(standing) == {0}
                return first[k]
            assert set(standing) == {0, 1, 2} - {k}
            judged_again.append(k)
            return again[k]

        memory = EstimationMemory()
        assert hold_new([np.eye(3)] * 3, 0, [], published, memory, names,
                        [r, _free_strip(2.0, 2.0, 2.0), _free_strip(6.0, 2.0, 2.0)], False, check) == 2
        transforms = [np.eye(3)] * 3
        grown = [r, _free_strip(0.0, 8.0, 2.0), _free_strip(5.0, 3.0, 4.0)]
        hold_new(transforms, 0, [], published, memory, names, grown, False, check)
        assert [t is not None for t in transforms] == placed, (first, again)
        assert judged_again == sorted(again), (first, again)


def test_a_new_seed_joined_to_published_grids_waits_like_any_new_placement():
    """r and x were published (r the reference, x 6 m along). The next estimation places them and a new grid s,
    seeded by s (its frame). The merge moves to r's frame and s is held: s's link to them is new. x placed 2 m from
    where it was shown relative to r is new too, and waits; as it was shown, it stands."""
    names = ['r', 'x', 's']
    grids = [_free_strip(0.0, 8.0, 4.0), _free_strip(0.0, 4.0, 4.0), _free_strip(0.0, 4.0, 4.0)]
    published = [np.eye(3), tf.rigid(6.0, 0.0, 0.0), None]
    in_s = tf.rigid(-3.0, 1.0, 0.4)   # r's map frame -> s's
    for x_moved, shown in ((0.0, ['r', 'x']), (2.0, ['r'])):
        result = Estimate([in_s, in_s @ tf.rigid(6.0 + x_moved, 0.0, 0.0), np.eye(3)], 2)
        anchor_on_published(result, published, grids)
        assert result.reference == 0 and np.allclose(result.transforms[0], np.eye(3))
        assert np.allclose(result.transforms[2], tf.inverse(in_s))
        hold_new(result.transforms, result.reference, result.pairs, published, EstimationMemory(), names, grids,
                 False)
        assert [n for n, t in zip(names, result.transforms) if t is not None] == shown


def test_a_reference_whose_map_frame_moved_gives_the_frame_to_the_published_grids_that_stayed():
    """r (the reference), x and y were published; r's map turned (a SLAM failure), and the next estimation, seeded
    by r again, places x and y together 20 degrees from where they were shown relative to r. The merge moves to the
    frame of x, the larger of the two that stayed as shown, and r waits."""
    names = ['r', 'x', 'y']
    grids = [_free_strip(0.0, 8.0, 4.0), _free_strip(0.0, 6.0, 4.0), _free_strip(0.0, 4.0, 4.0)]
    published = [np.eye(3), tf.rigid(6.0, 0.0, 0.0), tf.rigid(6.0, 5.0, 0.0)]
    turn = tf.rigid(0.0, 0.0, np.radians(20.0))
    result = Estimate([np.eye(3), turn @ published[1], turn @ published[2]], 0)
    anchor_on_published(result, published, grids)
    assert result.reference == 1 and np.allclose(result.transforms[2], tf.inverse(published[1]) @ published[2])
    hold_new(result.transforms, result.reference, result.pairs, published, EstimationMemory(), names, grids, False)
    assert [n for n, t in zip(names, result.transforms) if t is not None] == ['x', 'y']

def test_a_held_alias_does_not_push_a_right_robot_out_of_the_merge(repo_root):
    """The first 11 estimations of a live 12-robot run (seed 1; test/data/demo12_held_alias, a record of
    recording.py), estimated again as the node does but without a search budget. As recorded, at 25.2 sim s robots 5
    and 7 fit the merge 28 m along a corridor of alike rooms and were held; tracking checked them with the published
    robots, and robot_4's check beside them failed (agreement 0.81): robots 4 and 3 left the merge for five
    estimations, and with them what contradicted the alias. Robot 4 holds without them, they do not hold on the
    published maps without it: the held ones are in doubt. Since a search's placement on little of a map joins only
    where the members agree wall for wall, robots 5 and 7 are not held there; robot_3 is held at an alias (over
    5 m off) instead. No robot published leaves while the reference stays, none is published off."""
    from multirobot_map_merge.estimation.union import known_corners
    from multirobot_map_merge.recording import read_estimations
    from multirobot_map_merge.ros.params import MapMergeParams

    folder = repo_root / 'test' / 'data' / 'demo12_held_alias'
    poses = json.loads((folder / 'case.json').read_text())['start_poses']
    starts = {'/' + n: tf.rigid(*p[:3]) for n, p in poses.items()}
    pipeline = MergingPipeline(MapMergeParams().estimation_settings().replace(search_budget_s=float('inf')))
    published, reference, held_off = {}, None, set()
    for rec in read_estimations(str(folder)):
        pipeline.feed(rec.grids)
        preferred = rec.names.index(reference) if reference in rec.names else None
        result = pipeline.estimate(preferred_reference=preferred, previous=[published.get(n) for n in rec.names],
                                   names=rec.names, now=rec.now)
        now = {n: t for n, t in zip(rec.names, result.transforms) if t is not None}
        ref = rec.names[result.reference] if result.reference is not None else None
        grid_of = dict(zip(rec.names, rec.grids))

        def off(n, t, frame):
            rot, shift = tf.difference(tf.inverse(starts[frame]) @ starts[n], t, known_corners(grid_of[n]))
            return np.degrees(rot), shift

        if ref == reference and len(published) > 1:
            assert set(published) <= set(now), f'#{rec.index}: {sorted(set(published) - set(now))} left the merge'
        for n, t in now.items():
            assert off(n, t, ref)[0] < 1.0 and off(n, t, ref)[1] < 0.5, f'#{rec.index}: {n} published off'
        held_off |= {n for n, h in pipeline.memory.held.items()
                     if off(n, h.transform, pipeline.memory.held_reference)[1] > 5.0}
        published, reference = now, ref
    assert held_off   # the case is still there: a robot was held at an alias
    assert {'/robot_3', '/robot_4', '/robot_6', '/robot_9'} <= set(published)


def test_a_held_placement_gives_way_only_to_a_confirmed_one_the_published_maps_support_more():
    """tracking.held_in_doubt on stub checks: published grid 1 failed beside held grid 2 (near it). It holds without
    2 on 500 agreeing walls: 2 is dropped when it holds on fewer of the published maps' walls without 1, or not at
    all; with as many, or when 1 fails without 2 too, nothing is decided here (the least agreeing failure goes)."""
    from multirobot_map_merge.estimation.pair import PairMatch
    from multirobot_map_merge.estimation.tracking import Check, held_in_doubt
    from multirobot_map_merge.estimation.verify import Placement

    placed = {0: np.eye(3), 1: tf.rigid(3.0, 0.0, 0.0), 2: tf.rigid(5.0, 0.0, 0.0)}
    footprints = {0: (0.0, 0.0, 4.0, 4.0), 1: (3.0, 0.0, 7.0, 4.0), 2: (5.0, 0.0, 9.0, 4.0)}

    def stub(supports):
        def check(k, without):
            support = supports[k]
            match = PairMatch(k, 0)
            match.best = Placement(np.eye(3), support=support or 0, agreement=1.0, overlap_m2=10.0)
            return Check(k, np.eye(3) if support is not None else None, match)
        return check

    assert held_in_doubt([1], placed, footprints, {2}, stub({1: 500, 2: 120})) == {2: 1}
    assert held_in_doubt([1], placed, footprints, {2}, stub({1: 500, 2: None})) == {2: 1}
    assert held_in_doubt([1], placed, footprints, {2}, stub({1: 500, 2: 500})) == {}
    assert held_in_doubt([1], placed, footprints, {2}, stub({1: None, 2: 120})) == {}
    assert held_in_doubt([1], placed, footprints, set(), stub({1: 500, 2: 120})) == {}
