"""The nearest descriptors among a union's, from those kept per member (neighbours.py), against a direct match."""
import numpy as np
import pytest

from multirobot_map_merge.estimation.hypotheses import _ratio_tested, _two_nearest, putative_matches
from multirobot_map_merge.estimation.neighbours import K, NeighbourCache, two_nearest


def _descriptors(rng, n, bytes_=64):
    return rng.integers(0, 256, (n, bytes_), dtype=np.uint8)


def _near_copies(rng, base, flips):
    """Copies of `base` with `flips` random bits flipped in each row: the same corners seen by another map."""
    out = base.copy()
    for row in out:
        for bit in rng.choice(base.shape[1] * 8, flips, replace=False):
            row[bit // 8] ^= np.uint8(1 << (bit % 8))
    return out


@pytest.mark.parametrize('seed', range(12))
def test_two_nearest_among_pooled_members_equal_a_direct_match(seed):
    """Members share corners (near copies), and the union takes only some rows of each (a corner seen twice counts
    once): the kept K nearest of a member often hold fewer than two of its taken rows, so the bound and the direct
    match of those rows decide. The distances, the nearest and the ratio test's pairs equal a direct match's."""
    rng = np.random.default_rng(seed)
    print('seed', seed)
    shared = _descriptors(rng, 60)
    members = [np.vstack([_near_copies(rng, shared, int(rng.integers(2, 30))), _descriptors(rng, int(n))])
               for n in rng.integers(3, 80, 5)]
    members.append(_descriptors(rng, 2))   # fewer rows than K
    parts = [(m, np.sort(rng.choice(len(m), int(rng.integers(1, len(m) + 1)), replace=False))) for m in members]
    union = np.vstack([m[rows] for m, rows in parts])
    query = np.vstack([_near_copies(rng, shared, 10), _descriptors(rng, 40)])
    query_parts = [(query, np.arange(len(query)))]
    cache = NeighbourCache()
    for _ in range(2):   # computed, then kept
        distance, nearest = two_nearest(query, query_parts, union, parts, cache)
        direct_distance, direct_nearest = _two_nearest(query, union)
        assert np.array_equal(distance, direct_distance)
        unique = distance[:, 0] < distance[:, 1]
        assert np.array_equal(nearest[unique], direct_nearest[unique])
        pairs = _ratio_tested(distance, nearest, 0.8)
        assert len(pairs) > 0 and np.array_equal(pairs, _ratio_tested(direct_distance, direct_nearest, 0.8))
    # the rows left out of the union were among the kept nearest: the bound was needed
    kept = [cache.nearest(query, m)[1] for m, _ in parts]
    assert kept[0].shape[1] == K and any(
        (~np.isin(idx, rows)).any() for idx, (_, rows) in zip(kept, parts))


def test_putative_matches_with_kept_neighbours_equal_those_without(repo_root):
    """Two unions of the sample maps (a grid and its neighbours pooled), matched with and without the cache."""
    from multirobot_map_merge.estimation.features import prepare
    from multirobot_map_merge.estimation.union import UnionMap
    from multirobot_map_merge.mapio import load_map
    grids = [load_map(str(p)) for p in sorted((repo_root / 'data' / 'samples' / 'three_robots').glob('map_*.yaml'))]
    prepared = [prepare(g, 0.05, 'akaze') for g in grids]
    union = UnionMap(0.05)
    for k in (1, 2):
        union.add(k, grids[k], prepared[k], np.eye(3))
    onto = union.prepared()
    assert onto.descriptor_parts is not None and len(onto.descriptors) < sum(len(prepared[k].descriptors)
                                                                           for k in (1, 2))
    cache = NeighbourCache()
    for both_ways in (False, True):
        expected = putative_matches(prepared[0], onto, 0.8, both_ways)
        assert len(expected) > 0
        assert np.array_equal(putative_matches(prepared[0], onto, 0.8, both_ways, cache), expected)
