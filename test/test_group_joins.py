"""A join of two groups beside a place where their unions overlap far more and contradict (pair.ELSEWHERE_SUPPORT):
in a building of identical rooms the small join is a guess, right or wrong alike, and it is refused."""
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
