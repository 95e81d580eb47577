"""A join of two groups beside a place where their unions overlap far more and contradict (pair.ELSEWHERE_SUPPORT):
in a building of identical rooms the small join is a guess, right or wrong alike, and it is refused."""
import dataclasses

import numpy as np

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation import pair
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.grid import Grid

RES = 0.05
ROOM = 80   # pixels


def corridor_of_rooms(n: int) -> np.ndarray:
    """n identical rooms in a row, 4 m x 5 m each, a door from each to a 2 m corridor, the same stubs in each."""
    world = np.zeros((140, n * ROOM + 1), np.int8)
    world[0, :] = world[-1, :] = world[:, 0] = world[:, -1] = 100
    world[100, :] = 100
    for r in range(n):
        world[:100, r * ROOM] = 100
        world[100, r * ROOM + 30:r * ROOM + 50] = 0          # the door
        world[20:40, r * ROOM + 20] = 100
        world[60, r * ROOM + 40:r * ROOM + 60] = 100
    return world


def seen(world: np.ndarray, c0: int, c1: int) -> np.ndarray:
    data = np.full(world.shape, -1, np.int8)
    data[:, c0:c1] = world[:, c0:c1]
    return data


def test_a_small_join_beside_a_much_larger_contradicted_overlap_is_refused(monkeypatch):
    """Union A saw rooms 1-8, union B rooms 2-8 with a wall across room 8 that A saw free (a broken member). At the
    truth they overlap in seven rooms and contradict; six rooms further along B's first room fits A's last one wall
    for wall, and the rest of B lies where A knows nothing. Without the rule the unions join there, 24 m off."""
    world = corridor_of_rooms(10)
    b = seen(world, ROOM, 8 * ROOM + 1)
    b[10:90, 7 * ROOM + 40] = 100
    pa, pb = (prepare(Grid(d, RES), RES, 'akaze') for d in (seen(world, 0, 8 * ROOM + 1), b))

    def px(metric: np.ndarray) -> np.ndarray:
        return tf.inverse(pa.px_to_map) @ metric @ pb.px_to_map
    alias, truth = px(tf.translation(6 * ROOM * RES, 0.0)), px(np.eye(3))
    # the candidates the descriptors would propose in such a building: both places
    monkeypatch.setattr(pair, 'hypotheses', lambda p, q, s, rng: [alias.copy(), truth.copy()])
    monkeypatch.setattr(pair, 'correlate_candidates', lambda *args, **kwargs: [])
    s = EstimationSettings()
    m = pair.match_pair(1, 0, pb, pa, s, onto_union=True, between_groups=True)
    assert not m.accepted and m.reason.startswith('the unions overlap elsewhere')
    monkeypatch.setattr(pair, 'ELSEWHERE_SUPPORT', float('inf'))
    m = pair.match_pair(1, 0, pb, pa, s, onto_union=True, between_groups=True)
    assert m.accepted and np.allclose(m.transform_m[:2, 2], (6 * ROOM * RES, 0.0), atol=0.1)
    # as a single grid onto a union (not two groups) the rule does not apply
    monkeypatch.setattr(pair, 'ELSEWHERE_SUPPORT', 4.0)
    assert pair.match_pair(1, 0, pb, pa, s, onto_union=True, search=False).accepted


def lattice_maze(cells_x: int, cells_y: int, wall_share: float, seed: int) -> np.ndarray:
    """A maze on a lattice of 1 m cells: each side of a cell is a wall with probability `wall_share`, else open."""
    rng = np.random.default_rng(seed)
    cell = 20
    world = np.zeros((cells_y * cell + 1, cells_x * cell + 1), np.int8)
    world[0, :] = world[-1, :] = world[:, 0] = world[:, -1] = 100
    for cy in range(cells_y):
        for cx in range(cells_x):
            if rng.random() < wall_share:
                world[cy * cell, cx * cell:(cx + 1) * cell + 1] = 100
            if rng.random() < wall_share:
                world[cy * cell:(cy + 1) * cell + 1, cx * cell] = 100
    return world


