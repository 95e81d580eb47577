"""Confirmation (estimation/confirmation.py): with a memory (the node), a grid placed for the first time is published
once the next estimation confirms it on the maps of then."""
import json

import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.confirmation import HELD, STATIC_AFTER_S, hold_new
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
    a change of the map it was placed on confirms it at once, as without a clock."""
    grids = _chain(repo_root)
    pipeline = MergingPipeline()
    assert _placed(_estimate(pipeline, grids, now=100.0)) == {'a'}
    waited = 0.0
    while waited + 2.0 < STATIC_AFTER_S:
        waited += 2.0
        assert _reasons(_estimate(pipeline, grids, now=100.0 + waited)) == {'b': HELD, 'c': HELD}, waited
    assert _placed(_estimate(pipeline, grids, now=100.0 + STATIC_AFTER_S)) == {'a', 'b', 'c'}
    # the maps changed meanwhile: their placements count from the first estimation on the new maps
    grown = MergingPipeline()
    _estimate(grown, grids, now=0.0)
    b = grids[1]
    edited = b.data.copy()
    edited[0, 0] = 0 if edited[0, 0] != 0 else 100
    changed = [grids[0], Grid(edited, b.resolution, b.origin, b.frame_id), grids[2]]
    assert _placed(_estimate(grown, changed, now=2.0)) == {'a', 'b'}   # b's own map changed: confirmed
    assert _reasons(_estimate(grown, changed, now=4.0)) == {'c': HELD}


def test_a_held_placement_that_does_not_hold_on_the_next_maps_is_not_published(repo_root):
    """Map c's frame moves by 3 m between two estimations (its held placement is now wrong): it is placed anew and
    held again (and b, whose map has not changed while another has, with it), then published at its new place once
    the maps stay the same; a map that matches nothing is neither published nor held."""
    grids = _chain(repo_root)
    pipeline = MergingPipeline()
    _estimate(pipeline, grids)
    held_c = pipeline.memory.held['c'][0]
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
    each end. At 7.2 sim s robot_12 fits the room next to robot_6's through a door (agreement 0.99), 179 degrees
    from the truth; on the maps of 10.2 sim s that placement no longer holds, so it is never published."""
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
    assert early.transforms[3] is None and early.held == 1
    held = pipeline.memory.held['robot_12'][0]
    rot, _ = tf.difference(held, true[3], np.zeros((1, 2)))
    assert abs(np.degrees(rot)) > 170   # the placement that would have been published
    pipeline.feed(maps('later'))
    later = pipeline.estimate(preferred_reference=0, previous=early.transforms, names=names)
    assert later.transforms[3] is None
    assert all(later.transforms[k] is not None for k in range(3))


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
    the frame of the new seed, are confirmed where they stayed; the old seed is held anew."""
    grid = Grid(np.zeros((40, 40), np.int8), 0.05, (0.0, 0.0, 0.0))
    grids = [grid] * 4
    names = ['r', 'a', 'b', 'c']
    to_b, to_c = tf.rigid(1.5, 0.2, 0.3), tf.rigid(-0.4, 2.0, -1.1)
    memory = EstimationMemory()
    first = [None, np.eye(3), to_b, to_c]   # placed around a
    assert hold_new(first, 1, [], [np.eye(3), None, None, None], memory, names, grids,
                    ['r1', 'a1', 'b1', 'c1'], False) == 2
    # the next estimation, on grown maps, seeds the group with b: the same placements in b's frame
    second = [None, tf.inverse(to_b), np.eye(3), tf.inverse(to_b) @ to_c]
    pairs = []
    assert hold_new(second, 2, pairs, [np.eye(3), None, None, None], memory, names, grids,
                    ['r2', 'a2', 'b2', 'c2'], False) == 1
    assert second[3] is not None and second[1] is None
    assert [names[p.i] for p in pairs] == ['a'] and pairs[0].reason == HELD
