"""Why each mergeable map of a scenario is left out or placed wrong, read from a `merge_maps -v` log and the scorer.

The estimator logs every match it judges as `pair K-S: ..., <reason or accepted>` (K: the grid matched, S: the seed
of the group whose union it was matched against; a group merge logs the smaller group's seed as K). Replaying the
accepted lines tells which group each map ended in; a mergeable map the result leaves out is then either alone
(its own matches were all refused: the last refusal is its cause) or in a side group that never joined the merge
(the cause is that group's last refused merge). A map placed wrong is reported with the match that placed it.

    from merge_diagnosis import diagnose, cause_of
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Dict, List, Optional

PAIR = re.compile(r'pair (\d+)-(\d+): .*?agreement ([0-9.]+), overlap ([0-9.]+) m2, (.*)$')
# reason text -> cause label; the first that matches (verify.refusal, pair.match_pair, tracking)
CAUSES = [('accepted', 'accepted'), ('contradicting walls', 'contradicting walls'), ('imprecise', 'imprecise'),
          ('ambiguous', 'ambiguous'), ('confidence', 'confidence'), ('support', 'support'),
          ('overlap', 'overlap too small'), ('agreement', 'agreement'), ('no rigid model', 'no rigid model'),
          ('no placed grid', 'no placed grid near it')]


@dataclass
class Match:
    k: int
    seed: int
    agreement: float
    overlap_m2: float
    reason: str

    @property
    def accepted(self) -> bool:
        return self.reason == 'accepted'


@dataclass
class Verdict:
    map_index: int
    outcome: str                 # 'left out' or 'placed wrong'
    cause: str                   # a CAUSES label, or 'never matched'
    detail: str
    side_group: List[int] = field(default_factory=list)


def cause_of(reason: str) -> str:
    return next((label for key, label in CAUSES if key in reason), reason.split(':')[0][:40])


def parse_matches(log_text: str) -> List[Match]:
    out = []
    for line in log_text.splitlines():
        m = PAIR.search(line)
        if m:
            out.append(Match(int(m.group(1)), int(m.group(2)), float(m.group(3)), float(m.group(4)),
                             m.group(5).strip()))
    return out


def groups_of(matches: List[Match], n: int) -> List[int]:
    """The group (a representative index) each grid ends in, replaying the accepted matches in order."""
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a
    for m in matches:
        if m.accepted and m.k < n and m.seed < n:
            parent[root(m.k)] = root(m.seed)
    return [root(a) for a in range(n)]


def _summary(tries: List[Match]) -> str:
    best = max(tries, key=lambda t: t.agreement)
    return (f'{len(tries)} matches refused, the last: {tries[-1].reason} (overlap {tries[-1].overlap_m2:.0f} m2); '
            f'best agreement {best.agreement:.2f} ({best.reason})')


def diagnose(log_text: str, scored: dict, truth: dict) -> List[Verdict]:
    """A verdict for every mergeable map the scorer does not count as placed right."""
    n = len(truth['maps'])
    files = [m['file'] for m in truth['maps']]
    placements = {p['file'].rsplit('/', 1)[-1]: p for p in scored.get('placements', [])}
    ref = (scored.get('reference') or '').rsplit('/', 1)[-1]
    matches = parse_matches(log_text)
    group = groups_of(matches, n)
    verdicts = []
    for k in truth['mergeable']:
        p = placements.get(files[k])
        if files[k] == ref or (p is not None and p['ok']):
            continue
        if p is not None:           # included, but wrong
            how = next((m for m in reversed(matches) if m.accepted and m.k == k), None)
            verdicts.append(Verdict(k, 'placed wrong', 'accepted wrong' if how else 'placed by its group',
                                    f"off by {p['rot_deg']} deg, {p['trans_cells']} cells; "
                                    + (f'accepted onto group {how.seed}: agreement {how.agreement:.2f}, '
                                       f'overlap {how.overlap_m2:.0f} m2' if how else 'joined with its group')))
            continue
        included = {f.rsplit('/', 1)[-1] for f in placements} | {ref}
        side = [a for a in range(n) if group[a] == group[k] and a != k and files[a] not in included]
        if side:                    # placed with others, but that group never joined the merge
            merges = [m for m in matches if not m.accepted and m.k in side + [k] and group[m.seed] != group[k]]
            cause = cause_of(merges[-1].reason) if merges else 'never matched'
            verdicts.append(Verdict(k, 'left out', cause,
                                    f'in a side group of {len(side) + 1} maps; '
                                    + (_summary(merges) if merges else 'its group was never matched'), side))
            continue
        joined = max((i for i, m in enumerate(matches) if m.accepted and m.k == k), default=-1)
        own = [m for m in matches[joined + 1:] if m.k == k and not m.accepted]
        cause = cause_of(own[-1].reason) if own else 'never matched'
        if joined >= 0:             # it joined the merge once and was taken out again (tracking, regrouping)
            verdicts.append(Verdict(k, 'left out', 'joined, then removed' + (f' ({cause})' if own else ''),
                                    _summary(own) if own else 'no refusal of it logged after it joined'))
            continue
        verdicts.append(Verdict(k, 'left out', cause, _summary(own) if own else 'no match of it was judged'))
    return verdicts


def cause_counts(verdicts: List[Verdict]) -> Dict[str, int]:
    out: Dict[str, int] = {}
    for v in verdicts:
        key = f'{v.outcome}: {v.cause}'
        out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def verdict_lines(name: str, verdicts: List[Verdict], files: Optional[List[str]] = None) -> List[str]:
    label = (lambda k: files[k].rsplit('.', 1)[0]) if files else str   # noqa: E731
    return [f'- {name} {label(v.map_index)}: {v.outcome}, {v.cause}: {v.detail}' for v in verdicts]
