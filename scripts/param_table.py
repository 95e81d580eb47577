#!/usr/bin/env python3
"""The Markdown tables of the nodes' parameters, generated from their parameter dataclasses.

    scripts/env.sh python scripts/param_table.py [map_merge|explore|fleet_sim]   # print one table
    scripts/env.sh python scripts/param_table.py --write                         # update doc/<node>.md

Sources: MapMergeParams (multirobot_map_merge/ros/params.py), ExploreParams (explore/params.py) and FleetSimParams
(fleet_sim/params.py), the same as the nodes' docstrings and code defaults, so the docs cannot drift from the code.
In doc/<node>.md the table sits between `<!-- param_table: NODE -->` and `<!-- /param_table -->`;
test/test_docs.py checks that it is the generated one. Needs no ROS master.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, List

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from explore import params as explore_params  # noqa: E402
from fleet_sim import params as fleet_sim_params  # noqa: E402
from multirobot_map_merge.ros.params import MapMergeParams  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
NODES = ('map_merge', 'explore', 'fleet_sim')

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


def _plain_default(value: Any) -> str:
    """explore's and fleet_sim's style: strings unquoted, the empty string as `empty`/`""`."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    return str(value)


def map_merge_table() -> str:
    rows: List[str] = ['| Parameter | Type | Default | Meaning |', '|---|---|---|---|']
    for d in MapMergeParams.describe():
        rows.append(f'| `~{d.name}` | {d.type} | `{_default(d.default)}` | {_cell(d.doc)} |')
    for name, kind, doc in PER_ROBOT:
        rows.append(f'| `{name}` | {kind} | (none) | {_cell(doc)} |')
    return '\n'.join(rows)


_ROS_TYPES = {'str': 'string', 'float': 'double'}   # explore's table speaks the ROS parameter types


def explore_table() -> str:
    rows = ['| parameter | type | default | unit | description |', '|---|---|---|---|---|']
    for d in explore_params.describe():
        name = f'`~{d.name}`' + (' *(extension)*' if d.extension else '')
        default = 'empty' if d.default == '' else f'`{_plain_default(d.default)}`'
        kind = _ROS_TYPES.get(d.type, d.type)
        rows.append(f'| {name} | {kind} | {default} | {d.unit} | {d.doc} |')
    return '\n'.join(rows)


def fleet_sim_table() -> str:
    rows = ['| parameter | type | default | unit | meaning |', '|---|---|---|---|---|']
    for d in fleet_sim_params.describe():
        default = '""' if d.default == '' else _plain_default(d.default)
        rows.append(f'| `~{d.name}` | {d.type} | `{default}` | {d.unit} | {d.doc} |')
    return '\n'.join(rows)


def table(node: str = 'map_merge') -> str:
    return {'map_merge': map_merge_table, 'explore': explore_table, 'fleet_sim': fleet_sim_table}[node]()


def doc_page(node: str) -> Path:
    return REPO / 'doc' / f'{node}.md'


def replace_table(text: str, node: str) -> str:
    """`text` with its generated table of `node` (between the markers) brought up to date."""
    start, end = f'<!-- param_table: {node} -->', '<!-- /param_table -->'
    i = text.index(start) + len(start)
    j = text.index(end, i)
    return text[:i] + '\n' + table(node) + '\n' + text[j:]


if __name__ == '__main__':
    if sys.argv[1:] == ['--write']:
        for node in NODES:
            page = doc_page(node)
            page.write_text(replace_table(page.read_text(), node))
            print(f'updated {page.relative_to(REPO)}')
    elif len(sys.argv) <= 2 and all(a in NODES for a in sys.argv[1:]):
        print(table(*sys.argv[1:]))
    else:
        sys.exit(f'usage: {sys.argv[0]} [{"|".join(NODES)}] | --write')
