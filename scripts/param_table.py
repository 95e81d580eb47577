#!/usr/bin/env python3
"""Print the Markdown table of the map_merge node's parameters for the README.

    scripts/env.sh python scripts/param_table.py

It is generated from MapMergeParams (multirobot_map_merge/node_params.py), the same source as the node's docstring
and its code defaults, so the README cannot drift from the code. Needs no ROS master.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, List

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from multirobot_map_merge.node_params import MapMergeParams  # noqa: E402

# the per-robot parameters are read by name at discovery, not through the dataclass
PER_ROBOT = [('<robot_ns>/map_merge/init_pose_x, _y, _z, _yaw', 'double',
              'pose of the robot\'s map frame in world_frame (metres, radians; z required but unused), read only '
              'when known_init_poses is true; an int is accepted'),
             ]


def _default(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)


def _cell(text: str) -> str:
    return text.replace('|', '\\|').replace('<', '&lt;').replace('>', '&gt;')


def table() -> str:
    rows: List[str] = ['| Parameter | Type | Default | Meaning |', '|---|---|---|---|']
    for name, kind, default, doc in MapMergeParams.fields_doc():
        rows.append(f'| `~{name}` | {kind} | `{_default(default)}` | {_cell(doc)} |')
    for name, kind, doc in PER_ROBOT:
        rows.append(f'| `{name}` | {kind} | (none) | {_cell(doc)} |')
    return '\n'.join(rows)


if __name__ == '__main__':
    print(table())