def test_a_precise_join_beside_a_place_that_fits_only_the_lattice_stands(monkeypatch):
    """In a maze every place a cell's width along lines up the walls' lattice, and two unions overlap there far more
    than at the truth, agreeing where both mazes have a wall and contradicting elsewhere (0.74 here): that place is
    no near miss (pair.NEAR_MISS), and a precise join beside it stands. Were the join less precise than
    ELSEWHERE_PRECISION of the limit, the place would refuse it, as a place the unions nearly fit refuses any."""
    world = lattice_maze(30, 8, 0.6, 0)
    a, b = seen(world, 0, 16 * 20 + 1), seen(world, 14 * 20, 30 * 20 + 1)   # 2 m in common at the truth
    pa, pb = (prepare(Grid(d, RES), RES, 'akaze') for d in (a, b))

    def px(metric: np.ndarray) -> np.ndarray:
        return tf.inverse(pa.px_to_map) @ metric @ pb.px_to_map
    lattice, truth = px(tf.translation(-10 * 20 * RES, 0.0)), px(np.eye(3))   # 10 cells off: 12 m in common
    monkeypatch.setattr(pair, 'hypotheses', lambda p, q, s, rng: [lattice.copy(), truth.copy()])
    monkeypatch.setattr(pair, 'correlate_candidates', lambda *args, **kwargs: [])
    s = EstimationSettings()
    m = pair.match_pair(1, 0, pb, pa, s, onto_union=True, between_groups=True)
    at_lattice = next(c for c in m.alternatives if np.allclose(c.transform[:2, 2], lattice[:2, 2], atol=3))
    assert 0.6 <= at_lattice.agreement < pair.NEAR_MISS['min_agreement']
    assert at_lattice.support >= pair.ELSEWHERE_SUPPORT * m.best.support
    assert m.best.corner_error_m <= pair.ELSEWHERE_PRECISION * s.max_corner_error_m
    assert m.accepted and np.allclose(m.transform_m[:2, 2], (0.0, 0.0), atol=0.1)
    monkeypatch.setattr(pair, 'ELSEWHERE_PRECISION', 0.0)
    m = pair.match_pair(1, 0, pb, pa, s, onto_union=True, between_groups=True)
    assert not m.accepted and m.reason.startswith('the unions overlap elsewhere')


