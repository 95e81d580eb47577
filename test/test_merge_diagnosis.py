"""bench/merge_diagnosis.py: why each mergeable map is left out or placed wrong, from a merge_maps -v log."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'bench'))
from merge_diagnosis import cause_counts, diagnose  # noqa: E402

LINE = ('DEBUG pair {k}-{s}: 120 descriptor matches (9 inliers), 2000 wall correspondences (1700 inliers), '
        'confidence 2.5, agreement {a}, overlap {o} m2, {why}')


def log(*rows) -> str:
    return '\n'.join(LINE.format(k=k, s=s, a=a, o=o, why=why) for k, s, a, o, why in rows)


def scenario(n: int, mergeable, placements, reference='map_00.yaml'):
    truth = {'maps': [{'file': f'map_{i:02d}.yaml'} for i in range(n)], 'mergeable': mergeable}
    scored = {'reference': f'/x/{reference}', 'placements': [
        {'file': f'/x/map_{i:02d}.yaml', 'ok': ok, 'rot_deg': 0.0 if ok else 90.0, 'trans_cells': 0.0 if ok else 40.0}
        for i, ok in placements]}
    return truth, scored


def test_each_map_not_placed_right_gets_its_cause():
    # 0 the reference, 1 placed right, 2 placed wrong, 3 alone and refused, 4 and 5 a side group refused as one,
    # 6 joined and was taken out again
    text = log((1, 0, 0.99, 80, 'accepted'),
               (2, 0, 1.0, 60, 'accepted'),
               (3, 0, 0.95, 40, 'ambiguous: another placement agrees 0.95 with support 900 vs 950'),
               (3, 0, 0.86, 70, 'agreement 0.86 < 0.91'),
               (5, 4, 0.99, 90, 'accepted'),
               (4, 0, 0.93, 50, '60 contradicting walls well inside both maps, more than 1% of 1800 agreeing'),
               (6, 0, 0.97, 50, 'accepted'))
    truth, scored = scenario(7, [0, 1, 2, 3, 4, 5, 6], [(1, True), (2, False)])
    verdicts = {v.map_index: v for v in diagnose(text, scored, truth)}
    assert sorted(verdicts) == [2, 3, 4, 5, 6]
    assert verdicts[2].outcome == 'placed wrong' and verdicts[2].cause == 'accepted wrong'
    assert verdicts[3].outcome == 'left out' and verdicts[3].cause == 'agreement'   # the last refusal counts
    assert verdicts[4].cause == verdicts[5].cause == 'contradicting walls'
    assert verdicts[4].side_group == [5] and verdicts[5].side_group == [4]
    assert verdicts[6].cause == 'joined, then removed'
    assert cause_counts(list(verdicts.values()))['left out: contradicting walls'] == 2


def test_the_log_as_merge_maps_writes_it_is_read_with_its_precision_and_the_joins_that_did_not_happen():
    """merge_maps -v writes the expected error at the far corners before the verdict of a match whose precision was
    judged ('..., accepted' too), and a line of its own when a grid accepted by a match does not join by it (it waits,
    or the end's rules keep it out). 1 joined, 2 and 3 a side group refused beside a larger place, 4 accepted and not
    joined (it shared too little), 5 joined and left again."""
    precise = 'expected error at the far corners 0.05 m, '
    text = '\n'.join([
        log((1, 0, 1.0, 80, precise + 'accepted'), (3, 2, 0.99, 90, precise + 'accepted'),
            (2, 0, 1.0, 10, precise + 'the unions overlap elsewhere: a place with support 3391 (here 165) agrees '
                                      '0.74 and contradicts'),
            (4, 0, 1.0, 20, precise + 'accepted')),
        'DEBUG grid 4 left out stays out: placed on 0.17 of its area, less than 0.50',
        log((5, 0, 1.0, 60, precise + 'accepted')),
        'DEBUG grid 5 leaves group 0: a search onto the final merge without it places it elsewhere',
        log((5, 0, 0.97, 50, precise + 'agreement 0.97 < 0.98'))])
    truth, scored = scenario(6, [0, 1, 2, 3, 4, 5], [(1, True)])
    verdicts = {v.map_index: v for v in diagnose(text, scored, truth)}
    assert sorted(verdicts) == [2, 3, 4, 5]
    assert verdicts[2].side_group == [3] and verdicts[2].cause == 'the unions overlap elsewhere'
    assert verdicts[4].cause == 'accepted, not joined' and 'placed on 0.17 of its area' in verdicts[4].detail
    assert verdicts[5].cause.startswith('joined, then removed') and verdicts[5].side_group == []


def test_maps_placed_right_or_not_mergeable_are_not_reported():
    text = log((1, 0, 0.99, 80, 'accepted'), (2, 0, 0.5, 10, 'agreement 0.50 < 0.91'))
    truth, scored = scenario(3, [0, 1], [(1, True)])
    assert diagnose(text, scored, truth) == []
    truth, scored = scenario(3, [0, 1, 2], [(1, True)])
    (v,) = diagnose(text, scored, truth)
    assert (v.map_index, v.cause) == (2, 'agreement')


def test_replayed_labels_say_which_match_would_place_the_map():
    from merge_diagnosis import REPLAYED, replayed_label
    assert replayed_label([('pair', True, True), ('union', True, True)]) == REPLAYED['union right']
    assert replayed_label([('pair', False, True), ('pair', True, True), ('union', False, False)]) == \
        REPLAYED['pair right']
    assert replayed_label([('pair', True, False), ('union', False, True)]) == REPLAYED['wrong']
    assert replayed_label([('pair', False, True), ('union', False, False)]) == REPLAYED['refused']
    assert replayed_label([('union', False, False)]) == REPLAYED['no pair']


def test_a_log_of_the_maps_given_in_reverse_order_is_read_with_the_truth_in_that_order():
    """bench_merge.py --generated --reversed: merge_maps -v names a map by its place in the list it was given, so the
    diagnosis reads the log with the truth reversed (bench_merge.reversed_truth)."""
    from bench_merge import reversed_truth
    truth, scored = scenario(4, [0, 1, 3], [(0, True), (1, True)])
    truth['components'] = [[0, 1, 3]]
    back = reversed_truth(truth)
    assert [m['file'] for m in back['maps']] == ['map_03.yaml', 'map_02.yaml', 'map_01.yaml', 'map_00.yaml']
    assert back['mergeable'] == [0, 2, 3] and back['components'] == [[0, 2, 3]]
    # map_03, given first, refused onto the group of map_00, given last
    [verdict] = diagnose(log((0, 3, 0.8, 30.0, 'agreement 0.80 < 0.91')), scored, back)
    assert (verdict.map_index, verdict.outcome, verdict.cause) == (0, 'left out', 'agreement')


def test_a_truth_reordered_for_a_drawn_order_names_each_map_by_its_place_in_that_order():
    """bench_merge.py --generated --shuffled S: the maps are given in an order drawn with S, and the truth's indices
    (mergeable maps, components) follow them there; the same S draws the same order."""
    from bench_merge import reordered_truth, shuffled_truth
    truth, _ = scenario(4, [0, 1, 3], [(0, True), (1, True)])
    truth['components'] = [[0, 1, 3]]
    moved = reordered_truth(truth, [2, 0, 3, 1])
    assert [m['file'] for m in moved['maps']] == ['map_02.yaml', 'map_00.yaml', 'map_03.yaml', 'map_01.yaml']
    assert moved['mergeable'] == [1, 2, 3] and moved['components'] == [[1, 2, 3]]
    drawn = shuffled_truth(truth, 5)
    assert drawn == shuffled_truth(truth, 5)
    assert sorted(m['file'] for m in drawn['maps']) == sorted(m['file'] for m in truth['maps'])
    files = [m['file'] for m in drawn['maps']]
    assert [files[k] for k in drawn['mergeable']] == \
        sorted((truth['maps'][k]['file'] for k in truth['mergeable']), key=files.index)


def test_the_table_of_several_orders_or_seeds_has_a_column_each_and_their_totals():
    """bench_merge.py --generated --shuffled S S ... (or --seeds S ...): a column per variant, '-' for a building a
    variant did not score, and a last row of each variant's totals."""
    from bench_merge import variants_table

    def row(name, correct, mergeable, wrong):
        return {'name': name, 'correct': correct, 'mergeable': mergeable, 'wrong': wrong}
    per_variant = {'order 3': {'a36': row('a36', 27, 27, 0), 'b36': row('b36', 17, 27, 9)},
                   'order 4': {'a36': row('a36', 25, 27, 0)}}
    lines = variants_table(['a36', 'b36'], per_variant)
    assert lines[0] == '| building | order 3: right / mergeable, false | order 4: right / mergeable, false |'
    assert lines[2:] == ['| a36 | 27/27, 0 | 25/27, 0 |', '| b36 | 17/27, 9 | - |', '| all | 44/54, 9 | 25/27, 0 |']
    # with the maps the rules hold at the truth (merge_diagnosis.evidence), a column of them first
    for rows in per_variant.values():
        for r in rows.values():
            r['held'] = {'a36': 27, 'b36': 25}[r['name']]
    lines = variants_table(['a36', 'b36'], per_variant)
    assert lines[0].startswith('| building | held at the truth | order 3')
    assert lines[2:] == ['| a36 | 27 | 27/27, 0 | 25/27, 0 |', '| b36 | 25 | 17/27, 9 | - |',
                         '| all | 52 | 44/54, 9 | 25/27, 0 |']
    # and how many of those only narrowly (merge_diagnosis.NARROW_MARGIN)
    for r in per_variant['order 3'].values():
        r['narrowly'] = {'a36': 0, 'b36': 12}[r['name']]
    lines = variants_table(['a36', 'b36'], per_variant)
    assert lines[2:] == ['| a36 | 27 | 27/27, 0 | 25/27, 0 |', '| b36 | 25 (12 narrowly) | 17/27, 9 | - |',
                         '| all | 52 (12 narrowly) | 44/54, 9 | 25/27, 0 |']


def test_healthy_members_that_contradict_each_other_in_the_merge_are_named(repo_root, tmp_path):
    """bench_merge.py --generated names, for a merge with maps placed wrong, the healthy members that contradict each
    other as pairs: two healthy maps of a warehouse (test/data/warehouse_rack_slide) at their true places are not
    named; with one turned a quarter turn about the middle of its map, both are."""
    import json
    import math
    from merge_diagnosis import contradicting_members
    from multirobot_map_merge import transforms as tf
    folder = repo_root / 'test' / 'data' / 'warehouse_rack_slide'
    truth = json.loads((folder / 'truth.json').read_text())
    pose = {m['file']: tf.rigid(*m['pose']) for m in truth['maps']}
    true_robot = tf.inverse(pose['other.yaml']) @ pose['robot.yaml']   # robot's map frame -> other's

    def merged(robot: np.ndarray) -> list:
        maps = [{'file': str(folder / name), 'included': True,
                 'transform': {'x': float(t[0, 2]), 'y': float(t[1, 2]), 'yaw': math.atan2(t[1, 0], t[0, 0])}}
                for name, t in (('other.yaml', np.eye(3)), ('robot.yaml', robot))]
        out = tmp_path / 'result'
        out.mkdir(exist_ok=True)
        (out / 'result.json').write_text(json.dumps({'maps': maps}))
        return contradicting_members(folder, truth, out)

    assert merged(true_robot) == []
    from multirobot_map_merge.mapio import load_map
    robot = load_map(str(folder / 'robot.yaml'))
    rows, cols = np.nonzero(robot.data >= 0)   # its known cells: the turn about their middle keeps the overlap
    centre = true_robot @ robot.cell_to_map() @ np.array([cols.mean(), rows.mean(), 1.0])
    turn = tf.translation(centre[0], centre[1]) @ tf.rigid(0.0, 0.0, math.pi / 2) \
        @ tf.translation(-centre[0], -centre[1])
    lines = merged(turn @ true_robot)
    assert len(lines) == 1 and 'contradicts' in lines[0], lines


def test_maps_whose_true_places_pass_no_rule_are_told_apart_from_those_an_estimation_could_place(repo_root):
    """merge_diagnosis.evidence: two maps of a warehouse (test/data/warehouse_rack_slide) at their true places are
    held together by the rules of a pair, and by the rules onto a union where the truth's overlap figures skip the
    pair; with a 'truth' that places one of them 3 m off, no rule holds it, and the refusal is given."""
    import json
    import math
    from merge_diagnosis import evidence
    folder = repo_root / 'test' / 'data' / 'warehouse_rack_slide'
    truth = json.loads((folder / 'truth.json').read_text())

    def judged(shared_m2: float, robot_shift_m: float = 0.0):
        maps = [dict(m, broken=False) for m in truth['maps']]
        x, y, yaw = maps[0]['pose']
        maps[0]['pose'] = [x + robot_shift_m * math.cos(yaw), y + robot_shift_m * math.sin(yaw), yaw]
        return evidence(folder, {'maps': maps, 'mergeable': [0, 1],
                                 'overlap': {'shared_m2': [[0.0, shared_m2], [shared_m2, 0.0]]}})

    right = judged(100.0)
    assert right.held == [0, 1] and right.without == {}
    assert judged(0.0).held == [0, 1]   # no pair judged: the map joins the other's union
    off = judged(100.0, 3.0)
    assert len(off.held) == 1 and len(off.without) == 1
    (why,) = off.without.values()
    assert 'agreement' in why or 'contradicting' in why, why
    assert right.narrowly == [] and off.narrowly == []   # held with a margin, or not held at all


def test_maps_held_only_at_the_edge_of_a_rule_are_told_apart(repo_root):
    """merge_diagnosis.evidence's margin: the two maps of test/data/warehouse_rack_slide, held together at their true
    places by 109 m2 in common, are held as firmly by rules asking the same (a margin of 1), and only narrowly by
    rules asking ten times the support and common area and a tenth of the uncertainty."""
    import json
    from merge_diagnosis import evidence
    folder = repo_root / 'test' / 'data' / 'warehouse_rack_slide'
    truth = json.loads((folder / 'truth.json').read_text())
    truth = {'maps': [dict(m, broken=False) for m in truth['maps']], 'mergeable': [0, 1],
             'overlap': {'shared_m2': [[0.0, 109.0], [109.0, 0.0]]}}
    assert evidence(folder, truth, margin=None).narrowly == []
    assert evidence(folder, truth, margin=1.0).narrowly == []
    strict = evidence(folder, truth, margin=10.0)
    assert strict.held == [0, 1] and len(strict.narrowly) == 1


def test_a_map_left_out_is_matched_again_against_the_right_placed_maps_it_overlaps(repo_root, tmp_path):
    """merge_diagnosis.replay (bench_merge --generated --replay): map robot of test/data/warehouse_rack_slide, left
    out, is matched again against the right-placed map it overlaps (other, 109 m2 at the truth): its best placement
    is right, and refused beside an alias along the racks that agrees as well; without a merged map of the run, it
    says so."""
    import json
    from merge_diagnosis import REPLAYED, Verdict, replay
    from multirobot_map_merge.estimation.union import known_corners
    from multirobot_map_merge.mapio import load_map
    folder = repo_root / 'test' / 'data' / 'warehouse_rack_slide'
    truth = json.loads((folder / 'truth.json').read_text())
    maps = []
    for m in truth['maps']:
        grid = load_map(str(folder / m['file']))
        maps.append(dict(m, broken=False, resolution=grid.resolution, known_bbox=known_corners(grid).tolist()))
    truth = {'maps': maps, 'mergeable': [0, 1],
             'overlap': {'shared_m2': [[0.0, 109.0], [109.0, 0.0]], 'fraction': [[0.0, 0.5], [0.5, 0.0]],
                         'min_shared_m2': 4.0, 'min_fraction': 0.05}}
    scored = {'placements': [{'file': 'other.yaml', 'ok': True}], 'reference': 'other.yaml'}
    ((line, label),) = replay(folder, truth, scored, tmp_path, [Verdict(0, 'left out', 'support', '')])
    assert label == REPLAYED['refused'], line
    assert 'pair with other (109 m2): refused right' in line and 'ambiguous' in line, line
    assert 'no merged map to match against' in line, line
