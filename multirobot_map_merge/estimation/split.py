"""A group that a member taken out leaves in pieces is split into them.

A map broken by a SLAM failure that seeds a group places the maps that overlap one of its parts by that part and
the maps that overlap the other by the other: two halves turned against each other by the break. When the maps
left out single it out and it leaves (Grower.evict_contradicted), nothing holds the halves together but the
placements it gave them: in a generated campus held out of the benchmarks, broken map_32 (13.4 degrees) seeded
the merge, left it, and 14 maps stayed 13.4 degrees off the other 13.

So after a member leaves, the group keeps the members that hold together through members that agree as pairs
(eviction.judge_members), the part with the preferred reference or else the largest, and with it every part that
meets it where a member of either passes alone onto the union of the other (as two groups join where they meet,
Grower.joins_where_met); every other part becomes a group of its own, to be matched onto the others as groups are
(Grower.merge_groups).
"""
from __future__ import annotations

import logging
from typing import Dict, List, Set

import numpy as np

from .eviction import judge_members
from .union import footprint

log = logging.getLogger('rosout.' + __name__)


def parts_of(grower, group, without: Set[int] = frozenset()) -> List[Set[int]]:
    """The members of `group` (but those `without`) in parts that hold together by members agreeing as pairs, the
    one to keep first."""
    members = {k: t for k, t in group.members.items() if k not in without}
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
    parts.sort(key=lambda p: (grower.reference not in p, -len(p), min(p)))
    return _held_where_met(grower, group, parts)


def _held_where_met(grower, group, parts: List[Set[int]]) -> List[Set[int]]:
    """`parts` (the one to keep first) with every part of two or more members that meets the kept one where a member
    of either passes alone onto the union of the other (the rule by which two groups join where their unions' match
    was imprecise, Grower.joins_where_met) taken into the kept one.

    A group that joined the merge so is held to it by that member's walls, not by members agreeing as pairs: in the
    generated large36_b a group of 9, seeded by a broken map, joined a group of 12 where map_01 passed alone onto
    their union (its 8 healthy members 0.04-0.06 m from the truth); when the broken map left, the 8 held to the rest
    by no pair, fell apart from it and stayed out (17 of 27 placed)."""
    kept, rest = set(parts[0]), list(parts[1:])
    joined = True
    while joined and len(kept) > 1:
        joined = False
        for part in rest:
            if len(part) > 1 and _meet(grower, group, kept, part):
                kept |= part
                rest.remove(part)
                joined = True
                break
    return [kept] + rest


def _meet(grower, group, a: Set[int], b: Set[int]) -> bool:
    """Whether a member of part a or of part b of `group` passes alone onto the union of the other part."""
    return any(grower.member_passing({k: group.members[k] for k in one},
                                     grower.union_map_of(group, {k: group.members[k] for k in other}),
                                     np.eye(3)) is not None
               for one, other in ((b, a), (a, b)))


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
        grower.split_off.update(part)
        for k in part:
            group.leave(k)
        new = grower.group_of(max(part, key=lambda j: grower.prepared[j].known_pixels), part)
        for k in part:
            if k in links and links[k].j in part:
                new.links[k] = new.paired(links[k], k)
        out.append(new)
    return out