def test_two_groups_that_meet_by_one_member_join_as_that_member_would_alone(repo_root, monkeypatch):
    """test/data/classic_bridge: the side group of 12 maps meets the rest of classic36 by the 15.6 m2 it shares with
    map_21. Their unions placed at the truth pass every rule but precision when the side group's union has no wall
    direction (as when it held a broken map: classic36 seeded by map_05, 0.66 m expected at its far corners). map_21
    alone passes there (its own corners; seeded by the largest map it joined alone, and the others onto it), so the
    two groups join. Without map_21 no member of the side group meets the rest by the rules of a pair: they don't."""
    from concurrent.futures import ThreadPoolExecutor
    from test_orientation import _bridge
    from multirobot_map_merge.estimation import orientation
    from multirobot_map_merge.estimation.growth import Grower
    from multirobot_map_merge.estimation.verify import IMPRECISE, refusal, verify
    grids, true, _, side_names = _bridge(repo_root)
    real, blind = orientation.orientation, []
    monkeypatch.setattr(orientation, 'orientation', lambda p: None if any(p is b for b in blind) else real(p))
    names = side_names + ['map_16', 'map_24', 'rest']
    s = EstimationSettings(processes=False)
    grower = Grower([grids[n] for n in names], [prepare(grids[n], RES, s.feature) for n in names], RES, s,
                    ThreadPoolExecutor(max_workers=2), names.index('rest'), None)
    rest = names.index('rest')

    def group(members, seed):
        # placed at the truth, in the frame of `seed`
        return grower.group_of(seed, {k: tf.inverse(true[names[seed]]) @ true[names[k]] for k in members})

    side_to_rest = true['map_21']   # metric: the side group's frame (map_21's) -> the frame of the rest (map_16's)
    side = group(range(len(side_names)), names.index('map_21'))
    big = group([names.index('map_16'), names.index('map_24'), rest], rest)
    part, union = side.union.prepared(), big.union.prepared()
    blind.append(part)
    at_truth = verify(part, union, tf.inverse(union.px_to_map) @ side_to_rest @ part.px_to_map, s)
    assert refusal(at_truth, part, union, s, onto_union=True).startswith(IMPRECISE)
    assert grower.joins_where_met(side, big, side_to_rest)
    assert grower.joins_where_met(big, side, tf.inverse(side_to_rest))   # either group may be the smaller
    alone = group([names.index('map_21')], names.index('map_21'))
    assert not grower.joins_where_met(alone, big, side_to_rest)   # a map alone: its own match judged it
    without = [k for k in range(len(side_names)) if names[k] != 'map_21']
    others = group(without, without[0])
    blind.append(others.union.prepared())
    assert not grower.joins_where_met(others, big, side_to_rest @ tf.inverse(true['map_21']) @ true[names[without[0]]])

    # the match of the two unions, its descriptors proposing the truth: refused only as imprecise, and joined as one
    monkeypatch.setattr(pair, 'hypotheses', lambda p, q, s, rng: [
        tf.inverse(union.px_to_map) @ side_to_rest @ part.px_to_map])
    monkeypatch.setattr(pair, 'correlate_candidates', lambda *args, **kwargs: [])
    # and refined in place: ICP's sampled walls on 15 m2 of two unions can settle 0.9 agreeing beside the truth, as
    # they do by some draws (this case with the settings' seed 0: agreement 0.918, 0.78 m expected at the far corners)
    monkeypatch.setattr(pair, 'icp', lambda pi, pj, model, *args, **kwargs: model)
    m = pair.match_pair(side.seed, big.seed, part, union, s, onto_union=True, between_groups=True)
    assert m.reason.startswith(IMPRECISE) and m.imprecise_only
    # merge_groups matches the smaller union (the rest's) onto the larger: this match, restated so
    monkeypatch.setattr(grower, '_match_groups', lambda small, larger: dataclasses.replace(
        m, i=small.seed, j=larger.seed, transform_m=tf.inverse(m.transform_m)))
    groups = grower.merge_groups([big, side], [])
    assert len(groups) == 1 and len(groups[0].members) == len(names)


def test_a_place_the_unions_nearly_fit_refuses_a_join_though_a_larger_one_fits_only_the_lattice():
    """pair.overlap_elsewhere asks every distinct place with ELSEWHERE_SUPPORT times the join's support: a place the
    unions nearly fit (NEAR_MISS) refuses a precise join even where a larger place, lining up only a maze's lattice,
    would not; the largest alone decided before."""
    s = EstimationSettings()
    pi = prepare(Grid(seen(lattice_maze(10, 5, 0.6, 1), 0, 201), RES), RES, 'akaze')

    def at(x_px: float, support: int, agreement: float, corner_error_m: float = 0.0) -> pair.Placement:
        return pair.Placement(tf.translation(x_px, 0.0), support=support, agreement=agreement, overlap_m2=20.0,
                              corner_error_m=corner_error_m)
    join = at(0, 100, 1.0, 0.05)
    lattice, near_miss = at(200, 1000, 0.7), at(400, 500, 0.85)
    assert pair.overlap_elsewhere(join, [lattice, near_miss], pi, s, onto_union=True) is near_miss
    assert pair.overlap_elsewhere(join, [lattice], pi, s, onto_union=True) is None
    # a near miss with less than ELSEWHERE_SUPPORT times the join's support says nothing
    assert pair.overlap_elsewhere(join, [lattice, at(400, 300, 0.85)], pi, s, onto_union=True) is None
    # an imprecise join is refused beside the largest place, near miss or not
    loose = at(0, 100, 1.0, 0.2)
    assert pair.overlap_elsewhere(loose, [lattice], pi, s, onto_union=True) is lattice
