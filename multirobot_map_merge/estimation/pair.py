"""Stage 2 of estimation: match one pair of prepared grids and decide whether the match can be trusted.

For a pair (i, j): putative descriptor matches (ratio test, both directions, union as the original), several rigid
RANSAC hypotheses (the metadata fixes the scale, so the model is rigid), each refined by ICP on wall pixels and
checked against the maps themselves: walls of one map must lie on walls of the other wherever both are known.
A pair is accepted only when its best placement agrees well, overlaps enough, is pinned down precisely enough by
the walls the maps share (precision.py), and no clearly different placement agrees almost as well (symmetric
buildings make such aliases; a guess there would be a wrong merge).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import cv2
import numpy as np

from .. import transforms as tf
from .features import PreparedGrid, free_side_field, opposed
from .polish import polish
from .precision import corner_error
from .search import correlate_candidates
from .settings import EstimationSettings

log = logging.getLogger('rosout.multirobot_map_merge.estimation.pair')

FOUND_AGREEMENT = 0.6   # see overlap_found
POLISH_STARTS = 3       # nearby estimates of a small-overlap placement polished, the best kept
LIGHT_ICP_POINTS = 400  # walls of the ICP that brings a turned placement in before it is screened


@dataclass
class Placement:
    """A candidate rigid transform from pixels of grid i to pixels of grid j, with its verification figures."""
    transform: np.ndarray
    support: int = 0            # wall pixels (of both maps) that lie on a wall of the other map
    agreement: float = 0.0      # support / (support + conflicts other than fringe_conflicts)
    overlap_m2: float = 0.0     # common known area
    conflicts: int = 0          # wall pixels in the common known area with no wall of the other map near them
    opposed: int = 0            # wall pixels near a wall of the other map that was seen from the other side
    deep_conflicts: int = 0     # conflicts well inside the other map's known area, not at the fringe of its view
    fringe_conflicts: int = 0   # conflicts at the fringe of the other map's view (the ends of its beams)
    corner_error_m: float = 0.0  # expected error at the far corners of either map (precision.py); best only

    def score(self, conflict_weight: float) -> float:
        """Support less weighted conflicts: a shifted alias in a repetitive building overlaps more (more support)
        but also contradicts more than the right placement, which contradicts almost nowhere."""
        return self.support - conflict_weight * self.conflicts


@dataclass
class PairMatch:
    i: int
    j: int
    # Brown-Lowe statistics on verified correspondences: matches = wall pixels of both maps in the common area,
    # inliers = those with a wall of the other map near them (the placement's support); see pair_confidence()
    matches: int = 0
    inliers: int = 0
    confidence: float = 0.0
    descriptor_matches: int = 0     # putative descriptor matches (ratio test), as the original counts them
    descriptor_inliers: int = 0     # of those, consistent with the final placement
    accepted: bool = False
    reason: str = ''
    best: Optional[Placement] = None
    transform_m: Optional[np.ndarray] = None   # metric: map frame of i -> map frame of j
    alternatives: List[Placement] = field(default_factory=list, repr=False)

    @property
    def weight(self) -> float:
        return float(self.best.support) if self.best is not None else 0.0


def putative_matches(pi: PreparedGrid, pj: PreparedGrid, ratio: float, both_ways: bool = True) -> np.ndarray:
    """(K, 2) index pairs (keypoint of i, keypoint of j) passing the ratio test in either direction (or only from
    i to j: j is a union, most of whose keypoints are nowhere in i)."""
    pi.describe(), pj.describe()
    if pi.descriptors is None or pj.descriptors is None or len(pi.descriptors) < 2 or len(pj.descriptors) < 2:
        return np.zeros((0, 2), np.int64)
    norm = cv2.NORM_HAMMING if pi.descriptors.dtype == np.uint8 else cv2.NORM_L2
    matcher = cv2.BFMatcher(norm)
    found = set()
    directions = ((pi.descriptors, pj.descriptors, False), (pj.descriptors, pi.descriptors, True))
    for query, train, swapped in directions[:2 if both_ways else 1]:
        for pair in matcher.knnMatch(query, train, k=2):
            if len(pair) == 2 and pair[0].distance < ratio * pair[1].distance:
                a, b = pair[0].queryIdx, pair[0].trainIdx
                found.add((b, a) if swapped else (a, b))
    return np.array(sorted(found), np.int64).reshape(-1, 2)


def ransac_rigid(p: np.ndarray, q: np.ndarray, threshold: float, iterations: int,
                 rng: np.random.Generator) -> Tuple[Optional[np.ndarray], np.ndarray]:
    """Best rigid transform p -> q by 2-point RANSAC (vectorised over all hypotheses), refit on its inliers."""
    n = len(p)
    if n < 3:
        return None, np.zeros(n, bool)
    idx = rng.integers(0, n, (iterations, 2))
    idx = idx[idx[:, 0] != idx[:, 1]]
    dp = p[idx[:, 1]] - p[idx[:, 0]]
    dq = q[idx[:, 1]] - q[idx[:, 0]]
    lp, lq = np.hypot(*dp.T), np.hypot(*dq.T)
    # a rigid motion keeps distances: drop samples that cannot be one (and too short ones: bad angle)
    keep = (lp > 5.0) & (np.abs(lp - lq) < 1.5 * threshold)
    idx, dp, dq = idx[keep], dp[keep], dq[keep]
    if len(idx) == 0:
        return None, np.zeros(n, bool)
    ang = np.arctan2(dq[:, 1], dq[:, 0]) - np.arctan2(dp[:, 1], dp[:, 0])
    c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
    p0, q0 = p[idx[:, 0]], q[idx[:, 0]]
    tx = (q0[:, 0] - (c[:, 0] * p0[:, 0] - s[:, 0] * p0[:, 1]))[:, None]
    ty = (q0[:, 1] - (s[:, 0] * p0[:, 0] + c[:, 0] * p0[:, 1]))[:, None]
    ex = c * p[:, 0] - s * p[:, 1] + tx - q[:, 0]
    ey = s * p[:, 0] + c * p[:, 1] + ty - q[:, 1]
    inliers = ex * ex + ey * ey < threshold * threshold
    mask = inliers[np.argmax(inliers.sum(axis=1))]
    model = None
    for _ in range(3):
        if mask.sum() < 3:
            break
        model = tf.kabsch(p[mask], q[mask])
        mask = np.hypot(*(tf.apply(model, p) - q).T) < threshold
    return model, mask


def hypotheses(p: np.ndarray, q: np.ndarray, s: EstimationSettings, rng: np.random.Generator) -> List[np.ndarray]:
    """Up to s.max_hypotheses rigid models, each found after removing the inliers of the previous ones."""
    found = []
    remaining = np.arange(len(p))
    while len(found) < s.max_hypotheses and len(remaining) >= s.min_inliers:
        model, mask = ransac_rigid(p[remaining], q[remaining], s.ransac_threshold, s.ransac_iterations, rng)
        if model is None or mask.sum() < s.min_inliers:
            break
        found.append(model)
        remaining = remaining[~mask]
    return found


def icp(pi: PreparedGrid, pj: PreparedGrid, start: np.ndarray, s: EstimationSettings,
        rng: np.random.Generator) -> np.ndarray:
    """Refine a pixel transform i -> j by point-to-point ICP of i's walls onto j's nearest walls."""
    src, src_side = pi.walls, pi.wall_normals
    if len(src) > s.icp_max_points:
        pick = rng.choice(len(src), s.icp_max_points, replace=False)
        src, src_side = src[pick], src_side[pick]
    model = start.copy()
    if len(src) < 10 or len(pj.walls) < 10:
        return model
    # shrinking correspondence radius: coarse capture first, then precise; each level runs until it settles
    for radius in s.icp_radii:
        for _ in range(s.icp_iterations):
            moved = tf.apply(model, src)
            nn, dist = pj.nearest(moved)
            close = dist < radius
            if s.facing and close.any():
                # a wall's two faces are not the same wall: pair only walls seen from the same side
                turned = src_side[close] @ model[:2, :2].T
                far_side = pj.free_side[nn[close, 1].astype(np.int64), nn[close, 0].astype(np.int64)]
                close[np.flatnonzero(close)[opposed(turned, far_side)]] = False
            if close.sum() < 10:
                return model
            step = tf.kabsch(moved[close], nn[close])
            model = step @ model
            if abs(step[1, 0]) < 5e-4 and np.abs(step[:2, 2]).max() < 0.1:
                break
    return model


def quick_agreement(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, s: EstimationSettings,
                    rng: np.random.Generator) -> float:
    """Share of sampled walls of i that land near a wall of j, among those landing on j's known area.

    A cheap screen before ICP: hypotheses from unrelated maps score near zero, rough but right ones well above.
    """
    src = pi.walls
    if len(src) > s.screen_points:
        src = src[rng.choice(len(src), s.screen_points, replace=False)]
    moved = np.rint(tf.apply(model, src)).astype(np.int64)
    h, w = pj.work.shape
    inside = (moved[:, 0] >= 0) & (moved[:, 1] >= 0) & (moved[:, 0] < w) & (moved[:, 1] < h)
    x, y = moved[inside, 0], moved[inside, 1]
    on_known = pj.work[y, x] >= 0
    if on_known.sum() < 20:
        return 0.0
    return float((pj.wall_distance[y[on_known], x[on_known]] <= s.screen_tolerance).mean())


def verify(pi: PreparedGrid, pj: PreparedGrid, model: np.ndarray, s: EstimationSettings) -> Placement:
    """How well grid i placed by `model` (pixels i -> pixels j) agrees with grid j.

    Only walls in the common known area count. A wall near a wall of the other map supports the placement, unless
    the two were seen from opposite sides (a wall's two faces: neither support nor conflict); any other wall there
    contradicts it. A contradiction at the fringe of the other map's view (the ends of its beams) is common at the
    right placement and does not lower the agreement (fringe_conflicts); one well inside it is rare there
    (deep_conflicts).
    """
    h, w = pj.work.shape
    warped = cv2.warpAffine(pi.work.view(np.uint8), model[:2], (w, h), flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=255).view(np.int8)
    both = (warped >= 0) & (pj.work >= 0)
    rows, cols = np.nonzero(both)
    result = Placement(model, overlap_m2=float(rows.size) * pi.resolution ** 2)
    if rows.size == 0:
        return result
    # everything else only where both maps are known (plus a margin for the distance and side fields)
    r0, r1 = max(rows.min() - 8, 0), rows.max() + 9
    c0, c1 = max(cols.min() - 8, 0), cols.max() + 9
    wi, wj, both = warped[r0:r1, c0:c1], pj.work[r0:r1, c0:c1], both[r0:r1, c0:c1]
    walls_i = both & (wi >= 50)
    walls_j = both & (wj >= 50)
    n_i, n_j = int(walls_i.sum()), int(walls_j.sum())
    if n_i + n_j == 0:
        return result
    dist_i = cv2.distanceTransform(np.where(wi >= 50, 0, 255).astype(np.uint8), cv2.DIST_L2, 3)
    tol = s.verify_tolerance
    near_j = pj.wall_distance[r0:r1, c0:c1] <= tol
    near_i = dist_i <= tol
    agree_i, agree_j = walls_i & near_j, walls_j & near_i
    support = int(agree_i.sum()) + int(agree_j.sum())
    neutral = 0
    if s.facing and support:
        # only at the agreeing walls: the side fields are costly over the whole area
        rows, cols = np.nonzero(agree_i | agree_j)
        weight = agree_i[rows, cols].astype(np.int64) + agree_j[rows, cols]
        side_i = free_side_field(wi)[rows, cols]
        faces = opposed(side_i, pj.free_side[rows + r0, cols + c0])
        neutral = int(weight[faces].sum())
        support -= neutral
    result.support = support
    result.conflicts = n_i + n_j - support - neutral
    # how deep inside the other map's view each contradicting wall lies
    depth = [pj.known_depth[r0:r1, c0:c1][walls_i & ~near_j]]
    rows, cols = np.nonzero(walls_j & ~near_i)
    if rows.size:
        # j's contradicting walls: i's depth at the same place, looked up through the inverse placement
        back = np.rint(tf.apply(tf.inverse(model), np.column_stack([cols + c0, rows + r0]))).astype(np.int64)
        hi, wi_ = pi.work.shape
        inside = (back[:, 0] >= 0) & (back[:, 1] >= 0) & (back[:, 0] < wi_) & (back[:, 1] < hi)
        depth.append(pi.known_depth[back[inside, 1], back[inside, 0]])
    depth = np.concatenate(depth)
    result.deep_conflicts = int((depth > s.deep_conflict_m / pi.resolution).sum())
    result.fringe_conflicts = result.conflicts - int((depth > s.fringe_px).sum())
    result.opposed = neutral
    result.agreement = support / float(max(support + result.conflicts - result.fringe_conflicts, 1))
    return result


def plausible(c: Placement, s: EstimationSettings) -> bool:
    """Agrees well over a common area large enough to mean something, and (almost) everywhere well inside both
    maps' views."""
    return (c.agreement >= s.min_agreement and c.overlap_m2 >= s.min_overlap_m2 and c.support >= s.min_support
            and c.deep_conflicts <= s.max_deep_conflicts * c.support)


def refusal(c: Placement, pi: PreparedGrid, pj: PreparedGrid, s: EstimationSettings, onto_union: bool = False) -> str:
    """Why placement c of grid i on grid j fails the pair acceptance rules ('' if it passes): agreement, overlap,
    support, deep contradictions (as `plausible`), then precision, the costly one, which it stores in c. With
    `onto_union`, j is the union of a placed group: precision counts at grid i's corners only (the union stays)."""
    if c.agreement < s.min_agreement:
        return f'agreement {c.agreement:.2f} < {s.min_agreement:.2f}'
    if c.overlap_m2 < s.min_overlap_m2:
        return f'overlap {c.overlap_m2:.1f} m2 < {s.min_overlap_m2:.1f} m2'
    if c.support < s.min_support:
        return f'support {c.support} < {s.min_support}'
    if c.deep_conflicts > s.max_deep_conflicts * c.support:
        return (f'{c.deep_conflicts} contradicting walls well inside both maps, more than '
                f'{s.max_deep_conflicts:.0%} of {c.support} agreeing')
    c.corner_error_m = corner_error(pi, pj, c.transform, s.verify_tolerance, moving_only=onto_union) * pi.resolution
    if c.corner_error_m > s.max_corner_error_m:
        return (f'imprecise: the shared walls leave the far corners uncertain by '
                f'{c.corner_error_m:.2f} m > {s.max_corner_error_m:.2f} m')
    return ''


def symmetric_alternatives(pi: PreparedGrid, pj: PreparedGrid, best: Placement) -> List[np.ndarray]:
    """The best placement turned by 90, 180 and 270 degrees about the middle of the common area.

    Buildings repeat themselves; a placement that is as good after such a turn means the match is ambiguous.
    """
    h, w = pj.work.shape
    warped = cv2.warpAffine(pi.work.view(np.uint8), best.transform[:2], (w, h), flags=cv2.INTER_NEAREST,
                            borderValue=255).view(np.int8)
    rows, cols = np.nonzero((warped >= 0) & (pj.work >= 0))
    if rows.size == 0:
        return []
    cx, cy = cols.mean(), rows.mean()
    out = []
    for quarter in (1, 2, 3):
        turn = tf.translation(cx, cy) @ tf.rigid(0.0, 0.0, quarter * math.pi / 2) @ tf.translation(-cx, -cy)
        out.append(turn @ best.transform)
    return out


def distinct(a: np.ndarray, b: np.ndarray, pi: PreparedGrid, s: EstimationSettings) -> bool:
    """Whether two placements (pixel transforms of grid i) are different places, not two estimates of one."""
    h, w = pi.work.shape
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], float)
    rot, disp = tf.difference(a, b, corners)
    return rot > math.radians(s.distinct_degrees) or disp * pi.resolution > s.distinct_metres


