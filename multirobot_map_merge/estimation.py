"""Stage 3 of estimation: from pairwise matches to one metric transform per grid.

Accepted pairs form a graph; its largest connected component is merged. A maximum spanning tree (weight = the
pair's agreeing wall pixels) is walked from the reference grid, composing transforms in the right order:
T_child = T_parent @ H(child -> parent). (The C++ node composes in the reverse order, which misplaces grids two
or more hops from the reference.) Accepted pairs outside the tree are checked against it and reported.
"""
from __future__ import annotations

import logging
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import combinations
from typing import Dict, List, Optional, Sequence

import networkx as nx
import numpy as np

from . import transforms as tf
from .compose import compose
from .features import FeatureCache, PreparedGrid, prepare
from .grid import Grid
from .matching import PairMatch, match_pair, refusal, verify
from .settings import EstimationSettings

log = logging.getLogger('rosout.multirobot_map_merge.estimation')


@dataclass
class Estimate:
    """transforms[k]: metric map frame of grid k -> merged frame (the reference grid's map frame); None = excluded."""
    transforms: List[Optional[np.ndarray]]
    reference: Optional[int]
    pairs: List[PairMatch] = field(default_factory=list)
    inconsistent: List[PairMatch] = field(default_factory=list)
    seconds: float = 0.0


def working_resolution(grids: Sequence[Optional[Grid]], settings: EstimationSettings) -> float:
    """The finest resolution among the grids, but not finer than settings.min_work_resolution."""
    res = [g.resolution for g in grids if g is not None]
    return max(min(res), settings.min_work_resolution) if res else settings.min_work_resolution


def match_all(prepared: Sequence[Optional[PreparedGrid]], settings: EstimationSettings,
              pool: ThreadPoolExecutor) -> List[PairMatch]:
    """Match every pair by descriptors, then search (costly) only pairs that would join unconnected groups."""
    jobs = [(i, j) for i, j in combinations(range(len(prepared)), 2)
            if prepared[i] is not None and prepared[j] is not None]
    results = dict(zip(jobs, pool.map(
        lambda ij: match_pair(ij[0], ij[1], prepared[ij[0]], prepared[ij[1]], settings, search=False), jobs)))
    groups = nx.utils.UnionFind(range(len(prepared)))
    for (i, j), m in results.items():
        if m.accepted:
            groups.union(i, j)
    pending = [ij for ij, m in results.items() if not m.accepted]
    while pending:
        batch = [ij for ij in pending if groups[ij[0]] != groups[ij[1]]][:settings.threads]
        if not batch:
            break
        pending = [ij for ij in pending if ij not in batch]
        for ij, m in zip(batch, pool.map(
                lambda ij: match_pair(ij[0], ij[1], prepared[ij[0]], prepared[ij[1]], settings), batch)):
            results[ij] = m
            if m.accepted:
                groups.union(*ij)
    return [results[ij] for ij in jobs]


def pick_component(graph: nx.Graph, preferred: Optional[int]) -> List[int]:
    components = sorted((sorted(c) for c in nx.connected_components(graph)), key=lambda c: (-len(c), c[0]))
    largest = [c for c in components if len(c) == len(components[0])]
    for comp in largest:
        if preferred in comp:
            return comp
    return largest[0]


def tree_transforms(tree: nx.Graph, reference: int) -> Dict[int, np.ndarray]:
    """Compose along the tree from the reference: T[k] maps map k into the reference's map frame."""
    out = {reference: np.eye(3)}
    for parent, child in nx.bfs_edges(tree, reference):
        out[child] = out[parent] @ tree.edges[parent, child]['to'][(child, parent)]
    return out


