"""Maps revealed as a fleet explores them, and the shared scorer: what bench_node, replay_node and bench_merge --reveal
share.

A robot's map is revealed in 2 m tiles of its final map, nearest to its start (its map frame's origin) first; at
first only the tiles within START_RADIUS m are known. The shared scorer (../shared/eval/score.py) judges
placements against the scenario's truth: an included map placed wrong is a false merge (a broken map placed
consistently with one of its parts is not).
"""
from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

TILE = 40            # cells (2 m at 0.05 m/cell)
START_RADIUS = 3.0   # m known around the start at first
SCORER = Path(__file__).resolve().parents[2] / 'shared' / 'eval' / 'score.py'


def reveal_order(grid) -> Tuple[List[Tuple[int, int]], int]:
    """(tiles (row, col) holding known cells, nearest to the start first; how many are known at first)."""
    h, w = grid.data.shape
    tiles = [(r, c) for r in range(0, h, TILE) for c in range(0, w, TILE)
             if (grid.data[r:r + TILE, c:c + TILE] >= 0).any()]
    to_map = grid.cell_to_map()

    def centre(rc) -> float:
        return float(np.hypot(*(to_map @ [rc[1] + TILE / 2, rc[0] + TILE / 2, 1.0])[:2]))
    tiles.sort(key=centre)
    return tiles, max(sum(centre(t) <= START_RADIUS for t in tiles), 1)


def revealed(grid, tiles: List[Tuple[int, int]], n: int) -> np.ndarray:
    """The grid's cells with only its first n tiles known."""
    shown = np.full_like(grid.data, -1)
    for r, c in tiles[:n]:
        shown[r:r + TILE, c:c + TILE] = grid.data[r:r + TILE, c:c + TILE]
    return shown


def tiles_due(tiles: List, n_start: int, share: float) -> int:
    """Tiles known once `share` (0..1) of the reveal has passed."""
    return max(n_start, int(math.ceil(len(tiles) * min(max(share, 0.0), 1.0))))


def revealed_grids(grids: list, orders: List[Tuple[List[Tuple[int, int]], int]], share: float) -> list:
    """The grids as known once `share` (0..1) of the reveal has passed; `orders`: their reveal_order()."""
    from multirobot_map_merge.grid import Grid
    return [Grid(revealed(g, tiles, tiles_due(tiles, n, share)), g.resolution, g.origin, g.frame_id)
            for g, (tiles, n) in zip(grids, orders)]


def scorer():
    """The shared scorer module, or None when ../shared/eval is not there."""
    if not SCORER.is_file():
        return None
    sys.path.insert(0, str(SCORER.parent))   # the scorer imports its sibling module mapio
    spec = importlib.util.spec_from_file_location('shared_score', SCORER)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def score_placements(score, truth: dict, placed: Dict[int, Optional[np.ndarray]]) -> dict:
    """The scorer's verdict on placements (map index -> 3x3 metric transform into the merged frame, None = left
    out); maps not in `placed` count as left out."""
    files = [m['file'] for m in truth['maps']]
    return score.score_scenario(truth, {files[k]: (t is not None, t if t is not None else np.eye(3), 0)
                                        for k, t in placed.items()})


def wrong_of(scored: dict) -> List[Tuple[str, float, float]]:
    """(file, rotation error degrees, corner error cells) of the included maps the scorer finds placed wrong."""
    return [(p['file'], p['rot_deg'], p['trans_cells']) for p in scored['placements'] if not p['ok']]