def find_rival(pi: PreparedGrid, pj: PreparedGrid, best: Placement, s: EstimationSettings,
               keep: int = 40) -> Optional[Placement]:
    """Another place for grid i on grid j that passes the rules of `plausible` (not the precision rule), however
    much smaller its common area, searched by correlation away from `best` (`keep` candidates refined).

    Not an acceptance rule: small consistent placements are common (a corner of one map fitting a corner of the
    other), and on the saved maps of 199 live-demo runs such a rival, with 100-177 agreeing wall cells, existed
    for 19 right placements with 153-2175. scripts/evidence_report.py uses it to show true ambiguity."""
    rng = np.random.default_rng(s.seed)
    models = correlate_candidates(pi, pj, s.search_factor, s.search_sweep_degrees, peaks_per_angle=4,
                                  keep=keep, penalty=s.search_penalty,
                                  free_reward=s.search_free_reward,
                                  wanted=lambda model: distinct(model, best.transform, pi, s))
    for model in models:
        if quick_agreement(pi, pj, model, s, rng) < s.screen_min_agreement:
            continue
        c = verify(pi, pj, icp(pi, pj, model, s, rng), s)
        if plausible(c, s) and distinct(c.transform, best.transform, pi, s):
            return c
    return None


def overlap_found(c: Optional[Placement], s: EstimationSettings, onto_union: bool = False) -> bool:
    """Whether a placement shows the maps' overlap although it fails the rules: it agrees except for contradictions
    inside both views (a map broken by a SLAM failure), or, onto a union, it has twice the support a pair needs
    and agrees mostly (a broken map fits the union in part). Then a search would find the same placement."""
    if c is None:
        return False
    return (plausible(c, s.replace(max_deep_conflicts=math.inf))
            or (onto_union and c.support >= 2 * s.min_support and c.overlap_m2 >= s.min_overlap_m2
                and c.agreement >= FOUND_AGREEMENT))