def keep_previous(placed: Dict[int, np.ndarray], previous: Sequence[Optional[np.ndarray]],
                  grids: Sequence[Optional[Grid]], prepared: Sequence[Optional[PreparedGrid]], res: float,
                  settings: EstimationSettings) -> List[int]:
    """Grids placed before but not now keep their previous placement while they still agree with the placed
    ones together (the acceptance rules of a pair, precision included). A live map that grew can lose its only
    match for a while (a new part resembles something else); dropping it from the merged map until then helps no
    one. Returns the grids kept."""
    lost = [k for k, t in enumerate(previous) if t is not None and k not in placed and prepared[k] is not None]
    if not lost:
        return []
    others = compose([g if k in placed else None for k, g in enumerate(grids)],
                     [placed.get(k) for k in range(len(grids))])
    context = prepare(others, res, None) if others is not None else None
    if context is None:
        return []
    kept = []
    for k in lost:
        model = tf.inverse(context.px_to_map) @ previous[k] @ prepared[k].px_to_map
        if not refusal(verify(prepared[k], context, model, settings), prepared[k], context, settings):
            kept.append(k)
    for k in kept:
        placed[k] = np.asarray(previous[k], float)
    return kept


def estimate(grids: Sequence[Optional[Grid]], settings: EstimationSettings, cache: Optional[FeatureCache] = None,
             preferred_reference: Optional[int] = None,
             previous: Optional[Sequence[Optional[np.ndarray]]] = None) -> Estimate:
    """Estimate where every grid goes. Grids that are None, empty or unmatched get no transform, unless `previous`
    (the last estimate's transforms, same grid order) placed them and they still agree (see keep_previous)."""
    settings.validate()
    t0 = time.perf_counter()
    cache = cache or FeatureCache()
    res = working_resolution(grids, settings)
    usable = [g if g is not None and not g.is_empty() else None for g in grids]
    with ThreadPoolExecutor(max_workers=settings.threads) as pool:
        prepared = list(pool.map(lambda g: cache.get(g, res, settings.feature) if g is not None else None, usable))
        pairs = match_all(prepared, settings, pool)

    present = [k for k, p in enumerate(prepared) if p is not None]
    transforms: List[Optional[np.ndarray]] = [None] * len(grids)
    if not present:
        return Estimate(transforms, None, pairs, seconds=time.perf_counter() - t0)

    graph = nx.Graph()
    graph.add_nodes_from(present)
    for m in pairs:
        if m.accepted:
            graph.add_edge(m.i, m.j, weight=m.weight, match=m,
                           to={(m.i, m.j): m.transform_m, (m.j, m.i): tf.inverse(m.transform_m)})
    component = pick_component(graph, preferred_reference)
    tree = nx.maximum_spanning_tree(graph.subgraph(component), weight='weight')
    if preferred_reference in component:
        reference = preferred_reference
    else:
        reference = min(nx.center(tree)) if len(component) > 1 else component[0]
    placed = tree_transforms(tree, reference)
    if previous is not None and reference == preferred_reference and len(previous) == len(grids) \
            and previous[reference] is not None and np.allclose(previous[reference], np.eye(3)):
        # same reference, so the same merged frame
        kept = keep_previous(placed, previous, usable, prepared, res, settings)
        if kept:
            log.info('kept the previous placement of grid(s) %s: no pair places them now, but they still agree '
                     'with the placed grids', ', '.join(map(str, kept)))
    for k, t in placed.items():
        transforms[k] = t

    inconsistent = []
    for a, b, data in graph.subgraph(component).edges(data=True):
        if tree.has_edge(a, b):
            continue
        m: PairMatch = data['match']
        predicted = tf.inverse(placed[m.j]) @ placed[m.i]
        h, w = prepared[m.i].work.shape
        corners = tf.apply(prepared[m.i].px_to_map, np.array([[0, 0], [w, 0], [0, h], [w, h]], float))
        rot, disp = tf.difference(predicted, m.transform_m, corners)
        if rot > math.radians(settings.distinct_degrees) or disp > settings.distinct_metres:
            inconsistent.append(m)
            log.debug('pair %d-%d disagrees with the tree by %.1f deg, %.2f m', m.i, m.j, math.degrees(rot), disp)
    seconds = time.perf_counter() - t0
    log.debug('estimated %d grids: %d placed around grid %d, %d accepted pairs (%d off the tree disagree), %.2f s',
              len(grids), len(component), reference, graph.number_of_edges(), len(inconsistent), seconds)
    return Estimate(transforms, reference, pairs, inconsistent, seconds)
