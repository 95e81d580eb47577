"""A weak pair waits while its grid matches another grid clearly better (estimation/stronger.py).

test/data/pillar_hall_alias: three maps of a generated hall of square pillars (bench_merge.py --generated,
pillar_hall36 maps 17, 30 and 26). `lost` fits `alias`, a map it shares nothing with, a quarter turn away, well
enough to pass the rules; it overlaps `partner` in truth, and agrees with it fully."""
import json
import math
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from multirobot_map_merge import transforms as tf
from multirobot_map_merge.estimation.estimator import estimate
from multirobot_map_merge.estimation.features import prepare
from multirobot_map_merge.estimation.pair import match_pair
from multirobot_map_merge.estimation.settings import EstimationSettings
from multirobot_map_merge.estimation.workers import ParallelMatcher
from multirobot_map_merge.estimation.stronger import AGREEMENT_MARGIN, WEAK_AGREEMENT, PairEvidence, \
    stronger_elsewhere
from multirobot_map_merge.mapio import load_map

LOST, ALIAS, PARTNER = 0, 1, 2


@pytest.fixture(scope='module')
def hall(repo_root):
    folder = repo_root / 'test' / 'data' / 'pillar_hall_alias'
    truth = json.loads((folder / 'truth.json').read_text())
    grids = [load_map(str(folder / m['file'])) for m in truth['maps']]
    return grids, [tf.rigid(*m['pose']) for m in truth['maps']]


def _off(estimated: np.ndarray, poses, k: int, onto: int):
    """(degrees, metres) between a placement of map k in map `onto`'s frame and the truth."""
    d = tf.inverse(tf.inverse(poses[onto]) @ poses[k]) @ estimated
    return math.degrees(abs(math.atan2(d[1, 0], d[0, 0]))), float(np.hypot(*d[:2, 2]))


def test_a_weak_alias_waits_for_the_stronger_pair(hall):
    grids, poses = hall
    s = EstimationSettings()
    prepared = [prepare(g, 0.05, s.feature) for g in grids]
    alias = match_pair(LOST, ALIAS, prepared[LOST], prepared[ALIAS], s, search=False)
    partner = match_pair(LOST, PARTNER, prepared[LOST], prepared[PARTNER], s, search=False)
    # the premise: both pass the rules; the alias is a quarter turn off and agrees weakly, the partner is right
    assert alias.accepted and alias.best.agreement < WEAK_AGREEMENT
    assert _off(alias.transform_m, poses, LOST, ALIAS)[0] > 45.0
    assert partner.accepted and partner.best.agreement >= alias.best.agreement + AGREEMENT_MARGIN
    rot, dist = _off(partner.transform_m, poses, LOST, PARTNER)
    assert rot < 0.5 and dist < 0.1
    with ThreadPoolExecutor(2) as pool, ParallelMatcher(s, pool) as matcher:
        # onto a union the pairs matched already count, and none is yet
        evidence = PairEvidence(prepared, matcher)
        assert stronger_elsewhere(alias, evidence, [ALIAS, PARTNER], s, compute=False) is None
        evidence.put(partner)
        assert stronger_elsewhere(alias, evidence, [ALIAS, PARTNER], s, compute=False).startswith('waits')
        evidence = PairEvidence(prepared, matcher)
        why = stronger_elsewhere(alias, evidence, [ALIAS, PARTNER], s)
        assert why is not None and why.startswith(f'waits: as a pair with grid {PARTNER}')
        # the partner's evidence does not count (a map taken out of the merge): the alias stands on its own
        assert stronger_elsewhere(alias, evidence, [ALIAS, PARTNER], s, skip=lambda x: x == PARTNER) is None
        # the stronger pair is not weak, and the alias is no stronger than it
        assert stronger_elsewhere(partner, evidence, [ALIAS, PARTNER], s) is None


@pytest.mark.parametrize('order', [(0, 1, 2), (1, 0, 2), (2, 1, 0)])
def test_the_estimation_places_the_lost_map_by_its_partner_not_the_alias(hall, order):
    grids, poses = hall
    result = estimate([grids[k] for k in order], EstimationSettings())
    placed = {order[i]: t for i, t in enumerate(result.transforms) if t is not None}
    ref = order[result.reference]
    assert LOST in placed and PARTNER in placed, f'the lost map belongs with its partner: placed {sorted(placed)}'
    for k, t in placed.items():
        rot, dist = _off(t, poses, k, ref)
        assert rot < 0.5 and dist < 0.15, f'map {k} placed {rot:.1f} degrees and {dist:.2f} m off'
