"""estimation/memory.py: how much a robot's map grew and was revised between two estimations (cell by cell)."""
import math

import numpy as np

from multirobot_map_merge.estimation.memory import changed, unchanged
from multirobot_map_merge.grid import Grid


def test_changed_counts_new_cells_and_cells_that_changed_class_only():
    before = Grid(np.zeros((10, 10), np.int8), 0.05, (1.0, 2.0, 0.0))
    data = np.zeros((10, 11), np.int8)   # one more column on the left: the origin moves one cell
    data[:, 0] = 0                       # 10 new known cells
    old = data[:, 1:]                    # the cells `before` knew
    old.flat[:5] = 100                   # free -> occupied: revised
    old.flat[5:8] = -1                   # free -> unknown: revised
    old.flat[8:12] = 30                  # still free: not revised
    after = Grid(data, 0.05, (1.0 - 0.05, 2.0, 0.0))
    grown, revised = changed(before, after)
    assert math.isclose(grown, (10 - 3) / 100)    # 3 cells forgotten, 10 new
    assert math.isclose(revised, 8 / 100)
    assert not unchanged(before, after)           # 8 % revised is more than REVISION


def test_changed_cannot_compare_other_frames():
    before = Grid(np.zeros((4, 4), np.int8), 0.05, (0.0, 0.0, 0.0))
    shifted = Grid(np.zeros((4, 4), np.int8), 0.05, (0.02, 0.0, 0.0))   # not a whole cell
    turned = Grid(np.zeros((4, 4), np.int8), 0.05, (0.0, 0.0, 0.1))
    assert changed(before, shifted) == (math.inf, math.inf)
    assert changed(before, turned) == (math.inf, math.inf)
    assert changed(before, before) == (0.0, 0.0)