def pair_confidence(inliers: int, matches: int) -> float:
    """The original's confidence, inliers / (8 + 0.3 matches) (Brown & Lowe), here on verified correspondences.

    The original counts descriptor matches; on occupancy grids these are few and mostly wrong, so its threshold
    (default 1.0) says little. Counted on wall pixels, 1.0 means about a third of the walls in the common area
    agree; the acceptance rules (min_agreement etc.) are stricter, so the default threshold never decides alone,
    and a higher one (up to about 3.3 = every wall agrees) asks for more agreement.
    """
    return inliers / (8.0 + 0.3 * matches)


def match_pair(i: int, j: int, pi: PreparedGrid, pj: PreparedGrid, s: EstimationSettings,
               search: bool = True, onto_union: bool = False, descriptors: bool = True) -> PairMatch:
    """Match grids i and j; the result's transform_m maps metric points of map i into map j.

    With search=False, only descriptor matches propose placements (cheap); otherwise a correlation search adds
    candidates when they found no plausible one. With descriptors=False, only the search does (the caller has
    matched descriptors already and found nothing plausible). With `onto_union`, j is the union of a placed group
    (see refusal).
    """
    result = PairMatch(i, j)
    rng = np.random.default_rng(s.seed + 7919 * i + j)

    def refine(model: np.ndarray, screen: bool = True) -> Optional[Placement]:
        if screen and quick_agreement(pi, pj, model, s, rng) < s.screen_min_agreement:
            return None
        if not screen:
            # far off until ICP pulls it in: screened after a light ICP (few walls) instead
            model = icp(pi, pj, model, light, rng)
            if quick_agreement(pi, pj, model, s, rng) < s.screen_min_agreement:
                return None
        return verify(pi, pj, icp(pi, pj, model, s, rng), s)

    def refine_all(models, screen: bool = True) -> List[Placement]:
        return [c for c in (refine(m, screen) for m in models) if c is not None]

    light = s.replace(icp_max_points=LIGHT_ICP_POINTS)
    pairs = putative_matches(pi, pj, s.ratio, not onto_union) if descriptors else np.zeros((0, 2), np.int64)
    result.descriptor_matches = len(pairs)
    p, q = (pi.keypoints[pairs[:, 0]], pj.keypoints[pairs[:, 1]]) if len(pairs) else (np.zeros((0, 2)),) * 2

    def rank(c: Placement):
        # a placement that agrees beats any that does not, however large
        return plausible(c, s), c.score(s.conflict_weight)

    candidates = refine_all(hypotheses(p, q, s, rng))
    best = max(candidates, key=rank, default=None)
    if search and (best is None or not plausible(best, s)) and not overlap_found(best, s, onto_union):
        # too few good descriptor matches (small overlaps): search placements by correlation instead;
        # not when the overlap was found and the maps contradict there (a broken map): a search finds the same
        candidates += refine_all(correlate_candidates(pi, pj, s.search_factor, s.search_sweep_degrees,
                                                      keep=s.search_keep, penalty=s.search_penalty,
                                                      free_reward=s.search_free_reward))
        best = max(candidates, key=rank, default=None)
    if best is None:
        result.reason = 'no rigid model'
        return result
    if plausible(best, s):
        # only worth the extra work for a placement that could be accepted
        candidates += refine_all(symmetric_alternatives(pi, pj, best), screen=False)
    candidates.sort(key=rank, reverse=True)
    if plausible(candidates[0], s) and (candidates[0].support < s.polish_below_support
                                        or candidates[0].overlap_m2 < s.polish_below_overlap_m2):
        # ICP is precise on a large common area (there the polish measured worse), not always on a small one; the
        # other plausible estimates of the same place are polished too, and the most consistent result is kept
        same = [c.transform for c in candidates[1:] if plausible(c, s)
                and not distinct(c.transform, candidates[0].transform, pi, s)][:POLISH_STARTS - 1]
        polished = verify(pi, pj, polish(pi, pj, [candidates[0].transform] + same, rng), s)
        candidates[0] = polished if plausible(polished, s) else candidates[0]
    best = candidates[0]
    result.best = best
    result.alternatives = candidates[1:]
    if len(pairs):
        result.descriptor_inliers = int((np.hypot(*(tf.apply(best.transform, p) - q).T) < s.ransac_threshold).sum())
    result.matches, result.inliers = best.support + best.conflicts, best.support
    result.confidence = pair_confidence(result.inliers, result.matches)
    result.transform_m = pj.px_to_map @ best.transform @ tf.inverse(pi.px_to_map)

    best_score = best.score(s.conflict_weight)
    rival = next((c for c in candidates[1:] if distinct(c.transform, best.transform, pi, s) and plausible(c, s)
                  and c.score(s.conflict_weight) >= s.ambiguity_ratio * best_score), None)
    result.reason = refusal(best, pi, pj, s, onto_union)
    if not result.reason and rival is not None:
        result.reason = (f'ambiguous: another placement agrees {rival.agreement:.2f} with support '
                         f'{rival.support} vs {best.support}')
    if not result.reason and result.confidence < s.confidence:
        result.reason = f'confidence {result.confidence:.2f} < {s.confidence:.2f}'
    result.accepted = not result.reason
    log.debug('pair %d-%d: %d descriptor matches (%d inliers), %d wall correspondences (%d inliers), confidence '
              '%.3f, agreement %.3f, overlap %.1f m2, %s', i, j, result.descriptor_matches, result.descriptor_inliers,
              result.matches, result.inliers, result.confidence, best.agreement, best.overlap_m2,
              'accepted' if result.accepted else result.reason)
    return result
