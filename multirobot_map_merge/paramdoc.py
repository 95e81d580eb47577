"""One description per node parameter (no rospy): the dataclass field that holds it, and the rows that the node
docstrings and the doc/<node>.md tables (scripts/param_table.py) are generated from, for every node of the package."""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, List, NamedTuple


class ParamDoc(NamedTuple):
    name: str
    type: str      # as the dataclass declares it (float, str, ...) unless the caller names it otherwise
    default: Any
    unit: str
    doc: str
    extension: bool   # not a parameter of the original node


def param(default: Any, doc: str, unit: str = '', extension: bool = False) -> Any:
    """A parameter field: its code default, its one-line meaning, its unit and whether the original lacks it."""
    return dataclasses.field(default=default, metadata={'doc': doc, 'unit': unit, 'extension': extension})


def describe(params_class: type, type_name: Callable[[str], str] = str,
             shown_default: Callable[[str, Any], Any] = lambda name, default: default) -> List[ParamDoc]:
    """One row per parameter of the dataclass, in declaration order."""
    return [ParamDoc(f.name, type_name(f.type if isinstance(f.type, str) else f.type.__name__),
                     shown_default(f.name, f.default), f.metadata.get('unit', ''), f.metadata.get('doc', ''),
                     f.metadata.get('extension', False))
            for f in dataclasses.fields(params_class)]


def docstring(rows: List[ParamDoc]) -> str:
    """The parameter list of a node's docstring: `  ~name (type, default D[, unit]): meaning` per row."""
    return '\n'.join(f'  ~{d.name} ({d.type}, default {d.default!r}{", " + d.unit if d.unit else ""}): {d.doc}'
                     for d in rows)
