"""A group that a member taken out leaves in pieces is split into them.

A map broken by a SLAM failure that seeds a group places the maps that overlap one of its parts by that part and
the maps that overlap the other by the other: two halves turned against each other by the break. When the maps
left out single it out and it leaves (Grower.evict_contradicted), nothing holds the halves together but the
placements it gave them: in a generated campus held out of the benchmarks, broken map_32 (13.4 degrees) seeded
the merge, left it, and 14 maps stayed 13.4 degrees off the other 13.

So after a member leaves, the group keeps the members that hold together through members that agree as pairs
(eviction.judge_members), the part with the preferred reference or else the largest; every other part
becomes a group of its own, to be matched onto the others as groups are (Grower.merge_groups).
"""
from __future__ import annotations

import logging
from typing import Dict, List, Set

from .eviction import judge_members
from .union import footprint

log = logging.getLogger('rosout.' + __name__)


def parts_of(grower, group) -> List[Set[int]]:
    """The members of `group` in parts that hold together by members agreeing as pairs, the one to keep first."""
    members = dict(group.members)
    edges: Dict[int, Set[int]] = {k: set() for k in members}
    for k, t in members.items():
        others = {j: u for j, u in members.items() if j != k}
        agreeing, _ = judge_members(k, t, others, group.union.footprints, footprint(grower.grids[k], t),
                                    grower.prepared, grower.s, verified=grower.judged)
        for j in agreeing:
            edges[k].add(j)
            edges[j].add(k)
    parts: List[Set[int]] = []
    seen: Set[int] = set()
    for start in members:
        if start in seen:
            continue
        part, todo = set(), [start]
        while todo:
            k = todo.pop()
            if k not in part:
                part.add(k)
                todo.extend(edges[k] - part)
        seen |= part
        parts.append(part)
    return sorted(parts, key=lambda p: (grower.reference not in p, -len(p), min(p)))


def split(grower, group) -> list:
    """Split `group` into its parts (parts_of): it keeps the first, each other part of two or more members becomes
    a new group (returned) in the frame of its largest member, and a member alone leaves (returned as a group of
    one). Nothing happens when the group holds together."""
    parts = parts_of(grower, group)
    if len(parts) < 2:
        return []
    log.debug('group %d falls apart into %s after a member left: it keeps the first', group.seed,
              [sorted(p) for p in parts])
    placed = [{k: group.members[k] for k in part} for part in parts[1:]]
    links = {k: group.links[k] for part in parts[1:] for k in part if k in group.links}
    if group.seed not in parts[0]:
        # the kept part's largest member seeds the group, the matches refused onto it restated (as Grower._evict)
        new_seed = max(parts[0], key=lambda j: grower.prepared[j].known_pixels)
        old_seed = group.seed
        grower.restate_refused(old_seed, new_seed, group.reframe(new_seed))
    out = []
    for part in placed:
        for k in part:
            group.leave(k)
        new = grower.group_of(max(part, key=lambda j: grower.prepared[j].known_pixels), part)
        for k in part:
            if k in links and links[k].j in part:
                new.links[k] = new.paired(links[k], k)
        out.append(new)
    return out
